"""Stop detection and barometer sampling on raw sensor streams (numpy only, no GTSAM).

Shared by the factor graph (:mod:`fgins.graph.problem`) and the Kalman baselines, so both
decide "the IMU is quiet" and "the pressure at this time" the same way. Windows are given as
``before_s``/``after_s`` around each query time: the graph looks both ways (it sees the
whole log), a causal filter only back.
"""

from __future__ import annotations

from collections import deque

import numpy as np

from fgins.config import ImuNoise
from fgins.datatypes import BaroData, ImuData
from fgins.geodesy import Origin, plane_fall

MIN_QUIET_SAMPLES = 5
# A quiet window's mean rate is no turn while its norm is within this many of the gyro's
# per-axis turn-on sigmas: at rest it is the bias, whose norm is chi-distributed with 3
# degrees of freedom (99.95 % below 4.5 sigma). Three sigmas on the norm refused every stop
# of 3 % of IMUs for the whole drive: a simulated car parked 120 s whose bias was drawn at
# (2.0, -2.6, 0.4) sigma got no ZUPT at all. A slow steady turn above this stays refused,
# and a stop is confirmed by speed as well (speed_confirms_stop).
TURN_BIAS_SIGMAS = 4.5

# Fixes whose chord moves more than this many of its own sigmas show motion (gnss_moving).
STOP_SPEED_SIGMAS = 3.0
# A stop needs the solution's speed within this many sigmas of zero, or below the floor (a
# well-known speed of a few cm/s at a real stop), see speed_confirms_stop. Five, not three:
# the speed comes from a solution without stop information and with every fix at full weight,
# and a single 25 m outlier among the fixes of a stop pulls it several sigmas off zero. On the
# simulated urban car (110 s, industrial MEMS, no GNSS velocity, seeds 1-24) the first pass's
# velocity at the start-up stop had a squared Mahalanobis distance of 3.3 on average (2
# expected) with 14 and 17 where an outlier sat in or beside the stop; three sigmas refused
# those two real stops and the batch ended 2.3x EKF+RTS's outage error on them (pooled 1.57
# vs 1.32 m, after: 1.34 m). A steady crawl is still refused where its speed is known:
# 1.2 +- 0.1 m/s is 12 sigmas (tests/test_stop_detection.py).
SOLUTION_STOP_SIGMAS = 5.0
STOP_SPEED_FLOOR_M_PER_S = 0.25


def speed_confirms_stop(speed: float | None, sigma: float | None, max_speed: float) -> bool:
    """Does an estimate's speed (m/s) at a quiet IMU window confirm a stop?

    Below ``max_speed`` (``zupt_max_speed_m_per_s``) and, when its sigma is known, within
    ``SOLUTION_STOP_SIGMAS`` sigmas of zero (at least ``STOP_SPEED_FLOOR_M_PER_S``). Why the
    sigma: an IMU moving at constant velocity reads like one at rest (a smooth crawl, the peak
    of a gentle start; simulated data without vibration), so a quiet IMU alone cannot tell;
    a speed the estimate knows to be 1.2 +- 0.1 m/s can. The cap alone let such a crawl in an
    outage be frozen by 86 false stops (batch 13 m off where 0.2 m was possible). Where the
    speed is poorly known (a long outage) the cap decides. Shared by the graph and the Kalman
    baselines, so both decide stops alike.
    """
    if speed is None or not speed < max_speed:
        return False
    if sigma is None or not np.isfinite(sigma):
        return True
    return speed < max(STOP_SPEED_FLOOR_M_PER_S, SOLUTION_STOP_SIGMAS * sigma)


GNSS_MOTION_WINDOW_S = 4.0  # fixes this far back from a keyframe show whether it moves
GNSS_MOTION_MIN_SPAN_S = 2.0


def gnss_chord(
    times: np.ndarray, gnss_t: np.ndarray, window_s: float = GNSS_MOTION_WINDOW_S
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each time, the first and last fix (indices, clipped into range) of the
    ``window_s`` before it, and whether they span at least GNSS_MOTION_MIN_SPAN_S: where a
    chord between them can judge motion (:func:`gnss_moving`)."""
    last = np.searchsorted(gnss_t, times, side="right") - 1
    first = np.searchsorted(gnss_t, times - window_s, side="left")
    ok = (last >= 0) & (last > first)
    first, last = np.clip(first, 0, len(gnss_t) - 1), np.clip(last, 0, len(gnss_t) - 1)
    ok &= gnss_t[last] - gnss_t[first] >= GNSS_MOTION_MIN_SPAN_S
    return first, last, ok


def gnss_moving(
    times: np.ndarray,
    gnss_t: np.ndarray,
    gnss_enu: np.ndarray,
    gnss_sigma: np.ndarray,
    moving_before_fixes: bool = False,
    window_s: float = GNSS_MOTION_WINDOW_S,
) -> np.ndarray:
    """True (K,) where the fixes of the last ``window_s`` (``GNSS_MOTION_WINDOW_S``) before each time moved
    further than their own noise can fake: the chord's horizontal speed above
    ``STOP_SPEED_SIGMAS`` sigmas (from the two fixes' sigmas) and the floor. Causal, so the
    online solvers can use it: an estimate that starts at 0 +- 3 m/s (a quiet IMU at a
    steady speed) cannot refuse a stop by its sigma, the fixes can (a car reversing at 3
    m/s from the first sample was held still by iSAM2's online pass, 20 m off).
    ``moving_before_fixes``: the answer for the times before the fixes can first tell (the
    alignment's: True when it could not rule out a steady motion at the start).
    """
    times = np.asarray(times, dtype=float)
    out = np.zeros(len(times), dtype=bool)
    if len(gnss_t) < 2:
        return out
    first, last, ok = gnss_chord(times, gnss_t, window_s)
    span = gnss_t[last] - gnss_t[first]
    with np.errstate(invalid="ignore", divide="ignore"):
        chord = np.linalg.norm(gnss_enu[last, :2] - gnss_enu[first, :2], axis=1) / span
        sigma = np.sqrt(np.sum(gnss_sigma[first, :2] ** 2 + gnss_sigma[last, :2] ** 2, axis=1)) / span
    out[ok] = chord[ok] > np.maximum(STOP_SPEED_FLOOR_M_PER_S, STOP_SPEED_SIGMAS * sigma[ok])
    if moving_before_fixes and np.any(ok):
        out[times < times[np.argmax(ok)]] = True
    elif moving_before_fixes:
        out[:] = True
    return out


# A causal estimate (the Kalman baselines, iSAM2's online pass, the batch's initial guess)
# confirms a stop by its own speed and sigma, which metre-level fixes hold at 0.2-0.3 m/s,
# so a vehicle crawling at 1 m/s with a quiet IMU (a field robot on a straight, which an IMU
# reads like rest) passed as stopped: 17-27 false stops with GNSS, whole outages held still
# (forward EKF 33 m off, iSAM2 online 36 m without a word, where 0.6 m is possible). The fixes
# of the last 4 s (gnss_moving) cannot see such a crawl through their noise; a 12 s chord can
# (0.4 m/s through 1 m fixes). It refuses a stop only while the estimate's speed is above a
# known stop's floor: at a real stop the chord still holds the braking for 12 s, while the
# estimate, which integrated the braking, is near zero (refusing those stops as well made
# EKF+RTS 7 % better than the batch on the urban car: all methods must see the same stops).
CRAWL_WINDOW_S = 12.0


def crawl_refuses_stop(crawling: bool, speed: float | None) -> bool:
    """Do fixes that moved over ``CRAWL_WINDOW_S`` (``crawling``, :func:`gnss_moving` with
    that window) refuse a stop at an estimated ``speed`` (m/s)?"""
    return bool(crawling) and speed is not None and speed >= STOP_SPEED_FLOOR_M_PER_S


# Stops the whole log shows moving: a car creeping in a jam at 0.1-0.3 m/s, its engine
# idling, reads like rest to the IMU, its solved speed sits under the floor above, and 4-12 s
# chords of metre-level fixes cannot see it; over the minute it creeps the fixes can (an
# outside tester's 140 s creep at 0.13-0.24 m/s was frozen: 8 m off with every fix used,
# 14.5 m inside an outage, good fixes "faults", the blame on the receiver). The creep's stops
# come in short runs (a keyframe here and there whose fixes moved), so they are judged over
# the slow stretch around them: the keyframes where the solution without stops is slower than
# SLOW_STRETCH_M_PER_S (a stop-and-go's moves between stops are faster and split it).
# Between the medians of its fixes' first and last thirds, a distance beyond what their noise
# (CREEP_SIGMAS) and a stopped receiver's slow wander (CREEP_MIN_DISPLACEMENT_M) give, at a
# mean speed above CREEP_MIN_SPEED_M_PER_S, is no stop; nor are stops where the wheel reads a
# mean speed beyond its noise. A stretch without fixes (a stop in a tunnel) keeps its stops.
SLOW_STRETCH_M_PER_S = 0.5
CREEP_MIN_DISPLACEMENT_M = 2.5
CREEP_MIN_SPEED_M_PER_S = 0.03
CREEP_SIGMAS = 5.0
CREEP_MIN_FIXES = 6  # two in each third
WHEEL_CREEP_MIN_SPEED_M_PER_S = 0.05
MEDIAN_EFFICIENCY = 1.2533  # a median's sigma over a mean's (sqrt(pi / 2))


def true_runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """(first, one past the last) index of each run of True in ``mask``."""
    edges = np.diff(np.concatenate([[0], np.asarray(mask, dtype=np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return [(int(a), int(b)) for a, b in zip(starts, stops, strict=True)]


def moving_stops(
    times: np.ndarray,
    stops: np.ndarray,
    speed: np.ndarray,
    fix_keyframe: np.ndarray,
    fix_en: np.ndarray,
    fix_sigma_en: np.ndarray,
    wheel_speed: np.ndarray | None = None,
    wheel_sigma: float = 0.1,
) -> tuple[np.ndarray, list[tuple[float, float, str]]]:
    """The ``stops`` (K,) of slow stretches that moved (see SLOW_STRETCH_M_PER_S and
    CREEP_*), and for each such stretch (its first and last keyframe's time, what showed the
    motion). ``speed`` (K,): the solution's without stops; ``fix_keyframe`` (M,): the
    keyframe of each used fix; ``fix_en`` (M, 2), ``fix_sigma_en`` (M, 2): its east/north
    position and sigmas; ``wheel_speed`` (K,): the wheel's speed, NaN where none."""
    moving = np.zeros(len(times), dtype=bool)
    said: list[tuple[float, float, str]] = []
    for a, b in true_runs(stops | (speed < SLOW_STRETCH_M_PER_S)):
        if not stops[a:b].any():
            continue
        how = _fixes_moved(times, fix_keyframe, fix_en, fix_sigma_en, a, b)
        if not how and wheel_speed is not None:
            wheel = wheel_speed[a:b][stops[a:b]]
            wheel = wheel[np.isfinite(wheel)]
            mean = float(np.mean(wheel)) if len(wheel) >= 3 else 0.0
            if abs(mean) > max(WHEEL_CREEP_MIN_SPEED_M_PER_S, CREEP_SIGMAS * wheel_sigma / np.sqrt(max(len(wheel), 1))):
                how = f"the wheel read {mean:+.2f} m/s on average at them"
        if how:
            moving[a:b] = stops[a:b]
            said.append((float(times[a]), float(times[b - 1]), how))
    return moving, said


def _fixes_moved(
    times: np.ndarray, fix_keyframe: np.ndarray, fix_en: np.ndarray, fix_sigma_en: np.ndarray,
    a: int, b: int,
) -> str:
    """What the fixes of keyframes a..b-1 show of a motion beyond their noise ("" if none)."""
    fixes = np.flatnonzero((fix_keyframe >= a) & (fix_keyframe < b))
    if len(fixes) < CREEP_MIN_FIXES:
        return ""
    third = len(fixes) // 3
    first, last = fixes[:third], fixes[-third:]
    shift = np.median(fix_en[last], axis=0) - np.median(fix_en[first], axis=0)
    spread = MEDIAN_EFFICIENCY * np.sqrt(
        (np.mean(fix_sigma_en[first] ** 2, axis=0) + np.mean(fix_sigma_en[last] ** 2, axis=0)) / third
    )
    distance = float(np.hypot(*shift))
    apart = float(np.median(times[fix_keyframe[last]]) - np.median(times[fix_keyframe[first]]))
    if (
        distance > max(CREEP_MIN_DISPLACEMENT_M, CREEP_SIGMAS * float(np.hypot(*spread)))
        and apart > 0
        and distance / apart > CREEP_MIN_SPEED_M_PER_S
    ):
        return f"the fixes moved {distance:.1f} m ({distance / apart:.2f} m/s)"
    return ""


# A causal estimate takes a stop only after a slow-down it saw: a speed below half its peak
# over this many seconds before, or below a known stop's floor (see slowed_to_a_stop).
SLOWDOWN_WINDOW_S = 10.0


def slowed_to_a_stop(speed: float, recent_peak: float) -> bool:
    """Did a causal estimate (the Kalman baselines, iSAM2's online pass) slow down to a
    stop: ``speed`` below half ``recent_peak`` (its peak speed over the last
    ``SLOWDOWN_WINDOW_S`` among those it knew to be above zero, :class:`RecentSpeeds`; 0 when
    none was: nothing to slow from), or below a known stop's floor? Its speed
    sigma cannot refuse a steady crawl where the fixes are poor (a 2 m/s robot through 5 m
    phone fixes: 0.5 m/s sigma, 2.5 m/s allowed; false stops after its first turn, the
    forward EKF 24 m off) nor in dead reckoning, where the speed cap decides (a 1 m/s crawl
    held still through a whole outage); a vehicle braking to a stop integrates the braking
    to well below half its speed before the IMU is quiet for a second."""
    if recent_peak <= 0.0:
        return True  # no speed it knew to be above zero: nothing to slow down from
    return speed < max(STOP_SPEED_FLOOR_M_PER_S, 0.5 * recent_peak)


class RecentSpeeds:
    """A causal estimate's speeds over the last ``SLOWDOWN_WINDOW_S`` (for
    :func:`slowed_to_a_stop`): :meth:`add` after each update, :meth:`peak` before the next."""

    def __init__(self, window_s: float = SLOWDOWN_WINDOW_S) -> None:
        self._window_s = window_s
        self._items: deque[tuple[float, float]] = deque()

    def add(self, t: float, speed: float, sigma: float | None = None) -> None:
        """The speed after an update, with its sigma when known. A speed within
        ``PEAK_SPEED_SIGMAS`` of its sigma of zero is kept as 0: an estimate at rest whose
        fixes have no velocity swings to 0.3-0.6 m/s in its first seconds, and a slow-down
        from such a "peak" refused the real stop at the start (the urban car's first 2-10 s)."""
        if sigma is not None and np.isfinite(sigma) and speed <= PEAK_SPEED_SIGMAS * sigma:
            speed = 0.0
        self._items.append((float(t), float(speed)))
        while self._items and self._items[-1][0] - self._items[0][0] > self._window_s:
            self._items.popleft()

    def peak(self) -> float:
        """The largest speed kept (0 before any: at the start there is nothing to slow from)."""
        return max((speed for _, speed in self._items), default=0.0)


PEAK_SPEED_SIGMAS = 3.0


# A Kalman filter's speed sigma confirms stops only this soon after a GNSS update: dead
# reckoning in an outage, a filter can be far more sure of its speed than it should be (0.1
# m/s sigma, 1 m/s off), and refusing real stops then lets it drift away; later the speed
# cap alone decides.
FILTER_STOP_SIGMA_AIDED_S = 2.0


def filter_stop_sigma(velocity_cov: np.ndarray, since_fix_s: float) -> float | None:
    """The speed sigma a Kalman filter confirms a stop with (:func:`speed_confirms_stop`):
    its covariance's while GNSS anchors it, None (the cap alone) after
    ``FILTER_STOP_SIGMA_AIDED_S`` of dead reckoning."""
    return speed_sigma(velocity_cov) if since_fix_s <= FILTER_STOP_SIGMA_AIDED_S else None


def speed_sigma(velocity_cov: np.ndarray) -> float:
    """The largest sigma (m/s) of a velocity covariance (3, 3): the speed's, whatever its
    direction (at a stop the direction of the estimated velocity is noise); NaN if unknown."""
    cov = np.asarray(velocity_cov, dtype=float)
    if not np.all(np.isfinite(cov)):
        return float("nan")
    return float(np.sqrt(max(float(np.max(np.linalg.eigvalsh(0.5 * (cov + cov.T)))), 0.0)))


STEADY_T_LIMIT = 4.0  # two-sample t statistic above which a window's halves differ


def window_stats(
    signal: np.ndarray, lo: np.ndarray, hi: np.ndarray, ddof: int
) -> tuple[np.ndarray, np.ndarray]:
    """Mean and variance (K, 3) of ``signal`` (N, 3) over the sample windows ``[lo, hi)``
    (overlapping allowed; NaN where a window has fewer than ddof + 1 samples).

    Window sums by ``np.add.reduceat`` (each window summed on its own: no cumulative-sum
    cancellation over a long drive), taken about each window's first sample so that the
    variance E[x^2] - E[x]^2 is one of small numbers (a stop's scatter about its own level).
    O(N + K), no Python loop per window.
    """
    n, width = signal.shape
    if len(lo) == 0 or n == 0:
        empty = np.full((len(lo), width), np.nan)
        return empty, empty
    lo = np.minimum(lo, n)
    hi = np.minimum(hi, n)
    count = (hi - lo).astype(float)[:, None]
    padded = np.vstack([signal, np.zeros((1, width))])
    bounds = np.empty(2 * len(lo), dtype=np.int64)
    bounds[0::2], bounds[1::2] = lo, hi
    # reduceat sums [bounds[i], bounds[i+1]): the even slots are the windows.
    sums = np.add.reduceat(padded, bounds, axis=0)[0::2]
    sums_sq = np.add.reduceat(padded**2, bounds, axis=0)[0::2]
    centre = padded[lo]
    total = sums - count * centre  # sum(x - c)
    total_sq = sums_sq - 2.0 * centre * sums + count * centre**2  # sum((x - c)^2)
    empty = count[:, 0] <= 0
    total[empty], total_sq[empty] = 0.0, 0.0
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_rel = total / count
        var = np.maximum(total_sq - count * mean_rel**2, 0.0) / (count - ddof)
    var[count[:, 0] - ddof <= 0] = np.nan
    mean = mean_rel + centre
    mean[empty] = np.nan
    return mean, var


def steady_imu(
    imu_t: np.ndarray,
    signals: list[np.ndarray],
    times: np.ndarray,
    before_s: float,
    after_s: float = 0.0,
) -> np.ndarray:
    """True where no signal (N, 3) trends within ``[t - before_s, t + after_s)``.

    For every axis, the difference of the means of the window's two halves is compared with
    its standard error from the window's own sample scatter (a two-sample t statistic), so
    vibration at rest does not count as motion while a ramp of any size does: a smooth start
    from rest has tiny scatter but is not a stop. Vectorised over the windows (in chunks of
    bounded memory), no Python loop per window.
    """
    times = np.asarray(times, dtype=float)
    lo = np.searchsorted(imu_t, times - before_s)
    hi = np.searchsorted(imu_t, times + after_s)
    steady = np.ones(len(times), dtype=bool)
    if len(times) == 0 or len(imu_t) == 0:
        return steady
    half = (hi - lo) // 2
    judged = half >= 2  # too short to judge: the quiet test already refuses such windows
    trending = np.zeros(len(times), dtype=bool)
    with np.errstate(invalid="ignore", divide="ignore"):
        for signal in signals:
            first_mean, first_var = window_stats(signal, lo, lo + half, 1)
            second_mean, second_var = window_stats(signal, hi - half, hi, 1)
            spread = np.sqrt((first_var + second_var) / half[:, None])
            difference = np.abs(second_mean - first_mean)
            # Exactly constant signals (synthetic, noise-free data) have zero spread: steady.
            trending |= np.any(difference > STEADY_T_LIMIT * spread + 1e-12, axis=1)
    steady[judged & trending] = False
    return steady


def quiet_imu(
    imu: ImuData,
    times: np.ndarray,
    noise: ImuNoise,
    *,
    before_s: float = 0.5,
    after_s: float = 0.5,
    require_steady: bool = True,
    use_gyro: bool = True,
) -> np.ndarray:
    """True where the IMU shows no motion within ``[t - before_s, t + after_s)`` of each time.

    Thresholds sit well above the sensor's own white noise at its sample rate and below what
    a moving road vehicle's vibration gives; with ``require_steady`` the window must also
    show no trend (:func:`steady_imu`). Vectorised over the windows (bounded-memory chunks).

    ``use_gyro=False`` judges by the accelerometers alone: for rates derived from an
    accelerometer array, which at rest ramp with the integrated angular-acceleration bias
    (a trend and a mean no bias prior allows), so a stop would never be seen by them. A
    steady straight run then also looks quiet: the caller must confirm every stop by speed.
    """
    rate = imu.rate_hz
    gyro_threshold = max(4.0 * noise.gyro_noise * np.sqrt(rate), 0.005)
    accel_threshold = max(4.0 * noise.accel_noise * np.sqrt(rate), 0.05)
    turn_threshold = max(TURN_BIAS_SIGMAS * noise.gyro_bias_prior, 0.01)
    times = np.asarray(times, dtype=float)
    lo = np.searchsorted(imu.t, times - before_s)
    hi = np.searchsorted(imu.t, times + after_s)
    if len(times) == 0 or len(imu.t) == 0:
        return np.zeros(len(times), dtype=bool)
    gyro_mean, gyro_var = window_stats(imu.gyro, lo, hi, 0)
    _, accel_var = window_stats(imu.accel, lo, hi, 0)
    with np.errstate(invalid="ignore"):
        # A steady turn is smooth too: the mean rate must be no more than a bias could give.
        quiet = (hi - lo >= MIN_QUIET_SAMPLES) & (np.sqrt(accel_var).max(axis=1) < accel_threshold)
        if use_gyro:
            quiet &= (np.sqrt(gyro_var).max(axis=1) < gyro_threshold) & ~(
                np.linalg.norm(gyro_mean, axis=1) > turn_threshold
            )
    if require_steady:
        signals = [imu.accel, imu.gyro] if use_gyro else [imu.accel]
        quiet &= steady_imu(imu.t, signals, times, before_s, after_s)
    return quiet


def mean_gyro(
    imu: ImuData, times: np.ndarray, *, before_s: float, after_s: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Mean gyro reading (N, 3) and sample count (N,) within ``[t - before_s, t + after_s)``
    (NaN rows where the window is empty): the zero-angular-rate measurement at a stop."""
    return _window_mean(imu.t, imu.gyro, times, before_s, after_s)


def mean_accel(
    imu: ImuData, times: np.ndarray, *, before_s: float, after_s: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Mean accelerometer reading (N, 3) and sample count (N,) over the same windows as
    :func:`mean_gyro`: at a stop, gravity's reaction alone (see :func:`level_force_allows_stop`)."""
    return _window_mean(imu.t, imu.accel, times, before_s, after_s)


# A vehicle at rest does not accelerate: its specific force, levelled by the estimate's
# attitude, has no horizontal part beyond the attitude's and the accelerometer bias's errors
# (0.2 deg and 10 mg: 0.13 m/s^2). Braking steadily reads as "quiet" as a stop (no spread, no
# trend): a car braking at 1.33 m/s^2 in an outage was stopped by the Kalman baselines at
# 0.64 m/s (position jumped 5.5 m, EKF+RTS 3.4 m against 0.84 without stops, NEES 15-30).
STOP_MAX_LEVEL_FORCE_M_S2 = 0.3


def level_force_allows_stop(rotation: np.ndarray, mean_specific_force: np.ndarray) -> bool:
    """Is the window's mean specific force (IMU axes, bias removed), turned into the
    navigation frame by ``rotation`` (body -> ENU), level-free enough for a stop?"""
    if not np.all(np.isfinite(mean_specific_force)):
        return True  # no samples to judge by: the other tests decide
    level = np.asarray(rotation) @ np.asarray(mean_specific_force)
    return bool(np.hypot(level[0], level[1]) < STOP_MAX_LEVEL_FORCE_M_S2)


def _window_mean(
    t: np.ndarray, values: np.ndarray, times: np.ndarray, before_s: float, after_s: float
) -> tuple[np.ndarray, np.ndarray]:
    times = np.asarray(times, dtype=float)
    lo = np.searchsorted(t, times - before_s)
    hi = np.searchsorted(t, times + after_s)
    cumulative = np.vstack([np.zeros((1, 3)), np.cumsum(values, axis=0)])
    count = hi - lo
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (cumulative[hi] - cumulative[lo]) / count[:, None]
    mean[count == 0] = np.nan
    return mean, count


def pressure_at(
    baro: BaroData | None,
    times: np.ndarray,
    *,
    before_s: float = 0.25,
    after_s: float = 0.25,
) -> np.ndarray:
    """Mean barometric pressure (Pa) within ``[t - before_s, t + after_s)`` (NaN where none)."""
    times = np.asarray(times, dtype=float)
    out = np.full(len(times), np.nan)
    if baro is None or baro.pressure is None:
        return out
    valid = np.isfinite(baro.pressure) & (baro.pressure > 0.0)  # non-positive: no reading
    if not np.any(valid):
        return out
    t, pressure = baro.t[valid], baro.pressure[valid]
    lo = np.searchsorted(t, times - before_s)
    hi = np.searchsorted(t, times + after_s)
    cumulative = np.concatenate([[0.0], np.cumsum(pressure)])
    filled = hi > lo
    out[filled] = (cumulative[hi[filled]] - cumulative[lo[filled]]) / (hi - lo)[filled]
    return out


def pressure_before(baro: BaroData | None, times: np.ndarray, window_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(mean barometric pressure (Pa) of the samples within ``[t - window_s, t]``, how long
    before ``t`` their mean time lies (s)); NaN where none. What a causal filter can use at
    ``t``: the mean's age is a lag it must take out (a 0.25 s mean is 0.1 s old, 1 m in a
    10 m/s climb)."""
    times = np.asarray(times, dtype=float)
    pressure_out, age = np.full(len(times), np.nan), np.full(len(times), np.nan)
    if baro is None or baro.pressure is None:
        return pressure_out, age
    valid = np.isfinite(baro.pressure) & (baro.pressure > 0.0)
    if not np.any(valid):
        return pressure_out, age
    t, pressure = baro.t[valid], baro.pressure[valid]
    lo = np.searchsorted(t, times - window_s)
    hi = np.searchsorted(t, times, side="right")
    filled = hi > lo
    count = (hi - lo)[filled]
    # (times about the first sample: sums of POSIX times would keep ~0.01 s of a mean)
    for values, out in ((pressure, pressure_out), (t - t[0], age)):
        cumulative = np.concatenate([[0.0], np.cumsum(values)])
        out[filled] = (cumulative[hi[filled]] - cumulative[lo[filled]]) / count
    age[filled] = (times[filled] - t[0]) - age[filled]
    return pressure_out, age


# International Standard Atmosphere, troposphere (ICAO; below 11 km): the model a real
# barometer's pressure follows on a standard day, and the one fgins's simulator writes.
ISA_SEA_LEVEL_PA = 101325.0
ISA_LAPSE_COEFFICIENT_PER_M = 2.25577e-5  # lapse rate / sea-level temperature
ISA_EXPONENT = 5.25588


def standard_atmosphere_height(pressure_pa: float | np.ndarray) -> np.ndarray:
    """Height (m above mean sea level) of a pressure in the ISA troposphere.

    GTSAM's BarometricFactor has its own constants (288.08 K, 101.29 kPa, 5.256, 6.49 K/km),
    whose height scale is 0.13 % off the ISA's: 1.3 m per km of climb, which a flight's
    barometer turned into a vertical error of 3 sigma (outside tester). The graph feeds it
    :func:`gtsam_equivalent_kpa` instead, so every estimator uses this height.
    """
    ratio = np.asarray(pressure_pa, dtype=float) / ISA_SEA_LEVEL_PA
    return (1.0 - np.power(ratio, 1.0 / ISA_EXPONENT)) / ISA_LAPSE_COEFFICIENT_PER_M


def standard_atmosphere_pressure(height_m: float | np.ndarray) -> np.ndarray:
    """Pressure (Pa) at an ISA troposphere height: the inverse of
    :func:`standard_atmosphere_height`."""
    base = 1.0 - ISA_LAPSE_COEFFICIENT_PER_M * np.asarray(height_m, dtype=float)
    return ISA_SEA_LEVEL_PA * np.power(base, ISA_EXPONENT)


def pressure_in_plane(pressure_pa: np.ndarray, fall_m: np.ndarray) -> np.ndarray:
    """Pressure as if taken ``fall_m`` lower: a height above the surface made a height in
    the navigation frame, whose tangent plane falls d^2 / 2R below the surface d from the
    origin (7.8 m 10 km out), while a barometer's height stays with the surface."""
    height = standard_atmosphere_height(pressure_pa) - np.asarray(fall_m, dtype=float)
    return standard_atmosphere_pressure(height)


def plane_fall_along_fixes(
    times: np.ndarray, gnss_t: np.ndarray, gnss_enu: np.ndarray, origin: Origin
) -> np.ndarray:
    """:func:`fgins.geodesy.plane_fall` at ``times`` on the fixes' track (interpolated): the
    start before a solution exists. Across a long outage the chord between fixes can cut a
    turn by a kilometre (d x 1 km / R: 5 m 32 km out), so the solvers redo it at their
    solution's positions (:meth:`fgins.graph.problem.Problem.baro_fall_moved`)."""
    if not len(gnss_t):
        return np.zeros(len(times))
    track = np.column_stack([np.interp(times, gnss_t, gnss_enu[:, j]) for j in range(3)])
    return plane_fall(track, origin)


def gtsam_equivalent_kpa(pressure_pa: float | np.ndarray) -> np.ndarray:
    """The pressure (kPa) whose height in GTSAM's BarometricFactor (``heightOut``) is the ISA
    height of ``pressure_pa``: the inverse of ``(pow(p / 101.29, 1 / 5.256) * 288.08 -
    288.14) / -0.00649`` at :func:`standard_atmosphere_height`."""
    height = standard_atmosphere_height(pressure_pa)
    return 101.29 * np.power((288.14 - 0.00649 * height) / 288.08, 5.256)
