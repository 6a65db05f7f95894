"""The console commands and node executables of every package (each package's setup.py points here).

Their modules take up to 1.6 s to import (torch, rclpy, OpenCV). A Ctrl-C meanwhile ended a command or node with a
KeyboardInterrupt traceback, and a SIGTERM (`ros2 launch` escalating, `kill`) ended it at once with status -15, before
any of its own handling of those signals was in place. Each function here imports its module with both signals
ending the process quietly (`main_after_imports`), then runs its `main`. This module itself imports little (not
numpy: the package imports its sensor module on first use), so that what remains of the window is Python's start and
the console script's lookup of its entry point: 0.06-0.09 s on a loaded machine.
"""

from __future__ import annotations

import contextlib
import importlib
import os
import signal

from tactile_description.command_line import STOP_SIGNALS, StopSignal, stop_signals_handled_by


def main_after_imports(module: str, program: str | None = None):
    """Import `module`, then return what its `main()` returns.

    A Ctrl-C or SIGTERM during the import ends the process at once: a node (`program` None) with status 0 and no
    word, as `run_node` ends a node stopped while it builds itself; a command with one line on stderr,
    "PROGRAM: stopped by Ctrl-C", and the status a shell gives a command the signal killed (130, 143), as the commands
    end on those signals later (command_line.stop_signals_raised). os._exit: nothing is open yet to close or flush, and
    no `except` inside an imported library can swallow it. Python's handlers are back in place before `main` runs; once
    it has returned, both signals are ignored."""
    def stop(number: int, _frame) -> None:
        if program is not None:
            with contextlib.suppress(OSError):  # stderr closed: the process ends all the same
                os.write(2, f"{program}: stopped by {StopSignal(number).named}\n".encode())
        os._exit(0 if program is None else StopSignal(number).exit_status)

    with stop_signals_handled_by(stop):
        main = importlib.import_module(module).main
    status = main()
    # Done: a stop while the interpreter tears down torch and rclpy (tenths of a second) ended a command that had
    # printed its results with status -2 and no word (found by a walkthrough). It is ignored: the process is ending.
    for number in STOP_SIGNALS:
        signal.signal(number, signal.SIG_IGN)
    return status


def camera_node() -> None:
    main_after_imports("tactile_camera_driver.camera_node")


def sim_camera_node() -> None:
    main_after_imports("tactile_camera_driver.sim_camera_node")


def bundle_node() -> None:
    main_after_imports("tactile_fusion.bundle_node")


def fusion_node() -> None:
    main_after_imports("tactile_fusion.fusion_node")


def tactile_fusion() -> int:
    return main_after_imports("tactile_fusion.cli", "tactile-fusion")


def tactile_sim() -> int:
    return main_after_imports("tactile_sim.cli", "tactile-sim")


def tactile_bag() -> int:
    return main_after_imports("tactile_bag.cli", "tactile-bag")


def tactile_demo() -> int:
    return main_after_imports("tactile_bringup.demo", "tactile-demo")


def tactile_latency() -> int:
    return main_after_imports("tactile_bringup.latency", "tactile-latency")
