"""Simulated accelerometer-array readings (the inverse of the gyro-free front end) and grades.

reading_j = (1 + s_j) * A_j(truth) + b_j + white_j, with A_j the exact model of
:class:`fgins.factors.accel_array.AccelArray`, turn-on bias b_j and scale factor s_j drawn once
per accelerometer and reduced to their post-calibration residual (10 % of the raw draw), and
white noise of the grade's density held over each sample interval. All randomness comes from
the caller's seeded numpy Generator.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgins.datatypes import InputError
from fgins.factors.accel_array import AccelArray

MICRO_G = 9.80665e-6  # m/s^2
CALIBRATION_RESIDUAL = 0.1  # fraction of turn-on bias / scale factor left after calibration


@dataclass(frozen=True)
class ArrayGrade:
    """Accelerometer grade: 1-sigma turn-on bias (ug), scale factor (ppm), noise (ug/sqrt(Hz))."""

    name: str
    bias_ug: float
    scale_factor_ppm: float
    noise_ug_per_sqrt_hz: float

    @property
    def bias(self) -> float:
        """Raw turn-on bias sigma, m/s^2 (before calibration)."""
        return self.bias_ug * MICRO_G

    @property
    def scale_factor(self) -> float:
        """Raw scale-factor sigma, dimensionless (before calibration)."""
        return self.scale_factor_ppm * 1e-6

    @property
    def noise_density(self) -> float:
        """White-noise density, m/s^2/sqrt(Hz)."""
        return self.noise_ug_per_sqrt_hz * MICRO_G

    @property
    def residual_bias(self) -> float:
        """Bias sigma left after calibration, m/s^2 (what the estimator must live with)."""
        return CALIBRATION_RESIDUAL * self.bias


GRADES: dict[str, ArrayGrade] = {
    grade.name: grade
    for grade in (
        ArrayGrade("navigation", bias_ug=250.0, scale_factor_ppm=50.0, noise_ug_per_sqrt_hz=5.0),
        ArrayGrade("tactical", bias_ug=1000.0, scale_factor_ppm=300.0, noise_ug_per_sqrt_hz=200.0),
        ArrayGrade(
            "automotive", bias_ug=20000.0, scale_factor_ppm=2000.0, noise_ug_per_sqrt_hz=325.0
        ),
    )
}


def resolve_grade(grade: str | ArrayGrade) -> ArrayGrade:
    """A grade by name, or the given :class:`ArrayGrade` unchanged."""
    if isinstance(grade, ArrayGrade):
        return grade
    if grade not in GRADES:
        raise InputError(
            f"unknown accelerometer grade {grade!r}; choose one of {', '.join(GRADES)}"
        )
    return GRADES[grade]


@dataclass(frozen=True)
class ArrayErrors:
    """Per-accelerometer residual bias (m/s^2) and scale factor (dimensionless), each (N,)."""

    bias: np.ndarray
    scale_factor: np.ndarray


def draw_array_errors(
    rng: np.random.Generator, n_sensors: int, grade: str | ArrayGrade
) -> ArrayErrors:
    """Post-calibration errors: raw turn-on draws of the grade, times the 10 % residual."""
    spec = resolve_grade(grade)
    bias = rng.standard_normal(n_sensors) * spec.bias * CALIBRATION_RESIDUAL
    scale = rng.standard_normal(n_sensors) * spec.scale_factor * CALIBRATION_RESIDUAL
    return ArrayErrors(bias=bias, scale_factor=scale)


def array_readings(
    array: AccelArray,
    t: np.ndarray,
    gyro_true: np.ndarray,
    accel_true: np.ndarray,
    rng: np.random.Generator,
    grade: str | ArrayGrade,
    *,
    angular_acceleration: np.ndarray | None = None,
    errors: ArrayErrors | None = None,
) -> np.ndarray:
    """Readings (T, N) of ``array`` for true rate (T, 3, rad/s) and specific force at the
    array centre (T, 3, m/s^2), both in the body frame, at times t (T,).

    The angular acceleration is the time derivative of ``gyro_true`` (second-order finite
    differences) unless given exactly. ``errors`` fixes the per-sensor bias/scale factor
    (default: drawn from ``grade`` with ``rng``).
    """
    t = np.asarray(t, dtype=float)
    gyro_true = np.asarray(gyro_true, dtype=float)
    accel_true = np.asarray(accel_true, dtype=float)
    n_samples = t.shape[0] if t.ndim == 1 else -1
    if n_samples < 3:
        raise InputError(f"array_readings: t must be 1-D with at least 3 samples, got {t.shape}")
    for name, value in (("gyro_true", gyro_true), ("accel_true", accel_true)):
        if value.shape != (n_samples, 3):
            raise InputError(f"array_readings: {name} must be ({n_samples}, 3), got {value.shape}")
    if not np.all(np.diff(t) > 0):
        raise InputError("array_readings: timestamps must be strictly increasing")
    spec = resolve_grade(grade)
    if angular_acceleration is None:
        angular_acceleration = np.gradient(gyro_true, t, axis=0, edge_order=2)
    angular_acceleration = np.asarray(angular_acceleration, dtype=float)
    if angular_acceleration.shape != (n_samples, 3):
        raise InputError("array_readings: angular_acceleration must match gyro_true's shape")
    if errors is None:
        errors = draw_array_errors(rng, len(array), spec)
    if errors.bias.shape != (len(array),) or errors.scale_factor.shape != (len(array),):
        raise InputError(f"array_readings: errors must hold {len(array)} values each")
    exact = array.exact_readings(accel_true, angular_acceleration, gyro_true)
    # White noise of density d held over each sample interval has std d / sqrt(dt).
    dt = np.gradient(t)
    noise = rng.standard_normal(exact.shape) * (spec.noise_density / np.sqrt(dt))[:, None]
    return exact * (1.0 + errors.scale_factor) + errors.bias + noise
