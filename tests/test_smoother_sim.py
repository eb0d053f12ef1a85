"""The smoother against simulator truth (known noise): recovery, outages vs 3 sigma, lever arm."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from fgins.config import load_config
from fgins.graph.smoother import smooth
from fgins.outages import in_windows, outage_mask
from fgins.sim.scenarios import SCENARIOS


def _horizontal_error(trajectory, truth):
    return np.linalg.norm(trajectory.position[:, :2] - truth.at(trajectory.t)[:, :2], axis=1)


@pytest.fixture(scope="module")
def highway():
    run = SCENARIOS["highway"](seed=3, duration_s=150)
    config = load_config(dataset_imu=run.dataset.imu_config, dataset_gnss=run.dataset.gnss_config)
    return run, config


def test_exact_imu_and_exact_gnss_recover_truth():
    """Error-free IMU and GNSS with tiny sigmas: the trajectory is recovered to centimetres."""
    run = SCENARIOS["car-urban"](seed=0, duration_s=60)
    dataset = run.dataset
    truth = run.truth
    # Replace the IMU by its error-free version and the fixes by the true antenna positions.
    exact = replace(
        dataset,
        imu=replace(
            dataset.imu,
            gyro=dataset.imu.gyro - truth.gyro_bias,
            accel=dataset.imu.accel - truth.accel_bias,
        ),
    )
    from fgins.geodesy import enu_to_lla

    lever = np.asarray(run.dataset.gnss_config.get("lever_arm_m", [0, 0, 0]), dtype=float)
    rows = np.searchsorted(truth.t, dataset.gnss.t)
    rows = np.clip(rows, 0, len(truth.t) - 1)
    antenna = truth.position[rows] + np.einsum("nij,j->ni", truth.rotation[rows], lever)
    exact.gnss = replace(dataset.gnss, lla=enu_to_lla(antenna, dataset.origin))
    exact.gnss.__post_init__()
    config = load_config(
        dataset_imu={
            **dataset.imu_config,
            "gyro_turn_on_bias_deg_per_s": 0.01,
            "accel_turn_on_bias_mg": 0.1,
        },
        dataset_gnss={**dataset.gnss_config, "sigma_m": [0.01, 0.01, 0.01], "uere_m": {}},
    )
    trajectory = smooth(exact, config, "batch", progress=False)
    assert np.sqrt(np.mean(_horizontal_error(trajectory, truth) ** 2)) < 0.03
    heading_error = np.abs(
        (trajectory.roll_pitch_heading_deg()[:, 2] - truth.roll_pitch_heading_deg()[:, 2] + 180)
        % 360
        - 180
    )
    assert np.median(heading_error) < 0.1


def test_noisy_gnss_is_smoothed_below_its_sigma(highway):
    run, config = highway
    trajectory = smooth(run.dataset, config, "batch", progress=False)
    gnss_error = np.linalg.norm(
        run.dataset.gnss_enu()[:, :2] - run.truth.at(run.dataset.gnss.t)[:, :2], axis=1
    )
    rms_gnss = np.sqrt(np.mean(gnss_error**2))
    rms_smoothed = np.sqrt(np.mean(_horizontal_error(trajectory, run.truth) ** 2))
    assert rms_smoothed < 0.5 * rms_gnss


@pytest.mark.parametrize("method", ["batch", "isam2"])
def test_outage_stays_within_reported_3_sigma(highway, method):
    run, config = highway
    windows = [(60.0, 90.0)]
    trajectory = smooth(
        run.dataset, config, method, gnss_mask=outage_mask(run.dataset, windows), progress=False
    )
    inside = in_windows(trajectory.t, run.dataset.t0, windows)
    error = trajectory.position[inside] - run.truth.at(trajectory.t[inside])
    std = trajectory.position_std[inside]
    # Per axis, the true error lies within 3 reported sigmas nearly everywhere in the outage.
    assert np.mean(np.all(np.abs(error) <= 3 * std, axis=1)) > 0.95
    # ... and the reported sigma is not absurdly pessimistic either.
    assert np.median(np.linalg.norm(std[:, :2], axis=1)) < 20 * max(
        np.median(np.linalg.norm(error[:, :2], axis=1)), 0.1
    )


def test_batch_recovers_when_the_start_heading_is_wrong_by_120_degrees():
    """A wrong configured heading makes the EKF initial guess diverge; the batch solver
    notices the inconsistent fit and restarts from iSAM2."""
    run = SCENARIOS["highway"](seed=102, duration_s=150)
    config = load_config(dataset_imu=run.dataset.imu_config, dataset_gnss=run.dataset.gnss_config)
    true_heading = run.truth.roll_pitch_heading_deg()[0, 2]
    config.smoother.initial_heading_deg = float(true_heading + 120.0)
    trajectory = smooth(
        run.dataset,
        config,
        "batch",
        gnss_mask=outage_mask(run.dataset, [(60.0, 90.0)]),
        progress=False,
    )
    assert np.sqrt(np.mean(_horizontal_error(trajectory, run.truth) ** 2)) < 2.0
