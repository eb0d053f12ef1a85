"""Checks on raw IMU streams: NaN rows, duplicate or backwards timestamps, gaps, filled stretches.

Readers call :func:`clean_imu` so every format reports the same findings the same way.
"""

from __future__ import annotations

import numpy as np

from fgins.datatypes import ImuData, InputError

GAP_FACTOR = 3.0  # a gap is a sample interval longer than this many nominal periods
MIN_FILL_DURATION_S = 0.3  # shorter straight-line runs happen naturally at rest


def find_gaps(t: np.ndarray, factor: float = GAP_FACTOR) -> list[tuple[float, float]]:
    """Intervals between consecutive samples longer than ``factor`` nominal periods."""
    dt = np.diff(t)
    nominal = float(np.median(dt))
    idx = np.flatnonzero(dt > factor * nominal)
    return [(float(t[i]), float(t[i + 1])) for i in idx]


def find_linear_fills(
    t: np.ndarray, data: np.ndarray, min_duration_s: float = MIN_FILL_DURATION_S
) -> list[tuple[float, float]]:
    """Stretches where every channel moves on a straight line in time.

    Loggers that lose samples sometimes fill them by linear interpolation (the KITTI drive
    has eight such stretches). Real sensor noise never gives a zero second difference on all
    six channels at once, so runs of (near) zero second differences mark filled samples.
    """
    if len(t) < 3:
        return []
    slope = np.diff(data, axis=0) / np.diff(t)[:, None]
    curvature = np.abs(np.diff(slope, axis=0))
    scale = np.abs(slope[1:]) + np.abs(slope[:-1]) + 1e-9
    straight = np.all(curvature <= 1e-4 * scale + 1e-9, axis=1)
    # straight[i] says samples i, i+1, i+2 are collinear.
    fills: list[tuple[float, float]] = []
    edges = np.diff(np.concatenate([[0], straight.astype(np.int8), [0]]))
    for start, stop in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
        t_start, t_stop = float(t[start]), float(t[stop + 1])
        if t_stop - t_start >= min_duration_s:
            fills.append((t_start, t_stop))
    return fills


def clean_imu(
    t: np.ndarray, gyro: np.ndarray, accel: np.ndarray, *, source: str, warnings: list[str]
) -> ImuData:
    """Drop NaN rows and exact duplicate timestamps (counted), reject backwards time, flag
    gaps and linearly filled stretches as suspect intervals (reported)."""
    t = np.asarray(t, dtype=float)
    gyro = np.asarray(gyro, dtype=float)
    accel = np.asarray(accel, dtype=float)
    finite = np.isfinite(t) & np.all(np.isfinite(gyro), axis=1) & np.all(np.isfinite(accel), axis=1)
    if not finite.all():
        warnings.append(f"{source}: dropped {int((~finite).sum())} IMU row(s) with NaN/inf values")
        t, gyro, accel = t[finite], gyro[finite], accel[finite]
    if len(t) < 2:
        raise InputError(f"{source}: fewer than 2 valid IMU samples")
    dt = np.diff(t)
    if np.any(dt < 0):
        row = int(np.argmax(dt < 0)) + 1
        raise InputError(
            f"{source}: IMU time goes backwards at sample {row} ({t[row - 1]:.6f} -> {t[row]:.6f});"
            " the log mixes clocks or files — sort or split it"
        )
    duplicate = np.concatenate([[False], dt == 0])
    if duplicate.any():
        warnings.append(
            f"{source}: dropped {int(duplicate.sum())} IMU sample(s) with repeated time"
        )
        t, gyro, accel = t[~duplicate], gyro[~duplicate], accel[~duplicate]
    suspect: list[tuple[float, float]] = []
    gaps = find_gaps(t)
    if gaps:
        total = sum(b - a for a, b in gaps)
        warnings.append(
            f"{source}: {len(gaps)} IMU gap(s) longer than {GAP_FACTOR:g} sample periods "
            f"({total:.2f} s in all); bridged with inflated noise"
        )
        suspect.extend(gaps)
    fills = find_linear_fills(t, np.column_stack([gyro, accel]))
    if fills:
        total = sum(b - a for a, b in fills)
        warnings.append(
            f"{source}: {len(fills)} stretch(es) of linearly interpolated IMU samples "
            f"({total:.1f} s in all, at t-t_imu0 = "
            + ", ".join(f"{a - t[0]:.0f}" for a, _ in fills)
            + " s); treated as gaps with inflated noise"
        )
        suspect.extend(fills)
    return ImuData(t=t, gyro=gyro, accel=accel, suspect=sorted(suspect))
