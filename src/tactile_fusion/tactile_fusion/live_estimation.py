"""The reference frames of live estimation, without ROS: shared by the fusion node and offline bag evaluation.

The model needs each camera's frame at rest; the live graph takes the pixel-wise mean of the first `count`
complete bundles (nothing may touch the surface meanwhile) and can be asked to take it again.
"""

from __future__ import annotations

import numpy as np

#: Complete bundles averaged into the reference frames (the fusion node's default `reference_bundles`).
REFERENCE_BUNDLES = 10


class ReferenceFrames:
    """The pixel-wise mean of the first `count` complete frames: each camera's image at rest."""

    def __init__(self, n_cameras: int, image_shape: tuple[int, int], count: int = REFERENCE_BUNDLES):
        if count < 1:
            raise ValueError(f"the reference needs at least one frame, got count={count}")
        self.count = count
        self._sum = np.zeros((n_cameras, *image_shape), np.float64)
        self._frames = 0
        self.images: np.ndarray | None = None  # (C, H, W) uint8 once complete

    @property
    def frames_taken(self) -> int:
        return self._frames

    def reset(self) -> None:
        """Take the reference again from the next complete frames (e.g. after the gel has aged)."""
        self._sum[:] = 0
        self._frames = 0
        self.images = None

    def add(self, images: np.ndarray, camera_ok: np.ndarray) -> bool:
        """Count one frame (ignored unless every camera is ok); True when this frame completed the reference."""
        if self.images is not None or not np.all(camera_ok):
            return False
        self._sum += images
        self._frames += 1
        if self._frames < self.count:
            return False
        self.images = np.rint(self._sum / self._frames).astype(np.uint8)
        return True
