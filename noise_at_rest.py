"""The IMU's white noise as the data show it at rest, against the configured one (numpy only).

A datasheet's noise densities are those of the sensor on a quiet bench. Mounted in a vehicle
the IMU also reads the engine's and the road's vibration, and a configuration may simply
name the wrong sensor. Nothing in a fit to metre-level fixes at 1 Hz shows it (chi2/dof 0.91
with 20 times the configured accelerometer noise in the data: the fixes absorb it), but
inside an outage the reported sigmas are then several times too small, and the smoother
trusts the IMU more than it deserves (independent simulator, a car whose accelerometers read
0.03 m/s^2/sqrt(Hz) against an industrial datasheet's 0.0017: batch 1.25 m inside outages at
2.6 times its sigma; with the measured noise 0.76 m at 0.8 times its sigma).

So the noise is measured where it can be: wherever the fixes hold still and the IMU shows no
trend (:func:`fgins.factors.stationary.steady_imu`, which judges each window by its own
scatter, not by the configured noise). Over such stretches the Allan variance at a short
averaging time ``tau`` is the white noise alone (a bias does not move in ``tau``; gravity and
the earth's rate cancel in the differences; narrow-band vibration well above ``1/tau``
averages out): ``density = sqrt(AVAR(tau) * tau)``. The median of the squared differences
(scaled to their mean for a Gaussian) keeps a door slam or a passing truck from counting.

It is a floor: a vehicle vibrates more while it moves than at a stop. A measured density
more than :data:`NOISE_EXCESS` times the configured one replaces it (and is said); a smaller
one never does, since a datasheet that is pessimistic costs little and one that is
optimistic makes every sigma a lie.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgins.datatypes import Dataset
from fgins.factors.stationary import (
    gnss_chord,
    gnss_moving,
    mean_accel,
    mean_gyro,
    steady_imu,
    window_stats,
)

# Averaging time (the triangle spans twice it): the keyframe intervals' scale, which the
# preintegration integrates over, well above a vehicle's vibration periods, far below the
# time over which a bias moves.
TAU_S = 0.5
WINDOW_S = 2.0  # judged rest windows, centred every WINDOW_S / 2
MIN_DIFFERENCES = 6  # independent second differences (9 s at rest): the density to ~+-25 %
# Measured over configured beyond which the measured noise is used. Datasheet values are
# typical, and the estimate scatters: only a clear excess counts (drives simulated with the
# configured noise measure 0.86-1.12; 10 s at rest, 240 seeds, 0.70-1.59).
NOISE_EXCESS = 2.5
# The IMU's scatter about its mean over a rest window beyond which it is not at rest (a gait's
# swing: 4 m/s^2 and 0.66 rad/s RMS; a car idling: 0.04-0.2 m/s^2, 0.002 rad/s).
REST_MAX_ACCEL_RMS_M_S2 = 1.0
REST_MAX_GYRO_RMS_RAD_S = 0.3
SWING_AVERAGE_S = 0.25
# Median of a chi-square with one degree of freedom: median(d^2) / this estimates E[d^2].
CHI2_1_MEDIAN = 0.4549364231195724


@dataclass(frozen=True)
class RestNoise:
    """White-noise densities measured at rest (rad/s/sqrt(Hz), m/s^2/sqrt(Hz); None where the
    sensor was not measured) and how much rest they come from."""

    gyro: float | None
    accel: float
    rest_s: float


def rest_mask(dataset: Dataset, gnss_mask: np.ndarray | None = None) -> np.ndarray:
    """True (per IMU sample) inside windows where the IMU shows no trend and fixes on both
    sides held still (never where no fixes can tell, such as an outage or a flight)."""
    imu, gnss = dataset.imu, dataset.gnss
    mask = np.zeros(len(imu.t), dtype=bool)
    if gnss is None or len(gnss.t) < 2 or len(imu.t) < 2:
        return mask
    keep = np.ones(len(gnss.t), dtype=bool) if gnss_mask is None else np.asarray(gnss_mask, bool)
    enu = dataset.gnss_enu()[keep]
    fix_t = gnss.t[keep]
    good = np.all(np.isfinite(enu), axis=1)
    fix_t, enu = fix_t[good], enu[good]
    if len(fix_t) < 2:
        return mask
    sigma = np.full_like(enu, 3.0) if gnss.std is None else gnss.std[keep][good]
    sigma = np.where(np.isfinite(sigma) & (sigma > 0), sigma, 3.0)
    half = WINDOW_S / 2
    centres = np.arange(imu.t[0] + half, imu.t[-1] - half, half)
    if len(centres) == 0:
        return mask
    steady = steady_imu(imu.t, [imu.accel, imu.gyro], centres, half, half)
    # A walker's or a handheld device's gait has no trend either (a periodic swing), and
    # 1.3 m/s with 2-2.5 m fixes is still to them: its 2 Hz steps (+-2-4 m/s^2, 40-90 deg/s)
    # were read as 23-32 times the configured white noise and used, outages 4-8x worse
    # (outside tester). No vehicle at rest swings that much: an idling engine's vibration
    # is a few tenths of a m/s^2.
    # Over SWING_AVERAGE_S running means, which keep a 1-3 Hz gait and average out an
    # engine's 8-50 Hz vibration (2 m/s^2 of it at rest is vibration, not motion).
    lo = np.searchsorted(imu.t, centres - half)
    hi = np.searchsorted(imu.t, centres + half)
    swing = SWING_AVERAGE_S / 2
    _, accel_var = window_stats(mean_accel(imu, imu.t, before_s=swing, after_s=swing)[0], lo, hi, 1)
    _, gyro_var = window_stats(mean_gyro(imu, imu.t, before_s=swing, after_s=swing)[0], lo, hi, 1)
    with np.errstate(invalid="ignore"):
        swinging = (np.sqrt(np.sum(accel_var, axis=1)) > REST_MAX_ACCEL_RMS_M_S2) | (
            np.sqrt(np.sum(gyro_var, axis=1)) > REST_MAX_GYRO_RMS_RAD_S
        )
    steady &= ~swinging
    # The fixes of the 4 s up to the window's end moved no more than their noise, and they
    # cover the window (gnss_moving says "not moving" where it cannot tell).
    window = 2 * WINDOW_S
    still = ~gnss_moving(centres + half, fix_t, enu, sigma, window_s=window)
    first, _, covered = gnss_chord(centres + half, fix_t, window)
    covered &= fix_t[first] <= centres - half + 1.0
    rest = centres[steady & still & covered]
    lo = np.searchsorted(imu.t, rest - half)
    hi = np.searchsorted(imu.t, rest + half)
    # Mark the windows by a difference array: O(N + K).
    marks = np.zeros(len(imu.t) + 1, dtype=int)
    np.add.at(marks, lo, 1)
    np.add.at(marks, hi, -1)
    return np.cumsum(marks[:-1]) > 0


def _density(samples: np.ndarray, t: np.ndarray, at_rest: np.ndarray, m: int,
             rate: float) -> float | None:  # fmt: skip
    """RMS over the axes of the white-noise density from the second differences of three
    consecutive triangle-weighted means (two m-sample box means in a row, convolved: span
    2 m - 1), taken at every sample where all three lie at rest and come without a gap.
    The second difference cancels a steady trend (a ramp of 0.005 m/s^3 from a gentle
    start, which a first difference read as 1.8 times an industrial accelerometer's noise).

    A box mean lets a sinusoid of frequency f leak through at 1 / (pi f tau) of its
    amplitude (a 1 m/s^2 engine vibration at 23 Hz: up to 0.028 m/s^2 in 0.5 s means, which
    reads as 17 times an industrial accelerometer's noise); the triangle's response is that
    squared (0.0008). For white noise of density q, Var(second difference) = 6 q^2 rate sum(w^2)."""
    n = len(samples)
    span = 2 * m - 1
    if n < 2 * span + 2:
        return None
    weights = np.convolve(np.ones(m), np.ones(m)) / m**2
    centred = samples - np.median(samples, axis=0)  # small sums: no cancellation over a log
    total = np.vstack([np.zeros((1, samples.shape[1])), np.cumsum(centred, axis=0)])
    box = (total[m:] - total[:-m]) / m  # box[i]: mean of samples i .. i + m - 1
    box_total = np.vstack([np.zeros((1, samples.shape[1])), np.cumsum(box, axis=0)])
    triangle = (box_total[m:] - box_total[:-m]) / m  # [i]: samples i .. i + span - 1
    step = span + 1  # the next triangle starts one sample after one ends
    start = np.arange(len(triangle) - 2 * step)
    resting = np.concatenate([[0], np.cumsum(~at_rest)])
    end = start + 2 * step + span
    valid = (resting[end] == resting[start]) & (
        np.abs(t[end - 1] - t[start] - (end - 1 - start) / rate) < 0.25 * m / rate
    )
    if int(valid.sum()) < MIN_DIFFERENCES * span:  # overlapping: ~span per independent one
        return None
    second = triangle[start] - 2.0 * triangle[start + step] + triangle[start + 2 * step]
    variance = np.median(second[valid] ** 2, axis=0) / CHI2_1_MEDIAN  # E[second^2] per axis
    return float(np.sqrt(np.mean(variance / (6.0 * rate * np.sum(weights**2)))))


def white_noise_at_rest(dataset: Dataset, gnss_mask: np.ndarray | None = None) -> RestNoise | None:
    """The IMU's white noise measured at rest (see the module docstring), or None when the
    log has too little rest, or samples too sparse, to tell."""
    imu = dataset.imu
    if len(imu.t) < 2 or dataset.accel_array is not None:
        return None  # an accelerometer array's derived rates have a noise model of their own
    rate = float(imu.rate_hz)
    if not np.isfinite(rate) or round(TAU_S * rate) < 2:
        return None
    m = round(TAU_S * rate)
    at_rest = rest_mask(dataset, gnss_mask)
    if not at_rest.any():
        return None
    accel = _density(imu.accel, imu.t, at_rest, m, rate)
    if accel is None:
        return None
    gyro = _density(imu.gyro, imu.t, at_rest, m, rate)
    return RestNoise(gyro=gyro, accel=accel, rest_s=float(at_rest.sum()) / rate)


def noise_excess(measured: RestNoise, gyro_noise: float, accel_noise: float) -> dict[str, float]:
    """``{"gyro": density, "accel": density}`` for each sensor whose measured white noise
    exceeds the configured one by more than :data:`NOISE_EXCESS` (empty when none does)."""
    excess: dict[str, float] = {}
    if measured.gyro is not None and measured.gyro > NOISE_EXCESS * gyro_noise:
        excess["gyro"] = measured.gyro
    if measured.accel > NOISE_EXCESS * accel_noise:
        excess["accel"] = measured.accel
    return excess
