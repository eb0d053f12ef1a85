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

import pytest

import fgins

sys.path.insert(0, str(Path(__file__).parent))
from independent_sim import (
    FIVE_TURNS,
    INDUSTRIAL,
    CarProfile,
    outage_rms_and_sigma,
    shift_fix_times,
    write_drive,
)

OUTAGES = [(60.0, 105.0), (175.0, 215.0)]
STOP_AND_GO = [(10, 8, 12.0), (70, 6, -8.0), (110, 5, 10.0), (160, 6, -12.0), (172, 6, 9.0)]


def _drive(folder: Path, steps, seed: int, shift_s: float = 0.0, arm=(0.0, 0.0, 0.0)) -> None:
    profile = CarProfile(steps=steps, turns=FIVE_TURNS, gamma=lambda t: 0 * t)
    write_drive(folder, profile, 280.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                gnss_rate=1.0, seed=seed, lever_arm=arm)  # fmt: skip
    if shift_s:
        shift_fix_times(folder, shift_s)


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
    assert abs(found - shift) < 0.03, found
    assert _outage_rms(corrected, tmp_path) < 1.2 * true_stamps + 0.05
    kept = _smooth(tmp_path, method, "\n[gnss]\ntime_offset_from_data = false\n")
    named = [w for w in kept.info["fit_warnings"] if w.startswith("GNSS time:")]
    assert len(named) == 1 and f"--time-offset {-found:+.2f}"[:-1] in named[0], named
    assert "gnss_time_offset_corrected_s" not in kept.info
    assert _outage_rms(kept, tmp_path) > 2.0 * true_stamps


@pytest.mark.parametrize("arm, seed", [((-2.0, 0.3, 1.0), 5), ((3.0, -0.5, 0.5), 8)])
def test_an_unconfigured_arm_is_named_and_never_taken_for_a_clock(tmp_path, arm, seed):
    """An antenna 2-3 m from the IMU on a stop-and-go drive: the arm is named (alone, or
    with a time offset as the other reading when 1 m fixes cannot tell them apart), and no
    fix is moved in time."""
    _drive(tmp_path, STOP_AND_GO, seed, arm=arm)
    track = _smooth(tmp_path, outages=None)
    lines = [w for w in track.info.get("fit_warnings", []) if w.startswith("GNSS")]
    assert len(lines) == 1 and lines[0].startswith("GNSS lever arm"), lines
    assert "gnss_time_offset_corrected_s" not in track.info
    assert abs(track.info["gnss_lever_arm_fit_m"][0] - arm[0]) < 0.6


def test_at_one_steady_speed_an_arm_and_a_time_offset_are_both_named(tmp_path):
    _drive(tmp_path, [(10, 8, 15.0)], 6, arm=(-2.0, 0.3, 1.0))
    track = _smooth(tmp_path)
    lines = [w for w in track.info.get("fit_warnings", []) if w.startswith("GNSS")]
    assert len(lines) == 1 and lines[0].startswith("GNSS lever arm or time"), lines
    assert "cannot tell" in lines[0]
    assert "gnss_time_offset_corrected_s" not in track.info


def test_true_stamps_and_arm_are_left_alone(tmp_path):
    _drive(tmp_path, STOP_AND_GO, 7)
    track = _smooth(tmp_path)
    assert not [w for w in track.info.get("fit_warnings", []) if w.startswith("GNSS")]
    assert abs(track.info["gnss_time_offset_fit_s"]) < 5 * track.info["gnss_time_offset_fit_sigma_s"]
