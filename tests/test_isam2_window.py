"""iSAM2's bounded window: older keyframes are marginalised out of the running iSAM2, the
final pass smooths the whole graph; the final result is the unbounded one's."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import gtsam
import numpy as np
import pandas as pd
import pytest
from gtsam.symbol_shorthand import X

from fgins.config import load_config
from fgins.graph import isam2
from fgins.graph.problem import build_problem
from fgins.sim.scenarios import SCENARIOS

sys.path.insert(0, str(Path(__file__).parent))


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


@pytest.mark.parametrize(("gnss_rate", "window"), [(1.0, (118.0, 178.0)), (0.2, (60.0, 110.0))])
def test_the_online_sigma_knows_nothing_of_the_fix_that_ends_an_outage(tmp_path, gnss_rate, window):
    """The online estimate is causal: between keyframes its sigma grows with the prediction
    and never falls before the fix that ends an outage. It was interpolated towards the next
    keyframe's, which has that fix in it: over the outage's last second the sigma fell 2-14x
    while the position was still dead-reckoned, 27-586 m off at z 5-22 (outside tester)."""
    from independent_sim import FIVE_TURNS, INDUSTRIAL, CarProfile, horizontal_errors, write_drive

    import fgins

    profile = CarProfile(steps=[(10, 8, 12.0)], turns=FIVE_TURNS, gamma=lambda t: 0 * t)
    write_drive(tmp_path, profile, 200.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                gnss_rate=gnss_rate, seed=4)  # fmt: skip
    online = fgins.smooth(fgins.load(tmp_path), "isam2", online=True, gnss_outage=[window])
    frame = online.to_dataframe()
    t = frame["time"].to_numpy()
    sigma = np.hypot(frame["std_east"], frame["std_north"]).to_numpy()
    fixes = pd.read_csv(tmp_path / "gnss.csv")["time"].to_numpy()
    end = float(fixes[fixes >= window[1]][0])  # the fix that ends the outage
    last = (t > end - 2.0) & (t < end)  # its last keyframe interval(s) before that fix
    assert np.all(np.diff(sigma[last]) >= -1e-9), np.diff(sigma[last]).min()
    _, error = horizontal_errors(online, tmp_path)
    before = np.flatnonzero(t < end)[-1]
    assert error[before] < 3.0 * sigma[before], (error[before], sigma[before])
