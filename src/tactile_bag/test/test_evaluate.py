"""Offline evaluation: bundling recorded images, reference frames, ground-truth matching, metrics, errors."""

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest
from ament_index_python.packages import get_package_share_directory
from builtin_interfaces.msg import Time
from hypothesis import given
from hypothesis import strategies as st
from rclpy.serialization import serialize_message

from tactile_bag import evaluate
from tactile_bag.bagfile import BagError, BagReader, BagWriter, DefinitionMismatchError
from tactile_bag.cli import main
from tactile_bag.evaluate import FrameReader, evaluate_bag, image_bundles, match_stamps
from tactile_bag.topics import IMAGE_TYPE
from tactile_conversions.images import mono8_to_msg
from tactile_conversions.ros_time import seconds_to_time
from tactile_conversions.topics import GROUND_TRUTH_TOPIC, camera_topic
from tactile_description import default_sensor_path
from tactile_fusion.inference import load_predictor
from tactile_fusion.live_estimation import REFERENCE_PATIENCE_BUNDLES
from tactile_fusion.metrics import contact_metrics, force_metrics
from tactile_msgs.msg import ImageBundle
from tactile_sim import Simulator
from tactile_sim.scene import parse_scene


@pytest.fixture(scope="module")
def predictor(model_dir):
    return load_predictor(model_dir, "torch")


def test_images_are_bundled_frame_by_frame(tmp_path, write_bag, sensor, sim_frames):
    captures = write_bag(tmp_path / "bag", sensor, sim_frames)
    reader = FrameReader(sensor, 128)
    with BagReader(tmp_path / "bag") as bag:
        bundles = list(image_bundles(bag, sensor, reader))
    # The synchroniser waits for a later image before it lets the newest frame go: all but the last are bundled.
    assert len(bundles) >= len(sim_frames) - 1
    for frame, capture_s, bundle in zip(sim_frames, captures, bundles, strict=False):
        assert bundle.camera_ok.all()
        np.testing.assert_array_equal(bundle.images, frame.images)
        assert capture_s <= bundle.stamp_s <= capture_s + write_bag.jitter_s
    assert not reader.skipped


def test_images_stamped_before_1970_are_dropped_and_counted_as_bundle_node_drops_them(tmp_path, write_bag, sensor,
                                                                                      sim_frames):
    """A negative stamp is a legal message that no bundle can carry: bundle_node drops such an image before its
    synchroniser, and so does the offline bundling (before: the synchroniser took it as the camera's stamps jumping
    back and started over, dropping what it held)."""
    write_bag(tmp_path / "clean", sensor, sim_frames)
    stray = serialize_message(mono8_to_msg(sim_frames[0].images[1], Time(sec=-5), "cam1_optical"))
    with BagReader(tmp_path / "clean") as clean, BagWriter(tmp_path / "bag") as bag:
        for n, (topic, _, time_ns, raw) in enumerate(clean.messages(list(clean.topics))):
            bag.write(topic, clean.topics[topic], time_ns, raw)
            if n in (40, 80):
                bag.write(camera_topic("cam1"), IMAGE_TYPE, time_ns + 1, stray)
    bundled = {}
    for name in ("clean", "bag"):
        reader = FrameReader(sensor, 128)
        with BagReader(tmp_path / name) as bag:
            bundled[name] = (list(image_bundles(bag, sensor, reader)), reader.skipped)
    (clean_bundles, _), (bundles, skipped) = bundled["clean"], bundled["bag"]
    assert skipped == {"images dropped by the synchroniser (bad_stamp)": 2}
    assert [b.stamp_s for b in bundles] == [b.stamp_s for b in clean_bundles]


def test_estimates_are_the_predictors_against_the_mean_of_the_first_bundles(sim_bag, sensor, sim_frames, predictor):
    result = evaluate_bag(sim_bag, sensor, predictor, reference_bundles=10)
    assert result.source == "images"
    n = len(result.stamps_s)
    assert n >= len(sim_frames) - 11
    reference = np.rint(np.mean([f.images for f in sim_frames[:10]], axis=0)).astype(np.uint8)
    frames = sim_frames[10:10 + n]
    expected = np.stack([predictor.predict(f.images, reference) for f in frames])
    np.testing.assert_allclose(result.estimates_n, expected, rtol=1e-5, atol=1e-7)
    # Each estimate is matched with the ground truth of its own frame.
    np.testing.assert_array_equal(result.truth_index, np.arange(10, 10 + n))
    truth = np.stack([f.bin_forces_n for f in frames])
    direct = force_metrics(expected, truth)
    assert result.metrics["rmse_bin_n"] == pytest.approx(direct["rmse_bin_n"], rel=1e-5)
    assert result.metrics["rmse_total_n"] == pytest.approx(direct["rmse_total_n"], rel=1e-5)
    contact = contact_metrics(expected, truth, sensor.grid.bin_centers_m())
    assert [(b["frames"], b["reported_share"]) for b in result.metrics["contact"]["bands"]] == \
        [(b["frames"], b["reported_share"]) for b in contact["bands"]]
    assert sum(b["frames"] for b in contact["bands"]) + contact["frames_without_load"] == n
    summary = result.summary()
    assert summary["contact"] == result.metrics["contact"]
    assert summary["matched_with_ground_truth"] == summary["estimates"] == n
    assert summary["degraded_estimates"] == 0 and summary["missing_camera_ids"] == []
    assert summary["reference_checked"] and summary["off_reference_camera_ids"] == []
    assert summary["estimates_off_reference"] == 0
    json.dumps(summary)  # plain types only


def test_estimates_made_while_a_camera_no_longer_matched_the_reference_are_counted(tmp_path, write_bag, sensor,
                                                                                  model_dir, capsys):
    """cam3 knocked askew after the reference, from frame 30 on, while presses go on (as in the effects scene)."""
    askew = {"name": "askew", "seed": 5, "indenter": {"shape": "sphere", "diameter_mm": 10},
             "timeline": [{"rest": {"frames": 10}}, {"random_presses": {"frames": 70, "depth_mm": [0.1, 1.5]}}],
             "effects": [{"type": "sensor_noise", "sigma": 1.0},
                         {"type": "camera_misalignment", "cameras": ["cam3"], "shift_px": [1.5, -1.0],
                          "rotation_deg": 2.0, "frames": [30, 80]}]}
    write_bag(tmp_path / "bag", sensor, list(Simulator(sensor).stream(parse_scene(askew))))
    result = evaluate_bag(tmp_path / "bag", sensor, load_predictor(model_dir, "torch"))
    summary = result.summary()
    assert summary["off_reference_camera_ids"] == ["cam3"]
    # Off from a few checks into the askew frames (estimates start at frame 10) until the end, none before them.
    off = result.off_reference[:, 3]
    first = int(np.argmax(off))
    assert 20 < first <= 20 + 8 * 5 and off[first:].all() and summary["estimates_off_reference"] == off.sum()
    assert main(["eval", str(tmp_path / "bag"), "--model", str(model_dir), "--backend", "torch"]) == 0
    assert f"{off.sum()} estimates while cam3 no longer matched the reference frames" in capsys.readouterr().out
    unchecked = evaluate_bag(tmp_path / "bag", sensor, load_predictor(model_dir, "torch"), reference_bundles=1)
    assert unchecked.off_reference is None and unchecked.summary()["reference_checked"] is False


def test_recorded_bundles_give_the_same_estimates(tmp_path, write_bag, sensor, sim_frames, predictor):
    write_bag(tmp_path / "bag", sensor, sim_frames, images=True, bundles=True)
    from_images = evaluate_bag(tmp_path / "bag", sensor, predictor, source="images")
    from_bundles = evaluate_bag(tmp_path / "bag", sensor, predictor, source="bundles")
    assert from_bundles.source == "bundles" and from_bundles.bundles == len(sim_frames)
    n = len(from_images.stamps_s)
    np.testing.assert_allclose(from_bundles.stamps_s[:n], from_images.stamps_s, rtol=0, atol=1e-6)  # ns stamps
    np.testing.assert_allclose(from_bundles.estimates_n[:n], from_images.estimates_n, rtol=1e-6)


def test_bundles_missing_from_a_recording_are_counted(tmp_path, write_bag, sensor, sim_frames, predictor):
    kept = sim_frames[:25] + sim_frames[28:33] + sim_frames[34:]  # bundles 25-27 and 33 never reached the recorder
    write_bag(tmp_path / "bag", sensor, kept, images=False, bundles=True)
    summary = evaluate_bag(tmp_path / "bag", sensor, predictor).summary()
    assert summary["bundles"] == len(kept) == len(sim_frames) - 4
    assert summary["skipped"] == {"bundles missing from the recording (gaps in their sequence numbers)": 4}


def bundles_changed(tmp_path, write_bag, sensor, sim_frames, change) -> None:
    """tmp_path/clean: the frames recorded as bundles; tmp_path/bag: the same with change(bundle) applied to each."""
    write_bag(tmp_path / "clean", sensor, sim_frames, images=False, bundles=True)
    with BagReader(tmp_path / "clean") as clean, BagWriter(tmp_path / "bag") as bag:
        for topic, _, time_ns, raw in clean.messages(list(clean.topics)):
            if topic == "/tactile/image_bundle":
                msg = evaluate.deserialize(raw, ImageBundle, topic, time_ns)
                change(msg)
                raw = serialize_message(msg)
            bag.write(topic, clean.topics[topic], time_ns, raw)


def test_a_recorded_bundle_stamped_before_1970_is_skipped_as_the_fusion_node_skips_it(tmp_path, write_bag, sensor,
                                                                                        sim_frames, predictor):
    def stamped_before_1970(bundle):
        if bundle.sequence == 30:
            bundle.header.stamp = Time(sec=-5)

    bundles_changed(tmp_path, write_bag, sensor, sim_frames, stamped_before_1970)
    clean, stray = (evaluate_bag(tmp_path / name, sensor, predictor, source="bundles") for name in ("clean", "bag"))
    assert stray.skipped == {"bundle stamped outside [0, 2**31) s": 1}
    assert len(stray.stamps_s) == len(clean.stamps_s) - 1 and stray.stamps_s.min() > 0


def test_a_bag_of_another_sensors_bundles_is_refused_naming_them(tmp_path, write_bag, sensor, sim_frames, predictor):
    """Every recorded bundle holds a camera this sensor has not: none is usable, and the refusal said only "record
    longer at rest" (review)."""
    def of_another_sensor(bundle):
        bundle.camera_ids = [*bundle.camera_ids[:3], "cam4"]

    bundles_changed(tmp_path, write_bag, sensor, sim_frames, of_another_sensor)
    with pytest.raises(BagError, match=f"only 0 complete bundle\\(s\\) of {len(sim_frames)}; {len(sim_frames)} "
                                       "bundle of another sensor, the reference frames need"):
        evaluate_bag(tmp_path / "bag", sensor, predictor, source="bundles")


def test_a_dropped_camera_degrades_recorded_bundles(tmp_path, write_bag, sensor, sim_frames, predictor):
    frames = [dataclasses.replace(f, camera_ok=np.array([c != "cam1" or f.index % 5 for c in sensor.camera_ids]))
              for f in sim_frames]
    write_bag(tmp_path / "bag", sensor, frames, images=False, bundles=True)
    result = evaluate_bag(tmp_path / "bag", sensor, predictor)
    assert result.source == "bundles"  # cam1's images are not all there, the bundles are
    complete = [f.index for f in frames if f.camera_ok.all()]
    last_reference = complete[9]  # the reference takes the first 10 complete bundles, skipping degraded ones
    summary = result.summary()
    assert summary["missing_camera_ids"] == ["cam1"]
    assert summary["estimates"] == len(frames) - 1 - last_reference
    assert summary["degraded_estimates"] == len([f for f in frames[last_reference:] if not f.camera_ok.all()]) > 0


def test_a_camera_dead_from_the_start_is_left_out_of_the_reference_as_in_the_fusion_node(tmp_path, write_bag, sensor,
                                                                                       sim_frames, predictor, capsys,
                                                                                       model_dir):
    """cam1 never gives an image: after REFERENCE_PATIENCE_BUNDLES bundles the reference is taken without it (as the
    fusion node does, through the same LiveEstimation), and every later estimate is degraded."""
    cycles = -(-(REFERENCE_PATIENCE_BUNDLES + 10) // len(sim_frames))
    frames = [dataclasses.replace(f, index=f.index + k * len(sim_frames), time_s=f.time_s + k * len(sim_frames) / 40,
                                  camera_ok=np.array([c != "cam1" for c in sensor.camera_ids]))
              for k in range(cycles) for f in sim_frames]
    write_bag(tmp_path / "bag", sensor, frames, images=False, bundles=True)
    summary = evaluate_bag(tmp_path / "bag", sensor, predictor).summary()
    assert summary["cameras_without_reference"] == ["cam1"] and summary["missing_camera_ids"] == ["cam1"]
    assert summary["estimates"] == summary["degraded_estimates"] == len(frames) - REFERENCE_PATIENCE_BUNDLES
    assert main(["eval", str(tmp_path / "bag"), "--model", str(model_dir), "--backend", "torch"]) == 0
    out = capsys.readouterr().out
    assert "the reference frames were taken without cam1" in out
    assert "of the first bundles (fewer complete ones came) averaged into the reference frames without cam1" in out


def test_a_malformed_bundle_is_skipped_once_and_not_counted_towards_the_reference(tmp_path, write_bag, sensor,
                                                                                   sim_frames, predictor, monkeypatch):
    """Bundle 5 has four camera ids and three images: it is skipped (counted once, as malformed), and the reference
    taken without the dead cam1 after REFERENCE_PATIENCE_BUNDLES bundles does not count it among them."""
    cycles = -(-(REFERENCE_PATIENCE_BUNDLES + 10) // len(sim_frames))
    frames = [dataclasses.replace(f, index=f.index + k * len(sim_frames), time_s=f.time_s + k * len(sim_frames) / 40,
                                  camera_ok=np.array([c != "cam1" for c in sensor.camera_ids]))
              for k in range(cycles) for f in sim_frames]
    write_bag(tmp_path / "bag", sensor, frames, images=False, bundles=True)
    read = evaluate.deserialize

    def deserialize(raw, cls, topic, time_ns):
        msg = read(raw, cls, topic, time_ns)
        if cls is ImageBundle and msg.sequence == 5:
            msg.camera_ids = ["cam0", "cam1", "cam2", "cam3"]  # four ids for the three images
        return msg

    monkeypatch.setattr(evaluate, "deserialize", deserialize)
    summary = evaluate_bag(tmp_path / "bag", sensor, predictor).summary()
    assert summary["skipped"] == {"malformed bundle": 1}
    assert summary["bundles"] == len(frames)
    assert summary["estimates"] == len(frames) - REFERENCE_PATIENCE_BUNDLES - 1  # the reference waited one more


def test_ground_truth_of_an_older_message_definition_is_left_out_and_counted(tmp_path, write_bag, sensor, sim_frames,
                                                                             predictor):
    """A bag recorded before ForceDistribution got `estimated_components`: its images are still evaluated, its ground
    truth (optional by default) is left out with the reason and count in the summary; asked for by name, refused."""
    definition = (Path(get_package_share_directory("tactile_msgs")) / "msg" / "ForceDistribution.msg").read_text()
    assert "string[] estimated_components" in definition
    write_bag(tmp_path / "bag", sensor, sim_frames,
              truth_definition=definition.replace("string[] estimated_components", ""))
    summary = evaluate_bag(tmp_path / "bag", sensor, predictor).summary()
    assert summary["estimates"] >= len(sim_frames) - 11 and summary["rmse_bin_n"] is None
    assert summary["ground_truth_messages"] == 0
    assert summary["skipped"] == {f"ground truth on {GROUND_TRUTH_TOPIC} recorded with another ForceDistribution "
                                  "definition": len(sim_frames)}
    with pytest.raises(DefinitionMismatchError, match=f"topic {GROUND_TRUTH_TOPIC} was recorded with another"):
        evaluate_bag(tmp_path / "bag", sensor, predictor, truth_topic=GROUND_TRUTH_TOPIC)


def test_without_ground_truth_only_statistics(tmp_path, write_bag, sensor, sim_frames, predictor):
    write_bag(tmp_path / "bag", sensor, sim_frames, truth=False)
    result = evaluate_bag(tmp_path / "bag", sensor, predictor)
    summary = result.summary()
    assert result.metrics is None and summary["rmse_bin_n"] is None and summary["ground_truth_messages"] == 0
    totals = result.estimates_n.astype(np.float64).sum(axis=(1, 2))
    assert summary["estimated_total_n"]["max"] == pytest.approx(totals.max(axis=0).tolist())


# Frames are 25 ms apart and bundle stamps up to 2 ms after the capture: 12.5 ms off is 10.5 ms from any truth.
@pytest.mark.parametrize(("offset_s", "matched"), [(0.005, True), (-0.005, True), (0.0125, False)])
def test_ground_truth_is_matched_within_10_ms(tmp_path, write_bag, sensor, sim_frames, predictor, offset_s, matched):
    write_bag(tmp_path / "bag", sensor, sim_frames, truth_offset_s=offset_s)
    result = evaluate_bag(tmp_path / "bag", sensor, predictor)
    assert result.truth_messages == len(sim_frames)
    assert result.matched.all() if matched else not result.matched.any()


def test_match_stamps_examples():
    truth = np.array([3.0, 1.0, 2.0])
    np.testing.assert_array_equal(match_stamps(np.array([0.995, 1.4, 2.01, 3.02, 5.0]), truth, 0.011),
                                  [1, -1, 2, -1, -1])
    np.testing.assert_array_equal(match_stamps(np.array([1.0]), np.zeros(0)), [-1])
    np.testing.assert_array_equal(match_stamps(np.array([0.0, 7.0]), np.array([7.005]), 0.01), [-1, 0])


@given(st.lists(st.floats(0, 10), min_size=1, max_size=8), st.lists(st.floats(0, 10), max_size=8))
def test_match_stamps_is_the_nearest_within_tolerance(truth, stamps):
    truth, stamps = np.array(truth), np.array(stamps)
    index = match_stamps(stamps, truth, 0.5)
    for stamp, i in zip(stamps, index, strict=True):
        distance = np.abs(truth - stamp)
        if i < 0:
            assert distance.min() > 0.5
        else:
            assert distance[i] == distance.min() <= 0.5


def test_too_few_complete_bundles_for_the_reference(sim_bag, sensor, predictor):
    with pytest.raises(BagError, match="complete bundle.*the reference frames need 100; .*--reference-bundles"):
        evaluate_bag(sim_bag, sensor, predictor, reference_bundles=100)


def test_a_bag_whose_bundles_all_go_into_the_reference_is_refused(sim_bag, sensor, predictor):
    """Exactly as many bundles as the reference takes: eval reported 0 estimates and exit status 0 (found in review)."""
    bundles = evaluate_bag(sim_bag, sensor, predictor, reference_bundles=1).bundles
    with pytest.raises(BagError, match=f"the reference frames took every complete bundle of its {bundles}, none is "
                                       "left to estimate; record longer, or lower --reference-bundles"):
        evaluate_bag(sim_bag, sensor, predictor, reference_bundles=bundles)
    assert len(evaluate_bag(sim_bag, sensor, predictor, reference_bundles=bundles - 1).estimates_n) == 1


def test_cli_eval_json(sim_bag, model_dir, capsys):
    assert main(["eval", str(sim_bag), "--model", str(model_dir), "--backend", "torch", "--json",
                 "--reference-bundles", "5"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["reference_bundles"] == 5
    assert summary["matched_with_ground_truth"] == summary["estimates"] >= 34
    assert len(summary["rmse_bin_n"]) == len(summary["rmse_total_n"]) == 3
    assert summary["contact"]["contact_level_n"] == 0.01


def test_cli_eval_warns_of_a_sensor_description_edited_since_the_model_was_trained(sim_bag, model_dir, tmp_path,
                                                                                    capsys):
    """A description whose cameras and grid fit the model, but with a camera moved: evaluated, with a warning."""
    assert main(["eval", str(sim_bag), "--model", str(model_dir), "--backend", "torch", "--json"]) == 0
    captured = capsys.readouterr()
    assert captured.err == "" and json.loads(captured.out)["sensor_changes"] == []
    moved = tmp_path / "moved.yaml"
    moved.write_text(Path(default_sensor_path()).read_text().replace("cam0, position_mm: [12.25,",
                                                                     "cam0, position_mm: [12.5,"))
    assert main(["eval", str(sim_bag), "--model", str(model_dir), "--backend", "torch", "--json", "--sensor",
                 str(moved)]) == 0
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    assert summary["estimates"] > 0 and summary["sensor_changes"] == ["cameras[cam0].position_m"]
    assert captured.err == (f"tactile-bag eval: warning: the sensor description {moved} is not the one the model was "
                            "trained for: cameras[cam0].position_m changed since; its estimates may be off: retrain it "
                            "for this description (tactile-fusion train --sensor FILE), or use the description it was "
                            "trained with\n")


def test_cli_eval_contact_level(sim_bag, model_dir, capsys):
    assert main(["eval", str(sim_bag), "--model", str(model_dir), "--backend", "torch", "--json",
                 "--contact-level", "0.5"]) == 0
    assert json.loads(capsys.readouterr().out)["contact"]["contact_level_n"] == 0.5
    with pytest.raises(SystemExit) as exit_info:
        main(["eval", str(sim_bag), "--model", str(model_dir), "--contact-level", "nan"])
    assert exit_info.value.code == 2
    assert "--contact-level: must be a finite number of newtons > 0, got 'nan'" in capsys.readouterr().err


def test_cli_eval_text(sim_bag, model_dir, capsys):
    assert main(["eval", str(sim_bag), "--model", str(model_dir), "--backend", "torch"]) == 0
    out = capsys.readouterr().out
    assert "averaged into the reference frames" in out and "bin Fz mN" in out and "false contacts" in out


def test_cli_eval_without_camera_images(tmp_path, write_bag, sensor, sim_frames, model_dir, capsys):
    write_bag(tmp_path / "bag", sensor, sim_frames[:3], images=False)
    assert main(["eval", str(tmp_path / "bag"), "--model", str(model_dir), "--backend", "torch"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "has no camera images on ['/tactile/cam0/image'" in err[0]


@pytest.mark.parametrize("bag, says", [("missing", "does not exist"), ("not_a_bag", "has no metadata.yaml")])
def test_cli_eval_bad_bag(tmp_path, model_dir, capsys, bag, says):
    """A directory without metadata.yaml (its .mcap alone): rosbags' message named the directory as the missing
    "metadata file" (found by a walkthrough)."""
    (tmp_path / "not_a_bag").mkdir()
    assert main(["eval", str(tmp_path / bag), "--model", str(model_dir), "--backend", "torch"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"tactile-bag eval: error: bag {tmp_path / bag} {says}"), err


def test_cli_eval_model_of_another_sensor(sim_bag, model_dir, capsys):
    skin = default_sensor_path().parent / "skin_3x3.yaml"
    assert main(["eval", str(sim_bag), "--model", str(model_dir), "--backend", "torch", "--sensor", str(skin)]) == 2
    assert "use the model and the sensor description of the same sensor (--model, --sensor)" in capsys.readouterr().err


def test_unusable_images_leave_their_camera_out(sensor, sim_frames):
    reader = FrameReader(sensor, 128)
    stamp = seconds_to_time(1.0)
    good = mono8_to_msg(sim_frames[0].images[0], stamp, "cam0_optical")
    small = mono8_to_msg(np.zeros((64, 64), np.uint8), stamp, "cam1_optical")
    bad = mono8_to_msg(sim_frames[0].images[2], stamp, "cam2_optical")
    bad.encoding = "16UC1"
    frame = reader.frame(1.0, ["cam0", "cam1", "cam2"], [good, small, bad])
    np.testing.assert_array_equal(frame.camera_ok, [True, False, False, False])
    np.testing.assert_array_equal(frame.images[0], sim_frames[0].images[0])
    assert not frame.images[1:].any() and not frame.unusable
    assert reader.skipped == {"cam1 image of 64 x 64 pixels": 1, "unreadable image of cam2": 1}
    of_another_sensor = reader.frame(1.0, ["cam0", "cam9"], [good, good])
    assert of_another_sensor.unusable and not of_another_sensor.camera_ok.any()
    assert reader.skipped["bundle of another sensor"] == 1


def test_a_named_truth_topic_must_be_in_the_bag(sim_bag, model_dir, capsys):
    assert main(["eval", str(sim_bag), "--model", str(model_dir), "--backend", "torch", "--truth-topic",
                 "/tactile/truth"]) == 2
    assert "has no topic /tactile/truth; its topics are" in capsys.readouterr().err
    # an empty name was taken for the default topic without a word (review)
    assert main(["eval", str(sim_bag), "--model", str(model_dir), "--backend", "torch", "--truth-topic", ""]) == 2
    assert "topic name '' is empty; give e.g. /tactile/ground_truth/force_distribution" in capsys.readouterr().err


def test_images_of_cameras_the_description_does_not_name_are_named_not_evaluated(tmp_path, write_bag, sensor,
                                                                                 sim_frames, model_dir, capsys):
    """Five more cameras' images in the bag were left out without a word (review); now the summary and stderr name
    their topics."""
    write_bag(tmp_path / "clean", sensor, sim_frames)
    stray = serialize_message(mono8_to_msg(sim_frames[0].images[0], Time(sec=1_700_000_000), "cam4_optical"))
    with BagReader(tmp_path / "clean") as clean, BagWriter(tmp_path / "bag") as bag:
        for topic, _, time_ns, raw in clean.messages(list(clean.topics)):
            bag.write(topic, clean.topics[topic], time_ns, raw)
        for camera in ("cam4", "cam5"):
            bag.write(camera_topic(camera), IMAGE_TYPE, 1_700_000_000 * 10**9, stray)
    assert main(["eval", str(tmp_path / "bag"), "--model", str(model_dir), "--backend", "torch", "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["other_image_topics"] == ["/tactile/cam4/image", "/tactile/cam5/image"]
    assert "tactile-bag eval: the bag also holds images on /tactile/cam4/image, /tactile/cam5/image, not evaluated: " \
        "the cameras of another sensor description than" in err
    assert main(["eval", str(tmp_path / "clean"), "--model", str(model_dir), "--backend", "torch", "--json"]) == 0
    out, err = capsys.readouterr()
    assert json.loads(out)["other_image_topics"] == [] and "also holds images" not in err


def test_a_bag_of_two_sensors_graphs_is_evaluated_one_namespace_at_a_time(tmp_path, write_bag, sensor, sim_frames,
                                                                          model_dir, capsys):
    """Two sensors on one robot, each graph in a namespace (docs/nodes.md): `--namespace` evaluates one graph's images
    or bundles against its own ground truth, as the same frames in the root namespace; without it the bag is refused,
    naming the namespaces it holds."""
    write_bag(tmp_path / "root", sensor, sim_frames, bundles=True)
    write_bag(tmp_path / "two", sensor, sim_frames, bundles=True, namespaces=("/left", "/right"))
    args = ["--model", str(model_dir), "--backend", "torch", "--json"]
    for source in ("images", "bundles"):
        assert main(["eval", str(tmp_path / "root"), "--source", source, *args]) == 0
        root = json.loads(capsys.readouterr().out)
        for namespace, other in (("left", "right"), ("/right", "left")):
            assert main(["eval", str(tmp_path / "two"), "--namespace", namespace, "--source", source, *args]) == 0
            summary = json.loads(capsys.readouterr().out)
            assert summary["matched_with_ground_truth"] == root["matched_with_ground_truth"] >= 29, summary
            assert summary["rmse_bin_n"] == pytest.approx(root["rmse_bin_n"], rel=1e-6, abs=1e-9)
            assert summary["rmse_total_n"] == pytest.approx(root["rmse_total_n"], rel=1e-6, abs=1e-9)
            assert summary["other_image_topics"] == [f"/{other}/tactile/{c}/image" for c in sensor.camera_ids]
    assert main(["eval", str(tmp_path / "two"), *args]) == 2
    err = capsys.readouterr().err
    assert "has no camera images on ['/tactile/cam0/image', '/tactile/cam1/image'" in err
    assert "and no image bundles on /tactile/image_bundle" in err
    assert "the bag holds the topics of graphs in the namespaces ['/left', '/right'] (--namespace)" in err


def test_record_and_eval_refuse_a_namespace_ros_would_refuse(tmp_path, model_dir, capsys):
    for command in (["record", str(tmp_path / "bag"), "--duration", "1"], ["eval", str(tmp_path / "bag")]):
        with pytest.raises(SystemExit) as stop:
            main([*command, "--namespace", "left arm"])
        assert stop.value.code == 2
        assert "argument --namespace: namespace 'left arm': not a ROS namespace" in capsys.readouterr().err
    assert not (tmp_path / "bag").exists()
