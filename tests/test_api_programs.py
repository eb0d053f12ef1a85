"""The Python API as programs use it: objects made or changed in code, not only files.

An outside tester's findings, each a silently wrong result or a raw exception: a Dataset made
from arrays skipped every input check (an accelerometer in g smoothed 45 m off); a RunConfig
changed after it was made reached the solver unchecked (GTSAM's RuntimeError, ``vehicle =
"boat"`` taken); ``smooth(config=FILE)`` dropped load's ``robust="none"``; ``bench`` scored
another drive's trajectory as truth; ``check_output`` iterated a single input path by
character (so the input passed), and checked ``~/x.csv`` at $HOME while the writers wrote
``./~/x.csv``.
"""

from __future__ import annotations

import copy
import warnings
from pathlib import Path

import numpy as np
import pytest

import fgins
from fgins.config import GnssConfig


@pytest.fixture(scope="module")
def drive(tmp_path_factory) -> Path:
    return fgins.simulate("car-urban", tmp_path_factory.mktemp("api_programs") / "drive", duration=60, seed=1)


@pytest.fixture(scope="module")
def dataset(drive):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fgins.FginsWarning)
        return fgins.load(drive)


def _from_arrays(source, accel_scale: float = 1.0, name: str = "arrays") -> fgins.Dataset:
    imu = fgins.ImuData(source.imu.t, source.imu.gyro, source.imu.accel * accel_scale)
    gnss = fgins.GnssData(source.gnss.t, source.gnss.lla)
    return fgins.Dataset(imu=imu, gnss=gnss, origin=source.origin, name=name)


def _quiet_smooth(*args, **kwargs):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fgins.FginsWarning)
        return fgins.smooth(*args, **kwargs)


@pytest.mark.parametrize("scale, unit", [(1.0 / 9.80665, "in g"), (1.0, None)])
def test_a_dataset_made_from_arrays_passes_the_same_input_checks(dataset, scale, unit):
    built = _from_arrays(dataset, scale)
    if unit is not None:
        with pytest.raises(fgins.InputError, match=unit):
            _quiet_smooth(built, "ekf")
        with pytest.raises(fgins.InputError, match=unit):
            fgins.bench(built, methods=["ekf"], outages=[(20, 35)])
        return
    track = _quiet_smooth(built, "ekf")
    assert len(track) == len(built.imu) and np.all(np.isfinite(track.position))
    assert built.metadata.get("input_checks") is None  # the caller's dataset is not changed


@pytest.mark.parametrize(
    "section, key, value, words",
    [("gnss", "huber_k", -1.0, ["[gnss].huber_k", ">= 0"]),
     ("gnss", "sigma_m", "x", ["[gnss].sigma_m"]),
     ("smoother", "max_keyframe_interval_s", 0.0, ["max_keyframe_interval_s", "> 0"]),
     ("smoother", "vehicle", "boat", ["[smoother].vehicle", "car"]),
     ("smoother", "batch_max_iterations", 0, ["batch_max_iterations", ">= 1"])],
)  # fmt: skip
def test_a_run_config_changed_in_code_is_checked_again(dataset, section, key, value, words):
    config = copy.deepcopy(fgins.configure(dataset))
    setattr(getattr(config, section), key, value)
    with pytest.raises(fgins.ConfigError) as error:
        _quiet_smooth(dataset, "ekf", config=config)
    assert all(word in str(error.value) for word in words), str(error.value)
    assert "\n" not in str(error.value)


def test_a_uere_table_made_in_code_keeps_the_other_fix_types():
    config = GnssConfig(uere_m={"rtk_fixed": 0.05})
    assert config.uere_m["rtk_fixed"] == 0.05 and config.uere_m["autonomous"] > 0.0
    assert GnssConfig(uere_m={}).uere_m["autonomous"] > 0.0


def test_a_config_file_given_to_smooth_keeps_loads_explicit_choices(drive, tmp_path):
    empty = tmp_path / "empty.toml"
    empty.write_text("")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fgins.FginsWarning)
        no_kernel = fgins.load(drive, robust="none")
        plain = fgins.load(drive)
    with_file = _quiet_smooth(no_kernel, "batch", config=empty)
    without = _quiet_smooth(no_kernel, "batch")
    huber = _quiet_smooth(plain, "batch", config=empty)
    assert np.array_equal(with_file.position, without.position)
    assert not np.array_equal(with_file.position, huber.position)


def test_bench_refuses_another_drives_trajectory_as_truth(dataset, tmp_path):
    other = fgins.simulate("car-urban", tmp_path / "other", duration=40, seed=2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fgins.FginsWarning)
        other_track = fgins.smooth(fgins.load(other), "ekf")
    with pytest.raises(fgins.ConfigError, match="truth was smoothed from"):
        fgins.bench(dataset, methods=["ekf"], outages=[(20, 35)], truth=other_track)
    with pytest.raises(fgins.ConfigError, match="truth must be"):
        fgins.bench(dataset, methods=["ekf"], outages=[(20, 35)], truth=5)


def test_bench_refuses_a_truth_file_far_from_the_drives_fixes(dataset, drive, tmp_path):
    """Another drive's truth.csv over the same span was scored silently: 1,089 m of
    "outage error" (outside tester). A truth a median 30 m (and 10 fix sigmas) from the
    drive's own fixes is refused; the drive's own passes."""
    other = fgins.simulate("highway", tmp_path / "other", duration=60, seed=2)
    with pytest.raises(fgins.InputError, match=r"the truth lies \d+ m \(median\) from this drive's GNSS fixes"):
        fgins.bench(dataset, methods=["ekf"], outages=[(20, 35)], truth=other / "truth.csv")
    table = fgins.bench(dataset, methods=["ekf"], outages=[(20, 35)], truth=drive / "truth.csv")
    assert len(table) == 1


@pytest.mark.parametrize("given", ["str", "path"])
def test_check_output_takes_one_input_path_as_it_is(tmp_path, given):
    source = tmp_path / "in.csv"
    source.write_text("x\n")
    inputs = str(source) if given == "str" else source
    with pytest.raises(fgins.OutputError, match="is an input of this run"):
        fgins.check_output(source, inputs)
    assert fgins.check_output(tmp_path / "out.csv", None) == tmp_path / "out.csv"
    with pytest.raises(fgins.OutputError, match=r"one of \.json"):
        fgins.check_output(tmp_path / "out.csv", suffixes=".json")


def test_a_home_path_is_checked_and_written_at_home(dataset, tmp_path, monkeypatch):
    home = tmp_path / "home"
    home.mkdir()
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir(tmp_path)
    track = _quiet_smooth(dataset, "ekf")
    written = fgins.write(track, "~/track.csv")
    assert written == home / "track.csv" and written.is_file()
    assert not (tmp_path / "~").exists()


def test_small_argument_mistakes_are_one_line_errors(dataset, tmp_path):
    track = _quiet_smooth(dataset, "ekf", online=False)
    with pytest.raises(fgins.OutputError, match="NUL"):
        fgins.write(track, str(tmp_path / "x\0.csv"))
    with pytest.raises(fgins.ConfigError, match="outage duration -5 s"):
        fgins.bench(dataset, methods=["ekf"], outage_duration=-5)
    assert _quiet_smooth(dataset, "isam2", online=np.True_).info["run"]["method"] == "isam2-online"


def test_a_kml_says_its_heights_are_ellipsoidal(dataset, tmp_path):
    """KML's absolute altitudes are above sea level; fgins's are ellipsoidal and it has no
    geoid model: the file says so rather than being drawn tens of metres off unsaid."""
    import xml.etree.ElementTree as ElementTree

    track = _quiet_smooth(dataset, "ekf")
    root = ElementTree.parse(fgins.write(track, tmp_path / "track.kml")).getroot()
    descriptions = [e.text or "" for e in root.iter("{http://www.opengis.net/kml/2.2}description")]
    assert any("ellipsoidal" in text and "geoid" in text for text in descriptions), descriptions


def test_a_method_named_twice_is_one_row():
    from fgins.api import check_methods

    assert check_methods(["ekf", "ekf", "batch"]) == ["ekf", "batch"]
    assert check_methods("ekf-rts,ekf,ekf-rts") == ["ekf-rts", "ekf"]
    # Asked for on its own, isam2-online runs as alone (see the next test); else isam2's
    # run gives its row.
    assert check_methods("batch,isam2,isam2-online") == ["batch", "isam2", "isam2-online"]
    assert check_methods(["isam2-online"]) == ["isam2-online"]


def test_a_bench_of_isam2_and_its_online_row_has_each_row_once_as_alone(dataset):
    """Carried by isam2's run, the isam2-online row had lost the warning the same method
    gives alone ("its prediction missed the first fix ... by 25.9 m, 8 sigmas") and the
    sigmas its checks add (outside tester): asked for, it is run as alone."""
    table = fgins.bench(dataset, methods=["isam2", "isam2-online"], outages=[(20, 35)])
    assert sorted(table["method"]) == ["isam2", "isam2-online"], table["method"].tolist()
    alone = fgins.bench(dataset, methods=["isam2-online"], outages=[(20, 35)])
    both_row = table[table["method"] == "isam2-online"].iloc[0]
    alone_row = alone.iloc[0]
    for column in ("h_rms_outage_m", "h_rms_aided_m", "within_3sigma_outage"):
        assert both_row[column] == alone_row[column], column
    carried = fgins.bench(dataset, methods=["isam2"], outages=[(20, 35)])
    assert sorted(carried["method"]) == ["isam2", "isam2-online"]  # still given by isam2


def test_the_same_input_given_twice_is_named_once(drive):
    with pytest.raises(fgins.InputError, match="given twice"):
        fgins.load(drive, drive)
    with pytest.raises(fgins.InputError, match="given twice"):
        fgins.load(drive / "imu.csv", drive / "gnss.csv", drive / "imu.csv")


@pytest.mark.parametrize(
    "scenario, duration, options",
    [("car-urban", 1.0, {}), ("gyrofree-cube", 5.0, {"gnss_rate_hz": 0.2}), ("highway", 4.9, {})],
)
def test_a_simulation_too_short_to_load_is_refused_before_writing(tmp_path, scenario, duration, options):
    # A folder with one GNSS fix was written and then refused by load(): said at once now.
    folder = tmp_path / "short"
    with pytest.raises(fgins.FginsError, match=r"duration_s|at least 2"):
        fgins.simulate(scenario, folder, duration=duration, **options)
    assert not folder.exists()


def test_overlapping_outage_windows_are_said_and_refused_by_the_benchmark(dataset):
    # Withheld together they are one longer outage: smooth() says so; bench() scores each
    # window on its own, so it refuses them.
    with pytest.warns(fgins.FginsWarning, match=r"20:35 and 30:45 s overlap.*25 s"):
        track = fgins.smooth(dataset, "ekf", gnss_outage=[(30, 45), (20, 35)])
    assert track.info["run"]["gnss_withheld"] == 25
    with pytest.raises(fgins.ConfigError, match=r"touch.*must be apart"):
        fgins.bench(dataset, methods=["ekf"], outages=[(20, 35), (35, 45)])
    with warnings.catch_warnings():
        warnings.simplefilter("error", fgins.FginsWarning)  # apart: no such warning
        try:
            fgins.smooth(dataset, "ekf", gnss_outage=[(20, 30), (31, 40)])
        except fgins.FginsWarning as caught:
            assert "overlap" not in str(caught) and "touch" not in str(caught)


@pytest.mark.parametrize(
    "part, words",
    [
        ("gnss=None", "gnss must be a fgins.GnssData, not NoneType"),
        ("imu=None", "imu must be a fgins.ImuData"),
        ("baro=arrays", "baro must be a fgins.BaroData or None"),
        ("origin=text", "origin must be an Origin"),
        ("origin=pair", "origin must be an Origin"),
        ("origin=words", "origin.lat: expected a number"),
        ("imu.t=text", "imu.t: expected numbers"),
        ("gnss.lla=ragged", "gnss.lla: expected numbers"),
    ],
)
def test_a_malformed_dataset_made_in_code_is_a_one_line_input_error(dataset, part, words):
    """Found by an API fuzzer: gnss=None, origin=None or a tuple, and string times ended in
    TypeError / AttributeError / ValueError tracebacks from inside the solve."""
    source = dataset

    def build():
        imu = source.imu
        gnss = source.gnss
        parts = {"imu": imu, "gnss": gnss, "origin": source.origin}
        if part == "gnss=None":
            parts["gnss"] = None
        elif part == "imu=None":
            parts["imu"] = None
        elif part == "baro=arrays":
            parts["baro"] = (gnss.t, gnss.lla[:, 2])
        elif part == "origin=text":
            parts["origin"] = "48.1, 11.5, 500"
        elif part == "origin=pair":
            parts["origin"] = (48.1, 11.5)
        elif part == "origin=words":
            parts["origin"] = fgins.Origin("north", 11.5, 500.0)
        elif part == "imu.t=text":
            parts["imu"] = fgins.ImuData(imu.t.astype(str).astype(object) + "s", imu.gyro, imu.accel)
        elif part == "gnss.lla=ragged":
            parts["gnss"] = fgins.GnssData(gnss.t, [list(row) for row in gnss.lla[:-1]] + [[1.0]])
        return fgins.Dataset(**parts)

    with pytest.raises(fgins.InputError, match=words):
        build()


def test_a_dataset_made_in_code_takes_its_origin_as_a_tuple_or_the_first_fix(dataset):
    """None means the first fix (what every reader takes without a stated origin), a (lat,
    lon, alt) sequence the same as an Origin: the same trajectory either way."""
    first = tuple(float(v) for v in dataset.gnss.lla[0])
    tracks = [
        _quiet_smooth(fgins.Dataset(imu=dataset.imu, gnss=dataset.gnss, origin=origin), "ekf")
        for origin in (fgins.Origin(*first), first, np.array(first), None)
    ]
    for track in tracks[1:]:
        assert (track.origin.lat, track.origin.lon, track.origin.alt) == first
        np.testing.assert_allclose(track.position, tracks[0].position, atol=1e-9)


def test_a_trajectory_is_not_extrapolated(tmp_path):
    """Trajectory.at() at times outside the trajectory gave its first or last position
    without a word (a camera's stamps 10 s after the end got the last one); now NaN there,
    the ends held only when asked."""
    from fgins.datatypes import Origin, Trajectory

    t = np.array([10.0, 11.0, 12.0])
    position = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    track = Trajectory(t=t, position=position, velocity=np.zeros((3, 3)),
                       rotation=np.tile(np.eye(3), (3, 1, 1)), origin=Origin(45.0, 9.0, 100.0))
    out = track.at(np.array([9.0, 10.0, 11.5, 12.0, 22.0]))
    assert np.all(np.isnan(out[[0, 4]])) and np.allclose(out[1:4, 0], [0.0, 1.5, 2.0])
    assert np.allclose(track.at(np.array([9.0, 22.0]), hold_ends=True)[:, 0], [0.0, 2.0])
    assert np.allclose(track.at(11.0), [[1.0, 0, 0]]) and np.isnan(track.at(13.0)).all()
    # Times that are not numbers are the caller's error, said as one (a bare ValueError, and
    # None read as NaN: outside tester).
    for wrong in ("abc", None, ["1", "x"]):
        with pytest.raises(fgins.InputError, match=r"Trajectory.at\(\): times must be numbers"):
            track.at(wrong)
    # A column or a row of times (a one-column DataFrame) is a list of times; a table is not
    # (a raw numpy IndexError: outside tester), nor are datetime64 times (read as
    # nanoseconds: all NaN, unsaid).
    for shaped in (np.array([[10.0], [11.5]]), np.array([[10.0, 11.5]])):
        assert np.allclose(track.at(shaped)[:, 0], [0.0, 1.5])
    with pytest.raises(fgins.InputError, match="one-dimensional"):
        track.at(np.full((2, 3), 11.0))
    with pytest.raises(fgins.InputError, match="not datetime64"):
        track.at(np.array(["2026-01-01T00:00:10"], dtype="datetime64[ns]"))


def test_float32_posix_times_are_named_as_the_cause(tmp_path):
    """POSIX seconds held as float32 step by 128 s: 'not strictly increasing, sort or
    de-duplicate' sent the user to the order; the message names the precision."""
    from fgins.datatypes import ImuData, InputError

    t = (1.7e9 + 0.01 * np.arange(20)).astype(np.float32)
    with pytest.raises(InputError, match="stored as float32, which steps by 128 s there: give them as float64"):
        ImuData(t=t, gyro=np.zeros((20, 3)), accel=np.zeros((20, 3)))
    t = 100.0 + 0.01 * np.arange(20)
    t[7] = t[6]
    with pytest.raises(InputError, match="sort or de-duplicate"):
        ImuData(t=t, gyro=np.zeros((20, 3)), accel=np.zeros((20, 3)))


def test_a_window_between_two_sparse_epochs_is_said_to_fall_between_them():
    """Fixes 5 s apart and a 1 s window between two of them: it withholds nothing, and the
    reason gave the epochs' whole span, which the window lies inside (outside tester)."""
    from dataclasses import replace

    from fgins.outages import empty_windows
    from fgins.sim.scenarios import SCENARIOS

    dataset = SCENARIOS["car-urban"](seed=1, duration_s=60).dataset
    every_fifth = np.zeros(len(dataset.gnss), dtype=bool)
    every_fifth[::5] = True
    sparse = replace(dataset, gnss=dataset.gnss.subset(every_fifth))
    relative = sparse.gnss.t - sparse.t0
    a, b = relative[2], relative[3]
    (line,) = empty_windows(sparse, [(a + 1.0, a + 2.0)])
    assert f"falls between the epochs at {a:.1f} and {b:.1f} s after t0" in line
    (line,) = empty_windows(sparse, [(relative[-1] + 10.0, relative[-1] + 20.0)])
    assert "the epochs span" in line


def test_a_run_with_its_own_imu_table_does_not_report_loads_preset_guess(drive, tmp_path):
    """load() without a configuration guesses the consumer-mems preset and says so; a
    smooth(config=FILE) whose file has an [imu] table runs with that table, yet its summary
    still said "using the consumer-mems preset" (outside tester)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fgins.FginsWarning)
        bare = fgins.load(drive / "imu.csv", drive / "gnss.csv")
        assert any(w.startswith("imu: the data say nothing") for w in bare.warnings)
        guessed = fgins.smooth(bare, "ekf")
        (tmp_path / "imu.toml").write_text('[imu]\npreset = "industrial-mems"\n')
        configured = fgins.smooth(bare, "ekf", config=tmp_path / "imu.toml")
    assert any(w.startswith("imu: the data say nothing") for w in guessed.summary()["warnings"])
    assert not any(w.startswith("imu: the data say nothing") for w in configured.summary()["warnings"])


def test_every_data_class_a_dataset_takes_is_public_and_compares_by_identity():
    """A Dataset takes a barometer and a wheel (the error message named fgins.BaroData),
    but fgins exported neither class; and == on two datasets or two ImuData raised
    numpy's "truth value of an array is ambiguous" (outside tester)."""
    t = np.arange(5) * 0.1
    baro = fgins.BaroData(t=t, pressure=np.full(5, 95000.0))
    wheel = fgins.OdometerData(t=t, speed=np.ones(5))
    assert isinstance(baro, fgins.BaroData) and isinstance(wheel, fgins.OdometerData)
    assert {"BaroData", "OdometerData"} <= set(fgins.__all__)
    imu = fgins.ImuData(t, np.zeros((5, 3)), np.zeros((5, 3)))
    twin = fgins.ImuData(t, np.zeros((5, 3)), np.zeros((5, 3)))
    assert imu == imu and imu != twin  # identity, never an exception
    assert baro == baro and wheel != fgins.OdometerData(t=t, speed=np.ones(5))


def test_a_dataset_made_in_code_hears_what_its_configuration_guessed(dataset):
    """Smoothed without a configuration, a Dataset made in code ran on the consumer-mems
    preset guessed for it, said only in summary() (load() of the same files warns; outside
    tester). It arrives through warnings, and the caller's dataset keeps its own list."""
    made = _from_arrays(dataset)
    before = list(made.warnings)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", fgins.FginsWarning)
        fgins.smooth(made, "ekf")
    said = [str(w.message) for w in caught if issubclass(w.category, fgins.FginsWarning)]
    assert any("using the consumer-mems preset" in line for line in said), said
    assert made.warnings == before


def test_the_default_vehicle_model_is_said(dataset):
    """Without --vehicle, a configuration or an input naming one, a CSV drive runs as
    "other", without a car's constraints, and nothing said so (outside tester)."""
    other = _quiet_smooth(_from_arrays(dataset), "ekf")
    assert "vehicle: other (no vehicle constraints)" in other.summary().get("vehicle_model", "")
    car = _quiet_smooth(dataset, "ekf")  # fgins sim's folder names its car
    assert "vehicle_model" not in car.summary()
