"""Core data model: plain dataclasses over numpy arrays, validated on construction.

Conventions (see DESIGN.md): SI units, float seconds on one monotonic time base per
dataset, local ENU navigation frame at ``Dataset.origin``, heights ellipsoidal (WGS-84).
Every method (factor graph or Kalman baseline) consumes a :class:`Dataset` and returns a
:class:`Trajectory`, so comparisons run on identical inputs and outputs.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


class FginsError(Exception):
    """An error with a one-line message meant for the user (what, where, what to do)."""


class InputError(FginsError):
    """The input data is unusable as given."""


class ConfigError(FginsError):
    """A configuration value (TOML file, a dataset's own settings, a CLI or API choice) is
    of the wrong type or out of range; the message names the key and the value."""


class OutputError(FginsError):
    """An output cannot be written where asked (format, folder, permissions, an input)."""


def _as_float_array(name: str, value: object, shape_tail: tuple[int, ...]) -> np.ndarray:
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as error:  # strings, ragged lists, objects
        raise InputError(f"{name}: expected numbers, got {type(value).__name__} ({error})") from None
    if array.ndim != 1 + len(shape_tail) or array.shape[1:] != shape_tail:
        expected = "(N" + "".join(f", {d}" for d in shape_tail) + ")"
        raise InputError(f"{name}: expected shape {expected}, got {array.shape}")
    return array


def _check_time(name: str, t: np.ndarray) -> None:
    if t.size and not np.all(np.isfinite(t)):
        raise InputError(f"{name}: non-finite timestamps")
    if t.size > 1 and np.any(np.diff(t) <= 0):
        bad = int(np.argmax(np.diff(t) <= 0)) + 1
        fix = "sort or de-duplicate the input"
        if np.abs(t).max() >= 2.0**24 and np.all(t.astype(np.float32) == t):
            # Every stamp a float32 value, beyond where float32 counts whole seconds (POSIX
            # times in float32 step by 128 s): the precision, not the order, is lost.
            step = float(np.spacing(np.float32(np.abs(t).max())))
            fix = f"the times look stored as float32, which steps by {step:g} s there: give them as float64"
        raise InputError(
            f"{name}: timestamps not strictly increasing at row {bad} "
            f"(t={t[bad - 1]:.6f} then {t[bad]:.6f}); {fix}"
        )


def _optional(name: str, value: object, n: int, tail: tuple[int, ...] = ()) -> np.ndarray:
    """An optional per-epoch column: NaN-filled when absent."""
    if value is None:
        return np.full((n, *tail), np.nan)
    array = _as_float_array(name, value, tail)
    if array.shape[0] != n:
        raise InputError(f"{name}: {array.shape[0]} rows for {n} epochs")
    return array


@dataclass(eq=False)  # identity: array fields have no truth value (== raised)
class ImuData:
    """Strapdown IMU samples in the IMU's own axes.

    ``gyro`` is angular rate (rad/s) and ``accel`` specific force (m/s^2), both (N, 3).
    ``suspect`` lists [start, end) time intervals whose samples are not genuine (lost samples
    filled by interpolation, gaps); the smoother integrates across them with inflated noise.
    """

    t: np.ndarray
    gyro: np.ndarray
    accel: np.ndarray
    suspect: list[tuple[float, float]] = field(default_factory=list)
    frame: str = "imu"

    def __post_init__(self) -> None:
        self.t = _as_float_array("imu.t", self.t, ())
        self.gyro = _as_float_array("imu.gyro", self.gyro, (3,))
        self.accel = _as_float_array("imu.accel", self.accel, (3,))
        n = self.t.shape[0]
        if self.gyro.shape[0] != n or self.accel.shape[0] != n:
            raise InputError("imu: t, gyro and accel must have the same number of rows")
        if n < 2:
            raise InputError(f"imu: need at least 2 samples, got {n}")
        _check_time("imu.t", self.t)
        if not (np.all(np.isfinite(self.gyro)) and np.all(np.isfinite(self.accel))):
            raise InputError("imu: NaN or infinite samples; drop or repair those rows first")

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def rate_hz(self) -> float:
        """Nominal sample rate from the median sample interval."""
        return float(1.0 / np.median(np.diff(self.t)))


def median_interval(t: np.ndarray) -> float:
    """The median interval (s) between consecutive times ``t``; 0 with fewer than two (the
    fix interval the checks' chords and windows widen to where fixes are sparse)."""
    return float(np.median(np.diff(t))) if len(t) > 1 else 0.0


@dataclass(eq=False)
class GnssData:
    """GNSS fixes. Positions geodetic (deg, deg, ellipsoidal m); optional columns are NaN.

    ``velocity`` is ENU (m/s) in the local level at each fix, as receivers give it
    (:meth:`Dataset.gnss_velocity_nav` turns it into the navigation frame); ``std`` is the 1-sigma east/north/up position error (m) when the
    source gives it (GST, covariance); DOPs as reported; ``fix_quality`` uses the NMEA GGA codes
    (0 invalid, 1 autonomous, 2 DGPS, 4 RTK fixed, 5 RTK float, 6 dead reckoning).
    ``speed`` (m/s over ground) and ``course`` (deg from north) come from RMC/VTG-like sources.
    """

    t: np.ndarray
    lla: np.ndarray
    velocity: np.ndarray | None = None
    std: np.ndarray | None = None
    velocity_std: np.ndarray | None = None
    hdop: np.ndarray | None = None
    vdop: np.ndarray | None = None
    pdop: np.ndarray | None = None
    fix_quality: np.ndarray | None = None
    num_sats: np.ndarray | None = None
    speed: np.ndarray | None = None
    course: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.t = _as_float_array("gnss.t", self.t, ())
        n = self.t.shape[0]
        self.lla = _as_float_array("gnss.lla", self.lla, (3,))
        if self.lla.shape[0] != n:
            raise InputError("gnss: t and lla must have the same number of rows")
        _check_time("gnss.t", self.t)
        self.velocity = _optional("gnss.velocity", self.velocity, n, (3,))
        self.std = _optional("gnss.std", self.std, n, (3,))
        self.velocity_std = _optional("gnss.velocity_std", self.velocity_std, n, (3,))
        for name in ("hdop", "vdop", "pdop", "speed", "course"):
            setattr(self, name, _optional(f"gnss.{name}", getattr(self, name), n))
        quality = _optional("gnss.fix_quality", self.fix_quality, n)
        self.fix_quality = np.where(np.isfinite(quality), quality, 1).astype(int)
        sats = _optional("gnss.num_sats", self.num_sats, n)
        self.num_sats = np.where(np.isfinite(sats), sats, -1).astype(int)

    def __len__(self) -> int:
        return int(self.t.shape[0])

    def subset(self, mask: np.ndarray) -> GnssData:
        """The epochs where ``mask`` is true."""
        return GnssData(
            t=self.t[mask],
            lla=self.lla[mask],
            velocity=self.velocity[mask],
            std=self.std[mask],
            velocity_std=self.velocity_std[mask],
            hdop=self.hdop[mask],
            vdop=self.vdop[mask],
            pdop=self.pdop[mask],
            fix_quality=self.fix_quality[mask],
            num_sats=self.num_sats[mask],
            speed=self.speed[mask],
            course=self.course[mask],
        )


@dataclass(eq=False)
class BaroData:
    """Barometer: pressure (Pa) or, where the source already converted it, height (m)."""

    t: np.ndarray
    pressure: np.ndarray | None = None
    height: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.t = _as_float_array("baro.t", self.t, ())
        _check_time("baro.t", self.t)
        n = self.t.shape[0]
        self.pressure = _optional("baro.pressure", self.pressure, n)
        self.height = _optional("baro.height", self.height, n)


@dataclass(eq=False)
class OdometerData:
    """Wheel speed / odometer: forward speed over ground (m/s), before any scale correction."""

    t: np.ndarray
    speed: np.ndarray

    def __post_init__(self) -> None:
        self.t = _as_float_array("odometer.t", self.t, ())
        _check_time("odometer.t", self.t)
        self.speed = _as_float_array("odometer.speed", self.speed, ())
        if self.speed.shape != self.t.shape:
            raise InputError("odometer: t and speed must have the same number of rows")


@dataclass(eq=False)
class AccelArrayData:
    """Raw readings of a gyro-free IMU: N single-axis accelerometers (m/s^2) at times t (s).

    ``positions`` (N, 3, m) and unit sensing ``axes`` (N, 3) are in the body frame, origin at
    the point whose specific force is wanted. ``noise_density`` is the per-sensor white noise
    (m/s^2/sqrt(Hz)), ``bias_sigma`` the 1-sigma residual bias after calibration (m/s^2; None
    when unknown), ``initial_rate`` the angular rate at t[0] (rad/s) the rate integral starts
    from. Geometry is validated by :class:`fgins.factors.accel_array.AccelArray`.
    """

    t: np.ndarray
    readings: np.ndarray
    positions: np.ndarray
    axes: np.ndarray
    noise_density: float
    bias_sigma: float | None = None
    initial_rate: np.ndarray = field(default_factory=lambda: np.zeros(3))
    grade: str = ""

    def __post_init__(self) -> None:
        self.t = _as_float_array("accel_array.t", self.t, ())
        self.positions = _as_float_array("accel_array.positions", self.positions, (3,))
        n_sensors = self.positions.shape[0]
        self.axes = _as_float_array("accel_array.axes", self.axes, (3,))
        if self.axes.shape[0] != n_sensors:
            raise InputError(
                f"accel_array: {n_sensors} positions but {self.axes.shape[0]} sensing axes"
            )
        self.readings = _as_float_array("accel_array.readings", self.readings, (n_sensors,))
        if self.readings.shape[0] != self.t.shape[0]:
            raise InputError(
                f"accel_array: {self.readings.shape[0]} reading rows for {self.t.shape[0]} times"
            )
        _check_time("accel_array.t", self.t)
        self.initial_rate = np.asarray(self.initial_rate, dtype=float)
        if self.initial_rate.shape != (3,) or not np.all(np.isfinite(self.initial_rate)):
            raise InputError("accel_array.initial_rate: expected 3 finite values (rad/s)")
        try:
            self.noise_density = float(self.noise_density)
            self.bias_sigma = None if self.bias_sigma is None else float(self.bias_sigma)
        except (TypeError, ValueError):
            raise InputError(
                f"accel_array: noise density {self.noise_density!r} and bias sigma "
                f"{self.bias_sigma!r} must be numbers"
            ) from None
        if not (np.isfinite(self.noise_density) and self.noise_density > 0):
            raise InputError(
                f"accel_array: noise density {self.noise_density} must be finite and > 0"
            )
        if self.bias_sigma is not None:
            self.bias_sigma = float(self.bias_sigma)
            if not (np.isfinite(self.bias_sigma) and self.bias_sigma >= 0):
                raise InputError(f"accel_array: bias sigma {self.bias_sigma} must be >= 0")

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def n_sensors(self) -> int:
        return int(self.positions.shape[0])


@dataclass
class Origin:
    """Local ENU tangent-plane origin (deg, deg, ellipsoidal m)."""

    lat: float
    lon: float
    alt: float

    def __post_init__(self) -> None:
        for name in ("lat", "lon", "alt"):
            value = getattr(self, name)
            try:
                setattr(self, name, float(value))
            except (TypeError, ValueError):
                raise InputError(f"origin.{name}: expected a number, got {value!r}") from None


def _as_origin(value: object, gnss: GnssData) -> Origin:
    """A dataset's origin: an Origin (or any object with lat, lon, alt), a (lat, lon, alt)
    sequence, or None for the first fix (as every reader does without a stated origin)."""
    if value is None:
        if len(gnss) == 0:
            raise InputError("dataset: no GNSS fix at all; nothing to anchor the trajectory")
        return Origin(*(float(v) for v in gnss.lla[0]))
    if isinstance(value, Origin):
        return value
    if all(hasattr(value, name) for name in ("lat", "lon", "alt")):
        return Origin(value.lat, value.lon, value.alt)  # type: ignore[attr-defined]
    if isinstance(value, (str, bytes)) or np.ndim(value) != 1 or np.size(value) != 3:
        raise InputError(
            f"dataset: origin must be an Origin(lat, lon, alt), a (lat, lon, alt) sequence or "
            f"None (the first fix), not {type(value).__name__} {value!r:.60}"
        )
    return Origin(*value)  # type: ignore[misc]


# Dataset.metadata key: the IMU's times were derived from the GNSS receiver's epochs (a UBX
# log's sensor time tags mapped by anchors, fgins.io.ubx), so the receiver's clock is the
# only clock and a constant offset the fixes show is the mapping's, not a latency of theirs.
IMU_TIMES_FROM_FIXES_KEY = "imu_times_from_fix_epochs"
# Trajectory.info: the vehicle constraints fit poorly while moving (fgins.graph.reports).
NHC_FIT_POOR_KEY = "nhc_fit_poor"
# Dataset.metadata key: the fixes the input checks left out as a frozen output's repeats
# (fgins.io.motion_checks.drop_frozen_runs), which the GNSS count line adds.
FROZEN_DROPPED_KEY = "gnss_frozen_repeats_dropped"


@dataclass(eq=False)
class Dataset:
    """Everything one run consumes: sensors, the local frame origin and metadata.

    ``imu_noise`` and ``gnss_noise`` hold sensor settings that come with the data (KITTI's
    metadata file, a simulator's ``config.toml``) as datasheet-unit config dicts; the user's
    config overrides them. ``warnings`` collects counted, non-fatal findings of the readers.
    """

    imu: ImuData
    gnss: GnssData
    origin: Origin
    baro: BaroData | None = None
    odometer: OdometerData | None = None
    name: str = ""
    imu_config: dict[str, object] = field(default_factory=dict)
    gnss_config: dict[str, object] = field(default_factory=dict)
    # Smoother settings that come with the data (a sim folder's IMU mounting).
    smoother_config: dict[str, object] = field(default_factory=dict)
    vehicle: str | None = None
    warnings: list[str] = field(default_factory=list)
    metadata: dict[str, object] = field(default_factory=dict)
    # Raw gyro-free IMU readings when ``imu`` was derived from an accelerometer array.
    accel_array: AccelArrayData | None = None

    def __post_init__(self) -> None:
        # A dataset made in code (the API) gets a one-line error here, not an AttributeError
        # deep inside a solve.
        for name, kind, optional in (
            ("imu", ImuData, False), ("gnss", GnssData, False), ("baro", BaroData, True),
            ("odometer", OdometerData, True), ("accel_array", AccelArrayData, True),
        ):  # fmt: skip
            value = getattr(self, name)
            if not isinstance(value, kind) and not (optional and value is None):
                need = "GNSS fixes: fgins anchors the trajectory on them" if name == "gnss" else ""
                raise InputError(
                    f"dataset: {name} must be a fgins.{kind.__name__}{' or None' if optional else ''}"
                    f", not {type(value).__name__}{f' ({need})' if need and value is None else ''}"
                )
        self.origin = _as_origin(self.origin, self.gnss)

    @property
    def t0(self) -> float:
        """Time of the first GNSS epoch in the input, usable or not: the reference of outage
        windows (DESIGN.md). Readers that drop epochs without a fix (NMEA quality 0, a
        NavSatFix with status -1, a UBX epoch without a fix) record the first epoch's time as
        ``metadata["gnss_first_epoch_t"]``, so such a prefix does not move the windows."""
        if len(self.gnss) == 0:
            raise InputError(f"{self.name or 'dataset'}: no GNSS epochs at all")
        first = float(self.gnss.t[0])
        recorded = self.metadata.get("gnss_first_epoch_t")
        # Within a day before the first fix (a stray time in a no-fix epoch is not a t0).
        if isinstance(recorded, (int, float)) and 0.0 <= first - recorded <= 86400.0:
            return float(recorded)
        return first

    def gnss_enu(self) -> np.ndarray:
        """GNSS positions in the local ENU frame (M, 3)."""
        from fgins.geodesy import lla_to_enu

        return lla_to_enu(self.gnss.lla, self.origin)

    def gnss_velocity_nav(self) -> np.ndarray | None:
        """The receiver's velocities (M, 3) in the navigation frame (the origin's ENU), or
        None: a receiver gives them in the local level where it is, 0.09 deg turned from
        the origin's 10 km away (0.16 m/s of a 100 m/s flight)."""
        if self.gnss.velocity is None:
            return None
        from fgins.geodesy import vectors_local_to_nav

        return vectors_local_to_nav(self.gnss.lla, self.gnss.velocity, self.origin)


def level_axes(rotation: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The horizontal unit directions (N, 3) of bodies' forward (x) axes and across them (to
    the left), for body-to-ENU ``rotation`` (N, 3, 3); east where the x axis is vertical."""
    heading = rotation[:, :2, 0]
    norm = np.linalg.norm(heading, axis=1, keepdims=True)
    heading = np.where(norm > 1e-9, heading / np.maximum(norm, 1e-9), [1.0, 0.0])
    zeros = np.zeros(len(heading))
    forward = np.stack([heading[:, 0], heading[:, 1], zeros], axis=1)
    across = np.stack([-heading[:, 1], heading[:, 0], zeros], axis=1)
    return forward, across


END_TOLERANCE_S = 1e-6  # Trajectory.at(): this close to an end is at it


@dataclass(eq=False)
class Trajectory:
    """An estimated (or true) trajectory in the local ENU frame.

    ``rotation`` holds body-to-ENU rotation matrices (N, 3, 3); ``position_cov`` the ENU
    position covariance (N, 3, 3) or NaN where unknown. ``timings`` maps stage names to wall
    seconds; ``info`` carries method-specific counts (rejected epochs, iterations, ...).
    """

    t: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    rotation: np.ndarray
    origin: Origin
    method: str = ""
    gyro_bias: np.ndarray | None = None
    accel_bias: np.ndarray | None = None
    position_cov: np.ndarray | None = None
    velocity_cov: np.ndarray | None = None
    attitude_cov: np.ndarray | None = None
    timings: dict[str, float] = field(default_factory=dict)
    info: dict[str, object] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.t = _as_float_array("trajectory.t", self.t, ())
        n = self.t.shape[0]
        self.position = _as_float_array("trajectory.position", self.position, (3,))
        self.velocity = _as_float_array("trajectory.velocity", self.velocity, (3,))
        self.rotation = _as_float_array("trajectory.rotation", self.rotation, (3, 3))
        for name in ("position", "velocity", "rotation"):
            if getattr(self, name).shape[0] != n:
                raise InputError(f"trajectory.{name}: {getattr(self, name).shape[0]} rows for {n}")
        self.gyro_bias = _optional("trajectory.gyro_bias", self.gyro_bias, n, (3,))
        self.accel_bias = _optional("trajectory.accel_bias", self.accel_bias, n, (3,))
        self.position_cov = _optional("trajectory.position_cov", self.position_cov, n, (3, 3))
        self.velocity_cov = _optional("trajectory.velocity_cov", self.velocity_cov, n, (3, 3))
        self.attitude_cov = _optional("trajectory.attitude_cov", self.attitude_cov, n, (3, 3))

    def __len__(self) -> int:
        return int(self.t.shape[0])

    @property
    def position_std(self) -> np.ndarray:
        """1-sigma ENU position error (N, 3), NaN where unknown."""
        return np.sqrt(np.clip(np.diagonal(self.position_cov, axis1=1, axis2=2), 0, None))

    @property
    def attitude_std_deg(self) -> np.ndarray:
        """1-sigma roll, pitch and heading errors (N, 3) in deg, NaN where unknown: the
        navigation-frame attitude covariance about the horizontal direction of the body's
        forward axis (roll), the horizontal axis across it (pitch) and up (heading). Both
        tilt axes are horizontal, as the Euler angles' are: a heading known to 180 deg only
        (a vehicle that never moved) does not leak into the roll of a pitched body."""
        assert self.attitude_cov is not None  # filled with NaN by __post_init__
        forward, across = level_axes(self.rotation)
        cov = self.attitude_cov
        var = np.stack(
            [
                np.einsum("ni,nij,nj->n", forward, cov, forward),
                np.einsum("ni,nij,nj->n", across, cov, across),
                cov[:, 2, 2],
            ],
            axis=1,
        )
        return np.degrees(np.sqrt(np.clip(var, 0, None)))

    def roll_pitch_heading_deg(self) -> np.ndarray:
        """Roll, pitch (deg) and heading (deg from north, clockwise) of the body x axis (N, 3).

        Body axes are taken as x forward, y left, z up (the IMU's axes after the
        IMU-to-vehicle rotation); for an ENU frame, heading = 90 deg - yaw.
        """
        from fgins.geodesy import rotation_to_roll_pitch_heading

        return rotation_to_roll_pitch_heading(self.rotation)

    def at(self, t: np.ndarray, *, hold_ends: bool = False) -> np.ndarray:
        """Position interpolated to times ``t`` (linear), (len(t), 3). NaN at times outside
        the trajectory's span, which it does not know (a camera's stamps 10 s after the end
        got the last position, unsaid); ``hold_ends``: the first or last position there.
        Times that are not numbers (a string, None) are an :class:`InputError`; a NaN time
        gets a NaN position."""
        try:
            if t is None:
                raise TypeError
            given = np.asarray(t)
            if given.dtype.kind in "Mm":
                # datetime64 converted to float is nanoseconds: all NaN, unsaid (outside tester)
                raise InputError(
                    "Trajectory.at(): times must be seconds on the trajectory's own clock (its "
                    "time column), not datetime64; convert them, e.g. "
                    "(times - numpy.datetime64(0, 's')) / numpy.timedelta64(1, 's')"
                )
            t = np.asarray(given, dtype=float)
        except (TypeError, ValueError):
            raise InputError(f"Trajectory.at(): times must be numbers (seconds), not {t!r:.60}") from None
        if t.ndim == 2 and 1 in t.shape:  # a column or a row (a one-column DataFrame)
            t = t.ravel()
        if t.ndim > 1:
            raise InputError(f"Trajectory.at(): times must be one-dimensional, got shape {t.shape}")
        out = np.column_stack([np.interp(t, self.t, self.position[:, i]) for i in range(3)])
        if not hold_ends and len(self.t):
            # A microsecond's round-off at an end (times re-based, or stored as nanoseconds) is
            # the end, not outside.
            outside = (t < self.t[0] - END_TOLERANCE_S) | (t > self.t[-1] + END_TOLERANCE_S)
            out[np.atleast_1d(outside)] = np.nan
        return out

    # Thin entry points of the public API (fgins.api), imported on use so the data model
    # stays numpy-only.
    def to_dataframe(self):  # -> pandas.DataFrame
        """The trajectory as a pandas DataFrame with the trajectory CSV's columns, in order.

        See :func:`fgins.api.to_dataframe`.
        """
        from fgins.api import to_dataframe

        return to_dataframe(self)

    def write(self, path, *, with_input: bool = False) -> None:
        """Write the trajectory; the format follows the extension (.csv .geojson .kml .mcap .tum).

        See :func:`fgins.api.write`.
        """
        from fgins.api import write

        write(self, path, with_input=with_input)

    def summary(self) -> dict[str, object]:
        """The run summary as a dict (method, counts, GNSS gating, rejected fixes, timings...).

        See :func:`fgins.api.summary`.
        """
        from fgins.api import summary

        return summary(self)
