"""Position-domain ("harmonics domain", report sec. 2.3) analysis of position-sampled data.

Data sampled once per encoder count are periodic in the mechanical angle; a DFT
over whole revolutions gives harmonics of the mechanical revolution, not
frequencies. Ripple figures (docs/campaign.md) come from the synchronous average over the
trial's whole revolutions, limited to harmonics 1..H.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike


def whole_revolution_span(count: np.ndarray, counts_per_rev: int) -> slice:
    """The samples of strictly increasing ``count`` that lie in revolutions covered from their first to their
    last count: a slice (empty when there are none), so that selecting them copies nothing."""
    first, last = int(count[0]) // counts_per_rev, int(count[-1]) // counts_per_rev
    if count[0] > first * counts_per_rev:
        first += 1
    if count[-1] < (last + 1) * counts_per_rev - 1:
        last -= 1
    if last < first:
        return slice(0, 0)
    start, stop = np.searchsorted(count, [first * counts_per_rev, (last + 1) * counts_per_rev])
    return slice(int(start), int(stop))


def synchronous_average(count: np.ndarray, values: np.ndarray, counts_per_rev: int) -> np.ndarray:
    """Average of ``values`` per encoder count over the whole revolutions, shape (counts_per_rev, ...).

    Counts that were never sampled (skipped) are filled by periodic linear interpolation.
    """
    span = whole_revolution_span(count, counts_per_rev)
    if span.stop == span.start:
        raise ValueError("no whole revolution in the data")
    return synchronous_table(count[span], np.asarray(values)[span], counts_per_rev)


def linear_trend(x: np.ndarray, values: np.ndarray) -> np.ndarray:
    """The least-squares straight line through ``values`` against ``x``, at ``x``.

    ``values`` holds the samples along its last axis (one line per row of a stack).
    """
    dx = np.asarray(x, float)
    dx = dx - dx.mean()
    mean = values.mean(axis=-1, keepdims=True)
    # sum(dx) = 0: no need to centre values; one dot per line, as for a single line
    slope = np.array([np.dot(dx, line) for line in values.reshape(-1, dx.size)]) / max(np.dot(dx, dx), 1e-300)
    interpolated: np.ndarray = dx * slope.reshape(mean.shape) + mean
    return interpolated


def harmonic_amplitudes(table: np.ndarray, max_harmonic: int | None = None, axis: int = 0) -> np.ndarray:
    """Complex amplitudes c_h, h = 0..N/2 (or 0..max_harmonic), of a per-count table over one revolution.

    ``table = Re(sum_h c_h exp(j h theta))`` with c_0 the mean (one-sided spectrum); the counts run
    along ``axis``, and so do the amplitudes.
    """
    n = table.shape[axis]
    c = np.moveaxis(np.fft.rfft(table, axis=axis), axis, 0)[: None if max_harmonic is None else max_harmonic + 1] / n
    c[1:] *= 2.0
    if n % 2 == 0 and c.shape[0] == n // 2 + 1:
        c[-1] /= 2.0
    return np.moveaxis(c, 0, axis)


def table_from_amplitudes(amplitudes: np.ndarray, n_points: int) -> np.ndarray:
    """The per-count table ``Re(sum_h c_h exp(j h theta))`` over one revolution of ``n_points`` counts.

    The inverse of `harmonic_amplitudes`: ``amplitudes`` holds c_0, c_1, ... along axis 0
    (at most n_points // 2 + 1 of them; the missing higher ones are zero).
    """
    spectrum = np.zeros((n_points // 2 + 1,) + np.shape(amplitudes)[1:], complex)
    spectrum[: len(amplitudes)] = amplitudes
    spectrum[0] *= 2.0
    if n_points % 2 == 0 and len(amplitudes) > n_points // 2:
        spectrum[-1] *= 2.0
    return np.fft.irfft(spectrum, n=n_points, axis=0) * n_points / 2.0


def filtered(table: np.ndarray, response: np.ndarray, axis: int = 0) -> np.ndarray:
    """Per-count ``table`` with each harmonic h = 0..N/2 (along ``axis``) multiplied by ``response[h]``."""
    spectrum = np.fft.rfft(table, axis=axis)
    return np.fft.irfft(spectrum * response, n=table.shape[axis], axis=axis)


def harmonic_band(n_points: int, low: int, high: int, step: int = 1) -> np.ndarray:
    """1.0 at harmonics low, low + step, ... up to high of a table of ``n_points``, 0.0 elsewhere."""
    band = np.zeros(n_points // 2 + 1)
    band[low: high + 1: step] = 1.0
    return band


def harmonic_columns(theta_rad: np.ndarray, orders: ArrayLike) -> np.ndarray:
    """Regressors [cos(o theta), sin(o theta)] per order o, shape (n, 2 len(orders))."""
    arg = np.outer(theta_rad, np.asarray(orders, float))
    return np.hstack([np.cos(arg), np.sin(arg)])


@dataclass(frozen=True)
class RippleFigures:
    """Ripple of one trial (docs/campaign.md): fractions of the mean torque, amplitudes in N m.

    Attributes
    ----------
    pp, rms : float
        Peak-to-peak and RMS of the band-limited synchronous average, over the mean torque.
    rest_rms : float
        RMS of what is left (non-repeatable, and above H), over the mean torque.
    rms_repeatable : float
        ``rms`` with the expected contribution of the non-repeatable part to
        the average removed (from the revolution-to-revolution scatter): what
        compensation can still act on, over the mean torque.
    amp_1x, amp_2x, amp_cogging : float
        Amplitudes at 1x and 2x electrical and at the cogging order, N m.
    amp_rest : float
        RMS of the other harmonics in 1..H, N m.
    """

    pp: float
    rms: float
    rest_rms: float
    rms_repeatable: float
    amp_1x: float
    amp_2x: float
    amp_cogging: float
    amp_rest: float


#: draws of `expected_noise_pp`, and the seed of its generator (the figure is a function of its inputs)
NOISE_PP_DRAWS, NOISE_PP_SEED = 256, 20091


def expected_noise_pp(variance_nm2: np.ndarray, counts_per_rev: int, mean_nm: np.ndarray | None = None) -> float:
    """The expected peak-to-peak over one revolution of a ripple whose harmonics 1..H are independent complex
    Gaussians of variance ``variance_nm2[1:]`` (index 0, the mean, is left out) about ``mean_nm[1:]`` (complex;
    None: zero), N m.

    Noise of variance v_h in each harmonic's estimate leaves this much peak-to-peak in a table built from the
    estimates with nothing else in it: the floor that a synchronous average of that noise can show
    (docs/campaign.md, "The noise floor"). The peak-to-peak of a Gaussian process has no closed form; the mean
    over `NOISE_PP_DRAWS` draws of a fixed seed stands in for it (within about 1 % for white noise, 2 % for
    noise falling as 1 / h), each drawn on the fewest points, a power of two, that put 8 or more on a period of
    the highest harmonic (or ``counts_per_rev``, if fewer).
    """
    v = np.asarray(variance_nm2, float)
    counts_per_rev = min(counts_per_rev, 1 << max(int(8 * (v.size - 1)) - 1, 1).bit_length())
    rng = np.random.default_rng(NOISE_PP_SEED)
    sd = np.sqrt(v[1:] / 2.0)
    draws = np.zeros((NOISE_PP_DRAWS, v.size), complex)
    draws[:, 1:] = sd * (rng.standard_normal((NOISE_PP_DRAWS, v.size - 1))
                         + 1j * rng.standard_normal((NOISE_PP_DRAWS, v.size - 1)))
    if mean_nm is not None:
        draws[:, 1:] += np.asarray(mean_nm)[1:]
    return float(np.mean(np.ptp(table_from_amplitudes(draws.T, counts_per_rev), axis=0)))


def revolution_table(count: np.ndarray, values: np.ndarray, counts_per_rev: int) -> np.ndarray:
    """Position-sampled ``values`` as one row per revolution, shape ``values.shape[:-1] + (n_revs, counts_per_rev)``.

    ``count`` (strictly increasing) must cover whole revolutions (`whole_revolution_span`); ``values`` holds
    its samples along the last axis. Skipped counts are filled by linear interpolation within their
    revolution. When no count is skipped the table is a view of ``values``.
    """
    values = np.asarray(values, float)
    rev = count // counts_per_rev
    n_revs = int(rev[-1] - rev[0]) + 1
    shape = values.shape[:-1] + (n_revs, counts_per_rev)
    if count.size == n_revs * counts_per_rev:
        return values.reshape(shape)
    table = np.full(shape, np.nan)
    table[..., rev - rev[0], count % counts_per_rev] = values
    grid = np.arange(counts_per_rev)
    for row in table.reshape(-1, counts_per_rev):
        missing = np.isnan(row)
        if missing.any():
            row[missing] = np.interp(grid[missing], grid[~missing], row[~missing], period=counts_per_rev)
    return table


def table_harmonics(table: np.ndarray, max_harmonic: int) -> tuple[np.ndarray, np.ndarray]:
    """Harmonics 0..max_harmonic of a `revolution_table` averaged over its revolutions, and the variance of that mean.

    Each revolution's DFT gives complex amplitudes c_h^(r) (as `harmonic_amplitudes`);
    the mean over revolutions is the synchronous average's spectrum, and the
    revolution-to-revolution scatter gives its variance per harmonic,
    E|c_h - mean|^2 / n_revs (the non-repeatable part, e.g. sensor noise).
    Both have shape ``table.shape[:-2] + (max_harmonic + 1,)``.
    """
    n_revs = table.shape[-2]
    if n_revs < 2:
        raise ValueError("the variance of revolution harmonics needs at least 2 whole revolutions")
    c = harmonic_amplitudes(table, max_harmonic, axis=-1)
    mean = c.mean(axis=-2)
    variance = np.sum(np.abs(c - mean[..., None, :]) ** 2, axis=-2) / (n_revs - 1) / n_revs
    return mean, variance


#: harmonics on each side whose revolution-to-revolution scatter `pooled_variance` pools with a harmonic's own
POOL_HALF_WINDOW = 5
#: the chance that a harmonic whose noise is its neighbours' keeps its own scatter (`pooled_variance`)
OWN_SCATTER_FALSE_ALARM = 1e-3


def pooled_variance(variance: np.ndarray, n_revs: int, half_window: int = POOL_HALF_WINDOW) -> np.ndarray:
    """The variance of each harmonic 1..H of a synchronous average (`table_harmonics`) pooled with its neighbours'.

    Over ``n_revs`` revolutions a harmonic's scatter has only k = 2 (n_revs - 1) degrees of freedom (4 over three
    revolutions): E[1 / v^] = k / (k - 2) / v, twice the information there is, so a weighting or a test by it
    trusts the harmonics whose scatter happened to be low. The noise's spectrum is smooth in the harmonic, so
    log v^ is fitted by a line over the 2 ``half_window`` + 1 harmonics around each (fewer at the ends), its
    chi-squared bias E[log(chi2_k / k)] = psi(k/2) - log(k/2) removed; a harmonic keeps its own scatter where
    that stands out of the fit's at `OWN_SCATTER_FALSE_ALARM` (ripple whose amplitude varies from revolution to
    revolution). Harmonic 0, and spectra of fewer than three harmonics, keep their own. Along the last axis.
    """
    from scipy.special import gammaincinv  # deferred: scipy.special costs the campaign's import

    variance = np.asarray(variance, float)
    H = variance.shape[-1] - 1
    if H < 3 or n_revs < 2:
        return variance
    k = 2 * (n_revs - 1)
    log_bias = -np.euler_gamma + sum(1.0 / j for j in range(1, k // 2)) - np.log(k / 2)  # psi(k/2) - log(k/2)
    own = variance[..., 1:]
    y = np.log(np.maximum(own, np.finfo(float).tiny))
    x = np.arange(1.0, H + 1)
    lo = np.maximum(np.arange(H) - half_window, 0)
    hi = np.minimum(np.arange(H) + half_window + 1, H)

    def window_sum(values: np.ndarray) -> np.ndarray:
        cumulative = np.concatenate([np.zeros(values.shape[:-1] + (1,)), np.cumsum(values, axis=-1)], axis=-1)
        band: np.ndarray = cumulative[..., hi] - cumulative[..., lo]
        return band

    s0, sx, sxx = (window_sum(np.broadcast_to(x**p, y.shape)) for p in (0, 1, 2))
    sy, sxy = window_sum(y), window_sum(x * y)
    slope = (s0 * sxy - sx * sy) / (s0 * sxx - sx**2)
    fit = np.exp((sy + slope * (s0 * x - sx)) / s0 - log_bias)
    stands_out = own > fit * gammaincinv(k / 2.0, 1.0 - OWN_SCATTER_FALSE_ALARM) / (k / 2.0)
    pooled = variance.copy()
    pooled[..., 1:] = np.where(stands_out | (own == 0.0), own, fit)
    return pooled


def revolution_harmonics(count: np.ndarray, values: np.ndarray, counts_per_rev: int,
                         max_harmonic: int) -> tuple[np.ndarray, np.ndarray]:
    """`table_harmonics` of ``values`` (shape (n,)) over the whole revolutions of ``count``."""
    span = whole_revolution_span(count, counts_per_rev)
    return table_harmonics(revolution_table(count[span], np.asarray(values, float)[span], counts_per_rev),
                           max_harmonic)


def synchronous_table(count: np.ndarray, values: np.ndarray, counts_per_rev: int) -> np.ndarray:
    """Per-count mean of ``values`` (shape (n,) or (n, m)), shape (counts_per_rev, ...).

    The same table as `synchronous_average` for samples that already lie in
    whole revolutions, computed with one ``bincount`` per column (fast for
    many columns), or as the mean of the revolutions (the same sums, in the
    same order) when every count of them is sampled. Counts never sampled are
    filled by periodic linear interpolation. ``count`` must be strictly
    increasing (as in `TrialData`).
    """
    values = np.asarray(values, float)
    if every_count(count, counts_per_rev):
        means: np.ndarray = values.reshape((-1, counts_per_rev) + values.shape[1:]).mean(axis=0)
        return means
    position = count % counts_per_rev
    hits = np.bincount(position, minlength=counts_per_rev)
    columns = values.reshape(values.shape[0], -1)
    seen = hits > 0
    grid = np.arange(counts_per_rev)
    table = np.empty((counts_per_rev, columns.shape[1]))
    for j, column in enumerate(columns.T):
        sums = np.bincount(position, weights=column, minlength=counts_per_rev)
        table[seen, j] = sums[seen] / hits[seen]
        if not seen.all():
            table[~seen, j] = np.interp(grid[~seen], grid[seen], table[seen, j], period=counts_per_rev)
    return table.reshape((counts_per_rev,) + values.shape[1:])


def every_count(count: np.ndarray, counts_per_rev: int) -> bool:
    """Whether strictly increasing ``count`` samples every count of whole revolutions, from a revolution's start."""
    return bool(count[0] % counts_per_rev == 0 and count.size % counts_per_rev == 0
                and count[-1] - count[0] + 1 == count.size)


def periodic_interpolation(table: np.ndarray, position_counts: np.ndarray) -> np.ndarray:
    """A per-count ``table`` (counts_per_rev, ...) at real positions (counts, any revolution): linear between the
    counts, periodic; shape (n, ...)."""
    cpr = table.shape[0]
    base = np.floor(position_counts)
    frac = (position_counts - base).reshape((-1,) + (1,) * (table.ndim - 1))
    k = base.astype(np.int64) % cpr
    interpolated: np.ndarray = (1.0 - frac) * table[k] + frac * table[(k + 1) % cpr]
    return interpolated


def _at_samples(table: np.ndarray, count: np.ndarray, counts_per_rev: int) -> np.ndarray:
    """``table[count % counts_per_rev]`` for a per-count ``table`` (counts_per_rev, m): a copy per revolution
    where `every_count` (far faster than the gather)."""
    if every_count(count, counts_per_rev):
        return np.tile(table, (count.size // counts_per_rev, 1))
    return np.take(table, count % counts_per_rev, axis=0)


def slow_trend(count: np.ndarray, time_s: np.ndarray, values: np.ndarray, counts_per_rev: int,
               degree: int) -> tuple[np.ndarray, float]:
    """The slow aperiodic trend of position-sampled ``values`` and the variance of what is left.

    Models ``values = p(count mod counts_per_rev) + sum_{d=1}^{degree} c_d P_d(u) + noise``
    with p any per-count table, P_d the Legendre polynomials and u the time
    mapped onto [-1, 1]: a sensor's drift (degree 1) and slower settling
    (higher degrees). The coefficients c_d are fitted to the part of the data
    that is not periodic in position (each sample minus its per-count mean),
    so the periodic content cannot bias them. The samples must lie in whole
    revolutions, at least two of them.

    Returns
    -------
    trend : ndarray, shape (n,)
        ``sum_d c_d P_d(u)`` at the samples (subtract it from ``values``).
    noise_variance : float
        Per-sample variance of the rest (neither periodic nor trend).
    """
    counts_seen = counts_per_rev if every_count(count, counts_per_rev) else np.count_nonzero(
        np.bincount(count % counts_per_rev, minlength=counts_per_rev))
    dof = count.size - counts_seen - degree
    if dof <= 0:
        raise ValueError("the slow trend needs more samples than counts per revolution plus its degree")
    u = 2.0 * (time_s - time_s[0]) / (time_s[-1] - time_s[0]) - 1.0
    basis = np.polynomial.legendre.legvander(u, degree)[:, 1:]
    design = np.column_stack([basis, values])
    aperiodic = design - _at_samples(synchronous_table(count, design, counts_per_rev), count, counts_per_rev)
    gram = aperiodic.T @ aperiodic  # normal equations: the Legendre columns are well conditioned
    coef = np.linalg.solve(gram[:-1, :-1], gram[:-1, -1])
    rest = aperiodic[:, -1] - aperiodic[:, :-1] @ coef
    return basis @ coef, float(rest @ rest / dof)


def uniform_time_resample(time_s: np.ndarray, count: np.ndarray, values: np.ndarray, counts_per_rev: int,
                          samples_per_rev: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Re-sample position-sampled data at constant time intervals (report sec. 3.1).

    The position (a function of time) and ``values`` are interpolated with
    cubic splines through the samples' time stamps (`not_a_knot_spline`);
    the uniform grid has ``samples_per_rev`` points per mean revolution
    period, so that a DFT over whole revolutions puts each harmonic of the
    revolution in one bin.

    Returns
    -------
    t_s : ndarray
        The uniform time grid: from the first sample, as many mean revolution
        periods as the samples span (rounded; the last point may lie up to a
        count beyond the last sample).
    angle_rad, speed_rad_s : ndarray
        Mechanical angle and angular velocity (the spline's derivative) there.
    values_uniform : ndarray
        ``values`` interpolated there.
    """
    angle = 2.0 * np.pi * count / counts_per_rev
    revolutions = (count[-1] - count[0]) / counts_per_rev
    period_s = (time_s[-1] - time_s[0]) / revolutions
    n_revs = int(round(revolutions))
    t = time_s[0] + np.arange(n_revs * samples_per_rev) * (period_s / samples_per_rev)
    at, slope = not_a_knot_spline(time_s, np.stack([angle, values], axis=1), t)
    return t, at[:, 0], slope[:, 0], at[:, 1]


def not_a_knot_spline(x: np.ndarray, y: np.ndarray, at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The cubic spline through (x, y) with not-a-knot ends, and its derivative, at ``at``, each (len(at), m).

    scipy.interpolate.CubicSpline's (the same tridiagonal system for the
    slopes at the knots, solved by solve_banded, and the same Hermite
    coefficients; outside [x_0, x_-1] the end pieces go on) without the
    checks and the piecewise-polynomial object that take most of its time on
    long series. ``x`` (n >= 4) strictly increasing, ``y`` of shape (n, m).
    """
    from scipy.linalg import solve_banded  # deferred: scipy only where a spline is drawn

    if x.size < 4:
        from scipy.interpolate import CubicSpline  # 0.05 s to import: for the short series only

        spline = CubicSpline(x, y)
        return spline(at), spline(at, 1)
    dx = np.diff(x)
    column = dx[:, None]
    slope = np.diff(y, axis=0) / column
    bands = np.zeros((3, x.size))
    bands[1, 1:-1] = 2.0 * (dx[:-1] + dx[1:])
    bands[0, 2:] = dx[:-1]
    bands[-1, :-2] = dx[1:]
    rhs = np.empty(y.shape)
    rhs[1:-1] = 3.0 * (column[1:] * slope[:-1] + column[:-1] * slope[1:])
    first, last = x[2] - x[0], x[-1] - x[-3]
    bands[1, 0], bands[0, 1] = dx[1], first
    rhs[0] = ((column[0] + 2.0 * first) * column[1] * slope[0] + column[0] ** 2 * slope[1]) / first
    bands[1, -1], bands[-1, -2] = dx[-2], last
    rhs[-1] = (column[-1] ** 2 * slope[-2] + (2.0 * last + column[-1]) * column[-2] * slope[-1]) / last
    knot_slope = solve_banded((1, 1), bands, rhs, overwrite_ab=True, overwrite_b=True, check_finite=False)
    piece = np.clip(np.searchsorted(x, at, side="right") - 1, 0, x.size - 2)
    # the Hermite coefficients of the pieces evaluated only
    width, secant, linear, right = (np.take(a, piece, axis=0) for a in (column, slope, knot_slope[:-1],
                                                                          knot_slope[1:]))
    t = (linear + right - 2.0 * secant) / width
    cubic, square = t / width, (secant - linear) / width - t
    u = (at - x[piece])[:, None]
    value = ((cubic * u + square) * u + linear) * u + np.take(y, piece, axis=0)
    return value, (3.0 * cubic * u + 2.0 * square) * u + linear
