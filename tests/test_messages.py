"""User mistakes get messages that name the real cause and the fix (outside tester, round 3).

Each test fails on the code before the fix: the message blamed another cause (time bases, zero
noise, a key the user never wrote), said nothing (a tie between two IMU topics), refused a
valid file (a config with a UTF-8 BOM), went on with 1 % of the data (whole-second IMU
stamps), replaced a symlink to an input, or printed an internal error (a closed stdout).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fgins import api
from fgins.config import load_config
from fgins.datatypes import ConfigError, InputError, OutputError
from fgins.io.csv_pair import read_imu_csv
from fgins.io.inputs import load_dataset

IMU_HEADER = "time,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z"


def _imu_csv(path: Path, t: np.ndarray) -> Path:
    rows = [f"{v:.6f},0.001,-0.002,0.0005,0.05,-0.03,9.81" for v in t]
    path.write_text(IMU_HEADER + "\n" + "\n".join(rows) + "\n")
    return path


# --- 1. one GNSS fix in the whole input --------------------------------------------------------


def test_a_single_fix_in_the_input_says_so_not_the_time_bases(tmp_path: Path) -> None:
    """Before: "only 1 of 1 GNSS fixes lie within the IMU time span ... different time bases?"."""
    imu = _imu_csv(tmp_path / "imu.csv", np.arange(0, 20, 0.01))
    gnss = tmp_path / "gnss.csv"
    gnss.write_text("time,lat,lon,alt\n10.0,48.137,11.575,520.0\n")
    with pytest.raises(InputError, match=r"only 1 usable GNSS fix.*at least 2") as info:
        load_dataset([str(imu), str(gnss)], progress=False)
    assert "time bases" not in str(info.value)


# --- 2. a ROS 2 bag folder -------------------------------------------------------------------


def _bag(tmp_path: Path, **kw) -> Path:
    pytest.importorskip("rosbags", reason="test extra: pip install rosbags")
    from fgins.tests.mcap_fixtures import make_drive, write_ros2_bag

    return write_ros2_bag(tmp_path / "bag", make_drive(duration_s=10.0), **kw)


def test_a_ros2_bag_folder_is_read_and_a_stray_file_in_it_said(tmp_path: Path) -> None:
    """Before: "not a folder written by fgins sim ... give the CSV files themselves"; then an
    error naming the .mcap to give. Now the folder is read (its one MCAP file by the
    streaming reader); an MCAP file the bag's metadata.yaml does not list is not part of the
    bag: not read, and said."""
    mcap = _bag(tmp_path)
    dataset = load_dataset([str(mcap.parent)], progress=False)
    np.testing.assert_array_equal(dataset.imu.t, load_dataset([str(mcap)], progress=False).imu.t)
    shutil.copy(mcap, mcap.parent / "zz_1.mcap")
    dataset = load_dataset([str(mcap.parent)], progress=False)
    assert any("zz_1.mcap not listed in its metadata.yaml: not part of the bag, not read" in w
               for w in dataset.warnings)  # fmt: skip
    assert len(dataset.imu.t) == len(load_dataset([str(mcap)], progress=False).imu.t)


# --- 3. two IMU topics with as many messages ---------------------------------------------------


def test_a_tie_between_imu_topics_is_a_warning_naming_the_override(tmp_path: Path) -> None:
    """Before: "most messages of 2 candidates" and nothing else, though the counts tie."""
    from fgins.io.mcap import read_mcap

    result = read_mcap(_bag(tmp_path, second_imu_every=1), progress=False)
    (line,) = [w for w in result.warnings if "messages each" in w]
    assert "/imu/data, /imu/raw" in line and "--imu-topic /imu/raw" in line
    assert "tied" in result.report[0]


def test_no_tie_warning_when_one_imu_topic_has_more_messages(tmp_path: Path) -> None:
    from fgins.io.mcap import read_mcap

    result = read_mcap(_bag(tmp_path, second_imu_every=3), progress=False)
    assert not [w for w in result.warnings if "messages each" in w]


@pytest.mark.parametrize(
    ("topics", "read", "derived"),
    [
        ({"/gps/fix": 996, "/gps/filtered": 3980}, "/gps/fix", "/gps/filtered"),
        ({"/odometry/gps": 2000, "/ublox/fix": 1000, "/novatel/fix": 990}, "/ublox/fix", "/odometry/gps"),
        ({"/gnss/left": 1000, "/gnss/right": 990}, "/gnss/left", None),
        # an INS's fused fixes under its own or the IMU's name (outside tester: 1-1.5 m, z 3-7)
        ({"/imu/nav_sat_fix": 15000, "/ublox/fix": 301}, "/ublox/fix", "/imu/nav_sat_fix"),
        ({"/xsens/gnss_pose_fix": 6000, "/ublox/fix": 301}, "/ublox/fix", "/xsens/gnss_pose_fix"),
        ({"/sbg/ins_fix": 6000, "/gps/fix": 301}, "/gps/fix", "/sbg/ins_fix"),
        # "ins" only as a whole part: a receiver's topic that merely contains the letters stays
        ({"/instrument/fix": 1000, "/gps/fix": 990}, "/instrument/fix", None),
    ],
)
def test_a_gnss_topic_is_chosen_said_and_never_a_fusion_node_s_output(topics, read, derived) -> None:
    """A fusion node's fixes (robot_localization's /gps/filtered at 20 Hz) beside the
    receiver's: chosen for their count, 3 m off at 88 times their sigmas, said only in an
    info line (outside tester). Topics named as an estimator's output come last, whatever
    their count, and a choice among GNSS topics is a warning naming the override."""
    from fgins.io.mcap import ROLE_GNSS, ROLE_IMU, _Candidate, _choose

    candidates = [_Candidate(i, topic, "sensor_msgs/msg/NavSatFix", ROLE_GNSS) for i, topic in enumerate(topics)]
    counts = {i: n for i, n in enumerate(topics.values())}
    report: list[str] = []
    warnings: list[str] = []
    assert _choose(ROLE_GNSS, candidates, counts, None, report, warnings).topic == read
    (said,) = warnings
    assert said.startswith(f"gnss: {len(topics)} GNSS topics; read {read}") and "--gnss-topic" in said
    assert (derived is not None) == ("fused, filtered or INS output" in said)
    if derived is not None:
        assert f"({derived}: by its name" in said
    # IMU topics keep their rule (most messages), without a warning unless tied.
    imus = [_Candidate(i, topic, "sensor_msgs/msg/Imu", ROLE_IMU) for i, topic in enumerate(["/imu/filtered", "/imu"])]
    warnings.clear()
    assert _choose(ROLE_IMU, imus, {0: 10, 1: 5}, None, [], warnings).topic == "/imu/filtered"
    assert not warnings


def test_an_imu_error_in_a_multi_imu_file_names_the_other_topics(tmp_path: Path) -> None:
    """Before: the error blamed the IMU read without saying another topic could be read."""
    from dataclasses import replace

    from fgins.io.inputs import validated
    from fgins.io.mcap import read_mcap

    dataset = read_mcap(_bag(tmp_path, second_imu_every=1), progress=False).dataset
    dataset.imu = replace(dataset.imu, accel=dataset.imu.accel / 9.80665)  # in g: an IMU error
    with pytest.raises(InputError, match=r"^imu: .*topic /imu/data.*--imu-topic /imu/raw"):
        validated(dataset)


# --- 4. range messages ----------------------------------------------------------------------


def test_a_huge_noise_value_gets_the_upper_side_hint(tmp_path: Path) -> None:
    """Before: 1e308 got "zero white noise makes the IMU factors singular"."""
    path = tmp_path / "c.toml"
    path.write_text("[imu]\ngyro_arw_deg_per_sqrt_hr = 1e308\n")
    with pytest.raises(ConfigError, match=r"must be > 0 and <= 100 \(far beyond any IMU") as info:
        load_config(path)
    assert "zero white noise" not in str(info.value)
    path.write_text("[imu]\ngyro_arw_deg_per_sqrt_hr = 0\n")
    with pytest.raises(ConfigError, match=r"must be > 0 \(zero white noise"):
        load_config(path)


def test_noise_from_imu_covariances_names_its_source_and_the_override(tmp_path: Path) -> None:
    """Before: "sensor settings of bag_0: [imu].gyro_noise_... = 99.99": a key the user never
    wrote, and --imu-preset did not help (the data's value was checked all the same)."""
    from fgins.config import config_for_dataset
    from fgins.io.mcap import read_mcap

    dataset = read_mcap(_bag(tmp_path, imu_variances=(1e6, 1e-4)), progress=False).dataset
    with pytest.raises(ConfigError) as info:
        config_for_dataset(dataset)
    message = str(info.value)
    assert "sensor_msgs/Imu covariances of /imu/data" in message
    assert "gyro_noise_rad_per_s_per_sqrt_hz" in message and "--imu-preset" in message
    assert "zero white noise" not in message
    config = config_for_dataset(dataset, imu_preset="tactical")  # the override works
    assert config.imu == {"preset": "tactical"}


def test_a_user_noise_key_replaces_the_datas_key_for_the_same_quantity(tmp_path: Path) -> None:
    """An MCAP's Imu covariances give gyro_noise_rad_per_s_per_sqrt_hz; a user's
    gyro_arw_deg_per_sqrt_hr (the same quantity in datasheet units) used to lose to it."""
    from fgins.config import config_for_dataset
    from fgins.io.mcap import read_mcap

    dataset = read_mcap(_bag(tmp_path, imu_variances=(1e-6, 1e-4)), progress=False).dataset
    assert "gyro_noise_rad_per_s_per_sqrt_hz" in dataset.imu_config
    user = tmp_path / "user.toml"
    user.write_text("[imu]\ngyro_arw_deg_per_sqrt_hr = 0.5\naccel_vrw_m_per_s_per_sqrt_hr = 0.2\n")
    noise = config_for_dataset(dataset, user).imu_noise()
    assert noise.gyro_noise == pytest.approx(0.5 * np.pi / 180 / 60)
    assert noise.accel_noise == pytest.approx(0.2 / 60)


# --- 5. cosmetic ----------------------------------------------------------------------------


def test_a_config_with_a_utf8_bom_is_read(tmp_path: Path) -> None:
    """Before: "Invalid statement (at line 1, column 1)"."""
    path = tmp_path / "c.toml"
    path.write_bytes("\ufeff[imu]\ngyro_arw_deg_per_sqrt_hr = 0.3\n".encode())
    assert load_config(path).imu == {"gyro_arw_deg_per_sqrt_hr": 0.3}


def test_a_damaged_mcap_summary_is_reported_as_such(tmp_path: Path) -> None:
    """Before: "a damaged record at byte N ...; the rest of the file cannot be read" (or "file
    truncated"), though every message was before the damage."""
    from mcap.records import DataEnd
    from mcap.stream_reader import StreamReader

    from fgins.io.mcap import read_mcap, summarize_mcap

    good = _bag(tmp_path)
    with open(good, "rb") as file:
        reader = StreamReader(file, emit_chunks=True)
        for record in reader.records:
            if isinstance(record, DataEnd):
                summary_at = file.tell()
                break
    data = bytearray(good.read_bytes())
    data[summary_at + 1 : summary_at + 9] = b"\xff" * 8  # the first summary record's length
    bad = tmp_path / "damaged_summary.mcap"
    bad.write_bytes(bytes(data))
    expected = read_mcap(good, progress=False).dataset
    result = read_mcap(bad, progress=False)
    (line,) = [w for w in result.warnings if "damaged" in w]
    assert f"damaged summary section (a record at byte {summary_at} " in line
    assert "read in full" in line and "cannot be read" not in line
    np.testing.assert_array_equal(result.dataset.imu.t, expected.imu.t)
    summary = summarize_mcap(bad)
    assert "DAMAGED SUMMARY" in summary and "summary section: damaged" in summary


def test_imu_stamps_in_whole_seconds_are_an_error(tmp_path: Path) -> None:
    """Before: 99 % of the rows dropped as repeated times, the run went on at 1 Hz."""
    t = np.floor(np.arange(0, 60, 0.01) + 1e-9)
    with pytest.raises(InputError, match=r"about 100 per time.*1 s resolution.*fractional"):
        read_imu_csv(_imu_csv(tmp_path / "imu.csv", t))


@pytest.mark.parametrize("burst", [2, 5, 25])
def test_imu_stamps_taken_on_receipt_in_bursts_are_an_error(tmp_path: Path, burst: int) -> None:
    """A PC logger stamping 100 Hz samples as a driver hands them over, ``burst`` at a time,
    10 us apart: every burst's gap was bridged as an IMU gap (outside tester: 1,200 gaps
    over the whole drive at 4 Hz bursts, 2.4 m off at z 4.7, two false corrections)."""
    k = np.arange(6000)
    received = (k // burst + 1) * burst * 0.01 + 0.002  # after the burst's last sample
    t = 1000.0 + received + 1e-5 * (k % burst)
    with pytest.raises(InputError, match=rf"bursts of about {burst}, stamped when they were received"):
        read_imu_csv(_imu_csv(tmp_path / "imu.csv", t))


@pytest.mark.parametrize("jitter", [0.1, 0.45])
def test_jittered_imu_stamps_are_no_bursts(tmp_path: Path, jitter: float) -> None:
    """Stamps jittered by up to +-``jitter`` of the period (uniform) load as they are."""
    t = 1000.0 + np.arange(6000) * 0.01
    t = t + np.random.default_rng(1).uniform(-jitter, jitter, t.size) * 0.01
    assert len(read_imu_csv(_imu_csv(tmp_path / "imu.csv", np.sort(t)))) == t.size


def test_a_few_repeated_imu_stamps_stay_a_counted_warning(tmp_path: Path) -> None:
    t = np.arange(0, 10, 0.01)
    t[[100, 200, 300]] = t[[99, 199, 299]]
    warnings: list[str] = []
    imu = read_imu_csv(_imu_csv(tmp_path / "imu.csv", t), warnings)
    assert len(imu) == t.size - 3
    assert any("dropped 3 IMU sample(s) with repeated time" in w for w in warnings)


def test_an_output_linking_to_a_file_of_an_input_folder_is_refused(tmp_path: Path) -> None:
    """Before: -o link.csv (-> folder/imu.csv) passed the check; the write replaced the link."""
    folder = tmp_path / "drive"
    folder.mkdir()
    _imu_csv(folder / "imu.csv", np.arange(0, 1, 0.01))
    link = tmp_path / "out" / "link.csv"
    link.parent.mkdir()
    link.symlink_to(folder / "imu.csv")
    with pytest.raises(OutputError, match=r"link.csv \(a link to .*imu.csv\): imu.csv is a file"):
        api.check_output(link, [folder])
    assert link.is_symlink()
    api.check_output(tmp_path / "out" / "other.csv", [folder])  # a plain name is still fine


# --- 6. a closed stdout ---------------------------------------------------------------------


def test_inspect_into_a_closed_pipe_exits_quietly(tmp_path: Path) -> None:
    """Before: "fgins: internal error: BrokenPipeError: [Errno 32] Broken pipe", exit 1."""
    imu = _imu_csv(tmp_path / "imu.csv", np.arange(0, 10, 0.01))
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    process = subprocess.Popen(
        [sys.executable, "-m", "fgins", "inspect", str(imu)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        env=env,
    )
    process.stdout.close()  # the reader is gone before fgins writes (its imports take longer)
    _, stderr = process.communicate(timeout=120)
    assert process.returncode == 141, stderr
    assert stderr.decode().strip() == ""
