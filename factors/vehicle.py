"""Land-vehicle constraints: non-holonomic (no side-slip, no jump) and zero-velocity updates.

A wheeled vehicle does not move sideways or vertically in its own frame; when it stands
still its velocity is zero and it does not turn. In long GNSS outages these constraints
are what keeps velocity (and so position) from drifting.
"""

from __future__ import annotations

import gtsam
import numpy as np


def _skew(v: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])


def nhc_factor(
    pose_key: int,
    velocity_key: int,
    sigma_lateral: float,
    sigma_vertical: float,
    imu_to_vehicle: np.ndarray | None = None,
) -> gtsam.CustomFactor:
    """Vehicle-frame lateral and vertical velocity are zero (up to the given sigmas).

    Error: rows y, z of R_vb^T R^T v, where R is the IMU pose's rotation (IMU->ENU) and R_vb
    the IMU-to-vehicle mounting rotation (vehicle axes x forward, y left, z up). With GTSAM's
    right perturbation R Exp(w), d(R^T v)/dw = [R^T v]x, and d(R^T v)/dv = R^T.
    """
    mounting = np.eye(3) if imu_to_vehicle is None else np.asarray(imu_to_vehicle, dtype=float)
    select = mounting.T[1:3]  # vehicle y and z rows expressed in IMU axes

    def error(this: gtsam.CustomFactor, values: gtsam.Values, jacobians) -> np.ndarray:
        pose = values.atPose3(this.keys()[0])
        velocity = values.atVector(this.keys()[1])
        rotation = pose.rotation().matrix()
        body_velocity = rotation.T @ velocity
        if jacobians is not None:
            jacobians[0] = np.hstack([select @ _skew(body_velocity), np.zeros((2, 3))])
            jacobians[1] = select @ rotation.T
        return select @ body_velocity

    noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([sigma_lateral, sigma_vertical]))
    return gtsam.CustomFactor(noise, [pose_key, velocity_key], error)


def zero_velocity_factor(velocity_key: int, sigma: float) -> gtsam.PriorFactorVector:
    """The vehicle stands still: navigation-frame velocity is zero."""
    return gtsam.PriorFactorVector(
        velocity_key, np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, sigma)
    )


def no_motion_factor(
    pose_key_a: int, pose_key_b: int, sigma_rotation: float, sigma_position: float
) -> gtsam.BetweenFactorPose3:
    """Between two keyframes at a standstill, attitude and position do not change.

    This is what makes a stop observe the gyro biases (zero angular rate update).
    """
    sigmas = np.array([sigma_rotation] * 3 + [sigma_position] * 3)
    return gtsam.BetweenFactorPose3(
        pose_key_a, pose_key_b, gtsam.Pose3(), gtsam.noiseModel.Diagonal.Sigmas(sigmas)
    )
