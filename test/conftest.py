"""Fixtures of the system tests (real processes over Fast DDS on loopback)."""

import contextlib
import os
import signal
import subprocess
import time

import pytest
import rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy


@pytest.fixture(autouse=True)
def opencv_logging_restored(monkeypatch):
    """A camera node built in this process sets OpenCV's log level and FFmpeg's (camera_node.quiet_opencv), which
    outlived the test into later ones and their child processes (review): both are put back after each test, and a
    level the shell set is not seen by the tests."""
    import cv2

    for variable in ("OPENCV_LOG_LEVEL", "OPENCV_FFMPEG_LOGLEVEL"):
        monkeypatch.delenv(variable, raising=False)
    level = cv2.utils.logging.getLogLevel()
    yield
    cv2.utils.logging.setLogLevel(level)


@pytest.fixture
def ros_domain(monkeypatch):
    """A DDS domain of this test run's own, discovery on loopback only; child processes inherit it."""
    monkeypatch.setenv("ROS_DOMAIN_ID", str(150 + os.getpid() % 80))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")


def group_alive(pgid: int) -> bool:
    try:
        os.killpg(pgid, 0)
    except ProcessLookupError:
        return False
    return True


def kill_group(pgid: int) -> None:
    with contextlib.suppress(ProcessLookupError):  # the whole group has exited already
        os.killpg(pgid, signal.SIGKILL)


class GraphTools:
    """Command-line tools that start node processes (tactile-demo, tactile-latency), each in a process group and
    session of its own, whose id is the tool's pid. Whatever of a group still runs when the test ends is killed:
    killing only the tool would leave its nodes running, and publishing, after the test."""

    def __init__(self) -> None:
        self.started: list[subprocess.Popen] = []

    def start(self, args: list[str]) -> subprocess.Popen:
        process = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                                   start_new_session=True)
        self.started.append(process)
        return process

    def finish(self, process: subprocess.Popen, timeout_s: float) -> subprocess.CompletedProcess:
        """Wait for a started tool, like subprocess.run; the test fails if the tool left processes of its group. A tool
        that overruns `timeout_s` (or a Ctrl-C meanwhile) takes its whole group with it at once."""
        try:
            stdout, stderr = process.communicate(timeout=timeout_s)
        except BaseException:
            kill_group(process.pid)
            process.communicate()
            raise
        if group_alive(process.pid):
            kill_group(process.pid)
            pytest.fail(f"{process.args[0]} exited but left processes of its group running (killed now)")
        return subprocess.CompletedProcess(process.args, process.returncode, stdout, stderr)

    def run(self, args: list[str], timeout_s: float) -> subprocess.CompletedProcess:
        return self.finish(self.start(args), timeout_s)

    def kill_all(self) -> None:
        for process in self.started:
            kill_group(process.pid)
            process.communicate()


@pytest.fixture
def graph_tools():
    tools = GraphTools()
    yield tools
    tools.kill_all()


@pytest.fixture
def run_graph_tool(graph_tools):
    """run_graph_tool(args, timeout_s): run a tool that starts node processes, like subprocess.run (GraphTools)."""
    return graph_tools.run


@pytest.fixture
def ros_probe(ros_domain):
    """A node in the test run's own DDS domain (`ros_domain`)."""
    rclpy.init()
    node = Node("system_test_probe")
    yield node
    node.destroy_node()
    rclpy.try_shutdown()


@pytest.fixture
def lossless_image_qos():
    """Best effort, as the cameras publish, with a queue of 200 (sensor-data QoS keeps 5): a test process that stalls
    for more than a few frame periods on a loaded machine loses no frame it counts (73 of 80 arrived with a 0.3 s
    stall and the queue of 5; found in an audit of the tests)."""
    return QoSProfile(depth=200, reliability=ReliabilityPolicy.BEST_EFFORT)


@pytest.fixture
def collect(ros_probe):
    """collect(msg_type, topic, seconds, qos=50, until=None): the messages `ros_probe` receives on `topic`.

    Collects for `seconds`, or less once `until(received)` is true.
    qos: a depth (reliable) or a QoS profile (qos_profile_sensor_data for the best-effort camera topics).
    """
    def collect_messages(msg_type, topic: str, seconds: float, qos=50, until=None) -> list:
        received = []
        subscription = ros_probe.create_subscription(msg_type, topic, received.append, qos)
        end = time.monotonic() + seconds
        while time.monotonic() < end and not (until and until(received)):
            rclpy.spin_once(ros_probe, timeout_sec=0.05)
        ros_probe.destroy_subscription(subscription)
        return received

    return collect_messages
