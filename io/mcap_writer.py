"""Write a smoothed trajectory as an MCAP file that Foxglove opens as is.

Encoding: protobuf with the official Foxglove schemas (``foxglove-schemas-protobuf``; the
schema is stored in the file as a FileDescriptorSet, so no network is needed to read it).

Topics written (log time = the epoch's time in ns, monotonic over the whole file):

* ``/fgins/fix``   ``foxglove.LocationFix``    smoothed lat/lon/alt, ENU position covariance
* ``/fgins/pose``  ``foxglove.PoseInFrame``    pose in the local ENU frame ``map``
* ``/tf``          ``foxglove.FrameTransform`` ``map`` -> ``base_link``
* ``/fgins/gnss``  ``foxglove.LocationFix``    the raw GNSS fixes (when given)

With ``input_path`` every channel and message of the input recording is copied in too,
interleaved by log time.
"""

from __future__ import annotations

import heapq
import json
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.LocationFix_pb2 import LocationFix
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import build_file_descriptor_set

from fgins.datatypes import GnssData, InputError, Trajectory
from fgins.geodesy import enu_to_lla, rotation_to_quaternion
from fgins.io.atomic import atomic_path
from fgins.io.mcap import PRODUCER_FGINS, PRODUCER_KEY

FIX_TOPIC = "/fgins/fix"
POSE_TOPIC = "/fgins/pose"
TF_TOPIC = "/tf"
GNSS_TOPIC = "/fgins/gnss"
MAP_FRAME = "map"
BODY_FRAME = "base_link"

# An item of the merged output stream: (log time ns, order within the same time, channel, data)
_Item = tuple[int, int, int, bytes]
_OWN_CHANNEL = {PRODUCER_KEY: PRODUCER_FGINS}  # read_mcap never takes these as sensors


def _seconds_to_ns(t: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(t, dtype=float) * 1e9).astype(np.int64)


def _location_fixes(
    log_ns: np.ndarray,
    frame: str,
    lla: np.ndarray,
    covariance: np.ndarray,
    velocity: np.ndarray,
    heading_rad: np.ndarray | None = None,
) -> Iterator[bytes]:
    """Serialised LocationFix messages; the per-epoch checks are done once, vectorised."""
    n = log_ns.shape[0]
    covariance = covariance.reshape(n, 3, 3)
    cov_known = np.all(np.isfinite(covariance), axis=(1, 2))
    off_diagonal = covariance * (1.0 - np.eye(3))
    cov_type = np.where(
        np.any(off_diagonal != 0, axis=(1, 2)), LocationFix.KNOWN, LocationFix.DIAGONAL_KNOWN
    )
    vel_known = np.all(np.isfinite(velocity), axis=1)
    if heading_rad is None:
        heading_rad = np.full(n, np.nan)
    heading_known = np.isfinite(heading_rad)
    rows = zip(
        log_ns.tolist(),
        lla.tolist(),
        covariance.reshape(n, 9).tolist(),
        cov_known.tolist(),
        cov_type.tolist(),
        velocity.tolist(),
        vel_known.tolist(),
        heading_rad.tolist(),
        heading_known.tolist(),
        strict=True,
    )
    for ns, (lat, lon, alt), cov, has_cov, kind, vel, has_vel, heading, has_heading in rows:
        msg = LocationFix(frame_id=frame, latitude=lat, longitude=lon, altitude=alt)
        msg.timestamp.FromNanoseconds(ns)
        if has_cov:
            msg.position_covariance.extend(cov)
            msg.position_covariance_type = kind
        if has_vel:
            msg.velocity.x, msg.velocity.y, msg.velocity.z = vel
        if has_heading:
            msg.heading = heading
        yield msg.SerializeToString()


def _trajectory_items(
    trajectory: Trajectory, fix_id: int, pose_id: int, tf_id: int
) -> Iterator[_Item]:
    log_ns = _seconds_to_ns(trajectory.t)
    lla = enu_to_lla(trajectory.position, trajectory.origin)
    quat = rotation_to_quaternion(trajectory.rotation).tolist()
    heading = np.radians(trajectory.roll_pitch_heading_deg()[:, 2])
    fixes = _location_fixes(
        log_ns, BODY_FRAME, lla, trajectory.position_cov, trajectory.velocity, heading
    )
    pose = PoseInFrame(frame_id=MAP_FRAME)
    transform = FrameTransform(parent_frame_id=MAP_FRAME, child_frame_id=BODY_FRAME)
    p, o = pose.pose.position, pose.pose.orientation
    tr, ro = transform.translation, transform.rotation
    rows = zip(log_ns.tolist(), trajectory.position.tolist(), quat, fixes, strict=True)
    for ns, (x, y, z), (qx, qy, qz, qw), fix in rows:
        yield ns, 0, fix_id, fix
        pose.timestamp.FromNanoseconds(ns)
        p.x, p.y, p.z, o.x, o.y, o.z, o.w = x, y, z, qx, qy, qz, qw
        yield ns, 1, pose_id, pose.SerializeToString()
        transform.timestamp.FromNanoseconds(ns)
        tr.x, tr.y, tr.z, ro.x, ro.y, ro.z, ro.w = x, y, z, qx, qy, qz, qw
        yield ns, 2, tf_id, transform.SerializeToString()


def _gnss_items(gnss: GnssData, channel_id: int) -> Iterator[_Item]:
    log_ns = _seconds_to_ns(gnss.t)
    covariance = np.zeros((len(gnss), 3, 3))
    covariance[:, [0, 1, 2], [0, 1, 2]] = gnss.std**2  # NaN std -> no covariance
    fixes = _location_fixes(log_ns, "gnss", gnss.lla, covariance, gnss.velocity)
    for ns, fix in zip(log_ns.tolist(), fixes, strict=True):
        yield ns, 3, channel_id, fix


class _InputCopy:
    """Streams an input recording's messages into the writer's channels, by log time."""

    def __init__(self, path: Path, writer: Writer) -> None:
        self.path = path
        self.writer = writer
        self.notes: list[str] = []
        self._file = open(path, "rb")  # closed in close(): the copy streams lazily
        try:
            self._reader = make_reader(self._file)
            self._summary = self._reader.get_summary()
        except McapError as exc:
            self._file.close()
            raise InputError(f"{path}: cannot copy this input into the MCAP output: {exc}") from exc
        except Exception:
            self._summary = None  # torn input: streamed in file order instead
        self._schema_ids: dict[int, int] = {}
        self._channel_ids: dict[int, int] = {}

    def _channel_id(self, schema: Any, channel: Any) -> int:
        new_id = self._channel_ids.get(channel.id)
        if new_id is None:
            schema_id = 0
            if schema is not None:
                schema_id = self._schema_ids.get(schema.id, 0)
                if not schema_id:
                    schema_id = self.writer.register_schema(
                        schema.name, schema.encoding, schema.data
                    )
                    self._schema_ids[schema.id] = schema_id
            new_id = self.writer.register_channel(
                channel.topic, channel.message_encoding, schema_id, dict(channel.metadata)
            )
            self._channel_ids[channel.id] = new_id
        return new_id

    def items(self) -> Iterator[_Item]:
        copied = 0
        try:
            ordered = self._summary is not None
            messages = self._reader.iter_messages(log_time_order=ordered)
            for schema, channel, message in messages:
                yield message.log_time, 4, self._channel_id(schema, channel), message.data
                copied += 1
        except Exception as exc:  # torn input: keep what was copied
            self.notes.append(f"input {self.path}: copy stopped at a torn record ({exc})")
        self.notes.append(f"copied {copied} messages from {self.path}")

    def close(self) -> None:
        self._file.close()


def write_mcap(
    trajectory: Trajectory,
    path: str | Path,
    *,
    gnss: GnssData | None,
    input_path: str | Path | None = None,
) -> list[str]:
    """Write ``trajectory`` (and the raw ``gnss`` fixes) to ``path`` as a Foxglove MCAP.

    ``input_path`` copies every channel and message of that MCAP recording into the output.
    Written atomically. Returns human-readable notes (counts, clamped log times).
    """
    if len(trajectory) == 0:
        raise InputError(f"{path}: empty trajectory, nothing to write")
    if np.any(np.diff(trajectory.t) < 0):
        raise InputError(f"{path}: trajectory times go backwards; sort the trajectory first")
    notes: list[str] = []
    with atomic_path(path) as tmp, open(tmp, "wb") as stream:
        writer = Writer(stream, compression=CompressionType.ZSTD)
        writer.start(profile="", library="fgins")
        schema_ids = {
            cls.DESCRIPTOR.full_name: writer.register_schema(
                cls.DESCRIPTOR.full_name,
                "protobuf",
                build_file_descriptor_set(cls).SerializeToString(),
            )
            for cls in (LocationFix, PoseInFrame, FrameTransform)
        }

        def own_channel(topic: str, schema_name: str) -> int:
            return writer.register_channel(topic, "protobuf", schema_ids[schema_name], _OWN_CHANNEL)

        fix_id = own_channel(FIX_TOPIC, "foxglove.LocationFix")
        pose_id = own_channel(POSE_TOPIC, "foxglove.PoseInFrame")
        tf_id = own_channel(TF_TOPIC, "foxglove.FrameTransform")
        origin = trajectory.origin
        writer.add_metadata(
            "fgins",
            {
                "method": trajectory.method,
                "origin_lla": json.dumps([origin.lat, origin.lon, origin.alt]),
                "frame": f"{MAP_FRAME} = local ENU at origin_lla",
            },
        )
        streams: list[Iterator[_Item]] = [_trajectory_items(trajectory, fix_id, pose_id, tf_id)]
        if gnss is not None and len(gnss):
            gnss_id = own_channel(GNSS_TOPIC, "foxglove.LocationFix")
            streams.append(_gnss_items(gnss, gnss_id))
        copy = _InputCopy(Path(input_path), writer) if input_path is not None else None
        if copy is not None:
            streams.append(copy.items())
        last = -1
        clamped = 0
        written = 0
        try:
            for log_ns, _, channel_id, data in heapq.merge(*streams):
                if log_ns < last:  # an unordered input: keep the file's log times monotonic
                    clamped += 1
                    log_ns = last
                writer.add_message(channel_id, log_time=log_ns, data=data, publish_time=log_ns)
                last = log_ns
                written += 1
        finally:
            if copy is not None:
                copy.close()
                notes.extend(copy.notes)
        writer.finish()
    notes.append(f"wrote {written} messages to {path}")
    if clamped:
        notes.append(
            f"{clamped} input messages out of log-time order were given the previous log time"
        )
    return notes
