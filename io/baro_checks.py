"""Barometer checks of the input-validation layer (:mod:`fgins.io.validate`): pressures
no air has (hPa, kPa, psi, bar given as Pa), heights given instead of pressures, a scale
against the fixes' heights. GTSAM-free."""

from __future__ import annotations

import numpy as np

from fgins.datatypes import GnssData, InputError
from fgins.io.gnss_checks import fix_sigma

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


def checked_baro(baro, imu_t: np.ndarray, checks: list[str]):
    """Barometer samples the smoother can use: a pressure that is not a positive finite
    number is dropped and counted (more than 1 %: an error, the column is not pressure); none
    inside the IMU's span is said (outside testers: negative pressures and a barometer 5,000 s
    off the IMU were both dropped without a word, exit 0)."""
    if baro is None:
        return None
    from_height = given_as_height(baro)
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


def given_as_height(baro) -> bool:
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


def check_pressure_unit(baro) -> None:
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


def _isa_height(baro) -> np.ndarray:
    """The barometer's standard-atmosphere heights (m; NaN where its pressure is not one).
    A height given as such was made its pressure on loading: the same height back."""
    from fgins.factors.stationary import standard_atmosphere_height

    with np.errstate(invalid="ignore"):
        return np.asarray(standard_atmosphere_height(baro.pressure), dtype=float)


def check_baro_scale(
    baro, gnss: GnssData, what: str, checks: list[str] | None = None, *, rescale: bool = True
):
    """The barometer's height changes against the fixes' altitude changes, where it climbs
    or descends well beyond both sensors' noise: the fixes' altitude regressed on the
    barometer's (ISA) height has a slope of ~1 (the ISA against a real day's temperature:
    +-10 %); a height column in feet gives 1/3.28 (the barometer then pulled every height
    3.3x its climbs, and only the fit's chi-square said anything). The barometer's own
    noise is small, so the fixes' noise does not bias this slope. ``what``: how the
    barometer was given, for the message.

    Within that range, a scale the climbs show beyond doubt (BARO_SCALE_SIGMAS, and at least
    BARO_SCALE_MIN_ERROR) is the day's air against the standard atmosphere: the barometer's
    heights are rescaled to the fixes' about their mean, said in ``checks``, and the
    barometer returned so (else as given). An aircraft's 500 m climb on an ISA+20 C day
    (heights 7 % large): the smoother's slow bias walk could not follow it, and the fixes
    were scaled, the clocks and the gyro "corrected" instead: heights 13-18 m off at sigma
    1.1 m, horizontal 9-34 m inside outages (outside tester).

    ``rescale`` False only refuses a unit: the load's check, over every fix. The scale is an
    estimate a run makes from the fixes it uses (fgins.pipeline): from withheld ones, an
    outage's climbs set the barometer a real tunnel's would not have (outside tester: 4.6 m
    inside a 300 s outage against 11.5 m with those fixes really absent)."""
    if baro is None or not len(baro.t):
        return baro
    height = _isa_height(baro)
    alt = gnss.lla[:, 2]
    use = np.isfinite(alt) & (gnss.t >= baro.t[0]) & (gnss.t <= baro.t[-1])
    finite = np.isfinite(height)
    if use.sum() < BARO_SCALE_MIN_FIXES or finite.sum() < 2:
        return baro
    at_fixes = np.interp(gnss.t[use], baro.t[finite], height[finite])
    sigma_up = float(np.median(fix_sigma(gnss)[use]))  # 3-D: at least the vertical

    def spread_of(values: np.ndarray) -> float:  # robust: a few altitude outliers do not count
        q1, q3 = np.percentile(values, [25, 75])
        return float(q3 - q1) / 1.349

    spread = spread_of(at_fixes)
    if max(spread, spread_of(alt[use])) < max(BARO_SCALE_MIN_SPREAD_M, 2.0 * sigma_up):
        return baro  # level by both: nothing to tell a scale from
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
    if not rescale:
        return baro
    fit = _slope_with_drift(x, y, gnss.t[use])
    if fit is None:
        return baro
    slope, slope_sigma = fit
    if abs(slope - 1.0) < max(BARO_SCALE_MIN_ERROR, BARO_SCALE_SIGMAS * slope_sigma):
        return baro
    ratio = 1.0 / slope
    mean = float(np.mean(at_fixes))
    rescaled = mean + (height - mean) * slope
    if checks is not None:
        checks.append(
            f"baro: its {what} changes {ratio:.3f} (+-{slope_sigma * ratio**2:.3f}) times as "
            f"much as the fixes' altitude over climbs spreading {spread:.0f} m: a day's air off "
            f"the standard atmosphere (a few % is usual); rescaled to the fixes' (x{slope:.3f} "
            f"about {mean:.0f} m)"
        )
    from fgins.factors.stationary import standard_atmosphere_pressure

    with np.errstate(invalid="ignore"):
        pressure = np.where(np.isfinite(rescaled), standard_atmosphere_pressure(rescaled), np.nan)
    return type(baro)(t=baro.t, pressure=pressure, height=None if baro.height is None else rescaled)


def _slope_with_drift(x: np.ndarray, y: np.ndarray, t: np.ndarray) -> tuple[float, float] | None:
    """The fixes' altitude changes ``y`` regressed on the barometer's ``x`` (both about their
    means) at times ``t``, with a drift in time: (slope, its sigma), None where the two
    cannot be told apart. The scale apart from a drift in time (weather, a warming sensor),
    which the smoother's bias walk follows: a barometer drifting 0.05 m/s through a climb
    read as 2.4 % scale, and rescaled so, the clocks were "corrected" from the rest (38 m
    inside an outage)."""
    design = np.column_stack([x, t - float(np.mean(t))])
    normal = design.T @ design
    if np.linalg.cond(normal) > 1e12:
        return None
    slope, drift = np.linalg.solve(normal, design.T @ y)
    residual = y - design @ np.array([slope, drift])
    scatter = 1.4826 * float(np.median(np.abs(residual - np.median(residual))))
    # The fixes' height errors are correlated over tens of seconds (a real receiver's): the
    # slope's sigma counts the residuals' lag-one correlation (n (1 - r) / (1 + r) independent).
    centred = residual - residual.mean()
    lag_one = float(np.sum(centred[1:] * centred[:-1]) / max(float(np.sum(centred * centred)), 1e-12))
    correlated = (1.0 + max(lag_one, 0.0)) / max(1.0 - max(lag_one, 0.0), 1e-3)
    return float(slope), scatter * float(np.sqrt(np.linalg.inv(normal)[0, 0] * correlated))


# A scale taken from the climbs: beyond this many sigmas of the slope and this fraction.
BARO_SCALE_SIGMAS = 5.0
BARO_SCALE_MIN_ERROR = 0.005

# The barometer judged only over climbs and descents of this spread (std, m) or more, and
# twice the fixes' vertical sigma; its height scale within this range of the fixes'.
BARO_SCALE_MIN_SPREAD_M = 10.0
BARO_SCALE_MIN_FIXES = 10  # fixes with heights and pressures over the climbs judged
BARO_SCALE_RANGE = (0.7, 1.4)


# A day's air against the standard atmosphere where the fixes cannot show it: ISA +-15 C
# makes a barometer's height changes about 5 % large or small.
BARO_SCALE_UNKNOWN = 0.05
BARO_GAP_INTERVALS = 3.0  # a stretch without fixes longer than this many fix intervals


def scale_unknown_sigma(baro, gnss: GnssData, t: np.ndarray) -> np.ndarray | None:
    """The height sigma (m) at times ``t`` from the barometer's scale as far as the fixes
    ``gnss`` (those a run uses) leave it unknown: the regression's sigma of the scale (or its
    distance from 1, where not taken), BARO_SCALE_UNKNOWN at most and where they do not
    climb, times the barometer's climb inside each stretch without those fixes from the line
    between its heights at the stretch's ends (beside dense fixes the fixes pin the heights);
    None without a barometer. (Outside tester: a pass road
    whose only climbs, 90 m, lay inside a 300 s tunnel, on an ISA+20 day: heights 2 m off at
    sigma 0.3-0.5 m, z 4-8, nothing said.)"""
    if baro is None or not len(baro.t) or not len(gnss.t):
        return None
    height = _isa_height(baro)
    finite = np.isfinite(height)
    alt = gnss.lla[:, 2]
    use = np.isfinite(alt) & (gnss.t >= baro.t[0]) & (gnss.t <= baro.t[-1])
    if finite.sum() < 2 or not use.any():
        return None
    at_fixes = np.interp(gnss.t[use], baro.t[finite], height[finite])
    # What the fixes' climbs say of the scale (the barometer as the run has it: rescaled
    # where they showed one): its sigma, or its distance from 1 where that was not taken.
    unknown = BARO_SCALE_UNKNOWN
    if use.sum() >= BARO_SCALE_MIN_FIXES:
        fit = _slope_with_drift(at_fixes - at_fixes.mean(), alt[use] - alt[use].mean(), gnss.t[use])
        if fit is not None and np.isfinite(fit[1]):
            unknown = min(unknown, max(fit[1], abs(fit[0] - 1.0)))
    # Between fixes the solution's heights are the barometer's climbs from the fixes at
    # either end (the smoother pins both); beside dense fixes, the fixes' own.
    fix_t = gnss.t[use]
    at_t = np.interp(t, baro.t[finite], height[finite])
    after = np.clip(np.searchsorted(fix_t, t), 1, len(fix_t) - 1)
    t0, t1 = fix_t[after - 1], fix_t[after]
    inside = (t > t0) & (t < t1) & (t1 - t0 > BARO_GAP_INTERVALS * float(np.median(np.diff(fix_t))))
    h0, h1 = at_fixes[after - 1], at_fixes[after]
    reference = h0 + (h1 - h0) * np.clip((t - t0) / np.maximum(t1 - t0, 1e-9), 0.0, 1.0)
    return np.where(inside, unknown * np.abs(at_t - reference), 0.0)


# The barometer's clock against the fixes': its height changes lagged over +-BARO_MAX_LAG_S
# against the fixes' altitude changes, where both climb well beyond their noise. A lag of at
# least BARO_LAG_MIN_S that correlates at BARO_LAG_MIN_CORRELATION, where none does, is an
# error naming it.
BARO_MAX_LAG_S = 300.0
BARO_LAG_STEP_S = 1.0
BARO_LAG_MIN_S = 5.0
BARO_LAG_MIN_CORRELATION = 0.9
BARO_LAG_MAX_AT_ZERO = 0.6
BARO_CLIMB_S = 30.0


def check_baro_clock(baro, gnss: GnssData) -> None:
    """A barometer on another clock than the fixes: its climbs line up with theirs only
    when moved by seconds. (Outside tester: a barometer 100 s late ran to exit 0 with heights
    61 m off at z 140, 39 good fixes left out as faults and the gyro blamed; 5 s late, z 8.)
    Judged only where the fixes climb and descend (the scale check's spread) over a drive
    several times the lag."""
    if baro is None or len(baro.t) < 10 or len(gnss.t) < BARO_SCALE_MIN_FIXES:
        return
    height = _isa_height(baro)
    finite = np.isfinite(height)
    alt = gnss.lla[:, 2]
    ok = np.isfinite(alt)
    if finite.sum() < 10 or ok.sum() < BARO_SCALE_MIN_FIXES:
        return
    t_fix, alt = gnss.t[ok], alt[ok]
    q1, q3 = np.percentile(alt, [25, 75])
    sigma_up = float(np.median(fix_sigma(gnss)[ok]))
    if (q3 - q1) / 1.349 < max(BARO_SCALE_MIN_SPREAD_M, 2.0 * sigma_up):
        return
    bt, bh = baro.t[finite], height[finite]
    # Climbs over BARO_CLIMB_S, not heights: along a steady climb a lag is only an offset,
    # which the barometer's own offset takes.
    start = np.arange(t_fix[0], t_fix[-1] - BARO_CLIMB_S, BARO_CLIMB_S / 2)
    climb = np.interp(start + BARO_CLIMB_S, t_fix, alt) - np.interp(start, t_fix, alt)

    def correlation(lag: float) -> float:
        inside = (start + lag >= bt[0]) & (start + lag + BARO_CLIMB_S <= bt[-1])
        if inside.sum() < max(BARO_SCALE_MIN_FIXES, 0.5 * len(start)):
            return float("nan")
        a = np.interp(start[inside] + lag + BARO_CLIMB_S, bt, bh) - np.interp(start[inside] + lag, bt, bh)
        b = climb[inside]
        a, b = a - a.mean(), b - b.mean()
        denominator = float(np.sqrt(np.sum(a * a) * np.sum(b * b)))
        return float(np.sum(a * b)) / denominator if denominator > 0 else float("nan")

    lags = np.arange(-BARO_MAX_LAG_S, BARO_MAX_LAG_S + BARO_LAG_STEP_S / 2, BARO_LAG_STEP_S)
    values = np.array([correlation(float(lag)) for lag in lags])
    if not np.any(np.isfinite(values)):
        return
    best = int(np.nanargmax(values))
    at_zero = correlation(0.0)
    lag, peak = float(lags[best]), float(values[best])
    # (as stamped and strongly against: a sign, which the scale check names, not a clock)
    if abs(lag) >= BARO_LAG_MIN_S and peak >= BARO_LAG_MIN_CORRELATION and abs(at_zero) <= BARO_LAG_MAX_AT_ZERO:
        raise InputError(
            f"baro: its height changes line up with the fixes' altitude only when its times are "
            f"moved by {-lag:+.0f} s (correlation {peak:.2f}, {at_zero:.2f} as stamped): the "
            "barometer is on another clock; give its times on the IMU's and the fixes' clock"
        )


# A barometer whose heights come late against the fixes' by less than BARO_LAG_MIN_S (its
# own filter, a slow static port: a first-order lag of tau is a delay of tau on a steady
# climb): in a climb its heights are tau times the climb rate off, which its slow bias walk
# cannot follow. (Outside tester: an aircraft's barometer lagging 0.5-1.5 s, climbs at 7-12
# m/s: heights 2-9 m off inside outages at z 6-19, nothing or the antenna blamed.) The
# fixes' altitude less the barometer's height is regressed on an offset, a drift, the
# barometer's height (its scale) and its climb rate, whose coefficient is the delay; taken
# beyond BARO_DELAY_SIGMAS of its sigma and BARO_DELAY_MIN_S.
BARO_DELAY_MIN_S = 0.1
BARO_DELAY_SIGMAS = 5.0
BARO_RATE_WINDOW_S = 1.0  # the barometer's climb rate: its mean heights +-this apart
BARO_DELAY_OUTLIER_SIGMAS = 4.0


def baro_delay(baro, gnss: GnssData) -> tuple[float, float] | None:
    """(delay, its sigma) in s of the barometer's heights against the fixes' altitude
    (positive: the barometer's come late), None where the fixes and the barometer cannot
    show one (too few fixes with heights inside its span, a design that cannot be solved).
    The sigma counts the residuals' lag-one correlation, as the scale's does; fixes beyond
    BARO_DELAY_OUTLIER_SIGMAS robust sigmas of a first fit are left out."""
    if baro is None or len(baro.t) < 10 or not len(gnss.t):
        return None
    height = _isa_height(baro)
    finite = np.isfinite(height)
    bt, bh = baro.t[finite], height[finite]
    if len(bt) < 10 or not np.all(np.diff(bt) > 0):
        return None
    # The climb rate: the mean height over the window after less that over the window
    # before, on a uniform grid at the barometer's spacing (noise averaged, no lag).
    step = float(np.median(np.diff(bt)))
    grid = np.arange(bt[0], bt[-1], step)
    width = max(1, round(BARO_RATE_WINDOW_S / step))
    if len(grid) < 2 * width + 10:
        return None
    cumulative = np.concatenate([[0.0], np.cumsum(np.interp(grid, bt, bh))])
    means = (cumulative[width:] - cumulative[:-width]) / width  # means[i]: grid[i : i + width]
    rate = (means[width:] - means[:-width]) / (width * step)  # about grid[i + width]
    rate_t = grid[width : width + len(rate)] - 0.5 * step
    alt = gnss.lla[:, 2]
    use = np.isfinite(alt) & (gnss.t >= rate_t[0]) & (gnss.t <= rate_t[-1])
    if use.sum() < BARO_SCALE_MIN_FIXES:
        return None
    t = gnss.t[use]
    at_fixes = np.interp(t, bt, bh)
    weight = 1.0 / fix_sigma(gnss)[use]
    design = np.column_stack(
        [np.ones_like(t), t - t.mean(), at_fixes - at_fixes.mean(), np.interp(t, rate_t, rate)]
    )
    difference = alt[use] - at_fixes
    keep = np.ones(len(t), dtype=bool)
    for _ in range(2):  # a fit, then without its outliers (multipath, a jump)
        a, b = design[keep] * weight[keep, None], difference[keep] * weight[keep]
        normal = a.T @ a
        if keep.sum() < BARO_SCALE_MIN_FIXES or np.linalg.cond(normal) > 1e12:
            return None
        coefficients = np.linalg.solve(normal, a.T @ b)
        residual = (difference - design @ coefficients) * weight
        scatter = 1.4826 * float(np.median(np.abs(residual[keep] - np.median(residual[keep]))))
        keep = np.abs(residual - np.median(residual[keep])) <= BARO_DELAY_OUTLIER_SIGMAS * max(scatter, 1e-12)
    kept = residual[keep] - residual[keep].mean()
    lag_one = float(np.sum(kept[1:] * kept[:-1]) / max(float(np.sum(kept * kept)), 1e-300))
    correlated = (1.0 + max(lag_one, 0.0)) / max(1.0 - max(lag_one, 0.0), 1e-3)
    sigma = scatter * float(np.sqrt(np.linalg.inv(normal)[3, 3] * correlated))
    return float(coefficients[3]), sigma


def baro_on_fixes_time(baro, gnss: GnssData):
    """(the barometer, its samples moved earlier by the delay :func:`baro_delay` finds
    where it is taken, else as given; the line saying so or None)."""
    found = baro_delay(baro, gnss)
    if found is None:
        return baro, None
    delay, sigma = found
    if abs(delay) < max(BARO_DELAY_MIN_S, BARO_DELAY_SIGMAS * sigma) or abs(delay) >= BARO_LAG_MIN_S:
        return baro, None
    note = (
        f"baro: its heights come {abs(delay):.2f} s (+-{sigma:.2f}) "
        f"{'late' if delay > 0 else 'early'} against the fixes' altitude over their climbs "
        "(its own filter or port lag, or its clock): its samples moved by "
        f"{-delay:+.2f} s onto the fixes' time"
    )
    return type(baro)(t=baro.t - delay, pressure=baro.pressure, height=baro.height), note
