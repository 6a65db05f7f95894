"""Fixtures of the system tests (real processes over Fast DDS on loopback)."""

import os

import pytest
import rclpy
from rclpy.node import Node


@pytest.fixture
def ros_probe(monkeypatch):
    """A node in a DDS domain of this test run's own (child processes inherit it), discovery on loopback only."""
    monkeypatch.setenv("ROS_DOMAIN_ID", str(150 + os.getpid() % 80))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    rclpy.init()
    node = Node("system_test_probe")
    yield node
    node.destroy_node()
    rclpy.try_shutdown()
