"""Misuse of the simulator options, fleet, bench and the plotting API (an outside tester's
findings): each is one clear error before any work, never an internal error, a hang, a
half-written folder or a result of nothing at exit 0."""

from __future__ import annotations

from pathlib import Path

import pytest

import fgins
from fgins import cli


@pytest.fixture(scope="module")
def drive(tmp_path_factory) -> Path:
    return fgins.simulate("car-urban", tmp_path_factory.mktemp("misuse") / "drive", duration=20)


def _error(args: list[str], capsys) -> str:
    code = cli.main(args)
    err = capsys.readouterr().err
    assert code == 2, err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("fgins: error: "), err
    return lines[0]


@pytest.mark.parametrize(
    ("scenario", "option", "expect"),
    [
        ("mems-car-pdop", "bias_start_s=abc", "option bias_start_s: expected a number"),
        ("mems-car-pdop", "bias_offset_m=nan", "option bias_offset_m: expected three numbers"),
        ("aircraft-ekf", "outage_start_s=abc", "option outage_start_s: expected a number"),
        ("aircraft-ekf", "outage_start_s=-1", "option outage_start_s: -1 is outside"),
        ("gyrofree-cube", "half_edge_m=abc", "option half_edge_m: expected a number"),
        ("uav-loop-baro", "gnss_rate_hz=abc", "option gnss_rate_hz: expected a number"),
        ("car-urban", "start_time_s=-1e20", "option start_time_s: -1e\\+20 is outside"),
        ("car-urban", "start_time_s=nan", "option start_time_s: nan is outside"),
        ("uav-loop-baro", "duration_s=0.3", "option duration_s: 0.3 is outside"),
        ("car-urban", "imu_rate_hz=True", "option imu_rate_hz: expected a number, got True"),
        ("car-urban", "=5", "the option name before '=' is missing"),
    ],
)
def test_bad_simulator_options_are_one_line(scenario, option, expect, tmp_path, capsys):
    """Bare float() parses were 'internal error: ValueError / ZeroDivisionError'."""
    import re

    line = _error(["sim", scenario, "-o", str(tmp_path / "out"), "--set", option], capsys)
    assert re.search(expect, line), line
    assert not (tmp_path / "out").exists()


def test_a_mems_car_bias_offset_is_given_as_three_numbers(tmp_path):
    run_dir = fgins.simulate("mems-car-pdop", tmp_path / "m", duration=30, bias_offset_m="[1,2,3]", bias_start_s=10)
    assert "(1.0, 2.0, 3.0)" in (run_dir / "config.toml").read_text()


def test_duration_given_twice_is_an_error(tmp_path, capsys):
    line = _error(["sim", "car-urban", "-o", str(tmp_path / "x"), "--duration", "5",
                   "--set", "duration_s=10"], capsys)  # fmt: skip
    assert "--duration and --set duration_s both given" in line


def test_an_interrupted_simulation_leaves_no_folder(tmp_path, monkeypatch):
    """SIGTERM mid-write left a folder without truth.csv that loaded as a normal drive."""
    from fgins.sim import writer

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(writer, "write_trajectory_csv", interrupted)
    with pytest.raises(KeyboardInterrupt):
        fgins.simulate("car-urban", tmp_path / "new", duration=10)
    assert not (tmp_path / "new").exists()
    assert not [p for p in tmp_path.iterdir() if ".part-" in p.name]


def test_a_sim_folder_with_a_users_output_is_not_rewritten(drive, tmp_path, capsys):
    import shutil

    folder = tmp_path / "drive"
    shutil.copytree(drive, folder)
    (folder / "track.csv").write_text("time\n")
    line = _error(["sim", "car-urban", "-o", str(folder), "--duration", "5"], capsys)
    assert "a folder fgins sim wrote that now also holds other files (track.csv)" in line


def test_fleet_refuses_absurd_worker_counts_and_a_missing_config_before_starting(
    drive, tmp_path, capsys
):
    """--workers 64 on 2 CPUs hung (and ignored SIGTERM); a missing --config failed every
    drive separately after a cluster had started."""
    import os

    too_many = 4 * (os.cpu_count() or 1) + 1
    line = _error(["fleet", str(drive), "-o", str(tmp_path / "f"), "--workers", str(too_many)],
                  capsys)  # fmt: skip
    assert "more than 4 per CPU" in line
    line = _error(["fleet", str(drive), "-o", str(tmp_path / "f"), "--config",
                   str(tmp_path / "nope.toml")], capsys)  # fmt: skip
    assert "nope.toml not found" in line
    assert not (tmp_path / "f").exists()


def test_bench_with_no_outage_or_no_result_is_an_error(drive, tmp_path, capsys):
    """Both exited 0 with a table of NaN (and an empty JSON)."""
    line = _error(["bench", str(drive), "--methods", "ekf", "--gnss-outage", "100:120",
                   "-o", str(tmp_path / "b1")], capsys)  # fmt: skip
    assert "withholds no GNSS epoch" in line
    code = cli.main(["bench", str(drive), "--methods", "ekf", "--gnss-outage", "0:19.5",
                     "-o", str(tmp_path / "b2")])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and "bench: no method produced a result (ekf: " in err, err
    assert not (tmp_path / "b1").exists() and not (tmp_path / "b2").exists()


def test_plot_refuses_strings_dicts_and_another_drives_dataset(drive, tmp_path):
    dataset = fgins.load(drive)
    other = fgins.load(fgins.simulate("highway", tmp_path / "hw", duration=20))
    track = fgins.smooth(dataset, "ekf")
    for bad in ("car", {"a": track}):
        with pytest.raises(fgins.InputError, match="must be a Trajectory"):
            fgins.plot(bad, dataset)
    with pytest.raises(fgins.ConfigError, match="was smoothed from"):
        fgins.plot(track, other)
    fgins.plot(track, dataset)  # the right pair draws


def test_a_sim_folders_own_config_given_as_config_says_what_it_is(drive):
    with pytest.raises(fgins.ConfigError, match=r"config\.toml of a folder fgins sim wrote"):
        fgins.load(drive, config=drive / "config.toml")


def test_outage_windows_are_a_config_error_in_either_form(drive):
    """The string form raised the base FginsError naming the CLI's --gnss-outage flag; the
    list form a ConfigError: both are the same mistake."""
    dataset = fgins.load(drive)
    with pytest.raises(fgins.ConfigError, match=r"^gnss_outage: 'abc' is not START:END"):
        fgins.smooth(dataset, "ekf", gnss_outage="abc")
    with pytest.raises(fgins.ConfigError, match=r"^gnss_outage: window"):
        fgins.smooth(dataset, "ekf", gnss_outage=[(30, 10)])


def test_cli_numbers_are_named_by_their_flags_and_bench_shows_its_signature(
    drive, tmp_path, capsys
):
    """The CLI said 'simulate(): duration must be ...' (the API's wording) for --duration nan;
    inspect.signature(fgins.bench) showed (*args, **kwargs)."""
    import inspect

    import fgins.bench.metrics  # the package then stands for the function

    assert _error(["sim", "car-urban", "-o", str(tmp_path / "s"), "--duration", "nan"],
                  capsys).endswith("--duration nan: must be a positive number of seconds")  # fmt: skip
    assert "--seed -1: must be 0 or more" in _error(
        ["sim", "car-urban", "-o", str(tmp_path / "s"), "--seed", "-1"], capsys
    )
    assert "--outage-duration nan" in _error(
        ["bench", str(drive), "--outage-duration", "nan", "-o", str(tmp_path / "b")], capsys
    )
    assert list(inspect.signature(fgins.bench).parameters)[:3] == ["dataset", "methods", "outages"]


def test_a_plot_the_system_refuses_after_the_solve_says_the_csv_is_complete(drive, tmp_path, capsys, monkeypatch):
    """A place that passes the check but refuses the file (a pseudo file system): exit 2 and
    the trajectory CSV, complete, in place; the error now says so (it read as a failed run)."""
    from fgins import api
    from fgins.datatypes import OutputError

    def refuse(*args, **kwargs):
        raise OutputError("cannot write /proc/x.png: No such file or directory")

    monkeypatch.setattr(api, "plot", refuse)
    out = tmp_path / "out.csv"
    assert cli.main(["smooth", str(drive), "-o", str(out), "--plot", str(tmp_path / "x.png"), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("fgins: error: cannot write") and f"{out} is complete" in err, err
    assert out.stat().st_size > 0


def test_sim_to_a_place_the_system_refuses_is_one_line_naming_the_users_folder(tmp_path, capsys, monkeypatch):
    """`fgins sim -o /proc/x` exited 1 naming the writer's staging folder; a 300-character
    name exited 1 with the system's text. Both are exit 2, the user's path, the limit said."""
    import fgins.sim.writer as writer

    long_name = tmp_path / ("a" * 300)
    assert cli.main(["sim", "car-urban", "-o", str(long_name), "--duration", "5"]) == 2
    err = capsys.readouterr().err.strip()
    assert "file name too long (300 bytes" in err and "\n" not in err

    def refuse(run, folder):
        raise FileNotFoundError(2, "No such file or directory", str(folder.parent / ".x.part-1"))

    monkeypatch.setattr(writer, "write_sim_dir", refuse)
    target = tmp_path / "drive"
    assert cli.main(["sim", "car-urban", "-o", str(target), "--duration", "5"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == f"fgins: error: {target}: cannot write the simulation there (No such file or directory)"
