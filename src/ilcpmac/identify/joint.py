"""One joint least-squares fit over all set points (beyond the report).

The report fits the total system gain delta*eps to a frequency response
(ch. 2), then alpha*, beta* per set point by the pseudo-inverse of eq. (1.12)
with the cogging as the residual (eq. 1.13). Here every trial's torque
harmonics are fitted at once, in the harmonics domain (sec. 2.3), by

    tau*_k(h) = H_s(h f_k) [ sum_p theta_p A_kp(h) + sum_p beta*_p B_p(h) + c_e E_k(h) + s S_k(h) + T(h) ] + noise,

for harmonic h of trial k at mean speed f_k, where

- A_kp = DFT(K_p (G_p I*_p)): the per-phase theoretical torque (K . I*_i of
  eq. 1.3) through the current loop G_p (`ilcpmac.core.current_loop`, applied in
  time count by count), with theta_p = delta eps alpha_p: their mean is the
  total system gain delta*eps, so it no longer rests on the frequency
  response alone;
- B_p = DFT(K_p): the back-EMF columns of eq. (1.10), beta*_p = delta beta_p.
  An offset common to the three phases makes the torque beta_0 sum_p K_p:
  where the back-EMFs sum to zero (a symmetric, purely sinusoidal back-EMF:
  sum_p B_p below SIGNIFICANT of the largest B_p at every fitted harmonic)
  it makes none, the columns are rank-deficient by one, and the common
  offset mean_p beta*_p is not identified: it is held at 0 (the
  calibration's) and only the differential offsets beta*_p - mean beta* are
  fitted (`JointEstimate.common_offset_identified`), rather than a
  least-squares minimum norm passing for an estimate;
- E_k = DFT(sum_p K_p W (1 - G_p) e_p): the loop's tracking error to the
  back-EMF e_p = K_p omega (omega measured per count), through the winding
  W = 1 / (1 + s L/R); c_e = -delta / R. The speed ripple makes it ripple at
  the electrical harmonics where beta is read;
- S_k = -DFT(sum_p K_p i_p^3), i_p = theta_p G_p I*_p + beta*_p: a saturation
  term (the torque constant falling with current), whose set-point dependent
  ripple at 6x electrical would otherwise be taken for cogging;
- T(h): one position table shared by all trials, free on the cogging
  harmonics (multiples of lcm(slots, 2 pole_pairs)) and on the harmonics where
  K has no content: the cogging torque delta tau_c and the unexplained
  position-locked rest. Each trial has its own multisine phases, so the
  current columns vary from trial to trial and T cannot absorb them; freed
  too at a back-EMF harmonic where the trials share a residual the columns
  leave (`_shared_rest`: a disturbance at an electrical order, which would
  bend the winding's parameters), the fit then run again from its minimum;
- H_s: the torque sensor, a first-order high-pass (the piezo cannot measure
  the mean, sec. 1.1) with corner f_hp, and a delay D of the measurement,
  removed by advancing the data in time. H_s(h f_k) is the high-pass at a
  constant speed; it acts in time, and with the speed rippling the time per
  count differs from count to count: the difference mixes the speed ripple
  into the torque's harmonics (the cogging's with the electrical ones onto
  1x electrical, where beta is read). It is taken off the data
  (`_ripple_highpass`), the nonlinear parameters moved to the new minimum
  by one Gauss-Newton step (`_gauss_newton_step`) and the linear ones
  solved again.
  The encoder-derived torque passes no sensor: H_s = 1, and f_hp and D
  are not fitted (`SENSOR_PARAMETERS`, held at none), nor in the
  covariance, nor reported (None).

The sensor's DC level and drift never enter: they were removed from the
aperiodic part of each trial (`ilcpmac.identify.reduction`). The loop's time
constants and delay, f_hp, L/R and D enter nonlinearly and are found by
variable projection (the linear parameters and T are solved for at every
step); standard errors come from the covariance (J^T J)^-1 of all
parameters, inflated by the reduced chi-square of each family of harmonics
that determines them (`_covariance`, `MisfitGroup`), plus the structure of
the gains and offsets over blocks of harmonics and over set points
(`_gain_structure`, `GainStructure`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from enum import IntEnum
from typing import NamedTuple

import numpy as np
from numba import njit

from ilcpmac.core import torque_sensor
from ilcpmac.core.binning import count_means
from ilcpmac.core.current_loop import CurrentLoop, count_decay, lagged_phase, periodic_lag, sample_decay
from ilcpmac.core.errors import IdentificationError
from ilcpmac.core.lag_kernel import _advance, warm_up_start
from ilcpmac.core.records import LOOP_WINDING
from ilcpmac.identify.reduction import BenchTables, trial_amplitudes
from ilcpmac.identify.system_gain import chi2_quantile, structure_variance
from ilcpmac.model.tables import references_per_line
from ilcpmac.signals.harmonics import table_from_amplitudes

#: relative amplitude (of the largest harmonic) below which a column carries no information
SIGNIFICANT = 1e-3
#: the joint fit's names of `LOOP_WINDING` (the back-EMF column's coefficient c_e for the conductance -c_e / delta)
LOOP_WINDING_FITTED = dict(zip(LOOP_WINDING, ("tau_a_s", "tau_b_s", "tau_c_s", "delay_s", "winding_tau_s", "emf")))
#: the probability, over the harmonics tested, that `_shared_rest` frees T(h) where the trials share no residual
SHARED_FALSE_ALARM = 1e-3
#: reduced chi-square of a harmonic family above which (and above its 99.9 % noise quantile) the fit is called off
MISFIT_CHI2 = 1.5


class Phi(IntEnum):
    """The index of each nonlinear parameter in the vector phi (`NONLINEAR` names them in this order)."""

    TAU_A = 0  # the current loop's time constant per phase, s
    TAU_B = 1
    TAU_C = 2
    DELAY = 3  # the current loop's delay T_d, s
    HIGHPASS = 4  # the torque sensor's high-pass corner, Hz
    WINDING_TAU = 5  # the winding's L / R, s
    TORQUE_DELAY = 6  # the torque sensor's delay D, s


#: phases a, b, c's loop time constants in phi
TAU = (Phi.TAU_A, Phi.TAU_B, Phi.TAU_C)
#: names of the nonlinear parameters, in the order of `Phi`, and their typical sizes
NONLINEAR = ("tau_a_s", "tau_b_s", "tau_c_s", "delay_s", "highpass_hz", "winding_tau_s", "torque_delay_s")
NONLINEAR_SCALE = np.array([1e-3, 1e-3, 1e-3, 1e-4, 0.05, 1e-3, 1e-5])
#: their lower bounds (time constants, delay and corner not negative; the torque's delay free)
NONLINEAR_LOWER = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -np.inf])
#: the torque sensor's (high-pass corner and delay): held at 0 (none) on the encoder-derived torque, which
#: passes no sensor
SENSOR_PARAMETERS = np.isin(np.arange(len(Phi)), (Phi.HIGHPASS, Phi.TORQUE_DELAY))


class Column(IntEnum):
    """The index of each linear column, and of its coefficient in x (`LINEAR` names them in this order)."""

    THETA_A = 0  # each phase's current column K_p G_p I*_p
    THETA_B = 1
    THETA_C = 2
    BETA_STAR_A = 3  # each phase's offset column K_p
    BETA_STAR_B = 4
    BETA_STAR_C = 5
    EMF = 6  # the back-EMF column sum_p K_p W (1 - G_p) e_p
    SATURATION = 7


#: phases a, b, c's current and offset columns
THETA = (Column.THETA_A, Column.THETA_B, Column.THETA_C)
BETA_STAR = (Column.BETA_STAR_A, Column.BETA_STAR_B, Column.BETA_STAR_C)
#: the gains' block of the linear columns, theta and beta* (what `_gain_structure` tests), and its theta part
GAINS = len(THETA) + len(BETA_STAR)
#: the linear columns' names, in the order of `Column`
LINEAR = ("theta_a", "theta_b", "theta_c", "beta_star_a", "beta_star_b", "beta_star_c", "emf", "saturation")


class LoopDerivative(IntEnum):
    """The index of each column of `_JointProblem.loop_derivatives`."""

    CURRENT_TAU_A = 0  # K_p G_p I*_p with respect to tau_p
    CURRENT_TAU_B = 1
    CURRENT_TAU_C = 2
    CURRENT_DELAY_A = 3  # K_p G_p I*_p with respect to T_d
    CURRENT_DELAY_B = 4
    CURRENT_DELAY_C = 5
    EMF_TAU_A = 6  # the back-EMF column's phase p with respect to tau_p
    EMF_TAU_B = 7
    EMF_TAU_C = 8
    EMF_DELAY = 9  # the back-EMF column with respect to T_d
    EMF_WINDING_TAU = 10  # and to L / R


#: per loop parameter, the columns of `_JointProblem.loop_derivatives` and the linear columns they move
LOOP_COLUMNS = {
    Phi.TAU_A: ([LoopDerivative.CURRENT_TAU_A, LoopDerivative.EMF_TAU_A], [Column.THETA_A, Column.EMF]),
    Phi.TAU_B: ([LoopDerivative.CURRENT_TAU_B, LoopDerivative.EMF_TAU_B], [Column.THETA_B, Column.EMF]),
    Phi.TAU_C: ([LoopDerivative.CURRENT_TAU_C, LoopDerivative.EMF_TAU_C], [Column.THETA_C, Column.EMF]),
    Phi.DELAY: ([LoopDerivative.CURRENT_DELAY_A, LoopDerivative.CURRENT_DELAY_B, LoopDerivative.CURRENT_DELAY_C,
                 LoopDerivative.EMF_DELAY], [*THETA, Column.EMF]),
    Phi.WINDING_TAU: ([LoopDerivative.EMF_WINDING_TAU], [Column.EMF])}
#: why the common current offset is not identified where the back-EMFs sum to zero
COMMON_OFFSET_NOT_IDENTIFIED = (
    "current offsets: the common offset (mean of beta over the phases) not identified - the back-EMFs sum to zero "
    f"(sum_p K_p below {100 * SIGNIFICANT:g} % of K_p at every fitted harmonic), so an offset common to the three "
    "phases makes no torque; beta holds the differential offsets (mean 0) and the calibration keeps its common offset")


@dataclass(frozen=True)
class HarmonicSets:
    """Which harmonics the joint fit uses, and where the shared position table is free.

    Attributes
    ----------
    fit : ndarray of int
        Harmonics 1..max where the per-phase torque columns carry information.
    table_free : ndarray of bool, shape fit.shape
        Whether T(h) is free there (cogging harmonics, harmonics without back-EMF content, and those where the
        trials share a residual, `_shared_rest`).
    cogging : ndarray of int
        Multiples of the cogging order below the Nyquist harmonic.
    """

    fit: np.ndarray
    table_free: np.ndarray
    cogging: np.ndarray


@dataclass(frozen=True)
class MisfitGroup:
    """The joint fit's residual on one family of harmonics.

    Attributes
    ----------
    label : str
        The family: "electrical 1x-2x", "cogging", "other electrical" or "excitation".
    harmonics : ndarray of int
    chi2_reduced : float
        Weighted residual sum of squares over its degrees of freedom (1 when only noise is left).
    dof : float
        Real values less the share of the parameters and of T(h) the family determines.
    inflation : float
        The largest factor by which its misfit alone widens a parameter's standard error.
    """

    label: str
    harmonics: np.ndarray
    chi2_reduced: float
    dof: float
    inflation: float

    @property
    def is_off(self) -> bool:
        """Whether the residual holds structure the model lacks: chi2 beyond MISFIT_CHI2 and beyond noise."""
        return self.chi2_reduced > max(MISFIT_CHI2, chi2_quantile(0.999, self.dof) / self.dof)

    @property
    def warning(self) -> str:
        """One line: where the fit is off, by how much, and what it did to the standard errors."""
        return (f"joint fit: residual chi2/dof {self.chi2_reduced:.3g} at the {self.label} harmonics "
                f"{self.harmonics.min()}-{self.harmonics.max()} - the model misses structure there; standard "
                f"errors inflated up to x{self.inflation:.2g}")


@dataclass(frozen=True)
class GainStructure:
    """The gains theta_p and offsets beta*_p fitted on parts of the data, against the joint fit's.

    A model error that the fitted columns partly absorb (a delay, a roll-off) leaves a small residual
    but estimates that drift from block to block of harmonics, or from set point to set point: a
    structure no average over them removes (`_gain_structure`).

    Attributes
    ----------
    harmonics : ndarray of int
        The excitation harmonics the blocks split.
    chi2_reduced : tuple of float
        Chi-square per degree of freedom of delta*eps over the blocks of harmonics, and the largest of
        delta*eps and beta*_p over the set points (about 1 for noise alone).
    covariance : ndarray, shape (6, 6)
        The structure's covariance of (theta, beta*), added to the fit's (zero below the tests' quantile).
    inflation : float
        The largest factor it put on the standard error of delta*eps or a beta*_p.
    """

    harmonics: np.ndarray
    chi2_reduced: tuple
    covariance: np.ndarray
    inflation: float

    @property
    def is_off(self) -> bool:
        """Whether the estimates drift beyond noise and widen a standard error by more than 1.2."""
        return self.inflation > 1.2

    @property
    def warning(self) -> str:
        """One line: where the estimates drift, by how much, and what it did to the standard errors."""
        over_harmonics, over_set_points = self.chi2_reduced
        return (f"joint fit: the gains and offsets differ over the excitation harmonics "
                f"{self.harmonics.min()}-{self.harmonics.max()} (chi2/dof {over_harmonics:.3g} over blocks) or over "
                f"set points (chi2/dof {over_set_points:.3g}) - the model misses structure there; standard errors "
                f"inflated up to x{self.inflation:.2g}")


@dataclass(frozen=True)
class JointEstimate:
    """Result of the joint fit; torques in measured units (scaled by delta).

    Attributes
    ----------
    theta, theta_std : ndarray, shape (3,)
        delta eps alpha_p per phase (eq. 1.3 through 1.11).
    beta_star_a, beta_star_std : ndarray, shape (3,)
        delta beta_p, A (eq. 1.11).
    saturation_per_a2, saturation_std : float
        s = c / delta^2 of the saturation term, per A^2.
    loop : CurrentLoop
        The identified current loop.
    loop_std : ndarray, shape (4,)
        Standard errors of tau_a, tau_b, tau_c and delay_s, s.
    highpass_hz, highpass_std : float or None
        The torque sensor's high-pass corner; None on the encoder-derived torque (no sensor: not identified).
    winding_time_constant_s : float
        L / R of the winding filter of the back-EMF column.
    emf_gain, emf_gain_std : float
        c_e = -delta / R, the back-EMF column's coefficient, and its standard error, A/V.
    torque_delay_s : float or None
        Delay of the torque measurement (its filter and sampling), s; None on the encoder-derived torque.
    position_table : dict[int, complex]
        T(h), N m (measured), for every harmonic where it is free.
    cogging_harmonics : ndarray of int
    covariance : ndarray
        Covariance of (LINEAR + NONLINEAR active) parameters, named in ``parameter_names``, inflated
        by the misfit of each harmonic family (`_covariance`); on the encoder-derived torque the sensor's
        (SENSOR_PARAMETERS) are never active.
    bound_covariance : ndarray
        (J^T J)^-1 with the measured noise alone: the Cramer-Rao bound of the model.
    parameter_names : tuple of str
    chi2_reduced : float
        Weighted residual sum of squares per degree of freedom (1 when only noise is left).
    misfit : tuple of MisfitGroup
        The residual per harmonic family.
    gain_structure : GainStructure
        theta_p and beta*_p over blocks of harmonics and over set points (`_gain_structure`), included in
        ``covariance``.
    harmonic_response : ndarray, shape (n_trials, n_fit), complex
        Per trial and fit harmonic, the modelled response of the measured torque to
        the theoretical torque sum_p K_p I*_p (for plots).
    sets : HarmonicSets
    common_offset_identified : bool
        False where sum_p K_p is 0 (module notes): beta*_p then holds the differential offsets (their mean 0
        by constraint, not by estimate) and ``beta_star_std`` their standard errors.
    """

    theta: np.ndarray
    theta_std: np.ndarray
    beta_star_a: np.ndarray
    beta_star_std: np.ndarray
    saturation_per_a2: float
    saturation_std: float
    loop: CurrentLoop
    loop_std: np.ndarray
    highpass_hz: float | None
    highpass_std: float | None
    winding_time_constant_s: float
    torque_delay_s: float | None
    emf_gain: float
    emf_gain_std: float
    position_table: dict
    cogging_harmonics: np.ndarray
    covariance: np.ndarray
    bound_covariance: np.ndarray
    parameter_names: tuple
    chi2_reduced: float
    misfit: tuple
    gain_structure: GainStructure
    sets: HarmonicSets
    common_offset_identified: bool = True

    @property
    def delta_epsilon(self) -> float:
        """delta*eps = mean_p theta_p (alpha has mean 1, eq. 1.6)."""
        return float(self.theta.mean())

    @property
    def cramer_rao(self) -> np.ndarray:
        """(J^T J)^-1 with the measured noise alone: the Cramer-Rao bound of the model."""
        return self.bound_covariance

    @property
    def warnings(self) -> tuple[str, ...]:
        """One line per harmonic family where the residual holds structure the model lacks."""
        families = tuple(group.warning for group in self.misfit if group.is_off)
        offset = () if self.common_offset_identified else (COMMON_OFFSET_NOT_IDENTIFIED,)
        return offset + families + ((self.gain_structure.warning,) if self.gain_structure.is_off else ())

    def std_of(self, weights_by_name: dict[str, float], covariance: np.ndarray | None = None) -> float:
        """Standard error of a linear combination of named parameters (``covariance`` defaults to the fit's)."""
        g = np.array([weights_by_name.get(name, 0.0) for name in self.parameter_names])
        return float(np.sqrt(g @ (self.covariance if covariance is None else covariance) @ g))

    def loop_winding_covariance(self, delta: float, delta_std: float) -> np.ndarray:
        """The covariance of `LOOP_WINDING` (the loop's three time constants and delay, the winding's L / R, s, and
        its conductance 1 / R = -c_e / ``delta``, S), with ``delta``'s own relative error ``delta_std`` / ``delta``
        in the conductance; zero rows for what was not fitted (the ideal loop's)."""
        fitted = [LOOP_WINDING_FITTED[name] for name in LOOP_WINDING]
        index = np.array([self.parameter_names.index(n) if n in self.parameter_names else -1 for n in fitted])
        known = index >= 0
        covariance = np.zeros((len(fitted), len(fitted)))
        covariance[np.ix_(known, known)] = self.covariance[np.ix_(index[known], index[known])]
        # the conductance -c_e / delta: d conductance = -d c_e / delta, and delta's variance on its own
        conductance = LOOP_WINDING.index("winding_conductance_s")
        scale = np.ones(len(fitted))
        scale[conductance] = -1.0 / delta
        covariance = scale[:, None] * covariance * scale[None, :]
        covariance[conductance, conductance] += (self.emf_gain / delta * delta_std / delta) ** 2
        return covariance

    @property
    def delta_epsilon_std(self) -> float:
        """Standard error of delta*eps."""
        return self.delta_epsilon_std_of(self.covariance)

    def delta_epsilon_std_of(self, covariance: np.ndarray) -> float:
        """Standard error of delta*eps under ``covariance``."""
        return self.std_of({LINEAR[c]: 1.0 / len(THETA) for c in THETA}, covariance)

    @property
    def alpha(self) -> np.ndarray:
        """alpha_p = theta_p / mean(theta) (eq. 1.6)."""
        return self.theta / self.theta.mean()

    @property
    def alpha_std(self) -> np.ndarray:
        """Standard errors of alpha (first-order error propagation)."""
        return self.alpha_std_of(self.covariance)

    def alpha_std_of(self, covariance: np.ndarray) -> np.ndarray:
        """Standard errors of alpha under ``covariance``."""
        mean = self.theta.mean()
        out = []
        for p, column in enumerate(THETA):
            grad = {LINEAR[c]: -self.theta[p] / (len(THETA) * mean**2) for c in THETA}
            grad[LINEAR[column]] += 1.0 / mean
            out.append(self.std_of(grad, covariance))
        return np.array(out)

    @property
    def nonlinear(self) -> np.ndarray:
        """The nonlinear parameters in the order of NONLINEAR, the sensor's at none (0) where not identified."""
        return np.array([*self.loop.time_constant_s, self.loop.delay_s, self.highpass_hz or 0.0,
                         self.winding_time_constant_s, self.torque_delay_s or 0.0])

    def sensor_response(self, harmonics: np.ndarray, speed_hz: float) -> np.ndarray:
        """The torque sensor's identified response per harmonic at a speed: high-pass and delay (1 without a
        sensor)."""
        phi = self.nonlinear
        return torque_sensor.sensor_response(2.0 * np.pi * np.asarray(harmonics, float) * speed_hz,
                                             phi[Phi.HIGHPASS], phi[Phi.TORQUE_DELAY])

    def cogging_table_nm(self, counts_per_rev: int) -> np.ndarray:
        """delta tau_c per count, N m (measured units): T on the cogging harmonics."""
        amplitudes = np.zeros(counts_per_rev // 2 + 1, complex)
        for h in self.cogging_harmonics:
            amplitudes[h] = self.position_table[h]
        return table_from_amplitudes(amplitudes, counts_per_rev)


def misfit_groups(fit: np.ndarray, pole_pairs: int, cogging_order: int) -> list[tuple[str, np.ndarray]]:
    """The harmonic families of the misfit test, each (label, mask over ``fit``), empty ones left out.

    1x and 2x electrical (where beta and the scale errors act), the cogging
    multiples, the other multiples of the pole pairs, and the excitation rest.
    """
    cogging = fit % cogging_order == 0
    electrical = (fit % pole_pairs == 0) & ~cogging
    first = np.isin(fit, (pole_pairs, 2 * pole_pairs)) & ~cogging
    families = (("electrical 1x-2x", first), ("cogging", cogging), ("other electrical", electrical & ~first),
                ("excitation", ~cogging & ~electrical))
    return [(label, mask) for label, mask in families if mask.any()]


def harmonic_sets(tables: BenchTables) -> HarmonicSets:
    """The harmonics of the joint fit (see `HarmonicSets`), from the data and bench.toml alone."""
    motor = tables.motor
    cpr = motor.counts_per_rev
    nyquist = cpr // 2 - 1
    i_ref = np.stack([t.i_ref_table_a for t in tables.trials])
    ideal = trial_amplitudes(i_ref * tables.backemf_nm_per_a, nyquist)
    size = np.abs(ideal[:, 1:]).max(axis=(0, 2))
    significant = np.flatnonzero(size > SIGNIFICANT * size.max()) + 1
    fit = np.arange(1, significant.max() + 1)
    backemf = np.abs(trial_amplitudes(tables.backemf_nm_per_a[None], nyquist)[0])
    has_backemf = backemf[1:].max(axis=1) > SIGNIFICANT * backemf[1:].max()
    # the encoder-derived torque holds the fit's band only (its noise grows as h^2 to h^4 beyond)
    top = nyquist if tables.torque_source.reads_sensor else int(fit.max())
    cogging = np.arange(motor.cogging_order, top + 1, motor.cogging_order)
    table_free = ~has_backemf[fit - 1] | np.isin(fit, cogging)
    return HarmonicSets(fit=fit, table_free=table_free, cogging=cogging)


class _JointProblem:
    """The weighted, position-table-profiled least-squares problem for given nonlinear parameters.

    ``phi`` holds the nonlinear parameters in the order of NONLINEAR.
    """

    def __init__(self, tables: BenchTables, sets: HarmonicSets) -> None:
        self.sets = sets
        self.backemf = tables.backemf_nm_per_a
        self.cpr = tables.motor.counts_per_rev
        self.pole_pairs = tables.motor.pole_pairs
        self.cogging_order = tables.motor.cogging_order
        self.max_fit = int(sets.fit.max())
        self.speeds = np.array([t.speed_hz for t in tables.trials])
        self.i_ref = np.stack([t.i_ref_table_a for t in tables.trials])
        self.count_period = np.ascontiguousarray(np.stack([t.count_period_s for t in tables.trials]))
        #: b: each count the mean over b lines (`ilcpmac.core.binning`); the staircase then runs line by line, and
        #: each phase's torque K_p i_p is formed at the lines (K_p there from its harmonics) before the count mean
        b = self.lines_per_count = tables.motor.lines_per_count
        self.line_period = self.count_period if b == 1 else np.ascontiguousarray(
            np.repeat(self.count_period / b, b, axis=1))
        # I*_p at every line then (`references_per_line`)
        self.backemf_lines, references = (self.backemf, self.i_ref) if b == 1 else references_per_line(
            self.i_ref, self.backemf, b)
        self.instants = count_instants(self.count_period)
        self.torque = np.stack([t.torque_table_nm for t in tables.trials])
        self.max_harmonic = int(max(self.max_fit, sets.cogging.max(initial=0)))
        self._cache: dict[str, dict] = {}
        #: the high-pass's speed-ripple part at harmonics 0..max_harmonic, taken off the data (`_ripple_highpass`)
        self.ripple_highpass: np.ndarray | None = None
        #: the last shift and its tables (`shifted`); the last loop parameters and their `loop_derivatives`
        self._shifted: tuple = (None,)
        self._loop_derivatives: tuple = (None,)
        self.variance = np.array([t.harmonic_variance_nm2 for t in tables.trials])
        self.sensor = tables.torque_source.reads_sensor
        #: the nonlinear parameters the data determine: without a sensor, not the sensor's, held at none
        self.identifiable = np.ones(len(NONLINEAR), bool) if self.sensor else ~SENSOR_PARAMETERS
        self.variances: np.ndarray | None = None
        if not self.sensor:  # the brake's b omega leaves the data, and enters through the columns (`amplitudes`)
            parts = [t.encoder_parts() for t in tables.trials]
            self.variances = np.stack([variances for variances, _, _ in parts])
            speed = np.stack([table for _, table, _ in parts])
            mean = speed.mean(axis=1, keepdims=True)
            self.torque = self.torque - np.array([[viscous] for _, _, viscous in parts]) * (speed - mean)
            self.speed_ripple = trial_amplitudes(speed[:, :, None], self.max_fit)[:, sets.fit, 0] / mean
        backemf_cols = trial_amplitudes(self.counted(self.backemf_lines.T).T[None], self.max_fit)[0][sets.fit]
        self.backemf_design = np.broadcast_to(backemf_cols, (len(tables.trials),) + backemf_cols.shape)
        # where T(h) is free it takes the offsets' torque, the same in every trial: only the other harmonics tell
        held = backemf_cols[~sets.table_free]
        self.common_offset = bool(held.size and np.linalg.norm(held.sum(axis=1))
                                  > SIGNIFICANT * np.linalg.norm(held, axis=0).max())
        # back-EMF per count, e_p = K_p omega (omega over the intervals either side of the count)
        omega = 4.0 * np.pi / (self.cpr * (self.count_period + np.roll(self.count_period, 1, axis=1)))
        self.emf = self.backemf * omega[:, :, None]
        # per phase, contiguous: the count recursion's input (`lagged_phase` copies any other)
        self.phase_i_ref, self.phase_emf = ([np.ascontiguousarray(a[:, :, p]) for p in range(3)]
                                            for a in (references, self.emf))

    @staticmethod
    def loop_of(phi: np.ndarray) -> CurrentLoop:
        return CurrentLoop(phi[list(TAU)], phi[Phi.DELAY])

    def data(self, phi: np.ndarray) -> np.ndarray:
        """Harmonic amplitudes 0..max_harmonic of the measured torque tables advanced by D s (phi's
        TORQUE_DELAY).

        The torque sensor's filter and sampling delay the measurement by D;
        advancing the data in time (cubic interpolation through the count
        instants) puts it back on the count instants of the model.
        """
        shift = phi[Phi.TORQUE_DELAY] if self.sensor else 0.0  # the encoder-derived torque is at the count instants
        data = self._cached("data", (shift,), lambda: trial_amplitudes(
            self.shifted(shift)[0][:, :, None], self.max_harmonic)[:, :, 0])
        return data if self.ripple_highpass is None else data - self.ripple_highpass

    def data_slope(self, phi: np.ndarray) -> np.ndarray:
        """The derivative of `data` with respect to D (phi's TORQUE_DELAY, the torque sensor's), per s."""
        delay = phi[Phi.TORQUE_DELAY]
        return self._cached("data_slope", (delay,), lambda: trial_amplitudes(
            self.shifted(delay)[1][:, :, None], self.max_harmonic)[:, :, 0])

    def shifted(self, shift_s: float) -> tuple[np.ndarray, np.ndarray]:
        """The torque tables advanced by ``shift_s`` and their derivative in it (`shifted_at`), both from one
        pass; the last shift's kept (a fit asks for the data, then for their slope at the same shift)."""
        if self._shifted[0] != shift_s:
            self._shifted = (shift_s, *shifted_at(self.torque, self.instants, shift_s))
        return self._shifted[1:]

    def highpass(self, phi: np.ndarray, harmonics: np.ndarray) -> np.ndarray:
        """The piezo sensor's first-order high-pass j w / (j w + w_c), shape (n_trials, len(harmonics)); 1
        for the encoder-derived torque."""
        omega = 2.0 * np.pi * self.speeds[:, None] * harmonics[None, :]
        if not self.sensor:
            return np.ones(omega.shape, complex)
        return torque_sensor.highpass(omega, phi[Phi.HIGHPASS])

    def variance_at(self, harmonics: np.ndarray) -> np.ndarray:
        """Variance of the real (and imaginary) part of each trial's ``harmonics``, shape (n_trials, len(harmonics))."""
        if self.variances is not None:
            return self.variances[:, harmonics]
        return np.broadcast_to(self.variance[:, None], (self.variance.size, len(harmonics)))

    def _cached(self, kind: str, key: tuple, compute):
        """Memoised per-phase columns: a finite-difference step changes one parameter at a time."""
        store = self._cache.setdefault(kind, {})
        if key not in store:
            if len(store) >= 32:
                store.pop(next(iter(store)))
            store[key] = compute()
        return store[key]

    def _decays(self, tau: float, delay: float, continuous: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The periods a table runs through the loop at, and `count_decay` and `sample_decay` there (each computed
        once per tau and delay): the references of a record of count means run line by line (b lines per count,
        `references_per_line`), anything else count by count."""
        b = 1 if continuous else self.lines_per_count
        period = self.count_period if b == 1 else self.line_period
        decay = self._cached(f"decay{b}", (tau,), lambda: count_decay(period, tau))
        sample = decay if continuous else self._cached(f"sample_decay{b}", (tau, delay), lambda: sample_decay(
            period, tau, delay))
        return period, decay, sample

    def lagged(self, x: np.ndarray, tau: float, delay: float, continuous: bool = False) -> np.ndarray:
        """`lagged_phase` with the decays of each tau (and delay) computed once: per count, or for the references
        of a record of count means per line (`_decays`)."""
        period, decay, sample = self._decays(tau, delay, continuous)
        return lagged_phase(x, period, tau, delay, continuous, (decay, sample))

    def counted(self, lines: np.ndarray) -> np.ndarray:
        """Per-line tables (last axis) as the record holds them: their count means; per-count ones as they are."""
        b = self.lines_per_count
        return lines if b == 1 else count_means(lines, b)

    def phase_current(self, phi: np.ndarray, p: int) -> np.ndarray:
        """G_p I*_p per count (per line for a record of count means), shape (n_trials, cpr b)."""
        tau, delay = phi[TAU[p]], phi[Phi.DELAY]
        return self._cached(f"current{p}", (tau, delay), lambda: self.lagged(self.phase_i_ref[p], tau, delay))

    def current_torque(self, phi: np.ndarray, p: int) -> np.ndarray:
        """K_p G_p I*_p per count as the record holds it, shape (n_trials, cpr)."""
        return self.counted(self.backemf_lines[:, p] * self.phase_current(phi, p))

    def cubic_torque(self, phi: np.ndarray, x: np.ndarray) -> np.ndarray:
        """sum_p K_p i_p^3 per count, i_p = theta_p G_p I*_p + beta*_p, shape (n_trials, cpr)."""
        terms = []
        for p in range(3):
            current = x[THETA[p]] * self.phase_current(phi, p) + x[BETA_STAR[p]]
            terms.append(self.backemf_lines[:, p] * (current * current * current))
        return self.counted(terms[0] + terms[1] + terms[2])

    def amplitudes(self, tables: np.ndarray) -> np.ndarray:
        """Fit-harmonic amplitudes of per-count torque tables (n_trials, cpr, m) -> (n_trials, n_fit, m).

        On the encoder-derived torque, a column's mean tau_0 also turns the brake b = tau_0 / omega_0
        (omega_0 the speed's mean over the angle): b omega_h = tau_0 omega_h / omega_0 leaves the speed
        ripple's torque, which the data no longer hold.
        """
        amplitudes = trial_amplitudes(tables, self.max_fit)
        if self.sensor:
            return amplitudes[:, self.sets.fit]
        return amplitudes[:, self.sets.fit] - amplitudes[:, :1] * self.speed_ripple[:, :, None]

    def rejected(self, phi: np.ndarray, p: int) -> np.ndarray:
        """(1 - G_p) e_p per count, shape (n_trials, cpr): what the loop lets through of its back-EMF."""
        tau, delay = phi[TAU[p]], phi[Phi.DELAY]

        def compute():
            emf = self.phase_emf[p]
            return emf - self.lagged(emf, tau, delay, continuous=True)

        return self._cached(f"rejected{p}", (tau, delay), compute)

    def phase_columns(self, phi: np.ndarray, p: int) -> np.ndarray:
        """Amplitudes of K_p G_p I*_p and of K_p W (1 - G_p) e_p, shape (n_trials, n_fit, 2)."""
        k = self.backemf[:, p]
        tau, delay, winding = phi[TAU[p]], phi[Phi.DELAY], phi[Phi.WINDING_TAU]
        current = self._cached(f"current_amplitude{p}", (tau, delay), lambda: self.amplitudes(
            self.current_torque(phi, p)[:, :, None]))
        emf = self._cached(f"emf_amplitude{p}", (tau, delay, winding), lambda: self.amplitudes(
            (k * self.lagged(self.rejected(phi, p), winding, 0.0, continuous=True))[:, :, None]))
        return np.concatenate([current, emf], axis=2)

    def lag_derivatives(self, x: np.ndarray, tau: float, delay: float,
                        continuous: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """The derivatives of `lagged`'s output with respect to tau and the delay (`_lag_derivatives`)."""
        period, decay, sample = self._decays(tau, delay, continuous)
        x = np.ascontiguousarray(x, float)
        d_tau, d_delay = np.empty(x.shape), np.empty(x.shape)
        _lag_derivatives(x, period, float(tau), float(delay), decay, sample, continuous, d_tau, d_delay)
        return d_tau, d_delay

    def loop_derivatives(self, phi: np.ndarray) -> np.ndarray:
        """Derivatives of the current and back-EMF columns (`phase_columns`) with respect to the loop's parameters,
        shape (n_trials, n_fit, 11): of K_p G_p I*_p with respect to tau_p (p = a, b, c), then T_d; of
        K_p W (1 - G_p) e_p with respect to tau_p; of sum_p K_p W (1 - G_p) e_p with respect to T_d and L/R.
        The last ones kept: the Gauss-Newton step of `fit_joint` starts where the lagged loop's fit took its last
        Jacobian."""
        key = tuple(phi[[*TAU, Phi.DELAY, Phi.WINDING_TAU]])
        if self._loop_derivatives[0] != key:
            current_tau, current_delay, emf_tau, emf_delay, emf_winding = [], [], [], [], []
            delay, winding_tau = phi[Phi.DELAY], phi[Phi.WINDING_TAU]

            def amplitudes(table: np.ndarray) -> np.ndarray:
                # one transform per table: a stack of them transforms slower than its parts
                return self.amplitudes(table[:, :, None])

            for p in range(3):
                k, tau = self.backemf[:, p], phi[TAU[p]]
                d_tau, d_delay = self.lag_derivatives(self.phase_i_ref[p], tau, delay)
                current_tau.append(amplitudes(self.counted(self.backemf_lines[:, p] * d_tau)))
                current_delay.append(amplitudes(self.counted(self.backemf_lines[:, p] * d_delay)))
                e_tau, e_delay = self.lag_derivatives(self.phase_emf[p], tau, delay, continuous=True)
                emf_tau.append(amplitudes(-k * self.lagged(e_tau, winding_tau, 0.0, continuous=True)))
                emf_delay.append(amplitudes(-k * self.lagged(e_delay, winding_tau, 0.0, continuous=True)))
                winding, _ = self.lag_derivatives(self.rejected(phi, p), winding_tau, 0.0, continuous=True)
                emf_winding.append(amplitudes(k * winding))
            columns = [*current_tau, *current_delay, *emf_tau, emf_delay[0] + emf_delay[1] + emf_delay[2],
                       emf_winding[0] + emf_winding[1] + emf_winding[2]]  # in the order of LoopDerivative
            self._loop_derivatives = (key, np.concatenate(columns, axis=2))
        return self._loop_derivatives[1]

    def design(self, phi: np.ndarray, saturation: np.ndarray | None) -> np.ndarray:
        """All linear columns (LINEAR, without saturation when None), shape (n_trials, n_fit, n_columns).

        The back-EMF column is sum_p K_p W (1 - G_p) e_p: the current loop's
        tracking error to its back-EMF disturbance e_p = K_p omega, through the
        winding W = 1 / (1 + s L / R) (its coefficient is -delta / R).
        """
        per_phase = [self.phase_columns(phi, p) for p in range(3)]
        parts = [*(c[:, :, :1] for c in per_phase), self.backemf_design,
                 sum(c[:, :, 1:] for c in per_phase)]
        if saturation is not None:
            parts.append(saturation[:, :, None])
        return np.concatenate(parts, axis=2)

    def model_counts(self, phi: np.ndarray, x: np.ndarray, table: dict) -> np.ndarray:
        """The modelled torque per count before the sensor, N m (measured), shape (n_trials, cpr): the columns'
        tables (`design`, the saturation's from ``x``) times ``x``, plus the position table ``table`` (T(h))."""
        torque = np.zeros(self.i_ref.shape[:2])
        for p in range(3):
            k = self.backemf[:, p]
            torque += (x[THETA[p]] * self.current_torque(phi, p)
                       + x[BETA_STAR[p]] * self.counted(self.backemf_lines[:, p])
                       + x[Column.EMF] * k * self.lagged(self.rejected(phi, p), phi[Phi.WINDING_TAU], 0.0,
                                                         continuous=True))
        torque -= x[Column.SATURATION] * self.cubic_torque(phi, x)
        amplitudes = np.zeros(self.cpr // 2 + 1, complex)
        for h, value in table.items():
            amplitudes[h] = value
        return torque + table_from_amplitudes(amplitudes, self.cpr)

    def saturation_column(self, phi: np.ndarray, x: np.ndarray) -> np.ndarray:
        """S_k = -DFT(sum_p K_p i_p^3), i_p = theta_p G_p I*_p + beta*_p, shape (n_trials, n_fit)."""
        return self.amplitudes(-self.cubic_torque(phi, x)[:, :, None])[:, :, 0]

    def weights(self, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """High-pass per trial and fit harmonic, and the weights |H_hp|^2 / variance."""
        hp = self.highpass(phi, self.sets.fit)
        return hp, np.abs(hp) ** 2 / self.variance_at(self.sets.fit)

    def weighted(self, phi: np.ndarray, design: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Data over the high-pass and columns, weighted, with T(h) profiled out, stacked real."""
        hp, weights = self.weights(phi)
        y = self.data(phi)[:, self.sets.fit] / hp
        free = self.sets.table_free
        y = y - free * _weighted_mean(y, weights)
        design = design - free[:, None] * _weighted_mean(design, weights[:, :, None])
        root = np.sqrt(weights)
        y = (root * y).ravel()
        design = (root[:, :, None] * design).reshape(-1, design.shape[2])
        return np.concatenate([y.real, y.imag]), np.concatenate([design.real, design.imag])

    def sensitivities(self, phi: np.ndarray, saturation: np.ndarray, x: np.ndarray, rest: np.ndarray,
                      active: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per ``active`` nonlinear parameter, the analytic derivatives the fit and its covariance need.

        Returns the derivative of the weighted residual at fixed linear
        parameters ``x`` (n_rows, n_active), and D'^T ``rest`` (n_columns,
        n_active; n_active 0 for the ideal loop on the encoder-derived
        torque), D' that of the weighted columns: the current and back-EMF
        columns through the count recursion's derivatives
        (`loop_derivatives`), the data through the derivative of their time
        shift, the high-pass through 1 / H_hp = 1 + w_c / (j w) and the
        weights |H_hp|^2 / variance = w^2 / ((w^2 + w_c^2) variance).

        With root = sqrt(w) and M the weighted mean over trials, `weighted`'s
        root (Q - free M(Q)) has the derivative root [dQ - free M(dQ) +
        d(log w) / 2 (Q - free M(Q)) - free M(d(log w) (Q - M(Q)))]
        (`_weighted_change`); a loop parameter moves one to four columns and
        neither the data nor the weights.
        """
        design = self.design(phi, saturation)
        hp, weights = self.weights(phi)
        weights = weights[:, :, None]
        root = np.sqrt(weights)
        free = self.sets.table_free[:, None]
        n_rows = 2 * design.shape[0] * design.shape[1]
        indices = np.flatnonzero(active)
        residuals, products = np.empty((n_rows, indices.size)), np.empty((design.shape[2], indices.size))
        for column, i in enumerate(indices.tolist()):
            d_y, d_columns = np.zeros(n_rows), np.zeros((n_rows, design.shape[2]))
            if (parameter := Phi(i)) in LOOP_COLUMNS:
                source, target = LOOP_COLUMNS[parameter]
                loop = self.loop_derivatives(phi)[:, :, source]
                d_columns[:, target] = _weighted_change(loop, weights, root, free)
            elif parameter == Phi.HIGHPASS and self.sensor:
                omega = 2.0 * np.pi * self.speeds[:, None] * self.sets.fit[None, :]
                corner = 2.0 * np.pi * phi[Phi.HIGHPASS]
                data = self.data(phi)[:, self.sets.fit]
                d_data = data * (2.0 * np.pi / (1j * omega))
                d_log_weight = (-4.0 * np.pi * corner / (omega**2 + corner**2))[:, :, None]
                d_y = _weighted_change(d_data[:, :, None], weights, root, free,
                                       ((data / hp)[:, :, None], d_log_weight))[:, 0]
                d_columns = _weighted_change(None, weights, root, free, (design, d_log_weight))
            elif parameter == Phi.TORQUE_DELAY and self.sensor:
                d_data = self.data_slope(phi)[:, self.sets.fit] / self.highpass(phi, self.sets.fit)
                d_y = _weighted_change(d_data[:, :, None], weights, root, free)[:, 0]
            residuals[:, column] = d_y - d_columns @ x
            products[:, column] = d_columns.T @ rest
        return residuals, products

    def jacobian(self, phi: np.ndarray, saturation: np.ndarray, active: np.ndarray,
                 solution: tuple | None = None) -> np.ndarray:
        """The derivative of `solve`'s residual with respect to the ``active`` nonlinear parameters.

        Variable projection (Golub and Pereyra): with F the weighted, constrained columns and r = y - F z the
        residual at the least-squares z, dr = (I - F F^+) (dy - dD x) - (F^+)^T dF^T r. ``solution``: `solution`
        at ``phi``, when the caller has it.
        """
        x, rest, design = self.solution(phi, saturation) if solution is None else solution
        residual, products = self.sensitivities(phi, saturation, x, rest, active)
        constraint = self.constraint(design.shape[1])
        free = self.constrained(design)
        scale = np.sqrt(np.sum(free**2, axis=0))
        scale[scale == 0.0] = 1.0
        free = free / scale
        coefficients = np.linalg.pinv(free.T @ free) @ (free.T @ residual + (constraint.T @ products) / scale[:, None])
        return residual - _tall_product(free, coefficients)

    def constraint(self, size: int) -> np.ndarray:
        """P, shape (size, size) or (size, size - 1): the parameters are P times the free ones.

        The identity, or where the common offset is not identified (module notes) beta*_c = -beta*_a - beta*_b.
        """
        if self.common_offset:
            return np.eye(size)
        constraint = np.delete(np.eye(size), Column.BETA_STAR_C, axis=1)
        constraint[Column.BETA_STAR_C, [Column.BETA_STAR_A, Column.BETA_STAR_B]] = -1.0
        return constraint

    def constrained(self, columns: np.ndarray) -> np.ndarray:
        """``columns`` times `constraint`: the free parameters' columns (``columns`` itself where P is the
        identity)."""
        return columns if self.common_offset else _tall_product(columns, self.constraint(columns.shape[1]))

    def solve(self, phi: np.ndarray, saturation: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """Linear parameters and the weighted residual vector at ``phi``."""
        return self.solution(phi, saturation)[:2]

    def solution(self, phi: np.ndarray, saturation: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`solve`'s linear parameters and residual, and the weighted columns they come from."""
        y, design = self.weighted(phi, self.design(phi, saturation))
        constraint = self.constraint(design.shape[1])
        free = self.constrained(design)
        scale = np.sqrt(np.sum(free**2, axis=0))
        scale[scale == 0.0] = 1.0
        x = constraint @ (np.linalg.lstsq((free.T @ free) / np.outer(scale, scale), (free.T @ y) / scale,
                                          rcond=None)[0] / scale)
        return x, y - design @ x, design

    def position_table(self, phi: np.ndarray, design: np.ndarray, x: np.ndarray) -> dict:
        """T(h) where free: the weighted mean over trials of what the columns leave, N m."""
        hp, weights = self.weights(phi)
        rest = _weighted_mean(self.data(phi)[:, self.sets.fit] / hp - design @ x, weights)[0]
        table = {int(h): complex(c) for h, c, free in zip(self.sets.fit, rest, self.sets.table_free) if free}
        beyond = self.sets.cogging[self.sets.cogging > self.max_fit]
        if beyond.size:
            hp = self.highpass(phi, beyond)
            mean = _weighted_mean(self.data(phi)[:, beyond] / hp, np.abs(hp) ** 2 / self.variance_at(beyond))[0]
            table.update({int(h): complex(c) for h, c in zip(beyond, mean)})
        return table


def time_shifted(tables: np.ndarray, count_period_s: np.ndarray, shift_s: float,
                 slope: bool = False) -> np.ndarray:
    """Periodic per-count tables (n_trials, cpr) evaluated at t_c + shift_s instead of t_c.

    The count instants t_c follow from the count periods; values in between
    come from four-point (cubic) Lagrange interpolation in time. ``slope``:
    the interpolant's derivative there (per second) instead, the derivative
    of the tables with respect to ``shift_s`` (at a count instant, the one
    towards later instants).
    """
    return shifted_at(tables, count_instants(count_period_s), shift_s)[1 if slope else 0]


def count_instants(count_period_s: np.ndarray) -> np.ndarray:
    """The count instants of `time_shifted` over three revolutions from -1 revolution, shape (n_trials, 3 cpr + 1)."""
    count_period_s = np.ascontiguousarray(count_period_s, float)
    out = np.empty((count_period_s.shape[0], 3 * count_period_s.shape[1] + 1))
    _instants_kernel(count_period_s, out)
    return out


def shifted_at(tables: np.ndarray, instants: np.ndarray, shift_s: float) -> tuple[np.ndarray, np.ndarray]:
    """`time_shifted`'s values and slopes, from one pass, with the `count_instants` of its count periods given."""
    out, out_slope = np.empty_like(tables, dtype=float), np.empty_like(tables, dtype=float)
    _time_shift_kernel(np.ascontiguousarray(tables, float), instants, float(shift_s), out, out_slope)
    return out, out_slope


@njit(cache=True)
def _instants_kernel(count_period_s, out):
    n_trials, cpr = count_period_s.shape
    for k in range(n_trials):
        out[k, 0] = -count_period_s[k].sum()
        for r in range(3):
            for c in range(cpr):
                out[k, r * cpr + c + 1] = out[k, r * cpr + c] + count_period_s[k, c]


@njit(cache=True)
def _time_shift_kernel(tables, instants, shift_s, out, out_slope):
    n_trials, cpr = tables.shape
    for k in range(n_trials):
        t = instants[k]  # over three revolutions, the middle one holding the target instants
        base = cpr
        for c in range(cpr):
            target = t[cpr + c] + shift_s
            while target < t[base] and base > 1:
                base -= 1
            while base < 3 * cpr - 2 and target >= t[base + 1]:
                base += 1
            t0, t1, t2, t3 = t[base - 1], t[base], t[base + 1], t[base + 2]
            d0, d1, d2, d3 = target - t0, target - t1, target - t2, target - t3
            # the weights, and their derivatives with respect to the target instant
            numerators = (d1 * d2 * d3, d0 * d2 * d3, d0 * d1 * d3, d0 * d1 * d2)
            slopes = (d2 * d3 + d1 * d3 + d1 * d2, d2 * d3 + d0 * d3 + d0 * d2,
                      d1 * d3 + d0 * d3 + d0 * d1, d1 * d2 + d0 * d2 + d0 * d1)
            denominators = ((t0 - t1) * (t0 - t2) * (t0 - t3), (t1 - t0) * (t1 - t2) * (t1 - t3),
                            (t2 - t0) * (t2 - t1) * (t2 - t3), (t3 - t0) * (t3 - t1) * (t3 - t2))
            first = (base - 1) % cpr
            value = 0.0
            slope = 0.0
            for i in range(4):
                index = first + i
                sample = tables[k, index - cpr if index >= cpr else index]
                value += numerators[i] / denominators[i] * sample
                slope += slopes[i] / denominators[i] * sample
            out[k, c] = value
            out_slope[k, c] = slope


@njit(cache=True)
def _lag_derivatives(x, dt, tau, delay, decay, sample_decay, continuous, d_tau, d_delay):
    """The derivatives of `lagged_phase`'s output (n_trials, cpr) with respect to tau and T_d; fills ``d_tau``
    and ``d_delay``.

    The count recursion of `ilcpmac.core.lag_kernel` (the same warm-up and
    steps, through its `_advance`) carried with its derivative in tau
    (forward mode, a = exp(-dt / tau), da / dtau = a dt / tau^2); the sampled
    staircase and, with ``continuous``, the linear interpolation between
    counts for T_d != 0 differentiated as `lagged_phase` applies them. At
    T_d = 0 the delay's derivative is the one for T_d >= 0 (its bound).
    """
    n_trials, cpr = x.shape
    lag = tau > 0.0
    inverse_tau2 = 1.0 / (tau * tau) if lag else 0.0
    delayed = delay >= 0.0
    state = np.empty(cpr)
    d_state = np.empty(cpr)
    for k in range(n_trials):
        start = warm_up_start(decay[k])
        s = x[k, start]
        ds = 0.0
        s_prev = s
        ds_prev = ds
        for c in range(start, 2 * cpr):
            now = c if c < cpr else c - cpr
            following = now + 1 if now + 1 < cpr else 0
            if c >= cpr:
                if not continuous:
                    if delayed:  # the state at t_c - T_d, between counts c - 1 and c
                        x_prev = x[k, now - 1]
                        b = sample_decay[k, now]
                        span = dt[k, now - 1] - delay
                        d_tau[k, now] = ds_prev * b
                        d_delay[k, now] = 0.0
                        if lag and span > 0.0:
                            d_tau[k, now] += (s_prev - x_prev) * b * span * inverse_tau2
                            d_delay[k, now] = (s_prev - x_prev) * b / tau
                    else:  # the state at t_c + |T_d|, after count c
                        b = sample_decay[k, now]
                        d_tau[k, now] = ds * b
                        d_delay[k, now] = 0.0
                        if lag:
                            d_tau[k, now] -= (s - x[k, now]) * b * delay * inverse_tau2
                            d_delay[k, now] = (s - x[k, now]) * b / tau
            a = decay[k, now]
            da = a * dt[k, now] * inverse_tau2
            x_now, x_next = x[k, now], x[k, following]
            if continuous:
                d_next = a * ds + da * (s - x_now) - (x_next - x_now) / dt[k, now] * ((1.0 - a) - tau * da)
            else:
                d_next = a * ds + (s - x_now) * da
            s_prev = s
            ds_prev = ds
            s = _advance(s, a, x_now, x_next, tau, dt[k, now], continuous)
            ds = d_next
            if c >= cpr and continuous:
                state[following] = s
                d_state[following] = ds
        if continuous:
            for c in range(cpr):
                before = c - 1 if c > 0 else cpr - 1
                after = c + 1 if c + 1 < cpr else 0
                if delay >= 0.0:  # lagged_phase's interpolation towards the previous count
                    d_tau[k, c] = d_state[c] - delay / dt[k, before] * (d_state[c] - d_state[before])
                    d_delay[k, c] = -(state[c] - state[before]) / dt[k, before]
                else:  # towards the next one
                    d_tau[k, c] = d_state[c] - delay / dt[k, c] * (d_state[after] - d_state[c])
                    d_delay[k, c] = -(state[after] - state[c]) / dt[k, c]


def _tall_product(tall: np.ndarray, narrow: np.ndarray) -> np.ndarray:
    """tall @ narrow, one matrix-vector product per column of ``narrow``: a matrix product of a tall matrix by a
    small one starts BLAS threads that cost far more than it saves (the same sums)."""
    return np.stack([tall @ column for column in narrow.T], axis=1)


def _weighted_mean(values: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Weighted mean over trials (axis 0), kept as a leading axis of length 1."""
    return np.sum(weights * values, axis=0, keepdims=True) / np.sum(weights, axis=0, keepdims=True)


def _weighted_change(change: np.ndarray | None, weights: np.ndarray, root: np.ndarray, free: np.ndarray,
                     weight_change: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """The derivative of `_JointProblem.weighted`'s output for the change ``change`` (n_trials, n_fit, m; None: 0)
    of its input and, in ``weight_change`` (None: none), that input ``value`` and the change ``d_log_weight`` of
    the log of its ``weights`` (``root`` their square root), stacked real, shape (2 n_trials n_fit, m)
    (`_JointProblem.sensitivities`)."""
    derivative = 0.0 if change is None else change - free * _weighted_mean(change, weights)
    if weight_change is not None:
        value, d_log_weight = weight_change
        mean = _weighted_mean(value, weights)
        derivative = derivative + d_log_weight / 2.0 * (value - free * mean) - free * _weighted_mean(
            d_log_weight * (value - mean), weights)
    derivative = (root * derivative).reshape(-1, np.shape(derivative)[2])
    return np.concatenate([derivative.real, derivative.imag])


def fit_joint(tables: BenchTables, initial_loop: CurrentLoop) -> JointEstimate:
    """The joint fit (module docstring), its loop started from ``initial_loop``.

    The report's ideal loop (currents equal to references at each count) is
    fitted too and kept unless the lagged loop, whose delay cannot be
    negative, fits better by more than its extra parameters' worth. On a
    torque sensor's data the fit is moved to the minimum of the data less the
    high-pass's speed-ripple part (`_ripple_highpass`, `_gauss_newton_step`).

    Raises
    ------
    IdentificationError
        With a single trial, or when the references carry no excitation that
        differs between trials (the mean torque is unobservable through the
        piezo sensor and T(h) absorbs what all trials share).
    """
    sets = harmonic_sets(tables)
    problem = _JointProblem(tables, sets)
    _check_excitation(problem)
    lagged = _fit_nonlinear(problem, initial_loop, problem.identifiable)
    ideal = _fit_nonlinear(problem, CurrentLoop(), SENSOR_PARAMETERS & problem.identifiable)
    # the lag must pay for its five more parameters (Akaike)
    _, phi, active, saturation, x, rest = lagged if lagged.rss + 2.0 * 5 < ideal.rss else ideal
    shared = _shared_rest(problem, phi, saturation, x)
    if shared.any():
        sets = replace(sets, table_free=sets.table_free | shared)
        problem = _JointProblem(tables, sets)
        _, phi, active, saturation, x, rest = _fit_nonlinear(problem, problem.loop_of(phi), active, phi)
    if problem.sensor:
        problem.ripple_highpass = _ripple_highpass(problem, phi, x, problem.position_table(
            phi, problem.design(phi, saturation), x))
        phi = _gauss_newton_step(problem, phi, active, saturation)
        x, rest = problem.solve(phi, saturation)
    design = problem.design(phi, saturation)
    covariance, bound, names, chi2, misfit = _covariance(problem, phi, active, saturation, x, rest)
    structure = _gain_structure(problem, phi, saturation, rest, covariance)
    covariance = covariance.copy()
    covariance[:GAINS, :GAINS] += structure.covariance
    # B I B with I >= 0, plus a structure >= 0: a negative diagonal is round-off about zero (-1.7e-15 against 886)
    std = dict(zip(names, np.sqrt(np.maximum(np.diag(covariance), 0.0))))
    return JointEstimate(
        theta=x[list(THETA)], theta_std=np.array([std[LINEAR[c]] for c in THETA]),
        beta_star_a=x[list(BETA_STAR)], beta_star_std=np.array([std[LINEAR[c]] for c in BETA_STAR]),
        saturation_per_a2=float(x[Column.SATURATION]), saturation_std=float(std["saturation"]),
        loop=problem.loop_of(phi),
        loop_std=np.array([std.get(NONLINEAR[i], 0.0) for i in (*TAU, Phi.DELAY)]),
        highpass_hz=float(phi[Phi.HIGHPASS]) if problem.sensor else None,
        highpass_std=float(std["highpass_hz"]) if problem.sensor else None,
        winding_time_constant_s=float(phi[Phi.WINDING_TAU]),
        torque_delay_s=float(phi[Phi.TORQUE_DELAY]) if problem.sensor else None,
        emf_gain=float(x[Column.EMF]), emf_gain_std=float(std["emf"]),
        position_table=problem.position_table(phi, design, x), cogging_harmonics=sets.cogging,
        covariance=covariance, bound_covariance=bound, parameter_names=names, chi2_reduced=chi2, misfit=misfit,
        gain_structure=structure, sets=sets, common_offset_identified=problem.common_offset)


class NonlinearFit(NamedTuple):
    """What `_fit_nonlinear` ends at."""

    rss: float  # the weighted residual sum of squares
    phi: np.ndarray  # the nonlinear parameters (`Phi`)
    active: np.ndarray  # which of them were fitted
    saturation: np.ndarray  # the saturation column
    x: np.ndarray  # the linear parameters (`Column`)
    rest: np.ndarray  # the weighted residual


def _fit_nonlinear(problem: _JointProblem, loop: CurrentLoop, active: np.ndarray,
                   start: np.ndarray | None = None) -> NonlinearFit:
    """Variable projection over the ``active`` nonlinear parameters, started from ``loop``, or from ``start`` (all
    of phi, a fit's) when given.

    The saturation column is built from the currents of the starting point,
    and rebuilt once from the fitted ones. The Jacobian is analytic
    (`_JointProblem.jacobian`). The parameters not ``active`` keep their
    starting values: ``loop``'s, L / R at 1 ms, no high-pass, no torque delay.

    Returns the `NonlinearFit`.
    """
    from scipy.optimize import least_squares  # 0.35 s to import: only when fitting

    if start is not None:
        phi = start.copy()
    else:  # loop's, its delay within its bound where fitted, a 0.01 Hz corner where fitted, L / R 1 ms, no delay
        phi = np.zeros(len(Phi))
        phi[list(TAU)] = loop.time_constant_s
        phi[Phi.DELAY] = max(loop.delay_s, 0.0) if active[Phi.DELAY] else loop.delay_s
        phi[Phi.HIGHPASS] = 0.01 if active[Phi.HIGHPASS] else 0.0
        phi[Phi.WINDING_TAU] = 1e-3
    lower = NONLINEAR_LOWER[active]
    saturation = problem.saturation_column(phi, problem.solve(phi, None)[0])

    def full(free: np.ndarray) -> np.ndarray:
        out = phi.copy()
        out[active] = free
        return out

    last: dict = {}  # the residual's solution, for the Jacobian scipy asks for at the same point

    def residual(free: np.ndarray) -> np.ndarray:
        last.update(free=free.copy(), solution=problem.solution(full(free), saturation))
        return last["solution"][1]

    def jacobian(free: np.ndarray) -> np.ndarray:
        known = last["solution"] if "free" in last and np.array_equal(free, last["free"]) else None
        return problem.jacobian(full(free), saturation, active, known)

    if active.any():
        phi[active] = least_squares(residual, np.maximum(phi[active], lower), jac=jacobian, bounds=(lower, np.inf),
                                    x_scale=NONLINEAR_SCALE[active], method="trf", ftol=1e-6, xtol=1e-6).x
    saturation = problem.saturation_column(phi, problem.solve(phi, saturation)[0])
    x, rest = problem.solve(phi, saturation)
    return NonlinearFit(float(rest @ rest), phi, active, saturation, x, rest)


def _shared_rest(problem: _JointProblem, phi: np.ndarray, saturation: np.ndarray, x: np.ndarray) -> np.ndarray:
    """Where the trials share a residual at a harmonic with back-EMF content, T(h) not free there: a
    position-locked torque at an electrical order that no column holds (an unexplained disturbance), which the
    fit would otherwise put into the back-EMF's and the winding's parameters; mask over ``problem.sets.fit``.

    Per such harmonic but 1x electrical (where beta is read: a disturbance there is beta's, and not separable),
    with r_k trial k's residual, w_k its weight and m their weighted mean,

        F = (|m|^2 sum_k w_k / 2) / (sum_k w_k |r_k - m|^2 / (2 (n - 1))),

    the shared part over the trials' own scatter, is tested against the F(2, 2 (n - 1)) quantile at
    1 - SHARED_FALSE_ALARM / (the harmonics tested). Not on the encoder-derived torque: a position-locked
    residual there is first the encoder's own line errors, which `ilcpmac.identify.encoder` estimates from what
    this fit leaves (freed, a mirrored encoder-only seed bench's eps went from 0.04 % to 0.45 % off).
    """
    from scipy.special import fdtri  # deferred with scipy.optimize: only when fitting

    sets = problem.sets
    tested = ~sets.table_free & (sets.fit != problem.pole_pairs)
    n_trials = problem.speeds.size
    if not problem.sensor or not tested.any() or n_trials < 3:
        return np.zeros(sets.fit.shape, bool)
    hp, weights = problem.weights(phi)
    residual = problem.data(phi)[:, sets.fit] / hp - problem.design(phi, saturation) @ x
    mean = _weighted_mean(residual, weights)
    shared = np.abs(mean[0]) ** 2 * weights.sum(axis=0) / 2.0
    scatter = np.sum(weights * np.abs(residual - mean) ** 2, axis=0) / (2.0 * (n_trials - 1))
    quantile = fdtri(2.0, 2.0 * (n_trials - 1), 1.0 - SHARED_FALSE_ALARM / tested.sum())
    return tested & (shared > quantile * scatter)


def _ripple_highpass(problem: _JointProblem, phi: np.ndarray, x: np.ndarray, table: dict) -> np.ndarray:
    """What the sensor's high-pass in time adds to H_s(h f_k) m_h with the speed rippling, per trial and
    harmonic 0..max_harmonic (non-zero at the fit harmonics), N m.

    The piezo's output is y = m - z, dz/dt = w_c (m - z), in time: with the
    modelled torque per count m (`model_counts`, linear between counts) and
    the measured count intervals, z is the periodic steady state of the lag
    recursion of tau = 1 / w_c (`periodic_lag`), and

        c_h = DFT(m - z)_h - H_s(h f_k) DFT(m)_h,

    zero at a constant speed; to first order -(w_c / (j h w_0)) (eps m)_h
    with eps the relative speed ripple. It is second order (w_c / w times the
    ripple), so the first fit's parameters give it to well within the noise.
    """
    fit = problem.sets.fit
    out = np.zeros((problem.speeds.size, problem.max_harmonic + 1), complex)
    if not phi[Phi.HIGHPASS] > 0.0:  # no high-pass
        return out
    torque = problem.model_counts(phi, x, table)
    output = torque - periodic_lag(torque, problem.count_period, 1.0 / (2.0 * np.pi * phi[Phi.HIGHPASS]))
    amplitudes = trial_amplitudes(np.stack([output, torque], axis=2), problem.max_fit)[:, fit]
    out[:, fit] = amplitudes[:, :, 0] - problem.highpass(phi, fit) * amplitudes[:, :, 1]
    return out


def _gauss_newton_step(problem: _JointProblem, phi: np.ndarray, active: np.ndarray,
                       saturation: np.ndarray) -> np.ndarray:
    """The nonlinear parameters ``phi`` moved to the minimum of the data less `_ripple_highpass`'s part.

    ``phi`` minimises |r|^2 on the data with the ripple part; taking it off changes the data by dy, small
    (second order), and moves the minimum by the Gauss-Newton step (variable projection, J =
    `_JointProblem.jacobian`)

        d phi = -(J^T J)^-1 J^T r(phi),

    r the weighted residual on the corrected data: to first order in dy the minimum a second nonlinear
    fit finds (beta* within 0.02 mA of it, noise-free, at a tenth of its time). The first fit had absorbed
    the ripple part in the loop's and the torque's delays (the step: +3 to +5 us and -4 to -5 us with the
    PI loop at 80 Hz) and moved beta* with them. Kept within NONLINEAR_LOWER.
    """
    solution = problem.solution(phi, saturation)
    jac = problem.jacobian(phi, saturation, active, solution) * NONLINEAR_SCALE[active]
    step = np.linalg.lstsq(jac, -solution[1], rcond=None)[0] * NONLINEAR_SCALE[active]
    out = phi.copy()
    out[active] = np.maximum(phi[active] + step, NONLINEAR_LOWER[active])
    return out


def _check_excitation(problem: _JointProblem) -> None:
    """The theoretical torque sum_p K_p I*_p must ripple beyond what all trials share."""
    if problem.i_ref.shape[0] < 2:
        raise IdentificationError(
            "total system gain (joint fit): a single trial - the current response can only be told from the "
            "position-locked torque (cogging and the rest) by trials with different excitation")
    total = problem.amplitudes(np.sum(problem.i_ref * problem.backemf, axis=2)[:, :, None])[:, :, 0]
    varying = total - total.mean(axis=0, keepdims=True)
    if np.sqrt(np.mean(np.abs(varying) ** 2)) < 3.0 * np.sqrt(problem.variance_at(problem.sets.fit).mean()):
        raise IdentificationError(
            "total system gain (joint fit): no excitation - the current references do not ripple beyond "
            "what every trial shares, and the piezo sensor cannot see the mean torque")


def _covariance(problem: _JointProblem, phi: np.ndarray, active: np.ndarray, saturation: np.ndarray,
                x: np.ndarray, rest: np.ndarray) -> tuple[np.ndarray, np.ndarray, tuple, float, tuple]:
    """The group-scaled covariance over the linear and active nonlinear parameters, and its bound.

    J holds the weighted, T-profiled linear columns and the derivatives of the
    weighted residual with respect to each active nonlinear parameter at fixed
    linear parameters (`_JointProblem.sensitivities`); B = (J^T J)^-1 is the Cramer-Rao bound (the weights hold
    the noise variance measured off the aperiodic part). Each harmonic family g
    (`misfit_groups`) has its reduced chi-square chi2_g; the covariance is

        C = B (sum_g max(chi2_g, 1) J_g^T J_g) B,

    so a parameter is inflated by the misfit of the harmonics that determine
    it, and C = B where every family fits to its noise.

    Returns (C, B, parameter names, overall reduced chi-square, the `MisfitGroup`s).
    """
    _, design = problem.weighted(phi, problem.design(phi, saturation))
    columns = [design, -problem.sensitivities(phi, saturation, x, rest, active)[0]]
    names = list(LINEAR) + [NONLINEAR[i] for i in np.flatnonzero(active)]
    constraint = problem.constraint(sum(c.shape[1] for c in columns))
    jac = problem.constrained(np.hstack(columns))
    bound = np.linalg.pinv(jac.T @ jac)
    n_trials, n_fit = problem.variance.shape[0], problem.sets.fit.size
    per_harmonic = np.sum(rest.reshape(2, n_trials, n_fit) ** 2, axis=(0, 1))
    jac_per_harmonic = jac.reshape(2, n_trials, n_fit, -1)
    groups, information = [], np.zeros_like(bound)
    for label, members in misfit_groups(problem.sets.fit, problem.pole_pairs, problem.cogging_order):
        part = jac_per_harmonic[:, :, members].reshape(-1, jac.shape[1])
        # T(h) takes one complex value where free; the parameters take their leverage trace(B J_g^T J_g)
        dof = 2 * (n_trials * members.sum() - (members & problem.sets.table_free).sum()) - np.trace(
            bound @ part.T @ part)
        chi2 = float(per_harmonic[members].sum() / dof)
        scale = max(chi2, 1.0)
        information += scale * (part.T @ part)
        alone = bound @ (jac.T @ jac + (scale - 1.0) * (part.T @ part)) @ bound
        seen = np.diag(bound) > 0  # a parameter the data do not move (a zero column) has no error to widen
        inflation = float(np.sqrt(np.max(np.diag(alone)[seen] / np.diag(bound)[seen], initial=1.0)))
        groups.append(MisfitGroup(label, problem.sets.fit[members], chi2, float(dof), inflation))
    dof = jac.shape[0] - jac.shape[1] - 2 * int(problem.sets.table_free.sum())
    covariance = constraint @ bound @ information @ bound @ constraint.T
    return covariance, constraint @ bound @ constraint.T, tuple(names), float(rest @ rest / dof), tuple(groups)


def _gain_structure(problem: _JointProblem, phi: np.ndarray, saturation: np.ndarray, rest: np.ndarray,
                    covariance: np.ndarray) -> GainStructure:
    """theta_p and beta*_p fitted on parts of the data, the other parameters held; their structure.

    On a part j (a block of the excitation harmonics, all trials; or one trial, all harmonics) the
    weighted, T-profiled columns D_j of the parameters and the residual r_j give the shift
    d_j = (D_j^T D_j)^-1 D_j^T r_j and its noise covariance E_j = (D_j^T D_j)^-1: theta alone on the
    blocks (beta* lives at a few electrical harmonics), theta and beta* per set point. Where
    delta*eps = mean_p theta_p (or a beta*_p) drifts over the parts beyond E_j (`structure_variance`;
    blocks: the halves or blocks of ceil(sqrt(n)), whichever finds more), the structure's covariance
    sum_j w_j (d_j d_j^T - E_j) / sum_j w_j (w_j the part's information on delta*eps; its negative
    part dropped) joins the fit's: it does not average out over the parts.
    """
    _, design = problem.weighted(phi, problem.design(phi, saturation))
    n_trials, n_fit = problem.variance.shape[0], problem.sets.fit.size
    columns = design[:, :GAINS].reshape(2, n_trials, n_fit, GAINS)
    residual = rest.reshape(2, n_trials, n_fit)
    excitation = dict(misfit_groups(problem.sets.fit, problem.pole_pairs, problem.cogging_order)).get("excitation")
    members = np.flatnonzero(excitation) if excitation is not None else np.zeros(0, int)
    mean = np.full(3, 1.0 / 3.0)

    def structure(parts: list, size: int) -> tuple[float, np.ndarray]:
        """The largest chi2/dof over the tested quantities, and the structure's covariance (size x size)."""
        shift_rows, noise_rows = [], []
        constraint = problem.constraint(size) if size == GAINS else np.eye(size)
        for d, r in parts:
            d = d @ constraint
            noise = np.linalg.pinv(d.T @ d)
            shift_rows.append(constraint @ noise @ d.T @ r)
            noise_rows.append(constraint @ noise @ constraint.T)
        shifts, noises = np.array(shift_rows), np.array(noise_rows)
        tests = [mean] + [np.eye(size)[c] for c in range(len(THETA), size)]
        expected_gain = np.einsum("i,bij,j->b", mean, noises[:, :len(THETA), :len(THETA)], mean)
        if len(parts) < 2 or not np.all(expected_gain > 0.0):
            return 0.0, np.zeros((size, size))
        found, q_max = False, 0.0
        for g in tests:
            g = g[:size] if g.size >= size else np.concatenate([g, np.zeros(size - g.size)])
            expected = np.einsum("i,bij,j->b", g, noises, g)
            if not np.all(expected > 0.0):
                continue
            variance, q = structure_variance(shifts @ g, expected, 1.0 / expected)
            found, q_max = found or variance > 0.0, max(q_max, q)
        if not found:
            return q_max, np.zeros((size, size))
        excess = np.average(shifts[:, :, None] * shifts[:, None, :] - noises, axis=0, weights=1.0 / expected_gain)
        values, vectors = np.linalg.eigh(excess)
        return q_max, (vectors * np.maximum(values, 0.0)) @ vectors.T

    q_harmonics, excess_harmonics = 0.0, np.zeros((len(THETA), len(THETA)))
    for size in {members.size // 2, int(np.ceil(np.sqrt(members.size)))}:
        if size < 1 or members.size // size < 2:
            continue
        blocks = members[: members.size // size * size].reshape(-1, size)
        q, excess = structure([(columns[:, :, b, :len(THETA)].reshape(-1, len(THETA)), residual[:, :, b].ravel())
                               for b in blocks], len(THETA))
        if mean @ excess @ mean >= mean @ excess_harmonics @ mean:
            q_harmonics, excess_harmonics = max(q, q_harmonics), excess
    q_set_points, excess = structure([(columns[:, k].reshape(-1, GAINS), residual[:, k].ravel())
                                      for k in range(n_trials)], GAINS)
    excess[:len(THETA), :len(THETA)] += excess_harmonics
    fitted = covariance[:GAINS, :GAINS]
    gain = np.concatenate([mean, np.zeros(len(BETA_STAR))])
    ratios = [(g @ (fitted + excess) @ g) / (g @ fitted @ g) for g in (gain, *np.eye(GAINS)[len(THETA):])
              if g @ fitted @ g > 0.0]
    return GainStructure(problem.sets.fit[members], (q_harmonics, q_set_points), excess,
                         float(np.sqrt(max(ratios, default=1.0))))


def fitted_columns_nm(tables: BenchTables, estimate: JointEstimate) -> np.ndarray:
    """The joint model of ``tables``' torque less the position table T, per trial at ``estimate.sets.fit``.

    The current, back-EMF and saturation columns at the fitted nonlinear parameters, the linear ones
    solved again there, through the sensor's response, N m (measured), shape (n_trials, n_fit): what the
    trials do not share.
    """
    problem = _JointProblem(tables, estimate.sets)
    phi = estimate.nonlinear
    saturation = problem.saturation_column(phi, np.concatenate([estimate.theta, estimate.beta_star_a]))
    x, _ = problem.solve(phi, saturation)
    return problem.highpass(phi, estimate.sets.fit) * (problem.design(phi, saturation) @ x)


def modelled_mean_nm(tables: BenchTables, estimate: JointEstimate) -> tuple[np.ndarray, np.ndarray]:
    """The mean torque of each trial of ``tables`` by the joint model before the sensor, N m (measured), and its
    standard error from the covariance of the linear parameters, shape (n_trials,) each.

    The model's torque per count (`_JointProblem.model_counts`, the position table left out: its mean is not
    fitted) at h = 0, which the piezo does not see and the fit does not use: the currents through the loop times
    theta, the offsets' beta*, the back-EMF's tracking error K_p W (1 - G_p) e_p (the mean torque the loop loses
    with speed) and the saturation. Its derivative with respect to each linear parameter is taken by a step of
    1e-6 of its size (the saturation's column depends on them); the nonlinear parameters' error is left out.
    """
    problem = _JointProblem(tables, estimate.sets)
    phi = estimate.nonlinear
    x = np.concatenate([estimate.theta, estimate.beta_star_a, [estimate.emf_gain, estimate.saturation_per_a2]])
    mean = problem.model_counts(phi, x, {}).mean(axis=1)
    names = [name for name in LINEAR if name in estimate.parameter_names]
    slopes = np.empty((mean.size, len(names)))
    for k, name in enumerate(names):
        i = LINEAR.index(name)
        step = 1e-6 * max(abs(float(x[i])), 1e-3)
        moved = x.copy()
        moved[i] += step
        slopes[:, k] = (problem.model_counts(phi, moved, {}).mean(axis=1) - mean) / step
    rows = [estimate.parameter_names.index(name) for name in names]
    covariance = estimate.covariance[np.ix_(rows, rows)]
    return mean, np.sqrt(np.maximum(np.einsum("ti,ij,tj->t", slopes, covariance, slopes), 0.0))
