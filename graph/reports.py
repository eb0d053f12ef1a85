"""What a solution's summary says beyond the states: GNSS residuals and what the robust
kernel did, an unconfigured antenna lever arm, the DOP noise model's scale, how well the
vehicle constraints fit, the solver's report.
"""

from __future__ import annotations

from collections.abc import Callable

import gtsam
import numpy as np
from gtsam.symbol_shorthand import V, X

from fgins.datatypes import Trajectory
from fgins.factors import gnss as gnss_model
from fgins.factors import odometer as odometer_model
from fgins.factors import vehicle as vehicle_model
from fgins.gnss_scatter import gnss_scatter
from fgins.graph.problem import Problem
from fgins.graph.solve import CHI2_FAR_TOO_GOOD, CHI2_WARN, SolveReport

ODOMETER_SCALE_PRIOR_SIGMAS = 3.0
# A fix whose whitened residual exceeds this at the solution (chi-square, 3 dof, 99.9 %) has a
# large residual; only a robust kernel actually down-weights it.
LARGE_RESIDUAL_WHITENED = 4.03


def extra_states(
    problem: Problem, values: gtsam.Values, marginal: Callable[[int], np.ndarray] | None = None
) -> dict[str, object]:
    """Estimated non-navigation states worth reporting (odometer scale-factor error, the
    NHC misalignment: the angle between the vehicle's x axis as configured and its
    velocity, i.e. a mounting error, lateral (yaw) and vertical (pitch), degrees).

    A scale-factor error beyond 3 sigma of its prior is a warning: tyres are within a few
    per cent, so a scale the data pulled that far is a wrong radius or pulses-per-metre (a
    unit is refused at load: :func:`fgins.io.motion_checks.check_wheel_speed`). With
    ``marginal`` (a key's marginal covariance), the constant misalignment's sigmas too."""
    out: dict[str, object] = {}
    if values.exists(odometer_model.scale_key()):
        scale = float(values.atDouble(odometer_model.scale_key()))
        out["odometer_scale_error"] = scale
        prior = problem.config.smoother.odometer_scale_sigma
        if abs(scale) > ODOMETER_SCALE_PRIOR_SIGMAS * prior:
            out["fit_warnings"] = [
                f"wheel speed: its scale-factor error came out {100 * scale:+.1f} %, beyond "
                f"{ODOMETER_SCALE_PRIOR_SIGMAS:g} sigma of its prior ({100 * prior:g} %, [smoother] "
                "odometer_scale_sigma): a wrong tyre radius or pulses per metre in the wheel "
                "speed, or a wheel that slips; fix the wheel speed's scale, or widen the prior "
                "if it is real"
            ]
    if values.exists(vehicle_model.misalignment_key(0)):
        angles = values.atVector(vehicle_model.misalignment_key(0))
        out["nhc_misalignment_rad"] = (float(angles[0]), float(angles[1]))
        if marginal is not None:
            sigma = np.sqrt(np.diagonal(marginal(vehicle_model.misalignment_key(0))))
            out["nhc_misalignment_sigma_rad"] = (float(sigma[0]), float(sigma[1]))
        lateral, vertical = np.degrees(angles)
        drifting = values.exists(vehicle_model.misalignment_key(1))  # one key per keyframe
        out["nhc_misalignment_deg"] = f"lateral {lateral:+.2f}, vertical {vertical:+.2f}" + (
            " (at the start; it drifts)" if drifting else ""
        )
    return out


def gnss_report(problem: Problem, values: gtsam.Values) -> dict[str, object]:
    times, whitened = problem.gnss_whitened_residuals(values)
    norms = np.linalg.norm(whitened, axis=1)
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
        **_merged_warnings(_dop_model_scale(problem, norms), gnss_scatter(whitened)),
    }


def lever_arm_report(
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
        out["fit_warnings"] = [
            *out.get("fit_warnings", []),  # type: ignore[misc]
            f"GNSS: {int(modelled.sum())} fixes have sigmas from UERE x DOP (no GST or "
            f"covariance in the data) and residuals of only {scale:.2f} of them (whitened "
            "RMS): either the receiver is better than the UERE table and the reported "
            f"uncertainties are up to {1.0 / max(scale, 1e-9):.1f}x pessimistic (set "
            "[gnss.uere_m], e.g. autonomous = 1.0, or [gnss] sigma_m), or its errors are "
            "slow and the fit follows them",
        ]
    return out


def _merged_warnings(*parts: dict[str, object]) -> dict[str, object]:
    """The parts' entries in one dict, their ``fit_warnings`` lists joined in order."""
    out: dict[str, object] = {}
    warnings: list[str] = []
    for part in parts:
        entries = dict(part)
        warnings += entries.pop("fit_warnings", [])  # type: ignore[arg-type]
        out.update(entries)
    if warnings:
        out["fit_warnings"] = warnings
    return out


MIN_FIXES_FOR_SCALE = 30
DOP_MODEL_PESSIMISTIC = 0.4
# A receiver's own sigmas are often pessimistic (u-blox hAcc: 2-3x); 10x is a unit.
DATA_SIGMA_ABSURD = 0.1


def vehicle_fit_report(problem: Problem, values: gtsam.Values) -> dict[str, object]:
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
    if problem.estimates_misalignment:  # less the misalignment the fit estimated
        misalignment = np.array(
            [values.atVector(problem.misalignment_key(int(k))) for k in moving_k[moving]]
        )
        body_velocity = np.einsum("kji,kj->ki", rotation[moving], velocity[moving])
        residual = residual - misalignment * (body_velocity @ problem.imu_to_vehicle[0])[:, None]
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


def solver_report(report: SolveReport) -> dict[str, object]:
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


def merge_info(trajectory: Trajectory, *parts: dict[str, object]) -> None:
    """Each part's entries into ``trajectory.info``, their ``fit_warnings`` appended."""
    existing = trajectory.info.get("fit_warnings")
    start = {"fit_warnings": existing} if existing else {}
    trajectory.info.update(_merged_warnings(start, *parts))
