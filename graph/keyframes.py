"""Keyframe times and the IMU segments between them (numpy only).

Keyframes sit at the usable GNSS epochs, at the ends of suspect IMU stretches (gaps, filled
samples) and every ``max_interval`` seconds where nothing else puts one (GNSS outages). The
IMU is split exactly at keyframe times: each sample is held constant over [t_k, t_k+1), and a
keyframe falling inside that interval cuts it in two, so GNSS epochs need not coincide with
IMU samples.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgins.datatypes import ImuData


@dataclass
class Segments:
    """IMU integration segments grouped by keyframe interval.

    ``times`` are the keyframe times (K,). Segment j runs from ``start[j]`` for ``dt[j]``
    seconds using IMU sample ``sample[j]``; interval i owns segments
    ``bounds[i]:bounds[i + 1]``. ``suspect[i]`` marks intervals inside suspect IMU stretches.
    """

    times: np.ndarray
    start: np.ndarray
    dt: np.ndarray
    sample: np.ndarray
    bounds: np.ndarray
    suspect: np.ndarray

    def interval(self, i: int) -> slice:
        return slice(int(self.bounds[i]), int(self.bounds[i + 1]))


def keyframe_times(
    imu: ImuData, gnss_times: np.ndarray, max_interval: float, min_separation: float = 0.2
) -> np.ndarray:
    """Keyframe times over the IMU span (see module docstring)."""
    t_first, t_last = float(imu.t[0]), float(imu.t[-1])
    inside = gnss_times[(gnss_times >= t_first) & (gnss_times <= t_last)]
    anchors = np.unique(np.concatenate([[t_first, t_last], inside]))
    extra = [x for a, b in imu.suspect for x in (a, b) if t_first < x < t_last]
    for x in extra:
        # Suspect-stretch ends only matter to within a sample; never crowd a GNSS keyframe.
        if np.min(np.abs(anchors - x)) >= min_separation:
            anchors = np.sort(np.append(anchors, x))
    anchors_sorted = anchors
    times: list[float] = [float(anchors_sorted[0])]
    for b in anchors_sorted[1:]:
        a = times[-1]
        n_fill = int(np.ceil((b - a) / max_interval - 1e-9))
        times.extend(a + (b - a) * np.arange(1, n_fill) / n_fill)
        times.append(float(b))
    return np.asarray(times)


def build_segments(imu: ImuData, times: np.ndarray) -> Segments:
    """Split the IMU stream at keyframe times."""
    starts = np.union1d(imu.t, times)
    starts = starts[(starts >= times[0]) & (starts <= times[-1])]
    dt = np.diff(starts)
    seg_start = starts[:-1]
    sample = np.searchsorted(imu.t, seg_start, side="right") - 1
    sample = np.clip(sample, 0, len(imu) - 1)
    bounds = np.searchsorted(seg_start, times, side="left")
    bounds[-1] = len(seg_start)
    mid = 0.5 * (times[:-1] + times[1:])
    suspect = np.zeros(len(times) - 1, dtype=bool)
    for a, b in imu.suspect:
        suspect |= (mid > a) & (mid < b)
    return Segments(
        times=times, start=seg_start, dt=dt, sample=sample, bounds=bounds, suspect=suspect
    )
