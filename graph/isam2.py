"""Incremental smoothing: one iSAM2 update per keyframe over a sliding window, then a final
pass over the whole graph. Yields the final (smoothed) and the online (filtered) estimate:
each keyframe's state as it was right after its own update, what a real-time system would
have had.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X

from fgins.datatypes import FginsError, Trajectory
from fgins.factors import odometer as odometer_model
from fgins.factors import stationary
from fgins.factors.values import put_bias, put_double, put_pose, put_vector
from fgins.graph.gnss_faults import FaultExclusion, exclude_gnss_faults, with_every_fix
from fgins.graph.gyro_scale import add_scale_spread, correct_gyro_scale
from fgins.graph.output import KeyframeStates
from fgins.graph.problem import Problem
from fgins.graph.reports import (
    extra_states,
    gnss_report,
    lever_arm_report,
    merge_info,
    solver_report,
    vehicle_fit_report,
)
from fgins.graph.solution import (
    covariance_report,
    marginal_covariances,
    marginal_function,
    nav_covariances,
    states_from_values,
    to_trajectory,
)
from fgins.graph.solve import (
    CHI2_WARN,
    REPREINTEGRATE_ACCEL_M_S2,
    REPREINTEGRATE_GYRO_RAD_S,
    SolveReport,
    callback_factors,
    check_finite,
    degrees_of_freedom,
    error_blame,
    fail_if_diverged,
    full_graph,
    is_suspect,
    linearisation_moved,
    nonlinear_graph,
    pressure_factor_index,
    refresh_plane_fall,
    solve_from,
    solve_with_stops,
    stop_speeds,
)
from fgins.graph.start import InitialGuess, initial_values

RELINEARIZE_SKIP = 10  # GTSAM's default: relinearisation checks every 10 updates
ISAM2_WILDFIRE_THRESHOLD = 0.01  # see _run_isam2_with
ISAM2_WINDOW_S = 10.0  # keyframes the running iSAM2 holds: see _Window
ISAM2_MARGINALISE_EVERY = RELINEARIZE_SKIP  # updates (with the relinearisation ones)
# The GNSS counts of the online (filtered) estimate: every fix, before any fault exclusion.
ONLINE_GATING_KEYS = ("gnss_gating", "gnss_counts", "gnss_epochs_used")
ISAM2_FINAL_ROUNDS = 5  # rebuilds of the whole graph at most in the final pass
ISAM2_SETTLED_RELATIVE_ERROR = 1e-3  # a final Gauss-Newton step that gains less: converged


class _IndeterminateUpdate(Exception):
    pass


def run_isam2(
    problem: Problem,
    progress: bool,
    online_covariance: bool = True,
    relinearize_skip: int = RELINEARIZE_SKIP,
):
    """Incremental iSAM2, one update per keyframe.

    Returns (isam, final values, online values, online covariances, report, (update times,
    preintegration times) per keyframe):
    the online states and covariances are each keyframe's right after its own update.
    Cholesky first (fast); if it calls an update indeterminate (tight bias random walks
    against loose bias priors: the conditioning, not the problem, is at fault) the run
    restarts with QR. Anything else that fails is a clear error.
    """
    try:
        return _run_isam2_with(problem, progress, online_covariance, "CHOLESKY", relinearize_skip)
    except _IndeterminateUpdate:
        return _run_isam2_with(problem, progress, online_covariance, "QR", relinearize_skip)


def _guarded(factorization: str, failure: str, call: Callable[[], object]):
    """``call()``; a GTSAM failure restarts a Cholesky run on QR (_IndeterminateUpdate),
    and on QR is an error: ``failure``, then GTSAM's first line."""
    try:
        return call()
    except RuntimeError as exc:
        if factorization == "CHOLESKY":
            raise _IndeterminateUpdate from None
        raise FginsError(f"{failure}: {_first_line(exc)}") from None


def _isam2_step(isam: gtsam.ISAM2, factorization: str, what: str, *args, **kwargs):
    return _guarded(
        factorization, f"iSAM2: {what} failed even with QR factorization",
        lambda: isam.update(*args, **kwargs),
    )  # fmt: skip


class _Window:
    """The keyframes the running iSAM2 holds: about the last ``span_s`` seconds of them.

    GTSAM's iSAM2 update costs O(cliques) however little changes (the temporary Bayes tree
    of the re-eliminated top is destroyed by a walk over every clique below it, orphans
    included, i.e. the whole tree): 60 min, 200 Hz, 1 Hz keyframes: a plain update 0.4 ms
    at the start, 1.6 ms at the end; update p99 10 ms in the first quarter, 23 ms in the
    last. So older keyframes are marginalised out of the running iSAM2 (their information
    stays, as GTSAM's linear marginal on the window's oldest states) once their estimate is
    kept: the final pass then smooths the whole graph from those estimates
    (_run_isam2_with). The online estimate of the newest keyframe hardly changes (KITTI:
    keyframe positions within 9 mm of the unbounded run's, rms 1 mm): only states older
    than the window are no longer relinearised online.

    ``marginalizeLeaves`` needs the keys to be leaves of the Bayes tree (GTSAM's release
    build does not check it), which the incremental orderings do not promise. So every
    ``every`` updates the whole window is re-eliminated in one update, the leaving keys
    first (constrained ordering), and only then marginalised: a leaf by construction.
    That update sets the p99 (60 min: 5.4 ms with a 10 s window, 8.8 ms with 30 s).
    """

    def __init__(self, span_s: float, every: int, shared: frozenset[int]) -> None:
        self.span_s = span_s
        self.every = every
        self.shared = shared  # keys of every keyframe (never marginalised): ordered last
        self._keyframes: deque[tuple[float, list[int]]] = deque()  # (time, own keys)

    def add(self, t: float, keys: list[int]) -> None:
        self._keyframes.append((t, [key for key in keys if key not in self.shared]))

    def due(self, k: int, t: float) -> bool:
        """Does update k (at time t) marginalise keyframes out?"""
        return k % self.every == self.every - 1 and self._keyframes[0][0] < t - self.span_s

    def marginalisation(self, t: float) -> tuple[list[int], gtsam.KeyGroupMap, gtsam.KeyList]:
        """(leaving keys, ordering groups, keys to re-eliminate) for the update at time t
        that has just added the newest keyframe; the leaving keyframes leave the window."""
        leaving: list[int] = []
        while self._keyframes[0][0] < t - self.span_s:
            leaving += self._keyframes.popleft()[1]
        *kept, newest = self._keyframes
        groups = gtsam.KeyGroupMap()
        everything = gtsam.KeyList()  # the window's keys already in the tree
        # CCOLAMD wants the groups numbered 0, 1, ... without gaps.
        group = 0
        for keys, in_tree in (
            (leaving, True), ([key for _, own in kept for key in own], True),
            ([*newest[1], *self.shared], False),
        ):  # fmt: skip
            for key in keys:
                groups.insert2(key, group)
                if in_tree:
                    everything.push_back(key)
            group += bool(keys)
        return leaving, groups, everything


def _isam2_speed_sigma(
    problem: Problem, isam: gtsam.ISAM2, k: int, predicted: gtsam.NavState
) -> float | None:
    """The sigma of the speed predicted at quiet keyframe k: that of V(k-1) in the running
    iSAM2 (one marginal, asked only where it decides a stop); None where not needed or
    not available (the speed cap alone decides then)."""
    speed = float(np.linalg.norm(predicted.velocity()))
    if not (
        problem.config.smoother.zupt
        and problem.stop_candidates[k]
        and speed >= stationary.STOP_SPEED_FLOOR_M_PER_S
        and problem.speed_confirms_stop(speed, None)
    ):
        return None
    try:
        return stationary.speed_sigma(isam.marginalCovariance(V(k - 1)))
    except RuntimeError:
        return None


def _run_isam2_with(
    problem: Problem,
    progress: bool,
    online_covariance: bool,
    factorization: str,
    relinearize_skip: int,
):
    from tqdm import tqdm

    problem.zupt_keyframes.clear()
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(problem.config.smoother.isam2_relinearize_threshold)
    params.relinearizeSkip = relinearize_skip
    # Look for variables to relinearise from the root down, only into cliques whose
    # variables moved beyond the threshold (GTSAM's partial check), not over all K of them:
    # the full check made every 10th update O(K), so the p99 grew with the drive (20 min,
    # 200 Hz: update p99 53 -> 22 ms, last quarter 79 -> 20 ms; online and final positions
    # the same to 0.1 mm).
    params.enablePartialRelinearizationCheck = True
    # The per-update estimate is read at the newest keyframe only, which sits in the root
    # clique: the back-substitution need not descend into cliques whose solution changed by
    # less than this (GTSAM's default 0.001 sent it far back on every update: 20 min, 200
    # Hz: update p50 3.4 -> 1.7 ms, same online and final positions). Final estimates use a
    # full back-substitution (_estimate).
    params.setOptimizationParams(gtsam.ISAM2GaussNewtonParams(ISAM2_WILDFIRE_THRESHOLD))
    params.setFactorization(factorization)
    isam = gtsam.ISAM2(params)
    window = _Window(ISAM2_WINDOW_S, ISAM2_MARGINALISE_EVERY, problem.shared_keys)
    left = gtsam.Values()  # estimates of the keyframes marginalised out, for the final pass
    times = problem.segments.times
    n = problem.n_keyframes
    online = {name: np.full((n, 3, 3), np.nan) for name in ("position", "velocity", "attitude")}
    # The online states (right after each keyframe's own update), kept in arrays: inserting
    # into a gtsam.Values from Python costs up to ~0.2 ms a value (overload resolution).
    online_states = {
        "rotation": np.empty((n, 3, 3)), "position": np.empty((n, 3)),
        "velocity": np.empty((n, 3)), "accel_bias": np.empty((n, 3)),
        "gyro_bias": np.empty((n, 3)),
    }  # fmt: skip
    align = problem.alignment
    state = gtsam.NavState(gtsam.Rot3(align.rotation), align.position, align.velocity)
    bias = gtsam.imuBias.ConstantBias()
    scale_error = 0.0
    nonlinear = gtsam.NonlinearFactorGraph()  # every C++ factor added, for the final pass
    imu_index: dict[int, int] = {}  # interval -> index of its IMU factor in ``nonlinear``
    baro_index: dict[int, int] = {}  # keyframe -> index of its barometer factor there
    linear_point = gtsam.Values()  # where the linearised factors were made
    update_s = np.zeros(n)
    preintegrate_s = np.zeros(n)
    report = SolveReport(solver="iSAM2")
    recent = stationary.RecentSpeeds()  # online speeds of the last seconds (slow-downs)
    for k in tqdm(range(n), desc="iSAM2", unit="kf", disable=not progress, leave=False):
        if k > 0:
            # Preintegrate about the newest bias estimate: what a real-time system would do,
            # sample by sample as they arrive between keyframes; so it is timed apart from
            # the update (which starts when keyframe k arrives).
            started = time.perf_counter()
            problem.preintegrate(k - 1, bias)
            preintegrate_s[k] = time.perf_counter() - started
        step_started = time.perf_counter()
        graph = problem.prior_factors() if k == 0 else gtsam.NonlinearFactorGraph()
        new_values = gtsam.Values()
        speed_sigma = None
        if k > 0:
            state = problem.predict(k - 1, state, bias)
            speed_sigma = _isam2_speed_sigma(problem, isam, k, state)
            # The plane fall where the prediction is (the fixes' chord is not known online).
            problem.set_baro_fall(np.array([k]), state.position()[None])
        predicted_speed = float(np.linalg.norm(state.velocity()))
        keyframe = problem.keyframe_factors(
            k, predicted_speed, speed_sigma=speed_sigma,
            slowed_to_a_stop=stationary.slowed_to_a_stop(predicted_speed, recent.peak()),
        )  # fmt: skip
        if k > 0:
            imu_index[k - 1] = nonlinear.size() + graph.size()  # the IMU factor comes first
        baro_index.update(pressure_factor_index(keyframe, k, nonlinear.size() + graph.size()))
        graph.push_back(keyframe)
        nonlinear.push_back(graph)
        pose, velocity = state.pose(), state.velocity()
        put_pose(new_values, X(k), pose)
        put_vector(new_values, V(k), velocity)
        put_bias(new_values, B(k), bias)  # the antenna velocity's lever-arm term needs it
        problem.insert_extra_values(k, new_values)
        point = gtsam.Values(new_values)  # a C++ copy: cheaper than the typed inserts again
        if problem.has_odometer and k > 0:
            put_double(point, odometer_model.scale_key(), scale_error)
        graph.push_back(problem.linear_factors(point, np.array([k])))
        put_pose(linear_point, X(k), pose)
        put_vector(linear_point, V(k), velocity)
        window.add(float(times[k]), list(new_values.keys()))
        leaving: list[int] = []
        if window.due(k, float(times[k])):
            leaving, groups, everything = window.marginalisation(float(times[k]))
            _isam2_step(
                isam, factorization, f"update at keyframe {k}", graph, new_values,
                constrainedKeys=groups, extraReelimKeys=everything,
            )  # fmt: skip
        else:
            _isam2_step(isam, factorization, f"update at keyframe {k}", graph, new_values)
        try:
            pose = isam.calculateEstimatePose3(X(k))
            velocity = isam.calculateEstimateVector(V(k))
            bias = isam.calculateEstimateConstantBias(B(k))
            if problem.has_odometer:
                scale_error = isam.calculateEstimateDouble(odometer_model.scale_key())
        except RuntimeError as exc:
            if factorization == "CHOLESKY":
                raise _IndeterminateUpdate from None
            raise FginsError(
                f"iSAM2: estimate at keyframe {k} (t = {times[k] - problem.dataset.t0:.1f} s) "
                f"failed even with QR factorization: {_first_line(exc).rstrip('.')}; the online "
                "solution lost track of a state the data observe only later (e.g. a gyro-free "
                "IMU with sparse GNSS); no output written. Try --method batch"
            ) from None
        state = gtsam.NavState(pose, velocity)
        online_states["rotation"][k] = pose.rotation().matrix()
        online_states["position"][k] = pose.translation()
        online_states["velocity"][k] = velocity
        online_states["accel_bias"][k] = bias.accelerometer()
        online_states["gyro_bias"][k] = bias.gyroscope()
        if online_covariance:
            try:
                # One joint marginal of the newest pose and velocity (both in the root
                # clique): ~30 % cheaper than two marginalCovariance calls.
                joint = isam.jointMarginalCovariance(gtsam.KeyVector([X(k), V(k)]))
                attitude, position = nav_covariances(joint.at(X(k), X(k)), pose.rotation().matrix())
                online["attitude"][k], online["position"][k] = attitude, position
                online["velocity"][k] = joint.at(V(k), V(k))
            except RuntimeError:
                if factorization == "CHOLESKY":
                    raise _IndeterminateUpdate from None
                # QR could not resolve this marginal either: left NaN (reported as unknown).
        recent.add(
            float(times[k]), float(np.linalg.norm(velocity)),
            stationary.speed_sigma(online["velocity"][k]),
        )  # fmt: skip
        if leaving:
            left.insert(isam.calculateEstimate(leaving))
            _isam2_marginalize(isam, factorization, leaving)
        update_s[k] = time.perf_counter() - step_started
    # Final smoothing: the linearised vehicle factors (made at each keyframe's prediction)
    # and the preintegration (about the online bias) are redone at the smoothed estimate.
    # Removing hundreds of factors from a running iSAM2 costs O(K^2) in GTSAM, so the
    # refreshed graph goes into a new iSAM2 started at the old one's estimate. Once
    # keyframes have left the window, the first round always rebuilds: the running iSAM2
    # holds the window only, the marginalised keyframes at their estimates when they left.
    # A round's Gauss-Newton step is repeated while it still lowers the error: from the
    # window's estimates of the marginalised keyframes (fixed once they left) the first
    # step can fall short where the attitude was still poorly known (uav-loop-baro, 120 s,
    # 20 s window: error 18982 after it, 247 after a second, LM's 173.73 after the fourth).
    # Windowed, the highway and KITTI need three rebuilds (the third only confirms).
    windowed = not left.empty()
    step_from = math.inf  # the full graph's error where the last rebuild started
    for round_ in range(ISAM2_FINAL_ROUNDS):
        estimate = _estimate(isam, factorization)
        if windowed and round_ == 0:
            estimate.insert(left)
        redone = problem.repreintegrate(
            estimate, REPREINTEGRATE_GYRO_RAD_S, REPREINTEGRATE_ACCEL_M_S2
        )
        for i in redone:
            nonlinear.replace(imu_index[int(i)], problem.imu_factor(int(i)))
        report.repreintegrated += len(redone)
        refalled = refresh_plane_fall(problem, estimate, nonlinear, baro_index)
        has_linear = problem.has_linear_factors
        settled = not math.isfinite(step_from) or (
            step_from - isam.getFactorsUnsafe().error(estimate)
            < ISAM2_SETTLED_RELATIVE_ERROR * step_from
        )
        if (
            not (windowed and round_ == 0)
            and not len(redone)
            and not refalled
            and settled
            and not (has_linear and linearisation_moved(problem, linear_point, estimate))
        ):
            break
        graph = gtsam.NonlinearFactorGraph()
        graph.push_back(nonlinear)
        graph.push_back(problem.linear_factors(estimate))
        linear_point = estimate
        step_from = graph.error(estimate)
        isam = gtsam.ISAM2(params)
        _isam2_step(isam, factorization, "final relinearisation", graph, estimate)
        report.rounds += 1
    for _ in range(2):
        _isam2_step(isam, factorization, "final update")
    if problem.zupt_keyframes:
        isam = _isam2_redecide_stops(problem, isam, params, factorization, report)
    final = _estimate(isam, factorization)
    factors = compact_graph(isam.getFactorsUnsafe())
    report.initial_error = float("nan")
    report.final_error = factors.error(final)
    check_finite(report.final_error, "at the final estimate", "iSAM2")
    report.dof = degrees_of_freedom(factors, final)
    if report.chi2_per_dof > CHI2_WARN:
        report.blame = error_blame(factors, final)
    report.iterations = n
    online_keyframes = KeyframeStates(
        **online_states,
        position_cov=online["position"],
        velocity_cov=online["velocity"],
        attitude_cov=online["attitude"],
    )
    return isam, final, online_keyframes, online, report, (update_s, preintegrate_s)


def _isam2_redecide_stops(
    problem: Problem,
    isam: gtsam.ISAM2,
    params: gtsam.ISAM2Params,
    factorization: str,
    report: SolveReport,
) -> gtsam.ISAM2:
    """The online pass decided each stop from its causal prediction: dead reckoning through
    an outage, the predicted speed of a car creeping at 1.2 m/s can drift below the floor
    where a quiet IMU is taken as a stop, and the false stops then freeze the track (20 m
    off). The final estimate re-decides them as the batch does: solve the whole graph
    without stops, keep the quiet keyframes whose smoothed speed and its sigma confirm one
    (:func:`stop_speeds`), and re-solve with those. Unchanged stops keep ``isam``."""
    online_stops = set(problem.zupt_keyframes)
    estimate = _estimate(isam, factorization)
    free, free_estimate, _ = _isam2_solve_full(problem, None, estimate, params, factorization)
    speeds = stop_speeds(problem, free, free_estimate)
    confirmed = {int(k) for k in np.flatnonzero(np.isfinite(speeds))}
    if confirmed == online_stops:
        problem.zupt_keyframes = online_stops
        return isam
    problem.info["stops_redecided"] = (
        f"stops re-decided on the smoothed solution: {len(online_stops)} taken online, "
        f"{len(online_stops - confirmed)} dropped, {len(confirmed - online_stops)} added "
        "(the online output keeps its own)"
    )
    report.rounds += 2
    return _isam2_solve_full(problem, speeds, free_estimate, params, factorization)[2]


def _isam2_solve_full(
    problem: Problem,
    speeds: np.ndarray | None,
    start: gtsam.Values,
    params: gtsam.ISAM2Params,
    factorization: str,
) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, gtsam.ISAM2]:
    """The whole graph (stops where ``speeds`` confirm them) solved by a new iSAM2 from
    ``start``, the vehicle constraints relinearised until they settle. Returns (the graph
    at the solution, the solution, the iSAM2)."""
    estimate = start
    for _ in range(ISAM2_FINAL_ROUNDS):
        graph = full_graph(problem, nonlinear_graph(problem, speeds), estimate)
        isam = gtsam.ISAM2(params)
        _isam2_step(isam, factorization, "stop re-decision", graph, estimate)
        for _ in range(2):
            _isam2_step(isam, factorization, "stop re-decision")
        moved = problem.has_linear_factors and linearisation_moved(
            problem, estimate, _estimate(isam, factorization)
        )
        estimate = _estimate(isam, factorization)
        if not moved:
            break
    graph = full_graph(problem, nonlinear_graph(problem, speeds), estimate)
    return graph, estimate, isam


def _isam2_marginalize(isam: gtsam.ISAM2, factorization: str, keys: list[int]) -> None:
    leaves = gtsam.KeyList()
    for key in keys:
        leaves.push_back(key)
    _guarded(
        factorization, "iSAM2: marginalising old keyframes failed",
        lambda: isam.marginalizeLeaves(leaves),
    )  # fmt: skip


def _first_line(exc: Exception) -> str:
    """GTSAM's messages run over many lines; the CLI promises one."""
    lines = [line.strip() for line in str(exc).splitlines() if line.strip()]
    return " ".join(lines[:2]) if lines else type(exc).__name__


def _estimate(isam: gtsam.ISAM2, factorization: str) -> gtsam.Values:
    """Every variable's estimate by a full back-substitution (not the wildfire one that
    the per-update estimates use, which leaves old variables' small changes unapplied)."""
    return _guarded(
        factorization, "iSAM2: the estimate could not be computed", isam.calculateBestEstimate
    )


def _refit(
    problem: Problem, report: SolveReport, start: Callable[[], tuple[gtsam.Values, str]]
) -> tuple[gtsam.Values, gtsam.NonlinearFactorGraph] | None:
    """(solution, graph) of Levenberg-Marquardt on the same graph from ``start()`` (its
    values and what they are), when the iSAM2 estimate does not fit; None when that fits no
    better. ``report`` then says so (its fallback) and carries LM's fit."""
    try:
        values, label = start()
        refined, solution, graph = solve_with_stops(problem, *solve_from(problem, values))
    except FginsError:
        return None
    if not refined.final_error < report.final_error:
        return None
    before = report.chi2_per_dof
    _took_lm(
        report, refined,
        f"the iSAM2 estimate did not fit the data (chi2/dof {before:.3g}): solved by "
        f"Levenberg-Marquardt on the same graph from {label} ({refined.iterations} iterations)",
    )  # fmt: skip
    report.converged = refined.converged
    return solution, graph


def _took_lm(report: SolveReport, solve: SolveReport, note: str) -> None:
    """The iSAM2 ``report`` carries the fit of a Levenberg-Marquardt ``solve`` that replaced
    its estimate, and says so (``note`` appended to its fallback)."""
    report.final_error, report.dof, report.blame = solve.final_error, solve.dof, solve.blame
    report.rounds += solve.rounds
    _say(report, note)


def _say(report: SolveReport, note: str) -> None:
    report.fallback = "; ".join(filter(None, [report.fallback, note]))


def _without_gnss_faults(
    problem: Problem,
    report: SolveReport,
    solution: tuple[gtsam.Values, gtsam.NonlinearFactorGraph],
) -> tuple[tuple[gtsam.Values, gtsam.NonlinearFactorGraph] | None, FaultExclusion]:
    """The final ``solution`` (values, graph) with the GNSS faults left out
    (fgins.graph.gnss_faults): solved again by Levenberg-Marquardt from it, its stops kept,
    and said in ``report``; None where no fix is a fault."""
    solve = SolveReport(solver=report.solver)
    solve.final_error, solve.dof = report.final_error, report.dof
    values, graph, faults = exclude_gnss_faults(problem, solve, *solution)
    if not faults.keyframes:
        return None, faults
    _took_lm(
        report, solve,
        f"{len(faults.keyframes)} GNSS fault(s) left out: solved again by Levenberg-Marquardt "
        f"from the iSAM2 estimate ({solve.iterations} iterations)",
    )  # fmt: skip
    return (values, graph), faults


def _batch_start(
    problem: Problem, initial_guess: InitialGuess | None, progress: bool
) -> tuple[gtsam.Values, str]:
    """The batch's start (:func:`fgins.graph.start.initial_values`) and what it is."""
    start, _ = initial_values(problem, initial_guess, progress)
    return start.values, f"the batch's start ({start.source})"


def _refined(
    problem: Problem,
    report: SolveReport,
    estimate: gtsam.Values,
    initial_guess: InitialGuess | None,
    progress: bool,
) -> tuple[gtsam.Values, gtsam.NonlinearFactorGraph] | None:
    """A final estimate that does not fit, solved again: from the batch's start, and where
    that does not fit either, from the iSAM2 estimate; the better fit is kept, the
    preintegration left about its biases. None when neither does better than the iSAM2
    estimate. An online pass that diverged can leave LM from its estimate in another basin:
    a gyro-free IMU through two 30 s outages ended at chi2/dof 6.5 and 89 m inside them
    after 600 iterations, where the batch's start gives 0.43 and 7 m in 23."""
    refined = _refit(problem, report, lambda: _batch_start(problem, initial_guess, progress))
    if is_suspect(report):
        # A vehicle that never moves: its heading is unobservable, the online heading swung
        # by tens of degrees between updates and left the gyro bias 3 mrad/s off (chi2/dof
        # 4469); LM from that estimate fits.
        from_estimate = _refit(problem, report, lambda: (estimate, "the iSAM2 estimate"))
        refined = from_estimate if from_estimate is not None else refined
    problem.preintegrate_about(refined[0] if refined is not None else estimate)
    return refined


def smooth_isam2(
    problem: Problem,
    progress: bool = True,
    *,
    online_first: bool = False,
    initial_guess: InitialGuess | None = None,
) -> tuple[Trajectory, DeferredTrajectory | None]:
    """One iSAM2 update per keyframe. Returns (final smoothed, online filtered) trajectories,
    the second made on first use (``online_first``: the other way round; None where the
    online pass failed and the final estimate was solved without it). ``initial_guess``:
    the batch's (:func:`fgins.graph.start.initial_values`), for a final estimate that does
    not fit."""
    started = time.perf_counter()
    run, failure = _online_pass(problem, progress)
    if run is None:
        # The online pass lost track (a gyro-free IMU with sparse GNSS: an indeterminate
        # state near the end). The online estimate does not exist; the final one is the
        # same graph solved from the batch's start, said.
        assert failure is not None
        if online_first:
            raise failure
        report = SolveReport(solver="iSAM2", final_error=math.inf, converged=False)
        cause = _first_line(failure).split("; no output written")[0]
        report.fallback = f"the online pass failed ({cause}): no online estimate"
        refined = _refit(problem, report, lambda: _batch_start(problem, initial_guess, progress))
        if refined is None:
            raise failure
        isam = result = online_states = online = None
        update_s = (np.zeros(0), np.zeros(0))
    else:
        isam, result, online_states, online, report, update_s = run
        refined = _refined(problem, report, result, initial_guess, progress) if is_suspect(report) else None
    scale_info: dict[str, object] = {}
    spread = None
    final_graph = None if refined is not None else compact_graph(isam.getFactorsUnsafe())
    if report.converged:  # a poor fit may be poor for the scale (as in the batch)
        solution, graph = refined if refined is not None else (result, final_graph)
        scaled, scaled_graph, scale_info, spread = correct_gyro_scale(problem, report, solution, graph)
        if scaled is not solution:  # a scale corrected: LM from the iSAM2 estimate solved again
            refined = (scaled, scaled_graph)
            _say(report, "gyro scale corrected: solved again by Levenberg-Marquardt from the "
                 "iSAM2 estimate")  # fmt: skip
    # Faults last, as in the batch: a model error (a gyro scale) is not a fault of the fixes.
    online_gating = {key: problem.info[key] for key in ONLINE_GATING_KEYS}  # every fix
    before = refined if refined is not None else (result, final_graph)
    without, faults = _without_gnss_faults(problem, report, before)
    refined = without if without is not None else refined
    fail_if_diverged(report)
    incremental = time.perf_counter()
    report.notes = []
    # Final marginals through one batch factorisation of the final graph: iSAM2's own
    # per-key marginals after the final relinearisation can walk far up the tree (O(K) each).
    if refined is None:
        factors = final_graph
    else:
        result, factors = refined
    update_s, preintegrate_s = update_s
    # Per keyframe: the update once the keyframe is there (factors, iSAM2 update, estimate,
    # online covariance), and apart from it the preintegration of the interval's samples,
    # which a real-time system does as they arrive (~5 us a sample in GTSAM's binding).
    timings = {
        "incremental": incremental - started,
        "isam2_update_s": update_s.tolist(),
        "isam2_preintegrate_s": preintegrate_s.tolist(),
    }

    def make_final() -> Trajectory:
        marginal = marginal_function(factors, result)
        covariances = marginal_covariances(problem, marginal, marginal, result, progress)
        add_scale_spread(covariances, spread)
        final = to_trajectory(
            problem, states_from_values(problem, result, covariances), "isam2", smoothed=True
        )
        merge_info(
            final,
            gnss_report(problem, result),
            with_every_fix(
                problem, faults, lambda: lever_arm_report(problem, before[1], before[0])
            ),
            extra_states(problem, result),
            solver_report(report),
            vehicle_fit_report(problem, result),
            covariance_report(covariances),
            scale_info,
            faults.info(len(problem.gnss_used)),
            {
                "python_callback_factors": callback_factors(factors),
                "zupt_keyframes": len(problem.zupt_keyframes),
            },
        )
        final.timings.update({**timings, "final": time.perf_counter() - incremental})
        return final

    def make_online() -> Trajectory:
        filtered = to_trajectory(problem, online_states, "isam2-online", smoothed=False)
        merge_info(
            filtered,
            online_gating,  # the filter had every fix; the exclusion is the final pass's
            covariance_report(online),
            {"solver": "iSAM2 online (filtered)", "fallback": report.fallback},
        )
        filtered.timings.update(timings)
        return filtered

    if online_first:
        return make_online(), DeferredTrajectory(make_final)
    return make_final(), DeferredTrajectory(make_online) if run is not None else None


def _online_pass(problem: Problem, progress: bool) -> tuple[tuple | None, FginsError | None]:
    """(run_isam2's result, None), retried relinearising at every update where the default
    schedule diverged or failed (that follows a poor start, large biases, much better); (None,
    the first failure) where both fail."""
    failure: FginsError | None = None
    try:
        run = run_isam2(problem, progress)
    except FginsError as exc:
        run, failure = None, exc
    if run is None or is_suspect(run[4]):
        try:
            retry = run_isam2(problem, progress, relinearize_skip=1)
        except FginsError as exc:
            retry, failure = None, failure or exc
        if retry is not None and (run is None or retry[4].final_error < run[4].final_error):
            run = retry
            run[4].fallback = "relinearised at every update (the default schedule " + (
                "diverged)" if failure is None
                else f"failed: {_first_line(failure).split('; no output written')[0]})"
            )
    return run, failure


class DeferredTrajectory:
    """A trajectory made on first use: the other estimate of an iSAM2 run (online beside the
    final one, or the reverse). Each is a full IMU-rate trajectory (~0.4 KB per IMU sample),
    so a run makes only the one asked for until the other is used. Attribute access
    forwards to the trajectory."""

    def __init__(self, build: Callable[[], Trajectory]) -> None:
        self._build: Callable[[], Trajectory] | None = build
        self._value: Trajectory | None = None

    def get(self) -> Trajectory:
        if self._value is None:
            assert self._build is not None
            self._value, self._build = self._build(), None
        return self._value

    def __getattr__(self, name: str):
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self.get(), name)

    def __len__(self) -> int:
        return len(self.get())


def compact_graph(graph: gtsam.NonlinearFactorGraph) -> gtsam.NonlinearFactorGraph:
    """The graph without the empty slots that removed factors leave in iSAM2's."""
    out = gtsam.NonlinearFactorGraph()
    for i in range(graph.size()):
        if graph.exists(i):
            out.add(graph.at(i))
    return out
