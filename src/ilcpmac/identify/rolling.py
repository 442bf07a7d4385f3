"""The position-locked torque of a rolling log, on its rows as they are: never worse than the q current averaged by
position (docs/rolling-logs.md).

A drive's log of a rolling motor (rows at a drive's or a host's rate, position and current, no torque sensor)
holds the torque balance at every row (the report's eq. 3.1 with friction):

    J domega/dt = K(theta) . i + tau_pos(theta) - f                                          (1)

K(theta) . i the currents' torque (the back-EMF table times the phase currents; k_q(theta) i_q for a q-axis
log), tau_pos the position-locked torque, f the friction (one value: Coulomb plus viscous at the log's speed).
Two estimates of tau_pos come from it, per harmonic h of the mechanical angle:

    baseline:   tau_B,h = -(k_q . i_q)_h                                                  (2)
    corrected:  tau_F,h = J (domega/dt)_h - (k_q . F^-1[i_q])_h                           (3)

(2) is what a drive's own anticogging computes (moteus's compensate_cogging.py, ODrive's calibration): the q
current averaged by position, here as the least-squares Fourier fit over the rows, weighted by the time each row
stands for (coverage-aware). It is biased by the inertial torque J domega/dt wherever the speed ripples, and by a
report filter F of the logged current (a first-order lag of time constant T: ODrive's
I_measured_report_filter_k). (3) removes both, at the price of the noise and the encoder errors of domega/dt.
They are combined per harmonic by their measured errors (eq. 6): a correction is taken only where it stands
clear of its errors, so that the result is not worse than (2), and says per harmonic which it took (none: the
result is (2), said in a message). A phase-current log's q current is its torque K . i over k_q.

Estimator
---------
A block is one row (where the log's rows times the 2 H + 3 columns stay within `MAX_DESIGN_ENTRIES`; else the
fewest rows that do, and at least about ``1 / (4 H f)`` s, f the mean speed in Hz, H the highest harmonic;
never across a segment's end or a gap in its rows), and (1) over k_q is summed over each block b with the time
weights w_k (half the row intervals each side), in q-axis amperes:

    sum_k w_k i_q,k = F[ J A_b / k_q - sum_h tau_h sum_k w_k e^{j h theta_k} / k_q + f W_b / k_q ]   (4)

A_b = omega(b's end) - omega(b's start), the speed at each block edge the mean position of the m rows after it less
that of the m rows before over their mean times (m half a block; for one-row blocks a secant, A_b the position's
second difference, which any estimate linear in the rows' positions matches in what it tells of harmonic h;
blocks of several rows fold the positions' error above their own rate), k_q the block's mean. (4) is linear in
tau_h, J and f: one weighted least squares over the blocks (weights 1 / W_b). A_b passes harmonic h with the
gain g_h = D_m(h dtheta) sinc(h f m dt) sinc(h f dt) against the row sums (D_m the m-row mean's Dirichlet
kernel, dtheta and dt a row interval's angle and time), divided out of J's part of tau_h (and of A_b's error
beyond the position-locked motion).
F is the drive's filter on every column (block means, first order, exact for a current linear between block
centres), with one column per run for the filter's state at its start; T is stated (rolling.toml) or found:

    y + T' dy/dt = (4)'s right side unfiltered,  T' > 0,  RSS(0) > `FILTER_GAIN` RSS(T'),   (5)
    K_c ln(RSS(0) / RSS(T')) > `FILTER_SIGNIFICANCE`;   then T = argmin RSS_measured(T)

first whether there is a filter, on blocks of about ``1 / (4 H f)`` s (at least `BLOCKS_PER_COLUMN` per
coefficient): the unfiltered fit (J as given, or free) with the current advanced by the inverse filter, T' its
least-squares value (biased low by the current's noise in dy/dt; A_b's noise the same at every T'; K_c the
clusters below, a conservative count of independent residuals); then its time constant in the
measured domain, over a grid of log T refined by a parabola, its residuals summed over runs of `FILTER_GROUP`
blocks first; log T's standard error from the parabola's curvature, through the fit at log T +- it.

Inertia: J given with a relative standard uncertainty u_J ([motor] inertia_uncertainty) enters (4) as a prior
observation J0 +- u_J J0; the data add what their non-periodic motion tells of J (a speed loop's noise, a
stick-slip's jumps). The noise of A_b (the position's quantum q_theta and the stamps' quantum q_t over the
speed, or what the third differences of the position less its smooth part show, the larger: stamps even in
time though the positions were read at a host's jittered instants) biases that part towards zero; its expected
square is taken out of the normal equations, and the data are taken to identify J only where that leaves more
than half of J's information. Without u_J (J unknown), J is the data's where they identify it at 3 standard
errors, else 0 (the baseline's inertial term).

Errors: the cluster-robust ("sandwich") covariance over `CLUSTERS` runs of consecutive blocks, of (2), (3) and
their difference d_h = tau_F,h - tau_B,h: it holds the currents' noise, the timing jitter and what (1) does not
model, as far as they do not repeat with position. What repeats with position is a bias to the measured errors:

    sigma_enc,h = 2 J |a_q,h|                                                                 (7)

(`QUANTISER_BOUND` = 2), a_q,h what a quantiser of the logged position's quantum (a 12-16-bit position read once
per control cycle is a deterministic function of position at a steady speed) makes of A_b's harmonic h on the
log's own motion, at least (h Omega)^2 q / sqrt(3 U) (U distinct readings a revolution: its error spread evenly;
`_quantiser_bias`). The combination, per harmonic, with V_d = var(d_h) + sigma_enc,h^2 + the prior's and the
filter's parts, and V'_d the same with the quantiser's RMS bias sigma_enc,h / 2:

    |d_h|^2 > ln(n / alpha) V'_d:   g_h = 1 - `SHRINK` V'_d / |d_h|^2,  else 0;   tau_h = tau_B,h + g_h d_h   (6)

(n the harmonics of its kind: the orders a motor's torque is expected at, multiples of the cogging order and of
6 x pole pairs, with alpha = `SELECTION_EXPECTED`, the others with `SELECTION`): a correction is taken where its
noise alone would pass at any of them with a chance alpha, shrunk near the threshold, where a correction's bias
beyond its measured error would cost most; nearly the Wiener weight far above it. Its stated variance is
var(tau_B,h + g_h d_h) + g_h^2 (sigma_enc,h^2 + the prior's and the fitted filter's parts) + (1 - g_h)^2 |d_h|^2
(the correction's part left out is the baseline's bias), plus what folds from above the rows' Nyquist order:
for rows sparse enough that H reaches half of it, the top quarter's mean power (`_folded_power`), and the
currents' torque ripple, k_q's orders above it times the mean current, where it folds (`_ripple_folds`).

Harmonics: 1..H with H = min(twice the cogging order, counts_per_rev / 2 - 1, the highest order below
(1 - `NYQUIST_MARGIN`) f_s / (2 f), the rows' Nyquist order at the median row rate f_s); a cogging order up to
twice the cogging order above the Nyquist order folds onto |o - k f_s / f|: the harmonics within one of such a
fold are taken as 0 (not estimated).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from numba import njit

from ilcpmac.bench.rolling import POSITION_DECIMALS, TIME_DECIMALS, Rolling, RollingData, coverage, read_rolling
from ilcpmac.bench.standstill import truth_tables
from ilcpmac.core.errors import IdentificationError
from ilcpmac.core.files import atomic_write
from ilcpmac.core.records import IdentificationResult, MethodEstimates, MotorInfo
from ilcpmac.core.schema import finite_json
from ilcpmac.core.torque_source import TorqueSource
from ilcpmac.model.tables import q_axis
from ilcpmac.signals.harmonics import periodic_interpolation, table_from_amplitudes

__all__ = ["CLUSTERS", "FILTER_SIGNIFICANCE", "RollingEstimate", "estimate_rolling", "identify_rolling",
           "rolling_result"]

#: runs of consecutive blocks the sandwich covariance treats as independent (fewer for a short log: 8 blocks each)
CLUSTERS = 40
#: a block interval longer than this many median row intervals is a gap: no block spans it
GAP_INTERVALS = 10.0
#: a filter time constant is kept when K_c ln(RSS(0) / RSS(T)) passes this: chi^2 with one degree of freedom
#: at 0.1 %
FILTER_SIGNIFICANCE = 10.83
#: filter time constants tried (eq. 5), from twice the block duration to a quarter of the log, at most this long
MAX_FILTER_S = 2.0
FILTER_GRID = 16
#: how many times the inverse filter must lower the residual power for a filter to be found (eq. 5): a drive's
#: report filter of tens of row intervals leaves much of the torque unexplained without it (the ODrive logs: 5.8
#: with anticogging off, 1.9 with it on); an unfiltered log within a few % (the simulated logs: 1.0-1.05)
FILTER_GAIN = 1.5
#: blocks whose residuals the choice of the filter's time constant sums before squaring (eq. 5): A_b's noise, a
#: difference from edge to edge, cancels within them
FILTER_GROUP = 8
#: the smallest torque per ampere of i_q over a revolution, relative to its mean, a back-EMF table may give
MIN_TORQUE_PER_AMPERE = 0.2
#: the least fraction of A_b's information left once its noise is taken out for the data to identify J, and the
#: standard errors a J identified from the data alone needs
J_INFORMATION = 0.5
J_SIGNIFICANCE = 3.0
#: the smallest inertial gain g_h divided out; below it the corrected estimate is not formed (the baseline taken)
MIN_GAIN = 0.2
#: the highest order reported from a cogging order's fold: twice the cogging order
FOLDED_MULTIPLES = 2
#: the orders within this fraction below the rows' Nyquist order are not estimated: the mean speed's own scatter
#: puts them on either side of it
NYQUIST_MARGIN = 0.02
#: the fewest blocks per coefficient of eq. (5)'s test for a filter, on blocks of about 1 / (4 H f) s
BLOCKS_PER_COLUMN = 8
#: the most entries (blocks x columns) of eq. (4)'s design: a block is one row where the log's rows x (2 H + 3)
#: stay within it, else the fewest rows that do
MAX_DESIGN_ENTRIES = 5_000_000
#: the least travel of a rolling log, revolutions
MIN_TRAVEL = 0.05
#: draws of the Monte Carlo of A_b's noise, and phases of the quantiser whose bias eq. (7) averages
NOISE_DRAWS = 8
QUANTISER_PHASES = 8
#: sigma_enc,h (eq. 7) as this many times the quantiser's RMS bias over its phases: on one log, at its one phase
#: and with the motion's fine structure the smooth part leaves out, it was up to twice that (benchmarks/rolling_logs.py)
QUANTISER_BOUND = 2.0
#: the position ripple's harmonics the quantiser's motion keeps: above this many times a quantiser's level
RIPPLE_LEVEL = 3.0
#: the chance that the correction's noise alone passes eq. (6)'s threshold |d_h|^2 > ln(n / alpha) V_d at any of
#: n harmonics (|d_h|^2 / V_d of noise alone is exponential of mean 1): alpha at the orders a motor's torque is
#: expected at (multiples of the cogging order and of 6 x pole pairs), and at the n others
SELECTION_EXPECTED = 1e-2
SELECTION = 1e-3
#: eq. (6)'s weight of a correction that passes, g_h = 1 - SHRINK V_d / |d_h|^2: the Wiener weight's (SHRINK 1)
#: near the threshold, where a bias of the correction's beyond V_d would cost most, shrunk
SHRINK = 2.0
#: g_h below this is "baseline", above 1 - it "corrected", in between "combined"
CHOICE = 0.1


@dataclass(frozen=True)
class RollingEstimate:
    """The rolling identification of one folder (eqs. 2-7), harmonics 1..H (index h - 1).

    Attributes
    ----------
    harmonics_nm, variance_nm2 : ndarray, shapes (H,), complex and real
        tau_h as combined (eq. 6; 0 where not estimated) and E|d tau_h|^2 (where not estimated, what the rows
        hold there: the combined estimate's square and variance), N m (one-sided amplitudes: tau(theta) = Re
        sum_h tau_h e^{j h theta}).
    baseline_nm, baseline_variance_nm2 : ndarray, shape (H,)
        Eq. (2) and its measured variance (its bias not included).
    corrected_nm, correction_variance_nm2 : ndarray, shape (H,)
        Eq. (3), and the variance of d_h = tau_F,h - tau_B,h with the encoder's bias (V_d of eq. 6).
    encoder_bias_nm : ndarray, shape (H,)
        sigma_enc,h (eq. 7).
    weight : ndarray, shape (H,)
        g_h (eq. 6).
    estimated : ndarray of bool, shape (H,)
        Not where a cogging order folds.
    counts_per_rev, cogging_order, nyquist_order : int
    speed_hz : float
        The mean speed, Hz (signed).
    row_rate_hz : float
        The median row rate.
    torque_constant_nm_per_a : float
        K_t, the mean of k_q over a revolution (the q-axis log's torque per ampere).
    inertia_kgm2, inertia_std_kgm2 : float
        J as used (0: the data do not identify it and none is given) and its standard error.
    inertia_source : str
        "given", "given and data", "data" or "none".
    filter_s : float
        T as used (0: none), ``filter_source`` "stated", "fitted" or "none".
    friction_nm : float
        f of eq. (1).
    position_quantum_rad : float
        q_theta, the logged position's quantum (0: real-valued), rad.
    folded_nm2 : float
        What content above the rows' Nyquist order folds onto each harmonic (in ``variance_nm2``), N^2 m^2.
    samples, blocks, segments : int
    revolutions : float
    coverage : str
        What the rows cover of a revolution.
    messages : tuple of str
    """

    harmonics_nm: np.ndarray
    variance_nm2: np.ndarray
    baseline_nm: np.ndarray
    baseline_variance_nm2: np.ndarray
    corrected_nm: np.ndarray
    correction_variance_nm2: np.ndarray
    encoder_bias_nm: np.ndarray
    weight: np.ndarray
    estimated: np.ndarray
    counts_per_rev: int
    cogging_order: int
    nyquist_order: int
    speed_hz: float
    row_rate_hz: float
    torque_constant_nm_per_a: float
    inertia_kgm2: float
    inertia_std_kgm2: float
    inertia_source: str
    filter_s: float
    filter_source: str
    friction_nm: float
    position_quantum_rad: float
    folded_nm2: float
    samples: int
    blocks: int
    segments: int
    revolutions: float
    coverage: str
    messages: tuple[str, ...]

    @property
    def orders(self) -> np.ndarray:
        """h = 1..H."""
        return np.arange(1, self.harmonics_nm.size + 1)

    @property
    def cogging_band(self) -> np.ndarray:
        """Whether each harmonic is a multiple of the cogging order."""
        return self.orders % self.cogging_order == 0

    def table_nm(self, harmonics: np.ndarray | None = None, cogging_only: bool = False) -> np.ndarray:
        """A per-count table of ``harmonics`` (default: the combined ones), the estimated harmonics (the cogging
        band only: ``cogging_only``), N m."""
        values = self.harmonics_nm if harmonics is None else harmonics
        keep = self.estimated & (self.cogging_band if cogging_only else True)
        return table_from_amplitudes(np.concatenate([[0.0], np.where(keep, values, 0.0)]), self.counts_per_rev)

    def table_std_nm(self, cogging_only: bool = False) -> np.ndarray:
        """The standard error of `table_nm` per count: sqrt(sum_h E|d tau_h|^2 / 2) (the harmonics left out with
        theirs), N m."""
        keep = self.cogging_band if cogging_only else np.ones(self.harmonics_nm.size, bool)
        return np.full(self.counts_per_rev, math.sqrt(float(np.sum(self.variance_nm2[keep])) / 2.0))

    def choices(self) -> list[str]:
        """Per harmonic what eq. (6) took: "baseline", "combined", "corrected", or "aliased"."""
        return ["aliased" if not ok else "baseline" if g < CHOICE else "corrected" if g > 1 - CHOICE else "combined"
                for ok, g in zip(self.estimated, self.weight)]

    def to_json(self) -> dict:
        """JSON-able summary: the fit's figures and, per harmonic, the three estimates, their errors and choice."""
        k_t = self.torque_constant_nm_per_a
        return finite_json({
            "speed_hz": self.speed_hz, "row_rate_hz": self.row_rate_hz, "nyquist_order": self.nyquist_order,
            "samples": self.samples, "blocks": self.blocks, "segments": self.segments,
            "revolutions": self.revolutions, "coverage": self.coverage,
            "torque_constant_nm_per_a": k_t, "inertia_kgm2": self.inertia_kgm2,
            "inertia_std_kgm2": self.inertia_std_kgm2, "inertia": self.inertia_source,
            "current_filter_s": self.filter_s, "current_filter": self.filter_source,
            "friction_nm": self.friction_nm, "position_quantum_rad": self.position_quantum_rad,
            "folded_std_nm": math.sqrt(self.folded_nm2),
            "harmonics": [{"order": int(h), "re": float(x.real), "im": float(x.imag), "std": float(math.sqrt(v)),
                           "baseline_re": float(b.real), "baseline_im": float(b.imag),
                           "baseline_std": float(math.sqrt(vb)), "corrected_re": float(c.real),
                           "corrected_im": float(c.imag), "correction_std": float(math.sqrt(vd)),
                           "encoder_bias": float(e), "weight": float(g), "choice": choice,
                           "amplitude_a": float(abs(x) / k_t)}
                          for h, x, v, b, vb, c, vd, e, g, choice in zip(
                              self.orders, self.harmonics_nm, self.variance_nm2, self.baseline_nm,
                              self.baseline_variance_nm2, self.corrected_nm, self.correction_variance_nm2,
                              self.encoder_bias_nm, self.weight, self.choices())]})


# ---------------------------------------------------------------- the rows and their blocks


@dataclass(frozen=True)
class _Blocks:
    """Eq. (4)'s sums per block, rows (n_b, ...) in time order.

    ``current`` sum w i_q; ``rate`` sum w di_q/dt; ``inverse_gain`` the mean of 1 / k_q; ``angle`` sum w theta;
    ``fourier`` [W, sum w cos h theta, sum w sin h theta, ...] (n_b, 1 + 2H); ``inertial`` A_b; ``width`` W_b;
    ``centre_s`` the weighted mean time; ``run`` the run (between gaps or segment ends) of each block; ``edges``
    the rows (global) of the windows at each block's start and end edge, (n_b, 4): start from, start to, end from,
    end to, ``window_rows`` (m) of them each side of the edge; ``gain`` g_h, shape (H,).
    """

    current: np.ndarray
    rate: np.ndarray
    inverse_gain: np.ndarray
    fourier: np.ndarray
    inertial: np.ndarray
    angle: np.ndarray
    width: np.ndarray
    centre_s: np.ndarray
    run: np.ndarray
    edges: np.ndarray
    gain: np.ndarray
    window_rows: int

    def inertial_of(self, time_s: np.ndarray, signal: np.ndarray) -> np.ndarray:
        """A_b of a per-row ``signal`` (an angle, rad) as of the position: the edges' speeds' difference per block."""
        speeds = _edge_speeds(time_s, signal, self.edges, self.window_rows)
        return speeds[:, 1] - speeds[:, 0]


def _edge_speeds(time_s: np.ndarray, signal: np.ndarray, edges: np.ndarray, m: int) -> np.ndarray:
    """The speed at each block's start and end edge (n_b, 2): the mean of ``signal``'s m rows after the edge less
    the mean of its m rows before, over the same of the times (a secant of the rows either side for m = 1; for
    more, every row of the window counts, so that the blocks do not fold a position's error between them)."""
    if m == 1:
        return (signal[edges[:, [1, 3]]] - signal[edges[:, [0, 2]]]) / (time_s[edges[:, [1, 3]]]
                                                                          - time_s[edges[:, [0, 2]]])
    means = np.lib.stride_tricks.sliding_window_view(signal, m).mean(axis=1)
    times = np.lib.stride_tricks.sliding_window_view(time_s, m).mean(axis=1)
    left = edges[:, [0, 2]]
    return (means[left + m] - means[left]) / (times[left + m] - times[left])


def _current_rows(rolling: Rolling) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per row the q-axis current, A (i_q, or the phase currents' torque K(theta) . i over k_q(theta)), its rate of
    change, A / s (central differences within each segment), and 1 / k_q(theta), A / (N m): the torque per ampere
    of i_q, sum_p K_p sin(theta_e - 2 pi p / 3), from the back-EMF table.

    Raises
    ------
    IdentificationError
        Where k_q falls below `MIN_TORQUE_PER_AMPERE` of its mean (a back-EMF table at odds with i_q's axis).
    """
    d, motor = rolling.data, rolling.motor
    k = periodic_interpolation(rolling.backemf_nm_per_a, d.position_counts)
    theta_e = motor.pole_pairs * 2.0 * np.pi * d.position_counts / motor.counts_per_rev
    k_q = np.sum(k * q_axis(theta_e + rolling.settings.angle_offset_rad), axis=1)
    table = k_q_table(rolling)
    if table.min() < MIN_TORQUE_PER_AMPERE * table.mean():
        worst = int(np.argmin(table))
        raise IdentificationError(f"rolling log: the back-EMF's torque per ampere of i_q is {table[worst]:.3g} N m / A "
                                  f"at count {worst}, below {MIN_TORQUE_PER_AMPERE:g} of its mean {table.mean():.3g} "
                                  "(a back-EMF table or angle_offset_rad at odds with the currents' axis?)")
    current = d.i_q_a if d.i_q_a is not None else np.sum(k * np.asarray(d.currents_a), axis=1) / k_q
    assert current is not None
    slope = np.zeros_like(current)
    for rows in d.segments:
        t, i = d.time_s[rows], current[rows]
        slope[rows.start + 1:rows.stop - 1] = (i[2:] - i[:-2]) / (t[2:] - t[:-2])
    return current, slope, 1.0 / k_q


def _runs(data: RollingData) -> list[slice]:
    """The runs of rows without a gap (an interval longer than `GAP_INTERVALS` median ones) within each
    segment."""
    runs = []
    for rows in data.segments:
        interval = np.diff(data.time_s[rows])
        cut = np.flatnonzero(interval > GAP_INTERVALS * np.median(interval)) + 1 + rows.start
        bounds = np.concatenate([[rows.start], cut, [rows.stop]])
        runs += [slice(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:])]
    return runs


def _window_rows(block_rows: int) -> int:
    """m, the rows each side of a block's edge whose means make the speed there (`_edge_speeds`)."""
    return max(1, block_rows // 2)


def _blocks(data: RollingData, theta: np.ndarray, rows_: tuple[np.ndarray, np.ndarray, np.ndarray], top: int,
            block_rows: int) -> tuple[_Blocks, list[int]]:
    """The blocks of eq. (4), ``block_rows`` rows each, over every run long enough to hold one with its edge
    windows, and the runs' sizes in blocks. ``theta`` the rows' angle, rad; ``rows_`` `_current_rows`'."""
    parts: list[dict] = []
    sizes = []
    for run_index, rows in enumerate(_runs(data)):
        t, th = data.time_s[rows], theta[rows]
        n = t.size
        dt = np.diff(t)
        m = _window_rows(block_rows)
        if n < 2 * m + 4:
            continue
        w = np.zeros(n)
        w[:-1] += dt / 2.0
        w[1:] += dt / 2.0
        inner = np.arange(m, n - m)  # rows whose block edges have their windows inside the run
        block = np.arange(inner.size) // block_rows
        count = int(block[-1]) + 1
        first = np.searchsorted(block, np.arange(count))
        last = np.append(first[1:], inner.size) - 1
        starts, ends = inner[first] - 1, inner[last]  # each edge lies between rows k and k + 1
        edges = np.column_stack([starts - m + 1, starts + m, ends - m + 1, ends + m])
        weights = w[inner]
        z = np.exp(1j * th[inner])
        power = np.ones_like(z)
        sums = np.empty((count, 1 + 2 * top), float)
        sums[:, 0] = np.bincount(block, weights=weights, minlength=count)
        for h in range(top):
            power *= z
            sums[:, 1 + 2 * h] = np.bincount(block, weights=weights * power.real, minlength=count)
            sums[:, 2 + 2 * h] = np.bincount(block, weights=weights * power.imag, minlength=count)
        orders = np.arange(1, top + 1)[None, :]
        row = (th[np.column_stack([starts, ends]) + 1] - th[np.column_stack([starts, ends])]).reshape(-1, 1)
        half = orders * row / 2.0  # the edge's speed: an m-row mean's Dirichlet kernel, the means m rows apart
        apart = np.abs(np.sin(half)) > 1e-12
        dirichlet = np.where(apart, np.sin(m * half) / np.where(apart, m * np.sin(half), 1.0), 1.0)
        gain = np.mean(dirichlet * np.sinc(orders * m * row / (2 * np.pi)) * np.sinc(orders * row / (2 * np.pi)),
                       axis=0)
        speeds = _edge_speeds(t, th, edges, m)
        parts.append({"current": np.bincount(block, weights=weights * rows_[0][rows][inner], minlength=count),
                      "rate": np.bincount(block, weights=weights * rows_[1][rows][inner], minlength=count),
                      "inverse_gain": np.bincount(block, weights=weights * rows_[2][rows][inner], minlength=count)
                      / sums[:, 0],
                      "fourier": sums, "inertial": speeds[:, 1] - speeds[:, 0], "width": sums[:, 0],
                      "angle": np.bincount(block, weights=weights * th[inner], minlength=count),
                      "centre_s": np.bincount(block, weights=weights * t[inner], minlength=count) / sums[:, 0],
                      "run": np.full(count, run_index), "edges": edges + rows.start, "gain": gain * count})
        sizes.append(count)
    if not parts:
        raise IdentificationError("rolling log: no run of rows long enough for one block of the fit (too few rows "
                                  "between gaps)")
    joined = {key: np.concatenate([p[key] for p in parts]) for key in parts[0] if key != "gain"}
    gain = np.sum([p["gain"] for p in parts], axis=0) / sum(sizes)
    return _Blocks(**joined, gain=gain, window_rows=_window_rows(block_rows)), sizes


@njit(cache=True)
def _lag(centre_s, columns, run, tau_s):
    """A first-order lag of time constant ``tau_s`` along axis 0 of ``columns`` (block means at times
    ``centre_s``, linear in between: the exact response y_k = a y_k-1 + x_k - a x_k-1 - s tau (1 - a), s the
    slope), restarted at each new ``run`` from the run's first value."""
    out = np.empty_like(columns)
    for k in range(columns.shape[0]):
        if k == 0 or run[k] != run[k - 1]:
            out[k] = columns[k]
            continue
        step = centre_s[k] - centre_s[k - 1]
        a = math.exp(-step / tau_s)
        slope = (columns[k] - columns[k - 1]) / step
        out[k] = a * out[k - 1] + columns[k] - a * columns[k - 1] - slope * tau_s * (1.0 - a)
    return out


def _filtered(blocks: _Blocks, columns: np.ndarray, tau_s: float) -> np.ndarray:
    """Block-sum ``columns`` (n_b, m) as the drive's filter of time constant ``tau_s`` passes them, with one
    column per run for the filter's state at the run's start (its decay); as they are for ``tau_s`` = 0."""
    if tau_s <= 0.0:
        return columns
    width = blocks.width[:, None]
    lagged = _lag(blocks.centre_s, np.ascontiguousarray(columns / width), blocks.run, tau_s) * width
    runs = np.unique(blocks.run)
    start = {r: blocks.centre_s[np.argmax(blocks.run == r)] for r in runs}
    decay = np.column_stack([np.where(blocks.run == r, np.exp(-(blocks.centre_s - start[r]) / tau_s), 0.0)
                             for r in runs]) * width
    return np.hstack([lagged, decay])


# ---------------------------------------------------------------- the least squares


@dataclass(frozen=True)
class _Fit:
    """One weighted least squares of eq. (4): coefficients, their inverse normal matrix and the residuals
    (weighted), the design (weighted), and the cluster of each block."""

    beta: np.ndarray
    inverse: np.ndarray
    design: np.ndarray
    residual: np.ndarray
    prior_information: float

    def scores(self, cluster: np.ndarray, clusters: int) -> np.ndarray:
        """Per cluster, the influence of its blocks on the coefficients, shape (clusters, p)."""
        per = np.zeros((clusters, self.design.shape[1]))
        np.add.at(per, cluster, self.design * self.residual[:, None])
        return per @ self.inverse

    @property
    def rss(self) -> float:
        return float(self.residual @ self.residual)


def _solve(design: np.ndarray, target: np.ndarray, weight: np.ndarray, inertial: int | None = None,
           noise: float = 0.0, prior: tuple[float, float] | None = None) -> _Fit:
    """The weighted least squares of ``target`` on ``design`` (weights ``weight``); column ``inertial`` (J's) with
    the expected square of its noise ``noise`` taken out of the normal equations and the ``prior`` (J0, its
    standard deviation) added as an observation."""
    root = np.sqrt(weight)[:, None]
    x, y = design * root, target * root[:, 0]
    normal = x.T @ x
    right = x.T @ y
    information = 0.0
    if inertial is not None:
        normal[inertial, inertial] -= noise
        if prior is not None and prior[1] > 0:
            information = 1.0 / prior[1] ** 2
            normal[inertial, inertial] += information
            right[inertial] += prior[0] * information
    ridge = 1e-12 * float(np.trace(normal)) / normal.shape[0]
    inverse = np.linalg.pinv(normal + ridge * np.eye(normal.shape[0]), hermitian=True)
    beta = inverse @ right
    return _Fit(beta, inverse, x, y - x @ beta, information)


def _harmonics(vector: np.ndarray, top: int) -> np.ndarray:
    """tau_h = -(a_h - j b_h) of the Fourier coefficients at columns 1..2H of ``vector`` (eq. 4's sign)."""
    return -(vector[1:2 * top + 1:2] - 1j * vector[2:2 * top + 1:2])


def _variance(influence: np.ndarray, top: int, clusters: int) -> np.ndarray:
    """E|d tau_h|^2 from per-cluster influences on the coefficients, (clusters, p)."""
    scale = clusters / max(clusters - 1, 1)
    re, im = influence[:, 1:2 * top + 1:2], influence[:, 2:2 * top + 1:2]
    return scale * (np.sum(re**2, axis=0) + np.sum(im**2, axis=0))


def _quantum(steps: np.ndarray, resolution: float) -> float:
    """The smallest |change| between successive ``steps`` above 1e-6 of the largest |step| and 4 ``resolution``
    (the values' own rounding: rolling.csv's decimals, a change of steps holding three of them), or 0: a quantised
    position or clock makes every change a multiple of its quantum."""
    changes = np.abs(np.diff(steps))
    scale = float(np.abs(steps).max()) if steps.size else 0.0
    changes = changes[changes > max(1e-6 * scale, 4.0 * resolution)]
    return float(changes.min()) if changes.size else 0.0


def _position_noise_rad2(data: RollingData, quantum_rad: float, speed_rad_s: float, motion: _Motion) -> float:
    """The variance of one row's position error, rad^2: the larger of the quanta's (q_theta^2 + (Omega q_t)^2) / 12
    and the robust estimate from the third differences of the position less its smooth part (white noise:
    E d3^2 = 20 sigma^2), which holds what the quanta do not show: stamps even in time but not the instants the
    positions were read at (a host's jitter), a position estimator's own noise."""
    q_t = _quantum(np.concatenate([np.diff(data.time_s[rows]) for rows in data.segments]), 10.0**-TIME_DECIMALS)
    third = np.concatenate([np.diff(motion.residual[motion.run == r], 3) for r in np.unique(motion.run)])
    robust = float(np.median(third**2)) / 0.4549 / 20.0 if third.size else 0.0
    return max((quantum_rad**2 + (speed_rad_s * q_t) ** 2) / 12.0, robust)


def _edge_noise(grid: _Grid, time_s: np.ndarray, position_std_rad: float, tau_s: float) -> float:
    """E sum_b (noise of J's column, as the design has it)^2 / W_b: Monte Carlo over `NOISE_DRAWS` draws of
    independent errors of the rows' positions of standard deviation ``position_std_rad`` through A_b (seeded)."""
    if position_std_rad <= 0.0:
        return 0.0
    rng = np.random.default_rng(0)
    total = 0.0
    for _ in range(NOISE_DRAWS):
        noise = grid.blocks.inertial_of(time_s, rng.standard_normal(time_s.size) * position_std_rad)
        total += float(np.sum(grid.filtered(noise[:, None], tau_s)[:, 0] ** 2 / grid.blocks.width))
    return total / NOISE_DRAWS


def _projector(design: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """M with the weighted least-squares coefficients of any target y on ``design`` = M y."""
    root = np.sqrt(weight)[:, None]
    x = design * root
    normal = x.T @ x
    ridge = 1e-12 * float(np.trace(normal)) / normal.shape[0]
    return np.linalg.pinv(normal + ridge * np.eye(normal.shape[0]), hermitian=True) @ (x * root).T


def _cluster_scores(projector: np.ndarray, residual: np.ndarray, cluster: np.ndarray, clusters: int) -> np.ndarray:
    """Per cluster, what its blocks' ``residual`` (unweighted) adds to the coefficients ``projector`` (`_projector`)
    makes of it, shape (clusters, p)."""
    per = np.zeros((clusters, projector.shape[0]))
    np.add.at(per, cluster, (projector * residual).T)
    return per


@dataclass(frozen=True)
class _Motion:
    """The logged position's smooth part at the rows the blocks' edge windows span (``rows``, their runs ``run``):
    ``smooth`` and ``residual`` (the position less it), rad."""

    rows: np.ndarray
    run: np.ndarray
    smooth: np.ndarray
    residual: np.ndarray


def _smooth_motion(time_s: np.ndarray, theta: np.ndarray, quantum_rad: float, grid: _Grid, top: int) -> _Motion:
    """The logged position's smooth part: per run a quadratic in time and the position-locked ripple, harmonics
    1..H fitted over the blocks, those of them within `RIPPLE_LEVEL` times the level q / sqrt(3 R) a quantiser's
    error spreads over the R / 2 orders of R rows per revolution left out (they hold that error)."""
    blocks = grid.blocks
    runs = np.unique(blocks.run)
    start = {r: blocks.centre_s[np.argmax(blocks.run == r)] for r in runs}
    drift = [np.where(blocks.run == r, (blocks.centre_s - start[r]) ** power, 0.0)[:, None] * blocks.width[:, None]
             for r in runs for power in (0, 1, 2)]
    angle = np.column_stack([blocks.fourier[:, 1:], *drift])
    coefficients = _projector(angle, 1.0 / blocks.width) @ blocks.angle
    row_run = np.full(time_s.size, -1)
    for r in runs:  # the rows of a run's edge windows, first to last
        mine = blocks.edges[blocks.run == r]
        row_run[mine.min():mine.max() + 1] = r
    rows = np.flatnonzero(row_run >= 0)
    harmonic = coefficients[:2 * top:2] - 1j * coefficients[1:2 * top:2]
    rows_per_rev = rows.size / max(float(np.ptp(theta[rows])) / (2 * np.pi), 1.0)
    level = RIPPLE_LEVEL * quantum_rad / math.sqrt(3.0 * rows_per_rev)
    harmonic[np.abs(harmonic) < level] = 0.0
    harmonic[_sawtooth_orders(2 * np.pi / quantum_rad, rows_per_rev, level / quantum_rad, top) - 1] = 0.0
    smooth = np.real(np.exp(1j * np.outer(theta[rows], np.arange(1, top + 1))) @ harmonic)
    for k, r in enumerate(runs):
        mine = row_run[rows] == r
        smooth[mine] += sum(coefficients[2 * top + 3 * k + power] * (time_s[rows[mine]] - start[r]) ** power
                            for power in range(3))
    return _Motion(rows, row_run[rows], smooth, theta[rows] - smooth)


def _sawtooth_orders(lines_per_rev: float, rows_per_rev: float, level: float, top: int) -> np.ndarray:
    """The orders 1..top within one of where a quantiser's error of a steady motion lies: L lines and R rows per
    revolution make it a sawtooth of L / R lines per row, its harmonic k (amplitude q / (pi k), above ``level``
    quanta) at k L mod R, folded into [0, R / 2]."""
    orders = []
    for k in range(1, max(1, int(1.0 / (np.pi * level))) + 1):
        alias = abs(k * lines_per_rev - round(k * lines_per_rev / rows_per_rev) * rows_per_rev)
        orders += [o for o in (math.floor(alias), math.ceil(alias)) if 1 <= o <= top]
    return np.unique(np.array(orders, dtype=np.int64))


def _quantiser_bias(time_s: np.ndarray, motion: _Motion, quantum_rad: float, speed_rad_s: float, grid: _Grid,
                    projector: np.ndarray, tau_s: float, top: int) -> np.ndarray:
    """|a_h| of eq. (7) per harmonic, rad/s^2 (J times it is sigma_enc,h): what a quantiser of ``quantum_rad`` makes
    of A_b's harmonics on this log's own motion (`_smooth_motion`), RMS over `QUANTISER_PHASES` phases of the
    quantiser: the quantiser's error at the rows (q round((theta + u) / q) - theta - u, u the phase) passed through
    A_b, the drive's filter and the fit as the position is, g_h divided out; at least what an error of variance
    q^2 / 12 spread evenly over the U distinct readings of a revolution makes of harmonic h, (h Omega)^2 q /
    sqrt(3 U) (a motion whose ripple, below the quanta, the smooth part leaves out scatters the quantiser's lines
    over the orders: the servo's 12-bit log at 6 Hz, benchmarks/rolling_logs.py)."""
    blocks = grid.blocks
    bias = np.zeros(top)
    for phase in (np.arange(QUANTISER_PHASES) + 0.5) / QUANTISER_PHASES:
        shifted = motion.smooth + phase * quantum_rad
        error = np.zeros(time_s.size)
        error[motion.rows] = quantum_rad * np.round(shifted / quantum_rad) - shifted
        inertial = blocks.inertial_of(time_s, error)
        inertial = grid.filtered(inertial[:, None], tau_s)[:, 0]
        bias += np.abs(_harmonics(projector @ inertial, top)) ** 2
    readings = np.unique(np.round(np.mod(motion.smooth + motion.residual, 2 * np.pi) / quantum_rad)).size
    spread = (np.arange(1, top + 1) * speed_rad_s) ** 2 * quantum_rad / math.sqrt(3.0 * readings)
    return np.maximum(np.sqrt(bias / QUANTISER_PHASES) / np.maximum(blocks.gain, MIN_GAIN), spread)


def _folded_power(harmonics: np.ndarray, estimated: np.ndarray, cogging_order: int, nyquist: int) -> float:
    """E|d tau_h|^2 that the content above the rows' Nyquist order folds onto every harmonic, N^2 m^2: where the
    harmonics reach half the Nyquist order or more, the mean |tau_h|^2 over their top quarter, the cogging
    orders left out (near the Nyquist order a motor's own position torque is small beside what folds onto it:
    the currents' and the acceleration's content above it, spread over the orders by the speed's own ripple);
    0 for rows fast enough."""
    top = harmonics.size
    if top < nyquist // 2:
        return 0.0
    orders = np.arange(1, top + 1)
    band = (orders >= math.ceil(0.75 * top)) & estimated & (orders % cogging_order != 0)
    return float(np.mean(np.abs(harmonics[band]) ** 2)) if band.any() else 0.0


def _expected_orders(motor: MotorInfo, top: int) -> np.ndarray:
    """Whether each harmonic 1..top is one a motor's position torque and its currents' torque ripple are expected
    at: a multiple of the cogging order or of 6 x pole pairs."""
    orders = np.arange(1, top + 1)
    return (orders % motor.cogging_order == 0) | (orders % (6 * motor.pole_pairs) == 0)


def _ripple_folds(k_q: np.ndarray, current_a: float, rows_per_rev: float, top: int) -> np.ndarray:
    """E|d tau_h|^2 per harmonic 1..top that the currents' torque ripple above the rows' Nyquist order folds onto,
    N^2 m^2: k_q's order o (a back-EMF's harmonics 5 and 7 make 6 x pole pairs) times the mean current, at
    |o - k R| (R rows per revolution; both orders either side where it is not whole). Neither estimate removes
    it: the current does not carry a ripple above the speed loop's bandwidth, the rotor's acceleration does, and
    sampled below its Nyquist order the acceleration reads as that of the order it folds onto."""
    amplitude = 2.0 * np.abs(np.fft.rfft(k_q))[1:] / k_q.size * abs(current_a)
    power = np.zeros(top)
    for order in np.flatnonzero(np.arange(1, amplitude.size + 1) >= rows_per_rev / 2.0) + 1:
        alias = abs(order - round(order / rows_per_rev) * rows_per_rev)
        for h in {math.floor(alias), math.ceil(alias)}:
            if 1 <= h <= top:
                power[h - 1] += amplitude[order - 1] ** 2
    return power


def _nyquist_folds(cogging_order: int, rows_per_rev: float, top: int) -> tuple[np.ndarray, dict[int, int]]:
    """Harmonics 1..top within one of where a cogging order up to `FOLDED_MULTIPLES` times the cogging order, at or
    above the rows' Nyquist order, folds; and the folds (order -> harmonic)."""
    aliased = np.zeros(top, bool)
    folds = {}
    for order in range(cogging_order, FOLDED_MULTIPLES * cogging_order + 1, cogging_order):
        if order < rows_per_rev / 2.0:
            continue
        alias = int(round(abs(order - round(order / rows_per_rev) * rows_per_rev)))
        folds[order] = alias
        aliased[max(alias - 2, 0):alias + 1] = True
    return aliased, folds


@dataclass(frozen=True)
class _Grid:
    """The blocks of one size (``block_rows`` rows, ``block_s`` their mean duration) and what the fits on them
    share: the weights 1 / W_b, the clusters of the sandwich covariance, J's prior, and the design of eq. (4) at a
    filter time constant."""

    blocks: _Blocks
    sizes: list[int]
    block_rows: int
    block_s: float
    weight: np.ndarray
    cluster: np.ndarray
    clusters: int
    prior: tuple[float, float] | None

    @classmethod
    def of(cls, data: RollingData, theta: np.ndarray, rows: tuple[np.ndarray, np.ndarray, np.ndarray], top: int,
           block_rows: int, prior: tuple[float, float] | None) -> _Grid:
        blocks, sizes = _blocks(data, theta, rows, top, block_rows)
        n_b = blocks.width.size
        if n_b < 2 * (2 * top + 4):
            raise IdentificationError(f"rolling log: {n_b} blocks of {block_rows} row(s) for {2 * top + 1} "
                                      f"Fourier coefficients (harmonics 1..{top}): too few rows")
        clusters = max(2, min(CLUSTERS, n_b // 8))
        return cls(blocks, sizes, block_rows, float(np.sum(blocks.width)) / n_b, 1.0 / blocks.width,
                   np.minimum(np.arange(n_b) * clusters // n_b, clusters - 1), clusters, prior)

    @property
    def inertial_column(self) -> int:
        return self.blocks.fourier.shape[1]

    def design(self, tau_s: float) -> np.ndarray:
        """[Fourier sums, A_b] over k_q, in q-axis amperes per N m (and the filter's start columns), as the filter of
        ``tau_s`` passes them."""
        return self.filtered(np.column_stack([self.blocks.fourier, self.blocks.inertial]), tau_s)

    def filtered(self, columns: np.ndarray, tau_s: float) -> np.ndarray:
        """Block columns in N m over k_q (q-axis amperes) as the filter of ``tau_s`` passes them."""
        return _filtered(self.blocks, columns * self.blocks.inverse_gain[:, None], tau_s)

    def fit_at(self, tau_s: float) -> _Fit:
        """The fit at filter ``tau_s`` with J as given, or (none given) free."""
        x = self.design(tau_s)
        if self.prior is None:
            return _solve(x, self.blocks.current, self.weight)
        j = self.inertial_column
        return _solve(np.delete(x, j, axis=1), self.blocks.current - self.prior[0] * x[:, j], self.weight)


def estimate_rolling(rolling: Rolling, max_harmonic: int | None = None) -> RollingEstimate:
    """Eqs. (2)-(7) on a rolling folder's rows.

    ``max_harmonic``: H at most (default: twice the cogging order), within the counts' and the rows' Nyquist
    orders.

    Raises
    ------
    IdentificationError
        A log that does not move (no mean speed), too few rows for a block or a fit.
    """
    d, motor = rolling.data, rolling.motor
    cpr = motor.counts_per_rev
    duration = float(sum(d.time_s[r.stop - 1] - d.time_s[r.start] for r in d.segments))
    travel = float(sum(d.position_counts[r.stop - 1] - d.position_counts[r.start] for r in d.segments)) / cpr
    if abs(travel) < MIN_TRAVEL:
        raise IdentificationError(f"rolling log: the position moves {travel:.3g} revolutions in {duration:.3g} s: a "
                                  f"rolling identification needs a mean speed ({MIN_TRAVEL:g} revolutions or more)")
    speed_hz = travel / duration
    omega = 2.0 * np.pi * speed_hz
    row_rate_hz = 1.0 / float(np.median(np.concatenate([np.diff(d.time_s[r]) for r in d.segments])))
    rows_per_rev = row_rate_hz / abs(speed_hz)
    nyquist = int(math.ceil(rows_per_rev / 2.0 * (1.0 - NYQUIST_MARGIN))) - 1
    wanted = FOLDED_MULTIPLES * motor.cogging_order if max_harmonic is None else max_harmonic
    top = max(1, min(wanted, cpr // 2 - 1, nyquist))
    block_rows = 1
    if d.time_s.size * (2 * top + 3) > MAX_DESIGN_ENTRIES:
        block_rows = max(math.ceil(d.time_s.size * (2 * top + 3) / MAX_DESIGN_ENTRIES),
                         round(rows_per_rev / (4.0 * top)))
    theta = 2.0 * np.pi * d.position_counts / cpr
    rows = _current_rows(rolling)
    inertial_column = 2 * top + 1
    given = motor.inertia_uncertainty
    prior = None if given is None else (motor.inertia_kgm2, given * motor.inertia_kgm2)
    grid = _Grid.of(d, theta, rows, top, block_rows, prior)
    # eq. (5), the current's filter
    stated = rolling.settings.current_filter_s
    tau_log_std = 0.0
    if stated is not None:
        tau_s, tau_source = stated, "stated" if stated > 0 else "none"
    else:
        coarse_rows = max(block_rows, min(round(rows_per_rev / (4.0 * top)),
                                          d.time_s.size // (BLOCKS_PER_COLUMN * (2 * top + 2))))
        coarse = grid if coarse_rows == block_rows else _Grid.of(d, theta, rows, top, coarse_rows, prior)
        tau_s, tau_source, tau_log_std = _fitted_filter(grid, coarse, duration)
    blocks, weight, cluster, clusters = grid.blocks, grid.weight, grid.cluster, grid.clusters
    messages: list[str] = []
    # eq. (2), the baseline
    baseline_fit = _solve(grid.filtered(blocks.fourier, 0.0), blocks.current, weight)
    baseline = _harmonics(baseline_fit.beta, top)
    baseline_influence = baseline_fit.scores(cluster, clusters)
    design = grid.design
    # J: what the data tell beyond A_b's noise (eq. 7's quanta), and the prior
    quantum = _quantum(np.concatenate([np.diff(theta[r]) for r in d.segments]),
                       2.0 * np.pi * 10.0**-POSITION_DECIMALS / cpr)
    motion = _smooth_motion(d.time_s, theta, quantum, grid, top)
    position_std = math.sqrt(_position_noise_rad2(d, quantum, omega, motion))
    x = design(tau_s)
    without = np.delete(x, inertial_column, axis=1)
    projector = _projector(without, weight)
    projection = projector @ x[:, inertial_column]
    a_h = -_harmonics(projection, top)
    noise = _edge_noise(grid, d.time_s, position_std, tau_s)
    plain = _solve(x, blocks.current, weight)
    identifies = noise < (1.0 - J_INFORMATION) / plain.inverse[inertial_column, inertial_column]
    prior_part = np.zeros(2 * top + 1)
    inertia, inertia_var, source = 0.0, 0.0, "none"
    fit = _solve(without, blocks.current, weight)
    if identifies:
        free = _solve(x, blocks.current, weight, inertial_column, noise, prior)
        j = float(free.beta[inertial_column])
        j_var = (_scalar_variance(free.scores(cluster, clusters)[:, inertial_column], clusters)
                 + free.inverse[inertial_column, inertial_column] ** 2 * free.prior_information)
        if prior is not None or abs(j) >= J_SIGNIFICANCE * math.sqrt(j_var):
            fit, inertia, inertia_var = free, j, j_var
            source = "data" if prior is None else "given and data"
            prior_part = free.inverse[:2 * top + 1, inertial_column] * math.sqrt(free.prior_information)
        else:
            messages.append(f"inertia: the data give J = {j:.4g} +- {math.sqrt(j_var):.2g} kg m^2, within "
                            f"{J_SIGNIFICANCE:g} standard errors of 0 - not identified; no inertial term")
    elif prior is not None:
        fit = _solve(without, blocks.current - prior[0] * x[:, inertial_column], weight)
        inertia, inertia_var, source = prior[0], prior[1] ** 2, "given"
        prior_part = prior[1] * projection[:2 * top + 1]
    # eq. (3) with A's gain divided out, and its difference from (2) with its errors: the division stretches what
    # A_b holds beyond the position-locked motion (its noise) as it stretches the motion, which the fit's
    # residuals do not see
    usable = blocks.gain >= MIN_GAIN
    stretch = np.repeat(inertia * (1.0 / np.maximum(blocks.gain, MIN_GAIN) - 1.0), 2)
    influence = fit.scores(cluster, clusters)[:, :2 * top + 1]
    influence[:, 1:] -= stretch * _cluster_scores(projector, x[:, inertial_column] - without @ projection, cluster,
                                                  clusters)[:, 1:2 * top + 1]
    corrected = _harmonics(fit.beta, top) + inertia * (1.0 / np.maximum(blocks.gain, MIN_GAIN) - 1.0) * a_h
    difference = influence - baseline_influence[:, :2 * top + 1]
    bias = np.zeros(top)
    if inertia != 0.0 and quantum > 0.0:
        bias = QUANTISER_BOUND * abs(inertia) * _quantiser_bias(d.time_s, motion, quantum, omega, grid, projector,
                                                                tau_s, top)
    d_h = corrected - baseline
    filter_var = np.zeros(top)
    if tau_log_std > 0.0:  # the fitted filter's uncertainty, through the fit at log T +- its standard error
        up, down = (_harmonics(grid.fit_at(tau_s * math.exp(sign * tau_log_std)).beta, top) for sign in (1, -1))
        filter_var = np.abs(up - down) ** 2 / 4.0
    systematic = _prior_variance(prior_part, top) / np.maximum(blocks.gain, MIN_GAIN) ** 2 + bias**2 + filter_var
    d_var = np.where(usable, _variance(difference, top, clusters) + systematic, np.inf)
    # eq. (6), on the quantiser's RMS bias (its bound is for the stated error)
    likely = d_var - (1.0 - QUANTISER_BOUND**-2) * bias**2
    power = np.abs(d_h) ** 2
    expected = _expected_orders(motor, top)
    threshold = np.where(expected, math.log(max(int(expected.sum()), 1) / SELECTION_EXPECTED),
                         math.log(max(int((~expected).sum()), 1) / SELECTION))
    taken = usable & (power > threshold * likely)
    g = np.where(taken, 1.0 - SHRINK * likely / np.maximum(power, 1e-300), 0.0)
    combined = baseline + g * np.where(usable, d_h, 0.0)
    mixed = baseline_influence[:, :2 * top + 1].copy()
    for column in (1 + 2 * np.arange(top), 2 + 2 * np.arange(top)):
        mixed[:, column] += g * difference[:, column]
    variance = (_variance(mixed, top, clusters) + g**2 * systematic
                + (1.0 - g) ** 2 * np.where(usable, np.abs(d_h) ** 2, 0.0))
    aliased, folds = _nyquist_folds(motor.cogging_order, rows_per_rev, top)
    folded = _folded_power(combined, ~aliased, motor.cogging_order, nyquist)
    ripple = _ripple_folds(k_q_table(rolling), float(np.sum(blocks.current) / np.sum(blocks.width)), rows_per_rev,
                           top)
    variance = variance + folded + ripple
    cover = coverage(d.position_counts, cpr, d.segment)
    # a harmonic a cogging order folds onto is left out (taken as 0): what the rows hold there, its own torque or the
    # fold, is its error
    left_out = np.abs(combined) ** 2 + variance
    estimate = RollingEstimate(
        np.where(aliased, 0.0, combined), np.where(aliased, left_out, variance), baseline,
        _variance(baseline_influence, top, clusters), corrected, d_var, bias, g, ~aliased, cpr, motor.cogging_order,
        nyquist, speed_hz, row_rate_hz, float(np.mean(k_q_table(rolling))), inertia, math.sqrt(inertia_var), source,
        tau_s, tau_source, float(fit.beta[0]), quantum, folded, d.time_s.size, blocks.width.size, len(d.segments),
        cover.revolutions, cover.text(), ())
    return replace(estimate, messages=tuple(_messages(estimate, rolling, folds, ripple, wanted) + messages))


def _fitted_filter(grid: _Grid, coarse: _Grid, duration: float) -> tuple[float, str, float]:
    """Eq. (5): the logged current's filter, found (T > 0) where, on the ``coarse`` blocks (the current's rate of
    change is noise on a row's), the unfiltered fit with the torque advanced by the filter, y + T dy/dt (the
    inverse filter; A_b's noise the same at every T), explains `FILTER_GAIN` times more of the residual power with
    a significant T > 0; then T, on ``grid``'s blocks, the measured-domain fit's least residual power, summed
    over runs of `FILTER_GROUP` blocks, over `FILTER_GRID` values from twice the block to a quarter of the log (at
    most `MAX_FILTER_S`), refined by a parabola in log T; and the standard error of log T, from the parabola's
    curvature a as for `CLUSTERS` independent residuals: sqrt(P(T) / (K_c a)) (the grid's step where the minimum is
    at an end). (0, "none", 0) where no filter is found."""
    longest = min(MAX_FILTER_S, duration / 4.0)
    if longest <= 2.0 * grid.block_s:
        return 0.0, "none", 0.0
    base = coarse.fit_at(0.0)
    rate = coarse.blocks.rate * np.sqrt(coarse.weight)
    rate_left = rate - base.design @ (base.inverse @ (base.design.T @ rate))
    slope = -float(base.residual @ rate_left) / max(float(rate_left @ rate_left), 1e-300)
    explained = float(base.residual @ base.residual) / max(float(np.sum((base.residual + slope * rate_left) ** 2)),
                                                           1e-300)
    if not (slope > 0 and explained > FILTER_GAIN and coarse.clusters * math.log(explained) > FILTER_SIGNIFICANCE):
        return 0.0, "none", 0.0
    n_b = grid.blocks.width.size
    group = np.minimum(np.arange(n_b) // FILTER_GROUP, max(n_b // FILTER_GROUP - 1, 0))
    width = np.bincount(group, weights=grid.blocks.width)

    def power(log_tau: float) -> float:
        summed = np.bincount(group, weights=grid.fit_at(math.exp(log_tau)).residual * np.sqrt(grid.blocks.width))
        return float(np.sum(summed**2 / width))

    logs = np.linspace(math.log(2.0 * grid.block_s), math.log(longest), FILTER_GRID)
    powers = np.array([power(u) for u in logs])
    k = int(np.argmin(powers))
    step = float(logs[1] - logs[0])
    if 0 < k < logs.size - 1:
        a, b, _ = np.polyfit(logs[k - 1:k + 2], powers[k - 1:k + 2], 2)
        if a > 0:
            best = -b / (2 * a)
            least = power(best)
            if least < powers[k]:
                return math.exp(best), "fitted", min(math.sqrt(least / (grid.clusters * a)), step)
    return math.exp(logs[k]), "fitted", step


def _scalar_variance(influence: np.ndarray, clusters: int) -> float:
    return clusters / max(clusters - 1, 1) * float(np.sum(influence**2))


def _prior_variance(part: np.ndarray, top: int) -> np.ndarray:
    """E|d tau_h|^2 from J's prior, given its influence on the coefficients."""
    return part[1:2 * top + 1:2] ** 2 + part[2:2 * top + 1:2] ** 2


def k_q_table(rolling: Rolling) -> np.ndarray:
    """k_q per count: sum_p K_p sin(theta_e - 2 pi p / 3), N m / A."""
    motor = rolling.motor
    theta_e = motor.pole_pairs * 2.0 * np.pi * np.arange(motor.counts_per_rev) / motor.counts_per_rev
    return np.sum(rolling.backemf_nm_per_a * q_axis(theta_e + rolling.settings.angle_offset_rad), axis=1)


def _messages(e: RollingEstimate, rolling: Rolling, folds: dict[int, int], ripple_nm2: np.ndarray,
              wanted: int) -> list[str]:
    """What the rolling identification took, assumed and left out (``folds`` `_nyquist_folds`', ``ripple_nm2``
    `_ripple_folds`')."""
    choices = e.choices()
    counts = {c: choices.count(c) for c in ("corrected", "combined", "baseline", "aliased")}
    top = e.harmonics_nm.size
    out = [f"rolling log ({e.samples} rows in {e.segments} segment(s), {e.row_rate_hz:.4g} rows/s median, "
           f"{e.speed_hz:.4g} Hz mean, {e.coverage}): the position torque from the currents averaged by position "
           "(the baseline, a drive's own anticogging) and corrected by J domega/dt and the current's filter where "
           "the data support it, per harmonic"]
    if top < wanted:
        out.append(f"harmonics 1..{top} resolved (of {wanted}): the rows' Nyquist order at the mean speed is "
                   f"{e.nyquist_order} ({e.row_rate_hz:.4g} rows/s over {abs(e.speed_hz):.4g} Hz), or the counts' "
                   f"{rolling.motor.counts_per_rev // 2 - 1}")
    if folds:
        folded = ", ".join(f"{o} -> {a}" for o, a in folds.items())
        out.append(f"cogging orders above the Nyquist order fold ({folded}): the harmonics within one of a fold are "
                   "not estimated, taken as 0")
    out.append(f"per harmonic: {counts['corrected']} corrected, {counts['combined']} combined, {counts['baseline']} "
               f"baseline (the correction not clear of its measured error)")
    if not np.any(e.weight > 0):
        out.append("no correction clears its measured error: the result is the baseline's, the q current averaged "
                   "by position (the rows or the encoder too coarse for J domega/dt at this speed)")
    out.append({"given": f"inertia: J = {e.inertia_kgm2:.4g} +- {e.inertia_std_kgm2:.2g} kg m^2, as given (the data "
                         "do not tell J apart from the position torque)",
                "given and data": f"inertia: J = {e.inertia_kgm2:.4g} +- {e.inertia_std_kgm2:.2g} kg m^2, the given "
                                  "value with what the data tell of it",
                "data": f"inertia: J = {e.inertia_kgm2:.4g} +- {e.inertia_std_kgm2:.2g} kg m^2, identified from the "
                        "data (no inertia_uncertainty given: J taken as unknown)",
                "none": "inertia: not given with an uncertainty and not identified by the data: no inertial term"
                }[e.inertia_source])
    out.append({"stated": f"current filter: T = {e.filter_s:.4g} s, as rolling.toml states",
                "fitted": f"current filter: T = {e.filter_s:.4g} s, fitted (the logged current lags: a drive's "
                          "report filter; state current_filter_s if known)",
                "none": "current filter: none" + (" found" if rolling.settings.current_filter_s is None else "")
                }[e.filter_source])
    if e.position_quantum_rad > 0 and e.inertia_kgm2:
        worst = int(np.argmax(e.encoder_bias_nm))
        out.append(f"encoder: the logged position's quantum ({e.position_quantum_rad:.3g} rad, "
                   f"{e.position_quantum_rad / (2 * np.pi) * e.counts_per_rev:.3g} counts) repeats with position at a "
                   f"steady speed: its bias of J domega/dt, up to {1e3 * e.encoder_bias_nm[worst]:.2g} mN m (order "
                   f"{worst + 1}), is in the corrections' errors")
    if e.folded_nm2 > 0:
        out.append(f"sparse rows: content above the Nyquist order folds onto every harmonic, "
                   f"{1e3 * math.sqrt(e.folded_nm2):.2g} mN m each (the top quarter of the orders, the cogging's left "
                   "out): in the standard errors")
    if np.any(ripple_nm2 > 0):
        worst = int(np.argmax(ripple_nm2))
        out.append(f"sparse rows: the currents' torque ripple above the Nyquist order (k_q's orders times the mean "
                   f"current) folds onto {int(np.sum(ripple_nm2 > 0))} harmonic(s), up to "
                   f"{1e3 * math.sqrt(ripple_nm2[worst]):.2g} mN m (order {worst + 1}): in their standard errors")
    if rolling.data.torque_nm is not None:
        out.append("the log's torque column is kept in the folder, not used (the currents' torque is)")
    out.append(f"friction: {e.friction_nm:.4g} N m at the log's speed (Coulomb and viscous not separated)")
    return out


# ---------------------------------------------------------------- identify


def rolling_result(estimate: RollingEstimate) -> IdentificationResult:
    """The `IdentificationResult` of a rolling identification: its cogging band and whole position torque with
    their standard errors (what ``ilcpmac export`` takes), the baseline's cogging beside it under ``methods``."""
    cogging_band = estimate.estimated & estimate.cogging_band
    cogging = estimate.table_nm(cogging_only=True) if cogging_band.any() else None
    baseline = estimate.table_nm(estimate.baseline_nm, cogging_only=True) if cogging_band.any() else None
    return IdentificationResult(
        cogging_nm=cogging, methods={"rolling": MethodEstimates(cogging_nm=cogging),
                                     "baseline": MethodEstimates(cogging_nm=baseline)},
        messages=estimate.messages, diagnostics={"method": "rolling", "rolling": estimate.to_json()},
        details=estimate, torque_source=TorqueSource.ENCODER, position_torque_nm=estimate.table_nm(),
        position_torque_std_nm=estimate.table_std_nm())


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(values))))


def identify_rolling(folder: str | Path, output: str | Path) -> tuple[IdentificationResult, list[str]]:
    """``ilcpmac identify ROLLING_FOLDER``: the rolling identification, its result JSON written to ``output``; the
    result and the lines to print (with a truth.json, a simulated log's, the errors against it)."""
    import json

    folder = Path(folder)
    estimate = estimate_rolling(read_rolling(folder))
    result = rolling_result(estimate)
    output = Path(output)
    output.parent.mkdir(parents=True, exist_ok=True)
    atomic_write(output, json.dumps(result.to_json(), indent=1, allow_nan=False))
    e = estimate
    assert result.position_torque_nm is not None and result.position_torque_std_nm is not None
    lines = [f"rolling log: {e.samples} rows, {e.revolutions:.3g} revolutions at {e.speed_hz:.4g} Hz, harmonics "
             f"1..{e.harmonics_nm.size}; J = {e.inertia_kgm2:.4g} kg m^2 ({e.inertia_source}), current filter "
             f"{e.filter_s:.3g} s ({e.filter_source})",
             f"position torque: {1e3 * _rms(result.position_torque_nm):.4g} mN m RMS, ± "
             f"{1e3 * _rms(result.position_torque_std_nm):.2g} mN m per count "
             f"({_rms(result.position_torque_nm) / e.torque_constant_nm_per_a:.4g} A RMS of q current at K_t = "
             f"{e.torque_constant_nm_per_a:.4g} N m / A)",
             f"baseline (q current averaged by position): {1e3 * _rms(e.table_nm(e.baseline_nm)):.4g} mN m RMS"]
    for h in np.argsort(np.abs(e.harmonics_nm))[::-1][:6]:
        lines.append(f"  order {h + 1}: {1e3 * abs(e.harmonics_nm[h]):.4g} ± {1e3 * math.sqrt(e.variance_nm2[h]):.2g} "
                     f"mN m ({e.choices()[h]}; baseline {1e3 * abs(e.baseline_nm[h]):.4g})")
    for key, estimated in (("cogging", result.cogging_nm), ("position_torque", result.position_torque_nm)):
        true = truth_tables(folder).get(key)
        if true is not None and estimated is not None and true.shape == estimated.shape and np.ptp(true) > 0:
            true = true - true.mean()
            base = e.table_nm(e.baseline_nm, cogging_only=key == "cogging")
            error, base_error = (100 * _rms(x - true) / np.ptp(true) for x in (estimated, base))
            lines.append(f"vs truth: {key.replace('_', ' ')} RMS error {error:.3g} % of its peak-to-peak (baseline "
                         f"{base_error:.3g} %), correlation {np.corrcoef(estimated, true)[0, 1]:.4f} (baseline "
                         f"{np.corrcoef(base, true)[0, 1]:.4f})")
    lines.append(f"wrote {output}")
    return result, lines
