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

from tactile_fusion.data import FrameSet, check_finite_targets
from tactile_fusion.evaluation import predict_torch
from tactile_fusion.least_squares import fit_fusion
from tactile_fusion.metrics import force_metrics
from tactile_fusion.model import ForceFusionNet, FusionLayer
from tactile_fusion.sources import CachedSource
from tactile_fusion.training import TrainConfig, TrainResult, fit, phase_dropout


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
    # The input of the new fusion layer that takes each input of the base's: its cameras' feature blocks, moved.
    columns = [camera_ids.index(camera) * k + f for camera in base.camera_ids for f in range(k)]
    with torch.no_grad():
        _start_fusion_from(model.fusion, base.fusion, columns)
    return model


def _start_fusion_from(fusion: FusionLayer, base: FusionLayer, columns: list[int]) -> None:
    """Make `fusion` the map of `base` on its inputs at `columns` and 0 on the others (the new cameras' features).

    Both layers dense, or both factored: the first matrix's columns are copied, its other columns zeroed, and the
    rest copied. The fusion rank can also lie between the two layers' input counts (at least the base's, below the
    new layer's and its outputs): then the base is dense (FusionLayer: a rank that allows every map) and the new
    layer factored, and the base matrix is that product exactly: `reduce` passes the base inputs through (identity
    rows), `expand` starts with the base matrix. The rank's remaining directions keep their initial `reduce` rows
    and get zero `expand` columns: they change nothing yet, and they train.
    """
    if fusion.reduce is not None and base.reduce is None:
        n = len(columns)
        fusion.reduce.weight[:n] = 0.0
        fusion.reduce.weight[torch.arange(n), columns] = 1.0
        fusion.expand.weight.zero_()
        fusion.expand.weight[:, :n] = base.expand.weight
        fusion.expand.bias.copy_(base.expand.bias)
        return
    first = fusion.reduce if fusion.reduce is not None else fusion.expand
    base_first = base.reduce if base.reduce is not None else base.expand
    first.weight.zero_()
    first.weight[:, columns] = base_first.weight
    if fusion.reduce is not None:
        fusion.expand.load_state_dict(base.expand.state_dict())
    else:
        fusion.expand.bias.copy_(base.expand.bias)


def recalibrate(base: ForceFusionNet, train: FrameSet, val: FrameSet, config: TrainConfig,
                progress: bool = False) -> tuple[ForceFusionNet, TrainResult, float]:
    """Add the cameras of `train` that `base` lacks and retrain the last CNN layer and the fusion layer.

    The gradient phase runs with `config.recalibration_phase()` at the head phase's dropout (`TrainConfig.head_dropout`)
    and keeps its last epoch; as in full training, the least-squares fit of the fusion layer follows. Like a head cycle
    (training.train_phases), the phase is judged after its fit: unless the trained layers, fitted, have the lower
    validation RMSE, the starting point with only its fusion fitted is the model returned (the result's kept_epoch is
    then 0), also when the training diverged to NaN. Scoring the epochs before the fit kept the starting point with
    10-50 % of the training data (docs/learning.md). Returns the model,
    the training result and the wall time in seconds, feature caching and both fits included. Non-finite targets are
    refused (data.FrameDataError).
    """
    check_finite_targets(training=train, validation=val)
    started = time.perf_counter()
    model = add_camera(base, train.camera_ids)
    cached_train, cached_val = CachedSource(model, train, "hidden"), CachedSource(model, val, "hidden")
    start = copy.deepcopy(model.state_dict())
    phase = config.recalibration_phase()
    with phase_dropout(model, config.head_dropout):
        result = fit(model, cached_train, cached_val, phase, progress=progress, desc="recalibrate",
                     step_precision=phase.head_precision, keep="last")
    trained_val = fit_fusion(model, cached_train, cached_val)["val_rmse_after"]
    trained = copy.deepcopy(model.state_dict())
    model.load_state_dict(start)
    if trained_val < fit_fusion(model, cached_train, cached_val)["val_rmse_after"]:  # False for NaN: diverged
        model.load_state_dict(trained)
    else:
        result = replace(result, kept_epoch=0)
    model.eval()
    return model, result, time.perf_counter() - started


def checked_fractions(fractions) -> list[float]:
    """Fractions of the training data to recalibrate with, as floats in increasing order; ValueError unless there is
    at least one and each is a number in (0, 1]."""
    values = [float(f) for f in fractions]
    if not values or not all(0.0 < f <= 1.0 for f in values):
        raise ValueError(f"fractions must be numbers in (0, 1], got {list(fractions)}")
    return sorted(values)


def fraction_subset(frames: FrameSet, fraction: float, seed: int) -> FrameSet:
    """A seeded random `fraction` (0 < fraction <= 1) of `frames`, at least one frame; nested across fractions."""
    checked_fractions([fraction])
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
