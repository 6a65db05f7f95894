"""Frames for training and evaluation: from the simulator (streamed) or a written dataset, checked against
the sensor description, and split 70/10/20 deterministically from the scene's seed.
"""

from __future__ import annotations

import hashlib
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from tactile_description import SensorDescription
from tactile_description.value_checks import is_whole_number
from tactile_sim import DatasetError, Scene, SceneError, Simulator, open_dataset
from tactile_sim.contact import ground_truth_model
from tactile_sim.dataset import check_made_for

#: Train / validation / test fractions (the paper's split).
SPLIT_FRACTIONS = (0.7, 0.1, 0.2)
SPLITS = ("train", "val", "test")


class DatasetMismatchError(ValueError):
    """Frames that do not fit the sensor description (camera count or ids, bin grid, image size)."""


class FrameDataError(ValueError):
    """Frames that cannot be trained or evaluated on: too few to split, or ground-truth forces that are NaN or Inf (the
    message names the data and what to do)."""


@dataclass(frozen=True)
class FrameSet:
    """Frames held in memory (or memory-mapped): images, their reference frames and ground-truth forces."""

    images: np.ndarray        # (N, C, H, W) uint8
    bin_forces_n: np.ndarray  # (N, rows, cols, 3) float32, newtons
    reference: np.ndarray     # (C, H, W) uint8, the no-contact frames
    camera_ok: np.ndarray     # (N, C) bool, False for a dropped or frozen camera
    camera_ids: tuple[str, ...]
    scene: str = ""
    seed: int = 0

    def __len__(self) -> int:
        return int(self.images.shape[0])

    def first(self, n: int | None) -> FrameSet:
        """The first `n` frames (all of them when None or more), as views: a memory-mapped dataset stays mapped."""
        return replace(self, images=self.images[:n], bin_forces_n=self.bin_forces_n[:n],
                       camera_ok=self.camera_ok[:n])

    def subset(self, indices: np.ndarray) -> FrameSet:
        """The frames at `indices` (loaded into memory)."""
        indices = np.asarray(indices)
        return replace(self, images=np.ascontiguousarray(self.images[indices]),
                       bin_forces_n=np.ascontiguousarray(self.bin_forces_n[indices]),
                       camera_ok=np.ascontiguousarray(self.camera_ok[indices]))

    def select_cameras(self, camera_ids: tuple[str, ...] | list[str]) -> FrameSet:
        """The same frames seen by `camera_ids` only, in that order."""
        unknown = [c for c in camera_ids if c not in self.camera_ids]
        if unknown:
            raise DatasetMismatchError(f"cameras {unknown} are not in these frames (cameras {list(self.camera_ids)})")
        if tuple(camera_ids) == self.camera_ids:
            return self
        pick = [self.camera_ids.index(c) for c in camera_ids]
        return replace(self, images=np.ascontiguousarray(self.images[:, pick]), reference=self.reference[pick],
                       camera_ok=np.ascontiguousarray(self.camera_ok[:, pick]), camera_ids=tuple(camera_ids))


def split_indices(n_frames: int, seed: int, fractions: tuple[float, float, float] = SPLIT_FRACTIONS) -> dict:
    """Deterministic 70/10/20 split of frame indices: a permutation drawn from `seed`, cut in three.

    Returns {"train": idx, "val": idx, "test": idx}, each sorted. Every split gets at least one frame when
    n_frames >= 3; fewer raise FrameDataError.
    """
    if n_frames < 3:
        raise FrameDataError(f"a train/val/test split needs at least 3 frames, got {n_frames}: use more frames")
    order = np.random.default_rng(seed).permutation(n_frames)
    n_val = max(1, round(fractions[1] * n_frames))
    n_test = max(1, round(fractions[2] * n_frames))
    n_train = n_frames - n_val - n_test
    cuts = {"train": order[:n_train], "val": order[n_train:n_train + n_val], "test": order[n_train + n_val:]}
    return {name: np.sort(idx) for name, idx in cuts.items()}


def first_frames_split(total: int, seed: int, frames: int | None = None) -> dict:
    """The 70/10/20 `split_indices` of the first `frames` of `total` frames (of all of them when None, or when
    `frames` exceeds `total`), drawn from `seed`: the split that training makes of a scene or dataset."""
    return split_indices(total if frames is None else min(frames, total), seed)


def split_frames(frames: FrameSet, n_frames: int | None = None) -> dict[str, FrameSet]:
    """The 70/10/20 split of `frames` (of its first `n_frames` when given) drawn from its seed, each split copied
    into memory: {"train": ..., "val": ..., "test": ...}."""
    return {name: frames.subset(idx) for name, idx in first_frames_split(len(frames), frames.seed, n_frames).items()}


def forces_sha256(*forces: np.ndarray) -> str:
    """Hex SHA-256 of float32 force arrays, one after the other: which frames (and in which order) some data holds, as
    training.json and the checkpoints record it."""
    digest = hashlib.sha256()
    for array in forces:
        digest.update(np.ascontiguousarray(array, dtype=np.float32))
    return digest.hexdigest()


#: Frames whose forces are checked for NaN or Inf at a time (a memory-mapped dataset's need not fit in memory).
FINITE_CHECK_FRAMES = 4096


def first_non_finite_frame(forces: np.ndarray) -> int | None:
    """Index of the first frame of (N, rows, cols, 3) forces that holds a NaN or Inf; None when all are finite."""
    for start in range(0, len(forces), FINITE_CHECK_FRAMES):
        chunk = np.asarray(forces[start:start + FINITE_CHECK_FRAMES])
        bad = ~np.isfinite(chunk.reshape(len(chunk), -1)).all(axis=1)
        if bad.any():
            return start + int(np.argmax(bad))
    return None


def check_finite_targets(**frame_sets: FrameSet) -> None:
    """Raise FrameDataError unless every ground-truth force of the named frame sets (e.g. train=..., val=...) is
    finite: a NaN trains a model whose validation error is NaN, and that keeps its random weights."""
    for name, frames in frame_sets.items():
        bad = first_non_finite_frame(frames.bin_forces_n)
        if bad is not None:
            raise FrameDataError(f"the {name} frames of {frames.scene or 'the data'} (seed {frames.seed}) hold NaN or "
                                 f"Inf forces, first in frame {bad} of them: a model cannot learn from them; fix or "
                                 "regenerate the data")


def describe_splits(splits: dict[str, FrameSet]) -> dict:
    """What training.json and the recalibration study record of the data: scene, seed, frames and split sizes."""
    any_split = next(iter(splits.values()))
    return {"scene": any_split.scene, "seed": any_split.seed, "frames": sum(len(v) for v in splits.values()),
            "split_sizes": {k: len(v) for k, v in splits.items()}}


def check_frames_match_sensor(camera_ids, rows: int, cols: int, image_shape: tuple[int, int],
                              sensor: SensorDescription, what: str) -> None:
    """Raise DatasetMismatchError unless the frames' cameras, bin grid and image size are the sensor's.

    image_shape is (H, W) of the frames' images; `what` names the data in the message (e.g. the dataset path).
    """
    hint = ("regenerate the data with this sensor description (tactile-sim generate --sensor ...) or pass the "
            "sensor description the data was made with (--sensor)")
    if tuple(camera_ids) != sensor.camera_ids:
        raise DatasetMismatchError(f"{what} has cameras {list(camera_ids)} but the sensor description "
                                   f"{sensor.source or sensor.name} has {list(sensor.camera_ids)}: {hint}")
    if (rows, cols) != (sensor.grid.rows, sensor.grid.cols):
        raise DatasetMismatchError(f"{what} has a {rows} x {cols} bin grid but the sensor description "
                                   f"{sensor.source or sensor.name} has {sensor.grid.rows} x {sensor.grid.cols}: "
                                   f"{hint}")
    for cam in sensor.cameras:
        expected = (cam.output_size[1], cam.output_size[0])
        if tuple(image_shape) != expected:
            raise DatasetMismatchError(f"{what} has {image_shape[1]} x {image_shape[0]} images but camera "
                                       f"{cam.camera_id} of {sensor.source or sensor.name} outputs "
                                       f"{expected[1]} x {expected[0]}: {hint}")


def load_dataset_frames(path: str | Path, sensor: SensorDescription) -> FrameSet:
    """A dataset written by tactile_sim.write_dataset, memory-mapped, after checking it fits `sensor`."""
    ds = open_dataset(path)
    meta = ds.meta
    n, c, h, w = ds.images.shape
    check_frames_match_sensor(meta["camera_ids"], int(meta["rows"]), int(meta["cols"]), (h, w), sensor,
                              f"dataset {path}")
    if ds.forces.shape != (n, sensor.grid.rows, sensor.grid.cols, 3) or ds.reference.shape != (c, h, w):
        raise DatasetMismatchError(f"dataset {path}: forces {ds.forces.shape} / reference {ds.reference.shape} do "
                                   f"not match its {n} frames of {c} x {h} x {w} images; rewrite the dataset")
    check_made_for(ds, sensor)  # after the ids, grid and image size, whose own messages say more
    bad = first_non_finite_frame(ds.forces)
    if bad is not None:
        raise DatasetError(f"dataset {path}: forces.npy holds NaN or Inf, first in frame {bad}; the file is damaged or "
                           "was written by a broken simulation: regenerate the dataset (tactile-sim generate)")
    return FrameSet(images=ds.images, bin_forces_n=np.asarray(ds.forces, dtype=np.float32),
                    reference=np.array(ds.reference), camera_ok=np.asarray(ds.camera_ok, dtype=bool),
                    camera_ids=tuple(meta["camera_ids"]), scene=str(meta["scene"]), seed=int(meta["seed"]))


def simulate_frames(sensor: SensorDescription, scene: Scene, indices: np.ndarray | None = None,
                    progress: bool = False) -> FrameSet:
    """Stream `scene` through the simulator and keep the frames at `indices` (all when None).

    Memory is allocated once for the kept frames only, so a test split of a large scene costs 20 % of it.
    """
    keep = np.arange(len(scene)) if indices is None else np.asarray(indices)
    return simulate_splits(sensor, scene, {"frames": keep}, progress)["frames"]


def simulate_chunks(sensor: SensorDescription, scene: Scene, chunk_frames: int, progress: bool = False
                    ) -> Iterator[FrameSet]:
    """Every frame of `scene`, streamed through the simulator and handed on in FrameSets of `chunk_frames` frames (the
    last one shorter): a consumer that keeps only something of each chunk never holds the whole scene's images."""
    sim = Simulator(sensor)
    reference = sim.reference_images()
    for frame in tqdm(sim.stream(scene), total=len(scene), desc=f"simulate {scene.name} (seed {scene.seed})",
                      unit="frame", disable=not progress):
        slot = frame.index % chunk_frames
        if slot == 0:
            chunk = _empty_frames(sensor, scene, reference, min(chunk_frames, len(scene) - frame.index))
        _keep(chunk, slot, frame)
        if slot == len(chunk) - 1:
            yield chunk


def _empty_frames(sensor: SensorDescription, scene: Scene, reference: np.ndarray, n: int) -> FrameSet:
    """Room for `n` simulated frames of `scene`, filled by `_keep`."""
    w, h = sensor.cameras[0].output_size
    return FrameSet(images=np.empty((n, sensor.n_cameras, h, w), dtype=np.uint8),
                    bin_forces_n=np.empty((n, sensor.grid.rows, sensor.grid.cols, 3), dtype=np.float32),
                    reference=reference, camera_ok=np.empty((n, sensor.n_cameras), dtype=bool),
                    camera_ids=sensor.camera_ids, scene=scene.name, seed=scene.seed)


def _keep(frames: FrameSet, slot: int, frame) -> None:
    """A simulated frame into `frames` at `slot`."""
    frames.images[slot] = frame.images
    frames.bin_forces_n[slot] = frame.bin_forces_n
    frames.camera_ok[slot] = frame.camera_ok


#: Further draws of a training scene that the head phase learns from by default (SceneDraws; none for a dataset).
DEFAULT_EXTRA_DRAWS = 3
#: Frames per chunk of a further draw of a scene: one chunk of images is held at a time (64 MB with four cameras).
DRAW_CHUNK_FRAMES = 1024


@dataclass(frozen=True)
class SceneDraws:
    """Further draws of a simulated scene: draw k (1, 2, ...) is `scene` with seed + k, the same timeline and effects
    with other random press positions, depths and sensor noise; every frame of it (of its first frames, for a limited
    scene). Iterating simulates the draws (again, each time) and yields their frames in chunks of `DRAW_CHUNK_FRAMES`,
    seen by `camera_ids` (None: all the sensor's cameras).

    What they are for: the head phase and the least-squares fit learn from them besides the training split
    (train_phases). Their frames are new samples of the scene's own distribution, none of them a test frame. The head
    costs far less per frame than the end-to-end phase, and it needed data: the five-cycle model of 2026-11-23 fitted
    its own training frames to 1.80 mN per bin but its test frames to 2.48 (docs/learning.md).
    """

    sensor: SensorDescription
    scene: Scene | None
    draws: int
    camera_ids: tuple[str, ...] | None = None
    progress: bool = False

    def __post_init__(self):
        if not is_whole_number(self.draws, 0):
            raise ValueError(f"SceneDraws: draws must be an integer >= 0, got {self.draws!r}")
        object.__setattr__(self, "draws", int(self.draws))  # a NumPy integer would reach training.json
        if self.draws and self.scene is None:
            raise ValueError("SceneDraws: further draws need a scene to draw from")
        # Whether random presses find room depends on the seed: a draw that found none failed in the head phase, after
        # the end-to-end training (found in review). Checked here, before any frame is simulated.
        ground_truth = ground_truth_model(self.sensor)  # the simulator's default model
        for k in range(1, self.draws + 1):
            draw = self.draw(k)
            try:
                draw.check_playable(self.sensor, ground_truth)
            except SceneError as exc:  # it read as the scene's own fault, which generate and render play (walkthrough)
                raise SceneError(f"further draw {k} of scene {self.scene.name!r} for the head phase (its seed "
                                 f"{draw.seed}): {exc}; leave the further draws out (--head-extra-draws 0), or give "
                                 "the random presses more room") from exc

    @classmethod
    def none(cls, sensor: SensorDescription) -> SceneDraws:
        """No further draws: the head phase learns from the training split alone (a dataset, or draws turned off)."""
        return cls(sensor, None, 0)

    def __len__(self) -> int:
        return self.draws * len(self.scene) if self.draws else 0

    def draw(self, k: int) -> Scene:
        """Draw k: the scene with seed + k."""
        return replace(self.scene, seed=self.scene.seed + k)

    def __iter__(self) -> Iterator[FrameSet]:
        for k in range(1, self.draws + 1):
            for chunk in simulate_chunks(self.sensor, self.draw(k), DRAW_CHUNK_FRAMES, self.progress):
                yield chunk if self.camera_ids is None else chunk.select_cameras(self.camera_ids)

    def select_cameras(self, camera_ids: tuple[str, ...] | list[str]) -> SceneDraws:
        """The same draws seen by `camera_ids` only, in that order."""
        return replace(self, camera_ids=tuple(camera_ids))

    def describe(self) -> dict:
        """What training.json records of them: scene, the seed of each draw, frames in all."""
        if not self.draws:
            return {"draws": 0, "frames": 0}
        return {"draws": self.draws, "scene": self.scene.name, "seeds": [self.scene.seed + k
                                                                         for k in range(1, self.draws + 1)],
                "frames": len(self)}


def simulate_splits(sensor: SensorDescription, scene: Scene, splits: dict[str, np.ndarray],
                    progress: bool = False) -> dict[str, FrameSet]:
    """Stream `scene` through the simulator once and keep the frames at each split's indices in a FrameSet of its
    own: {name: frames}. The streamed frames go straight into their split, so training holds a scene once, not as a
    whole and again as copies of its parts."""
    slots = {}  # frame index -> (split name, position in that split)
    for name, idx in splits.items():
        for slot, frame in enumerate(np.asarray(idx).tolist()):
            # A frame past the scene's end, or kept twice, left its place in the split unfilled: np.empty's NaN and
            # Inf forces (found in review).
            if not (is_whole_number(frame, low=0) and frame < len(scene)) or frame in slots:
                raise ValueError(f"simulate_splits: split {name!r} holds frame {frame!r}, which is "
                                 f"{'kept twice' if frame in slots else 'not a frame'} of the {len(scene)}-frame scene "
                                 f"{scene.name!r}: each index must be a whole number in [0, {len(scene)}), once")
            slots[int(frame)] = (name, slot)
    sim = Simulator(sensor)
    kept = {name: _empty_frames(sensor, scene, sim.reference_images(), len(idx)) for name, idx in splits.items()}
    last = max(slots) + 1 if slots else 0
    stream = sim.stream(scene, frames=last) if last else iter(())
    for frame in tqdm(stream, total=last, desc=f"simulate {scene.name}", unit="frame", disable=not progress):
        if frame.index in slots:
            name, slot = slots[frame.index]
            _keep(kept[name], slot, frame)
    return kept
