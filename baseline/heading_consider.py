"""A heading the motion cannot tell is not learnt from the filter's own errors.

A Kalman filter learns its heading from how a heading error rotates the horizontal specific
force into the velocity (and, under the non-holonomic constraint, from the direction of the
velocity). Its transition evaluates that coupling at the filter's own estimate. A vehicle
that hovers or stands has no horizontal specific force; the filter's own one is then only
its accelerometer-bias and tilt errors, and the linearised updates read a heading out of
them. A multirotor hovering for 100 s with its heading unknown (90 deg sigma) had its
forward heading walk 80 deg in 5 s and its sigma fall to 41 deg in 12 s, with nothing in the
data to say so. When it flew, the 110 deg correction went partly into the gyro's z bias, and
the RTS smoother spread that bias over the whole flight: its heading drifted 1.4 deg/s, 12 m
off at the fixes it had used (NEES 4,400).

So over a block where the heading is unknown (sigma above :data:`HEADING_UNKNOWN_RAD`) and the
motion cannot tell it, the block's transition does not couple the heading error into the
velocity and position. The error it would have made there is process noise instead (what a
heading off by its sigma makes of the block's specific force), so the uncertainty still
grows as it should, but no update can correct the heading through it. The model stays
linear-Gaussian, so the forward filter stays optimal for it and the RTS smoother exact. The
motion tells the heading once the block's mean horizontal specific force is beyond what
those errors can fake (:data:`FORCE_SIGMAS` of their sigma), or, with the non-holonomic
constraint, once the vehicle moves faster than its velocity sigma can fake. A heading known
to better than that sigma is never decoupled: cars align theirs on their velocity, and
nothing changes for them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgins.baseline.mechanization import ACC_BIAS, ATT, POS, VEL

HEADING_UNKNOWN_RAD = np.radians(10.0)
FORCE_SIGMAS = 3.0
YAW = ATT.start + 2  # the error rotation about the navigation frame's up axis
# The rows the heading error reaches through the specific force.
_DRIVEN = np.r_[np.arange(POS.start, POS.stop), np.arange(VEL.start, VEL.stop)]


@dataclass
class HeadingGate:
    """Decides, block by block, whether the heading error is coupled into the velocity."""

    gravity: float  # m/s^2
    accel_noise: float  # accelerometer white noise, m/s^2/sqrt(Hz)
    nhc: bool  # the non-holonomic constraint is applied
    decoupled_blocks: int = 0

    def transition(
        self,
        phi: np.ndarray,
        q: np.ndarray,
        cov: np.ndarray,
        force_nav: np.ndarray,
        dt: np.ndarray,
        rotation: np.ndarray,
        velocity: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """The block's ``phi`` and ``q``, the heading decoupled where the motion cannot tell
        it. ``cov``: the covariance at the block's start; ``force_nav`` (n, 3) and ``dt``
        (n,): its specific force in the navigation frame per sample and their intervals;
        ``rotation`` and ``velocity``: the nominal attitude and velocity at its start."""
        yaw_variance = float(cov[YAW, YAW])
        if yaw_variance <= HEADING_UNKNOWN_RAD**2:
            return phi, q
        if self.nhc and float(np.linalg.norm(velocity[:2])) > FORCE_SIGMAS * np.sqrt(
            np.trace(cov[VEL, VEL][:2, :2]) / 2
        ):
            return phi, q
        span = float(np.sum(dt))
        force = float(np.linalg.norm(dt @ force_nav[:, :2])) / span
        if force > FORCE_SIGMAS * self._fakeable_force(cov, rotation, span):
            return phi, q
        coupling = phi[_DRIVEN, YAW].copy()
        phi = phi.copy()
        phi[_DRIVEN, YAW] = 0.0
        q = q.copy()
        q[np.ix_(_DRIVEN, _DRIVEN)] += np.outer(coupling, coupling) * yaw_variance
        self.decoupled_blocks += 1
        return phi, q

    def _fakeable_force(self, cov: np.ndarray, rotation: np.ndarray, span_s: float) -> float:
        """The 1-sigma horizontal specific force (per axis) that the filter's accelerometer
        bias and tilt errors, and the accelerometer's noise over the block, can make."""
        bias = (rotation @ cov[ACC_BIAS, ACC_BIAS] @ rotation.T)[:2, :2]
        tilt = cov[ATT, ATT][:2, :2]
        variance = (
            np.trace(bias) / 2
            + self.gravity**2 * np.trace(tilt) / 2
            + self.accel_noise**2 / span_s
        )
        return float(np.sqrt(variance))
