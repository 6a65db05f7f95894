"""What every command line of the stack does alike (no ROS import)."""

import functools
import os
import signal
import sys
from collections.abc import Callable

# A shell reports a command killed by SIGPIPE as 128 + its number; a command that stops on a closed pipe says so.
CLOSED_PIPE_EXIT = 128 + signal.SIGPIPE


def stops_quietly_on_closed_pipe(main: Callable[..., int]) -> Callable[..., int]:
    """Make a command line's `main` end like a shell tool when its reader goes away (`tactile-fusion eval | head`).

    Python ignores SIGPIPE, so a write to a pipe whose reader has exited raises BrokenPipeError, and the
    interpreter would print its traceback and a second one when it flushes stdout at exit. Instead the command
    stops there with CLOSED_PIPE_EXIT; `finally` blocks (a node graph's shutdown) have run by then.
    """

    @functools.wraps(main)
    def wrapped(*args, **kwargs) -> int:
        try:
            return main(*args, **kwargs)
        except BrokenPipeError:
            # The flush at exit would fail again: point stdout at /dev/null (the Python docs' recipe for SIGPIPE).
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
            return CLOSED_PIPE_EXIT

    return wrapped
