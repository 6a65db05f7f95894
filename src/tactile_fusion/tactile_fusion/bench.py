"""Inference speed of every backend and precision: milliseconds per frame (all cameras), batch of one.

Each backend runs the same frame `runs` times after a warm-up; the figure is the median, with the 90th
percentile, and the ratio to ONNX Runtime float32 measured in the same run (the baseline).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from tactile_fusion.inference import BACKENDS, load_predictor

BASELINE = "onnxruntime_fp32"


def synthetic_frame(camera_count: int, image_size: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A reference frame of random grey levels and a current frame that differs by noise (speed does not depend
    on image content for these networks, only on shapes)."""
    rng = np.random.default_rng(seed)
    reference = rng.integers(20, 236, size=(camera_count, image_size, image_size), dtype=np.uint8)
    images = np.clip(reference + rng.integers(-10, 11, size=reference.shape), 0, 255).astype(np.uint8)
    return images, reference


def time_predictor(predictor, images: np.ndarray, reference: np.ndarray, runs: int, warmup: int) -> dict:
    for _ in range(warmup):
        predictor.predict(images, reference)
    times = np.empty(runs)
    for i in range(runs):
        started = time.perf_counter()
        predictor.predict(images, reference)
        times[i] = time.perf_counter() - started
    return {"ms_per_frame": float(np.median(times) * 1e3), "p90_ms": float(np.percentile(times, 90) * 1e3)}


def benchmark(model_dir: str | Path | None = None, runs: int = 300, warmup: int = 30,
              threads: int | None = 1) -> dict:
    """{backend_precision: {ms_per_frame, p90_ms, ratio_to_baseline}} plus the setting, for one model directory."""
    results = {}
    camera_count = image_size = None
    for backend, precisions in BACKENDS.items():
        for precision in precisions:
            predictor = load_predictor(model_dir, backend, precision, threads)
            if camera_count is None:
                camera_count, image_size = len(predictor.camera_ids), predictor.image_size
                images, reference = synthetic_frame(camera_count, image_size)
            results[f"{backend}_{precision}"] = time_predictor(predictor, images, reference, runs, warmup)
    for entry in results.values():
        entry["ratio_to_baseline"] = entry["ms_per_frame"] / results[BASELINE]["ms_per_frame"]
    return {"backends": results, "baseline": BASELINE, "cameras": camera_count, "image_size": image_size,
            "batch": 1, "runs": runs, "threads": threads,
            "statistic": "median over runs of one predict() call, input checks included"}
