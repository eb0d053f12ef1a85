"""GNSS measurements for the Kalman baselines: which epochs, their values, sigmas and models.

The epochs, sigmas and gating come from :mod:`fgins.factors.gnss` (the one GNSS noise model
of the project) exactly as the factor graph uses them; only the linearisation lives here, and
the closed-loop linear Kalman update (:func:`kalman_update`) every linearised measurement of
the baselines goes through.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from fgins.baseline.heading_consider import YAW
from fgins.baseline.mechanization import (
    ATT,
    GYRO_BIAS,
    POS,
    STATE_DIM,
    VEL,
    NominalState,
    skew_batch,
)
from fgins.config import RunConfig
from fgins.datatypes import Dataset, InputError
from fgins.factors import gnss as gnss_model


@dataclass
class GnssEpochs:
    """The usable GNSS epochs inside the IMU span, ENU, with their 1-sigma errors."""

    t: np.ndarray  # (M,)
    position: np.ndarray  # (M, 3) antenna, ENU
    position_sigma: np.ndarray  # (M, 3)
    velocity: np.ndarray  # (M, 3) ENU, NaN where none
    velocity_sigma: np.ndarray  # (M, 3), NaN where that component is not used
    usable: np.ndarray  # (len(dataset.gnss),) mask of the epochs used
    gating_summary: str
    outside_imu_span: int


def select_gnss(dataset: Dataset, config: RunConfig, gnss_mask: np.ndarray | None) -> GnssEpochs:
    """Gated, outage-masked epochs within the IMU span (as :func:`graph.problem.build_problem`)."""
    gnss = dataset.gnss
    if gnss_mask is not None:
        gnss_mask = np.asarray(gnss_mask, dtype=bool)
        if gnss_mask.shape != (len(gnss),):
            raise InputError(
                f"gnss_mask has shape {gnss_mask.shape} for {len(gnss)} GNSS epochs; "
                "build it with fgins.outages.outage_mask(dataset, windows)"
            )
    imu_t = dataset.imu.t
    # The graph's count (factors.gnss.select_epochs): withheld, outside the IMU span, gated,
    # each epoch once; the summary line said "60 pass the gates" right after a warning that
    # 20 of the 60 lie outside the IMU span (outside tester).
    gate = gnss_model.gate_epochs(
        gnss, config.gnss, withheld=None if gnss_mask is None else ~gnss_mask,
        imu_span=(float(imu_t[0]), float(imu_t[-1])),
    )  # fmt: skip
    usable = gate.used
    gnss_model.require_usable_fixes(dataset, config.gnss, gnss_mask, usable)
    outside = gate.outside_span
    subset = gnss.subset(usable)
    velocity_sigma = gnss_model.velocity_sigmas(subset, config.gnss)
    if not config.gnss.use_velocity:
        velocity_sigma[:] = np.nan
    return GnssEpochs(
        t=subset.t,
        position=dataset.gnss_enu()[usable],
        position_sigma=gnss_model.position_sigmas(subset, config.gnss),
        velocity=None if subset.velocity is None else dataset.gnss_velocity_nav()[usable],
        velocity_sigma=velocity_sigma,
        usable=usable,
        gating_summary=gate.summary() + gnss_model.dropped_on_read_note(dataset.metadata),
        outside_imu_span=outside,
    )


@dataclass
class Linearized:
    """Stacked measurement rows at one epoch: residual z - h(x), Jacobian, noise variances."""

    residual: np.ndarray  # (m,)
    jacobian: np.ndarray  # (m, 15), or up to the antenna states' last column
    variance: np.ndarray  # (m,)
    n_position: int
    n_velocity: int


@dataclass(frozen=True)
class AntennaStates:
    """Five augmented error states of a Kalman pass from ``index`` on: the antenna's offset
    from the configured lever arm (3, IMU axes), the fixes' time offset at ``middle`` (s,
    late) and its change from there to ``middle +- half_span`` (a drift between two clocks),
    in the layout of :mod:`fgins.antenna_verdict` (ARM, TIME, DRIFT)."""

    index: int
    middle: float
    half_span: float

    def nominal(self, state: NominalState) -> tuple[np.ndarray, float, float]:
        """The arm offset, time offset and drift of ``state``."""
        assert state.extra is not None
        values = state.extra[self.index - STATE_DIM : self.index - STATE_DIM + 5]
        return values[:3], float(values[3]), float(values[4])


def linearize_gnss(
    epochs: GnssEpochs,
    g: int,
    state: NominalState,
    body_rate: np.ndarray,
    lever_arm: np.ndarray,
    antenna: AntennaStates | None = None,
) -> Linearized:
    """Antenna position (and velocity where given) of epoch ``g`` against the nominal state.

    h_p = p + R l and h_v = v + R (w_nb x l), with w_nb the body rate relative to ENU (bias
    corrected). With R_true = Exp(phi) R: d(R l)/dphi = -[R l]x, d(R (w x l))/dphi =
    -[R (w x l)]x and, since w_true = w_nominal - dbg, d(R (w x l))/d(dbg) = R [l]x.

    With ``antenna`` (:class:`AntennaStates`): the arm is ``l + a`` (d/da: R, and R [w]x on
    the velocity) and the position was stamped ``d = d0 + d1 s`` late (s = (t - middle) /
    half_span), h_p = p + R (l + a) - v d (d/dd0: -v, d/dd1: -v s, d/dv: -d I). Only the
    positions carry the time offset: a receiver's velocities may lag its positions by
    their own 0.5-2.5 s (smoothing), and at a turn's 2 m/s^2 a shared offset would be taken
    from them (0.1 m/s sigmas) and move every position by the speed times their lag. The
    Jacobian then has a column per error state up to the antenna's, else 15.
    """
    rotation = state.rotation
    columns = STATE_DIM
    late = along = 0.0
    if antenna is not None:
        offset, late0, drift = antenna.nominal(state)
        lever_arm = lever_arm + offset
        along = (float(epochs.t[g]) - antenna.middle) / antenna.half_span  # the drift's s
        late = late0 + drift * along
        columns = antenna.index + 5
    arm_nav = rotation @ lever_arm
    rows_h = [np.zeros((3, columns))]
    rows_h[0][:, POS] = np.eye(3)
    rows_h[0][:, ATT] = -skew_batch(arm_nav)
    predicted = state.position + arm_nav
    if antenna is not None:
        a = antenna.index
        rows_h[0][:, VEL] = -late * np.eye(3)
        rows_h[0][:, a : a + 3] = rotation
        rows_h[0][:, a + 3] = -state.velocity
        rows_h[0][:, a + 4] = -state.velocity * along
        predicted = predicted - state.velocity * late
    residual = [epochs.position[g] - predicted]
    variance = [epochs.position_sigma[g] ** 2]
    n_velocity = 0
    use = np.isfinite(epochs.velocity_sigma[g]) & np.isfinite(epochs.velocity[g])
    if use[0] and use[1]:
        w, arm = body_rate, lever_arm  # w x l written out: np.cross's axis handling costs
        arm_velocity = rotation @ np.array(  # more than the product (issue 9)
            [w[1] * arm[2] - w[2] * arm[1], w[2] * arm[0] - w[0] * arm[2],
             w[0] * arm[1] - w[1] * arm[0]]
        )  # fmt: skip
        h = np.zeros((3, columns))
        h[:, VEL] = np.eye(3)
        h[:, ATT] = -skew_batch(arm_velocity)
        h[:, GYRO_BIAS] = rotation @ skew_batch(lever_arm)
        if antenna is not None:
            h[:, antenna.index : antenna.index + 3] = rotation @ skew_batch(body_rate)
        r = epochs.velocity[g] - (state.velocity + arm_velocity)
        # Vertical velocity only where the receiver gives it (speed + course has none).
        rows = np.flatnonzero(use)
        rows_h.append(h[rows])
        residual.append(r[rows])
        variance.append(epochs.velocity_sigma[g][rows] ** 2)
        n_velocity = len(rows)
    return Linearized(
        residual=np.concatenate(residual),
        jacobian=np.vstack(rows_h),
        variance=np.concatenate(variance),
        n_position=3,
        n_velocity=n_velocity,
    )


# A forward filter's state before a fix is its prediction of it. After a stretch of
# GAP_RETURN_S without fixes used, the first fix is the test of everything the filter
# carried across: a miss beyond GAP_RETURN_CHI2 (chi-square, 2 dof: 4e-6 for a filter that
# holds) and GAP_RETURN_MIN_M is said (fgins.pipeline; for EKF+RTS, of its forward pass).
# At 50 (7 sigmas) a gyro 1 % off in scale left EKF, UKF and the online iSAM2 at NEES 7-11
# inside outages with a 15.6 m miss at 5.5 sigmas unsaid (outside tester).
GAP_RETURN_S = 10.0
GAP_RETURN_CHI2 = 25.0
GAP_RETURN_MIN_M = 2.0


@dataclass
class GapReturnMiss:
    """The worst miss of a filter's prediction at the first fix after a gap in its fixes."""

    t: float  # the fix's time
    gap_s: float  # the gap before it
    distance_m: float  # horizontal miss
    sigmas: float  # in sigmas of the prediction's and the fix's horizontal uncertainty
    count: int  # gaps whose return was missed this badly
    gaps: int  # gaps of GAP_RETURN_S or more


def gap_return_miss(
    epochs: GnssEpochs,
    predicted_at: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, np.ndarray] | None],
    lever_arm: np.ndarray,
) -> GapReturnMiss | None:
    """The worst miss beyond GAP_RETURN_CHI2 and GAP_RETURN_MIN_M, or None.
    ``predicted_at(times)``: the filter's (position (n, 3), rotation (n, 3, 3), position
    covariance (n, 3, 3)) just before the fixes at ``times`` (None: none known)."""
    t = np.asarray(epochs.t, dtype=float)
    after = np.flatnonzero(np.diff(t) > GAP_RETURN_S) + 1
    if not after.size:
        return None
    predicted = predicted_at(t[after])
    if predicted is None:
        return None
    position, rotation, cov = predicted
    known = np.all(np.isfinite(position), axis=1)
    after, position, rotation, cov = after[known], position[known], rotation[known], cov[known]
    if not after.size:
        return None
    antenna = position + rotation @ np.asarray(lever_arm, dtype=float)
    miss = (epochs.position[after] - antenna)[:, :2]
    covariance = cov[:, :2, :2] + np.stack(
        [np.diag(sigma[:2] ** 2) for sigma in epochs.position_sigma[after]]
    )
    with np.errstate(invalid="ignore"):
        chi2 = np.einsum("ni,ni->n", miss, np.linalg.solve(covariance, miss[..., None])[..., 0])
    distance = np.linalg.norm(miss, axis=1)
    bad = np.flatnonzero(np.isfinite(chi2) & (chi2 > GAP_RETURN_CHI2) & (distance > GAP_RETURN_MIN_M))
    if not bad.size:
        return None
    worst = bad[np.argmax(chi2[bad])]
    return GapReturnMiss(
        t=float(t[after[worst]]), gap_s=float(t[after[worst]] - t[after[worst] - 1]),
        distance_m=float(distance[worst]), sigmas=float(np.sqrt(chi2[worst])),
        count=int(bad.size), gaps=int(after.size),
    )  # fmt: skip


def chi2_quantile(probability: float, dof: int) -> float:
    """Chi-square quantile (Wilson-Hilferty; within ~1 % for dof >= 3), numpy/stdlib only."""
    z = NormalDist().inv_cdf(probability)
    c = 2.0 / (9.0 * dof)
    return float(dof * (1.0 - c + z * np.sqrt(c)) ** 3)


def huber_variances(
    residual: np.ndarray, innovation_var: np.ndarray, variance: np.ndarray, k: float
) -> tuple[np.ndarray, int]:
    """Measurement variances inflated like the graph's Huber kernel (weight k/|u| beyond k).

    u is the residual normalised by its innovation sigma (prediction + measurement), the
    filter's analogue of the graph's whitened error. Returns the variances and how many
    components were down-weighted.
    """
    u = np.abs(residual) / np.sqrt(innovation_var)
    factor = np.where(u > k, u / k, 1.0)
    return variance * factor, int((u > k).sum())


def reset_jacobian(
    phi: np.ndarray, dim: int = STATE_DIM, heading_unknown: bool = False
) -> np.ndarray:
    """Covariance reset after injecting an attitude correction ``phi`` (first order).

    The error is global (``R_true = Exp(e) R``) and the correction is injected on the left
    (``R+ = Exp(phi) R``), so the new error is ``log(Exp(e) Exp(-phi)) ~ e - phi +
    [phi]x e / 2``: d(e+)/de = I + [phi]x / 2 (I - [phi]x / 2 is the reset of a local,
    right-multiplied error)."""
    g = np.eye(dim)
    g[ATT, ATT] += 0.5 * skew_batch(phi)
    if heading_unknown:
        # First order in the heading error too: for one of tens of degrees it is no
        # longer a coupling but noise, which would teach the tilt a heading (and the tilt,
        # seen in the velocity, would teach it back).
        g[YAW, ATT.start : YAW] = g[ATT.start : YAW, YAW] = 0.0
    return g


def pad_columns(jacobian: np.ndarray, dim: int) -> np.ndarray:
    """A Jacobian over the 15 navigation error states extended by zero columns to ``dim``."""
    if jacobian.shape[1] == dim:
        return jacobian
    out = np.zeros((jacobian.shape[0], dim))
    out[:, : jacobian.shape[1]] = jacobian
    return out


def kalman_update(
    state: NominalState,
    cov: np.ndarray,
    residual: np.ndarray,
    jacobian: np.ndarray,
    variance: np.ndarray,
    innovation_cov: np.ndarray | None = None,
    heading_unknown: bool = False,
) -> tuple[NominalState, np.ndarray]:
    """Closed-loop linear update: inject ``K r`` into the nominal state, Joseph-form covariance
    and the attitude reset. ``innovation_cov`` (H P H^T + R) may be passed when the caller has
    it already (gating); ``jacobian`` has as many columns as ``cov``. ``heading_unknown``:
    the motion cannot tell the heading (:mod:`fgins.baseline.heading_consider`), and the
    reset leaves it uncoupled."""
    s = (
        jacobian @ cov @ jacobian.T + np.diag(variance)
        if innovation_cov is None
        else innovation_cov
    )
    gain = np.linalg.solve(s, jacobian @ cov).T
    dx = gain @ residual
    i_kh = np.eye(len(cov)) - gain @ jacobian
    cov = i_kh @ cov @ i_kh.T + (gain * variance) @ gain.T
    reset = reset_jacobian(dx[ATT], len(cov), heading_unknown)
    cov = reset @ cov @ reset.T
    return state.boxplus(dx), 0.5 * (cov + cov.T)
