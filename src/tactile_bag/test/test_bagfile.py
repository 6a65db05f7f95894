"""Writing bags with rosbags and reading them back; what a damaged or missing bag gives."""

import json
import os
import re
import struct
import zlib
from pathlib import Path

import apsw
import lz4.frame
import numpy as np
import pytest
import yaml
from ament_index_python.packages import get_package_share_directory
from backports import zstd
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
from rosbags.rosbag2.storage_mcap import McapReader
from rosbags.typesys import get_types_from_msg, get_typestore
from sensor_msgs.msg import Image

from tactile_bag import mcap_crcs
from tactile_bag.bagfile import BAG_VERSION, BagError, BagReader, BagWriter
from tactile_bag.mcap_crcs import McapCrcs, McapError, fill_mcap_crcs
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
    with pytest.raises(BagError, match="empty has no metadata.yaml"):
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


def test_a_file_compressed_bag_reads_back(zstd_file_bag, sim_bag):
    """rosbag2's FILE compression (the whole .mcap as one zstd frame), which rosbags decompresses when it opens it."""
    with BagReader(zstd_file_bag) as compressed, BagReader(sim_bag) as plain:
        assert list(compressed.messages()) == list(plain.messages())


def test_a_damaged_file_compressed_bag_is_refused(damaged_zstd_file_bag):
    """Cut short (EOFError) or not zstd at all (ZstdError): the one-line BagError that names the bag, not rosbags'
    exception (before: EOFError's or ZstdError's traceback)."""
    bag, reason = damaged_zstd_file_bag
    with pytest.raises(BagError, match=rf"^bag {bag} cannot be opened \({reason}\); expected a rosbag2 directory"):
        BagReader(bag)


def test_a_zstd_chunk_that_does_not_decompress_is_refused(tmp_path, damage_chunk):
    """A zstd-compressed MCAP chunk (ros2 bag's default storage preset writes them) whose zstd frame is damaged: the
    error comes from decompressing it, when its messages are read."""
    mcap = rosbags_bag(tmp_path / "bag", messages=100, compression=True)
    damage_chunk(mcap, "zstd", b"\x28\xb5\x2f\xfd")  # the zstd frame's magic number
    with BagReader(tmp_path / "bag") as bag, \
            pytest.raises(BagError, match=rf"^bag {tmp_path / 'bag'} is damaged: reading its messages failed \(Unable "
                                          r"to decompress Zstandard data: Unknown frame descriptor\)$"):
        list(bag.messages())


def test_an_lz4_chunk_bag_reads_back(lz4_chunk_bag, sim_bag):
    with BagReader(lz4_chunk_bag) as compressed, BagReader(sim_bag) as plain:
        assert list(compressed.messages()) == list(plain.messages())


def test_an_lz4_chunk_that_does_not_decompress_is_refused(damaged_lz4_chunk_bag):
    """Before: the lz4 package's RuntimeError, a traceback."""
    with BagReader(damaged_lz4_chunk_bag) as bag, \
            pytest.raises(BagError, match=rf"^bag {damaged_lz4_chunk_bag} is damaged: reading its messages failed "
                                          r"\(LZ4F_getFrameInfo failed with code: ERROR_frameType_unknown\)$"):
        list(bag.messages())


def stored_crcs(mcap: Path) -> tuple[list[tuple[int, int]], tuple[int, int], tuple[int, int]]:
    """([(stored CRC, CRC-32 of the records) of every chunk], (stored, computed) data-section CRC, (stored, computed)
    summary CRC) of an MCAP file with uncompressed chunks. The chunks are found through rosbags' reading of the
    file's chunk index (not by walking the records as fill_mcap_crcs does); the Data End record lies just before the
    summary, whose start the Footer gives (MCAP specification)."""
    data = mcap.read_bytes()
    reader = McapReader(mcap)
    reader.open()
    chunks = list(reader.chunks)
    reader.close()
    crcs = []
    for chunk in chunks:
        assert chunk.compression == ""
        records_at = chunk.chunk_start_offset + 9 + 40
        stored = struct.unpack_from("<I", data, chunk.chunk_start_offset + 9 + 24)[0]
        crcs.append((stored, zlib.crc32(data[records_at:records_at + chunk.uncompressed_size])))
    footer_at = len(data) - 8 - 29
    summary_start = struct.unpack_from("<Q", data, footer_at + 9)[0]
    data_end_at = summary_start - 13
    assert data[data_end_at] == 0x0F and data[footer_at] == 0x02
    data_crc = (struct.unpack_from("<I", data, data_end_at + 9)[0], zlib.crc32(data[:data_end_at]))
    summary_crc = (struct.unpack_from("<I", data, footer_at + 25)[0], zlib.crc32(data[summary_start:footer_at + 25]))
    return crcs, data_crc, summary_crc


def rosbags_bag(path: Path, messages: int = 300, compression: bool = False) -> Path:
    """A bag written by rosbags alone, as BagWriter's writer writes it before the CRCs are filled in: chunks of
    about 1 MiB (here 5), optionally zstd-compressed (rosbags' only chunk compression)."""
    writer = Writer(path, version=BAG_VERSION, storage_plugin=StoragePlugin.MCAP)
    if compression:
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    writer.open()
    connection = writer.add_connection("/tactile/cam0/image", IMAGE_TYPE, typestore=bag_typestore([IMAGE_TYPE]))
    rng = np.random.default_rng(0)
    for i in range(messages):
        writer.write(connection, 1_700_000_000_000_000_000 + i, rng.integers(0, 32, 16_500, np.uint8).tobytes())
    writer.close()
    return next(path.glob("*.mcap"))


def test_our_bags_carry_every_crc(sim_bag, sim_frames):
    """Each chunk's CRC-32 is that of its records; the Data End and Footer records carry the data section's and the
    summary's. The bag reads back whole, and filling in the CRCs again finds nothing to write."""
    mcap = next(Path(sim_bag).glob("*.mcap"))
    chunks, data_crc, summary_crc = stored_crcs(mcap)
    assert len(chunks) > 1 and all(stored == computed != 0 for stored, computed in chunks)
    assert data_crc[0] == data_crc[1] != 0 and summary_crc[0] == summary_crc[1] != 0
    with BagReader(sim_bag) as bag:
        assert len(list(bag.messages())) == len(sim_frames) * len(bag.topics)
    before = mcap.read_bytes()
    assert fill_mcap_crcs(mcap) == McapCrcs(len(chunks), 0, data_crc[0], summary_crc[0])
    assert mcap.read_bytes() == before


def crc_field_bytes(mcap: Path) -> set[int]:
    """The byte positions of every CRC field of an MCAP file (chunks found through rosbags' chunk index; MCAP
    specification: a chunk's uncompressed_crc 24 bytes into its content, the Data End record's data_section_crc first
    in its content, the Footer's summary_crc last)."""
    size = mcap.stat().st_size
    reader = McapReader(mcap)
    reader.open()
    fields = [chunk.chunk_start_offset + 9 + 24 for chunk in reader.chunks]
    reader.close()
    footer_at = size - 8 - 29
    summary_start = struct.unpack_from("<Q", mcap.read_bytes(), footer_at + 9)[0]
    fields += [summary_start - 13 + 9, footer_at + 25]
    return {at + k for at in fields for k in range(4)}


@pytest.mark.parametrize("compression", [False, True], ids=["uncompressed", "zstd"])
def test_filling_in_the_crcs_changes_nothing_else(tmp_path, compression):
    """rosbags writes every CRC 0; filling them in changes bytes of those 4-byte fields only: the same size, the same
    messages read back, and rosbags' reader, which checks chunk CRCs over the decompressed records, accepts them."""
    mcap = rosbags_bag(tmp_path / "bag", compression=compression)
    if not compression:
        chunks, data_crc, summary_crc = stored_crcs(mcap)
        assert {stored for stored, _ in chunks} == {0} and data_crc[0] == summary_crc[0] == 0
    with BagReader(tmp_path / "bag") as bag:
        messages = list(bag.messages())
    before = mcap.read_bytes()
    filled = fill_mcap_crcs(mcap)
    after = mcap.read_bytes()
    assert filled.chunks == 5 and filled.filled == 5 + 2
    assert len(after) == len(before)
    changed = {i for i, (a, b) in enumerate(zip(before, after, strict=True)) if a != b}
    assert len(changed) > 5 + 2 and changed <= crc_field_bytes(mcap)
    with BagReader(tmp_path / "bag") as bag:
        assert list(bag.messages()) == messages and len(messages) == 300
    if not compression:
        chunks, data_crc, summary_crc = stored_crcs(mcap)
        assert all(stored == computed for stored, computed in chunks + [data_crc, summary_crc])


def test_the_written_file_must_be_the_one_planned(tmp_path, monkeypatch):
    """A file written (here: only its modification time changed) between reading it and writing its CRCs is left
    alone: the CRC offsets planned may no longer be those of its records."""
    mcap = rosbags_bag(tmp_path / "bag", messages=100)
    plan = mcap_crcs._plan_mcap_crcs

    def plan_then_touch(file, path):
        planned = plan(file, path)
        os.utime(path, ns=(0, 0))
        return planned

    monkeypatch.setattr(mcap_crcs, "_plan_mcap_crcs", plan_then_touch)
    before = mcap.read_bytes()
    with pytest.raises(McapError, match="was replaced or written while its CRCs were computed: nothing was written"):
        fill_mcap_crcs(mcap)
    assert mcap.read_bytes() == before


@pytest.mark.parametrize("codec", ["lz4", "zstd"])
def test_compressed_chunk_records_are_decompressed_for_their_crc(codec):
    """rosbags writes zstd chunks only (tested above); `ros2 bag record` may write lz4 ones."""
    records = bytes(range(256)) * 64
    if codec == "lz4":
        compressed = lz4.frame.compress(records)
    else:
        compressed = zstd.compress(records)
    assert mcap_crcs._decompress(codec, memoryview(compressed), Path("x.mcap"), "the chunk") == records
    with pytest.raises(McapError, match=f"x.mcap is damaged: the chunk does not decompress as {codec}"):
        mcap_crcs._decompress(codec, memoryview(bytes(32)), Path("x.mcap"), "the chunk")  # no frame magic
    with pytest.raises(McapError, match="compressed as 'brotli', none of lz4 and zstd"):
        mcap_crcs._decompress("brotli", memoryview(compressed), Path("x.mcap"), "the chunk")


def test_a_flipped_pixel_byte_is_refused(flipped_pixels_bag, sim_frames):
    """64 bytes of an image's pixels changed on disk: the chunk's CRC refuses them, naming the CRC mismatch, and so
    does filling in the CRCs again. Without the CRC (set to 0, "not available", as rosbags writes it) the changed
    image would read back, unnoticed: the damage breaks neither the file's structure nor the message's encoding."""
    with BagReader(flipped_pixels_bag) as bag, \
            pytest.raises(BagError, match=rf"^bag {flipped_pixels_bag} is damaged: a chunk's CRC-32 does not match its "
                                          r"data \(Chunk checksum mismatch\.\): bytes of the file changed"):
        list(bag.messages())
    mcap = next(flipped_pixels_bag.glob("*.mcap"))
    with pytest.raises(McapError, match=r"is damaged: the chunk at byte \d+ carries the CRC-32 0x[0-9a-f]{8}, its "
                                        r"records give 0x[0-9a-f]{8}$"):
        fill_mcap_crcs(mcap)

    data = bytearray(mcap.read_bytes())
    reader = McapReader(mcap)
    reader.open()
    chunk_at = reader.chunks[-1].chunk_start_offset  # the last image is in the last chunk
    reader.close()
    struct.pack_into("<I", data, chunk_at + 9 + 24, 0)
    mcap.write_bytes(bytes(data))
    with BagReader(flipped_pixels_bag) as bag:
        last = [raw for topic, _, _, raw in bag.messages() if topic == camera_topic("cam2")][-1]
    changed = np.frombuffer(bytes(deserialize_message(last, Image).data), np.uint8)
    assert (changed != sim_frames[-1].images[2].ravel()).sum() == 64


def test_a_data_section_crc_taken_before_the_chunk_crcs_is_recomputed(tmp_path):
    """A writer that set the data-section CRC but no chunk CRC (none known does): the data-section CRC is checked
    against the bytes as they were, then recomputed over the chunk CRCs filled in. A wrong one is refused."""
    mcap = rosbags_bag(tmp_path / "bag", messages=100)
    data = bytearray(mcap.read_bytes())
    data_end_at = struct.unpack_from("<Q", data, len(data) - 8 - 29 + 9)[0] - 13
    struct.pack_into("<I", data, data_end_at + 9, zlib.crc32(data[:data_end_at]))
    mcap.write_bytes(bytes(data))
    assert fill_mcap_crcs(mcap).filled == 2 + 1 + 1
    chunks, data_crc, summary_crc = stored_crcs(mcap)
    assert all(stored == computed != 0 for stored, computed in chunks + [data_crc, summary_crc])
    struct.pack_into("<I", data, data_end_at + 9, 12345)
    mcap.write_bytes(bytes(data))
    with pytest.raises(McapError, match=r"is damaged: its data section has the CRC-32 0x00003039 in its Data End "
                                        r"record, its bytes give 0x"):
        fill_mcap_crcs(mcap)


def truncated_in_a_chunk(data: bytearray, chunk_at: int) -> bytes:
    return bytes(data[:chunk_at + 9 + 40 + 1000])


def chunk_records_too_long(data: bytearray, chunk_at: int) -> bytes:
    records_length_at = chunk_at + 9 + 32
    struct.pack_into("<Q", data, records_length_at, struct.unpack_from("<Q", data, records_length_at)[0] + 1)
    return bytes(data)


def chunk_of_another_size(data: bytearray, chunk_at: int) -> bytes:
    struct.pack_into("<Q", data, chunk_at + 9 + 16, struct.unpack_from("<Q", data, chunk_at + 9 + 16)[0] - 1)
    return bytes(data)


def without_footer(data: bytearray, chunk_at: int) -> bytes:
    return bytes(data[:-20])


def not_mcap(data: bytearray, chunk_at: int) -> bytes:
    return b"PK\x03\x04" + bytes(data[4:])


@pytest.mark.parametrize(("damage", "error"), [
    (truncated_in_a_chunk, r"is truncated or damaged: its record of opcode 0x06 at byte \d+ claims \d+ bytes, but "
                           r"the file ends 1040 bytes after its start"),
    (chunk_records_too_long, r"is damaged: the chunk at byte \d+ says it holds \d+ bytes of records, it has room "
                             r"for \d+"),
    (chunk_of_another_size, r"is damaged: the chunk at byte \d+ holds \d+ bytes of records, its header says \d+"),
    (without_footer, r"is truncated or damaged: it does not end with an MCAP Footer record and the magic"),
    (not_mcap, r"is not an MCAP file: it does not start with the MCAP magic"),
])
def test_a_damaged_file_is_refused_by_the_crc_fill_in_and_left_as_it_was(tmp_path, damage, error):
    """Defined behaviour for a damaged file: an McapError that names it and where the damage lies; nothing written."""
    mcap = rosbags_bag(tmp_path / "bag", messages=100)
    data = bytearray(mcap.read_bytes())
    reader = McapReader(mcap)
    reader.open()
    second_chunk_at = reader.chunks[1].chunk_start_offset
    reader.close()
    damaged = damage(data, second_chunk_at)
    mcap.write_bytes(damaged)
    with pytest.raises(McapError, match=rf"^{mcap} {error}$") as refused:
        fill_mcap_crcs(mcap)
    if re.search(r"chunk at byte|opcode 0x06 at byte", str(refused.value)):
        assert f"at byte {second_chunk_at} " in str(refused.value)
    assert mcap.read_bytes() == damaged


def test_closing_twice_completes_the_bag_once(tmp_path):
    bag = BagWriter(tmp_path / "bag")
    bag.write("/x", IMAGE_TYPE, 1, serialize_message(Image(height=1, width=1, encoding="mono8", step=1, data=[7])))
    bag.close()
    bag.close()
    with BagReader(tmp_path / "bag") as reader:
        assert reader.counts == {"/x": 1}


def test_damaged_metadata(sim_bag, tmp_path):
    bag = copy_bag(sim_bag, tmp_path / "damaged")
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: [1")
    with pytest.raises(BagError, match="cannot be opened"):
        BagReader(bag)


@pytest.mark.parametrize("where", [0.25, 0.5, 0.9])
def test_a_byte_changed_in_the_summary_is_refused_by_its_crc(sim_bag, tmp_path, where):
    """The summary (channels, statistics, the chunk index) is read without any error after most changes: as fewer
    messages, or a topic of another name (found in review). Its CRC in the Footer, which BagWriter fills in, is
    checked when the bag is opened."""
    bag = copy_bag(sim_bag, tmp_path / "summary")
    mcap = next(bag.glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    footer_start = len(data) - 37  # Footer record (1 + 8 + 8 + 8 + 4 bytes), then the 8-byte magic
    summary_start = struct.unpack_from("<Q", data, footer_start + 9)[0]
    data[summary_start + int(where * (footer_start - summary_start))] ^= 0x20
    mcap.write_bytes(bytes(data))
    with pytest.raises(BagError, match=r"is damaged: its summary \(the index of its topics and messages\) has the "
                                       r"CRC-32 0x[0-9a-f]{8} in its Footer, its bytes give 0x[0-9a-f]{8}: bytes of "
                                       "the file changed after it was written; take it from a copy"):
        BagReader(bag)


def test_a_summary_without_its_crc_is_read_unchecked(sim_bag, tmp_path):
    """summary_crc 0 means "not available" (the rosbags writer's, before BagWriter fills it in)."""
    bag = copy_bag(sim_bag, tmp_path / "no_summary_crc")
    mcap = next(bag.glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    struct.pack_into("<I", data, len(data) - 12, 0)  # the Footer's summary_crc, before the magic
    mcap.write_bytes(bytes(data))
    with BagReader(bag) as reader:
        assert sum(reader.counts.values()) > 0


def test_a_record_length_too_large_to_allocate_is_refused(sim_bag, tmp_path):
    """One byte of the MCAP header record's length set to 0x7f: rosbags tried to read 2**62 bytes, and the MemoryError
    ended tactile-bag in a traceback (found in review)."""
    bag = copy_bag(sim_bag, tmp_path / "long_record")
    mcap = next(bag.glob("*.mcap"))
    data = bytearray(mcap.read_bytes())
    data[16] = 0x7F  # after the 8-byte magic and the opcode, the top byte of the first record's 8-byte length
    mcap.write_bytes(bytes(data))
    with pytest.raises(BagError, match=r"cannot be opened \(a record length beyond any memory\)"):
        BagReader(bag)


@pytest.mark.parametrize(("old", "new", "message"), [
    # rosbags itself fails on these: a quoted number (TypeError), a number as a type name (AttributeError)
    (r"nanoseconds: (\d+)", r"nanoseconds: '\1'", "a field of its metadata.yaml is of the wrong kind"),
    # these rosbags takes, and the reader failed later on them
    (r"- message_count: (\d+)", r"- message_count: '\1'", "message count '"),  # a topic's
    (r"name: /tactile/ground_truth/force_distribution", "name: 5", "gives topic 5 the type"),
    (r"type: tactile_msgs/msg/ForceDistribution", "type: 5", "the type 5 and"),
])
def test_metadata_fields_of_the_wrong_kind_are_refused_naming_the_file(sim_bag, tmp_path, old, new, message):
    """A hand-edited metadata.yaml ended tactile-bag eval and play in a TypeError or AttributeError traceback (found in
    review)."""
    bag = copy_bag(sim_bag, tmp_path / "edited")
    metadata = bag / "metadata.yaml"
    edited = re.sub(old, new, metadata.read_text(), count=1)
    assert edited != metadata.read_text()
    metadata.write_text(edited)
    with pytest.raises(BagError, match=re.escape(message)) as refused:
        BagReader(bag)
    assert "metadata.yaml" in str(refused.value)


def test_metadata_listing_its_files_as_text_is_refused_before_anything_is_read(sim_bag, tmp_path):
    """rosbags opened such a bag and failed as it closed it: an AttributeError traceback (review)."""
    bag = copy_bag(sim_bag, tmp_path / "files_as_text")
    metadata = bag / "metadata.yaml"
    information = yaml.safe_load(metadata.read_text())
    information["rosbag2_bagfile_information"]["files"] = "abc"
    metadata.write_text(yaml.safe_dump(information))
    with pytest.raises(BagError, match="its metadata.yaml gives `files` as 'abc', not a list of its storage files"):
        BagReader(bag)


def test_a_damaged_sqlite3_bag_is_refused_as_damaged(sim_bag, tmp_path):
    """rosbags reads a .db3 bag through apsw, whose CorruptError ("database disk image is malformed") ended tactile-bag
    eval and play in a traceback (review). The first byte of each of the first pages flipped in turn: every damage
    is read or refused as damaged, and one of them is apsw's."""
    db3 = tmp_path / "db3"
    with BagReader(sim_bag) as source:
        messages, topics = list(source.messages()), dict(source.topics)
    writer = Writer(db3, version=BAG_VERSION, storage_plugin=StoragePlugin.SQLITE3)
    writer.open()
    typestore = bag_typestore(set(topics.values()))
    connections = {topic: writer.add_connection(topic, kind, typestore=typestore) for topic, kind in topics.items()}
    for topic, _, time_ns, raw in messages:
        writer.write(connections[topic], time_ns, raw)
    writer.close()
    database = next(db3.glob("*.db3"))
    intact = database.read_bytes()
    apsw_errors = 0
    for page in range(1, 41):
        damaged = bytearray(intact)
        damaged[page * 4096] ^= 0xFF
        database.write_bytes(bytes(damaged))
        try:
            with BagReader(db3) as bag:
                sum(1 for _ in bag.messages())
        except BagError as exc:
            apsw_errors += isinstance(exc.__cause__, apsw.CorruptError | apsw.NotADBError)
    assert apsw_errors > 0


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
                                               rf"one \({installed}\);.* or leave the topic out \(play: --topics; "
                                               r"eval: --source images, for recorded bundles\)"):
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
