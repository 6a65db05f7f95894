"""What a batch of frame indices becomes for the training loop: normalised predictions and targets.

- `ImageSource`: difference images through the whole network (end-to-end training).
- `CachedSource`: the output of a frozen front part of the network, computed once per frame; a training step
  runs only the layers after it. Used twice: the head phase of training (conv trunk frozen, training.py) and
  modular recalibration (trunk and first fully connected layer frozen, recalibration.py). Running the frozen
  part in every step would give the same numbers (frozen batch norm uses its running statistics in both
  cases; the dropout of a cached stage is applied to the cached features in training mode), only slower.
  Optionally (`augmentation`) the cache also holds a second copy of every frame, seen through camera imperfections
  (a camera knocked askew, defocus blur, extra sensor noise): the head then learns from clean and imperfect images
  alike, which the conv trunk alone never saw (docs/learning.md).
"""

from __future__ import annotations

import copy
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from tactile_fusion.camera_out import with_cameras_at_rest
from tactile_fusion.data import FrameSet
from tactile_fusion.export import onnx_bytes
from tactile_fusion.inference import onnx_session
from tactile_fusion.model import ForceFusionNet, camera_batch, difference_images
from tactile_sim.effects import defocus, misalign

#: Where a CachedSource cuts the network: after the conv trunk, or after the first fully connected layer.
CUTS = ("trunk", "hidden")
#: Frames per call when a CachedSource fills its cache. Small batches keep the activations in the CPU's caches: ONNX
#: Runtime ran the conv trunk at 0.60 ms per frame with 4 frames per call, 0.74 with 16 and 0.84 with 64 (two threads,
#: its threads sleeping between calls; the same features to the bit for any batch). With its threads waiting busily
#: instead (see `CachedSource._front`), 2 frames per call ran at 0.38 ms, 1 at 0.42 and 4 at 0.52.
FRONT_BATCH_FRAMES = 2


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
        picked = np.sort(indices)
        images = with_cameras_at_rest(np.asarray(self.frames.images[picked]), self.frames.reference,
                                      self.frames.camera_ok[picked])
        # uint8 to the model's device: a quarter of the bytes of the float32 differences
        difference = difference_images(torch.from_numpy(images).to(model.device), self.reference.to(model.device))
        return model.cnn(camera_batch(difference))

    def predict(self, model: ForceFusionNet, indices: np.ndarray) -> torch.Tensor:
        return model.fuse(self.features_at(model, indices))

    def forces_n(self, indices: np.ndarray) -> torch.Tensor:
        """(B, rows, cols, 3) true forces in newtons."""
        return torch.from_numpy(np.asarray(self.frames.bin_forces_n[np.sort(indices)]))

    def target(self, indices: np.ndarray) -> torch.Tensor:
        return self.forces_n(indices) / self.force_scale_n


class FrontPart(nn.Module):
    """The network up to a cut as one graph, the difference image included: (B, C, H, W) uint8 frames and their
    (C, H, W) uint8 reference -> (B, C, features at the cut).

    A CachedSource runs it through ONNX Runtime rather than torch: on two cores it computed the conv trunk 1.6x
    faster (0.60 against 0.96 ms per frame, 4 frames per call; the features within 1e-5 of torch's, which reach
    about 30), and `make model` passes every training frame, its imperfect copies and the further draws through it.
    """

    def __init__(self, model: ForceFusionNet, cut: str):
        super().__init__()
        self.model, self.cut = model, cut

    def forward(self, images: torch.Tensor, reference: torch.Tensor) -> torch.Tensor:
        x = self.model.cnn.conv_features(camera_batch(difference_images(images, reference)))
        if self.cut == "hidden":
            x = self.model.cnn.first_layer(x)
        return x.reshape(images.shape[0], images.shape[1], -1)


class CachedSource:
    """Frames as the cached output of the model's front part up to `cut` ("trunk" or "hidden").

    The front part must stay frozen while this source is used (the caller sets requires_grad False on it).
    extra: more frames to learn from, in chunks (data.SceneDraws: further draws of the scene), of which only the
    features and targets are kept; they follow the N frames as M samples more, without an imperfect copy.
    augmentation: if given and active, an imperfect copy of each of the N frames follows as well (`Augmentation.
    apply_each`: frame i drawn from (`seed`, i)), with the same targets: sample N + M + i has frame i's.
    """

    def __init__(self, model: ForceFusionNet, frames: FrameSet, cut: str, augmentation: Augmentation | None = None,
                 seed: int = 0, extra: Iterable[FrameSet] = ()):
        if cut not in CUTS:
            raise ValueError(f"CachedSource: cut must be one of {CUTS}, got {cut!r}")
        self.cut = cut
        self.force_scale_n = model.force_scale_n
        extra_parts = []  # (features, targets) of each chunk of extra frames; their count is known only at the end
        for chunk in extra:
            if chunk.camera_ids != frames.camera_ids:
                raise ValueError(f"CachedSource: extra frames of cameras {list(chunk.camera_ids)}, the frames' are "
                                 f"{list(frames.camera_ids)}")
            extra_parts.append((self._front(model, chunk, cut), np.asarray(chunk.bin_forces_n)))
        self.extra_frames = sum(len(targets) for _, targets in extra_parts)
        n = len(frames)
        copied = n if augmentation is not None and augmentation.active else 0
        self._allocate(model, frames, n + self.extra_frames + copied)
        self._front(model, frames, cut, out=self._cache[:n])
        targets = np.asarray(frames.bin_forces_n)  # (N + M, rows, cols, 3); without extra frames the frames' own
        if self.extra_frames:
            targets = np.concatenate([targets, np.empty((self.extra_frames, *targets.shape[1:]), targets.dtype)])
        self.targets = torch.from_numpy(targets)
        start = n
        while extra_parts:  # each chunk's features freed once in place, so they are never held twice
            features, chunk_targets = extra_parts.pop(0)
            self._cache[start:start + len(features)] = features
            self.targets[start:start + len(features)] = torch.from_numpy(chunk_targets)
            start += len(features)
        self.redraw_copy(model, frames, augmentation, seed)

    def _allocate(self, model: ForceFusionNet, frames: FrameSet, samples: int) -> None:
        """One float32 tensor for every cached sample. The imperfect copy is redrawn into its place in every head
        cycle, so the cache is never held beside a new one (it is one of the largest arrays of training: 1.7 GB for
        make model's 203280 samples of 4 x 512 features)."""
        self._cache = _features_at_cut(model, frames, self.cut, samples)

    def redraw_copy(self, model: ForceFusionNet, frames: FrameSet, augmentation: Augmentation | None,
                    seed: int) -> None:
        """Replace the imperfect copy (if any) by one drawn from `seed`, as the constructor would with this seed; the
        features of the frames and the extra frames, which do not change, are kept rather than computed again."""
        samples = len(self.targets)
        if augmentation is None or not augmentation.active:
            self.features = self._cache[:samples]
            return
        if len(self._cache) < samples + len(frames):  # built without a copy: the frames' features move to a new cache
            kept = self._cache[:samples]
            self._allocate(model, frames, samples + len(frames))
            self._cache[:samples] = kept
        self.features = self._cache[:samples + len(frames)]
        self._front(model, frames, self.cut, lambda images, start: augmentation.apply_each(images, seed, start),
                    out=self.features[samples:])

    def frames_only(self) -> CachedSource:
        """This source without the imperfect copy: the cached features of the frames and the extra frames (shared,
        not copied)."""
        view = copy.copy(self)
        view.features = self._cache[:len(self.targets)]
        return view

    @staticmethod
    def _front(model: ForceFusionNet, frames: FrameSet, cut: str, change=None,
               out: torch.Tensor | None = None) -> torch.Tensor:
        """(N, C, features at the cut) of `frames` through ONNX Runtime, each chunk of images first passed through
        change(images, first frame index) if given; written into `out` if given (a float32 tensor of that shape),
        else into a new tensor.

        Why torch runs on one thread meanwhile: its pool's threads wait busily for work after each parallel call (the
        imperfect copy's noise), and took a core from ONNX Runtime's, whose own busy wait between calls then made
        things worse. With torch on one thread the session's threads may wait busily and are faster for it: 0.81 ms
        per frame with the imperfect copy against 1.10 with torch's two threads, the session's sleeping and 4 frames
        per call, 0.41 against 0.58 without it (2048 frames of the default scene, 2026-11-28)."""
        if out is None:
            out = _features_at_cut(model, frames, cut, len(frames))
        reference = np.ascontiguousarray(frames.reference)
        front = FrontPart(model, cut).eval()
        example = (torch.from_numpy(np.asarray(frames.images[:1])), torch.from_numpy(reference))
        session = onnx_session(onnx_bytes(front, example, "features"), torch.get_num_threads())
        with torch_threads(1):
            for start in range(0, len(frames), FRONT_BATCH_FRAMES):
                images = np.asarray(frames.images[start:start + FRONT_BATCH_FRAMES])
                if change is not None:
                    images = change(images, start)
                images = with_cameras_at_rest(images, reference, frames.camera_ok[start:start + FRONT_BATCH_FRAMES])
                features = session.run(None, {"images": np.ascontiguousarray(images), "reference": reference})[0]
                out[start:start + len(features)] = torch.from_numpy(features)
        return out

    def __len__(self) -> int:
        return len(self.features)

    def features_at(self, model: ForceFusionNet, indices: np.ndarray) -> torch.Tensor:
        """(B * C, camera_features) CNN features of the frames at `indices`, from the cache."""
        x = self.features[np.sort(indices)].to(model.device)
        b, c, n = x.shape
        x = x.reshape(b * c, n)
        x = model.cnn.first_layer(x) if self.cut == "trunk" else model.cnn.first_layer.dropout(x)
        return model.cnn.last_layer(x)

    def predict(self, model: ForceFusionNet, indices: np.ndarray) -> torch.Tensor:
        return model.fuse(self.features_at(model, indices))

    def forces_n(self, indices: np.ndarray) -> torch.Tensor:
        """(B, rows, cols, 3) true forces in newtons (a sample of the copy has its frame's)."""
        return self.targets[np.sort(indices) % len(self.targets)]

    def target(self, indices: np.ndarray) -> torch.Tensor:
        return self.forces_n(indices) / self.force_scale_n


@contextmanager
def torch_threads(threads: int) -> Iterator[None]:
    """torch's intra-op thread count set to `threads` inside the block, restored after it."""
    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(before)


def _features_at_cut(model: ForceFusionNet, frames: FrameSet, cut: str, samples: int) -> torch.Tensor:
    """An empty float32 (samples, C, features at the cut) tensor for the front part's output of `frames`' cameras."""
    width = model.config.flat_features if cut == "trunk" else model.config.hidden_features
    return torch.empty((samples, len(frames.camera_ids), width), dtype=torch.float32)


#: The weakest blur an augmented frame gets (pixels): a Gaussian below this hardly changes an image.
MIN_BLUR_SIGMA_PX = 0.3


@dataclass(frozen=True)
class Augmentation:
    """Camera imperfections for a copy of the training frames, in the simulator's order (effects.py): on a share of
    them one camera knocked askew (its image shifted and turned against the reference, as CameraMisalignment does),
    defocus blur on another share, then extra sensor noise on all, each drawn per frame. The blur acts on the
    simulated frames, which carry the scene's own sensor noise, so it smooths that noise too; the extra noise after
    it stands in for the sensor's.

    Why: the head learns from the conv trunk's features of images unlike the training's, which the trunk itself
    never saw. With noise and blur alone (up to 1.2 grey levels, a fifth blurred with up to 1.2 px) the model kept
    its error in distribution and six of the eight windows of the effects scene lost half to four fifths of their
    total-force error, but the misaligned camera's doubled; one camera askew on a tenth of the frames as well cuts
    that window's error six-fold for 2 % more error per bin in distribution (docs/learning.md).
    """

    noise_sigma: float = 0.0     # Gaussian noise, standard deviation per frame from [0, this] grey levels
    blur_fraction: float = 0.0   # share of the frames defocused
    blur_sigma_px: float = 1.2   # their Gaussian blur, sigma per frame from [MIN_BLUR_SIGMA_PX, this] pixels
    misalign_fraction: float = 0.0   # share of the frames in which one camera (drawn per frame) is knocked askew
    misalign_shift_px: float = 2.0   # its image shift, per axis from [-this, this] pixels
    misalign_rotation_deg: float = 2.0  # its rotation about the image centre, from [-this, this] degrees

    def __post_init__(self):
        if not 0.0 <= self.noise_sigma <= 255.0:
            raise ValueError(f"Augmentation.noise_sigma must be in [0, 255] grey levels, got {self.noise_sigma}")
        if not 0.0 <= self.blur_fraction <= 1.0:
            raise ValueError(f"Augmentation.blur_fraction must be in [0, 1], got {self.blur_fraction}")
        if not MIN_BLUR_SIGMA_PX <= self.blur_sigma_px <= 10.0:
            raise ValueError(f"Augmentation.blur_sigma_px must be in [{MIN_BLUR_SIGMA_PX}, 10] pixels, got "
                             f"{self.blur_sigma_px}")
        if not 0.0 <= self.misalign_fraction <= 1.0:
            raise ValueError(f"Augmentation.misalign_fraction must be in [0, 1], got {self.misalign_fraction}")
        if not 0.0 <= self.misalign_shift_px <= 16.0:
            raise ValueError(f"Augmentation.misalign_shift_px must be in [0, 16] pixels, got {self.misalign_shift_px}")
        if not 0.0 <= self.misalign_rotation_deg <= 45.0:
            raise ValueError(f"Augmentation.misalign_rotation_deg must be in [0, 45] degrees, got "
                             f"{self.misalign_rotation_deg}")

    @property
    def active(self) -> bool:
        """Whether `apply` changes anything."""
        return self.noise_sigma > 0 or self.blur_fraction > 0 or self.misalign_fraction > 0

    def apply_each(self, images: np.ndarray, seed: int, first_index: int) -> np.ndarray:
        """`apply` frame by frame, frame `first_index + i` drawn from (seed, first_index + i): a frame's copy does not
        depend on which frames share its batch."""
        return np.stack([self.apply(image[None], np.random.default_rng([seed, first_index + i]))[0]
                         for i, image in enumerate(images)])

    def apply(self, images: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """(N, C, H, W) uint8 frames -> a changed uint8 copy (rounded and clipped, never wrapped)."""
        out = np.array(images, dtype=np.uint8)
        if self.misalign_fraction > 0:
            askew = np.flatnonzero(rng.random(len(out)) < self.misalign_fraction)
            cameras = rng.integers(0, out.shape[1], len(askew))
            shifts = rng.uniform(-self.misalign_shift_px, self.misalign_shift_px, (len(askew), 2))
            rotations = rng.uniform(-self.misalign_rotation_deg, self.misalign_rotation_deg, len(askew))
            for i, c, shift, rotation in zip(askew, cameras, shifts, rotations, strict=True):
                out[i, c] = misalign(out[i, c], shift, rotation)
        blurred = rng.random(len(out)) < self.blur_fraction
        sigmas = rng.uniform(MIN_BLUR_SIGMA_PX, self.blur_sigma_px, len(out))
        for i in np.flatnonzero(blurred):
            for c in range(out.shape[1]):
                out[i, c] = defocus(out[i, c], sigmas[i])
        if self.noise_sigma > 0:
            # torch's normal generator is vectorised: with it the noise takes 9 ms per 32 frames instead of numpy's
            # 23 ms (260 M pixels per cycle). Its draws are the same for any thread count, but may differ in the last
            # bits between CPU instruction sets (as the conv trunk's sums do): a copy is reproducible on one machine.
            sigma = torch.from_numpy(rng.uniform(0.0, self.noise_sigma, len(out)).astype(np.float32))
            generator = torch.Generator().manual_seed(int(rng.integers(2**63)))
            noisy = torch.from_numpy(out) + torch.randn(out.shape, generator=generator) * sigma[:, None, None, None]
            out = noisy.round_().clamp_(0, 255).to(torch.uint8).numpy()
        return out


@torch.no_grad()
def normalised_rmse(model: ForceFusionNet, source, batch_size: int = 64) -> float:
    """RMSE over all frames of `source` (normalised forces), evaluation mode."""
    model.eval()
    total, count = 0.0, 0
    for start in range(0, len(source), batch_size):
        idx = np.arange(start, min(start + batch_size, len(source)))
        prediction = source.predict(model, idx)
        err = prediction - source.target(idx).to(prediction.device)
        total += float(torch.sum(err.double() ** 2))
        count += err.numel()
    return float(np.sqrt(total / max(count, 1)))
