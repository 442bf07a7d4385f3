"""The numba kernel of `ilcpmac.core.current_loop`: the count recursion of a first-order lag.

Apart from the loop's model so that importing `CurrentLoop` (records, stages, the CLI) does not import numba.
"""

import numpy as np
from numba import njit


@njit(cache=True)
def _advance(s: float, a: float, x_now: float, x_next: float, tau: float, dt: float, continuous: bool) -> float:
    """The state at the next count from ``s`` at this one (``a`` = exp(-dt / tau))."""
    if continuous:  # exact for an input linear between counts
        return a * s + x_next - a * x_now - (x_next - x_now) * (1.0 - a) * tau / dt
    return x_now + (s - x_now) * a


@njit(cache=True)
def warm_up_start(decay: np.ndarray) -> int:
    """The count of a revolution from which the recursion, started there, has forgotten its start below 1e-16
    by the revolution's end (``decay`` = exp(-dt / tau) per count)."""
    start = decay.size - 1
    remaining = 1.0
    while start > 0 and remaining > 1e-16:
        remaining *= decay[start]
        start -= 1
    return start


@njit(cache=True)
def lag_kernel(x: np.ndarray, dt: np.ndarray, tau: float, decay: np.ndarray, sample_decay: np.ndarray, delayed: bool,
               continuous: bool, out: np.ndarray) -> None:
    """The count recursion (`ilcpmac.core.current_loop`) for one phase, x of shape (n_trials, cpr); fills ``out``.

    ``decay`` = exp(-dt / tau) per count; ``delayed``: T_d >= 0, the sample
    lies between the previous count and this one, and ``sample_decay`` =
    exp(-(dt_{c-1} - T_d) / tau), else exp(T_d / tau) (0 without lag). With ``continuous`` the input is linear
    between counts (a smooth signal such as the back-EMF) instead of a
    staircase, and ``out`` holds the undelayed state at each count.
    """
    n_trials, cpr = x.shape
    for k in range(n_trials):
        start = warm_up_start(decay[k])  # warm up over the end of the revolution
        s = x[k, start]
        s_prev = s
        for c in range(start, cpr):
            s_prev = s
            s = _advance(s, decay[k, c], x[k, c], x[k, c + 1 if c + 1 < cpr else 0], tau, dt[k, c], continuous)
        for c in range(cpr):
            following = c + 1 if c + 1 < cpr else 0
            if not continuous:
                if delayed:  # the state at t_c - T_d, between counts c - 1 and c
                    x_prev = x[k, c - 1]  # c - 1 = -1 wraps to the revolution's last count
                    out[k, c] = x_prev + (s_prev - x_prev) * sample_decay[k, c]
                else:  # the state at t_c + |T_d|, after count c
                    out[k, c] = x[k, c] + (s - x[k, c]) * sample_decay[k, c]
            s_prev = s
            s = _advance(s, decay[k, c], x[k, c], x[k, following], tau, dt[k, c], continuous)
            if continuous:
                out[k, following] = s
