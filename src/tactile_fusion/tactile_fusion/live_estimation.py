"""Live estimation without ROS: the reference frames (shared by the fusion node and offline bag evaluation), the
check that the fusion node keeps up with its cameras, and the count of bundles lost on the way to it.

The model needs each camera's frame at rest; the live graph takes the pixel-wise mean of the first `count`
complete bundles (nothing may touch the surface meanwhile) and can be asked to take it again.
"""

from __future__ import annotations

from collections import deque

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
    The time per bundle is an exponential average with weight `smoothing` for the newest, so that one slow bundle
    (the first inference) does not count as falling behind.

    The time between bundles is measured from their capture stamps, so that cameras running at another rate than
    the sensor's nominal one (a camera node's `rate_hz`) are judged by their real rate: of the last
    `PERIOD_INTERVALS` intervals between consecutive stamps, the median of those shorter than 1.5 times their
    `PERIOD_PERCENTILE`th percentile, once `MIN_INTERVALS` have come (the nominal period until then). Not a plain
    mean or median: a node that has fallen behind far enough to fill its queue sees only the bundles the queue
    kept, whose stamps are a frame period apart or a multiple of it, and an average over all of them would grow
    with the node's own slowness and hide it. Not the low percentile itself: stamps jitter (a bundle's stamp is
    the median of its cameras'), which would put it a millisecond or two below the real period.
    What stamps cannot tell apart goes unnoticed here: a node exactly k times slower than its cameras, without any
    spread in its time per bundle, looks like cameras k times slower; a bag replayed faster than real time
    delivers bundles faster than their stamps say. Both lose bundles from a full queue, which `BundleSequence`
    counts. A stamp that does not advance (a repeated or reordered bundle) is not counted.
    """

    PERIOD_INTERVALS = 64
    PERIOD_PERCENTILE = 10
    MIN_INTERVALS = 8

    def __init__(self, nominal_period_s: float, smoothing: float = 0.1):
        if not nominal_period_s > 0 or not 0 < smoothing <= 1:
            raise ValueError(f"need nominal_period_s > 0 and 0 < smoothing <= 1, got {nominal_period_s}, {smoothing}")
        self.nominal_period_s = nominal_period_s
        self.smoothing = smoothing
        self.mean_s: float | None = None
        self._intervals_s: deque[float] = deque(maxlen=self.PERIOD_INTERVALS)
        self._last_stamp_s: float | None = None

    @property
    def period_s(self) -> float:
        """The time between bundles as measured (the nominal period until enough stamps have come)."""
        if len(self._intervals_s) < self.MIN_INTERVALS:
            return self.nominal_period_s
        intervals = np.asarray(self._intervals_s)
        low = np.percentile(intervals, self.PERIOD_PERCENTILE)
        return float(np.median(intervals[intervals < 1.5 * low]))

    def add(self, duration_s: float, stamp_s: float) -> bool:
        """Count one bundle's handling time and capture stamp; True while the average time per bundle exceeds
        the time between bundles."""
        if self._last_stamp_s is None or stamp_s > self._last_stamp_s:
            if self._last_stamp_s is not None:
                self._intervals_s.append(stamp_s - self._last_stamp_s)
            self._last_stamp_s = stamp_s
        if self.mean_s is None:
            self.mean_s = duration_s
        else:
            self.mean_s += self.smoothing * (duration_s - self.mean_s)
        return self.mean_s > self.period_s


class BundleSequence:
    """Bundles lost before they reached this subscriber, from the gaps in their `sequence` numbers.

    The bundle node numbers its bundles 0, 1, 2, ...; a jump means the bundles in between were lost: the
    subscription queue overflowed (the subscriber is slower than the cameras) or the network dropped them. A
    number at or below the last one means the bundle node restarted (or a recording starts over): counting
    goes on from the new number and nothing counts as lost.
    """

    def __init__(self) -> None:
        self.last: int | None = None
        self.lost = 0      # bundles lost in all
        self.restarts = 0  # times the numbering went back

    def add(self, sequence: int) -> int:
        """Count one bundle's number; returns how many bundles were lost right before it."""
        if self.last is not None and sequence <= self.last:
            self.restarts += 1
            gap = 0
        else:
            gap = 0 if self.last is None else sequence - self.last - 1
        self.last = sequence
        self.lost += gap
        return gap
