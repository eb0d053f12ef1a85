"""Checks of what the ``fgins`` command prints, shared by the CLI tests."""

from __future__ import annotations

from fgins.cli import main


def cli_error(capsys, argv: list[str]) -> str:
    """The one line ``fgins: error: ...`` that ``argv`` gives (exit 2), without the prefix."""
    capsys.readouterr()
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("fgins: error: "), err
    return err[0].removeprefix("fgins: error: ")
