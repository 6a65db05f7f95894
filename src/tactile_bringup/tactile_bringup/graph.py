"""The sensor graph as data: which nodes run, with which parameters.

One description serves `launch/sensor.launch.py` (on a ROS 2 install with `launch_ros`) and `tactile-demo`
(which starts the same nodes as plain processes, for installs without the launch system, such as the PyPI
wheels), so the two cannot drift apart.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from tactile_conversions.topics import ROOT_NAMESPACE, graph_namespace
from tactile_description import SensorDescription
from tactile_description.yaml_fields import load_yaml_file

SOURCES = ("sim", "cameras")


@dataclass(frozen=True)
class NodeSpec:
    package: str
    executable: str
    name: str
    parameters: dict[str, str | int | float | bool] = field(default_factory=dict)
    namespace: str = ROOT_NAMESPACE  # "left", "/left": made absolute by tactile_conversions.topics.graph_namespace

    def __post_init__(self) -> None:
        object.__setattr__(self, "namespace", graph_namespace(self.namespace))  # rcl takes only absolute ones

    def ros_arguments(self) -> list[str]:
        """Command-line arguments that give the node its name, namespace and parameters (`--ros-args ...`)."""
        args = ["--ros-args", "-r", f"__node:={self.name}"]
        if self.namespace != ROOT_NAMESPACE:
            args += ["-r", f"__ns:={self.namespace}"]
        for key, value in self.parameters.items():
            args += ["-p", f"{key}:={yaml_scalar(value)}"]
        return args


def yaml_scalar(value: str | int | float | bool) -> str:
    """A parameter value as rcl reads `-p name:=value` (YAML): strings quoted, so that "" or "true" stay strings."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return "'" + value.replace("'", "''") + "'"
    return str(value)


def camera_sources(path: str | Path, sensor: SensorDescription) -> dict[str, str]:
    """The OpenCV source (device index, device path or video file) of every camera, from a YAML mapping."""
    sources = load_yaml_file(path, "camera sources file") or {}
    if not isinstance(sources, dict):
        raise ValueError(f"{path}: expected a mapping camera_id -> source")
    missing = [c for c in sensor.camera_ids if c not in sources]
    if missing:
        raise ValueError(f"{path}: no source for cameras {missing}; add e.g. `{missing[0]}: /dev/video0`")
    # A YAML null or an empty entry would become the source "None" or "": say so instead.
    empty = [c for c in sensor.camera_ids
             if sources[c] is None or isinstance(sources[c], bool) or str(sources[c]) == ""]
    if empty:
        raise ValueError(f"{path}: cameras {empty} have no source (a device index, a device path or a video file)")
    return {c: str(sources[c]) for c in sensor.camera_ids}


def sensor_graph(sensor: SensorDescription, sensor_config: str, source: str = "sim", scene: str = "demo",
                 camera_sources_file: str = "", model_dir: str = "", backend: str = "onnxruntime",
                 precision: str = "fp32", namespace: str = ROOT_NAMESPACE) -> list[NodeSpec]:
    """The nodes from camera images to /tactile/force_distribution for one sensor description; every node in
    `namespace` ("left", "/left"; tactile_conversions.topics.graph_namespace, whose ValueError a name that ROS refuses
    raises), which moves all the graph's topics under it: one graph per sensor, each in a namespace of its own."""
    if source not in SOURCES:
        raise ValueError(f"source must be one of {SOURCES}, got {source!r}")
    common = {"sensor_config": sensor_config}
    bundles = NodeSpec("tactile_fusion", "bundle_node", "tactile_bundle", common, namespace)
    fusion = NodeSpec("tactile_fusion", "fusion_node", "tactile_fusion",
                      {**common, "model_dir": model_dir, "backend": backend, "precision": precision}, namespace)
    if source == "sim":
        # The scene plays once the bundle node and the fusion node (which subscribes after loading its model) listen,
        # so that the fusion node's reference frames are the scene's opening rest: see sim_camera_node.
        cameras = [NodeSpec("tactile_camera_driver", "sim_camera_node", "tactile_sim_cameras",
                            {**common, "scene": scene, "wait_for_nodes": f"{bundles.name},{fusion.name}"},
                            namespace)]
    else:
        if not camera_sources_file:
            raise ValueError("source 'cameras' needs a camera sources file (camera_id -> OpenCV source)")
        cameras = [NodeSpec("tactile_camera_driver", "camera_node", f"tactile_camera_{camera_id}",
                            {**common, "camera_id": camera_id, "source": device}, namespace)
                   for camera_id, device in camera_sources(camera_sources_file, sensor).items()]
    return [*cameras, bundles, fusion]
