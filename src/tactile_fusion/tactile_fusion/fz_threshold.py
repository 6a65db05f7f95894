"""The Fz soft threshold, the last fitted step of `tactile-fusion train` (ForceFusionNet.to_newtons says what it does).

Chosen like the fusion layer's ridge: on the validation split, among thresholds of 0 to 0.3 times the model's Fz
scale (the RMS of Fz over all bins and frames) in steps of 0.01, the one with the lowest per-bin Fz RMSE; none if
no threshold beats the model without one. The per-bin error is the paper's metric. A threshold trades a little
of the light presses' force (every contact bin loses it) for the spurious forces all over the surface; the total
force's RMSE is reported beside it for each candidate, to show that trade.

`tactile-fusion train` then fits the fusion layer again for the thresholded output (`fit_threshold_and_fusion`,
least_squares.fit_fusion_under_threshold) and chooses the threshold once more for the refitted layer.
"""

from __future__ import annotations

import copy
import time

import numpy as np
import torch

from tactile_description import FORCE_COMPONENTS
from tactile_fusion.least_squares import fit_fusion_under_threshold
from tactile_fusion.model import ForceFusionNet

#: Iterations of the fusion layer's refit for the thresholded output (64 s for the default scene and its three further
#: draws on 2026-11-28). Measured on the
#: features of the network shipped on 2026-11-23, of the training split alone (docs/learning.md): 12 iterations took
#: the test split from 2.111 to 2.061 mN per bin, each later one gaining less than the one before; in `make model` of
#: that day, 10 over the training split and its further draw reached 2.021.
REFIT_ITERATIONS = 10
#: Candidate thresholds, relative to the model's Fz scale.
RELATIVE_THRESHOLDS = tuple(round(0.01 * k, 2) for k in range(31))
FZ = FORCE_COMPONENTS.index("fz")


def fit_fz_threshold(model: ForceFusionNet, val) -> dict:
    """Set `model.fz_threshold_n` to the candidate with the lowest validation per-bin Fz RMSE (None if none beats
    no threshold, or if the model does not estimate Fz). `val`: the validation frames as a source of the training
    loop (sources.ImageSource, or a CachedSource of them, whose front part the model must still have).

    Returns {"fz_threshold_n": the threshold set, "val_rmse_bin_fz_n" and "val_rmse_total_fz_n": {candidate in
    newtons ("none" for no threshold): validation RMSE}}.
    """
    if "fz" not in model.components:
        model.fz_threshold_n = None
        return {"fz_threshold_n": None, "val_rmse_bin_fz_n": {}, "val_rmse_total_fz_n": {}}
    predicted, true = _fz_n(model, val)
    scale = float(model.force_scale_n[FZ])
    candidates = {"none": None, **{f"{r * scale:.6g}": r * scale for r in RELATIVE_THRESHOLDS}}
    per_bin, total = {}, {}
    for name, threshold in candidates.items():
        thresholded = predicted if threshold is None else np.maximum(predicted - threshold, 0.0)
        per_bin[name] = float(np.sqrt(np.mean((thresholded - true) ** 2)))
        total[name] = float(np.sqrt(np.mean((thresholded.sum(1) - true.sum(1)) ** 2)))
    best = min(per_bin, key=per_bin.get)  # "none" first: a candidate must beat it, not tie
    model.fz_threshold_n = candidates[best]
    return {"fz_threshold_n": model.fz_threshold_n, "val_rmse_bin_fz_n": per_bin, "val_rmse_total_fz_n": total}


def fit_threshold_and_fusion(model: ForceFusionNet, train_source, val, ridge: float) -> dict:
    """Choose the Fz threshold (`fit_fz_threshold` on the source `val`), refit the dense fusion layer for the
    thresholded output on `train_source` (a CachedSource of the training frames, with the ridge of the last
    least-squares fit) and choose the threshold again for it. The refit is kept only if its validation per-bin Fz
    RMSE, thresholded, beats the model's before it; otherwise the model is left as the first choice set it.

    Returns {"fz_threshold": the threshold report that applies (fit_fz_threshold's), "fusion_refit": {"kept",
    "iterations", "ridge", "wall_time_s", "threshold_before_n", "val_rmse_bin_fz_before_n",
    "val_rmse_bin_fz_after_n"} or {"kept": False, "skipped": why}}.
    """
    first = fit_fz_threshold(model, val)
    if first["fz_threshold_n"] is None or model.fusion.reduce is not None:
        why = "no Fz threshold" if first["fz_threshold_n"] is None else "a rank-limited fusion layer"
        return {"fz_threshold": first, "fusion_refit": {"kept": False, "skipped": why}}
    before = copy.deepcopy(model.fusion.state_dict())
    started = time.perf_counter()
    if not fit_fusion_under_threshold(model, train_source, ridge, REFIT_ITERATIONS):
        return {"fz_threshold": first, "fusion_refit": {"kept": False, "skipped": "the features' normal matrix is "
                                                        "singular at this ridge"}}
    refit_s = time.perf_counter() - started
    second = fit_fz_threshold(model, val)
    before_rmse, after_rmse = _best_rmse(first), _best_rmse(second)
    kept = after_rmse < before_rmse
    if not kept:
        model.fusion.load_state_dict(before)
        model.fz_threshold_n = first["fz_threshold_n"]
    return {"fz_threshold": second if kept else first,
            "fusion_refit": {"kept": kept, "iterations": REFIT_ITERATIONS, "ridge": ridge, "wall_time_s": refit_s,
                             "threshold_before_n": first["fz_threshold_n"], "val_rmse_bin_fz_before_n": before_rmse,
                             "val_rmse_bin_fz_after_n": after_rmse}}


@torch.no_grad()
def _fz_n(model: ForceFusionNet, source, batch_size: int = 256) -> tuple[np.ndarray, np.ndarray]:
    """(predicted, true) Fz of every frame of `source` in newtons, (N, bins) float64; predicted as `model` (in
    evaluation mode) outputs it without its threshold."""
    model.eval()
    threshold, model.fz_threshold_n = model.fz_threshold_n, None
    predicted, true = [], []
    try:  # the model keeps its threshold also when a batch fails, or a stop signal arrives
        for start in range(0, len(source), batch_size):
            indices = np.arange(start, min(start + batch_size, len(source)))
            predicted.append(model.to_newtons(source.predict(model, indices))[..., FZ].flatten(1).double())
            true.append(source.forces_n(indices)[..., FZ].flatten(1).double())
    finally:
        model.fz_threshold_n = threshold
    return torch.cat(predicted).numpy(), torch.cat(true).numpy()


def _best_rmse(report: dict) -> float:
    """The validation per-bin Fz RMSE of the threshold a fit_fz_threshold report chose."""
    return min(report["val_rmse_bin_fz_n"].values())
