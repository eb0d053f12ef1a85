"""What a finished solution cannot show by itself, said beside it: a log without heights, a
vehicle that never moved (no observable heading), an aircraft's IMU turned in the airframe.

Each takes the dataset and the solution, adjusts the reported uncertainty where the solver's
is meaningless (in place), and returns a warning line or None.
"""

from __future__ import annotations

import math

import numpy as np

from fgins.config import RunConfig
from fgins.datatypes import Dataset, Trajectory


def unknown_height(dataset: Dataset, trajectory: Trajectory) -> str | None:
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
    span = _running_median_span(enu)
    return span if span <= STATIC_SPAN_M else None


def _running_median_span(enu: np.ndarray) -> float:
    """How far (m) the fixes' running median over STATIC_MEDIAN_FIXES strays from their
    median (one outlier cannot move it); their own spread with fewer fixes."""
    running = enu
    if len(enu) >= STATIC_MEDIAN_FIXES:
        windows = np.lib.stride_tricks.sliding_window_view(enu, STATIC_MEDIAN_FIXES, axis=0)
        running = np.median(windows, axis=-1)  # (n - w + 1, 2)
    return float(np.max(np.linalg.norm(running - np.median(enu, axis=0), axis=1)))


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


def nose_off_track(config: RunConfig, trajectory: Trajectory, dataset: Dataset | None = None) -> str | None:
    """A warning when an aircraft's forward axis (IMU x, turned by the mounting) lies more
    than NOSE_OFF_TRACK_DEG from its solved velocity (median over the flight above
    NOSE_MIN_SPEED_M_S). The in-motion alignment takes that axis for the direction of
    travel: an IMU with x right and y forward went unsaid (the graph recovered; EKF+RTS
    1.24 m inside an outage instead of 0.36 m), one facing backwards only as a diverged
    filter."""
    if config.smoother.vehicle != "aircraft" or len(trajectory.t) < 10:
        return None
    if trajectory.info.get("filter_fit_failed"):
        return None  # its attitude is already said not to be trusted: no mounting to blame
    from fgins.mounting import mounting_rotation

    forward = mounting_rotation(config.smoother.imu_to_vehicle_rpy_deg)[0]  # IMU axes
    velocity = trajectory.velocity
    speed = np.linalg.norm(velocity, axis=1)
    # Where the solution does not know its own heading (a gyro-free array in straight
    # flight: 40-60 deg sigmas) it cannot tell where the nose points: an aircraft whose
    # IMU x was its nose had been told its axes were turned.
    heading_std = trajectory.attitude_std_deg[:, 2]
    unknown = heading_std > NOSE_OFF_TRACK_DEG / 3
    flying = np.isfinite(speed) & (speed > NOSE_MIN_SPEED_M_S) & ~unknown
    if flying.sum() < 10:
        return None
    nose = trajectory.rotation[flying] @ forward  # ENU
    cosine = np.einsum("ni,ni->n", nose, velocity[flying]) / speed[flying]
    angle = float(np.degrees(np.arccos(np.clip(np.median(cosine), -1.0, 1.0))))
    if angle <= NOSE_OFF_TRACK_DEG:
        return None
    if dataset is not None and dataset.accel_array is not None:
        # A gyro-free array's attitude is held by nothing but the fixes on an aircraft (no
        # vehicle constraint; in coordinated flight the specific force lies along the lift
        # axis whatever the heading): the solution's heading, not the array, is suspect.
        return (
            f"accel_array: the solution's forward axis (array x, turned by "
            f"imu_to_vehicle_rpy_deg = {list(config.smoother.imu_to_vehicle_rpy_deg)}) lies "
            f"{angle:.0f} deg from its velocity over the flight (an aircraft flies along its nose "
            "to within 15-20 deg): a gyro-free IMU keeps its heading here only through the fixes "
            "(no vehicle constraint holds it), so the solution's attitude and its sigmas are not "
            "to be trusted, or the array's axes are turned in the airframe ([accel_array] axes, "
            "[smoother] imu_to_vehicle_rpy_deg); --method batch keeps the heading's sigma honest"
        )
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


# A track this long (m) while the fixes the run used stay within STATIC_SPAN_M of one place:
# the vehicle moved only where no fix was used, and nothing there showed its heading.
UNSEEN_HEADING_TRAVEL_M = 100.0


def heading_unseen_in_motion(
    dataset: Dataset, gnss_mask: np.ndarray | None, trajectory: Trajectory
) -> str | None:
    """A warning when every fix the run used lies at one place (their running median within
    STATIC_SPAN_M of their median) while the solved track travels UNSEEN_HEADING_TRAVEL_M or
    more: the vehicle moved only while fixes were withheld or absent (a drive whose GNSS
    comes only at a stop at its end), so no fix shows which way it went. A start outage of
    290 s ending at a stop gave EKF+RTS 219-625 m off with sigmas of 2 m and its heading
    37-113 deg off with 0.2 deg, and the batch on a consumer IMU 111 m off at 5.3 m, with no
    word or one blaming the gyro's axes (outside tester). None otherwise."""
    used = np.ones(len(dataset.gnss), dtype=bool) if gnss_mask is None else np.asarray(gnss_mask, bool)
    enu = dataset.gnss_enu()[used, :2]
    enu = enu[np.all(np.isfinite(enu), axis=1)]
    if len(enu) < 2 or len(trajectory) < 2:
        return None
    shown = float(np.max(np.linalg.norm(enu - np.median(enu, axis=0), axis=1)))
    span = _running_median_span(enu)  # one outlier cannot make a motion
    travel = float(np.sum(np.linalg.norm(np.diff(trajectory.position[:, :2], axis=0), axis=1)))
    if span > STATIC_SPAN_M or travel < UNSEEN_HEADING_TRAVEL_M:
        return None
    return (
        f"heading: every fix the run used lies within {shown:.1f} m of one place, but the track "
        f"runs {travel:.0f} m where no fix was used (withheld or absent): no fix shows which "
        "way the vehicle went there, so the track there may be turned about those fixes by "
        "far more than its linearised sigmas say; give fixes while it moves, or "
        "[smoother] initial_heading_deg"
    )
