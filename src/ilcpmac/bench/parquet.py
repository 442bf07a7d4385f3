"""Trial files in Parquet (docs/bench-format.md): the trial CSV's columns and numbers, as float64 columns.

Each value is stored as the double the CSV's text of it parses to (the value
rounded to the column's decimals, `rounded`): a Parquet DOUBLE (``count``: an
INT64), so pandas, polars and Arrow read every column as float64 (int64) with
no conversion, and reading a Parquet trial gives exactly the doubles reading
its CSV gives. Each column is zstd-compressed in the encoding `_encoding`
picks for it (a dictionary, byte-stream-split or plain). Files of earlier
versions store DECIMAL(18, d) columns, which read as before.
"""

from __future__ import annotations

from collections.abc import Callable, Collection
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from ilcpmac.core.errors import BenchFormatError

SUFFIX = ".parquet"
#: decimal digits a DECIMAL column (files of earlier versions, other writers) may have: a 64-bit integer's
PRECISION = 18
#: bytes a numeric column may take per row once decompressed (a 16-byte decimal), and per column chunk besides
_COLUMN_ROW_BYTES = 16
_COLUMN_SLACK_BYTES = 1 << 20
#: zstd's level for every column (docs/bench-format.md: sizes and times at other levels)
ZSTD_LEVEL = 4
#: a float column whose distinct values number at most this share of its rows is dictionary-encoded
_DICTIONARY_SHARE = 0.5
#: the encodings tried for any other float column, on its first _SAMPLE_ROWS values
_ENCODINGS = ("BYTE_STREAM_SPLIT", "PLAIN")
_SAMPLE_ROWS = 16384
#: `_file`'s name for a dictionary (Parquet's RLE_DICTIONARY, with a PLAIN dictionary page)
DICTIONARY = "RLE_DICTIONARY"


def rounded(values: np.ndarray, d: int) -> np.ndarray:
    """round(``values`` 10^d) / 10^d (half to even, through a double) as a new float64 array: each value the
    double nearest to its text with ``d`` decimals, the number the CSV writer writes and its reader reads."""
    scale = 10.0**d
    out = np.multiply(values, scale, dtype=np.float64)
    np.rint(out, out=out)
    out /= scale
    return out


def _file(header: list[str], arrays: list[pa.Array], encodings: list[str]) -> bytes:
    """A Parquet file of ``arrays``, column c named ``header[c]`` in the encoding ``encodings[c]`` (DICTIONARY:
    a dictionary), zstd-compressed, required (no value is ever null, so no definition levels), without statistics
    (no reader of a trial filters on them) and without an Arrow schema (a reader needs none)."""
    schema = pa.schema([pa.field(name, array.type, nullable=False) for name, array in zip(header, arrays)])
    sink = pa.BufferOutputStream()
    pq.write_table(pa.Table.from_arrays(arrays, schema=schema), sink, compression="zstd",
                   compression_level=ZSTD_LEVEL,
                   use_dictionary=[name for name, e in zip(header, encodings) if e == DICTIONARY],
                   column_encoding={name: e for name, e in zip(header, encodings) if e != DICTIONARY},
                   store_schema=False, write_statistics=False)
    return sink.getvalue().to_pybytes()


def _encoding(name: str, array: pa.Array, values: np.ndarray) -> str:
    """The encoding of the float64 column ``values`` (``array`` over it): a dictionary when its values repeat
    (at most `_DICTIONARY_SHARE` of them distinct), else whichever of byte-stream-split and plain makes the smaller
    file of its first `_SAMPLE_ROWS` values (byte-stream-split for a slowly changing value, plain for noise about
    zero, whose sign and exponent change from row to row)."""
    if values.size and np.unique(values).size <= _DICTIONARY_SHARE * values.size:
        return DICTIONARY
    sample = array.slice(0, _SAMPLE_ROWS)
    return min(_ENCODINGS, key=lambda e: len(_file([name], [sample], [e])))


def table_bytes(header: list[str], columns: list[np.ndarray], decimals: list[int]) -> bytes:
    """A Parquet file holding ``columns`` (1-D), column c rounded to ``decimals[c]`` decimals (`rounded`).

    A column of integers is stored as it is, as INT64 (delta-encoded), any
    other as DOUBLE in the encoding `_encoding` picks: the doubles the CSV's
    text gives, which any reader gives back bit for bit, as float64.

    Raises
    ------
    ValueError
        For a NaN or infinite value.
    """
    arrays, encodings = [], []
    for name, values, d in zip(header, columns, decimals):
        if values.dtype.kind in "iu":
            arrays.append(pa.array(values, pa.int64()))
            encodings.append("DELTA_BINARY_PACKED")
            continue
        values = rounded(values, d)
        if values.size and not (np.isfinite(values.min()) and np.isfinite(values.max())):
            raise ValueError("cannot write NaN or infinite values")
        arrays.append(pa.array(values))
        encodings.append(_encoding(name, arrays[-1], values))
    return _file(header, arrays, encodings)


def _one_line(e: Exception) -> str:
    text = " ".join(str(e).split())
    return text if len(text) <= 160 else text[:160] + "..."


def _separate(header: list[str], rows: int) -> list[np.ndarray]:
    """One new float64 array of ``rows`` values per column."""
    return [np.empty(rows) for _ in header]


def _decode(path: Path, name: str, column: pa.ChunkedArray, integral: bool, out: np.ndarray) -> None:
    """A numeric column into the float64 array ``out``: a decimal as its integer over 10^scale, exactly as the
    CSV text parses.

    Decimals may come as any of Arrow's decimal widths (32 to 256 bits, as another writer's stored Arrow schema
    says), each value a little-endian two's-complement integer. Its high words are checked to extend the low
    word's sign unless the file stores it in an INT32 or INT64 (``integral``), which Arrow widens by sign
    extension.
    """
    kind = column.type
    if pa.types.is_decimal(kind) and kind.precision > PRECISION:
        raise BenchFormatError(f"{path}: column {name!r} is {kind}; decimals may have at most {PRECISION} "
                               "digits (docs/bench-format.md)")
    start = 0
    for chunk in column.chunks:
        part = out[start: start + len(chunk)]
        start += len(chunk)
        if not pa.types.is_decimal(kind):
            part[:] = chunk.to_numpy()
            continue
        words = max(kind.bit_width // 64, 1)
        word: type[np.signedinteger] = np.int64 if kind.bit_width >= 64 else np.int32
        values = np.frombuffer(chunk.buffers()[1], word).reshape(
            -1, words)[chunk.offset: chunk.offset + len(chunk)]
        if words > 1 and not integral:
            wide = np.flatnonzero((values[:, 1:] != (values[:, :1] >> 63)).any(axis=1))
            if wide.size:
                raise BenchFormatError(f"{path}: row {start - len(chunk) + wide[0] + 1}: {name} holds more than "
                                       f"its {kind.precision} digits")
        np.divide(values[:, 0], 10.0**kind.scale, out=part)


def _first_not_finite(columns: list[np.ndarray]) -> tuple[int, int] | None:
    """(row, column) of the first value, row by row, of ``columns`` that is NaN or infinite; None if none is."""
    first = None
    for k, values in enumerate(columns):
        if values.size and not (np.isfinite(values.min()) and np.isfinite(values.max())):
            row = int(np.argmin(np.isfinite(values)))
            if first is None or row < first[0]:
                first = (row, k)
    return first


def read_columns(path: Path, max_rows: int, wanted: Collection[str],
                 allocate: Callable[[list[str], int], list[np.ndarray]] = _separate) -> tuple[
                     list[str], list[np.ndarray]]:
    """The columns of ``path`` named in ``wanted`` (those it has), as float64 arrays, every value finite.

    The footer is read first: a file declaring more than ``max_rows`` rows, a
    column ``wanted`` that is not a number (integer, float or decimal), or a
    column chunk larger than its rows may take is refused before any data is
    decompressed. Other columns are never read. Each column is decoded straight
    into its array of ``allocate(header, rows)`` (1-D, float64, possibly strided: a column of a larger
    array), in one pass.

    Raises
    ------
    BenchFormatError
        Naming ``path`` and the row or column at fault.
    """
    try:
        with pq.ParquetFile(path, memory_map=False) as f:
            meta, schema = f.metadata, f.schema_arrow
            if meta.num_rows > max_rows or meta.num_rows < 0:
                raise BenchFormatError(f"{path}: declares {meta.num_rows} rows, more than {max_rows} "
                                       "(docs/bench-format.md)")
            names = schema.names
            dup = sorted({n for n in names if names.count(n) > 1})
            if dup:
                raise BenchFormatError(f"{path}: column {dup[0][:120]!r} appears twice")
            header = [n for n in names if n in wanted]
            for name in header:
                kind = schema.field(name).type
                if not (pa.types.is_integer(kind) or pa.types.is_floating(kind) or pa.types.is_decimal(kind)):
                    raise BenchFormatError(f"{path}: column {name!r} holds {kind}, not numbers")
            stored = f.schema
            integral = {stored.column(c).path: stored.column(c).physical_type in ("INT32", "INT64")
                        for c in range(len(stored))}
            for g in range(meta.num_row_groups):
                group = meta.row_group(g)
                bound = _COLUMN_ROW_BYTES * group.num_rows + _COLUMN_SLACK_BYTES
                for c in range(group.num_columns):
                    chunk = group.column(c)
                    if chunk.path_in_schema in header and chunk.total_uncompressed_size > bound:
                        raise BenchFormatError(f"{path}: column {chunk.path_in_schema!r} declares "
                                               f"{chunk.total_uncompressed_size} bytes, more than its "
                                               f"{group.num_rows} rows may take")
            table = f.read(columns=header, use_threads=True)
    except (pa.ArrowException, OSError, ValueError) as e:
        raise BenchFormatError(f"{path}: not a readable Parquet file ({_one_line(e)})") from None
    if table.num_rows != meta.num_rows:
        raise BenchFormatError(f"{path}: holds {table.num_rows} rows, its footer declares {meta.num_rows}")
    columns = allocate(header, table.num_rows)
    for name, out in zip(header, columns):
        column = table.column(name)
        if column.null_count:
            row = int(np.flatnonzero(column.is_null().to_numpy(zero_copy_only=False))[0]) + 1
            raise BenchFormatError(f"{path}: row {row}: {name[:120]} is empty")
        _decode(path, name, column, integral.get(name, False), out)
    floats = [k for k, name in enumerate(header) if pa.types.is_floating(table.schema.field(name).type)]
    bad = _first_not_finite([columns[k] for k in floats])
    if bad:
        raise BenchFormatError(f"{path}: row {bad[0] + 1}: {header[floats[bad[1]]][:120]} is not a finite number")
    return header, columns
