#!/usr/bin/env python3
"""What a receiver's GNSS velocities can do, and what fgins makes of it: outages with each
correction on and off, against the same drive with clean velocities, in one run.

fgins's simulated urban car and highway (velocity sigma configured 0.2 / their own), each
written clean and then with one thing real receivers do to their velocities:

- noise beyond the configured sigma (a city's Doppler: 0.5-1 m/s; ``[gnss] sigma_from_fit``
  scales the velocity sigmas to their scatter);
- outliers (multipath: 3-5 % of the velocities 5-10 m/s off; the fixes' kernel, Huber 4,
  on every velocity factor);
- a delay against the positions (a velocity from the positions' differences or smoothed:
  0.5-1 s; ``[gnss] time_offset_from_data`` finds it in the antenna check and moves the
  velocities back);

and fgins's aircraft with its IMU on a clock 100-300 ppm off the receiver's (the check's
drift, read through the velocities as well as the positions).

For each: batch's horizontal RMS inside the outages against the simulator's truth with the
correction on (the default) and off, and both as ratios to the clean drive measured in the
same run ("off" for outliers is a kernel-free run: ``huber_k = 0`` takes the kernel off the
positions too).

    python scripts/bench_gnss_velocity.py [--seeds 1,2] [--method batch]
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

from drive_fixtures import add_velocity_outliers, sim_outage_rms_and_sigma  # noqa: E402
from independent_sim import run_imu_clock_off  # noqa: E402

import fgins  # noqa: E402
from fgins.sim.scenarios import SCENARIOS  # noqa: E402
from fgins.sim.writer import write_sim_dir  # noqa: E402

OUTAGES = {
    "car-urban": [(90.0, 120.0), (195.0, 255.0)],
    "highway": [(70.0, 100.0), (150.0, 200.0)],
    "aircraft-ekf": [(500.0, 560.0)],  # its own outage
}


def _noise(size: float) -> Callable[[Path, int], None]:
    def apply(folder: Path, seed: int) -> None:
        fixes = pd.read_csv(folder / "gnss.csv")
        rng = np.random.default_rng(seed)
        for column in ("vel_east", "vel_north", "vel_up"):
            fixes[column] += rng.normal(0.0, size, len(fixes))
        fixes.to_csv(folder / "gnss.csv", index=False, float_format="%.6f")

    return apply


def _outliers(fraction: float, size: float) -> Callable[[Path, int], None]:
    return lambda folder, seed: add_velocity_outliers(folder, fraction, size, seed)


def _delay(lag: float, smoothed: bool) -> Callable[[Path, int], None]:
    """Velocities ``lag`` late: smoothed, interpolated between the epochs' own (at 0.5 s the
    mean of two, as from the positions' differences); else a pure delay (a Doppler velocity
    reported late: the truth ``lag`` earlier, with the epoch's own noise)."""

    def apply(folder: Path, seed: int) -> None:
        fixes = pd.read_csv(folder / "gnss.csv")
        truth = pd.read_csv(folder / "truth.csv")
        t = fixes["time"]
        for column in ("vel_east", "vel_north", "vel_up"):
            if smoothed:
                fixes[column] = np.interp(t - lag, t, fixes[column])
            else:
                own = np.interp(t, truth["time"], truth[column])
                fixes[column] += np.interp(t - lag, truth["time"], truth[column]) - own
        fixes.to_csv(folder / "gnss.csv", index=False, float_format="%.6f")

    return apply


def _clock(ppm: float) -> Callable[[Path, int], None]:
    return lambda folder, seed: run_imu_clock_off(folder, ppm)


# (scenario, what, how, the switch that turns fgins's answer off, in [gnss])
CASES = [
    ("car-urban", "velocity noise 0.5 m/s", _noise(0.5), "sigma_from_fit = false"),
    ("car-urban", "velocity noise 1.0 m/s", _noise(1.0), "sigma_from_fit = false"),
    ("highway", "velocity noise 1.0 m/s", _noise(1.0), "sigma_from_fit = false"),
    ("car-urban", "outliers 3 % of 5 m/s", _outliers(0.03, 5.0), "huber_k = 0"),
    ("highway", "outliers 4 % of 8 m/s", _outliers(0.04, 8.0), "huber_k = 0"),
    ("car-urban", "velocities 0.5 s late, smoothed", _delay(0.5, True), "time_offset_from_data = false"),
    ("highway", "velocities 0.5 s late, smoothed", _delay(0.5, True), "time_offset_from_data = false"),
    ("car-urban", "velocities 1.0 s late, smoothed", _delay(1.0, True), "time_offset_from_data = false"),
    ("car-urban", "velocities 0.5 s late", _delay(0.5, False), "time_offset_from_data = false"),
    ("aircraft-ekf", "velocities 0.5 s late", _delay(0.5, False), "time_offset_from_data = false"),
    ("aircraft-ekf", "velocities 0.5 s late, smoothed", _delay(0.5, True), "time_offset_from_data = false"),
    ("aircraft-ekf", "IMU clock +100 ppm", _clock(100.0), "time_offset_from_data = false"),
    ("aircraft-ekf", "IMU clock -100 ppm", _clock(-100.0), "time_offset_from_data = false"),
    ("aircraft-ekf", "IMU clock -300 ppm", _clock(-300.0), "time_offset_from_data = false"),
]


def _outage_rms(folder: Path, scenario: str, method: str, switch: str = "") -> tuple[float, list[str]]:
    config = folder / "config.toml"
    text = config.read_text()
    if switch:
        config.write_text(text.replace("[gnss]\n", f"[gnss]\n{switch}\n", 1))
    try:
        outages = OUTAGES[scenario]
        window = None if scenario == "aircraft-ekf" else outages
        track = fgins.smooth(fgins.load(folder), method, gnss_outage=window, progress=False)
    finally:
        config.write_text(text)
    said = [w for w in track.info.get("fit_warnings", []) if w.startswith("GNSS")]
    return sim_outage_rms_and_sigma(track, folder, outages)[0], said


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="1,2")
    parser.add_argument("--method", default="batch", choices=["batch", "isam2"])
    args = parser.parse_args()
    warnings.simplefilter("ignore")
    seeds = [int(s) for s in args.seeds.split(",")]
    started = time.perf_counter()
    print(f"fgins bench_gnss_velocity: {args.method}, seeds {seeds}")
    print(f"{'case':44s} seed  clean m   on m  on/clean  off m  off/clean  fgins said")
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            clean: dict[str, tuple[Path, float]] = {}
            for scenario, what, apply, switch in CASES:
                if scenario not in clean:
                    folder = Path(tmp) / f"{scenario}-{seed}"
                    write_sim_dir(SCENARIOS[scenario](seed=seed), folder)
                    clean[scenario] = (folder, _outage_rms(folder, scenario, args.method)[0])
                source, reference = clean[scenario]
                folder = Path(tmp) / "case"
                shutil.rmtree(folder, ignore_errors=True)
                shutil.copytree(source, folder)
                apply(folder, seed)
                on, said = _outage_rms(folder, scenario, args.method)
                off, _ = _outage_rms(folder, scenario, args.method, switch)
                print(
                    f"{scenario + ': ' + what:44s} {seed:4d} {reference:8.2f} {on:6.2f} "
                    f"{on / reference:8.2f} {off:6.2f} {off / reference:9.2f}  "
                    f"{(said[0][:70] if said else '-')}",
                    flush=True,
                )
    print(f"benchmark wall time {time.perf_counter() - started:.0f} s")


if __name__ == "__main__":
    main()
