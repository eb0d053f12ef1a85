"""CSV in and out: the vectorised reader and writer against Python's csv/float and %-formatting.

Independent references: the reader is checked cell by cell against Python's ``csv`` module and
``float`` (the contract: same rows kept, same malformed-row count and warning, same bits); the
writer against ``np.savetxt`` with the same per-column formats (same bytes) and against
Python's own ``%`` formatting of random doubles, ties and extremes.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fgins.datatypes import InputError, Origin, Trajectory
from fgins.io.csv_pair import _read_columns, read_imu_csv
from fgins.io.trajectory_csv import (
    COLUMNS,
    EXTRA_COLUMNS,
    format_columns,
    read_trajectory_csv,
    trajectory_table,
    write_trajectory_csv,
)


def reference_read(path: Path) -> tuple[dict[str, np.ndarray], int, list[str]]:
    """The contract of _read_columns, written out with Python's csv module and float(): the
    columns, the malformed-row count, and the columns ignored as text (a column fgins does not
    read that holds no number at all)."""
    from fgins.io.csv_pair import KNOWN_NUMERIC_COLUMNS

    with path.open(newline="") as handle:
        header = [n.strip().lower() for n in handle.readline().strip().split(",")]
    rows, bad = [], 0
    with path.open(newline="") as handle:
        reader = csv.reader(handle)
        next(reader, None)
        for row in reader:
            if not row or all(not c.strip() for c in row):
                continue
            if len(row) != len(header):
                bad += 1
                continue
            rows.append(row)

    def number(cell: str):
        if not cell.strip():
            return np.nan
        try:
            return float(cell)
        except ValueError:
            return None

    text = [
        i for i, name in enumerate(header)
        if name not in KNOWN_NUMERIC_COLUMNS
        and any(r[i].strip() for r in rows)
        and all(number(r[i]) is None for r in rows if r[i].strip())
    ]  # fmt: skip
    table = []
    for row in rows:
        values = [np.nan if i in text else number(c) for i, c in enumerate(row)]
        if any(v is None for v in values):
            bad += 1
        else:
            table.append(values)
    array = np.array(table, dtype=float).reshape(len(table), len(header))
    columns = {name: array[:, i] for i, name in enumerate(header) if i not in text}
    return columns, bad, [header[i] for i in text]


def assert_same_read(path: Path) -> None:
    expected, bad, text = reference_read(path)
    warnings: list[str] = []
    good = len(next(iter(expected.values()))) if expected else 0
    if bad and good == 0:  # nothing left: either error names the cause (text columns first)
        with pytest.raises(InputError, match=r"no data rows|data rows are malformed"):
            _read_columns(path, warnings)
        return
    if bad > good:
        # Most rows malformed: an error naming that, not a read of the few left (whatever
        # they would then be blamed on) nor "no data rows".
        with pytest.raises(InputError, match=f"{bad} of {bad + good} data rows are malformed"):
            _read_columns(path, warnings)
        return
    if all(len(v) == 0 for v in expected.values()):
        with pytest.raises(InputError, match="no data rows"):
            _read_columns(path, warnings)
        return
    got = _read_columns(path, warnings)
    assert list(got) == list(expected)
    for name in expected:
        # Same bits, NaN where NaN (np.array_equal would let -0.0 == 0.0 pass).
        assert got[name].tobytes() == expected[name].tobytes(), name
    notes = [f"{path.name}: dropped {bad} malformed row(s)"] if bad else []
    if text:
        notes.append(f"{path.name}: ignored column(s) {', '.join(text)} (text, not used by fgins)")
    assert warnings == notes


CELLS = st.one_of(
    st.floats(allow_nan=False, allow_infinity=False).map(repr),
    st.floats(allow_nan=False, allow_infinity=False, width=32).map(lambda x: f"{x:.6f}"),
    st.floats(min_value=-1e6, max_value=1e6).map(lambda x: f"{x:.17e}"),
    st.integers(-(10**20), 10**20).map(str),
    st.sampled_from(
        ["", " ", "  1.5", "2.5 ", "\t3", "nan", "NaN", "-inf", "Infinity", "1_000", "abc",
         "1.2.3", "1e", ".5", "5.", "+7", "-0", "0x10", "NA", "null", '"4.25"', '" 8 "',
         "1e400", "4.9e-324", "\x1c", "\u00a0 9", "١٢"]
    ),
)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    width=st.integers(1, 5),
    rows=st.lists(st.tuples(st.integers(-1, 1), st.lists(CELLS, min_size=6, max_size=6)), max_size=25),
    crlf=st.booleans(),
)
def test_reader_matches_python_csv_and_float(tmp_path, width, rows, crlf):
    """Random tables with blank, short, long and non-numeric rows: the same columns, bits and
    malformed-row warning as Python's csv + float."""
    header = ["time", "gyro_x", "Accel_X ", "x3", "x4"][:width]
    lines = [",".join(header)]
    for delta, cells in rows:
        if delta == 0 and cells[0] == "abc":
            lines.append("")  # a blank line
            continue
        lines.append(",".join(cells[: max(width + delta, 1)]))
    path = tmp_path / "t.csv"
    path.write_bytes(("\r\n" if crlf else "\n").join(lines).encode() + b"\n")
    assert_same_read(path)


def test_reader_on_a_large_file_keeps_bits_and_counts(tmp_path):
    rng = np.random.default_rng(7)
    n = 50_000
    data = rng.normal(size=(n, 7)) * np.array([1e6, 1, 1, 1, 10, 10, 10])
    lines = ["time,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z"]
    lines += [",".join(repr(v) for v in row) for row in data.tolist()]
    lines[100] = "1,2,3"  # short
    lines[200] = lines[200].replace(",", ",x", 1)  # garbage cell
    lines[300] = ",,,,,,"  # blank: skipped, not counted
    lines[400] = " 1.5 , 2 ,3,4,5,6,7"  # padded: fine
    path = tmp_path / "imu.csv"
    path.write_text("\n".join(lines) + "\n")
    assert_same_read(path)
    warnings: list[str] = []
    columns = _read_columns(path, warnings)
    assert warnings == ["imu.csv: dropped 2 malformed row(s)"]
    assert len(columns["time"]) == n - 3


def test_reader_header_only_and_bad_encoding_are_input_errors(tmp_path):
    path = tmp_path / "imu.csv"
    path.write_text("time,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z\n")
    with pytest.raises(InputError, match="no data rows"):
        read_imu_csv(path)
    path.write_bytes(b"time,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z\n0,1,2,3,4,5,\xff\xfe\n")
    with pytest.raises(InputError, match=r"imu\.csv"):
        read_imu_csv(path)


# --- writer --------------------------------------------------------------------------------


FORMATS = ["%.6f", "%.9f", "%.4f", "%.4e"]
SPECIAL = np.array(
    [0.0, -0.0, 0.5, 1.5, 2.5, -2.5, 0.125, 0.00005, -0.00005, 1e-5, 0.99995, 9.99995e-5,
     1e15, -1e15, 1e17, 9.2e18, 1e300, 5e-324, 1e-300, np.nan, -np.nan, np.inf, -np.inf,
     1.7e9 + 0.0000005, 123456.0000005, 2.0**53, 2.0**53 + 2, 0.1, 1e22, 1e23]
)  # fmt: skip


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_format_columns_equals_python_percent_formatting(fmt, seed):
    rng = np.random.default_rng(seed)
    scale = 10.0 ** rng.integers(-12, 16, size=4000)
    values = np.concatenate([rng.normal(size=4000) * scale, SPECIAL, -SPECIAL])
    # Exact ties of the format's last digit, and their neighbours (round-half-even cases).
    digits = int(fmt[2])
    ties = (rng.integers(-10**6, 10**6, size=500) + 0.5) / 10.0**digits
    values = np.concatenate([values, ties, np.nextafter(ties, np.inf), np.nextafter(ties, -np.inf)])
    got = format_columns(values[:, None], [fmt])
    assert got == [fmt % v for v in values]


def _trajectory(n: int, seed: int) -> Trajectory:
    rng = np.random.default_rng(seed)
    t = 1.7e9 + np.cumsum(rng.uniform(0.004, 0.006, n)) if seed % 2 else np.arange(n) * 0.01
    angles = np.cumsum(rng.normal(scale=0.01, size=(n, 3)), axis=0)
    cz, sz = np.cos(angles[:, 2]), np.sin(angles[:, 2])
    rotation = np.zeros((n, 3, 3))
    rotation[:, 0, 0], rotation[:, 0, 1], rotation[:, 1, 0], rotation[:, 1, 1] = cz, -sz, sz, cz
    rotation[:, 2, 2] = 1.0
    cov = np.zeros((n, 3, 3))
    cov[:, [0, 1, 2], [0, 1, 2]] = rng.uniform(0.01, 4.0, size=(n, 3))
    return Trajectory(
        t=t,
        position=np.cumsum(rng.normal(size=(n, 3)), axis=0) * 10,
        velocity=rng.normal(size=(n, 3)) * 20,
        rotation=rotation,
        origin=Origin(48.1 + seed, 11.5, 520.0),
        method="test",
        gyro_bias=rng.normal(size=(n, 3)) * 1e-4 if seed % 3 else None,
        accel_bias=rng.normal(size=(n, 3)) * 1e-2,
        position_cov=cov if seed != 2 else None,
    )


@pytest.mark.parametrize("seed", [1, 2, 3, 4])
def test_trajectory_csv_bytes_equal_savetxt(tmp_path, seed):
    """The writer's bytes equal np.savetxt's with the same formats (the old writer)."""
    trajectory = _trajectory(3000, seed)
    out = tmp_path / "traj.csv"
    write_trajectory_csv(trajectory, out)
    table = trajectory_table(trajectory)
    formats = ["%.6f", "%.9f", "%.9f"] + ["%.4f"] * (table.shape[1] - 3)
    formats[16:22] = ["%.4e"] * 6  # the biases; the attitude sigmas after them in %.4f
    reference = tmp_path / "ref.csv"
    np.savetxt(
        reference, table, delimiter=",", fmt=formats,
        header=",".join(COLUMNS + EXTRA_COLUMNS), comments="",
    )  # fmt: skip
    assert out.read_bytes() == reference.read_bytes()
    back = read_trajectory_csv(out, origin=trajectory.origin)
    assert np.allclose(back.position, trajectory.position, atol=1e-4, rtol=0)


@pytest.mark.parametrize(
    "cells",
    [
        ["nan", "-nan", "inf", "-inf"],
        ["Infinity", "NaN", "+inf", "1e400"],
        ["+1.5", "-0", "", "5."],
        ['"1.5"', '""', "1E5", "-.5"],
        ["4.9e-324", "2.2250738585072014e-308", "0.1000000000000000055511151231257827", "1_0"],
    ],
)
def test_reader_special_cells_on_the_fast_and_the_string_path(tmp_path, cells):
    """Files with only numbers (pyarrow's float parser) and with one odd cell (the string
    path) give Python's float bits, NaN signs included."""
    path = tmp_path / "t.csv"
    path.write_text("a,b,c,d\n" + ",".join(cells) + "\n1,2,3,4\n")
    assert_same_read(path)
    path.write_text("a,b,c,d\n" + ",".join(cells) + "\n1,2,3, 4\n")  # padded: string path
    assert_same_read(path)


def test_attitude_sigmas_are_written_after_the_biases(tmp_path):
    """std_roll_deg, std_pitch_deg, std_heading_deg: the navigation-frame attitude
    covariance about the body's forward axis, the horizontal axis across it and up (a
    user could not see how uncertain a hover's heading was). Body x east, then north."""
    from fgins.datatypes import Origin, Trajectory
    from fgins.geodesy import roll_pitch_heading_to_rotation

    sigma = np.radians([0.5, 1.0, 3.0])  # about east, north, up
    rotation = np.array([roll_pitch_heading_to_rotation(0.0, 0.0, h) for h in (90.0, 0.0)])
    trajectory = Trajectory(
        t=np.array([0.0, 1.0]), position=np.zeros((2, 3)), velocity=np.zeros((2, 3)),
        rotation=rotation, origin=Origin(45.0, 10.0, 100.0),
        attitude_cov=np.tile(np.diag(sigma**2), (2, 1, 1)),
    )  # fmt: skip
    out = tmp_path / "t.csv"
    write_trajectory_csv(trajectory, out)
    header = out.read_text().splitlines()[0].split(",")
    assert header[-3:] == ["std_roll_deg", "std_pitch_deg", "std_heading_deg"]
    values = np.loadtxt(out, delimiter=",", skiprows=1)[:, -3:]
    np.testing.assert_allclose(values[0], [0.5, 1.0, 3.0], atol=1e-4)  # forward = east
    np.testing.assert_allclose(values[1], [1.0, 0.5, 3.0], atol=1e-4)  # forward = north


@pytest.mark.parametrize("given", ["vel_east", "vel_north", "speed", "course"])
def test_one_horizontal_velocity_column_is_said_not_silently_unused(tmp_path, given):
    """A gnss.csv with vel_east but no vel_north was read, its velocity never used, and
    nothing said."""
    from fgins.io.csv_pair import read_gnss_csv

    rows = [f"{t},45.0,10.0,100.0,{1.5 * t}" for t in range(12)]
    (tmp_path / "gnss.csv").write_text(f"time,lat,lon,alt,{given}\n" + "\n".join(rows) + "\n")
    found: list[str] = []
    gnss = read_gnss_csv(tmp_path / "gnss.csv", found)
    assert len(found) == 1 and f"{given} without" in found[0], found
    assert not np.any(np.all(np.isfinite(gnss.velocity[:, :2]), axis=1))
