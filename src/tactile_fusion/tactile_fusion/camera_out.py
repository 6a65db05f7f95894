"""What the model is shown for a camera that is out (missing from a bundle, black, frozen, unreadable) or whose frame
is its reference itself: that camera at rest. One rule for inference, evaluation and training, so that a model is
trained on what it is shown later."""

from __future__ import annotations

import functools

import numpy as np

#: Sensor noise (standard deviation, grey levels) of the view at rest: the default scene's
#: (config/scenes/paper_grid.yaml), about what a camera's own noise is.
REST_NOISE_GREY_LEVELS = 1.0
REST_NOISE_SEED = 0


def rest_view(reference: np.ndarray) -> np.ndarray:
    """(C, H, W) uint8 reference frames -> what the cameras show at rest: the reference with REST_NOISE_GREY_LEVELS of
    sensor noise, one fixed pattern, so that an estimate does not depend on a draw.

    Why not the reference itself: that is a difference of exactly 0, which no training frame has (every frame
    carries sensor noise), and the model shipped on 2026-11-24 read it as contact: one camera out on a surface at
    rest gave 0.37-0.45 N of total Fz, against 0 with this view, which also errs 3 % less per bin and 7 % more in
    total with presses (docs/learning.md, "A camera out").
    """
    return np.clip(reference + _rest_noise(reference.shape), 0, 255).astype(np.uint8)


def with_cameras_at_rest(images: np.ndarray, reference: np.ndarray, camera_ok: np.ndarray | None) -> np.ndarray:
    """(B, C, H, W) uint8 frames with every camera that `camera_ok` (B, C) marks False (None: all ok), and every
    camera whose frame equals its (C, H, W) reference pixel for pixel, shown at rest (`rest_view`); the frames
    themselves when no camera is either.

    Why a frame equal to its reference: it is a difference of exactly 0, the failure `rest_view` avoids, and no camera
    with sensor noise delivers one. It comes from a camera that shows one image all the time (a still image or a
    looped video as the source, a lens cap or an LED off from start-up, so that the reference is that image too) or
    from a scene simulated without noise. Read as it is, the model shipped on 2026-11-24 reported 1.6 N of contact for
    such a frame from every camera, and 0.37-0.45 N for one such camera beside three with noise."""
    ok = (np.ones(images.shape[:2], dtype=bool) if camera_ok is None else np.asarray(camera_ok, dtype=bool))
    if ok.shape != images.shape[:2]:
        raise ValueError(f"camera_ok: expected shape {images.shape[:2]} (frames, cameras), got {ok.shape}")
    ok = ok & (images != reference[None]).any(axis=(2, 3))
    if ok.all():
        return images
    return np.where(ok[:, :, None, None], images, rest_view(reference)[None])


@functools.cache
def _rest_noise(shape: tuple[int, ...]) -> np.ndarray:
    noise = np.rint(np.random.default_rng(REST_NOISE_SEED).normal(0.0, REST_NOISE_GREY_LEVELS, shape)).astype(np.int16)
    noise.setflags(write=False)  # shared by every call of this shape
    return noise
