"""Spinning a node until something has happened, for the command-line tools and the tests that run nodes."""

from __future__ import annotations

import time
from collections.abc import Callable

import rclpy
from rclpy.node import Node


def spin_until(node: Node, condition: Callable[[], object], timeout_s: float) -> bool:
    """Spin `node` until `condition()` is true (then True) or for `timeout_s` (then False)."""
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() >= deadline:
            return False
        rclpy.spin_once(node, timeout_sec=0.05)
    return True
