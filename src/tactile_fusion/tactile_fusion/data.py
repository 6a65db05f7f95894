"""Frames for training and evaluation: from the simulator (streamed) or a written dataset, checked against
the sensor description, and split 70/10/20 deterministically from the scene's seed.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from tactile_description import SensorDescription
from tactile_sim import Scene, Simulator, open_dataset

#: Train / validation / test fractions (the paper's split).
SPLIT_FRACTIONS = (0.7, 0.1, 0.2)
SPLITS = ("train", "val", "test")


class DatasetMismatchError(ValueError):
    """Frames that do not fit the sensor description (camera count or ids, bin grid, image size)."""


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
        pick = [self.camera_ids.index(c) for c in camera_ids]
        return replace(self, images=np.ascontiguousarray(self.images[:, pick]), reference=self.reference[pick],
                       camera_ok=np.ascontiguousarray(self.camera_ok[:, pick]), camera_ids=tuple(camera_ids))


def split_indices(n_frames: int, seed: int, fractions: tuple[float, float, float] = SPLIT_FRACTIONS) -> dict:
    """Deterministic 70/10/20 split of frame indices: a permutation drawn from `seed`, cut in three.

    Returns {"train": idx, "val": idx, "test": idx}, each sorted. Every split gets at least one frame when
    n_frames >= 3.
    """
    if n_frames < 3:
        raise ValueError(f"split_indices: need at least 3 frames for a train/val/test split, got {n_frames}")
    order = np.random.default_rng(seed).permutation(n_frames)
    n_val = max(1, round(fractions[1] * n_frames))
    n_test = max(1, round(fractions[2] * n_frames))
    n_train = n_frames - n_val - n_test
    cuts = {"train": order[:n_train], "val": order[n_train:n_train + n_val], "test": order[n_train + n_val:]}
    return {name: np.sort(idx) for name, idx in cuts.items()}


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
    return FrameSet(images=ds.images, bin_forces_n=np.asarray(ds.forces, dtype=np.float32),
                    reference=np.asarray(ds.reference), camera_ok=np.asarray(ds.camera_ok, dtype=bool),
                    camera_ids=tuple(meta["camera_ids"]), scene=str(meta["scene"]), seed=int(meta["seed"]))


def simulate_frames(sensor: SensorDescription, scene: Scene, indices: np.ndarray | None = None,
                    progress: bool = False) -> FrameSet:
    """Stream `scene` through the simulator and keep the frames at `indices` (all when None).

    Memory is allocated once for the kept frames only, so a test split of a large scene costs 20 % of it.
    """
    sim = Simulator(sensor)
    n_total = len(scene)
    keep = np.arange(n_total) if indices is None else np.asarray(indices)
    slot = np.full(n_total, -1)
    slot[keep] = np.arange(len(keep))
    c = sensor.n_cameras
    w, h = sensor.cameras[0].output_size
    images = np.empty((len(keep), c, h, w), dtype=np.uint8)
    forces = np.empty((len(keep), sensor.grid.rows, sensor.grid.cols, 3), dtype=np.float32)
    camera_ok = np.empty((len(keep), c), dtype=bool)
    last = int(keep.max()) + 1 if len(keep) else 0
    stream = sim.stream(scene, frames=last) if last else iter(())
    for frame in tqdm(stream, total=last, desc=f"simulate {scene.name}", unit="frame", disable=not progress):
        if slot[frame.index] >= 0:
            images[slot[frame.index]] = frame.images
            forces[slot[frame.index]] = frame.bin_forces_n
            camera_ok[slot[frame.index]] = frame.camera_ok
    return FrameSet(images=images, bin_forces_n=forces, reference=sim.reference_images(), camera_ok=camera_ok,
                    camera_ids=sensor.camera_ids, scene=scene.name, seed=scene.seed)
