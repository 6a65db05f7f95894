"""The sensor description shared by the simulator, the model and the ROS nodes (no ROS import).

Its names are imported from `tactile_description.sensor` on first use (PEP 562), not with the package: every console
command starts in `tactile_description.commands`, whose stop handling is in place only once the package is imported,
and the sensor module's numpy took 0.11 s of that window (a Ctrl-C in it ended a command with a traceback).
"""

import importlib

__all__ = [
    "FORCE_COMPONENTS", "SENSOR_ENV", "BinGrid", "CameraSpec", "Crop", "FisheyeLens", "GelLayer", "ParticleSpec",
    "SensorConfigError", "SensorDescription", "default_sensor_path", "installed_config_dir",
    "left_out_components",
    "load_sensor",
]


def __getattr__(name: str):
    if name in __all__:
        return getattr(importlib.import_module("tactile_description.sensor"), name)
    raise AttributeError(f"module 'tactile_description' has no attribute {name!r}")
