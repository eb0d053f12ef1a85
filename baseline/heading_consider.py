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
motion tells the heading once the vehicle travels (faster than MIN_SPEED_M_S), or once the block's mean horizontal specific force is beyond what those
errors can fake (:data:`FORCE_SIGMAS` of their sigma). A heading known to better than
HEADING_UNKNOWN_RAD is never decoupled: cars align theirs on their velocity, and nothing
changes for them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgins.baseline.mechanization import ACC_BIAS, ATT, POS, VEL

HEADING_UNKNOWN_RAD = np.radians(10.0)
FORCE_SIGMAS = 3.0
# A vehicle that travels tells its heading through its turns (their centripetal force turns
# with it, which no constant bias does; the simulated loop at 3 m/s, a consumer IMU whose
# bias sigma put its 0.4-0.65 m/s^2 within 3 sigma: decoupled, its EKF+RTS went 1.1 -> 24 m)
# and, under the non-holonomic constraint, its velocity's direction: only a vehicle that
# stands or hovers is judged by its force. The filter's own speed, not against its sigma:
# that grows in an outage, and decoupling there cut the correlation between the heading and
# the drifting velocity that the first fix after it corrects through (the loop: 1.5 -> 2.8 m).
MIN_SPEED_M_S = 1.0
YAW = ATT.start + 2  # the error rotation about the navigation frame's up axis
# The rows the heading error reaches through the specific force.
_DRIVEN = np.r_[np.arange(POS.start, POS.stop), np.arange(VEL.start, VEL.stop)]


@dataclass
class HeadingGate:
    """Decides, block by block, whether the heading error is coupled into the velocity."""

    gravity: float  # m/s^2
    accel_noise: float  # accelerometer white noise, m/s^2/sqrt(Hz)
    decoupled_blocks: int = 0
    # The last block's decision, which the updates at its end follow too: their attitude
    # reset (fgins.baseline.measurements.reset_jacobian) is first order in the heading error,
    # and for a heading the motion cannot tell its heading coupling is noise (a hover's 90
    # deg taught the tilt a heading through it).
    decoupled: bool = False
    # A fix was applied since the last block began: the motion is judged again. Between
    # fixes (an outage) the last judgement holds: a hover's dead-reckoned drift (1-3 m/s,
    # 0.15 m/s^2 from its biases) is no motion, and coupled there, the first fix after the
    # outage taught it a heading (sigma 90 -> 20 deg at once); a loop's real turning stays
    # coupled through its outage.
    _fix_seen: bool = True

    def fix_applied(self) -> None:
        """The filter made a GNSS update at this boundary."""
        self._fix_seen = True

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
        if self._fix_seen:
            self.decoupled = self._cannot_tell(yaw_variance, cov, force_nav, dt, rotation, velocity)
            self._fix_seen = False
        if not self.decoupled:
            return phi, q
        coupling = phi[_DRIVEN, YAW].copy()
        phi = phi.copy()
        phi[_DRIVEN, YAW] = 0.0
        q = q.copy()
        q[np.ix_(_DRIVEN, _DRIVEN)] += np.outer(coupling, coupling) * yaw_variance
        self.decoupled_blocks += 1
        return phi, q

    def _cannot_tell(
        self,
        yaw_variance: float,
        cov: np.ndarray,
        force_nav: np.ndarray,
        dt: np.ndarray,
        rotation: np.ndarray,
        velocity: np.ndarray,
    ) -> bool:
        """The heading is unknown, the vehicle stands or hovers, and its force is within
        what the filter's errors fake."""
        if yaw_variance <= HEADING_UNKNOWN_RAD**2:
            return False
        if float(np.linalg.norm(velocity[:2])) > MIN_SPEED_M_S:
            return False
        span = float(np.sum(dt))
        force = float(np.linalg.norm(dt @ force_nav[:, :2])) / span
        return force <= FORCE_SIGMAS * self._fakeable_force(cov, rotation, span)

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
