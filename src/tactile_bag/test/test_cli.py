"""`tactile-bag record` and `play` refuse bad input with one line and exit status 2, before any message flows."""

import os
import subprocess
import sys

import pytest

from tactile_bag.cli import main


@pytest.fixture(autouse=True)
def own_domain(monkeypatch):
    """rclpy is initialised by these commands: keep its DDS participant away from other graphs."""
    monkeypatch.setenv("ROS_DOMAIN_ID", str(20 + (os.getpid() + 40) % 80))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")


def error_line(capsys) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    return err[0]


def test_record_never_overwrites(sim_bag, capsys):
    assert main(["record", str(sim_bag), "--duration", "1"]) == 2
    assert error_line(capsys) == (f"tactile-bag record: error: {sim_bag} already exists: name a new bag directory "
                                  "(a bag is never overwritten)")


def test_record_needs_a_positive_duration(tmp_path, capsys):
    assert main(["record", str(tmp_path / "bag"), "--duration", "0"]) == 2
    assert "--duration and --wait must be > 0 seconds" in error_line(capsys)
    assert not (tmp_path / "bag").exists()


def test_play_an_unknown_topic(sim_bag, capsys):
    assert main(["play", str(sim_bag), "--topics", "/tactile/wrench"]) == 2
    assert error_line(capsys).startswith(f"tactile-bag play: error: bag {sim_bag} has no topic /tactile/wrench; its "
                                         "topics are ['/tactile/cam0/image'")


def test_play_a_damaged_bag(tmp_path, capsys):
    (tmp_path / "bag").mkdir()
    (tmp_path / "bag" / "metadata.yaml").write_text("not: [a bag")
    assert main(["play", str(tmp_path / "bag")]) == 2
    assert "cannot be opened" in error_line(capsys)


def test_play_and_eval_refuse_a_bag_whose_bytes_changed(flipped_pixels_bag, model_dir, capsys):
    """Pixels changed on disk (the chunk CRC that BagWriter filled in no longer matches): one line, exit status 2,
    during playback or evaluation alike."""
    assert main(["play", str(flipped_pixels_bag), "--rate", "1000", "--wait-subscribers", "0"]) == 2
    expected = (f"error: bag {flipped_pixels_bag} is damaged: a chunk's CRC-32 does not match its data (Chunk "
                "checksum mismatch.): bytes of the file changed after it was written; take it from a copy")
    assert error_line(capsys) == f"tactile-bag play: {expected}"
    assert main(["eval", str(flipped_pixels_bag), "--model", str(model_dir), "--backend", "torch"]) == 2
    assert error_line(capsys) == f"tactile-bag eval: {expected}"


def test_play_needs_a_positive_rate(sim_bag, capsys):
    assert main(["play", str(sim_bag), "--rate", "0"]) == 2
    assert "--rate must be > 0" in error_line(capsys)


def test_record_and_play_do_not_import_the_model_stack():
    """torch takes a second to import; only `eval` needs it."""
    imported = subprocess.run([sys.executable, "-c", "import sys, tactile_bag.cli; print(sorted({'torch', "
                               "'onnxruntime', 'tactile_fusion.inference'} & set(sys.modules)))"],
                              capture_output=True, text=True, timeout=60)
    assert imported.returncode == 0, imported.stderr
    assert imported.stdout.strip() == "[]"
