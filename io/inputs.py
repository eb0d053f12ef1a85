"""Open whatever the user gave as INPUT... and return one checked :class:`Dataset`.

``demo:kitti``; an MCAP file; a ROS 1 ``.bag`` or ROS 2 bag folder; a u-blox UBX log (alone, or with an imu.csv / MCAP IMU); an NMEA
file plus an IMU CSV; the CSV pair ``imu.csv gnss.csv`` (any order, recognised by header); or
a folder written by ``fgins sim``. Readers only parse; every dataset then passes through the
one input-validation layer (:func:`fgins.io.validate.validate_dataset`), here and nowhere else.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

from fgins.datatypes import Dataset, InputError
from fgins.io.empty_files import check_not_empty

NMEA_SUFFIXES = {".nmea", ".log", ".txt", ".gps", ".ubx_nmea"}


def looks_like_nmea(path: Path) -> bool:
    from fgins.io.ubx import looks_like_ubx

    if looks_like_ubx(path):  # UBX logs often carry NMEA sentences too: never read as NMEA
        return False
    try:
        with path.open("rb") as handle:
            head = handle.read(4096)
    except OSError:
        return False
    return b"$GP" in head or b"$GN" in head or b"$GL" in head or b"$GB" in head or b"$BD" in head


def _is_ubx(item: str) -> bool:
    from fgins.io.ubx import looks_like_ubx

    path = Path(item)
    return path.is_file() and looks_like_ubx(path)


def _is_mcap(item: str | Path) -> bool:
    """An MCAP file: by its magic bytes whatever its name (drive.bin), or named .mcap (one
    with other bytes is then refused by the MCAP reader as "not an MCAP file")."""
    from fgins.io.mcap_stream import is_mcap

    path = Path(item)
    return is_mcap(path) or (path.suffix.lower() == ".mcap" and path.is_file())


def _is_bag(item: str) -> bool:
    """A ROS 1 bag, a ROS 2 bag folder, or a .db3 / metadata.yaml of one (io/rosbag); a
    file that begins with the MCAP magic is an MCAP whatever its name."""
    from fgins.io.mcap_stream import is_mcap
    from fgins.io.rosbag import is_rosbag

    path = Path(item)
    return is_rosbag(path) and not is_mcap(path)


def _bag_storage(path: Path) -> Path:
    """What to read for a bag: a ROS 2 bag of one uncompressed MCAP file, as its metadata
    lists it, is that file (the MCAP reader streams it and reads a cut-off recording up to
    the cut); anything else the bag path (io/rosbag reads it), or a clear error."""
    from fgins.io.rosbag import bag_path, is_ros2_bag_folder, single_mcap_file

    path = bag_path(path)
    if is_ros2_bag_folder(path):
        return single_mcap_file(path) or path
    return path


def _piece_of_split_bag(path: Path) -> tuple[Path, str] | None:
    """(the bag folder, what to say) when ``path`` is one of several MCAP storage files a
    ROS 2 bag's metadata.yaml lists: read alone it was a third of the drive, unsaid, where a
    .db3 of the same bag stands for the whole (outside tester)."""
    from fgins.io.rosbag import is_ros2_bag_folder, listed_files

    folder = path.parent
    if not (path.is_file() and path.suffix.lower() == ".mcap" and is_ros2_bag_folder(folder)):
        return None
    try:
        names = listed_files(folder)
    except InputError:
        return None  # a metadata.yaml that is no bag's: the file is read as it is
    if len(names) < 2 or path.name not in {Path(name).name for name in names}:
        return None
    return folder, (
        f"{path}: one of the {len(names)} storage files of the ROS 2 bag {folder} (its "
        f"metadata.yaml lists them): the whole bag is read"
    )


def validated(
    dataset: Dataset, vehicle: str | None = None, sample_timing: str | None = None
) -> Dataset:
    """The one call of the input-validation layer (checks, repairs, counted warnings)."""
    from fgins.io.validate import validate_dataset

    # The vehicle the data carry (a sim folder's config.toml) when no other is given.
    return validate_dataset(dataset, vehicle=vehicle or dataset.vehicle, sample_timing=sample_timing)


#: Largest ``--time-offset`` magnitude taken (s, about 317 years; GNSS in seconds of the day
#: against an IMU in POSIX time needs ~1.8e9): beyond it the offset is a mistake
#: (nanoseconds), not a clock difference.
MAX_TIME_OFFSET_S = 1e10


def check_time_offset(time_offset_s: float) -> float:
    """``time_offset_s`` if it is a usable clock offset, else an :class:`InputError`."""
    if not math.isfinite(time_offset_s):
        raise InputError(f"--time-offset {time_offset_s}: must be a finite number of seconds")
    if abs(time_offset_s) > MAX_TIME_OFFSET_S:
        raise InputError(
            f"--time-offset {time_offset_s:g}: more than {MAX_TIME_OFFSET_S:g} s (about 317 years) "
            "from zero; it is seconds added to the GNSS times (e.g. -18 for GPS time against UTC)"
        )
    return time_offset_s


def load_dataset(
    inputs: list[str],
    *,
    time_offset_s: float = 0.0,
    imu_topic: str | None = None,
    gnss_topic: str | None = None,
    progress: bool = True,
    vehicle: str | None = None,
    sample_timing: str | None = None,
) -> Dataset:
    """Read ``inputs`` with the reader for their format and check the result (see module).
    ``vehicle``: the vehicle type when known (some checks assume a body that yaws with its
    track, which a multirotor need not); ``sample_timing``: the ``[imu] sample_timing`` when
    given (else the data's own, e.g. a sim folder's config.toml).
    ``time_offset_s`` is added to the GNSS times, whatever the format (a receiver logging
    GPS time against an IMU in UTC: -18)."""
    check_time_offset(time_offset_s)
    dataset = _parse(
        inputs,
        time_offset_s=time_offset_s,
        imu_topic=imu_topic,
        gnss_topic=gnss_topic,
        progress=progress,
    )
    if time_offset_s and not dataset.metadata.get("gnss_time_offset_applied"):
        dataset.gnss = replace(dataset.gnss, t=dataset.gnss.t + time_offset_s)
        first = dataset.metadata.get("gnss_first_epoch_t")
        if isinstance(first, float):
            dataset.metadata["gnss_first_epoch_t"] = first + time_offset_s
    if time_offset_s:
        dataset.metadata["gnss_time_offset_s"] = time_offset_s
    return validated(dataset, vehicle, sample_timing)


def _parse(
    inputs: list[str],
    *,
    time_offset_s: float,
    imu_topic: str | None,
    gnss_topic: str | None,
    progress: bool,
) -> Dataset:
    if not inputs:
        raise InputError("no input given")
    topics = [f"--{name}-topic" for name, topic in (("imu", imu_topic), ("gnss", gnss_topic))
              if topic is not None]  # fmt: skip
    if topics and not any(item.lower().endswith((".mcap", ".ubx")) or _is_ubx(item)
                          or _is_mcap(item) or _is_bag(item) for item in inputs):  # fmt: skip
        raise InputError(
            f"{' and '.join(topics)} {'choose' if len(topics) > 1 else 'chooses'} channels of an "
            "MCAP file (or the MCAP IMU beside a UBX log); these inputs have no topics: leave "
            "the option out"
        )
    if inputs == ["demo:kitti"]:
        from fgins.io.kitti import parse_kitti

        return parse_kitti()
    if "demo:kitti" in inputs:
        raise InputError(
            "demo:kitti is a whole drive on its own (IMU and GNSS); give it alone, not with "
            f"{', '.join(item for item in inputs if item != 'demo:kitti')}"
        )
    if any(item.startswith("demo:") for item in inputs):
        raise InputError(f"unknown built-in input among {inputs}; the demo input is demo:kitti")
    if "" in inputs:
        # Path("") is "." (the current folder): what it read would depend on the cwd
        number = inputs.index("") + 1
        raise InputError(
            f"empty input path (input {number} of {len(inputs)}); give a file or folder "
            '("." for the current folder)'
        )
    paths = [Path(item) for item in inputs]
    for path in paths:
        if not path.exists():
            raise InputError(f"{path}: no such file or folder")
        check_not_empty(path)
    split_piece = _piece_of_split_bag(paths[0]) if len(paths) == 1 else None
    if split_piece is not None:
        paths = [split_piece[0]]  # the bag folder, read whole (as a .db3 of it is)
    bags = [p for p in paths if _is_bag(str(p))]
    if bags:
        if len(paths) > 1:
            others = [str(p) for p in paths if p != bags[0]] or [f"{bags[0]} again"]
            raise InputError(
                f"{bags[0]}: a ROS bag is a whole recording on its own; give it alone, not "
                f"with {', '.join(others)}"
            )
        paths = [_bag_storage(bags[0])]
    mcaps = [p for p in paths if _is_mcap(p)]
    if len(paths) == 1 and mcaps:
        from fgins.io.mcap import read_mcap

        result = read_mcap(paths[0], imu_topic=imu_topic, gnss_topic=gnss_topic, progress=progress)
        result.dataset.metadata["mcap_report"] = result.report
        if bags:  # a bag folder read as its one MCAP file: what else it holds is said
            from fgins.io.rosbag import unlisted_warning

            result.dataset.warnings.extend(unlisted_warning(paths[0].parent))
        return result.dataset
    if bags:
        from fgins.io.rosbag import read_rosbag

        result = read_rosbag(paths[0], imu_topic=imu_topic, gnss_topic=gnss_topic,
                             progress=progress)  # fmt: skip
        result.dataset.metadata["mcap_report"] = result.report
        if split_piece is not None:
            result.dataset.warnings.append(split_piece[1])
        return result.dataset
    from fgins.io.ubx import looks_like_ubx

    ubx = [p for p in paths if p.is_file() and p not in mcaps and looks_like_ubx(p)]
    if ubx:
        from fgins.io.ubx import load_ubx_dataset

        others = [p for p in paths if p not in ubx]
        return load_ubx_dataset(ubx, others, imu_topic=imu_topic, progress=progress)
    if mcaps:
        _refuse_mcap_with_others(mcaps, [p for p in paths if p not in mcaps])
    nmea = [p for p in paths if p.is_file() and looks_like_nmea(p)]
    if nmea:
        return _nmea_with_imu(nmea, [p for p in paths if p not in nmea], time_offset_s)
    from fgins.io.csv_pair import read_csv_dataset

    return read_csv_dataset(paths)


def _refuse_mcap_with_others(mcaps: list[Path], others: list[Path]) -> None:
    """An MCAP recording is read alone (a whole drive: IMU and GNSS topics), or as the IMU
    beside a UBX log; given with anything else it is refused in one line that says what to
    do instead (outside tester: it was called "none of the formats fgins reads")."""
    from fgins.io.csv_pair import csv_kind

    first = mcaps[0]
    if len(mcaps) > 1:
        if first.resolve() == mcaps[1].resolve():
            raise InputError(f"{mcaps[1]}: given twice (once is enough)")
        raise InputError(
            f"{len(mcaps)} MCAP recordings given ({', '.join(map(str, mcaps))}); fgins reads "
            "one recording: give one of them (or merge them first with mcap merge)"
        )
    whole = f"{first}: an MCAP recording is a whole drive (IMU and GNSS topics), read alone"
    kinds = {}
    for path in others:
        try:
            kinds[path] = csv_kind(path) if path.is_file() else None
        except InputError:
            kinds[path] = None
    imu = [p for p, kind in kinds.items() if kind == "imu"]
    gnss = [p for p, kind in kinds.items() if kind == "gnss"]
    if imu and not gnss and len(others) == 1:
        raise InputError(
            f"{whole}, not with {imu[0]}; to use that IMU with the recording's fixes, write "
            f"them out with `fgins convert {first} -o gnss.csv` and give {imu[0]} gnss.csv"
        )
    if gnss and not imu and len(others) == 1:
        raise InputError(
            f"{whole}, not with {gnss[0]}: fgins takes an MCAP's IMU only with the "
            "recording's own GNSS topic (--gnss-topic picks one) or beside a u-blox UBX log; "
            "give the MCAP alone"
        )
    raise InputError(
        f"{whole}; give it alone, not with {', '.join(map(str, others))} (beside a u-blox UBX "
        "log it gives the IMU)"
    )


def _nmea_with_imu(nmea: list[Path], others: list[Path], time_offset_s: float) -> Dataset:
    from fgins.datatypes import Origin
    from fgins.io.csv_pair import csv_kind, read_baro_csv, read_imu_csv, read_odometer_csv
    from fgins.io.nmea import read_nmea

    if len(nmea) > 1:
        raise InputError(f"give one NMEA file, got {len(nmea)}")
    kinds = {p: (csv_kind(p) if p.is_file() else None) for p in others}
    # Every other input is used or refused, never dropped (outside tester: a gnss.csv given
    # beside the NMEA log was ignored without a word).
    for path, kind in kinds.items():
        if kind == "gnss":
            raise InputError(
                f"two GNSS sources: {nmea[0].name} and {path.name}; give one of them"
            )
        if kind not in ("imu", "baro", "odometer"):
            raise InputError(
                f"{path}: not an input fgins reads beside an NMEA log (one IMU CSV, and "
                "optionally baro.csv and wheel.csv)"
            )
    for kind in ("baro", "odometer"):
        if sum(1 for k in kinds.values() if k == kind) > 1:
            raise InputError(f"more than one {kind} CSV among the inputs; give one")
    imu_files = [p for p, kind in kinds.items() if kind == "imu"]
    if len(imu_files) != 1:
        raise InputError(
            f"{nmea[0]}: an NMEA file needs exactly one IMU CSV beside it "
            "(header time,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z)"
        )
    warnings: list[str] = []
    result = read_nmea(nmea[0], time_offset_s=time_offset_s)
    warnings.extend(f"{nmea[0].name}: {warning}" for warning in result.warnings)
    imu = read_imu_csv(imu_files[0], warnings)
    gnss = result.gnss
    baro_files = [p for p, kind in kinds.items() if kind == "baro"]
    odometer_files = [p for p, kind in kinds.items() if kind == "odometer"]
    return Dataset(
        imu=imu,
        gnss=gnss,
        baro=read_baro_csv(baro_files[0], warnings) if baro_files else None,
        odometer=read_odometer_csv(odometer_files[0], warnings) if odometer_files else None,
        origin=Origin(*map(float, gnss.lla[0])),
        name=nmea[0].stem,
        warnings=warnings,
        metadata={
            "nmea_counts": result.counts,
            "gnss_time_offset_applied": True,
            "gnss_epochs_without_fix": result.epochs_without_fix,
            "gnss_first_epoch_t": result.first_epoch_t,
        },
    )
