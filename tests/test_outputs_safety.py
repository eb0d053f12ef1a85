"""Outputs (issue 12): checked before any work, never over an input, never half-written.

Each refused case must: exit 2 with one ``fgins: error:`` line, never reach loading (the
loader is replaced by one that fails the test), write nothing, and leave every input byte
for byte as it was.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

import pytest

import fgins
from fgins import api
from fgins.cli import main
from fgins.tests.cli_checks import cli_error


@pytest.fixture(scope="module")
def drive(tmp_path_factory) -> Path:
    return fgins.simulate(
        "car-urban", tmp_path_factory.mktemp("safety") / "drive", duration=20, seed=7
    )


def _digest(folder: Path) -> dict[str, str]:
    return {
        str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }



def _refused(capsys, argv: list[str], message: str) -> None:
    error = cli_error(capsys, argv)
    assert message in error, error


def test_output_under_a_file_is_refused_before_loading(tmp_path, drive, capsys, no_loading):
    blocker = tmp_path / "notes.txt"
    blocker.write_text("not a folder")
    for output in (blocker / "out.csv", blocker / "deeper" / "out.csv"):
        _refused(capsys, ["smooth", str(drive), "-o", str(output)], "it is a file, not a folder")
    assert blocker.read_text() == "not a folder"


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("out.txt", "output format must be one of .csv, .geojson, .kml, .mcap, .tum"),
        ("out", "output format must be one of"),
    ],
)
def test_unknown_format_is_refused_before_loading(
    tmp_path, drive, capsys, no_loading, name, message
):
    _refused(capsys, ["smooth", str(drive), "-o", str(tmp_path / name)], message)
    assert not (tmp_path / name).exists()


def test_output_that_is_a_folder_is_refused(tmp_path, drive, capsys, no_loading):
    (tmp_path / "out.csv").mkdir()
    _refused(capsys, ["smooth", str(drive), "-o", str(tmp_path / "out.csv")], "is a folder")


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_unwritable_folder_is_refused(tmp_path, drive, capsys, no_loading):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        _refused(capsys, ["smooth", str(drive), "-o", str(locked / "x.csv")], "not writable")
    finally:
        locked.chmod(0o755)


def test_read_only_folder_check_uses_permissions(tmp_path, monkeypatch):
    """The writability check itself (testable as root too): os.access says no -> refused."""
    monkeypatch.setattr(api.os, "access", lambda path, mode: False)
    with pytest.raises(fgins.OutputError, match="is not writable"):
        api.check_output(tmp_path / "x.csv")


def test_never_over_an_input(tmp_path, drive, capsys, no_loading):
    copy = tmp_path / "copy"
    shutil.copytree(drive, copy)
    before = _digest(copy)
    imu, gnss = copy / "imu.csv", copy / "gnss.csv"
    link = tmp_path / "link.csv"
    link.symlink_to(imu)
    hard = tmp_path / "hard.csv"
    os.link(gnss, hard)
    cases = [
        (["smooth", str(imu), str(gnss), "-o", str(imu)], "is an input of this run"),
        (["smooth", str(imu), str(gnss), "-o", str(link)], "is an input of this run"),
        (["smooth", str(imu), str(gnss), "-o", str(hard)], "is an input of this run"),
        # relative spelling of the same file
        (["smooth", str(imu), str(gnss), "-o", str(copy / ".." / "copy" / "gnss.csv")],
         "is an input of this run"),
        # the file names a folder input is read from, inside that folder
        (["smooth", str(copy), "-o", str(copy / "gnss.csv")], "a file name the input folder"),
        (["smooth", str(copy), "-o", str(copy / "truth.csv")], "a file name the input folder"),
        (["smooth", str(copy), "-o", str(copy / "wheel.csv")], "a file name the input folder"),
        # --plot: neither over an input nor over the output itself
        (["smooth", str(imu), str(gnss), "-o", str(tmp_path / "t.csv"), "--plot", str(tmp_path / "t.csv")],
         "plot format must be one of"),
        (["convert", str(gnss), "-o", str(gnss)], "is an input of this run"),
        (["convert", str(gnss), "-o", str(tmp_path / "fixes.mcap")], "GNSS output format"),
    ]  # fmt: skip
    for argv, message in cases:
        _refused(capsys, argv, message)
    assert _digest(copy) == before
    assert not (tmp_path / "t.csv").exists()


def test_plot_over_an_input_is_refused(tmp_path, drive, capsys, no_loading):
    shutil.copytree(drive, tmp_path / "d")
    picture = tmp_path / "d" / "picture.png"
    picture.write_bytes(b"\x89PNG")
    _refused(
        capsys,
        ["smooth", str(tmp_path / "d" / "imu.csv"), str(picture), "-o", str(tmp_path / "o.csv"),
         "--plot", str(picture)],
        "is an input of this run",
    )  # fmt: skip
    assert picture.read_bytes() == b"\x89PNG"


def test_bench_and_demo_outputs_are_checked_first(tmp_path, drive, capsys, no_loading):
    blocker = tmp_path / "results"
    blocker.write_text("x")
    _refused(capsys, ["bench", str(drive), "--methods", "ekf", "-o", str(blocker)], "not a folder")
    _refused(capsys, ["demo", "-o", str(blocker / "sub")], "not a folder")


def test_allowed_output_beside_inputs_works_and_inputs_stay(tmp_path, drive, capsys):
    copy = tmp_path / "copy"
    shutil.copytree(drive, copy)
    before = _digest(copy)
    out = tmp_path / "new" / "deeper" / "track.tum"  # missing folders are created
    assert main(["smooth", str(copy / "imu.csv"), str(copy / "gnss.csv"), "--method", "ekf",
                 "-o", str(out), "--plot", str(tmp_path / "track.png"), "--no-progress"]) == 0  # fmt: skip
    assert out.stat().st_size > 0 and (tmp_path / "track.png").stat().st_size > 0
    assert _digest(copy) == before


def test_failed_write_leaves_no_file(tmp_path, drive, monkeypatch):
    """A writer failing half-way (disk full, a bug) leaves neither the target nor a temp file."""
    track = fgins.smooth(fgins.load(drive), "ekf")
    import fgins.io.trajectory_csv as trajectory_csv
    import fgins.io.trajectory_tum as trajectory_tum


    def half_then_fail(path, rows, *args, **kwargs):
        Path(path).write_text("time,lat\n1,2\n")  # something is on disk when it fails
        raise OSError(28, "No space left on device")

    # (the trajectory CSV is written by its own vectorised writer, write_table, not savetxt)
    for module, attr, name in (
        (trajectory_csv, "write_table", "track.csv"),
        (trajectory_tum.np, "savetxt", "track.tum"),
    ):
        saved = getattr(module, attr)
        monkeypatch.setattr(module, attr, half_then_fail)
        # The API's own error, naming the user's path (it was a bare OSError).
        with pytest.raises(fgins.OutputError, match=f"cannot write .*{name}: No space"):
            track.write(tmp_path / name)
        monkeypatch.setattr(module, attr, saved)
        assert sorted(p.name for p in tmp_path.iterdir()) == []
    # An existing output is kept intact by a failed rewrite.
    track.write(tmp_path / "track.csv")
    good = (tmp_path / "track.csv").read_bytes()
    monkeypatch.setattr(trajectory_csv, "write_table", half_then_fail)
    with pytest.raises(fgins.OutputError):
        track.write(tmp_path / "track.csv")
    assert (tmp_path / "track.csv").read_bytes() == good
    assert sorted(p.name for p in tmp_path.iterdir()) == ["track.csv"]


def test_api_write_refuses_the_inputs_of_its_run(tmp_path, drive):
    shutil.copytree(drive, tmp_path / "d")
    imu = tmp_path / "d" / "imu.csv"
    before = imu.read_bytes()
    track = fgins.smooth(fgins.load(imu, tmp_path / "d" / "gnss.csv"), "ekf")
    with pytest.raises(fgins.OutputError, match="is an input of this run"):
        track.write(imu)
    assert imu.read_bytes() == before


def test_sigterm_mid_write_leaves_no_file_and_exits_143(tmp_path, monkeypatch, capsys):
    """A job scheduler's SIGTERM while an output is being written unwinds like Ctrl-C: the
    atomic writer removes its temporary file, nothing lands under the output's name, exit 143
    with one line, and the previous SIGTERM handler is back afterwards."""
    import signal
    import time

    from fgins import cli
    from fgins.io.atomic import atomic_path

    target = tmp_path / "out.csv"
    before = signal.getsignal(signal.SIGTERM)

    def writing_when_killed(args) -> int:
        with atomic_path(target) as part:
            part.write_text("half a trajectory")
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)  # the handler raises before this ends
        raise AssertionError("SIGTERM did not interrupt the write")

    monkeypatch.setitem(cli.COMMANDS, "demo", writing_when_killed)
    assert cli.main(["demo"]) == 143
    assert capsys.readouterr().err.strip() == "fgins: terminated (SIGTERM)"
    assert sorted(p.name for p in tmp_path.iterdir()) == []
    assert signal.getsignal(signal.SIGTERM) is before


def test_ctrl_c_while_plotting_says_the_trajectory_is_complete(tmp_path, drive, capsys,
                                                               monkeypatch):
    """Ctrl-C while the plot is drawn: the CSV is already complete and in place, so the
    message says so and names the missing plot (outside tester: a bare 'interrupted' left
    the user guessing whether out.csv could be trusted)."""

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(api, "plot", interrupted)
    out, png = tmp_path / "out.csv", tmp_path / "out.png"
    code = main(["smooth", str(drive), "--method", "ekf", "-o", str(out), "--plot", str(png)])
    stderr = capsys.readouterr().err
    assert code == 130
    assert f"interrupted while plotting: {out} is complete, {png} was not written" in stderr
    assert out.exists() and not png.exists()
    assert len(out.read_text().splitlines()) > 100


def test_ctrl_c_while_the_cli_is_imported_is_one_line(monkeypatch, capsys):
    """The console entry point catches Ctrl-C during the CLI's imports (numpy, GTSAM: the
    first half second), which used to print a KeyboardInterrupt traceback."""
    import sys
    import types

    from fgins import entry

    class Importing(types.ModuleType):
        def __getattr__(self, name):
            raise KeyboardInterrupt

    monkeypatch.setitem(sys.modules, "fgins.cli", Importing("fgins.cli"))
    assert entry.main() == 130
    assert capsys.readouterr().err == "fgins: interrupted\n"


def test_ctrl_c_while_the_demo_plots_says_the_trajectory_is_complete(tmp_path, capsys, monkeypatch):
    """The demo's plot interrupted likewise: its CSV complete, the PNG named as missing
    (outside tester: the demo left kitti_ekf.csv without its PNG and said nothing)."""

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(api, "plot", interrupted)
    code = main(["demo", "--method", "ekf", "--output-dir", str(tmp_path)])
    stderr = capsys.readouterr().err
    out, png = tmp_path / "kitti_ekf.csv", tmp_path / "kitti_ekf.png"
    assert code == 130
    assert f"interrupted while plotting: {out} is complete, {png} was not written" in stderr
    assert out.exists() and not png.exists()
