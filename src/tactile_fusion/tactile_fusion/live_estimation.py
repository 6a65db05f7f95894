"""Live estimation without ROS: the reference frames (shared by the fusion node and offline bag evaluation) and
the check that the fusion node keeps up with its cameras.

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


class ProcessingLoad:
    """Whether handling a bundle takes longer, on average, than the time between two of them.

    A node slower than its input drops nothing at first: the bundles wait in its subscription queue and every
    estimate is older than the one before, until the queue is full (the torch fp16 backend at 22 ms per frame
    behind 40 Hz cameras: estimates 60-270 ms old). Nothing in the estimates shows that, hence this check.
    Both averages are exponential with weight `smoothing` for the newest value, so that one slow bundle (the
    first inference) or one missing bundle does not count as falling behind.

    The time between bundles comes from their capture stamps, so that cameras running at another rate than the
    sensor's nominal one (a camera node's `rate_hz`) are judged by their real rate; until two stamps have come,
    the nominal `frame_period_s` stands in. A stamp that does not advance (a repeated or reordered bundle) is
    not counted. A bag replayed faster than real time delivers bundles faster than their stamps say: that goes
    unnoticed.
    """

    def __init__(self, frame_period_s: float, smoothing: float = 0.1):
        if not frame_period_s > 0 or not 0 < smoothing <= 1:
            raise ValueError(f"need frame_period_s > 0 and 0 < smoothing <= 1, got {frame_period_s}, {smoothing}")
        self.frame_period_s = frame_period_s
        self.smoothing = smoothing
        self.mean_s: float | None = None
        self._last_stamp_s: float | None = None
        self._period_measured = False

    def add(self, duration_s: float, stamp_s: float) -> bool:
        """Count one bundle's handling time and capture stamp; True while the average time exceeds the average
        time between bundles."""
        self._count_stamp(stamp_s)
        if self.mean_s is None:
            self.mean_s = duration_s
        else:
            self.mean_s += self.smoothing * (duration_s - self.mean_s)
        return self.mean_s > self.frame_period_s

    def _count_stamp(self, stamp_s: float) -> None:
        if self._last_stamp_s is not None and stamp_s <= self._last_stamp_s:
            return
        if self._last_stamp_s is not None:
            interval_s = stamp_s - self._last_stamp_s
            if self._period_measured:
                self.frame_period_s += self.smoothing * (interval_s - self.frame_period_s)
            else:
                self.frame_period_s, self._period_measured = interval_s, True
        self._last_stamp_s = stamp_s
