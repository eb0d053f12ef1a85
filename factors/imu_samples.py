"""What an IMU sample stands for in time, and its conversion to the held samples the
integrators use (numpy only; shared by the factor graph and the Kalman baselines).

Every integrator here (GTSAM's preintegration, the baselines' mechanization, the dense
output) holds sample k constant over [t_k, t_k+1) and rotates its specific force with the
attitude at t_k. That is exact for ``sample_timing = "held"`` data: the interval's velocity
and angle increments over its length, in the axes at its start (a delta-output IMU's
compensated increments; fgins's own simulator defines its samples that way). A plain mean of
the body-axis readings over the interval (``"mean"``: a decimating filter without sculling
compensation) is turned by half the interval's rotation first (:func:`held_from_means`). Most logs and
simulators give instantaneous rates and specific forces at the time stamps
(``"instant"``, the default: sensor_msgs/Imu, u-blox ESF-RAW, a CSV from a test rig), for
which holding is first order in dt: the attitude lags by w dt / 2 and the specific force is
rotated with the start-of-interval attitude. In a 115 deg/s aircraft roll at 100 Hz that
tipped gravity sideways enough for 5 m of error in 40 s (noise-free), and the smoother's
sigma (0.11 m) did not cover its 1.3 m inside an outage (NEES 135).

Instantaneous samples are therefore converted once, before any estimator sees them, into
the held samples of the same motion to second order:

    w_held_k = (w_k + w_k+1) / 2                        (trapezoid)
    f_held_k = Exp(w_held_k dt_k / 2) (f_k + f_k+1) / 2  (the specific force at mid-interval
                                                          attitude, in start-of-interval axes)

Across an IMU gap (an interval longer than ``GAP_PERIODS`` sample periods) the sample is
kept as it is: nothing is known inside a gap, and the estimators bridge it with inflated
noise.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from fgins.config import IMU_SAMPLE_TIMINGS
from fgins.datatypes import ImuData
from fgins.geodesy import so3_exp

SAMPLE_TIMINGS = IMU_SAMPLE_TIMINGS
GAP_PERIODS = 3.0  # the readers' gap rule (fgins.io.imu_checks.find_gaps)


# The IMU's period where it is: the median spacing of each block of PERIOD_BLOCK intervals,
# the largest of the block's and its two neighbours'. An IMU that changes rate mid-drive
# (100 -> 25 Hz) is no gap at the new rate: its 3,750 intervals had been called gaps,
# bridged with inflated noise and left unconverted, 2.8-6.7x worse inside outages
# (outside tester); a real gap is still many times its neighbours' period.
PERIOD_BLOCK = 200


def _block_periods(dt: np.ndarray) -> np.ndarray:
    """The median of each block of PERIOD_BLOCK intervals ``dt`` (the last one shorter)."""
    blocks = -(-len(dt) // PERIOD_BLOCK)
    padded = np.full(blocks * PERIOD_BLOCK, np.nan)
    padded[: len(dt)] = dt
    return np.nanmedian(padded.reshape(blocks, PERIOD_BLOCK), axis=1)


RATE_CHANGE = 1.5  # a block's period this many times its predecessor's (or a fraction)


def rate_changes(t: np.ndarray) -> list[tuple[float, float, float]]:
    """(time, rate before, rate after in Hz) where the IMU's period changes by RATE_CHANGE
    or more from one block of PERIOD_BLOCK intervals to the next."""
    dt = np.diff(np.asarray(t, dtype=float))
    if len(dt) < 2 * PERIOD_BLOCK:
        return []
    medians = _block_periods(dt)
    ratio = medians[1:] / medians[:-1]
    where = np.flatnonzero((ratio >= RATE_CHANGE) | (ratio <= 1.0 / RATE_CHANGE))
    return [(float(t[(b + 1) * PERIOD_BLOCK]), 1.0 / medians[b], 1.0 / medians[b + 1]) for b in where]


def local_periods(t: np.ndarray) -> np.ndarray:
    """The IMU's sample period at each interval of ``t`` (len(t) - 1; see PERIOD_BLOCK);
    O(N), no window copies."""
    dt = np.diff(np.asarray(t, dtype=float))
    if len(dt) == 0:
        return dt
    medians = _block_periods(dt)
    widest = medians.copy()
    widest[1:] = np.maximum(widest[1:], medians[:-1])
    widest[:-1] = np.maximum(widest[:-1], medians[1:])
    return widest[np.arange(len(dt)) // PERIOD_BLOCK]


def held_samples(imu: ImuData) -> ImuData:
    """``imu`` (instantaneous samples) as held samples over [t_k, t_k+1) (module docstring).

    Vectorised, O(N); the last sample and samples before a gap are kept unchanged."""
    n = len(imu.t)
    if n < 2:
        return imu
    dt = np.diff(imu.t)
    regular = dt <= GAP_PERIODS * local_periods(imu.t)
    gyro = imu.gyro.copy()
    accel = imu.accel.copy()
    mean_gyro = 0.5 * (imu.gyro[:-1] + imu.gyro[1:])
    mean_accel = 0.5 * (imu.accel[:-1] + imu.accel[1:])
    half_turn = so3_exp(mean_gyro[regular] * (0.5 * dt[regular])[:, None])
    rows = np.flatnonzero(regular)
    gyro[rows] = mean_gyro[regular]
    accel[rows] = np.einsum("kij,kj->ki", half_turn, mean_accel[regular])
    return replace(imu, gyro=gyro, accel=accel)


def held_from_means(imu: ImuData) -> ImuData:
    """``imu`` (``"mean"`` samples: each the plain mean of the body-axis readings over
    [t_k, t_k+1), as a decimating filter without sculling compensation gives them) as held
    samples: the specific force turned by half the interval's rotation, Exp(w dt / 2) f,
    into the interval's start axes (first order in w dt, the specific force's change over
    the interval aside). Taken as held, a 2 Hz mean of a car turning at 0.3 rad/s lacked
    0.3 m/s^2 sideways: about 1 m off at 0.5 m fixes, z 2.4-5.5, a lever arm, a clock and a
    gyro scale "corrected" instead (outside tester). Samples before a gap kept."""
    n = len(imu.t)
    if n < 2:
        return imu
    dt = np.diff(imu.t)
    rows = np.flatnonzero(dt <= GAP_PERIODS * local_periods(imu.t))
    accel = imu.accel.copy()
    half_turn = so3_exp(imu.gyro[rows] * (0.5 * dt[rows])[:, None])
    accel[rows] = np.einsum("kij,kj->ki", half_turn, imu.accel[rows])
    return replace(imu, accel=accel)


def for_integration(imu: ImuData, sample_timing: str) -> ImuData:
    """The samples the integrators should hold: converted from ``"instant"`` and
    ``"mean"``, as they are for ``"held"``."""
    if sample_timing not in SAMPLE_TIMINGS:
        raise ValueError(f"sample_timing {sample_timing!r}: one of {SAMPLE_TIMINGS}")
    if sample_timing == "instant":
        return held_samples(imu)
    return held_from_means(imu) if sample_timing == "mean" else imu


def segment_leads(imu_t: np.ndarray, start: np.ndarray, sample: np.ndarray) -> np.ndarray:
    """How long after its sample's time each integration segment starts (s; 0 for the first
    piece of an interval and inside a gap, where nothing is known and the sample is kept as
    it is): the ``lead`` :func:`cut_sample_accel` turns back by."""
    imu_t = np.asarray(imu_t, dtype=float)
    lead = np.maximum(np.asarray(start, dtype=float) - imu_t[sample], 0.0)
    if len(imu_t) < 2:
        return lead
    interval = np.diff(imu_t)
    regular = np.append(interval <= GAP_PERIODS * local_periods(imu_t), False)  # the last: no next
    return np.where(regular[sample], lead, 0.0)


def cut_sample_accel(accel: np.ndarray, gyro: np.ndarray, lead: np.ndarray) -> np.ndarray:
    """The held specific force of integration segments that start ``lead`` seconds (>= 0)
    after their sample's time, in each segment's own start axes (rows of ``accel``/``gyro``,
    the segments' samples; a copy). A held sample stands for a specific force fixed in the
    axes at its interval's start; a keyframe cutting the interval starts the second piece in
    axes turned by w * lead, where the sample's force was applied again as it was: a car
    turning at 0.3 rad/s with a 2 Hz IMU and 10 Hz fixes was pushed 0.3 m/s^2 sideways,
    outages 3.7x worse at z 5-7 (outside tester). Turned back here: exact for the held
    model."""
    out = np.array(accel, dtype=float, copy=True)
    cut = np.flatnonzero(lead > 0.0)
    if len(cut):
        back = so3_exp(-np.asarray(gyro, dtype=float)[cut] * lead[cut, None])
        out[cut] = np.einsum("kij,kj->ki", back, out[cut])
    return out
