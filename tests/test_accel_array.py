"""Gyro-free IMU front end: exact inversion, rate integration order, noise propagation against
Monte-Carlo, equivalent IMU noise, degenerate geometries and the simulated readings."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fgins.config import imu_noise_from_config
from fgins.datatypes import ImuData, InputError
from fgins.factors.accel_array import (
    AccelArray,
    alpha_is_rate_free,
    centripetal_coupling,
    equivalent_imu_noise,
    solution_noise_densities,
    solve_array,
    solve_with_rate,
    to_imu_data,
)
from fgins.sim.accel_array import (
    CALIBRATION_RESIDUAL,
    GRADES,
    ArrayErrors,
    ArrayGrade,
    array_readings,
    draw_array_errors,
)

L = 0.05  # cube half-edge, m


def _independent_readings(
    positions: np.ndarray, axes: np.ndarray, f: np.ndarray, alpha: np.ndarray, w: np.ndarray
) -> np.ndarray:
    """A_j = theta_j . (f + alpha x r_j + w x (w x r_j)), straight from the physics (T, N)."""
    f, alpha, w = (np.atleast_2d(v) for v in (f, alpha, w))
    out = np.empty((f.shape[0], len(positions)))
    for j, (r, theta) in enumerate(zip(positions, axes, strict=True)):
        point = f + np.cross(alpha, r) + np.cross(w, np.cross(w, r))
        out[:, j] = point @ theta
    return out


def _random_array(rng: np.random.Generator, n: int = 9) -> AccelArray:
    axes = rng.standard_normal((n, 3))
    return AccelArray(
        positions=rng.uniform(-0.2, 0.2, (n, 3)),
        axes=axes / np.linalg.norm(axes, axis=1, keepdims=True),
    )


def _sinusoid_truth(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rate (rad/s), its exact derivative and a specific force, each (T, 3)."""
    amp = np.array([0.8, -0.5, 1.2])
    freq = np.array([0.7, 1.1, 0.4]) * 2 * np.pi
    phase = np.array([0.3, 1.0, -0.4])
    arg = t[:, None] * freq + phase
    w = amp * np.sin(arg)
    alpha = amp * freq * np.cos(arg)
    f = np.array([0.5, -0.2, 9.8]) + 0.3 * np.cos(arg * 1.3)
    return w, alpha, f


# --- geometry ------------------------------------------------------------------------------


def test_cube_preset_matches_the_brief() -> None:
    cube = AccelArray.cube(L)
    assert cube.positions[0] == pytest.approx([0, 0, -L])
    assert cube.axes[3] * math.sqrt(2) == pytest.approx([0, -1, 1])
    assert np.allclose(np.linalg.norm(cube.axes, axis=1), 1.0)
    # every sensing axis is tangential to its face position
    assert np.allclose(np.einsum("ij,ij->i", cube.axes, cube.positions), 0.0)


def test_cube_centripetal_terms_project_only_onto_specific_force() -> None:
    coupling = centripetal_coupling(AccelArray.cube(L))  # rows (f, alpha), cols m(w)
    expected = np.zeros((6, 6))
    expected[0, 5] = expected[1, 4] = expected[2, 3] = -L  # -(wy wz, wx wz, wx wy) * L
    assert np.allclose(coupling, expected, atol=1e-14)
    assert alpha_is_rate_free(AccelArray.cube(L))
    assert not alpha_is_rate_free(_random_array(np.random.default_rng(1)))


@pytest.mark.parametrize(
    ("positions", "axes", "why"),
    [
        (AccelArray.cube(L).positions[:5], AccelArray.cube(L).axes[:5], "five sensors"),
        (AccelArray.cube(L).positions, np.tile([1.0, 0.0, 0.0], (6, 1)), "parallel axes"),
        (np.zeros((6, 3)), AccelArray.cube(L).axes, "co-located sensors"),
        (AccelArray.cube(L).positions, AccelArray.cube(L).positions / L, "radial axes"),
        (AccelArray.cube(L).positions, AccelArray.cube(L).axes * 1.1, "non-unit axes"),
        (AccelArray.cube(L).positions[:, :2], AccelArray.cube(L).axes, "wrong shape"),
    ],
)
def test_degenerate_geometry_raises(positions: np.ndarray, axes: np.ndarray, why: str) -> None:
    with pytest.raises(InputError):
        AccelArray(positions=positions, axes=axes)


def test_geometry_check_does_not_depend_on_length_unit() -> None:
    # a millimetre-sized cube is as well conditioned as a metre-sized one
    AccelArray.cube(1e-3)
    AccelArray.cube(10.0)
    with pytest.raises(InputError):
        AccelArray.cube(0.0)


# --- exact inversion -------------------------------------------------------------------------


@pytest.mark.parametrize(
    "make_array", [lambda: AccelArray.cube(L), lambda: _random_array(np.random.default_rng(7))]
)
def test_exact_readings_invert_to_machine_precision(make_array) -> None:
    array = make_array()
    rng = np.random.default_rng(3)
    w, alpha, f = rng.normal(0, 2, (3, 50, 3))
    readings = _independent_readings(array.positions, array.axes, f, alpha, w)
    assert np.allclose(array.exact_readings(f, alpha, w), readings, rtol=0, atol=1e-13)
    f_hat, alpha_hat = solve_with_rate(array, readings, w)
    assert np.abs(f_hat - f).max() < 1e-12
    assert np.abs(alpha_hat - alpha).max() < 1e-11
    # one sample through solve_array with w0 = the true rate: same answer
    single = solve_array(array, readings[:1], np.array([0.0]), w[0])
    assert np.abs(single.specific_force[0] - f[0]).max() < 1e-12
    assert np.abs(single.angular_acceleration[0] - alpha[0]).max() < 1e-11


def test_weights_do_not_bias_exact_solution() -> None:
    array = _random_array(np.random.default_rng(11), n=12)
    rng = np.random.default_rng(4)
    w, alpha, f = rng.normal(0, 1, (3, 5, 3))
    readings = _independent_readings(array.positions, array.axes, f, alpha, w)
    f_hat, alpha_hat = solve_with_rate(array, readings, w, sigmas=rng.uniform(0.5, 3.0, 12))
    assert np.abs(f_hat - f).max() < 1e-12 and np.abs(alpha_hat - alpha).max() < 1e-10


# --- rate integration ------------------------------------------------------------------------


@pytest.mark.parametrize(
    "make_array", [lambda: AccelArray.cube(L), lambda: _random_array(np.random.default_rng(7))]
)
def test_constant_rate_is_held_exactly(make_array) -> None:
    # exact up to round-off; for a general geometry the rate ODE w' = b - G m(w) can amplify
    # round-off slowly, hence 1e-8 rather than machine precision
    array = make_array()
    t = np.arange(0, 5, 0.01)
    w = np.tile([0.4, -1.1, 2.0], (t.size, 1))
    f = np.tile([0.1, 0.2, 9.81], (t.size, 1))
    readings = _independent_readings(array.positions, array.axes, f, np.zeros_like(w), w)
    sol = solve_array(array, readings, t, w[0])
    assert np.abs(sol.angular_rate - w).max() < 1e-8
    assert np.abs(sol.angular_acceleration).max() < 1e-8
    assert np.abs(sol.specific_force - f).max() < 1e-8


@pytest.mark.parametrize(
    ("make_array", "bound_at_100hz"),
    [
        # cube: alpha exact, rate = cumulative trapezoid of it
        (lambda: AccelArray.cube(L), 1e-3),
        # general: alpha depends on the (integrated) rate itself, errors feed back
        (lambda: _random_array(np.random.default_rng(7)), 3e-2),
    ],
)
def test_sinusoidal_rate_error_shrinks_with_second_order(make_array, bound_at_100hz) -> None:
    array = make_array()
    f_errors = []
    errors = []
    for rate_hz in (100.0, 200.0, 400.0):
        t = np.arange(0, 10, 1 / rate_hz)
        w, alpha, f = _sinusoid_truth(t)
        readings = _independent_readings(array.positions, array.axes, f, alpha, w)
        sol = solve_array(array, readings, t, w[0])
        errors.append(np.abs(sol.angular_rate - w).max())
        f_errors.append(np.abs(sol.specific_force - f).max())
    assert errors[0] < bound_at_100hz and f_errors[0] < bound_at_100hz
    # trapezoid / Heun: halving the step divides the error by ~4 (second order)
    assert 3.0 < errors[0] / errors[1] < 5.0
    assert 3.0 < errors[1] / errors[2] < 5.0
    assert 12.0 < f_errors[0] / f_errors[2] < 20.0  # 4x the rate: 16x


def test_to_imu_data_feeds_the_rest_of_fgins() -> None:
    array = AccelArray.cube(L)
    t = np.arange(0, 1, 0.01)
    w, alpha, f = _sinusoid_truth(t)
    sol = solve_array(
        array, _independent_readings(array.positions, array.axes, f, alpha, w), t, w[0]
    )
    imu = to_imu_data(sol)
    assert isinstance(imu, ImuData) and len(imu) == t.size
    assert imu.rate_hz == pytest.approx(100.0)
    assert np.array_equal(imu.gyro, sol.angular_rate) and np.array_equal(
        imu.accel, sol.specific_force
    )


@pytest.mark.parametrize(
    ("readings", "t", "w0"),
    [
        (np.zeros((4, 5)), np.arange(4.0), np.zeros(3)),
        (np.zeros((4, 6)), np.arange(3.0), np.zeros(3)),
        (np.zeros((4, 6)), np.array([0.0, 1.0, 1.0, 2.0]), np.zeros(3)),
        (np.where(np.eye(4, 6) > 0, np.nan, 0.0), np.arange(4.0), np.zeros(3)),
        (np.zeros((4, 6)), np.arange(4.0), np.zeros(2)),
        (np.zeros((0, 6)), np.zeros(0), np.zeros(3)),
    ],
)
def test_bad_input_raises(readings: np.ndarray, t: np.ndarray, w0: np.ndarray) -> None:
    with pytest.raises(InputError):
        solve_array(AccelArray.cube(L), readings, t, w0)


# --- noise -----------------------------------------------------------------------------------


def test_cube_noise_maps_to_closed_form_monte_carlo() -> None:
    array = AccelArray.cube(L)
    sigma_a = 1e-3
    rng = np.random.default_rng(5)
    t = np.arange(40000) * 0.01
    f_true = np.array([0.0, 0.0, 9.81])
    clean = _independent_readings(array.positions, array.axes, f_true, np.zeros(3), np.zeros(3))
    readings = clean + rng.standard_normal((t.size, 6)) * sigma_a
    sol = solve_array(array, readings, t, np.zeros(3))
    f_std = (sol.specific_force - f_true).std(axis=0)
    alpha_std = sol.angular_acceleration.std(axis=0)
    assert f_std == pytest.approx(np.full(3, sigma_a / math.sqrt(2)), rel=0.03)
    assert alpha_std == pytest.approx(np.full(3, sigma_a / (math.sqrt(2) * L)), rel=0.03)
    # the analytic propagation agrees with the same closed form
    sigma_f, sigma_alpha = solution_noise_densities(array, sigma_a)
    assert sigma_f == pytest.approx(np.full(3, sigma_a / math.sqrt(2)), rel=1e-12)
    assert sigma_alpha == pytest.approx(np.full(3, sigma_a / (math.sqrt(2) * L)), rel=1e-12)


def test_general_geometry_noise_matches_propagation() -> None:
    array = _random_array(np.random.default_rng(8), n=9)
    density = np.random.default_rng(9).uniform(1e-3, 3e-3, 9)
    rng = np.random.default_rng(10)
    t = np.arange(20000) * 0.01
    readings = rng.standard_normal((t.size, 9)) * density / math.sqrt(0.01)
    f_hat, alpha_hat = solve_with_rate(array, readings, np.zeros((t.size, 3)), sigmas=density)
    sigma_f, sigma_alpha = solution_noise_densities(array, density)
    assert f_hat.std(axis=0) * math.sqrt(0.01) == pytest.approx(sigma_f, rel=0.04)
    assert alpha_hat.std(axis=0) * math.sqrt(0.01) == pytest.approx(sigma_alpha, rel=0.04)


def test_rate_error_is_a_random_walk_of_the_equivalent_density() -> None:
    array = AccelArray.cube(L)
    density, dt, n, runs = 1e-3, 0.01, 1000, 400  # m/s^2/sqrt(Hz)
    config = equivalent_imu_noise(array, density, 0.0)
    rng = np.random.default_rng(12)
    t = np.arange(n) * dt
    noise = rng.standard_normal((runs, n, 6)) * density / math.sqrt(dt)
    final_rate = np.array(
        [solve_array(array, noise[k], t, np.zeros(3)).angular_rate[-1] for k in range(runs)]
    )
    expected = config["gyro_bias_rw_rad_per_s_per_sqrt_s"] * math.sqrt(t[-1])
    assert final_rate.std() == pytest.approx(expected, rel=0.08)


def test_equivalent_imu_noise_is_valid_fgins_config() -> None:
    array = AccelArray.cube(L)
    density, bias, horizon = 2e-3, 5e-3, 30.0
    config = equivalent_imu_noise(array, density, bias, drift_horizon_s=horizon)
    noise = imu_noise_from_config(config)  # every key must be accepted
    sigma_alpha = density / (math.sqrt(2) * L)
    bias_alpha = bias / (math.sqrt(2) * L)
    assert noise.accel_noise == pytest.approx(density / math.sqrt(2))
    assert noise.gyro_bias_rw == pytest.approx(math.sqrt(sigma_alpha**2 + bias_alpha**2 * horizon))
    # The in-interval random walk, folded into a white gyro noise over one keyframe interval
    # (1 s): a Monte Carlo of the integrated walk (the attitude error) has variance q^2 T^3/3.
    rng = np.random.default_rng(21)
    dt, steps = 0.01, 100
    walk = np.cumsum(rng.standard_normal((4000, steps)) * noise.gyro_bias_rw * math.sqrt(dt), 1)
    angle = walk.sum(axis=1) * dt
    assert noise.gyro_noise * math.sqrt(steps * dt) == pytest.approx(angle.std(), rel=0.06)
    assert noise.accel_bias_prior == pytest.approx(bias / math.sqrt(2))
    with pytest.raises(InputError):
        equivalent_imu_noise(array, -1.0, 0.0)


# --- simulator -------------------------------------------------------------------------------


def test_grades_in_si() -> None:
    assert GRADES["automotive"].bias == pytest.approx(20e-3 * 9.80665)
    assert GRADES["tactical"].scale_factor == pytest.approx(300e-6)
    assert GRADES["navigation"].noise_density == pytest.approx(5e-6 * 9.80665)
    errors = draw_array_errors(np.random.default_rng(0), 200000, "tactical")
    assert errors.bias.std() == pytest.approx(CALIBRATION_RESIDUAL * 1000e-6 * 9.80665, rel=0.01)
    assert errors.scale_factor.std() == pytest.approx(CALIBRATION_RESIDUAL * 300e-6, rel=0.01)
    with pytest.raises(InputError):
        draw_array_errors(np.random.default_rng(0), 6, "consumer")


def test_simulated_error_free_readings_round_trip() -> None:
    array = AccelArray.cube(L)
    t = np.arange(0, 10, 0.005)
    w, _, f = _sinusoid_truth(t)
    perfect = ArrayGrade("perfect", 0.0, 0.0, 0.0)
    # angular acceleration from finite differences of the rate, as a caller with only w has it
    readings = array_readings(array, t, w, f, np.random.default_rng(0), perfect)
    sol = solve_array(array, readings, t, w[0])
    assert np.abs(sol.angular_rate - w).max() < 1e-3
    assert np.abs(sol.specific_force - f).max() < 1e-3


def test_simulated_bias_gives_constant_alpha_bias_and_rate_ramp() -> None:
    array = AccelArray.cube(L)
    t = np.arange(0, 20, 0.01)
    w, alpha, f = _sinusoid_truth(t)
    bias = np.random.default_rng(1).normal(0, 1e-3, 6)
    errors = ArrayErrors(bias=bias, scale_factor=np.zeros(6))
    quiet = ArrayGrade("bias-only", 0.0, 0.0, 0.0)
    readings = array_readings(
        array, t, w, f, np.random.default_rng(0), quiet, angular_acceleration=alpha, errors=errors
    )
    clean = array_readings(
        array,
        t,
        w,
        f,
        np.random.default_rng(0),
        quiet,
        angular_acceleration=alpha,
        errors=ArrayErrors(bias=np.zeros(6), scale_factor=np.zeros(6)),
    )
    biased_sol = solve_array(array, readings, t, w[0])
    clean_sol = solve_array(array, clean, t, w[0])
    # independent expectation: the per-sensor biases solved by plain lstsq through H
    h = np.hstack([array.axes, np.cross(array.positions, array.axes)])
    bias_x = np.linalg.lstsq(h, bias, rcond=None)[0]
    alpha_error = biased_sol.angular_acceleration - clean_sol.angular_acceleration
    assert np.allclose(alpha_error, bias_x[3:], rtol=0, atol=1e-12)
    # the rate error is a ramp b_alpha * t (here up to ~0.4 rad/s after 20 s)
    rate_error = biased_sol.angular_rate - clean_sol.angular_rate
    assert np.allclose(rate_error, np.outer(t - t[0], bias_x[3:]), rtol=0, atol=1e-10)
    assert np.abs(rate_error[-1]).max() > 0.1


def test_simulated_noise_has_grade_density() -> None:
    array = AccelArray.cube(L)
    dt = 0.01
    t = np.arange(20000) * dt
    zero = np.zeros((t.size, 3))
    grade = GRADES["automotive"]
    errors = ArrayErrors(bias=np.zeros(6), scale_factor=np.zeros(6))
    readings = array_readings(array, t, zero, zero, np.random.default_rng(2), grade, errors=errors)
    assert readings.std(axis=0) == pytest.approx(
        np.full(6, grade.noise_density / math.sqrt(dt)), rel=0.04
    )
    with pytest.raises(InputError):
        array_readings(array, t, zero[:-1], zero, np.random.default_rng(2), grade)


def test_simulated_scale_factor_multiplies_exact_reading() -> None:
    array = AccelArray.cube(L)
    t = np.arange(0, 1, 0.01)
    w, alpha, f = _sinusoid_truth(t)
    scale = np.linspace(-1e-3, 1e-3, 6)
    errors = ArrayErrors(bias=np.zeros(6), scale_factor=scale)
    quiet = ArrayGrade("scale-only", 0.0, 0.0, 0.0)
    readings = array_readings(
        array, t, w, f, np.random.default_rng(0), quiet, angular_acceleration=alpha, errors=errors
    )
    exact = _independent_readings(array.positions, array.axes, f, alpha, w)
    assert np.allclose(readings, exact * (1 + scale), rtol=0, atol=1e-12)


def test_diverging_rate_integration_raises_instead_of_returning_inf() -> None:
    # a general geometry's rate ODE w' = b - G m(w) is quadratic: a large bias blows it up
    array = _random_array(np.random.default_rng(7))
    t = np.arange(20000) * 0.01
    readings = np.full((t.size, len(array)), 5.0)
    with pytest.raises(InputError, match="diverged"):
        solve_array(array, readings, t, np.zeros(3))
    # the cube only drifts linearly under the same abuse: finite, no error
    cube_sol = solve_array(AccelArray.cube(L), np.full((t.size, 6), 5.0), t, np.zeros(3))
    assert np.all(np.isfinite(cube_sol.angular_rate))
