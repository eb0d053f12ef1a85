"""Barometer model: standard-atmosphere pressure from the true height, with height-domain
white noise and a slowly drifting bias (weather, temperature)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgins.datatypes import BaroData, InputError

# International Standard Atmosphere, troposphere (valid below 11 km).
SEA_LEVEL_PRESSURE_PA = 101325.0
LAPSE_COEFFICIENT_PER_M = 2.25577e-5
PRESSURE_EXPONENT = 5.25588


def pressure_from_height(height_m: np.ndarray) -> np.ndarray:
    """ISA pressure (Pa) at a height above mean sea level (m)."""
    height_m = np.asarray(height_m, dtype=float)
    if np.any(height_m > 11000.0):
        raise InputError("barometer: height above 11 km is outside the troposphere model")
    return SEA_LEVEL_PRESSURE_PA * (1.0 - LAPSE_COEFFICIENT_PER_M * height_m) ** PRESSURE_EXPONENT


def height_from_pressure(pressure_pa: np.ndarray) -> np.ndarray:
    """Inverse of :func:`pressure_from_height`."""
    ratio = np.asarray(pressure_pa, dtype=float) / SEA_LEVEL_PRESSURE_PA
    return (1.0 - ratio ** (1.0 / PRESSURE_EXPONENT)) / LAPSE_COEFFICIENT_PER_M


@dataclass(frozen=True)
class BaroModel:
    """Sample rate, height white noise (m, 1 sigma), bias random walk (m/sqrt(s)), bias at 0."""

    rate_hz: float = 20.0
    noise_m: float = 0.3
    bias_rw_m_per_sqrt_s: float = 0.01
    initial_bias_m: float = 0.0

    def __post_init__(self) -> None:
        if self.rate_hz <= 0 or self.noise_m < 0 or self.bias_rw_m_per_sqrt_s < 0:
            raise InputError("barometer model: rate must be > 0, noise and drift >= 0")

    def config_table(self) -> dict[str, float]:
        return {
            "rate_hz": self.rate_hz,
            "noise_m": self.noise_m,
            "bias_rw_m_per_sqrt_s": self.bias_rw_m_per_sqrt_s,
        }


def simulate_baro(
    rng: np.random.Generator, t: np.ndarray, height_m: np.ndarray, model: BaroModel
) -> tuple[BaroData, np.ndarray]:
    """Barometer samples at ``model.rate_hz`` (on the times ``t`` of the true height series).

    Returns the data (pressure and the height it converts back to) and the bias history (m).
    """
    rate = 1.0 / float(np.median(np.diff(t)))
    step = round(rate / model.rate_hz)
    if step < 1 or abs(rate / model.rate_hz - step) > 1e-6 * step:
        raise InputError(f"barometer rate {model.rate_hz} Hz does not divide {rate:.6g} Hz")
    index = np.arange(0, len(t), step)
    dt = step / rate
    n = len(index)
    drift = np.cumsum(rng.standard_normal(n) * model.bias_rw_m_per_sqrt_s * np.sqrt(dt))
    bias = model.initial_bias_m + drift - drift[0]
    measured_height = height_m[index] + bias + rng.standard_normal(n) * model.noise_m
    pressure = pressure_from_height(measured_height)
    return BaroData(t=t[index], pressure=pressure, height=height_from_pressure(pressure)), bias
