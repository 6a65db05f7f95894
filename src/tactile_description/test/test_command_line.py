"""What every command line does alike: one error line, argparse types, quiet stop on a closed pipe (in a real process
with a real pipe), stop signals ignored while a bag closes."""

import argparse
import os
import signal
import subprocess
import sys
import textwrap
import threading
import time

import pytest

from tactile_description.command_line import (
    CLOSED_PIPE_EXIT,
    INPUT_ERROR_EXIT,
    ArgumentParser,
    StopSignal,
    error_exit,
    number_argument,
    stop_signals_ignored,
    stop_signals_raised,
    stops_quietly_on_closed_pipe,
    whole_number_argument,
)

PRINTS_A_LINE = textwrap.dedent("""
    import sys
    from tactile_description.command_line import stops_quietly_on_closed_pipe

    @stops_quietly_on_closed_pipe
    def main():
        try:
            print("a line nobody reads", flush=True)
        finally:
            print("cleaned up", file=sys.stderr)
        return 0

    raise SystemExit(main())
""")


def test_a_closed_pipe_ends_the_command_with_the_shell_status_and_no_traceback():
    reader, writer = os.pipe()
    os.close(reader)  # the reader has gone before the command writes, as `| head` once it has what it wants
    process = subprocess.Popen([sys.executable, "-c", PRINTS_A_LINE], stdout=writer, stderr=subprocess.PIPE, text=True)
    os.close(writer)
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


def test_a_broken_pipe_to_anything_but_stdout_is_raised():
    @stops_quietly_on_closed_pipe
    def talks_to_a_child_that_went_away():
        raise BrokenPipeError("the pipe to a helper process")

    with pytest.raises(BrokenPipeError, match="helper process"):
        talks_to_a_child_that_went_away()


def test_an_error_is_reported_on_one_line_with_status_2(capsys):
    assert error_exit("tactile-x run", ValueError("bad.yaml: while parsing\n  in line 3\n   expected ':'")) == 2
    assert capsys.readouterr().err == "tactile-x run: error: bad.yaml: while parsing in line 3 expected ':'\n"


def test_a_whole_number_argument_names_its_unit_and_bounds():
    frames = whole_number_argument(1, "frames", maximum=10)
    assert frames("10") == 10
    for text in ("0", "11", "2.5", "many"):
        with pytest.raises(argparse.ArgumentTypeError, match=f"whole number of frames from 1 to 10, got '{text}'"):
            frames(text)
    with pytest.raises(argparse.ArgumentTypeError, match=r"of draws >= 0 \(why\), got '-1'"):
        whole_number_argument(0, "draws", " (why)")("-1")


def test_a_number_argument_refuses_what_float_takes_but_no_wait_can_use():
    seconds = number_argument(0.0, "seconds")
    assert seconds("2.5") == 2.5 and seconds("1e-3") == 0.001
    for text in ("0", "-1", "nan", "inf", "-inf", "soon", ""):
        with pytest.raises(argparse.ArgumentTypeError, match=f"must be a finite number of seconds > 0, got '{text}'"):
            seconds(text)
    settle = number_argument(0.0, "seconds", inclusive=True)
    assert settle("0") == 0.0
    with pytest.raises(argparse.ArgumentTypeError, match="of seconds >= 0, got '-0.5'"):
        settle("-0.5")


class CtrlC(Exception):
    """What this test's own Ctrl-C handler raises: a KeyboardInterrupt that escaped would end the pytest session
    instead of failing the test (found in an audit of the tests)."""


def test_a_ctrl_c_while_stop_signals_are_ignored_neither_cuts_the_block_short_nor_leaves_it():
    # A Ctrl-C handler of this test's own, whatever this process inherited (a shell's background job starts with
    # SIGINT ignored), and the inherited one back afterwards.
    def ctrl_c(_number, _frame):
        raise CtrlC

    inherited = signal.signal(signal.SIGINT, ctrl_c)
    try:
        finished = []
        with stop_signals_ignored():
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.1)  # CtrlC would be raised here, were the signal not ignored
            finished.append(True)
        assert finished == [True]
        assert signal.getsignal(signal.SIGINT) is ctrl_c
        with pytest.raises(CtrlC):  # and Ctrl-C works again after the block
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(1.0)
    finally:
        signal.signal(signal.SIGINT, inherited)


def test_stop_signals_ignored_outside_the_main_thread_runs_the_block_as_it_is():
    """signal.signal raised ValueError there: train_and_export, which uses it, could not run in a worker thread."""
    ran, errors = [], []

    def block():
        try:
            with stop_signals_ignored():
                ran.append(signal.getsignal(signal.SIGTERM))
        except ValueError as exc:
            errors.append(exc)

    worker = threading.Thread(target=block)
    worker.start()
    worker.join()
    assert errors == [] and ran == [signal.getsignal(signal.SIGTERM)]


def test_a_parser_and_its_subcommands_refuse_arguments_in_one_line(capsys):
    """argparse printed its usage block before the error, 3 to 9 lines; the commands refuse other input in one."""
    parser = ArgumentParser(prog="tactile-sim")
    render = parser.add_subparsers(dest="command", required=True).add_parser("render")
    render.add_argument("--count", type=whole_number_argument(1, "previews"))
    for args, line in ((["render", "--count", "0"], "tactile-sim render: error: argument --count: must be a whole "
                                                    "number of previews >= 1, got '0'"),
                       (["draw"], "tactile-sim: error: argument command: invalid choice: 'draw' (choose from "
                                  "'render')")):
        with pytest.raises(SystemExit) as refused:
            parser.parse_args(args)
        assert refused.value.code == INPUT_ERROR_EXIT and capsys.readouterr().err == line + "\n"


def test_a_stop_signal_that_a_c_extension_turned_into_another_error_is_raised_as_itself():
    """pybind11 turns an exception raised inside a call (the StopSignal) into a TypeError caused by it; rclpy's
    deserialisation did so on a Ctrl-C to `tactile-bag eval`, which then ended in a traceback."""
    inherited = signal.getsignal(signal.SIGINT)
    with pytest.raises(StopSignal) as stopped, stop_signals_raised():
        try:
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(5)
        except StopSignal as stop:
            raise TypeError("Unable to convert function return value to a Python type!") from stop
    assert stopped.value.number == signal.SIGINT and isinstance(stopped.value.__cause__, TypeError)
    assert signal.getsignal(signal.SIGINT) is inherited
    with pytest.raises(ValueError), stop_signals_raised():  # any other error passes as it is
        raise ValueError("not a stop")
