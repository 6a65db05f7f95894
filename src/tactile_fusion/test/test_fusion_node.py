"""The fusion node in this process (real rclpy and DDS, the shipped model): bundles are handed to its callback, its
estimates come back through a subscription, its log through stderr."""

import os
from types import SimpleNamespace

import numpy as np
import pytest
import rclpy
import torch
from builtin_interfaces.msg import Time
from sensor_msgs.msg import Image
from std_srvs.srv import Trigger

from tactile_conversions.images import mono8_to_msg
from tactile_conversions.spinning import spin_until
from tactile_conversions.topics import ESTIMATE_TOPIC
from tactile_description import load_sensor
from tactile_fusion.fusion_node import FusionNode
from tactile_fusion.live_estimation import REFERENCE_PATIENCE_BUNDLES, FrozenCameras
from tactile_msgs.msg import ForceDistribution, ImageBundle
from tactile_sim import Simulator
from tactile_sim.scene import parse_scene

#: Two frames at rest, then a press.
PRESS = {"name": "press", "seed": 0, "indenter": {"shape": "sphere", "diameter_mm": 10},
         "timeline": [{"rest": {"frames": 2}}, {"press": {"x_mm": 18.0, "y_mm": 20.0, "depths_mm": [1.0]}}]}


@pytest.fixture(scope="module")
def press_frames():
    return list(Simulator(load_sensor()).stream(parse_scene(PRESS)))


@pytest.fixture
def init_ros(monkeypatch):
    """init_ros(*parameters): rclpy initialised with these `name:=value` parameters, in a DDS domain of this test
    process's own on loopback; shut down after the test."""
    monkeypatch.setenv("ROS_DOMAIN_ID", str(20 + (os.getpid() + 60) % 80))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

    def init(*parameters: str) -> None:
        rclpy.init(args=["--ros-args", *(arg for parameter in parameters for arg in ("-p", parameter))])

    yield init
    rclpy.try_shutdown()


@pytest.fixture
def fusion(init_ros):
    """A FusionNode with the shipped model and a reference of 2 bundles, and the list its estimates arrive in."""
    init_ros("reference_bundles:=2", "publish_markers:=false")
    node = FusionNode()
    estimates: list[ForceDistribution] = []
    node.create_subscription(ForceDistribution, ESTIMATE_TOPIC, estimates.append, 10)
    try:
        assert spin_until(node, lambda: node.forces_pub.get_subscription_count() > 0, 10.0)
        yield node, estimates
    finally:
        node.destroy_node()


def bundle(frame, sequence: int, cameras=("cam0", "cam1", "cam2", "cam3")) -> ImageBundle:
    """The frame's images of `cameras` as the bundle node bundles them."""
    sensor_ids = list(load_sensor().camera_ids)
    stamp = Time(sec=1_700_000_000 + sequence)
    images = [mono8_to_msg(frame.images[sensor_ids.index(c)], stamp, f"{c}_optical") for c in cameras]
    msg = ImageBundle(sequence=sequence, camera_ids=list(cameras), images=images)
    msg.header.stamp = stamp
    return msg


def test_a_camera_dead_at_start_up_is_named_then_left_out_of_the_reference(fusion, press_frames, capfd):
    node, estimates = fusion
    without_cam1 = ("cam0", "cam2", "cam3")
    for sequence in range(REFERENCE_PATIENCE_BUNDLES):
        node.on_bundle(bundle(press_frames[sequence % 2], sequence, without_cam1))
    node.on_bundle(bundle(press_frames[2], REFERENCE_PATIENCE_BUNDLES, without_cam1))
    node.on_bundle(bundle(press_frames[2], REFERENCE_PATIENCE_BUNDLES + 1))  # cam1 is back
    assert spin_until(node, lambda: len(estimates) == 2, 10.0)
    log = capfd.readouterr().err
    assert "capturing the reference: no usable image of cam1 (0 of 2 complete bundles so far); after 80 bundles" in log
    # a camera no bundle held may be dead or another sensor's: a bundle node with another sensor_config was told apart
    # from a camera that fell silent only by reading both nodes' logs (found in review)
    assert ", which are then not used until it is taken again; no bundle has held cam1 since this node started: dead " \
        "since, or the bundle node runs with another sensor description than this node's" in log
    assert "no image of cam1 (missing from the bundle: the bundle node leaves out a camera that fell silent (its log " \
        "says since when); no bundle has held cam1 since this node started" in log
    assert f"reference frames captured without cam1 ({REFERENCE_PATIENCE_BUNDLES} bundles brought fewer than 2 " \
        "complete ones): publishing forces without them (listed as missing)" in log
    assert "images of cam1 arrive again, but the reference frames were taken without them" in log
    assert [list(e.missing_camera_ids) for e in estimates] == [["cam1"], ["cam1"]]
    assert all(np.isfinite(e.forces_n).all() and sum(e.forces_n[2::3]) > 0.5 for e in estimates)  # the press


def test_a_camera_whose_images_never_change_while_the_reference_is_taken_is_named(fusion, press_frames, capfd):
    """A frozen camera (or a still source, a covered lens) is shown at rest while its image equals its reference: it
    went unmentioned."""
    node, estimates = fusion
    for sequence in range(2):
        images = np.array(press_frames[0].images)  # the scene has no sensor noise: its frames at rest are equal
        images[:, 0, 0] ^= sequence  # a pixel of each camera differs in the second bundle ...
        images[2] = press_frames[0].images[2]  # ... but cam2's: the same image in both reference bundles
        node.on_bundle(bundle(SimpleNamespace(images=images), sequence))
    node.on_bundle(bundle(press_frames[2], 2))
    assert spin_until(node, lambda: len(estimates) == 1, 10.0)
    log = capfd.readouterr().err
    assert "the images of cam2 did not change at all over the 2 reference bundles: a frozen camera" in log, log


def test_a_camera_that_sends_the_same_image_again_and_again_is_named_and_so_is_its_recovery(fusion, press_frames,
                                                                                            capfd):
    node, estimates = fusion
    count = 2 + FrozenCameras.FRAMES + 1  # the reference, then the first image and FRAMES equal ones
    for sequence in range(count + 1):
        images = np.array(press_frames[0].images)
        images[:, 0, 0] ^= sequence & 1  # the others change from bundle to bundle, as sensor noise makes them
        if sequence < count:
            images[2] = press_frames[0].images[2]  # cam2 is stuck on one image, then changes again
        node.on_bundle(bundle(SimpleNamespace(images=images), sequence))
    assert spin_until(node, lambda: len(estimates) > 0, 10.0)  # estimated all along (the last 10 are kept)
    log = capfd.readouterr().err
    assert log.count(f"cam2 has sent the same image, pixel for pixel, for {FrozenCameras.FRAMES} bundles") == 1, log
    assert "cam0 has sent" not in log and "cam2's images change again" in log


def test_every_broken_camera_of_a_bundle_is_named_in_one_line(fusion, press_frames, capfd):
    node, estimates = fusion
    for sequence in range(2):
        node.on_bundle(bundle(press_frames[sequence], sequence))
    broken = bundle(press_frames[2], 2)
    broken.images[1].data = bytes(10)  # cam1: too few bytes
    broken.images[3] = Image(height=4, width=4, encoding="mono8", step=4, data=bytes(16))  # cam3: too small
    node.on_bundle(broken)
    assert spin_until(node, lambda: len(estimates) == 1, 10.0)
    lines = [line for line in capfd.readouterr().err.splitlines() if "bundle 2:" in line]
    assert len(lines) == 1 and "unreadable image of cam1" in lines[0] and "cam3 image of 4 x 4 pixels" in lines[0]
    assert "(1 bundle(s) with missing or unusable images since start)" in lines[0]
    assert list(estimates[0].missing_camera_ids) == ["cam1", "cam3"]


@pytest.mark.parametrize(("cameras", "named", "published"), [
    (("cam0", "cam2", "cam3"), "cam1", 1),
    ((), "cam0, cam1, cam2, cam3", 0),  # an empty bundle: nothing to publish
])
def test_cameras_missing_from_a_bundle_are_named(fusion, press_frames, capfd, cameras, named, published):
    """After the reference, a bundle without cam1 was published listing it as missing, and of an empty bundle nothing
    was published, both without a word in the log (found in review)."""
    node, estimates = fusion
    for sequence in range(2):
        node.on_bundle(bundle(press_frames[sequence], sequence))
    node.on_bundle(bundle(press_frames[2], 2, cameras))
    spin_until(node, lambda: len(estimates) == published, 2.0)
    assert len(estimates) == published and all(list(e.missing_camera_ids) == [named] for e in estimates)
    assert f"bundle 2: no image of {named} (missing from the bundle: the bundle node leaves out a camera that fell " \
           "silent (its log says since when)) (1 bundle(s) with missing or unusable images since start)" \
           in capfd.readouterr().err


def malformed(msg: ImageBundle) -> ImageBundle:
    msg.images = msg.images[:3]  # four camera ids, three images
    return msg


def of_another_sensor(msg: ImageBundle) -> ImageBundle:
    """As a bundle node run with another sensor description bundles: its cam4 is a camera this sensor has not (a
    3 x 3 skin's cam0 to cam8: the estimate of the other cameras went out as complete; review)."""
    msg.camera_ids = ["cam0", "cam1", "cam2", "cam4"]
    return msg


UNUSABLE = [(malformed, "malformed bundle (4 camera ids ['cam0', 'cam1', 'cam2', 'cam3'] for 3 image(s); the bundle "
             "is skipped)"),
            (of_another_sensor, "bundle of another sensor (cameras ['cam4'] are not in the sensor description, whose "
             "cameras are ['cam0', 'cam1', 'cam2', 'cam3']: the bundle node (or the bag) bundles another sensor's "
             "cameras; give both the same sensor_config; the bundle is skipped)")]


@pytest.mark.parametrize(("spoil", "said"), UNUSABLE)
def test_a_bundle_that_cannot_be_used_is_skipped_and_the_node_goes_on(fusion, press_frames, capfd, spoil, said):
    node, estimates = fusion
    for sequence in range(2):
        node.on_bundle(bundle(press_frames[sequence], sequence))
    node.on_bundle(spoil(bundle(press_frames[2], 2)))
    node.on_bundle(bundle(press_frames[2], 3))
    assert spin_until(node, lambda: len(estimates) == 1, 10.0)
    assert not spin_until(node, lambda: len(estimates) > 1, 0.3)  # nothing from the bundle that cannot be used
    assert f"bundle 2: {said}" in capfd.readouterr().err
    assert list(estimates[0].missing_camera_ids) == [] and estimates[0].header.stamp.sec == 1_700_000_003


@pytest.mark.parametrize(("sec", "nanosec"), [(-5, 0), (-1, 1_500_000_000)])
def test_a_bundle_stamped_before_1970_is_skipped_not_published_with_its_stamp(fusion, press_frames, capfd, sec,
                                                                              nanosec):
    """The estimate carried the bundle's stamp as it was: sec -5 reached /tactile/force_distribution (review). A Time
    message holds a negative sec, and a bag or another publisher than the bundle node may send one; sec -1 with
    nanosec 1.5e9 is 0.5 s as seconds, and went out as sec -1 (review)."""
    node, estimates = fusion
    for sequence in range(2):
        node.on_bundle(bundle(press_frames[sequence], sequence))
    bad = bundle(press_frames[2], 2)
    bad.header.stamp = Time(sec=sec, nanosec=nanosec)
    node.on_bundle(bad)
    node.on_bundle(bundle(press_frames[2], 3))
    assert spin_until(node, lambda: len(estimates) == 1, 10.0)
    assert not spin_until(node, lambda: len(estimates) > 1, 0.3)
    assert estimates[0].header.stamp.sec == 1_700_000_003
    assert f"bundle 2: stamp outside [0, 2**31) s (sec {sec}, nanosec {nanosec}, which no estimate can carry; the " \
        "bundle is skipped)" in capfd.readouterr().err


@pytest.mark.parametrize("spoil", [malformed, of_another_sensor])
def test_a_bundle_that_cannot_be_used_does_not_count_towards_the_reference(fusion, press_frames, spoil):
    node, estimates = fusion
    node.on_bundle(bundle(press_frames[0], 0))
    node.on_bundle(spoil(bundle(press_frames[1], 1)))
    assert node.live.reference.images is None and node.live.reference.frames_seen == 1  # still one of 2 to come
    node.on_bundle(bundle(press_frames[1], 2))
    node.on_bundle(bundle(press_frames[2], 3))
    assert node.live.reference.images is not None
    assert spin_until(node, lambda: len(estimates) == 1, 10.0)


def test_the_capture_reference_service_takes_the_reference_again_from_the_next_bundles(fusion, press_frames):
    """Nothing is published while the new reference is taken; then estimates against it: the press itself taken as
    the reference reads as no contact."""
    node, estimates = fusion
    for sequence in range(2):
        node.on_bundle(bundle(press_frames[sequence], sequence))
    node.on_bundle(bundle(press_frames[2], 2))
    assert spin_until(node, lambda: len(estimates) == 1, 10.0)
    pressed = np.asarray(estimates[0].forces_n).reshape(-1, 3)[:, 2].sum()
    response = node.on_capture_reference(Trigger.Request(), Trigger.Response())
    assert response.success and response.message == "capturing the reference from the next 2 complete bundles"
    for sequence in range(3, 5):
        node.on_bundle(bundle(press_frames[2], sequence))  # the press held: the new reference
    assert not spin_until(node, lambda: len(estimates) > 1, 0.3)
    node.on_bundle(bundle(press_frames[2], 5))
    assert spin_until(node, lambda: len(estimates) == 2, 10.0)
    assert pressed > 0.1 and np.asarray(estimates[1].forces_n).reshape(-1, 3)[:, 2].sum() < 0.01 * pressed


def test_the_nodes_torch_work_runs_on_its_threads(init_ros):
    """The reference check runs in torch whatever the backend; with ONNX Runtime torch kept its default of every core,
    and beside other busy processes a check took 128 ms instead of 0.8 ms (review)."""
    torch.set_num_threads(2)
    init_ros("threads:=1", "backend:=onnxruntime")
    node = FusionNode()
    assert torch.get_num_threads() == 1
    node.destroy_node()


def test_markers_rate_hz_is_refused_without_the_remedy_already_taken(init_ros):
    """With publish_markers false the refusal still said "to publish no markers, set publish_markers false" (review)."""
    init_ros("publish_markers:=false", "markers_rate_hz:=0")
    with pytest.raises(ValueError, match="parameter markers_rate_hz must be a") as refusal:
        FusionNode()
    assert "set publish_markers false" not in str(refusal.value)


@pytest.mark.parametrize(("value", "accepted"), [("5", 5.0), ("2.5", 2.5), ("inf", None), ("0", None),
                                                 ("nan", None), ("fast", None)])
def test_markers_rate_hz_takes_integers_and_refuses_what_is_not_a_finite_positive_rate(init_ros, value, accepted):
    init_ros(f"markers_rate_hz:={value}")
    if accepted is None:
        with pytest.raises(ValueError, match="parameter markers_rate_hz must be a"):
            FusionNode()
    else:
        node = FusionNode()
        assert node.markers_period_s == pytest.approx(1.0 / accepted)
        node.destroy_node()
