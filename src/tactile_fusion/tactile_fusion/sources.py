"""What a batch of frame indices becomes for the training loop: normalised predictions and targets.

- `ImageSource`: difference images through the whole network (end-to-end training).
- `CachedSource`: the output of a frozen front part of the network, computed once per frame; a training step
  runs only the layers after it. Used twice: the head phase of training (conv trunk frozen, training.py) and
  modular recalibration (trunk and first fully connected layer frozen, recalibration.py). Running the frozen
  part in every step would give the same numbers (frozen batch norm uses its running statistics in both
  cases; the dropout of a cached stage is applied to the cached features in training mode), only slower.
  Optionally the frames get extra sensor noise before their features are cached (`extra_noise_sigma`): the head
  then learns from features of noisier images than the conv trunk was trained on (docs/learning.md).
"""

from __future__ import annotations

import numpy as np
import torch

from tactile_fusion.data import FrameSet
from tactile_fusion.model import ForceFusionNet, difference_images

#: Where a CachedSource cuts the network: after the conv trunk, or after the first fully connected layer.
CUTS = ("trunk", "hidden")


class ImageSource:
    """Frames -> difference images through the whole network; targets divided by the model's force scale."""

    def __init__(self, frames: FrameSet, force_scale_n: torch.Tensor):
        self.frames = frames
        self.reference = torch.from_numpy(np.asarray(frames.reference))
        self.force_scale_n = force_scale_n

    def __len__(self) -> int:
        return len(self.frames)

    def features_at(self, model: ForceFusionNet, indices: np.ndarray) -> torch.Tensor:
        """(B * C, camera_features) CNN features of the frames at `indices`, frame-major."""
        images = torch.from_numpy(np.asarray(self.frames.images[np.sort(indices)]))
        difference = difference_images(images, self.reference)
        b, c, h, w = difference.shape
        return model.cnn(difference.reshape(b * c, 1, h, w))

    def predict(self, model: ForceFusionNet, indices: np.ndarray) -> torch.Tensor:
        return model.fuse(self.features_at(model, indices))

    def target(self, indices: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.asarray(self.frames.bin_forces_n[np.sort(indices)])) / self.force_scale_n


class CachedSource:
    """Frames as the cached output of the model's front part up to `cut` ("trunk" or "hidden").

    The front part must stay frozen while this source is used (the caller sets requires_grad False on it).
    extra_noise_sigma: if > 0, each frame gets Gaussian noise of a standard deviation drawn uniformly from
    [0, extra_noise_sigma] grey levels (seeded by `seed`) on top of its own before it goes through the front part.
    """

    def __init__(self, model: ForceFusionNet, frames: FrameSet, cut: str, batch_size: int = 32,
                 extra_noise_sigma: float = 0.0, seed: int = 0):
        if cut not in CUTS:
            raise ValueError(f"CachedSource: cut must be one of {CUTS}, got {cut!r}")
        self.cut = cut
        self.force_scale_n = model.force_scale_n
        reference = torch.from_numpy(np.asarray(frames.reference))
        chunks = []
        model.eval()
        with torch.no_grad():
            for start in range(0, len(frames), batch_size):
                images = np.asarray(frames.images[start:start + batch_size])
                if extra_noise_sigma > 0:
                    images = with_extra_noise(images, extra_noise_sigma, np.random.default_rng([seed, start]))
                difference = difference_images(torch.from_numpy(images), reference)
                b, c, h, w = difference.shape
                x = model.cnn.conv_features(difference.reshape(b * c, 1, h, w))
                if cut == "hidden":
                    x = model.cnn.first_layer(x)
                chunks.append(x.reshape(b, c, -1))
        self.features = torch.cat(chunks)                                  # (N, C, features at the cut)
        self.targets = torch.from_numpy(np.asarray(frames.bin_forces_n))

    def __len__(self) -> int:
        return len(self.features)

    def features_at(self, model: ForceFusionNet, indices: np.ndarray) -> torch.Tensor:
        """(B * C, camera_features) CNN features of the frames at `indices`, from the cache."""
        x = self.features[np.sort(indices)]
        b, c, n = x.shape
        x = x.reshape(b * c, n)
        x = model.cnn.first_layer(x) if self.cut == "trunk" else model.cnn.first_layer.dropout(x)
        return model.cnn.last_layer(x)

    def predict(self, model: ForceFusionNet, indices: np.ndarray) -> torch.Tensor:
        return model.fuse(self.features_at(model, indices))

    def target(self, indices: np.ndarray) -> torch.Tensor:
        return self.targets[np.sort(indices)] / self.force_scale_n


def with_extra_noise(images: np.ndarray, max_sigma: float, rng: np.random.Generator) -> np.ndarray:
    """(N, C, H, W) uint8 frames plus Gaussian noise, one standard deviation per frame drawn from [0, max_sigma]
    grey levels, rounded and clipped to uint8."""
    sigma = rng.uniform(0.0, max_sigma, len(images)).astype(np.float32)[:, None, None, None]
    noisy = images.astype(np.float32) + rng.standard_normal(images.shape, dtype=np.float32) * sigma
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


@torch.no_grad()
def normalised_rmse(model: ForceFusionNet, source, batch_size: int = 64) -> float:
    """RMSE over all frames of `source` (normalised forces), evaluation mode."""
    model.eval()
    total, count = 0.0, 0
    for start in range(0, len(source), batch_size):
        idx = np.arange(start, min(start + batch_size, len(source)))
        err = source.predict(model, idx) - source.target(idx)
        total += float(torch.sum(err.double() ** 2))
        count += err.numel()
    return float(np.sqrt(total / max(count, 1)))
