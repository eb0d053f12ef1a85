"""The input-validation layer: every reader's :class:`Dataset` passes through here, once.

Readers parse; this module checks, whatever the source (CSV pair, sim folder, NMEA + IMU CSV,
MCAP, KITTI, UBX), so the same drive read from different formats gets the same findings:

* IMU samples no IMU can measure (|gyro| > 200 rad/s, |accel| > 1e4 m/s^2: a corrupt record)
  -> dropped and counted, the hole bridged like a gap (more than 1 % of them: a unit mistake,
  :class:`InputError`);
* isolated IMU spike samples (more rotation or speed change within one sample than a vehicle
  can make) -> replaced by the line through their neighbours, counted;
* IMU gaps and linearly interpolated stretches -> ``ImuData.suspect`` (bridged with inflated
  noise), see :mod:`fgins.io.imu_checks`;
* units: a gyro in deg/s (its integrated rotation over GNSS turns is ~57x the turn the fixes
  show, or its rates are routinely above any vehicle's), an accelerometer in g (median
  specific-force norm ~1 instead of ~9.8), IMU times in ms or ns (samples "seconds" apart)
  -> :class:`InputError`;
* GNSS velocity against the fixes' own track: speed ratio (km/h, knots), direction (east and
  north swapped), climb rate against the altitude's (feet, a down velocity) -> :class:`InputError`;
* signs: the gyro's rotation about up (the direction the accelerometer's gravity reaction
  gives) turning against the GNSS track in the turns -> :class:`InputError` (an accelerometer
  giving acceleration instead of specific force, a gyro axis with its sign flipped, latitude
  and longitude swapped); a gyro that does not see the turns (dead, converted twice, clocks
  apart) likewise;
* geodetic ranges: |lat| > 90, |lon| > 180, altitude outside [-1000, 1e5] m -> fix dropped
  and counted (an error when no fix is left);
* GNSS sigmas and DOPs that are not positive finite numbers, and DOPs that are a receiver's
  "not available" placeholder (0, 99.99) -> missing, counted;
* fixes that are no measurement by their quality (6 dead reckoning, 7 manual, 8 simulator)
  -> noted (the GNSS gate of :mod:`fgins.factors.gnss` leaves them out);
* GNSS jumps no vehicle can make (> 1000 m/s between fixes beyond their own sigmas) -> fix
  dropped and counted; a jump that persists (two sources in one log) -> :class:`InputError`;
* GNSS time gaps (outages or a clock jump) -> reported;
* barometric pressure outside what air has (hPa, kPa, psi, bar given as Pa) -> :class:`InputError`;
* time bases: IMU and GNSS spans that do not overlap -> :class:`InputError` naming both spans
  and ``--time-offset``; GNSS epochs outside the IMU span -> counted.

Each finding is one line, appended to ``dataset.warnings`` and to
``dataset.metadata["input_checks"]``; unusable input raises :class:`InputError`. GTSAM-free.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from fgins.datatypes import Dataset, GnssData, InputError, Origin
from fgins.io.imu_checks import drop_out_of_range, flag_suspect, repair_spikes

# Geodetic ranges for the supported vehicles (cars, UAVs, aircraft): below the Dead Sea shore
# (-430 m) and deep mines with margin; above any aircraft (1e5 m is the Karman line).
ALT_MIN_M, ALT_MAX_M = -1000.0, 1.0e5
# No supported vehicle moves faster (airliners ~250 m/s, fast jets ~700 m/s).
MAX_SPEED_M_PER_S = 1000.0
JUMP_SIGMA_FACTOR = 5.0  # tolerance in the fixes' own sigmas on top of the speed bound
DEFAULT_FIX_SIGMA_M = 10.0  # a fix without any sigma or DOP: a consumer receiver's error
UERE_FOR_DOP_M = 5.0
JUMP_NEIGHBOURS = 3  # a fix is judged against this many fixes on each side
# Units. In rad/s no vehicle's rate is routinely (10 % of the time) above 10 rad/s; integrated
# over a turn the GNSS track shows, a rad/s gyro gives ~1x the turn, a deg/s one 57x.
GYRO_ROUTINE_MAX_RAD_PER_S = 10.0
GYRO_TURN_RATIO_MAX = 8.0
GYRO_TURN_RATIO_MIN = 0.25  # a right gyro gives 0.7-1.25 (median over the turns)
TURN_WINDOW_S = 10.0
TURN_MIN_RAD = 0.5  # a turn far above the course noise of the window's end points
TURN_MIN_SPEED_M_PER_S = 3.0
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
VELOCITY_SPEED_RATIO_RANGE = (0.7, 1.4)
VELOCITY_MAX_ANGLE_DEG = 25.0
CLIMB_MIN_STD_M_S = 1.0
CLIMB_RATIO_RANGE = (0.6, 1.6)
GNSS_GAP_MIN_S = 5.0
GNSS_GAP_PERIODS = 10.0


def validate_dataset(dataset: Dataset, vehicle: str | None = None) -> Dataset:
    """Check and repair ``dataset`` (see the module docstring); returns the checked dataset.

    Idempotent: a dataset already checked is returned unchanged.
    """
    if dataset.metadata.get("input_checks") is not None:
        return dataset
    try:
        return _validated(dataset, vehicle)
    except InputError as exc:
        # An IMU that fails a check in a file with several IMU topics: another topic may be
        # the right one (the reader picked the one with most messages, or the first by name).
        others = dataset.metadata.get("imu_topics_other") or []
        if not str(exc).startswith("imu:") or not others:
            raise
        raise InputError(
            f"{exc} [the IMU read is topic {dataset.metadata.get('topics', {}).get('imu', '?')}; "
            f"the file has {len(others)} other IMU topic(s): {', '.join(others)}; "
            f"--imu-topic {others[0]} reads {'it' if len(others) == 1 else 'another'}]"
        ) from None


def _validated(dataset: Dataset, vehicle: str | None) -> Dataset:
    checks: list[str] = []
    _check_imu_time_unit(dataset.imu.t)
    imu = flag_suspect(repair_spikes(drop_out_of_range(dataset.imu, checks), checks), checks)
    span = float(imu.t[-1] - imu.t[0])
    if span < SHORT_IMU_S:
        checks.append(
            f"imu: only {span:.1f} s of IMU data: too short to tell the heading (it needs a "
            "turn or an acceleration the fixes also see) or the biases; the output covers only "
            "those seconds, its attitude barely more than the alignment's guess"
        )
    gnss, origin = _check_gnss(dataset.gnss, dataset.origin, checks)
    from fgins.geodesy import lla_to_enu

    enu = lla_to_enu(gnss.lla, origin)  # the checks below share the fixes' local positions
    up = _mean_up(imu)
    _check_frozen_position(gnss, enu, imu, up)
    _check_time_bases(imu.t, gnss.t, checks, n_read=len(dataset.gnss))
    if vehicle not in FREE_BODY_VEHICLES:  # after the time bases: a time unit shrinks speeds too
        _check_track_scale_by_turns(gnss, enu, imu, up)
    given_offset = dataset.metadata.get("gnss_time_offset_s")
    try:
        _check_units(
            imu, gnss, origin, checks, has_accel_array=dataset.accel_array is not None,
            body_follows_track=vehicle not in FREE_BODY_VEHICLES,
        )  # fmt: skip
    except TurnsDisagree:
        # Turns that line up at another time are offset clocks, and the offset is the fix
        # (GPS time against UTC: "the gyro does not see the turns", its ratio 0.05).
        _clock_offset_explains_turns(
            imu, gnss, enu, up, origin, given_offset, banks=vehicle == "aircraft"
        )  # fmt: skip
        raise
    if vehicle not in FREE_BODY_VEHICLES and dataset.accel_array is None:
        _check_clock_offset(
            imu, gnss, enu, up, checks, given_offset, banks=vehicle == "aircraft"
        )  # fmt: skip
    _check_gnss_velocity(gnss, origin)
    if dataset.odometer is not None and len(dataset.odometer.t):
        _check_wheel_speed(dataset.odometer, gnss, enu)
    baro_heights = dataset.baro is not None and _given_as_height(dataset.baro)
    baro = _checked_baro(dataset.baro, imu.t, checks)
    if not baro_heights:  # heights were checked for range and made pressures
        _check_pressure_unit(baro)
    _check_baro_scale(baro, gnss, "height" if baro_heights else "pressure's ISA height")
    _warn_frame_extent(gnss, origin, checks)
    _report_gnss_time_gaps(gnss.t, checks)
    metadata = {**dataset.metadata, "input_checks": list(checks)}
    with np.errstate(invalid="ignore"):
        if not np.any(np.isfinite(dataset.gnss.lla[:, 2])):
            metadata["gnss_without_height"] = True  # every height invented: see pipeline
    return replace(
        dataset,
        imu=imu,
        gnss=gnss,
        baro=baro,
        origin=origin,
        warnings=[*dataset.warnings, *checks],
        metadata=metadata,
    )


# The navigation frame (DESIGN.md) is the tangent plane at the origin: an Earth-fixed
# Cartesian frame, exact with gravity taken where the vehicle is (fgins.geodesy.gravity_enu:
# normal gravity along the local vertical) and receivers' velocities turned into it. With the
# origin's gravity everywhere, an outside tester's round-Earth flights drifted 2.8 m in a 60 s
# outage 21 km out (0.18 m on a flat twin) and 22 m 64 km out (NEES 2400). What stays
# approximate far out: the gravity's height (the sphere's d^2 / 2R fall of the plane, metres
# off at a few hundred km) and the barometer's (the same fall, taken from the fixes).
FRAME_EXTENT_M = 100_000.0
EARTH_RADIUS_M = 6.371e6


def _warn_frame_extent(gnss: GnssData, origin: Origin, checks: list[str]) -> None:
    """An error for an origin away from every fix (a mistaken one), a warning for fixes
    that reach beyond :data:`FRAME_EXTENT_M`."""
    from fgins.geodesy import lla_to_enu

    if not len(gnss.t):
        return
    distance = np.hypot(*lla_to_enu(gnss.lla, origin)[:, :2].T)
    reach = float(np.nanmax(distance)) if np.any(np.isfinite(distance)) else 0.0
    nearest = float(np.nanmin(distance)) if np.any(np.isfinite(distance)) else 0.0
    if nearest > FRAME_EXTENT_M:
        # Only a stated origin can be away from every fix (readers otherwise take the first
        # fix): an outside tester's [origin] 3,900 km off gave 43 m errors with 0.6 m sigmas.
        raise InputError(
            f"frame: the origin ({origin.lat:.6f}, {origin.lon:.6f}; a sim folder's config.toml "
            f"[origin]) lies {nearest / 1000:,.0f} km from the nearest fix: give an origin "
            "at the drive, or remove [origin] to use the first fix"
        )
    if reach <= FRAME_EXTENT_M:
        return
    checks.append(
        f"frame: the fixes reach {reach / 1000:.0f} km from the origin; fgins navigates in the "
        f"tangent plane there ({reach**2 / (2 * EARTH_RADIUS_M) / 1000:.1f} km below the "
        "surface at that distance), with gravity's height and the barometer approximate "
        f"beyond {FRAME_EXTENT_M / 1000:.0f} km: smooth it in parts"
    )


# --------------------------------------------------------------------------------------------
# Barometer
# --------------------------------------------------------------------------------------------

# Air pressure from the Dead Sea shore (~107 kPa) to 20 km (~5.5 kPa), with margin: outside
# it the numbers are in another unit (hPa/mbar ~1000, kPa ~100, psi ~15, bar/atm ~1).
PRESSURE_PLAUSIBLE_PA = (3.0e3, 1.2e5)
PRESSURE_UNITS = (  # (median range, unit, factor to Pa)
    ((250.0, 1200.0), "hPa (mbar)", 100.0),
    ((25.0, 120.0), "kPa", 1000.0),
    ((3.0, 17.5), "psi", 6894.757),
    ((0.25, 1.2), "bar or atm", 1.0e5),
)


BARO_MAX_BAD_FRACTION = 0.01


def _checked_baro(baro, imu_t: np.ndarray, checks: list[str]):
    """Barometer samples the smoother can use: a pressure that is not a positive finite
    number is dropped and counted (more than 1 %: an error, the column is not pressure); none
    inside the IMU's span is said (outside testers: negative pressures and a barometer 5,000 s
    off the IMU were both dropped without a word, exit 0)."""
    if baro is None:
        return None
    from_height = _given_as_height(baro)
    if from_height:
        baro = _pressure_from_height(baro)
    values = baro.height if from_height else baro.pressure
    name = "height" if from_height else "pressure"
    if values is None or not len(baro.t):
        return baro
    with np.errstate(invalid="ignore"):
        bad = ~np.isfinite(values) | ((values <= 0.0) if name == "pressure" else False)
    if bad.any():
        count = int(bad.sum())
        example = values[bad][0]
        if count > BARO_MAX_BAD_FRACTION * len(values):
            raise InputError(
                f"baro: {count} of {len(values)} samples have a {name} no barometer gives "
                f"(e.g. {example:g}{' Pa' if name == 'pressure' else ' m'}): "
                + ("give pressure_pa in pascals (> 0)" if name == "pressure" else "check the column")
            )
        checks.append(
            f"baro: dropped {count} sample(s) with a {name} no barometer gives (e.g. {example:g})"
        )
        keep = ~bad
        baro = type(baro)(
            t=baro.t[keep],
            pressure=None if baro.pressure is None else baro.pressure[keep],
            height=None if baro.height is None else baro.height[keep],
        )
    inside = (baro.t >= imu_t[0]) & (baro.t <= imu_t[-1])
    if len(baro.t) and not inside.any():
        checks.append(
            f"baro: none of its {len(baro.t)} samples ({baro.t[0]:.3f}-{baro.t[-1]:.3f} s) lies "
            f"within the IMU's span ({imu_t[0]:.3f}-{imu_t[-1]:.3f} s): the barometer is not "
            "used; check its time base"
        )
    elif not inside.all():
        checks.append(
            f"baro: {int((~inside).sum())} of {len(baro.t)} samples lie outside the IMU's span "
            "and are not used"
        )
    return baro


def _given_as_height(baro) -> bool:
    """A barometer given as heights (a ``baro_height`` column) and no pressure."""
    return (
        baro.height is not None
        and bool(np.any(np.isfinite(baro.height)))
        and (baro.pressure is None or not np.any(np.isfinite(baro.pressure)))
    )


def _pressure_from_height(baro):
    """Heights made the standard-atmosphere pressure they stand for, so that the graph and
    every filter, which take pressure, use them (they read only pressure, and this check
    refused every ``baro_height`` file as "a pressure no barometer gives (nan)"). Heights no
    barometer reports are an error."""
    from fgins.factors.stationary import standard_atmosphere_pressure

    height = np.asarray(baro.height, dtype=float)
    finite = height[np.isfinite(height)]
    median = float(np.median(finite))
    if not BARO_HEIGHT_PLAUSIBLE_M[0] <= median <= BARO_HEIGHT_PLAUSIBLE_M[1]:
        raise InputError(
            f"baro: the median baro_height is {median:.4g} m, outside what a barometer "
            f"reports ({BARO_HEIGHT_PLAUSIBLE_M[0]:g} to {BARO_HEIGHT_PLAUSIBLE_M[1]:g} m): give "
            "baro_height in metres (or pressure_pa in pascals)"
        )
    with np.errstate(invalid="ignore"):
        pressure = np.where(np.isfinite(height), standard_atmosphere_pressure(height), np.nan)
    return type(baro)(t=baro.t, pressure=pressure, height=height)


# Heights a barometer column can hold (the Dead Sea to 20 km), metres.
BARO_HEIGHT_PLAUSIBLE_M = (-1000.0, 20000.0)


def _check_pressure_unit(baro) -> None:
    """A pressure no air has is a unit mistake (outside testers: hPa given as Pa, 955 "Pa"
    or ~30 km of standard atmosphere, moved the height by metres at exit 0)."""
    if baro is None or baro.pressure is None:
        return
    pressure = baro.pressure[np.isfinite(baro.pressure) & (baro.pressure > 0.0)]
    if not len(pressure):
        return
    median = float(np.median(pressure))
    low, high = PRESSURE_PLAUSIBLE_PA
    if low <= median <= high:
        return
    guess = next(
        (f"; it looks like {unit}: multiply by {factor:g}" for (a, b), unit, factor in
         PRESSURE_UNITS if a <= median <= b),
        "",
    )  # fmt: skip
    raise InputError(
        f"baro: the median pressure is {median:.4g} Pa, which no air between the Dead Sea and "
        f"20 km has ({low:g}-{high:g} Pa){guess}; give pressure_pa in pascals"
    )


def _check_baro_scale(baro, gnss: GnssData, what: str) -> None:
    """The barometer's height changes against the fixes' altitude changes, where it climbs
    or descends well beyond both sensors' noise: the fixes' altitude regressed on the
    barometer's (ISA) height has a slope of ~1 (the ISA against a real day's temperature:
    +-10 %); a height column in feet gives 1/3.28 (the barometer then pulled every height
    3.3x its climbs, and only the fit's chi-square said anything). The barometer's own
    noise is small, so the fixes' noise does not bias this slope. ``what``: how the
    barometer was given, for the message."""
    if baro is None or not len(baro.t):
        return
    from fgins.factors.stationary import standard_atmosphere_height

    with np.errstate(invalid="ignore"):  # a height given as such: the same height back
        height = np.asarray(standard_atmosphere_height(baro.pressure), dtype=float)
    alt = gnss.lla[:, 2]
    use = np.isfinite(alt) & (gnss.t >= baro.t[0]) & (gnss.t <= baro.t[-1])
    finite = np.isfinite(height)
    if use.sum() < VELOCITY_MIN_EPOCHS or finite.sum() < 2:
        return
    at_fixes = np.interp(gnss.t[use], baro.t[finite], height[finite])
    sigma_up = float(np.median(_fix_sigma(gnss)[use]))  # 3-D: at least the vertical

    def spread_of(values: np.ndarray) -> float:  # robust: a few altitude outliers do not count
        q1, q3 = np.percentile(values, [25, 75])
        return float(q3 - q1) / 1.349

    spread = spread_of(at_fixes)
    if max(spread, spread_of(alt[use])) < max(BARO_SCALE_MIN_SPREAD_M, 2.0 * sigma_up):
        return  # level by both: nothing to tell a scale from
    x = at_fixes - at_fixes.mean()
    y = alt[use] - alt[use].mean()
    slope = float(np.sum(x * y) / np.sum(x * x))
    ratio = 1.0 / slope if slope != 0 else np.inf
    if not BARO_SCALE_RANGE[0] <= ratio <= BARO_SCALE_RANGE[1]:
        raise InputError(
            f"baro: the barometer's {what} changes {ratio:.3g} times as much as the fixes' "
            f"altitude (its heights spread {spread:.0f} m, 1 sigma; ~1 expected, feet give "
            "3.28, a negative ratio a height that falls as the fixes climb): give "
            "baro_height in metres, up positive, or pressure_pa in pascals"
        )


# The barometer judged only over climbs and descents of this spread (std, m) or more, and
# twice the fixes' vertical sigma; its height scale within this range of the fixes'.
BARO_SCALE_MIN_SPREAD_M = 10.0
BARO_SCALE_RANGE = (0.7, 1.4)


# --------------------------------------------------------------------------------------------
# GNSS
# --------------------------------------------------------------------------------------------


def _geodetic_ok(lla: np.ndarray) -> np.ndarray:
    lat, lon, alt = lla[:, 0], lla[:, 1], lla[:, 2]
    finite = np.all(np.isfinite(lla), axis=1)
    with np.errstate(invalid="ignore"):
        return (
            finite
            & (np.abs(lat) <= 90.0)
            & (np.abs(lon) <= 180.0)
            & (alt >= ALT_MIN_M)
            & (alt <= ALT_MAX_M)
        )


def _describe_bad_lla(lla: np.ndarray) -> str:
    parts = []
    lat, lon, alt = lla[:, 0], lla[:, 1], lla[:, 2]
    with np.errstate(invalid="ignore"):
        if np.any(~np.all(np.isfinite(lla), axis=1)):
            parts.append(f"{int(np.sum(~np.all(np.isfinite(lla), axis=1)))} not finite")
        if np.any(np.abs(lat) > 90):
            parts.append(
                f"{int(np.sum(np.abs(lat) > 90))} with |lat| > 90 (e.g. {lat[np.abs(lat) > 90][0]:g})"
            )
        if np.any(np.abs(lon) > 180):
            parts.append(
                f"{int(np.sum(np.abs(lon) > 180))} with |lon| > 180 (e.g. {lon[np.abs(lon) > 180][0]:g})"
            )
        out = (alt < ALT_MIN_M) | (alt > ALT_MAX_M)
        if np.any(out):
            parts.append(
                f"{int(np.sum(out))} with altitude outside [{ALT_MIN_M:g}, {ALT_MAX_M:g}] m "
                f"(e.g. {alt[out][0]:g})"
            )
    return ", ".join(parts)


def _fix_sigma(gnss: GnssData) -> np.ndarray:
    """A 3D 1-sigma per fix (m): the fix's own std, else from HDOP, else a consumer default."""
    sigma = np.linalg.norm(np.nan_to_num(gnss.std, nan=0.0), axis=1)
    from_dop = UERE_FOR_DOP_M * np.where(np.isfinite(gnss.pdop), gnss.pdop, gnss.hdop)
    sigma = np.where(np.all(np.isfinite(gnss.std), axis=1), sigma, np.nan)
    sigma = np.where(np.isfinite(sigma), sigma, from_dop)
    return np.where(np.isfinite(sigma) & (sigma > 0), sigma, DEFAULT_FIX_SIGMA_M)


def _ecef(lla: np.ndarray) -> np.ndarray:
    """WGS-84 ECEF (m), vectorised (distances between fixes anywhere on Earth)."""
    a, f = 6378137.0, 1 / 298.257223563
    e2 = f * (2 - f)
    lat, lon, alt = np.radians(lla[:, 0]), np.radians(lla[:, 1]), lla[:, 2]
    n = a / np.sqrt(1 - e2 * np.sin(lat) ** 2)
    return np.column_stack(
        [
            (n + alt) * np.cos(lat) * np.cos(lon),
            (n + alt) * np.cos(lat) * np.sin(lon),
            (n * (1 - e2) + alt) * np.sin(lat),
        ]
    )


def _implausible_jumps(t: np.ndarray, xyz: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Mask of fixes that disagree with most of their neighbours by more than any vehicle moves.

    Fix i and j agree when |x_i - x_j| <= v_max |t_i - t_j| + k (sigma_i + sigma_j). A fix is
    implausible when it disagrees with more than half of the (up to 2 x JUMP_NEIGHBOURS)
    fixes around it: a lone spike disagrees with all of them, its neighbours with one or two.
    Repeated on the remaining fixes until nothing changes (a run of bad fixes). O(N).
    """
    bad = np.zeros(t.size, dtype=bool)
    for _ in range(5):
        idx = np.flatnonzero(~bad)
        n = idx.size
        if n < 3:
            break
        disagree = np.zeros(n)
        compared = np.zeros(n)
        for k in range(1, min(JUMP_NEIGHBOURS, n - 1) + 1):
            a, b = idx[:-k], idx[k:]
            distance = np.linalg.norm(xyz[b] - xyz[a], axis=1)
            allowed = MAX_SPEED_M_PER_S * (t[b] - t[a]) + JUMP_SIGMA_FACTOR * (sigma[a] + sigma[b])
            off = (distance > allowed).astype(float)
            disagree[:-k] += off
            disagree[k:] += off
            compared[:-k] += 1
            compared[k:] += 1
        new = disagree > 0.5 * compared
        if not new.any():
            break
        bad[idx[new]] = True
    return bad


def _check_gnss(gnss: GnssData, origin: Origin, checks: list[str]) -> tuple[GnssData, Origin]:
    n = len(gnss)
    if n == 0:
        raise InputError("gnss: no fix at all; nothing to anchor the trajectory")
    origin_is_first_fix = bool(
        np.allclose(
            [origin.lat, origin.lon, origin.alt], gnss.lla[0], rtol=0, atol=1e-12, equal_nan=True
        )
    )
    gnss = _fill_missing_heights(gnss, checks)
    if origin_is_first_fix and not np.isfinite(origin.alt):  # a 2-D first fix, height given
        origin = Origin(*(float(v) for v in gnss.lla[0]))
    keep = _geodetic_ok(gnss.lla)
    if not keep.any():
        raise InputError(
            f"gnss: none of the {n} fixes has a possible position ({_describe_bad_lla(gnss.lla)}); "
            "check the columns (lat, lon in degrees, ellipsoidal altitude in m)"
        )
    if not keep.all():
        checks.append(
            f"gnss: dropped {int((~keep).sum())} of {n} fix(es) outside the geodetic ranges "
            f"({_describe_bad_lla(gnss.lla[~keep])}) as implausible"
        )
        gnss = gnss.subset(keep)
    gnss = check_gnss_records(gnss, checks)
    gnss = _drop_no_fix(gnss, checks)
    bad = _implausible_jumps(gnss.t, _ecef(gnss.lla), _fix_sigma(gnss))
    if bad.all() or (~bad).sum() < 1:
        raise InputError("gnss: no two fixes agree with each other; the positions are not usable")
    if bad.any():
        times = ", ".join(f"{v - gnss.t[0]:.1f}" for v in gnss.t[bad][:5])
        more = " ..." if bad.sum() > 5 else ""
        checks.append(
            f"gnss: dropped {int(bad.sum())} fix(es) that jump further than "
            f"{MAX_SPEED_M_PER_S:g} m/s from their neighbours (beyond {JUMP_SIGMA_FACTOR:g} "
            f"sigma) as implausible, at t - t_gnss0 = {times}{more} s"
        )
        gnss = gnss.subset(~bad)
    _reject_persistent_jumps(gnss)
    _warn_radians(gnss, checks)
    if not _geodetic_ok(np.array([[origin.lat, origin.lon, origin.alt]]))[0]:
        if not origin_is_first_fix:
            raise InputError(
                f"origin ({origin.lat:g}, {origin.lon:g}, {origin.alt:g} m) is outside the "
                "geodetic ranges; fix the [origin] table of config.toml"
            )
    if origin_is_first_fix and not np.allclose(
        [origin.lat, origin.lon, origin.alt], gnss.lla[0], rtol=0, atol=1e-12
    ):
        origin = Origin(*(float(v) for v in gnss.lla[0]))
        checks.append(
            "gnss: the first fix was implausible; the local frame's origin is the first fix kept "
            f"({origin.lat:.7f}, {origin.lon:.7f}, {origin.alt:.2f} m)"
        )
    return gnss, origin


def _warn_radians(gnss: GnssData, checks: list[str]) -> None:
    """Every fix inside |lat| <= pi/2, |lon| <= pi: latitude and longitude given in radians
    look like a valid place in the Gulf of Guinea, 57x too close together (a drive of 1 km
    shrinks to 17 m). Rare for real data there, so a warning, not an error; with velocity
    columns the speed check below turns it into a clear error."""
    lat, lon = gnss.lla[:, 0], gnss.lla[:, 1]
    if len(lat) and np.all(np.abs(lat) <= np.pi / 2) and np.all(np.abs(lon) <= np.pi):
        checks.append(
            f"gnss: every fix lies within {np.pi / 2:.4f} deg of latitude and {np.pi:.4f} deg of "
            "longitude of (0, 0): if the lat/lon columns are in radians, convert them to degrees"
        )


def _fill_missing_heights(gnss: GnssData, checks: list[str]) -> GnssData:
    """2-D fixes (latitude and longitude without a height: NMEA RMC without GGA, a GGA with
    an empty altitude, a 2-D fix) get the height of the 3-D fixes around them (held at the
    ends) with a vertical sigma of ``HELD_HEIGHT_SIGMA_M``; in a log without any height, 0 m
    with ``NO_HEIGHT_SIGMA_M``: the horizontal solution is as good, the vertical says it is
    unknown. Counted in one line."""
    lla = gnss.lla
    with np.errstate(invalid="ignore"):
        flat = np.all(np.isfinite(lla[:, :2]), axis=1) & ~np.isfinite(lla[:, 2])
    if not flat.any():
        return gnss
    solid = np.all(np.isfinite(lla), axis=1)
    lla, std = lla.copy(), gnss.std.copy()
    if solid.any():
        lla[flat, 2] = np.interp(gnss.t[flat], gnss.t[solid], lla[solid, 2])
        sigma, how = HELD_HEIGHT_SIGMA_M, "the height of the 3-D fixes around them"
    else:
        # One invented height, not N measurements of it: each held 0 m gets sqrt(N) x the
        # sigma, so that all of them together say "within ~1 km" (241 fixes at 1000 m each
        # claimed 64 m).
        lla[flat, 2] = 0.0
        sigma = NO_HEIGHT_SIGMA_M * math.sqrt(int(flat.sum()))
        how = "height 0 m (the log has no height at all; together they weigh as one)"
    std[flat, 2] = np.fmax(np.nan_to_num(std[flat, 2], nan=0.0), sigma)
    checks.append(
        f"gnss: {int(flat.sum())} of {len(gnss)} fix(es) without a height (2-D: RMC without "
        f"GGA, an empty altitude) given {how}, vertical sigma {sigma:g} m"
    )
    return replace(gnss, lla=lla, std=std)


HELD_HEIGHT_SIGMA_M = 30.0
NO_HEIGHT_SIGMA_M = 1000.0


def _drop_no_fix(gnss: GnssData, checks: list[str]) -> GnssData:
    """Epochs that are a receiver's "no fix" in a fix's clothes: position exactly (0, 0) (null
    island, what a receiver reports before its first fix) or a horizontal sigma above
    ``NO_FIX_SIGMA_M`` (u-blox NAV-POSLLH before a fix: hAcc 4,294,967 m). Kept, they became
    the local frame's origin and the batch "diverged" with chi2/dof 1e11."""
    lat, lon = gnss.lla[:, 0], gnss.lla[:, 1]
    null_island = (lat == 0.0) & (lon == 0.0)
    with np.errstate(invalid="ignore"):
        vague = np.nan_to_num(np.hypot(gnss.std[:, 0], gnss.std[:, 1])) > NO_FIX_SIGMA_M
    drop = null_island | vague
    if not drop.any():
        return gnss
    if drop.all():
        raise InputError(
            f"gnss: none of the {len(gnss)} fixes is a fix: "
            f"{int(null_island.sum())} at position (0, 0), {int((vague & ~null_island).sum())} "
            f"with a horizontal sigma above {NO_FIX_SIGMA_M:g} m (what receivers report "
            "without a fix)"
        )
    checks.append(
        f"gnss: dropped {int(drop.sum())} of {len(gnss)} epoch(s) that report no fix "
        f"({int(null_island.sum())} at position (0, 0), {int((vague & ~null_island).sum())} "
        f"with a horizontal sigma above {NO_FIX_SIGMA_M:g} m)"
    )
    return gnss.subset(~drop)


NO_FIX_SIGMA_M = 1000.0


# A DOP the receiver could not compute is sent as a placeholder, not left empty: u-blox caps
# its U2 DOP fields at 99.99 (NAV-DOP, NAV-PVT pDOP: ublox-glo gives hDOP 99.99 next to vDOP
# 1.0), NMEA receivers print 99.9/99.99 in GSA or 99.0 in GGA, or 0.00. Taken as DOPs they gate
# every epoch (pdop_max) or scale a sigma to 500 m or to 0: they are missing (NaN) instead, and
# the sigma falls back as for a log without DOPs. Geometry that bad has no usable fix anyway.
DOP_NOT_AVAILABLE_MIN = 99.0


def _clean_sigmas(gnss: GnssData, checks: list[str]) -> GnssData:
    """Sigmas and DOPs must be positive and finite where given, velocities finite and below
    any vehicle's; others are ignored (counted). DOP placeholders (0, >= ``DOP_NOT_AVAILABLE_MIN``) become missing, counted."""
    std = gnss.std
    given = ~np.isnan(std)
    bad_std = given & ~(np.isfinite(std) & (std > 0))
    replaced = {}
    if bad_std.any():
        std = np.where(bad_std, np.nan, std)
        replaced["std"] = std
        checks.append(
            f"gnss: {int(bad_std.any(axis=1).sum())} fix(es) with a zero, negative or infinite "
            "sigma; those sigmas ignored (DOP or the [gnss] config used instead)"
        )
    if gnss.velocity is not None:
        velocity = np.asarray(gnss.velocity, dtype=float)
        with np.errstate(invalid="ignore", over="ignore"):
            bad_velocity = np.any(~np.isnan(velocity) & ~np.isfinite(velocity), axis=1) | (
                np.nan_to_num(np.linalg.norm(np.nan_to_num(velocity, posinf=0, neginf=0), axis=1))
                > MAX_SPEED_M_PER_S
            )
        if bad_velocity.any():
            velocity = velocity.copy()
            velocity[bad_velocity] = np.nan
            replaced["velocity"] = velocity
            checks.append(
                f"gnss: {int(bad_velocity.sum())} fix(es) with an infinite velocity or one "
                f"above {MAX_SPEED_M_PER_S:g} m/s; those velocities ignored (positions kept)"
            )
    bad_dops = 0
    placeholders = np.zeros(len(gnss), dtype=bool)
    placeholder_values = 0
    for name in ("hdop", "vdop", "pdop"):
        value = getattr(gnss, name)
        with np.errstate(invalid="ignore"):
            absent = (value == 0.0) | ((value >= DOP_NOT_AVAILABLE_MIN) & np.isfinite(value))
        bad = ~np.isnan(value) & ~(np.isfinite(value) & (value > 0)) & ~absent
        if bad.any() or absent.any():
            bad_dops += int(bad.sum())
            placeholder_values += int(absent.sum())
            placeholders |= absent
            replaced[name] = np.where(bad | absent, np.nan, value)
    if placeholder_values:
        checks.append(
            f"gnss: {placeholder_values} DOP value(s) in {int(placeholders.sum())} fix(es) are "
            f"the receiver's 'not available' (0, or >= {DOP_NOT_AVAILABLE_MIN:g}: u-blox 99.99, "
            "NMEA 99.99/0.00): treated as missing (sigmas from the fixes' own accuracy, else "
            "UERE x another DOP or [gnss] default_sigma_m; no PDOP gate on them)"
        )
    if bad_dops:
        checks.append(f"gnss: {bad_dops} negative or infinite DOP value(s) ignored")
    return replace(gnss, **replaced) if replaced else gnss


def _note_not_measured(gnss: GnssData, checks: list[str]) -> None:
    """A note for fixes whose quality says they are no measurement (6 dead reckoning, 7 manual
    input, 8 simulator): the smoother's gate leaves them out, the user should know why; a log
    that is all simulator (Garmin GPSmap-76S, Geko 201 in demo mode) is said as such."""
    from fgins.factors.gnss import NOT_MEASURED_QUALITIES

    quality = np.asarray(gnss.fix_quality)
    counts = {q: int((quality == q).sum()) for q in NOT_MEASURED_QUALITIES}
    total = sum(counts.values())
    if not total:
        return
    gate = "the smoother's fix-quality gate leaves them out (\"by fix quality\")"
    if total == len(quality) and len({q for q, n in counts.items() if n}) == 1:
        q = next(q for q, n in counts.items() if n)
        what = (
            "the receiver was in simulator mode, its positions are not GNSS measurements"
            if q == 8
            else f"{NOT_MEASURED_QUALITIES[q]}, not GNSS measurements"
        )
        checks.append(f"gnss: every fix ({total}) has fix quality {q}: {what}; {gate}")
        return
    kinds = ", ".join(
        f"{n} with {q} ({NOT_MEASURED_QUALITIES[q]})" for q, n in counts.items() if n
    )
    checks.append(
        f"gnss: {total} of {len(quality)} fix(es) are not GNSS measurements by their fix "
        f"quality ({kinds}); {gate}"
    )


def check_gnss_records(gnss: GnssData, checks: list[str]) -> GnssData:
    """The checks a GNSS record needs without an IMU: sigmas and DOPs that are not positive
    finite numbers or are "not available" placeholders become missing (counted), and fixes
    that are no measurement by their quality are noted. :func:`validate_dataset` applies it
    to every dataset, ``fgins convert`` to the fixes it writes (fix_quality kept)."""
    gnss = _clean_sigmas(gnss, checks)
    _note_not_measured(gnss, checks)
    return gnss


def _reject_persistent_jumps(gnss: GnssData) -> None:
    """After spikes are gone, a jump between consecutive fixes means two sources in one log."""
    if len(gnss) < 2:
        return
    xyz = _ecef(gnss.lla)
    sigma = _fix_sigma(gnss)
    distance = np.linalg.norm(np.diff(xyz, axis=0), axis=1)
    dt = np.diff(gnss.t)
    allowed = MAX_SPEED_M_PER_S * dt + JUMP_SIGMA_FACTOR * (sigma[1:] + sigma[:-1])
    off = np.flatnonzero(distance > allowed)
    if off.size:
        i = int(off[0])
        raise InputError(
            f"gnss: the position jumps {distance[i] / 1e3:.1f} km in {dt[i]:.1f} s at "
            f"t={gnss.t[i + 1]:.3f} ({distance[i] / max(dt[i], 1e-9):.0f} m/s, faster than any "
            f"vehicle) and stays there ({off.size} such jump(s)); the log mixes two receivers or "
            "datums: split it"
        )


def _gnss_gap_limit(t: np.ndarray) -> float:
    """A stretch without fixes longer than this is a gap: 10 fix intervals, at least 5 s."""
    nominal = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    return max(GNSS_GAP_PERIODS * nominal, GNSS_GAP_MIN_S)


def _report_gnss_time_gaps(t: np.ndarray, checks: list[str]) -> None:
    """GNSS gaps far beyond the fix interval: outages, or a clock that jumped."""
    if len(t) < 3:
        return
    dt = np.diff(t)
    limit = _gnss_gap_limit(t)
    jumps = np.flatnonzero(dt > limit)
    if jumps.size:
        largest = int(jumps[int(np.argmax(dt[jumps]))])
        checks.append(
            f"gnss: {jumps.size} gap(s) in the fixes longer than {limit:.0f} s (largest "
            f"{dt[largest]:.1f} s at t={t[largest]:.1f}): outages or a time jump"
        )


# --------------------------------------------------------------------------------------------
# Time bases
# --------------------------------------------------------------------------------------------


# No navigation receiver reports fixes this far apart (the gyro-free study's slowest is 5 s).
GNSS_MAX_EPOCH_INTERVAL_S = 100.0


def _check_time_bases(
    t_imu: np.ndarray, t_gnss: np.ndarray, checks: list[str], n_read: int = 0
) -> None:
    """The GNSS epochs against the IMU's span; ``n_read``: the fixes the reader gave (before
    the GNSS checks dropped any), to tell a log with one fix from two clocks."""
    a, b = float(t_imu[0]), float(t_imu[-1])
    c, d = float(t_gnss[0]), float(t_gnss[-1])
    inside = (t_gnss >= a) & (t_gnss <= b)
    if t_gnss.size == 1 and inside.all():
        # One fix in the whole input, inside the IMU span: nothing to do with the clocks.
        dropped = n_read - 1
        notes = [line.removeprefix("gnss: ") for line in checks if line.startswith("gnss:")]
        why = f" ({dropped} of the {n_read} read were dropped as unusable" if dropped > 0 else ""
        why += f": {notes[0]})" if why and notes else ")" if why else ""
        raise InputError(
            f"gnss: the input has only 1 usable GNSS fix (at t = {c:.3f} s){why}; at least 2 "
            "are needed to anchor the trajectory (position and heading): give a GNSS log that "
            "covers the drive"
        )
    if not inside.any():
        raise InputError(
            f"the IMU ({a:.3f} .. {b:.3f} s) and the GNSS ({c:.3f} .. {d:.3f} s) time spans do "
            f"not overlap (offset ~{c - a:+.3f} s): the files use different time bases; give "
            "--time-offset SECONDS (added to the GNSS times) or convert one clock"
        )
    if inside.sum() < 2:
        # One fix cannot anchor a trajectory; say why there is only one, not "alignment
        # needs 2 fixes" (GNSS times in milliseconds overlap the IMU at t = 0 only).
        spacing = float(np.median(np.diff(t_gnss))) if t_gnss.size > 1 else float("nan")
        if spacing >= GNSS_MAX_EPOCH_INTERVAL_S:
            hint = (
                f"the GNSS times look like milliseconds (fixes {spacing:.4g} units apart): give "
                "them in seconds"
            )
        elif c >= a - max(2 * spacing, 2.0) and d <= b + max(2 * spacing, 2.0):
            # The fixes lie where the IMU is (one clock), there are just too few of them (a
            # log cut short), not an offset.
            hint = (
                f"the recording is too short (IMU {b - a:.1f} s, {t_gnss.size} fixes): at least "
                "2 fixes within the IMU's span are needed; give a longer log"
            )
        else:
            hint = (
                "the files use different time bases? give --time-offset SECONDS or convert "
                "one clock"
            )
        raise InputError(
            f"only {int(inside.sum())} of {t_gnss.size} GNSS fixes lie within the IMU time "
            f"span ({a:.3f} .. {b:.3f} s; GNSS {c:.3f} .. {d:.3f} s): {hint}"
        )
    outside = int((~inside).sum())
    if outside:
        checks.append(
            f"time: {outside} of {t_gnss.size} GNSS epoch(s) lie outside the IMU time span "
            f"({a:.3f} .. {b:.3f} s; GNSS {c:.3f} .. {d:.3f} s) and cannot be used"
        )
    # The output covers the IMU's span; where no fix brackets it, it is dead reckoning.
    first, last = float(t_gnss[inside][0]), float(t_gnss[inside][-1])
    limit = _gnss_gap_limit(t_gnss)
    ends = [
        f"{span:.1f} s {where}"
        for span, where in ((first - a, "before the first fix"), (b - last, "after the last fix"))
        if span > limit
    ]
    if ends:
        checks.append(
            f"time: the IMU runs {' and '.join(ends)}: the trajectory there is dead reckoning "
            "(its std_* grow accordingly)"
        )


# --------------------------------------------------------------------------------------------
# Units
# --------------------------------------------------------------------------------------------


def _check_imu_time_unit(t: np.ndarray) -> None:
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


def _check_units(
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
    if has_accel_array:
        # Rates derived from an accelerometer array carry a large, ramping bias by nature;
        # their unit follows from the accelerometers', checked above.
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
            f"imu: the gyro looks like deg/s, not rad/s: over {turns} {TURN_WINDOW_S:g}-s windows "
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
            f"imu: the gyro does not see the turns: over {turns} {TURN_WINDOW_S:g}-s windows of "
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


def _clock_offset_explains_turns(
    imu, gnss: GnssData, enu: np.ndarray, up: np.ndarray, origin: Origin,
    given_offset_s: object, *, banks: bool,
) -> None:
    """Raise the clock-offset error when the gyro's turns disagree with the track's at the
    stamped times but agree (size and sense) once the fixes are moved by the offset the
    turns show. A mirrored track (lat/lon swapped) lines up best somewhere too (a false
    -14 s at 2.2x): it still disagrees there, and the caller's error stands."""
    lag, verdict = _clock_verdict(imu, gnss, enu, up, given_offset_s, banks=banks)
    if verdict is None or verdict[0] != "error":
        return
    moved = replace(gnss, t=gnss.t + lag)
    ratio, turns, turn_sign = _gyro_turn_ratio(imu, moved, origin)
    agree = GYRO_TURN_RATIO_MIN <= ratio <= GYRO_TURN_RATIO_MAX and turn_sign >= -TURN_SIGN_MIN_RATIO
    if turns >= TURN_SIGN_MIN_WINDOWS and agree:
        raise InputError(verdict[1])


def _check_clock_offset(
    imu, gnss: GnssData, enu: np.ndarray, up: np.ndarray, checks: list[str],
    given_offset_s: object, *, banks: bool = False,
) -> None:
    """The GNSS clock against the IMU's from the drive's turns (:mod:`fgins.io.clock_offset`):
    an offset of seconds is an error naming the --time-offset that aligns them (KITTI with 3 s
    added ran 29 s to a fit blamed on the lever arm and the mounting), a fraction of a second
    a warning. Only for a body that yaws with its track (not a multirotor or a walker)."""
    _, verdict = _clock_verdict(imu, gnss, enu, up, given_offset_s, banks=banks)
    if verdict is None:
        return
    kind, message = verdict
    if kind == "error":
        raise InputError(message)
    checks.append(message)


def _clock_verdict(
    imu, gnss: GnssData, enu: np.ndarray, up: np.ndarray, given_offset_s: object, *, banks: bool
) -> tuple[float, tuple[str, str] | None]:
    """(the lag the turns show, s; :func:`fgins.io.clock_offset.judge`'s verdict on it)."""
    from fgins.io.clock_offset import estimate_clock_offset, judge

    offset = estimate_clock_offset(imu.t, imu.gyro @ up, gnss.t, enu[:, :2])
    given = float(given_offset_s) if isinstance(given_offset_s, (int, float)) else 0.0
    return (offset.lag_s if offset else 0.0), judge(offset, given, banks=banks)


def _chord_velocity(gnss: GnssData, enu: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The velocity the fixes' own VELOCITY_CHORD_S chords show, centred on each fix:
    (dense: the chord spans most of its length, velocity (N, 3), clear: a horizontal speed
    well above what the fixes' noise fakes over the chord and above TURN_MIN_SPEED_M_PER_S;
    a few satellites give tens of metres of scatter, "metres per second" at a standstill)."""
    t = gnss.t
    a = np.searchsorted(t, t - VELOCITY_CHORD_S / 2)
    b = np.clip(np.searchsorted(t, t + VELOCITY_CHORD_S / 2, side="right") - 1, 0, len(t) - 1)
    span = t[b] - t[a]
    dense = span > 0.75 * VELOCITY_CHORD_S
    sigma = _fix_sigma(gnss)
    with np.errstate(invalid="ignore", divide="ignore"):
        velocity = (enu[b] - enu[a]) / span[:, None]
        noise = np.sqrt(sigma[a] ** 2 + sigma[b] ** 2) / span
        speed = np.hypot(velocity[:, 0], velocity[:, 1])
        clear = dense & np.isfinite(speed) & (speed > np.maximum(TURN_MIN_SPEED_M_PER_S, 3 * noise))
    return dense, velocity, clear


def _check_wheel_speed(odometer, gnss: GnssData, enu: np.ndarray) -> None:
    """The wheel speed against the speed the fixes' own 4-s chords show, where they move well
    beyond their noise: a median ratio outside 0.7-1.4 is a unit (km/h: the wheel-speed
    scale state took +260 % on a simulated car and the run said nothing but that number) or
    a wheel's angular rate. A wheel log beside no moving fix is not judged."""
    t = gnss.t
    dense, track, clear = _chord_velocity(gnss, enu)
    track_speed = np.hypot(track[:, 0], track[:, 1])
    # Only where a wheel sample lies within half a second (a wheel log covering part of the
    # drive is judged where it is).
    nearest = np.clip(np.searchsorted(odometer.t, t), 1, len(odometer.t) - 1)
    close = np.minimum(np.abs(odometer.t[nearest] - t), np.abs(odometer.t[nearest - 1] - t))
    moving = dense & clear & (close <= 0.5)
    if moving.sum() < VELOCITY_MIN_EPOCHS:
        return
    wheel = np.abs(np.interp(t[moving], odometer.t, odometer.speed))
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


def _check_gnss_velocity(gnss: GnssData, origin: Origin) -> None:
    """The receiver's velocity against the velocity its own fixes show (see the constants)."""
    from fgins.geodesy import lla_to_enu

    if gnss.velocity is None or len(gnss.t) < 3:
        return
    enu = lla_to_enu(gnss.lla, origin)
    dense, track_all, clear = _chord_velocity(gnss, enu)
    if dense.sum() < VELOCITY_MIN_EPOCHS:
        return
    track = track_all[dense]
    given = gnss.velocity[dense]
    track_speed = np.hypot(track[:, 0], track[:, 1])
    given_speed = np.hypot(given[:, 0], given[:, 1])
    moving = np.isfinite(given_speed) & clear[dense]
    _check_shrunk_track(gnss, enu, _fix_sigma(gnss))
    if moving.sum() >= VELOCITY_MIN_EPOCHS:
        from_course = _velocity_from_speed_course(gnss)
        ratio = float(np.median(given_speed[moving] / track_speed[moving]))
        if not VELOCITY_SPEED_RATIO_RANGE[0] <= ratio <= VELOCITY_SPEED_RATIO_RANGE[1]:
            what, fix = (
                ("speed over ground gives", "give the speed column in m/s")
                if from_course
                else ("velocity columns give", "give vel_east/north/up in m/s")
            )
            raise InputError(
                f"gnss: the {what} {ratio:.3g} times the speed the fixes show "
                f"(~1 expected; km/h gives 3.6, knots 1.94): {fix}"
            )
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
    climb = track[:, 2]
    given_climb = given[:, 2]
    usable = np.isfinite(given_climb)
    if usable.sum() >= VELOCITY_MIN_EPOCHS and np.std(given_climb[usable]) >= CLIMB_MIN_STD_M_S:
        slope = float(
            np.sum(climb[usable] * given_climb[usable]) / np.sum(given_climb[usable] ** 2)
        )
        if not CLIMB_RATIO_RANGE[0] <= slope <= CLIMB_RATIO_RANGE[1]:
            raise InputError(
                f"gnss: the altitude changes {slope:.3g} times as fast as vel_up says (~1 "
                "expected; 3.28 for altitude in feet, -1 for a down velocity): give the "
                "altitude in metres and vel_up positive up"
            )


# Fixes that move this many times less than the velocity says do not move at all (lat/lon in
# radians gives 1/57): a frozen output, not a unit.
FROZEN_RATIO = 1e-3
FROZEN_SPREAD_M = 0.01  # all fixes within this: one position repeated
FROZEN_MIN_FIXES = 10
TURNING_RATE_RAD_S = 0.1  # 1-s mean yaw rates this far from their median: the IMU turns
MOVING_ACCEL_M_S2 = 1.0  # 1-s mean horizontal specific force this far: it speeds up or brakes


def _frozen_note(gnss: GnssData) -> str:
    return f"{len(gnss.t)} fixes over {gnss.t[-1] - gnss.t[0]:.0f} s"


def _mean_up(imu) -> np.ndarray:
    """Up in IMU axes: the mean accelerometer reading (gravity's reaction)."""
    up = np.mean(imu.accel, axis=0)
    return up / max(float(np.linalg.norm(up)), 1e-9)


def _check_frozen_position(gnss: GnssData, enu: np.ndarray, imu, up: np.ndarray) -> None:
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
    rate = 1.0 / float(np.median(np.diff(imu.t)))
    n = max(round(rate), 5)
    blocks = len(imu.t) // n
    if blocks < 3:
        return
    gyro = imu.gyro[: blocks * n].reshape(blocks, n, 3).mean(axis=1)
    accel = imu.accel[: blocks * n].reshape(blocks, n, 3).mean(axis=1)
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


def _check_track_scale_by_turns(gnss: GnssData, enu: np.ndarray, imu, up: np.ndarray) -> None:
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
    gyro = imu.gyro[: blocks * n].reshape(blocks, n, 3).mean(axis=1)
    accel = imu.accel[: blocks * n].reshape(blocks, n, 3).mean(axis=1)
    yaw_rate = np.abs(gyro @ up - np.median(gyro @ up))
    horizontal = accel - np.outer(accel @ up, up)
    force = np.linalg.norm(horizontal - np.median(horizontal, axis=0), axis=1)
    inside = (t_mid > t_fix[0]) & (t_mid < t_fix[-1])
    turns = inside & (yaw_rate > SCALE_TURN_RAD_S) & (force > SCALE_FORCE_M_S2)
    if turns.sum() < SCALE_MIN_TURNS:
        return
    velocity = np.gradient(xy, t_fix, axis=0)
    speed = np.hypot(*(np.interp(t_mid[turns], t_fix, velocity[:, i]) for i in range(2)))
    ratio = float(np.median(speed / (force[turns] / yaw_rate[turns])))
    if ratio < SCALE_SHRUNK_RATIO:
        raise InputError(
            f"gnss: the fixes move {1.0 / max(ratio, 1e-9):.3g} times slower than the IMU's "
            f"turns say (their speed against horizontal specific force over yaw rate, median "
            f"of {int(turns.sum())} 1-s turns; ~1 expected, lat/lon in radians gives "
            "57): give lat/lon in degrees (and positions in metres)"
        )


# A turn: 1-s means of the yaw rate and the horizontal specific force above these; this
# many of them; the fixes' speed over the speed they imply below this is a shrunk track.
SCALE_TURN_RAD_S = 0.05
SCALE_FORCE_M_S2 = 0.5
SCALE_MIN_TURNS = 8
SCALE_SHRUNK_RATIO = 0.1


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
    """Median gyro-rate norm over 1-s windows where the vehicle is at rest: a steady specific
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
    return float(np.median(np.linalg.norm(gyro[rest].mean(axis=1), axis=1)))


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


def _gyro_turn_ratio(imu, gnss: GnssData, origin: Origin) -> tuple[float, int, float]:
    """Median of |integrated gyro| / |GNSS course change| over windows with a clear turn,
    their number, and the median over them of the gyro's rotation about up over the course
    change (up: the mean accelerometer reading, the reaction to gravity; ~+1).

    The course at a time comes from positions TURN_WINDOW_S/2 apart (a few metres of noise are
    small against the tens of metres travelled); a window spans TURN_WINDOW_S seconds between
    two such courses. Only windows whose end points lie among dense fixes (no outage) count.
    """
    from fgins.geodesy import lla_to_enu

    t = gnss.t
    half = TURN_WINDOW_S / 2
    lo, hi = max(t[0], imu.t[0]) + half, min(t[-1], imu.t[-1]) - half
    if t.size < 4 or hi - lo < TURN_WINDOW_S:
        return math.nan, 0, math.nan
    step = TURN_WINDOW_S / 4
    grid = np.arange(lo, hi, step)
    enu = lla_to_enu(gnss.lla, origin)
    a, b = grid - half / 2, grid + half / 2
    east = np.interp(b, t, enu[:, 0]) - np.interp(a, t, enu[:, 0])
    north = np.interp(b, t, enu[:, 1]) - np.interp(a, t, enu[:, 1])
    # largest fix interval around each course's baseline: an outage makes the course a guess
    idx_a = np.clip(np.searchsorted(t, a), 1, t.size - 1)
    idx_b = np.clip(np.searchsorted(t, b), 1, t.size - 1)
    local_gap = np.maximum(t[idx_a] - t[idx_a - 1], t[idx_b] - t[idx_b - 1])
    good = (np.hypot(east, north) / half > TURN_MIN_SPEED_M_PER_S) & (local_gap <= half / 2)
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
    moving = good[i0] & good[i1]
    rotated = np.linalg.norm(rotation, axis=1)
    signed_turn = course[i1] - course[i0]  # compass course: clockwise positive
    use = moving & (np.abs(signed_turn) > TURN_MIN_RAD)
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
