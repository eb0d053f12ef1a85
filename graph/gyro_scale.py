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
Schur complement of the linearised graph (:mod:`fgins.graph.parameter_step`): O(K), no
Python callback in a solve.
A weak prior (:data:`SCALE_PRIOR`) keeps an axis that never turns at zero. An axis whose
estimate is both significant and above the floor is corrected: the gyro's samples are
rescaled, every interval re-preintegrated and the solve repeated from its solution (a turn
the size of the error was linear enough to need one round; at most :data:`MAX_ROUNDS`).
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X

from fgins.datatypes import FginsError
from fgins.graph.parameter_step import (
    imu_bias_jacobians,
    interval_mean,
    interval_spans,
    parameter_step,
)
from fgins.graph.problem import Problem
from fgins.graph.solve import SolveReport, is_suspect, solve_from, solve_with_stops

SCALE_PRIOR = 0.05  # 1-sigma of a scale error before the data (5 %: beyond any MEMS gyro)
# An axis's scale error is corrected when it is at least this large and this many sigmas.
MIN_SCALE_ERROR = 0.002
MIN_SCALE_SIGMAS = 5.0
# Beyond this on any axis, and determined (MIN_SCALE_SIGMAS: an axis a car hardly turns
# about scatters widely), the solution, not the gyro, is wrong: consumer MEMS datasheets give
# +-1-3 % (with temperature); a car's pitch axis, which its drive hardly turns, read +6.0 +-
# 1.0 % (and -5.9 %) where the configured mounting was 4 deg off in yaw (an independent
# simulator's car, no scale error): corrected, that was a false finding.
MAX_SCALE_ERROR = 0.05
# Beyond this and this many sigmas no gyro and no small mounting error explains it: the
# gyro's axes are wrong (an independent simulator's car on 0.2-2 % grades with gyro_y
# negated read +79 to +154 % at 21-70 sigmas, gyro x and y swapped +47 to +92 %: 5-130 m
# inside outages at exit 0, unsaid). An error, no output. (A gyro_x negated on a highway,
# +31 % at 6.8 sigmas, 1.7 m: said, as implausible.)
GROSS_SCALE_ERROR = 0.25
GROSS_SCALE_SIGMAS = 10.0
GROSS_SCALE_KEY = "gyro_scale_gross_error"  # info: the error the pipeline raises
MAX_ROUNDS = 3
_BIAS_GYRO = slice(3, 6)  # ConstantBias's vector: accelerometer, then gyro


@dataclass(frozen=True)
class ScaleEstimate:
    """Per-axis gyro scale error (read rate over true rate, less 1) and its 1-sigma."""

    error: np.ndarray
    sigma: np.ndarray
    # Each keyframe state's move with the scale (parameter_step's sensitivity), by key.
    sensitivity: dict[int, np.ndarray] | None = None
    # The reduced normal equations (under SCALE_PRIOR): information @ error = rhs.
    information: np.ndarray | None = None
    rhs: np.ndarray | None = None

    def under_prior(self, sigma: float) -> tuple[np.ndarray, np.ndarray]:
        """(estimate, covariance) with a zero-mean prior of ``sigma`` per axis instead of
        SCALE_PRIOR (the same data): what the gyro's grade says the scale can be."""
        assert self.information is not None and self.rhs is not None
        information = self.information + (sigma**-2 - SCALE_PRIOR**-2) * np.eye(3)
        covariance = np.linalg.inv(information)
        return covariance @ self.rhs, covariance

    @property
    def implausible(self) -> np.ndarray:
        """Axes whose determined estimate is beyond any gyro's scale error."""
        size = np.abs(self.error)
        return (size > MAX_SCALE_ERROR) & (size >= MIN_SCALE_SIGMAS * self.sigma)

    @property
    def gross(self) -> np.ndarray:
        """Axes beyond GROSS_SCALE_ERROR at GROSS_SCALE_SIGMAS: no gyro's scale, an axis mistake."""
        size = np.abs(self.error)
        return (size > GROSS_SCALE_ERROR) & (size >= GROSS_SCALE_SIGMAS * self.sigma)

    @property
    def significant(self) -> np.ndarray:
        """Axes to correct; none when any axis is beyond what a gyro's scale can be: the
        solution, not the gyro, is then wrong (a start heading 120 deg off, its first fit
        at chi2/dof 19, read as scale errors of +398 % and -44 %)."""
        size = np.abs(self.error)
        determined = size >= MIN_SCALE_SIGMAS * self.sigma
        if np.any((size > MAX_SCALE_ERROR) & determined):
            return np.zeros(3, dtype=bool)
        return (size >= MIN_SCALE_ERROR) & determined


# Half-width (s) of the neighbourhood whose mean turn rate stands for an interval's.
RATE_NEIGHBOURS_S = 1.0


def neighbour_rates(problem: Problem) -> np.ndarray:
    """(K-1, 3) each keyframe interval's turn rate as the mean reading of the intervals
    within RATE_NEIGHBOURS_S around it, its own left out (time-weighted).

    A scale error multiplies the turn, and an interval's own mean reading carries the noise
    its IMU factor's residual carries too: regressed on it, the scale picks up that noise's
    share (a consumer gyro on an axis that hardly turns read as +17 % +- 3 and +21 % +- 3,
    a false "gyro column flipped" warning on a drive with long stops: outside tester). A
    turn lasts seconds, so its neighbours' rate is its own, without its noise."""
    means = interval_mean_rates(problem)
    span = interval_spans(problem)
    if len(means) < 3:
        return means
    typical = float(np.median(span[span > 0])) if np.any(span > 0) else 0.0
    half = max(1, round(RATE_NEIGHBOURS_S / typical)) if typical > 0 else 1
    kernel = np.ones(2 * half + 1)
    weighted = np.stack([np.convolve(means[:, a] * span, kernel, mode="same") for a in range(3)], axis=1)
    weights = np.convolve(span, kernel, mode="same")
    weighted -= means * span[:, None]  # its own left out
    weights = weights - span
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(weights[:, None] > 0, weighted / weights[:, None], means)


def interval_mean_rates(problem: Problem) -> np.ndarray:
    """(K-1, 3) mean gyro reading over each keyframe interval (time-weighted)."""
    return interval_mean(problem, problem.dataset.imu.gyro)


def estimate_gyro_scale(
    problem: Problem, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values
) -> ScaleEstimate | None:
    """The per-axis scale error the solution ``values`` of ``graph`` points to (see the
    module docstring), about the scale the problem's samples already carry; None when the
    graph has no IMU factor or its linearisation cannot be eliminated."""
    linear = graph.linearize(values)
    # The turn rate, not the reading: a scale error multiplies the rate, not the gyro's bias.
    # On the axes a car hardly turns about the reading is mostly bias, and regressed on it
    # the "scale" took the bias's changes (a van idling at 14 stops with a vibrating engine,
    # a car parked on a rolling ferry: x +34-39 % at 10 sigmas, refused as "a gyro column
    # with its sign flipped"; outside tester).
    rates = neighbour_rates(problem)
    columns = {
        index: bias_jacobian[:, _BIAS_GYRO]
        * (rates[interval] - values.atConstantBias(B(interval)).gyroscope())[None, :]
        for index, interval, bias_jacobian in imu_bias_jacobians(graph, linear)
    }
    if not columns:
        return None
    keys = [key for k in range(problem.n_keyframes) for key in (X(k), V(k))]
    estimate = parameter_step(linear, columns, np.eye(3) / SCALE_PRIOR**2, sensitive=keys)
    if estimate is None:
        return None
    return ScaleEstimate(
        error=estimate.step, sigma=estimate.sigma, sensitivity=estimate.sensitivity,
        information=estimate.information, rhs=estimate.rhs,
    )  # fmt: skip


def scale_spread(problem: Problem, values: gtsam.Values, estimate: ScaleEstimate) -> dict[str, np.ndarray] | None:
    """(K, 3, 3) ENU position, velocity and attitude covariances that the gyro's remaining
    scale error adds to the solution ``values`` (held at the scale its samples carry):
    ``J (C + e e') J'``, J each keyframe state's sensitivity to the scale, e and C the
    estimate of what is left and its covariance (an axis not corrected keeps its whole
    error), under the prior of the gyro's grade (``[imu] gyro_scale_sigma_percent``): the
    estimate's own 5 % prior lets the gross checks see any error, but on an axis the drive
    hardly turns it left 0.2 % open on a tactical IMU, and its spread made the sigmas 1.3x
    the errors' size on fgins's simulated aircraft, whose gyro has no scale error. The
    solves hold the scale fixed, so their marginals are conditioned on it: an independent
    simulator's car with gyro scale errors of +0.5, -0.25 and +0.5 % (its [imu] a custom
    one, so the consumer prior) had z corrected, x (+0.74 +- 0.19 %, under the 5 sigmas a
    correction needs) not, and its first 15 s outage 0.71 m off at a reported 0.16 m (NEES
    10.5), unsaid. None without a sensitivity."""
    if estimate.sensitivity is None or estimate.information is None:
        return None
    error, covariance = estimate.under_prior(problem.noise.gyro_scale_sigma)
    spread = covariance + np.outer(error, error)
    if not np.all(np.isfinite(spread)):
        return None
    n = problem.n_keyframes
    none = np.zeros((6, 3))
    pose = np.stack([estimate.sensitivity.get(X(k), none) for k in range(n)])
    velocity = np.stack([estimate.sensitivity.get(V(k), none[:3]) for k in range(n)])
    # Pose3's tangent is in the body frame, rotation first (as the marginals').
    rotation = np.stack([values.atPose3(X(k)).rotation().matrix() for k in range(n)])
    moves = {"attitude": rotation @ pose[:, :3], "position": rotation @ pose[:, 3:], "velocity": velocity}
    return {name: move @ spread @ move.transpose(0, 2, 1) for name, move in moves.items()}


def add_scale_spread(covariances: dict[str, np.ndarray], spread: dict[str, np.ndarray] | None) -> None:
    """Add :func:`scale_spread`'s covariances to the keyframes' marginal ``covariances``
    (in place; nothing without them)."""
    if spread is None:
        return
    for name, added in spread.items():
        covariances[name] = covariances[name] + added


def correct_gyro_scale(
    problem: Problem, report: SolveReport, result: gtsam.Values, graph: gtsam.NonlinearFactorGraph
) -> tuple[gtsam.Values, gtsam.NonlinearFactorGraph, dict[str, object], dict[str, np.ndarray] | None]:
    """The batch's solution with the gyro's significant scale errors corrected (see the
    module docstring): ``result`` and ``graph`` themselves when there are none. ``report``
    takes the extra solves' counts and errors; the info dict says what was found; last, the
    covariances the scale's remaining error adds to the keyframes' (:func:`scale_spread`,
    for :func:`add_scale_spread`; None where there is none to add)."""
    if problem.dataset.accel_array is not None:
        return result, graph, {}, None
    if not problem.config.smoother.estimate_gyro_scale:
        return result, graph, *_kept_scale_said(problem, graph, result)
    estimate = estimate_gyro_scale(problem, graph, result)
    if estimate is None:
        return result, graph, {}, None
    implausible = estimate.implausible
    gross = estimate.gross
    gross_error = None
    if gross.any():
        found = _axes_text(estimate.error, estimate.sigma, gross, (0, 1))
        # Raised by the pipeline if its last solve still reads so: a correction after this
        # solve (turn-on bias sigmas widened) may explain it (a gyro bias 20 times its prior
        # read as +40 % about z on the first solve, and fits once widened).
        gross_error = (
            f"imu: the gyro's turns contradict the solution's, read as scale errors of {found} "
            "(a gyro's is within a few %): a gyro column with its sign flipped or two columns "
            "swapped (gyro_x, gyro_y, gyro_z must be the accelerometer's right-handed axes), an "
            "IMU mounting far off, gyro biases far beyond their turn-on sigmas, or a solution far "
            "off the truth (a configured initial heading?"
            + (
                f"; or a vehicle model that does not hold: --vehicle {problem.config.smoother.vehicle}"
                " ties the IMU's heading to its track, which a multirotor, a walker or a boat in"
                " a current does not follow: --vehicle uav, pedestrian or other"
                if problem.config.smoother.nhc
                else ""
            )
            + "); no output written"
        )
    if gross_error and not _an_axis_mistake_fits_better(problem, report, result, gross):
        # No column mistake explains the misfit: not one (a car parked on a rolling ferry, a
        # van whose vibrating engine shakes its gyro: x +34-39 % at 10 sigmas, refused as "a
        # gyro column with its sign flipped" where EKF+RTS was 0.3-1.1 m off; outside
        # tester). Said as implausible (the warning below), the run goes on.
        gross_error = None
    axes = estimate.significant
    total = np.ones(3)
    for _ in range(MAX_ROUNDS if axes.any() else 0):
        factor = 1.0 + np.where(axes, estimate.error, 0.0)
        before = (problem.dataset, list(problem.pims), problem.pim_bias.copy(),
                  set(problem.zupt_keyframes))  # fmt: skip
        problem.rescale_gyro(factor, result)
        again, corrected, corrected_graph = solve_with_stops(problem, *solve_from(problem, result))
        # The corrected gyro does not fit (or fits worse than the solution it came from,
        # whose misfit may be the scale's): keep the solution before.
        if not again.converged or (is_suspect(again) and again.chi2_per_dof >= report.chi2_per_dof):
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
    info = _info(total * (1.0 + estimate.error) - 1.0, estimate.sigma, corrected_axes, implausible)
    if gross_error:
        info[GROSS_SCALE_KEY] = gross_error
    # An error beyond any gyro's is said, not spread: a linear sensitivity does not reach it.
    spread = None if implausible.any() else scale_spread(problem, result, estimate)
    return result, graph, info, spread


# A gyro axis mistake fits the drive once undone: its chi2/dof at most this share of the
# solution's (an independent simulator's car with gyro_y negated or x/y swapped: 5-130 m
# off, undone it fits as the recording does).
MISTAKE_FIT_GAIN = 0.7


def axis_mistakes(gross: np.ndarray) -> list[tuple[str, np.ndarray]]:
    """(what, the matrix that undoes it) for the column mistakes that can read as gross
    scale errors on the ``gross`` axes: each such axis negated, and each pair of axes one
    of which is gross swapped (alone, or with either negated: right-handed again)."""
    names = "xyz"
    out: list[tuple[str, np.ndarray]] = []
    for a in np.flatnonzero(gross):
        flip = np.eye(3)
        flip[a, a] = -1.0
        out.append((f"gyro_{names[a]} negated", flip))
    for a in range(3):
        for b in range(a + 1, 3):
            if not (gross[a] or gross[b]):
                continue
            swap = np.eye(3)
            swap[[a, b]] = swap[[b, a]]
            out.append((f"gyro_{names[a]} and gyro_{names[b]} swapped", swap))
            for c in (a, b):
                turned = swap.copy()
                turned[c] *= -1.0
                out.append((f"gyro_{names[a]} and gyro_{names[b]} swapped, one negated", turned))
    return out


def _an_axis_mistake_fits_better(
    problem: Problem, report: SolveReport, result: gtsam.Values, gross: np.ndarray
) -> bool:
    """Does undoing some column mistake (:func:`axis_mistakes`) make the drive fit far
    better (MISTAKE_FIT_GAIN)? Each is solved from ``result``; the problem is left as it
    was. Only where the scale reads gross: a few extra solves on a drive about to be
    refused."""
    dataset, pims, pim_bias, stops = problem.dataset, problem.pims, problem.pim_bias, problem.zupt_keyframes
    for _, matrix in axis_mistakes(gross):
        # Each trial works on copies (remap_gyro re-preintegrates in place), then lets go.
        problem.pims, problem.pim_bias, problem.zupt_keyframes = list(pims), pim_bias.copy(), set(stops)
        problem.remap_gyro(matrix, result)
        try:
            trial = solve_with_stops(problem, *solve_from(problem, result))[0]
        except (FginsError, RuntimeError):  # a trial that breaks down fits no better
            trial = None
        finally:
            problem.dataset, problem.pims, problem.pim_bias, problem.zupt_keyframes = dataset, pims, pim_bias, stops
        if trial is not None and trial.converged and trial.chi2_per_dof <= MISTAKE_FIT_GAIN * report.chi2_per_dof:
            return True
    return False


def _kept_scale_said(
    problem: Problem, graph: gtsam.NonlinearFactorGraph, result: gtsam.Values
) -> tuple[dict[str, object], dict[str, np.ndarray] | None]:
    """``estimate_gyro_scale = false`` set by the user: the estimate is still read, a
    significant one said, not corrected (a 3 % scale error kept so left outages at z 4-6.6
    while the lines blamed the receiver's slow errors and the mounting: outside tester), and
    its spread added to the sigmas. Nothing where the pipeline, not the user, turned it off.
    The info and the spread, as :func:`correct_gyro_scale`'s."""
    if "estimate_gyro_scale" not in problem.config.explicit_smoother_keys:
        return {}, None
    estimate = estimate_gyro_scale(problem, graph, result)
    if estimate is None:
        return {}, None
    spread = None if estimate.implausible.any() else scale_spread(problem, result, estimate)
    if not estimate.significant.any():
        return {}, spread
    found = _axes_text(estimate.error, estimate.sigma, estimate.significant, (2, 2))
    return {
        "gyro_scale_error": estimate.error.tolist(),
        "gyro_scale_sigma": estimate.sigma.tolist(),
        "gyro_scale_corrected": [False, False, False],
        "fit_warnings": [
            f"imu: the gyro reads turns larger or smaller than the solution shows (scale error "
            f"{found}): not corrected ([smoother] estimate_gyro_scale = false), so each turn "
            "inside a GNSS outage leaves the heading off by that fraction of it (the output's "
            "sigmas include it)"
        ],
    }, spread


def _axes_text(error: np.ndarray, sigma: np.ndarray, mask: np.ndarray, digits: tuple[int, int]) -> str:
    """"x +1.03 % +- 0.05, z ..." for the axes in ``mask`` (percent, with ``digits`` decimals
    for the estimate and its sigma)."""
    d, e = digits
    return ", ".join(
        f"{axis} {100 * error[a]:+.{d}f} % +- {100 * sigma[a]:.{e}f}"
        for a, axis in enumerate("xyz")
        if mask[a]
    )


def _info(error: np.ndarray, sigma: np.ndarray, axes: np.ndarray, implausible: np.ndarray) -> dict[str, object]:
    """The run summary's entries: the estimate, and a warning naming what was corrected or
    what no scale error explains."""
    info: dict[str, object] = {
        "gyro_scale_error": error.tolist(),
        "gyro_scale_sigma": sigma.tolist(),
        "gyro_scale_corrected": axes.tolist(),
    }
    if implausible.any():
        # Said, not corrected: a gyro axis whose sign is flipped read as a scale error of
        # +31 % +- 4.5 on an independent simulator's highway (1.7 m inside an outage against
        # 0.5, NEES 4.7, unsaid); a mounting 4 deg off in yaw as +6 %.
        found = _axes_text(error, sigma, implausible, (1, 1))
        info["fit_warnings"] = [
            f"imu: the gyro's turns disagree with the solution's far beyond any gyro's scale "
            f"error (read as a scale error of {found}; a MEMS gyro's is within "
            f"{100 * MAX_SCALE_ERROR:.0f} %): a gyro column with its sign flipped or two "
            "columns swapped, an IMU mounting that is off ([smoother] imu_to_vehicle_rpy_deg), "
            "or a wrong solution; not corrected"
        ]
        return info
    if axes.any():
        found = _axes_text(error, sigma, axes, (2, 2))
        info["fit_warnings"] = [
            f"imu: the gyro reads turns larger or smaller than the solution shows (scale "
            f"error {found}): corrected in the smoother (the Kalman baselines do not model "
            "it); [smoother] estimate_gyro_scale = false turns this off"
        ]
    return info
