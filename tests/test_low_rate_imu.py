"""Fixes faster than a low-rate IMU (a 2-10 Hz IMU, as u-blox ESF-MEAS or a phone's, with
5-20 Hz fixes): every fix is a keyframe, so keyframes cut the IMU's intervals, several per
interval. A held sample is a specific force fixed in the axes at its interval's start; each
cut piece after the first had it applied again in its own turned axes, a sideways push of
w * lead * f in every turn. An outside tester's 2 Hz IMU with 10 Hz fixes: 3.7x worse inside
outages than with 1 Hz fixes, at z 5-7; 20 Hz RTK fixes beside a 10 Hz IMU 6-7x worse than
10 Hz ones, z 2.8-4. More fixes must not make the answer worse or its sigmas dishonest.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pytest

import fgins

sys.path.insert(0, str(Path(__file__).parent))
from independent_sim import FIVE_TURNS, INDUSTRIAL, CarProfile, write_drive

OUTAGE = (95.0, 125.0)


def _outage_rms_and_z(folder: Path, imu_rate: float, gnss_rate: float, method: str) -> tuple[float, float]:
    import pandas as pd
    import pymap3d

    profile = CarProfile(steps=[(0.0, 10.0, 12.0)], turns=FIVE_TURNS, gamma=lambda t: 0 * t)
    write_drive(folder, profile, 200.0, grade=INDUSTRIAL, imu_rate=imu_rate, jitter=0.0,
                gnss_rate=gnss_rate, seed=3, sigma_h=0.3, sigma_u=0.5)  # fmt: skip
    dataset = fgins.load([folder / "imu.csv", folder / "gnss.csv"], config=folder / "cfg.toml", vehicle="car")
    config = fgins.configure(dataset, folder / "cfg.toml", vehicle="car")
    track = fgins.smooth(dataset, method, config=config, gnss_outage=[OUTAGE])
    truth = pd.read_csv(folder / "truth.csv")
    frame = track.to_dataframe()
    east, north, _ = pymap3d.geodetic2enu(frame["lat"], frame["lon"], frame["alt"], 45.0, 10.0, 100.0)
    t = frame["time"].to_numpy()
    inside = (t >= dataset.t0 + OUTAGE[0]) & (t < dataset.t0 + OUTAGE[1])
    error = np.column_stack([east - np.interp(t, truth["time"], truth["east"]),
                             north - np.interp(t, truth["time"], truth["north"])])[inside]  # fmt: skip
    sigma = np.sqrt(np.column_stack([track.position_cov[inside, 0, 0], track.position_cov[inside, 1, 1]]))
    return float(np.sqrt(np.mean(np.sum(error**2, 1)))), float(np.sqrt(np.mean((error / sigma) ** 2)))


@pytest.mark.parametrize("imu_rate, gnss_rate, method", [(2.0, 10.0, "batch"), (5.0, 20.0, "ekf-rts")])
def test_fixes_faster_than_the_imu_are_no_worse_than_fewer(tmp_path, imu_rate, gnss_rate, method):
    fast_rms, fast_z = _outage_rms_and_z(tmp_path / "fast", imu_rate, gnss_rate, method)
    slow_rms, slow_z = _outage_rms_and_z(tmp_path / "slow", imu_rate, 1.0, method)
    assert fast_rms < 1.3 * slow_rms + 0.05, (fast_rms, slow_rms)
    assert fast_z < 2.5, (fast_z, slow_z)


def test_an_imu_that_changes_rate_is_not_a_run_of_gaps(tmp_path):
    """An IMU logged at 100 Hz, then at 25 Hz (every sample there): its 25 Hz intervals are
    4 of the median period. They had been called gaps (3,750 of them), bridged with inflated
    noise and left unconverted: 2.8-6.7x worse inside outages (outside tester). The change is
    said, each part integrated at its own rate."""
    import pandas as pd

    profile = CarProfile(steps=[(0.0, 10.0, 12.0)], turns=FIVE_TURNS, gamma=lambda t: 0 * t)
    results = {}
    for name in ("steady", "changed"):
        folder = tmp_path / name
        write_drive(folder, profile, 200.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                    gnss_rate=1.0, seed=4, sigma_h=0.3, sigma_u=0.5)  # fmt: skip
        if name == "changed":
            imu = pd.read_csv(folder / "imu.csv")
            keep = (imu["time"] < 100.0) | (np.arange(len(imu)) % 4 == 0)
            imu[keep].to_csv(folder / "imu.csv", index=False, float_format="%.10g")
        dataset = fgins.load([folder / "imu.csv", folder / "gnss.csv"], config=folder / "cfg.toml", vehicle="car")
        config = fgins.configure(dataset, folder / "cfg.toml", vehicle="car")
        track = fgins.smooth(dataset, "batch", config=config, gnss_outage=[(120.0, 150.0)])
        truth = pd.read_csv(folder / "truth.csv")
        inside = (track.t >= dataset.t0 + 120.0) & (track.t < dataset.t0 + 150.0)
        error = track.position[inside, :2] - np.column_stack(
            [np.interp(track.t[inside], truth["time"], truth[c]) for c in ("east", "north")]
        )
        sigma = np.sqrt(np.column_stack([track.position_cov[inside, 0, 0], track.position_cov[inside, 1, 1]]))
        results[name] = (float(np.sqrt(np.mean(np.sum(error**2, 1)))), float(np.sqrt(np.mean((error / sigma) ** 2))))
        if name == "changed":
            assert not any("IMU gap" in w for w in dataset.warnings), dataset.warnings
            assert any(re.search(r"100 -> 25 Hz at t-t_imu0 = (9[6-9]|10[0-4]) s", w) for w in dataset.warnings), dataset.warnings
    (changed, z), (steady, _) = results["changed"], results["steady"]
    assert changed < 1.5 * steady + 0.05 and z < 2.5, results


def test_a_plain_mean_imu_is_integrated_as_such(tmp_path):
    """A 2 Hz IMU whose samples are the plain means of its readings over the interval to
    the next (a decimating filter, no sculling compensation): given as "held" (increments in
    the interval's start axes) it lacks w dt / 2 x f in turns, about 1 m off at 0.5 m fixes at
    z 2.4-5.5 (outside tester); as ``sample_timing = "mean"`` it is as good as instant
    samples of the same drive."""
    import pandas as pd

    profile = CarProfile(steps=[(0.0, 10.0, 12.0)], turns=FIVE_TURNS, gamma=lambda t: 0 * t)
    folder = tmp_path / "fine"
    write_drive(folder, profile, 200.0, grade=INDUSTRIAL, imu_rate=128.0, jitter=0.0,
                gnss_rate=1.0, seed=5, sigma_h=0.3, sigma_u=0.5)  # fmt: skip
    fine = pd.read_csv(folder / "imu.csv")
    columns = [c for c in fine.columns if c != "time"]
    blocks = (len(fine) - 1) // 64
    means = fine[columns].to_numpy()[: blocks * 64].reshape(blocks, 64, len(columns)).mean(axis=1)
    results = {}
    for timing in ("mean", "held", "instant"):
        case = tmp_path / timing
        case.mkdir()
        (case / "gnss.csv").write_bytes((folder / "gnss.csv").read_bytes())
        if timing == "instant":
            imu = fine.iloc[::64]
        else:
            imu = pd.DataFrame(means, columns=columns)
            imu.insert(0, "time", fine["time"].to_numpy()[: blocks * 64 : 64])
        imu.to_csv(case / "imu.csv", index=False, float_format="%.10g")
        config = (folder / "cfg.toml").read_text().replace("[imu]", f'[imu]\nsample_timing = "{timing}"', 1)
        config = re.sub(r"rate_hz = [0-9.]+", "rate_hz = 2", config)
        (case / "cfg.toml").write_text(config)
        dataset = fgins.load([case / "imu.csv", case / "gnss.csv"], config=case / "cfg.toml", vehicle="car")
        track = fgins.smooth(dataset, "batch", config=fgins.configure(dataset, case / "cfg.toml", vehicle="car"),
                             gnss_outage=[OUTAGE])  # fmt: skip
        truth = pd.read_csv(folder / "truth.csv")
        inside = (track.t >= dataset.t0 + OUTAGE[0]) & (track.t < dataset.t0 + OUTAGE[1])
        error = track.position[inside, :2] - np.column_stack(
            [np.interp(track.t[inside], truth["time"], truth[c]) for c in ("east", "north")]
        )
        results[timing] = float(np.sqrt(np.mean(np.sum(error**2, 1))))
    # measured: mean 0.32 m, held 2.05 m, instant 0.95 m (2 Hz instants miss the turns between)
    assert results["mean"] < 1.5 * results["instant"] + 0.05, results
    assert results["held"] > 2.0 * results["mean"], results  # the increments' model is not a mean's
