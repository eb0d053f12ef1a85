"""Read MCAP logs (ROS 2 bags with the mcap storage plugin, ROS 1 bags converted to MCAP,
Foxglove recordings).

Topics are chosen by *schema*, never by name. The file is streamed record by record (constant
memory in the file size: only floats of the chosen channels are kept), so a recording cut off
mid-write (no summary, no footer) is read up to the cut with a warning.

Supported schemas and the role they fill:

* ``sensor_msgs/msg/Imu`` -> IMU (gyro, accel; a fast CDR path, no generic decoding)
* ``sensor_msgs/msg/NavSatFix``, ``gps_msgs/msg/GPSFix``, ``foxglove.LocationFix`` (protobuf
  or JSON), ``nmea_msgs/msg/Sentence`` (parsed by :mod:`fgins.io.nmea`) -> GNSS fixes
* ``geometry_msgs/msg/TwistWithCovarianceStamped`` / ``TwistStamped`` -> GNSS ENU velocity
* ``sensor_msgs/msg/FluidPressure`` -> barometer (Pa)

ROS 1 messages (``ros1`` encoding, ``ros1msg`` schemas named ``sensor_msgs/Imu`` etc., what
``mcap convert`` makes of a ``.bag``) fill the same roles: their names are read as the ROS 2
ones (``pkg/Type`` -> ``pkg/msg/Type``; ROS 1's ``gps_common/GPSFix`` is ``gps_msgs/msg/GPSFix``
with the same fields), the IMU through a fast ROS 1 path, the rest through rosbags' ROS 1
deserializer. :mod:`fgins.io.rosbag` feeds ROS 1 ``.bag`` files and ROS 2 SQLite bags
through the same scan.
"""

from __future__ import annotations

import json
import math
import os
import struct
import tempfile
import zlib
from array import array
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.exceptions import InvalidMagic
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, DataEnd, Footer, Message, MessageIndex, Schema
from mcap.stream_reader import StreamReader

from fgins.datatypes import BaroData, Dataset, GnssData, ImuData, InputError, Origin
from fgins.io.imu_checks import imu_from_samples

IMU_SCHEMAS = frozenset({"sensor_msgs/msg/Imu"})
NAVSATFIX = "sensor_msgs/msg/NavSatFix"
GPSFIX = "gps_msgs/msg/GPSFix"
LOCATIONFIX = "foxglove.LocationFix"
NMEA_SENTENCE = "nmea_msgs/msg/Sentence"
FIX_SCHEMAS = frozenset({NAVSATFIX, GPSFIX, LOCATIONFIX, NMEA_SENTENCE})
VELOCITY_SCHEMAS = frozenset(
    {"geometry_msgs/msg/TwistWithCovarianceStamped", "geometry_msgs/msg/TwistStamped"}
)
BARO_SCHEMAS = frozenset({"sensor_msgs/msg/FluidPressure"})

ROLE_IMU, ROLE_GNSS, ROLE_VELOCITY, ROLE_BARO = "imu", "gnss", "gnss velocity", "baro"

# NavSatFix / LocationFix position_covariance_type: 0 = unknown (ignore the numbers).
COVARIANCE_TYPE_UNKNOWN = 0
# sensor_msgs/NavSatStatus and gps_msgs/GPSStatus: < 0 is "no fix"; SBAS/GBAS/DGPS are
# differential (NMEA GGA quality 2); plain fix is autonomous (quality 1).
NAVSAT_STATUS_TO_QUALITY = {0: 1, 1: 2, 2: 2, 18: 2, 33: 2}

_PROGRESS_EVERY_RECORDS = 4096

# Channel metadata that marks channels fgins wrote (see fgins.io.mcap_writer).
PRODUCER_KEY, PRODUCER_FGINS = "producer", "fgins"


@dataclass
class McapResult:
    """What :func:`read_mcap` returns: the data and human-readable lines about how it was read."""

    dataset: Dataset
    report: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


# ROS 1 packages whose messages are the ROS 2 ones under another package name.
_ROS1_PACKAGE_ALIASES = {"gps_common": "gps_msgs"}


def ros2_type_name(name: str) -> str:
    """A message type name as ROS 2 spells it: ROS 1's ``sensor_msgs/Imu`` (and rosbags'
    ``sensor_msgs/msg/Imu``) -> ``sensor_msgs/msg/Imu``; other names unchanged."""
    parts = name.split("/")
    if len(parts) == 2 and all(parts):
        package = _ROS1_PACKAGE_ALIASES.get(parts[0], parts[0])
        return f"{package}/msg/{parts[1]}"
    if len(parts) == 3 and parts[1] == "msg" and parts[0] in _ROS1_PACKAGE_ALIASES:
        return f"{_ROS1_PACKAGE_ALIASES[parts[0]]}/msg/{parts[2]}"
    return name


def role_of_schema(schema_name: str) -> str | None:
    """The sensor role a schema fills, or None when fgins does not use it."""
    schema_name = ros2_type_name(schema_name)
    if schema_name in IMU_SCHEMAS:
        return ROLE_IMU
    if schema_name in FIX_SCHEMAS:
        return ROLE_GNSS
    if schema_name in VELOCITY_SCHEMAS:
        return ROLE_VELOCITY
    if schema_name in BARO_SCHEMAS:
        return ROLE_BARO
    return None


# --------------------------------------------------------------------------------------------
# Streaming over records, robust to torn files
# --------------------------------------------------------------------------------------------


class _ByteProgress:
    """A tqdm bar over the bytes consumed from a file (a no-op when disabled)."""

    def __init__(self, file: Any, total: int, enabled: bool, label: str) -> None:
        self._file = file
        self._bar = None
        self._last = 0
        if enabled:
            from tqdm import tqdm

            self._bar = tqdm(total=total, unit="B", unit_scale=True, desc=label, leave=False)

    def update(self) -> None:
        if self._bar is not None:
            position = self._file.tell()
            self._bar.update(position - self._last)
            self._last = position

    def close(self) -> None:
        if self._bar is not None:
            self.update()
            self._bar.close()


@dataclass
class _DamagedChunk:
    """A complete chunk record whose content is damaged (corrupt bytes inside it)."""

    at: int  # file offset of the chunk record
    why: str
    read: int = 0  # messages read from it, before the damage
    dropped: int = 0  # messages parsed but not used (a failed CRC: no message trusted)
    indexed: int = 0  # messages its message-index records list (0: no index)


@dataclass
class _StreamOutcome:
    truncated: bool = False
    error: str = ""
    has_footer: bool = False
    has_summary: bool = False
    cut_at: int = 0  # file size of a truncated file (the byte it was cut at)
    torn_chunk: str = ""  # how much of the chunk the cut went through could be read
    messages: int = 0
    last_log_time_ns: int | None = None
    damaged: list[_DamagedChunk] = field(default_factory=list)
    # A top-level record that does not parse in a file that ends with its magic: corrupt
    # bytes, not a cut; nothing after it can be framed (-1: none).
    damaged_record_at: int = -1
    # The DataEnd record was read: every message is before it, damage after it is in the
    # summary section (channels and counts repeated for indexed readers), not in the data.
    data_end_seen: bool = False


_CHUNK_OPCODE = 0x06
_MESSAGE_OPCODE = 0x05
_SCHEMA_OPCODE = 0x03
_CHANNEL_OPCODE = 0x04


def _decompress_prefix(compression: str, data: bytes) -> tuple[bytes, str]:
    """As much of a torn chunk's records as its compressed prefix gives, and the bound.

    Uncompressed chunks give every byte before the cut. zstd and lz4 frames decode block by
    block, so a streaming decompressor returns everything up to the last complete compressed
    block: at most one block (zstd <= 128 KiB, lz4 64 KiB to 4 MiB by the frame's block size)
    of messages before the cut is lost.
    """
    if compression == "":
        return data, "uncompressed: every message before the cut"
    try:
        if compression == "zstd":
            import zstandard

            out = zstandard.ZstdDecompressor().decompressobj().decompress(data)
            return out, "zstd: up to the last complete compressed block (<= 128 KiB)"
        if compression == "lz4":
            import lz4.frame

            decompressor = lz4.frame.LZ4FrameDecompressor()
            return decompressor.decompress(data), "lz4: up to the last complete lz4 block"
    except Exception as exc:
        return b"", f"{compression}: nothing decodable ({type(exc).__name__})"
    return b"", f"compression {compression!r} not supported for a torn chunk"


class _ChunkDamage(Exception):
    """Raised by :func:`_chunk_records` at the first damaged record of a chunk."""

    def __init__(self, offset: int, why: str) -> None:
        super().__init__(why)
        self.offset = offset


def _chunk_records(data: bytes, offset: int) -> Iterator[Any]:
    """The Schema/Channel/Message records of a chunk's (decompressed) records from byte
    ``offset`` on, in order. Raises :class:`_ChunkDamage` at the first one that does not
    parse: a header cut at the end, a length past the end, or bytes that are no Schema,
    Channel or Message record (a chunk holds only these)."""
    from io import BytesIO

    from mcap.data_stream import ReadDataStream

    while offset < len(data):
        if offset + 9 > len(data):
            raise _ChunkDamage(offset, f"a record header cut at byte {offset} of {len(data)}")
        opcode = data[offset]
        (length,) = struct.unpack_from("<Q", data, offset + 1)
        end = offset + 9 + length
        if opcode not in (_MESSAGE_OPCODE, _SCHEMA_OPCODE, _CHANNEL_OPCODE):
            raise _ChunkDamage(offset, f"no record at byte {offset} of {len(data)}")
        if end > len(data):
            raise _ChunkDamage(offset, f"a record at byte {offset} of {len(data)} runs past it")
        stream = ReadDataStream(BytesIO(data[offset + 9 : end]))
        try:
            if opcode == _MESSAGE_OPCODE:
                record: Any = Message.read(stream, length)
            elif opcode == _SCHEMA_OPCODE:
                record = Schema.read(stream)
            else:
                record = Channel.read(stream)
        except Exception:  # mcap raises EndOfFile, struct and decoding errors
            why = f"an unreadable record at byte {offset} of {len(data)}"
            raise _ChunkDamage(offset, why) from None
        yield record
        offset = end


# Message record header: opcode (1), length (8), channel id (2), sequence (4), log time (8),
# publish time (8); then the message data.
_MESSAGE_HEADER = 9 + 2 + 4 + 8 + 8


def _resync(data: bytes, start: int, chunk: Chunk, channels: set[int]) -> int | None:
    """The offset of the first intact Message record after damage at ``start`` (None: none).

    A candidate must be a Message record of a channel the file declared, with a log time
    inside the chunk's own time range, fit in the chunk, and end where another record (or
    the chunk) begins: corrupt bytes pass all of that by chance about once in 10^10."""
    position = start + 1
    while (position := data.find(b"\x05", position)) >= 0:
        if position + _MESSAGE_HEADER > len(data):
            return None
        (length,) = struct.unpack_from("<Q", data, position + 1)
        end = position + 9 + length
        channel_id, _, log_time = struct.unpack_from("<HIQ", data, position + 9)
        fits = length >= _MESSAGE_HEADER - 9 and end <= len(data)
        in_time = chunk.message_start_time <= log_time <= chunk.message_end_time
        if fits and in_time and channel_id in channels:
            if end == len(data):
                return position
            known = data[end] in (_MESSAGE_OPCODE, _SCHEMA_OPCODE, _CHANNEL_OPCODE)
            if known and end + 9 <= len(data):
                (next_length,) = struct.unpack_from("<Q", data, end + 1)
                if end + 9 + next_length <= len(data):
                    return position
        position += 1
    return None


def _chunk_data(chunk: Chunk) -> tuple[bytes, str]:
    """A chunk's decompressed records, and "" or what is wrong with them (a failed CRC, a
    compressed stream that breaks off: then the prefix the decompressor gave)."""
    data = chunk.data
    problem = ""
    if chunk.compression:
        try:
            if chunk.compression == "zstd":
                import zstandard

                data = zstandard.decompress(chunk.data, chunk.uncompressed_size)
            elif chunk.compression == "lz4":
                import lz4.frame

                data = lz4.frame.decompress(chunk.data)
            else:
                return b"", f"compression {chunk.compression!r} not supported"
        except Exception as exc:
            data, _ = _decompress_prefix(chunk.compression, chunk.data)
            problem = f"{chunk.compression} data do not decompress ({type(exc).__name__})"
    if not problem and len(data) != chunk.uncompressed_size:
        problem = f"{len(data)} bytes where the chunk header says {chunk.uncompressed_size}"
    elif not problem and chunk.uncompressed_crc and zlib.crc32(data) != chunk.uncompressed_crc:
        problem = CRC_FAILED
    return data, problem


CRC_FAILED = "its CRC fails"


def _open_chunk(
    chunk: Chunk, at: int, outcome: _StreamOutcome, channels: set[int]
) -> Iterator[Any]:
    """The records of one complete chunk record (``at``: its file offset). In a damaged one
    the records before the damage are read (the last message before it dropped: the damage
    may begin inside it), the damaged bytes skipped to the next intact message record, and
    the chunk counted in ``outcome.damaged``. A chunk whose CRC fails gives its Schema and
    Channel records only: its messages are damaged somewhere, none can be trusted."""
    data, problem = _chunk_data(chunk)
    crc_failed = problem == CRC_FAILED
    records: list[Any] = []
    offset, skipped, regions = 0, 0, 0
    while True:
        try:
            records.extend(_chunk_records(data, offset))
            break
        except _ChunkDamage as exc:
            regions += 1
            if regions == 1:
                problem = f"{problem}; {exc}" if problem else str(exc)
            for k in range(len(records) - 1, -1, -1):
                if isinstance(records[k], Message):
                    del records[k]  # the message just before the damage: maybe damaged too
                    break
            channels.update(r.id for r in records if isinstance(r, Channel))
            resume = _resync(data, exc.offset, chunk, channels)
            skipped += (len(data) if resume is None else resume) - exc.offset
            if resume is None:
                break
            offset = resume
    if not problem:
        yield from records
        return
    if regions:
        problem += f" ({skipped} damaged byte(s) skipped in {regions} place(s))"
    damage = _DamagedChunk(at=at, why=problem)
    outcome.damaged.append(damage)
    for record in records:
        if isinstance(record, Message):
            if crc_failed:
                damage.dropped += 1
                continue
            damage.read += 1
        yield record


def _damage_warning(path: Path, outcome: _StreamOutcome) -> str:
    """One counted warning for the damaged chunks of a file ("" when there is none)."""
    if not outcome.damaged:
        return ""
    parts = []
    for damage in outcome.damaged[:3]:
        text = f"the chunk at byte {damage.at}: {damage.why}; {damage.read} message(s) read"
        lost = damage.indexed - damage.read
        if damage.indexed and lost > 0:
            text += f", {lost} of its {damage.indexed} lost"
        if damage.dropped:
            text += f" ({damage.dropped} parsed but none trusted)"
        parts.append(text)
    more = f"; and {len(outcome.damaged) - 3} more" if len(outcome.damaged) > 3 else ""
    return (
        f"{path}: {len(outcome.damaged)} damaged chunk(s) (corrupt bytes inside the "
        f"recording; the rest of the file is read): {'; '.join(parts)}{more}"
    )


def _records_in_torn_chunk(body: bytes, outcome: _StreamOutcome) -> Iterator[Any]:
    """The complete Schema/Channel/Message records inside a chunk cut off by the file's end."""


    head = 8 + 8 + 8 + 4
    if len(body) < head + 4:
        outcome.torn_chunk = "cut inside the chunk header: no message of that chunk"
        return
    (name_len,) = struct.unpack_from("<I", body, head)
    start = head + 4 + name_len + 8
    if len(body) < start:
        outcome.torn_chunk = "cut inside the chunk header: no message of that chunk"
        return
    compression = body[head + 4 : head + 4 + name_len].decode("utf-8", "replace")
    data, bound = _decompress_prefix(compression, body[start:])
    outcome.torn_chunk = bound
    try:
        yield from _chunk_records(data, 0)
    except _ChunkDamage:
        return  # the record the cut went through (or corrupt bytes: nothing after them)


def _stream_records(
    path: Path, outcome: _StreamOutcome, progress: bool, label: str
) -> Iterator[Any]:
    """Yield every record of the data section (chunks opened); at a torn end, every complete
    message before the cut, inside a torn chunk too (see :func:`_decompress_prefix`)."""
    size = path.stat().st_size
    with open(path, "rb") as file:
        bar = _ByteProgress(file, size, progress, label)
        try:
            # emit_chunks: the chunks are opened here, so the byte offset after each complete
            # top-level record is known and a torn one can be read record by record.
            reader = StreamReader(file, emit_chunks=True, record_size_limit=1 << 31)
            records = reader.records
            count = 0
            next_record_at = 8  # after the magic
            last_chunk_at = -1  # the chunk the message-index records that follow belong to
            channels: set[int] = set()  # ids of the channels declared so far
            while True:
                try:
                    record = next(records)
                except StopIteration:
                    break
                except InvalidMagic as exc:
                    if count == 0:
                        raise InputError(
                            f"{path}: not an MCAP file (bad magic bytes); give a .mcap recording"
                        ) from exc
                    outcome.truncated, outcome.error = True, f"bad magic at end: {exc}"
                    break
                except Exception as exc:
                    # mcap raises on the torn last record of a recording that was cut off
                    # (EndOfFile, struct errors, ...): everything before it is intact.
                    outcome.truncated = True
                    outcome.error = f"{type(exc).__name__}: {exc}"
                    if _ends_with_magic(file, size):  # a complete file: damage, not a cut
                        outcome.damaged_record_at = next_record_at
                    yield from _count(_torn_tail(file, next_record_at, size, outcome), outcome)
                    break
                record_at, next_record_at = next_record_at, file.tell()
                count += 1
                if isinstance(record, MessageIndex):
                    if outcome.damaged and outcome.damaged[-1].at == last_chunk_at:
                        outcome.damaged[-1].indexed += len(record.records)
                elif not isinstance(record, Chunk):
                    last_chunk_at = -1
                if isinstance(record, DataEnd):
                    outcome.data_end_seen = True
                if isinstance(record, Footer):
                    outcome.has_footer = True
                    outcome.has_summary = record.summary_start != 0
                if count % _PROGRESS_EVERY_RECORDS == 0:
                    bar.update()
                if isinstance(record, Chunk):
                    last_chunk_at = record_at
                    for inner in _count(_open_chunk(record, record_at, outcome, channels), outcome):
                        if isinstance(inner, Channel):
                            channels.add(inner.id)
                        yield inner
                else:
                    if isinstance(record, Channel):
                        channels.add(record.id)
                    yield from _count((record,), outcome)
        finally:
            bar.close()
    if outcome.truncated:
        outcome.cut_at = size


def _ends_with_magic(file: Any, size: int) -> bool:
    """Whether the file ends with the closing MCAP magic (it was written to the end)."""
    if size < 16:
        return False
    file.seek(size - 8)
    return bool(file.read(8) == b"\x89MCAP0\r\n")


def _count(records: Any, outcome: _StreamOutcome) -> Iterator[Any]:
    for record in records:
        if isinstance(record, Message):
            outcome.messages += 1
            outcome.last_log_time_ns = record.log_time
        yield record


def _torn_tail(file: Any, offset: int, size: int, outcome: _StreamOutcome) -> Iterator[Any]:
    """Records of the top-level record the cut went through (a chunk: its complete messages)."""
    file.seek(offset)
    head = file.read(9)
    if len(head) < 9:
        return
    opcode = head[0]
    if opcode == _CHUNK_OPCODE:
        yield from _records_in_torn_chunk(file.read(size - offset - 9), outcome)


def _read_summary(path: Path) -> Any:
    """The summary section (channels, schemas, statistics), or None when there is none."""
    try:
        with open(path, "rb") as file:
            summary = make_reader(file).get_summary()
    except Exception:  # a torn or foreign file: fall back to choosing while streaming
        return None
    if summary is None or summary.statistics is None:
        return None
    return summary


def _check_magic(path: Path) -> None:
    if not path.is_file():
        raise InputError(f"{path}: no such file; check the path")
    with open(path, "rb") as file:
        head = file.read(8)
    if head != b"\x89MCAP0\r\n":
        raise InputError(f"{path}: not an MCAP file (bad magic bytes); give a .mcap recording")


# --------------------------------------------------------------------------------------------
# Decoding
# --------------------------------------------------------------------------------------------


def _make_decoder(schema: Schema | None, channel: Channel) -> Callable[[bytes], Any] | None:
    """A function bytes -> message object for this channel, or None if it cannot be decoded."""
    encoding = channel.message_encoding
    if encoding == "json":
        return json.loads
    if schema is None:
        return None
    if encoding == "cdr" and schema.encoding == "ros2msg":
        from mcap_ros2.decoder import DecoderFactory as Ros2DecoderFactory

        return Ros2DecoderFactory().decoder_for(encoding, schema)
    if encoding == "ros1" and schema.encoding == "ros1msg":
        return _ros1_decoder(schema.name, schema.data.decode("utf-8", errors="replace"))
    if encoding == "protobuf" and schema.encoding == "protobuf":
        try:
            from mcap_protobuf.decoder import DecoderFactory as ProtobufDecoderFactory
        except ImportError:  # optional dependency: report the channel as undecodable
            return None
        return ProtobufDecoderFactory().decoder_for(encoding, schema)
    return None


# sensor_msgs/Imu as every ROS distribution defines it: the fixed layout the fast IMU
# readers assume (field name, type), after the header.
_STANDARD_IMU_FIELDS = (
    ("orientation", "geometry_msgs/msg/Quaternion"), ("orientation_covariance", "float64[9]"),
    ("angular_velocity", "geometry_msgs/msg/Vector3"), ("angular_velocity_covariance", "float64[9]"),
    ("linear_acceleration", "geometry_msgs/msg/Vector3"),
    ("linear_acceleration_covariance", "float64[9]"),
)  # fmt: skip


def _nonstandard_imu(schema: Schema | None) -> str | None:
    """Why an Imu-named channel cannot be read by the fixed-layout IMU readers (its schema
    text defines other fields), or None (standard, or no definition to check)."""
    if schema is None or schema.encoding not in ("ros1msg", "ros2msg"):
        return None  # no .msg text to check (an IDL schema, none)
    text = schema.data.decode("utf-8", errors="replace")
    if not text.strip():
        return None
    fields = []
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if line.startswith("=") or line.startswith("MSG:"):
            break  # the dependencies' definitions follow
        parts = line.split()
        if len(parts) >= 2 and "=" not in line:
            fields.append((parts[1], parts[0]))
    if not fields:
        return None
    names = [name for name, _ in fields]
    expected = [name for name, _ in _STANDARD_IMU_FIELDS]
    types_ok = all(  # ROS 1 and ROS 2 texts spell the packages differently: last part only
        kind.split("/")[-1] == want.split("/")[-1]
        for (_, kind), (_, want) in zip(fields[1:], _STANDARD_IMU_FIELDS, strict=False)
    )
    if names[1:] == expected and names[0] == "header" and types_ok:
        return None
    return (
        f"{schema.name} with a definition other than the standard one (fields "
        f"{', '.join(names[:8])}{' ...' if len(names) > 8 else ''}): not read as an IMU"
    )


def _ros1_decoder(type_name: str, definition: str) -> Callable[[bytes], Any]:
    """bytes -> message for a ROS 1 type from its definition (the concatenated ``gendeps``
    text a bag or MCAP carries), by rosbags' ROS 1 deserializer; header stamps come out as
    ROS 2's ``sec``/``nanosec``."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.EMPTY)
    name = type_name if "/msg/" in type_name else type_name.replace("/", "/msg/", 1)
    store.register(get_types_from_msg(definition, name))
    return lambda data: store.deserialize_ros1(data, name)


def _imu_ros1_reader(data: bytes) -> tuple[int, tuple[float, ...]]:
    """sensor_msgs/Imu from ROS 1 serialization (little endian, packed): header (seq,
    stamp secs/nsecs, frame_id), orientation (4 doubles) and its covariance (9), then
    angular velocity (3), its covariance (9), linear acceleration (3)."""
    sec, nanosec, frame_len = struct.unpack_from("<IIII", data, 0)[1:]
    gyro_at = 16 + frame_len + 13 * 8
    values = struct.unpack_from("<3d9d3d", data, gyro_at)
    return sec * 1_000_000_000 + nanosec, values[:3] + values[12:15]


def _imu_ros1_covariance_diagonals(data: bytes) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Diagonals of angular_velocity_covariance and linear_acceleration_covariance (ROS 1)."""
    frame_len = struct.unpack_from("<I", data, 12)[0]
    gyro_cov_at = 16 + frame_len + 13 * 8 + 3 * 8
    gyro_cov = struct.unpack_from("<9d", data, gyro_cov_at)
    accel_cov = struct.unpack_from("<9d", data, gyro_cov_at + 12 * 8)
    return gyro_cov[0::4], accel_cov[0::4]


def _imu_cdr_reader(data: bytes) -> tuple[int, tuple[float, ...]]:
    """sensor_msgs/msg/Imu from CDR without generic decoding (the high-rate stream).

    Returns (header stamp ns, (gx, gy, gz, ax, ay, az)). CDR aligns 8-byte fields to 8 relative
    to the byte after the 4-byte encapsulation header.
    """
    little = data[1] == 1
    prefix = "<" if little else ">"
    sec, nanosec, frame_len = struct.unpack_from(prefix + "iII", data, 4)
    body = 12 + frame_len
    body = (body + 7) & ~7
    # orientation (4 doubles) + its covariance (9 doubles) precede angular_velocity
    gyro_at = 4 + body + 13 * 8
    accel_at = gyro_at + 12 * 8  # angular_velocity (3) + its covariance (9)
    gyro = struct.unpack_from(prefix + "3d", data, gyro_at)
    accel = struct.unpack_from(prefix + "3d", data, accel_at)
    return sec * 1_000_000_000 + nanosec, gyro + accel


def _imu_cdr_covariance_diagonals(data: bytes) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Diagonals of angular_velocity_covariance and linear_acceleration_covariance (CDR)."""
    little = data[1] == 1
    prefix = "<" if little else ">"
    _sec, _nanosec, frame_len = struct.unpack_from(prefix + "iII", data, 4)
    body = (12 + frame_len + 7) & ~7
    gyro_cov_at = 4 + body + 13 * 8 + 3 * 8
    accel_cov_at = gyro_cov_at + 9 * 8 + 3 * 8
    gyro_cov = struct.unpack_from(prefix + "9d", data, gyro_cov_at)
    accel_cov = struct.unpack_from(prefix + "9d", data, accel_cov_at)
    return gyro_cov[0::4], accel_cov[0::4]


def _get(msg: Any, name: str, default: Any = None) -> Any:
    """Field access for decoded objects (ROS 2, protobuf) and JSON dicts alike."""
    if isinstance(msg, dict):
        return msg.get(name, default)
    return getattr(msg, name, default)


def _ros_stamp_ns(msg: Any) -> int:
    stamp = msg.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _foxglove_stamp_ns(msg: Any) -> int:
    stamp = _get(msg, "timestamp")
    if stamp is None:
        return 0
    if isinstance(stamp, dict):  # JSON: {"sec": .., "nsec": ..}
        return int(stamp.get("sec", 0)) * 1_000_000_000 + int(stamp.get("nsec", 0))
    return int(stamp.seconds) * 1_000_000_000 + int(stamp.nanos)


def _std_from_covariance(covariance: Any, covariance_type: Any) -> tuple[float, float, float]:
    """1-sigma east/north/up from an ENU row-major 3x3 covariance (REP-145 / Foxglove)."""
    if isinstance(covariance_type, str):  # JSON may spell the enum
        covariance_type = 0 if covariance_type.upper() == "UNKNOWN" else 1
    if covariance is None or len(covariance) != 9 or int(covariance_type or 0) == 0:
        return (math.nan, math.nan, math.nan)
    diag = (float(covariance[0]), float(covariance[4]), float(covariance[8]))
    return tuple(math.sqrt(v) if v > 0 else math.nan for v in diag)  # type: ignore[return-value]


# --------------------------------------------------------------------------------------------
# Accumulators: one per chosen channel, Python lists of floats (never messages)
# --------------------------------------------------------------------------------------------


class _Accumulator:
    def __init__(self, topic: str, schema_name: str) -> None:
        self.topic = topic
        self.schema_name = schema_name
        self.t = array("d")
        self.stamp_fallbacks = 0  # header stamp zero -> log time used
        self.decode_errors = 0

    def __len__(self) -> int:
        return len(self.t)

    def time(self, stamp_ns: int, log_time_ns: int, use_header_stamp: bool) -> float:
        if use_header_stamp and stamp_ns > 0:
            return stamp_ns / 1e9
        if use_header_stamp:
            self.stamp_fallbacks += 1
        return log_time_ns / 1e9


class _ImuAccumulator(_Accumulator):
    # Covariances are read from the first messages only: a driver fills them with constants.
    COVARIANCE_SAMPLES = 64

    def __init__(self, topic: str, schema_name: str) -> None:
        super().__init__(topic, schema_name)
        self.values = array("d")  # gx gy gz ax ay az per sample
        self.gyro_var: list[float] = []  # mean diagonal variance per sampled message
        self.accel_var: list[float] = []
        self.read_values = _imu_cdr_reader  # ROS 2 CDR, or ROS 1 (set_encoding)
        self.read_covariances = _imu_cdr_covariance_diagonals

    def set_encoding(self, message_encoding: str) -> None:
        if message_encoding == "ros1":
            self.read_values = _imu_ros1_reader
            self.read_covariances = _imu_ros1_covariance_diagonals

    def add_raw(self, data: bytes, log_time: int, use_header_stamp: bool) -> None:
        stamp, values = self.read_values(data)
        self.t.append(self.time(stamp, log_time, use_header_stamp))
        self.values.extend(values)
        if len(self.t) <= self.COVARIANCE_SAMPLES:
            gyro_diag, accel_diag = self.read_covariances(data)
            self.gyro_var.append(_known_variance(gyro_diag))
            self.accel_var.append(_known_variance(accel_diag))

    def noise_config(self, rate_hz: float) -> dict[str, float]:
        """White-noise densities from the messages' covariances ({} when they carry none).

        sensor_msgs/Imu covariances are per-sample variances: sigma = sqrt(variance), and a
        density of sigma / sqrt(rate) gives that sigma at the sample rate.
        """
        config: dict[str, float] = {}
        for key, variances in (
            ("gyro_noise_rad_per_s_per_sqrt_hz", self.gyro_var),
            ("accel_noise_m_per_s2_per_sqrt_hz", self.accel_var),
        ):
            known = [v for v in variances if math.isfinite(v)]
            if known and rate_hz > 0:
                config[key] = math.sqrt(float(np.median(known))) / math.sqrt(rate_hz)
        return config


def _known_variance(diagonal: tuple[float, ...]) -> float:
    """Mean of a covariance diagonal, NaN when unknown (all zero, or -1: "no such data")."""
    if diagonal[0] == -1.0 or not all(math.isfinite(v) and v > 0 for v in diagonal):
        return math.nan
    return sum(diagonal) / 3.0


class _FixAccumulator(_Accumulator):
    """NavSatFix, GPSFix and LocationFix rows."""

    COLUMNS = ("lat", "lon", "alt", "se", "sn", "su", "quality", "hdop", "vdop", "pdop")
    COLUMNS += ("ve", "vn", "vu", "speed", "course", "sats")

    def __init__(self, topic: str, schema_name: str) -> None:
        super().__init__(topic, schema_name)
        self.rows = array("d")
        self.no_fix = 0
        self.first_t = math.inf  # of any message, with a fix or not (the t0 of outages)

    def add(self, msg: Any, log_time: int, use_header_stamp: bool) -> None:
        nan = math.nan
        velocity = (nan, nan, nan)
        speed = course = nan
        hdop = vdop = pdop = nan
        sats = nan
        if self.schema_name == LOCATIONFIX:
            stamp = _foxglove_stamp_ns(msg)
            quality = 1.0
            vel = _get(msg, "velocity")
            if vel:  # newer LocationFix carries ENU velocity
                velocity = (float(_get(vel, "x", nan)), float(_get(vel, "y", nan)))
                velocity += (float(_get(vel, "z", nan)),)
        else:
            stamp = _ros_stamp_ns(msg)
            status = int(msg.status.status)
            if status < 0:
                self.no_fix += 1
                self.first_t = min(self.first_t, self.time(stamp, log_time, use_header_stamp))
                return
            quality = float(NAVSAT_STATUS_TO_QUALITY.get(status, 1))
            if self.schema_name == GPSFIX:
                hdop, vdop, pdop = float(msg.hdop), float(msg.vdop), float(msg.pdop)
                sats = float(msg.status.satellites_used)
                speed, course = float(msg.speed), float(msg.track)
                track = math.radians(course)
                velocity = (speed * math.sin(track), speed * math.cos(track), float(msg.climb))
        std = _std_from_covariance(
            _get(msg, "position_covariance"), _get(msg, "position_covariance_type", 0)
        )
        lat = float(_get(msg, "latitude", nan))
        lon = float(_get(msg, "longitude", nan))
        alt = float(_get(msg, "altitude", nan))
        t = self.time(stamp, log_time, use_header_stamp)
        self.first_t = min(self.first_t, t)
        if not (math.isfinite(lat) and math.isfinite(lon) and math.isfinite(alt)):
            self.no_fix += 1
            return
        self.t.append(t)
        self.rows.extend((lat, lon, alt, *std, quality, hdop, vdop, pdop, *velocity))
        self.rows.extend((speed, course, sats))


class _VelocityAccumulator(_Accumulator):
    def __init__(self, topic: str, schema_name: str) -> None:
        super().__init__(topic, schema_name)
        self.rows = array("d")  # ve vn vu std_e std_n std_u

    def add(self, msg: Any, log_time: int, use_header_stamp: bool) -> None:
        twist = msg.twist
        std = (math.nan, math.nan, math.nan)
        if self.schema_name.endswith("TwistWithCovarianceStamped"):
            covariance = twist.covariance  # 6x6 row-major, linear part first (ENU per REP-145)
            twist = twist.twist
            diag = (covariance[0], covariance[7], covariance[14])
            std = tuple(math.sqrt(v) if v > 0 else math.nan for v in diag)  # type: ignore[assignment]
        linear = twist.linear
        self.t.append(self.time(_ros_stamp_ns(msg), log_time, use_header_stamp))
        self.rows.extend((float(linear.x), float(linear.y), float(linear.z), *std))


class _BaroAccumulator(_Accumulator):
    def __init__(self, topic: str, schema_name: str) -> None:
        super().__init__(topic, schema_name)
        self.pressure = array("d")

    def add(self, msg: Any, log_time: int, use_header_stamp: bool) -> None:
        self.t.append(self.time(_ros_stamp_ns(msg), log_time, use_header_stamp))
        self.pressure.append(float(msg.fluid_pressure))


class _NmeaAccumulator(_Accumulator):
    """Streams sentences into a temp file for :func:`fgins.io.nmea.read_nmea`."""

    def __init__(self, topic: str, schema_name: str) -> None:
        super().__init__(topic, schema_name)
        handle, name = tempfile.mkstemp(prefix="fgins-mcap-", suffix=".nmea")
        self.file = os.fdopen(handle, "w", encoding="ascii", errors="replace")
        self.path = Path(name)
        self.fix_stamps = array("d")  # stamps of GGA sentences: aligns NMEA time to the bag

    def add(self, msg: Any, log_time: int, use_header_stamp: bool) -> None:
        sentence = str(msg.sentence).strip()
        t = self.time(_ros_stamp_ns(msg), log_time, use_header_stamp)
        self.t.append(t)
        if sentence[3:6] == "GGA":
            self.fix_stamps.append(t)
        self.file.write(sentence + "\n")

    def close(self) -> None:
        if not self.file.closed:
            self.file.close()


_ACCUMULATOR_BY_ROLE: dict[str, type[_Accumulator]] = {
    ROLE_IMU: _ImuAccumulator,
    ROLE_VELOCITY: _VelocityAccumulator,
    ROLE_BARO: _BaroAccumulator,
}


def _new_accumulator(role: str, topic: str, schema_name: str) -> _Accumulator:
    if role == ROLE_GNSS:
        cls = _NmeaAccumulator if schema_name == NMEA_SENTENCE else _FixAccumulator
        return cls(topic, schema_name)
    return _ACCUMULATOR_BY_ROLE[role](topic, schema_name)


# --------------------------------------------------------------------------------------------
# Building the Dataset
# --------------------------------------------------------------------------------------------


def _sorted_unique(t: np.ndarray, label: str, warnings: list[str]) -> np.ndarray | slice:
    """Indices that put ``t`` in strictly increasing order (duplicates dropped, counted).

    The usual case, already increasing, gives a slice: views, no copy of large arrays.
    """
    if t.size < 2 or bool(np.all(np.diff(t) > 0)):
        return slice(None)
    order = np.argsort(t, kind="stable")
    reordered = int(np.count_nonzero(np.diff(t) < 0)) if t.size > 1 else 0
    keep = np.ones(order.size, dtype=bool)
    keep[1:] = np.diff(t[order]) > 0
    dropped = int(order.size - np.count_nonzero(keep))
    if reordered:
        warnings.append(f"{label}: {reordered} time steps backwards; samples sorted by time")
    if dropped:
        warnings.append(f"{label}: {dropped} samples with a repeated timestamp dropped")
    return order[keep]


def _build_imu(acc: _ImuAccumulator, warnings: list[str]) -> ImuData:
    t = np.frombuffer(acc.t, dtype=float)
    values = np.frombuffer(acc.values, dtype=float).reshape(-1, 6)
    if t.size < 2:
        raise InputError(f"imu topic {acc.topic}: fewer than 2 usable samples; check the recording")
    # the one row policy of every reader (NaN rows, reordering, repeated stamps)
    return imu_from_samples(
        t, values[:, :3], values[:, 3:], source=f"imu {acc.topic}", warnings=warnings
    )


def _build_fixes(acc: _FixAccumulator, warnings: list[str]) -> GnssData:
    t = np.frombuffer(acc.t, dtype=float)
    rows = np.frombuffer(acc.rows, dtype=float).reshape(-1, len(_FixAccumulator.COLUMNS))
    idx = _sorted_unique(t, f"gnss {acc.topic}", warnings)
    t, rows = t[idx], rows[idx]
    velocity = rows[:, 10:13]
    return GnssData(
        t=t,
        lla=rows[:, 0:3],
        std=rows[:, 3:6],
        fix_quality=rows[:, 6],
        hdop=rows[:, 7],
        vdop=rows[:, 8],
        pdop=rows[:, 9],
        velocity=velocity,
        speed=rows[:, 13],
        course=rows[:, 14],
        num_sats=rows[:, 15],
    )


def _build_nmea(acc: _NmeaAccumulator, path: Path, warnings: list[str]) -> GnssData:
    acc.close()
    try:
        try:
            from fgins.io.nmea import read_nmea
        except ImportError as exc:
            raise InputError(
                f"{path}: topic {acc.topic} carries NMEA sentences but fgins.io.nmea is not "
                "available; install a complete fgins"
            ) from exc
        parsed = read_nmea(acc.path)
    finally:
        acc.path.unlink(missing_ok=True)
    gnss = parsed if isinstance(parsed, GnssData) else parsed.gnss
    warnings.extend(f"gnss {acc.topic}: {line}" for line in getattr(parsed, "warnings", []))
    stamps = np.frombuffer(acc.fix_stamps, dtype=float)
    n = min(len(gnss), stamps.size)
    if n:
        # NMEA time is UTC (of day, or POSIX with a date); the bag's stamps are the time base of
        # the IMU. Shift by the median offset between GGA stamps and parsed epochs.
        offset = float(np.median(stamps[:n] - gnss.t[:n]))
        if abs(offset) > 0.5:
            gnss.t = gnss.t + offset
            warnings.append(
                f"gnss {acc.topic}: NMEA times shifted by {offset:.3f} s onto the message stamps"
            )
    return gnss


def _attach_velocity(
    gnss: GnssData, acc: _VelocityAccumulator, warnings: list[str], report: list[str]
) -> None:
    """Fill GNSS ENU velocity from a Twist topic, matched to the nearest fix in time."""
    t_vel = np.frombuffer(acc.t, dtype=float)
    rows = np.frombuffer(acc.rows, dtype=float).reshape(-1, 6)
    idx = _sorted_unique(t_vel, f"gnss velocity {acc.topic}", warnings)
    t_vel, rows = t_vel[idx], rows[idx]
    if t_vel.size == 0 or len(gnss) == 0:
        return
    period = float(np.median(np.diff(gnss.t))) if len(gnss) > 1 else 1.0
    tolerance = 0.25 * period
    nearest = np.clip(np.searchsorted(t_vel, gnss.t), 1, max(t_vel.size - 1, 1))
    left = np.clip(nearest - 1, 0, t_vel.size - 1)
    right = np.clip(nearest, 0, t_vel.size - 1)
    pick = np.where(np.abs(t_vel[left] - gnss.t) <= np.abs(t_vel[right] - gnss.t), left, right)
    matched = np.abs(t_vel[pick] - gnss.t) <= tolerance
    gnss.velocity[matched] = rows[pick[matched], :3]
    gnss.velocity_std[matched] = rows[pick[matched], 3:]
    report.append(
        f"gnss velocity: {int(matched.sum())}/{len(gnss)} fixes matched to {acc.topic} "
        f"(within {tolerance:.3f} s)"
    )
    if not matched.all():
        warnings.append(
            f"gnss velocity {acc.topic}: {int((~matched).sum())} fixes without a velocity "
            f"within {tolerance:.3f} s"
        )


# --------------------------------------------------------------------------------------------
# The reader
# --------------------------------------------------------------------------------------------


@dataclass
class _Candidate:
    channel_id: int
    topic: str
    schema_name: str
    role: str


def _choose(
    role: str,
    candidates: list[_Candidate],
    counts: dict[int, int],
    override: str | None,
    report: list[str],
    warnings: list[str] | None = None,
) -> _Candidate | None:
    """The channel to read for one role: the override, else the one with most messages
    (a tie for most, broken by topic name, is a warning naming the override)."""
    mine = [c for c in candidates if c.role == role]
    if override is not None:
        chosen = [c for c in mine if c.topic == override]
        if not chosen:
            available = ", ".join(sorted({c.topic for c in mine})) or "none"
            raise InputError(
                f"{role} topic {override!r} not found among the {role} topics ({available}); "
                "pick one of those"
            )
        report.append(f"{role}: {override} ({chosen[0].schema_name}) chosen by the user")
        return chosen[0]
    if not mine:
        return None
    ranked = sorted(mine, key=lambda c: (-counts.get(c.channel_id, 0), c.topic))
    best = ranked[0]
    if len(ranked) == 1:
        why = "the only candidate"
    else:
        others = ", ".join(f"{c.topic} ({counts.get(c.channel_id, 0)})" for c in ranked[1:])
        best_count = counts.get(best.channel_id, 0)
        tied = [c.topic for c in ranked[1:] if counts.get(c.channel_id, 0) == best_count]
        tie = " (tied; first by name)" if tied else ""
        why = f"most messages of {len(ranked)} candidates{tie}; others: {others}"
        if tied and warnings is not None:
            option = {ROLE_IMU: "--imu-topic", ROLE_GNSS: "--gnss-topic"}.get(role)
            pick = (
                f"give {option} {tied[0]} to read " + ("that one" if len(tied) == 1 else "another")
                if option
                else "fgins has no option to pick another"
            )
            warnings.append(
                f"{role}: {len(tied) + 1} {role} topics have {best_count} messages each "
                f"({', '.join([best.topic, *tied])}); read {best.topic} (first by name): "
                f"{pick}"
            )
    report.append(
        f"{role}: {best.topic} ({best.schema_name}, {counts.get(best.channel_id, 0)} messages), "
        f"{why}"
    )
    return best


_ROLES = (ROLE_IMU, ROLE_GNSS, ROLE_VELOCITY, ROLE_BARO)


class TopicScan:
    """One streaming pass: routes the messages of candidate channels into accumulators."""

    def __init__(
        self,
        path: Path,
        use_header_stamp: bool,
        overrides: dict[str, str | None],
        roles: tuple[str, ...] = (),
    ) -> None:
        self.path = path
        self.use_header_stamp = use_header_stamp
        self.overrides = overrides
        self.roles = roles or _ROLES  # the roles to read (convert needs no IMU)
        # Channels of one topic and type (a ROS 1 topic has one connection per publisher:
        # a driver restart, two nodes) are one stream: every channel id -> the first one's.
        self.merged_into: dict[int, int] = {}
        self.report: list[str] = []
        self.warnings: list[str] = []
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.candidates: dict[int, _Candidate] = {}
        self.skipped: dict[int, str] = {}  # channel id -> why it is not used
        self.counts: dict[int, int] = {}
        self.accumulators: dict[int, _Accumulator] = {}
        self.decoders: dict[int, Callable[[bytes], Any] | None] = {}
        self.encodings: dict[int, str] = {}  # channel id -> message encoding
        self.outcome = _StreamOutcome()
        self.chosen: dict[str, _Candidate] | None = None
        self.format = "mcap"  # the dataset's metadata["format"]

    # -- choosing ---------------------------------------------------------------------------

    def merged_counts(self, counts: dict[int, int]) -> dict[int, int]:
        """Message counts per stream (channels merged into the first of their topic)."""
        merged: dict[int, int] = {}
        for cid, n in counts.items():
            key = self.merged_into.get(cid, cid)
            merged[key] = merged.get(key, 0) + n
        return merged

    def choose(self, counts: dict[int, int]) -> None:
        self.chosen = {}
        counts = self.merged_counts(counts)
        for role in _ROLES:
            pick = _choose(
                role,
                list(self.candidates.values()),
                counts,
                self.overrides.get(role),
                self.report,
                self.warnings,
            )
            if pick is not None:
                self.chosen[role] = pick

    def preselect_from_summary(self, summary: Any) -> None:
        """With a summary, the channels and counts are known before any message is read."""
        self.schemas.update(summary.schemas)
        for channel in summary.channels.values():
            self.on_channel(channel)
        self.choose(dict(summary.statistics.channel_message_counts))
        chosen_ids = {c.channel_id for c in self.chosen.values()}
        for cid in list(self.accumulators):
            if cid not in chosen_ids:
                self.discard(cid)

    # -- records ----------------------------------------------------------------------------

    def on_channel(self, channel: Channel) -> None:
        if channel.id in self.channels:
            return
        self.channels[channel.id] = channel
        schema = self.schemas.get(channel.schema_id)
        name = ros2_type_name(schema.name) if schema is not None else ""
        role = role_of_schema(name)
        if role is None:
            self.skipped[channel.id] = f"unknown schema {name or '(none)'}"
            return
        if channel.metadata.get(PRODUCER_KEY) == PRODUCER_FGINS:
            # fgins's own output (smoothed fixes, copied GNSS) is not a sensor: never read back
            self.skipped[channel.id] = f"{name} written by fgins, not a sensor"
            return
        if role not in self.roles:
            self.skipped[channel.id] = f"{name}: no {role} needed here"
            return
        for cid, candidate in self.candidates.items():
            if (candidate.topic, candidate.schema_name, self.encodings[cid]) == (
                channel.topic, name, channel.message_encoding,
            ):  # fmt: skip
                self.merged_into[channel.id] = cid
                return
        if role == ROLE_IMU:
            if channel.message_encoding not in ("cdr", "ros1"):
                self.skipped[channel.id] = f"{name} in {channel.message_encoding} not supported"
                return
            unlike = _nonstandard_imu(schema)
            if unlike:
                self.skipped[channel.id] = unlike
                return
        else:
            try:
                decoder = self.make_decoder(schema, channel)
            except Exception as exc:  # a schema text the decoder cannot parse
                decoder = None
                self.warnings.append(f"{channel.topic}: cannot build a decoder for {name}: {exc}")
            if decoder is None:
                schema_encoding = schema.encoding if schema is not None else "no schema"
                self.skipped[channel.id] = (
                    f"{name} in {channel.message_encoding} with a {schema_encoding or 'blank'} "
                    "schema cannot be decoded here"
                )
                return
            self.decoders[channel.id] = decoder
        self.candidates[channel.id] = _Candidate(channel.id, channel.topic, name, role)
        self.encodings[channel.id] = channel.message_encoding
        if self.chosen is None or channel.id in {c.channel_id for c in self.chosen.values()}:
            self.accumulators[channel.id] = self.new_accumulator(channel.id)

    def new_accumulator(self, channel_id: int) -> _Accumulator:
        candidate = self.candidates[channel_id]
        accumulator = _new_accumulator(candidate.role, candidate.topic, candidate.schema_name)
        if isinstance(accumulator, _ImuAccumulator):
            accumulator.set_encoding(self.encodings[channel_id])
        return accumulator

    def make_decoder(self, schema: Schema | None, channel: Channel) -> Callable[[bytes], Any] | None:
        """bytes -> message for a non-IMU channel (None: not decodable here)."""
        return _make_decoder(schema, channel)

    def on_message(self, record: Message) -> None:
        self.on_data(record.channel_id, record.log_time, record.data)

    def on_data(self, cid: int, log_time: int, data: bytes) -> None:
        cid = self.merged_into.get(cid, cid)
        self.counts[cid] = self.counts.get(cid, 0) + 1
        acc = self.accumulators.get(cid)
        if acc is None:
            return
        try:
            if isinstance(acc, _ImuAccumulator):
                acc.add_raw(data, log_time, self.use_header_stamp)
            else:
                message = self.decoders[cid](data)  # type: ignore[misc]
                acc.add(message, log_time, self.use_header_stamp)  # type: ignore[attr-defined]
        except Exception:  # one corrupt message must not end the read: counted, reported
            acc.decode_errors += 1

    def run(self, progress: bool) -> None:
        for record in _stream_records(self.path, self.outcome, progress, self.path.name):
            if isinstance(record, Message):
                self.on_message(record)
            elif isinstance(record, Schema):
                self.schemas.setdefault(record.id, record)
            elif isinstance(record, Channel):
                self.on_channel(record)
        if self.chosen is None:  # no summary: every candidate was read, choose now
            self.choose(self.counts)
            chosen_ids = {c.channel_id for c in self.chosen.values()}  # type: ignore[union-attr]
            for cid in list(self.accumulators):
                if cid not in chosen_ids:
                    self.discard(cid)

    def discard(self, channel_id: int) -> None:
        acc = self.accumulators.pop(channel_id)
        if isinstance(acc, _NmeaAccumulator):
            acc.close()
            acc.path.unlink(missing_ok=True)

    def close(self) -> None:
        for cid in list(self.accumulators):
            self.discard(cid)


def _accumulator_for(scan: TopicScan, role: str) -> _Accumulator | None:
    chosen = (scan.chosen or {}).get(role)
    return None if chosen is None else scan.accumulators.get(chosen.channel_id)


def assemble(scan: TopicScan) -> McapResult:
    """The dataset of a finished scan: IMU and GNSS required."""
    gnss, imu_acc = assemble_gnss(scan, need_imu=True)
    assert imu_acc is not None
    return assemble_dataset(scan, gnss, imu_acc)


def _unreadable(scan: TopicScan, role: str) -> str:
    """'; /topic (why) cannot be read' for channels of ``role`` that exist but were skipped
    (an encoding or definition fgins cannot decode), else ''."""
    unreadable = []
    for cid, why in sorted(scan.skipped.items()):
        schema = scan.schemas.get(scan.channels[cid].schema_id)
        if schema is not None and role_of_schema(schema.name) == role and "fgins" not in why:
            unreadable.append(f"{scan.channels[cid].topic} ({why})")
    return f"; {', '.join(unreadable)} cannot be read" if unreadable else ""


def _fgins_output_only(scan: TopicScan) -> str:
    """' (it holds only fgins output channels ...)' for a file fgins wrote, else ''."""
    ours = sorted(c.topic for c in scan.channels.values()
                  if c.metadata.get(PRODUCER_KEY) == PRODUCER_FGINS)  # fmt: skip
    if ours and len(ours) == len(scan.channels):
        return (
            f"; it holds only fgins output channels ({', '.join(ours[:4])}"
            f"{' ...' if len(ours) > 4 else ''}): a trajectory fgins wrote, not sensor data"
        )
    return ""


def assemble_gnss(scan: TopicScan, need_imu: bool) -> tuple[GnssData, Any]:
    """The GNSS fixes (with velocity) of a finished scan and the IMU accumulator (None when
    there is none and ``need_imu`` is false); truncation and damage reported."""
    path, report, warnings = scan.path, scan.report, scan.warnings
    if scan.outcome.truncated:
        outcome = scan.outcome
        last = (
            f"last complete message at t={outcome.last_log_time_ns / 1e9:.3f} s (log time)"
            if outcome.last_log_time_ns is not None
            else "no complete message"
        )
        if outcome.damaged_record_at >= 0 and outcome.data_end_seen:
            warnings.append(
                f"{path}: damaged summary section (a record at byte "
                f"{outcome.damaged_record_at} of {outcome.cut_at} does not parse); the data "
                f"section before it was read in full ({outcome.messages} messages); tools "
                "that rely on the summary (indexed readers) may fail on this file"
            )
        elif outcome.damaged_record_at >= 0:
            warnings.append(
                f"{path}: a damaged record at byte {outcome.damaged_record_at} of "
                f"{outcome.cut_at} (corrupt bytes in a complete file): {outcome.messages} "
                f"messages read, {last}; the rest of the file cannot be read"
            )
        else:
            torn = f"; torn chunk {outcome.torn_chunk}" if outcome.torn_chunk else ""
            if outcome.data_end_seen:  # cut inside the summary: nothing of the data lost
                torn += "; the cut is in the summary section: the data section was read in full"
            warnings.append(
                f"{path}: file truncated at byte {outcome.cut_at}: {outcome.messages} messages "
                f"read, {last}{torn}"
            )
    damage = _damage_warning(path, scan.outcome)
    if damage:
        warnings.append(damage)
    for cid, why in sorted(scan.skipped.items()):
        topic = scan.channels[cid].topic
        report.append(f"skipped {topic}: {why} ({scan.counts.get(cid, 0)} messages)")
    imu_acc = _accumulator_for(scan, ROLE_IMU)
    gnss_acc = _accumulator_for(scan, ROLE_GNSS)
    if imu_acc is None and need_imu:
        raise InputError(
            f"{path}: no IMU channel (sensor_msgs/msg/Imu) found; record the IMU topic "
            f"or give an IMU CSV{_fgins_output_only(scan)}{_unreadable(scan, ROLE_IMU)}"
        )
    if gnss_acc is None:
        raise InputError(
            f"{path}: no GNSS channel (NavSatFix, GPSFix, foxglove.LocationFix, "
            f"nmea_msgs/Sentence) found; record a GNSS topic or give an NMEA/GNSS CSV"
            f"{_fgins_output_only(scan)}{_unreadable(scan, ROLE_GNSS)}"
        )
    for acc in scan.accumulators.values():
        if acc.decode_errors:
            warnings.append(f"{acc.topic}: {acc.decode_errors} messages could not be decoded")
        if acc.stamp_fallbacks:
            warnings.append(
                f"{acc.topic}: {acc.stamp_fallbacks} messages with a zero header stamp; "
                "their log time was used"
            )
    if isinstance(gnss_acc, _NmeaAccumulator):
        gnss = _build_nmea(gnss_acc, path, warnings)
    else:
        assert isinstance(gnss_acc, _FixAccumulator)
        if gnss_acc.no_fix:
            warnings.append(f"gnss {gnss_acc.topic}: {gnss_acc.no_fix} no-fix messages dropped")
        gnss = _build_fixes(gnss_acc, warnings)
    if len(gnss) == 0:
        no_fix = getattr(gnss_acc, "no_fix", 0)
        why = (
            f"all {no_fix} of its fix messages report no fix (NavSatFix status -1) or no "
            "position"
            if no_fix and not gnss_acc.decode_errors
            else f"{gnss_acc.decode_errors} undecodable messages, {no_fix} without a fix"
        )
        raise InputError(
            f"{path}: GNSS topic {gnss_acc.topic} has no valid fix ({why}); nothing to anchor "
            "the trajectory"
        )
    velocity_acc = _accumulator_for(scan, ROLE_VELOCITY)
    if velocity_acc is not None:
        _attach_velocity(gnss, velocity_acc, warnings, report)  # type: ignore[arg-type]
    return gnss, imu_acc


def assemble_dataset(scan: TopicScan, gnss: GnssData, imu_acc: Any) -> McapResult:
    path, report, warnings = scan.path, scan.report, scan.warnings
    gnss_acc = _accumulator_for(scan, ROLE_GNSS)
    imu = _build_imu(imu_acc, warnings)
    imu_config = imu_acc.noise_config(imu.rate_hz)
    if imu_config:
        report.append(
            f"imu noise from the sensor_msgs/Imu covariances of {imu_acc.topic}: "
            + ", ".join(f"{k} = {v:.3g}" for k, v in imu_config.items())
            + " (at "
            + f"{imu.rate_hz:.1f} Hz); other [imu] terms from the preset"
        )
    baro = None
    baro_acc = _accumulator_for(scan, ROLE_BARO)
    if isinstance(baro_acc, _BaroAccumulator) and len(baro_acc):
        t = np.frombuffer(baro_acc.t, dtype=float)
        idx = _sorted_unique(t, f"baro {baro_acc.topic}", warnings)
        baro = BaroData(t=t[idx], pressure=np.frombuffer(baro_acc.pressure, dtype=float)[idx])
    origin = Origin(*(float(v) for v in gnss.lla[0]))
    report.append(
        f"read {len(imu)} IMU samples, {len(gnss)} GNSS fixes"
        + (f", {len(baro.t)} barometer samples" if baro is not None else "")
        + f"; origin at the first valid fix ({origin.lat:.7f}, {origin.lon:.7f}, "
        f"{origin.alt:.2f} m)"
    )
    dataset = Dataset(
        imu=imu,
        gnss=gnss,
        origin=origin,
        baro=baro,
        name=path.stem,
        imu_config=imu_config,
        warnings=list(warnings),
        metadata={
            "source": str(path),
            "format": scan.format,
            "topics": {role: c.topic for role, c in (scan.chosen or {}).items()},
            "time_base": "header stamp" if scan.use_header_stamp else "log time",
            "gnss_epochs_without_fix": getattr(gnss_acc, "no_fix", 0),
            "gnss_first_epoch_t": float(getattr(gnss_acc, "first_t", math.nan)),
            # For messages: errors about the IMU name the topics --imu-topic could read
            # instead, and errors about the noise the data set say where it came from.
            "imu_topics_other": sorted(
                {c.topic for c in scan.candidates.values() if c.role == ROLE_IMU} - {imu_acc.topic}
            ),
            "imu_config_source": (
                f"the sensor_msgs/Imu covariances of {imu_acc.topic} (variances per sample)"
                if imu_config
                else ""
            ),
        },
    )
    return McapResult(dataset=dataset, report=report, warnings=warnings)


def read_mcap_gnss(
    path: str | Path, *, gnss_topic: str | None = None, progress: bool = False
) -> tuple[GnssData, list[str]]:
    """The GNSS fixes (with velocity) of an MCAP file and the reader's warnings; no IMU
    needed (``fgins convert``: a log of a receiver alone)."""
    scan = _scan(Path(path), True, {ROLE_IMU: None, ROLE_GNSS: gnss_topic}, progress,
                 roles=(ROLE_GNSS, ROLE_VELOCITY))  # fmt: skip
    try:
        gnss, _ = assemble_gnss(scan, need_imu=False)
        return gnss, scan.warnings
    finally:
        scan.close()


def _scan(
    path: Path,
    use_header_stamp: bool,
    topics: dict[str, str | None],
    progress: bool,
    roles: tuple[str, ...] = (),
) -> TopicScan:
    """A finished scan of ``path`` (the caller closes it)."""
    _check_magic(path)
    scan = TopicScan(path, use_header_stamp, topics, roles)
    try:
        summary = _read_summary(path)
        if summary is not None:
            scan.preselect_from_summary(summary)
        scan.run(progress)
    except BaseException:
        scan.close()
        raise
    return scan


def read_mcap(
    path: str | Path,
    *,
    imu_topic: str | None = None,
    gnss_topic: str | None = None,
    use_header_stamp: bool = True,
    progress: bool = True,
) -> McapResult:
    """Read IMU, GNSS (+ GNSS velocity, barometer) from an MCAP file into a :class:`Dataset`.

    Topics are chosen by schema; with several candidates for one role the one with most
    messages is used (``imu_topic`` / ``gnss_topic`` override). Times are float seconds of the
    header stamps (``use_header_stamp``; log time where a stamp is zero), else of the log
    times. Raises :class:`InputError` for a file that is not an MCAP or lacks IMU or GNSS.
    """
    scan = _scan(
        Path(path), use_header_stamp, {ROLE_IMU: imu_topic, ROLE_GNSS: gnss_topic}, progress
    )
    try:
        return assemble(scan)
    finally:
        scan.close()


# --------------------------------------------------------------------------------------------
# Inspection
# --------------------------------------------------------------------------------------------

GAP_NOMINAL_PERIODS = 3.0  # a gap is an interval longer than this many nominal periods


def _gap_lines(log_ns: np.ndarray) -> tuple[float, list[str]]:
    """Nominal rate (Hz) and one line per gap (> 3 nominal periods) of a channel's log times."""
    if log_ns.size < 2:
        return math.nan, []
    ordered = np.sort(log_ns)
    dt = np.diff(ordered) / 1e9  # differences in integer ns first: no float cancellation
    t = (ordered - ordered[0]) / 1e9
    period = float(np.median(dt))
    if period <= 0:
        return math.nan, []
    gaps = np.flatnonzero(dt > GAP_NOMINAL_PERIODS * period)
    lines = [f"gap of {dt[i]:.3f} s at t+{t[i]:.3f} s" for i in gaps[:5]]
    if gaps.size > 5:
        lines.append(f"... {gaps.size - 5} more gaps")
    return 1.0 / period, lines


def summarize_mcap(path: str | Path, *, progress: bool = False) -> str:
    """A human-readable overview of an MCAP file (for ``fgins inspect``).

    Channels with schema, encoding, role for fgins, message count, nominal rate, time span and
    gaps (> 3 nominal periods); whether a summary section exists; truncation.
    """
    path = Path(path)
    _check_magic(path)
    outcome = _StreamOutcome()
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    log_times: dict[int, array] = {}
    for record in _stream_records(path, outcome, progress, f"inspecting {path.name}"):
        if isinstance(record, Message):
            log_times.setdefault(record.channel_id, array("q")).append(record.log_time)
        elif isinstance(record, Schema):
            schemas.setdefault(record.id, record)
        elif isinstance(record, Channel):
            channels.setdefault(record.id, record)
    size_mb = path.stat().st_size / 1e6
    lines = [f"{path} ({size_mb:.1f} MB)"]
    if outcome.damaged_record_at >= 0 and outcome.data_end_seen:
        lines.append(
            f"DAMAGED SUMMARY: a record at byte {outcome.damaged_record_at} of the summary "
            f"section does not parse ({outcome.error}); the data section was read in full"
        )
    elif outcome.damaged_record_at >= 0:
        lines.append(
            f"DAMAGED: a record at byte {outcome.damaged_record_at} does not parse ("
            f"{outcome.error}); everything before it is listed"
        )
    elif outcome.truncated:
        lines.append(f"TRUNCATED: {outcome.error}; everything before the cut is listed")
    damage = _damage_warning(path, outcome)
    if damage:
        lines.append(f"DAMAGED: {damage}")
    has = "yes" if outcome.has_summary else "no (fgins streams the whole file to choose topics)"
    if outcome.data_end_seen and outcome.truncated:
        has = "damaged (fgins streams the whole file to choose topics)"
    lines.append("summary section: " + has)
    all_times = [np.frombuffer(v, dtype=np.int64) for v in log_times.values() if len(v)]
    if all_times:
        start = min(int(a.min()) for a in all_times)
        end = max(int(a.max()) for a in all_times)
        total = sum(a.size for a in all_times)
        lines.append(
            f"time span: {start / 1e9:.3f} .. {end / 1e9:.3f} s ({(end - start) / 1e9:.3f} s), "
            f"{total} messages, {len(channels)} channels"
        )
    else:
        lines.append(f"no messages, {len(channels)} channels")
    for cid in sorted(channels, key=lambda c: channels[c].topic):
        channel = channels[cid]
        schema = schemas.get(channel.schema_id)
        name = schema.name if schema is not None else "(no schema)"
        role = role_of_schema(name) or "not used"
        if channel.metadata.get(PRODUCER_KEY) == PRODUCER_FGINS:
            role = "fgins output, not read as a sensor"
        times = np.frombuffer(log_times.get(cid, array("q")), dtype=np.int64)
        rate, gaps = _gap_lines(times)
        rate_text = f"{rate:.2f} Hz" if math.isfinite(rate) else "rate n/a"
        span = f"{(times.max() - times.min()) / 1e9:.3f} s" if times.size else "empty"
        lines.append(
            f"  {channel.topic}: {name} [{channel.message_encoding}] -> {role}; "
            f"{times.size} messages, {rate_text}, span {span}"
        )
        lines.extend(f"      {gap}" for gap in gaps)
    return "\n".join(lines)
