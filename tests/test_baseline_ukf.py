"""Unscented Kalman filter baseline (fgins.baseline.ukf).

Independent references: closed-form moments of a linear map (the unscented transform is exact
there), the EKF on error-free data (both must agree to cm when the sigma points barely spread),
and simulator truth with known sensor noise (tracking and 3-sigma consistency).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from fgins.baseline.ekf import run_ekf
from fgins.baseline.ukf import UkfOptions, run_ukf, sigma_weights, unscented_transform
from fgins.config import RunConfig, imu_noise_from_config, load_config
from fgins.datatypes import InputError, Origin
from fgins.pipeline import run_method
from fgins.sim import motion
from fgins.sim.gnss import GnssModel
from fgins.sim.imu_errors import ImuErrorModel
from fgins.sim.scenarios import SCENARIOS, simulate_run


def _config(run, *, true_heading: bool = False) -> RunConfig:
    config = load_config(dataset_imu=run.dataset.imu_config, dataset_gnss=run.dataset.gnss_config)
    if true_heading:
        heading = float(run.truth.roll_pitch_heading_deg()[0, 2])
        config.smoother = replace(config.smoother, initial_heading_deg=heading)
    return config


@pytest.fixture(scope="module")
def mems_car():
    run = SCENARIOS["mems-car-pdop"](seed=0, duration_s=180)
    return run, _config(run, true_heading=True)


# --- the unscented transform -----------------------------------------------------------------


@pytest.mark.parametrize(("alpha", "kappa"), [(1.0, 0.0), (0.5, 0.0), (1e-3, 0.0), (1.0, 3.0)])
def test_weights_sum_to_one_and_the_transform_is_exact_for_a_linear_map(alpha, kappa):
    n = 15
    weights = sigma_weights(n, alpha, 2.0, kappa)
    assert len(weights.mean) == 2 * n + 1
    assert weights.mean.sum() == pytest.approx(1.0, abs=1e-9)
    # The covariance weights sum to 1 + (1 - alpha^2 + beta) by construction.
    assert weights.cov.sum() == pytest.approx(1.0 + 1.0 - alpha**2 + 2.0, abs=1e-9)
    rng = np.random.default_rng(1)
    a = rng.normal(size=(6, n))
    b = rng.normal(size=6)
    root = rng.normal(size=(n, n))
    cov = root @ root.T + 0.1 * np.eye(n)
    mean = rng.normal(size=n)
    y_mean, y_cov, cross = unscented_transform(lambda x: x @ a.T + b, mean, cov, weights)
    tolerance = 1e-8 if alpha > 0.1 else 1e-3  # alpha = 1e-3: weights of +-1e6 cancel
    np.testing.assert_allclose(y_mean, a @ mean + b, atol=tolerance)
    np.testing.assert_allclose(y_cov, a @ cov @ a.T, atol=tolerance * np.abs(a @ cov @ a.T).max())
    np.testing.assert_allclose(cross, cov @ a.T, atol=tolerance * np.abs(cov @ a.T).max())


def test_the_default_weights_are_non_negative_unlike_the_studys_kappa():
    default = UkfOptions()
    weights = sigma_weights(15, default.alpha, default.beta, default.kappa)
    assert np.all(weights.mean >= 0) and np.all(weights.cov >= 0)
    # The study's unscaled kappa = 3 - n: central weight kappa / (n + kappa) = -12 / 3 = -4.
    study = sigma_weights(15, 1.0, 0.0, 3.0 - 15)
    assert study.mean[0] == pytest.approx(-4.0)


def test_unscented_transform_captures_a_quadratic_mean():
    # y = x^2 with x ~ N(m, s^2): E[y] = m^2 + s^2 exactly (the EKF's linearisation says m^2).
    weights = sigma_weights(1, 1.0, 2.0, 2.0)
    y_mean, _, _ = unscented_transform(lambda x: x**2, np.array([1.5]), np.array([[0.04]]), weights)
    assert y_mean[0] == pytest.approx(1.5**2 + 0.04, rel=1e-12)


# --- the filter ------------------------------------------------------------------------------


def test_tracks_truth_on_the_mems_car(mems_car):
    run, config = mems_car
    trajectory = run_ukf(run.dataset, config, progress=False)
    np.testing.assert_array_equal(trajectory.t, run.dataset.imu.t)
    assert trajectory.method == "ukf"
    settled = trajectory.t > trajectory.t[0] + 20.0
    horizontal = np.linalg.norm((trajectory.position - run.truth.position)[settled, :2], axis=1)
    # GNSS: UERE 3 m x HDOP ~1.1 per axis at 2 Hz; the PDOP > 5 stretch (120-150 s) is gated
    # out (its fixes are biased by ~12 m), so it is an outage the consumer IMU must bridge.
    aided = trajectory.t[settled] < trajectory.t[0] + 120.0
    assert np.sqrt(np.mean(horizontal[aided] ** 2)) < 2.5
    assert horizontal.max() < 20.0
    gated = run.dataset.gnss.pdop > config.gnss.pdop_max
    assert gated.sum() > 50
    assert trajectory.info["gnss_updates"] == len(run.dataset.gnss) - gated.sum()


def test_stays_within_its_3_sigma(mems_car):
    run, config = mems_car
    trajectory = run_ukf(run.dataset, config, progress=False)
    settled = trajectory.t > trajectory.t[0] + 20.0
    z = np.abs(trajectory.position - run.truth.position)[settled] / trajectory.position_std[settled]
    assert np.all(np.isfinite(z))
    assert np.mean(np.all(z < 3.0, axis=1)) > 0.95
    velocity_std = np.sqrt(np.diagonal(trajectory.velocity_cov, axis1=1, axis2=2))[settled]
    velocity_error = np.abs(trajectory.velocity - run.truth.velocity)[settled]
    assert np.mean(velocity_error < 3 * velocity_std) > 0.95
    eigenvalues = np.linalg.eigvalsh(trajectory.position_cov)
    assert np.all(eigenvalues > 0)


def test_with_tiny_noise_it_agrees_with_the_ekf_to_cm():
    noise = imu_noise_from_config({"preset": "industrial-mems"})
    run = simulate_run(
        name="exact",
        seed=1,
        profile=motion.urban_car(100.0, 60.0),
        origin=Origin(48.1372, 11.5755, 520.0),
        imu_preset="industrial-mems",
        noise=noise,
        errors=ImuErrorModel(),
        gnss_model=GnssModel(
            rate_hz=1.0,
            sigma_m=(1e-3,) * 3,
            velocity_sigma_m_per_s=1e-3,
            lever_arm_m=(0.5, 0.2, 1.2),
        ),
    )
    config = _config(run)
    ukf = run_ukf(run.dataset, config, progress=False)
    ekf = run_ekf(run.dataset, config, progress=False)
    settled = ukf.t > ukf.t[0] + 20.0
    difference = np.linalg.norm(ukf.position - ekf.position, axis=1)[settled]
    assert difference.max() < 0.01
    truth_error = np.linalg.norm(ukf.position - run.truth.position, axis=1)[settled]
    assert truth_error.max() < 0.01


def test_pipeline_runs_the_ukf_with_an_outage_mask(mems_car):
    run, config = mems_car
    mask = np.ones(len(run.dataset.gnss), dtype=bool)
    mask[:40] = False  # the first 20 s (alignment still sees the start of the remaining fixes)
    trajectory = run_method(run.dataset, config, "ukf", gnss_mask=mask, progress=False)
    assert trajectory.method == "ukf"
    assert trajectory.info["gnss_epochs_used"] == int(
        (mask & ~(run.dataset.gnss.pdop > config.gnss.pdop_max)).sum()
    )
    assert {"filter", "total"} <= set(trajectory.timings)


def test_bad_input_and_options_are_input_errors(mems_car):
    run, config = mems_car
    with pytest.raises(InputError, match="no usable GNSS"):
        run_ukf(run.dataset, config, gnss_mask=np.zeros(len(run.dataset.gnss), bool))
    with pytest.raises(InputError, match="gnss_mask"):
        run_ukf(run.dataset, config, gnss_mask=np.ones(3, bool), progress=False)
    for bad in ({"alpha": 0.0}, {"alpha": 2.0}, {"max_block_s": 0.0}, {"kappa": -20.0}):
        with pytest.raises(InputError):
            UkfOptions(**bad)
