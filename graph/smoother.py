"""Batch (Levenberg-Marquardt) and incremental (iSAM2) smoothing of a dataset.

Entry point: :func:`smooth`. Both methods share the same problem (keyframes, factors,
priors); iSAM2 also yields the online estimate: each keyframe's state as it was right after
its own update, i.e. what a real-time system would have had.

Every factor the optimiser evaluates runs in C++: the land-vehicle constraints, which GTSAM
has no factor for, enter as factors linearised at an estimate and rebuilt in an outer loop
(:mod:`fgins.factors.vehicle`), so one linearisation costs O(K), not O(K^2).

Honesty: every solve checks that its error is finite, that it made progress and converged,
and how consistent the fit is (chi-square per degree of freedom); the result says which
solver produced it, how, and any fallback taken. A solve that cannot be trusted is an error,
never an initial guess under the method's name.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Protocol

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X

from fgins.config import RunConfig
from fgins.datatypes import Dataset, FginsError, Trajectory
from fgins.factors import gnss as gnss_model
from fgins.factors import odometer as odometer_model
from fgins.factors import stationary
from fgins.factors import vehicle as vehicle_model
from fgins.factors.values import put_bias, put_double, put_pose, put_vector
from fgins.graph.keyframe_filter import keyframe_filter
from fgins.graph.output import KeyframeStates, densify
from fgins.graph.problem import (
    Problem,
    bias_estimates,
    build_problem,
    rotations_and_velocities,
)


class KeyframeGuess(Protocol):
    """States at the keyframe times (K rows): what an initial-guess provider returns."""

    rotation: np.ndarray  # (K, 3, 3) body -> ENU
    position: np.ndarray  # (K, 3)
    velocity: np.ndarray  # (K, 3)
    accel_bias: np.ndarray  # (K, 3)
    gyro_bias: np.ndarray  # (K, 3)


# keyframe times (K,) -> candidate states there, best first; chosen and supplied by the
# pipeline (a filter that matches the input, a guess from the GNSS track), so graph/ does not
# depend on baseline/. The batch starts from the candidate that fits best (_held_fit_error).
InitialGuess = Callable[[np.ndarray], Sequence[KeyframeGuess]]

# A fix whose whitened residual exceeds this at the solution (chi-square, 3 dof, 99.9 %) has a
# large residual; only a robust kernel actually down-weights it.
LARGE_RESIDUAL_WHITENED = 4.03
RELINEARIZE_SKIP = 10  # GTSAM's default: relinearisation checks every 10 updates
ISAM2_WILDFIRE_THRESHOLD = 0.01  # see _run_isam2_with
ISAM2_WINDOW_S = 10.0  # keyframes the running iSAM2 holds: see _Window
ISAM2_MARGINALISE_EVERY = RELINEARIZE_SKIP  # updates (with the relinearisation ones)
ISAM2_FINAL_ROUNDS = 5  # rebuilds of the whole graph at most in the final pass
ISAM2_SETTLED_RELATIVE_ERROR = 1e-3  # a final Gauss-Newton step that gains less: converged
# Re-preintegrate an interval when its bias estimate moved this far from the one it was
# integrated about (GTSAM's bias correction is first order).
REPREINTEGRATE_GYRO_RAD_S = 0.01
REPREINTEGRATE_ACCEL_M_S2 = 0.2
# An outer round that changes the error by less than this (relative) has settled, whatever
# small bias or attitude moves remain (they are then below what the data can resolve).
SETTLED_RELATIVE_ERROR = 1e-5
# The linearised vehicle constraints are rebuilt until no attitude moves more than this.
RELINEARIZE_ATTITUDE_RAD = 1e-3
RELINEARIZE_VELOCITY_M_S = 0.05
# While the linearisation still moves, every LM iteration is followed by a rebuild of the
# linearised factors (vectorised, O(K)): the iterations then follow the exact Jacobians, as
# with a nonlinear factor, and converge as fast. Once nothing moves LM gets its full budget.
MAX_OUTER_ROUNDS = 40
ROUND_ITERATIONS = 1
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


def _check_finite(error: float, what: str, solver: str) -> None:
    if not math.isfinite(error):
        raise FginsError(
            f"{solver}: the factor graph's error {what} is not finite (a NaN or infinite "
            "measurement or noise value reached a factor); check the inputs and the sensor "
            "configuration"
        )


def _dof(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> int:
    dims = sum(graph.at(i).dim() for i in range(graph.size()) if graph.exists(i))
    return int(dims - values.dim())


# -- initial values ------------------------------------------------------------------------


def _values_from_states(problem: Problem, guess: KeyframeGuess) -> gtsam.Values:
    values = gtsam.Values()
    for k in range(problem.n_keyframes):
        put_pose(values, X(k), gtsam.Pose3(gtsam.Rot3(guess.rotation[k]), guess.position[k]))
        put_vector(values, V(k), guess.velocity[k])
        put_bias(values, B(k), gtsam.imuBias.ConstantBias(guess.accel_bias[k], guess.gyro_bias[k]))
        problem.insert_extra_values(k, values)
    return values


def _usable_guess(guess: KeyframeGuess | None, n: int) -> bool:
    if guess is None:
        return False
    arrays = (guess.rotation, guess.position, guess.velocity, guess.accel_bias, guess.gyro_bias)
    return all(len(a) == n and np.all(np.isfinite(a)) for a in arrays)


@dataclass
class Start:
    """A start for LM: initial values and what made them (the problem's preintegration is
    about their biases when they are the current start)."""

    values: gtsam.Values
    source: str
    guess: KeyframeGuess | None = None  # to re-preintegrate about when taken up again

    def take(self, problem: Problem, progress: bool = False) -> gtsam.Values:
        """Preintegrate about this start's biases (if it has its own) and return its values."""
        if self.guess is not None:
            problem.preintegrate_all(self.guess.accel_bias, self.guess.gyro_bias, progress)
        return self.values


def initial_values(
    problem: Problem, initial_guess: InitialGuess | None, progress: bool
) -> tuple[Start, list[Start]]:
    """The start for LM, and the other candidates (for a restart), best first.

    Without ``initial_guess`` (an IMU): the keyframe EKF over the graph's own factors
    (:mod:`fgins.graph.keyframe_filter`), which preintegrates every interval about its
    filtered bias as it goes. With one (for an accelerometer array: the pipeline's ekf18 and
    the GNSS-track guess): every usable candidate, each interval preintegrated about its
    biases; LM starts from the one that fits best (:func:`_held_fit_error`). If none gives a
    usable start:
    GNSS-reset dead reckoning about zero bias. On return the preintegration is about the
    start's biases.
    """
    n = problem.n_keyframes
    try:
        if initial_guess is None:
            return Start(keyframe_filter(problem, progress), "keyframe EKF"), []
        guesses = list(initial_guess(problem.segments.times))
    except FginsError as exc:
        problem.info.setdefault("fit_warnings", []).append(
            f"the initial-guess filter failed ({exc}); started from dead reckoning instead"
        )
        guesses = []
    starts = [
        Start(_values_from_states(problem, guess), getattr(guess, "method", "filter"), guess)
        for guess in guesses
        if _usable_guess(guess, n)
    ]
    if len(starts) > 1:
        errors = [_held_fit_error(problem, start.take(problem, progress)) for start in starts]
        order = np.argsort(np.nan_to_num(np.array(errors), nan=np.inf), kind="stable")
        if order[0] != len(starts) - 1:  # the last one evaluated is preintegrated already
            starts[order[0]].take(problem, progress)
        starts = [starts[i] for i in order]
        problem.info["initial_guess_errors"] = {
            starts[j].source: float(errors[i]) for j, i in enumerate(order)
        }
    elif starts:
        starts[0].take(problem, progress)
    if starts:
        return starts[0], starts[1:]
    zeros = np.zeros((n, 3))
    problem.preintegrate_all(zeros, zeros, progress)
    return Start(_dead_reckoning_guess(problem), "dead reckoning"), []


# Candidate starts are compared with their attitudes and biases held this tightly.
HELD_ATTITUDE_RAD = 1e-5
HELD_BIAS = 1e-7
HELD_FIT_ITERATIONS = 5


def _held_fit_error(problem: Problem, values: gtsam.Values) -> float:
    """The graph error once a candidate's positions and velocities are fitted to its own
    attitudes and biases (held by tight priors): how well what is hard to find (attitude,
    rate bias) explains the data. The error at the raw guess says little about that: it is
    dominated by how the guess's positions and velocities fit each other (a track guess
    interpolates fixes, a filter's states are propagated), which a few iterations put right
    for any start; a heading 40 deg off barely changes it (tests/test_track_guess.py)."""
    graph = _full_graph(problem, _nonlinear_graph(problem, None), values)
    held = gtsam.NonlinearFactorGraph()
    held.push_back(graph)
    pose_noise = gtsam.noiseModel.Diagonal.Sigmas(
        np.r_[np.full(3, HELD_ATTITUDE_RAD), np.full(3, 1e6)]  # Pose3 tangent: rotation first
    )
    bias_noise = gtsam.noiseModel.Isotropic.Sigma(6, HELD_BIAS)
    for k in range(problem.n_keyframes):
        held.add(gtsam.PriorFactorPose3(X(k), values.atPose3(X(k)), pose_noise))
        held.add(gtsam.PriorFactorConstantBias(B(k), values.atConstantBias(B(k)), bias_noise))
    try:
        fitted = _lm(held, values, HELD_FIT_ITERATIONS, 1e-5, "batch LM")[0]
    except (FginsError, RuntimeError):
        return math.inf  # a start whose error is not even finite
    error = graph.error(fitted)
    return error if math.isfinite(error) else math.inf


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
        put_pose(values, X(k), state.pose())
        put_vector(values, V(k), state.velocity())
        put_bias(values, B(k), bias)
        problem.insert_extra_values(k, values)
    return values


def _finite_difference_velocity(problem: Problem) -> np.ndarray:
    """GNSS velocity where given, else central differences over neighbours <= 5 s apart."""
    keyed = problem.gnss_at[problem.gnss_at >= 0]
    t = np.full(len(problem.gnss_enu), np.nan)
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


# -- reporting -----------------------------------------------------------------------------


def _extra_states(values: gtsam.Values) -> dict[str, object]:
    """Estimated non-navigation states worth reporting (odometer scale-factor error, the
    NHC misalignment: the angle between the vehicle's x axis as configured and its
    velocity, i.e. a mounting error, lateral (yaw) and vertical (pitch), degrees)."""
    out: dict[str, object] = {}
    if values.exists(odometer_model.scale_key()):
        out["odometer_scale_error"] = float(values.atDouble(odometer_model.scale_key()))
    if values.exists(vehicle_model.misalignment_key(0)):
        lateral, vertical = np.degrees(values.atVector(vehicle_model.misalignment_key(0)))
        drifting = values.exists(vehicle_model.misalignment_key(1))  # one key per keyframe
        out["nhc_misalignment_deg"] = (
            f"lateral {lateral:+.2f}, vertical {vertical:+.2f}"
            + (" (at the start; it drifts)" if drifting else "")
        )
    return out


def _gnss_report(problem: Problem, values: gtsam.Values) -> dict[str, object]:
    times, norms = problem.gnss_whitened_residuals(values)
    large = times[norms > LARGE_RESIDUAL_WHITENED]
    gnss = problem.config.gnss
    kernel = "Cauchy" if gnss.cauchy_k is not None else "Huber" if gnss.huber_k else None
    listed = (
        ": t - t0 = "
        + ", ".join(f"{t - problem.dataset.t0:.1f}" for t in large[:20])
        + (" ..." if len(large) > 20 else "")
        if len(large)
        else ""
    )
    if kernel == "Cauchy":
        # A redescending kernel leaves such fixes almost no weight: they are rejected.
        text = f"GNSS outliers: {len(large)} of {len(times)} fixes rejected by the Cauchy kernel"
    elif kernel == "Huber":
        text = (
            f"GNSS large residuals: {len(large)} of {len(times)} fixes above "
            f"{LARGE_RESIDUAL_WHITENED} sigma, down-weighted by the Huber kernel"
        )
    else:
        text = (
            f"GNSS large residuals: {len(large)} of {len(times)} fixes above "
            f"{LARGE_RESIDUAL_WHITENED} sigma (no robust kernel: all kept at full weight)"
        )
    return {
        "gnss_rejected_times": [float(t) for t in large] if kernel == "Cauchy" else [],
        "gnss_large_residual_times": [float(t) for t in large],
        "gnss_rejected": text + listed,
        **_dop_model_scale(problem, norms),
    }


def _lever_arm_report(
    problem: Problem, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values
) -> dict[str, object]:
    """Does the configured GNSS lever arm fit? One Gauss-Newton step from the solution with
    the arm free (``GPSFactorArmCalib``, a loose 10 m prior at the configured arm) gives the
    arm the data want and its covariance; a change beyond 10 sigma and 0.5 m is reported.
    (The sigma takes the fixes' errors as white; real ones are correlated over seconds, and
    a correctly configured drive can sit at 4-5 sigma: KITTI's arm fits 0.23 +- 0.06 m
    forward of the configured zero.)

    An arm left out (or wrong) is a body-fixed offset between the IMU and the antenna: on
    straights the trajectory absorbs it, in turns, banks and climbs it turns with the body
    and the fit degrades without any one residual standing out (an aircraft with an
    unconfigured 2.5 m arm: position z 2.9 inside outages, chi2/dof 1.3, nothing said). An
    along-track offset is also what fixes late or early by ``offset / speed`` look like."""
    keyframes = np.flatnonzero(problem.gnss_at >= 0)
    if len(keyframes) < MIN_FIXES_FOR_SCALE:
        return {}
    position_types = (gtsam.GPSFactor, gtsam.GPSFactorArm)
    check = gtsam.NonlinearFactorGraph()
    for i in range(graph.size()):
        if graph.exists(i) and not isinstance(graph.at(i), position_types):
            check.add(graph.at(i))
    config = problem.config.gnss
    for k in keyframes:
        g = int(problem.gnss_at[k])
        check.add(gnss_model.lever_arm_check_factor(
            X(int(k)), problem.gnss_enu[g], problem.gnss_sigma[g], config
        ))  # fmt: skip
    check.add(gnss_model.lever_arm_prior(config, LEVER_ARM_PRIOR_M))
    point = gtsam.Values(values)
    key = gnss_model.lever_arm_key()
    configured = np.asarray(config.lever_arm_m, dtype=float)
    point.insert(key, gtsam.Point3(configured))
    try:
        tree = check.linearize(point).eliminateMultifrontal(
            gtsam.Ordering.OrderingType.COLAMD, gtsam.EliminateQR
        )
        change = np.asarray(tree.optimize().at(key))
        covariance = np.asarray(tree.marginalCovariance(key))
        statistic = float(change @ np.linalg.solve(covariance, change))
    except (RuntimeError, np.linalg.LinAlgError):
        return {}
    if not np.isfinite(statistic):
        return {}
    fitted = configured + change
    sigma = np.sqrt(np.diag(covariance))
    out: dict[str, object] = {
        "gnss_lever_arm_fit_m": [float(x) for x in fitted],
        "gnss_lever_arm_fit_sigma_m": [float(x) for x in sigma],
    }
    if statistic > LEVER_ARM_CHI2 and np.linalg.norm(change) > LEVER_ARM_MIN_M:
        shown = ", ".join(f"{x:.2f}" for x in fitted)
        out["fit_warnings"] = [
            f"GNSS lever arm: the fixes fit an antenna at [{shown}] m (IMU axes; +-"
            f"{', '.join(f'{x:.2f}' for x in sigma)}), not the configured "
            f"{list(config.lever_arm_m)} ([gnss] lever_arm_m): measure and set it (an "
            "offset along the forward axis is also what fixes late or early by offset / "
            "speed look like: check the time bases)"
        ]
    return out


LEVER_ARM_PRIOR_M = 10.0
LEVER_ARM_CHI2 = 100.0  # ~10 sigma in one direction (chi-square with 3 dof)
LEVER_ARM_MIN_M = 0.5


def _dop_model_scale(problem: Problem, norms: np.ndarray) -> dict[str, object]:
    """How the fixes whose sigmas come from UERE x DOP fit against those sigmas.

    Without GST or a covariance in the data the sigmas are a model (3 m x HDOP for an
    autonomous fix). A receiver much better than that makes every reported sigma that much
    too large, and the overall chi-square, diluted by the IMU's, hides it (0.06 on a drive
    whose fixes scatter by 1 m: 3x pessimistic). The smoothed residuals are somewhat smaller
    than the fixes' errors (the fit follows them), so only a whitened RMS below 0.4 is
    reported (white errors: the sigmas are then at least 2.5x too large; slow errors, which
    the fit follows, also give small residuals, so the warning names both)."""
    modelled = problem.gnss_sigma_modelled[problem.gnss_used]
    out: dict[str, object] = {}
    own = ~modelled
    if own.sum() >= MIN_FIXES_FOR_SCALE:
        own_scale = float(np.sqrt(np.mean(norms[own] ** 2) / 3.0))
        out["gnss_data_sigma_whitened_rms"] = own_scale
        if own_scale < DATA_SIGMA_ABSURD:
            out["fit_warnings"] = [
                f"GNSS: {int(own.sum())} fixes carry sigmas of their own (std columns, GST, a "
                f"covariance) and fit {1.0 / max(own_scale, 1e-9):.0f}x better than them "
                f"(whitened residual RMS {own_scale:.3f}): a unit (cm given as m?) or a "
                "receiver's sigma far too pessimistic; the reported uncertainties are that large"
            ]
    if modelled.sum() < MIN_FIXES_FOR_SCALE:
        return out
    scale = float(np.sqrt(np.mean(norms[modelled] ** 2) / 3.0))
    out["gnss_dop_model_whitened_rms"] = scale
    if scale < DOP_MODEL_PESSIMISTIC:
        out["fit_warnings"] = [*out.get("fit_warnings", []),  # type: ignore[misc]
            f"GNSS: {int(modelled.sum())} fixes have sigmas from UERE x DOP (no GST or "
            f"covariance in the data) and residuals of only {scale:.2f} of them (whitened "
            "RMS): either the receiver is better than the UERE table and the reported "
            f"uncertainties are up to {1.0 / max(scale, 1e-9):.1f}x pessimistic (set "
            "[gnss.uere_m], e.g. autonomous = 1.0, or [gnss] sigma_m), or its errors are "
            "slow and the fit follows them"
        ]
    return out


MIN_FIXES_FOR_SCALE = 30
DOP_MODEL_PESSIMISTIC = 0.4
# A receiver's own sigmas are often pessimistic (u-blox hAcc: 2-3x); 10x is a unit.
DATA_SIGMA_ABSURD = 0.1


def _vehicle_fit_report(problem: Problem, values: gtsam.Values) -> dict[str, object]:
    """How well the land-vehicle constraints fit while moving (speed > 3 m/s): a wrong or
    missing IMU mounting shows as vehicle-frame lateral/vertical velocities far beyond what a
    car does. The statistic uses fixed reference sigmas (0.1 m/s lateral, 0.2 m/s vertical,
    whatever the configured constraint sigmas), RMS over both: 0.1 on a simulated car, 0.5 on
    the KITTI drive, 2.4 with the mounting's yaw 5 deg wrong, 13.5 with a 20/-10/35 deg
    mounting left out; a roll error is invisible to it (and harmless)."""
    moving_k = problem.nhc_keyframes
    if len(moving_k) == 0:
        return {}
    rotation = np.array([values.atPose3(X(int(k))).rotation().matrix() for k in moving_k])
    velocity = np.array([values.atVector(V(int(k))) for k in moving_k])
    moving = np.linalg.norm(velocity, axis=1) > 3.0
    if moving.sum() < 10:
        return {}
    select = vehicle_model.nhc_rows(problem.imu_to_vehicle)
    residual = vehicle_model.nhc_residuals(rotation[moving], velocity[moving], select)
    statistic = float(np.sqrt(np.mean((residual / NHC_REFERENCE_SIGMAS) ** 2)))
    out: dict[str, object] = {"nhc_fit_rms": statistic}
    if statistic > NHC_FIT_WARN:
        lateral, vertical = np.sqrt(np.mean(residual**2, axis=0))
        out["fit_warnings"] = [
            f"vehicle constraints fit poorly while moving: lateral/vertical velocity RMS "
            f"{lateral:.2f}/{vertical:.2f} m/s in the vehicle frame (a car: ~0.1/0.05): the IMU "
            f"mounting ([smoother] imu_to_vehicle_rpy_deg = "
            f"{list(problem.config.smoother.imu_to_vehicle_rpy_deg)}) is probably wrong or "
            "missing, or the vehicle is not a car (--vehicle)"
        ]
    return out


NHC_REFERENCE_SIGMAS = np.array([0.1, 0.2])
NHC_FIT_WARN = 1.5


def _solver_report(report: SolveReport) -> dict[str, object]:
    warnings = list(report.notes)
    if report.chi2_per_dof > CHI2_WARN:
        warnings.append(
            f"{report.solver}: the fit is inconsistent with the noise model (chi2/dof "
            f"{report.chi2_per_dof:.1f}; ~1 expected): the reported sigmas are too small for "
            "this data; "
            + (report.blame or "check the IMU preset (--imu-preset, --config) and the GNSS sigmas")
        )
    if report.chi2_per_dof < CHI2_FAR_TOO_GOOD:
        warnings.append(
            f"{report.solver}: the fit is far better than the noise model says (chi2/dof "
            f"{report.chi2_per_dof:.3g}; ~1 expected, 0.1-0.6 usual): the reported sigmas are "
            "far too large; check the [imu] noise values (their units) and the GNSS sigmas"
        )
    return {
        "solver": report.line(),
        "iterations": report.iterations,
        "outer_rounds": report.rounds,
        "repreintegrated_intervals": report.repreintegrated,
        "initial_error": report.initial_error,
        "final_error": report.final_error,
        "chi2_per_dof": report.chi2_per_dof,
        "dof": report.dof,
        "fallback": report.fallback,
        "fit_warnings": warnings,
    }


def _merge_info(trajectory: Trajectory, *parts: dict[str, object]) -> None:
    for part in parts:
        part = dict(part)
        warnings = part.pop("fit_warnings", [])
        trajectory.info.update(part)
        if warnings:
            trajectory.info["fit_warnings"] = [*trajectory.info.get("fit_warnings", []), *warnings]


# -- states, covariances, output --------------------------------------------------------------


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
    cannot be computed: reported, the rest of the output is still valid)."""
    from tqdm import tqdm

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


def _covariance_report(covariances: dict[str, np.ndarray]) -> dict[str, object]:
    """Reported sigmas must be positive and finite; say where they are not."""
    variances = np.diagonal(covariances["position"], axis1=1, axis2=2)
    bad = ~np.all(np.isfinite(variances) & (variances > 0), axis=1)
    if not bad.any():
        return {}
    return {
        "covariance_unknown_keyframes": int(bad.sum()),
        "fit_warnings": [
            f"position uncertainty could not be computed at {int(bad.sum())} of {len(bad)} "
            "keyframes (std_* is NaN there): the system is indeterminate there"
        ],
    }


def _to_trajectory(
    problem: Problem, states: KeyframeStates, method: str, *, smoothed: bool
) -> Trajectory:
    imu = problem.dataset.imu
    dense = densify(  # densify picks each segment's sample itself (segments.sample)
        problem.segments,
        imu.accel,
        imu.gyro,
        states,
        problem.interval_gravity,
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


# -- batch ---------------------------------------------------------------------------------


def _nonlinear_graph(
    problem: Problem, speeds: np.ndarray | None, imu_index: list[int] | None = None
) -> gtsam.NonlinearFactorGraph:
    """Every C++ nonlinear factor; ZUPTs only where ``speeds`` (a solution's) confirm a stop.
    ``imu_index`` (if given) receives the graph index of each interval's IMU factor."""
    problem.zupt_keyframes.clear()
    graph = problem.prior_factors()
    for k in range(problem.n_keyframes):
        if k > 0 and imu_index is not None:
            imu_index.append(graph.size())  # keyframe_factors puts the IMU factor first
        graph.push_back(problem.keyframe_factors(k, None if speeds is None else float(speeds[k])))
    return graph


def _full_graph(
    problem: Problem, nonlinear: gtsam.NonlinearFactorGraph, values: gtsam.Values
) -> gtsam.NonlinearFactorGraph:
    graph = gtsam.NonlinearFactorGraph()
    graph.push_back(nonlinear)
    graph.push_back(problem.linear_factors(values))
    return graph


def _lm(
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
    _check_finite(start_error, "at the initial guess", solver)
    result = optimizer.optimize()
    return result, optimizer.iterations(), optimizer.lambda_(), start_error, optimizer.error()


def _linearisation_moved(problem: Problem, before: gtsam.Values, after: gtsam.Values) -> bool:
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


def _solve(
    problem: Problem, values: gtsam.Values, speeds: np.ndarray | None, report: SolveReport
) -> tuple[gtsam.Values, gtsam.NonlinearFactorGraph]:
    """Levenberg-Marquardt alternating with re-preintegration and relinearisation of the
    vehicle constraints until neither changes anything. Returns (solution, the exact graph
    at it)."""
    max_iterations = problem.config.smoother.batch_max_iterations
    has_linear = problem.has_linear_factors
    imu_index: list[int] = []
    nonlinear = _nonlinear_graph(problem, speeds, imu_index)
    settled = False
    previous_error = math.inf
    damping = 1e-5  # carried across rounds: LM's trust region survives the rebuilds
    steady_rounds = 0
    for _ in range(MAX_OUTER_ROUNDS):
        graph = _full_graph(problem, nonlinear, values)
        # One iteration per rebuild while the linearisation moves; a slow, poorly observable
        # problem (a gyro-free IMU) that keeps moving gets longer rounds as they go on.
        escalated = ROUND_ITERATIONS * (1 + report.rounds // 10) ** 2
        budget = max_iterations if (settled or not has_linear) else escalated
        result, iterations, damping, start_error, end_error = _lm(
            graph, values, budget, damping, report.solver
        )
        if math.isnan(report.initial_error):
            report.initial_error = start_error
        report.iterations += iterations
        report.rounds += 1
        _check_finite(end_error, "after Levenberg-Marquardt", report.solver)
        converged = iterations < budget
        redone_intervals = problem.repreintegrate(
            result, REPREINTEGRATE_GYRO_RAD_S, REPREINTEGRATE_ACCEL_M_S2
        )
        redone = len(redone_intervals)
        report.repreintegrated += redone
        moved = has_linear and _linearisation_moved(problem, values, result)
        values = result
        for i in redone_intervals:  # only their IMU factors change
            nonlinear.replace(imu_index[i], problem.imu_factor(int(i)))
        steady = abs(previous_error - end_error) <= SETTLED_RELATIVE_ERROR * end_error
        steady_rounds = steady_rounds + 1 if steady else 0
        previous_error = end_error
        # Done when LM converged on a linearisation that no longer moves, or when rebuilds
        # stopped changing the error at all (twice in a row).
        if (converged and (steady or (not redone and not moved))) or steady_rounds >= 2:
            break
        if not redone and not moved:
            settled = True  # only iterations are missing: give LM its full budget
    else:
        report.converged = False
    graph = _full_graph(problem, nonlinear, values)
    return values, graph


def _finish(report: SolveReport, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
    report.final_error = graph.error(values)
    _check_finite(report.final_error, "at the solution", report.solver)
    report.dof = _dof(graph, values)
    if report.chi2_per_dof > CHI2_WARN:
        report.blame = _error_blame(graph, values)


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


def _error_blame(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> str:
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


def _fail_if_diverged(report: SolveReport) -> None:
    if report.chi2_per_dof > CHI2_FAIL:
        other = "--method batch" if report.solver.startswith("iSAM2") else "--method isam2"
        check = report.blame or "check the IMU preset and the axis and unit conventions of the IMU data"
        raise FginsError(
            f"{report.solver} diverged: the solution does not fit the data (chi2/dof "
            f"{report.chi2_per_dof:.3g}, ~1 expected); no output written. {check[0].upper()}"
            f"{check[1:]}; or try {other}"
        )


def _suspect(report: SolveReport) -> bool:
    return not report.converged or report.chi2_per_dof > CHI2_SUSPECT


def _solve_from(
    problem: Problem, initial: gtsam.Values
) -> tuple[SolveReport, gtsam.Values, gtsam.NonlinearFactorGraph]:
    report = SolveReport(solver="batch LM")
    result, graph = _solve(problem, initial, None, report)
    _finish(report, graph, result)
    return report, result, graph


def _fall_back(
    problem: Problem,
    source: str,
    others: list[Start],
    report: SolveReport,
    result: gtsam.Values,
    graph: gtsam.NonlinearFactorGraph,
) -> tuple[SolveReport, gtsam.Values, gtsam.NonlinearFactorGraph]:
    """The first start led LM to an unconverged or inconsistent fit (e.g. the filter
    diverged in an outage, or with sparse GNSS): try the other candidate guesses, then
    GNSS-reset dead reckoning, then iSAM2 (whose incremental relinearisation follows a poor
    start far better), and keep the first consistent fit, else the one with the least error.
    Says which it took."""
    first = report

    def dead_reckoning() -> gtsam.Values:
        zeros = np.zeros((problem.n_keyframes, 3))
        problem.preintegrate_all(zeros, zeros, False)
        return _dead_reckoning_guess(problem)

    def isam2() -> gtsam.Values:
        return _run_isam2(problem, False, online_covariance=False, relinearize_skip=1)[1]

    best = (report, result, graph, source)
    restarts: list[tuple[str, Callable[[], gtsam.Values]]] = [
        (other.source, lambda other=other: other.take(problem)) for other in others
    ]
    restarts += [("dead reckoning", dead_reckoning), ("iSAM2", isam2)]
    for name, start in restarts:
        if name == source:
            continue
        try:
            candidate = (*_solve_from(problem, start()), name)
        except FginsError:
            continue  # this start cannot even be computed: try the next
        if candidate[0].final_error < best[0].final_error:
            best = candidate
        if not _suspect(candidate[0]):
            break
    report, result, graph, taken = best
    # The preintegration must be the one about the kept solution's biases.
    bias = bias_estimates(result, problem.n_keyframes)
    problem.preintegrate_all(bias[:, :3], bias[:, 3:], False)
    if taken != source:
        report.initial_error = first.initial_error
        report.iterations += first.iterations
        report.rounds += first.rounds
        report.fallback = (
            f"the {source} initial guess gave an unconverged or inconsistent fit "
            f"(chi2/dof {first.chi2_per_dof:.1f}); restarted from {taken}"
        )
        graph = _full_graph(problem, _nonlinear_graph(problem, None), result)
        _finish(report, graph, result)
    return report, result, graph


def _stop_speeds(
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
    marginal = _marginal_function(graph, result)
    for k in slow:
        sigma = stationary.speed_sigma(marginal(V(k)))
        if problem.speed_confirms_stop(float(speeds[k]), sigma):
            out[k] = speeds[k]
    return out


def smooth_batch(
    problem: Problem, progress: bool = True, initial_guess: InitialGuess | None = None
) -> Trajectory:
    """Levenberg-Marquardt over the whole drive, covariances from the marginals.

    With ZUPT on, two passes: the first solves without zero-velocity factors; stops are then
    the quiet-IMU keyframes where that solution's speed is low, and the second pass adds
    their ZUPTs. Deciding stops from the initial guess instead would let a guess that is
    wrong in an outage plant a false stop, which no optimiser recovers from.
    """
    started = time.perf_counter()
    start, others = initial_values(problem, initial_guess, progress)
    source = start.source
    report, result, graph = _solve_from(problem, start.values)
    if _suspect(report):
        report, result, graph = _fall_back(problem, source, others, report, result, graph)
    report.start = source  # a restart says so in report.fallback
    if problem.config.smoother.zupt and problem.stop_candidates.any():
        speeds = _stop_speeds(problem, graph, result)
        problem.zupt_keyframes.clear()
        if np.isfinite(speeds).any():
            zupt_report = SolveReport(solver="batch LM", initial_error=report.initial_error)
            result, graph = _solve(problem, result, speeds, zupt_report)
            report.iterations += zupt_report.iterations
            report.rounds += zupt_report.rounds
            report.repreintegrated += zupt_report.repreintegrated
            report.converged = zupt_report.converged
            _finish(report, graph, result)
    _fail_if_diverged(report)
    if not report.converged:
        raise FginsError(
            f"batch: Levenberg-Marquardt did not converge ({report.iterations} iterations in "
            f"{report.rounds} rounds, error {report.initial_error:.4g} -> "
            f"{report.final_error:.4g}); no output written. Try --method isam2, or check the "
            "IMU noise settings"
        )
    solved = time.perf_counter()
    marginal = _marginal_function(graph, result)
    covariances = _marginal_covariances(problem, marginal, marginal, result, progress)
    states = _states_from_values(problem, result, covariances)
    trajectory = _to_trajectory(problem, states, "batch", smoothed=True)
    trajectory.timings.update(
        {"optimize": solved - started, "covariance": time.perf_counter() - solved}
    )
    _merge_info(
        trajectory,
        _gnss_report(problem, result),
        _lever_arm_report(problem, graph, result),
        _extra_states(result),
        _solver_report(report),
        _vehicle_fit_report(problem, result),
        _covariance_report(covariances),
        {
            "initial_guess": source,
            "zupt_keyframes": len(problem.zupt_keyframes),
            "restarted_from_isam2": report.fallback is not None,
            "python_callback_factors": _callback_factors(graph),
        },
    )
    return trajectory


def _callback_factors(graph: gtsam.NonlinearFactorGraph) -> int:
    """Factors whose evaluation calls back into Python (must stay 0: see module docs)."""
    return sum(
        isinstance(graph.at(i), gtsam.CustomFactor) for i in range(graph.size()) if graph.exists(i)
    )


# -- iSAM2 ---------------------------------------------------------------------------------


class _IndeterminateUpdate(Exception):
    pass


def _run_isam2(
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
    linear_point = gtsam.Values()  # where the linearised factors were made
    update_s = np.zeros(n)
    preintegrate_s = np.zeros(n)
    report = SolveReport(solver="iSAM2")
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
        keyframe = problem.keyframe_factors(
            k, float(np.linalg.norm(state.velocity())), speed_sigma=speed_sigma
        )
        if k > 0:
            imu_index[k - 1] = nonlinear.size() + graph.size()  # the IMU factor comes first
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
                attitude, position = _nav_covariances(
                    joint.at(X(k), X(k)), pose.rotation().matrix()
                )
                online["attitude"][k], online["position"][k] = attitude, position
                online["velocity"][k] = joint.at(V(k), V(k))
            except RuntimeError:
                if factorization == "CHOLESKY":
                    raise _IndeterminateUpdate from None
                # QR could not resolve this marginal either: left NaN (reported as unknown).
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
        redone = problem.repreintegrate(estimate, REPREINTEGRATE_GYRO_RAD_S, REPREINTEGRATE_ACCEL_M_S2)
        for i in redone:
            nonlinear.replace(imu_index[int(i)], problem.imu_factor(int(i)))
        report.repreintegrated += len(redone)
        has_linear = problem.has_linear_factors
        settled = not math.isfinite(step_from) or (
            step_from - isam.getFactorsUnsafe().error(estimate)
            < ISAM2_SETTLED_RELATIVE_ERROR * step_from
        )
        if not (windowed and round_ == 0) and not len(redone) and settled and not (
            has_linear and _linearisation_moved(problem, linear_point, estimate)
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
    factors = _compact(isam.getFactorsUnsafe())
    report.initial_error = float("nan")
    report.final_error = factors.error(final)
    _check_finite(report.final_error, "at the final estimate", "iSAM2")
    report.dof = _dof(factors, final)
    if report.chi2_per_dof > CHI2_WARN:
        report.blame = _error_blame(factors, final)
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
    (:func:`_stop_speeds`), and re-solve with those. Unchanged stops keep ``isam``."""
    online_stops = set(problem.zupt_keyframes)
    estimate = _estimate(isam, factorization)
    free, free_estimate, _ = _isam2_solve_full(problem, None, estimate, params, factorization)
    speeds = _stop_speeds(problem, free, free_estimate)
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
        graph = _full_graph(problem, _nonlinear_graph(problem, speeds), estimate)
        isam = gtsam.ISAM2(params)
        _isam2_step(isam, factorization, "stop re-decision", graph, estimate)
        for _ in range(2):
            _isam2_step(isam, factorization, "stop re-decision")
        moved = problem.has_linear_factors and _linearisation_moved(
            problem, estimate, _estimate(isam, factorization)
        )
        estimate = _estimate(isam, factorization)
        if not moved:
            break
    graph = _full_graph(problem, _nonlinear_graph(problem, speeds), estimate)
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


def smooth_isam2(
    problem: Problem, progress: bool = True, *, online_first: bool = False
) -> tuple[Trajectory, DeferredTrajectory]:
    """One iSAM2 update per keyframe. Returns (final smoothed, online filtered) trajectories,
    the second made on first use (``online_first``: the other way round)."""
    started = time.perf_counter()
    isam, result, online_states, online, report, update_s = _run_isam2(problem, progress)
    if _suspect(report):
        # Relinearising at every update follows a poor start (large biases) much better.
        retry = _run_isam2(problem, progress, relinearize_skip=1)
        if retry[4].final_error < report.final_error:
            isam, result, online_states, online, report, update_s = retry
            report.fallback = "relinearised at every update (the default schedule diverged)"
    _fail_if_diverged(report)
    incremental = time.perf_counter()
    report.notes = []
    # Final marginals through one batch factorisation of the final graph: iSAM2's own
    # per-key marginals after the final relinearisation can walk far up the tree (O(K) each).
    factors = _compact(isam.getFactorsUnsafe())
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
        marginal = _marginal_function(factors, result)
        covariances = _marginal_covariances(problem, marginal, marginal, result, progress)
        final = _to_trajectory(
            problem, _states_from_values(problem, result, covariances), "isam2", smoothed=True
        )
        _merge_info(
            final,
            _gnss_report(problem, result),
            _lever_arm_report(problem, factors, result),
            _extra_states(result),
            _solver_report(report),
            _vehicle_fit_report(problem, result),
            _covariance_report(covariances),
            {
                "python_callback_factors": _callback_factors(factors),
                "zupt_keyframes": len(problem.zupt_keyframes),
            },
        )
        final.timings.update({**timings, "final": time.perf_counter() - incremental})
        return final

    def make_online() -> Trajectory:
        filtered = _to_trajectory(problem, online_states, "isam2-online", smoothed=False)
        _merge_info(
            filtered,
            _covariance_report(online),
            {"solver": "iSAM2 online (filtered)", "fallback": report.fallback},
        )
        filtered.timings.update(timings)
        return filtered

    if online_first:
        return make_online(), DeferredTrajectory(make_final)
    return make_final(), DeferredTrajectory(make_online)


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


def _compact(graph: gtsam.NonlinearFactorGraph) -> gtsam.NonlinearFactorGraph:
    """The graph without the empty slots that removed factors leave in iSAM2's."""
    out = gtsam.NonlinearFactorGraph()
    for i in range(graph.size()):
        if graph.exists(i):
            out.add(graph.at(i))
    return out


def smooth(
    dataset: Dataset,
    config: RunConfig,
    method: str = "batch",
    *,
    gnss_mask: np.ndarray | None = None,
    progress: bool = True,
    initial_guess: InitialGuess | None = None,
) -> Trajectory:
    """Smooth ``dataset`` with ``method`` ('batch', 'isam2' or 'isam2-online').

    ``initial_guess`` (batch): keyframe times -> states there, e.g. a Kalman filter's; the
    pipeline chooses the filter that matches the input.
    """
    started = time.perf_counter()
    problem = build_problem(dataset, config, gnss_mask, progress=progress)
    built = time.perf_counter()
    if method == "batch":
        trajectory = smooth_batch(problem, progress, initial_guess)
    elif method in ("isam2", "isam2-online"):
        trajectory, other = smooth_isam2(
            problem, progress, online_first=method == "isam2-online"
        )
        trajectory.info["online"] = other
    else:
        raise FginsError(f"unknown factor-graph method {method!r}")
    trajectory.timings["build"] = built - started
    trajectory.timings["total"] = time.perf_counter() - started
    return trajectory
