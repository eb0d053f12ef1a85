"""The batch smoother's initial guess, the keyframe EKF over the graph's own factors.

Against independent references: simulator truth (it must be as good a filter as the
IMU-rate 15-state EKF baseline) and the batch smoother of the same graph (at the last
keyframe a filter and a smoother carry the same information, so they must agree within the
smoother's own uncertainty). Cars, an aircraft, a UAV with a barometer and an FRD IMU
turned in its car.
"""

from __future__ import annotations

import numpy as np
import pytest
from gtsam.symbol_shorthand import B, V, X

from fgins.config import config_for_dataset, load_config
from fgins.graph import start
from fgins.graph.keyframe_filter import keyframe_filter
from fgins.graph.problem import build_problem
from fgins.graph.solution import marginal_function
from fgins.graph.solve import solve_from
from fgins.pipeline import run_method
from fgins.sim.scenarios import SCENARIOS
from fgins.tests.drive_fixtures import turned_imu

CASES = [
    ("highway", 1, None),
    ("car-urban", 2, None),
    ("aircraft-ekf", 3, None),
    ("uav-loop-baro", 5, None),
    ("car-urban", 6, (180.0, 0.0, -90.0)),  # FRD, turned by -90 deg in yaw
]


def _case(name: str, seed: int, rpy):
    run = SCENARIOS[name](seed=seed, duration_s=120)
    dataset = run.dataset
    config = config_for_dataset(dataset)
    if rpy is not None:
        dataset, gnss = turned_imu(run, rpy)
        config = load_config(dataset_imu=dataset.imu_config, dataset_gnss=gnss)
        config.smoother.vehicle = "car"
        config.smoother.imu_to_vehicle_rpy_deg = rpy
    return run, dataset, config


def _horizontal_rms(estimate: np.ndarray, truth: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.sum((estimate - truth)[:, :2] ** 2, axis=1))))


@pytest.mark.parametrize(("name", "seed", "rpy"), CASES)
def test_keyframe_filter_is_a_good_filter_and_ends_where_the_smoother_ends(name, seed, rpy):
    run, dataset, config = _case(name, seed, rpy)
    problem = build_problem(dataset, config, progress=False)
    filtered = keyframe_filter(problem)
    times = problem.segments.times
    last = problem.n_keyframes - 1
    truth = run.truth.position[np.clip(np.searchsorted(run.truth.t, times), 0, len(run.truth.t) - 1)]
    position = np.array([filtered.atPose3(X(k)).translation() for k in range(last + 1)])

    # (1) A filter as good as the 15-state EKF at IMU rate on the same data (truth).
    ekf = run_method(dataset, config, "ekf", progress=False)
    assert _horizontal_rms(position, truth) <= 1.1 * _horizontal_rms(ekf.at(times), truth)

    # (2) Every interval was preintegrated about the filter's bias at its start.
    for i in (0, last // 2, last - 1):
        used = problem.pims[i].biasHat()
        estimate = filtered.atConstantBias(B(i))
        assert np.allclose(used.vector(), estimate.vector(), atol=1e-12)

    # (3) At the last keyframe the filter and the smoother of the same graph agree within
    # three of the smoother's sigmas (a filter's last state is the smoother's, up to the
    # linearisation points).
    report, result, graph = solve_from(problem, filtered)
    assert report.converged
    marginal = marginal_function(graph, result)
    position_sigma = np.sqrt(np.diag(marginal(X(last))[3:, 3:]))
    velocity_sigma = np.sqrt(np.diag(marginal(V(last))))
    smoothed = result.atPose3(X(last))
    body_error = smoothed.rotation().matrix().T @ (
        filtered.atPose3(X(last)).translation() - smoothed.translation()
    )  # Pose3's translation marginal is in body axes
    assert np.all(np.abs(body_error) < 3 * position_sigma + 0.01), (body_error, position_sigma)
    velocity_error = filtered.atVector(V(last)) - result.atVector(V(last))
    assert np.all(np.abs(velocity_error) < 3 * velocity_sigma + 0.01), (velocity_error, velocity_sigma)


def test_a_failed_guess_filter_falls_back_to_dead_reckoning_and_says_so(monkeypatch):
    from fgins.datatypes import FginsError

    def fail(problem, progress=False):
        raise FginsError("the initial-guess filter failed at keyframe 3: singular update")

    monkeypatch.setattr(start, "keyframe_filter", fail)
    run = SCENARIOS["highway"](seed=4, duration_s=60)
    config = config_for_dataset(run.dataset)
    batch = run_method(run.dataset, config, "batch", progress=False)
    assert batch.info["initial_guess"] == "dead reckoning"
    assert any("singular update" in w for w in batch.info.get("fit_warnings", []))
    # The same optimum from the other start (the fit does not depend on the guess here).
    monkeypatch.undo()
    filtered = run_method(run.dataset, config, "batch", progress=False)
    assert filtered.info["initial_guess"] == "keyframe EKF"
    np.testing.assert_allclose(batch.position, filtered.position, atol=0.02)


def test_each_keyframe_update_is_a_fixed_small_system(monkeypatch):
    """Linear cost by construction: every keyframe's update solves a dense system over the
    previous and the new keyframe's states only, whatever the drive's length."""
    from fgins.graph import keyframe_filter as module

    sizes: list[int] = []
    original = module._update

    def recording(factors, linearisation, carried_keys, root, dropped, kept, k):
        sizes.append(len(dropped) + len(kept))
        return original(factors, linearisation, carried_keys, root, dropped, kept, k)

    monkeypatch.setattr(module, "_update", recording)
    largest = []
    for duration in (40.0, 120.0):
        run = SCENARIOS["uav-loop-baro"](seed=1, duration_s=duration)  # with a baro bias state
        problem = build_problem(run.dataset, config_for_dataset(run.dataset), progress=False)
        sizes.clear()
        keyframe_filter(problem)
        assert len(sizes) >= problem.n_keyframes
        largest.append(max(sizes))
    # X, V, B and the barometer bias of two keyframes: 8 keys, on either drive.
    assert largest == [8, 8], largest
