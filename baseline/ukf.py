"""Loosely coupled unscented Kalman filter on the error state (numpy only, method "ukf").

The sigma-point filter of the MEMS study (20 Hz MEMS IMU + 2 Hz GPS on a car; fixes with
PDOP > 5 rejected, which :func:`fgins.factors.gnss.gate_epochs` already does through
``config.gnss.pdop_max``). Everything but the estimator is the EKF's
(:mod:`fgins.baseline.ekf`): same alignment and initial covariance, same GNSS epochs, sigmas,
gating and lever arm (:mod:`fgins.baseline.measurements`), same strapdown model and blocks
(:mod:`fgins.baseline.mechanization`), same output construction, all from the one shared
setup (:func:`fgins.baseline.ekf.prepare_filter`, :class:`fgins.baseline.ekf.FilterRecorder`).
The error state has 15 dimensions, 16 with a barometer bias; the land-vehicle and barometer
pseudo-measurements (:mod:`fgins.baseline.vehicle_updates`) are the EKF's linear updates (they
are linear, or for NHC nearly so, in the error state).

Sigma points. Error-state sigma points ``dx_i`` (2n + 1 = 31 for n = 15) are drawn around the
nominal state and turned into full states ``x_i = nominal [+] dx_i``; each is propagated
through the nonlinear mechanization, and the propagated spread, expressed again as error
states relative to the propagated central point, gives the predicted mean and covariance.

Why the *scaled* unscented transform: the study used the unscaled form with kappa = 3 - n,
which for n = 15 is kappa = -12; the central weight kappa / (n + kappa) = -4 is negative, and
a covariance built with a negative weight can be indefinite (a Cholesky factor of it then does
not exist and the filter stops). The scaled form (alpha, beta, kappa) with the defaults
alpha = 1, beta = 2, kappa = 0 has lambda = alpha^2 (n + kappa) - n = 0: mean weights
W0 = 0 and Wi = 1 / (2n), covariance weight W0 = beta + 1 - alpha^2 = 2, all non-negative,
so the predicted covariance is a sum of positive semidefinite terms (plus Q). Points lie at
+-sqrt(n + lambda) = 3.9 sigma, which probes the attitude nonlinearity over the range that
matters after an outage; smaller ``alpha`` moves them in (and then W0 < 0).

Speed. Propagating 31 sigma points per IMU sample in a Python loop would be far too slow;
instead each block (the stretch between two GNSS epochs, at most ``max_block_s``) is
propagated for all 31 points and all samples at once with the vectorised block mechanization
(:func:`fgins.baseline.mechanization.propagate_nominal` takes batch axes). Sigma points are
drawn afresh at every block start; the process noise of the block is added after the
propagation, mapped to the block end through the central point's transition (exact for the
additive, linear noise model of the EKF: white IMU noise and bias random walks).

GNSS update. Position (and velocity where given) with the lever arm, ``p + R l`` and
``v + R (w x l)``: nonlinear in the attitude when there is a lever arm, so the update uses the
unscented transform too (for a zero lever arm it is linear and the transform reproduces the
linear Kalman update exactly). Injection of the update into the nominal state and the
covariance reset are the EKF's.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from fgins.baseline.ekf import (
    FilterRecorder,
    FilterRun,
    GnssUpdater,
    antenna_check,
    forward_pass,
    kalman_trajectory,
    prepare_filter,
)
from fgins.baseline.measurements import GnssEpochs, reset_jacobian
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
    propagate_nominal,
)
from fgins.config import RunConfig
from fgins.datatypes import Dataset, InputError, Trajectory
from fgins.geodesy import so3_exp, so3_log


@dataclass(frozen=True)
class UkfOptions:
    """Unscented-transform scaling and block length (see the module docstring)."""

    alpha: float = 1.0
    beta: float = 2.0
    kappa: float = 0.0
    max_block_s: float = 1.0
    innovation_gate_probability: float | None = None

    def __post_init__(self) -> None:
        if not 0.0 < self.alpha <= 1.0:
            raise InputError(f"UKF: alpha must be in (0, 1], got {self.alpha}")
        if not self.max_block_s > 0:
            raise InputError(f"UKF: max_block_s must be > 0, got {self.max_block_s}")
        if self.alpha**2 * (STATE_DIM + self.kappa) <= 0:
            raise InputError(f"UKF: alpha^2 (n + kappa) must be > 0 (kappa = {self.kappa})")
        p = self.innovation_gate_probability
        if p is not None and not 0.5 < p < 1.0:
            raise InputError(f"UKF: innovation_gate_probability must be in (0.5, 1), got {p}")


@dataclass(frozen=True)
class SigmaWeights:
    """Weights of the scaled unscented transform; points at +-sqrt(scale) sigma."""

    mean: np.ndarray  # (2n + 1,)
    cov: np.ndarray  # (2n + 1,)
    scale: float  # n + lambda


def sigma_weights(n: int, alpha: float, beta: float = 2.0, kappa: float = 0.0) -> SigmaWeights:
    """Scaled unscented transform (Julier 2002): lambda = alpha^2 (n + kappa) - n."""
    lam = alpha**2 * (n + kappa) - n
    scale = n + lam
    mean = np.full(2 * n + 1, 0.5 / scale)
    mean[0] = lam / scale
    cov = mean.copy()
    cov[0] += 1.0 - alpha**2 + beta
    return SigmaWeights(mean=mean, cov=cov, scale=scale)


def sigma_offsets(cov: np.ndarray, scale: float) -> np.ndarray:
    """Offsets (2n + 1, n): zero, then +- the columns of a square root of ``scale * cov``."""
    try:
        root = np.linalg.cholesky(scale * cov)
    except np.linalg.LinAlgError:
        # Rounding can leave a tiny negative eigenvalue after many updates: clip it.
        values, vectors = np.linalg.eigh(0.5 * (cov + cov.T))
        root = vectors * np.sqrt(scale * np.clip(values, 0.0, None))
    return np.concatenate([np.zeros((1, len(cov))), root.T, -root.T])


def unscented_transform(
    function: Callable[[np.ndarray], np.ndarray],
    mean: np.ndarray,
    cov: np.ndarray,
    weights: SigmaWeights,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mean, covariance of ``function(x)`` for x ~ (mean, cov), and the cross-covariance
    cov(x, y). ``function`` maps points (2n + 1, n) to outputs (2n + 1, m) in one call."""
    points = mean + sigma_offsets(cov, weights.scale)
    outputs = function(points)
    y_mean = weights.mean @ outputs
    dy = outputs - y_mean
    dx = points - weights.mean @ points
    return y_mean, (weights.cov * dy.T) @ dy, (weights.cov * dx.T) @ dy


def _errors_from_central(block: BlockNominal, offsets: np.ndarray) -> np.ndarray:
    """Error states (S, nodes, n) of every propagated sigma point relative to point 0."""
    s, nodes = block.position.shape[:2]
    errors = np.empty((s, nodes, offsets.shape[1]))
    errors[..., POS] = block.position - block.position[:1]
    errors[..., VEL] = block.velocity - block.velocity[:1]
    errors[..., ATT] = so3_log(block.rotation @ np.swapaxes(block.rotation[:1], -1, -2))
    errors[..., ACC_BIAS] = offsets[:, None, ACC_BIAS]  # biases are constant over the block
    errors[..., GYRO_BIAS] = offsets[:, None, GYRO_BIAS]
    errors[..., STATE_DIM:] = offsets[:, None, STATE_DIM:]  # augmented states: constant too
    return errors


def _central(block: BlockNominal) -> BlockNominal:
    return BlockNominal(
        block.rotation[0], block.velocity[0], block.position[0], block.specific_force_nav[0]
    )


def _gnss_predictions(
    points: NominalState, gyro: np.ndarray, frame: NavFrame, lever_arm: np.ndarray, n_vel: int
) -> np.ndarray:
    """Antenna position and the first ``n_vel`` velocity components for states (S, ...)."""
    rotation = points.rotation
    arm = np.einsum("sij,j->si", rotation, lever_arm)
    rows = [points.position + arm]
    if n_vel:
        body_rate = gyro - points.gyro_bias - np.einsum("sji,j->si", rotation, frame.earth_rate)
        arm_velocity = np.einsum("sij,sj->si", rotation, np.cross(body_rate, lever_arm))
        rows.append((points.velocity + arm_velocity)[:, :n_vel])
    return np.concatenate(rows, axis=1)


@dataclass(kw_only=True)
class _UnscentedUpdater(GnssUpdater):
    """GNSS update at a block boundary through the unscented transform (closed loop)."""

    weights: SigmaWeights

    def __call__(
        self, g: int, state: NominalState, cov: np.ndarray, gyro: np.ndarray
    ) -> tuple[NominalState, np.ndarray]:
        # Measured values, rows and variances as the EKF forms them; residual = z - h(state).
        lin = self.linearize(g, state, gyro)

        def predict(offsets: np.ndarray) -> np.ndarray:
            points = state.boxplus(offsets)
            return _gnss_predictions(points, gyro, self.frame, self.lever_arm, lin.n_velocity)

        y_mean, predicted, cross = unscented_transform(
            predict, np.zeros(len(cov)), cov, self.weights
        )
        # residual = z - h(state), so the innovation z - y_mean is:
        innovation = lin.residual - (y_mean - predict(np.zeros((1, len(cov))))[0])
        screened = self.screen(g, innovation, predicted, lin.variance)
        if screened is None:
            return state, cov
        _, s = screened
        gain = np.linalg.solve(s, cross.T).T
        correction = gain @ innovation
        cov = cov - gain @ s @ gain.T
        reset = reset_jacobian(correction[ATT], len(cov), self.heading_unknown)
        cov = reset @ cov @ reset.T
        self.count_update(lin)
        return state.boxplus(correction), 0.5 * (cov + cov.T)


def _predict_block(
    state: NominalState,
    cov: np.ndarray,
    gyro: np.ndarray,
    accel: np.ndarray,
    dt: np.ndarray,
    frame: NavFrame,
    weights: SigmaWeights,
) -> tuple[NominalState, np.ndarray, BlockNominal]:
    """Propagate all sigma points through one block at once.

    Returns the predicted mean states at every node of the block (batch of nodes), the
    sigma covariance at the block end (without process noise), and the central point's
    propagation (for the process noise and the transition).
    """
    offsets = sigma_offsets(cov, weights.scale)
    points = state.boxplus(offsets)
    block = propagate_nominal(points, gyro, accel, dt, frame)
    errors = _errors_from_central(block, offsets)  # (S, nodes, 15)
    mean_error = np.einsum("s,snk->nk", weights.mean, errors)
    spread = errors[:, -1] - mean_error[-1]
    sigma_cov = (weights.cov * spread.T) @ spread
    central = _central(block)
    means = NominalState(
        rotation=so3_exp(mean_error[:, ATT]) @ central.rotation,
        velocity=central.velocity + mean_error[:, VEL],
        position=central.position + mean_error[:, POS],
        accel_bias=np.broadcast_to(state.accel_bias + mean_error[-1, ACC_BIAS], (len(dt) + 1, 3)),
        gyro_bias=np.broadcast_to(state.gyro_bias + mean_error[-1, GYRO_BIAS], (len(dt) + 1, 3)),
        extra=np.broadcast_to(
            state.extra + mean_error[-1, STATE_DIM:], (len(dt) + 1, mean_error.shape[1] - STATE_DIM)
        ),
    )
    return means, sigma_cov, central


def run_ukf_filter(
    dataset: Dataset,
    config: RunConfig,
    gnss_mask: np.ndarray | None,
    options: UkfOptions,
    progress: bool,
) -> tuple[FilterRun, GnssEpochs]:
    """The forward UKF pass; the result has the EKF's layout (transition: central point's)."""
    setup = prepare_filter(dataset, config, gnss_mask, options.max_block_s)
    recorder = FilterRecorder(setup, dataset.imu.t, dataset.imu.gyro)
    weights = sigma_weights(len(setup.cov), options.alpha, options.beta, options.kappa)
    update = _UnscentedUpdater.for_setup(
        setup, config, options.innovation_gate_probability, weights=weights
    )

    def predict(
        b: int, span: slice, state: NominalState, cov: np.ndarray
    ) -> tuple[NominalState, np.ndarray]:
        means, sigma_cov, central = _predict_block(
            state,
            cov,
            setup.gyro_at[span],
            setup.accel_at[span],
            setup.segments.dt[span],
            setup.frame,
            weights,
        )
        recorder.store_nodes(span, means)
        _, q = recorder.block_noise(b, span, central)
        assert means.extra is not None
        end = NominalState(
            means.rotation[-1].copy(),
            means.velocity[-1].copy(),
            means.position[-1].copy(),
            means.accel_bias[-1].copy(),
            means.gyro_bias[-1].copy(),
            means.extra[-1].copy(),
        )
        return end, sigma_cov + q

    return forward_pass(recorder, update, predict, "UKF", progress), setup.epochs


def run_ukf(
    dataset: Dataset,
    config: RunConfig,
    *,
    gnss_mask: np.ndarray | None = None,
    progress: bool = True,
    options: UkfOptions | None = None,
) -> Trajectory:
    """Loosely coupled 15-state error-state UKF (method ``"ukf"``), output at every IMU sample.

    ``gnss_mask`` withholds GNSS epochs (outages, True = keep). Raises InputError when no
    usable GNSS epoch lies within the IMU span. ``info`` counts updates and rejections and
    records the unscented-transform parameters.
    """
    options = options or UkfOptions()
    return kalman_trajectory(
        dataset,
        "ukf",
        lambda: run_ukf_filter(dataset, config, gnss_mask, options, progress),
        extra_info={
            "unscented": {"alpha": options.alpha, "beta": options.beta, "kappa": options.kappa}
        },
        antenna_check=antenna_check(dataset, config, gnss_mask, options.max_block_s),
    )
