"""Closed-form fit of the linear fusion layer on the CNN's features (ridge regression).

The fusion layer is linear, so for fixed camera features its best weights solve a least-squares problem
exactly. Gradient training leaves this layer far from that optimum in the time we have (measured in
docs/learning.md: the same features give a clearly lower error with the exact solution), so training ends
with this fit:

    W = argmin ||X W - Y||^2 + ridge ||W||^2  =  (X^T X + ridge I)^-1 X^T Y      (Hoerl & Kennard 1970)

X: (N, C * camera_features + 1) features of the training frames in evaluation mode, with a column of ones for
the bias (not penalised); Y: (N, rows * cols * K) normalised forces of the K components the model estimates.
The ridge is chosen on the validation frames. For a rank-limited fusion layer the solution is projected onto the
`rank` leading right singular vectors of the centred fitted values X W (reduced-rank regression, Izenman 1975: the
best rank-r fit without a ridge, an approximation of the best rank-r ridge fit); the bias lies outside the rank
(the layer adds it after the factored matrix) and is refitted for the projected matrix.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from tactile_description import FORCE_COMPONENTS, left_out_components
from tactile_fusion.model import ForceFusionNet
from tactile_fusion.sources import normalised_rmse

#: Candidate ridges, relative to the number of training frames; features are of order 1 (sigmoid: in (0, 1), ReLU:
#: >= 0 after batch normalisation). The large ones matter
#: when few frames are available (recalibration with 10 % of the data: 1627 frames for 1201 unknowns per output).
RIDGES = (1e-6, 3e-6, 1e-5, 3e-5, 1e-4, 3e-4, 1e-3, 3e-3, 1e-2, 3e-2, 0.1, 0.3, 1.0)


@torch.no_grad()
def camera_features(model: ForceFusionNet, source, batch_size: int = 256, dtype: torch.dtype = torch.float64,
                    ones_column: bool = False) -> tuple[torch.Tensor, torch.Tensor, float]:
    """(features (N, C * camera_features), targets (N, rows * cols * K) of the K components the model estimates, both
    of `dtype`, sum of the squared targets of the others) of a CachedSource or ImageSource, evaluation mode (no
    dropout, batch-norm running statistics). The model computes both in float32, so float32 loses nothing; float64
    is for the sums of the fit. With `ones_column` the features get a last column of ones: the fit's design matrix.

    Both are written batch by batch into tensors of their final size, never held as batches beside a whole: for the
    default scene's 170940 frames (the training split and three further draws) the float64 features are 1.6 GB.
    """
    if not len(source):
        raise ValueError("camera_features: no frames to compute features of")
    model.eval()
    estimated = model.component_indices
    others = [FORCE_COMPONENTS.index(c) for c in left_out_components(model.components)]
    features = targets = None
    unestimated = 0.0
    for start in range(0, len(source), batch_size):
        idx = np.arange(start, min(start + batch_size, len(source)))
        batch = source.features_at(model, idx).reshape(len(idx), -1)
        target = source.target(idx)
        estimated_target = target[..., estimated].reshape(len(idx), -1)
        if features is None:
            features = torch.empty(len(source), batch.shape[1] + int(ones_column), dtype=dtype)
            targets = torch.empty(len(source), estimated_target.shape[1], dtype=dtype)
        features[start:start + len(idx), :batch.shape[1]] = batch
        targets[start:start + len(idx)] = estimated_target
        unestimated += float(torch.sum(target[..., others].double() ** 2))
    if ones_column:
        features[:, -1] = 1.0
    return features, targets, unestimated


def fit_fusion(model: ForceFusionNet, train_source, val_source, ridges: tuple[float, ...] = RIDGES) -> dict:
    """Set the fusion layer of `model` to the ridge solution whose validation RMSE is lowest.

    Returns {"ridge": chosen value, "val_rmse": {ridge: normalised validation RMSE}, "val_rmse_before": the
    gradient-trained layer's, "val_rmse_after": the model's as the fit leaves it}. If no ridge beats the layer as it
    was, the layer is left unchanged.
    """
    before = normalised_rmse(model, val_source)
    design, y, _ = camera_features(model, train_source, ones_column=True)
    x = design[:, :-1]
    xv, yv, val_unestimated = camera_features(model, val_source)
    # The validation RMSE over all three components, as normalised_rmse: the model outputs 0 for the others.
    val_count = yv.numel() * 3 // len(model.components)
    gram = design.T @ design
    rhs = design.T @ y
    rank = model.fusion.reduce.out_features if model.fusion.reduce is not None else None
    scores, solutions = {}, {}
    for ridge in ridges:
        try:
            weights = torch.linalg.solve(_ridged(gram, ridge, len(x)), rhs)      # (F + 1, O)
        except torch.linalg.LinAlgError:  # singular: features of a head that diverged (NaN, Inf), found in review
            weights = None
        if weights is None or not bool(torch.isfinite(weights).all()):  # no fit at this ridge (the SVD raised)
            scores[ridge] = math.inf
            continue
        if rank is not None:
            weights, basis = _reduce_rank(weights, x, y, rank)
        prediction = _design(xv) @ weights
        scores[ridge] = float(torch.sqrt((torch.sum((prediction - yv) ** 2) + val_unestimated) / val_count))
        solutions[ridge] = (weights, basis if rank is not None else None)
    best = min(scores, key=scores.get)
    if scores[best] < before:
        _assign(model, *solutions[best])
    return {"ridge": best if scores[best] < before else None, "val_rmse": {str(k): v for k, v in scores.items()},
            "val_rmse_before": before, "val_rmse_after": min(scores[best], before)}


@torch.no_grad()
def fit_fusion_under_threshold(model: ForceFusionNet, train_source, ridge: float, iterations: int) -> bool:
    """Refit the dense fusion layer of a model with an Fz threshold t for its thresholded output max(Fz - t, 0).

    `fit_fusion` fits Fz itself: it spends weights on pulling the bins without force to exactly 0, although anything
    below t comes out as 0 anyway, and it leaves the loaded bins t short. This refit minimises instead, over the
    training frames (plus the ridge term),

        H = sum over loaded bins (y > 0) of (Fz - t - y)^2  +  sum over the others of max(Fz - t, 0)^2,

    which equals the squared error of the thresholded output while every loaded bin is predicted above t and lies
    above it otherwise (a loaded bin predicted below t costs y^2 in the output but more in H: H keeps pulling it up,
    where the output's own error is flat). H is convex; each iteration minimises the least-squares problem that
    lies above H and touches it at the current weights (majorisation-minimisation, Lange, Hunter & Yang 2000):
    targets y + t on loaded bins and min(Fz, t) on the others. So no iteration raises H (tested), but the output's
    error can rise; whether the refit helps is decided on the validation split (`fz_threshold.
    fit_threshold_and_fusion`). Every iteration solves with the same matrix (one Cholesky factor), so it costs two
    products of the features with the weights. Fx and Fy keep their plain targets.

    The features are kept in float32 and taken to float64 a chunk of frames at a time: for the default scene's 170940
    frames a float64 copy of them, their targets and the fitted values would add about 7 GB to training's peak.

    Returns False, the layer unchanged, if the ridge leaves the features' normal matrix not positive definite
    (numerically singular); True when refitted.
    """
    if model.fz_threshold_n is None or "fz" not in model.components:
        raise ValueError("fit_fusion_under_threshold: the model has no Fz threshold to fit for")
    if model.fusion.reduce is not None:
        raise ValueError("fit_fusion_under_threshold: only a dense fusion layer (no --fusion-rank) can be refitted")
    x, y, _ = camera_features(model, train_source, dtype=torch.float32)
    chunks = [slice(start, start + REFIT_CHUNK_FRAMES) for start in range(0, len(x), REFIT_CHUNK_FRAMES)]
    gram = torch.zeros(x.shape[1] + 1, x.shape[1] + 1, dtype=torch.float64)
    for rows in chunks:
        design = _design(x[rows])
        gram += design.T @ design
    factor, singular = torch.linalg.cholesky_ex(_ridged(gram, ridge, len(x)))
    if singular:
        return False
    fusion = model.fusion.expand
    weights = torch.cat([fusion.weight.T, fusion.bias[None]]).double()               # (F + 1, O)
    fz = torch.zeros(len(model.components), dtype=torch.bool)
    fz[model.components.index("fz")] = True
    fz = fz.repeat(y.shape[1] // len(model.components))                            # output columns of Fz
    threshold = torch.tensor(model.fz_threshold_n / float(model.force_scale_n[FORCE_COMPONENTS.index("fz")]),
                             dtype=gram.dtype)
    for _ in range(iterations):
        rhs = torch.zeros_like(weights)
        for rows in chunks:
            design, target = _design(x[rows]), y[rows].double()
            below = torch.minimum(design @ weights, threshold)
            rhs += design.T @ torch.where(fz & (target > 0), target + threshold, torch.where(fz, below, target))
        weights = torch.cholesky_solve(rhs, factor)
    _assign(model, weights, None)
    return True


#: Frames per chunk of the refit's float64 products (about 40 MB of features each for the reference sensor).
REFIT_CHUNK_FRAMES = 4096


def _design(features: torch.Tensor) -> torch.Tensor:
    """(N, F) features -> (N, F + 1) float64 with a column of ones for the bias."""
    return torch.cat([features.double(), torch.ones(len(features), 1, dtype=torch.float64)], dim=1)


def _ridged(gram: torch.Tensor, ridge: float, frames: int) -> torch.Tensor:
    """The normal matrix of the ridge problem: `gram` (of `_design` features) + ridge * frames on the diagonal of
    the weights; the bias is not shrunk."""
    penalty = torch.eye(len(gram), dtype=gram.dtype)
    penalty[-1, -1] = 0.0
    return gram + ridge * frames * penalty


def _reduce_rank(weights: torch.Tensor, x: torch.Tensor, y: torch.Tensor, rank: int
                 ) -> tuple[torch.Tensor, torch.Tensor]:
    """(F + 1, O) solution -> (its best rank-`rank` version with the least-squares bias, basis (rank, O))."""
    matrix = weights[:-1]
    fitted = x @ matrix
    _, _, vt = torch.linalg.svd(fitted - fitted.mean(0), full_matrices=False)
    basis = vt[:rank]
    if len(basis) < rank:  # fewer frames than the rank: the directions the data do not reach get zero weight
        basis = torch.cat([basis, torch.zeros(rank - len(basis), basis.shape[1], dtype=basis.dtype)])
    matrix = matrix @ basis.T @ basis
    bias = y.mean(0) - x.mean(0) @ matrix
    return torch.cat([matrix, bias[None]]), basis


def _assign(model: ForceFusionNet, weights: torch.Tensor, basis: torch.Tensor | None) -> None:
    """Write a (F + 1, O) solution (last row: bias) into the fusion layer, factored through `basis` if given."""
    matrix, bias = weights[:-1], weights[-1]
    fusion = model.fusion
    with torch.no_grad():
        if basis is None:
            fusion.expand.weight.copy_(matrix.T.float())
            fusion.expand.bias.copy_(bias.float())
        else:
            fusion.reduce.weight.copy_((matrix @ basis.T).T.float())            # (r, F)
            fusion.expand.weight.copy_(basis.T.float())                         # (O, r)
            fusion.expand.bias.copy_(bias.float())
