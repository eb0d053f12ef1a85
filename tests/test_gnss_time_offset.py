"""Fixes stamped late or early against the IMU, told apart from an unconfigured lever arm
(fgins.graph.reports.lever_arm_report) and corrected (fgins.pipeline).

An independent simulator's car; its GNSS file's times moved by a known offset (a receiver's
or logger's latency: NMEA over a serial line lags by 0.1-0.3 s), or its antenna put away
from the IMU without saying so. The joint estimate must find the offset that was put in,
the corrected run must bridge the outages as with true stamps, and an arm must be called an
arm where speed changes tell the two apart, and "cannot tell" where one steady speed does not.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import fgins

sys.path.insert(0, str(Path(__file__).parent))
from independent_sim import (
    STOP_AND_GO,
    horizontal_errors,
    outage_rms_and_sigma,
    run_imu_clock_off,
    shift_fix_times,
)
from independent_sim import write_turning_drive as _drive

OUTAGES = [(60.0, 105.0), (175.0, 215.0)]


def _smooth(folder: Path, method: str = "batch", extra: str = "", outages=OUTAGES):
    config = folder / "run.toml"
    config.write_text((folder / "cfg.toml").read_text() + extra)
    dataset = fgins.load(folder / "imu.csv", folder / "gnss.csv", config=config, vehicle="car")
    return fgins.smooth(dataset, method, gnss_outage=outages)


def _outage_rms(track, folder: Path) -> float:
    return outage_rms_and_sigma(track, folder, OUTAGES)[0]


@pytest.mark.parametrize(
    "shift, steps, seed, method",
    [(0.2, [(10, 8, 15.0)], 2, "batch"), (-0.3, STOP_AND_GO, 3, "batch"),
     (0.15, STOP_AND_GO, 4, "isam2")],
)  # fmt: skip
def test_fixes_stamped_late_or_early_are_found_and_corrected(tmp_path, shift, steps, seed, method):
    _drive(tmp_path, steps, seed)
    true_stamps = _outage_rms(_smooth(tmp_path, method), tmp_path)
    _drive(tmp_path, steps, seed, shift_s=shift)
    corrected = _smooth(tmp_path, method)
    said = [w for w in corrected.info["fit_warnings"] if w.startswith("GNSS time:")]
    assert len(said) == 1 and "corrected" in said[0], corrected.info["fit_warnings"]
    assert ("late" if shift > 0 else "early") in said[0]
    found = -corrected.info["gnss_time_offset_corrected_s"]
    # Within 2.5 of its sigmas (seed 3: -0.341 +- 0.020 s for -0.3, with the IMU's scale
    # errors estimated too; -0.323 +- 0.017 without).
    assert abs(found - shift) < 2.5 * corrected.info["gnss_time_offset_fit_sigma_s"], found
    assert _outage_rms(corrected, tmp_path) < 1.2 * true_stamps + 0.05
    kept = _smooth(tmp_path, method, "\n[gnss]\ntime_offset_from_data = false\n")
    named = [w for w in kept.info["fit_warnings"] if w.startswith("GNSS time:")]
    assert len(named) == 1 and f"--time-offset {-found:+.2f}"[:-1] in named[0], named
    assert "gnss_time_offset_corrected_s" not in kept.info
    assert _outage_rms(kept, tmp_path) > 2.0 * true_stamps
    # Kept as asked, the offset is in the output's sigmas and said (fixes 0.2 s late had
    # left the track 2-3 m off at z 6-8: outside tester).
    assert "kept as stamped" in named[0] and "sigmas include" in named[0], named
    rms, sigma = outage_rms_and_sigma(kept, tmp_path, OUTAGES)
    assert rms < 2.0 * sigma, (rms, sigma)


@pytest.mark.parametrize("arm, seed", [((-2.0, 0.3, 1.0), 5), ((3.0, -0.5, 0.5), 8)])
def test_an_unconfigured_arm_is_found_corrected_and_never_taken_for_a_clock(tmp_path, arm, seed):
    """An antenna 2-3 m from the IMU on a stop-and-go drive (speed changes tell an arm from
    a clock): the arm is named and taken in the axes the drive determines (not the car's
    vertical, +-2 m), no fix is moved in time, and the outages are bridged about as with the
    arm configured."""
    _drive(tmp_path, STOP_AND_GO, seed, arm=arm)
    measured = _outage_rms(_smooth(tmp_path, extra=f"\n[gnss]\nlever_arm_m = {list(arm)}\n"), tmp_path)
    track = _smooth(tmp_path)
    lines = [w for w in track.info.get("fit_warnings", []) if w.startswith("GNSS")]
    assert len(lines) == 1 and lines[0].startswith("GNSS lever arm"), lines
    assert "corrected" in lines[0] and "gnss_time_offset_corrected_s" not in track.info
    taken = track.info["gnss_lever_arm_corrected_m"]
    # The undetermined direction is the car's vertical (up to the fit's correlations: a few
    # mm of it in x and y), held as configured.
    assert abs(taken[0] - arm[0]) < 0.6 and abs(taken[1] - arm[1]) < 0.6 and abs(taken[2]) < 0.05, taken
    # a level car cannot show the antenna's height: said, with what that means for the heights
    assert "its z part not determined by this drive and kept as configured" in lines[0], lines
    kept = _smooth(tmp_path, extra="\n[gnss]\nlever_arm_from_data = false\n")
    named = [w for w in kept.info.get("fit_warnings", []) if w.startswith("GNSS lever arm")]
    assert len(named) == 1 and "measure" in named[0] and "gnss_lever_arm_corrected_m" not in kept.info
    # The arm the fixes fit is as good as 1 m fixes make it (seed 8's fit 0.5 m short, at
    # 1.7 sigma: 0.80 m inside outages against 0.47 m measured and 2.90 m left out).
    corrected, left_out = _outage_rms(track, tmp_path), _outage_rms(kept, tmp_path)
    assert corrected < 2.0 * measured + 0.1 and corrected < 0.4 * left_out, (corrected, measured, left_out)
    # The solve holds the taken arm fixed; its uncertainty is in the reported sigmas (seed
    # 8: horizontal NEES over the drive 4.6 without it, 1.25 with it; seed 5 0.55 -> 0.16).
    sigma = track.info["gnss_lever_arm_corrected_sigma_m"]
    assert 0.05 < min(sigma[:2]) and max(sigma[:2]) < 1.0 and sigma[2] < 0.05, sigma
    _, error = horizontal_errors(track, tmp_path)
    frame = track.to_dataframe()
    variance = (frame["std_east"] ** 2 + frame["std_north"] ** 2).to_numpy()
    assert np.all(variance >= 0.9 * min(sigma[:2]) ** 2)
    assert float(np.mean(error**2 / variance)) < 2.0


@pytest.mark.parametrize(
    "shift, arm, seed",
    [(0.0, (-2.0, 0.3, 1.0), 6), (0.0, (-1.5, 0.0, 0.0), 1), (0.1, (0.0, 0.0, 0.0), 1),
     (0.12, (0.0, 0.0, 0.0), 9)],
)  # fmt: skip
def test_at_one_steady_speed_an_arm_or_a_time_offset_is_named_as_both_and_corrected(
    tmp_path, shift, arm, seed
):
    """At one steady speed (a start from rest, then 15 m/s) an arm along the track and fixes
    stamped late look the same: both are named, "cannot tell", and the one that explains
    more is corrected (either gives the same track at that speed; leaving both out put
    1.1-1.6 m inside outages at 2.4-5 times the sigmas)."""
    _drive(tmp_path, [(10, 8, 15.0)], seed, arm=arm)
    measured = _outage_rms(_smooth(tmp_path, extra=f"\n[gnss]\nlever_arm_m = {list(arm)}\n"), tmp_path)
    if shift:
        shift_fix_times(tmp_path, shift)
    track = _smooth(tmp_path)
    lines = [w for w in track.info.get("fit_warnings", []) if w.startswith("GNSS")]
    assert len(lines) == 1 and lines[0].startswith("GNSS lever arm or time"), lines
    assert "cannot tell" in lines[0] and "corrected" in lines[0]
    rms, sigma = outage_rms_and_sigma(track, tmp_path, OUTAGES)
    # (seed 9: 0.099 s found for 0.12, 1.3 sigma off: 0.99 m against 0.75 m with true
    # stamps and 2.22 m left out)
    assert rms < 1.4 * measured + 0.1 and rms < 2.5 * sigma, (rms, measured, sigma)


@pytest.mark.parametrize(
    "ppm, steps, seed, method",
    [(2000.0, [(10, 8, 15.0)], 1, "batch"), (-2000.0, STOP_AND_GO, 2, "batch"),
     (1500.0, STOP_AND_GO, 3, "isam2"), (1000.0, [(10, 8, 15.0)], 1, "batch"),
     (-1000.0, [(10, 8, 15.0)], 2, "batch")],
)  # fmt: skip
def test_an_imu_clock_at_another_rate_is_found_and_the_output_is_on_the_receivers(
    tmp_path, ppm, steps, seed, method
):
    """The IMU stamped by its own oscillator, 0.1-0.2 % off the receiver's (GNSS) time: the
    offset grows to 0.3-0.6 s over the drive. A constant offset cannot fit it (0.2 % was
    read as an antenna 3.7 m ahead, "measure and set it"; 1.0 m inside outages against
    0.43 m with one clock); the offset and its drift are found and the IMU stamped onto
    the receiver's clock, which ``truth.csv`` keeps. At 0.1 % on one steady speed the
    drift is under 5 sigma and the offset looks like an arm too (taken as an antenna
    2.3 m ahead: 1.95 m); it is two clocks because the offset, taken as a time, still
    changes along the drive."""
    _drive(tmp_path, steps, seed)
    one_clock = _outage_rms(_smooth(tmp_path, method), tmp_path)
    run_imu_clock_off(tmp_path, ppm)
    track = _smooth(tmp_path, method)
    said = [w for w in track.info["fit_warnings"] if w.startswith("GNSS")]
    assert len(said) == 1 and "two clocks" in said[0], said
    assert "corrected" in said[0] and "receiver's clock" in said[0]
    end_offset = ppm * 1e-6 * 280.0  # the IMU's stamp minus the receiver's at the end
    found = track.info["gnss_time_offset_corrected_s"] + track.info["gnss_time_drift_corrected_s"]
    assert abs(found - end_offset) < 0.1, (found, end_offset)
    assert abs(track.t[-1] - 280.0) < 0.1, track.t[-1]
    corrected = _outage_rms(track, tmp_path)
    assert corrected < 1.3 * one_clock + 0.1
    kept = _smooth(tmp_path, method, "\n[gnss]\ntime_offset_from_data = false\n")
    assert "gnss_time_drift_corrected_s" not in kept.info
    assert _outage_rms(kept, tmp_path) > 1.2 * corrected


@pytest.mark.parametrize(("ppm", "seed"), [(5000.0, 1), (-5000.0, 2)])
def test_two_clocks_far_apart_are_corrected_before_the_sigmas_are_judged(tmp_path, ppm, seed):
    """An IMU clock 0.5 % off (1.4 s at the end of the drive): the fixes scattered 3.9x
    about the solution on the wrong stamps, their sigmas were scaled so before the clocks
    were corrected, and never judged again: the track right, its sigmas 2.7x too large (z
    0.26; outside tester). Two clocks that far apart are corrected first, as one offset is."""
    _drive(tmp_path, [(10, 8, 15.0)], seed)
    _with_antenna_velocities(tmp_path, np.zeros(3), seed)  # the receiver's velocities too
    run_imu_clock_off(tmp_path, ppm)
    track = _smooth(tmp_path)
    said = [w for w in track.info["fit_warnings"] if w.startswith("GNSS")]
    assert any("two clocks" in w and "corrected" in w for w in said), said
    assert not any("fixes scatter" in w for w in said), said
    rms, sigma = outage_rms_and_sigma(track, tmp_path, OUTAGES)
    assert 0.4 * sigma < rms < 2.0 * sigma, (rms, sigma)
    # (This drive's fixes happened to scatter under 2x on the wrong stamps; the tester's
    # scattered 3.9x. The rule itself: two clocks 1.4 s apart at the ends come first.)
    from dataclasses import replace

    from fgins.config import config_for_dataset
    from fgins.corrections import clock_offset_first

    dataset = fgins.load(tmp_path / "imu.csv", tmp_path / "gnss.csv", vehicle="car")
    reading = replace(track, info={"gnss_time_offset_s": -0.7 * np.sign(ppm), "gnss_time_drift_s": -0.7 * np.sign(ppm)})
    assert clock_offset_first(dataset, config_for_dataset(dataset), reading)


@pytest.mark.parametrize(("jump", "seed"), [(0.5, 1), (2.0, 2)])
def test_an_imu_clock_step_mid_drive_is_taken_out_not_fitted_as_a_drift(tmp_path, jump, seed):
    """The IMU's stamps step forward mid-drive with no sample lost (a logger's clock
    corrected): fitted as two clocks at different rates, a ramp that matches neither clock
    (outside tester: 0.5 s gave 2.6 m inside outages at z 4.2 and an arm "corrected" that
    is not there; 2 s, 9.5 m at z 11.9). The gap closed fits one clock: taken out, said."""
    import pandas as pd

    _drive(tmp_path, [(10, 8, 15.0)], seed)
    clean = _outage_rms(_smooth(tmp_path), tmp_path)
    imu = pd.read_csv(tmp_path / "imu.csv")
    imu.loc[imu["time"] >= 140.0, "time"] += jump
    imu.to_csv(tmp_path / "imu.csv", index=False, float_format="%.10e")
    track = _smooth(tmp_path)
    said = [w for w in track.info["fit_warnings"] if w.startswith("imu: its stamps jump")]
    assert said and f"{jump:+.3f} s" in said[0], track.info["fit_warnings"]
    assert "gnss_time_drift_corrected_s" not in track.info
    assert _outage_rms(track, tmp_path) < 1.2 * clean + 0.1


def test_true_stamps_and_arm_are_left_alone(tmp_path):
    _drive(tmp_path, STOP_AND_GO, 7)
    track = _smooth(tmp_path)
    assert not [w for w in track.info.get("fit_warnings", []) if w.startswith("GNSS")]
    assert abs(track.info["gnss_time_offset_fit_s"]) < 5 * track.info["gnss_time_offset_fit_sigma_s"]
    assert abs(track.info["gnss_time_drift_fit_s"]) < 5 * track.info["gnss_time_drift_fit_sigma_s"]


@pytest.mark.slow
@pytest.mark.parametrize("ppm", [300.0, -300.0, 100.0, -100.0])
def test_an_aircraft_imu_clock_off_is_corrected_over_rounds(tmp_path, ppm):
    """fgins's aircraft (720 s at ~100 m/s, tactical IMU, one 60 s outage) with its IMU on a
    clock 100-300 ppm off the receiver's. With only the fixes' positions in the check it
    found 30 % of a fast drift (outage 8.3 m against 1.0 m with one clock; 1.7 m after
    rounds), read 300 ppm slow as an antenna 12 m off the IMU and did not see 100 ppm
    (3.1 m); with their velocities too it is found and corrected in one round."""
    import pandas as pd
    import pymap3d

    from fgins.sim.scenarios import SCENARIOS
    from fgins.sim.writer import write_sim_dir

    run = SCENARIOS["aircraft-ekf"](seed=0)
    write_sim_dir(run, tmp_path)
    truth = pd.read_csv(tmp_path / "truth.csv")
    outage = [(500.0, 560.0)]

    def outage_rms() -> tuple[float, dict]:
        track = fgins.smooth(fgins.load(tmp_path), "batch", gnss_outage=outage, progress=False)
        frame = track.to_dataframe()
        t = frame["time"].to_numpy()
        reference = [np.interp(t, truth["time"], truth[c]) for c in ("lat", "lon", "alt")]
        east, north, _ = pymap3d.geodetic2enu(frame["lat"], frame["lon"], frame["alt"], *reference)
        inside = (t >= outage[0][0]) & (t < outage[0][1])
        return float(np.sqrt(np.mean(np.hypot(east, north)[inside] ** 2))), track.info

    one_clock, _ = outage_rms()
    run_imu_clock_off(tmp_path, ppm)
    corrected, info = outage_rms()
    # (The scenario's own outage lies in the window: "withholds no GNSS epoch" is said too.)
    said = [w for w in info["fit_warnings"] if w.startswith("GNSS") and "outage window" not in w]
    assert len(said) == 1 and "two clocks" in said[0] and "corrected" in said[0], said
    end_offset = ppm * 1e-6 * 720.0
    found = info["gnss_time_offset_corrected_s"] + info["gnss_time_drift_corrected_s"]
    assert abs(found - end_offset) < 0.15 * abs(end_offset), (found, end_offset)
    # (300 ppm slow: 1.39 m against 0.98, its clock found 5 % short: the velocities' own
    # delay, free in the check, takes their say in the common offset)
    assert corrected < 1.5 * one_clock, (corrected, one_clock)


@pytest.mark.parametrize("ppm, seed", [(500.0, 3), (-500.0, 4), (700.0, 5)])
def test_an_imu_clock_drift_is_measured_in_full(tmp_path, ppm, seed):
    """An IMU on its own clock, ``ppm`` off the receiver's, seen from the IMU's time: the
    fixes' positions and velocities come stamped ever earlier (or later), their velocities
    read ``1 + r`` times the solution's and the IMU integrates every interval over ``1 +
    r`` its length. The check modelled only the positions' stamps, while the velocities, 50
    times sharper than the positions here, held the solution where the stamps put them:
    on fgins's aircraft (5 min: take-off, climb, turns) 500 ppm fast gave half the drift
    and a fifth of the offset, 500 ppm slow a quarter of each. Both must come out within
    3 sigma of what was put in (the estimate itself: the correction is off)."""
    import pandas as pd

    from fgins.sim.scenarios import SCENARIOS
    from fgins.sim.writer import write_sim_dir

    write_sim_dir(SCENARIOS["aircraft-ekf"](seed=seed, duration_s=300.0, outage_start_s=200.0), tmp_path)
    start = float(pd.read_csv(tmp_path / "imu.csv")["time"].iloc[0])
    run_imu_clock_off(tmp_path, ppm)
    config = tmp_path / "config.toml"
    config.write_text(config.read_text().replace(
        "[gnss]\n", "[gnss]\ntime_offset_from_data = false\nlever_arm_from_data = false\n"
    ))  # fmt: skip
    info = fgins.smooth(fgins.load(tmp_path), "batch", progress=False).info
    # The fixes' stamps minus the IMU's, at the drive's middle and its change to the end.
    offset = -ppm * 1e-6 * (info["gnss_time_middle_s"] - start)
    drift = -ppm * 1e-6 * info["gnss_time_half_span_s"]
    for put_in, name in ((offset, "clock_offset"), (drift, "drift")):
        found, sigma = info[f"gnss_time_{name}_fit_s"], info[f"gnss_time_{name}_fit_sigma_s"]
        assert abs(put_in) > 5 * sigma, (name, put_in, sigma)
        assert abs(found - put_in) < 3 * sigma, (name, found, put_in, sigma)


@pytest.mark.parametrize(
    "sensor, scale, seed, duration",
    [("accel", 0.01, 1, 300.0), ("accel", -0.01, 2, 720.0), ("gyro", 0.01, 3, 720.0),
     ("gyro", -0.015, 4, 300.0)],
)  # fmt: skip
def test_an_imus_own_scale_error_is_not_read_as_an_arm_or_a_clock(
    tmp_path, sensor, scale, seed, duration
):
    """An accelerometer or gyro whose scale is 1 % off (within MEMS datasheets) moves the
    solution in climbs, banks and turns the way an antenna off the IMU or a clock drift
    would: on fgins's aircraft a gyro 1 % large read as an antenna 8 m above the IMU, 1.5 %
    small as one 17 m away and two clocks (with the fixes' velocities in the check and not
    the scales, an accelerometer 1 % off read as an antenna 1-1.5 m above or below at 10-14
    sigma). The check estimates the IMU's scales with them; nothing about the antenna or
    the clock may be said, and the correctly configured arm must fit within 3 sigma."""
    import pandas as pd

    from fgins.sim.scenarios import SCENARIOS
    from fgins.sim.writer import write_sim_dir

    write_sim_dir(SCENARIOS["aircraft-ekf"](seed=seed, duration_s=duration, outage_start_s=duration - 220.0), tmp_path)
    imu = pd.read_csv(tmp_path / "imu.csv")
    columns = [c for c in imu.columns if c.startswith(sensor)]
    imu[columns] *= 1.0 + scale
    imu.to_csv(tmp_path / "imu.csv", index=False, float_format="%.10e")
    info = fgins.smooth(fgins.load(tmp_path), "batch", progress=False).info
    said = [w for w in info.get("fit_warnings", []) if w.startswith("GNSS")]
    assert not said, said
    if sensor == "gyro":  # the batch's own gyro-scale step takes it, though the first fit is
        # poor for it (chi2/dof 10 with a gyro 1 % large: it used to be skipped there)
        assert all(info["gyro_scale_corrected"]) and info["chi2_per_dof"] < 2.0, info["gyro_scale_error"]
    configured = np.array(fgins.load(tmp_path).gnss_config["lever_arm_m"])
    change = np.array(info["gnss_lever_arm_fit_m"]) - configured
    assert np.all(np.abs(change) < 3 * np.array(info["gnss_lever_arm_fit_sigma_m"])), change


def test_sigmas_scaled_and_a_latency_corrected_are_both_said(tmp_path):
    """Fixes 0.2 s late whose std columns are 3x too small: the sigmas are scaled first
    (too-small sigmas make any offset look significant to the antenna check), then the
    latency corrected on top. Each correction solves again; the second's solve must still
    say the first (the sigma scaling, once after the antenna step, dropped what that step
    had corrected from the summary)."""
    import pandas as pd

    _drive(tmp_path, [(10, 8, 15.0)], 2)
    right = _outage_rms(_smooth(tmp_path), tmp_path)
    _drive(tmp_path, [(10, 8, 15.0)], 2, shift_s=0.2)
    fixes = pd.read_csv(tmp_path / "gnss.csv")
    fixes[["std_east", "std_north", "std_up"]] *= 1.0 / 3.0
    fixes.to_csv(tmp_path / "gnss.csv", index=False, float_format="%.10f")
    track = _smooth(tmp_path)
    said = [w for w in track.info["fit_warnings"] if w.startswith("GNSS")]
    assert len(said) == 2 and all("corrected" in w for w in said), said
    assert "scatter" in said[0] and said[1].startswith("GNSS time:"), said
    assert 2.0 < track.info["gnss_sigma_scale"][0] < 4.5, track.info["gnss_sigma_scale"]
    assert abs(track.info["gnss_time_offset_corrected_s"] + 0.2) < 0.05
    assert _outage_rms(track, tmp_path) < 1.3 * right + 0.1



@pytest.mark.parametrize("shift", [-1.5, 1.5])
def test_fixes_seconds_off_with_their_velocities_move_as_one(tmp_path, shift):
    """fgins's urban car with its whole GNSS file (positions and velocities) 1.5 s off. The
    first-order check also reads the offset as the velocities lagging their positions
    (0.44-0.48 s), and that was corrected first, alone: the offset was then left at "smooth
    again with --time-offset", or solved and declined (11-14 m, every epoch beyond 3
    sigma, exit 0; outside tester). An offset larger than the velocities' lag moves first,
    velocities with their positions."""
    import pandas as pd
    import pymap3d

    from fgins.sim.scenarios import SCENARIOS
    from fgins.sim.writer import write_sim_dir

    folder = tmp_path / "drive"
    write_sim_dir(SCENARIOS["car-urban"](seed=0, duration_s=180.0), folder)
    fixes = pd.read_csv(folder / "gnss.csv")
    fixes["time"] += shift
    fixes.to_csv(folder / "gnss.csv", index=False)
    track = fgins.smooth(fgins.load(folder), "batch", progress=False)
    said = [w for w in track.info["fit_warnings"] if w.startswith("GNSS time:")]
    assert said and "corrected" in said[0], track.info["fit_warnings"]
    truth = pd.read_csv(folder / "truth.csv")
    frame = track.to_dataframe()
    t = frame["time"].to_numpy()
    reference = [np.interp(t, truth["time"], truth[c]) for c in ("lat", "lon", "alt")]
    east, north, _ = pymap3d.geodetic2enu(frame["lat"], frame["lon"], frame["alt"], *reference)
    z = np.hypot(east / frame["std_east"], north / frame["std_north"])
    assert np.sqrt(np.mean(east**2 + north**2)) < 1.5 and np.mean(z > 3.0) < 0.05


def _with_antenna_velocities(folder: Path, arm: np.ndarray, seed: int) -> None:
    """The receiver's velocities (0.1 m/s noise) of an antenna at ``arm`` (body FLU axes of
    a car with no roll, its nose along its velocity), written into ``folder``'s gnss.csv:
    the rate of change of the antenna's position, from the truth at the IMU's rate."""
    import pandas as pd

    truth, fixes = pd.read_csv(folder / "truth.csv"), pd.read_csv(folder / "gnss.csv")
    t, v = truth["time"].to_numpy(), truth[["vel_east", "vel_north", "vel_up"]].to_numpy()
    speed = np.hypot(v[:, 0], v[:, 1])
    moving = speed > 0.05  # at a stop the nose keeps its last heading
    heading = np.interp(t, t[moving], np.unwrap(np.arctan2(v[moving, 0], v[moving, 1])))
    pitch = np.interp(t, t[moving], np.arctan2(v[moving, 2], speed[moving]))
    forward = np.stack([np.sin(heading) * np.cos(pitch), np.cos(heading) * np.cos(pitch), np.sin(pitch)], -1)
    left = np.stack([-np.cos(heading), np.sin(heading), 0.0 * heading], -1)
    antenna = truth[["east", "north", "up"]].to_numpy() + arm[0] * forward + arm[1] * left
    antenna += arm[2] * np.cross(forward, left)
    velocity = np.gradient(antenna, t, axis=0)
    noise = np.random.default_rng(seed).normal(0.0, 0.1, (len(fixes), 3))
    for i, column in enumerate(("vel_east", "vel_north", "vel_up")):
        fixes[column] = np.interp(fixes["time"], t, velocity[:, i]) + noise[:, i]
    fixes.to_csv(folder / "gnss.csv", index=False)


@pytest.mark.parametrize("seed", [2, 4])
def test_an_arm_taken_from_the_data_is_refined_until_the_fixes_point_nowhere_else(tmp_path, seed):
    """An antenna 1.5 m behind the IMU, unconfigured, 5 Hz fixes of 0.5 m with velocities (an
    outside tester's setup). The check is one Gauss-Newton step about a solution that has
    absorbed part of the arm: the batch took -1.34 / -1.36 m (EKF+RTS, which carries the arm
    in its filter, -1.42 / -1.44), and the check about the corrected solution still pointed
    further. The arm is now refined until it points nowhere else."""
    from independent_sim import FIVE_TURNS, INDUSTRIAL, CarProfile, write_drive

    arm = np.array([-1.5, 0.0, 0.0])
    profile = CarProfile(steps=STOP_AND_GO, turns=FIVE_TURNS, gamma=lambda t: 0 * t)
    write_drive(tmp_path, profile, 280.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                gnss_rate=5.0, seed=seed, sigma_h=0.5, sigma_u=0.8, lever_arm=tuple(arm))  # fmt: skip
    _with_antenna_velocities(tmp_path, arm, seed)
    track = _smooth(tmp_path)
    taken = np.array(track.info["gnss_lever_arm_corrected_m"])
    fit = np.array(track.info["gnss_lever_arm_fit_m"])
    sigma = np.array(track.info["gnss_lever_arm_fit_sigma_m"])
    assert abs(fit[0] - taken[0]) < 0.5 * sigma[0], (taken, fit, sigma)
    assert abs(taken[0] - arm[0]) < 2.5 * sigma[0], (taken, sigma)


@pytest.mark.parametrize("shift", [0.15, -0.1])
def test_a_latency_of_fixes_with_velocities_is_a_latency_for_the_kalman_check_too(tmp_path, shift):
    """Fixes with the receiver's velocities, all stamped 0.15 s late (or 0.1 s early): the
    Kalman baselines' check, whose model lets only the positions carry a time offset, read
    the late velocities as an antenna turning with the car: 'an antenna at [-2.5, 0.1,
    -1.9] m', taken, and EKF+RTS 1.3 m off at the fixes at NEES ~200 where the batch found
    the latency (outside tester). The check now reads the positions alone."""
    from independent_sim import FIVE_TURNS, INDUSTRIAL, CarProfile, write_drive

    profile = CarProfile(steps=STOP_AND_GO, turns=FIVE_TURNS, gamma=lambda t: 0 * t)
    write_drive(tmp_path, profile, 280.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                gnss_rate=5.0, seed=3, sigma_h=0.5, sigma_u=0.8)  # fmt: skip
    _with_antenna_velocities(tmp_path, np.zeros(3), 3)
    shift_fix_times(tmp_path, shift)  # positions and velocities alike
    track = _smooth(tmp_path, "ekf-rts")
    said = [w for w in track.info.get("fit_warnings", []) if w.startswith("GNSS")]
    assert said and said[0].startswith("GNSS time:") and "corrected" in said[0], said
    assert "gnss_lever_arm_corrected_m" not in track.info, said
    assert abs(-track.info["gnss_time_offset_corrected_s"] - shift) < 0.02
    _, error = horizontal_errors(track, tmp_path)
    assert float(np.sqrt(np.mean(error**2))) < 0.5


@pytest.mark.parametrize("shift", [2.0, -2.5])
def test_fixes_seconds_off_are_corrected_in_full(tmp_path, shift):
    """fgins's urban car, its GNSS file 2-2.5 s off. The offset moved the fixes by 10-20
    sigmas, and their scatter was taken first for sigmas too small (2.1x); the correction,
    one linear step about a solution bent toward the late fixes, found 1.85 of 2 s, and the
    rest hid under the widened sigmas: 2.8 m over the drive against 0.32 with the stamps
    right, exit 0 (outside tester: "partly corrected"). An offset that large is corrected
    before the sigmas are judged, the rest of it taken at 2 sigma, and the whole run made
    again on the moved stamps: the offset to 0.1 s, the track as with true stamps."""
    import pandas as pd
    import pymap3d

    from fgins.sim.scenarios import SCENARIOS
    from fgins.sim.writer import write_sim_dir

    folder = tmp_path / "drive"
    write_sim_dir(SCENARIOS["car-urban"](seed=0, duration_s=180.0), folder)
    truth = pd.read_csv(folder / "truth.csv")

    def errors(track) -> tuple[float, float]:
        """Horizontal RMS against the truth, and the share of epochs beyond 3 sigma."""
        frame = track.to_dataframe()
        t = frame["time"].to_numpy()
        reference = [np.interp(t, truth["time"], truth[c]) for c in ("lat", "lon", "alt")]
        east, north, _ = pymap3d.geodetic2enu(frame["lat"], frame["lon"], frame["alt"], *reference)
        z = np.hypot(east / frame["std_east"], north / frame["std_north"])
        return float(np.sqrt(np.mean(east**2 + north**2))), float(np.mean(z > 3.0))

    right, _ = errors(fgins.smooth(fgins.load(folder), "batch", progress=False))
    fixes = pd.read_csv(folder / "gnss.csv")
    fixes["time"] += shift
    fixes.to_csv(folder / "gnss.csv", index=False)
    track = fgins.smooth(fgins.load(folder), "batch", progress=False)
    assert abs(track.info["gnss_time_offset_corrected_s"] + shift) < 0.1, track.info["gnss_time_offset_corrected_s"]
    said = [w for w in track.info["fit_warnings"] if w.startswith("GNSS time:")]
    assert len(said) == 1 and "in all" in said[0], track.info["fit_warnings"]
    # What is left of the offset is within its own sigma (0.05 s: 0.5 m along the track at
    # 10 m/s, in the reported sigmas): 0.61-0.64 m against 0.34 with true stamps; 2.8 m before.
    rms, beyond = errors(track)
    assert rms < 2.0 * right + 0.1 and beyond < 0.05, (rms, right, beyond)


def test_a_clock_reading_the_solve_could_not_take_is_carried_in_the_sigmas():
    """A clock offset read at 5 sigma whose correction fitted no better was left as
    configured, and the output kept sigmas for the fixes alone: an independent simulator's
    aircraft in a 60 deg bank, fixes 0.5 s late, came out 40 m off at sigmas of 0.3 m (z 116).
    The reading (here 0.8 s) now widens the covariance along the velocity by exactly its
    square times v v^T, and nothing else."""
    from fgins.corrections import TIME_UNRESOLVED_KEY, add_unresolved_time_uncertainty
    from fgins.datatypes import Origin, Trajectory

    n = 5
    velocity = np.tile([80.0, 0.0, 0.0], (n, 1)) * np.arange(1, n + 1)[:, None]
    cov = np.tile(np.diag([0.09, 0.09, 0.25]), (n, 1, 1))
    track = Trajectory(
        t=np.arange(n, dtype=float), position=np.zeros((n, 3)), velocity=velocity,
        rotation=np.tile(np.eye(3), (n, 1, 1)), origin=Origin(45.0, 10.0, 100.0),
        method="batch", position_cov=cov.copy(), info={TIME_UNRESOLVED_KEY: 0.8},
    )  # fmt: skip
    add_unresolved_time_uncertainty(track)
    expected = cov + 0.64 * np.einsum("ni,nj->nij", velocity, velocity)
    np.testing.assert_allclose(track.position_cov, expected, rtol=1e-12)
    assert np.sqrt(track.position_cov[0, 0, 0]) > 60.0  # 0.8 s at 80 m/s: the 40 m inside 1 sigma
    untouched = Trajectory(
        t=track.t, position=track.position, velocity=velocity, rotation=track.rotation,
        origin=track.origin, method="batch", position_cov=cov.copy(),
    )  # fmt: skip
    add_unresolved_time_uncertainty(untouched)
    np.testing.assert_array_equal(untouched.position_cov, cov)


def test_an_offset_read_through_left_out_fixes_is_stepped_on_before_the_verdict():
    """A closed-form fit landscape for the clock's decision (fgins.corrections): fixes 0.5 s
    late, the solution before the correction with the turn's fixes left out as faults (chi2/dof
    1.67 over what is left), the reading 0.608 s. Solved with 0.608 s, every fix back in, the fit
    is 2.41, worse than the faulted one's, and the correction was declined: an independent
    simulator's fixed-wing in a 60 deg bank stayed 40 m off. Its own reading of the rest
    (-0.108 s) is one step more: solved there, 0.87, taken; the fixes moved by 0.500 s."""
    from dataclasses import replace as changed

    from fgins.config import RunConfig
    from fgins.corrections import Rerun, with_antenna_corrected
    from fgins.datatypes import Dataset, GnssData, ImuData, Origin, Trajectory

    late = 0.5
    t = np.arange(0.0, 100.0, 1.0)
    imu = ImuData(t=np.arange(0.0, 101.0, 0.01), gyro=np.zeros((10100, 3)), accel=np.zeros((10100, 3)))
    gnss = GnssData(t=t + late, lla=np.tile([47.0, 8.0, 400.0], (len(t), 1)))
    dataset = Dataset(imu=imu, gnss=gnss, origin=Origin(47.0, 8.0, 400.0))

    def solution(info: dict) -> Trajectory:
        n = len(t)
        return Trajectory(t=t, position=np.zeros((n, 3)), velocity=np.zeros((n, 3)),
                          rotation=np.tile(np.eye(3), (n, 1, 1)), origin=dataset.origin, info=info)  # fmt: skip

    def reading(rest: float) -> dict:
        """A solve's clock check: the offset left (s), at sigma 5 ms; said at 5 sigma."""
        out = {"gnss_time_offset_fit_s": rest, "gnss_time_offset_fit_sigma_s": 0.005}
        if abs(rest) > 5 * 0.005:
            out["gnss_time_offset_s"] = rest
        return out

    solves: list[float] = []

    def solver(data: Dataset, config: RunConfig, method: str) -> Trajectory:
        rest = float(data.gnss.t[0] - t[0])  # what is left of the delay after the move
        solves.append(rest)
        return solution({"chi2_per_dof": 0.87 + 130.0 * rest**2, "dof": 2190, **reading(rest)})

    first = solution({"chi2_per_dof": 1.67, "dof": 2016, **reading(0.608),
                      "antenna_findings": ["GNSS time: the fixes fit time stamps 0.608 s late"]})  # fmt: skip
    best, data, _ = with_antenna_corrected(dataset, RunConfig(), Rerun("batch", None, solver), first)
    assert best.info["gnss_time_offset_corrected_s"] == pytest.approx(-late, abs=0.005), solves
    assert data.gnss.t[0] == pytest.approx(t[0], abs=0.005)
    assert best.info["chi2_per_dof"] < 1.0
    # a reading that does not converge (the rest as large as the step) is still declined
    solves.clear()
    first_far = changed(first, info={**first.info, **reading(0.2)})
    declined, _, _ = with_antenna_corrected(changed(dataset, gnss=changed(gnss, t=t + 2.0)), RunConfig(),
                                            Rerun("batch", None, solver), first_far)  # fmt: skip
    assert "gnss_time_offset_corrected_s" not in declined.info, (solves, declined.info)


@pytest.mark.parametrize("late", [0.0, 0.05])
def test_a_latency_the_fixes_show_under_five_sigma_is_carried_and_said(tmp_path, late):
    """Fixes 50 ms late on a long straight road at 40 m/s: the delay shows only in a slow
    curve and the speed-up (here at 4.4 sigma, under the 5 a correction needs). Before, it
    was neither taken nor said, and the track sat 2 m along itself at sigmas of 0.25 m (an
    outside tester's 50 m/s car: z 10; an aircraft at 250 m/s: z 36). Now the sigmas carry
    it along the track and a line names the offset and the --time-offset that would remove
    it; on time, nothing is added."""
    import pandas as pd
    from independent_sim import INDUSTRIAL, CarProfile, write_drive

    profile = CarProfile(steps=[(5, 8, 40.0)], turns=[(100, 160, 8, 0.01)], gamma=lambda t: 0 * t)
    write_drive(tmp_path, profile, 200.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0, gnss_rate=1.0, seed=1)
    if late:
        shift_fix_times(tmp_path, late)
    track = _smooth(tmp_path, outages=[(120.0, 150.0)])
    aided = [(20.0, 120.0), (150.0, 195.0)]
    rms, sigma = outage_rms_and_sigma(track, tmp_path, aided)
    said = [w for w in track.info.get("fit_warnings", []) if w.startswith("GNSS time")]
    if not late:
        assert not said and "gnss_time_offset_unresolved_s" not in track.info, said
        assert rms < 0.4
        return
    assert len(said) == 1 and "--time-offset -0.0" in said[0] and "along the track" in said[0], said
    assert rms > 1.0 and rms < 1.5 * sigma, (rms, sigma)  # 2 m off, and the sigmas say so
    std = pd.DataFrame(track.to_dataframe())[["std_east", "std_north"]].to_numpy()
    assert np.all(np.isfinite(std)) and np.all(std > 0)


def _pitch_imu(folder: Path, pitch_deg: float) -> np.ndarray:
    """Rewrite ``folder/imu.csv`` as read by the same IMU pitched ``pitch_deg`` in the car
    (README: a positive pitch turns its x axis down), its mounting in cfg.toml; returns
    R_vi (vehicle axes -> IMU axes: a vector in IMU axes is R_vi^T v)."""
    import pandas as pd
    from scipy.spatial.transform import Rotation

    r_vi = Rotation.from_euler("ZYX", [0.0, pitch_deg, 0.0], degrees=True).as_matrix()
    imu = pd.read_csv(folder / "imu.csv")
    for kind in ("gyro", "accel"):
        columns = [f"{kind}_{axis}" for axis in "xyz"]
        imu[columns] = imu[columns].to_numpy() @ r_vi  # each row v -> R_vi^T v
    imu.to_csv(folder / "imu.csv", index=False, float_format="%.10e")
    with open(folder / "cfg.toml", "a") as config:
        config.write(f"\n[smoother]\nimu_to_vehicle_rpy_deg = [0.0, {pitch_deg}, 0.0]\n")
    return r_vi


@pytest.mark.parametrize("pitch_deg, seed", [(30.0, 5), (-20.0, 8)])
def test_an_unconfigured_arm_is_taken_on_an_imu_tilted_in_the_car(tmp_path, pitch_deg, seed):
    """What a car's drive cannot show is the antenna's height above the IMU: a direction of
    the vehicle, which on an IMU pitched in the car lies between its x and z axes. Judged
    per IMU axis, both were "not determined" and the arm the fixes showed thrown away (an
    outside tester's car, IMU pitched 30 deg, antenna 2.9 m off: 2.1 m off at the fixes at
    z 7, "GNSS sigmas set too small"). Now the arm is taken but along the car's vertical,
    and said so, and the outages are bridged about as with the arm measured."""
    arm_vehicle = np.array([-2.5, 0.3, 1.5])  # behind, left and above the IMU
    _drive(tmp_path, STOP_AND_GO, seed, arm=tuple(arm_vehicle))
    r_vi = _pitch_imu(tmp_path, pitch_deg)
    arm_imu = r_vi.T @ arm_vehicle
    measured = _outage_rms(_smooth(tmp_path, extra=f"\n[gnss]\nlever_arm_m = {[float(x) for x in arm_imu]}\n"), tmp_path)
    track = _smooth(tmp_path)
    lines = [w for w in track.info.get("fit_warnings", []) if w.startswith("GNSS")]
    assert len(lines) == 1 and "corrected" in lines[0], lines
    up = r_vi.T @ np.array([0.0, 0.0, 1.0])  # the car's vertical in IMU axes
    assert f"its part along [{', '.join(f'{x:.2f}' for x in up * np.sign(up[2]))}]" in lines[0], lines
    taken_vehicle = r_vi @ np.asarray(track.info["gnss_lever_arm_corrected_m"])
    assert np.all(np.abs(taken_vehicle[:2] - arm_vehicle[:2]) < 0.6), taken_vehicle
    assert abs(taken_vehicle[2]) < 0.05, taken_vehicle  # held as configured (0)
    kept = _smooth(tmp_path, extra="\n[gnss]\nlever_arm_from_data = false\n")
    corrected, left_out = _outage_rms(track, tmp_path), _outage_rms(kept, tmp_path)
    assert corrected < 1.5 * measured + 0.1 and corrected < 0.5 * left_out, (corrected, measured, left_out)
    _, error = horizontal_errors(track, tmp_path)
    frame = track.to_dataframe()
    z = error / np.sqrt(0.5 * (frame["std_east"] ** 2 + frame["std_north"] ** 2)).to_numpy()
    assert np.sqrt(np.mean(z**2)) < 2.0


@pytest.mark.parametrize("seed", [1, 2])
def test_an_antenna_read_under_the_correction_threshold_is_carried_in_the_sigmas(tmp_path, seed):
    """An antenna 0.58 m off the configured arm horizontally, read at 3-5 sigma (under the
    correction's 5): nothing was said and the track lay 0.6 m off at the fixes at sigma 0.1
    (z 6; an outside tester's car: z 4). It is said and carried in the output's sigmas;
    with the true arm nothing is said."""
    arm = (0.5, 0.3, 1.2)
    _drive(tmp_path, [(10, 8, 15.0)], seed, arm=arm, sigma_h=0.3, sigma_u=1.0)
    at_fixes = [(0.0, 60.0), (105.0, 175.0), (215.0, 280.0)]
    wrong = _smooth(tmp_path, extra="\n[gnss]\nlever_arm_m = [0.0, 0.0, 1.2]\n")
    said = [w for w in wrong.info.get("fit_warnings", []) if w.startswith("GNSS lever arm")]
    assert len(said) == 1 and "the output's sigmas include it" in said[0], wrong.info.get("fit_warnings")
    rms, sigma = outage_rms_and_sigma(wrong, tmp_path, at_fixes)
    assert rms < 1.5 * sigma, (rms, sigma)
    right = _smooth(tmp_path, extra=f"\n[gnss]\nlever_arm_m = {list(arm)}\n")
    assert not any(w.startswith("GNSS lever arm") for w in right.info.get("fit_warnings", []))
    assert "gnss_lever_arm_unconfirmed_m" not in right.info


@pytest.mark.parametrize("seed", [2, 6])
def test_the_online_estimate_gets_the_runs_time_correction(tmp_path, seed):
    """``--method isam2 --online`` had no time or lever-arm check: fixes 0.2 s late left the
    online track 2.4 m off at the fixes at z 3.3, unsaid (outside tester), where the same
    run's final estimate and the forward EKF corrected them. The final solution's readings
    decide for the online estimate too: corrected and said."""
    _drive(tmp_path, [(10, 8, 15.0)], seed, shift_s=0.2)
    config = tmp_path / "run.toml"
    config.write_text((tmp_path / "cfg.toml").read_text())
    dataset = fgins.load(tmp_path / "imu.csv", tmp_path / "gnss.csv", config=config, vehicle="car")
    online = fgins.smooth(dataset, "isam2", online=True, gnss_outage=OUTAGES)
    said = [w for w in online.info.get("fit_warnings", []) if w.startswith("GNSS time:")]
    assert len(said) == 1 and "corrected" in said[0], online.info.get("fit_warnings")
    assert online.info["gnss_time_offset_corrected_s"] == pytest.approx(-0.2, abs=0.03)
    at_fixes = [(0.0, 60.0), (105.0, 175.0), (215.0, 280.0)]
    rms, sigma = outage_rms_and_sigma(online, tmp_path, at_fixes)
    assert rms < 2.0 * sigma, (rms, sigma)


def _highway(folder: Path, seed: int, shift_s: float, duration_s: float = 300.0) -> None:
    """``duration_s`` of highway at 28 m/s from the first sample (a log cut from a longer
    drive) with two 10-deg curves, the road's only turns (a third and two thirds in)."""
    from independent_sim import INDUSTRIAL, CarProfile, write_drive

    first, second = round(duration_s / 3), round(2 * duration_s / 3)
    curves = [(first, first + 10, 3, np.radians(1.0)), (second, second + 10, 3, np.radians(-1.0))]
    profile = CarProfile(steps=[(-30.0, 12, 28.0)], turns=curves, gamma=lambda t: 0 * t)
    write_drive(folder, profile, duration_s, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                gnss_rate=1.0, seed=seed)  # fmt: skip
    if shift_s:
        shift_fix_times(folder, shift_s)


@pytest.mark.parametrize(("seed", "late"), [(1, 0.2), (2, 0.1)])
def test_a_drive_that_cannot_check_its_time_stamps_says_so(tmp_path, seed, late):
    """On a highway at one speed a latency moves the fixes along the track exactly as the
    car's place does: fixes 0.1-0.2 s late on a 10-min stretch were 2.9-6.2 m off at sigmas of
    0.16 m, nothing said (outside tester). The data cannot show it (the check reads it under
    its sigma), so the run says how far its stamps are known and what that leaves out; a
    town drive with true stamps says nothing (test_true_stamps_and_arm_are_left_alone)."""
    _highway(tmp_path, seed, late)
    track = _smooth(tmp_path, outages=[(150.0, 190.0)])
    said = track.info["gnss_time_unresolved"]  # a summary line: what the data cannot check
    assert "tells the fixes' time stamps only" in said
    sigma = track.info["gnss_time_offset_fit_sigma_s"]
    assert f"+-{sigma:.3f} s" in said and "--time-offset" in said
    _, errors = horizontal_errors(track, tmp_path)
    assert np.sqrt(np.mean(errors**2)) > 0.5 * late * 28.0  # the latency is in the track


@pytest.mark.parametrize("seed", [1, 2])
def test_whole_seconds_late_on_a_highway_are_found_where_the_fit_is_best(tmp_path, seed):
    """Fixes whole seconds late on a highway: the check reads the offset by one Gauss-Newton
    step about a solution that bent towards the late fixes, and its rounds stopped once the
    rest fell under 2 of its sigmas, 0.2-0.45 s short (6-13 m at 28 m/s, z 3.7-7.5 with
    "corrected" said; outside tester). The offset is then searched where the solved fits are
    best, and its sigma read from their curvature is in the output's (10 min, 2 s late,
    seeds 1-3: taken 1.70-1.81 s, 5.4-8.6 m at z 3.5-5.6; now 1.85-1.98 s, 0.6-4.3 m at z
    0.3-2.0)."""
    late = 2.0
    _highway(tmp_path, seed, late, duration_s=600.0)
    track = _smooth(tmp_path, outages=[(250.0, 290.0)])
    taken = -track.info["gnss_time_offset_corrected_s"]
    sigma = track.info.get("gnss_time_offset_search_sigma_s", track.info["gnss_time_offset_fit_sigma_s"])
    assert abs(taken - late) < max(3.0 * sigma, 0.05), (taken, sigma)
    frame = track.to_dataframe()
    _, errors = horizontal_errors(track, tmp_path)
    variance = (frame["std_east"] ** 2 + frame["std_north"] ** 2).to_numpy() / 2.0
    assert np.sqrt(np.mean(errors**2 / variance)) < 3.0 * np.sqrt(2.0)


def test_an_arm_or_clock_rate_no_car_or_oscillator_has_is_not_taken():
    """A multirotor given --vehicle car: its misfit read as an antenna 72 m from the IMU and
    two clocks 4.5 % apart in rate, both "corrected", the output's times rewritten to a
    4.77 ms step for a 200 Hz IMU (outside tester). Such readings are said, not taken."""
    from fgins.config import RunConfig, SmootherConfig
    from fgins.corrections import Rerun, with_antenna_corrected
    from fgins.datatypes import Dataset, GnssData, ImuData, Origin, Trajectory

    t = np.arange(0.0, 290.0, 1.0)
    imu = ImuData(t=np.arange(0.0, 290.0, 0.005), gyro=np.zeros((58000, 3)), accel=np.zeros((58000, 3)))
    dataset = Dataset(imu=imu, gnss=GnssData(t=t, lla=np.tile([47.0, 8.0, 400.0], (len(t), 1))),
                      origin=Origin(47.0, 8.0, 400.0))  # fmt: skip

    def solution(info: dict) -> Trajectory:
        n = len(t)
        return Trajectory(t=t, position=np.zeros((n, 3)), velocity=np.zeros((n, 3)),
                          rotation=np.tile(np.eye(3), (n, 1, 1)), origin=dataset.origin, info=info)  # fmt: skip

    solves = []

    def solver(data: Dataset, config: RunConfig, method: str) -> Trajectory:
        solves.append(method)  # whatever was taken "fits" far better
        return solution({"chi2_per_dof": 1.0, "dof": 1335})

    first = solution({
        "chi2_per_dof": 28.7, "dof": 1335, "gnss_lever_arm_m": [4.79, -72.15, -30.18],
        "gnss_time_offset_s": -3.4, "gnss_time_drift_s": -6.6, "gnss_time_middle_s": 145.0,
        "gnss_time_half_span_s": 145.0,
        "antenna_findings": ["GNSS lever arm: the fixes fit an antenna at [4.79, -72.15, -30.18] m"],
    })  # fmt: skip
    config = RunConfig(smoother=SmootherConfig(vehicle="car"))
    assert config.smoother.nhc
    best, data, _ = with_antenna_corrected(dataset, config, Rerun("batch", None, solver), first)
    assert best is first and not solves
    assert np.array_equal(data.imu.t, imu.t) and "gnss_lever_arm_corrected_m" not in best.info
    said = [w for w in best.info["fit_warnings"] if "not taken" in w]
    assert len(said) == 1 and "78 m from the IMU" in said[0] and "4.6 % apart in rate" in said[0], said
