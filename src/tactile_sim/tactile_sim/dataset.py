"""Simulated data sets on disk: a directory of .npy arrays plus meta.json, written frame by frame.

Format (version 2), for N frames, C cameras of H x W pixels, a rows x cols bin grid:
  meta.json        format, format_version, complete, sensor_name, sensor (the description's physical fields,
                   tactile_description.made_for, as a model.json keeps them), camera_ids, rows, cols,
                   image_height, image_width, frame_count, frame_rate_hz, scene, scene_source, seed,
                   ground_truth (model name), effects (names)
  reference.npy    (C, H, W) uint8     the rest frames (no contact, no effects)
  images.npy       (N, C, H, W) uint8  every camera of every frame, after the scene's effects
  forces.npy       (N, rows, cols, 3) float32  ground-truth bin forces (fx, fy, fz), newtons, fz > 0 pressing
  camera_ok.npy    (N, C) bool         False where a camera dropped out or froze
  times_s.npy      (N,) float64        frame times
  contacts.json    list of N lists of contacts {x_mm, y_mm, depth_mm, shape, radius_mm, shear_mm, friction}
The arrays are written through np.lib.format.open_memmap, so writing a data set holds one frame in memory;
meta.json says `complete: false` until the last frame is on disk. `open_dataset` maps the arrays read-only.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from tactile_description import SensorDescription
from tactile_description.json_file import read_json
from tactile_description.made_for import changed_fields, changes_text, made_for_problem, physical_fields
from tactile_description.value_checks import is_whole_number
from tactile_sim.contact import contact_record
from tactile_sim.scene import Scene

FORMAT = "tactile_sim.dataset"
#: 2 since 2026-11-27: meta.json holds the sensor's physical description (version 1: a hash of the whole description,
#: its name included, so that a renamed copy of a sensor refused its data sets, naming nothing that differed).
FORMAT_VERSION = 2
ARRAYS = ("reference", "images", "forces", "camera_ok", "times_s")


class DatasetError(ValueError):
    """A data set directory that is missing, incomplete, corrupt or made for another sensor."""


def _write_meta(directory: Path, meta: dict) -> None:
    tmp = directory / "meta.json.tmp"
    tmp.write_text(json.dumps(meta, indent=2) + "\n")
    os.replace(tmp, directory / "meta.json")


def write_dataset(sim, scene: Scene, out_dir: str | os.PathLike, progress: bool = True,
                  frames: int | None = None, overwrite: bool = False) -> Path:
    """Stream `scene` (or its first `frames` frames) through the simulator `sim` into `out_dir`; returns the path.

    Refuses a non-empty `out_dir` unless `overwrite` and it holds a data set, complete or not: then the data set's own
    files are replaced and every other file stays. One without a data set is refused even with `overwrite`: most
    likely the wrong directory, whose files of the data set's names would be replaced.
    """
    directory = Path(out_dir)
    if directory.exists() and not directory.is_dir():
        raise DatasetError(f"output {directory} exists and is not a directory; choose another --out")
    if directory.exists() and any(directory.iterdir()):
        if not _holds_dataset(directory):
            raise DatasetError(f"output directory {directory} is not empty and holds no data set (no meta.json of a "
                               f"{FORMAT} data set); choose a new or empty one (overwrite, --overwrite, replaces a "
                               "data set only)")
        if not overwrite:
            raise DatasetError(f"output directory {directory} is not empty: it holds a data set; choose a new one or "
                               "replace it with --overwrite (overwrite=True in Python)")
    if frames is not None:
        scene = scene.limited(frames)
    stream = sim.stream(scene)  # checks the scene before the directory is made: a refusal leaves none behind
    directory.mkdir(parents=True, exist_ok=True)
    sensor = sim.sensor
    n, c = len(scene), sensor.n_cameras
    height, width = sim.image_shape
    meta = {
        "format": FORMAT, "format_version": FORMAT_VERSION, "complete": False,
        "sensor_name": sensor.name, "sensor": physical_fields(sensor), "camera_ids": list(sensor.camera_ids),
        "rows": sensor.grid.rows, "cols": sensor.grid.cols, "image_height": height, "image_width": width,
        "frame_count": n, "frame_rate_hz": sensor.frame_rate_hz, "scene": scene.name,
        "scene_source": scene.source, "seed": scene.seed, "ground_truth": sim.ground_truth.name,
        "effects": [e.name for e in scene.effects],
    }
    _write_meta(directory, meta)
    np.save(directory / "reference.npy", sim.reference_images())
    images = _reserved_array(directory / "images.npy", np.uint8, (n, c, height, width))
    forces = _reserved_array(directory / "forces.npy", np.float32, (n, sensor.grid.rows, sensor.grid.cols, 3))
    camera_ok = _reserved_array(directory / "camera_ok.npy", bool, (n, c))
    times = _reserved_array(directory / "times_s.npy", np.float64, (n,))
    with (directory / "contacts.json.tmp").open("w") as contacts_file:
        contacts_file.write("[\n")
        for frame in tqdm(stream, total=n, disable=not progress, desc=f"{scene.name} -> {directory}",
                          unit="frame"):
            i = frame.index
            images[i] = frame.images
            forces[i] = frame.bin_forces_n
            camera_ok[i] = frame.camera_ok
            times[i] = frame.time_s
            separator = ",\n" if i + 1 < n else "\n"
            contacts_file.write(json.dumps([contact_record(k) for k in frame.contacts]) + separator)
        contacts_file.write("]\n")
    for array in (images, forces, camera_ok, times):
        array.flush()
    del images, forces, camera_ok, times
    os.replace(directory / "contacts.json.tmp", directory / "contacts.json")
    meta["complete"] = True
    _write_meta(directory, meta)
    return directory


def _reserved_array(path: Path, dtype, shape: tuple[int, ...]) -> np.memmap:
    """A new .npy file of `shape`, memory-mapped for writing, with its disk space reserved now. A memory-mapped file
    is created sparse: on a disk that fills while the frames are written, the write into the mapping is a SIGBUS that
    killed the process ("Bus error", no message). Reserved, a full disk is an OSError naming the file, at once."""
    array = np.lib.format.open_memmap(path, mode="w+", dtype=dtype, shape=shape)
    try:
        with open(path, "r+b") as file:
            os.posix_fallocate(file.fileno(), 0, os.fstat(file.fileno()).st_size)
    except OSError as exc:
        del array
        raise OSError(exc.errno, exc.strerror, str(path)) from exc
    return array


@dataclass(frozen=True)
class Dataset:
    """A data set opened read-only; the frame arrays are memory-mapped (see the module docstring)."""

    path: Path
    meta: dict
    reference: np.ndarray   # (C, H, W) uint8
    images: np.ndarray      # (N, C, H, W) uint8
    forces: np.ndarray      # (N, rows, cols, 3) float32
    camera_ok: np.ndarray   # (N, C) bool
    times_s: np.ndarray     # (N,) float64

    def __len__(self) -> int:
        return len(self.images)

    def contacts(self) -> list[list[dict]]:
        """The contacts of every frame (read on demand: contacts.json)."""
        return _read_contacts(self.path, len(self))


def _read_json(path: Path):
    """The JSON value in `path`; DatasetError if it is missing, unreadable, not UTF-8 or not JSON."""
    return read_json(path, DatasetError, "regenerate the data set")


def _read_contacts(directory: Path, frames: int) -> list[list[dict]]:
    """contacts.json: one list of contact mappings per frame (DatasetError otherwise)."""
    path = directory / "contacts.json"
    contacts = _read_json(path)
    if not (isinstance(contacts, list) and len(contacts) == frames
            and all(isinstance(f, list) and all(isinstance(c, dict) for c in f) for f in contacts)):
        found = f"{len(contacts)} entries" if isinstance(contacts, list) else type(contacts).__name__
        raise DatasetError(f"{path} must list the contacts of each of the {frames} frames (a list of mappings per "
                           f"frame), found {found}; regenerate the data set")
    return contacts


def _holds_dataset(directory: Path) -> bool:
    """Whether `directory` holds a data set, complete or not: its meta.json, which write_dataset writes first, is one
    of this format."""
    try:
        meta = _read_json(directory / "meta.json")
    except DatasetError:
        return False
    return isinstance(meta, dict) and meta.get("format") == FORMAT


def _meta_count(meta: dict, key: str, meta_path: Path) -> int:
    value = meta.get(key)
    if not is_whole_number(value):
        raise DatasetError(f"{meta_path}: {key} must be an integer >= 1, got {value!r}; regenerate the data set")
    return value


def open_dataset(path: str | os.PathLike, sensor: SensorDescription | None = None) -> Dataset:
    """Open a data set directory written by write_dataset; with `sensor`, also check it was made for that sensor."""
    directory = Path(path)
    meta_path = directory / "meta.json"
    if not meta_path.is_file():
        raise DatasetError(f"{directory} is not a data set: no meta.json (write one with `tactile-sim generate`)")
    meta = _read_json(meta_path)
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise DatasetError(f"{meta_path} does not describe a {FORMAT} data set")
    if meta.get("format_version") != FORMAT_VERSION:
        raise DatasetError(f"{directory} has format version {meta.get('format_version')!r}; this reader knows "
                           f"version {FORMAT_VERSION}: regenerate the data set")
    if meta.get("complete") is not True:
        raise DatasetError(f"{directory} is incomplete (meta.json says complete: {meta.get('complete')!r}, not true: "
                           f"the writer stopped before the last frame); regenerate it")
    camera_ids = meta.get("camera_ids")
    if not (isinstance(camera_ids, list) and camera_ids and all(isinstance(i, str) for i in camera_ids)):
        raise DatasetError(f"{meta_path}: camera_ids must be a non-empty list of camera ids, got {camera_ids!r}; "
                           f"regenerate the data set")
    # Read by whoever splits the frames (tactile-fusion): a KeyError or numpy's error there before (found in review).
    if not (isinstance(meta.get("scene"), str) and is_whole_number(meta.get("seed"), 0)):
        raise DatasetError(f"{meta_path}: scene must be a name and seed a whole number >= 0, got "
                           f"{meta.get('scene')!r} and {meta.get('seed')!r}; regenerate the data set")
    n, c = _meta_count(meta, "frame_count", meta_path), len(camera_ids)
    h, w, rows, cols = (_meta_count(meta, k, meta_path) for k in ("image_height", "image_width", "rows", "cols"))
    expected = {"reference": ((c, h, w), np.uint8), "images": ((n, c, h, w), np.uint8),
                "forces": ((n, rows, cols, 3), np.float32), "camera_ok": ((n, c), np.bool_),
                "times_s": ((n,), np.float64)}
    arrays = {}
    for name in ARRAYS:
        file = directory / f"{name}.npy"
        try:
            array = np.load(file, mmap_mode="r")
        except FileNotFoundError as exc:
            raise DatasetError(f"{directory} lacks {file.name}; regenerate the data set") from exc
        except (OSError, ValueError, EOFError) as exc:  # EOFError: an empty file
            raise DatasetError(f"{file} is corrupt or truncated ({exc}); regenerate the data set") from exc
        shape, dtype = expected[name]
        if array.shape != shape or array.dtype != dtype:
            raise DatasetError(f"{file} holds {array.dtype} {array.shape}, meta.json promises {np.dtype(dtype)} "
                               f"{shape}; the directory mixes data sets: regenerate it")
        arrays[name] = array
    _read_contacts(directory, n)
    dataset = Dataset(path=directory, meta=meta, **arrays)
    if sensor is not None:
        check_made_for(dataset, sensor)
    return dataset


def check_made_for(dataset: Dataset, sensor: SensorDescription) -> None:
    """Refuse (DatasetError) a data set made with another sensor description than `sensor`: same camera ids and bin
    grid, say, but another gel, camera pose or surface, whose images and forces are not this sensor's. Its name, frame
    and frame rate may differ (tactile_description.made_for), as for a model."""
    meta_path = dataset.path / "meta.json"
    problem = made_for_problem(dataset.meta.get("sensor"))
    if problem:
        raise DatasetError(f"{meta_path}: sensor (the description it was made for): {problem}; regenerate the data set")
    changes = changed_fields(dataset.meta["sensor"], physical_fields(sensor))
    if changes:
        raise DatasetError(f"{dataset.path} was made for sensor {dataset.meta.get('sensor_name')!r} with another "
                           f"description than {sensor.source or sensor.name} (differing: {changes_text(changes)}); "
                           "pass the sensor description it was made with (--sensor), or regenerate it for this sensor")
