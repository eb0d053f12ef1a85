"""GNSS velocity of an antenna off the IMU: v + R (w x l) (the simulator's and the EKF's
model), in the graph as a linearised factor. Checked against finite differences of the
closed form and, end to end, against simulator truth with a tall lever arm."""

from __future__ import annotations

from dataclasses import replace

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import B, V, X

import fgins.graph.problem as problem_module
from fgins.config import load_config
from fgins.factors.gnss import antenna_velocity, antenna_velocity_factors
from fgins.geodesy import enu_to_lla
from fgins.graph.smoother import smooth
from fgins.sim.scenarios import SCENARIOS


def _values(rotation: gtsam.Rot3, velocity: np.ndarray, bias: np.ndarray) -> gtsam.Values:
    values = gtsam.Values()
    values.insert(X(0), gtsam.Pose3(rotation, np.array([1.0, 2.0, 3.0])))
    values.insert(V(0), velocity)
    values.insert(B(0), gtsam.imuBias.ConstantBias(bias[:3], bias[3:]))
    return values


@pytest.mark.parametrize("seed", range(4))
def test_linearised_factor_matches_the_closed_form_to_second_order(seed):
    """Moved off its linearisation point by a small step, the factor's error is the exact
    whitened error of v + R (w x l) to second order (so its Jacobians are right)."""
    rng = np.random.default_rng(seed)
    rotation = gtsam.Rot3.Expmap(rng.normal(size=3))
    velocity = rng.normal(scale=10.0, size=3)
    bias = rng.normal(scale=0.05, size=6)
    gyro, lever = rng.normal(scale=0.5, size=3), rng.normal(scale=1.5, size=3)
    measured = rng.normal(scale=10.0, size=3)
    sigma = np.array([0.1, 0.2, 0.3])
    point = _values(rotation, velocity, bias)
    (factor,) = antenna_velocity_factors(
        np.array([X(0)]), np.array([V(0)]), np.array([B(0)]), rotation.matrix()[None],
        velocity[None], gyro[None], bias[3:][None], lever, measured[None], sigma[None], point,
    )  # fmt: skip
    for scale in (1e-3, 1e-4):
        step = rng.normal(size=15) * scale
        moved = gtsam.Values()
        moved.insert(X(0), point.atPose3(X(0)).retract(step[:6]))
        moved.insert(V(0), velocity + step[6:9])
        moved.insert(B(0), point.atConstantBias(B(0)).retract(step[9:]))
        r = moved.atPose3(X(0)).rotation().matrix()
        b_g = moved.atConstantBias(B(0)).gyroscope()
        exact_residual = (antenna_velocity(r, moved.atVector(V(0)), gyro - b_g, lever) - measured)
        exact = 0.5 * np.sum((exact_residual / sigma) ** 2)
        linear = factor.error(moved)
        # Both are smooth in the step: they agree to O(step^2) of the O(1) residual.
        assert abs(linear - exact) < 50 * scale**2 * (1 + exact)


def _tall_antenna_drive(lever: np.ndarray, velocity_sigma: float, seed: int):
    """car-urban with GNSS made anew from the truth for an antenna ``lever`` (IMU axes) away:
    positions +- 0.5 m, velocities +- ``velocity_sigma``, each the antenna's."""
    run = SCENARIOS["car-urban"](seed=seed, duration_s=120)
    dataset, truth = run.dataset, run.truth
    rng = np.random.default_rng(100 + seed)
    gnss_t = dataset.gnss.t
    rows = np.clip(np.searchsorted(truth.t, gnss_t), 0, len(truth.t) - 1)
    rotation = truth.rotation[rows]
    # Body rate from the IMU without its biases (Earth rate x 2.5 m is 0.2 mm/s: left out).
    imu_rows = np.clip(np.searchsorted(dataset.imu.t, gnss_t), 0, len(dataset.imu.t) - 1)
    body_rate = dataset.imu.gyro[imu_rows] - truth.gyro_bias[rows]
    antenna = truth.position[rows] + rotation @ lever
    antenna_v = truth.velocity[rows] + np.einsum("nij,nj->ni", rotation, np.cross(body_rate, lever))
    gnss = replace(
        dataset.gnss,
        lla=enu_to_lla(antenna + rng.normal(scale=0.5, size=antenna.shape), dataset.origin),
        velocity=antenna_v + rng.normal(scale=velocity_sigma, size=antenna_v.shape),
        std=np.full(antenna.shape, 0.5),
        velocity_std=np.full(antenna.shape, velocity_sigma),
    )
    gnss.__post_init__()
    gnss_config = {
        **dataset.gnss_config, "lever_arm_m": list(lever), "sigma_m": [0.5, 0.5, 0.5],
        "velocity_sigma_m_per_s": velocity_sigma, "use_velocity": True,
    }  # fmt: skip
    return replace(dataset, gnss=gnss), truth, gnss_config


@pytest.mark.parametrize("seed", [0, 1])
def test_a_tall_antenna_velocity_is_modelled_not_absorbed(monkeypatch, seed):
    """An antenna 2 m ahead of, 1 m left of and 2.5 m above the IMU of a turning car: its
    Doppler velocity carries R (w x l), 0.2 m/s RMS and up to 0.9 m/s in the turns (4x the
    velocity sigma). Modelled, the smoothed velocity is much better than without the term
    (a plain prior on V, forced here for the comparison) and near the noise level."""
    lever = np.array([2.0, 1.0, 2.5])
    dataset, truth, gnss_config = _tall_antenna_drive(lever, 0.05, seed)
    config = load_config(dataset_imu=dataset.imu_config, dataset_gnss=gnss_config)
    config.smoother.vehicle = "other"  # the velocity factor alone, no car constraints

    def velocity_rms(trajectory) -> float:
        rows = np.clip(np.searchsorted(truth.t, trajectory.t), 0, len(truth.t) - 1)
        return float(np.sqrt(np.mean(np.sum((trajectory.velocity - truth.velocity[rows]) ** 2, 1))))

    modelled = velocity_rms(smooth(dataset, config, "batch", progress=False))
    monkeypatch.setattr(problem_module.Problem, "has_antenna_velocity", property(lambda self: False))
    plain = velocity_rms(smooth(dataset, config, "batch", progress=False))
    assert modelled < 0.7 * plain, (modelled, plain)
    assert modelled < 0.06, modelled
