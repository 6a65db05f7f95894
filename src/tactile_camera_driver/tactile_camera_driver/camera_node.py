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

A device is asked for the sensor description's capture size and the node's `rate_hz` (CAP_PROP_FRAME_WIDTH, _HEIGHT,
_FPS; a camera that starts in its own default mode, 640 x 480 for many, had every frame dropped as the wrong size),
and the node logs the mode it got, which a device may choose nearest to the one asked for (not tried on camera
hardware: there is none here).

A video file is played at `rate_hz`, not at its own frame rate: the node warns when the two differ (a 30 fps file
at 40 Hz plays, and is stamped, 1.33 times as fast). A URL (rtsp://, http://) is read as a live stream: one that
stops delivering is reopened, whatever `loop` says. OpenCV's own messages are limited to errors and FFmpeg's to fatal
ones (they repeated at every retry, beside the node's throttled lines).

Stamps (not tried on camera hardware): a device is opened with a buffer of one frame (CAP_PROP_BUFFERSIZE;
OpenCV's V4L2 backend keeps 4 by default, so a node that fell behind would get frames up to 4 periods older than
their stamps; backends without the property ignore it), and a frame is stamped as soon as grab() returns it,
before it is decoded, not before read() waits for it.

The OpenCV calls run in a thread of their own (`capture_thread.CaptureThread`), so that a source that blocks (a
stream that does not answer holds FFmpeg's open for 30 s) does not hold up a Ctrl-C or `ros2 launch`'s SIGINT.
"""

from __future__ import annotations

import contextlib
import os
import re
import signal
import sys
import time
import traceback
from pathlib import Path

import cv2
import rclpy.context
from rclpy.exceptions import InvalidHandle
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image

from tactile_camera_driver.capture_thread import CaptureThread
from tactile_conversions.images import mono8_to_msg
from tactile_conversions.node_main import run_node
from tactile_conversions.parameters import (
    DYNAMIC,
    ParameterError,
    boolean,
    log_sensor_description,
    period_s,
    rate_hz,
    sensor_description,
    text,
)
from tactile_conversions.timers import clock_running, steady_timer
from tactile_conversions.topics import camera_frame_id, camera_topic, node_topic
from tactile_description.imaging import FrameError, crop_and_downsample
from tactile_description.value_checks import is_whole_number

#: OpenCV takes a device index as a C int: 2**32 ended the node in cv2.error at its first frame (found in review).
MAX_DEVICE_INDEX = 2**31 - 1

#: How long a stopping node waits for an OpenCV call still running before it leaves the source to the process's end.
CLOSE_TIMEOUT_S = 1.0

#: How far a video file's own frame rate may lie from rate_hz before the node says it plays at another speed.
FILE_RATE_TOLERANCE = 0.01


def quiet_opencv() -> None:
    """Leave OpenCV's own messages to errors and FFmpeg's to fatal ones: "[ WARN] cap_v4l.cpp ... can't open camera by
    index" at every retry of an unplugged camera, and a damaged file's decoder errors at every replay, went to stderr
    beside the node's throttled lines (review); the node says what it cannot read. A level the user set
    (OPENCV_LOG_LEVEL, OPENCV_FFMPEG_LOGLEVEL) stays. FFmpeg's is read once per process, at its first capture."""
    if "OPENCV_LOG_LEVEL" not in os.environ:
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
    os.environ.setdefault("OPENCV_FFMPEG_LOGLEVEL", "8")  # AV_LOG_FATAL


def is_url(source: int | str) -> bool:
    """Whether `source` is a stream's URL (rtsp://, http://): read as a live stream, whatever it holds."""
    return isinstance(source, str) and "://" in source


def is_image_sequence(source: int | str) -> bool:
    """Whether `source` is an OpenCV image sequence: a printf pattern such as "img_%04d.png", which names no file
    itself (a URL's percent-encoding, "p%40ss", is none)."""
    return isinstance(source, str) and "%" in source and not is_url(source)


def is_video_file(source: int | str) -> bool:
    """Whether `source` is read like a file (it ends, is rewound, keeps no frame buffer): a video file, or an
    image sequence."""
    return isinstance(source, str) and not is_url(source) and (Path(source).is_file() or is_image_sequence(source))


def missing_file(source: int | str) -> str:
    """", no such file" for a path that names nothing (a mistyped video file, or a device not plugged in yet), else
    "": a source that exists and cannot be opened is another matter (a busy device, an unreadable video), and so is a
    stream's URL (rtsp://...), which names no file."""
    if isinstance(source, str) and not (is_image_sequence(source) or is_url(source)) and not Path(source).exists():
        return ", no such file"
    return ""


def open_source(source: int | str, capture_size: tuple[int, int], frame_rate_hz: float) -> cv2.VideoCapture:
    """A VideoCapture for a device index, a device path, a video file or an image sequence. A device keeps one frame
    and is asked for the sensor description's capture size and the node's frame rate (module docstring)."""
    capture = cv2.VideoCapture(source)
    if capture.isOpened() and not is_video_file(source):
        capture.set(cv2.CAP_PROP_BUFFERSIZE, 1)
        capture.set(cv2.CAP_PROP_FRAME_WIDTH, capture_size[0])
        capture.set(cv2.CAP_PROP_FRAME_HEIGHT, capture_size[1])
        capture.set(cv2.CAP_PROP_FPS, frame_rate_hz)
    return capture


class CameraNode(Node):
    def __init__(self) -> None:
        super().__init__("tactile_camera")
        # first: rclpy destroys the node even if __init__ fails
        self.capture: cv2.VideoCapture | None = None
        self.capture_thread: CaptureThread | None = None
        self.capture_left_blocked = False  # destroy_node left an OpenCV call blocked (main)
        quiet_opencv()
        self.camera_id = text(self, "camera_id", "cam0")
        self.source = self.declare_source()
        self.loop = boolean(self, "loop", True)
        self.reopen_period_s = period_s(self, "reopen_period_s", 1.0)
        sensor = sensor_description(self)
        if self.camera_id not in sensor.camera_ids:
            raise ParameterError(f"{self.get_name()}: parameter camera_id must name a camera of the sensor description "
                                 f"({list(sensor.camera_ids)}), got {self.camera_id!r}")
        self.camera = sensor.cameras[sensor.camera_ids.index(self.camera_id)]
        self.frame_rate_hz = rate_hz(self, "rate_hz", sensor.frame_rate_hz)
        self.publisher = self.create_publisher(Image, node_topic(camera_topic(self.camera_id)), qos_profile_sensor_data)
        self.next_open_s = 0.0
        self.frames_published = 0
        self.frames_since_rewind = 0  # since the source was opened or a video file played again from its start
        self.ended = False  # a video file played to its end with loop false
        read_failed = self.create_guard_condition(lambda: capture_thread.raise_error())
        capture_thread = self.capture_thread = CaptureThread(self.grab, f"{self.camera_id} capture",
                                                             on_error=lambda: self.wake(read_failed))
        self.timer = steady_timer(self, 1.0 / self.frame_rate_hz, self.capture_thread.tick)
        log_sensor_description(self, sensor)

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

    @staticmethod
    def wake(read_failed) -> None:
        """Have the executor raise the capture thread's error, unless the node is being destroyed (nothing to end)."""
        with contextlib.suppress(InvalidHandle):
            read_failed.trigger()

    def destroy_node(self) -> None:
        """Destroy the node, then stop the capture thread and release the source. In this order, the warning below,
        after a Ctrl-C has shut the context down, goes to the console and the log file only (see main), not to a
        /rosout that is gone ("Failed to publish log message to rosout": review)."""
        super().destroy_node()
        idle = self.capture_thread is None or self.capture_thread.close(CLOSE_TIMEOUT_S)
        if not idle:  # releasing a capture that another thread reads from is not safe
            self.capture_left_blocked = True
            self.get_logger().warning(f"{self.camera_id}: camera source {self.source!r} still blocks OpenCV after "
                                      f"{CLOSE_TIMEOUT_S:g} s; leaving it to the end of the process")
        elif self.capture is not None:
            self.capture.release()

    def ensure_open(self) -> bool:
        if self.capture is not None and self.capture.isOpened():
            return True
        # The retries keep the monotonic clock, not the node's: a step back of the system clock, or a simulated clock,
        # held them off (code review).
        if time.monotonic() < self.next_open_s:
            return False
        self.capture = open_source(self.source, self.camera.capture_size, self.frame_rate_hz)
        if not self.capture.isOpened():
            # A try happens at a frame tick: every reopen_period_s, or every frame period where that is longer.
            retry_s = max(self.reopen_period_s, 1.0 / self.frame_rate_hz)
            self.get_logger().error(f"{self.camera_id}: cannot open camera source {self.source!r}"
                                    f"{missing_file(self.source)}; retrying every {retry_s:.3g} s",
                                    throttle_duration_sec=10.0)
            self.capture = None
            self.next_open_s = time.monotonic() + self.reopen_period_s
            return False
        self.get_logger().info(f"{self.camera_id}: reading {self.source!r}{self.device_mode()}",
                               throttle_duration_sec=10.0)
        self.warn_of_file_rate()
        self.frames_since_rewind = 0
        return True

    def warn_of_file_rate(self) -> None:
        """Say when a video file's own frame rate is not rate_hz: it is played, and stamped, at rate_hz (review). An
        image sequence has none (FFmpeg reports its default, 25 fps)."""
        if not is_video_file(self.source) or is_image_sequence(self.source):
            return
        file_fps = self.capture.get(cv2.CAP_PROP_FPS)
        if file_fps > 0 and abs(file_fps - self.frame_rate_hz) > FILE_RATE_TOLERANCE * self.frame_rate_hz:
            self.get_logger().warning(
                f"{self.camera_id}: video file {self.source!r} is {file_fps:g} fps, played at rate_hz "
                f"{self.frame_rate_hz:g} Hz: {self.frame_rate_hz / file_fps:.3g} times its speed, and stamped so; "
                f"-p rate_hz:={file_fps:g} plays it at its own", throttle_duration_sec=60.0)

    def device_mode(self) -> str:
        """For a device, the size and rate it delivers, which it may have chosen nearest to those asked for."""
        if is_video_file(self.source):
            return ""
        width, height = (int(self.capture.get(p)) for p in (cv2.CAP_PROP_FRAME_WIDTH, cv2.CAP_PROP_FRAME_HEIGHT))
        return (f" at {width} x {height} px, {self.capture.get(cv2.CAP_PROP_FPS):g} fps (asked for "
                f"{self.camera.capture_size[0]} x {self.camera.capture_size[1]} px, {self.frame_rate_hz:g} fps)")

    def grab(self) -> None:
        """One frame tick, in the capture thread: open the source if need be, read a frame, publish it. Nothing once
        a video file ended with loop false: a tick the executor had taken as the timer was cancelled reopened it
        (review)."""
        if self.ended or not clock_running(self) or not self.ensure_open():
            return
        frame, stamp = self.read_frame()
        if frame is None and self.on_no_frame():  # a video file played again: its first frame in this tick
            frame, stamp = self.read_frame()
            if frame is None:
                self.on_no_frame()
        if frame is None:
            return
        try:
            image = crop_and_downsample(frame, self.camera)
        except FrameError as exc:
            self.get_logger().error(str(exc), throttle_duration_sec=5.0)
            return
        self.publisher.publish(mono8_to_msg(image, stamp, camera_frame_id(self.camera_id)))
        self.frames_published += 1

    def read_frame(self):
        """(the next capture frame or None, its stamp). A frame is stamped when grab() returns it, before decoding."""
        grabbed = self.capture.grab()
        stamp = self.get_clock().now().to_msg()
        ok, frame = self.capture.retrieve() if grabbed else (False, None)
        if not ok:
            return None, stamp
        self.frames_since_rewind += 1  # of any size: a file of the wrong size is played again, not reopened
        return frame, stamp

    def on_no_frame(self) -> bool:
        """A video file that ended is played again (`loop`; True) or ends the reading; any other source is reopened,
        and so is a video file that gave no frame since it was opened or played again (one that OpenCV opens but
        cannot decode: playing it again would be silent for ever)."""
        if is_video_file(self.source) and not self.loop:
            if self.frames_since_rewind:  # decoded, of any size (a file of the wrong size has its own errors)
                self.get_logger().info(f"{self.camera_id}: video file {self.source!r} ended ({self.frames_published} "
                                       "frames published; loop false): publishing nothing more")
            else:  # "ended (0 frames published)" for a file never decoded (review)
                self.get_logger().error(f"{self.camera_id}: video file {self.source!r} gave no frame OpenCV can "
                                        "decode (loop false): publishing nothing")
            self.ended = True
            self.timer.cancel()
            self.capture.release()
            self.capture = None
            return False
        if is_video_file(self.source) and self.frames_since_rewind and self.capture.set(cv2.CAP_PROP_POS_FRAMES, 0):
            self.frames_since_rewind = 0
            return True  # played again from the start
        self.get_logger().warning(f"{self.camera_id}: {self.source!r} delivered no frame; reopening",
                                  throttle_duration_sec=10.0)
        self.capture.release()
        self.capture = None
        self.next_open_s = time.monotonic() + self.reopen_period_s
        return False


def main(args: list[str] | None = None) -> None:
    """run_node; where the node left an OpenCV call blocked, the process then ends without Python's finalization: a
    call that returned while Python finalized aborted the process (SIGABRT, exit code 134: its thread exited from
    inside OpenCV's C++ code; review). Before that, ROS's logging is finished, which writes the log file's buffer
    (after a Ctrl-C, rclpy's shutdown leaves it to the process's end, which os._exit skips; review)."""
    built: list[CameraNode] = []

    def camera_node() -> CameraNode:
        built.append(CameraNode())
        return built[-1]

    try:
        run_node(camera_node, args)
        exit_code = 0
    except SystemExit as exc:  # run_node's 1 or 2
        exit_code = exc.code if isinstance(exc.code, int) else 1
    except KeyboardInterrupt:  # a second Ctrl-C before run_node ignores them
        exit_code = 128 + signal.SIGINT
    except BaseException:  # an error of the teardown itself
        traceback.print_exc()
        exit_code = 1
    if any(node.capture_left_blocked for node in built):
        if rclpy.context.g_logging_ref_count > 0:
            rclpy_implementation.rclpy_logging_fini()
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(exit_code)
    if exit_code:
        raise SystemExit(exit_code)
