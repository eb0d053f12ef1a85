"""The canonical CSV inputs of DESIGN.md: ``imu.csv``, ``gnss.csv`` (and ``baro.csv``).

Files are recognised by their header, not their name, so ``imu.csv gnss.csv`` may come in
any order. A folder written by ``fgins sim`` holds them plus ``config.toml`` (sensor settings
and the frame origin); ``truth.csv`` in it is never read here.
"""

from __future__ import annotations

import csv
import difflib
import io
import math
import tomllib
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

import numpy as np

from fgins.config import Check, check_table
from fgins.datatypes import (
    AccelArrayData,
    BaroData,
    ConfigError,
    Dataset,
    GnssData,
    ImuData,
    InputError,
    OdometerData,
    Origin,
)
from fgins.io.accel_array_csv import (
    accel_array_from_table,
    derive_imu,
    is_accel_array_header,
    read_accel_array_csv,
)
from fgins.io.atomic import atomic_path
from fgins.io.empty_files import check_not_empty
from fgins.io.imu_checks import imu_from_samples

IMU_COLUMNS = ["time", "gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z"]
GNSS_REQUIRED = ["time", "lat", "lon", "alt"]
GNSS_OPTIONAL = [
    "vel_east", "vel_north", "vel_up", "std_east", "std_north", "std_up",
    "hdop", "vdop", "pdop", "fix_quality", "num_sats", "speed", "course",
]  # fmt: skip
BARO_COLUMNS = ["time", "pressure_pa"]
# Columns fgins reads as numbers; a column of text elsewhere (a comment) is ignored.
KNOWN_NUMERIC_COLUMNS = frozenset(
    [*IMU_COLUMNS, *GNSS_REQUIRED, *GNSS_OPTIONAL, *BARO_COLUMNS, "baro_height", "wheel_speed"]
)
# An MCAP file's first bytes (fgins.io.mcap_stream.MCAP_MAGIC; not imported: CSV reading
# needs no mcap library).
MCAP_MAGIC = b"\x89MCAP0\r\n"
# The files a `fgins sim` folder holds that are inputs (config.toml is read separately).
# Byte-order marks of UTF-16 text (little, big endian).
UTF16_BOMS = (b"\xff\xfe", b"\xfe\xff")
SIM_FOLDER_FILES = ("imu.csv", "accel_array.csv", "gnss.csv", "baro.csv", "wheel.csv")


def _utf16_without_bom(start: bytes) -> bool:
    """Do these first bytes read as printable ASCII interleaved with zero bytes?"""
    for text, zeros in ((start[::2], start[1::2]), (start[1::2], start[::2])):
        if len(start) == 4 and zeros == b"\0\0" and all(32 <= byte < 127 for byte in text):
            return True
    return False


@dataclass(frozen=True)
class CsvHeader:
    """Where a CSV file's header is: its column names (lower case), the physical lines
    before the data (the header and any ``#`` comment lines before it) and how many of those
    are comments (a header written as a ``#`` comment, numpy.savetxt's default, is not
    counted: it is the header)."""

    columns: list[str]
    skip: int = 1
    comments: int = 0


def _is_comment(line: str) -> bool:
    return line.lstrip().startswith("#")


def _looks_like_data(line: str) -> bool:
    """Every cell of ``line`` a number or blank, at least one a number: a data row."""
    cells = [cell.strip() for cell in line.strip().split(",")]
    return any(cells) and all(not c or _python_float(c) is not None for c in cells)


def read_csv_header(path: Path) -> CsvHeader:
    """The header of a CSV file (see :class:`CsvHeader`). ``#`` comment lines before it are
    skipped; when the first other line is already data, the last comment is the header
    (``# time,gyro_x,...`` as numpy.savetxt writes it). A UTF-8 byte-order mark (spreadsheet
    exports) and quotes around the names are dropped; a header separated by ';' or tabs, not
    commas, is an error that says so (its cells would be misread, e.g. decimal commas)."""
    comments: list[str] = []
    try:
        with path.open("rb") as raw:
            start = raw.read(8)
        if start[:2] in UTF16_BOMS or _utf16_without_bom(start[:4]):
            raise InputError(
                f"{path}: UTF-16 text (a spreadsheet's 'Unicode text' export); fgins reads "
                "UTF-8 or ASCII comma-separated files (re-save as CSV UTF-8)"
            )
        if start == MCAP_MAGIC:
            raise InputError(
                f"{path}: an MCAP recording (by its magic bytes), not a CSV file; an MCAP is a "
                "whole drive (IMU and GNSS): give it alone"
            )
        with path.open(newline="", encoding="utf-8-sig") as handle:
            first = handle.readline()
            while first and _is_comment(first):
                comments.append(first)
                first = handle.readline()
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    except UnicodeDecodeError:
        raise InputError(
            f"{path}: binary content that is none of the formats fgins reads (CSV, NMEA 0183, "
            "u-blox UBX, MCAP)"
        ) from None
    skip = len(comments) + 1
    if comments and _looks_like_data(first) and "," in comments[-1]:
        first = comments.pop().lstrip().lstrip("#")  # the header, written as a comment
        skip -= 1
    if "," not in first:
        for separator, name in ((";", "semicolons"), ("\t", "tabs")):
            if separator in first:
                raise InputError(
                    f"{path}: the fields are separated by {name}; fgins reads comma-separated "
                    "files with '.' as the decimal point (re-export as CSV)"
                )
    columns = [name.strip().strip('"').strip().lower() for name in first.strip().split(",")]
    return CsvHeader(columns=columns, skip=skip, comments=len(comments))


def read_header(path: Path) -> list[str]:
    """The header's column names, lower case (see :func:`read_csv_header`)."""
    return read_csv_header(path).columns


def csv_kind(path: Path) -> str | None:
    """'imu', 'accel_array', 'gnss', 'baro', 'odometer' or None, from the header line."""
    columns = read_header(path)
    if is_accel_array_header(columns):
        return "accel_array"
    header = set(columns)
    if {"gyro_x", "accel_x"} <= header:
        return "imu"
    if {"lat", "lon"} <= header:
        return "gnss"
    if {"pressure_pa"} <= header or {"baro_height"} <= header:
        return "baro"
    if {"time", "wheel_speed"} <= header:
        return "odometer"
    return None


def _read_columns(path: Path, warnings: list[str]) -> dict[str, np.ndarray]:
    """Numeric columns by header name; empty cells are NaN, malformed rows dropped (counted).

    A row is skipped silently when every cell is blank, and dropped and counted as malformed
    when its number of fields differs from the header's or a cell is not a number to Python's
    ``float``. A line that begins with '#' (before the header or among the rows) is a
    comment: skipped, and all of them counted in one note. Vectorised with pyarrow's CSV
    reader (issue 9: the per-cell Python loop cost ~18 s on a 1 h, 200 Hz drive); the
    numbers are the bits Python's ``float`` gives.
    """
    layout = read_csv_header(path)
    header = layout.columns
    repeated = sorted({name for name in header if header.count(name) > 1})
    if repeated:  # which copy is meant cannot be told; the last one silently won
        raise InputError(
            f"{path}: column(s) {', '.join(repeated)} appear more than once in the header; "
            "keep one of each"
        )
    textable = [name not in KNOWN_NUMERIC_COLUMNS for name in header]
    try:
        table, bad, ignored, text, comments = _parse_table(
            path, len(header), textable, skip=layout.skip
        )
    except _Fallback:
        table, bad, ignored, text, comments = _parse_table_python(
            path, len(header), textable, skip=layout.skip
        )
    comments += layout.comments
    if comments:  # one note, before any error about the rows
        warnings.append(f"{path.name}: skipped {comments} '#' comment line(s)")
    if bad > len(table) and not (len(table) == 0 and text):  # text columns: named below
        # Most rows unusable: what is left would be blamed on something else (time spans
        # that do not overlap, too few samples; outside tester).
        raise InputError(
            f"{path}: {bad} of {bad + len(table)} data rows are malformed (a field count "
            "other than the header's, or a cell that is not a number such as 'n/a'); fix "
            "or drop those rows"
        )
    if bad:
        warnings.append(f"{path.name}: dropped {bad} malformed row(s)")
    if len(table) == 0:
        hint = (
            f": column(s) {', '.join(header[i] for i in text)} hold text, not numbers (e.g. an "
            "ISO time or 'GPS' for a fix type); write them as numbers (seconds, GGA fix codes)"
            if text else ""
        )
        raise InputError(f"{path}: no data rows{hint}")
    if ignored:
        warnings.append(
            f"{path.name}: ignored column(s) {', '.join(header[i] for i in ignored)} (text, "
            "not used by fgins)"
        )
    return {name: table[:, i] for i, name in enumerate(header) if i not in ignored}


class _Fallback(Exception):
    """pyarrow could not read the file as a plain CSV table: use the Python reader."""


# A plain decimal number (after trimming): pyarrow's cast gives the same correctly rounded
# double as Python's float. Anything else (nan, inf, 1_000, other digits, garbage) goes
# through float() itself, cell by cell; there are few such cells in real files.
_DECIMAL = r"^[+-]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)(?:[eE][+-]?[0-9]+)?$"


def _python_float(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


def _count_wrong_width(lines: list[str]) -> tuple[int, int]:
    """(malformed, comments) of the rows of the wrong width: a row that begins with '#' is a
    comment; the others are malformed unless all their cells are blank (csv's view)."""
    comments = sum(_is_comment(text) for text in lines)
    bad = sum(_has_content(text) for text in lines if not _is_comment(text))
    return bad, comments


def _has_content(text: str) -> bool:
    try:
        return any(cell.strip() for row in csv.reader([text]) for cell in row)
    except csv.Error:  # a field beyond csv's limit (a logger's NUL padding): not blank
        return bool(text.strip())


def _unclosed_quote_lines(data: bytes, skip: int) -> list[tuple[int, int]]:
    """The byte spans of the lines after the first ``skip`` that open a double quote and do
    not close it. Read as CSV, one such quote swallows every line up to the next quote into
    one cell (a gnss.csv's last 70 rows lost as "1 malformed row", 38 m off at exit 0;
    outside tester); numeric data never quotes across lines. Vectorised (a file without
    quotes costs one search)."""
    if b'"' not in data:
        return []
    buffer = np.frombuffer(data, dtype=np.uint8)
    newlines = np.flatnonzero(buffer == ord("\n"))
    line_of_quote = np.searchsorted(newlines, np.flatnonzero(buffer == ord('"')))
    odd = np.flatnonzero(np.bincount(line_of_quote, minlength=len(newlines) + 1) % 2)
    starts = np.concatenate([[0], newlines + 1])
    ends = np.concatenate([newlines, [len(data)]])
    return [(int(starts[i]), int(ends[i])) for i in odd if i >= skip]


def _parse_table(
    path: Path, n_columns: int, textable: list[bool] | None = None, skip: int = 1
) -> tuple[np.ndarray, int, list[int], list[int], int]:
    """(rows x columns table, malformed-row count, text columns ignored, text columns that
    made rows malformed, '#' comment rows skipped) through pyarrow, from the data after the
    first ``skip`` lines. A column that holds no number at all (a comment) is text: ignored
    when ``textable`` says so (fgins does not read it), its cells NaN. A row whose first
    cell begins with '#' is a comment: skipped and counted, never a malformed row."""
    textable = [False] * n_columns if textable is None else textable
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.csv as pacsv

    names = [f"c{i}" for i in range(n_columns)]
    wrong_width: list[str] = []
    # Read once: scanned for unclosed quotes, then parsed from memory by pyarrow.
    source = path.read_bytes()
    unclosed = _unclosed_quote_lines(source, skip)
    if unclosed:  # blanked (a blank row is skipped) and counted as malformed below
        cleaned = bytearray(source)
        for start, end in unclosed:
            cleaned[start:end] = b" " * (end - start)
        source = bytes(cleaned)

    def on_invalid(row) -> str:  # a row with a wrong number of fields
        wrong_width.append(row.text)
        return "skip"

    def read(column_type, **options):
        wrong_width.clear()
        return pacsv.read_csv(
            pa.BufferReader(source),
            read_options=pacsv.ReadOptions(skip_rows=skip, column_names=names),
            parse_options=pacsv.ParseOptions(invalid_row_handler=on_invalid),
            convert_options=pacsv.ConvertOptions(
                column_types={name: column_type for name in names}, **options
            ),
        )

    try:
        # Fast path: every cell a plain number or empty (null: NaN). pyarrow's parser is
        # correctly rounded like Python's float; any other cell fails the whole read.
        numbers = read(pa.float64(), null_values=[""], strings_can_be_null=True)
    except pa.ArrowInvalid:
        numbers = None
    except (pa.ArrowException, UnicodeDecodeError) as exc:
        # (pyarrow's threaded reader with a Python row handler once failed a valid file with
        # "a chunk failed converting for an unknown reason": the full suite, under load, not
        # again on a rerun; the slower reader reads the same rows.)
        raise _Fallback from exc
    if numbers is not None:
        bad, comments = _count_wrong_width(wrong_width)
        bad += len(unclosed)
        n_rows = numbers.num_rows
        table = np.empty((n_rows, n_columns))
        blank_row = np.ones(n_rows, dtype=bool)
        for i, name in enumerate(names):
            column = numbers.column(name)
            blank_row &= np.asarray(column.is_null(), dtype=bool)
            table[:, i] = column.to_numpy(zero_copy_only=False)  # nulls -> NaN
        return table[~blank_row], bad, [], [], comments
    try:
        raw = read(pa.string(), strings_can_be_null=False, quoted_strings_can_be_null=False)
    except (pa.ArrowException, UnicodeDecodeError) as exc:
        raise _Fallback from exc
    bad, comments = _count_wrong_width(wrong_width)
    bad += len(unclosed)
    if n_columns and raw.num_rows:
        first = pc.utf8_ltrim_whitespace(raw.column(names[0]).combine_chunks())
        comment = np.asarray(pc.starts_with(first, "#"), dtype=bool)
        if comment.any():
            comments += int(np.count_nonzero(comment))
            raw = raw.filter(pa.array(~comment))
    n_rows = raw.num_rows
    table = np.empty((n_rows, n_columns))
    blank_row = np.ones(n_rows, dtype=bool)
    failed = np.zeros(n_rows, dtype=bool)
    ignored: list[int] = []
    text: list[int] = []  # all text, but a column fgins reads: its rows are malformed
    for i, name in enumerate(names):
        cells = pc.utf8_trim_whitespace(raw.column(name).combine_chunks())
        blank = np.asarray(pc.equal(pc.utf8_length(cells), 0), dtype=bool)
        decimal = np.asarray(pc.match_substring_regex(cells, _DECIMAL), dtype=bool)
        values = np.full(n_rows, np.nan)
        if decimal.any():
            values[decimal] = pc.cast(cells.filter(pa.array(decimal)), pa.float64()).to_numpy(
                zero_copy_only=False
            )
        other = np.flatnonzero(~decimal & ~blank)
        if other.size:
            texts = cells.take(pa.array(other)).to_pylist()
            # Python's idea of blank is wider than pyarrow's (e.g. the \x1c-\x1f separators).
            space = np.array([not text.strip() for text in texts])
            blank[other[space]] = True
            parsed = [None if text.isspace() else _python_float(text) for text in texts]
            ok = np.array([v is not None for v in parsed]) & ~space
            values[other[ok]] = [v for v, good in zip(parsed, ok, strict=True) if good]
            all_text = not decimal.any() and not ok.any() and bool((~ok & ~space).any())
            if all_text and textable[i]:
                ignored.append(i)  # a column of text (a comment): no numbers, not read
            else:
                failed[other[~ok & ~space]] = True
                if all_text:
                    text.append(i)
        table[:, i] = values
        blank_row &= blank
    keep = ~blank_row & ~failed
    bad += int(np.count_nonzero(failed & ~blank_row))
    return table[keep], bad, ignored, text, comments


def _parse_table_python(
    path: Path, n_columns: int, textable: list[bool] | None = None, skip: int = 1
) -> tuple[np.ndarray, int, list[int], list[int], int]:
    """The reference reader (Python's csv, cell by cell), for files pyarrow rejects; the
    same result as :func:`_parse_table`."""
    textable = [False] * n_columns if textable is None else textable
    rows: list[list[str]] = []
    bad = comments = 0
    data = bytearray(path.read_bytes())
    unclosed = _unclosed_quote_lines(bytes(data), skip)
    for start, end in unclosed:  # as _parse_table: blanked, counted as malformed
        data[start:end] = b" " * (end - start)
    bad += len(unclosed)
    try:
        with io.StringIO(data.decode("utf-8"), newline="") as handle:
            del data
            for _ in range(skip):
                handle.readline()
            reader = csv.reader(handle)
            for row in reader:
                if not row or all(not cell.strip() for cell in row):
                    continue
                if _is_comment(row[0]):
                    comments += 1
                    continue
                if len(row) != n_columns:
                    bad += 1
                    continue
                rows.append(row)
    except UnicodeDecodeError:
        raise InputError(f"{path}: not a text CSV file (invalid UTF-8 after the header)") from None
    except csv.Error as exc:
        raise InputError(f"{path}: not a readable CSV file ({exc})") from None

    def number(cell: str) -> float | None:
        return np.nan if not cell.strip() else _python_float(cell)

    values = [[number(cell) for cell in row] for row in rows]
    ignored, text = [], []
    for i in range(n_columns):
        cells = [v for row, v in zip(rows, (r[i] for r in values), strict=True) if row[i].strip()]
        if cells and all(v is None for v in cells):
            (ignored if textable[i] else text).append(i)
    table = []
    for row in values:
        row = [np.nan if i in ignored else v for i, v in enumerate(row)]
        if any(v is None for v in row):
            bad += 1
        else:
            table.append(row)
    table_array = np.array(table, dtype=float).reshape(len(table), n_columns)
    return table_array, bad, ignored, text, comments


def _read_required(
    path: Path, warnings: list[str], kind: str, required: Iterable[str]
) -> dict[str, np.ndarray]:
    """The columns of a CSV file that must hold all ``required`` ones (InputError if not)."""
    columns = _read_columns(path, warnings)
    missing = [c for c in required if c not in columns]
    if missing:
        raise InputError(f"{path}: missing {kind} column(s) {', '.join(missing)}")
    return columns


def _warn_unknown_columns(
    path: Path, columns: Iterable[str], known: list[str], warnings: list[str]
) -> None:
    """One counted warning naming the numeric columns fgins does not read in this file,
    each with the known column it is closest to (a misspelt ``std_est`` was ignored without
    a word and the result changed; outside tester). Text columns are said by the reader."""
    unknown = [(place, name) for place, name in enumerate(columns, 1) if name not in known]
    if not unknown:
        return
    named = []
    for place, name in unknown[:8]:
        if not name.strip():  # an Excel export's trailing comma on every line
            named.append(f"column {place} (no name: a trailing comma?)")
            continue
        close = difflib.get_close_matches(name, known, n=1, cutoff=0.6)
        named.append(f"{name} (did you mean {close[0]}?)" if close else name)
    more = f" and {len(unknown) - 8} more" if len(unknown) > 8 else ""
    warnings.append(
        f"{path.name}: {len(unknown)} unknown column(s) ignored: {', '.join(named)}{more}; "
        f"the columns read are {','.join(known)}"
    )


def read_imu_csv(path: str | Path, warnings: list[str] | None = None) -> ImuData:
    path = Path(path)
    warnings = [] if warnings is None else warnings
    columns = _read_required(path, warnings, "IMU", IMU_COLUMNS)
    _warn_unknown_columns(path, columns, IMU_COLUMNS, warnings)
    gyro = np.column_stack([columns[f"gyro_{a}"] for a in "xyz"])
    accel = np.column_stack([columns[f"accel_{a}"] for a in "xyz"])
    return imu_from_samples(columns["time"], gyro, accel, source=path.name, warnings=warnings)


def read_gnss_csv(path: str | Path, warnings: list[str] | None = None) -> GnssData:
    """The fixes of a ``gnss.csv`` (rows without a time or a position dropped, counted)."""
    return read_gnss_csv_epochs(path, warnings)[0]


def _warn_partial_std(path: Path, columns: dict[str, np.ndarray], warnings: list[str]) -> None:
    """Some but not all of std_east/std_north/std_up: the missing axes' 1-sigma comes from
    the DOP model (UERE x DOP, or [gnss] default_sigma_m), said rather than silent."""
    names = ["std_east", "std_north", "std_up"]
    given = [name for name in names if name in columns]
    if not given or len(given) == 3:
        return
    missing = [name for name in names if name not in given]
    # As fgins.factors.gnss.position_sigmas fills a missing axis: east/north UERE x HDOP,
    # up UERE x VDOP (else PDOP, else 1.5 HDOP), else [gnss] default_sigma_m.
    horizontal = "UERE x hdop" if "hdop" in columns else "[gnss] default_sigma_m (no hdop column)"
    vertical_dops = [name for name in ("vdop", "pdop", "hdop") if name in columns]
    vertical = (
        f"UERE x {' else '.join(vertical_dops)}" if vertical_dops
        else "[gnss] default_sigma_m (no DOP column)"
    )  # fmt: skip
    used = "; ".join(
        f"{name.removeprefix('std_')} from {vertical if name == 'std_up' else horizontal}"
        for name in missing
    )
    warnings.append(
        f"{path.name}: {', '.join(missing)} missing beside {', '.join(given)}: {used} "
        "(give all three std columns, or none)"
    )


def read_gnss_csv_epochs(
    path: str | Path, warnings: list[str] | None = None
) -> tuple[GnssData, float]:
    """The fixes of a ``gnss.csv`` and the time of its first epoch, usable or not (the
    earliest row with a time, with a position or not): the t0 of ``--gnss-outage`` windows
    (``Dataset.metadata["gnss_first_epoch_t"]``), as the NMEA, UBX and MCAP readers give it
    for epochs without a fix; NaN without any time."""
    path = Path(path)
    warnings = [] if warnings is None else warnings
    columns = _read_required(path, warnings, "GNSS", GNSS_REQUIRED)
    _warn_unknown_columns(path, columns, GNSS_REQUIRED + GNSS_OPTIONAL, warnings)
    _warn_partial_std(path, columns, warnings)
    t = columns["time"]
    timed = t[np.isfinite(t)]
    first_epoch_t = float(timed.min()) if timed.size else math.nan
    lla = np.column_stack([columns["lat"], columns["lon"], columns["alt"]])
    # Latitude and longitude without a height (a 2-D fix, an empty alt cell) is kept: the
    # validation layer gives it a held height with a large vertical sigma.
    no_time = ~np.isfinite(t)
    no_position = ~np.all(np.isfinite(lla[:, :2]), axis=1) & ~no_time
    keep = ~no_time & ~no_position
    for count, what in ((no_time.sum(), "time"), (no_position.sum(), "position")):
        if count:
            warnings.append(f"{path.name}: dropped {int(count)} fix(es) without a {what}")
    order = np.argsort(t[keep], kind="stable")
    if np.any(np.diff(t[keep]) < 0):
        warnings.append(f"{path.name}: fixes were out of time order; sorted")
    index = np.flatnonzero(keep)[order]
    t_sorted = t[index]
    duplicate = np.concatenate([[False], np.diff(t_sorted) == 0])
    if duplicate.any():
        warnings.append(f"{path.name}: dropped {int(duplicate.sum())} fix(es) with repeated time")
        index = index[~duplicate]

    def column(name: str) -> np.ndarray | None:
        return columns[name][index] if name in columns else None

    def triple(names: list[str]) -> np.ndarray | None:
        if not any(n in columns for n in names):
            return None
        return np.column_stack(
            [columns[n][index] if n in columns else np.full(len(index), np.nan) for n in names]
        )

    # speed/course (m/s, degrees from north) give the horizontal velocity where the vel_*
    # columns do not (absent, or empty cells): vel_* win where both are given.
    velocity = triple(["vel_east", "vel_north", "vel_up"])
    horizontal = [name for name in ("vel_east", "vel_north") if name in columns]
    if len(horizontal) == 1:  # one horizontal component is no velocity: said, not silently unused
        warnings.append(
            f"{path.name}: {horizontal[0]} without "
            f"{'vel_north' if horizontal[0] == 'vel_east' else 'vel_east'}: the horizontal "
            "velocity is not used (give both, or neither)"
        )
    lone = [name for name in ("speed", "course") if name in columns]
    if len(lone) == 1 and not horizontal:
        warnings.append(
            f"{path.name}: {lone[0]} without {'course' if lone[0] == 'speed' else 'speed'}: "
            "no horizontal velocity from them (give both, or vel_east and vel_north)"
        )
    if "speed" in columns and "course" in columns:
        speed, course = columns["speed"][index], columns["course"][index]
        fill = np.isfinite(speed) & np.isfinite(course)
        if velocity is not None:
            fill &= ~np.any(np.isfinite(velocity[:, :2]), axis=1)
        if fill.any():
            velocity = np.full((len(index), 3), np.nan) if velocity is None else velocity
            velocity[fill, :2] = _velocity_from_speed_course(speed[fill], course[fill])[:, :2]
    gnss = GnssData(
        t=t[index],
        lla=lla[index],
        velocity=velocity,
        std=triple(["std_east", "std_north", "std_up"]),
        hdop=column("hdop"),
        vdop=column("vdop"),
        pdop=column("pdop"),
        fix_quality=column("fix_quality"),
        num_sats=column("num_sats"),
        speed=column("speed"),
        course=column("course"),
    )
    return gnss, first_epoch_t


def _velocity_from_speed_course(speed: np.ndarray, course: np.ndarray) -> np.ndarray:
    """ENU velocity (m/s) from speed over ground (m/s) and course over ground (degrees
    clockwise from north), as the NMEA reader builds it; no vertical component (NaN). The
    validation layer checks it against the fixes' own track (km/h, radians are errors)."""
    course_rad = np.radians(course)
    return np.column_stack(
        [speed * np.sin(course_rad), speed * np.cos(course_rad), np.full(len(speed), np.nan)]
    )


def read_odometer_csv(path: str | Path, warnings: list[str] | None = None) -> OdometerData:
    """``wheel.csv``: ``time,wheel_speed`` (m/s, forward, before scale correction)."""
    path = Path(path)
    warnings = [] if warnings is None else warnings
    columns = _read_columns(path, warnings)
    _warn_unknown_columns(path, columns, ["time", "wheel_speed"], warnings)
    t, speed = columns["time"], columns["wheel_speed"]
    keep = np.isfinite(t) & np.isfinite(speed)
    if not keep.all():
        warnings.append(f"{path.name}: dropped {int((~keep).sum())} wheel-speed row(s) with NaN")
    t, speed = t[keep], speed[keep]
    repeated = np.concatenate([[False], np.diff(t) <= 0])
    if repeated.any():
        warnings.append(
            f"{path.name}: dropped {int(repeated.sum())} wheel-speed row(s) out of time order"
        )
        t, speed = t[~repeated], speed[~repeated]
    return OdometerData(t=t, speed=speed)


def read_baro_csv(path: str | Path, warnings: list[str] | None = None) -> BaroData:
    path = Path(path)
    warnings = [] if warnings is None else warnings
    columns = _read_columns(path, warnings)
    known = ["time", "pressure_pa"] if "pressure_pa" in columns else ["time", "baro_height"]
    _warn_unknown_columns(path, columns, known, warnings)
    t = columns["time"]
    pressure = columns.get("pressure_pa")
    height = columns.get("baro_height")
    values = pressure if pressure is not None else height
    keep = np.isfinite(t) & np.isfinite(values)
    if not keep.all():
        warnings.append(f"{path.name}: dropped {int((~keep).sum())} barometer row(s) with NaN")
    return BaroData(
        t=t[keep],
        pressure=None if pressure is None else pressure[keep],
        height=None if height is None else height[keep],
    )


def _write_table(path: str | Path, header: list[str], table: np.ndarray, fmts: list[str]) -> None:
    with atomic_path(path) as tmp, tmp.open("w", newline="") as handle:
        handle.write(",".join(header) + "\n")
        for row in table:
            handle.write(
                ",".join(
                    "" if not np.isfinite(v) else f % v for f, v in zip(fmts, row, strict=True)
                )
                + "\n"
            )


def write_imu_csv(imu: ImuData, path: str | Path) -> None:
    """Write the canonical ``imu.csv``."""
    table = np.column_stack([imu.t, imu.gyro, imu.accel])
    with atomic_path(path) as tmp:
        np.savetxt(
            tmp, table, delimiter=",", header=",".join(IMU_COLUMNS), comments="",
            fmt=["%.6f"] + ["%.10e"] * 6,
        )  # fmt: skip


def write_gnss_csv(gnss: GnssData, path: str | Path) -> None:
    """Write the canonical ``gnss.csv`` (empty cells where a value is unknown)."""
    quality = gnss.fix_quality.astype(float)
    sats = np.where(gnss.num_sats >= 0, gnss.num_sats, np.nan).astype(float)
    table = np.column_stack(
        [
            gnss.t, gnss.lla, gnss.velocity, gnss.std, gnss.hdop, gnss.vdop, gnss.pdop,
            quality, sats, gnss.speed, gnss.course,
        ]
    )  # fmt: skip
    fmts = ["%.6f", "%.9f", "%.9f", "%.4f"] + ["%.4f"] * 9 + ["%d", "%d", "%.4f", "%.3f"]
    _write_table(path, GNSS_REQUIRED + GNSS_OPTIONAL, table, fmts)


def write_baro_csv(baro: BaroData, path: str | Path) -> None:
    table = np.column_stack([baro.t, baro.pressure])
    _write_table(path, BARO_COLUMNS, table, ["%.6f", "%.3f"])


ORIGIN_SCHEMA = {
    "lat": Check("number", abs_max=90.0, hint="degrees"),
    "lon": Check("number", abs_max=180.0, hint="degrees"),
    "alt": Check("number", abs_max=1e5, hint="metres above the ellipsoid"),
}


def _checked_origin(table: object, config_path: Path | None) -> Origin:
    """The local frame's origin of a sim folder's ``[origin]`` table: lat, lon, alt, each a
    finite number in range, no other key (a hand-edited table raised KeyError/TypeError)."""
    where = f"{config_path}: " if config_path else ""
    checked = check_table(where, "origin", table, ORIGIN_SCHEMA)
    missing = [key for key in ORIGIN_SCHEMA if key not in checked]
    if missing:
        raise ConfigError(f"{where}[origin]: missing {', '.join(missing)} (needs lat, lon, alt)")
    return Origin(checked["lat"], checked["lon"], checked["alt"])


DATA_FOLDER_SECTIONS = frozenset(
    {"imu", "gnss", "smoother", "origin", "scenario", "accel_array", "baro"}
)


def _read_sim_config(folder: Path) -> dict[str, Any]:
    path = folder / "config.toml"
    if not path.exists():
        return {}
    try:
        table = tomllib.loads(path.read_text(encoding="utf-8-sig"))  # a BOM, as in the CSVs
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{path}: {exc}") from None
    # A misspelt section ([smoothr]) would otherwise be ignored without a word, as --config's
    # unknown sections are not. [scenario] and [baro] describe the simulation (not read).
    unknown = sorted(set(table) - DATA_FOLDER_SECTIONS)
    if unknown:
        raise InputError(
            f"{path}: unknown section(s) {', '.join(f'[{name}]' for name in unknown)} (valid: "
            f"{', '.join(f'[{name}]' for name in sorted(DATA_FOLDER_SECTIONS))})"
        )
    return table


def _not_a_sim_folder(path: Path) -> NoReturn:
    """The error for a folder given as input that ``fgins sim`` did not write: a ROS 2 bag
    folder (metadata.yaml beside its .mcap or .db3 files) says which file to give."""
    mcaps = sorted(p for p in path.glob("*") if p.suffix.lower() == ".mcap" and p.is_file())
    db3 = sorted(p for p in path.glob("*.db3") if p.is_file())
    bag = "a ROS 2 bag folder" if (path / "metadata.yaml").is_file() else "a folder"
    if len(mcaps) == 1:
        raise InputError(f"{path}: {bag} with one MCAP file; give the file itself: {mcaps[0]}")
    if mcaps:
        names = ", ".join(p.name for p in mcaps[:5]) + (" ..." if len(mcaps) > 5 else "")
        raise InputError(
            f"{path}: {bag} split into {len(mcaps)} MCAP files ({names}); fgins reads one "
            "MCAP file: give one of them, or merge them first (mcap merge, or ros2 bag convert)"
        )
    if db3:
        raise InputError(
            f"{path}: {bag} of ROS 2 SQLite bag files ({db3[0].name}) without the bag's "
            "metadata.yaml; give the bag folder that holds both"
        )
    raise InputError(
        f"{path}: not a folder written by fgins sim (none of {', '.join(SIM_FOLDER_FILES)} in "
        "it); give the CSV files themselves"
    )


def read_csv_dataset(paths: list[Path]) -> Dataset:
    """Build a :class:`Dataset` from CSV files (recognised by header) or one ``fgins sim`` folder."""
    warnings: list[str] = []
    config: dict[str, Any] = {}
    config_path: Path | None = None
    files: list[Path] = []
    name = ""
    for path in paths:
        if path.is_dir():
            config = _read_sim_config(path)
            config_path = path / "config.toml"
            name = path.name
            # A sim folder's own file names only: an output written into it later (out.csv,
            # a second GNSS export) must not make it unreadable; truth.csv is never an input.
            files.extend(path / f for f in SIM_FOLDER_FILES if (path / f).is_file())
            if not files:
                _not_a_sim_folder(path)
        else:
            files.append(path)
    by_kind: dict[str, Path] = {}
    for path in files:
        if not path.exists():
            raise InputError(f"{path}: no such file")
        check_not_empty(path)  # a folder's empty file as one given by name (not "unrecognised")
        kind = csv_kind(path)
        if kind is None:
            if path.name == "truth.csv":
                continue
            layout = read_csv_header(path)
            after = ""
            if layout.comments and layout.columns == [""]:
                after = f" (the file holds only {layout.comments} '#' comment line(s))"
            elif layout.comments:
                after = f" (the first line after {layout.comments} '#' comment line(s))"
            raise InputError(
                f"{path}: unrecognised CSV header{after}; expected imu.csv "
                f"({','.join(IMU_COLUMNS)}), "
                f"gnss.csv ({','.join(GNSS_REQUIRED)},...), baro.csv (time,pressure_pa or "
                "time,baro_height) or wheel.csv (time,wheel_speed)"
            )
        if kind in by_kind:
            if Path(by_kind[kind]).resolve() == Path(path).resolve():
                raise InputError(f"{path}: given twice (once is enough)")
            raise InputError(f"two {kind} files given: {by_kind[kind]} and {path}")
        by_kind[kind] = path
    if "imu" in by_kind and "accel_array" in by_kind:
        raise InputError(
            f"both an IMU CSV ({by_kind['imu']}) and accelerometer-array readings "
            f"({by_kind['accel_array']}) given; pass one of them"
        )
    if "imu" not in by_kind and "accel_array" not in by_kind:
        raise InputError(
            "no IMU CSV among the inputs (header time,gyro_x,...,accel_z, or time,a1,...,aN "
            "for a gyro-free accelerometer array)"
        )
    if "gnss" not in by_kind:
        raise InputError("no GNSS CSV among the inputs (header time,lat,lon,alt,...)")
    accel_array: AccelArrayData | None = None
    if "accel_array" in by_kind:
        if not config:  # a file given on its own: its geometry sits beside it
            config = _read_sim_config(by_kind["accel_array"].parent)
            config_path = by_kind["accel_array"].parent / "config.toml"
        accel_array = _read_accel_array(by_kind["accel_array"], config, warnings)
        imu, derived_noise = derive_imu(accel_array)
        given = dict(config.get("imu") or {})
        preset_fills = set(derived_noise) - set(given) - {"preset", "rate_hz"}
        if "preset" in given and not preset_fills:  # every key given: the preset says nothing
            given.pop("preset")
        if "preset" in given:
            # A preset describes a gyro; an array's rates are its accelerometers' integral
            # (a "preset = tactical" line alone gave the derived rates a tactical gyro's
            # noise: every batch "diverged", blaming the vehicle and the antenna).
            warnings.append(
                f"[imu] preset = {given.pop('preset')!r} is not used for an accelerometer "
                "array: the rates' noise follows from its [accel_array] noise and geometry "
                "(the [imu] keys given explicitly are)"
            )
        config = {**config, "imu": {**derived_noise, **given}}
    else:
        imu = read_imu_csv(by_kind["imu"], warnings)
    gnss, first_epoch_t = read_gnss_csv_epochs(by_kind["gnss"], warnings)
    baro = read_baro_csv(by_kind["baro"], warnings) if "baro" in by_kind else None
    odometer = read_odometer_csv(by_kind["odometer"], warnings) if "odometer" in by_kind else None
    if len(gnss) == 0:
        raise InputError(f"{by_kind['gnss']}: no GNSS fix with a position")
    origin_table = config.get("origin")
    if origin_table:
        origin = _checked_origin(origin_table, config_path)
    else:
        origin = Origin(*map(float, gnss.lla[0]))
    return Dataset(
        imu=imu,
        gnss=gnss,
        baro=baro,
        odometer=odometer,
        origin=origin,
        name=name or by_kind.get("imu", by_kind.get("accel_array", Path())).parent.name,
        imu_config=dict(config.get("imu", {})),
        gnss_config=dict(config.get("gnss", {})),
        smoother_config=dict(config.get("smoother", {})),
        vehicle=config.get("scenario", {}).get("vehicle"),
        warnings=warnings,
        accel_array=accel_array,
        metadata={
            **_scenario_outages(config, float(imu.t[0]) if len(imu.t) else None),
            # A stated origin: a truth given in east/north/up alone is taken about it.
            **({"origin_stated": True} if origin_table else {}),
            # The t0 of outage windows: rows with a time but no position (dropped above)
            # do not move it, as NMEA/UBX/MCAP epochs without a fix do not (Dataset.t0).
            "gnss_first_epoch_t": first_epoch_t,
        },
    )


def _scenario_outages(config: dict[str, Any], start: float | None) -> dict[str, Any]:
    """The GNSS outages ``fgins sim`` built into the folder's data (its [scenario] table:
    seconds from the run's first sample), as absolute times: ``fgins bench`` scores them by
    default. Only well-formed windows; the table describes the run and is otherwise not read
    (an edited one must not stop a solve)."""
    scenario = config.get("scenario")
    windows = scenario.get("outages") if isinstance(scenario, dict) else None
    if start is None or not isinstance(windows, list):
        return {}
    kept = []
    for window in windows:
        if (
            isinstance(window, list) and len(window) == 2
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in window)
            and math.isfinite(window[0]) and math.isfinite(window[1]) and window[0] < window[1]
        ):  # fmt: skip
            kept.append((start + float(window[0]), start + float(window[1])))
    return {"scenario_outages_t": kept} if kept else {}


def _read_accel_array(path: Path, config: dict[str, Any], warnings: list[str]) -> AccelArrayData:
    """Readings of ``path`` with the ``[accel_array]`` table of the accompanying config."""
    table = config.get("accel_array")
    if not table:
        raise InputError(
            f"{path}: accelerometer-array readings need an [accel_array] table (positions_m, "
            "axes, noise_m_per_s2_per_sqrt_hz) in config.toml beside them"
        )
    t, readings = read_accel_array_csv(path, warnings)
    return accel_array_from_table(
        dict(table),
        t,
        readings,
        where=f"{path.parent / 'config.toml'} [accel_array]",
        warnings=warnings,
    )
