"""Barometer: height from pressure with a slowly varying bias state (GTSAM BarometricFactor).

GTSAM's factor takes pressure in kPa and its error is ``z + bias - h(p)`` with its own
standard-atmosphere height ``h``, fed the pressure that gives the ISA height
(:func:`fgins.factors.stationary.gtsam_equivalent_kpa`); the bias absorbs the origin's height and the weather, and
follows a random walk between keyframes.
"""

from __future__ import annotations

import gtsam
import numpy as np

from fgins.factors import stationary


def baro_key(k: int) -> int:
    return gtsam.symbol("z", int(k))


def pressure_factor(
    pose_key: int, bias_key: int, pressure_pa: float, sigma_m: float
) -> gtsam.BarometricFactor:
    return gtsam.BarometricFactor(
        pose_key,
        bias_key,
        float(stationary.gtsam_equivalent_kpa(pressure_pa)),
        gtsam.noiseModel.Isotropic.Sigma(1, sigma_m),
    )


def bias_walk_factor(
    key_a: int, key_b: int, dt: float, walk_m_per_sqrt_s: float
) -> gtsam.BetweenFactorDouble:
    sigma = max(walk_m_per_sqrt_s * np.sqrt(max(dt, 1e-6)), 1e-4)
    return gtsam.BetweenFactorDouble(key_a, key_b, 0.0, gtsam.noiseModel.Isotropic.Sigma(1, sigma))


def initial_bias(height_enu_m: float, pressure_pa: float) -> float:
    """Bias that makes the first pressure agree with the first height: h(p) - z."""
    return float(standard_atmosphere_height(pressure_pa) - height_enu_m)


def standard_atmosphere_height(pressure_pa: float | np.ndarray) -> float | np.ndarray:
    """ISA height of a pressure; one copy, in factors/stationary (GTSAM-free)."""
    return stationary.standard_atmosphere_height(pressure_pa)
