"""Monte-Carlo consistency of the factor graph's covariances (slow): NEES against truth."""

from __future__ import annotations

import numpy as np
import pytest

from fgins.config import config_for_dataset
from fgins.graph.smoother import smooth
from fgins.outages import outage_mask
from fgins.sim.scenarios import SCENARIOS


def _nees_per_dof(error: np.ndarray, covariance: np.ndarray) -> float:
    return float(np.mean(np.einsum("ni,nij,nj->n", error, np.linalg.inv(covariance), error)) / 3)


@pytest.mark.slow
@pytest.mark.parametrize("method", ["batch", "isam2"])
@pytest.mark.parametrize("scenario", ["highway", "car-urban"])
def test_position_and_velocity_nees_is_consistent(scenario, method):
    """Average NEES per degree of freedom over 20 runs, each with a 30 s outage, lies in
    [0.5, 2]: the reported uncertainty is neither optimistic nor uselessly pessimistic."""
    position, velocity = [], []
    for seed in range(20):
        run = SCENARIOS[scenario](seed=200 + seed, duration_s=150)
        dataset = run.dataset
        trajectory = smooth(
            dataset, config_for_dataset(dataset), method,
            gnss_mask=outage_mask(dataset, [(60.0, 90.0)]), progress=False,
        )  # fmt: skip
        rows = slice(None, None, 50)
        truth_velocity = np.column_stack(
            [np.interp(trajectory.t, run.truth.t, run.truth.velocity[:, i]) for i in range(3)]
        )
        position.append(
            _nees_per_dof(
                (trajectory.position - run.truth.at(trajectory.t))[rows],
                trajectory.position_cov[rows],
            )
        )
        velocity.append(
            _nees_per_dof(
                (trajectory.velocity - truth_velocity)[rows], trajectory.velocity_cov[rows]
            )
        )
    assert 0.5 <= np.mean(position) <= 2.0, position
    assert 0.5 <= np.mean(velocity) <= 2.0, velocity
