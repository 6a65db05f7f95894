"""Inference speed of every backend and precision, next to its accuracy: what accuracy costs in time.

Speed: milliseconds per frame (all cameras), batch of one. The backends take turns in `ROUNDS` blocks of
`runs / ROUNDS` calls each (after a warm-up), so that a change of the machine's state during the benchmark (another
process, clock changes) reaches all of them alike instead of the one that happened to run then; within a block a
backend runs back to back, as in the fusion node. The figure is the median over all calls, with the 90th
percentile, and the ratio to ONNX Runtime float32 measured in the same run (the baseline).

Accuracy: the test-split metrics of each backend and precision that `tactile-fusion train` wrote into the model
directory's metrics.json, for the files it measured: an entry whose file (ONNX graph or state dict) is no longer
the one metrics.json records the SHA-256 of (e.g. re-exported with other package versions), or whose model.json is
not the one measured with (the torch backend reads its Fz threshold there: `export --fit-threshold` changes it and
not model.pt), gets None and is listed under `accuracy_stale`. None everywhere for a directory without metrics.json.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from tactile_description import SensorDescription
from tactile_description.command_line import one_line
from tactile_description.value_checks import is_number, is_whole_number
from tactile_fusion.artifacts import (
    METRICS_JSON,
    MODEL_JSON,
    ModelFileError,
    backend_file,
    check_model_fits,
    default_model_dir,
    file_sha256,
    read_json_object,
)
from tactile_fusion.inference import BACKENDS, load_predictor

BASELINE = "onnxruntime_fp32"
#: Blocks per backend; each backend's timed calls are spread over this many turns.
ROUNDS = 5
#: Figures of a backend that its metrics.json entry may leave out (or give as null).
OPTIONAL_FIGURES = ("max_abs_deviation_from_torch_fp32_n", "frames")


def synthetic_frame(camera_count: int, image_size: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A reference frame of random grey levels and a current frame that differs by noise (speed does not depend
    on image content for these networks, only on shapes)."""
    rng = np.random.default_rng(seed)
    reference = rng.integers(20, 236, size=(camera_count, image_size, image_size), dtype=np.uint8)
    images = np.clip(reference + rng.integers(-10, 11, size=reference.shape), 0, 255).astype(np.uint8)
    return images, reference


def call_times_s(predictor, images: np.ndarray, reference: np.ndarray, calls: int) -> list[float]:
    """Wall time of each of `calls` predict() calls on the same frame."""
    times = []
    for _ in range(calls):
        started = time.perf_counter()
        predictor.predict(images, reference)
        times.append(time.perf_counter() - started)
    return times


def recorded_accuracy(model_dir: Path) -> tuple[dict[str, dict], list[str]]:
    """({backend_precision: {rmse_bin_fz_n, rmse_total_fz_n, max_abs_deviation_from_torch_fp32_n, frames}}, stale) from
    the model directory's metrics.json, for the backends and precisions there are now: the entries whose file and
    model.json are still the ones measured, and the keys of those whose file or model.json changed since (or whose
    file has no recorded SHA-256).
    ({}, []) without metrics.json; ModelFileError for a metrics.json that is damaged, lacks figures or has figures that
    are not numbers."""
    path = model_dir / METRICS_JSON
    if not path.exists():
        return {}, []
    remedy = f"measure the model again (tactile-fusion export --model {model_dir} --measure)"
    recorded = read_json_object(path, remedy).get("backends", {})
    if not isinstance(recorded, dict):
        raise ModelFileError(f"{path}: backends must be an object, got {recorded!r}; {remedy}")
    accuracy, stale = {}, []
    model_json_sha256 = file_sha256(model_dir / MODEL_JSON)
    for backend, precision in ((b, p) for b, precisions in BACKENDS.items() for p in precisions):
        key = f"{backend}_{precision}"
        entry, model_file = recorded.get(key), backend_file(model_dir, backend, precision)
        if entry is None:
            continue
        if not isinstance(entry, dict):
            raise ModelFileError(f"{path}: the figures of {key} must be an object, got {entry!r}; {remedy}")
        measured_with = entry.get("model_json_sha256")  # None: recorded before 2026-11-25, its file is checked alone
        if (not model_file.exists() or entry.get("model_file_sha256") != file_sha256(model_file)
                or (measured_with is not None and measured_with != model_json_sha256)):
            stale.append(key)
            continue
        try:
            accuracy[key] = {"rmse_bin_fz_n": entry["rmse_bin_n"][2], "rmse_total_fz_n": entry["rmse_total_n"][2],
                             "max_abs_deviation_from_torch_fp32_n": entry.get("max_abs_deviation_from_torch_fp32_n"),
                             "frames": entry.get("frames")}
        except (KeyError, IndexError, TypeError) as exc:
            raise ModelFileError(f"{path}: the figures of {key} are incomplete ({exc!r}); {remedy}") from exc
        wrong = {name: value for name, value in accuracy[key].items()
                 if not (is_number(value) or (value is None and name in OPTIONAL_FIGURES))
                 or (name == "frames" and value is not None and not is_whole_number(value))}
        if wrong:
            raise ModelFileError(f"{path}: the figures of {key} must be numbers (frames a whole number >= 1), got "
                                 f"{wrong}; {remedy}")
    return accuracy, stale


def benchmark(model_dir: str | Path | None = None, runs: int = 300, warmup: int = 30,
              threads: int | None = 1, sensor: SensorDescription | None = None) -> dict:
    """{backend_precision: {ms_per_frame, p90_ms, ratio_to_baseline, accuracy}} plus the setting, for one model
    directory. runs: timed calls per backend, at least 1 (ValueError otherwise). A backend and precision whose file
    is missing or damaged, or whose model overflows, is left out and listed under "failed" with the reason; the
    baseline's failure is raised (every ratio is to it). With `sensor`, a model of other cameras, bins or images is
    refused (ModelFileError, artifacts.check_model_fits), as every other command refuses it: `tactile-fusion bench
    --sensor` took any description, or a missing file, and timed the model (walkthrough)."""
    if not is_whole_number(runs):
        raise ValueError(f"benchmark: runs must be a whole number >= 1, got {runs!r}")
    model_dir = Path(model_dir) if model_dir is not None else default_model_dir()
    # The baseline first: a directory without a model is refused as such, not for its metrics.json (found in review).
    baseline = load_predictor(model_dir, *BASELINE.split("_"), threads)
    if sensor is not None:
        check_model_fits(baseline, sensor)
    accuracy, stale = recorded_accuracy(model_dir)  # a damaged metrics.json is refused before the runs
    images, reference = synthetic_frame(len(baseline.camera_ids), baseline.image_size)
    predictors, failed = {}, {}
    for backend, precisions in BACKENDS.items():
        for precision in precisions:
            key = f"{backend}_{precision}"
            try:
                predictor = baseline if key == BASELINE else load_predictor(model_dir, backend, precision, threads)
                call_times_s(predictor, images, reference, warmup)
            except (ModelFileError, FloatingPointError) as exc:
                # One graph missing or overflowing (fp16) ended the benchmark of all the others (walkthrough).
                if key == BASELINE:
                    raise
                failed[key] = one_line(exc)
            else:
                predictors[key] = predictor
    times = {key: [] for key in predictors}
    block = max(1, -(-runs // ROUNDS))
    while any(len(t) < runs for t in times.values()):
        for key, predictor in predictors.items():
            times[key] += call_times_s(predictor, images, reference, min(block, runs - len(times[key])))
    results = {key: {"backend": predictors[key].backend, "precision": predictors[key].precision,
                     "ms_per_frame": float(np.median(t) * 1e3), "p90_ms": float(np.percentile(t, 90) * 1e3),
                     "accuracy": accuracy.get(key)}
               for key, t in times.items()}
    for entry in results.values():
        entry["ratio_to_baseline"] = entry["ms_per_frame"] / results[BASELINE]["ms_per_frame"]
    return {"backends": results, "baseline": BASELINE, "cameras": len(baseline.camera_ids),
            "image_size": baseline.image_size, "batch": 1, "runs": runs, "rounds": -(-runs // block),
            "threads": threads,
            "statistic": "median over runs of one predict() call, input checks included",
            "accuracy_source": f"{METRICS_JSON} (test split, written by tactile-fusion train)" if accuracy else None,
            "accuracy_stale": stale, "failed": failed}
