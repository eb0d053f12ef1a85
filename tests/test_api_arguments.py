"""Bad arguments to the public Python API are one-line FginsErrors naming the argument.

Each call below used to end in a raw TypeError/AttributeError/ValueError from deep inside
(or was accepted silently); the message must name the argument and what it must be.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

import fgins


@pytest.fixture(scope="module")
def drive(tmp_path_factory) -> Path:
    return fgins.simulate(
        "car-urban", tmp_path_factory.mktemp("api_args") / "drive", duration=20, seed=3
    )


@pytest.fixture(scope="module")
def dataset(drive):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fgins.FginsWarning)
        return fgins.load(drive)


@pytest.fixture(scope="module")
def track(dataset):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fgins.FginsWarning)
        return fgins.smooth(dataset, "ekf")


# (id, call(drive, dataset, track, tmp_path), error class, words the message must hold)
CASES = [
    ("load-None", lambda d, ds, tr, t: fgins.load(None), fgins.InputError,
     ["load()", "inputs[0]", "path"]),
    ("load-bytes", lambda d, ds, tr, t: fgins.load(str(d).encode()), fgins.InputError,
     ["inputs[0]", "path", "bytes"]),
    ("load-int", lambda d, ds, tr, t: fgins.load(123), fgins.InputError, ["inputs[0]"]),
    ("load-time_offset-str", lambda d, ds, tr, t: fgins.load(d, time_offset="x"),
     fgins.InputError, ["time_offset", "a real number", "str"]),
    ("load-time_offset-bool", lambda d, ds, tr, t: fgins.load(d, time_offset=True),
     fgins.InputError, ["time_offset", "a real number", "bool"]),
    ("load-time_offset-nan", lambda d, ds, tr, t: fgins.load(d, time_offset=float("nan")),
     fgins.InputError, ["--time-offset nan", "finite"]),
    ("load-progress-str", lambda d, ds, tr, t: fgins.load(d, progress="no"),
     fgins.InputError, ["progress", "True or False"]),
    ("load-config-dict", lambda d, ds, tr, t: fgins.load(d, config={"imu": {}}),
     fgins.InputError, ["config", "TOML path", "RunConfig"]),
    ("smooth-path-str", lambda d, ds, tr, t: fgins.smooth(str(d), "ekf"), fgins.InputError,
     ["smooth()", "dataset", "Dataset", "fgins.load"]),
    ("smooth-None", lambda d, ds, tr, t: fgins.smooth(None), fgins.InputError, ["dataset"]),
    ("smooth-method-list", lambda d, ds, tr, t: fgins.smooth(ds, ["ekf"]), fgins.InputError,
     ["method", "a string"]),
    ("smooth-gnss_outage-int", lambda d, ds, tr, t: fgins.smooth(ds, "ekf", gnss_outage=5),
     fgins.ConfigError, ["gnss_outage", "(start, end)"]),
    ("smooth-gnss_outage-str-pair",
     lambda d, ds, tr, t: fgins.smooth(ds, "ekf", gnss_outage=[("10", "20")]),
     fgins.ConfigError, ["gnss_outage", "(start, end)"]),
    ("smooth-config-int", lambda d, ds, tr, t: fgins.smooth(ds, "ekf", config=5),
     fgins.InputError, ["smooth()", "config", "int"]),
    ("smooth-online-str", lambda d, ds, tr, t: fgins.smooth(ds, "isam2", online="yes"),
     fgins.InputError, ["smooth()", "online", "True or False", "'yes'"]),
    ("smooth-progress-int", lambda d, ds, tr, t: fgins.smooth(ds, "ekf", progress=1),
     fgins.InputError, ["progress", "True or False"]),
    ("write-None", lambda d, ds, tr, t: tr.write(None), fgins.InputError,
     ["write()", "path", "NoneType"]),
    ("write-int", lambda d, ds, tr, t: fgins.write(tr, 123), fgins.InputError, ["path"]),
    ("write-not-a-trajectory", lambda d, ds, tr, t: fgins.write(ds, t / "x.csv"),
     fgins.InputError, ["trajectory", "Trajectory"]),
    ("write-with_input-str", lambda d, ds, tr, t: tr.write(t / "x.mcap", with_input="yes"),
     fgins.InputError, ["with_input", "True or False"]),
    ("plot-dataset-None", lambda d, ds, tr, t: fgins.plot(tr, None), fgins.InputError,
     ["plot()", "dataset", "Dataset"]),
    ("plot-trajectory-None", lambda d, ds, tr, t: fgins.plot(None, ds), fgins.InputError,
     ["plot()", "trajectories[0]", "Trajectory"]),
    ("plot-empty", lambda d, ds, tr, t: fgins.plot([], ds), fgins.InputError,
     ["trajectories"]),
    ("plot-path-csv", lambda d, ds, tr, t: fgins.plot(tr, ds, path=t / "p.csv"),
     fgins.OutputError, ["plot format must be one of .png, .pdf, .svg"]),
    ("simulate-seed-negative",
     lambda d, ds, tr, t: fgins.simulate("car-urban", t / "s", duration=10, seed=-1),
     fgins.InputError, ["simulate()", "seed", "non-negative integer"]),
    ("simulate-seed-float",
     lambda d, ds, tr, t: fgins.simulate("car-urban", t / "s", duration=10, seed=1.5),
     fgins.InputError, ["seed", "non-negative integer"]),
    ("simulate-duration-str",
     lambda d, ds, tr, t: fgins.simulate("car-urban", t / "s", duration="60"),
     fgins.InputError, ["simulate()", "duration", "finite real number", "str"]),
    ("simulate-output_dir-None", lambda d, ds, tr, t: fgins.simulate("car-urban", None),
     fgins.InputError, ["output_dir", "path"]),
    ("configure-vehicle-int", lambda d, ds, tr, t: fgins.configure(ds, vehicle=5),
     fgins.InputError, ["configure()", "vehicle", "a string"]),
    ("bench-outage_duration-str",
     lambda d, ds, tr, t: fgins.bench(ds, methods=["ekf"], outage_duration="30"),
     fgins.InputError, ["bench()", "outage_duration", "finite real number"]),
    ("check_output-None", lambda d, ds, tr, t: fgins.check_output(None), fgins.InputError,
     ["check_output()", "path"]),
    ("summary-None", lambda d, ds, tr, t: fgins.api.summary(None), fgins.InputError,
     ["summary()", "trajectory"]),
]  # fmt: skip


@pytest.mark.parametrize(
    ("call", "error", "words"), [c[1:] for c in CASES], ids=[c[0] for c in CASES]
)
def test_bad_argument_is_a_one_line_fgins_error_naming_it(
    drive, dataset, track, tmp_path, call, error, words
):
    with pytest.raises(error) as caught:
        call(drive, dataset, track, tmp_path)
    message = str(caught.value)
    assert isinstance(caught.value, fgins.FginsError)
    assert "\n" not in message
    for word in words:
        assert word in message, message
    assert list(tmp_path.iterdir()) == []  # refused before anything was written


@pytest.mark.parametrize(
    "value",
    [0, 0.5, -18, np.float64(2.5), np.int64(3)],
    ids=["int", "float", "neg", "np-f", "np-i"],
)
def test_real_numbers_of_any_type_are_accepted(drive, value):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fgins.FginsWarning)
        dataset = fgins.load(drive, time_offset=value)
    assert len(dataset.gnss) > 0


def test_valid_calls_still_work(dataset, track, tmp_path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fgins.FginsWarning)
        windowed = fgins.smooth(dataset, "ekf", gnss_outage=np.array([[5, 10]]), online=False)
    assert windowed.summary()["gnss_withheld"] > 0
    assert fgins.write(track, tmp_path / "t.csv").is_file()
    figure = fgins.plot([track], dataset, path=tmp_path / "t.png")
    assert figure is not None and (tmp_path / "t.png").is_file()
