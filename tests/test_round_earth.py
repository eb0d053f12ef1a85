"""The navigation frame is an Earth-fixed Cartesian frame (the tangent plane at the origin),
exact when gravity is taken where the vehicle is and receivers' local-level velocities are
turned into it. Checked against pymap3d (tests/round_earth.py, independent of fgins.geodesy)
and by the property that matters: the answer does not depend on where the origin is."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pymap3d
import pytest

import fgins
from fgins.datatypes import Origin, Trajectory
from fgins.geodesy import (
    gravity_enu,
    normal_gravity,
    plane_fall,
    rotation_to_roll_pitch_heading,
    vectors_local_to_nav,
    vectors_nav_to_local,
)
from fgins.io.trajectory_csv import read_trajectory_csv, write_trajectory_csv

sys.path.insert(0, str(Path(__file__).parent))
import round_earth

ORIGINS = [Origin(0.0, 0.0, 0.0), Origin(47.4, 8.5, 432.0), Origin(-62.0, -58.0, 2500.0)]


@pytest.mark.parametrize("origin", ORIGINS, ids=["equator", "zurich", "antarctic"])
def test_gravity_is_normal_gravity_along_the_local_vertical(origin):
    rng = np.random.default_rng(3)
    points = np.column_stack(
        [rng.uniform(-80e3, 80e3, 50), rng.uniform(-80e3, 80e3, 50), rng.uniform(-500, 9e3, 50)]
    )
    expected = round_earth.gravity(points, origin.lat, origin.lon, origin.alt)
    assert np.abs(gravity_enu(points, origin) - expected).max() < 5e-6  # 0.5 ug
    at_origin = gravity_enu(np.zeros(3), origin)
    assert np.array_equal(at_origin, [0.0, 0.0, -normal_gravity(origin.lat, origin.alt)])
    # 10 km east: up leans east by the angle subtended at the Earth's centre.
    lean = -gravity_enu(np.array([10e3, 0.0, 0.0]), origin)
    assert abs(np.degrees(np.arctan2(lean[0], lean[2])) - np.degrees(10e3 / 6.37e6)) < 0.002


@pytest.mark.parametrize("origin", ORIGINS, ids=["equator", "zurich", "antarctic"])
@pytest.mark.parametrize("azimuth_deg", [0.0, 90.0, 35.0])
def test_the_tangent_plane_falls_below_the_surface_by_d_squared_over_2r(origin, azimuth_deg):
    """Closed form: the origin's tangent plane lies d^2 / 2r below the surface d away along
    an azimuth, r the normal section's radius of curvature (Euler: 1/r = cos^2(az)/M +
    sin^2(az)/N); the point is put at the origin's height, up = -d^2 / 2r."""
    a, e2 = 6378137.0, 6.69437999014e-3
    lat = np.radians(origin.lat)
    w = 1.0 - e2 * np.sin(lat) ** 2
    m, n = a * (1.0 - e2) / w**1.5, a / np.sqrt(w)
    az = np.radians(azimuth_deg)
    r = 1.0 / (np.cos(az) ** 2 / m + np.sin(az) ** 2 / n)
    d = np.array([1e3, 10e3, 30e3])
    enu = np.column_stack([d * np.sin(az), d * np.cos(az), -(d**2) / (2.0 * r)])  # on the surface
    np.testing.assert_allclose(plane_fall(enu, origin), d**2 / (2.0 * r), rtol=2e-3)


@pytest.mark.parametrize("origin", ORIGINS, ids=["equator", "zurich", "antarctic"])
def test_the_plane_fall_agrees_with_pymap3ds_ellipsoidal_heights(origin):
    """Against pymap3d's exact ENU -> geodetic conversion: within 2 mm 32 km out and 5 cm
    100 km out, at heights from -300 m to 10 km above the origin."""
    rng = np.random.default_rng(7)
    for distance, tolerance in ((1e3, 1e-6), (32e3, 2e-3), (100e3, 5e-2)):
        azimuth = rng.uniform(0.0, 2.0 * np.pi, 50)
        up = rng.uniform(-300.0, 10e3, 50)
        enu = np.column_stack([distance * np.sin(azimuth), distance * np.cos(azimuth), up])
        height = pymap3d.enu2geodetic(*enu.T, origin.lat, origin.lon, origin.alt)[2]
        np.testing.assert_allclose(
            plane_fall(enu, origin), height - origin.alt - up, atol=tolerance
        )


def test_local_level_vectors_turn_into_the_navigation_frame_and_back():
    origin = ORIGINS[1]
    rng = np.random.default_rng(5)
    enu = rng.uniform(-60e3, 60e3, (20, 3))
    lla = np.column_stack(pymap3d.enu2geodetic(*enu.T, origin.lat, origin.lon, origin.alt))
    vectors = rng.normal(0.0, 50.0, (20, 3))
    vectors[3, 2] = np.nan  # a receiver without vertical velocity
    nav = vectors_local_to_nav(lla, vectors, origin)
    axes = round_earth.local_axes(enu, origin.lat, origin.lon, origin.alt)
    finite = np.all(np.isfinite(vectors), axis=1)
    expected = np.einsum("nij,nj->ni", axes, vectors)
    assert np.abs(nav[finite] - expected[finite]).max() < 1e-9
    assert np.isnan(nav[3, 2]) and np.all(np.isfinite(nav[3, :2]))
    back = vectors_nav_to_local(lla, nav, origin)
    assert np.abs(back[finite] - vectors[finite]).max() < 1e-9


def test_the_trajectory_csv_gives_velocity_and_attitude_in_the_local_level(tmp_path):
    """50 km east of the origin the origin's north is 0.6 deg off the local one (meridian
    convergence at 47 deg: 0.49): a body facing local north, moving north, is written as heading 0
    and vel_east 0, and read back to the same navigation-frame state."""
    origin = ORIGINS[1]
    position = np.array([[0.0, 0.0, 0.0], [50e3, 0.0, -196.0]])
    axes = round_earth.local_axes(position, origin.lat, origin.lon, origin.alt)
    # Body x forward (north), y left (west), z up, in the local level; then into nav.
    body_local = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    rotation = axes @ body_local
    velocity = np.einsum("nij,j->ni", axes, [0.0, 30.0, 0.0])
    track = Trajectory(
        t=np.array([0.0, 1.0]), position=position, velocity=velocity, rotation=rotation,
        origin=origin,
    )  # fmt: skip
    assert abs(rotation_to_roll_pitch_heading(rotation)[1, 2] - 360.0) > 0.4  # nav: not north
    path = tmp_path / "track.csv"
    write_trajectory_csv(track, path)
    table = pd.read_csv(path)
    assert np.abs(((table["heading_deg"] + 180) % 360) - 180).max() < 1e-6
    assert np.abs(table[["vel_east", "vel_up"]].to_numpy()).max() < 1e-6
    assert np.allclose(table["vel_north"], 30.0)
    back = read_trajectory_csv(path, origin)
    assert np.abs(back.velocity - velocity).max() < 1e-6
    assert np.abs(back.rotation - rotation).max() < 1e-6


def _cut(source: Path, folder: Path, start_s: float, keep_origin: bool) -> Path:
    """The flight from ``start_s`` on, with the simulator's origin or (without it) the first
    fix's."""
    shutil.copytree(source, folder)
    for name in ("imu.csv", "gnss.csv"):
        table = pd.read_csv(source / name)
        table[table["time"] >= start_s].to_csv(folder / name, index=False)
    if not keep_origin:
        config = (folder / "config.toml").read_text()
        (folder / "config.toml").write_text(config.split("[origin]")[0])
    return folder


def _outage_rms(folder: Path, window: tuple[float, float], truth: pd.DataFrame):
    dataset = fgins.load(folder)
    t0 = dataset.t0
    track = fgins.smooth(dataset, "batch", gnss_outage=[(window[0] - t0, window[1] - t0)])
    origin = track.origin
    east, north, _ = pymap3d.geodetic2enu(
        truth["lat"], truth["lon"], truth["alt"], origin.lat, origin.lon, origin.alt
    )
    inside = (track.t >= window[0]) & (track.t < window[1])
    error = np.hypot(
        track.position[inside, 0] - np.interp(track.t[inside], truth["time"], east),
        track.position[inside, 1] - np.interp(track.t[inside], truth["time"], north),
    )
    return float(np.sqrt(np.mean(error**2))), dataset.origin


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_a_flight_gives_the_same_answer_whatever_its_origin(tmp_path):
    """The simulated aircraft from 240 s on (15 km from where it took off), a 45 s outage
    over its turn: smoothed about its own first fix and about the take-off point it agrees to
    within 5 % inside the outage (1.100 m both). With the origin's gravity everywhere and a
    flat-Earth simulator, the first-fix origin gave 5.86 m and the take-off origin an error."""
    source = fgins.simulate("aircraft-ekf", tmp_path / "flight", seed=2, duration=420.0)
    truth = pd.read_csv(source / "truth.csv")
    window = (300.0, 345.0)
    near, near_origin = _outage_rms(_cut(source, tmp_path / "near", 240.0, False), window, truth)
    far, far_origin = _outage_rms(_cut(source, tmp_path / "far", 240.0, True), window, truth)
    apart = np.hypot(
        *pymap3d.geodetic2enu(
            near_origin.lat, near_origin.lon, 0.0, far_origin.lat, far_origin.lon, 0.0
        )[:2]
    )
    assert apart > 10e3, apart
    assert near < 2.0 and far < 2.0, (near, far)
    assert abs(far - near) <= 0.05 * near + 0.02, (near, far)
