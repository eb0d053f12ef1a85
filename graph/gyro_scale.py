"""The gyro's scale factors, estimated with the whole solution (the batch's last step).

A MEMS gyro's scale factor is off by 0.1-3 % (datasheets: consumer 1-3 %, industrial
0.1-0.5 %), and GTSAM's IMU factors carry no scale state: every turn then leaves the heading
off by that fraction of the turn. With GNSS the fixes hide it in the fit; inside an outage it
shows, and nothing said so (independent simulator, car, industrial IMU, five turns: a gyro
1 % large took the batch from 0.43 m to 0.71 m inside two outages, errors 1.5 times the
sigmas it reported; 3 % large: 1.37 m, 2.9 times).

Over one keyframe interval a scale error ``s`` (per axis) reads like a bias of ``s`` times
the interval's mean rate, so its effect on the IMU factor's whitened error is the factor's
bias Jacobian times ``diag(mean rate)``. At the solution (where the gradient in every state
vanishes) the scale's Gauss-Newton estimate, with all states free to move with it, is the
Schur complement of the linearised graph: information ``J'J - U' S U`` and gradient
``J'r - U' S A'r``, with ``U = A'J`` and ``S = (A'A)^-1``, applied to a few columns by one
elimination and back-substitution (``S = R^-1 R^-T``): O(K), no Python callback in a solve.
A weak prior (:data:`SCALE_PRIOR`) keeps an axis that never turns at zero. An axis whose
estimate is both significant and above the floor is corrected: the gyro's samples are
rescaled, every interval re-preintegrated and the solve repeated from its solution (a turn
the size of the error was linear enough to need one round; at most :data:`MAX_ROUNDS`).
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B

from fgins.graph.problem import Problem
from fgins.graph.solve import SolveReport, is_suspect, solve_from, solve_with_stops

SCALE_PRIOR = 0.05  # 1-sigma of a scale error before the data (5 %: beyond any MEMS gyro)
# An axis's scale error is corrected when it is at least this large and this many sigmas.
MIN_SCALE_ERROR = 0.002
MIN_SCALE_SIGMAS = 5.0
MAX_ROUNDS = 3
_BIAS_GYRO = slice(3, 6)  # ConstantBias's vector: accelerometer, then gyro
_WALK_ROWS = slice(9, 15)  # CombinedImuFactor's error: rotation, position, velocity, bias walk


@dataclass(frozen=True)
class ScaleEstimate:
    """Per-axis gyro scale error (read rate over true rate, less 1) and its 1-sigma."""

    error: np.ndarray
    sigma: np.ndarray

    @property
    def significant(self) -> np.ndarray:
        size = np.abs(self.error)
        return (size >= MIN_SCALE_ERROR) & (size >= MIN_SCALE_SIGMAS * self.sigma)


def interval_mean_rates(problem: Problem) -> np.ndarray:
    """(K-1, 3) mean gyro reading over each keyframe interval (time-weighted)."""
    segments = problem.segments
    gyro = problem.dataset.imu.gyro[segments.sample] * segments.dt[:, None]
    sums = np.add.reduceat(gyro, segments.bounds[:-1], axis=0)
    span = np.add.reduceat(segments.dt, segments.bounds[:-1])
    empty = segments.bounds[1:] == segments.bounds[:-1]
    sums[empty] = 0.0
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(span[:, None] > 0, sums / span[:, None], 0.0)


def estimate_gyro_scale(
    problem: Problem, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values
) -> ScaleEstimate | None:
    """The per-axis scale error the solution ``values`` of ``graph`` points to (see the
    module docstring), about the scale the problem's samples already carry; None when the
    graph has no IMU factor or its linearisation cannot be eliminated."""
    linear = graph.linearize(values)
    gradient = linear.gradientAtZero()  # -A'b, over every variable
    # keyVector, a list: iterating the KeySet that keys() returns read freed memory.
    all_keys = [int(key) for key in linear.keyVector()]
    dims = {key: gradient.at(key).shape[0] for key in all_keys}
    rates = interval_mean_rates(problem)
    first_bias = {int(B(i)): i for i in range(problem.n_keyframes - 1)}
    jtj = np.zeros((3, 3))
    jtr = np.zeros(3)
    u: dict[int, np.ndarray] = {}
    found = 0
    for index in range(graph.size()):
        if not graph.exists(index) or not isinstance(graph.at(index), gtsam.CombinedImuFactor):
            continue
        factor = linear.at(index)
        keys = list(factor.keys())
        matrix, rhs = factor.jacobian()  # whitened [A_1 ... A_n], b (error = A dx - b)
        offsets = np.concatenate([[0], np.cumsum([dims[key] for key in keys])])
        interval = first_bias[keys[4]]  # keys: X(i), V(i), X(j), V(j), B(i), B(j)
        bias_cols = offsets[4] + np.arange(6)[_BIAS_GYRO]
        # The bias Jacobian less its random-walk rows (a scale error does not move the bias
        # from one keyframe to the next): un-whiten, drop them, whiten again.
        root = graph.at(index).noiseModel().R()
        plain = np.linalg.solve(root, matrix[:, bias_cols])
        plain[_WALK_ROWS] = 0.0
        jacobian = (root @ plain) * rates[interval][None, :]  # (rows, 3)
        jtj += jacobian.T @ jacobian
        jtr += jacobian.T @ rhs
        for position, key in enumerate(keys):
            block = matrix[:, offsets[position] : offsets[position + 1]].T @ jacobian
            u[key] = u[key] + block if key in u else block
        found += 1
    if not found:
        return None
    # QR, as the solves: tight bias random walks make the normal equations lose every digit
    # (Cholesky then reports an indeterminant system).
    try:
        bayes_net = linear.eliminateSequential(
            gtsam.Ordering.OrderingType.COLAMD, gtsam.EliminateQR
        )
    except RuntimeError:
        return None

    def back_transposed(column: dict[int, np.ndarray] | gtsam.VectorValues) -> gtsam.VectorValues:
        vector = gtsam.VectorValues()
        for key in all_keys:
            if isinstance(column, gtsam.VectorValues):
                vector.insert(key, -column.at(key))
            else:
                vector.insert(key, column.get(key, np.zeros(dims[key])))
        return bayes_net.backSubstituteTranspose(vector)

    w = [back_transposed({key: block[:, c] for key, block in u.items()}) for c in range(3)]
    w_r = back_transposed(gradient)
    schur = np.array([[w[a].dot(w[b]) for b in range(3)] for a in range(3)])
    information = jtj - schur + np.eye(3) / SCALE_PRIOR**2
    rhs = jtr - np.array([w[a].dot(w_r) for a in range(3)])
    covariance = np.linalg.inv(information)
    step = covariance @ rhs
    return ScaleEstimate(error=step, sigma=np.sqrt(np.diag(covariance)))


def correct_gyro_scale(
    problem: Problem, report: SolveReport, result: gtsam.Values, graph: gtsam.NonlinearFactorGraph
) -> tuple[gtsam.Values, gtsam.NonlinearFactorGraph, dict[str, object]]:
    """The batch's solution with the gyro's significant scale errors corrected (see the
    module docstring): ``result`` and ``graph`` themselves when there are none. ``report``
    takes the extra solves' counts and errors; the info dict says what was found."""
    if not problem.config.smoother.estimate_gyro_scale or problem.dataset.accel_array is not None:
        return result, graph, {}
    estimate = estimate_gyro_scale(problem, graph, result)
    if estimate is None:
        return result, graph, {}
    axes = estimate.significant
    total = np.ones(3)
    for _ in range(MAX_ROUNDS if axes.any() else 0):
        factor = 1.0 + np.where(axes, estimate.error, 0.0)
        before = (problem.dataset, list(problem.pims), problem.pim_bias.copy(),
                  set(problem.zupt_keyframes))  # fmt: skip
        problem.rescale_gyro(factor, result)
        again, corrected, corrected_graph = solve_with_stops(problem, *solve_from(problem, result))
        if is_suspect(again):  # the corrected gyro does not fit: keep the solution before
            problem.dataset, problem.pims, problem.pim_bias, problem.zupt_keyframes = before
            break
        total = total * factor
        result, graph = corrected, corrected_graph
        report.iterations += again.iterations
        report.rounds += again.rounds
        report.repreintegrated += again.repreintegrated + problem.n_keyframes - 1
        report.final_error, report.dof, report.blame = again.final_error, again.dof, again.blame
        report.converged = again.converged
        latest = estimate_gyro_scale(problem, graph, result)
        if latest is None:  # the graph lost its IMU factors: cannot happen
            break
        estimate = latest
        if np.all(np.abs(estimate.error[axes]) <= estimate.sigma[axes]):
            break
    corrected_axes = axes & (total != 1.0)
    return (
        result,
        graph,
        _info(total * (1.0 + estimate.error) - 1.0, estimate.sigma, corrected_axes),
    )


def _info(error: np.ndarray, sigma: np.ndarray, axes: np.ndarray) -> dict[str, object]:
    """The run summary's entries: the estimate, and a warning naming what was corrected."""
    info: dict[str, object] = {
        "gyro_scale_error": error.tolist(),
        "gyro_scale_sigma": sigma.tolist(),
        "gyro_scale_corrected": axes.tolist(),
    }
    if axes.any():
        found = ", ".join(
            f"{axis} {100 * error[a]:+.2f} % +- {100 * sigma[a]:.2f}"
            for a, axis in enumerate("xyz")
            if axes[a]
        )
        info["fit_warnings"] = [
            f"imu: the gyro reads turns larger or smaller than the solution shows (scale "
            f"error {found}): corrected in the smoother (the Kalman baselines do not model "
            "it); [smoother] estimate_gyro_scale = false turns this off"
        ]
    return info
