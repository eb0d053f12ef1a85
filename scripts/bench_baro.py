#!/usr/bin/env python3
"""A barometer far from the origin: does it hold the height through an outage in a turn?

fgins's simulated aircraft (``aircraft-ekf``: ~100 m/s, 25-32 km from its first fix by the
60 s GNSS outage at 500-560 s, turning through it) is given a 10 Hz barometer: the ISA
pressure of the true ellipsoidal height (pymap3d) with 0.5 m of white noise. Every method
runs with and without it in the same process; the table gives the vertical RMS inside the
outage and the ratio with / without (below 1: the barometer helps).

The navigation frame's tangent plane falls d^2 / 2r below the surface (80 m 32 km out), a
barometer's height stays with it. Measured with this script, seeds 1 / 2 / 3, with / without
ratio: taking that fall from the fixes' chord across the outage (the code before session
27, e9c794b) made the barometer worse than none: batch 18.5 / 1.07 / 7.04 (1.48 / 1.04 /
1.88 m), forward EKF 1.88 / 2.43 / 6.54, planar filter 14 / 65 / 25 (75 m). Each solver
taking it at its own positions: batch 1.97 / 0.62 / 0.96 (0.16 / 0.60 / 0.26 m; seed 1's
0.16 m against 0.08 m is the barometer's own noise and bias walk), EKF+RTS alike, forward
EKF 0.33 / 0.24 / 0.51, planar filter 0.18 / 1.54 / 1.00.

    python scripts/bench_baro.py [--seeds 1,2,3] [--methods batch,isam2,ekf-rts,ekf,planar-kf]
"""

from __future__ import annotations

import argparse
import time
import warnings
from dataclasses import replace

import numpy as np


def isa_pressure(height_m: np.ndarray) -> np.ndarray:
    """ICAO standard atmosphere (troposphere): 101325 Pa, 288.15 K, 6.5 K/km."""
    return 101325.0 * (1.0 - 0.0065 * height_m / 288.15) ** (9.80665 / (287.05287 * 0.0065))


def with_barometer(run, seed: int):
    """The run's dataset with a 10 Hz barometer of the true ellipsoidal height."""
    import pymap3d

    from fgins.datatypes import BaroData

    truth, origin = run.truth, run.dataset.origin
    every = max(1, round(0.1 / float(np.median(np.diff(truth.t)))))
    t = truth.t[::every]
    east, north, up = truth.position[::every].T
    height = pymap3d.enu2geodetic(east, north, up, origin.lat, origin.lon, origin.alt)[2]
    noise = np.random.default_rng(seed).normal(0.0, 0.5, len(t))
    return replace(run.dataset, baro=BaroData(t=t, pressure=isa_pressure(height + noise)))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="1,2,3")
    parser.add_argument("--methods", default="batch,isam2,ekf-rts,ekf,planar-kf")
    parser.add_argument("--duration", type=float, default=720.0, help="s (the scenario's 720)")
    args = parser.parse_args()
    from fgins.config import config_for_dataset
    from fgins.pipeline import run_method
    from fgins.sim.scenarios import SCENARIOS

    warnings.simplefilter("ignore")
    methods = args.methods.split(",")
    print(f"{'seed':>4s} {'method':10s} {'with m':>7s} {'without m':>9s} {'ratio':>6s} {'s':>5s}")
    for seed in (int(s) for s in args.seeds.split(",")):
        run = SCENARIOS["aircraft-ekf"](seed=seed, duration_s=args.duration)
        ((start, end),) = run.outages
        config = config_for_dataset(run.dataset)
        barometer = with_barometer(run, seed)
        for method in methods:
            rms = []
            started = time.perf_counter()
            for dataset in (barometer, run.dataset):
                track = run_method(dataset, config, method, progress=False)
                inside = (track.t - dataset.t0 >= start) & (track.t - dataset.t0 < end)
                error = track.position[inside, 2] - run.truth.at(track.t[inside])[:, 2]
                rms.append(float(np.sqrt(np.mean(error**2))))
            print(
                f"{seed:4d} {method:10s} {rms[0]:7.2f} {rms[1]:9.2f} {rms[0] / rms[1]:6.2f} "
                f"{time.perf_counter() - started:5.1f}",
                flush=True,
            )


if __name__ == "__main__":
    main()
