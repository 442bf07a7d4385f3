"""Position-domain ("harmonics domain", report sec. 2.3) analysis of position-sampled data.

Data sampled once per encoder count are periodic in the mechanical angle; a DFT
over whole revolutions gives harmonics of the mechanical revolution, not
frequencies. Ripple figures follow DESIGN.md: the synchronous average over the
trial's whole revolutions, limited to harmonics 1..H.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


def whole_revolutions(count: np.ndarray, counts_per_rev: int) -> np.ndarray:
    """Mask of the samples that lie in revolutions covered from their first to their last count."""
    rev = count // counts_per_rev
    first, last = rev[0], rev[-1]
    if count[0] > first * counts_per_rev:
        first += 1
    if count[-1] < (last + 1) * counts_per_rev - 1:
        last -= 1
    return (rev >= first) & (rev <= last)


def synchronous_average(count: np.ndarray, values: np.ndarray, counts_per_rev: int) -> np.ndarray:
    """Average of ``values`` per encoder count over the whole revolutions, shape (counts_per_rev, ...).

    Counts that were never sampled (skipped) are filled by periodic linear interpolation.
    """
    mask = whole_revolutions(count, counts_per_rev)
    if not mask.any():
        raise ValueError("no whole revolution in the data")
    position = count[mask] % counts_per_rev
    values = np.asarray(values)[mask]
    sums = np.zeros((counts_per_rev,) + values.shape[1:])
    np.add.at(sums, position, values)
    hits = np.bincount(position, minlength=counts_per_rev)
    seen = hits > 0
    average = sums[seen] / hits[seen].reshape((-1,) + (1,) * (values.ndim - 1))
    if seen.all():
        return average
    grid = np.arange(counts_per_rev)
    known = grid[seen]
    flat = average.reshape(known.size, -1)
    filled = np.column_stack([np.interp(grid, known, col, period=counts_per_rev) for col in flat.T])
    return filled.reshape((counts_per_rev,) + values.shape[1:])


def harmonic_amplitudes(table: np.ndarray) -> np.ndarray:
    """Complex amplitudes c_h, h = 0..N/2, of a per-count table over one revolution.

    ``table = Re(sum_h c_h exp(j h theta))`` with c_0 the mean (one-sided spectrum).
    """
    c = np.fft.rfft(table, axis=0) / table.shape[0]
    c[1:] *= 2.0
    if table.shape[0] % 2 == 0:
        c[-1] /= 2.0
    return c


def band_limited(table: np.ndarray, max_harmonic: int) -> np.ndarray:
    """The table with only harmonics 1..max_harmonic (mean and higher harmonics removed)."""
    spectrum = np.fft.rfft(table, axis=0)
    spectrum[0] = 0.0
    spectrum[max_harmonic + 1:] = 0.0
    return np.fft.irfft(spectrum, n=table.shape[0], axis=0)


def harmonic_columns(theta_rad: np.ndarray, orders) -> np.ndarray:
    """Regressors [cos(o theta), sin(o theta)] per order o, shape (n, 2 len(orders))."""
    arg = np.outer(theta_rad, np.asarray(orders, float))
    return np.hstack([np.cos(arg), np.sin(arg)])


@dataclass(frozen=True)
class RippleFigures:
    """Ripple of one trial (DESIGN.md): fractions of the mean torque, amplitudes in N m.

    Attributes
    ----------
    pp, rms : float
        Peak-to-peak and RMS of the band-limited synchronous average, over the mean torque.
    rest_rms : float
        RMS of what is left (non-repeatable, and above H), over the mean torque.
    amp_1x, amp_2x, amp_cogging : float
        Amplitudes at 1x and 2x electrical and at the cogging order, N m.
    amp_rest : float
        RMS of the other harmonics in 1..H, N m.
    """

    pp: float
    rms: float
    rest_rms: float
    amp_1x: float
    amp_2x: float
    amp_cogging: float
    amp_rest: float


def ripple_figures(count: np.ndarray, torque_nm: np.ndarray, counts_per_rev: int, mean_torque_nm: float,
                   pole_pairs: int, cogging_order: int, max_harmonic: int = 150) -> RippleFigures:
    """Ripple figures of a position-sampled torque, as DESIGN.md defines them.

    The torque's mean and linear drift are removed first (a piezo sensor
    cannot measure them); ``mean_torque_nm`` is the mean torque the fractions
    refer to.
    """
    mask = whole_revolutions(count, counts_per_rev)
    count, torque = count[mask], torque_nm[mask]
    trend = np.polyval(np.polyfit(count.astype(float), torque, 1), count)
    detrended = torque - trend
    average = synchronous_average(count, detrended, counts_per_rev)
    ripple = band_limited(average, max_harmonic)
    c = np.abs(harmonic_amplitudes(ripple))
    named = [h for h in (pole_pairs, 2 * pole_pairs, cogging_order) if h <= max_harmonic]
    others = np.ones(c.size, bool)
    others[0] = False
    others[max_harmonic + 1:] = False
    others[named] = False
    rest = detrended - ripple[count % counts_per_rev]

    def amp(h: int) -> float:
        return float(c[h]) if h <= max_harmonic else 0.0

    return RippleFigures(
        pp=float(np.ptp(ripple) / mean_torque_nm),
        rms=float(np.std(ripple) / mean_torque_nm),
        rest_rms=float(np.std(rest) / mean_torque_nm),
        amp_1x=amp(pole_pairs),
        amp_2x=amp(2 * pole_pairs),
        amp_cogging=amp(cogging_order),
        amp_rest=float(np.sqrt(np.sum(c[others] ** 2) / 2.0)),
    )
