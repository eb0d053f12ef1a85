"""Checks of what the ``fgins`` command prints, shared by the CLI tests."""

from __future__ import annotations

from fgins.cli import main


def cli_error(capsys, argv: list[str]) -> str:
    """The one line ``fgins: error: ...`` that ``argv`` gives (exit 2), without the prefix.
    Before it only ``warning:`` lines (what the input checks found, printed when a solve
    fails: it may be why)."""
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err and err[-1].startswith("fgins: error: "), err
    assert all(line.startswith("warning: ") for line in err[:-1]), err
    return err[-1].removeprefix("fgins: error: ")
