"""Simulated drives changed the way a user's data can differ (shared by several tests)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import numpy as np

from fgins.datatypes import Dataset
from fgins.mounting import mounting_rotation


def turned_imu(run: Any, rpy: tuple[float, float, float]) -> tuple[Dataset, dict[str, Any]]:
    """``run``'s dataset with its IMU mounted at ``rpy`` (deg, the IMU's orientation in the
    car), and the ``[gnss]`` table whose lever arm (IMU axes) turns with it. The mounting
    itself is not put into any configuration: that is the caller's choice."""
    r_vi = mounting_rotation(rpy)
    dataset = run.dataset
    imu = replace(dataset.imu, gyro=dataset.imu.gyro @ r_vi, accel=dataset.imu.accel @ r_vi)
    gnss = dict(dataset.gnss_config)
    gnss["lever_arm_m"] = list(r_vi.T @ np.asarray(gnss.get("lever_arm_m", [0, 0, 0]), float))
    return replace(dataset, imu=imu, warnings=[]), gnss
