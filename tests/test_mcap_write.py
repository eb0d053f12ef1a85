"""write_mcap read back with the mcap reader and the protobuf decoder of mcap-protobuf-support
(independent of fgins's writer), and with fgins's own reader for the --with-input copy."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags", reason="test extra: pip install rosbags")
pytest.importorskip("mcap_protobuf", reason="test extra: pip install mcap-protobuf-support")
pytest.importorskip(
    "foxglove_schemas_protobuf", reason="test extra: pip install foxglove-schemas-protobuf"
)
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from fgins.datatypes import GnssData, InputError, Origin, Trajectory
from fgins.geodesy import enu_to_lla, so3_exp
from fgins.io.mcap import read_mcap
from fgins.io.mcap_writer import (
    FIX_TOPIC,
    GNSS_TOPIC,
    POSE_TOPIC,
    TF_TOPIC,
    rotation_to_quaternion,
    write_mcap,
)
from fgins.tests.mcap_fixtures import make_drive, write_ros2_bag

T_START = 1_700_000_000.0


def make_trajectory(n: int = 500) -> Trajectory:
    """A circle of 200 m radius with the body x axis along the velocity, at 50 Hz."""
    t = T_START + np.arange(n) * 0.02
    angle = 0.05 * (t - T_START)
    position = np.column_stack([200 * np.cos(angle), 200 * np.sin(angle), 0.5 * (t - T_START)])
    velocity = np.column_stack([-10 * np.sin(angle), 10 * np.cos(angle), 0.5 + 0 * angle])
    yaw = angle + np.pi / 2
    rotation = np.stack([so3_exp(np.array([0.02, -0.01, y])) for y in yaw])
    cov = np.zeros((n, 3, 3))
    cov[:, 0, 0], cov[:, 1, 1], cov[:, 2, 2] = 0.04, 0.09, 0.25 + 0.001 * np.arange(n)
    cov[:, 0, 1] = cov[:, 1, 0] = 0.01
    return Trajectory(
        t=t,
        position=position,
        velocity=velocity,
        rotation=rotation,
        origin=Origin(48.137, 11.575, 520.0),
        method="batch",
        position_cov=cov,
    )


def make_gnss(trajectory: Trajectory) -> GnssData:
    every = slice(0, None, 10)
    lla = enu_to_lla(trajectory.position[every], trajectory.origin)
    n = lla.shape[0]
    return GnssData(t=trajectory.t[every], lla=lla, std=np.tile([1.0, 1.5, 3.0], (n, 1)))


def decode_all(path: Path) -> dict[str, list[tuple[int, object]]]:
    """Every message of the file, decoded with mcap-protobuf-support, by topic."""
    by_topic: dict[str, list[tuple[int, object]]] = {}
    with open(path, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, message, decoded in reader.iter_decoded_messages(log_time_order=False):
            by_topic.setdefault(channel.topic, []).append((message.log_time, decoded))
    return by_topic


def quaternion_to_rotation(q: np.ndarray) -> np.ndarray:
    """Closed-form rotation matrix of a unit quaternion x, y, z, w."""
    x, y, z, w = q
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def test_quaternion_closed_forms() -> None:
    half = 0.3
    q = rotation_to_quaternion(so3_exp(np.array([0.0, 0.0, 2 * half]))[None])[0]
    np.testing.assert_allclose(q, [0, 0, np.sin(half), np.cos(half)], atol=1e-15)
    # a rotation by pi about x: w = 0, the branch Shepperd's method exists for
    q = rotation_to_quaternion(np.diag([1.0, -1.0, -1.0])[None])[0]
    np.testing.assert_allclose(np.abs(q), [1, 0, 0, 0], atol=1e-15)
    rng = np.random.default_rng(3)
    rotations = np.stack([so3_exp(v) for v in rng.normal(0, 2.0, (200, 3))])
    for r, q in zip(rotations, rotation_to_quaternion(rotations), strict=True):
        np.testing.assert_allclose(quaternion_to_rotation(q), r, atol=1e-12)


def test_written_file_decodes_and_matches_the_trajectory(tmp_path: Path) -> None:
    trajectory = make_trajectory()
    gnss = make_gnss(trajectory)
    path = tmp_path / "out.mcap"
    write_mcap(trajectory, path, gnss=gnss)
    assert [p.name for p in tmp_path.iterdir()] == ["out.mcap"]  # no temp file left behind

    with open(path, "rb") as stream:
        log_times = [m.log_time for _, _, m in make_reader(stream).iter_messages()]
    assert np.all(np.diff(log_times) >= 0)

    topics = decode_all(path)
    assert set(topics) == {FIX_TOPIC, POSE_TOPIC, TF_TOPIC, GNSS_TOPIC}
    n = len(trajectory)
    assert [len(topics[t]) for t in (FIX_TOPIC, POSE_TOPIC, TF_TOPIC)] == [n, n, n]

    expected_lla = enu_to_lla(trajectory.position, trajectory.origin)
    fixes = topics[FIX_TOPIC]
    lat = np.array([m.latitude for _, m in fixes])
    lon = np.array([m.longitude for _, m in fixes])
    alt = np.array([m.altitude for _, m in fixes])
    np.testing.assert_allclose(lat, expected_lla[:, 0], atol=1e-9, rtol=0)
    np.testing.assert_allclose(lon, expected_lla[:, 1], atol=1e-9, rtol=0)
    np.testing.assert_allclose(alt, expected_lla[:, 2], atol=1e-6)
    covariance = np.array([list(m.position_covariance) for _, m in fixes]).reshape(-1, 3, 3)
    np.testing.assert_array_equal(covariance, trajectory.position_cov)
    assert all(m.position_covariance_type == 3 for _, m in fixes)  # KNOWN: off-diagonals
    stamps = np.array([m.timestamp.ToNanoseconds() for _, m in fixes])
    np.testing.assert_array_equal(stamps, np.round(trajectory.t * 1e9).astype(np.int64))
    np.testing.assert_array_equal(stamps, [log for log, _ in fixes])
    heading = np.array([m.heading for _, m in fixes])
    np.testing.assert_allclose(
        np.degrees(heading), trajectory.roll_pitch_heading_deg()[:, 2], atol=1e-9
    )

    for (_, pose), (_, tf), k in zip(topics[POSE_TOPIC], topics[TF_TOPIC], range(n), strict=True):
        assert pose.frame_id == "map" and (tf.parent_frame_id, tf.child_frame_id) == (
            "map",
            "base_link",
        )
        p = pose.pose.position
        np.testing.assert_array_equal([p.x, p.y, p.z], trajectory.position[k])
        o = pose.pose.orientation
        np.testing.assert_allclose(
            quaternion_to_rotation(np.array([o.x, o.y, o.z, o.w])),
            trajectory.rotation[k],
            atol=1e-12,
        )
        tr = tf.translation
        np.testing.assert_array_equal([tr.x, tr.y, tr.z], trajectory.position[k])

    raw = topics[GNSS_TOPIC]
    np.testing.assert_array_equal([m.latitude for _, m in raw], gnss.lla[:, 0])
    np.testing.assert_array_equal([list(m.position_covariance)[::4] for _, m in raw], gnss.std**2)


def test_with_input_copies_the_recording(tmp_path: Path) -> None:
    drive = make_drive(duration_s=10.0)
    bag = write_ros2_bag(tmp_path / "bag", drive)
    source = read_mcap(bag, progress=False).dataset
    trajectory = make_trajectory(200)
    trajectory.t = source.imu.t[: len(trajectory)]  # interleave with the input's times
    out = tmp_path / "smoothed.mcap"
    notes = write_mcap(trajectory, out, gnss=source.gnss, input_path=bag)
    assert any("copied" in line for line in notes)

    with open(bag, "rb") as stream:
        original = [
            (c.topic, m.log_time, m.data) for _, c, m in make_reader(stream).iter_messages()
        ]
    with open(out, "rb") as stream:
        copied = [
            (c.topic, m.log_time, m.data)
            for _, c, m in make_reader(stream).iter_messages(log_time_order=False)
        ]
    own = {FIX_TOPIC, POSE_TOPIC, TF_TOPIC, GNSS_TOPIC}
    assert sorted(x for x in copied if x[0] not in own) == sorted(original)
    assert np.all(np.diff([log for _, log, _ in copied]) >= 0)

    # Reading the output again finds the copied sensors, never fgins's own LocationFix topics.
    again = read_mcap(out, progress=False)
    np.testing.assert_array_equal(again.dataset.imu.t, source.imu.t)
    np.testing.assert_array_equal(again.dataset.gnss.lla, source.gnss.lla)
    assert any(FIX_TOPIC in line and "written by fgins" in line for line in again.report)


def test_failed_write_leaves_no_file(tmp_path: Path) -> None:
    not_mcap = tmp_path / "input.mcap"
    not_mcap.write_bytes(b"definitely not an mcap file")
    out = tmp_path / "out.mcap"
    with pytest.raises(InputError):
        write_mcap(make_trajectory(10), out, gnss=None, input_path=not_mcap)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["input.mcap"]
