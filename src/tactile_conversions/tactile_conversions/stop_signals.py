"""How a Ctrl-C or SIGTERM shows up in a process that spins rclpy, for the nodes and the command-line tools alike."""

from __future__ import annotations

import contextlib

import rclpy
from rclpy.executors import ExternalShutdownException


def stopped_by_signal(error: BaseException) -> bool:
    """Whether `error` is how a Ctrl-C or SIGTERM ended the spinning: KeyboardInterrupt, rclpy's
    ExternalShutdownException, or any error raised once the signal had shut rclpy's context down. rclpy's handler does
    that at once, from another thread, so an rcl call already under way (count_publishers, publish, the timer of
    spin_once) then fails with "context is invalid" instead."""
    return isinstance(error, (KeyboardInterrupt, ExternalShutdownException)) or (isinstance(error, Exception)
                                                                                 and not rclpy.ok())


@contextlib.contextmanager
def until_stop_signal():
    """Run the block until a Ctrl-C or SIGTERM stops it: that stop (`stopped_by_signal`) ends the block quietly, and
    the code after it runs (a summary, a bag's close); any other error passes."""
    try:
        yield
    except (KeyboardInterrupt, Exception) as exc:
        if not stopped_by_signal(exc):
            raise
