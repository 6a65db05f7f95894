"""CaptureThread: the camera node's blocking OpenCV calls, one at a time, off the executor's thread."""

import threading
import time

import pytest

from tactile_camera_driver.capture_thread import CaptureThread

WAIT_S = 10.0  # for an event that comes at once unless the code is wrong


class BlockingRead:
    """A read_once that records its calls and, while `released` is clear, waits in its call as OpenCV's open does."""

    def __init__(self):
        self.calls = 0
        self.called = threading.Semaphore(0)
        self.released = threading.Event()
        self.released.set()
        self.threads = []

    def __call__(self):
        self.calls += 1
        self.threads.append(threading.current_thread())
        self.called.release()
        assert self.released.wait(WAIT_S)


def wait_until_idle(capture):
    """Until the read in progress has returned (a tick before that would ask for one more read after it)."""
    deadline = time.monotonic() + WAIT_S
    while capture._reading.locked():
        assert time.monotonic() < deadline
        time.sleep(0.001)


def test_each_tick_reads_once_in_a_thread_of_its_own():
    read = BlockingRead()
    capture = CaptureThread(read, "cam0 capture", on_error=lambda: None)
    for expected in (1, 2, 3):
        capture.tick()
        assert read.called.acquire(timeout=WAIT_S)
        wait_until_idle(capture)
        assert read.calls == expected
    assert all(thread is not threading.current_thread() and thread.daemon for thread in read.threads)
    assert capture.close(WAIT_S)


def blocked_capture():
    """A CaptureThread whose first read has begun and blocks until its `released` is set."""
    read = BlockingRead()
    read.released.clear()
    capture = CaptureThread(read, "cam0 capture", on_error=lambda: None)
    capture.tick()
    assert read.called.acquire(timeout=WAIT_S)
    return read, capture


def test_ticks_while_a_read_blocks_fold_into_one_read_right_after_it():
    """As rcl folds the ticks a blocked timer callback missed into one late call: dropping them halved the rate of a
    source a little slower than the period (review)."""
    read, capture = blocked_capture()
    for _ in range(5):
        capture.tick()  # returns at once: the read still blocks
    read.released.set()
    assert read.called.acquire(timeout=WAIT_S)  # the one read right after
    assert not read.called.acquire(timeout=0.2)  # and no more
    assert read.calls == 2
    assert capture.close(WAIT_S)


def test_close_gives_up_on_a_read_that_still_blocks_and_starts_no_other():
    read, capture = blocked_capture()
    capture.tick()
    assert not capture.close(0.05)  # still blocked: the caller must not release what it reads from
    read.released.set()
    assert not read.called.acquire(timeout=0.2)  # the tick before the close starts nothing after it
    assert read.calls == 1


def test_close_waits_for_a_read_that_ends_within_its_timeout():
    read, capture = blocked_capture()
    threading.Timer(0.1, read.released.set).start()
    assert capture.close(WAIT_S)
    assert read.calls == 1


def test_an_error_of_a_read_wakes_the_caller_which_raises_it():
    """A thread's exception is printed and forgotten: the node would run on, publishing nothing."""
    woken = threading.Event()

    def read_once():
        raise RuntimeError("cannot decode the frame")

    capture = CaptureThread(read_once, "cam0 capture", on_error=woken.set)
    capture.raise_error()  # nothing to raise yet
    capture.tick()
    assert woken.wait(WAIT_S)
    with pytest.raises(RuntimeError, match="cannot decode the frame"):
        capture.raise_error()
    capture._thread.join(WAIT_S)
    assert not capture._thread.is_alive()  # the thread ended with the error
