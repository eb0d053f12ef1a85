"""GNSS export round trips: gnss.csv via the csv module and numpy, GeoJSON via json, KML via
xml.etree; the reader side is independent of the writer."""

from __future__ import annotations

import csv
import itertools
import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from fgins.datatypes import GnssData, InputError
from fgins.io.gnss_export import GNSS_CSV_COLUMNS, write_gnss

KML_NS = {"k": "http://www.opengis.net/kml/2.2"}


def _sample_gnss() -> GnssData:
    rng = np.random.default_rng(7)
    n = 6
    lla = np.column_stack(
        [45.0 + rng.normal(0, 1e-3, n), -122.0 + rng.normal(0, 1e-3, n), rng.normal(100, 5, n)]
    )
    lla[2, 2] = np.nan  # a 2D fix
    velocity = rng.normal(0, 3, (n, 3))
    velocity[:, 2] = np.nan
    std = np.abs(rng.normal(1, 0.2, (n, 3)))
    std[4] = np.nan
    return GnssData(
        t=1.6e9 + np.arange(n) * 0.2 + 1 / 3,
        lla=lla,
        velocity=velocity,
        std=std,
        hdop=np.array([0.9, 1.1, np.nan, 1.3, 2.0, 0.8]),
        vdop=rng.uniform(1, 2, n),
        pdop=rng.uniform(1, 3, n),
        fix_quality=np.array([1, 2, 4, 5, 1, 1]),
        num_sats=np.array([7, 8, np.nan, 9, 10, 11]),
        speed=np.hypot(velocity[:, 0], velocity[:, 1]),
        course=np.degrees(np.arctan2(velocity[:, 0], velocity[:, 1])) % 360,
    )


def _expected(gnss: GnssData) -> np.ndarray:
    sats = np.where(gnss.num_sats >= 0, gnss.num_sats, np.nan)
    return np.column_stack(
        [gnss.t, gnss.lla, gnss.velocity, gnss.std, gnss.hdop, gnss.vdop, gnss.pdop,
         gnss.fix_quality, sats, gnss.speed, gnss.course]
    )  # fmt: skip


def test_csv_round_trip_exact(tmp_path: Path) -> None:
    gnss = _sample_gnss()
    path = write_gnss(gnss, tmp_path / "gnss.csv")
    with path.open(newline="") as handle:
        rows = list(csv.reader(handle))
    assert tuple(rows[0]) == GNSS_CSV_COLUMNS
    assert rows[3][3] == "" and rows[3][13] == "4" and rows[3][14] == ""  # NaN -> empty cell
    loaded = np.genfromtxt(
        path, delimiter=",", skip_header=1, missing_values="", filling_values=np.nan
    )
    np.testing.assert_array_equal(np.isnan(loaded), np.isnan(_expected(gnss)))
    np.testing.assert_array_equal(np.nan_to_num(loaded), np.nan_to_num(_expected(gnss)))
    assert not list(tmp_path.glob(".*.part"))  # written atomically, no leftovers


def test_geojson_parses_with_track_and_points(tmp_path: Path) -> None:
    gnss = _sample_gnss()
    document = json.loads(write_gnss(gnss, tmp_path / "fixes.geojson").read_text())
    assert document["type"] == "FeatureCollection"
    line, *points = document["features"]
    assert line["geometry"]["type"] == "LineString"
    assert len(line["geometry"]["coordinates"]) == len(points) == len(gnss)
    for i, point in enumerate(points):
        lon, lat, *alt = point["geometry"]["coordinates"]
        assert (lat, lon) == (gnss.lla[i, 0], gnss.lla[i, 1])  # GeoJSON order is lon, lat
        assert alt == ([] if math.isnan(gnss.lla[i, 2]) else [gnss.lla[i, 2]])
        assert point["properties"]["time"] == gnss.t[i]
        assert point["properties"]["fix_quality"] == gnss.fix_quality[i]
    assert points[2]["properties"]["hdop"] is None and points[2]["properties"]["num_sats"] is None


def test_kml_parses_with_track_and_points(tmp_path: Path) -> None:
    gnss = _sample_gnss()
    root = ET.parse(write_gnss(gnss, tmp_path / "fixes.kml")).getroot()
    line = root.find(".//k:LineString/k:coordinates", KML_NS)
    assert line is not None and len(line.text.split()) == len(gnss)
    points = root.findall(".//k:Point/k:coordinates", KML_NS)
    assert len(points) == len(gnss)
    for i, point in enumerate(points):
        values = [float(v) for v in point.text.split(",")]
        lon, lat = values[:2]
        assert (lat, lon) == (gnss.lla[i, 0], gnss.lla[i, 1])
        # A 2-D fix has no height in the KML (not 0 m), others their own.
        assert values[2:] == ([] if math.isnan(gnss.lla[i, 2]) else [gnss.lla[i, 2]])
    times = [
        float(d.find("k:value", KML_NS).text)
        for d in root.iterfind(".//k:Data[@name='time']", KML_NS)
    ]
    np.testing.assert_array_equal(times, gnss.t)


def test_unknown_suffix_is_input_error(tmp_path: Path) -> None:
    with pytest.raises(InputError, match=r"\.gpx"):
        write_gnss(_sample_gnss(), tmp_path / "fixes.gpx")
    assert not any(tmp_path.iterdir())


def test_real_logs_whose_first_fix_is_2d_export_every_fix(shared, tmp_path: Path, capsys) -> None:
    """garmin38 (a 2-D first fix, then 3-D) and ait250 (RMC only: no height at all): the TUM
    reference took the first fix's missing height as its origin's and wrote every row NaN at
    exit 0 (12 of gpsd's 59 convertible logs); the KML drew 2-D fixes at 0 m "absolute"
    between fixes 5-6 m up (outside tester). Now the TUM rows are finite with the heights
    fgins smooth gives (said), and a KML 2-D fix has no height and lies on the ground."""
    from fgins.cli import main
    from fgins.io.nmea import read_nmea
    from fgins.io.trajectory_tum import read_tum

    for name in ("garmin38.log", "ait250.log"):
        log = shared / "data" / "nmea" / "gpsd" / name
        fixes = read_nmea(log).gnss
        flat = ~np.isfinite(fixes.lla[:, 2])
        assert flat[0], name  # the case: the first fix has no height
        tum = tmp_path / f"{name}.tum"
        assert main(["convert", str(log), "-o", str(tum)]) == 0
        err = capsys.readouterr().err
        rows = read_tum(tum)
        assert len(rows) == len(fixes) and np.all(np.isfinite(rows)), name
        assert "without a height" in err and "(in the TUM reference as in fgins smooth)" in err
        if not flat.all():  # 3-D fixes keep their own heights, about the filled origin's
            origin_height = float(np.interp(fixes.t[0], fixes.t[~flat], fixes.lla[~flat, 2]))
            up = rows[~flat, 3]
            assert np.allclose(up, fixes.lla[~flat, 2] - origin_height, atol=0.05), name
        root = ET.parse(write_gnss(fixes, tmp_path / f"{name}.kml")).getroot()
        points = root.findall(".//k:Point", KML_NS)
        for i, point in enumerate(points):
            values = point.find("k:coordinates", KML_NS).text.split(",")
            mode = point.find("k:altitudeMode", KML_NS).text
            assert (len(values), mode) == ((2, "clampToGround") if flat[i] else (3, "absolute"))


@pytest.mark.parametrize("east", [True, False])
def test_a_track_across_the_antimeridian_is_split_there(tmp_path: Path, east: bool) -> None:
    """A track from 179.99 E to 179.99 W was one LineString whose segment jumps 360 deg:
    map viewers drew it round the world (outside tester). RFC 7946 (3.1.9) splits it at the
    antimeridian: a MultiLineString whose pieces end and begin at +-180 at the latitude the
    track crosses it; KML likewise (a MultiGeometry). Fixes stay where they are."""
    from dataclasses import replace

    gnss = _sample_gnss()
    lon = np.array([179.998, 179.999, -179.9995, -179.999, -179.998, -179.997])
    lat = 10.0 + 0.001 * np.arange(6)
    if not east:
        lon, lat = -lon[::-1], lat
    lla = np.column_stack([lat, lon, np.full(6, 50.0)])
    crossed = replace(gnss, lla=lla)
    document = json.loads(write_gnss(crossed, tmp_path / "fixes.geojson").read_text())
    line, *points = document["features"]
    assert line["geometry"]["type"] == "MultiLineString"
    first, second = line["geometry"]["coordinates"]
    edge = 180.0 if lon[0] > 0 else -180.0
    assert first[-1][0] == edge and second[0][0] == -edge
    k = len(first) - 1  # fixes before the crossing
    assert first[-1][1] == second[0][1] and lat[k - 1] < first[-1][1] < lat[k]
    assert all(abs(b[0] - a[0]) < 1.0 for piece in (first, second) for a, b in itertools.pairwise(piece))
    assert [p["geometry"]["coordinates"][0] for p in points] == lon.tolist()
    root = ET.parse(write_gnss(crossed, tmp_path / "fixes.kml")).getroot()
    assert len(root.findall(".//k:MultiGeometry/k:LineString", KML_NS)) == 2
    # A track that stays on one side is one LineString, as before.
    assert json.loads(write_gnss(gnss, tmp_path / "plain.geojson").read_text())["features"][0]["geometry"]["type"] == "LineString"
