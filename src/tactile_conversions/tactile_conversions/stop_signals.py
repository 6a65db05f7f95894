"""How a Ctrl-C or SIGTERM shows up in a process that spins rclpy, for the nodes and the command-line tools alike."""

from __future__ import annotations

import contextlib
import signal
import threading

import rclpy
from rclpy.executors import ExternalShutdownException

#: Set by the SIGINT handler that `init_ros` installs; cleared by each `init_ros`.
_interrupted = threading.Event()
#: Set by `init_ros`: before it, rclpy's context is not yet valid, and that says nothing of a signal.
_started = threading.Event()


def init_ros(args: list[str] | None = None) -> None:
    """`rclpy.init`, with a Ctrl-C (SIGINT) recorded for `stopped_by_signal`: how the nodes and tools start ROS.

    rclpy's SIGINT handler passes the signal on to Python's handler, which raises KeyboardInterrupt in the main thread,
    and shuts the context down a moment later from a thread of its own. The KeyboardInterrupt can be raised inside
    Python code that rclpy's C++ calls, such as the conversion of a taken message into its Python object; pybind11
    then replaces it with a RuntimeError ("Unable to convert call argument '0' to Python object") while `rclpy.ok()`
    is still True (seen once in the suite: a bundle node stopped by the demo ended with exit code 1). The handler
    installed here raises KeyboardInterrupt as Python's does, after recording the signal."""
    _interrupted.clear()
    signal.signal(signal.SIGINT, _record_interrupt)
    rclpy.init(args=args)
    _started.set()


def _record_interrupt(signum: int, frame) -> None:
    _interrupted.set()
    raise KeyboardInterrupt


def stopped_by_signal(error: BaseException) -> bool:
    """Whether `error` is how a Ctrl-C or SIGTERM ended the spinning: KeyboardInterrupt, rclpy's
    ExternalShutdownException, or, after `init_ros`, any error raised once the signal had shut rclpy's context down or
    once a Ctrl-C had arrived. rclpy's handler shuts the context down at once, from another thread, so an rcl call
    already under way (count_publishers, publish, the timer of spin_once) then fails with "context is invalid"
    instead; a Ctrl-C can also surface as another error (`init_ros`). Before `init_ros` the context is not valid
    either, and every error passed for a stop (review)."""
    return isinstance(error, (KeyboardInterrupt, ExternalShutdownException)) or (
        isinstance(error, Exception) and _started.is_set() and (not rclpy.ok() or _interrupted.is_set()))


class StopState:
    """What `until_stop_signal` yields: `signalled` is True once a Ctrl-C or SIGTERM ended the block."""

    def __init__(self) -> None:
        self.signalled = False


@contextlib.contextmanager
def until_stop_signal():
    """Run the block until a Ctrl-C or SIGTERM stops it: that stop (`stopped_by_signal`) ends the block quietly, and
    the code after it runs (a summary, a bag's close), which can tell from the StopState yielded; any other error
    passes."""
    state = StopState()
    try:
        yield state
    except (KeyboardInterrupt, Exception) as exc:
        if not stopped_by_signal(exc):
            raise
        state.signalled = True
