"""The suite's guard against a hung test (pyproject.toml: pytest-timeout, thread method): a test that never returns,
as one caught in a Fast DDS teardown deadlock would, ends the run with every thread's stack instead of holding CI
until its limit."""

import subprocess
import sys
from pathlib import Path

REPOSITORY = Path(__file__).resolve().parents[1]

HUNG_TEST = '''
import threading

def test_waits_for_ever():
    threading.Event().wait()
'''


def test_a_hung_test_ends_the_run_with_every_threads_stack(tmp_path):
    (tmp_path / "test_hung.py").write_text(HUNG_TEST)
    # The repository's own configuration, with the limit cut from minutes to a second.
    run = subprocess.run([sys.executable, "-m", "pytest", "-c", str(REPOSITORY / "pyproject.toml"),
                          "--rootdir", str(tmp_path), "-p", "no:cacheprovider", "-o", "timeout=1",
                          str(tmp_path / "test_hung.py")],
                         capture_output=True, text=True, timeout=60, cwd=tmp_path)
    output = run.stdout + run.stderr
    assert run.returncode != 0
    # The thread method's report (a signal would wait for a deadlock in C++ to return), naming where it hung.
    assert "Timeout" in output and "Stack of MainThread" in output
    assert "in test_waits_for_ever" in output
