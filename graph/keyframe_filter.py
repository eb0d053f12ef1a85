"""The batch smoother's initial guess: an extended Kalman filter over the graph's own factors.

A filter is the right initialiser for a batch smoother: it corrects attitude and biases as it
goes and bridges outages with its own dead reckoning. This one runs keyframe by keyframe on
exactly the factors the smoother will optimise (the preintegrated IMU factor, GNSS, the
land-vehicle constraints, barometer, odometer), so it matches the input by construction:

- predict: GTSAM's preintegration of the interval (C++), made about the filter's newest
  bias estimate, which is also the preintegration the smoother starts from (GTSAM's
  first-order bias correction stays small from the start);
- update: the keyframe's factors linearised at the prediction (GNSS position Huber-weighted:
  a gross outlier cannot drag the guess far), solved together with the previous keyframe's
  Gaussian, which is then marginalised out (square-root information, by QR); an iterated
  update where the attitude correction is large (the first fixes after an outage).

Cost: one small dense QR per keyframe (about 30 columns), no per-IMU-sample work beyond the
preintegration itself. The 15-state error-state EKF at IMU rate it replaces as the guess cost
4-5x as much (issue 9) and did not see the graph's own models.
"""

from __future__ import annotations

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X

from fgins.datatypes import FginsError
from fgins.factors.values import put_bias, put_pose, put_vector
from fgins.graph.problem import Problem
from fgins.initial_guess import guess_config

# Iterate a keyframe's update (relinearise at the corrected state) while its attitude
# correction exceeds this; at most MAX_UPDATE_ITERATIONS linearisations per keyframe.
ITERATE_ATTITUDE_RAD = 2e-3
MAX_UPDATE_ITERATIONS = 3


def keyframe_filter(problem: Problem, progress: bool = False) -> gtsam.Values:
    """Filtered states at every keyframe (the smoother's initial values), each interval
    preintegrated about the filtered bias at its start. Raises FginsError when the filter
    cannot go on (a non-finite or singular update)."""
    from tqdm import tqdm  # imported on use (import time)

    gnss_config = guess_config(problem.config).gnss
    constants = problem.shared_keys
    out = gtsam.Values()
    carried = gtsam.Values()  # the filter's current mean: keyframe k's states and constants
    carried_keys: list[int] = []
    root = np.zeros((0, 0))  # upper-triangular square-root information about ``carried``
    problem.zupt_keyframes.clear()
    for k in tqdm(
        range(problem.n_keyframes), desc="initial guess", unit="kf", disable=not progress,
        leave=False,
    ):  # fmt: skip
        point = _prediction(problem, k, carried)
        if k > 0:  # the plane fall where the prediction is (not on the fixes' chord)
            problem.set_baro_fall(np.array([k]), point.atPose3(X(k)).translation()[None])
        factors = problem.prior_factors() if k == 0 else gtsam.NonlinearFactorGraph()
        speed = float(np.linalg.norm(point.atVector(V(k))))
        factors.push_back(problem.keyframe_factors(k, speed, gnss_config=gnss_config))
        linearisation = gtsam.Values(carried)
        linearisation.insert(point)
        factors.push_back(problem.linear_factors(linearisation, np.array([k])))
        new_keys = [int(key) for key in point.keys()]
        kept = new_keys + [key for key in carried_keys if key in constants]
        dropped = [key for key in carried_keys if key not in constants]
        for iteration in range(MAX_UPDATE_ITERATIONS):
            delta, root_kept = _update(factors, linearisation, carried_keys, root, dropped, kept, k)
            if iteration == MAX_UPDATE_ITERATIONS - 1:
                break
            if np.max(np.abs(delta.at(X(k))[:3])) <= ITERATE_ATTITUDE_RAD:
                break
            # Relinearise at the corrected keyframe-k states; the constants stay at their
            # mean, so the previous keyframe's Gaussian keeps a zero right-hand side.
            linearisation = linearisation.retract(_only(delta, carried_keys + new_keys, new_keys))
        estimate = linearisation.retract(delta)
        for key in dropped:
            estimate.erase(key)
        out.insert(_without(estimate, constants))
        carried, carried_keys, root = estimate, kept, root_kept
    out.insert(_without(carried, set(carried_keys) - constants))
    problem.zupt_keyframes.clear()
    return out


def _prediction(problem: Problem, k: int, carried: gtsam.Values) -> gtsam.Values:
    """Keyframe k's predicted states: the alignment at k = 0, else the preintegrated IMU
    from keyframe k-1's estimate (interval k-1 preintegrated about its bias, now)."""
    point = gtsam.Values()
    if k == 0:
        align = problem.alignment
        pose = gtsam.Pose3(gtsam.Rot3(align.rotation), align.position)
        velocity = np.asarray(align.velocity, dtype=float)
        bias = gtsam.imuBias.ConstantBias()
    else:
        bias = carried.atConstantBias(B(k - 1))
        problem.preintegrate(k - 1, bias)
        state = gtsam.NavState(carried.atPose3(X(k - 1)), carried.atVector(V(k - 1)))
        state = problem.predict(k - 1, state, bias)
        pose, velocity = state.pose(), state.velocity()
    put_pose(point, X(k), pose)
    put_vector(point, V(k), velocity)
    put_bias(point, B(k), bias)
    problem.insert_extra_values(k, point, carried if k > 0 else None)
    return point


def _update(
    factors: gtsam.NonlinearFactorGraph,
    linearisation: gtsam.Values,
    carried_keys: list[int],
    root: np.ndarray,
    dropped: list[int],
    kept: list[int],
    k: int,
) -> tuple[gtsam.VectorValues, np.ndarray]:
    """One linearised update: (the correction of the kept keys, their new square-root
    information about the corrected mean). ``dropped`` keys are marginalised out."""
    linear = factors.linearize(linearisation)
    columns = dropped + kept
    dims = _dims(linearisation, columns)
    where: dict[int, tuple[int, int]] = {}
    n = 0
    for key in columns:  # each key's column span
        where[key] = (n, n + dims[key])
        n += dims[key]
    in_graph = set(linear.keyVector())
    present = [key for key in columns if key in in_graph]
    ordering = gtsam.Ordering()
    for key in present:
        ordering.push_back(key)
    jacobian, rhs = linear.jacobian(ordering)
    rows = [np.zeros((jacobian.shape[0], n + 1))]
    column = 0
    for key in present:
        a, b = where[key]
        rows[0][:, a:b] = jacobian[:, column : column + (b - a)]
        column += b - a
    rows[0][:, n] = rhs
    if root.size:  # the previous keyframe's Gaussian, zero right-hand side at its mean
        prior = np.zeros((root.shape[0], n + 1))
        start = 0
        for key in carried_keys:
            a, b = where[key]
            prior[:, a:b] = root[:, start : start + (b - a)]
            start += b - a
        rows.append(prior)
    stacked = np.vstack(rows)
    if not np.all(np.isfinite(stacked)):
        raise FginsError(f"the initial-guess filter failed at keyframe {k}: non-finite update")
    if stacked.shape[0] < n:
        raise FginsError(f"the initial-guess filter failed at keyframe {k}: too few constraints")
    # R of the QR factorisation: the upper triangle of the (transposed) Householder array
    # that "raw" mode returns, at half the cost of mode="r" on these small matrices.
    triangular = np.triu(np.linalg.qr(stacked, mode="raw")[0].T[: n + 1])
    m = int(sum(dims[key] for key in dropped))
    root_kept = triangular[m:n, m:n]
    diagonal = np.abs(root_kept.diagonal())
    if not diagonal.min() > 1e-12 * max(diagonal.max(), 1.0):
        raise FginsError(f"the initial-guess filter failed at keyframe {k}: singular update")
    solution = np.linalg.solve(root_kept, triangular[m:n, n])  # ~30 x 30: no scipy import
    delta = gtsam.VectorValues()
    for key in dropped:  # marginalised at their mean: not moved
        delta.insert(key, np.zeros(dims[key]))
    for key in kept:
        a, b = where[key]
        delta.insert(key, solution[a - m : b - m])
    return delta, root_kept


def _only(delta: gtsam.VectorValues, keys: list[int], chosen: list[int]) -> gtsam.VectorValues:
    """``delta`` over ``keys``, zero but at the ``chosen`` ones."""
    out = gtsam.VectorValues()
    chosen = set(chosen)
    for key in keys:
        vector = delta.at(key)
        out.insert(key, vector if key in chosen else np.zeros_like(vector))
    return out


def _without(values: gtsam.Values, keys: set[int]) -> gtsam.Values:
    out = gtsam.Values(values)
    for key in keys:
        if out.exists(key):
            out.erase(key)
    return out


def _dims(values: gtsam.Values, keys: list[int]) -> dict[int, int]:
    zero = values.zeroVectors()
    return {key: len(zero.at(key)) for key in keys}
