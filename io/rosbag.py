"""Read ROS bags that are not a single MCAP file: ROS 1 ``.bag`` files and ROS 2 bag folders
(``metadata.yaml`` beside SQLite ``.db3`` files, several ``.mcap`` files, or compressed
storage), through rosbags' ``AnyReader``.

Everything after the bytes of a message is :mod:`fgins.io.mcap`'s: the bag's connections become
the scan's channels (schema = the message type, ROS 2 spelling, with its definition), topics
are chosen by schema (the one with most messages; ``--imu-topic``/``--gnss-topic`` override),
the connections of one topic (ROS 1 has one per publisher) are one stream, and the same
accumulators, time bases (header stamps; the bag's receive time where a stamp is zero),
reports and checks build the dataset. The IMU goes through the fast fixed-layout paths (ROS 1
packed, ROS 2 CDR) after its definition is checked to be the standard one; other messages
through rosbags' deserializer, which gives ROS 1 messages the ROS 2 field names
(``header.stamp.sec``/``nanosec``). The message counts are in the bag's index (a ROS 2 bag's
``metadata.yaml``): only the chosen topics are read, and the report gives the counts read.

What is given is what is read: a ``.db3`` file stands for its bag folder only when the
folder's ``metadata.yaml`` lists it; a storage file the metadata does not list is said and not
read; a ROS 1 bag is recognised by its magic line whatever its name; a recording cut off
before its index was written (``.bag.active``) needs ``rosbag reindex`` first. A bag damaged
inside (a corrupt chunk, a malformed database) is an error naming where reading stopped.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from mcap.records import Channel, Schema

from fgins.datatypes import GnssData, InputError
from fgins.io.mcap import McapResult, TopicScan, assemble, assemble_gnss
from fgins.io.ros_messages import ROLE_GNSS, ROLE_IMU, ROLE_VELOCITY, role_of_schema, ros2_type_name

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


def is_rosbag(path: Path) -> bool:
    """Whether ``path`` is for this module: a ROS 1 bag (by content, or named .bag), a ROS 2
    bag folder, one of its .db3 files or its metadata.yaml."""
    if path.is_dir():
        return is_ros2_bag_folder(path)
    suffix = path.suffix.lower()
    return (
        looks_like_ros1_bag(path)
        or suffix in (".bag", ".db3", ".active")
        or (path.name == ROS2_METADATA and is_ros2_bag_folder(path.parent))
    )


def ros2_metadata(folder: Path) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` table of a bag folder's metadata.yaml."""
    from ruamel.yaml import YAML  # rosbags' own YAML library

    path = folder / ROS2_METADATA
    try:
        loaded = YAML(typ="safe").load(path.read_text(encoding="utf-8", errors="replace"))
        if not isinstance(loaded, dict) or "rosbag2_bagfile_information" not in loaded:
            raise TypeError("empty" if loaded is None else "no rosbag2_bagfile_information table")
        info = loaded["rosbag2_bagfile_information"]
        if not isinstance(info, dict):
            raise TypeError("rosbag2_bagfile_information is not a table")
    except Exception as exc:  # any YAML or shape error: the file is not a bag's metadata
        why = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"{path}: not a readable ROS 2 bag metadata file ({why})") from None
    return info


def listed_files(folder: Path, info: dict[str, Any] | None = None) -> list[str]:
    """The storage files a ROS 2 bag folder's metadata lists (relative names); ``info``: its
    metadata when already read."""
    info = ros2_metadata(folder) if info is None else info
    return [str(name) for name in info.get("relative_file_paths") or []]


def single_mcap_file(folder: Path) -> Path | None:
    """The bag's one MCAP file when the plain MCAP reader can read the bag as that file:
    the metadata lists exactly that file, it is there, and nothing is compressed."""
    info = ros2_metadata(folder)
    names = listed_files(folder, info)
    if len(names) != 1 or not names[0].lower().endswith(".mcap"):
        return None
    if info.get("compression_mode") or info.get("compression_format"):
        return None
    path = folder / names[0]
    return path if path.is_file() else None


def bag_path(path: Path) -> Path:
    """The path a bag is read from (a .bag file or a bag folder), or a clear error for a
    path that only looks like one."""
    if path.is_dir():
        return path
    if path.name == ROS2_METADATA and is_ros2_bag_folder(path.parent):
        return path.parent
    suffix = path.suffix.lower()
    if suffix == ".db3":
        folder = path.parent
        if not (folder / ROS2_METADATA).is_file():
            raise InputError(
                f"{path}: a ROS 2 SQLite bag file without its {ROS2_METADATA}; give the bag "
                "folder that holds both"
            )
        listed = listed_files(folder)
        if path.name not in listed:
            raise InputError(
                f"{path}: not listed in {folder / ROS2_METADATA}, so not part of that bag "
                f"(it lists {', '.join(listed) or 'no file'}); a .db3 is read as part of its "
                "bag folder"
            )
        return folder
    if suffix == ".active" or path.name.lower().endswith(".bag.active"):
        raise InputError(
            f"{path}: a ROS 1 recording that was never closed (.active: no index); run "
            "rosbag reindex on it, then give the .bag"
        )
    if not looks_like_ros1_bag(path):
        raise InputError(
            f"{path}: not a ROS 1 bag (no '#ROSBAG V2.0' line at its start); give a .bag file "
            "or a ROS 2 bag folder"
        )
    return path


def _damage_said(exc: BaseException) -> str:
    """What stopped reading a damaged bag: an operating system's reason in its words, a
    parser's failure (an AssertionError, a KeyError 96 from corrupt bytes) as what it means."""
    if isinstance(exc, OSError):
        return _one_line(exc)
    return "its bytes there do not parse: a corrupted or cut-off file"


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


@contextmanager
def _open(path: Path) -> Iterator[Any]:
    """rosbags' AnyReader over one bag, its failures as one-line input errors. A ROS 1 bag
    not named .bag (AnyReader goes by the name) is read through a link that is."""
    from rosbags.highlevel import AnyReader

    kind = "ROS 1 bag" if path.is_file() else "ROS 2 bag folder"
    if not path.is_file():
        ros2_metadata(path)  # its own words for a metadata.yaml that is no bag's (rosbags: "'NoneType' ...")
    with tempfile.TemporaryDirectory(prefix="fgins-bag-") as scratch:
        source = path
        if path.is_file() and path.suffix != ".bag":
            source = Path(scratch) / "recording.bag"
            os.symlink(path.resolve(), source)
        try:
            reader = AnyReader([source])
            reader.open()
        except Exception as exc:  # rosbags raises several kinds: all mean "cannot read"
            why = _one_line(exc)
            hint = ""
            if path.is_file() and "index" in why.lower():
                hint = "; a recording cut off before its index was written: run rosbag reindex"
            elif not path.is_file() and ("malformed" in why.lower() or "not a database" in why.lower()):
                # SQLite refuses a damaged or cut-off file as a whole: nothing of it is read.
                hint = (
                    "; its .db3 is damaged or cut off (a recording stopped mid-write), so reading "
                    "stopped before its first message: `sqlite3 FILE.db3 .recover` may salvage "
                    "the messages into a readable database"
                )
            raise InputError(f"{path}: cannot read this {kind}: {why}{hint}") from None
        try:
            yield reader
        finally:
            reader.close()


class _BagScan(TopicScan):
    """The MCAP scan fed from a bag: connections as channels, messages as records."""

    def __init__(
        self,
        path: Path,
        reader: Any,
        use_header_stamp: bool,
        overrides: dict[str, str | None],
        roles: tuple[str, ...] = (),
    ) -> None:
        super().__init__(path, use_header_stamp, overrides, roles)
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
            msgdef = getattr(connection, "msgdef", None)  # .msg text, IDL or none
            is_msg = getattr(getattr(msgdef, "format", None), "name", "") == "MSG"
            definition = (getattr(msgdef, "data", "") or "") if is_msg else ""
            self.schemas[cid] = Schema(
                id=cid,
                name=ros2_type_name(connection.msgtype),
                encoding="ros1msg" if ros1 else "ros2msg",
                data=definition.encode("utf-8", errors="replace"),
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
        self.choose({cid: int(c.msgcount) for cid, c in self.connections.items()})
        chosen = {c.channel_id for c in (self.chosen or {}).values()}
        for cid in list(self.accumulators):
            if cid not in chosen:
                self.discard(cid)

    def read(self, progress: bool) -> None:
        """Every message of the chosen streams (all their connections); the counts reported
        afterwards are those read for these, the index's for the others."""
        from tqdm import tqdm

        wanted_ids = [cid for cid in self.connections
                      if self.merged_into.get(cid, cid) in self.accumulators]  # fmt: skip
        ids = {id(self.connections[cid]): cid for cid in wanted_ids}
        wanted = [self.connections[cid] for cid in wanted_ids]
        self.counts = {cid: int(c.msgcount) for cid, c in self.connections.items()
                       if cid not in wanted_ids}  # fmt: skip
        total = sum(int(c.msgcount) for c in wanted)
        done = 0
        with tqdm(
            total=total, desc=f"reading {self.path.name}", unit="msg", disable=not progress,
            leave=False,
        ) as bar:  # fmt: skip
            try:
                for connection, timestamp, data in self.reader.messages(connections=wanted):
                    self.on_data(ids[id(connection)], int(timestamp), data)
                    done += 1
                    if done % 4096 == 0:
                        bar.update(4096)
            except (KeyboardInterrupt, MemoryError):
                raise
            except Exception as exc:  # a damaged chunk or database: say where it stopped
                raise InputError(
                    f"{self.path}: damaged bag: reading stopped after {done} of the "
                    f"{total} messages of the chosen topics ({_damage_said(exc)})"
                ) from None
        for role, chosen in (self.chosen or {}).items():
            indexed = sum(int(c.msgcount) for cid, c in self.connections.items()
                          if self.merged_into.get(cid, cid) == chosen.channel_id)  # fmt: skip
            read = self.counts.get(chosen.channel_id, 0)
            if read != indexed:  # a stale metadata.yaml: the report says what was read
                self.report.append(
                    f"{role}: {chosen.topic}: {read} messages read (the bag's index said "
                    f"{indexed})"
                )


def _scan(
    path: Path,
    reader: Any,
    use_header_stamp: bool,
    topics: dict[str, str | None],
    progress: bool,
    roles: tuple[str, ...] = (),
) -> _BagScan:
    scan = _BagScan(path, reader, use_header_stamp, topics, roles)
    try:
        scan.add_connections()
        scan.read(progress)
    except BaseException:
        scan.close()
        raise
    return scan


def _unlisted_files(path: Path) -> list[str]:
    """Storage files in a ROS 2 bag folder that its metadata.yaml does not list (a copy, a
    file of another recording): not part of the bag, so not read, and said."""
    if not is_ros2_bag_folder(path):
        return []
    listed = set(listed_files(path))
    return sorted(
        p.name for p in path.iterdir()
        if p.suffix.lower() in (".db3", ".mcap", ".zstd") and p.name not in listed
    )  # fmt: skip


def unlisted_warning(path: Path) -> list[str]:
    """The warning for storage files a bag folder holds but does not list ([] if none)."""
    unlisted = _unlisted_files(path)
    if not unlisted:
        return []
    return [f"{path}: {', '.join(unlisted)} not listed in its {ROS2_METADATA}: not part of the "
            "bag, not read"]  # fmt: skip


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
    path = bag_path(Path(path))
    with _open(path) as reader:
        scan = _scan(
            path, reader, use_header_stamp, {ROLE_IMU: imu_topic, ROLE_GNSS: gnss_topic}, progress
        )
        scan.warnings.extend(unlisted_warning(path))
        try:
            return assemble(scan)
        finally:
            scan.close()


def read_rosbag_gnss(
    path: str | Path, *, gnss_topic: str | None = None, progress: bool = False
) -> tuple[GnssData, list[str]]:
    """The GNSS fixes (with velocity) of a bag and the reader's warnings; no IMU read."""
    path = bag_path(Path(path))
    with _open(path) as reader:
        scan = _scan(path, reader, True, {ROLE_IMU: None, ROLE_GNSS: gnss_topic}, progress,
                     roles=(ROLE_GNSS, ROLE_VELOCITY))  # fmt: skip
        scan.warnings.extend(unlisted_warning(path))
        try:
            gnss, _ = assemble_gnss(scan, need_imu=False)
            return gnss, scan.warnings
        finally:
            scan.close()


def summarize_rosbag(path: str | Path) -> str:
    """What ``fgins inspect`` prints for a bag: its connections with type, role and the
    index's message count (a ROS 2 bag's counts are its metadata.yaml's)."""
    path = bag_path(Path(path))
    with _open(path) as reader:
        kind = "ROS 2 bag" if reader.is2 else "ROS 1 bag"
        span = (reader.end_time - reader.start_time) / 1e9 if reader.message_count else 0.0
        lines = [
            f"{path} ({kind}): {reader.message_count} messages in its index over {span:.3f} s, "
            f"{len(reader.connections)} connections"
        ]
        topics: dict[tuple[str, str], list[int]] = {}
        for connection in reader.connections:
            key = (connection.topic, ros2_type_name(connection.msgtype))
            topics.setdefault(key, []).append(int(connection.msgcount))
        for (topic, name), counts in sorted(topics.items()):
            role = role_of_schema(name) or "not used"
            count = sum(counts)
            rate = f", ~{count / span:.2f} Hz" if span > 0 and count > 1 else ""
            publishers = f" from {len(counts)} connections" if len(counts) > 1 else ""
            lines.append(f"  {topic}: {name} -> {role}; {count} messages{rate}{publishers}")
        lines.extend(f"  warning: {w}" for w in unlisted_warning(path))
    return "\n".join(lines)
