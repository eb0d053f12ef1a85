"""Fleets: smooth many drives in parallel on Dask, one task per drive.

A local ``distributed.LocalCluster`` (worker processes, one thread each, since GTSAM and numpy
bring their own threads) is used by default; a scheduler address connects to an existing
cluster instead. With a remote cluster, every worker needs fgins installed and must see the
drives and the output folder under the same absolute paths (a shared file system).

Each task loads, configures, smooths and writes one drive and returns a small summary dict,
never the trajectory, so results stay cheap to ship back. A failing drive is a summary with
a one-line error; it never stops the rest of the fleet.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import sys
import time
import warnings
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, TextIO

from fgins.datatypes import FginsError, InputError
from fgins.io.atomic import check_command_folder

FORMATS = ("csv", "geojson", "kml", "mcap")
FLEET_JSON = "fleet.json"


@dataclass(frozen=True)
class Drive:
    """One drive: the INPUT items ``load_dataset`` receives and the name of its output."""

    name: str
    inputs: tuple[str, ...]


@dataclass(frozen=True)
class FleetOptions:
    """What every drive of a fleet is smoothed with (mirrors ``fgins smooth`` options).

    The attribute names match the CLI's options.
    """

    method: str = "batch"
    output_format: str = "csv"
    config: Path | None = None
    imu_preset: str | None = None
    vehicle: str | None = None
    robust: str | None = None
    gnss_outage: str | None = None


@dataclass
class FleetResult:
    """Per-drive summaries (in input order) and the timing of the whole fleet."""

    summaries: list[dict[str, Any]]
    wall_seconds: float
    startup_seconds: float
    workers: int
    scheduler: str
    method: str
    extra: dict[str, Any] = field(default_factory=dict)
    # What every drive was smoothed with (FleetOptions as given): a fleet.json whose numbers
    # could not be tied to their outage windows or configuration afterwards (outside tester).
    options: dict[str, Any] = field(default_factory=dict)

    @property
    def failed(self) -> list[dict[str, Any]]:
        return [s for s in self.summaries if s.get("error")]

    @property
    def busy_seconds(self) -> float:
        """Sum of per-drive task times: what one worker alone would have needed."""
        return float(sum(s.get("seconds") or 0.0 for s in self.summaries))

    @property
    def speedup(self) -> float:
        return self.busy_seconds / self.wall_seconds if self.wall_seconds > 0 else float("nan")

    @property
    def efficiency(self) -> float:
        return self.speedup / self.workers if self.workers else float("nan")

    def to_json(self) -> dict[str, Any]:
        from fgins.io.atomic import json_safe

        return json_safe(
            {
                "method": self.method,
                "options": self.options,
                "scheduler": self.scheduler,
                "workers": self.workers,
                "drives_total": len(self.summaries),
                "drives_failed": len(self.failed),
                "wall_seconds": self.wall_seconds,
                "startup_seconds": self.startup_seconds,
                "sum_drive_seconds": self.busy_seconds,
                "speedup": self.speedup,
                "parallel_efficiency": self.efficiency,
                "drives": self.summaries,
            }
        )


# ---------------------------------------------------------------------------------------------
# Which drives


def _read_list_file(item: str) -> list[str]:
    """``@list.txt``: one drive per line; blank lines and ``#`` comments are skipped.
    Relative paths are taken relative to the list file's folder."""
    list_path = Path(item[1:])
    try:
        lines = list_path.read_text().splitlines()
    except OSError as exc:
        raise InputError(
            f"{list_path}: cannot read the drive list ({exc.strerror}); give @FILE with one "
            "drive per line"
        ) from None
    drives = []
    for line in lines:
        entry = line.split("#", 1)[0].strip()
        if entry:
            path = Path(entry).expanduser()
            drives.append(str(path if path.is_absolute() else list_path.parent / path))
    if not drives:
        raise InputError(f"{list_path}: the drive list is empty; put one drive per line")
    return drives


def _drive_stem(path: Path) -> str:
    return path.stem if path.suffix.lower() == ".mcap" else path.name


def expand_drives(items: list[str]) -> list[Drive]:
    """INPUT items (folders, .mcap files, ``@list.txt``) -> drives with unique output names.

    Paths are made absolute so that workers in other processes (or machines sharing the file
    system) find them. Drives whose names collide (e.g. ``a/log.mcap``, ``b/log.mcap``) are
    named after their path below the common folder instead (``a_log``, ``b_log``).
    """
    paths: list[Path] = []
    for item in items:
        entries = _read_list_file(item) if item.startswith("@") else [item]
        paths.extend(Path(os.path.abspath(Path(entry).expanduser())) for entry in entries)
    if not paths:
        raise InputError("no drives given; pass folders, .mcap files or @list.txt")
    seen: set[Path] = set()
    unique, repeated = [], []
    for p in paths:
        (repeated if p in seen else unique).append(p)
        seen.add(p)
    if repeated:
        # Said: "4 inputs, 3 drives" without a word looked like a lost drive.
        twice = repeated[0]
        print(
            f"warning: fleet: {len(paths) - len(unique)} drive(s) given more than once run once "
            f"({twice})",
            file=sys.stderr,
        )
    stems = [_drive_stem(p) for p in unique]
    common = Path(os.path.commonpath([str(p.parent) for p in unique]))
    names = []
    for path, stem in zip(unique, stems, strict=True):
        if stems.count(stem) > 1:
            relative = path.with_name(stem).relative_to(common)
            stem = "_".join(relative.parts)
        names.append(stem or "drive")
    return [Drive(name, (str(path),)) for name, path in zip(names, unique, strict=True)]


# ---------------------------------------------------------------------------------------------
# One drive (runs on a worker; top level so that it pickles by reference)


def one_line(exc: BaseException) -> str:
    """An exception as one line: the message for fgins errors, the type for anything else."""
    text = str(exc).strip()
    first = text.splitlines()[0] if text else ""
    if isinstance(exc, FginsError):
        return first or type(exc).__name__
    return f"{type(exc).__name__}: {first}" if first else type(exc).__name__


def smooth_drive(drive: Drive, options: FleetOptions, out_dir: str) -> dict[str, Any]:
    """Load, configure, smooth and write one drive; return its small summary.

    Never raises for a bad drive: the error is the summary's one-line ``error``.
    """
    output = Path(out_dir) / f"{drive.name}.{options.output_format}"
    summary: dict[str, Any] = {
        "drive": drive.name,
        "input": drive.inputs[0] if len(drive.inputs) == 1 else list(drive.inputs),
        "method": options.method,
        "states": 0,
        "seconds": None,
        "smooth_seconds": None,
        "imu_samples_per_s": None,
        "h_rms_aided_m": None,
        "chi2_per_dof": None,
        "warnings": 0,
        "warning_lines": [],
        "output": None,
        "error": None,
    }
    started = time.perf_counter()
    try:
        summary.update(_smooth_and_write(drive, options, output))
    except Exception as exc:  # a failing drive must not stop the fleet
        summary["error"] = one_line(exc)
    summary["seconds"] = time.perf_counter() - started
    return summary


def _smooth_and_write(drive: Drive, options: FleetOptions, output: Path) -> dict[str, Any]:
    # Imported here: workers import only on demand. The public API, not the CLI (which imports
    # this module): no import cycle, and a drive runs exactly as `fgins smooth` would.
    from fgins import api
    from fgins.bench.metrics import h_rms_at_used_fixes
    from fgins.outages import parse_windows

    windows = parse_windows(options.gnss_outage)
    # Counted in the summary, not printed by every worker: the solve's as well as the load's
    # (the solve's came on stderr as raw Python warnings with fleet's source line, beside the
    # summary's own line).
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", api.FginsWarning)
        dataset = api.load(
            *drive.inputs, config=options.config, imu_preset=options.imu_preset,
            vehicle=options.vehicle, robust=options.robust,
        )  # fmt: skip
        trajectory = api.smooth(dataset, options.method, gnss_outage=windows)
    elapsed = trajectory.summary()["wall_s"]
    trajectory.write(output)
    # Horizontal RMS against the drive's own GNSS at the fixes the run used: not at those it
    # gated (PDOP, fix quality) or left out as faults, which the fit never followed (outside
    # tester: 9.47 m over all fixes of a car-urban drive, 4.43 m over the 85 it used).
    config = dataset.metadata.get("run_config") or api.configure(dataset)
    h_rms_aided = h_rms_at_used_fixes(trajectory, dataset, config)
    # What the input checks repaired and what the solve found doubtful (an inconsistent
    # fit, a diverged filter): `fgins smooth` prints both; a fleet counted only the first,
    # so a drive whose fit said "the reported sigmas are too small" looked clean.
    found = trajectory.summary()
    lines = [*dataset.warnings, *found.get("fit_warnings", [])]
    said = {str(line) for line in lines}
    lines += [
        str(w.message) for w in caught
        if issubclass(w.category, api.FginsWarning) and str(w.message) not in said
    ]  # fmt: skip
    chi2 = found.get("chi2_per_dof")
    return {
        "method": trajectory.method or options.method,
        "states": len(trajectory),
        "smooth_seconds": elapsed,
        "imu_samples_per_s": len(dataset.imu) / max(elapsed, 1e-9),
        "h_rms_aided_m": h_rms_aided,
        "chi2_per_dof": float(chi2) if chi2 is not None else None,
        "warnings": len(lines),
        "warning_lines": [str(line) for line in lines],
        "output": str(output),
    }


# ---------------------------------------------------------------------------------------------
# The fleet


def check_scheduler_address(address: str) -> str:
    """``address`` if it has the form of a Dask scheduler address (``tcp://host:port``, or
    another scheme Dask knows), else an :class:`InputError` naming ``--scheduler``. Whether a
    scheduler answers there is found on connecting."""
    from distributed.comm.addressing import parse_address, parse_host_port
    from distributed.comm.registry import backends

    try:
        if not isinstance(address, str) or not address.strip() or any(c.isspace() for c in address):
            raise ValueError
        scheme, location = parse_address(address)
        if scheme not in backends:
            raise ValueError
        if scheme != "inproc":
            host, port = parse_host_port(location)
            if not host or not 0 < int(port) < 65536:
                raise ValueError
    except (ValueError, TypeError):
        raise InputError(
            f"--scheduler {address!r}: not a Dask scheduler address; expected tcp://HOST:PORT "
            "(e.g. tcp://10.0.0.5:8786), or omit --scheduler for a local cluster"
        ) from None
    return address


@contextlib.contextmanager
def _client(
    workers: int | None, scheduler: str | None, connect_timeout_s: float = 10.0
) -> Iterator[Any]:
    """A Dask client on a new local cluster, or on the scheduler at ``scheduler``.

    The local cluster is closed on any exit (also Ctrl-C), which stops its worker processes.
    """
    from distributed import Client, LocalCluster

    if scheduler:
        try:
            client = Client(scheduler, timeout=f"{connect_timeout_s}s")
        except (OSError, TimeoutError) as exc:
            raise FginsError(
                f"cannot connect to the Dask scheduler {scheduler} ({one_line(exc)}); check the "
                "address (tcp://host:port) or omit --scheduler for a local cluster"
            ) from None
        with client:
            yield client
        return
    n_workers = workers or os.cpu_count() or 1
    if n_workers < 1:
        raise InputError(f"--workers {n_workers}: need at least 1 worker")
    with _workers_ignore_ctrl_c():
        cluster = LocalCluster(
            n_workers=n_workers,
            threads_per_worker=1,  # GTSAM and numpy already use threads of their own
            processes=True,
            dashboard_address=None,
            silence_logs=logging.WARNING,
        )
    with cluster, Client(cluster) as client:
        yield client


@contextlib.contextmanager
def _workers_ignore_ctrl_c() -> Iterator[None]:
    """Start worker processes with SIGINT ignored (an ignored signal survives exec).

    A terminal's Ctrl-C reaches every process of the group: the workers would each die with a
    traceback. This way only this process sees it, and it closes the cluster, which stops them.
    """
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield  # signal handlers can only be changed from the main thread
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


def _quiet_teardown() -> None:
    """Silence the event loop's and Dask's loggers while an interrupted fleet closes.

    Closing a cluster mid-task makes tornado log the callbacks it cuts off as "Exception in
    callback ... Traceback" (seen twice in ~40 tries, under load): noise after a stop
    the user asked for, and a traceback is what a Ctrl-C must not print.
    """
    for name in ("tornado", "asyncio", "distributed"):
        logging.getLogger(name).setLevel(logging.CRITICAL + 1)


def _failed_task_summary(drive: Drive, options: FleetOptions, exc: BaseException) -> dict:
    """Summary of a drive whose task itself failed (worker died, could not unpickle, ...)."""
    return {
        "drive": drive.name,
        "input": drive.inputs[0] if len(drive.inputs) == 1 else list(drive.inputs),
        "method": options.method,
        "states": 0,
        "seconds": None,
        "error": f"task failed: {one_line(exc)}",
    }


def run_fleet(
    drives: list[Drive],
    options: FleetOptions,
    out_dir: str | Path,
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    progress: bool = True,
    connect_timeout_s: float = 10.0,
) -> FleetResult:
    """Smooth ``drives`` in parallel; write ``out_dir/<drive>.<format>`` and ``fleet.json``."""
    from distributed import as_completed
    from tqdm import tqdm

    if options.output_format not in FORMATS:
        raise InputError(
            f"output format {options.output_format!r}: choose one of {', '.join(FORMATS)}"
        )
    if scheduler is not None:
        check_scheduler_address(scheduler)
    names = [d.name for d in drives]
    if len(set(names)) != len(names):
        raise InputError("two drives share an output name; rename one of them")
    out_path = Path(os.path.abspath(out_dir))
    if out_path.exists() and not out_path.is_dir():
        raise InputError(f"{out_path}: exists and is not a folder; choose another -o")
    outputs = {f"{d.name}.{options.output_format}" for d in drives}
    earlier = check_fleet_dir(out_path, outputs)  # before a cluster starts
    out_path.mkdir(parents=True, exist_ok=True)
    if earlier or (out_path / FLEET_JSON).exists():
        # A run into an earlier fleet's folder rewrites its drive files one by one: until this
        # fleet's summary replaces it, the folder's fleet.json says it is incomplete (an
        # interrupted re-run had left new drive files beside the old summary, which described
        # them wrongly: outside tester). It lists every drive file, so the folder stays the
        # fleet's to rewrite.
        _write_incomplete(out_path / FLEET_JSON, out_path, earlier | outputs)
    # Workers may run in other processes or on other machines: give them absolute paths.
    if options.config is not None:
        options = replace(options, config=Path(os.path.abspath(options.config)))
    logging.getLogger("distributed").setLevel(logging.WARNING)

    started = time.perf_counter()
    with _client(workers, scheduler, connect_timeout_s) as client:
        n_workers = sum(w["nthreads"] for w in client.scheduler_info()["workers"].values())
        address = client.scheduler.address if scheduler else "local"
        submitted = time.perf_counter()
        futures = client.map(
            smooth_drive, drives, options=options, out_dir=str(out_path), pure=False
        )
        drive_of = {future.key: drive for future, drive in zip(futures, drives, strict=True)}
        summaries: dict[str, dict[str, Any]] = {}
        bar = tqdm(total=len(drives), desc="drives", unit="drive", disable=not progress)
        try:
            for future in as_completed(futures):
                drive = drive_of[future.key]
                try:
                    summary = future.result()
                except Exception as exc:
                    summary = _failed_task_summary(drive, options, exc)
                summaries[drive.name] = summary
                bar.update()
                bar.set_postfix(failed=sum(1 for s in summaries.values() if s.get("error")))
        except BaseException as exc:
            # Ctrl-C: a shared scheduler drops our queued work; a local cluster just closes.
            if isinstance(exc, KeyboardInterrupt):
                _quiet_teardown()
            if scheduler:
                client.cancel(futures)
            raise
        finally:
            bar.close()
        finished = time.perf_counter()
    result = FleetResult(
        summaries=[summaries[d.name] for d in drives],
        wall_seconds=finished - submitted,
        startup_seconds=submitted - started,
        workers=n_workers,
        scheduler=address,
        method=options.method,
        options={k: (str(v) if isinstance(v, Path) else v) for k, v in asdict(options).items()},
    )
    write_fleet_json(result, out_path / FLEET_JSON)
    # An earlier fleet's drive files this one did not write (a drive not in this fleet, one
    # that failed this time, another format): not left beside this fleet.json.
    written = {Path(s["output"]).name for s in result.summaries if s.get("output")}
    for name in earlier - written:
        (out_path / name).unlink(missing_ok=True)
    return result


def _earlier_outputs(folder: Path) -> set[str] | None:
    """The drive files (names in ``folder``) of the fleet.json an earlier ``fgins fleet``
    wrote there, or None when it holds none (or one that is not a fleet's)."""
    import json

    try:
        payload = json.loads((folder / FLEET_JSON).read_text())
        drives = payload["drives"]
        outputs = [d.get("output") for d in drives]
    except (OSError, ValueError, KeyError, TypeError, AttributeError):
        return None
    names = set()
    for output in outputs:
        if isinstance(output, str) and Path(output).parent == folder:
            names.add(Path(output).name)
    return names


def check_fleet_dir(folder: Path, outputs: set[str]) -> set[str]:
    """``folder`` may receive a fleet: a new or empty folder, or one an earlier ``fgins
    fleet`` wrote (its fleet.json and drive files, replaced by this fleet's: an earlier drive
    file this fleet does not write is removed once it is done). Anything else in it is not the
    fleet's to replace: an :class:`InputError` before any work, as ``fgins sim`` treats its
    folder. ``outputs``: this fleet's drive file names. Returns the earlier drive files."""
    if not folder.is_dir() or not any(folder.iterdir()):
        return set()
    earlier = _earlier_outputs(folder)
    own = {FLEET_JSON, *(earlier or ()), *outputs}
    check_command_folder(folder, "fleet", own, earlier is not None, "fleet", InputError)
    return earlier or set()


def _write_incomplete(path: Path, folder: Path, names: set[str]) -> None:
    from fgins.io.atomic import write_json

    write_json(path, {
        "status": "incomplete",
        "note": "an fgins fleet run was writing this folder and did not finish (interrupted or "
        "failed): the drive files here may come from two runs; run the fleet again",
        "drives": [{"output": str(folder / name)} for name in sorted(names)],
    })  # fmt: skip


def write_fleet_json(result: FleetResult, path: Path) -> None:
    from fgins.io.atomic import write_json

    write_json(path, result.to_json())


# ---------------------------------------------------------------------------------------------
# Reporting


def _number(value: Any, fmt: str) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return format(value, fmt)


def markdown_table(summaries: list[dict[str, Any]]) -> str:
    """The summaries as a markdown table, one row per drive, in input order."""
    header = (
        # "seconds" is the whole drive (reading and writing too), the rate the solve's alone
        # (side by side unnamed, 120,001 states in 23 s read as 27,893 samples/s: outside tester).
        "| drive | method | states | seconds (all) | IMU samples/s (solve) | aided h RMS (m) | chi2/dof "
        "| warnings | result |"
    )
    lines = [header, "|---|---|---:|---:|---:|---:|---:|---:|---|"]
    for s in summaries:
        result = f"FAILED: {s['error']}" if s.get("error") else Path(s["output"]).name
        result = result.replace("|", "\\|")
        lines.append(
            f"| {s['drive']} | {s['method']} | {s.get('states', 0)} "
            f"| {_number(s.get('seconds'), '.2f')} | {_number(s.get('imu_samples_per_s'), ',.0f')} "
            f"| {_number(s.get('h_rms_aided_m'), '.3f')} | {_number(s.get('chi2_per_dof'), '.2f')} "
            f"| {s.get('warnings', 0)} | {result} |"
        )
    return "\n".join(lines)


def timing_line(result: FleetResult) -> str:
    return (
        f"fleet: {len(result.summaries)} drives ({len(result.failed)} failed) on "
        f"{result.workers} workers ({result.scheduler}): wall {result.wall_seconds:.2f} s "
        f"(+{result.startup_seconds:.2f} s cluster start), sum of per-drive times "
        f"{result.busy_seconds:.2f} s, speed-up {result.speedup:.2f}x, parallel efficiency "
        f"{100 * result.efficiency:.0f}%"
    )


def print_report(result: FleetResult, out_dir: Path, stream: TextIO | None = None) -> None:
    stream = stream or sys.stdout  # looked up at call time (tests and callers redirect it)
    print(markdown_table(result.summaries), file=stream)
    print(file=stream)
    for summary in result.summaries:  # one line each, as `fgins smooth` says them
        for line in summary.get("warning_lines") or []:
            print(f"warning: {summary['drive']}: {line}", file=stream)
    print(timing_line(result), file=stream)
    print(f"summaries in {out_dir / FLEET_JSON}", file=stream)
