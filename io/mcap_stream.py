"""MCAP records streamed from a file, robust to torn files.

A recording cut off mid-write has no summary, no footer and a torn last chunk: the stream
yields every complete record up to the cut (message level: a chunk cut short still gives the
messages before the cut) and says what it could not read. Constant memory in the file size.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.exceptions import InvalidMagic
from mcap.reader import make_reader
from mcap.records import Channel, Chunk, DataEnd, Footer, Message, MessageIndex, Schema
from mcap.stream_reader import StreamReader

from fgins.datatypes import InputError

_PROGRESS_EVERY_RECORDS = 4096


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
class StreamOutcome:
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


MCAP_MAGIC = b"\x89MCAP0\r\n"  # opens (and closes) every MCAP file
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


def _open_chunk(chunk: Chunk, at: int, outcome: StreamOutcome, channels: set[int]) -> Iterator[Any]:
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


def damage_warning(path: Path, outcome: StreamOutcome) -> str:
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


def _records_in_torn_chunk(body: bytes, outcome: StreamOutcome) -> Iterator[Any]:
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


def stream_records(path: Path, outcome: StreamOutcome, progress: bool, label: str) -> Iterator[Any]:
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
    return bool(file.read(8) == MCAP_MAGIC)


def _count(records: Any, outcome: StreamOutcome) -> Iterator[Any]:
    for record in records:
        if isinstance(record, Message):
            outcome.messages += 1
            outcome.last_log_time_ns = record.log_time
        yield record


def _torn_tail(file: Any, offset: int, size: int, outcome: StreamOutcome) -> Iterator[Any]:
    """Records of the top-level record the cut went through (a chunk: its complete messages)."""
    file.seek(offset)
    head = file.read(9)
    if len(head) < 9:
        return
    opcode = head[0]
    if opcode == _CHUNK_OPCODE:
        yield from _records_in_torn_chunk(file.read(size - offset - 9), outcome)


def read_summary(path: Path) -> Any:
    """The summary section (channels, schemas, statistics), or None when there is none."""
    try:
        with open(path, "rb") as file:
            summary = make_reader(file).get_summary()
    except Exception:  # a torn or foreign file: fall back to choosing while streaming
        return None
    if summary is None or summary.statistics is None:
        return None
    return summary


def is_mcap(path: Path) -> bool:
    """Whether ``path`` is a file that begins with the MCAP magic bytes, whatever its name
    (a file cut inside the 8 magic bytes counts when what is there matches them)."""
    try:
        if not path.is_file():
            return False
        with open(path, "rb") as file:
            head = file.read(len(MCAP_MAGIC))
    except OSError:
        return False
    return len(head) >= 5 and MCAP_MAGIC.startswith(head)


def check_magic(path: Path) -> None:
    if not path.is_file():
        raise InputError(f"{path}: no such file; check the path")
    with open(path, "rb") as file:
        head = file.read(8)
    if len(head) < len(MCAP_MAGIC) and len(head) >= 2 and MCAP_MAGIC.startswith(head):
        raise InputError(
            f"{path}: file truncated at byte {len(head)}, inside the MCAP magic bytes: nothing "
            "to read; the recording was cut off before its data: give a complete copy"
        )
    if head != MCAP_MAGIC:
        raise InputError(f"{path}: not an MCAP file (bad magic bytes); give a .mcap recording")
