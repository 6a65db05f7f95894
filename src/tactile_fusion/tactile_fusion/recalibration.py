"""Modular recalibration (Trueeb et al. 2020, Sec. IV-C): add a camera to a trained model by retraining only the
last fully connected layer of the shared CNN and the fusion layer; the rest of the CNN stays frozen.

Because the frozen part (conv blocks, first fully connected layer, their batch-norm statistics) no longer
changes, its output for every training image is computed once and cached (sources.CachedSource); the
retrained layers then train on these cached features. That is the same optimisation problem as running the
frozen layers in every step, and it is where the speed-up over full training comes from.
"""

from __future__ import annotations

import copy
import time
from dataclasses import replace

import numpy as np
import torch

from tactile_fusion.data import FrameSet
from tactile_fusion.evaluation import predict_torch
from tactile_fusion.least_squares import fit_fusion
from tactile_fusion.metrics import force_metrics
from tactile_fusion.model import ForceFusionNet
from tactile_fusion.sources import CachedSource
from tactile_fusion.training import TrainConfig, TrainResult, fit, head_dropout


def add_camera(base: ForceFusionNet, camera_ids: tuple[str, ...]) -> ForceFusionNet:
    """A model for `camera_ids` (the base model's cameras plus new ones) that starts from `base`.

    The CNN is copied; trunk and first fully connected layer are frozen. The fusion layer keeps the base
    model's weights for the cameras it knew and starts with zero weights for the new cameras' features, so
    the new model initially predicts what the base model did.
    """
    missing = [c for c in base.camera_ids if c not in camera_ids]
    if missing or len(camera_ids) <= base.n_cameras:
        raise ValueError(f"add_camera: camera_ids {list(camera_ids)} must contain the base model's cameras "
                         f"{list(base.camera_ids)} and at least one more")
    model = ForceFusionNet(base.config, camera_ids, base.rows, base.cols, base.force_scale_n, base.components,
                           base.fz_threshold_n)
    model.cnn.load_state_dict(base.cnn.state_dict())
    for module in (model.cnn.trunk, model.cnn.first_layer):
        module.requires_grad_(False)
    k = base.config.camera_features
    first = model.fusion.reduce if model.fusion.reduce is not None else model.fusion.expand
    base_first = base.fusion.reduce if base.fusion.reduce is not None else base.fusion.expand
    with torch.no_grad():
        first.weight.zero_()
        for i, camera in enumerate(base.camera_ids):
            j = camera_ids.index(camera)
            first.weight[:, j * k:(j + 1) * k] = base_first.weight[:, i * k:(i + 1) * k]
        if model.fusion.reduce is not None:
            model.fusion.expand.load_state_dict(base.fusion.expand.state_dict())
        else:
            model.fusion.expand.bias.copy_(base.fusion.expand.bias)
    return model


def recalibrate(base: ForceFusionNet, train: FrameSet, val: FrameSet, config: TrainConfig,
                progress: bool = False) -> tuple[ForceFusionNet, TrainResult, float]:
    """Add the cameras of `train` that `base` lacks and retrain the last CNN layer and the fusion layer.

    The gradient phase runs with `config.recalibration_phase()` at the head phase's dropout (`head_dropout`) and
    keeps its last epoch; as in full training, the least-squares fit of the fusion layer follows. Like a head cycle
    (training.train_phases), the phase is judged after its fit: if the starting point with only its fusion fitted
    has the lower validation RMSE, that is the model returned (the result's kept_epoch is then 0). Scoring the epochs
    before the fit kept the starting point with 10-50 % of the training data (docs/learning.md). Returns the model,
    the training result and the wall time in seconds, feature caching and both fits included.
    """
    started = time.perf_counter()
    model = add_camera(base, train.camera_ids)
    cached_train, cached_val = CachedSource(model, train, "hidden"), CachedSource(model, val, "hidden")
    start = copy.deepcopy(model.state_dict())
    phase = config.recalibration_phase()
    with head_dropout(model, config):
        result = fit(model, cached_train, cached_val, phase, progress=progress, desc="recalibrate",
                     step_precision=phase.head_precision, keep="last")
    trained_val = fit_fusion(model, cached_train, cached_val)["val_rmse_after"]
    trained = copy.deepcopy(model.state_dict())
    model.load_state_dict(start)
    if fit_fusion(model, cached_train, cached_val)["val_rmse_after"] <= trained_val:
        result = replace(result, kept_epoch=0)
    else:
        model.load_state_dict(trained)
    model.eval()
    return model, result, time.perf_counter() - started


def fraction_subset(frames: FrameSet, fraction: float, seed: int) -> FrameSet:
    """A seeded random `fraction` (0 < fraction <= 1) of `frames`, at least one frame; nested across fractions."""
    if not 0.0 < fraction <= 1.0:
        raise ValueError(f"fraction must be in (0, 1], got {fraction}")
    order = np.random.default_rng([seed, 7]).permutation(len(frames))
    return frames.subset(np.sort(order[:max(1, round(fraction * len(frames)))]))


def recalibration_sweep(base: ForceFusionNet, train: FrameSet, val: FrameSet, test: FrameSet,
                        fractions: list[float], config: TrainConfig, progress: bool = False) -> list[dict]:
    """Recalibrate with each fraction of the training frames; test metrics and wall time of each."""
    runs = []
    for fraction in fractions:
        subset = fraction_subset(train, fraction, config.seed)
        model, result, wall_s = recalibrate(base, subset, val, config, progress)
        runs.append({"fraction": fraction, "train_frames": len(subset), "wall_time_s": wall_s,
                     "epochs_run": result.epochs_run, "best_epoch": result.best_epoch, "kept_epoch": result.kept_epoch,
                     "step_precision": result.step_precision,
                     "metrics": force_metrics(predict_torch(model, test), test.bin_forces_n)})
    return runs
