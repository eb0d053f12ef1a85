"""IMU error models: white noise, turn-on bias, bias random walk, scale factor.

measured = (1 + scale) * true + bias(t) + white, with
  white_k ~ N(0, density^2 * rate)          (density in unit/sqrt(Hz): ARW / VRW)
  bias_k+1 = bias_k + N(0, rw^2 * dt)        (rw in unit/sqrt(s))
  bias_0 = turn-on bias (given, or drawn from N(0, turn_on_sigma^2) per axis).
The additive bias history is the truth's gyro_bias / accel_bias (the scale factor is not part
of it). All randomness comes from the caller's seeded numpy Generator.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fgins.config import ImuNoise
from fgins.datatypes import InputError


@dataclass(frozen=True)
class SensorErrors:
    """Error model of one triad (gyro or accel), SI units."""

    noise_density: float = 0.0
    bias_rw: float = 0.0
    turn_on_sigma: float = 0.0
    turn_on_bias: tuple[float, float, float] | None = None
    scale_factor: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if min(self.noise_density, self.bias_rw, self.turn_on_sigma) < 0:
            raise InputError("IMU error model: densities and sigmas must be >= 0")


@dataclass(frozen=True)
class ImuErrorModel:
    """Gyro (rad/s) and accelerometer (m/s^2) error models."""

    gyro: SensorErrors = field(default_factory=SensorErrors)
    accel: SensorErrors = field(default_factory=SensorErrors)

    @classmethod
    def from_noise(
        cls,
        noise: ImuNoise,
        *,
        gyro_bias: tuple[float, float, float] | None = None,
        accel_bias: tuple[float, float, float] | None = None,
        bias_random_walk: bool = True,
    ) -> ImuErrorModel:
        """From :class:`fgins.config.ImuNoise`; fixed turn-on biases optional."""
        return cls(
            gyro=SensorErrors(
                noise_density=noise.gyro_noise,
                bias_rw=noise.gyro_bias_rw if bias_random_walk else 0.0,
                turn_on_sigma=noise.gyro_bias_prior,
                turn_on_bias=gyro_bias,
            ),
            accel=SensorErrors(
                noise_density=noise.accel_noise,
                bias_rw=noise.accel_bias_rw if bias_random_walk else 0.0,
                turn_on_sigma=noise.accel_bias_prior,
                turn_on_bias=accel_bias,
            ),
        )


def white_noise(rng: np.random.Generator, n: int, density: float, dt: float) -> np.ndarray:
    """(n, 3) samples of white noise of the given density held over ``dt``."""
    return rng.standard_normal((n, 3)) * (density / np.sqrt(dt))


def bias_history(rng: np.random.Generator, n: int, errors: SensorErrors, dt: float) -> np.ndarray:
    """(n, 3) bias: turn-on value plus a random walk of density ``errors.bias_rw``."""
    if errors.turn_on_bias is not None:
        start = np.asarray(errors.turn_on_bias, dtype=float)
    else:
        start = rng.standard_normal(3) * errors.turn_on_sigma
    steps = rng.standard_normal((n - 1, 3)) * (errors.bias_rw * np.sqrt(dt))
    return start + np.vstack([np.zeros((1, 3)), np.cumsum(steps, axis=0)])


def corrupt_triad(
    rng: np.random.Generator, true: np.ndarray, errors: SensorErrors, dt: float
) -> tuple[np.ndarray, np.ndarray]:
    """Measured samples and the additive bias history for one triad."""
    n = len(true)
    bias = bias_history(rng, n, errors, dt)
    measured = true * (1.0 + np.asarray(errors.scale_factor)) + bias
    return measured + white_noise(rng, n, errors.noise_density, dt), bias


def apply_imu_errors(
    rng: np.random.Generator,
    gyro: np.ndarray,
    accel: np.ndarray,
    dt: float,
    model: ImuErrorModel,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Corrupt error-free samples: (gyro, accel, gyro_bias, accel_bias), each (N, 3)."""
    if dt <= 0:
        raise InputError(f"IMU error model: sample interval {dt} must be > 0")
    gyro_m, gyro_bias = corrupt_triad(rng, gyro, model.gyro, dt)
    accel_m, accel_bias = corrupt_triad(rng, accel, model.accel, dt)
    return gyro_m, accel_m, gyro_bias, accel_bias


def apply_imu_errors_in_axes(
    rng: np.random.Generator,
    gyro: np.ndarray,
    accel: np.ndarray,
    dt: float,
    model: ImuErrorModel,
    axes: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Like :func:`apply_imu_errors` for samples in IMU axes that ``axes`` maps into base axes.

    The errors (white noise, turn-on bias, random walk; given turn-on biases are in the base
    axes) are drawn in the base axes and rotated into the IMU's. The error model is isotropic
    (equal densities per axis, no scale factor), so this is the same distribution as drawing
    per IMU axis, and one seed is the same physical experiment whatever the IMU's axes: an
    estimator's result must not depend on the convention. ``axes`` None or identity: exactly
    :func:`apply_imu_errors`.
    """
    if axes is None or np.array_equal(axes, np.eye(3)):
        return apply_imu_errors(rng, gyro, accel, dt, model)
    if any(np.any(np.asarray(s.scale_factor) != 0.0) for s in (model.gyro, model.accel)):
        raise InputError("IMU error model: a scale factor needs the IMU's own axes (axes=None)")
    zeros = np.zeros_like(gyro)
    gyro_error, accel_error, gyro_bias, accel_bias = apply_imu_errors(rng, zeros, zeros, dt, model)
    a = np.asarray(axes, dtype=float)
    # Rows v_base -> v_imu = A^T v_base, i.e. row @ A.
    return gyro + gyro_error @ a, accel + accel_error @ a, gyro_bias @ a, accel_bias @ a
