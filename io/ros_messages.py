"""ROS 1 / ROS 2 / Foxglove sensor messages -> fgins sensor arrays, shared by the MCAP and
ROS bag readers: which schema fills which role, message decoding (a fast path for
``sensor_msgs/Imu`` in CDR and ROS 1 encodings, rosbags' deserializers and Foxglove's
protobuf/JSON otherwise), per-channel accumulators of plain floats (never messages), and
the :class:`ImuData` / :class:`GnssData` they build.
"""

from __future__ import annotations

import datetime
import json
import math
import os
import re
import struct
import tempfile
from array import array
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from mcap.records import Channel, Schema

from fgins.datatypes import GnssData, ImuData, InputError
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
# Decoding
# --------------------------------------------------------------------------------------------


def message_decoder(schema: Schema | None, channel: Channel) -> Callable[[bytes], Any] | None:
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


def nonstandard_imu(schema: Schema | None) -> str | None:
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


def _imu_ros1_reader(data: bytes) -> tuple[int, tuple[float, ...], bytes]:
    """sensor_msgs/Imu from ROS 1 serialization (little endian, packed): header (seq,
    stamp secs/nsecs, frame_id), orientation (4 doubles) and its covariance (9), then
    angular velocity (3), its covariance (9), linear acceleration (3)."""
    sec, nanosec, frame_len = struct.unpack_from("<IIII", data, 0)[1:]
    gyro_at = 16 + frame_len + 13 * 8
    values = struct.unpack_from("<3d9d3d", data, gyro_at)
    return sec * 1_000_000_000 + nanosec, values[:3] + values[12:15], data[16 : 16 + frame_len]


def _imu_ros1_covariance_diagonals(data: bytes) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Diagonals of angular_velocity_covariance and linear_acceleration_covariance (ROS 1)."""
    frame_len = struct.unpack_from("<I", data, 12)[0]
    gyro_cov_at = 16 + frame_len + 13 * 8 + 3 * 8
    gyro_cov = struct.unpack_from("<9d", data, gyro_cov_at)
    accel_cov = struct.unpack_from("<9d", data, gyro_cov_at + 12 * 8)
    return gyro_cov[0::4], accel_cov[0::4]


def _imu_cdr_reader(data: bytes) -> tuple[int, tuple[float, ...], bytes]:
    """sensor_msgs/msg/Imu from CDR without generic decoding (the high-rate stream).

    Returns (header stamp ns, (gx, gy, gz, ax, ay, az), the frame_id's bytes). CDR aligns
    8-byte fields to 8 relative to the byte after the 4-byte encapsulation header.
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
    return sec * 1_000_000_000 + nanosec, gyro + accel, data[16 : 16 + frame_len]


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


def _has(msg: Any, name: str) -> bool:
    """Is the (optional) field ``name`` set? An unset protobuf sub-message reads as an empty
    default one, all zeros: foxglove-sdk's LocationFix without its velocity was read as
    standing still (outside tester: 'km/h' refused by smooth, zeros written by convert)."""
    if isinstance(msg, dict):
        return msg.get(name) is not None
    has_field = getattr(msg, "HasField", None)
    if has_field is not None:
        try:
            return bool(has_field(name))
        except ValueError:  # not a message field of this type
            return False
    return getattr(msg, name, None) is not None


def _ros_stamp_ns(msg: Any) -> int:
    stamp = msg.header.stamp
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _foxglove_stamp_ns(msg: Any) -> int:
    stamp = _get(msg, "timestamp")
    if stamp is None:
        return 0
    if isinstance(stamp, dict):  # JSON: {"sec": .., "nsec": ..}
        return int(stamp.get("sec", 0)) * 1_000_000_000 + int(stamp.get("nsec", 0))
    if isinstance(stamp, str):  # protobuf's JSON mapping of a Timestamp
        return _rfc3339_ns(stamp)
    return int(stamp.seconds) * 1_000_000_000 + int(stamp.nanos)


_RFC3339 = re.compile(r"(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d)(?:\.(\d{1,9}))?(Z|[+-]\d\d:\d\d)")


def _rfc3339_ns(text: str) -> int:
    """'2024-05-01T12:00:00.123456789Z' (0-9 fraction digits, Z or an offset) -> POSIX ns, as
    protobuf's JSON mapping writes a google.protobuf.Timestamp (a LocationFix written from a
    protobuf message's JSON); ValueError otherwise (counted as undecodable)."""
    match = _RFC3339.fullmatch(text.strip())
    if match is None:
        raise ValueError(f"timestamp {text!r} is neither {{sec, nsec}} nor RFC 3339")
    whole = datetime.datetime.fromisoformat(match[1] + ("+00:00" if match[3] == "Z" else match[3]))
    return int(whole.timestamp()) * 1_000_000_000 + int((match[2] or "0").ljust(9, "0"))


def _std_from_covariance(covariance: Any, covariance_type: Any) -> tuple[float, float, float]:
    """1-sigma east/north/up from an ENU row-major 3x3 covariance (REP-145 / Foxglove)."""
    if isinstance(covariance_type, str):  # JSON may spell the enum
        covariance_type = 0 if covariance_type.upper() == "UNKNOWN" else 1
    if covariance is None or len(covariance) != 9 or int(covariance_type or 0) == 0:
        return (math.nan, math.nan, math.nan)
    diag = (float(covariance[0]), float(covariance[4]), float(covariance[8]))
    # A variance given as known but not positive goes on as such: the validation layer
    # counts it and ignores it (fgins.io.gnss_checks), as a CSV's std column of zeros.
    return tuple(math.sqrt(v) if v > 0 else v for v in diag)  # type: ignore[return-value]


CORRELATION_SAID = 0.1  # an off-diagonal correlation of the position covariance beyond this is said


def _correlation(covariance: Any, covariance_type: Any) -> float:
    """The largest |correlation| between the axes of a fully known 3x3 position covariance
    (type 3, COVARIANCE_TYPE_KNOWN; 0 for any other type, where only the diagonal means
    anything, and when malformed or without a positive diagonal)."""
    if isinstance(covariance_type, str):
        covariance_type = 3 if covariance_type.upper() == "KNOWN" else 0
    if covariance is None or len(covariance) != 9 or int(covariance_type or 0) != 3:
        return 0.0
    c = [float(x) for x in covariance]
    out = 0.0
    for i, j in ((0, 1), (0, 2), (1, 2)):
        scale = c[4 * i] * c[4 * j]
        if scale > 0 and math.isfinite(scale):
            out = max(out, abs(c[3 * i + j]) / math.sqrt(scale))
    return out


def _malformed_covariance(covariance: Any, covariance_type: Any) -> bool:
    """A covariance said to be known whose length is not the 3x3 matrix's 9."""
    if isinstance(covariance_type, str):
        covariance_type = 0 if covariance_type.upper() == "UNKNOWN" else 1
    return int(covariance_type or 0) != 0 and covariance is not None and len(covariance) != 9


# --------------------------------------------------------------------------------------------
# Accumulators: one per chosen channel, Python lists of floats (never messages)
# --------------------------------------------------------------------------------------------


class Accumulator:
    def __init__(self, topic: str, schema_name: str) -> None:
        self.topic = topic
        self.schema_name = schema_name
        self.t = array("d")
        self.log_ns = array("q")  # each row's log time: the order a recording is read in
        self.stamp_fallbacks = 0  # header stamp zero -> log time used
        self.decode_errors = 0
        # Each row's frame_id (an index into frame_names): two sensors on one topic (a ROS 1
        # topic with two publishers, one ROS 2 channel) differ in it.
        self.frames = array("q")
        self.frame_names: list[str] = []
        self._frame_of: dict[str | bytes, int] = {}  # name (or its raw bytes) -> index

    def frame_named(self, name: str | bytes) -> int:
        """The index of frame_id ``name`` (a str, or the raw bytes of a serialized string)."""
        index = self._frame_of.get(name)
        if index is None:
            text = name.decode("utf-8", "replace").rstrip("\x00") if isinstance(name, bytes) else name
            index = self._frame_of.get(text)
            if index is None:
                index = len(self.frame_names)
                self.frame_names.append(text)
                self._frame_of[text] = index
            self._frame_of[name] = index
        return index

    def one_source(self, role: str, sensors: str, warnings: list[str]) -> np.ndarray:
        """Mask of the rows of one sensor: where rows of two or more frame_ids interleave in
        time (two ``sensors`` publishing on one topic), those of the frame_id with most rows,
        said; frame_ids one after another (a driver restarted under another name) are one
        stream."""
        frames = np.frombuffer(self.frames, dtype=np.int64)
        keep = np.ones(frames.size, dtype=bool)
        if len(self.frame_names) < 2 or frames.size != len(self.t):
            return keep
        t = np.frombuffer(self.t, dtype=float)
        counts = np.bincount(frames, minlength=len(self.frame_names))
        main = int(min(np.flatnonzero(counts == counts.max()), key=lambda i: self.frame_names[i]))
        first, last = t[frames == main].min(), t[frames == main].max()
        others = [
            i for i in np.flatnonzero(counts)
            if i != main and np.any((t[frames == i] > first) & (t[frames == i] < last))
        ]  # fmt: skip
        if not others:
            return keep
        keep = ~np.isin(frames, others)
        listed = ", ".join(
            f"{self.frame_names[i] or '(empty)'}: {counts[i]}" for i in [main, *others]
        )
        warnings.append(
            f"{role} {self.topic}: messages of {len(others) + 1} frame_ids interleave ({listed}): "
            f"two {sensors} on one topic; read frame_id {self.frame_names[main] or '(empty)'} "
            f"only (the most messages), {int((~keep).sum())} of the others left out"
        )
        return keep

    def __len__(self) -> int:
        return len(self.t)

    def put_in_log_time_order(self) -> int:
        """Reorder the rows by log time (ties by time), as the ``mcap`` reader's
        ``iter_messages(log_time_order=True)`` yields them: a recording whose messages are
        stored in another order (valid MCAP: chunks written out of order) then reads as the
        same drive stored in order. Returns the number of steps back in log time found."""
        log_ns = np.frombuffer(self.log_ns, dtype=np.int64)
        if log_ns.size != len(self.t):  # rows not recorded one per message: left as read
            return 0
        backwards = int(np.count_nonzero(np.diff(log_ns) < 0))
        if backwards:
            order = np.lexsort((np.frombuffer(self.t, dtype=float), log_ns))
            if not self._permute(order):
                return 0
            self.t = _reordered(self.t, order, "d")
            self.log_ns = _reordered(self.log_ns, order, "q")
        return backwards

    def _permute(self, order: np.ndarray) -> bool:
        """Reorder the subclass's own per-row arrays (``t`` and ``log_ns`` are done after);
        False: they cannot be, the rows stay as read."""
        return True

    def time(self, stamp_ns: int, log_time_ns: int, use_header_stamp: bool) -> float:
        if use_header_stamp and stamp_ns > 0:
            return stamp_ns / 1e9
        if use_header_stamp:
            self.stamp_fallbacks += 1
        return log_time_ns / 1e9


class ImuAccumulator(Accumulator):
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
        stamp, values, frame = self.read_values(data)
        self.t.append(self.time(stamp, log_time, use_header_stamp))
        self.log_ns.append(log_time)
        self.values.extend(values)
        self.frames.append(self.frame_named(frame))
        if len(self.t) <= self.COVARIANCE_SAMPLES:
            gyro_diag, accel_diag = self.read_covariances(data)
            self.gyro_var.append(_known_variance(gyro_diag))
            self.accel_var.append(_known_variance(accel_diag))

    def _permute(self, order: np.ndarray) -> bool:
        self.values = _reordered(self.values, order, "d", width=6)
        self.frames = _reordered(self.frames, order, "q")
        return True

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


class FixAccumulator(Accumulator):
    """NavSatFix, GPSFix and LocationFix rows."""

    COLUMNS = ("lat", "lon", "alt", "se", "sn", "su", "quality", "hdop", "vdop", "pdop")
    COLUMNS += ("ve", "vn", "vu", "speed", "course", "sats")

    def __init__(self, topic: str, schema_name: str) -> None:
        super().__init__(topic, schema_name)
        self.rows = array("d")
        self.no_fix = 0
        self.malformed_covariance = 0  # said known, not 9 values: sigmas unknown, counted
        self.correlated_covariance = 0  # with correlated axes: their diagonal is used, counted
        self.largest_correlation = 0.0
        self.first_t = math.inf  # of any message, with a fix or not (the t0 of outages)

    def _frame_index(self, msg: Any) -> int:
        header = _get(msg, "header")
        return self.frame_named(
            str(_get(header, "frame_id", "") if header is not None else _get(msg, "frame_id", "") or "")
        )

    def add(self, msg: Any, log_time: int, use_header_stamp: bool) -> None:
        nan = math.nan
        velocity = (nan, nan, nan)
        speed = course = nan
        hdop = vdop = pdop = nan
        sats = nan
        if self.schema_name == LOCATIONFIX:
            stamp = _foxglove_stamp_ns(msg)
            quality = 1.0
            vel = _get(msg, "velocity") if _has(msg, "velocity") else None
            if vel is not None:  # newer LocationFix carries ENU velocity
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
        covariance = _get(msg, "position_covariance")
        covariance_type = _get(msg, "position_covariance_type", 0)
        std = _std_from_covariance(covariance, covariance_type)
        self.malformed_covariance += _malformed_covariance(covariance, covariance_type)
        correlation = _correlation(covariance, covariance_type)
        if correlation > CORRELATION_SAID:
            self.correlated_covariance += 1
            self.largest_correlation = max(self.largest_correlation, correlation)
        lat = float(_get(msg, "latitude", nan))
        lon = float(_get(msg, "longitude", nan))
        # NaN (or no) altitude: a 2-D fix (NavSatFix's documented "no altitude"), kept; the
        # validation layer gives it the height of the 3-D fixes around it, as for a CSV.
        alt = float(_get(msg, "altitude", nan))
        t = self.time(stamp, log_time, use_header_stamp)
        self.first_t = min(self.first_t, t)
        if not (math.isfinite(lat) and math.isfinite(lon)):
            self.no_fix += 1
            return
        self.t.append(t)
        self.log_ns.append(log_time)
        self.frames.append(self._frame_index(msg))
        self.rows.extend((lat, lon, alt, *std, quality, hdop, vdop, pdop, *velocity))
        self.rows.extend((speed, course, sats))

    def _permute(self, order: np.ndarray) -> bool:
        self.rows = _reordered(self.rows, order, "d", width=len(self.COLUMNS))
        self.frames = _reordered(self.frames, order, "q")
        return True

    def one_receiver(self, warnings: list[str]) -> np.ndarray:
        """Mask of the fixes of one receiver (:meth:`Accumulator.one_source`). Merged, two
        antennas 3 m apart read as one receiver jumping between them: 1.4 m off at 14 times
        the sigmas, blamed on a lever arm and multipath (outside tester)."""
        return self.one_source("gnss", "receivers", warnings)


class VelocityAccumulator(Accumulator):
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
        self.log_ns.append(log_time)
        self.rows.extend((float(linear.x), float(linear.y), float(linear.z), *std))

    def _permute(self, order: np.ndarray) -> bool:
        self.rows = _reordered(self.rows, order, "d", width=6)
        return True


class BaroAccumulator(Accumulator):
    def __init__(self, topic: str, schema_name: str) -> None:
        super().__init__(topic, schema_name)
        self.pressure = array("d")

    def add(self, msg: Any, log_time: int, use_header_stamp: bool) -> None:
        self.t.append(self.time(_ros_stamp_ns(msg), log_time, use_header_stamp))
        self.log_ns.append(log_time)
        self.pressure.append(float(msg.fluid_pressure))

    def _permute(self, order: np.ndarray) -> bool:
        self.pressure = _reordered(self.pressure, order, "d")
        return True


class NmeaAccumulator(Accumulator):
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
        self.log_ns.append(log_time)
        if sentence[3:6] == "GGA":
            self.fix_stamps.append(t)
        self.file.write(sentence + "\n")

    def _permute(self, order: np.ndarray) -> bool:
        """Rewrite the sentence file in the new order (when it holds one line per message)."""
        self.close()
        lines = self.path.read_text(encoding="ascii", errors="replace").splitlines()
        if len(lines) != order.size:
            return False
        lines = [lines[k] for k in order]
        self.path.write_text("".join(line + "\n" for line in lines), encoding="ascii")
        t = np.frombuffer(self.t, dtype=float)[order]
        self.fix_stamps = array("d", (float(t[k]) for k, line in enumerate(lines)
                                      if line[3:6] == "GGA"))  # fmt: skip
        return True

    def close(self) -> None:
        if not self.file.closed:
            self.file.close()


def _reordered(values: array, order: np.ndarray, typecode: str, width: int = 1) -> array:
    """``values`` (rows of ``width`` items) with its rows in ``order``, as an array."""
    dtype = np.int64 if typecode == "q" else float
    rows = np.frombuffer(values, dtype=dtype).reshape(-1, width)[order]
    out = array(typecode)
    out.frombytes(np.ascontiguousarray(rows).tobytes())
    return out


_ACCUMULATOR_BY_ROLE: dict[str, type[Accumulator]] = {
    ROLE_IMU: ImuAccumulator,
    ROLE_VELOCITY: VelocityAccumulator,
    ROLE_BARO: BaroAccumulator,
}


def make_accumulator(role: str, topic: str, schema_name: str) -> Accumulator:
    if role == ROLE_GNSS:
        cls = NmeaAccumulator if schema_name == NMEA_SENTENCE else FixAccumulator
        return cls(topic, schema_name)
    return _ACCUMULATOR_BY_ROLE[role](topic, schema_name)


# --------------------------------------------------------------------------------------------
# Building the Dataset
# --------------------------------------------------------------------------------------------


def sorted_unique(t: np.ndarray, label: str, warnings: list[str]) -> np.ndarray | slice:
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


def build_imu(acc: ImuAccumulator, warnings: list[str]) -> ImuData:
    # Two IMUs on one topic (two frame_ids interleaving) were read as one at twice the rate,
    # one turned 180 deg "diverged ... check imu_to_vehicle_rpy_deg" (outside tester).
    one = acc.one_source("imu", "IMUs", warnings)
    t = np.frombuffer(acc.t, dtype=float)[one]
    values = np.frombuffer(acc.values, dtype=float).reshape(-1, 6)[one]
    if t.size < 2:
        raise InputError(f"imu topic {acc.topic}: fewer than 2 usable samples; check the recording")
    # the one row policy of every reader (NaN rows, reordering, repeated stamps)
    return imu_from_samples(
        t, values[:, :3], values[:, 3:], source=f"imu {acc.topic}", warnings=warnings
    )


def build_fixes(acc: FixAccumulator, warnings: list[str]) -> GnssData:
    one = acc.one_receiver(warnings)
    t = np.frombuffer(acc.t, dtype=float)[one]
    rows = np.frombuffer(acc.rows, dtype=float).reshape(-1, len(FixAccumulator.COLUMNS))[one]
    idx = sorted_unique(t, f"gnss {acc.topic}", warnings)
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


def build_nmea(acc: NmeaAccumulator, path: Path, warnings: list[str]) -> GnssData:
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


def attach_velocity(
    gnss: GnssData, acc: VelocityAccumulator, warnings: list[str], report: list[str]
) -> None:
    """Fill GNSS ENU velocity from a Twist topic, matched to the nearest fix in time."""
    t_vel = np.frombuffer(acc.t, dtype=float)
    rows = np.frombuffer(acc.rows, dtype=float).reshape(-1, 6)
    idx = sorted_unique(t_vel, f"gnss velocity {acc.topic}", warnings)
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
