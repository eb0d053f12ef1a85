"""Keyframe estimates -> states at every IMU sample (numpy, vectorised over keyframe intervals).

Between keyframes the state is predicted from the earlier keyframe with its estimated bias,
using the same discrete mechanization as the preintegration. For a smoother the small
mismatch with the next keyframe's estimate is spread linearly over the interval, so the
IMU-rate output is continuous and ends exactly on every keyframe; a filter's (online) output
is the pure forward prediction, which uses no future data: its biases are the earlier
keyframe's, and its covariances grow towards the next keyframe's but never fall before it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgins.geodesy import skew, so3_exp, so3_log
from fgins.graph.keyframes import Segments


@dataclass
class KeyframeStates:
    """Estimated states at keyframes (K rows)."""

    rotation: np.ndarray  # (K, 3, 3) body -> ENU
    velocity: np.ndarray  # (K, 3)
    position: np.ndarray  # (K, 3)
    accel_bias: np.ndarray  # (K, 3)
    gyro_bias: np.ndarray  # (K, 3)
    position_cov: np.ndarray  # (K, 3, 3) ENU
    velocity_cov: np.ndarray  # (K, 3, 3)
    attitude_cov: np.ndarray  # (K, 3, 3)


@dataclass
class DenseStates:
    t: np.ndarray
    rotation: np.ndarray
    velocity: np.ndarray
    position: np.ndarray
    accel_bias: np.ndarray
    gyro_bias: np.ndarray
    position_cov: np.ndarray
    velocity_cov: np.ndarray
    attitude_cov: np.ndarray


def densify(
    segments: Segments,
    accel: np.ndarray,
    gyro: np.ndarray,
    states: KeyframeStates,
    gravity: np.ndarray,  # (K-1, 3) per interval
    omega_earth: np.ndarray,
    *,
    close_to_next: bool,
    at: np.ndarray | None = None,
) -> DenseStates:
    """States at every segment start plus the last keyframe (see module docstring).
    ``accel``/``gyro`` are the IMU's samples (N, 3), not per segment: segment j integrates
    sample ``segments.sample[j]``. (They were once passed per segment and indexed again: every
    keyframe cutting a sample shifted all later segments by one more sample, and the output's
    attitude drifted up to 2.6 deg off the keyframes' between them on KITTI.)"""
    n_int = len(segments.times) - 1
    counts = np.diff(segments.bounds)
    n_max = int(counts.max())
    first = segments.bounds[:-1]
    n_seg = len(segments.start)

    d_rot = np.tile(np.eye(3), (n_int, 1, 1))
    d_vel = np.zeros((n_int, 3))
    d_pos = np.zeros((n_int, 3))
    d_t = np.zeros(n_int)
    seg_rot = np.empty((n_seg, 3, 3))
    seg_vel = np.empty((n_seg, 3))
    seg_pos = np.empty((n_seg, 3))
    seg_t = np.empty(n_seg)
    ba, bg = states.accel_bias[:-1], states.gyro_bias[:-1]
    for m in range(n_max):
        active = m < counts
        idx = np.where(active, first + m, 0)
        seg_rot[idx[active]] = d_rot[active]
        seg_vel[idx[active]] = d_vel[active]
        seg_pos[idx[active]] = d_pos[active]
        seg_t[idx[active]] = d_t[active]
        dt = np.where(active, segments.dt[idx], 0.0)
        a = segments.accel(accel, gyro, idx) - ba
        w = gyro[segments.sample[idx]] - bg
        rotated = np.einsum("nij,nj->ni", d_rot, a)
        d_pos += d_vel * dt[:, None] + 0.5 * rotated * dt[:, None] ** 2
        d_vel += rotated * dt[:, None]
        d_rot = d_rot @ so3_exp(w * dt[:, None])
        d_t += dt

    def predict(rot_i, vel_i, pos_i, dr, dv, dp, dtt, gravity):
        """Navigation state after (dr, dv, dp) over dtt from keyframe state i."""
        w_cross = skew(omega_earth)
        earth_turn = so3_exp(-omega_earth[None, :] * dtt[:, None])
        rotation = earth_turn @ rot_i @ dr
        coriolis = vel_i @ w_cross.T  # omega x v
        velocity = vel_i + gravity * dtt[:, None] + np.einsum("nij,nj->ni", rot_i, dv)
        velocity -= 2.0 * coriolis * dtt[:, None]
        position = pos_i + vel_i * dtt[:, None] + 0.5 * gravity * dtt[:, None] ** 2
        position += np.einsum("nij,nj->ni", rot_i, dp) - coriolis * dtt[:, None] ** 2
        return rotation, velocity, position

    # The output rows: every segment start and the last keyframe, or (``at``) the row at or
    # after each of those times. Everything below is computed at those rows only: a dense
    # array over every segment indexed afterwards held each output twice (an hour at 200 Hz:
    # ~0.3 GB a copy, the covariances' interpolation several more).
    starts = np.append(segments.start, segments.times[-1])
    rows = np.arange(len(starts)) if at is None else np.clip(np.searchsorted(starts, at), 0, len(starts) - 1)
    inner = rows < n_seg  # a segment's start; else the last keyframe
    sel = rows[inner]
    interval_of = np.repeat(np.arange(n_int), counts)[sel]
    rot, vel, pos = predict(
        states.rotation[interval_of],
        states.velocity[interval_of],
        states.position[interval_of],
        seg_rot[sel],
        seg_vel[sel],
        seg_pos[sel],
        seg_t[sel],
        gravity[interval_of],
    )
    share = seg_t[sel] / np.maximum(d_t[interval_of], 1e-12)
    if close_to_next:
        end_rot, end_vel, end_pos = predict(
            states.rotation[:-1],
            states.velocity[:-1],
            states.position[:-1],
            d_rot,
            d_vel,
            d_pos,
            d_t,
            gravity,
        )
        err_pos = states.position[1:] - end_pos
        err_vel = states.velocity[1:] - end_vel
        err_rot = so3_log(np.swapaxes(end_rot, 1, 2) @ states.rotation[1:])
        pos += share[:, None] * err_pos[interval_of]
        vel += share[:, None] * err_vel[interval_of]
        rot = rot @ so3_exp(share[:, None] * err_rot[interval_of])

    def output(inside: np.ndarray, last: np.ndarray) -> np.ndarray:
        """Rows at segment starts from ``inside``, the others the last keyframe's ``last``."""
        out = np.empty((len(rows), *last.shape), dtype=float)
        out[inner] = inside
        out[~inner] = last
        return out

    def interpolate(values: np.ndarray) -> np.ndarray:
        """Linear interpolation between keyframe values (a smoother's biases and
        covariances)."""
        weight = share.reshape(-1, *([1] * (values.ndim - 1)))
        between = values[:-1][interval_of]
        between += weight * (values[1:][interval_of] - between)
        return output(between, values[-1])

    def held(values: np.ndarray) -> np.ndarray:
        """The earlier keyframe's value (a filter's bias: the next one knows later data)."""
        return output(values[:-1][interval_of], values[-1])

    def grown(values: np.ndarray) -> np.ndarray:
        """A filter's covariance between keyframes: towards the next keyframe's where that is
        larger (the interval's prediction), held where it is smaller. The next keyframe's
        covariance has its own update in it (a fix ending an outage): interpolated towards
        it, the online sigma fell 2-14x over the outage's last second while the position was
        still dead-reckoned, 27-586 m off at z 5-22 (outside tester)."""
        larger = np.trace(values[1:], axis1=1, axis2=2) >= np.trace(values[:-1], axis1=1, axis2=2)
        target = np.where(larger[:, None, None], values[1:], values[:-1])
        weight = share[:, None, None]
        between = values[:-1][interval_of]
        between += weight * (target[interval_of] - between)
        return output(between, values[-1])

    bias, covariance = (interpolate, interpolate) if close_to_next else (held, grown)
    return DenseStates(
        t=starts[rows],
        rotation=output(rot, states.rotation[-1]),
        velocity=output(vel, states.velocity[-1]),
        position=output(pos, states.position[-1]),
        accel_bias=bias(states.accel_bias),
        gyro_bias=bias(states.gyro_bias),
        position_cov=covariance(states.position_cov),
        velocity_cov=covariance(states.velocity_cov),
        attitude_cov=covariance(states.attitude_cov),
    )
