"""Batch (Levenberg-Marquardt) and incremental (iSAM2) smoothing of a dataset.

Entry point: :func:`smooth`. Both methods share the same problem (keyframes, factors,
priors); iSAM2 also yields the online estimate: each keyframe's state as it was right after
its own update, i.e. what a real-time system would have had.
"""

from __future__ import annotations

import time
from dataclasses import replace

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X
from tqdm import tqdm

from fgins.config import RunConfig
from fgins.datatypes import Dataset, FginsError, Trajectory
from fgins.graph.output import KeyframeStates, densify
from fgins.graph.problem import Problem, build_problem


def initial_values(problem: Problem) -> gtsam.Values:
    """A guess for every keyframe from the forward EKF baseline (Huber-weighted GNSS).

    A filter is the right initialiser for a batch smoother: it corrects attitude and biases
    as it goes, bridges outages with its own best dead reckoning and down-weights gross GNSS
    outliers, so Levenberg-Marquardt starts in the right basin (and the ZUPT test sees a
    sensible speed). Falls back to GNSS-reset dead reckoning if the filter cannot run.
    """
    from fgins.baseline.ekf import run_ekf

    # Huber-weighted updates bound what a gross outlier can do to the guess; a hard
    # innovation gate would be worse: once it rejects a few fixes the filter can lock out.
    config = replace(problem.config, gnss=replace(problem.config.gnss, huber_k=2.0, cauchy_k=None))
    try:
        ekf = run_ekf(problem.dataset, config, gnss_mask=problem.gnss_mask, progress=False)
    except FginsError:
        return _dead_reckoning_guess(problem)
    times = problem.segments.times
    nearest = np.clip(np.searchsorted(ekf.t, times), 0, len(ekf.t) - 1)
    position = np.column_stack([np.interp(times, ekf.t, ekf.position[:, i]) for i in range(3)])
    velocity = np.column_stack([np.interp(times, ekf.t, ekf.velocity[:, i]) for i in range(3)])
    accel_bias = np.nan_to_num(ekf.accel_bias[nearest])
    gyro_bias = np.nan_to_num(ekf.gyro_bias[nearest])
    if not (np.all(np.isfinite(position)) and np.all(np.isfinite(velocity))):
        return _dead_reckoning_guess(problem)
    values = gtsam.Values()
    for k in range(problem.n_keyframes):
        values.insert(X(k), gtsam.Pose3(gtsam.Rot3(ekf.rotation[nearest[k]]), position[k]))
        values.insert(V(k), velocity[k])
        values.insert(B(k), gtsam.imuBias.ConstantBias(accel_bias[k], gyro_bias[k]))
        problem.insert_extra_values(k, values)
    return values


def _dead_reckoning_guess(problem: Problem) -> gtsam.Values:
    """IMU prediction reset to GNSS position (and differenced-GNSS velocity) at every fix."""
    align = problem.alignment
    values = gtsam.Values()
    state = gtsam.NavState(gtsam.Rot3(align.rotation), align.position, align.velocity)
    bias = gtsam.imuBias.ConstantBias()
    fd_velocity = _finite_difference_velocity(problem)
    for k in range(problem.n_keyframes):
        if k > 0:
            state = problem.predict(k - 1, state, bias)
            g = int(problem.gnss_at[k])
            if g >= 0:
                velocity = state.velocity()
                if np.all(np.isfinite(fd_velocity[g])):
                    velocity = fd_velocity[g]
                state = gtsam.NavState(state.attitude(), problem.gnss_enu[g], velocity)
        values.insert(X(k), state.pose())
        values.insert(V(k), state.velocity())
        values.insert(B(k), bias)
        problem.insert_extra_values(k, values)
    return values


def _finite_difference_velocity(problem: Problem) -> np.ndarray:
    """GNSS velocity where given, else central differences over neighbours <= 5 s apart."""
    keyed = problem.gnss_at[problem.gnss_at >= 0]
    t = np.empty(len(problem.gnss_enu))
    t[keyed] = problem.segments.times[problem.gnss_at >= 0]
    enu = problem.gnss_enu
    out = problem.gnss_velocity.copy()
    for g in range(len(enu)):
        if np.all(np.isfinite(out[g])):
            continue
        lo, hi = max(g - 1, 0), min(g + 1, len(enu) - 1)
        if hi > lo and t[hi] - t[lo] <= 5.0:
            out[g] = (enu[hi] - enu[lo]) / (t[hi] - t[lo])
        else:
            out[g] = np.nan
    return out


# A fix whose whitened residual exceeds this at the solution (chi-square, 3 dof, 99.9 %) is
# reported as rejected: the robust kernel has all but removed its weight.
REJECT_WHITENED = 4.03
RELINEARIZE_SKIP = 10  # GTSAM's default: relinearisation checks every 10 updates


def _extra_states(values: gtsam.Values) -> dict[str, object]:
    """Estimated non-navigation states worth reporting (odometer scale-factor error)."""
    from fgins.factors.odometer import scale_key

    if values.exists(scale_key()):
        return {"odometer_scale_error": float(values.atDouble(scale_key()))}
    return {}


def _gnss_report(problem: Problem, values: gtsam.Values) -> dict[str, object]:
    times, norms = problem.gnss_whitened_residuals(values)
    rejected = times[norms > REJECT_WHITENED]
    return {
        "gnss_rejected_times": [float(t) for t in rejected],
        "gnss_rejected": f"GNSS outliers: {len(rejected)} of {len(times)} fixes rejected "
        f"(whitened residual > {REJECT_WHITENED})"
        + (
            ": t - t0 = "
            + ", ".join(f"{t - problem.dataset.t0:.1f}" for t in rejected[:20])
            + (" ..." if len(rejected) > 20 else "")
            if len(rejected)
            else ""
        ),
    }


def _states_from_values(
    problem: Problem, values: gtsam.Values, covariances: dict[str, np.ndarray]
) -> KeyframeStates:
    n = problem.n_keyframes
    rotation = np.empty((n, 3, 3))
    position = np.empty((n, 3))
    velocity = np.empty((n, 3))
    accel_bias = np.empty((n, 3))
    gyro_bias = np.empty((n, 3))
    for k in range(n):
        pose = values.atPose3(X(k))
        rotation[k] = pose.rotation().matrix()
        position[k] = pose.translation()
        velocity[k] = values.atVector(V(k))
        bias = values.atConstantBias(B(k))
        accel_bias[k] = bias.accelerometer()
        gyro_bias[k] = bias.gyroscope()
    return KeyframeStates(
        rotation=rotation,
        velocity=velocity,
        position=position,
        accel_bias=accel_bias,
        gyro_bias=gyro_bias,
        position_cov=covariances["position"],
        velocity_cov=covariances["velocity"],
        attitude_cov=covariances["attitude"],
    )


def _nav_covariances(pose_cov: np.ndarray, rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """GTSAM's Pose3 covariance is in the body frame (rotation first): rotate into ENU."""
    attitude = rotation @ pose_cov[:3, :3] @ rotation.T
    position = rotation @ pose_cov[3:, 3:] @ rotation.T
    return attitude, position


def _qr_marginals(graph: gtsam.NonlinearFactorGraph, result: gtsam.Values):
    params = gtsam.ISAM2Params()
    params.setFactorization("QR")
    isam = gtsam.ISAM2(params)
    isam.update(graph, result)
    return isam.marginalCovariance


def _marginal_function(graph: gtsam.NonlinearFactorGraph, result: gtsam.Values):
    """Marginal covariance lookup: Cholesky (fast), falling back to QR through iSAM2 for the
    keys where Cholesky calls the system indeterminate (tight bias random walks of
    tactical-grade IMUs, long IMU gaps), and to NaN where even QR cannot tell."""
    qr = None
    try:
        cholesky = gtsam.Marginals(graph, result).marginalCovariance
    except RuntimeError:
        cholesky = None

    def marginal(key: int) -> np.ndarray:
        nonlocal qr, cholesky
        if cholesky is not None:
            try:
                return cholesky(key)
            except RuntimeError:
                cholesky = None  # once ill-conditioned, use QR for the rest
        if qr is None:
            qr = _qr_marginals(graph, result)
        try:
            return qr(key)
        except RuntimeError:
            dim = 6 if gtsam.Symbol(key).chr() == ord("x") else 3
            return np.full((dim, dim), np.nan)

    return marginal


def _marginal_covariances(
    problem: Problem, marginal_pose, marginal_velocity, values: gtsam.Values, progress: bool
) -> dict[str, np.ndarray]:
    """ENU position/velocity/attitude covariances at every keyframe (NaN where a marginal
    cannot be computed: the rest of the output is still valid)."""
    n = problem.n_keyframes
    out = {name: np.full((n, 3, 3), np.nan) for name in ("position", "velocity", "attitude")}
    for k in tqdm(range(n), desc="covariances", unit="kf", disable=not progress, leave=False):
        rotation = values.atPose3(X(k)).rotation().matrix()
        try:
            out["attitude"][k], out["position"][k] = _nav_covariances(marginal_pose(X(k)), rotation)
            out["velocity"][k] = marginal_velocity(V(k))
        except RuntimeError:
            continue
    return out


def _to_trajectory(
    problem: Problem, states: KeyframeStates, method: str, *, smoothed: bool
) -> Trajectory:
    imu = problem.dataset.imu
    dense = densify(
        problem.segments,
        imu.accel[problem.segments.sample],
        imu.gyro[problem.segments.sample],
        states,
        problem.gravity,
        problem.omega_earth,
        close_to_next=smoothed,
    )
    # Rows at the IMU sample times (segment starts also include keyframe cuts).
    rows = np.searchsorted(dense.t, imu.t)
    rows = np.clip(rows, 0, len(dense.t) - 1)
    return Trajectory(
        t=imu.t,
        position=dense.position[rows],
        velocity=dense.velocity[rows],
        rotation=dense.rotation[rows],
        origin=problem.dataset.origin,
        method=method,
        gyro_bias=dense.gyro_bias[rows],
        accel_bias=dense.accel_bias[rows],
        position_cov=dense.position_cov[rows],
        velocity_cov=dense.velocity_cov[rows],
        attitude_cov=dense.attitude_cov[rows],
        info=dict(problem.info),
    )


def _batch_graph(problem: Problem, speeds: np.ndarray | None) -> gtsam.NonlinearFactorGraph:
    """All factors; ZUPTs only where ``speeds`` (a solution's, per keyframe) confirm a stop."""
    problem.zupt_keyframes.clear()
    graph = problem.prior_factors()
    for k in range(problem.n_keyframes):
        graph.push_back(problem.keyframe_factors(k, None if speeds is None else float(speeds[k])))
    return graph


def _optimize(graph: gtsam.NonlinearFactorGraph, initial: gtsam.Values, max_iterations: int):
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(1e-6)
    params.setAbsoluteErrorTol(1e-6)
    optimizer = gtsam.LevenbergMarquardtOptimizer(graph, initial, params)
    return optimizer.optimize(), optimizer.iterations()


def _suspect_solution(
    graph: gtsam.NonlinearFactorGraph, result: gtsam.Values, iterations: int, max_iterations: int
) -> bool:
    """Did LM stall or end far from a consistent fit? A consistent solution has an error of
    about half the number of measurement dimensions (chi-square / 2), i.e. ~1-2 per factor."""
    return iterations >= max_iterations or graph.error(result) > 25.0 * graph.size()


def smooth_batch(problem: Problem, progress: bool = True) -> Trajectory:
    """Levenberg-Marquardt over the whole drive, covariances from the marginals.

    With ZUPT on, two passes: the first solves without zero-velocity factors; stops are then
    the quiet-IMU keyframes where that solution's speed is low, and the second pass adds
    their ZUPTs. Deciding stops from the initial guess instead would let a guess that is
    wrong in an outage plant a false stop, which no optimiser recovers from.
    """
    started = time.perf_counter()
    max_iterations = problem.config.smoother.batch_max_iterations
    initial = initial_values(problem)
    graph = _batch_graph(problem, None)
    result, iterations = _optimize(graph, initial, max_iterations)
    fallback = False
    if _suspect_solution(graph, result, iterations, max_iterations):
        # The filter's guess led Levenberg-Marquardt astray (e.g. the EKF diverged in an
        # outage): restart from iSAM2, whose incremental relinearisation is far more robust.
        # Relinearise at every update here: the start is known to be poor.
        isam, _, _ = _run_isam2(problem, progress, online_covariance=False, relinearize_skip=1)
        graph = _batch_graph(problem, None)
        retry, more = _optimize(graph, isam.calculateEstimate(), max_iterations)
        iterations += more
        if graph.error(retry) < graph.error(result):
            result, fallback = retry, True
    # Re-linearise the preintegration where the bias estimate moved far from zero.
    for _ in range(3):
        if not problem.repreintegrate(result, gyro_threshold=0.02, accel_threshold=0.3):
            break
        graph = _batch_graph(problem, None)
        result, more = _optimize(graph, result, max_iterations)
        iterations += more
    if problem.config.smoother.zupt and problem.quiet.any():
        speeds = np.array(
            [np.linalg.norm(result.atVector(V(k))) for k in range(problem.n_keyframes)]
        )
        with_stops = _batch_graph(problem, speeds)
        if problem.zupt_keyframes:
            graph = with_stops
            result, more = _optimize(graph, result, max_iterations)
            iterations += more
    solved = time.perf_counter()
    marginal = _marginal_function(graph, result)
    covariances = _marginal_covariances(problem, marginal, marginal, result, progress)
    states = _states_from_values(problem, result, covariances)
    trajectory = _to_trajectory(problem, states, "batch", smoothed=True)
    trajectory.timings.update(
        {"optimize": solved - started, "covariance": time.perf_counter() - solved}
    )
    trajectory.info.update(_gnss_report(problem, result))
    trajectory.info.update(_extra_states(result))
    trajectory.info.update(
        {
            "iterations": iterations,
            "zupt_keyframes": len(problem.zupt_keyframes),
            "restarted_from_isam2": fallback,
            "initial_error": graph.error(initial),
            "final_error": graph.error(result),
        }
    )
    return trajectory


def _run_isam2(
    problem: Problem,
    progress: bool,
    online_covariance: bool = True,
    relinearize_skip: int = RELINEARIZE_SKIP,
):
    """Incremental iSAM2, one update per keyframe.

    Returns (isam, online values, online covariances): each keyframe's state and covariance
    right after its own update. Cholesky first (fast); if it calls an update indeterminate
    (tight bias random walks against loose bias priors: the conditioning, not the problem,
    is at fault) the run restarts with QR.
    """
    try:
        return _run_isam2_with(problem, progress, online_covariance, "CHOLESKY", relinearize_skip)
    except _IndeterminateUpdate:
        return _run_isam2_with(problem, progress, online_covariance, "QR", relinearize_skip)


class _IndeterminateUpdate(Exception):
    pass


def _run_isam2_with(
    problem: Problem,
    progress: bool,
    online_covariance: bool,
    factorization: str,
    relinearize_skip: int,
):
    problem.zupt_keyframes.clear()
    params = gtsam.ISAM2Params()
    params.setRelinearizeThreshold(problem.config.smoother.isam2_relinearize_threshold)
    params.relinearizeSkip = relinearize_skip
    params.setFactorization(factorization)
    isam = gtsam.ISAM2(params)
    n = problem.n_keyframes
    online = {name: np.full((n, 3, 3), np.nan) for name in ("position", "velocity", "attitude")}
    online_values = gtsam.Values()
    align = problem.alignment
    state = gtsam.NavState(gtsam.Rot3(align.rotation), align.position, align.velocity)
    bias = gtsam.imuBias.ConstantBias()
    for k in tqdm(range(n), desc="iSAM2", unit="kf", disable=not progress, leave=False):
        graph = problem.prior_factors() if k == 0 else gtsam.NonlinearFactorGraph()
        new_values = gtsam.Values()
        if k > 0:
            state = problem.predict(k - 1, state, bias)
        graph.push_back(problem.keyframe_factors(k, float(np.linalg.norm(state.velocity()))))
        new_values.insert(X(k), state.pose())
        new_values.insert(V(k), state.velocity())
        new_values.insert(B(k), bias)
        problem.insert_extra_values(k, new_values, online_values)
        try:
            isam.update(graph, new_values)
        except RuntimeError as exc:
            if factorization == "CHOLESKY":
                raise _IndeterminateUpdate from None
            raise FginsError(f"iSAM2 update at keyframe {k} failed: {exc}") from None
        pose = isam.calculateEstimatePose3(X(k))
        velocity = isam.calculateEstimateVector(V(k))
        bias = isam.calculateEstimateConstantBias(B(k))
        state = gtsam.NavState(pose, velocity)
        online_values.insert(X(k), pose)
        online_values.insert(V(k), velocity)
        online_values.insert(B(k), bias)
        if online_covariance:
            try:
                attitude, position = _nav_covariances(
                    isam.marginalCovariance(X(k)), pose.rotation().matrix()
                )
                online["attitude"][k], online["position"][k] = attitude, position
                online["velocity"][k] = isam.marginalCovariance(V(k))
            except RuntimeError:
                if factorization == "CHOLESKY":
                    raise _IndeterminateUpdate from None
                # QR could not resolve this marginal either: leave it NaN (reported as unknown).
    # A few extra relinearisation passes let the final estimate settle like the batch one.
    for _ in range(3):
        try:
            isam.update()
        except RuntimeError:
            if factorization == "CHOLESKY":
                raise _IndeterminateUpdate from None
            break
    return isam, online_values, online


def smooth_isam2(problem: Problem, progress: bool = True) -> tuple[Trajectory, Trajectory]:
    """One iSAM2 update per keyframe. Returns (final smoothed, online filtered) trajectories."""
    started = time.perf_counter()
    isam, online_values, online = _run_isam2(problem, progress)
    incremental = time.perf_counter()
    result = isam.calculateEstimate()
    covariances = _marginal_covariances(
        problem, isam.marginalCovariance, isam.marginalCovariance, result, progress
    )
    final = _to_trajectory(
        problem, _states_from_values(problem, result, covariances), "isam2", smoothed=True
    )
    filtered = _to_trajectory(
        problem, _states_from_values(problem, online_values, online), "isam2-online", smoothed=False
    )
    final.info.update(_gnss_report(problem, result))
    final.info.update(_extra_states(result))
    final.timings.update(
        {"incremental": incremental - started, "final": time.perf_counter() - incremental}
    )
    filtered.timings.update({"incremental": incremental - started})
    return final, filtered


def smooth(
    dataset: Dataset,
    config: RunConfig,
    method: str = "batch",
    *,
    gnss_mask: np.ndarray | None = None,
    progress: bool = True,
) -> Trajectory:
    """Smooth ``dataset`` with ``method`` ('batch', 'isam2' or 'isam2-online')."""
    started = time.perf_counter()
    problem = build_problem(dataset, config, gnss_mask, progress=progress)
    built = time.perf_counter()
    if method == "batch":
        trajectory = smooth_batch(problem, progress)
    elif method in ("isam2", "isam2-online"):
        final, filtered = smooth_isam2(problem, progress)
        trajectory = final if method == "isam2" else filtered
        trajectory.info["online"] = filtered if method == "isam2" else final
    else:
        raise FginsError(f"unknown factor-graph method {method!r}")
    trajectory.timings["build"] = built - started
    trajectory.timings["total"] = time.perf_counter() - started
    return trajectory
