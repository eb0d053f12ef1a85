"""IMU preintegration: GTSAM parameters from the SI error model, and the combined IMU factor."""

from __future__ import annotations

import gtsam
import numpy as np

from fgins.config import ImuNoise, constant_bias_noise
from fgins.datatypes import Origin
from fgins.geodesy import earth_rate_enu, normal_gravity


def preintegration_params(
    noise: ImuNoise, origin: Origin, *, earth_rate: bool = True
) -> gtsam.PreintegrationCombinedParams:
    """ENU (z-up) preintegration parameters: normal gravity and Earth rate at the origin.

    GTSAM takes continuous-time covariances: (unit/sqrt(Hz))^2 for white noise and
    (unit/sqrt(s))^2 for the bias random walks, i.e. exactly our densities squared.
    """
    params = gtsam.PreintegrationCombinedParams.MakeSharedU(normal_gravity(origin.lat, origin.alt))
    eye = np.eye(3)
    params.setAccelerometerCovariance(eye * noise.accel_noise**2)
    params.setGyroscopeCovariance(eye * noise.gyro_noise**2)
    params.setIntegrationCovariance(eye * noise.integration_sigma**2)
    params.setBiasAccCovariance(eye * noise.accel_bias_rw**2)
    params.setBiasOmegaCovariance(eye * noise.gyro_bias_rw**2)
    if earth_rate:
        params.setOmegaCoriolis(earth_rate_enu(origin.lat))
    return params


def with_gravity(
    params: gtsam.PreintegrationCombinedParams, gravity: np.ndarray
) -> gtsam.PreintegrationCombinedParams:
    """A copy of ``params`` with gravity ``gravity`` (ENU, m/s^2): gravity where an interval
    lies (:func:`fgins.geodesy.gravity_enu`), not the origin's."""
    out = gtsam.PreintegrationCombinedParams(np.asarray(gravity, dtype=float))
    out.setAccelerometerCovariance(params.getAccelerometerCovariance())
    out.setGyroscopeCovariance(params.getGyroscopeCovariance())
    out.setIntegrationCovariance(params.getIntegrationCovariance())
    out.setBiasAccCovariance(params.getBiasAccCovariance())
    out.setBiasOmegaCovariance(params.getBiasOmegaCovariance())
    omega = params.getOmegaCoriolis()  # None when unset
    if omega is not None:
        out.setOmegaCoriolis(omega)
    return out


def conditioned_noise(noise: ImuNoise, span_s: float) -> tuple[ImuNoise, list[str]]:
    """``noise`` with a zero bias instability made a constant bias (the rule the Kalman
    baselines share: :func:`fgins.config.constant_bias_noise`)."""
    return constant_bias_noise(noise, span_s)


def bias_prior_sigmas(noise: ImuNoise) -> np.ndarray:
    """Prior sigmas of the initial bias state (accelerometer first, as gtsam's ConstantBias)."""
    return np.array([noise.accel_bias_prior] * 3 + [noise.gyro_bias_prior] * 3)


def integrate(
    pim: gtsam.PreintegratedCombinedMeasurements,
    accel: np.ndarray,
    gyro: np.ndarray,
    dt: np.ndarray,
) -> None:
    """Feed samples into a preintegrator (each held constant over its dt)."""
    integrate_one = pim.integrateMeasurement
    for a, w, step in zip(accel, gyro, dt, strict=True):
        integrate_one(a, w, step)


def combined_imu_factor(
    i: int, j: int, pim: gtsam.PreintegratedCombinedMeasurements
) -> gtsam.CombinedImuFactor:
    """IMU factor between keyframes i and j, carrying the bias random walk between them."""
    from gtsam.symbol_shorthand import B, V, X

    return gtsam.CombinedImuFactor(X(i), V(i), X(j), V(j), B(i), B(j), pim)
