"""The horizontal plane's signals as complex numbers, east + i north or first + i second
IMU axis (numpy only). Shared by the two checks that compare the IMU's horizontal specific
force, carried by the gyro about up, with the fixes' acceleration: the mounting's heading
match (:mod:`fgins.mounting`) and the accelerometer's handedness
(:mod:`fgins.io.axes_handedness`)."""

from __future__ import annotations

import numpy as np


def horizontal_axes(up: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit axes normal to ``up`` (unit), the second the first turned counter-clockwise
    about up (first x second = up)."""
    first = np.cross(up, np.eye(3)[int(np.argmin(np.abs(up)))])
    first /= np.linalg.norm(first)
    return first, np.cross(up, first)


def yaw_about(imu, up: np.ndarray) -> np.ndarray:
    """The gyro's rotation about ``up`` since the first sample (rad, trapezoid rule)."""
    dt = np.diff(imu.t)
    return np.concatenate([[0.0], np.cumsum(0.5 * (imu.gyro[1:] + imu.gyro[:-1]) @ up * dt)])


def complex_at(x: np.ndarray, t: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Complex ``values`` at times ``t`` interpolated linearly at ``x``."""
    return np.interp(x, t, values.real) + 1j * np.interp(x, t, values.imag)


def window_means(times: np.ndarray, values: np.ndarray, grid: np.ndarray, half: float, box: bool) -> np.ndarray:
    """Means of complex ``values`` over +-half about ``grid`` as the fixes measure their
    acceleration: a box (velocities differenced over the window), or the triangle a second
    difference of positions over +-half weighs them by."""
    dt = np.diff(times)
    once = np.concatenate([[0.0], np.cumsum(0.5 * (values[1:] + values[:-1]) * dt)])
    if box:
        return (complex_at(grid + half, times, once) - complex_at(grid - half, times, once)) / (2.0 * half)
    twice = np.concatenate([[0.0], np.cumsum(0.5 * (once[1:] + once[:-1]) * dt)])
    return (complex_at(grid + half, times, twice) - 2.0 * complex_at(grid, times, twice)
            + complex_at(grid - half, times, twice)) / half**2  # fmt: skip
