"""The bundle node in this process (real rclpy and DDS): images are handed to its image callback, its bundles come
back through a subscription, its log through stderr. The parameters and the drop reports: test/test_camera_nodes.py."""

import os
import time

import numpy as np
import pytest
import rclpy
from builtin_interfaces.msg import Time
from rclpy.parameter import Parameter
from rosgraph_msgs.msg import Clock

from tactile_conversions.images import mono8_to_msg
from tactile_conversions.ros_time import seconds_to_time, time_to_seconds
from tactile_conversions.spinning import spin_until
from tactile_conversions.topics import BUNDLE_TOPIC
from tactile_fusion.bundle_node import CAMERA_CHECK_MIN_PERIOD_S, BundleNode
from tactile_msgs.msg import ImageBundle

CAMERAS = ("cam0", "cam1", "cam2", "cam3")
PERIOD_S = 0.025  # the default sensor's 40 Hz


@pytest.fixture
def bundler(monkeypatch):
    """bundler(*ros_args): a BundleNode for the default sensor, and the list its bundles arrive in."""
    monkeypatch.setenv("ROS_DOMAIN_ID", str(20 + (os.getpid() + 70) % 80))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    nodes = []

    def make(*ros_args: str):
        rclpy.init(args=["--ros-args", *ros_args])
        nodes.append(BundleNode())
        bundles: list[ImageBundle] = []
        nodes[-1].create_subscription(ImageBundle, BUNDLE_TOPIC, bundles.append, 100)
        assert spin_until(nodes[-1], lambda: nodes[-1].publisher.get_subscription_count() > 0, 10.0)
        return nodes[-1], bundles

    yield make
    for node in nodes:
        node.destroy_node()
    rclpy.try_shutdown()


def send(node, stamps, cameras=CAMERAS) -> None:
    """One image of each camera per stamp, camera by camera, through the node's image callback."""
    for stamp in stamps:
        for camera_id in cameras:
            image = stamp if isinstance(stamp, Time) else seconds_to_time(stamp)
            node.on_image(camera_id, mono8_to_msg(np.zeros((128, 128), np.uint8), image, f"{camera_id}_optical"))


@pytest.mark.parametrize("bad", [
    Time(sec=-5),                                  # the reporter's: the node died in to_msg
    Time(sec=-1, nanosec=999_999_999),             # 1 ns before 1970
    Time(sec=2**31 - 1, nanosec=999_999_999),      # rounds to 2**31 s: the bundle went out stamped sec=-2**31
])
def test_an_image_whose_stamp_no_bundle_can_carry_is_dropped_counted_and_logged_and_the_node_goes_on(
        bundler, capfd, bad):
    node, bundles = bundler()
    send(node, [bad] * 10)
    assert node.dropped.bad_stamp == 40 and node.sequence == 0  # never bundled
    assert node.live_cameras == ()  # not a sign of life: no synchroniser was started for them
    err = capfd.readouterr().err
    assert err.count(f"cam0: dropped an image stamped sec={bad.sec} nanosec={bad.nanosec}: a bundle's stamp must "
                     "lie in [0, 2**31) s; 1 such image(s) since start") == 1
    assert err.count("such image(s) since start") == 1  # throttled like the other drop logs
    send(node, [100.0 + k * PERIOD_S for k in range(10)])
    assert spin_until(node, lambda: len(bundles) >= 8, 10.0)
    assert [b.sequence for b in bundles] == list(range(len(bundles)))
    assert all(100.0 <= time_to_seconds(b.header.stamp) < 100.3 for b in bundles)
    node.report_drops()
    assert "dropped 40 image(s) (bad_stamp 40; cam0 10, cam1 10, cam2 10, cam3 10), 40 since start" \
        in capfd.readouterr().err


def test_a_camera_that_sends_only_stamps_no_bundle_can_carry_is_left_out_like_a_silent_one(bundler, capfd):
    node, bundles = bundler("-p", "camera_timeout_s:=0.5")
    for k in range(6):
        send(node, [100.0 + k * PERIOD_S], CAMERAS[:3])
        send(node, [Time(sec=-5)], CAMERAS[3:])
    assert node.sequence == 0  # the synchroniser waits for cam3 during its first timeout
    # Its first timeout over, without waiting for it on the wall clock (a pause of this process that long would
    # take the other cameras for silent as well).
    node.arrivals.last_s["cam3"] -= 1.0
    node.check_cameras()  # the node's timer does this every camera_timeout_s / 2
    assert node.live_cameras == CAMERAS[:3]
    assert "no images from ['cam3'] for 0.50 s" in capfd.readouterr().err
    send(node, [101.0 + k * PERIOD_S for k in range(4)], CAMERAS[:3])
    assert spin_until(node, lambda: len(bundles) >= 3, 10.0)
    assert all(list(b.camera_ids) == list(CAMERAS[:3]) for b in bundles)


@pytest.mark.parametrize(("value", "accepted"), [("86400", True), ("1e12", False)])
def test_a_camera_timeout_longer_than_a_day_is_refused_naming_the_parameter(monkeypatch, value, accepted):
    """Half of it is the period of a timer: 1e12 s made create_timer fail with a TypeError naming no parameter."""
    monkeypatch.setenv("ROS_DOMAIN_ID", str(20 + (os.getpid() + 70) % 80))
    rclpy.init(args=["--ros-args", "-p", f"camera_timeout_s:={value}"])
    try:
        if accepted:
            node = BundleNode()
            assert node.camera_timeout_s == 86400.0
            node.destroy_node()
        else:
            with pytest.raises(ValueError, match="tactile_bundle: parameter camera_timeout_s must be at most 86400 s "
                                                 r"\(one day\), got 1000000000000.0"):
                BundleNode()
    finally:
        rclpy.try_shutdown()


def test_cameras_slower_than_the_sensor_description_are_named_once_with_the_remedy(bundler, capfd):
    """Cameras at 10 Hz where the description says 40 Hz: before, the only signs were too_wide drops, or cameras lost
    and back with every frame."""
    node, bundles = bundler()
    send(node, [100.0 + k * 0.1 for k in range(8)])
    err = capfd.readouterr().err
    for camera_id in CAMERAS:
        assert err.count(f"{camera_id} captures 10 frames a second by its stamps, the sensor description says 40 Hz: "
                         "4 cameras without a common trigger capture up to 0.075 s apart") == 1
    assert "Set frame_rate_hz in the sensor description" in err
    assert "left out of the bundles" not in err  # 0.1 s is within camera_timeout_s


def test_cameras_at_the_descriptions_rate_under_a_too_narrow_max_spread_are_named_with_that_remedy(bundler, capfd):
    """The remedy was to set frame_rate_hz to the cameras' rate, which it already was (found in review)."""
    node, bundles = bundler("-p", "max_spread_s:=0.005")
    send(node, [100.0 + k * PERIOD_S for k in range(8)])
    err = capfd.readouterr().err
    assert err.count("cam0 captures 40 frames a second by its stamps, the sensor description says 40 Hz: 4 cameras "
                     "without a common trigger capture up to 0.0187 s apart at this rate, more than max_spread_s "
                     "(0.005 s)") == 1
    assert "The camera runs at the description's rate, so the parameters given to this node do not fit it" in err
    assert "Set frame_rate_hz" not in err


def test_cameras_at_the_sensor_descriptions_rate_are_not_named(bundler, capfd):
    node, bundles = bundler()
    send(node, [100.0 + k * PERIOD_S + 0.002 * (k % 2) for k in range(12)])  # with jitter
    assert spin_until(node, lambda: len(bundles) >= 10, 10.0)
    assert "frames a second by its stamps" not in capfd.readouterr().err


def test_every_camera_falling_silent_is_said_as_such(bundler, capfd):
    """A replayed bag that ended logged "no images from [every camera] ...: bundling [] only" (found by a
    walkthrough)."""
    node, _ = bundler("-p", "camera_timeout_s:=0.5")
    send(node, [100.0 + k * PERIOD_S for k in range(3)])
    for camera in CAMERAS:
        node.arrivals.last_s[camera] -= 1.0
    node.check_cameras()
    err = capfd.readouterr().err
    assert node.live_cameras == () and "bundling []" not in err
    assert f"no images from {sorted(CAMERAS)} for 0.50 s: no camera sends: no bundles until one does" in err


@pytest.mark.parametrize(("timeout_s", "check_s"), [(0.001, CAMERA_CHECK_MIN_PERIOD_S), (0.25, 0.125)])
def test_the_camera_check_runs_at_half_the_timeout_but_not_faster_than_a_hundred_times_a_second(bundler, timeout_s,
                                                                                               check_s):
    """camera_timeout_s 0.001 made a 2 kHz check that held a third of a core (review)."""
    node, _ = bundler("-p", f"camera_timeout_s:={timeout_s}")
    assert sorted(t.timer_period_ns for t in node.timers) == sorted([round(check_s * 1e9), 1_000_000_000])


def test_a_cameras_silence_is_timed_on_the_steady_clock(bundler):
    """On the system clock an NTP step longer than camera_timeout_s counted every camera silent once (review)."""
    node, _ = bundler()
    before = time.monotonic()
    assert before <= node.now_s() <= time.monotonic()


def assert_simulated_clock_reaches(node, seconds: int = 1000) -> None:
    """Publish /clock at `seconds` until the node's arrival clock reads it."""
    clock = node.create_publisher(Clock, "/clock", 10)
    at = Clock(clock=Time(sec=seconds))
    assert spin_until(node, lambda: clock.publish(at) or node.now_s() == pytest.approx(seconds), 10.0)


def test_with_use_sim_time_a_cameras_silence_is_timed_on_the_simulated_clock(bundler):
    """A bag played slower than it was recorded, or paused, is judged in its own time."""
    node, _ = bundler("-p", "use_sim_time:=true")
    assert_simulated_clock_reaches(node)


def test_images_that_come_before_the_first_clock_message_do_not_make_the_cameras_silent_when_it_comes(bundler, capfd):
    """With use_sim_time the clock reads 0 until the first /clock: the cameras whose images came before it were all
    found silent once it came, and the synchroniser started over (review)."""
    node, _ = bundler("-p", "use_sim_time:=true", "-p", "camera_timeout_s:=0.5")
    send(node, [100.0 + k * PERIOD_S for k in range(3)])
    assert node.now_s() == 0.0 and node.live_cameras == CAMERAS
    assert_simulated_clock_reaches(node)
    node.check_cameras()
    assert node.live_cameras == CAMERAS and "no images from" not in capfd.readouterr().err


def test_use_sim_time_cleared_while_the_node_runs_keeps_the_cameras_live(bundler, capfd):
    """rclpy lets use_sim_time change at runtime: after a simulated clock at 1 s the steady clock's time since boot
    read as a step forward, and every camera was found silent at once (noticed in stop 41's review)."""
    node, _ = bundler("-p", "use_sim_time:=true", "-p", "camera_timeout_s:=0.5")
    assert_simulated_clock_reaches(node, 1)
    send(node, [100.0 + k * PERIOD_S for k in range(3)])
    node.set_parameters([Parameter("use_sim_time", value=False)])
    assert node.now_s() == pytest.approx(time.monotonic(), abs=1.0)
    node.check_cameras()
    err = capfd.readouterr().err
    assert node.live_cameras == CAMERAS and "no images from" not in err, err
    assert "use_sim_time is now false: a camera's silence is timed on the steady clock from now on" in err
