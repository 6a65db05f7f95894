"""How often each camera captures, from its images' stamps, and whether the bundle node's synchronisation settings fit
that rate.

The settings' defaults follow the sensor description's frame rate (approximate_sync.camera_sync_settings), but a camera
node run at its own `rate_hz`, or a camera that cannot keep up, sends at another rate. That broke the bundles without
saying why: a camera silent between two frames for longer than `camera_timeout_s` was left out and back with every
frame; slow cameras without a common trigger capture further apart than `max_spread_s` (`too_wide` drops); a camera
faster than `min_period_s` assumes lets a bundle out before a tighter frame arrives.
"""

from __future__ import annotations

import statistics
from collections import deque
from dataclasses import dataclass
from itertools import pairwise

#: The period is the median of this many intervals: a lost frame (one interval of two periods) does not move it.
INTERVALS = 4


class CameraPeriods:
    """Each camera's frame period: the median of its last INTERVALS intervals between capture stamps."""

    def __init__(self) -> None:
        self._stamps: dict[str, deque[float]] = {}

    def add(self, camera_id: str, stamp_s: float) -> None:
        """Record an image's capture stamp. A stamp at or before the camera's last one (a bag replayed again, a
        restarted camera, a clock set back) starts its record over: no interval across it is a frame period."""
        stamps = self._stamps.setdefault(camera_id, deque(maxlen=INTERVALS + 1))
        if stamps and stamp_s <= stamps[-1]:
            stamps.clear()
        stamps.append(stamp_s)

    def period_s(self, camera_id: str) -> float | None:
        """The camera's frame period in seconds, or None until INTERVALS intervals are recorded."""
        stamps = self._stamps.get(camera_id, ())
        if len(stamps) <= INTERVALS:
            return None
        return statistics.median(later - earlier for earlier, later in pairwise(stamps))


@dataclass(frozen=True)
class SyncSettings:
    """The bundle node's settings that a camera's frame period must fit (seconds)."""

    cameras: int
    max_spread_s: float
    min_period_s: float
    camera_timeout_s: float


def period_misfits(period_s: float, settings: SyncSettings) -> list[str]:
    """What goes wrong for a camera capturing every `period_s`, one phrase per setting it does not fit (none: it fits).

    Cameras without a common trigger capture at phases of their own, n of them up to (1 - 1/n) of their period apart
    (approximate_sync.camera_sync_settings)."""
    misfits = []
    if period_s >= settings.camera_timeout_s:
        misfits.append(f"a frame every {period_s:.3g} s is no sooner than camera_timeout_s "
                       f"({settings.camera_timeout_s:.3g} s): the camera is left out of the bundles and back with "
                       "every frame")
    spread_s = (1 - 1 / settings.cameras) * period_s
    if spread_s > settings.max_spread_s:
        misfits.append(f"{settings.cameras} cameras without a common trigger capture up to {spread_s:.3g} s apart at "
                       f"this rate, more than max_spread_s ({settings.max_spread_s:.3g} s): such frames are dropped as "
                       "too wide")
    if period_s < settings.min_period_s:
        misfits.append(f"frames come sooner than min_period_s ({settings.min_period_s:.3g} s) says they can: a bundle "
                       "may go out before a tighter frame arrives")
    return misfits
