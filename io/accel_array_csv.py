"""Gyro-free IMU input: ``accel_array.csv`` (raw accelerometer-array readings) + its geometry.

``accel_array.csv`` is ``time,a1,...,aN`` (s, m/s^2), one column per single-axis accelerometer.
The geometry and noise come from an ``[accel_array]`` TOML table (a ``fgins sim`` folder's
``config.toml``)::

    [accel_array]
    positions_m = [[0.0, 0.0, -0.1], ...]     # N x 3, body frame, m
    axes = [[0.7071, 0.7071, 0.0], ...]        # N x 3 unit sensing axes
    noise_m_per_s2_per_sqrt_hz = 0.00196       # per-sensor white noise density
    bias_sigma_m_per_s2 = 0.00098              # optional: residual bias after calibration
    initial_rate_rad_per_s = [0.0, 0.0, 0.0]   # optional: rate at the first sample (default 0)
    grade = "tactical"                         # optional: fgins.sim.accel_array.GRADES name

The ordinary IMU the rest of fgins consumes is *derived* by the front end
(:func:`fgins.factors.accel_array.solve_array`): :func:`derive_imu` returns it with the
``[imu]`` noise keys that describe it (:func:`fgins.factors.accel_array.equivalent_imu_noise`).
"""

from __future__ import annotations

import csv
import itertools
import math
import re
from pathlib import Path
from typing import Any

import numpy as np

from fgins.datatypes import AccelArrayData, ImuData, InputError
from fgins.factors.accel_array import (
    AccelArray,
    RestCalibration,
    calibrate_at_rest,
    equivalent_imu_noise,
    solve_array,
    to_imu_data,
)
from fgins.io.atomic import atomic_path

ACCEL_ARRAY_FILE = "accel_array.csv"
_READING_COLUMN = re.compile(r"a(\d+)$")
# Residual bias assumed when neither the table nor the grade states one: 1 mg (a calibrated
# MEMS accelerometer); stated in the dataset's warnings so it is never silent.
DEFAULT_BIAS_SIGMA = 1e-3 * 9.80665


def is_accel_array_header(header: list[str]) -> bool:
    """True for ``time,a1,...,aN`` (N >= 1, columns numbered 1..N in order)."""
    if len(header) < 2 or header[0] != "time":
        return False
    numbers = [_READING_COLUMN.match(name) for name in header[1:]]
    return all(m is not None and int(m.group(1)) == i + 1 for i, m in enumerate(numbers))


def _is_comment(row: list[str]) -> bool:
    return bool(row) and row[0].lstrip().startswith("#")


def _is_data(row: list[str]) -> bool:
    """Every cell a number or blank, at least one a number."""
    cells = [cell.strip() for cell in row]
    if not any(cells):
        return False
    try:
        [float(cell) for cell in cells if cell]
    except ValueError:
        return False
    return True


def read_accel_array_csv(
    path: str | Path, warnings: list[str] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Times (T,) and readings (T, N) of ``accel_array.csv``.

    Malformed rows and rows with a missing or non-finite value are dropped and counted in
    ``warnings`` (the rate integral then spans the longer interval); unsorted times raise.
    """
    path = Path(path)
    warnings = [] if warnings is None else warnings
    comments = 0
    try:
        with path.open(newline="", encoding="utf-8-sig") as handle:
            reader = csv.reader(handle)
            first = next(reader, [])
            leading: list[list[str]] = []
            while first and _is_comment(first):  # '#' comment lines before the header
                leading.append(first)
                first = next(reader, [])
            rows: list[list[float]] = []
            if leading and _is_data(first) and len(leading[-1]) > 1:
                # the header written as a comment ("# time,a1,...", numpy.savetxt's default)
                header_row = leading.pop()
                header_row[0] = header_row[0].lstrip().lstrip("#")
                pending = [first]
            else:
                header_row, pending = first, []
            comments = len(leading)
            header = [name.strip().lower() for name in header_row]
            if not is_accel_array_header(header):
                after = f" (after {comments} '#' comment line(s))" if comments else ""
                raise InputError(
                    f"{path}: header must be time,a1,...,aN (accelerometer array readings){after}"
                )
            bad = 0
            for row in itertools.chain(pending, reader):
                if not row or all(not cell.strip() for cell in row):
                    continue
                if _is_comment(row):
                    comments += 1
                    continue
                try:
                    values = [float(cell) for cell in row]
                except ValueError:
                    bad += 1
                    continue
                if len(values) != len(header) or not all(math.isfinite(v) for v in values):
                    bad += 1
                    continue
                rows.append(values)
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text CSV file") from None
    if comments:
        warnings.append(f"{path.name}: skipped {comments} '#' comment line(s)")
    if bad:
        warnings.append(f"{path.name}: dropped {bad} malformed or incomplete reading row(s)")
    if len(rows) < 3:
        raise InputError(f"{path}: need at least 3 reading rows, got {len(rows)}")
    table = np.array(rows)
    return table[:, 0], table[:, 1:]


def write_accel_array_csv(data: AccelArrayData, path: str | Path) -> None:
    """Write ``time,a1,...,aN`` (atomically)."""
    header = ["time"] + [f"a{j + 1}" for j in range(data.n_sensors)]
    table = np.column_stack([data.t, data.readings])
    with atomic_path(path) as tmp:
        np.savetxt(
            tmp,
            table,
            delimiter=",",
            header=",".join(header),
            comments="",
            fmt=["%.6f"] + ["%.10e"] * data.n_sensors,
        )


def accel_array_table(data: AccelArrayData) -> dict[str, Any]:
    """The ``[accel_array]`` config table describing ``data`` (geometry, noise, grade)."""
    table: dict[str, Any] = {
        "positions_m": data.positions.tolist(),
        "axes": data.axes.tolist(),
        "noise_m_per_s2_per_sqrt_hz": data.noise_density,
    }
    if data.bias_sigma is not None:
        table["bias_sigma_m_per_s2"] = data.bias_sigma
    if np.any(data.initial_rate != 0):
        table["initial_rate_rad_per_s"] = data.initial_rate.tolist()
    if data.grade:
        table["grade"] = data.grade
    return table


_TABLE_KEYS = {
    "positions_m",
    "axes",
    "noise_m_per_s2_per_sqrt_hz",
    "bias_sigma_m_per_s2",
    "initial_rate_rad_per_s",
    "grade",
}


def accel_array_from_table(
    table: dict[str, Any],
    t: np.ndarray,
    readings: np.ndarray,
    *,
    where: str = "[accel_array]",
    warnings: list[str] | None = None,
) -> AccelArrayData:
    """Readings plus an ``[accel_array]`` table -> validated :class:`AccelArrayData`."""
    warnings = [] if warnings is None else warnings
    unknown = set(table) - _TABLE_KEYS
    if unknown:
        raise InputError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}")
    missing = [k for k in ("positions_m", "axes", "noise_m_per_s2_per_sqrt_hz") if k not in table]
    if missing:
        raise InputError(
            f"{where}: missing key(s) {', '.join(missing)}; the accelerometer-array readings "
            "need the geometry and noise density (see fgins.io.accel_array_csv)"
        )
    try:
        positions = np.asarray(table["positions_m"], dtype=float)
        axes = np.asarray(table["axes"], dtype=float)
        initial_rate = np.asarray(table.get("initial_rate_rad_per_s", [0.0, 0.0, 0.0]), float)
        noise = float(table["noise_m_per_s2_per_sqrt_hz"])
    except (TypeError, ValueError):
        raise InputError(f"{where}: positions_m, axes and noise must be numbers") from None
    if positions.ndim != 2 or positions.shape[0] != readings.shape[1]:
        raise InputError(
            f"{where}: {positions.shape[0] if positions.ndim == 2 else '?'} positions for "
            f"{readings.shape[1]} reading columns; list one position and axis per column a1..aN"
        )
    grade = str(table.get("grade", ""))
    bias_sigma = table.get("bias_sigma_m_per_s2")
    if bias_sigma is None and grade:
        from fgins.sim.accel_array import resolve_grade

        bias_sigma = resolve_grade(grade).residual_bias
    if bias_sigma is None:
        bias_sigma = DEFAULT_BIAS_SIGMA
        warnings.append(
            f"{where}: no bias_sigma_m_per_s2 or grade; assuming {DEFAULT_BIAS_SIGMA:.3g} m/s^2"
        )
    return AccelArrayData(
        t=t,
        readings=readings,
        positions=positions,
        axes=axes,
        noise_density=noise,
        bias_sigma=float(bias_sigma),
        initial_rate=initial_rate,
        grade=grade,
    )


def array_geometry(data: AccelArrayData) -> AccelArray:
    """The validated geometry (raises InputError for degenerate arrays)."""
    return AccelArray(positions=data.positions, axes=data.axes)


def derive_imu(data: AccelArrayData, *, calibrate: bool = True) -> tuple[ImuData, dict[str, float]]:
    """The front end: the array's ordinary IMU output and the ``[imu]`` keys describing it.

    Readings are solved by noise-weighted least squares (equal weights for one density) and
    the rate integrated from ``data.initial_rate``. With ``calibrate`` (default) the angular-
    acceleration bias is first measured over the initial standstill, if the record has one
    (:func:`fgins.factors.accel_array.calibrate_at_rest`): without it the residual
    accelerometer biases make the rate error a ramp that no rate random walk describes. The noise keys say that the "gyro" error is
    the integral of accelerometer noise and bias (:func:`equivalent_imu_noise`); ``rate_hz``
    is added so the graph knows the sample rate.
    """
    array = array_geometry(data)
    calibration = rest_calibration(data) if calibrate else None
    solution = solve_array(
        array,
        data.readings,
        data.t,
        data.initial_rate,
        alpha_bias=None if calibration is None else calibration.alpha_bias,
    )
    imu = to_imu_data(solution)
    _check_rates(imu, calibration is not None, calibrate)
    bias = DEFAULT_BIAS_SIGMA if data.bias_sigma is None else data.bias_sigma
    noise = equivalent_imu_noise(
        array,
        data.noise_density,
        bias,
        alpha_bias_sigma=None if calibration is None else calibration.alpha_bias_sigma,
    )
    walk = noise.get("gyro_bias_rw_rad_per_s_per_sqrt_s", 0.0)
    if walk > ARRAY_RATE_WALK_MAX:
        # Derived, not given: it had been refused as a config value "[imu].gyro_bias_rw...
        # = 1.08: must be <= 1", a key the user never wrote (outside tester).
        raise InputError(
            f"accel_array: its rates, integrated from the angular acceleration, would drift at "
            f"{walk:.3g} rad/s/sqrt(s) (from the accelerometers' bias sigma {bias:g} m/s^2"
            + (", with no standstill at the start to calibrate it" if calibration is None else "")
            + f"; fgins takes at most {ARRAY_RATE_WALK_MAX:g}): no estimator holds an attitude "
            "on that; start the log at rest (10 s or more) for the rest calibration, or give "
            "the calibrated array's [accel_array] bias_sigma_m_per_s2"
        )
    return imu, {"preset": "tactical", **noise, "rate_hz": imu.rate_hz}


# Rates the front end integrates beyond this (rad/s; a MEMS gyro's top range is ~35) are no
# vehicle's: the readings do not fit the geometry or their biases ran the rate away.
ARRAY_RATE_MAX_RAD_S = 35.0
ARRAY_RATE_WALK_MAX = 1.0  # rad/s/sqrt(s): the [imu] bound of gyro_bias_rw_rad_per_s_per_sqrt_s


def _check_rates(imu: ImuData, calibrated: bool, calibrate: bool) -> None:
    """An error naming the array when its integrated rates run beyond any vehicle's: they
    were refused as "a unit mistake; give gyro_x..z in rad/s" of an input that has no gyro
    columns (columns swapped, one sensing axis negated, a dead or 5-20 mg biased
    accelerometer on a drive that does not start at rest; outside tester)."""
    rate = np.linalg.norm(imu.gyro, axis=1)
    beyond = np.flatnonzero(~(rate <= ARRAY_RATE_MAX_RAD_S))
    if not beyond.size:
        return
    when = float(imu.t[beyond[0]] - imu.t[0])
    rest = (
        "" if calibrated or not calibrate
        else "; the log does not start at rest, so no angular-acceleration bias was calibrated"
    )
    raise InputError(
        f"accel_array: the angular rate integrated from the accelerometers runs to "
        f"{float(np.nanmax(rate)) if np.any(np.isfinite(rate)) else float('inf'):.3g} rad/s "
        f"(beyond {ARRAY_RATE_MAX_RAD_S:g} from t-t0 = {when:.1f} s on): the columns a1..aN "
        "do not match the [accel_array] geometry (order, positions, sensing axes and their "
        "signs), an accelerometer is dead, or one is biased far beyond bias_sigma_m_per_s2 "
        f"(the geometry makes a bias an angular acceleration){rest}"
    )


def rest_calibration(data: AccelArrayData) -> RestCalibration | None:
    """The alpha-bias calibration over the initial standstill (None: the record starts moving)."""
    return calibrate_at_rest(array_geometry(data), data.readings, data.t, data.noise_density)
