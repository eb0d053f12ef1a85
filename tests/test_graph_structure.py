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
from fgins.graph.problem import build_problem
from fgins.graph.smoother import _callback_factors, _full_graph, _nonlinear_graph, initial_values
from fgins.sim.scenarios import SCENARIOS


def _car_problem(duration_s: float, wheel: bool):
    run = SCENARIOS["car-urban"](seed=1, duration_s=duration_s)
    dataset = run.dataset
    if not wheel:
        dataset.odometer = None
    config = load_config(dataset_imu=dataset.imu_config, dataset_gnss=dataset.gnss_config)
    config.smoother.vehicle = "car"
    problem = build_problem(dataset, config, progress=False)
    values, _ = initial_values(problem, None, progress=False)
    return problem, values


@pytest.mark.parametrize("wheel", [False, True])
def test_no_python_callback_factor_and_linear_factor_count(wheel):
    counts = []
    for duration in (40.0, 80.0):
        problem, values = _car_problem(duration, wheel)
        if wheel and problem.dataset.odometer is None:
            pytest.skip("car-urban has no wheel speed")
        graph = _full_graph(problem, _nonlinear_graph(problem, None), values)
        assert _callback_factors(graph) == 0
        assert not any(
            isinstance(graph.at(i), gtsam.CustomFactor) for i in range(graph.size())
        )
        counts.append((problem.n_keyframes, graph.size()))
    (k1, f1), (k2, f2) = counts
    # Factors per keyframe: the same for a drive twice as long (a constant, not O(K)).
    assert abs(f2 / k2 - f1 / k1) < 0.5


def test_vehicle_factors_are_linearised_and_exact_at_their_point():
    """The NHC enters as linear (C++) factors whose error at their own linearisation point is
    the exact nonlinear NHC error: the batch error at convergence is the true one."""
    from fgins.factors import vehicle

    problem, values = _car_problem(40.0, wheel=False)
    linear = problem.linear_factors(values)
    assert linear.size() == problem.n_keyframes
    rotation = np.array([values.atPose3(gtsam.symbol("x", k)).rotation().matrix()
                         for k in range(problem.n_keyframes)])
    velocity = np.array([values.atVector(gtsam.symbol("v", k)) for k in range(problem.n_keyframes)])
    residual = vehicle.nhc_residuals(rotation, velocity, vehicle.nhc_rows(problem.imu_to_vehicle))
    exact = 0.5 * np.sum((residual / problem.nhc_sigma) ** 2)
    assert np.isclose(linear.error(values), exact, rtol=1e-9)
