"""A few global parameters estimated with the whole solution, every state free.

The gyro's scale factors (:mod:`fgins.graph.gyro_scale`), the GNSS lever arm, time offset
and clock drift (:func:`fgins.graph.reports.lever_arm_report`) each add a column or a few to
some factors' rows of the linearised graph (the factor's whitened error as the parameter
moves). GTSAM's Python factors hold at most three keys, and an IMU factor has six, so the
columns are not put into the graph: at the solution (where the gradient in every state
vanishes) the parameters' Gauss-Newton step with all states free to move with them is the
Schur complement of the linearised graph, information ``C'C - U' S U`` and gradient ``C'b -
U' S A'b``, with ``U = A'C`` and ``S = (A'A)^-1``, applied to the few columns by one
elimination and back-substitution (``S = R^-1 R^-T``): O(K), no Python callback in a solve.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import gtsam
import numpy as np

from fgins.graph.problem import Problem

_WALK_ROWS = slice(9, 15)  # CombinedImuFactor's error: rotation, position, velocity, bias walk
# Its columns: X(i) 6, V(i) 3, X(j) 6, V(j) 3, then B(i) (accelerometer, gyro) and B(j).
_FIRST_BIAS_COLUMNS = slice(18, 24)


@dataclass(frozen=True)
class ParameterStep:
    """The parameters' Gauss-Newton step from where the columns were taken, and its
    covariance (the prior's information included)."""

    step: np.ndarray
    covariance: np.ndarray
    # The reduced normal equations the step solves (information @ step = rhs).
    information: np.ndarray
    rhs: np.ndarray
    # Asked for (parameter_step's ``sensitive``): each state's move with the parameters,
    # d(state)/d(parameters) (dim, p) per key, every other state free: what an error of the
    # parameters does to the solution (:func:`fgins.graph.gyro_scale.scale_spread`).
    sensitivity: dict[int, np.ndarray] | None = None

    @property
    def sigma(self) -> np.ndarray:
        variance = np.diag(self.covariance)
        # A negative variance is round-off of an ill-conditioned inverse: that parameter's
        # step is not known at all (infinite sigma, never significant), not known exactly.
        return np.sqrt(np.where(variance < 0, np.inf, variance))

    def held(self, index: list[int]) -> ParameterStep:
        """The step of the other parameters with those at ``index`` held where they are
        (conditioned on a zero step): what a step without them would have given, from the
        same elimination. None of the returned parameters is dropped: the held ones keep a
        zero step and zero variance."""
        free = np.setdiff1d(np.arange(len(self.step)), index)
        information = self.information[np.ix_(free, free)]
        covariance = np.zeros_like(self.covariance)
        covariance[np.ix_(free, free)] = np.linalg.inv(information)
        step = np.zeros_like(self.step)
        step[free] = covariance[np.ix_(free, free)] @ self.rhs[free]
        return ParameterStep(step=step, covariance=covariance, information=self.information, rhs=self.rhs)


def imu_bias_jacobians(
    graph: gtsam.NonlinearFactorGraph, linear: gtsam.GaussianFactorGraph
) -> Iterator[tuple[int, int, np.ndarray]]:
    """For each ``CombinedImuFactor`` of ``graph``: its index (in ``graph`` and in
    ``linear``, its linearisation), its interval i (from its first bias key B(i)) and the
    whitened Jacobian of its error in the interval's bias (accelerometer, then gyro), less
    the random-walk rows: an error in the samples (a scale, a clock rate) reads over one
    interval like a bias of its size there, but does not move the bias from one keyframe to
    the next."""
    for index in range(graph.size()):
        if not graph.exists(index) or not isinstance(graph.at(index), gtsam.CombinedImuFactor):
            continue
        factor = linear.at(index)
        keys = [int(key) for key in factor.keys()]  # X(i), V(i), X(j), V(j), B(i), B(j)
        matrix, _ = factor.jacobian()
        # Un-whiten, drop the walk rows, whiten again.
        root = graph.at(index).noiseModel().R()
        plain = np.linalg.solve(root, matrix[:, _FIRST_BIAS_COLUMNS])
        plain[_WALK_ROWS] = 0.0
        yield index, gtsam.Symbol(keys[4]).index(), root @ plain


def interval_spans(problem: Problem) -> np.ndarray:
    """(K-1,) the IMU time (s) each keyframe interval integrates (zero for an empty one)."""
    segments = problem.segments
    span = np.add.reduceat(segments.dt, segments.bounds[:-1])
    span[segments.bounds[1:] == segments.bounds[:-1]] = 0.0
    return span


def interval_mean(problem: Problem, samples: np.ndarray) -> np.ndarray:
    """(K-1, n) the time-weighted mean of the IMU's ``samples`` (N, n) over each keyframe
    interval (zero over an empty one)."""
    segments = problem.segments
    weighted = samples[segments.sample] * segments.dt[:, None]
    sums = np.add.reduceat(weighted, segments.bounds[:-1], axis=0)
    sums[segments.bounds[1:] == segments.bounds[:-1]] = 0.0
    span = interval_spans(problem)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(span[:, None] > 0, sums / span[:, None], 0.0)


def parameter_step(
    linear: gtsam.GaussianFactorGraph,
    columns: dict[int, np.ndarray],
    prior_information: np.ndarray,
    sensitive: list[int] | None = None,
) -> ParameterStep | None:
    """The step of p parameters whose whitened columns ``columns`` (factor index in
    ``linear`` -> (rows, p)) add to those factors' rows, every state of ``linear`` free (see
    the module docstring), with a zero-mean prior of information ``prior_information``
    (p, p). With ``sensitive`` (keys), also those states' sensitivity to the parameters:
    ``-S U = -R^-1 (R^-T U)``, one more back-substitution per parameter. None when the graph
    cannot be eliminated."""
    gradient = linear.gradientAtZero()  # -A'b, over every variable
    # keyVector, a list: iterating the KeySet that keys() returns read freed memory.
    all_keys = [int(key) for key in linear.keyVector()]
    dims = {key: gradient.at(key).shape[0] for key in all_keys}
    information = np.array(prior_information, dtype=float)
    count = information.shape[0]
    rhs = np.zeros(count)
    u: dict[int, np.ndarray] = {}
    for index, column in columns.items():
        factor = linear.at(index)
        keys = [int(key) for key in factor.keys()]
        matrix, b = factor.jacobian()  # whitened [A_1 ... A_n], b (error = A dx - b)
        information += column.T @ column
        rhs += column.T @ b
        start = 0
        for key in keys:
            block = matrix[:, start : start + dims[key]].T @ column
            start += dims[key]
            u[key] = u[key] + block if key in u else block
    # QR, as the solves: tight bias random walks make the normal equations lose every digit
    # (Cholesky then reports an indeterminant system).
    try:
        bayes_net = linear.eliminateSequential(
            gtsam.Ordering.OrderingType.COLAMD, gtsam.EliminateQR
        )
    except RuntimeError:
        return None

    zeros = {key: np.zeros(dims[key]) for key in all_keys}

    def back_transposed(column: dict[int, np.ndarray]) -> gtsam.VectorValues:
        vector = gtsam.VectorValues()
        for key in all_keys:
            vector.insert(key, column.get(key, zeros[key]))
        return bayes_net.backSubstituteTranspose(vector)

    # Every result holds the same keys, so .vector() orders them alike (key order).
    w_values = [back_transposed({key: block[:, c] for key, block in u.items()}) for c in range(count)]
    w = np.column_stack([values.vector() for values in w_values])
    w_r = back_transposed({key: -gradient.at(key) for key in all_keys}).vector()
    information -= w.T @ w
    rhs -= w.T @ w_r
    try:
        covariance = np.linalg.inv(information)
    except np.linalg.LinAlgError:
        return None
    sensitivity = None
    if sensitive is not None:
        moves = -np.column_stack([bayes_net.backSubstitute(values).vector() for values in w_values])
        ordered = sorted(all_keys)  # .vector()'s order
        offsets = dict(zip(ordered, np.cumsum([0] + [dims[key] for key in ordered[:-1]]), strict=True))
        sensitivity = {
            key: moves[offsets[key] : offsets[key] + dims[key]] for key in sensitive if key in dims
        }
    return ParameterStep(
        step=covariance @ rhs, covariance=covariance, information=information, rhs=rhs,
        sensitivity=sensitivity,
    )  # fmt: skip
