"""gnss.csv ``speed``/``course`` columns (m/s, degrees clockwise from north) give the horizontal
velocity when there are no ``vel_*`` columns, as NMEA RMC does; wrong units are errors.

The gnss.csv files are written here as plain text from the simulator's truth-free fixes
(``fgins sim``), with speed and course computed from the simulated receiver's ENU velocity by
hand (hypot, atan2); the fit is scored against the simulator's truth.csv.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from fgins import cli
from fgins.datatypes import InputError
from fgins.io.csv_pair import read_gnss_csv
from fgins.io.inputs import load_dataset

DURATION_S = 60.0


@pytest.fixture(scope="module")
def drive(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("sim") / "drive"
    assert cli.main(["sim", "car-urban", "-o", str(folder), "--duration", str(DURATION_S)]) == 0
    return folder


def _rows(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as handle:
        return list(csv.DictReader(handle))


def _write_gnss(
    drive: Path, folder: Path, *, speed_scale: float = 1.0, course: str = "deg",
    speed_course: bool = True,
) -> Path:  # fmt: skip
    """A copy of the drive with gnss.csv rewritten: no vel_* columns, speed/course from the
    receiver's own velocity (or none)."""
    folder.mkdir(parents=True)
    for name in ("imu.csv", "config.toml"):
        (folder / name).write_bytes((drive / name).read_bytes())
    base = ["time", "lat", "lon", "alt", "std_east", "std_north", "std_up", "hdop", "pdop"]
    header = base + (["speed", "course"] if speed_course else [])
    lines = [",".join(header)]
    for row in _rows(drive / "gnss.csv"):
        east, north = float(row["vel_east"]), float(row["vel_north"])
        angle = math.atan2(east, north) % (2 * math.pi)  # clockwise from north
        cells = [row[name] for name in base]
        if speed_course:
            heading = {
                "deg": math.degrees(angle),
                "rad": angle,
                "reversed": math.degrees(angle) + 180,
            }
            cells += [
                f"{math.hypot(east, north) * speed_scale:.4f}",
                f"{heading[course] % 360:.3f}",
            ]
        lines.append(",".join(cells))
    (folder / "gnss.csv").write_text("\n".join(lines) + "\n")
    return folder


def test_speed_and_course_give_the_horizontal_velocity(tmp_path):
    path = tmp_path / "gnss.csv"
    path.write_text(
        "time,lat,lon,alt,speed,course\n"
        "0,48.1,11.5,500,10,0\n"
        "1,48.1,11.5,500,10,90\n"
        "2,48.1,11.5,500,4,225\n"
        "3,48.1,11.5,500,,\n"
    )
    gnss = read_gnss_csv(path)
    assert gnss.velocity is not None
    s = 4 / math.sqrt(2)
    expected = [[0, 10], [10, 0], [-s, -s], [math.nan, math.nan]]
    np.testing.assert_allclose(gnss.velocity[:, :2], expected, atol=1e-9)
    assert np.all(np.isnan(gnss.velocity[:, 2]))  # no vertical component from a course


def test_vel_columns_win_over_speed_and_course(tmp_path):
    path = tmp_path / "gnss.csv"
    path.write_text(
        "time,lat,lon,alt,vel_east,vel_north,vel_up,speed,course\n"
        "0,48.1,11.5,500,1,2,3,10,0\n"
        "1,48.1,11.5,500,,,,10,90\n"  # empty vel_* cells: speed and course fill in
    )
    gnss = read_gnss_csv(path)
    np.testing.assert_allclose(gnss.velocity[0], [1, 2, 3])
    np.testing.assert_allclose(gnss.velocity[1, :2], [10, 0], atol=1e-9)
    assert math.isnan(gnss.velocity[1, 2])


def test_empty_speed_and_course_columns_give_no_velocity(tmp_path):
    path = tmp_path / "gnss.csv"
    path.write_text("time,lat,lon,alt,speed,course\n0,48.1,11.5,500,,\n1,48.1,11.5,500,,\n")
    assert np.all(np.isnan(read_gnss_csv(path).velocity))


@pytest.mark.parametrize(
    ("change", "match"),
    [
        ({"speed_scale": 3.6}, r"speed over ground gives 3\.\d+ times the speed the fixes show.*m/s"),
        ({"course": "rad"}, r"course points \d+ deg away from the track.*radians\?"),
        ({"course": "reversed"}, r"course points 1[5-8]\d deg away from the track.*degrees"),
    ],
)
def test_speed_or_course_in_the_wrong_unit_is_an_error(tmp_path, drive, change, match):
    folder = _write_gnss(drive, tmp_path / "bad", **change)
    with pytest.raises(InputError, match=match):
        load_dataset([str(folder)])


def _batch_error(folder: Path, out: Path, truth: Path) -> float:
    assert (
        cli.main(["smooth", str(folder), "--method", "batch", "-o", str(out), "--no-progress"]) == 0
    )
    est, ref = _rows(out), _rows(truth)
    t = np.array([float(r["time"]) for r in est])
    tt = np.array([float(r["time"]) for r in ref])
    err = [
        np.array([float(r[axis]) for r in est])
        - np.interp(t, tt, [float(r[axis]) for r in ref])
        for axis in ("east", "north")
    ]  # fmt: skip
    return float(np.sqrt(np.mean(err[0] ** 2 + err[1] ** 2)))


def test_speed_and_course_improve_the_fit(tmp_path, drive):
    """The same fixes without any velocity, and with speed/course: the course-over-ground
    factors must change the batch fit, and for the better (same drive, same truth)."""
    plain = _write_gnss(drive, tmp_path / "plain", speed_course=False)
    with_course = _write_gnss(drive, tmp_path / "course")
    loaded = load_dataset([str(with_course)])
    assert loaded.gnss.velocity is not None and np.isfinite(loaded.gnss.velocity[:, :2]).all()
    truth = drive / "truth.csv"
    error_plain = _batch_error(plain, tmp_path / "plain.csv", truth)
    error_course = _batch_error(with_course, tmp_path / "course.csv", truth)
    assert error_course < 0.9 * error_plain, (error_plain, error_course)
