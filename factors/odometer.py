"""Wheel speed / odometer: forward speed in the vehicle frame, with a scale-factor state.

Measurement model: s = (1 + e) * u_x, where u = R_vb^T R^T v is the velocity in the vehicle
frame (x forward) and e the odometer's scale-factor error (tyre radius, calibration), one
state for the drive with a prior. Like the non-holonomic constraint, this is what keeps a
car's speed honest through a GNSS outage.
"""

from __future__ import annotations

import gtsam
import numpy as np


def scale_key() -> int:
    return gtsam.symbol("w", 0)


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def speed_factor(
    pose_key: int,
    velocity_key: int,
    speed: float,
    sigma: float,
    imu_to_vehicle: np.ndarray | None = None,
) -> gtsam.CustomFactor:
    """Odometer speed at a keyframe (see module docstring); Jacobians as in the NHC factor."""
    mounting = np.eye(3) if imu_to_vehicle is None else np.asarray(imu_to_vehicle, dtype=float)
    forward = mounting.T[0:1]  # vehicle x expressed in IMU axes (1 x 3)

    def error(this: gtsam.CustomFactor, values: gtsam.Values, jacobians) -> np.ndarray:
        pose = values.atPose3(this.keys()[0])
        velocity = values.atVector(this.keys()[1])
        scale = 1.0 + values.atDouble(this.keys()[2])
        rotation = pose.rotation().matrix()
        body_velocity = rotation.T @ velocity
        forward_speed = float((forward @ body_velocity)[0])
        if jacobians is not None:
            jacobians[0] = scale * np.hstack([forward @ _skew(body_velocity), np.zeros((1, 3))])
            jacobians[1] = scale * (forward @ rotation.T)
            jacobians[2] = np.array([[forward_speed]])
        return np.array([scale * forward_speed - speed])

    noise = gtsam.noiseModel.Isotropic.Sigma(1, sigma)
    return gtsam.CustomFactor(noise, [pose_key, velocity_key, scale_key()], error)


def scale_prior(sigma: float) -> gtsam.PriorFactorDouble:
    """Prior on the scale-factor error (0 +- sigma, e.g. 0.05 for 5 %)."""
    return gtsam.PriorFactorDouble(scale_key(), 0.0, gtsam.noiseModel.Isotropic.Sigma(1, sigma))
