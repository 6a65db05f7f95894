"""`tactile-bag record` and `play` refuse bad input with one line and exit status 2, before any message flows."""

import math
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
import torch
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.serialization import serialize_message
from sensor_msgs.msg import Image

from tactile_bag.bagfile import BagWriter
from tactile_bag.cli import main
from tactile_bag.play import play
from tactile_bag.record import record
from tactile_bag.topics import IMAGE_TYPE
from tactile_conversions import stop_signals
from tactile_conversions.stop_signals import init_ros
from tactile_fusion.artifacts import STATE_DICT


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


def test_eval_with_a_model_that_outputs_nan_is_an_error_line_not_a_traceback(sim_bag, model_dir, tmp_path, capsys):
    broken = Path(shutil.copytree(model_dir, tmp_path / "model"))
    weights = torch.load(broken / STATE_DICT)
    weights["fusion.expand.bias"][0] = float("nan")
    torch.save(weights, broken / STATE_DICT)
    assert main(["eval", str(sim_bag), "--model", str(broken), "--backend", "torch"]) == 2
    assert error_line(capsys) == ("tactile-bag eval: error: torch fp32: the model produced NaN or Inf from finite "
                                  "inputs; the model file is corrupt or overflowed: restore model.pt from a copy or "
                                  "retrain the model")


@pytest.mark.parametrize("args, message", [
    (["play", "BAG", "--rate", "0"], "argument --rate: must be a finite number of times the recorded speed >= "
                                     "0.001, got '0'"),
    (["play", "BAG", "--rate", "1e-300", "--wait-subscribers", "0"], "argument --rate: must be a finite number of "
                                                                     "times the recorded speed >= 0.001, got '1e-300'"),
    (["play", "BAG", "--rate", "nan"], "argument --rate: must be a finite number"),
    (["play", "BAG", "--wait-subscribers", "inf"], "argument --wait-subscribers: must be a finite number of seconds "
                                                   ">= 0, got 'inf'"),
    (["record", "OUT", "--duration", "0"], "argument --duration: must be a finite number of seconds > 0, got '0'"),
    (["record", "OUT", "--duration", "nan"], "argument --duration: must be a finite number of seconds > 0"),
    (["record", "OUT", "--duration", "1", "--wait", "nan"], "argument --wait: must be a finite number of seconds > 0"),
    (["eval", "BAG", "--reference-bundles", "0"], "argument --reference-bundles: must be a whole number of bundles "
                                                  "from 1 to 400, got '0'"),
    # as fusion_node: 10**20 overflowed a deque's maxlen, with a traceback
    (["eval", "BAG", "--reference-bundles", "100000000000000000000"], "argument --reference-bundles: must be a whole "
                                                                      "number of bundles from 1 to 400"),
])
def test_bad_numbers_are_refused_before_anything_runs(sim_bag, tmp_path, capsys, args, message):
    """NaN would have recorded or waited for ever (every comparison with it is false)."""
    args = [str(sim_bag) if a == "BAG" else str(tmp_path / "new_bag") if a == "OUT" else a for a in args]
    with pytest.raises(SystemExit) as stopped:
        main(args)
    err = capsys.readouterr().err.strip().splitlines()
    assert stopped.value.code == 2 and len(err) == 1 and message in err[0], err  # argparse's usage block went first
    assert not (tmp_path / "new_bag").exists()


def test_play_and_eval_refuse_a_damaged_file_compressed_bag(damaged_zstd_file_bag, model_dir, capsys):
    """A zstd-compressed .mcap cut short, or metadata that claims zstd over a plain .mcap: one line, exit status 2
    (before: EOFError's or ZstdError's traceback, exit status 1)."""
    bag, reason = damaged_zstd_file_bag
    for command in (["play", str(bag), "--wait-subscribers", "0"],
                    ["eval", str(bag), "--model", str(model_dir), "--backend", "torch"]):
        assert main(command) == 2
        expected = f"tactile-bag {command[0]}: error: bag {bag} cannot be opened ({reason}); expected a rosbag2 "
        assert error_line(capsys).startswith(expected)


def test_play_and_eval_refuse_an_lz4_chunk_that_does_not_decompress(damaged_lz4_chunk_bag, model_dir, capsys):
    """One line, exit status 2 (before: the lz4 package's RuntimeError, a traceback and exit status 1)."""
    bag = damaged_lz4_chunk_bag
    for command in (["play", str(bag), "--rate", "1000", "--wait-subscribers", "0"],
                    ["eval", str(bag), "--model", str(model_dir), "--backend", "torch"]):
        assert main(command) == 2
        assert error_line(capsys) == (f"tactile-bag {command[0]}: error: bag {bag} is damaged: reading its messages "
                                      "failed (LZ4F_getFrameInfo failed with code: ERROR_frameType_unknown)")


def test_play_itself_refuses_a_rate_below_the_slowest(sim_bag):
    """At --rate 1e-300 the bag's 25 ms frame period became a sleep beyond what time.sleep takes (OverflowError)."""
    with pytest.raises(ValueError, match=r"--rate must be a finite number >= 0\.001, got 1e-300"):
        play(sim_bag, rate=1e-300)


@pytest.mark.parametrize(("offsets_s", "passes"), [((0.0,), 3), ((0.0, 0.0), 2), ((0.0, 0.1, 0.2), 3)])
def test_a_looped_bag_starts_over_one_period_after_its_last_message(tmp_path, monkeypatch, offsets_s, passes):
    """A pass went straight on into the next: one message was published 160000 times in 3 s, and so were two received
    at one time (reviews), and a bag's first message followed its last at once. Now a pass lasts one period of its
    topics more than its messages span (no period: a second). The real publisher's calls are timed, and ROS is shut
    down after `passes` passes: lower bounds on the gaps, which a loaded machine only lengthens."""
    image = serialize_message(Image(height=1, width=1, encoding="mono8", step=1, data=[7]))
    with BagWriter(tmp_path / "bag") as bag:
        for offset_s in offsets_s:
            bag.write("/tactile/cam0/image", IMAGE_TYPE, 1_700_000_000 * 10**9 + round(offset_s * 1e9), image)
    published_s = []
    real_publish = Publisher.publish

    def timed_publish(publisher, message):
        real_publish(publisher, message)
        if publisher.topic_name != "/tactile/cam0/image":  # the node's own publishers (/rosout, parameter events)
            return
        published_s.append(time.monotonic())
        if len(published_s) == passes * len(offsets_s):
            rclpy.shutdown()  # as a SIGTERM does: the replay ends at its next wait

    monkeypatch.setattr(Publisher, "publish", timed_publish)
    monkeypatch.setattr(stop_signals, "_started", threading.Event())  # init_ros's flags, fresh for this test
    monkeypatch.setattr(stop_signals, "_interrupted", threading.Event())
    python_handler = signal.getsignal(signal.SIGINT)
    init_ros()  # as the command starts ROS: a shutdown during a publish is a stop
    try:
        counts = play(tmp_path / "bag", loop=True, wait_subscribers_s=0.0)
    finally:
        rclpy.try_shutdown()
        signal.signal(signal.SIGINT, python_handler)
    assert counts["/tactile/cam0/image"] == passes * len(offsets_s), (counts, published_s)
    gaps = np.diff(published_s)
    per_pass = len(offsets_s)
    pass_gaps = gaps[per_pass - 1::per_pass]  # from a pass's last message to the next pass's first
    if offsets_s[-1] > offsets_s[0]:  # a period of 0.1 s: the next pass 0.1 s after the last message
        assert (pass_gaps >= 0.095).all() and (np.delete(gaps, np.s_[per_pass - 1::per_pass]) >= 0.095).all(), gaps
    else:  # no period: a second between passes
        assert (pass_gaps >= 0.99).all(), gaps


def test_play_stops_on_sigterm_during_a_long_gap(tmp_path):
    """A message 10^7 s (116 days) after the first, played at the slowest rate: the wait of 10^10 s, beyond one
    time.sleep (before: OverflowError), is slept in pieces, and SIGTERM, which does not wake a sleep, ends it within
    one (with a single sleep it would have waited out the gap)."""
    image = serialize_message(Image(height=1, width=1, encoding="mono8", step=1, data=[7]))
    with BagWriter(tmp_path / "bag") as bag:
        for time_ns in (1_700_000_000 * 10**9, 1_710_000_000 * 10**9):
            bag.write("/tactile/cam0/image", IMAGE_TYPE, time_ns, image)
    args = ["tactile-bag", "play", str(tmp_path / "bag"), "--rate", "0.001", "--wait-subscribers", "0"]
    returncode, out, err, stopped_s = play_until_signal(args, signal.SIGTERM)
    assert returncode == 0 and "Traceback" not in err, err
    assert out.startswith("played 1 messages ") and stopped_s < 5.0, (out, stopped_s)


def play_until_signal(args: list[str], stop: int) -> tuple[int, str, str, float]:
    """Run `tactile-bag play` (args), send it `stop` once its publishers are on the graph (seen by a probe node):
    (exit status, stdout, stderr, seconds from the signal to its exit)."""
    rclpy.init()
    probe = Node("play_signal_probe")
    player = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 30.0
        while not probe.count_publishers("/tactile/cam0/image") and time.monotonic() < deadline:
            time.sleep(0.05)
        time.sleep(0.5)
        player.send_signal(stop)
        stopped_at = time.monotonic()
        out, err = player.communicate(timeout=30)
        return player.returncode, out, err, time.monotonic() - stopped_at
    finally:
        if player.poll() is None:
            player.kill()
            player.communicate()
        probe.destroy_node()
        rclpy.try_shutdown()


def test_record_stopped_before_any_message_says_so_not_that_none_came_in_time(tmp_path):
    """No graph runs; a Ctrl-C 0.5 s into a wait of 30 s for the first message. It said "no message within 30 s: is
    the graph running" (found in review)."""
    rclpy.init()
    probe = Node("record_signal_probe")
    recorder = subprocess.Popen(["tactile-bag", "record", str(tmp_path / "bag"), "--duration", "5", "--wait", "30"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        deadline = time.monotonic() + 30.0
        while not probe.count_subscribers("/tactile/cam0/image") and time.monotonic() < deadline:
            time.sleep(0.05)  # subscribed: recording, waiting for a first message
        time.sleep(0.5)
        recorder.send_signal(signal.SIGINT)
        out, err = recorder.communicate(timeout=30)
    finally:
        if recorder.poll() is None:
            recorder.kill()
            recorder.communicate()
        probe.destroy_node()
        rclpy.try_shutdown()
    assert recorder.returncode == 1 and out.startswith("recorded 0 messages"), (out, err)
    assert err.strip() == "tactile-bag record: stopped before any message arrived", err


@pytest.mark.parametrize("duration_s, wait_s", [(math.nan, 1.0), (1.0, math.inf), (0.0, 1.0)])
def test_record_itself_refuses_a_duration_or_wait_that_never_or_at_once_ends(tmp_path, duration_s, wait_s):
    with pytest.raises(ValueError, match="--duration and --wait must be finite numbers > 0 seconds"):
        record(tmp_path / "new_bag", ["/tactile/cam0/image"], {}, duration_s, wait_s=wait_s)
    assert not (tmp_path / "new_bag").exists()


def test_record_and_play_do_not_import_the_model_stack():
    """torch takes a second to import; only `eval` needs it."""
    imported = subprocess.run([sys.executable, "-c", "import sys, tactile_bag.cli; print(sorted({'torch', "
                               "'onnxruntime', 'tactile_fusion.inference'} & set(sys.modules)))"],
                              capture_output=True, text=True, timeout=60)
    assert imported.returncode == 0, imported.stderr
    assert imported.stdout.strip() == "[]"


@pytest.mark.parametrize("stop", [signal.SIGINT, signal.SIGTERM], ids=["ctrl-c", "sigterm"])
@pytest.mark.parametrize("loop", [False, True], ids=["waiting-for-subscribers", "playing"])
def test_play_stopped_by_a_signal_says_what_it_played(sim_bag, stop, loop):
    """Stopped while it waits for subscribers (before: KeyboardInterrupt's traceback), or while it plays in a loop: a
    summary line and exit status 0, never a traceback. The signal is sent once the player's publishers are on the
    graph, seen by a probe node."""
    args = ["tactile-bag", "play", str(sim_bag)] + (["--loop", "--wait-subscribers", "0"] if loop else
                                                     ["--wait-subscribers", "60"])
    returncode, out, err, _ = play_until_signal(args, stop)
    assert returncode == 0 and "Traceback" not in err, err
    played = int(out.split("played ")[1].split()[0])
    assert played > 0 if loop else played == 0, out


@pytest.mark.parametrize("stop, named", [(signal.SIGINT, "Ctrl-C"), (signal.SIGTERM, "SIGTERM")])
def test_eval_stopped_by_a_signal_says_so_in_one_line(sim_bag, model_dir, capsys, monkeypatch, stop, named,
                                                      stop_signals_fail_the_test):
    """Before: a KeyboardInterrupt traceback for a Ctrl-C while eval estimated, and no word for a SIGTERM. The signal
    is sent to this process while the bag is evaluated."""
    from tactile_bag import cli

    def evaluated_until_stopped(*args, **kwargs):
        os.kill(os.getpid(), stop)
        time.sleep(30)
        raise AssertionError(f"{named} did not stop the evaluation")

    monkeypatch.setattr(cli, "evaluate_bag", evaluated_until_stopped)
    before = signal.getsignal(signal.SIGTERM)
    assert main(["eval", str(sim_bag), "--model", str(model_dir), "--backend", "torch"]) == 128 + stop
    assert capsys.readouterr().err == f"tactile-bag eval: stopped by {named}\n"
    assert signal.getsignal(signal.SIGTERM) is before  # the handler from before is back
