"""A command line whose reader goes away stops quietly, in a real process with a real pipe."""

import subprocess
import sys
import textwrap

import pytest

from tactile_description.command_line import CLOSED_PIPE_EXIT, stops_quietly_on_closed_pipe

PRINTS_AFTER_A_PAUSE = textwrap.dedent("""
    import time
    from tactile_description.command_line import stops_quietly_on_closed_pipe

    @stops_quietly_on_closed_pipe
    def main():
        time.sleep(0.5)  # the reader has gone by now
        try:
            print("a line nobody reads", flush=True)
        finally:
            print("cleaned up", file=__import__("sys").stderr)
        return 0

    raise SystemExit(main())
""")


def test_a_closed_pipe_ends_the_command_with_the_shell_status_and_no_traceback():
    process = subprocess.Popen([sys.executable, "-c", PRINTS_AFTER_A_PAUSE], stdout=subprocess.PIPE,
                               stderr=subprocess.PIPE, text=True)
    process.stdout.close()  # as `| head` does once it has what it wants
    _, stderr = process.communicate(timeout=60)
    assert process.returncode == CLOSED_PIPE_EXIT == 141
    assert stderr.strip() == "cleaned up"  # finally ran, and nothing else was said


def test_main_returns_its_own_status_and_other_errors_pass_through():
    assert stops_quietly_on_closed_pipe(lambda code: code)(3) == 3

    @stops_quietly_on_closed_pipe
    def failing():
        raise ConnectionResetError("not a closed stdout")

    with pytest.raises(ConnectionResetError):
        failing()
