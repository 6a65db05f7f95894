"""The camera drivers and the bundle node: their parameters as a command line gives them, the end of a recording
with `loop` false, and what the bundle node does with stamps that jump back and with images it drops.

Parameters: the nodes built in this process (real rclpy, `-p` arguments as a command line passes them). The
rest: real node processes over Fast DDS on loopback."""

import itertools
import re
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from rclpy.clock import ClockType
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import Image

from tactile_bringup.graph import NodeSpec
from tactile_bringup.processes import spin_until, start_node, stop_nodes, wait_for_log
from tactile_camera_driver.camera_node import CameraNode
from tactile_camera_driver.sim_camera_node import SimCameraNode
from tactile_conversions.images import mono8_to_msg
from tactile_conversions.parameters import ParameterError
from tactile_conversions.ros_time import seconds_to_time, time_to_seconds
from tactile_description import default_sensor_path, load_sensor
from tactile_fusion.bundle_node import DROP_LOG_PERIOD_S, BundleNode
from tactile_fusion.fusion_node import FusionNode
from tactile_msgs.msg import ImageBundle

CONFIG = str(default_sensor_path())


def build_node(node_class, parameters: dict[str, str]):
    """`node_class()` with `-p name:=value` for each parameter, as on a command line; returns the node (destroyed
    and shut down by the caller's `rclpy.try_shutdown()`)."""
    args = ["--ros-args", "-p", f"sensor_config:={CONFIG}"]
    for name, value in parameters.items():
        args += ["-p", f"{name}:={value}"]
    rclpy.init(args=args)
    return node_class()


@pytest.fixture
def ros_args_node(ros_domain):
    """ros_args_node(node_class, {name: command-line value}): a node built as a command line would build it."""
    nodes = []

    def build(node_class, parameters):
        nodes.append(build_node(node_class, parameters))
        return nodes[-1]

    yield build
    for node in nodes:
        node.destroy_node()
    rclpy.try_shutdown()


def test_the_nodes_keep_their_pace_on_the_steady_clock(ros_args_node):
    """Timers on the node's ROS clock, the system clock: an NTP step back of 30 s silenced a camera for 30 s, and with
    use_sim_time and no /clock it never published (review). The stamps stay the node's clock's."""
    for node_class in (CameraNode, SimCameraNode, BundleNode):
        node = ros_args_node(node_class, {})
        assert node.timers and all(t.clock.clock_type == ClockType.STEADY_TIME for t in node.timers), node_class
        assert node.get_clock().clock_type == ClockType.ROS_TIME
        rclpy.try_shutdown()


def test_integers_from_the_command_line_are_taken_for_float_parameters_and_a_device_index(ros_args_node):
    bundle = ros_args_node(BundleNode, {"max_spread_s": "1", "min_period_s": "0", "camera_timeout_s": "2",
                                        "keep_grouping_s": "0"})
    assert (bundle.max_spread_s, bundle.min_period_s, bundle.camera_timeout_s, bundle.keep_grouping_s) == \
        (1.0, 0.0, 2.0, 0.0)
    assert isinstance(bundle.max_spread_s, float)
    rclpy.try_shutdown()
    camera = ros_args_node(CameraNode, {"camera_id": "cam1", "source": "2", "rate_hz": "30", "reopen_period_s": "2"})
    assert camera.source == 2 and camera.reopen_period_s == 2.0
    assert camera.timer.timer_period_ns == round(1e9 / 30)
    rclpy.try_shutdown()
    camera = ros_args_node(CameraNode, {"source": "'3'"})  # a string of digits, as camera_sources.yaml gives one
    assert camera.source == 3
    rclpy.try_shutdown()
    sim = ros_args_node(SimCameraNode, {"rate_hz": "20", "stamp_jitter_s": "0"})
    assert sim.timer.timer_period_ns == 50_000_000 and sim.stamp_jitter_s == 0.0
    rclpy.try_shutdown()
    sim = ros_args_node(SimCameraNode, {"stamp_jitter_s": "0.025", "loop": "false"})  # one frame period at 40 Hz
    assert sim.stamp_jitter_s == 0.025 and sim.loop is False
    rclpy.try_shutdown()
    sim = ros_args_node(SimCameraNode, {"rate_hz": "1000"})  # the default jitter, 2 ms, is cut to the frame period
    assert sim.timer.timer_period_ns == 1_000_000 and sim.stamp_jitter_s == 0.001


@pytest.mark.parametrize("node_class, parameters, message", [
    (BundleNode, {"max_spread_s": ".nan"}, "tactile_bundle: parameter max_spread_s must be a finite number > 0, "
                                           "got nan"),
    (BundleNode, {"min_period_s": ".nan"}, "parameter min_period_s must be a finite number >= 0, got nan"),
    (BundleNode, {"keep_grouping_s": "-1"}, "parameter keep_grouping_s must be a finite number >= 0, got -1"),
    (BundleNode, {"camera_timeout_s": ".nan"}, "parameter camera_timeout_s must be a finite number > 0, got nan"),
    (BundleNode, {"camera_timeout_s": ".inf"}, "parameter camera_timeout_s must be a finite number > 0, got inf"),
    (BundleNode, {"max_spread_s": "fast"}, "parameter max_spread_s must be a finite number > 0, got 'fast'"),
    (BundleNode, {"queue_size": "0"}, "parameter queue_size must be a whole number >= 1, got 0"),
    (BundleNode, {"queue_size": "10.0"}, "parameter queue_size must be a whole number >= 1, got 10.0"),
    (CameraNode, {"rate_hz": ".nan"}, "tactile_camera: parameter rate_hz must be a finite number > 0, got nan"),
    (CameraNode, {"reopen_period_s": "0"}, "parameter reopen_period_s must be a finite number > 0, got 0"),
    # accepted before: a source that failed was never tried again (review)
    (CameraNode, {"reopen_period_s": "1e300"},
     "parameter reopen_period_s must be at most 86400 s (one day), got 1e+300"),
    (CameraNode, {"source": "-1"}, "parameter source must be a device index (an integer from 0 to 2147483647), a "
                                   "device path or a video file, got -1"),
    (CameraNode, {"source": "''"}, "parameter source must be a device index"),
    # OpenCV's index is a C int, and '²'.isdigit(): cv2.error and ValueError tracebacks (found in review)
    (CameraNode, {"source": "4294967296"}, "parameter source must be a device index (an integer from 0 to "
                                           "2147483647), a device path or a video file, got 4294967296"),
    (CameraNode, {"source": "'4294967296'"}, "got 4294967296"),
    (SimCameraNode, {"stamp_jitter_s": ".nan"}, "parameter stamp_jitter_s must be a finite number >= 0, got nan"),
    (SimCameraNode, {"rate_hz": ".nan"}, "tactile_sim_cameras: parameter rate_hz must be a finite number > 0"),
    # a timer of a period beyond rcl's reach failed with a pybind TypeError naming no parameter
    (SimCameraNode, {"rate_hz": "1e-12"}, "tactile_sim_cameras: parameter rate_hz must be at least 1.15741e-05 Hz"),
    (CameraNode, {"rate_hz": "1e-12"}, "tactile_camera: parameter rate_hz must be at least 1.15741e-05 Hz"),
    (FusionNode, {"markers_rate_hz": "1e-12"}, "parameter markers_rate_hz must be at least 1.15741e-05 Hz (once a "
                                               "day), got 1e-12 (to publish no markers, set publish_markers false)"),
    (FusionNode, {"threads": "0"}, "tactile_fusion: parameter threads must be a whole number from 1 to 1024, got 0"),
    # went to ONNX Runtime, whose thread pool took 24 GB for 100000000 threads
    (FusionNode, {"threads": "1025"}, "parameter threads must be a whole number from 1 to 1024, got 1025"),
    # every bundle is held until the reference is taken: 100000 would be 6.5 GB and 42 minutes without an estimate
    (FusionNode, {"reference_bundles": "401"}, "parameter reference_bundles must be a whole number from 1 to 400, "
                                               "got 401"),
    # ended the node with load_predictor's ValueError traceback
    (FusionNode, {"precision": "int4"}, "tactile_fusion: parameters backend and precision: the onnxruntime backend "
                                        "runs fp32, int8, fp16, not 'int4'"),
    # a file named by a parameter that cannot be used ended the node with a traceback
    (BundleNode, {"sensor_config": "/no/such/sensor.yaml"}, "tactile_bundle: parameter sensor_config: "),
    (SimCameraNode, {"scene": "no_such_scene"}, "tactile_sim_cameras: parameter scene: no scene file 'no_such_scene'"),
    (FusionNode, {"model_dir": "/no/such/model"}, "tactile_fusion: parameter model_dir: no model in /no/such/model: "
                                                  "no such directory"),
    # the shipped model, for the reference sensor, refused for another without naming it (found in review)
    (FusionNode, {"sensor_config": str(Path(CONFIG).parent / "skin_3x3.yaml")},
     "tactile_fusion: parameter model_dir (empty: the shipped model, "),
    (FusionNode, {"backend": "tensorrt"}, "parameters backend and precision: backend must be one of ['onnxruntime', "
                                          "'torch'], got 'tensorrt'"),
    (FusionNode, {"reference_bundles": "2.5"}, "parameter reference_bundles must be a whole number from 1 to 400, "
                                               "got 2.5"),
    # a timer of period 0 (1e-12 s rounded to whole nanoseconds), which fires on every spin
    (SimCameraNode, {"rate_hz": "1e12"}, "tactile_sim_cameras: parameter rate_hz must be at most 1000 Hz, got "
                                         "1000000000000.0"),
    (CameraNode, {"rate_hz": "1001"}, "tactile_camera: parameter rate_hz must be at most 1000 Hz, got 1001"),
    (FusionNode, {"markers_rate_hz": "1e12"}, "parameter markers_rate_hz must be at most 1000 Hz, got 1000000000000.0"),
    # stamps past what a ROS Time holds: the node failed at its first frame
    (SimCameraNode, {"stamp_jitter_s": "1e12"}, "tactile_sim_cameras: parameter stamp_jitter_s must be at most one "
                                                "frame period, 0.025 s at rate_hz 40, got 1000000000000.0"),
    (SimCameraNode, {"rate_hz": "100", "stamp_jitter_s": "0.02"}, "parameter stamp_jitter_s must be at most one "
                                                                  "frame period, 0.01 s at rate_hz 100, got 0.02"),
    # rclpy's typed declarations refused these with an InvalidParameterTypeException traceback naming no node
    (SimCameraNode, {"loop": "0"}, "tactile_sim_cameras: parameter loop must be a bool (true or false), got 0"),
    (SimCameraNode, {"scene": "3"}, "tactile_sim_cameras: parameter scene must be a string, got 3"),
    # a name rcl cannot expand would have raised in the timer, at the first frame
    # a name no node can have would have been waited for for ever
    (SimCameraNode, {"wait_for_nodes": "'tactile_bundle, no node'"}, "tactile_sim_cameras: parameter wait_for_nodes: "
                                                                     "Invalid node name: node name must not contain"),
    (CameraNode, {"loop": "'no'"}, "tactile_camera: parameter loop must be a bool (true or false), got 'no'"),
    (CameraNode, {"camera_id": "3"}, "tactile_camera: parameter camera_id must be a string, got 3"),
    (CameraNode, {"camera_id": "cam9"}, "tactile_camera: parameter camera_id must name a camera of the sensor "
                                        "description (['cam0', 'cam1', 'cam2', 'cam3']), got 'cam9'"),
    (BundleNode, {"sensor_config": "1.5"}, "tactile_bundle: parameter sensor_config must be a string, got 1.5"),
    (FusionNode, {"publish_markers": "1"}, "tactile_fusion: parameter publish_markers must be a bool (true or "
                                           "false), got 1"),
    (FusionNode, {"backend": "2"}, "tactile_fusion: parameter backend must be a string, got 2"),
])
def test_bad_parameter_values_are_refused_naming_the_parameter(ros_args_node, node_class, parameters, message):
    """A ParameterError: run_node ends the node with its message in one line and exit code 2."""
    with pytest.raises(ParameterError) as refused:
        ros_args_node(node_class, parameters)
    assert message in str(refused.value)


def test_the_simulated_cameras_refuse_a_scene_whose_contacts_their_ground_truth_would_count_twice(ros_args_node,
                                                                                                  tmp_path):
    """Refused as the scene, in one line (run_node): the refusal came from `Simulator.stream`, outside the scene's
    refusal, and ended the node in a traceback with status 1 (found in review)."""
    scene = tmp_path / "overlap.yaml"
    scene.write_text("name: overlap\nseed: 1\ntimeline:\n  - contacts: {contacts: [{x_mm: 20, y_mm: 20, "
                     "depth_mm: 1.0}, {x_mm: 22, y_mm: 20, depth_mm: 1.0}]}\n")
    with pytest.raises(ParameterError) as refused:
        ros_args_node(SimCameraNode, {"scene": str(scene)})
    assert str(refused.value).startswith(f"tactile_sim_cameras: parameter scene: {scene}.timeline[0].contacts."
                                         "contacts[0] and contacts[1] overlap: 2 mm apart")


@pytest.mark.parametrize("node_class", [SimCameraNode, CameraNode, BundleNode, FusionNode])
def test_each_node_says_which_sensor_description_it_uses(ros_args_node, capfd, node_class):
    """A misspelt `-p sensor_configs:=...` left a node on the default sensor without a word (found in review): each
    node names the description it took, once it has accepted its parameters (a refusal stays one line, below)."""
    ros_args_node(node_class, {"sensor_configs": "/my/skin.yaml"})
    assert f"sensor description 'trueeb2020_4cam' (4 cameras, 26 x 25 bins) from {CONFIG}" in capfd.readouterr().err


@pytest.mark.parametrize("executable, parameter, line", [
    ("sim_camera_node", "loop:=0", "tactile_sim_cameras: parameter loop must be a bool (true or false), got 0"),
    ("camera_node", "rate_hz:=1e12", "tactile_camera: parameter rate_hz must be at most 1000 Hz, got 1000000000000.0"),
])
def test_a_node_refusing_a_parameter_says_why_in_one_line_and_exits_with_status_2(ros_domain, executable, parameter,
                                                                                   line):
    """As the command-line tools refuse their input; `-p loop:=0` ended in rclpy's InvalidParameterTypeException
    traceback (exit code 1), and `-p rate_hz:=1e12` started a camera node whose timer had a period of 0."""
    run = subprocess.run([executable, "--ros-args", "-p", f"sensor_config:={CONFIG}", "-p", parameter],
                         capture_output=True, text=True, timeout=60)
    assert (run.returncode, run.stderr) == (2, line + "\n"), run.stderr


@pytest.mark.parametrize("problem", ["particles_in_the_rigid_base", "a_scene_whose_frames_cannot_be_made"])
def test_the_simulated_cameras_refuse_what_only_the_simulator_finds_in_one_line(ros_probe, tmp_path, problem):
    """A sensor description that only the simulator refuses, and a scene whose frames cannot be made (no room for four
    presses 45 mm apart, after three frames at rest), ended sim_camera_node in a traceback with status 1, the second
    with the graph running (found in review); the simulator now finds the second before any frame
    (Scene.check_playable). The probe listens, so that the scene would play."""
    if problem == "particles_in_the_rigid_base":
        config = tmp_path / "sensor.yaml"
        config.write_text(re.sub(r"(?m)^  layer: particle_layer$", "  layer: transparent_base",
                                 default_sensor_path().read_text()))
        parameters, line = ["sensor_config:=" + str(config)], "parameter sensor_config: "
    else:
        scene = tmp_path / "crowded.yaml"
        scene.write_text("name: crowded\nseed: 1\nindenter: {shape: sphere, diameter_mm: 4}\ntimeline:\n"
                         "  - rest: {frames: 3}\n  - random_presses: {frames: 10, contacts_per_frame: 4, "
                         "min_separation_mm: 45.0, depth_mm: [0.3, 0.5]}\n")
        parameters, line = ["sensor_config:=" + CONFIG, "scene:=" + str(scene)], "parameter scene: "
    ros_probe.create_subscription(Image, "/tactile/cam0/image", lambda _: None, qos_profile_sensor_data)
    node = subprocess.Popen(["sim_camera_node", "--ros-args", *itertools.chain(*(["-p", p] for p in parameters))],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        spin_until(ros_probe, lambda: node.poll() is not None, 60.0)
    finally:
        if node.poll() is None:
            node.kill()
        _, stderr = node.communicate()
    last = stderr.strip().splitlines()[-1]
    assert node.returncode == 2 and last.startswith("tactile_sim_cameras: " + line), stderr
    assert "Traceback" not in stderr


def test_the_bundle_node_reports_the_images_it_dropped_when_it_stops(ros_domain, capfd):
    """However recent its previous report (here: none, the node never spun), as its camera set never changed."""
    node = build_node(BundleNode, {})
    try:
        image = mono8_to_msg(np.zeros((128, 128), np.uint8), seconds_to_time(100.0), "cam0_optical")
        node.on_image("cam0", image)
        node.on_image("cam0", image)  # the same stamp again
        node.destroy_node()
    finally:
        rclpy.try_shutdown()
    assert "the synchroniser dropped 1 image(s) (out_of_order 1; cam0 1), 1 since start" in capfd.readouterr().err


def test_the_bundle_node_logs_drops_at_once_then_at_most_every_drop_log_period(ros_domain, capfd):
    """The timer's report_drops, called here by hand; the 10 s are skipped by moving the last report back in time."""
    node = build_node(BundleNode, {})
    try:
        def drop_one(stamp_s: float) -> str:
            image = mono8_to_msg(np.zeros((128, 128), np.uint8), seconds_to_time(stamp_s), "cam0_optical")
            node.on_image("cam0", image)
            node.on_image("cam0", image)  # the same stamp again: dropped as out of order
            node.report_drops()
            return capfd.readouterr().err

        assert "dropped 1 image(s) (out_of_order 1; cam0 1), 1 since start" in drop_one(100.0)
        assert "dropped" not in drop_one(101.0)  # within DROP_LOG_PERIOD_S of the first report
        node.last_report_s -= DROP_LOG_PERIOD_S
        assert "dropped 2 image(s) (out_of_order 2; cam0 2), 3 since start" in drop_one(102.0)
        node.last_report_s -= DROP_LOG_PERIOD_S
        node.report_drops()
        assert "dropped" not in capfd.readouterr().err  # nothing new, nothing said
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


@pytest.mark.system
def test_the_simulated_cameras_play_from_the_first_frame_once_subscribed_then_say_once_that_the_scene_ended(
        collect, lossless_image_qos, tmp_path):
    """8 frames, loop false: nothing is played while nobody listens (the scene ran on while DDS discovery connected
    the bundle node, and under load the reference frames were taken during a press: found in review), then all 8."""
    scene = tmp_path / "short.yaml"
    scene.write_text("name: short\nseed: 1\ntimeline:\n  - rest: {frames: 8}\n")
    spec = NodeSpec("tactile_camera_driver", "sim_camera_node", "sim_once",
                    {"sensor_config": CONFIG, "scene": str(scene), "loop": False, "rate_hz": 40})
    process = start_node(spec, tmp_path)
    try:
        wait_for_log(tmp_path / "sim_once.log", "simulating scene", timeout_s=20.0)
        time.sleep(1.0)  # 40 frame periods: the scene would have ended unheard
        unheard = (tmp_path / "sim_once.log").read_text()
        images = collect(Image, "/tactile/cam0/image", seconds=20.0, qos=lossless_image_qos,
                         until=lambda received: len(received) >= 8)
        wait_for_log(tmp_path / "sim_once.log", "ended", timeout_s=20.0)
        after_the_end = collect(Image, "/tactile/cam0/image", seconds=0.5, qos=qos_profile_sensor_data)
        running = process.poll() is None
    finally:
        codes = stop_nodes([process])
    log = (tmp_path / "sim_once.log").read_text()
    assert "ended" not in unheard and "playing" not in unheard, unheard
    assert running and codes == [0], log
    assert len(images) == 8, log  # from the first frame: the subscriber lost none
    assert log.count(f"scene '{scene}' ended (8 frames; loop false): publishing nothing more") == 1, log
    assert after_the_end == []


@pytest.mark.system
def test_the_simulated_scene_waits_for_the_nodes_of_wait_for_nodes_and_loses_none_of_its_frames(collect, tmp_path):
    """The sensor graph's cameras wait for the fusion node, which subscribes to bundles once its model is loaded,
    seconds after a launch file starts every node at once: a scene that played on the bundle node's subscription
    alone gave it bundles of the press for its reference. Here the probe is the fusion node; it subscribes 2 s after
    the scene could have played, and misses none of it."""
    scene = tmp_path / "short.yaml"
    scene.write_text("name: short\nseed: 1\ntimeline:\n  - rest: {frames: 8}\n")
    specs = [NodeSpec("tactile_fusion", "bundle_node", "bundles", {"sensor_config": CONFIG}),
             NodeSpec("tactile_camera_driver", "sim_camera_node", "sim_once",
                      {"sensor_config": CONFIG, "scene": str(scene), "loop": False, "rate_hz": 40,
                       "wait_for_nodes": "bundles, system_test_probe"})]
    processes = [start_node(spec, tmp_path) for spec in specs]
    try:
        wait_for_log(tmp_path / "sim_once.log", "waiting for nodes ['system_test_probe'] to subscribe",
                     timeout_s=20.0)
        time.sleep(2.0)
        unheard = (tmp_path / "sim_once.log").read_text()
        bundles = collect(ImageBundle, "/tactile/image_bundle", seconds=20.0, until=lambda got: len(got) >= 7)
    finally:
        codes = stop_nodes(processes)
    log = (tmp_path / "sim_once.log").read_text()
    assert "playing scene" not in unheard, unheard
    assert "once their images and nodes ['bundles', 'system_test_probe'] subscribe" in log
    assert codes == [0, 0] and len(bundles) >= 7, log
    assert bundles[0].sequence == 0  # the first bundle of the scene


@pytest.mark.system
def test_the_simulated_scene_waits_for_the_nodes_of_its_own_namespace(ros_probe, lossless_image_qos, tmp_path):
    """Two sensors' graphs in /left and /right: the right cameras wait for the right bundle node, and the left one of
    the same name, up first, does not start the right scene (until 2026-11-28 a node of that name in any namespace
    counted, and the right fusion node could take a press for its reference)."""
    frames = 40
    scene = tmp_path / "rest.yaml"
    scene.write_text(f"name: rest\nseed: 1\ntimeline:\n  - rest: {{frames: {frames}}}\n")
    images = []
    ros_probe.create_subscription(Image, "/right/tactile/cam0/image", images.append, lossless_image_qos)

    def bundles(side: str) -> NodeSpec:
        return NodeSpec("tactile_fusion", "bundle_node", "bundles", {"sensor_config": CONFIG}, f"/{side}")

    def left_bundles_subscribe() -> bool:
        return ("bundles", "/left") in ros_probe.get_node_names_and_namespaces() and bool(
            ros_probe.get_subscriber_names_and_types_by_node("bundles", "/left"))

    right = tmp_path / "right"
    processes = [start_node(bundles("left"), tmp_path / "left")]
    try:
        left_up = spin_until(ros_probe, left_bundles_subscribe, 20.0)  # before the right scene could start on it
        processes.append(start_node(NodeSpec("tactile_camera_driver", "sim_camera_node", "sim_once",
                                             {"sensor_config": CONFIG, "scene": str(scene), "loop": False,
                                              "rate_hz": 40, "wait_for_nodes": "bundles"}, "/right"), right))
        wait_for_log(right / "sim_once.log", "waiting for nodes ['bundles'] to subscribe", timeout_s=20.0)
        spin_until(ros_probe, lambda: False, 2.0)
        images_before = len(images)
        processes.append(start_node(bundles("right"), right))
        spin_until(ros_probe, lambda: len(images) >= frames, 30.0)
    finally:
        codes = stop_nodes(processes)
    log = (right / "sim_once.log").read_text()
    assert left_up and images_before == 0 and len(images) == frames, log
    assert codes == [0, 0, 0], log


@pytest.mark.system
def test_an_image_subscriber_that_came_first_does_not_start_the_scene_before_the_bundle_node(ros_probe,
                                                                                           lossless_image_qos,
                                                                                           tmp_path):
    """A bag recorder started before the demo subscribed to the images at once, and the scene played while DDS
    discovery took 2.4 s to connect the bundle node: the fusion node's reference showed a press (found in review, 1
    of 7 runs). Here the probe is the recorder; the bundle node starts 1 s after the scene could have played. Bundle k
    must hold frame k: the bundle node heard the scene from its first frame. The probe itself connects to the bundle
    node while the scene plays and may miss its first bundles: once, on a loaded machine, more than 60 of them (a fresh
    clone's CI run, 2026-11-27, when the scene lasted 2 s). The scene lasts 5 s, and the check is of the first bundle
    the probe got."""
    frames = 200
    scene = tmp_path / "rest.yaml"
    scene.write_text(f"name: rest\nseed: 1\ntimeline:\n  - rest: {{frames: {frames}}}\n")
    images, bundles = [], []
    ros_probe.create_subscription(Image, "/tactile/cam0/image", images.append, lossless_image_qos)
    ros_probe.create_subscription(ImageBundle, "/tactile/image_bundle", bundles.append, 100)
    processes = [start_node(NodeSpec("tactile_camera_driver", "sim_camera_node", "sim_once",
                                     {"sensor_config": CONFIG, "scene": str(scene), "loop": False, "rate_hz": 40,
                                      "wait_for_nodes": "bundles"}), tmp_path)]
    try:
        wait_for_log(tmp_path / "sim_once.log", "waiting for nodes ['bundles'] to subscribe", timeout_s=20.0)
        spin_until(ros_probe, lambda: False, 1.0)
        images_before = len(images)
        processes.append(start_node(NodeSpec("tactile_fusion", "bundle_node", "bundles", {"sensor_config": CONFIG}),
                                    tmp_path))
        spin_until(ros_probe, lambda: "ended" in (tmp_path / "sim_once.log").read_text(), 30.0)  # receiving
        spin_until(ros_probe, lambda: False, 1.0)
    finally:
        codes = stop_nodes(processes)
    log = (tmp_path / "sim_once.log").read_text()
    assert images_before == 0 and len(images) == frames, log
    assert codes == [0, 0] and bundles, log
    first = bundles[0]
    cam0 = first.images[list(first.camera_ids).index("cam0")]
    assert cam0.header.stamp == images[first.sequence].header.stamp


class FakeCameras:
    """Four cameras as the probe node: publishes each camera's frame k stamped `start_s + k * PERIOD_S` (plus a
    small per-camera offset), one frame every PERIOD_S of wall time, spinning the probe in between."""

    PERIOD_S = 0.025

    def __init__(self, probe, camera_ids):
        self.probe = probe
        self.publishers = {c: probe.create_publisher(Image, f"/tactile/{c}/image", qos_profile_sensor_data)
                           for c in camera_ids}
        self.image = np.zeros((128, 128), np.uint8)

    def play(self, start_s: float, frames: int, cameras=None) -> None:
        for k in range(frames):
            for i, (camera_id, publisher) in enumerate(self.publishers.items()):
                if cameras is None or camera_id in cameras:
                    stamp = seconds_to_time(start_s + k * self.PERIOD_S + 0.001 * i)
                    publisher.publish(mono8_to_msg(self.image, stamp, f"{camera_id}_optical"))
            deadline = time.monotonic() + self.PERIOD_S
            while (left := deadline - time.monotonic()) > 0:
                rclpy.spin_once(self.probe, timeout_sec=left)


@pytest.mark.system
def test_the_bundle_node_starts_over_when_stamps_jump_back_and_logs_what_it_drops(ros_probe, tmp_path):
    """A bag replayed with --loop: the same stamps again, without a pause in the images (a pause longer than
    camera_timeout_s would rebuild the synchroniser and hide the problem). Before the fix, no bundle came after the
    first pass and the node said nothing."""
    camera_ids = load_sensor().camera_ids
    bundles = []
    ros_probe.create_subscription(ImageBundle, "/tactile/image_bundle", bundles.append, 50)
    cameras = FakeCameras(ros_probe, camera_ids)
    # camera_timeout_s 1 s, not the default 0.25 s: a pause of the probe (this process) or the node that long on a
    # loaded machine would take every camera for lost, and log a second "are back".
    process = start_node(NodeSpec("tactile_fusion", "bundle_node", "bundle",
                                  {"sensor_config": CONFIG, "camera_timeout_s": 1.0}), tmp_path)
    try:
        assert spin_until(ros_probe, lambda: all(p.get_subscription_count() for p in cameras.publishers.values())
                          and ros_probe.count_publishers("/tactile/image_bundle"), 30.0)
        cameras.play(100.0, 20)
        cameras.play(100.0, 20)  # the bag again
        cameras.play(100.5, 80, cameras=camera_ids[1:])  # cam0 falls silent for 2 s, twice camera_timeout_s
        cameras.play(102.5, 6)  # and is back
        spin_until(ros_probe, lambda: False, 1.5)  # time for the drop report (every second) and the last bundles
        running = process.poll() is None
    finally:
        codes = stop_nodes([process])
    log = (tmp_path / "bundle.log").read_text()
    assert running and codes == [0], log
    # What the node guarantees, not how many bundles a loaded machine manages in real time: bundles before and after
    # the jump back, one numbering throughout (the probe may match after the first ones), the restart logged for
    # whichever camera's stamps went back first, and the images left waiting reported as dropped by the reset.
    stamps = [time_to_seconds(b.header.stamp) for b in bundles]
    assert any(later < earlier for earlier, later in itertools.pairwise(stamps)), (stamps, log)  # resumed after it
    sequences = [b.sequence for b in bundles]
    assert sequences == list(range(sequences[0], sequences[0] + len(sequences))), sequences
    assert re.search(r"cam\d+'s stamps went back \d+\.\d+ s \(from \d+\.\d+ s to \d+\.\d+ s\)", log), log
    assert "synchronising from the new stamps" in log
    first_camera = camera_ids[0]
    assert f"no images from ['{first_camera}']" in log and f"cameras ['{first_camera}'] are back" in log, log
    assert log.count("are back") == 1, log  # not at start-up
    assert re.search(r"the synchroniser dropped \d+ image\(s\) \(.*reset \d+", log), log


@pytest.mark.system
def test_the_bundle_node_logs_its_last_drops_at_ctrl_c_without_a_rosout_error(ros_probe, tmp_path):
    """The drops since the last report are logged when the node stops, after the Ctrl-C has shut its context down:
    the line was printed, followed by "Failed to publish log message to rosout: publisher's context is invalid"."""
    log_path = tmp_path / "bundle.log"
    cameras = FakeCameras(ros_probe, load_sensor().camera_ids)
    process = start_node(NodeSpec("tactile_fusion", "bundle_node", "bundle", {"sensor_config": CONFIG}), tmp_path)
    try:
        assert spin_until(ros_probe, lambda: all(p.get_subscription_count() for p in cameras.publishers.values()),
                          30.0)
        stamp_s = 100.0
        cameras.play(stamp_s, 4)
        cameras.play(stamp_s + 3 * FakeCameras.PERIOD_S, 1)  # the last frame again: dropped, reported at once
        deadline = time.monotonic() + 10.0
        while "the synchroniser dropped" not in log_path.read_text() and time.monotonic() < deadline:
            stamp_s += FakeCameras.PERIOD_S  # the cameras go on, so that none is left out of the bundles
            cameras.play(stamp_s + 3 * FakeCameras.PERIOD_S, 1)
        cameras.play(stamp_s + 3 * FakeCameras.PERIOD_S, 1)  # and again: reported when the node stops
        cameras.play(stamp_s + 4 * FakeCameras.PERIOD_S, 4)
        running = process.poll() is None
    finally:
        codes = stop_nodes([process])
    log = log_path.read_text()
    assert running and codes == [0], log
    assert log.count("the synchroniser dropped") == 2, log  # at once, and at the stop, within DROP_LOG_PERIOD_S
    assert "Failed to publish log message to rosout" not in log, log
