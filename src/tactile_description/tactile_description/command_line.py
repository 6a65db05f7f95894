"""What every command line of the stack does alike (no ROS import)."""

import argparse
import contextlib
import functools
import os
import select
import signal
import sys
import threading
from collections.abc import Callable

from tactile_description.value_checks import is_number

# A shell reports a command killed by SIGPIPE as 128 + its number; a command that stops on a closed pipe says so.
CLOSED_PIPE_EXIT = 128 + signal.SIGPIPE
#: The exit status of a command refused for its input (argparse's too).
INPUT_ERROR_EXIT = 2


class StopSignal(BaseException):
    """A Ctrl-C (SIGINT) or SIGTERM that `stop_signals_raised` turned into an exception in the main thread. A
    BaseException, as KeyboardInterrupt is, so that no `except Exception` swallows it."""

    def __init__(self, number: int) -> None:
        super().__init__(signal.Signals(number).name)
        self.number = number

    @property
    def exit_status(self) -> int:
        """What a shell reports for a command the signal killed: 128 + its number."""
        return 128 + self.number

    @property
    def named(self) -> str:
        return "Ctrl-C" if self.number == signal.SIGINT else signal.Signals(self.number).name


@contextlib.contextmanager
def stop_signals_raised():
    """Raise StopSignal for a Ctrl-C or SIGTERM while the block runs; Python's handlers are restored afterwards.

    By default a SIGTERM (`kill`, a job scheduler's time limit) ends Python at once: no `finally` block or clean-up
    runs, so a command stopped so left what it had half made behind (an empty --out). Raised as an exception, it
    unwinds like a Ctrl-C, and the command can say in one line what it leaves.

    Raised inside a C extension's call, the StopSignal may come out as another error caused by it: pybind11's
    TypeError "Unable to convert function return value to a Python type!" from rclpy's deserialisation, onnxruntime's
    ImportError "initialization failed" from its import (3 of 26 Ctrl-Cs to `tactile-bag eval`, each a traceback; found
    by a walkthrough). Such an error is raised as its StopSignal again."""
    def raise_stop(number, _frame):
        raise StopSignal(number)

    with stop_signals_handled_by(raise_stop):
        try:
            yield
        except BaseException as error:
            stop = _stop_signal_behind(error)
            if stop is not None and stop is not error:
                raise stop from error
            raise


#: Ctrl-C and SIGTERM: how a user or a launcher stops a command or a node.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def stop_signals_handled_by(handler):
    """Both STOP_SIGNALS handled by `handler` (a function of the signal's number and frame, or signal.SIG_IGN) while the
    block runs; the handlers before it are back afterwards."""
    previous = {number: signal.signal(number, handler) for number in STOP_SIGNALS}
    try:
        yield
    finally:
        for number, before in previous.items():
            signal.signal(number, before)


class ArgumentParser(argparse.ArgumentParser):
    """argparse's parser, refusing its arguments in one line on stderr ("tactile-sim render: error: argument --count:
    ..."), as the commands refuse any other input, with INPUT_ERROR_EXIT. argparse printed its usage block first, 3 to
    9 lines (found by the docs walkthrough); `--help` shows it. Subcommands' parsers are of this class too
    (add_subparsers makes them of the parser's own class)."""

    def error(self, message: str):
        self.exit(INPUT_ERROR_EXIT, f"{self.prog}: error: {one_line(message)}\n")


def _stop_signal_behind(error: BaseException) -> StopSignal | None:
    """The StopSignal that `error` is, or that caused it (however far down its chain of causes), else None."""
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, StopSignal):
            return error
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return None


def error_exit(program: str, error: BaseException | str) -> int:
    """Report why a command refuses its input as one line on stderr (a YAML parser's message spans several: they are
    joined); INPUT_ERROR_EXIT, for `main` to return."""
    print(f"{program}: error: {one_line(error)}", file=sys.stderr)
    return INPUT_ERROR_EXIT


def one_line(error: BaseException | str) -> str:
    """An error's message on one line: its lines (a YAML parser's message spans several) and runs of spaces joined by
    single spaces."""
    return " ".join(str(error).split())


def whole_number_argument(minimum: int, unit: str, why: str = "", maximum: int | None = None):
    """An argparse type: a whole number of `unit` from `minimum` (to `maximum`, if given); `why`: the reason for the
    minimum, if it is not plain."""
    bound = f">= {minimum}" if maximum is None else f"from {minimum} to {maximum}"

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < minimum or (maximum is not None and value > maximum):
            raise argparse.ArgumentTypeError(f"must be a whole number of {unit} {bound}{why}, got {text!r}")
        return value
    return parse


def number_argument(low: float, unit: str | None, inclusive: bool = False, high: float | None = None):
    """An argparse type: a finite number of `unit` (None: a plain number) above `low` (at or above it, with
    `inclusive`), and at most `high` where given. float() alone would take "nan" and "inf", which every comparison lets
    through or which never ends a wait."""
    if high is None:
        bound = f"{'>=' if inclusive else '>'} {low:g}"
    else:
        bound = f"in {'[' if inclusive else '('}{low:g}, {high:g}]"
    what = "a finite number" if unit is None else f"a finite number of {unit}"

    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = None
        if not (is_number(value) and (value >= low if inclusive else value > low) and (high is None or value <= high)):
            raise argparse.ArgumentTypeError(f"must be {what} {bound}, got {text!r}")
        return value
    return parse


def stops_quietly_on_closed_pipe(main: Callable[..., int]) -> Callable[..., int]:
    """Make a command line's `main` end like a shell tool when its reader goes away (`tactile-fusion eval | head`).

    Python ignores SIGPIPE, so a write to a pipe whose reader has exited raises BrokenPipeError, and the
    interpreter would print its traceback and a second one when it flushes stdout at exit. Instead the command
    stops there with CLOSED_PIPE_EXIT; `finally` blocks (a node graph's shutdown) have run by then. A broken pipe to
    anything but stdout is raised as it is.
    """

    @functools.wraps(main)
    def wrapped(*args, **kwargs) -> int:
        try:
            return main(*args, **kwargs)
        except BrokenPipeError:
            if not _stdout_closed():
                raise  # a pipe to some other process broke: that is an error of its own
            # The flush at exit would fail again: point stdout at /dev/null (the Python docs' recipe for SIGPIPE).
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return CLOSED_PIPE_EXIT

    return wrapped


@contextlib.contextmanager
def stop_signals_ignored():
    """Ignore Ctrl-C and SIGTERM while the block runs: for the end of a command that a second Ctrl-C must not cut
    short, such as closing a recording, which a half-done close would leave unreadable; the stop is under way anyway.

    Ignored, not held back: a blocked signal would still reach the process through any thread that does not block it
    (DDS has several), and Python would raise KeyboardInterrupt in the main thread all the same. Python's handlers are
    restored afterwards; one installed outside Python (rclpy's) is not, so use this at the end of a ROS session.

    Outside the main thread it does nothing: Python runs signal handlers there only, and may set them there only (a
    library function that uses this, such as train_and_export, may run in another thread)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    with stop_signals_handled_by(signal.SIG_IGN):
        yield


def _stdout_closed() -> bool:
    """Whether standard output is a pipe whose reader has gone: polling its write end then reports an error (POLLERR;
    a failed write's data may already be dropped, so a flush cannot tell)."""
    try:
        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        return any(events & select.POLLERR for _, events in poller.poll(0))
    except (OSError, ValueError):  # no file descriptor behind sys.stdout
        return False
