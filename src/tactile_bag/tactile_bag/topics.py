"""The message types of the tactile graph's topics (docs/nodes.md), and the QoS to record and replay them.

A bag holds the topics of a graph in the root namespace (/tactile/...) or, for a graph run in a namespace (two
sensors on one robot, docs/nodes.md), under it (/left/tactile/...): the functions here take that namespace ("left"
or "/left", default the root one).
"""

from __future__ import annotations

from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

from tactile_conversions.topics import (
    BUNDLE_TOPIC,
    ESTIMATE_TOPIC,
    GROUND_TRUTH_TOPIC,
    MARKERS_TOPIC,
    ROOT_NAMESPACE,
    WRENCH_TOPIC,
    camera_topic,
    in_namespace,
)
from tactile_description import SensorDescription

IMAGE_TYPE = "sensor_msgs/msg/Image"
BUNDLE_TYPE = "tactile_msgs/msg/ImageBundle"
FORCES_TYPE = "tactile_msgs/msg/ForceDistribution"

#: Queue depth of reliable subscriptions and publishers: a second of the sensor's frames and then some.
RELIABLE_DEPTH = 100


def camera_topics(sensor: SensorDescription, namespace: str = ROOT_NAMESPACE) -> dict[str, str]:
    """The image topic of each camera of `sensor` -> its camera id, in the description's camera order."""
    return {in_namespace(camera_topic(c), namespace): c for c in sensor.camera_ids}


def other_sensor_hint(sensor: SensorDescription) -> str:
    """What images on topics of no camera of `sensor` suggest (record and eval say it where they see them)."""
    return (f"the cameras of another sensor description than {sensor.source} (--sensor FILE), or of a graph in "
            "another namespace (--namespace)?")


def stack_topics(sensor: SensorDescription, namespace: str = ROOT_NAMESPACE) -> dict[str, str]:
    """Every topic the graph of `sensor` publishes -> its message type."""
    topics = dict.fromkeys(camera_topics(sensor, namespace), IMAGE_TYPE)
    topics.update({in_namespace(topic, namespace): msgtype for topic, msgtype in (
        (BUNDLE_TOPIC, BUNDLE_TYPE), (ESTIMATE_TOPIC, FORCES_TYPE), (GROUND_TRUTH_TOPIC, FORCES_TYPE),
        (WRENCH_TOPIC, "geometry_msgs/msg/WrenchStamped"), (MARKERS_TOPIC, "visualization_msgs/msg/MarkerArray"))})
    return topics


def default_record_topics(sensor: SensorDescription, namespace: str = ROOT_NAMESPACE) -> list[str]:
    """What `tactile-bag record` takes without --topics: the images, the bundles, the estimate and the truth."""
    return [*camera_topics(sensor, namespace),
            *(in_namespace(topic, namespace) for topic in (BUNDLE_TOPIC, ESTIMATE_TOPIC, GROUND_TRUTH_TOPIC))]


def absolute_topic(name: str, example: str = BUNDLE_TOPIC) -> str:
    """A topic name as the graph resolves it in the root namespace ('tactile/x' -> '/tactile/x'); an empty one is
    refused, with `example` as the name to give instead."""
    name = name.strip()
    if not name or name == "/":
        raise ValueError(f"topic name {name!r} is empty; give e.g. {example}")
    return name if name.startswith("/") else "/" + name


def qos_profile(msgtype: str) -> QoSProfile:
    """The QoS the live graph uses for a type: sensor-data (best effort) for camera images, as the camera drivers
    publish them and image_pipeline does; reliable for everything else.

    Recording the stack's topics with it matches their publishers (a best-effort subscription also takes a reliable
    publisher's messages; record.recording_qos chooses for other topics); replaying with it gives subscribers exactly
    what the live graph gave them.
    """
    if msgtype == IMAGE_TYPE:
        return qos_profile_sensor_data
    return QoSProfile(depth=RELIABLE_DEPTH, reliability=ReliabilityPolicy.RELIABLE)
