"""Bags written from simulator frames, as the live graph would have recorded them, and a small real model.

`write_sim_bag` stamps every message as sim_camera_node and bundle_node do: each camera's image at the
capture time plus a random offset of up to 2 ms, the ground truth at the capture time, the bundle at the median
of its images' stamps; receive times lag the stamps by a millisecond or two. Bundles are numbered by frame
index, so that frames left out of `frames` stand for bundles lost before the recorder.
"""

import shutil
from pathlib import Path

import lz4.frame
import numpy as np
import pytest
import torch
from backports import zstd
from rclpy.serialization import serialize_message
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.storage_mcap import McapReader
from rosbags.typesys import get_types_from_msg

from tactile_bag.bagfile import BAG_VERSION, BagReader, BagWriter
from tactile_bag.mcap_crcs import fill_mcap_crcs
from tactile_bag.message_types import bag_typestore
from tactile_bag.topics import BUNDLE_TYPE, FORCES_TYPE, IMAGE_TYPE
from tactile_conversions.forces import force_distribution_msg
from tactile_conversions.images import mono8_to_msg
from tactile_conversions.ros_time import seconds_to_time
from tactile_conversions.topics import BUNDLE_TOPIC, GROUND_TRUTH_TOPIC, camera_topic, in_namespace
from tactile_description import FORCE_COMPONENTS, load_sensor
from tactile_fusion.artifacts import save_model
from tactile_fusion.model import ModelConfig
from tactile_fusion.training import build_model
from tactile_msgs.msg import ImageBundle
from tactile_sim import Simulator, load_scene

START_S = 1_700_000_000.0  # capture time of the first frame, like a wall clock
JITTER_S = 0.002


@pytest.fixture(scope="session")
def sensor():
    return load_sensor()


@pytest.fixture(scope="session")
def sim_frames(sensor):
    """The first 40 frames of the demo scene: 20 at rest, then the sphere presses in."""
    return list(Simulator(sensor).stream(load_scene("demo", sensor), frames=40))


def write_sim_bag(path: Path, sensor, frames, images: bool = True, bundles: bool = False, truth: bool = True,
                  truth_offset_s: float = 0.0, seed: int = 0, truth_definition: str | None = None,
                  namespaces: tuple[str, ...] = ("/",)) -> list[float]:
    """Write `frames` into a new bag; returns each frame's capture time (s).

    namespaces: the graphs whose topics carry them (the same messages in each), as a bag recorded from graphs in
    those namespaces holds them.

    Images are stamped in [capture, capture + JITTER_S], the ground truth at capture + truth_offset_s.
    truth_definition: the ForceDistribution definition the ground-truth topic is recorded with (its type hash),
    default the installed one; another one makes a bag as an older tactile_msgs recorded it (only the recorded
    definition differs: the messages are the installed type's, for a reader that refuses them unread).
    """
    rng = np.random.default_rng(seed)
    captures = []
    with BagWriter(path) as bag:

        def write(topic: str, msgtype: str, time_ns: int, raw: bytes) -> None:
            for namespace in namespaces:
                bag.write(in_namespace(topic, namespace), msgtype, time_ns, raw)

        if truth_definition is not None:
            bag.typestore.register(get_types_from_msg(truth_definition, FORCES_TYPE))
        for frame in frames:
            capture_s = START_S + frame.time_s
            captures.append(capture_s)
            receive_ns = round(capture_s * 1e9) + 1_000_000
            msgs = []
            for i, camera_id in enumerate(sensor.camera_ids):
                if frame.camera_ok[i]:
                    stamp = seconds_to_time(capture_s + rng.uniform(0.0, JITTER_S))
                    msgs.append(mono8_to_msg(frame.images[i], stamp, f"{camera_id}_optical"))
                    if images:
                        write(camera_topic(camera_id), IMAGE_TYPE, receive_ns + i, serialize_message(msgs[-1]))
            if truth:
                truth_stamp = seconds_to_time(capture_s + truth_offset_s)
                msg = force_distribution_msg(frame.bin_forces_n, sensor.grid, truth_stamp, sensor.frame_id,
                                             sensor.camera_ids, [], FORCE_COMPONENTS)
                write(GROUND_TRUTH_TOPIC, FORCES_TYPE, receive_ns + 100, serialize_message(msg))
            if bundles and msgs:
                stamps = [m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in msgs]
                bundle = ImageBundle(sequence=frame.index,
                                     camera_ids=[m.header.frame_id.removesuffix("_optical") for m in msgs],
                                     images=msgs, max_stamp_spread_s=max(stamps) - min(stamps))
                bundle.header.stamp = seconds_to_time(float(np.median(stamps)))
                bundle.header.frame_id = sensor.frame_id
                write(BUNDLE_TOPIC, BUNDLE_TYPE, receive_ns + 1_000_000, serialize_message(bundle))
    return captures


@pytest.fixture(scope="session")
def write_bag():
    """write_sim_bag itself, for tests that need a bag of their own (conftest is not importable here)."""
    write_sim_bag.jitter_s = JITTER_S
    return write_sim_bag


@pytest.fixture(scope="session")
def sim_bag(tmp_path_factory, sensor, sim_frames):
    """Camera images and ground truth of the 40 demo frames."""
    path = tmp_path_factory.mktemp("bags") / "demo"
    write_sim_bag(path, sensor, sim_frames)
    return path


@pytest.fixture
def flipped_pixels_bag(sim_bag, sim_frames, tmp_path):
    """A copy of sim_bag whose .mcap has 64 bytes of cam2's last image flipped: damage that breaks neither the file's
    structure nor the message's encoding, found only by the chunk's CRC."""
    bag = Path(shutil.copytree(sim_bag, tmp_path / "flipped_pixels"))
    mcap = next(bag.glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    pixels = sim_frames[-1].images[2].tobytes()
    assert data.count(pixels) == 1
    at = data.find(pixels) + len(pixels) // 2
    data[at:at + 64] = bytes(255 - b for b in data[at:at + 64])
    mcap.write_bytes(bytes(data))
    return bag


def zstd_file_metadata(source: Path, target: Path, compressed_name: str | None = None) -> None:
    """Write into `target` the metadata.yaml of the bag `source` as rosbag2's FILE compression (zstd) writes it, its
    .mcap named as `compressed_name` (default: as it is)."""
    mcap_name = next(source.glob("*.mcap")).name
    metadata = (source / "metadata.yaml").read_text()
    for key, value in (("compression_format", "zstd"), ("compression_mode", "FILE")):
        assert f"{key}: ''" in metadata
        metadata = metadata.replace(f"{key}: ''", f"{key}: {value}")
    (target / "metadata.yaml").write_text(metadata.replace(mcap_name, compressed_name or mcap_name))


@pytest.fixture
def zstd_file_bag(sim_bag, tmp_path):
    """sim_bag as `ros2 bag record --compression-mode file --compression-format zstd` leaves it: the .mcap file
    compressed whole into .mcap.zstd (a zstd frame), which metadata.yaml names, with compression FILE zstd."""
    bag = tmp_path / "zstd_file"
    bag.mkdir()
    mcap = next(sim_bag.glob("*.mcap"))
    (bag / f"{mcap.name}.zstd").write_bytes(zstd.compress(mcap.read_bytes()))
    zstd_file_metadata(sim_bag, bag, f"{mcap.name}.zstd")
    return bag


@pytest.fixture(params=["truncated", "plain_mcap_said_zstd"])
def damaged_zstd_file_bag(request, zstd_file_bag, sim_bag, tmp_path):
    """(bag, what rosbags says): zstd_file_bag with its .mcap.zstd cut to half (a copy broken off), or a copy of
    sim_bag whose metadata.yaml claims FILE zstd compression over its plain .mcap."""
    if request.param == "truncated":
        compressed = next(zstd_file_bag.glob("*.mcap.zstd"))
        compressed.write_bytes(compressed.read_bytes()[: compressed.stat().st_size // 2])
        return zstd_file_bag, "Compressed file ended before the end-of-stream marker was reached"
    bag = tmp_path / "plain_said_zstd"
    bag.mkdir()
    shutil.copy(next(sim_bag.glob("*.mcap")), bag)
    zstd_file_metadata(sim_bag, bag)
    return bag, "Unable to decompress Zstandard data: Unknown frame descriptor"


@pytest.fixture
def lz4_chunk_bag(sim_bag, tmp_path):
    """sim_bag's messages in lz4-compressed MCAP chunks with their CRCs, as `ros2 bag record` writes them with the
    storage configuration `compression: Lz4`. No installed package writes lz4 chunks for us (rosbags' Writer offers
    zstd alone, the `mcap` library is not installed), but rosbags' MCAP writer compresses its chunks with the codec
    named in two attributes, here set to the lz4 package's frame format, which the MCAP specification prescribes."""
    bag = tmp_path / "lz4_chunks"
    writer = Writer(bag, version=BAG_VERSION, storage_plugin=StoragePlugin.MCAP)
    writer.open()
    writer.storage.compression, writer.storage.compressor = "lz4", lz4.frame.compress
    with BagReader(sim_bag) as source:
        typestore = bag_typestore(set(source.topics.values()))
        connections = {t: writer.add_connection(t, m, typestore=typestore) for t, m in source.topics.items()}
        for topic, _, time_ns, raw in source.messages():
            writer.write(connections[topic], time_ns, raw)
    writer.close()
    fill_mcap_crcs(next(bag.glob("*.mcap")))
    return bag


@pytest.fixture
def damaged_lz4_chunk_bag(lz4_chunk_bag):
    """lz4_chunk_bag with the magic number of its second chunk's lz4 frame zeroed."""
    damage_second_chunk(next(lz4_chunk_bag.glob("*.mcap")), "lz4", b"\x04\x22\x4d\x18")
    return lz4_chunk_bag


@pytest.fixture(scope="session")
def damage_chunk():
    """damage_second_chunk itself (conftest is not importable here)."""
    return damage_second_chunk


def damage_second_chunk(mcap: Path, compression: str, magic: bytes) -> None:
    """Zero the magic number that opens the compressed data of the second chunk of the MCAP file `mcap`, after
    checking that the chunk is compressed with `compression` and that its data opens with `magic`."""
    reader = McapReader(mcap)
    reader.open()
    chunk = reader.chunks[1]
    reader.close()
    assert chunk.compression == compression
    data = bytearray(mcap.read_bytes())
    # The chunk record: opcode and length (9 bytes), its header (40), the compression's name, then the data.
    frame_at = chunk.chunk_start_offset + 9 + 40 + len(compression)
    assert data[frame_at:frame_at + len(magic)] == magic
    data[frame_at:frame_at + len(magic)] = bytes(len(magic))
    mcap.write_bytes(bytes(data))


@pytest.fixture(scope="session")
def model_dir(tmp_path_factory, sensor):
    """An untrained model of the reference sensor's shape (small layers): a real predictor, quick to build."""
    config = ModelConfig(image_size=128, conv_channels=(4, 4, 4), hidden_features=16, camera_features=8,
                         fusion_rank=4)
    model = build_model(config, sensor.camera_ids, sensor.grid.rows, sensor.grid.cols,
                        torch.tensor([0.001, 0.001, 0.01]), seed=0)
    return save_model(model, tmp_path_factory.mktemp("model"), sensor)
