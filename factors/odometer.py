"""Wheel speed / odometer: forward speed in the vehicle frame, with a scale-factor state.

Measurement model: s = (1 + e) * u_x, where u = R_vi R^T v is the velocity in the vehicle
frame (x forward) and e the odometer's scale-factor error (tyre radius, calibration), one
state for the drive with a prior. Like the non-holonomic constraint, this is what keeps a
car's speed honest through a GNSS outage, and like it (see :mod:`fgins.factors.vehicle`) it
is given to GTSAM as factors linearised at an estimate that the smoother rebuilds in an
outer loop: no Python callback runs inside an optimisation.
"""

from __future__ import annotations

import gtsam
import numpy as np

from fgins.factors.values import put_double, put_pose, put_vector
from fgins.geodesy import skew_batch

ODOMETER_CAUCHY_K = 3.0  # sigmas: a wheel speed's weight is 1 / (1 + (residual / k sigma)^2)


def scale_key() -> int:
    return gtsam.symbol("w", 0)


def speed_residuals(
    rotation: np.ndarray, velocity: np.ndarray, scale_error: float, speed: np.ndarray,
    forward: np.ndarray,
) -> np.ndarray:  # fmt: skip
    """(1 + e) u_x - s per keyframe (K,) for IMU states (K,3,3), (K,3)."""
    body_velocity = np.einsum("kji,kj->ki", rotation, velocity)
    return (1.0 + scale_error) * (body_velocity @ forward) - speed


def speed_factors(
    pose_keys: np.ndarray,
    velocity_keys: np.ndarray,
    poses: list[gtsam.Pose3],
    velocity: np.ndarray,
    scale_error: float,
    speed: np.ndarray,
    sigma: float,
    forward: np.ndarray,
    point: gtsam.Values | None = None,
) -> list[gtsam.LinearContainerFactor]:
    """Odometer factors linearised at (poses, velocity, scale error), one per keyframe.

    ``forward``: the vehicle's x axis in IMU axes (row 0 of the mounting ``R_vi``).
    Jacobians as in the NHC factor, times the scale, plus d/de = u_x. ``point``: Values
    that already hold these states (as in :func:`fgins.factors.vehicle.nhc_factors`).
    """
    rotation = np.array([pose.rotation().matrix() for pose in poses]).reshape(-1, 3, 3)
    body_velocity = np.einsum("kji,kj->ki", rotation, velocity)
    forward_speed = body_velocity @ forward
    scale = 1.0 + scale_error
    residual = scale * forward_speed - speed
    d_rotation = scale * np.einsum("j,kjl->kl", forward, skew_batch(body_velocity))
    d_velocity = scale * np.einsum("j,klj->kl", forward, rotation)
    # Cauchy weights from the residuals at this estimate (the smoother's outer loop rebuilds
    # the factors, so this is iteratively reweighted least squares): a wheel that slips in
    # hard turns (15 % fast there, 13 % of the samples) pulled the batch 4.8 m off inside an
    # outage where EKF+RTS, without the wheel, was 0.8 m (outside tester); Huber's weights
    # still left 1.6 m, Cauchy's 0.39 (0.74 without the wheel). A right wheel is unchanged.
    whitened = np.abs(residual) / sigma
    sigmas = sigma * np.sqrt(1.0 + (whitened / ODOMETER_CAUCHY_K) ** 2)
    out = []
    for i in range(len(poses)):
        noise = gtsam.noiseModel.Isotropic.Sigma(1, float(sigmas[i]))
        linear = gtsam.JacobianFactor(
            int(pose_keys[i]), np.hstack([d_rotation[i], np.zeros(3)])[None, :],
            int(velocity_keys[i]), d_velocity[i][None, :],
            scale_key(), np.array([[forward_speed[i]]]),
            np.array([-residual[i]]), noise,
        )  # fmt: skip
        at = point
        if at is None:
            at = gtsam.Values()
            put_pose(at, int(pose_keys[i]), poses[i])
            put_vector(at, int(velocity_keys[i]), velocity[i])
            put_double(at, scale_key(), scale_error)
        out.append(gtsam.LinearContainerFactor(linear, at))
    return out


def scale_prior(sigma: float) -> gtsam.PriorFactorDouble:
    """Prior on the scale-factor error (0 +- sigma, e.g. 0.05 for 5 %)."""
    return gtsam.PriorFactorDouble(scale_key(), 0.0, gtsam.noiseModel.Isotropic.Sigma(1, sigma))
