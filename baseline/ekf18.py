"""18-state error-state EKF for a gyro-free IMU (accelerometer array + GNSS), numpy only.

Error states: position (3), velocity (3), attitude ``phi`` (3, ENU, ``R_true = Exp(phi) R``),
angular rate (3, body, ``w_true = w + dw``) and the biases of the N accelerometers (N): 18
for the study's cube of six, 12 + N for any array of N >= 6 the front end solves.
The filter propagates from the *raw array readings*, not from the front end's integrated rate:
with readings A (bias-corrected by the estimate), P the least-squares solver of the geometry
and G = P Q its centripetal coupling (:mod:`fgins.factors.accel_array`),

    alpha = P_alpha (A - b) - G_alpha m(w)      (zero coupling for the cube)
    w'    = alpha                               (the rate is a state, integrated here)
    f     = P_f (A - b) - G_f m(w)              (centripetal term from the current rate)

and the strapdown mechanization of :mod:`fgins.baseline.mechanization` runs on (w, f). The rate
is integrated over the segments between IMU samples and block boundaries with the trapezoid
rule on linearly interpolated alpha (the front end's scheme), and each segment uses its mean
rate, so the attitude integration is second order in the sample interval.

Error dynamics (per segment, first order): dphi' = R dw - w_ie x phi, dw' = -P_alpha db -
G_alpha M(w) dw, dv' = -[f_n]x phi + R (-P_f db - G_f M(w) dw) - 2 w_ie x dv, p' = v, with
M = dm/dw. White accelerometer noise (density sigma per sensor, held over each sample) drives
velocity and rate together (correlated through P); the biases are constants with a tiny
random walk. GNSS position (+ velocity where given) updates use the project's GNSS noise model
(:mod:`fgins.baseline.measurements`, :mod:`fgins.factors.gnss`) with closed-loop injection.
Blocks end at GNSS epochs and at most ``max_block_s`` apart, as in :mod:`fgins.baseline.ekf`.

Land-vehicle pseudo-measurements at every block boundary, switched and weighted by the same
``config.smoother`` settings as the graph's factors (:mod:`fgins.factors.vehicle`): at a stop
(quiet array and predicted speed below ``zupt_max_speed_m_per_s``) ZUPT plus a zero-angular-
rate update (rate = Earth rate), which observes the rate state and through it the alpha-bias
combinations of the biases; otherwise the non-holonomic constraint. Why: the array's rate
is a random walk (0.8 deg/s/sqrt(s) for the tactical 0.1 m cube) driven further by residual
biases; 1 Hz GNSS positions alone observe it too weakly and the filter lost the attitude.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from fgins.alignment import initial_alignment
from fgins.baseline.ekf import (
    RTS_NONLINEAR_DEG,
    RTS_UNAIDED_GAP_S,
    IntervalSums,
    largest_unaided_turn_deg,
)
from fgins.baseline.measurements import linearize_gnss, select_gnss
from fgins.baseline.mechanization import (
    NavFrame,
    NominalState,
    block_times,
    compose_transitions,
    propagate_nominal,
    segment_imu,
    skew_batch,
)
from fgins.config import RunConfig, SmootherConfig
from fgins.datatypes import AccelArrayData, Dataset, InputError, Trajectory
from fgins.factors import stationary
from fgins.factors.accel_array import AccelArray, rate_monomials
from fgins.geodesy import so3_exp, so3_log
from fgins.initial_guess import KeyframeGuess
from fgins.mounting import mounting_rotation

NAV_RATE_DIM = 12  # position, velocity, attitude, rate; the N biases follow
POS = slice(0, 3)
VEL = slice(3, 6)
ATT = slice(6, 9)
RATE = slice(9, 12)
BIAS = slice(NAV_RATE_DIM, None)  # one per accelerometer


def state_dim(n_sensors: int) -> int:
    """Error states of the filter for an array of ``n_sensors`` accelerometers."""
    return NAV_RATE_DIM + n_sensors


# Random walk of the accelerometer biases (m/s^2/sqrt(s)): constants in the model, but a
# tiny walk keeps the covariance from collapsing over long drives.
BIAS_RANDOM_WALK = 1e-6
INITIAL_RATE_SIGMA = 1e-3  # rad/s: the front end's w0 (zero) misses the Earth rate and more


def _rate_jacobian(rate: np.ndarray) -> np.ndarray:
    """M(w) = dm/dw (n, 6, 3) of the monomials m = (wx^2, wy^2, wz^2, wxwy, wxwz, wywz)."""
    x, y, z = rate[:, 0], rate[:, 1], rate[:, 2]
    zero = np.zeros_like(x)
    rows = [
        (2 * x, zero, zero),
        (zero, 2 * y, zero),
        (zero, zero, 2 * z),
        (y, x, zero),
        (z, zero, x),
        (zero, z, y),
    ]
    return np.stack([np.stack(r, axis=-1) for r in rows], axis=1)


class _ArrayModel:
    """Solver pieces of the array geometry, weighted by the (equal) sensor noise."""

    def __init__(self, data: AccelArrayData) -> None:
        array = AccelArray(positions=data.positions, axes=data.axes)
        solver = array.solver()
        self.solver_f, self.solver_alpha = solver[:3], solver[3:]
        coupling = solver @ array.centripetal_matrix()
        self.coupling_f, self.coupling_alpha = coupling[:3], coupling[3:]
        self.n_sensors = len(array)
        self.dim = state_dim(self.n_sensors)
        self.noise_density = data.noise_density

    def alpha(self, readings: np.ndarray, rate: np.ndarray) -> np.ndarray:
        return readings @ self.solver_alpha.T - rate_monomials(rate) @ self.coupling_alpha.T

    def specific_force(self, readings: np.ndarray, rate: np.ndarray) -> np.ndarray:
        return readings @ self.solver_f.T - rate_monomials(rate) @ self.coupling_f.T


def _integrate_rate(
    model: _ArrayModel, corrected: np.ndarray, node_t: np.ndarray, w0: np.ndarray
) -> np.ndarray:
    """Rates at the block's nodes: trapezoid rule on alpha interpolated at the node times.

    ``corrected`` are the bias-corrected readings interpolated to the nodes (n+1, N). For a
    rate-free geometry alpha is known at every node at once; otherwise Heun steps per node.
    """
    dt = np.diff(node_t)
    if np.max(np.abs(model.coupling_alpha)) < 1e-9:
        alpha = corrected @ model.solver_alpha.T
        steps = 0.5 * (alpha[1:] + alpha[:-1]) * dt[:, None]
        return w0 + np.vstack([np.zeros((1, 3)), np.cumsum(steps, axis=0)])
    rate = np.empty((len(node_t), 3))
    rate[0] = w0
    for k, h in enumerate(dt):
        a0 = model.alpha(corrected[k], rate[k])
        predicted = rate[k] + h * a0
        rate[k + 1] = rate[k] + 0.5 * h * (a0 + model.alpha(corrected[k + 1], predicted))
    return rate


def _segment_transitions(
    model: _ArrayModel,
    rotation: np.ndarray,
    f_nav: np.ndarray,
    rate: np.ndarray,
    dt: np.ndarray,
    frame: NavFrame,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-segment error-state transitions and process noise, each (n, 12 + N, 12 + N)."""
    n = len(dt)
    eye = np.eye(3)
    d1 = dt[:, None, None]
    d2 = d1**2
    w_x = skew_batch(frame.earth_rate)
    f_x = skew_batch(f_nav)
    m_jac = _rate_jacobian(rate)
    df_dw = -np.einsum("ij,njk->nik", model.coupling_f, m_jac)  # (n, 3, 3)
    dalpha_dw = -np.einsum("ij,njk->nik", model.coupling_alpha, m_jac)
    r_pf = -rotation @ model.solver_f  # (n, 3, N): d(R f)/db
    pa = -model.solver_alpha  # (3, N): d alpha/db
    r_df_dw = rotation @ df_dw

    phi = np.tile(np.eye(model.dim), (n, 1, 1))
    phi[:, POS, VEL] = eye * d1 - w_x * d2
    phi[:, POS, ATT] = -0.5 * f_x * d2
    phi[:, POS, RATE] = 0.5 * r_df_dw * d2
    phi[:, POS, BIAS] = 0.5 * r_pf * d2
    phi[:, VEL, VEL] -= 2.0 * w_x * d1
    phi[:, VEL, ATT] = -f_x * d1
    phi[:, VEL, RATE] = r_df_dw * d1
    phi[:, VEL, BIAS] = r_pf * d1
    phi[:, ATT, ATT] -= w_x * d1
    phi[:, ATT, RATE] = rotation * d1 + 0.5 * rotation @ dalpha_dw * d2
    phi[:, ATT, BIAS] = 0.5 * rotation @ pa * d2
    phi[:, RATE, RATE] += dalpha_dw * d1
    phi[:, RATE, BIAS] = pa * d1

    # Sensor white noise n (N,) held over dt (variance sigma^2 / dt) enters like a bias.
    noise_in = np.zeros((n, model.dim, model.n_sensors))
    noise_in[:, POS] = 0.5 * r_pf * d2
    noise_in[:, VEL] = r_pf * d1
    noise_in[:, ATT] = 0.5 * rotation @ pa * d2
    noise_in[:, RATE] = pa * d1
    variance = model.noise_density**2 / dt
    q = np.einsum("nik,n,njk->nij", noise_in, variance, noise_in)
    q[:, BIAS, BIAS] += (BIAS_RANDOM_WALK**2 * dt)[:, None, None] * np.eye(model.n_sensors)
    return phi, q


def _interpolate_readings(data: AccelArrayData, times: np.ndarray) -> np.ndarray:
    """Readings linearly interpolated to ``times`` (n, N)."""
    return np.column_stack(
        [np.interp(times, data.t, data.readings[:, j]) for j in range(data.n_sensors)]
    )


# Zero-angular-rate update at a stop (rad/s): what an idling engine's rocking leaves. The
# graph's counterpart is the no-motion factor between stationary keyframes.
ZARU_SIGMA_RAD_PER_S = 5e-4
# Rest detection window (s) around a block boundary and the floor of its specific-force
# spread (m/s^2): below a moving road vehicle's vibration, above the sensors' own noise
# (the thresholds of graph.problem's quiet-IMU test).
QUIET_HALF_WINDOW_S = 0.5
QUIET_FORCE_FLOOR = 0.05


def rotation_from_rpy(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll) (GTSAM's Rot3.Ypr), the IMU-to-vehicle mounting."""
    cr, sr, cp, sp, cy, sy = (f(a) for a in (roll, pitch, yaw) for f in (np.cos, np.sin))
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def quiet_array(model: _ArrayModel, data: AccelArrayData, times: np.ndarray) -> np.ndarray:
    """True at block boundaries where the array's specific force shows no motion within
    +-QUIET_HALF_WINDOW_S: per-axis spread below max(4 sigma of one sample, 0.05 m/s^2).

    A steady cruise also has a flat specific force, so callers must also require a low
    predicted speed (as the graph does)."""
    force = data.readings @ model.solver_f.T  # centripetal part is negligible at rest
    rate_hz = (len(data.t) - 1) / (data.t[-1] - data.t[0])
    sigma_f = model.noise_density * float(np.sqrt(np.max(np.sum(model.solver_f**2, axis=1))))
    threshold = max(4.0 * sigma_f * np.sqrt(rate_hz), QUIET_FORCE_FLOOR)
    lo = np.searchsorted(data.t, times - QUIET_HALF_WINDOW_S)
    hi = np.searchsorted(data.t, times + QUIET_HALF_WINDOW_S)
    # Windowed standard deviation from cumulative sums (vectorised over boundaries).
    first = np.vstack([np.zeros((1, 3)), np.cumsum(force, axis=0)])
    second = np.vstack([np.zeros((1, 3)), np.cumsum(force**2, axis=0)])
    count = np.maximum(hi - lo, 1)[:, None]
    mean = (first[hi] - first[lo]) / count
    variance = np.maximum((second[hi] - second[lo]) / count - mean**2, 0.0)
    return (hi - lo >= 5) & np.all(np.sqrt(variance) < threshold, axis=1)


def standstill_measurement(
    nav: NominalState, rate: np.ndarray, frame: NavFrame, smoother: SmootherConfig, dim: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ZUPT + ZARU at a stop: velocity zero and inertial body rate = the Earth rate
    (``dim``: the filter's error states).

    The rate is the ekf18 state that the angular-acceleration biases drive, so a stop observes
    the alpha-bias combinations of the accelerometer biases directly."""
    h = np.zeros((6, dim))
    h[0:3, VEL] = np.eye(3)
    h[3:6, RATE] = np.eye(3)
    residual = np.concatenate([-nav.velocity, nav.rotation.T @ frame.earth_rate - rate])
    variance = np.array([smoother.zupt_sigma_m_per_s**2] * 3 + [ZARU_SIGMA_RAD_PER_S**2] * 3)
    return h, residual, variance


def nhc_measurement(
    nav: NominalState, mounting: np.ndarray, smoother: SmootherConfig, dim: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Non-holonomic constraint: vehicle-frame lateral and vertical velocity are zero
    (``dim``: the filter's error states).

    Same model as :func:`fgins.factors.vehicle.nhc_factor`, in this filter's left (ENU)
    attitude error R_true = Exp(phi) R: v_b = R^T v + R^T dv + R^T [v]x phi."""
    select = mounting[1:3]  # R_vi rows: the vehicle's y and z axes in IMU axes
    rotation_t = nav.rotation.T
    h = np.zeros((2, dim))
    h[:, VEL] = select @ rotation_t
    h[:, ATT] = select @ rotation_t @ skew_batch(nav.velocity)
    residual = -(select @ rotation_t @ nav.velocity)
    variance = np.array(
        [smoother.nhc_sigma_lateral_m_per_s**2, smoother.nhc_sigma_vertical_m_per_s**2]
    )
    return h, residual, variance


class _NodeStore:
    """Where the forward pass puts its nominal states: every node (the IMU-rate output) or,
    with ``keep``, only those node indices (the keyframe guess; O(len(keep)) memory)."""

    def __init__(
        self,
        n_nodes: int,
        n_boundaries: int,
        keep: np.ndarray | None,
        dim: int,
        rate_error: tuple[np.ndarray, np.ndarray, IntervalSums] | None = None,
    ) -> None:
        # (node of every sample, front-end rate per sample, sums at the interval bounds):
        # the interval means of the front end's rate error, accumulated block by block.
        self.rate_error = rate_error
        self.keep = None if keep is None else np.unique(np.asarray(keep, dtype=np.int64))
        m = n_nodes if self.keep is None else len(self.keep)
        self.n_nodes = n_nodes
        self.rotation = np.empty((m, 3, 3))
        self.velocity = np.empty((m, 3))
        self.position = np.empty((m, 3))
        self.rate = np.empty((m, 3))
        full = n_boundaries if self.keep is None else 0
        self.dim = dim
        shape = (full, dim, dim)
        self.cov_prior = np.empty(shape)
        self.cov_post = np.empty(shape)
        # For the RTS smoother (full output only): each block's transition and the states at
        # every boundary before and after its updates (rotation, velocity, position, rate,
        # the N biases), O(boundaries) memory.
        self.transition = np.empty((max(full - 1, 0), dim, dim))
        self.boundary_prior = _BoundaryStates(full, dim)
        self.boundary_post = _BoundaryStates(full, dim)

    def _add_rate_error(self, first: int, stop: int, rates: np.ndarray) -> None:
        if self.rate_error is None:
            return
        sample_node, front_end, sums = self.rate_error
        a, b = np.searchsorted(sample_node, [first, stop])
        sums.add(np.nan_to_num(front_end[a:b] - rates[sample_node[a:b] - first]))

    def block(self, span: slice, nominal, rates: np.ndarray) -> None:
        """The nodes of a block (all but its end node)."""
        self._add_rate_error(span.start, span.stop, rates)
        if self.keep is None:
            rows, local = slice(span.start, span.stop), slice(0, -1)
        else:
            lo, hi = np.searchsorted(self.keep, [span.start, span.stop])
            rows = slice(int(lo), int(hi))
            local = self.keep[rows] - span.start
        self.rotation[rows] = nominal.rotation[local]
        self.velocity[rows] = nominal.velocity[local]
        self.position[rows] = nominal.position[local]
        self.rate[rows] = rates[local]

    def final(self, nav: NominalState, rate: np.ndarray) -> None:
        self._add_rate_error(self.n_nodes - 1, self.n_nodes, np.atleast_2d(rate))
        if self.keep is None or (len(self.keep) and self.keep[-1] == self.n_nodes - 1):
            self.rotation[-1], self.velocity[-1], self.position[-1] = (
                nav.rotation,
                nav.velocity,
                nav.position,
            )
            self.rate[-1] = rate

    def covariance(self, k: int, prior: np.ndarray, posterior: np.ndarray) -> None:
        if self.keep is None:
            self.cov_prior[k] = prior
            self.cov_post[k] = posterior

    def boundary(self, k: int, prior: _State, posterior: _State) -> None:
        if self.keep is None:
            self.boundary_prior.put(k, prior)
            self.boundary_post.put(k, posterior)

    def block_transition(self, b: int, phi: np.ndarray) -> None:
        if self.keep is None:
            self.transition[b] = phi


# (navigation state, angular rate, the N accelerometer biases) at a block boundary
_State = tuple[NominalState, np.ndarray, np.ndarray]


class _BoundaryStates:
    """The filter's states at every block boundary, as arrays."""

    def __init__(self, n: int, dim: int) -> None:
        self.dim = dim
        self.rotation = np.empty((n, 3, 3))
        self.velocity = np.empty((n, 3))
        self.position = np.empty((n, 3))
        self.rate = np.empty((n, 3))
        self.bias = np.empty((n, dim - NAV_RATE_DIM))

    def put(self, k: int, state: _State) -> None:
        nav, rate, bias = state
        self.rotation[k], self.velocity[k], self.position[k] = nav.rotation, nav.velocity, nav.position
        self.rate[k], self.bias[k] = rate, bias

    def from_other(self, other: _BoundaryStates, k: int, dx: np.ndarray) -> np.ndarray:
        """The error state taking boundary k's state here to ``other``'s corrected by ``dx``
        (the attitude error ``R_true = Exp(phi) R``; the rest additive)."""
        out = np.empty(self.dim)
        rotation = so3_exp(dx[ATT]) @ other.rotation[k]
        out[ATT] = so3_log(rotation @ self.rotation[k].T)
        out[VEL] = other.velocity[k] + dx[VEL] - self.velocity[k]
        out[POS] = other.position[k] + dx[POS] - self.position[k]
        out[RATE] = other.rate[k] + dx[RATE] - self.rate[k]
        out[BIAS] = other.bias[k] + dx[BIAS] - self.bias[k]
        return out


def run_ekf18(
    dataset: Dataset,
    config: RunConfig,
    *,
    gnss_mask: np.ndarray | None = None,
    progress: bool = True,
    max_block_s: float = 1.0,
    smooth: bool = False,
) -> Trajectory:
    """The 18-state gyro-free EKF (method ``"ekf18"``), output at every array sample; with
    ``smooth``, followed by a Rauch-Tung-Striebel smoother (:func:`run_ekf18_rts`).

    Needs ``dataset.accel_array`` (raw readings + geometry); ``dataset.imu`` (the front-end
    output) is used only for the initial alignment. ``info`` holds the update counts and the
    final accelerometer bias estimates (``accel_array_bias``, m/s^2).
    """
    started = time.perf_counter()
    pass_ = _ekf18_pass(dataset, config, gnss_mask, progress, max_block_s, None)
    data, store, times, counts, node_t = pass_.data, pass_.store, pass_.times, pass_.counts, pass_.node_t
    epochs, bias = pass_.epochs, pass_.bias
    n_nodes = len(node_t)
    rotation, velocity, position, rate_out = store.rotation, store.velocity, store.position, store.rate
    cov_start, cov_end = store.cov_post, store.cov_prior
    n_blocks = len(times) - 1

    # Output at the array samples: the node at each sample time; covariances interpolated
    # between a block's a-posteriori start and a-priori end (smoothed: between its two
    # boundaries' smoothed covariances).
    rows = np.clip(np.searchsorted(node_t, data.t), 0, n_nodes - 1)
    block = np.clip(np.searchsorted(times, data.t, side="right") - 1, 0, len(times) - 2)
    share = np.clip((data.t - times[block]) / (times[block + 1] - times[block]), 0.0, 1.0)
    s = share[:, None, None]
    last = data.t >= times[-1]
    rotation, velocity, position, rate_out = rotation[rows], velocity[rows], position[rows], rate_out[rows]
    info: dict[str, object] = {}
    if smooth:
        from_post, from_prior, cov_smoothed = _rts_smooth(store)
        # Each sample's correction: from its block's start (a-posteriori) to its end
        # (a-priori), linearly in time, as the 15-state EKF+RTS (zero after the last boundary).
        correction = (1.0 - share[:, None]) * from_post[block] + share[:, None] * from_prior[block + 1]
        correction[last] = 0.0
        rotation = so3_exp(correction[:, ATT]) @ rotation
        velocity = velocity + correction[:, VEL]
        position = position + correction[:, POS]
        rate_out = rate_out + correction[:, RATE]
        cov_start = cov_end = cov_smoothed
        turned = largest_unaided_turn_deg(from_post[:, ATT], times, epochs.t)
        counts["rts_largest_turn_deg"] = turned
        info["solver"] = "EKF18+RTS: one forward pass, smoothed about it (not relinearised)"
        if turned > RTS_NONLINEAR_DEG:
            info["fit_warnings"] = [
                f"EKF18+RTS: the smoother turns the filter's attitude by up to {turned:.0f} deg "
                f"more than {RTS_UNAIDED_GAP_S:g} s from any fix, far beyond what its linear "
                "correction carries: its track and sigmas are not to be trusted there "
                "(compare --method batch, which relinearises until it converges)"
            ]
    nav_cov = []
    for rows_cov in (POS, VEL, ATT):  # only the 3x3 blocks the output keeps (same bits)
        start = np.ascontiguousarray(cov_start[:, rows_cov, rows_cov])
        end = np.ascontiguousarray(cov_end[:, rows_cov, rows_cov])
        out_cov = (1.0 - s) * start[block] + s * end[block + 1]
        out_cov[last] = cov_start[-1][rows_cov, rows_cov]
        nav_cov.append(out_cov)
    counts["blocks"] = n_blocks
    method = "ekf18-rts" if smooth else "ekf18"
    trajectory = Trajectory(
        t=data.t,
        position=position,
        velocity=velocity,
        rotation=rotation,
        origin=dataset.origin,
        method=method,
        # The rate error of the front end, as a gyro "bias": front-end rate minus filter rate.
        gyro_bias=(dataset.imu.gyro - rate_out) if len(dataset.imu) == len(data) else None,
        position_cov=nav_cov[0],
        velocity_cov=nav_cov[1],
        attitude_cov=nav_cov[2],
        info={
            "gnss_gating": epochs.gating_summary,
            **counts,
            "gnss_epochs_used": len(epochs.t),
            "accel_array_bias": np.asarray(bias).tolist(),
            "angular_rate": rate_out,
            **info,
        },
    )
    trajectory.timings["total"] = time.perf_counter() - started
    return trajectory


def run_ekf18_rts(
    dataset: Dataset,
    config: RunConfig,
    *,
    gnss_mask: np.ndarray | None = None,
    progress: bool = True,
    max_block_s: float = 1.0,
) -> Trajectory:
    """The 18-state gyro-free EKF followed by a Rauch-Tung-Striebel smoother (method
    ``"ekf18-rts"``; ``ekf-rts`` on an accelerometer array): one forward pass, smoothed
    linearly about it. The 15-state EKF+RTS's relinearised passes are not repeated here; a
    correction too large for a linear smoother, far from the fixes, is said."""
    return run_ekf18(
        dataset, config, gnss_mask=gnss_mask, progress=progress, max_block_s=max_block_s,
        smooth=True,
    )  # fmt: skip


def _rts_smooth(store: _NodeStore) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Backward RTS pass over the block boundaries of a full forward pass: per boundary the
    smoothed correction from the a-posteriori state, from the a-priori state, and the
    smoothed covariance (as :func:`fgins.baseline.ekf.rts_smooth` for 15 states)."""
    post, prior = store.boundary_post, store.boundary_prior
    n = len(store.cov_post)
    from_post = np.zeros((n, store.dim))
    from_prior = np.zeros((n, store.dim))
    cov_smoothed = np.empty_like(store.cov_post)
    cov_smoothed[-1] = store.cov_post[-1]
    from_prior[-1] = prior.from_other(post, n - 1, from_post[-1])
    for k in range(n - 2, -1, -1):
        # C = P+_k Phi^T (P-_k+1)^-1, computed as a solve with the symmetric P-_k+1.
        gain = np.linalg.solve(store.cov_prior[k + 1], store.transition[k] @ store.cov_post[k]).T
        from_post[k] = gain @ from_prior[k + 1]
        from_prior[k] = prior.from_other(post, k, from_post[k])
        cov = store.cov_post[k] + gain @ (cov_smoothed[k + 1] - store.cov_prior[k + 1]) @ gain.T
        cov_smoothed[k] = 0.5 * (cov + cov.T)
    return from_post, from_prior, cov_smoothed


@dataclass
class _Pass:
    data: AccelArrayData
    store: _NodeStore
    times: np.ndarray
    node_t: np.ndarray
    counts: dict[str, int]
    epochs: object
    bias: np.ndarray


def _ekf18_pass(
    dataset: Dataset,
    config: RunConfig,
    gnss_mask: np.ndarray | None,
    progress: bool,
    max_block_s: float,
    keep_samples: Callable[[np.ndarray, np.ndarray], np.ndarray] | None,
    rate_error_at: np.ndarray | None = None,
) -> _Pass:
    """The forward pass of :func:`run_ekf18`. ``keep_samples(node_t, array_t)``, when given,
    names the node indices to keep (else every node and the boundary covariances);
    ``rate_error_at`` (sample indices) asks for cumulative sums of the front end's rate
    error (front-end gyro minus filter rate) there."""
    data = dataset.accel_array
    if data is None:
        raise InputError(
            f"{dataset.name or 'input'}: method ekf18 needs accelerometer-array readings "
            "(accel_array.csv); use ekf for an ordinary IMU"
        )
    if not max_block_s > 0:
        raise InputError(f"ekf18: max_block_s must be > 0, got {max_block_s}")
    model = _ArrayModel(data)
    frame = NavFrame.at(dataset.origin)
    epochs = select_gnss(dataset, config, gnss_mask)
    align = initial_alignment(
        dataset, epochs.usable, smoother=config.smoother,
        gyro_bias_sigma=config.imu_noise().gyro_bias_prior,
    )  # fmt: skip
    lever_arm = np.asarray(config.gnss.lever_arm_m, dtype=float)
    times = block_times(float(data.t[0]), float(data.t[-1]), epochs.t, max_block_s)
    segments = segment_imu(data.t, times)
    node_t = segments.nodes
    # Which block boundary carries which GNSS epoch (-1: none); epochs are boundaries.
    gnss_at = np.full(len(times), -1)
    at = np.clip(np.searchsorted(times, epochs.t), 0, len(times) - 1)
    on_boundary = np.isclose(times[at], epochs.t, rtol=0.0, atol=1e-9)
    gnss_at[at[on_boundary]] = np.flatnonzero(on_boundary)
    node_readings = _interpolate_readings(data, node_t)

    keep = None if keep_samples is None else keep_samples(node_t, data.t)
    rate_error = None
    if rate_error_at is not None:
        sample_node = np.clip(np.searchsorted(node_t, data.t), 0, len(node_t) - 1)
        rate_error = (sample_node, dataset.imu.gyro, IntervalSums(rate_error_at, 3))
    store = _NodeStore(len(node_t), len(times), keep, model.dim, rate_error)

    # Nominal state: navigation + rate + the N biases.
    nav = NominalState(
        rotation=np.asarray(align.rotation, dtype=float),
        velocity=np.asarray(align.velocity, dtype=float),
        position=np.asarray(align.position, dtype=float),
        accel_bias=np.zeros(3),
        gyro_bias=np.zeros(3),
    )
    rate = data.initial_rate.copy()
    bias = np.zeros(data.n_sensors)
    bias_sigma = data.bias_sigma if data.bias_sigma is not None else 1e-3 * 9.80665
    dim = model.dim
    cov = np.zeros((dim, dim))
    cov[POS, POS] = np.eye(3) * align.position_sigma**2
    cov[VEL, VEL] = np.eye(3) * align.velocity_sigma**2
    att_sigma = np.asarray(align.attitude_sigma_rad)
    cov[ATT, ATT] = np.diag(att_sigma**2)  # tilt about east, north; heading about up
    cov[RATE, RATE] = np.eye(3) * INITIAL_RATE_SIGMA**2
    cov[BIAS, BIAS] = np.eye(data.n_sensors) * max(bias_sigma, 1e-9) ** 2
    counts = {"gnss_updates": 0, "velocity_updates": 0, "nhc_updates": 0, "zupt_updates": 0}
    smoother = config.smoother
    mounting = mounting_rotation(smoother.imu_to_vehicle_rpy_deg)
    zupt_max_speed = smoother.zupt_max_speed_m_per_s
    quiet = quiet_array(model, data, times) if smoother.zupt else np.zeros(len(times), bool)

    def correct(h: np.ndarray, residual: np.ndarray, variance: np.ndarray) -> None:
        """Closed-loop linear update of the error states (Joseph form, attitude reset)."""
        nonlocal nav, rate, bias, cov
        s = h @ cov @ h.T + np.diag(variance)
        gain = np.linalg.solve(s, h @ cov).T
        dx = gain @ residual
        i_kh = np.eye(dim) - gain @ h
        cov = i_kh @ cov @ i_kh.T + (gain * variance) @ gain.T  # Joseph form
        reset = np.eye(dim)
        reset[ATT, ATT] -= 0.5 * skew_batch(dx[ATT])
        cov = reset @ cov @ reset.T
        cov = 0.5 * (cov + cov.T)
        dx15 = np.zeros(15)
        dx15[:9] = dx[:9]
        nav = nav.boxplus(dx15)
        rate = rate + dx[RATE]
        bias = bias + dx[BIAS]

    def gnss_update(k: int) -> None:
        body_rate = rate - nav.rotation.T @ frame.earth_rate
        lin = linearize_gnss(epochs, int(gnss_at[k]), nav, body_rate, lever_arm)
        h = np.zeros((len(lin.residual), dim))
        h[:, :9] = lin.jacobian[:, :9]
        h[:, RATE] = -lin.jacobian[:, 12:15]  # w_true = w + dw, the gyro bias enters as -dw
        correct(h, lin.residual, lin.variance)
        counts["gnss_updates"] += 1
        counts["velocity_updates"] += int(lin.n_velocity > 0)

    def vehicle_updates(k: int) -> None:
        if (
            smoother.zupt
            and quiet[k]
            and stationary.speed_confirms_stop(
                float(np.linalg.norm(nav.velocity)),
                stationary.filter_stop_sigma(cov[VEL, VEL], float(times[k]) - last_fix),
                zupt_max_speed,
            )
        ):
            h, residual, variance = standstill_measurement(nav, rate, frame, smoother, dim)
            correct(h, residual, variance)
            counts["zupt_updates"] += 1
        elif smoother.nhc:
            h, residual, variance = nhc_measurement(nav, mounting, smoother, dim)
            correct(h, residual, variance)
            counts["nhc_updates"] += 1

    last_fix = -np.inf

    def boundary(k: int) -> None:
        nonlocal last_fix
        prior, prior_state = cov, (nav, rate, bias)
        if gnss_at[k] >= 0:
            gnss_update(k)
            last_fix = float(times[k])
        vehicle_updates(k)
        store.covariance(k, prior, cov)
        store.boundary(k, prior_state, (nav, rate, bias))

    boundary(0)
    n_blocks = len(times) - 1
    blocks: Iterable[int] = range(n_blocks)
    if progress:  # tqdm only when a bar is shown (import time)
        from tqdm import tqdm

        blocks = tqdm(blocks, desc="EKF18", unit="block", leave=False)
    for b in blocks:
        span = segments.block(b)
        nodes = slice(span.start, span.stop + 1)
        dt = segments.dt[span]
        corrected = node_readings[nodes] - bias
        rates = _integrate_rate(model, corrected, node_t[nodes], rate)
        mean_rate = 0.5 * (rates[1:] + rates[:-1])
        # Specific force over a segment: readings held from the segment start (the IMU hold
        # model), centripetal term at the segment's mean rate.
        held = data.readings[segments.sample[span]] - bias
        force = model.specific_force(held, mean_rate)
        nominal = propagate_nominal(nav, mean_rate, force, dt, frame)
        store.block(span, nominal, rates)
        phi, q = _segment_transitions(
            model, nominal.rotation[:-1], nominal.specific_force_nav, mean_rate, dt, frame
        )
        phi_block, q_block = compose_transitions(phi, q)
        store.block_transition(b, phi_block)
        cov = phi_block @ cov @ phi_block.T + q_block
        cov = 0.5 * (cov + cov.T)
        nav = nominal.end(nav)
        rate = rates[-1]
        boundary(b + 1)
    store.final(nav, rate)
    return _Pass(data, store, times, node_t, counts, epochs, bias)


def ekf18_states_at(
    dataset: Dataset,
    config: RunConfig,
    times: np.ndarray,
    *,
    gnss_mask: np.ndarray | None = None,
    progress: bool = False,
    max_block_s: float = 1.0,
    biases: str = "interval",
) -> KeyframeGuess:
    """The 18-state gyro-free EKF of :func:`run_ekf18`, reported only at ``times``.

    Built like :func:`fgins.baseline.ekf.ekf_states_at`: position and velocity interpolated
    (np.interp) between the filter's states at the array samples around each time, attitude
    and rate at the first sample at or after it; only those samples' states are kept (no
    output per sample, no covariance per block). ``gyro_bias`` is the front end's rate error
    (front-end rate minus the filter's, as ``run_ekf18`` reports it; zeros when the front
    end's samples are not the array's), averaged over each keyframe interval like
    sampling the filter's IMU-rate output (``biases="interval"``; the front end's rate error is
    noisy sample to sample) or at the first sample (``"nearest"``); ``accel_bias`` is zero
    (this filter estimates each sensor's bias, not a three-axis one).
    """
    from fgins.baseline.ekf import _guess_samples, interval_bounds

    if biases not in ("interval", "nearest"):
        raise InputError(f"ekf18_states_at: biases must be 'interval' or 'nearest', got {biases!r}")

    times = np.asarray(times, dtype=float)
    if times.ndim != 1 or len(times) == 0 or not np.all(np.isfinite(times)):
        raise InputError("ekf18_states_at: times must be a non-empty 1-D array of finite seconds")
    picked: dict[str, np.ndarray] = {}

    def keep(node_t: np.ndarray, array_t: np.ndarray) -> np.ndarray:
        samples, nearest = _guess_samples(array_t, times)
        rows = np.clip(np.searchsorted(node_t, array_t[samples]), 0, len(node_t) - 1)
        picked.update(samples=samples, nearest=nearest, rows=rows)
        return rows

    data = dataset.accel_array
    same_samples = data is not None and len(dataset.imu) == len(data)
    interval = biases == "interval" and same_samples
    if interval:
        lo, hi = interval_bounds(data.t, times)
    bounds = np.concatenate([lo, hi]) if interval else None
    result = _ekf18_pass(dataset, config, gnss_mask, progress, max_block_s, keep, bounds)
    store, data = result.store, result.data
    samples, nearest, rows = picked["samples"], picked["nearest"], picked["rows"]
    at = np.searchsorted(store.keep, rows)
    xp = data.t[samples]
    position = np.column_stack([np.interp(times, xp, store.position[at, i]) for i in range(3)])
    velocity = np.column_stack([np.interp(times, xp, store.velocity[at, i]) for i in range(3)])
    pick = at[nearest]
    if interval:
        assert store.rate_error is not None
        sums = store.rate_error[2].at
        k = len(times)
        gyro_bias = (sums[k:] - sums[:k]) / (hi - lo)[:, None]
    elif same_samples:
        gyro_bias = dataset.imu.gyro[samples[nearest]] - store.rate[pick]
    else:
        gyro_bias = np.zeros((len(times), 3))
    return KeyframeGuess(
        t=times,
        rotation=store.rotation[pick],
        position=position,
        velocity=velocity,
        accel_bias=np.zeros((len(times), 3)),
        gyro_bias=np.nan_to_num(gyro_bias),
        method="ekf18",
    )
