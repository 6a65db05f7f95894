"""Point the ROS 2 wheels' CMake export files at this interpreter's include directories.

Why: the ROS 2 Kilted wheels on PyPI are built on a manylinux host whose Python lives in /opt/python/cp311-cp311.
Their generated `*__rosidl_generator_pyExport.cmake` files record that host's Python and numpy include
directories as INTERFACE_INCLUDE_DIRECTORIES of imported targets. CMake refuses imported targets whose include
directories do not exist ("Imported target ... includes non-existent path"), so building any interface package
(tactile_msgs) against the wheels fails until those two paths name the directories of the venv's interpreter.

Idempotent: files that no longer contain the build host's paths are left alone. Prints how many files changed.
"""

import sys
import sysconfig
from pathlib import Path

import numpy

BUILD_HOST_PYTHON_INCLUDE = "/opt/python/cp311-cp311/include/python3.11"
BUILD_HOST_NUMPY_INCLUDE = "/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include"


def main() -> int:
    prefix = Path(sys.prefix)
    replacements = {
        BUILD_HOST_PYTHON_INCLUDE: sysconfig.get_paths()["include"],
        BUILD_HOST_NUMPY_INCLUDE: numpy.get_include(),
    }
    changed = 0
    for cmake_file in sorted((prefix / "share").glob("*/cmake/*.cmake")):
        text = cmake_file.read_text()
        fixed = text
        for host_path, local_path in replacements.items():
            fixed = fixed.replace(host_path, local_path)
        if fixed != text:
            cmake_file.write_text(fixed)
            changed += 1
    print(f"fix_ros_wheel_cmake: {changed} CMake file(s) repointed to {sys.executable}'s include directories")
    return 0


if __name__ == "__main__":
    sys.exit(main())
