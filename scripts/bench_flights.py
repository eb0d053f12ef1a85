#!/usr/bin/env python3
"""Batch against EKF+RTS and the forward EKF on flights of an independent simulator.

Flights from ``tests/flight_sim.py`` (shares no code with ``fgins.sim``): a fixed-wing at 25
or 60 m/s that climbs and flies two banked coordinated turns (bank 20-45 deg), or a multirotor
that flies sideways and yaws on its own; FLU or FRD axes; GNSS at 1 or 0.2 Hz, with or without
velocity; constant turn-on biases; one 30-60 s outage that starts 5 s into the first turn
(where the heading, unobservable in straight flight, is only just being resolved). For each
flight: horizontal RMS inside the outage against the simulator's truth for batch, EKF+RTS and
the forward EKF, the ratios batch/EKF+RTS and batch/EKF from the same run, and each smoother's
position NEES over the run (~1 for honest sigmas); then the RMS pooled over all flights.

EKF+RTS relinearised about its smoothed states from session 40 on; before, its one linear
pass left it 2.3-6.9 m off with NEES 5-70 on such flights (pooled 1.39 m against the
batch's 0.74 m over 96 flights).

With ``--late S`` every fix (position and velocity) is stamped S s late (a receiver's or
logger's latency) and the batch is also run on the true stamps in the same run: the
``batch/on-time`` column is what the latency costs after fgins's antenna and clock check
(session 41: a fixed-wing's 0.5 s had been taken for two clocks, 10-30 m off).

    python scripts/bench_flights.py [--kinds fw25,fw60,mr] [--frames flu,frd] [--rates 1,0.2]
                                    [--velocity yes,no] [--seeds 1,2,3] [--late 0.5]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
import pandas as pd
import pymap3d

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

from flight_sim import FixedWing, Multirotor, write_flight  # noqa: E402

import fgins  # noqa: E402

METHODS = ("batch", "ekf-rts", "ekf")
ORIGIN = (47.0, 8.0, 400.0)  # write_flight's default origin


def flight(kind: str, seed: int):
    """The motion, its duration (s) and its outage window, drawn from ``seed``."""
    rng = np.random.default_rng(seed + 100)
    heading = float(rng.uniform(0, 360))
    if kind.startswith("fw"):
        speed = float(kind[2:])
        rate = 9.8 * np.tan(np.radians(rng.uniform(20, 45))) / speed
        turn = float(rng.uniform(60, 90))
        motion = FixedWing(
            speed=speed, heading0_deg=heading,
            turns=[(turn, turn + 40, 4, rate), (turn + 70, turn + 100, 4, -0.7 * rate)],
            climbs=[(20, 45, 5, np.radians(5)), (turn + 20, turn + 50, 5, np.radians(-4))],
        )  # fmt: skip
        start = turn + 5
        return motion, 260.0, (start, start + float(rng.choice([30, 45, 60])))
    moves = [(6, 6, [0, 0, 10]), (18, 10, [*rng.uniform(-40, 40, 2), 0]),
             (32, 8, [*rng.uniform(-30, 30, 2), 3]), (46, 12, [*rng.uniform(-40, 40, 2), -2]),
             (64, 10, [*rng.uniform(-20, 20, 2), 0]), (80, 10, [*rng.uniform(-30, 30, 2), 0])]  # fmt: skip
    yaws = [(12, 5, np.radians(rng.uniform(-150, 150))), (36, 6, np.radians(rng.uniform(-150, 150))),
            (66, 6, np.radians(rng.uniform(-90, 90)))]  # fmt: skip
    return Multirotor(heading0_deg=heading, moves=moves, yaws=yaws), 110.0, (40.0, 40.0 + float(rng.choice([30, 40])))


def scores(track: fgins.Trajectory, truth: pd.DataFrame, window: tuple[float, float]) -> tuple[float, float]:
    """Horizontal RMS inside ``window`` and position NEES over the run."""
    frame = track.to_dataframe()
    estimate = np.column_stack(pymap3d.geodetic2enu(frame["lat"], frame["lon"], frame["alt"], *ORIGIN))
    true = np.column_stack(pymap3d.geodetic2enu(truth["lat"], truth["lon"], truth["alt"], *ORIGIN))
    t = frame["time"].to_numpy()
    error = estimate - np.column_stack([np.interp(t, truth["time"], true[:, i]) for i in range(3)])
    inside = (t >= window[0]) & (t < window[1])
    sigma = frame[["std_east", "std_north", "std_up"]].to_numpy()
    rms = float(np.sqrt(np.mean(np.sum(error[inside, :2] ** 2, axis=1))))
    return rms, float(np.mean(np.sum((error / sigma) ** 2, axis=1) / 3))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kinds", default="fw25,fw60,mr", help="fw<speed m/s> and/or mr")
    parser.add_argument("--frames", default="flu,frd")
    parser.add_argument("--rates", default="1,0.2", help="GNSS rates (Hz)")
    parser.add_argument("--velocity", default="yes,no", help="GNSS velocity given: yes and/or no")
    parser.add_argument("--seeds", default="1,2")
    parser.add_argument("--late", type=float, default=0.0, help="stamp every fix this many s late")
    args = parser.parse_args()
    print(f"{'flight':24} {'batch m':>8} {'rts m':>7} {'ekf m':>8} {'batch/rts':>9} "
          f"{'batch/ekf':>9} {'NEES batch':>10} {'NEES rts':>8}"
          + (f" {'on-time m':>9} {'batch/on-time':>13}" if args.late else ""))  # fmt: skip
    pooled: dict[str, list[float]] = {m: [] for m in METHODS}
    with tempfile.TemporaryDirectory() as scratch:
        for kind in args.kinds.split(","):
            for frame in args.frames.split(","):
                for rate in (float(r) for r in args.rates.split(",")):
                    for velocity in args.velocity.split(","):
                        for seed in (int(s) for s in args.seeds.split(",")):
                            name = f"{kind}_{frame}_{rate:g}Hz_{'vel' if velocity == 'yes' else 'novel'}_{seed}"
                            folder = Path(scratch) / name
                            motion, duration, window = flight(kind, seed)
                            write_flight(folder, motion, duration, seed=seed, frame=frame, gnss_rate=rate,
                                         vehicle="uav" if kind == "mr" else "aircraft")  # fmt: skip
                            if velocity != "yes":
                                gnss = pd.read_csv(folder / "gnss.csv")
                                gnss.drop(columns=["vel_east", "vel_north", "vel_up"]).to_csv(
                                    folder / "gnss.csv", index=False
                                )
                            truth = pd.read_csv(folder / "truth.csv")
                            on_time = ""
                            if args.late:
                                track = fgins.smooth(fgins.load(folder), "batch", gnss_outage=[window])
                                on_time_rms = scores(track, truth, window)[0]
                                gnss = pd.read_csv(folder / "gnss.csv")
                                gnss["time"] += args.late
                                gnss.to_csv(folder / "gnss.csv", index=False, float_format="%.10f")
                            dataset = fgins.load(folder)
                            result = {m: scores(fgins.smooth(dataset, m, gnss_outage=[window]), truth, window)
                                      for m in METHODS}  # fmt: skip
                            for m in METHODS:
                                pooled[m].append(result[m][0])
                            (b, nb), (r, nr), (e, _) = (result[m] for m in METHODS)
                            if args.late:
                                on_time = f" {on_time_rms:9.2f} {b / on_time_rms:13.2f}"
                            print(f"{name:24} {b:8.2f} {r:7.2f} {e:8.2f} {b / r:9.2f} {b / e:9.2f} "
                                  f"{nb:10.2f} {nr:8.2f}{on_time}", flush=True)  # fmt: skip
    rms = {m: float(np.sqrt(np.mean(np.square(v)))) for m, v in pooled.items()}
    print(f"\npooled outage RMS over {len(pooled['batch'])} flights: batch {rms['batch']:.2f} m, "
          f"EKF+RTS {rms['ekf-rts']:.2f} m, EKF {rms['ekf']:.2f} m; batch/EKF+RTS "
          f"{rms['batch'] / rms['ekf-rts']:.2f}, batch/EKF {rms['batch'] / rms['ekf']:.2f}")  # fmt: skip


if __name__ == "__main__":
    main()
