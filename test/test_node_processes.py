"""start_node / stop_nodes on real processes: a node that is asked for its stacks, a node that inherited Ctrl-C
ignored, a process that will not stop."""

import os
import signal
import subprocess
import sys
import threading
import time

import pytest

from tactile_bringup.graph import NodeSpec
from tactile_bringup.processes import SIGINT_REPEAT_S, start_node, stop_nodes
from tactile_description import default_sensor_path

pytestmark = pytest.mark.system
STACK_HEADER = "most recent call first"


def wait_for_text(path, text: str, timeout_s: float) -> str:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        content = path.read_text() if path.exists() else ""
        if text in content:
            return content
        time.sleep(0.05)
    return path.read_text()


def test_a_node_prints_its_stacks_on_sigusr1_and_keeps_running(ros_probe, tmp_path):
    spec = NodeSpec("tactile_fusion", "bundle_node", "bundle", {"sensor_config": str(default_sensor_path())})
    process = start_node(spec, tmp_path)
    try:
        log = wait_for_text(tmp_path / "bundle.log", "bundling cameras", timeout_s=30.0)
        assert "bundling cameras" in log, log
        process.send_signal(signal.SIGUSR1)
        log = wait_for_text(tmp_path / "bundle.log", "in <module>", timeout_s=10.0)  # the stack's last line
        assert STACK_HEADER in log and "in run_node" in log, log
        time.sleep(0.3)
        assert process.poll() is None, log
    finally:
        codes = stop_nodes([process])
    assert codes == [0], (tmp_path / "bundle.log").read_text()


def test_a_node_that_inherited_ctrl_c_ignored_and_missed_the_first_one_still_stops(ros_domain, tmp_path):
    # What a background job of a non-interactive shell inherits; a SIGINT then, during the node's imports (before
    # rclpy.init), is lost. stop_nodes interrupts at once, well within the imports, so only a repeat can stop it.
    spec = NodeSpec("tactile_fusion", "bundle_node", "bundle", {"sensor_config": str(default_sensor_path())})
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        process = start_node(spec, tmp_path)
    finally:
        signal.signal(signal.SIGINT, previous)
    started = time.monotonic()
    codes = stop_nodes([process], timeout_s=30.0)
    assert codes == [0], (tmp_path / "bundle.log").read_text()
    assert time.monotonic() - started >= SIGINT_REPEAT_S  # the first SIGINT was lost indeed; a repeat stopped it


def test_a_process_that_ignores_ctrl_c_is_killed_with_its_stacks_in_its_log(tmp_path):
    stubborn = ("import faulthandler, signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN); "
                "faulthandler.register(signal.SIGUSR1); print('ready', flush=True); time.sleep(60)")
    log_path = tmp_path / "stubborn.log"
    with open(log_path, "w") as log:
        process = subprocess.Popen([sys.executable, "-c", stubborn], stdout=log, stderr=subprocess.STDOUT)
    assert "ready" in wait_for_text(log_path, "ready", timeout_s=10.0)
    started = time.monotonic()
    assert stop_nodes([process], timeout_s=0.5) == [-signal.SIGKILL]
    assert time.monotonic() - started < 5.0
    log = log_path.read_text()
    assert STACK_HEADER in log and "in <module>" in log, log


def test_nodes_are_stopped_one_after_the_other(tmp_path):
    """A node gets its SIGINT only once the one before it has exited (Fast DDS's teardown deadlock, docs/nodes.md)."""
    slow_exit = ("import signal, sys, time\n"
                 "def stop(*_):\n"
                 "    print('interrupted', time.monotonic(), flush=True); time.sleep(0.5)\n"
                 "    print('exiting', time.monotonic(), flush=True); sys.exit(0)\n"
                 "signal.signal(signal.SIGINT, stop); print('ready', flush=True)\n"
                 "while True: time.sleep(0.01)\n")
    logs = [tmp_path / f"node{i}.log" for i in range(2)]
    processes = []
    for log_path in logs:
        with open(log_path, "w") as log:
            processes.append(subprocess.Popen([sys.executable, "-c", slow_exit], stdout=log, stderr=subprocess.STDOUT))
    for log_path in logs:
        assert "ready" in wait_for_text(log_path, "ready", timeout_s=10.0)
    assert stop_nodes(processes) == [0, 0]
    times = [{line.split()[0]: float(line.split()[1]) for line in path.read_text().splitlines()[1:]} for path in logs]
    assert times[0]["exiting"] <= times[1]["interrupted"], times


def running(pid: int) -> bool:
    """Whether process `pid` exists and is not a zombie (a container's init may never reap it)."""
    try:
        with open(f"/proc/{pid}/stat") as stat:
            return stat.read().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except FileNotFoundError:
        return False


def test_a_graph_tool_that_overruns_its_test_takes_its_nodes_with_it(run_graph_tool, tmp_path):
    """The tests' `run_graph_tool` kills the tool's whole process group, not only the tool."""
    pid_file = tmp_path / "node.pid"
    tool = ("import subprocess, sys, time\n"
            "node = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(600)'], "
            "stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)\n"
            f"open({str(pid_file)!r}, 'w').write(str(node.pid))\n"
            "time.sleep(600)\n")
    with pytest.raises(subprocess.TimeoutExpired):  # 6 s: time to start, and to write the pid, on a loaded machine
        run_graph_tool([sys.executable, "-c", tool], 6)
    node_pid = int(pid_file.read_text())
    end = time.monotonic() + 5.0
    while running(node_pid) and time.monotonic() < end:
        time.sleep(0.05)
    if running(node_pid):
        os.kill(node_pid, signal.SIGKILL)
        pytest.fail("the tool's node outlived the tool")


def test_a_ctrl_c_while_the_nodes_are_stopped_does_not_leave_the_rest_running(stop_signals_fail_the_test):
    """tactile-demo and tactile-latency stop their nodes one at a time; a second Ctrl-C (or SIGTERM) meanwhile raised
    KeyboardInterrupt out of stop_nodes, and the nodes not yet stopped ran on, adopted by init (found in review).
    Stand-ins for nodes that take a second to exit after their SIGINT."""
    slow_exit = ("import signal, sys, time\n"
                 "signal.signal(signal.SIGINT, lambda *_: (time.sleep(1.0), sys.exit(0)))\n"
                 "print('ready', flush=True)\n"
                 "time.sleep(60)\n")
    processes = [subprocess.Popen([sys.executable, "-c", slow_exit], stdout=subprocess.PIPE, text=True)
                 for _ in range(2)]
    try:
        assert [p.stdout.readline() for p in processes] == ["ready\n"] * 2  # their handlers are installed
        ctrl_c = threading.Timer(0.3, os.kill, (os.getpid(), signal.SIGINT))  # while the first one exits
        ctrl_c.start()
        codes = stop_nodes(processes)
        ctrl_c.join()
        assert codes == [0, 0]
    finally:
        for process in processes:
            process.kill()
            process.communicate()
