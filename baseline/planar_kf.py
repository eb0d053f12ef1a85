"""The 5-state planar Kalman filter of the low-cost UAV/car study (numpy only, "planar-kf").

State ``(east, north, up, speed, yaw)``; ``yaw`` is the direction of travel in the ENU frame,
counter-clockwise from east (heading from north = 90 deg - yaw), kept in (-pi, pi].

Inputs, from the IMU through the alignment's tilt (:func:`fgins.alignment.initial_alignment`;
``R_tilt`` is the initial body-to-level rotation with the heading removed):

* forward acceleration: the level-frame x component of ``R_tilt @ accel``. Gravity has no
  horizontal component, so on a vehicle that keeps its initial tilt this is the forward
  acceleration exactly (it is ``accel_x - g sin(pitch)`` for a pure pitch). Its constant
  error (the first tilt against the drive's usual one, the accelerometer's bias along the
  track) is the median of that input against the fixes' change of speed over 20-s windows
  (:func:`forward_accel_error`), and is taken out; the spread about it (grade changes) is the
  speed's unestimated bias;
* yaw rate: the vertical component of ``R_tilt @ gyro`` minus the Earth rate's vertical part.

Motion per IMU sample (inputs held over ``dt``, midpoint rule):
``speed += a dt``, ``yaw += r dt``, ``(east, north) += speed_mid (cos, sin)(yaw_mid) dt``;
``up`` is a random walk. IMU biases are not states of this filter: their effect enters as
extra white noise, the variance a turn-on bias builds up over ``bias_horizon_s`` between
fixes, and growing with the time since the last fix through an outage (:func:`bias_hold`).

Measurements (all from the project's shared models):

* GNSS antenna position with sigmas from :func:`fgins.factors.gnss.position_sigmas`
  (UERE x HDOP horizontally, x VDOP or PDOP vertically), after the PDOP/fix gate and the
  outage mask (:func:`fgins.baseline.measurements.select_gnss`); the lever arm turns with yaw;
* GNSS speed and course where the receiver gives a horizontal velocity and the speed exceeds
  ``config.gnss.course_min_speed_m_per_s`` (course sigma = velocity sigma / speed);
* barometric height (``dataset.baro``): pressure -> height with
  :func:`fgins.factors.baro.standard_atmosphere_height` (or the given height), offset so that
  it equals the GNSS up at the start (mean over the usable fixes of the first
  ``baro_offset_window_s``: a single fix's vertical error is metres), sigma
  ``config.smoother.baro_sigma_m``.

The study's known defects are fixed: the course innovation is wrapped to (-pi, pi] (without
it, a course of +179 deg against a yaw of -179 deg is a 358 deg "error"), and every
measurement is applied at its own time (the IMU stream is cut there and propagated to it, no
index lag).

Output: a full :class:`~fgins.datatypes.Trajectory` at IMU rate; rotation from yaw only
(roll = pitch = 0), velocity from speed and yaw, vertical velocity the time derivative of the
filtered up state, position covariance from the filter (velocity and attitude covariances are
not reported: NaN).
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from fgins.alignment import initial_alignment
from fgins.baseline.measurements import GnssEpochs, select_gnss
from fgins.baseline.mechanization import block_times, segment_imu
from fgins.config import RunConfig
from fgins.datatypes import Dataset, InputError, Trajectory
from fgins.factors.baro import standard_atmosphere_height
from fgins.geodesy import earth_rate_enu, plane_fall
from fgins.mounting import mounting_rotation

EAST, NORTH, UP, SPEED, YAW = range(5)
STATE_DIM = 5


@dataclass(frozen=True)
class PlanarKfOptions:
    """Tuning the shared configuration does not carry.

    ``wrap_heading`` False reproduces the study's unwrapped course innovation (for tests and
    comparisons only). ``bias_horizon_s``: see the module docstring. ``up_walk`` and
    ``horizontal_walk``: random-walk densities (m/sqrt(s)) for vertical motion (not modelled)
    and for lateral slip / model error.
    """

    wrap_heading: bool = True
    max_block_s: float = 1.0
    bias_horizon_s: float = 1.0
    up_walk_m_per_sqrt_s: float = 0.5
    horizontal_walk_m_per_sqrt_s: float = 0.1
    baro_offset_window_s: float = 30.0

    def __post_init__(self) -> None:
        for name in (
            "max_block_s",
            "bias_horizon_s",
            "up_walk_m_per_sqrt_s",
            "horizontal_walk_m_per_sqrt_s",
            "baro_offset_window_s",
        ):
            if not getattr(self, name) > 0:
                raise InputError(f"planar KF: {name} must be > 0, got {getattr(self, name)}")


def wrap_angle(angle: np.ndarray | float) -> np.ndarray:
    """Angles wrapped to (-pi, pi]."""
    return np.pi - np.mod(np.pi - np.asarray(angle, dtype=float), 2.0 * np.pi)


@dataclass
class PlanarInputs:
    """Forward acceleration and yaw rate per IMU sample, and the initial state."""

    forward_accel: np.ndarray  # (N,) m/s^2
    yaw_rate: np.ndarray  # (N,) rad/s
    state: np.ndarray  # (5,)
    cov: np.ndarray  # (5, 5)
    lever_arm_level: np.ndarray  # (3,) antenna in the level vehicle frame


def planar_inputs(dataset: Dataset, config: RunConfig, epochs: GnssEpochs) -> PlanarInputs:
    """Level-frame inputs and the initial state from the shared alignment."""
    align = initial_alignment(
        dataset, epochs.usable, smoother=config.smoother,
        gyro_bias_sigma=config.imu_noise().gyro_bias_prior,
    )  # fmt: skip
    rotation = np.asarray(align.rotation, dtype=float)
    # The direction of travel is the vehicle's forward axis, not the IMU's x: an IMU mounted
    # turned ([smoother] imu_to_vehicle_rpy_deg; row 0 is the vehicle's forward in IMU axes)
    # read its x as "forward" (an independent simulator's car with the IMU at [180, 0, -90]
    # or [20, -10, 35]: 185-190 m inside a 40 s outage).
    forward = rotation @ mounting_rotation(config.smoother.imu_to_vehicle_rpy_deg)[0]
    yaw = float(np.arctan2(forward[1], forward[0]))
    c, s = np.cos(yaw), np.sin(yaw)
    tilt = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]]) @ rotation  # Rz(-yaw) R
    level_accel = dataset.imu.accel @ tilt.T
    level_gyro = dataset.imu.gyro @ tilt.T
    velocity = np.asarray(align.velocity, dtype=float)
    speed = float(np.hypot(velocity[0], velocity[1]))
    yaw_sigma = min(float(align.attitude_sigma_rad[2]), np.pi)
    state = np.array([*align.position, speed, yaw])
    cov = np.diag([align.position_sigma**2] * 3 + [align.velocity_sigma**2, yaw_sigma**2])
    lever = tilt @ np.asarray(config.gnss.lever_arm_m, dtype=float)
    return PlanarInputs(
        forward_accel=level_accel[:, 0],
        yaw_rate=level_gyro[:, 2] - earth_rate_enu(dataset.origin.lat)[2],
        state=state,
        cov=cov,
        lever_arm_level=lever,
    )


@dataclass
class BaroHeights:
    """Barometric heights above the origin (offset to the first usable GNSS heights): the
    navigation frame's up is below them by the plane fall where the vehicle is."""

    t: np.ndarray
    up: np.ndarray
    dropped: int


def baro_heights(
    dataset: Dataset, epochs: GnssEpochs, window_s: float = 30.0
) -> BaroHeights | None:
    """Heights from pressure (standard atmosphere) or the given height; None without baro."""
    baro = dataset.baro
    if baro is None or len(baro.t) == 0:
        return None
    height = np.where(
        np.isfinite(baro.pressure),
        standard_atmosphere_height(np.where(np.isfinite(baro.pressure), baro.pressure, 1e5)),
        baro.height,
    )
    imu_t = dataset.imu.t
    valid = np.isfinite(height) & (baro.t >= imu_t[0]) & (baro.t <= imu_t[-1])
    dropped = int((~np.isfinite(height)).sum())
    if valid.sum() < 1:
        return None
    t, height = baro.t[valid], height[valid]
    # The offset to the GNSS up is averaged over the fixes of the first ``window_s``: one
    # fix's vertical error (UERE x VDOP, metres) would otherwise stay in every baro height.
    # The fixes' heights above the origin are up + the plane fall (fgins.geodesy.plane_fall).
    first = epochs.t <= epochs.t[0] + window_s
    above = epochs.position[first, 2] + plane_fall(epochs.position[first], dataset.origin)
    offset = float(np.mean(np.interp(epochs.t[first], t, height) - above))
    return BaroHeights(t=t, up=height - offset, dropped=dropped)


def _propagate(
    state: np.ndarray, accel: np.ndarray, yaw_rate: np.ndarray, dt: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """States at every node of a block (n + 1, 5) and per-step Jacobians (n, 5, 5)."""
    speed = state[SPEED] + np.concatenate([[0.0], np.cumsum(accel * dt)])
    yaw = state[YAW] + np.concatenate([[0.0], np.cumsum(yaw_rate * dt)])
    speed_mid = speed[:-1] + 0.5 * accel * dt
    yaw_mid = yaw[:-1] + 0.5 * yaw_rate * dt
    cos, sin = np.cos(yaw_mid), np.sin(yaw_mid)
    nodes = np.empty((len(dt) + 1, STATE_DIM))
    nodes[:, EAST] = state[EAST] + np.concatenate([[0.0], np.cumsum(speed_mid * cos * dt)])
    nodes[:, NORTH] = state[NORTH] + np.concatenate([[0.0], np.cumsum(speed_mid * sin * dt)])
    nodes[:, UP] = state[UP]
    nodes[:, SPEED] = speed
    nodes[:, YAW] = yaw
    jacobian = np.tile(np.eye(STATE_DIM), (len(dt), 1, 1))
    jacobian[:, EAST, SPEED] = cos * dt
    jacobian[:, EAST, YAW] = -speed_mid * sin * dt
    jacobian[:, NORTH, SPEED] = sin * dt
    jacobian[:, NORTH, YAW] = speed_mid * cos * dt
    return nodes, jacobian


@dataclass
class _Measurement:
    """Stacked measurement rows: residual z - h(x) (angles wrapped), Jacobian, variances."""

    residual: np.ndarray
    jacobian: np.ndarray
    variance: np.ndarray


def _gnss_rows(
    epochs: GnssEpochs,
    g: int,
    state: np.ndarray,
    lever: np.ndarray,
    min_speed: float,
    wrap_heading: bool,
) -> _Measurement:
    c, s = np.cos(state[YAW]), np.sin(state[YAW])
    arm = np.array([c * lever[0] - s * lever[1], s * lever[0] + c * lever[1], lever[2]])
    h = np.zeros((3, STATE_DIM))
    h[:, :3] = np.eye(3)
    h[EAST, YAW] = -arm[NORTH]  # d(arm)/dyaw = (-arm_n, arm_e)
    h[NORTH, YAW] = arm[EAST]
    residual = [epochs.position[g] - (state[:3] + arm)]
    rows = [h]
    variance = [epochs.position_sigma[g] ** 2]
    velocity, sigma = epochs.velocity[g], epochs.velocity_sigma[g]
    speed = float(np.hypot(velocity[0], velocity[1])) if np.all(np.isfinite(velocity[:2])) else 0
    if np.all(np.isfinite(sigma[:2])) and speed >= min_speed:
        course = np.arctan2(velocity[1], velocity[0])
        course_residual = course - state[YAW]
        if wrap_heading:
            course_residual = wrap_angle(course_residual)
        h2 = np.zeros((2, STATE_DIM))
        h2[0, SPEED] = h2[1, YAW] = 1.0
        rows.append(h2)
        residual.append(np.array([speed - state[SPEED], course_residual]))
        variance.append(np.array([sigma[0] ** 2, (sigma[0] / speed) ** 2]))
    return _Measurement(np.concatenate(residual), np.vstack(rows), np.concatenate(variance))


def _update(
    state: np.ndarray, cov: np.ndarray, m: _Measurement, wrap_heading: bool
) -> tuple[np.ndarray, np.ndarray]:
    """Kalman update (Joseph form), then the forward-motion convention.

    (speed, yaw) and (-speed, yaw + pi) move the vehicle alike; from an unknown initial
    heading, position fixes can pull the filter onto the negative-speed twin. The vehicle
    drives forwards, so a clearly negative speed is mapped back (an exact, linear change of variables:
    the speed row and column of the covariance change sign).
    """
    h = m.jacobian
    s = h @ cov @ h.T + np.diag(m.variance)
    gain = np.linalg.solve(s, h @ cov).T
    state = state + gain @ m.residual
    i_kh = np.eye(STATE_DIM) - gain @ h
    cov = i_kh @ cov @ i_kh.T + (gain * m.variance) @ gain.T
    # Only a clearly negative speed: around a stop the sign of the speed is noise.
    if state[SPEED] < -max(3.0 * np.sqrt(cov[SPEED, SPEED]), 0.5):
        state[SPEED], state[YAW] = -state[SPEED], state[YAW] + np.pi
        flip = np.ones(STATE_DIM)
        flip[SPEED] = -1.0
        cov = cov * flip[:, None] * flip[None, :]
    if wrap_heading:
        state[YAW] = wrap_angle(state[YAW])
    return state, 0.5 * (cov + cov.T)


def _boundary_index(times: np.ndarray, event_t: np.ndarray) -> np.ndarray:
    """For every block boundary, the event at it (-1: none). Events are boundaries."""
    at = np.full(len(times), -1)
    k = np.clip(np.searchsorted(times, event_t), 0, len(times) - 1)
    matched = np.isclose(times[k], event_t, rtol=0.0, atol=1e-9)
    at[k[matched]] = np.flatnonzero(matched)
    return at


def run_planar_kf(
    dataset: Dataset,
    config: RunConfig,
    *,
    gnss_mask: np.ndarray | None = None,
    progress: bool = True,
    options: PlanarKfOptions | None = None,
) -> Trajectory:
    """The 5-state planar filter (method ``"planar-kf"``), output at every IMU sample.

    ``gnss_mask`` withholds GNSS epochs (True = keep). Raises InputError when no usable GNSS
    epoch lies within the IMU span. ``info`` counts the updates of each kind.
    """
    options = options or PlanarKfOptions()
    started = time.perf_counter()
    imu = dataset.imu
    epochs = select_gnss(dataset, config, gnss_mask)
    inputs = planar_inputs(dataset, config, epochs)
    baro = baro_heights(dataset, epochs, options.baro_offset_window_s)
    noise = config.imu_noise()
    horizon = options.bias_horizon_s
    walk = options.horizontal_walk_m_per_sqrt_s**2
    white = np.array(
        [walk, walk, options.up_walk_m_per_sqrt_s**2, noise.accel_noise**2, noise.gyro_noise**2]
    )
    # The levelled forward acceleration against the fixes' change of speed: its constant part
    # (the first tilt's pitch against the drive's, and the accelerometer's bias along the
    # track) is taken out of the input, and what remains unknown of it (the grade's changes)
    # is the speed's unestimated bias, in place of the turn-on prior. KITTI starts braking on
    # a slope: the tilt read there (pitch -4.7 deg against ~0.5 deg after) was -0.96 m/s^2
    # of "acceleration" all drive long; its speed ran 20 % low with every fix and 30 s
    # outages ended 173 m off (max 475 m) with 10 % of the epochs within 3 sigma.
    found = forward_accel_error(imu.t, inputs.forward_accel, epochs)
    offset = found.offset if found is not None else 0.0
    accel_variance = found.variance if found is not None else noise.accel_bias_prior**2
    bias_variance = np.array([0.0, 0.0, 0.0, accel_variance, noise.gyro_bias_prior**2])

    anchors = epochs.t if baro is None else np.union1d(epochs.t, baro.t)
    times = block_times(float(imu.t[0]), float(imu.t[-1]), anchors, options.max_block_s)
    segments = segment_imu(imu.t, times)
    gnss_at = _boundary_index(times, epochs.t)
    baro_at = _boundary_index(times, baro.t) if baro is not None else np.full(len(times), -1)
    accel = inputs.forward_accel[segments.sample] - offset
    # Filled-in IMU samples (gaps) are not genuine: inflate their process noise, as the EKF does.
    white_scale = np.ones(len(segments.dt))
    for a, b in imu.suspect:
        white_scale[(segments.start >= a) & (segments.start < b)] = (
            config.smoother.suspect_noise_factor
        )
    yaw_rate = inputs.yaw_rate[segments.sample]

    n_nodes = len(segments.start) + 1
    states = np.empty((n_nodes, STATE_DIM))
    covs = np.empty((n_nodes, STATE_DIM, STATE_DIM))
    counts = {"gnss_updates": 0, "course_updates": 0, "baro_updates": 0}
    baro_var = config.smoother.baro_sigma_m**2
    state, cov = inputs.state.copy(), inputs.cov.copy()
    last_fix = [float(times[0])]  # time of the latest GNSS update (bias_hold)

    def at_boundary(k: int, state: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if gnss_at[k] >= 0:
            last_fix[0] = float(times[k])
            m = _gnss_rows(
                epochs,
                int(gnss_at[k]),
                state,
                inputs.lever_arm_level,
                config.gnss.course_min_speed_m_per_s,
                options.wrap_heading,
            )
            state, cov = _update(state, cov, m, options.wrap_heading)
            counts["gnss_updates"] += 1
            counts["course_updates"] += int(len(m.residual) > 3)
        if baro_at[k] >= 0:
            # The barometer's height stays with the surface: up + the plane fall there. The
            # fall is the prediction's, not a handle on the horizontal: through its gradient
            # (d / R, 0.5 % at 35 km) every height error was read as hundreds of metres of
            # position where the horizontal sigma is large (an outside tester's aircraft in a
            # 100 s outage: 1.6 km with no barometer, 27 km with it).
            position = state[[EAST, NORTH, UP]]
            h = np.zeros((1, STATE_DIM))
            h[0, UP] = 1.0
            fall = plane_fall(position, dataset.origin)[0]
            residual = np.array([baro.up[baro_at[k]] - fall - state[UP]])
            m = _Measurement(residual, h, np.array([baro_var]))
            state, cov = _update(state, cov, m, options.wrap_heading)
            counts["baro_updates"] += 1
        return state, cov

    state, cov = at_boundary(0, state, cov)
    n_blocks = len(times) - 1
    blocks: Iterable[int] = range(n_blocks)
    if progress:  # tqdm only when a bar is shown (import time)
        from tqdm import tqdm

        blocks = tqdm(blocks, desc="planar KF", unit="block", leave=False)
    for b in blocks:
        span = segments.block(b)
        dt = segments.dt[span]
        nodes, jacobian = _propagate(state, accel[span], yaw_rate[span], dt)
        states[span.start : span.stop] = nodes[:-1]
        since = segments.start[span] + 0.5 * dt - last_fix[0]
        density = white[None, :] + bias_variance[None, :] * bias_hold(since, horizon)[:, None]
        q = density * (dt * white_scale[span] ** 2)[:, None]
        # Covariance at every node (5 x 5 per sample: cheap next to the bookkeeping).
        for j in range(len(dt)):
            covs[span.start + j] = cov
            cov = jacobian[j] @ cov @ jacobian[j].T + np.diag(q[j])
        state = nodes[-1].copy()
        if options.wrap_heading:
            state[YAW] = wrap_angle(state[YAW])
        # The next block starts from the a-posteriori state, so a boundary node (an update
        # epoch) shows it, as the EKF's output does.
        state, cov = at_boundary(b + 1, state, cov)
    states[-1], covs[-1] = state, cov
    filtered = time.perf_counter()

    rows = np.clip(np.searchsorted(segments.nodes, imu.t), 0, n_nodes - 1)
    info: dict[str, object] = {
        "gnss_gating": epochs.gating_summary,
        **counts,
        "gnss_epochs_used": len(epochs.t),
        "gnss_epochs_outside_imu_span": epochs.outside_imu_span,
        "baro_samples_dropped": baro.dropped if baro is not None else 0,
        "heading_wrap": options.wrap_heading,
    }
    if found is not None:
        info["forward_accel_offset_m_s2"] = found.offset
        info["grade_spread_m_s2"] = found.spread
    if (note := grade_note(found.spread if found is not None else None)) is not None:
        info["fit_warnings"] = [note]
    trajectory = planar_trajectory(dataset, states[rows], covs[rows], info)
    trajectory.timings.update(
        {"filter": filtered - started, "total": time.perf_counter() - started}
    )
    return trajectory


def bias_hold(since_fix_s: np.ndarray, horizon_s: float) -> np.ndarray:
    """The seconds (per sample, ``since_fix_s`` after the latest GNSS update) over which the
    unmodelled turn-on biases act as white noise of their prior variance.

    Between fixes (1-2 s) a bias's effect is a small, re-corrected drift: ``horizon_s`` of
    it. Through an outage it is one constant: a yaw error ``b t`` and an along-track position
    error ``v b t^2 / 2`` (speed alike with the accelerometer's). White noise of density
    ``3 sigma_b^2 t`` gives that position variance ``v^2 sigma_b^2 t^4 / 4`` (and a yaw 1.2x
    wide); a fixed horizon left the sigmas 4-5x too small at the end of 30 s outages (the
    highway's 150 m error against a 33 m sigma, 35 % of the outage within 3 sigma). Continuous
    at ``horizon_s``."""
    return np.maximum(horizon_s, 3.0 * np.asarray(since_fix_s, dtype=float) - 2.0 * horizon_s)


# The planar model's climb rate is read over at least this much of its height's updates.
CLIMB_WINDOW_S = 2.0


def _climb_rate(t: np.ndarray, up: np.ndarray) -> np.ndarray:
    """Vertical velocity of the planar model's height, which is held between updates and
    steps at each fix or barometer reading: the slope of a straight line through the
    updated heights within +-CLIMB_WINDOW_S (at least two update intervals) of each. Its
    derivative sample by sample had read each step as 150-517 m/s at every fix (outside
    tester); the slope between neighbouring updates carries the barometer's noise."""
    starts = np.concatenate([[0], np.flatnonzero(np.diff(up) != 0.0) + 1]) if len(t) else np.zeros(0, int)
    if len(starts) < 3:
        return np.zeros(len(t))
    tu, hu = t[starts] - t[starts[0]], up[starts]
    half = max(CLIMB_WINDOW_S, 2.0 * float(np.median(np.diff(tu))))
    lo = np.searchsorted(tu, tu - half)
    hi = np.searchsorted(tu, tu + half, side="right")

    def window_sum(x: np.ndarray) -> np.ndarray:
        total = np.concatenate([[0.0], np.cumsum(x)])
        return total[hi] - total[lo]

    n = (hi - lo).astype(float)
    st, sh, stt, sth = window_sum(tu), window_sum(hu), window_sum(tu * tu), window_sum(tu * hu)
    denominator = n * stt - st * st
    slope = np.where(denominator > 1e-12, (n * sth - st * sh) / np.where(denominator > 1e-12, denominator, 1.0), 0.0)
    return slope[np.searchsorted(starts, np.arange(len(t)), side="right") - 1]


def planar_trajectory(
    dataset: Dataset, states: np.ndarray, cov: np.ndarray, info: dict[str, object]
) -> Trajectory:
    """Full trajectory from planar states at the IMU samples (N, 5) and covariances."""
    t = dataset.imu.t
    yaw = states[:, YAW]
    cos, sin = np.cos(yaw), np.sin(yaw)
    rotation = np.zeros((len(t), 3, 3))
    rotation[:, 0, 0], rotation[:, 0, 1] = cos, -sin
    rotation[:, 1, 0], rotation[:, 1, 1] = sin, cos
    rotation[:, 2, 2] = 1.0
    velocity = np.column_stack(
        [states[:, SPEED] * cos, states[:, SPEED] * sin, _climb_rate(t, states[:, UP])]
    )
    return Trajectory(
        t=t,
        position=states[:, :3],
        velocity=velocity,
        rotation=rotation,
        origin=dataset.origin,
        method="planar-kf",
        position_cov=cov[:, :3, :3],
        info=info,
    )


# The planar model's forward acceleration is the accelerometer levelled by the first tilt:
# where the road's grade changes, gravity's share along it is read as acceleration (0.8 m/s^2
# at 8 %), which the fixes correct and an outage does not (an independent simulator's car
# over 2-3 deg grades: 31-48 m inside outages at NEES 12-13, nothing said). Over
# GRADE_WINDOW_S windows while moving, that input against the fixes' change of speed: an
# RMS spread beyond GRADE_SPREAD_M_S2 (a grade change of ~1.5 %) is said.
GRADE_WINDOW_S = 20.0
GRADE_SPREAD_M_S2 = 0.15
GRADE_MIN_WINDOWS = 10
GRADE_MIN_SPEED_M_S = 3.0
GRADE_CHORD_S = 4.0


@dataclass(frozen=True)
class ForwardAccelError:
    """The levelled forward acceleration against the fixes' change of speed, over
    GRADE_WINDOW_S windows while moving (m/s^2): its median ``offset`` (the first tilt's
    pitch against the drive's, and the accelerometer's bias along the track) and the RMS
    ``spread`` about it (the grade's changes, and the fixes' own speed noise, a few
    hundredths), over ``windows`` windows."""

    offset: float
    spread: float
    windows: int
    noise: float  # the part of the spread the fixes' speed noise explains (m/s^2)

    @property
    def variance(self) -> float:
        """What the filter's speed does not know of its input once ``offset`` is taken out:
        the spread beyond the fixes' own noise (which the filter is not subject to), and the
        median's error (~ spread / sqrt(windows))."""
        return max(self.spread**2 - self.noise**2, 0.0) + self.spread**2 / self.windows


def forward_accel_error(
    t_imu: np.ndarray, forward_accel: np.ndarray, epochs: GnssEpochs
) -> ForwardAccelError | None:
    """The forward acceleration's error against the fixes (:class:`ForwardAccelError`); None
    when the fixes cannot tell (too few moving, dense windows)."""
    t = epochs.t
    if len(t) < 2 * GRADE_MIN_WINDOWS:
        return None
    grid = np.arange(t[0] + GRADE_CHORD_S, t[-1] - GRADE_CHORD_S - GRADE_WINDOW_S, GRADE_WINDOW_S / 2)
    velocity = epochs.velocity[:, :2]
    known = np.all(np.isfinite(velocity), axis=1)

    receiver_speed = known.mean() >= 0.8  # else a chord of two fixes GRADE_CHORD_S apart
    sigmas = (
        epochs.velocity_sigma[:, :2]
        if receiver_speed
        else np.sqrt(2.0) * epochs.position_sigma[:, :2] / GRADE_CHORD_S
    )
    speed_sigma = float(np.median(sigmas[np.isfinite(sigmas)])) if np.isfinite(sigmas).any() else 0.0

    def speed(at: np.ndarray) -> np.ndarray:
        if receiver_speed:
            return np.hypot(*(np.interp(at, t[known], velocity[known, i]) for i in range(2)))
        half = GRADE_CHORD_S / 2
        chord = [np.interp(at + half, t, epochs.position[:, i]) - np.interp(at - half, t, epochs.position[:, i])
                 for i in range(2)]  # fmt: skip
        return np.hypot(*chord) / GRADE_CHORD_S

    start, end = speed(grid), speed(grid + GRADE_WINDOW_S)
    cumulative = np.concatenate([[0.0], np.cumsum(0.5 * (forward_accel[1:] + forward_accel[:-1]) * np.diff(t_imu))])
    felt = np.interp(grid + GRADE_WINDOW_S, t_imu, cumulative) - np.interp(grid, t_imu, cumulative)
    gaps = np.diff(t)
    inside = [gaps[(t[:-1] >= a) & (t[:-1] < a + GRADE_WINDOW_S)] for a in grid]
    dense = np.array([x.size > 0 and x.max() <= 2.5 * float(np.median(gaps)) for x in inside])
    use = (np.minimum(start, end) > GRADE_MIN_SPEED_M_S) & dense
    use &= (grid >= t_imu[0]) & (grid + GRADE_WINDOW_S <= t_imu[-1])
    if use.sum() < GRADE_MIN_WINDOWS:
        return None
    mismatch = (felt[use] - (end[use] - start[use])) / GRADE_WINDOW_S
    # The median is the constant error (the first tilt's, the bias); the spread is an RMS
    # about it, not a robust one: the grade changes are a few windows of a drive, which a
    # robust spread would discard.
    offset = float(np.median(mismatch))
    spread = float(np.sqrt(np.mean((mismatch - offset) ** 2)))
    # Each window's change of speed differences two speeds of that sigma.
    noise = np.sqrt(2.0) * speed_sigma / GRADE_WINDOW_S
    return ForwardAccelError(offset, spread, len(mismatch), float(noise))


def grade_note(spread: float | None) -> str | None:
    """A warning when the drive's grade changes enough to mislead the planar model (a
    :func:`forward_accel_error` beyond GRADE_SPREAD_M_S2); None otherwise."""
    if spread is None or spread <= GRADE_SPREAD_M_S2:
        return None
    return (
        f"planar-kf: the vehicle's pitch (a road's grade, an aircraft's climb) changes along "
        f"the drive: the levelled forward "
        f"acceleration departs from the fixes' change of speed by +-{spread:.2f} m/s^2 over "
        f"{GRADE_WINDOW_S:g}-s windows (RMS; gravity at a grade change of "
        f"~{100 * spread / 9.81:.1f} %): the planar model reads it as acceleration, so inside "
        "outages its track drifts (its sigma takes that spread as an unestimated "
        "accelerometer bias); batch or ekf-rts model the attitude"
    )

