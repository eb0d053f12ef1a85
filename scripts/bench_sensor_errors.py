#!/usr/bin/env python3
"""Sensor errors the data show and fgins corrects: outage bridging with each step on and off.

Drives from the independent car simulator of the tests (``tests/independent_sim.py``: shares
no code with ``fgins.sim``): rest 10 s, then 15 m/s through five turns, industrial MEMS at
100 Hz, 1 m fixes at 1 Hz, outages 60-105 s and 175-215 s. Each drive is written with a true
sensor, then with one error a real log carries:

- vibration: white noise on the accelerometers beyond the datasheet (``noise_from_data``,
  fgins.noise_at_rest);
- gyro scale: the gyro reading 1-3 % large or small (``estimate_gyro_scale``,
  fgins.graph.gyro_scale);
- latency: the fixes stamped late or early (``time_offset_from_data``,
  fgins.graph.reports.lever_arm_report and fgins.pipeline);
- lever arm: the antenna away from the IMU and not configured (``lever_arm_from_data``,
  the same modules); an antenna along the track looks like latency at one steady speed;
- clock: the IMU stamped by its own oscillator, 0.1-0.2 % off the receiver's time (the
  offset between the two grows along the drive; truth keeps the receiver's time).

For each: batch's horizontal RMS inside the outages against the simulator's truth and its
error / reported sigma there, with the step on (the default) and off, and the ratios to the
true sensor's RMS measured in the same run.

The Kalman baselines (``--method ekf``, ``ekf-rts``, ``ukf``) run the same antenna and clock
check (session 41; ``--cases late,early,arm`` for those rows only): "off" is what they did
before, following the fixes they were given.

    python scripts/bench_sensor_errors.py [--seeds 1,2] [--method batch] [--cases late,arm]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import warnings
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

from independent_sim import (  # noqa: E402
    FIVE_TURNS,
    INDUSTRIAL,
    CarProfile,
    add_vibration,
    outage_rms_and_sigma,
    run_imu_clock_off,
    scale_gyro,
    shift_fix_times,
    write_drive,
)

import fgins  # noqa: E402

OUTAGES = [(60.0, 105.0), (175.0, 215.0)]
# (label, how the error is written, the config line that turns fgins's step off); an
# unconfigured antenna's arm is written with the drive (ARMS).
ANTENNA_OFF = "[gnss]\ntime_offset_from_data = false\nlever_arm_from_data = false"
CASES = [
    ("vibration 0.1 m/s^2", lambda d, s: add_vibration(d, 0.1, s), "[imu]\nnoise_from_data = false"),
    ("vibration 0.3 m/s^2", lambda d, s: add_vibration(d, 0.3, s), "[imu]\nnoise_from_data = false"),
    ("gyro scale +1 %", lambda d, s: scale_gyro(d, 0.01), "[smoother]\nestimate_gyro_scale = false"),
    ("gyro scale -2 %", lambda d, s: scale_gyro(d, -0.02), "[smoother]\nestimate_gyro_scale = false"),
    ("gyro scale +3 %", lambda d, s: scale_gyro(d, 0.03), "[smoother]\nestimate_gyro_scale = false"),
    ("fixes 0.1 s late", lambda d, s: shift_fix_times(d, 0.1), ANTENNA_OFF),
    ("fixes 0.2 s late", lambda d, s: shift_fix_times(d, 0.2), ANTENNA_OFF),
    ("fixes 0.3 s early", lambda d, s: shift_fix_times(d, -0.3), ANTENNA_OFF),
    ("fixes 1 s late", lambda d, s: shift_fix_times(d, 1.0), ANTENNA_OFF),
    ("arm [-1.5, 0, 0] m", lambda d, s: None, ANTENNA_OFF),
    ("arm [2, 0.5, 1] m", lambda d, s: None, ANTENNA_OFF),
    ("IMU clock +2000 ppm", lambda d, s: run_imu_clock_off(d, 2000.0), ANTENNA_OFF),
    ("IMU clock -1000 ppm", lambda d, s: run_imu_clock_off(d, -1000.0), ANTENNA_OFF),
]  # fmt: skip
ARMS = {"arm [-1.5, 0, 0] m": (-1.5, 0.0, 0.0), "arm [2, 0.5, 1] m": (2.0, 0.5, 1.0)}


def _write(folder: Path, seed: int, arm: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> None:
    profile = CarProfile(steps=[(10, 8, 15.0)], turns=FIVE_TURNS, gamma=lambda t: 0 * t)
    write_drive(folder, profile, 280.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                gnss_rate=1.0, seed=seed, lever_arm=arm)  # fmt: skip


def _run(folder: Path, method: str, off: str = "") -> tuple[float, float, list[str]]:
    """(outage RMS, RMS / reported sigma, fgins's warnings) of one run."""
    text = (folder / "cfg.toml").read_text()
    if off:
        section = off.split("\n")[0]
        # Into the section where the simulator's file has it (TOML has one table per name).
        text = text.replace(section, off, 1) if section in text else f"{text}\n{off}\n"
    config = folder / "run.toml"
    config.write_text(text)
    dataset = fgins.load(folder / "imu.csv", folder / "gnss.csv", config=config, vehicle="car")
    track = fgins.smooth(dataset, method, gnss_outage=OUTAGES, progress=False)
    rms, sigma = outage_rms_and_sigma(track, folder, OUTAGES)
    return rms, rms / sigma, list(track.info.get("fit_warnings", []))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="1,2")
    parser.add_argument("--method", default="batch", choices=["batch", "isam2", "ekf", "ekf-rts", "ukf"])
    parser.add_argument("--cases", default="", help="only the rows whose label holds one of these words")
    args = parser.parse_args()
    wanted = [word for word in args.cases.split(",") if word]
    cases = [case for case in CASES if not wanted or any(word in case[0] for word in wanted)]
    seeds = [int(s) for s in args.seeds.split(",")]
    warnings.simplefilter("ignore")  # fgins's warnings are read from the run's info instead
    started = time.perf_counter()
    print(f"fgins bench_sensor_errors: independent car sim, {args.method}, seeds {seeds}, "
          f"outages {OUTAGES}")  # fmt: skip
    print(f"{'error':<20} {'seed':>4} {'true m':>7} {'on m':>6} {'on/true':>7} {'on err/sig':>10} "
          f"{'off m':>6} {'off/true':>8} {'off err/sig':>11}  fgins said")  # fmt: skip
    with tempfile.TemporaryDirectory() as scratch:
        for seed in seeds:
            folder = Path(scratch) / f"seed{seed}"
            _write(folder, seed)
            true_rms, true_ratio, _ = _run(folder, args.method)
            print(f"{'true sensors':<20} {seed:>4} {true_rms:7.2f} {'':>6} {'':>7} {true_ratio:10.2f}")
            for label, make, off in cases:
                _write(folder, seed, ARMS.get(label, (0.0, 0.0, 0.0)))
                make(folder, seed)
                on_rms, on_ratio, said = _run(folder, args.method)
                off_rms, off_ratio, _ = _run(folder, args.method, off)
                note = next((w for w in said if w.startswith(("imu:", "GNSS"))), "")
                print(f"{label:<20} {seed:>4} {true_rms:7.2f} {on_rms:6.2f} {on_rms / true_rms:7.2f} "
                      f"{on_ratio:10.2f} {off_rms:6.2f} {off_rms / true_rms:8.2f} {off_ratio:11.2f}  "
                      f"{note[:70]}")  # fmt: skip
    print(f"benchmark wall time {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
