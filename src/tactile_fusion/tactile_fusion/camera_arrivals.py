"""When each camera's images last arrived, by which the bundle node finds a camera silent."""

from __future__ import annotations

from collections.abc import Iterable


class CameraArrivals:
    """The last arrival of each camera's images, on a clock that may step back or not run yet.

    Readings are seconds of the bundle node's arrival clock: the steady clock, or with use_sim_time the simulated
    clock, which reads 0 until the first /clock message and steps back when a bag played with --loop starts again.
    - A step back (a reading below the latest) shifts every arrival by the step, so that each camera keeps its age:
      on the raw readings every camera, a silent one too, was live for the length of the step (a camera silent in a
      looped bag came back at every loop, and the synchroniser waited for it; review).
    - A reading of 0 means the clock does not run yet: an arrival then counts from the first reading of the running
      clock (images that reached the node before the first /clock made every camera silent when it came; review).
    """

    def __init__(self, camera_ids: Iterable[str]):
        self.last_s = dict.fromkeys(camera_ids, -float("inf"))
        self._waiting: set[str] = set()  # arrived while the clock did not run
        self._latest_s: float | None = None
        self._clock_changed = False

    def arrived(self, camera_ids: Iterable[str], reading_s: float) -> None:
        """Images of `camera_ids` arrived at `reading_s`."""
        if self._observe(reading_s):
            self.last_s.update(dict.fromkeys(camera_ids, reading_s))
        else:
            self._waiting.update(camera_ids)

    def live(self, reading_s: float, timeout_s: float) -> tuple[str, ...]:
        """The cameras whose images arrived less than `timeout_s` before `reading_s`, in their given order. While the
        clock does not run: those that sent since, and those live at its latest reading (a simulation reset to 0
        revived a camera silent for long: review)."""
        if self._observe(reading_s):
            return tuple(c for c, t in self.last_s.items() if reading_s - t < timeout_s)
        return tuple(c for c, t in self.last_s.items()
                     if c in self._waiting or self._latest_s is not None and self._latest_s - t < timeout_s)

    def clock_changed(self) -> None:
        """The readings come from another clock from now on (use_sim_time set or cleared while the node runs): each
        camera keeps its age at the latest reading of the old clock, counted on from the new clock's first reading. The
        steady clock's hours since boot against a bag's simulated seconds read as a step: a step forward made every
        camera silent at once."""
        self._clock_changed = True

    def _observe(self, reading_s: float) -> bool:
        """Take a reading: shift the arrivals for a step back or another clock, date those that waited for the clock;
        whether it runs."""
        if not reading_s:
            return False
        if self._latest_s is not None and (reading_s < self._latest_s or self._clock_changed):
            step_s = reading_s - self._latest_s
            self.last_s = {c: t + step_s for c, t in self.last_s.items()}
        self._clock_changed = False
        self._latest_s = reading_s
        self.last_s.update(dict.fromkeys(self._waiting, reading_s))
        self._waiting.clear()
        return True
