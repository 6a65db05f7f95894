"""The thread in which a camera node makes its blocking OpenCV calls."""

from __future__ import annotations

import threading
from collections.abc import Callable


class CaptureThread:
    """Runs `read_once` in a daemon thread of its own at each `tick()` (the node's timer), one call at a time. The ticks
    that come while a call runs are folded into one call right after it, as rcl folds the ticks that a timer callback
    blocked past into one late call: a source a little slower than the rate reads back to back (dropping those ticks
    halved the rate of a read 10 % longer than the period: review).

    Why a thread: OpenCV's open, grab and retrieve block, on a device until its next frame, and on a stream that does
    not answer for FFmpeg's open and read timeouts (30 s each; measured: a URL whose server accepts and never
    answers). Made in the timer callback, they held the executor, and a Ctrl-C, or the SIGINT of `ros2 launch` (which
    sends SIGTERM 5 s later, and SIGKILL 5 s after that), waited for them (review). The executor now stays free, and
    the process can end while the thread still waits: it is a daemon thread.

    An exception raised by `read_once` ends the thread; it is kept, and `on_error` is called (the trigger of a guard
    condition of the node), whose callback in the executor's thread calls `raise_error`: the error ends the node at
    once, as it did when the call was made in the timer callback (a thread's exception would be printed and forgotten,
    and the node would run on without a frame).
    """

    def __init__(self, read_once: Callable[[], None], name: str, on_error: Callable[[], None]) -> None:
        self._read_once = read_once
        self._on_error = on_error
        self._reading = threading.Lock()  # held while read_once runs
        self._wanted = threading.Event()
        self._closed = False
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def tick(self) -> None:
        """Ask for a call of read_once: now, or right after the one running (however many ticks came meanwhile)."""
        self._wanted.set()

    def raise_error(self) -> None:
        """Raise what read_once raised, if it did (in the executor's thread: see the class docstring)."""
        if self._error is not None:
            raise self._error

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
                except BaseException as exc:  # raised again by raise_error(), in the executor's thread
                    self._error = exc
                    self._on_error()
                    return
