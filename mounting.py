"""IMU mounting: the IMU's orientation in the vehicle frame (numpy only).

``imu_to_vehicle_rpy_deg = [roll, pitch, yaw]`` are the usual mounting angles: the rotation
that takes the vehicle frame (x forward, y left, z up) onto the IMU's axes, applied as yaw
about z, then pitch about the new y, then roll about the new x (ZYX). Its matrix
``R_vi = Rz(yaw) Ry(pitch) Rx(roll)`` maps a vector given in IMU axes into vehicle axes:
``u_vehicle = R_vi @ u_imu``. Example: an IMU turned 90 deg to the left in the car (its x
axis points to the car's left) has yaw = 90; an IMU mounted x forward, y right, z down (FRD)
has roll = 180.

The factor graph, every Kalman baseline and the initial alignment take the rotation from
here, so they cannot disagree about the convention.
"""

from __future__ import annotations

import numpy as np


def _axis_rotation(axis: int, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    rotation = np.eye(3)
    rotation[i, i] = rotation[j, j] = c
    rotation[i, j], rotation[j, i] = -s, s
    return rotation


def mounting_rotation(rpy_deg: tuple[float, float, float] | np.ndarray) -> np.ndarray:
    """``R_vi`` (IMU axes -> vehicle axes) from the mounting angles (deg; see module docs).

    Its rows are the vehicle's forward, left and up axes expressed in IMU axes.
    """
    roll, pitch, yaw = np.radians(np.asarray(rpy_deg, dtype=float))
    return _axis_rotation(2, yaw) @ _axis_rotation(1, pitch) @ _axis_rotation(0, roll)

