"""Write outputs atomically: a failed run never leaves a half-written file behind."""

from __future__ import annotations

import contextlib
import json
import math
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from fgins.datatypes import OutputError


def check_command_folder(
    folder: Path,
    command: str,
    own: set[str],
    written_by_it: bool,
    what: str,
    error: type[Exception] = OutputError,
) -> None:
    """The rule of the commands that write a folder (``fgins sim``, ``bench``, ``fleet``):
    it may be new or empty, or one an earlier run of ``command`` wrote (``written_by_it``)
    holding only names in ``own`` (what that run or this one writes). Anything else in it is
    the user's and is never written over or beside: one ``error`` line, before any work.
    ``what``: what a rewrite would leave the user's files beside ("drive", "benchmark")."""
    if not folder.is_dir():
        return
    entries = sorted(entry.name for entry in folder.iterdir())
    if not entries:
        return
    foreign = [name for name in entries if name not in own]
    shown = ", ".join((foreign or entries)[:4]) + (" ..." if len(foreign or entries) > 4 else "")
    if not written_by_it:
        raise error(
            f"{folder}: the folder is not empty ({shown}) and was not written by fgins "
            f"{command}; give a new or empty folder (nothing was written)"
        )
    if foreign:
        raise error(
            f"{folder}: a folder fgins {command} wrote that now also holds other files "
            f"({shown}); rewriting it would leave them beside a different {what}: move them, "
            "or give a new or empty folder (nothing was written)"
        )


@contextlib.contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path``; move it into place only if the block succeeds."""
    target = Path(path)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(
            prefix=f".{target.name}.", suffix=".part", dir=target.parent
        )
    except OSError as exc:
        raise _cannot_write(target, exc) from None
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        yield tmp
        # mkstemp creates the file 0600; give the result the usual umask-based mode.
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, target)
    except OSError as exc:
        if exc.errno is None:
            raise
        raise _cannot_write(target, exc) from None
    finally:
        if tmp.exists():
            tmp.unlink()


def _cannot_write(target: Path, exc: OSError) -> OutputError:
    """The machine refused the output (disk full, no permission, a read-only or virtual
    folder): one line naming the user's path, not the temporary one (outside tester: disk
    full was an "internal error", and the API raised a bare OSError)."""
    reason = exc.strerror or str(exc)
    return OutputError(f"cannot write {target}: {reason}")


def json_safe(value: Any) -> Any:
    """``value`` as JSON can carry it: NaN and inf (which JSON has not; Python would write
    ``NaN``, which other readers refuse) as null, numpy scalars and arrays as numbers and
    lists, tuples as lists."""
    if hasattr(value, "tolist") and not isinstance(value, (str, bytes)):
        value = value.tolist()  # numpy scalar or array
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return value


def write_json(path: str | Path, value: Any) -> None:
    """``value`` (see :func:`json_safe`) as indented JSON, written atomically."""
    with atomic_path(path) as tmp:
        tmp.write_text(json.dumps(json_safe(value), indent=2, allow_nan=False) + "\n")
