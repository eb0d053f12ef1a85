"""The trajectory CSV of DESIGN.md (results and simulator truth), written atomically."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pymap3d

from fgins.datatypes import InputError, Origin, Trajectory
from fgins.geodesy import (
    enu_to_lla,
    lla_to_enu,
    local_to_origin_rotation,
    roll_pitch_heading_to_rotation,
    rotation_to_roll_pitch_heading,
)
from fgins.io.atomic import atomic_path

COLUMNS = [
    "time", "lat", "lon", "alt", "east", "north", "up",
    "vel_east", "vel_north", "vel_up", "roll_deg", "pitch_deg", "heading_deg",
    "std_east", "std_north", "std_up",
]  # fmt: skip
EXTRA_COLUMNS = [
    "gyro_bias_x", "gyro_bias_y", "gyro_bias_z", "accel_bias_x", "accel_bias_y", "accel_bias_z",
    "std_roll_deg", "std_pitch_deg", "std_heading_deg",
]  # fmt: skip


def trajectory_table(trajectory: Trajectory) -> np.ndarray:
    """The trajectory as rows of :data:`COLUMNS` + :data:`EXTRA_COLUMNS`.

    east/north/up are the navigation frame's (the tangent plane at the origin); velocity and
    attitude are in the local level at each point, as a receiver or a reference system
    gives them (20 km from the origin the two differ by 0.18 deg).
    """
    lla = enu_to_lla(trajectory.position, trajectory.origin)
    to_local = np.swapaxes(local_to_origin_rotation(lla[:, 0], lla[:, 1], trajectory.origin), 1, 2)
    velocity = np.einsum("nij,nj->ni", to_local, trajectory.velocity)
    attitude = rotation_to_roll_pitch_heading(to_local @ trajectory.rotation)
    return np.column_stack(
        [
            trajectory.t, lla, trajectory.position, velocity, attitude,
            trajectory.position_std, trajectory.gyro_bias, trajectory.accel_bias,
            trajectory.attitude_std_deg,
        ]
    )  # fmt: skip


def trajectory_columns(trajectory: Trajectory) -> tuple[list[str], np.ndarray]:
    """The CSV's header and its values before formatting: (:data:`COLUMNS` +
    :data:`EXTRA_COLUMNS`, (N, 25) float array). One place for the column computation, shared
    by the CSV writer and ``Trajectory.to_dataframe()``."""
    return COLUMNS + EXTRA_COLUMNS, trajectory_table(trajectory)


def trajectory_formats() -> list[str]:
    """%-formats of :data:`COLUMNS` + :data:`EXTRA_COLUMNS`: time to the microsecond,
    degrees of latitude/longitude to 1e-9, metres and degrees to 0.1 mm / 1e-4, biases in
    exponent form."""
    formats = ["%.6f", "%.9f", "%.9f"] + ["%.4f"] * (len(COLUMNS) + len(EXTRA_COLUMNS) - 3)
    bias = len(COLUMNS)
    formats[bias : bias + 6] = ["%.4e"] * 6
    return formats


def write_trajectory_csv(trajectory: Trajectory, path: str | Path) -> None:
    """Write the DESIGN.md trajectory CSV (plus bias columns); NaN where unknown."""
    table = trajectory_table(trajectory)
    formats = trajectory_formats()
    with atomic_path(path) as tmp:
        write_table(tmp, table, formats, ",".join(COLUMNS + EXTRA_COLUMNS))


# --- vectorised %-formatting (issue 9: np.savetxt formats row by row in Python) -------------
#
# The bytes are exactly np.savetxt's (``fmt % row`` per line): each number is rounded the way
# Python's correctly rounded %-formatting does, from the exact value of the double. Numbers
# are scaled by an exact power of ten with an error-free product (Dekker), so the rounding
# direction is decided on the exact product; the rare cells where it cannot be (exact or
# near ties, values too large or too small for int64 digits, formats other than %.Nf and
# %.Ne) are formatted by Python itself.


def write_table(path: str | Path, table: np.ndarray, formats: list[str], header: str) -> None:
    """``np.savetxt(path, table, delimiter=",", fmt=formats, header=header, comments="")``,
    same bytes, vectorised (in chunks of rows, so memory stays bounded)."""
    table = np.asarray(table, dtype=float)
    with open(path, "wb") as handle:
        handle.write(header.encode() + b"\n")
        for start in range(0, len(table), CHUNK_ROWS):
            handle.write(_format_rows(table[start : start + CHUNK_ROWS], formats))


CHUNK_ROWS = 65536


def format_columns(table: np.ndarray, formats: list[str]) -> list[str]:
    """The lines ``np.savetxt`` would write for ``table`` (n, m) with ``formats`` (m)."""
    body = _format_rows(np.asarray(table, dtype=float), formats).decode()
    return body.split("\n")[:-1]


def _format_rows(table: np.ndarray, formats: list[str]) -> bytes:
    """The CSV lines of ``table``: every cell as a row of bytes in a (rows, width) uint8
    matrix, 0 where a cell is shorter than its column's width; the lines are the matrix
    with the zeros dropped."""
    if table.ndim != 2 or table.shape[1] != len(formats):
        raise ValueError("format_columns: one format per column of a 2-D table")
    n = len(table)
    if n == 0:
        return b""
    comma = np.full((n, 1), ord(","), dtype=np.uint8)
    parts: list[np.ndarray] = []
    for j, fmt in enumerate(formats):
        if j:
            parts.append(comma)
        parts.append(_format_column(table[:, j], fmt))
    parts.append(np.full((n, 1), ord("\n"), dtype=np.uint8))
    flat = np.concatenate(parts, axis=1).ravel()
    return flat[flat != 0].tobytes()


def _digits(value: np.ndarray, width: int, min_digits: int = 1) -> np.ndarray:
    """Decimal digits of non-negative int64 ``value`` as (n, width) ASCII, most significant
    first; leading zeros beyond ``min_digits`` digits are 0 bytes (dropped on output)."""
    out = np.zeros((len(value), width), dtype=np.uint8)
    rest = value.copy()
    for k in range(width - 1, -1, -1):
        digit = (rest % 10).astype(np.uint8) + ord("0")
        out[:, k] = digit if k >= width - min_digits else np.where(rest > 0, digit, 0)
        rest //= 10
    return out


_FIXED = re.compile(r"^%\.(\d+)([fe])$")
_INT_LIMIT = 2.0**53  # scaled values below this are exact integers in float and int64
_SPLIT = 134217729.0  # 2^27 + 1, Veltkamp's splitter


def _two_product(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """hi, lo with hi + lo == a * b exactly (Dekker; needs |a|, |b| < 1e290)."""
    hi = a * b
    t = _SPLIT * a
    a_hi = t - (t - a)
    a_lo = a - a_hi
    t = _SPLIT * b
    b_hi = t - (t - b)
    b_lo = b - b_hi
    lo = ((a_hi * b_hi - hi) + a_hi * b_lo + a_lo * b_hi) + a_lo * b_lo
    return hi, lo


def _round_scaled(a: np.ndarray, power: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """round(a * 10**power) of the exact product (a >= 0, power in 0..22 each), and where
    that is certain (not a tie or too close to one, not beyond int64 digits)."""
    scale = 10.0 ** power.astype(float)  # exact for powers 0..22
    with np.errstate(all="ignore"):  # huge cells overflow here; they are not "certain"
        hi, lo = _two_product(a, scale)
        q0 = np.rint(hi)
        rest = (hi - q0) + lo  # the exact fraction, to within 1e-16
        q = q0 + (rest > 0.5) - (rest < -0.5)
        certain = (np.abs(np.abs(rest) - 0.5) > 1e-15) & (hi < _INT_LIMIT) & (a < 1e290)
    return q, certain


def _python_cells(x: np.ndarray, fmt: str) -> np.ndarray:
    """Python's own ``fmt % value`` per cell, as a (n, width) ASCII matrix (0-padded)."""
    cells = [(fmt % v).encode() for v in x.tolist()]
    width = max((len(c) for c in cells), default=1)
    return np.frombuffer(b"".join(c.ljust(width, b"\0") for c in cells), dtype=np.uint8).reshape(
        len(cells), width
    )


def _format_column(x: np.ndarray, fmt: str) -> np.ndarray:
    """One column, each cell ``fmt % value``, as a (n, width) ASCII matrix (0-padded)."""
    match = _FIXED.match(fmt)
    n = len(x)
    if match is None or int(match.group(1)) > 15:
        return _python_cells(x, fmt)
    digits, kind = int(match.group(1)), match.group(2)
    finite = np.isfinite(x)
    safe = np.where(finite, np.abs(x), 0.0)
    if kind == "f":
        q, certain = _round_scaled(safe, np.full(n, digits))
        exponent = None
    else:
        # a = m * 10^e with 1 <= m < 10: round(a * 10^(digits - e)) has digits + 1 digits.
        with np.errstate(divide="ignore"):
            e = np.floor(np.log10(np.where(safe > 0, safe, 1.0))).astype(np.int64)
        for _ in range(2):  # log10 can be one off near powers of ten; so can the rounding
            power = digits - e
            usable = (power >= 0) & (power <= 22)
            q, certain = _round_scaled(safe, np.clip(power, 0, 22))
            high = usable & (q >= 10.0 ** (digits + 1))
            low = usable & (q < 10.0**digits) & (safe > 0)
            e = e + high - low
        certain &= usable & ~high & ~low
        q = np.where(safe > 0, q, 0.0)
        exponent = np.where(safe > 0, e, 0)
    certain &= finite
    q_int = np.where(certain, q, 0.0).astype(np.int64)
    unit = 10**digits
    whole = q_int // unit
    largest = int(whole.max()) if n else 0
    parts = [
        np.where(np.signbit(x), ord("-"), 0).astype(np.uint8)[:, None],
        _digits(whole, len(str(largest))),
    ]
    if digits:
        parts.append(np.full((n, 1), ord("."), dtype=np.uint8))
        parts.append(_digits(q_int % unit, digits, digits))
    if exponent is not None:
        parts.append(np.full((n, 1), ord("e"), dtype=np.uint8))
        parts.append(np.where(exponent < 0, ord("-"), ord("+")).astype(np.uint8)[:, None])
        magnitude = np.abs(exponent)
        parts.append(_digits(magnitude, max(2, len(str(int(magnitude.max())))), 2))
    out = np.concatenate(parts, axis=1)
    if not finite.all():  # Python writes nan (whatever its sign), inf and -inf
        if out.shape[1] < 4:
            out = np.pad(out, ((0, 0), (0, 4 - out.shape[1])))
        for word, where in (
            (b"nan", np.isnan(x)),
            (b"inf", np.isposinf(x)),
            (b"-inf", np.isneginf(x)),
        ):
            out[where] = 0
            out[where, : len(word)] = np.frombuffer(word, dtype=np.uint8)
    # The cells whose rounding is not certain: Python's own formatting.
    python = finite & ~certain
    if python.any():
        index = np.flatnonzero(python)
        cells = _python_cells(x[index], fmt)
        if cells.shape[1] > out.shape[1]:
            out = np.pad(out, ((0, 0), (0, cells.shape[1] - out.shape[1])))
        out[index] = 0
        out[index, : cells.shape[1]] = cells
    return out


def read_trajectory_csv(
    path: str | Path, origin: Origin | None = None, *, enu_about_origin: bool = False
) -> Trajectory:
    """Read a trajectory CSV (e.g. simulator ``truth.csv``) back into a :class:`Trajectory`.

    Needs ``time`` and a position: ``lat,lon,alt`` (taken in ``origin``'s frame when it is
    given), or ``east,north,up`` alone where the caller knows them to be about ``origin``
    (``enu_about_origin``: a sim folder's stated [origin]; otherwise their origin is unknown:
    an independent car simulator's truth, about its own origin 2.6 m from the first fix,
    scored every epoch 2 m off). Velocity, attitude and sigma columns are read where
    present, NaN where not: another simulator's truth has no sigmas (an independent flight
    simulator's truth.csv stopped ``fgins bench`` with "missing trajectory column(s)
    std_east, ..."). Without ``origin`` the ENU origin is recovered from the first row's
    lat/lon/alt and ENU.
    """
    path = Path(path)
    try:
        with path.open() as handle:
            header = [name.strip() for name in handle.readline().strip().split(",")]
        data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a readable trajectory CSV ({exc})") from None
    has_lla = all(c in header for c in ("lat", "lon", "alt"))
    has_enu = all(c in header for c in ("east", "north", "up"))
    if "time" not in header or not (has_lla or (has_enu and origin is not None and enu_about_origin)):
        unknown = (
            " (its east, north, up are about an origin the file does not give)" if has_enu else ""
        )
        raise InputError(f"{path}: a trajectory CSV needs the columns time and lat, lon, alt{unknown}")
    if data.shape[1] != len(header):
        raise InputError(f"{path}: {data.shape[1]} values per row for {len(header)} columns")
    col = {name: data[:, header.index(name)] for name in header}
    n = len(data)
    if has_lla and origin is None and has_enu:
        lat, lon, alt = pymap3d.enu2geodetic(
            -col["east"][0], -col["north"][0], -col["up"][0],
            col["lat"][0], col["lon"][0], col["alt"][0],
        )  # fmt: skip
        origin = Origin(float(lat), float(lon), float(alt))
        position = np.column_stack([col["east"], col["north"], col["up"]])
    elif has_lla:
        # In the caller's frame, whatever origin the file's own east/north/up are about.
        origin = origin or Origin(float(col["lat"][0]), float(col["lon"][0]), float(col["alt"][0]))
        position = lla_to_enu(np.column_stack([col["lat"], col["lon"], col["alt"]]), origin)
    else:
        position = np.column_stack([col["east"], col["north"], col["up"]])
    assert origin is not None
    lat_lon = (col["lat"], col["lon"]) if has_lla else tuple(
        enu_to_lla(position, origin)[:, i] for i in range(2)
    )  # fmt: skip
    # Velocity and attitude columns are in the local level at each point (trajectory_table).
    to_nav = local_to_origin_rotation(lat_lon[0], lat_lon[1], origin)

    def columns(names: list[str]) -> np.ndarray | None:
        if all(name in col for name in names):
            return np.column_stack([col[name] for name in names])
        return None

    attitude = columns(["roll_deg", "pitch_deg", "heading_deg"])
    rotation = np.full((n, 3, 3), np.nan)
    if attitude is not None:
        rotation = to_nav @ np.array([roll_pitch_heading_to_rotation(*row) for row in attitude])
    velocity = columns(["vel_east", "vel_north", "vel_up"])
    velocity = np.full((n, 3), np.nan) if velocity is None else np.einsum("nij,nj->ni", to_nav, velocity)
    std = columns(["std_east", "std_north", "std_up"])
    cov = np.zeros((n, 3, 3))
    for i in range(3):
        cov[:, i, i] = np.nan if std is None else std[:, i] ** 2
    return Trajectory(
        t=col["time"],
        position=position,
        velocity=velocity,
        rotation=rotation,
        origin=origin,
        method=path.stem,
        gyro_bias=columns(EXTRA_COLUMNS[:3]),
        accel_bias=columns(EXTRA_COLUMNS[3:6]),
        position_cov=cov,
    )
