"""Checks on raw IMU streams: NaN rows, repeated or backwards timestamps, gaps, filled stretches.

Two halves, one policy for every format:

* :func:`imu_from_samples` turns a reader's arrays into :class:`ImuData` (the data model cannot
  hold NaN rows or non-increasing times, so these row repairs happen while the samples are put
  into it; every reader calls this one function, with the same rules and messages).
* :func:`flag_suspect` finds gaps, linearly interpolated stretches and saturated runs (a
  channel held at its measuring range) in an :class:`ImuData`.
  It is called by the input-validation layer (:mod:`fgins.io.validate`) for every source.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from fgins.config import STANDARD_GRAVITY
from fgins.datatypes import ImuData, InputError
from fgins.factors.stationary import true_runs

GAP_FACTOR = 3.0  # a gap is a sample interval longer than this many nominal periods
MIN_FILL_DURATION_S = 0.3  # shorter straight-line runs happen naturally at rest
# A backward step of at most this many nominal periods is a reordering (a logger that wrote
# two messages out of order): the samples are sorted. A larger one means two clocks or files.
MAX_REORDER_PERIODS = 5.0
# Farther back, up to this (s), samples are a recorder's messages received late (a bag's
# transport delivered a burst after newer ones) where their stamps, sorted, are one series.
MAX_LATE_DELIVERY_S = 1.0
WEEK_S = 604800.0  # GPS seconds of the week roll over to 0 after this
DAY_S = 86400.0  # seconds of the day roll over to 0 at midnight


def find_gaps(t: np.ndarray, factor: float = GAP_FACTOR) -> list[tuple[float, float]]:
    """Intervals between consecutive samples longer than ``factor`` periods of the IMU
    where it is (:func:`fgins.factors.imu_samples.local_periods`: a rate change is no gap)."""
    from fgins.factors.imu_samples import local_periods

    dt = np.diff(t)
    idx = np.flatnonzero(dt > factor * local_periods(t))
    return [(float(t[i]), float(t[i + 1])) for i in idx]


def imu_at_instants(imu: ImuData, sample_timing: str) -> ImuData:
    """``imu`` stamped at the instants its samples stand for, for checks that line its
    rotation up with the fixes in time: an "instant" sample at its stamp, a "held" or "mean"
    one (over the interval to the next sample) at the middle of that interval; the last
    sample, and one before a gap, by the IMU's local period. The readings are not changed."""
    from fgins.factors.imu_samples import local_periods

    if sample_timing == "instant" or len(imu.t) < 2:
        return imu
    period = local_periods(imu.t)
    step = np.minimum(np.diff(imu.t), period)
    middle = imu.t + 0.5 * np.concatenate([step, period[-1:]])
    return replace(imu, t=middle)


def second_means(
    t: np.ndarray, *series: np.ndarray, min_samples: int = 1
) -> list[np.ndarray] | None:
    """Each of ``series`` (N, 3), sampled at ``t``, averaged over consecutive 1-s blocks (at
    least ``min_samples`` samples each; a last partial block left out), or None when not one
    block fits. The IMU's motion as its checks judge it: turns and accelerations that last,
    not vibration."""
    if len(t) < 2:
        return None
    n = max(round(1.0 / float(np.median(np.diff(t)))), min_samples)
    blocks = len(t) // n
    if blocks < 1:
        return None
    return [values[: blocks * n].reshape(blocks, n, values.shape[1]).mean(axis=1) for values in series]


NOISE_FREE_BEND = 0.05


QUANTUM_SAMPLES = 50_000  # samples a channel's fixed quantum is read from


def _storage_quantum(data: np.ndarray) -> np.ndarray:
    """Each value's storage resolution, same shape as ``data``: a channel's fixed quantum
    (the smallest step between its distinct values, read on up to QUANTUM_SAMPLES samples:
    1e-6 for six decimals; ~1e-12 and less for unrounded doubles) plus, for a channel whose
    every value is a float32, that value's float32 spacing."""
    every = max(1, len(data) // QUANTUM_SAMPLES)
    out = np.zeros_like(data, dtype=float)
    for channel in range(data.shape[1]):
        column = data[:, channel]
        steps = np.diff(np.unique(column[::every]))
        steps = steps[steps > 0]
        out[:, channel] = float(steps.min()) if steps.size else 0.0
        single = column.astype(np.float32)
        # float32 values printed with 10+ digits come back a few 1e-13 off
        if np.all(np.abs(single.astype(float) - column) <= 1e-11 * np.abs(column)):
            out[:, channel] += np.spacing(np.abs(single)).astype(float)
    return out


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
    dt = np.diff(t)
    slope = np.diff(data, axis=0) / dt[:, None]
    curvature = np.abs(np.diff(slope, axis=0))
    scale = np.abs(slope[1:]) + np.abs(slope[:-1]) + 1e-9
    # The stamps' own resolution moves a slope by up to 2 ulp(t) / dt of itself: POSIX
    # seconds (1.6e9, ulp 2.4e-7 s) from a ROS bag's nanoseconds at 400 Hz were already 1e-4
    # of a sample period, and KITTI's filled stretches went unseen there (8 m off, exit 0;
    # outside tester). Noise is still orders of magnitude above this on every channel.
    resolution = np.spacing(np.maximum(np.abs(t[1:-1]), np.abs(t[2:])))
    shortest = np.minimum(dt[1:], dt[:-1])
    tolerance = 1e-4 + 4.0 * resolution / np.maximum(shortest, 1e-12)
    # Noise-free readings (a simulation without sensor noise) bend smoothly everywhere: the
    # change of slope is a small fraction of the slope (0.001-0.007 in an independent
    # simulator's flights and drives; about 1 for any real IMU, whose noise sets it). Every
    # steady stretch of them is straight, and was said to be a logger's fill, with its noise
    # inflated (outside tester): no fill can be told there, none is looked for.
    if float(np.median(np.max(curvature / scale, axis=1))) < NOISE_FREE_BEND:
        return []
    # A stored value carries its storage's rounding: float32 (6e-8 of the value), a fixed
    # number of decimals, a u-blox ESF-RAW's fixed point (2^-12 deg/s, 2^-10 m/s^2). Rounded
    # so, a filled stretch bends by up to two quanta a sample, and KITTI's eight went unseen
    # in every such copy of the drive (the batch refused it as a gyro with swapped columns;
    # EKF+RTS 0.64 m inside the outage against 0.36; outside tester).
    step = np.maximum(_storage_quantum(data), 0.0)
    rounding = 2.5 * np.maximum(np.maximum(step[:-2], step[1:-1]), step[2:]) / np.maximum(shortest, 1e-12)[:, None]
    straight = np.all(curvature <= tolerance[:, None] * scale + rounding + 1e-9, axis=1)
    # straight[i] says samples i, i+1, i+2 are collinear.
    fills: list[tuple[float, float]] = []
    for start, stop in true_runs(straight):
        t_start, t_stop = float(t[start]), float(t[stop + 1])
        if t_stop - t_start >= min_duration_s:
            fills.append((t_start, t_stop))
    return fills


# No IMU measures beyond these (the widest MEMS gyros read +-4000 deg/s = 70 rad/s, shock-
# rated accelerometers +-400 g): a sample beyond them is a logger's corrupt record, not motion.
IMU_GYRO_MAX_RAD_PER_S = 200.0
IMU_ACCEL_MAX_M_PER_S2 = 1.0e4
# More of them than this share of the samples is not corruption but a unit or scale mistake.
IMU_OUT_OF_RANGE_MAX_SHARE = 0.01


def drop_out_of_range(imu: ImuData, warnings: list[str], *, label: str = "imu") -> ImuData:
    """``imu`` without samples no IMU can measure (|gyro| > 200 rad/s or |accel| > 1e4 m/s^2
    on any axis), counted in one warning line; the hole they leave is a gap like any other
    (bridged with inflated noise, refused when too long). Raises :class:`InputError` when
    they are more than 1 % of the samples (a unit mistake, not a glitch).

    Before, eleven accelerometer samples of 1e300 overflowed every estimator: the Kalman
    filters ended in "internal error: SVD did not converge", the batch in a non-finite error."""
    with np.errstate(invalid="ignore"):
        bad_gyro = np.abs(imu.gyro) > IMU_GYRO_MAX_RAD_PER_S
        bad_accel = np.abs(imu.accel) > IMU_ACCEL_MAX_M_PER_S2
    bad = bad_gyro.any(axis=1) | bad_accel.any(axis=1)
    n_bad = int(bad.sum())
    if n_bad == 0:
        return imu
    worst_gyro = float(np.abs(imu.gyro).max())
    worst_accel = float(np.abs(imu.accel).max())
    what = ", ".join(
        text
        for text, present in (
            (f"|gyro| up to {worst_gyro:.3g} rad/s", bad_gyro.any()),
            (f"|accel| up to {worst_accel:.3g} m/s^2", bad_accel.any()),
        )
        if present
    )
    first = float(imu.t[np.argmax(bad)] - imu.t[0])
    if n_bad > IMU_OUT_OF_RANGE_MAX_SHARE * len(imu.t) or len(imu.t) - n_bad < 2:
        raise InputError(
            f"{label}: {n_bad} of {len(imu.t)} samples hold values no IMU measures ({what}; "
            f"limits {IMU_GYRO_MAX_RAD_PER_S:g} rad/s, {IMU_ACCEL_MAX_M_PER_S2:g} m/s^2), the "
            f"first at t-t_imu0 = {first:.2f} s: a unit or scale mistake; give gyro_x..z in "
            "rad/s and accel_x..z in m/s^2"
        )
    keep = ~bad
    warnings.append(
        f"{label}: {n_bad} sample(s) with values no IMU measures ({what}), the first at "
        f"t-t_imu0 = {first:.2f} s, dropped as corrupt; the hole is bridged like a gap"
    )
    return ImuData(
        t=imu.t[keep], gyro=imu.gyro[keep], accel=imu.accel[keep], suspect=imu.suspect,
        frame=imu.frame,
    )  # fmt: skip


# A sample is a spike when it departs from the line through its neighbours by more than a
# vehicle can turn or change speed within one sample: 0.1 rad (5.7 deg) of rotation or 0.5
# m/s of velocity (a 1.5 m/s jump in 10 ms is 15 g; a pothole's 3 g for 3 ms is 0.09 m/s),
# while the neighbours themselves agree to a quarter of that. One or two samples in a row.
# In a slow IMU's long sample a vehicle turns and brakes that much for real (1 Hz: braking at
# 1.9 m/s^2 was "repaired"): never less than SPIKE_MIN_RATE_RAD_S / SPIKE_MIN_ACCEL_M_S2
# apart from the neighbours' line, beyond any road vehicle's rate and acceleration (a
# logger's bit error is tens of rad/s or g).
SPIKE_ANGLE_RAD = 0.1
SPIKE_VELOCITY_M_S = 0.5
SPIKE_MIN_RATE_RAD_S = 2.0
SPIKE_MIN_ACCEL_M_S2 = 30.0


def repair_spikes(imu: ImuData, warnings: list[str], *, label: str = "imu") -> ImuData:
    """``imu`` with isolated spike samples (bit errors, a logger's glitch: one gyro sample at
    30 rad/s) replaced by the line through their neighbours, counted in one warning line.

    Integrated as data, one such sample turned the heading by 17 deg and left the Kalman
    filters 8-80 m off without a word, and made the batch blame the mounting."""
    t = imu.t
    if len(t) < 5:
        return imu
    dt = np.diff(t)
    nominal = float(np.median(dt))
    gyro, accel = imu.gyro.copy(), imu.accel.copy()
    found: list[tuple[int, str, float, float]] = []  # (sample, channel, size, size / limit)
    for data, names, limit in (
        (gyro, ("gyro_x", "gyro_y", "gyro_z"), max(SPIKE_ANGLE_RAD / nominal, SPIKE_MIN_RATE_RAD_S)),
        (accel, ("accel_x", "accel_y", "accel_z"), max(SPIKE_VELOCITY_M_S / nominal, SPIKE_MIN_ACCEL_M_S2)),
    ):
        for width in (1, 2):  # spikes of one sample, then of two in a row
            before, after = data[: -width - 1], data[width + 1 :]
            line = [before + (after - before) * (j + 1) / (width + 1) for j in range(width)]
            off = np.stack([data[1 + j : len(data) - width + j] - line[j] for j in range(width)])
            agree = np.abs(after - before) < 0.25 * limit
            spike = np.all(np.abs(off) > limit, axis=0) & agree
            spike &= np.all(np.sign(off) == np.sign(off[0]), axis=0)
            for row, channel in zip(*np.nonzero(spike), strict=True):
                for j in range(width):
                    k = row + 1 + j
                    size = float(data[k, channel] - line[j][row, channel])
                    found.append((k, names[channel], size, abs(size) / limit))
                    data[k, channel] = line[j][row, channel]
    if not found:
        return imu
    k, channel, size, _ = max(found, key=lambda item: item[3])
    unit = "rad/s" if channel.startswith("gyro") else "m/s^2"
    samples = len({item[0] for item in found})
    warnings.append(
        f"{label}: {samples} isolated spike sample(s) (a channel departing from its "
        f"neighbours by more than a vehicle can turn or speed up in one sample) replaced by "
        f"the line through the neighbours; largest {channel} {size:+.4g} {unit} at "
        f"t-t_imu0 = {t[k] - t[0]:.2f} s"
    )
    return ImuData(t=t, gyro=gyro, accel=accel, suspect=imu.suspect, frame=imu.frame)


# A few samples whose stamp alone is far from its neighbours' (corrupt bytes in a recording's
# header stamp) are dropped, counted; more than this share of the samples is no damage but
# a log that mixes clocks or files.
MAX_STRAY_STAMP_SHARE = 0.005
STRAY_WINDOW = 4  # samples each side: up to four stray stamps in a row are found


def _without_stray_stamps(
    t: np.ndarray, gyro: np.ndarray, accel: np.ndarray, source: str, warnings: list[str]
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The samples without those whose time stamp lies more than MAX_REORDER_PERIODS
    periods from where its neighbours put it (the median over the nine samples around it
    of each stamp less its index times the period): a few corrupted header stamps in a bag
    refused the whole recording as "two clocks or files". A gap moves every stamp after it
    alike, and the median keeps each sample on its own side."""
    steps = np.diff(t)
    if not np.any(steps < 0) and (len(t) < 9 or not np.any(steps > 0)):
        return t, gyro, accel
    # the period of the stamps, whatever their order in the file (in order: no sort needed)
    positive = np.diff(np.sort(t)) if np.any(steps < 0) else steps
    positive = positive[positive > 0]
    if len(t) < 9 or not positive.size:
        return t, gyro, accel
    period = float(np.median(positive))
    reach = MAX_REORDER_PERIODS * period
    odd = np.flatnonzero((steps < 0) | (steps > reach))  # only near these can a stamp be stray
    if not odd.size:
        return t, gyro, accel
    near = np.unique(np.clip((odd[:, None] + np.arange(-STRAY_WINDOW + 1, STRAY_WINDOW + 1)).ravel(), 0, len(t) - 1))
    size = 2 * STRAY_WINDOW + 1
    start = np.clip(near - STRAY_WINDOW, 0, len(t) - size)  # the nine nearest, inside the log
    window = start[:, None] + np.arange(size)[None, :]
    level = t - np.arange(len(t)) * period
    stray = near[np.abs(level[near] - np.median(level[window], axis=1)) > reach]
    # A sample only received late (a bag's burst) fits, sorted, between two stamps a period
    # or so away; a corrupted stamp lands a fraction of a period from another, or alone.
    order = np.argsort(t, kind="stable")
    ordered, rank = t[order], np.empty_like(order)
    rank[order] = np.arange(len(t))
    at = rank[stray]
    before = np.where(at > 0, ordered[at] - ordered[np.maximum(at - 1, 0)], np.inf)
    after = np.where(at < len(t) - 1, ordered[np.minimum(at + 1, len(t) - 1)] - ordered[at], np.inf)
    closest = np.minimum(before, after)
    # ... and a corrupted stamp moves its sample out of its place in the file: a sample in
    # its place with a gap beside it is real (KITTI's first sample, 1.9 s before the second).
    stray = stray[((closest < 0.5 * period) | (closest > reach)) & (at != stray)]
    if not stray.size or stray.size > MAX_STRAY_STAMP_SHARE * len(t):
        return t, gyro, accel
    keep = np.ones(len(t), dtype=bool)
    keep[stray] = False
    first = int(stray[0])
    kept = np.flatnonzero(keep)
    after = kept[np.searchsorted(kept, first)] if first < kept[-1] else kept[-1]
    warnings.append(
        f"{source}: dropped {stray.size} IMU sample(s) whose time stamp alone lies far from its "
        f"neighbours' (corrupted stamps; the first, sample {first}, at {t[first]:.6f} where its "
        f"neighbours put it near {t[after] - (after - first) * period:.6f})"
    )
    return t[keep], gyro[keep], accel[keep]


def _few_out_of_place(t: np.ndarray) -> bool:
    """Whether sorting ``t`` moves at most MAX_STRAY_STAMP_SHARE of its samples: the fewest
    to take out for the rest to be in order, ``len - the longest increasing run`` (patience
    sorting, n log n). Two files one after the other move a whole stretch; messages whose log
    time was corrupted, or a chunk read out of order, move a few."""
    import bisect

    limit = MAX_STRAY_STAMP_SHARE * len(t)
    if np.count_nonzero(np.diff(t) < 0) > 2 * limit:  # each sample moved ends at most two
        return False  # steps back: shuffled rows are refused without the walk below
    tails: list[float] = []
    for value in t.tolist():
        at = bisect.bisect_left(tails, value)
        if at == len(tails):
            tails.append(value)
        else:
            tails[at] = value
    return len(t) - len(tails) <= limit


def _one_series_out_of_order(sorted_steps: np.ndarray) -> bool:
    """Whether stamps that go back are one clock's series received out of order (a bag's
    transport delivered bursts late): sorted, no step is shorter than half the period (but
    in one sample in a thousand). A log recorded twice repeats its
    stamps; two overlapping files interleave; a corrupted stamp lands between two others:
    each leaves steps of a fraction of a period. ``sorted_steps``: the sorted stamps'
    steps."""
    steps = sorted_steps
    positive = steps[steps > 0]
    if not positive.size:
        return False
    short = int(np.count_nonzero(steps < 0.5 * float(np.median(positive))))
    return short <= 0.001 * len(steps)


def _check_shared_stamps(t: np.ndarray, source: str) -> None:
    """Sorted IMU times of which most repeat the one before: an error naming why, not most
    of the IMU dropped as repeated samples (whole seconds at 100 Hz ran at 1 Hz on 1 % of
    the data with a warning only). Times that are whole multiples of their spacing were
    rounded; times that are not came in groups sharing one stamp (a driver that stamps each
    read of a buffer, not each sample: an outside tester's MCAP kept 3,001 of 30,001 samples
    at 10 Hz, 1.4 m off at z 4.5, where the same stamps in a CSV were refused). A few
    repeated rows (a logger hiccup) stay the caller's counted warning."""
    if t.size < 3:
        return
    repeated = int(np.count_nonzero(np.diff(t) == 0))
    if repeated <= 0.5 * (t.size - 1):
        return
    distinct = np.unique(t)
    if distinct.size < 2:
        raise InputError(
            f"{source}: all {t.size} IMU samples have the same time ({t[0]:.6f}); give each "
            "sample its own time, in seconds with fractional digits"
        )
    spacing = np.diff(distinct)
    resolution = float(np.min(spacing))
    per_time = t.size / distinct.size
    multiples = distinct / resolution  # rounded times lie on their resolution's grid
    if np.all(np.abs(multiples - np.round(multiples)) < 1e-3):
        raise InputError(
            f"{source}: {repeated} of {t.size} IMU samples repeat the time of the one before "
            f"(about {per_time:.0f} per time): the timestamps have {resolution:.3g} s "
            "resolution, coarser than the IMU's sample period; write them with fractional "
            "seconds (e.g. 12.345678), not rounded"
        )
    raise InputError(
        f"{source}: {repeated} of {t.size} IMU samples share their time with the one before, "
        f"in groups of about {per_time:.0f} ({float(np.median(spacing)):.3g} s between the "
        "groups' times): the stamps are when a driver read a buffer of samples, not when "
        "each was taken; give each sample its own time (the group's time less its place "
        "from the group's end times the sample period)"
    )


# Intervals under this share of the mean sample period are a burst's; more than
# BURST_SHARE of them (bursts of 2 give half) is stamps taken on receipt. Jitter of half a
# period gives 2 % of them.
BURST_INTERVAL = 0.2
BURST_SHARE = 0.4


def _check_bursts(t: np.ndarray, source: str) -> None:
    """Sorted, distinct IMU times that come in bursts: most intervals a small part of the
    mean period, the rest several periods (a PC logger stamping each sample as the USB or
    serial driver hands over a buffer). Integrated so, every burst's gap was a "gap" bridged
    with inflated noise (an outside tester's 4 Hz bursts: 1,200 gaps over the whole drive,
    2.4 m off at z 4.7 and two corrections made on them). An error naming the bursts: the
    samples' own times cannot be recovered from their receipt times here."""
    if t.size < 20:
        return
    step = np.diff(t)
    mean = float(t[-1] - t[0]) / (t.size - 1)
    short = step < BURST_INTERVAL * mean
    if np.count_nonzero(short) <= BURST_SHARE * step.size:
        return
    long = step[~short]
    per_burst = step.size / max(long.size, 1)
    raise InputError(
        f"{source}: {np.count_nonzero(short)} of {step.size} IMU intervals are under "
        f"{BURST_INTERVAL:g} of the mean sample period ({mean:.3g} s), the others "
        f"{float(np.median(long)):.3g} s: the samples come in bursts of about "
        f"{per_burst:.0f}, stamped when they were received, not when each was taken; give each "
        "sample its own time (spaced by the sample period: t0 + k / rate where none is lost)"
    )


def imu_from_samples(
    t: np.ndarray, gyro: np.ndarray, accel: np.ndarray, *, source: str, warnings: list[str]
) -> ImuData:
    """:class:`ImuData` from a reader's arrays, with the row repairs the data model needs.

    NaN/inf rows are dropped (counted); samples a few periods out of order are sorted (counted);
    exact repeated timestamps are dropped (counted); time that goes back further (two clocks or
    files in one log) is an :class:`InputError`.
    """
    t = np.asarray(t, dtype=float)
    gyro = np.asarray(gyro, dtype=float).reshape(-1, 3)
    accel = np.asarray(accel, dtype=float).reshape(-1, 3)
    finite = np.isfinite(t) & np.all(np.isfinite(gyro), axis=1) & np.all(np.isfinite(accel), axis=1)
    if not finite.all():
        warnings.append(f"{source}: dropped {int((~finite).sum())} IMU row(s) with NaN/inf values")
        t, gyro, accel = t[finite], gyro[finite], accel[finite]
    if len(t) < 2:
        raise InputError(f"{source}: fewer than 2 valid IMU samples; check the recording")
    t, gyro, accel = _without_stray_stamps(t, gyro, accel, source, warnings)
    dt = np.diff(t)
    backwards = np.flatnonzero(dt < 0)
    if backwards.size:
        # The period from the sorted times: a file's shuffled rows have huge forward steps
        # too, and their median passed a 119 s step back as a reordering.
        sorted_dt = np.diff(np.sort(t))
        positive = sorted_dt[sorted_dt > 0]
        nominal = float(np.median(positive)) if positive.size else 0.0
        worst = int(backwards[np.argmin(dt[backwards])])
        far = -dt[worst] > MAX_REORDER_PERIODS * nominal
        # a few samples out of place, however far (a message's log time corrupted puts it
        # at the file's start), or bursts received up to MAX_LATE_DELIVERY_S late; two files
        # or a week's rollover put a whole stretch after a later one
        row = worst + 1
        rollover = WEEK_S - 3600.0 < t[row - 1] <= WEEK_S + 1.0 and t[row] < 3600.0
        # Seconds of the day (a logger stamping UTC time of day, as NMEA does) wrap at midnight:
        # "sort or split it" had been the advice (outside tester).
        midnight = DAY_S - 3600.0 < t[row - 1] <= DAY_S + 1.0 and t[row] < 3600.0
        late = -dt[worst] <= MAX_LATE_DELIVERY_S
        if far and (rollover or midnight or not (late or _few_out_of_place(t)) or not _one_series_out_of_order(sorted_dt)):
            if rollover:
                raise InputError(
                    f"{source}: IMU time goes from {t[row - 1]:.6f} back to {t[row]:.6f} at "
                    f"sample {row}: GPS seconds of the week rolling over into a new week; add "
                    f"{WEEK_S:.0f} s to the times from there on (or give GPS or POSIX seconds)"
                )
            if midnight:
                raise InputError(
                    f"{source}: IMU time goes from {t[row - 1]:.6f} back to {t[row]:.6f} at "
                    f"sample {row}: seconds of the day wrapping at midnight; add {DAY_S:.0f} s "
                    "to the times from there on (or give POSIX seconds)"
                )
            raise InputError(
                f"{source}: IMU time goes backwards at sample {row} "
                f"({t[row - 1]:.6f} -> {t[row]:.6f}); the log mixes clocks or files — sort or "
                "split it"
            )
        order = np.argsort(t, kind="stable")
        t, gyro, accel = t[order], gyro[order], accel[order]
        warnings.append(
            f"{source}: {backwards.size} IMU time step(s) backwards by at most "
            f"{-dt[worst] * 1e3:.1f} ms; samples sorted by time"
            + (", their stamps one regular series (received or written out of order)" if far else "")
        )
    _check_shared_stamps(t, source)
    _check_bursts(t, source)
    duplicate = np.concatenate([[False], np.diff(t) == 0])
    if duplicate.any():
        warnings.append(
            f"{source}: dropped {int(duplicate.sum())} IMU sample(s) with repeated time"
        )
        t, gyro, accel = t[~duplicate], gyro[~duplicate], accel[~duplicate]
    if len(t) < 2:
        raise InputError(f"{source}: fewer than 2 valid IMU samples; check the recording")
    return ImuData(t=t, gyro=gyro, accel=accel)


# A channel saturates at its measuring range: its samples sit on one extreme value, several
# in a row, while the motion goes on beyond it. Ranges start at +-125 deg/s (2.2 rad/s) and
# +-2 g; below these floors a repeated extreme is an IMU at rest, not a range.
SATURATION_FLOOR = {"gyro": 1.5, "accel": 15.0}  # rad/s, m/s^2
SATURATION_MIN_RUN = 3  # samples in a row on the extreme
CHANNELS = ("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z")


@dataclass(frozen=True)
class Saturation:
    """Runs of one channel's samples held at its extreme value (the sensor's range)."""

    channel: str
    extreme: float
    runs: list[tuple[int, int]]  # sample index ranges [first, last]

    @property
    def samples(self) -> int:
        return sum(b - a + 1 for a, b in self.runs)


def _smooth(column: np.ndarray) -> bool:
    """A channel without sensor noise: away from its extremes, its second differences are far
    below its first ones (white noise gives ~1.4x them on average, a smooth signal ~w dt),
    or it never changes."""
    at = (column == column.max()) | (column == column.min())
    first = np.abs(np.diff(column))[~(at[:-1] | at[1:])]
    second = np.abs(np.diff(column, 2))[~(at[:-2] | at[1:-1] | at[2:])]
    if not first.size or not first.any():
        return True
    return bool(second.size) and float(second.mean()) < 0.3 * float(first.mean())


def find_saturation(data: np.ndarray) -> list[Saturation]:
    """Channels of ``data`` (N, 6: gyro then accel) that sit on their maximum or minimum
    value for SATURATION_MIN_RUN samples in a row, beyond SATURATION_FLOOR. Real noise never
    repeats a large value exactly; a clipped sensor does, run after run. Data with no noise on
    any channel (a noise-free simulation, whose steady fast roll repeats its rate exactly)
    are not judged: a vehicle's real IMU always has noise and vibration somewhere."""
    if len(data) < 3 or all(_smooth(data[:, j]) for j in range(data.shape[1])):
        return []
    found = []
    for j, channel in enumerate(CHANNELS):
        column = data[:, j]
        floor = SATURATION_FLOOR[channel.split("_")[0]]
        for extreme in {float(np.max(column)), float(np.min(column))}:
            if abs(extreme) < floor:
                continue
            at = np.abs(column - extreme) <= 1e-9 * abs(extreme)
            runs = [(a, b - 1) for a, b in true_runs(at) if b - a >= SATURATION_MIN_RUN]
            if runs:
                found.append(Saturation(channel, extreme, runs))
    return found


def flag_suspect(imu: ImuData, warnings: list[str], *, label: str = "imu") -> ImuData:
    """``imu`` with gaps, linearly filled stretches and saturated runs added to ``suspect``
    (one line each)."""
    t = imu.t
    suspect: list[tuple[float, float]] = list(imu.suspect)
    from fgins.factors.imu_samples import rate_changes

    if changes := rate_changes(t):
        warnings.append(
            f"{label}: the IMU's rate changes {len(changes)} time(s) ("
            + ", ".join(f"{a:.4g} -> {b:.4g} Hz at t-t_imu0 = {at - t[0]:.0f} s" for at, a, b in changes[:3])
            + (", ..." if len(changes) > 3 else "")
            + "): each part integrated at its own rate"
        )
    gaps = find_gaps(t)
    if gaps:
        total = sum(b - a for a, b in gaps)
        longest = max(b - a for a, b in gaps)
        warnings.append(
            f"{label}: {len(gaps)} IMU gap(s) longer than {GAP_FACTOR:g} sample periods "
            f"({total:.2f} s in all, the longest {longest:.2f} s); bridged with inflated noise "
            "up to [smoother] max_imu_gap_s"
        )
        suspect.extend(gaps)
    fills = find_linear_fills(t, np.column_stack([imu.gyro, imu.accel]))
    if fills:
        total = sum(b - a for a, b in fills)
        warnings.append(
            f"{label}: {len(fills)} stretch(es) of linearly interpolated IMU samples "
            f"({total:.1f} s in all, at t-t_imu0 = "
            + ", ".join(f"{a - t[0]:.0f}" for a, _ in fills)
            + " s); treated as gaps with inflated noise"
        )
        suspect.extend(fills)
    last = len(t) - 1
    for found in find_saturation(np.column_stack([imu.gyro, imu.accel])):
        # A held sample stands for its interval up to the next one.
        spans = [(float(t[a]), float(t[min(b + 1, last)])) for a, b in found.runs]
        unit, shown = (
            ("deg/s", np.degrees(found.extreme))
            if found.channel.startswith("gyro")
            else ("g", found.extreme / STANDARD_GRAVITY)
        )
        warnings.append(
            f"{label}: {found.channel} sits on {found.extreme:+.6g} ({shown:+.4g} {unit}) in "
            f"{len(spans)} run(s) of {SATURATION_MIN_RUN} or more samples ({found.samples} "
            f"samples, {sum(b - a for a, b in spans):.2f} s, first at t-t_imu0 = "
            f"{spans[0][0] - t[0]:.1f} s): the sensor saturated at its measuring range and the "
            "motion beyond it is lost; those stretches are treated as gaps with inflated "
            "noise (set the IMU to a wider range)"
        )
        suspect.extend(spans)
    return ImuData(
        t=imu.t, gyro=imu.gyro, accel=imu.accel, suspect=sorted(set(suspect)), frame=imu.frame
    )
