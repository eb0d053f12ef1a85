"""Outside tester h3, items B4, B5, B7, B8a-c: repeated options, a signal during the heavy
imports, ``inspect`` on binary files and three misleading messages, through the real CLI.
"""

from __future__ import annotations

import random
import shutil
import sys
import types
from pathlib import Path

import pytest

import fgins
from fgins import cli, entry
from fgins.cli import main
from fgins.tests.cli_checks import cli_error

BINARY = "binary content that is none of the formats fgins reads"


@pytest.fixture(scope="module")
def drive(tmp_path_factory) -> Path:
    return fgins.simulate(
        "car-urban", tmp_path_factory.mktemp("cli_repeats") / "drive", duration=20, seed=3
    )



def _argparse_refusal(capsys, argv: list[str]) -> str:
    """The one stderr line of a command line argparse refuses (exit 2)."""
    capsys.readouterr()
    with pytest.raises(SystemExit) as stopped:
        main(argv)
    assert stopped.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith("fgins: error: "), err
    return err[0].removeprefix("fgins: error: ")


# --- B5: a single-value option given twice is refused, not last-wins -------------------------


@pytest.mark.parametrize(
    ("argv", "option", "first", "second"),
    [
        (["smooth", "{d}", "--config", "a.toml", "--config", "b.toml", "-o", "x.csv"],
         "--config", "a.toml", "b.toml"),
        (["smooth", "{d}", "--method", "ukf", "--method", "ekf", "-o", "x.csv"],
         "--method", "ukf", "ekf"),
        (["smooth", "{d}", "--method=ukf", "--method=ekf", "-o", "x.csv"],
         "--method", "ukf", "ekf"),
        (["smooth", "{d}", "-o", "a.csv", "-o", "b.csv"], "-o", "a.csv", "b.csv"),
        (["smooth", "{d}", "-o", "a.csv", "--output", "b.csv"], "-o/--output", "a.csv", "b.csv"),
        (["smooth", "{d}", "-o", "a.csv", "--plot", "a.png", "--plot", "b.png"],
         "--plot", "a.png", "b.png"),
        (["smooth", "{d}", "-o", "a.csv", "--time-offset", "1", "--time-offset", "2"],
         "--time-offset", "1.0", "2.0"),
        (["smooth", "{d}", "-o", "a.csv", "--imu-preset", "consumer-mems", "--imu-preset",
          "tactical"], "--imu-preset", "consumer-mems", "tactical"),
        (["smooth", "{d}", "-o", "a.csv", "--vehicle", "car", "--vehicle", "uav"],
         "--vehicle", "car", "uav"),
        (["smooth", "{d}", "-o", "a.csv", "--robust", "huber", "--robust", "none"],
         "--robust", "huber", "none"),
        (["smooth", "{d}", "-o", "a.csv", "--imu-topic", "/a", "--imu-topic", "/b"],
         "--imu-topic", "/a", "/b"),
        (["bench", "{d}", "--methods", "ekf", "--methods", "batch"], "--methods", "ekf", "batch"),
        (["bench", "{d}", "--baseline", "ekf", "--baseline", "batch"], "--baseline", "ekf",
         "batch"),
        (["bench", "{d}", "--outage-duration", "10", "--outage-duration", "20"],
         "--outage-duration", "10.0", "20.0"),
        (["bench", "{d}", "-o", "a", "-o", "b"], "-o", "a", "b"),
        (["bench", "{d}", "--config", "a.toml", "--config", "b.toml"], "--config", "a.toml",
         "b.toml"),
        (["demo", "--method", "ekf", "--method", "batch"], "--method", "ekf", "batch"),
        (["demo", "-o", "a", "-o", "b"], "-o", "a", "b"),
        (["fleet", "{d}", "-o", "a", "-o", "b"], "-o", "a", "b"),
        (["fleet", "{d}", "-o", "a", "--format", "csv", "--format", "kml"], "--format", "csv",
         "kml"),
        (["fleet", "{d}", "-o", "a", "--workers", "1", "--workers", "2"], "--workers", "1", "2"),
        (["convert", "{d}/gnss.csv", "-o", "a.csv", "-o", "b.csv"], "-o", "a.csv", "b.csv"),
        (["convert", "{d}/gnss.csv", "-o", "a.csv", "--time-offset", "1", "--time-offset",
          "2"], "--time-offset", "1.0", "2.0"),
        (["sim", "car-urban", "--seed", "1", "--seed", "2"], "--seed", "1", "2"),
    ],
)  # fmt: skip
def test_a_single_value_option_given_twice_is_refused(
    drive, capsys, no_loading, argv, option, first, second
):
    message = _argparse_refusal(capsys, [item.format(d=drive) for item in argv])
    assert message == f"{option} given twice ({first} and {second}); give it once"


def test_options_given_once_still_parse():
    args = cli.build_parser().parse_args(
        ["smooth", "d", "--config", "c.toml", "--method", "ekf", "-o", "x.csv"]
    )
    assert (str(args.config), args.method, str(args.output)) == ("c.toml", "ekf", "x.csv")
    assert cli.build_parser().parse_args(["demo"]).method == "batch"  # defaults untouched


def _withheld(capsys, argv: list[str]) -> str:
    capsys.readouterr()
    assert main(argv) == 0
    lines = [line for line in capsys.readouterr().err.splitlines() if "withheld by outage" in line]
    assert len(lines) == 1, lines
    return lines[0]


def test_repeated_gnss_outage_withholds_every_window(drive, tmp_path, capsys):
    """``--gnss-outage 2:5 --gnss-outage 10:13`` is ``2:5,10:13`` (it withheld only 10:13)."""
    common = ["smooth", str(drive), "--method", "ekf", "--no-progress"]
    repeated = _withheld(capsys, [*common, "--gnss-outage", "2:5", "--gnss-outage", "10:13",
                                  "-o", str(tmp_path / "a.csv")])  # fmt: skip
    joined = _withheld(capsys, [*common, "--gnss-outage", "2:5,10:13",
                                "-o", str(tmp_path / "b.csv")])  # fmt: skip
    last = _withheld(capsys, [*common, "--gnss-outage", "10:13", "-o", str(tmp_path / "c.csv")])
    assert repeated == joined != last
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()


@pytest.fixture
def recorded(monkeypatch):
    """What each command receives as ``args.gnss_outage`` (the command itself not run)."""
    seen: dict[str, object] = {}

    def record(args) -> int:
        seen[args.command] = args.gnss_outage
        return 0

    for command in ("smooth", "demo", "bench", "fleet"):
        monkeypatch.setitem(cli.COMMANDS, command, record)
    return seen


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["smooth", "d", "-o", "x.csv"], None),
        (["smooth", "d", "-o", "x.csv", "--gnss-outage", "1:2,3:4"], "1:2,3:4"),
        (["smooth", "d", "-o", "x.csv", "--gnss-outage", "1:2", "--gnss-outage=-9:-5,3:4"],
         "1:2,-9:-5,3:4"),
        (["smooth", "d", "-o", "x.csv", "--gnss-outage", "1:2", "--gnss-outage", "-9:-5"],
         "1:2,-9:-5"),
        (["demo"], "150:180"),
        (["demo", "--gnss-outage", "10:20"], "10:20"),
        (["demo", "--gnss-outage", "10:20", "--gnss-outage", "30:40"], "10:20,30:40"),
        (["bench", "d"], None),
        (["bench", "d", "--gnss-outage", "10:20", "--gnss-outage", "30:40"], "10:20,30:40"),
        (["fleet", "d", "-o", "o", "--gnss-outage", "10:20", "--gnss-outage", "30:40"],
         "10:20,30:40"),
    ],
)  # fmt: skip
def test_gnss_outage_occurrences_are_joined_for_every_command(recorded, argv, expected):
    assert main(argv) == 0
    assert recorded[argv[0]] == expected


def test_an_empty_gnss_outage_among_several_is_still_an_error(recorded, capsys):
    message = cli_error(capsys, ["demo", "--gnss-outage", "10:20", "--gnss-outage", " "])
    assert message.startswith("--gnss-outage: no window given")
    assert "demo" not in recorded


# --- B8a-c: three misleading messages --------------------------------------------------------


@pytest.mark.parametrize("window", ["10:inf", "-inf:10", "nan:20", "10:20,30:inf"])
def test_a_window_that_is_not_finite_says_so(drive, tmp_path, capsys, no_loading, window):
    message = cli_error(
        capsys, ["smooth", str(drive), f"--gnss-outage={window}", "-o", str(tmp_path / "x.csv")]
    )
    assert "START and END must be finite numbers" in message
    assert "START < END" not in message


def test_a_reversed_window_still_says_start_before_end(drive, tmp_path, capsys, no_loading):
    message = cli_error(
        capsys, ["smooth", str(drive), "--gnss-outage", "20:10", "-o", str(tmp_path / "x.csv")]
    )
    assert message.endswith("must have START < END")


@pytest.mark.parametrize(
    ("argv", "suffixes"),
    [
        (["smooth", "{d}", "-o", "{o}"], ".csv, .geojson, .kml, .mcap, .tum"),
        (["smooth", "{d}", "-o", "{o}/"], ".csv, .geojson, .kml, .mcap, .tum"),
        (["smooth", "{d}", "-o", "{t}/x.csv", "--plot", "{o}"], ".png, .pdf, .svg"),
        (["convert", "{d}/gnss.csv", "-o", "{o}"], ".csv, .geojson, .kml, .tum"),
    ],
)
def test_output_that_is_an_existing_folder_is_named_a_folder(
    drive, tmp_path, capsys, no_loading, argv, suffixes
):
    folder = tmp_path / "o2"
    folder.mkdir()
    message = cli_error(capsys, [a.format(d=drive, o=folder, t=tmp_path) for a in argv])
    assert message.endswith(f": is a folder; give a file name (ending in {suffixes})")
    assert "format must be one of" not in message
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o2"]


@pytest.mark.parametrize("command", ["smooth", "bench"])
def test_demo_kitti_given_twice_names_the_repeat(tmp_path, capsys, no_loading, command):
    out = ["-o", str(tmp_path / ("x.csv" if command == "smooth" else "b"))]
    message = cli_error(capsys, [command, "demo:kitti", "demo:kitti", *out])
    assert message.startswith("demo:kitti given twice (once is enough)")
    assert not message.rstrip().endswith("not with")


# --- B7: inspect on binary content -----------------------------------------------------------


def _binary_files(folder: Path) -> dict[str, Path]:
    noise = random.Random(7).randbytes(4096)
    files = {
        "random.bin": noise,
        "picture.png": b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR" + noise[:2000],
        "archive.gz": b"\x1f\x8b\x08\x00" + noise[:3000],
    }
    for name, data in files.items():
        (folder / name).write_bytes(data)
    return {name: folder / name for name in files}


@pytest.mark.parametrize("name", ["random.bin", "picture.png", "archive.gz"])
def test_inspect_of_binary_content_is_the_error_smooth_gives(drive, tmp_path, capsys, name):
    path = _binary_files(tmp_path)[name]
    inspected = cli_error(capsys, ["inspect", str(path)])
    smoothed = cli_error(
        capsys, ["smooth", str(path), str(drive / "imu.csv"), "-o", str(tmp_path / "x.csv")]
    )
    assert inspected == smoothed
    assert inspected.startswith(f"{path}: {BINARY}")
    assert "NMEA" not in capsys.readouterr().out


def test_inspect_of_an_mcap_under_another_name_summarises_it(tmp_path, capsys):
    sys.path.insert(0, str(Path(__file__).parent))
    from mcap_fixtures import make_drive, write_ros2_bag

    mcap = write_ros2_bag(tmp_path / "bag", make_drive(duration_s=5.0))
    renamed = tmp_path / "drive.bin"
    shutil.copyfile(mcap, renamed)
    capsys.readouterr()
    assert main(["inspect", str(renamed)]) == 0
    out = capsys.readouterr().out
    assert "sensor_msgs/msg/Imu" in out and "NMEA" not in out


def test_inspect_of_nmea_and_csv_is_unchanged(drive, tmp_path, capsys):
    assert main(["inspect", str(drive / "gnss.csv")]) == 0
    assert ": GNSS, " in capsys.readouterr().out
    nmea = tmp_path / "log.nmea"
    nmea.write_text(
        "$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47\n"
        "$GPRMC,123519,A,4807.038,N,01131.000,E,022.4,084.4,230394,003.1,W*6A\n"
    )
    assert main(["inspect", str(nmea)]) == 0
    assert "NMEA" in capsys.readouterr().out


# --- B4: a signal while GTSAM (or any module) initialises ------------------------------------


def _wrapped(signal_exception: BaseException) -> ImportError:
    """What GTSAM's import raises when Ctrl-C lands in numpy's initialisation under it."""
    try:
        try:
            raise signal_exception
        except BaseException as exc:
            raise ImportError("initialization failed") from exc
    except ImportError as error:
        return error


@pytest.fixture
def failing_command(monkeypatch):
    def install(error: BaseException) -> None:
        def command(args) -> int:
            raise error

        monkeypatch.setitem(cli.COMMANDS, "demo", command)

    return install


def test_ctrl_c_inside_an_import_is_an_interruption(failing_command, capsys):
    failing_command(_wrapped(KeyboardInterrupt()))
    assert main(["demo"]) == 130
    assert capsys.readouterr().err == "fgins: interrupted\n"


def test_ctrl_c_inside_an_import_with_debug_is_an_interruption(failing_command, capsys):
    failing_command(_wrapped(KeyboardInterrupt()))
    assert main(["--debug", "demo"]) == 130
    assert capsys.readouterr().err == "fgins: interrupted\n"


def test_sigterm_inside_an_import_is_a_termination(failing_command, capsys):
    failing_command(_wrapped(cli._Terminated()))
    assert main(["demo"]) == 143
    assert capsys.readouterr().err == "fgins: terminated (SIGTERM)\n"


def test_an_interrupt_in_the_context_chain_counts(failing_command, capsys):
    try:
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt:
            raise RuntimeError("cleanup failed") from None  # __context__ only
    except RuntimeError as error:
        failing_command(error)
    assert main(["demo"]) == 130
    assert capsys.readouterr().err == "fgins: interrupted\n"


def test_an_import_error_without_an_interrupt_is_still_an_internal_error(
    failing_command, capsys
):
    failing_command(_wrapped(ValueError("a real bug")))
    assert main(["demo"]) == 1
    assert capsys.readouterr().err.startswith(
        "fgins: internal error: ImportError: initialization failed"
    )


def test_ctrl_c_inside_the_cli_import_is_an_interruption(monkeypatch, capsys):
    """The console entry point, when the signal lands while ``fgins.cli`` itself imports."""

    class Importing(types.ModuleType):
        def __getattr__(self, name):
            raise _wrapped(KeyboardInterrupt())

    monkeypatch.setitem(sys.modules, "fgins.cli", Importing("fgins.cli"))
    assert entry.main() == 130
    assert capsys.readouterr().err == "fgins: interrupted\n"


def test_the_entry_point_lets_other_errors_through(monkeypatch):
    class Importing(types.ModuleType):
        def __getattr__(self, name):
            raise _wrapped(ValueError("a real bug"))

    monkeypatch.setitem(sys.modules, "fgins.cli", Importing("fgins.cli"))
    with pytest.raises(ImportError):
        entry.main()
