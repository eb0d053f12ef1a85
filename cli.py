"""The ``fgins`` command: smooth, demo, sim, bench, fleet, convert, inspect.

Every failure is one line on stderr and a non-zero exit; outputs are written atomically.
"""

from __future__ import annotations

import argparse
import math
import os
import signal
import sys
import threading
import warnings
from pathlib import Path
from typing import NoReturn

import numpy as np

from fgins import __version__, api
from fgins.config import IMU_PRESETS, RunConfig
from fgins.datatypes import Dataset, FginsError, OutputError, Trajectory
from fgins.interrupts import interruption
from fgins.io.inputs import check_time_offset
from fgins.outages import parse_windows
from fgins.pipeline import METHODS

OUTPUT_SUFFIXES = api.OUTPUT_SUFFIXES
PLOT_SUFFIXES = api.PLOT_SUFFIXES
GNSS_OUTPUT_SUFFIXES = (".csv", ".geojson", ".kml", ".tum")


#: Where the options given so far are noted on the namespace argparse fills: dest -> the
#: option string and value of its first occurrence.
_GIVEN = "_fgins_given"


def _first_occurrence(
    namespace: argparse.Namespace, action: argparse.Action, option: str | None, value: object
) -> tuple[str, object] | None:
    """Note this occurrence of ``action``; return the earlier one (option string, value) if
    the option was given before on this command line, else None."""
    given = namespace.__dict__.setdefault(_GIVEN, {})
    earlier = given.get(action.dest)
    if earlier is None:
        given[action.dest] = (option or "/".join(action.option_strings), value)
    return earlier


class _Once(argparse.Action):
    """A single-value option that may be given once: a second occurrence (``--config a.toml
    --config b.toml``, ``-o a.csv -o b.csv``) is one ``fgins: error:`` line and exit 2, not
    argparse's silent last-wins (outside tester: a tactical config dropped without a word)."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: object,
        option_string: str | None = None,
    ) -> None:
        earlier = _first_occurrence(namespace, self, option_string, values)
        if earlier is not None:
            first_option, first_value = earlier
            name = (
                option_string if option_string == first_option
                else "/".join(self.option_strings)
            )  # fmt: skip
            parser.exit(
                2,
                f"fgins: error: {name} given twice ({first_value} and {values}); give it once\n",
            )
        setattr(namespace, self.dest, values)


class _AppendWindows(argparse.Action):
    """``--gnss-outage``, repeatable: each occurrence adds its windows (``--gnss-outage 10:20
    --gnss-outage 50:60`` is ``10:20,50:60``); the first replaces the default (demo's
    150:180). The list is joined in the comma form by :func:`_joined_outages`."""

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: object,
        option_string: str | None = None,
    ) -> None:
        if _first_occurrence(namespace, self, option_string, values) is None:
            setattr(namespace, self.dest, [values])
        else:
            getattr(namespace, self.dest).append(values)


def _joined_outages(args: argparse.Namespace) -> None:
    """Every ``--gnss-outage`` given, as one ``A:B,C:D`` string; each occurrence is checked
    on its own first (an empty one is an error, not skipped by the join)."""
    given = getattr(args, "gnss_outage", None)
    if isinstance(given, list):
        for text in given:
            parse_windows(text)
        args.gnss_outage = ",".join(given)


def _check_output(path: Path, *args: object, suffixes=OUTPUT_SUFFIXES, **kwargs) -> Path:
    """``api.check_output``, but an existing folder is named as such first (outside tester:
    ``-o out`` with a folder ``out`` said "output format must be one of ...")."""
    try:
        folder = path.is_dir()
    except OSError:  # a name the system refuses to look at (too long): api.check_output says so
        folder = False
    if folder:
        raise OutputError(
            f"{path}: is a folder; give a file name (ending in {', '.join(suffixes)})"
        )
    return api.check_output(path, *args, suffixes=suffixes, **kwargs)


def _add_sensor_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--config", type=Path, action=_Once,
        help="run configuration TOML ([imu], [gnss], [smoother])",
    )  # fmt: skip
    parser.add_argument(
        "--imu-preset", choices=sorted(IMU_PRESETS), action=_Once, help="IMU grade preset"
    )
    parser.add_argument(
        "--vehicle", choices=["car", "aircraft", "uav", "pedestrian", "other"], action=_Once,
        help="vehicle type (land-vehicle constraints apply to car)",
    )  # fmt: skip
    parser.add_argument(
        "--robust", choices=["huber", "cauchy", "none"], action=_Once,
        help="robust GNSS kernel against outliers: Huber (k=4 sigmas, or the config's "
        "huber_k) or Cauchy (k=3, or the config's cauchy_k), or none (every fix at full "
        "weight, no fault exclusion); default Huber k=4",
    )  # fmt: skip
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")


class _OneLineParser(argparse.ArgumentParser):
    """argparse, but a mistake on the command line is one ``fgins: error:`` line (exit 2, as
    argparse's), not the usage block before it (outside tester: a wrong --method printed 11
    lines). ``--help`` is unchanged."""

    def error(self, message: str) -> NoReturn:
        command = self.prog.removeprefix("fgins").strip()
        where = f"{command}: " if command else ""
        self.exit(
            2,
            f"fgins: error: {where}{message} (see {self.prog} --help)\n",
        )


def build_parser() -> argparse.ArgumentParser:
    parser = _OneLineParser(
        prog="fgins", description="GNSS/INS factor-graph smoothing (GTSAM) with Kalman baselines."
    )
    parser.add_argument("--version", action="version", version=f"fgins {__version__}")
    parser.add_argument("--debug", action="store_true", help="show tracebacks of internal errors")
    sub = parser.add_subparsers(dest="command", required=True)

    smooth = sub.add_parser("smooth", help="estimate the trajectory of a recorded drive")
    smooth.add_argument(
        "inputs", nargs="+", metavar="INPUT",
        help="demo:kitti | FILE.mcap | ROS bag (.bag, ROS 2 bag folder) | UBX log | NMEA + "
        "imu.csv | imu.csv gnss.csv | 'fgins sim' folder",
    )  # fmt: skip
    smooth.add_argument("--method", choices=METHODS, default="batch", action=_Once)
    smooth.add_argument(
        "--gnss-outage", metavar="A:B[,C:D...]", action=_AppendWindows,
        help="withhold GNSS epochs with A <= t - t0 < B (seconds after the first GNSS epoch); "
        "may be repeated",
    )  # fmt: skip
    smooth.add_argument(
        "-o", "--output", type=Path, required=True, action=_Once,
        help="OUT.csv|.geojson|.kml|.mcap|.tum",
    )  # fmt: skip
    smooth.add_argument(
        "--online", action="store_true",
        help="with --method isam2: write the online (filtered) estimate instead of the final one",
    )  # fmt: skip
    smooth.add_argument(
        "--plot", type=Path, action=_Once, help="also write a PNG: track and error vs time"
    )
    smooth.add_argument(
        "--time-offset", type=float, default=0.0, action=_Once,
        help="seconds added to the GNSS times (any input; e.g. -18 for GPS time against UTC)",
    )  # fmt: skip
    smooth.add_argument(
        "--imu-topic", action=_Once, help="MCAP: IMU topic (default: chosen by schema)"
    )
    smooth.add_argument(
        "--gnss-topic", action=_Once, help="MCAP: GNSS topic (default: chosen by schema)"
    )
    smooth.add_argument(
        "--with-input", action="store_true", help="MCAP output: copy input channels"
    )
    _add_sensor_options(smooth)

    demo = sub.add_parser("demo", help="smooth the built-in KITTI drive with one 30 s GNSS outage")
    demo.add_argument("-o", "--output-dir", type=Path, default=Path("out"), action=_Once)
    demo.add_argument("--method", choices=METHODS, default="batch", action=_Once)
    demo.add_argument(
        "--gnss-outage", default="150:180", metavar="A:B[,C:D...]", action=_AppendWindows,
        help="GNSS outage windows (default 150:180); may be repeated",
    )  # fmt: skip
    _add_sensor_options(demo)

    sim = sub.add_parser(
        "sim", help="simulate a scenario: imu.csv, gnss.csv, config.toml, truth.csv"
    )
    sim.add_argument("scenario", help="scenario name ('fgins sim list' lists them)")
    sim.add_argument("-o", "--output-dir", type=Path, action=_Once)
    sim.add_argument("--seed", type=int, default=0, action=_Once)
    sim.add_argument(
        "--duration", type=float, action=_Once, help="shorten the scenario (seconds)"
    )
    sim.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="scenario option"
    )

    bench = sub.add_parser(
        "bench", help="outage benchmark: every method on the same data and outages"
    )
    bench.add_argument("inputs", nargs="+", metavar="INPUT", help="as for smooth")
    bench.add_argument("--methods", default="batch,isam2,ekf,ekf-rts", action=_Once)
    bench.add_argument(
        "--gnss-outage", metavar="A:B[,C:D...]", action=_AppendWindows,
        help="explicit windows; may be repeated",
    )  # fmt: skip
    # The protocol's defaults (30 s every 90 s from 60 s) live in api.bench: any of these
    # given asks for the protocol over a sim folder's own outages.
    bench.add_argument(
        "--outage-duration", type=float, action=_Once,
        help="protocol window length, s (default 30)",
    )  # fmt: skip
    bench.add_argument(
        "--outage-period", type=float, action=_Once,
        help="protocol window spacing, s (default 90)",
    )  # fmt: skip
    bench.add_argument(
        "--outage-start", type=float, action=_Once,
        help="protocol's first window, s after t0 (default 60)",
    )  # fmt: skip
    bench.add_argument(
        "--baseline", action=_Once,
        help="method of --methods the ratios are taken against (default: ekf if run, else the first)",
    )
    bench.add_argument(
        "-o", "--output-dir", type=Path, default=Path("out/bench"), action=_Once
    )
    _add_sensor_options(bench)

    fleet = sub.add_parser(
        "fleet", help="smooth many drives in parallel on Dask (one output per drive)"
    )
    fleet.add_argument(
        "inputs", nargs="+", metavar="INPUT",
        help="drives: folders from 'fgins sim' or with imu.csv + gnss.csv, FILE.mcap, or "
        "@LIST.txt with one drive per line (relative to the list's folder)",
    )  # fmt: skip
    fleet.add_argument(
        "-o", "--output-dir", type=Path, required=True, action=_Once,
        help="folder for <drive>.<format> and fleet.json",
    )  # fmt: skip
    fleet.add_argument("--method", choices=METHODS, default="batch", action=_Once)
    fleet.add_argument(
        "--format", choices=["csv", "geojson", "kml", "mcap"], default="csv", action=_Once,
        help="output format of each drive",
    )  # fmt: skip
    fleet.add_argument(
        "--workers", type=int, action=_Once,
        help="local worker processes (default: number of CPUs)",
    )  # fmt: skip
    fleet.add_argument(
        "--scheduler", metavar="tcp://HOST:PORT", action=_Once,
        help="use an existing Dask scheduler (workers must see the same paths)",
    )  # fmt: skip
    fleet.add_argument(
        "--gnss-outage", metavar="A:B[,C:D...]", action=_AppendWindows,
        help="withhold GNSS epochs with A <= t - t0 < B in every drive; may be repeated",
    )  # fmt: skip
    _add_sensor_options(fleet)

    convert = sub.add_parser(
        "convert", help="write GNSS fixes of a log as gnss.csv/.geojson/.kml or a TUM reference"
    )
    convert.add_argument("input", type=Path)
    convert.add_argument("-o", "--output", type=Path, required=True, action=_Once)
    convert.add_argument("--time-offset", type=float, default=0.0, action=_Once)
    convert.add_argument(
        "--imu", action="store_true", help="UBX: write the receiver's IMU as imu.csv instead"
    )

    inspect = sub.add_parser("inspect", help="summarise what a log (NMEA, MCAP, CSV) contains")
    inspect.add_argument("input", type=Path)
    return parser


def _progress(args: argparse.Namespace) -> bool:
    return not getattr(args, "no_progress", False) and sys.stderr.isatty()


def _config_for(dataset: Dataset, args: argparse.Namespace) -> RunConfig:
    return api.configure(
        dataset, args.config, imu_preset=args.imu_preset, vehicle=args.vehicle,
        robust=getattr(args, "robust", None),
    )  # fmt: skip


def _load(args: argparse.Namespace, inputs: list[str], **options) -> Dataset:
    """``fgins.load`` with the sensor options; its warnings are printed by :func:`_report`."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", api.FginsWarning)
        return api.load(
            *inputs, config=args.config, imu_preset=args.imu_preset, vehicle=args.vehicle,
            robust=getattr(args, "robust", None), progress=_progress(args), **options,
        )  # fmt: skip


def _report_input(dataset: Dataset) -> None:
    for line in dataset.metadata.get("mcap_report", []):
        print(line, file=sys.stderr)
    for warning in dataset.warnings:
        print(f"warning: {warning}", file=sys.stderr)


def _report(dataset: Dataset, trajectory: Trajectory) -> None:
    _report_input(dataset)
    summary = trajectory.summary()
    for key in ("vehicle_model", "gnss_gating", "gnss_rejected", "gnss_excluded", "gnss_correlation",
                "gnss_time_unresolved", "stops_moving", "imu_bias_model", "solver"):  # fmt: skip
        if key in summary:
            print(summary[key], file=sys.stderr)
    for warning in summary.get("fit_warnings", []):
        print(f"warning: {warning}", file=sys.stderr)
    if "odometer_scale_error" in summary:
        print(
            f"odometer scale-factor error: {100 * summary['odometer_scale_error']:+.2f} %"
            + _wheel_weights(summary),
            file=sys.stderr,
        )
    if "nhc_misalignment_deg" in summary:
        print(f"NHC misalignment (deg): {summary['nhc_misalignment_deg']}", file=sys.stderr)


def _wheel_weights(summary: dict[str, object]) -> str:
    """``; 12 of 480 wheel speeds beyond 3 sigma ..., down-weighted by its Cauchy kernel``."""
    return f"; {summary['wheel_weights']}" if "wheel_weights" in summary else ""


def _check_demo_alone(inputs: list[str]) -> None:
    """``demo:kitti demo:kitti``: named here, as a repeated file is (the loader's "give it
    alone, not with ..." had no other input to name)."""
    if inputs.count("demo:kitti") > 1:
        raise FginsError(
            "demo:kitti given twice (once is enough): it is a whole drive on its own (IMU and "
            "GNSS); give it once, alone"
        )


def cmd_smooth(args: argparse.Namespace) -> int:
    _check_demo_alone(args.inputs)
    # Every output is checked before any work (a bad path is not found after the solve).
    args.output = _check_output(args.output, args.inputs)
    if args.with_input:
        api._check_with_input(args.inputs, args.output)
    if args.plot:
        args.plot = _check_output(
            args.plot, [*args.inputs, args.output], suffixes=PLOT_SUFFIXES, what="plot"
        )
    windows = parse_windows(args.gnss_outage)
    dataset = _load(
        args, args.inputs, time_offset=args.time_offset, imu_topic=args.imu_topic,
        gnss_topic=args.gnss_topic,
    )  # fmt: skip
    try:
        trajectory = api.smooth(
            dataset, args.method, gnss_outage=windows, online=args.online,
            progress=_progress(args),
        )  # fmt: skip
    except FginsError:
        _report_input(dataset)  # what the input checks found may be why (a dead axis)
        raise
    trajectory.write(args.output, with_input=args.with_input)
    _report(dataset, trajectory)
    summary = trajectory.summary()
    elapsed = summary["wall_s"]
    print(
        f"{summary['method']}: {summary['states']} states over {summary['duration_s']:.1f} s "
        f"in {elapsed:.2f} s ({summary['imu_samples'] / max(elapsed, 1e-9):,.0f} IMU samples/s) "
        f"-> {args.output}",
        file=sys.stderr,
    )
    if args.plot and not _plotted(trajectory, dataset, windows, args.output, args.plot):
        return 130
    return 0


def _plotted(trajectory, dataset, windows, written: Path, png: Path) -> bool:
    """Plot ``trajectory`` into ``png``; False (said) when interrupted: the trajectory in
    ``written`` is complete and in place, only the plot is missing."""
    try:
        api.plot(trajectory, dataset, gnss_outage=windows, path=png,
                 title=f"{dataset.name}: {trajectory.method}")  # fmt: skip
    except KeyboardInterrupt:
        print(f"fgins: interrupted while plotting: {written} is complete, {png} was not written",
              file=sys.stderr)  # fmt: skip
        return False
    except FginsError as exc:  # a place that refused the file after the check (outside tester)
        raise type(exc)(f"{exc}: {written} is complete, only the plot was not written") from None
    return True


def cmd_demo(args: argparse.Namespace) -> int:
    from fgins.bench.metrics import errors_against

    out_csv = args.output_dir / f"kitti_{args.method}.csv"
    out_png = args.output_dir / f"kitti_{args.method}.png"
    api.check_output(out_csv)
    api.check_output(out_png, suffixes=PLOT_SUFFIXES, what="plot")
    windows = parse_windows(args.gnss_outage)
    dataset = _load(args, ["demo:kitti"])
    trajectory = api.smooth(dataset, args.method, gnss_outage=windows, progress=_progress(args))
    elapsed = trajectory.summary()["wall_s"]
    trajectory.write(out_csv)
    gnss_enu = dataset.gnss_enu()
    errors = errors_against(trajectory, dataset.gnss.t, gnss_enu, dataset.t0, windows)
    if not _plotted(trajectory, dataset, windows, out_csv, out_png):
        return 130
    summary = errors.summary()
    print(
        f"fgins demo: KITTI drive ({len(dataset.imu)} IMU samples, {len(dataset.gnss)} GNSS epochs, "
        f"{dataset.imu.t[-1] - dataset.imu.t[0]:.0f} s), method {args.method}"
    )
    for warning in dataset.warnings:
        print(f"  note: {warning}")
    print(
        f"  GNSS withheld in {', '.join(f'{a:g}-{b:g} s' for a, b in windows)} after the first epoch"
    )
    # What smooth warns of (a window that withholds nothing, a doubtful fit), said here too.
    for warning in trajectory.info.get("fit_warnings", []):
        print(f"warning: {warning}", file=sys.stderr)
    measured = bool(np.isfinite(summary["h_rms_outage"]))
    if measured:
        print(
            f"  horizontal error inside the outage vs withheld GNSS: RMS {summary['h_rms_outage']:.2f} m, "
            f"max {summary['h_max_outage']:.2f} m"
        )
    else:
        print("  horizontal error inside the outage: not measured (no GNSS epoch withheld)")
    # At the fixes the run used (not those it gated or left out as faults), as fgins fleet.
    from fgins.bench.metrics import h_rms_at_used_fixes

    config = dataset.metadata.get("run_config") or api.configure(dataset)
    aided = h_rms_at_used_fixes(trajectory, dataset, config)
    print(f"  horizontal RMS at GNSS epochs used: {aided:.3f} m")
    if "within_3sigma_outage" in summary:
        print(
            f"  outage epochs inside the reported 3-sigma: {100 * summary['within_3sigma_outage']:.0f}%"
        )
    print(f"  wall time {elapsed:.2f} s ({len(dataset.imu) / elapsed:,.0f} IMU samples/s)")
    if args.method != "ekf" and measured:
        # The same data and outage through the forward EKF baseline, for scale.
        ekf = api.smooth(dataset, "ekf", gnss_outage=windows, progress=False)
        ekf_summary = errors_against(ekf, dataset.gnss.t, gnss_enu, dataset.t0, windows).summary()
        ratio = summary["h_rms_outage"] / ekf_summary["h_rms_outage"]
        print(
            f"  forward EKF on the same data: RMS {ekf_summary['h_rms_outage']:.2f} m in the "
            f"outage ({args.method}/EKF = {ratio:.2f}), {ekf.summary()['wall_s']:.2f} s"
        )
    print(f"  wrote {out_csv} and {out_png}")
    return 0


def cmd_sim(args: argparse.Namespace) -> int:
    if args.scenario == "list":
        try:
            from fgins.sim.scenarios import scenario_list
        except ImportError:
            raise FginsError("the simulator is not available in this build") from None
        print(scenario_list())
        return 0
    if args.output_dir is None:
        raise FginsError("fgins sim: -o DIR is required")
    if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
        raise FginsError(f"--duration {args.duration:g}: must be a positive number of seconds")
    if args.seed < 0:
        raise FginsError(f"--seed {args.seed}: must be 0 or more")
    options: dict[str, object] = {}
    for item in args.set:
        key, _, value = item.partition("=")
        if not _:
            raise FginsError(f"--set {item!r}: expected KEY=VALUE")
        if not key.strip():
            raise FginsError(f"--set {item!r}: the option name before '=' is missing")
        options[key.strip()] = _parse_value(value.strip())
    if args.duration is not None and "duration_s" in options:
        raise FginsError(
            "--duration and --set duration_s both given; they set the same length: keep one"
        )
    # api._simulate checks the folder before simulating (a path under a file, a folder of
    # other data): one line and exit 2, as every command's output, not "File exists".
    _, run = api._simulate(args.scenario, args.output_dir, args.seed, args.duration, options)
    print(
        f"{args.scenario}: wrote {args.output_dir} ({len(run.dataset.imu)} IMU samples, "
        f"{len(run.dataset.gnss)} GNSS epochs)"
    )
    return 0


def _parse_value(text: str) -> object:
    for convert in (int, float):
        try:
            return convert(text)
        except ValueError:
            pass
    if text.lower() in ("true", "false"):
        return text.lower() == "true"
    return text


def cmd_bench(args: argparse.Namespace) -> int:
    import time

    from fgins.bench.outages import check_bench_dir, frame_to_markdown

    _check_demo_alone(args.inputs)
    methods = api.check_methods(args.methods, args.baseline)  # before any work
    for flag, value in (("--outage-duration", args.outage_duration),
                        ("--outage-period", args.outage_period),
                        ("--outage-start", args.outage_start)):  # fmt: skip
        if value is not None and not math.isfinite(value):
            raise FginsError(f"{flag} {value:g}: must be a finite number of seconds")
    api.check_output(args.output_dir / "outages.json", args.inputs, suffixes=(".json",))
    # A folder of an earlier benchmark is rewritten whole; one holding anything else is not
    # written into (as `fgins sim`): said now, before the solves.
    check_bench_dir(args.output_dir)
    windows = parse_windows(args.gnss_outage)
    started = time.perf_counter()
    dataset = _load(args, args.inputs)
    table = api.bench(
        dataset, methods, windows or None, baseline=args.baseline,
        outage_duration=args.outage_duration, outage_period=args.outage_period,
        outage_start=args.outage_start, output_dir=args.output_dir, progress=_progress(args),
    )  # fmt: skip
    for line in table.attrs.get("warnings", []):
        print(f"warning: {line.removeprefix('bench: ')}", file=sys.stderr)
    print(frame_to_markdown(table, baseline=table.attrs["baseline"]))
    if table.attrs.get("window_table"):
        print("\n" + table.attrs["window_table"])
    reference = (
        "simulator truth" if table.attrs["reference"] == "truth" else "the withheld GNSS fixes"
    )
    protocol = table.attrs.get("protocol") or (0.0, 0.0, 0.0)
    source = {"data": " (the data's own, from the sim folder's [scenario])",
              "protocol": f" ({protocol[0]:g} s every {protocol[1]:g} s from {protocol[2]:g} s)"
              }.get(table.attrs.get("outages_from", ""), "")  # fmt: skip
    left_out = table.attrs.get("outages_left_out") or []
    dropped = (
        f"; left out (no usable fix withheld): {', '.join(f'{a:g}:{b:g}' for a, b in left_out)}"
        if left_out else ""
    )  # fmt: skip
    print(f"\nreference: {reference}; outages {table.attrs['outages']}{source}{dropped}")
    print(
        f"benchmark wall time {time.perf_counter() - started:.1f} s; results in {args.output_dir}/"
    )
    return 0


def cmd_fleet(args: argparse.Namespace) -> int:
    from fgins.fleet import FleetOptions, expand_drives, print_report, run_fleet

    if args.workers is not None and args.workers < 1:
        raise FginsError(f"--workers {args.workers}: need at least 1 worker")
    cpus = os.cpu_count() or 1
    if args.workers is not None and args.scheduler is None and args.workers > 4 * cpus:
        # Each worker is a process holding a drive: 64 on 2 CPUs hung at start-up (and
        # 100,000 took 2 GB and never started); a remote cluster sizes itself.
        raise FginsError(
            f"--workers {args.workers}: more than 4 per CPU on this machine ({cpus} CPUs); "
            f"use at most {4 * cpus} (each drive's solve keeps about one CPU busy)"
        )
    parse_windows(args.gnss_outage)  # a bad window is one error now, not one per drive
    if args.config is not None:
        # Settings every drive shares: checked once here, before a cluster starts, not
        # reported as a failure of every drive.
        from fgins.config import load_config

        load_config(args.config)
    drives = expand_drives(args.inputs)
    options = FleetOptions(
        method=args.method, output_format=args.format, config=args.config,
        imu_preset=args.imu_preset, vehicle=args.vehicle, robust=args.robust,
        gnss_outage=args.gnss_outage,
    )  # fmt: skip
    result = run_fleet(
        drives, options, args.output_dir, workers=args.workers, scheduler=args.scheduler,
        progress=_progress(args),
    )  # fmt: skip
    print_report(result, args.output_dir)
    return 1 if result.failed else 0


def cmd_convert(args: argparse.Namespace) -> int:
    from fgins.io.gnss_export import write_gnss

    if args.imu:
        from fgins.io.ubx import convert_ubx_imu

        _refuse_builtin_input(args.input, "convert --imu")

        args.output = _check_output(args.output, [args.input], suffixes=(".csv",), what="IMU output")
        print(convert_ubx_imu(args.input, args.output), file=sys.stderr)
        return 0
    args.output = _check_output(args.output, [args.input], suffixes=GNSS_OUTPUT_SUFFIXES, what="GNSS output")
    gnss, warnings = _read_gnss_only(args.input, check_time_offset(args.time_offset))
    from fgins.io.gnss_checks import check_gnss_records

    # DOP placeholders (u-blox 99.99, NMEA 0.00) written as missing; fixes that are no
    # measurement (quality 6-8) written with their fix_quality, and said.
    checks: list[str] = []
    gnss = check_gnss_records(gnss, checks)
    warnings = [*warnings, *checks]
    if args.output.suffix.lower() == ".tum":
        # ENU about the origin ``fgins smooth`` takes: KITTI's own for demo:kitti (about the
        # first fix, 13.7 m from it, evo read the README's recipe as 13.7 m of error)
        from fgins.io.kitti import KITTI_ORIGIN

        origin = KITTI_ORIGIN if str(args.input) == "demo:kitti" else None
        _write_gnss_tum(gnss, args.output, warnings, origin)
    else:
        write_gnss(gnss, args.output)
    for warning in warnings:
        print(f"warning: {warning}", file=sys.stderr)
    print(f"wrote {len(gnss)} fixes to {args.output}", file=sys.stderr)
    return 0


def _write_gnss_tum(gnss, path: Path, warnings: list[str], origin=None) -> None:
    """The fixes as a TUM reference: ENU at ``origin``, else at the first fix (the origin
    ``fgins smooth`` takes for a log without one), identity orientation. Fixes without a height (2-D) get the one
    ``fgins smooth`` gives them (said): a TUM row has no empty field, and a 2-D first fix
    made the origin's height NaN and every row NaN (12 of gpsd's 59 real logs, exit 0)."""
    from fgins.datatypes import InputError, Origin
    from fgins.io.gnss_checks import fill_missing_heights
    from fgins.io.trajectory_tum import write_gnss_tum

    if len(gnss) == 0:
        raise InputError(f"{path}: the log has no GNSS fix with a position")
    filled: list[str] = []
    gnss = fill_missing_heights(gnss, filled)
    warnings.extend(f"{line} (in the TUM reference as in fgins smooth)" for line in filled)
    write_gnss_tum(gnss.t, gnss.lla, origin or Origin(*map(float, gnss.lla[0])), path)


def _refuse_builtin_input(path: Path, command: str) -> None:
    """A ``demo:...`` name given to a command that reads it not: said as such, not "no such
    file"."""
    if not str(path).startswith("demo:"):
        return
    if str(path) != "demo:kitti":
        raise FginsError(f"{path}: unknown built-in input; the demo input is demo:kitti")
    if command == "inspect":
        raise FginsError(
            "demo:kitti is the built-in KITTI drive, not a log file: inspect reads a file "
            "(NMEA, UBX, MCAP, a ROS bag, a CSV) or a sim folder; `fgins convert demo:kitti -o "
            "fixes.csv` writes its GNSS fixes, `fgins smooth demo:kitti` smooths it"
        )
    raise FginsError(
        "convert --imu writes the IMU of a u-blox UBX log; demo:kitti is the built-in KITTI "
        "drive (leave out --imu to write its GNSS fixes)"
    )


def _read_gnss_only(path: Path, time_offset: float):
    if str(path) == "demo:kitti":
        from dataclasses import replace

        from fgins.io.kitti import parse_kitti

        dataset = parse_kitti()  # the fixes as smooth reads them (checked by the caller)
        gnss = dataset.gnss
        return (replace(gnss, t=gnss.t + time_offset) if time_offset else gnss), dataset.warnings
    _refuse_builtin_input(path, "convert")
    if not path.exists():
        raise FginsError(f"{path}: no such file")
    from fgins.io.empty_files import check_not_empty

    check_not_empty(path)
    from fgins.io.mcap_stream import is_mcap
    from fgins.io.rosbag import is_rosbag, read_rosbag_gnss

    mcap = path.suffix.lower() == ".mcap" or is_mcap(path)  # an MCAP by its magic, any name
    if mcap or is_rosbag(path):
        from dataclasses import replace

        from fgins.io.mcap import read_mcap_gnss

        # A receiver's log needs no IMU; --time-offset shifts its fixes as smooth does.
        reader = read_mcap_gnss if mcap else read_rosbag_gnss
        gnss, warnings = reader(path)
        return (replace(gnss, t=gnss.t + time_offset) if time_offset else gnss), warnings
    if path.is_dir():
        raise FginsError(
            f"{path}: is a folder: convert takes one GNSS log file (NMEA, u-blox UBX, MCAP, "
            "ROS bag) or a ROS 2 bag folder; a folder written by fgins sim holds its fixes as "
            "gnss.csv already"
        )
    from fgins.io.ubx import looks_like_ubx, read_ubx_gnss

    if looks_like_ubx(path):
        return read_ubx_gnss(path, time_offset)
    from fgins.io.csv_pair import csv_kind, read_gnss_csv
    from fgins.io.inputs import looks_like_nmea

    kind = None if looks_like_nmea(path) else csv_kind(path)
    if kind == "gnss":
        warnings: list[str] = []
        return read_gnss_csv(path, warnings), warnings
    if kind is not None:
        raise FginsError(
            f"{path}: an {kind} CSV; convert takes a GNSS log (NMEA, u-blox UBX, MCAP or a "
            "gnss.csv)"
        )
    from fgins.io.nmea import read_nmea

    result = read_nmea(path, time_offset_s=time_offset)
    return result.gnss, result.warnings


def cmd_inspect(args: argparse.Namespace) -> int:
    path: Path = args.input
    _refuse_builtin_input(path, "inspect")
    if not path.exists():
        raise FginsError(f"{path}: no such file")
    from fgins.io.empty_files import check_not_empty
    from fgins.io.inputs import looks_like_nmea

    check_not_empty(path)
    from fgins.io.mcap_stream import is_mcap

    if path.suffix.lower() == ".mcap" or is_mcap(path):  # an MCAP by its magic, any name
        from fgins.io.mcap import summarize_mcap

        print(summarize_mcap(path))
        return 0
    from fgins.io.rosbag import is_rosbag, summarize_rosbag

    if is_rosbag(path):
        print(summarize_rosbag(path))
        return 0
    if path.is_dir():
        print(_summarize_folder(path))
        return 0
    from fgins.io.ubx import looks_like_ubx, summarize_ubx

    # By content, as smooth and convert read it (a UBX or NMEA log saved as .csv).
    if looks_like_ubx(path):
        print(summarize_ubx(path))
        return 0
    if path.suffix.lower() == ".csv" and not looks_like_nmea(path):
        print(_summarize_csv(path))
        return 0
    if path.is_file() and not looks_like_nmea(path):
        from fgins.io.csv_pair import csv_kind

        # Binary content that is no format fgins reads (random bytes, a PNG): the one
        # check smooth makes, not an "NMEA log ... not usable" summary with exit 0. A CSV
        # fgins knows under another name (a gnss.csv saved as .ubx) is read as convert and
        # smooth read it.
        if csv_kind(path) is not None:
            print(_summarize_csv(path))
            return 0
    from fgins.io.nmea import summarize_nmea

    print(summarize_nmea(path))
    return 0


def _summarize_folder(path: Path) -> str:
    """``fgins inspect FOLDER``: a ``fgins sim`` folder's CSVs, each as ``inspect FILE.csv``
    says it (a ROS 2 bag folder is the bag's; any other folder is no log)."""
    from fgins.io.csv_pair import SIM_FOLDER_FILES

    files = [path / name for name in SIM_FOLDER_FILES if (path / name).is_file()]
    if not files:
        raise FginsError(
            f"{path}: is a folder, not a log: inspect takes one log file (NMEA, u-blox UBX, "
            f"MCAP, ROS bag, a CSV), a ROS 2 bag folder or a folder written by fgins sim (none "
            f"of {', '.join(SIM_FOLDER_FILES)} here); give a file in it"
        )
    # Written by fgins sim where its config.toml has a [scenario] table; any folder of the
    # canonical CSVs is read the same way, but was headed "fgins sim folder" too (outside tester).
    config = path / "config.toml"
    written_by_sim = config.is_file() and "[scenario]" in config.read_text(errors="replace")
    heading = f"fgins sim folder {path}" if written_by_sim else f"input folder {path}"
    return "\n".join([heading, *(_summarize_csv(f) for f in files)])


def _rate(t: np.ndarray) -> float:
    return 1.0 / float(np.median(np.diff(t))) if len(t) > 1 else float("nan")


def _span(t: np.ndarray) -> float:
    return float(t[-1] - t[0]) if len(t) else 0.0


def _summarize_csv(path: Path) -> str:
    from fgins.io.csv_pair import csv_kind, read_gnss_csv, read_imu_csv

    kind = csv_kind(path)
    warnings: list[str] = []
    if kind == "imu":
        imu = read_imu_csv(path, warnings)
        lines = [
            f"{path}: IMU, {len(imu)} samples, {imu.rate_hz:.1f} Hz, {imu.t[-1] - imu.t[0]:.1f} s",
            f"  gyro mean {np.round(imu.gyro.mean(axis=0), 5)} rad/s, accel mean "
            f"{np.round(imu.accel.mean(axis=0), 3)} m/s^2",
        ]
    elif kind == "gnss":
        gnss = read_gnss_csv(path, warnings)
        rate = 1 / np.median(np.diff(gnss.t)) if len(gnss) > 1 else float("nan")
        lines = [f"{path}: GNSS, {len(gnss)} fixes, {rate:.2f} Hz, {gnss.t[-1] - gnss.t[0]:.1f} s"]
    elif kind == "baro":
        from fgins.io.csv_pair import read_baro_csv

        baro = read_baro_csv(path, warnings)
        given = "pressure_pa" if np.any(np.isfinite(baro.pressure)) else "baro_height"
        values = baro.pressure if given == "pressure_pa" else baro.height
        unit = "Pa" if given == "pressure_pa" else "m"
        lines = [
            f"{path}: barometer ({given}), {len(baro.t)} samples, {_rate(baro.t):.2f} Hz, "
            f"{_span(baro.t):.1f} s",
            f"  {given} median {np.nanmedian(values):.6g} {unit}, range "
            f"{np.nanmin(values):.6g} .. {np.nanmax(values):.6g} {unit}",
        ]
    elif kind == "odometer":
        from fgins.io.csv_pair import read_odometer_csv

        wheel = read_odometer_csv(path, warnings)
        lines = [
            f"{path}: wheel speed, {len(wheel.t)} samples, {_rate(wheel.t):.2f} Hz, "
            f"{_span(wheel.t):.1f} s",
            f"  speed median {np.nanmedian(wheel.speed):.3g} m/s, max {np.nanmax(wheel.speed):.3g} m/s",
        ]
    elif kind == "accel_array":
        from fgins.io.accel_array_csv import read_accel_array_csv

        t, readings = read_accel_array_csv(path, warnings)
        lines = [
            f"{path}: accelerometer array, {readings.shape[1]} accelerometers, {len(t)} samples, "
            f"{_rate(t):.1f} Hz, {_span(t):.1f} s (its geometry: the folder's config.toml "
            "[accel_array])"
        ]
    else:
        raise FginsError(
            f"{path}: not a CSV fgins reads (unrecognised header): imu.csv (time,gyro_x,...,"
            "accel_z), gnss.csv (time,lat,lon,alt,...), baro.csv (time,pressure_pa or "
            "time,baro_height), wheel.csv (time,wheel_speed) or accel_array.csv (time,a1,...)"
        )
    lines += [f"  warning: {w}" for w in warnings]
    return "\n".join(lines)


COMMANDS = {
    "smooth": cmd_smooth,
    "demo": cmd_demo,
    "sim": cmd_sim,
    "bench": cmd_bench,
    "fleet": cmd_fleet,
    "convert": cmd_convert,
    "inspect": cmd_inspect,
}


def _joined_negative_windows(argv: list[str]) -> list[str]:
    """``--gnss-outage -50:-10`` as ``--gnss-outage=-50:-10``: argparse takes a value that
    starts with '-' for an option ("expected one argument")."""
    out: list[str] = []
    items = iter(argv)
    for item in items:
        if item == "--gnss-outage":
            value = next(items, None)
            if value is not None and value.startswith("-") and ":" in value:
                out.append(f"--gnss-outage={value}")
                continue
            out.append(item)
            if value is not None:
                out.append(value)
            continue
        out.append(item)
    return out


class _Terminated(Exception):
    """SIGTERM (a job scheduler, ``timeout``, ``kill``): unwound like Ctrl-C, so the
    atomic writers remove their temporary files instead of leaving ``.part`` files behind."""


def _raise_terminated(signum: int, frame: object) -> None:
    raise _Terminated


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(_joined_negative_windows(sys.argv[1:] if argv is None else argv))
    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        return _dispatch(args)
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)


#: Exit status after the reader of stdout went away (``fgins inspect LOG | head -1``): that of
#: a process ended by SIGPIPE, as ``cat`` or ``yes`` give in the same pipe.
EXIT_STDOUT_CLOSED = 128 + 13


def _stdout_closed() -> int:
    """Quiet exit on a closed stdout: nothing more can be shown, and Python's final flush of
    the buffered rest must not report the broken pipe either (stdout goes to /dev/null)."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):  # no real file descriptor (stdout replaced in-process)
        pass
    return EXIT_STDOUT_CLOSED


def _dispatch(args: argparse.Namespace) -> int:
    try:
        with warnings.catch_warnings():
            # The CLI prints every finding itself, as counted one-line `warning:`s.
            warnings.simplefilter("ignore", api.FginsWarning)
            _joined_outages(args)
            code = COMMANDS[args.command](args)
            sys.stdout.flush()  # a closed pipe shows here, not at the interpreter's exit
            return code
    except BrokenPipeError:
        return _stdout_closed()
    except FginsError as exc:
        print(f"fgins: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("fgins: interrupted", file=sys.stderr)
        return 130
    except _Terminated:
        print("fgins: terminated (SIGTERM)", file=sys.stderr)
        return 143
    except MemoryError:
        print("fgins: error: out of memory", file=sys.stderr)
        return 1
    except Exception as exc:  # the promise is one line, not a traceback
        # A signal that landed while a module initialised comes back wrapped (GTSAM's import:
        # "ImportError: initialization failed" from a KeyboardInterrupt inside numpy's):
        # still an interruption, not an internal error (outside tester: rc 1 at ~1 s).
        stop = interruption(exc, (KeyboardInterrupt, _Terminated))
        if isinstance(stop, _Terminated):
            print("fgins: terminated (SIGTERM)", file=sys.stderr)
            return 143
        if stop is not None:
            print("fgins: interrupted", file=sys.stderr)
            return 130
        if args.debug:
            raise
        if isinstance(exc, OSError) and exc.errno is not None:
            # The machine's refusal (disk full, no permission, a read-only or missing
            # folder), not a bug: the file and the reason (outside tester: "internal error:
            # OSError: [Errno 28] No space left on device ... please report it").
            where = f"{exc.filename}: " if exc.filename else ""
            print(f"fgins: error: {where}{exc.strerror or exc}", file=sys.stderr)
            return 1
        print(
            f"fgins: internal error: {type(exc).__name__}: {str(exc).strip().splitlines()[0] if str(exc).strip() else ''}"
            " (rerun with --debug for the traceback; please report it)",
            file=sys.stderr,
        )
        return 1
