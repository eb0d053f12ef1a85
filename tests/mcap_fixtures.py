"""MCAP fixtures for the tests, written by libraries independent of fgins's reader.

* ROS 2 bags (mcap storage) through ``rosbags`` (its own CDR serializer and bag writer);
* Foxglove ``LocationFix`` in protobuf through ``foxglove-sdk``;
* Foxglove ``LocationFix`` in JSON through the plain ``mcap`` writer.

The drive is synthetic with known values: the tests compare what fgins reads with these.
Imported as ``fgins.tests.mcap_fixtures`` (the package maps onto the repository root).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

T0_NS = 1_700_000_000_000_000_000  # a POSIX epoch in ns: header stamps start here
LOG_LATENCY_NS = 3_000_000  # log time = header stamp + 3 ms, so the two time bases differ


@dataclass
class Drive:
    """A synthetic drive: integer-ns stamps and the values each message carries."""

    imu_ns: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    gnss_ns: np.ndarray
    lla: np.ndarray
    std: np.ndarray  # east, north, up 1-sigma (m)
    velocity: np.ndarray  # ENU m/s
    velocity_std: np.ndarray
    status: np.ndarray  # NavSatStatus: -1 = no fix
    baro_ns: np.ndarray
    pressure: np.ndarray

    @property
    def valid(self) -> np.ndarray:
        return self.status >= 0


def make_drive(duration_s: float = 20.0, imu_hz: int = 100, gnss_hz: int = 5) -> Drive:
    """A gently turning drive near Munich; every 17th GNSS epoch has no fix."""
    rng = np.random.default_rng(7)
    imu_ns = T0_NS + np.arange(int(duration_s * imu_hz)) * (1_000_000_000 // imu_hz)
    t_imu = (imu_ns - T0_NS) / 1e9
    gyro = np.column_stack(
        [0.01 * np.sin(t_imu), 0.02 * np.cos(0.5 * t_imu), 0.1 * np.sin(0.2 * t_imu)]
    ) + rng.normal(0, 1e-3, (t_imu.size, 3))
    accel = np.column_stack(
        [0.3 * np.cos(0.3 * t_imu), 0.1 * np.sin(t_imu), 9.81 + 0.05 * np.sin(2 * t_imu)]
    ) + rng.normal(0, 1e-2, (t_imu.size, 3))
    gnss_ns = T0_NS + np.arange(int(duration_s * gnss_hz)) * (1_000_000_000 // gnss_hz)
    t_gnss = (gnss_ns - T0_NS) / 1e9
    lla = np.column_stack(
        [48.137 + 1e-5 * t_gnss, 11.575 + 2e-5 * np.sin(0.1 * t_gnss), 520.0 + 0.1 * t_gnss]
    )
    std = np.column_stack([1.5 + 0.01 * t_gnss, 2.0 + 0.02 * t_gnss, 3.5 + 0.0 * t_gnss])
    # The velocity the positions above have (east: the longitude's rate at 48.137 deg; the
    # unit checks compare the two).
    metres_per_deg = 111_195.0
    velocity = np.column_stack([
        2e-6 * np.cos(0.1 * t_gnss) * metres_per_deg * np.cos(np.radians(48.137)),
        1e-5 * metres_per_deg + 0 * t_gnss,
        0.1 + 0 * t_gnss,
    ])  # fmt: skip
    velocity_std = np.column_stack([0.1 + 0 * t_gnss, 0.2 + 0 * t_gnss, 0.3 + 0 * t_gnss])
    status = np.where(np.arange(t_gnss.size) % 17 == 5, -1, 0)
    baro_ns = T0_NS + np.arange(int(duration_s * 10)) * 100_000_000
    pressure = 101325.0 - 12.0 * (baro_ns - T0_NS) / 1e9
    return Drive(
        imu_ns, gyro, accel, gnss_ns, lla, std, velocity, velocity_std, status, baro_ns, pressure
    )


# ------------------------------------------------------------------------------------------
# ROS 2 bag through rosbags
# ------------------------------------------------------------------------------------------

NMEA_SENTENCE_MSG = "std_msgs/Header header\nstring sentence\n"
UNKNOWN_MSG = "float64 value\n"
GPS_STATUS_MSG = """std_msgs/Header header
uint16 satellites_used
int32[] satellite_used_prn
uint16 satellites_visible
int32[] satellite_visible_prn
int32[] satellite_visible_z
int32[] satellite_visible_azimuth
int32[] satellite_visible_snr
int16 status
uint16 motion_source
uint16 orientation_source
uint16 position_source
"""
GPS_FIX_FLOATS = (
    "latitude longitude altitude track speed climb pitch roll dip time gdop pdop hdop "
    "vdop tdop err err_horz err_vert err_track err_speed err_climb err_time err_pitch "
    "err_roll err_dip"
).split()
GPS_FIX_MSG = (
    "std_msgs/Header header\ngps_msgs/GPSStatus status\n"
    + "".join(f"float64 {name}\n" for name in GPS_FIX_FLOATS)
    + "float64[9] position_covariance\nuint8 position_covariance_type\n"
)


def _typestore(ros1: bool = False):
    """rosbags' ROS 2 Humble (or ROS 1 Noetic) types plus the GNSS ones they lack; ROS 1
    spells GPSFix's package gps_common."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    gps = "gps_common" if ros1 else "gps_msgs"
    store.register(get_types_from_msg(NMEA_SENTENCE_MSG, "nmea_msgs/msg/Sentence"))
    store.register(get_types_from_msg(UNKNOWN_MSG, "acme_msgs/msg/Mystery"))
    store.register(get_types_from_msg(
        GPS_STATUS_MSG, f"{gps}/msg/GPSStatus"))  # fmt: skip
    store.register(get_types_from_msg(
        GPS_FIX_MSG.replace("gps_msgs/", f"{gps}/"), f"{gps}/msg/GPSFix"))  # fmt: skip
    return store


def _header(store, ns: int, frame: str):
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    stamp = Time(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))
    if "seq" in Header.__dataclass_fields__:  # ROS 1
        return Header(seq=0, stamp=stamp, frame_id=frame)
    return Header(stamp=stamp, frame_id=frame)


def write_ros2_bag(directory: Path, drive: Drive, **options: Any) -> Path:
    """Write a rosbag2 in mcap storage; returns the .mcap file inside the bag folder. The
    options are :func:`write_bag`'s (which also writes the same drive as a ROS 1 bag, a ROS 2
    SQLite bag or a ROS 1 MCAP)."""
    write_bag(directory, drive, "ros2-mcap", **options)
    (mcap_file,) = Path(directory).glob("*.mcap")
    return mcap_file


def write_bag(
    path: Path,
    drive: Drive,
    kind: str,
    *,
    imu_topic: str = "/imu/data",
    second_imu_every: int = 0,
    with_baro: bool = True,
    with_velocity: bool = True,
    with_imu: bool = True,
    with_unknown: bool = True,
    nmea_sentences: list[tuple[int, str]] | None = None,
    gpsfix: bool = False,
    imu_variances: tuple[float, float] | None = None,
    publishers: int = 1,
    compression: str = "",
    position_correlation: float = 0.0,
    second_receiver_m: float = 0.0,
    second_imu_frame: bool = False,
    receiver_renamed: bool = False,
) -> Path:
    """The drive through rosbags' serializers: ``kind`` "ros2-mcap" / "ros2-sqlite" (a bag
    folder ``path``), "ros1-bag" (a ``.bag`` file ``path``) or "ros1-mcap" (an MCAP file of
    ROS 1 messages, ros1msg schemas named ``sensor_msgs/Imu`` etc., as ``mcap convert`` makes
    of a .bag, written with the plain mcap writer). Returns ``path``.

    ``imu_variances`` (gyro (rad/s)^2, accel (m/s^2)^2) fills the diagonals of the Imu
    messages' angular_velocity / linear_acceleration covariances (zeros, "unknown", otherwise).

    ``second_imu_every`` > 0 adds ``/imu/raw`` carrying every n-th IMU sample (a second,
    sparser IMU candidate).

    ``second_imu_frame``: a second IMU (frame_id ``imu2``, turned 180 deg about z, 5 ms
    later, at half the rate) publishing on the IMU topic too.
    ``second_receiver_m`` > 0: a second receiver (frame_id ``gps2``) ``second_receiver_m``
    north of the first publishes on /gps/fix too, 0.1 s after each fix; ``receiver_renamed``:
    the fixes of the drive's second half carry frame_id ``gps_b`` (a driver restarted under
    another name).

    ``publishers`` > 1 (ROS 1 kinds): each topic gets that many connections (callers
    ``/node_0``...), its messages dealt to them in turn, as when a driver restarts or two
    nodes publish one topic. ``compression``: "bz2"/"lz4" chunks (ROS 1 bag), "file" /
    "message" zstd (ROS 2 bag).
    """
    ros1 = kind.startswith("ros1")
    store = _typestore(ros1)
    t = store.types
    vec3 = t["geometry_msgs/msg/Vector3"]
    quat = t["geometry_msgs/msg/Quaternion"]
    gps = "gps_common" if ros1 else "gps_msgs"
    records: list[tuple[int, object, object, str]] = []  # (stamp, connection, msg, type)
    with _BagWriter(path, kind, store, compression) as writer:

        def add(topic: str, msgtype: str):
            if publishers > 1:
                return _Dealer([writer.add_connection(topic, msgtype, f"/node_{k}")
                                for k in range(publishers)])  # fmt: skip
            return writer.add_connection(topic, msgtype)

        gyro_cov, accel_cov = np.zeros(9), np.zeros(9)
        if imu_variances is not None:
            gyro_cov = np.diag(np.full(3, imu_variances[0])).ravel()
            accel_cov = np.diag(np.full(3, imu_variances[1])).ravel()
        if with_imu:
            imu_conn = add(imu_topic, "sensor_msgs/msg/Imu")
            imu_conns = [(imu_conn, 1)]
            if second_imu_every:
                imu_conns.append((add("/imu/raw", "sensor_msgs/msg/Imu"), second_imu_every))
            sensors = [("imu_link_with_a_longer_name", 0, np.ones(3))]
            if second_imu_frame:
                sensors.append(("imu2", 5_000_000, np.array([-1.0, -1.0, 1.0])))
            for conn, every in imu_conns:
                for i in range(0, drive.imu_ns.size, every):
                    for frame, later_ns, turn in sensors if conn is imu_conn else sensors[:1]:
                        if later_ns and i % 2:
                            continue
                        ns = int(drive.imu_ns[i]) + later_ns
                        msg = t["sensor_msgs/msg/Imu"](
                            header=_header(store, ns, frame),
                            orientation=quat(x=0.0, y=0.0, z=0.0, w=1.0),
                            orientation_covariance=np.full(9, -1.0),
                            angular_velocity=vec3(*map(float, drive.gyro[i] * turn)),
                            angular_velocity_covariance=gyro_cov,
                            linear_acceleration=vec3(*map(float, drive.accel[i] * turn)),
                            linear_acceleration_covariance=accel_cov,
                        )
                        records.append((ns, conn, msg, "sensor_msgs/msg/Imu"))
        if gpsfix:
            gpsfix_conn = add("/gps/gpsfix", f"{gps}/msg/GPSFix")
            for i, ns in enumerate(map(int, drive.gnss_ns)):
                ve, vn, vu = drive.velocity[i]
                values = dict.fromkeys(GPS_FIX_FLOATS, 0.0)
                values.update(
                    latitude=float(drive.lla[i, 0]),
                    longitude=float(drive.lla[i, 1]),
                    altitude=float(drive.lla[i, 2]),
                    track=float(np.degrees(np.arctan2(ve, vn)) % 360.0),
                    speed=float(np.hypot(ve, vn)),
                    climb=float(vu),
                    hdop=0.9 + 0.01 * i,
                    vdop=1.4,
                    pdop=1.7,
                )
                status = t[f"{gps}/msg/GPSStatus"](
                    header=_header(store, ns, "gps"),
                    satellites_used=9,
                    satellite_used_prn=np.zeros(0, np.int32),
                    satellites_visible=12,
                    satellite_visible_prn=np.zeros(0, np.int32),
                    satellite_visible_z=np.zeros(0, np.int32),
                    satellite_visible_azimuth=np.zeros(0, np.int32),
                    satellite_visible_snr=np.zeros(0, np.int32),
                    status=int(drive.status[i]),
                    motion_source=0,
                    orientation_source=0,
                    position_source=0,
                )
                msg = t[f"{gps}/msg/GPSFix"](
                    header=_header(store, ns, "gps"),
                    status=status,
                    position_covariance=np.zeros(9),
                    position_covariance_type=0,
                    **values,
                )
                records.append((ns, gpsfix_conn, msg, f"{gps}/msg/GPSFix"))
        elif nmea_sentences is None:
            fix_conn = add("/gps/fix", "sensor_msgs/msg/NavSatFix")
            for i, ns in enumerate(map(int, drive.gnss_ns)):
                cov = np.zeros(9)
                cov[[0, 4, 8]] = drive.std[i] ** 2
                cov[1] = cov[3] = 0.3  # off-diagonal terms must not leak into the std
                if position_correlation:  # a full covariance (type 3) with east-north correlated
                    cov[1] = cov[3] = position_correlation * drive.std[i, 0] * drive.std[i, 1]
                renamed = receiver_renamed and i >= drive.gnss_ns.size // 2
                receivers = [(ns, "gps_b" if renamed else "gps", 0.0)]
                if second_receiver_m:
                    receivers.append((ns + 100_000_000, "gps2", second_receiver_m / 111_195.0))
                for stamp, frame, north_deg in receivers:
                    msg = t["sensor_msgs/msg/NavSatFix"](
                        header=_header(store, stamp, frame),
                        status=t["sensor_msgs/msg/NavSatStatus"](
                            status=int(drive.status[i]), service=1
                        ),
                        latitude=float(drive.lla[i, 0]) + north_deg,
                        longitude=float(drive.lla[i, 1]),
                        altitude=float(drive.lla[i, 2]),
                        position_covariance=cov,
                        position_covariance_type=3 if position_correlation else 2,
                    )
                    records.append((stamp, fix_conn, msg, "sensor_msgs/msg/NavSatFix"))
        else:
            nmea_conn = add("/nmea_sentence", "nmea_msgs/msg/Sentence")
            for ns, sentence in nmea_sentences:
                msg = t["nmea_msgs/msg/Sentence"](
                    header=_header(store, ns, "gps"), sentence=sentence
                )
                records.append((ns, nmea_conn, msg, "nmea_msgs/msg/Sentence"))
        if with_velocity:
            vel_conn = add("/gps/vel", "geometry_msgs/msg/TwistWithCovarianceStamped")
            for i, ns in enumerate(map(int, drive.gnss_ns)):
                cov = np.zeros(36)
                cov[[0, 7, 14]] = drive.velocity_std[i] ** 2
                cov[[21, 28, 35]] = 99.0
                twist = t["geometry_msgs/msg/Twist"](
                    linear=vec3(*map(float, drive.velocity[i])), angular=vec3(0.0, 0.0, 0.0)
                )
                msg = t["geometry_msgs/msg/TwistWithCovarianceStamped"](
                    header=_header(store, ns, "gps"),
                    twist=t["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=cov),
                )
                records.append((ns, vel_conn, msg, "geometry_msgs/msg/TwistWithCovarianceStamped"))
        if with_baro:
            baro_conn = add("/baro", "sensor_msgs/msg/FluidPressure")
            for ns, p in zip(map(int, drive.baro_ns), drive.pressure, strict=True):
                msg = t["sensor_msgs/msg/FluidPressure"](
                    header=_header(store, ns, "baro"), fluid_pressure=float(p), variance=0.0
                )
                records.append((ns, baro_conn, msg, "sensor_msgs/msg/FluidPressure"))
        if with_unknown:
            mystery = add("/mystery", "acme_msgs/msg/Mystery")
            for k in range(7):
                records.append(
                    (
                        T0_NS + k,
                        mystery,
                        t["acme_msgs/msg/Mystery"](value=k * 1.0),
                        "acme_msgs/msg/Mystery",
                    )
                )
        records.sort(key=lambda r: r[0])
        for ns, conn, msg, msgtype in records:
            writer.write(conn, ns + LOG_LATENCY_NS, msg, msgtype)
    return path


class _Dealer:
    """Several connections of one topic: each write goes to the next one in turn."""

    def __init__(self, connections: list) -> None:
        self.connections, self.count = connections, 0

    def next(self):
        self.count += 1
        return self.connections[(self.count - 1) % len(self.connections)]


class _BagWriter:
    """One interface over rosbags' ROS 1 and ROS 2 bag writers and a plain-mcap ROS 1 MCAP."""

    def __init__(self, path: Path, kind: str, store, compression: str = "") -> None:
        self.path, self.kind, self.store = Path(path), kind, store
        self.compression = compression

    def __enter__(self) -> _BagWriter:
        if self.kind == "ros1-bag":
            from rosbags.rosbag1 import Writer

            self.writer = Writer(self.path)
            if self.compression:
                self.writer.set_compression(Writer.CompressionFormat[self.compression.upper()])
            self.writer.open()
        elif self.kind.startswith("ros2"):
            from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer

            plugin = StoragePlugin.MCAP if self.kind == "ros2-mcap" else StoragePlugin.SQLITE3
            self.writer = Writer(self.path, version=9, storage_plugin=plugin)
            if self.compression:
                self.writer.set_compression(
                    CompressionMode[self.compression.upper()], CompressionFormat.ZSTD
                )
            self.writer.open()
        else:
            from mcap.writer import Writer

            self.stream = self.path.open("wb")
            self.writer = Writer(self.stream)
            self.writer.start(profile="ros1", library="fgins tests")
        return self

    def add_connection(self, topic: str, msgtype: str, caller: str | None = None):
        if self.kind == "ros1-bag":
            return self.writer.add_connection(topic, msgtype, typestore=self.store,
                                              callerid=caller)  # fmt: skip
        if self.kind != "ros1-mcap":
            return self.writer.add_connection(topic, msgtype, typestore=self.store)
        text, _md5 = self.store.generate_msgdef(msgtype)
        ros1_name = msgtype.replace("/msg/", "/")
        schema = self.writer.register_schema(ros1_name, "ros1msg", text.encode())
        metadata = {"callerid": caller} if caller else {}
        return self.writer.register_channel(topic, "ros1", schema, metadata=metadata)

    def write(self, connection, ns: int, msg, msgtype: str) -> None:
        if isinstance(connection, _Dealer):
            connection = connection.next()
        if self.kind == "ros1-mcap":
            data = self.store.serialize_ros1(msg, msgtype)
            self.writer.add_message(connection, log_time=ns, data=data, publish_time=ns)
        elif self.kind == "ros1-bag":
            self.writer.write(connection, ns, self.store.serialize_ros1(msg, msgtype))
        else:
            self.writer.write(connection, ns, self.store.serialize_cdr(msg, msgtype))

    def __exit__(self, *exc) -> None:
        if self.kind == "ros1-mcap":
            self.writer.finish()
            self.stream.close()
        else:
            self.writer.close()


def imu_cdr_bytes(drive: Drive) -> list[tuple[int, bytes, str]]:
    """(stamp ns, CDR bytes, ros2msg schema text) of the drive's IMU samples, via rosbags."""
    store = _typestore()
    t = store.types
    vec3 = t["geometry_msgs/msg/Vector3"]
    out = []
    for i, ns in enumerate(map(int, drive.imu_ns)):
        msg = t["sensor_msgs/msg/Imu"](
            header=_header(store, ns, "imu"),
            orientation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=np.zeros(9),
            angular_velocity=vec3(*map(float, drive.gyro[i])),
            angular_velocity_covariance=np.zeros(9),
            linear_acceleration=vec3(*map(float, drive.accel[i])),
            linear_acceleration_covariance=np.zeros(9),
        )
        out.append((ns, bytes(store.serialize_cdr(msg, "sensor_msgs/msg/Imu")), ""))
    return out


def imu_ros2msg_schema() -> str:
    """The concatenated ros2msg definition of sensor_msgs/msg/Imu (what rosbag2 stores)."""
    text, _ = _typestore().generate_msgdef("sensor_msgs/msg/Imu", ros_version=2)
    return text


# ------------------------------------------------------------------------------------------
# Foxglove LocationFix recordings (+ a ROS 2 IMU channel so read_mcap has both roles)
# ------------------------------------------------------------------------------------------


def write_foxglove_protobuf(path: Path, drive: Drive, with_velocity: bool = True) -> Path:
    """LocationFix (protobuf, by foxglove-sdk) + raw CDR Imu logged through the same SDK;
    ``with_velocity=False`` leaves the optional velocity unset (older LocationFix)."""
    import foxglove
    from foxglove.channels import LocationFixChannel
    from foxglove.messages import (
        LocationFix,
        LocationFixPositionCovarianceType,
        Timestamp,
        Vector3,
    )

    context = foxglove.Context()
    with foxglove.open_mcap(str(path), allow_overwrite=True, context=context):
        imu_channel = foxglove.Channel(
            "/imu",
            schema=foxglove.Schema(
                name="sensor_msgs/msg/Imu", encoding="ros2msg", data=imu_ros2msg_schema().encode()
            ),
            message_encoding="cdr",
            context=context,
        )
        fix_channel = LocationFixChannel("/fix", context=context)
        events = [(int(ns), "imu", k) for k, (ns, _, _) in enumerate(imu_cdr_bytes(drive))]
        events += [(int(ns), "fix", k) for k, ns in enumerate(drive.gnss_ns) if drive.valid[k]]
        cdr = imu_cdr_bytes(drive)
        for ns, kind, k in sorted(events):
            if kind == "imu":
                imu_channel.log(cdr[k][1], log_time=ns + LOG_LATENCY_NS)
                continue
            cov = np.zeros(9)
            cov[[0, 4, 8]] = drive.std[k] ** 2
            fix_channel.log(
                LocationFix(
                    timestamp=Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000),
                    frame_id="antenna",
                    latitude=float(drive.lla[k, 0]),
                    longitude=float(drive.lla[k, 1]),
                    altitude=float(drive.lla[k, 2]),
                    position_covariance=[float(c) for c in cov],
                    position_covariance_type=LocationFixPositionCovarianceType.DiagonalKnown,
                    **({"velocity": Vector3(**dict(zip("xyz", map(float, drive.velocity[k]), strict=True)))}
                       if with_velocity else {}),
                ),
                log_time=ns + LOG_LATENCY_NS,
            )
    return path


LOCATION_FIX_JSON_SCHEMA = {
    "title": "foxglove.LocationFix",
    "type": "object",
    "properties": {
        "timestamp": {
            "type": "object",
            "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}},
        },
        "frame_id": {"type": "string"},
        "latitude": {"type": "number"},
        "longitude": {"type": "number"},
        "altitude": {"type": "number"},
        "position_covariance": {"type": "array", "items": {"type": "number"}},
        "position_covariance_type": {"type": "integer"},
    },
}


def write_foxglove_json(
    path: Path,
    drive: Drive,
    *,
    chunk_size: int = 1024 * 1024,
    imu_keep: np.ndarray | None = None,
    covariance_length: int = 9,
    rfc3339_stamps: bool = False,
) -> Path:
    """LocationFix in JSON + CDR Imu with the plain mcap writer.

    ``chunk_size`` small gives many chunks (a truncated copy keeps some); ``imu_keep`` is a
    mask of the IMU samples to write (to make gaps); ``covariance_length`` < 9 writes a
    malformed position covariance (its first values only); ``rfc3339_stamps`` writes the
    fixes' timestamps as protobuf's JSON mapping does ("2024-05-01T12:00:00.200000000Z").
    """
    from mcap.writer import Writer

    with open(path, "wb") as stream:
        writer = Writer(stream, chunk_size=chunk_size)
        writer.start(profile="", library="fgins-tests")
        imu_schema = writer.register_schema(
            "sensor_msgs/msg/Imu", "ros2msg", imu_ros2msg_schema().encode()
        )
        fix_schema = writer.register_schema(
            "foxglove.LocationFix", "jsonschema", json.dumps(LOCATION_FIX_JSON_SCHEMA).encode()
        )
        imu_channel = writer.register_channel("/imu", "cdr", imu_schema)
        fix_channel = writer.register_channel("/gps/location", "json", fix_schema)
        events = [
            (ns, "imu", payload)
            for k, (ns, payload, _) in enumerate(imu_cdr_bytes(drive))
            if imu_keep is None or imu_keep[k]
        ]
        for k, ns in enumerate(map(int, drive.gnss_ns)):
            if not drive.valid[k]:
                continue
            cov = np.zeros(9)
            cov[[0, 4, 8]] = drive.std[k] ** 2
            stamp: object = {"sec": ns // 1_000_000_000, "nsec": ns % 1_000_000_000}
            if rfc3339_stamps:
                import datetime

                whole = datetime.datetime.fromtimestamp(ns // 1_000_000_000, datetime.UTC)
                stamp = whole.strftime("%Y-%m-%dT%H:%M:%S") + f".{ns % 1_000_000_000:09d}Z"
            fix = {
                "timestamp": stamp,
                "frame_id": "antenna",
                "latitude": float(drive.lla[k, 0]),
                "longitude": float(drive.lla[k, 1]),
                "altitude": float(drive.lla[k, 2]),
                "position_covariance": cov[:covariance_length].tolist(),
                "position_covariance_type": 2,
            }
            events.append((ns, "fix", json.dumps(fix).encode()))
        for ns, kind, payload in sorted(events, key=lambda e: (e[0], e[1])):
            channel = imu_channel if kind == "imu" else fix_channel
            writer.add_message(channel, log_time=ns + LOG_LATENCY_NS, data=payload, publish_time=ns)
        writer.finish()
    return path


def _nmea_checksum(body: str) -> str:
    value = 0
    for char in body:
        value ^= ord(char)
    return f"{value:02X}"


def gga_sentences(drive: Drive, geoid_separation_m: float = 47.5) -> list[tuple[int, str]]:
    """One $GPGGA per valid epoch (UTC of day from the stamp), with the bag stamp it came at."""
    out = []
    for k, ns in enumerate(map(int, drive.gnss_ns)):
        if not drive.valid[k]:
            continue
        seconds_of_day = (ns // 10_000_000) % 8_640_000 / 100.0
        hh, rest = divmod(seconds_of_day, 3600)
        mm, ss = divmod(rest, 60)
        lat, lon, alt = drive.lla[k]
        lat_min = (lat - int(lat)) * 60
        lon_min = (lon - int(lon)) * 60
        body = (
            f"GPGGA,{int(hh):02d}{int(mm):02d}{ss:05.2f},{int(lat):02d}{lat_min:010.7f},N,"
            f"{int(lon):03d}{lon_min:010.7f},E,1,09,0.9,{alt - geoid_separation_m:.3f},M,"
            f"{geoid_separation_m:.1f},M,,"
        )
        out.append((ns, f"${body}*{_nmea_checksum(body)}"))
    return out


def drive_from_dataset(dataset, start_time_s: float) -> Drive:
    """A :class:`Drive` carrying a simulator's dataset (stamps: T0_NS + integer ns offsets)."""

    def to_ns(t: np.ndarray) -> np.ndarray:
        return T0_NS + np.round((np.asarray(t) - start_time_s) * 1e9).astype(np.int64)

    gnss = dataset.gnss
    baro = dataset.baro
    return Drive(
        imu_ns=to_ns(dataset.imu.t),
        gyro=dataset.imu.gyro,
        accel=dataset.imu.accel,
        gnss_ns=to_ns(gnss.t),
        lla=gnss.lla,
        std=gnss.std,
        velocity=gnss.velocity,
        velocity_std=gnss.velocity_std,
        status=np.where(gnss.fix_quality == 0, -1, 0),
        baro_ns=to_ns(baro.t) if baro is not None else np.zeros(0, np.int64),
        pressure=baro.pressure if baro is not None else np.zeros(0),
    )
