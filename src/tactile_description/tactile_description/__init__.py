"""The sensor description shared by the simulator, the model and the ROS nodes (no ROS import)."""

from tactile_description.sensor import (
    FORCE_COMPONENTS,
    SENSOR_ENV,
    BinGrid,
    CameraSpec,
    Crop,
    FisheyeLens,
    GelLayer,
    ParticleSpec,
    SensorConfigError,
    SensorDescription,
    default_sensor_path,
    installed_config_dir,
    left_out_components,
    load_sensor,
)

__all__ = [
    "FORCE_COMPONENTS", "SENSOR_ENV", "BinGrid", "CameraSpec", "Crop", "FisheyeLens", "GelLayer", "ParticleSpec",
    "SensorConfigError", "SensorDescription", "default_sensor_path", "installed_config_dir",
    "left_out_components",
    "load_sensor",
]
