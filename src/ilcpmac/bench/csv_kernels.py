"""The numba kernels of `ilcpmac.bench.fastcsv`: fixed-point formatting and plain-decimal parsing of CSV rows."""

import numpy as np
from numba import njit


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
def format_kernel(values, decimals, out, pairs):
    """Write rows of ``values`` (n, m) into byte buffer ``out``; return the bytes used."""
    pos = 0
    n, m = values.shape
    scales = np.empty(m, np.int64)
    for c in range(m):
        scales[c] = 10 ** decimals[c]
    for r in range(n):
        for c in range(m):
            scaled = int(np.rint(values[r, c] * scales[c]))  # rint: np.round would compile rounding to any decimals
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


#: largest mantissa a double holds exactly
_MAX_MANTISSA = 2**53


@njit(cache=True, nogil=True)
def parse_kernel(buf, out, pow10):
    """Parse rows of plain decimal numbers from ``buf`` into ``out`` (rows, columns); return the rows filled.

    A field is [sign] digits [. digits] [e [sign] digits] of at most 2^53 as an
    integer mantissa and a power of ten within 10^+-22, so that one IEEE
    multiplication or division gives the correctly rounded double (Clinger's
    fast path). Anything else (spaces, blank lines, NaN, a field count other
    than the columns', longer numbers) returns -1: the caller parses the file
    another way.
    """
    n = buf.size
    rows, m = out.shape
    pos = 0
    r = 0
    while pos < n and r < rows:
        for c in range(m):
            negative = False
            if pos < n and (buf[pos] == 45 or buf[pos] == 43):  # '-' '+'
                negative = buf[pos] == 45
                pos += 1
            mantissa = 0
            digits = 0
            power = 0
            dot = False
            while pos < n:
                b = buf[pos]
                if 48 <= b <= 57:
                    mantissa = mantissa * 10 + (b - 48)
                    if mantissa > _MAX_MANTISSA:
                        return -1
                    digits += 1
                    if dot:
                        power -= 1
                elif b == 46 and not dot:  # '.'
                    dot = True
                else:
                    break
                pos += 1
            if digits == 0:
                return -1
            if pos < n and (buf[pos] == 101 or buf[pos] == 69):  # 'e' 'E'
                pos += 1
                sign = 1
                if pos < n and (buf[pos] == 45 or buf[pos] == 43):
                    sign = -1 if buf[pos] == 45 else 1
                    pos += 1
                exponent = 0
                exp_digits = 0
                while pos < n and 48 <= buf[pos] <= 57 and exp_digits < 4:
                    exponent = exponent * 10 + (buf[pos] - 48)
                    exp_digits += 1
                    pos += 1
                if exp_digits == 0 or exp_digits == 4:
                    return -1
                power += sign * exponent
            if power > 22 or power < -22:
                return -1
            value = mantissa * pow10[power] if power >= 0 else mantissa / pow10[-power]
            out[r, c] = -value if negative else value
            if c < m - 1:
                if pos >= n or buf[pos] != 44:  # ','
                    return -1
                pos += 1
            elif pos < n:
                if buf[pos] == 13:  # '\r\n'
                    pos += 1
                if pos >= n or buf[pos] != 10:
                    return -1
                pos += 1
        r += 1
    return r
