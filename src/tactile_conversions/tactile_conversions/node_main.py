"""The `main()` of every node of the stack: init, spin until Ctrl-C or SIGTERM, shut down cleanly."""

from __future__ import annotations

import faulthandler
import signal
import sys
import traceback
from collections.abc import Callable

import rclpy
from rclpy.node import Node

from tactile_conversions.parameters import ParameterError
from tactile_conversions.stop_signals import init_ros, stopped_by_signal
from tactile_description.command_line import INPUT_ERROR_EXIT, one_line

#: How long the middleware may take to destroy the node and the context once the node has stopped. Fast DDS 3.2.3
#: (the newest wheel) can deadlock while it deletes the participant if a discovery message about a peer that is
#: leaving arrives at that moment (measured: 4 of 498 starts and stops of two camera nodes stopped together;
#: docs/nodes.md). Below the 5 s after which `ros2 launch` escalates to SIGTERM and SIGKILL.
TEARDOWN_TIMEOUT_S = 3.0


def run_node(make_node: Callable[[], Node], args: list[str] | None = None) -> None:
    """Spin the node built by `make_node` until interrupted (SIGINT) or terminated (SIGTERM, ros2 launch).

    rclpy's signal handler shuts the ROS context down at once, from another thread, wherever the node is: in
    its constructor or in a callback a `create_*` or `publish` then fails ("context is invalid"). A Ctrl-C can
    also surface as another error from inside rclpy (stop_signals.init_ros). Such an error after shutdown was
    requested is the shutdown itself, so it ends the node cleanly (exit code 0). A
    parameter the node refuses (ParameterError, whose message names the node and the parameter) is printed in one line
    on stderr and ends the process with exit code 2 (SystemExit(INPUT_ERROR_EXIT)), as a command line refuses its
    input. Any other error is printed with its traceback and ends the process with exit code 1 (SystemExit(1)).

    Once the node is shutting down, SIGINT is ignored (and stays so: the process is ending), so that a repeated
    Ctrl-C does not interrupt the shutdown.

    SIGUSR1 (`kill -USR1 <pid>`) prints the stack of every thread to stderr and the node keeps running: how to
    see where a node that does not stop is stuck.

    If destroying the node and the context takes longer than `TEARDOWN_TIMEOUT_S`, faulthandler prints
    "Timeout" and every thread's stack to stderr and ends the process with exit code 1. It runs in a thread of
    its own without the GIL, which the middleware's deadlock keeps (a Python thread could not step in). The error
    that ended the node, if any, has been printed before the teardown began.
    """
    faulthandler.register(signal.SIGUSR1)
    init_ros(args)
    node = None
    exit_code = 0
    try:
        node = make_node()
        rclpy.spin(node)
    except ParameterError as exc:
        print(one_line(exc), file=sys.stderr)
        exit_code = INPUT_ERROR_EXIT
    except (KeyboardInterrupt, Exception) as exc:
        if not stopped_by_signal(exc):
            traceback.print_exc()
            exit_code = 1
    finally:
        # A repeated Ctrl-C (`stop_nodes` repeats it) must not interrupt the shutdown itself: once rclpy's handler
        # is gone (try_shutdown restores Python's), it would raise KeyboardInterrupt here and end the node with -2.
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        faulthandler.dump_traceback_later(TEARDOWN_TIMEOUT_S, exit=True)
        try:
            if node is not None:
                node.destroy_node()
            rclpy.try_shutdown()
        finally:
            faulthandler.cancel_dump_traceback_later()  # also when the teardown raised: never exit later
        signal.signal(signal.SIGINT, signal.SIG_IGN)
    if exit_code:
        raise SystemExit(exit_code)
