"""Stop detection and barometer sampling on raw sensor streams (numpy only, no GTSAM).

Shared by the factor graph (:mod:`fgins.graph.problem`) and the Kalman baselines, so both
decide "the IMU is quiet" and "the pressure at this time" the same way. Windows are given as
``before_s``/``after_s`` around each query time: the graph looks both ways (it sees the
whole log), a causal filter only back.
"""

from __future__ import annotations

import numpy as np

from fgins.config import ImuNoise
from fgins.datatypes import BaroData, ImuData

MIN_QUIET_SAMPLES = 5


STEADY_T_LIMIT = 4.0  # two-sample t statistic above which a window's halves differ


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
    from rest has tiny scatter but is not a stop.
    """
    times = np.asarray(times, dtype=float)
    lo = np.searchsorted(imu_t, times - before_s)
    hi = np.searchsorted(imu_t, times + after_s)
    steady = np.ones(len(times), dtype=bool)
    for k, (a, b) in enumerate(zip(lo, hi, strict=True)):
        half = (b - a) // 2
        if half < 2:
            continue  # too short to judge; the quiet test already refuses such windows
        for signal in signals:
            first, second = signal[a : a + half], signal[b - half : b]
            spread = np.sqrt((first.var(axis=0, ddof=1) + second.var(axis=0, ddof=1)) / half)
            difference = np.abs(second.mean(axis=0) - first.mean(axis=0))
            # Exactly constant signals (synthetic, noise-free data) have zero spread: steady.
            if np.any(difference > STEADY_T_LIMIT * spread + 1e-12):
                steady[k] = False
                break
    return steady


def quiet_imu(
    imu: ImuData,
    times: np.ndarray,
    noise: ImuNoise,
    *,
    before_s: float = 0.5,
    after_s: float = 0.5,
    require_steady: bool = True,
) -> np.ndarray:
    """True where the IMU shows no motion within ``[t - before_s, t + after_s)`` of each time.

    Thresholds sit well above the sensor's own white noise at its sample rate and below what
    a moving road vehicle's vibration gives; with ``require_steady`` the window must also
    show no trend (:func:`steady_imu`).
    """
    rate = imu.rate_hz
    gyro_threshold = max(4.0 * noise.gyro_noise * np.sqrt(rate), 0.005)
    accel_threshold = max(4.0 * noise.accel_noise * np.sqrt(rate), 0.05)
    turn_threshold = max(3.0 * noise.gyro_bias_prior, 0.01)
    times = np.asarray(times, dtype=float)
    lo = np.searchsorted(imu.t, times - before_s)
    hi = np.searchsorted(imu.t, times + after_s)
    quiet = np.zeros(len(times), dtype=bool)
    for k, (a, b) in enumerate(zip(lo, hi, strict=True)):
        if b - a < MIN_QUIET_SAMPLES:
            continue
        gyro_std = imu.gyro[a:b].std(axis=0).max()
        accel_std = imu.accel[a:b].std(axis=0).max()
        # A steady turn is smooth too: the mean rate must be no more than a bias could give.
        turning = np.linalg.norm(imu.gyro[a:b].mean(axis=0)) > turn_threshold
        quiet[k] = gyro_std < gyro_threshold and accel_std < accel_threshold and not turning
    if require_steady:
        quiet &= steady_imu(imu.t, [imu.accel, imu.gyro], times, before_s, after_s)
    return quiet


def mean_gyro(
    imu: ImuData, times: np.ndarray, *, before_s: float, after_s: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """Mean gyro reading (N, 3) and sample count (N,) within ``[t - before_s, t + after_s)``
    (NaN rows where the window is empty): the zero-angular-rate measurement at a stop."""
    times = np.asarray(times, dtype=float)
    lo = np.searchsorted(imu.t, times - before_s)
    hi = np.searchsorted(imu.t, times + after_s)
    cumulative = np.vstack([np.zeros((1, 3)), np.cumsum(imu.gyro, axis=0)])
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


def standard_atmosphere_height(pressure_pa: float | np.ndarray) -> np.ndarray:
    """Height (m) of a pressure in GTSAM's standard atmosphere (BarometricFactor::heightOut).

    The same NASA Glenn troposphere model as :func:`fgins.factors.baro.standard_atmosphere_height`,
    here without importing GTSAM so that the Kalman baselines can use it.
    """
    kpa = np.asarray(pressure_pa, dtype=float) / 1000.0
    return (np.power(kpa / 101.29, 1.0 / 5.256) * 288.08 - 273.1 - 15.04) / -0.00649
