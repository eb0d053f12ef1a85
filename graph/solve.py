"""The solve shared by the batch and iSAM2 smoothers: the factor graph assembled from the
problem, Levenberg-Marquardt alternating with re-preintegration and relinearisation of the
linearised vehicle factors, and the honesty checks every solve passes.

Honesty: every solve checks that its error is finite, that it made progress and converged,
and how consistent the fit is (chi-square per degree of freedom); the report says which
solver produced it, how, and any fallback taken. A solve that cannot be trusted is an error,
never an initial guess under the method's name.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import gtsam
import numpy as np
from gtsam.symbol_shorthand import V

from fgins.datatypes import FginsError
from fgins.factors import stationary
from fgins.graph.problem import Problem, rotations_and_velocities
from fgins.graph.solution import marginal_function

# Re-preintegrate an interval when its bias estimate moved this far from the one it was
# integrated about (GTSAM's bias correction is first order).
REPREINTEGRATE_GYRO_RAD_S = 0.01
REPREINTEGRATE_ACCEL_M_S2 = 0.2
# An outer round that changes the error by less than this (relative) has settled, whatever
# small bias or attitude moves remain (they are then below what the data can resolve).
SETTLED_RELATIVE_ERROR = 1e-5
# Out of rounds or iterations with the error's last FLAT_ROUNDS changes each under this share
# of it, the solve has settled as far as its data say (iSAM2's own test, 1e-3): a gyro-free
# car at 0.2 Hz GNSS through a 40 s outage, re-preintegration and LM trading the last 0.1 %
# along directions the data leave loose, was refused after 600 iterations where iSAM2 wrote
# the same fit (error 52.8, chi2/dof 0.09) with honest sigmas (outside tester).
FLAT_RELATIVE_ERROR = 1e-3
FLAT_ROUNDS = 3
# The linearised vehicle constraints are rebuilt until no attitude moves more than this.
RELINEARIZE_ATTITUDE_RAD = 1e-3
RELINEARIZE_VELOCITY_M_S = 0.05
# While the linearisation still moves, every LM iteration is followed by a rebuild of the
# linearised factors (vectorised, O(K)): the iterations then follow the exact Jacobians, as
# with a nonlinear factor, and converge as fast. Once nothing moves LM gets its full budget.
MAX_OUTER_ROUNDS = 40
ROUND_ITERATIONS = 1
# One solve makes at most this many times ``batch_max_iterations`` LM iterations in all its
# rounds; beyond, it is unconverged (batch then tries its other starts). A solve whose LM
# crawls (a real log with 5 fixes and a 307 s gap: each 100-iteration round lowered the
# error by 1-2 %, re-preintegration reopened it) took 40 full rounds from each start, 8,000
# iterations and 10 minutes, before the iSAM2 start converged in 19. Drives that converge
# take far fewer (the gyro-free cube 11-13).
SOLVE_ITERATION_BUDGET_FACTOR = 10
# chi-square / dof of a fit whose noise model describes the data is ~1; far above, the
# solution is suspect (batch restarts from iSAM2) and reported as inconsistent.
CHI2_SUSPECT = 10.0
CHI2_WARN = 4.0
# Below this the noise model is absurdly pessimistic (an ARW given 1e30 times too large:
# 0.00). Real drives sit at 0.1-0.6 (KITTI 0.11: NHC and stop factors fit better than their
# sigmas, which must cover slip), so only two orders of magnitude count.
CHI2_FAR_TOO_GOOD = 0.01
# Beyond this the solution is not a fit of the data at all (diverged): an error, no output.
CHI2_FAIL = 100.0


@dataclass
class SolveReport:
    """What a solve did: iterations, errors before/after, consistency, fallbacks."""

    solver: str
    iterations: int = 0
    rounds: int = 0
    repreintegrated: int = 0
    initial_error: float = math.nan
    final_error: float = math.nan
    dof: int = 0
    converged: bool = True
    fallback: str | None = None
    start: str | None = None  # what the initial values came from (batch)
    notes: list[str] = field(default_factory=list)
    blame: str = ""  # which factors carry an inconsistent fit's error (said with it)

    @property
    def chi2_per_dof(self) -> float:
        return 2.0 * self.final_error / max(self.dof, 1)

    def line(self) -> str:
        steps = "updates" if self.solver.startswith("iSAM2") else "iterations"
        error = (
            f"error {self.final_error:.4g}"
            if math.isnan(self.initial_error)
            else f"error {self.initial_error:.4g} -> {self.final_error:.4g}"
        )
        start = f" from the {self.start} guess" if self.start else ""
        text = (
            f"{self.solver}{start}: {self.iterations} {steps}, {self.rounds} relinearisation "
            "round(s)"
            f" ({self.repreintegrated} interval(s) re-preintegrated), {error}, chi2/dof "
            f"{self.chi2_per_dof:.2f} over {self.dof} dof"
        )
        if self.fallback:
            text += f"; fallback: {self.fallback}"
        return text


class NonFiniteError(FginsError):
    """A solve whose error is not finite (what the pipeline explains where it can)."""


class NotConvergedError(FginsError):
    """A batch solve that did not converge (what the pipeline explains where it can)."""


class DivergedError(FginsError):
    """A solve whose fit is far beyond its noise model (chi2/dof above CHI2_FAIL)."""


def check_finite(error: float, what: str, solver: str) -> None:
    if not math.isfinite(error):
        raise NonFiniteError(
            f"{solver}: the factor graph's error {what} is not finite (a NaN or infinite "
            "measurement or noise value reached a factor); check the inputs and the sensor "
            "configuration"
        )


def degrees_of_freedom(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> int:
    dims = sum(graph.at(i).dim() for i in range(graph.size()) if graph.exists(i))
    return int(dims - values.dim())


def nonlinear_graph(
    problem: Problem,
    speeds: np.ndarray | None,
    imu_index: list[int] | None = None,
    baro_index: dict[int, int] | None = None,
) -> gtsam.NonlinearFactorGraph:
    """Every C++ nonlinear factor; ZUPTs only where ``speeds`` (a solution's) confirm a stop.
    ``imu_index`` (if given) receives the graph index of each interval's IMU factor,
    ``baro_index`` that of each keyframe's barometer factor."""
    problem.zupt_keyframes.clear()
    graph = problem.prior_factors()
    for k in range(problem.n_keyframes):
        if k > 0 and imu_index is not None:
            imu_index.append(graph.size())  # keyframe_factors puts the IMU factor first
        factors = problem.keyframe_factors(k, None if speeds is None else float(speeds[k]))
        if baro_index is not None:
            baro_index.update(pressure_factor_index(factors, k, graph.size()))
        graph.push_back(factors)
    return graph


def pressure_factor_index(
    factors: gtsam.NonlinearFactorGraph, k: int, offset: int
) -> dict[int, int]:
    """{k: offset + index of the barometer factor in ``factors``}, or {} without one."""
    for i in range(factors.size()):
        if isinstance(factors.at(i), gtsam.BarometricFactor):
            return {k: offset + i}
    return {}


def refresh_plane_fall(
    problem: Problem,
    values: gtsam.Values,
    nonlinear: gtsam.NonlinearFactorGraph,
    baro_index: dict[int, int],
) -> int:
    """Rebuild the barometer factors whose plane fall moved at ``values``; how many."""
    moved = problem.baro_fall_moved(values)
    for k in moved:
        nonlinear.replace(baro_index[int(k)], problem.pressure_factor(int(k)))
    return len(moved)


def full_graph(
    problem: Problem, nonlinear: gtsam.NonlinearFactorGraph, values: gtsam.Values
) -> gtsam.NonlinearFactorGraph:
    graph = gtsam.NonlinearFactorGraph()
    graph.push_back(nonlinear)
    graph.push_back(problem.linear_factors(values))
    return graph


def levenberg_marquardt(
    graph: gtsam.NonlinearFactorGraph,
    initial: gtsam.Values,
    max_iterations: int,
    lambda_initial: float,
    solver: str,
):
    """Levenberg-Marquardt; returns (result, iterations, final damping, error at the start,
    error at the result). The errors are the optimiser's own (evaluating a 1 h graph costs
    ~40 ms); a non-finite start is an error before any iteration."""
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(1e-6)
    params.setAbsoluteErrorTol(1e-6)
    params.setlambdaInitial(lambda_initial)
    # QR, not Cholesky: tight bias random walks over short keyframe intervals (an industrial
    # IMU, 10 Hz GNSS) make the normal equations lose every digit; Cholesky's inexact steps
    # then crawled for minutes (100s of LM iterations, error still falling) where QR
    # converges in 6 iterations. At no measurable cost on KITTI or a 10 min 200 Hz drive.
    params.setLinearSolverType("MULTIFRONTAL_QR")
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    start_error = optimizer.error()
    check_finite(start_error, "at the initial guess", solver)
    result = optimizer.optimize()
    return result, optimizer.iterations(), optimizer.lambda_(), start_error, optimizer.error()


def linearisation_moved(problem: Problem, before: gtsam.Values, after: gtsam.Values) -> bool:
    """Did any keyframe carrying a linearised factor move beyond the relinearisation limits?"""
    keyframes = np.union1d(problem.nhc_keyframes, problem.antenna_velocity_keyframes)
    if not len(keyframes):
        return False
    rotation_a, velocity_a = rotations_and_velocities(before, keyframes)
    rotation_b, velocity_b = rotations_and_velocities(after, keyframes)
    if np.max(np.abs(velocity_a - velocity_b)) > RELINEARIZE_VELOCITY_M_S:
        return True
    relative = np.einsum("nji,njk->nik", rotation_a, rotation_b)  # R_a^T R_b
    # Its skew part is sin(angle) * axis: the rotation vector to within angle^2 / 6 below
    # 60 deg, where the limit (1e-3 rad) is decided; beyond, the trace says "moved".
    sine_axis = 0.5 * np.stack(
        [
            relative[:, 2, 1] - relative[:, 1, 2],
            relative[:, 0, 2] - relative[:, 2, 0],
            relative[:, 1, 0] - relative[:, 0, 1],
        ],
        axis=1,
    )
    cosine = 0.5 * (np.trace(relative, axis1=1, axis2=2) - 1.0)
    return bool(np.any(cosine < 0.5) or np.max(np.abs(sine_axis)) > RELINEARIZE_ATTITUDE_RAD)


def solve_in_rounds(
    problem: Problem, values: gtsam.Values, speeds: np.ndarray | None, report: SolveReport
) -> tuple[gtsam.Values, gtsam.NonlinearFactorGraph]:
    """Levenberg-Marquardt alternating with re-preintegration and relinearisation of the
    vehicle constraints until neither changes anything. Returns (solution, the exact graph
    at it)."""
    max_iterations = problem.config.smoother.batch_max_iterations
    budget_left = SOLVE_ITERATION_BUDGET_FACTOR * max_iterations
    has_linear = problem.has_linear_factors
    imu_index: list[int] = []
    baro_index: dict[int, int] = {}
    nonlinear = nonlinear_graph(problem, speeds, imu_index, baro_index)
    settled = False
    previous_error = math.inf
    damping = 1e-5  # carried across rounds: LM's trust region survives the rebuilds
    steady_rounds = flat_rounds = 0
    for _ in range(MAX_OUTER_ROUNDS):
        graph = full_graph(problem, nonlinear, values)
        # One iteration per rebuild while the linearisation moves; a slow, poorly observable
        # problem (a gyro-free IMU) that keeps moving gets longer rounds as they go on.
        escalated = ROUND_ITERATIONS * (1 + report.rounds // 10) ** 2
        budget = min(max_iterations if (settled or not has_linear) else escalated, budget_left)
        result, iterations, damping, start_error, end_error = levenberg_marquardt(
            graph, values, budget, damping, report.solver
        )
        if math.isnan(report.initial_error):
            report.initial_error = start_error
        report.iterations += iterations
        report.rounds += 1
        budget_left -= iterations
        check_finite(end_error, "after Levenberg-Marquardt", report.solver)
        converged = iterations < budget
        redone_intervals = problem.repreintegrate(
            result, REPREINTEGRATE_GYRO_RAD_S, REPREINTEGRATE_ACCEL_M_S2
        )
        report.repreintegrated += len(redone_intervals)
        redone = len(redone_intervals) + refresh_plane_fall(problem, result, nonlinear, baro_index)
        moved = has_linear and linearisation_moved(problem, values, result)
        values = result
        for i in redone_intervals:  # only their IMU factors change
            nonlinear.replace(imu_index[i], problem.imu_factor(int(i)))
        change = abs(previous_error - end_error)
        steady = change <= SETTLED_RELATIVE_ERROR * end_error
        steady_rounds = steady_rounds + 1 if steady else 0
        flat_rounds = flat_rounds + 1 if change <= FLAT_RELATIVE_ERROR * end_error else 0
        previous_error = end_error
        # Done when LM converged on a linearisation that no longer moves, or when rebuilds
        # stopped changing the error at all (twice in a row).
        if (converged and (steady or (not redone and not moved))) or steady_rounds >= 2:
            break
        if budget_left <= 0:
            report.converged = flat_rounds >= FLAT_ROUNDS
            break
        if not redone and not moved:
            settled = True  # only iterations are missing: give LM its full budget
    else:
        report.converged = flat_rounds >= FLAT_ROUNDS
    graph = full_graph(problem, nonlinear, values)
    return values, graph


def solve_with_stops(
    problem: Problem,
    report: SolveReport,
    result: gtsam.Values,
    graph: gtsam.NonlinearFactorGraph,
) -> tuple[SolveReport, gtsam.Values, gtsam.NonlinearFactorGraph]:
    """With ZUPT on, the second pass of a solve: stops are the quiet keyframes where the
    first solution (without stops) is slow enough (:func:`stop_speeds`), and their ZUPTs
    are added. Deciding stops from a start instead would let a start that is wrong in an
    outage plant a false stop, which no optimiser recovers from."""
    if not (problem.config.smoother.zupt and problem.stop_candidates.any()):
        return report, result, graph
    speeds = stop_speeds(problem, graph, result)
    problem.zupt_keyframes.clear()
    if np.isfinite(speeds).any():
        stops = SolveReport(solver=report.solver, initial_error=report.initial_error)
        result, graph = solve_in_rounds(problem, result, speeds, stops)
        report.iterations += stops.iterations
        report.rounds += stops.rounds
        report.repreintegrated += stops.repreintegrated
        report.converged = stops.converged
        finish_report(report, graph, result)
    return report, result, graph


def finish_report(
    report: SolveReport, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values
) -> None:
    report.final_error = graph.error(values)
    check_finite(report.final_error, "at the solution", report.solver)
    report.dof = degrees_of_freedom(graph, values)
    if report.chi2_per_dof > CHI2_WARN:
        report.blame = error_blame(graph, values)


# What each kind of factor stands for, and what to check when it carries an inconsistent fit.
FACTOR_KINDS = {
    "GPSFactor": "GNSS position",
    "GPSFactorArm": "GNSS position",
    "CombinedImuFactor": "IMU",
    "PriorFactorVector": "velocity (GNSS velocity, stops)",
    "LinearContainerFactor": "vehicle constraint / antenna velocity / odometer",
    "BarometricFactor": "barometer",
    "BetweenFactorDouble": "barometer bias walk",
}
KIND_ADVICE = {
    "GNSS position": "the fixes' sigmas (std_* columns, [gnss] settings) are too small for "
    "these fixes, or IMU and GNSS disagree (a clock offset: --time-offset; the antenna lever "
    "arm: [gnss] lever_arm_m)",
    "IMU": "the IMU noise (--imu-preset, [imu]) is too small for this IMU, its biases are "
    "larger than their turn-on sigmas ([imu] gyro_turn_on_bias_deg_per_s, "
    "accel_turn_on_bias_mg), its axes or units are wrong, or the GNSS times are offset from "
    "the IMU's (--time-offset)",
    "velocity (GNSS velocity, stops)": "the GNSS velocities disagree with the IMU: its noise "
    "preset is too optimistic for it (--imu-preset, [imu]), the clocks are offset "
    "(--time-offset), the antenna lever arm is wrong ([gnss] lever_arm_m), the velocity sigmas "
    "are too small, or a detected stop was not one",
    "vehicle constraint / antenna velocity / odometer": "the vehicle constraints or the "
    "antenna's velocity do not hold: check [smoother] imu_to_vehicle_rpy_deg, --vehicle and "
    "[gnss] lever_arm_m",
    "barometer": "the pressure heights disagree with the GNSS and IMU heights by more than "
    "baro_sigma_m and the bias walk allow: over a large climb on a day far from the standard "
    "atmosphere's temperature its height scale is off by several %; raise [smoother] "
    "baro_bias_walk_m_per_sqrt_s or leave the barometer out",
}
KIND_ADVICE["barometer bias walk"] = KIND_ADVICE["barometer"]


def error_blame(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> str:
    """'the GNSS position factors carry 97 % of the error (chi2/dof 3.9e4 there): ...' for
    the kind of factor with the largest share (a failure path: one pass over the factors)."""
    error: dict[str, float] = {}
    dims: dict[str, int] = {}
    for i in range(graph.size()):
        factor = graph.at(i)
        if factor is None:
            continue
        kind = FACTOR_KINDS.get(type(factor).__name__, type(factor).__name__)
        error[kind] = error.get(kind, 0.0) + float(factor.error(values))
        dims[kind] = dims.get(kind, 0) + int(factor.dim())
    total = sum(error.values())
    if not error or not total > 0:
        return ""
    kind = max(error, key=lambda name: error[name])
    advice = KIND_ADVICE.get(kind)
    text = (
        f"the {kind} factors carry {100 * error[kind] / total:.0f} % of the error (chi2/dof "
        f"{2 * error[kind] / max(dims[kind], 1):.3g} there)"
    )
    return f"{text}: {advice}" if advice else text


def fail_if_diverged(report: SolveReport) -> None:
    if report.chi2_per_dof > CHI2_FAIL:
        other = "--method batch" if report.solver.startswith("iSAM2") else "--method isam2"
        check = (
            report.blame or "check the IMU preset and the axis and unit conventions of the IMU data"
        )
        raise DivergedError(
            f"{report.solver} diverged: the solution does not fit the data (chi2/dof "
            f"{report.chi2_per_dof:.3g}, ~1 expected); no output written. {check[0].upper()}"
            f"{check[1:]}; or try {other}"
        )


def is_suspect(report: SolveReport) -> bool:
    return not report.converged or report.chi2_per_dof > CHI2_SUSPECT


def solve_from(
    problem: Problem, initial: gtsam.Values
) -> tuple[SolveReport, gtsam.Values, gtsam.NonlinearFactorGraph]:
    report = SolveReport(solver="batch LM")
    result, graph = solve_in_rounds(problem, initial, None, report)
    finish_report(report, graph, result)
    return report, result, graph


def stop_speeds(
    problem: Problem, graph: gtsam.NonlinearFactorGraph, result: gtsam.Values
) -> np.ndarray:
    """The solved speed at each keyframe where it confirms a stop, inf elsewhere.

    At the stop candidates (:attr:`Problem.stop_candidates`) slow enough to be stops, the speed's sigma (the largest of its
    velocity marginal's) decides too (:meth:`Problem.speed_confirms_stop`); one marginal
    factorisation, made only when there is such a keyframe.
    """
    speeds = np.array([np.linalg.norm(result.atVector(V(k))) for k in range(problem.n_keyframes)])
    out = np.full(problem.n_keyframes, np.inf)
    slow = [
        int(k) for k in np.flatnonzero(problem.stop_candidates)
        if problem.speed_confirms_stop(float(speeds[k]), None)
    ]  # fmt: skip
    if not slow:
        return out
    marginal = marginal_function(graph, result)
    floor_only = np.zeros(problem.n_keyframes, dtype=bool)
    for k in slow:
        sigma = stationary.speed_sigma(marginal(V(k)))
        if problem.speed_confirms_stop(float(speeds[k]), sigma):
            out[k] = speeds[k]
            floor_only[k] = sigma is not None and speeds[k] >= stationary.SOLUTION_STOP_SIGMAS * sigma
    # A speed only the floor let in (known many sigmas off zero) beside a keyframe moving
    # faster than the floor: the car is pulling away or not yet stopped. One touching rest and
    # pulling away at once was stopped at 0.17 +- 0.014 m/s, and the ZUPT's pull read as a GNSS
    # antenna 2.1 m to the side, "corrected": the track 2.1 m off everywhere at z 3.6-3.9
    # (outside tester). The floor stays for a real stop whose first solve an outlier or late
    # fixes pulled a few sigmas off zero.
    fast = speeds >= stationary.STOP_SPEED_FLOOR_M_PER_S
    beside_fast = np.zeros(problem.n_keyframes, dtype=bool)
    beside_fast[:-1] |= fast[1:]
    beside_fast[1:] |= fast[:-1]
    out[floor_only & beside_fast] = np.inf
    return _without_moving_stops(problem, out, speeds)


def _without_moving_stops(problem: Problem, stop_speed: np.ndarray, speeds: np.ndarray) -> np.ndarray:
    """``stop_speed`` (finite at stops) with the stops of slow stretches the fixes or the
    wheel show moving set to inf (:func:`fgins.factors.stationary.moving_stops`: a crawl
    under the speed floor; ``speeds``: the solution's without stops), said in
    ``problem.info["stops_moving"]``."""
    keyframes = problem.position_keyframes
    fixes = problem.gnss_at[keyframes]
    moving, said = stationary.moving_stops(
        problem.segments.times, np.isfinite(stop_speed), speeds, keyframes, problem.gnss_enu[fixes, :2],
        problem.gnss_sigma[fixes, :2],
        problem.odometer_speed if problem.has_odometer else None,
        problem.config.smoother.odometer_sigma_m_per_s,
    )  # fmt: skip
    problem.info.pop("stops_moving", None)
    if not moving.any():
        return stop_speed
    t0 = problem.dataset.t0
    runs = "; ".join(f"t - t0 = {a - t0:.0f}-{b - t0:.0f} s: {how}" for a, b, how in said)
    problem.info["stops_moving"] = (
        f"stops: {int(moving.sum())} keyframe(s) of a quiet IMU at a low solved speed not taken "
        f"as stops: the vehicle crawled ({runs}), which reads like rest to an IMU"
    )
    return np.where(moving, np.inf, stop_speed)


def callback_factors(graph: gtsam.NonlinearFactorGraph) -> int:
    """Factors whose evaluation calls back into Python (must stay 0: see module docs)."""
    return sum(
        isinstance(graph.at(i), gtsam.CustomFactor) for i in range(graph.size()) if graph.exists(i)
    )
