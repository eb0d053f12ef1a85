"""A solution as the smoother's output: keyframe states with their marginal covariances
(Cholesky, QR where Cholesky calls the system indeterminate), densified to one state per IMU
sample.
"""

from __future__ import annotations

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X

from fgins.datatypes import Trajectory
from fgins.graph.output import KeyframeStates, densify
from fgins.graph.problem import Problem


def states_from_values(
    problem: Problem, values: gtsam.Values, covariances: dict[str, np.ndarray]
) -> KeyframeStates:
    n = problem.n_keyframes
    rotation = np.empty((n, 3, 3))
    position = np.empty((n, 3))
    velocity = np.empty((n, 3))
    accel_bias = np.empty((n, 3))
    gyro_bias = np.empty((n, 3))
    for k in range(n):
        pose = values.atPose3(X(k))
        rotation[k] = pose.rotation().matrix()
        position[k] = pose.translation()
        velocity[k] = values.atVector(V(k))
        bias = values.atConstantBias(B(k))
        accel_bias[k] = bias.accelerometer()
        gyro_bias[k] = bias.gyroscope()
    return KeyframeStates(
        rotation=rotation,
        velocity=velocity,
        position=position,
        accel_bias=accel_bias,
        gyro_bias=gyro_bias,
        position_cov=covariances["position"],
        velocity_cov=covariances["velocity"],
        attitude_cov=covariances["attitude"],
    )


def nav_covariances(pose_cov: np.ndarray, rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """GTSAM's Pose3 covariance is in the body frame (rotation first): rotate into ENU."""
    attitude = rotation @ pose_cov[:3, :3] @ rotation.T
    position = rotation @ pose_cov[3:, 3:] @ rotation.T
    return attitude, position


def _qr_marginals(graph: gtsam.NonlinearFactorGraph, result: gtsam.Values):
    params = gtsam.ISAM2Params()
    params.setFactorization("QR")
    isam = gtsam.ISAM2(params)
    isam.update(graph, result)
    return isam.marginalCovariance


def marginal_function(graph: gtsam.NonlinearFactorGraph, result: gtsam.Values):
    """Marginal covariance lookup: Cholesky (fast), falling back to QR through iSAM2 for the
    keys where Cholesky calls the system indeterminate (tight bias random walks of
    tactical-grade IMUs, long IMU gaps), and to NaN where even QR cannot tell."""
    qr = None
    try:
        cholesky = gtsam.Marginals(graph, result).marginalCovariance
    except RuntimeError:
        cholesky = None

    def marginal(key: int) -> np.ndarray:
        nonlocal qr, cholesky
        if cholesky is not None:
            try:
                return cholesky(key)
            except RuntimeError:
                cholesky = None  # once ill-conditioned, use QR for the rest
        if qr is None:
            qr = _qr_marginals(graph, result)
        try:
            return qr(key)
        except RuntimeError:
            dim = 6 if gtsam.Symbol(key).chr() == ord("x") else 3
            return np.full((dim, dim), np.nan)

    return marginal


def marginal_covariances(
    problem: Problem, marginal_pose, marginal_velocity, values: gtsam.Values, progress: bool
) -> dict[str, np.ndarray]:
    """ENU position/velocity/attitude covariances at every keyframe (NaN where a marginal
    cannot be computed: reported, the rest of the output is still valid)."""
    from tqdm import tqdm

    n = problem.n_keyframes
    out = {name: np.full((n, 3, 3), np.nan) for name in ("position", "velocity", "attitude")}
    for k in tqdm(range(n), desc="covariances", unit="kf", disable=not progress, leave=False):
        rotation = values.atPose3(X(k)).rotation().matrix()
        try:
            out["attitude"][k], out["position"][k] = nav_covariances(marginal_pose(X(k)), rotation)
            out["velocity"][k] = marginal_velocity(V(k))
        except RuntimeError:
            continue
    return out


def covariance_report(covariances: dict[str, np.ndarray]) -> dict[str, object]:
    """Reported sigmas must be positive and finite; say where they are not."""
    variances = np.diagonal(covariances["position"], axis1=1, axis2=2)
    bad = ~np.all(np.isfinite(variances) & (variances > 0), axis=1)
    if not bad.any():
        return {}
    return {
        "covariance_unknown_keyframes": int(bad.sum()),
        "fit_warnings": [
            f"position uncertainty could not be computed at {int(bad.sum())} of {len(bad)} "
            "keyframes (std_* is NaN there): the system is indeterminate there"
        ],
    }


def to_trajectory(
    problem: Problem, states: KeyframeStates, method: str, *, smoothed: bool
) -> Trajectory:
    imu = problem.dataset.imu
    dense = densify(  # densify picks each segment's sample itself (segments.sample)
        problem.segments,
        imu.accel,
        imu.gyro,
        states,
        problem.interval_gravity,
        problem.omega_earth,
        close_to_next=smoothed,
        at=imu.t,  # rows at the IMU sample times (segment starts also include keyframe cuts)
    )
    return Trajectory(
        t=imu.t,
        position=dense.position,
        velocity=dense.velocity,
        rotation=dense.rotation,
        origin=problem.dataset.origin,
        method=method,
        gyro_bias=dense.gyro_bias,
        accel_bias=dense.accel_bias,
        position_cov=dense.position_cov,
        velocity_cov=dense.velocity_cov,
        attitude_cov=dense.attitude_cov,
        info=dict(problem.info),
    )
