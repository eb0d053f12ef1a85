"""Corrections the data call for: each solves the drive again with what they showed.

Every step here looks at a solution (or at the data before one), finds something the
configuration got wrong (IMU noise, turn-on bias sigmas, the IMU's mounting, the GNSS sigmas,
the antenna's lever arm or the clocks), solves the drive again with it corrected through
:class:`Rerun`, keeps the new solution only where it fits better, and says what it did in a
warning with the setting that switches it off. :func:`fgins.pipeline.run_method` runs them in
order. The steps do not import the pipeline: it hands them the solve (no import cycle).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TypeVar

import numpy as np

from fgins.antenna_verdict import (
    LEVER_ARM_CHI2,
    LEVER_ARM_MIN_M,
    TIME_OFFSET_CHI2,
    determined_directions,
    held_directions,
    typical_speed,
)
from fgins.config import NHC_LEVER_MAX_M, STANDARD_GRAVITY, RunConfig
from fgins.datatypes import (
    AccelArrayData,
    BaroData,
    Dataset,
    FginsError,
    GnssData,
    OdometerData,
    Trajectory,
    level_axes,
)
from fgins.factors import gnss as gnss_model
from fgins.gnss_scatter import SIGMA_AXIS_RATIO, SIGMA_TOO_SMALL

SensorData = TypeVar("SensorData", BaroData, OdometerData, AccelArrayData)


@dataclass(frozen=True)
class Rerun:
    """A run's method and outage mask, and how to solve the (corrected) drive with them:
    ``solver(dataset, config, method)``, the pipeline's own dispatch."""

    method: str
    gnss_mask: np.ndarray | None
    solver: Callable[[Dataset, RunConfig, str], Trajectory]

    def solve(self, dataset: Dataset, config: RunConfig, method: str | None = None) -> Trajectory:
        """The drive solved by the run's method (or ``method``) on its outage mask."""
        return self.solver(dataset, config, method or self.method)


# What a correction step (a solve again with something the data showed) said, kept in the
# run's info so that the next step's solve again says it too; and its entries.
CORRECTIONS_SAID = "corrections_said"
# Set in a Kalman baseline's info when its own fit check fails (fgins.pipeline): its antenna
# and clock check then reads the divergence, not the antenna (a filter 15 m off at 0.2 Hz
# GNSS "found" an antenna 15 m to the side and fixes 4.5 s early).
FILTER_FIT_FAILED = "filter_fit_failed"
# In a dataset's metadata: the time (s) the pipeline already moved its fixes' stamps by, in
# a run before this one (fgins.pipeline's passes).
GNSS_STAMPS_MOVED_KEY = "gnss_stamps_moved_s"
# A time offset the antenna and clock check reads at its 5 sigmas and more, whose correction
# did not fit better (s, in a trajectory's info): the sigmas carry it.
TIME_UNRESOLVED_KEY = "gnss_time_offset_unresolved_s"
CARRIED_KEYS = (
    "gnss_sigma_scale",
    "gnss_velocity_sigma_scale",
    "gnss_time_offset_corrected_s",
    "gnss_time_drift_corrected_s",
    "gnss_velocity_lag_corrected_s",
    "gnss_lever_arm_corrected_m",
    "gnss_lever_arm_corrected_cov_m2",
    TIME_UNRESOLVED_KEY,
)
SCATTER_AFTER_MIN = 0.5


def _carry_said(previous: Trajectory, solution: Trajectory, said: list[str]) -> None:
    """``solution`` (a step's solve again of ``previous``'s drive) says what the steps before
    it said and corrected (CORRECTIONS_SAID, CARRIED_KEYS), then ``said``, and keeps both for
    the steps after it."""
    said = [*previous.info.get(CORRECTIONS_SAID, []), *said]  # type: ignore[list-item]
    for key in CARRIED_KEYS:
        if key in previous.info and key not in solution.info:
            solution.info[key] = previous.info[key]
    solution.info[CORRECTIONS_SAID] = said
    solution.info["fit_warnings"] = [*said, *solution.info.get("fit_warnings", [])]

# The densities the [imu] schema allows (fgins.config.IMU_SCHEMA): a measured one beyond them
# is clipped there (a log that vibrates that much is refused by its unit checks first).
MAX_GYRO_DENSITY = 1.0
MAX_ACCEL_DENSITY = 2.0


def noise_from_data(dataset: Dataset, config: RunConfig, run: Rerun) -> tuple[RunConfig, str | None]:
    """The configured white noise, or (a copy of ``config``, said in a warning) the noise
    the IMU shows at rest where that is more than NOISE_EXCESS times larger
    (:mod:`fgins.noise_at_rest`): every method then weighs the IMU by what it reads."""
    from fgins.noise_at_rest import NOISE_EXCESS, noise_excess, white_noise_at_rest

    measured = white_noise_at_rest(dataset, run.gnss_mask)
    if measured is None:
        return config, None
    noise = config.imu_noise()
    excess = noise_excess(measured, noise.gyro_noise, noise.accel_noise)
    if not excess:
        return config, None
    if not config.imu.get("noise_from_data", True):
        # Kept, as asked, but said: an IMU 10-20x noisier than configured had outages 3-4x
        # worse at z 4-11 while the warnings blamed the arm, the clocks and the gyro scale
        # (outside tester), never the noise.
        ratios = ", ".join(
            f"{sensor} {excess[sensor] / configured:.1f} times"
            for sensor, configured in (("gyro", noise.gyro_noise), ("accel", noise.accel_noise))
            if sensor in excess
        )
        return config, (
            f"imu: where the fixes stand still and the IMU shows no trend ({measured.rest_s:.0f}"
            f" s of the log) it reads more white noise than configured ({ratios}); kept as "
            "configured ([imu] noise_from_data = false), so the IMU is weighed above what it "
            "reads: the sigmas inside GNSS outages are too small, and lever-arm, time or "
            "gyro-scale findings may come from this noise (noise_from_data = true uses the "
            "measured noise)"
        )
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
    graded = _bias_of_grade(config, excess)
    imu.update(graded.values)
    return replace(config, imu=imu), (
        f"imu: where the fixes stand still within their noise and the IMU shows no trend "
        f"({measured.rest_s:.0f} s of the log: at rest, or too slow for the fixes to tell) "
        "the IMU reads more white noise "
        f"than configured (over {NOISE_EXCESS:g} times): {'; '.join(said)}. Vibration or a "
        "noisier sensor: the measured noise is used (a floor: a moving vehicle vibrates more)"
        f"{graded.said}. [imu] noise_from_data = false keeps the configured noise"
    )


@dataclass(frozen=True)
class _GradedBias:
    values: dict[str, float]  # [imu] keys set
    said: str  # "" or "; ..." appended to the noise warning


def _bias_of_grade(config: RunConfig, excess: dict[str, float]) -> _GradedBias:
    """The bias instability and turn-on bias of the grade (the IMU preset) whose white noise
    is nearest to what a sensor reads at rest, where that grade's white noise is itself more
    than NOISE_EXCESS times the configured one (a sensor of another grade than configured,
    not a vehicle that vibrates: cars 1.3-2 times a datasheet's accelerometer noise stay in
    their grade) and its bias terms are larger than the configured ones (never smaller).

    A sensor's white noise and its bias stability go together (the presets' ratios span the
    grades); the bias terms cannot be read at rest. A navigation preset on a consumer IMU
    (150 times the gyro's configured noise at rest) took the measured white noise but kept
    biases walking 0.005 deg/h: chi2/dof 39, 14.6 m off the truth, and every antenna and
    clock check read the bias drift as something else; with the consumer grade's bias terms
    the same drive solves as with the right preset."""
    from fgins.config import IMU_PRESETS, imu_noise_from_config
    from fgins.noise_at_rest import NOISE_EXCESS

    configured = config.imu_noise()
    tau = config.imu.get("bias_correlation_time_s")
    grades = {
        name: imu_noise_from_config({"preset": name, **({} if tau is None else {"bias_correlation_time_s": tau})})
        for name in IMU_PRESETS
    }
    values: dict[str, float] = {}
    said = []
    for sensor, white, walk, prior, keys in (
        ("gyro", "gyro_noise", "gyro_bias_rw", "gyro_bias_prior",
         ("gyro_bias_instability_deg_per_hr", "gyro_bias_rw_rad_per_s_per_sqrt_s", "gyro_turn_on_bias_deg_per_s")),
        ("accel", "accel_noise", "accel_bias_rw", "accel_bias_prior",
         ("accel_bias_instability_mg", "accel_bias_rw_m_per_s2_per_sqrt_s", "accel_turn_on_bias_mg")),
    ):  # fmt: skip
        if sensor not in excess:
            continue
        name = min(grades, key=lambda n: abs(math.log(getattr(grades[n], white) / excess[sensor])))
        grade = grades[name]
        if getattr(grade, white) <= NOISE_EXCESS * getattr(configured, white):
            continue
        instability_key, walk_key, prior_key = keys
        taken = []
        if getattr(grade, walk) > getattr(configured, walk):
            values[walk_key] = getattr(grade, walk)
            taken.append(f"bias instability {IMU_PRESETS[name][instability_key]:g} {_UNITS[instability_key]}")
        if getattr(grade, prior) > getattr(configured, prior):
            values[prior_key] = IMU_PRESETS[name][prior_key]
            taken.append(f"turn-on bias {IMU_PRESETS[name][prior_key]:.3g} {_UNITS[prior_key]}")
        if taken:
            said.append(f"{sensor} {' and '.join(taken)}")
    if not said:
        return _GradedBias({}, "")
    return _GradedBias(
        values,
        "; noise of another grade than configured has its biases too: the nearest preset's "
        f"{', '.join(said)} are used",
    )


_UNITS = {
    "gyro_bias_instability_deg_per_hr": "deg/h",
    "gyro_turn_on_bias_deg_per_s": "deg/s",
    "accel_bias_instability_mg": "mg",
    "accel_turn_on_bias_mg": "mg",
}


# A solved turn-on bias this many of its prior sigmas from zero (on any axis) says the prior
# is wrong, not the bias: a right one is beyond 5 sigma on one of three axes once in ~600,000
# drives. The drive is solved again with the prior this many times the largest estimate.
TURN_ON_BIAS_EXCESS = 5.0
TURN_ON_BIAS_WIDENED = 2.0


def clock_correction_pending(config: RunConfig, trajectory: Trajectory) -> bool:
    """Does ``trajectory``'s antenna and clock check find the fixes' time stamps off, which
    :func:`with_antenna_corrected` will correct? Then its biases are not yet the IMU's:
    fixes 2 s late made a forward EKF's accelerometer bias 6 times its turn-on sigma, and
    the solve with that sigma widened left the filter too far off to check its clocks (28 m
    inside outages; with the stamps corrected first, 2.9 m). An arm found is not one: a
    turn-on sigma far too small (0.5 mg for a 10 mg bias) made the filter's check find an
    antenna 4.4 m off, while the bias, widened first, explained the drive (0.39 m)."""
    info = trajectory.info
    return bool(
        config.gnss.time_offset_from_data
        and any(key in info for key in ("gnss_time_offset_s", "gnss_time_drift_s", "gnss_velocity_lag_s"))
    )


# A clock offset found in the first solution is corrected before the fixes' sigmas are judged
# where it moves them by this many of their (median horizontal) sigmas at the drive's typical
# speed, and is at least OFFSET_FIRST_MIN_S: their scatter is then the offset's. Judged first,
# fixes 2 s late on an urban car scattered 2.1x, the sigmas were widened so, and the 0.15 s
# the first correction left (one linear step) hid under them: 1.6 m inside outages, 0.7 m
# with the stamps right. Below it the sigmas come first (sigmas too small make a small
# latency look significant).
OFFSET_FIRST_SIGMAS = 5.0
OFFSET_FIRST_MIN_S = 0.5


def clock_offset_first(dataset: Dataset, config: RunConfig, trajectory: Trajectory) -> bool:
    """Is the time offset ``trajectory``'s antenna and clock check finds large enough to be
    corrected before the fixes' sigmas are judged (OFFSET_FIRST_SIGMAS)?"""
    offset = trajectory.info.get("gnss_time_offset_s")
    if not config.gnss.time_offset_from_data or not isinstance(offset, float):
        return False
    # Two clocks: the offset at the drive's ends (its middle's plus the drift). An IMU clock
    # 0.5 % fast on a 300 s drive (0.75 s at the ends) had the fixes' sigmas scaled 3.9x
    # before the clocks were corrected and never judged again: the track right, its sigmas
    # 3-4x too large (outside tester).
    drift = trajectory.info.get("gnss_time_drift_s")
    offset = abs(offset) + (abs(drift) if isinstance(drift, float) else 0.0)
    if offset < OFFSET_FIRST_MIN_S:
        return False
    speed = typical_speed(np.linalg.norm(np.asarray(trajectory.velocity)[:, :2], axis=1))
    sigmas = gnss_model.position_sigmas(dataset.gnss, config.gnss)[:, :2]
    sigma = float(np.nanmedian(sigmas)) if np.isfinite(sigmas).any() else math.nan
    return bool(math.isfinite(sigma) and sigma > 0 and offset * speed > OFFSET_FIRST_SIGMAS * sigma)


def with_turn_on_bias_widened(
    dataset: Dataset, config: RunConfig, run: Rerun, trajectory: Trajectory
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
        again = run.solve(dataset, widened_config)
    except FginsError:
        return trajectory, config, (
            f"imu: {'; '.join(said)} failed; the configured turn-on sigmas are too small for "
            "this IMU ([imu] gyro_turn_on_bias_deg_per_s, accel_turn_on_bias_mg, --imu-preset)"
        )
    if again.info.get(FILTER_FIT_FAILED):
        # Still diverged with the wider prior: the biases were the diverged filter's, no
        # reading of the IMU (a multirotor whose hover heading ran away: 'accelerometer bias
        # 9.2x its 15 mg sigma, solved again with 276 mg' where the true ones fit 15 mg;
        # outside tester). The first solve and its own warnings stand.
        return trajectory, config, None
    _carry_said(trajectory, again, [])  # the antenna's, when this runs after it
    return again, widened_config, (
        f"imu: {'; '.join(said)}: the configured turn-on bias sigmas are too small for this "
        "IMU (a preset of a better grade? --imu-preset, [imu]); [imu] turn_on_bias_from_data = "
        "false keeps them"
    )


# The methods whose solutions carry the antenna and clock check (fgins.antenna_verdict): the
# graph's (fgins.graph.reports.lever_arm_report) and the Kalman baselines' with the 15-state
# model (fgins.baseline.ekf.antenna_about; the planar and gyro-free filters have none).
ANTENNA_CHECKED_METHODS = ("batch", "isam2", "isam2-online", "ekf", "ekf-rts", "ukf")
# Rounds of antenna and clock corrections: a fix stamped late is found at once (0.193 s of
# 0.2), an IMU clock's drift only in part where the drive's biases absorb some (an aircraft
# whose IMU runs 300 ppm fast: 30 % in the first round).
ANTENNA_ROUNDS = 4


def with_antenna_corrected(
    dataset: Dataset, config: RunConfig, run: Rerun, trajectory: Trajectory
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
    if run.method not in ANTENNA_CHECKED_METHODS:
        return trajectory, dataset, config
    fit_key, fit_name = ("chi2_per_dof", "chi2/dof") if run.method in ("batch", "isam2", "isam2-online") else (
        "gnss_nis_mean", "mean NIS of the GNSS updates"
    )  # fmt: skip
    first, best = trajectory, trajectory
    # Called again after the sigmas were judged (clock_offset_first), it goes on from what
    # the first call corrected: the totals are said and kept.
    done_before = trajectory.info
    fixes_moved = velocity_lag = 0.0
    if "gnss_time_drift_corrected_s" not in done_before:
        fixes_moved = float(done_before.get("gnss_time_offset_corrected_s", 0.0))  # type: ignore[arg-type]
    velocity_lag = float(done_before.get("gnss_velocity_lag_corrected_s", 0.0))  # type: ignore[arg-type]
    imu_t0, imu_t1 = float(dataset.imu.t[0]), float(dataset.imu.t[-1])
    drifting, last = False, (0.0, 0.0)
    arm_taken = done_before.get("gnss_lever_arm_corrected_m")
    arm_covariance = done_before.get("gnss_lever_arm_corrected_cov_m2")
    tried = clocks_declined = False
    declined: tuple[object, object] | None = None  # (fit before, fit with the correction)
    declined_time = 0.0  # the time offset (s) of a declined correction
    implausible: list[str] = []  # readings no vehicle or clock can have: not taken
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
        refining = False
        if arm is None and arm_taken is not None and config.gnss.lever_arm_from_data:
            arm = _refined_arm(info, arm_taken)
            refining = arm is not None
        offset_refined = False
        moved_before = fixes_moved or dataset.metadata.get(GNSS_STAMPS_MOVED_KEY)
        searched = bool(dataset.metadata.get(GNSS_STAMPS_SEARCHED_KEY))
        if offset is None and moved_before and not drifting and not searched and config.gnss.time_offset_from_data:
            # The check is one Gauss-Newton step about a solution that absorbed part of the
            # offset (fixes 2 s late found at 1.85, the rest 0.14 +- 0.04 s, under its 5 sigmas
            # for a finding, left 1.5 m inside outages against 0.7): the rest of an offset
            # already found is taken while it shows at 2 sigma and the fit improves.
            rest, rest_sigma = info.get("gnss_time_offset_fit_s"), info.get("gnss_time_offset_fit_sigma_s")
            if isinstance(rest, float) and isinstance(rest_sigma, float) and abs(rest) > 2.0 * rest_sigma:
                offset, offset_refined = rest, True
        drift = float(info.get("gnss_time_drift_s", 0.0))  # type: ignore[arg-type]
        half_span = float(info.get("gnss_time_half_span_s", 0.0) or 0.0)  # type: ignore[arg-type]
        if drift and half_span > 0 and abs(drift) / half_span > MAX_CLOCK_RATE:
            # No oscillator is that far off: the "drift" is a misfit of something else (a
            # multirotor given --vehicle car: a 4.5 % rate taken, the output's times rewritten).
            implausible.append(f"two clocks {100 * abs(drift) / half_span:.1f} % apart in rate (oscillators: 0.002-0.5 %)")
            offset, drift = None, 0.0
        if arm is not None and config.smoother.nhc and float(np.linalg.norm(arm)) > NHC_LEVER_MAX_M:  # type: ignore[arg-type]
            implausible.append(f"an antenna {float(np.linalg.norm(arm)):.0f} m from the IMU (a car is under {NHC_LEVER_MAX_M:g} m)")  # type: ignore[arg-type]
            arm = None
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
        if lag is not None and (offset is None or abs(float(offset)) <= abs(float(lag))):  # type: ignore[arg-type]
            # The velocities' delay alone first: the check models it to first order (the
            # acceleration times the delay), and what is left, the second derivative times
            # half its square, lies along the track in turns as a vertical arm's velocity
            # does (an aircraft's velocities 0.5 s late read as an antenna 2 m above the
            # IMU); the next round asks again with the velocities on time.
            offset = arm = None
        elif lag is not None and offset is not None:
            # The fixes' offset first, velocities with them: a delay of both reads, before it
            # is corrected, partly as velocities early against their positions (fixes 2 s
            # late: 1.85 s, and their velocities 0.88 s "early", taken together 2.4 s off).
            lag = None
        first_clocks = bool(drift) and not drifting and offset is not None
        drifting, last = drifting or bool(drift), (offset or 0.0, drift)
        trial, trial_config, trial_moved, trial_lag = dataset, config, fixes_moved, velocity_lag
        if lag is not None:
            trial = replace(trial, gnss=_velocities_retimed(trial.gnss, float(lag), best))  # type: ignore[arg-type]
            trial_lag += float(lag)  # type: ignore[arg-type]
        unshifted = trial
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
        tried = True
        try:
            corrected = run.solve(trial, trial_config)
        except FginsError:
            break
        one_clock: Trajectory | None = None
        if first_clocks:
            # Two clocks only where they fit better than the offset alone (a latency): the
            # check is first order in the offset, and a fixed-wing's fixes 0.5 s late read
            # as +0.2 s at the start and +0.66 s at the end through its turns; taken as two
            # clocks, the output went onto the receiver's clock, 0.5 s (12-30 m) from the
            # IMU's, with NEES 1,300-9,300.
            latency = replace(unshifted, gnss=replace(unshifted.gnss, t=unshifted.gnss.t - offset))
            try:
                one_clock = run.solve(latency, trial_config)
            except FginsError:
                one_clock = None
            if one_clock is not None and not _fits_better(corrected, one_clock, fit_key, CLOCK_CHI2_GAIN):
                corrected, trial, trial_moved, drifting = one_clock, latency, trial_moved - offset, False
                clocks_declined = True
        # Kept only where it fits better by CORRECTION_CHI2_PER_NUMBER per number taken. A
        # correction that explains nothing is not a finding: velocities weighted 2x too much
        # in a stretch of HDOP 3.5 read to EKF+RTS as an antenna 1 m ahead of the configured
        # one at 5 sigma; taken, its total fit gained 3.7-8.5 and the outage went 0.47 ->
        # 0.99 m.
        taken = 3 * (arm is not None) + (offset is not None) + bool(drift) + (lag is not None)
        if refining:  # the arm is a finding already: its refinement needs only to fit better
            taken -= 3
        if offset_refined:  # likewise the offset
            taken -= 1
        margin = CORRECTION_CHI2_PER_NUMBER * taken
        latency_only = one_clock if first_clocks else (None if drifting else corrected)
        further = None
        if latency_only is not None and offset is not None:
            further = _offset_continued(latency_only.info, offset)
        if further is not None and not _fits_better(corrected, best, fit_key, margin):
            # The reading is one Gauss-Newton step about a solution that left out, as faults,
            # the very fixes that show the delay: a fixed-wing's fixes 0.5 s late in a 60 deg
            # bank read as 0.61 s, and solved so, the fit was worse than the faulted solution
            # (chi2/dof 2.21 against 1.67), which kept the track 40 m off; the next step
            # (-0.105 s, to 0.503) fits at 0.87. One step more before the verdict.
            latency = replace(unshifted, gnss=replace(unshifted.gnss, t=unshifted.gnss.t - further))
            try:
                stepped = run.solve(latency, trial_config)
            except FginsError:
                stepped = None
            if stepped is not None and _fits_better(stepped, best, fit_key, margin):
                corrected, trial, trial_moved, offset = stepped, latency, fixes_moved - further, further
                clocks_declined, drifting = clocks_declined or first_clocks, False
        if not _fits_better(corrected, best, fit_key, margin):
            if not ((refining or offset_refined) and taken == 0):  # a refinement that gains nothing just stops
                declined = (best.info.get(fit_key), corrected.info.get(fit_key))
                if offset is not None:  # the clock's reading, at its largest along the drive
                    declined_time = abs(float(offset)) + abs(drift)
            break
        best, dataset, config, fixes_moved, velocity_lag = corrected, trial, trial_config, trial_moved, trial_lag
        if arm is not None:
            # A refinement keeps the finding's covariance (the verdict says nothing new).
            arm_taken, arm_covariance = arm, info.get("gnss_lever_arm_cov_m2") or arm_covariance
    moved_here = fixes_moved - float(done_before.get("gnss_time_offset_corrected_s", 0.0) or 0.0)  # type: ignore[arg-type]
    on_imu_clock = float(dataset.imu.t[0]) == imu_t0 and float(dataset.imu.t[-1]) == imu_t1
    first_pass = not dataset.metadata.get(GNSS_STAMPS_MOVED_KEY)
    if (best is not first and abs(moved_here) >= LINE_SEARCH_MIN_OFFSET_S and on_imu_clock
            and first_pass and arm_taken is None and config.gnss.time_offset_from_data):  # fmt: skip
        found = _offset_line_search(run, dataset, config, best, fit_key)
        if found is not None:
            best, dataset, extra = found
            fixes_moved -= extra
    if implausible:
        best.info.setdefault("fit_warnings", []).append(
            f"GNSS antenna: the fixes fit {' and '.join(dict.fromkeys(implausible))}: not "
            "taken, as no car or clock is so; the vehicle constraints fit poorly (the vehicle "
            "may not be a car: --vehicle) or the inputs' axes or clocks are wrong"
        )
    filter_failed = best is first and tried and bool(first.info.get(FILTER_FIT_FAILED))
    if filter_failed:
        # Corrected, it fit no better: what the check found is the divergence's (said in the
        # filter's own note), not the antenna's.
        first.info["fit_warnings"] = _findings_reworded(
            first.info.get("fit_warnings", []), tuple(first.info.pop("antenna_findings", None) or ()), None
        )
    elif declined is not None:
        # The check's reading, solved with, explains nothing: no advice to set it.
        before, after = (f"{v:.2f}" if isinstance(v, float) else "?" for v in declined)
        best.info["fit_warnings"] = _findings_reworded(
            best.info.get("fit_warnings", []),
            tuple(best.info.get("antenna_findings") or ()),
            f"solved again with it, the fit is no better ({fit_name} {before} -> {after}): "
            "left as configured (GNSS sigmas set too small make small offsets look significant)"
            + (
                f"; the output's sigmas include {declined_time:.2f} s along the track, which "
                "the fixes show and the solve could not take"
                if declined_time
                else ""
            ),
        )
        if declined_time:
            best.info[TIME_UNRESOLVED_KEY] = declined_time
    if best is first:
        return first, dataset, config
    done, switches = [], []
    if fixes_moved:
        best.info["gnss_time_offset_corrected_s"] = fixes_moved
        done.append(moved_phrase(fixes_moved))
        if clocks_declined:
            done[-1] += " (one offset fits as well as two clocks: the IMU's clock is kept)"
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
        held = _held_arm_axes(arm_covariance)
        if held:
            # A level car cannot show its antenna's height above the IMU: the heights are then
            # the antenna's, off by what the true arm has there (an outside tester's 1.2 m:
            # heights 1.4 m off at sigma 0.2-0.3, the arm said "corrected" to 0.00).
            done[-1] += (
                f" (its {' and '.join(held)} not determined by this drive and kept as "
                "configured: positions along it are the antenna's, off the IMU's by what the "
                "true arm has there; measure and set it)"
            )
        switches.append("lever_arm_from_data = false the configured arm")
    before, after = first.info.get(fit_key), best.info.get(fit_key)
    how = (
        f"{' and '.join(done)}, and the drive solved again ({fit_name} {before:.2f} -> "
        f"{after:.2f}; {', '.join(switches)})"
    )
    findings = first.info.get("antenna_findings") or ["GNSS antenna"]
    _carry_said(first, best, [f"{finding}: corrected, {how}" for finding in findings])  # type: ignore[union-attr]
    return best, dataset, config


# In a dataset's metadata: an earlier pass found its fixes' offset by the line search (the
# next pass then takes no rest of it under the finding's 5 sigmas: the search stood there).
GNSS_STAMPS_SEARCHED_KEY = "gnss_stamps_searched"
# In a solution's info: the sigma (s) of the fixes' time offset the line search measured.
SEARCH_SIGMA_KEY = "gnss_time_offset_search_sigma_s"
# The line search over the fixes' time offset (see _offset_line_search): its first step in
# the offset's sigmas as the check read it, at least LINE_SEARCH_MIN_STEP_S, and at most
# LINE_SEARCH_SOLVES solves, in the first pass that moves the stamps only.
LINE_SEARCH_STEP_SIGMAS = 3.0
LINE_SEARCH_MIN_STEP_S = 0.05
LINE_SEARCH_SOLVES = 4
# Only for offsets this large: a step about a solution bent by whole seconds is what falls
# short; a latency of tenths the rounds of steps take to within their sigma.
LINE_SEARCH_MIN_OFFSET_S = 0.5


def _offset_line_search(
    run: Rerun, dataset: Dataset, config: RunConfig, best: Trajectory, fit_key: str
) -> tuple[Trajectory, Dataset, float] | None:
    """The fixes' time offset where the fit is best, searched about the one taken: (the
    solution, its dataset, the further move of the fixes' stamps (s)), or None where no
    offset nearby fits better.

    The check reads an offset by one Gauss-Newton step about a solution that has absorbed
    part of it (the mounting, the biases and the heading bend towards late fixes), and the
    rounds stop once the rest falls under 2 of its sigmas: a highway drive's fixes 2 s late
    were taken at 1.79 s, 0.21 s (6 m at 28 m/s, 3.7 of the output's sigmas) short of the
    fit's own minimum at 1.95-2.0 s. Here each trial is solved in full, and a parabola
    through the fits (chi2/dof times the best solution's dof: a trial moves fixes in or out
    of the IMU's span) steps to its vertex."""
    sigma = best.info.get("gnss_time_offset_fit_sigma_s")
    step = LINE_SEARCH_MIN_STEP_S
    if isinstance(sigma, float) and math.isfinite(sigma):
        step = max(step, LINE_SEARCH_STEP_SIGMAS * sigma)
    dof = best.info.get("dof") if fit_key == "chi2_per_dof" else None

    def fit_of(trajectory: Trajectory) -> float:
        value = trajectory.info.get(fit_key)
        if dof is None or not isinstance(value, float):
            return _fit_total(trajectory.info, fit_key)
        return value * float(dof)  # type: ignore[arg-type]

    tried: dict[float, tuple[float, Trajectory, Dataset]] = {0.0: (fit_of(best), best, dataset)}

    def trial(shift: float) -> None:
        if shift in tried or len(tried) > LINE_SEARCH_SOLVES:  # the best's own is no trial
            return
        moved = replace(dataset, gnss=replace(dataset.gnss, t=dataset.gnss.t - shift))
        try:
            solution = run.solve(moved, config)
        except FginsError:
            return
        tried[shift] = (fit_of(solution), solution, moved)

    trial(-step)
    trial(step)
    for _ in range(2):  # to the vertex of the parabola through the three trials nearest the best
        centre = min(tried, key=lambda v: tried[v][0])
        near = sorted(tried, key=lambda v: abs(v - centre))[:3]
        x = np.array(near) - centre
        y = np.array([tried[v][0] for v in near])
        if len(near) < 3 or not np.all(np.isfinite(y)):
            break
        curve, slope, _ = np.polyfit(x, y, 2)
        if curve <= 0:  # no minimum between them
            break
        trial(round(centre + float(np.clip(-slope / (2 * curve), -2 * step, 2 * step)), 4))
    shift = min(tried, key=lambda v: tried[v][0])
    if shift == 0.0 or not tried[shift][0] < tried[0.0][0]:
        return None
    _, solution, moved = tried[shift]
    solution.info[SEARCH_SIGMA_KEY] = _search_sigma(tried, shift)
    return solution, moved, shift


def _search_sigma(tried: dict[float, tuple[float, Trajectory, Dataset]], best: float) -> float:
    """The offset's sigma (s) from the curvature of the fits about ``best``: chi-square
    rises by (x / sigma)^2 away from its minimum. Each trial is solved with the offset
    held, the rest free, so the curve is the data's own (a highway drive whose check read
    +-0.06 s had fits 3 apart over 0.4 s: +-0.13 s, and the offset was 0.24 s off). Where
    the fits do not curve up, the span searched."""
    x = np.array(sorted(tried)) - best
    y = np.array([tried[v][0] for v in sorted(tried)])
    span = float(np.ptp(x)) if len(x) > 1 else LINE_SEARCH_MIN_STEP_S
    if len(x) < 3 or not np.all(np.isfinite(y)):
        return span
    curve = float(np.polyfit(x, y, 2)[0])
    return float(1.0 / np.sqrt(curve)) if curve > 1.0 / span**2 else span


def moved_phrase(moved: float) -> str:
    """How a move of the fixes' stamps by ``moved`` s is said (fgins.pipeline's passes find
    it in the lines and put the total in its place)."""
    return f"the fixes' times moved by {moved:+.3f} s (as --time-offset {moved:+.3f})"


def _refined_arm(info: dict[str, object], taken: list[float]) -> list[float] | None:
    """The arm a solution with the arm ``taken`` points to next, in the components the drive
    determines, or None when that is within REFINE_ARM_SIGMAS of ``taken``. The check is one
    Gauss-Newton step about a solution that has absorbed part of the arm: an antenna 1.5 m
    behind the IMU, unconfigured, was found at -1.46 m over 10 seeds of an independent
    simulator (EKF+RTS, whose filter carries the arm: -1.50), and the batch came out 10 %
    worse than EKF+RTS inside outages; the step about the corrected solution finds the
    rest."""
    fit, covariance = info.get("gnss_lever_arm_fit_m"), info.get("gnss_lever_arm_fit_cov_m2")
    if not isinstance(fit, list) or not isinstance(covariance, list) or len(fit) != 3:
        return None
    fit_a, taken_a = np.asarray(fit, dtype=float), np.asarray(taken, dtype=float)
    cov = np.asarray(covariance, dtype=float).reshape(3, 3)
    if not (np.all(np.isfinite(fit_a)) and np.all(np.isfinite(cov))):
        return None
    directions, variances = determined_directions(cov)
    if not directions.shape[1]:
        return None
    rest = directions.T @ (fit_a - taken_a)  # along each determined direction
    if np.max(np.abs(rest) / np.sqrt(variances)) < REFINE_ARM_SIGMAS:
        return None
    return [float(x) for x in taken_a + directions @ rest]


REFINE_ARM_SIGMAS = 0.5


# Two clocks further apart in rate than this are not two clocks: crystal oscillators are off
# by 20-5000 ppm.
MAX_CLOCK_RATE = 0.01


# What a correction must gain in total fit (chi-square, or a filter's NIS summed over its GNSS
# components) per number it takes (3 for an arm, 1 for a time offset, its drift, a velocity
# lag). Real ones gain far more: 34-8,300 for the arms, latencies and clocks of
# tests/test_kalman_antenna_check.py, test_gnss_time_offset.py and test_flight_gnss_latency.py.
CORRECTION_CHI2_PER_NUMBER = 4.0


def _findings_reworded(warnings: list[str], findings: tuple[str, ...], then: str | None) -> list[str]:
    """``warnings`` with each line that says one of ``findings`` ending in ``then`` instead of
    its advice, or left out where ``then`` is None."""
    out = []
    for warning in warnings:
        finding = next((f for f in findings if warning.startswith(f)), None)
        if finding is None:
            out.append(warning)
        elif then is not None:
            out.append(f"{finding}: {then}")
    return out


# How much better (in total chi-square: chi2/dof times dof, or a filter's mean NIS times its
# GNSS measurements) two clocks must fit than one offset to be taken: the drift's 4 sigma
# (fgins.antenna_verdict.CLOCK_CHI2).
CLOCK_CHI2_GAIN = 16.0


def _held_arm_axes(covariance: object) -> list[str]:
    """The parts of an arm taken from the data held as configured (the null space of its
    covariance: fgins.antenna_verdict's undetermined directions), said as an IMU axis ("z
    part") where one lies along it, else by its direction in IMU axes."""
    if covariance is None:
        return []
    out = []
    for direction in held_directions(covariance):
        axis = int(np.argmax(np.abs(direction)))
        if abs(direction[axis]) > 0.99:
            out.append(f"{'xyz'[axis]} part")
        else:
            unit = direction if direction[axis] > 0 else -direction
            out.append(f"part along [{', '.join(f'{x:.2f}' for x in unit)}] (IMU axes)")
    return out


def _offset_continued(info: dict[str, object], offset: float) -> float | None:
    """The fixes' offset one step on (s): ``offset`` plus what a solution with the fixes
    moved by it still reads, where that rest shows at 2 sigma and is less than half the step
    taken (the reading converges); else None."""
    rest, sigma = info.get("gnss_time_offset_fit_s"), info.get("gnss_time_offset_fit_sigma_s")
    if not (isinstance(rest, float) and isinstance(sigma, float)):
        return None
    if abs(rest) <= 2.0 * sigma or abs(rest) >= 0.5 * abs(offset):
        return None
    return offset + rest


def _fit_total(info: dict[str, object], fit_key: str) -> float:
    """A solution's total fit: chi2/dof x dof (graph), mean NIS x 3 per GNSS update (filter)."""
    value = info.get(fit_key)
    count = info.get("dof") if fit_key == "chi2_per_dof" else 3 * float(info.get("gnss_updates", 0))  # type: ignore[arg-type]
    if not (isinstance(value, float) and isinstance(count, (int, float)) and math.isfinite(value)):
        return math.inf
    return value * float(count)


def _fits_better(a: Trajectory, b: Trajectory, fit_key: str, margin: float) -> bool:
    """Does ``a`` fit its data better than ``b`` by more than ``margin`` of total chi-square?"""
    return _fit_total(a.info, fit_key) < _fit_total(b.info, fit_key) - margin


def add_arm_uncertainty(trajectory: Trajectory, covariance: object) -> None:
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


def add_mounting_uncertainty(trajectory: Trajectory, sigma_deg: float) -> None:
    """Add the uncertainty of a mounting taken from the data (1-sigma ``sigma_deg`` about
    the vehicle's up and across axes) to ``trajectory``'s attitude covariance (in place).
    The car's constraints tie the IMU's heading and pitch to the track through the
    mounting, so an error of the mounting is one of the IMU's attitude; the solves hold it
    fixed. (An independent simulator's highway, mounting [3, -4, 25] deg taken 0.34 deg off
    in yaw at 0.14 deg sigma: heading 0.31 deg off at a reported 0.06, NEES 35.)"""
    if not sigma_deg or trajectory.attitude_cov is None:
        return
    variance = np.radians(sigma_deg) ** 2
    _, across = level_axes(trajectory.rotation)
    up = np.zeros_like(across)
    up[:, 2] = 1.0
    trajectory.attitude_cov = trajectory.attitude_cov + variance * (
        np.einsum("ni,nj->nij", up, up) + np.einsum("ni,nj->nij", across, across)
    )
    trajectory.info["imu_mounting_sigma_deg"] = float(sigma_deg)


def add_unresolved_time_uncertainty(trajectory: Trajectory) -> None:
    """Add a time offset the fixes show but the solve could not take
    (``TIME_UNRESOLVED_KEY``) to ``trajectory``'s position covariance (in place), along its
    velocity as :func:`add_time_offset_uncertainty`. An independent simulator's aircraft in
    a 60 deg bank with its fixes 0.5 s late: the turn's fixes left out as faults, the clocks
    read as 0.38-0.84 s, corrected no better, and the track 40 m off at sigmas of 0.3 m
    (z 116), exit 0. A reading this size means the track may lie that far along itself."""
    offset = trajectory.info.get(TIME_UNRESOLVED_KEY)
    if isinstance(offset, float) and offset > 0.0:
        _add_along_track(trajectory, offset)


# An antenna the fixes put this many sigmas (chi-square over the arm's determined
# directions) and this far (m) from the configured lever arm, under what a correction needs,
# is carried in the output's sigmas and said.
UNCONFIRMED_ARM_CHI2 = 9.0
UNCONFIRMED_ARM_MIN_M = 0.3
UNCONFIRMED_ARM_VELOCITY_SCALE = 1.5


def carry_unconfirmed_arm(trajectory: Trajectory, configured: object) -> str | None:
    """An antenna the last solve's check reads away from the configured lever arm at
    UNCONFIRMED_ARM_CHI2 or more but under what a correction needs (fgins.antenna_verdict),
    added to the output's position covariance as an arm error (its size and its covariance,
    in the directions the drive determines), and the line saying so; None where nothing was
    read, or the arm was corrected or said. An outside tester's car given its antenna 0.58 m
    off horizontally (1 Hz fixes of 0.5 m): read at chi2 23 (25 needed), nothing said, the
    track 0.57 m off at the fixes at sigma 0.15 (z 4)."""
    info = trajectory.info
    # Only a reading of fixes that fit otherwise: none where the check found or corrected
    # anything (a time offset reads as an arm along the track), where the fixes or their
    # velocities scatter beyond twice their sigmas (sigmas too small make any offset look
    # significant) or more than a few lie beyond 4 sigma (a run of multipath bends it).
    if any(key in info for key in (
        "gnss_lever_arm_corrected_m", "antenna_findings", TIME_UNRESOLVED_KEY,
        "gnss_time_offset_corrected_s", "gnss_velocity_lag_corrected_s", "gnss_velocity_lag_s",
    )) or any(
        str(w).startswith(("GNSS lever arm", "GNSS time")) for w in info.get("fit_warnings", [])  # type: ignore[union-attr]
    ):
        return None
    # (Velocities, which tie the arm to the turn rate, already at 1.5x: weighted 2x too
    # much, 1.84x, they read an arm 0.83 m off the true one at 3.2 sigma.)
    for key, most in (("gnss_whitened_scale_horizontal", SIGMA_TOO_SMALL),
                      ("gnss_velocity_whitened_scale_horizontal", UNCONFIRMED_ARM_VELOCITY_SCALE)):  # fmt: skip
        scale = info.get(key)
        if isinstance(scale, float) and scale > most:
            return None
    large = info.get("gnss_large_residual_times") or []
    used = info.get("gnss_epochs_used")
    if len(large) > max(2, 0.01 * (used if isinstance(used, int) else 0)):  # type: ignore[arg-type]
        return None
    fit, cov = info.get("gnss_lever_arm_fit_m"), info.get("gnss_lever_arm_fit_cov_m2")
    if fit is None or cov is None or configured is None:
        return None
    shift = np.asarray(fit, dtype=float) - np.asarray(configured, dtype=float)
    covariance = np.asarray(cov, dtype=float).reshape(3, 3)
    if not (np.all(np.isfinite(shift)) and np.all(np.isfinite(covariance))):
        return None
    basis, variances = determined_directions(covariance)
    basis, variances = basis[:, variances > 0.0], variances[variances > 0.0]
    if not len(variances):
        return None
    along = basis.T @ shift
    chi2 = float(np.sum(along**2 / variances))
    size = float(np.linalg.norm(along))
    if not UNCONFIRMED_ARM_CHI2 <= chi2 < LEVER_ARM_CHI2 or size < UNCONFIRMED_ARM_MIN_M:
        return None
    part = basis @ along
    arm_cov = np.outer(part, part) + basis @ np.diag(variances) @ basis.T
    add_arm_uncertainty(trajectory, arm_cov)
    info["gnss_lever_arm_unconfirmed_m"] = [float(x) for x in part]
    shown = ", ".join(f"{x:.2f}" for x in np.asarray(configured, dtype=float) + part)
    return (
        f"GNSS lever arm: the fixes fit an antenna {size:.2f} m from the configured one (at "
        f"[{shown}] m in IMU axes, {math.sqrt(chi2):.1f} sigma, under what a correction needs): "
        f"the output's sigmas include it; measure the arm and set [gnss] lever_arm_m"
    )


# A time offset the fixes show at this many sigmas, under the 5 a correction needs, moving
# them at least LEVER_ARM_MIN_M at the drive's typical speed, is carried in the sigmas.
UNCONFIRMED_TIME_SIGMAS = 2.5


def carry_unconfirmed_time_offset(trajectory: Trajectory, time_from_data: bool = True) -> str | None:
    """A time offset the last solve's check reads at UNCONFIRMED_TIME_SIGMAS or more but
    under its 5 sigmas for a correction (correlated fix errors read so too), set as
    ``TIME_UNRESOLVED_KEY`` (its size plus its sigma) for the output's sigmas along the track,
    and the line saying so; None where nothing was read or it was corrected or declined.
    An independent simulator's car at 50 m/s with fixes 50 ms late read 0.032 +- 0.010 s,
    said nothing, and its track was 2.4 m off at sigma 0.17 (z 10; an aircraft at 250 m/s
    with 20-50 ms: 5-12 m, z 15-36)."""
    info = trajectory.info
    if TIME_UNRESOLVED_KEY in info or "gnss_time_offset_corrected_s" in info:
        return None
    if "gnss_velocity_lag_corrected_s" in info:
        # the velocities moved already: what is left of their delay reads as the fixes'
        # (velocities 0.5 s late, positions on time: "0.093 s early" after the correction)
        return None
    reading, sigma = info.get("gnss_time_offset_fit_s"), info.get("gnss_time_offset_fit_sigma_s")
    if not (isinstance(reading, float) and isinstance(sigma, float) and sigma > 0.0):
        return None
    confirmed = abs(reading) >= math.sqrt(TIME_OFFSET_CHI2) * sigma
    if abs(reading) < UNCONFIRMED_TIME_SIGMAS * sigma or (confirmed and time_from_data):
        return None
    typical = typical_speed(np.linalg.norm(np.asarray(trajectory.velocity)[:, :2], axis=1))
    seconds = abs(reading) + sigma
    if seconds * typical < LEVER_ARM_MIN_M:
        return None
    info[TIME_UNRESOLVED_KEY] = seconds
    if confirmed:
        # Found, not corrected as asked ([gnss] time_offset_from_data = false): fixes 0.2 s
        # late left the track 2-3 m off at z 6-8 while the fault exclusion and the slow-error
        # check read the offset as their own (outside tester). The sigmas carry it.
        kept = (
            f"kept as stamped ([gnss] time_offset_from_data = false): the output's sigmas "
            f"include {seconds:.3f} s along the track ({seconds * typical:.1f} m at "
            f"{typical:.0f} m/s), and fixes left out as faults or read as slow errors may be "
            "this offset's"
        )
        warnings = info.setdefault("fit_warnings", [])
        for i, line in enumerate(warnings):  # type: ignore[union-attr]
            if line.startswith("GNSS time:") or line.startswith("GNSS lever arm or time:"):
                warnings[i] = f"{line}; {kept}"  # type: ignore[index]
                return None
        return (
            f"GNSS time: the fixes fit time stamps {abs(reading):.3f} +- {sigma:.3f} s "
            f"{'late' if reading > 0 else 'early'} against the IMU's, {kept}; give "
            f"--time-offset {-reading:+.3f} if the time bases differ"
        )
    return (
        f"GNSS time: the fixes fit time stamps {abs(reading):.3f} +- {sigma:.3f} s "
        f"{'late' if reading > 0 else 'early'} against the IMU's ({abs(reading) / sigma:.1f} "
        "sigma, under the 5 a correction needs: fixes' errors correlated over seconds read so "
        f"too): the output's sigmas include {seconds:.3f} s along the track ({seconds * typical:.1f} m "
        f"at {typical:.0f} m/s); if the time bases differ, give --time-offset {-reading:+.3f}"
    )


# The drive tells the fixes' time stamps only to a sigma that moves the track this far
# along itself at its typical speed, and this many times the output's own horizontal sigma:
# said (see time_unresolved_note).
TIME_BLIND_MIN_M = 1.0
TIME_BLIND_SIGMAS = 3.0
# ... and only a sigma this large (s): a check to 20 ms (an aircraft at 60 m/s: 1.2 m) has
# checked the stamps against the latencies that matter (0.05-0.3 s over a serial line).
TIME_BLIND_MIN_S = 0.04


def time_unresolved_note(trajectory: Trajectory) -> str | None:
    """Where the drive cannot check the fixes' time stamps: its check's sigma for their
    offset, at the drive's typical speed, beyond TIME_BLIND_MIN_M and TIME_BLIND_SIGMAS of
    the output's median horizontal sigma, with nothing read, corrected or carried. At one
    steady speed on a straight road a latency moves the fixes along the track exactly as the
    car's place there does, and nothing else in the data tells them apart (fixes 0.1-0.2 s
    late on a 10-min highway stretch at 28 m/s: 2.9-6.2 m off at sigmas of 0.16 m, nothing
    said; the check read 0.07 +- 0.06 s; outside tester). The output takes the stamps as
    right: its sigmas cannot include a latency the data do not show without being ~10x too
    wide wherever the stamps are right, so the line says what they leave out."""
    info = trajectory.info
    if TIME_UNRESOLVED_KEY in info or "gnss_time_offset_corrected_s" in info:
        return None
    reading, sigma = info.get("gnss_time_offset_fit_s"), info.get("gnss_time_offset_fit_sigma_s")
    if not (isinstance(reading, float) and isinstance(sigma, float) and sigma > 0.0):
        return None
    if abs(reading) >= UNCONFIRMED_TIME_SIGMAS * sigma or trajectory.position_cov is None:
        return None  # read: corrected, carried or declined elsewhere
    if sigma < TIME_BLIND_MIN_S:
        return None
    typical = typical_speed(np.linalg.norm(np.asarray(trajectory.velocity)[:, :2], axis=1))
    along = sigma * typical
    horizontal = np.sqrt(np.trace(np.asarray(trajectory.position_cov)[:, :2, :2], axis1=1, axis2=2) / 2.0)
    if along < max(TIME_BLIND_MIN_M, TIME_BLIND_SIGMAS * float(np.median(horizontal))):
        return None
    return (
        f"GNSS time: the drive tells the fixes' time stamps only to +-{sigma:.3f} s (too few "
        "turns and speed changes to tell a latency from the car's place along its track): "
        f"the output takes them as stamped, and a latency that size moves it {along:.1f} m "
        f"along the track at {typical:.0f} m/s, which its sigmas leave out; fixes that may "
        "be late (NMEA over a serial line, a logger's stamps): measure it and give --time-offset"
    )


def add_time_offset_uncertainty(trajectory: Trajectory) -> None:
    """Add the uncertainty of the fixes' time offset taken from the data to ``trajectory``'s
    position covariance (in place). The solve holds the moved stamps fixed, so its
    covariance is conditioned on them; an error ``e`` in the offset moves every position by
    ``v e`` (the fixes pin the track at the wrong instants): ``s^2 v v^T`` is added, ``s``
    the offset's sigma in the corrected solution's own check. (An independent simulator's
    fixed-wing at 60 m/s, fixes 0.5 s late, found 0.009 s short at 1.1 sigma of 0.008 s:
    0.5 m along the track, position NEES 4.1 over the flight.)"""
    if "gnss_time_offset_corrected_s" not in trajectory.info:
        return
    # The larger of the corrected solution's own check and the line search's curvature
    # (:func:`_offset_line_search`): the check is a step about one solution, the search the
    # fits of the solutions themselves.
    sigmas = [trajectory.info.get(key) for key in ("gnss_time_offset_fit_sigma_s", SEARCH_SIGMA_KEY)]
    finite = [x for x in sigmas if isinstance(x, float) and math.isfinite(x) and x > 0.0]
    if finite:
        _add_along_track(trajectory, max(finite))


def _add_along_track(trajectory: Trajectory, seconds: float) -> None:
    """Add ``seconds``^2 v v^T to the position covariance (in place): the track's uncertainty
    along itself from a time its fixes may be off by."""
    if trajectory.position_cov is None:
        return
    velocity = np.asarray(trajectory.velocity, dtype=float)
    if velocity.shape != (len(trajectory.position_cov), 3) or not np.all(np.isfinite(velocity)):
        return
    trajectory.position_cov = trajectory.position_cov + seconds**2 * np.einsum("ni,nj->nij", velocity, velocity)


def with_gnss_sigmas_scaled(
    dataset: Dataset,
    config: RunConfig,
    run: Rerun,
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
    if run.method not in ("batch", "isam2") or not config.gnss.sigma_from_fit or not scaled:
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
        corrected = run.solve(trial, trial_config)
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
    _carry_said(trajectory, corrected, said)
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


# The sigma of the misalignment state that refines a mounting taken from the drive's turns.
ADOPTED_MOUNTING_SIGMA_DEG = 3.0
# A mounting (the default or a given one) the turns put this far off is refined (see
# mounting_from_drive); a refined mounting within DEFAULT_HOLDS_DEG (a given one: GIVEN_HOLDS_DEG)
# or 3 sigmas of the misalignment estimate of the one it started from leaves that one (and
# says nothing): the simulated highway's rough turn fit (-1 deg) came back to 0.26 deg,
# within the estimate's noise.
MOUNTING_REFINE_DEG = 0.5
DEFAULT_HOLDS_DEG = 0.2
# Someone measured a given mounting: the data replace it only where they show it off by more
# than this as well (the refining solve is good to ~0.3 deg on simulated drives).
GIVEN_HOLDS_DEG = 0.5
MISALIGNMENT_SIGNIFICANT = 3.0  # sigmas of its estimate before a misalignment turns it


def mounting_from_drive(
    dataset: Dataset, config: RunConfig, run: Rerun
) -> tuple[RunConfig, str | None, float]:
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
    24) where the true mounting gives 0.5 m.

    The third value is the 1-sigma (deg) of a refined mounting taken (0 otherwise): the
    solves hold it fixed, so :func:`add_mounting_uncertainty` adds it to the output."""
    if not config.smoother.nhc or dataset.accel_array is not None:
        return config, None, 0.0  # no vehicle-frame constraint (or derived rates: too noisy)
    from fgins.mounting import adopted_mounting, check_mounting, default_axes_note

    rpy = config.smoother.imu_to_vehicle_rpy_deg
    given = "imu_to_vehicle_rpy_deg" in config.explicit_smoother_keys or any(rpy)
    finding = None
    if given:
        finding = check_mounting(dataset, rpy)  # raises beyond MOUNTING_ERROR_DEG
        if not config.smoother.mounting_from_data:
            return config, finding, 0.0
    adopted = adopted_mounting(dataset, rpy, refine_beyond_deg=MOUNTING_REFINE_DEG)
    if adopted is None:
        return config, finding if given else None, 0.0
    original = config
    evidence = adopted.evidence
    smoother = replace(config.smoother, imu_to_vehicle_rpy_deg=tuple(float(a) for a in adopted.rpy_deg))
    config = replace(config, smoother=smoother)
    refined = None
    holds_deg = GIVEN_HOLDS_DEG if given else DEFAULT_HOLDS_DEG
    if smoother.nhc_misalignment_prior_deg == 0.0:  # else the run estimates one itself
        # A coarse heading match (a crawl: +-16 deg) leaves more to refine than the turns.
        prior_deg = max(ADOPTED_MOUNTING_SIGMA_DEG, adopted.sigma_deg or 0.0)
        refined = _refined_mounting(dataset, config, run, prior_deg)
        if refined is None:  # the refining solve failed: judged as a given mounting is
            return original, finding if given else check_mounting(dataset, rpy), 0.0
    elif given:
        return original, finding, 0.0  # the run's own misalignment state takes up the rest
    taken_sigma_deg = 0.0
    if refined is not None:
        angles, turned_deg, sigma_deg = refined
        taken_sigma_deg = sigma_deg
        holds_deg = max(holds_deg, MISALIGNMENT_SIGNIFICANT * sigma_deg)
        smoother = replace(smoother, imu_to_vehicle_rpy_deg=angles)
        config = replace(config, smoother=smoother)
        evidence += (
            f"; a batch solve with a constant misalignment state turned that by "
            f"{turned_deg:.2f} deg"
        )
    moved_deg = _forward_angle_deg(smoother.imu_to_vehicle_rpy_deg, rpy)
    if moved_deg <= holds_deg:  # it holds after all (a rough fit)
        # A default off in roll alone (an FRD IMU given no mounting) is said all the same:
        # the car constraints do not see it, the output's roll does (outside tester).
        return original, finding if given else default_axes_note(dataset, rpy), 0.0
    shown = ", ".join(f"{a:.2f}" for a in smoother.imu_to_vehicle_rpy_deg)
    if given:
        return config, (
            f"imu: the configured mounting imu_to_vehicle_rpy_deg = {list(rpy)} does not fit "
            f"the drive (its forward axis {moved_deg:.1f} deg off): using "
            f"imu_to_vehicle_rpy_deg = [{shown}] ({evidence}); [smoother] mounting_from_data "
            "= false keeps the configured one"
        ), taken_sigma_deg
    return config, (
        f"imu: no IMU mounting was given, and the default {list(rpy)} does not fit the drive: "
        f"using imu_to_vehicle_rpy_deg = [{shown}] ({evidence}); set it in [smoother] to "
        "silence this"
    ), taken_sigma_deg


def _forward_angle_deg(rpy_a, rpy_b) -> float:
    """The angle (deg) between two mountings' forward axes (a roll alone changes none of the
    constraints: they zero the lateral and vertical velocity alike)."""
    from fgins.mounting import mounting_rotation

    cosine = mounting_rotation(rpy_a)[0] @ mounting_rotation(rpy_b)[0]
    return float(np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0))))


def _refined_mounting(
    dataset: Dataset, config: RunConfig, run: Rerun, prior_deg: float = ADOPTED_MOUNTING_SIGMA_DEG
) -> tuple[tuple[float, float, float], float, float] | None:
    """The mounting taken from the turns, turned by the constant NHC misalignment a batch
    solve estimates with it (sigma ``prior_deg``), each of its two angles only
    where it exceeds MISALIGNMENT_SIGNIFICANT sigmas of its own estimate; the angle turned
    and the larger sigma (deg). None when that solve fails. The turns' fit is good to
    ~0.1-1 deg: 1.2 deg off on an independent simulator's hilly drive, 1.52 m inside a 40 s
    outage where the true mounting gives 0.23 m; the state alone (kept in the run) got
    0.24 m there, but where the fit is exact it costs 6-9 %, and so does turning by an
    estimate within its noise (0.07 deg of yaw: 1.33 m against 1.24 m on the urban car). Folded into the mounting, the
    misalignment serves every method, the Kalman baselines too, at the cost of one solve."""
    from fgins.mounting import turned_by_misalignment

    smoother = replace(config.smoother, nhc_misalignment_prior_deg=prior_deg)
    try:
        probe = run.solve(dataset, replace(config, smoother=smoother), "batch")
    except FginsError:
        return None
    found = np.asarray(probe.info["nhc_misalignment_rad"])
    sigma = np.asarray(probe.info.get("nhc_misalignment_sigma_rad", (np.inf, np.inf)))
    lateral, vertical = np.where(np.abs(found) > MISALIGNMENT_SIGNIFICANT * sigma, found, 0.0)
    angles, turned_deg = turned_by_misalignment(smoother.imu_to_vehicle_rpy_deg, lateral, vertical)
    sigma_deg = float(np.degrees(np.max(sigma))) if np.all(np.isfinite(sigma)) else 0.0
    return tuple(float(a) for a in angles), turned_deg, sigma_deg


def nhc_lever_from_turns(
    dataset: Dataset, config: RunConfig, method: str
) -> tuple[RunConfig, str | None]:
    """A car whose non-holonomic point nobody gave (``[smoother] nhc_lever_arm_m``), its IMU
    shown ahead of it by the turns' forward-axis fit (fgins.mounting.imu_lever_from_turns:
    the -l w^2 and l dw/dt it feels, agreeing beyond 3 sigma and 0.5 m): the point taken
    there for every method, said. The graph's own lever check (with_nhc_lever_corrected)
    comes later and serves the graph methods only: an independent simulator's roundabout
    with the IMU 2 m ahead ran EKF+RTS to 1.01 m inside an outage (0.78 with the lever)."""
    smoother = config.smoother
    if not smoother.nhc or dataset.accel_array is not None or not smoother.nhc_lever_from_data:
        return config, None
    given = "nhc_lever_arm_m" in config.explicit_smoother_keys or any(smoother.nhc_lever_arm_m)
    from fgins.mounting import imu_lever_from_turns

    found = imu_lever_from_turns(dataset)
    if found is None:
        return config, None
    ahead, sigma = found
    if abs(ahead) > NHC_LEVER_MAX_M:
        return config, _no_vehicle_has_that_lever(ahead, sigma)
    lever = (-ahead, 0.0, 0.0)
    if given and method in ("batch", "isam2"):
        return config, None  # their own lever check moves it (with_nhc_lever_corrected)
    if given:
        # A point given where the turns put it far away (its sign the other way: the IMU
        # 1.5 m ahead entered as [1.5, 0, 0]): the Kalman baselines and the online iSAM2,
        # which have no lever check of their own, went 6.5-7.7 m off inside outages at 3-3.6
        # times their sigmas, blaming an antenna (outside tester); the graph's own check
        # (with_nhc_lever_corrected) serves the batch and iSAM2's final estimate only.
        configured = float(smoother.nhc_lever_arm_m[0])
        limit = max(NHC_LEVER_SIGMAS * sigma, NHC_LEVER_MIN_M)
        if abs(configured + ahead) <= limit:
            return config, None
        flipped = "; a sign the other way?" if abs(configured - ahead) <= limit else ""
        moved = (-ahead, *smoother.nhc_lever_arm_m[1:])
        config = replace(config, smoother=replace(smoother, nhc_lever_arm_m=moved))
        return config, (
            f"vehicle: the non-holonomic point (the rear axle's centre, [smoother] "
            f"nhc_lever_arm_m = {[float(x) for x in smoother.nhc_lever_arm_m]}) does not fit "
            f"the turns: they show the IMU {ahead:+.2f} +- {sigma:.2f} m ahead of it (the IMU "
            f"feels -l w^2 forward and l dw/dt sideways), where the configured point puts it "
            f"{-configured:+.2f} m ahead (vehicle axes: the point from the IMU{flipped}): "
            f"using nhc_lever_arm_m = [{-ahead:.2f}, "
            f"{', '.join(f'{float(x):g}' for x in smoother.nhc_lever_arm_m[1:])}]; "
            "[smoother] nhc_lever_from_data = false keeps yours"
        )
    config = replace(config, smoother=replace(smoother, nhc_lever_arm_m=lever))
    return config, (
        f"vehicle: no non-holonomic point ([smoother] nhc_lever_arm_m) was given, and the turns "
        f"show the IMU {ahead:+.2f} +- {sigma:.2f} m ahead of it (the IMU feels -l w^2 forward "
        f"and l dw/dt sideways): using nhc_lever_arm_m = [{-ahead:.2f}, 0, 0]; set it in "
        "[smoother] to silence this"
    )


def _no_vehicle_has_that_lever(ahead: float, sigma: float) -> str:
    """What the turns say when they put the IMU further from the non-holonomic point than
    any vehicle allows (beyond the config's range: a highway drive with its fixes 10-18 s
    off was refused with a config error on nhc_lever_arm_m, a key nobody had set, as the
    estimate was written into the config; outside tester)."""
    return (
        f"vehicle: the turns show the IMU {ahead:+.1f} +- {sigma:.1f} m ahead of the "
        f"non-holonomic point (the rear axle's centre), beyond any vehicle ({NHC_LEVER_MAX_M:g} "
        "m): not used; the fixes' times off the IMU's (a clock offset: --time-offset) or "
        "a vehicle that is no car (--vehicle) read that way"
    )


# The non-holonomic point's forward offset, where the drive's turns put it this many of its
# sigmas and this many metres from the configured one, is taken from them (the GNSS arm's
# floor). A car's IMU sits anywhere from the rear axle (the point) to the engine bay, 0-3 m
# ahead; KITTI fits 0.27 +- 0.05 m with the clocks free, and its outage sweep (issue 12) is
# worse with the point 0.15-0.25 m forward: below the floor, left as configured.
NHC_LEVER_SIGMAS = 5.0
NHC_LEVER_MIN_M = 0.5


def with_nhc_lever_corrected(
    dataset: Dataset, config: RunConfig, run: Rerun, trajectory: Trajectory
) -> tuple[Trajectory, RunConfig, str | None]:
    """A graph solution whose turns put the NHC's point (``[smoother] nhc_lever_arm_m``)
    significantly further forward or back (:func:`fgins.graph.reports.lever_arm_report`,
    every other parameter free with it) solved again with the point moved there, kept where
    it fits better, and said (in the run's corrections); without a solve when
    ``nhc_lever_from_data`` is false, or where the solve does not fit better, the misfit
    alone is returned as a note.
    The constraint zeroes the lateral velocity at that point, and yaw rate x a wrong offset
    is a lateral velocity the car does not have: an urban car's IMU given 2.5 m behind its
    point, 1.58 m inside a 40 s outage against 0.24 m, chi2/dof 0.78, nothing said."""
    info = trajectory.info
    shift, sigma = info.get("nhc_lever_forward_fit_m"), info.get("nhc_lever_forward_fit_sigma_m")
    if run.method not in ("batch", "isam2") or not config.smoother.nhc:
        return trajectory, config, None
    if not (isinstance(shift, float) and isinstance(sigma, float)):
        return trajectory, config, None
    if abs(shift) <= max(NHC_LEVER_SIGMAS * sigma, NHC_LEVER_MIN_M):
        return trajectory, config, None
    configured = [float(x) for x in config.smoother.nhc_lever_arm_m]
    lever = [configured[0] + shift, *configured[1:]]
    if abs(lever[0]) > NHC_LEVER_MAX_M:
        return trajectory, config, _no_vehicle_has_that_lever(-lever[0], sigma)
    shown = ", ".join(f"{x:.2f}" for x in lever)
    finding = (
        f"vehicle: the non-holonomic point (the rear axle's centre, [smoother] nhc_lever_arm_m "
        f"= {configured}) does not fit the turns: they put it {shift:+.2f} +- {sigma:.2f} m "
        "further forward (yaw rate x that offset is lateral velocity at the IMU)"
    )
    if not config.smoother.nhc_lever_from_data:
        return trajectory, config, f"{finding}; nhc_lever_arm_m = [{shown}] fits the drive"
    trial = replace(config, smoother=replace(config.smoother, nhc_lever_arm_m=tuple(lever)))
    try:
        corrected = run.solve(dataset, trial)
    except FginsError:
        corrected = None
    before = info.get("chi2_per_dof")
    after = corrected.info.get("chi2_per_dof") if corrected is not None else None
    if corrected is None or not (isinstance(before, float) and isinstance(after, float) and after < before):
        return trajectory, config, (
            f"{finding}; solved with nhc_lever_arm_m = [{shown}] it fits no better: kept as "
            "configured"
        )
    corrected.info["nhc_lever_arm_corrected_m"] = lever
    _carry_said(trajectory, corrected, [
        f"{finding}: corrected, nhc_lever_arm_m = [{shown}] and the drive solved again "
        f"(chi2/dof {before:.2f} -> {after:.2f}; [smoother] nhc_lever_from_data = false keeps "
        "it)"
    ])  # fmt: skip
    return corrected, trial, None
