"""Linearly interpolated IMU stretches (fgins.io.imu_checks.find_linear_fills) whatever the
rate and the time base: a ROS bag's nanosecond stamps turned into POSIX seconds carry one
ulp (2.4e-7 s at 1.6e9 s) of error, which at 300-400 Hz hid most of KITTI's filled
stretches (outside tester: the KITTI drive upsampled to 400 Hz in a bag, 8 m off at exit 0)."""

from __future__ import annotations

import numpy as np
import pytest

from fgins.io.imu_checks import find_linear_fills


def _noisy_with_fill(rate: float, start_ns: int, seed: int) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    """20 s of six noisy channels at ``rate`` stamped in integer nanoseconds (as a bag's
    header stamps), read as seconds, with 2 s between 8 and 10 s filled by linear
    interpolation (in time, as a logger fills)."""
    rng = np.random.default_rng(seed)
    n = round(20 * rate)
    # a real clock's periods scatter (KITTI's by ~2 %); the stamps are whole nanoseconds
    periods_ns = np.round(1e9 / rate * (1 + rng.uniform(-0.02, 0.02, n - 1))).astype(np.int64)
    stamps_ns = start_ns + np.concatenate([[0], np.cumsum(periods_ns)])
    t = stamps_ns / 1e9
    data = np.cumsum(rng.normal(0, 0.01, (n, 6)), axis=0) + rng.normal(0, 0.02, (n, 6))
    a, b = np.searchsorted(t - t[0], [8.0, 10.0])
    exact = (stamps_ns - stamps_ns[0]).astype(float)  # the logger's own time, not the reader's
    for channel in range(6):
        data[a:b + 1, channel] = np.interp(exact[a:b + 1], [exact[a], exact[b]], [data[a, channel], data[b, channel]])
    return t, data, (float(t[a]), float(t[b]))


@pytest.mark.parametrize("rate", [100.0, 200.0, 400.0, 1000.0])
@pytest.mark.parametrize("start_ns", [0, 1_600_000_000_478_375_700])
def test_a_filled_stretch_is_found_at_any_rate_and_time_base(rate, start_ns):
    t, data, (a, b) = _noisy_with_fill(rate, start_ns, seed=int(rate))
    fills = find_linear_fills(t, data)
    assert len(fills) == 1, fills
    assert abs(fills[0][0] - a) <= 2 / rate and abs(fills[0][1] - b) <= 2 / rate, (fills, a, b)


@pytest.mark.parametrize("rate", [100.0, 400.0, 1000.0])
def test_noise_is_never_a_fill(rate):
    rng = np.random.default_rng(7)
    n = round(60 * rate)
    t = (1_600_000_000_000_000_000 + np.round(np.arange(n) * 1e9 / rate).astype(np.int64)) / 1e9
    # a quiet, well-quantised IMU at rest (0.001 steps): noise still on every channel
    data = np.round(rng.normal(0, 0.003, (n, 6)), 3) + np.array([0, 0, 0, 0, 0, 9.806])
    assert find_linear_fills(t, data) == []


def test_noise_free_readings_have_no_fills_to_find():
    """A simulation without sensor noise: its steady stretches are exactly straight, and were
    said to be a logger's interpolated fills (with their noise inflated) on an independent
    simulator's noise-free flights and drives. No fill can be told there; none is reported.
    A real IMU's noise (here 1e-3) keeps the detector on, and a fill in it is found."""
    t = np.arange(0.0, 60.0, 0.01)
    steady = np.where(t < 20.0, 0.0, np.sin(0.3 * (t - 20.0)))  # 20 s of steady motion
    data = np.column_stack([steady * (k + 1) + 0.1 * k for k in range(6)]) + np.column_stack(
        [0.05 * np.sin(0.2 * t + k) for k in range(6)]
    ) * (t >= 20.0)[:, None]
    assert find_linear_fills(t, data) == []
    noisy = data + np.random.default_rng(1).normal(0.0, 1e-3, data.shape)
    assert find_linear_fills(t, noisy) == []
    filled = noisy.copy()
    a, b = 3000, 3200  # 2 s interpolated across a dropout
    filled[a:b] = noisy[a] + (noisy[b] - noisy[a]) * ((t[a:b] - t[a]) / (t[b] - t[a]))[:, None]
    (start, stop), = find_linear_fills(t, filled)
    assert start == pytest.approx(t[a - 1], abs=0.02) or start == pytest.approx(t[a], abs=0.02)
    assert stop == pytest.approx(t[b], abs=0.02)


STORAGES = {
    "float32": lambda x: x.astype(np.float32).astype(float),
    "float32-printed": lambda x: np.array([float(f"{v:.12e}") for v in x.astype(np.float32).ravel()]).reshape(x.shape),
    "six-decimals": lambda x: np.round(x, 6),
    "ubx-fixed-point": lambda x: np.round(x * 2**12) / 2**12,
}


@pytest.mark.parametrize("storage", list(STORAGES))
@pytest.mark.parametrize("rate", [100.0, 400.0])
def test_a_fill_is_found_in_values_stored_rounded(storage, rate):
    """The same data stored as float32, to six decimals or in a u-blox ESF-RAW's fixed point:
    rounded, a filled stretch bends by a quantum or two a sample, and KITTI's eight fills
    went unseen in every such copy (an outside tester: the drive refused as a gyro with
    swapped columns, or EKF+RTS 0.64 m inside an outage against 0.36 at exit 0). Noise
    stored so is still never a fill."""
    t, data, (a, b) = _noisy_with_fill(rate, 1_600_000_000_478_375_700, seed=int(rate) + 1)
    data = data * 50 + np.array([0, 0, 0, 0, 0, 9.8])  # up to tens of m/s^2: float32's quantum grows
    stored = STORAGES[storage](data)
    fills = find_linear_fills(t, stored)
    assert len(fills) == 1, fills
    assert abs(fills[0][0] - a) <= 2 / rate and abs(fills[0][1] - b) <= 2 / rate, (fills, a, b)
    rng = np.random.default_rng(3)
    quiet = STORAGES[storage](rng.normal(0, 0.003, (len(t), 6)) + np.array([0, 0, 0, 0, 0, 9.806]))
    assert find_linear_fills(t, quiet) == []
