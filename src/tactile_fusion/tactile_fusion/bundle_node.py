"""ROS node: camera images -> tactile_msgs/ImageBundle, with the approximate-time synchroniser.

Subscribes `/tactile/<camera_id>/image` for every camera of the sensor description and publishes
`/tactile/image_bundle`, numbering the bundles (`sequence`: 0, 1, 2, ...) so that a subscriber can tell when it
lost some. A camera that falls silent for `camera_timeout_s` is left out of the bundles (they
then list fewer cameras, and the fusion node reports it as missing) until it sends images again, so one broken
camera degrades the estimate instead of stopping it.
"""

from __future__ import annotations

import statistics

from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image
from std_msgs.msg import Header

from tactile_conversions.node_main import run_node
from tactile_conversions.ros_time import seconds_to_time, time_to_seconds
from tactile_conversions.topics import BUNDLE_TOPIC, camera_topic
from tactile_description import load_sensor
from tactile_fusion.approximate_sync import ApproximateTimeSync, Bundle, camera_sync_settings
from tactile_msgs.msg import ImageBundle


class BundleNode(Node):
    def __init__(self) -> None:
        super().__init__("tactile_bundle")
        sensor_config = self.declare_parameter("sensor_config", "").value
        self.sensor = load_sensor(sensor_config or None)
        defaults = camera_sync_settings(self.sensor.frame_rate_hz)
        self.max_spread_s = float(self.declare_parameter("max_spread_s", defaults["max_spread_s"]).value)
        self.queue_size = int(self.declare_parameter("queue_size", defaults["queue_size"]).value)
        self.min_period_s = float(self.declare_parameter("min_period_s", defaults["min_period_s"]).value)
        self.camera_timeout_s = float(self.declare_parameter("camera_timeout_s", 10 / self.sensor.frame_rate_hz).value)
        if self.max_spread_s <= 0 or self.queue_size < 1 or self.min_period_s < 0 or self.camera_timeout_s <= 0:
            raise ValueError("tactile_bundle: max_spread_s and camera_timeout_s must be > 0, queue_size >= 1, "
                             "min_period_s >= 0")
        self.publisher = self.create_publisher(ImageBundle, BUNDLE_TOPIC, 10)
        self.last_arrival_s = dict.fromkeys(self.sensor.camera_ids, -float("inf"))
        self.live_cameras: tuple[str, ...] = ()
        self.sync: ApproximateTimeSync[Image] | None = None
        self.sequence = 0
        for camera_id in self.sensor.camera_ids:
            self.create_subscription(Image, camera_topic(camera_id),
                                     lambda msg, c=camera_id: self.on_image(c, msg), qos_profile_sensor_data)
        self.create_timer(self.camera_timeout_s / 2, self.check_cameras)
        self.get_logger().info(f"bundling cameras {list(self.sensor.camera_ids)} "
                               f"(max spread {self.max_spread_s * 1e3:.1f} ms)")

    def now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def on_image(self, camera_id: str, msg: Image) -> None:
        now = self.now_s()
        if not self.live_cameras:
            # First image since start-up (or since every camera fell silent): give every camera one timeout to
            # show up, so that the first bundles hold all cameras that work rather than whichever came first.
            self.last_arrival_s = dict.fromkeys(self.sensor.camera_ids, now)
        self.last_arrival_s[camera_id] = now
        if camera_id not in self.live_cameras:
            self.check_cameras()
        if self.sync is None or camera_id not in self.live_cameras:
            return
        for bundle in self.sync.add(camera_id, time_to_seconds(msg.header.stamp), msg):
            self.publisher.publish(self.to_msg(bundle, self.sequence))
            self.sequence += 1

    def check_cameras(self) -> None:
        """Rebuild the synchroniser when the set of cameras that send images changes."""
        now = self.now_s()
        live = tuple(c for c, t in self.last_arrival_s.items() if now - t < self.camera_timeout_s)
        if live == self.live_cameras:
            return
        lost = sorted(set(self.live_cameras) - set(live))
        if lost:
            self.get_logger().warning(f"no images from {lost} for {self.camera_timeout_s:.2f} s: bundling "
                                      f"{list(live)} only")
        back = sorted(set(live) - set(self.live_cameras))
        if back:
            self.get_logger().info(f"cameras {back} are back")
        if self.sync is not None and self.sync.dropped.total:
            self.get_logger().info(f"synchroniser dropped {self.sync.dropped.total} image(s): {self.sync.dropped}")
        self.live_cameras = live
        self.sync = ApproximateTimeSync(live, self.queue_size, self.max_spread_s, self.min_period_s) if live else None

    def to_msg(self, bundle: Bundle[Image], sequence: int) -> ImageBundle:
        return ImageBundle(header=Header(stamp=seconds_to_time(statistics.median(bundle.stamps)),
                                         frame_id=self.sensor.frame_id), sequence=sequence,
                           camera_ids=list(bundle.stream_ids), images=list(bundle.items),
                           max_stamp_spread_s=bundle.spread)


def main(args: list[str] | None = None) -> None:
    run_node(BundleNode, args)
