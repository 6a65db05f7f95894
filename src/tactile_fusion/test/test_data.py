"""Frames from the simulator and from written datasets, the deterministic split, and sensor mismatch errors."""

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tactile_description import load_sensor
from tactile_fusion import data, pipeline
from tactile_fusion.artifacts import default_model_dir
from tactile_fusion.data import (
    SPLITS,
    DatasetMismatchError,
    FrameDataError,
    SceneDraws,
    check_finite_targets,
    check_frames_match_sensor,
    first_frames_split,
    first_non_finite_frame,
    load_dataset_frames,
    simulate_frames,
    simulate_splits,
    split_frames,
    split_indices,
)
from tactile_fusion.pipeline import further_draws, held_out_split, scene_frames, training_splits
from tactile_sim import DatasetError, SceneError, Simulator, load_scene, write_dataset

CONFIG = Path(__file__).resolve().parents[3] / "config"


@pytest.fixture(scope="module")
def sensor():
    return load_sensor(CONFIG / "sensor.yaml")


def test_split_is_70_10_20_disjoint_complete_and_deterministic():
    split = split_indices(1000, seed=7)
    assert [len(split[k]) for k in ("train", "val", "test")] == [700, 100, 200]
    everything = np.concatenate([split["train"], split["val"], split["test"]])
    assert sorted(everything) == list(range(1000))
    again = split_indices(1000, seed=7)
    assert all(np.array_equal(split[k], again[k]) for k in split)
    assert not np.array_equal(split["test"], split_indices(1000, seed=8)["test"])
    tiny = split_indices(3, seed=0)
    assert all(len(tiny[k]) == 1 for k in tiny)
    with pytest.raises(ValueError, match="at least 3 frames"):
        split_indices(2, seed=0)


def test_the_split_of_the_first_frames_is_that_of_those_frames():
    assert all(np.array_equal(first_frames_split(100, 7, 30)[k], split_indices(30, 7)[k]) for k in SPLITS)
    assert all(np.array_equal(first_frames_split(100, 7, 500)[k], split_indices(100, 7)[k]) for k in SPLITS)
    assert all(np.array_equal(first_frames_split(100, 7)[k], split_indices(100, 7)[k]) for k in SPLITS)
    with pytest.raises(FrameDataError, match="needs at least 3 frames, got 2"):
        first_frames_split(100, 7, 2)


def test_every_command_keeps_the_frames_it_took_of_the_default_scene(sensor, monkeypatch, tmp_path):
    """The shipped model's test set (eval without --scene, and its test's first 150 frames) and a scene's test split
    are the test split of the whole scene, their first frames when fewer; training on the first N frames splits
    those. Captured where the frames would be simulated."""
    scene = load_scene("paper_grid", sensor)
    whole = split_indices(len(scene), scene.seed)
    asked = []
    monkeypatch.setattr(pipeline, "simulate_frames", lambda sensor, scene, picks, progress=False: asked.append(picks))
    monkeypatch.setattr(pipeline, "simulate_splits", lambda sensor, scene, splits, progress=False: asked.append(splits))
    scene_frames(sensor, "paper_grid", "test", 150)
    held_out_split(default_model_dir(), sensor, "test", 150)  # the shipped model's training.json
    held_out_split(tmp_path, sensor, "test", 150)             # none: the default scene's
    held_out_split(default_model_dir(), sensor, "val")
    training_splits(sensor, "paper_grid", None, 130, False)
    for picks in asked[:3]:
        np.testing.assert_array_equal(picks, whole["test"][:150])
    np.testing.assert_array_equal(asked[3], whole["val"])
    assert all(np.array_equal(asked[4][k], split_indices(130, scene.seed)[k]) for k in SPLITS)


def test_simulated_frames_keep_only_the_requested_indices(sensor):
    scene = load_scene("paper_grid", sensor)
    every = simulate_frames(sensor, scene, np.arange(130))
    picked = simulate_frames(sensor, scene, np.array([3, 121, 127]))
    assert picked.images.shape == (3, 4, 128, 128) and picked.images.dtype == np.uint8
    assert picked.bin_forces_n.shape == (3, 26, 25, 3) and picked.bin_forces_n.dtype == np.float32
    np.testing.assert_array_equal(picked.images, every.images[[3, 121, 127]])
    np.testing.assert_array_equal(picked.bin_forces_n, every.bin_forces_n[[3, 121, 127]])
    assert picked.camera_ids == sensor.camera_ids and picked.seed == scene.seed and picked.scene == "paper_grid"
    assert every.bin_forces_n[125:, :, :, 2].sum() > 0  # presses after the rest frames


def test_splits_are_simulated_in_one_stream_and_equal_the_split_of_the_whole(sensor):
    scene = load_scene("paper_grid", sensor)
    every = simulate_frames(sensor, scene, np.arange(130))
    parts = simulate_splits(sensor, scene, {"late": np.array([127, 121]), "early": np.array([3])})
    np.testing.assert_array_equal(parts["late"].images, every.images[[127, 121]])
    np.testing.assert_array_equal(parts["early"].bin_forces_n, every.bin_forces_n[[3]])
    np.testing.assert_array_equal(parts["early"].reference, every.reference)
    # `tactile-fusion train --frames 130`: the same frames as splitting the first 130 frames afterwards.
    trained_on, split_after = training_splits(sensor, "paper_grid", None, 130, False), split_frames(every)
    assert [len(trained_on[k]) for k in ("train", "val", "test")] == [91, 13, 26]
    for name, part in split_after.items():
        np.testing.assert_array_equal(trained_on[name].images, part.images)
        np.testing.assert_array_equal(trained_on[name].bin_forces_n, part.bin_forces_n)
        np.testing.assert_array_equal(trained_on[name].camera_ok, part.camera_ok)


def test_splits_refuse_frames_past_the_scene_or_kept_twice(sensor):
    """Both left a place of the split unfilled: NaN and Inf forces from np.empty (found in review)."""
    scene = load_scene("paper_grid", sensor).limited(3)
    with pytest.raises(ValueError, match=r"split 'a' holds frame 7, which is not a frame of the 3-frame scene "
                                         r"'paper_grid': each index must be a whole number in \[0, 3\), once"):
        simulate_splits(sensor, scene, {"a": np.array([0, 7])})
    with pytest.raises(ValueError, match="split 'b' holds frame 1, which is kept twice"):
        simulate_splits(sensor, scene, {"a": np.array([1]), "b": np.array([1])})
    with pytest.raises(ValueError, match="frame -1, which is not a frame"):
        simulate_frames(sensor, scene, np.array([-1]))


def test_further_draws_are_the_scene_with_the_next_seeds_in_chunks(sensor, monkeypatch):
    scene = load_scene("paper_grid", sensor).limited(130)  # 120 frames at rest, then 10 presses
    monkeypatch.setattr(data, "DRAW_CHUNK_FRAMES", 50)
    draws = SceneDraws(sensor, scene, 2)
    chunks = list(draws)
    assert [len(c) for c in chunks] == [50, 50, 30] * 2 and len(draws) == 260
    assert [c.seed for c in chunks] == [scene.seed + 1] * 3 + [scene.seed + 2] * 3
    for k, first in ((1, 0), (2, 3)):
        drawn = simulate_frames(sensor, replace(scene, seed=scene.seed + k))
        np.testing.assert_array_equal(np.concatenate([c.images for c in chunks[first:first + 3]]), drawn.images)
        np.testing.assert_array_equal(np.concatenate([c.bin_forces_n for c in chunks[first:first + 3]]),
                                      drawn.bin_forces_n)
        np.testing.assert_array_equal(np.concatenate([c.camera_ok for c in chunks[first:first + 3]]),
                                      drawn.camera_ok)
    own = simulate_frames(sensor, scene)
    # Other presses than the scene's own (other positions and depths), on the same reference images.
    assert not np.array_equal(chunks[2].bin_forces_n, own.bin_forces_n[100:])
    np.testing.assert_array_equal(chunks[0].reference, own.reference)
    assert draws.describe() == {"draws": 2, "scene": "paper_grid", "seeds": [scene.seed + 1, scene.seed + 2],
                                "frames": 260}
    two = draws.select_cameras(("cam2", "cam0"))
    picked = next(iter(two))
    assert picked.camera_ids == ("cam2", "cam0")
    np.testing.assert_array_equal(picked.images, chunks[0].images[:, [2, 0]])
    assert list(SceneDraws.none(sensor)) == [] and SceneDraws.none(sensor).describe() == {"draws": 0, "frames": 0}
    with pytest.raises(ValueError, match="draws must be an integer >= 0"):
        SceneDraws(sensor, scene, -1)
    with pytest.raises(ValueError, match="further draws need a scene"):
        SceneDraws(sensor, None, 1)
    # On a 28 mm wide surface multi_contact's random presses find room with its seed and seeds + 1 and + 2, not + 3:
    # the third draw failed in the head phase, after the end-to-end training (found in review).
    narrow = replace(sensor, grid=replace(sensor.grid, width_m=28e-3))
    assert len(SceneDraws(narrow, load_scene("multi_contact"), 2)) == 2 * 242
    # It named the scene alone, which generate and render play (walkthrough).
    seed = load_scene("multi_contact").seed + 3
    with pytest.raises(SceneError, match=rf"further draw 3 of scene 'multi_contact' for the head phase \(its seed "
                                         rf"{seed}\): .*multi_contact.yaml.timeline\[2\].random_presses: frame \d+ of "
                                         r"the segment found room for only 3 of 4.*; leave the further draws out "
                                         r"\(--head-extra-draws 0\), or give the random presses more room"):
        SceneDraws(narrow, load_scene("multi_contact"), 3)
    from_numpy = SceneDraws(sensor, scene.limited(np.int64(5)), np.int64(1))  # as an array's length or index gives
    assert json.loads(json.dumps(from_numpy.describe())) == {"draws": 1, "scene": "paper_grid",
                                                             "seeds": [scene.seed + 1], "frames": 5}


def test_further_draws_of_the_training_data_as_the_command_line_resolves_them(sensor):
    assert len(further_draws(sensor, "paper_grid", None, 130, None, False)) == 3 * 130  # three draws by default
    assert further_draws(sensor, None, None, None, 2, False).describe()["frames"] == 2 * 46200
    assert len(further_draws(sensor, None, "some/dataset", None, None, False)) == 0  # a dataset: none by default
    with pytest.raises(ValueError, match="a dataset cannot be drawn again"):
        further_draws(sensor, None, "some/dataset", None, 1, False)


def test_dataset_written_by_the_simulator_loads_and_a_mismatch_is_explained(sensor, tmp_path):
    sim = Simulator(sensor)
    path = write_dataset(sim, load_scene("paper_grid", sensor), tmp_path / "ds", progress=False, frames=6)
    frames = load_dataset_frames(path, sensor)
    assert len(frames) == 6 and frames.camera_ids == sensor.camera_ids and frames.scene == "paper_grid"
    assert frames.reference.flags.writeable  # torch warns about (and must not write into) a read-only array
    first_five = split_frames(frames, 5)
    assert sum(len(part) for part in first_five.values()) == 5 and first_five["test"].seed == frames.seed
    skin = load_sensor(CONFIG / "skin_3x3.yaml")
    with pytest.raises(DatasetMismatchError, match=r"cameras \['cam0', 'cam1', 'cam2', 'cam3'\].*regenerate"):
        load_dataset_frames(path, skin)
    # Same camera ids, grid and image size, another sensor (a softer gel): its images and forces are not this
    # sensor's. Only ids, grid and image size were compared, and it trained a model without a word (found in review).
    softer = replace(sensor, name="softer", gel_layers=tuple(
        replace(layer, youngs_modulus_pa=layer.youngs_modulus_pa / 2) for layer in sensor.gel_layers))
    with pytest.raises(DatasetError, match=rf"{path} was made for sensor '{sensor.name}' with another description "
                                           rf"than {sensor.source} \(differing: gel_layers\[transparent_base\]"
                                           r".youngs_modulus_pa, gel_layers\[particle_layer\].youngs_modulus_pa, "
                                           r"gel_layers\[protective_top\].youngs_modulus_pa\); pass the sensor "
                                           r"description it was made with \(--sensor\), or regenerate it"):
        load_dataset_frames(path, softer)
    # A renamed copy at another frame rate is the same sensor to its images: its data sets are taken (a hash of the
    # whole description refused them, naming nothing that differed; found by the docs walkthrough).
    assert len(load_dataset_frames(path, replace(sensor, name="my_copy", frame_rate_hz=30.0))) == 6


def test_a_dataset_with_non_finite_forces_is_refused_naming_the_file_and_the_frame(sensor, tmp_path):
    path = write_dataset(Simulator(sensor), load_scene("paper_grid", sensor), tmp_path / "ds", progress=False, frames=5)
    forces = np.load(path / "forces.npy")
    forces[3, 2, 1, 2] = np.nan
    np.save(path / "forces.npy", forces)
    with pytest.raises(DatasetError, match=r"ds: forces.npy holds NaN or Inf, first in frame 3; .*regenerate"):
        load_dataset_frames(path, sensor)


def test_non_finite_targets_are_found_in_any_chunk_and_named(frames, monkeypatch):
    monkeypatch.setattr(data, "FINITE_CHECK_FRAMES", 4)
    assert first_non_finite_frame(frames.bin_forces_n) is None
    check_finite_targets(training=frames)
    broken = frames.subset(np.arange(len(frames)))
    broken.bin_forces_n[9, 0, 0, 0], broken.bin_forces_n[13, 2, 3, 2] = np.inf, np.nan
    assert first_non_finite_frame(broken.bin_forces_n) == 9
    with pytest.raises(FrameDataError, match="validation frames of synthetic .* NaN or Inf forces, first in frame 9"):
        check_finite_targets(training=frames, validation=broken)


def test_the_first_frames_are_views_of_the_same_data(frames):
    first = frames.first(5)
    assert len(first) == 5 and np.shares_memory(first.images, frames.images)
    np.testing.assert_array_equal(first.bin_forces_n, frames.bin_forces_n[:5])
    assert len(frames.first(None)) == len(frames.first(1000)) == len(frames)


def test_mismatched_grid_and_image_size_are_named(sensor):
    with pytest.raises(DatasetMismatchError, match="10 x 10 bin grid.*26 x 25"):
        check_frames_match_sensor(sensor.camera_ids, 10, 10, (128, 128), sensor, "data X")
    with pytest.raises(DatasetMismatchError, match="64 x 64 images.*outputs 128 x 128"):
        check_frames_match_sensor(sensor.camera_ids, 26, 25, (64, 64), sensor, "data X")
    check_frames_match_sensor(sensor.camera_ids, 26, 25, (128, 128), sensor, "data X")  # the matching case passes


def test_select_cameras_reorders_and_rejects_unknown_ids(frames):
    picked = frames.select_cameras(("right",))
    np.testing.assert_array_equal(picked.images[:, 0], frames.images[:, 1])
    np.testing.assert_array_equal(picked.reference[0], frames.reference[1])
    with pytest.raises(DatasetMismatchError, match="cam7"):
        frames.select_cameras(("cam7",))
    assert frames.select_cameras(frames.camera_ids) is frames  # the same cameras: no copy of the images
