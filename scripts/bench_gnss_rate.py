#!/usr/bin/env python3
"""Does batch use fast GNSS as well as the Kalman smoother? Outage bridging against GNSS rate.

Drives from the independent car simulator of the tests (``tests/independent_sim.py``: shares
no code with ``fgins.sim``; industrial MEMS IMU, hilly road, fixes off the IMU's sample grid),
GNSS at 1/2/5/10 Hz, one 60 s outage; for each rate and seed: horizontal RMS inside the outage
against the simulator's truth for batch, EKF+RTS and the forward EKF, and the ratios
batch/EKF+RTS and batch/EKF measured in the same run. A keyframe floor that drops fixes (the
0.2 s floor before session 18 used half of a 10 Hz receiver's) shows as batch/EKF+RTS > 1 at
the fast rates only.

With ``--imu-turned rfu`` (x right, y forward) or ``backward``, each drive is also read by
an IMU turned so, with no mounting given (the mounting, handedness and turn checks must find
it from the drive at every rate, 0.2 Hz included); the table then adds each method's outage
RMS turned over straight, from the same run (~1 expected).

    python scripts/bench_gnss_rate.py [--rates 1,2,5,10] [--seeds 1,2,3,4] [--duration 200]
                                      [--imu-turned rfu]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

from independent_sim import INDUSTRIAL, hilly_drive, horizontal_errors, turn_imu_axes, write_drive  # noqa: E402

import fgins  # noqa: E402

OUTAGE = (100.0, 160.0)
METHODS = ("batch", "ekf-rts", "ekf")
ORIGIN = (45.0, 10.0, 100.0)  # write_drive's default origin


def outage_rms(track: fgins.Trajectory, folder: Path) -> float:
    t, error = horizontal_errors(track, folder, ORIGIN)
    inside = (t >= OUTAGE[0]) & (t < OUTAGE[1])
    return float(np.sqrt(np.mean(error[inside] ** 2)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rates", default="1,2,5,10", help="GNSS rates (Hz)")
    parser.add_argument("--seeds", default="1,2,3,4")
    parser.add_argument("--duration", type=float, default=200.0, help="drive length (s)")
    parser.add_argument("--imu-rate", type=float, default=100.0)
    parser.add_argument("--gnss-offset", type=float, default=0.25,
                        help="first fix's offset from the IMU's sample grid, in IMU periods")
    parser.add_argument("--imu-turned", choices=["rfu", "backward"], default=None,
                        help="also smooth each drive read by an IMU turned so, no mounting given")
    args = parser.parse_args()
    rates = [float(r) for r in args.rates.split(",")]
    seeds = [int(s) for s in args.seeds.split(",")]
    print(f"fgins bench_gnss_rate: independent car sim, industrial MEMS at {args.imu_rate:g} Hz, "
          f"{args.duration:g} s, outage {OUTAGE[0]:g}-{OUTAGE[1]:g} s, seeds {seeds}")  # fmt: skip
    header = (f"{'GNSS Hz':>7} {'seed':>4} {'batch m':>8} {'ekf-rts m':>9} {'ekf m':>7} "
              f"{'batch/rts':>9} {'batch/ekf':>9} {'batch s':>7} {'rts s':>6}"
              + (f" {'turned/straight: batch':>22} {'ekf-rts':>7}" if args.imu_turned else ""))  # fmt: skip
    print(header)
    summary: dict[float, list[float]] = {}
    with tempfile.TemporaryDirectory() as scratch:
        for rate in rates:
            for seed in seeds:
                folder = Path(scratch) / f"r{rate:g}_s{seed}"
                # Fixes off the IMU's sample grid (a receiver's own clock): a quarter period.
                write_drive(folder, hilly_drive(), args.duration, grade=INDUSTRIAL,
                            imu_rate=args.imu_rate, jitter=0.0, gnss_rate=rate, seed=seed,
                            gnss_t0=args.gnss_offset / args.imu_rate)  # fmt: skip
                dataset = fgins.load(folder / "imu.csv", folder / "gnss.csv",
                                     config=folder / "cfg.toml", vehicle="car")  # fmt: skip
                rms, wall = {}, {}
                for method in METHODS:
                    started = time.perf_counter()
                    track = fgins.smooth(dataset, method, gnss_outage=[OUTAGE])
                    wall[method] = time.perf_counter() - started
                    rms[method] = outage_rms(track, folder)
                ratio = rms["batch"] / rms["ekf-rts"]
                summary.setdefault(rate, []).append(ratio)
                turned = ""
                if args.imu_turned:
                    turn_imu_axes(folder, args.imu_turned)
                    dataset = fgins.load(folder / "imu.csv", folder / "gnss.csv",
                                         config=folder / "cfg.toml", vehicle="car")  # fmt: skip
                    with warnings.catch_warnings():  # the adopted mounting's line, expected
                        warnings.simplefilter("ignore", fgins.FginsWarning)
                        share = {m: outage_rms(fgins.smooth(dataset, m, gnss_outage=[OUTAGE]), folder) / rms[m]
                                 for m in ("batch", "ekf-rts")}  # fmt: skip
                    turned = f" {share['batch']:22.2f} {share['ekf-rts']:7.2f}"
                print(f"{rate:7g} {seed:4d} {rms['batch']:8.3f} {rms['ekf-rts']:9.3f} "
                      f"{rms['ekf']:7.3f} {ratio:9.2f} {rms['batch'] / rms['ekf']:9.2f} "
                      f"{wall['batch']:7.2f} {wall['ekf-rts']:6.2f}{turned}", flush=True)  # fmt: skip
    print("\nbatch/EKF+RTS inside the outage, by GNSS rate (median, max over seeds):")
    for rate, ratios in summary.items():
        print(f"  {rate:5g} Hz: median {np.median(ratios):.2f}, max {np.max(ratios):.2f}")


if __name__ == "__main__":
    main()
