"""rosbag2 bags through the pure-Python `rosbags`: serialized (CDR) messages in, serialized messages out.

Bags are written as rosbag2 version 9 (ROS 2 Kilted) with MCAP storage: a directory holding metadata.yaml and
one .mcap file, each topic with its type name, definition and type hash, each message with its receive time
(nanoseconds since the epoch). Reading accepts any rosbag2 bag `rosbags` reads (MCAP or sqlite3).
Every failure to open or read a bag becomes a BagError that names the bag.

The `rosbags` MCAP writer (0.11) leaves every CRC of the file 0, "not available"; BagWriter.close fills them in
(fill_mcap_crcs), so that a reader finds bytes changed on disk, an image's pixels included, and not only damage
that breaks the file's structure.
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterable, Iterator
from pathlib import Path

import apsw
import yaml
from rosbags.rosbag2 import Reader, ReaderError, StoragePlugin, Writer, WriterError

from tactile_bag.mcap_crcs import McapError, check_summary_crc, fill_mcap_crcs
from tactile_bag.message_types import MessageTypeError, add_types, bag_typestore

try:
    from compression.zstd import ZstdError  # Python 3.14
except ImportError:
    from backports.zstd import ZstdError  # the zstd module rosbags uses before 3.14

#: rosbag2 metadata version written (Kilted's; `ros2 bag` of Jazzy and later reads it).
BAG_VERSION = 9

#: What rosbags' readers raise on a damaged bag (bad magic, truncated chunk, lengths out of range, bad YAML), on a
#: zstd-compressed one (rosbag2's FILE or MESSAGE compression, zstd MCAP chunks) whose compressed bytes are cut short
#: (EOFError) or are not zstd (ZstdError, e.g. metadata that claims zstd over a plain .mcap), and on an lz4 MCAP chunk
#: whose bytes are not an lz4 frame (the lz4 package raises a plain RuntimeError), and on a record length damaged
#: into one too large to allocate (MemoryError: one byte of the MCAP header record's length set to 0x7f), and on a
#: damaged sqlite3 (.db3) file, read through apsw ("database disk image is malformed": a traceback before, review;
#: its errors that say nothing of damage, such as a locked file, are not taken for it).
DAMAGED_BAG_ERRORS = (ReaderError, OSError, ValueError, ArithmeticError, IndexError, KeyError, struct.error, EOFError,
                      ZstdError, RuntimeError, MemoryError, apsw.CorruptError, apsw.NotADBError)
#: What rosbags' Reader.open raises on a metadata.yaml whose fields are of the wrong kind: a number quoted (a
#: TypeError inside rosbags), a number as a type name (AttributeError).
METADATA_KIND_ERRORS = (TypeError, AttributeError)


class BagError(ValueError):
    """A bag that cannot be written or read, or does not hold what was asked for."""


class DefinitionMismatchError(BagError):
    """A topic recorded with another definition of its message type than the installed one (an older tactile_msgs)."""


class BagWriter:
    """A new MCAP bag; `write` takes a topic, its type name, the receive time in ns and the serialized message.

    Use as a context manager (or call `close`): the MCAP file is only complete, and readable, once closed; closing
    also fills in its CRCs (fill_mcap_crcs).
    """

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f"{self.path} already exists: name a new bag directory (a bag is never overwritten)")
        if not self.path.parent.is_dir():
            raise BagError(f"{self.path}: the folder {self.path.parent} does not exist; create it first")
        self.typestore = bag_typestore()
        self.counts: dict[str, int] = {}
        self._connections: dict[str, tuple[str, object]] = {}
        self._writer = Writer(self.path, version=BAG_VERSION, storage_plugin=StoragePlugin.MCAP)
        self._closed = False
        try:
            self._writer.open()
        except (WriterError, OSError) as exc:
            raise BagError(f"{self.path}: cannot create the bag: {exc}") from exc

    def add_topic(self, topic: str, msgtype: str) -> None:
        """Declare a topic (written into the bag's metadata even if no message follows)."""
        known = self._connections.get(topic)
        if known is not None:
            if known[0] != msgtype:
                raise BagError(f"{self.path}: topic {topic} is already recorded as {known[0]}, not {msgtype}")
            return
        try:
            add_types(self.typestore, [msgtype])
        except MessageTypeError as exc:
            raise BagError(f"{self.path}: cannot record {topic}: {exc}") from exc
        self._connections[topic] = (msgtype, self._writer.add_connection(topic, msgtype, typestore=self.typestore))
        self.counts[topic] = 0

    def write(self, topic: str, msgtype: str, time_ns: int, raw: bytes) -> None:
        self.add_topic(topic, msgtype)
        self._writer.write(self._connections[topic][1], int(time_ns), raw)
        self.counts[topic] += 1

    def close(self) -> None:
        """Complete the bag (rosbags writes the MCAP index and metadata.yaml), fill in the MCAP file's CRCs and flush
        the bag to the disk.

        The bag is complete and readable before the CRCs are filled in: should that fail, the BagError says so and
        the bag reads back without them (a crash meanwhile leaves some chunks with their CRC, the rest without)."""
        if self._closed:
            return
        self._closed = True
        try:
            self._writer.close()
        except (WriterError, OSError) as exc:
            raise BagError(f"{self.path}: cannot complete the bag: {exc}") from exc
        for mcap in sorted(self.path.glob("*.mcap")):
            try:
                fill_mcap_crcs(mcap)
            except McapError as exc:
                raise BagError(f"{self.path} is written, but without CRCs: {exc}") from exc
        try:
            _flush_to_disk(self.path)
        except OSError as exc:
            raise BagError(f"{self.path} is written, but may not be on the disk yet: {exc}") from exc

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()


def _flush_to_disk(bag: Path) -> None:
    """fsync the bag's metadata.yaml (the .mcap files are, by fill_mcap_crcs) and its directory, whose entries a power
    loss could otherwise lose: the rosbags writer syncs nothing."""
    for path in (bag / "metadata.yaml", bag):
        descriptor = os.open(path, os.O_RDONLY)
        try:
            os.fsync(descriptor)
        finally:
            os.close(descriptor)


class BagReader:
    """An existing bag: its topics (name -> type name), message counts and serialized messages in time order."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        if not self.path.exists():
            raise BagError(f"bag {self.path} does not exist: give the directory that `tactile-bag record` (or "
                           "`ros2 bag record`) wrote")
        if self.path.is_dir() and not (self.path / "metadata.yaml").exists():  # rosbags: "Expected metadata file
            raise BagError(f"bag {self.path} has no metadata.yaml: give the directory that `tactile-bag record` (or "
                           "`ros2 bag record`) wrote, whole")  # 'DIR' does not exist", naming the directory
        if self.path.is_dir():
            self._check_files_listed()
        try:
            self._reader = Reader(self.path)
            self._reader.open()
        except METADATA_KIND_ERRORS as exc:
            raise BagError(f"bag {self.path} cannot be opened: a field of its metadata.yaml is of the wrong kind "
                           f"({exc}): a number quoted, or a name given as a number? Compare it with the metadata.yaml "
                           "of a bag that `tactile-bag record` wrote") from exc
        except DAMAGED_BAG_ERRORS as exc:
            reason = "a record length beyond any memory" if isinstance(exc, MemoryError) else exc
            raise BagError(f"bag {self.path} cannot be opened ({reason}); expected a rosbag2 directory with "
                           "metadata.yaml and its .mcap or .db3 file, complete (a recorder killed with SIGKILL "
                           "leaves an unreadable file)") from exc
        for mcap in sorted(self.path.glob("*.mcap")):
            try:
                check_summary_crc(mcap)
            except McapError as exc:
                self._reader.close()
                raise BagError(f"bag {self.path}: {exc}: bytes of the file changed after it was written; take it "
                               "from a copy") from exc
        for connection in self._reader.connections:
            if not (isinstance(connection.topic, str) and isinstance(connection.msgtype, str)
                    and type(connection.msgcount) is int):
                self._reader.close()
                raise BagError(f"bag {self.path}: its metadata.yaml gives topic {connection.topic!r} the type "
                               f"{connection.msgtype!r} and message count {connection.msgcount!r}: expected a name, a "
                               "type name and a whole number; compare it with the metadata.yaml of a bag that "
                               "`tactile-bag record` wrote")
        self.topics = {c.topic: c.msgtype for c in self._reader.connections}
        self._checked_topics: set[str] = set()
        self.counts = dict.fromkeys(self.topics, 0)
        for connection in self._reader.connections:
            self.counts[connection.topic] += connection.msgcount

    def _check_files_listed(self) -> None:
        """BagError unless metadata.yaml's `files` (where given) lists mappings: rosbags opened a bag whose `files` was
        text, and failed as it closed it, with an AttributeError traceback (review). Other damage to metadata.yaml is
        left to rosbags, whose errors the constructor reports."""
        try:
            information = yaml.safe_load((self.path / "metadata.yaml").read_text(encoding="utf-8"))
            files = information["rosbag2_bagfile_information"].get("files", [])
        except (OSError, ValueError, yaml.YAMLError, TypeError, KeyError, AttributeError):
            return
        if not (isinstance(files, list) and all(isinstance(entry, dict) for entry in files)):
            raise BagError(f"bag {self.path} cannot be opened: its metadata.yaml gives `files` as {files!r}, not a "
                           "list of its storage files; compare it with the metadata.yaml of a bag that `tactile-bag "
                           "record` wrote")

    def require_topics(self, topics: Iterable[str]) -> list[str]:
        """`topics` if the bag has every one, else BagError listing what it has."""
        topics = list(topics)
        unknown = [t for t in topics if t not in self.topics]
        if unknown:
            raise BagError(f"bag {self.path} has no topic {', '.join(unknown)}; its topics are "
                           f"{sorted(self.topics) or 'none'}")
        return topics

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[tuple[str, str, int, bytes]]:
        """(topic, type name, receive time ns, serialized message) of the given topics (default all), by time."""
        wanted = set(self.require_topics(topics)) if topics is not None else set(self.topics)
        connections = [c for c in self._reader.connections if c.topic in wanted]
        if not connections:
            return
        self.check_definitions(wanted)
        try:
            for connection, time_ns, raw in self._reader.messages(connections=connections):
                yield connection.topic, connection.msgtype, time_ns, raw
        except DAMAGED_BAG_ERRORS as exc:
            if isinstance(exc, MemoryError):
                raise BagError(f"bag {self.path} is damaged: a record length beyond any memory") from exc
            if "checksum mismatch" in str(exc).lower():  # rosbags: "Chunk checksum mismatch."
                raise BagError(f"bag {self.path} is damaged: a chunk's CRC-32 does not match its data ({exc}): bytes "
                               "of the file changed after it was written; take it from a copy") from exc
            raise BagError(f"bag {self.path} is damaged: reading its messages failed ({exc})") from exc

    def check_definitions(self, topics: Iterable[str]) -> None:
        """BagError if one of `topics` was recorded with another definition of its type than the installed one (its
        type hash, RIHS01, differs): its bytes would be decoded, or republished, as a message they are not. Topics
        recorded without a hash (rosbag2 before version 7, or a recorder that could not resolve the type) cannot be
        checked and pass. Each topic is checked once per reader."""
        unchecked = set(topics) - self._checked_topics
        connections = [c for c in self._reader.connections if c.topic in unchecked]
        if not connections:  # every pass of `play --loop` asks again: no type store to build then
            return
        hashed = [c for c in connections if c.digest]
        try:
            typestore = bag_typestore({c.msgtype for c in hashed})
        except MessageTypeError as exc:
            raise BagError(f"bag {self.path}: {exc}") from exc
        for connection in hashed:
            installed = typestore.hash_rihs01(connection.msgtype)
            if connection.digest != installed:
                raise DefinitionMismatchError(
                    f"bag {self.path}: topic {connection.topic} was recorded with another definition of "
                    f"{connection.msgtype} (type hash {connection.digest}) than the installed one ({installed}); read "
                    "it with the version of the interface package that recorded it, or leave the topic out (play: "
                    "--topics; eval: --source images, for recorded bundles)")
        self._checked_topics.update(c.topic for c in connections)

    def close(self) -> None:
        self._reader.close()

    def __enter__(self) -> BagReader:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()
