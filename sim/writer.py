"""Write a simulated run as the folder ``fgins sim`` produces (DESIGN.md).

imu.csv (accel_array.csv instead for a gyro-free IMU, whose IMU is derived on reading),
gnss.csv, baro.csv (when there is a barometer), config.toml and truth.csv, each written
atomically. tomllib only reads TOML, so config.toml comes from the small emitter here.
"""

from __future__ import annotations

import math
import os
import shutil
import tempfile
from pathlib import Path
from typing import Any

from fgins.datatypes import InputError, OutputError
from fgins.io.accel_array_csv import (
    ACCEL_ARRAY_FILE,
    accel_array_table,
    write_accel_array_csv,
)
from fgins.io.atomic import atomic_path, check_command_folder
from fgins.io.csv_pair import write_baro_csv, write_gnss_csv, write_imu_csv
from fgins.io.trajectory_csv import write_trajectory_csv
from fgins.sim.scenarios import SimRun


def toml_value(value: Any, where: str = "") -> str:
    """One TOML value: bool, int, float, str, list (inline array) or dict (inline table)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        escaped = value.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")
        return f'"{escaped}"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(toml_value(v, where) for v in value) + "]"
    if isinstance(value, dict):
        items = ", ".join(f"{toml_key(k)} = {toml_value(v, where)}" for k, v in value.items())
        return "{ " + items + " }" if items else "{}"
    # numpy scalars and the like
    if hasattr(value, "item"):
        return toml_value(value.item(), where)
    raise InputError(f"config.toml: cannot write {type(value).__name__} value at {where}")


def toml_key(key: str) -> str:
    if key and all(c.isalnum() or c in "_-" for c in key):
        return key
    return toml_value(str(key))


def dumps_toml(tables: dict[str, dict[str, Any]]) -> str:
    """Top-level tables of scalars / arrays / inline tables as TOML text."""
    lines: list[str] = []
    for name, table in tables.items():
        if lines:
            lines.append("")
        lines.append(f"[{toml_key(name)}]")
        for key, value in table.items():
            lines.append(f"{toml_key(key)} = {toml_value(value, f'{name}.{key}')}")
    return "\n".join(lines) + "\n"


SIM_FILES = ("imu.csv", ACCEL_ARRAY_FILE, "gnss.csv", "baro.csv", "config.toml", "truth.csv")


def _is_sim_folder(folder: Path) -> bool:
    """Written by an earlier ``fgins sim``: a config.toml with its [scenario] table."""
    try:
        return "[scenario]" in (folder / "config.toml").read_text(errors="replace")
    except OSError:
        return False


def check_out_dir(folder: str | Path) -> None:
    """A new or empty folder, or one an earlier ``fgins sim`` wrote (rewritten whole: its
    files that this run does not make are removed, so an old baro.csv cannot join a new
    drive). Anything else is the user's data and is never written over. (Whether a new
    folder can be made at all, not under a file, is fgins.api's output check: the caller's.)"""
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise OutputError(f"{folder}: exists and is not a folder; choose another output path")
    # An output the user wrote beside a simulated drive (a track.csv) is never removed.
    check_command_folder(
        folder, "sim", set(SIM_FILES), folder.is_dir() and _is_sim_folder(folder), "drive"
    )  # where to write: an OutputError, as bench's and fleet's (it was an InputError)


def write_sim_dir(run: SimRun, out_dir: str | Path) -> None:
    """Write ``run`` into ``out_dir``: a new or empty folder, or one an earlier run wrote.

    All files are written into a hidden folder beside it first and moved in only when every
    one is complete: an interrupted run (Ctrl-C, SIGTERM, a full disk) leaves the folder as it
    was, never a drive without its truth.csv that would still load as a normal input.
    """
    folder = Path(out_dir)
    check_out_dir(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{folder.name}.part-", dir=folder.parent))
    try:
        written = _write_files(run, staging)
        folder.mkdir(parents=True, exist_ok=True)
        # Files of an earlier scenario this one does not write (its barometer, its array).
        for name in set(SIM_FILES) - written:
            (folder / name).unlink(missing_ok=True)
        for name in sorted(written):
            os.replace(staging / name, folder / name)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _write_files(run: SimRun, folder: Path) -> set[str]:
    """Every file of ``run`` in ``folder``; their names."""
    written = {"gnss.csv", "config.toml", "truth.csv"}
    written.add(ACCEL_ARRAY_FILE if run.dataset.accel_array is not None else "imu.csv")
    if run.dataset.baro is not None:
        written.add("baro.csv")
    dataset = run.dataset
    if dataset.accel_array is not None:
        # Gyro-free IMU: the raw readings are the data; the IMU is derived when reading.
        write_accel_array_csv(dataset.accel_array, folder / ACCEL_ARRAY_FILE)
    else:
        write_imu_csv(dataset.imu, folder / "imu.csv")
    write_gnss_csv(dataset.gnss, folder / "gnss.csv")
    if dataset.baro is not None:
        write_baro_csv(dataset.baro, folder / "baro.csv")
    origin = dataset.origin
    tables: dict[str, dict[str, Any]] = {
        **run.config,
        **(
            {"accel_array": accel_array_table(dataset.accel_array)}
            if dataset.accel_array is not None
            else {}
        ),
        "origin": {"lat": origin.lat, "lon": origin.lon, "alt": origin.alt},
        "scenario": {
            "name": dataset.name,
            "seed": int(dataset.metadata.get("seed", 0)),  # type: ignore[call-overload]
            "vehicle": dataset.vehicle or "",
            "outages": [[a, b] for a, b in run.outages],
            "description": run.description,
            "initial_errors": dict(run.initial_errors),
            # Turns of the motion (s from the first GNSS epoch): where outages hurt most.
            "turns": [[round(a, 3), round(b, 3)] for a, b in run.info.get("turns", [])],
        },
    }
    setup = run.info.get("setup")
    if setup is not None:
        # Documentation of the truth's axes; the mounting the smoother should use is the
        # [smoother] table (absent with write_mounting=false).
        tables["scenario"]["body_frame"] = setup.body_frame
        tables["scenario"]["imu_mounting_rpy_deg"] = list(setup.mounting_rpy_deg)
        tables["scenario"]["bias_model"] = setup.bias_model
    with atomic_path(folder / "config.toml") as tmp:
        tmp.write_text(dumps_toml(tables))
    write_trajectory_csv(run.truth, folder / "truth.csv")
    return written
