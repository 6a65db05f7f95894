"""Which errors mean that a Ctrl-C or SIGTERM stopped an rclpy process, and a block that such a stop ends quietly
(real rclpy context, no DDS traffic)."""

import signal
import threading

import pytest
import rclpy
from rclpy.executors import ExternalShutdownException

from tactile_conversions import stop_signals
from tactile_conversions.stop_signals import init_ros, stopped_by_signal, until_stop_signal

#: What a Ctrl-C raised inside rclpy's conversion of a taken message became in a bundle node (pybind11's words).
CONVERSION_ERROR = RuntimeError("Unable to convert call argument '0' to Python object")


def test_before_ros_is_started_an_error_is_no_stop(monkeypatch):
    """rclpy's context is not valid before init_ros either: every error passed for a stop, and a block ended by a real
    failure ended quietly as if stopped (review)."""
    monkeypatch.setattr(stop_signals, "_started", threading.Event())  # as in a process that has not started ROS
    rclpy.try_shutdown()  # no context left over from another test
    assert not rclpy.ok() and not stopped_by_signal(ValueError("a real bug"))
    with pytest.raises(ValueError, match="a real bug"), until_stop_signal():
        raise ValueError("a real bug")


def test_an_error_is_a_stop_only_once_rclpy_is_shut_down(ros_started_by_init_ros):
    assert stopped_by_signal(KeyboardInterrupt()) and stopped_by_signal(ExternalShutdownException())
    assert not stopped_by_signal(RuntimeError("failed to create timer"))  # a real failure while ROS runs
    rclpy.shutdown()  # what rclpy's handler does at once on SIGINT or SIGTERM
    assert stopped_by_signal(RuntimeError("failed to create timer: the given context is not valid"))
    assert not stopped_by_signal(SystemExit(1))  # not an error of an rcl call


def test_a_block_until_a_stop_signal_ends_quietly_on_the_stop_only(ros_started_by_init_ros):
    ran_on = []
    with until_stop_signal() as stop:
        raise KeyboardInterrupt
    assert stop.signalled
    with until_stop_signal() as stop:
        pass
    assert not stop.signalled  # a block that ran to its end
    with pytest.raises(RuntimeError, match="a real failure"), until_stop_signal():
        raise RuntimeError("a real failure")
    rclpy.shutdown()
    with until_stop_signal() as stop:
        raise RuntimeError("failed to get subscription count: publisher's context is invalid")
    ran_on.append(stop.signalled)  # reached: the stop did not leave the function
    assert ran_on == [True]


@pytest.fixture
def ros_started_by_init_ros(monkeypatch):
    monkeypatch.setattr(stop_signals, "_started", threading.Event())  # init_ros's flags, fresh for each test
    monkeypatch.setattr(stop_signals, "_interrupted", threading.Event())
    python_handler = signal.getsignal(signal.SIGINT)
    init_ros()
    yield
    rclpy.try_shutdown()
    signal.signal(signal.SIGINT, python_handler)


def test_an_error_after_a_ctrl_c_is_a_stop_while_rclpy_still_runs(ros_started_by_init_ros):
    assert not stopped_by_signal(CONVERSION_ERROR)
    with pytest.raises(KeyboardInterrupt):  # the Python handler that rclpy's passes SIGINT on to, called alone: the
        signal.getsignal(signal.SIGINT)(signal.SIGINT, None)  # moment before rclpy's thread shuts the context down
    assert rclpy.ok() and stopped_by_signal(CONVERSION_ERROR)
    rclpy.shutdown()
    init_ros()  # a new session starts without the old Ctrl-C
    assert not stopped_by_signal(CONVERSION_ERROR)


def test_a_real_ctrl_c_after_init_ros_raises_keyboard_interrupt_and_counts_as_a_stop(ros_started_by_init_ros):
    with pytest.raises(KeyboardInterrupt):  # through rclpy's handler, which passes it on to the recording one
        signal.raise_signal(signal.SIGINT)
    assert stopped_by_signal(CONVERSION_ERROR)
