"""An IMU preset of a better grade than the sensor (fgins.corrections.noise_from_data).

The white noise a sensor reads at rest replaces a configured one far below it; the bias
terms cannot be read at rest, but they go with the grade: a sensor whose noise is that of
another grade gets that grade's bias instability and turn-on bias where they are larger
than configured. Checked on the independent simulator's consumer car, whose biases walk
(10 deg/h, 0.1 mg), configured as a navigation or tactical IMU: before, the batch stopped
with "diverged" and EKF+RTS ran 1.4 km off (navigation); now every method bridges the
outages as with the right numbers. A vibrating industrial IMU (accelerometer noise 20-40
times its datasheet's, its gyro clean) keeps its grade's biases: cars vibrate, they do not
change grade.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

import fgins

sys.path.insert(0, str(Path(__file__).parent))
from independent_sim import FIVE_TURNS, CarProfile, outage_rms_and_sigma, write_drive

CONSUMER_WALKING = dict(preset="consumer-mems", gyro_arw=0.3, gyro_bi=10.0, gyro_on=1080.0,
                        accel_vrw=0.1, accel_bi=0.1, accel_on=10.0)  # fmt: skip
OUTAGES = [(60.0, 100.0), (175.0, 215.0)]
STEPS = [(10, 8, 12.0), (110, 5, 6.0), (160, 6, -8.0)]


def _smooth(folder: Path, method: str, preset: str | None):
    config = folder / "run.toml"
    config.write_text(f'[imu]\npreset = "{preset}"\n' if preset else (folder / "cfg.toml").read_text())
    dataset = fgins.load(folder / "imu.csv", folder / "gnss.csv", config=config, vehicle="car")
    return fgins.smooth(dataset, method, gnss_outage=OUTAGES)


def _graded(track) -> list[str]:
    return [w for w in track.info.get("fit_warnings", []) if "another grade" in w]


@pytest.mark.parametrize(
    "preset, method, seed",
    [("navigation", "batch", 3), ("navigation", "ekf-rts", 3), ("tactical", "isam2", 7)],
)
def test_a_better_grade_preset_takes_the_grade_the_noise_shows(tmp_path, preset, method, seed):
    profile = CarProfile(steps=STEPS, turns=FIVE_TURNS, gamma=lambda t: 0 * t)
    write_drive(tmp_path, profile, 260.0, grade=CONSUMER_WALKING, imu_rate=100.0, jitter=0.0,
                gnss_rate=1.0, seed=seed)  # fmt: skip
    right = _smooth(tmp_path, method, None)
    assert not _graded(right) and not any("white noise" in w for w in right.info.get("fit_warnings", []))
    wrong = _smooth(tmp_path, method, preset)
    said = _graded(wrong)
    assert len(said) == 1 and "nearest preset's gyro bias instability 10 deg/h" in said[0], wrong.info
    assert "noise_from_data = false" in said[0]
    expected = outage_rms_and_sigma(right, tmp_path, OUTAGES)[0]
    got, sigma = outage_rms_and_sigma(wrong, tmp_path, OUTAGES)
    assert got <= 1.15 * expected + 0.05, (expected, got)
    assert 0.5 * got < sigma < 2.0 * got, (got, sigma)  # honest sigmas
