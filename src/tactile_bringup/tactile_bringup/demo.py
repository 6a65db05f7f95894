"""`tactile-demo`: run the sensor graph on the simulated sensor and watch the estimate against ground truth.

Starts the nodes of tactile_bringup.graph as separate processes (what `ros2 launch tactile_bringup
sensor.launch.py` starts where the launch system is installed), listens to `/tactile/force_distribution` and the
simulator's `/tactile/ground_truth/force_distribution` (under `--namespace`, where the graph runs in one), prints one
line per second, stops the graph after
`--duration` seconds and prints a summary (`--json`: one JSON object) with every node's exit code. Exits 1 when
the graph produced no estimate or an estimate that breaks the message contract, or a node exited before the end
or with a non-zero code; 2, before any node starts, when an option, the sensor or scene file is refused or the log
directory cannot be made, and when a node exits while the graph starts. Ctrl-C and SIGTERM end the run early, with the
summary.
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from collections import deque
from pathlib import Path

import numpy as np
import rclpy
from rclpy.node import Node

from tactile_bringup.graph import sensor_graph
from tactile_bringup.processes import (
    LogDirError,
    check_tool_inputs,
    first_exited,
    report_exited,
    start_tool_graph,
    stop_nodes,
)
from tactile_conversions.forces import components_problem, forces_from_msg
from tactile_conversions.ros_time import time_to_seconds
from tactile_conversions.stop_signals import init_ros, until_stop_signal
from tactile_conversions.topics import (
    ESTIMATE_TOPIC,
    GROUND_TRUTH_TOPIC,
    MATCH_TOLERANCE_S,
    ROOT_NAMESPACE,
    namespace_argument,
    node_topic,
)
from tactile_description import BinGrid, SensorConfigError, default_sensor_path
from tactile_description.command_line import ArgumentParser, error_exit, number_argument, stops_quietly_on_closed_pipe
from tactile_fusion.metrics import force_metrics
from tactile_msgs.msg import ForceDistribution
from tactile_sim import SceneError


class Monitor(Node):
    """Collects estimates and matches each to the ground truth of the same capture time, of the graph in `namespace`
    (the monitor is a node there)."""

    def __init__(self, grid: BinGrid, namespace: str = ROOT_NAMESPACE) -> None:
        super().__init__("tactile_demo_monitor", namespace=namespace)
        self.grid = grid
        self.truths: deque[tuple[float, np.ndarray]] = deque(maxlen=200)
        self.latencies_s: list[float] = []
        self.arrivals_s: list[float] = []
        self.matched: list[tuple[np.ndarray, np.ndarray]] = []  # (estimate, truth), each (rows, cols, 3)
        self.violations: list[str] = []
        self.missing_cameras: set[str] = set()
        self.estimated_components: set[tuple[str, ...]] = set()
        self.last: tuple[float, float] | None = None  # (estimated Fz, true Fz)
        self.create_subscription(ForceDistribution, node_topic(ESTIMATE_TOPIC), self.on_estimate, 50)
        self.create_subscription(ForceDistribution, node_topic(GROUND_TRUTH_TOPIC), self.on_truth, 50)

    def on_truth(self, msg: ForceDistribution) -> None:
        try:  # a message of another grid ended the demo with numpy's reshape error (code review)
            truth = forces_from_msg(msg, self.grid)
        except ValueError as exc:
            self.violations.append(f"ground truth: {exc}")
            return
        problem = components_problem(truth, msg.estimated_components)
        if problem:
            self.violations.append(f"ground truth: {problem}")
        self.truths.append((time_to_seconds(msg.header.stamp), truth))

    def on_estimate(self, msg: ForceDistribution) -> None:
        now_s = self.get_clock().now().nanoseconds * 1e-9
        stamp_s = time_to_seconds(msg.header.stamp)
        self.arrivals_s.append(now_s)
        self.latencies_s.append(now_s - stamp_s)
        self.missing_cameras.update(msg.missing_camera_ids)
        try:
            estimate = forces_from_msg(msg, self.grid)
        except ValueError as exc:
            self.violations.append(str(exc))
            return
        self.estimated_components.add(tuple(msg.estimated_components))
        problem = components_problem(estimate, msg.estimated_components)
        if problem:
            self.violations.append(problem)
        total = np.array([msg.total_force_n.x, msg.total_force_n.y, msg.total_force_n.z])
        if not np.allclose(total, estimate.sum(axis=(0, 1)), atol=1e-4):
            self.violations.append("total_force_n is not the sum of the bins")
        if not self.truths:
            return
        truth_stamp, truth = min(self.truths, key=lambda t: abs(t[0] - stamp_s))
        if abs(truth_stamp - stamp_s) <= MATCH_TOLERANCE_S:
            self.matched.append((estimate, truth))
            self.last = (float(estimate[..., 2].sum()), float(truth[..., 2].sum()))

    def rate_hz(self) -> float:
        """Estimates a second over the span of their arrivals. One over the median interval between arrivals, as it
        was, counted a burst of estimates delivered together as a high rate: 141.8 Hz from cameras at 35 Hz on a loaded
        machine (found in review)."""
        if len(self.arrivals_s) < 2 or self.arrivals_s[-1] <= self.arrivals_s[0]:
            return 0.0
        return (len(self.arrivals_s) - 1) / (self.arrivals_s[-1] - self.arrivals_s[0])

    def summary(self, duration_s: float) -> dict:
        metrics = force_metrics(*map(np.stack, zip(*self.matched, strict=True))) if self.matched else {}
        return {
            "duration_s": duration_s,
            "estimates": len(self.arrivals_s),
            "rate_hz": self.rate_hz(),
            "latency_ms_median": 1e3 * statistics.median(self.latencies_s) if self.latencies_s else None,
            "matched_with_ground_truth": len(self.matched),
            "rmse_bin_n": metrics.get("rmse_bin_n"),
            "rmse_total_n": metrics.get("rmse_total_n"),
            "missing_camera_ids": sorted(self.missing_cameras),
            "estimated_components": [list(c) for c in sorted(self.estimated_components)],
            "contract_violations": self.violations[:10],
        }


@stops_quietly_on_closed_pipe
def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog="tactile-demo", description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=number_argument(0.0, "seconds"), default=20.0,
                        help="seconds to run the graph (default 20)")
    parser.add_argument("--scene", default="demo", help="simulator scene name or YAML file (default: demo)")
    parser.add_argument("--sensor", default="", help="sensor description YAML (default: the installed one)")
    parser.add_argument("--model", default="", help="trained model directory (default: the shipped model)")
    parser.add_argument("--log-dir", default="log/demo", help="where the nodes' output goes (default log/demo)")
    parser.add_argument("--namespace", type=namespace_argument, default="/",
                        help="ROS namespace of the graph (e.g. left: its estimate on /left/tactile/force_distribution; "
                             "default: the root namespace)")
    parser.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    args = parser.parse_args(argv)

    sensor_config = args.sensor or str(default_sensor_path())
    log_dir = Path(args.log_dir)
    try:
        sensor = check_tool_inputs(sensor_config, args.scene, log_dir)
    except (SensorConfigError, SceneError, LogDirError) as exc:
        return error_exit("tactile-demo", exc)
    init_ros()
    monitor = Monitor(sensor.grid, args.namespace)
    graph = start_tool_graph("tactile-demo", sensor_graph(sensor, sensor_config, "sim", args.scene,
                                                          model_dir=args.model, namespace=args.namespace), log_dir,
                             monitor)
    if isinstance(graph, int):
        return graph
    specs, processes = graph
    started = time.monotonic()
    next_report = started + 1.0
    died = None  # the first node that exited while the graph ran
    try:
        with until_stop_signal():  # Ctrl-C, or SIGTERM (rclpy shuts the context down): the summary all the same
            while time.monotonic() - started < args.duration:
                rclpy.spin_once(monitor, timeout_sec=0.05)
                died = first_exited(specs, processes)
                if died:
                    report_exited("tactile-demo", died, log_dir)
                    break
                if time.monotonic() >= next_report and not args.json:
                    next_report += 1.0
                    line = f"{time.monotonic() - started:5.1f} s  {len(monitor.arrivals_s):5d} estimates"
                    if monitor.last:
                        line += f"  total Fz estimated {monitor.last[0]:6.3f} N, true {monitor.last[1]:6.3f} N"
                    print(line, flush=True)
    finally:
        ran_s = time.monotonic() - started  # the graph's run, not the nodes' shutdown: 9.02 s for --duration 8
        codes = stop_nodes(processes)
        summary = monitor.summary(ran_s)
        monitor.destroy_node()
        rclpy.try_shutdown()
    summary["exit_codes"] = {spec.name: code for spec, code in zip(specs, codes, strict=True)}
    print(json.dumps(summary) if args.json else json.dumps(summary, indent=2))
    if not summary["estimates"] or summary["contract_violations"] or died or any(codes):
        print(f"tactile-demo: the graph produced {summary['estimates']} estimate(s), violations "
              f"{summary['contract_violations']}, node exit codes {summary['exit_codes']}"
              f"{f', {died.name} exited early' if died else ''}; node logs in {log_dir}/", file=sys.stderr)
        return 1
    return 0

if __name__ == "__main__":
    sys.exit(main())
