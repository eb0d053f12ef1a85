"""GNSS stamped late on flights of an independent simulator (tests/flight_sim.py).

A fixed-wing in coordinated turns at one speed: an antenna along the body's x axis and fixes
stamped late give the same positions and velocities (the velocity's lag is the centripetal
acceleration times the delay, an arm's the yaw rate times the arm), so the check says
"cannot tell apart". Its estimate is first order in the delay: fixes and velocities 0.5 s
late read as +0.2 s at the start and +0.66 s at the end, "two clocks", and the drive was put
onto the receiver's clock: every output time 0.5 s (12-30 m) from the IMU's, position NEES
1,300-9,300, said as "corrected". Two clocks are now taken only where they fit better than
the offset alone. A Kalman baseline that cannot follow velocities that late must say so.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import fgins

sys.path.insert(0, str(Path(__file__).parent))
from flight_sim import FixedWing, write_flight

OUTAGE = (90.0, 130.0)


def _flight(folder: Path, frame: str, speed: float, heading: float, late_s: float) -> fgins.Dataset:
    rate = 9.8 * np.tan(np.radians(30)) / speed
    motion = FixedWing(
        speed=speed, heading0_deg=heading,
        turns=[(70, 110, 4, rate), (140, 170, 4, -0.7 * rate)],
        climbs=[(20, 45, 5, np.radians(5)), (90, 120, 5, np.radians(-4))],
    )  # fmt: skip
    write_flight(folder, motion, 220.0, seed=3, frame=frame, gnss_rate=1.0, vehicle="aircraft")
    if late_s:
        fixes = pd.read_csv(folder / "gnss.csv")
        fixes["time"] += late_s
        fixes.to_csv(folder / "gnss.csv", index=False, float_format="%.10f")
    return fgins.load(folder)


def _scores(track, folder: Path) -> tuple[float, float]:
    """Horizontal RMS inside the outage and position NEES over the flight, against the
    truth in the IMU's time."""
    truth = pd.read_csv(folder / "truth.csv")
    t = track.t
    true = np.column_stack([np.interp(t, truth["time"], truth[c]) for c in ("east", "north", "up")])
    error = track.position - true
    inside = (t >= OUTAGE[0]) & (t < OUTAGE[1])
    variance = np.stack([track.position_cov[:, i, i] for i in range(3)], -1)
    return (
        float(np.sqrt(np.mean(np.sum(error[inside, :2] ** 2, 1)))),
        float(np.mean(np.sum(error**2 / variance, 1) / 3)),
    )


@pytest.mark.parametrize("frame, speed, heading", [("flu", 25.0, 30.0), ("frd", 60.0, 200.0)])
def test_a_fixed_wing_with_fixes_late_keeps_the_imu_clock(tmp_path, frame, speed, heading):
    on_time = _scores(fgins.smooth(_flight(tmp_path / "a", frame, speed, heading, 0.0), "batch",
                                   gnss_outage=[OUTAGE]), tmp_path / "a")[0]  # fmt: skip
    track = fgins.smooth(_flight(tmp_path / "b", frame, speed, heading, 0.5), "batch", gnss_outage=[OUTAGE])
    rms, nees = _scores(track, tmp_path / "b")
    said = [w for w in track.info["fit_warnings"]
            if w.startswith(("GNSS time", "GNSS lever arm")) and "corrected" in w]  # fmt: skip
    assert len(said) == 1 and "receiver's clock" not in said[0], track.info["fit_warnings"]
    # The offset is found to ~0.01 s (1 Hz fixes, 1 m sigma): 0.25-0.6 m along the track at
    # 25-60 m/s, in the reported sigmas (fgins.corrections.add_time_offset_uncertainty).
    assert rms < 1.5 * on_time + 0.02 * speed + 0.1 and nees < 2.5, (rms, on_time, nees)
    # As fixes moved back by about the delay, or as an antenna about that far behind
    moved = track.info.get("gnss_time_offset_corrected_s")
    arm = track.info.get("gnss_lever_arm_corrected_m")
    assert (moved is not None and abs(moved + 0.5) < 0.05) or (
        arm is not None and abs(arm[0] + 0.5 * speed) < 0.1 * speed
    ), (moved, arm)


@pytest.mark.parametrize("method", ["ekf-rts", "ekf"])
def test_a_kalman_baseline_that_cannot_follow_late_velocities_says_so(tmp_path, method):
    """Velocities 0.5 s late in 30 deg banked turns are 2.8 m/s off (sigma 0.1): the filter
    follows neither them nor the fixes, and its Huber kernel held the median NIS under the
    limit (EKF+RTS 5.7 m inside the outage with sigmas for 0.15 m, unsaid)."""
    track = fgins.smooth(_flight(tmp_path, "flu", 25.0, 30.0, 0.5), method, gnss_outage=[OUTAGE])
    rms, nees = _scores(track, tmp_path)
    notes = [w for w in track.info.get("fit_warnings", [])
             if w.startswith(f"{method}: ") or (w.startswith("GNSS") and "corrected" in w)]  # fmt: skip
    assert nees < 3.0 or notes, (rms, nees, track.info.get("fit_warnings"))
