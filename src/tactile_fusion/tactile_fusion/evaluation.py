"""Evaluation of a predictor on frames: the paper's metrics, a printed table, JSON and Fz map figures."""

from __future__ import annotations

import numpy as np
import torch
from tqdm import tqdm

from tactile_fusion.camera_out import with_cameras_at_rest
from tactile_fusion.data import FrameSet
from tactile_fusion.inference import ForcePredictor
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


@torch.no_grad()
def predict_torch(model: ForceFusionNet, frames: FrameSet, batch_size: int = 32) -> np.ndarray:
    """(N, rows, cols, 3) newtons from the torch model (evaluation mode); cameras flagged not ok shown at rest."""
    model.eval()
    reference = np.asarray(frames.reference)
    out = []
    for i in range(0, len(frames), batch_size):
        images = with_cameras_at_rest(np.asarray(frames.images[i:i + batch_size]), reference,
                                      frames.camera_ok[i:i + batch_size])
        out.append(model(torch.from_numpy(images), torch.from_numpy(reference)).numpy())
    return np.concatenate(out)
