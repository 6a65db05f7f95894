"""run_node: how a node's process ends (real rclpy, no DDS traffic)."""

import datetime
import select
import signal
import subprocess
import sys
import time

import pytest
import rclpy
from rclpy.node import Node
from std_msgs.msg import Header

from tactile_conversions.node_main import TEARDOWN_TIMEOUT_S, run_node
from tactile_conversions.parameters import boolean, sensor_description


@pytest.fixture(autouse=True)
def restore_ctrl_c():
    """run_node leaves SIGINT ignored (its process is ending); give this test process its handler back."""
    previous = signal.getsignal(signal.SIGINT)
    yield
    signal.signal(signal.SIGINT, previous)


class ShutDownWhileStarting(Node):
    """What Ctrl-C during a node's constructor looks like: the context is shut down, then a publisher is made."""

    def __init__(self):
        super().__init__("shut_down_while_starting")
        rclpy.shutdown()
        self.create_publisher(Header, "/never", 1)


def test_an_error_after_shutdown_was_requested_ends_the_node_cleanly():
    with pytest.raises(Exception, match="destruction was requested"):  # what such a node does outside run_node
        rclpy.init()
        try:
            ShutDownWhileStarting()
        finally:
            rclpy.try_shutdown()
    assert run_node(ShutDownWhileStarting) is None
    assert not rclpy.ok()
    # A Ctrl-C repeated while the node shuts down (stop_nodes repeats it) must not interrupt the shutdown.
    assert signal.getsignal(signal.SIGINT) == signal.SIG_IGN


def test_an_error_while_ros_runs_is_printed_ros_is_shut_down_and_the_exit_code_is_1(capfd):
    def broken_node():
        raise ValueError("bad parameter")

    with pytest.raises(SystemExit) as ended:
        run_node(broken_node)
    assert ended.value.code == 1
    assert "ValueError: bad parameter" in capfd.readouterr().err
    assert not rclpy.ok()


class Switched(Node):
    """A node with one switch, as the camera nodes' `loop`."""

    def __init__(self):
        super().__init__("switched")
        boolean(self, "loop", True)


def test_a_refused_parameter_ends_the_node_with_one_line_and_exit_code_2(capfd):
    """As a command line refuses its input; rclpy's typed declaration of `loop` ended in an
    InvalidParameterTypeException traceback and exit code 1."""
    with pytest.raises(SystemExit) as ended:
        run_node(Switched, ["--ros-args", "-p", "loop:=0"])
    assert ended.value.code == 2
    assert capfd.readouterr().err == "switched: parameter loop must be a bool (true or false), got 0\n"
    assert not rclpy.ok()


class Described(Node):
    def __init__(self):
        super().__init__("described")
        sensor_description(self)


def test_a_refused_sensor_description_is_one_line_though_the_yaml_parser_says_it_in_several(capfd, tmp_path):
    broken = tmp_path / "sensor.yaml"
    broken.write_text("name: [unclosed\n")
    with pytest.raises(SystemExit) as ended:
        run_node(Described, ["--ros-args", "-p", f"sensor_config:={broken}"])
    assert ended.value.code == 2
    err = capfd.readouterr().err
    assert err.startswith(f"described: parameter sensor_config: sensor description {broken}"), err
    assert err.count("\n") == 1, err


#: A node process whose teardown hangs, as the middleware's does when Fast DDS deadlocks deleting the participant.
HANGING_TEARDOWN = """
import sys, time
from rclpy.node import Node
from tactile_conversions.node_main import run_node

class HangsOnDestroy(Node):
    def __init__(self):
        super().__init__("hangs_on_destroy")
        self.create_timer(0.05, self.started)

    def started(self):
        print("spinning", flush=True)
        if sys.argv[1] == "error":
            raise ValueError("a broken camera frame")

    def destroy_node(self):
        time.sleep(60)

run_node(HangsOnDestroy)
"""


@pytest.mark.parametrize("ending", ["ctrl-c", "error"])
def test_a_hanging_teardown_ends_the_process_after_the_timeout_with_exit_code_1_and_the_stacks(tmp_path, ending):
    script = tmp_path / "node.py"
    script.write_text(HANGING_TEARDOWN)
    process = subprocess.Popen([sys.executable, str(script), ending], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True)
    try:
        assert select.select([process.stdout], [], [], 60.0)[0], "the node did not start spinning"
        assert process.stdout.readline() == "spinning\n"
        interrupted = time.monotonic()
        if ending == "ctrl-c":
            process.send_signal(signal.SIGINT)
        _, stderr = process.communicate(timeout=TEARDOWN_TIMEOUT_S + 20)
    finally:
        process.kill()
        process.wait()
    assert process.returncode == 1, stderr
    if ending == "ctrl-c":  # the teardown got its time first (the SIGINT was sent before it began)
        assert time.monotonic() - interrupted > TEARDOWN_TIMEOUT_S, stderr
    timeout_line = f"Timeout ({datetime.timedelta(seconds=TEARDOWN_TIMEOUT_S)})!"  # faulthandler's own header
    assert timeout_line in stderr and "in destroy_node" in stderr  # where it hung
    assert ("ValueError: a broken camera frame" in stderr) == (ending == "error")  # the error is not lost
