"""Checks of the IMU against the GNSS track (input-validation layer, :mod:`fgins.io.validate`):
units (IMU times, gyro in deg/s, accelerometer in g), the gyro's turns against the track's
(signs, a dead gyro, clocks offset), GNSS velocity and wheel speed against the fixes, frozen
or shrunk tracks. GTSAM-free."""

from __future__ import annotations

import math
from dataclasses import replace
from statistics import NormalDist

import numpy as np

from fgins.datatypes import GnssData, InputError, Origin, median_interval
from fgins.factors.stationary import true_runs
from fgins.io.gnss_checks import VELOCITY_SPEED_RATIO_RANGE, fix_sigma, horizontal_fix_sigma
from fgins.io.imu_checks import second_means

# Units. In rad/s no vehicle's rate is routinely (10 % of the time) above 10 rad/s; integrated
# over a turn the GNSS track shows, a rad/s gyro gives ~1x the turn, a deg/s one 57x.
GYRO_ROUTINE_MAX_RAD_PER_S = 10.0
GYRO_TURN_RATIO_MAX = 8.0
GYRO_TURN_RATIO_MIN = 0.25  # a right gyro gives 0.7-1.25 (median over the turns)
TURN_WINDOW_S = 10.0
TURN_MIN_RAD = 0.5  # a turn far above the course noise of the window's end points
TURN_MIN_SPEED_M_PER_S = 3.0
# A course from a chord this many of its noise sigmas long (0.33 rad at most); a turn this
# many sigmas of the two courses' noise.
COURSE_MIN_CHORD_SIGMAS = 3.0
TURN_MIN_SIGMAS = 2.0
# Windows are chosen by their own course change: at k sigmas the noise alone passes a share
# 2 (1 - Phi(k)) of the straight ones, so k rises with their number until noise is expected
# to pass fewer than this many windows over the drive (a boat at 4-5 m/s with 10 Hz fixes of
# 5 m: at 2 sigmas, 5 of 120 straight windows passed as "turns" the gyro did not see, 0.185
# times, and valid data were refused).
NOISE_TURNS_EXPECTED = 0.05
REVERSAL_TOL_RAD = math.radians(40.0)  # a window's course flip within this of 180 deg: a reversal
# A course step between chords 2.5 s apart above this: a reversal (a car turning at 0.5 rad/s
# steps 72 deg; reversing while turning so, 108 deg).
REVERSAL_STEP_MIN_RAD = math.radians(100.0)
TURN_MIN_WINDOWS = 1  # ratio > 8 needs > 4 rad of gyro rotation in one window: not noise
# Without turns: the gyro integrated over a window of straight driving stays below this
# (biases of 1 deg/s and body oscillations give ~0.2 rad in 10 s; deg/s values give rad-sized).
STRAIGHT_MAX_ROTATION_RAD = 1.5
# At rest a gyro reads its bias plus Earth rate: 0.2 rad/s (11 deg/s) is beyond any real gyro
# bias (consumer MEMS: < 5 deg/s), while a 0.2-deg/s bias read as rad/s is exactly this.
GYRO_REST_MAX_RAD_PER_S = 0.2
# A multirotor's or pedestrian's gyro need not follow the track's turns, but it is alive:
# its rates vary (tilting to accelerate, own yaw) by more than this at the 90th percentile
# about their median; a dead gyro (noise only) or one converted to rad/s twice (57x too
# small) varies by less.
GYRO_ALIVE_RAD_PER_S = 0.02
REST_ACCEL_STD_M_S2 = 0.05
REST_ACCEL_NORM_TOL_M_S2 = 0.3
STRAIGHT_MIN_WINDOWS = 10
G = 9.80665
ACCEL_G_RANGE = (0.5, 2.0)  # a median specific-force norm here is g, not m/s^2
ACCEL_PLAUSIBLE_RANGE = (5.0, 20.0)  # m/s^2: gravity plus any vehicle's mean acceleration
# No IMU samples slower than 1 Hz: samples 10 or 1e7 "seconds" apart are times in ms or ns.
IMU_MAX_SAMPLE_INTERVAL_S = 1.0
# In the clear turns, the gyro's rotation about up must turn the way the track does: over the
# track's turn it gives ~+1 (median over the turns), ~-1 when its sign is reversed.
TURN_SIGN_MIN_RATIO = -0.3
TURN_SIGN_MIN_WINDOWS = 3
# GNSS velocity against the track of the fixes (chords of VELOCITY_CHORD_S, moving epochs):
# speed ratio ~1 (km/h gives 3.6, knots 1.94), direction within a few degrees (east and north
# swapped mirror it), and the climb rate against the altitude's (feet give 3.28, NED's down
# -1) where the vehicle climbs and sinks enough to tell.
VELOCITY_CHORD_S = 4.0
VELOCITY_MIN_EPOCHS = 10
VELOCITY_MAX_ANGLE_DEG = 25.0
CLIMB_MIN_STD_M_S = 1.0
CLIMB_RATIO_RANGE = (0.6, 1.6)
CLIMB_MIN_CORRELATION = 0.5


# --------------------------------------------------------------------------------------------
# Units
# --------------------------------------------------------------------------------------------


def check_imu_time_unit(t: np.ndarray) -> None:
    if t.size < 2:
        return
    interval = float(np.median(np.diff(t)))
    if interval > IMU_MAX_SAMPLE_INTERVAL_S:
        raise InputError(
            f"imu: the samples are {interval:.6g} time units apart ({1 / interval:.3g} Hz): no "
            f"IMU samples that slowly; the times look like {_likely_time_unit(interval)}, give "
            "them in seconds (and the GNSS times on the same clock)"
        )


def _likely_time_unit(interval: float) -> str:
    """The units in which ``interval`` (a median IMU sample spacing) is that of an IMU of
    1-4000 Hz: a 100 Hz log in ms is 10 units apart, in us 1e4, in ns 1e7."""
    units = [name for name, per_second in (("milliseconds", 1e3), ("microseconds", 1e6),
                                           ("nanoseconds", 1e9))
             if 1.0 <= per_second / interval <= 4000.0]  # fmt: skip
    if not units:
        return "another unit than seconds"
    return " or ".join(units)


SHORT_IMU_S = 10.0  # an IMU record shorter than this cannot show the heading or the biases

# A multirotor or a pedestrian need not yaw with its track (a drone circles with its nose
# held): for them a gyro that does not follow the track's turns is a note, not an error.
FREE_BODY_VEHICLES = ("uav", "pedestrian")


# The specific force an accelerometer array's readings solve to, median norm (m/s^2): gravity
# within ~12 % (a vehicle's own accelerations raise it a little; an automotive-grade array's
# runaway rates move it by centripetal terms: 9.60 on a 5-min drive). Two columns swapped or one
# accelerometer dead gave 7.75 over the first minute (the rates it derives then run away:
# 163 over five minutes), within the band a single IMU gets for its scale errors.
ARRAY_FORCE_RANGE = (8.5, 11.0)


def _note_constant_channels(imu, checks: list[str]) -> None:
    """A warning for each IMU axis that reads one value in every sample: a dead or missing
    axis (a real sensor's noise moves every axis), unless the data were simulated without
    noise (a level car's roll and pitch rates are then exactly 0, and valid). A gyro_y
    column of zeros on a hilly drive ran to "batch LM diverged" blamed on the GNSS sigmas."""
    if len(imu.t) < 100:
        return
    for kind, samples in (("gyro", imu.gyro), ("accel", imu.accel)):
        for axis, name in enumerate("xyz"):
            column = samples[:, axis]
            if np.all(column == column[0]):
                checks.append(
                    f"imu: {kind}_{name} reads {column[0]:g} in every one of {len(column)} "
                    "samples: a dead or missing axis (a real sensor's noise moves every axis) "
                    "unless the data are simulated without noise; a wrong axis makes the "
                    "solution drift and fit badly"
                )


def check_accel_units(imu, *, has_accel_array: bool) -> None:
    """The accelerometer's unit from its median specific-force norm (gravity's 9.8 m/s^2):
    in g, swapped with the gyro's columns, or another unit or scale. Before the checks that
    compare the IMU with the track: an accelerometer in mg read as a car turning at 100
    times its speed, and was called lat/lon in radians (outside tester)."""
    accel_norm = np.linalg.norm(imu.accel, axis=1)
    median_accel = float(np.median(accel_norm))
    median_gyro = float(np.median(np.linalg.norm(imu.gyro, axis=1)))
    # Swapped columns: gravity in the gyro's, rates (not g: below its range) in the accel's.
    rate_like = median_accel < ACCEL_G_RANGE[0]
    if rate_like and ACCEL_PLAUSIBLE_RANGE[0] <= median_gyro <= ACCEL_PLAUSIBLE_RANGE[1]:
        raise InputError(
            f"imu: the gyro and accelerometer columns look swapped: the gyro's median norm is "
            f"{median_gyro:.3g} (gravity's 9.8 m/s^2) and the accelerometer's {median_accel:.3g}; "
            "the columns are time, gyro_x, gyro_y, gyro_z (rad/s), accel_x, accel_y, accel_z "
            "(m/s^2), matched by their header names"
        )
    if ACCEL_G_RANGE[0] <= median_accel <= ACCEL_G_RANGE[1]:
        raise InputError(
            f"imu: the accelerometer is in g, not m/s^2: its median specific-force norm is "
            f"{median_accel:.3f} (gravity alone gives 9.81 m/s^2, i.e. 1 g); multiply "
            f"{'a1..aN' if has_accel_array else 'accel_x, accel_y, accel_z'} by {G} before "
            "giving them to fgins"
        )
    plausible = ARRAY_FORCE_RANGE if has_accel_array else ACCEL_PLAUSIBLE_RANGE
    if not plausible[0] <= median_accel <= plausible[1]:
        if has_accel_array:  # its specific force is solved from N readings and the geometry
            raise InputError(
                f"accel_array: the specific force solved from the accelerometers has a median "
                f"norm of {median_accel:.4g}, not the ~9.8 m/s^2 of gravity: the columns a1..aN "
                "do not match the [accel_array] geometry (order, positions, sensing axes), an "
                "accelerometer is dead, or the readings are not in m/s^2"
            )
        raise InputError(
            f"imu: the accelerometer's median specific-force norm is {median_accel:.4g}, not "
            f"the ~9.8 m/s^2 of gravity: a wrong unit or scale factor; give accel_x..z in m/s^2"
        )


ARRAY_TURN_RATIO_MIN = 0.2  # see check_units


def check_units(
    imu,
    gnss: GnssData,
    origin: Origin,
    checks: list[str],
    *,
    has_accel_array: bool,
    body_follows_track: bool = True,
) -> None:
    if not has_accel_array:
        _note_constant_channels(imu, checks)
    if has_accel_array:
        # Rates derived from an accelerometer array carry a large, ramping bias by nature;
        # their unit follows from the accelerometers' (check_accel_units, run before). Their
        # scale follows from the positions, whose unit does not: given in cm the rates are
        # 100x small, and a run went on to 103 m off at z 16 blaming a 62 m antenna arm and
        # two clocks (outside tester). A ramp adds turn, it does not take it away: derived
        # rates turn 2.4-125x the track on right arrays, 0.09-0.13x with positions in cm.
        ratio, turns, _ = _gyro_turn_ratio(imu, gnss, origin)
        if turns >= TURN_MIN_WINDOWS and ratio < ARRAY_TURN_RATIO_MIN:
            raise InputError(
                f"accel_array: the rates derived from the accelerometers integrate to "
                f"{ratio:.2g} times the turn the fixes show over {turns} "
                f"{turn_window_s(gnss.t):g}-s windows: the [accel_array] positions_m are not "
                "in metres (cm give 0.01x, mm 0.001x) or the geometry does not fit the columns"
            )
        return
    gyro_norm = np.linalg.norm(imu.gyro, axis=1)
    routine = float(np.percentile(gyro_norm, 90))
    if routine > GYRO_ROUTINE_MAX_RAD_PER_S:
        raise InputError(
            f"imu: the gyro looks like deg/s, not rad/s: 10 % of its rates exceed {routine:.1f} "
            f"(no vehicle turns at {routine:.0f} rad/s routinely); multiply gyro_x, gyro_y, "
            f"gyro_z by pi/180 = {math.pi / 180:.6f}"
        )
    at_rest = _gyro_at_rest(imu, gnss, origin)
    if at_rest > GYRO_REST_MAX_RAD_PER_S:
        raise InputError(
            f"imu: the gyro looks like deg/s, not rad/s: it reads {at_rest:.2f} while the "
            f"accelerometer shows the IMU at rest (a bias of {math.degrees(at_rest):.0f} deg/s, "
            f"far beyond any gyro's); multiply gyro_x, gyro_y, gyro_z by "
            f"pi/180 = {math.pi / 180:.6f}"
        )
    ratio, turns, turn_sign = _gyro_turn_ratio(imu, gnss, origin)
    if turns >= TURN_MIN_WINDOWS and ratio > GYRO_TURN_RATIO_MAX:
        raise InputError(
            f"imu: the gyro looks like deg/s, not rad/s: over {turns} {turn_window_s(gnss.t):g}-s windows "
            f"of the GNSS track it integrates to {ratio:.1f} times the turn the fixes show "
            f"(57.3 for deg/s, ~1 for rad/s); multiply gyro_x, gyro_y, gyro_z by "
            f"pi/180 = {math.pi / 180:.6f}"
        )
    problems = []
    gyro_alive = (
        float(np.percentile(np.linalg.norm(imu.gyro - np.median(imu.gyro, axis=0), axis=1), 90))
        > GYRO_ALIVE_RAD_PER_S
    )
    if (
        turns >= TURN_SIGN_MIN_WINDOWS
        and ratio < GYRO_TURN_RATIO_MIN
        and (body_follows_track or not gyro_alive)
    ):
        problems.append(
            f"imu: the gyro does not see the turns: over {turns} {turn_window_s(gnss.t):g}-s windows of "
            f"the GNSS track it integrates to {ratio:.3g} times the turn the fixes show (~1 "
            "expected; 0.017 if rad/s were converted to rad/s again, 0 for a dead gyro), or "
            "the IMU and GNSS clocks are offset (give --time-offset SECONDS)"
        )
    # A multirotor or a walker may yaw against its track (outside tester: every valid
    # multirotor flight got this note): only a body that follows its track is judged.
    if body_follows_track and turns >= TURN_SIGN_MIN_WINDOWS and turn_sign < TURN_SIGN_MIN_RATIO:
        problems.append(
            f"imu: the gyro turns against the GNSS track: over {turns} turns its rotation about "
            "up (the direction of the accelerometer's mean reading) is "
            f"{turn_sign:.2f} times the track's (~+1 expected); the accelerometer must give "
            "specific force (+9.8 m/s^2 along up at rest, not the acceleration -9.8) and the "
            "axes must be right-handed (a flipped axis sign flips the turn); or latitude and "
            "longitude are swapped (a mirrored track), or the IMU and GNSS clocks are offset "
            "(give --time-offset SECONDS)"
        )
    if problems and body_follows_track:
        raise TurnsDisagree(
            problems[0] + "; a multirotor or a pedestrian, which need not yaw with the track: "
            "--vehicle uav or pedestrian"
        )
    checks.extend(f"{problem} (a {'/'.join(FREE_BODY_VEHICLES)} need not yaw with its track: "
                  "checked, not refused)" for problem in problems)  # fmt: skip


class TurnsDisagree(InputError):
    """The gyro's turns do not match the track's (size or sense): units, axes, a mirrored
    track or offset clocks."""


def clock_offset_explains_turns(
    imu, gnss: GnssData, enu: np.ndarray, up: np.ndarray, origin: Origin,
    given_offset_s: object, *, banks: bool,
) -> None:
    """Raise the clock-offset error when the gyro's turns disagree with the track's at the
    stamped times but agree (size and sense) once the fixes are moved by the offset the
    turns show. A mirrored track (lat/lon swapped) lines up best somewhere too (a false
    -14 s at 2.2x): it still disagrees there, and the caller's error stands."""
    if (sharp := _clock_error_from_velocities(imu, gnss, enu, up, origin, given_offset_s, banks=banks)) is not None:
        raise InputError(sharp)
    lag, verdict = _clock_verdict(imu, gnss, enu, up, given_offset_s, banks=banks)
    if verdict is None or verdict[0] != "error":
        return
    moved = replace(gnss, t=gnss.t + lag)
    ratio, turns, turn_sign = _gyro_turn_ratio(imu, moved, origin)
    agree = GYRO_TURN_RATIO_MIN <= ratio <= GYRO_TURN_RATIO_MAX and turn_sign >= -TURN_SIGN_MIN_RATIO
    if turns >= TURN_SIGN_MIN_WINDOWS and agree:
        raise InputError(verdict[1])


def check_clock_offset(
    imu, gnss: GnssData, enu: np.ndarray, up: np.ndarray, origin: Origin, checks: list[str],
    given_offset_s: object, *, banks: bool = False,
) -> None:
    """The GNSS clock against the IMU's from the drive's turns (:mod:`fgins.io.clock_offset`):
    an offset of seconds is an error naming the --time-offset that aligns them (KITTI with 3 s
    added ran 29 s to a fit blamed on the lever arm and the mounting), a fraction of a second
    a warning. Only for a body that yaws with its track (not a multirotor or a walker)."""
    if (sharp := _clock_error_from_velocities(imu, gnss, enu, up, origin, given_offset_s, banks=banks)) is not None:
        raise InputError(sharp)
    _, verdict = _clock_verdict(imu, gnss, enu, up, given_offset_s, banks=banks)
    if verdict is None:
        return
    kind, message = verdict
    if kind == "error":
        raise InputError(message)
    checks.append(message)


def _clock_error_from_velocities(
    imu, gnss: GnssData, enu: np.ndarray, up: np.ndarray, origin: Origin, given_offset_s: object,
    *, banks: bool,
) -> str | None:
    """The clock-offset error from the receiver's velocities, where most fixes have one: their
    course is far sharper than a chord of noisy fixes (a 2-min urban drive with 3 m fixes, 18 s
    of GPS time against UTC: the chords' best lag -27.5, +13.2 or -18.2 s at 1.4-1.6x, and one
    such run went on to a solution 18 s off; the velocities' -17.8 to -17.9 s at 280-460x). A
    receiver's velocity may lag its positions (0.5-2.5 s: differences of 1-0.2 Hz fixes, or
    smoothed), so only an offset of CLOCK_VELOCITY_MIN_LAG_S or more, and only where the
    fixes' own track, moved by it, turns with the gyro too."""
    from fgins.io.clock_offset import (
        CLOCK_VELOCITY_MIN_LAG_S,
        ERROR_MIN_IMPROVEMENT,
        MIN_TURNING_WINDOWS,
        estimate_clock_offset,
    )

    if gnss.velocity is None:
        return None
    horizontal = gnss.velocity[:, :2]
    if np.all(np.isfinite(horizontal), axis=1).mean() < 0.8:
        return None
    offset = estimate_clock_offset(imu.t, imu.gyro @ up, gnss.t, enu[:, :2], horizontal)
    if (
        offset is None
        or abs(offset.lag_s) < CLOCK_VELOCITY_MIN_LAG_S
        or offset.improvement < ERROR_MIN_IMPROVEMENT
        or offset.windows < MIN_TURNING_WINDOWS
    ):
        return None
    ratio, turns, turn_sign = _gyro_turn_ratio(imu, replace(gnss, t=gnss.t + offset.lag_s), origin)
    if not (turns >= TURN_SIGN_MIN_WINDOWS and GYRO_TURN_RATIO_MIN <= ratio <= GYRO_TURN_RATIO_MAX
            and turn_sign >= -TURN_SIGN_MIN_RATIO):  # fmt: skip
        return None
    given = float(given_offset_s) if isinstance(given_offset_s, (int, float)) else 0.0
    return (
        f"time: the receiver's velocities turn with the gyro when the fixes are moved by "
        f"{offset.lag_s:+.2f} s ({offset.improvement:.3g}x closer than as stamped, over "
        f"{offset.windows} turning 4-s windows; the fixes' own track agrees): the IMU and GNSS "
        f"clocks differ (GPS time against UTC is 18 s); give --time-offset {given + offset.lag_s:+.2f}"
        + (" (from a banking aircraft's turns this is good to about 2 s)" if banks else "")
    )


def _clock_verdict(
    imu, gnss: GnssData, enu: np.ndarray, up: np.ndarray, given_offset_s: object, *, banks: bool
) -> tuple[float, tuple[str, str] | None]:
    """(the lag the turns show, s; :func:`fgins.io.clock_offset.judge`'s verdict on it)."""
    from fgins.io.clock_offset import clock_rate, estimate_clock_offset, judge

    offset = estimate_clock_offset(imu.t, imu.gyro @ up, gnss.t, enu[:, :2])
    given = float(given_offset_s) if isinstance(given_offset_s, (int, float)) else 0.0
    verdict = judge(offset, given, banks=banks)
    if verdict is not None and verdict[0] == "error" and not banks:
        rate = clock_rate(imu.t, imu.gyro @ up, gnss.t, enu[:, :2])
        if rate is not None:
            first, last, per_second = rate
            verdict = ("error", (
                f"time: the GNSS track's turns line up with the gyro's when the fixes are moved "
                f"by {first:+.2f} s over the first half of the drive and {last:+.2f} s over the "
                f"second: the IMU's clock runs {100 * per_second:+.2f} % against the receiver's (an "
                "IMU stamped by its sample count at a nominal rate, or a logger's oscillator), "
                "which no --time-offset aligns; stamp the IMU samples on the receiver's clock "
                f"(its times scaled by {1 / (1 + per_second):.6f} about the first fix, if the rate "
                "is steady)"
            ))  # fmt: skip
    return (offset.lag_s if offset else 0.0), verdict


def _chord_velocity(
    gnss: GnssData, enu: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The velocity the fixes' own VELOCITY_CHORD_S chords show, centred on each fix:
    (dense: the chord spans most of its length, velocity (N, 3), clear: a horizontal speed
    well above what the fixes' noise fakes over the chord and above TURN_MIN_SPEED_M_PER_S;
    a few satellites give tens of metres of scatter, "metres per second" at a standstill;
    noise: the RMS of the horizontal velocity error the fixes' noise gives the chord)."""
    t = gnss.t
    a = np.searchsorted(t, t - VELOCITY_CHORD_S / 2)
    b = np.clip(np.searchsorted(t, t + VELOCITY_CHORD_S / 2, side="right") - 1, 0, len(t) - 1)
    span = t[b] - t[a]
    dense = span > 0.75 * VELOCITY_CHORD_S
    sigma = horizontal_fix_sigma(gnss)
    with np.errstate(invalid="ignore", divide="ignore"):
        velocity = (enu[b] - enu[a]) / span[:, None]
        noise = np.sqrt(sigma[a] ** 2 + sigma[b] ** 2) / span
        speed = np.hypot(velocity[:, 0], velocity[:, 1])
        clear = dense & np.isfinite(speed) & (speed > np.maximum(TURN_MIN_SPEED_M_PER_S, 3 * noise))
    return dense, velocity, clear, noise


def check_wheel_time_base(odometer, imu_t: np.ndarray, checks: list[str]) -> None:
    """Wheel samples beside the IMU's: none within its span is an error naming the spans
    (and milliseconds where the wheel's span is about 1,000 times the IMU's), some outside it
    a counted warning. (Outside tester: a wheel.csv in milliseconds, or on a clock 100 s off,
    was left unused without a word.)"""
    t = np.asarray(odometer.t, dtype=float)
    inside = (t >= imu_t[0]) & (t <= imu_t[-1])
    if inside.all():
        return
    # Milliseconds from a relative start overlap the IMU's seconds at their first samples.
    ratio = float(t[-1] - t[0]) / max(float(imu_t[-1] - imu_t[0]), 1e-9)
    milliseconds = 300.0 <= ratio <= 3000.0
    if milliseconds or not inside.any():
        hint = "its times look like milliseconds; " if milliseconds else ""
        within = f"{int(inside.sum())} of its {len(t)} samples ({t[0]:.3f}-{t[-1]:.3f} s) lie"
        if not inside.any():
            within = f"none of its {len(t)} samples ({t[0]:.3f}-{t[-1]:.3f} s) lies"
        raise InputError(
            f"wheel: {within} within the IMU's span ({imu_t[0]:.3f}-{imu_t[-1]:.3f} s): "
            f"{hint}give the wheel's times in seconds on the IMU's clock"
        )
    checks.append(
        f"wheel: {int((~inside).sum())} of {len(t)} samples lie outside the IMU's span "
        f"({imu_t[0]:.3f}-{imu_t[-1]:.3f} s) and are not used"
    )


def check_wheel_speed(odometer, gnss: GnssData, enu: np.ndarray) -> None:
    """The wheel speed against the speed the fixes' own 4-s chords show, where they move well
    beyond their noise: a median ratio outside 0.7-1.4 is a unit (km/h: the wheel-speed
    scale state took +260 % on a simulated car and the run said nothing but that number) or
    a wheel's angular rate. A wheel log beside no moving fix is not judged."""
    t = gnss.t
    dense, track, clear, _ = _chord_velocity(gnss, enu)
    track_speed = np.hypot(track[:, 0], track[:, 1])
    # Only where a wheel sample lies within half a second (a wheel log covering part of the
    # drive is judged where it is).
    nearest = np.clip(np.searchsorted(odometer.t, t), 1, len(odometer.t) - 1)
    close = np.minimum(np.abs(odometer.t[nearest] - t), np.abs(odometer.t[nearest - 1] - t))
    moving = dense & clear & (close <= 0.5)
    if moving.sum() < VELOCITY_MIN_EPOCHS:
        return
    signed = np.interp(t[moving], odometer.t, odometer.speed)
    if float(np.median(signed)) < 0.0:
        # A car reverses for moments; one that "reverses" most of its drive has the wheel
        # speed's sign flipped (read as a -200 % scale error, unsaid at load; outside tester).
        raise InputError(
            f"wheel: the wheel speed is negative at {100 * float(np.mean(signed < 0)):.0f} % of "
            f"the {int(moving.sum())} moving fixes: its sign is flipped (wheel_speed counts "
            "forward motion positive, reversing negative); negate the column"
        )
    wheel = np.abs(signed)
    ratio = float(np.median(wheel / track_speed[moving]))
    if not VELOCITY_SPEED_RATIO_RANGE[0] <= ratio <= VELOCITY_SPEED_RATIO_RANGE[1]:
        raise InputError(
            f"wheel: the wheel speed is {ratio:.3g} times the speed the fixes show (median "
            f"over {int(moving.sum())} moving fixes; ~1 expected: km/h gives 3.6, mph 2.24, a "
            "wheel's angular rate in rad/s about 3, pulses per second far more): give "
            "wheel_speed in m/s over ground"
        )


def _velocity_from_speed_course(gnss: GnssData) -> bool:
    """Whether the velocity is the horizontal one built from speed and course (CSV speed and
    course columns, NMEA RMC/VTG), so that a complaint names those, not vel_* columns."""
    if gnss.velocity is None or gnss.speed is None or gnss.course is None:
        return False
    if np.any(np.isfinite(gnss.velocity[:, 2])):
        return False
    course = np.radians(gnss.course)
    built = np.column_stack([gnss.speed * np.sin(course), gnss.speed * np.cos(course)])
    given = gnss.velocity[:, :2]
    both = np.all(np.isfinite(given), axis=1) & np.all(np.isfinite(built), axis=1)
    return bool(both.any()) and bool(np.allclose(given[both], built[both], atol=1e-6))


def _in_origin_axes(velocity: np.ndarray, lla: np.ndarray, origin: Origin) -> np.ndarray:
    """Each fix's local-level (ENU) velocity in the origin's ENU axes, where the chords are
    taken: near a pole east turns with the longitude (a car at the South Pole station had
    its right velocities refused as "64 deg away ... NED order?"); elsewhere a few km turn
    it by hundredths of a degree."""
    from fgins.geodesy import ecef_to_enu_rotation

    at_fix = ecef_to_enu_rotation(lla[:, 0], lla[:, 1])
    to_origin = ecef_to_enu_rotation(origin.lat, origin.lon)
    rotated = np.einsum("ij,njk,nk->ni", to_origin, np.swapaxes(at_fix, -1, -2), np.nan_to_num(velocity))
    return np.where(np.isfinite(velocity), rotated, np.nan)


# A constant difference between the receiver's velocities and the displacement of its fixes
# (m/s, horizontal) beyond this and VELOCITY_BIAS_SIGMAS of its own uncertainty; judged over
# stretches of dense fixes at least VELOCITY_BIAS_MIN_S long.
VELOCITY_BIAS_MIN_M_S = 0.1
VELOCITY_BIAS_SIGMAS = 5.0
VELOCITY_BIAS_MIN_S = 60.0


def velocities_without_bias(gnss: GnssData, origin: Origin, checks: list[str]) -> GnssData:
    """``gnss`` without its velocities, said in ``checks``, where they integrate to a
    displacement that differs from the fixes' own by a constant velocity: over a stretch of
    dense fixes the fixes' displacement is known to twice their sigma however slow their
    errors, the velocities' integral to their noise over the count; an antenna's arm or a
    velocity's lag moves the integral by a bounded amount, a bias grows with the stretch.
    (Outside tester: velocities 0.4 m/s off in east sent the EKF 11.6 m off inside outages
    at z 8.7 and the batch blamed a time offset, an antenna and a gyro scale, nothing said.)"""
    from fgins.geodesy import lla_to_enu

    if gnss.velocity is None or len(gnss.t) < VELOCITY_MIN_EPOCHS:
        return gnss
    enu = lla_to_enu(gnss.lla, origin)
    given = _in_origin_axes(gnss.velocity, gnss.lla, origin)[:, :2]
    interval = float(median_interval(gnss.t))
    finite = np.all(np.isfinite(given), axis=1) & np.all(np.isfinite(enu[:, :2]), axis=1)
    breaks = np.flatnonzero(np.diff(gnss.t) > 2.5 * interval) + 1
    sigma_h = float(np.median(horizontal_fix_sigma(gnss)))
    total, weight, spread = np.zeros(2), 0.0, []
    for rows in np.split(np.arange(len(gnss.t)), breaks):
        rows = rows[finite[rows]]
        if len(rows) < 3 or gnss.t[rows[-1]] - gnss.t[rows[0]] < VELOCITY_BIAS_MIN_S:
            continue
        t, v, p = gnss.t[rows], given[rows], enu[rows, :2]
        span = float(t[-1] - t[0])
        integral = np.sum(0.5 * (v[1:] + v[:-1]) * np.diff(t)[:, None], axis=0)
        total += integral - (p[-1] - p[0])  # metres of difference over the stretch
        weight += span
        spread.append(np.diff(v, axis=0))
    if weight < VELOCITY_BIAS_MIN_S:
        return gnss
    bias = total / weight
    # The fixes' displacement: 2 sigma per stretch end; the velocities' integral: their own
    # noise from one velocity to the next (the vehicle's accelerations in it: conservative).
    steps = np.concatenate(spread)
    noise = 1.4826 * np.median(np.abs(steps - np.median(steps, axis=0)), axis=0) / np.sqrt(2.0)
    count = max(len(spread), 1)
    sigma = np.hypot(2.0 * sigma_h * np.sqrt(count) / weight, noise * interval * np.sqrt(len(steps)) / weight)
    if not (np.linalg.norm(bias) > VELOCITY_BIAS_MIN_M_S and np.all(np.isfinite(sigma))
            and np.sqrt(np.sum((bias / sigma) ** 2)) > VELOCITY_BIAS_SIGMAS):  # fmt: skip
        return gnss
    checks.append(
        f"gnss: the velocities integrate to the fixes' displacement only with a constant "
        f"[{bias[0]:+.2f}, {bias[1]:+.2f}] m/s (east, north; +-{max(sigma):.2f}) taken off, over "
        f"{weight:.0f} s of dense fixes: a receiver's velocity has no such bias (another frame "
        "or reference, a processing error); the velocities are not used"
    )
    return replace(gnss, velocity=None, velocity_std=None)


def check_gnss_velocity(gnss: GnssData, origin: Origin) -> None:
    """The receiver's velocity against the velocity its own fixes show (see the constants)."""
    from fgins.geodesy import lla_to_enu

    if gnss.velocity is None or len(gnss.t) < 3:
        return
    enu = lla_to_enu(gnss.lla, origin)
    dense, track_all, clear, chord_noise = _chord_velocity(gnss, enu)
    if dense.sum() < VELOCITY_MIN_EPOCHS:
        return
    track = track_all[dense]
    given = _in_origin_axes(gnss.velocity[dense], gnss.lla[dense], origin)
    given_speed = np.hypot(given[:, 0], given[:, 1])
    moving = np.isfinite(given_speed) & clear[dense]
    _check_shrunk_track(gnss, enu, fix_sigma(gnss))
    from_course = _velocity_from_speed_course(gnss)
    if moving.sum() >= VELOCITY_MIN_EPOCHS:
        # The direction first: a ratio of velocities turned against the chords means nothing.
        angle = np.degrees(np.abs(np.angle(
            (given[moving, 0] + 1j * given[moving, 1]) / (track[moving, 0] + 1j * track[moving, 1])
        )))  # fmt: skip
        median_angle = float(np.median(angle))
        if median_angle > VELOCITY_MAX_ANGLE_DEG:
            if from_course:
                course = np.asarray(gnss.course, dtype=float)
                course = course[np.isfinite(course)]
                why = (
                    "all course values lie within 0..6.3: radians?"
                    if np.all(np.abs(course) <= 2 * np.pi + 0.01)
                    else "a course not measured clockwise from north?"
                )
                raise InputError(
                    f"gnss: the course points {median_angle:.0f} deg away from the track the "
                    f"fixes show (median; ~0 expected): {why} give the course column in degrees "
                    "clockwise from north"
                )
            raise InputError(
                f"gnss: the velocity points {median_angle:.0f} deg away from the track the fixes "
                "show (median; ~0 expected): east and north swapped (NED order?) or another "
                "frame; give vel_east, vel_north, vel_up (ENU, m/s)"
            )
    ratio = _speed_ratio(given_speed, np.hypot(track[:, 0], track[:, 1]), chord_noise[dense])
    if math.isfinite(ratio) and not VELOCITY_SPEED_RATIO_RANGE[0] <= ratio <= VELOCITY_SPEED_RATIO_RANGE[1]:
        what, fix = (
            ("speed over ground gives", "give the speed column in m/s")
            if from_course
            else ("velocity columns give", "give vel_east/north/up in m/s")
        )
        raise InputError(
            f"gnss: the {what} {ratio:.3g} times the speed the fixes show "
            f"(~1 expected; km/h gives 3.6, knots 1.94): {fix}"
        )
    climb = track[:, 2]
    given_climb = given[:, 2]
    usable = np.isfinite(given_climb)
    bounds = None
    if usable.sum() >= VELOCITY_MIN_EPOCHS and np.std(given_climb[usable]) >= CLIMB_MIN_STD_M_S:
        bounds = _climb_ratio_bounds(climb[usable], given_climb[usable])
    if bounds is None:  # too little climb, or noise, not a unit: the sign over longer stretches
        _check_climb_sign_over_windows(gnss, enu)
        return
    low, high = bounds
    if high < CLIMB_RATIO_RANGE[0] or low > CLIMB_RATIO_RANGE[1]:
        ratio = float(np.sign(low) * np.sqrt(low * high))
        raise InputError(
            f"gnss: the altitude changes {ratio:.3g} times as fast as vel_up says (~1 "
            "expected; 3.28 for altitude in feet, -1 for a down velocity): give the "
            "altitude in metres and vel_up positive up"
        )


def _speed_ratio(given: np.ndarray, chord: np.ndarray, noise: np.ndarray) -> float:
    """How many times the given horizontal speeds are the fixes' chords' (per epoch, with
    the RMS ``noise`` the fixes give a chord's velocity): the median of their ratios where
    the given speed stands clear of that noise, each chord's speed less its noise
    (sqrt(c^2 - noise^2): noise only lengthens a chord on average); NaN with too few such
    epochs. Chosen by the given speed, which the chords' noise does not touch: chosen by
    the chords' own speed, the ones noise had lengthened were taken (a 5 m/s boat with 3 m
    fixes: "0.68 times the speed the fixes show", refused as a unit error; now 1.00). The
    median, as chords through turns are shorter than the path (a multirotor's 4-s chords)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        chosen = np.isfinite(given) & np.isfinite(chord) & np.isfinite(noise)
        chosen &= given > np.maximum(TURN_MIN_SPEED_M_PER_S, 3.0 * noise)
        if chosen.sum() < VELOCITY_MIN_EPOCHS:
            return math.nan
        corrected = np.sqrt(np.maximum(chord[chosen] ** 2 - noise[chosen] ** 2, 0.0))
        return float(np.median(given[chosen] / corrected))


# A car's grades climb a few tenths of a m/s, lost in a 4-s chord of fixes 2 m apart
# vertically, so the epoch-by-epoch comparison cannot judge vel_up there, and a down velocity
# given as up sent the solution 2-2.6x further off vertically at z_up 3.7-4.8, unsaid (outside
# tester). Over CLIMB_WINDOW_S the height changes add up: the sign is judged there (the unit
# needs the steeper climbs above), as which of vel_up and -vel_up the height changes fit in
# the fixes' own vertical sigmas.
CLIMB_WINDOW_S = 15.0
CLIMB_WINDOW_MAX_GAP_S = 2.5  # fixes this far apart end a dense stretch
CLIMB_WINDOW_MIN = 5  # windows needed
CLIMB_SIGN_CHI2 = 25.0  # how much better -vel_up must fit (5 sigma)
CLIMB_SIGN_FIT = 4.0  # and fit at all (chi2 per window): else it is not a sign


def _check_climb_sign_over_windows(gnss: GnssData, enu: np.ndarray) -> None:
    """vel_up integrated over windows of CLIMB_WINDOW_S of dense fixes against the fixes'
    height change over each: an InputError where -vel_up fits those changes better by
    CLIMB_SIGN_CHI2 (in their vertical sigmas) and fits them (CLIMB_SIGN_FIT per window)."""
    if gnss.velocity is None:
        return
    vertical = np.asarray(gnss.std[:, 2], dtype=float) if gnss.std is not None else np.full(len(gnss.t), np.nan)
    vertical = np.where(np.isfinite(vertical) & (vertical > 0), vertical, 1.5 * fix_sigma(gnss))
    climb = np.asarray(gnss.velocity[:, 2], dtype=float)
    finite = np.isfinite(enu[:, 2]) & np.isfinite(climb)
    t, up, climb, vertical = gnss.t[finite], enu[finite, 2], climb[finite], vertical[finite]
    if len(t) < 3:
        return
    steps = np.diff(t)
    integral = np.concatenate([[0.0], np.cumsum(0.5 * (climb[1:] + climb[:-1]) * steps)])
    gap_count = np.concatenate([[0], np.cumsum(steps > CLIMB_WINDOW_MAX_GAP_S)])
    windows, i = [], 0
    while i < len(t):
        j = int(np.searchsorted(t, t[i] + CLIMB_WINDOW_S))
        if j >= len(t):
            break
        if gap_count[j] == gap_count[i]:
            windows.append((i, j))
            i = j
        else:
            i += 1
    if len(windows) < CLIMB_WINDOW_MIN:
        return
    first, last = np.array(windows).T
    rise, given = up[last] - up[first], integral[last] - integral[first]
    variance = vertical[first] ** 2 + vertical[last] ** 2
    as_given = float(np.sum((rise - given) ** 2 / variance))
    flipped = float(np.sum((rise + given) ** 2 / variance))
    if as_given - flipped < CLIMB_SIGN_CHI2 or flipped > CLIMB_SIGN_FIT * len(windows):
        return
    ratio = float(np.sum(rise * given) / np.sum(given**2))
    raise InputError(
        f"gnss: over {len(windows)} stretches of {CLIMB_WINDOW_S:g} s the altitude changes "
        f"{ratio:.2g} times as much as vel_up integrates to (~1 expected; -1 for a down "
        "velocity, NED's third axis): give vel_up positive up"
    )


def _climb_ratio_bounds(climb: np.ndarray, given: np.ndarray) -> tuple[float, float] | None:
    """Where the ratio of the fixes' climb rate to the receiver's vel_up lies: between the
    slope of one on the other and the inverse of the reverse one, as noise in either pulls
    its own regression towards zero (vel_up scattering 1 m/s on a level drive gave 0.12,
    "altitude in feet?"; the reverse slope there puts it at 8). None when the two are too
    weakly related (CLIMB_MIN_CORRELATION) to tell a unit."""
    both = float(np.sum(climb * given))
    norm = float(np.sqrt(np.sum(climb**2) * np.sum(given**2)))
    if norm == 0.0 or abs(both) < CLIMB_MIN_CORRELATION * norm:
        return None
    low, high = sorted((both / float(np.sum(given**2)), float(np.sum(climb**2)) / both))
    return low, high


# Fixes that move this many times less than the velocity says do not move at all (lat/lon in
# radians gives 1/57): a frozen output, not a unit.
FROZEN_RATIO = 1e-3
FROZEN_SPREAD_M = 0.01  # all fixes within this: one position repeated
FROZEN_MIN_FIXES = 10
TURNING_RATE_RAD_S = 0.1  # 1-s mean yaw rates this far from their median: the IMU turns
MOVING_ACCEL_M_S2 = 1.0  # 1-s mean horizontal specific force this far: it speeds up or brakes


def _frozen_note(gnss: GnssData) -> str:
    return f"{len(gnss.t)} fixes over {gnss.t[-1] - gnss.t[0]:.0f} s"


def mean_up(imu) -> np.ndarray:
    """Up in IMU axes: the mean accelerometer reading (gravity's reaction)."""
    up = np.mean(imu.accel, axis=0)
    return up / max(float(np.linalg.norm(up)), 1e-9)


def check_frozen_position(gnss: GnssData, enu: np.ndarray, imu, up: np.ndarray) -> None:
    """Every fix at one position (to 1 cm) while the IMU turns or accelerates (1-s means, so
    not vibration; a tilt of 6 deg would be needed at rest): a frozen receiver output or a
    constant column. Without velocity columns an outside tester's frozen fixes passed at
    exit 0 with advice to set the lever arm. A vehicle at rest does not turn, so a static
    recording (or a receiver's static hold at a stop) is not caught."""
    finite = np.all(np.isfinite(enu[:, :2]), axis=1)
    if finite.sum() < FROZEN_MIN_FIXES:
        return
    xy = enu[finite, :2]
    if float(np.max(np.ptp(xy, axis=0))) > FROZEN_SPREAD_M:
        return
    means = second_means(imu.t, imu.gyro, imu.accel, min_samples=5)
    if means is None or len(means[0]) < 3:
        return
    gyro, accel = means
    yaw_rate = gyro @ up
    turning = float(np.percentile(np.abs(yaw_rate - np.median(yaw_rate)), 95))
    horizontal = accel - np.outer(accel @ up, up)
    speeding = float(
        np.percentile(np.linalg.norm(horizontal - np.median(horizontal, axis=0), axis=1), 95)
    )
    if turning > TURNING_RATE_RAD_S or speeding > MOVING_ACCEL_M_S2:
        motion = (
            f"turns (yaw rates of {np.degrees(turning):.0f} deg/s)"
            if turning > TURNING_RATE_RAD_S
            else f"accelerates ({speeding:.1f} m/s^2 sustained over 1 s)"
        )
        raise InputError(
            f"gnss: the position never changes ({_frozen_note(gnss)}, all within "
            f"{FROZEN_SPREAD_M * 100:g} cm) while the IMU {motion}: a frozen position output "
            "(a receiver repeating its last fix, or a constant column); give the fixes' real "
            "positions"
        )


def drop_frozen_runs(
    gnss: GnssData, enu: np.ndarray, imu, up: np.ndarray, checks: list[str]
) -> tuple[GnssData, np.ndarray]:
    """The fixes without the repeats of frozen stretches: FROZEN_RUN_MIN or more fixes in a
    row at one position (to 1 cm) while the vehicle moved (the IMU turned or accelerated
    over them, or the next fix lies FROZEN_JUMP_M or more away), each stretch's first fix
    kept; said in one line. A receiver that repeats its last fix for 20 s is no multipath:
    left in, the fault exclusion took those fixes out only after a gyro scale of -2.3 % had
    been read from them (2.6 m RMS where the drive gives 0.34 m; outside tester). A vehicle
    at rest under a receiver's static hold repeats its fix too, and keeps it."""
    finite = np.all(np.isfinite(enu[:, :2]), axis=1)
    same = finite[1:] & finite[:-1] & np.all(np.abs(np.diff(enu[:, :2], axis=0)) <= FROZEN_SPREAD_M, axis=1)
    keep = np.ones(len(gnss.t), dtype=bool)
    dropped_runs = []
    for a, b in true_runs(same):  # fixes a .. b are one position
        if b - a + 1 < FROZEN_RUN_MIN:
            continue
        after = b + 1 if b + 1 < len(gnss.t) and finite[b + 1] else None
        jumped = (
            after is not None
            and float(np.linalg.norm(enu[after, :2] - enu[b, :2])) >= FROZEN_JUMP_M
            and not _receiver_at_rest(gnss, a, b)
            and not _track_returns(enu, finite, b, run=b - a + 1)
        )
        inside = (imu.t >= gnss.t[a]) & (imu.t <= gnss.t[b])
        if not (jumped or _imu_moves(imu.gyro[inside], imu.accel[inside], imu.t[inside], up)):
            continue
        keep[a + 1 : b + 1] = False
        dropped_runs.append((float(gnss.t[a] - gnss.t[0]), float(gnss.t[b] - gnss.t[a]), b - a))
    if not dropped_runs:
        return gnss, enu
    checks.append(
        f"gnss: {len(dropped_runs)} stretch(es) where the fixes repeat one position while the "
        f"vehicle moves ({sum(n for *_, n in dropped_runs)} repeated fixes left out, at t - t0 = "
        + ", ".join(f"{start:.0f} s for {span:.0f} s" for start, span, _ in dropped_runs[:5])
        + "): a frozen position output (a receiver repeating its last fix)"
    )
    return gnss.subset(keep), enu[keep]


FROZEN_RUN_MIN = 5
FROZEN_JUMP_M = 10.0
FROZEN_REST_SPEED_M_S = 0.5  # a receiver's own speed under this over a stretch: it stood


def _receiver_at_rest(gnss: GnssData, a: int, b: int) -> bool:
    """The receiver's own velocity over fixes ``a`` .. ``b`` says it stood (a frozen output
    repeats a moving receiver's velocity with its position)."""
    if gnss.velocity is None:
        return False
    velocity = np.asarray(gnss.velocity, dtype=float)[a : b + 1, :2]
    speed = np.hypot(velocity[:, 0], velocity[:, 1])
    speed = speed[np.isfinite(speed)]
    return len(speed) > 0 and float(np.median(speed)) < FROZEN_REST_SPEED_M_S


def _track_returns(enu: np.ndarray, finite: np.ndarray, b: int, run: int) -> bool:
    """A fix within the stretch's length after it back within half FROZEN_JUMP_M of the
    stretch's position: a static receiver whose output steps between a coarse grid's points
    (a timing receiver at 0.01 arc-minute: 12.5-18.5 m), not a vehicle moving on. Its 48
    fixes at the true position were left out as frozen, the 22 on the grid's next points
    kept: 12-23 m off at z 11-12 (outside tester)."""
    later = np.arange(b + 1, min(b + 1 + max(run, FROZEN_RUN_MIN), len(enu)))
    later = later[finite[later]]
    return bool(np.any(np.linalg.norm(enu[later, :2] - enu[b, :2], axis=1) < 0.5 * FROZEN_JUMP_M))


def _imu_moves(gyro: np.ndarray, accel: np.ndarray, t: np.ndarray, up: np.ndarray) -> bool:
    """Whether the IMU turned or accelerated (1-s means, as check_frozen_position judges)."""
    means = second_means(t, gyro, accel) if len(t) >= 3 else None
    if means is None:  # fewer than 3 samples, or not one block
        return False
    yaw, force = means[0] @ up, means[1]
    horizontal = force - np.outer(force @ up, up)
    return bool(
        np.max(np.abs(yaw)) > TURNING_RATE_RAD_S
        or np.max(np.linalg.norm(horizontal - np.median(horizontal, axis=0), axis=1)) > MOVING_ACCEL_M_S2
    )


def check_track_scale_by_turns(gnss: GnssData, enu: np.ndarray, imu, up: np.ndarray) -> None:
    """Fixes that move far slower than the IMU's turns say, without velocity columns to
    compare with: in a turn the horizontal specific force is at least speed x yaw rate (1-s
    means, so not vibration), so its ratio to the yaw rate is at least the speed (more while
    speeding up or braking, or tilted). The fixes' own speed far below it is a shrunk track
    (lat/lon in radians: 57x; it ran 80 Levenberg-Marquardt rounds to an error blaming the
    IMU noise). A multirotor or a walker (yaw without a turn, steps) is not judged, and
    a banked aircraft's specific force stays along its up axis (a larger ratio, never
    smaller)."""
    finite = np.all(np.isfinite(enu[:, :2]), axis=1)
    t_fix, xy = gnss.t[finite], enu[finite, :2]
    if len(t_fix) < VELOCITY_MIN_EPOCHS or np.any(np.diff(t_fix) <= 0):
        return
    rate = 1.0 / float(np.median(np.diff(imu.t)))
    n = max(round(rate), 5)
    blocks = len(imu.t) // n
    if blocks < SCALE_MIN_TURNS:
        return
    t_mid = imu.t[: blocks * n].reshape(blocks, n).mean(axis=1)
    samples = imu.gyro[: blocks * n].reshape(blocks, n, 3)
    gyro = samples.mean(axis=1)
    accel = imu.accel[: blocks * n].reshape(blocks, n, 3).mean(axis=1)
    # Only blocks whose tilt holds still: a body rolling or pitching (a boat in waves: 8 deg
    # at 0.25 Hz) puts gravity into the "horizontal" force, read as a turn far faster than
    # the fixes go (a 1.5 m/s boat: "10.3 times slower ... lat/lon in radians", refused).
    # The rate in fifths of a block (0.2 s means: an engine's vibration averages out there,
    # a swell's roll does not).
    fifth = max(n // 5, 1)
    parts = samples[:, : 5 * fifth].reshape(blocks, 5, fifth, 3).mean(axis=2)
    tilting = np.linalg.norm(parts - (parts @ up)[..., None] * up, axis=2).mean(axis=1)
    inside = (t_mid > t_fix[0]) & (t_mid < t_fix[-1]) & (tilting < SCALE_TILT_RATE_RAD_S)
    velocity = np.gradient(xy, t_fix, axis=0)
    yaw_rate = gyro @ up
    horizontal = accel - np.outer(accel @ up, up)
    # Read as they are and less their medians (a gyro bias, a tilt): both must call the track
    # shrunk. A car circling a skid pad from a rest has turning as its median: less it, the
    # rest looked like a turn the fixes did not follow (a false "20 times slower" error).
    ratios = []
    for rate, force in (
        (np.abs(yaw_rate - np.median(yaw_rate)), np.linalg.norm(horizontal - np.median(horizontal, axis=0), axis=1)),
        (np.abs(yaw_rate), np.linalg.norm(horizontal, axis=1)),
    ):  # fmt: skip
        turns = inside & (rate > SCALE_TURN_RAD_S) & (force > SCALE_FORCE_M_S2)
        if turns.sum() < SCALE_MIN_TURNS:
            return
        speed = np.hypot(*(np.interp(t_mid[turns], t_fix, velocity[:, i]) for i in range(2)))
        ratios.append((float(np.median(speed / (force[turns] / rate[turns]))), int(turns.sum())))
    ratio, count = max(ratios)
    if ratio < SCALE_SHRUNK_RATIO:
        raise InputError(
            f"gnss: the fixes move {1.0 / max(ratio, 1e-9):.3g} times slower than the IMU's "
            f"turns say (their speed against horizontal specific force over yaw rate, median "
            f"of {count} 1-s turns; ~1 expected, lat/lon in radians gives "
            "57): give lat/lon in degrees (and positions in metres)"
        )


# A turn: 1-s means of the yaw rate and the horizontal specific force above these; this
# many of them; the fixes' speed over the speed they imply below this is a shrunk track.
SCALE_TURN_RAD_S = 0.05
SCALE_FORCE_M_S2 = 0.5
SCALE_MIN_TURNS = 8
SCALE_SHRUNK_RATIO = 0.1
# Mean rotation rate about the horizontal axes (rad/s) of a block that counts: a car's roll
# into a turn stays below; a boat rolling 8 deg at 0.25 Hz averages 0.14.
SCALE_TILT_RATE_RAD_S = 0.05


def _check_shrunk_track(gnss: GnssData, enu: np.ndarray, sigma: np.ndarray) -> None:
    """Fixes that move far less than the receiver's own velocity says, over the shortest
    stretch (at most 5 s) whose path length is well above the fixes' noise: positions shrunk
    by a unit (lat/lon in radians: 57x closer together). The chord check above cannot see
    it: its track speeds fall below the speed floor. Short stretches, so a small loop (a
    chord much shorter than its arc) cannot trigger it: over 5 s a 25 m loop at 11 km/h
    still gives 0.94."""
    t = gnss.t
    speed = np.hypot(gnss.velocity[:, 0], gnss.velocity[:, 1])
    finite = np.isfinite(speed) & np.all(np.isfinite(enu[:, :2]), axis=1)
    if finite.sum() < VELOCITY_MIN_EPOCHS:
        return
    t, speed, xy, noise = t[finite], speed[finite], enu[finite, :2], sigma[finite]
    path = np.concatenate([[0.0], np.cumsum(0.5 * (speed[:-1] + speed[1:]) * np.diff(t))])
    end = np.searchsorted(path, path + 3.0 * np.sqrt(2.0) * noise)
    usable = end < len(t)
    end = np.minimum(end, len(t) - 1)
    usable &= (t[end] - t <= 5.0) & (path[end] > path)
    if usable.sum() < VELOCITY_MIN_EPOCHS:
        return
    start = np.flatnonzero(usable)
    chord = np.hypot(*(xy[end[start]] - xy[start]).T)
    ratio = float(np.median(chord / (path[end[start]] - path[start])))
    if ratio < FROZEN_RATIO:
        raise InputError(
            f"gnss: the position stays the same ({_frozen_note(gnss)}) while the velocity "
            f"columns say {np.median(speed):.3g} m/s: a frozen position output (a receiver "
            "repeating its last fix, or a constant column); give the fixes' real positions"
        )
    if ratio < 0.1:
        raise InputError(
            f"gnss: the fixes move {1 / max(ratio, 1e-12):.3g} times less than the velocity "
            "columns say (~1 expected; lat/lon in radians gives 57): give lat/lon in degrees "
            "(and the velocity in m/s)"
        )


def _gyro_at_rest(imu, gnss: GnssData, origin: Origin, window_s: float = 1.0) -> float:
    """Low-end (10 %) gyro-rate norm over 1-s windows where the vehicle is at rest: a steady specific
    force of ~g (which a steady turn also shows: 8 m/s around a 30 m circle is 0.27 rad/s
    at 10.0 m/s^2, and such test-track drives were refused as "gyro in deg/s") and fixes
    around it that stay together (:func:`_fixes_at_rest`). That is the gyro bias plus Earth
    rate (0.0 when the vehicle is never seen at rest)."""
    rate = 1.0 / float(np.median(np.diff(imu.t)))
    n = max(round(window_s * rate), 5)
    blocks = len(imu.t) // n
    if blocks == 0:
        return 0.0
    accel = imu.accel[: blocks * n].reshape(blocks, n, 3)
    gyro = imu.gyro[: blocks * n].reshape(blocks, n, 3)
    steady = np.all(accel.std(axis=1) < REST_ACCEL_STD_M_S2, axis=1)
    level = np.abs(np.linalg.norm(accel.mean(axis=1), axis=1) - G) < REST_ACCEL_NORM_TOL_M_S2
    rest = steady & level
    if rest.any():
        middle = imu.t[: blocks * n].reshape(blocks, n).mean(axis=1)
        rest[rest] = _fixes_at_rest(middle[rest], gnss, origin)
    if rest.sum() < 3:
        return 0.0
    # The low end, not the median: a vehicle turning in place (a skid-steer robot, a tracked
    # vehicle) also reads a steady ~g with fixes that stay together, and a field robot that
    # spun at 0.5 rad/s for longer than it stood still was refused as "gyro in deg/s". A
    # bias read in the wrong unit is the same in every window at rest, so also at the low end.
    return float(np.quantile(np.linalg.norm(gyro[rest].mean(axis=1), axis=1), REST_RATE_QUANTILE))


# The quantile of the rest windows' gyro rates taken as the rest rate (see _gyro_at_rest).
REST_RATE_QUANTILE = 0.1


# Fixes within this many seconds of a moment, all within this many metres (or this many of
# their horizontal sigmas) of their median, show the vehicle at rest then.
REST_GNSS_WINDOW_S = 5.0
REST_GNSS_SPREAD_M = 5.0
REST_GNSS_SPREAD_SIGMAS = 3.5
REST_GNSS_SPEED_M_S = 0.5


def _fixes_at_rest(times: np.ndarray, gnss: GnssData, origin: Origin) -> np.ndarray:
    """For each of ``times``: do at least 3 fixes lie within ``REST_GNSS_WINDOW_S`` of it,
    all close to their median (a vehicle at rest), rather than strung along a track, and
    their median horizontal speed (where the receiver gives velocity) below
    ``REST_GNSS_SPEED_M_S`` (a car circling a few metres at walking pace keeps its fixes
    together, not its velocity; a receiver at rest reads its velocity noise, ~1.2 sigma)?"""
    from fgins.geodesy import lla_to_enu

    enu = lla_to_enu(gnss.lla, origin)[:, :2]
    speed = (
        np.zeros(len(gnss.t))
        if gnss.velocity is None
        else np.nan_to_num(np.linalg.norm(gnss.velocity[:, :2], axis=1), nan=0.0)
    )
    speed_limit = REST_GNSS_SPEED_M_S
    stated_v = gnss.velocity_std[:, :2] if gnss.velocity_std is not None else np.zeros((0, 2))
    if np.isfinite(stated_v).any():
        speed_limit = max(speed_limit, REST_GNSS_SPREAD_SIGMAS * float(np.nanmedian(stated_v)))
    limit = REST_GNSS_SPREAD_M
    stated = gnss.std[:, :2] if gnss.std is not None else np.zeros((0, 2))
    if np.isfinite(stated).any():
        limit = max(limit, REST_GNSS_SPREAD_SIGMAS * float(np.nanmedian(stated)))
    lo = np.searchsorted(gnss.t, times - REST_GNSS_WINDOW_S)
    hi = np.searchsorted(gnss.t, times + REST_GNSS_WINDOW_S, side="right")
    out = np.zeros(len(times), dtype=bool)
    for i, (a, b) in enumerate(zip(lo, hi, strict=True)):
        if b - a >= 3 and np.median(speed[a:b]) <= speed_limit:
            near = enu[a:b]
            out[i] = np.linalg.norm(near - np.median(near, axis=0), axis=1).max() <= limit
    return out


def _horizontal_sigma(gnss: GnssData) -> float:
    """The fixes' median per-axis horizontal sigma (m): their std east/north where given,
    else the 3-D sigma (from DOP or the default) over sqrt(3)."""
    std = gnss.std[:, :2]
    given = np.all(np.isfinite(std) & (std > 0), axis=1)
    if given.any():
        return float(np.median(np.sqrt(np.mean(std[given] ** 2, axis=1))))
    return float(np.median(fix_sigma(gnss))) / np.sqrt(3.0)


def _wrapped(angle: np.ndarray) -> np.ndarray:
    """Angles (rad) wrapped into [-pi, pi)."""
    return np.mod(angle + np.pi, 2.0 * np.pi) - np.pi


def turn_window_s(t: np.ndarray) -> float:
    """The turn windows' length for fixes at times ``t``: TURN_WINDOW_S, or four fix
    intervals where the fixes are sparser (at 0.2 Hz a 10 s window's courses, 5 s chords,
    spanned one fix interval and were all left out: an IMU with a flipped axis, a gyro in
    deg/s or one that does not see the turns went unchecked)."""
    return max(TURN_WINDOW_S, 4.0 * median_interval(t))


def _gyro_turn_ratio(imu, gnss: GnssData, origin: Origin) -> tuple[float, int, float]:
    """Median of |integrated gyro| / |GNSS course change| over windows with a clear turn,
    their number, and the median over them of the gyro's rotation about up over the course
    change (up: the mean accelerometer reading, the reaction to gravity; ~+1).

    The course at a time comes from positions half a window (:func:`turn_window_s`) apart (a
    few metres of noise are small against the tens of metres travelled); a window spans the
    time between two such courses. Only windows whose end points lie among dense fixes (no outage) count.
    """
    from fgins.geodesy import lla_to_enu

    t = gnss.t
    if t.size < 4:
        return math.nan, 0, math.nan
    window_s = turn_window_s(t)
    half = window_s / 2
    lo, hi = max(t[0], imu.t[0]) + half, min(t[-1], imu.t[-1]) - half
    if hi - lo < window_s:
        return math.nan, 0, math.nan
    step = window_s / 4
    grid = np.arange(lo, hi, step)
    enu = lla_to_enu(gnss.lla, origin)
    a, b = grid - half / 2, grid + half / 2
    east = np.interp(b, t, enu[:, 0]) - np.interp(a, t, enu[:, 0])
    north = np.interp(b, t, enu[:, 1]) - np.interp(a, t, enu[:, 1])
    # largest fix interval around each course's baseline: an outage makes the course a guess
    idx_a = np.clip(np.searchsorted(t, a), 1, t.size - 1)
    idx_b = np.clip(np.searchsorted(t, b), 1, t.size - 1)
    local_gap = np.maximum(t[idx_a] - t[idx_a - 1], t[idx_b] - t[idx_b - 1])
    # The fixes' own noise on a course: its chord must stand well above it, and a turn above
    # the two courses' noise (a robot at 2 m/s through 5 m phone fixes: 10 s "turns" of
    # 30-60 deg that were noise, and "the gyro does not see the turns", an error on valid
    # data).
    chord_sigma = np.sqrt(2.0) * _horizontal_sigma(gnss)
    length = np.hypot(east, north)
    speed = length / half
    good = (speed > TURN_MIN_SPEED_M_PER_S) & (local_gap <= max(half / 2, 1.5 * median_interval(t)))
    good &= length >= COURSE_MIN_CHORD_SIGMAS * chord_sigma
    course_sigma = chord_sigma / np.maximum(length, 1e-9)
    course = np.unwrap(np.arctan2(east, north))
    dt = np.diff(imu.t)
    cumulative = np.vstack(
        [np.zeros(3), np.cumsum(0.5 * (imu.gyro[1:] + imu.gyro[:-1]) * dt[:, None], axis=0)]
    )
    span = 4  # grid steps per window
    i0, i1 = np.arange(grid.size - span), np.arange(span, grid.size)
    turn = np.abs(course[i1] - course[i0])
    rotation = np.column_stack(
        [
            np.interp(grid[i1], imu.t, cumulative[:, k])
            - np.interp(grid[i0], imu.t, cumulative[:, k])
            for k in range(3)
        ]
    )
    rotated = np.linalg.norm(rotation, axis=1)
    signed_turn = course[i1] - course[i0]  # compass course: clockwise positive
    # Moving at both ends, and no reversal: a land vehicle that reverses (a forklift, a
    # tractor, a parking manoeuvre) flips its course without turning (a vehicle shuttling
    # back and forth was refused: "the gyro does not see the turns", 0.002 times). A window
    # is left out when its course flips by nearly 180 deg; when it flips from one chord to
    # the next (2.5 s apart) by 180 deg less what it turned meanwhile, more than any vehicle
    # turns in that time at speed; or when the vehicle slowed in between to less than half
    # its speed at either end (through a reversal a chord's course is any direction). A
    # U-turn within one window is lost as evidence with them; the other turns still count.
    flip = np.abs(_wrapped(np.diff(course))) > REVERSAL_STEP_MIN_RAD
    slowest = np.min([speed[i0 + j] for j in range(1, span)], axis=0)
    moving = good[i0] & good[i1] & ~np.any([flip[i0 + j] for j in range(span)], axis=0)
    moving &= slowest >= 0.5 * np.minimum(speed[i0], speed[i1])
    moving &= np.abs(_wrapped(signed_turn)) < np.pi - REVERSAL_TOL_RAD
    turn_noise = np.hypot(course_sigma[i0], course_sigma[i1])
    sigmas = max(TURN_MIN_SIGMAS, NormalDist().inv_cdf(1.0 - 0.5 * NOISE_TURNS_EXPECTED / max(int(moving.sum()), 1)))
    use = moving & (np.abs(signed_turn) > np.maximum(TURN_MIN_RAD, sigmas * turn_noise))
    if use.any():
        up = np.mean(imu.accel, axis=0)
        up = up / np.linalg.norm(up)
        # A left turn (counter-clockwise from above, about up) lowers the compass course:
        # the gyro's turn about up over the track's is ~+1 (about -1 when reversed); the
        # median, as a few windows' courses are noise (slow driving, PDOP-biased fixes).
        signed_ratio = (rotation[use] @ up) / -signed_turn[use]
        return (
            float(np.median(rotated[use] / turn[use])),
            int(use.sum()),
            float(np.median(signed_ratio)),
        )
    # No clear turn (a motorway): driving straight, the gyro must not say it rotated far.
    if moving.sum() >= STRAIGHT_MIN_WINDOWS:
        median_rotation = float(np.median(rotated[moving]))
        median_turn = float(np.median(turn[moving]))
        if median_rotation > STRAIGHT_MAX_ROTATION_RAD:
            ratio = median_rotation / max(median_turn, median_rotation / 1e3)
            return ratio, int(moving.sum()), math.nan
    return math.nan, 0, math.nan
