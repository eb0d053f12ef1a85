"""An independent car simulator for tests: written from scratch, shares no code with fgins.sim.

ENU axes at the origin (an Earth-fixed Cartesian frame), normal gravity where the car is (a
round Earth: :mod:`round_earth`, through pymap3d), Earth rate on. The trajectory is analytic in speed, heading and flight-path
angle (smooth steps and turns), integrated on a 1 ms grid. IMU samples are the
*instantaneous* body rate and specific force at each (possibly jittered) timestamp, from
4th-order central differences:

    gyro  = vee(R^T dR/dt) + R^T w_ie,    accel = R^T (a - g(p) + 2 w_ie x v)

with turn-on biases, random-walk biases and white noise; GNSS fixes are positions with white
noise and their sigmas in ``std_*``. It found a batch solve that crawled for minutes (Cholesky
on an ill-conditioned system), which fgins's own simulator never produced.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pymap3d
import round_earth

EARTH_RATE = 7.292115e-5
STEP_S = 1e-3  # differentiation step
DEG = np.pi / 180

# datasheet grades: gyro ARW deg/sqrt(h), instability deg/h, turn-on deg/h; accel VRW
# m/s/sqrt(h), instability mg, turn-on mg
INDUSTRIAL = dict(preset="industrial-mems", gyro_arw=0.15, gyro_bi=2.0, gyro_on=180.0,
                  accel_vrw=0.05, accel_bi=0.03, accel_on=3.0)  # fmt: skip


def _d1(f, t):
    h = STEP_S
    return (-f(t + 2 * h) + 8 * f(t + h) - 8 * f(t - h) + f(t - 2 * h)) / (12 * h)


def _smooth_step(u):
    u = np.clip(u, 0, 1)
    return u**3 * (10 - 15 * u + 6 * u * u)


def _smooth_step_integral(u):
    u = np.asarray(u, float)
    uc = np.clip(u, 0, 1)
    return np.where(u > 1, u - 0.5, uc**6 - 3 * uc**5 + 2.5 * uc**4)


def _ramp(t, start, tau):
    return _smooth_step((t - start) / tau)


def _plateau_integral(t, start, end, tau):
    return tau * (_smooth_step_integral((t - start) / tau) - _smooth_step_integral((t - end) / tau))


def _frame(x, z_hint):
    """FLU body axes as columns: x given, z = z_hint orthogonalised."""
    x = x / np.linalg.norm(x, axis=-1, keepdims=True)
    z = z_hint - np.sum(z_hint * x, axis=-1, keepdims=True) * x
    z = z / np.linalg.norm(z, axis=-1, keepdims=True)
    return np.stack([x, np.cross(z, x), z], axis=-1)


def _vee_of_skew(m):
    return 0.5 * np.stack(
        [m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1
    )


class CarProfile:
    """Speed steps [(start, tau, dv)], turns [(start, end, tau, yaw rate)], road grade
    angle gamma(t); the car's body is level across (no roll), pitched with the road."""

    def __init__(self, steps, turns, gamma, heading0_deg: float = 30.0):
        self.steps, self.turns, self.gamma = steps, turns, gamma
        self.psi0 = np.radians(heading0_deg)

    def speed(self, t):
        v = 0.0 * np.asarray(t, float)
        for start, tau, dv in self.steps:
            v = v + dv * _ramp(t, start, tau)
        return v

    def _yaw(self, t):  # counter-clockwise from east
        p = self.psi0 + 0.0 * np.asarray(t, float)
        for start, end, tau, rate in self.turns:
            p = p + rate * _plateau_integral(t, start, end, tau)
        return p

    def forward(self, t):
        g, p = self.gamma(t), self._yaw(t)
        return np.stack([np.cos(g) * np.cos(p), np.cos(g) * np.sin(p), np.sin(g)], -1)

    def velocity(self, t):
        return self.speed(t)[..., None] * self.forward(t)

    def build(self, t0, t1, dt=1e-3):
        grid = np.arange(t0 - 1, t1 + 1 + dt / 2, dt)
        v, v_mid = self.velocity(grid), self.velocity(grid[:-1] + dt / 2)
        p = np.vstack([np.zeros(3), np.cumsum(dt / 6 * (v[:-1] + 4 * v_mid + v[1:]), 0)])
        self._grid = (grid, p - p[np.argmin(np.abs(grid))])

    def position(self, t):  # cubic Hermite on the integration grid
        grid, p = self._grid
        t = np.asarray(t, float)
        i = np.clip(np.searchsorted(grid, t) - 1, 0, len(grid) - 2)
        h = grid[i + 1] - grid[i]
        s = ((t - grid[i]) / h)[..., None]
        v0, v1 = self.velocity(grid[i]), self.velocity(grid[i + 1])
        return ((2 * s**3 - 3 * s**2 + 1) * p[i] + (s**3 - 2 * s**2 + s) * h[..., None] * v0
                + (-2 * s**3 + 3 * s**2) * p[i + 1] + (s**3 - s**2) * h[..., None] * v1)  # fmt: skip

    def rotation(self, t):
        x = self.forward(t)
        up = np.zeros_like(x)
        up[..., 2] = 1.0
        return _frame(x, up)


def hilly_drive() -> CarProfile:
    """At rest for 10 s, then 15 m/s over +-8 % grades with four turns."""

    def gamma(t):
        return np.arctan(0.08 * np.sin(2 * np.pi * (t - 20) / 70) * _ramp(t, 20, 5))

    turns = [(40, 50, 4, 0.12), (115, 130, 4, 0.09), (170, 180, 4, -0.12), (220, 232, 4, -0.1)]
    return CarProfile(steps=[(10, 10, 15.0)], turns=turns, gamma=gamma)


def write_drive(folder: Path, profile: CarProfile, duration_s: float, *, grade: dict,
                imu_rate: float, jitter: float, gnss_rate: float, seed: int,
                lat0: float = 45.0, lon0: float = 10.0, alt0: float = 100.0,
                sigma_h: float = 1.0, sigma_u: float = 1.5,
                lever_arm: tuple[float, float, float] = (0.0, 0.0, 0.0),
                gnss_t0: float = 0.0,
                imu_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:  # fmt: skip
    """imu.csv, gnss.csv, truth.csv and cfg.toml of ``profile`` in ``folder``; the fixes
    are those of an antenna ``lever_arm`` (body axes) from the IMU (cfg.toml leaves it out),
    the first at ``gnss_t0`` (off the IMU's sample grid when not a multiple of its period).
    The profile moves the car's non-slip point (its velocity along the body's x); the IMU
    sits ``imu_offset`` (body axes) from it, and truth.csv is the IMU's."""
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    w_ie = EARTH_RATE * np.array([0, np.cos(np.radians(lat0)), np.sin(np.radians(lat0))])
    profile.build(0.0, duration_s)
    n = round(duration_s * imu_rate) + 1
    t = np.arange(n) / imu_rate
    if jitter:
        t = t + rng.uniform(-jitter, jitter, n) / imu_rate
        t[0] = 0.0
    if any(imu_offset):
        offset = np.asarray(imu_offset, float)

        def imu_position(u):
            return profile.position(u) + profile.rotation(u) @ offset

        def imu_velocity(u):
            return _d1(imu_position, u)

        p, v, a = imu_position(t), imu_velocity(t), _d1(imu_velocity, t)
    else:
        imu_position = profile.position
        p, v = profile.position(t), profile.velocity(t)
        a = _d1(profile.velocity, t)
    rot, rot_dot = profile.rotation(t), _d1(profile.rotation, t)
    gyro = _vee_of_skew(np.einsum("nji,njk->nik", rot, rot_dot)) + np.einsum("nji,j->ni", rot, w_ie)
    gravity = round_earth.gravity(p, lat0, lon0, alt0)
    accel = np.einsum("nji,nj->ni", rot, a - gravity + 2 * np.cross(w_ie, v))
    dt = np.diff(t, prepend=t[0])
    walk_g = grade["gyro_bi"] * DEG / 3600 / np.sqrt(600.0)
    walk_a = grade["accel_bi"] * 1e-3 * 9.80665 / np.sqrt(600.0)
    bias_g0 = rng.normal(0, grade["gyro_on"] * DEG / 3600, 3)
    bias_a0 = rng.normal(0, grade["accel_on"] * 1e-3 * 9.80665, 3)
    bias_g = bias_g0 + np.cumsum(rng.normal(0, 1, (n, 3)) * (walk_g * np.sqrt(dt))[:, None], 0)
    bias_a = bias_a0 + np.cumsum(rng.normal(0, 1, (n, 3)) * (walk_a * np.sqrt(dt))[:, None], 0)
    white_g = grade["gyro_arw"] * DEG / 60 * np.sqrt(imu_rate)
    white_a = grade["accel_vrw"] / 60 * np.sqrt(imu_rate)
    gyro = gyro + bias_g + rng.normal(0, white_g, gyro.shape)
    accel = accel + bias_a + rng.normal(0, white_a, accel.shape)
    np.savetxt(folder / "imu.csv", np.column_stack([t, gyro, accel]), delimiter=",",
               fmt="%.6f,%.10e,%.10e,%.10e,%.10e,%.10e,%.10e",
               header="time,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z", comments="")  # fmt: skip
    np.savetxt(folder / "truth.csv", np.column_stack([t, p, v]), delimiter=",", fmt="%.6f",
               header="time,east,north,up,vel_east,vel_north,vel_up", comments="")  # fmt: skip
    n_gnss = int(np.floor((duration_s - gnss_t0) * gnss_rate + 1e-9)) + 1
    t_gnss = gnss_t0 + np.arange(n_gnss) / gnss_rate
    antenna = imu_position(t_gnss) + profile.rotation(t_gnss) @ np.asarray(lever_arm, float)
    fixes = antenna + np.column_stack([
        rng.normal(0, sigma_h, n_gnss), rng.normal(0, sigma_h, n_gnss), rng.normal(0, sigma_u, n_gnss)
    ])  # fmt: skip
    lat, lon, alt = pymap3d.enu2geodetic(*fixes.T, lat0, lon0, alt0)
    table = np.column_stack([t_gnss, lat, lon, alt, np.tile([sigma_h, sigma_h, sigma_u], (n_gnss, 1))])
    np.savetxt(folder / "gnss.csv", table, delimiter=",", fmt="%.10f",
               header="time,lat,lon,alt,std_east,std_north,std_up", comments="")  # fmt: skip
    (folder / "cfg.toml").write_text(
        f'[imu]\npreset = "{grade["preset"]}"\n'
        f"gyro_arw_deg_per_sqrt_hr = {grade['gyro_arw']:g}\n"
        f"gyro_bias_instability_deg_per_hr = {grade['gyro_bi']:g}\n"
        f"gyro_turn_on_bias_deg_per_s = {grade['gyro_on'] / 3600:g}\n"
        f"accel_vrw_m_per_s_per_sqrt_hr = {grade['accel_vrw']:g}\n"
        f"accel_bias_instability_mg = {grade['accel_bi']:g}\n"
        f"accel_turn_on_bias_mg = {grade['accel_on']:g}\n"
    )


def move_fixes(folder: Path, times: list[float], offset_m, origin=(45.0, 10.0, 100.0)) -> None:
    """Move the fixes of ``folder/gnss.csv`` nearest each of ``times`` by ``offset_m`` (east,
    north[, up] metres), as multipath does; the file is rewritten in place."""
    import pandas as pd

    offset = np.zeros(3)
    offset[: len(offset_m)] = offset_m
    gnss = pd.read_csv(folder / "gnss.csv")
    for at in times:
        row = int(np.argmin(np.abs(gnss["time"].to_numpy() - at)))
        e, n, u = pymap3d.geodetic2enu(*gnss.loc[row, ["lat", "lon", "alt"]], *origin)
        moved = pymap3d.enu2geodetic(e + offset[0], n + offset[1], u + offset[2], *origin)
        gnss.loc[row, ["lat", "lon", "alt"]] = moved
    gnss.to_csv(folder / "gnss.csv", index=False, float_format="%.10f")


def write_rtk_drive(folder: Path, seed: int) -> None:
    """The five-turn car (200 s) with RTK fixes (1.5 cm / 2.5 cm at 1 Hz) and the receiver's
    velocities (2 cm/s noise), from the truth."""
    import pandas as pd

    profile = CarProfile(steps=[(0.0, 10.0, 12.0)], turns=FIVE_TURNS, gamma=lambda t: 0 * t)
    write_drive(folder, profile, 200.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                gnss_rate=1.0, seed=seed, sigma_h=0.015, sigma_u=0.025)  # fmt: skip
    truth, fixes = pd.read_csv(folder / "truth.csv"), pd.read_csv(folder / "gnss.csv")
    noise = np.random.default_rng(seed).normal(0.0, 0.02, (len(fixes), 3))
    for i, axis in enumerate(("east", "north", "up")):
        fixes[f"vel_{axis}"] = np.interp(fixes["time"], truth["time"], truth[f"vel_{axis}"]) + noise[:, i]
    fixes.to_csv(folder / "gnss.csv", index=False, float_format="%.10f")


def horizontal_errors(track, folder: Path, origin=(45.0, 10.0, 100.0)) -> tuple[np.ndarray, np.ndarray]:
    """Times and horizontal errors (m) of a fgins trajectory against ``folder/truth.csv``."""
    import pandas as pd

    truth = pd.read_csv(folder / "truth.csv")
    frame = track.to_dataframe()
    east, north, _ = pymap3d.geodetic2enu(frame["lat"], frame["lon"], frame["alt"], *origin)
    t = frame["time"].to_numpy()
    error = np.hypot(east - np.interp(t, truth["time"], truth["east"]),
                     north - np.interp(t, truth["time"], truth["north"]))  # fmt: skip
    return t, error


# Five quarter-ish turns, left and right, over a 280 s drive (start, end, ramp s, yaw rate).
FIVE_TURNS = [(40, 50, 3, 0.12), (90, 100, 3, -0.15), (130, 145, 3, 0.1),
              (180, 190, 3, -0.12), (230, 240, 3, 0.15)]  # fmt: skip


def add_vibration(folder: Path, white: float, seed: int) -> None:
    """Rewrite ``folder/imu.csv`` as read by an IMU that also picks up ``white`` m/s^2 of white
    noise per sample and a 1 m/s^2 engine vibration (20-26 Hz) on its accelerometers."""
    import pandas as pd

    imu = pd.read_csv(folder / "imu.csv")
    t = imu["time"].to_numpy()
    rate = 1.0 / float(np.median(np.diff(t)))
    rng = np.random.default_rng(seed + 100)
    phase = 2 * np.pi * np.cumsum(23.0 + 3 * np.sin(0.05 * t)) / rate
    for i, axis in enumerate("xyz"):
        imu[f"accel_{axis}"] += [0.5, 0.3, 1.0][i] * np.sin(phase + i)
        imu[f"accel_{axis}"] += white * rng.standard_normal(len(t))
    imu.to_csv(folder / "imu.csv", index=False, float_format="%.10e")


def scale_gyro(folder: Path, scale: float, axes: str = "xyz") -> None:
    """Rewrite ``folder/imu.csv`` as read by a gyro whose ``axes`` read ``1 + scale`` times."""
    import pandas as pd

    imu = pd.read_csv(folder / "imu.csv")
    for axis in axes:
        imu[f"gyro_{axis}"] *= 1.0 + scale
    imu.to_csv(folder / "imu.csv", index=False, float_format="%.10e")


def shift_fix_times(folder: Path, shift_s: float) -> None:
    """Rewrite ``folder/gnss.csv`` with each fix stamped ``shift_s`` late (a latency)."""
    import pandas as pd

    gnss = pd.read_csv(folder / "gnss.csv")
    gnss["time"] += shift_s
    gnss.to_csv(folder / "gnss.csv", index=False, float_format="%.10f")


def run_imu_clock_off(folder: Path, ppm: float) -> None:
    """Rewrite ``folder/imu.csv`` stamped by a clock running ``ppm`` parts per million fast
    (slow if negative) from the first sample on: an IMU's or a logger's own oscillator,
    while the fixes and ``truth.csv`` keep the receiver's (true) time."""
    import pandas as pd

    imu = pd.read_csv(folder / "imu.csv")
    start = imu["time"].iloc[0]
    imu["time"] = start + (imu["time"] - start) * (1.0 + ppm * 1e-6)
    imu.to_csv(folder / "imu.csv", index=False, float_format="%.10e")


def outage_rms_and_sigma(track, folder: Path, windows, origin=(45.0, 10.0, 100.0)) -> tuple[float, float]:
    """Horizontal RMS error inside ``windows`` against ``folder/truth.csv`` (east, north about
    ``origin``), and the RMS of the horizontal sigma the track reports there (their ratio: how
    honest the sigmas are)."""
    t, error = horizontal_errors(track, folder, origin)
    frame = track.to_dataframe()
    sigma = np.hypot(frame["std_east"], frame["std_north"]).to_numpy()
    inside = np.zeros(len(t), bool)
    for start, end in windows:
        inside |= (t >= start) & (t < end)
    return float(np.sqrt(np.mean(error[inside] ** 2))), float(np.sqrt(np.mean(sigma[inside] ** 2)))


def turn_imu_axes(folder: Path, turn: str) -> None:
    """Rewrite ``folder/imu.csv`` as read by an IMU mounted otherwise: ``"rfu"`` x right,
    y forward, z up; ``"backward"`` x back, y right, z up (from the FLU samples)."""
    import pandas as pd

    imu = pd.read_csv(folder / "imu.csv")
    for kind in ("gyro", "accel"):
        x, y = imu[f"{kind}_x"].copy(), imu[f"{kind}_y"].copy()
        imu[f"{kind}_x"], imu[f"{kind}_y"] = {"rfu": (-y, x), "backward": (-x, -y)}[turn]
    imu.to_csv(folder / "imu.csv", index=False, float_format="%.10e")

# Speed steps of a stop-and-go drive (FIVE_TURNS' companion): speed changes tell an antenna
# along the track from fixes stamped late, which one steady speed does not.
STOP_AND_GO = [(10, 8, 12.0), (70, 6, -8.0), (110, 5, 10.0), (160, 6, -12.0), (172, 6, 9.0)]


def write_turning_drive(folder: Path, steps, seed: int, shift_s: float = 0.0,
                        arm=(0.0, 0.0, 0.0), gnss_rate: float = 1.0, **fixes) -> None:  # fmt: skip
    """A 280 s drive through FIVE_TURNS at ``steps``' speeds (industrial IMU at 100 Hz,
    ``gnss_rate`` fixes, ``fixes``: their ``sigma_h``, ``sigma_u``), its antenna ``arm`` from
    the IMU (left out of cfg.toml) and its fixes stamped ``shift_s`` late."""
    profile = CarProfile(steps=steps, turns=FIVE_TURNS, gamma=lambda t: 0 * t)
    write_drive(folder, profile, 280.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                gnss_rate=gnss_rate, seed=seed, lever_arm=arm, **fixes)  # fmt: skip
    if shift_s:
        shift_fix_times(folder, shift_s)
