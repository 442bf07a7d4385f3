"""Count means: a record whose every count is the mean over b encoder lines centred on it.

A record at N / b counts per revolution of an encoder of N lines may hold at
count c the value at line b c (b = 1, or a decimated encoder: the edge of
every b-th line) or the mean over the lines centred on line b c: lines
b c - b/2 .. b c + b/2 with the two end lines half-weighted for even b
(b + 1 lines, weights summing to b), lines b c - (b - 1)/2 .. b c + (b - 1)/2
for odd b. Centred, the mean delays no harmonic and scales harmonic h of the
revolution by `bin_response`; it keeps the information of every line (the
noise of a harmonic is the per-line record's), where decimation keeps one
line in b.
"""

from __future__ import annotations

import numpy as np

__all__ = ["bin_response", "count_means", "noise_gain", "per_line", "sample_means"]


def bin_response(harmonics: np.ndarray | float, lines_per_rev: int, b: int) -> np.ndarray:
    """What the centred mean over ``b`` of ``lines_per_rev`` lines makes of harmonic h: real (no delay).

    sin(pi h b / N) / (b tan(pi h / N)) for even b (the half-weighted ends),
    sin(pi h b / N) / (b sin(pi h / N)) for odd b; 1 at h = 0 and for b = 1.
    """
    x = np.pi * np.asarray(harmonics, dtype=np.float64) / lines_per_rev
    below = np.tan(x) if b % 2 == 0 else np.sin(x)
    safe = np.where(x == 0.0, 1.0, below)
    return np.where(x == 0.0, 1.0, np.sin(b * x) / (b * safe))


def noise_gain(b: int) -> float:
    """A harmonic's noise power in a record of count means over b lines, over the one its rows' variance gives as
    if they were independent: 1 / (b sum_j w_j^2) (the weights `_weights`; 8/7 for b = 4, 4/3 for b = 2, 1 for
    odd b). Independent noise at the lines leaves each low harmonic the per-line record's power, and each row
    sum_j w_j^2 of a line's variance; neighbouring rows share their end lines (even b)."""
    return float(1.0 / (b * np.sum(_weights(b) ** 2)))


def _weights(b: int) -> np.ndarray:
    """The weights of lines -(b // 2) .. b // 2 about a count's centre, summing to 1."""
    weights = np.ones(2 * (b // 2) + 1)
    if b % 2 == 0:
        weights[[0, -1]] = 0.5
    return weights / b


def count_means(table: np.ndarray, b: int) -> np.ndarray:
    """The count means of periodic per-line tables (last axis: the N lines of a revolution): N / b per row."""
    table = np.asarray(table, dtype=np.float64)
    out = np.zeros(table.shape)
    for offset, weight in zip(range(-(b // 2), b // 2 + 1), _weights(b)):
        out += weight * np.roll(table, -offset, axis=-1)
    return out[..., ::b]


def per_line(table: np.ndarray, b: int) -> np.ndarray:
    """A periodic per-count table (first axis: the N counts of a revolution) at the N b lines, by its harmonics
    below N / 2 (exact for a table without content at N / 2 and above, a back-EMF table, say)."""
    table = np.asarray(table, dtype=np.float64)
    n = table.shape[0]
    spectrum = np.fft.rfft(table, axis=0)
    lines = np.zeros((b * n // 2 + 1,) + table.shape[1:], complex)
    lines[: (n + 1) // 2] = spectrum[: (n + 1) // 2]
    return np.fft.irfft(lines, b * n, axis=0) * b


def sample_means(line: np.ndarray, columns: list[np.ndarray], b: int, n_counts: int
                 ) -> tuple[np.ndarray, list[np.ndarray]]:
    """Counts 0 .. ``n_counts`` - 1 as count means of samples at lines ``line`` (integers from the line of
    count 0, increasing; lines may be missing), and each of ``columns`` (first axis: one row per sample) there.

    A count missing any of its lines (one the rotor skipped, the record's
    edges) is left out. Returns the counts kept and the columns' means there.
    """
    line = np.asarray(line, dtype=np.int64)
    shifted = line + b // 2
    count = np.floor_divide(shifted, b)
    rows, weights = np.arange(line.size), np.ones(line.size)
    if b % 2 == 0:  # a line midway between two counts' centres enters both, half each
        shared = np.flatnonzero(shifted - count * b == 0)
        weights[shared] = 0.5
        rows, count = np.concatenate([rows, shared]), np.concatenate([count, count[shared] - 1])
        weights = np.concatenate([weights, np.full(shared.size, 0.5)])
    inside = (count >= 0) & (count < n_counts)
    rows, count, weights = rows[inside], count[inside], weights[inside]
    total = np.bincount(count, weights, minlength=n_counts)
    kept = np.flatnonzero(total > b - 0.25)  # weights are halves: their sums are exact
    means = []
    for column in columns:
        values = column.reshape(column.shape[0], -1)
        sums = np.stack([np.bincount(count, weights * values[rows, k], minlength=n_counts)
                         for k in range(values.shape[1])], axis=-1)
        means.append((sums[kept] / total[kept, None]).reshape((kept.size,) + column.shape[1:]))
    return kept, means
