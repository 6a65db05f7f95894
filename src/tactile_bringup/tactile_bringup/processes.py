"""Run the nodes of a graph (tactile_bringup.graph) as plain processes, where no launch system is installed."""

from __future__ import annotations

import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import rclpy
from ament_index_python.packages import get_package_prefix
from rclpy.node import Node

from tactile_bringup.graph import NodeSpec
from tactile_conversions.spinning import spin_until
from tactile_conversions.stop_signals import stopped_by_signal
from tactile_conversions.topics import ESTIMATE_TOPIC, node_topic
from tactile_description import SensorDescription, load_sensor
from tactile_description.command_line import error_exit, stop_signals_ignored
from tactile_sim.contact import ground_truth_model
from tactile_sim.scene import load_scene

#: Time a stuck node gets to write its stacks before it is killed.
STACK_DUMP_S = 1.0
#: SIGINT is sent again this often while a node has not exited (see `stop_nodes`).
SIGINT_REPEAT_S = 3.0


class LogDirError(ValueError):
    """A --log-dir that cannot be a directory (an existing file, a path under a file, ...)."""


def check_tool_inputs(sensor_config: str, scene: str, log_dir: Path) -> SensorDescription:
    """What tactile-demo and tactile-latency check before they start any node: the sensor description, the scene
    against it and the simulated camera node's ground-truth model, as that node will load them (a node that refused
    them would only say so in its log, once the graph had started), and the nodes' log directory, made here. The
    sensor description; raises SensorConfigError, SceneError or LogDirError, each with a one-line message naming the
    file."""
    sensor = load_sensor(sensor_config)
    load_scene(scene).check_playable(sensor, ground_truth_model(sensor))  # as the node's Simulator, with its model
    try:
        log_dir.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=log_dir).close()  # a directory that takes no file (/proc, read-only, not ours)
    except OSError as exc:  # FileExistsError for a file, NotADirectoryError for a path under one
        raise LogDirError(f"--log-dir {log_dir}: cannot make it a directory for the nodes' logs "
                          f"({exc.strerror or exc}); name a directory or a path to create") from exc
    return sensor


def first_exited(specs: list[NodeSpec], processes: list[subprocess.Popen]) -> NodeSpec | None:
    """The first node (in start order) whose process has exited, None while all run."""
    return next((spec for spec, process in zip(specs, processes, strict=True) if process.poll() is not None), None)


def report_exited(program: str, spec: NodeSpec, log_dir: Path) -> None:
    """Say on stderr that node `spec` exited while the tool ran, with the last line of its log."""
    print(f"{program}: node {spec.name} exited: {log_tail(log_dir, spec)}; see {log_dir}/", file=sys.stderr)


def start_node(spec: NodeSpec, log_dir: Path) -> subprocess.Popen:
    """Start one node; its output goes to `log_dir/<node name>.log`."""
    executable = Path(get_package_prefix(spec.package)) / "lib" / spec.package / spec.executable
    log_dir.mkdir(parents=True, exist_ok=True)
    with open(log_dir / f"{spec.name}.log", "w") as log:  # the child keeps its own copy of the descriptor
        return subprocess.Popen([str(executable), *spec.ros_arguments()], stdout=log, stderr=subprocess.STDOUT)


class GraphStartError(RuntimeError):
    """A node of the graph exited while the graph was starting (a bad model, scene or sensor file, ...), or could
    not be started."""


def started(spec: NodeSpec, log_dir: Path) -> subprocess.Popen:
    """start_node, with a log file that cannot be written (a directory of its name) as a GraphStartError."""
    try:
        return start_node(spec, log_dir)
    except OSError as exc:
        raise GraphStartError(f"node {spec.name} cannot be started: {exc.strerror or exc}: {exc.filename}") from exc


def wait_for_log(path: Path, text: str, timeout_s: float) -> str:
    """A node's log file (where start_node sends its output) once it holds `text`, or after `timeout_s`."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end and text not in path.read_text():
        time.sleep(0.05)
    return path.read_text()


def log_tail(log_dir: Path, spec: NodeSpec, lines: int = 1) -> str:
    """The last non-empty lines of a node's log (where start_node sent its output), "" without any."""
    try:
        text = (log_dir / f"{spec.name}.log").read_text(errors="replace")
    except OSError:
        return ""
    return "\n".join([line for line in text.splitlines() if line.strip()][-lines:])


def start_graph(specs: list[NodeSpec], log_dir: Path, probe: Node,
                timeout_s: float = 60.0) -> tuple[list[NodeSpec], list[subprocess.Popen]]:
    """Start the nodes of a sensor graph, cameras last; (the specs in start order, their processes).

    The fusion node takes its reference frames from the first bundles it sees, which must show the surface at
    rest: the cameras start only once `probe` (a node in the graph's namespace) sees it publish (it loads the model
    for a few seconds), so a scene's opening rest frames are the ones it gets. Returns after `timeout_s` without it,
    with a message. A node that exits meanwhile (it refused its model, scene or sensor file) stops the graph:
    GraphStartError names it with the last line of its log, which says why.
    """
    cameras = [s for s in specs if s.package == "tactile_camera_driver"]
    others = [s for s in specs if s not in cameras]
    estimate = node_topic(ESTIMATE_TOPIC)  # in the probe's namespace
    processes = []
    try:
        for spec in others:  # one at a time: a list built whole lost the processes before a start that failed
            processes.append(started(spec, log_dir))
        spin_until(probe, lambda: probe.count_publishers(estimate) or first_exited(others, processes),
                   timeout_s)
        died = first_exited(others, processes)
        if died:
            code = processes[others.index(died)].returncode
            raise GraphStartError(f"node {died.name} exited with status {code} while the graph started: "
                                  f"{log_tail(log_dir, died) or '(its log is empty)'} (log: {log_dir / died.name}.log)")
        if not probe.count_publishers(estimate):
            print(f"the fusion node did not come up within {timeout_s:.0f} s; see {log_dir}/", file=sys.stderr)
        for spec in cameras:
            processes.append(started(spec, log_dir))
    except BaseException:  # Ctrl-C, an error while waiting or a node that exited: leave no node behind
        stop_nodes(processes)
        raise
    return others + cameras, processes


def start_tool_graph(program: str, specs: list[NodeSpec], log_dir: Path, probe: Node
                     ) -> tuple[list[NodeSpec], list[subprocess.Popen]] | int:
    """`start_graph` for a command-line tool (tactile-demo, tactile-latency): the specs and processes, or the tool's
    exit status when the graph did not start: 2 with error_exit's line for a node that exited meanwhile
    (GraphStartError), 1 for a Ctrl-C or SIGTERM meanwhile. Then `probe` is destroyed and rclpy shut down, and no
    node is left running (start_graph stops those it started)."""
    try:
        return start_graph(specs, log_dir, probe)
    except BaseException as exc:
        if not (isinstance(exc, GraphStartError) or stopped_by_signal(exc)):
            raise
        probe.destroy_node()
        rclpy.try_shutdown()
        if isinstance(exc, GraphStartError):
            return error_exit(program, exc)
        print(f"{program}: stopped while the graph was starting", file=sys.stderr)
        return 1


def stop_nodes(processes: list[subprocess.Popen], timeout_s: float = 10.0) -> list[int]:
    """Interrupt the nodes (SIGINT, as Ctrl-C) one after the other, kill one that does not exit in time; their exit
    codes.

    One at a time: Fast DDS can deadlock while a node deletes its participant if another node is leaving at the
    same moment (docs/nodes.md; the node then ends itself with exit code 1 after TEARDOWN_TIMEOUT_S). Stopped in
    turn, a node has seen the others leave before its own teardown begins. That holds only where this function
    sends the first signal: a Ctrl-C in the terminal reaches every node of the foreground process group at once.

    SIGINT is repeated every `SIGINT_REPEAT_S` while the node runs: a node started with SIGINT ignored (what a
    background job of a non-interactive shell inherits) loses a SIGINT that arrives before its imports begin
    (Python's start and its console script's lookup; tactile_description.commands handles the imports themselves),
    and would otherwise spin until killed. A node still running
    `timeout_s` after its first SIGINT (the timeout is per node) gets SIGUSR1, which makes it print its threads'
    stacks into its log (tactile_conversions.node_main), so that the log says where it was stuck, and is then
    killed.
    """
    # A second Ctrl-C or a SIGTERM meanwhile would end the caller with the rest of the nodes still running (found
    # in review): the stop is under way anyway.
    with stop_signals_ignored():
        for process in processes:
            _stop_node(process, timeout_s)
    return [process.returncode for process in processes]


def _stop_node(process: subprocess.Popen, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while process.poll() is None and time.monotonic() < deadline:
        process.send_signal(signal.SIGINT)
        repeat_at = min(time.monotonic() + SIGINT_REPEAT_S, deadline)
        while process.poll() is None and time.monotonic() < repeat_at:
            time.sleep(0.02)
    if process.poll() is None:
        process.send_signal(signal.SIGUSR1)
        time.sleep(STACK_DUMP_S)
        process.kill()
        process.wait()
