"""The topic names of the tactile graph (docs/nodes.md), in one place for the nodes, the tools and the tests.

The names below are where the topics lie for a graph in the root namespace, the default. The nodes publish and
subscribe them relative (`node_topic`), so that a graph started in a namespace (`sensor.launch.py namespace:=left`,
`tactile-demo --namespace left`, `--ros-args -r __ns:=/left`) has all its topics under it: two sensors on one robot
each run their own graph, /left/tactile/force_distribution beside /right/tactile/force_distribution.
"""

from __future__ import annotations

from argparse import ArgumentTypeError

BUNDLE_TOPIC = "/tactile/image_bundle"
ESTIMATE_TOPIC = "/tactile/force_distribution"
GROUND_TRUTH_TOPIC = "/tactile/ground_truth/force_distribution"
#: Largest distance between an estimate's stamp and its ground truth's for the two to be compared (tactile-demo,
#: tactile-bag eval): the sensor's frames are 25 ms apart, and an estimate's stamp, its bundle's, is the median of
#: jittered camera stamps.
MATCH_TOLERANCE_S = 0.010
WRENCH_TOPIC = "/tactile/wrench"
MARKERS_TOPIC = "/tactile/force_markers"
ROOT_NAMESPACE = "/"


def camera_topic(camera_id: str) -> str:
    """Where the camera `camera_id` publishes its images."""
    return f"/tactile/{camera_id}/image"


def camera_frame_id(camera_id: str) -> str:
    """The frame_id of the camera `camera_id`'s images (the real and the simulated cameras stamp the same)."""
    return f"{camera_id}_optical"


def node_topic(topic: str) -> str:
    """A topic of this module as a node publishes or subscribes it: relative, so that rcl resolves it in the node's
    namespace ('/tactile/x' -> 'tactile/x', which a node in /left resolves to /left/tactile/x and a node in the root
    namespace to /tactile/x)."""
    return topic.lstrip("/")


def graph_namespace(text: str, parent: str = ROOT_NAMESPACE) -> str:
    """The namespace a sensor graph runs in, from a launch argument or a command-line option, absolute: "" or "/" for
    the root namespace, "left" or "/left" for /left, "robot/left" for /robot/left. As in ROS, a relative name lies in
    `parent` (the namespace a launch file that includes sensor.launch.py pushed: "left" in /robot is /robot/left, ""
    is /robot) and an absolute one does not ("/left" is /left). A name that ROS refuses (a token that starts with a
    digit, characters other than letters, digits, "_" and "/") raises ValueError with rcl's reason."""
    from rclpy.exceptions import InvalidNamespaceException  # rclpy's C extension, for the tools that need it only
    from rclpy.validate_namespace import validate_namespace

    name = text.strip()
    name = "/" + (name if name.startswith("/") else f"{parent}/{name}").strip("/")
    try:
        validate_namespace(name)
    except InvalidNamespaceException as exc:
        reason = str(exc).splitlines()[0].removeprefix("Invalid namespace: ").rstrip(":")
        raise ValueError(f"namespace {text!r}: not a ROS namespace ({reason})") from None
    return name


def namespace_argument(text: str) -> str:
    """`--namespace` of a command-line tool (argparse type): as `graph_namespace` gives it; a name ROS refuses is a
    usage error (status 2) saying why."""
    try:
        return graph_namespace(text)
    except ValueError as exc:
        raise ArgumentTypeError(str(exc)) from None


def in_namespace(topic: str, namespace: str) -> str:
    """Where a topic of this module lies for a graph in `namespace` ("left" or "/left", see `graph_namespace`):
    in_namespace(ESTIMATE_TOPIC, "left") == "/left/tactile/force_distribution"."""
    namespace = graph_namespace(namespace)
    return topic if namespace == ROOT_NAMESPACE else namespace + topic
