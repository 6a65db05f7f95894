"""Live estimation without ROS: the loop that turns frames into estimates (`LiveEstimation`, shared by the fusion
node and offline bag evaluation so that the two estimate alike), the reference frames, the check that they still
match the cameras, the check that the fusion node keeps up with its cameras, and the count of bundles lost on the way
to it.

The model needs each camera's frame at rest; the live graph takes the pixel-wise mean of the first `count`
complete bundles (nothing may touch the surface meanwhile) and can be asked to take it again.

torch (and the model code) is imported where it is used: `tactile-bag record` and `play` import this module (through
tactile_bag.evaluate) without needing the model stack, which takes a second to import.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from tactile_description.value_checks import is_whole_number

if TYPE_CHECKING:
    from tactile_description import SensorDescription
    from tactile_fusion.inference import ForcePredictor

#: Complete bundles averaged into the reference frames (the fusion node's default `reference_bundles`).
REFERENCE_BUNDLES = 10
#: The most `reference_bundles` the fusion node takes: 10 s at 40 Hz. The bundles are held until the reference is
#: taken (64 KB each for four cameras) and nothing is published meanwhile: 100000 would be 6.5 GB (twice that while
#: averaged) and 42 min without an estimate.
MAX_REFERENCE_BUNDLES = 400
#: Bundles the reference capture waits for its complete ones before it does without the cameras missing from them
#: (ReferenceFrames): 2 s at the sensor's 40 Hz.
REFERENCE_PATIENCE_BUNDLES = 80
#: The most frames of a reference whose `mismatch_levels` give its rest levels (spread over them): a median needs no
#: more, and each costs about 0.8 ms in the bundle callback that completes the reference; 400 of them held it for
#: 0.3 s, 4 s beside other busy processes, and the bundles queued meanwhile were lost (review).
REST_LEVEL_FRAMES = 20


def mismatch_levels(images: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """(C,) how far each camera's image is from its reference: the 75th percentile of the absolute difference the
    model reads (`model.difference_images`: brightness compensated, saturated pixels as lower bounds), in grey levels.

    A press moves the particles in part of an image only and raises this a little above the sensor noise (the
    simulator's scenes, presses up to 1.5 mm deep, shear and up to four contacts included: at most 3.6 grey levels,
    1.0 at rest with sensor noise of sigma 1, 2.0 with sigma 1.5). What moves or changes every particle raises it all
    over (the effects scene, sigma 1.5: defocus blur 9.6, a camera shifted by 1.8 px and turned by 2 degrees 9.7, the
    gel's creep after half a pixel 3.1)."""
    import torch

    from tactile_fusion.model import difference_images

    difference = difference_images(torch.from_numpy(images[None]), torch.from_numpy(reference))[0]
    magnitude = difference.abs().reshape(len(images), -1)
    rank = -(-3 * magnitude.shape[1] // 4)  # the smallest value that 75 % of the pixels do not exceed
    return torch.kthvalue(magnitude, rank, dim=1).values.double().numpy() * 255.0


class ReferenceFrames:
    """The pixel-wise mean of the first `count` complete frames: each camera's image at rest, and how far the frames
    it was taken from lie from it (`rest_levels`; with one frame that cannot be told, and they stay None).

    A camera without usable images (dead at start-up, or out when the reference is taken again) would hold the
    reference up for good, and the fusion node would never publish. So once `patience` frames have come
    without `count` complete ones, the reference is taken from the last `count` frames over the cameras usable in
    each of them; `cameras` says which cameras it covers. The others have no reference frame (black): their images
    cannot be used until the reference is taken again.
    """

    def __init__(self, n_cameras: int, image_shape: tuple[int, int], count: int = REFERENCE_BUNDLES,
                 patience: int = REFERENCE_PATIENCE_BUNDLES):
        if not is_whole_number(count):
            raise ValueError(f"the reference needs a whole number of frames >= 1, got count={count!r}")
        self.count = count
        self.patience = max(count, patience)
        self.n_cameras, self.image_shape = n_cameras, image_shape
        self.frames_seen = 0  # since the capture began
        self._complete: list[np.ndarray] = []
        self._recent: deque[tuple[np.ndarray, np.ndarray]] = deque(maxlen=count)  # (frame, camera_ok)
        self.images: np.ndarray | None = None  # (C, H, W) uint8 once taken
        self.cameras: np.ndarray | None = None  # (C,) bool once taken: the cameras that have a reference frame
        self.rest_levels: np.ndarray | None = None  # (C,) grey levels once taken (`mismatch_levels`' median)
        # (C,) bool once taken from two frames or more: the cameras whose frames were all the same, pixel for pixel.
        # No camera with sensor noise does that; while such a camera's image equals its reference it is shown at
        # rest (camera_out.with_cameras_at_rest), whatever is on the surface.
        self.still: np.ndarray | None = None

    @property
    def frames_taken(self) -> int:
        """Complete frames counted so far (`count` once the reference is taken)."""
        return self.count if self.images is not None else len(self._complete)

    def reset(self) -> None:
        """Take the reference again from the next complete frames (e.g. after the gel has aged)."""
        self.frames_seen = 0
        self._complete = []
        self._recent.clear()
        self.images = self.cameras = self.rest_levels = self.still = None

    def add(self, images: np.ndarray, camera_ok: np.ndarray) -> bool:
        """Count one frame; True when this frame completed the reference."""
        if self.images is not None:
            return False
        if images.shape != (self.n_cameras, *self.image_shape):
            raise ValueError(f"reference frames are {(self.n_cameras, *self.image_shape)} (cameras, height, width), "
                             f"got {images.shape}")
        frame, ok = np.array(images, dtype=np.uint8), np.array(camera_ok, dtype=bool)
        self.frames_seen += 1
        self._recent.append((frame, ok))
        if ok.all():
            self._complete.append(frame)
        if len(self._complete) == self.count:
            self._take(self._complete, np.ones(self.n_cameras, dtype=bool))
            return True
        if self.frames_seen < self.patience:
            return False
        alive = np.logical_and.reduce([ok for _, ok in self._recent])  # `patience` >= `count`: the deque is full
        if not alive.any():
            return False
        self._take([frame for frame, _ in self._recent], alive)
        return True

    def _take(self, frames: list[np.ndarray], cameras: np.ndarray) -> None:
        self.images = np.rint(np.mean(frames, axis=0)).astype(np.uint8)
        self.images[~cameras] = 0
        self.cameras = cameras
        if len(frames) > 1:
            spread = np.linspace(0, len(frames) - 1, min(len(frames), REST_LEVEL_FRAMES)).round().astype(int)
            self.rest_levels = np.median([mismatch_levels(frames[i], self.images) for i in spread], axis=0)
            self.still = cameras & np.logical_and.reduce([(f == frames[0]).all(axis=(1, 2)) for f in frames[1:]])
        self._complete = []
        self._recent.clear()


@dataclass
class FrameResult:
    """What `LiveEstimation.add` made of one frame."""

    camera_ok: np.ndarray  # (C,) the cameras whose images were used (while the reference is taken: the frame's own)
    for_reference: bool = False  # the frame went into the reference (no estimate)
    reference_taken: bool = False  # ... and completed it
    forces: np.ndarray | None = None  # (rows, cols, 3) newtons; None for a reference frame or without a usable image
    unreferenced: np.ndarray | None = None  # (C,) cameras with a usable image but without a reference frame
    match_changed: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))  # ReferenceMatch.add's
    frozen_changed: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=int))  # FrozenCameras.add's


class LiveEstimation:
    """Frames in the sensor's camera order -> estimates, as the fusion node makes them: the reference is taken from
    the first frames (ReferenceFrames), then each frame is checked against it (ReferenceMatch) and goes through the
    predictor, which gets the frame's camera ids (so a sensor description listing the cameras in another order than
    the model's gives the same estimates) and the cameras to leave out (missing, unreadable, or without a reference
    frame: they report "no contact").

    Offline bag evaluation (tactile_bag.evaluate) runs the same loop, so that a bag and the live graph agree.
    """

    def __init__(self, predictor: ForcePredictor, sensor: SensorDescription, reference_bundles: int = REFERENCE_BUNDLES,
                 patience: int = REFERENCE_PATIENCE_BUNDLES):
        """Raises ModelFileError (a ValueError) unless the model fits the sensor (artifacts.check_model_fits)."""
        from tactile_fusion.artifacts import check_model_fits  # imports torch: see the module's docstring

        check_model_fits(predictor, sensor)
        self.predictor = predictor
        self.camera_ids: Sequence[str] = sensor.camera_ids
        self.reference = ReferenceFrames(sensor.n_cameras, (predictor.image_size, predictor.image_size),
                                         reference_bundles, patience)
        self.match: ReferenceMatch | None = None  # once the reference is taken from 2 frames or more
        self.frozen = FrozenCameras(sensor.n_cameras)

    def reset(self) -> None:
        """Take the reference again from the next frames."""
        self.reference.reset()
        self.match = None

    def add(self, images: np.ndarray, camera_ok: np.ndarray) -> FrameResult:
        """One frame: images (C, H, W) uint8 and camera_ok (C,) in the sensor's camera order.

        Raises what predict raises (InputError, FloatingPointError); such a frame changes no state.
        """
        camera_ok = np.asarray(camera_ok, dtype=bool)
        reference = self.reference
        if reference.images is None:
            taken = reference.add(images, camera_ok)
            if taken and reference.rest_levels is not None:
                self.match = ReferenceMatch(reference.rest_levels)
            return FrameResult(camera_ok, for_reference=True, reference_taken=taken)
        usable = camera_ok & reference.cameras
        result = FrameResult(usable, unreferenced=camera_ok & ~reference.cameras)
        if usable.any():
            result.forces = self.predictor.predict(images, reference.images, camera_ids=self.camera_ids,
                                                   camera_ok=usable)
        # After predict: a frame it refuses raises before the match's state changes, so no change goes unreported.
        if self.match is not None:
            result.match_changed = self.match.add(images, reference.images, usable)
        result.frozen_changed = self.frozen.add(images, usable)
        return result


class ReferenceMatch:
    """Which cameras' images no longer match their reference frames, for the hint to take the reference again.

    The model reads the difference of each image from its camera's reference and takes it for pressure. A camera
    knocked askew or refocused, or a gel that has crept or dimmed since the reference was taken, makes a difference
    all over the image, and the estimate errs 3-5 times more per bin (docs/nodes.md); only a new reference at rest
    helps. A camera counts as off its reference while the median of its last `CHECKS` `mismatch_levels`, one every
    `EVERY` frames (five a second at 40 Hz), exceeds its level when the reference was taken by more than `MARGIN`:
    the simulator's presses raise it by 2.6 grey levels at most, blur and a camera askew by 7.6 (see
    `mismatch_levels`), and a single frame does not decide. A contact wide enough to move the particles in most of a
    camera's view for a second would count too. Cameras not ok in a frame are not checked in it.
    """

    EVERY = 8
    CHECKS = 5
    MARGIN = 4.0

    def __init__(self, rest_levels: np.ndarray):
        self.limits = np.asarray(rest_levels, dtype=np.float64) + self.MARGIN
        self._levels = [deque(maxlen=self.CHECKS) for _ in self.limits]
        self.off = np.zeros(len(self.limits), dtype=bool)
        self._frames = 0

    def add(self, images: np.ndarray, reference: np.ndarray, camera_ok: np.ndarray) -> np.ndarray:
        """Count one frame; returns the indices of the cameras whose state (`off`) this frame changed."""
        self._frames += 1
        if self._frames % self.EVERY:
            return np.zeros(0, dtype=int)
        levels = mismatch_levels(images, reference)
        for camera in np.flatnonzero(camera_ok):
            self._levels[camera].append(levels[camera])
        median = np.array([np.median(q) if len(q) == self.CHECKS else np.nan for q in self._levels])
        decided = ~np.isnan(median)
        now_off = self.off.copy()
        now_off[decided] = median[decided] > self.limits[decided]
        changed = np.flatnonzero(now_off != self.off)
        self.off = now_off
        return changed

    def level(self, camera: int) -> float:
        """The median of the camera's last checks (grey levels); ValueError before its first (numpy's median of
        none is NaN)."""
        if not self._levels[camera]:
            raise ValueError(f"ReferenceMatch.level: camera {camera} has not been checked yet")
        return float(np.median(self._levels[camera]))


class FrozenCameras:
    """Which cameras send the same image, pixel for pixel, frame after frame: a camera or driver stuck on one frame,
    a still image as the source, a covered lens or an unlit LED. No camera with sensor noise does that even twice in
    a row; the model reads such a camera as it is (at rest while its image equals its reference, one fixed press
    otherwise), whatever happens on the surface. A camera counts as frozen after `FRAMES` equal images in a row (one
    second at 40 Hz), and as live again at its first image that differs. Cameras not ok in a frame are not checked
    in it. About 5 us a camera per frame."""

    FRAMES = 40

    def __init__(self, n_cameras: int):
        self._last: list[np.ndarray | None] = [None] * n_cameras
        self._repeats = np.zeros(n_cameras, dtype=int)  # images equal to the one before, in a row

    @property
    def frozen(self) -> np.ndarray:
        """(C,) bool: the cameras that count as frozen."""
        return self._repeats >= self.FRAMES

    def add(self, images: np.ndarray, camera_ok: np.ndarray) -> np.ndarray:
        """Count one frame; returns the indices of the cameras whose state (`frozen`) this frame changed."""
        before = self.frozen
        for camera in np.flatnonzero(camera_ok):
            last = self._last[camera]
            repeated = last is not None and np.array_equal(images[camera], last)
            self._repeats[camera] = self._repeats[camera] + 1 if repeated else 0
            self._last[camera] = np.array(images[camera])
        return np.flatnonzero(self.frozen != before)


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
