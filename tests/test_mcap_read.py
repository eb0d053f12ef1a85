"""read_mcap / summarize_mcap against files written by independent libraries (rosbags,
foxglove-sdk, the plain mcap writer) from a synthetic drive with known values."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("rosbags", reason="test extra: pip install rosbags")
pytest.importorskip("foxglove", reason="test extra: pip install foxglove-sdk")
pytest.importorskip("mcap_protobuf", reason="test extra: pip install mcap-protobuf-support")

from fgins.datatypes import InputError
from fgins.io.mcap import read_mcap, summarize_mcap
from fgins.tests.mcap_fixtures import (
    LOG_LATENCY_NS,
    Drive,
    drive_from_dataset,
    gga_sentences,
    make_drive,
    write_foxglove_json,
    write_foxglove_protobuf,
    write_ros2_bag,
)


@pytest.fixture(scope="module")
def drive() -> Drive:
    return make_drive(duration_s=20.0)


@pytest.fixture(scope="module")
def ros2_bag(drive: Drive, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_ros2_bag(tmp_path_factory.mktemp("ros2") / "bag", drive, second_imu_every=3)


def test_ros2_bag_values_are_read_exactly(ros2_bag: Path, drive: Drive) -> None:
    result = read_mcap(ros2_bag, progress=False)
    data = result.dataset
    valid = drive.valid
    # Header stamps are the time base: ns / 1e9 exactly.
    np.testing.assert_array_equal(data.imu.t, drive.imu_ns / 1e9)
    np.testing.assert_array_equal(data.imu.gyro, drive.gyro)
    np.testing.assert_array_equal(data.imu.accel, drive.accel)
    np.testing.assert_array_equal(data.gnss.t, drive.gnss_ns[valid] / 1e9)
    np.testing.assert_array_equal(data.gnss.lla, drive.lla[valid])
    # std from the covariance diagonal (the off-diagonal 0.3 must not leak in)
    np.testing.assert_allclose(data.gnss.std, drive.std[valid], rtol=1e-14)
    np.testing.assert_array_equal(data.gnss.velocity, drive.velocity[valid])
    np.testing.assert_allclose(data.gnss.velocity_std, drive.velocity_std[valid], rtol=1e-14)
    assert np.all(data.gnss.fix_quality == 1)
    assert data.baro is not None
    np.testing.assert_array_equal(data.baro.t, drive.baro_ns / 1e9)
    np.testing.assert_array_equal(data.baro.pressure, drive.pressure)
    first = drive.lla[valid][0]
    assert (data.origin.lat, data.origin.lon, data.origin.alt) == tuple(first)
    no_fix = int(np.sum(~valid))
    assert no_fix > 0
    assert any(f"{no_fix} no-fix messages dropped" in w for w in result.warnings)
    assert data.metadata["gnss_epochs_without_fix"] == no_fix  # for the GNSS count line
    # Outage windows count from the first GNSS message, with a fix or not (DESIGN.md).
    assert data.t0 == drive.gnss_ns.min() / 1e9


def test_navsatfix_without_altitude_or_with_zero_variances_is_read_as_a_csv_would_be(
    drive: Drive, tmp_path: Path
) -> None:
    """NavSatFix says "altitude NaN if no altitude": such a 2-D fix was dropped as "no fix"
    (every third fix; all of them: "no valid fix", an error), while the same fixes as a CSV
    with an empty alt are kept and given the height of the 3-D fixes around them. A
    covariance said to be known (DIAGONAL_KNOWN) of zeros was ignored without a word; the
    validation layer now counts it, as a CSV's zero std column."""
    from dataclasses import replace as dc_replace

    from fgins.io.validate import validate_dataset

    lla, std = drive.lla.copy(), drive.std.copy()
    lla[::3, 2] = np.nan
    std[1::4] = 0.0
    path = write_ros2_bag(tmp_path / "bag", dc_replace(drive, lla=lla, std=std), with_unknown=False)
    result = read_mcap(path, progress=False)
    valid = drive.valid
    np.testing.assert_array_equal(result.dataset.gnss.t, drive.gnss_ns[valid] / 1e9)
    checked = validate_dataset(result.dataset)
    heightless = int(np.sum(np.isnan(lla[valid, 2])))
    assert any(f"{heightless} of {int(valid.sum())} fix(es) without a height" in w for w in checked.warnings)
    assert np.all(np.isfinite(checked.gnss.lla[:, 2]))
    zero = int(np.sum(np.all(std[valid] == 0.0, axis=1)))
    assert any(f"{zero} fix(es) with a zero, negative or infinite sigma" in w for w in checked.warnings)


def test_a_malformed_location_fix_covariance_is_counted_not_silently_ignored(drive: Drive, tmp_path: Path) -> None:
    path = write_foxglove_json(tmp_path / "fix.mcap", drive, covariance_length=3)
    result = read_mcap(path, progress=False)
    assert np.all(np.isnan(result.dataset.gnss.std))
    fixes = int(drive.valid.sum())
    assert any(f"{fixes} fix message(s) with a position covariance said to be known that is not 9 values" in w
               for w in result.warnings), result.warnings  # fmt: skip


@pytest.mark.parametrize("correlation", [0.0, 0.6])
def test_a_correlated_position_covariance_is_said_to_be_used_as_diagonal(drive: Drive, tmp_path: Path,
                                                                       correlation: float) -> None:
    """A NavSatFix covariance of type 3 (fully known) whose east and north correlate gave a
    result identical to the diagonal one without a word (an outside tester): fgins weights
    each axis by its own variance, now said. A diagonal-known one (type 2) says nothing,
    whatever its off-diagonal numbers hold."""
    path = write_ros2_bag(tmp_path / "bag", drive, with_unknown=False, position_correlation=correlation)
    result = read_mcap(path, progress=False)
    said = [w for w in result.warnings if "axes correlate" in w]
    np.testing.assert_allclose(result.dataset.gnss.std, drive.std[drive.valid], rtol=1e-9)
    if correlation:
        assert len(said) == 1 and "|r| up to 0.60" in said[0], result.warnings
    else:
        assert not said, said


def test_location_fix_stamps_in_protobufs_json_mapping_are_read(drive: Drive, tmp_path: Path) -> None:
    """protobuf's JSON mapping writes a Timestamp as an RFC 3339 string: every fix was an
    "undecodable message" while ``inspect`` listed the channel as fine."""
    path = write_foxglove_json(tmp_path / "fix.mcap", drive, rfc3339_stamps=True)
    data = read_mcap(path, progress=False).dataset
    np.testing.assert_array_equal(data.gnss.t, drive.gnss_ns[drive.valid] / 1e9)


def test_log_time_is_used_when_asked(ros2_bag: Path, drive: Drive) -> None:
    data = read_mcap(ros2_bag, use_header_stamp=False, progress=False).dataset
    np.testing.assert_array_equal(data.imu.t, (drive.imu_ns + LOG_LATENCY_NS) / 1e9)
    assert data.metadata["time_base"] == "log time"


def test_candidate_with_most_messages_is_chosen_and_reported(ros2_bag: Path) -> None:
    result = read_mcap(ros2_bag, progress=False)
    imu_line = next(line for line in result.report if line.startswith("imu:"))
    assert "/imu/data" in imu_line and "most messages" in imu_line and "/imu/raw" in imu_line
    assert result.dataset.metadata["topics"]["imu"] == "/imu/data"


def test_override_picks_the_sparser_imu(ros2_bag: Path, drive: Drive) -> None:
    result = read_mcap(ros2_bag, imu_topic="/imu/raw", progress=False)
    np.testing.assert_array_equal(result.dataset.imu.t, drive.imu_ns[::3] / 1e9)
    np.testing.assert_array_equal(result.dataset.imu.gyro, drive.gyro[::3])
    assert any("chosen by the user" in line for line in result.report)


def test_override_of_a_missing_topic_is_an_input_error(ros2_bag: Path) -> None:
    with pytest.raises(InputError, match="/imu/nope"):
        read_mcap(ros2_bag, imu_topic="/imu/nope", progress=False)
    with pytest.raises(InputError, match="/gps/vel"):
        # a velocity topic is not a GNSS position topic
        read_mcap(ros2_bag, gnss_topic="/gps/vel", progress=False)


def test_unknown_schema_is_skipped_and_listed(ros2_bag: Path) -> None:
    result = read_mcap(ros2_bag, progress=False)
    assert any(
        "/mystery" in line and "acme_msgs/msg/Mystery" in line and "7 messages" in line
        for line in result.report
    )


def test_missing_imu_is_an_input_error(drive: Drive, tmp_path: Path) -> None:
    path = write_ros2_bag(tmp_path / "bag", drive, with_imu=False)
    with pytest.raises(InputError, match="no IMU channel"):
        read_mcap(path, progress=False)


def test_a_receiver_log_without_imu_converts(drive: Drive, tmp_path: Path, capsys) -> None:
    """``fgins convert`` needs only the fixes: a ROS 2 bag (rosbags writer) with a
    NavSatFix topic and no IMU was refused with "no IMU channel"."""
    from fgins.cli import main
    from fgins.io.mcap import read_mcap_gnss

    path = write_ros2_bag(tmp_path / "bag", drive, with_imu=False)
    gnss, _ = read_mcap_gnss(path)
    np.testing.assert_array_equal(gnss.lla, drive.lla[drive.valid])
    out = tmp_path / "fixes.csv"
    assert main(["convert", str(path), "-o", str(out)]) == 0, capsys.readouterr().err
    assert len(out.read_text().splitlines()) == 1 + int(drive.valid.sum())


def test_an_mcap_fgins_wrote_is_called_fgins_output(tmp_path: Path, capsys) -> None:
    """fgins's own trajectory MCAP given back as an input: "no IMU channel" (smooth) and "no
    GNSS channel" (convert) now say it holds only fgins output, not sensor data."""
    import fgins
    from fgins.cli import main

    folder = fgins.simulate("car-urban", tmp_path / "drive", duration=20, seed=1)
    out = tmp_path / "track.mcap"
    assert main(["smooth", str(folder), "--method", "ekf", "-o", str(out)]) == 0
    capsys.readouterr()
    for args in (["smooth", str(out), "-o", str(tmp_path / "x.csv")],
                 ["convert", str(out), "-o", str(tmp_path / "y.csv")]):  # fmt: skip
        assert main(args) == 2
        assert "holds only fgins output channels" in capsys.readouterr().err


def test_not_an_mcap_is_an_input_error(tmp_path: Path) -> None:
    path = tmp_path / "drive.mcap"
    path.write_text("time,lat,lon\n1,2,3\n")
    with pytest.raises(InputError, match="not an MCAP"):
        read_mcap(path, progress=False)
    with pytest.raises(InputError, match="no such file"):
        read_mcap(tmp_path / "missing.mcap", progress=False)
    with pytest.raises(InputError, match="not an MCAP"):
        summarize_mcap(path)


def _assert_location_fixes(data, drive: Drive) -> None:
    valid = drive.valid
    np.testing.assert_array_equal(data.gnss.t, drive.gnss_ns[valid] / 1e9)
    np.testing.assert_array_equal(data.gnss.lla, drive.lla[valid])
    np.testing.assert_allclose(data.gnss.std, drive.std[valid], rtol=1e-14)
    np.testing.assert_array_equal(data.imu.t, drive.imu_ns / 1e9)
    np.testing.assert_array_equal(data.imu.accel, drive.accel)


def test_foxglove_protobuf_location_fix(drive: Drive, tmp_path: Path) -> None:
    path = write_foxglove_protobuf(tmp_path / "foxglove.mcap", drive)
    result = read_mcap(path, progress=False)
    _assert_location_fixes(result.dataset, drive)
    # the LocationFix velocity field (ENU) is carried through
    np.testing.assert_array_equal(result.dataset.gnss.velocity, drive.velocity[drive.valid])
    assert result.warnings == []


def test_foxglove_protobuf_location_fix_without_velocity_has_none(drive: Drive, tmp_path: Path) -> None:
    """The optional velocity left unset is no velocity, not (0, 0, 0) (outside tester: a
    moving drive refused for 'km/h', and convert wrote zero velocities), in smooth's reader
    and in convert's alike."""
    from fgins.cli import main

    path = write_foxglove_protobuf(tmp_path / "foxglove.mcap", drive, with_velocity=False)
    result = read_mcap(path, progress=False)
    _assert_location_fixes(result.dataset, drive)
    assert np.all(np.isnan(result.dataset.gnss.velocity))
    out = tmp_path / "fixes.csv"
    assert main(["convert", str(path), "-o", str(out)]) == 0
    header, first = out.read_text().splitlines()[:2]
    columns = dict(zip(header.split(","), first.split(","), strict=True))
    assert all(columns.get(name, "") == "" for name in ("vel_east", "vel_north", "vel_up")), columns


def test_foxglove_json_location_fix(drive: Drive, tmp_path: Path) -> None:
    path = write_foxglove_json(tmp_path / "json.mcap", drive)
    result = read_mcap(path, progress=False)
    _assert_location_fixes(result.dataset, drive)
    assert np.all(np.isnan(result.dataset.gnss.velocity))


def test_gpsfix_dops_and_velocity(drive: Drive, tmp_path: Path) -> None:
    path = write_ros2_bag(tmp_path / "bag", drive, gpsfix=True, with_velocity=False)
    gnss = read_mcap(path, progress=False).dataset.gnss
    valid = drive.valid
    np.testing.assert_array_equal(gnss.lla, drive.lla[valid])
    np.testing.assert_allclose(gnss.hdop, (0.9 + 0.01 * np.arange(valid.size))[valid])
    np.testing.assert_allclose(gnss.vdop, 1.4)
    assert np.all(gnss.num_sats == 9)
    # velocity rebuilt from track/speed/climb
    np.testing.assert_allclose(gnss.velocity, drive.velocity[valid], atol=1e-12)
    assert np.all(np.isnan(gnss.std))  # covariance type UNKNOWN: not used


def test_nmea_sentences_are_parsed(drive: Drive, tmp_path: Path) -> None:
    pytest.importorskip("fgins.io.nmea", reason="fgins.io.nmea (read_nmea) not available yet")
    sentences = gga_sentences(drive)
    path = write_ros2_bag(tmp_path / "bag", drive, nmea_sentences=sentences, with_velocity=False)
    result = read_mcap(path, progress=False)
    gnss = result.dataset.gnss
    valid = drive.valid
    assert len(gnss) == len(sentences)
    # GGA carries 1e-7 arc-minutes: < 2e-9 deg; ellipsoidal height = MSL + separation
    np.testing.assert_allclose(gnss.lla[:, :2], drive.lla[valid, :2], atol=3e-9)
    np.testing.assert_allclose(gnss.lla[:, 2], drive.lla[valid, 2], atol=1e-3)
    # times on the bag's stamps (the IMU's time base), not UTC of day
    np.testing.assert_allclose(gnss.t, drive.gnss_ns[valid] / 1e9, atol=1e-3)


def test_truncated_recording_reads_a_prefix(drive: Drive, tmp_path: Path) -> None:
    full_path = write_foxglove_json(tmp_path / "full.mcap", drive, chunk_size=8192)
    full = read_mcap(full_path, progress=False).dataset
    cut_path = tmp_path / "cut.mcap"
    data = full_path.read_bytes()
    cut_path.write_bytes(data[: int(0.6 * len(data))])
    result = read_mcap(cut_path, progress=False)
    cut = result.dataset
    assert any("truncated" in w for w in result.warnings)
    n_imu, n_gnss = len(cut.imu), len(cut.gnss)
    assert 0.3 * len(full.imu) < n_imu < 0.8 * len(full.imu)
    np.testing.assert_array_equal(cut.imu.t, full.imu.t[:n_imu])
    np.testing.assert_array_equal(cut.imu.gyro, full.imu.gyro[:n_imu])
    np.testing.assert_array_equal(cut.gnss.lla, full.gnss.lla[:n_gnss])
    summary = summarize_mcap(cut_path)
    assert "TRUNCATED" in summary and "summary section: no" in summary


def test_summary_lists_channels_rates_and_gaps(drive: Drive, tmp_path: Path) -> None:
    keep = np.ones(drive.imu_ns.size, dtype=bool)
    t = (drive.imu_ns - drive.imu_ns[0]) / 1e9
    keep[(t >= 5.0) & (t < 6.0)] = False  # a 1 s hole in a 100 Hz stream
    path = write_foxglove_json(tmp_path / "gap.mcap", drive, imu_keep=keep)
    text = summarize_mcap(path)
    assert "summary section: yes" in text
    imu_line = next(line for line in text.splitlines() if line.strip().startswith("/imu:"))
    assert f"{int(keep.sum())} messages" in imu_line and "100.00 Hz" in imu_line
    assert "gap of 1.010 s at t+4.990 s" in text
    fix_line = next(line for line in text.splitlines() if "/gps/location" in line)
    assert f"{int(drive.valid.sum())} messages" in fix_line and "-> gnss" in fix_line


def test_repeated_and_backward_stamps_are_sorted_and_counted(tmp_path: Path) -> None:
    drive = make_drive(duration_s=5.0)
    drive.imu_ns[10] = drive.imu_ns[9]  # a repeated stamp
    drive.imu_ns[20], drive.imu_ns[21] = drive.imu_ns[21], drive.imu_ns[20]  # a backward step
    path = write_ros2_bag(tmp_path / "bag", drive, with_unknown=False)
    result = read_mcap(path, progress=False)
    imu = result.dataset.imu
    assert len(imu) == drive.imu_ns.size - 1
    assert np.all(np.diff(imu.t) > 0)
    assert any("dropped 1 IMU sample(s) with repeated time" in w for w in result.warnings)
    # the swapped pair is put back in time order with its own values
    k = int(np.searchsorted(imu.t, drive.imu_ns[21] / 1e9))
    np.testing.assert_array_equal(imu.gyro[k], drive.gyro[21])


def test_simulated_urban_drive_round_trips_through_a_ros2_bag(tmp_path: Path) -> None:
    scenarios = pytest.importorskip("fgins.sim.scenarios", reason="fgins.sim not available yet")
    if "car-urban" not in scenarios.SCENARIOS:
        pytest.skip("scenario car-urban not available yet")
    start = 1_000.0
    run = scenarios.SCENARIOS["car-urban"](seed=0, duration_s=30, start_time_s=start)
    drive = drive_from_dataset(run.dataset, start)
    path = write_ros2_bag(tmp_path / "bag", drive, with_baro=drive.baro_ns.size > 0)
    data = read_mcap(path, progress=False).dataset
    valid = drive.valid
    np.testing.assert_array_equal(data.imu.t, drive.imu_ns / 1e9)
    np.testing.assert_allclose(data.imu.t - data.imu.t[0], run.dataset.imu.t - start, atol=1e-6)
    np.testing.assert_array_equal(data.imu.gyro, run.dataset.imu.gyro)
    np.testing.assert_array_equal(data.imu.accel, run.dataset.imu.accel)
    np.testing.assert_array_equal(data.gnss.lla, run.dataset.gnss.lla[valid])
    np.testing.assert_allclose(data.gnss.std, run.dataset.gnss.std[valid], rtol=1e-14)


# --- corrupt bytes inside a chunk --------------------------------------------------------------


def _imu_only_mcap(path: Path, drive: Drive, compression: str, crcs: bool) -> Path:
    """The drive's Imu messages (CDR) in small chunks, with the plain mcap writer."""
    from mcap.writer import CompressionType, Writer

    from fgins.tests.mcap_fixtures import imu_cdr_bytes, imu_ros2msg_schema

    kind = {"": CompressionType.NONE, "zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4}
    with open(path, "wb") as stream:
        writer = Writer(stream, chunk_size=16384, compression=kind[compression], enable_crcs=crcs)
        writer.start(profile="", library="fgins-tests")
        schema = writer.register_schema(
            "sensor_msgs/msg/Imu", "ros2msg", imu_ros2msg_schema().encode()
        )
        channel = writer.register_channel("/imu", "cdr", schema)
        for ns, payload, _ in imu_cdr_bytes(drive):
            writer.add_message(channel, log_time=ns, data=payload, publish_time=ns)
        writer.finish()
    return path


def _chunk_spans(path: Path) -> list[tuple[int, int]]:
    """(start, end) file offsets of the chunk records, by mcap's own stream reader."""
    from mcap.records import Chunk
    from mcap.stream_reader import StreamReader

    spans = []
    with open(path, "rb") as file:
        reader = StreamReader(file, emit_chunks=True)
        start = file.tell()
        for record in reader.records:
            if isinstance(record, Chunk):
                spans.append((start, file.tell()))
            start = file.tell()
    return spans


def _damage(path: Path, out: Path, at: int, length: int) -> Path:
    data = bytearray(path.read_bytes())
    for k in range(at, at + length):
        data[k] ^= 0xFF
    out.write_bytes(bytes(data))
    return out


def _imu_only_scan(path: Path):
    """The message log times of an IMU-only file and the stream outcome (read_mcap wants a
    GNSS topic too)."""
    from mcap.records import Message

    from fgins.io.mcap_stream import StreamOutcome, stream_records

    outcome = StreamOutcome()
    stamps = []
    for record in stream_records(path, outcome, False, ""):
        if isinstance(record, Message):
            stamps.append(record.log_time)
    return np.array(stamps), outcome


def test_corrupt_bytes_inside_a_ros2_bag_chunk_lose_only_the_damaged_messages(
    drive: Drive, tmp_path: Path
) -> None:
    """rosbags writes uncompressed chunks without CRC: 1000 corrupt bytes in the middle of one
    used to end the read with "OverflowError: cannot fit 'int' into an index-sized integer"."""
    good_path = write_ros2_bag(tmp_path / "bag", drive, with_unknown=False)
    good = read_mcap(good_path, progress=False).dataset
    ((start, end),) = [span for span in _chunk_spans(good_path) if span[1] - span[0] > 100_000]
    bad_path = _damage(good_path, tmp_path / "damaged.mcap", (start + end) // 2, 1000)
    result = read_mcap(bad_path, progress=False)
    (warning,) = [w for w in result.warnings if "damaged chunk" in w]
    assert "1 damaged chunk(s)" in warning and "damaged byte(s) skipped" in warning, warning
    imu = result.dataset.imu
    # only the messages the damage touched are lost (1000 bytes: a few Imu messages)
    assert len(good.imu) - 8 <= len(imu) < len(good.imu)
    kept = np.searchsorted(good.imu.t, imu.t)
    np.testing.assert_array_equal(good.imu.t[kept], imu.t)
    np.testing.assert_array_equal(good.imu.gyro[kept], imu.gyro)  # no damaged value read
    np.testing.assert_array_equal(good.imu.accel[kept], imu.accel)
    summary = summarize_mcap(bad_path)
    assert "DAMAGED:" in summary and "TRUNCATED" not in summary


@pytest.mark.parametrize(("compression", "crcs"), [("zstd", True), ("lz4", True), ("", True)])
def test_a_damaged_chunk_is_counted_and_the_chunks_after_it_read(
    drive: Drive, tmp_path: Path, compression: str, crcs: bool
) -> None:
    good_path = _imu_only_mcap(tmp_path / "good.mcap", drive, compression, crcs)
    good_stamps, _ = _imu_only_scan(good_path)
    spans = _chunk_spans(good_path)
    assert len(spans) > 5
    start, end = spans[len(spans) // 2]
    bad_path = _damage(good_path, tmp_path / "bad.mcap", (start + end) // 2, 64)
    stamps, outcome = _imu_only_scan(bad_path)
    assert len(outcome.damaged) == 1 and not outcome.truncated
    assert set(stamps) <= set(good_stamps)
    assert stamps[-1] == good_stamps[-1]  # the chunks after the damaged one are read
    lost = len(good_stamps) - len(stamps)
    assert 0 < lost <= len(good_stamps) // len(spans) + 2  # at most that chunk
    if compression == "":  # uncompressed, payload bytes damaged: only its CRC tells
        assert "CRC fails" in outcome.damaged[0].why and outcome.damaged[0].dropped > 0


@pytest.mark.parametrize("seed", [9, 201, 206])
def test_corrupt_bytes_in_a_recording_never_end_in_an_internal_error(tmp_path, seed):
    """300 random bytes overwritten in a ROS 2 MCAP: a message's log time beyond 64 signed
    bits broke the readers' arrays ("internal error: int too big to convert" in inspect,
    "operands could not be broadcast" in smooth; outside tester). Every reader now either
    reads the rest (damage counted) or stops with a one-line user error."""
    import random

    import fgins
    from fgins.datatypes import FginsError
    from fgins.io.mcap import summarize_mcap
    from fgins.sim.scenarios import SCENARIOS
    from fgins.tests.mcap_fixtures import drive_from_dataset, write_bag

    run = SCENARIOS["car-urban"](seed=4, duration_s=60.0, start_time_s=1_700_000_000.0)
    write_bag(tmp_path / "good", drive_from_dataset(run.dataset, 1_700_000_000.0), "ros2-mcap")
    data = bytearray(next((tmp_path / "good").glob("*.mcap")).read_bytes())
    random.seed(seed)
    for _ in range(300):
        data[random.randrange(100, len(data))] = random.randrange(256)
    path = tmp_path / "damaged.mcap"
    path.write_bytes(bytes(data))
    try:
        assert "damaged.mcap" in summarize_mcap(path)
    except FginsError:
        pass
    try:
        fgins.load(path)
    except FginsError as exc:
        assert "\n" not in str(exc)


@pytest.mark.parametrize("group", [10, 4])
def test_imu_stamps_shared_by_groups_of_samples_are_refused_as_in_a_csv(tmp_path, group):
    """A driver that stamps each read of a buffer gives every sample of it one header stamp
    (rosbags writer): the reader dropped 90 % of the IMU as repeated samples with a warning
    and smoothed at 10 Hz (outside tester: 1.4 m off at z 4.5), where the same stamps in a
    CSV were refused. Now the one check of the samples refuses both, naming the groups."""
    import dataclasses

    from fgins.io.csv_pair import read_imu_csv
    from fgins.io.inputs import load_dataset

    drive = make_drive(duration_s=20.0)
    period = int(np.median(np.diff(drive.imu_ns)))
    last_of_group = (np.arange(len(drive.imu_ns)) // group + 1) * group - 1
    stamps = drive.imu_ns[0] + last_of_group * period + 2_000_000  # the read, 2 ms after the last
    shared = dataclasses.replace(drive, imu_ns=stamps)
    bag = write_ros2_bag(tmp_path / "bag", shared)
    with pytest.raises(InputError, match=rf"groups of about {group} .*not when each was taken"):
        load_dataset([str(bag)], progress=False)
    csv = tmp_path / "imu.csv"
    rows = np.column_stack([stamps / 1e9, drive.gyro, drive.accel])
    np.savetxt(csv, rows, delimiter=",", fmt="%.9f", header="time,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z",
               comments="")  # fmt: skip
    with pytest.raises(InputError, match=rf"groups of about {group} "):
        read_imu_csv(csv, [])
