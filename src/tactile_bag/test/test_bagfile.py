"""Writing bags with rosbags and reading them back; what a damaged or missing bag gives."""

import json
import re
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest
from ament_index_python.packages import get_package_share_directory
from rclpy.serialization import deserialize_message
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import get_types_from_msg, get_typestore
from sensor_msgs.msg import Image

from tactile_bag.bagfile import BAG_VERSION, BagError, BagReader, BagWriter
from tactile_bag.message_types import STORE, MessageTypeError, bag_typestore, message_class
from tactile_bag.topics import FORCES_TYPE, IMAGE_TYPE
from tactile_conversions.topics import ESTIMATE_TOPIC, GROUND_TRUTH_TOPIC, camera_topic
from tactile_msgs.msg import ForceDistribution


def test_simulated_frames_read_back_unchanged(sim_bag, sensor, sim_frames):
    with BagReader(sim_bag) as bag:
        expected = {camera_topic(c): IMAGE_TYPE for c in sensor.camera_ids} | {GROUND_TRUTH_TOPIC: FORCES_TYPE}
        assert bag.topics == expected
        assert bag.counts == dict.fromkeys(expected, len(sim_frames))
        messages = list(bag.messages())
    times = [t for _, _, t, _ in messages]
    assert times == sorted(times)
    images = [deserialize_message(raw, Image) for topic, _, _, raw in messages if topic == camera_topic("cam2")]
    for frame, msg in zip(sim_frames, images, strict=True):
        assert (msg.height, msg.width, msg.encoding) == (128, 128, "mono8")
        np.testing.assert_array_equal(np.frombuffer(bytes(msg.data), np.uint8).reshape(128, 128), frame.images[2])
    truths = [deserialize_message(raw, ForceDistribution) for topic, _, _, raw in messages
              if topic == GROUND_TRUTH_TOPIC]
    for frame, msg in zip(sim_frames, truths, strict=True):
        np.testing.assert_array_equal(np.asarray(msg.forces_n).reshape(frame.bin_forces_n.shape), frame.bin_forces_n)


def test_bag_metadata_carries_the_installed_type_hashes(sim_bag):
    """`ros2 bag` checks each topic's type hash (RIHS01) against the installed interface: they must agree."""
    metadata = (Path(sim_bag) / "metadata.yaml").read_text()
    for msgtype in (IMAGE_TYPE, FORCES_TYPE):
        package, _, name = msgtype.split("/")
        rosidl = json.loads((Path(get_package_share_directory(package)) / "msg" / f"{name}.json").read_text())
        hash_string = next(h["hash_string"] for h in rosidl["type_hashes"] if h["type_name"] == msgtype)
        assert hash_string in metadata
    assert "storage_identifier: mcap" in metadata and "version: 9" in metadata


def test_rosbags_reads_the_cdr_that_rclpy_wrote(sim_bag, sim_frames):
    """The bag's bytes are plain CDR: the pure-Python reader decodes rclpy's serialization of our own type."""
    typestore = bag_typestore([FORCES_TYPE])
    with BagReader(sim_bag) as bag:
        raw = [raw for _, _, _, raw in bag.messages([GROUND_TRUTH_TOPIC])][-1]
    msg = typestore.deserialize_cdr(raw, FORCES_TYPE)
    np.testing.assert_array_equal(msg.forces_n.reshape(msg.rows, msg.cols, 3), sim_frames[-1].bin_forces_n)
    assert msg.total_force_n.z == pytest.approx(float(sim_frames[-1].bin_forces_n[..., 2].sum()), rel=1e-5)


def test_a_declared_topic_without_messages_is_listed(tmp_path):
    with BagWriter(tmp_path / "bag") as bag:
        bag.add_topic("/tactile/cam0/image", IMAGE_TYPE)
    with BagReader(tmp_path / "bag") as bag:
        assert bag.topics == {"/tactile/cam0/image": IMAGE_TYPE}
        assert bag.counts == {"/tactile/cam0/image": 0}
        assert list(bag.messages()) == []


def test_a_topic_keeps_one_type(tmp_path):
    with BagWriter(tmp_path / "bag") as bag:
        bag.add_topic("/x", IMAGE_TYPE)
        with pytest.raises(BagError, match="already recorded as sensor_msgs/msg/Image"):
            bag.add_topic("/x", FORCES_TYPE)


def test_writer_never_overwrites(sim_bag, tmp_path):
    with pytest.raises(BagError, match="already exists"):
        BagWriter(sim_bag)
    with pytest.raises(BagError, match="does not exist; create it first"):
        BagWriter(tmp_path / "no" / "bag")


def test_unknown_message_types_are_refused(tmp_path):
    with BagWriter(tmp_path / "bag") as bag, pytest.raises(BagError, match="no_such_msgs is not installed"):
        bag.add_topic("/x", "no_such_msgs/msg/Thing")
    with pytest.raises(MessageTypeError, match="expected 'package/msg/Name'"):
        message_class("sensor_msgs/Image")
    with pytest.raises(MessageTypeError, match="sensor_msgs has no message Imag"):
        message_class("sensor_msgs/msg/Imag")
    assert message_class(FORCES_TYPE) is ForceDistribution


def test_missing_bag(tmp_path):
    with pytest.raises(BagError, match="does not exist"):
        BagReader(tmp_path / "nothing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagError, match="cannot be opened"):
        BagReader(tmp_path / "empty")


def copy_bag(source: Path, target: Path) -> Path:
    target.mkdir()
    for path in source.iterdir():
        (target / path.name).write_bytes(path.read_bytes())
    return target


def test_truncated_bag(sim_bag, tmp_path):
    """What a recorder killed with SIGKILL leaves: an MCAP file without its end."""
    bag = copy_bag(sim_bag, tmp_path / "truncated")
    mcap = next(bag.glob("*.mcap"))
    mcap.write_bytes(mcap.read_bytes()[: mcap.stat().st_size // 2])
    with pytest.raises(BagError, match=r"cannot be opened \(.*\); expected a rosbag2 directory"):
        BagReader(bag)


def with_chunk_crcs(mcap: bytes) -> bytes:
    """The MCAP file with the CRC-32 of every (uncompressed) chunk filled in, as `ros2 bag record` writes them;
    rosbags 0.11 writes 0, "no CRC". Chunk record: opcode, length, start and end time, uncompressed size, CRC,
    compression, records length, records (MCAP specification)."""
    data, offset = bytearray(mcap), 8  # after the magic
    while offset < len(data):
        opcode, length = data[offset], struct.unpack_from("<Q", data, offset + 1)[0]
        if opcode == 0x06:
            compression_length = struct.unpack_from("<I", data, offset + 9 + 28)[0]
            assert compression_length == 0, "a compressed chunk"
            records_start = offset + 9 + 28 + 4 + 8
            size = struct.unpack_from("<Q", data, offset + 9 + 16)[0]
            struct.pack_into("<I", data, offset + 9 + 24, zlib.crc32(data[records_start:records_start + size]))
        if opcode == 0x0F:  # data end: the summary follows
            break
        offset += 9 + length
    return bytes(data)


def test_changed_bytes_are_found_in_a_bag_with_chunk_crcs_only(sim_bag, sim_frames, tmp_path):
    """64 bytes of cam2's last image flipped. The bags written here have no chunk CRC (rosbags' writer has none to
    offer): the images read back changed, unnoticed (docs/bags.md says so). `ros2 bag record` writes CRCs, and then
    the damage is refused."""
    pixels = sim_frames[-1].images[2].tobytes()

    def damaged(name: str, crcs: bool) -> Path:
        bag = copy_bag(sim_bag, tmp_path / name)
        mcap = next(bag.glob("*.mcap"))
        data = bytearray(with_chunk_crcs(mcap.read_bytes()) if crcs else mcap.read_bytes())
        at = data.find(pixels) + len(pixels) // 2
        data[at:at + 64] = bytes(255 - b for b in data[at:at + 64])
        mcap.write_bytes(bytes(data))
        return bag

    with BagReader(damaged("without_crcs", crcs=False)) as bag:
        last = [raw for topic, _, _, raw in bag.messages() if topic == camera_topic("cam2")][-1]
    changed = np.frombuffer(bytes(deserialize_message(last, Image).data), np.uint8)
    assert (changed != sim_frames[-1].images[2].ravel()).sum() == 64
    with BagReader(copy_bag(sim_bag, tmp_path / "intact")) as bag:
        mcap = next(bag.path.glob("*.mcap"))
        mcap.write_bytes(with_chunk_crcs(mcap.read_bytes()))
    with BagReader(tmp_path / "intact") as bag:
        assert len(list(bag.messages())) == len(sim_frames) * len(bag.topics)  # the CRCs are right
    with BagReader(damaged("with_crcs", crcs=True)) as bag, \
            pytest.raises(BagError, match=r"is damaged: reading its messages failed \(Chunk checksum mismatch"):
        list(bag.messages())


def test_damaged_metadata(sim_bag, tmp_path):
    bag = copy_bag(sim_bag, tmp_path / "damaged")
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: [1")
    with pytest.raises(BagError, match="cannot be opened"):
        BagReader(bag)


def test_a_topic_recorded_with_another_definition_of_its_type_is_refused(tmp_path):
    """A bag recorded with an older tactile_msgs (here: ForceDistribution without missing_camera_ids) would be
    decoded as the installed type: refused, naming the topic and both type hashes. Each topic is checked on its own,
    so the other topic of the same type, recorded with the installed definition, is still read."""
    older = get_typestore(STORE)
    definition = (Path(get_package_share_directory("tactile_msgs")) / "msg" / "ForceDistribution.msg").read_text()
    assert "string[] missing_camera_ids" in definition
    older.register(get_types_from_msg(definition.replace("string[] missing_camera_ids", ""), FORCES_TYPE))
    writer = Writer(tmp_path / "mixed", version=BAG_VERSION, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    for topic, typestore in ((ESTIMATE_TOPIC, bag_typestore([FORCES_TYPE])), (GROUND_TRUTH_TOPIC, older)):
        writer.write(writer.add_connection(topic, FORCES_TYPE, typestore=typestore), 1, bytes(64))  # never decoded
    writer.close()
    with BagReader(tmp_path / "mixed") as bag:
        assert bag.topics == {ESTIMATE_TOPIC: FORCES_TYPE, GROUND_TRUTH_TOPIC: FORCES_TYPE}
        assert len(list(bag.messages([ESTIMATE_TOPIC]))) == 1
        installed = bag_typestore([FORCES_TYPE]).hash_rihs01(FORCES_TYPE)
        for topics in (None, [GROUND_TRUTH_TOPIC]):
            with pytest.raises(BagError, match=rf"topic {GROUND_TRUTH_TOPIC} was recorded with another definition "
                                               rf"of {FORCES_TYPE} \(type hash RIHS01_\w+\) than the installed "
                                               rf"one \({installed}\);.* or leave the topic out"):
                list(bag.messages(topics))


def test_a_bag_without_type_hashes_is_read_unchecked(sim_bag, sim_frames, tmp_path):
    """rosbag2 before version 7 recorded no type hash: nothing to check, the messages are read as before."""
    bag = copy_bag(sim_bag, tmp_path / "unhashed")
    metadata = bag / "metadata.yaml"
    unhashed = re.sub(r"type_description_hash:\s*RIHS01_\w+", "type_description_hash: ''", metadata.read_text())
    assert "RIHS01" not in unhashed
    metadata.write_text(unhashed)
    with BagReader(bag) as reader:
        assert len(list(reader.messages())) == len(sim_frames) * (len(reader.topics))


def test_unknown_topic_names_what_the_bag_has(sim_bag):
    with BagReader(sim_bag) as bag, pytest.raises(BagError, match=r"no topic /tactile/wrench; its topics are \["):
        list(bag.messages(["/tactile/wrench"]))
