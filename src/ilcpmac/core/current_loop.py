"""The current loop: how the phase currents follow their references (beyond the report).

The one model of the loop: the identification fits it (`ilcpmac.identify.joint`) and the
stages invert it (`ilcpmac.stages.base.StageSetup.torque_response`).

The report assumes the currents follow the references I*_p exactly (sec. 2.3:
"in this range the current follows the reference closely"). With a 140 Hz
current loop (sec. 2.1) and harmonics up to 144 at 1 Hz they do not: the
harmonic response rolls off, which biases the total system gain (the report's
14 % residue). Here each phase's loop is a first-order lag with time constant
tau_p and a common delay T_d,

    G_p(s) = exp(-s T_d) / (1 + s tau_p).

A PI loop tuned for bandwidth f_c by pole-zero cancellation on a current
sensor whose gain error is eps alpha_p closes at f_c / (eps alpha_p), so the
phases differ; T_d stands for the controller's computation and sampling.

The reference is a staircase in time (the controller updates it once per
encoder count) and the rotor speed ripples, so the loop is applied exactly in
time, count by count, with each trial's measured count intervals: the state
s_c (the current when count c is reached) obeys

    s_{c+1} = x_c + (s_c - x_c) exp(-dt_c / tau),

and the current sampled at count c is the state at t_c - T_d. The periodic
steady state is found by running the recursion from late in the previous
revolution, long enough for the start to be forgotten. The same loop leaves a
tracking error to the back-EMF e_p = K_p omega, which its sensitivity
1 - G_p lets through (`ilcpmac.identify.joint`).

That error closes a second loop through the rotor. A torque ripple tau_h at
angular frequency w ripples the speed by tau_h / Z(w), Z = j w J + b (the
inertia and the brake), the back-EMF by K_p times that, and the currents by
-Y_p(w) K_p times that, where

    Y_p(w) = (1 / R) W(w) (1 - G_p(w)),   W = 1 / (1 + j w L/R),

is the loop's admittance to a voltage disturbance (a PI loop cancelling the
winding's pole: the joint fit's back-EMF column, c_e = -delta / R). Their
torque opposes the ripple, so every torque ripple, the feed-forward's and
the motor's own, reaches the shaft times

    M(w) = 1 / (1 + sum_p kappa_p Y_p(w) / Z(w)),   kappa_p = mean over the revolution of K_p^2

(`speed_feedback`, which evaluates Y_p at the frequencies the speed ripple
makes of each back-EMF harmonic, through both its size and its timing). On a
light rotor with a slow loop M is far from 1: 0.85 at 5 degrees on the
cogging (h 12) of a 2-pole-pair actuator at 4.6 Hz (J 2.8e-4 kg m^2, 282 Hz
loop), 0.65 at 19 degrees at the electrical frequency of a 40 N m servo at
1 Hz (60 Hz loop, J 0.05 kg m^2); on the seed bench 0.99-1.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ilcpmac.core.binning import bin_response


@dataclass(frozen=True)
class CurrentLoop:
    """A first-order current loop per phase with a common delay.

    Attributes
    ----------
    time_constant_s : ndarray, shape (3,)
        tau_p per phase, s. All zero with ``delay_s < 0`` is the report's
        ideal loop (the current equals the reference at each count).
    delay_s : float
        T_d, s.
    """

    time_constant_s: np.ndarray = field(default_factory=lambda: np.zeros(3))
    delay_s: float = -1e-9

    def __post_init__(self) -> None:
        object.__setattr__(self, "time_constant_s", np.asarray(self.time_constant_s, float).reshape(3))
        object.__setattr__(self, "delay_s", float(self.delay_s))

    @property
    def is_ideal(self) -> bool:
        """Whether the currents equal the references (no lag, eq. 1.3 as the report uses it)."""
        return bool(np.all(self.time_constant_s <= 0.0))

    @property
    def bandwidth_hz(self) -> np.ndarray:
        """Corner frequency 1 / (2 pi tau_p) per phase, Hz (inf without lag)."""
        with np.errstate(divide="ignore"):
            return 1.0 / (2.0 * np.pi * self.time_constant_s)

    def scaled(self, factor: np.ndarray | float) -> CurrentLoop:
        """The loop with each phase's time constant times ``factor`` (the delay kept)."""
        return CurrentLoop(self.time_constant_s * factor, self.delay_s)

    def response(self, harmonics: np.ndarray, speed_hz: float | np.ndarray, counts_per_rev: int,
                 lines_per_count: int = 1) -> np.ndarray:
        """The loop's response per harmonic and phase at a constant speed, shape (len(harmonics), 3); for an
        array of speeds, one such block per speed, shape speed_hz.shape + (len(harmonics), 3).

        The z-transform of the count recursion (module docstring) with equal
        count intervals 1 / (counts_per_rev speed_hz), at z = exp(j 2 pi h / counts_per_rev). With b =
        ``lines_per_count`` > 1 the currents are recorded as count means (`ilcpmac.core.binning`): the
        staircase over N b lines has harmonic h at h + k N (k = 0 .. b - 1) with weights D_k = mean_j
        exp(-j 2 pi (h + k N) j / (N b)), each through the loop sampled per line and the count mean
        (`bin_response`), all folding back onto h.
        """
        if lines_per_count > 1:
            h = np.asarray(harmonics, float)
            lines = lines_per_count * counts_per_rev
            total = np.zeros(np.shape(speed_hz) + (h.size, 3), complex)
            for k in range(lines_per_count):
                image = h + k * counts_per_rev
                weight = np.exp(-2j * np.pi * image[:, None] * np.arange(lines_per_count) / lines).mean(axis=1)
                total = total + (weight * bin_response(image, lines, lines_per_count))[:, None] * self.response(
                    image, speed_hz, lines)
            return total
        z_inv = np.exp(-2j * np.pi * np.asarray(harmonics, float)[:, None] / counts_per_rev)
        dt = 1.0 / (counts_per_rev * np.asarray(speed_hz, float)[..., None, None])
        a, b = self.count_decays(dt)
        state = (1.0 - a) * z_inv / (1.0 - a * z_inv)  # s_c / x_c
        if self.delay_s >= 0.0:
            return z_inv * (1.0 - b) + b * z_inv * state
        return 1.0 - b + b * state

    @property
    def lag_time_constant_s(self) -> np.ndarray:
        """tau_p per phase, s, kept above zero (1e-300 s) so that the decays below divide by it."""
        bounded: np.ndarray = np.maximum(self.time_constant_s, 1e-300)
        return bounded

    def count_decays(self, count_period_s: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """The recursion's decays per phase over equal count intervals dt = ``count_period_s`` (module docstring):
        a = exp(-dt / tau_p) over a count, and b, what is left at the sample: exp(-(dt - T_d) / tau_p) for
        T_d >= 0 (the sample within the count before), else exp(T_d / tau_p)."""
        tau = self.lag_time_constant_s
        a = np.exp(-count_period_s / tau)
        if self.delay_s >= 0.0:
            return a, np.exp(-(count_period_s - self.delay_s) / tau)
        return a, np.exp(self.delay_s / tau)


def lagged(x: np.ndarray, count_period_s: np.ndarray, loop: CurrentLoop, continuous: bool = False) -> np.ndarray:
    """Per-count tables ``x`` (n_trials, cpr, 3) through the loop, sampled at each count.

    ``continuous``: ``x`` samples a smooth signal (linear between counts)
    rather than a staircase held from each count to the next.
    """
    return np.stack([lagged_phase(x[:, :, p], count_period_s, loop.time_constant_s[p], loop.delay_s, continuous)
                     for p in range(3)], axis=2)


def count_decay(count_period_s: np.ndarray, time_constant_s: float) -> np.ndarray:
    """exp(-dt_c / tau) per count (zero without lag): how much of the state is left after each count."""
    tau = float(time_constant_s)
    return np.exp(-count_period_s / tau) if tau > 0.0 else np.zeros_like(count_period_s)


def sample_decay(count_period_s: np.ndarray, time_constant_s: float, delay_s: float) -> np.ndarray:
    """exp(-(dt_{c-1} - T_d) / tau) per count for T_d >= 0 (at most one count back), else exp(T_d / tau).

    Zero without lag. A staircase input's sample at t_c - T_d is read from the state with it.
    """
    tau = float(time_constant_s)
    if tau <= 0.0:
        return np.zeros_like(count_period_s)
    if delay_s >= 0.0:
        return np.exp(-np.maximum(np.roll(count_period_s, 1, axis=1) - delay_s, 0.0) / tau)
    return np.full_like(count_period_s, np.exp(delay_s / tau))


def lagged_phase(x: np.ndarray, count_period_s: np.ndarray, time_constant_s: float, delay_s: float,
                 continuous: bool = False, decays: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """One phase's per-count tables ``x`` (n_trials, cpr) through a loop with time constant tau and delay T_d.

    ``decays``: `count_decay` and, unless ``continuous`` (which does not use it),
    `sample_decay` of these count periods, tau and T_d, when the caller keeps them
    (each is an exp over every count, the bulk of the cost).
    """
    tau = float(time_constant_s)
    if decays is None:
        decay = count_decay(count_period_s, tau)
        decays = (decay, decay if continuous else sample_decay(count_period_s, tau, delay_s))
    from ilcpmac.core.lag_kernel import lag_kernel  # numba, only when a loop is applied

    out = np.empty(x.shape)
    lag_kernel(np.ascontiguousarray(x, float), count_period_s, tau, *decays, delay_s >= 0.0, continuous, out)
    if continuous and delay_s != 0.0:  # the state at t_c - T_d, linear between counts
        if delay_s > 0.0:
            out = out - delay_s / np.roll(count_period_s, 1, axis=1) * (out - np.roll(out, 1, axis=1))
        else:
            out = out - delay_s / count_period_s * (np.roll(out, -1, axis=1) - out)
    return out


def periodic_lag(x: np.ndarray, count_period_s: np.ndarray, time_constant_s: float) -> np.ndarray:
    """Periodic per-count tables ``x`` (n_trials, cpr), linear between counts in time, through a first-order
    lag of time constant tau: its state at each count in the periodic steady state.

    The count recursion (module docstring, for an input linear between counts)
    s_{c+1} = a_c s_c + u_c, a_c = exp(-dt_c / tau), closed over a revolution:
    s_0 = sum_c u_c prod_{i>c} a_i / (1 - prod_c a_c), for a tau long against
    a revolution (a torque sensor's high-pass) where `lagged_phase`'s warm-up
    within one revolution does not forget its start (down to a corner of
    1e-15 Hz, whose state is the input's mean over time); for a tau whose
    decay over a revolution is below 1e-16, `lagged_phase` (exact then).
    """
    x = np.asarray(x, float)
    dt = np.asarray(count_period_s, float)
    tau = float(time_constant_s)
    log_decay = np.cumsum(-dt / tau, axis=1)  # log prod_{i<=c} a_i
    if np.any(log_decay[:, -1] < np.log(1e-16)):
        return lagged_phase(x, dt, tau, 0.0, continuous=True)
    r = dt / tau
    # u_c = x_{c+1} - a_c x_c - (x_{c+1} - x_c) (1 - a_c) / r_c, r_c = dt_c / tau, as (x_{c+1} - x_c) (1 - phi_c)
    # + (1 - a_c) x_c with phi = (1 - exp(-r)) / r: every term O(r), exact to rounding for a tau of any length
    one_minus_a = -np.expm1(-r)
    one_minus_phi = np.where(r < 1e-3, r / 2.0 - r**2 / 6.0 + r**3 / 24.0 - r**4 / 120.0, 1.0 - one_minus_a / r)
    u = (np.roll(x, -1, axis=1) - x) * one_minus_phi + one_minus_a * x
    total = log_decay[:, -1:]
    start = np.sum(u * np.exp(total - log_decay), axis=1, keepdims=True) / -np.expm1(total)
    # s_c = prod_{i<c} a_i (s_0 + sum_{i<c} u_i / prod_{j<=i} a_j), every factor at most exp(-total) <= 1e16
    before = np.concatenate([np.zeros((x.shape[0], 1)), log_decay[:, :-1]], axis=1)
    summed = np.concatenate([np.zeros((x.shape[0], 1)), np.cumsum(u * np.exp(-log_decay), axis=1)[:, :-1]], axis=1)
    lagged: np.ndarray = np.exp(before) * (start + summed)
    return lagged


#: the back-EMF's harmonics below this fraction of its largest power are left out of `speed_feedback`
BACKEMF_POWER_FLOOR = 1e-8


def speed_feedback(harmonics: np.ndarray, speed_hz: float, loop: CurrentLoop, backemf: tuple[np.ndarray, np.ndarray],
                   conductance_s: float, winding_time_constant_s: float, inertia_kgm2: float,
                   brake_nms: float) -> np.ndarray:
    """M(h) per mechanical harmonic h at a speed f (module docstring): the part of a torque ripple that reaches
    the shaft when its speed ripple's back-EMF passes the current loop, complex, shape of ``harmonics``.

    A speed ripple dw at h changes each back-EMF harmonic c_pn e^{j n theta} w in two ways the loop sees in
    time: its size (c_pn dw at h + n) and its timing (the rotor reaches each angle early or late, a phase
    modulation of the main back-EMF). Through Y_p and sampled at the angles again, both give at h + n
    c_pn dw ((h + n) Y_p(h + n) - n Y_p(n)) / h, Y_p(k) at k f; K_p's harmonic -n turns that into torque
    at h, so sum_p kappa_p Y_p = sum_p sum_n |c_pn|^2 ((h + n) Y_p(h + n) - n Y_p(n)) / h over the harmonics n
    (of either sign) of the back-EMF table, ``backemf`` its `backemf_power`. ``conductance_s`` is
    1 / R (S), ``inertia_kgm2`` J and ``brake_nms`` b of Z = j w J + b. 1 where the loop is ideal, or with no
    conductance.
    """
    h = np.asarray(harmonics, float)
    if loop.is_ideal or not conductance_s > 0.0:
        return np.ones(h.shape, complex)
    n, power = backemf

    def weighted(k: np.ndarray) -> np.ndarray:
        """k Y_p(k), shape k.shape + (3,)."""
        w = 2.0 * np.pi * speed_hz * k[..., None]
        g = np.exp(-1j * w * max(loop.delay_s, 0.0)) / (1.0 + 1j * w * loop.time_constant_s)
        rejected: np.ndarray = k[..., None] * conductance_s / (1.0 + 1j * w * winding_time_constant_s) * (1.0 - g)
        return rejected

    coupling = np.sum(power * (weighted(h[..., None] + n) - weighted(n)), axis=(-2, -1)) / h
    response: np.ndarray = 1.0 / (1.0 + coupling / (2j * np.pi * speed_hz * h * inertia_kgm2 + brake_nms))
    return response


def backemf_power(backemf_nm_per_a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The harmonics n (of either sign) of a back-EMF table (shape (N, 3), N m / A) and their power |c_pn|^2 per
    phase, shape (k, 3), those above `BACKEMF_POWER_FLOOR` of the largest: what `speed_feedback` sums over."""
    table = np.asarray(backemf_nm_per_a, float)
    power = np.abs(np.fft.fft(table, axis=0) / table.shape[0]) ** 2  # n = 0, 1, .., -1
    orders = np.fft.fftfreq(table.shape[0], 1.0 / table.shape[0])
    keep = power.max(axis=1) > BACKEMF_POWER_FLOOR * power.max()
    return orders[keep], power[keep]
