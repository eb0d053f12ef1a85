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

This module runs the checks in their order (each may rely on the ones before: the time bases
before the turns, a time unit shrinks speeds too); they live by subject in
:mod:`fgins.io.imu_checks` (the IMU stream alone), :mod:`fgins.io.gnss_checks` (GNSS records
and time bases), :mod:`fgins.io.motion_checks` (the IMU against the GNSS track: units, signs,
clocks, velocity, wheel speed) and :mod:`fgins.io.baro_checks`.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from fgins.datatypes import FROZEN_DROPPED_KEY, Dataset, InputError, Origin
from fgins.io.axes_handedness import check_accel_handedness, handedness_note_3d
from fgins.io.baro_checks import (
    check_baro_clock,
    check_baro_scale,
    check_pressure_unit,
    checked_baro,
    given_as_height,
)
from fgins.io.gnss_checks import check_gnss, check_time_bases, report_gnss_time_gaps
from fgins.io.imu_checks import drop_out_of_range, flag_suspect, imu_at_instants, repair_spikes
from fgins.io.motion_checks import (
    FREE_BODY_VEHICLES,
    SHORT_IMU_S,
    TurnsDisagree,
    check_accel_units,
    check_clock_offset,
    check_frozen_position,
    check_gnss_velocity,
    check_imu_time_unit,
    check_track_scale_by_turns,
    check_units,
    check_wheel_speed,
    check_wheel_time_base,
    clock_offset_explains_turns,
    drop_frozen_runs,
    mean_up,
    velocities_without_bias,
)


def validate_dataset(
    dataset: Dataset, vehicle: str | None = None, sample_timing: str | None = None
) -> Dataset:
    """Check and repair ``dataset`` (see the module docstring); returns the checked dataset.
    ``sample_timing``: what an IMU sample stands for (``[imu] sample_timing``: "instant",
    "held", "mean"; by default the dataset's own ``imu_config``'s, else "instant").

    Idempotent: a dataset already checked is returned unchanged.
    """
    if dataset.metadata.get("input_checks") is not None:
        return dataset
    try:
        timing = sample_timing or dataset.imu_config.get("sample_timing") or "instant"
        return _validated(dataset, vehicle, str(timing))
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


def _validated(dataset: Dataset, vehicle: str | None, sample_timing: str) -> Dataset:
    checks: list[str] = []
    check_imu_time_unit(dataset.imu.t)
    imu = flag_suspect(repair_spikes(drop_out_of_range(dataset.imu, checks), checks), checks)
    span = float(imu.t[-1] - imu.t[0])
    if span < SHORT_IMU_S:
        checks.append(
            f"imu: only {span:.1f} s of IMU data: too short to tell the heading (it needs a "
            "turn or an acceleration the fixes also see) or the biases; the output covers only "
            "those seconds, its attitude barely more than the alignment's guess"
        )
    gnss, origin = check_gnss(dataset.gnss, dataset.origin, checks)
    from fgins.geodesy import lla_to_enu

    enu = lla_to_enu(gnss.lla, origin)  # the checks below share the fixes' local positions
    # First: the tracks and turns the checks below compare are meaningless in a frame far
    # from the drive (an [origin] 168 deg of longitude off was called "the gyro does not see
    # the turns").
    _warn_frame_extent(enu, origin, checks)
    check_accel_units(imu, has_accel_array=dataset.accel_array is not None)
    up = mean_up(imu)
    check_frozen_position(gnss, enu, imu, up)
    read = len(gnss)
    gnss, enu = drop_frozen_runs(gnss, enu, imu, up, checks)
    frozen_dropped = read - len(gnss)
    check_time_bases(imu.t, gnss.t, checks, n_read=len(dataset.gnss))
    if vehicle not in FREE_BODY_VEHICLES:  # after the time bases: a time unit shrinks speeds too
        check_track_scale_by_turns(gnss, enu, imu, up)
    given_offset = dataset.metadata.get("gnss_time_offset_s")
    # The checks that line the gyro's turns up with the track's in time read each sample at
    # the instant it stands for: a held or mean sample, the middle of its interval (a 2 Hz
    # IMU of means read at its stamps was "fixes stamped 0.28 s late", outside tester).
    at_instants = imu_at_instants(imu, sample_timing)
    try:
        check_units(
            at_instants, gnss, origin, checks, has_accel_array=dataset.accel_array is not None,
            body_follows_track=vehicle not in FREE_BODY_VEHICLES,
        )  # fmt: skip
    except TurnsDisagree:
        # Turns that line up at another time are offset clocks, and the offset is the fix
        # (GPS time against UTC: "the gyro does not see the turns", its ratio 0.05).
        clock_offset_explains_turns(
            at_instants, gnss, enu, up, origin, given_offset, banks=vehicle == "aircraft"
        )  # fmt: skip
        raise
    # The receiver's velocity once the gyro's turns have judged the fixes' track (swapped
    # latitude and longitude turn it against both), before the checks that compare the IMU
    # with the velocity: swapped east and north made the accelerometer "a mirror image of the
    # gyro's" (outside tester).
    check_gnss_velocity(gnss, origin)
    if vehicle not in FREE_BODY_VEHICLES and dataset.accel_array is None:
        check_clock_offset(
            at_instants, gnss, enu, up, origin, checks, given_offset, banks=vehicle == "aircraft"
        )  # fmt: skip
        check_accel_handedness(at_instants, gnss, enu)
    if vehicle != "car" and dataset.accel_array is None:
        # Aircraft (banked turns put no force across the body), vehicles that need not
        # follow their track, and any vehicle not known to be a car, which the track test
        # may not judge: the 3-D fit, said as a warning (~0.1 s on a 10 min flight).
        from fgins.geodesy import normal_gravity

        note = handedness_note_3d(at_instants, gnss, enu, normal_gravity(origin.lat, origin.alt))
        if note:
            checks.append(note)
    gnss = velocities_without_bias(gnss, origin, checks)
    if dataset.odometer is not None and len(dataset.odometer.t):
        check_wheel_time_base(dataset.odometer, imu.t, checks)
        check_wheel_speed(dataset.odometer, gnss, enu)
    baro_heights = dataset.baro is not None and given_as_height(dataset.baro)
    baro = checked_baro(dataset.baro, imu.t, checks)
    # Before the unit: a barometer seconds off fits the fixes' climbs with a nonsense scale.
    check_baro_clock(baro, gnss)
    if not baro_heights:  # heights were checked for range and made pressures
        check_pressure_unit(baro)
    # Units only: the scale is the run's, from the fixes it uses (fgins.pipeline).
    baro = check_baro_scale(
        baro, gnss, "height" if baro_heights else "pressure's ISA height", checks, rescale=False
    )

    report_gnss_time_gaps(gnss.t, checks)
    metadata = {**dataset.metadata, "input_checks": list(checks)}
    if frozen_dropped:
        metadata[FROZEN_DROPPED_KEY] = frozen_dropped
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


def _warn_frame_extent(enu: np.ndarray, origin: Origin, checks: list[str]) -> None:
    """An error for an origin away from every fix (a mistaken one), a warning for fixes
    (``enu``: their positions in the origin's frame) that reach beyond
    :data:`FRAME_EXTENT_M`."""
    if not len(enu):
        return
    distance = np.hypot(*enu[:, :2].T)
    reach = float(np.nanmax(distance)) if np.any(np.isfinite(distance)) else 0.0
    nearest = float(np.nanmin(distance)) if np.any(np.isfinite(distance)) else 0.0
    if nearest > FRAME_EXTENT_M:
        # Only a stated origin can be away from every fix (readers otherwise take the first
        # fix): an outside tester's [origin] 3,900 km off gave 43 m errors with 0.6 m sigmas.
        raise InputError(
            f"frame: the origin ({origin.lat:.6f}, {origin.lon:.6f}) lies {nearest / 1000:,.0f} "
            "km from the nearest fix: give an origin at the drive (a sim folder's config.toml "
            "[origin], a Dataset's origin), or leave it out to use the first fix"
        )
    if reach <= FRAME_EXTENT_M:
        return
    checks.append(
        f"frame: the fixes reach {reach / 1000:.0f} km from the origin; fgins navigates in the "
        f"tangent plane there ({reach**2 / (2 * EARTH_RADIUS_M) / 1000:.1f} km below the "
        "surface at that distance), with gravity's height and the barometer approximate "
        f"beyond {FRAME_EXTENT_M / 1000:.0f} km: smooth it in parts"
    )
