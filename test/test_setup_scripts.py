"""scripts/fix_ros_wheel_cmake.py, which `make setup` runs: the paths it rewrites in the ROS wheels' CMake files."""

import importlib.util
from pathlib import Path

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "fix_ros_wheel_cmake.py"


def load_script():
    spec = importlib.util.spec_from_file_location("fix_ros_wheel_cmake", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def export_line(tag: str, version: str) -> str:
    """The line of a wheel's *__rosidl_generator_pyExport.cmake that names the build host's include directories."""
    return (f'  INTERFACE_INCLUDE_DIRECTORIES "/opt/python/{tag}-{tag}/include/python{version};'
            f'/opt/python/{tag}-{tag}/lib/python{version}/site-packages/numpy/_core/include"\n')


def test_the_build_hosts_include_directories_of_every_python_version_are_repointed():
    """Only the 3.11 wheels' paths were rewritten: `make PYTHON=python3.12 setup` (README) failed in CMake."""
    script = load_script()
    for tag, version in (("cp311", "3.11"), ("cp312", "3.12"), ("cp313", "3.13"), ("cp310", "3.10")):
        fixed = script.repointed(export_line(tag, version), "/venv/include/python", "/venv/numpy/include")
        assert fixed == '  INTERFACE_INCLUDE_DIRECTORIES "/venv/include/python;/venv/numpy/include"\n', tag
        assert script.repointed(fixed, "/venv/include/python", "/venv/numpy/include") == fixed  # idempotent


def test_the_venvs_cmake_files_name_no_build_host_path():
    """What `make setup` left in this checkout's .venv: every export file repointed."""
    script = load_script()
    venv = Path(__file__).resolve().parents[1] / ".venv"
    exports = sorted((venv / "share").glob("*/cmake/*__rosidl_generator_pyExport.cmake"))
    assert exports
    left = [f.name for f in exports if script.BUILD_HOST_PYTHON_INCLUDE.search(f.read_text())
            or script.BUILD_HOST_NUMPY_INCLUDE.search(f.read_text())]
    assert left == []
