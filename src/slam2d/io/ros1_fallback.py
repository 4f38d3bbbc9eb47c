"""Sequential reader for ROS 1 bag v2.0 files whose index cannot be trusted.

The indexed reader (``rosbags.rosbag1.Reader``) jumps around the file using the
index records at the end of the bag. When those are damaged (inconsistent index
data lengths, a missing index after a killed ``rosbag record``, a truncated
file) the data itself is usually intact, so this module walks the record
stream from the start instead, one chunk at a time, in constant memory.

The record layout is the public ROS bag v2.0 format: every record is
``header_len (uint32 LE) | header | data_len (uint32 LE) | data``, where the
header is a list of ``field_len (uint32 LE) | name=value`` fields and the
``op`` field gives the record type. Messages come out in the order they were
recorded (receive order), which is roughly time order.
"""

from __future__ import annotations

import bz2
import os
import struct
from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from rosbags.typesys.msg import normalize_msgtype

__all__ = ["Ros1Connection", "Ros1SequentialReader", "BagDamaged", "MAGIC", "TRUNCATED", "DATA_LOSS"]

MAGIC = b"#ROSBAG V2.0\n"

OP_MSG_DATA = 0x02
OP_BAG_HEADER = 0x03
OP_INDEX_DATA = 0x04
OP_CHUNK = 0x05
OP_CHUNK_INFO = 0x06
OP_CONNECTION = 0x07

#: Problem kinds. A cut-off tail is the normal end of a killed recording; the
#: others lose data in the middle of the bag.
TRUNCATED = "bag truncated (kept the complete messages before the cut)"
SKIPPED_BYTES = "damaged bytes skipped in bag"
BAD_CHUNK = "damaged chunk: rest of it skipped"
UNREADABLE_CHUNK = "unreadable chunk skipped"
BAD_CONNECTION = "unreadable connection record skipped"
BAD_MESSAGE = "message with unknown connection or time skipped"
INDEX_LENGTH = "bag index record states a wrong length (read by its entry count, as rosbag does)"
DATA_LOSS = frozenset({SKIPPED_BYTES, BAD_CHUNK, UNREADABLE_CHUNK, BAD_CONNECTION, BAD_MESSAGE})

_UINT32 = struct.Struct("<I")
_UINT64 = struct.Struct("<Q")
_TIME = struct.Struct("<II")

# A record header is a handful of short fields; anything far larger is garbage
# (and must not make us allocate gigabytes).
_MAX_HEADER_LEN = 1 << 20
# Bigger than any sane chunk (rosbag record defaults to 768 KB) or message.
_MAX_DATA_LEN = 1 << 31
# How far past a damaged record we look for the next chunk before giving up.
_RESYNC_BLOCK = 1 << 20
# A chunk header holds 'compression', 'op' and 'size'; the op field is at most
# this many bytes after the record start.
_MAX_CHUNK_HEADER_BEFORE_OP = 64


class BagDamaged(Exception):
    """The record stream is unreadable at byte ``offset``; ``truncated`` if the file ends there."""

    def __init__(self, message: str, offset: int, *, truncated: bool = False) -> None:
        super().__init__(message)
        self.offset = offset
        self.truncated = truncated


@dataclass(frozen=True)
class Ros1Connection:
    """A connection record: one topic published with one message type."""

    id: int
    topic: str
    msgtype: str  # ROS 2 style, e.g. "sensor_msgs/msg/LaserScan"
    md5sum: str
    msgdef: str
    callerid: str = ""
    latching: bool = False


def parse_header(buf: bytes | memoryview, offset: int = 0) -> dict[str, bytes]:
    """Split a record header into its ``name=value`` fields.

    Raises ``ValueError`` when the fields do not tile the header exactly.
    """
    fields: dict[str, bytes] = {}
    pos = 0
    size = len(buf)
    while pos < size:
        if pos + 4 > size:
            raise ValueError(f"header field length cut off at byte {offset + pos}")
        (flen,) = _UINT32.unpack_from(buf, pos)
        pos += 4
        if flen > size - pos:
            raise ValueError(f"header field of {flen} bytes overruns the header at byte {offset + pos}")
        item = bytes(buf[pos : pos + flen])
        pos += flen
        name, sep, value = item.partition(b"=")
        if not sep:
            raise ValueError(f"header field without '=' at byte {offset + pos - flen}")
        fields[name.decode("ascii", "replace")] = value
    return fields


def _op(fields: dict[str, bytes]) -> int:
    op = fields.get("op")
    if op is None or len(op) != 1:
        raise ValueError("record header has no one-byte 'op' field")
    return op[0]


def _uint32(fields: dict[str, bytes], name: str) -> int:
    value = fields.get(name)
    if value is None or len(value) != 4:
        raise ValueError(f"record header field {name!r} is missing or not a uint32")
    return _UINT32.unpack(value)[0]


def _time_ns(fields: dict[str, bytes], name: str) -> int:
    value = fields.get(name)
    if value is None or len(value) != 8:
        raise ValueError(f"record header field {name!r} is missing or not a time")
    sec, nsec = _TIME.unpack(value)
    return sec * 1_000_000_000 + nsec


def _string(fields: dict[str, bytes], name: str, default: str | None = None) -> str:
    value = fields.get(name)
    if value is None:
        if default is not None:
            return default
        raise ValueError(f"record header field {name!r} is missing")
    return value.decode("utf-8", "replace")


def _connection(fields: dict[str, bytes], data: bytes) -> Ros1Connection:
    """A connection from its record header (conn, topic) and data (a second header)."""
    inner = parse_header(data)
    topic = _string(fields, "topic")
    latching = _string(inner, "latching", "0").strip() in ("1", "true")
    return Ros1Connection(
        id=_uint32(fields, "conn"),
        # The same normalisation rosbags applies, so both readers agree on names.
        topic="/" * topic.startswith("/") + "/".join(p for p in topic.split("/") if p),
        msgtype=normalize_msgtype(_string(inner, "type")),
        md5sum=_string(inner, "md5sum", ""),
        msgdef=_string(inner, "message_definition", ""),
        callerid=_string(inner, "callerid", ""),
        latching=latching,
    )


def _decompress_partial(compression: str, data: bytes) -> bytes:
    """Decompress as much of a (possibly cut-off) chunk as can be recovered."""
    if compression == "none":
        return data
    if compression == "bz2":
        return bz2.BZ2Decompressor().decompress(data)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.LZ4FrameDecompressor().decompress(data)
    raise ValueError(f"unknown chunk compression {compression!r}")


#: ``problem(kind, example, byte offset or None)``; it may raise to stop the read.
ProblemCallback = Callable[[str, str, "int | None"], None]


class Ros1SequentialReader:
    """Walk a ROS 1 bag v2.0 record by record, ignoring its index.

    ``problem(kind, example, offset)`` is called for every defect found (a
    cut-off tail, skipped damaged bytes, inconsistent index records); the
    caller decides whether to count it or stop (kinds in :data:`DATA_LOSS`
    lose data in the middle of the bag). Each distinct defect is
    reported once however many times the file is walked.
    """

    def __init__(self, path: str | Path, problem: ProblemCallback | None = None) -> None:
        self.path = Path(path)
        self._report: ProblemCallback = problem or (lambda kind, example, offset: None)
        self._reported: set[tuple[str, str]] = set()
        self.size = os.path.getsize(self.path)
        self.connections: dict[int, Ros1Connection] = {}
        self.counts: Counter[int] = Counter()
        self.index_pos = 0
        with open(self.path, "rb") as f:
            if f.read(len(MAGIC)) != MAGIC:
                raise BagDamaged("not a ROS 1 bag v2.0 (the first line is not '#ROSBAG V2.0')", 0)
            fields, _, data_len = self._record_header(f)
            if _op(fields) != OP_BAG_HEADER:
                raise BagDamaged("the first record is not the bag header", len(MAGIC))
            self.index_pos = (
                _UINT64.unpack(fields["index_pos"])[0] if len(fields.get("index_pos", b"")) == 8 else 0
            )
            self.data_start = f.tell() + data_len

    def problem(self, kind: str, example: str, offset: int | None = None) -> None:
        # The file is walked more than once (metadata, tf discovery, the read
        # itself); each defect is reported the first time only.
        if (kind, example) not in self._reported:
            self._reported.add((kind, example))
            self._report(kind, example, offset)

    # -- metadata -----------------------------------------------------------------

    def read_metadata(self) -> None:
        """Fill :attr:`connections` and :attr:`counts` (messages per connection).

        Uses the connection and chunk-info records of the index section when
        they parse; otherwise (no index, or it is cut off) walks the whole file.
        """
        if self._read_index_section():
            return
        self.connections.clear()
        self.counts.clear()
        for conn, _, _ in self.messages():
            self.counts[conn.id] += 1

    def _read_index_section(self) -> bool:
        if not (len(MAGIC) < self.index_pos < self.size):
            return False
        connections: dict[int, Ros1Connection] = {}
        counts: Counter[int] = Counter()
        try:
            with open(self.path, "rb") as f:
                f.seek(self.index_pos)
                while f.tell() < self.size:
                    fields, start, data_len = self._record_header(f)
                    data = f.read(data_len)
                    if len(data) != data_len:
                        return False
                    op = _op(fields)
                    if op == OP_CONNECTION:
                        conn = _connection(fields, data)
                        connections[conn.id] = conn
                    elif op == OP_CHUNK_INFO:
                        n = _uint32(fields, "count")
                        if len(data) < 8 * n:
                            return False
                        for k in range(n):
                            cid, cnt = struct.unpack_from("<II", data, 8 * k)
                            counts[cid] += cnt
                    else:
                        return False
        except (BagDamaged, ValueError, KeyError, struct.error):
            return False
        if not connections:
            return False
        self.connections = connections
        self.counts = counts
        return True

    def only_index_lengths_wrong(self) -> bool:
        """True when the bag is whole and its one defect is index data records stating a wrong length.

        rosbag reads those records by their entry count and the bag plays; an indexed reader that trusts
        the length fails on them. Walks the record headers up to the index section (chunks are skipped,
        not read): cheap.
        """
        if not (len(MAGIC) < self.index_pos < self.size):
            return False
        wrong = 0
        try:
            with open(self.path, "rb") as f:
                f.seek(self.data_start)
                while f.tell() < self.index_pos:
                    fields, _, data_len = self._record_header(f)
                    if _op(fields) == OP_INDEX_DATA and _uint32(fields, "ver") == 1:
                        count = _uint32(fields, "count")
                        if data_len != 12 * count:
                            wrong += 1
                            data_len = 12 * count
                    f.seek(data_len, os.SEEK_CUR)
                return wrong > 0 and f.tell() == self.index_pos
        except (BagDamaged, ValueError, KeyError, OSError):
            return False

    # -- records --------------------------------------------------------------------

    def _record_header(self, f: BinaryIO) -> tuple[dict[str, bytes], int, int]:
        """Read one record's header and data length; the file is left at the data."""
        start = f.tell()
        raw = f.read(4)
        if len(raw) < 4:
            raise BagDamaged("file ends inside a record header", start, truncated=True)
        (header_len,) = _UINT32.unpack(raw)
        if header_len > _MAX_HEADER_LEN:
            raise BagDamaged(f"implausible record header length {header_len}", start)
        header = f.read(header_len)
        raw = f.read(4)
        if len(header) < header_len or len(raw) < 4:
            raise BagDamaged("file ends inside a record header", start, truncated=True)
        try:
            fields = parse_header(header, start + 4)
            _op(fields)
        except ValueError as exc:
            raise BagDamaged(str(exc), start) from None
        (data_len,) = _UINT32.unpack(raw)
        return fields, start, data_len

    def _resync(self, f: BinaryIO, offset: int) -> int | None:
        """Offset of the next plausible chunk record after ``offset``, or None."""
        # Writers order the chunk header fields differently (rosbag sorts them,
        # rosbags puts 'op' first), so find the op field and try the few record
        # starts that could precede it.
        needle = b"op=" + bytes([OP_CHUNK])
        pos = offset + 1
        while pos < self.size:
            f.seek(pos)
            block = f.read(_RESYNC_BLOCK + len(needle))
            if not block:
                return None
            at = block.find(needle)
            while at >= 0:
                hit = pos + at
                for back in range(8, 8 + _MAX_CHUNK_HEADER_BEFORE_OP):
                    candidate = hit - back
                    if candidate <= offset:
                        break
                    f.seek(candidate)
                    try:
                        fields, _, _ = self._record_header(f)
                    except BagDamaged:
                        continue
                    if _op(fields) == OP_CHUNK and "compression" in fields and "size" in fields:
                        return candidate
                at = block.find(needle, at + 1)
            pos += _RESYNC_BLOCK
        return None

    def messages(self) -> Iterator[tuple[Ros1Connection, int, bytes]]:
        """``(connection, bag time in ns, raw ROS 1 message bytes)`` in file order."""
        with open(self.path, "rb") as f:
            f.seek(self.data_start)
            while f.tell() < self.size:
                try:
                    fields, start, data_len = self._record_header(f)
                except BagDamaged as exc:
                    if exc.truncated:
                        self.problem(
                            TRUNCATED,
                            f"last {self.size - exc.offset} bytes are an incomplete record",
                        )
                        return
                    resume = self._resync(f, exc.offset)
                    skipped = (resume if resume is not None else self.size) - exc.offset
                    self.problem(
                        SKIPPED_BYTES,
                        f"{skipped} bytes at offset {exc.offset}: {exc}",
                        exc.offset,
                    )
                    if resume is None:
                        return
                    f.seek(resume)
                    continue
                op = _op(fields)
                if op == OP_CHUNK:
                    yield from self._chunk(f, fields, start, data_len)
                elif op == OP_INDEX_DATA:
                    self._skip_index_data(f, fields, start, data_len)
                elif op in (OP_CONNECTION, OP_MSG_DATA):
                    data = f.read(data_len)
                    if len(data) < data_len:
                        self.problem(
                            TRUNCATED,
                            f"record at offset {start} (op {op}) is cut off",
                        )
                        return
                    if op == OP_CONNECTION:
                        self._add_connection(fields, data, start)
                    else:
                        # Messages belong in chunks, but v2.0 readers accept them here too.
                        msg = self._message(fields, data, start)
                        if msg is not None:
                            yield msg
                else:
                    # Bag header, chunk info, or an unknown record: skip its data.
                    if f.tell() + data_len > self.size:
                        self.problem(
                            TRUNCATED,
                            f"record at offset {start} (op {op}) is cut off",
                        )
                        return
                    f.seek(data_len, os.SEEK_CUR)

    def _skip_index_data(self, f: BinaryIO, fields: dict[str, bytes], start: int, data_len: int) -> None:
        # Version 1 index data holds 12 bytes (time, offset) per message. Some
        # writers stored a data length that disagrees with the count (the
        # laser_scan_matcher demo bag does); the count is what the format
        # defines, so trust it and note the disagreement.
        try:
            ver = _uint32(fields, "ver")
            count = _uint32(fields, "count")
        except ValueError:
            ver, count = 0, 0
        if ver == 1 and data_len != 12 * count:
            self.problem(
                INDEX_LENGTH,
                f"index data at offset {start}: length {data_len} for {count} entries",
            )
            data_len = 12 * count
        f.seek(data_len, os.SEEK_CUR)

    def _add_connection(self, fields: dict[str, bytes], data: bytes, offset: int) -> None:
        try:
            conn = _connection(fields, data)
        except (ValueError, KeyError) as exc:
            self.problem(BAD_CONNECTION, f"offset {offset}: {exc}", offset)
            return
        self.connections.setdefault(conn.id, conn)

    def _message(
        self, fields: dict[str, bytes], data: bytes, offset: int
    ) -> tuple[Ros1Connection, int, bytes] | None:
        try:
            conn = self.connections[_uint32(fields, "conn")]
            time_ns = _time_ns(fields, "time")
        except (ValueError, KeyError) as exc:
            self.problem(BAD_MESSAGE, f"offset {offset}: {exc}", offset)
            return None
        return conn, time_ns, data

    def _chunk(
        self, f: BinaryIO, fields: dict[str, bytes], start: int, data_len: int
    ) -> Iterator[tuple[Ros1Connection, int, bytes]]:
        compression = _string(fields, "compression", "none")
        raw = f.read(data_len)
        truncated = len(raw) < data_len
        try:
            if truncated:
                data = _decompress_partial(compression, raw)
            elif compression == "none":
                data = raw
            elif compression == "bz2":
                data = bz2.decompress(raw)
            elif compression == "lz4":
                import lz4.frame

                data = lz4.frame.decompress(raw)
            else:
                raise ValueError(f"unknown chunk compression {compression!r}")
        except (OSError, ValueError, RuntimeError, EOFError) as exc:
            self.problem(UNREADABLE_CHUNK, f"chunk at offset {start}: {exc}", start)
            return
        del raw
        view = memoryview(data)
        pos = 0
        size = len(view)
        kept = 0
        while pos < size:
            # Records inside a chunk: connections and message data.
            if pos + 4 > size:
                break
            (header_len,) = _UINT32.unpack_from(view, pos)
            end_header = pos + 4 + header_len
            if header_len > _MAX_HEADER_LEN or end_header + 4 > size:
                break
            try:
                inner = parse_header(view[pos + 4 : end_header], start)
                op = _op(inner)
            except ValueError as exc:
                self.problem(BAD_CHUNK, f"chunk at offset {start}: {exc}", start)
                return
            (inner_len,) = _UINT32.unpack_from(view, end_header)
            body_start = end_header + 4
            if body_start + inner_len > size:
                break
            body = bytes(view[body_start : body_start + inner_len])
            pos = body_start + inner_len
            if op == OP_MSG_DATA:
                msg = self._message(inner, body, start)
                if msg is not None:
                    kept += 1
                    yield msg
            elif op == OP_CONNECTION:
                self._add_connection(inner, body, start)
        if pos < size or truncated:
            if truncated:
                self.problem(
                    TRUNCATED,
                    f"chunk at offset {start} cut after {len(data)} of its bytes; "
                    f"{kept} complete messages kept from it",
                )
            else:
                self.problem(BAD_CHUNK, f"chunk at offset {start}: last record cut off", start)
        if truncated:
            # Nothing after a cut-off chunk can be read.
            f.seek(self.size)
