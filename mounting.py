"""IMU mounting: the IMU's orientation in the vehicle frame (numpy only).

``imu_to_vehicle_rpy_deg = [roll, pitch, yaw]`` are the usual mounting angles: the rotation
that takes the vehicle frame (x forward, y left, z up) onto the IMU's axes, applied as yaw
about z, then pitch about the new y, then roll about the new x (ZYX). Its matrix
``R_vi = Rz(yaw) Ry(pitch) Rx(roll)`` maps a vector given in IMU axes into vehicle axes:
``u_vehicle = R_vi @ u_imu``. Example: an IMU turned 90 deg to the left in the car (its x
axis points to the car's left) has yaw = 90; an IMU mounted x forward, y right, z down (FRD)
has roll = 180.

The factor graph, every Kalman baseline and the initial alignment take the rotation from
here, so they cannot disagree about the convention.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np

from fgins.datatypes import InputError, median_interval
from fgins.planar import complex_at, horizontal_axes, window_means, yaw_about


def _axis_rotation(axis: int, angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    i, j = [(1, 2), (2, 0), (0, 1)][axis]
    rotation = np.eye(3)
    rotation[i, i] = rotation[j, j] = c
    rotation[i, j], rotation[j, i] = -s, s
    return rotation


def mounting_rotation(rpy_deg: tuple[float, float, float] | np.ndarray) -> np.ndarray:
    """``R_vi`` (IMU axes -> vehicle axes) from the mounting angles (deg; see module docs).

    Its rows are the vehicle's forward, left and up axes expressed in IMU axes.
    """
    roll, pitch, yaw = np.radians(np.asarray(rpy_deg, dtype=float))
    return _axis_rotation(2, yaw) @ _axis_rotation(1, pitch) @ _axis_rotation(0, roll)



# Centripetal acceleration: the motion's own evidence of where the vehicle's nose points.
MOTION_MIN_RATE_RAD_S = 0.05  # ~3 deg/s: a turn, not a curve
MOTION_STEP_S = 0.2  # evaluated on this grid
MOTION_WINDOW_S = 1.0  # IMU averaged over this around each grid time
MOTION_MAX_FIX_GAP_S = 1.5  # speed interpolated only this close to a fix
MOTION_MIN_SPEED_M_S = 3.0
CENTRIPETAL_MIN_M_S2 = 0.5  # a time "in a turn" has v * w above this
MOTION_MIN_TURN_S = 12.0  # seconds of turning needed to tell (9 s: up to 20 deg off)
# Without enough turns, speeding up and slowing down (forward acceleration above this, for
# this long) show the nose too.
SPEED_CHANGE_MIN_M_S2 = 0.5
SPEED_CHANGE_WINDOW_S = 4.0
STRAIGHT_MAX_CENTRIPETAL_M_S2 = 0.1  # straight ahead: v w below this
MOTION_MIN_SPEED_CHANGE_S = 8.0
MOTION_MAX_SIGMA_DEG = 2.0  # the fitted nose direction's standard error: above, cannot tell
GRAVITY_M_S2 = 9.81
MOTION_SCALE_RANGE = (0.7, 1.3)  # |specific force per v w| in the turns: ~1
CHORD_S = 4.0  # speed from positions over this (when the GNSS has no velocity)
CLIMB_CHORD_S = 10.0  # and the climb (grades change slowly; heights are noisier)


def forward_axis_from_motion(dataset) -> tuple[np.ndarray, int] | None:
    """The vehicle's forward axis in IMU axes as the motion shows it (the turns, else the
    straight speed changes, else the IMU's heading against the direction of travel), or
    None when the drive cannot tell; with the seconds used."""
    found = _forward_axis(dataset)
    return None if found is None else (found.forward, found.seconds)


@dataclass(frozen=True)
class ForwardAxis:
    """The vehicle's forward axis in IMU axes as the drive shows it, the seconds used, what
    shows it (words for a message), from the heading match its standard error (deg; None
    for the turns' and speed changes' fits, good to ~0.1-1 deg), and from the turns the
    IMU's lever ahead of the non-slipping point where they show one."""

    forward: np.ndarray
    seconds: int
    evidence: str
    sigma_deg: float | None = None
    lever: tuple[float, float] | None = None  # the turns' lever terms: (m ahead, sigma)
    way_known: bool = True  # False: forward or backward along ``forward``, the data cannot tell

    def facing(self, rpy_deg) -> np.ndarray:
        """``forward``, or its opposite where the data cannot tell the way and that lies
        nearer the forward axis of the mounting ``rpy_deg``."""
        if self.way_known or mounting_rotation(rpy_deg)[0] @ self.forward >= 0.0:
            return self.forward
        return -self.forward


# One run asks up to three times (check, adopt, the adopted check) for the same drive: the
# last answer is kept while the very same IMU and GNSS data are asked about (weak
# references: a new or changed dataset brings new objects).
_last_forward_axis: list = []


def _forward_axis(dataset) -> ForwardAxis | None:
    arrays = (dataset.imu, dataset.imu.accel, dataset.imu.gyro, dataset.gnss, dataset.gnss.lla)
    if _last_forward_axis and all(ref() is array for ref, array in zip(_last_forward_axis[0], arrays, strict=True)):
        return _last_forward_axis[1]
    answer = None
    # Fixes further apart than the turns' speed can follow (0.2 Hz): the heading match
    # first. There the turns' fit missed a lever's -l w^2 (IMU 1.2 m ahead in a roundabout:
    # 3.9 deg off, the batch 1.34 m inside an outage against 0.65 m); the heading match
    # regresses the fixes' own accelerations over its long windows (+-1 deg).
    sparse = median_interval(dataset.gnss.t) > MOTION_MAX_FIX_GAP_S
    if sparse:
        answer = _heading_answer(dataset)
    if answer is None:
        found = _turns_fit(dataset)
        if found is not None:
            answer = ForwardAxis(found[0], found[1], "turns or speed changes", lever=found[2])
        elif not sparse:
            answer = _heading_answer(dataset)
    _last_forward_axis[:] = [tuple(weakref.ref(array) for array in arrays), answer]
    return answer


def _heading_answer(dataset) -> ForwardAxis | None:
    heading = forward_axis_from_heading(dataset)
    return None if heading is None else ForwardAxis(
        heading[0], heading[1], "travel against the IMU's heading", heading[2], way_known=heading[3]
    )  # fmt: skip


def _forward_axis_from_turns(dataset) -> tuple[np.ndarray, int] | None:
    """The vehicle's forward axis in IMU axes from the turns or straight speed changes, or
    None when the drive has too few of them to tell; with the seconds used (see _turns_fit)."""
    found = _turns_fit(dataset)
    return None if found is None else (found[0], found[1])


def _turns_fit(dataset) -> tuple[np.ndarray, int, tuple[float, float] | None] | None:
    """The vehicle's forward axis in IMU axes from the turns or straight speed changes, or
    None when the drive has too few of them to tell; with the seconds used and the IMU's
    lever ahead of the non-slipping point where the turns show one (m, sigma).

    A ground vehicle turning at rate ``w`` (about up) with speed ``v`` accelerates toward the
    turn's centre, ``v w`` along its left axis; the IMU's specific force shows it in the
    horizontal plane (up: the mean accelerometer reading). Regressing the horizontal specific
    force on ``v w`` over the turning epochs gives the left axis in IMU axes, and
    forward = left x up. Independent of the configured mounting, so it can check it.
    """
    imu, gnss = dataset.imu, dataset.gnss
    if len(gnss.t) < 3 or len(imu.t) < 10:
        return None
    # On a grid finer than the fixes (a turn lasts a few epochs), where fixes are dense.
    epoch_speed = _speed(gnss.t, dataset.gnss_enu(), gnss.velocity)
    start, end = max(gnss.t[0], imu.t[0]), min(gnss.t[-1], imu.t[-1])
    if end - start < 10 * MOTION_STEP_S:
        return None
    t = np.arange(start, end, MOTION_STEP_S)
    nearest_fix = np.abs(gnss.t[np.clip(np.searchsorted(gnss.t, t), 0, len(gnss.t) - 1)] - t)
    speed = np.interp(t, gnss.t, epoch_speed)
    # Within a fix interval of slower receivers too (0.2 Hz: 5 s apart, and every turn was
    # "cannot tell"); a gap (an outage) is not interpolated across.
    speed[nearest_fix > max(MOTION_MAX_FIX_GAP_S, 0.75 * median_interval(gnss.t))] = np.nan
    lo = np.searchsorted(imu.t, t - MOTION_WINDOW_S / 2)
    hi = np.searchsorted(imu.t, t + MOTION_WINDOW_S / 2)
    count = np.maximum(hi - lo, 1)[:, None]
    summed_accel, summed_gyro = _prefix_sums(imu.accel), _prefix_sums(imu.gyro)
    accel = (summed_accel[hi] - summed_accel[lo]) / count
    gyro = (summed_gyro[hi] - summed_gyro[lo]) / count
    up = _up_axis(imu)
    with np.errstate(invalid="ignore", divide="ignore"):
        # The forward specific force: speeding up or slowing down, plus the grade's share of
        # gravity (a road climbing through a curve); regressed out below.
        along = np.gradient(speed, t) + GRAVITY_M_S2 * np.interp(
            t, gnss.t, _climb(gnss.t, dataset.gnss_enu(), gnss.velocity)
        ) / speed
    rate = gyro @ up
    moving = (hi - lo >= 3) & np.isfinite(speed) & np.isfinite(along)
    moving &= speed > MOTION_MIN_SPEED_M_S
    straight = moving & (np.abs(speed * rate) < 0.5 * CENTRIPETAL_MIN_M_S2)
    if straight.sum() >= 5:  # the gyro bias, which v turns into a false centripetal term
        rate = rate - np.median(rate[straight])
    centripetal = speed * rate
    # Real turns only: a highway's gentle curves (~1 deg/s) at speed pass the centripetal
    # bound too, and there lane changes and grades mislead the fit by 10-30 deg.
    turning = moving & (np.abs(centripetal) > CENTRIPETAL_MIN_M_S2)
    turning &= np.abs(rate) > MOTION_MIN_RATE_RAD_S
    n = int(turning.sum())
    if n * MOTION_STEP_S < MOTION_MIN_TURN_S:
        bias = np.median(gyro[straight] @ up) if straight.sum() >= 5 else 0.0
        straight_ahead = _forward_from_speed_changes(imu.t, summed_accel, summed_gyro, t, speed, up, bias)
        return None if straight_ahead is None else (*straight_ahead, None)
    motion = np.column_stack([centripetal[turning], along[turning]])
    # An IMU a lever l ahead of the non-slipping point (the rear axle) feels -l w^2 along
    # the forward axis and l dw/dt along the left one as well: regressed out where they show
    # a lever (LEVER_TERMS_SIGMAS), or a roundabout's steady turn tilts the fitted axis by
    # atan(l w / v) (2 m ahead at 8 m/s and 0.3 rad/s: 3 deg).
    lever_terms = np.column_stack([rate**2, np.gradient(rate, t)])[turning]
    forward, lever = _free_fit(accel[turning], motion, up, lever_terms)
    if forward is None and lever is not None:
        # The lever shows but the axis does not, with it: a fit without it is tilted by
        # atan(l w / v) (IMU 2 m ahead in a roundabout with fixes at 0.2 Hz: 5 deg, the batch
        # 1.85 m inside an outage, 0.65 m with the heading match instead). Cannot tell; nor
        # is such a lever taken (a 20 % climb at 0.2 Hz showed one of -1.6 +- 0.3 m).
        return None
    if forward is None:
        forward = _rigid_fit(accel[turning], motion, up)
    if forward is None:
        return None  # the turns do not show the nose well enough: cannot tell
    return forward / np.linalg.norm(forward), round(n * MOTION_STEP_S), lever


def imu_lever_from_turns(dataset) -> tuple[float, float] | None:
    """How far (m) the IMU sits ahead of the non-slipping point (the rear axle) as the
    turns show it (its -l w^2 and l dw/dt agreeing beyond LEVER_TERMS_SIGMAS and
    LEVER_TERMS_MIN_M), with its sigma; None where they do not show one."""
    found = _forward_axis(dataset)  # the mounting check's own fit, kept
    return None if found is None else found.lever


def _forward_from_speed_changes(
    imu_t: np.ndarray, summed_accel: np.ndarray, summed_gyro: np.ndarray, t: np.ndarray,
    speed: np.ndarray, up: np.ndarray, rate_bias: float,
) -> tuple[np.ndarray, int] | None:
    """The forward axis from speeding up and slowing down, for a drive with too few turns
    (a straight road). Over SPEED_CHANGE_WINDOW_S windows (a speed differenced over 1 s of
    metre-level fixes is all noise), the mean horizontal specific force less its median
    where the speed holds is regressed on the speed change, over the epochs where the speed
    clearly changes straight ahead; the coefficient is the forward axis (~unit length). The
    grade's share of gravity is left out (from metre-level heights at a few m/s it is noise
    of ~1 m/s^2): it acts along the forward axis too, so it can bias the scale, not the
    direction. None when there is too little of it, its scale is not ~1 or its direction is
    uncertain by more than MOTION_MAX_SIGMA_DEG. An IMU with x right and y forward on a
    straight drive went unchecked to "batch LM diverged", the Kalman baselines to 126 m at
    exit 0."""
    half = SPEED_CHANGE_WINDOW_S / 2
    with np.errstate(invalid="ignore", divide="ignore"):
        along = (np.interp(t + half, t, speed) - np.interp(t - half, t, speed)) / (2 * half)
    lo = np.searchsorted(imu_t, t - half)
    hi = np.searchsorted(imu_t, t + half)
    count = np.maximum(hi - lo, 1)[:, None]
    accel = (summed_accel[hi] - summed_accel[lo]) / count  # the caller's prefix sums
    centripetal = speed * (((summed_gyro[hi] - summed_gyro[lo]) / count) @ up - rate_bias)
    usable = (hi - lo >= 3) & np.isfinite(along) & np.isfinite(centripetal)
    usable &= (t - half >= t[0]) & (t + half <= t[-1])
    with np.errstate(invalid="ignore"):
        changing = usable & (speed > MOTION_MIN_SPEED_M_S) & (np.abs(along) > SPEED_CHANGE_MIN_M_S2)
        # Straight ahead only: a highway's lane changes and curves while speeding up turned
        # the fit 11-12 deg (the simulated highway, seed 4).
        changing &= np.abs(centripetal) < STRAIGHT_MAX_CENTRIPETAL_M_S2
    n = int(changing.sum())
    if n * MOTION_STEP_S < MOTION_MIN_SPEED_CHANGE_S:
        return None
    # The constant (accelerometer bias, the mounting's tilt) from where the speed holds: a
    # drive whose one speed change is its start would make it collinear with that change.
    with np.errstate(invalid="ignore"):
        steady = usable & (np.abs(along) < 0.4 * SPEED_CHANGE_MIN_M_S2)
        steady &= np.abs(centripetal) < STRAIGHT_MAX_CENTRIPETAL_M_S2
    if steady.sum() < n:
        return None
    level = accel - np.outer(accel @ up, up)
    horizontal = level[changing] - np.median(level[steady], axis=0)
    design = along[changing][:, None]
    coefficients, *_ = np.linalg.lstsq(design, horizontal, rcond=None)
    forward = coefficients[0]
    scale = float(np.linalg.norm(forward))
    if not MOTION_SCALE_RANGE[0] <= scale <= MOTION_SCALE_RANGE[1]:
        return None
    try:
        unscaled = float(np.linalg.inv(design.T @ design)[0, 0])
    except np.linalg.LinAlgError:
        return None
    variance = _residual_variance(horizontal - design @ coefficients, design.shape[1])
    variance *= SPEED_CHANGE_WINDOW_S / MOTION_WINDOW_S  # longer windows: fewer independent
    if not np.degrees(np.sqrt(max(variance * unscaled, 0.0)) / scale) <= MOTION_MAX_SIGMA_DEG:
        return None
    forward = forward - (forward @ up) * up
    return forward / np.linalg.norm(forward), round(n * MOTION_STEP_S)


# The IMU's lever terms (-l w^2 forward, l dw/dt left; see _forward_axis_from_turns) are
# kept in the turns' fit only where the lever they show is this many of its sigmas and
# metres from zero: two more regressors cost precision, and KITTI (0.27 m) moved 0.13 deg
# with them, enough to replace its configured mounting and lose 38 % in its 60 s outages.
LEVER_TERMS_SIGMAS = 3.0
LEVER_TERMS_MIN_M = 0.5


def _free_fit(
    accel: np.ndarray, motion: np.ndarray, up: np.ndarray, lever_terms: np.ndarray | None = None
) -> tuple[np.ndarray | None, tuple[float, float] | None]:
    """Forward axis from a free regression of the horizontal specific force on v w (the
    left axis), the forward acceleration (braking into a turn, or a grade through it,
    correlates it with v w), the IMU's ``lever_terms`` (w^2, dw/dt) where they show a
    significant lever, and a constant; None when the left axis's scale is not ~1 or its
    direction is uncertain by more than MOTION_MAX_SIGMA_DEG. With it, the lever (m, the IMU
    ahead of the non-slipping point) and its sigma where it was regressed out."""
    horizontal = accel - np.outer(accel @ up, up)
    if lever_terms is not None:
        fit = _regression(horizontal, np.column_stack([motion, lever_terms]))
        if fit is not None:
            coefficients, covariance_scale, variance = fit
            left = coefficients[0] / np.linalg.norm(coefficients[0])
            forward = np.cross(left, up)
            # Both terms show the lever: -l along forward per w^2, l along left per dw/dt.
            # They must agree, and together put it clear of zero (a hilly drive's grades
            # made the w^2 term alone -38 +- 7 m).
            estimates = np.array([-float(coefficients[2] @ forward), float(coefficients[3] @ left)])
            sigmas = np.sqrt(np.maximum(variance * np.diag(covariance_scale)[2:4], 1e-12))
            weights = 1.0 / sigmas**2
            lever = float(np.sum(weights * estimates) / np.sum(weights))
            sigma = float(1.0 / np.sqrt(np.sum(weights)))
            agree = abs(estimates[0] - estimates[1]) <= LEVER_TERMS_SIGMAS * float(np.hypot(*sigmas))
            if agree and abs(lever) > max(LEVER_TERMS_SIGMAS * sigma, LEVER_TERMS_MIN_M):
                # The lever even where the axis is too uncertain with it: a fit without
                # the lever would be tilted by it (see _turns_fit).
                forward = _checked_left(coefficients[0], covariance_scale[0, 0], variance, up)
                return forward, (lever, sigma)
    fit = _regression(horizontal, motion)
    if fit is None:
        return None, None
    coefficients, covariance_scale, variance = fit
    return _checked_left(coefficients[0], covariance_scale[0, 0], variance, up), None


def _regression(horizontal: np.ndarray, columns: np.ndarray) -> tuple[np.ndarray, np.ndarray, float] | None:
    """Least squares of ``horizontal`` on ``columns`` and a constant: (coefficients,
    (X^T X)^-1, per-axis residual variance); None when singular."""
    design = np.column_stack([columns, np.ones(len(columns))])
    coefficients, *_ = np.linalg.lstsq(design, horizontal, rcond=None)
    try:
        covariance_scale = np.linalg.inv(design.T @ design)
    except np.linalg.LinAlgError:
        return None
    return coefficients, covariance_scale, _residual_variance(horizontal - design @ coefficients, design.shape[1])


def _checked_left(left: np.ndarray, unscaled: float, variance: float, up: np.ndarray) -> np.ndarray | None:
    """The forward axis from the fitted left axis (specific force per unit of v w, IMU axes,
    ~unit length); None when its scale is not ~1 or its direction is uncertain by more than
    MOTION_MAX_SIGMA_DEG."""
    scale = float(np.linalg.norm(left))
    if not MOTION_SCALE_RANGE[0] <= scale <= MOTION_SCALE_RANGE[1]:
        return None
    if not np.degrees(np.sqrt(max(variance * unscaled, 0.0)) / scale) <= MOTION_MAX_SIGMA_DEG:
        return None
    forward = np.cross(left / scale, up)
    return forward / np.linalg.norm(forward)


def _rigid_fit(accel: np.ndarray, motion: np.ndarray, up: np.ndarray) -> np.ndarray | None:
    """Forward axis as one angle: in the horizontal plane (basis e1, e2, e1 x e2 = up) a
    nose at angle a has forward (cos a, sin a) and left (-sin a, cos a), so the specific
    force is the rotation R(a) of (forward acceleration, v w) times ~1, plus a constant (a
    2-D Procrustes fit). Used when the free fit cannot tell: on a highway whose only turns
    are an accelerating on-ramp and one curve, v w, the forward acceleration and the
    constant are nearly collinear (the free fit put the nose 15 deg off); one angle is
    still determined. None when the scale is not ~1 or the angle uncertain."""
    e1 = np.cross(up, [1.0, 0.0, 0.0] if abs(up[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    measured = accel @ np.column_stack([e1, e2])
    measured -= measured.mean(axis=0)
    planar = motion[:, ::-1] - motion[:, ::-1].mean(axis=0)  # (forward acceleration, v w)
    cross = float(np.sum(planar[:, 0] * measured[:, 1] - planar[:, 1] * measured[:, 0]))
    angle = float(np.arctan2(cross, float(np.sum(planar * measured))))
    c, s = np.cos(angle), np.sin(angle)
    rotated = planar @ np.array([[c, s], [-s, c]])  # rows: R(angle) @ planar[i]
    spread = float(np.sum(planar**2))
    scale = float(np.sum(rotated * measured)) / spread if spread > 0 else 0.0
    if not MOTION_SCALE_RANGE[0] <= scale <= MOTION_SCALE_RANGE[1]:
        return None
    variance = _residual_variance(measured - scale * rotated, 4)
    if not np.degrees(np.sqrt(variance / (spread * scale**2))) <= MOTION_MAX_SIGMA_DEG:
        return None
    return c * e1 + s * e2


# Without turns or speed changes strong enough to fit (a crawl, a parking garage, gentle
# curves), the IMU's heading still follows from matching its horizontal specific force,
# carried into one frame by the gyro, to the fixes' acceleration in the navigation frame
# (an in-motion coarse alignment; no track direction, so reversing and slip do not enter),
# and the forward axis is then the direction of travel in IMU axes. An independent
# simulator's car with its IMU turned 90 deg and no mounting given ran to 17-40 m inside a
# 40 s outage (NEES 485-4663) at 2-7 m/s, the turns' fit "cannot tell".
HEADING_BOX_S = 2.0  # accelerations: means over +-this (velocities), second differences over +-2x (fixes)
HEADING_MIN_SPEED_M_S = 1.0  # the direction of travel taken above this
# The heading match answers up to this standard error. What it overturns scales with it
# (HEADING_WARN_SIGMAS, HEADING_ERROR_SIGMAS), so a coarse answer only overturns a mounting
# that is grossly off: a 0.5 m/s crawl's fixes (1 m noise, 0.5 m apart) give +-16 deg, which
# tells the 90 and 180 deg turns people mix up (beyond 3 sigma, 47 deg) from the default. An
# independent simulator's crawl with the IMU mounted backward and no mounting given ran to
# 2.8 m inside a 40 s outage (NEES 46, not a word on the mounting) where the heading match,
# then capped at 6 deg, saw it 154 +- 16 deg off the default.
HEADING_MAX_SIGMA_DEG = 20.0
HEADING_MIN_WINDOWS = 30
# A configured mounting the heading match puts off by more than these many of its standard
# errors (and MOUNTING_WARN_DEG / MOUNTING_ERROR_DEG) is said / refused.
HEADING_WARN_SIGMAS = 3.0
HEADING_HALVES_SIGMAS = 3.0
HEADING_ERROR_SIGMAS = 5.0


def forward_axis_from_heading(dataset) -> tuple[np.ndarray, int, float, bool] | None:
    """The vehicle's forward axis in IMU axes from the IMU's heading (see HEADING_BOX_S),
    the seconds of travel it is taken over, the heading's standard error (deg) and whether
    the data tell which way along that axis is forward (:data:`WAY_DECISIVE_SHARE`); None when
    the drive's accelerations do not fix the heading to HEADING_MAX_SIGMA_DEG. Accelerations
    are taken over windows of 1, 2 and 4 times HEADING_BOX_S, the one that fixes the heading
    best kept: metre-level fixes' second differences need long windows, sharp turns short."""
    found = [_forward_from_heading(dataset, HEADING_BOX_S * scale) for scale in (1.0, 2.0, 4.0)]
    found = [item for item in found if item is not None]
    if not found:
        return None
    best = min(found, key=lambda item: item[2])
    return best if best[2] <= HEADING_MAX_SIGMA_DEG else None


def _forward_from_heading(dataset, box_s: float) -> tuple[np.ndarray, int, float, bool] | None:
    imu, gnss = dataset.imu, dataset.gnss
    t, enu = gnss.t, dataset.gnss_enu()
    if len(t) < HEADING_MIN_WINDOWS or len(imu.t) < 10:
        return None
    velocity = None
    if gnss.velocity is not None and np.mean(np.isfinite(gnss.velocity[:, 0])) > 0.8:
        known = np.isfinite(gnss.velocity[:, 0]) & np.isfinite(gnss.velocity[:, 1])
        velocity = (t[known], gnss.velocity[known, 0] + 1j * gnss.velocity[known, 1])
    half = box_s if velocity is not None else 2.0 * box_s
    grid = np.arange(max(t[0], imu.t[0]) + 2 * half, min(t[-1], imu.t[-1]) - 2 * half, 1.0)
    if grid.size < HEADING_MIN_WINDOWS:
        return None
    ends = np.clip(np.searchsorted(t, grid + np.array([[-half], [0.0], [half]])), 1, len(t) - 1)
    dense = np.max(t[ends] - t[ends - 1], axis=0) <= half
    position = enu[:, 0] + 1j * enu[:, 1]
    if velocity is not None:
        fixes = (complex_at(grid + half, *velocity) - complex_at(grid - half, *velocity)) / (2 * half)
    else:
        fixes = (complex_at(grid + half, t, position) - 2 * complex_at(grid, t, position)
                 + complex_at(grid - half, t, position)) / half**2  # fmt: skip
    # A grade leans the IMU's horizontal plane (normal to the mean specific force) and
    # gravity's share g sin(grade) acts along the direction of travel, either way of
    # driving: fitted with it (its coefficient ~g).
    epoch_speed = _speed(t, enu, gnss.velocity)
    with np.errstate(invalid="ignore", divide="ignore"):
        slope = np.where(epoch_speed > HEADING_MIN_SPEED_M_S, _climb(t, enu, gnss.velocity) / epoch_speed, 0.0)
    position_rate = np.gradient(position, t)
    travel_direction = position_rate / np.maximum(np.abs(position_rate), 1e-9)
    grade_lean = complex_at(grid, t, np.nan_to_num(slope) * travel_direction)
    up = _up_axis(imu)
    first, second = horizontal_axes(up)
    force = imu.accel @ first + 1j * (imu.accel @ second)
    measured_yaw = yaw_about(imu, up)
    middle = 0.5 * (imu.t[0] + imu.t[-1])
    use, drift, fit = dense.copy(), 0.0, None
    for _ in range(4):  # the gyro's bias about up turns the carried frame: fitted, removed
        yaw = measured_yaw - drift * (imu.t - middle)
        carried = window_means(imu.t, force * np.exp(1j * yaw), grid, half, velocity is not None)
        bias_turn = window_means(imu.t, np.exp(1j * yaw), grid, half, velocity is not None)
        # The fixes' acceleration (the noisy side: metre-level fixes' second differences)
        # regressed on the IMU's: fixes = W carried, W = e^{i heading} at the middle time,
        # turning with the gyro's bias (the second column) and less the accelerometer's
        # bias turned with the IMU (the third).
        design = np.column_stack([carried, (grid - middle) * carried, bias_turn, grade_lean])
        fit = _complex_fit(design, fixes, use)
        if fit is None:
            return None
        coefficients, residual = fit
        misfit = np.abs(residual)
        use = dense & (misfit <= 3.0 * np.median(misfit[use]) + 0.05)
        drift -= float(np.imag(coefficients[1] / coefficients[0]))
    heading = _heading_fit(design, fixes, use, half)
    if heading is None:
        return None
    w, sigma_deg = heading
    # Each half of the drive on its own must agree with the other within their errors: a
    # drive with too little acceleration (a short motorway stretch) fitted the model's
    # leftovers instead, 10 deg off at a standard error of 3.
    middle_window = np.median(grid[use])
    halves = [_heading_fit(design, fixes, use & part, half) for part in (grid < middle_window, grid >= middle_window)]
    if any(item is None for item in halves):
        return None
    (first_w, first_sigma), (second_w, second_sigma) = halves
    apart = abs(float(np.degrees(np.angle(first_w / second_w))))
    if apart > HEADING_HALVES_SIGMAS * float(np.hypot(first_sigma, second_sigma)):
        return None
    # The travel direction in IMU axes at each fix: e^{-i heading} v, heading = arg W + yaw.
    travel = velocity[1] if velocity is not None else position_rate
    travel_t = velocity[0] if velocity is not None else t
    speed = np.abs(travel)
    moving = speed > HEADING_MIN_SPEED_M_S
    if moving.sum() < HEADING_MIN_WINDOWS:
        return None
    heading = np.angle(w) + np.interp(travel_t[moving], imu.t, yaw)
    along = travel[moving] / speed[moving] * np.exp(-1j * heading)
    # One axis, either way along it (reversing): the doubled angles' mean, then its median
    # refinement; the way it points is the one most of the distance goes, where most does
    # (WAY_DECISIVE_SHARE), or the one a signed wheel speed reads positive.
    axis = np.angle(np.sum(speed[moving] * along**2)) / 2.0
    axis += float(np.median(np.angle(along**2 * np.exp(-2j * axis)))) / 2.0
    way = np.sign(np.real(along * np.exp(-1j * axis)))
    ahead = float(np.sum(speed[moving] * (way > 0))) / max(float(np.sum(speed[moving])), 1e-12)
    if ahead < 0.5:
        axis, way, ahead = axis + np.pi, -way, 1.0 - ahead
    way_known = ahead >= WAY_DECISIVE_SHARE
    wheel = _wheel_way(dataset, travel_t[moving], way, speed[moving])
    if wheel is not None:
        way_known = True
        if wheel < 0:
            axis += np.pi
    forward = np.cos(axis) * first + np.sin(axis) * second
    seconds = round(float(np.sum(moving)) * float(np.median(np.diff(travel_t))))
    return forward / np.linalg.norm(forward), seconds, sigma_deg, way_known


# The forward way along the fitted axis is the one this share of the distance goes; below
# it (a car reversing 182 s of a 267 s drive, out of bays and round bends: the right
# mounting was refused as "+179 deg" off, and without one the car was turned round and its
# right wheel read as -202 %; outside tester) the data cannot tell, and the configured
# mounting's way stands.
WAY_DECISIVE_SHARE = 0.8
WHEEL_WAY_SHARE = 0.8  # of the distance where the wheel's sign agrees with one way


def _wheel_way(dataset, t: np.ndarray, way: np.ndarray, speed: np.ndarray) -> int | None:
    """+1 where a signed wheel speed (some of it negative: reversing) is positive along
    ``way`` (+-1 at times ``t``) over WHEEL_WAY_SHARE of the distance, -1 where against it,
    None where there is no such wheel or it does not tell."""
    odometer = getattr(dataset, "odometer", None)
    if odometer is None or len(odometer.t) < 2 or not np.any(odometer.speed < 0):
        return None
    inside = (t >= odometer.t[0]) & (t <= odometer.t[-1])
    if inside.sum() < HEADING_MIN_WINDOWS:
        return None
    wheel = np.sign(np.interp(t[inside], odometer.t, odometer.speed))
    agree = float(np.sum(speed[inside] * (wheel == way[inside]))) / max(float(np.sum(speed[inside])), 1e-12)
    if agree >= WHEEL_WAY_SHARE:
        return 1
    return -1 if agree <= 1.0 - WHEEL_WAY_SHARE else None


def _heading_fit(design: np.ndarray, fixes: np.ndarray, use: np.ndarray, half: float) -> tuple[complex, float] | None:
    """W (the first column's coefficient: e^{i heading}) and its angle's standard error
    (deg) over the windows ``use``; None when too few, or its scale is not ~1."""
    fit = _complex_fit(design, fixes, use)
    if fit is None:
        return None
    coefficients, residual = fit
    w = complex(coefficients[0])
    if not MOTION_SCALE_RANGE[0] <= abs(w) <= MOTION_SCALE_RANGE[1]:
        return None
    used = design[use]
    dof = max(int(use.sum()) - used.shape[1], 1)
    noise = float(np.sum(np.abs(residual[use]) ** 2)) / dof * (2 * half)  # overlapping windows
    try:
        spread = float(np.real(np.linalg.inv(used.conj().T @ used)[0, 0]))
    except np.linalg.LinAlgError:
        return None
    sigma_deg = float(np.degrees(np.sqrt(max(noise * spread / 2.0, 0.0)) / abs(w)))
    return (w, sigma_deg) if np.isfinite(sigma_deg) else None


def _complex_fit(design: np.ndarray, target: np.ndarray, use: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """Complex least squares over the rows ``use``: (coefficients, residual at every row)."""
    if use.sum() < HEADING_MIN_WINDOWS:
        return None
    coefficients, *_ = np.linalg.lstsq(design[use], target[use], rcond=None)
    if not np.all(np.isfinite(coefficients)) or abs(coefficients[0]) == 0.0:
        return None
    return coefficients, target - design @ coefficients


def _residual_variance(residual: np.ndarray, parameters: int) -> float:
    """Per-axis residual variance, counted once per averaging window (grid points inside
    one window share their IMU samples, so they are not independent)."""
    n, axes = residual.shape
    if n <= parameters:
        return np.inf
    dof = axes * n - parameters * axes
    return float(np.sum(residual**2)) / dof * (MOTION_WINDOW_S / MOTION_STEP_S)


def _up_axis(imu, accel_bias: np.ndarray | None = None) -> np.ndarray:
    """Up in IMU axes: the mean accelerometer reading (gravity's reaction; roads are level
    on average), less ``accel_bias`` where given."""
    up = np.mean(imu.accel, axis=0)
    if accel_bias is not None:
        up = up - np.asarray(accel_bias, dtype=float)
    return up / np.linalg.norm(up)


def _gravity_axis(dataset, forward: np.ndarray, accel_bias: np.ndarray | None = None) -> np.ndarray:
    """Up in IMU axes from gravity alone: the mean accelerometer reading less the vehicle's
    own acceleration (centripetal ``w x v`` and along-track ``dv/dt``, with the velocity
    ``speed * forward``; ``forward`` in IMU axes). A drive that turns mostly one way leans
    the plain mean: the last 100 s of the KITTI drive read 3.3-3.6 deg of roll, 1.8 deg
    without its turns' centripetal acceleration (its crossfall). ``accel_bias`` (IMU axes, a
    solution's) is taken off the readings first."""
    imu, gnss = dataset.imu, dataset.gnss
    speed = _speed(gnss.t, dataset.gnss_enu(), gnss.velocity)
    known = np.isfinite(speed)
    if known.sum() < 2:
        return _up_axis(imu, accel_bias)
    t, speed = gnss.t[known], speed[known]
    speed_at = np.interp(imu.t, t, speed)
    change_at = np.interp(imu.t, t, np.gradient(speed, t))
    motion = np.cross(imu.gyro, np.outer(speed_at, forward)) + np.outer(change_at, forward)
    up = np.mean(imu.accel - motion, axis=0)
    if accel_bias is not None:
        up = up - np.asarray(accel_bias, dtype=float)
    return up / np.linalg.norm(up)


def _prefix_sums(samples: np.ndarray) -> np.ndarray:
    return np.vstack([np.zeros(samples.shape[1]), np.cumsum(samples, axis=0)])


def _speed(t: np.ndarray, enu: np.ndarray, velocity: np.ndarray | None) -> np.ndarray:
    """Horizontal speed at each epoch: the receiver's velocity, else a position chord."""
    if velocity is not None and np.mean(np.isfinite(velocity[:, 0])) > 0.5:
        return np.hypot(velocity[:, 0], velocity[:, 1])
    chord = _chord_s(t, CHORD_S)
    a = np.searchsorted(t, t - chord / 2)
    b = np.clip(np.searchsorted(t, t + chord / 2, side="right") - 1, 0, len(t) - 1)
    span = t[b] - t[a]
    with np.errstate(invalid="ignore", divide="ignore"):
        speed = np.hypot(*(enu[b, :2] - enu[a, :2]).T) / span
    return np.where(span > 0.5 * chord, speed, np.nan)


def _chord_s(t: np.ndarray, nominal_s: float) -> float:
    """A chord of ``nominal_s``, or of two fix intervals where the fixes are sparser (at
    0.2 Hz a 4 s chord held no other fix: no speed anywhere, every turn "cannot tell")."""
    return max(nominal_s, 2.0 * median_interval(t) + 1e-6)


def _climb(t: np.ndarray, enu: np.ndarray, velocity: np.ndarray | None) -> np.ndarray:
    """Vertical speed at each epoch: the receiver's, else a height chord (noisy, but without
    it a hilly road's grade, correlated with the turns on a short drive, turned the fitted
    forward axis by 34 deg: a false mounting error on valid data)."""
    if velocity is not None and np.mean(np.isfinite(velocity[:, 2])) > 0.5:
        return np.nan_to_num(velocity[:, 2])
    chord = _chord_s(t, CLIMB_CHORD_S)
    a = np.searchsorted(t, t - chord / 2)
    b = np.clip(np.searchsorted(t, t + chord / 2, side="right") - 1, 0, len(t) - 1)
    span = t[b] - t[a]
    with np.errstate(invalid="ignore", divide="ignore"):
        climb = (enu[b, 2] - enu[a, 2]) / span
    return np.where(span > 0.5 * chord, climb, 0.0)


def mounting_yaw_error_deg(dataset, rpy_deg) -> tuple[float, int] | None:
    """Angle (deg, about up) from the configured mounting's forward axis to the one the
    motion shows (:func:`forward_axis_from_motion`), with the seconds of turning used; None
    when the drive cannot tell."""
    found = forward_axis_from_motion(dataset)
    if found is None:
        return None
    angle = _yaw_error_deg(found[0], _gravity_axis(dataset, found[0]), rpy_deg)
    return None if angle is None else (angle, found[1])


def _yaw_error_deg(forward: np.ndarray, up: np.ndarray, rpy_deg) -> float | None:
    configured = mounting_rotation(rpy_deg)[0]
    configured = configured - (configured @ up) * up
    if np.linalg.norm(configured) < 0.1:  # forward configured along up: no yaw to compare
        return None
    configured = configured / np.linalg.norm(configured)
    return float(np.degrees(np.arctan2(np.cross(configured, forward) @ up, configured @ forward)))


# A configured mounting whose forward axis lies this far (about up) from the one the motion
# shows: beyond MOUNTING_ERROR_DEG the vehicle constraints would fight the data (an error);
# beyond MOUNTING_WARN_DEG they would bend it (a warning). The estimate is good to ~0.1-0.5 deg.
# At 15 m/s a 1 deg error is 0.26 m/s of lateral velocity the NHC (0.2 m/s) calls zero: an
# outside tester's IMU mounted 15 deg off (then a warning) ran at exit 0 to 6.2 m inside
# outages where the right mounting gives 0.25 m. The fit is accepted with a standard error
# up to MOTION_MAX_SIGMA_DEG (2 deg), so the error line sits at 5 of those.
MOUNTING_WARN_DEG = 5.0
MOUNTING_ERROR_DEG = 10.0
# The vehicle's up axis against gravity's mean direction (roads are level on average; a
# camber of 1-2 % leans a right-hand-traffic car ~1 deg): the roll and pitch of the mounting
# (an outside tester's [5, -3, 45] given as [0, 0, 45]: +45 % inside outages, not a word).
TILT_WARN_DEG = 3.0
# A configured forward axis this far above or below the horizontal is no road's grade (a
# drive's mean grade is a few degrees at most): the IMU is on its side or on end. Its yaw
# check cannot run (no horizontal forward to compare), and an outside tester's IMU with x up
# and y forward ran to "batch LM diverged" with a generic hint.
FORWARD_ELEVATION_ERROR_DEG = 30.0
FORWARD_TILT_SEEN_DEG = 1.0  # a forward axis tilted less is a roll-only difference
MAX_MEAN_GRADE_DEG = 1.5  # a drive mostly uphill or downhill leans the mean: cannot tell


def fitted_mounting_rpy_deg(dataset) -> np.ndarray | None:
    """The mounting (deg, ZYX) the data show: forward from the turns
    (:func:`forward_axis_from_motion`), up from gravity (roads are level on average;
    :func:`_gravity_axis`)."""
    found = forward_axis_from_motion(dataset)
    return None if found is None else _mounting_rpy_deg(found[0], _gravity_axis(dataset, found[0]))


def _mounting_rpy_deg(forward: np.ndarray, up: np.ndarray) -> np.ndarray:
    forward = forward - (forward @ up) * up
    forward = forward / np.linalg.norm(forward)
    r_vi = np.vstack([forward, np.cross(up, forward), up])  # rows: vehicle axes in IMU axes
    pitch = -np.arcsin(np.clip(r_vi[2, 0], -1.0, 1.0))
    if abs(r_vi[2, 0]) > np.cos(np.radians(0.5)):  # pitch ~+-90: roll and yaw act as one
        return np.degrees([np.arctan2(-r_vi[2, 0] * r_vi[0, 1], r_vi[1, 1]), pitch, 0.0])
    yaw = np.arctan2(r_vi[1, 0], r_vi[0, 0])
    roll = np.arctan2(r_vi[2, 1], r_vi[2, 2])
    return np.degrees([roll, pitch, yaw])


def check_mounting(dataset, rpy_deg) -> str | None:
    """Compare the configured mounting with the motion (ground vehicles: the turns'
    centripetal acceleration). Raises InputError when the forward axes are more than
    MOUNTING_ERROR_DEG apart; returns a warning line when more than MOUNTING_WARN_DEG; None
    when they agree or the drive cannot tell."""
    found = _forward_axis(dataset)
    if found is None:
        return None
    forward = found.facing(rpy_deg)
    up = _gravity_axis(dataset, forward)
    _check_forward_level(rpy_deg, forward, up)
    angle = _yaw_error_deg(forward, up, rpy_deg)
    if angle is None:
        return None
    warn_deg, error_deg = MOUNTING_WARN_DEG, MOUNTING_ERROR_DEG
    if found.sigma_deg is not None:  # the heading match: its own standard error
        warn_deg = max(warn_deg, HEADING_WARN_SIGMAS * found.sigma_deg)
        error_deg = max(error_deg, HEADING_ERROR_SIGMAS * found.sigma_deg)
    if abs(angle) <= warn_deg:
        return _tilt_note(dataset, rpy_deg, forward, up)
    message = (
        f"imu: the vehicle's forward axis, from {_evidence(found)}, lies {angle:+.0f} deg about "
        f"up from the configured mounting's (imu_to_vehicle_rpy_deg = {_angles(rpy_deg, 2)}); a "
        f"mounting that fits the data: imu_to_vehicle_rpy_deg = "
        f"{_angles(_mounting_rpy_deg(forward, up), 0)}"
    )
    if abs(angle) > error_deg:
        raise InputError(message + "; the car constraints would fight the data")
    return message


def _evidence(found: ForwardAxis) -> str:
    """What shows the forward axis, for a message."""
    if found.sigma_deg is None:
        return f"the horizontal specific force over {found.seconds} s of turns or speed changes"
    return (
        f"the direction of travel over {found.seconds} s against the IMU's heading (its "
        f"specific force matched to the fixes' acceleration, +-{found.sigma_deg:.1f} deg)"
    )


def _check_forward_level(rpy_deg, forward: np.ndarray, up: np.ndarray) -> None:
    """Raise InputError when the configured forward axis points more than
    FORWARD_ELEVATION_ERROR_DEG above or below the horizontal (gravity's mean direction):
    an IMU mounted on its side or nose up, whose forward axis has no yaw to compare."""
    configured = mounting_rotation(rpy_deg)[0]
    elevation = float(np.degrees(np.arcsin(np.clip(configured @ up, -1.0, 1.0))))
    if abs(elevation) <= FORWARD_ELEVATION_ERROR_DEG:
        return
    raise InputError(
        f"imu: the configured mounting's forward axis (imu_to_vehicle_rpy_deg = "
        f"{_angles(rpy_deg, 2)}) points {abs(elevation):.0f} deg "
        f"{'above' if elevation > 0 else 'below'} the horizontal (gravity's mean direction "
        "over the drive): the IMU sits on its side or on end in the vehicle; a mounting that "
        f"fits the data: imu_to_vehicle_rpy_deg = {_angles(_mounting_rpy_deg(forward, up), 0)} "
        "(forward from the turns or speed changes, up from gravity); the car "
        "constraints would fight the data"
    )


@dataclass(frozen=True)
class AdoptedMounting:
    """A mounting the data show (:func:`adopted_mounting`): its angles (deg, ZYX), what
    shows it (words for a warning) and, from the heading match, its forward axis's standard
    error about up (deg; None for the turns' fit, good to ~0.1-1 deg)."""

    rpy_deg: np.ndarray
    evidence: str
    sigma_deg: float | None = None


def adopted_mounting(
    dataset, rpy_deg, refine_beyond_deg: float = MOUNTING_WARN_DEG
) -> AdoptedMounting | None:
    """For a car whose mounting nobody gave (``rpy_deg`` the default): the mounting the data
    show, with what shows it, when :func:`check_mounting` finds the
    default wrong or the turns put its forward axis more than ``refine_beyond_deg`` off
    about up; None when it agrees or the drive cannot tell. The forward axis comes from the
    turns where its yaw (or the whole axis) is off by more than that, else it is the
    default's own (the turns' fit is good to ~0.1-1 deg, no better than a right default);
    the up axis from gravity's mean direction over the drive, pitched by the drive's mean
    grade (a drive mostly uphill leans gravity backward in the vehicle)."""
    found = _forward_axis(dataset)
    if found is None:
        return None
    forward = found.facing(rpy_deg)
    up = _gravity_axis(dataset, forward)
    try:
        finding = check_mounting(dataset, rpy_deg)
    except InputError as error:
        finding = str(error)
    configured = mounting_rotation(rpy_deg)[0]
    yaw_error = _yaw_error_deg(forward, up, rpy_deg)
    if found.sigma_deg is not None:
        refine_beyond_deg = max(refine_beyond_deg, HEADING_WARN_SIGMAS * found.sigma_deg)
    yaw_agrees = yaw_error is not None and abs(yaw_error) <= refine_beyond_deg
    if finding is None and yaw_agrees:
        return None
    if yaw_agrees:
        forward = configured  # the finding is the roll or pitch
    forward = forward - (forward @ up) * up
    forward = forward / np.linalg.norm(forward)
    grade = np.radians(_mean_grade_deg(dataset) or 0.0)
    vehicle_forward = np.cos(grade) * forward - np.sin(grade) * up
    vehicle_up = np.cos(grade) * up + np.sin(grade) * forward
    rpy = _mounting_rpy_deg(vehicle_forward, vehicle_up)
    sigma = None if yaw_agrees else found.sigma_deg  # the roll and pitch come from gravity
    return AdoptedMounting(rpy, f"{_evidence(found)} and gravity show {_angles(rpy, 1)}", sigma)


def turned_by_misalignment(rpy_deg, lateral_rad: float, vertical_rad: float) -> tuple[np.ndarray, float]:
    """The mounting whose forward axis is ``rpy_deg``'s turned by an NHC misalignment (the
    vehicle's velocity has ``lateral`` and ``vertical`` parts per unit of forward speed in
    the vehicle axes ``rpy_deg`` sets: the true forward axis is f + lateral l + vertical u),
    and the angle (deg) between the two forward axes. The up axis stays as near the old one
    as the new forward axis allows."""
    r_vi = mounting_rotation(rpy_deg)
    forward = r_vi[0] + lateral_rad * r_vi[1] + vertical_rad * r_vi[2]
    forward = forward / np.linalg.norm(forward)
    up = r_vi[2] - (r_vi[2] @ forward) * forward
    angle = float(np.degrees(np.arccos(np.clip(forward @ r_vi[0], -1.0, 1.0))))
    return _mounting_rpy_deg(forward, up / np.linalg.norm(up)), angle


def _mean_grade_deg(dataset) -> float | None:
    """The drive's mean grade (deg, uphill positive) over the epochs it moves, from the
    fixes; None with fewer than 10 such epochs."""
    gnss = dataset.gnss
    speed = _speed(gnss.t, dataset.gnss_enu(), gnss.velocity)
    climb = _climb(gnss.t, dataset.gnss_enu(), gnss.velocity)
    moving = np.isfinite(speed) & np.isfinite(climb) & (speed > MOTION_MIN_SPEED_M_S)
    if moving.sum() < 10:
        return None
    return float(np.degrees(np.arctan(np.mean(climb[moving] / speed[moving]))))


def default_axes_note(dataset, rpy_deg) -> str | None:
    """For a mounting nobody gave whose forward axis holds: the up-axis note where the IMU's
    up lies more than CONVENTION_TILT_DEG from the default's (an FRD IMU: 180 deg; one on
    its side: 90), another axis convention rather than a road's bank (a highway's curves
    lean gravity's mean direction by a few degrees)."""
    found = _forward_axis(dataset)
    if found is None:
        return None
    up = _gravity_axis(dataset, found.forward)
    return _tilt_note(dataset, rpy_deg, found.forward, up, CONVENTION_TILT_DEG)


CONVENTION_TILT_DEG = 30.0


TILT_NOTE_START = "imu: the vehicle's up axis, from gravity's mean direction"


def tilt_note_without_bias(dataset, rpy_deg, accel_bias: np.ndarray) -> str | None:
    """The tilt warning (:func:`_tilt_note`) again with a solution's accelerometer bias (IMU
    axes) taken off the readings: a bias of 90-100 mg leans their mean by 5-7 deg, which had
    been said as the mounting's roll or pitch, with a wrong mounting to set (outside tester;
    the same run solved the bias to 0.1 mg)."""
    found = _forward_axis(dataset)
    if found is None:
        return None
    forward = found.facing(rpy_deg)
    return _tilt_note(dataset, rpy_deg, forward, _gravity_axis(dataset, forward, accel_bias))


def _tilt_note(
    dataset, rpy_deg, forward: np.ndarray, up: np.ndarray, warn_deg: float = TILT_WARN_DEG
) -> str | None:
    """A warning when the configured mounting's up axis lies more than ``warn_deg`` from
    gravity's mean direction in IMU axes, on a drive whose mean grade is near zero."""
    mean_grade = _mean_grade_deg(dataset)
    if mean_grade is None or abs(mean_grade) > MAX_MEAN_GRADE_DEG:
        return None
    configured = mounting_rotation(rpy_deg)
    tilt = float(np.degrees(np.arccos(np.clip(configured[2] @ up, -1.0, 1.0))))
    if tilt <= warn_deg:
        return None
    # The constraints zero the lateral and vertical velocity alike: a mounting off in roll
    # alone (an FRD IMU given no mounting: 180 deg) leaves them as they are, to the bit.
    forward_tilt = float(np.degrees(np.arcsin(np.clip(abs(configured[0] @ up), 0.0, 1.0))))
    effect = (
        "its roll or pitch is off, and the car constraints bend the fit toward it"
        if forward_tilt > FORWARD_TILT_SEEN_DEG
        else "its roll is off (the car constraints do not see a roll; only their lever arm, "
        "nhc_lever_arm_m, does)"
    )
    return (
        f"{TILT_NOTE_START} over the drive (mean grade "
        f"{mean_grade:+.1f} deg), lies {tilt:.1f} deg from the configured mounting's "
        f"(imu_to_vehicle_rpy_deg = {_angles(rpy_deg, 2)}): {effect}; a mounting that fits "
        f"the data: imu_to_vehicle_rpy_deg = {_angles(_mounting_rpy_deg(forward, up), 1)}"
    )


def _angles(rpy_deg, digits: int) -> str:
    rounded = np.round(np.asarray(rpy_deg, dtype=float), digits) + 0.0  # no "-0"
    return "[" + ", ".join(f"{value:g}" for value in rounded) + "]"


def nhc_point_velocity(imu, times: np.ndarray, imu_to_vehicle: np.ndarray, lever_vehicle_m) -> np.ndarray:
    """Lateral and vertical velocity (K, 2), vehicle axes, of the non-holonomic point
    (``[smoother] nhc_lever_arm_m``, vehicle axes) relative to the IMU at each time:
    ``S (w x r)`` with ``r`` the point's position from the IMU in IMU axes and ``w`` the
    mean gyro over +-0.05 s (its bias, ~1e-4 rad/s, is negligible against yaw rates times a
    lever). The factor graph and the Kalman baselines add it to the IMU's own."""
    from fgins.factors.stationary import mean_gyro

    lever = np.asarray(lever_vehicle_m, dtype=float)
    if not np.any(lever):
        return np.zeros((len(times), 2))
    gyro, _ = mean_gyro(imu, times, before_s=0.05, after_s=0.05)
    rotation = np.asarray(imu_to_vehicle, dtype=float)
    return np.cross(np.nan_to_num(gyro), rotation.T @ lever) @ rotation[1:3].T
