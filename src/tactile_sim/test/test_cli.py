"""Every `tactile-sim` subcommand through a real subprocess, on small scenes."""

import json
import math
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from tactile_sim import open_dataset
from tactile_sim.dataset import DatasetError


def _run(*args, check=True):
    result = subprocess.run([sys.executable, "-m", "tactile_sim.cli", *args], capture_output=True, text=True,
                            timeout=300)
    if check:
        assert result.returncode == 0, result.stderr
    return result


def test_press_json_reports_the_bin_forces():
    report = json.loads(_run("press", "--x-mm", "24.5", "--y-mm", "25.5", "--depth-mm", "1.0", "--json").stdout)
    forces = np.array(report["bin_forces_n"])
    assert forces.shape == (report["rows"] * report["cols"], 3)
    assert report["total_force_n"][2] == pytest.approx(forces[:, 2].sum()) and report["total_force_n"][2] > 0.5
    # The press as given, in millimetres: not 25.500000000000004 from its round trip through metres.
    assert report["contact"] == {"x_mm": 24.5, "y_mm": 25.5, "depth_mm": 1.0, "shape": "Sphere", "radius_mm": 5.0,
                                 "shear_mm": [0.0, 0.0], "friction": 1.0}


def test_generate_writes_a_readable_data_set(tmp_path):
    out = tmp_path / "ds"
    result = _run("generate", "--scene", "multi_contact", "--out", str(out), "--frames", "6")
    assert "wrote 6 frames" in result.stdout
    assert "frame" in result.stderr  # the tqdm progress bar
    ds = open_dataset(out)
    assert ds.images.shape == (6, 4, 128, 128) and ds.forces[..., 2].sum() > 1.0


def test_generate_overwrite_refuses_a_directory_without_a_data_set(tmp_path, capsys):
    from tactile_sim.cli import main

    (tmp_path / "notes.txt").write_text("mine")
    assert main(["generate", "--scene", "demo", "--out", str(tmp_path), "--frames", "2", "--overwrite"]) == 2
    assert capsys.readouterr().err == (f"tactile-sim generate: error: output directory {tmp_path} is not empty and "
                                       "holds no data set (no meta.json of a tactile_sim.dataset data set); choose a "
                                       "new or empty one (overwrite, --overwrite, replaces a data set only)\n")
    assert [f.name for f in tmp_path.iterdir()] == ["notes.txt"]


@pytest.mark.parametrize("stop, named", [(signal.SIGINT, "Ctrl-C"), (signal.SIGTERM, "SIGTERM")])
def test_a_stop_while_the_sensor_file_is_read_ends_the_command_in_one_line(tmp_path, stop, named):
    """The sensor file is read before the command runs; a stop there gave a traceback (found in review). A FIFO holds
    the reading up: once the command has it open, its writer stays open and sends nothing."""
    fifo = tmp_path / "sensor.yaml"
    os.mkfifo(fifo)
    process = subprocess.Popen([sys.executable, "-m", "tactile_sim.cli", "press", "--sensor", str(fifo), "--x-mm", "0",
                                "--y-mm", "0", "--depth-mm", "0.5"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True, preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 60
    writer = None
    while writer is None and time.monotonic() < deadline:
        try:
            writer = os.open(fifo, os.O_WRONLY | os.O_NONBLOCK)  # fails (ENXIO) until the command opens it to read
        except OSError:
            time.sleep(0.02)
    try:
        time.sleep(0.2)  # into the read, which waits for the writer
        process.send_signal(stop)
        _, stderr = process.communicate(timeout=60)
    finally:
        if writer is not None:
            os.close(writer)
    assert process.returncode == 128 + stop, stderr
    assert stderr.strip() == f"tactile-sim press: stopped by {named}", stderr


@pytest.mark.parametrize("stop, named", [(signal.SIGINT, "Ctrl-C"), (signal.SIGTERM, "SIGTERM")])
def test_ctrl_c_or_sigterm_stops_generate_in_one_line_with_the_data_set_left_incomplete(tmp_path, stop, named):
    """Before: Python's KeyboardInterrupt traceback for a Ctrl-C, and for a SIGTERM nothing said at all. The child
    gets the default SIGINT disposition, so that Python installs its Ctrl-C handler even where this test runs as a
    background job, which starts with SIGINT ignored."""
    out = tmp_path / "ds"
    process = subprocess.Popen([sys.executable, "-m", "tactile_sim.cli", "generate", "--scene", "paper_grid", "--out",
                                str(out), "--no-progress"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 120
    while not (out / "meta.json").exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    process.send_signal(stop)
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == 128 + stop, stderr
    assert stderr.strip().splitlines()[-1] == (f"tactile-sim generate: stopped by {named}; the data set is left "
                                               "marked incomplete") and "Traceback" not in stderr, stderr
    with pytest.raises(DatasetError, match="is incomplete"):
        open_dataset(out)


def test_render_writes_previews(tmp_path):
    result = _run("render", "--scene", "shear", "--out", str(tmp_path), "--frames", "5", "--count", "2")
    written = result.stdout.split()
    assert len(written) == 3 and all(p.endswith(".png") for p in written)
    assert (tmp_path / "rest.png").stat().st_size > 10_000


def test_render_previews_overlapping_contacts_with_the_numerical_model_only(tmp_path):
    """The analytic model would count the overlap twice and refuses the scene; the numerical one solves it."""
    scene = tmp_path / "overlap.yaml"
    scene.write_text("name: overlap\nseed: 1\ntimeline:\n  - contacts: {contacts: [{x_mm: 20, y_mm: 20, "
                     "depth_mm: 1.0}, {x_mm: 22, y_mm: 20, depth_mm: 1.0}]}\n")
    refused = _run("render", "--scene", str(scene), "--out", str(tmp_path / "analytic"), check=False)
    assert refused.returncode == 2 and "counting the overlap twice" in refused.stderr, refused.stderr
    assert not (tmp_path / "analytic").exists()
    written = _run("render", "--scene", str(scene), "--out", str(tmp_path / "numerical"), "--model", "numerical")
    assert len(written.stdout.split()) == 2  # rest.png and the one frame

def test_bench_prints_one_json_object_with_the_promised_figures():
    result = _run("bench", "--json", "--frames", "20", "--runs", "1", "--effect-frames", "10")
    report = json.loads(result.stdout)
    assert report["frames_per_second"] > 0 and math.isfinite(report["frames_per_second"])
    assert set(report["effect_ms"]) >= {"sensor_noise", "defocus_blur", "led_flicker", "illumination_drift",
                                        "exposure_saturation", "camera_dropout", "reference_drift",
                                        "camera_misalignment"}
    assert all(math.isfinite(v) for v in report["effect_ms"].values())
    assert set(report["ground_truth"]) == {"analytic", "numerical"}


def test_bad_input_gets_a_clear_error_and_exit_status_2(tmp_path):
    result = _run("generate", "--scene", "no_such_scene", "--out", str(tmp_path / "x"), check=False)
    assert result.returncode == 2 and "installed scenes are" in result.stderr
    result = _run("press", "--x-mm", "10", "--y-mm", "10", "--depth-mm", "9", check=False)
    assert result.returncode == 2 and "deeper than the deepest allowed press" in result.stderr


def test_a_reader_that_goes_away_ends_the_command_quietly():
    """`tactile-sim press ... | head -0`: status 141 as a shell tool's, no traceback."""
    process = subprocess.Popen([sys.executable, "-m", "tactile_sim.cli", "press", "--x-mm", "0", "--y-mm", "0",
                                "--depth-mm", "1"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    process.stdout.close()
    _, stderr = process.communicate(timeout=300)
    assert process.returncode == 141 and "Traceback" not in stderr, stderr


def test_unusable_paths_unsafe_names_and_huge_counts_get_one_line_and_status_2(tmp_path, capsys):
    from tactile_sim.cli import main

    def refused(*argv):
        assert main(list(argv)) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "Traceback" not in err, err
        return err

    assert "error: Not a directory: /dev/null/x" in refused("generate", "--scene", "demo", "--out", "/dev/null/x",
                                                              "--frames", "2")
    unsafe = tmp_path / "unsafe.yaml"
    unsafe.write_text("name: ../x\nseed: 1\ntimeline: [{rest: {frames: 2}}]\n")
    assert "name must be a file name" in refused("render", "--scene", str(unsafe), "--out", str(tmp_path / "p"))
    huge = tmp_path / "huge.yaml"
    huge.write_text("name: huge\nseed: 1\ntimeline: [{rest: {frames: 100000000000000000000}}]\n")
    assert "more than 10000000" in refused("generate", "--scene", str(huge), "--out", str(tmp_path / "d"))
    assert not (tmp_path / "d").exists()
    assert "a / h = 2.5, above 1" in refused("press", "--x-mm", "20", "--y-mm", "20", "--depth-mm", "1", "--shape",
                                             "punch", "--radius-mm", "10")
    # a scene refused it, one press reported fx +1.3 N for it
    assert "a shear of 5 mm is longer than the 4 mm compliant gel" in refused(
        "press", "--x-mm", "24", "--y-mm", "25", "--depth-mm", "1", "--shear-x-mm", "3", "--shear-y-mm", "4")
    # scenes refused it, a press reported fx +0.0000 N for a sheared press at 1e20 (found in review)
    assert "--friction must be a Coulomb coefficient from 0 to 10, as in scenes, got 1e+20" in refused(
        "press", "--x-mm", "24", "--y-mm", "25", "--depth-mm", "1", "--shear-x-mm", "1", "--friction", "1e20")
    # named Contact's fields in metres: "Contact.depth_m must be >= 0 (...metres), got -0.001" (docs walkthrough)
    assert "tactile-sim press: error: --depth-mm must be a finite number of millimetres >= 0, got -1.0" in refused(
        "press", "--x-mm", "24", "--y-mm", "25", "--depth-mm", "-1")
    assert "--x-mm must be a finite number of millimetres, got nan" in refused(
        "press", "--x-mm", "nan", "--y-mm", "25", "--depth-mm", "1")
    assert "--radius-mm must be a finite number of millimetres > 0, got -1.0" in refused(
        "press", "--x-mm", "24", "--y-mm", "25", "--depth-mm", "1", "--radius-mm", "-1")
    assert "it would press nothing (--x-mm and --y-mm are millimetres from the surface's corner)" in refused(
        "press", "--x-mm", "60", "--y-mm", "25", "--depth-mm", "1")
    crowded = tmp_path / "crowded.yaml"  # an OverflowError checking that the contacts fit, a directory left behind
    crowded.write_text("name: crowded\nseed: 1\ntimeline: [{random_presses: {frames: 3, depth_mm: 1, "
                       "min_separation_mm: 1.0e+199}}]\n")
    assert "min_separation_mm must be a finite number in [0, 1000]" in refused(
        "generate", "--scene", str(crowded), "--out", str(tmp_path / "c"))
    assert not (tmp_path / "c").exists()
