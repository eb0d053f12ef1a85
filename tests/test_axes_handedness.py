"""An accelerometer whose axes are a mirror image of the gyro's (one column's sign flipped,
or two columns swapped, in a logger's mapping) is refused (fgins.io.axes_handedness).

Before, nothing saw it: the norm is gravity's, the mean points up, the gyro turns with the
track; the pipeline "corrected" the mounting (yaw 179 deg), the clocks and the sigmas around
it and wrote a track 264 m off the truth with exit code 0 (accel_y negated on fgins's urban
car; accel_x and accel_y swapped: 55 m). Drives from two simulators (fgins's and the
independent one of tests/independent_sim.py), FLU and FRD axes, a turned mounting, with and
without receiver velocities: every mirror refused, every right-handed original read.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import fgins
from fgins.io.axes_handedness import MIRRORED_RESIDUAL_RATIO, handedness_fit
from fgins.sim.scenarios import SCENARIOS
from fgins.sim.writer import write_sim_dir

sys.path.insert(0, str(Path(__file__).parent))
from independent_sim import FIVE_TURNS, INDUSTRIAL, CarProfile, write_drive

MIRRORS = {
    "accel_x negated": lambda imu: imu.assign(accel_x=-imu["accel_x"]),
    "accel_y negated": lambda imu: imu.assign(accel_y=-imu["accel_y"]),
    "accel_x and accel_y swapped": lambda imu: imu.assign(accel_x=imu["accel_y"], accel_y=imu["accel_x"]),
}

DRIVES = [
    ("car-urban", {}, 1),
    ("highway", {"body_frame": "frd", "mounting_rpy_deg": [20.0, -10.0, 35.0], "write_mounting": True}, 2),
    ("car-urban", {"gnss_velocity": False}, 3),
    ("mems-car-pdop", {}, 4),
    ("independent", {}, 5),
    # Fixes 5 s apart: no window was dense enough before, and every mirror went unchecked.
    ("independent", {"gnss_rate": 0.2}, 6),
    ("independent", {"gnss_rate": 0.2}, 7),
]


def _write(folder: Path, scenario: str, options: dict, seed: int) -> None:
    if scenario == "independent":  # fixes only (no velocities), 1 m sigma, stop-and-go with turns
        profile = CarProfile(steps=[(10, 8, 12.0), (70, 6, -8.0), (110, 5, 10.0)], turns=FIVE_TURNS,
                             gamma=lambda t: 0 * t)  # fmt: skip
        write_drive(folder, profile, 200.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                    gnss_rate=options.get("gnss_rate", 1.0), seed=seed)  # fmt: skip
        (folder / "cfg.toml").unlink()
    else:
        write_sim_dir(SCENARIOS[scenario](seed=seed, duration_s=200.0, **options), folder)


@pytest.mark.parametrize(("scenario", "options", "seed"), DRIVES)
def test_a_mirrored_accelerometer_is_refused_and_the_original_read(tmp_path, scenario, options, seed):
    _write(tmp_path, scenario, options, seed)
    fgins.load(tmp_path)  # right-handed: read
    original = pd.read_csv(tmp_path / "imu.csv")
    for name, mirror in MIRRORS.items():
        mirror(original).to_csv(tmp_path / "imu.csv", index=False, float_format="%.10e")
        with pytest.raises(fgins.InputError, match="accelerometer's axes are a mirror image") as refused:
            fgins.load(tmp_path)
        assert "\n" not in str(refused.value), name


def test_kitti_is_right_handed_by_a_wide_margin():
    """The real drive: the right-handed fit leaves far less unexplained than the mirrored
    one, and its mirror image is told as surely."""
    from dataclasses import replace

    from fgins.geodesy import lla_to_enu

    dataset = fgins.load("demo:kitti")
    enu = lla_to_enu(dataset.gnss.lla, dataset.origin)
    right, mirrored, _ = handedness_fit(dataset.imu, dataset.gnss, enu)
    assert mirrored > 4.0 * right
    flipped = replace(dataset.imu, accel=dataset.imu.accel * np.array([1.0, -1.0, 1.0]))
    right, mirrored, correlation = handedness_fit(flipped, dataset.gnss, enu)
    assert mirrored < MIRRORED_RESIDUAL_RATIO * right and correlation > 0.8


@pytest.mark.parametrize(("frame", "seed"), [("flu", 1), ("frd", 2), ("flu", 6)])
def test_a_flight_with_accel_x_negated_is_said_and_the_original_is_not(tmp_path, frame, seed):
    """An aircraft's banked turns put no force across its body, so the track test above
    cannot judge it (an independent simulator's flight with accel_x negated ran to 99 m inside
    an outage, "corrected" as an antenna 17 m away, fix sigmas 3.3x, a bias 55 prior sigmas
    out, with exit code 0). In 3-D the accelerometer, carried by the gyro, fits the fixes'
    specific force through one rotation only with the column mistake undone (3.2-4.3x better
    here; right-handed flights 0.5-1.2): said, whatever the vehicle when it is not a car.
    A coordinated flight's accel_y negated (no side force to flip) fits both ways, 1.0."""
    from flight_sim import write_flight

    from fgins.geodesy import lla_to_enu, normal_gravity
    from fgins.io.axes_handedness import MIRRORED_3D_RATIO, handedness_fit_3d
    from fgins.tests.test_flights_independent import _fixed_wing

    write_flight(tmp_path, _fixed_wing(30.0, 50.0), 150.0, seed=seed, frame=frame, vehicle="aircraft")
    original = pd.read_csv(tmp_path / "imu.csv")
    for vehicle in (None, "aircraft"):
        right = fgins.load(tmp_path, vehicle=vehicle)
        assert not [w for w in right.warnings if "axes look wrong" in w], right.warnings
    MIRRORS["accel_x negated"](original).to_csv(tmp_path / "imu.csv", index=False, float_format="%.10e")
    for vehicle in (None, "aircraft", "uav"):
        flipped = fgins.load(tmp_path, vehicle=vehicle)
        said = [w for w in flipped.warnings if "the IMU's axes look wrong" in w]
        assert len(said) == 1 and "only with accel_x negated" in said[0], flipped.warnings
    enu = lla_to_enu(flipped.gnss.lla, flipped.origin)
    gravity = normal_gravity(flipped.origin.lat)
    as_given, mistakes = handedness_fit_3d(flipped.imu, flipped.gnss, enu, gravity)
    assert as_given > MIRRORED_3D_RATIO * mistakes["accel_x negated"]
    assert mistakes["accel_x negated"] == min(mistakes.values())


def test_the_rotation_fit_never_ends_above_its_kabsch_start():
    """A window of steady flight or a taxi (the specific force barely turning) leaves the
    rotation and the gyro-drift term nearly inseparable: the undamped Gauss-Newton stepped
    from 0.36 to 12 m/s^2 there, and right-handed flights were called mirrored (an outside
    tester: 2 of 6 taxi-and-takeoff seeds, a 720 deg roll). Here 300 such windows, random
    rotations and noise: the refined fit is never worse than the closed-form start (54 of
    300 were before)."""
    from fgins.geodesy import skew_batch, so3_exp
    from fgins.io.axes_handedness import _rotation_fit

    tau = np.linspace(-15, 15, 30)
    for seed in range(300):
        rng = np.random.default_rng(seed)
        force = np.array([0.3, -0.2, 9.8]) + rng.normal(0, 0.05, (30, 3)) * rng.uniform(0.1, 3)
        specific = force @ so3_exp(rng.normal(0, 1, 3)).T + rng.normal(0, 0.3, (30, 3))
        start = _rotation_fit(specific, force, tau, so3_exp, skew_batch, iterations=0)
        assert _rotation_fit(specific, force, tau, so3_exp, skew_batch) <= start * (1 + 1e-9)
    # Where the force does turn, the refinement still fits the drift Kabsch cannot.
    rng = np.random.default_rng(1)
    force = np.column_stack([3 * np.sin(tau / 4), 3 * np.cos(tau / 3), 9.8 + np.sin(tau / 5)])
    drifted = np.einsum("nij,nj->ni", so3_exp(np.outer(tau, [0.0, 0.0, 0.004])), force)
    specific = drifted + rng.normal(0, 0.01, drifted.shape)
    start = _rotation_fit(specific, force, tau, so3_exp, skew_batch, iterations=0)
    assert _rotation_fit(specific, force, tau, so3_exp, skew_batch) < 0.1 * start


# A drive that reverses with turns: the track's direction is the body's opposite there, so a
# turn taken reversing reads as a mirrored one in track axes (an outside red team's car: 30 s
# forward, 90 s reversing at 4.5 m/s round three bends, then forward; refused as "a mirror
# image", 0.08, by every method). Each stretch between stops has its own fitted sign now.
REVERSING = {
    "reverse round bends": CarProfile(
        steps=[(10, 4, 8.0), (40, 4, -8.0), (50, 4, -4.5), (140, 4, 4.5), (150, 5, 8.0)],
        turns=[(20, 30, 2, 0.1), (60, 72, 2, 0.15), (85, 97, 2, -0.15), (110, 122, 2, 0.15), (200, 208, 2, -0.1)],
        gamma=lambda t: 0 * t,
    ),
    "reverse out of a driveway": CarProfile(
        steps=[(10, 3, -4.0), (35, 3, 4.0), (45, 15, 20.0)],
        turns=[(15, 27, 2, 0.15), (120, 160, 10, 0.01), (220, 260, 10, -0.01)],
        gamma=lambda t: 0 * t,
    ),
    "reverse 15 s in a town drive": CarProfile(
        steps=[(10, 5, 8.0), (60, 5, -8.0), (75, 3, -3.0), (90, 3, 3.0), (105, 5, 8.0)],
        turns=[(30, 40, 3, 0.1), (140, 150, 3, -0.12), (200, 210, 3, 0.1)],
        gamma=lambda t: 0 * t,
    ),
}


@pytest.mark.parametrize("seed", [1, 3])
@pytest.mark.parametrize("name", list(REVERSING))
def test_a_drive_that_reverses_round_bends_is_read_and_its_mirror_not_passed_as_right(tmp_path, name, seed):
    """Right-handed: read, whatever the share of reversing. Mirrored: refused wherever the
    drive's stretches can tell (a forward stretch with both turns and speed changes); a drive
    whose reversing alone holds the turns cannot tell, and is not judged either way."""
    write_drive(tmp_path, REVERSING[name], 300.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0, gnss_rate=1.0,
                seed=seed)  # fmt: skip
    (tmp_path / "cfg.toml").unlink()
    fgins.load(tmp_path, vehicle="car")
    if name != "reverse 15 s in a town drive":
        return
    original = pd.read_csv(tmp_path / "imu.csv")
    MIRRORS["accel_y negated"](original).to_csv(tmp_path / "imu.csv", index=False, float_format="%.10e")
    with pytest.raises(fgins.InputError, match="accelerometer's axes are a mirror image"):
        fgins.load(tmp_path, vehicle="car")


@pytest.mark.parametrize("seed", [1, 2])
def test_at_0_2_hz_a_flipped_imu_axis_or_a_gyro_in_deg_per_s_is_refused(tmp_path, seed):
    """The turn check's 10 s windows took courses 5 s apart: at 0.2 Hz one fix interval,
    all left out, so an IMU read with its y axis flipped (the gyro turning against the
    track) or a gyro in deg/s was smoothed with exit code 0. Its windows now span four fix
    intervals."""
    profile = CarProfile(steps=[(10, 5, 10.0), (100, 5, -5.0), (150, 5, 5.0)],
                         turns=[(40, 50, 3, 0.15), (120, 130, 3, -0.15), (200, 210, 3, 0.15)], gamma=lambda t: 0 * t)  # fmt: skip
    write_drive(tmp_path, profile, 300.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0, gnss_rate=0.2, seed=seed)
    fgins.load(tmp_path, vehicle="car")  # as written: read
    original = pd.read_csv(tmp_path / "imu.csv")
    flipped_y = original.assign(accel_y=-original["accel_y"], gyro_x=-original["gyro_x"], gyro_z=-original["gyro_z"])
    in_deg = original.assign(**{f"gyro_{a}": np.degrees(original[f"gyro_{a}"]) for a in "xyz"})
    for changed, message in ((flipped_y, "gyro turns against the GNSS track"), (in_deg, "deg/s")):
        changed.to_csv(tmp_path / "imu.csv", index=False, float_format="%.10e")
        with pytest.raises(fgins.InputError, match=message):
            fgins.load(tmp_path, vehicle="car")


GYRO_AND_BOTH_MISTAKES = {
    "gyro_x negated": lambda o: o.assign(gyro_x=-o.gyro_x),
    "gyro x/y swapped": lambda o: o.assign(gyro_x=o.gyro_y, gyro_y=o.gyro_x),
    "x/y swapped in both sensors": lambda o: o.assign(gyro_x=o.gyro_y, gyro_y=o.gyro_x,
                                                      accel_x=o.accel_y, accel_y=o.accel_x),
}  # fmt: skip


@pytest.mark.parametrize("mistake", list(GYRO_AND_BOTH_MISTAKES))
@pytest.mark.parametrize(("vehicle", "frame", "seed"), [("aircraft", "flu", 3), ("aircraft", "frd", 4),
                                                        ("uav", "flu", 5)])  # fmt: skip
def test_a_gyro_or_left_handed_imu_mistake_is_refused_or_said(tmp_path, vehicle, frame, seed, mistake):
    """The gyro's columns mistaken, or both sensors' alike (a left-handed IMU): the 3-D fit
    undoes these too (an independent simulator's multirotor with x/y swapped in both ran to
    103 m inside an outage at exit 0, 214 s, the blame on the fixes' sigmas; an aircraft
    with the gyro's x/y swapped EKF+RTS 207 km at exit 0). An aircraft's banked turns make
    it certain (13-16x): an error; a multirotor's motion at least a warning (3.2-6.5x); the
    data as given never."""
    from flight_sim import Multirotor, write_flight

    if vehicle == "aircraft":
        from fgins.tests.test_flights_independent import _fixed_wing

        motion = _fixed_wing(30.0, 50.0)
    else:
        # brisk moves tilt it enough to tell (gentle ones, 10 s for 40 m, fit alike: 1.0-1.3x)
        motion = Multirotor(heading0_deg=40.0,
                            moves=[(5, 4, [0, 0, 15]), (20, 5, [60, -30, 0]), (40, 5, [-70, 40, 5]),
                                   (60, 5, [50, 50, 0]), (80, 5, [-40, -60, 0]), (100, 5, [30, 40, -5])],
                            yaws=[(30, 3, np.radians(90)), (70, 3, np.radians(-120))])  # fmt: skip
    folder = write_flight(tmp_path, motion, 150.0, seed=seed, frame=frame, vehicle=vehicle)
    original = pd.read_csv(folder / "imu.csv")
    right = fgins.load(folder, vehicle=vehicle)
    assert not [w for w in right.warnings if "axes look wrong" in w], right.warnings
    GYRO_AND_BOTH_MISTAKES[mistake](original).to_csv(folder / "imu.csv", index=False, float_format="%.10e")
    if vehicle == "aircraft":
        with pytest.raises(fgins.InputError, match=r"the IMU's axes look wrong: .* fits the fixes"):
            fgins.load(folder, vehicle=vehicle)
        return
    try:
        said = [w for w in fgins.load(folder, vehicle=vehicle).warnings if "axes look wrong" in w]
    except fgins.InputError as error:  # certain enough to refuse: as good
        said = [str(error)]
    assert len(said) == 1 and "check the column mapping" in said[0], said
