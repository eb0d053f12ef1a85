"""Issue 12 item 8: mounting angles are the IMU's orientation in the vehicle.

The same simulated car drive is fed with its IMU turned inside the car: the IMU readings
(and the antenna lever arm, which is given in IMU axes) are rotated by the mounting, and the
mounting angles are given in the configuration. Every estimator must then reproduce the
unrotated drive; with the mounting left out, the fit must say so.
"""

from __future__ import annotations

import numpy as np
import pytest

from fgins.config import load_config
from fgins.outages import in_windows, outage_mask
from fgins.pipeline import run_method
from fgins.sim.scenarios import SCENARIOS
from fgins.tests.drive_fixtures import turned_imu

WINDOWS = [(50.0, 85.0)]


@pytest.fixture(scope="module")
def drive():
    return SCENARIOS["car-urban"](seed=2, duration_s=140)


def _config(dataset, gnss, rpy):
    config = load_config(dataset_imu=dataset.imu_config, dataset_gnss=gnss)
    config.smoother.vehicle = "car"
    config.smoother.imu_to_vehicle_rpy_deg = tuple(float(a) for a in rpy)
    return config


def _rms(trajectory, run, dataset) -> float:
    inside = in_windows(trajectory.t, dataset.t0, WINDOWS)
    error = np.linalg.norm(trajectory.position[:, :2] - run.truth.at(trajectory.t)[:, :2], axis=1)
    return float(np.sqrt(np.mean(error[inside] ** 2)))


@pytest.mark.parametrize("rpy", [(20.0, -10.0, 35.0), (180.0, 0.0, 0.0), (0.0, 0.0, -90.0)])
@pytest.mark.parametrize("method", ["batch", "ekf-rts"])
def test_a_turned_imu_with_its_mounting_reproduces_the_drive(drive, rpy, method):
    reference_dataset, gnss = turned_imu(drive, (0.0, 0.0, 0.0))
    reference = run_method(
        reference_dataset, _config(reference_dataset, gnss, (0, 0, 0)), method,
        gnss_mask=outage_mask(reference_dataset, WINDOWS), progress=False,
    )  # fmt: skip
    dataset, gnss = turned_imu(drive, rpy)
    turned = run_method(
        dataset, _config(dataset, gnss, rpy), method,
        gnss_mask=outage_mask(dataset, WINDOWS), progress=False,
    )  # fmt: skip
    expected, got = _rms(reference, drive, reference_dataset), _rms(turned, drive, dataset)
    assert got <= 1.05 * expected + 0.02, (expected, got)
    assert not turned.info.get("fit_warnings"), turned.info.get("fit_warnings")


def test_a_missing_mounting_is_flagged(drive):
    dataset, gnss = turned_imu(drive, (20.0, -10.0, 35.0))
    trajectory = run_method(
        dataset, _config(dataset, gnss, (0, 0, 0)), "batch",
        gnss_mask=outage_mask(dataset, WINDOWS), progress=False,
    )  # fmt: skip
    warnings = " ".join(trajectory.info.get("fit_warnings", []))
    assert "mounting" in warnings
