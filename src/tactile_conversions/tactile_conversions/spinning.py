"""Spinning a node until something has happened, for the command-line tools and the tests that run nodes."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

import rclpy
from rclpy.node import Node


def spin_until(node: Node, condition: Callable[[], object], timeout_s: float) -> bool:
    """Spin `node` until `condition()` is true (then True) or for `timeout_s` (then False)."""
    if not (math.isfinite(timeout_s) and timeout_s >= 0):  # a NaN deadline never came (review)
        raise ValueError(f"spin_until: timeout_s must be a finite number >= 0, got {timeout_s!r}")
    deadline = time.monotonic() + timeout_s
    while not condition():
        if time.monotonic() >= deadline:
            return False
        rclpy.spin_once(node, timeout_sec=0.05)
    return True
