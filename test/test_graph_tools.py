"""`tactile-demo` under signals and failures while its graph runs: real node processes over Fast DDS."""

import json
import os
import signal
import subprocess
import threading
import time

import pytest
import yaml

pytestmark = pytest.mark.system


#: How long `running_demo` waits for the demo's first estimate (its graph starts in seconds; 120 s is its duration).
FIRST_ESTIMATE_TIMEOUT_S = 60.0


@pytest.fixture
def running_demo(ros_domain, graph_tools, tmp_path):
    """A `tactile-demo` (GraphTools), once it has printed an estimate; the test fails if none comes within
    FIRST_ESTIMATE_TIMEOUT_S (a demo that stalls would otherwise hold the test for its whole duration)."""
    process = graph_tools.start(["tactile-demo", "--duration", "120", "--log-dir", str(tmp_path)])
    estimated = threading.Event()

    def read_until_estimate() -> None:  # stops reading once it is seen: finish() reads the rest
        for line in process.stdout:  # one line a second: "  3.0 s    41 estimates  total Fz ..."
            if "estimates" in line and int(line.split()[2]) > 0:
                estimated.set()
                return

    reader = threading.Thread(target=read_until_estimate, daemon=True)
    reader.start()
    reader.join(FIRST_ESTIMATE_TIMEOUT_S)
    if estimated.is_set():
        return process
    if reader.is_alive():  # stalled: end the demo's whole group (its session), then say what it printed
        os.killpg(process.pid, signal.SIGKILL)
        reader.join(10.0)
        pytest.fail(f"no estimate from tactile-demo within {FIRST_ESTIMATE_TIMEOUT_S:g} s (killed): "
                    + process.stderr.read())
    pytest.fail("tactile-demo ended before its first estimate: " + process.stderr.read())


def finish(graph_tools, process: subprocess.Popen) -> tuple[dict, str]:
    """Wait for the demo (its nodes must be gone with it); (its JSON summary, its stderr)."""
    result = graph_tools.finish(process, 60)
    return json.loads(result.stdout[result.stdout.index("{"):]), result.stderr


def test_sigterm_ends_the_demo_with_its_summary_and_a_clean_graph(graph_tools, running_demo):
    running_demo.send_signal(signal.SIGTERM)
    summary, stderr = finish(graph_tools, running_demo)
    assert "Traceback" not in stderr, stderr
    assert running_demo.returncode == 0, stderr
    assert summary["estimates"] > 0 and set(summary["exit_codes"].values()) == {0}, summary


def test_a_node_that_dies_while_the_demo_runs_fails_it(graph_tools, running_demo):
    bundle_nodes = subprocess.run(["pgrep", "-s", str(running_demo.pid), "-f", "bundle_node"], capture_output=True,
                                  text=True, check=True).stdout.split()
    assert len(bundle_nodes) == 1
    os.kill(int(bundle_nodes[0]), signal.SIGKILL)
    summary, stderr = finish(graph_tools, running_demo)
    assert running_demo.returncode == 1
    assert "node tactile_bundle exited" in stderr and "tactile_bundle exited early" in stderr, stderr
    assert summary["exit_codes"]["tactile_bundle"] == -signal.SIGKILL, summary


def test_sigterm_while_the_graph_starts_ends_the_demo_without_a_traceback_or_a_node_left(ros_domain, graph_tools,
                                                                                         tmp_path):
    """The fusion node loads its model for seconds while the demo waits for it (start_graph): a SIGTERM then must
    stop the nodes started so far and end the demo with a line, not a traceback."""
    process = graph_tools.start(["tactile-demo", "--duration", "60", "--log-dir", str(tmp_path)])
    fusion_log = tmp_path / "tactile_fusion.log"
    deadline = time.monotonic() + 60.0
    while not fusion_log.exists() and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.02)
    assert fusion_log.exists(), "the demo never started its fusion node"
    process.send_signal(signal.SIGTERM)
    result = graph_tools.finish(process, 60)  # fails the test if a node of the demo's group is left
    assert "Traceback" not in result.stderr, result.stderr
    assert result.returncode == 1 and "stopped while the graph was starting" in result.stderr, result.stderr
    assert not (tmp_path / "tactile_sim_cameras.log").exists()  # the cameras were never started


@pytest.mark.parametrize("duration", ["0", "nan"])
def test_the_demo_refuses_a_duration_that_would_end_at_once_or_never(duration, tmp_path):
    run = subprocess.run(["tactile-demo", "--duration", duration, "--log-dir", str(tmp_path)], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 2, run.stderr
    assert f"argument --duration: must be a finite number of seconds > 0, got '{duration}'" in run.stderr


@pytest.mark.parametrize("segment, refusal", [
    ({"contacts": {"contacts": [{"x_mm": 20, "y_mm": 20, "depth_mm": 1.0}, {"x_mm": 22, "y_mm": 20, "depth_mm": 1.0}]}},
     "contacts[0] and contacts[1] overlap: 2 mm apart"),
    ({"random_presses": {"frames": 10, "contacts_per_frame": 4, "min_separation_mm": 45.0, "depth_mm": [0.3, 0.5]}},
     "found room for only"),
], ids=["overlapping-contacts", "no-room-for-random-presses"])
def test_the_demo_refuses_a_scene_the_simulated_cameras_cannot_play_before_it_starts_a_node(tmp_path, segment,
                                                                                             refusal):
    """Contacts the simulated camera node's ground-truth model would count twice, or random presses that find no room
    for their separation: the node refused them only once the graph had started, and the demo ended with status 1
    and a summary of 0 estimates (found in review)."""
    scene = tmp_path / "scene.yaml"
    scene.write_text(yaml.safe_dump({"name": "refused", "seed": 1, "timeline": [{"rest": {"frames": 3}}, segment]}))
    run = subprocess.run(["tactile-demo", "--scene", str(scene), "--log-dir", str(tmp_path / "logs")],
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2, run.stderr
    assert refusal in run.stderr, run.stderr
    assert len(run.stderr.splitlines()) == 1 and not list((tmp_path / "logs").glob("*.log"))
