"""System test of `tactile-latency`: the whole simulated graph as real processes, measured from outside."""

import json
import os
import signal
import subprocess
import time

import pytest

pytestmark = pytest.mark.system


def test_latency_reports_each_window_against_the_inference_baseline(ros_domain, run_graph_tool, tmp_path):
    # Markers with every estimate (40 Hz cameras): the graph must still deliver every window.
    run = run_graph_tool(["tactile-latency", "--windows", "2", "--window", "2", "--settle", "1", "--markers-rate",
                          "40", "--log-dir", str(tmp_path)], 300)
    logs = "\n".join(p.read_text() for p in tmp_path.glob("*.log"))
    assert run.returncode == 0, run.stderr + logs
    report = json.loads(run.stdout.strip().splitlines()[-1])
    assert set(report["exit_codes"].values()) == {0}
    assert len(report["estimate_latency"]["windows_ms"]) == 2 and all(report["estimates_per_window"])
    estimate, bundle = report["estimate_latency"]["median_ms"], report["bundle_latency"]["median_ms"]
    # An estimate carries its bundle's capture stamp and leaves after the bundle arrived and went through the model.
    assert 0 < bundle < estimate <= report["estimate_latency"]["p90_ms"]
    assert report["inference_ms"] > 0 and report["markers_rate_hz"] == 40
    assert report["ratio_to_inference"] == pytest.approx(estimate / report["inference_ms"])


def test_latency_rejects_a_bad_window_or_precision(tmp_path):
    run = subprocess.run(["tactile-latency", "--window", "0", "--log-dir", str(tmp_path)], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 2 and "argument --window: must be a finite number of seconds > 0, got '0'" in run.stderr
    for option in ("--markers-rate", "--settle"):
        run = subprocess.run(["tactile-latency", option, "nan", "--log-dir", str(tmp_path)], capture_output=True,
                             text=True, timeout=60)
        assert run.returncode == 2 and f"argument {option}: must be a finite number of" in run.stderr, run.stderr
    run = subprocess.run(["tactile-latency", "--backend", "torch", "--precision", "int8", "--log-dir", str(tmp_path)],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and "the torch backend runs fp32, fp16, not 'int8'" in run.stderr, run.stderr


def test_latency_refuses_a_model_directory_without_a_model(tmp_path):
    run = subprocess.run(["tactile-latency", "--model", str(tmp_path), "--log-dir", str(tmp_path)],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2 and run.stderr.startswith("tactile-latency: error: no model in"), run.stderr


def test_a_node_that_exits_ends_the_measurement_at_once(ros_domain, graph_tools, tmp_path):
    """Not the 60 s wait for a first estimate, nor the 100 windows asked for: the bundle node's exit ends the run."""
    process = graph_tools.start(["tactile-latency", "--windows", "100", "--window", "1", "--log-dir", str(tmp_path)])

    def nodes(name: str) -> list[str]:
        found = subprocess.run(["pgrep", "-s", str(process.pid), "-f", name], capture_output=True, text=True)
        return found.stdout.split()

    deadline = time.monotonic() + 120.0
    while not nodes("sim_camera_node"):  # the cameras start last, once the fusion node publishes
        assert process.poll() is None and time.monotonic() < deadline, "the graph did not start"
        time.sleep(0.2)
    (bundle_node,) = nodes("bundle_node")
    os.kill(int(bundle_node), signal.SIGKILL)
    killed = time.monotonic()
    run = graph_tools.finish(process, 50)
    assert time.monotonic() - killed < 30.0
    assert run.returncode == 1 and "tactile-latency: node tactile_bundle exited" in run.stderr, run.stderr
    assert json.loads(run.stdout.strip().splitlines()[-1])["exit_codes"]["tactile_bundle"] == -signal.SIGKILL
