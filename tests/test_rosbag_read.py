"""ROS 1 bags, ROS 2 SQLite bags and ROS 1 MCAP files, written by rosbags (its own ROS 1 and
CDR serializers and bag writers; the ROS 1 MCAP through the plain mcap writer with rosbags'
message definitions, as ``mcap convert`` makes of a .bag), against the values written.

Every kind must give exactly the dataset the ROS 2 MCAP bag of the same drive gives (the
reference path, itself checked against the written values in test_mcap_read.py), and a
simulated drive smoothed from a ROS 1 bag must equal the same drive from its CSVs.
"""

from __future__ import annotations

import numpy as np
import pytest

from fgins.cli import main
from fgins.datatypes import InputError
from fgins.io.inputs import load_dataset
from fgins.io.rosbag import read_rosbag, summarize_rosbag
from fgins.tests.mcap_fixtures import (
    drive_from_dataset,
    gga_sentences,
    make_drive,
    write_bag,
    write_ros2_bag,
)

KINDS = {"ros1-bag": "drive.bag", "ros2-sqlite": "bag", "ros1-mcap": "drive.mcap"}


def _same(a, b) -> None:
    np.testing.assert_array_equal(a.imu.t, b.imu.t)
    np.testing.assert_array_equal(a.imu.gyro, b.imu.gyro)
    np.testing.assert_array_equal(a.imu.accel, b.imu.accel)
    np.testing.assert_array_equal(a.gnss.t, b.gnss.t)
    np.testing.assert_array_equal(a.gnss.lla, b.gnss.lla)
    np.testing.assert_array_equal(a.gnss.std, b.gnss.std)
    for name in ("velocity", "velocity_std", "hdop", "fix_quality"):
        x, y = getattr(a.gnss, name), getattr(b.gnss, name)
        assert (x is None) == (y is None), name
        if x is not None:
            np.testing.assert_array_equal(x, y)
    assert (a.baro is None) == (b.baro is None)
    if a.baro is not None:
        np.testing.assert_array_equal(a.baro.t, b.baro.t)
        np.testing.assert_array_equal(a.baro.pressure, b.baro.pressure)
    assert a.imu_config == b.imu_config


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize(
    "options",
    [
        {"second_imu_every": 3},
        {"gpsfix": True, "with_velocity": False},
        {"imu_variances": (4e-6, 9e-4), "with_baro": False},
    ],
    ids=["navsatfix-twist-baro", "gpsfix", "imu-covariances"],
)
def test_every_bag_kind_reads_as_the_ros2_mcap_of_the_same_drive(tmp_path, kind, options):
    drive = make_drive()
    reference = load_dataset([str(write_ros2_bag(tmp_path / "ref", drive, **options))],
                             progress=False)  # fmt: skip
    path = write_bag(tmp_path / KINDS[kind], drive, kind, **options)
    dataset = load_dataset([str(path)], progress=False)
    _same(dataset, reference)
    valid = drive.valid
    np.testing.assert_array_equal(dataset.gnss.lla, drive.lla[valid])  # and the written values
    np.testing.assert_array_equal(dataset.imu.t, drive.imu_ns / 1e9)
    report = dataset.metadata["mcap_report"]
    assert any(line.startswith("imu: /imu/data (sensor_msgs/msg/Imu") for line in report)
    assert any("skipped /mystery: unknown schema acme_msgs/msg/Mystery (7" in line
               for line in report)  # fmt: skip
    if options.get("imu_variances"):
        assert dataset.imu_config["gyro_noise_rad_per_s_per_sqrt_hz"] == pytest.approx(
            np.sqrt(4e-6) / np.sqrt(100.0)
        )


@pytest.mark.parametrize("kind", KINDS)
def test_nmea_sentences_in_a_bag(tmp_path, kind):
    drive = make_drive()
    sentences = gga_sentences(drive)
    reference = load_dataset(
        [str(write_ros2_bag(tmp_path / "ref", drive, nmea_sentences=sentences,
                            with_velocity=False))], progress=False,
    )  # fmt: skip
    path = write_bag(tmp_path / KINDS[kind], drive, kind, nmea_sentences=sentences,
                     with_velocity=False)  # fmt: skip
    _same(load_dataset([str(path)], progress=False), reference)


def test_topic_override_and_its_error(tmp_path):
    drive = make_drive()
    path = write_bag(tmp_path / "drive.bag", drive, "ros1-bag", second_imu_every=3)
    sparse = read_rosbag(path, imu_topic="/imu/raw", progress=False).dataset
    np.testing.assert_array_equal(sparse.imu.t, drive.imu_ns[::3] / 1e9)
    with pytest.raises(InputError, match=r"imu topic '/nope' not found .*/imu/data, /imu/raw"):
        read_rosbag(path, imu_topic="/nope", progress=False)


def test_a_db3_file_means_its_bag_folder(tmp_path):
    drive = make_drive()
    folder = write_bag(tmp_path / "bag", drive, "ros2-sqlite")
    (db3,) = folder.glob("*.db3")
    _same(load_dataset([str(db3)], progress=False), load_dataset([str(folder)], progress=False))
    alone = tmp_path / "alone" / db3.name
    alone.parent.mkdir()
    alone.write_bytes(db3.read_bytes())
    with pytest.raises(InputError, match=r"without its metadata\.yaml; give the bag folder"):
        load_dataset([str(alone)], progress=False)


def test_a_ros2_bag_folder_of_one_mcap_is_read_as_that_file(tmp_path):
    drive = make_drive()
    mcap_file = write_ros2_bag(tmp_path / "bag", drive)
    from_folder = load_dataset([str(mcap_file.parent)], progress=False)
    _same(from_folder, load_dataset([str(mcap_file)], progress=False))
    assert from_folder.metadata["format"] == "mcap"  # the streaming MCAP reader


def test_bad_bags_are_one_line_errors(tmp_path, capsys):
    drive = make_drive()
    good = write_bag(tmp_path / "drive.bag", drive, "ros1-bag")
    cut = tmp_path / "cut.bag"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    no_imu = write_bag(tmp_path / "gnss.bag", drive, "ros1-bag", with_imu=False)
    cases = [
        ([str(cut)], "cannot read this ROS 1 bag"),
        ([str(no_imu)], "no IMU channel"),
        ([str(good), str(no_imu)], "a ROS bag is a whole recording on its own"),
    ]
    for inputs, message in cases:
        out = tmp_path / "out.csv"
        assert main(["smooth", *inputs, "-o", str(out)]) == 2
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err, err
        assert len(err.strip().splitlines()) <= 3 and not out.exists()


def test_convert_and_inspect_read_bags(tmp_path, capsys):
    drive = make_drive()
    bag = write_bag(tmp_path / "drive.bag", drive, "ros1-bag")
    assert main(["inspect", str(bag)]) == 0
    out = capsys.readouterr().out
    assert "ROS 1 bag" in out and "/imu/data: sensor_msgs/msg/Imu -> imu; 2000 messages" in out
    gnss_only = write_bag(tmp_path / "gnss", drive, "ros2-sqlite", with_imu=False)
    assert main(["convert", str(gnss_only), "-o", str(tmp_path / "fixes.csv")]) == 0
    rows = np.genfromtxt(tmp_path / "fixes.csv", delimiter=",", names=True)
    np.testing.assert_allclose(rows["lat"], drive.lla[drive.valid, 0], rtol=0, atol=1e-9)
    assert "ROS 2 bag" in summarize_rosbag(gnss_only)


def test_a_simulated_drive_smooths_alike_from_a_ros1_bag_and_from_the_simulator(tmp_path):
    """The round trip a user makes: a drive recorded as a ROS 1 bag smooths to the trajectory
    the same samples give straight from the simulator (same config; the ENU origins differ,
    so positions are compared as latitude/longitude), and near the simulator's truth."""
    from fgins.config import config_for_dataset
    from fgins.geodesy import enu_to_lla
    from fgins.pipeline import run_method
    from fgins.sim.scenarios import SCENARIOS

    start = 1_000.0
    run = SCENARIOS["car-urban"](seed=1, duration_s=40, start_time_s=start)
    bag = write_bag(tmp_path / "drive.bag", drive_from_dataset(run.dataset, start), "ros1-bag",
                    with_baro=False, with_unknown=False)  # fmt: skip
    from_bag = load_dataset([str(bag)], progress=False)
    np.testing.assert_array_equal(from_bag.imu.gyro, run.dataset.imu.gyro)
    np.testing.assert_array_equal(from_bag.imu.accel, run.dataset.imu.accel)
    direct = run.dataset
    direct.baro = None  # the bag was written without it
    # One configuration for both: the simulator's (its IMU grade and sample timing, the
    # antenna lever arm), which a user would give the bag with --config.
    config = config_for_dataset(direct, vehicle="car")
    tracks = []
    for dataset in (from_bag, direct):
        trajectory = run_method(dataset, config, "batch", progress=False)
        tracks.append(enu_to_lla(trajectory.position, dataset.origin))
    bag_track, direct_track = tracks
    north_m = np.radians(bag_track[:, 0] - direct_track[:, 0]) * 6.371e6
    east_m = np.radians(bag_track[:, 1] - direct_track[:, 1]) * 6.371e6 * np.cos(
        np.radians(bag_track[:, 0])
    )
    assert np.max(np.hypot(north_m, east_m)) < 0.02


def test_a_file_named_bag_that_is_not_one_is_named_by_its_content(tmp_path, capsys):
    fake = tmp_path / "fake.bag"
    fake.write_text("time,gyro_x\n0,1\n")
    assert main(["smooth", str(fake), "-o", str(tmp_path / "out.csv")]) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and "fgins: error:" in err
