"""The Fz soft threshold, the last fitted step of `tactile-fusion train` (ForceFusionNet.to_newtons says what it does).

Chosen like the fusion layer's ridge: on the validation split, among thresholds of 0 to 0.3 times the model's Fz
scale (the RMS of Fz over all bins and frames) in steps of 0.01, the one with the lowest per-bin Fz RMSE; none if
no threshold beats the model without one. The per-bin error is the paper's metric. A threshold trades a little
of the light presses' force (every contact bin loses it) for the spurious forces all over the surface; the total
force's RMSE is reported beside it for each candidate, to show that trade.
"""

from __future__ import annotations

import numpy as np

from tactile_description import FORCE_COMPONENTS
from tactile_fusion.data import FrameSet
from tactile_fusion.evaluation import predict_torch
from tactile_fusion.model import ForceFusionNet

#: Candidate thresholds, relative to the model's Fz scale.
RELATIVE_THRESHOLDS = tuple(round(0.01 * k, 2) for k in range(31))
FZ = FORCE_COMPONENTS.index("fz")


def fit_fz_threshold(model: ForceFusionNet, val: FrameSet) -> dict:
    """Set `model.fz_threshold_n` to the candidate with the lowest validation per-bin Fz RMSE (None if none beats
    no threshold, or if the model does not estimate Fz).

    Returns {"fz_threshold_n": the threshold set, "val_rmse_bin_fz_n" and "val_rmse_total_fz_n": {candidate in
    newtons ("none" for no threshold): validation RMSE}}.
    """
    model.fz_threshold_n = None
    if "fz" not in model.components:
        return {"fz_threshold_n": None, "val_rmse_bin_fz_n": {}, "val_rmse_total_fz_n": {}}
    predicted = predict_torch(model, val)[..., FZ].reshape(len(val), -1).astype(np.float64)
    true = np.asarray(val.bin_forces_n)[..., FZ].reshape(len(val), -1).astype(np.float64)
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
