"""Gyro-free IMU front end: an array of N >= 6 single-axis accelerometers -> an :class:`ImuData`.

Measurement model of accelerometer j at position r_j (m, body frame) with unit sensing axis
theta_j, for specific force f at the array centre, angular acceleration alpha and rate w:

    A_j = theta_j . (f + alpha x r_j + w x (w x r_j))
        = [theta_j^T, (r_j x theta_j)^T] (f, alpha) + c_j(w)

The first part is linear in x = (f, alpha) with the rows of H = [theta_j^T, (r_j x theta_j)^T]
(using theta . (alpha x r) = alpha . (r x theta)). The centripetal part c_j(w) =
theta_j^T (w w^T - |w|^2 I) r_j is a quadratic form in w, written here as c = Q m(w) with the
six monomials m(w) = (wx^2, wy^2, wz^2, wx wy, wx wz, wy wz) and an (N, 6) matrix Q fixed by
the geometry. Weighted least squares with P = (H^T W H)^-1 H^T W then gives

    x = P A - (P Q) m(w).

**The cube (six accelerometers on the faces, axes along face diagonals).** Every sensing axis
is tangential (theta_j . r_j = 0), and the centripetal terms project *only onto f*:
P Q has zero alpha rows, and the f rows are exactly

    f = (P A)_f + L (wy wz, wx wz, wx wy).

So alpha is a fixed linear map of the readings, independent of w (Chen, Lee & DeBra 1994), the
rate is a plain cumulative integral of alpha, and f needs the rate only for that one correction.
:func:`centripetal_coupling` returns P Q so this property can be checked for any geometry.

**Integration.** w is integrated from w0 with the trapezoid rule (second order in the sample
interval; a zero-order hold would be first order and bias the rate by alpha * dt / 2). When the
geometry decouples alpha from w (the cube, any array with P_alpha Q = 0) alpha is computed for
all samples at once and w is a cumulative trapezoid sum: fully vectorised, no choice of "which
w" to use for the centripetal term is needed. Otherwise alpha_k depends on w_k itself; taking the
centripetal term from the previous w would make the scheme first order, so the rate is instead
*predicted* from the previous w and alpha (Euler) and corrected with the trapezoid rule (Heun's
method, second order): a short sequential loop of 3-vector operations per sample. Such
geometries are also worse in principle: the rate obeys the nonlinear ODE w' = b - G m(w), whose
linearisation can have growing modes, so rate errors feed back and amplify (tests show ~40x the
cube's integration error on a random 9-sensor array); prefer rate-free designs like the cube.

**Errors.** Accelerometer white noise and bias enter alpha linearly, so the rate error is the
*integral* of the alpha error: a random walk in angular rate driven by the white alpha noise,
plus a linear drift from the residual biases. :func:`equivalent_imu_noise` maps this onto the
error model of an ordinary IMU (gyro bias random walk) so the rest of fgins consumes the array
output unchanged.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fgins.config import STANDARD_GRAVITY
from fgins.datatypes import ImuData, InputError

# |theta| must be 1 to this tolerance (axes are direction cosines from a datasheet or a fit).
_UNIT_AXIS_TOLERANCE = 1e-6
# Reciprocal condition number below which the (f, alpha) map counts as rank deficient.
_MIN_RECIPROCAL_CONDITION = 1e-9
# |P_alpha Q| below which alpha is treated as independent of the rate (dimensionless).
_DECOUPLED_TOLERANCE = 1e-9
# |w| (rad/s) beyond which the rate integration counts as diverged (no vehicle spins this fast).
_DIVERGED_RATE = 1e4

CUBE_UNIT_POSITIONS = np.array(
    [(0, 0, -1), (0, -1, 0), (-1, 0, 0), (1, 0, 0), (0, 1, 0), (0, 0, 1)], dtype=float
)
CUBE_AXES = np.array(
    [(1, 1, 0), (1, 0, 1), (0, 1, 1), (0, -1, 1), (-1, 0, 1), (-1, 1, 0)], dtype=float
) / math.sqrt(2.0)


def _readonly(array: np.ndarray) -> np.ndarray:
    array = np.array(array, dtype=float)
    array.flags.writeable = False
    return array


@dataclass(frozen=True)
class AccelArray:
    """N single-axis accelerometers: ``positions`` (N, 3) in m and unit sensing ``axes`` (N, 3),
    both in the body frame with the origin at the point whose specific force is wanted."""

    positions: np.ndarray
    axes: np.ndarray

    def __post_init__(self) -> None:
        positions = np.asarray(self.positions, dtype=float)
        axes = np.asarray(self.axes, dtype=float)
        for name, value in (("positions", positions), ("axes", axes)):
            if value.ndim != 2 or value.shape[1] != 3:
                raise InputError(
                    f"accelerometer array {name}: expected shape (N, 3), got {value.shape}"
                )
            if not np.all(np.isfinite(value)):
                raise InputError(f"accelerometer array {name}: NaN or infinite entries")
        if positions.shape[0] != axes.shape[0]:
            raise InputError(
                f"accelerometer array: {positions.shape[0]} positions but {axes.shape[0]} axes"
            )
        n = positions.shape[0]
        if n < 6:
            raise InputError(
                f"accelerometer array: {n} accelerometers cannot resolve specific force and "
                "angular acceleration (6 unknowns); use at least 6"
            )
        norms = np.linalg.norm(axes, axis=1)
        bad = np.flatnonzero(np.abs(norms - 1.0) > _UNIT_AXIS_TOLERANCE)
        if bad.size:
            raise InputError(
                f"accelerometer array: sensing axis {int(bad[0])} has length {norms[bad[0]]:.6g}, "
                "expected a unit vector; normalise the axes"
            )
        object.__setattr__(self, "positions", _readonly(positions))
        object.__setattr__(self, "axes", _readonly(axes))
        reciprocal_condition = _reciprocal_condition(self.design_matrix(), positions)
        if reciprocal_condition < _MIN_RECIPROCAL_CONDITION:
            raise InputError(
                f"accelerometer array: geometry is degenerate (reciprocal condition "
                f"{reciprocal_condition:.3g}); the {n} readings cannot separate specific force "
                "and angular acceleration; move or re-orient accelerometers"
            )

    @classmethod
    def cube(cls, half_edge_m: float, per_face: int = 1) -> AccelArray:
        """Six accelerometers at the face centres of a cube of half-edge L, face-diagonal axes;
        ``per_face = 2``: twelve, each face's second along its other diagonal (a redundant
        array: every reading is tangential, so alpha stays independent of the rate)."""
        if not (math.isfinite(half_edge_m) and half_edge_m > 0):
            raise InputError(f"cube accelerometer array: half-edge {half_edge_m} m must be > 0")
        if per_face not in (1, 2):
            raise InputError(f"cube accelerometer array: {per_face} accelerometers per face; 1 or 2")
        positions, axes = CUBE_UNIT_POSITIONS * half_edge_m, CUBE_AXES.copy()
        if per_face == 2:
            other = np.cross(CUBE_UNIT_POSITIONS, CUBE_AXES)  # in the face, across the first
            positions, axes = np.vstack([positions, positions]), np.vstack([axes, other])
        return cls(positions=positions, axes=axes)

    def __len__(self) -> int:
        return int(self.positions.shape[0])

    def design_matrix(self) -> np.ndarray:
        """H (N, 6): rows [theta_j^T, (r_j x theta_j)^T], mapping (f, alpha) to readings."""
        return np.hstack([self.axes, np.cross(self.positions, self.axes)])

    def centripetal_matrix(self) -> np.ndarray:
        """Q (N, 6): centripetal readings c = Q m(w), m = (wx^2, wy^2, wz^2, wxwy, wxwz, wywz)."""
        theta, r = self.axes, self.positions
        tangential = np.einsum("ij,ij->i", theta, r)
        squares = theta * r - tangential[:, None]  # theta_a r_a - theta . r
        products = np.column_stack(
            [theta[:, a] * r[:, b] + theta[:, b] * r[:, a] for a, b in ((0, 1), (0, 2), (1, 2))]
        )
        return np.hstack([squares, products])

    def solver(self, sigmas: np.ndarray | None = None) -> np.ndarray:
        """P (6, N) = (H^T W H)^-1 H^T W with W = diag(1 / sigma_j^2) (unweighted if None)."""
        h = self.design_matrix()
        weights = _weights(sigmas, len(self))
        hw = h.T * weights
        return np.linalg.solve(hw @ h, hw)

    def exact_readings(
        self, specific_force: np.ndarray, angular_acceleration: np.ndarray, angular_rate: np.ndarray
    ) -> np.ndarray:
        """Error-free readings (T, N) from (T, 3) truth (or single (3,) vectors -> (N,))."""
        f, alpha, w = (
            np.asarray(v, dtype=float) for v in (specific_force, angular_acceleration, angular_rate)
        )
        linear = np.concatenate([f, alpha], axis=-1) @ self.design_matrix().T
        return linear + rate_monomials(w) @ self.centripetal_matrix().T


def _weights(sigmas: np.ndarray | None, n: int) -> np.ndarray:
    if sigmas is None:
        return np.ones(n)
    sigmas = np.broadcast_to(np.asarray(sigmas, dtype=float), (n,))
    if not np.all(np.isfinite(sigmas)) or np.any(sigmas <= 0):
        raise InputError("accelerometer array: per-sensor sigmas must be finite and > 0")
    return 1.0 / sigmas**2


def _reciprocal_condition(h: np.ndarray, positions: np.ndarray) -> float:
    """Smallest / largest singular value of H with the alpha columns scaled to the array size,
    so that the test does not depend on the unit of length."""
    size = float(np.sqrt(np.mean(np.sum(positions**2, axis=1))))
    if size == 0.0:
        return 0.0  # all accelerometers at one point: alpha is unobservable
    scaled = h * np.array([1.0, 1.0, 1.0, 1 / size, 1 / size, 1 / size])
    singular = np.linalg.svd(scaled, compute_uv=False)
    return float(singular[-1] / singular[0])


def rate_monomials(angular_rate: np.ndarray) -> np.ndarray:
    """m(w) = (wx^2, wy^2, wz^2, wx wy, wx wz, wy wz), shape (..., 6)."""
    w = np.asarray(angular_rate, dtype=float)
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    return np.stack([x * x, y * y, z * z, x * y, x * z, y * z], axis=-1)


def centripetal_coupling(array: AccelArray, sigmas: np.ndarray | None = None) -> np.ndarray:
    """P Q (6, 6): how the centripetal monomials m(w) leak into the solved (f, alpha).

    For the cube its alpha rows vanish and its f rows are -L * [[0,0,0,0,0,1],[0,0,0,0,1,0],
    [0,0,0,1,0,0]], i.e. (P A)_f = f - L (wy wz, wx wz, wx wy).
    """
    return array.solver(sigmas) @ array.centripetal_matrix()


def alpha_is_rate_free(array: AccelArray, sigmas: np.ndarray | None = None) -> bool:
    """True when the solved angular acceleration does not depend on the rate (P_alpha Q = 0)."""
    return bool(np.max(np.abs(centripetal_coupling(array, sigmas)[3:])) < _DECOUPLED_TOLERANCE)


@dataclass
class ArraySolution:
    """Front-end output at the reading times: specific force at the array centre (m/s^2),
    angular acceleration (rad/s^2) and integrated angular rate (rad/s), each (T, 3)."""

    t: np.ndarray
    specific_force: np.ndarray
    angular_acceleration: np.ndarray
    angular_rate: np.ndarray
    integration: str = ""


def solve_with_rate(
    array: AccelArray,
    readings: np.ndarray,
    angular_rate: np.ndarray,
    sigmas: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(specific_force, angular_acceleration), each (T, 3), from readings (T, N) with the
    centripetal term evaluated at a known rate (T, 3). Exact for exact readings."""
    solver = array.solver(sigmas)
    x = (readings - rate_monomials(angular_rate) @ array.centripetal_matrix().T) @ solver.T
    return x[..., :3], x[..., 3:]


def _check_inputs(
    array: AccelArray, readings: np.ndarray, t: np.ndarray, w0: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    readings = np.asarray(readings, dtype=float)
    t = np.asarray(t, dtype=float)
    w0 = np.asarray(w0, dtype=float)
    if readings.ndim != 2 or readings.shape[1] != len(array):
        raise InputError(
            f"accelerometer array readings: expected shape (T, {len(array)}), got {readings.shape}"
        )
    if t.ndim != 1 or t.shape[0] != readings.shape[0]:
        raise InputError(
            f"accelerometer array: {t.shape} timestamps for {readings.shape[0]} reading rows"
        )
    if t.shape[0] == 0:
        raise InputError("accelerometer array: no readings")
    if w0.shape != (3,) or not np.all(np.isfinite(w0)):
        raise InputError(f"accelerometer array: initial rate w0 must be 3 finite values, got {w0}")
    if not np.all(np.isfinite(t)):
        raise InputError("accelerometer array: non-finite timestamps")
    steps = np.diff(t)
    if np.any(steps <= 0):
        row = int(np.argmax(steps <= 0)) + 1
        raise InputError(
            f"accelerometer array: timestamps not strictly increasing at row {row}; "
            "sort or de-duplicate the input"
        )
    finite = np.all(np.isfinite(readings), axis=1)
    if not np.all(finite):
        row = int(np.argmin(finite))
        raise InputError(
            f"accelerometer array: NaN or infinite reading at row {row} (t={t[row]:.6f}); "
            "repair or drop those rows first (the rate integral cannot skip a sample)"
        )
    return readings, t, w0


def solve_array(
    array: AccelArray,
    readings: np.ndarray,
    t: np.ndarray,
    w0: np.ndarray,
    *,
    sigmas: np.ndarray | None = None,
    alpha_bias: np.ndarray | None = None,
) -> ArraySolution:
    """Specific force, angular acceleration and rate from readings (T, N) at times t (T,).

    ``w0`` is the angular rate at t[0] (rad/s), e.g. zero for a start at rest. ``sigmas`` are
    optional per-accelerometer noise sigmas for the weighted least squares. ``alpha_bias``
    (rad/s^2, e.g. from :func:`calibrate_at_rest`) is subtracted from the solved angular
    acceleration before integration. The rate is the trapezoid integral of alpha (see the
    module docstring for the two integration paths).
    """
    readings, t, w0 = _check_inputs(array, readings, t, w0)
    solver = array.solver(sigmas)
    coupling = solver @ array.centripetal_matrix()  # P Q
    linear = readings @ solver.T  # P A: (f, alpha) before the centripetal correction
    if alpha_bias is not None:
        alpha_bias = np.asarray(alpha_bias, dtype=float)
        if alpha_bias.shape != (3,) or not np.all(np.isfinite(alpha_bias)):
            raise InputError("accelerometer array: alpha_bias must be 3 finite values (rad/s^2)")
        linear[:, 3:] -= alpha_bias
    dt = np.diff(t)
    if alpha_is_rate_free(array, sigmas):
        alpha = linear[:, 3:]
        increments = 0.5 * (alpha[1:] + alpha[:-1]) * dt[:, None]
        rate = w0 + np.vstack([np.zeros((1, 3)), np.cumsum(increments, axis=0)])
        integration = "cumulative trapezoid (alpha independent of rate)"
    else:
        alpha, rate = _heun_integrate(linear[:, 3:], coupling[3:], dt, w0)
        integration = "Heun (predicted-rate centripetal term, trapezoid corrector)"
    specific_force = linear[:, :3] - rate_monomials(rate) @ coupling[:3].T
    return ArraySolution(
        t=t,
        specific_force=specific_force,
        angular_acceleration=alpha,
        angular_rate=rate,
        integration=integration,
    )


def _heun_integrate(
    alpha_linear: np.ndarray, alpha_coupling: np.ndarray, dt: np.ndarray, w0: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """alpha_k = alpha_linear_k - G m(w_k) integrated with Heun's method from w0.

    Sequential because alpha_k depends on w_k. The loop runs on Python floats (no per-sample
    array allocation), about 10 us per sample. Raises InputError when the rate diverges (the
    quadratic ODE can blow up in finite time once errors have accumulated).
    """
    g = [tuple(float(v) for v in row) for row in alpha_coupling]
    (g0, g1, g2) = g

    def rate_derivative(k: int, x: float, y: float, z: float) -> tuple[float, float, float]:
        m = (x * x, y * y, z * z, x * y, x * z, y * z)
        b = linear_rows[k]
        return (
            b[0] - sum(c * v for c, v in zip(g0, m, strict=True)),
            b[1] - sum(c * v for c, v in zip(g1, m, strict=True)),
            b[2] - sum(c * v for c, v in zip(g2, m, strict=True)),
        )

    linear_rows = alpha_linear.tolist()
    steps = dt.tolist()
    n = len(linear_rows)
    rate = [(float(w0[0]), float(w0[1]), float(w0[2]))]
    alpha = [rate_derivative(0, *rate[0])]
    for k in range(1, n):
        h = steps[k - 1]
        (x, y, z), (ax, ay, az) = rate[-1], alpha[-1]
        px, py, pz = rate_derivative(k, x + h * ax, y + h * ay, z + h * az)
        new_rate = (x + 0.5 * h * (ax + px), y + 0.5 * h * (ay + py), z + 0.5 * h * (az + pz))
        if not max(abs(v) for v in new_rate) < _DIVERGED_RATE:
            raise InputError(
                f"accelerometer array: rate integration diverged at sample {k}; this geometry "
                "couples angular acceleration to the rate (P_alpha Q != 0), which amplifies "
                "errors; use a rate-free geometry (e.g. AccelArray.cube) or shorter records"
            )
        rate.append(new_rate)
        alpha.append(rate_derivative(k, *new_rate))
    return np.array(alpha), np.array(rate)


@dataclass(frozen=True)
class RestCalibration:
    """Angular-acceleration bias measured while the array stood still at the start.

    ``alpha_bias`` (rad/s^2) is the mean solved alpha over the rest span [t[0], t[0] +
    ``duration_s``) (the truth is zero there); ``alpha_bias_sigma`` its 1-sigma error from the
    white noise, sigma_alpha / sqrt(duration). ``samples`` is the number of readings used.
    """

    alpha_bias: np.ndarray
    duration_s: float
    samples: int
    alpha_bias_sigma: float


# Rest detection: the specific force of a vehicle at rest is constant (gravity). Windows whose
# mean deviates from the first window's by more than this many sigmas of the window mean (white
# noise only), or by the absolute floor (vibration, tiny creeping), count as motion.
_REST_SIGMAS = 5.0
_REST_FLOOR_M_PER_S2 = 0.02


def calibrate_at_rest(
    array: AccelArray,
    readings: np.ndarray,
    t: np.ndarray,
    noise_density: float,
    *,
    window_s: float = 0.5,
    min_rest_s: float = 2.0,
) -> RestCalibration | None:
    """The angular-acceleration bias from the initial standstill, or None if there is none.

    Why: residual accelerometer biases b give a constant alpha bias P_alpha b, so the integrated
    rate error grows *linearly* (for the 0.1 m cube, 100 ug of residual bias is 0.4 deg/s per
    second) and soon swamps the white-noise random walk. At rest the true alpha is zero (the
    Earth rate is constant), so the mean solved alpha over the rest span is the alpha bias (a
    zero-angular-rate-update calibration, as done at every land-vehicle start). The rest span
    is the longest prefix of whole windows whose mean specific force stays within
    max(5 sigma of a window mean, 0.02 m/s^2) of the first window's; the last window is dropped
    because motion may have begun inside it. Needs at least ``min_rest_s`` of rest.
    """
    readings, t, _ = _check_inputs(array, readings, t, np.zeros(3))
    if not (window_s > 0 and min_rest_s > 0):
        raise InputError("calibrate_at_rest: window_s and min_rest_s must be > 0")
    solver = array.solver()
    linear = readings @ solver.T
    sigma_f, sigma_alpha = solution_noise_densities(array, noise_density)
    window = np.floor((t - t[0]) / window_s).astype(int)
    n_windows = int(window[-1])  # the last (possibly partial) window is never used
    if n_windows < 2:
        return None
    counts = np.bincount(window, minlength=n_windows + 1)[:n_windows]
    sums = np.stack(
        [np.bincount(window, weights=linear[:, i], minlength=n_windows + 1) for i in range(3)],
        axis=1,
    )[:n_windows]
    means = sums / counts[:, None]
    tolerance = max(
        _REST_SIGMAS * float(np.max(sigma_f)) / math.sqrt(window_s), _REST_FLOOR_M_PER_S2
    )
    moving = np.linalg.norm(means - means[0], axis=1) > tolerance
    first_moving = int(np.argmax(moving)) if np.any(moving) else n_windows
    rest_windows = first_moving - 1  # drop the window just before motion was seen
    duration = rest_windows * window_s
    if duration < min_rest_s:
        return None
    rest = window < rest_windows
    alpha_bias = linear[rest, 3:].mean(axis=0)
    return RestCalibration(
        alpha_bias=alpha_bias,
        duration_s=float(duration),
        samples=int(np.count_nonzero(rest)),
        alpha_bias_sigma=float(np.max(sigma_alpha)) / math.sqrt(duration),
    )


def to_imu_data(solution: ArraySolution) -> ImuData:
    """The array output as an ordinary IMU (gyro = integrated rate, accel = specific force)."""
    return ImuData(
        t=solution.t.copy(),
        gyro=solution.angular_rate.copy(),
        accel=solution.specific_force.copy(),
        frame="accel-array",
    )


def solution_noise_densities(
    array: AccelArray, accel_noise_density: float | np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis white-noise densities of (f, alpha) from per-sensor densities (scalar or (N,)).

    The least squares is weighted by the same densities, so this is the best the geometry
    allows: cov = P diag(sigma^2) P^T. For the cube: sigma_f = sigma_a / sqrt(2) and
    sigma_alpha = sigma_a / (sqrt(2) L) on every axis.
    """
    sigmas = np.broadcast_to(np.asarray(accel_noise_density, dtype=float), (len(array),))
    if not np.all(np.isfinite(sigmas)) or np.any(sigmas <= 0):
        raise InputError("accelerometer noise density must be finite and > 0")
    solver = array.solver(sigmas)
    variance = np.einsum("ij,j,ij->i", solver, sigmas**2, solver)
    return np.sqrt(variance[:3]), np.sqrt(variance[3:])


def equivalent_imu_noise(
    array: AccelArray,
    accel_noise_density: float | np.ndarray,
    accel_bias: float | np.ndarray,
    *,
    drift_horizon_s: float = 60.0,
    initial_rate_sigma_rad_per_s: float = 1e-3,
    alpha_bias_sigma: float | None = None,
    keyframe_interval_s: float = 1.0,
    typical_rate_rad_per_s: float = 0.3,
) -> dict[str, float]:
    """fgins ``[imu]`` config (SI ``*_si`` keys of :data:`fgins.config.IMU_KEYS`) for the array.

    Inputs per accelerometer (scalar or (N,)): white-noise density (m/s^2/sqrt(Hz)) and the
    1-sigma residual bias after calibration (m/s^2), independent between sensors.

    The approximation, and why:
    - The rate is the integral of alpha, so alpha's white noise (density sigma_alpha) is a
      *random walk in rate*: exactly GTSAM's gyro-bias random walk with density sigma_alpha.
    - Residual accelerometer biases give a constant alpha bias b_alpha, i.e. a rate error
      growing linearly, b_alpha * t. A random walk cannot represent a ramp; we inflate the walk
      so that its spread over ``drift_horizon_s`` (the span the smoother must bridge, e.g. a GNSS
      outage) matches the ramp: q^2 = sigma_alpha^2 + b_alpha^2 * horizon.
    - The integrated rate has no white noise of its own, but GTSAM's preintegration holds the
      gyro bias *constant* between two keyframes, so the rate's random walk inside an interval
      T would be ignored: its attitude error has variance q^2 T^3 / 3, the same as a white
      gyro noise of density q T / sqrt(3) over T. That is the gyro noise given
      (``keyframe_interval_s`` = the graph's keyframe spacing, 1 s by default).
      When the alpha bias was calibrated at rest (:func:`calibrate_at_rest`), pass the
      calibration's ``alpha_bias_sigma``: only that residual ramps.
    - The initial rate error is the error of w0: it becomes the gyro turn-on bias prior.
    - Specific force noise/bias come straight from the least squares (largest axis). The
      constant f bias gets a slow random walk (one prior sigma per hour) so the smoother can
      still refine it.
    - The rate error dw also leaks into f through the centripetal correction: f error =
      -P_f Q (m(w + dw) - m(w)), of size |P_f Q| (2 |w| |dw| + |dw|^2) (for the cube
      |P_f Q| = L). It starts at zero and grows with dw, so it is an accelerometer bias *walk*:
      the walk is raised until its spread over the horizon covers the leak at that horizon's
      rate error, for a vehicle turning at ``typical_rate_rad_per_s``. Ignoring it (as a
      second-order effect) made the graph explain 0.01-0.1 m/s^2 of f error with tilt.
    """
    if not (math.isfinite(drift_horizon_s) and drift_horizon_s > 0):
        raise InputError(f"equivalent_imu_noise: drift_horizon_s {drift_horizon_s} must be > 0")
    if not (math.isfinite(keyframe_interval_s) and keyframe_interval_s > 0):
        raise InputError(
            f"equivalent_imu_noise: keyframe_interval_s {keyframe_interval_s} must be > 0"
        )
    if not (math.isfinite(initial_rate_sigma_rad_per_s) and initial_rate_sigma_rad_per_s > 0):
        raise InputError("equivalent_imu_noise: initial_rate_sigma_rad_per_s must be > 0")
    bias = np.broadcast_to(np.asarray(accel_bias, dtype=float), (len(array),))
    if not np.all(np.isfinite(bias)) or np.any(bias < 0):
        raise InputError("equivalent_imu_noise: accel_bias sigmas must be finite and >= 0")
    sigma_f, sigma_alpha = solution_noise_densities(array, accel_noise_density)
    # Bias sigmas through the same (noise-weighted) solver the front end uses.
    sigmas = np.broadcast_to(np.asarray(accel_noise_density, dtype=float), (len(array),))
    solver = array.solver(sigmas)
    bias_std = np.sqrt(np.einsum("ij,j,ij->i", solver, bias**2, solver))
    bias_f, bias_alpha = float(np.max(bias_std[:3])), float(np.max(bias_std[3:]))
    if alpha_bias_sigma is not None:
        if not (math.isfinite(alpha_bias_sigma) and alpha_bias_sigma >= 0):
            raise InputError("equivalent_imu_noise: alpha_bias_sigma must be finite and >= 0")
        bias_alpha = alpha_bias_sigma
    alpha_density = float(np.max(sigma_alpha))
    rate_walk = math.sqrt(alpha_density**2 + bias_alpha**2 * drift_horizon_s)
    # Centripetal leak of the rate error into f at the horizon (see above).
    rate_error = rate_walk * math.sqrt(drift_horizon_s)
    leak_gain = float(np.linalg.norm(centripetal_coupling(array, sigmas)[:3], ord=2))
    leak = leak_gain * (2.0 * abs(typical_rate_rad_per_s) * rate_error + rate_error**2)
    accel_walk = max(bias_f / math.sqrt(3600.0), leak / math.sqrt(drift_horizon_s), 1e-12)
    return {
        "gyro_noise_rad_per_s_per_sqrt_hz": max(
            rate_walk * keyframe_interval_s / math.sqrt(3.0), 1e-12
        ),
        "gyro_bias_rw_rad_per_s_per_sqrt_s": rate_walk,
        "gyro_turn_on_bias_deg_per_s": math.degrees(initial_rate_sigma_rad_per_s),
        "accel_noise_m_per_s2_per_sqrt_hz": float(np.max(sigma_f)),
        "accel_bias_rw_m_per_s2_per_sqrt_s": accel_walk,
        "accel_turn_on_bias_mg": max(bias_f, 1e-9) / (1e-3 * STANDARD_GRAVITY),
    }
