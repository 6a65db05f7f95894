"""Evaluation of a predictor on frames: the paper's metrics, a printed table, JSON and Fz map figures."""

from __future__ import annotations

import numpy as np
from tqdm import tqdm

from tactile_fusion.data import FrameSet
from tactile_fusion.inference import ForcePredictor, TorchPredictor
from tactile_fusion.metrics import force_metrics
from tactile_fusion.model import ForceFusionNet


def predict_frames(predictor: ForcePredictor, frames: FrameSet, batch_size: int = 32,
                   progress: bool = False) -> np.ndarray:
    """(N, rows, cols, 3) predictions for every frame; cameras flagged not ok are shown at rest (camera_out)."""
    out = np.empty(frames.bin_forces_n.shape, dtype=np.float32)
    starts = range(0, len(frames), batch_size)
    for start in tqdm(starts, desc=f"evaluate {frames.scene}", unit="batch", disable=not progress):
        stop = min(start + batch_size, len(frames))
        out[start:stop] = predictor.predict_batch(np.asarray(frames.images[start:stop]), frames.reference,
                                                  frames.camera_ids, np.asarray(frames.camera_ok[start:stop]))
    return out


def evaluate(predictor: ForcePredictor, frames: FrameSet, progress: bool = False) -> tuple[dict, np.ndarray]:
    """(metrics, predictions) of `predictor` on `frames`."""
    predicted = predict_frames(predictor, frames, progress=progress)
    return force_metrics(predicted, frames.bin_forces_n), predicted


def predict_torch(model: ForceFusionNet, frames: FrameSet) -> np.ndarray:
    """(N, rows, cols, 3) newtons from the torch model (set to evaluation mode) in fp32, as `predict_frames` with its
    predictor: cameras flagged not ok shown at rest, frames of cameras in another order put into the model's."""
    return predict_frames(TorchPredictor(model, threads=None), frames)
