"""ROS node: the simulated sensor's cameras, publishing like real ones.

Plays a simulator scene (default `demo`, looped) at the sensor's frame rate and publishes each camera's mono8 image (the
description's `cameras.output`, 128 x 128 on the reference sensor) on `/tactile/<camera_id>/image` with sensor-data QoS,
stamped with the capture time plus a random delay drawn afresh for each image, uniform in [0, `stamp_jitter_s`] (the
spread of stamps of cameras that are not triggered together; 0 stamps every image with the capture time).
`stamp_jitter_s` is at most one frame period (`declare_stamp_jitter`). A camera that the scene drops or freezes
publishes nothing for that frame, exactly like a broken camera. With `loop` false the node says once that the scene
ended and publishes nothing more (it keeps running). The scene's ground truth goes out on
`/tactile/ground_truth/force_distribution` (tactile_msgs/ForceDistribution) for live evaluation.

The scene plays from its first frame once a camera's image topic has a subscriber; until then the node publishes
nothing. Frames nobody receives are lost for good, and a scene's first frames matter: the fusion node takes its
reference frames from the first bundles, which must show the surface at rest. Started at once, the scene ran on while
DDS discovery connected the bundle node, and under load the demo's 2 s of rest were over before the first bundle
reached the fusion node: its reference showed a press, and the estimates were off by 0.25-0.37 N in total (found in
review). Nor does a subscriber of the images say that the graph is listening: a bag recorder started first is one,
and while DDS discovery took 2.4 s to connect the bundle node, the demo's rest went by (found in review, 1 of 7 runs).
So where later nodes must hear the scene from its start, `wait_for_nodes` names them (comma-separated), and the scene
plays only once the ROS graph shows each of them with a subscription: the sensor graph (sensor.launch.py,
tactile-demo) names its bundle node, which subscribes to the images, and its fusion node, which subscribes to the
bundles only once its model is loaded, seconds after a launch file starts every node at once. The names are of nodes in
this node's own namespace: with two sensors' graphs in /left and /right, the right cameras wait for the right fusion
node, not for whichever came up first (until 2026-11-28 any namespace counted). Left empty (the default), as a graph
without those nodes needs, the scene plays as soon as its images are heard.

The topics above are those of the root namespace; in a namespace they lie under it (tactile_conversions.topics).
"""

from __future__ import annotations

import numpy as np
from rclpy.exceptions import NameValidationException
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from rclpy.validate_node_name import validate_node_name
from sensor_msgs.msg import Image

from tactile_conversions.forces import force_distribution_msg
from tactile_conversions.images import mono8_to_msg
from tactile_conversions.node_main import run_node
from tactile_conversions.parameters import (
    ParameterError,
    boolean,
    log_sensor_description,
    positive_float,
    rate_hz,
    refused_as,
    sensor_description,
    text,
)
from tactile_conversions.ros_time import seconds_to_time
from tactile_conversions.timers import clock_running, steady_timer
from tactile_conversions.topics import GROUND_TRUTH_TOPIC, camera_frame_id, camera_topic, node_topic
from tactile_description import FORCE_COMPONENTS, SensorConfigError
from tactile_msgs.msg import ForceDistribution
from tactile_sim import SceneError, Simulator, load_scene

#: Default `stamp_jitter_s` (s), or one frame period where that is shorter.
STAMP_JITTER_S = 0.002


class SimCameraNode(Node):
    def __init__(self) -> None:
        super().__init__("tactile_sim_cameras")
        self.scene_name = text(self, "scene", "demo")
        self.loop = boolean(self, "loop", True)
        self.sensor = sensor_description(self)
        frame_rate_hz = rate_hz(self, "rate_hz", self.sensor.frame_rate_hz)
        self.stamp_jitter_s = self.declare_stamp_jitter(frame_rate_hz)
        self.awaited_nodes = self.declare_awaited_nodes()
        with refused_as(self, "parameter sensor_config", SensorConfigError):
            self.simulator = Simulator(self.sensor)  # refuses what only the simulator needs (where the particles are)
        with refused_as(self, "parameter scene", SceneError):
            self.scene = load_scene(self.scene_name, self.sensor)
            self.frames = self.simulator.stream(self.scene)  # refuses contacts the ground truth would count twice
        self.rng = np.random.default_rng(0)
        self.image_pubs = {c: self.create_publisher(Image, node_topic(camera_topic(c)), qos_profile_sensor_data)
                           for c in self.sensor.camera_ids}
        self.truth_pub = self.create_publisher(ForceDistribution, node_topic(GROUND_TRUTH_TOPIC), 10)
        self.playing = False  # until its listeners are there (module docstring, `listened`)
        self.timer = steady_timer(self, 1.0 / frame_rate_hz, self.publish_frame)
        awaited = f" and nodes {list(self.awaited_nodes)} subscribe" if self.awaited_nodes else " are subscribed"
        log_sensor_description(self, self.sensor)
        self.get_logger().info(f"simulating scene {self.scene_name!r} ({len(self.scene)} frames) at "
                               f"{frame_rate_hz:.1f} Hz for cameras {list(self.sensor.camera_ids)}, from its first "
                               f"frame once their images{awaited}")

    def declare_awaited_nodes(self) -> tuple[str, ...]:
        """The `wait_for_nodes` parameter: node names separated by commas, "" for none (module docstring)."""
        names = tuple(name.strip() for name in text(self, "wait_for_nodes", "").split(",") if name.strip())
        for name in names:
            with refused_as(self, "parameter wait_for_nodes", NameValidationException):
                validate_node_name(name)
        return names

    def listened(self) -> bool:
        """Whether the scene may play: a camera's images are subscribed, and each node of `wait_for_nodes` has a
        subscription."""
        if not any(publisher.get_subscription_count() for publisher in self.image_pubs.values()):
            return False
        waiting = [name for name in self.awaited_nodes if not self.subscribes(name)]
        if waiting:
            self.get_logger().info(f"images subscribed; waiting for nodes {waiting} to subscribe (parameter "
                                   "wait_for_nodes) before playing the scene", throttle_duration_sec=10.0)
        return not waiting

    def subscribes(self, name: str) -> bool:
        """Whether the ROS graph shows a node called `name` in this node's namespace with a subscription."""
        namespace = self.get_namespace()
        if (name, namespace) not in self.get_node_names_and_namespaces():
            return False
        try:
            return bool(self.get_subscriber_names_and_types_by_node(name, namespace))
        except RuntimeError:  # rclpy's NodeNameNonExistentError: it left the graph meanwhile
            return False

    def declare_stamp_jitter(self, frame_rate_hz: float) -> float:
        """The `stamp_jitter_s` parameter: from 0 to one frame period.

        Cameras that run at the same rate without a common trigger capture at most one frame period apart, and a
        jitter within a frame period keeps every camera's own stamps in order while frames come a period apart
        (frame k + 1 is stamped no earlier than the latest stamp frame k can get), as a real camera's are. A larger
        one made stamps no camera gives: out of order within a camera, and with `-p stamp_jitter_s:=1e12` past what a
        ROS Time holds, which ended the node at its first frame with a traceback ("a ROS time must be a finite number
        below 2**31 s").
        """
        frame_period_s = 1.0 / frame_rate_hz
        jitter_s = positive_float(self, "stamp_jitter_s", min(STAMP_JITTER_S, frame_period_s), allow_zero=True)
        if jitter_s > frame_period_s:
            raise ParameterError(f"{self.get_name()}: parameter stamp_jitter_s must be at most one frame period, "
                                 f"{frame_period_s!r} s at rate_hz {frame_rate_hz:g}, got {jitter_s!r}")
        return jitter_s

    def publish_frame(self) -> None:
        if not clock_running(self):
            return
        if not self.playing:
            if not self.listened():
                return
            self.playing = True
            self.get_logger().info(f"images subscribed: playing scene {self.scene_name!r} from its first frame")
        # Every frame of the scene can be made: the simulator checked it at start-up (Scene.check_playable, random
        # presses' room included), where a refusal ends the node in one line.
        frame = next(self.frames, None)
        if frame is None:
            if not self.loop:
                self.get_logger().info(f"scene {self.scene_name!r} ended ({len(self.scene)} frames; loop false): "
                                       "publishing nothing more")
                self.timer.cancel()
                return
            self.frames = self.simulator.stream(self.scene)
            frame = next(self.frames)
        capture_s = self.get_clock().now().nanoseconds * 1e-9
        for i, camera_id in enumerate(self.sensor.camera_ids):
            if not frame.camera_ok[i]:
                continue
            stamp = seconds_to_time(capture_s + self.rng.uniform(0.0, self.stamp_jitter_s))
            self.image_pubs[camera_id].publish(mono8_to_msg(frame.images[i], stamp, camera_frame_id(camera_id)))
        self.truth_pub.publish(force_distribution_msg(frame.bin_forces_n, self.sensor.grid, seconds_to_time(capture_s),
                                                      self.sensor.frame_id, self.sensor.camera_ids, [],
                                                      FORCE_COMPONENTS))


def main(args: list[str] | None = None) -> None:
    run_node(SimCameraNode, args)
