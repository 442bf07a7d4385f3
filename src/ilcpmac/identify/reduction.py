"""Each trial reduced to one mechanical revolution (the report's "harmonics domain", sec. 2.3).

A trial is sampled once per encoder count, so over whole revolutions its
repeatable part is a per-count table and its DFT gives harmonics of the
mechanical revolution. The piezo torque sensor adds an unknown DC level and a
slow drift (sec. 1.1): the drift is fitted to the part of the torque that is
not periodic in position (`ilcpmac.signals.harmonics.slow_trend`) and removed
before averaging, so neither can bias an estimate; what is left over gives the
noise variance that weights every fit. Without a torque sensor the torque
comes from the encoder's time stamps instead (`ilcpmac.identify.encoder`).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ilcpmac.bench.format import Bench, check_backemf, check_trial
from ilcpmac.core.binning import noise_gain
from ilcpmac.core.errors import BenchFormatError, IdentificationError
from ilcpmac.core.records import MotorInfo, TrialData
from ilcpmac.core.torque_source import TorqueSource
from ilcpmac.signals.harmonics import (
    every_count,
    harmonic_amplitudes,
    slow_trend,
    synchronous_table,
    whole_revolution_span,
)

#: Highest Legendre degree of the torque sensor's slow trend (linear drift and slow settling).
TREND_DEGREE = 5
#: a torque whose scatter about its revolutions' mean (RMS) is within this much of its largest value, 16 double
#: roundings, repeats exactly: no sensor's reading (a noise-free simulation still scatters 1e-3 of its torque)
EXACT_REPEAT = 16 * np.finfo(float).eps
#: what numpy and scipy raise on degenerate data (collinear or constant columns, NaN from a division by zero)
NUMERICAL_FAILURES = (np.linalg.LinAlgError, ValueError, FloatingPointError, ZeroDivisionError)


def degenerate(error: Exception) -> str:
    """One line for a numerical failure (`NUMERICAL_FAILURES`) on degenerate data."""
    first = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
    return f"degenerate data - constant, collinear or non-finite columns ({first[:120]})"


@dataclass(frozen=True)
class TrialTables:
    """One trial over its whole revolutions, and its synchronous averages.

    Attributes
    ----------
    torque_setpoint_nm, speed_setpoint_hz : float
        The set point, as listed in bench.toml.
    speed_hz : float
        Mean mechanical speed over the whole revolutions, Hz.
    revolutions : int
        Whole revolutions used.
    count, time_s : ndarray, shape (n,)
        The samples in whole revolutions.
    torque_nm : ndarray, shape (n,)
        Measured torque there with the sensor's slow trend removed, N m.
    torque_table_nm : ndarray, shape (counts_per_rev,)
        Synchronous average of ``torque_nm`` per encoder count, N m.
    i_ref_table_a : ndarray, shape (counts_per_rev, 3)
        Synchronous average of the current references I*_p, A.
    count_period_s : ndarray, shape (counts_per_rev,)
        Mean time from each count to the next, s (from the synchronous average
        of the time stamps: the speed ripple, 2 pi / (counts_per_rev dt) rad/s).
    noise_variance_nm2 : float
        Per-sample variance of the torque that is neither periodic nor trend, N^2 m^2.
    harmonic_variance_nm2 : float
        Variance of the real (and of the imaginary) part of one harmonic
        amplitude of ``torque_table_nm`` due to that noise, N^2 m^2.
    harmonic_variances_nm2 : ndarray, shape (H + 1,), or None
        The same per harmonic 0..H where it depends on the harmonic (the encoder-derived torque, whose
        ``torque_table_nm`` holds harmonics 1..H only); None: ``harmonic_variance_nm2`` at every harmonic.
    speed_table_rad_s : ndarray, shape (counts_per_rev,), or None
        The encoder-derived torque's mechanical speed per count, harmonics 0..H, rad/s (its mean: over the angle).
    viscous_nm_s : float or None
        The brake b whose torque b omega ``torque_table_nm`` includes (encoder-derived), N m s/rad.
    """

    torque_setpoint_nm: float
    speed_setpoint_hz: float
    speed_hz: float
    revolutions: int
    count: np.ndarray
    time_s: np.ndarray
    torque_nm: np.ndarray
    torque_table_nm: np.ndarray
    i_ref_table_a: np.ndarray
    count_period_s: np.ndarray
    noise_variance_nm2: float
    harmonic_variance_nm2: float
    harmonic_variances_nm2: np.ndarray | None = None
    speed_table_rad_s: np.ndarray | None = None
    viscous_nm_s: float | None = None

    def encoder_parts(self) -> tuple[np.ndarray, np.ndarray, float]:
        """``harmonic_variances_nm2``, ``speed_table_rad_s`` and ``viscous_nm_s`` of a trial reduced on the
        encoder-derived torque.

        Raises
        ------
        IdentificationError
            When it lacks one (a trial reduced on the sensor's torque).
        """
        if self.harmonic_variances_nm2 is None or self.speed_table_rad_s is None or self.viscous_nm_s is None:
            raise IdentificationError(f"trial at {self.torque_setpoint_nm:g} N m, {self.speed_setpoint_hz:g} Hz: "
                                      "not reduced on the encoder-derived torque")
        return self.harmonic_variances_nm2, self.speed_table_rad_s, self.viscous_nm_s


@dataclass(frozen=True)
class BenchTables:
    """A bench folder reduced trial by trial.

    Attributes
    ----------
    motor : MotorInfo
    backemf_nm_per_a : ndarray, shape (counts_per_rev, 3)
        K per phase and count, N m / A.
    trials : tuple of TrialTables
        The trials that could be reduced.
    trial_files : tuple of str
        Their file names.
    messages : tuple of str
        Why other trials were left out.
    torque_source : TorqueSource
        SENSOR: the torque sensor's, through its gain delta, high-pass and delay; ENCODER: the true
        torque from the encoder's time stamps (`ilcpmac.identify.encoder`), through none of them.
    """

    motor: MotorInfo
    backemf_nm_per_a: np.ndarray
    trials: tuple[TrialTables, ...]
    trial_files: tuple[str, ...]
    messages: tuple[str, ...]
    torque_source: TorqueSource = TorqueSource.SENSOR


def reduce_trial(trial: TrialData, counts_per_rev: int, lines_per_count: int = 1) -> TrialTables:
    """Reduce one trial: whole revolutions, slow trend removed, synchronous averages; a harmonic's variance from the
    rows' scatter, as a record of count means over ``lines_per_count`` lines holds it (`noise_gain`).

    Raises
    ------
    IdentificationError
        With fewer than two whole revolutions: the sensor's drift cannot then
        be told from the ripple; and for a torque whose scatter about its
        revolutions' mean is none (`EXACT_REPEAT`): it weighs a fit by that scatter.
    """
    span = whole_revolution_span(trial.count, counts_per_rev)
    count, time_s = trial.count[span], trial.time_s[span]
    revolutions = int(np.count_nonzero(np.diff(count // counts_per_rev))) + 1 if count.size else 0  # count increases
    if revolutions < 2:
        raise IdentificationError(
            f"{revolutions} whole revolution(s); at least 2 are needed to tell the torque sensor's drift "
            "from the ripple")
    if trial.torque_nm is None:
        raise IdentificationError("no torque column (a bench without a torque sensor): identify it with the "
                                  "encoder-derived torque")
    degree = min(TREND_DEGREE, revolutions - 1)
    torque = trial.torque_nm[span]
    trend, noise_variance = slow_trend(count, time_s, torque, counts_per_rev, degree)
    if noise_variance <= (EXACT_REPEAT * np.abs(torque).max()) ** 2:
        raise IdentificationError("the torque repeats exactly from revolution to revolution, without noise: no "
                                  "sensor reads that (a current reference, or an exact table, in the torque column?)")
    torque = torque - trend
    speed_hz, i_ref_table, count_period = revolution_averages(count, time_s, trial.i_ref_a[span], counts_per_rev)
    return TrialTables(
        torque_setpoint_nm=trial.torque_setpoint_nm, speed_setpoint_hz=trial.speed_setpoint_hz,
        speed_hz=speed_hz, revolutions=revolutions, count=count, time_s=time_s,
        torque_nm=torque,
        torque_table_nm=synchronous_table(count, torque, counts_per_rev),
        i_ref_table_a=i_ref_table,
        count_period_s=count_period,
        noise_variance_nm2=noise_variance,
        harmonic_variance_nm2=2.0 * noise_variance * mean_inverse_hits(count, counts_per_rev) / counts_per_rev
        * noise_gain(lines_per_count),
    )


def mean_inverse_hits(count: np.ndarray, counts_per_rev: int) -> float:
    """The mean over the counts of a revolution of 1 / (samples at that count): a synchronous average's
    noise per harmonic is 2 sigma^2 times this over counts_per_rev."""
    hits = np.bincount(count % counts_per_rev, minlength=counts_per_rev)
    return float(np.mean(1.0 / np.maximum(hits, 1)))


def revolution_averages(count: np.ndarray, time_s: np.ndarray, i_ref_a: np.ndarray,
                        counts_per_rev: int) -> tuple[float, np.ndarray, np.ndarray]:
    """The mean speed (Hz), the synchronous average of the current references (counts_per_rev, 3), A, and the
    mean time from each count to the next (counts_per_rev,), s, of samples in whole revolutions.

    The time of each count over one mean revolution is the mean revolution's slope plus the averaged wobble
    (speed ripple), so that revolutions missing a count (skipped) do not bias the average. The slope is the
    mean of t(c + counts_per_rev) - t(c) over the counts recorded a revolution apart: a straight line
    fitted through a few revolutions with a strong speed ripple would tilt with the ripple's phase, and
    make the period at the wrap wrong, even negative.

    Raises `IdentificationError` when a mean count period is not positive (a trial of too few revolutions
    for its speed ripple).
    """
    # every count of whole revolutions sampled (as a simulator records): the count a revolution later is there
    later = np.arange(count.size) + counts_per_rev if every_count(count, counts_per_rev) else np.searchsorted(
        count, count + counts_per_rev)
    paired = later < count.size
    paired[paired] = count[later[paired]] == count[paired] + counts_per_rev
    seconds_per_count = float(np.mean(time_s[later[paired]] - time_s[paired])) / counts_per_rev
    wobble = synchronous_table(count, time_s - time_s[0] - seconds_per_count * (count - count[0]), counts_per_rev)
    time_table = wobble + seconds_per_count * np.arange(counts_per_rev)
    count_period_s = np.diff(time_table, append=time_table[0] + seconds_per_count * counts_per_rev)
    if not np.all(count_period_s > 0):
        worst = int(np.argmin(count_period_s))
        raise IdentificationError(f"count {worst}: mean time to the next count {count_period_s[worst]:.3g} s, not "
                                  f"positive (too few revolutions, {count.size / counts_per_rev:.3g}, for the speed "
                                  "ripple)")
    return 1.0 / (seconds_per_count * counts_per_rev), synchronous_table(count, i_ref_a, counts_per_rev), count_period_s


def reduce_bench(bench: Bench, reduce: Callable[[TrialData, int], TrialTables] | None = None,
                 torque_source: TorqueSource = TorqueSource.SENSOR) -> BenchTables:
    """Reduce every trial of ``bench`` with ``reduce`` (None: `reduce_trial` at the bench's lines per count); trials
    that cannot be reduced are left out with a message.

    The data are checked first (`ilcpmac.bench.format.check_trial` and
    `check_backemf`), so that a bench built in memory gets the reader's messages.
    ``torque_source`` says where ``reduce`` takes the torque from (`BenchTables`).

    Raises
    ------
    IdentificationError
        When no trial can be reduced, or the back-EMF is zero or at odds with the pole pairs.
    """
    cpr = bench.motor.counts_per_rev
    if reduce is None:
        reduce = functools.partial(reduce_trial, lines_per_count=bench.motor.lines_per_count)
    try:
        check_backemf(bench.backemf_nm_per_a, bench.motor, "back-EMF")
    except BenchFormatError as e:
        raise IdentificationError(str(e)) from None
    trials, files, messages = [], [], []
    for name, trial in zip(bench.trial_files, bench.trials):
        try:
            check_trial(trial, bench.motor, name)
            trials.append(reduce(trial, cpr))
            files.append(name)
        except (IdentificationError, BenchFormatError) as e:
            messages.append(f"{name} left out: {str(e).removeprefix(name + ': ')}")
        except NUMERICAL_FAILURES as e:
            messages.append(f"{name} left out: {degenerate(e)}")
    if not trials:
        raise IdentificationError("no trial can be used: " + "; ".join(messages))
    return BenchTables(bench.motor, np.asarray(bench.backemf_nm_per_a, float), tuple(trials), tuple(files),
                       tuple(messages), torque_source)


def trial_amplitudes(tables: np.ndarray, max_harmonic: int) -> np.ndarray:
    """Harmonic amplitudes 0..max_harmonic of per-count tables stacked along axis 0 (trials)."""
    return harmonic_amplitudes(tables, max_harmonic, axis=1)
