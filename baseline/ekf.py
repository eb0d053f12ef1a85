"""Loosely coupled error-state EKF and EKF + Rauch-Tung-Striebel smoother (numpy only).

Fifteen error states (position, velocity, attitude error ``phi`` in ENU, accelerometer and
gyro bias) around a nominal strapdown solution, with closed-loop feedback: after every GNSS
update the estimated errors are injected into the nominal state and reset to zero. Same
inputs as the factor graph (:class:`~fgins.datatypes.Dataset`, :class:`~fgins.config.RunConfig`),
same initial state and uncertainty (:func:`fgins.alignment.initial_alignment`), same GNSS
epochs, gating, sigmas and lever arm (:mod:`fgins.factors.gnss`), same navigation model
(:mod:`fgins.baseline.mechanization`), same output (:class:`~fgins.datatypes.Trajectory` at every
IMU sample).

Land vehicles and barometers: with ``config.smoother.nhc`` / ``zupt`` and a dataset with
pressure, the filter also gets the graph's non-holonomic, zero-velocity / zero-rate and
barometric height information as pseudo-measurements at its block boundaries
(:mod:`fgins.baseline.vehicle_updates`); a barometer appends its bias as a 16th error state,
which the RTS pass smooths with the rest.

The IMU stream is processed in blocks that end at each usable GNSS epoch (the sample that
straddles an epoch is split there, so updates happen at the exact epoch time) and at most
``max_block_s`` apart in outages. Within a block the nominal state is mechanized at every
sample and the block's transition Phi and process noise Q are the exact compositions of the
per-sample ones; covariances of the output rows inside a block are interpolated linearly
between its a-posteriori start and a-priori end.

The RTS smoother runs backwards over the block boundaries with the stored Phi, a-priori and
a-posteriori covariances; the smoothed error-state corrections (relative to the forward
nominal trajectory at the start and end of each block) are interpolated linearly onto the IMU
samples inside the block. Where those corrections turn the attitude by more than a
linearisation carries, the pass is repeated linearised about the smoothed states
(:func:`relinearised_passes`, an iterated extended Kalman smoother).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, Self

import numpy as np

from fgins.alignment import initial_alignment
from fgins.antenna_verdict import (
    ANTENNA_PRIOR_SIGMAS,
    MIN_FIXES,
    antenna_verdict,
    drift_time_base,
    typical_speed,
)
from fgins.baseline.heading_consider import HeadingGate
from fgins.baseline.measurements import (
    AntennaStates,
    GapReturnMiss,
    GnssEpochs,
    Linearized,
    chi2_quantile,
    gap_return_miss,
    huber_variances,
    kalman_update,
    linearize_gnss,
    pad_columns,
    select_gnss,
)
from fgins.baseline.mechanization import (
    ACC_BIAS,
    ATT,
    GYRO_BIAS,
    POS,
    STATE_DIM,
    VEL,
    BlockNominal,
    NavFrame,
    NominalState,
    Segments,
    augment_transition,
    block_times,
    block_transition,
    coarse_block_transition,
    propagate_nominal,
    segment_imu,
)
from fgins.baseline.vehicle_updates import VehicleAiding, vehicle_aiding
from fgins.config import ImuNoise, RunConfig, constant_bias_noise
from fgins.datatypes import Dataset, FginsError, InputError, Trajectory
from fgins.factors.imu_samples import cut_sample_accel
from fgins.geodesy import so3_exp
from fgins.initial_guess import KeyframeGuess

# 1-sigma of an initial heading the configuration supplies (``smoother.initial_heading_deg``):
# fgins.alignment's own value for a configured heading when it starts moving. Its at-rest
# branch gives a configured heading the 15 deg of a heading guessed from the first motion.
CONFIGURED_HEADING_SIGMA_RAD = np.radians(2.0)


@dataclass(frozen=True)
class EkfOptions:
    """Filter settings that the shared :class:`RunConfig` does not carry.

    ``innovation_gate_probability``: reject a GNSS epoch whose normalised innovation squared
    exceeds the chi-square quantile of this probability (None: no gate, the default, like the
    graph). ``max_block_s``: longest propagation block (covariance rows inside are
    interpolated, so keep it short).
    """

    max_block_s: float = 1.0
    innovation_gate_probability: float | None = None
    # None: each block's Phi and Q composed over every IMU sample (exact); n: over at most n
    # merged sub-steps (:func:`~fgins.baseline.mechanization.coarse_block_transition`), the
    # initial guess's setting (a start for the smoother, not an output).
    transition_steps: int | None = None

    def __post_init__(self) -> None:
        if not self.max_block_s > 0:
            raise InputError(f"EKF: max_block_s must be > 0, got {self.max_block_s}")
        p = self.innovation_gate_probability
        if p is not None and not 0.5 < p < 1.0:
            raise InputError(f"EKF: innovation_gate_probability must be in (0.5, 1), got {p}")
        if self.transition_steps is not None and self.transition_steps < 1:
            raise InputError(f"EKF: transition_steps must be >= 1, got {self.transition_steps}")


@dataclass
class FilterRun:
    """Everything the forward pass produces (and the RTS smoother needs).

    The error state is 15 navigation states plus any augmented ones (barometer bias), so
    covariances are (K, n, n) with n = 15 + extra (see :mod:`fgins.baseline.vehicle_updates`).
    """

    segments: Segments
    # Nominal states at every node (segment starts + final time), forward in time: inside
    # block b they are the propagation from the a-posteriori state at boundary b.
    rotation: np.ndarray
    velocity: np.ndarray
    position: np.ndarray
    accel_bias: np.ndarray  # (nodes, 3) bias used while propagating
    gyro_bias: np.ndarray
    # Per block boundary k (K = len(segments.times)).
    prior: list[NominalState]
    posterior: list[NominalState]
    cov_prior: np.ndarray  # (K, n, n)
    cov_posterior: np.ndarray  # (K, n, n)
    transition: np.ndarray  # (K-1, n, n), block k -> k+1 about the posterior at k
    counts: dict[str, int] = field(default_factory=dict)
    rejected_times: list[float] = field(default_factory=list)  # GNSS epochs failing the gate
    zupt_times: list[float] = field(default_factory=list)  # boundaries taken as stops
    # rts_smooth's result, kept: iterated_forward's check of the last pass is the output's.
    smoothed: tuple[np.ndarray, np.ndarray, np.ndarray] | None = field(default=None, repr=False)
    # EKF+RTS: its last plain forward pass's worst miss of the first fix after a gap
    # (gap_return_miss; relinearised passes predict about the smoothed states, not causally).
    forward_gap_miss: GapReturnMiss | None = None


def initial_covariance(
    rotation: np.ndarray,
    attitude_sigma: np.ndarray,
    velocity_sigma: float,
    position_sigma: float,
    noise: ImuNoise,
    extra_variance: np.ndarray | None = None,
) -> np.ndarray:
    """P0 from the alignment sigmas (tilt about east and north, heading about up: the
    navigation frame, whatever the IMU's axes; the graph's Pose3 prior is the same
    covariance seen from the body), the turn-on bias priors and the priors of any
    augmented states."""
    extra = np.zeros(0) if extra_variance is None else np.asarray(extra_variance, dtype=float)
    dim = STATE_DIM + len(extra)
    p0 = np.zeros((dim, dim))
    p0[POS, POS] = np.eye(3) * position_sigma**2
    p0[VEL, VEL] = np.eye(3) * velocity_sigma**2
    del rotation  # the error state's attitude is in the navigation frame already
    p0[ATT, ATT] = np.diag(np.asarray(attitude_sigma) ** 2)
    p0[ACC_BIAS, ACC_BIAS] = np.eye(3) * noise.accel_bias_prior**2
    p0[GYRO_BIAS, GYRO_BIAS] = np.eye(3) * noise.gyro_bias_prior**2
    p0[STATE_DIM:, STATE_DIM:] = np.diag(extra)
    return p0


def configured_heading_sigma(
    attitude_sigma: np.ndarray, initial_heading_deg: float | None
) -> np.ndarray:
    """Alignment sigmas (tilt about east, north; heading about up) with the heading sigma of a heading
    that the configuration gives, rather than one guessed from the first motion.

    Why it matters: a linearised filter is only as good as its prior is honest. With 15 deg of
    claimed heading doubt at rest (the true error is the configuration's), a consumer gyro
    turn-on bias of 3 sigma (highway seed 108: 1.5 deg/s) tilts the platform during the slow
    start, and the filter explains the resulting cross-track velocity error by a heading error
    that its prior allows: the heading estimate moved 34 deg away from the truth while its
    sigma shrank to 9 deg, and the filter never recovered (velocity NEES 55). With the 2 deg
    of a configured heading the same run has velocity NEES 1.3.
    """
    if initial_heading_deg is None:
        return attitude_sigma
    out = attitude_sigma.copy()
    out[2] = min(out[2], CONFIGURED_HEADING_SIGMA_RAD)
    return out


@dataclass
class FilterSetup:
    """What every Kalman baseline's forward pass starts from, built once by
    :func:`prepare_filter`: the GNSS epochs, the blocks, the pseudo-measurements, P0, x0."""

    epochs: GnssEpochs
    noise: ImuNoise
    frame: NavFrame
    segments: Segments
    gnss_at: np.ndarray  # (K,) GNSS epoch at each boundary, -1 where none
    white_scale: np.ndarray  # (segments, 2) accel, gyro white-noise inflation (suspect IMU)
    aiding: VehicleAiding
    state: NominalState
    cov: np.ndarray
    gyro_at: np.ndarray  # (segments, 3) IMU sample held over each segment
    accel_at: np.ndarray
    counts: dict[str, int]
    heading: HeadingGate  # whether a block couples the heading into the velocity
    # Each GNSS update's normalised innovation squared per dimension (the filter's own
    # consistency: ~1 for a filter whose covariance holds, see :func:`median_nis`).
    gnss_nis: list[float] = field(default_factory=list)
    # The antenna's augmented error states (after the barometer bias), None without them
    # (:func:`antenna_about`).
    antenna: AntennaStates | None = None

    @property
    def times(self) -> np.ndarray:
        return self.segments.times

    def block_process_noise(
        self, b: int, phi: np.ndarray, q: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """A block's 15-state Phi, Q extended to the augmented states (the antenna's are
        constants: no process noise)."""
        dt = float(self.times[b + 1] - self.times[b])
        extra = self.aiding.extra_process_variance(dt)
        if self.antenna is not None:
            extra = np.append(extra, np.zeros(5))
        return augment_transition(phi, q, extra)


def prepare_filter(
    dataset: Dataset,
    config: RunConfig,
    gnss_mask: np.ndarray | None,
    max_block_s: float,
    antenna_prior: np.ndarray | None = None,
) -> FilterSetup:
    """Shared setup of the EKF and UKF forward passes (same inputs as the factor graph).
    With ``antenna_prior`` (5 sigmas), the antenna's offset from the configured arm, the
    fixes' time offset and its drift are augmented states (zero mean; :class:`AntennaStates`),
    last of the error state."""
    imu = dataset.imu
    epochs = select_gnss(dataset, config, gnss_mask)
    # A constant bias is the graph's: fgins.config.constant_bias_noise.
    noise, _ = constant_bias_noise(config.imu_noise(), float(imu.t[-1] - imu.t[0]))
    frame = NavFrame.at(dataset.origin)
    align = initial_alignment(
        dataset, epochs.usable, smoother=config.smoother, gyro_bias_sigma=noise.gyro_bias_prior
    )
    times = block_times(float(imu.t[0]), float(imu.t[-1]), epochs.t, max_block_s)
    segments = segment_imu(imu.t, times)
    # Which boundary carries which GNSS epoch (-1: none).
    boundary = np.clip(np.searchsorted(times, epochs.t), 0, len(times) - 1)
    matched = np.isclose(times[boundary], epochs.t, rtol=0.0, atol=1e-9)
    if not np.all(matched):  # cannot happen: epochs are block boundaries by construction
        raise FginsError("Kalman filter: a GNSS epoch fell between block boundaries (internal)")
    gnss_at = np.full(len(times), -1)
    gnss_at[boundary] = np.arange(len(epochs.t))
    # Suspect stretches: the graph's inflation (ImuNoise.suspect), per sensor, as a scale.
    white_scale = np.ones((len(segments.dt), 2))
    for a, b in imu.suspect:
        inside = (segments.start >= a) & (segments.start < b)
        inflated = noise.suspect(config.smoother.suspect_noise_factor, b - a)
        white_scale[inside] = [
            inflated.accel_noise / noise.accel_noise, inflated.gyro_noise / noise.gyro_noise
        ]
    aiding = vehicle_aiding(dataset, config, times, noise, frame.earth_rate, epochs)
    extra, extra_variance = aiding.initial_extra(float(align.position[2]))
    antenna = None
    if antenna_prior is not None:
        middle, half_span = drift_time_base(epochs.t)
        antenna = AntennaStates(index=STATE_DIM + len(extra), middle=middle, half_span=half_span)
        extra = np.append(extra, np.zeros(5))
        extra_variance = np.append(extra_variance, np.asarray(antenna_prior, dtype=float) ** 2)
    rotation = np.asarray(align.rotation, dtype=float)
    attitude_sigma = configured_heading_sigma(
        np.asarray(align.attitude_sigma_rad, dtype=float), config.smoother.initial_heading_deg
    )
    state = NominalState(
        rotation=rotation,
        velocity=np.asarray(align.velocity, dtype=float),
        position=np.asarray(align.position, dtype=float),
        accel_bias=np.zeros(3),
        gyro_bias=np.zeros(3),
        extra=extra,
    )
    cov = initial_covariance(
        rotation,
        attitude_sigma,
        align.velocity_sigma,
        align.position_sigma,
        noise,
        extra_variance,
    )
    counts = {
        "gnss_updates": 0,
        "velocity_updates": 0,
        "rejected_innovation": 0,
        "huber_downweighted": 0,
    }
    return FilterSetup(
        epochs=epochs,
        noise=noise,
        frame=frame,
        segments=segments,
        gnss_at=gnss_at,
        white_scale=white_scale,
        aiding=aiding,
        state=state,
        cov=cov,
        gyro_at=imu.gyro[segments.sample],
        accel_at=cut_sample_accel(imu.accel[segments.sample], imu.gyro[segments.sample], segments.lead),
        counts=counts,
        heading=HeadingGate(gravity=float(-frame.gravity[2]), accel_noise=noise.accel_noise),
        antenna=antenna,
    )


def _progress(blocks: range, desc: str, progress: bool):
    """A tqdm bar over the blocks when asked for; tqdm is imported only then (import time)."""
    if not progress:
        return blocks
    from tqdm import tqdm

    return tqdm(blocks, desc=desc, unit="block", leave=False)


GnssUpdate = Callable[[int, NominalState, np.ndarray, np.ndarray], tuple[NominalState, np.ndarray]]


class FilterRecorder:
    """Runs the boundary updates (GNSS, then the vehicle/barometer pseudo-measurements) and
    records what the RTS smoother and the output need, for any forward filter."""

    # Phi/Q of a block over every sample (None) or at most this many sub-steps (EkfOptions).
    transition_steps: int | None = None

    def __init__(self, setup: FilterSetup, imu_t: np.ndarray, gyro: np.ndarray) -> None:
        self.setup = setup
        self._imu_t = imu_t
        self._gyro = gyro
        n_nodes = len(setup.segments.start) + 1
        n_boundaries = len(setup.times)
        dim = len(setup.cov)
        self.rotation = np.empty((n_nodes, 3, 3))
        self.velocity = np.empty((n_nodes, 3))
        self.position = np.empty((n_nodes, 3))
        self.accel_bias = np.empty((n_nodes, 3))
        self.gyro_bias = np.empty((n_nodes, 3))
        self.cov_prior = np.empty((n_boundaries, dim, dim))
        self.cov_posterior = np.empty_like(self.cov_prior)
        self.transition = np.empty((n_boundaries - 1, dim, dim))
        self.prior: list[NominalState] = []
        self.posterior: list[NominalState] = []

    def boundary(
        self, k: int, state: NominalState, cov: np.ndarray, gnss_update: GnssUpdate
    ) -> tuple[NominalState, np.ndarray]:
        self.prior.append(state.copy())
        self.cov_prior[k] = cov
        state, cov = self.update(k, state, cov, gnss_update)
        self.posterior.append(state.copy())
        self.cov_posterior[k] = cov
        return state, cov

    def update(
        self, k: int, state: NominalState, cov: np.ndarray, gnss_update: GnssUpdate
    ) -> tuple[NominalState, np.ndarray]:
        """The measurement updates at boundary ``k``: GNSS, then the vehicle pseudo-ones."""
        g = int(self.setup.gnss_at[k])
        if g >= 0:
            t = self.setup.times[k]
            sample = min(
                int(np.searchsorted(self._imu_t, t, side="right")) - 1, len(self._imu_t) - 1
            )
            state, cov = gnss_update(g, state, cov, self._gyro[sample])
            self.setup.aiding.fix_applied(t)
            self.setup.heading.fix_applied()
        return self.setup.aiding.update(k, state, cov, self.setup.heading.decoupled)

    def store_nodes(self, span: slice, nodes: NominalState) -> None:
        """Nominal states at the nodes of a block (all but its end node)."""
        rows = slice(span.start, span.stop)
        self.rotation[rows] = nodes.rotation[:-1]
        self.velocity[rows] = nodes.velocity[:-1]
        self.position[rows] = nodes.position[:-1]
        self.accel_bias[rows] = nodes.accel_bias[:-1]
        self.gyro_bias[rows] = nodes.gyro_bias[:-1]

    def block_noise(
        self, b: int, span: slice, central: BlockNominal, cov: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Phi and Q of block ``b`` about the propagation ``central`` (augmented states
        included); Phi is recorded for the RTS smoother. With ``cov`` (the covariance at the
        block's start), a heading the block's motion cannot tell is decoupled
        (:class:`fgins.baseline.heading_consider.HeadingGate`)."""
        phi, q = self._block_noise(b, span, central, cov)
        self.transition[b] = phi
        return phi, q

    def _block_noise(
        self, b: int, span: slice, central: BlockNominal, cov: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        setup = self.setup
        phi, q = self._transition(b, span, central)
        if cov is not None:
            phi, q = setup.heading.transition(
                phi, q, cov, central.specific_force_nav, setup.segments.dt[span],
                central.rotation[0], central.velocity[0],
            )  # fmt: skip
        return setup.block_process_noise(b, phi, q)

    def _transition(
        self, b: int, span: slice, central: BlockNominal
    ) -> tuple[np.ndarray, np.ndarray]:
        """The block's 15-state Phi and Q."""
        setup = self.setup
        dt = setup.segments.dt[span]
        if self.transition_steps is None:
            phi, q = block_transition(
                central, dt, setup.frame, setup.noise, setup.white_scale[span]
            )
        else:
            phi, q = coarse_block_transition(
                central, dt, setup.frame, setup.noise, setup.white_scale[span],
                self.transition_steps,
            )  # fmt: skip
        return phi, q

    def _counts(self) -> dict[str, int]:
        setup = self.setup
        return {
            **setup.counts,
            **setup.aiding.counts,
            "blocks": len(setup.times) - 1,
            "gnss_epochs_used": len(setup.epochs.t),
            "gnss_epochs_outside_imu_span": setup.epochs.outside_imu_span,
            "augmented_states": setup.aiding.n_extra,
            "gnss_nis_median": median_nis(setup.gnss_nis),
            # The fit the antenna and clock corrections compare (fgins.corrections): outliers
            # count here, as in the graph's chi2/dof.
            "gnss_nis_mean": float(np.mean(setup.gnss_nis)) if setup.gnss_nis else float("nan"),
        }

    def finish(self, state: NominalState, rejected_times: list[float]) -> FilterRun:
        # The final node is the last boundary's a-posteriori state.
        self.rotation[-1], self.velocity[-1], self.position[-1] = (
            state.rotation,
            state.velocity,
            state.position,
        )
        self.accel_bias[-1], self.gyro_bias[-1] = state.accel_bias, state.gyro_bias
        setup = self.setup
        counts = self._counts()
        return FilterRun(
            segments=setup.segments,
            rotation=self.rotation,
            velocity=self.velocity,
            position=self.position,
            accel_bias=self.accel_bias,
            gyro_bias=self.gyro_bias,
            prior=self.prior,
            posterior=self.posterior,
            cov_prior=self.cov_prior,
            cov_posterior=self.cov_posterior,
            transition=self.transition,
            counts=counts,
            rejected_times=list(rejected_times),
            zupt_times=list(setup.aiding.zupt_times),
        )


class LinearisationLost(Exception):
    """A pass linearised about a reference found the filter's estimate too far from it."""


# The largest attitude error from the reference a relinearised pass carries (rad).
MAX_REFERENCE_TURN_RAD = 0.5 * np.pi


class ReferenceUpdates:
    """The updates of a pass linearised about ``reference`` (a state per boundary), for a
    recorder class listed after this one (see :class:`ReferenceRecorder`).

    The updates (GNSS, then the vehicle and barometer ones) run on the reference, giving its
    correction ``K r(L)`` and the covariance ``P+ = (I - K H) P-``; the filter's error from
    the reference ``e`` then updates as in any linear Kalman filter, ``e+ = (I - K H) e- +
    K r(L)``, with ``I - K H = P+ P-^-1`` (that of the whole sequence of updates). A car's
    non-holonomic constraint taken at a filter estimate 9 deg and 70 m off in an outage, as
    the forward pass's was, is no model of the drive; at the smoothed states it is."""

    reference: list[NominalState]

    def update(
        self, k: int, state: NominalState, cov: np.ndarray, gnss_update: GnssUpdate
    ) -> tuple[NominalState, np.ndarray]:
        about = self.reference[k]
        error = state.boxminus(about)
        corrected, cov_after = super().update(k, about.copy(), cov, gnss_update)  # type: ignore[misc]
        # P+ P-^-1 e, in correlation form (variances from 1e2 m^2 to 1e-10 (rad/s)^2).
        scale = np.sqrt(np.clip(np.diag(cov), 1e-300, None))
        correlation = cov / np.outer(scale, scale)
        whitened = np.linalg.solve(correlation, error / scale) / scale
        error = cov_after @ whitened + corrected.boxminus(about)
        # Beyond this the reference is no linearisation point (a heading nothing observes,
        # 165 deg from where the smoother put it at rest), and the updates' attitude resets
        # make P+ P-^-1 no contraction: the pass is abandoned, not run to NaN.
        if not np.all(np.isfinite(error)) or np.linalg.norm(error[ATT]) > MAX_REFERENCE_TURN_RAD:
            raise LinearisationLost(f"boundary {k}")
        return about.boxplus(error), cov_after


class ReferenceRecorder(ReferenceUpdates, FilterRecorder):
    """The recorder of a pass linearised about ``reference`` (:class:`ReferenceUpdates`)."""

    def __init__(
        self, setup: FilterSetup, imu_t: np.ndarray, gyro: np.ndarray, reference: list[NominalState]
    ) -> None:
        super().__init__(setup, imu_t, gyro)
        self.reference = reference


@dataclass
class SampledNodes:
    """Nominal states at chosen nodes of a forward pass (see :class:`NodeSampler`)."""

    nodes: np.ndarray  # (M,) node indices, sorted, unique
    rotation: np.ndarray  # (M, 3, 3)
    velocity: np.ndarray  # (M, 3)
    position: np.ndarray
    accel_bias: np.ndarray
    gyro_bias: np.ndarray
    counts: dict[str, int] = field(default_factory=dict)


class IntervalSums:
    """Running cumulative sums of per-IMU-sample values, kept only at chosen sample indices.

    ``np.vstack([0, np.cumsum(values, axis=0)])[index]`` for ``index`` (M,) without the
    per-sample array: the values arrive block by block in sample order, and each block is
    accumulated starting from the running total (the same sequential additions as one
    cumsum over all samples, so the same bits).
    """

    def __init__(self, index: np.ndarray, width: int) -> None:
        self.index = np.asarray(index, dtype=np.int64)
        self.order = np.argsort(self.index, kind="stable")
        self.sorted = self.index[self.order]
        self.total = np.zeros(width)
        self.at = np.zeros((len(self.index), width))
        self.next = 0  # samples consumed so far

    def add(self, values: np.ndarray) -> None:
        """The values (n, width) of the next n samples."""
        n = len(values)
        if n == 0:
            return
        cumulative = np.cumsum(np.vstack([self.total[None, :], values]), axis=0)
        lo, hi = np.searchsorted(self.sorted, [self.next, self.next + n], side="right")
        # cumulative[j] is the sum of the first self.next + j samples.
        picked = self.order[lo:hi]
        self.at[picked] = cumulative[self.index[picked] - self.next]
        self.total = cumulative[-1]
        self.next += n


def interval_bounds(sample_t: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sample ranges [lo, hi) of the keyframe intervals [t_k, t_k+1) (the last to the end),
    at least one sample each: the ranges the biases of the initial guess are averaged over."""
    n = len(sample_t)
    lo = np.searchsorted(sample_t, times)
    hi = np.append(lo[1:], n)
    hi = np.maximum(hi, lo + 1)
    return np.clip(lo, 0, n - 1), np.clip(hi, 1, n)


class NodeSampler(FilterRecorder):
    """A recorder that keeps the nominal states at chosen nodes only.

    Same updates and propagation as :class:`FilterRecorder` (so the same numbers at those
    nodes), but nothing per node or per boundary besides them: no covariances, no
    transitions, no prior/posterior lists. Memory is O(len(nodes)), not O(IMU samples).
    """

    def __init__(
        self,
        setup: FilterSetup,
        imu_t: np.ndarray,
        gyro: np.ndarray,
        nodes,
        bias_sums: tuple[np.ndarray, IntervalSums] | None = None,
    ) -> None:
        self.setup = setup
        self._imu_t = imu_t
        self._gyro = gyro
        # (node of every IMU sample, sums at the interval bounds) for interval-mean biases.
        self.bias_sums = bias_sums
        self.nodes = np.unique(np.asarray(nodes, dtype=np.int64))
        m = len(self.nodes)
        self.rotation = np.empty((m, 3, 3))
        self.velocity = np.empty((m, 3))
        self.position = np.empty((m, 3))
        self.accel_bias = np.empty((m, 3))
        self.gyro_bias = np.empty((m, 3))

    def boundary(
        self, k: int, state: NominalState, cov: np.ndarray, gnss_update: GnssUpdate
    ) -> tuple[NominalState, np.ndarray]:
        return self.update(k, state, cov, gnss_update)

    def _add_biases(self, first: int, stop: int, nodes: NominalState) -> None:
        """The biases of the IMU samples whose output node is in [first, stop)."""
        if self.bias_sums is None:
            return
        sample_node, sums = self.bias_sums
        a, b = np.searchsorted(sample_node, [first, stop])
        local = sample_node[a:b] - first
        values = np.empty((len(local), 6))
        values[:, :3] = nodes.accel_bias[local]
        values[:, 3:] = nodes.gyro_bias[local]
        if not np.isfinite(values).all():  # the same numbers as nan_to_num, at less cost
            values = np.nan_to_num(values)
        sums.add(values)

    def store_nodes(self, span: slice, nodes: NominalState) -> None:
        self._add_biases(span.start, span.stop, nodes)
        lo, hi = np.searchsorted(self.nodes, [span.start, span.stop])
        if hi == lo:
            return
        rows = slice(int(lo), int(hi))
        local = self.nodes[rows] - span.start  # positions among the block's nodes
        self.rotation[rows] = nodes.rotation[local]
        self.velocity[rows] = nodes.velocity[local]
        self.position[rows] = nodes.position[local]
        self.accel_bias[rows] = nodes.accel_bias[local]
        self.gyro_bias[rows] = nodes.gyro_bias[local]

    def block_noise(
        self, b: int, span: slice, central: BlockNominal, cov: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        return self._block_noise(b, span, central, cov)

    def finish(self, state: NominalState, rejected_times: list[float]) -> SampledNodes:  # type: ignore[override]
        last = len(self.setup.segments.start)  # the final node: the last a-posteriori state
        final = NominalState(
            state.rotation[None], state.velocity[None], state.position[None],
            np.atleast_2d(state.accel_bias), np.atleast_2d(state.gyro_bias),
        )  # fmt: skip
        self._add_biases(last, last + 1, final)
        if len(self.nodes) and self.nodes[-1] == last:
            self.rotation[-1], self.velocity[-1], self.position[-1] = (
                state.rotation,
                state.velocity,
                state.position,
            )
            self.accel_bias[-1], self.gyro_bias[-1] = state.accel_bias, state.gyro_bias
        return SampledNodes(
            nodes=self.nodes,
            rotation=self.rotation,
            velocity=self.velocity,
            position=self.position,
            accel_bias=self.accel_bias,
            gyro_bias=self.gyro_bias,
            counts=self._counts(),
        )


@dataclass
class GnssUpdater:
    """What the GNSS updates of the Kalman baselines share at a block boundary: the epochs,
    lever arm and frame, Huber down-weighting, the innovation gate and their counters."""

    epochs: GnssEpochs
    lever_arm: np.ndarray
    huber_k: float | None
    gate_probability: float | None
    frame: NavFrame
    counts: dict[str, int]
    rejected_times: list[float] = field(default_factory=list)
    nis: list[float] = field(default_factory=list)  # per update, over its dimension
    antenna: AntennaStates | None = None  # FilterSetup.antenna
    heading: HeadingGate | None = None  # FilterSetup.heading

    @property
    def heading_unknown(self) -> bool:
        """The motion cannot tell the heading at this boundary (FilterSetup.heading)."""
        return self.heading is not None and self.heading.decoupled

    @classmethod
    def for_setup(
        cls, setup: FilterSetup, config: RunConfig, gate_probability: float | None, **extra: Any
    ) -> Self:
        """The updater of a forward pass (``extra``: a subclass's own fields)."""
        return cls(
            epochs=setup.epochs,
            lever_arm=np.asarray(config.gnss.lever_arm_m, dtype=float),
            huber_k=config.gnss.huber_k,
            gate_probability=gate_probability,
            frame=setup.frame,
            counts=setup.counts,
            nis=setup.gnss_nis,
            antenna=setup.antenna,
            heading=setup.heading,
            **extra,
        )

    def linearize(self, g: int, state: NominalState, gyro: np.ndarray) -> Linearized:
        """Measured values, rows and variances of epoch ``g``; residual = z - h(state)."""
        body_rate = gyro - state.gyro_bias - state.rotation.T @ self.frame.earth_rate
        return linearize_gnss(
            self.epochs, g, state, body_rate, self.lever_arm, self.antenna
        )

    def screen(
        self, g: int, innovation: np.ndarray, predicted: np.ndarray, variance: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """Measurement variances (Huber-inflated) and innovation covariance S of epoch ``g``
        given the predicted measurement covariance; None when the gate rejects the epoch."""
        plain = predicted + np.diag(variance)  # the model's own S, before Huber and gate
        if np.all(np.isfinite(innovation)):
            self.nis.append(float(innovation @ np.linalg.solve(plain, innovation)) / len(innovation))
        if self.gate_probability is not None:
            # Judged on the model's S: after the Huber inflation (on by default) an outlier's
            # own variance would shrink its NIS below the gate.
            nis = float(innovation @ np.linalg.solve(plain, innovation))
            if nis > chi2_quantile(self.gate_probability, len(innovation)):
                self.counts["rejected_innovation"] += 1
                self.rejected_times.append(float(self.epochs.t[g]))
                return None
        if self.huber_k is not None:
            variance, n_down = huber_variances(
                innovation, np.diag(predicted) + variance, variance, self.huber_k
            )
            self.counts["huber_downweighted"] += n_down
        return variance, predicted + np.diag(variance)

    def count_update(self, lin: Linearized) -> None:
        self.counts["gnss_updates"] += 1
        self.counts["velocity_updates"] += int(lin.n_velocity > 0)


class _Updater(GnssUpdater):
    """Linearised GNSS update at a block boundary (closed loop: returns the corrected state)."""

    def __call__(
        self, g: int, state: NominalState, cov: np.ndarray, gyro: np.ndarray
    ) -> tuple[NominalState, np.ndarray]:
        lin = self.linearize(g, state, gyro)
        h = pad_columns(lin.jacobian, len(cov))
        screened = self.screen(g, lin.residual, h @ cov @ h.T, lin.variance)
        if screened is None:
            return state, cov
        variance, s = screened
        self.count_update(lin)
        return kalman_update(state, cov, lin.residual, h, variance, s, self.heading_unknown)


# Prediction over block b (its IMU span given) from the a-posteriori state and covariance at
# its start: the a-priori state and covariance at its end. It also records the block's nodes
# (FilterRecorder.store_nodes) and transition (FilterRecorder.block_noise).
BlockPrediction = Callable[[int, slice, NominalState, np.ndarray], tuple[NominalState, np.ndarray]]


def forward_pass(
    recorder: FilterRecorder,
    update: GnssUpdater,
    predict: BlockPrediction,
    desc: str,
    progress: bool,
) -> FilterRun:
    """The forward loop of every Kalman baseline: update at each block boundary, predict over
    each block in between."""
    setup = recorder.setup
    state, cov = recorder.boundary(0, setup.state, setup.cov, update)
    n_blocks = len(setup.times) - 1
    for b in _progress(range(n_blocks), desc, progress):
        end, cov = predict(b, setup.segments.block(b), state, cov)
        state, cov = recorder.boundary(b + 1, end, 0.5 * (cov + cov.T), update)
    return recorder.finish(state, update.rejected_times)


def run_filter(
    dataset: Dataset,
    config: RunConfig,
    gnss_mask: np.ndarray | None,
    options: EkfOptions,
    progress: bool,
    start: NominalState | None = None,
    reference: list[NominalState] | None = None,
) -> tuple[FilterRun, GnssEpochs]:
    """The forward EKF pass over the whole IMU span (from ``start``'s attitude, velocity and
    position instead of the alignment's when given; P0 and the biases' prior unchanged).

    With ``reference`` (a state per block boundary), every block is linearised about it
    instead of about the filter's own estimate (:func:`relinearised_passes`)."""
    setup = prepare_filter(dataset, config, gnss_mask, options.max_block_s)
    if start is not None:
        setup.state = NominalState(
            rotation=start.rotation, velocity=start.velocity, position=start.position,
            accel_bias=start.accel_bias, gyro_bias=start.gyro_bias,
            extra=setup.state.extra,
        )  # fmt: skip
    if reference is None:
        recorder = FilterRecorder(setup, dataset.imu.t, dataset.imu.gyro)
        return _ekf_forward(setup, recorder, config, options, progress), setup.epochs
    recorder = ReferenceRecorder(setup, dataset.imu.t, dataset.imu.gyro, reference)
    anchors: list[NominalState] = [reference[0]]
    run = _ekf_forward(setup, recorder, config, options, progress, reference, anchors)
    return _about_reference(run, reference, anchors), setup.epochs


def _ekf_forward(
    setup: FilterSetup,
    recorder: FilterRecorder,
    config: RunConfig,
    options: EkfOptions,
    progress: bool,
    reference: list[NominalState] | None = None,
    anchors: list[NominalState] | None = None,
) -> Any:
    """The EKF's forward loop with any recorder (its ``finish`` makes the result).

    With ``reference``, block b is mechanised from ``reference[b]`` and its Phi and Q taken
    there; the filter's own estimate moves through the block with that Phi (its error from
    the reference, transformed linearly), and the recorder (:class:`ReferenceRecorder`)
    linearises the updates at the reference too. The propagated reference at each block's
    end goes to ``anchors``."""
    update = _Updater.for_setup(setup, config, options.innovation_gate_probability)

    def predict(
        b: int, span: slice, state: NominalState, cov: np.ndarray
    ) -> tuple[NominalState, np.ndarray]:
        dt = setup.segments.dt[span]
        about = state if reference is None else reference[b]
        nominal = propagate_nominal(
            about, setup.gyro_at[span], setup.accel_at[span], dt, setup.frame
        )
        # The biases are held constant over the block.
        held = (len(dt) + 1, 3)
        recorder.store_nodes(
            span,
            NominalState(
                nominal.rotation, nominal.velocity, nominal.position,
                np.broadcast_to(about.accel_bias, held), np.broadcast_to(about.gyro_bias, held),
            ),
        )  # fmt: skip
        phi, q = recorder.block_noise(b, span, nominal, cov)
        if reference is None:
            return nominal.end(state), phi @ cov @ phi.T + q
        assert anchors is not None
        anchors.append(nominal.end(about))
        return anchors[-1].boxplus(phi @ state.boxminus(about)), phi @ cov @ phi.T + q

    return forward_pass(recorder, update, predict, "EKF", progress)


def _about_reference(
    run: FilterRun, reference: list[NominalState], anchors: list[NominalState]
) -> FilterRun:
    """A relinearised pass's run, re-expressed about its reference: the RTS corrections
    (smoothed, with the pass's Phi) taken from the reference at each boundary's start and
    from the propagated reference at its end, so that the output adds small corrections to
    the reference's mechanised nodes (where the filter's own estimate may lie far off)."""
    smoothed = smoothed_states(run)
    cov_smoothed = rts_smooth(run)[2]
    last = reference[-1]
    run.rotation[-1], run.velocity[-1], run.position[-1] = (
        last.rotation, last.velocity, last.position,
    )  # fmt: skip
    run.accel_bias[-1], run.gyro_bias[-1] = last.accel_bias, last.gyro_bias
    run.posterior, run.prior = list(reference), list(anchors)
    run.smoothed = (
        np.array([s.boxminus(r) for s, r in zip(smoothed, reference, strict=True)]),
        np.array([s.boxminus(a) for s, a in zip(smoothed, anchors, strict=True)]),
        cov_smoothed,
    )
    return run


def _node_rows(segments: Segments, imu_t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For every IMU sample: its node index, its block, and its time share within the block."""
    nodes_t = segments.nodes
    rows = np.clip(np.searchsorted(nodes_t, imu_t), 0, len(nodes_t) - 1)
    times = segments.times
    block = np.clip(np.searchsorted(times, imu_t, side="right") - 1, 0, len(times) - 2)
    share = (imu_t - times[block]) / (times[block + 1] - times[block])
    return rows, block, np.clip(share, 0.0, 1.0)


def _interpolate(start: np.ndarray, end: np.ndarray, block: np.ndarray, share: np.ndarray):
    """Linear interpolation between per-boundary values at the blocks' start and end."""
    s = share.reshape(-1, *([1] * (start.ndim - 1)))
    return (1.0 - s) * start[block] + s * end[block + 1]


# The output's covariance blocks: position, velocity, attitude (N, 3, 3) each.
NavCovariance = tuple[np.ndarray, np.ndarray, np.ndarray]
NAV_BLOCKS = (POS, VEL, ATT)


def _interpolate_nav(
    start: np.ndarray,
    end: np.ndarray,
    block: np.ndarray,
    share: np.ndarray,
    last: np.ndarray,
    last_value: np.ndarray,
) -> NavCovariance:
    """:func:`_interpolate` of the three 3x3 navigation blocks of per-boundary covariances
    (K, n, n), rows ``last`` set to ``last_value`` (n, n).

    Elementwise the same arithmetic as interpolating the full n x n matrices and slicing
    afterwards (so the same bits), but 27 instead of n^2 (225+) numbers per IMU sample and
    temporaries of one 3x3 block at a time: the full (N, 15, 15) interpolation was most of
    the 5.7 KB per IMU sample that the EKF used to need.
    """
    out = []
    for rows in NAV_BLOCKS:
        cov = _interpolate(
            np.ascontiguousarray(start[:, rows, rows]),
            np.ascontiguousarray(end[:, rows, rows]),
            block,
            share,
        )
        cov[last] = last_value[rows, rows]
        out.append(cov)
    return out[0], out[1], out[2]


def make_trajectory(
    dataset: Dataset,
    method: str,
    states: NominalState,
    cov: NavCovariance,
    info: dict[str, object],
) -> Trajectory:
    """The output :class:`Trajectory` of a Kalman baseline: states and the position,
    velocity and attitude blocks of the error covariance (N, 3, 3 each) at every IMU sample."""
    position_cov, velocity_cov, attitude_cov = cov
    return Trajectory(
        t=dataset.imu.t,
        position=states.position,
        velocity=states.velocity,
        rotation=states.rotation,
        origin=dataset.origin,
        method=method,
        gyro_bias=states.gyro_bias,
        accel_bias=states.accel_bias,
        position_cov=position_cov,
        velocity_cov=velocity_cov,
        attitude_cov=attitude_cov,
        info=info,
    )


def median_nis(nis: list[float]) -> float:
    """The median normalised innovation squared per dimension of a filter's GNSS updates:
    about 0.8 (the median of chi2(n)/n) for a filter whose covariance describes its errors;
    a median (robust to the outliers a Huber kernel or gate handles) far above that means
    the filter's predictions are wrong by far more than it thinks: IMU and GNSS on different
    clocks, wrong axes or units, noise set far too small. NaN without updates."""
    return float(np.median(nis)) if nis else float("nan")


def trajectory_info(run: FilterRun, epochs: GnssEpochs) -> dict[str, object]:
    """``Trajectory.info`` of a Kalman baseline: gating summary, update counters, rejections
    (and for the RTS smoother, its passes as the ``solver`` line the summary prints)."""
    info: dict[str, object] = {
        "gnss_gating": epochs.gating_summary,
        **run.counts,
        "rejected_times": list(run.rejected_times),
        "zupt_times": list(run.zupt_times),
    }
    if "relinearised_passes" in run.counts:
        info["solver"] = (
            f"EKF+RTS: {run.counts['forward_passes']} forward pass(es) from the start, then "
            f"{run.counts['relinearised_passes']} relinearised about the smoothed states"
        )
        if run.counts.get("relinearisation_abandoned"):
            info["solver"] += (
                " (one more abandoned: its estimate left the linearisation, or it did not "
                "converge)"
            )
        turned = _largest_unaided_turn_deg(run, epochs)
        anywhere = float(run.counts.get("rts_largest_turn_deg", 0.0))
        if turned <= RTS_NONLINEAR_DEG and run.counts.get("relinearisation_abandoned") and (
            anywhere > RTS_NONLINEAR_ANYWHERE_DEG
        ):
            # Beside fixes too, a turn this large is no linear correction: a multirotor
            # hovering its first minute (heading unseen) was turned 99-139 deg there, and the
            # heading stayed 1-3.5 deg off at sigmas of 0.2-0.35 deg, the track 6.5 m off
            # inside the outage after it and 5.8 m at fixes it used (17 sigma), unsaid
            # (outside tester).
            info["fit_warnings"] = [
                f"EKF+RTS: the smoother turns the filter's attitude by up to {anywhere:.0f} deg "
                "(where its forward pass could not see it: a hover, a start at rest), far beyond "
                "what its linear correction carries, and relinearising about the smoothed states "
                "did not settle it: its track and sigmas are not to be trusted (compare --method "
                "batch, which relinearises until it converges)"
            ]
        miss = run.forward_gap_miss
        if miss is not None:
            # A forward pass that missed the fix after a gap by tens of sigmas carried a
            # wrong model across it (a stop-and-go jam in an outage: stops it did not take),
            # which a linear smoother cannot mend: 3.7-41 m off inside the outages at z
            # 10-79, unsaid, where the forward EKF said its miss (outside tester).
            info["fit_warnings"] = [*info.get("fit_warnings", []), (  # type: ignore[list-item]
                f"EKF+RTS: its forward pass missed the first fix after {miss.gap_s:.0f} s "
                f"without fixes by {miss.distance_m:.1f} m, {miss.sigmas:.0f} sigmas of its own "
                f"uncertainty ({miss.count} of {miss.gaps} such gap(s)): the smoother corrects "
                "that pass linearly, so inside such gaps its track and sigmas are not to be "
                "trusted (compare --method batch, which relinearises until it converges)"
            )]
        if turned > RTS_NONLINEAR_DEG:
            # The RTS correction is linear about the forward pass: one this large where no
            # fix holds the track is no correction its covariance describes (an independent
            # simulator's multirotor, its heading unknown until it flew inside an outage:
            # 71 deg, the relinearised pass did not converge; 1.5-3.3 m off inside the outage
            # with sigmas for 0.17 m, NEES 9-14). Beside the fixes they hold the track (a
            # loop's start heading turned 22-29 deg: 0.5-0.8 m, fine).
            info["fit_warnings"] = [*info.get("fit_warnings", []), (  # type: ignore[list-item]
                f"EKF+RTS: the smoother turns the filter's attitude by up to {turned:.0f} deg "
                f"more than {RTS_UNAIDED_GAP_S:g} s from any fix, far beyond what its linear "
                "correction carries, and relinearising about the smoothed states did not settle "
                "it: its track and sigmas are not to be trusted there (compare --method batch, "
                "which relinearises until it converges)"
            )]
    return info


def _largest_unaided_turn_deg(run: FilterRun, epochs: GnssEpochs) -> float:
    """The largest attitude correction (deg) the RTS smoother makes to a run."""
    return largest_unaided_turn_deg(rts_smooth(run)[0][:, ATT], run.segments.times, epochs.t)


def largest_unaided_turn_deg(turns: np.ndarray, times: np.ndarray, fixes: np.ndarray) -> float:
    """The largest of the attitude corrections ``turns`` (rad vectors, one per block boundary
    at ``times``) in deg, among the boundaries more than RTS_UNAIDED_GAP_S from any GNSS epoch
    used (``fixes``)."""
    turns = np.degrees(np.linalg.norm(turns, axis=1))
    times = np.asarray(times, dtype=float)[: len(turns)]
    fixes = np.sort(np.asarray(fixes, dtype=float))
    if fixes.size == 0:
        return float(turns.max(initial=0.0))
    after = np.clip(np.searchsorted(fixes, times), 0, fixes.size - 1)
    before = np.clip(after - 1, 0, fixes.size - 1)
    gap = np.minimum(np.abs(fixes[after] - times), np.abs(times - fixes[before]))
    return float(turns[gap > RTS_UNAIDED_GAP_S].max(initial=0.0))


def filtered_output(dataset: Dataset, run: FilterRun) -> tuple[NominalState, NavCovariance]:
    """Forward-filter states at every IMU sample (a-posteriori at update epochs)."""
    rows, block, share = _node_rows(run.segments, dataset.imu.t)
    states = NominalState(
        rotation=run.rotation[rows],
        velocity=run.velocity[rows],
        position=run.position[rows],
        accel_bias=run.accel_bias[rows],
        gyro_bias=run.gyro_bias[rows],
    )
    # The last sample sits on the last boundary: a-posteriori, not a-priori.
    last = dataset.imu.t >= run.segments.times[-1]
    cov = _interpolate_nav(
        run.cov_posterior, run.cov_prior, block, share, last, run.cov_posterior[-1]
    )
    return states, cov


def rts_smooth(run: FilterRun) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Backward RTS pass over the block boundaries.

    Returns per boundary k: the smoothed correction relative to the forward a-posteriori
    state (the start of block k), the smoothed correction relative to the forward a-priori
    state (the end of block k-1), and the smoothed covariance (computed once per run).
    """
    if run.smoothed is not None:
        return run.smoothed
    n, dim = len(run.posterior), run.cov_posterior.shape[1]
    from_posterior = np.zeros((n, dim))
    from_prior = np.zeros((n, dim))
    cov_smoothed = np.empty_like(run.cov_posterior)
    cov_smoothed[-1] = run.cov_posterior[-1]
    smoothed = run.posterior[-1]
    from_prior[-1] = smoothed.boxminus(run.prior[-1])
    for k in range(n - 2, -1, -1):
        # C = P+_k Phi^T (P-_k+1)^-1, computed as a solve with the symmetric P-_k+1.
        gain = np.linalg.solve(run.cov_prior[k + 1], run.transition[k] @ run.cov_posterior[k]).T
        from_posterior[k] = gain @ from_prior[k + 1]
        smoothed = run.posterior[k].boxplus(from_posterior[k])
        from_prior[k] = smoothed.boxminus(run.prior[k])
        delta = cov_smoothed[k + 1] - run.cov_prior[k + 1]
        cov = run.cov_posterior[k] + gain @ delta @ gain.T
        cov_smoothed[k] = 0.5 * (cov + cov.T)
    run.smoothed = (from_posterior, from_prior, cov_smoothed)
    return run.smoothed


def smoothed_states(run: FilterRun) -> list[NominalState]:
    """The RTS-smoothed state at every block boundary of a run."""
    from_posterior = rts_smooth(run)[0]
    return [post.boxplus(dx) for post, dx in zip(run.posterior, from_posterior, strict=True)]


def smoothed_output(dataset: Dataset, run: FilterRun) -> tuple[NominalState, NavCovariance]:
    """RTS states at every IMU sample: forward nominal plus interpolated smoothed corrections."""
    from_posterior, from_prior, cov_smoothed = rts_smooth(run)
    rows, block, share = _node_rows(run.segments, dataset.imu.t)
    correction = _interpolate(from_posterior, from_prior, block, share)
    last = dataset.imu.t >= run.segments.times[-1]
    correction[last] = from_posterior[-1]  # zero: the last filter state is already smoothed
    forward = NominalState(
        rotation=run.rotation[rows],
        velocity=run.velocity[rows],
        position=run.position[rows],
        accel_bias=run.accel_bias[rows],
        gyro_bias=run.gyro_bias[rows],
    )
    share_cov = share.copy()
    share_cov[last] = 1.0
    block_cov = np.minimum(block, len(cov_smoothed) - 2)
    # Rows ``last`` already interpolate to the last smoothed covariance (share 1): no override.
    cov = _interpolate_nav(
        cov_smoothed, cov_smoothed, block_cov, share_cov, np.zeros(len(share), bool), cov_smoothed[-1]
    )
    states = NominalState(
        rotation=so3_exp(correction[:, ATT]) @ forward.rotation,
        velocity=forward.velocity + correction[:, VEL],
        position=forward.position + correction[:, POS],
        accel_bias=forward.accel_bias + correction[:, ACC_BIAS],
        gyro_bias=forward.gyro_bias + correction[:, GYRO_BIAS],
    )
    return states, cov


def kalman_trajectory(
    dataset: Dataset,
    method: str,
    forward: Callable[[], tuple[FilterRun, GnssEpochs]],
    *,
    smooth: bool = False,
    extra_info: dict[str, object] | None = None,
    antenna_check: Callable[[list[NominalState]], dict[str, object]] | None = None,
) -> Trajectory:
    """Run a forward pass, turn it into the output trajectory (filtered, or RTS-smoothed
    with ``smooth``) and record the timings of both steps. With ``antenna_check``, what it
    finds about the pass's smoothed states (:func:`antenna_about`, :func:`antenna_report`)
    goes to ``info`` as the graph's check does."""
    started = time.perf_counter()
    run, epochs = forward()
    filtered = time.perf_counter()
    states, cov = smoothed_output(dataset, run) if smooth else filtered_output(dataset, run)
    info = {**trajectory_info(run, epochs), **(extra_info or {})}
    trajectory = make_trajectory(dataset, method, states, cov, info)
    finished = time.perf_counter()
    timings = {"filter": filtered - started}
    if smooth:
        timings["smoother"] = finished - filtered
    if antenna_check is not None:
        found = antenna_check(smoothed_states(run))
        said: list[str] = found.pop("fit_warnings", [])  # type: ignore[assignment]
        info.update(found)
        if said:
            info["fit_warnings"] = [*info.get("fit_warnings", []), *said]  # type: ignore[list-item]
        timings["antenna_check"] = time.perf_counter() - finished
        finished = time.perf_counter()
    timings["total"] = finished - started
    trajectory.timings.update(timings)
    return trajectory


def run_ekf(
    dataset: Dataset,
    config: RunConfig,
    *,
    gnss_mask: np.ndarray | None = None,
    progress: bool = True,
    options: EkfOptions | None = None,
) -> Trajectory:
    """Loosely coupled error-state EKF (method ``"ekf"``), output at every IMU sample: 15
    states, 16 with a barometer; NHC/ZUPT pseudo-measurements per ``config.smoother``.

    ``gnss_mask`` withholds GNSS epochs (outages, True = keep). Raises InputError when no
    usable GNSS epoch lies within the IMU span. ``info`` counts updates and rejections.
    """
    options = options or EkfOptions()
    return kalman_trajectory(
        dataset,
        "ekf",
        lambda: run_filter(dataset, config, gnss_mask, options, progress),
        antenna_check=antenna_check(dataset, config, gnss_mask, options.max_block_s),
    )


def run_ekf_rts(
    dataset: Dataset,
    config: RunConfig,
    *,
    gnss_mask: np.ndarray | None = None,
    progress: bool = True,
    options: EkfOptions | None = None,
) -> Trajectory:
    """The EKF of :func:`run_ekf` followed by a Rauch-Tung-Striebel smoother (``"ekf-rts"``),
    the forward pass repeated from the smoothed start attitude while that turns it far
    (:func:`iterated_forward`)."""
    options = options or EkfOptions()
    return kalman_trajectory(
        dataset,
        "ekf-rts",
        lambda: iterated_forward(dataset, config, gnss_mask, options, progress),
        smooth=True,
        antenna_check=antenna_check(dataset, config, gnss_mask, options.max_block_s),
    )


# A smoothed start attitude this far from the forward pass's (rad) is beyond what one
# linearisation carries: the pass is repeated from the smoothed start, and again while the
# start still moves by more than a tenth of that or by START_MOVED (velocity m/s, position m).
START_TURNED_RAD = np.radians(2.0)
START_MOVED = (1.0, 10.0)
MAX_FORWARD_PASSES = 4


def iterated_forward(
    dataset: Dataset,
    config: RunConfig,
    gnss_mask: np.ndarray | None,
    options: EkfOptions,
    progress: bool,
) -> tuple[FilterRun, GnssEpochs]:
    """Forward passes, each from the previous pass's RTS-smoothed start, when the smoother
    turned the first pass's start attitude by more than :data:`START_TURNED_RAD`. The RTS
    correction is linear about the forward pass: a start dead-reckoned 45 s back to where GNSS
    was withheld (an aircraft already airborne, 5.5 deg off) came out 50 m off with a 1 m
    sigma (NEES 3266; the batch, which relinearises, 1.4 m), and a multirotor's heading at
    hover, unobservable until it flew, 117 deg off left the filter 290 m off in an outage.
    Attitude, velocity and position move; the biases too once a pass turned the start by
    less than that (moved with a start far off they were bent around it; kept at their prior,
    an aircraft's vertical settled 21 m off with a 2.4 m sigma). P0 stays: the start's prior
    is counted twice only where the first pass found it far off, so broad; the passes then
    reach the batch's start (the same 2-12 m, sigmas within 1 %). A start the first pass
    barely turns (KITTI: 0.6 deg) takes one pass. The count is ``counts["forward_passes"]``
    (``info["forward_passes"]`` of the trajectory)."""
    run, epochs = run_filter(dataset, config, gnss_mask, options, progress)
    start: NominalState | None = None
    count = 1
    while count < MAX_FORWARD_PASSES:
        moved = rts_smooth(run)[0][0].copy()
        turned = np.linalg.norm(moved[ATT])
        far = (
            turned > START_TURNED_RAD
            if count == 1
            else turned > 0.1 * START_TURNED_RAD
            or np.linalg.norm(moved[VEL]) > START_MOVED[0]
            or np.linalg.norm(moved[POS]) > START_MOVED[1]
        )
        if not far:
            break
        if turned > START_TURNED_RAD:
            # A start turned this far leaves the pass's bias estimates bent around it (a
            # hover's heading 117 deg off: gyro z bias 1-3 deg/s): they move once it holds.
            moved[ACC_BIAS] = moved[GYRO_BIAS] = 0.0
        start = run.posterior[0].boxplus(moved)
        run, epochs = run_filter(dataset, config, gnss_mask, options, progress, start)
        count += 1
    gap_miss = forward_gap_miss(run, epochs, config)
    run, relinearised = relinearised_passes(dataset, config, gnss_mask, options, progress, run, start)
    run.forward_gap_miss = gap_miss
    run.counts["forward_passes"] = count
    run.counts["relinearised_passes"] = relinearised
    return run, epochs


def forward_gap_miss(run: FilterRun, epochs: GnssEpochs, config: RunConfig) -> GapReturnMiss | None:
    """A forward pass's worst miss of the first fix after a gap (its state before the fix's
    update: its prediction), as :func:`fgins.baseline.measurements.gap_return_miss`."""
    times = run.segments.times

    def prior_at(fix_t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        k = np.clip(np.searchsorted(times, fix_t), 0, len(times) - 1)
        on = np.isclose(times[k], fix_t, rtol=0.0, atol=1e-9)
        position = np.array([run.prior[i].position for i in k], dtype=float)
        position[~on] = np.nan
        rotation = np.array([run.prior[i].rotation for i in k], dtype=float)
        return position, rotation, run.cov_prior[k][:, POS, POS]

    return gap_return_miss(epochs, prior_at, np.asarray(config.gnss.lever_arm_m, dtype=float))


# The RTS corrections are linear about the forward pass. Where they turn its attitude by
# more than this anywhere (rad), the pass is repeated linearised about the smoothed states.
RELINEARISE_TURNED_RAD = np.radians(2.0)
MAX_RELINEARISED_PASSES = 3
# Left beyond this after the relinearised passes (deg), the smoothed output is said to be
# untrustworthy (the linear correction of a 10 deg attitude error misses by its square).
RTS_NONLINEAR_DEG = 10.0
# ... and anywhere, beside fixes too, where the relinearised passes did not settle it (a
# loop's start heading turned 22-29 deg beside the fixes came out fine).
RTS_NONLINEAR_ANYWHERE_DEG = 45.0
RTS_UNAIDED_GAP_S = 5.0  # a boundary this far from any fix used: no fix holds the track there


def relinearised_passes(
    dataset: Dataset,
    config: RunConfig,
    gnss_mask: np.ndarray | None,
    options: EkfOptions,
    progress: bool,
    run: FilterRun,
    start: NominalState | None,
) -> tuple[FilterRun, int]:
    """Forward-backward passes linearised about the previous pass's smoothed states (an
    iterated extended Kalman smoother: each is one Gauss-Newton step of the whole problem,
    as the batch takes them), while the smoother still turns the attitude of the states it
    was linearised about by more than :data:`RELINEARISE_TURNED_RAD` somewhere.

    The forward filter's attitude can be far off where the data leave it unobservable and
    the smoother later resolves it: an aircraft's heading 9 deg off in a straight climb
    at 0.2 Hz GNSS, entering a 45 s outage in a turn. Its RTS correction is linear in
    that error; the position it dead-reckoned through the outage is not (60 m/s x 45 s x
    (1 - cos 9 deg) = 33 m), and the RTS ended 6.4 m off with sigmas for 0.8 m (NEES 70)
    where the batch was 0.7 m off. Returns the last run and the number of passes made."""
    passes = 0
    turned = _largest_turn(run)
    while passes < MAX_RELINEARISED_PASSES and turned > RELINEARISE_TURNED_RAD:
        reference = smoothed_states(run)
        try:
            again, _ = run_filter(dataset, config, gnss_mask, options, progress, start, reference)
        except (LinearisationLost, np.linalg.LinAlgError):
            run.counts["relinearisation_abandoned"] = 1
            break
        turned_again = _largest_turn(again)
        if not turned_again < turned:  # not converging: the last pass that did stays
            run.counts["relinearisation_abandoned"] = 1
            break
        run, turned = again, turned_again
        passes += 1
    run.counts["rts_largest_turn_deg"] = float(np.degrees(turned))
    return run, passes


def _largest_turn(run: FilterRun) -> float:
    """The largest attitude correction (rad) the RTS smoother makes to a run's states."""
    return float(np.max(np.linalg.norm(rts_smooth(run)[0][:, ATT], axis=1)))


def _guess_samples(imu_t: np.ndarray, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The IMU samples an IMU-rate guess at ``times`` reads: both samples around each time
    (np.interp's bracket), the first sample at or after it (the attitude and biases) and the
    two ends (np.interp's clamping). Returns the sorted unique samples and, per time, the
    index of its at-or-after sample among them."""
    last = len(imu_t) - 1
    before = np.clip(np.searchsorted(imu_t, times, side="right") - 1, 0, last)
    after = np.clip(np.searchsorted(imu_t, times), 0, last)
    samples = np.unique(np.concatenate([[0, last], before, np.minimum(before + 1, last), after]))
    return samples, np.searchsorted(samples, after)


def ekf_states_at(
    dataset: Dataset,
    config: RunConfig,
    times: np.ndarray,
    *,
    gnss_mask: np.ndarray | None = None,
    progress: bool = False,
    options: EkfOptions | None = None,
    biases: str = "interval",
) -> KeyframeGuess:
    """The forward EKF of :func:`run_ekf`, reported only at ``times`` (the keyframes).

    The numbers are exactly those the pipeline takes from ``run_ekf``'s IMU-rate output
    (as sampling the filter's IMU-rate output would): position and velocity linearly interpolated
    (np.interp) between the filter's states at the IMU samples around each time, attitude
    that of the first sample at or after it, and the biases averaged over the samples of
    each keyframe interval [t_k, t_k+1) (``biases="interval"``; ``"nearest"``: the first
    sample's, as graph.smoother did before). Only the states at those samples and running
    bias sums are kept: no IMU-rate output, no covariance per sample or per block, so memory
    grows with the number of keyframes (plus the filter's per-block working set and an index
    per sample), not with the IMU samples. Pass the guess configuration
    (:func:`fgins.initial_guess.guess_config`) for the graph's guess.

    Raises InputError as :func:`run_ekf` does (no usable GNSS, bad mask or options).
    """
    times = np.asarray(times, dtype=float)
    if times.ndim != 1 or len(times) == 0 or not np.all(np.isfinite(times)):
        raise InputError("ekf_states_at: times must be a non-empty 1-D array of finite seconds")
    if biases not in ("interval", "nearest"):
        raise InputError(f"ekf_states_at: biases must be 'interval' or 'nearest', got {biases!r}")
    options = options or EkfOptions()
    imu_t = dataset.imu.t
    setup = prepare_filter(dataset, config, gnss_mask, options.max_block_s)
    samples, nearest = _guess_samples(imu_t, times)
    # The output state at an IMU sample is the node at its time (as in filtered_output).
    node_t = setup.segments.nodes
    rows = np.clip(np.searchsorted(node_t, imu_t[samples]), 0, len(node_t) - 1)
    bias_sums = None
    if biases == "interval":
        lo, hi = interval_bounds(imu_t, times)
        sample_node = np.clip(np.searchsorted(node_t, imu_t), 0, len(node_t) - 1)
        bias_sums = (sample_node, IntervalSums(np.concatenate([lo, hi]), 6))
    del node_t
    sampler = NodeSampler(setup, imu_t, dataset.imu.gyro, rows, bias_sums)
    sampler.transition_steps = options.transition_steps
    nodes: SampledNodes = _ekf_forward(setup, sampler, config, options, progress)
    at = np.searchsorted(nodes.nodes, rows)  # each sample's row among the kept nodes
    xp = imu_t[samples]
    position = np.column_stack([np.interp(times, xp, nodes.position[at, i]) for i in range(3)])
    velocity = np.column_stack([np.interp(times, xp, nodes.velocity[at, i]) for i in range(3)])
    pick = at[nearest]
    if bias_sums is None:
        accel_bias = np.nan_to_num(nodes.accel_bias[pick])
        gyro_bias = np.nan_to_num(nodes.gyro_bias[pick])
    else:
        sums = bias_sums[1].at
        k = len(times)
        mean = (sums[k:] - sums[:k]) / (hi - lo)[:, None]
        accel_bias, gyro_bias = mean[:, :3], mean[:, 3:]
    return KeyframeGuess(
        t=times,
        rotation=nodes.rotation[pick],
        position=position,
        velocity=velocity,
        accel_bias=accel_bias,
        gyro_bias=gyro_bias,
        method="ekf",
    )


# The sub-steps of each block's Phi and Q in :func:`antenna_about` (an estimate of five
# constants, not an output).
ANTENNA_TRANSITION_STEPS = 4


@dataclass(frozen=True)
class AntennaEstimate:
    """The antenna's offset from the configured arm, the fixes' time offset and its drift as
    a Kalman pass finds them (``change``, :mod:`fgins.antenna_verdict`'s layout, and its
    ``covariance``), the median speed of the pass's reference where it moves
    (``typical_speed``, above 1 m/s; 0 if it never does) and the drift's time base."""

    change: np.ndarray
    covariance: np.ndarray
    typical_speed: float
    middle: float
    half_span: float


class _LastState(ReferenceUpdates, NodeSampler):
    """A recorder linearised about its reference that keeps only the state and covariance
    after the last boundary."""

    last: tuple[NominalState, np.ndarray] | None = None

    def boundary(
        self, k: int, state: NominalState, cov: np.ndarray, gnss_update: GnssUpdate
    ) -> tuple[NominalState, np.ndarray]:
        self.last = self.update(k, state, cov, gnss_update)
        return self.last


def antenna_about(
    dataset: Dataset,
    config: RunConfig,
    gnss_mask: np.ndarray | None,
    reference: list[NominalState],
    max_block_s: float,
) -> AntennaEstimate | None:
    """Where the fixes put the antenna and their time stamps, against the configured lever
    arm and the IMU's clock: one forward pass linearised about ``reference`` (a Kalman
    baseline's smoothed states at its block boundaries), whose error state also carries the
    arm's offset, the fixes' time offset and its drift (constants with the graph's priors,
    :data:`fgins.antenna_verdict.ANTENNA_PRIOR_SIGMAS`; :func:`linearize_gnss`). For a
    constant the forward pass's last estimate is the smoothed one. None when the pass
    leaves its linearisation.

    A filter follows the fixes it is given: lagging fixes leave its innovations small on
    straight roads, where a time shift of the whole track fits the IMU as well as the
    truth, and show only in turns and speed changes, spread over the biases and attitude
    (an independent simulator's gentle drive with fixes 1 s late: EKF+RTS 4.9 m inside an
    outage with sigmas for 0.3 m, median NIS 0.9). An antenna left out does the same in
    every turn. About the smoothed states, not the filter's own: the forward filter's early
    heading error went into the offset (0.23 +- 0.05 s on the same drive with true stamps;
    about the smoothed states 0.02 +- 0.05). The arm is free beside it: an antenna 2 m behind
    the IMU was otherwise read as fixes 0.1 s late. First order (a turn's curvature over a
    2 s lag is 4 m): :func:`fgins.corrections.with_antenna_corrected` corrects and asks
    again."""
    options = EkfOptions(max_block_s=max_block_s, transition_steps=ANTENNA_TRANSITION_STEPS)
    if dataset.gnss.velocity is not None:
        # From the positions alone: a latency delays the receiver's velocities too, which
        # this model (no lag of theirs) would read as an antenna turning with the car (fixes
        # 0.15 s late with velocities: an antenna 2.5 m behind, EKF+RTS 1.3 m off at the
        # fixes, NEES 200; the positions alone: 0.148 s late).
        dataset = replace(dataset, gnss=replace(dataset.gnss, velocity=None, velocity_std=None))
    setup = prepare_filter(dataset, config, gnss_mask, options.max_block_s, ANTENNA_PRIOR_SIGMAS)
    if len(setup.epochs.t) < MIN_FIXES:
        return None
    antenna = setup.antenna
    assert antenna is not None and len(reference) == len(setup.times)
    about = [state.copy() for state in reference]
    for state in about:  # the reference: the configured arm and the fixes as stamped
        assert state.extra is not None
        state.extra = np.append(state.extra[: antenna.index - STATE_DIM], np.zeros(5))
    # The pass starts on the reference (P0 kept, as the relinearised passes do): from the
    # alignment, a car already reversing at the start began 39 deg off it, and the first
    # 25 s read as an antenna 4 m to the side and two clocks (the batch: nothing).
    setup.state = about[0].copy()
    recorder = _LastState(setup, dataset.imu.t, dataset.imu.gyro, np.zeros(0, dtype=np.int64))
    recorder.reference = about
    recorder.transition_steps = options.transition_steps
    try:
        _ekf_forward(setup, recorder, config, options, False, about, [about[0]])
    except (LinearisationLost, np.linalg.LinAlgError):
        return None
    assert recorder.last is not None
    state, cov = recorder.last
    assert state.extra is not None
    rows = slice(antenna.index, antenna.index + 5)
    change, covariance = state.extra[rows.start - STATE_DIM : rows.stop - STATE_DIM], cov[rows, rows]
    if not (np.all(np.isfinite(change)) and np.all(np.isfinite(covariance))):
        return None
    return AntennaEstimate(
        change=np.array(change, dtype=float),
        covariance=0.5 * (covariance + covariance.T),
        typical_speed=typical_speed(np.linalg.norm([state.velocity for state in reference], axis=1)),
        middle=antenna.middle,
        half_span=antenna.half_span,
    )


def antenna_report(estimate: AntennaEstimate | None, config: RunConfig) -> dict[str, object]:
    """``Trajectory.info`` entries of a Kalman baseline's antenna and clock check: the
    graph's (:func:`fgins.antenna_verdict.antenna_verdict`), from its own estimate."""
    if estimate is None:
        return {}
    configured = np.asarray(config.gnss.lever_arm_m, dtype=float)
    out = antenna_verdict(
        config.gnss, configured, estimate.change, estimate.covariance, estimate.typical_speed
    )
    out["gnss_time_middle_s"], out["gnss_time_half_span_s"] = estimate.middle, estimate.half_span
    return out


def antenna_check(
    dataset: Dataset, config: RunConfig, gnss_mask: np.ndarray | None, max_block_s: float
) -> Callable[[list[NominalState]], dict[str, object]]:
    """The ``antenna_check`` of :func:`kalman_trajectory` for a pass on these inputs."""
    return lambda reference: antenna_report(
        antenna_about(dataset, config, gnss_mask, reference, max_block_s), config
    )
