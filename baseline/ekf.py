"""Loosely coupled error-state EKF and EKF + Rauch-Tung-Striebel smoother (numpy only).

Fifteen error states (position, velocity, attitude error ``phi`` in ENU, accelerometer and
gyro bias) around a nominal strapdown solution, with closed-loop feedback: after every GNSS
update the estimated errors are injected into the nominal state and reset to zero. Same
inputs as the factor graph (:class:`~fgins.datatypes.Dataset`, :class:`~fgins.config.RunConfig`),
same initial state and uncertainty (:func:`fgins.alignment.initial_alignment`), same GNSS
epochs, gating, sigmas and lever arm (:mod:`fgins.factors.gnss`), same navigation model
(:mod:`fgins.baseline.mechanization`), same output (:class:`~fgins.datatypes.Trajectory` at every
IMU sample).

The IMU stream is processed in blocks that end at each usable GNSS epoch (the sample that
straddles an epoch is split there, so updates happen at the exact epoch time) and at most
``max_block_s`` apart in outages. Within a block the nominal state is mechanized at every
sample and the block's transition Phi and process noise Q are the exact compositions of the
per-sample ones; covariances of the output rows inside a block are interpolated linearly
between its a-posteriori start and a-priori end.

The RTS smoother runs backwards over the block boundaries with the stored Phi, a-priori and
a-posteriori covariances; the smoothed error-state corrections (relative to the forward
nominal trajectory at the start and end of each block) are interpolated linearly onto the IMU
samples inside the block.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from tqdm import tqdm

from fgins.alignment import initial_alignment
from fgins.baseline.measurements import (
    GnssEpochs,
    chi2_quantile,
    huber_variances,
    linearize_gnss,
    select_gnss,
)
from fgins.baseline.mechanization import (
    ACC_BIAS,
    ATT,
    GYRO_BIAS,
    POS,
    STATE_DIM,
    VEL,
    NavFrame,
    NominalState,
    Segments,
    block_times,
    block_transition,
    propagate_nominal,
    segment_imu,
    skew_batch,
)
from fgins.config import ImuNoise, RunConfig
from fgins.datatypes import Dataset, FginsError, InputError, Trajectory
from fgins.geodesy import so3_exp


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

    def __post_init__(self) -> None:
        if not self.max_block_s > 0:
            raise InputError(f"EKF: max_block_s must be > 0, got {self.max_block_s}")
        p = self.innovation_gate_probability
        if p is not None and not 0.5 < p < 1.0:
            raise InputError(f"EKF: innovation_gate_probability must be in (0.5, 1), got {p}")


@dataclass
class FilterRun:
    """Everything the forward pass produces (and the RTS smoother needs)."""

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
    cov_prior: np.ndarray  # (K, 15, 15)
    cov_posterior: np.ndarray  # (K, 15, 15)
    transition: np.ndarray  # (K-1, 15, 15), block k -> k+1 about the posterior at k
    counts: dict[str, int] = field(default_factory=dict)
    rejected_times: list[float] = field(default_factory=list)  # GNSS epochs failing the gate


def initial_covariance(
    rotation: np.ndarray,
    attitude_sigma: np.ndarray,
    velocity_sigma: float,
    position_sigma: float,
    noise: ImuNoise,
) -> np.ndarray:
    """P0 from the alignment sigmas (attitude sigmas about the body axes, as the graph's
    Pose3 prior) and the turn-on bias priors."""
    p0 = np.zeros((STATE_DIM, STATE_DIM))
    p0[POS, POS] = np.eye(3) * position_sigma**2
    p0[VEL, VEL] = np.eye(3) * velocity_sigma**2
    p0[ATT, ATT] = rotation @ np.diag(np.asarray(attitude_sigma) ** 2) @ rotation.T
    p0[ACC_BIAS, ACC_BIAS] = np.eye(3) * noise.accel_bias_prior**2
    p0[GYRO_BIAS, GYRO_BIAS] = np.eye(3) * noise.gyro_bias_prior**2
    return p0


def reset_jacobian(phi: np.ndarray) -> np.ndarray:
    """Covariance reset after injecting an attitude correction ``phi`` (first order)."""
    g = np.eye(STATE_DIM)
    g[ATT, ATT] -= 0.5 * skew_batch(phi)
    return g


@dataclass
class _Updater:
    """GNSS update at a block boundary (closed loop: returns the corrected state)."""

    epochs: GnssEpochs
    lever_arm: np.ndarray
    huber_k: float | None
    gate_probability: float | None
    frame: NavFrame
    counts: dict[str, int]
    rejected_times: list[float] = field(default_factory=list)

    def __call__(
        self, g: int, state: NominalState, cov: np.ndarray, gyro: np.ndarray
    ) -> tuple[NominalState, np.ndarray]:
        body_rate = gyro - state.gyro_bias - state.rotation.T @ self.frame.earth_rate
        lin = linearize_gnss(self.epochs, g, state, body_rate, self.lever_arm)
        h = lin.jacobian
        predicted = h @ cov @ h.T
        variance = lin.variance
        if self.huber_k is not None:
            variance, n_down = huber_variances(
                lin.residual, np.diag(predicted) + variance, variance, self.huber_k
            )
            self.counts["huber_downweighted"] += n_down
        s = predicted + np.diag(variance)
        if self.gate_probability is not None:
            nis = float(lin.residual @ np.linalg.solve(s, lin.residual))
            if nis > chi2_quantile(self.gate_probability, len(lin.residual)):
                self.counts["rejected_innovation"] += 1
                self.rejected_times.append(float(self.epochs.t[g]))
                return state, cov
        gain = np.linalg.solve(s, h @ cov).T
        dx = gain @ lin.residual
        i_kh = np.eye(STATE_DIM) - gain @ h
        cov = i_kh @ cov @ i_kh.T + (gain * variance) @ gain.T  # Joseph form
        reset = reset_jacobian(dx[ATT])
        cov = reset @ cov @ reset.T
        self.counts["gnss_updates"] += 1
        self.counts["velocity_updates"] += int(lin.n_velocity > 0)
        return state.boxplus(dx), 0.5 * (cov + cov.T)


def run_filter(
    dataset: Dataset,
    config: RunConfig,
    gnss_mask: np.ndarray | None,
    options: EkfOptions,
    progress: bool,
) -> tuple[FilterRun, GnssEpochs]:
    """The forward EKF pass over the whole IMU span."""
    imu = dataset.imu
    epochs = select_gnss(dataset, config, gnss_mask)
    noise = config.imu_noise()
    frame = NavFrame.at(dataset.origin)
    align = initial_alignment(
        dataset, epochs.usable, heading_deg=config.smoother.initial_heading_deg
    )

    times = block_times(float(imu.t[0]), float(imu.t[-1]), epochs.t, options.max_block_s)
    segments = segment_imu(imu.t, times)
    # Which boundary carries which GNSS epoch (-1: none).
    boundary = np.searchsorted(times, epochs.t)
    boundary = np.clip(boundary, 0, len(times) - 1)
    matched = np.isclose(times[boundary], epochs.t, rtol=0.0, atol=1e-9)
    if not np.all(matched):  # cannot happen: epochs are block boundaries by construction
        raise FginsError("EKF: a GNSS epoch fell between block boundaries (internal error)")
    gnss_at = np.full(len(times), -1)
    gnss_at[boundary] = np.arange(len(epochs.t))

    white_scale = np.ones(len(segments.dt))
    for a, b in imu.suspect:
        inside = (segments.start >= a) & (segments.start < b)
        white_scale[inside] = config.smoother.suspect_noise_factor

    n_nodes = len(segments.start) + 1
    rotation = np.empty((n_nodes, 3, 3))
    velocity = np.empty((n_nodes, 3))
    position = np.empty((n_nodes, 3))
    accel_bias = np.empty((n_nodes, 3))
    gyro_bias = np.empty((n_nodes, 3))
    n_blocks = len(times) - 1
    cov_prior = np.empty((n_blocks + 1, STATE_DIM, STATE_DIM))
    cov_posterior = np.empty_like(cov_prior)
    transition = np.empty((n_blocks, STATE_DIM, STATE_DIM))
    prior: list[NominalState] = []
    posterior: list[NominalState] = []
    counts = {
        "gnss_updates": 0,
        "velocity_updates": 0,
        "rejected_innovation": 0,
        "huber_downweighted": 0,
    }
    update = _Updater(
        epochs=epochs,
        lever_arm=np.asarray(config.gnss.lever_arm_m, dtype=float),
        huber_k=config.gnss.huber_k,
        gate_probability=options.innovation_gate_probability,
        frame=frame,
        counts=counts,
    )

    state = NominalState(
        rotation=np.asarray(align.rotation, dtype=float),
        velocity=np.asarray(align.velocity, dtype=float),
        position=np.asarray(align.position, dtype=float),
        accel_bias=np.zeros(3),
        gyro_bias=np.zeros(3),
    )
    cov = initial_covariance(
        state.rotation, align.attitude_sigma_rad, align.velocity_sigma, align.position_sigma, noise
    )
    gyro_at = imu.gyro[segments.sample]
    accel_at = imu.accel[segments.sample]

    def at_boundary(
        k: int, state: NominalState, cov: np.ndarray
    ) -> tuple[NominalState, np.ndarray]:
        prior.append(state.copy())
        cov_prior[k] = cov
        if gnss_at[k] >= 0:
            sample = min(int(np.searchsorted(imu.t, times[k], side="right")) - 1, len(imu) - 1)
            state, cov = update(int(gnss_at[k]), state, cov, imu.gyro[sample])
        posterior.append(state.copy())
        cov_posterior[k] = cov
        return state, cov

    state, cov = at_boundary(0, state, cov)
    for b in tqdm(range(n_blocks), desc="EKF", unit="block", disable=not progress, leave=False):
        span = segments.block(b)
        dt = segments.dt[span]
        nominal = propagate_nominal(state, gyro_at[span], accel_at[span], dt, frame)
        nodes = slice(span.start, span.stop)
        rotation[nodes] = nominal.rotation[:-1]
        velocity[nodes] = nominal.velocity[:-1]
        position[nodes] = nominal.position[:-1]
        accel_bias[nodes] = state.accel_bias
        gyro_bias[nodes] = state.gyro_bias
        phi, q = block_transition(nominal, dt, frame, noise, white_scale[span])
        transition[b] = phi
        cov = phi @ cov @ phi.T + q
        state, cov = at_boundary(b + 1, nominal.end(state), 0.5 * (cov + cov.T))
    # The final node is the last boundary's a-posteriori state.
    rotation[-1], velocity[-1], position[-1] = state.rotation, state.velocity, state.position
    accel_bias[-1], gyro_bias[-1] = state.accel_bias, state.gyro_bias
    counts["blocks"] = n_blocks
    run_rejected = update.rejected_times
    counts["gnss_epochs_used"] = len(epochs.t)
    counts["gnss_epochs_outside_imu_span"] = epochs.outside_imu_span
    run = FilterRun(
        segments=segments,
        rotation=rotation,
        velocity=velocity,
        position=position,
        accel_bias=accel_bias,
        gyro_bias=gyro_bias,
        prior=prior,
        posterior=posterior,
        cov_prior=cov_prior,
        cov_posterior=cov_posterior,
        transition=transition,
        counts=counts,
        rejected_times=run_rejected,
    )
    return run, epochs


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


def _trajectory(
    dataset: Dataset,
    method: str,
    states: NominalState,
    cov: np.ndarray,
    info: dict[str, object],
) -> Trajectory:
    return Trajectory(
        t=dataset.imu.t,
        position=states.position,
        velocity=states.velocity,
        rotation=states.rotation,
        origin=dataset.origin,
        method=method,
        gyro_bias=states.gyro_bias,
        accel_bias=states.accel_bias,
        position_cov=cov[:, POS, POS],
        velocity_cov=cov[:, VEL, VEL],
        attitude_cov=cov[:, ATT, ATT],
        info=info,
    )


def _info(run: FilterRun, epochs: GnssEpochs) -> dict[str, object]:
    return {
        "gnss_gating": epochs.gating_summary,
        **run.counts,
        "rejected_times": list(run.rejected_times),
    }


def filtered_output(dataset: Dataset, run: FilterRun) -> tuple[NominalState, np.ndarray]:
    """Forward-filter states at every IMU sample (a-posteriori at update epochs)."""
    rows, block, share = _node_rows(run.segments, dataset.imu.t)
    states = NominalState(
        rotation=run.rotation[rows],
        velocity=run.velocity[rows],
        position=run.position[rows],
        accel_bias=run.accel_bias[rows],
        gyro_bias=run.gyro_bias[rows],
    )
    cov = _interpolate(run.cov_posterior, run.cov_prior, block, share)
    # The last sample sits on the last boundary: a-posteriori, not a-priori.
    cov[dataset.imu.t >= run.segments.times[-1]] = run.cov_posterior[-1]
    return states, cov


def rts_smooth(run: FilterRun) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Backward RTS pass over the block boundaries.

    Returns per boundary k: the smoothed correction relative to the forward a-posteriori
    state (the start of block k), the smoothed correction relative to the forward a-priori
    state (the end of block k-1), and the smoothed covariance.
    """
    n = len(run.posterior)
    from_posterior = np.zeros((n, STATE_DIM))
    from_prior = np.zeros((n, STATE_DIM))
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
    return from_posterior, from_prior, cov_smoothed


def smoothed_output(dataset: Dataset, run: FilterRun) -> tuple[NominalState, np.ndarray]:
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
    cov = _interpolate(
        cov_smoothed, cov_smoothed, np.minimum(block, len(cov_smoothed) - 2), share_cov
    )
    states = NominalState(
        rotation=so3_exp(correction[:, ATT]) @ forward.rotation,
        velocity=forward.velocity + correction[:, VEL],
        position=forward.position + correction[:, POS],
        accel_bias=forward.accel_bias + correction[:, ACC_BIAS],
        gyro_bias=forward.gyro_bias + correction[:, GYRO_BIAS],
    )
    return states, cov


def run_ekf(
    dataset: Dataset,
    config: RunConfig,
    *,
    gnss_mask: np.ndarray | None = None,
    progress: bool = True,
    options: EkfOptions | None = None,
) -> Trajectory:
    """Loosely coupled 15-state error-state EKF (method ``"ekf"``), output at every IMU sample.

    ``gnss_mask`` withholds GNSS epochs (outages, True = keep). Raises InputError when no
    usable GNSS epoch lies within the IMU span. ``info`` counts updates and rejections.
    """
    started = time.perf_counter()
    run, epochs = run_filter(dataset, config, gnss_mask, options or EkfOptions(), progress)
    filtered = time.perf_counter()
    states, cov = filtered_output(dataset, run)
    trajectory = _trajectory(dataset, "ekf", states, cov, _info(run, epochs))
    trajectory.timings.update(
        {"filter": filtered - started, "total": time.perf_counter() - started}
    )
    return trajectory


def run_ekf_rts(
    dataset: Dataset,
    config: RunConfig,
    *,
    gnss_mask: np.ndarray | None = None,
    progress: bool = True,
    options: EkfOptions | None = None,
) -> Trajectory:
    """The EKF of :func:`run_ekf` followed by a Rauch-Tung-Striebel smoother (``"ekf-rts"``)."""
    started = time.perf_counter()
    run, epochs = run_filter(dataset, config, gnss_mask, options or EkfOptions(), progress)
    filtered = time.perf_counter()
    states, cov = smoothed_output(dataset, run)
    trajectory = _trajectory(dataset, "ekf-rts", states, cov, _info(run, epochs))
    trajectory.timings.update(
        {
            "filter": filtered - started,
            "smoother": time.perf_counter() - filtered,
            "total": time.perf_counter() - started,
        }
    )
    return trajectory
