"""ROS node: one real camera (or a video file) of the sensor, through OpenCV.

Reads capture frames from `source` (a device index such as "0", a device path such as "/dev/video2", or a
video file), crops and downsamples them as the sensor description says, and publishes
`/tactile/<camera_id>/image` (mono8, sensor-data QoS) stamped with the time the frame was read.

A source that cannot be opened or stops delivering is retried every `reopen_period_s` while the node keeps
running, so a camera that is unplugged and plugged back in recovers by itself. A video file that ends is
replayed from the start when `loop` is true. Frames of the wrong size are dropped with an error naming the
camera and the expected size.
"""

from __future__ import annotations

import cv2
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image

from tactile_conversions.images import mono8_to_msg
from tactile_conversions.node_main import run_node
from tactile_conversions.topics import camera_topic
from tactile_description import load_sensor
from tactile_description.imaging import FrameError, crop_and_downsample


def open_source(source: str) -> cv2.VideoCapture:
    """A VideoCapture for a device index ("0"), a device path or a video file."""
    return cv2.VideoCapture(int(source)) if source.isdigit() else cv2.VideoCapture(source)


class CameraNode(Node):
    def __init__(self) -> None:
        super().__init__("tactile_camera")
        sensor_config = self.declare_parameter("sensor_config", "").value
        self.camera_id = self.declare_parameter("camera_id", "cam0").value
        self.source = str(self.declare_parameter("source", "0").value)
        self.loop = bool(self.declare_parameter("loop", True).value)
        self.reopen_period_s = float(self.declare_parameter("reopen_period_s", 1.0).value)
        sensor = load_sensor(sensor_config or None)
        if self.camera_id not in sensor.camera_ids:
            raise ValueError(f"camera_id {self.camera_id!r} is not in the sensor description "
                             f"({list(sensor.camera_ids)})")
        self.camera = sensor.cameras[sensor.camera_ids.index(self.camera_id)]
        rate_hz = float(self.declare_parameter("rate_hz", sensor.frame_rate_hz).value)
        if rate_hz <= 0 or self.reopen_period_s <= 0:
            raise ValueError(f"rate_hz and reopen_period_s must be > 0, got {rate_hz}, {self.reopen_period_s}")
        self.publisher = self.create_publisher(Image, camera_topic(self.camera_id), qos_profile_sensor_data)
        self.capture: cv2.VideoCapture | None = None
        self.next_open_s = 0.0
        self.frames_published = 0
        self.create_timer(1.0 / rate_hz, self.grab)

    def destroy_node(self) -> None:
        if self.capture is not None:
            self.capture.release()
        super().destroy_node()

    def now_s(self) -> float:
        return self.get_clock().now().nanoseconds * 1e-9

    def ensure_open(self) -> bool:
        if self.capture is not None and self.capture.isOpened():
            return True
        if self.now_s() < self.next_open_s:
            return False
        self.capture = open_source(self.source)
        if not self.capture.isOpened():
            self.get_logger().error(f"{self.camera_id}: cannot open camera source {self.source!r}; retrying every "
                                    f"{self.reopen_period_s:.1f} s", throttle_duration_sec=10.0)
            self.capture = None
            self.next_open_s = self.now_s() + self.reopen_period_s
            return False
        self.get_logger().info(f"{self.camera_id}: reading {self.source!r}")
        return True

    def grab(self) -> None:
        if not self.ensure_open():
            return
        stamp = self.get_clock().now().to_msg()
        ok, frame = self.capture.read()
        if not ok:
            if self.loop and self.capture.get(cv2.CAP_PROP_FRAME_COUNT) > 0:
                self.capture.set(cv2.CAP_PROP_POS_FRAMES, 0)  # a video file ended: play it again
                return
            self.get_logger().warning(f"{self.camera_id}: {self.source!r} delivered no frame; reopening")
            self.capture.release()
            self.capture = None
            self.next_open_s = self.now_s() + self.reopen_period_s
            return
        try:
            image = crop_and_downsample(frame, self.camera)
        except FrameError as exc:
            self.get_logger().error(str(exc), throttle_duration_sec=5.0)
            return
        self.publisher.publish(mono8_to_msg(image, stamp, f"{self.camera_id}_optical"))
        self.frames_published += 1


def main(args: list[str] | None = None) -> None:
    run_node(CameraNode, args)
