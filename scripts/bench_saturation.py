"""IMU saturation: the same flights read by a sensor with a limited range, against the full one.

An independent simulator's flights (tests/flight_sim.py): a multirotor pirouetting at ~800
deg/s read by a +-250 / +-300 deg/s gyro, and a fixed-wing in 62 deg banks read by a +-2 g
accelerometer, each with an outage over the clipped motion. fgins finds the clipped runs
(:func:`fgins.io.imu_checks.find_saturation`) and bridges them as gaps. Printed per case and
method: horizontal RMS inside the outage and at the fixes, the outage error over its reported
sigma (z, ~1 when honest), and clipped / full-range ratios measured in the same run.

    python scripts/bench_saturation.py [--methods batch,ekf-rts]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

from flight_sim import FixedWing, Multirotor, write_flight  # noqa: E402

import fgins  # noqa: E402


def _pirouettes() -> Multirotor:
    moves = [(4, 6, [0, 0, 10]), (12, 10, [40, 10, 0]), (28, 12, [-30, 40, 0]),
             (44, 10, [10, -40, 5]), (58, 8, [20, 0, -5])]  # fmt: skip
    yaws = [(16, 2.0, np.radians(720)), (34, 2.0, -np.radians(720)), (50, 2.0, np.radians(720))]
    return Multirotor(heading0_deg=40.0, moves=moves, yaws=yaws)


def _banks() -> FixedWing:
    rate = 9.8 * np.tan(np.radians(62)) / 30.0
    return FixedWing(speed=30.0, heading0_deg=80.0, turns=[(30, 45, 3, rate), (80, 92, 3, -rate)])


# name, motion, duration s, vehicle, GNSS Hz, clipped columns, limit, outage
CASES = [
    ("multirotor, gyro +-250 deg/s", _pirouettes, 70.0, "uav", 5.0, "gyro", np.radians(250.0), (36.0, 56.0)),
    ("multirotor, gyro +-300 deg/s", _pirouettes, 70.0, "uav", 5.0, "gyro", np.radians(300.0), (36.0, 56.0)),
    ("fixed-wing, accel +-2 g", _banks, 130.0, "aircraft", 1.0, "accel", 2 * 9.80665, (70.0, 100.0)),
]  # fmt: skip


def _score(track, folder: Path, outage: tuple[float, float]) -> tuple[float, float, float]:
    truth = pd.read_csv(folder / "truth.csv")
    rows = np.clip(np.searchsorted(truth["time"].to_numpy(), track.t - 1e-9), 0, len(truth) - 1)
    diff = track.position[:, :2] - truth[["east", "north"]].to_numpy()[rows]
    var = np.stack([track.position_cov[:, 0, 0], track.position_cov[:, 1, 1]], -1)
    inside = (track.t >= outage[0]) & (track.t < outage[1])
    rms_in = float(np.sqrt(np.mean(np.sum(diff[inside] ** 2, 1))))
    rms_out = float(np.sqrt(np.mean(np.sum(diff[~inside] ** 2, 1))))
    z = float(np.sqrt(np.mean(np.sum(diff[inside] ** 2 / var[inside], 1) / 2)))
    return rms_in, rms_out, z


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--methods", default="batch,ekf-rts")
    args = parser.parse_args()
    methods = args.methods.split(",")
    print("| case | method | outage RMS full / clipped (m) | ratio | fixes RMS full / clipped (m) | z full / clipped |")
    print("|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        for name, motion, duration, vehicle, rate, kind, limit, outage in CASES:
            folder = write_flight(Path(tmp) / "full", motion(), duration, seed=11, vehicle=vehicle,
                                  gnss_rate=rate)  # fmt: skip
            clipped = Path(tmp) / "clipped"
            clipped.mkdir(exist_ok=True)
            for file in folder.iterdir():
                (clipped / file.name).write_bytes(file.read_bytes())
            imu = pd.read_csv(folder / "imu.csv")
            for axis in "xyz":
                imu[f"{kind}_{axis}"] = imu[f"{kind}_{axis}"].clip(-limit, limit)
            imu.to_csv(clipped / "imu.csv", index=False, float_format="%.10e")
            for method in methods:
                scores = []
                for source in (folder, clipped):
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore", fgins.FginsWarning)
                        dataset = fgins.load(source, vehicle=vehicle)
                        track = fgins.smooth(dataset, method, gnss_outage=[outage], progress=False)
                    scores.append(_score(track, source, outage))
                (full_in, full_out, full_z), (clip_in, clip_out, clip_z) = scores
                print(f"| {name} | {method} | {full_in:.2f} / {clip_in:.2f} | {clip_in / full_in:.2f} | "
                      f"{full_out:.2f} / {clip_out:.2f} | {full_z:.2f} / {clip_z:.2f} |")  # fmt: skip


if __name__ == "__main__":
    main()
