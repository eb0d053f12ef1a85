"""Issue 12 item 8: mounting angles are the IMU's orientation in the vehicle.

The same simulated car drive is fed with its IMU turned inside the car: the IMU readings
(and the antenna lever arm, which is given in IMU axes) are rotated by the mounting, and the
mounting angles are given in the configuration. Every estimator must then reproduce the
unrotated drive; with the mounting left out, the fit must say so.
"""

from __future__ import annotations

import numpy as np
import pytest

from fgins.config import load_config
from fgins.outages import in_windows, outage_mask
from fgins.pipeline import run_method
from fgins.sim.scenarios import SCENARIOS
from fgins.tests.drive_fixtures import turned_imu

WINDOWS = [(50.0, 85.0)]


@pytest.fixture(scope="module")
def drive():
    return SCENARIOS["car-urban"](seed=2, duration_s=140)


def _config(dataset, gnss, rpy, given: bool = True):
    """The run's configuration with the mounting ``rpy``; ``given``: as if from a config
    file (even when zero), else the default nobody gave."""
    from dataclasses import replace

    config = load_config(dataset_imu=dataset.imu_config, dataset_gnss=gnss)
    config.smoother.vehicle = "car"
    config.smoother.imu_to_vehicle_rpy_deg = tuple(float(a) for a in rpy)
    if given:
        keys = config.explicit_smoother_keys | {"imu_to_vehicle_rpy_deg"}
        config = replace(config, explicit_smoother_keys=keys)
    return config


def _rms(trajectory, run, dataset) -> float:
    inside = in_windows(trajectory.t, dataset.t0, WINDOWS)
    error = np.linalg.norm(trajectory.position[:, :2] - run.truth.at(trajectory.t)[:, :2], axis=1)
    return float(np.sqrt(np.mean(error[inside] ** 2)))


@pytest.mark.parametrize("rpy", [(20.0, -10.0, 35.0), (180.0, 0.0, 0.0), (0.0, 0.0, -90.0)])
@pytest.mark.parametrize("method", ["batch", "ekf-rts"])
def test_a_turned_imu_with_its_mounting_reproduces_the_drive(drive, rpy, method):
    reference_dataset, gnss = turned_imu(drive, (0.0, 0.0, 0.0))
    reference = run_method(
        reference_dataset, _config(reference_dataset, gnss, (0, 0, 0)), method,
        gnss_mask=outage_mask(reference_dataset, WINDOWS), progress=False,
    )  # fmt: skip
    dataset, gnss = turned_imu(drive, rpy)
    turned = run_method(
        dataset, _config(dataset, gnss, rpy), method,
        gnss_mask=outage_mask(dataset, WINDOWS), progress=False,
    )  # fmt: skip
    expected, got = _rms(reference, drive, reference_dataset), _rms(turned, drive, dataset)
    assert got <= 1.05 * expected + 0.02, (expected, got)
    assert not turned.info.get("fit_warnings"), turned.info.get("fit_warnings")


@pytest.mark.parametrize(
    "rpy",
    [(20.0, -10.0, 35.0), (0.0, 0.0, 90.0), (0.0, 0.0, 180.0), (180.0, 0.0, -90.0),
     (-90.0, -90.0, 0.0), (30.0, 90.0, 0.0), (0.0, -60.0, 20.0)],
)  # fmt: skip
def test_a_wrong_mounting_is_an_error_that_names_the_mounting_the_data_show(drive, rpy):
    """Given as zero, a mounting whose forward axis is off by >= 35 deg: one line naming the
    mounting the turns show (here the true one, to a degree), before any solve; given that
    mounting, the same drive runs clean. An IMU on its side or on end (the configured forward
    axis vertical: no yaw to compare) ran to "batch LM diverged" with a generic hint."""
    import re

    from fgins.datatypes import InputError
    from fgins.mounting import mounting_rotation

    dataset, gnss = turned_imu(drive, rpy)
    with pytest.raises(InputError, match=r"forward axis.*fits the data") as info:
        run_method(dataset, _config(dataset, gnss, (0, 0, 0)), "ekf", progress=False)
    suggested = [float(v) for v in re.search(r"fits the data: \S+ = \[([^]]+)\]", str(info.value))
                 .group(1).split(",")]  # fmt: skip
    forward_true, forward_fit = mounting_rotation(rpy)[0], mounting_rotation(suggested)[0]
    assert np.degrees(np.arccos(np.clip(forward_true @ forward_fit, -1, 1))) < 2.0
    fitted = run_method(dataset, _config(dataset, gnss, suggested), "batch", progress=False)
    assert not fitted.info.get("fit_warnings"), fitted.info.get("fit_warnings")


@pytest.mark.parametrize(("yaw", "method"), [(7.0, "batch"), (-2.0, "ekf-rts"), (1.0, "batch")])
def test_a_given_mounting_a_few_degrees_off_is_replaced_by_the_one_the_drive_shows(drive, yaw, method):
    """At 15 m/s one degree is 0.26 m/s of lateral velocity the NHC calls zero: an outside
    tester's IMU 15 deg off (a warning then) ran at exit 0 to 6.2 m in outages where the
    right mounting gives 0.25 m, and an independent simulator's car given a yaw 4 deg off
    3.8 m (NEES 24) where the true one gives 0.8 m. A given mounting the turns put more than
    0.5 deg off is refined by a solve with a misalignment state and, where that moves it by
    more than 0.5 deg, replaced and said, for every method; ``mounting_from_data = false``
    keeps the given one (the 5-10 deg warning then), and a right one is left alone."""
    from dataclasses import replace

    right_dataset, right_gnss = turned_imu(drive, (0.0, 0.0, yaw))
    right = run_method(
        right_dataset, _config(right_dataset, right_gnss, (0.0, 0.0, yaw)), method,
        gnss_mask=outage_mask(right_dataset, WINDOWS), progress=False,
    )  # fmt: skip
    assert not any("mounting" in w for w in right.info.get("fit_warnings", [])), right.info
    # The IMU sits turned by `yaw` in the car, the configuration says 0.
    trajectory = run_method(
        right_dataset, _config(right_dataset, right_gnss, (0, 0, 0)), method,
        gnss_mask=outage_mask(right_dataset, WINDOWS), progress=False,
    )  # fmt: skip
    warnings = " ".join(trajectory.info.get("fit_warnings", []))
    assert "configured mounting" in warnings and "does not fit the drive" in warnings, warnings
    expected, got = _rms(right, drive, right_dataset), _rms(trajectory, drive, right_dataset)
    assert got <= 1.25 * expected + 0.05, (expected, got)
    if abs(yaw) < 5.0:
        return
    kept = _config(right_dataset, right_gnss, (0, 0, 0))
    kept = replace(kept, smoother=replace(kept.smoother, mounting_from_data=False))
    as_given = run_method(
        right_dataset, kept, method, gnss_mask=outage_mask(right_dataset, WINDOWS), progress=False
    )
    warnings = " ".join(as_given.info.get("fit_warnings", []))
    assert "forward axis" in warnings and f"{-yaw:+.0f} deg" in warnings, warnings
    assert _rms(as_given, drive, right_dataset) > 2.0 * got


def test_a_mounting_15_deg_off_is_an_error(drive):
    """Beyond 10 deg a given mounting is a mistake to fix (inverted angles, another axis
    convention), not a calibration to refine: an error before any solve."""
    from fgins.datatypes import InputError

    dataset, gnss = turned_imu(drive, (0.0, 0.0, 15.0))
    with pytest.raises(InputError, match=r"forward axis.* -15 deg .*would fight the data"):
        run_method(dataset, _config(dataset, gnss, (0, 0, 0)), "ekf", progress=False)


@pytest.mark.parametrize("seed", [0, 3])
def test_a_mounting_whose_roll_and_pitch_are_left_out_is_said(seed):
    """An outside tester's IMU mounted [5, -3, 45] and given as [0, 0, 45]: the yaw check
    passed, the roll and pitch went unnoticed, +45 % inside outages. Gravity's mean direction
    (roads level on average) now shows the tilt; the right mounting draws nothing."""
    from fgins.mounting import check_mounting

    run = SCENARIOS["car-urban"](seed=seed)
    turned, _ = turned_imu(run, (5.0, -3.0, 45.0))
    note = check_mounting(turned, (0.0, 0.0, 45.0))
    assert note is not None and "up axis" in note and "roll or pitch is off" in note, note
    assert check_mounting(turned, (5.0, -3.0, 45.0)) is None
    assert check_mounting(run.dataset, (0.0, 0.0, 0.0)) is None


def test_forward_axis_from_motion_across_vehicles_and_mountings():
    """Against the simulator's mounting: cars in town, a consumer car with PDOP-biased
    fixes; FLU, FRD and turned IMUs; and KITTI against its configured mounting. A highway's
    gentle curves (no turn above 3 deg/s) or too few turns: no verdict at all."""
    from fgins.config import config_for_dataset
    from fgins.io.kitti import read_kitti
    from fgins.mounting import _forward_axis_from_turns, mounting_yaw_error_deg

    for name, seed in (("car-urban", 3), ("mems-car-pdop", 5)):
        run = SCENARIOS[name](seed=seed, duration_s=200)
        for rpy in ((0.0, 0.0, 0.0), (180.0, 0.0, 0.0), (10.0, 5.0, -120.0)):
            dataset, _ = turned_imu(run, rpy)
            error, turning_s = mounting_yaw_error_deg(dataset, rpy)  # about up
            assert abs(error) < 2.0 and turning_s >= 12, (name, rpy, error, turning_s)
            assert abs(mounting_yaw_error_deg(dataset, (0.0, 0.0, 0.0))[0]) > 5 or rpy[2] == 0
    kitti = read_kitti()
    error, _ = mounting_yaw_error_deg(kitti, config_for_dataset(kitti).smoother.imu_to_vehicle_rpy_deg)
    assert abs(error) < 2.0
    for seed, duration in ((1, 50.0), (4, 200.0), (6, 60.0)):  # 4 and 6 fooled a curve fit
        highway = SCENARIOS["highway"](seed=seed, duration_s=duration)
        assert _forward_axis_from_turns(highway.dataset) is None
        # The heading match (travel against the IMU's heading) gives the right axis or none
        # (the 50-60 s stretches: 10 deg off at 3 sigma before each half had to agree).
        found = mounting_yaw_error_deg(highway.dataset, (0.0, 0.0, 0.0))
        assert found is None or abs(found[0]) < 2.0, (seed, found)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_default_highway_is_no_mounting_error_and_a_turned_imu_on_it_is_found(seed):
    """The default highway (240 s: an accelerating on-ramp and one curve) drew "the forward
    axis lies -15 deg from the configured mounting" on a straight-mounted IMU: v w, the
    forward acceleration and the constant were nearly collinear in the free regression. The
    free fit now says when it cannot tell (its own standard error) and a one-angle fit takes
    over: a verdict within 2 deg of the simulator's mounting, so a turned IMU whose mounting
    is left out is still found on a highway."""
    from fgins.mounting import check_mounting, mounting_yaw_error_deg

    run = SCENARIOS["highway"](seed=seed)
    assert check_mounting(run.dataset, (0.0, 0.0, 0.0)) is None
    found = mounting_yaw_error_deg(run.dataset, (0.0, 0.0, 0.0))
    assert found is not None and abs(found[0]) < 2.0, found
    for rpy in ((0.0, 0.0, 90.0), (180.0, 0.0, -30.0)):
        turned, _ = turned_imu(run, rpy)
        found = mounting_yaw_error_deg(turned, rpy)
        assert found is not None and abs(found[0]) < 2.0, (rpy, found)
        missing = mounting_yaw_error_deg(turned, (0.0, 0.0, 0.0))
        assert missing is not None and abs(abs(missing[0]) - abs(rpy[2])) < 2.0, (rpy, missing)


@pytest.mark.parametrize("given", [True, False])
@pytest.mark.parametrize("roll", [180.0, 90.0])
def test_a_mounting_off_in_roll_alone_is_said_without_blaming_the_constraints(drive, roll, given):
    """The car constraints zero the lateral and the vertical velocity alike, so an IMU
    turned about the forward axis alone (an FRD IMU given no mounting: roll 180) gives the
    unturned drive's solution; the note said "the car constraints bend the fit toward it".
    It now says the roll is off and what it does not change; a pitch left out still blames
    the constraints. With no mounting given at all, nothing was said (outside tester)."""
    from fgins.mounting import check_mounting

    reference_dataset, gnss = turned_imu(drive, (0.0, 0.0, 0.0))
    reference = run_method(
        reference_dataset, _config(reference_dataset, gnss, (0, 0, 0)), "batch",
        gnss_mask=outage_mask(reference_dataset, WINDOWS), progress=False,
    )  # fmt: skip
    dataset, gnss = turned_imu(drive, (roll, 0.0, 0.0))  # zero, given or not: the check's note
    turned = run_method(
        dataset, _config(dataset, gnss, (0, 0, 0), given), "batch",
        gnss_mask=outage_mask(dataset, WINDOWS), progress=False,
    )  # fmt: skip
    expected, got = _rms(reference, drive, reference_dataset), _rms(turned, drive, dataset)
    assert abs(got - expected) <= 0.02 * expected, (expected, got)
    note = " ".join(turned.info.get("fit_warnings", []))
    assert "roll is off" in note and "do not see a roll" in note and "bend" not in note, note
    pitched, _ = turned_imu(drive, (0.0, 6.0, 0.0))
    note = check_mounting(pitched, (0.0, 0.0, 0.0))
    assert note is not None and "bend the fit" in note, note


@pytest.mark.parametrize(
    "rpy",
    [(0.0, 0.0, -90.0), (180.0, 0.0, 35.0), (-90.0, -90.0, 0.0), (0.0, 0.0, 8.0),
     (0.0, 0.0, -0.5)],
)  # fmt: skip
@pytest.mark.parametrize("method", ["batch", "isam2", "ekf-rts"])
def test_a_mounting_nobody_gave_is_taken_from_the_drive(drive, rpy, method):
    """A car IMU in other axes (x right and y forward, upside down and turned, on its side,
    8 deg off, half a degree off: 48 % worse inside the outage, below any check's line) and
    no mounting anywhere: the axes are a convention, not a mistake. The run
    takes the mounting the turns and gravity show, refined by a batch solve's constant
    misalignment state, says so in a warning naming it, and every method matches the IMU
    given its true mounting inside the outage. Before, an error (or, within 10 deg, a
    warning and a solution bent by the constraints)."""
    from fgins.mounting import mounting_rotation

    dataset, gnss = turned_imu(drive, rpy)
    reference = run_method(
        dataset, _config(dataset, gnss, rpy), method,
        gnss_mask=outage_mask(dataset, WINDOWS), progress=False,
    )  # fmt: skip
    adopted = run_method(
        dataset, _config(dataset, gnss, (0, 0, 0), given=False), method,
        gnss_mask=outage_mask(dataset, WINDOWS), progress=False,
    )  # fmt: skip
    notes = [w for w in adopted.info.get("fit_warnings", []) if "no IMU mounting was given" in w]
    assert len(notes) == 1, adopted.info.get("fit_warnings")
    import re

    angles = [float(v) for v in re.search(r"using \S+ = \[([^]]+)\]", notes[0]).group(1).split(",")]
    forward_true, forward_used = mounting_rotation(rpy)[0], mounting_rotation(angles)[0]
    assert np.degrees(np.arccos(np.clip(forward_true @ forward_used, -1, 1))) < 0.5, angles
    expected, got = _rms(reference, drive, dataset), _rms(adopted, drive, dataset)
    assert got <= 1.1 * expected + 0.05, (expected, got)
    # The mounting taken is uncertain, and the solves held it fixed: its sigma is in the
    # output's heading and pitch (outside tester: a highway's heading 0.31 deg off at a
    # reported 0.06, the mounting's 0.14 deg left out).
    sigma = adopted.info["imu_mounting_sigma_deg"]
    assert 0.0 < sigma < 2.0
    widened = adopted.attitude_std_deg[:, 1:] ** 2 - reference.attitude_std_deg[:, 1:] ** 2
    assert np.median(widened) > 0.5 * sigma**2, (np.median(widened, axis=0), sigma)


def test_a_taken_mountings_sigma_widens_heading_and_pitch_only():
    """Closed form: the mounting's variance adds to the heading's and the pitch's, not the
    roll's (the constraints do not see a roll)."""
    from fgins.corrections import add_mounting_uncertainty
    from fgins.datatypes import Origin, Trajectory
    from fgins.geodesy import so3_exp

    rng = np.random.default_rng(3)
    n = 50
    yaw = rng.uniform(-np.pi, np.pi, n)
    rotation = so3_exp(np.column_stack([rng.normal(0, 0.05, n), rng.normal(0, 0.05, n), yaw]))
    covariance = np.tile(np.diag(np.radians([0.2, 0.3, 0.5]) ** 2), (n, 1, 1))
    track = Trajectory(t=np.arange(n, dtype=float), position=np.zeros((n, 3)), velocity=np.zeros((n, 3)),
                       rotation=rotation, origin=Origin(45.0, 10.0, 0.0), attitude_cov=covariance)  # fmt: skip
    before = track.attitude_std_deg ** 2
    add_mounting_uncertainty(track, 0.4)
    added = track.attitude_std_deg ** 2 - before
    np.testing.assert_allclose(added[:, 2], 0.16, rtol=1e-9)  # heading
    np.testing.assert_allclose(added[:, 1], 0.16, rtol=1e-9)  # pitch (the across axis)
    np.testing.assert_allclose(added[:, 0], 0.0, atol=1e-12)  # roll
    assert track.info["imu_mounting_sigma_deg"] == 0.4


@pytest.mark.parametrize("method", ["batch", "ekf-rts"])
def test_a_mounting_taken_from_a_hilly_drive_is_refined_by_the_fit(tmp_path, method):
    """An independent simulator's hilly drive, its IMU x right and y forward, no mounting
    given: the turns' fit alone is 1.2 deg off (1.52 m inside a 40 s outage where the true
    mounting gives 0.23 m); refined by a batch solve's constant misalignment state, the
    mounting is right to a few hundredths of a degree and every method gets the true
    mounting's accuracy."""
    import re
    import sys
    from pathlib import Path

    import fgins

    sys.path.insert(0, str(Path(__file__).parent))
    from independent_sim import (
        INDUSTRIAL,
        hilly_drive,
        horizontal_errors,
        turn_imu_axes,
        write_drive,
    )

    write_drive(tmp_path, hilly_drive(), 300.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                gnss_rate=1.0, seed=3)  # fmt: skip
    turn_imu_axes(tmp_path, "rfu")
    config = tmp_path / "cfg.toml"

    def outage_rms(track) -> float:
        t, error = horizontal_errors(track, tmp_path)
        return float(np.sqrt(np.mean(error[(t >= 110.0) & (t < 150.0)] ** 2)))

    runs = {}
    for label, extra in (("given", "[smoother]\nimu_to_vehicle_rpy_deg = [0, 0, -90]\n"), ("none", "")):
        (tmp_path / f"{label}.toml").write_text(config.read_text() + extra)
        dataset = fgins.load(tmp_path / "imu.csv", tmp_path / "gnss.csv",
                             config=tmp_path / f"{label}.toml", vehicle="car")  # fmt: skip
        runs[label] = fgins.smooth(dataset, method, gnss_outage=[(110.0, 150.0)])
    notes = [w for w in runs["none"].info["fit_warnings"] if "no IMU mounting was given" in w]
    assert len(notes) == 1, notes
    turned = float(re.search(r"misalignment state turned that by ([0-9.]+) deg", notes[0]).group(1))
    assert turned > 0.2, notes[0]  # the turns' fit alone is off
    yaw = float(re.search(r"using \S+ = \[[^,]+, [^,]+, ([^]]+)\]", notes[0]).group(1))
    assert abs(yaw + 90.0) < 0.1, notes[0]
    expected, got = outage_rms(runs["given"]), outage_rms(runs["none"])
    assert got <= 1.1 * expected + 0.02, (expected, got)


@pytest.mark.parametrize("turned", [False, True])
def test_a_straight_drive_shows_the_forward_axis_by_its_speed_changes(tmp_path, turned):
    """An independent simulator's straight road (two 1 deg/s curves, one start to 25 m/s):
    too few turns for the centripetal fit, so an IMU with x right and y forward went
    unchecked, to "batch LM diverged" and an EKF+RTS 126 m off at exit 0. Speeding up
    straight ahead shows the nose too: the mounting is taken to within 0.1 deg, and the
    outage matches the true mounting's; an IMU mounted right draws nothing."""
    import sys
    from pathlib import Path

    import fgins
    from fgins.mounting import forward_axis_from_motion

    sys.path.insert(0, str(Path(__file__).parent))
    from independent_sim import (
        INDUSTRIAL,
        CarProfile,
        horizontal_errors,
        turn_imu_axes,
        write_drive,
    )

    profile = CarProfile(steps=[(5, 10, 25.0)], turns=[(60, 120, 10, 0.01), (200, 260, 10, -0.012)],
                         gamma=lambda t: 0 * t)  # fmt: skip
    write_drive(tmp_path, profile, 300.0, grade=INDUSTRIAL, imu_rate=100.0, jitter=0.0,
                gnss_rate=1.0, seed=2)  # fmt: skip
    if turned:
        turn_imu_axes(tmp_path, "rfu")
    dataset = fgins.load(tmp_path / "imu.csv", tmp_path / "gnss.csv", config=tmp_path / "cfg.toml",
                         vehicle="car")  # fmt: skip
    forward, _ = forward_axis_from_motion(dataset)
    expected = np.array([0.0, 1.0, 0.0]) if turned else np.array([1.0, 0.0, 0.0])
    assert np.degrees(np.arccos(np.clip(forward @ expected, -1, 1))) < 1.0, forward
    track = fgins.smooth(dataset, "ekf-rts", gnss_outage=[(130.0, 190.0)])
    notes = [w for w in track.info.get("fit_warnings", []) if "no IMU mounting" in w]
    assert len(notes) == (1 if turned else 0), track.info.get("fit_warnings")
    t, error = horizontal_errors(track, tmp_path)
    inside = (t >= 130.0) & (t < 190.0)
    assert np.sqrt(np.mean(error[inside] ** 2)) < 0.7  # the true mounting: 0.47 m


@pytest.mark.parametrize("seed", [0, 2, 6])
def test_a_rough_turn_fit_on_a_right_default_changes_nothing(seed):
    """The simulated highway's few turns put the right (FLU) default's forward axis 1-3.9 deg
    off; refined, it comes back within the estimate's noise: the default stays, and nothing
    is said."""
    from fgins.config import config_for_dataset

    run = SCENARIOS["highway"](seed=seed)
    config = config_for_dataset(run.dataset, vehicle="car")
    track = run_method(run.dataset, config, "batch", progress=False)
    assert not [w for w in track.info.get("fit_warnings", []) if "mounting" in w], track.info


@pytest.mark.parametrize("seed", [2, 4])
def test_a_mounting_kept_off_holds_the_arm_the_point_and_the_gyro_scale(tmp_path, seed):
    """``mounting_from_data = false`` with the yaw 3 deg off: the constraints, bent by it in
    every turn, were read as a gyro y scale error of -67 % and the run refused as "a gyro
    column with its sign flipped" (5 Hz fixes, the independent simulator's car); an outside
    tester's true antenna arm was "corrected" 0.6 m away. Kept as the user asked, the
    mounting's misfit is not taken for the arm, the constraint point or the gyro's scale:
    said, and the outage errors within twice the sigmas."""
    import sys
    from pathlib import Path

    import fgins

    sys.path.insert(0, str(Path(__file__).parent))
    from independent_sim import outage_rms_and_sigma, write_turning_drive

    arm = (0.5, 0.3, 1.2)
    write_turning_drive(tmp_path, [(10, 8, 15.0)], seed, arm=arm, gnss_rate=5.0, sigma_h=0.5, sigma_u=1.0)
    config = tmp_path / "run.toml"
    config.write_text((tmp_path / "cfg.toml").read_text() + f"\n[gnss]\nlever_arm_m = {list(arm)}\n"
                      "[smoother]\nimu_to_vehicle_rpy_deg = [0, 0, 3]\nmounting_from_data = false\n")  # fmt: skip
    outages = [(60.0, 105.0), (175.0, 215.0)]
    dataset = fgins.load(tmp_path / "imu.csv", tmp_path / "gnss.csv", config=config, vehicle="car")
    track = fgins.smooth(dataset, "batch", gnss_outage=outages)
    warnings = track.info.get("fit_warnings", [])
    assert any("probably wrong" in w for w in warnings), warnings
    held = [w for w in warnings if "not taken from this drive" in w]
    assert len(held) == 1 and "gyro's scale" in held[0] and "mounting_from_data = false" in held[0], warnings
    assert "gnss_lever_arm_corrected_m" not in track.info
    rms, sigma = outage_rms_and_sigma(track, tmp_path, outages)
    assert rms < 2.0 * sigma, (rms, sigma)


@pytest.mark.parametrize("seed", [0, 3])
def test_an_accelerometer_bias_is_not_said_as_the_mounting_s_tilt(seed):
    """An accelerometer biased by ~100 mg across (a consumer MEMS within its turn-on spec)
    leans the readings' mean by 5-7 deg: said as the mounting's roll or pitch, with a wrong
    mounting to set, while the same run solved the bias to 0.1 mg (outside tester). The tilt
    is judged again with the solution's bias off the readings."""
    from dataclasses import replace

    from fgins.config import config_for_dataset
    from fgins.mounting import check_mounting, tilt_note_without_bias

    run = SCENARIOS["car-urban"](seed=seed, duration_s=200)
    bias = np.array([0.4, -0.95, 0.0])
    imu = replace(run.dataset.imu, accel=run.dataset.imu.accel + bias)
    dataset = replace(run.dataset, imu=imu, imu_config={**run.dataset.imu_config, "accel_turn_on_bias_mg": 120.0})
    before = check_mounting(dataset, (0.0, 0.0, 0.0))
    assert before is not None and "up axis" in before  # what the readings alone show
    assert tilt_note_without_bias(dataset, (0.0, 0.0, 0.0), bias) is None
    config = config_for_dataset(dataset, vehicle="car")
    track = run_method(dataset, config, "batch", progress=False)
    said = [w for w in track.info.get("fit_warnings", []) if "up axis" in w]
    assert not said, said
    assert np.allclose(np.median(track.accel_bias, axis=0)[:2], bias[:2], atol=0.2)  # solved
