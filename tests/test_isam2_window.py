"""iSAM2's bounded window: older keyframes are marginalised out of the running iSAM2, the
final pass smooths the whole graph; the final result is the unbounded one's."""

from __future__ import annotations

import math

import gtsam
import numpy as np
from gtsam.symbol_shorthand import X

from fgins.config import load_config
from fgins.graph import isam2
from fgins.graph.problem import build_problem
from fgins.sim.scenarios import SCENARIOS


def _run(run, window_s: float, monkeypatch):
    """(final positions, online positions, marginalisations, (final graph, final values)) of
    iSAM2 with this window."""
    calls = []
    marginalise = isam2._isam2_marginalize

    def counted(*args):
        calls.append(args[-1])
        marginalise(*args)

    monkeypatch.setattr(isam2, "ISAM2_WINDOW_S", window_s)
    monkeypatch.setattr(isam2, "_isam2_marginalize", counted)
    dataset = run.dataset
    config = load_config(dataset_imu=dataset.imu_config, dataset_gnss=dataset.gnss_config)
    problem = build_problem(dataset, config, progress=False)
    isam, final, online, *_ = isam2.run_isam2(problem, False)
    position = np.array([final.atPose3(X(k)).translation() for k in range(problem.n_keyframes)])
    graph = isam2.compact_graph(isam.getFactorsUnsafe())
    return position, online.position, len(calls), (graph, final)


def test_windowed_isam2_final_equals_the_unbounded_one(monkeypatch):
    run = SCENARIOS["highway"](seed=1, duration_s=120)
    final, online, marginalised, _ = _run(run, 20.0, monkeypatch)
    full_final, full_online, none, _ = _run(run, math.inf, monkeypatch)
    assert none == 0 and marginalised > 5
    assert np.max(np.linalg.norm(final - full_final, axis=1)) < 1e-3
    # The online (filtered) states differ only by the marginal's fixed linearisation.
    assert np.max(np.linalg.norm(online - full_online, axis=1)) < 0.05


def test_windowed_isam2_final_is_the_optimum_on_a_slow_loop(monkeypatch):
    """A slow loop (per-keyframe barometer bias too): the window's estimates of the old
    keyframes are far enough off that one final Gauss-Newton step is not the optimum."""
    run = SCENARIOS["uav-loop-baro"](seed=1, duration_s=120)
    final, _, marginalised, (graph, values) = _run(run, 20.0, monkeypatch)
    assert marginalised > 5
    optimum = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    assert graph.error(values) <= graph.error(optimum) * (1 + 1e-3)
    best = np.array([optimum.atPose3(X(k)).translation() for k in range(len(final))])
    assert np.max(np.linalg.norm(final - best, axis=1)) < 1e-3
