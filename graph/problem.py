"""The factor-graph problem shared by the batch and iSAM2 smoothers.

Keyframes, preintegrated IMU between them, GNSS position/velocity factors at their epochs,
priors from the initial alignment, and an initial guess for every keyframe.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property

import gtsam
import numpy as np
from gtsam.symbol_shorthand import B, V, X

from fgins.alignment import Alignment, initial_alignment
from fgins.config import GnssConfig, ImuNoise, RunConfig
from fgins.datatypes import Dataset
from fgins.factors import baro as baro_model
from fgins.factors import gnss as gnss_model
from fgins.factors import imu as imu_model
from fgins.factors import odometer as odometer_model
from fgins.factors import stationary
from fgins.factors import vehicle as vehicle_model
from fgins.factors.values import put_double, put_vector
from fgins.geodesy import earth_rate_enu, gravity_enu, normal_gravity, plane_fall
from fgins.graph.keyframes import Segments, build_segments, keyframe_times
from fgins.mounting import mounting_rotation, nhc_point_velocity

# Between two stopped keyframes: rotation and position walk per sqrt(second) of standstill
# (rad, m), the Kalman baselines' zero-angular-rate sigma (baseline.vehicle_updates).
NO_MOTION_RATE_SIGMA = float(np.radians(0.01))
NO_MOTION_SPEED_SIGMA = 0.01
# A barometer factor is rebuilt when its plane fall at the solution moved this far (m): a
# tenth of the best barometers' noise.
BARO_FALL_REDO_M = 0.02

@dataclass
class Problem:
    dataset: Dataset
    config: RunConfig
    noise: ImuNoise
    segments: Segments
    # Interval i's preintegration (keyframes i -> i+1), made lazily about a bias estimate.
    pims: list[gtsam.PreintegratedCombinedMeasurements | None]
    pim_bias: np.ndarray  # (K-1, 6) the bias (accelerometer, gyro) each was made about
    params: gtsam.PreintegrationCombinedParams
    # Interval -> the preintegration parameters of the suspect stretch it lies in.
    suspect_params: dict[int, gtsam.PreintegrationCombinedParams]
    gnss_at: np.ndarray  # (K,) index into the usable GNSS epochs, -1 where none
    gnss_enu: np.ndarray  # usable epochs, ENU
    gnss_sigma: np.ndarray
    gnss_sigma_modelled: np.ndarray  # (M,) sigma from UERE x DOP, not the data's or configured
    gnss_velocity: np.ndarray
    gnss_gyro: np.ndarray  # (M, 3) the gyro sample held at each used GNSS epoch (lever arm)
    gnss_velocity_sigma: np.ndarray
    alignment: Alignment
    gravity: np.ndarray  # (3,) at the origin
    # (K-1, 3) gravity where each interval lies (fgins.geodesy.gravity_enu at its middle):
    # from the fixes first, then from each solution (repreintegrate)
    interval_gravity: np.ndarray
    omega_earth: np.ndarray
    quiet: np.ndarray  # (K,) the IMU is quiet around keyframe k (a stop, if the speed agrees)
    # (K,) the fixes of the last seconds before keyframe k moved (stationary.gnss_moving)
    gnss_moving: np.ndarray
    # (K,) the fixes moved over the last stationary.CRAWL_WINDOW_S (a crawl refuses a stop)
    crawling: np.ndarray
    baro_surface_pressure: np.ndarray  # (K,) mean pressure (Pa) around keyframe k, NaN where none
    # (K,) how far the navigation frame's tangent plane lies below the surface at keyframe k
    # (fgins.geodesy.plane_fall): from the fixes first, then from each solution
    baro_fall: np.ndarray
    odometer_speed: np.ndarray  # (K,) mean wheel speed (m/s) around keyframe k, NaN where none
    imu_to_vehicle: np.ndarray  # R_vi: IMU axes -> vehicle axes (fgins.mounting)
    nhc_sigma: np.ndarray  # (K, 2) lateral, vertical NHC sigma per keyframe
    # (K, 2) lateral, vertical velocity of the non-holonomic point relative to the IMU
    # (yaw/pitch rate times the configured lever arm), added to the IMU's in the NHC
    nhc_offset: np.ndarray
    # (K,) keyframes that carry the NHC and the wheel speed: at least
    # ``vehicle_constraint_interval_s`` apart (their errors are correlated over seconds), the
    # Kalman baselines' rule, while every fix up to 20 Hz is a keyframe
    vehicle_keyframe: np.ndarray
    gnss_mask: np.ndarray | None = None  # the caller's withheld epochs (outages), True = keep
    info: dict[str, object] = field(default_factory=dict)
    # Factors that do not change between the batch's graph rebuilds, made once: the GNSS
    # ones of each keyframe (the run's kernel), the IMU one of each interval (per
    # preintegration). Creating them from Python costs ~50-100 us each (issue 9).
    _gnss_factors: dict[int, list] = field(default_factory=dict, repr=False)
    _imu_factors: dict[int, tuple] = field(default_factory=dict, repr=False)
    zupt_keyframes: set[int] = field(default_factory=set)
    # Keyframes whose fix's position is left out as a fault (fgins.graph.gnss_faults); its
    # velocity stays (its own kernel judges it: a reflected signal's range is metres long,
    # its Doppler barely off, and the sim's 25 m jumps leave it right).
    gnss_position_out: frozenset[int] = frozenset()
    _gnss_counts_all: dict[str, int] | None = field(default=None, repr=False)
    # (noise parameters, rounded gravity) -> their preintegration parameters
    _gravity_params: dict[tuple, gtsam.PreintegrationCombinedParams] = field(
        default_factory=dict, repr=False
    )
    # The fixes' gravity and plane fall, which a new start returns to (restart)
    _fixes_gravity: np.ndarray = field(init=False, repr=False)
    _fixes_baro_fall: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._fixes_gravity = self.interval_gravity.copy()
        self._fixes_baro_fall = self.baro_fall.copy()

    def restart(self) -> None:
        """Forget what earlier solutions set before a solve from a new start: gravity and
        the plane fall go back to the fixes' (a diverged estimate's far-off or NaN positions
        left them wrong: a gyro-free IMU's batch start, after an iSAM2 pass that diverged,
        began at an error of 1e36 instead of 1e8 and took 599 iterations), no stops. The
        preintegration is the start's to make."""
        self.interval_gravity = self._fixes_gravity.copy()
        self.baro_fall = self._fixes_baro_fall.copy()
        self.zupt_keyframes.clear()

    @property
    def n_keyframes(self) -> int:
        return len(self.segments.times)

    def prior_factors(self) -> gtsam.NonlinearFactorGraph:
        """Priors on the first keyframe's pose, velocity and bias from the alignment."""
        align = self.alignment
        graph = gtsam.NonlinearFactorGraph()
        pose = gtsam.Pose3(gtsam.Rot3(align.rotation), align.position)
        # The alignment's sigmas are tilt about east and north and heading about up: a
        # navigation-frame covariance, seen from the body (Pose3's tangent) as R^T S R. Taken
        # as body-axis sigmas, an FRD or turned IMU would get its heading doubt on a tilt.
        rotation = np.asarray(align.rotation, dtype=float)
        covariance = np.zeros((6, 6))
        covariance[:3, :3] = rotation.T @ np.diag(align.attitude_sigma_rad**2) @ rotation
        covariance[3:, 3:] = np.eye(3) * align.position_sigma**2
        graph.add(
            gtsam.PriorFactorPose3(X(0), pose, gtsam.noiseModel.Gaussian.Covariance(covariance))
        )
        graph.add(
            gtsam.PriorFactorVector(
                V(0), align.velocity, gtsam.noiseModel.Isotropic.Sigma(3, align.velocity_sigma)
            )
        )
        graph.add(
            gtsam.PriorFactorConstantBias(
                B(0),
                gtsam.imuBias.ConstantBias(),
                gtsam.noiseModel.Diagonal.Sigmas(imu_model.bias_prior_sigmas(self.noise)),
            )
        )
        return graph

    def keyframe_factors(
        self,
        k: int,
        predicted_speed: float | None = None,
        gnss_config: GnssConfig | None = None,
        speed_sigma: float | None = None,
        slowed_to_a_stop: bool = True,
    ) -> gtsam.NonlinearFactorGraph:
        """Factors that arrive with keyframe k: the IMU factor from k-1, k's GNSS, land-vehicle
        constraints, odometer and barometer. ``predicted_speed`` (the current best guess of
        the speed at k, with its sigma ``speed_sigma`` when known) must confirm a stop before
        a quiet IMU is taken as one (:meth:`speed_confirms_stop`), and fixes that moved over
        the last seconds must not refuse it (:func:`stationary.crawl_refuses_stop`);
        ``slowed_to_a_stop`` False (an online pass that saw no slow-down,
        :func:`stationary.slowed_to_a_stop`) refuses it too.
        ``gnss_config``: the GNSS position kernel to use instead of the run's (the initial
        guess's Huber weighting)."""
        graph = gtsam.NonlinearFactorGraph()
        if k > 0:
            graph.add(self.imu_factor(k - 1))
        self._add_gnss(graph, k, gnss_config or self.config.gnss)
        self._add_stop(graph, k, predicted_speed, speed_sigma, slowed_to_a_stop)
        self._add_misalignment(graph, k)
        if k == 0 and self.has_odometer:
            graph.add(odometer_model.scale_prior(self.config.smoother.odometer_scale_sigma))
        self._add_baro(graph, k)
        return graph

    def imu_factor(self, i: int) -> gtsam.CombinedImuFactor:
        pim = self.pims[i]
        if pim is None:
            raise RuntimeError(f"interval {i} has not been preintegrated")  # a bug, not input
        cached = self._imu_factors.get(i)
        if cached is None or cached[0] is not pim:
            cached = self._imu_factors[i] = (pim, imu_model.combined_imu_factor(i, i + 1, pim))
        return cached[1]

    @cached_property
    def _nhc_rows(self) -> np.ndarray:
        return vehicle_model.nhc_rows(self.imu_to_vehicle)

    @cached_property
    def has_odometer(self) -> bool:
        return bool(np.any(np.isfinite(self.odometer_speed)))

    @property
    def has_linear_factors(self) -> bool:
        """Does :meth:`linear_factors` make anything (then the solvers rebuild it)?"""
        return self.config.smoother.nhc or self.has_odometer or self.has_antenna_velocity

    @property
    def estimates_misalignment(self) -> bool:
        """Does the NHC carry a misalignment state (:func:`vehicle_model.misalignment_key`)?"""
        smoother = self.config.smoother
        return smoother.nhc and smoother.nhc_misalignment_prior_deg > 0.0

    @property
    def constant_misalignment(self) -> bool:
        """Zero walks: one misalignment for the whole drive (a mounting error), one key."""
        smoother = self.config.smoother
        return (
            smoother.nhc_misalignment_walk_deg_per_sqrt_s == 0.0
            and smoother.nhc_misalignment_vertical_walk_deg_per_sqrt_s == 0.0
            and smoother.nhc_misalignment_correlation_s == 0.0
        )

    @property
    def shared_keys(self) -> frozenset[int]:
        """States that are one key for the whole drive, shared by every keyframe (a constant
        misalignment, the odometer scale): carried along by the keyframe EKF, never
        marginalised out of a running iSAM2."""
        keys = set()
        if self.estimates_misalignment and self.constant_misalignment:
            keys.add(self.misalignment_key(0))
        if self.has_odometer:
            keys.add(odometer_model.scale_key())
        return frozenset(keys)

    def misalignment_key(self, k: int) -> int:
        """The misalignment state keyframe k's NHC uses."""
        return vehicle_model.misalignment_key(0 if self.constant_misalignment else k)

    def _add_misalignment(self, graph: gtsam.NonlinearFactorGraph, k: int) -> None:
        """The NHC misalignment's prior (k = 0) or its random walk from k - 1."""
        if not self.estimates_misalignment:
            return
        smoother = self.config.smoother
        key = vehicle_model.misalignment_key
        if k == 0:
            sigma = np.radians(smoother.nhc_misalignment_prior_deg)
            graph.add(vehicle_model.misalignment_prior(key(0), sigma))
            return
        if self.constant_misalignment:
            return
        if smoother.nhc_misalignment_correlation_s > 0.0:
            dt = float(self.segments.times[k] - self.segments.times[k - 1])
            graph.add(vehicle_model.misalignment_gauss_markov_factor(
                key(k - 1), key(k), dt, smoother.nhc_misalignment_correlation_s,
                float(np.radians(smoother.nhc_misalignment_prior_deg)),
            ))  # fmt: skip
            return
        walk = np.radians([
            smoother.nhc_misalignment_walk_deg_per_sqrt_s,
            smoother.nhc_misalignment_vertical_walk_deg_per_sqrt_s,
        ])  # fmt: skip
        dt = float(self.segments.times[k] - self.segments.times[k - 1])
        graph.add(vehicle_model.misalignment_walk_factor(key(k - 1), key(k), dt, walk))

    @property
    def nhc_keyframes(self) -> np.ndarray:
        """Keyframes that carry a non-holonomic constraint."""
        if not self.config.smoother.nhc:
            return np.zeros(0, dtype=int)
        return np.flatnonzero(self.vehicle_keyframe)

    def linear_factors(
        self, values: gtsam.Values, keyframes: np.ndarray | None = None
    ) -> gtsam.NonlinearFactorGraph:
        """NHC and odometer factors of ``keyframes`` (all by default), linearised at ``values``.

        These constraints have no GTSAM factor; see :mod:`fgins.factors.vehicle` for why they
        are linearised factors rebuilt in an outer loop rather than Python callbacks.
        """
        graph = gtsam.NonlinearFactorGraph()
        all_k = np.arange(self.n_keyframes) if keyframes is None else np.asarray(keyframes)
        nhc_k = all_k[self.vehicle_keyframe[all_k]] if self.config.smoother.nhc else all_k[:0]
        if len(nhc_k) == 1:  # one keyframe (an iSAM2 update): no batching overhead
            k = int(nhc_k[0])
            key = self.misalignment_key(k) if self.estimates_misalignment else None
            if key is not None and not values.exists(key):
                put_vector(values, key, np.zeros(2))  # not estimated yet: its initial value
            graph.add(
                vehicle_model.nhc_factor(
                    X(k), V(k), values.atPose3(X(k)).rotation().matrix(), values.atVector(V(k)),
                    self._nhc_rows, self.nhc_sigma[k], values, key, self.imu_to_vehicle[0],
                    self.nhc_offset[k],
                )
            )  # fmt: skip
        elif len(nhc_k):
            poses = [values.atPose3(X(int(k))) for k in nhc_k]
            velocity = np.array([values.atVector(V(int(k))) for k in nhc_k])
            misalignment_keys = misalignment = None
            if self.estimates_misalignment:
                misalignment_keys = np.array(
                    [self.misalignment_key(int(k)) for k in nhc_k], dtype=np.int64
                )
                # Not yet in ``values`` (an iSAM2 prediction): its initial value, zero.
                misalignment = np.array([
                    values.atVector(int(key)) if values.exists(int(key)) else np.zeros(2)
                    for key in misalignment_keys
                ])  # fmt: skip
            for factor in vehicle_model.nhc_factors(
                _keys(X, nhc_k), _keys(V, nhc_k), poses, velocity,
                vehicle_model.nhc_rows(self.imu_to_vehicle), self.nhc_sigma[nhc_k], values,
                misalignment_keys, misalignment, self.imu_to_vehicle[0],
                offset=self.nhc_offset[nhc_k],
            ):  # fmt: skip
                graph.add(factor)
        antenna_k, measured, sigma, gyro = self._antenna_velocities
        rows = self._antenna_row[all_k] if len(antenna_k) else all_k[:0]
        chosen = rows[rows >= 0]  # O(len(all_k)): an iSAM2 update asks for one keyframe
        if len(chosen):
            ks = antenna_k[chosen]
            rotation, velocity = rotations_and_velocities(values, ks)
            gyro_bias = np.array([values.atConstantBias(B(int(k))).gyroscope() for k in ks])
            for factor in gnss_model.antenna_velocity_factors(
                _keys(X, ks), _keys(V, ks), _keys(B, ks), rotation, velocity, gyro[chosen],
                gyro_bias, self._lever_arm, measured[chosen], sigma[chosen], values,
                self.config.gnss,
            ):  # fmt: skip
                graph.add(factor)
        odo_k = all_k[np.isfinite(self.odometer_speed[all_k])] if self.has_odometer else all_k[:0]
        if len(odo_k):
            poses = [values.atPose3(X(int(k))) for k in odo_k]
            velocity = np.array([values.atVector(V(int(k))) for k in odo_k])
            for factor in odometer_model.speed_factors(
                _keys(X, odo_k), _keys(V, odo_k), poses, velocity,
                values.atDouble(odometer_model.scale_key()), self.odometer_speed[odo_k],
                self.config.smoother.odometer_sigma_m_per_s, self.imu_to_vehicle[0], values,
            ):  # fmt: skip
                graph.add(factor)
        return graph

    def linear_factor_count(self, k: int) -> int:
        """How many factors :meth:`linear_factors` makes for keyframe k."""
        nhc = int(self.config.smoother.nhc and self.vehicle_keyframe[k])
        antenna = int(self._antenna_row[k] >= 0)
        return nhc + antenna + int(self.has_odometer and np.isfinite(self.odometer_speed[k]))

    def _add_gnss(self, graph: gtsam.NonlinearFactorGraph, k: int, config: GnssConfig) -> None:
        run_config = config is self.config.gnss
        factors = self._gnss_factors.get(k) if run_config else None
        if factors is None:
            factors = []
            g = int(self.gnss_at[k])
            if g >= 0 and k not in self.gnss_position_out:
                factors.append(
                    gnss_model.position_factor(X(k), self.gnss_enu[g], self.gnss_sigma[g], config)
                )
                measured = self.gnss_velocity_at(k)
                if measured is not None and not self.has_antenna_velocity:
                    factors.append(gnss_model.velocity_factor(V(k), *measured, config))
            if run_config:
                self._gnss_factors[k] = factors
        for factor in factors:
            graph.add(factor)

    def gnss_velocity_at(self, k: int) -> tuple[np.ndarray, np.ndarray] | None:
        """(velocity, sigma) of keyframe k's GNSS velocity, or None where it has none."""
        g = int(self.gnss_at[k])
        if g < 0:
            return None
        velocity = self.gnss_velocity[g].copy()
        sigma = self.gnss_velocity_sigma[g].copy()
        # The noise model leaves a velocity out (NaN sigma) where it is not trustworthy, e.g.
        # a course at walking speed.
        if not (self.config.gnss.use_velocity and np.all(np.isfinite(sigma[:2]))):
            return None
        if not np.isfinite(velocity[2]) or not np.isfinite(sigma[2]):
            velocity[2], sigma[2] = 0.0, 1e3  # horizontal-only (speed + course): vertical free
        return velocity, sigma

    @property
    def has_antenna_velocity(self) -> bool:
        """GNSS velocities are the antenna's, off the IMU by a lever arm: they go in as the
        linearised :func:`fgins.factors.gnss.antenna_velocity_factors` (the lever-arm
        velocity R (w x l) depends on the attitude and the gyro bias)."""
        return self.config.gnss.use_velocity and bool(np.any(self._lever_arm != 0))

    @property
    def _lever_arm(self) -> np.ndarray:
        return np.asarray(self.config.gnss.lever_arm_m, dtype=float)

    @property
    def antenna_velocity_keyframes(self) -> np.ndarray:
        """Keyframes whose GNSS velocity is an antenna velocity factor."""
        return self._antenna_velocities[0]

    @cached_property
    def _antenna_row(self) -> np.ndarray:
        """(K,) row of each keyframe in :attr:`_antenna_velocities`, -1 where none."""
        row = np.full(self.n_keyframes, -1)
        keyframes = self._antenna_velocities[0]
        row[keyframes] = np.arange(len(keyframes))
        return row

    @cached_property
    def _antenna_velocities(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(keyframes, measured velocity, sigma, gyro sample) of the antenna velocities."""
        keyframes: list[int] = []
        measured: list[np.ndarray] = []
        sigma: list[np.ndarray] = []
        if self.has_antenna_velocity:
            for k in np.flatnonzero(self.gnss_at >= 0):
                found = self.gnss_velocity_at(int(k))
                if found is not None:
                    keyframes.append(int(k))
                    measured.append(found[0])
                    sigma.append(found[1])
        k = np.array(keyframes, dtype=int)
        shape = (len(k), 3)
        gyro = self.gnss_gyro[self.gnss_at[k]] if len(k) else np.zeros(shape)
        return (
            k,
            np.array(measured).reshape(shape),
            np.array(sigma).reshape(shape),
            np.asarray(gyro).reshape(shape),
        )

    @cached_property
    def stop_candidates(self) -> np.ndarray:
        """(K,) keyframes that may be stops, once a speed confirms them: the IMU is quiet
        and the last seconds of fixes do not move (:func:`stationary.gnss_moving`)."""
        return self.quiet & ~self.gnss_moving

    def speed_confirms_stop(self, speed: float | None, sigma: float | None) -> bool:
        """Does a solution's speed (m/s, with its sigma when known) at a quiet keyframe
        confirm a stop? (:func:`fgins.factors.stationary.speed_confirms_stop`)"""
        return stationary.speed_confirms_stop(
            speed, sigma, self.config.smoother.zupt_max_speed_m_per_s
        )

    def _add_stop(
        self,
        graph: gtsam.NonlinearFactorGraph,
        k: int,
        predicted_speed: float | None,
        speed_sigma: float | None = None,
        slowed_to_a_stop: bool = True,
    ) -> None:
        smoother = self.config.smoother
        stopped = (
            smoother.zupt
            and bool(self.stop_candidates[k])
            and self.speed_confirms_stop(predicted_speed, speed_sigma)
            and not stationary.crawl_refuses_stop(self.crawling[k], predicted_speed)
            and slowed_to_a_stop
        )
        if stopped:
            graph.add(vehicle_model.zero_velocity_factor(V(k), smoother.zupt_sigma_m_per_s))
            if k - 1 in self.zupt_keyframes:
                # A random walk of NO_MOTION_RATE_SIGMA per sqrt(s): the same constraint per
                # second of standstill whatever the keyframe rate (a fixed 0.01 deg per
                # link made a 10 Hz receiver's stops 3x looser than a 1 Hz one's).
                dt = float(self.segments.times[k] - self.segments.times[k - 1])
                scale = np.sqrt(max(dt, 1e-3))
                graph.add(vehicle_model.no_motion_factor(
                    X(k - 1), X(k), NO_MOTION_RATE_SIGMA * scale, NO_MOTION_SPEED_SIGMA * scale
                ))  # fmt: skip
            self.zupt_keyframes.add(k)

    def _add_baro(self, graph: gtsam.NonlinearFactorGraph, k: int) -> None:
        if not self.has_baro:
            return
        smoother = self.config.smoother
        if k == 0:
            graph.add(
                gtsam.PriorFactorDouble(
                    baro_model.baro_key(0),
                    self.baro_bias0,
                    gtsam.noiseModel.Isotropic.Sigma(1, 100.0),
                )
            )
        else:
            dt = float(self.segments.times[k] - self.segments.times[k - 1])
            graph.add(
                baro_model.bias_walk_factor(
                    baro_model.baro_key(k - 1), baro_model.baro_key(k), dt,
                    smoother.baro_bias_walk_m_per_sqrt_s,
                )
            )  # fmt: skip
        if np.isfinite(self.baro_surface_pressure[k]):
            graph.add(self.pressure_factor(k))

    def pressure_factor(self, k: int) -> gtsam.BarometricFactor:
        """Keyframe k's barometer factor, its height taken down to the navigation frame's
        tangent plane by the current :attr:`baro_fall`."""
        return baro_model.pressure_factor(
            X(k), baro_model.baro_key(k), self.pressure_in_plane(k),
            self.config.smoother.baro_sigma_m,
        )  # fmt: skip

    def pressure_in_plane(self, k: int) -> float:
        """Keyframe k's pressure as if taken at the navigation frame's height there."""
        return float(
            stationary.pressure_in_plane(self.baro_surface_pressure[k], self.baro_fall[k])
        )

    def set_baro_fall(self, keyframes: np.ndarray, positions: np.ndarray) -> np.ndarray:
        """Take the plane fall of ``keyframes`` (those with a pressure) at ``positions``
        (ENU); returns the keyframes whose fall moved by more than ``BARO_FALL_REDO_M``
        (their pressure factors must be rebuilt)."""
        keyframes = np.asarray(keyframes, dtype=int)
        has = np.isfinite(self.baro_surface_pressure[keyframes])
        keyframes, positions = keyframes[has], np.asarray(positions, dtype=float)[has]
        if not len(keyframes):
            return keyframes
        fall = plane_fall(positions, self.dataset.origin)
        moved = np.abs(fall - self.baro_fall[keyframes]) > BARO_FALL_REDO_M
        self.baro_fall[keyframes[moved]] = fall[moved]
        return keyframes[moved]

    def baro_fall_moved(self, values: gtsam.Values) -> np.ndarray:
        """Redo the plane fall at the solution's positions (a chord between fixes across a
        long outage can cut a turn by a kilometre: 5 m of fall 32 km out); returns the
        keyframes whose pressure factor changed."""
        if not self.has_baro:
            return np.zeros(0, dtype=int)
        keyframes = np.flatnonzero(np.isfinite(self.baro_surface_pressure))
        position = np.array([values.atPose3(X(int(k))).translation() for k in keyframes])
        return self.set_baro_fall(keyframes, position)

    @cached_property
    def has_baro(self) -> bool:
        return bool(np.any(np.isfinite(self.baro_surface_pressure)))

    @property
    def baro_bias0(self) -> float:
        first = int(np.flatnonzero(np.isfinite(self.baro_surface_pressure))[0])
        # Up at the first baro keyframe is roughly the alignment's up (near the start).
        return baro_model.initial_bias(
            float(self.alignment.position[2]), self.pressure_in_plane(first)
        )

    def insert_extra_values(
        self, k: int, values: gtsam.Values, estimate: gtsam.Values | None = None
    ) -> None:
        """Initial values of keyframe k's non-navigation states (NHC misalignment, barometer
        bias, odometer scale factor)."""
        if self.estimates_misalignment and (k == 0 or not self.constant_misalignment):
            put_vector(values, self.misalignment_key(k), np.zeros(2))
        if k == 0 and np.any(np.isfinite(self.odometer_speed)):
            put_double(values, odometer_model.scale_key(), 0.0)
        if self.has_baro:
            key = baro_model.baro_key(k)
            previous = baro_model.baro_key(k - 1) if k > 0 else None
            if estimate is not None and previous is not None and estimate.exists(previous):
                put_double(values, key, estimate.atDouble(previous))
            else:
                put_double(values, key, self.baro_bias0)

    def gnss_whitened_residuals(self, values: gtsam.Values) -> tuple[np.ndarray, np.ndarray]:
        """(times, whitened residual east/north/up, one row per fix) of every GNSS position
        factor at an estimate, in the order of :attr:`gnss_used`."""
        keyframes = self.position_keyframes
        lever = np.asarray(self.config.gnss.lever_arm_m, dtype=float)
        whitened = np.empty((len(keyframes), 3))
        for i, k in enumerate(keyframes):
            g = int(self.gnss_at[k])
            pose = values.atPose3(X(int(k)))
            antenna = pose.translation() + pose.rotation().matrix() @ lever
            whitened[i] = (antenna - self.gnss_enu[g]) / self.gnss_sigma[g]
        return self.segments.times[keyframes], whitened

    def gnss_velocity_whitened_residuals(self, values: gtsam.Values) -> np.ndarray:
        """(n, 3) whitened residual east/north/up of every GNSS velocity factor at an
        estimate (the antenna's velocity ``v + R (w x l)`` less the measured), NaN up where
        the velocity has no vertical (speed and course)."""
        rows = []
        lever = self._lever_arm
        for k in np.flatnonzero(self.gnss_at >= 0):
            measured = self.gnss_velocity_at(int(k))
            if measured is None:
                continue
            velocity, sigma = measured
            g = int(self.gnss_at[k])
            rotation = values.atPose3(X(int(k))).rotation().matrix()
            rate = self.gnss_gyro[g] - values.atConstantBias(B(int(k))).gyroscope()
            antenna = gnss_model.antenna_velocity(rotation, values.atVector(V(int(k))), rate, lever)
            row = (antenna - velocity) / sigma
            if not np.isfinite(self.gnss_velocity[g, 2] + self.gnss_velocity_sigma[g, 2]):
                row[2] = np.nan  # gnss_velocity_at's placeholder: no vertical
            rows.append(row)
        return np.array(rows).reshape(-1, 3)

    def exclude_gnss(self, keyframes: set[int] | list[int]) -> None:
        """Leave the positions of the fixes at ``keyframes`` out of the graph (GNSS faults,
        fgins.graph.gnss_faults), every other one back in; an empty set restores all. Their
        velocities stay."""
        out = frozenset(int(k) for k in keyframes)
        for k in out ^ self.gnss_position_out:
            self._gnss_factors.pop(k, None)
        self.gnss_position_out = out
        # The counts say it: used + left out as faults + gated ... = total.
        if self._gnss_counts_all is None:
            self._gnss_counts_all = dict(self.info["gnss_counts"])  # type: ignore[arg-type]
        counts = dict(self._gnss_counts_all)
        counts["excluded_fault"] = len(out)
        counts["used"] -= len(out)
        self.info["gnss_counts"] = counts
        self.info["gnss_epochs_used"] = counts["used"]
        self.info["gnss_gating"] = _gating_summary(
            counts, counts["used"], counts["decimated"], self.config
        ) + gnss_model.dropped_on_read_note(self.dataset.metadata)

    @property
    def position_keyframes(self) -> np.ndarray:
        """Keyframes with a GNSS position factor (a used fix not left out as a fault)."""
        keyframes = np.flatnonzero(self.gnss_at >= 0)
        if not self.gnss_position_out:
            return keyframes
        return keyframes[~np.isin(keyframes, list(self.gnss_position_out))]

    @property
    def excluded_gnss_times(self) -> np.ndarray:
        """Times of the fixes whose positions are left out as faults (:meth:`exclude_gnss`)."""
        return self.segments.times[sorted(self.gnss_position_out)]

    @property
    def gnss_used(self) -> np.ndarray:
        """Rows (into the usable epochs) of the fixes with a position factor, by keyframe."""
        return self.gnss_at[self.position_keyframes]

    def preintegrate(self, i: int, bias: gtsam.imuBias.ConstantBias) -> None:
        """(Re)do interval i's preintegration about ``bias``."""
        params = self._params_for(i)
        self.pims[i] = _preintegrate(self.dataset.imu, self.segments, i, params, bias)
        self.pim_bias[i] = bias.vector()

    def _params_for(self, i: int) -> gtsam.PreintegrationCombinedParams:
        """Interval i's parameters: its noise (suspect stretches inflated) and the gravity
        where it lies; one parameter set per noise and gravity (rounded to
        ``GRAVITY_SAME_M_S2``), and the origin's within that of the origin's gravity."""
        base = self.suspect_params.get(i, self.params)
        gravity = self.interval_gravity[i]
        if np.all(np.abs(gravity - self.gravity) < GRAVITY_SAME_M_S2):
            return base
        key = (id(base), *np.round(gravity / GRAVITY_SAME_M_S2).astype(int).tolist())
        params = self._gravity_params.get(key)
        if params is None:
            params = imu_model.with_gravity(base, gravity)
            self._gravity_params[key] = params
        return params

    def gravity_moved(self, values: gtsam.Values) -> np.ndarray:
        """Intervals whose gravity at the solution's positions differs from the one they were
        preintegrated with (a long outage's chord between fixes cuts a turn by kilometres);
        their gravity is updated (to be re-preintegrated)."""
        position = np.array(
            [values.atPose3(X(k)).translation() for k in range(self.n_keyframes)]
        )
        gravity = gravity_enu(0.5 * (position[:-1] + position[1:]), self.dataset.origin)
        change = np.max(np.abs(gravity - self.interval_gravity), axis=1)
        # Not where the positions are not finite (a diverged estimate): no gravity there.
        moved = np.flatnonzero((change > GRAVITY_REDO_M_S2) & np.all(np.isfinite(gravity), axis=1))
        self.interval_gravity[moved] = gravity[moved]
        return moved

    def preintegrate_about(self, values: gtsam.Values) -> None:
        """Make the preintegration the one of the solution ``values``, which a solve from
        another start may have left otherwise: gravity where its positions are, every
        interval about its biases."""
        self.gravity_moved(values)
        bias = bias_estimates(values, self.n_keyframes)
        self.preintegrate_all(bias[:, :3], bias[:, 3:], False)

    def preintegrate_all(self, accel_bias: np.ndarray, gyro_bias: np.ndarray, progress: bool) -> None:
        """Every interval about the bias estimate at its first keyframe (K, 3) each."""
        from tqdm import tqdm  # imported on use, not with the module (import time)

        for i in tqdm(
            range(self.n_keyframes - 1), desc="preintegrating", unit="kf",
            disable=not progress, leave=False,
        ):  # fmt: skip
            self.preintegrate(i, gtsam.imuBias.ConstantBias(accel_bias[i], gyro_bias[i]))

    def repreintegrate(
        self, values: gtsam.Values, gyro_threshold: float, accel_threshold: float
    ) -> np.ndarray:
        """Redo the preintegration of intervals whose estimated bias moved far from the one
        they were integrated about: GTSAM's first-order bias correction is only good for
        small changes (a gyro-free IMU's rate error, a badly known turn-on bias). Returns the
        intervals redone."""
        estimate = bias_estimates(values, self.n_keyframes)[:-1]
        change = np.abs(estimate - self.pim_bias)  # NaN (never preintegrated): not redone
        redo = np.flatnonzero(
            (change[:, 3:].max(axis=1) > gyro_threshold)
            | (change[:, :3].max(axis=1) > accel_threshold)
        )
        redo = np.union1d(redo, self.gravity_moved(values)).astype(int)
        for i in redo:
            self.preintegrate(int(i), gtsam.imuBias.ConstantBias(estimate[i, :3], estimate[i, 3:]))
        return redo

    def rescale_gyro(self, scale: np.ndarray, values: gtsam.Values) -> None:
        """Divide the gyro's samples by ``scale`` (per axis: read over true rate) and
        re-preintegrate every interval about its bias in ``values``
        (:mod:`fgins.graph.gyro_scale`)."""
        self.remap_gyro(np.diag(1.0 / np.asarray(scale, dtype=float)), values)

    def remap_gyro(self, matrix: np.ndarray, values: gtsam.Values) -> None:
        """Replace the gyro's samples w by ``matrix`` @ w (a rescale, an axis negated or two
        swapped) and re-preintegrate every interval about its bias in ``values``, mapped
        alike."""
        matrix = np.asarray(matrix, dtype=float)
        imu = self.dataset.imu
        self.dataset = replace(self.dataset, imu=replace(imu, gyro=imu.gyro @ matrix.T))
        estimate = bias_estimates(values, self.n_keyframes)[:-1]
        estimate[:, 3:] = estimate[:, 3:] @ matrix.T
        for i in range(self.n_keyframes - 1):
            self.preintegrate(i, gtsam.imuBias.ConstantBias(estimate[i, :3], estimate[i, 3:]))

    def predict(
        self, k: int, state: gtsam.NavState, bias: gtsam.imuBias.ConstantBias
    ) -> gtsam.NavState:
        """State at keyframe k+1 predicted from keyframe k."""
        return self.pims[k].predict(state, bias)


def bias_estimates(values: gtsam.Values, n_keyframes: int) -> np.ndarray:
    """(K, 6) every keyframe's bias in ``values``: accelerometer, gyro (ConstantBias order)."""
    return np.array([values.atConstantBias(B(k)).vector() for k in range(n_keyframes)])


def rotations_and_velocities(
    values: gtsam.Values, keyframes: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3, 3) attitudes and (n, 3) velocities of ``keyframes`` in ``values``."""
    rotation = np.array([values.atPose3(X(int(k))).rotation().matrix() for k in keyframes])
    velocity = np.array([values.atVector(V(int(k))) for k in keyframes])
    return rotation.reshape(-1, 3, 3), velocity.reshape(-1, 3)


def _keys(symbol, keyframes: np.ndarray) -> np.ndarray:
    return np.array([symbol(int(k)) for k in keyframes], dtype=np.int64)


def _gating_summary(counts: dict[str, int], used: int, decimated: int, config: RunConfig) -> str:
    parts = [f"{used} used"]
    if counts.get("excluded_fault"):
        parts.append(f"{counts['excluded_fault']} left out as faults")
    if counts["withheld"]:
        parts.append(f"{counts['withheld']} withheld by outage")
    pdop = config.gnss.pdop_max
    parts.append(f"{counts['gated_pdop']} gated by PDOP > {pdop:g}" if pdop else "no PDOP gate")
    parts.append(f"{counts['gated_quality']} by fix quality")
    if counts["outside_imu_span"]:
        parts.append(f"{counts['outside_imu_span']} outside the IMU time span")
    if decimated:
        parts.append(f"{decimated} decimated (faster than the keyframe rate)")
    return f"GNSS: {counts['total']} epochs: " + ", ".join(parts)


def build_problem(
    dataset: Dataset, config: RunConfig, gnss_mask: np.ndarray | None = None, progress: bool = True
) -> Problem:
    """Keyframes and GNSS assignment (preintegration comes later, about a bias estimate).
    ``gnss_mask`` withholds epochs (outages)."""
    usable, counts = gnss_model.select_epochs(dataset, config.gnss, gnss_mask)
    gnss_model.require_usable_fixes(dataset, config.gnss, gnss_mask, usable, counts)
    imu = dataset.imu
    noise, bias_notes = imu_model.conditioned_noise(
        config.imu_noise(), float(imu.t[-1] - imu.t[0])
    )
    gnss = dataset.gnss.subset(usable)
    enu = dataset.gnss_enu()[usable]
    sigma = gnss_model.position_sigmas(gnss, config.gnss)
    velocity_sigma = gnss_model.velocity_sigmas(gnss, config.gnss)
    imu_to_vehicle = mounting_rotation(config.smoother.imu_to_vehicle_rpy_deg)
    alignment = initial_alignment(
        dataset, usable, smoother=config.smoother, gyro_bias_sigma=noise.gyro_bias_prior
    )

    decimated = _decimate(gnss.t, config.smoother.min_keyframe_interval_s)
    times = keyframe_times(
        imu, gnss.t[decimated], config.smoother.max_keyframe_interval_s,
        config.smoother.min_keyframe_interval_s,
    )  # fmt: skip
    segments = build_segments(imu, times)
    gnss_at = np.full(len(times), -1)
    position = np.searchsorted(times, gnss.t)
    position = np.clip(position, 0, len(times) - 1)
    matched = np.isclose(times[position], gnss.t, rtol=0, atol=1e-9) & decimated
    gnss_at[position[matched]] = np.flatnonzero(matched)

    params = imu_model.preintegration_params(noise, dataset.origin)
    suspect_params = _suspect_params(imu, segments, noise, config, dataset)
    smoother = config.smoother
    quiet = (
        # Rates derived from an accelerometer array ramp at rest: judge stops by the specific
        # force alone (each stop is still confirmed by the solution's speed, _add_stop).
        stationary.quiet_imu(imu, times, noise, use_gyro=dataset.accel_array is None)
        if smoother.zupt
        else np.zeros(len(times), dtype=bool)
    )
    baro_surface_pressure = stationary.pressure_at(dataset.baro, times)
    baro_fall = stationary.plane_fall_along_fixes(times, gnss.t, enu, dataset.origin)
    vehicle_keyframe = _decimate(times, smoother.vehicle_constraint_interval_s)
    odometer_speed = np.where(vehicle_keyframe, _odometer_at(dataset, times), np.nan)
    nhc_sigma = np.tile(
        [smoother.nhc_sigma_lateral_m_per_s, smoother.nhc_sigma_vertical_m_per_s],
        (len(times), 1),
    )
    nhc_offset = nhc_point_velocity(
        imu, times, imu_to_vehicle, smoother.nhc_lever_arm_m
    ) if smoother.nhc else np.zeros((len(times), 2))  # fmt: skip
    return Problem(
        dataset=dataset,
        config=config,
        noise=noise,
        segments=segments,
        pims=[None] * (len(times) - 1),
        pim_bias=np.full((len(times) - 1, 6), np.nan),
        params=params,
        suspect_params=suspect_params,
        gnss_at=gnss_at,
        gnss_enu=enu,
        gnss_sigma=sigma,
        gnss_sigma_modelled=gnss_model.sigmas_from_dop_model(gnss, config.gnss),
        gnss_velocity=None if gnss.velocity is None else dataset.gnss_velocity_nav()[usable],
        gnss_gyro=imu.gyro[np.clip(np.searchsorted(imu.t, gnss.t, side="right") - 1, 0, len(imu) - 1)],
        gnss_velocity_sigma=velocity_sigma,
        alignment=alignment,
        gravity=np.array([0.0, 0.0, -normal_gravity(dataset.origin.lat, dataset.origin.alt)]),
        interval_gravity=_interval_gravity_from_fixes(times, gnss.t, enu, dataset.origin),
        omega_earth=earth_rate_enu(dataset.origin.lat),
        quiet=quiet,
        gnss_moving=stationary.gnss_moving(
            times, gnss.t, enu, sigma, moving_before_fixes=alignment.steady_motion_possible
        ),
        crawling=stationary.gnss_moving(
            times, gnss.t, enu, sigma, window_s=stationary.CRAWL_WINDOW_S
        ),
        baro_surface_pressure=baro_surface_pressure,
        baro_fall=baro_fall,
        odometer_speed=odometer_speed,
        imu_to_vehicle=imu_to_vehicle,
        nhc_sigma=nhc_sigma,
        nhc_offset=nhc_offset,
        vehicle_keyframe=vehicle_keyframe,
        gnss_mask=gnss_mask,
        info={
            "gnss_gating": _gating_summary(
                counts, int(matched.sum()), int((~decimated).sum()), config
            )
            + gnss_model.dropped_on_read_note(dataset.metadata),
            "gnss_counts": {**counts, "used": int(matched.sum()),
                            "decimated": int((~decimated).sum())},
            "gnss_epochs_used": int(matched.sum()),
            "gnss_epochs_decimated": int((~decimated).sum()),
            "keyframes": len(times),
            "suspect_intervals": int(segments.suspect.sum()),
            **({"imu_bias_model": "; ".join(bias_notes)} if bias_notes else {}),
        },
    )


# Gravity per interval: one parameter set per 1e-6 m/s^2 (0.1 ug) of gravity; re-preintegrated
# when a solution puts an interval where gravity differs by more than 1.5e-5 m/s^2 (1.5 ug,
# ~10 m of horizontal distance: a long outage's chord between fixes, not the fixes' noise; a
# navigation-grade accelerometer's bias is ~25 ug).
GRAVITY_SAME_M_S2 = 1e-6
GRAVITY_REDO_M_S2 = 1.5e-5


def _interval_gravity_from_fixes(
    times: np.ndarray, gnss_t: np.ndarray, enu: np.ndarray, origin
) -> np.ndarray:
    """(K-1, 3) gravity at the middle of each interval, its position interpolated between
    the usable fixes (held before the first and after the last)."""
    middle = 0.5 * (times[:-1] + times[1:])
    position = np.column_stack([np.interp(middle, gnss_t, enu[:, j]) for j in range(3)])
    return gravity_enu(position, origin)


def _preintegrate(
    imu, segments: Segments, i: int, params, bias: gtsam.imuBias.ConstantBias
) -> gtsam.PreintegratedCombinedMeasurements:
    """Preintegrate keyframe interval i's IMU segments about ``bias``."""
    span = segments.interval(i)
    samples = segments.sample[span]
    pim = gtsam.PreintegratedCombinedMeasurements(params, bias)
    accel = segments.accel(imu.accel, imu.gyro, span)
    imu_model.integrate(pim, accel, imu.gyro[samples], segments.dt[span])
    return pim


def _suspect_params(
    imu, segments: Segments, noise: ImuNoise, config: RunConfig, dataset: Dataset
) -> dict[int, gtsam.PreintegrationCombinedParams]:
    """Per suspect interval, the inflated noise of its stretch (by the stretch's length:
    :meth:`fgins.config.ImuNoise.suspect`); one parameter set per stretch."""
    out: dict[int, gtsam.PreintegrationCombinedParams] = {}
    mid = 0.5 * (segments.times[:-1] + segments.times[1:])
    for a, b in imu.suspect:
        inside = np.flatnonzero((mid > a) & (mid < b))
        if len(inside):
            params = imu_model.preintegration_params(
                noise.suspect(config.smoother.suspect_noise_factor, b - a), dataset.origin
            )
            out.update({int(i): params for i in inside})
    return out


def _decimate(t: np.ndarray, min_interval: float) -> np.ndarray:
    """Keep epochs at least ``min_interval`` after the previously kept one."""
    keep = np.zeros(len(t), dtype=bool)
    last = -np.inf
    for i, ti in enumerate(t):
        if ti - last >= min_interval - 1e-9:
            keep[i] = True
            last = ti
    return keep


def _odometer_at(dataset: Dataset, times: np.ndarray, half_window_s: float = 0.1) -> np.ndarray:
    """Mean wheel speed within +-half_window_s of each keyframe (NaN where none)."""
    out = np.full(len(times), np.nan)
    odometer = dataset.odometer
    if odometer is None:
        return out
    valid = np.isfinite(odometer.speed)
    t, speed = odometer.t[valid], odometer.speed[valid]
    lo = np.searchsorted(t, times - half_window_s)
    hi = np.searchsorted(t, times + half_window_s)
    for k, (a, b) in enumerate(zip(lo, hi, strict=True)):
        if b > a:
            out[k] = speed[a:b].mean()
    return out
