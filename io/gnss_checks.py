"""GNSS record and time-base checks of the input-validation layer (:mod:`fgins.io.validate`):
geodetic ranges, sigmas and DOPs, fixes that are no measurement, jumps no vehicle can make,
time gaps, IMU and GNSS time bases. GTSAM-free."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from fgins.datatypes import GnssData, InputError, Origin

# Geodetic ranges for the supported vehicles (cars, UAVs, aircraft): below the Dead Sea shore
# (-430 m) and deep mines with margin; above any aircraft (1e5 m is the Karman line).
ALT_MIN_M, ALT_MAX_M = -1000.0, 1.0e5
# No supported vehicle moves faster (airliners ~250 m/s, fast jets ~700 m/s).
MAX_SPEED_M_PER_S = 1000.0
JUMP_SIGMA_FACTOR = 5.0  # tolerance in the fixes' own sigmas on top of the speed bound
DEFAULT_FIX_SIGMA_M = 10.0  # a fix without any sigma or DOP: a consumer receiver's error
UERE_FOR_DOP_M = 5.0
JUMP_NEIGHBOURS = 3  # a fix is judged against this many fixes on each side
# A chord between two fixes judges the track's speed only where it spans far more than the
# fixes' own scatter; this many sigmas (of both ends) at least.
TRACK_CHORD_SIGMAS = 10.0
TRACK_CHORDS_MIN = 5
GNSS_GAP_MIN_S = 5.0
GNSS_GAP_PERIODS = 10.0


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


def fix_sigma(gnss: GnssData) -> np.ndarray:
    """A 3D 1-sigma per fix (m): the fix's own std, else from HDOP, else a consumer default."""
    sigma = np.linalg.norm(np.nan_to_num(gnss.std, nan=0.0), axis=1)
    from_dop = UERE_FOR_DOP_M * np.where(np.isfinite(gnss.pdop), gnss.pdop, gnss.hdop)
    sigma = np.where(np.all(np.isfinite(gnss.std), axis=1), sigma, np.nan)
    sigma = np.where(np.isfinite(sigma), sigma, from_dop)
    return np.where(np.isfinite(sigma) & (sigma > 0), sigma, DEFAULT_FIX_SIGMA_M)


def horizontal_fix_sigma(gnss: GnssData) -> np.ndarray:
    """A horizontal (2-D) 1-sigma per fix (m): from the fix's own std east/north, else
    UERE x HDOP, else the 3-D :func:`fix_sigma`. What chords between fixes over ground
    scatter by: their 3-D sigma (a 5 m vertical beside 3 m horizontal) faked a 7 m/s
    threshold for "moving clearly" (outside tester: a 5 m/s boat)."""
    std = np.asarray(gnss.std, dtype=float)[:, :2]
    sigma = np.where(np.all(np.isfinite(std), axis=1), np.linalg.norm(np.nan_to_num(std), axis=1), np.nan)
    sigma = np.where(np.isfinite(sigma) & (sigma > 0), sigma, UERE_FOR_DOP_M * gnss.hdop)
    return np.where(np.isfinite(sigma) & (sigma > 0), sigma, fix_sigma(gnss))


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


def check_gnss(gnss: GnssData, origin: Origin, checks: list[str]) -> tuple[GnssData, Origin]:
    n = len(gnss)
    if n == 0:
        raise InputError("gnss: no fix at all; nothing to anchor the trajectory")
    origin_is_first_fix = bool(
        np.allclose(
            [origin.lat, origin.lon, origin.alt], gnss.lla[0], rtol=0, atol=1e-12, equal_nan=True
        )
    )
    gnss = fill_missing_heights(gnss, checks)
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
    _reject_rounded_positions(gnss)
    bad = _implausible_jumps(gnss.t, _ecef(gnss.lla), fix_sigma(gnss))
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
    # The kept fixes' positions and sigmas, for both checks of the track as a whole.
    xyz, sigma = _ecef(gnss.lla), fix_sigma(gnss)
    _reject_persistent_jumps(gnss, xyz, sigma)
    _reject_steps_against_velocities(gnss, xyz, sigma)
    _reject_impossible_track_speed(gnss, xyz, sigma)
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


def fill_missing_heights(gnss: GnssData, checks: list[str]) -> GnssData:
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
    with np.errstate(invalid="ignore"):
        # No position geometry (PDOP not available): a DOP beside it is no DOP either (u-blox
        # NAV-DOP with pDOP 99.99 sends vDOP 1.00, which made a median VDOP of 1.0).
        no_geometry = (gnss.pdop == 0.0) | ((gnss.pdop >= DOP_NOT_AVAILABLE_MIN) & np.isfinite(gnss.pdop))
    beside = 0  # DOPs dropped beside a PDOP that is not available
    for name in ("hdop", "vdop", "pdop"):
        value = getattr(gnss, name)
        with np.errstate(invalid="ignore"):
            absent = (value == 0.0) | ((value >= DOP_NOT_AVAILABLE_MIN) & np.isfinite(value))
            companion = no_geometry & ~absent & ~np.isnan(value)
        bad = ~np.isnan(value) & ~(np.isfinite(value) & (value > 0)) & ~absent & ~companion
        if bad.any() or absent.any() or companion.any():
            bad_dops += int(bad.sum())
            placeholder_values += int(absent.sum())
            beside += int(companion.sum())
            placeholders |= absent
            replaced[name] = np.where(bad | absent | companion, np.nan, value)
    if placeholder_values:
        also = (
            f"; {beside} DOP value(s) beside a PDOP not available dropped too (u-blox sends "
            "vDOP 1.00 there)" if beside else ""
        )
        checks.append(
            f"gnss: {placeholder_values} DOP value(s) in {int(placeholders.sum())} fix(es) are "
            f"the receiver's 'not available' (0, or >= {DOP_NOT_AVAILABLE_MIN:g}: u-blox 99.99, "
            "NMEA 99.99/0.00): treated as missing (sigmas from the fixes' own accuracy, else "
            f"UERE x another DOP or [gnss] default_sigma_m; no PDOP gate on them){also}"
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
    gnss = _sigmas_within_fix_quality(gnss, checks)
    _note_not_measured(gnss, checks)
    return gnss


# The smallest horizontal sigma (m) a fix of each GGA quality can have: an SBAS or DGPS
# solution is never good to a decimetre, an RTK float one to centimetres. Not quality 1
# (single point): it is also what a fix without a quality column gets, and an RTK receiver's
# CSV without one was held to 0.3 m.
QUALITY_MIN_SIGMA_M = {2: 0.3, 9: 0.3, 5: 0.05}


def _sigmas_within_fix_quality(gnss: GnssData, checks: list[str]) -> GnssData:
    """Stated sigmas below what the fix's own quality allows (QUALITY_MIN_SIGMA_M) raised to
    it, counted: an RTK receiver's std columns kept claiming 1.5 cm through float, DGPS and
    single-point stretches; weighted so, the scatter check scaled every fix, RTK ones too,
    and the drive came out 0.15 m off at z 3.7 where the quality's weights gave 0.036 m
    (outside tester)."""
    std = np.asarray(gnss.std, dtype=float)
    quality = np.asarray(gnss.fix_quality, dtype=int)
    floor = np.array([QUALITY_MIN_SIGMA_M.get(int(q), 0.0) for q in quality])
    with np.errstate(invalid="ignore"):
        rows = np.any(np.isfinite(std[:, :2]) & (std[:, :2] < floor[:, None]), axis=1)
    if not rows.any():
        return gnss
    raised = std.copy()
    raised[rows, :2] = np.maximum(raised[rows, :2], floor[rows, None])
    raised[rows, 2] = np.maximum(raised[rows, 2], 1.5 * floor[rows])
    kinds = sorted({int(q) for q in quality[rows]})
    checks.append(
        f"gnss: {int(rows.sum())} fix(es) state sigmas below what their fix quality allows "
        f"(quality {', '.join(map(str, kinds))}: at least "
        f"{', '.join(f'{QUALITY_MIN_SIGMA_M[k]:g} m' for k in kinds)}): raised to it"
    )
    return replace(gnss, std=raised)


# Latitude and longitude rounded to this many decimals or fewer (0.0001 deg: 11 m steps, far
# beyond any receiver's sigma) cannot place a vehicle: 3 decimals (110 m) were blamed on the
# velocity columns' unit (outside tester). Real logs carry 6-9 (NMEA's minutes: 6-7).
ROUNDED_MAX_DECIMALS = 4
ROUNDED_MIN_FIXES = 10


def _reject_rounded_positions(gnss: GnssData) -> None:
    # Judged on fixes at several places (a receiver at rest on a round coordinate is not).
    if len(np.unique(gnss.lla[:, :2], axis=0)) < ROUNDED_MIN_FIXES:
        return
    for decimals in range(ROUNDED_MAX_DECIMALS + 1):
        scaled = gnss.lla[:, :2] * 10.0**decimals
        if np.all(np.abs(scaled - np.round(scaled)) < 1e-6):
            step = 111_195.0 * 10.0**-decimals
            raise InputError(
                f"gnss: every latitude and longitude is rounded to {decimals} decimal(s) "
                f"(steps of {step:,.0f} m, far beyond any fix's sigma): write them with 7 or "
                "more decimals (1 cm)"
            )


def _reject_persistent_jumps(gnss: GnssData, xyz: np.ndarray, sigma: np.ndarray) -> None:
    """After spikes are gone, a jump between consecutive fixes means two sources in one log
    (``xyz``, ``sigma``: the fixes' ECEF positions and sigmas)."""
    if len(gnss) < 2:
        return
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


# A step of the positions against the fixes' own velocities (datum, base-station or receiver
# switched in one log): at least this far, this many sigmas of the two fixes, between fixes
# at most STEP_MAX_DT_S apart (the velocities' trapezoid is exact to centimetres there), and
# still there STEP_HOLD_S later (a multipath run of 10-30 s comes back: the fault exclusion
# takes it).
STEP_MIN_M = 20.0
# A receiver's speed over the speed its fixes show outside this range is another unit (km/h
# 3.6, knots 1.94; io/motion_checks.check_gnss_velocity names it).
VELOCITY_SPEED_RATIO_RANGE = (0.7, 1.4)
# ... or pointing this far from them (median): another axis order (io/motion_checks names it).
VELOCITY_TURNED_DEG = 25.0
STEP_SIGMAS = 5.0
STEP_MAX_DT_S = 2.0
STEP_HOLD_S = 60.0


def _in_another_unit(moved: np.ndarray, predicted: np.ndarray, noise: np.ndarray) -> bool:
    """Do the velocities move the fixes a constant factor off their own steps (median over
    the intervals that move well beyond the fixes' noise) outside VELOCITY_SPEED_RATIO_RANGE?
    A highway drive's velocities in km/h were "two sources of positions" at 158 steps."""
    travel = np.linalg.norm(moved, axis=1)
    along = np.linalg.norm(predicted, axis=1)
    clear = np.isfinite(travel) & np.isfinite(along) & (travel > 3.0 * noise)
    if clear.sum() < 10:
        return False
    ratio = float(np.median(along[clear] / travel[clear]))
    # Or turned: east and north swapped (a NED or NEU velocity) moved the fixes "22 m where
    # the velocities move them 11 m" and was refused as two sources of positions (outside
    # testers); the velocity check names the columns.
    turned = np.abs(np.angle((predicted[clear, 0] + 1j * predicted[clear, 1]) / (moved[clear, 0] + 1j * moved[clear, 1])))
    if float(np.degrees(np.median(turned))) > VELOCITY_TURNED_DEG:
        return True
    return not VELOCITY_SPEED_RATIO_RANGE[0] <= ratio <= VELOCITY_SPEED_RATIO_RANGE[1]


def _reject_steps_against_velocities(gnss: GnssData, xyz: np.ndarray, sigma: np.ndarray) -> None:
    """A position step the fixes' own velocities do not make, that stays: two sources of
    positions in one log. An outside tester's gnss.csv moved 100 m north from t = 40 s on:
    every check passed (100 m/s is a speed some vehicle flies), the smoother took an antenna
    arm and a clock offset from the step and ran 7-56 m off where the fixes were right, at
    exit 0. O(N)."""
    if gnss.velocity is None or len(gnss) < 3:
        return
    # Horizontal only: heights have their own unit checks (an altitude in feet climbs 3.3x
    # as fast as vel_up, read here as steps), and vertical velocities are often noisy.
    from fgins.geodesy import ecef_to_enu_rotation

    local = ecef_to_enu_rotation(gnss.lla[:-1, 0], gnss.lla[:-1, 1])
    moved = np.einsum("nij,nj->ni", local, np.diff(xyz, axis=0))[:, :2]  # east, north
    velocity = gnss.velocity[:, :2]
    dt = np.diff(gnss.t)
    predicted = 0.5 * (velocity[1:] + velocity[:-1]) * dt[:, None]
    if _in_another_unit(moved, predicted, np.hypot(sigma[1:], sigma[:-1])):
        return  # every interval "steps": the velocity check names the unit, not two sources
    gap = moved - predicted
    size = np.linalg.norm(gap, axis=1)
    change = np.linalg.norm(velocity[1:] - velocity[:-1], axis=1)
    tolerance = STEP_SIGMAS * np.hypot(sigma[1:], sigma[:-1]) + 0.5 * dt * change
    candidates = np.flatnonzero(
        np.isfinite(size) & (dt <= STEP_MAX_DT_S) & (size > np.maximum(STEP_MIN_M, tolerance))
    )
    if not candidates.size:
        return
    # What the track does after each: the steps summed over the next STEP_HOLD_S (where the
    # velocities are known), along the step. A spike or a multipath run comes back.
    gap_sum = np.vstack([np.zeros(2), np.cumsum(np.nan_to_num(gap), axis=0)])
    steps = []
    for i in candidates:
        end = int(np.searchsorted(gnss.t, gnss.t[i + 1] + STEP_HOLD_S, side="right")) - 1
        if gnss.t[end] - gnss.t[i + 1] < STEP_HOLD_S:
            continue  # too near the end to tell a step from a run of bad fixes
        direction = gap[i] / size[i]
        held = (gap_sum[i + 1 : end + 1] - gap_sum[i]) @ direction
        # A step back to where the velocities put the track (the end of a run of bad fixes)
        # undoes an earlier one: the track before it had moved away by as much.
        start = int(np.searchsorted(gnss.t, gnss.t[i] - STEP_HOLD_S))
        before = (gap_sum[i] - gap_sum[start : i + 1]) @ direction
        if np.all(held > 0.5 * size[i]) and not np.any(before < -0.5 * size[i]):
            steps.append(int(i))
    if steps:
        i = steps[0]
        raise InputError(
            f"gnss: the positions step {size[i]:.0f} m at t - t_gnss0 = {gnss.t[i + 1] - gnss.t[0]:.1f} s "
            f"where the fixes' own velocities move them {np.linalg.norm(moved[i] - gap[i]):.1f} m, "
            f"and stay there for at least {STEP_HOLD_S:g} s ({len(steps)} such step(s)): two "
            "sources of positions in one log (a datum, base-station or receiver switch); split "
            "the log at the step or correct the fixes"
        )


def _reject_impossible_track_speed(gnss: GnssData, xyz: np.ndarray, sigma: np.ndarray) -> None:
    """A whole track faster than any vehicle: its times are not in seconds.

    The jump checks compare a fix with its near neighbours, within their sigmas: fixes whose
    times were divided by 1000 lie 1 ms apart and move 8 m each, inside the sigmas, so every
    neighbour agrees while the track runs at 8 km/s. Chords of doubling length (1, 2, 4 ...
    epochs) that span at least TRACK_CHORD_SIGMAS of both ends' sigmas show the speed free of
    the fixes' noise; their median beyond any vehicle's refuses the log. O(N log N).
    """
    n = len(gnss)
    if n < TRACK_CHORDS_MIN + 1:
        return
    speeds = []
    lag = 1
    while lag < n:
        distance = np.linalg.norm(xyz[lag:] - xyz[:-lag], axis=1)
        dt = gnss.t[lag:] - gnss.t[:-lag]
        spans = (distance > TRACK_CHORD_SIGMAS * (sigma[lag:] + sigma[:-lag])) & (dt > 0)
        speeds.append(distance[spans] / dt[spans])
        lag *= 2
    chords = np.concatenate(speeds)
    if chords.size < TRACK_CHORDS_MIN:
        return
    median = float(np.median(chords))
    if median > MAX_SPEED_M_PER_S:
        raise InputError(
            f"gnss: the track moves at {median:,.0f} m/s (median over {chords.size} chords between "
            f"fixes far beyond their sigmas), faster than any vehicle ({MAX_SPEED_M_PER_S:g} m/s): "
            f"the fixes' times are not in seconds ({gnss.t[0]:.6g} .. {gnss.t[-1]:.6g} for "
            f"{n} fixes), or lat/lon are not in degrees"
        )


def _gnss_gap_limit(t: np.ndarray) -> float:
    """A stretch without fixes longer than this is a gap: 10 fix intervals, at least 5 s."""
    nominal = float(np.median(np.diff(t))) if t.size > 1 else 0.0
    return max(GNSS_GAP_PERIODS * nominal, GNSS_GAP_MIN_S)


def report_gnss_time_gaps(t: np.ndarray, checks: list[str]) -> None:
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
            f"{dt[largest]:.1f} s, {t[largest] - t[0]:.1f} s after the first fix): outages or a time jump"
        )


# --------------------------------------------------------------------------------------------
# Time bases
# --------------------------------------------------------------------------------------------


# The GPS week number's 10-bit rollover (1024 weeks, s): a receiver past it dates its fixes
# that much early (named where the clocks' offset is a multiple of it, within a day).
GPS_ROLLOVER_S = 1024 * 604800.0
DAY_S = 86400.0
# No navigation receiver reports fixes this far apart (the gyro-free study's slowest is 5 s).
GNSS_MAX_EPOCH_INTERVAL_S = 100.0


def check_time_bases(
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
        weeks = (a - c) / GPS_ROLLOVER_S
        rollover = (
            f" ({round(weeks)} x 1024 GPS weeks: a receiver whose week number rolled over, "
            "dating its fixes 19.6 years early)"
            if round(weeks) != 0 and abs(a - c - round(weeks) * GPS_ROLLOVER_S) < DAY_S
            else ""
        )
        raise InputError(
            f"the IMU ({a:.3f} .. {b:.3f} s) and the GNSS ({c:.3f} .. {d:.3f} s) time spans do "
            f"not overlap (the GNSS starts {c - a:+.3f} s from the IMU): the files use different "
            f"time bases; give --time-offset SECONDS (added to the GNSS times: about "
            f"--time-offset {a - c:+.3f} if both start together{rollover}) or convert one clock"
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
            f"({a:.3f} .. {b:.3f} s; GNSS {c:.3f} .. {d:.3f} s) as stamped: not used unless "
            "the GNSS time correction moves them inside (the summary's count is the one used)"
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
