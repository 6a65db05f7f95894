"""Run the nodes of a graph (tactile_bringup.graph) as plain processes, where no launch system is installed."""

from __future__ import annotations

import signal
import subprocess
import time
from pathlib import Path

from ament_index_python.packages import get_package_prefix

from tactile_bringup.graph import NodeSpec

#: Time a stuck node gets to write its stacks before it is killed.
STACK_DUMP_S = 1.0
#: SIGINT is sent again this often while a node has not exited (see `stop_nodes`).
SIGINT_REPEAT_S = 3.0


def start_node(spec: NodeSpec, log_dir: Path, env: dict[str, str] | None = None) -> subprocess.Popen:
    """Start one node; its output goes to `log_dir/<node name>.log`."""
    executable = Path(get_package_prefix(spec.package)) / "lib" / spec.package / spec.executable
    log_dir.mkdir(parents=True, exist_ok=True)
    with open(log_dir / f"{spec.name}.log", "w") as log:  # the child keeps its own copy of the descriptor
        return subprocess.Popen([str(executable), *spec.ros_arguments()], stdout=log, stderr=subprocess.STDOUT,
                                env=env)


def stop_nodes(processes: list[subprocess.Popen], timeout_s: float = 10.0) -> list[int]:
    """Interrupt every node (SIGINT, as Ctrl-C), kill those that do not exit in time; their exit codes.

    SIGINT is repeated every `SIGINT_REPEAT_S` until a node exits: a node started with SIGINT ignored (what a
    background job of a non-interactive shell inherits) loses a SIGINT that arrives while it imports, before
    `rclpy.init()` installs rclpy's handler, and would otherwise spin until killed. A node that is killed first
    gets SIGUSR1, which makes it print its threads' stacks into its log (tactile_conversions.node_main), so that
    the log says where it was stuck.
    """
    deadline = time.monotonic() + timeout_s
    for process in processes:
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
    for process in processes:
        while process.poll() is None and time.monotonic() < deadline:
            try:
                process.wait(timeout=min(SIGINT_REPEAT_S, max(deadline - time.monotonic(), 0.0)))
            except subprocess.TimeoutExpired:
                if time.monotonic() < deadline:
                    process.send_signal(signal.SIGINT)
        if process.poll() is None:
            process.send_signal(signal.SIGUSR1)
            time.sleep(STACK_DUMP_S)
            process.kill()
            process.wait()
    return [process.returncode for process in processes]
