"""The modularity study of `tactile-fusion recalibrate` (the paper's Sec. IV-C and Fig. 7).

1. Train a model with every camera but one (the base), and a model with all cameras (full training), on the
   same 70/10/20 split, both timed.
2. Add the missing camera to the base model by recalibration (recalibration.py) with 10 % ... 100 % of the
   training split, each timed and evaluated on the test split.
3. Write recalibration.json and recalibration.png (errors against data fraction with least-squares trend lines,
   wall times of full training and recalibration).
"""

from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from tactile_description import SensorDescription
from tactile_fusion.artifacts import write_json
from tactile_fusion.data import SPLITS, SceneDraws, describe_splits
from tactile_fusion.evaluation import predict_torch
from tactile_fusion.metrics import force_metrics
from tactile_fusion.model import ModelConfig
from tactile_fusion.pipeline import machine_record, train_model, training_splits
from tactile_fusion.plots import plot_recalibration
from tactile_fusion.recalibration import checked_fractions, recalibration_sweep
from tactile_fusion.training import TrainConfig

REPORT_JSON = "recalibration.json"
REPORT_PNG = "recalibration.png"


def recalibration_speedup(full_wall_time_s: float, runs: list[dict]) -> dict:
    """How much faster than full training recalibration with the largest fraction of the data was (`runs`: the
    recalibration runs in increasing fraction): {"fraction": that fraction, "factor": full / its wall time}."""
    largest = runs[-1]
    return {"fraction": largest["fraction"], "factor": full_wall_time_s / largest["wall_time_s"]}


def least_squares_line(x: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """(slope, intercept) of the least-squares line through (x, y): y ~ slope x + intercept. ValueError for fewer than
    two distinct x: no line is determined (lstsq would give the smallest-norm one, a made-up slope)."""
    if len(np.unique(np.asarray(x, dtype=np.float64))) < 2:
        raise ValueError(f"a least-squares line needs two distinct x, got {list(np.asarray(x).tolist())}")
    design = np.stack([np.asarray(x, dtype=np.float64), np.ones(len(x))], axis=1)
    (slope, intercept), *_ = np.linalg.lstsq(design, np.asarray(y, dtype=np.float64), rcond=None)
    return float(slope), float(intercept)


def camera_to_add(sensor: SensorDescription, added_camera: str | None) -> str:
    """The camera the study adds: `added_camera`, or the sensor's last camera when None; ValueError unless it is one of
    the sensor's cameras and the sensor has another to train the base model with."""
    if sensor.n_cameras < 2:  # blamed --add-camera, also where none was given (walkthrough)
        raise ValueError(f"the recalibration study adds a camera to a model of the others: the sensor description "
                         f"{sensor.source} has one camera, {sensor.camera_ids[0]!r}; it needs two or more")
    camera = added_camera or sensor.camera_ids[-1]
    if camera not in sensor.camera_ids:
        raise ValueError(f"--add-camera {camera!r}: expected one of {list(sensor.camera_ids)}")
    return camera


def run_recalibration_study(sensor: SensorDescription, scene: str | None, dataset: str | None, frames: int | None,
                            added_camera: str | None, fractions: list[float], model_config: ModelConfig,
                            train_config: TrainConfig, out_dir: Path, progress: bool = False,
                            head_extra: SceneDraws | None = None) -> dict:
    """Train a model without `added_camera` and one with all cameras, both as `tactile-fusion train` does (the head
    phases also on `head_extra`, further draws of the scene), then recalibrate the first at each data fraction; write
    recalibration.json and recalibration.png into `out_dir` and return the report."""
    added_camera = camera_to_add(sensor, added_camera)
    fractions = checked_fractions(fractions)
    if len(set(fractions)) < 2:
        raise ValueError(f"the study needs two different data fractions or more for its trend line, got {fractions}")
    train_config.recalibration_phase()  # settings that cannot recalibrate fail now, not after two trainings
    splits = training_splits(sensor, scene, dataset, frames, progress)
    head_extra = head_extra if head_extra is not None else SceneDraws.none(sensor)
    train, val, test = (splits[k] for k in SPLITS)
    base_ids = tuple(c for c in sensor.camera_ids if c != added_camera)

    timings, models = {}, {}
    for name, camera_ids in (("base", base_ids), ("full", sensor.camera_ids)):
        started = time.perf_counter()
        models[name], _ = train_model(train.select_cameras(camera_ids), val.select_cameras(camera_ids), model_config,
                                      train_config, None, False, progress, head_extra.select_cameras(camera_ids))
        timings[name] = time.perf_counter() - started
    full_metrics = force_metrics(predict_torch(models["full"], test), test.bin_forces_n)
    base_metrics = force_metrics(predict_torch(models["base"], test.select_cameras(base_ids)), test.bin_forces_n)
    runs = recalibration_sweep(models["base"], train, val, test, fractions, train_config, progress)
    trend = {}
    for key in ("rmse_bin_n", "rmse_total_n"):
        slope, intercept = least_squares_line(np.array(fractions), np.array([r["metrics"][key][2] for r in runs]))
        trend[f"{key}_fz"] = {"slope_n_per_fraction": slope, "intercept_n": intercept}
    report = {
        "added_camera": added_camera,
        "base_cameras": len(base_ids),
        "data": {**describe_splits(splits), "head_extra": head_extra.describe()},
        "train_config": asdict(train_config),
        "machine": machine_record(train_config),
        "model_config": model_config.to_dict(),
        "base_training": {"wall_time_s": timings["base"], "metrics": base_metrics},
        "full_training": {"wall_time_s": timings["full"], "metrics": full_metrics},
        "recalibration": runs,
        "trend_lines": trend,
        "speedup": recalibration_speedup(timings["full"], runs),
        "note": "wall times include the validation passes; recalibration includes caching the frozen features",
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    write_json(out_dir / REPORT_JSON, report)
    plot_recalibration(report, out_dir / REPORT_PNG)
    return report
