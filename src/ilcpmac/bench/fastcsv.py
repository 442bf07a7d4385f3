"""Fast fixed-point CSV formatting and parsing (numba kernels in `ilcpmac.bench.csv_kernels`, imported
when a large table is formatted or a body parsed, so that importing the bench format does not import numba).

``numpy.savetxt`` and ``%`` formatting cost ~0.1 s per 32768-row trial; this
kernel writes each value as a fixed-point decimal with a per-column number of
decimals, about four times faster, and releases the GIL so a campaign can
write one trial while it simulates the next. Values are rounded to that many
decimals. `parse_rows` reads such text back (plain decimal numbers) five
times faster than ``numpy.loadtxt``, to the same doubles.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np

#: largest magnitude a column may hold at its number of decimals (int64 headroom)
_MAX_SCALED = 9.0e17
#: most values of a table formatted without the compiled kernel
_SMALL_TABLE = 32768


#: "00" "01" ... "99": two decimal digits per table lookup
_PAIRS = np.frombuffer("".join(f"{i:02d}" for i in range(100)).encode(), np.uint8).copy()


def _format_block(values: np.ndarray, decimals: np.ndarray) -> bytes:
    from ilcpmac.bench.csv_kernels import format_kernel  # numba: loaded on the first CSV written

    width = 21 + decimals.max(initial=0) + 3  # sign, 19 integer digits, '.', decimals, separator
    out = np.empty(values.shape[0] * values.shape[1] * width, np.uint8)
    used = format_kernel(values, decimals, out, _PAIRS)
    return out[:used].tobytes()


def _format_small(values: np.ndarray, decimals: np.ndarray) -> bytes:
    """`csv_kernels.format_kernel` in Python, digit for digit: a small table (backemf.csv) is written without compiling
    the kernel (a second, when a run's numba cache is cold)."""
    scaled = np.round(values * 10.0**decimals).astype(np.int64).tolist()
    units = [10**d for d in decimals.tolist()]
    rows = []
    for row in scaled:
        fields = []
        for v, d, unit in zip(row, decimals.tolist(), units):
            whole, fraction = divmod(abs(v), unit)
            fields.append(f"{'-' if v < 0 else ''}{whole}" + (f".{fraction:0{d}d}" if d else ""))
        rows.append(",".join(fields) + "\n")
    return "".join(rows).encode()


def format_rows(values: np.ndarray, decimals: np.ndarray, threads: int = 2) -> bytes:
    """CSV body for ``values`` (n rows, m columns), column c with ``decimals[c]`` decimals.

    Large tables are formatted in ``threads`` blocks of rows at once (the kernel
    releases the GIL); tables of at most _SMALL_TABLE values in Python, to the
    same bytes. Raises ValueError for non-finite values or values too large
    for their decimals.
    """
    values = np.ascontiguousarray(values, dtype=np.float64)
    decimals = np.ascontiguousarray(decimals, dtype=np.int64)
    if values.ndim != 2 or decimals.shape != (values.shape[1],):
        raise ValueError("format_rows needs an (n, m) array and m decimals")
    if not np.all(np.isfinite(values)):
        raise ValueError("cannot write NaN or infinite values")
    limits = _MAX_SCALED / 10.0**decimals
    if np.any(np.abs(values) > limits):
        raise ValueError("a value is too large for its number of decimals")
    if values.size <= _SMALL_TABLE:
        return _format_small(values, decimals)
    if threads < 2 or values.shape[0] < 65536:
        return _format_block(values, decimals)
    blocks = np.array_split(values, threads)
    with ThreadPoolExecutor(max_workers=threads) as pool:
        return b"".join(pool.map(_format_block, blocks, [decimals] * threads))


#: 10^0 ... 10^22: every one exact in a double
_POW10 = 10.0 ** np.arange(23)


def parse_rows(body: bytes | np.ndarray, columns: int, max_rows: int) -> np.ndarray | None:
    """The rows of a CSV body (after its header; bytes or a read-only uint8 array) of plain decimal numbers,
    ``columns`` per row, exactly as a correctly rounding parser reads them, every one finite; at most ``max_rows``
    + 1 rows are parsed.

    Returns None when a field is not a plain decimal number, a row has another
    number of fields, or a line is blank: parse such a body another way.
    """
    from ilcpmac.bench.csv_kernels import parse_kernel  # numba: loaded on the first CSV read

    if columns < 1:
        return None
    text = np.frombuffer(body, np.uint8)
    lines = np.count_nonzero(text == 10) + (text.size > 0 and text[-1] != 10)
    out = np.empty((min(lines, max_rows + 1), columns))
    used = parse_kernel(text, out, _POW10)
    return None if used < 0 else out[:used]
