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
