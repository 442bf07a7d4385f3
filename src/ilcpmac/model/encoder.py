"""Graduation errors of an incremental encoder: where its lines truly sit.

Convention, in counts: line c (c = 0 .. N - 1, N counts per revolution) sits
at the true mechanical angle ``(c + e_c) 2 pi / N``. A positive ``e_c`` puts
the line late: at constant speed f (rev / s) count c is seen ``e_c / (N f)``
seconds after a perfect encoder's. The errors have mean zero (a shift of all
lines is an angle offset, not an error) and must stay below
`MAX_LINE_ERROR_COUNTS` for the lines to keep their order
(`line_errors_problem`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["MAX_LINE_ERROR_COUNTS", "line_errors_counts", "line_errors_problem"]

#: Every line lies less than half a count from its nominal angle (so the lines keep their order).
MAX_LINE_ERROR_COUNTS = 0.5


def line_errors_counts(counts_per_rev: int, eccentricity_counts: float, eccentricity_phase_rad: float,
                       line_std_counts: float, seed: int) -> np.ndarray:
    """The error of each line, counts, shape (counts_per_rev,).

    ``e_c = eccentricity_counts sin(2 pi c / N + eccentricity_phase_rad) +
    line_std_counts z_c``, less its mean, with ``z_c`` standard normal from
    ``np.random.default_rng(seed)``: one draw per encoder, the same in every
    trial (the errors are fixed to the position).

    Parameters
    ----------
    counts_per_rev : int
        N, lines per mechanical revolution.
    eccentricity_counts : float
        Amplitude of the once-per-revolution error (a disk mounted off centre), counts.
    eccentricity_phase_rad : float
        Its phase at line 0, rad.
    line_std_counts : float
        RMS of the independent error of each line, counts.
    seed : int
        Seed of the per-line draws.
    """
    angle_rad = 2.0 * np.pi * np.arange(counts_per_rev) / counts_per_rev
    errors = (eccentricity_counts * np.sin(angle_rad + eccentricity_phase_rad)
              + line_std_counts * np.random.default_rng(seed).standard_normal(counts_per_rev))
    centred: np.ndarray = errors - errors.mean()
    return centred


def line_errors_problem(errors_counts: np.ndarray, counts_per_rev: int) -> str | None:
    """Why ``errors_counts`` cannot be the line errors of an encoder of ``counts_per_rev`` lines, or None.

    They must be a real array of shape (counts_per_rev,), finite, each below
    `MAX_LINE_ERROR_COUNTS` in magnitude.
    """
    errors = np.asarray(errors_counts)
    if errors.dtype.kind not in "fiu" or errors.shape != (counts_per_rev,):
        return f"line errors must be {counts_per_rev} real numbers, got shape {errors.shape} of {errors.dtype}"
    if not np.all(np.isfinite(errors)):
        return "line errors hold NaN or infinite values"
    worst = int(np.argmax(np.abs(errors)))
    if not abs(errors[worst]) < MAX_LINE_ERROR_COUNTS:
        return (f"line {worst} errs by {errors[worst]:.3g} counts, not within {MAX_LINE_ERROR_COUNTS} "
                "(the lines would leave their order)")
    return None
