"""Does the configured GNSS lever arm fit, and do the fixes' time stamps (numpy only)?

The verdict on a joint estimate of the antenna's offset from the configured arm (3, IMU
axes), the fixes' time offset at the drive's middle and its change from there to the ends
(a drift: two clocks), with their covariance, wherever that estimate comes from: the
factor graph's parameter step (:func:`fgins.graph.reports.lever_arm_report`) or a Kalman
baseline's augmented states (:func:`fgins.baseline.ekf.antenna_about`). One rule for every
method: what is said, and what :func:`fgins.corrections.with_antenna_corrected` corrects.
"""

from __future__ import annotations

import numpy as np

from fgins.config import GnssConfig

# The joint estimate's parameters: the arm's change (3, body axes), the time offset at the
# drive's middle and its change from there to the end (s).
ARM, TIME, DRIFT = [0, 1, 2], [3], [4]


def typical_speed(speeds: np.ndarray) -> float:
    """The drive's typical speed, against which a time offset is sized: the median of the
    speeds above 1 m/s (0 if it never moves)."""
    moving = np.asarray(speeds, dtype=float)
    moving = moving[moving > 1.0]
    return float(np.median(moving)) if len(moving) else 0.0


def drift_time_base(fix_times: np.ndarray) -> tuple[float, float]:
    """Where a drift between two clocks is counted from and over: the middle of the fixes'
    span and half its length (the DRIFT parameter is the offset's change from there to the
    ends)."""
    first, last = float(fix_times[0]), float(fix_times[-1])
    return 0.5 * (first + last), max(0.5 * (last - first), 1e-9)


def significance(change: np.ndarray, covariance: np.ndarray) -> float:
    """The chi-square of ``change`` against its covariance."""
    return float(change @ np.linalg.solve(covariance, change))


def held(index: list[int], change: np.ndarray, covariance: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The estimate of the parameters ``index`` with all others held at zero (their
    configured values): the conditional Gaussian of the joint one."""
    others = [i for i in range(len(change)) if i not in index]
    gain = covariance[np.ix_(index, others)] @ np.linalg.inv(covariance[np.ix_(others, others)])
    return (
        change[index] - gain @ change[others],
        covariance[np.ix_(index, index)] - gain @ covariance[np.ix_(others, index)],
    )


def antenna_verdict(
    config: GnssConfig,
    configured: np.ndarray,
    change: np.ndarray,
    covariance: np.ndarray,
    typical_speed: float,
) -> dict[str, object]:
    """The lever-arm and GNSS time entries and warnings of :func:`lever_arm_report`, from
    the joint change (:data:`ARM`, :data:`TIME`, :data:`DRIFT`) and its covariance. A time
    offset counts when it moves the fixes as far as an arm must (LEVER_ARM_MIN_M) at the
    drive's typical speed (KITTI: 0.046 +- 0.007 s early at ~9 m/s, 0.4 m: not said), a
    drift when the offset's change from the middle to the ends does.

    What counts is also returned as the correction fgins.pipeline makes (solved again with
    it, kept when the fit improves): ``gnss_time_offset_s`` (the fixes' times to move back,
    at the drive's middle), ``gnss_time_drift_s`` (and its change from there to the ends)
    and ``gnss_lever_arm_m`` (the arm to use; components the drive does not determine to
    ARM_CORRECTION_MAX_SIGMA_M stay as configured), with ``antenna_findings``, what is said."""

    def says(name: str, shift: np.ndarray, cov: np.ndarray) -> bool:
        size = float(np.linalg.norm(shift)) * (1.0 if name == "arm" else typical_speed)
        chi2 = LEVER_ARM_CHI2 if name == "arm" else TIME_OFFSET_CHI2
        return significance(shift, cov) > chi2 and size > LEVER_ARM_MIN_M

    clock, clock_cov = held(TIME + DRIFT, change, covariance)  # the arm held as configured
    drifting = says("drift", change[DRIFT], covariance[np.ix_(DRIFT, DRIFT)])
    if not drifting:
        # The sharper question with no drift: one free blurs an arm with an offset wherever
        # the speed changes along the drive (an unconfigured 3 m arm on a stop-and-go drive
        # fell under 5 sigma).
        change, covariance = held(ARM + TIME, change, covariance)
    readings = {"arm": ARM, "time": TIME, **({"drift": DRIFT} if drifting else {})}
    # Each reading alone, the others held as configured.
    alone = {name: held(index, change, covariance) for name, index in (("arm", ARM), ("time", TIME))}
    out: dict[str, object] = {
        "gnss_lever_arm_fit_m": [float(x) for x in configured + alone["arm"][0]],
        "gnss_lever_arm_fit_sigma_m": [float(x) for x in np.sqrt(np.diag(alone["arm"][1]))],
        "gnss_lever_arm_fit_cov_m2": [[float(x) for x in row] for row in alone["arm"][1]],
        "gnss_time_offset_fit_s": float(alone["time"][0][0]),
        "gnss_time_offset_fit_sigma_s": float(np.sqrt(max(alone["time"][1][0, 0], 0.0))),
        "gnss_time_drift_fit_s": float(clock[1]),
        "gnss_time_drift_fit_sigma_s": float(np.sqrt(max(clock_cov[1, 1], 0.0))),
        # The offset at the drive's middle that goes with the drift (both with the arm as
        # configured): what fgins.pipeline refines once two clocks are found.
        "gnss_time_clock_offset_fit_s": float(clock[0]),
        "gnss_time_clock_offset_fit_sigma_s": float(np.sqrt(max(clock_cov[0, 0], 0.0))),
    }

    def arm_line(shift: np.ndarray, cov: np.ndarray) -> str:
        shown = ", ".join(f"{x:.2f}" for x in configured + shift)
        sigma = ", ".join(f"{x:.2f}" for x in np.sqrt(np.diag(cov)))
        return f"an antenna at [{shown}] m (IMU axes; +-{sigma})"

    def time_line(shift: float, var: float) -> str:
        return (
            f"time stamps {abs(shift):.3f} +- {np.sqrt(var):.3f} s "
            f"{'late' if shift > 0 else 'early'} against the IMU's"
        )

    def drift_line(offset: float, drift: float, drift_var: float) -> str:
        return (
            f"time stamps {offset - drift:+.3f} s at the start and {offset + drift:+.3f} s at "
            f"the end against the IMU's (+ late; the change +-{2 * np.sqrt(drift_var):.3f} s: "
            "two clocks at different rates)"
        )

    configured_arm = f"the configured {[round(float(x), 3) for x in config.lever_arm_m]} ([gnss] lever_arm_m)"
    found = [name for name, index in readings.items()
             if says(name, change[index], covariance[np.ix_(index, index)])]  # fmt: skip
    findings, advice = [], []
    if found:  # the drive tells them apart
        # What is corrected, with the rest held as configured; a drift moves the offset too.
        index = sorted({i for name in found for i in {"arm": ARM, "time": TIME, "drift": TIME + DRIFT}[name]})
        shift, shift_cov = held(index, change, covariance)
        fitted = dict(zip(index, shift, strict=True))
        variance = dict(zip(index, np.diag(shift_cov), strict=True))
        if "arm" in found:
            arm_cov = shift_cov[:3, :3]
            arm = np.array([fitted[i] for i in ARM])
            findings.append(f"GNSS lever arm: the fixes fit {arm_line(arm, arm_cov)}, not {configured_arm}")
            advice.append("measure and set it")
            if (taken := _determined_arm(configured, arm, arm_cov)) is not None:
                out["gnss_lever_arm_m"] = taken
                out["gnss_lever_arm_cov_m2"] = _determined_arm_covariance(arm_cov)
        if "drift" in found:
            findings.append(f"GNSS time: the fixes fit {drift_line(fitted[3], fitted[4], variance[4])}")
            advice.append("put both on one clock, or stamp the IMU samples with the receiver's time")
            out["gnss_time_offset_s"], out["gnss_time_drift_s"] = fitted[3], fitted[4]
        elif "time" in found:
            findings.append(
                f"GNSS time: the fixes fit {time_line(fitted[3], variance[3])} (a receiver's "
                "or a logger's latency)"
            )
            advice.append(f"smooth again with --time-offset {-fitted[3]:+.3f} (the IMU's clock is kept)")
            out["gnss_time_offset_s"] = fitted[3]
    else:
        if not any(says(name, *alone[name]) for name in ("arm", "time")):
            return out
        # An arm along the track and a time offset look the same at one steady speed: either
        # correction gives the same track there (they differ by at most the arm at stops);
        # leaving both out does not (fixes 0.1 s late at 15 m/s: 1.4 m beside the fixes and
        # 1.1-1.6 m inside outages at 2.4-5 times the sigmas; an antenna 1.5 m behind
        # likewise; corrected 0.3-0.6 m). The one that explains more is made, with an Akaike
        # penalty for the arm's three numbers against the offset's one (an antenna 2 m
        # behind on a stop-and-go drive: 0.29 m as an arm, 1.11 m as a time, 1.70 m left).
        arm, arm_cov = alone["arm"]
        offset, offset_var = float(alone["time"][0][0]), float(alone["time"][1][0, 0])
        # The offset still changing along the drive once it is taken as a time: two clocks,
        # which no arm or latency gives (an IMU clock 0.1 % slow, its drift under 5 sigma
        # with the arm free and at 6.6 with the offset, was taken as an antenna 2.3 m ahead:
        # 1.95 m inside outages, 0.51 m left alone).
        two_clocks = bool(clock[1] ** 2 / clock_cov[1, 1] > CLOCK_CHI2) and abs(clock[1]) * typical_speed > LEVER_ARM_MIN_M
        readings = f"{arm_line(arm, arm_cov)} instead of {configured_arm}, or {time_line(offset, offset_var)}"
        if two_clocks:
            readings += f", or {drift_line(float(clock[0]), float(clock[1]), float(clock_cov[1, 1]))}"
        findings.append(
            f"GNSS lever arm or time: the fixes fit {readings}: the drive cannot tell the two "
            "apart (an offset along the track at a steady speed)"
            + ("; the offset changes along the drive" if two_clocks else "")
        )
        advice.append(f"measure the arm, check the time bases (--time-offset {-offset:+.3f} would align them)")
        arm_merit = significance(arm, arm_cov) - 6.0
        time_merit = offset**2 / offset_var - 2.0
        time_says = says("time", np.array([offset]), np.array([[offset_var]]))
        taken = _determined_arm(configured, arm, arm_cov) if says("arm", arm, arm_cov) else None
        if two_clocks:
            out["gnss_time_offset_s"], out["gnss_time_drift_s"] = float(clock[0]), float(clock[1])
        elif taken is not None and (arm_merit > time_merit or not time_says):
            out["gnss_lever_arm_m"] = taken
            out["gnss_lever_arm_cov_m2"] = _determined_arm_covariance(arm_cov)
        elif time_says:
            out["gnss_time_offset_s"] = offset
    out["antenna_findings"] = findings
    out["fit_warnings"] = [f"{finding}: {then}" for finding, then in zip(findings, advice, strict=True)]
    return out


def determined_directions(cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The directions (unit columns, IMU axes) in which the drive determines the arm to
    ARM_CORRECTION_MAX_SIGMA_M, and their variances: the eigenvectors of its covariance
    whose sigma is under that. Directions, not IMU axes: what a drive leaves open is a
    direction of the vehicle (a car's vertical, an aircraft's along-track), which on an IMU
    pitched 30 deg in the vehicle spreads over two IMU axes; judged per axis, both were
    "not determined" and the well-determined rest thrown away with them (an independent
    simulator's car with an unconfigured 2.9 m arm: 2.1-2.2 m off at z 7, an aircraft's
    5 m tail arm 5 m off at z 22, where a level IMU had it corrected)."""
    cov = 0.5 * (np.asarray(cov, dtype=float) + np.asarray(cov, dtype=float).T)
    variances, vectors = np.linalg.eigh(cov)
    known = np.sqrt(np.clip(variances, 0.0, None)) < ARM_CORRECTION_MAX_SIGMA_M
    return vectors[:, known], variances[known]


def _determined_arm(configured: np.ndarray, shift: np.ndarray, cov: np.ndarray) -> list[float] | None:
    """The configured arm moved by ``shift`` in the directions the drive determines
    (:func:`determined_directions`), held as configured in the others (in the covariance's
    own directions the two are uncorrelated: the determined part is the projection); None
    when it determines none. (A car's drive leaves the vertical at +-2 m: taking its
    estimate would move every height by up to that.)"""
    directions, _ = determined_directions(cov)
    if not directions.shape[1]:
        return None
    determined = directions @ (directions.T @ shift)
    if float(np.linalg.norm(determined)) <= LEVER_ARM_MIN_M:
        # What the drive determines is no arm that matters: the shift's size was in the
        # directions it leaves open (an IMU mapped 30 ms early read as an arm 0.76 m off,
        # 0.72 of it vertical at +-2 m: [-0.23, 0, 0] taken, the drive 4x worse at z 3.3;
        # outside tester).
        return None
    arm = configured.astype(float) + determined
    return [float(x) for x in arm]


def _determined_arm_covariance(cov: np.ndarray) -> list[list[float]]:
    """The covariance (m^2, IMU axes) of the arm :func:`_determined_arm` takes: the
    covariance's determined directions only, zero along the ones it holds."""
    directions, variances = determined_directions(cov)
    out = directions @ np.diag(variances) @ directions.T
    return [[float(x) for x in row] for row in out]


def held_directions(covariance: object) -> list[np.ndarray]:
    """The unit directions (IMU axes) an arm taken with ``covariance``
    (:func:`_determined_arm_covariance`) holds as configured: its null space."""
    cov = np.asarray(covariance, dtype=float).reshape(3, 3)
    variances, vectors = np.linalg.eigh(0.5 * (cov + cov.T))
    floor = 1e-9 * max(float(variances.max()), 1e-12)
    return [vectors[:, i] for i in range(3) if variances[i] <= floor]


LEVER_ARM_PRIOR_M = 10.0
# 5 sigma in one direction (chi-square with 3 dof; 1 for the time): the fixes' errors are
# correlated over seconds, so a correctly configured drive can sit at 4-5 sigma (KITTI's arm:
# 0.23 +- 0.06 m, under the floor below); an unconfigured 2 m arm on a 280 s drive with five
# turns showed at 7 sigma, a 1.5 m one at 5.8, with 1.5-2 m errors everywhere.
LEVER_ARM_CHI2 = 25.0
LEVER_ARM_MIN_M = 0.5
TIME_OFFSET_PRIOR_S = 1.0
TIME_OFFSET_CHI2 = 25.0
# Where an offset is there (5 sigma) but the drive cannot tell an arm from a time: the drift
# with the time taken, at 4 sigma, makes it two clocks (no arm or offset keeps changing so).
CLOCK_CHI2 = 16.0
ARM_CORRECTION_MAX_SIGMA_M = 0.5
# The priors of the arm's offset (3, m), the time offset and its drift (s) in the joint
# estimates (the graph's parameter step, a Kalman baseline's augmented states).
ANTENNA_PRIOR_SIGMAS = np.array([LEVER_ARM_PRIOR_M] * 3 + [TIME_OFFSET_PRIOR_S] * 2)
# The fewest fixes a joint estimate is made from (the graph's lever_arm_report and the Kalman
# baselines' antenna_about alike).
MIN_FIXES = 30
