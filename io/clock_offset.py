"""The GNSS clock against the IMU's, from the drive's own turns (numpy only).

A turning vehicle's GNSS track turns when its gyro does. The track's course from position
chords (on an arc a chord points along the heading at its middle) changes over 4-s windows by
as much as the gyro's rotation about up over the same 4 s, less the gyro bias; with the fixes
stamped ``lag`` early the two line up only where the gyro is read ``lag`` later. The lag that
fits best, over +-30 s, is the clock offset: adding it to the GNSS times (``--time-offset``)
aligns the clocks. Independent of the IMU's mounting (only the rotation about up is used).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

CHORD_HALF_S = 1.0  # course from positions this far either side
WINDOW_S = 4.0  # course change over this span
GRID_S = 0.5  # windows start this often
MIN_SPEED_M_S = 3.0
MAX_LAG_S = 30.0
COARSE_STEP_S = 0.1
FINE_STEP_S = 0.005
MIN_TURN_RAD = 0.35  # a window with a clear turn (20 deg)
MIN_TURNING_WINDOWS = 8
# A lag is judged over at least this fraction of the windows that zero lag is judged over.
COMPARABLE_WINDOWS = 0.8
MIN_TOTAL_TURN_RAD = 2 * np.pi  # turns in all (overlapping windows count again): ~1 rad real
# What is said. KITTI: its own fixes 0.045 s late (1.07x better), a 0.2 s offset 1.8x, 3 s
# 190x, over 279 turning windows; the simulated highway, 14 windows, a false 3 s at 2.4x and a
# 25 m loop a false 23 s at 1.06x (periodic motion aliases): so many windows and a clear gain.
WARN_MIN_WINDOWS = 50
WARN_MIN_LAG_S = 0.1
WARN_MIN_IMPROVEMENT = 1.5
ERROR_MIN_WINDOWS = 30
ERROR_MIN_LAG_S = 1.0
ERROR_MIN_IMPROVEMENT = 10.0
# Over as many windows as a warning needs, a smaller gain will do for an offset of seconds:
# noisy fixes raise the mismatch at every lag alike (an independent simulator's hilly drive,
# 1 m fixes, 4 turns: 3 s found at 3.0-3.8x, 7 s at 8.5-10.9x, 0 s at 1.00x; 3 m fixes:
# 7 s at 1.5-2.0x, found to 0.05-0.3 s). At 3-7 s it was a warning, and the run went on to
# chi2/dof 12-40 and an antenna "41-84 m ahead" of the IMU.
ERROR_MIN_IMPROVEMENT_MANY_WINDOWS = 2.0
# From the receiver's velocities (their course, fgins.io.motion_checks): an offset of at least
# this many seconds, beyond the 0.5-2.5 s a receiver's velocity may lag its own positions.
CLOCK_VELOCITY_MIN_LAG_S = 3.0


@dataclass
class ClockOffset:
    """``lag_s``: the fixes line up with the gyro when their times are moved by this (add it
    to the GNSS times: ``--time-offset lag_s``); ``improvement``: the mismatch at zero lag
    over the mismatch at ``lag_s`` (1: no better); ``windows``: turning windows used."""

    lag_s: float
    improvement: float
    windows: int


def estimate_clock_offset(
    t_imu: np.ndarray,
    yaw_rate: np.ndarray,
    t_gnss: np.ndarray,
    east_north: np.ndarray,
    velocity_en: np.ndarray | None = None,
) -> ClockOffset | None:
    """The lag between the GNSS track's course changes and the gyro's rotation about up
    (``yaw_rate``, counter-clockwise positive, rad/s), or None when the drive has too few
    turns while moving among dense fixes to tell. With ``velocity_en`` (the receiver's east
    and north velocity at the fixes) the course is the velocity's, far sharper than a 2-s
    chord of 3 m fixes (0.02 against 0.25 rad at 10 m/s), though a receiver's velocity may
    lag its positions by a fraction of a second: for offsets of seconds only."""
    if len(t_gnss) < 10 or len(t_imu) < 10:
        return None
    interval = float(np.median(np.diff(t_gnss)))
    if not interval > 0 or interval > CHORD_HALF_S:
        return None  # fixes too sparse for a 2-s chord
    # Windows only where both sensors are: a few fixes stamped 0 (1970) among POSIX-time
    # ones made a grid over 54 years (25 GiB) before any check saw them.
    lo = max(t_gnss[0], t_imu[0]) + CHORD_HALF_S
    hi = min(t_gnss[-1], t_imu[-1]) - CHORD_HALF_S - WINDOW_S
    if hi - lo < 10 * WINDOW_S:
        return None
    start = np.arange(lo, hi, GRID_S)
    course = [_course(t, t_gnss, east_north, interval, velocity_en) for t in (start, start + WINDOW_S)]
    good = course[0][1] & course[1][1]
    change = np.angle(np.exp(1j * (course[1][0] - course[0][0])))  # counter-clockwise
    turning = good & (np.abs(change) > MIN_TURN_RAD)
    if turning.sum() < MIN_TURNING_WINDOWS or np.abs(change[good]).sum() < MIN_TOTAL_TURN_RAD:
        return None
    start, change, turning = start[good], change[good], turning[good]
    steps = 0.5 * (yaw_rate[1:] + yaw_rate[:-1]) * np.diff(t_imu)
    rotation = np.concatenate([[0.0], np.cumsum(steps)])

    def mismatch(lags: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(mean squared mismatch, windows inside the IMU's span, turning ones) per lag."""
        a = start[None, :] + lags[:, None]
        inside = (a >= t_imu[0]) & (a + WINDOW_S <= t_imu[-1])
        count = inside.sum(axis=1)
        gyro = np.interp(a + WINDOW_S, t_imu, rotation) - np.interp(a, t_imu, rotation)
        diff = np.where(inside, change[None, :] - gyro, 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            bias = diff.sum(axis=1, keepdims=True) / count[:, None]  # the gyro bias
            cost = np.where(inside, (diff - bias) ** 2, 0.0).sum(axis=1) / count
        return cost, count, (inside & turning[None, :]).sum(axis=1)

    # Lags are compared over (nearly) the same windows: those inside the IMU's span at each
    # lag. An IMU that covers only part of the fixes' span left a few windows at some lag
    # (one window fits any lag exactly: a false "18.5 s, infinitely better").
    at_zero, count_zero, turns_zero = (v[0] for v in mismatch(np.array([0.0])))
    if turns_zero < MIN_TURNING_WINDOWS:
        return None

    def comparable_cost(lags: np.ndarray) -> np.ndarray:
        cost, count, turns = mismatch(lags)
        usable = (turns >= MIN_TURNING_WINDOWS) & (count >= COMPARABLE_WINDOWS * count_zero)
        return np.where(usable, cost, np.nan)

    coarse = np.arange(-MAX_LAG_S, MAX_LAG_S + COARSE_STEP_S / 2, COARSE_STEP_S)
    cost = comparable_cost(coarse)
    if not np.any(np.isfinite(cost)):
        return None
    best = coarse[int(np.nanargmin(cost))]
    fine = best + np.arange(-2 * COARSE_STEP_S, 2 * COARSE_STEP_S + FINE_STEP_S / 2, FINE_STEP_S)
    fine_cost = comparable_cost(fine)
    if not np.any(np.isfinite(fine_cost)):
        return None
    lag = float(fine[int(np.nanargmin(fine_cost))])
    at_lag, _, turns = (v[0] for v in mismatch(np.array([lag])))
    improvement = at_zero / at_lag if at_lag > 0 else np.inf
    return ClockOffset(lag_s=lag, improvement=float(improvement), windows=int(turns))


def _course(
    t: np.ndarray,
    t_gnss: np.ndarray,
    east_north: np.ndarray,
    interval: float,
    velocity_en: np.ndarray | None = None,
):
    """Course (rad, counter-clockwise from east, as a yaw) of the chord t +- CHORD_HALF_S (or
    of the receiver's velocity at t), and whether it is usable (moving, fixes dense around
    both ends)."""
    a, b = t - CHORD_HALF_S, t + CHORD_HALF_S
    if velocity_en is not None:
        known = np.all(np.isfinite(velocity_en), axis=1)
        d = 2 * CHORD_HALF_S * np.column_stack([
            np.interp(t, t_gnss[known], velocity_en[known, i]) for i in range(2)
        ])  # fmt: skip
    else:
        d = np.column_stack([
            np.interp(b, t_gnss, east_north[:, i]) - np.interp(a, t_gnss, east_north[:, i])
            for i in range(2)
        ])  # fmt: skip
    ia = np.clip(np.searchsorted(t_gnss, a), 1, len(t_gnss) - 1)
    ib = np.clip(np.searchsorted(t_gnss, b), 1, len(t_gnss) - 1)
    gap = np.maximum(t_gnss[ia] - t_gnss[ia - 1], t_gnss[ib] - t_gnss[ib - 1])
    speed = np.hypot(d[:, 0], d[:, 1]) / (2 * CHORD_HALF_S)
    usable = (speed > MIN_SPEED_M_S) & (gap <= 2.5 * interval)
    return np.arctan2(d[:, 1], d[:, 0]), usable


def judge(
    offset: ClockOffset | None, given_offset_s: float = 0.0, *, banks: bool = False
) -> tuple[str, str] | None:
    """("error" | "warning", message) for an offset worth saying, else None.
    ``given_offset_s``: the --time-offset already applied (the advice is the total).
    ``banks``: the body banks into its turns (an aircraft): its gyro about the log's mean
    "up" is not its rotation about the vertical while it rolls in and out, which shifts the
    fit by seconds at a small gain (a climbing 45 deg turn: a false +2.1 s at 1.6x; the gyro
    about the true vertical does no better, as a roll at a pitch turns about it too), so only
    a clock offset (many seconds, a large gain) is said, with its uncertainty, not a
    receiver's latency."""
    if offset is None:
        return None
    lag, gain, windows = offset.lag_s, offset.improvement, offset.windows
    total = given_offset_s + lag
    where = (
        f"the GNSS track's turns line up with the gyro's when the fixes are moved by "
        f"{lag:+.2f} s ({gain:.3g}x closer than as stamped, over {windows} turning 4-s windows)"
    )
    clear = gain >= ERROR_MIN_IMPROVEMENT and windows >= ERROR_MIN_WINDOWS
    if not banks:  # a banking aircraft's turns are off by seconds at a small gain
        clear |= gain >= ERROR_MIN_IMPROVEMENT_MANY_WINDOWS and windows >= WARN_MIN_WINDOWS
    if abs(lag) >= ERROR_MIN_LAG_S and clear:
        # (GPS time against UTC is named only where the offset is that: an IMU clock 1 %
        # fast read as 1.45 s was told of the 18 s; outside tester)
        leap = " (GPS time against UTC is 18 s)" if min(abs(abs(x) - 18.0) for x in (lag, total)) < 1.0 else ""
        return "error", (
            f"time: {where}: the IMU and GNSS clocks differ{leap}; "
            f"give --time-offset {total:+.2f}"
            + (" (from a banking aircraft's turns this is good to about 2 s)" if banks else "")
        )
    if banks:
        return None
    if abs(lag) >= WARN_MIN_LAG_S and gain >= WARN_MIN_IMPROVEMENT and windows >= WARN_MIN_WINDOWS:
        return "warning", (
            f"time: {where}: fixes stamped late or early (receiver latency) or offset clocks; "
            f"--time-offset {total:+.2f} aligns them"
        )
    return None


# An offset that changes along the drive by more than this (s), and this share of itself,
# between the drive's two halves: two clocks at different rates, not one offset.
RATE_MIN_CHANGE_S = 0.3
RATE_MIN_SHARE = 0.25


def clock_rate(
    t_imu: np.ndarray, yaw_rate: np.ndarray, t_gnss: np.ndarray, east_north: np.ndarray
) -> tuple[float, float, float] | None:
    """(lag over the first half of the drive, lag over the second half, the IMU clock's rate
    against the receiver's: the lag's change per second of GNSS time) where both halves show
    one clearly and they differ by RATE_MIN_CHANGE_S and RATE_MIN_SHARE; else None. An IMU
    clock 1-2.4 % fast (an IMU at 101 Hz stamped as its sample count / 100) was refused as
    one offset of 1.45-3.4 s, and the output, following the advice, lay that far off the
    receiver's times (outside tester)."""
    lo, hi = max(t_gnss[0], t_imu[0]), min(t_gnss[-1], t_imu[-1])
    half = (hi - lo) / 2.0
    found = []
    for a, b in ((lo, lo + half), (hi - half, hi)):
        fixes = (t_gnss >= a) & (t_gnss <= b)
        samples = (t_imu >= a - MAX_LAG_S) & (t_imu <= b + MAX_LAG_S)
        offset = estimate_clock_offset(t_imu[samples], yaw_rate[samples], t_gnss[fixes], east_north[fixes])
        if offset is None or offset.improvement < WARN_MIN_IMPROVEMENT:
            return None
        found.append((0.5 * (a + b), offset.lag_s))
    (t1, lag1), (t2, lag2) = found
    change = lag2 - lag1
    if abs(change) < max(RATE_MIN_CHANGE_S, RATE_MIN_SHARE * max(abs(lag1), abs(lag2))):
        return None
    return lag1, lag2, change / (t2 - t1)
