"""Fast fixed-point CSV formatting (numba): trial files are written as they finish.

``numpy.savetxt`` and ``%`` formatting cost ~0.1 s per 32768-row trial; this
kernel writes each value as a fixed-point decimal with a per-column number of
decimals, about four times faster, and releases the GIL so a campaign can
write one trial while it simulates the next. Values are rounded to that many
decimals.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import njit

#: largest magnitude a column may hold at its number of decimals (int64 headroom)
_MAX_SCALED = 9.0e17


#: "00" "01" ... "99": two decimal digits per table lookup
_PAIRS = np.frombuffer("".join(f"{i:02d}" for i in range(100)).encode(), np.uint8).copy()


@njit(cache=True, inline="always")
def _put_uint(buf, pos, value, min_digits, pairs):
    """Write the decimal digits of a non-negative int, at least ``min_digits`` of them."""
    n = 1
    rest = value // 10
    while rest > 0:
        n += 1
        rest //= 10
    n = max(n, min_digits)
    k = pos + n
    while k - pos >= 2:  # two digits at a time, from the right
        q = value // 100
        r = value - q * 100
        buf[k - 2] = pairs[2 * r]
        buf[k - 1] = pairs[2 * r + 1]
        value = q
        k -= 2
    if k > pos:
        buf[pos] = 48 + value % 10
    return pos + n


@njit(cache=True, nogil=True)
def _format_rows(values, decimals, out, pairs):
    """Write rows of ``values`` (n, m) into byte buffer ``out``; return the bytes used."""
    pos = 0
    n, m = values.shape
    scales = np.empty(m, np.int64)
    for c in range(m):
        scales[c] = 10 ** decimals[c]
    for r in range(n):
        for c in range(m):
            scaled = int(np.round(values[r, c] * scales[c]))
            if scaled < 0:
                out[pos] = 45  # '-'
                pos += 1
                scaled = -scaled
            whole = scaled // scales[c]
            pos = _put_uint(out, pos, whole, 1, pairs)
            if decimals[c] > 0:
                out[pos] = 46  # '.'
                pos += 1
                pos = _put_uint(out, pos, scaled - whole * scales[c], decimals[c], pairs)
            out[pos] = 44 if c < m - 1 else 10  # ',' or '\n'
            pos += 1
    return pos


def _format_block(values: np.ndarray, decimals: np.ndarray) -> bytes:
    width = 21 + decimals.max(initial=0) + 3  # sign, 19 integer digits, '.', decimals, separator
    out = np.empty(values.shape[0] * values.shape[1] * width, np.uint8)
    used = _format_rows(values, decimals, out, _PAIRS)
    return out[:used].tobytes()


def format_rows(values: np.ndarray, decimals: np.ndarray, threads: int = 2) -> bytes:
    """CSV body for ``values`` (n rows, m columns), column c with ``decimals[c]`` decimals.

    Large tables are formatted in ``threads`` blocks of rows at once (the kernel
    releases the GIL). Raises ValueError for non-finite values or values too
    large for their decimals.
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
    if threads < 2 or values.shape[0] < 65536:
        return _format_block(values, decimals)
    blocks = np.array_split(values, threads)
    with ThreadPoolExecutor(max_workers=threads) as pool:
        return b"".join(pool.map(_format_block, blocks, [decimals] * threads))
