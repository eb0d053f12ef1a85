"""Land-vehicle constraints: non-holonomic (no side-slip, no jump) and zero-velocity updates.

A wheeled vehicle does not move sideways or vertically in its own frame; when it stands
still its velocity is zero and it does not turn. In long GNSS outages these constraints
are what keeps velocity (and so position) from drifting.

The non-holonomic constraint (NHC) ``S R^T v = 0`` has no factor in GTSAM, and a Python
``CustomFactor`` is called with a copy of the whole ``Values`` on every evaluation, which
makes each linearisation cost O(K^2) over a drive of K keyframes. So the NHC is given to
GTSAM as *linearised* factors (a ``JacobianFactor`` inside a ``LinearContainerFactor``, all
C++), built here in one vectorised pass at a linearisation point; the smoother rebuilds them
at its newer estimate in an outer loop until the estimate stops moving (Gauss-Newton on the
NHC, exact at convergence). The constraint is only mildly nonlinear (through the attitude),
so one or two rebuilds settle it.
"""

from __future__ import annotations

import gtsam
import numpy as np

from fgins.factors.values import put_pose, put_vector
from fgins.geodesy import skew_batch


def nhc_rows(imu_to_vehicle: np.ndarray) -> np.ndarray:
    """The vehicle's left and up axes in IMU axes (2, 3): rows 1, 2 of ``R_vi``."""
    return np.asarray(imu_to_vehicle, dtype=float)[1:3]


def nhc_residuals(rotation: np.ndarray, velocity: np.ndarray, select: np.ndarray) -> np.ndarray:
    """Vehicle-frame lateral and vertical velocity (K, 2) of IMU states (K,3,3), (K,3)."""
    body_velocity = np.einsum("kji,kj->ki", rotation, velocity)  # R^T v
    return body_velocity @ select.T


def misalignment_key(k: int) -> int:
    """Keyframe k's NHC misalignment state (2,): lateral and vertical velocity per unit of
    forward speed (small angles, rad) that the vehicle really has at the IMU."""
    return gtsam.symbol("n", int(k))


def misalignment_prior(key: int, sigma_rad: float) -> gtsam.PriorFactorVector:
    """The first keyframe's NHC misalignment: zero (the configured mounting) +- sigma."""
    return gtsam.PriorFactorVector(
        key, np.zeros(2), gtsam.noiseModel.Isotropic.Sigma(2, max(sigma_rad, 1e-9))
    )


def misalignment_gauss_markov_factor(
    key_a: int, key_b: int, dt: float, correlation_s: float, sigma_rad: float
) -> gtsam.LinearContainerFactor:
    """First-order Gauss-Markov step of the NHC misalignment: ``m_b = exp(-dt/tau) m_a + w``
    with ``w`` of variance ``sigma^2 (1 - exp(-2 dt/tau))`` (a process of stationary sigma
    ``sigma``). Linear, so a JacobianFactor is exact; it is wrapped to live in the nonlinear
    graphs."""
    phi = float(np.exp(-max(dt, 0.0) / correlation_s))
    noise = max(float(sigma_rad) * np.sqrt(max(1.0 - phi**2, 1e-12)), 1e-9)
    linear = gtsam.JacobianFactor(
        int(key_a), -phi * np.eye(2), int(key_b), np.eye(2), np.zeros(2),
        gtsam.noiseModel.Isotropic.Sigma(2, noise),
    )  # fmt: skip
    point = gtsam.Values()
    put_vector(point, int(key_a), np.zeros(2))
    put_vector(point, int(key_b), np.zeros(2))
    return gtsam.LinearContainerFactor(linear, point)


def misalignment_walk_factor(
    key_a: int, key_b: int, dt: float, walk_rad_per_sqrt_s: float | np.ndarray
) -> gtsam.BetweenFactorVector:
    """Random walk of the NHC misalignment between two keyframes ``dt`` apart (lateral,
    vertical walks; a zero walk holds it constant, up to a 1e-7 rad floor)."""
    walk = np.broadcast_to(np.asarray(walk_rad_per_sqrt_s, dtype=float), (2,))
    sigma = np.maximum(walk * np.sqrt(max(dt, 1e-6)), 1e-7)
    return gtsam.BetweenFactorVector(
        key_a, key_b, np.zeros(2), gtsam.noiseModel.Diagonal.Sigmas(sigma)
    )


def nhc_factors(
    pose_keys: np.ndarray,
    velocity_keys: np.ndarray,
    poses: list[gtsam.Pose3],
    velocity: np.ndarray,
    select: np.ndarray,
    sigmas: np.ndarray,
    point: gtsam.Values | None = None,
    misalignment_keys: np.ndarray | None = None,
    misalignment: np.ndarray | None = None,
    forward: np.ndarray | None = None,
    offset: np.ndarray | None = None,
) -> list[gtsam.LinearContainerFactor]:
    """NHC factors linearised at (poses, velocity[, misalignment]), one per keyframe given.

    Error ``S R^T v`` (S: :func:`nhc_rows`). With GTSAM's right perturbation R Exp(w),
    d(R^T v)/dw = [R^T v]x and d(R^T v)/dv = R^T; translation does not enter.
    ``sigmas`` (K, 2): lateral and vertical, per keyframe. ``point``: Values that already
    hold (poses, velocity[, misalignment]) under the keys (each factor copies only its own
    keys from it, in C++); without it (or without the misalignment keys in it) a small
    Values is made per factor.

    With ``misalignment_keys`` (and their values ``misalignment`` (K, 2) and the vehicle's
    forward axis in IMU axes ``forward``, row 0 of ``R_vi``), the error is
    ``S R^T v - m u_f`` with ``u_f = f^T R^T v``: the lateral and vertical velocity a real
    car has at the IMU in proportion to its speed (a residual mounting error, crab, slowly
    varying slip), a random-walk state instead of white noise the constraint would average
    down. ``offset`` (K, 2): the constraint point's velocity relative to the IMU (a lever
    arm times the angular rate), added to the IMU's: the NHC holds at that point.
    """
    rotation = np.array([pose.rotation().matrix() for pose in poses]).reshape(-1, 3, 3)
    body_velocity = np.einsum("kji,kj->ki", rotation, velocity)
    residual = body_velocity @ select.T
    if offset is not None:
        residual = residual + offset
    skew = skew_batch(body_velocity)
    d_rotation = np.einsum("ij,kjl->kil", select, skew)
    d_velocity = np.einsum("ij,klj->kil", select, rotation)  # S R^T
    estimated = misalignment_keys is not None
    if estimated:
        if misalignment is None or forward is None:
            raise ValueError("misalignment_keys need misalignment values and forward")
        f = np.asarray(forward, dtype=float)
        forward_speed = body_velocity @ f  # (K,)
        m = np.asarray(misalignment, dtype=float).reshape(-1, 2)
        residual = residual - m * forward_speed[:, None]
        d_rotation = d_rotation - np.einsum("ki,j,kjl->kil", m, f, skew)
        d_velocity = d_velocity - np.einsum("ki,j,klj->kil", m, f, rotation)
        d_misalignment = -forward_speed[:, None, None] * np.eye(2)
    out = []
    d_pose = np.concatenate([d_rotation, np.zeros((len(poses), 2, 3))], axis=2)
    noise_models: dict[tuple[float, float], gtsam.noiseModel.Diagonal] = {}
    for i in range(len(poses)):
        sigma = (float(sigmas[i][0]), float(sigmas[i][1]))
        noise = noise_models.get(sigma)
        if noise is None:
            noise = noise_models[sigma] = gtsam.noiseModel.Diagonal.Sigmas(np.array(sigma))
        keys_and_blocks: list = [
            int(pose_keys[i]), d_pose[i], int(velocity_keys[i]), d_velocity[i],
        ]  # fmt: skip
        if estimated:
            keys_and_blocks += [int(misalignment_keys[i]), d_misalignment[i]]
        linear = gtsam.JacobianFactor(*keys_and_blocks, -residual[i], noise)
        at = point
        if at is None or (estimated and not at.exists(int(misalignment_keys[i]))):
            at = gtsam.Values()
            put_pose(at, int(pose_keys[i]), poses[i])
            put_vector(at, int(velocity_keys[i]), velocity[i])
            if estimated:
                put_vector(at, int(misalignment_keys[i]), m[i])
        out.append(gtsam.LinearContainerFactor(linear, at))
    return out


def nhc_factor(
    pose_key: int,
    velocity_key: int,
    rotation: np.ndarray,
    velocity: np.ndarray,
    select: np.ndarray,
    sigmas: np.ndarray,
    point: gtsam.Values,
    misalignment_key: int | None = None,
    forward: np.ndarray | None = None,
    offset: np.ndarray | None = None,
) -> gtsam.LinearContainerFactor:
    """One keyframe's NHC factor, as :func:`nhc_factors` makes it (the same Jacobians), with
    the few 3x3 operations of one keyframe instead of the batched ones: an iSAM2 update adds
    one keyframe at a time, where the batched path's fixed cost dominated (issue 9).
    ``point`` holds the pose and velocity (and the misalignment, if any) under the keys."""
    rotation_t = rotation.T
    body_velocity = rotation_t @ velocity
    skew = skew_batch(body_velocity)
    d_rotation = select @ skew
    d_velocity = select @ rotation_t
    residual = select @ body_velocity
    if offset is not None:
        residual = residual + offset
    blocks: list = []
    if misalignment_key is not None:
        if forward is None:
            raise ValueError("a misalignment key needs the forward axis")
        m = point.atVector(int(misalignment_key))
        forward_speed = float(body_velocity @ forward)
        residual = residual - m * forward_speed
        d_rotation = d_rotation - np.outer(m, forward @ skew)
        d_velocity = d_velocity - np.outer(m, forward @ rotation_t)
        blocks = [int(misalignment_key), -forward_speed * np.eye(2)]
    d_pose = np.zeros((2, 6))
    d_pose[:, :3] = d_rotation
    linear = gtsam.JacobianFactor(
        int(pose_key), d_pose, int(velocity_key), d_velocity, *blocks,
        -residual, gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, float)),
    )  # fmt: skip
    return gtsam.LinearContainerFactor(linear, point)


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
