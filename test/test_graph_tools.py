"""`tactile-demo` under signals and failures while its graph runs: real node processes over Fast DDS."""

import json
import os
import signal
import subprocess

import pytest

pytestmark = pytest.mark.system


@pytest.fixture
def running_demo(ros_domain, graph_tools, tmp_path):
    """A `tactile-demo` (GraphTools), once it has printed an estimate."""
    process = graph_tools.start(["tactile-demo", "--duration", "120", "--log-dir", str(tmp_path)])
    for line in process.stdout:  # one line a second: "  3.0 s    41 estimates  total Fz ..."
        if "estimates" in line and int(line.split()[2]) > 0:
            return process
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
