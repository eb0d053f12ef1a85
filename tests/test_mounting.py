"""Mounting angles mean the IMU's orientation in the vehicle (roll, pitch, yaw; ZYX)."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from fgins.mounting import mounting_rotation


@pytest.mark.parametrize("rpy", [(0.0, 0.0, 0.0), (2.0, -3.0, 90.0), (-10.0, 5.0, -170.0)])
def test_mounting_rotation_is_zyx(rpy):
    roll, pitch, yaw = np.radians(rpy)
    np.testing.assert_allclose(
        mounting_rotation(rpy), gtsam.Rot3.Ypr(yaw, pitch, roll).matrix(), atol=1e-12
    )


def test_closed_forms():
    # An IMU turned 90 deg to the left in the car: its x axis points along the car's left.
    np.testing.assert_allclose(mounting_rotation([0, 0, 90]) @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    # x forward, y right, z down (FRD) is roll 180: IMU z is the car's down, IMU y its right.
    frd = mounting_rotation([180, 0, 0])
    np.testing.assert_allclose(frd @ [0, 0, 1], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(frd @ [0, 1, 0], [0, -1, 0], atol=1e-12)
    # Pitch is right-handed about the car's left axis: a positive pitch turns IMU x down.
    down = mounting_rotation([0, 10, 0]) @ [1, 0, 0]
    assert down[2] < 0
    # Rows are the vehicle's axes in IMU axes.
    rotation = mounting_rotation([20, -10, 35])
    forward_in_imu = rotation[0]
    np.testing.assert_allclose(rotation @ forward_in_imu, [1, 0, 0], atol=1e-12)


@pytest.mark.parametrize("seed", [5, 6, 7])
def test_a_short_hilly_drive_without_gnss_velocity_is_no_mounting_error(tmp_path, seed):
    """150 s of the independent simulator's hilly drive (+-8 % grades, two turns), fixes
    without velocity, IMU mounted straight: the grade's share of gravity along the forward
    axis, correlated with the two turns, turned the fitted forward axis by 34 deg, and the
    run stopped with "the car constraints would fight the data". The climb now comes from
    the fixes' heights when the receiver gives no vertical velocity."""
    import sys
    from pathlib import Path

    import fgins
    from fgins.mounting import check_mounting, mounting_yaw_error_deg

    sys.path.insert(0, str(Path(__file__).parent))
    from independent_sim import INDUSTRIAL, hilly_drive, write_drive

    write_drive(tmp_path, hilly_drive(), 150.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                gnss_rate=1.0, seed=seed, sigma_h=0.05, sigma_u=0.1)  # fmt: skip
    dataset = fgins.load(tmp_path / "imu.csv", tmp_path / "gnss.csv", config=tmp_path / "cfg.toml")
    assert check_mounting(dataset, (0.0, 0.0, 0.0)) is None
    found = mounting_yaw_error_deg(dataset, (0.0, 0.0, 0.0))
    assert found is None or abs(found[0]) < 5.0, found


@pytest.mark.parametrize("start_s", [300.0, 345.0, 365.0])
def test_a_drive_that_turns_mostly_one_way_is_no_tilted_mounting(start_s):
    """The last 100-170 s of the KITTI drive (its mounting is right: the whole drive fits it)
    turn mostly one way; the plain mean of the specific force leaned 3.3-3.6 deg with their
    centripetal acceleration, and every method warned that the mounting's roll was off. A
    roll really left out of the mounting (5 deg) is still said."""
    import fgins
    from fgins.datatypes import ImuData
    from fgins.mounting import check_mounting

    dataset = fgins.load("demo:kitti")
    start = float(dataset.t0) + start_s
    keep = dataset.imu.t >= start - 0.3
    dataset.imu = ImuData(t=dataset.imu.t[keep], gyro=dataset.imu.gyro[keep],
                          accel=dataset.imu.accel[keep])  # fmt: skip
    dataset.gnss = dataset.gnss.subset(dataset.gnss.t >= start)
    assert check_mounting(dataset, (0.0, 0.55, 0.0)) is None
    note = check_mounting(dataset, (5.0, 0.55, 0.0))
    assert note is not None and "roll is off" in note and "do not see a roll" in note
