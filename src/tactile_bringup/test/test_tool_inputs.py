"""tactile-demo and tactile-latency refuse a bad scene, sensor file, log directory or option before any node starts: one
line on stderr and exit status 2 (no graph starts, so these run in a second)."""

from pathlib import Path

import pytest

from tactile_bringup import demo, latency

TOOLS = {"tactile-demo": demo.main, "tactile-latency": latency.main}


def refused(capsys, program: str, args: list[str]) -> str:
    """Run the tool's main in this process; it must end with status 2 and one line on stderr, which is returned."""
    assert TOOLS[program](args) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"{program}: error: "), err
    return err


def usage_error(capsys, main, args: list[str]) -> str:
    """Run a tool's main with `args` that its argument parser refuses: status 2; stderr, which is returned."""
    with pytest.raises(SystemExit) as stop:
        main(args)
    assert stop.value.code == 2
    return capsys.readouterr().err


@pytest.mark.parametrize("program", sorted(TOOLS))
def test_an_unknown_scene_is_refused_before_the_log_directory_is_made(program, capsys, tmp_path):
    logs = tmp_path / "logs"
    err = refused(capsys, program, ["--scene", "nonexistent_scene", "--log-dir", str(logs)])
    assert "no scene file 'nonexistent_scene'" in err and "installed scenes are" in err
    assert not logs.exists()


@pytest.mark.parametrize("program", sorted(TOOLS))
def test_a_scene_the_sensor_cannot_play_is_refused(program, capsys, tmp_path):
    scene = tmp_path / "deep.yaml"
    scene.write_text("{name: deep, seed: 1, timeline: [{press: {x_mm: 24, y_mm: 25, depths_mm: [5]}}]}")
    err = refused(capsys, program, ["--scene", str(scene), "--log-dir", str(tmp_path / "logs")])
    assert f"{scene}.timeline[0].press: a press 5 mm deep is deeper than" in err


@pytest.mark.parametrize("program", sorted(TOOLS))
def test_a_sensor_file_that_is_not_text_is_refused_naming_it(program, capsys, tmp_path):
    sensor = tmp_path / "binary.yaml"
    sensor.write_bytes(bytes(range(128, 256)) + bytes(72))
    err = refused(capsys, program, ["--sensor", str(sensor), "--log-dir", str(tmp_path / "logs")])
    assert f"sensor description {sensor} is not UTF-8 text" in err


@pytest.mark.parametrize("program", sorted(TOOLS))
def test_a_log_directory_that_cannot_be_made_is_refused(program, capsys, tmp_path):
    afile = tmp_path / "afile"
    afile.write_text("")
    # /proc is a directory that takes no file: a traceback when the first node's log was opened (found in review)
    for log_dir, why in ((afile, "File exists"), (afile / "x", "Not a directory"),
                         (Path("/proc"), "No such file or directory")):
        err = refused(capsys, program, ["--duration" if program == "tactile-demo" else "--window", "1",
                                        "--log-dir", str(log_dir)])
        assert f"--log-dir {log_dir}: cannot make it a directory for the nodes' logs ({why})" in err


@pytest.mark.parametrize("rate", ["5000", "1e-6", "0"])
def test_latency_refuses_a_markers_rate_the_fusion_node_would_refuse(capsys, tmp_path, rate):
    """--markers-rate 5000 passed, and the graph stopped after its start with the fusion node's error about
    markers_rate_hz and publish_markers, neither an option of the tool (review)."""
    err = usage_error(capsys, latency.main, ["--markers-rate", rate, "--log-dir", str(tmp_path / "logs")])
    assert f"argument --markers-rate: must be a finite number of Hz in [1.15741e-05, 1000], got '{rate}'" in err
    assert not (tmp_path / "logs").exists()


@pytest.mark.parametrize("namespace", ["1st", "left arm", "robot//left"])
def test_demo_refuses_a_namespace_ros_would_refuse_before_any_node_starts(capsys, tmp_path, namespace):
    err = usage_error(capsys, demo.main, ["--namespace", namespace, "--log-dir", str(tmp_path / "logs")])
    assert f"argument --namespace: namespace '{namespace}': not a ROS namespace (namespace must not" in err
    assert not (tmp_path / "logs").exists()
