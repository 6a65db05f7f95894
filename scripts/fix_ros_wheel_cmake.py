"""Point the ROS 2 wheels' CMake export files at this interpreter's include directories.

Why: the ROS 2 Kilted wheels on PyPI are built on a manylinux host whose Python lives in /opt/python/cp311-cp311
(cp312-cp312 for the Python 3.12 wheels, and so on).
Their generated `*__rosidl_generator_pyExport.cmake` files record that host's Python and numpy include
directories as INTERFACE_INCLUDE_DIRECTORIES of imported targets. CMake refuses imported targets whose include
directories do not exist ("Imported target ... includes non-existent path"), so building any interface package
(tactile_msgs) against the wheels fails until those two paths name the directories of the venv's interpreter.

Idempotent: files that no longer contain the build host's paths are left alone. Prints how many files changed.
"""

import re
import sys
import sysconfig
from pathlib import Path

import numpy

#: The build host's Python and numpy include directories, for the wheel of each Python version (cp311-cp311 for 3.11,
#: cp312-cp312 for 3.12, ...).
BUILD_HOST_PYTHON_INCLUDE = re.compile(r"/opt/python/cp3\d+-cp3\d+/include/python3\.\d+")
BUILD_HOST_NUMPY_INCLUDE = re.compile(r"/opt/python/cp3\d+-cp3\d+/lib/python3\.\d+/site-packages/numpy/_core/include")


def repointed(cmake_text: str, python_include: str, numpy_include: str) -> str:
    """`cmake_text` with the build host's include directories replaced by these (numpy's first: it lies inside the
    host's Python tree but is not its include directory)."""
    text = BUILD_HOST_NUMPY_INCLUDE.sub(lambda _: numpy_include, cmake_text)
    return BUILD_HOST_PYTHON_INCLUDE.sub(lambda _: python_include, text)


def main() -> int:
    prefix = Path(sys.prefix)
    changed = 0
    for cmake_file in sorted((prefix / "share").glob("*/cmake/*.cmake")):
        text = cmake_file.read_text()
        fixed = repointed(text, sysconfig.get_paths()["include"], numpy.get_include())
        if fixed != text:
            cmake_file.write_text(fixed)
            changed += 1
    print(f"fix_ros_wheel_cmake: {changed} CMake file(s) repointed to {sys.executable}'s include directories")
    return 0


if __name__ == "__main__":
    sys.exit(main())
