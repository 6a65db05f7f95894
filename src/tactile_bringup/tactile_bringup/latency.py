"""`tactile-latency`: how long the live graph takes from a camera capture to the force estimate, as JSON.

Runs the sensor graph on the simulated sensor (the nodes `tactile-demo` starts), waits for its first estimate and
`--settle` seconds more, then measures `--windows` windows of `--window` seconds each. A message's latency is its
arrival in this process minus its capture stamp (the bundle's stamp, the median of its cameras' stamps, which the
estimate keeps): for the bundles on /tactile/image_bundle (cameras and synchronisation) and for the estimates on
/tactile/force_distribution (plus inference and publication). Per window the median and the 90th percentile over
its messages; reported are their medians over the windows and the range of the window medians. Exits 1 when a
window got no estimate or a node failed (a node that exits ends the wait and the measurement at once); 2, before
any node starts, when the sensor, scene or model is refused or the log directory cannot be made.

The probe's own subscription to the 64 KB bundles is one more reader for the bundle node; without it, bundles
would leave that node a little sooner.

The baseline, measured in the same run before the graph starts: one predict() of the fusion node's model, backend,
precision and thread count in this process (median of 300 calls), i.e. the inference alone. `ratio_to_inference`
says how much the graph around the network costs.
"""

from __future__ import annotations

import json
import statistics
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import rclpy
from rclpy.node import Node

from tactile_bringup.graph import NodeSpec, sensor_graph
from tactile_bringup.processes import (
    LogDirError,
    check_tool_inputs,
    first_exited,
    report_exited,
    spin_until,
    start_tool_graph,
    stop_nodes,
)
from tactile_conversions.parameters import MAX_RATE_HZ, MIN_RATE_HZ
from tactile_conversions.ros_time import time_to_seconds
from tactile_conversions.stop_signals import init_ros, until_stop_signal
from tactile_conversions.topics import BUNDLE_TOPIC, ESTIMATE_TOPIC
from tactile_description import SensorConfigError, default_sensor_path
from tactile_description.command_line import (
    ArgumentParser,
    error_exit,
    number_argument,
    stops_quietly_on_closed_pipe,
    whole_number_argument,
)
from tactile_fusion.artifacts import ModelFileError
from tactile_fusion.bench import call_times_s, synthetic_frame
from tactile_fusion.fusion_node import MARKERS_RATE_HZ
from tactile_fusion.inference import BACKENDS, PRECISIONS, check_backend, load_predictor
from tactile_msgs.msg import ForceDistribution, ImageBundle
from tactile_sim import SceneError

#: The fusion node's intra-op threads here, in the graph and in the baseline.
FUSION_THREADS = 1
BASELINE_CALLS = 300
#: How long the cameras may take to start and the fusion node to take its reference frames.
FIRST_ESTIMATE_TIMEOUT_S = 60.0


class LatencyProbe(Node):
    """Records, per topic, the latency of every message received since the last `take()`."""

    def __init__(self) -> None:
        super().__init__("tactile_latency_probe")
        self.latencies_s: dict[str, list[float]] = {BUNDLE_TOPIC: [], ESTIMATE_TOPIC: []}
        self.create_subscription(ImageBundle, BUNDLE_TOPIC, lambda m: self.record(BUNDLE_TOPIC, m), 50)
        self.create_subscription(ForceDistribution, ESTIMATE_TOPIC, lambda m: self.record(ESTIMATE_TOPIC, m), 50)

    def record(self, topic: str, msg) -> None:
        now_s = self.get_clock().now().nanoseconds * 1e-9
        self.latencies_s[topic].append(now_s - time_to_seconds(msg.header.stamp))

    def take(self) -> dict[str, list[float]]:
        taken = {topic: list(values) for topic, values in self.latencies_s.items()}
        for values in self.latencies_s.values():
            values.clear()
        return taken


def measured_spec(spec: NodeSpec, markers_rate_hz: float) -> NodeSpec:
    """The graph's node as measured here: simulated cameras stamp the capture time itself (no stamp jitter, which
    would move the bundle stamps up to 2 ms after the capture), the fusion node runs the baseline's threads and
    publishes RViz markers `markers_rate_hz` times a second."""
    if spec.executable == "sim_camera_node":
        return replace(spec, parameters={**spec.parameters, "stamp_jitter_s": 0.0})
    if spec.executable == "fusion_node":
        return replace(spec, parameters={**spec.parameters, "threads": FUSION_THREADS,
                                         "markers_rate_hz": markers_rate_hz})
    return spec


def summarise(windows: list[dict[str, list[float]]], topic: str) -> dict:
    """Per window the median and 90th percentile latency of `topic` (None for a window without messages), and
    their medians over the windows, in milliseconds."""
    latencies = [window[topic] for window in windows]
    medians = [1e3 * float(np.median(v)) if v else None for v in latencies]
    p90s = [1e3 * float(np.percentile(v, 90)) if v else None for v in latencies]
    valid_medians, valid_p90s = [m for m in medians if m is not None], [p for p in p90s if p is not None]
    return {"median_ms": statistics.median(valid_medians) if valid_medians else None,
            "range_ms": [min(valid_medians), max(valid_medians)] if valid_medians else None,
            "p90_ms": statistics.median(valid_p90s) if valid_p90s else None,
            "windows_ms": medians, "windows_p90_ms": p90s}


def inference_ms(model_dir: str, backend: str, precision: str) -> float:
    """Median time of one predict() of a frame of all the model's cameras, as the fusion node runs it."""
    predictor = load_predictor(model_dir or None, backend, precision, FUSION_THREADS)
    images, reference = synthetic_frame(len(predictor.camera_ids), predictor.image_size)
    call_times_s(predictor, images, reference, 30)
    return 1e3 * statistics.median(call_times_s(predictor, images, reference, BASELINE_CALLS))


@stops_quietly_on_closed_pipe
def main(argv: list[str] | None = None) -> int:
    parser = ArgumentParser(prog="tactile-latency", description=__doc__.split("\n\n")[0])
    parser.add_argument("--windows", type=whole_number_argument(1, "windows"), default=5,
                        help="measurement windows (default %(default)s)")
    parser.add_argument("--window", type=number_argument(0.0, "seconds"), default=4.0,
                        help="seconds per window (default %(default)s)")
    parser.add_argument("--settle", type=number_argument(0.0, "seconds", inclusive=True), default=3.0,
                        help="seconds between the first estimate and the first window (default %(default)s)")
    parser.add_argument("--scene", default="demo", help="simulator scene name or YAML file (default: demo)")
    parser.add_argument("--sensor", default="", help="sensor description YAML (default: the installed one)")
    parser.add_argument("--model", default="", help="trained model directory (default: the shipped model)")
    parser.add_argument("--backend", choices=list(BACKENDS), default="onnxruntime")
    parser.add_argument("--precision", choices=PRECISIONS, default="fp32")
    # The fusion node's own bounds (parameters.rate_hz): a rate beyond them passed here and stopped the graph after its
    # start, its error naming a parameter the tool has not (review).
    parser.add_argument("--markers-rate", type=number_argument(MIN_RATE_HZ, "Hz", inclusive=True, high=MAX_RATE_HZ),
                        default=MARKERS_RATE_HZ,
                        help="RViz marker arrays per second from the fusion node (default %(default)s; the cameras' "
                             "frame rate or more: one with every estimate)")
    parser.add_argument("--log-dir", default="log/latency", help="where the nodes' output goes (default %(default)s)")
    args = parser.parse_args(argv)
    try:
        check_backend(args.backend, args.precision)
    except ValueError as exc:
        parser.error(str(exc))

    sensor_config = args.sensor or str(default_sensor_path())
    log_dir = Path(args.log_dir)
    try:
        sensor = check_tool_inputs(sensor_config, args.scene, log_dir)  # first: the baseline takes seconds
        baseline_ms = inference_ms(args.model, args.backend, args.precision)
    except (SensorConfigError, SceneError, LogDirError, ModelFileError) as exc:
        return error_exit("tactile-latency", exc)
    nodes = sensor_graph(sensor, sensor_config, "sim", args.scene, model_dir=args.model, backend=args.backend,
                         precision=args.precision)
    graph = [measured_spec(spec, args.markers_rate) for spec in nodes]
    init_ros()
    probe = LatencyProbe()
    windows = []
    started = start_tool_graph("tactile-latency", graph, log_dir, probe)
    if isinstance(started, int):
        return started
    specs, processes = started

    def exited() -> bool:  # every wait ends at once when a node exits: no estimate or window could follow
        return first_exited(specs, processes) is not None

    try:
        with until_stop_signal():  # Ctrl-C, or SIGTERM (rclpy shuts the context down): the summary all the same
            if not spin_until(probe, lambda: probe.latencies_s[ESTIMATE_TOPIC] or exited(), FIRST_ESTIMATE_TIMEOUT_S):
                print(f"tactile-latency: no estimate within {FIRST_ESTIMATE_TIMEOUT_S:.0f} s of the cameras' start",
                      file=sys.stderr)
            elif not exited():
                spin_until(probe, exited, args.settle)
                probe.take()
                for _ in range(args.windows):
                    if spin_until(probe, exited, args.window):
                        break
                    windows.append(probe.take())
            died = first_exited(specs, processes)
            if died:
                report_exited("tactile-latency", died, log_dir)
    finally:
        codes = stop_nodes(processes)
        probe.destroy_node()
        rclpy.try_shutdown()

    estimate = summarise(windows, ESTIMATE_TOPIC)
    report = {
        "estimate_latency": estimate,
        "bundle_latency": summarise(windows, BUNDLE_TOPIC),
        "estimates_per_window": [len(w[ESTIMATE_TOPIC]) for w in windows],
        "baseline": "inference_ms",
        "inference_ms": baseline_ms,
        "ratio_to_inference": estimate["median_ms"] / baseline_ms if estimate["median_ms"] is not None else None,
        "backend": args.backend, "precision": args.precision, "threads": FUSION_THREADS,
        "markers_rate_hz": args.markers_rate, "window_s": args.window, "scene": args.scene,
        "statistic": "per window the median (and 90th percentile) over its messages of arrival here minus capture "
                     "stamp; then the median over the windows",
        "exit_codes": {spec.name: code for spec, code in zip(specs, codes, strict=True)},
    }
    print(json.dumps(report))
    if len(windows) < args.windows or not all(report["estimates_per_window"]) or any(codes):
        print(f"tactile-latency: a window missing or without estimates, or a node failed; node logs in {args.log_dir}/",
              file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
