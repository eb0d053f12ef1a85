"""Keyframe times and the IMU segments between them (numpy only).

Keyframes sit at the usable GNSS epochs, at the ends of suspect IMU stretches (gaps, filled
samples) and every ``max_interval`` seconds where nothing else puts one (GNSS outages). The
IMU is split exactly at keyframe times: each sample is held constant over [t_k, t_k+1), and a
keyframe falling inside that interval cuts it in two, so GNSS epochs need not coincide with
IMU samples. An interval in which the gyro turns more than a quarter revolution is split further
(a flipping or spinning multirotor: :func:`_split_by_turn`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fgins.datatypes import ImuData
from fgins.factors.imu_samples import cut_sample_accel, segment_leads


@dataclass
class Segments:
    """IMU integration segments grouped by keyframe interval.

    ``times`` are the keyframe times (K,). Segment j runs from ``start[j]`` for ``dt[j]``
    seconds using IMU sample ``sample[j]``, ``lead[j]`` seconds after that sample's time (a
    keyframe cut its interval; 0 otherwise); interval i owns segments
    ``bounds[i]:bounds[i + 1]``. ``suspect[i]`` marks intervals inside suspect IMU stretches.
    """

    times: np.ndarray
    start: np.ndarray
    dt: np.ndarray
    sample: np.ndarray
    bounds: np.ndarray
    suspect: np.ndarray
    lead: np.ndarray

    def interval(self, i: int) -> slice:
        return slice(int(self.bounds[i]), int(self.bounds[i + 1]))

    def accel(self, imu_accel: np.ndarray, imu_gyro: np.ndarray, rows) -> np.ndarray:
        """The held specific force of segments ``rows`` in their own start axes
        (:func:`fgins.factors.imu_samples.cut_sample_accel`)."""
        sample = self.sample[rows]
        return cut_sample_accel(imu_accel[sample], imu_gyro[sample], self.lead[rows])


# Largest rotation one preintegration interval may hold (see _split_by_turn). A quarter turn:
# with half a turn a 540 deg pirouette in 1.5 s still bridged an outage 1.6 m off (0.7 m
# yawing slowly; NEES 4), with a quarter 0.71 m; 1 or 0.5 rad steps bought nothing more.
MAX_TURN_RAD = np.pi / 2


def keyframe_times(
    imu: ImuData,
    gnss_times: np.ndarray,
    max_interval: float,
    min_separation: float = 0.2,
    max_turn_rad: float = MAX_TURN_RAD,
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
    return _split_by_turn(imu, np.asarray(times), max_turn_rad)


def turned_angle(imu: ImuData) -> tuple[np.ndarray, np.ndarray]:
    """(times, the angle in rad the gyro has turned since the first sample at those times):
    each sample's |rate| held over its interval, as the preintegration holds it."""
    rate = np.linalg.norm(imu.gyro[:-1], axis=1)
    return imu.t, np.concatenate([[0.0], np.cumsum(rate * np.diff(imu.t))])


def _split_by_turn(imu: ImuData, times: np.ndarray, max_turn_rad: float) -> np.ndarray:
    """``times`` with keyframes added inside every interval that turns more than
    ``max_turn_rad``, at equal steps of turned angle.

    GTSAM's preintegrated rotation is a tangent-space vector: its Jacobians are singular where
    the accumulated rotation reaches 2 pi (and the first-order bias correction poor well
    before), and a multirotor's 360 deg flip or a 400 deg/s
    pirouette inside one 1 s interval gave metre errors with no warning (noise-free data: 1.1 m
    off, NEES 20). No land vehicle or aircraft turns that fast, so they keep their keyframes."""
    if len(imu) < 2:
        return times
    t, angle = turned_angle(imu)
    at = np.interp(times, t, angle)
    turned = np.diff(at)
    over = np.flatnonzero(turned > max_turn_rad)
    if not len(over):
        return times
    added = []
    for i in over:
        n = int(np.ceil(turned[i] / max_turn_rad))
        targets = at[i] + turned[i] * np.arange(1, n) / n
        # The angle is non-decreasing in time: the first time it reaches each target.
        where = np.searchsorted(angle, targets, side="left")
        where = np.clip(where, 1, len(t) - 1)
        lo, hi = angle[where - 1], angle[where]
        frac = np.where(hi > lo, (targets - lo) / np.where(hi > lo, hi - lo, 1.0), 0.0)
        cut = t[where - 1] + frac * (t[where] - t[where - 1])
        added.append(cut[(cut > times[i]) & (cut < times[i + 1])])
    return np.unique(np.concatenate([times, *added]))


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
        times=times, start=seg_start, dt=dt, sample=sample, bounds=bounds, suspect=suspect,
        lead=segment_leads(imu.t, seg_start, sample),
    )  # fmt: skip
