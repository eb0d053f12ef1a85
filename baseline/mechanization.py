"""Strapdown mechanization and the 15-state error model of the Kalman baselines (numpy only).

Navigation model (the simulator's and the factor graph's, see :mod:`fgins.sim.strapdown`):
local ENU frame at the origin (an Earth-fixed Cartesian frame), gravity ``g_n(p)`` where the
vehicle is (:func:`fgins.geodesy.gravity_enu`; ``(0, 0, -normal_gravity(lat0, h0))`` at the
origin), constant Earth rate ``w_ie`` in ENU. Each IMU sample is held over its interval ``dt`` and

    R_k+1 = R_k Exp((gyro_k - b_g - R_k^T w_ie) dt)
    a_k   = R_k (accel_k - b_a) + g_n(p_k) - 2 w_ie x v_k
    p_k+1 = p_k + v_k dt + a_k dt^2 / 2,   v_k+1 = v_k + a_k dt.

The per-sample Python work is avoided by propagating whole *blocks* of samples at once (the
stretch between two GNSS epochs, at most ``max_block_s``): rotations by a log-depth prefix
product (``R_k = Exp(-w_ie (t_k - t_0)) R_0 prod Exp(w_k dt)``, equal to the recursion above
to first order in the tiny ``|w_ie dt| |w dt|``), velocities by a cumulative sum in which the
Coriolis term is evaluated three times (fixed point; relative error ``(2 |w_ie| T)^3``), and the
error-state transition and process noise of the block by a tree reduction of the exact
per-sample Jacobians of the map above.

Error state (15): ``dp, dv, phi, dba, dbg`` with ``true = nominal + d`` for position, velocity
and biases and ``R_true = Exp(phi) R_nominal`` (``phi`` in ENU). Filters may append further
additive states after these 15 (e.g. a barometer bias): :attr:`NominalState.extra` carries
their nominal values and :func:`augment_transition` extends a block's Phi and Q to them.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np

from fgins.config import ImuNoise
from fgins.datatypes import Origin
from fgins.factors.imu_samples import segment_leads
from fgins.geodesy import (
    earth_rate_enu,
    gravity_enu,
    normal_gravity,
    skew_batch,
    so3_exp,
    so3_log,
)

STATE_DIM = 15
POS = slice(0, 3)
VEL = slice(3, 6)
ATT = slice(6, 9)
ACC_BIAS = slice(9, 12)
GYRO_BIAS = slice(12, 15)


@dataclass(frozen=True)
class NavFrame:
    """Gravity and Earth rate of the local ENU frame at the origin; with ``origin``, gravity
    where the vehicle is (:func:`fgins.geodesy.gravity_enu`)."""

    gravity: np.ndarray
    earth_rate: np.ndarray
    origin: Origin | None = None

    @classmethod
    def at(cls, origin: Origin) -> NavFrame:
        return cls(
            gravity=np.array([0.0, 0.0, -normal_gravity(origin.lat, origin.alt)]),
            earth_rate=earth_rate_enu(origin.lat),
            origin=origin,
        )

    def gravity_at(self, position: np.ndarray) -> np.ndarray:
        """Gravity (..., 3) at ENU positions (..., 3)."""
        if self.origin is None:
            return np.broadcast_to(self.gravity, np.shape(position))
        return gravity_enu(position, self.origin)


@dataclass
class NominalState:
    """Nominal (total) navigation state; leading batch axes allowed (sigma points)."""

    rotation: np.ndarray  # (..., 3, 3) body -> ENU
    velocity: np.ndarray  # (..., 3)
    position: np.ndarray  # (..., 3)
    accel_bias: np.ndarray  # (..., 3)
    gyro_bias: np.ndarray  # (..., 3)
    # Additive states after the 15 navigation ones (..., m); m = 0 unless a filter augments.
    extra: np.ndarray | None = None

    def __post_init__(self) -> None:
        if self.extra is None:
            self.extra = np.zeros((*np.shape(self.velocity)[:-1], 0))

    @property
    def dim(self) -> int:
        """Length of the error-state vector: 15 plus the extra states."""
        assert self.extra is not None
        return STATE_DIM + self.extra.shape[-1]

    def copy(self) -> NominalState:
        assert self.extra is not None
        return NominalState(
            self.rotation.copy(),
            self.velocity.copy(),
            self.position.copy(),
            self.accel_bias.copy(),
            self.gyro_bias.copy(),
            self.extra.copy(),
        )

    def boxplus(self, dx: np.ndarray) -> NominalState:
        """The state corrected by error-state vectors ``dx`` (..., 15 + m)."""
        assert self.extra is not None
        rotation = so3_exp(dx[..., ATT]) @ self.rotation
        # Re-orthonormalise: thousands of corrections and prefix products accumulate rounding.
        u, _, vt = np.linalg.svd(rotation)
        return NominalState(
            rotation=u @ vt,
            velocity=self.velocity + dx[..., VEL],
            position=self.position + dx[..., POS],
            accel_bias=self.accel_bias + dx[..., ACC_BIAS],
            gyro_bias=self.gyro_bias + dx[..., GYRO_BIAS],
            extra=self.extra + dx[..., STATE_DIM:],
        )

    def boxminus(self, reference: NominalState) -> np.ndarray:
        """Error-state vector ``dx`` with ``reference.boxplus(dx) == self`` (..., 15 + m)."""
        assert self.extra is not None and reference.extra is not None
        phi = so3_log(self.rotation @ np.swapaxes(reference.rotation, -1, -2))
        return np.concatenate(
            [
                self.position - reference.position,
                self.velocity - reference.velocity,
                phi,
                self.accel_bias - reference.accel_bias,
                self.gyro_bias - reference.gyro_bias,
                self.extra - reference.extra,
            ],
            axis=-1,
        )


@dataclass
class Segments:
    """The IMU stream cut at block boundaries (GNSS epochs, fill times).

    Segment j starts at ``start[j]``, lasts ``dt[j]`` and uses IMU sample ``sample[j]`` (held
    constant), ``lead[j]`` seconds after that sample's time (a block boundary cut its
    interval; 0 otherwise); block b owns segments ``bounds[b]:bounds[b + 1]`` and ends at
    ``times[b + 1]``.
    """

    times: np.ndarray
    start: np.ndarray
    dt: np.ndarray
    sample: np.ndarray
    bounds: np.ndarray
    lead: np.ndarray

    def block(self, b: int) -> slice:
        return slice(int(self.bounds[b]), int(self.bounds[b + 1]))

    @property
    def nodes(self) -> np.ndarray:
        """Times of all segment starts plus the final time (the propagated states)."""
        return np.append(self.start, self.times[-1])


def block_times(
    t_first: float, t_last: float, anchors: np.ndarray, max_block_s: float
) -> np.ndarray:
    """Block boundaries: the span ends, every anchor inside, and fill times so that no block
    is longer than ``max_block_s``."""
    inside = anchors[(anchors > t_first) & (anchors < t_last)]
    ends = np.unique(np.concatenate([[t_first], inside, [t_last]]))
    pieces = [ends[:1]]
    for a, b in itertools.pairwise(ends):
        n_fill = max(1, int(np.ceil((b - a) / max_block_s - 1e-9)))
        # The anchor itself ends the piece: a + (b - a) can round below b (0.0396 + 1.0 from
        # fixes moved by 0.2604 s), and the epoch then matched no boundary.
        pieces.append(np.append(a + (b - a) * np.arange(1, n_fill) / n_fill, b))
    times = np.concatenate(pieces)
    times[-1] = t_last
    return times


def segment_imu(imu_t: np.ndarray, times: np.ndarray) -> Segments:
    """Cut the IMU stream at ``times`` (which span ``imu_t[0]..imu_t[-1]``)."""
    starts = np.union1d(imu_t, times)
    starts = starts[(starts >= times[0]) & (starts <= times[-1])]
    seg_start = starts[:-1]
    sample = np.clip(np.searchsorted(imu_t, seg_start, side="right") - 1, 0, len(imu_t) - 1)
    bounds = np.searchsorted(seg_start, times, side="left")
    bounds[-1] = len(seg_start)
    lead = segment_leads(imu_t, seg_start, sample)
    return Segments(times=times, start=seg_start, dt=np.diff(starts), sample=sample, bounds=bounds, lead=lead)


def prefix_products(steps: np.ndarray) -> np.ndarray:
    """``out[k] = steps[0] @ ... @ steps[k-1]`` for k = 0..n, vectorised over leading axes.

    Short runs: a Hillis-Steele scan along axis -3 (log2(n) batched products over all n).
    Longer ones (an IMU block of 100-200 samples): a blocked scan, ~sqrt(n) chunks of
    ~sqrt(n) matrices: the running product inside every chunk at once, then across the
    chunk totals, then one batched product; ~4x fewer 3x3 products (issue 9).
    """
    n = steps.shape[-3]
    if n > BLOCKED_SCAN_MIN:
        return _blocked_prefix_products(steps)
    prefix = steps.copy()
    n = prefix.shape[-3]
    shift = 1
    while shift < n:
        prefix[..., shift:, :, :] = prefix[..., :-shift, :, :] @ prefix[..., shift:, :, :]
        shift *= 2
    eye = np.broadcast_to(np.eye(3), (*prefix.shape[:-3], 1, 3, 3))
    return np.concatenate([eye, prefix], axis=-3)


BLOCKED_SCAN_MIN = 32


def _blocked_prefix_products(steps: np.ndarray) -> np.ndarray:
    """:func:`prefix_products` by chunks (see there)."""
    n = steps.shape[-3]
    lead = steps.shape[:-3]
    width = int(np.ceil(np.sqrt(n)))
    chunks = -(-n // width)
    padded = np.empty((*lead, chunks * width, 3, 3))
    padded[..., :n, :, :] = steps
    padded[..., n:, :, :] = np.eye(3)
    inner = padded.reshape(*lead, chunks, width, 3, 3)
    for j in range(1, width):  # running product inside every chunk, all chunks at once
        inner[..., j, :, :] = inner[..., j - 1, :, :] @ inner[..., j, :, :]
    before = np.empty((*lead, chunks, 3, 3))  # product of all earlier chunks
    before[..., 0, :, :] = np.eye(3)
    for i in range(1, chunks):
        before[..., i, :, :] = before[..., i - 1, :, :] @ inner[..., i - 1, -1, :, :]
    out = np.empty((*lead, n + 1, 3, 3))
    out[..., 0, :, :] = np.eye(3)
    out[..., 1:, :, :] = (before[..., :, None, :, :] @ inner).reshape(*lead, -1, 3, 3)[
        ..., :n, :, :
    ]
    return out


@dataclass
class BlockNominal:
    """Nominal states at every node of a block (n segments -> n + 1 nodes)."""

    rotation: np.ndarray  # (..., n+1, 3, 3)
    velocity: np.ndarray  # (..., n+1, 3)
    position: np.ndarray  # (..., n+1, 3)
    specific_force_nav: np.ndarray  # (..., n, 3) R_k (accel_k - b_a)

    def end(self, state: NominalState) -> NominalState:
        return NominalState(
            rotation=self.rotation[..., -1, :, :],
            velocity=self.velocity[..., -1, :],
            position=self.position[..., -1, :],
            accel_bias=state.accel_bias.copy(),
            gyro_bias=state.gyro_bias.copy(),
            extra=None if state.extra is None else state.extra.copy(),
        )


def cross_const(w: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``np.cross(w, v)`` of a constant 3-vector ``w`` and vectors ``v`` (..., 3): the same
    products and differences (so the same bits), without np.cross's axis handling, which
    was a fifth of the EKF's time per block."""
    out = np.empty(np.broadcast_shapes(np.shape(w), np.shape(v)))
    w0, w1, w2 = w[..., 0], w[..., 1], w[..., 2]
    v0, v1, v2 = v[..., 0], v[..., 1], v[..., 2]
    out[..., 0] = w1 * v2 - w2 * v1
    out[..., 1] = w2 * v0 - w0 * v2
    out[..., 2] = w0 * v1 - w1 * v0
    return out


_EARTH_TURNS: dict[bytes, np.ndarray] = {}
_EARTH_TURNS_MAX = 64


def _earth_turn(w_ie: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """The Earth's rotation (n+1, 3, 3) from a block's start to each of its nodes.

    It depends on the block's sample intervals only, and a regular IMU gives the same few
    patterns block after block: cached (the same numbers, computed once per pattern; issue 9).
    Read-only: callers must not write into it.
    """
    key = w_ie.tobytes() + dt.tobytes()
    turn = _EARTH_TURNS.get(key)
    if turn is None:
        elapsed = np.concatenate([[0.0], np.cumsum(dt)])
        turn = so3_exp(-w_ie[None, :] * elapsed[:, None])
        turn.flags.writeable = False
        if len(_EARTH_TURNS) >= _EARTH_TURNS_MAX:
            _EARTH_TURNS.pop(next(iter(_EARTH_TURNS)))
        _EARTH_TURNS[key] = turn
    return turn


def propagate_nominal(
    state: NominalState, gyro: np.ndarray, accel: np.ndarray, dt: np.ndarray, frame: NavFrame
) -> BlockNominal:
    """Mechanize samples (n, 3) held over ``dt`` (n,) from ``state`` (batch axes allowed)."""
    w_ie = frame.earth_rate
    bg = state.gyro_bias[..., None, :]
    ba = state.accel_bias[..., None, :]
    steps = so3_exp((gyro - bg) * dt[:, None])  # (..., n, 3, 3)
    earth_turn = _earth_turn(w_ie, dt)  # (n+1, 3, 3)
    rotation = earth_turn @ state.rotation[..., None, :, :] @ prefix_products(steps)
    f_nav = np.einsum("...nij,...nj->...ni", rotation[..., :-1, :, :], accel - ba)
    # Acceleration without the Coriolis term; gravity where the block starts (a block is
    # at most a few seconds: 100 m at 30 m/s changes gravity by 15 ug).
    a_free = f_nav + frame.gravity_at(state.position)[..., None, :]
    v0 = state.velocity[..., None, :]
    velocity_guess = np.broadcast_to(v0, a_free.shape)
    for _ in range(3):  # fixed point on the (tiny) Coriolis term, see module docstring
        accel_nav = a_free - 2.0 * cross_const(w_ie, velocity_guess)
        dv = accel_nav * dt[:, None]
        velocity = np.concatenate([v0, v0 + np.cumsum(dv, axis=-2)], axis=-2)
        velocity_guess = velocity[..., :-1, :]
    accel_nav = a_free - 2.0 * cross_const(w_ie, velocity_guess)
    dp = velocity_guess * dt[:, None] + 0.5 * accel_nav * dt[:, None] ** 2
    p0 = state.position[..., None, :]
    position = np.concatenate([p0, p0 + np.cumsum(dp, axis=-2)], axis=-2)
    return BlockNominal(rotation, velocity, position, f_nav)


def sample_transitions(
    rotation: np.ndarray, f_nav: np.ndarray, dt: np.ndarray, frame: NavFrame
) -> np.ndarray:
    """Exact Jacobians (n, 15, 15) of the per-sample map with respect to the error state."""
    n = len(dt)
    eye = np.eye(3)
    w_x = skew_batch(frame.earth_rate)
    f_x = skew_batch(f_nav)
    d1 = dt[:, None, None]
    d2 = d1**2
    phi = np.tile(np.eye(STATE_DIM), (n, 1, 1))
    phi[:, POS, VEL] = eye * d1 - w_x * d2
    phi[:, POS, ATT] = -0.5 * f_x * d2
    phi[:, POS, ACC_BIAS] = -0.5 * rotation * d2
    phi[:, VEL, VEL] -= 2.0 * w_x * d1
    phi[:, VEL, ATT] = -f_x * d1
    phi[:, VEL, ACC_BIAS] = -rotation * d1
    phi[:, ATT, ATT] -= w_x * d1
    phi[:, ATT, GYRO_BIAS] = -rotation * d1
    return phi


def sample_process_noise(noise: ImuNoise, dt: np.ndarray, white_scale: np.ndarray) -> np.ndarray:
    """Discrete process noise (n, 15, 15) of samples held over ``dt``.

    A white-noise sample held over dt has variance density^2 / dt (the simulator's model); it
    enters like a bias error, so velocity gets density^2 dt, position dt^3/4 of it, and their
    covariance dt^2/2. Bias random walks add rw^2 dt. GTSAM's integration sigma (position
    integration uncertainty of the graph) is kept for parity.
    """
    n = len(dt)
    # white_scale: (n,) one inflation for both sensors, or (n, 2) accel and gyro apart.
    scale = np.asarray(white_scale, dtype=float).reshape(n, -1)
    qa = (noise.accel_noise * scale[:, 0]) ** 2 * dt
    qg = (noise.gyro_noise * scale[:, -1]) ** 2 * dt
    q = np.zeros((n, STATE_DIM, STATE_DIM))
    eye = np.eye(3)
    q[:, POS, POS] = (0.25 * qa * dt**2 + noise.integration_sigma**2 * dt)[:, None, None] * eye
    q[:, POS, VEL] = q[:, VEL, POS] = (0.5 * qa * dt)[:, None, None] * eye
    q[:, VEL, VEL] = qa[:, None, None] * eye
    q[:, ATT, ATT] = qg[:, None, None] * eye
    q[:, ACC_BIAS, ACC_BIAS] = (noise.accel_bias_rw**2 * dt)[:, None, None] * eye
    q[:, GYRO_BIAS, GYRO_BIAS] = (noise.gyro_bias_rw**2 * dt)[:, None, None] * eye
    return q


def compose_transitions(phi: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(Phi, Q) of a whole block from per-sample ones, by an associative tree reduction:
    (Phi_a, Q_a) then (Phi_b, Q_b) -> (Phi_b Phi_a, Phi_b Q_a Phi_b^T + Q_b). Any state
    dimension (the 18-state gyro-free EKF composes its own)."""
    dim = phi.shape[-1]
    while phi.shape[0] > 1:
        if phi.shape[0] % 2:
            phi = np.concatenate([phi, np.eye(dim)[None]])
            q = np.concatenate([q, np.zeros((1, dim, dim))])
        early, late = phi[0::2], phi[1::2]
        q = late @ q[0::2] @ np.swapaxes(late, 1, 2) + q[1::2]
        phi = late @ early
    return phi[0], q[0]


def block_transition(
    nominal: BlockNominal,
    dt: np.ndarray,
    frame: NavFrame,
    noise: ImuNoise,
    white_scale: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Error-state transition and process noise (15, 15) over one (unbatched) block."""
    phi = sample_transitions(nominal.rotation[:-1], nominal.specific_force_nav, dt, frame)
    return compose_transitions(phi, sample_process_noise(noise, dt, white_scale))


def coarse_block_transition(
    nominal: BlockNominal,
    dt: np.ndarray,
    frame: NavFrame,
    noise: ImuNoise,
    white_scale: np.ndarray,
    steps: int,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`block_transition` from at most ``steps`` sub-steps instead of every sample.

    Consecutive samples are merged into sub-steps of their summed dt h, with the dt-weighted
    mean attitude and specific force (so the first-order terms, sum F dt, are those of the
    exact composition) and the white-noise variance they add (sum of scale^2 dt). A
    sub-step's transition is exp(A h) of its (so held) error dynamics A, to third order,
    which is exact for the chain position <- velocity <- attitude <- gyro bias (A^4 = 0 but
    for the Earth-rate terms); Phi and Q are then composed over the sub-steps. What is lost
    is how the attitude and specific force vary inside a sub-step, and how white noise
    inside it reaches position: fine for a filter that only makes an initial guess, and
    ~10x less work per block than composing 100-200 samples.
    """
    n = len(dt)
    if n <= steps:
        return block_transition(nominal, dt, frame, noise, white_scale)
    edges = np.linspace(0, n, steps + 1).round().astype(np.int64)[:-1]
    sub_dt = np.add.reduceat(dt, edges)
    weight = dt / np.repeat(sub_dt, np.diff(np.append(edges, n)))
    rotation = np.add.reduceat(nominal.rotation[:-1] * weight[:, None, None], edges, axis=0)
    f_nav = np.add.reduceat(nominal.specific_force_nav * weight[:, None], edges, axis=0)
    scale = np.asarray(white_scale, dtype=float).reshape(n, -1)
    sub_scale = np.sqrt(np.add.reduceat(scale**2 * dt[:, None], edges, axis=0) / sub_dt[:, None])
    return compose_transitions(
        _held_transitions(rotation, f_nav, sub_dt, frame),
        sample_process_noise(noise, sub_dt, sub_scale),
    )


def _held_transitions(
    rotation: np.ndarray, f_nav: np.ndarray, dt: np.ndarray, frame: NavFrame
) -> np.ndarray:
    """exp(A dt) (n, 15, 15) to third order, A the error dynamics with ``rotation`` and
    ``f_nav`` held over each dt (see :func:`coarse_block_transition`)."""
    n = len(dt)
    eye = np.eye(3)
    w_x = skew_batch(frame.earth_rate)
    d1 = dt[:, None, None]
    m = np.zeros((n, STATE_DIM, STATE_DIM))
    m[:, POS, VEL] = eye * d1
    m[:, VEL, VEL] = -2.0 * w_x * d1
    m[:, VEL, ATT] = -skew_batch(f_nav) * d1
    m[:, VEL, ACC_BIAS] = -rotation * d1
    m[:, ATT, ATT] = -w_x * d1
    m[:, ATT, GYRO_BIAS] = -rotation * d1
    m2 = m @ m
    return np.eye(STATE_DIM) + m + 0.5 * m2 + (m2 @ m) / 6.0


def augment_transition(
    phi: np.ndarray, q: np.ndarray, extra_variance: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Phi and Q (15, 15) of a block extended by random-walk states (constant in the
    propagation) that gain ``extra_variance`` (m,) of process noise over the block."""
    m = len(extra_variance)
    if m == 0:
        return phi, q
    n = STATE_DIM + m
    phi_out = np.eye(n)
    phi_out[:STATE_DIM, :STATE_DIM] = phi
    q_out = np.zeros((n, n))
    q_out[:STATE_DIM, :STATE_DIM] = q
    q_out[STATE_DIM:, STATE_DIM:] = np.diag(extra_variance)
    return phi_out, q_out
