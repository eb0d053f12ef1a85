"""The structure that keeps smoothing cost linear in the drive length.

A ``gtsam.CustomFactor`` is evaluated by calling back into Python with a copy of the whole
``Values``: one linearisation would cost O(K) callbacks of O(K) each. These tests hold the
graphs to what makes the cost linear: no Python-callback factor at all, and a number of
factors per keyframe that does not grow with the number of keyframes.
"""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from fgins.config import load_config
from fgins.datatypes import GnssData, OdometerData
from fgins.graph.problem import build_problem
from fgins.graph.solve import callback_factors, full_graph, nonlinear_graph
from fgins.graph.start import initial_values
from fgins.sim.scenarios import SCENARIOS


def _car_problem(duration_s: float, wheel: bool):
    run = SCENARIOS["car-urban"](seed=1, duration_s=duration_s)
    dataset = run.dataset
    dataset.odometer = None
    if wheel:
        # A wheel-speed sensor reading the true forward speed 3 % high, at 10 Hz.
        t = run.truth.t[::10]
        body = np.einsum("kji,kj->ki", run.truth.rotation[::10], run.truth.velocity[::10])
        dataset.odometer = OdometerData(t=t, speed=1.03 * body[:, 0])
    config = load_config(dataset_imu=dataset.imu_config, dataset_gnss=dataset.gnss_config)
    config.smoother.vehicle = "car"
    problem = build_problem(dataset, config, progress=False)
    start, _ = initial_values(problem, None, progress=False)
    return problem, start.values


@pytest.mark.parametrize("wheel", [False, True])
def test_no_python_callback_factor_and_linear_factor_count(wheel):
    counts = []
    for duration in (40.0, 80.0):
        problem, values = _car_problem(duration, wheel)
        assert problem.has_odometer == wheel
        graph = full_graph(problem, nonlinear_graph(problem, None), values)
        assert callback_factors(graph) == 0
        assert not any(
            isinstance(graph.at(i), gtsam.CustomFactor) for i in range(graph.size())
        )
        counts.append((problem.n_keyframes, graph.size()))
    # Factors per keyframe are bounded by a constant (IMU, GNSS position and velocity, NHC,
    # odometer, a stop's two): a drive twice as long has twice the factors, not four times.
    for keyframes, factors in counts:
        assert factors <= 7 * keyframes + 5, counts


def test_vehicle_factors_are_linearised_and_exact_at_their_point():
    """The NHC enters as linear (C++) factors whose error at their own linearisation point is
    the exact nonlinear NHC error: the batch error at convergence is the true one."""
    from fgins.factors import vehicle
    from fgins.factors.gnss import antenna_velocity

    problem, values = _car_problem(40.0, wheel=False)
    linear = problem.linear_factors(values)
    # car-urban's antenna sits off the IMU: its GNSS velocities are linearised factors too.
    antenna_k = problem.antenna_velocity_keyframes
    assert len(antenna_k) > 20
    assert linear.size() == problem.n_keyframes + len(antenna_k)
    rotation = np.array([values.atPose3(gtsam.symbol("x", k)).rotation().matrix()
                         for k in range(problem.n_keyframes)])
    velocity = np.array([values.atVector(gtsam.symbol("v", k)) for k in range(problem.n_keyframes)])
    residual = vehicle.nhc_residuals(rotation, velocity, vehicle.nhc_rows(problem.imu_to_vehicle))
    exact = 0.5 * np.sum((residual / problem.nhc_sigma) ** 2)
    lever = np.asarray(problem.config.gnss.lever_arm_m, dtype=float)
    for k in antenna_k:
        measured, sigma = problem.gnss_velocity_at(int(k))
        gyro_bias = values.atConstantBias(gtsam.symbol("b", int(k))).gyroscope()
        rate = problem.gnss_gyro[problem.gnss_at[k]] - gyro_bias
        predicted = antenna_velocity(rotation[k], velocity[k], rate, lever)
        exact += 0.5 * np.sum(((predicted - measured) / sigma) ** 2)
    assert np.isclose(linear.error(values), exact, rtol=1e-9)


def test_odometer_scale_is_estimated_through_the_linearised_factors():
    """The odometer's scale-factor error (3 % here) comes out of the batch solve."""
    from fgins.graph.smoother import smooth_batch

    problem, _ = _car_problem(80.0, wheel=True)
    trajectory = smooth_batch(problem, progress=False)
    assert trajectory.info["python_callback_factors"] == 0
    assert abs(trajectory.info["odometer_scale_error"] - 0.03) < 0.01


def test_10hz_fixes_are_keyframes_and_car_constraints_stay_at_5hz():
    """Every 10 Hz fix becomes a keyframe, but the NHC and the wheel speed go in at most every
    0.2 s (``vehicle_constraint_interval_s``), the Kalman baselines' rule: their errors are
    correlated over seconds, so a denser GNSS must not multiply their weight."""
    run = SCENARIOS["car-urban"](seed=1, duration_s=40.0)
    dataset = run.dataset
    imu_t = dataset.imu.t
    # 10 Hz fixes between the IMU's samples (the 1 Hz fixes interpolated: only times matter).
    t = np.arange(imu_t[0] + 0.013, imu_t[-1], 0.1)
    gnss = dataset.gnss
    lla = np.column_stack([np.interp(t, gnss.t, gnss.lla[:, i]) for i in range(3)])
    dataset.gnss = GnssData(t=t, lla=lla, std=np.ones((len(t), 3)))
    dataset.odometer = OdometerData(t=imu_t[::10], speed=np.full(len(imu_t[::10]), 5.0))
    config = load_config(dataset_imu=dataset.imu_config, dataset_gnss=dataset.gnss_config)
    config.smoother.vehicle = "car"
    problem = build_problem(dataset, config, progress=False)
    assert problem.info["gnss_epochs_decimated"] == 0
    assert problem.info["gnss_epochs_used"] == len(t)
    constrained = problem.segments.times[problem.nhc_keyframes]
    assert np.min(np.diff(constrained)) >= 0.2 - 1e-9
    assert len(constrained) == pytest.approx(40.0 / 0.2, rel=0.05)
    wheel = np.flatnonzero(np.isfinite(problem.odometer_speed))
    assert set(wheel) <= set(problem.nhc_keyframes)
    assert problem.n_keyframes >= len(t)
