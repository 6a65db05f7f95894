"""ROS node: one real camera (or a video file) of the sensor, through OpenCV.

Reads capture frames from `source` (a device index such as 0, a device path such as "/dev/video2", a video
file, or an OpenCV image sequence such as "img_%04d.png"), crops and downsamples them as the sensor description
says, and publishes `/tactile/<camera_id>/image` (mono8, sensor-data QoS) stamped with the time the frame was
grabbed.

A source that cannot be opened or stops delivering is retried every `reopen_period_s` while the node keeps
running, so a camera that is unplugged and plugged back in recovers by itself. A video file (or image sequence)
that ends is replayed from the start when `loop` is true; with `loop` false the node says once that the file
ended and publishes nothing more, but keeps running (as sim_camera_node does at the end of its scene), so that a
launch file does not take the end of a recording for a failure. Frames of the wrong size are dropped with an error
naming the camera and the expected size.

Stamps (not tried on camera hardware): a device is opened with a buffer of one frame (CAP_PROP_BUFFERSIZE;
OpenCV's V4L2 backend keeps 4 by default, so a node that fell behind would get frames up to 4 periods older than
their stamps; backends without the property ignore it), and a frame is stamped as soon as grab() returns it,
before it is decoded, not before read() waits for it.
"""

from __future__ import annotations

import re
from pathlib import Path

import cv2
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image

from tactile_conversions.images import mono8_to_msg
from tactile_conversions.node_main import run_node
from tactile_conversions.parameters import (
    DYNAMIC,
    ParameterError,
    boolean,
    positive_float,
    rate_hz,
    sensor_description,
    text,
)
from tactile_conversions.topics import camera_topic
from tactile_description.imaging import FrameError, crop_and_downsample
from tactile_description.value_checks import is_whole_number

#: OpenCV takes a device index as a C int: 2**32 ended the node in cv2.error at its first frame (found in review).
MAX_DEVICE_INDEX = 2**31 - 1


def is_video_file(source: int | str) -> bool:
    """Whether `source` is read like a file (it ends, is rewound, keeps no frame buffer): a video file, or an
    OpenCV image sequence (a printf pattern such as "img_%04d.png", which names no file itself)."""
    return isinstance(source, str) and (Path(source).is_file() or "%" in source)


def open_source(source: int | str) -> cv2.VideoCapture:
    """A VideoCapture for a device index, a device path, a video file or an image sequence; a device keeps one frame
    (module docstring)."""
    capture = cv2.VideoCapture(source)
    if capture.isOpened() and not is_video_file(source):
        capture.set(cv2.CAP_PROP_BUFFERSIZE, 1)
    return capture


class CameraNode(Node):
    def __init__(self) -> None:
        super().__init__("tactile_camera")
        self.capture: cv2.VideoCapture | None = None  # first: rclpy destroys the node even if __init__ fails
        self.camera_id = text(self, "camera_id", "cam0")
        self.source = self.declare_source()
        self.loop = boolean(self, "loop", True)
        self.reopen_period_s = positive_float(self, "reopen_period_s", 1.0)
        sensor = sensor_description(self)
        if self.camera_id not in sensor.camera_ids:
            raise ParameterError(f"{self.get_name()}: parameter camera_id must name a camera of the sensor description "
                                 f"({list(sensor.camera_ids)}), got {self.camera_id!r}")
        self.camera = sensor.cameras[sensor.camera_ids.index(self.camera_id)]
        frame_rate_hz = rate_hz(self, "rate_hz", sensor.frame_rate_hz)
        self.publisher = self.create_publisher(Image, camera_topic(self.camera_id), qos_profile_sensor_data)
        self.next_open_s = 0.0
        self.frames_published = 0
        self.frames_since_rewind = 0  # since the source was opened or a video file played again from its start
        self.timer = self.create_timer(1.0 / frame_rate_hz, self.grab)

    def declare_source(self) -> int | str:
        """The `source` parameter as OpenCV takes it: a device index (an integer >= 0, or a string of digits:
        `-p source:=2` gives the one, camera_sources.yaml's `cam0: 2` the other) or a path (a device or a video
        file)."""
        value = self.declare_parameter("source", "0", DYNAMIC).value
        if isinstance(value, str) and re.fullmatch("[0-9]+", value):  # not isdigit(): '²' is a digit to it
            value = int(value)
        if is_whole_number(value, 0) and value <= MAX_DEVICE_INDEX:
            return value
        if isinstance(value, str) and value:
            return value
        raise ParameterError(f"{self.get_name()}: parameter source must be a device index (an integer from 0 to "
                             f"{MAX_DEVICE_INDEX}), a device path or a video file, got {value!r}")

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
        self.frames_since_rewind = 0
        return True

    def grab(self) -> None:
        if not self.ensure_open():
            return
        grabbed = self.capture.grab()
        stamp = self.get_clock().now().to_msg()  # the frame exists now; decoding it (retrieve) takes a while
        ok, frame = self.capture.retrieve() if grabbed else (False, None)
        if not ok:
            self.on_no_frame()
            return
        try:
            image = crop_and_downsample(frame, self.camera)
        except FrameError as exc:
            self.get_logger().error(str(exc), throttle_duration_sec=5.0)
            return
        self.publisher.publish(mono8_to_msg(image, stamp, f"{self.camera_id}_optical"))
        self.frames_published += 1
        self.frames_since_rewind += 1

    def on_no_frame(self) -> None:
        """A video file that ended is played again (`loop`) or ends the reading; any other source is reopened, and
        so is a video file that gave no frame since it was opened or played again (one that OpenCV opens but cannot
        decode: playing it again would be silent for ever)."""
        if is_video_file(self.source) and not self.loop:
            self.get_logger().info(f"{self.camera_id}: video file {self.source!r} ended ({self.frames_published} "
                                   "frames published; loop false): publishing nothing more")
            self.timer.cancel()
            self.capture.release()
            self.capture = None
            return
        if is_video_file(self.source) and self.frames_since_rewind and self.capture.set(cv2.CAP_PROP_POS_FRAMES, 0):
            self.frames_since_rewind = 0
            return  # played again from the start
        self.get_logger().warning(f"{self.camera_id}: {self.source!r} delivered no frame; reopening")
        self.capture.release()
        self.capture = None
        self.next_open_s = self.now_s() + self.reopen_period_s


def main(args: list[str] | None = None) -> None:
    run_node(CameraNode, args)
