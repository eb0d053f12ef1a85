"""The fast paths of issue 9 compute what the straightforward code computes.

Each speed-up replaced a per-window / per-vector / per-keyframe Python loop or a slow
binding call by a vectorised or specialised one; these tests hold each to its reference.
"""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from gtsam.symbol_shorthand import B, V, X

from fgins.baseline.mechanization import (
    BlockNominal,
    NavFrame,
    block_transition,
    coarse_block_transition,
)
from fgins.config import ImuNoise
from fgins.datatypes import ImuData, Origin
from fgins.factors import stationary
from fgins.factors import vehicle as vehicle_model
from fgins.factors.values import put_bias, put_double, put_pose, put_vector
from fgins.geodesy import so3_exp


def _quiet_reference(imu, times, noise, before_s, after_s):
    """quiet_imu as it was: one window at a time with np.std / np.mean (and steady_imu)."""
    rate = imu.rate_hz
    gyro_threshold = max(4.0 * noise.gyro_noise * np.sqrt(rate), 0.005)
    accel_threshold = max(4.0 * noise.accel_noise * np.sqrt(rate), 0.05)
    turn_threshold = max(stationary.TURN_BIAS_SIGMAS * noise.gyro_bias_prior, 0.01)
    lo = np.searchsorted(imu.t, times - before_s)
    hi = np.searchsorted(imu.t, times + after_s)
    quiet = np.zeros(len(times), dtype=bool)
    steady = np.ones(len(times), dtype=bool)
    for k, (a, b) in enumerate(zip(lo, hi, strict=True)):
        if b - a >= stationary.MIN_QUIET_SAMPLES:
            quiet[k] = (
                imu.gyro[a:b].std(axis=0).max() < gyro_threshold
                and imu.accel[a:b].std(axis=0).max() < accel_threshold
                and not np.linalg.norm(imu.gyro[a:b].mean(axis=0)) > turn_threshold
            )
        half = (b - a) // 2
        if half < 2:
            continue
        for signal in (imu.accel, imu.gyro):
            first, second = signal[a : a + half], signal[b - half : b]
            spread = np.sqrt((first.var(axis=0, ddof=1) + second.var(axis=0, ddof=1)) / half)
            if np.any(np.abs(second.mean(axis=0) - first.mean(axis=0)) > 4.0 * spread + 1e-12):
                steady[k] = False
                break
    return quiet & steady


@pytest.mark.parametrize("before_s,after_s", [(0.5, 0.5), (1.0, 0.0)])
def test_vectorised_quiet_windows_decide_as_the_loop(before_s, after_s):
    rng = np.random.default_rng(3)
    rate = 200.0
    t = np.arange(0.0, 120.0, 1.0 / rate)
    moving = (np.sin(t / 7.0) > -0.3).astype(float)  # stops where the sine is low
    gyro = moving[:, None] * 0.05 * np.sin(t / 3.0)[:, None] + rng.normal(0, 2e-3, (len(t), 3))
    accel = np.array([0.0, 0.0, 9.8]) + moving[:, None] * 0.8 * np.cos(t / 2.0)[:, None]
    accel = accel + rng.normal(0, 0.02, (len(t), 3))
    accel[(t > 40) & (t < 45)] = [0.1, -0.2, 9.81]  # noise-free and exactly constant
    gyro[(t > 40) & (t < 45)] = 0.0
    imu = ImuData(t=t, gyro=gyro, accel=accel)
    noise = ImuNoise(
        accel_noise=0.003, gyro_noise=2e-4, accel_bias_rw=1e-4, gyro_bias_rw=1e-5,
        accel_bias_prior=0.1, gyro_bias_prior=0.005,
    )  # fmt: skip
    times = np.concatenate([np.arange(-1.0, 121.0, 0.37), [41.0, 42.5, 44.0]])
    expected = _quiet_reference(imu, times, noise, before_s, after_s)
    got = stationary.quiet_imu(imu, times, noise, before_s=before_s, after_s=after_s)
    assert expected.any() and not expected.all()
    np.testing.assert_array_equal(got, expected)


def test_so3_exp_one_vector_equals_the_batched_formula():
    rng = np.random.default_rng(0)
    for scale in (0.0, 1e-12, 1e-9, 1e-4, 0.3, 2.5):
        phi = rng.normal(size=(20, 3)) * scale
        batched = so3_exp(phi)
        single = np.array([so3_exp(p) for p in phi])
        np.testing.assert_allclose(single, batched, rtol=0, atol=1e-15)
        np.testing.assert_allclose(
            batched @ np.swapaxes(batched, 1, 2), np.broadcast_to(np.eye(3), (20, 3, 3)),
            atol=1e-14,
        )  # fmt: skip


def test_one_keyframe_nhc_factor_equals_the_batched_one():
    rng = np.random.default_rng(1)
    rotation = so3_exp(rng.normal(size=3) * 0.5)
    velocity = rng.normal(size=3) * 10.0
    select = vehicle_model.nhc_rows(so3_exp(np.array([0.01, -0.02, 0.3])))
    sigmas = np.array([0.1, 0.2])
    pose = gtsam.Pose3(gtsam.Rot3(rotation), rng.normal(size=3))
    point = gtsam.Values()
    put_pose(point, X(3), pose)
    put_vector(point, V(3), velocity)
    one = vehicle_model.nhc_factor(X(3), V(3), rotation, velocity, select, sigmas, point)
    (batched,) = vehicle_model.nhc_factors(
        np.array([X(3)]), np.array([V(3)]), [pose], velocity[None], select, sigmas[None]
    )
    moved = gtsam.Values()
    put_pose(moved, X(3), pose.retract(rng.normal(size=6) * 0.01))
    put_vector(moved, V(3), velocity + 0.1)
    assert one.error(moved) == pytest.approx(batched.error(moved), rel=1e-12)
    assert one.error(point) == pytest.approx(batched.error(point), rel=1e-12)


def test_typed_values_writes_store_the_right_types():
    values = gtsam.Values()
    put_pose(values, X(0), gtsam.Pose3(gtsam.Rot3.Yaw(0.3), np.array([1.0, 2.0, 3.0])))
    put_vector(values, V(0), [1.0, 2.0, 3.0])
    put_bias(values, B(0), gtsam.imuBias.ConstantBias(np.ones(3), 2 * np.ones(3)))
    put_double(values, gtsam.symbol("w", 0), 0.25)
    put_double(values, gtsam.symbol("w", 0), 0.5)  # insert or assign
    assert values.atPose3(X(0)).rotation().yaw() == pytest.approx(0.3)
    np.testing.assert_array_equal(values.atVector(V(0)), [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(values.atConstantBias(B(0)).gyroscope(), [2.0, 2.0, 2.0])
    assert values.atDouble(gtsam.symbol("w", 0)) == 0.5


def test_coarse_block_transition_is_close_to_the_exact_composition():
    rng = np.random.default_rng(2)
    n, dt = 200, np.full(200, 0.005)
    frame = NavFrame.at(Origin(lat=48.0, lon=11.0, alt=500.0))
    rotation = so3_exp(np.cumsum(rng.normal(size=(n + 1, 3)) * 1e-3, axis=0))
    f_nav = np.array([0.5, -0.3, 9.81]) + rng.normal(size=(n, 3)) * 0.2
    nominal = BlockNominal(rotation, np.zeros((n + 1, 3)), np.zeros((n + 1, 3)), f_nav)
    noise = ImuNoise(
        accel_noise=0.003, gyro_noise=2e-4, accel_bias_rw=1e-4, gyro_bias_rw=1e-5,
        accel_bias_prior=0.1, gyro_bias_prior=0.005,
    )  # fmt: skip
    scale = np.ones((n, 2))
    phi, q = block_transition(nominal, dt, frame, noise, scale)
    phi_c, q_c = coarse_block_transition(nominal, dt, frame, noise, scale, 8)
    # Every term to 1 % or 1e-3 (the per-sample composition is itself first order per
    # sample; small cross terms move with the attitude inside a sub-step).
    np.testing.assert_allclose(phi_c, phi, rtol=0.01, atol=1e-3)
    # Velocity, attitude and bias noise to a few per cent; position noise (second order
    # within a sub-step) within a factor 1.5.
    diag, diag_c = np.diag(q), np.diag(q_c)
    np.testing.assert_allclose(diag_c[3:], diag[3:], rtol=0.05)
    assert np.all((diag_c[:3] > diag[:3] / 1.5) & (diag_c[:3] < 1.5 * diag[:3]))
