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
            "geometry": {
                "type": "LineString",
                "coordinates": [[lo, la, h] for la, lo, h in lla.tolist()],
            },
            "properties": {
                "method": trajectory.method,
                "t_start": float(t[0]),
                "t_end": float(t[-1]),
            },
        }
        text = json.dumps({"type": "FeatureCollection", "features": [feature]})
    elif path.suffix.lower() == ".kml":
        coordinates = " ".join(f"{lo:.9f},{la:.9f},{h:.3f}" for la, lo, h in lla.tolist())
        text = (
            '<?xml version="1.0" encoding="UTF-8"?>\n'
            '<kml xmlns="http://www.opengis.net/kml/2.2"><Document>'
            f"<name>{escape(trajectory.method)}</name><Placemark><name>trajectory</name>"
            f"<description>{KML_HEIGHTS}</description>"
            "<LineString><altitudeMode>absolute</altitudeMode>"
            f"<coordinates>{coordinates}</coordinates></LineString></Placemark></Document></kml>\n"
        )
    else:
        raise FginsError(f"{path}: expected .geojson or .kml")
    with atomic_path(path) as tmp:
        tmp.write_text(text)
