"""An input file that holds nothing: named as such before any format's reader sees it."""

from __future__ import annotations

from pathlib import Path

from fgins.datatypes import InputError


def check_not_empty(path: Path) -> None:
    """An empty file, or one of only zero bytes (a log whose writer never flushed), is named
    as such instead of failing a format's header test ("unrecognised CSV header")."""
    if not path.is_file():
        return
    size = path.stat().st_size
    if size == 0:
        raise InputError(f"{path}: empty file (0 bytes)")
    if _only_zeros(path):
        raise InputError(f"{path}: holds only zero bytes ({size:,} of them): no data was written")


def _only_zeros(path: Path) -> bool:
    """Whether every byte is zero (stops at the first chunk that is not)."""
    with path.open("rb") as handle:
        while chunk := handle.read(1 << 20):
            if chunk.strip(b"\x00"):
                return False
    return True
