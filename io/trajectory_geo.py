"""Trajectory as GeoJSON or KML (for map viewers), decimated to at most ~10 points/s."""

from __future__ import annotations

import json
from pathlib import Path
from xml.sax.saxutils import escape

import numpy as np

from fgins.datatypes import FginsError, Trajectory
from fgins.geodesy import enu_to_lla
from fgins.io.atomic import atomic_path


def _decimated_lla(
    trajectory: Trajectory, max_rate_hz: float = 10.0
) -> tuple[np.ndarray, np.ndarray]:
    step = max(
        1,
        round(len(trajectory) / max(1.0, (trajectory.t[-1] - trajectory.t[0]) * max_rate_hz)),
    )
    index = np.unique(np.append(np.arange(0, len(trajectory), step), len(trajectory) - 1))
    return trajectory.t[index], enu_to_lla(trajectory.position[index], trajectory.origin)


def split_at_antimeridian(points: list[list[float]]) -> list[list[list[float]]]:
    """A track's [lon, lat(, alt)] points as pieces that never cross the antimeridian: where
    consecutive points lie more than 180 deg of longitude apart, the piece ends at +-180 and
    the next begins at -+180, latitude (and height) interpolated there (RFC 7946, 3.1.9: a
    LineString jumping from 179.9 to -179.9 is drawn round the world by map viewers)."""
    pieces: list[list[list[float]]] = [[]]
    for point in points:
        piece = pieces[-1]
        if piece and abs(point[0] - piece[-1][0]) > 180.0:
            last = piece[-1]
            edge = 180.0 if last[0] > 0 else -180.0
            unwrapped = point[0] + (360.0 if edge > 0 else -360.0)
            share = (edge - last[0]) / (unwrapped - last[0]) if unwrapped != last[0] else 0.0
            middle = [a + share * (b - a) for a, b in zip(last[1:], point[1:], strict=False)]
            piece.append([edge, *middle])
            pieces.append([[-edge, *middle]])
        pieces[-1].append(point)
    return pieces


def line_geometry(points: list[list[float]]) -> dict[str, object]:
    """GeoJSON geometry of a track: a LineString, or a MultiLineString split at the
    antimeridian (:func:`split_at_antimeridian`)."""
    pieces = split_at_antimeridian(points)
    if len(pieces) == 1:
        return {"type": "LineString", "coordinates": pieces[0]}
    return {"type": "MultiLineString", "coordinates": pieces}


def kml_lines(pieces: list[str], altitude_mode: str) -> str:
    """KML geometry of a track's pieces (each "lon,lat,alt ..." text): one LineString, or a
    MultiGeometry of them where the track crosses the antimeridian."""
    lines = "".join(
        f"<LineString><altitudeMode>{altitude_mode}</altitudeMode><coordinates>{piece}</coordinates></LineString>"
        for piece in pieces
    )
    return lines if len(pieces) == 1 else f"<MultiGeometry>{lines}</MultiGeometry>"


# KML's "absolute" altitudes are above sea level; fgins's are above the WGS84 ellipsoid (what
# GNSS gives and GeoJSON assumes), and no geoid model ships with it: said in the file, not
# silently drawn tens of metres off.
KML_HEIGHTS = (
    "Heights are WGS84 ellipsoidal (m), as fgins outputs them; KML's absolute mode takes them as "
    "above mean sea level, so a viewer draws the track off by the local geoid height "
    "(-107 to +85 m; e.g. +47 m in central Europe)."
)


def write_trajectory_geo(trajectory: Trajectory, path: str | Path) -> None:
    path = Path(path)
    t, lla = _decimated_lla(trajectory)
    if path.suffix.lower() == ".geojson":
        feature = {
            "type": "Feature",
            "geometry": line_geometry([[lo, la, h] for la, lo, h in lla.tolist()]),
            "properties": {
                "method": trajectory.method,
                "t_start": float(t[0]),
                "t_end": float(t[-1]),
            },
        }
        text = json.dumps({"type": "FeatureCollection", "features": [feature]})
    elif path.suffix.lower() == ".kml":
        pieces = split_at_antimeridian([[lo, la, h] for la, lo, h in lla.tolist()])
        coordinates = [" ".join(f"{lo:.9f},{la:.9f},{h:.3f}" for lo, la, h in piece) for piece in pieces]
        text = (
            '<?xml version="1.0" encoding="UTF-8"?>\n'
            '<kml xmlns="http://www.opengis.net/kml/2.2"><Document>'
            f"<name>{escape(trajectory.method)}</name><Placemark><name>trajectory</name>"
            f"<description>{KML_HEIGHTS}</description>"
            f"{kml_lines(coordinates, 'absolute')}</Placemark></Document></kml>\n"
        )
    else:
        raise FginsError(f"{path}: expected .geojson or .kml")
    with atomic_path(path) as tmp:
        tmp.write_text(text)
