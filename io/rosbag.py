"""Read ROS bags that are not a single MCAP file: ROS 1 ``.bag`` files and ROS 2 bag folders
(``metadata.yaml`` beside SQLite ``.db3`` files, or several ``.mcap`` files), through rosbags'
``AnyReader``.

Everything after the bytes of a message is :mod:`fgins.io.mcap`'s: the bag's connections become
the scan's channels (schema = the message type, ROS 2 spelling), topics are chosen by schema
(the one with most messages; ``--imu-topic``/``--gnss-topic`` override), and the same
accumulators, time bases (header stamps; the bag's receive time where a stamp is zero),
reports and checks build the dataset. The IMU goes through the fast fixed-layout paths (ROS 1
packed, ROS 2 CDR); other messages through rosbags' deserializer, which gives ROS 1 messages
the ROS 2 field names (``header.stamp.sec``/``nanosec``). The message counts are in the bag's
index, so only the chosen topics are read.

A ROS 1 bag whose recording was cut off (no index: ``.bag.active``) cannot be read by rosbags:
the error says to run ``rosbag reindex`` first.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from mcap.records import Channel, Schema

from fgins.datatypes import GnssData, InputError
from fgins.io.mcap import (
    ROLE_GNSS,
    ROLE_IMU,
    McapResult,
    TopicScan,
    assemble,
    assemble_gnss,
    role_of_schema,
    ros2_type_name,
)

ROS1_MAGIC = b"#ROSBAG V2.0\n"
ROS2_METADATA = "metadata.yaml"


def looks_like_ros1_bag(path: Path) -> bool:
    """A ROS 1 bag by its magic line (whatever the file's name)."""
    try:
        with path.open("rb") as handle:
            return handle.read(len(ROS1_MAGIC)) == ROS1_MAGIC
    except OSError:
        return False


def is_ros2_bag_folder(path: Path) -> bool:
    return path.is_dir() and (path / ROS2_METADATA).is_file()


def ros2_bag_files(path: Path) -> list[Path]:
    """The storage files of a ROS 2 bag folder (.db3 and .mcap), sorted."""
    return sorted(p for p in path.iterdir() if p.suffix.lower() in (".db3", ".mcap"))


def is_rosbag(path: Path) -> bool:
    """Whether :func:`read_rosbag` is the reader for ``path``."""
    return (path.is_file() and looks_like_ros1_bag(path)) or is_ros2_bag_folder(path)


@contextmanager
def _open(path: Path) -> Iterator[Any]:
    """rosbags' AnyReader over one bag, its failures as one-line input errors."""
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.rosbag1 import ReaderError as Ros1Error
    from rosbags.rosbag2 import ReaderError as Ros2Error

    kind = "ROS 1 bag" if path.is_file() else "ROS 2 bag folder"
    try:
        reader = AnyReader([path])
        reader.open()
    except (AnyReaderError, Ros1Error, Ros2Error, OSError, ValueError, KeyError) as exc:
        why = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        hint = ""
        if path.is_file() and ("index" in why.lower() or "unindexed" in why.lower()):
            hint = "; a recording cut off before its index was written: run rosbag reindex"
        raise InputError(f"{path}: cannot read this {kind}: {why}{hint}") from None
    try:
        yield reader
    finally:
        reader.close()


class _BagScan(TopicScan):
    """The MCAP scan fed from a bag: connections as channels, messages as records."""

    def __init__(
        self, path: Path, reader: Any, use_header_stamp: bool, overrides: dict[str, str | None]
    ) -> None:
        super().__init__(path, use_header_stamp, overrides)
        self.reader = reader
        self.format = "ros1 bag" if path.is_file() else "ros2 bag"
        self.connections: dict[int, Any] = {}

    def make_decoder(self, schema: Schema | None, channel: Channel) -> Callable[[bytes], Any]:
        msgtype = self.connections[channel.id].msgtype
        deserialize = self.reader.deserialize
        return lambda data: deserialize(data, msgtype)

    def add_connections(self) -> None:
        ros1 = not self.reader.is2
        for cid, connection in enumerate(self.reader.connections):
            self.connections[cid] = connection
            name = ros2_type_name(connection.msgtype)
            self.schemas[cid] = Schema(
                id=cid, name=name, encoding="ros1msg" if ros1 else "ros2msg", data=b""
            )
            self.on_channel(
                Channel(
                    id=cid,
                    schema_id=cid,
                    topic=connection.topic,
                    message_encoding="ros1" if ros1 else "cdr",
                    metadata={},
                )
            )
        counts = {cid: int(c.msgcount) for cid, c in self.connections.items()}
        self.counts = dict(counts)  # known from the index: reported as is
        self.choose(counts)
        chosen = {c.channel_id for c in (self.chosen or {}).values()}
        for cid in list(self.accumulators):
            if cid not in chosen:
                self.discard(cid)

    def read(self, progress: bool) -> None:
        from tqdm import tqdm

        ids = {id(c): cid for cid, c in self.connections.items()}
        wanted = [self.connections[cid] for cid in self.accumulators]
        total = sum(int(c.msgcount) for c in wanted)
        index_counts = dict(self.counts)  # on_data counts again what it reads
        with tqdm(
            total=total, desc=f"reading {self.path.name}", unit="msg", disable=not progress,
            leave=False,
        ) as bar:  # fmt: skip
            for done, (connection, timestamp, data) in enumerate(
                self.reader.messages(connections=wanted), start=1
            ):
                self.on_data(ids[id(connection)], int(timestamp), data)
                if done % 4096 == 0:
                    bar.update(4096)
        self.counts = index_counts


def _scan(
    path: Path, reader: Any, use_header_stamp: bool, topics: dict[str, str | None], progress: bool
) -> _BagScan:
    scan = _BagScan(path, reader, use_header_stamp, topics)
    try:
        scan.add_connections()
        scan.read(progress)
    except BaseException:
        scan.close()
        raise
    return scan


def _bag_path(path: Path) -> Path:
    """The path AnyReader takes: the .bag file, or the ROS 2 bag folder."""
    if path.is_file() and path.suffix.lower() == ".db3":
        if (path.parent / ROS2_METADATA).is_file():
            return path.parent
        raise InputError(
            f"{path}: a ROS 2 SQLite bag file without its {ROS2_METADATA}; give the bag folder "
            "that holds both"
        )
    return path


def _unlisted_files(path: Path) -> list[str]:
    """Storage files in a ROS 2 bag folder that its metadata.yaml does not list (a copy, a
    file of another recording): not part of the bag, so not read, and said."""
    if not is_ros2_bag_folder(path):
        return []
    listed = set(re.findall(r"[\w.\-]+\.(?:db3|mcap)\b", (path / ROS2_METADATA).read_text(
        encoding="utf-8", errors="replace")))  # fmt: skip
    return [p.name for p in ros2_bag_files(path) if p.name not in listed]


def read_rosbag(
    path: str | Path,
    *,
    imu_topic: str | None = None,
    gnss_topic: str | None = None,
    use_header_stamp: bool = True,
    progress: bool = True,
) -> McapResult:
    """IMU, GNSS (+ GNSS velocity, barometer) of a ROS 1 bag or a ROS 2 bag folder; the
    conventions of :func:`fgins.io.mcap.read_mcap`."""
    path = _bag_path(Path(path))
    with _open(path) as reader:
        scan = _scan(
            path, reader, use_header_stamp, {ROLE_IMU: imu_topic, ROLE_GNSS: gnss_topic}, progress
        )
        unlisted = _unlisted_files(path)
        if unlisted:
            scan.warnings.append(
                f"{path}: {', '.join(unlisted)} not listed in its {ROS2_METADATA}: not part of "
                "the bag, not read"
            )
        try:
            return assemble(scan)
        finally:
            scan.close()


def read_rosbag_gnss(
    path: str | Path, *, gnss_topic: str | None = None, progress: bool = False
) -> tuple[GnssData, list[str]]:
    """The GNSS fixes (with velocity) of a bag and the reader's warnings; no IMU needed."""
    path = _bag_path(Path(path))
    with _open(path) as reader:
        scan = _scan(path, reader, True, {ROLE_IMU: None, ROLE_GNSS: gnss_topic}, progress)
        try:
            gnss, _ = assemble_gnss(scan, need_imu=False)
            return gnss, scan.warnings
        finally:
            scan.close()


def summarize_rosbag(path: str | Path) -> str:
    """What ``fgins inspect`` prints for a bag: its connections with type, role, count, span."""
    path = _bag_path(Path(path))
    with _open(path) as reader:
        kind = "ROS 2 bag" if reader.is2 else "ROS 1 bag"
        span = (reader.end_time - reader.start_time) / 1e9 if reader.message_count else 0.0
        lines = [
            f"{path} ({kind}): {reader.message_count} messages over {span:.3f} s, "
            f"{len(reader.connections)} connections"
        ]
        for connection in sorted(reader.connections, key=lambda c: c.topic):
            name = ros2_type_name(connection.msgtype)
            role = role_of_schema(name) or "not used"
            count = int(connection.msgcount)
            rate = f", ~{count / span:.2f} Hz" if span > 0 and count > 1 else ""
            lines.append(f"  {connection.topic}: {name} -> {role}; {count} messages{rate}")
    return "\n".join(lines)
