"""An initial guess from the GNSS track and gravity alone, at every keyframe (numpy only).

For a vehicle whose nose points along its track (a car), each keyframe's attitude follows
from two vector pairs, as the start-up alignment does (:mod:`fgins.alignment`): the specific
force the accelerometers average over a second, which is ``R^T (a - g)`` with ``a`` the
track's acceleration, and the vehicle's forward axis, which points along the track's
horizontal velocity. TRIAD on the pairs, gravity first, gives ``R``. Position and velocity
are the track's (receiver velocity where it has one, else chords over >= 4 s).

The gyro bias then follows from the rotation the rate sensor measures between attitudes
0.1 s apart against the rotation between their TRIAD attitudes: a median over 21 s per
keyframe, so a few bad attitudes (a stop, a slip) cannot move it. Steps of 0.1 s keep the
rotation a bias causes inside one turn (the bias of a gyro-free IMU's derived rate ramps to
several rad/s; over a 1 s keyframe interval it would alias).

Why: a gyro-free IMU with GNSS at 0.2 Hz leaves the 18-state EKF nothing to hold its
attitude between fixes, and it diverges (tens to hundreds of metres); Levenberg-Marquardt
started there cannot recover, while started here it converges to the smoothed solution
(issue 12). Each attitude is independent of every other, so nothing here can diverge; it is
only as good as a car's nose follows its track (a few degrees), which is what the smoother
needs to start from.
"""

from __future__ import annotations

import numpy as np
from numpy.lib.stride_tricks import sliding_window_view

from fgins.config import RunConfig
from fgins.datatypes import Dataset, InputError
from fgins.factors.gnss import gate_epochs
from fgins.geodesy import lla_to_enu, normal_gravity, so3_exp, so3_log, triad
from fgins.initial_guess import KeyframeGuess
from fgins.mounting import mounting_rotation

CHORD_S = 4.0  # velocity from positions over at least this (1 s chords: the fixes' scatter)
FORCE_WINDOW_S = 1.0  # specific force averaged over this around each attitude
MOVING_SPEED_M_S = 3.0  # heading from the track only above this; held through stops
BIAS_STEP_S = 0.1  # rate-sensor rotation compared over this
BIAS_BLOCK_S = 1.0  # ... averaged over blocks of this ...
BIAS_MEDIAN_BLOCKS = 21  # ... and the median taken over this many blocks
METHOD = "GNSS track + gravity"


def track_guess(
    dataset: Dataset,
    config: RunConfig,
    times: np.ndarray,
    *,
    gnss_mask: np.ndarray | None = None,
) -> KeyframeGuess:
    """States at ``times`` from the GNSS track and gravity (see the module docstring).

    Raises InputError when the track cannot give one: fewer than 3 usable fixes, or no
    stretch faster than 3 m/s to take a heading from."""
    times = np.asarray(times, dtype=float)
    track_t, track_enu, track_velocity = _track(dataset, config, gnss_mask)
    position = _interp(times, track_t, track_enu)
    velocity = _interp(times, track_t, track_velocity)
    forward = mounting_rotation(config.smoother.imu_to_vehicle_rpy_deg)[0]
    gravity = np.array([0.0, 0.0, -normal_gravity(dataset.origin.lat, dataset.origin.alt)])

    imu = dataset.imu
    summed_force = np.vstack([np.zeros((1, 3)), np.cumsum(imu.accel, axis=0)])

    def attitude(at: np.ndarray) -> np.ndarray:
        # The specific force averaged over FORCE_WINDOW_S around each time.
        lo = np.searchsorted(imu.t, at - FORCE_WINDOW_S / 2)
        hi = np.searchsorted(imu.t, at + FORCE_WINDOW_S / 2)
        hi = np.clip(np.maximum(hi, lo + 1), 1, len(imu.t))
        lo = np.minimum(lo, hi - 1)
        force = (summed_force[hi] - summed_force[lo]) / (hi - lo)[:, None]
        return _attitude(at, force, track_t, track_velocity, forward, gravity)

    rotation = attitude(times)
    gyro_bias = _gyro_bias(dataset, times, attitude)
    return KeyframeGuess(
        t=times,
        rotation=rotation,
        position=position,
        velocity=velocity,
        accel_bias=np.zeros((len(times), 3)),
        gyro_bias=gyro_bias,
        method=METHOD,
    )


def _track(
    dataset: Dataset, config: RunConfig, gnss_mask: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fixes the smoother may use (the one GNSS gate, :func:`fgins.factors.gnss.gate_epochs`,
    and the outage mask): times, ENU positions and velocities (the receiver's where given and
    used, else chords)."""
    gnss = dataset.gnss
    usable = gate_epochs(gnss, config.gnss).usable
    if gnss_mask is not None:
        usable &= np.asarray(gnss_mask, dtype=bool)
    if usable.sum() < 3:
        raise InputError(f"the track guess needs >= 3 usable GNSS fixes, got {usable.sum()}")
    t = gnss.t[usable]
    enu = lla_to_enu(gnss.lla[usable], dataset.origin)
    index = np.arange(len(t))
    lo = np.minimum(np.searchsorted(t, t - CHORD_S / 2), np.maximum(index - 1, 0))
    hi = np.searchsorted(t, t + CHORD_S / 2, side="right") - 1
    hi = np.maximum(np.clip(hi, 0, len(t) - 1), np.minimum(index + 1, len(t) - 1))
    velocity = (enu[hi] - enu[lo]) / np.maximum(t[hi] - t[lo], 1e-9)[:, None]
    if gnss.velocity is not None and config.gnss.use_velocity:
        receiver = dataset.gnss_velocity_nav()[usable]
        given = np.all(np.isfinite(receiver), axis=1)
        velocity[given] = receiver[given]
    return t, enu, velocity


def _interp(at: np.ndarray, t: np.ndarray, values: np.ndarray) -> np.ndarray:
    return np.column_stack([np.interp(at, t, values[:, j]) for j in range(values.shape[1])])


def _attitude(
    at: np.ndarray,
    force: np.ndarray,
    track_t: np.ndarray,
    track_velocity: np.ndarray,
    forward: np.ndarray,
    gravity: np.ndarray,
) -> np.ndarray:
    """Body -> ENU rotations at ``at`` by TRIAD (gravity pair first, then the heading) from
    the averaged specific ``force`` there and the track."""
    velocity = _interp(at, track_t, track_velocity)
    acceleration = np.gradient(velocity, at, axis=0) if len(at) > 2 else np.zeros_like(velocity)
    moving = np.hypot(velocity[:, 0], velocity[:, 1]) > MOVING_SPEED_M_S
    if not moving.any():
        raise InputError(
            f"the track guess needs the vehicle moving faster than {MOVING_SPEED_M_S:g} m/s"
        )
    # The heading of the last moment in motion (the first one before any).
    held = np.maximum.accumulate(np.where(moving, np.arange(len(at)), 0))
    held[: np.argmax(moving)] = np.argmax(moving)
    heading = np.column_stack([velocity[held, :2], np.zeros(len(at))])
    return triad(force, np.broadcast_to(forward, force.shape), acceleration - gravity, heading)


def _rate_rotations(imu, grid: np.ndarray) -> np.ndarray:
    """Rotation the rate sensor measures over each step of ``grid`` (n-1, 3, 3)."""
    dt = np.diff(imu.t, append=imu.t[-1])
    start = np.searchsorted(imu.t, grid[:-1])
    count = np.searchsorted(imu.t, grid[1:]) - start
    rotation = np.tile(np.eye(3), (len(grid) - 1, 1, 1))
    for m in range(int(count.max(initial=0))):
        active = m < count
        sample = start[active] + m
        rotation[active] = rotation[active] @ so3_exp(imu.gyro[sample] * dt[sample][:, None])
    return rotation


def _gyro_bias(dataset: Dataset, times: np.ndarray, attitude) -> np.ndarray:
    """Gyro bias at ``times``: the measured minus the TRIAD rotation rate, robustly smoothed."""
    grid = np.arange(times[0], times[-1] + BIAS_STEP_S / 2, BIAS_STEP_S)
    if len(grid) < 3:
        return np.zeros((len(times), 3))
    rotation = attitude(grid)
    measured = _rate_rotations(dataset.imu, grid)
    between = np.swapaxes(rotation[:-1], 1, 2) @ rotation[1:]
    # measured = between . Exp(bias dt): the bias is what the sensor turned beyond the track.
    rate = so3_log(np.swapaxes(between, 1, 2) @ measured) / np.diff(grid)[:, None]
    per_block = max(1, round(BIAS_BLOCK_S / BIAS_STEP_S))
    n_blocks = len(rate) // per_block
    if n_blocks == 0:
        return np.repeat(np.median(rate, axis=0)[None], len(times), axis=0)
    blocks = rate[: n_blocks * per_block].reshape(n_blocks, per_block, 3).mean(axis=1)
    block_t = grid[0] + (np.arange(n_blocks) + 0.5) * per_block * BIAS_STEP_S
    smoothed = _running_median(blocks, BIAS_MEDIAN_BLOCKS // 2)
    return _interp(times, block_t, smoothed)


def _running_median(x: np.ndarray, half: int) -> np.ndarray:
    """Median over 2 half + 1 rows; the ends take the nearest full window's (a shrunken
    window there would be one outlier's)."""
    half = min(half, (len(x) - 1) // 2)
    if half <= 0:
        return x.copy()
    middle = np.median(sliding_window_view(x, 2 * half + 1, axis=0), axis=-1)
    return np.concatenate([np.repeat(middle[:1], half, 0), middle, np.repeat(middle[-1:], half, 0)])
