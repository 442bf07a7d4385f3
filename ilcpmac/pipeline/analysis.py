"""One analysis per trial: the detrended revolution harmonics of its torque, computed once.

The pipeline's joint fit (`ilcpmac.pipeline.pipeline.Pipeline.frame`), the
campaign's ripple figures (docs/campaign.md) and the report's plots all derive
from it. The piezo torque sensor measures neither DC nor drift, so each torque
loses its least-squares straight line against time over the trial's whole
revolutions before the revolution harmonics (`revolution_harmonics`) are taken.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ilcpmac.records import TrialData
from ilcpmac.signals.harmonics import (
    RippleFigures,
    linear_trend,
    revolution_table,
    table_from_amplitudes,
    table_harmonics,
    whole_revolutions,
)

__all__ = ["TorqueSpectrum", "TrialAnalysis"]


def _ripple_table(harmonics: np.ndarray, counts_per_rev: int) -> np.ndarray:
    """Harmonics 1..H (axis 0, the mean left out) as per-count tables along axis 0."""
    ripple = np.array(harmonics)
    ripple[0] = 0.0
    return table_from_amplitudes(ripple, counts_per_rev)


@dataclass(frozen=True)
class TorqueSpectrum:
    """The detrended synchronous average of one position-sampled torque, as harmonics.

    Attributes
    ----------
    harmonics_nm : ndarray of complex, shape (H + 1,)
        Harmonics 0..H of the synchronous average over the whole revolutions (as `harmonic_amplitudes`).
    variance_nm2 : ndarray, shape (H + 1,)
        The variance of each (revolution-to-revolution scatter over the number of revolutions).
    rest_rms_nm : float
        RMS of what the band-limited average leaves of the detrended torque (non-repeatable, and above H).
    counts_per_rev : int
    """

    harmonics_nm: np.ndarray
    variance_nm2: np.ndarray
    rest_rms_nm: float
    counts_per_rev: int

    @classmethod
    def of(cls, count: np.ndarray, time_s: np.ndarray, torque_nm: np.ndarray, counts_per_rev: int,
           max_harmonic: int) -> TorqueSpectrum:
        """The spectrum of harmonics 0..``max_harmonic`` of ``torque_nm`` sampled at ``count``, ``time_s``."""
        return cls.of_each(count, time_s, [torque_nm], counts_per_rev, max_harmonic)[0]

    @classmethod
    def of_each(cls, count: np.ndarray, time_s: np.ndarray, torques_nm: list[np.ndarray], counts_per_rev: int,
                max_harmonic: int) -> list[TorqueSpectrum]:
        """`of` for several torques sampled at the same ``count`` and ``time_s``, in one pass."""
        mask = whole_revolutions(count, counts_per_rev)
        count, time_s = count[mask], time_s[mask]
        torque = np.stack([np.asarray(t, float)[mask] for t in torques_nm])
        detrended = torque - linear_trend(time_s, torque)
        table = revolution_table(count, detrended, counts_per_rev)
        harmonics, variance = table_harmonics(table, max_harmonic)
        ripple = _ripple_table(harmonics.T, counts_per_rev).T
        if table[0].size == count.size:  # the table holds exactly the samples
            rest = table - ripple[:, None, :]
        else:
            rest = detrended - ripple[:, count % counts_per_rev]
        return [cls(h, v, float(np.std(r)), counts_per_rev) for h, v, r in zip(harmonics, variance, rest)]

    @property
    def max_harmonic(self) -> int:
        """H, the highest harmonic held."""
        return self.harmonics_nm.size - 1

    def ripple_table(self) -> np.ndarray:
        """The ripple over one revolution, per count: harmonics 1..H (no mean), N m."""
        return _ripple_table(self.harmonics_nm, self.counts_per_rev)

    def figures(self, mean_torque_nm: float, pole_pairs: int, cogging_order: int) -> RippleFigures:
        """The ripple figures of docs/campaign.md, fractions of ``mean_torque_nm``."""
        H = self.max_harmonic
        ripple = self.ripple_table()
        c = np.abs(self.harmonics_nm)
        named = [h for h in (pole_pairs, 2 * pole_pairs, cogging_order) if h <= H]
        others = np.ones(c.size, bool)
        others[0] = False
        others[named] = False
        noise_power = float(np.sum(self.variance_nm2[1:]) / 2.0)  # expected power of the noise left in the average

        def amp(h: int) -> float:
            return float(c[h]) if h <= H else 0.0

        return RippleFigures(
            pp=float(np.ptp(ripple) / mean_torque_nm),
            rms=float(np.std(ripple) / mean_torque_nm),
            rest_rms=self.rest_rms_nm / mean_torque_nm,
            rms_repeatable=float(np.sqrt(max(np.var(ripple) - noise_power, 0.0)) / mean_torque_nm),
            amp_1x=amp(pole_pairs),
            amp_2x=amp(2 * pole_pairs),
            amp_cogging=amp(cogging_order),
            amp_rest=float(np.sqrt(np.sum(c[others] ** 2) / 2.0)),
        )


@dataclass(frozen=True)
class TrialAnalysis:
    """The analysis of one finished trial.

    Attributes
    ----------
    measured : TorqueSpectrum
        Of the measured torque (``torque_nm``, in the sensor's units): the joint fit and the measured ripple.
    true : TorqueSpectrum or None
        Of the simulator's true torque, when the trial has one: the true ripple.
    true_mean_nm : float or None
        The true torque's mean over the trial, N m (the true ripple's reference).
    """

    measured: TorqueSpectrum
    true: TorqueSpectrum | None = None
    true_mean_nm: float | None = None

    @classmethod
    def of(cls, trial: TrialData, counts_per_rev: int, max_harmonic: int) -> TrialAnalysis:
        """Analyse ``trial`` up to harmonic ``max_harmonic`` (H)."""
        torques = [trial.torque_nm] if trial.torque_true_nm is None else [trial.torque_nm, trial.torque_true_nm]
        spectra = TorqueSpectrum.of_each(trial.count, trial.time_s, torques, counts_per_rev, max_harmonic)
        if trial.torque_true_nm is None:
            return cls(spectra[0])
        return cls(*spectra, float(trial.torque_true_nm.mean()))
