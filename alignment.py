"""Initial alignment: attitude, velocity and position at the start of a log (numpy only).

Identity rotation is not an initialisation. Two cases:

* at rest (GNSS speed below ``moving_speed``, or a quiet IMU whose fixes move less than GNSS
  drift can fake, ``MIN_CRUISE_DISTANCE_M`` between medians): roll/pitch from the averaged accelerometer
  (it measures -g in the body frame); heading from GNSS velocity at the first epoch where the
  vehicle moves, carried back to the start with the integrated gyro yaw rate, or a configured
  heading;
* in motion (the KITTI drive starts at ~9 m/s; an aircraft cruising straight and level, whose
  IMU reads as if at rest): a quadratic fit to the first seconds of GNSS
  positions gives velocity and acceleration; the accelerometer average then measures
  R^T (a - g), and the velocity direction gives the body x axis (forward) in the navigation
  frame. TRIAD on these two vector pairs, with the gravity-dominated pair as the primary,
  gives the full attitude.

Used by the factor graph and by every Kalman baseline, so all methods start from the same
state and the same uncertainty.
"""

from __future__ import annotations

import functools
import inspect
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import ParamSpec

import numpy as np

from fgins.config import SmootherConfig
from fgins.datatypes import Dataset, FginsError, InputError
from fgins.geodesy import normal_gravity, so3_exp, triad
from fgins.io.imu_checks import GAP_FACTOR, second_means
from fgins.mounting import mounting_rotation


@dataclass
class Alignment:
    """Initial navigation state at time ``t`` with 1-sigma uncertainties."""

    t: float
    rotation: np.ndarray  # body -> ENU
    velocity: np.ndarray
    position: np.ndarray
    attitude_sigma_rad: np.ndarray  # roll, pitch, yaw
    velocity_sigma: float
    position_sigma: float
    moving: bool
    # At rest by the IMU, but the fixes' fit did not rule out a steady motion (the velocity
    # sigma covers it): stops at the start wait until the fixes can tell.
    steady_motion_possible: bool = False


# How a vehicle travels relative to its forward axis (:func:`_travel`).
AHEAD, AHEAD_OR_BACK, ANY_DIRECTION = "ahead", "ahead or back", "any direction"


def _gnss_fit(
    t: np.ndarray, enu: np.ndarray, t_eval: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, velocity and acceleration at ``t_eval`` from a quadratic fit."""
    position, velocity, acceleration, _ = _gnss_fit_with_sigma(t, enu, t_eval)
    return position, velocity, acceleration


# Residuals of fewer degrees of freedom than this say little about the fixes' noise: their
# own sigma (or this default, metre-level autonomous GNSS) is the floor.
FIT_MIN_DOF = 3
DEFAULT_FIX_SIGMA_M = 3.0
# Outlying fixes of the start's fit: a least-trimmed-squares fit over half the fixes (up to
# FIT_LTS_STARTS elemental starts, two concentration steps each) sets the scale;
# fixes beyond FIT_OUTLIER_SIGMAS of it (never judged below the fixes' stated sigma or
# FIT_MIN_SCALE_M: RTK fixes agree to centimetres, a vehicle's jerk over the window is
# larger) are left out.
FIT_OUTLIER_SIGMAS = 6.0
FIT_MIN_SCALE_M = 0.5
FIT_LTS_STARTS = 200


def _fit_inliers(design: np.ndarray, horizontal: np.ndarray, min_scale_m: float) -> np.ndarray:
    """Rows (fixes) of a polynomial fit ``design`` (n, p) to ``horizontal`` (n, 2) that are
    not outliers. Least trimmed squares, not the residuals of one least-squares fit: over
    the 6-7 fixes of a short window that fit bends toward an outlier, shrinking its residual
    and growing the others', so no residual test on it tells the outlier apart. The scale
    is never below ``min_scale_m`` (the fixes' own stated sigma): half of 6-7 fixes fit a
    quadratic almost exactly, and a fix is no outlier within 6 of its own sigmas."""
    n, p = design.shape
    h = (n + p + 1) // 2  # the most robust choice: up to about half the fixes may be off
    keep = np.ones(n, dtype=bool)
    if h >= n or h - p < 2:
        return keep
    rng = np.random.default_rng(0)
    n_subsets = math.comb(n, p)
    if n_subsets <= FIT_LTS_STARTS:
        starts = [list(c) for c in itertools.combinations(range(n), p)]
    else:
        starts = [sorted(rng.choice(n, p, replace=False)) for _ in range(FIT_LTS_STARTS)]
    best_cost, best_coeffs = np.inf, None
    for start in starts:
        rows = np.asarray(start)
        for _ in range(3):  # elemental fit, then two concentration steps
            coeffs, *_ = np.linalg.lstsq(design[rows], horizontal[rows], rcond=None)
            squared = np.sum((horizontal - design @ coeffs) ** 2, axis=1)
            rows = np.argsort(squared)[:h]
        coeffs, *_ = np.linalg.lstsq(design[rows], horizontal[rows], rcond=None)
        squared = np.sum((horizontal - design @ coeffs) ** 2, axis=1)
        cost = float(np.sum(np.sort(squared)[:h]))
        if cost < best_cost:
            best_cost, best_coeffs = cost, coeffs
    squared = np.sum((horizontal - design @ best_coeffs) ** 2, axis=1)
    scale = max(float(np.sqrt(best_cost / (2 * (h - p)))), min_scale_m)
    return squared <= (FIT_OUTLIER_SIGMAS * scale) ** 2


def _gnss_fit_with_sigma(
    t: np.ndarray,
    enu: np.ndarray,
    t_eval: float,
    fix_sigma: float | None = None,
    degree: int | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """As :func:`_gnss_fit`, plus the 1-sigma of the horizontal speed: from the residuals,
    and with few of them at least from ``fix_sigma`` (m, horizontal per axis). Two fixes
    used to give a sigma of 0 (no residual): a speed of 23 +- 0 m/s from fixes 3 m apart
    in noise, the dead reckoning after them 4-5x more certain than its errors."""
    dt = t - t_eval
    if degree is None:
        degree = 2 if len(t) >= 4 else 1
    design = np.vander(dt, degree + 1, increasing=True)
    # Without the fixes a trimmed fit of the others puts far off: one or two multipath fixes
    # among the first seconds' made the residual RMS, and with it the speed sigma and the
    # motion threshold (3 sigma), several times too large, so a car cruising at 8 m/s was
    # aligned at rest (the forward EKF 70-300 m off) and one driving off was never "moving".
    stated = fix_sigma if fix_sigma is not None and np.isfinite(fix_sigma) else 0.0
    keep = _fit_inliers(design, enu[:, :2], max(stated, FIT_MIN_SCALE_M))
    if keep.sum() < degree + 1 + FIT_MIN_DOF:  # too few left to fit: a parabola through
        keep[:] = True  # five of seven noisy fixes extrapolates velocity by 10 m/s
    design, enu = design[keep], enu[keep]
    coeffs, *_ = np.linalg.lstsq(design, enu, rcond=None)
    position = coeffs[0]
    velocity = coeffs[1]
    acceleration = 2 * coeffs[2] if degree == 2 else np.zeros(3)
    dof = len(design) - (degree + 1)
    noise = 0.0
    if dof > 0:
        residual = enu[:, :2] - design @ coeffs[:, :2]
        noise = float(np.sqrt(np.sum(residual**2) / (2 * dof)))
    if dof < FIT_MIN_DOF:
        floor = fix_sigma if fix_sigma is not None and np.isfinite(fix_sigma) else None
        noise = max(noise, DEFAULT_FIX_SIGMA_M if floor is None else floor)
    covariance = np.linalg.pinv(design.T @ design)
    return position, velocity, acceleration, noise * float(np.sqrt(covariance[1, 1]))


_Args = ParamSpec("_Args")


def _finite(align: Callable[_Args, Alignment]) -> Callable[_Args, Alignment]:
    """The alignment ``align`` makes, or an error where it is not finite: not NaN handed to
    every estimator, which each failed differently (planar-kf wrote an all-NaN track at exit
    0, the EKF ended in an SVD error)."""

    @functools.wraps(align)
    def checked(*args: _Args.args, **kwargs: _Args.kwargs) -> Alignment:
        alignment = align(*args, **kwargs)
        parts = (alignment.rotation, alignment.velocity, alignment.position, alignment.attitude_sigma_rad)
        sigmas = (alignment.velocity_sigma, alignment.position_sigma)
        if not (all(np.all(np.isfinite(x)) for x in parts) and np.all(np.isfinite(sigmas))):
            raise FginsError(
                f"the initial alignment at t = {alignment.t:.3f} s is not finite: a defect of "
                "fgins's, please report it with the input (--vehicle or [smoother] "
                "initial_heading_deg may avoid it)"
            )
        return alignment

    return checked


# The start's position prior is a starting point, not a measurement: the fixes it was fitted
# from are the graph's and the filters' measurements too. Its sigma is at least a third of
# those fixes' RMS stated sigma (2 m at least: metre-level fixes keep the 2 m every estimator
# was tuned with), so fixes stated far worse do not get it far tighter. (Outside tester: a
# fixed 2 m held fixes of 15 m vertical sigma, counted twice: heights 5-8 m off at the start
# at z 3.5 over 8 seeds, now 1.6-2.4 m at z 1.2-1.7; three first fixes 30 m off with a 30 m
# sigma moved the start 1.8 m, now 0.15.)
START_PRIOR_FIX_SIGMAS = 1.0 / 3.0
START_PRIOR_MIN_SIGMA_M = 2.0


def _start_prior_floored(align: Callable[_Args, Alignment]) -> Callable[_Args, Alignment]:
    """The alignment ``align`` makes, its position sigma at least START_PRIOR_FIX_SIGMAS
    times the RMS stated sigma of the fixes its position was fitted from (those within
    ``fit_window_s`` of the first usable one)."""
    parameters = inspect.signature(align)

    @functools.wraps(align)
    def floored(*args: _Args.args, **kwargs: _Args.kwargs) -> Alignment:
        alignment = align(*args, **kwargs)
        bound = parameters.bind(*args, **kwargs)
        bound.apply_defaults()
        dataset, gnss_mask = bound.arguments["dataset"], bound.arguments["gnss_mask"]
        fit_window_s = float(bound.arguments["fit_window_s"])
        mask = np.ones(len(dataset.gnss), dtype=bool) if gnss_mask is None else np.asarray(gnss_mask, bool)
        t = dataset.gnss.t
        window = mask & (t >= t[mask][0]) & (t <= t[mask][0] + fit_window_s)
        stated = np.max(np.asarray(dataset.gnss.std, dtype=float)[window], axis=1)
        stated = stated[np.isfinite(stated) & (stated > 0)]
        if not stated.size:
            return alignment
        # The fit takes its fixes unweighted: the worst of them set its error (their RMS sigma).
        floor = max(START_PRIOR_MIN_SIGMA_M, START_PRIOR_FIX_SIGMAS * float(np.sqrt(np.mean(stated**2))))
        if alignment.position_sigma >= floor:
            return alignment
        return replace(alignment, position_sigma=floor)

    return floored


@_finite
@_start_prior_floored
def initial_alignment(
    dataset: Dataset,
    gnss_mask: np.ndarray | None = None,
    *,
    smoother: SmootherConfig | None = None,
    heading_deg: float | None = None,
    moving_speed: float = 2.0,
    fit_window_s: float = 6.0,
    forward_axis: np.ndarray | None = None,
    gyro_bias_sigma: float = 0.0,
) -> Alignment:
    """Initial state at the first IMU sample (see module docstring).

    ``gyro_bias_sigma`` (rad/s, the IMU's turn-on bias prior) bounds what the yaw carried
    back from the first motion to the start can be off by when the gyro's bias could not be
    read at rest first; the heading's sigma includes it.

    ``smoother`` (the run's settings) supplies the configured initial heading and the IMU
    mounting; ``heading_deg``/``forward_axis`` give them directly instead. ``forward_axis``
    is the vehicle's forward direction in IMU axes (row 0 of the mounting rotation,
    :func:`fgins.mounting.mounting_rotation`), the IMU's x axis by default: in motion it is
    the body axis aligned with the velocity, and the heading is that axis's.

    When the first usable fix comes well after the IMU starts (GNSS withheld or lost at the
    start), the state is aligned at that fix and carried back to the first IMU sample by
    backward dead reckoning, with uncertainties grown by what dead reckoning over that
    stretch can get wrong; a tight prior on an extrapolated state would pin the start wrong.
    The position sigma is at least a share of the fitted fixes' own (:func:`_start_prior_floored`).
    """
    imu = dataset.imu
    mask = np.ones(len(dataset.gnss), dtype=bool) if gnss_mask is None else gnss_mask
    gnss_t = dataset.gnss.t[mask]
    gnss_enu = dataset.gnss_enu()[mask]
    if len(gnss_t) < 2:
        raise InputError("alignment needs at least 2 usable GNSS fixes")
    if smoother is not None:
        heading_deg = smoother.initial_heading_deg if heading_deg is None else heading_deg
        if forward_axis is None:
            forward_axis = mounting_rotation(smoother.imu_to_vehicle_rpy_deg)[0]
    forward = np.array([1.0, 0.0, 0.0]) if forward_axis is None else np.asarray(forward_axis, float)
    # A land vehicle (the NHC holds) travels along its forward axis, ahead or reversing; a
    # multirotor or a pedestrian in any direction; anything else (an aircraft) ahead.
    travel = _travel(smoother)
    t_start = float(imu.t[0])
    lead = float(gnss_t[0]) - t_start
    if lead <= MAX_LEAD_S:
        at_start = _align_at(
            dataset, t_start, gnss_t, gnss_enu, heading_deg, moving_speed, fit_window_s, forward,
            gyro_bias_sigma, travel,
        )  # fmt: skip
        if not at_start.moving:
            return at_start
        straight = _straight_alignment(
            dataset, t_start, gnss_t, gnss_enu, heading_deg, moving_speed, fit_window_s, forward,
            gyro_bias_sigma, travel,
        )  # fmt: skip
        if straight is None:
            return at_start
        return _carry_back_along_nose(dataset, straight, t_start, gnss_t, forward, gyro_bias_sigma)
    rest = _rest_before_first_fix(
        dataset, gnss_t, gnss_enu, heading_deg, moving_speed, fit_window_s, forward,
        gyro_bias_sigma, travel,
    )  # fmt: skip
    if rest is not None:
        return rest
    later = _align_at(
        dataset, float(gnss_t[0]), gnss_t, gnss_enu, heading_deg, moving_speed, fit_window_s,
        forward, gyro_bias_sigma, travel,
    )  # fmt: skip
    if travel == AHEAD_OR_BACK and heading_deg is None:
        # A car's velocity follows its nose: carried back by the gyro and the along-track
        # accelerometer, where a strapdown turns every degree of tilt into 0.17 m/s^2 (a car
        # whose first 15 s of fixes were withheld started 40 m/s off with a 2.6 m/s sigma,
        # and the batch did not converge).
        straight = None
        if later.moving:
            straight = _straight_alignment(
                dataset, float(gnss_t[0]), gnss_t, gnss_enu, heading_deg, moving_speed,
                fit_window_s, forward, gyro_bias_sigma, travel,
            )  # fmt: skip
        return _carry_back_along_nose(
            dataset, later if straight is None else straight, t_start, gnss_t, forward,
            gyro_bias_sigma,
        )  # fmt: skip
    rotation, velocity, position = _propagate_back(dataset, later, t_start)
    # The gyro's unknown bias turns the carried attitude by up to its sigma times the lead (an
    # industrial MEMS: 1.9 deg over 45 s; without it an aircraft carried back 45 s started
    # 3.5 deg off in pitch with a 1 deg sigma, and the EKF+RTS held its vertical 21 m off
    # with a 2.4 m sigma).
    attitude_sigma = later.attitude_sigma_rad + np.radians([1.0, 1.0, 5.0]) + gyro_bias_sigma * lead
    # Dead reckoning over `lead` seconds: the level's error tilts gravity into the velocity,
    # plus ~0.1 m/s^2 of unknown acceleration (bias).
    drift = 0.1 + normal_gravity(dataset.origin.lat, dataset.origin.alt) * float(
        np.max(attitude_sigma[:2])
    )
    return Alignment(
        t=t_start,
        rotation=rotation,
        velocity=velocity,
        position=position,
        attitude_sigma_rad=attitude_sigma,
        velocity_sigma=later.velocity_sigma + drift * lead,
        position_sigma=later.position_sigma + 0.5 * drift * lead**2 + later.velocity_sigma * lead,
        moving=later.moving,
        steady_motion_possible=later.steady_motion_possible,
    )


MAX_LEAD_S = 2.0  # first usable fix this long after the IMU starts: align there, carry back
# The start's fit spans at most this much of the first fixes, unless the IMU stays steady over
# them (sparse fixes: see _align_at).
MAX_FIT_SPAN_S = 10.0
UNKNOWN_START_SPEED_SIGMA = 20.0  # m/s: a vehicle moving at one lone fix, speed unknown
# Motion over the alignment window that no GNSS drift at rest fakes (a receiver converging
# after a cold start moves its fix by metres; the first-motion heading uses the same 20 m).
MIN_CRUISE_DISTANCE_M = 20.0


def _rest_before_first_fix(
    dataset: Dataset,
    gnss_t: np.ndarray,
    gnss_enu: np.ndarray,
    heading_deg: float | None,
    moving_speed: float,
    fit_window_s: float,
    forward_axis: np.ndarray,
    gyro_bias_sigma: float,
    travel: str,
) -> Alignment | None:
    """The alignment at the first IMU sample when the vehicle stands there but the first
    usable fix comes much later (a receiver's cold start, GNSS withheld at the start), or
    None when the IMU does not start at rest or its dead reckoning to the first fix does not
    arrive at the fixes' velocity (a vehicle cruising with a quiet IMU).

    At rest the IMU itself gives level and zero velocity; the heading is the first motion's,
    carried back with the gyro less its rest reading. Only the position is unknown: the first
    fix less the dead-reckoned way there, with a sigma for a dead reckoning that long. The
    alternative, aligning at the first fix and dead-reckoning backwards from there, starts
    from a moving alignment's attitude (degrees off), and on a car whose first 40 s of fixes
    were withheld the Kalman filters ended 300-1200 m off with sigmas 10-150x too small.
    """
    imu = dataset.imu
    t_start = float(imu.t[0])
    g = normal_gravity(dataset.origin.lat, dataset.origin.alt)
    first = (imu.t >= t_start) & (imu.t <= t_start + 1.0)
    if first.sum() < 10 or not _imu_static(imu.gyro[first], imu.accel[first], g):
        return None
    rotation, heading_sigma_deg = _rest_attitude(
        dataset, gnss_t, gnss_enu, t_start, first, heading_deg, moving_speed, forward_axis,
        gyro_bias_sigma, travel, static=True,
    )  # fmt: skip
    t_fix = float(gnss_t[0])
    window = gnss_t <= t_fix + fit_window_s
    fix_position, fix_velocity, _ = _gnss_fit(gnss_t[window], gnss_enu[window], t_fix)
    # The gyro's reading at rest is its bias (and the Earth's rate): taken off (a MEMS gyro's
    # few mrad/s would tilt the dead reckoning by degrees in half a minute).
    velocity, way = _propagate_forward(
        dataset, rotation, t_start, t_fix, imu.gyro[first].mean(axis=0)
    )
    lead = t_fix - t_start
    # A level error of ~0.1 m/s^2 (0.6 deg, a MEMS accelerometer's bias) over the lead; a
    # heading known to heading_sigma over the way.
    if np.linalg.norm(velocity[:2] - fix_velocity[:2]) > 2.0 + DEAD_RECKONING_ACCEL * lead:
        return None
    position_sigma = float(
        2.0 + 0.5 * DEAD_RECKONING_ACCEL * lead**2
        + np.radians(heading_sigma_deg) * np.linalg.norm(way[:2])
    )  # fmt: skip
    return Alignment(
        t=t_start,
        rotation=rotation,
        velocity=np.zeros(3),
        position=fix_position - way,
        attitude_sigma_rad=np.radians([2.0, 2.0, heading_sigma_deg]),
        velocity_sigma=0.5,
        position_sigma=position_sigma,
        moving=False,
    )


DEAD_RECKONING_ACCEL = 0.15  # m/s^2: unknown acceleration of a dead reckoning from rest


def _yaw_turned(imu, up_body: np.ndarray, t0: float, t1: np.ndarray) -> np.ndarray:
    """Rotation about ``up_body`` (rad, counter-clockwise) from ``t0`` to each of ``t1``."""
    rate = imu.gyro @ up_body
    yaw = np.concatenate([[0.0], np.cumsum(0.5 * (rate[1:] + rate[:-1]) * np.diff(imu.t))])
    return np.interp(t1, imu.t, yaw) - float(np.interp(t0, imu.t, yaw))


def _straight_alignment(
    dataset: Dataset,
    t_from: float,
    gnss_t: np.ndarray,
    gnss_enu: np.ndarray,
    heading_deg: float | None,
    moving_speed: float,
    fit_window_s: float,
    forward_axis: np.ndarray,
    gyro_bias_sigma: float,
    travel: str,
) -> Alignment | None:
    """For a log that starts (at ``t_from``) while its vehicle turns: the in-motion alignment
    where it first goes straight, to be carried back (:func:`_carry_back_along_nose`); None
    when the start does not turn, the vehicle may move sideways, or it does not go straight
    in the first minutes.

    The in-motion alignment fits a quadratic to the first seconds of fixes: through a turn
    (1 Hz fixes, 30-90 deg in the fit window) its velocity came out 30-130 deg off its true
    direction and the reversing test, which projects the way onto one direction, called a
    car that drove ahead reversing (the KITTI drive started at 22 places along it: 7 of them
    were turned by 37-174 deg, with a 10 deg sigma; 3 ended in chi2/dof 5-98 or an error).
    On a straight, both hold; the gyro carries the attitude back with an error of its bias
    times the way back."""
    imu = dataset.imu
    if travel == ANY_DIRECTION or heading_deg is not None:
        return None
    g = normal_gravity(dataset.origin.lat, dataset.origin.alt)
    first = (imu.t >= t_from) & (imu.t <= t_from + 1.0)
    if first.sum() < 10 or _imu_static(imu.gyro[first], imu.accel[first], g):
        return None
    # Up in IMU axes over the first minutes (a turn's centripetal part averages out).
    minutes = (imu.t >= t_from) & (imu.t <= t_from + MAX_TURN_SEARCH_S)
    up_body = imu.accel[minutes].mean(axis=0)
    up_body = up_body / np.linalg.norm(up_body)
    candidates = gnss_t[(gnss_t >= t_from) & (gnss_t <= t_from + MAX_TURN_SEARCH_S)]
    # Only windows the IMU covers whole: beyond its last sample the turn reads as none (the
    # integrated yaw is held there), and an aircraft orbiting through its whole 90 s log was
    # "aligned" after the IMU ended, every state NaN.
    candidates = np.concatenate([[t_from], candidates])
    candidates = candidates[candidates + fit_window_s <= float(imu.t[-1])]
    if len(candidates) == 0:
        return None
    turned = np.abs(
        _yaw_turned(imu, up_body, 0.0, candidates + fit_window_s)
        - _yaw_turned(imu, up_body, 0.0, candidates)
    )
    if turned[0] <= np.radians(STRAIGHT_ALIGN_TURN_DEG):
        return None  # the start goes straight: the in-motion fit holds there
    for straight_from in candidates[turned <= np.radians(STRAIGHT_ALIGN_TURN_DEG)]:
        # The fit over the straight's fixes, read at its middle (at an end a quadratic's
        # slope is least sure).
        straight = (gnss_t >= straight_from - 1e-9) & (gnss_t <= straight_from + fit_window_s)
        if straight.sum() < 3:
            continue
        later = _align_at(
            dataset, float(straight_from + 0.5 * fit_window_s), gnss_t[straight],
            gnss_enu[straight], None, moving_speed, fit_window_s, forward_axis, gyro_bias_sigma,
            travel,
        )  # fmt: skip
        if later.moving:  # stopped there: the start's speed is not the straight's
            return later
    return None


def _carry_back_along_nose(
    dataset: Dataset,
    later: Alignment,
    t_start: float,
    gnss_t: np.ndarray,
    forward_axis: np.ndarray,
    gyro_bias_sigma: float,
) -> Alignment:
    """``later`` (moving) carried back to ``t_start`` for a vehicle whose velocity follows
    its nose: the attitude by the gyro, the speed by the accelerometer along track (or the
    receiver's own among the usable fixes ``gnss_t``), the way along the nose."""
    imu = dataset.imu
    lead = float(later.t) - t_start
    rotation = _rotate_back(dataset, later.rotation, t_start, float(later.t))
    # Ahead or reversing, as found where aligned.
    ahead = float(np.sign(later.velocity @ (later.rotation @ forward_axis))) or 1.0
    speed = _speed_carried_back(dataset, later, t_start, gnss_t, forward_axis, ahead)
    # The way from t_start to later.t along the nose, at the speed the accelerometer gives.
    span = np.flatnonzero((imu.t >= t_start) & (imu.t < later.t))
    level_up = _level_up(imu, t_start)
    along = forward_axis - (forward_axis @ level_up) * level_up
    along = ahead * along / np.linalg.norm(along)
    way, step_speed, attitude = np.zeros(3), speed, rotation
    for k in span:
        dt = (float(imu.t[k + 1]) if k + 1 < len(imu.t) else float(later.t)) - float(imu.t[k])
        dt = min(dt, float(later.t) - float(imu.t[k]))
        nose = attitude @ forward_axis
        nose[2] = 0.0
        way += ahead * step_speed * dt * nose / max(float(np.linalg.norm(nose)), 1e-9)
        step_speed = max(step_speed + float(imu.accel[k] @ along) * dt, 0.0)
        attitude = attitude @ so3_exp(imu.gyro[k] * dt)
    nose = rotation @ forward_axis
    nose[2] = 0.0
    velocity = ahead * speed * nose / max(float(np.linalg.norm(nose)), 1e-9)
    carried = gyro_bias_sigma * lead
    return Alignment(
        t=t_start,
        rotation=rotation,
        velocity=velocity,
        position=later.position - way,
        attitude_sigma_rad=later.attitude_sigma_rad + np.array([0.01, 0.01, carried + 0.02]),
        velocity_sigma=max(1.0, 0.3 * speed) + DEAD_RECKONING_ACCEL * lead,
        position_sigma=later.position_sigma + 0.5 * DEAD_RECKONING_ACCEL * lead**2
        + (np.tan(later.attitude_sigma_rad[2] + carried) + 0.1) * speed * lead,
        moving=True,
    )


def _level_up(imu, t_start: float) -> np.ndarray:
    """Gravity's direction in IMU axes: the specific force averaged over a minute from
    ``t_start`` (a vehicle's accelerations average out)."""
    window = (imu.t >= t_start) & (imu.t <= t_start + GRAVITY_MEAN_S)
    up = imu.accel[window].mean(axis=0) if window.sum() >= 10 else imu.accel[:10].mean(axis=0)
    return up / np.linalg.norm(up)


def _speed_carried_back(
    dataset: Dataset,
    later: Alignment,
    t_start: float,
    gnss_t: np.ndarray,
    forward_axis: np.ndarray,
    ahead: float,
) -> float:
    """The speed at ``t_start``: the receiver's own velocity at a usable fix (``gnss_t``)
    within a second of it if the data carry one, else ``later``'s speed less the
    accelerometer's along-track gain since ``t_start`` (two fixes' chord is metres off at
    1 Hz in a town, and a quadratic's slope through a turn cuts the arc)."""
    gnss = dataset.gnss
    usable = gnss_t[np.abs(gnss_t - t_start) <= 1.0]
    if gnss.velocity is not None and len(usable):
        rows = np.searchsorted(gnss.t, usable)
        rows = rows[(rows < len(gnss.t))]
        rows = rows[np.all(np.isfinite(gnss.velocity[rows, :2]), axis=1)]
        if len(rows):
            k = rows[np.argmin(np.abs(gnss.t[rows] - t_start))]
            return float(np.hypot(*gnss.velocity[k, :2]))
    imu = dataset.imu
    span = (imu.t >= t_start) & (imu.t <= later.t)
    speed = float(np.linalg.norm(later.velocity[:2]))
    if span.sum() < 2:
        return speed
    level_up = _level_up(imu, t_start)
    along = forward_axis - (forward_axis @ level_up) * level_up
    along = ahead * along / np.linalg.norm(along)
    force = imu.accel[span] @ along
    gained = float(np.sum(0.5 * (force[1:] + force[:-1]) * np.diff(imu.t[span])))
    return max(speed - gained, 0.0)


# The in-motion fit is trusted over a window that turns less than this.
STRAIGHT_ALIGN_TURN_DEG = 10.0
MAX_TURN_SEARCH_S = 120.0  # how far into the log a straight is looked for
GRAVITY_MEAN_S = 60.0  # a vehicle's accelerations average out of the specific force over this


def _rotate_back(dataset: Dataset, rotation: np.ndarray, t_start: float, t_end: float) -> np.ndarray:
    """The attitude at ``t_start`` of a body whose attitude at ``t_end`` is ``rotation``:
    the gyro's rotations undone (no bias; the Earth's rate is far below a vehicle's)."""
    imu = dataset.imu
    end = int(np.searchsorted(imu.t, t_end, side="right")) - 1
    t_next = t_end
    for k in range(end, -1, -1):
        if imu.t[k] < t_start - 1e-9:
            break
        dt = t_next - float(imu.t[k])
        if dt > 0:
            rotation = rotation @ so3_exp(-imu.gyro[k] * dt)
        t_next = float(imu.t[k])
    return rotation


def _propagate_forward(
    dataset: Dataset, rotation: np.ndarray, t_start: float, t_end: float, gyro_bias: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(velocity, displacement) at ``t_end`` of a strapdown (ENU, normal gravity, zero
    accelerometer bias) from rest at ``t_start`` with attitude ``rotation``."""
    imu = dataset.imu
    gravity = np.array([0.0, 0.0, -normal_gravity(dataset.origin.lat, dataset.origin.alt)])
    velocity, position = np.zeros(3), np.zeros(3)
    start = max(int(np.searchsorted(imu.t, t_start, side="right")) - 1, 0)
    end = int(np.searchsorted(imu.t, t_end, side="left"))
    for k in range(start, end):
        t_next = min(float(imu.t[k + 1]) if k + 1 < len(imu) else t_end, t_end)
        dt = t_next - max(float(imu.t[k]), t_start)
        if dt <= 0:
            continue
        acceleration = rotation @ imu.accel[k] + gravity
        position = position + velocity * dt + 0.5 * acceleration * dt**2
        velocity = velocity + acceleration * dt
        rotation = rotation @ so3_exp((imu.gyro[k] - gyro_bias) * dt)
    return velocity, position


def _propagate_back(
    dataset: Dataset, later: Alignment, t_start: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Backward strapdown (ENU, normal gravity, zero bias) from ``later`` to ``t_start``."""
    imu = dataset.imu
    gravity = np.array([0.0, 0.0, -normal_gravity(dataset.origin.lat, dataset.origin.alt)])
    rotation, velocity, position = (
        later.rotation.copy(),
        later.velocity.copy(),
        later.position.copy(),
    )
    end = int(np.searchsorted(imu.t, later.t, side="right")) - 1
    t_next = later.t
    for k in range(end, -1, -1):
        dt = t_next - float(imu.t[k])
        if dt <= 0:
            continue
        # Sample k is held over [t_k, t_next): undo its step.
        rotation = rotation @ so3_exp(-imu.gyro[k] * dt)
        acceleration = rotation @ imu.accel[k] + gravity
        velocity = velocity - acceleration * dt
        position = position - velocity * dt - 0.5 * acceleration * dt**2
        t_next = float(imu.t[k])
    return rotation, velocity, position


def _align_at(
    dataset: Dataset,
    t0: float,
    gnss_t: np.ndarray,
    gnss_enu: np.ndarray,
    heading_deg: float | None,
    moving_speed: float,
    fit_window_s: float,
    forward_axis: np.ndarray,
    gyro_bias_sigma: float = 0.0,
    travel: str = AHEAD,
) -> Alignment:
    """Alignment at time ``t0`` from the fixes around it and the IMU's first second there.
    ``travel``: how the vehicle moves relative to its forward axis (:func:`_travel`)."""
    imu = dataset.imu
    g = normal_gravity(dataset.origin.lat, dataset.origin.alt)
    gravity = np.array([0.0, 0.0, -g])

    window = gnss_t <= max(gnss_t[0], t0) + fit_window_s
    if window.sum() < 3:
        # Sparse fixes (GNSS at 0.2 Hz): the first three, where they lie close enough in time
        # for one line or parabola to stand for the motion. Fixes 40 s apart did not: a car
        # at rest was started 80 m from its first fix at a 2 m sigma, the batch 67 m off
        # there (35 m RMS at sigmas of 1.7 m) and the fixes blamed.
        first_three = np.arange(len(gnss_t)) < 3
        end = float(gnss_t[first_three][-1])
        if end - gnss_t[0] <= MAX_FIT_SPAN_S or _steady(imu, t0, end):
            window = first_three  # a steady IMU: at rest or cruising, a line fits it
    # Accelerometer average over the first second of IMU data from t0.
    first = (imu.t >= t0) & (imu.t <= t0 + 1.0)
    if first.sum() < 10:
        start = int(np.searchsorted(imu.t, t0))
        first[start : start + 10] = True
    static = _imu_static(imu.gyro[first], imu.accel[first], g)
    # A quiet IMU does not accelerate: a line through the fixes, not a parabola. Its two
    # parameters leave the trimmed fit (_fit_inliers) enough fixes to find two multipath
    # outliers among 7 (a parabola through 5 noisy fixes fits one of them as well).
    if window.sum() >= 2:
        position, velocity, acceleration, speed_sigma = _gnss_fit_with_sigma(
            gnss_t[window], gnss_enu[window], t0,
            _stated_fix_sigma(dataset), degree=1 if static else None,
        )  # fmt: skip
    else:  # one fix: where the vehicle is, not how it moves
        position, velocity, acceleration = gnss_enu[0].copy(), np.zeros(3), np.zeros(3)
        speed_sigma = math.inf
    receiver = _receiver_velocity(dataset, gnss_t[window], t0)
    if receiver is not None:  # Doppler: centimetres per second where positions give m/s
        velocity, acceleration, speed_sigma = receiver
    speed = float(np.linalg.norm(velocity[:2]))
    # Motion must stand out of the fit's own noise (metre-level fixes fake m/s at rest).
    moving_speed = max(moving_speed, 3.0 * speed_sigma)
    specific_force = imu.accel[first].mean(axis=0)
    # A quiet IMU means no acceleration and no turning: at rest, or cruising straight at a
    # constant speed (an aircraft in level flight, a car on a highway), which an IMU cannot
    # tell apart. The fixes can: a converging receiver fakes a few metres of motion at rest,
    # a cruising vehicle covers tens to thousands of metres in the fit window. So the IMU
    # decides "at rest" only when the fixes move further than GNSS drift can fake, judged on
    # medians (one multipath outlier near the start fakes tens of m/s in a quadratic fit).
    cruise_velocity = None
    if static:
        cruise_velocity = (
            velocity if receiver is not None else _median_velocity(gnss_t[window], gnss_enu[window])
        )
    if cruise_velocity is not None and not np.linalg.norm(cruise_velocity[:2]) >= moving_speed:
        cruise_velocity = None

    if cruise_velocity is not None or (speed >= moving_speed and not static):
        if cruise_velocity is not None:  # no acceleration: the quiet IMU says so
            velocity, acceleration = cruise_velocity, np.zeros(3)
        if travel == AHEAD_OR_BACK:
            # A car's height changes slowly; 6 s of metre-level fix heights fake m/s and m/s^2
            # (an urban car's fit: 9.8 m/s up, an acceleration that turned TRIAD upside down).
            velocity, acceleration = velocity * [1.0, 1.0, 0.0], acceleration * [1.0, 1.0, 0.0]
        elif abs(np.linalg.norm(acceleration - gravity) - np.linalg.norm(specific_force)) > 1.0:
            acceleration = acceleration * [1.0, 1.0, 0.0]  # the fit's vertical is not the IMU's
        nav_force = acceleration - gravity
        forward = np.array([velocity[0], velocity[1], velocity[2]])
        # Gravity's direction in IMU axes for the reversing test: the specific force averaged
        # over a minute (a car pulling away at 1.8 m/s^2 tilts the first second's by 10 deg,
        # and the gravity that tilt leaks into the forward axis outweighed the acceleration
        # it tested: a car driving ahead was aligned reversing).
        up_now = _level_up(imu, t0)
        if travel != ANY_DIRECTION and _travels_backward(
            imu, gnss_t[window], gnss_enu[window], velocity[:2], forward_axis, up_now
        ):
            forward = -forward  # reversing: the body's forward axis points against the track
        rotation = triad(specific_force, forward_axis, nav_force, forward)
        course_sigma_deg = max(10.0, float(np.degrees(np.arctan2(speed_sigma, max(speed, 1e-3)))))
        if heading_deg is not None:
            rotation = _with_heading(rotation, heading_deg, forward_axis)
            course_sigma_deg = 2.0
        return Alignment(
            t=t0,
            rotation=rotation,
            velocity=velocity,
            position=position,
            # The course's own uncertainty (a fit over few or noisy fixes) bounds the heading.
            attitude_sigma_rad=np.radians([3.0, 3.0, course_sigma_deg]),
            velocity_sigma=max(1.0, float(speed_sigma)),
            position_sigma=2.0,
            moving=True,
        )

    # At rest: level from gravity; heading from the first motion (or the configuration).
    rotation, heading_sigma_deg = _rest_attitude(
        dataset, gnss_t, gnss_enu, t0, first, heading_deg, moving_speed, forward_axis,
        gyro_bias_sigma, travel, static,
    )  # fmt: skip
    # A quiet IMU is at rest or moving at a constant velocity. Where the fixes' fit says it
    # moves (over 2 of its sigmas) but not far enough to rule out a converging receiver's
    # drift (the medians above), either may be true: rest, with a sigma that covers the
    # fitted speed. A car reversing at a steady 3 m/s was started at 0 +- 0.5 m/s (fit 3.2
    # +- 1.0): iSAM2's online pass never recovered (20 m off in its first outage).
    velocity_sigma = 0.5
    if static and speed > 2.0 * speed_sigma:
        velocity_sigma = max(velocity_sigma, speed)
    if not static and not math.isfinite(speed_sigma):
        velocity_sigma = UNKNOWN_START_SPEED_SIGMA  # moving, and one fix cannot say how
    return Alignment(
        t=t0,
        rotation=rotation,
        velocity=np.zeros(3) if static else velocity,
        position=position,
        attitude_sigma_rad=np.radians([2.0, 2.0, heading_sigma_deg]),
        velocity_sigma=velocity_sigma,
        position_sigma=2.0,
        moving=False,
        steady_motion_possible=velocity_sigma > 0.5,
    )


def _rest_attitude(
    dataset: Dataset,
    gnss_t: np.ndarray,
    gnss_enu: np.ndarray,
    t0: float,
    first: np.ndarray,
    heading_deg: float | None,
    moving_speed: float,
    forward_axis: np.ndarray,
    gyro_bias_sigma: float,
    travel: str,
    static: bool,
) -> tuple[np.ndarray, float]:
    """(body -> ENU rotation, heading 1-sigma in deg) of a vehicle standing at ``t0``:
    level from the specific force over the IMU samples ``first``; the heading configured,
    else (a vehicle moving in any direction, at rest) from its accelerations, else from the
    course of its first motion carried back with the gyro."""
    imu = dataset.imu
    g = normal_gravity(dataset.origin.lat, dataset.origin.alt)
    specific_force = imu.accel[first].mean(axis=0)
    up_body = specific_force / np.linalg.norm(specific_force)
    heading_sigma_deg = 2.0
    if heading_deg is None and travel == ANY_DIRECTION and static:
        found = _heading_from_acceleration(
            dataset, gnss_t, gnss_enu, t0, up_body, forward_axis, imu.gyro[first].mean(axis=0)
        )
        if found is not None:
            heading_deg, heading_sigma_deg = found
    if heading_deg is None:
        heading_deg, heading_sigma_deg = _heading_from_first_motion(
            dataset, gnss_t, gnss_enu, moving_speed, t0, up_body,
            rest_rate=_rest_rate_about(imu, t0, up_body, g) if static else None,
            gyro_bias_sigma=gyro_bias_sigma,
            # Not only a car's: any vehicle whose nose is its forward axis can back (an
            # aircraft's pushback, a vehicle of unstated kind reversing out of a bay, whose
            # heading from the track was 180 deg off: 67 of 141 fixes called faults).
            forward_axis=forward_axis if travel != ANY_DIRECTION else None,
            rest_force=specific_force if static else None,
        )  # fmt: skip
        if travel == ANY_DIRECTION:
            # A multirotor or walker moves in any direction: the course of its first motion
            # says nothing of its heading (outside tester: after a 60 s hover, 89 +- 2 deg
            # where the nose pointed at 30, and a backward flight 180 deg off; the batch bent
            # the gyro bias to meet it). Unknown, but for what the fit finds later.
            heading_sigma_deg = UNKNOWN_HEADING_SIGMA_DEG
    level = triad(up_body, forward_axis, np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0]))
    return _with_heading(level, heading_deg, forward_axis), heading_sigma_deg


def _receiver_velocity(
    dataset: Dataset, times: np.ndarray, t0: float
) -> tuple[np.ndarray, np.ndarray, float] | None:
    """(velocity at ``t0``, acceleration, horizontal speed sigma) from the receiver's own
    velocities at the fixes of ``times`` (a straight line through them), or None when the
    data carry fewer than two there. A 6-s quadratic through an urban receiver's fixes (3 m
    sigma, multipath jumps) put a car cruising at 14 m/s at rest with a 0.5 m/s sigma."""
    gnss = dataset.gnss
    velocity_nav = dataset.gnss_velocity_nav()
    if velocity_nav is None:
        return None
    rows = np.searchsorted(gnss.t, times)
    rows = rows[(rows < len(gnss.t))]
    rows = rows[np.isclose(gnss.t[rows], times[: len(rows)])] if len(rows) == len(times) else rows
    rows = rows[np.all(np.isfinite(velocity_nav[rows]), axis=1)]
    if len(rows) < 2:
        return None
    # A line through the fixes nearest t0 (over the whole window it misses a car braking
    # a few seconds later by m/s).
    near = rows[np.argsort(np.abs(gnss.t[rows] - t0), kind="stable")[:RECEIVER_FIXES]]
    rows = np.sort(near)
    dt = gnss.t[rows] - t0
    design = np.column_stack([np.ones(len(rows)), dt])
    coef, *_ = np.linalg.lstsq(design, velocity_nav[rows], rcond=None)
    residual = velocity_nav[rows] - design @ coef
    scatter = float(np.sqrt(np.mean(residual[:, :2] ** 2))) if len(rows) > 2 else 0.3
    return coef[0], coef[1], max(scatter, RECEIVER_SPEED_SIGMA_FLOOR)


RECEIVER_SPEED_SIGMA_FLOOR = 0.1  # m/s: a receiver's Doppler velocity at its best
RECEIVER_FIXES = 3  # the velocity at t0 from the receiver's this many nearest


def _median_velocity(t: np.ndarray, enu: np.ndarray) -> np.ndarray | None:
    """Constant velocity between the medians of the first and the second half of the fixes
    (time and position), when they lie ``MIN_CRUISE_DISTANCE_M`` or more apart; else None.
    Three fixes will do (the first and the last): at 0.2 Hz the fit window holds no more,
    and a car already at 15 m/s was aligned at rest (0 +- 15 m/s), EKF+RTS diverging to
    320 m at exit 0. (A wider window took in the first metres of a car moving off.)"""
    if len(t) < 3:
        return None
    order = np.argsort(t)
    half = len(t) // 2
    early, late = order[:half], order[len(t) - half :]
    displacement = np.median(enu[late], axis=0) - np.median(enu[early], axis=0)
    elapsed = float(np.median(t[late]) - np.median(t[early]))
    if elapsed <= 0 or float(np.linalg.norm(displacement[:2])) < MIN_CRUISE_DISTANCE_M:
        return None
    return displacement / elapsed


def _rest_rate_about(imu, t0: float, up_body: np.ndarray, gravity: float) -> float:
    """Mean gyro rate about ``up_body`` over the 1 s blocks from ``t0`` while the IMU stays
    at rest (up to ``MAX_REST_S``): the gyro bias plus the Earth's rate about up. A block
    whose rate differs from the first's by more than ``REST_RATE_TOLERANCE`` ends the rest
    (a car creeping off into a bend is still "quiet" to the IMU, but it turns)."""
    rates: list[float] = []
    starts = np.arange(t0, t0 + MAX_REST_S, 1.0)
    bounds = np.searchsorted(imu.t, np.append(starts, starts[-1] + 1.0))  # [start, start + 1)
    for lo, hi in itertools.pairwise(bounds):
        block = slice(int(lo), int(hi))
        if hi - lo < 10 or not _imu_static(imu.gyro[block], imu.accel[block], gravity):
            break
        rate = float(np.mean(imu.gyro[block] @ up_body))
        if rates and abs(rate - rates[0]) > REST_RATE_TOLERANCE:
            break
        rates.append(rate)
    return float(np.mean(rates)) if rates else 0.0


MAX_REST_S = 120.0
REST_RATE_TOLERANCE = 0.002  # rad/s (0.1 deg/s): far above a 1 s mean's gyro noise


def _with_heading(rotation: np.ndarray, heading_deg: float, forward_axis: np.ndarray) -> np.ndarray:
    """Turn ``rotation`` about the vertical so that the vehicle's forward axis (in IMU axes)
    points at ``heading_deg`` (from north, clockwise), keeping the tilt."""
    forward = rotation @ forward_axis
    current = np.degrees(np.arctan2(forward[0], forward[1]))
    turn = np.radians(current - heading_deg)  # counter-clockwise about up lowers the heading
    c, s = np.cos(turn), np.sin(turn)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ rotation


def _steady(imu, t0: float, t1: float) -> bool:
    """Whether the IMU's 1-s means stay within STEADY_FORCE_M_S2 (specific force, per axis)
    and STEADY_RATE_RAD_S (rates) of their mean from ``t0`` to ``t1``: at rest or at one
    velocity (an aircraft cruising), where a line through the fixes is the motion."""
    inside = (imu.t >= t0) & (imu.t <= t1)
    if inside.sum() < 3:
        return False
    means = second_means(imu.t[inside], imu.accel[inside], imu.gyro[inside])
    if means is None or len(means[0]) < 2:
        return False
    return bool(
        np.max(np.abs(means[0] - means[0].mean(axis=0))) < STEADY_FORCE_M_S2
        and np.max(np.abs(means[1] - means[1].mean(axis=0))) < STEADY_RATE_RAD_S
    )


STEADY_FORCE_M_S2 = 0.1
STEADY_RATE_RAD_S = 0.01


def _imu_static(gyro: np.ndarray, accel: np.ndarray, gravity: float) -> bool:
    """At rest: steady rates (their mean is the gyro bias, which can be large), specific
    force close to g and steady."""
    return bool(
        np.all(gyro.std(axis=0) < 0.01)
        and np.linalg.norm(gyro.mean(axis=0)) < 0.05
        and abs(np.linalg.norm(accel.mean(axis=0)) - gravity) < 0.3
        and np.all(accel.std(axis=0) < 0.3)
    )


# A first-motion chord at speed v needs the accelerometer (less its rest level) to have
# integrated to at least this fraction of v since the start, or CHORD_SPEED_SEEN_M_PER_S.
CHORD_SPEED_SEEN_FRACTION = 0.25
CHORD_SPEED_SEEN_M_PER_S = 1.0
# A chord of chord_s this fraction of min_chord_m long (5 m in 5 s: 1 m/s, above metre-level
# fix noise at rest) may be a slow vehicle's first motion: it is followed along the straight.
SLOW_CHORD_MIN_FRACTION = 0.25


OUTLIER_WINDOW_FIXES = 3  # each side of a fix judged against its neighbours


def _stated_fix_sigma(dataset: Dataset) -> float | None:
    """Median horizontal 1-sigma (m) the fixes state (covariance, GST), None without."""
    std = dataset.gnss.std
    horizontal = std[:, :2][np.isfinite(std[:, :2])] if std is not None else np.zeros(0)
    return float(np.median(horizontal)) if len(horizontal) else None


def _outlying_fix(gnss_t: np.ndarray, gnss_enu: np.ndarray, i: int, fix_sigma: float) -> bool:
    """Is fix ``i`` off the line its neighbours trace (the ``2 OUTLIER_WINDOW_FIXES + 1``
    fixes around it, shifted inward at the ends of the log), by the trimmed fit's test
    (:func:`_fit_inliers`, scale at least ``fix_sigma``)?"""
    width = 2 * OUTLIER_WINDOW_FIXES + 1
    lo = int(np.clip(i - OUTLIER_WINDOW_FIXES, 0, max(len(gnss_t) - width, 0)))
    hi = min(len(gnss_t), lo + width)
    design = np.vander(gnss_t[lo:hi] - gnss_t[i], 2, increasing=True)
    return not bool(_fit_inliers(design, gnss_enu[lo:hi, :2], fix_sigma)[i - lo])


def _imu_saw_speed(imu, rest_force: np.ndarray, t0: float, t1: float, speed: float) -> bool:
    """Did the IMU, at rest at ``t0``, pick up speed by ``t1``? The specific force less its
    rest level, integrated (the velocity change in body axes, near enough over a start
    that turns little): a vehicle that stood still has ~0 however far its fixes jump (two
    fixes 23 m apart in 1 s at a standstill gave a heading 34 deg off with an 8 deg sigma)."""
    inside = (imu.t >= t0) & (imu.t <= t1)
    if inside.sum() < 2:
        return True
    dt = np.diff(imu.t[inside], append=imu.t[inside][-1])
    gained = float(np.linalg.norm(((imu.accel[inside] - rest_force) * dt[:, None]).sum(axis=0)))
    return gained >= min(CHORD_SPEED_SEEN_FRACTION * speed, CHORD_SPEED_SEEN_M_PER_S)


def _heading_from_first_motion(
    dataset: Dataset,
    gnss_t: np.ndarray,
    gnss_enu: np.ndarray,
    moving_speed: float,
    t0: float,
    up_body: np.ndarray,
    chord_s: float = 5.0,
    min_chord_m: float = 20.0,
    rest_rate: float | None = None,
    gyro_bias_sigma: float = 0.0,
    forward_axis: np.ndarray | None = None,
    rest_force: np.ndarray | None = None,
) -> tuple[float, float]:
    """(heading at the start, its 1-sigma) in deg: the course once moving, minus the yaw
    turned since the start; (0, 180) when the vehicle never moves.

    The course comes from a chord of at least ``min_chord_m`` over ``chord_s`` seconds, so
    metre-level GNSS noise at rest cannot fake a direction (single-epoch differences can).
    When the vehicle then goes straight (the gyro turns it less than ``STRAIGHT_TURN_DEG``,
    up to ``MAX_CHORD_S``) the fixes along the whole straight give the course: an
    aircraft's take-off roll or a car's first straight, good to a degree instead of the ~5
    deg of 20 m of metre-level fixes. The sigma says which: the scatter of the fixes about
    their line, the turn the gyro saw over them (a course fitted through a curve is not
    the heading at one instant), and the unknown gyro bias over the time carried back.

    ``rest_rate`` (rad/s) is what the gyro reads about up while the vehicle stands still
    (its bias and the Earth's rate): a vehicle at rest does not turn, so that reading is
    not counted as yaw turned. Without it (no rest at the start) ``gyro_bias_sigma`` times
    the time carried back enters the sigma.

    A vehicle that first backs out (of a parking space, a hangar) travels against its
    forward axis (``forward_axis``, IMU axes): :func:`_travels_backward` reads that from the
    accelerometer, and the heading is then the course plus 180 deg.
    """
    imu = dataset.imu
    fix_sigma = max(_stated_fix_sigma(dataset) or DEFAULT_FIX_SIGMA_M, FIT_MIN_SCALE_M)
    # Yaw rate about the body's up (gravity at rest), any axes, less what it reads at rest.
    rate_up = imu.gyro @ up_body - (0.0 if rest_rate is None else rest_rate)
    unknown_rate = gyro_bias_sigma if rest_rate is None else 0.0
    yaw = np.concatenate([[0.0], np.cumsum(rate_up[:-1] * np.diff(imu.t))])

    def yaw_at(t: float) -> float:
        return float(np.interp(t, imu.t, yaw))

    if rest_force is not None:
        # The IMU confirms each chord (below), so the chord's length decides, not the
        # caller's noise-based speed: one or two multipath fixes among the first seconds'
        # inflate that to 17-20 m/s, and a car driving off at 8 m/s was never "moving" (its
        # heading unknown, the forward EKF 57-108 m off).
        moving_speed = min(moving_speed, min_chord_m / chord_s)
    # The last fix within chord_s (and within MAX_CHORD_S) of each fix (times ascending).
    chord_end = np.searchsorted(gnss_t, gnss_t + chord_s, side="right") - 1
    stretch_end = np.searchsorted(gnss_t, gnss_t + MAX_CHORD_S, side="right") - 1
    def slow_chord_end(k: int, j: int) -> int:
        """A vehicle pulling away slowly (a field robot, a tractor, a car creeping off at
        2 m/s) covers less than ``min_chord_m`` in ``chord_s``: the chord from fix k goes
        on while the gyro says straight, up to ``MAX_CHORD_S``, until it is that long (at
        2 m/s the heading was never found; the forward EKF, started 180 deg unknown, locked
        onto a heading 55 deg off and ran 105 m off). ``j`` when it never gets there."""
        for m in range(j + 1, int(stretch_end[k]) + 1):
            if abs(yaw_at(gnss_t[m]) - yaw_at(gnss_t[k])) > np.radians(STRAIGHT_TURN_DEG):
                break
            if np.linalg.norm(gnss_enu[m, :2] - gnss_enu[k, :2]) >= min_chord_m:
                return m
        return j

    for k in range(len(gnss_t)):
        j = int(chord_end[k])
        if j <= k:
            continue
        chord = gnss_enu[j, :2] - gnss_enu[k, :2]
        span = gnss_t[j] - gnss_t[k]
        length = float(np.linalg.norm(chord))
        speed_needed = moving_speed
        if rest_force is not None and SLOW_CHORD_MIN_FRACTION * min_chord_m <= length < min_chord_m:
            # The accelerometer confirms the motion below, so a slower speed may count.
            j = slow_chord_end(k, j)
            span = gnss_t[j] - gnss_t[k]
            length = float(np.linalg.norm(gnss_enu[j, :2] - gnss_enu[k, :2]))
            speed_needed = min(moving_speed, min_chord_m / MAX_CHORD_S)
        if length >= min_chord_m and length / span >= speed_needed:
            if rest_force is not None and not _imu_saw_speed(
                imu, rest_force, t0, float(gnss_t[j]), length / span
            ):
                continue  # fixes that jump while the IMU stays at rest: noise, not motion
            if _outlying_fix(gnss_t, gnss_enu, k, fix_sigma) or _outlying_fix(
                gnss_t, gnss_enu, j, fix_sigma
            ):
                # A chord from or to a multipath fix points anywhere (a highway car pulling
                # away: a 25 m fix at 1 s turned its start heading by 167 deg; the forward EKF
                # 545 m off, the batch diverged).
                continue
            for m in range(j + 1, int(stretch_end[k]) + 1):  # while the vehicle goes straight
                if abs(yaw_at(gnss_t[m]) - yaw_at(gnss_t[k])) > np.radians(STRAIGHT_TURN_DEG):
                    break
                j = int(m)
            points = gnss_enu[k : j + 1, :2]
            direction, line_sigma = _straight_direction(points)
            # From the start (at rest: speed zero, the accelerometer's reading there its
            # bias) through the stretch, so the test sees the vehicle pull away.
            first = int(np.searchsorted(gnss_t, t0)) if rest_rate is not None else k
            if forward_axis is not None and _travels_backward(
                imu, gnss_t[first : j + 1], gnss_enu[first : j + 1], direction, forward_axis,
                up_body, rest_force=rest_force,
            ):  # fmt: skip
                direction = -direction
            # The fitted course is that of the middle of the stretch in distance, not in
            # time (a vehicle speeding up through a curve): the heading of that instant.
            along = (points - points[0]) @ direction
            middle = 0.5 * (along.min() + along.max())
            t_move = float(np.interp(middle, np.maximum.accumulate(along), gnss_t[k : j + 1]))
            heading = float(np.degrees(np.arctan2(direction[0], direction[1])))
            # Yaw turned since the start: the rate about the body's up direction (gravity at
            # rest), whatever the IMU's axis convention (z up or z down).
            yaw_turned = yaw_at(t_move) - yaw_at(t0)
            turn_over_chord = abs(yaw_at(gnss_t[j]) - yaw_at(gnss_t[k]))
            carried = unknown_rate * abs(t_move - t0)
            sigma = float(np.degrees(np.sqrt(line_sigma**2 + turn_over_chord**2 + carried**2)))
            return float(np.mod(heading + np.degrees(yaw_turned), 360.0)), float(
                np.clip(sigma, 2.0, 180.0)
            )
    if rest_force is not None:
        found = _heading_from_straightened_track(
            imu, gnss_t, gnss_enu, t0, yaw_at, up_body, min_chord_m, fix_sigma,
            forward_axis, rest_force,
        )  # fmt: skip
        if found is not None:
            return found
    return 0.0, 180.0


def _heading_from_straightened_track(
    imu,
    gnss_t: np.ndarray,
    gnss_enu: np.ndarray,
    t0: float,
    yaw_at,
    up_body: np.ndarray,
    min_chord_m: float,
    fix_sigma: float,
    forward_axis: np.ndarray | None,
    rest_force: np.ndarray,
) -> tuple[float, float] | None:
    """(heading at ``t0``, its 1-sigma) in deg of a vehicle that left rest along its forward
    axis but never went straight for ``min_chord_m``: a field robot, a tractor or a car
    creeping at 0.5-1 m/s between turns. Each step between fixes is turned back by the yaw the
    gyro turned since ``t0`` (``yaw_at``, counter-clockwise): the steps of a vehicle that
    travels along its forward axis then all point along its heading at ``t0``, so the
    straightened track is a line, whatever the turns. Its direction (a line fit; the scatter
    about it, from fix noise, slip or gyro error, gives the sigma) over the first
    ``STRAIGHTENED_MAX_S`` is the heading once it reaches ``min_chord_m`` and the IMU saw
    the vehicle pick up speed. None otherwise. (Without it the heading stayed unknown, and
    the forward EKF locked onto one 55 deg off: 33 m off in outages at 1 m/s.)"""
    after = np.flatnonzero((gnss_t >= t0) & (gnss_t <= t0 + STRAIGHTENED_MAX_S))
    if len(after) < 5:
        return None
    t, points = gnss_t[after], gnss_enu[after, :2]
    yaw_mid = np.array([yaw_at(0.5 * (a + b)) for a, b in itertools.pairwise(t)]) - yaw_at(t0)
    step = np.diff(points, axis=0)
    cos, sin = np.cos(yaw_mid), np.sin(yaw_mid)
    back = np.column_stack([cos * step[:, 0] + sin * step[:, 1], -sin * step[:, 0] + cos * step[:, 1]])
    track = np.vstack([np.zeros(2), np.cumsum(back, axis=0)])
    length = float(np.linalg.norm(track[-1]))
    span = float(t[-1] - t[0])
    if length < min_chord_m or not _imu_saw_speed(imu, rest_force, t0, float(t[-1]), length / span):
        return None
    direction, line_sigma = _straight_direction(track)
    scatter = float(np.linalg.norm(track - np.outer((track - track[0]) @ direction, direction) - track[0], axis=1).max())
    if scatter > STRAIGHTENED_MAX_SCATTER_SIGMAS * max(fix_sigma, MIN_LINE_SCATTER_M) + 0.1 * length:
        return None  # not a line: the vehicle did not travel along its forward axis
    if forward_axis is not None and _travels_backward(
        imu, t, np.column_stack([track, np.zeros(len(t))]), direction, forward_axis, up_body,
        rest_force=rest_force,
    ):  # fmt: skip
        direction = -direction
    heading = float(np.degrees(np.arctan2(direction[0], direction[1])))
    return float(np.mod(heading, 360.0)), float(np.clip(np.degrees(line_sigma), 2.0, 180.0))


def travels_along_nose(smoother: SmootherConfig | None) -> bool:
    """Does the vehicle's velocity follow its forward axis (ahead, or for a land vehicle
    ahead or reversing)? Not a multirotor's or a pedestrian's."""
    return _travel(smoother) != ANY_DIRECTION


def _travel(smoother: SmootherConfig | None) -> str:
    """How the vehicle moves relative to its forward axis: a land vehicle (the NHC holds)
    ahead or reversing; a multirotor or a pedestrian in any direction (a drone flies
    sideways with its nose held); anything else (an aircraft, a boat) ahead."""
    if smoother is None:
        return AHEAD
    if smoother.nhc:
        return AHEAD_OR_BACK
    return ANY_DIRECTION if smoother.vehicle in ("uav", "pedestrian") else AHEAD


def _heading_from_acceleration(
    dataset: Dataset,
    gnss_t: np.ndarray,
    gnss_enu: np.ndarray,
    t0: float,
    up_body: np.ndarray,
    forward_axis: np.ndarray,
    gyro_bias: np.ndarray,
) -> tuple[float, float] | None:
    """(heading of the forward axis at ``t0``, its 1-sigma) in deg, for a vehicle at rest at
    ``t0`` that may move in any direction; None when it does not move far enough to tell.

    The course of the first motion is the heading only for a vehicle that travels along its
    forward axis; a multirotor that takes off and flies sideways was aligned 90 deg off (the
    Kalman filters 76-185 m off, z 100-300). Instead the IMU is dead-reckoned from rest in a
    level frame of unknown heading (gyro less its rest reading, the accelerometer, gravity),
    and the heading is the rotation about up that lays that track onto the fixes' (a least-
    squares fit with the start position and a constant acceleration error free). Its sigma
    from the fit, at least ``MIN_ACCEL_HEADING_SIGMA_DEG``."""
    imu = dataset.imu
    far = np.flatnonzero(
        np.linalg.norm(gnss_enu[:, :2] - np.median(gnss_enu[:3, :2], axis=0), axis=1)
        >= ACCEL_HEADING_DISTANCE_M
    )
    far = far[gnss_t[far] > t0]
    if not len(far) or gnss_t[far[0]] > t0 + MAX_ACCEL_HEADING_S - ACCEL_HEADING_EXTRA_S:
        # No motion inside the fit's window (a multirotor hovering 70 s before it flies):
        # the fit would lay out noise and bias drift, and found headings 70-150 deg off with
        # sigmas of 40-50 deg.
        return None
    t_end = min(float(gnss_t[far[0]]) + ACCEL_HEADING_EXTRA_S, t0 + MAX_ACCEL_HEADING_S)
    inside = (imu.t >= t0) & (imu.t <= t_end)
    fixes = (gnss_t >= t0) & (gnss_t <= t_end)
    if inside.sum() < 10 or fixes.sum() < 5:
        return None
    g = normal_gravity(dataset.origin.lat, dataset.origin.alt)
    level = triad(up_body, forward_axis, np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0]))
    t = imu.t[inside]
    step = np.diff(t)
    gyro, accel = imu.gyro[inside], imu.accel[inside]  # once: not a masked copy per sample
    rotations = np.empty((len(t), 3, 3))
    rotations[0] = level
    for k in range(len(t) - 1):
        rotations[k + 1] = rotations[k] @ so3_exp((gyro[k] - gyro_bias) * step[k])

    def twice_integrated(acceleration: np.ndarray) -> np.ndarray:
        """Position (at the fixes, horizontal) of a dead reckoning from rest, held samples."""
        velocity = np.vstack([np.zeros(3), np.cumsum(acceleration[:-1] * step[:, None], axis=0)])
        position = np.vstack([
            np.zeros(3),
            np.cumsum(velocity[:-1] * step[:, None] + 0.5 * acceleration[:-1] * step[:, None] ** 2,
                      axis=0),
        ])  # fmt: skip
        return np.column_stack([np.interp(gnss_t[fixes], t, position[:, i]) for i in range(2)])

    dead = twice_integrated(np.einsum("nij,nj->ni", rotations, accel) + np.array([0.0, 0.0, -g]))
    # What a constant accelerometer bias (body axes) does to the dead reckoning: one track per
    # axis. A consumer IMU's 10 mg is 45 m over 30 s, and it turns with the body as the
    # vehicle yaws, so a constant level-frame acceleration cannot absorb it. The track of the
    # axis along up stands for the rest level's tilt error (that bias tilts the level, and
    # the error turns with the body). Each bias is bounded by a prior (below): a multirotor
    # tilts its up (thrust) axis toward its acceleration, so that track is the dead
    # reckoning itself over g, and a free coefficient on it made the fit's scale and turn
    # arbitrary (3-13 instead of 1 on an outside tester's flights; the heading fell back to
    # the course of the first motion, 90-180 deg off). Mimicking the scale needs ~g there,
    # 20 prior sigmas away.
    bias_tracks = [twice_integrated(rotations[:, :, i]) for i in range(3)]
    seen = gnss_enu[fixes, :2]
    # seen = Rz(turn) (dead + sum_i b_i D_i) + c + d tau^2: linear in (cos, sin), c, d and,
    # for each bias axis, the 2-vector (cos b_i, sin b_i) (a free pair: over-parametrised,
    # unbiased). c: the start position; d: a level error (a constant acceleration).
    tau = gnss_t[fixes] - t0
    n = len(tau)

    def rotated(track: np.ndarray) -> np.ndarray:
        """Columns multiplying (cos, sin) in Rz(turn) @ track, east rows then north rows."""
        return np.vstack([
            np.column_stack([track[:, 0], -track[:, 1]]),
            np.column_stack([track[:, 1], track[:, 0]]),
        ])  # fmt: skip

    offsets = np.zeros((2 * n, 4))
    offsets[:n, 0], offsets[n:, 1] = 1.0, 1.0
    offsets[:n, 2], offsets[n:, 3] = tau**2, tau**2
    design = np.hstack([rotated(dead), offsets, *[rotated(track) for track in bias_tracks]])
    observed = np.concatenate([seen[:, 0], seen[:, 1]])
    # Prior rows: each bias coefficient (m/s^2) is 0 +- ACCEL_HEADING_BIAS_PRIOR, against
    # fixes of ~ACCEL_HEADING_FIX_SIGMA_M (metres): weights in the fit's own units.
    n_bias = 2 * len(bias_tracks)
    prior = np.zeros((n_bias, design.shape[1]))
    prior[:, -n_bias:] = np.eye(n_bias) * (ACCEL_HEADING_FIX_SIGMA_M / ACCEL_HEADING_BIAS_PRIOR)
    design_p = np.vstack([design, prior])
    coef, *_ = np.linalg.lstsq(design_p, np.concatenate([observed, np.zeros(n_bias)]), rcond=None)
    scale = float(np.hypot(coef[0], coef[1]))
    if not 0.5 < scale < 2.0:  # the dead reckoning does not look like the track: cannot tell
        return None
    turn = float(np.arctan2(coef[1], coef[0]))  # counter-clockwise from the level frame to ENU
    residual = observed - design @ coef
    scatter = max(float(np.sqrt(residual @ residual / max(2 * n - design.shape[1], 1))), 0.5)
    covariance = scatter**2 * np.linalg.pinv(design_p.T @ design_p)[:2, :2]
    tangent = np.array([-np.sin(turn), np.cos(turn)])
    sigma = float(np.degrees(np.sqrt(tangent @ covariance @ tangent) / scale))
    sigma = max(sigma, MIN_ACCEL_HEADING_SIGMA_DEG)
    # The level frame's forward axis points north (heading 0); turned counter-clockwise by
    # ``turn``, its heading (clockwise from north) is -turn.
    return float(np.mod(-np.degrees(turn), 360.0)), float(min(sigma, 180.0))


ACCEL_HEADING_DISTANCE_M = 20.0  # the fixes must move this far from the start to tell
ACCEL_HEADING_EXTRA_S = 10.0  # and the fit runs this much longer
MAX_ACCEL_HEADING_S = 60.0
MIN_ACCEL_HEADING_SIGMA_DEG = 3.0
UNKNOWN_HEADING_SIGMA_DEG = 90.0  # a heading prior that says only "somewhere"
ACCEL_HEADING_BIAS_PRIOR = 0.5  # m/s^2 (50 mg): beyond any MEMS turn-on bias
ACCEL_HEADING_FIX_SIGMA_M = 1.0


def _travels_backward(
    imu,
    gnss_t: np.ndarray,
    gnss_enu: np.ndarray,
    direction: np.ndarray,
    forward_axis: np.ndarray,
    up_body: np.ndarray,
    rest_force: np.ndarray | None = None,
) -> bool:
    """Did the vehicle move along ``direction`` (the fixes' horizontal course over
    ``gnss_t``) backwards, i.e. against its forward axis?

    The accelerometer along the body's horizontal forward axis (``forward_axis`` less its
    part along ``up_body``) integrates twice to a signed distance travelled, up to the
    unknown initial speed; the fixes' distance along ``direction`` is fitted by
    ``b + a t + c D(t)``: ``c`` near +1 means forward, near -1 backward. Only a speed change
    tells the two apart (a vehicle cruising at constant speed reads nothing), so backward is
    claimed only when ``c`` is below -0.5 and significantly negative (3 sigma, from the
    fixes' scatter about the fit). Gravity leaking in through a pitch change and the
    accelerometer bias look like a constant acceleration: they scale ``c`` towards zero but
    do not flip it while the real acceleration dominates (a car pulling away: 1-3 m/s^2
    against ~0.1). ``rest_force``: the specific force read at rest before (its horizontal
    part is the accelerometer's bias and is taken off).
    """
    axis = np.asarray(forward_axis, dtype=float)
    axis = axis - (axis @ up_body) * up_body
    if np.linalg.norm(axis) < 0.5:  # the forward axis is (nearly) vertical: no test
        return False
    axis = axis / np.linalg.norm(axis)
    # The double integral holds only where the IMU has no gap: the fixes are taken over the
    # IMU's longest gap-free run (the KITTI drive's first sample stands 1.92 s before the
    # next; integrated across that gap, or with fixes outside the run clamped to its ends,
    # a 20 ms clock offset turned the start round by 180 deg at exit 0).
    inside = (imu.t >= gnss_t[0]) & (imu.t <= gnss_t[-1])
    if inside.sum() < 10:
        return False
    start, end = _longest_gap_free_run(imu.t[inside])
    covered = (gnss_t >= start) & (gnss_t <= end)
    gnss_t, gnss_enu = gnss_t[covered], gnss_enu[covered]
    if len(gnss_t) < 5:
        return False
    inside = (imu.t >= gnss_t[0]) & (imu.t <= gnss_t[-1])
    if inside.sum() < 10:
        return False
    t = imu.t[inside]
    step = np.diff(t)
    force = imu.accel[inside] @ axis - (0.0 if rest_force is None else float(rest_force @ axis))
    speed = np.concatenate([[0.0], np.cumsum(force[:-1] * step)])
    if np.ptp(speed) < MIN_SPEED_CHANGE_M_S:
        # No speed change the accelerometer's bias could not fake: nothing to tell ahead
        # from back by (a car cruising at 12 m/s through 3 m urban fixes was fitted c = -14).
        return False
    distance = np.concatenate([[0.0], np.cumsum(0.5 * (speed[:-1] + speed[1:]) * step)])
    along = (gnss_enu[:, :2] - gnss_enu[0, :2]) @ (direction / np.linalg.norm(direction))
    design = np.column_stack(
        [np.ones(len(gnss_t)), gnss_t - gnss_t[0], np.interp(gnss_t, t, distance)]
    )
    coef, *_ = np.linalg.lstsq(design, along, rcond=None)
    residual = along - design @ coef
    scatter = max(float(np.sqrt(residual @ residual / (len(gnss_t) - 3))), 0.3)
    # The model must explain the motion (not a loop flown sideways, not a slipping vehicle).
    if scatter > max(3.0, 0.2 * float(np.std(along))):
        return False
    normal = design.T @ design
    if np.linalg.cond(normal) > 1e12:
        return False
    c_sigma = scatter * float(np.sqrt(np.linalg.inv(normal)[2, 2]))
    return bool(coef[2] < -0.5 and coef[2] + 3.0 * c_sigma < 0.0)


def _longest_gap_free_run(t: np.ndarray) -> tuple[float, float]:
    """First and last time of the longest stretch of ``t`` without a gap (an interval over
    :data:`fgins.io.imu_checks.GAP_FACTOR` nominal periods)."""
    step = np.diff(t)
    breaks = np.flatnonzero(step > GAP_FACTOR * float(np.median(step)))
    first = np.concatenate([[0], breaks + 1])
    last = np.concatenate([breaks, [len(t) - 1]])
    longest = int(np.argmax(t[last] - t[first]))
    return float(t[first[longest]]), float(t[last[longest]])


MIN_SPEED_CHANGE_M_S = 1.0  # 0.1 m/s^2 of bias and tilt over 6 s fake 0.6 m/s


def _straight_direction(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Unit direction of travel along a stretch of fixes (n, 2), first to last, and its
    1-sigma (rad): the principal axis of the fixes, refitted once without those far off the
    line (a multipath outlier at an end would turn a two-point chord by degrees), the sigma
    from the scatter about the line and the stretch's extent."""
    keep = np.ones(len(points), dtype=bool)
    for _ in range(2):
        centre = points[keep].mean(axis=0)
        _, _, axes = np.linalg.svd(points[keep] - centre, full_matrices=False)
        direction = axes[0]
        if direction @ (points[-1] - points[0]) < 0:
            direction = -direction
        normal = np.array([-direction[1], direction[0]])
        across = (points - centre) @ normal
        spread = 1.4826 * float(np.median(np.abs(across[keep])))
        keep = np.abs(across) <= max(3.0 * spread, MIN_LINE_SCATTER_M)
    along = (points[keep] - centre) @ direction
    n = int(keep.sum())
    scatter = max(float(np.std(across[keep])) * np.sqrt(n / max(n - 2, 1)), MIN_LINE_SCATTER_M)
    extent = float(np.sqrt(np.sum((along - along.mean()) ** 2)))
    return direction, scatter / max(extent, 1e-6)


# The first-motion chord is stretched over a straight stretch up to this long, and while
# the gyro turns less than this; fixes are taken to scatter about the line by at least
# this much (the sigma is never claimed from a few lucky fixes).
MAX_CHORD_S = 30.0
STRAIGHT_TURN_DEG = 2.0
MIN_LINE_SCATTER_M = 1.0
# A slow vehicle's track straightened by the gyro's yaw: fixes over this long from the start,
# and no fix further off the fitted line than this many fix sigmas plus 10 % of its length.
STRAIGHTENED_MAX_S = 60.0
STRAIGHTENED_MAX_SCATTER_SIGMAS = 4.0
