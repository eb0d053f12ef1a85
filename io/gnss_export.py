"""Write GNSS fixes as the canonical ``gnss.csv``, GeoJSON or KML (format from the suffix).

``gnss.csv`` follows DESIGN.md: ``time,lat,lon,alt`` then the optional columns; NaN is an empty
cell. GeoJSON is a FeatureCollection of one LineString (the track) and one Point per fix with
its properties; KML a LineString placemark plus one point placemark per fix. Every file is
written through :func:`fgins.io.atomic.atomic_path`.
"""

from __future__ import annotations

import csv
import json
import math
from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np

from fgins.datatypes import GnssData, InputError
from fgins.io.atomic import atomic_path
from fgins.io.trajectory_geo import KML_HEIGHTS, kml_lines, line_geometry, split_at_antimeridian

GNSS_CSV_COLUMNS = (
    "time",
    "lat",
    "lon",
    "alt",
    "vel_east",
    "vel_north",
    "vel_up",
    "std_east",
    "std_north",
    "std_up",
    "hdop",
    "vdop",
    "pdop",
    "fix_quality",
    "num_sats",
    "speed",
    "course",
)
_INTEGER_COLUMNS = ("fix_quality", "num_sats")


def gnss_columns(gnss: GnssData) -> dict[str, np.ndarray]:
    """The ``gnss.csv`` columns as float arrays (NaN where unknown; num_sats -1 -> NaN)."""
    sats = gnss.num_sats.astype(float)
    return {
        "time": gnss.t,
        "lat": gnss.lla[:, 0],
        "lon": gnss.lla[:, 1],
        "alt": gnss.lla[:, 2],
        "vel_east": gnss.velocity[:, 0],
        "vel_north": gnss.velocity[:, 1],
        "vel_up": gnss.velocity[:, 2],
        "std_east": gnss.std[:, 0],
        "std_north": gnss.std[:, 1],
        "std_up": gnss.std[:, 2],
        "hdop": gnss.hdop,
        "vdop": gnss.vdop,
        "pdop": gnss.pdop,
        "fix_quality": gnss.fix_quality.astype(float),
        "num_sats": np.where(sats >= 0, sats, np.nan),
        "speed": gnss.speed,
        "course": gnss.course,
    }


def _cell(name: str, value: float) -> str:
    if not math.isfinite(value):
        return ""
    if name in _INTEGER_COLUMNS:
        return str(int(value))
    return repr(float(value))  # shortest text that round-trips exactly


def _write_csv(gnss: GnssData, path: Path) -> None:
    columns = gnss_columns(gnss)
    with path.open("w", newline="", encoding="utf-8") as handle:
        writer = csv.writer(handle, lineterminator="\n")
        writer.writerow(GNSS_CSV_COLUMNS)
        table = np.column_stack([columns[name] for name in GNSS_CSV_COLUMNS])
        for row in table:
            writer.writerow(_cell(n, float(v)) for n, v in zip(GNSS_CSV_COLUMNS, row, strict=True))


def _properties(columns: dict[str, np.ndarray], i: int) -> dict[str, float | int | None]:
    props: dict[str, float | int | None] = {}
    for name in GNSS_CSV_COLUMNS:
        value = float(columns[name][i])
        if not math.isfinite(value):
            props[name] = None
        elif name in _INTEGER_COLUMNS:
            props[name] = int(value)
        else:
            props[name] = value
    return props


def _position(gnss: GnssData, i: int) -> list[float]:
    lat, lon, alt = (float(v) for v in gnss.lla[i])
    return [lon, lat, alt] if math.isfinite(alt) else [lon, lat]


def _write_geojson(gnss: GnssData, path: Path) -> None:
    columns = gnss_columns(gnss)
    features: list[dict[str, object]] = [
        {
            "type": "Feature",
            "geometry": line_geometry([_position(gnss, i) for i in range(len(gnss))]),
            "properties": {"name": "GNSS track", "fixes": len(gnss)},
        }
    ]
    features.extend(
        {
            "type": "Feature",
            "geometry": {"type": "Point", "coordinates": _position(gnss, i)},
            "properties": _properties(columns, i),
        }
        for i in range(len(gnss))
    )
    with path.open("w", encoding="utf-8") as handle:
        json.dump({"type": "FeatureCollection", "features": features}, handle, allow_nan=False)


def _kml_coordinates(gnss: GnssData, i: int) -> str:
    """KML's "lon,lat[,alt]": a fix without a height (2-D) has none (not 0 m)."""
    lat, lon, alt = (float(v) for v in gnss.lla[i])
    return f"{lon!r},{lat!r},{alt!r}" if math.isfinite(alt) else f"{lon!r},{lat!r}"


def _kml_altitude_mode(heights: np.ndarray) -> str:
    """Absolute heights where every fix has one; else on the ground (a 2-D fix written at
    0 m "absolute" was drawn at sea level between fixes 5-6 m up)."""
    return "absolute" if np.all(np.isfinite(heights)) else "clampToGround"


def _write_kml(gnss: GnssData, path: Path) -> None:
    columns = gnss_columns(gnss)
    # Split where the track crosses the antimeridian (the pieces' ends at +-180 are points
    # of the line, not fixes: they are written like the fixes' own coordinates).
    pieces = split_at_antimeridian([_position(gnss, i) for i in range(len(gnss))])
    track = [" ".join(",".join(repr(float(v)) for v in point) for point in piece) for piece in pieces]
    parts = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        '<kml xmlns="http://www.opengis.net/kml/2.2"><Document><name>GNSS fixes</name>',
        f"<Placemark><name>GNSS track</name><description>{KML_HEIGHTS}</description>"
        f"{kml_lines(track, _kml_altitude_mode(gnss.lla[:, 2]))}</Placemark>",
    ]
    for i in range(len(gnss)):
        data = "".join(
            f'<Data name="{name}"><value>{escape(_cell(name, float(columns[name][i])))}'
            "</value></Data>"
            for name in GNSS_CSV_COLUMNS
        )
        parts.append(
            f"<Placemark><name>{i}</name><ExtendedData>{data}</ExtendedData>"
            f"<Point><altitudeMode>{_kml_altitude_mode(gnss.lla[i : i + 1, 2])}</altitudeMode>"
            f"<coordinates>{_kml_coordinates(gnss, i)}</coordinates></Point></Placemark>"
        )
    parts.append("</Document></kml>")
    path.write_text("\n".join(parts) + "\n", encoding="utf-8")


_WRITERS = {".csv": _write_csv, ".geojson": _write_geojson, ".kml": _write_kml}


def write_gnss(gnss: GnssData, path: str | Path) -> Path:
    """Write ``gnss`` to ``path`` as CSV, GeoJSON or KML according to its suffix."""
    target = Path(path)
    writer = _WRITERS.get(target.suffix.lower())
    if writer is None:
        raise InputError(
            f"{target}: unknown GNSS output format {target.suffix!r}; "
            f"use one of {', '.join(sorted(_WRITERS))}"
        )
    with atomic_path(target) as tmp:
        writer(gnss, tmp)
    return target
