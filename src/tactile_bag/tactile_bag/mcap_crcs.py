"""The CRC-32s of an MCAP file that the rosbags writer (0.11) leaves 0, "not available", filled in.

With them a reader finds bytes changed on disk, an image's pixels included, and not only damage that breaks the
file's structure. From the MCAP specification (https://mcap.dev/spec).
"""

from __future__ import annotations

import os
import struct
import zlib
from pathlib import Path
from typing import BinaryIO, NamedTuple


class McapError(ValueError):
    """An MCAP file whose CRCs cannot be filled in: damaged, truncated, or compressed in a way not readable here."""


MCAP_MAGIC = b"\x89MCAP0\r\n"
_HEADER, _FOOTER, _CHUNK, _DATA_END = 0x01, 0x02, 0x06, 0x0F
_RECORD_HEAD = struct.Struct("<BQ")  # opcode, content length
_CHUNK_HEAD = struct.Struct("<QQQI")  # message_start_time, message_end_time, uncompressed_size, uncompressed_crc
_CHUNK_CRC_AT = 24  # uncompressed_crc, from the start of a chunk record's content
_FOOTER_RECORD = struct.Struct("<BQQQI")  # opcode 0x02, length 20, summary_start, summary_offset_start, summary_crc
_FOOTER_CRC_AT = 25  # summary_crc, from the start of the Footer record
_READ_PIECE = 1 << 24


class McapCrcs(NamedTuple):
    """What fill_mcap_crcs found: the file's chunk count and its CRCs as they are now."""

    chunks: int  # Chunk records in the data section, each with its CRC now
    filled: int  # CRC fields this call wrote (the others were set already, and right)
    data_section_crc: int  # in the Data End record: of every byte from the magic up to that record
    summary_crc: int  # in the Footer: of the summary (and summary offset) sections and the Footer up to this field


def fill_mcap_crcs(path: str | Path) -> McapCrcs:
    """Fill in the CRC-32s of an MCAP file that are 0 ("not available"): each chunk's `uncompressed_crc`, the Data End
    record's `data_section_crc` and the Footer's `summary_crc` (`ros2 bag record` writes the chunks' and the
    summary's). rosbags, hence `tactile-bag eval` and `play`, checks a chunk's CRC whenever it reads the chunk; the
    other two are for MCAP tools (the `mcap` library's stream reader checks the data section's with validate_crcs).
    The values are those the `mcap` library's writer computes (compared by hand, mcap 1.6.0).

    The records are walked from the magic on (opcode, uint64 length, content), the chunks' content parsed as the
    specification lays it out: message_start_time, message_end_time, uncompressed_size (uint64 each),
    uncompressed_crc (uint32), compression (uint32-length string), records (uint64-length bytes). The chunk CRC is
    that of the uncompressed records: a compressed chunk ("lz4" or "zstd", the codecs rosbags itself depends on, so
    importable wherever rosbags is) is decompressed to compute it; another compression, or a codec that is not
    installed, is a McapError. Our BagWriter writes uncompressed chunks (rosbags' default, no compression mode set).

    A CRC already set is checked, never overwritten: one that does not match is a McapError (the file is damaged; a
    data-section CRC taken before the chunks had theirs, and right for those bytes, is recomputed). So a second call
    writes nothing, and a file without a CRC to fill in is only read (it may be read-only).

    A file that does not have the structure (no magic, a record running past the end of the file, a chunk whose
    parts do not add up, no Data End record, no Footer and closing magic: a truncated or damaged file, a recorder
    killed before closing it) is a McapError naming the file and the byte where the damage lies, and the file is left
    as it was: everything is read and computed before the first byte is written.

    In place, not a rewritten copy: only 4-byte CRC fields change, from 0 to their value, and no byte of a message,
    record length or offset; the file never changes size. So at every moment it is a complete MCAP file holding all
    its messages, and a crash (power loss included) part-way leaves CRC fields each either 0, which no reader checks,
    or right (a 4-byte write torn by a power loss would read as a mismatch: a false alarm, never damage let through);
    calling this again finishes the job. The chunks' CRCs are written and flushed to the disk (fsync)
    before the data-section CRC that covers them, so that no crash leaves a data-section CRC over chunk CRCs that
    never reached the disk. A temporary copy and os.replace would protect nothing more and would write the whole
    bag (gigabytes) a second time, needing that much free disk space.
    """
    path = Path(path)
    try:
        with path.open("rb") as file:
            planned = _identity(file)
            chunks, patches, data_crc, summary_crc = _plan_mcap_crcs(file, path)
        if any(patches):
            with path.open("r+b") as file:
                _write_mcap_crcs(file, path, planned, patches)
    except OSError as exc:
        raise McapError(f"{path}: cannot fill in its CRCs: {exc}") from exc
    return McapCrcs(chunks, sum(len(group) for group in patches), data_crc, summary_crc)


Patch = tuple[int, int, int]  # file offset of a uint32 CRC field, its value now, the value to write


def check_summary_crc(path: str | Path) -> None:
    """McapError if the Footer's `summary_crc` is set and its summary's bytes give another CRC-32.

    The summary (channels, schemas, statistics, the chunk index) tells a reader which topics the file holds and where
    their messages lie; a byte changed there read, without any error, as fewer messages or a topic of another name
    (found in review: 28 of 30 estimates, no ground truth matched). It is a few kB at the file's end, so checking it
    costs nothing next to reading the messages. A summary_crc of 0 ("not available") passes, and so does a file
    whose end is no Footer and magic: the reader reports such damage itself."""
    path = Path(path)
    try:
        with path.open("rb") as file:
            try:
                footer = _read_footer(file, os.fstat(file.fileno()).st_size, path)
            except McapError:
                return
            if not footer.summary_crc:
                return
            start = footer.summary_start or footer.start  # without a summary, the CRC is of the Footer's fields alone
            if not len(MCAP_MAGIC) <= start <= footer.start:
                raise McapError(f"{path} is damaged: its Footer puts the summary at byte {footer.summary_start}, "
                                f"outside the file's {footer.start} bytes before the Footer")
            computed = _summary_crc(file, footer, start)
    except OSError as exc:
        raise McapError(f"{path}: cannot check its summary: {exc}") from exc
    if computed != footer.summary_crc:
        raise McapError(f"{path} is damaged: its summary (the index of its topics and messages) has the CRC-32 "
                        f"{footer.summary_crc:#010x} in its Footer, its bytes give {computed:#010x}")


class Footer(NamedTuple):
    """An MCAP file's Footer record, before its closing magic."""

    start: int  # the record's byte offset
    summary_start: int  # 0: no summary section
    summary_crc: int  # as stored; 0: "not available"


def _read_footer(file: BinaryIO, size: int, path: Path, data_end: int = len(MCAP_MAGIC)) -> Footer:
    """The Footer of a file of `size` bytes whose data section ends at byte `data_end`; McapError for a file that does
    not end with a Footer record and the magic after it."""
    start = size - _FOOTER_RECORD.size - len(MCAP_MAGIC)
    file.seek(max(start, 0))
    footer = file.read(_FOOTER_RECORD.size + len(MCAP_MAGIC))
    if start < data_end or footer[_FOOTER_RECORD.size:] != MCAP_MAGIC:
        raise McapError(f"{path} is truncated or damaged: it does not end with an MCAP Footer record and the magic")
    opcode, length, summary_start, _, summary_crc = _FOOTER_RECORD.unpack_from(footer)
    if (opcode, length) != (_FOOTER, _FOOTER_RECORD.size - _RECORD_HEAD.size):
        raise McapError(f"{path} is damaged: the record before its closing magic is not an MCAP Footer")
    return Footer(start, summary_start, summary_crc)


def _summary_crc(file: BinaryIO, footer: Footer, start: int) -> int:
    """The CRC-32 that the Footer's summary_crc holds: of the bytes from `start` (the summary section's, as the
    Footer's CRC counts it) up to that field."""
    return _crc_of(file, footer.start + _FOOTER_CRC_AT - start, 0, at=start)


def _plan_mcap_crcs(file: BinaryIO, path: Path) -> tuple[int, list[list[Patch]], int, int]:
    """(chunks, [chunk CRC patches, data-section and summary CRC patches], data-section CRC, summary CRC)."""
    size = os.fstat(file.fileno()).st_size
    if file.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
        raise McapError(f"{path} is not an MCAP file: it does not start with the MCAP magic")
    data_crc = zlib.crc32(MCAP_MAGIC)  # over the data section as it will be, chunk CRCs filled in
    offset, chunks, chunk_patches = len(MCAP_MAGIC), 0, []
    while True:
        head = file.read(_RECORD_HEAD.size)
        if len(head) < _RECORD_HEAD.size:
            raise McapError(f"{path} is truncated: it ends at byte {size}, before the Data End record (a recorder "
                            "stopped before it closed the bag?)")
        opcode, length = _RECORD_HEAD.unpack(head)
        start, end = offset + _RECORD_HEAD.size, offset + _RECORD_HEAD.size + length
        if offset == len(MCAP_MAGIC) and opcode != _HEADER:
            raise McapError(f"{path} is damaged: its first record (opcode {opcode:#04x}) is not an MCAP Header")
        if end > size:
            raise McapError(f"{path} is truncated or damaged: its record of opcode {opcode:#04x} at byte {offset} "
                            f"claims {length} bytes, but the file ends {size - start} bytes after its start")
        if opcode == _DATA_END:
            if length < 4:
                raise McapError(f"{path} is damaged: its Data End record at byte {offset} is {length} bytes long")
            (stored_data_crc,) = struct.unpack("<I", file.read(4))
            data_end, offset = offset, end
            break
        data_crc = zlib.crc32(head, data_crc)
        if opcode == _CHUNK:
            content = bytearray(length)
            if file.readinto(content) != length:
                raise McapError(f"{path} is truncated: it ends inside the chunk at byte {offset}")
            stored, computed = _chunk_crcs(content, path, offset)
            if not stored:
                _CHUNK_HEAD.pack_into(content, 0, *_CHUNK_HEAD.unpack_from(content)[:3], computed)
                chunk_patches.append((start + _CHUNK_CRC_AT, 0, computed))
            elif stored != computed:
                raise McapError(f"{path} is damaged: the chunk at byte {offset} carries the CRC-32 {stored:#010x}, its "
                                f"records give {computed:#010x}")
            data_crc = zlib.crc32(content, data_crc)
            chunks += 1
        else:
            data_crc = _crc_of(file, length, data_crc)
        offset = end

    footer = _read_footer(file, size, path, data_end=offset)
    if footer.summary_start not in (0, offset):
        raise McapError(f"{path} is damaged: its Footer puts the summary at byte {footer.summary_start}, the data "
                        f"section ends at byte {offset}")
    summary_crc = _summary_crc(file, footer, offset)

    final_patches = []
    if stored_data_crc != data_crc:
        if stored_data_crc and not (chunk_patches and _crc_of(file, data_end, 0, at=0) == stored_data_crc):
            raise McapError(f"{path} is damaged: its data section has the CRC-32 {stored_data_crc:#010x} in its Data "
                            f"End record, its bytes give {data_crc:#010x}")
        final_patches.append((data_end + _RECORD_HEAD.size, stored_data_crc, data_crc))
    if footer.summary_crc != summary_crc:
        if footer.summary_crc:
            raise McapError(f"{path} is damaged: its summary has the CRC-32 {footer.summary_crc:#010x} in its Footer, "
                            f"its bytes give {summary_crc:#010x}")
        final_patches.append((footer.start + _FOOTER_CRC_AT, 0, summary_crc))
    return chunks, [chunk_patches, final_patches], data_crc, summary_crc


def _chunk_crcs(content: bytearray, path: Path, offset: int) -> tuple[int, int]:
    """(stored, computed) CRC-32 of the uncompressed records of the chunk whose record content is `content`."""
    where = f"the chunk at byte {offset}"
    try:
        _, _, uncompressed_size, stored = _CHUNK_HEAD.unpack_from(content)
        (name_length,) = struct.unpack_from("<I", content, _CHUNK_HEAD.size)
        records_at = _CHUNK_HEAD.size + 4 + name_length + 8
        (records_length,) = struct.unpack_from("<Q", content, records_at - 8)
        compression = bytes(content[_CHUNK_HEAD.size + 4:records_at - 8]).decode()
    except (struct.error, UnicodeDecodeError) as exc:
        raise McapError(f"{path} is damaged: {where} ({len(content)} bytes) has no readable chunk header") from exc
    if records_at + records_length > len(content):
        raise McapError(f"{path} is damaged: {where} says it holds {records_length} bytes of records, it has room "
                        f"for {len(content) - records_at}")
    records = memoryview(content)[records_at:records_at + records_length]
    if compression:
        records = _decompress(compression, records, path, where)
    if len(records) != uncompressed_size:
        raise McapError(f"{path} is damaged: {where} holds {len(records)} bytes of records, its header says "
                        f"{uncompressed_size}")
    return stored, zlib.crc32(records)


def _decompress(compression: str, data: memoryview, path: Path, where: str) -> bytes:
    """A chunk's records, decompressed with the MCAP compression format `compression` (lz4 or zstd)."""
    try:
        if compression == "zstd":
            try:
                from compression import zstd  # Python 3.14
            except ImportError:
                from backports import zstd  # what rosbags uses before 3.14
            return zstd.decompress(data)
        if compression == "lz4":
            from lz4.frame import decompress
            return decompress(data)
    except ImportError as exc:
        raise McapError(f"{path}: {where} is {compression}-compressed and no {compression} codec is installed "
                        f"({exc}): its CRC cannot be computed") from exc
    except Exception as exc:  # zstd.ZstdError, lz4's RuntimeError: data that does not decompress
        raise McapError(f"{path} is damaged: {where} does not decompress as {compression} ({exc})") from exc
    raise McapError(f"{path}: {where} is compressed as {compression!r}, none of lz4 and zstd: its CRC cannot be "
                    "computed")


def _crc_of(file: BinaryIO, length: int, crc: int, at: int | None = None) -> int:
    """`crc` continued over the next `length` bytes of `file` (from byte `at`, if given), read in pieces."""
    if at is not None:
        file.seek(at)
    while length > 0:
        piece = file.read(min(length, _READ_PIECE))
        if not piece:
            raise McapError(f"{getattr(file, 'name', 'the file')} is truncated: it ends at byte {file.tell()}")
        crc = zlib.crc32(piece, crc)
        length -= len(piece)
    return crc


FileIdentity = tuple[int, int, int, int]


def _identity(file: BinaryIO) -> FileIdentity:
    """(device, inode, size, modification time in ns) of an open file: another file, or this one written, differs."""
    status = os.fstat(file.fileno())
    return status.st_dev, status.st_ino, status.st_size, status.st_mtime_ns


def _write_mcap_crcs(file: BinaryIO, path: Path, planned: FileIdentity, patches: list[list[Patch]]) -> None:
    """Write each group of CRC patches and flush it to the disk before the next; first check that the file is the one
    planned (`planned`: its _identity then), unchanged, and every field still holds the value the plan read."""
    if _identity(file) != planned:
        raise McapError(f"{path} was replaced or written while its CRCs were computed: nothing was written; try again "
                        "once nothing else writes it")
    for position, now, _ in (patch for group in patches for patch in group):
        file.seek(position)
        if file.read(4) != struct.pack("<I", now):
            raise McapError(f"{path} changed while its CRCs were computed (byte {position}): nothing was written; "
                            "try again once nothing else writes it")
    for group in patches:
        for position, _, value in group:
            file.seek(position)
            file.write(struct.pack("<I", value))
        file.flush()
        os.fsync(file.fileno())
