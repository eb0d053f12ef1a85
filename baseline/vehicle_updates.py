"""Land-vehicle and barometer pseudo-measurements for the Kalman baselines (numpy only).

The same information the factor graph gets (:mod:`fgins.factors.vehicle`,
:mod:`fgins.factors.baro`, :meth:`fgins.graph.problem.Problem.keyframe_factors`), with the same
configuration keys and sigmas, applied at the filter's block boundaries:

- **NHC** (``config.smoother.nhc``): vehicle-frame lateral and vertical velocity are zero,
  ``S R^T v = 0`` with ``S`` the vehicle y, z axes in IMU axes (mounting
  ``imu_to_vehicle_rpy_deg``, :mod:`fgins.mounting`), sigmas ``nhc_sigma_lateral/vertical_m_per_s``. Rate: at block
  boundaries no closer than ``vehicle_constraint_interval_s`` (0.2 s) -- the graph's rule for
  its keyframes (every GNSS epoch up to 5 Hz, and every ``max_block_s`` = 1 s in outages). The NHC
  error (side-slip, mounting) is strongly time-correlated, so applying the same sigma at 10 or
  100 Hz would claim far more information than it carries and than the graph uses; matching the
  graph's rate keeps the comparison about the estimator.
- **ZUPT** (``config.smoother.zupt``): where the IMU has been quiet over the last second
  (:func:`fgins.factors.stationary.quiet_imu`, causal window) *and* the filter's own current
  speed is below ``zupt_max_speed_m_per_s`` (within 5 sigma of zero while fixes aid it), no
  12 s chord of fixes shows a crawl at that speed (:func:`~fgins.factors.stationary.crawl_refuses_stop`)
  and the filter saw itself slow down (:func:`~fgins.factors.stationary.slowed_to_a_stop`):
  velocity = 0 (sigma ``zupt_sigma_m_per_s``) and
  zero angular rate, the mean gyro over that second = gyro bias + Earth rate in the body
  (sigma: its white noise averaged over the window, plus the graph's 0.01 deg/s no-motion
  allowance). The latter is what makes a stop observe the gyro biases. Its rows go in at most
  once per window (boundaries at 5-10 Hz fixes would count the same samples 5-10 times): a
  second of standstill tells the filter what it tells the graph's no-motion walk.
  A quiet window must also be *steady* (:func:`fgins.factors.stationary.steady_imu`): the means of its two halves
  agree within their own scatter. The quiet test bounds only the spread of the samples, and a
  smooth start from rest (a jerk-limited ramp, no vibration) stays under it while the vehicle
  already moves: on the highway scenario the window [1 s, 2 s] is quiet while the car speeds
  up from 0.02 to 0.18 m/s, and a ZUPT there (sigma 0.02 m/s, a 9-sigma error) left the
  forward filter's attitude and velocity covariance overconfident for the whole run (velocity
  NEES ~4 on every seed). A ramp moves the half-window means apart by half its rise, far
  beyond their noise, while a stop (noise, vibration) keeps them together.
- **Barometer** (``dataset.baro`` with pressure): standard-atmosphere height of the pressure
  averaged over the last 0.25 s (at least 1.5 of its periods) = the height at the samples'
  mean time (up - v_up age) + b, with ``b`` a random-walk bias state
  (``baro_bias_walk_m_per_sqrt_s``) appended to the error state as state 16 (augmentation
  rather than differencing consecutive heights: a first-difference measurement is correlated
  with the previous state, which a plain filter cannot express without cloning it). Prior of
  ``b``: the first pressure height minus the aligned up, sigma 100 m (the graph's), sigma of
  the height ``baro_sigma_m``.

All are linear-Gaussian updates through :func:`fgins.baseline.measurements.kalman_update`
(the UKF uses them too: NHC is only mildly nonlinear in the attitude, the rest is linear).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from fgins.baseline.measurements import GnssEpochs, kalman_update
from fgins.baseline.mechanization import ATT, GYRO_BIAS, POS, STATE_DIM, VEL, NominalState
from fgins.config import ImuNoise, RunConfig
from fgins.datatypes import Dataset
from fgins.factors import stationary
from fgins.geodesy import Origin, plane_fall, skew
from fgins.mounting import mounting_rotation, nhc_point_velocity

BARO_BIAS = STATE_DIM  # index of the barometer bias in the augmented error state
BARO_BIAS_PRIOR_SIGMA_M = 100.0  # as the graph's prior on its first bias key
QUIET_WINDOW_S = 1.0  # the graph's +-0.5 s, looking back only
BARO_WINDOW_S = 0.25
# Half-window means of a stop differ by noise only: a difference beyond this many of its own
# standard errors is a trend (starting or stopping), not rest.
NO_MOTION_RATE_SIGMA = np.radians(0.01)  # the graph's no-motion rotation sigma per sqrt(s)


@dataclass
class VehicleAiding:
    """Which pseudo-measurements apply at which block boundary, with their sigmas."""

    times: np.ndarray  # (K,) block boundaries
    nhc: bool
    nhc_sigma: np.ndarray  # (2,) lateral, vertical
    nhc_rows: np.ndarray  # (2, 3) vehicle y, z axes in IMU axes
    nhc_min_interval_s: float
    # (K, 2) the constraint point's lateral/vertical velocity relative to the IMU (a lever
    # arm nhc_lever_arm_m times the angular rate; fgins.mounting.nhc_point_velocity)
    nhc_offset: np.ndarray
    zupt: bool
    zupt_sigma: float
    zupt_max_speed: float
    quiet: np.ndarray  # (K,) IMU quiet over the last QUIET_WINDOW_S
    crawl: np.ndarray  # (K,) the fixes moved over the last stationary.CRAWL_WINDOW_S
    rest_gyro: np.ndarray  # (K, 3) mean gyro over that window
    rest_gyro_sigma: np.ndarray  # (K,) per-axis sigma of that mean as a rate measurement
    rest_accel: np.ndarray  # (K, 3) mean accelerometer over that window (a stop is level-free)
    baro_height: np.ndarray  # (K,) standard-atmosphere height, NaN where no pressure
    baro_age: np.ndarray  # (K,) how long before the boundary that height's samples were read (s)
    origin: Origin  # the navigation frame's (a barometer's height is taken down to its plane)
    baro_sigma: float
    baro_walk: float
    earth_rate: np.ndarray
    counts: dict[str, int] = field(default_factory=dict)
    zupt_times: list[float] = field(default_factory=list)  # boundaries taken as stops
    _last_nhc: float = -np.inf
    _last_fix: float = -np.inf  # time of the last GNSS update (fix_applied)
    _last_zero_rate: float = -np.inf  # time of the last zero-rate (gyro bias) update
    # the filter's speeds after its updates over the last seconds (a stop must follow a slow-down)
    _recent: stationary.RecentSpeeds = field(default_factory=stationary.RecentSpeeds)

    @property
    def has_baro(self) -> bool:
        return bool(np.any(np.isfinite(self.baro_height)))

    @property
    def n_extra(self) -> int:
        """Error states appended after the 15 navigation ones (the barometer bias)."""
        return 1 if self.has_baro else 0

    def extra_process_variance(self, dt: float) -> np.ndarray:
        """Random-walk variance of the extra states over a block of length ``dt``."""
        return np.full(self.n_extra, self.baro_walk**2 * dt)

    def initial_extra(self, up: float) -> tuple[np.ndarray, np.ndarray]:
        """Nominal value and variance of the extra states at the start."""
        if not self.has_baro:
            return np.zeros(0), np.zeros(0)
        first = self.baro_height[np.isfinite(self.baro_height)][0]
        return np.array([first - up]), np.array([BARO_BIAS_PRIOR_SIGMA_M**2])

    def fix_applied(self, t: float) -> None:
        """The filter made a GNSS update at time ``t`` (its velocity sigma is anchored)."""
        self._last_fix = float(t)

    def update(
        self, k: int, state: NominalState, cov: np.ndarray, heading_unknown: bool = False
    ) -> tuple[NominalState, np.ndarray]:
        """Apply the pseudo-measurements due at boundary ``k`` (after any GNSS update);
        ``heading_unknown``: as :func:`kalman_update`'s."""
        t = float(self.times[k])
        if self.nhc and t >= self._last_nhc + self.nhc_min_interval_s - 1e-9:
            state, cov = kalman_update(
                state, cov, *self.nhc_measurement(k, state, len(cov)),
                heading_unknown=heading_unknown,
            )  # fmt: skip
            self._last_nhc = t
            self.counts["nhc_updates"] += 1
        speed = float(np.linalg.norm(state.velocity))
        if (
            self.zupt
            and self.quiet[k]
            and stationary.speed_confirms_stop(
                speed,
                stationary.filter_stop_sigma(cov[VEL, VEL], t - self._last_fix),
                self.zupt_max_speed,
            )
            and not stationary.crawl_refuses_stop(self.crawl[k], speed)
            and stationary.slowed_to_a_stop(speed, self._recent.peak())
            and stationary.level_force_allows_stop(state.rotation, self.rest_accel[k] - state.accel_bias)
        ):
            residual, h, variance = self.zupt_measurement(k, state, len(cov))
            if t < self._last_zero_rate + QUIET_WINDOW_S - 1e-9:
                # The zero-rate rows are the mean gyro over the last QUIET_WINDOW_S: at stops
                # closer than that they would count the same samples again (five times at 5
                # Hz fixes: gyro biases 2-3x tighter than the graph's per-second no-motion
                # walk, EKF+RTS 0.24 against the batch's 0.31 m on one drive whose only car
                # constraint was the stops). Velocity alone there.
                residual, h, variance = residual[:3], h[:3], variance[:3]
            else:
                self._last_zero_rate = t
                self.counts["zero_rate_updates"] += 1
            state, cov = kalman_update(
                state, cov, residual, h, variance, heading_unknown=heading_unknown
            )
            self.counts["zupt_updates"] += 1
            self.zupt_times.append(t)
        if np.isfinite(self.baro_height[k]):
            state, cov = kalman_update(
                state, cov, *self.baro_measurement(k, state, len(cov)),
                heading_unknown=heading_unknown,
            )  # fmt: skip
            self.counts["baro_updates"] += 1
        self._recent.add(
            t, float(np.linalg.norm(state.velocity)), stationary.speed_sigma(cov[VEL, VEL])
        )
        return state, cov

    def nhc_measurement(
        self, k: int, state: NominalState, dim: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Residual, Jacobian, variance of ``S R^T v + o_k = 0`` (``o_k``: the constraint
        point's velocity relative to the IMU at boundary ``k``, as the graph's).

        With R_true = Exp(phi) R and v_true = v + dv: R_true^T v_true ~ R^T v + R^T dv +
        R^T [v]x phi, so H_v = S R^T and H_phi = S R^T [v]x.
        """
        rt = state.rotation.T
        h = np.zeros((2, dim))
        h[:, VEL] = self.nhc_rows @ rt
        h[:, ATT] = self.nhc_rows @ rt @ skew(state.velocity)
        residual = -(self.nhc_rows @ rt @ state.velocity + self.nhc_offset[k])
        return residual, h, self.nhc_sigma**2

    def zupt_measurement(
        self, k: int, state: NominalState, dim: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Residual, Jacobian, variance of velocity = 0 and of the resting gyro = b_g + R^T w_ie.

        R_true^T w_ie ~ R^T w_ie + R^T [w_ie]x phi (tiny, kept for exactness).
        """
        h = np.zeros((6, dim))
        h[:3, VEL] = np.eye(3)
        h[3:, GYRO_BIAS] = np.eye(3)
        h[3:, ATT] = state.rotation.T @ skew(self.earth_rate)
        predicted_rate = state.gyro_bias + state.rotation.T @ self.earth_rate
        residual = np.concatenate([-state.velocity, self.rest_gyro[k] - predicted_rate])
        variance = np.concatenate(
            [np.full(3, self.zupt_sigma**2), np.full(3, self.rest_gyro_sigma[k] ** 2)]
        )
        return residual, h, variance

    def baro_measurement(
        self, k: int, state: NominalState, dim: int
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Residual, Jacobian, variance of ``height(pressure) = up - v_up age + fall + b``:
        the height read ``age`` seconds before the boundary (the window's mean time); the
        navigation frame's tangent plane falls ``fall`` below the surface where the vehicle
        is (:func:`fgins.geodesy.plane_fall`), a barometer's height stays with the surface."""
        assert state.extra is not None
        h = np.zeros((1, dim))
        # The fall is the prediction's only: its horizontal gradient (d / R) read height
        # errors as horizontal position where that is uncertain (fgins.baseline.planar_kf).
        age = float(self.baro_age[k])
        h[0, POS.start + 2] = 1.0
        h[0, VEL.start + 2] = -age
        h[0, BARO_BIAS] = 1.0
        fall = plane_fall(state.position, self.origin)[0]
        then = state.position[2] - age * state.velocity[2]
        residual = np.array([self.baro_height[k] - fall - then - state.extra[0]])
        return residual, h, np.array([self.baro_sigma**2])


def vehicle_aiding(
    dataset: Dataset,
    config: RunConfig,
    times: np.ndarray,
    noise: ImuNoise,
    earth_rate: np.ndarray,
    epochs: GnssEpochs,
) -> VehicleAiding:
    """The pseudo-measurements of ``dataset`` at the block boundaries ``times``; the GNSS
    ``epochs`` the filter uses refuse stops where they show a crawl."""
    smoother = config.smoother
    imu = dataset.imu
    mounting = mounting_rotation(smoother.imu_to_vehicle_rpy_deg)
    if smoother.zupt:
        quiet = stationary.quiet_imu(imu, times, noise, before_s=QUIET_WINDOW_S, after_s=0.0)
        # Not the graph's 4 s test of the fixes (stop_candidates): a filter confirms with its
        # own speed at once, and refusing its first stop at a start that may be a steady
        # motion let its speed run to 2.6 m/s at rest through 3 m fixes without velocity.
        crawl = stationary.gnss_moving(
            times, epochs.t, epochs.position, np.nan_to_num(epochs.position_sigma, nan=np.inf),
            window_s=stationary.CRAWL_WINDOW_S,
        )
        rest_gyro, n_samples = stationary.mean_gyro(imu, times, before_s=QUIET_WINDOW_S)
        rest_accel, _ = stationary.mean_accel(imu, times, before_s=QUIET_WINDOW_S)
        window = np.maximum(n_samples, 1) / imu.rate_hz
        rest_sigma = np.hypot(noise.gyro_noise / np.sqrt(window), NO_MOTION_RATE_SIGMA)
    else:
        quiet = crawl = np.zeros(len(times), dtype=bool)
        rest_gyro, rest_sigma = np.zeros((len(times), 3)), np.ones(len(times))
        rest_accel = np.zeros((len(times), 3))
    # The samples of the last BARO_WINDOW_S (at least 1.5 of the barometer's periods: a 1-2
    # Hz barometer had none in most 0.25 s windows and was ignored, unsaid), and the age of
    # their mean, which the update takes out with the filter's climb rate (a mean 0.1 s old
    # left EKF+RTS 2-8x worse in height than the batch in climbs: outside tester).
    baro = dataset.baro
    period = float(np.median(np.diff(baro.t))) if baro is not None and len(baro.t) > 1 else 0.0
    pressure, baro_age = stationary.pressure_before(baro, times, max(BARO_WINDOW_S, 1.5 * period))
    return VehicleAiding(
        times=np.asarray(times, dtype=float),
        nhc=smoother.nhc,
        nhc_sigma=np.array(
            [smoother.nhc_sigma_lateral_m_per_s, smoother.nhc_sigma_vertical_m_per_s]
        ),
        nhc_rows=mounting[1:3],  # R_vi rows: the vehicle's left and up axes in IMU axes
        nhc_min_interval_s=smoother.vehicle_constraint_interval_s,
        nhc_offset=nhc_point_velocity(imu, times, mounting, smoother.nhc_lever_arm_m),
        zupt=smoother.zupt,
        zupt_sigma=smoother.zupt_sigma_m_per_s,
        zupt_max_speed=smoother.zupt_max_speed_m_per_s,
        quiet=quiet,
        crawl=crawl,
        rest_gyro=rest_gyro,
        rest_gyro_sigma=rest_sigma,
        rest_accel=rest_accel,
        baro_height=np.asarray(stationary.standard_atmosphere_height(pressure), dtype=float),
        baro_age=baro_age,
        origin=dataset.origin,
        baro_sigma=smoother.baro_sigma_m,
        baro_walk=smoother.baro_bias_walk_m_per_sqrt_s,
        earth_rate=np.asarray(earth_rate, dtype=float),
        counts={"nhc_updates": 0, "zupt_updates": 0, "zero_rate_updates": 0, "baro_updates": 0},
    )
