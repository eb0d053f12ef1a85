"""Land-vehicle constraints, barometer and robust GNSS against simulator truth."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from fgins.config import config_for_dataset
from fgins.datatypes import BaroData
from fgins.factors.gnss import position_sigmas
from fgins.geodesy import enu_to_lla
from fgins.graph.smoother import smooth
from fgins.outages import in_windows, outage_mask
from fgins.pipeline import run_method
from fgins.sim.scenarios import SCENARIOS


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values**2)))


def _errors(trajectory, truth):
    return trajectory.position - truth.at(trajectory.t)


@pytest.fixture(scope="module")
def loop():
    return SCENARIOS["uav-loop-baro"](seed=5, duration_s=180)


def test_nhc_shrinks_outage_error_on_a_car(loop):
    windows = [(60.0, 120.0)]
    mask = outage_mask(loop.dataset, windows)
    results = {}
    for vehicle in ("other", "car"):
        config = config_for_dataset(loop.dataset, vehicle=vehicle)
        # The simulated car does not slip: its constraint is as tight as one sample's.
        config.smoother.nhc_sigma_lateral_m_per_s = 0.1
        trajectory = smooth(loop.dataset, config, "batch", gnss_mask=mask, progress=False)
        inside = in_windows(trajectory.t, loop.dataset.t0, windows)
        results[vehicle] = _rms(np.linalg.norm(_errors(trajectory, loop.truth)[inside, :2], axis=1))
    assert results["car"] < 0.8 * results["other"]


def test_barometer_holds_height_in_an_outage(loop):
    windows = [(60.0, 120.0)]
    mask = outage_mask(loop.dataset, windows)
    # As on the UAV of the low-cost study: no land-vehicle constraint holds the vertical.
    config = config_for_dataset(loop.dataset, vehicle="uav")
    with_baro = smooth(loop.dataset, config, "batch", gnss_mask=mask, progress=False)
    without = smooth(
        replace(loop.dataset, baro=None), config, "batch", gnss_mask=mask, progress=False
    )
    inside = in_windows(with_baro.t, loop.dataset.t0, windows)
    up_with = _rms(_errors(with_baro, loop.truth)[inside, 2])
    up_without = _rms(_errors(without, loop.truth)[inside, 2])
    assert up_with < 0.7 * up_without


def test_zupt_at_stops_and_never_while_turning(loop):
    config = config_for_dataset(loop.dataset)
    trajectory = smooth(loop.dataset, config, "batch", progress=False)
    # The loop never stops: a steady turn is smooth but must not be taken for a stop.
    assert np.median(np.linalg.norm(trajectory.velocity[:, :2], axis=1)) > 2.5
    urban = SCENARIOS["car-urban"](seed=0, duration_s=120)
    result = smooth(urban.dataset, config_for_dataset(urban.dataset), "batch", progress=False)
    truth_speed = np.linalg.norm(urban.truth.velocity[:, :2], axis=1)
    stopped = truth_speed < 0.01
    assert stopped.any()
    assert np.max(np.linalg.norm(result.velocity[stopped, :2], axis=1)) < 0.1


def test_robust_kernel_survives_five_percent_jumps_and_lists_them():
    run = SCENARIOS["car-urban"](seed=4, duration_s=240)
    dataset = run.dataset
    rng = np.random.default_rng(1)
    enu = dataset.gnss_enu()
    jumped = rng.choice(len(enu), size=int(0.05 * len(enu)), replace=False)
    angle = rng.uniform(0, 2 * np.pi, len(jumped))
    size = rng.uniform(20, 100, len(jumped))
    enu[jumped, 0] += size * np.cos(angle)
    enu[jumped, 1] += size * np.sin(angle)
    corrupted = replace(dataset, gnss=replace(dataset.gnss, lla=enu_to_lla(enu, dataset.origin)))
    config = config_for_dataset(dataset)
    config.gnss.cauchy_k = 3.0
    clean = smooth(dataset, config, "batch", progress=False)
    dirty = smooth(corrupted, config, "batch", progress=False)
    clean_rms = _rms(np.linalg.norm(_errors(clean, run.truth)[:, :2], axis=1))
    dirty_rms = _rms(np.linalg.norm(_errors(dirty, run.truth)[:, :2], axis=1))
    assert dirty_rms < 1.2 * clean_rms
    rejected = set(np.round(dirty.info["gnss_rejected_times"], 6))
    # Every jump that stands out of its fix's own noise (> 6 sigma horizontally) is listed;
    # a 20 m jump on an urban fix with HDOP 8 is inside its error budget and harmless.
    sigma = np.hypot(*position_sigmas(dataset.gnss, config.gnss)[jumped, :2].T)
    visible = jumped[size > 6 * sigma]
    assert visible.size >= len(jumped) // 2
    assert set(np.round(dataset.gnss.t[visible], 6)) <= rejected
    assert len(rejected) <= len(jumped) + 3  # few good fixes thrown away


def test_wheel_speed_with_unknown_scale_bridges_an_outage(tmp_path):
    """A wheel-speed CSV with a 3 % scale error: the graph estimates the scale and the
    outage error drops against the same run without the odometer. Stops are left out of
    both runs (``use_zupt = false``): this drive's stops alone bring the outage from 1.32
    to 0.65 m, and the test is about what the wheel speed adds."""
    from fgins.cli import main
    from fgins.sim.writer import write_sim_dir

    run = SCENARIOS["car-urban"](seed=6, duration_s=200)
    folder = tmp_path / "drive"
    write_sim_dir(run, folder)
    windows = "60:120"
    no_stops = tmp_path / "no_stops.toml"
    no_stops.write_text("[smoother]\nuse_zupt = false\n")
    rows = np.searchsorted(run.truth.t, run.dataset.imu.t[::10])
    body_velocity = np.einsum("nji,nj->ni", run.truth.rotation[rows], run.truth.velocity[rows])
    rng = np.random.default_rng(0)
    wheel = 1.03 * body_velocity[:, 0] + rng.normal(0, 0.05, len(rows))
    results = {}
    for label in ("without", "with"):
        if label == "with":
            table = np.column_stack([run.truth.t[rows], wheel])
            np.savetxt(
                folder / "wheel.csv",
                table,
                delimiter=",",
                header="time,wheel_speed",
                comments="",
                fmt="%.6f",
            )
        out = tmp_path / f"{label}.csv"
        assert (
            main(
                [
                    "smooth",
                    str(folder),
                    "--vehicle",
                    "car",
                    "--gnss-outage",
                    windows,
                    "--config",
                    str(no_stops),
                    "-o",
                    str(out),
                ]
            )
            == 0
        )
        table = np.genfromtxt(out, delimiter=",", names=True)
        truth = run.truth.at(table["time"])
        inside = in_windows(table["time"], run.dataset.t0, [(60.0, 120.0)])
        error = np.hypot(table["east"] - truth[:, 0], table["north"] - truth[:, 1])[inside]
        results[label] = _rms(error)
    assert results["with"] < 0.85 * results["without"]
    from fgins.config import config_for_dataset as configure
    from fgins.io.csv_pair import read_csv_dataset

    dataset = read_csv_dataset([folder])
    estimate = smooth(dataset, configure(dataset, vehicle="car"), "batch", progress=False)
    assert estimate.info["odometer_scale_error"] == pytest.approx(0.03, abs=0.005)


@pytest.mark.parametrize("method", ["ekf", "ekf-rts"])
def test_a_filter_that_cannot_use_the_wheel_speed_says_so(method):
    """The Kalman baselines have no wheel-speed update: a wheel.csv they ignore is said."""
    from dataclasses import replace

    import fgins
    from fgins.datatypes import OdometerData

    run = SCENARIOS["car-urban"](seed=2, duration_s=40)
    t = run.dataset.imu.t[::10]
    # The car's own speed (a made-up one is refused by the input checks smooth() runs).
    velocity = np.column_stack([np.interp(t, run.truth.t, run.truth.velocity[:, i]) for i in range(3)])
    speed = np.linalg.norm(velocity, axis=1)
    dataset = replace(run.dataset, odometer=OdometerData(t=t, speed=speed))
    with pytest.warns(fgins.FginsWarning, match=f"{method} does not use the wheel speed"):
        fgins.smooth(dataset, method)
    track = fgins.smooth(run.dataset, method)
    assert not any("wheel" in w for w in track.summary().get("fit_warnings", []))


def _isa_pressure(height_m: np.ndarray) -> np.ndarray:
    """ICAO standard atmosphere (troposphere): 101325 Pa, 288.15 K, 6.5 K/km."""
    return 101325.0 * (1.0 - 0.0065 * height_m / 288.15) ** (9.80665 / (287.05287 * 0.0065))


@pytest.mark.parametrize("seed", [1, 3])
def test_a_barometer_far_from_the_origin_holds_the_height_through_a_turning_outage(seed):
    """The navigation frame's tangent plane falls d^2 / 2R below the surface (80 m 32 km
    out) while a barometer's height stays with it. The fall was taken from the fixes' chord
    across the 60 s outage, which cut the aircraft's turn by 1.6 km: 7 m of false fall, and
    the barometer made the vertical worse than none (seed 1: 1.48 m against 0.08 m; the
    forward EKF 4.5 m, the planar filter 76 m). Now each solver takes it at its own
    positions. The barometer is the ISA pressure of the true ellipsoidal height (pymap3d)."""
    import pymap3d

    run = SCENARIOS["aircraft-ekf"](seed=seed, duration_s=600)
    truth, origin = run.truth, run.dataset.origin
    t = truth.t[::10]  # a 10 Hz barometer, 0.5 m of white noise
    east, north, up = truth.position[::10].T
    height = pymap3d.enu2geodetic(east, north, up, origin.lat, origin.lon, origin.alt)[2]
    noise = np.random.default_rng(seed).normal(0.0, 0.5, len(t))
    baro = BaroData(t=t, pressure=_isa_pressure(height + noise))
    assert np.max(np.hypot(east, north)) > 25e3  # the plane falls > 50 m below the surface
    config = config_for_dataset(run.dataset)
    ((start, end),) = run.outages
    for method in ("batch", "ekf-rts"):
        up_rms = []
        for dataset in (replace(run.dataset, baro=baro), run.dataset):
            track = run_method(dataset, config, method, progress=False)
            inside = (track.t - dataset.t0 >= start) & (track.t - dataset.t0 < end)
            up_rms.append(_rms(_errors(track, truth)[inside, 2]))
        assert up_rms[0] <= up_rms[1] + 0.15, (method, up_rms)
    # The fall is each filter's prediction, not a handle on its horizontal position: through
    # its gradient (d / R) the planar filter read every height error as hundreds of metres
    # where its horizontal sigma is large (an outside tester's aircraft 35 km out: 1.6 km
    # inside a 100 s outage without the barometer, 27 km with it).
    # A barometer drifting 0.3 m/s through the outage (the cabin's or the weather's pressure)
    # moved the planar filter 0.8 km where it was 0.2 km off without a barometer.
    drifting = BaroData(t=t, pressure=_isa_pressure(height + noise + 0.3 * np.clip(t - run.dataset.t0 - start, 0, None)))
    horizontal = []
    for dataset in (replace(run.dataset, baro=drifting), run.dataset):
        track = run_method(dataset, config, "planar-kf", progress=False)
        inside = (track.t - dataset.t0 >= start) & (track.t - dataset.t0 < end)
        horizontal.append(_rms(np.linalg.norm(_errors(track, truth)[inside, :2], axis=1)))
    assert horizontal[0] <= 1.05 * horizontal[1] + 0.5, horizontal


@pytest.mark.parametrize("seed", [6, 7])
def test_a_wheel_that_slips_in_hard_turns_does_not_pull_the_track(tmp_path, seed):
    """A wheel reading 15 % fast while the car turns hard (the driven wheel slipping, here
    wherever the yaw rate exceeds 0.15 rad/s): its speeds pulled the batch 4.8 m off inside
    an outage where EKF+RTS, which takes no wheel, stayed at 0.8 m (an outside tester's
    drive, chi2/dof 3.86 and no warning). Down-weighted by the residuals (a Cauchy kernel in
    the outer loop), the slipping wheel does no worse than no wheel and about as well as a
    wheel without slip."""
    import fgins
    from fgins.sim.writer import write_sim_dir

    run = SCENARIOS["car-urban"](seed=seed, duration_s=200)
    folder = tmp_path / "drive"
    write_sim_dir(run, folder)
    rows = np.searchsorted(run.truth.t, run.dataset.imu.t[::10])
    body_velocity = np.einsum("nji,nj->ni", run.truth.rotation[rows], run.truth.velocity[rows])
    yaw_rate = np.gradient(np.unwrap(np.arctan2(run.truth.velocity[rows, 1], run.truth.velocity[rows, 0])),
                           run.truth.t[rows])  # fmt: skip
    speed = body_velocity[:, 0] + np.random.default_rng(seed).normal(0, 0.05, len(rows))
    slipping = np.abs(yaw_rate) > 0.15
    assert 0.03 < slipping.mean() < 0.3
    windows = [(60.0, 120.0), (130.0, 170.0)]
    outage = [(run.dataset.t0 + a, run.dataset.t0 + b) for a, b in windows]
    errors, summary = {}, {}
    for label, wheel in (("none", None), ("true", speed), ("slips", np.where(slipping, 1.15 * speed, speed))):
        if wheel is not None:
            np.savetxt(folder / "wheel.csv", np.column_stack([run.truth.t[rows], wheel]), delimiter=",",
                       header="time,wheel_speed", comments="", fmt="%.6f")  # fmt: skip
        elif (folder / "wheel.csv").exists():
            (folder / "wheel.csv").unlink()
        track = fgins.smooth(fgins.load(folder, vehicle="car"), "batch", gnss_outage=outage)
        truth = run.truth.at(track.t)
        inside = in_windows(track.t, run.dataset.t0, windows)
        errors[label] = _rms(np.hypot(*(track.position[inside, :2] - truth[inside, :2]).T))
        summary[label] = track.summary()
    assert errors["slips"] < 1.1 * errors["none"] + 0.05 and errors["slips"] < 1.5 * errors["true"] + 0.1, errors
    # The summary says how many speeds the kernel kept out: most of the slipping ones (15 %
    # of a speed is 10-20 sigmas), hardly any of a wheel that does not slip.
    assert "wheel_speeds" not in summary["none"]
    kept_out = {label: summary[label]["wheel_downweighted"] / summary[label]["wheel_speeds"] for label in ("true", "slips")}
    assert kept_out["true"] < 0.02 and kept_out["slips"] > 0.5 * slipping.mean(), (kept_out, slipping.mean())
    assert "wheel speeds beyond 3 sigma" in summary["slips"]["wheel_weights"]


@pytest.mark.parametrize("scale", [1.07, 0.94])
def test_a_barometer_whose_scale_the_fixes_cannot_show_carries_it_in_its_sigmas(tmp_path, scale):
    """A pass road whose only climb (a 60 m hill) lies inside a 100 s tunnel, on a warm or
    cold day (the barometer's climbs 6-7 % off the standard atmosphere's): the fixes the run
    uses are level, so nothing can show the scale, and the heights came out metres off at
    sigmas of 0.3 m (outside tester: z 4-8, nothing said). The scale's uncertainty (5 %)
    now enters the vertical sigmas over the barometer's climb inside the stretch, said."""
    import sys
    from pathlib import Path

    import pandas as pd
    import pymap3d

    import fgins

    sys.path.insert(0, str(Path(__file__).parent))
    from independent_sim import INDUSTRIAL, CarProfile, write_drive

    def gamma(t):  # a 60 m hill between 110 and 190 s
        u = np.clip((np.asarray(t, float) - 110.0) / 80.0, 0.0, 1.0)
        return np.arctan(0.16 * np.sin(2 * np.pi * u) * ((u > 0) & (u < 1)))

    profile = CarProfile(steps=[(5, 8, 15.0)], turns=[(40, 50, 4, 0.12), (220, 230, 4, 0.09)], gamma=gamma)
    write_drive(tmp_path, profile, 300.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                gnss_rate=1.0, seed=2, sigma_h=1.5, sigma_u=3.0)  # fmt: skip
    truth = pd.read_csv(tmp_path / "truth.csv")
    rows = truth.iloc[::20]
    height = np.asarray(pymap3d.enu2geodetic(rows["east"], rows["north"], rows["up"], 45.0, 10.0, 100.0)[2])
    stretched = height[0] + scale * (height - height[0])
    pd.DataFrame({"time": rows["time"], "pressure_pa": _isa_pressure(stretched)}).to_csv(
        tmp_path / "baro.csv", index=False, float_format="%.4f"
    )
    dataset = fgins.load(tmp_path / "imu.csv", tmp_path / "gnss.csv", tmp_path / "baro.csv",
                         config=tmp_path / "cfg.toml", vehicle="car")  # fmt: skip
    track = fgins.smooth(dataset, "batch", gnss_outage=[(100.0, 200.0)])
    assert any(w.startswith("baro: the fixes this run uses climb too little") for w in track.info["fit_warnings"])
    frame = track.to_dataframe()
    _, _, up = pymap3d.geodetic2enu(frame["lat"], frame["lon"], frame["alt"], 45.0, 10.0, 100.0)
    t = frame["time"].to_numpy()
    inside = (t >= 100.0) & (t < 200.0)
    error = (np.asarray(up) - np.interp(t, truth["time"], truth["up"]))[inside]
    sigma = frame["std_up"].to_numpy()[inside]
    z = float(np.sqrt(np.mean(error**2) / np.mean(sigma**2)))
    assert z < 2.0, z
