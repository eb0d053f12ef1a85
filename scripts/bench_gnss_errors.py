#!/usr/bin/env python3
"""GNSS error classes the sigmas must cover: slow (Gauss-Markov) receiver errors and an RTK
fix on wrong integers, on the independent simulator's car (tests/independent_sim.py).

(a) Slow errors: 1 Hz fixes whose errors are white or Gauss-Markov (30 s), 3 m / 5 m, with
    their marginal sigmas stated (honest per fix). Horizontal z = RMS error / RMS reported
    sigma, with fgins's slow-error term (fgins.correlated_fixes) and, as the baseline in the
    same run, without it (the output's covariance less the term it added).
(b) An RTK fix on wrong integers: 1.5 cm fixes with 2 cm/s velocities, 20-30 s of them
    0.5 m off. Error inside the false stretch with the fault exclusion, and with it off
    (``[gnss] fault_exclusion = false``, the kernel alone) in the same run.

Prints markdown tables; run from the repository: ``python scripts/bench_gnss_errors.py``.
"""

from __future__ import annotations

import sys
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pymap3d

import fgins

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from independent_sim import (
    FIVE_TURNS,
    INDUSTRIAL,
    CarProfile,
    horizontal_errors,
    move_fixes,
    write_drive,
    write_rtk_drive,
)

ORIGIN = (45.0, 10.0, 100.0)


def _gauss_markov(n: int, tau_s: float, sigma: np.ndarray, rng) -> np.ndarray:
    phi = np.exp(-1.0 / tau_s)
    out = np.empty((n, 3))
    out[0] = rng.normal(0.0, sigma)
    for k in range(1, n):
        out[k] = phi * out[k - 1] + rng.normal(0.0, sigma * np.sqrt(1.0 - phi**2))
    return out


def slow_errors(folder: Path, seed: int, slow: bool) -> dict[str, float]:
    profile = CarProfile(steps=[(0.0, 10.0, 12.0)], turns=FIVE_TURNS, gamma=lambda t: 0 * t)
    write_drive(folder, profile, 280.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                gnss_rate=1.0, seed=seed, sigma_h=3.0, sigma_u=5.0)  # fmt: skip
    fixes, truth = pd.read_csv(folder / "gnss.csv"), pd.read_csv(folder / "truth.csv")
    rng = np.random.default_rng(100 + seed)
    sigma = np.array([3.0, 3.0, 5.0])
    errors = _gauss_markov(len(fixes), 30.0, sigma, rng) if slow else rng.normal(0.0, sigma, (len(fixes), 3))
    at = np.column_stack([np.interp(fixes["time"], truth["time"], truth[k]) for k in ("east", "north", "up")])
    fixes["lat"], fixes["lon"], fixes["alt"] = pymap3d.enu2geodetic(*(at + errors).T, *ORIGIN)
    fixes.to_csv(folder / "gnss.csv", index=False, float_format="%.10f")
    dataset = fgins.load(folder / "imu.csv", folder / "gnss.csv", config=folder / "cfg.toml", vehicle="car")
    track = fgins.smooth(dataset, "batch")
    t, error = horizontal_errors(track, folder, ORIGIN)
    keep = t > t[0] + 10.0
    variance = 0.5 * (track.position_cov[:, 0, 0] + track.position_cov[:, 1, 1])
    added = track.info.get("gnss_slow_error_sigma_m", [0.0, 0.0])[0] ** 2
    rms = float(np.sqrt(np.mean(error[keep] ** 2)))
    return {
        "rms": rms,
        "sigma": float(np.sqrt(np.mean(variance[keep]))),
        "z": rms / float(np.sqrt(np.mean(variance[keep]))),
        "z_without": rms / float(np.sqrt(np.mean(variance[keep] - added))),
    }


def rtk_false_fix(folder: Path, seed: int, seconds: int) -> tuple[float, float, int]:
    write_rtk_drive(folder, seed)
    move_fixes(folder, [70.0 + i for i in range(seconds)], (0.4, -0.3, 0.2))
    out = []
    for extra in ("", "\n[gnss]\nfault_exclusion = false\n"):
        (folder / "run.toml").write_text((folder / "cfg.toml").read_text() + extra)
        dataset = fgins.load(folder / "imu.csv", folder / "gnss.csv", config=folder / "run.toml", vehicle="car")
        track = fgins.smooth(dataset, "batch")
        t, error = horizontal_errors(track, folder, ORIGIN)
        during = (t >= 70.0) & (t < 70.0 + seconds)
        out.append((float(np.sqrt(np.mean(error[during] ** 2))), int(track.info.get("gnss_excluded_count", 0))))
    return out[0][0], out[1][0], out[0][1]


def main() -> None:
    warnings.simplefilter("ignore", fgins.FginsWarning)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        print("(a) slow receiver errors, horizontal, batch")
        print("| errors | seed | RMS (m) | sigma (m) | z | z without the slow-error term | ratio |")
        print("|---|---|---|---|---|---|---|")
        for slow in (False, True):
            for seed in (1, 2, 3):
                r = slow_errors(root / f"slow-{slow}-{seed}", seed, slow)
                print(f"| {'Gauss-Markov 30 s' if slow else 'white'} | {seed} | {r['rms']:.2f} | "
                      f"{r['sigma']:.2f} | {r['z']:.2f} | {r['z_without']:.2f} | "
                      f"{r['z'] / r['z_without']:.2f} |")  # fmt: skip
        print("\n(b) RTK fix on wrong integers (0.5 m off), error inside it, batch")
        print("| seed | seconds | with fault exclusion (m) | fixes left out | kernel alone (m) | ratio |")
        print("|---|---|---|---|---|---|")
        for seed, seconds in ((1, 30), (2, 20), (3, 15)):
            with_exclusion, kernel, left_out = rtk_false_fix(root / f"rtk-{seed}", seed, seconds)
            print(f"| {seed} | {seconds} | {with_exclusion:.3f} | {left_out} | {kernel:.3f} | "
                  f"{with_exclusion / kernel:.2f} |")  # fmt: skip


if __name__ == "__main__":
    main()
