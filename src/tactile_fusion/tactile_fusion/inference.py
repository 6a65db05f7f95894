"""Inference backends behind one interface: current + reference images in, bin forces in newtons out.

    predictor = load_predictor()                      # shipped model, ONNX Runtime, float32
    bin_forces_n = predictor.predict(images, reference_images)   # (C, H, W) uint8 each -> (rows, cols, 3) float32

Backends: "onnxruntime" (default; precisions fp32, int8, fp16) and "torch" (fp32, fp16). Every input is
checked before it reaches a backend: shape (C, H, W) with the model's camera count and image size, dtype
uint8 or a float type holding grey levels (finite, in [0, 255]; rounded to uint8, the sensor's own depth),
and, when `camera_ids` names the order of the images, only the model's cameras. A bad input raises
InputError naming the input; a NaN never reaches the output.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from tactile_description.value_checks import is_whole_number
from tactile_fusion.artifacts import (
    SENSOR_KEY,
    ModelFileError,
    backend_file,
    default_model_dir,
    described_model,
    load_model,
    model_fields,
    read_model_json,
)
from tactile_fusion.camera_out import with_cameras_at_rest
from tactile_fusion.export import copy_to_half, graph_mismatches
from tactile_fusion.model import ForceFusionNet, difference_images

BACKENDS = {"onnxruntime": ("fp32", "int8", "fp16"), "torch": ("fp32", "fp16")}
#: Every precision of some backend, for command-line choices.
PRECISIONS = tuple(dict.fromkeys(p for precisions in BACKENDS.values() for p in precisions))
DEFAULT_THREADS = 1
#: The most CPU threads a predictor takes (tactile-fusion --threads, the fusion node's `threads`): above the hardware
#: threads of the largest two-socket servers of 2025 (768: two 192-core CPUs, two threads a core), so that no machine's
#: cores are refused; more threads than cores only take turns on them. Far below a mistyped count such as 100000000,
#: which went to torch and ONNX Runtime unchecked: `eval --threads 100000000` took 24 GB of memory until the kernel
#: killed it (ONNX Runtime's thread pool), and torch crashed (segmentation fault) at its first matrix product. 1024
#: works with both (on 2 cores ONNX Runtime took 22 s to load the shipped model with that many threads).
MAX_THREADS = 1024


class InputError(ValueError):
    """Images that the model cannot take: wrong shape, dtype, values, or cameras."""


class ForcePredictor:
    """Common part of the backends: metadata and input checking. Subclasses implement `_run`."""

    backend = ""
    #: The physical description of the sensor the model was trained for (model.json's, set by load_predictor), None
    #: where it is not known: artifacts.sensor_changes compares it with the sensor's.
    made_for: dict | None = None

    def __init__(self, camera_ids: Sequence[str], rows: int, cols: int, image_size: int, precision: str,
                 components: Sequence[str], fz_threshold_n: float | None):
        self.camera_ids = tuple(camera_ids)
        self.rows, self.cols = rows, cols
        self.image_size = image_size
        self.precision = precision
        self.components = tuple(components)  # the force components estimated; the others are always 0
        self.fz_threshold_n = fz_threshold_n  # Fz per bin below it comes out as 0 (ForceFusionNet.to_newtons)

    def predict(self, images: np.ndarray, reference: np.ndarray, camera_ids: Sequence[str] | None = None,
                camera_ok: np.ndarray | None = None) -> np.ndarray:
        """One frame: images and reference (C, H, W) -> bin forces (rows, cols, 3) float32 newtons.

        camera_ids: the camera of each image, in the given order, when it is not the model's order.
        camera_ok: (C,) bool, False for a camera known to be broken (dropped, frozen): it is shown at rest
        (`camera_out.rest_view`), i.e. that camera reports "no contact" and the other cameras carry the estimate.
        """
        ok = None if camera_ok is None else np.asarray(camera_ok)[None]
        images = self._checked(images, "images", camera_ids, batched=False)[None]
        reference = self._checked(reference, "reference", camera_ids, batched=False)
        return self._finite(self._run(self._masked(images, reference, ok, camera_ids), reference))[0]

    def predict_batch(self, images: np.ndarray, reference: np.ndarray, camera_ids: Sequence[str] | None = None,
                      camera_ok: np.ndarray | None = None) -> np.ndarray:
        """Several frames: images (B, C, H, W), reference (C, H, W), camera_ok (B, C) -> (B, rows, cols, 3); no frames
        (B = 0, uint8 or float) give an empty (0, rows, cols, 3)."""
        images = self._checked(images, "images", camera_ids, batched=True)
        reference = self._checked(reference, "reference", camera_ids, batched=False)
        return self._finite(self._run(self._masked(images, reference, camera_ok, camera_ids), reference))

    def _masked(self, images: np.ndarray, reference: np.ndarray, camera_ok, camera_ids) -> np.ndarray:
        """Images (in the model's camera order), each camera marked not ok, or whose image is its reference itself,
        shown at rest (`camera_out.with_cameras_at_rest`)."""
        ok = None
        if camera_ok is not None:
            ok = np.asarray(camera_ok)
            if ok.shape != images.shape[:2]:
                raise InputError(f"camera_ok: expected shape {images.shape[:2]} (frames, cameras), got {ok.shape}")
            # As bool, any string, NaN or 2 was True: the camera meant to be out was read as it was (review)
            if ok.dtype != bool and not (ok.dtype.kind in "iuf" and np.isin(ok, (0, 1)).all()):
                raise InputError(f"camera_ok: expected True or False (or 1 or 0) per camera, got {ok.dtype} values "
                                 f"{ok.ravel().tolist()[:8]}")
            ok = ok.astype(bool)
            if camera_ids is not None:
                ok = ok[:, self._order(camera_ids)]
        return with_cameras_at_rest(images, reference, ok)

    def _run(self, images: np.ndarray, reference: np.ndarray) -> np.ndarray:
        raise NotImplementedError

    def _checked(self, array, name: str, camera_ids: Sequence[str] | None, batched: bool) -> np.ndarray:
        """`array` as contiguous uint8 in the model's camera order, or InputError."""
        if not isinstance(array, np.ndarray):
            raise InputError(f"{name}: expected a numpy array, got {type(array).__name__}")
        c, s = len(self.camera_ids), self.image_size
        expected = (c, s, s) if not batched else ("B", c, s, s)
        if array.ndim != len(expected) or array.shape[-3:] != (c, s, s):
            raise InputError(f"{name}: expected shape {expected} (cameras {list(self.camera_ids)}, {s} x {s} "
                             f"model images from crop_and_downsample), got {array.shape}")
        if array.dtype == np.uint8:
            checked = array
        elif np.issubdtype(array.dtype, np.floating):
            if not np.isfinite(array).all():
                bad = np.argwhere(~np.isfinite(array))[0]
                raise InputError(f"{name}: contains NaN or Inf (first at index {tuple(int(i) for i in bad)}): a "
                                 "broken camera? Mark it as such upstream; the model needs finite grey levels")
            if array.size and (array.min() < 0 or array.max() > 255):
                raise InputError(f"{name}: float grey levels must lie in [0, 255], got [{array.min()}, "
                                 f"{array.max()}]")
            checked = np.rint(array).astype(np.uint8)
        else:
            raise InputError(f"{name}: expected uint8 (or float grey levels in [0, 255]), got {array.dtype}")
        if camera_ids is not None:
            checked = checked[..., self._order(camera_ids), :, :]
        return np.ascontiguousarray(checked)

    def _order(self, camera_ids: Sequence[str]) -> list[int]:
        """Indices that put images given in `camera_ids` order into the model's order."""
        given = list(camera_ids)
        unknown = [c for c in given if c not in self.camera_ids]
        if unknown:
            raise InputError(f"camera_ids: unknown cameras {unknown}; this model knows {list(self.camera_ids)}")
        if sorted(given) != sorted(self.camera_ids):
            raise InputError(f"camera_ids: expected each of {list(self.camera_ids)} once, got {given}")
        return [given.index(c) for c in self.camera_ids]

    def _finite(self, forces: np.ndarray) -> np.ndarray:
        if not np.isfinite(forces).all():
            if self.precision == "fp16":  # re-exporting, the advice below, overflowed again (walkthrough)
                raise FloatingPointError(f"{self.backend} fp16: the model produced NaN or Inf from finite inputs: "
                                         "its weights or activations exceed float16's range (65504), as those of a "
                                         "training that diverged do; use fp32, or retrain the model (if fp32 fails "
                                         "too, the model file is corrupt)")
            remedy = ("re-export it from model.pt (tactile-fusion export)" if self.backend == "onnxruntime" else
                      "restore model.pt from a copy or retrain the model")
            raise FloatingPointError(f"{self.backend} {self.precision}: the model produced NaN or Inf from finite "
                                     f"inputs; the model file is corrupt or overflowed: {remedy}")
        return forces.reshape(forces.shape[0], self.rows, self.cols, 3).astype(np.float32, copy=False)


class TorchPredictor(ForcePredictor):
    backend = "torch"

    def __init__(self, model: ForceFusionNet, precision: str = "fp32", threads: int | None = DEFAULT_THREADS):
        super().__init__(model.camera_ids, model.rows, model.cols, model.config.image_size, precision,
                         model.components, model.fz_threshold_n)
        check_backend(self.backend, precision)
        self.model = model.eval() if precision == "fp32" else copy_to_half(model)
        self.dtype = torch.float32 if precision == "fp32" else torch.float16
        if threads is not None:
            torch.set_num_threads(threads)

    @torch.no_grad()
    def _run(self, images: np.ndarray, reference: np.ndarray) -> np.ndarray:
        difference = difference_images(torch.from_numpy(images), torch.from_numpy(reference)).to(self.dtype)
        return self.model.to_newtons(self.model.forward_normalised(difference)).numpy()


class OnnxRuntimePredictor(ForcePredictor):
    backend = "onnxruntime"

    def __init__(self, onnx_path: str | Path, description: dict, precision: str = "fp32",
                 threads: int | None = DEFAULT_THREADS):
        described = described_model(Path(onnx_path).parent, description)
        super().__init__(described.camera_ids, described.rows, described.cols, described.config.image_size,
                         precision, described.components, described.fz_threshold_n)
        self.session = _graph_session(Path(onnx_path), threads)
        mismatches = (graph_mismatches(self.session.get_modelmeta().custom_metadata_map, model_fields(described))
                      + self._shape_mismatches())
        if mismatches:
            raise ModelFileError(f"{onnx_path} was exported from another model than its model.json describes "
                                 f"({'; '.join(mismatches)}): files of two models are mixed, or model.json was "
                                 "edited after export; put back the model.json that came with the graphs, or, if "
                                 "only its Fz threshold was meant to change, re-export them (tactile-fusion export "
                                 f"--model {Path(onnx_path).parent})")

    def _shape_mismatches(self) -> list[str]:
        """The graph's inputs and output whose names or fixed sizes differ from the model that model.json describes.
        The metadata check alone misses a graph that names nothing (exported before 2026-11-24): one of another
        model then failed at its first frame with numpy's reshape error."""
        n, size = len(self.camera_ids), self.image_size
        needed = {"images": ["batch", n, size, size], "reference": [n, size, size],
                  "bin_forces_n": ["batch", self.rows, self.cols, 3]}
        found = {t.name: t.shape for t in (*self.session.get_inputs(), *self.session.get_outputs())}
        return [f"{name} {found.get(name)} in the graph, {shape} in model.json" for name, shape in needed.items()
                if found.get(name) is None or len(found[name]) != len(shape)
                or any(isinstance(want, int) and got != want for got, want in zip(found[name], shape, strict=True))]

    def _run(self, images: np.ndarray, reference: np.ndarray) -> np.ndarray:
        return self.session.run(None, {"images": images, "reference": reference})[0]


def _graph_session(path: Path, threads: int | None):
    """An `onnx_session` of a model directory's graph file; ModelFileError if ONNX Runtime cannot load it (empty,
    truncated, not a graph, an operator it does not know)."""
    from onnxruntime.capi import onnxruntime_pybind11_state as ort_errors

    try:
        return onnx_session(path, threads)
    except (ort_errors.InvalidProtobuf, ort_errors.InvalidGraph, ort_errors.InvalidArgument, ort_errors.Fail,
            ort_errors.NotImplemented) as exc:  # InvalidArgument: an empty file ("No graph was found")
        raise ModelFileError(f"{path} cannot be loaded by ONNX Runtime ({exc}): the graph is damaged or of an "
                             f"incompatible version; re-export it (tactile-fusion export --model {path.parent})"
                             ) from exc


def onnx_session(graph: str | Path | bytes, threads: int | None):
    """An ONNX Runtime CPU session of a graph file or serialised graph, fully optimised, with `threads` intra-op
    threads (None: all cores)."""
    import onnxruntime as ort

    options = ort.SessionOptions()
    options.intra_op_num_threads = threads or 0
    options.inter_op_num_threads = 1
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    source = graph if isinstance(graph, bytes) else str(graph)
    return ort.InferenceSession(source, options, providers=["CPUExecutionProvider"])


def check_backend(backend: str, precision: str) -> None:
    """Raise ValueError unless `backend` is one of BACKENDS and runs `precision`; the message says what to choose."""
    if backend not in BACKENDS:
        raise ValueError(f"backend must be one of {list(BACKENDS)}, got {backend!r}")
    if precision not in BACKENDS[backend]:
        raise ValueError(f"the {backend} backend runs {', '.join(BACKENDS[backend])}, not {precision!r}; choose one of "
                         "those or another backend")


def load_predictor(model_dir: str | Path | None = None, backend: str = "onnxruntime", precision: str = "fp32",
                   threads: int | None = DEFAULT_THREADS) -> ForcePredictor:
    """A predictor for a model directory (default: the shipped model).

    threads: intra-op threads (None: the backend's default, all cores). One thread is the default: a batch of
    one frame is too small to gain from more (docs/learning.md has the measurements), and the sensor's
    other nodes need the remaining cores.
    """
    check_backend(backend, precision)
    if not (threads is None or is_whole_number(threads) and threads <= MAX_THREADS):
        # torch refused 0 with its own RuntimeError, and ONNX Runtime took -1 for all cores (found in review)
        raise ValueError(f"threads must be a whole number from 1 to {MAX_THREADS}, or None for the backend's "
                         f"default, got {threads!r}")
    model_dir = Path(model_dir) if model_dir is not None else default_model_dir()
    description = read_model_json(model_dir)
    if backend == "torch":
        predictor = TorchPredictor(load_model(model_dir), precision, threads)
    else:
        path = backend_file(model_dir, backend, precision)
        if not path.exists():
            raise ModelFileError(f"{path} is missing: export it with `tactile-fusion export --model {model_dir}`")
        predictor = OnnxRuntimePredictor(path, description, precision, threads)
    predictor.made_for = description.get(SENSOR_KEY)
    return predictor
