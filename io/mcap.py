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

Here: choosing channels and assembling the dataset (:class:`TopicScan`), and inspection;
records are streamed by :mod:`fgins.io.mcap_stream`, messages decoded into sensor arrays by
:mod:`fgins.io.ros_messages`.
"""

from __future__ import annotations

import math
from array import array
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.records import Channel, Message, Schema

from fgins.datatypes import BaroData, Dataset, GnssData, InputError, Origin
from fgins.io.mcap_stream import (
    StreamOutcome,
    check_magic,
    damage_warning,
    read_summary,
    stream_records,
)
from fgins.io.ros_messages import (
    ROLE_BARO,
    ROLE_GNSS,
    ROLE_IMU,
    ROLE_VELOCITY,
    Accumulator,
    BaroAccumulator,
    FixAccumulator,
    ImuAccumulator,
    NmeaAccumulator,
    attach_velocity,
    build_fixes,
    build_imu,
    build_nmea,
    make_accumulator,
    message_decoder,
    nonstandard_imu,
    role_of_schema,
    ros2_type_name,
    sorted_unique,
)

# Channel metadata that marks channels fgins wrote (see fgins.io.mcap_writer).
PRODUCER_KEY, PRODUCER_FGINS = "producer", "fgins"

# Log times (ns) are unsigned 64-bit in MCAP; one beyond a signed 64-bit integer (year 2262)
# comes only from corrupt bytes, and broke the readers' int64 arrays (an internal error on a
# damaged recording; outside tester). Such a message is counted as damaged, not read.
LOG_TIME_LIMIT = 2**63


@dataclass
class McapResult:
    """What :func:`read_mcap` returns: the data and human-readable lines about how it was read."""

    dataset: Dataset
    report: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


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
    ranked = sorted(mine, key=lambda c: (_derived(c, role), -counts.get(c.channel_id, 0), c.topic))
    best = ranked[0]
    if len(ranked) == 1:
        why = "the only candidate"
    else:
        others = ", ".join(f"{c.topic} ({counts.get(c.channel_id, 0)})" for c in ranked[1:])
        best_count = counts.get(best.channel_id, 0)
        tied = [c.topic for c in ranked[1:]
                if counts.get(c.channel_id, 0) == best_count and not _derived(c, role)]  # fmt: skip
        tie = " (tied; first by name)" if tied else ""
        derived = [c.topic for c in ranked[1:] if _derived(c, role)]
        most = max(counts.get(c.channel_id, 0) for c in ranked) == best_count
        why = (
            f"{'most messages' if most else 'a receiver by its name'} among {len(ranked)} "
            f"candidates{tie}; others: {others}"
        )
        if role == ROLE_GNSS and not tied and warnings is not None:
            # Fixes from a fusion node (robot_localization's /gps/filtered at 20 Hz) beside
            # the receiver's: read as fixes, they were 3 m off at 88 times their sigmas,
            # chi2/dof 0.11, unsaid (outside tester). The choice is said, and the topics whose
            # names say fused or filtered come last whatever their count.
            warnings.append(
                f"gnss: {len(ranked)} GNSS topics; read {best.topic} "
                f"({counts.get(best.channel_id, 0)} messages), not {others}"
                + (
                    f" ({', '.join(derived)}: by {'its' if len(derived) == 1 else 'their'} "
                    "name a fused, filtered or INS output, not a receiver's)"
                    if derived
                    else ""
                )
                + ": give --gnss-topic TOPIC to read another"
            )
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


# Words in a topic's name that mark a GNSS or velocity topic as an estimator's output (a
# fusion node's, a filter's), not a receiver's measurement.
DERIVED_TOPIC_WORDS = ("filtered", "fused", "fusion", "odom", "ekf", "ukf", "smoothed",
                       "estimate", "localization", "navsat_transform")  # fmt: skip
# Whole name parts (between "/" and "_") that mark an INS's output: an INS driver publishes its
# fused solution as a NavSatFix under its own or the IMU's name (SBG's /imu/nav_sat_fix at 50
# Hz, Xsens' /xsens/gnss_pose_fix at 20 Hz), read before a 1 Hz /ublox/fix for its count: 1-1.5
# m off at z 3-7, a lever arm and a gyro scale "corrected" from its errors (outside tester).
INS_TOPIC_PARTS = frozenset(("ins", "imu", "xsens", "sbg", "vectornav", "inspva", "pose"))


def _derived(candidate: _Candidate, role: str) -> bool:
    """Does the candidate's topic name say an estimator's output (GNSS and velocity roles)?"""
    if role not in (ROLE_GNSS, ROLE_VELOCITY):
        return False
    name = candidate.topic.lower()
    parts = set(name.replace("_", "/").split("/"))
    return any(word in name for word in DERIVED_TOPIC_WORDS) or bool(parts & INS_TOPIC_PARTS)


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
        self.accumulators: dict[int, Accumulator] = {}
        self.decoders: dict[int, Callable[[bytes], Any] | None] = {}
        self.encodings: dict[int, str] = {}  # channel id -> message encoding
        self.outcome = StreamOutcome()
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
            unlike = nonstandard_imu(schema)
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

    def new_accumulator(self, channel_id: int) -> Accumulator:
        candidate = self.candidates[channel_id]
        accumulator = make_accumulator(candidate.role, candidate.topic, candidate.schema_name)
        if isinstance(accumulator, ImuAccumulator):
            accumulator.set_encoding(self.encodings[channel_id])
        return accumulator

    def make_decoder(
        self, schema: Schema | None, channel: Channel
    ) -> Callable[[bytes], Any] | None:
        """bytes -> message for a non-IMU channel (None: not decodable here)."""
        return message_decoder(schema, channel)

    def on_message(self, record: Message) -> None:
        self.on_data(record.channel_id, record.log_time, record.data)

    def on_data(self, cid: int, log_time: int, data: bytes) -> None:
        cid = self.merged_into.get(cid, cid)
        self.counts[cid] = self.counts.get(cid, 0) + 1
        acc = self.accumulators.get(cid)
        if acc is None:
            return
        if not 0 <= log_time < LOG_TIME_LIMIT:  # corrupt bytes: a record no recorder writes
            acc.decode_errors += 1
            return
        try:
            if isinstance(acc, ImuAccumulator):
                acc.add_raw(data, log_time, self.use_header_stamp)
            else:
                message = self.decoders[cid](data)  # type: ignore[misc]
                acc.add(message, log_time, self.use_header_stamp)  # type: ignore[attr-defined]
        except Exception:  # one corrupt message must not end the read: counted, reported
            acc.decode_errors += 1

    def run(self, progress: bool) -> None:
        for record in stream_records(self.path, self.outcome, progress, self.path.name):
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
        if isinstance(acc, NmeaAccumulator):
            acc.close()
            acc.path.unlink(missing_ok=True)

    def close(self) -> None:
        for cid in list(self.accumulators):
            self.discard(cid)


def _accumulator_for(scan: TopicScan, role: str) -> Accumulator | None:
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


def _refuse_truncated_without_messages(scan: TopicScan) -> None:
    """A recording cut off (or damaged) before its first complete message: the error says
    so and where reading stopped, not only that a channel is missing."""
    outcome = scan.outcome
    if not outcome.truncated or outcome.messages:
        return
    what = (
        f"a damaged record at byte {outcome.damaged_record_at} of {outcome.cut_at}"
        if outcome.damaged_record_at >= 0
        else f"file truncated at byte {outcome.cut_at}"
    )
    channels = f" ({len(scan.channels)} channel(s) declared before it)" if scan.channels else ""
    raise InputError(
        f"{scan.path}: {what}: no complete message before it{channels}, nothing to read; the "
        "recording was cut off (or damaged) before its data: give a complete copy"
    )


def _cut_note(scan: TopicScan, what: str) -> str:
    """'; the file is truncated ...' for a missing channel of a cut-off recording, else ''."""
    outcome = scan.outcome
    if not outcome.truncated or outcome.damaged_record_at >= 0 or outcome.data_end_seen:
        return ""
    return (
        f"; the file is truncated at byte {outcome.cut_at} after {outcome.messages} "
        f"message(s): the {what} channel may be in the part that was cut off"
    )


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
    damage = damage_warning(path, scan.outcome)
    if damage:
        warnings.append(damage)
    for acc in scan.accumulators.values():
        # Read in log-time order whatever order the file stores the messages in (a valid
        # MCAP may hold its chunks out of order; it looked like "the log mixes clocks").
        backwards = acc.put_in_log_time_order()
        if backwards:
            report.append(
                f"{acc.topic}: messages stored out of log-time order ({backwards} step(s) "
                "back); read in log-time order"
            )
    for cid, why in sorted(scan.skipped.items()):
        topic = scan.channels[cid].topic
        report.append(f"skipped {topic}: {why} ({scan.counts.get(cid, 0)} messages)")
    imu_acc = _accumulator_for(scan, ROLE_IMU)
    gnss_acc = _accumulator_for(scan, ROLE_GNSS)
    if (imu_acc is None and need_imu) or gnss_acc is None:
        _refuse_truncated_without_messages(scan)
    if imu_acc is None and need_imu:
        raise InputError(
            f"{path}: no IMU channel (sensor_msgs/msg/Imu) found; record the IMU topic "
            f"or give an IMU CSV{_fgins_output_only(scan)}{_unreadable(scan, ROLE_IMU)}"
            f"{_cut_note(scan, 'IMU')}"
        )
    if gnss_acc is None:
        raise InputError(
            f"{path}: no GNSS channel (NavSatFix, GPSFix, foxglove.LocationFix, "
            f"nmea_msgs/Sentence) found; record a GNSS topic or give an NMEA/GNSS CSV"
            f"{_fgins_output_only(scan)}{_unreadable(scan, ROLE_GNSS)}"
            f"{_cut_note(scan, 'GNSS')}"
        )
    for acc in scan.accumulators.values():
        if acc.decode_errors:
            warnings.append(f"{acc.topic}: {acc.decode_errors} messages could not be decoded")
        if acc.stamp_fallbacks:
            warnings.append(
                f"{acc.topic}: {acc.stamp_fallbacks} messages with a zero header stamp; "
                "their log time was used"
            )
    if isinstance(gnss_acc, NmeaAccumulator):
        gnss = build_nmea(gnss_acc, path, warnings)
    else:
        assert isinstance(gnss_acc, FixAccumulator)
        if gnss_acc.no_fix:
            warnings.append(f"gnss {gnss_acc.topic}: {gnss_acc.no_fix} no-fix messages dropped")
        if gnss_acc.malformed_covariance:
            warnings.append(
                f"gnss {gnss_acc.topic}: {gnss_acc.malformed_covariance} fix message(s) with a "
                "position covariance said to be known that is not 9 values (a 3x3 matrix): "
                "their sigmas are taken as unknown"
            )
        if gnss_acc.correlated_covariance:
            warnings.append(
                f"gnss {gnss_acc.topic}: {gnss_acc.correlated_covariance} fix message(s) with a "
                f"position covariance whose axes correlate (|r| up to "
                f"{gnss_acc.largest_correlation:.2f}): each axis is weighted by its own variance, "
                "the correlation is not used"
            )
        gnss = build_fixes(gnss_acc, warnings)
    if len(gnss) == 0:
        no_fix = getattr(gnss_acc, "no_fix", 0)
        why = (
            f"all {no_fix} of its fix messages report no fix (NavSatFix status -1) or no position"
            if no_fix and not gnss_acc.decode_errors
            else f"{gnss_acc.decode_errors} undecodable messages, {no_fix} without a fix"
        )
        raise InputError(
            f"{path}: GNSS topic {gnss_acc.topic} has no valid fix ({why}); nothing to anchor "
            "the trajectory"
        )
    velocity_acc = _accumulator_for(scan, ROLE_VELOCITY)
    if velocity_acc is not None:
        attach_velocity(gnss, velocity_acc, warnings, report)  # type: ignore[arg-type]
    return gnss, imu_acc


def assemble_dataset(scan: TopicScan, gnss: GnssData, imu_acc: Any) -> McapResult:
    path, report, warnings = scan.path, scan.report, scan.warnings
    gnss_acc = _accumulator_for(scan, ROLE_GNSS)
    imu = build_imu(imu_acc, warnings)
    imu_config = imu_acc.noise_config(imu.rate_hz)
    if imu_config:
        report.append(
            f"imu noise from the sensor_msgs/Imu covariances of {imu_acc.topic}: "
            + ", ".join(f"{k} = {v:.3g}" for k, v in imu_config.items())
            + " (at "
            + f"{imu.rate_hz:.1f} Hz): used for the terms neither --imu-preset nor a --config "
            "[imu] table sets (those replace them), the other [imu] terms from the preset"
        )
    baro = None
    baro_acc = _accumulator_for(scan, ROLE_BARO)
    if isinstance(baro_acc, BaroAccumulator) and len(baro_acc):
        t = np.frombuffer(baro_acc.t, dtype=float)
        idx = sorted_unique(t, f"baro {baro_acc.topic}", warnings)
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
    check_magic(path)
    scan = TopicScan(path, use_header_stamp, topics, roles)
    try:
        summary = read_summary(path)
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
    check_magic(path)
    outcome = StreamOutcome()
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    log_times: dict[int, array] = {}
    for record in stream_records(path, outcome, progress, f"inspecting {path.name}"):
        if isinstance(record, Message) and 0 <= record.log_time < LOG_TIME_LIMIT:
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
        lines.append(f"TRUNCATED at byte {outcome.cut_at}; everything before the cut is listed")
    damage = damage_warning(path, outcome)
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
    elif outcome.truncated and not channels:  # a cut before its first record: nothing to list
        raise InputError(
            f"{path}: file truncated at byte {outcome.cut_at}: no complete record after the "
            "MCAP magic, nothing to list; the recording was cut off before its data"
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
