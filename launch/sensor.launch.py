"""Start the tactile sensor graph: cameras (real or simulated) -> bundles -> force distribution (-> RViz).

    ros2 launch tactile_bringup sensor.launch.py                          # simulated sensor, demo scene
    ros2 launch tactile_bringup sensor.launch.py source:=cameras camera_sources:=/path/to/sources.yaml
    ros2 launch tactile_bringup sensor.launch.py rviz:=true
    ros2 launch tactile_bringup sensor.launch.py namespace:=left sensor_config:=/path/to/left.yaml   # one per sensor

The nodes and their parameters come from tactile_bringup.graph, the same description `tactile-demo` runs
where no launch system is installed. RViz gets the configuration of the sensor description it runs
(tactile_bringup.rviz_config: its frame and its bins, the topics of its namespace), written to
$ROS_HOME/tactile_bringup/ (~/.ros/tactile_bringup/). With `namespace`, every node and topic of the graph lies under
it (/left/tactile/force_distribution): a robot with two sensors launches this file once for each. Included by a launch
file that pushes a namespace (PushRosNamespace("robot")), the graph lies in it: /robot, or /robot/left with
namespace:=left (an absolute namespace:=/left is not put under it).
"""

from pathlib import Path

from ament_index_python.packages import get_package_share_directory
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node

from tactile_bringup.graph import sensor_graph
from tactile_bringup.rviz_config import write_rviz_config
from tactile_conversions.topics import graph_namespace
from tactile_description import load_sensor

SHARE = Path(get_package_share_directory("tactile_bringup"))
ARGUMENTS = {
    "sensor_config": (str(SHARE / "config" / "sensor.yaml"), "sensor description YAML"),
    "source": ("sim", "'sim' (simulated sensor) or 'cameras' (OpenCV devices or video files)"),
    "scene": ("demo", "simulator scene name or YAML file (source:=sim)"),
    "camera_sources": (str(SHARE / "config" / "camera_sources.yaml"), "camera_id -> OpenCV source (source:=cameras)"),
    "model_dir": ("", "trained model directory; empty: the shipped default model"),
    "backend": ("onnxruntime", "inference backend: onnxruntime or torch"),
    "precision": ("fp32", "fp32, fp16 or int8 (onnxruntime)"),
    "rviz": ("false", "also start RViz with the force markers, set up for the sensor description"),
    "namespace": ("", "ROS namespace of the graph's nodes and topics (e.g. left: /left/tactile/force_distribution); "
                      "empty: the root namespace"),
}


def graph_nodes(context):
    value = {name: LaunchConfiguration(name).perform(context) for name in ARGUMENTS}
    sensor = load_sensor(value["sensor_config"])
    # Absolute, so within what an including launch file pushed (PushRosNamespace): a node given an absolute namespace
    # is not put under the pushed one, so the pushed one must be part of it.
    namespace = graph_namespace(value["namespace"], context.launch_configurations.get("ros_namespace") or "/")
    specs = sensor_graph(sensor, value["sensor_config"], value["source"], value["scene"], value["camera_sources"],
                         value["model_dir"], value["backend"], value["precision"], namespace)
    nodes = [Node(package=s.package, executable=s.executable, name=s.name, namespace=s.namespace,
                  parameters=[s.parameters], output="screen") for s in specs]
    if IfCondition(value["rviz"]).evaluate(context):
        config = write_rviz_config(sensor, namespace=namespace)
        nodes.append(Node(package="rviz2", executable="rviz2", namespace=namespace,
                          arguments=["-d", str(config)]))
    return nodes


def generate_launch_description():
    arguments = [DeclareLaunchArgument(name, default_value=default, description=text)
                 for name, (default, text) in ARGUMENTS.items()]
    return LaunchDescription([*arguments, OpaqueFunction(function=graph_nodes)])
