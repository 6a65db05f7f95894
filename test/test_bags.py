"""System test of `tactile-bag`: record the simulated graph, check the bag, replay it, evaluate it offline.

Real processes over Fast DDS on loopback in a DDS domain of this test's own: the simulated cameras and the
bundle node, the `tactile-bag` console script, and this process as the subscriber of the replay.
"""

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch
from ament_index_python.packages import get_package_prefix
from rclpy.qos import qos_profile_sensor_data
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import Image

from tactile_bag.bagfile import BagReader
from tactile_bag.mcap_crcs import fill_mcap_crcs
from tactile_bringup.graph import NodeSpec
from tactile_bringup.processes import spin_until, start_node, stop_nodes
from tactile_description import default_sensor_path, load_sensor
from tactile_fusion.artifacts import save_model
from tactile_fusion.model import ModelConfig
from tactile_fusion.training import build_model

pytestmark = pytest.mark.system
RECORD_S = 4.0


def tactile_bag_executable() -> Path:
    return Path(get_package_prefix("tactile_bag")) / "lib" / "tactile_bag" / "tactile-bag"


def tactile_bag(*args: str, timeout_s: float = 30.0) -> subprocess.CompletedProcess:
    return subprocess.run([str(tactile_bag_executable()), *args], capture_output=True, text=True, timeout=timeout_s)


def test_record_replay_and_evaluate_the_simulated_graph(ros_probe, collect, lossless_image_qos, tmp_path):
    config = str(default_sensor_path())
    sensor = load_sensor(config)
    specs = [NodeSpec("tactile_camera_driver", "sim_camera_node", "sim_cameras", {"sensor_config": config}),
             NodeSpec("tactile_fusion", "bundle_node", "bundle", {"sensor_config": config})]
    processes = [start_node(spec, tmp_path / "logs") for spec in specs]
    try:
        # The graph is up once images flow.
        live = collect(Image, "/tactile/cam0/image", seconds=20.0, qos=qos_profile_sensor_data, until=bool)
        assert live, "the simulated cameras never published"
        recorded = tactile_bag("record", str(tmp_path / "bag"), "--duration", str(RECORD_S))
        unknown = tactile_bag("record", str(tmp_path / "other"), "--duration", "1", "--topics", "/tactile/nothing",
                              "--discovery-timeout", "0.3")
    finally:
        codes = stop_nodes(processes)
    logs = "\n".join(p.read_text() for p in (tmp_path / "logs").glob("*.log"))
    assert codes == [0, 0], logs
    assert recorded.returncode == 0, recorded.stderr + logs
    assert recorded.stdout.startswith("recorded ") and "(nothing received on /tactile/force_distribution)" in \
        recorded.stdout  # no fusion node in this graph
    assert unknown.returncode == 2 and not (tmp_path / "other").exists()
    assert unknown.stderr.strip() == ("tactile-bag record: error: unknown topic /tactile/nothing: not a topic of the "
                                      "tactile stack and no publisher seen within 0.3 s; check the name or start its "
                                      "publisher first")

    # The bag: every default topic, the cameras at about the sensor's rate, readable images in capture order.
    image_topics = [f"/tactile/{c}/image" for c in sensor.camera_ids]
    with BagReader(tmp_path / "bag") as bag:
        assert set(bag.topics) == {*image_topics, "/tactile/image_bundle", "/tactile/force_distribution",
                                   "/tactile/ground_truth/force_distribution"}
        # Recording starts with the first message, but DDS discovery of each publisher may take a second or more
        # on a loaded machine, and the simulator may then run slower than its 40 Hz.
        minimum = 0.25 * RECORD_S * sensor.frame_rate_hz
        assert all(bag.counts[t] >= minimum for t in [*image_topics, "/tactile/image_bundle",
                                                      "/tactile/ground_truth/force_distribution"]), str(bag.counts)
        assert bag.counts["/tactile/force_distribution"] == 0
        cam0 = [(t, deserialize_message(raw, Image)) for _, _, t, raw in bag.messages(["/tactile/cam0/image"])]
    stamps = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for _, m in cam0])
    receive_s = np.array([t for t, _ in cam0]) * 1e-9
    assert np.all(np.diff(stamps) > 0)
    # receive times are wall-clock times after the capture (stamps run up to 2 ms ahead: sim_camera_node's jitter);
    # the upper bound tells the wall clock from another (a monotonic one is decades off), not a latency target
    assert np.all(receive_s - stamps > -0.0025) and np.median(receive_s - stamps) < 10.0
    assert all((m.height, m.width, m.encoding, len(m.data)) == (128, 128, "mono8", 128 * 128) for _, m in cam0)
    # `record` filled in every CRC of the MCAP file (chunks, data section, summary), each right: none left to fill.
    crcs = fill_mcap_crcs(next((tmp_path / "bag").glob("*.mcap")))
    assert crcs.chunks >= 1 and crcs.filled == 0 and crcs.data_section_crc and crcs.summary_crc

    # Replay: a subscriber with the camera drivers' QoS receives the recorded images, bytes unchanged.
    replayed = []
    ros_probe.create_subscription(Image, "/tactile/cam0/image", replayed.append, lossless_image_qos)
    player = subprocess.Popen([str(Path(get_package_prefix("tactile_bag")) / "lib" / "tactile_bag" / "tactile-bag"),
                               "play", str(tmp_path / "bag"), "--rate", "2", "--topics", "/tactile/cam0/image",
                               "--wait-subscribers", "15"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    spin_until(ros_probe, lambda: player.poll() is not None, timeout_s=30.0)
    spin_until(ros_probe, lambda: False, timeout_s=0.3)  # the last messages in flight
    out, err = player.communicate(timeout=5)
    assert player.returncode == 0, err
    assert out.startswith(f"played {len(cam0)} messages")
    assert len(replayed) >= 0.9 * len(cam0)
    recorded_by_stamp = {(m.header.stamp.sec, m.header.stamp.nanosec): bytes(m.data) for _, m in cam0}
    assert all(recorded_by_stamp[(m.header.stamp.sec, m.header.stamp.nanosec)] == bytes(m.data) for m in replayed)

    # Offline evaluation of the live recording: every estimate finds the ground truth of its capture.
    model = build_model(ModelConfig(conv_channels=(4, 4, 4), hidden_features=16, camera_features=8, fusion_rank=4),
                        sensor.camera_ids, sensor.grid.rows, sensor.grid.cols, torch.tensor([1e-3, 1e-3, 1e-2]), 0)
    save_model(model, tmp_path / "model", sensor)
    evaluated = tactile_bag("eval", str(tmp_path / "bag"), "--model", str(tmp_path / "model"), "--backend", "torch",
                            "--json")
    assert evaluated.returncode == 0, evaluated.stderr
    summary = json.loads(evaluated.stdout)
    assert summary["source"] == "images" and summary["estimates"] >= minimum - 10
    assert summary["matched_with_ground_truth"] >= summary["estimates"] - 2  # truth may lag at the bag's ends


def test_record_and_evaluate_the_graph_of_one_sensor_of_two_in_its_namespace(collect, tmp_path):
    """A robot with two sensors runs a graph per sensor, each in a namespace (docs/nodes.md): `--namespace left`
    records that graph's topics, and evaluates them against its ground truth."""
    config = str(default_sensor_path())
    sensor = load_sensor(config)
    specs = [NodeSpec("tactile_camera_driver", "sim_camera_node", "sim_cameras", {"sensor_config": config}, "/left"),
             NodeSpec("tactile_fusion", "bundle_node", "bundle", {"sensor_config": config}, "/left")]
    processes = [start_node(spec, tmp_path / "logs") for spec in specs]
    try:
        assert collect(Image, "/left/tactile/cam0/image", seconds=20.0, qos=qos_profile_sensor_data, until=bool)
        recorded = tactile_bag("record", str(tmp_path / "bag"), "--duration", "2", "--namespace", "left")
    finally:
        codes = stop_nodes(processes)
    assert codes == [0, 0] and recorded.returncode == 0, recorded.stderr
    with BagReader(tmp_path / "bag") as bag:
        assert set(bag.topics) == {*(f"/left/tactile/{c}/image" for c in sensor.camera_ids),
                                   *(f"/left/tactile/{topic}" for topic in ("image_bundle", "force_distribution",
                                                                             "ground_truth/force_distribution"))}
    evaluated = tactile_bag("eval", str(tmp_path / "bag"), "--namespace", "left", "--json", timeout_s=60.0)
    assert evaluated.returncode == 0, evaluated.stderr
    summary = json.loads(evaluated.stdout)
    assert summary["source"] == "images" and summary["matched_with_ground_truth"] >= 10, summary


#: A publisher outside the stack of a String every 20 ms until it is stopped: on topic sys.argv[1], its QoS
#: sys.argv[2] ("best_effort": sensor-data QoS; "reliable"), its data the QoS and the message's number ("reliable 7").
FOREIGN_PUBLISHER = """
import sys
import rclpy
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from std_msgs.msg import String
rclpy.init()
node = rclpy.create_node("foreign_" + sys.argv[2])
qos = qos_profile_sensor_data if sys.argv[2] == "best_effort" else QoSProfile(depth=10)
publisher = node.create_publisher(String, sys.argv[1], qos)
sent = iter(range(10**9))
node.create_timer(0.02, lambda: publisher.publish(String(data=f"{sys.argv[2]} {next(sent)}")))
try:
    rclpy.spin(node)
except KeyboardInterrupt:
    pass
"""


def foreign_publisher(topic: str, reliability: str) -> subprocess.Popen:
    import sys

    return subprocess.Popen([sys.executable, "-c", FOREIGN_PUBLISHER, topic, reliability])


def stop_publishers(*publishers) -> None:
    """Ctrl-C to each, then a wait for each; one that does not end in 20 s is killed."""
    import signal

    for publisher in publishers:
        publisher.send_signal(signal.SIGINT)
    for publisher in publishers:
        try:
            publisher.wait(timeout=20)
        except subprocess.TimeoutExpired:
            publisher.kill()
            publisher.wait()


def test_a_best_effort_topic_outside_the_stack_is_recorded(ros_probe, tmp_path):
    """Its reliable subscription matched no best-effort publisher: 0 messages, and the tool asked whether the graph
    was running (code review)."""
    publisher = foreign_publisher("/foreign_best_effort", "best_effort")
    try:
        assert spin_until(ros_probe, lambda: ros_probe.count_publishers("/foreign_best_effort"), 20.0)
        # its own discovery of the publisher takes seconds on a loaded machine (2 s, the default, was too short once)
        recorded = tactile_bag("record", str(tmp_path / "bag"), "--duration", "1", "--topics", "/foreign_best_effort",
                               "--discovery-timeout", "20", timeout_s=60.0)
    finally:
        stop_publishers(publisher)
    assert recorded.returncode == 0, recorded.stderr
    with BagReader(tmp_path / "bag") as bag:
        assert bag.topics == {"/foreign_best_effort": "std_msgs/msg/String"}
        assert sum(1 for _ in bag.messages(["/foreign_best_effort"])) >= 10


def test_a_best_effort_publisher_that_appears_while_recording_is_recorded_too(ros_probe, tmp_path):
    """The topic is subscribed reliably for the reliable publisher seen at the start; a best-effort one that came
    later matched nothing, and its messages were lost without a word (review)."""
    from std_msgs.msg import String

    publishers = [foreign_publisher("/foreign_mixed", "reliable")]
    recorder = None
    try:
        assert spin_until(ros_probe, lambda: ros_probe.count_publishers("/foreign_mixed"), 20.0)
        recorder = subprocess.Popen([str(tactile_bag_executable()), "record", str(tmp_path / "bag"), "--duration",
                                     "10", "--topics", "/foreign_mixed", "--discovery-timeout", "20"],
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert spin_until(ros_probe, lambda: ros_probe.count_subscribers("/foreign_mixed"), 20.0)  # it records
        publishers.append(foreign_publisher("/foreign_mixed", "best_effort"))
        _, err = recorder.communicate(timeout=60)
    finally:
        if recorder is not None and recorder.poll() is None:
            recorder.kill()
        stop_publishers(*publishers)
    assert recorder.returncode == 0, err
    assert ("tactile-bag record: /foreign_mixed: a best-effort publisher matched no reliable subscription; the topic "
            "was subscribed anew, best effort") in err
    with BagReader(tmp_path / "bag") as bag:
        data = [deserialize_message(raw, String).data.split() for *_, raw in bag.messages(["/foreign_mixed"])]
    reliable = [int(n) for qos, n in data if qos == "reliable"]
    first_best_effort = next(i for i, (qos, _) in enumerate(data) if qos == "best_effort")
    assert any(qos == "reliable" for qos, _ in data[first_best_effort:]), "the reliable publisher was left out"
    # Each reliable message once, in order, and none lost but those sent while the new subscription was matched
    assert reliable == sorted(set(reliable)) and len(reliable) >= reliable[-1] - reliable[0] + 1 - 3, reliable


def test_record_names_the_image_topics_of_other_cameras_when_its_own_are_silent(ros_probe, tmp_path):
    """A graph of other camera ids recorded with the default description: 0 images and no hint (walkthrough)."""
    renamed = tmp_path / "renamed.yaml"
    renamed.write_text(default_sensor_path().read_text().replace("{id: cam", "{id: c"))
    camera = start_node(NodeSpec("tactile_camera_driver", "sim_camera_node", "renamed_cameras",
                                 {"sensor_config": str(renamed)}), tmp_path / "logs")
    try:
        assert spin_until(ros_probe, lambda: ros_probe.count_publishers("/tactile/c3/image"), 30.0)
        # --wait: the recorder's own discovery of all four publishers takes seconds on a loaded machine
        recorded = tactile_bag("record", str(tmp_path / "bag"), "--duration", "1", "--wait", "10", "--topics",
                               "/tactile/cam0/image", "/tactile/cam1/image", timeout_s=60.0)
    finally:
        stop_nodes([camera])
    assert recorded.returncode == 1, recorded.stderr
    assert (f"tactile-bag record: images are published on /tactile/c0/image, /tactile/c1/image, /tactile/c2/image, "
            f"/tactile/c3/image, not recorded: the cameras of another sensor description than "
            f"{default_sensor_path()} (--sensor FILE), or of a graph in another namespace (--namespace)?") in \
        recorded.stderr


def test_a_topic_outside_the_stack_with_subscribers_alone_is_not_recorded_without_a_publisher(ros_probe, tmp_path):
    """Its type came from the subscriber, and the QoS then chosen matched no best-effort publisher that came later
    (review): a topic outside the stack is taken once a publisher tells its type and QoS."""
    from std_msgs.msg import String

    ros_probe.create_subscription(String, "/foreign_listened", lambda _: None, 10)
    recorded = tactile_bag("record", str(tmp_path / "bag"), "--duration", "1", "--topics", "/foreign_listened",
                           "--discovery-timeout", "3")
    assert recorded.returncode == 2 and not (tmp_path / "bag").exists()
    assert recorded.stderr.strip() == ("tactile-bag record: error: unknown topic /foreign_listened: not a topic of "
                                       "the tactile stack and no publisher seen within 3 s; check the name or start "
                                       "its publisher first")
