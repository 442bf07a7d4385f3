"""Process-wide settings of a process that runs campaigns (the CLI, a sweep's workers), made before it works."""

from __future__ import annotations

import ctypes
import os

__all__ = ["KEPT_BLOCK_BYTES", "keep_freed_memory", "tune_process", "use_one_blas_thread"]


def use_one_blas_thread() -> None:
    """One OpenBLAS thread, unless OPENBLAS_NUM_THREADS says otherwise (read when NumPy is first imported).

    The matrices are small: a second BLAS thread costs more than it gains and, spinning while it waits,
    takes a core from the simulator's threads (0.8 s of the default ``ilcpmac run``'s 7.3 s on two cores,
    more when they are shared).
    """
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


#: glibc's mallopt parameters (malloc.h): M_TRIM_THRESHOLD, M_MMAP_THRESHOLD
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
#: blocks up to this size come from malloc's heap and are reused; freed memory up to twice it stays there
KEPT_BLOCK_BYTES = 64 << 20


def keep_freed_memory() -> None:
    """Have glibc's malloc reuse freed blocks of up to `KEPT_BLOCK_BYTES` instead of mapping each afresh,
    unless MALLOC_MMAP_THRESHOLD_ says otherwise; elsewhere than glibc nothing changes.

    A trial's arrays are megabytes: above malloc's (adaptive) mmap threshold every NumPy temporary of that size
    is a new mapping whose pages all fault on first touch. Reused, the campaign's analysis of a trial takes
    4.8 ms instead of 7.4 and its rounding to the file's decimals 1.4 ms instead of 4.0.
    """
    if "MALLOC_MMAP_THRESHOLD_" in os.environ:
        return
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (AttributeError, OSError, TypeError):
        return
    mallopt(_M_MMAP_THRESHOLD, KEPT_BLOCK_BYTES)
    mallopt(_M_TRIM_THRESHOLD, 2 * KEPT_BLOCK_BYTES)


def tune_process() -> None:
    """`use_one_blas_thread` and `keep_freed_memory`."""
    use_one_blas_thread()
    keep_freed_memory()
