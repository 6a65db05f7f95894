"""The thread in which a camera node makes its blocking OpenCV calls."""

from __future__ import annotations

import threading
from collections.abc import Callable


class CaptureThread:
    """Runs `read_once` in a daemon thread of its own at each `tick()` (the node's timer), one call at a time: a tick
    that comes while the call before it still runs is skipped, as a timer callback that blocked made the timer skip.

    Why a thread: OpenCV's open, grab and retrieve block, on a device until its next frame, and on a stream that does
    not answer for FFmpeg's open and read timeouts (30 s each; measured: a URL whose server accepts and never
    answers). Made in the timer callback, they held the executor, and a Ctrl-C, or the SIGINT of `ros2 launch` (which
    sends SIGTERM and SIGKILL 5 s later), waited for them (review). The executor now stays free, and the process ends
    while the thread still waits: it is a daemon thread.

    An exception raised by `read_once` is kept and raised by the next `tick()`, in the executor's thread, so that it
    ends the node as it did when the call was made there (a thread's exception would be printed and forgotten, and
    the node would run on without a frame).
    """

    def __init__(self, read_once: Callable[[], None], name: str) -> None:
        self._read_once = read_once
        self._reading = threading.Lock()  # held while read_once runs
        self._wanted = threading.Event()
        self._closed = False
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def tick(self) -> None:
        """Ask for one call of read_once, unless one is asked for or running; raise what the last call raised."""
        if self._error is not None:
            error, self._error = self._error, None
            raise error
        if not (self._wanted.is_set() or self._reading.locked()):
            self._wanted.set()

    def close(self, timeout_s: float) -> bool:
        """Start no further call. True once no call runs (waiting up to `timeout_s` for the one running), so that the
        caller may release what read_once uses; False if one still blocks after that."""
        self._closed = True
        idle = self._reading.acquire(timeout=timeout_s)
        if idle:
            self._reading.release()
        self._wanted.set()  # wakes the thread, which sees _closed and ends
        return idle

    def _run(self) -> None:
        while True:
            self._wanted.wait()
            with self._reading:
                self._wanted.clear()
                if self._closed:
                    return
                try:
                    self._read_once()
                except BaseException as exc:  # raised again by tick(), in the executor's thread
                    self._error = exc
