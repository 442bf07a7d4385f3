"""Drive logs as columns: the [log] and [limits] tables of a mapping file (`LogLayout`, `ImportLimits`) and the
bounded reader (`read_log`) of text logs (CSV and the like) and NumPy arrays (.npy, `NPY_SUFFIX`).

The importer (`ilcpmac.bench.importer`) resamples what this reads onto encoder counts or keeps it as a rolling
folder (`ilcpmac.bench.rolling`); a standstill scan folder (`ilcpmac.bench.standstill`) reads its samples with it.
"""

from __future__ import annotations

import codecs
import dataclasses
import io
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import numpy.lib.format as npy_format

from ilcpmac.bench.fastcsv import parse_rows
from ilcpmac.bench.format import MAX_HEADER_BYTES, MAX_TIMER_RESOLUTION_S, loadtxt_problem
from ilcpmac.config import LimitSettings
from ilcpmac.core.errors import BenchFormatError
from ilcpmac.core.files import read_bounded
from ilcpmac.core.schema import field_like, in_range, setting, shown

__all__ = ["ImportLimits", "LOG_KINDS", "LOG_LIMIT_FACTOR", "LogLayout", "MAX_LOG_ROWS", "MAX_LOG_ROW_BYTES",
           "MAX_SCALE", "MIN_SCALE", "NPY_SUFFIX", "beyond_limit", "current_columns", "named_columns", "read_log",
           "utf8_text"]

#: most data rows of one log (20 kHz for 200 s) ...
MAX_LOG_ROWS = 2**22
#: ... and bytes per row on average: a larger file is refused before it is parsed
MAX_LOG_ROW_BYTES = 128
#: range of |current_a_per_unit| and |torque_nm_per_unit|: a scale beyond it is a wrong unit, never a sensor's
MIN_SCALE, MAX_SCALE = 1e-12, 1e12
#: a log of this file suffix is a NumPy array (np.save's format), its quantities named by [log] names
NPY_SUFFIX = ".npy"
#: the longest header of a .npy file read (numpy's own default bound)
MAX_NPY_HEADER_BYTES = 10000
#: what a mapping's [log] kind may say ("moteus-cogging" is `ilcpmac.bench.moteus`'s, with no other key)
LOG_KINDS = ("run", "scan", "rolling")
#: how many times its mapping's [limits] a run log's currents, its torque column and the torque its currents ask
#: for (K . i) may reach: a drive's peak is a few times its rated current, a unit off 100x or 1000x (mA read as A)
LOG_LIMIT_FACTOR = 10.0


#: byte-order marks of the encodings a text file of a bench may not be in (UTF-32's first: UTF-16 LE's is its start)
_WIDE_BOMS = ((codecs.BOM_UTF32_LE, "UTF-32"), (codecs.BOM_UTF32_BE, "UTF-32"), (codecs.BOM_UTF16_LE, "UTF-16"),
              (codecs.BOM_UTF16_BE, "UTF-16"))


def column_names(path: Path, named_by: str) -> list[str]:
    """The column names on the first line of the samples file ``path`` (bounded read), which ``named_by`` (a
    folder's settings file and key, for the error) names; `BenchFormatError` naming it otherwise."""
    if not path.is_file():
        raise BenchFormatError(f"{path}: no such file (named by {named_by})")
    try:
        with open(path, "rb") as f:
            line = f.readline(MAX_HEADER_BYTES)
    except OSError as e:
        raise BenchFormatError(f"{path}: cannot read ({e.strerror or e})") from None
    try:
        return [n.strip() for n in utf8_text(path, line).decode("utf-8").strip().split(",")]
    except UnicodeDecodeError:
        raise BenchFormatError(f"{path}: line 1: the column names are not UTF-8 text") from None


def utf8_text(path: Path, raw: bytes) -> bytes:
    """The bytes of a text file without a UTF-8 byte-order mark (a spreadsheet's "CSV UTF-8" writes one).

    Logs, scan samples and moteus cogging files are UTF-8 (ASCII is UTF-8): a file that starts with a UTF-16 or
    UTF-32 byte-order mark, or holds a NUL byte (UTF-16 or UTF-32 text without a mark, or not text at all),
    raises `BenchFormatError` naming the file (and the line of the NUL), never read as something else.
    """
    for bom, encoding in _WIDE_BOMS:
        if raw.startswith(bom):
            raise BenchFormatError(f"{path}: {encoding} text (its byte-order mark): save it as UTF-8 or ASCII")
    nul = raw.find(b"\0")
    if nul >= 0:
        line = raw.count(b"\n", 0, nul) + 1
        raise BenchFormatError(f"{path}: line {line}: a NUL byte (UTF-16 or UTF-32 text, or not text): save it as "
                               "UTF-8 or ASCII")
    return raw.removeprefix(codecs.BOM_UTF8)


@dataclass(frozen=True)
class ImportLimits:
    """[limits] of a mapping file (optional): the motor's limits, as a campaign config's [limits] states them and
    with the same defaults; what the logged values are judged against (docs/bench-format.md, "The mapping file").
    """

    max_current_a: float = field_like(LimitSettings, "max_current_a", default=LimitSettings.max_current_a)
    max_torque_nm: float = field_like(LimitSettings, "max_torque_nm", default=LimitSettings.max_torque_nm)


def beyond_limit(values: np.ndarray, bound: float) -> tuple[int, str] | None:
    """The first index where |values| passes ``bound``, and what that likely is: a wrong unit ("in mA?", when
    most values pass it) or an outlier; None when none does."""
    beyond = np.flatnonzero(np.abs(values) > bound)
    if not beyond.size:
        return None
    most = np.median(np.abs(values)) > bound
    return int(beyond[0]), ("most values pass it: a unit 1000x too small (mA for A, mN m for N m?) or a wrong scale"
                            if most else "an outlier (a corrupt row or bin?)")


def _one_of(*choices: str):
    return lambda x: x in choices


def _scale(x: float) -> bool:
    return MIN_SCALE <= abs(x) <= MAX_SCALE


@dataclass(frozen=True)
class LogLayout:
    """[log] of a mapping file: the columns of a drive log, their units and scales.

    Column keys name a column of the log's last header line; a value in the
    log times its ``*_per_unit`` scale is in the unit the key names.
    """

    time: str = setting(None, "column of the time stamps", dataclasses.MISSING)
    position: str = setting(None, "column of the mechanical position (multi-turn or wrapping once per revolution)",
                           dataclasses.MISSING)
    position_unit: str = setting(_one_of("rad", "counts"), 'unit of the position: "rad" or "counts"',
                                dataclasses.MISSING)
    delimiter: str = setting(lambda x: len(x) == 1 and x not in "0123456789.+-eE\r\n\"",
                            "the one character between fields", ",")
    header_lines: int = setting(in_range(1, 1000), "lines before the first row, 1..1000; the last names the columns",
                               1)
    time_s_per_unit: float = setting(in_range(0.0, 1e6, low_open=True), "seconds per unit of the time column", 1.0)
    timer_resolution_s: float | None = setting(
        in_range(0.0, MAX_TIMER_RESOLUTION_S, low_open=True), "the time stamps' quantum, s, within (0, 1e-3] "
        "(for a log without torque; without it, read off the rows)", None)
    position_counts_per_rev: int | None = setting(
        in_range(1, 2**40), 'counts per revolution of the position, when position_unit = "counts"', None)
    phase_currents: tuple[str, ...] | None = setting(
        lambda x: len(x) == 3, "columns of the phase currents a, b, c (three names); or i_q", None)
    i_q: str | None = setting(None, "column of the q-axis current (amplitude-invariant Park, i_d = 0); or "
                             "phase_currents", None)
    angle_offset_rad: float = setting(
        in_range(-2 * math.pi, 2 * math.pi), "theta_e = pole_pairs * theta + angle_offset_rad in the inverse Park "
        "transform of i_q, within [-2 pi, 2 pi]", 0.0)
    current: str = setting(_one_of("commanded", "measured"),
                          'the currents logged: "commanded" (references) or "measured" (by the controller)',
                          "commanded")
    current_a_per_unit: float = setting(_scale, "amperes per unit of the current columns, of magnitude within "
                                       "[1e-12, 1e12]", 1.0)
    torque: str | None = setting(None, "column of the torque-sensor output; without it, a bench without a torque "
                                "sensor", None)
    torque_nm_per_unit: float = setting(_scale, "N m per unit of the torque column, of magnitude within "
                                       "[1e-12, 1e12]", 1.0)
    highest_harmonic: int = setting(in_range(1, 2**19), "highest harmonic of a revolution the data must resolve "
                                   "(two rows per period or more)", 150)
    kind: str = setting(_one_of(*LOG_KINDS), '"run" (turning laps, resampled onto counts; a log that cannot be is '
                       'kept as a rolling log), "scan" (a standstill position scan, forward and back) or "rolling" '
                       "(rows kept as they are, docs/rolling-logs.md); \"moteus-cogging\" for moteus cogging files, "
                       "with no other key", "run")
    direction: str | None = setting(None, "column of the direction of motion of a scan (> 0 forward, < 0 reverse); "
                                   "without it, the sign of the position's last change", None)
    names: tuple[str, ...] | None = setting(
        lambda x: 2 <= len(x) <= 64 and all(x) and len(set(x)) == len(x), "the names of a .npy log's quantities, "
        "2 to 64 distinct ones: one per row of a (k, n) array or per column of an (n, k) array (instead of a header "
        "line)", None)
    position_wraps_at: float | None = setting(
        in_range(0.0, 2.0**53, low_open=True), "where the logged position wraps to 0, in its own unit (a count_in_cpr "
        "column, a 16-bit counter); without it, once per revolution or not at all", None)
    current_filter_s: float | None = setting(
        in_range(0.0, 10.0), "of a rolling log: the time constant of a first-order filter the drive applied to the "
        "logged current, s, within [0, 10] (ODrive: 1 / (I_measured_report_filter_k x its current-control rate)); "
        "without it, fitted from the data", None)
    cut_transients: bool = setting(None, "of a rolling log: leave out a start and an end where the speed has not "
                                   "settled (docs/rolling-logs.md)", True)


def read_log(path: Path, layout: LogLayout) -> dict[str, np.ndarray]:
    """The columns of a drive log that ``layout`` names, as floats, by column name.

    The file is at most `MAX_LOG_ROWS` rows of `MAX_LOG_ROW_BYTES` on average
    (read bounded), UTF-8 (`utf8_text`); every named column must be in the header and every value
    finite, or `BenchFormatError` names the file, line and column. A .npy log (`NPY_SUFFIX`) is read by
    `_read_npy`, its quantities named by [log] names; its messages number its samples as the lines of a CSV of
    the same rows under one header line.
    """
    if path.suffix.lower() == NPY_SUFFIX:
        return _finite(path, _read_npy(path, layout), 1)
    if layout.names is not None:
        raise BenchFormatError(f"{path}: [log] names: only for a .npy log (a text log names its columns in its "
                               "header)")
    raw = utf8_text(path, read_bounded(path, layout.header_lines * MAX_HEADER_BYTES + MAX_LOG_ROWS * MAX_LOG_ROW_BYTES,
                                       BenchFormatError))
    start = 0
    for line in range(1, layout.header_lines + 1):
        end = raw.find(b"\n", start, start + MAX_HEADER_BYTES)
        if end < 0:
            raise BenchFormatError(f"{path}: line {line}: no end of the header line in {MAX_HEADER_BYTES} bytes "
                                   f"([log] header_lines = {layout.header_lines})")
        header, start = raw[start:end], end + 1
    try:
        names = [n.strip().strip('"') for n in header.decode("utf-8").strip().split(layout.delimiter)]
    except UnicodeDecodeError:
        raise BenchFormatError(f"{path}: line {layout.header_lines}: the column names are not UTF-8 text") from None
    wanted = _columns(layout)
    missing = [w for w in wanted if w not in names]
    if missing:
        raise BenchFormatError(f"{path}: line {layout.header_lines}: no column {shown(missing[0])} (the header "
                               f"has {shown(names)})")
    rows = _rows(path, raw[start:], names, layout)
    return _finite(path, {name: rows[:, names.index(name)] for name in wanted}, layout.header_lines)


def _finite(path: Path, columns: dict[str, np.ndarray], header_lines: int) -> dict[str, np.ndarray]:
    """``columns``, every value a finite number, or `BenchFormatError` naming the line (rows under
    ``header_lines``) and the column."""
    for name, values in columns.items():
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise BenchFormatError(f"{path}: line {header_lines + 1 + bad[0]}: {name} is not a finite number")
    return columns


def _read_npy(path: Path, layout: LogLayout) -> dict[str, np.ndarray]:
    """The named quantities of a .npy log (np.save's format, read without pickles): a real 2-D array of k
    quantities by n >= 3 samples, or n by k, k = len([log] names); its header is checked (version, dtype, shape
    against the file's size) before any array is made, the file read bounded."""
    if layout.names is None:
        raise BenchFormatError(f"{path}: a .npy log needs [log] names (its quantities, in order)")
    if layout.header_lines != 1 or layout.delimiter != ",":
        raise BenchFormatError(f"{path}: [log] header_lines, delimiter: not for a .npy log")
    k = len(layout.names)
    raw = read_bounded(path, MAX_NPY_HEADER_BYTES + MAX_LOG_ROWS * k * 8, BenchFormatError)
    stream = io.BytesIO(raw)
    try:
        version = npy_format.read_magic(stream)
        read_header = {(1, 0): npy_format.read_array_header_1_0, (2, 0): npy_format.read_array_header_2_0}.get(version)
        if read_header is None:
            raise ValueError(f"format version {version}")
        shape, fortran, dtype = read_header(stream, max_header_size=MAX_NPY_HEADER_BYTES)
    except ValueError as e:
        raise BenchFormatError(f"{path}: not a .npy array file numpy writes ({e})") from None
    if dtype.kind not in "fiu" or dtype.hasobject:
        raise BenchFormatError(f"{path}: holds {dtype}, not real numbers")
    if len(shape) != 2 or (shape[0] == k) == (shape[1] == k):
        raise BenchFormatError(f"{path}: an array of shape {shape}; [log] names gives {k} quantities: it needs shape "
                               f"({k}, n) or (n, {k}), n != {k}")
    n = shape[1] if shape[0] == k else shape[0]
    if not 3 <= n <= MAX_LOG_ROWS:
        raise BenchFormatError(f"{path}: {n} samples; a log holds 3 to {MAX_LOG_ROWS}")
    offset = stream.tell()
    if len(raw) - offset != n * k * dtype.itemsize:
        raise BenchFormatError(f"{path}: {len(raw) - offset} bytes of data for an array of shape {shape} of {dtype} "
                               "(a truncated or padded file)")
    array = np.frombuffer(raw, dtype, n * k, offset).reshape(shape, order="F" if fortran else "C").astype(float)
    by_row = array if shape[0] == k else array.T
    wanted = _columns(layout)
    missing = [w for w in wanted if w not in layout.names]
    if missing:
        raise BenchFormatError(f"{path}: no quantity {shown(missing[0])} ([log] names has {shown(layout.names)})")
    return {name: np.ascontiguousarray(by_row[layout.names.index(name)]) for name in wanted}


def named_columns(layout: LogLayout) -> list[tuple[str, str]]:
    """(key, column) of each log column ``layout`` names: time, position, currents, torque, direction."""
    currents = [(f"phase_currents[{p}]", c) for p, c in enumerate(layout.phase_currents or ())] + (
        [] if layout.i_q is None else [("i_q", layout.i_q)])
    return [("time", layout.time), ("position", layout.position), *currents] + [
        (key, c) for key, c in (("torque", layout.torque), ("direction", layout.direction)) if c is not None]


def _columns(layout: LogLayout) -> list[str]:
    """The log columns ``layout`` names: time, position, currents, torque, direction."""
    return [c for _, c in named_columns(layout)]


def current_columns(layout: LogLayout) -> list[str]:
    """The current columns ``layout`` names: three phases, the q axis, or none."""
    if layout.phase_currents is not None:
        return list(layout.phase_currents)
    return [] if layout.i_q is None else [layout.i_q]


def _rows(path: Path, body: bytes, names: list[str], layout: LogLayout) -> np.ndarray:
    """The data rows under the column ``names``: plain decimals by the compiled parser, anything else by numpy
    (a ``#`` is no comment: a value that is not a number); errors name the line and column, never quote the
    file."""
    width = len(names)
    delimiter = layout.delimiter.encode()
    rows = None
    if delimiter == b"," or b"," not in body:
        rows = parse_rows(body.replace(delimiter, b","), width, MAX_LOG_ROWS)
    if rows is None:
        try:
            rows = np.loadtxt(io.BytesIO(body), delimiter=layout.delimiter, ndmin=2, dtype=float,
                              max_rows=MAX_LOG_ROWS + 1, comments=None)
        except ValueError as e:
            raise BenchFormatError(f"{path}: {loadtxt_problem(e, names, layout.delimiter, layout.header_lines)}"
                                   ) from None
    if rows.shape[0] > MAX_LOG_ROWS:
        raise BenchFormatError(f"{path}: more than {MAX_LOG_ROWS} rows (refused)")
    if rows.shape[0] < 3:
        raise BenchFormatError(f"{path}: {rows.shape[0]} rows after the header; a log needs 3 or more")
    if rows.shape[1] != width:
        raise BenchFormatError(f"{path}: line {layout.header_lines + 1} has {rows.shape[1]} fields, the header "
                               f"has {width}")
    return rows
