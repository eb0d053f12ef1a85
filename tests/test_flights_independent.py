"""The Kalman baselines on flights of an independent simulator (tests/flight_sim.py).

A multirotor tilts its thrust (z) axis toward its acceleration, flies sideways and backwards
and yaws on its own: motion fgins's own simulator does not make. There the at-rest heading
fit of :func:`fgins.alignment._heading_from_acceleration` was degenerate (the z-accelerometer
bias track equals the dead reckoning over g), fell back to the course of the first motion
(90-180 deg off, sigma 2 deg), and the EKF+RTS ended 20-150 m off in outages (z 30-290).
Fixed-wing flights with GNSS velocity (banked coordinated turns, south/west headings, FRD)
guard the EKF+RTS against the batch solve.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import fgins
from fgins.alignment import initial_alignment
from fgins.baseline.measurements import reset_jacobian
from fgins.geodesy import rotation_to_roll_pitch_heading, skew, so3_exp, so3_log

sys.path.insert(0, str(Path(__file__).parent))
from flight_sim import FixedWing, Multirotor, write_flight

# A multirotor need not yaw with its GNSS track; its gyro is alive, so no "the gyro does not
# see the turns" note may come (it came on every valid multirotor flight until session 20).
pytestmark = pytest.mark.filterwarnings("error:imu. the gyro does not see the turns")

MR_OUTAGE = (40.0, 70.0)
FW_OUTAGE = (70.0, 110.0)


def _multirotor(heading: float) -> Multirotor:
    moves = [(6, 6, [0, 0, 10]),  # climb out of the hover
             (18, 10, [40, 0, 0]),  # east, whatever the nose
             (30, 8, [0, -30, 0]),  # south
             (42, 12, [-40, 30, 0]),  # back north-west inside the outage
             (58, 10, [20, 20, 0])]  # fmt: skip
    yaws = [(12, 5, np.radians(90)), (34, 6, np.radians(-150)), (60, 6, np.radians(60))]
    return Multirotor(heading0_deg=heading, moves=moves, yaws=yaws)


def _fixed_wing(heading: float, speed: float) -> FixedWing:
    rate = 9.8 * np.tan(np.radians(35)) / speed  # a coordinated turn banked 35 deg
    return FixedWing(
        speed=speed, heading0_deg=heading,
        turns=[(40, 75, 4, rate), (95, 120, 4, -rate)], climbs=[(20, 45, 5, np.radians(6))],
    )  # fmt: skip


def _errors(track, folder: Path, window: tuple[float, float]) -> dict[str, float]:
    truth = pd.read_csv(folder / "truth.csv")
    t = track.t
    rows = np.clip(np.searchsorted(truth["time"].to_numpy(), t - 1e-9), 0, len(truth) - 1)
    diff = track.position[:, :2] - truth[["east", "north"]].to_numpy()[rows]
    inside = (t >= window[0]) & (t < window[1])
    var = np.stack([track.position_cov[:, 0, 0], track.position_cov[:, 1, 1]], -1)
    heading = rotation_to_roll_pitch_heading(track.rotation)[:, 2]
    heading_error = (heading - truth["heading_deg"].to_numpy()[rows] + 180) % 360 - 180
    return {
        "rms": float(np.sqrt(np.mean(np.sum(diff[inside] ** 2, 1)))),
        "z": float(np.sqrt(np.mean(np.sum(diff[inside] ** 2 / var[inside], 1) / 2))),
        "heading": float(np.max(np.abs(heading_error[t > 5.0]))),
    }


@pytest.fixture(scope="module", params=[("flu", 0.0), ("frd", 225.0)], ids=["flu-north", "frd-sw"])
def multirotor(request, tmp_path_factory) -> Path:
    frame, heading = request.param
    folder = tmp_path_factory.mktemp("multirotor") / frame
    return write_flight(folder, _multirotor(heading), 80.0, seed=5, frame=frame, vehicle="uav")


@pytest.mark.parametrize("frame", ["flu", "frd"])
def test_a_circling_multirotor_with_its_nose_held_gets_no_gyro_note(tmp_path, frame):
    """Two minutes of circles (overlapping moves whose direction turns 45 deg every 4 s)
    with the nose held: the track turns, the gyro about up does not. That is how a
    multirotor flies, and its gyro is alive (it tilts to accelerate): no "does not see the
    turns" note (the module's filter makes it an error). It came with a ratio of 0.2."""
    moves = [(5 + 4 * i, 8, 40 * np.array([np.cos(i * np.pi / 4), np.sin(i * np.pi / 4), 0]))
             for i in range(25)]  # fmt: skip
    folder = write_flight(tmp_path / "mr", Multirotor(heading0_deg=30, moves=moves, yaws=[]),
                          120.0, seed=5, frame=frame, vehicle="uav")  # fmt: skip
    dataset = fgins.load(folder, vehicle="uav")
    assert not any("gyro" in note for note in dataset.metadata["input_checks"])
    # The vehicle from the config file alone counts as well (the input checks used to
    # see only --vehicle: "[smoother] vehicle = 'uav'" was refused as a dead gyro).
    (tmp_path / "run.toml").write_text('[smoother]\nvehicle = "uav"\n')
    dataset = fgins.load(folder / "imu.csv", folder / "gnss.csv", config=tmp_path / "run.toml")
    assert not any("gyro" in note for note in dataset.metadata["input_checks"])
    assert dataset.metadata["run_config"].smoother.vehicle == "uav"


def test_a_multirotor_yawing_against_its_track_gets_no_gyro_note(tmp_path):
    """Circles counter-clockwise while the nose yaws clockwise (a camera drone panning):
    the gyro turns against the track, as a multirotor may. With --vehicle uav that was a
    note blaming the accelerometer's sign, the axes or swapped latitude and longitude on
    every such valid flight (outside tester); a car or an aircraft is still judged."""
    moves = [(5 + 4 * i, 8, 40 * np.array([np.cos(i * np.pi / 4), np.sin(i * np.pi / 4), 0]))
             for i in range(25)]  # fmt: skip
    yaws = [(5 + 10 * i, 8, -np.pi / 2) for i in range(11)]
    folder = write_flight(tmp_path / "mr", Multirotor(heading0_deg=30, moves=moves, yaws=yaws),
                          120.0, seed=6, frame="frd", vehicle="uav")  # fmt: skip
    dataset = fgins.load(folder, vehicle="uav")
    assert not any("gyro" in note for note in dataset.metadata["input_checks"]), dataset.metadata[
        "input_checks"
    ]
    with pytest.raises(fgins.InputError, match="gyro turns against the GNSS track"):
        fgins.load(folder, vehicle="aircraft")


def test_a_multirotor_that_hovers_long_then_flies_backward_keeps_an_honest_heading(tmp_path):
    """A 70 s hover, then backward and sideways moves: the acceleration fit of the heading
    at rest has no motion within its window, and the alignment took the course of the first
    (backward) motion as the heading with a 2 deg sigma, 180 deg off (outside tester: the
    batch bent the gyro bias to meet it, heading errors 1.4 deg against a 0.1 deg sigma).
    The course says nothing of a multirotor's heading: the batch's heading is now within its
    own 3 sigma over the whole flight."""
    nose = 45.0
    back = np.array([-np.sin(np.radians(nose)), -np.cos(np.radians(nose)), 0.0])  # tail-first
    side = np.array([np.cos(np.radians(nose)), -np.sin(np.radians(nose)), 0.0])
    moves = [(70, 10, 60 * back), (85, 10, 50 * side), (100, 10, -40 * back + 30 * side),
             (115, 10, -60 * side)]  # fmt: skip
    folder = write_flight(tmp_path / "hb", Multirotor(heading0_deg=nose, moves=moves, yaws=[]),
                          140.0, seed=8, vehicle="uav")  # fmt: skip
    track = fgins.smooth(fgins.load(folder, vehicle="uav"), "batch").to_dataframe()
    truth = pd.read_csv(folder / "truth.csv")
    error = (track["heading_deg"].to_numpy() - truth["heading_deg"].to_numpy() + 180) % 360 - 180
    z = np.abs(error) / track["std_heading_deg"].to_numpy()
    assert np.percentile(z, 99) < 3.0, (np.abs(error).max(), np.percentile(z, 99))


def test_multirotor_heading_at_rest(multirotor):
    """The nose's heading, not the course of the (sideways) first motion."""
    dataset = fgins.load(multirotor, vehicle="uav")
    config = fgins.configure(dataset, vehicle="uav")
    align = initial_alignment(dataset, smoother=config.smoother)
    truth = pd.read_csv(multirotor / "truth.csv")
    found = rotation_to_roll_pitch_heading(np.asarray(align.rotation)[None])[0, 2]
    error = (found - truth["heading_deg"][0] + 180) % 360 - 180
    assert abs(error) < max(3.0 * np.degrees(align.attitude_sigma_rad[2]), 5.0), error


def test_multirotor_ekf_rts_outage(multirotor):
    dataset = fgins.load(multirotor, vehicle="uav")
    track = fgins.smooth(dataset, "ekf-rts", gnss_outage=[MR_OUTAGE])
    err = _errors(track, multirotor, MR_OUTAGE)
    assert err["rms"] < 3.0 and err["z"] < 3.0, err  # was 20-150 m, z 30-290
    assert err["heading"] < 3.0, err


@pytest.mark.parametrize(("frame", "heading"), [("flu", 0.0), ("frd", 250.0)])
def test_fixed_wing_ekf_rts_matches_batch(tmp_path, frame, heading):
    folder = write_flight(tmp_path / frame, _fixed_wing(heading, 80.0), 130.0, seed=3,
                          frame=frame, vehicle="aircraft", gnss_rate=2.0)  # fmt: skip
    dataset = fgins.load(folder, vehicle="aircraft")
    rts = _errors(fgins.smooth(dataset, "ekf-rts", gnss_outage=[FW_OUTAGE]), folder, FW_OUTAGE)
    batch = _errors(fgins.smooth(dataset, "batch", gnss_outage=[FW_OUTAGE]), folder, FW_OUTAGE)
    assert rts["rms"] < 1.3 * batch["rms"] + 0.2, (rts, batch)
    assert rts["z"] < 3.0 and rts["heading"] < 1.0, rts


# A fixed-wing at 60 m/s whose heading the straight climb leaves unobservable until a
# turn that starts just before a GNSS outage: the forward EKF enters the outage with its
# heading 9-13 deg off (honestly: sigma 6-10 deg) and dead-reckons 100-460 m off. The RTS
# correction, linear about that pass, ended 2.9-6.9 m off with NEES 11-70 (the batch:
# 0.3-1.1 m) until the smoother relinearised about its own smoothed states.
# (heading, bank deg, turn start s, outage s, frame, GNSS Hz, velocity, seed)
LATE_HEADING_FLIGHTS = [
    (339.7, 29.0, 83.5, 45.0, "flu", 0.2, True, 1),
    (339.7, 29.0, 83.5, 45.0, "frd", 0.2, True, 1),
    (112.6, 25.6, 65.5, 45.0, "frd", 1.0, False, 3),
    (301.9, 37.3, 66.5, 30.0, "frd", 0.2, False, 4),
]


@pytest.mark.parametrize(
    ("heading", "bank", "turn", "outage_s", "frame", "rate", "velocity", "seed"),
    LATE_HEADING_FLIGHTS,
    ids=["flu-0.2Hz-vel", "frd-0.2Hz-vel", "frd-1Hz", "frd-0.2Hz"],
)
def test_a_heading_resolved_only_after_the_outage_is_relinearised_by_the_rts(
    tmp_path, heading, bank, turn, outage_s, frame, rate, velocity, seed
):
    rate_rad = 9.8 * np.tan(np.radians(bank)) / 60.0
    flight = FixedWing(
        speed=60.0, heading0_deg=heading,
        turns=[(turn, turn + 40, 4, rate_rad), (turn + 70, turn + 100, 4, -0.7 * rate_rad)],
        climbs=[(20, 45, 5, np.radians(5)), (turn + 20, turn + 50, 5, np.radians(-4))],
    )  # fmt: skip
    folder = write_flight(tmp_path / "fw", flight, 260.0, seed=seed, frame=frame,
                          vehicle="aircraft", gnss_rate=rate)  # fmt: skip
    if not velocity:
        gnss = pd.read_csv(folder / "gnss.csv")
        gnss.drop(columns=["vel_east", "vel_north", "vel_up"]).to_csv(folder / "gnss.csv", index=False)
    window = (turn + 5.0, turn + 5.0 + outage_s)
    dataset = fgins.load(folder, vehicle="aircraft")
    smoothed = fgins.smooth(dataset, "ekf-rts", gnss_outage=[window])
    rts = _errors(smoothed, folder, window)
    batch = _errors(fgins.smooth(dataset, "batch", gnss_outage=[window]), folder, window)
    assert rts["rms"] < 1.25 * batch["rms"] + 0.2, (rts, batch)
    assert rts["z"] < 2.5, rts
    assert smoothed.info["relinearised_passes"] >= 1, smoothed.info


def test_attitude_reset_is_that_of_the_global_error():
    """After injecting dtheta on the left, the new error is log(Exp(e) Exp(-dtheta)): its
    Jacobian in e is I + [dtheta]x / 2 (the code had the local error's I - [dtheta]x / 2)."""
    dtheta = np.array([0.05, -0.03, 0.08])
    rotation = so3_exp(np.array([0.3, 0.2, 1.0]))

    def new_error(e):
        return so3_log(so3_exp(e) @ rotation @ (so3_exp(dtheta) @ rotation).T)

    h = 1e-6
    numeric = np.column_stack([(new_error(dtheta + d) - new_error(dtheta - d)) / (2 * h)
                               for d in np.eye(3) * h])  # fmt: skip
    reset = reset_jacobian(dtheta)[6:9, 6:9]
    assert np.abs(reset - numeric).max() < 5e-3
    assert np.abs(reset - (np.eye(3) + 0.5 * skew(dtheta))).max() < 1e-12


def test_a_climbing_banked_turn_is_not_called_a_clock_offset(tmp_path):
    """An 80 s climbing turn banked 45 deg: rolling in and out, the gyro about the log's mean
    "up" is not the rotation about the vertical (it saw 0.73 of the track's turn, its roll-in
    shifted by ~2 s), and every flight like it got "the fixes line up with the gyro when
    moved by +2.12 s ... --time-offset +2.12 aligns them", advice that makes the fit worse.
    A real clock offset (GPS time against UTC) is still an error."""
    rate = 9.8 * np.tan(np.radians(45)) / 80.0
    motion = FixedWing(speed=80.0, heading0_deg=250, turns=[(30, 110, 3, rate)],
                       climbs=[(25, 120, 15, np.radians(30))])  # fmt: skip
    folder = write_flight(tmp_path / "climbturn", motion, 140.0, seed=2, vehicle="aircraft",
                          gnss_rate=2.0)  # fmt: skip
    dataset = fgins.load(folder, vehicle="aircraft")
    assert not any(w.startswith("time:") for w in dataset.warnings), dataset.warnings
    track = fgins.smooth(dataset, "batch", gnss_outage=[(60.0, 110.0)])
    assert _errors(track, folder, (60.0, 110.0))["rms"] < 1.0
    with pytest.raises(fgins.InputError, match=r"clocks differ .* good to about 2 s") as error:
        fgins.load(folder, vehicle="aircraft", time_offset=18.0)
    advice = float(re.search(r"give --time-offset ([-+][0-9.]+)", str(error.value)).group(1))
    assert abs(advice) < 2.5, error.value


@pytest.mark.parametrize(("turn", "said"), [("none", False), ("rfu", True), ("backward", True)])
def test_an_aircraft_imu_whose_x_is_not_forward_is_said(tmp_path, turn, said):
    """A fixed wing whose IMU has x right and y forward, or faces backwards, and no mounting:
    the graph recovered, but the in-motion alignment took x for the nose, and EKF+RTS ended
    1.24 m inside an outage instead of 0.36 m without a word (backwards: a diverged filter).
    The solved nose against the velocity now says so; an IMU mounted right draws nothing."""
    folder = write_flight(tmp_path / turn, _fixed_wing(30.0, 60.0), 130.0, seed=2,
                          vehicle="aircraft", gnss_rate=2.0)  # fmt: skip
    if turn != "none":
        from independent_sim import turn_imu_axes

        turn_imu_axes(folder, turn)
    dataset = fgins.load(folder, vehicle="aircraft")
    track = fgins.smooth(dataset, "batch", gnss_outage=[FW_OUTAGE])
    notes = [w for w in track.info.get("fit_warnings", []) if "forward axis" in w]
    assert bool(notes) == said, track.info.get("fit_warnings")
    if said:
        angle = float(re.search(r"lies (\d+) deg from its velocity", notes[0]).group(1))
        assert abs(angle - (90.0 if turn == "rfu" else 180.0)) < 10.0, notes


@pytest.mark.parametrize(("frame", "bank_deg", "method"), [
    ("flu", 30.0, "batch"), ("frd", 25.0, "batch"), ("flu", 30.0, "ekf-rts"), ("frd", 30.0, "ekf"),
])  # fmt: skip
def test_a_flight_that_turns_through_its_whole_log_is_aligned(tmp_path, frame, bank_deg, method):
    """An aircraft orbiting through its whole 90 s log (25-30 deg bank, 1 Hz fixes), as a
    holding pattern or a slice of a flight cut inside its turn: the search for a straight
    to align on read the integrated yaw past the IMU's end as "no turn", aligned after the
    last sample and gave NaN. planar-kf wrote an all-NaN track at exit 0; the graph called
    the inputs non-finite; the EKF ended in an SVD error. Now the start is aligned in the
    turn, and the track is as good as the data (outside tester: 0.29 m)."""
    rate = 9.8 * np.tan(np.radians(bank_deg)) / 70.0
    motion = FixedWing(speed=70.0, heading0_deg=120.0, turns=[(-20.0, 200.0, 1.0, rate)])
    folder = write_flight(tmp_path / "orbit", motion, 90.0, seed=3, frame=frame,
                          vehicle="aircraft", gnss_rate=1.0)  # fmt: skip
    dataset = fgins.load(folder, vehicle="aircraft")
    alignment = initial_alignment(dataset, smoother=dataset.metadata["run_config"].smoother)
    assert np.all(np.isfinite(alignment.position)) and np.all(np.isfinite(alignment.rotation))
    track = fgins.smooth(dataset, method)
    errors = _errors(track, folder, (0.0, 90.0))
    assert errors["rms"] < (3.0 if method == "ekf" else 1.0), errors
    assert errors["z"] < 3.0, errors


def test_a_filter_with_car_constraints_on_an_aircraft_names_the_vehicle(tmp_path):
    """An aircraft run with --vehicle car: the Kalman filters' fit notes blamed clocks, axes,
    units and noise (EKF+RTS 43 m off vertically at the fixes, outside tester), never the
    constraints the vehicle does not obey; the batch's constraint fit names it."""

    class WithAngleOfAttack(FixedWing):  # the nose 5 deg above the flight path, as wings fly
        def rotation(self, t):
            pitch_up = so3_exp(np.array([0.0, -np.radians(5.0), 0.0]))
            return super().rotation(t) @ pitch_up

    motion = WithAngleOfAttack(
        speed=60.0, heading0_deg=30.0, turns=[(40, 70, 4, 0.16), (110, 140, 4, -0.12)],
        climbs=[(20, 60, 5, np.radians(8)), (90, 130, 5, np.radians(-6))],
    )  # fmt: skip
    folder = write_flight(tmp_path, motion, 160.0, seed=4, gnss_rate=1.0, vehicle="aircraft")
    dataset = fgins.load(folder)
    track = fgins.smooth(dataset, "ekf-rts", config=fgins.configure(dataset, vehicle="car"))
    notes = [w for w in track.info.get("fit_warnings", []) if "its IMU predictions miss" in w or "does not fit" in w]
    assert notes and all("a vehicle that is not a car" in w and "--vehicle" in w for w in notes), track.info.get("fit_warnings")
    clean = fgins.smooth(dataset, "ekf-rts")
    assert not any("not a car" in w for w in clean.info.get("fit_warnings", []))
