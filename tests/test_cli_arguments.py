"""Bad command-line arguments: one ``fgins: error:`` line, exit 2, before any solve.

Each case used to be an internal error, a misleading message, or a silent column of NaN.
"""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

import fgins
from fgins import api
from fgins.cli import main
from fgins.datatypes import InputError
from fgins.fleet import FleetOptions, expand_drives, run_fleet
from fgins.io.atomic import atomic_path
from fgins.tests.cli_checks import cli_error


@pytest.fixture(scope="module")
def drive(tmp_path_factory) -> Path:
    return fgins.simulate(
        "car-urban", tmp_path_factory.mktemp("cli_args") / "drive", duration=20, seed=5
    )



# --- --with-input needs an MCAP input (item 07) ----------------------------------------------


@pytest.mark.parametrize("inputs", ["folder", "csv-pair"])
def test_with_input_needs_an_mcap_input(drive, tmp_path, capsys, no_loading, inputs):
    given = (
        [str(drive)] if inputs == "folder" else [str(drive / "imu.csv"), str(drive / "gnss.csv")]
    )
    out = tmp_path / "wi.mcap"
    message = cli_error(capsys, ["smooth", *given, "--method", "ekf", "--with-input", "-o", str(out)])
    assert message.startswith("--with-input needs an MCAP input (got ")
    assert all(item in message for item in given)
    assert not out.exists()


def test_with_input_needs_an_mcap_output(drive, tmp_path, capsys, no_loading):
    message = cli_error(capsys, ["smooth", str(drive), "--with-input", "-o", str(tmp_path / "t.csv")])
    assert message.startswith("--with-input needs an MCAP output")


def test_with_input_of_an_mcap_input_still_copies_it(tmp_path, capsys):
    sys.path.insert(0, str(Path(__file__).parent))
    from mcap_fixtures import make_drive, write_ros2_bag

    bag = write_ros2_bag(tmp_path / "bag", make_drive(duration_s=10.0))
    out = tmp_path / "wi.mcap"
    argv = ["smooth", str(bag), "--method", "ekf", "--with-input", "-o", str(out), "--no-progress"]
    assert main(argv) == 0
    from fgins.io.mcap import read_mcap

    copied = read_mcap(out, progress=False).dataset  # the input's channels are in it
    assert len(copied.imu) == len(read_mcap(bag, progress=False).dataset.imu) > 0


def test_api_write_with_input_needs_an_mcap_input(drive, tmp_path):
    track = fgins.smooth(fgins.load(drive), "ekf")
    with pytest.raises(InputError, match=r"with_input=True needs an MCAP input \(got the folder"):
        track.write(tmp_path / "wi.mcap", with_input=True)
    assert not (tmp_path / "wi.mcap").exists()


# --- fleet --scheduler must look like an address (item 08) -----------------------------------


@pytest.mark.parametrize("address", ["not a url", "tcp://host", "tcp://host:abc", "foo://h:1"])
def test_fleet_scheduler_that_is_no_address_is_one_line(tmp_path, capsys, address):
    out = tmp_path / "fleet"
    message = cli_error(capsys, ["fleet", str(tmp_path), "-o", str(out), "--scheduler", address])
    assert message.startswith(f"--scheduler {address!r}: not a Dask scheduler address")
    assert "tcp://HOST:PORT" in message
    assert not out.exists()  # refused before the output folder is made
    with pytest.raises(InputError, match="--scheduler"):
        run_fleet(expand_drives([str(tmp_path)]), FleetOptions(), out, scheduler=address)


# --- output names longer than the file system allows (item 09) -------------------------------


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("x" * 300 + ".csv", "file name too long (304 bytes"),
        ("x" * 246 + ".csv", "file name too long (250 bytes"),  # fits, but not its temp name
        ("é" * 130 + ".csv", "file name too long (264 bytes"),  # bytes, not characters
        ("d" * 256 + "/track.csv", "folder name"),
        ("/".join(["d" * 200] * 25) + "/track.csv", "cannot write there"),  # > PATH_MAX
    ],
    ids=["300", "250", "utf8", "folder", "path-max"],
)
def test_output_name_too_long_is_refused_before_the_solve(
    drive, tmp_path, capsys, no_loading, name, message
):
    out = tmp_path / name
    error = cli_error(capsys, ["smooth", str(drive), "--method", "ekf", "-o", str(out)])
    assert message in error and len(error) < 300, error
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(fgins.OutputError, match=r"too long|cannot write there"):
        api.check_output(out)


def test_longest_accepted_output_name_can_be_written(tmp_path):
    target = tmp_path / ("x" * (api.NAME_MAX_BYTES - 15 - 4) + ".csv")
    api.check_output(target)
    with atomic_path(target) as tmp:  # the temporary name beside it fits too
        tmp.write_text("ok")
    assert target.read_text() == "ok"


# --- bench: --methods and --baseline up front (item 15) --------------------------------------


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (["--methods", ""], "--methods: no method given; choose from batch"),
        (["--methods", ","], "--methods: no method given"),
        (["--methods", "ekf", "--baseline", "nope"], "--baseline 'nope': unknown method"),
        (["--methods", "ekf", "--baseline", "ukf"], "--baseline 'ukf': not among --methods"),
        (["--methods", "ekf", "--baseline", "isam2-online"], "not among --methods"),
    ],
)
def test_bench_methods_and_baseline_checked_before_loading(
    drive, tmp_path, capsys, no_loading, options, message
):
    out = tmp_path / "bench"
    error = cli_error(capsys, ["bench", str(drive), "--gnss-outage", "5:10", *options, "-o", str(out)])
    assert message in error, error
    assert not out.exists()


def test_bench_baseline_checks_accept_the_rows_a_run_makes():
    assert api.check_methods(["isam2"], "isam2-online") == ["isam2"]
    assert api.check_methods("ekf, ekf-rts", "ekf-rts") == ["ekf", "ekf-rts"]


def test_bench_default_baseline_is_a_method_that_ran(drive, tmp_path, capsys):
    """Without ekf among --methods the ratios are against the first method, never NaN."""
    out = tmp_path / "bench"
    argv = ["bench", str(drive), "--gnss-outage", "5:10", "--methods", "ekf-rts", "-o", str(out)]
    assert main([*argv, "--no-progress"]) == 0
    printed = capsys.readouterr().out
    assert "RMS / ekf-rts" in printed
    row = next(line for line in printed.splitlines() if line.startswith("| drive | ekf-rts |"))
    assert row.strip(" |").split("|")[-1].strip() == "1.00"  # the ratio column, not nan


# --- demo warns of an outage outside the drive as smooth does (item 16) ----------------------


def test_demo_outage_outside_the_drive_warns_like_smooth(tmp_path, capsys):
    window = ["--gnss-outage", "1000:1030", "--method", "ekf", "--no-progress"]
    assert main(["smooth", "demo:kitti", *window, "-o", str(tmp_path / "s.csv")]) == 0
    smooth_warnings = [
        line for line in capsys.readouterr().err.splitlines() if "withholds no GNSS" in line
    ]
    assert len(smooth_warnings) == 1 and smooth_warnings[0].startswith("warning: ")
    assert main(["demo", "-o", str(tmp_path / "demo"), *window]) == 0
    captured = capsys.readouterr()
    demo_warnings = [line for line in captured.err.splitlines() if "withholds no GNSS" in line]
    assert demo_warnings == smooth_warnings
    assert "nan" not in captured.out.lower()
    assert "not measured (no GNSS epoch withheld)" in captured.out


# --- --time-offset of absurd size (item 17) --------------------------------------------------


@pytest.mark.parametrize("offset", ["1e20", "-2e10", "1.5e19"])
def test_absurd_time_offset_is_refused_naming_the_option(drive, tmp_path, capsys, offset):
    out = tmp_path / "x.csv"
    error = cli_error(capsys, ["smooth", str(drive), f"--time-offset={offset}", "-o", str(out)])
    assert error.startswith(f"--time-offset {float(offset):g}: more than 1e+10 s")
    assert "strictly increasing" not in error
    assert list(tmp_path.iterdir()) == []
    error = cli_error(capsys, ["convert", str(drive / "gnss.csv"), f"--time-offset={offset}",
                            "-o", str(tmp_path / "g.geojson")])  # fmt: skip
    assert error.startswith("--time-offset")
    with pytest.raises(InputError, match="--time-offset"):
        fgins.load(drive, time_offset=float(offset))


def test_plausible_time_offsets_are_taken():
    from fgins.io.inputs import check_time_offset

    for offset in (-18.0, 0.0, 3600.0, 1e9, -1e9, 1.8e9):
        assert check_time_offset(offset) == offset
