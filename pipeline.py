"""One call from a dataset to a trajectory, whatever the method (factor graph or baseline)."""

from __future__ import annotations

import importlib
import math
from collections.abc import Callable
from dataclasses import replace
from typing import TypeVar

import numpy as np

from fgins.config import STANDARD_GRAVITY, RunConfig
from fgins.datatypes import (
    AccelArrayData,
    BaroData,
    Dataset,
    FginsError,
    GnssData,
    InputError,
    OdometerData,
    Trajectory,
)
from fgins.factors import gnss as gnss_model
from fgins.gnss_scatter import SIGMA_AXIS_RATIO, SIGMA_TOO_SMALL, gnss_scatter
from fgins.initial_guess import KeyframeGuess

SensorData = TypeVar("SensorData", BaroData, OdometerData, AccelArrayData)

GRAPH_METHODS = ("batch", "isam2", "isam2-online")
# What a correction step (a solve again with something the data showed) said, kept in the
# run's info so that the next step's solve again says it too; and its entries.
CORRECTIONS_SAID = "corrections_said"
CARRIED_KEYS = (
    "gnss_sigma_scale",
    "gnss_velocity_sigma_scale",
    "gnss_time_offset_corrected_s",
    "gnss_time_drift_corrected_s",
    "gnss_velocity_lag_corrected_s",
    "gnss_lever_arm_corrected_m",
    "gnss_lever_arm_corrected_cov_m2",
)
SCATTER_AFTER_MIN = 0.5
# Kalman baselines: method name -> "module:function" taking (dataset, config, gnss_mask=...,
# progress=...) and returning a Trajectory. Modules are imported only when asked for.
BASELINE_METHODS = {
    "ekf": "fgins.baseline.ekf:run_ekf",
    "ekf-rts": "fgins.baseline.ekf:run_ekf_rts",
    "ukf": "fgins.baseline.ukf:run_ukf",
    "planar-kf": "fgins.baseline.planar_kf:run_planar_kf",
    "ekf18": "fgins.baseline.ekf18:run_ekf18",
}
# A gyro-free IMU (raw accelerometer-array readings in the dataset) has its own filter.
ACCEL_ARRAY_METHODS = {"ekf": "ekf18"}
METHODS = GRAPH_METHODS + tuple(BASELINE_METHODS)


def run_method(
    dataset: Dataset,
    config: RunConfig,
    method: str,
    *,
    gnss_mask: np.ndarray | None = None,
    progress: bool = True,
) -> Trajectory:
    check_imu_gaps(dataset, config, gnss_mask)
    dataset = integration_samples(dataset, config)
    config, noise_note = _noise_from_data(dataset, config, gnss_mask)
    config, mounting_note = _check_mounting(dataset, config, gnss_mask, progress)
    trajectory = _run(dataset, config, method, gnss_mask, progress)
    trajectory, config, bias_note = _with_turn_on_bias_widened(
        dataset, config, method, gnss_mask, progress, trajectory
    )
    # The sigmas first: sigmas a few times too small make any offset look significant to
    # the antenna check (velocities scattering 5x their sigma were read as an antenna or a
    # latency), while an arm or a latency hardly moves the robust scatter (1.0-1.24 with
    # 2-3 m arms and 0.15-0.3 s latencies).
    # Velocities late against their positions scatter by the acceleration times the delay
    # (an aircraft's 0.5 s: 2x their sigma, scaled so, 1.34 m beside the fixes against 0.94
    # on time): their sigmas are judged once the delay is corrected.
    lagging = "gnss_velocity_lag_s" in trajectory.info
    first_scaled = ("position",) if lagging else ("position", "velocity")
    trajectory, dataset, config = _with_gnss_sigmas_scaled(
        dataset, config, method, gnss_mask, progress, trajectory, first_scaled
    )
    trajectory, dataset, config = _with_antenna_corrected(dataset, config, method, gnss_mask, progress, trajectory)
    if lagging:
        trajectory, dataset, config = _with_gnss_sigmas_scaled(
            dataset, config, method, gnss_mask, progress, trajectory, ("velocity",)
        )
    # Last: the solves above hold a taken arm fixed, the output's uncertainty must not.
    _add_arm_uncertainty(trajectory, trajectory.info.pop("gnss_lever_arm_corrected_cov_m2", None))
    notes = [noise_note, bias_note, mounting_note, _unknown_height(dataset, trajectory), _nose_off_track(config, trajectory)]
    if config.smoother.initial_heading_deg is None:  # else the configured heading is known
        notes.append(unobservable_heading(dataset, trajectory))
    for note in filter(None, notes):
        trajectory.info.setdefault("fit_warnings", []).append(note)
    trajectory.info.pop(CORRECTIONS_SAID, None)  # said in fit_warnings
    return trajectory


# The densities the [imu] schema allows (fgins.config.IMU_SCHEMA): a measured one beyond them
# is clipped there (a log that vibrates that much is refused by its unit checks first).
MAX_GYRO_DENSITY = 1.0
MAX_ACCEL_DENSITY = 2.0


def _noise_from_data(
    dataset: Dataset, config: RunConfig, gnss_mask: np.ndarray | None
) -> tuple[RunConfig, str | None]:
    """The configured white noise, or (a copy of ``config``, said in a warning) the noise
    the IMU shows at rest where that is more than NOISE_EXCESS times larger
    (:mod:`fgins.noise_at_rest`): every method then weighs the IMU by what it reads."""
    if not config.imu.get("noise_from_data", True):
        return config, None
    from fgins.noise_at_rest import NOISE_EXCESS, noise_excess, white_noise_at_rest

    measured = white_noise_at_rest(dataset, gnss_mask)
    if measured is None:
        return config, None
    noise = config.imu_noise()
    excess = noise_excess(measured, noise.gyro_noise, noise.accel_noise)
    if not excess:
        return config, None
    imu = dict(config.imu)
    said = []
    for sensor, synonym, key, configured, unit, most in (
        ("gyro", "gyro_arw_deg_per_sqrt_hr", "gyro_noise_rad_per_s_per_sqrt_hz",
         noise.gyro_noise, "rad/s", MAX_GYRO_DENSITY),
        ("accel", "accel_vrw_m_per_s_per_sqrt_hr", "accel_noise_m_per_s2_per_sqrt_hz",
         noise.accel_noise, "m/s^2", MAX_ACCEL_DENSITY),
    ):  # fmt: skip
        if sensor in excess:
            imu.pop(synonym, None)
            imu[key] = min(excess[sensor], most)
            said.append(
                f"{sensor} {excess[sensor]:.3g} {unit}/sqrt(Hz), {excess[sensor] / configured:.1f}"
                f" times the configured {configured:.3g}"
            )
    return replace(config, imu=imu), (
        f"imu: at rest ({measured.rest_s:.0f} s of the log) the IMU reads more white noise "
        f"than configured (over {NOISE_EXCESS:g} times): {'; '.join(said)}. Vibration or a "
        "noisier sensor: the measured noise is used (a floor: a moving vehicle vibrates more). "
        "[imu] noise_from_data = false keeps the configured noise"
    )


# A solved turn-on bias this many of its prior sigmas from zero (on any axis) says the prior
# is wrong, not the bias: a right one is beyond 5 sigma on one of three axes once in ~600,000
# drives. The drive is solved again with the prior this many times the largest estimate.
TURN_ON_BIAS_EXCESS = 5.0
TURN_ON_BIAS_WIDENED = 2.0


def _with_turn_on_bias_widened(
    dataset: Dataset,
    config: RunConfig,
    method: str,
    gnss_mask: np.ndarray | None,
    progress: bool,
    trajectory: Trajectory,
) -> tuple[Trajectory, RunConfig, str | None]:
    """A solution whose initial gyro or accelerometer bias lies more than TURN_ON_BIAS_EXCESS
    of its prior sigma (the turn-on bias, ``[imu] *_turn_on_bias_*``) from zero, solved again
    with that prior TURN_ON_BIAS_WIDENED times the largest estimate, and said (a copy of
    ``config``). A prior far too tight still pulls the estimate toward zero where the data
    are weaker than it: an independent simulator's car with 10 mg accelerometer biases and
    1 mg configured came out at 5.7-9.8 sigma, the outage 2-3x the right prior's (0.75 m
    against 0.26), with chi2/dof 0.7 and nothing said; a tactical preset on a consumer IMU
    likewise. ``[imu] turn_on_bias_from_data = false`` keeps the configured sigmas."""
    if not config.imu.get("turn_on_bias_from_data", True) or dataset.accel_array is not None:
        return trajectory, config, None
    if trajectory.gyro_bias is None or trajectory.accel_bias is None or not len(trajectory):
        return trajectory, config, None
    noise = config.imu_noise()
    elapsed = trajectory.t - trajectory.t[0]
    imu = dict(config.imu)
    said = []
    for sensor, bias, prior, walk, key, unit, per_unit in (
        ("gyro", trajectory.gyro_bias, noise.gyro_bias_prior, noise.gyro_bias_rw,
         "gyro_turn_on_bias_deg_per_s", "deg/s", np.degrees(1.0)),
        ("accelerometer", trajectory.accel_bias, noise.accel_bias_prior, noise.accel_bias_rw,
         "accel_turn_on_bias_mg", "mg", 1e3 / STANDARD_GRAVITY),
    ):  # fmt: skip
        # Against what the model allows at each time: the prior, grown by the bias's random
        # walk since the start (a filter's bias starts at zero and ends where the data put it).
        allowed = np.sqrt(prior**2 + walk**2 * elapsed)
        excess = np.max(np.abs(bias), axis=1) / allowed
        if not np.all(np.isfinite(excess)) or float(np.max(excess)) <= TURN_ON_BIAS_EXCESS:
            continue
        worst = int(np.argmax(excess))
        estimate = bias[worst]
        largest = float(np.max(np.abs(estimate)))
        widened = TURN_ON_BIAS_WIDENED * largest * per_unit
        imu[key] = widened
        shown = ", ".join(f"{x * per_unit:.3g}" for x in estimate)
        said.append(
            f"the {sensor} bias came out at [{shown}] {unit}, {float(excess[worst]):.1f} times "
            f"its turn-on sigma ({prior * per_unit:.3g} {unit}); solved again with {key} = "
            f"{widened:.3g}"
        )
    if not said:
        return trajectory, config, None
    widened_config = replace(config, imu=imu)
    try:
        again = _run(dataset, widened_config, method, gnss_mask, progress)
    except FginsError:
        return trajectory, config, (
            f"imu: {'; '.join(said)} failed; the configured turn-on sigmas are too small for "
            "this IMU ([imu] gyro_turn_on_bias_deg_per_s, accel_turn_on_bias_mg, --imu-preset)"
        )
    return again, widened_config, (
        f"imu: {'; '.join(said)}: the configured turn-on bias sigmas are too small for this "
        "IMU (a preset of a better grade? --imu-preset, [imu]); [imu] turn_on_bias_from_data = "
        "false keeps them"
    )


# Rounds of antenna and clock corrections: a fix stamped late is found at once (0.193 s of
# 0.2), an IMU clock's drift only in part where the drive's biases absorb some (an aircraft
# whose IMU runs 300 ppm fast: 30 % in the first round).
ANTENNA_ROUNDS = 4


def _with_antenna_corrected(
    dataset: Dataset,
    config: RunConfig,
    method: str,
    gnss_mask: np.ndarray | None,
    progress: bool,
    trajectory: Trajectory,
) -> tuple[Trajectory, Dataset, RunConfig]:
    """A graph solution whose fixes fit time stamps late or early against the IMU's, an
    offset that drifts along the drive (two clocks), or an antenna elsewhere than the
    configured lever arm (:func:`fgins.graph.reports.lever_arm_report`), solved again with
    the fixes' times moved, the IMU stamped onto the receiver's clock and/or the arm the
    fixes fit, and said; again while a round finds more and fits better (ANTENNA_ROUNDS);
    the first solution when the second does not fit better or the correction is switched
    off (``[gnss] time_offset_from_data``, ``lever_arm_from_data``). (Independent
    simulator's car, fixes stamped 0.2 s late: 2.9 m inside outages, 2.7 m beside the
    fixes; corrected, as with true stamps. An unconfigured 2-3 m arm on a stop-and-go
    drive: 1.2-1.6 m inside outages; corrected, 0.4-0.5 m.)"""
    if method not in ("batch", "isam2"):
        return trajectory, dataset, config
    first, best = trajectory, trajectory
    fixes_moved = velocity_lag = 0.0
    imu_t0, imu_t1 = float(dataset.imu.t[0]), float(dataset.imu.t[-1])
    drifting, last, arm_taken, arm_covariance = False, (0.0, 0.0), None, None
    for _ in range(ANTENNA_ROUNDS):
        info = best.info
        offset = info.get("gnss_time_offset_s") if config.gnss.time_offset_from_data else None
        arm = info.get("gnss_lever_arm_m") if config.gnss.lever_arm_from_data else None
        lag = info.get("gnss_velocity_lag_s") if config.gnss.time_offset_from_data else None
        if velocity_lag and lag is None:
            # Velocities moved back once: a 1 s delay is found at 0.8 (the linear step); the
            # rest is taken while it shows at 2 sigma and the fit improves.
            rest, rest_sigma = info.get("gnss_velocity_lag_fit_s"), info.get("gnss_velocity_lag_fit_sigma_s")
            if isinstance(rest, float) and isinstance(rest_sigma, float) and abs(rest) > 2.0 * rest_sigma:
                lag = rest
        drift = float(info.get("gnss_time_drift_s", 0.0))  # type: ignore[arg-type]
        if drifting and offset is None and _still_drifting(info):
            # Two clocks found: what is left of the drift is taken at 2 sigma. The biases
            # absorb part of it, so each round finds the same part of what remains (a
            # geometric series): the rest of the series at once (Aitken; at most 5 times
            # this round's finding).
            offset, drift = (
                value / (1.0 - min(max(value / before, 0.0), 0.8)) if before else value
                for value, before in zip(_clock_fit(info), last, strict=True)
            )
        if offset is None and arm is None and lag is None:
            break
        if lag is not None:
            # The velocities' delay alone first: the check models it to first order (the
            # acceleration times the delay), and what is left, the second derivative times
            # half its square, lies along the track in turns as a vertical arm's velocity
            # does (an aircraft's velocities 0.5 s late read as an antenna 2 m above the
            # IMU); the next round asks again with the velocities on time.
            offset = arm = None
        drifting, last = drifting or bool(drift), (offset or 0.0, drift)
        trial, trial_config, trial_moved, trial_lag = dataset, config, fixes_moved, velocity_lag
        if lag is not None:
            trial = replace(trial, gnss=_velocities_retimed(trial.gnss, float(lag), best))  # type: ignore[arg-type]
            trial_lag += float(lag)  # type: ignore[arg-type]
        if offset is not None:
            offset = float(offset)  # type: ignore[arg-type]
            if drift:
                # Two clocks at different rates: the receiver's is the one kept (GNSS time;
                # a logger's or an IMU's oscillator is off by 20-5000 ppm), so the IMU's
                # samples (and every other sensor on its clock) are stamped onto it; that
                # also gives the integration its true intervals (0.2 % fast: a 0.2 % gyro
                # scale error, 1.0 m inside outages where moving the fixes instead left
                # 0.75 m). A time offset alone is a latency between two stamps of one
                # clock: there the fixes move.
                middle = float(info["gnss_time_middle_s"])  # type: ignore[arg-type]
                half_span = float(info["gnss_time_half_span_s"])  # type: ignore[arg-type]
                trial = _on_receiver_clock(
                    trial, lambda u, d0=offset, d1=drift, m=middle, h=half_span: u + d0 + d1 * (u - m) / h
                )
            else:
                trial = replace(trial, gnss=replace(trial.gnss, t=trial.gnss.t - offset))
                trial_moved -= offset
        if arm is not None:
            arm = [float(x) for x in arm]  # type: ignore[union-attr]
            trial_config = replace(config, gnss=replace(config.gnss, lever_arm_m=arm))
        try:
            corrected = _run(trial, trial_config, method, gnss_mask, progress)
        except FginsError:
            break
        before, after = best.info.get("chi2_per_dof"), corrected.info.get("chi2_per_dof")
        if not (isinstance(before, float) and isinstance(after, float) and after < before):
            break
        best, dataset, config, fixes_moved, velocity_lag = corrected, trial, trial_config, trial_moved, trial_lag
        if arm is not None:
            arm_taken, arm_covariance = arm, info.get("gnss_lever_arm_cov_m2")
    if best is first:
        return first, dataset, config
    done, switches = [], []
    if fixes_moved:
        best.info["gnss_time_offset_corrected_s"] = fixes_moved
        done.append(f"the fixes' times moved by {fixes_moved:+.3f} s (as --time-offset {fixes_moved:+.3f})")
    start, end = float(dataset.imu.t[0]) - imu_t0, float(dataset.imu.t[-1]) - imu_t1
    if start or end:
        best.info["gnss_time_offset_corrected_s"] = -0.5 * (start + end) + fixes_moved
        best.info["gnss_time_drift_corrected_s"] = -0.5 * (end - start)
        done.append(
            f"the IMU's times moved by {start:+.3f} s at the start to {end:+.3f} s at the end, "
            "onto the receiver's clock (the output's times are the receiver's)"
        )
    if velocity_lag:
        best.info["gnss_velocity_lag_corrected_s"] = velocity_lag
        done.append(f"each velocity taken as the one {velocity_lag:+.3f} s after its stamp")
    if done:
        switches.append("[gnss] time_offset_from_data = false keeps the stamps")
    if arm_taken is not None:
        best.info["gnss_lever_arm_corrected_m"] = arm_taken
        if arm_covariance is not None:
            best.info["gnss_lever_arm_corrected_cov_m2"] = arm_covariance
        done.append(f"the lever arm set to [{', '.join(f'{x:.2f}' for x in arm_taken)}] m")
        switches.append("lever_arm_from_data = false the configured arm")
    before, after = first.info.get("chi2_per_dof"), best.info.get("chi2_per_dof")
    how = (
        f"{' and '.join(done)}, and the drive solved again (chi2/dof {before:.2f} -> {after:.2f}; "
        f"{', '.join(switches)})"
    )
    findings = first.info.get("antenna_findings") or ["GNSS antenna"]
    said = [
        *first.info.get(CORRECTIONS_SAID, []),  # type: ignore[list-item]
        *(f"{finding}: corrected, {how}" for finding in findings),  # type: ignore[union-attr]
    ]
    for key in CARRIED_KEYS:
        if key in first.info and key not in best.info:
            best.info[key] = first.info[key]
    best.info[CORRECTIONS_SAID] = said
    best.info["fit_warnings"] = [*said, *best.info.get("fit_warnings", [])]
    return best, dataset, config


def _add_arm_uncertainty(trajectory: Trajectory, covariance: object) -> None:
    """Add the uncertainty of a lever arm taken from the data to ``trajectory``'s position
    covariance (in place). The solve holds the arm fixed, so its covariance is conditioned
    on it; the fixes pin the antenna, and the IMU lies ``R arm`` from it, so an arm error
    ``e`` moves every position by ``-R e``: ``R C R^T`` is added. (An independent
    simulator's aircraft with an unconfigured 2.3 m arm, found 0.37 m off in x at 2 sigma:
    position NEES 7.4 over the flight, 1.9 with it.)"""
    if covariance is None or trajectory.position_cov is None:
        return
    arm_cov = np.asarray(covariance, dtype=float).reshape(3, 3)
    if not np.all(np.isfinite(arm_cov)) or not arm_cov.any():
        return
    rotation = trajectory.rotation
    trajectory.position_cov = trajectory.position_cov + np.einsum(
        "nij,jk,nlk->nil", rotation, arm_cov, rotation
    )
    trajectory.info["gnss_lever_arm_corrected_sigma_m"] = [
        float(x) for x in np.sqrt(np.diag(arm_cov))
    ]


def _with_gnss_sigmas_scaled(
    dataset: Dataset,
    config: RunConfig,
    method: str,
    gnss_mask: np.ndarray | None,
    progress: bool,
    trajectory: Trajectory,
    kinds: tuple[str, ...] = ("position", "velocity"),
) -> tuple[Trajectory, Dataset, RunConfig]:
    """A graph solution whose fixes' positions or velocities (``kinds``) scatter more than
    SIGMA_TOO_SMALL times their own sigmas about it (fgins.gnss_scatter: robust, per
    horizontal and vertical) solved again with those sigmas scaled by that scatter, and
    said; the first when ``[gnss] sigma_from_fit`` is false or the second does not scatter
    less; with the dataset and configuration that gave it. Said alone, every reported
    uncertainty stayed that much too small (an independent
    simulator's car whose std columns were 4x too small: errors 2.8-4.1 times the reported
    sigmas, and the fixes weighted 16x too much: 0.64 m inside outages, 0.43 m with the
    right sigmas; an urban car whose velocities scattered 0.5 m/s against 0.2 configured:
    2.16 m against 1.09 m)."""
    info = trajectory.info
    before = {what: _scatter(info, what) for what in kinds}
    scaled = {what: scale for what, scale in before.items() if scale is not None and max(scale) > SIGMA_TOO_SMALL}
    if method not in ("batch", "isam2") or not config.gnss.sigma_from_fit or not scaled:
        return trajectory, dataset, config
    gnss, gnss_config = dataset.gnss, config.gnss
    if "position" in scaled:
        horizontal, vertical = scaled["position"]
        scale = np.array([max(horizontal, 1.0), max(horizontal, 1.0), max(vertical, 1.0)])
        gnss = replace(gnss, std=gnss_model.position_sigmas(dataset.gnss, config.gnss) * scale)
        gnss_config = replace(gnss_config, sigma_m=None)
    if "velocity" in scaled:
        horizontal, vertical = scaled["velocity"]
        vertical = horizontal if not math.isfinite(vertical) else vertical
        speed_scale = np.array([max(horizontal, 1.0), max(horizontal, 1.0), max(vertical, 1.0)])
        sigma = gnss_model.velocity_sigmas(dataset.gnss, config.gnss) * speed_scale
        gnss = replace(gnss, velocity_std=sigma)
        gnss_config = replace(gnss_config, velocity_sigma_m_per_s=None)
    trial, trial_config = replace(dataset, gnss=gnss), replace(config, gnss=gnss_config)
    try:
        corrected = _run(trial, trial_config, method, gnss_mask, progress)
    except FginsError:
        return trajectory, dataset, config
    after = {what: _scatter(corrected.info, what) for what in scaled}
    # Kept when the scatter falls to about its sigmas: far below them, the first solve's
    # scatter was not the receiver's noise but a model error the second solve took
    # elsewhere (an aircraft's gyro 1 % large: velocities 2.8x, then 0.3x).
    if any(
        after[what] is None or not SCATTER_AFTER_MIN <= max(after[what]) < max(scaled[what])  # type: ignore[arg-type]
        for what in scaled
    ):
        return trajectory, dataset, config
    said = []
    if "position" in scaled:
        (horizontal, vertical), now = scaled["position"], after["position"]
        corrected.info["gnss_sigma_scale"] = [float(x) for x in scale]
        heights = vertical > SIGMA_AXIS_RATIO * horizontal  # gnss_scatter's reading
        why = (
            "an altitude in feet (3.3x), heights of two datums mixed, or a vertical sigma too small"
            if heights
            else "the sigmas (std columns, GST, covariance, [gnss] sigma_m or UERE x DOP) too small "
            "for this receiver, or the IMU's noise set too small"
        )
        said.append(
            f"GNSS: the fixes scatter {horizontal:.1f}x their horizontal and {vertical:.1f}x their "
            f"vertical sigma about the solution (robust whitened RMS, ~1 expected: {why}): "
            f"corrected, every fix's sigma scaled by {scale[0]:.1f} horizontally and "
            f"{scale[2]:.1f} vertically and the drive solved again (now {now[0]:.1f}x / "  # type: ignore[index]
            f"{now[1]:.1f}x; [gnss] sigma_from_fit = false keeps them)"  # type: ignore[index]
        )
    if "velocity" in scaled:
        (horizontal, _), now = scaled["velocity"], after["velocity"]
        corrected.info["gnss_velocity_sigma_scale"] = [float(x) for x in speed_scale]
        said.append(
            f"GNSS: the fixes' velocities scatter {horizontal:.1f}x their horizontal sigma about "
            "the solution (robust whitened RMS, ~1 expected: the velocity sigmas, from the data, "
            "[gnss] velocity_sigma_m_per_s or 0.1 m/s x HDOP, too small for this receiver): "
            f"corrected, every velocity's sigma scaled by {speed_scale[0]:.1f} horizontally and "
            f"{speed_scale[2]:.1f} vertically and the drive solved again (now {now[0]:.1f}x; "  # type: ignore[index]
            "[gnss] sigma_from_fit = false keeps them)"
        )
    said = [*info.get(CORRECTIONS_SAID, []), *said]  # type: ignore[list-item]
    for key in CARRIED_KEYS:
        if key in info and key not in corrected.info:
            corrected.info[key] = info[key]
    corrected.info[CORRECTIONS_SAID] = said
    corrected.info["fit_warnings"] = [*said, *corrected.info.get("fit_warnings", [])]
    return corrected, trial, trial_config


def _scatter(info: dict[str, object], what: str) -> tuple[float, float] | None:
    """The robust whitened scatter (horizontal, vertical) of the fixes' positions or
    velocities about a graph solution (fgins.graph.reports.gnss_report), None without
    one; a velocity without a vertical has NaN there."""
    prefix = "gnss_whitened_scale" if what == "position" else "gnss_velocity_whitened_scale"
    horizontal, vertical = info.get(f"{prefix}_horizontal"), info.get(f"{prefix}_vertical")
    if not (isinstance(horizontal, float) and isinstance(vertical, float)):
        return None
    return horizontal, vertical


def _velocities_retimed(gnss: GnssData, lag: float, solution: Trajectory) -> GnssData:
    """The receiver's velocities stamped ``lag`` s late moved back onto their stamps: each
    takes the solution's change of velocity over the ``lag`` before its stamp (what the IMU
    says the vehicle did then). Interpolating the 1 Hz velocities ``lag`` later instead
    misses their curvature in turns (half an epoch: the second derivative / 8, 0.03 m/s
    along the track of an aircraft in a 3 deg/s turn, which the next check read as an
    antenna 3 m above the IMU)."""
    if gnss.velocity is None:
        return gnss
    velocity = np.array(gnss.velocity, dtype=float, copy=True)
    for axis in range(velocity.shape[1]):
        change = np.interp(gnss.t, solution.t, solution.velocity[:, axis]) - np.interp(
            gnss.t - lag, solution.t, solution.velocity[:, axis]
        )
        velocity[:, axis] += change  # NaN (no velocity on this axis) stays NaN
    return replace(gnss, velocity=velocity)


def _clock_fit(info: dict[str, object]) -> tuple[float, float]:
    """The time offset at the drive's middle and its drift to the ends that the fixes fit
    with the arm as configured (fgins.graph.reports.lever_arm_report)."""
    return float(info["gnss_time_clock_offset_fit_s"]), float(info["gnss_time_drift_fit_s"])  # type: ignore[arg-type]


def _still_drifting(info: dict[str, object]) -> bool:
    """Is either of :func:`_clock_fit` beyond 2 sigma?"""
    sigmas = info.get("gnss_time_clock_offset_fit_sigma_s"), info.get("gnss_time_drift_fit_sigma_s")
    return any(
        isinstance(sigma, float) and abs(value) > 2.0 * sigma
        for value, sigma in zip(_clock_fit(info), sigmas, strict=True)
    )


def _on_receiver_clock(dataset: Dataset, receiver_time: Callable[[np.ndarray], np.ndarray]) -> Dataset:
    """The dataset with every sensor but the GNSS receiver (IMU and its suspect stretches,
    barometer, wheel speed, accelerometer array) stamped by ``receiver_time`` (IMU clock ->
    receiver's clock)."""

    def moved(data: SensorData | None) -> SensorData | None:
        return None if data is None else replace(data, t=receiver_time(data.t))

    imu = replace(
        dataset.imu,
        t=receiver_time(dataset.imu.t),
        suspect=[(float(receiver_time(np.array(a))), float(receiver_time(np.array(b)))) for a, b in dataset.imu.suspect],
    )
    return replace(
        dataset, imu=imu, baro=moved(dataset.baro), odometer=moved(dataset.odometer),
        accel_array=moved(dataset.accel_array),
    )  # fmt: skip


def _unknown_height(dataset: Dataset, trajectory: Trajectory) -> str | None:
    """A log without any height (NMEA RMC only): the heights are the validation's invented
    0 m, and nothing in the data fixes the vertical. Its sigma is said to be at least the
    invented height's, whatever the solver's covariance gives: the batch said 2.7 m (the
    start's 2 m position prior holds the invented height) with the height 85 m off, and
    43.7 m with that prior widened (QR marginals of a near-singular system: numerical
    noise)."""
    if not dataset.metadata.get("gnss_without_height"):
        return None
    from fgins.io.gnss_checks import NO_HEIGHT_SIGMA_M

    cov = trajectory.position_cov
    cov[:, 2, 2] = np.fmax(np.nan_to_num(cov[:, 2, 2], nan=0.0), NO_HEIGHT_SIGMA_M**2)
    return (
        "GNSS: the log has no height at all (2-D fixes): alt and up are the invented 0 m "
        f"carried by the IMU, std_up at least {NO_HEIGHT_SIGMA_M:g} m; add GGA sentences or an "
        "altitude column for a vertical solution"
    )


# Fixes whose running median (over this many) never leaves this many metres of the log's
# median, over a log they cover almost end to end, and an IMU whose 1-s means of rate and
# specific force stay this close to their medians (idle vibration averages out; a vehicle
# circling a small courtyard turns and accelerates far more) show a vehicle that never moved.
STATIC_SPAN_M = 10.0
STATIC_MEDIAN_FIXES = 9
STATIC_COVERAGE = 0.8
STATIC_RATE_RAD_S = 0.02
STATIC_FORCE_M_S2 = 0.3


def never_moved(dataset: Dataset) -> float | None:
    """How far (m) the fixes' running median strays from their median when the vehicle
    never moved, else None (it moved, or the fixes do not cover the log to tell)."""
    if not _imu_at_rest(dataset.imu):
        return None
    t, enu = dataset.gnss.t, dataset.gnss_enu()[:, :2]
    span_imu = float(dataset.imu.t[-1] - dataset.imu.t[0])
    good = np.all(np.isfinite(enu), axis=1)
    t, enu = t[good], enu[good]
    if len(t) < STATIC_MEDIAN_FIXES or (t[-1] - t[0]) < STATIC_COVERAGE * span_imu:
        return None
    windows = np.lib.stride_tricks.sliding_window_view(enu, STATIC_MEDIAN_FIXES, axis=0)
    running = np.median(windows, axis=-1)  # (n - w + 1, 2): one outlier cannot move it
    span = float(np.max(np.linalg.norm(running - np.median(enu, axis=0), axis=1)))
    return span if span <= STATIC_SPAN_M else None


def _imu_at_rest(imu) -> bool:
    """Do 99 % of the IMU's 1-s means of rate and specific force stay within
    ``STATIC_RATE_RAD_S`` and ``STATIC_FORCE_M_S2`` of their medians?"""
    per_second = max(1, round(imu.rate_hz))
    blocks = len(imu.t) // per_second
    if blocks < 2:
        return False
    for samples, limit in ((imu.gyro, STATIC_RATE_RAD_S), (imu.accel, STATIC_FORCE_M_S2)):
        means = samples[: blocks * per_second].reshape(blocks, per_second, 3).mean(axis=1)
        spread = np.linalg.norm(means - np.median(means, axis=0), axis=1)
        if float(np.percentile(spread, 99)) > limit:
            return False
    return True


# An aircraft's nose points along its velocity to within its angle of attack and sideslip
# (and a crab in wind): a few degrees, 15-20 at most. Its configured forward axis this far
# from the solved velocity, over most of the flight, is an IMU whose x axis is not forward.
NOSE_OFF_TRACK_DEG = 45.0
NOSE_MIN_SPEED_M_S = 10.0


def _nose_off_track(config: RunConfig, trajectory: Trajectory) -> str | None:
    """A warning when an aircraft's forward axis (IMU x, turned by the mounting) lies more
    than NOSE_OFF_TRACK_DEG from its solved velocity (median over the flight above
    NOSE_MIN_SPEED_M_S). The in-motion alignment takes that axis for the direction of
    travel: an IMU with x right and y forward went unsaid (the graph recovered; EKF+RTS
    1.24 m inside an outage instead of 0.36 m), one facing backwards only as a diverged
    filter."""
    if config.smoother.vehicle != "aircraft" or len(trajectory.t) < 10:
        return None
    from fgins.mounting import mounting_rotation

    forward = mounting_rotation(config.smoother.imu_to_vehicle_rpy_deg)[0]  # IMU axes
    velocity = trajectory.velocity
    speed = np.linalg.norm(velocity, axis=1)
    flying = np.isfinite(speed) & (speed > NOSE_MIN_SPEED_M_S)
    if flying.sum() < 10:
        return None
    nose = trajectory.rotation[flying] @ forward  # ENU
    cosine = np.einsum("ni,ni->n", nose, velocity[flying]) / speed[flying]
    angle = float(np.degrees(np.arccos(np.clip(np.median(cosine), -1.0, 1.0))))
    if angle <= NOSE_OFF_TRACK_DEG:
        return None
    return (
        f"imu: the aircraft's forward axis (IMU x, turned by imu_to_vehicle_rpy_deg = "
        f"{list(config.smoother.imu_to_vehicle_rpy_deg)}) lies {angle:.0f} deg from its "
        "velocity over the flight (an aircraft flies along its nose to within 15-20 deg): the "
        "IMU's axes are turned in the airframe; set [smoother] imu_to_vehicle_rpy_deg (the "
        "in-motion alignment and the Kalman baselines take that axis for the direction of "
        "travel)"
    )


def unobservable_heading(dataset: Dataset, trajectory: Trajectory) -> str | None:
    """A vehicle that never moved has no observable heading: only the Earth's rate would
    show it (15 deg/h at most, far below a MEMS gyro's bias), and every solver's linearised
    covariance claimed 5-60 deg where the errors were up to 160 deg (their Gauss-Newton
    curvature takes the noise-level wiggles of the track for motion). The heading's
    variance is then set to (180 deg)^2, uncorrelated with the rest, and said; None when
    the vehicle moved."""
    span = never_moved(dataset)
    if span is None:
        return None
    cov = trajectory.attitude_cov
    if cov is not None:
        cov[:, 2, :] = 0.0
        cov[:, :, 2] = 0.0
        cov[:, 2, 2] = math.pi**2
    trajectory.info["heading_observable"] = False
    return (
        f"heading: the vehicle never moved (the fixes' running median stays within {span:.1f} "
        "m): nothing shows its heading, so heading_deg is arbitrary and std_heading_deg is "
        "180; position, velocity, roll and pitch are not affected ([smoother] "
        "initial_heading_deg gives a known heading)"
    )


def integration_samples(dataset: Dataset, config: RunConfig) -> Dataset:
    """``dataset`` with the IMU samples every estimator holds over their intervals: converted
    from instantaneous readings unless ``[imu] sample_timing = "held"``
    (:mod:`fgins.factors.imu_samples`). Not for a gyro-free IMU (its filter integrates the
    raw accelerometer readings). The caller's dataset is not changed."""
    from dataclasses import replace

    from fgins.factors.imu_samples import for_integration

    if dataset.accel_array is not None:
        return dataset
    imu = for_integration(dataset.imu, config.imu_sample_timing)
    return dataset if imu is dataset.imu else replace(dataset, imu=imu)


def check_imu_gaps(dataset: Dataset, config: RunConfig, gnss_mask: np.ndarray | None) -> None:
    """Refuse, with the gap named, an IMU gap no method can bridge: longer than
    ``max_imu_gap_s``, or with more than ``max_unaided_imu_gap_s`` of it without a usable
    GNSS fix (withheld by an outage, gated, or none). Shorter gaps are bridged with inflated
    noise (and said so by the reader's warning)."""
    from fgins.factors.gnss import gate_epochs
    from fgins.io.imu_checks import find_gaps

    imu, gnss, smoother = dataset.imu, dataset.gnss, config.smoother
    if len(imu) < 3:
        return
    gaps = find_gaps(imu.t)  # the reader's own rule (flag_suspect): > 3 sample periods
    if not gaps:
        return
    period = float(np.median(np.diff(imu.t)))
    withheld = None if gnss_mask is None else ~np.asarray(gnss_mask, dtype=bool)
    gate = gate_epochs(gnss, config.gnss, withheld=withheld)
    fixes = gnss.t[gate.used]
    t0 = dataset.t0
    for a, b in gaps:
        missing = b - a - period  # the samples' own period is not missing
        where = (
            f"imu: the {b - a:.1f} s gap in the IMU data at t - t0 = {a - t0:.1f}-{b - t0:.1f} s"
        )
        if missing > smoother.max_imu_gap_s + 1e-9:
            raise InputError(
                f"{where} is longer than fgins bridges ([smoother] max_imu_gap_s = "
                f"{smoother.max_imu_gap_s:g} s): attitude and velocity cannot be carried across "
                "it; split the log at the gap and smooth the parts"
            )
        inside = fixes[(fixes > a) & (fixes < b)]
        unaided = float(np.max(np.diff(np.concatenate([[a], inside, [b]])))) - period
        if unaided > smoother.max_unaided_imu_gap_s + 1e-9:
            cause = (
                "the outage windows withhold its fixes"
                if gnss_mask is not None and len(gnss.t[(gnss.t > a) & (gnss.t < b)]) > len(inside)
                else "no usable GNSS fix falls in it"
            )
            raise InputError(
                f"{where} goes {unaided:.1f} s without IMU or GNSS ({cause}); fgins bridges at "
                f"most {smoother.max_unaided_imu_gap_s:g} s of neither ([smoother] "
                "max_unaided_imu_gap_s): move the outage window off the gap, or split the log"
            )


# The sigma of the misalignment state that refines a mounting taken from the drive's turns.
ADOPTED_MOUNTING_SIGMA_DEG = 3.0
# A mounting (the default or a given one) the turns put this far off is refined (see
# _check_mounting); a refined mounting within DEFAULT_HOLDS_DEG (a given one: GIVEN_HOLDS_DEG)
# or 3 sigmas of the misalignment estimate of the one it started from leaves that one (and
# says nothing): the simulated highway's rough turn fit (-1 deg) came back to 0.26 deg,
# within the estimate's noise.
MOUNTING_REFINE_DEG = 0.5
DEFAULT_HOLDS_DEG = 0.2
# Someone measured a given mounting: the data replace it only where they show it off by more
# than this as well (the refining solve is good to ~0.3 deg on simulated drives).
GIVEN_HOLDS_DEG = 0.5
MISALIGNMENT_SIGNIFICANT = 3.0  # sigmas of its estimate before a misalignment turns it


def _check_mounting(
    dataset: Dataset, config: RunConfig, gnss_mask: np.ndarray | None, progress: bool
) -> tuple[RunConfig, str | None]:
    """A car's IMU mounting against the one its turns show (fgins.mounting): the
    constraints every method applies in the vehicle frame depend on it.

    A given mounting (config file, sim folder, API) more than MOUNTING_ERROR_DEG off is an
    error (a mistake to fix, such as inverted angles). Otherwise a mounting whose forward
    axis the turns put more than MOUNTING_REFINE_DEG off about up (or whose roll and pitch
    gravity contradicts) is refined by a batch solve with a constant misalignment state and
    replaced by the refined one (a copy of ``config``, said in a warning) where that turns
    it beyond DEFAULT_HOLDS_DEG (the default, given by nobody: an IMU with x right and y
    forward is a convention, not a mistake) or GIVEN_HOLDS_DEG (a given one, unless ``[smoother]
    mounting_from_data = false``) and beyond 3 sigmas of its estimate. On the urban car 2
    deg of yaw cost 32 % inside an outage, half a degree 48 % (or, by chance, helped: the
    NHC's white noise cannot hold a constant error, so the outage's drift follows it); an
    independent simulator's car given a yaw 4 deg off ran 3.8 m inside a 40 s outage (NEES
    24) where the true mounting gives 0.5 m."""
    if not config.smoother.nhc or dataset.accel_array is not None:
        return config, None  # no vehicle-frame constraint (or derived rates: too noisy)
    from fgins.mounting import adopted_mounting, check_mounting

    rpy = config.smoother.imu_to_vehicle_rpy_deg
    given = "imu_to_vehicle_rpy_deg" in config.explicit_smoother_keys or any(rpy)
    finding = None
    if given:
        finding = check_mounting(dataset, rpy)  # raises beyond MOUNTING_ERROR_DEG
        if not config.smoother.mounting_from_data:
            return config, finding
    adopted = adopted_mounting(dataset, rpy, refine_beyond_deg=MOUNTING_REFINE_DEG)
    if adopted is None:
        return config, finding if given else None
    original = config
    angles, evidence = adopted
    smoother = replace(config.smoother, imu_to_vehicle_rpy_deg=tuple(float(a) for a in angles))
    config = replace(config, smoother=smoother)
    refined = None
    holds_deg = GIVEN_HOLDS_DEG if given else DEFAULT_HOLDS_DEG
    if smoother.nhc_misalignment_prior_deg == 0.0:  # else the run estimates one itself
        refined = _refined_mounting(dataset, config, gnss_mask, progress)
        if refined is None:  # the refining solve failed: judged as a given mounting is
            return original, finding if given else check_mounting(dataset, rpy)
    elif given:
        return original, finding  # the run's own misalignment state takes up the rest
    if refined is not None:
        angles, turned_deg, sigma_deg = refined
        holds_deg = max(holds_deg, MISALIGNMENT_SIGNIFICANT * sigma_deg)
        smoother = replace(smoother, imu_to_vehicle_rpy_deg=angles)
        config = replace(config, smoother=smoother)
        evidence += (
            f"; a batch solve with a constant misalignment state turned that by "
            f"{turned_deg:.2f} deg"
        )
    moved_deg = _forward_angle_deg(smoother.imu_to_vehicle_rpy_deg, rpy)
    if moved_deg <= holds_deg:
        return original, finding if given else None  # it holds after all (a rough fit)
    shown = ", ".join(f"{a:.2f}" for a in smoother.imu_to_vehicle_rpy_deg)
    if given:
        return config, (
            f"imu: the configured mounting imu_to_vehicle_rpy_deg = {list(rpy)} does not fit "
            f"the drive (its forward axis {moved_deg:.1f} deg off): using "
            f"imu_to_vehicle_rpy_deg = [{shown}] ({evidence}); [smoother] mounting_from_data "
            "= false keeps the configured one"
        )
    return config, (
        f"imu: no IMU mounting was given, and the default {list(rpy)} does not fit the drive: "
        f"using imu_to_vehicle_rpy_deg = [{shown}] ({evidence}); set it in [smoother] to "
        "silence this"
    )


def _forward_angle_deg(rpy_a, rpy_b) -> float:
    """The angle (deg) between two mountings' forward axes (a roll alone changes none of the
    constraints: they zero the lateral and vertical velocity alike)."""
    from fgins.mounting import mounting_rotation

    cosine = mounting_rotation(rpy_a)[0] @ mounting_rotation(rpy_b)[0]
    return float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))


def _refined_mounting(
    dataset: Dataset, config: RunConfig, gnss_mask: np.ndarray | None, progress: bool
) -> tuple[tuple[float, float, float], float, float] | None:
    """The mounting taken from the turns, turned by the constant NHC misalignment a batch
    solve estimates with it (sigma ADOPTED_MOUNTING_SIGMA_DEG), each of its two angles only
    where it exceeds MISALIGNMENT_SIGNIFICANT sigmas of its own estimate; the angle turned
    and the larger sigma (deg). None when that solve fails. The turns' fit is good to
    ~0.1-1 deg: 1.2 deg off on an independent simulator's hilly drive, 1.52 m inside a 40 s
    outage where the true mounting gives 0.23 m; the state alone (kept in the run) got
    0.24 m there, but where the fit is exact it costs 6-9 %, and so does turning by an
    estimate within its noise (0.07 deg of yaw: 1.33 m against 1.24 m on the urban car). Folded into the mounting, the
    misalignment serves every method, the Kalman baselines too, at the cost of one solve."""
    from fgins.mounting import turned_by_misalignment

    smoother = replace(config.smoother, nhc_misalignment_prior_deg=ADOPTED_MOUNTING_SIGMA_DEG)
    try:
        probe = _run(dataset, replace(config, smoother=smoother), "batch", gnss_mask, progress)
    except FginsError:
        return None
    found = np.asarray(probe.info["nhc_misalignment_rad"])
    sigma = np.asarray(probe.info.get("nhc_misalignment_sigma_rad", (np.inf, np.inf)))
    lateral, vertical = np.where(np.abs(found) > MISALIGNMENT_SIGNIFICANT * sigma, found, 0.0)
    angles, turned_deg = turned_by_misalignment(smoother.imu_to_vehicle_rpy_deg, lateral, vertical)
    sigma_deg = float(np.degrees(np.max(sigma))) if np.all(np.isfinite(sigma)) else 0.0
    return tuple(float(a) for a in angles), turned_deg, sigma_deg


def _run(
    dataset: Dataset,
    config: RunConfig,
    method: str,
    gnss_mask: np.ndarray | None,
    progress: bool,
) -> Trajectory:
    if method in GRAPH_METHODS:
        from fgins.graph.smoother import smooth

        trajectory = smooth(
            dataset, config, method, gnss_mask=gnss_mask, progress=progress,
            initial_guess=filter_initial_guess(dataset, config, gnss_mask),
        )  # fmt: skip
        if method == "isam2-online":
            # The online pass is causal like a filter and has no chi-square check of its own
            # (the final smoothing's is another solution): a 0.5 m/s crawl held still by false
            # stops ran 19 m off in an outage and 5.6 m off beside the fixes, without a word.
            for note in _filter_fit_note(dataset, config, gnss_mask, trajectory, method):
                trajectory.info.setdefault("fit_warnings", []).append(note)
        return trajectory
    if dataset.accel_array is not None:
        method = ACCEL_ARRAY_METHODS.get(method, method)
    if method in BASELINE_METHODS:
        module_name, function_name = BASELINE_METHODS[method].split(":")
        try:
            function = getattr(importlib.import_module(module_name), function_name)
        except (ImportError, AttributeError):
            raise FginsError(f"method {method!r} is not available in this build") from None
        trajectory = function(dataset, config, gnss_mask=gnss_mask, progress=progress)
        for note in _filter_fit_note(dataset, config, gnss_mask, trajectory, method):
            trajectory.info.setdefault("fit_warnings", []).append(note)
        if dataset.odometer is not None and len(dataset.odometer.t):
            # The Kalman baselines have no wheel-speed update: said, never silently ignored.
            trajectory.info["fit_warnings"] = [
                *trajectory.info.get("fit_warnings", []),
                f"{method} does not use the wheel speed ({len(dataset.odometer.t)} samples); "
                "--method batch or isam2 do",
            ]
        return trajectory
    raise FginsError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")


# A Kalman baseline's horizontal residuals at the fixes it used, over their own variances:
# about 1 or below for a filter that holds (0.07-1.04 on KITTI and simulated cars and
# aircraft), 11-240 where it diverged (an IMU gap it could not bridge); the batch and
# iSAM2 run their own chi-square checks.
FILTER_FIT_CHI2_MAX = 5.0
# The median normalised innovation squared per dimension of its GNSS updates: 0.06 on KITTI,
# 0.78-0.96 on every simulated scenario (cars, UAV, aircraft, constant biases, FRD axes); 7
# with GNSS 1 s late on an urban car, 39 with 18 s (GPS against UTC), where the residuals
# stay small because a filter follows the fixes it is given (issue 12, outside tester: an
# 18 s offset with --method ekf was 218 m off at exit 0 without a word).
FILTER_NIS_MAX = 5.0


def _filter_fit_note(
    dataset: Dataset,
    config: RunConfig,
    gnss_mask: np.ndarray | None,
    trajectory: Trajectory,
    method: str,
) -> list[str]:
    """Warnings when a Kalman baseline's track does not fit the fixes it used or its
    predictions miss the fixes by far more than its covariance says (one of the two), and
    when the fixes scatter about its track far beyond their sigmas
    (:func:`fgins.gnss_scatter.gnss_scatter`, the graph's check too): said beside the
    others only when the heights alone scatter, which names a cause they cannot (feet)."""
    from fgins.baseline.measurements import select_gnss

    epochs = select_gnss(dataset, config, gnss_mask)
    if len(epochs.t) < 10 or len(trajectory) < 2:
        return []
    nearest = np.clip(np.searchsorted(trajectory.t, epochs.t), 0, len(trajectory) - 1)
    lever = np.asarray(config.gnss.lever_arm_m, dtype=float)
    antenna = trajectory.at(epochs.t) + trajectory.rotation[nearest] @ lever
    whitened = (antenna - epochs.position) / epochs.position_sigma
    scatter = gnss_scatter(whitened, method)
    trajectory.info.update({k: v for k, v in scatter.items() if k != "fit_warnings"})
    scatter_notes: list[str] = scatter.get("fit_warnings", [])  # type: ignore[assignment]
    heights_only = [note for note in scatter_notes if "heights scatter" in note]
    z2 = whitened[:, :2] ** 2
    chi2 = float(np.nanmean(z2))
    if np.isfinite(chi2) and chi2 > FILTER_FIT_CHI2_MAX:
        planar = (
            "its planar model reads the forward acceleration as if the vehicle kept its first "
            "tilt (a hill's grade or a bank is taken for acceleration: 0.8 m/s^2 at 8 %), or "
            if method == "planar-kf" else ""
        )  # fmt: skip
        estimate = "online estimate" if method == "isam2-online" else "filter"
        return [(
            f"{method}: its track does not fit the GNSS fixes it used: horizontal residuals "
            f"chi2/dof {chi2:.3g} (about 1 or below expected from their sigmas); {planar}the "
            f"{estimate} diverged (IMU gaps, axes or units, noise too small for this IMU, IMU "
            "and GNSS on different clocks: --time-offset), it took a crawl for a stop, or the "
            "GNSS sigmas are too small: compare --method batch, which checks its own fit"
        ), *heights_only]
    nis = float(trajectory.info.get("gnss_nis_median", math.nan))
    if np.isfinite(nis) and nis > FILTER_NIS_MAX:
        return [(
            f"{method}: its IMU predictions miss the GNSS fixes by far more than its covariance "
            f"says (median normalised innovation {nis:.3g} per dimension, ~0.8 expected): IMU "
            "and GNSS on different clocks (--time-offset), wrong axes or units, or IMU noise "
            "set far too small; its output and sigmas are not to be trusted: compare --method "
            "batch, which checks its own fit"
        ), *heights_only]
    return scatter_notes


def filter_initial_guess(
    dataset: Dataset, config: RunConfig, gnss_mask: np.ndarray | None
) -> Callable[[np.ndarray], list[KeyframeGuess]] | None:
    """The initial guesses the factor graph may start from, for the input at hand.

    For an IMU, None: the graph runs its own keyframe EKF over the very factors it
    optimises (:mod:`fgins.graph.keyframe_filter`: the same measurement models, a fifth of
    the cost of the IMU-rate 15-state EKF). For an accelerometer array (gyro-free): the
    18-state EKF on the raw readings, with Huber-weighted GNSS updates, sampled at the
    keyframe times; and, for a car, the guess from the GNSS track and gravity
    (:mod:`fgins.track_guess`), which cannot diverge where the EKF does (GNSS at 0.2 Hz
    leaves the EKF's attitude nothing to hold it between fixes). The graph starts from the
    one that fits its factors best and restarts from the other if that fit fails.

    Huber-weighted updates bound what a gross outlier can do to the guess; a hard innovation
    gate would be worse: once it rejects a few fixes the filter can lock out
    (:func:`fgins.initial_guess.guess_config`).
    """
    if dataset.accel_array is None:
        return None

    def guesses(times: np.ndarray) -> list[KeyframeGuess]:
        # The filter reports its states at the keyframes only (the same numbers as sampling
        # its IMU-rate output there, without making that output: issue 9).
        from fgins.baseline.guess import filter_guess
        from fgins.track_guess import track_guess

        candidates: list[KeyframeGuess] = []
        failures: list[FginsError] = []
        makers = [lambda: filter_guess(dataset, config, times, gnss_mask=gnss_mask)]
        if config.smoother.nhc:  # the vehicle's nose follows its track
            makers.append(lambda: track_guess(dataset, config, times, gnss_mask=gnss_mask))
        for make in makers:
            try:
                candidates.append(make())
            except FginsError as exc:
                failures.append(exc)
        if not candidates:
            raise failures[0]
        return candidates

    return guesses
