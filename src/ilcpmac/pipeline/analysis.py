"""One analysis per trial: the revolution harmonics of its torque, measured and true, computed once.

The pipeline's joint fit (`ilcpmac.pipeline.pipeline.Pipeline.frame`), the
campaign's ripple figures (docs/campaign.md) and the report's plots all derive
from it. The piezo torque sensor measures neither DC nor drift, so each torque
loses its least-squares straight line against time over the trial's whole
revolutions before the revolution harmonics (`revolution_harmonics`) are taken.

What measures the ripple is a `TorqueMeasurement` ([campaign] torque_source,
docs/sensorless.md): the torque sensor, in its units (delta times the true
torque through its high-pass); the encoder's time stamps
(`ilcpmac.signals.encoder_torque`), the torque at the lines in N m; or both
fused per harmonic by inverse mean-square error, in N m.
`TorqueMeasurement.response` is the one place that says how a measured
harmonic relates to the true torque's.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ilcpmac.core.errors import IlcpmacError
from ilcpmac.core.records import SensorCalibration, TrialData, TrialRequest
from ilcpmac.core.torque_source import TorqueSource
from ilcpmac.signals.encoder_torque import (
    EncoderTorqueSpectrum,
    brake_viscous_nm_s,
    separate_encoder_error,
    with_viscous,
    without_staircase,
)
from ilcpmac.signals.harmonics import (
    RippleFigures,
    harmonic_amplitudes,
    linear_trend,
    pooled_variance,
    revolution_table,
    slow_trend,
    table_from_amplitudes,
    table_harmonics,
    whole_revolution_span,
)
from ilcpmac.stages.base import Identified

__all__ = ["TorqueMeasurement", "TorqueSpectrum", "TrialAnalysis", "fused"]


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
           max_harmonic: int, trend_degree: int | None = None) -> TorqueSpectrum:
        """The spectrum of harmonics 0..``max_harmonic`` of ``torque_nm`` sampled at ``count``, ``time_s``.

        The trend taken out is the least-squares straight line against time through every sample; with
        ``trend_degree`` d, Legendre polynomials of time up to degree d (at most the whole revolutions less one)
        fitted to the samples' part that is not periodic in position (`slow_trend`, as the identification
        reduces a trial: a sensor's drift and slower settling). The ripple biases the straight line's slope,
        over R whole revolutions as 1 / R^2: a harmonic h_0 of 1 N m in sine phase puts 68 / h_0 mN m into
        harmonic 1 over 3 revolutions (4.2 / h_0 over 12), 1 / h of it into harmonic h; ``trend_degree`` has no
        such error.
        """
        return cls.of_each(count, time_s, [torque_nm], counts_per_rev, max_harmonic, trend_degree)[0]

    @classmethod
    def of_each(cls, count: np.ndarray, time_s: np.ndarray, torques_nm: list[np.ndarray], counts_per_rev: int,
                max_harmonic: int, trend_degree: int | None = None) -> list[TorqueSpectrum]:
        """`of` for several torques sampled at the same ``count`` and ``time_s``, in one pass."""
        span = whole_revolution_span(count, counts_per_rev)
        count, time_s = count[span], time_s[span]
        torque = np.stack([np.asarray(t, float)[span] for t in torques_nm])
        if trend_degree is None:
            detrended = torque - linear_trend(time_s, torque)
        else:
            degree = min(trend_degree, int(count[-1] // counts_per_rev - count[0] // counts_per_rev))
            detrended = torque - np.stack([slow_trend(count, time_s, t, counts_per_rev, degree)[0] for t in torque])
            detrended -= detrended.mean(axis=-1, keepdims=True)
        table = revolution_table(count, detrended, counts_per_rev)
        harmonics, variance = table_harmonics(table, max_harmonic)
        variance = pooled_variance(variance, table.shape[-2])
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

    def divided_by(self, response: np.ndarray) -> TorqueSpectrum:
        """This spectrum divided by a response per harmonic 0..H (``rest_rms_nm`` by the mean's)."""
        return TorqueSpectrum(self.harmonics_nm / response, self.variance_nm2 / np.abs(response) ** 2,
                              self.rest_rms_nm / abs(response[0]), self.counts_per_rev)

    def ripple_table(self) -> np.ndarray:
        """The ripple over one revolution, per count: harmonics 1..H (no mean), N m."""
        return _ripple_table(self.harmonics_nm, self.counts_per_rev)

    def figures(self, mean_torque_nm: float, pole_pairs: int, cogging_order: int) -> RippleFigures:
        """The ripple figures of docs/campaign.md, fractions of ``mean_torque_nm``'s size (a generating point's is
        negative)."""
        mean_torque_nm = abs(mean_torque_nm)
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


#: |s_h|^2 / v_s,h beyond which a sensor harmonic is the column of the sensor gain's error in the graduation error's
#: separation (`TorqueMeasurement.graduation_error`): the noise it carries, also in the difference it is fitted to,
#: biases the gain by less than 1 / this
SENSOR_GAIN_SNR = 100.0
#: |e - s|^2 / (v_e + v_s) beyond which "both" takes the encoder's harmonic for biased (`fused`): e^-4 of
#: harmonics pass it by noise alone (|e - s|^2 / (v_e + v_s) of an unbiased pair is exponential of mean 1)
DISAGREEMENT = 4.0


def fused(sensor: TorqueSpectrum, encoder: TorqueSpectrum, encoder_bias_nm: np.ndarray | None = None
          ) -> TorqueSpectrum:
    """Two spectra of one torque in N m, combined per harmonic by inverse mean-square error; the mean (h = 0),
    which a piezo does not see, is the encoder's.

    ``encoder_bias_nm`` (shape (H + 1,), N m; None: 0) bounds the encoder's bias per harmonic, which repeats
    trial after trial and no revolution scatter shows: its mean-square error is v_e + bias^2
    (docs/sensorless.md, "both"). Where the two disagree beyond their noise (|e - s|^2 above `DISAGREEMENT`
    times v_e + v_s, which noise alone passes at 1 harmonic in 50), the disagreement bounds it too: bias^2 is
    at least |e - s|^2 - (v_e + v_s), an unbiased estimate of the encoder's squared bias (the sensor has
    none), whatever biases the encoder (an encoder error its identification missed, or took for too much).
    Each harmonic's variance is 1 / (1 / v_s + 1 / (v_e + bias^2)), below either; ``rest_rms_nm`` is the
    smaller of the two.
    """
    noise2 = encoder.variance_nm2 + sensor.variance_nm2
    disagreement2 = np.abs(encoder.harmonics_nm - sensor.harmonics_nm) ** 2
    bias2 = np.maximum(0.0 if encoder_bias_nm is None else np.abs(encoder_bias_nm) ** 2,
                       np.where(disagreement2 > DISAGREEMENT * noise2, disagreement2 - noise2, 0.0))
    ws, we = 1.0 / sensor.variance_nm2, 1.0 / (encoder.variance_nm2 + bias2)
    harmonics = (ws * sensor.harmonics_nm + we * encoder.harmonics_nm) / (ws + we)
    variance = 1.0 / (ws + we)
    harmonics[0], variance[0] = encoder.harmonics_nm[0], encoder.variance_nm2[0]
    return TorqueSpectrum(harmonics, variance, min(sensor.rest_rms_nm, encoder.rest_rms_nm), encoder.counts_per_rev)


@dataclass(frozen=True)
class TorqueMeasurement:
    """What measures a trial's torque ripple ([campaign] torque_source), and how it relates to the true torque.

    A measured harmonic is ``response`` times the true torque's: the sensor's delta at the trial's calibration
    times its high-pass and delay (`Identified.sensor_response`); 1 for the encoder and for both fused (N m).

    Attributes
    ----------
    identified : Identified
        The identification (delta, epsilon alpha for the brake, the sensor's high-pass).
    source : TorqueSource
        What is read (`TorqueSource.reads_sensor`, `TorqueSource.reads_encoder`).
    inertia_kgm2 : float
        J of eq. 3.1, kg m^2 (the bench's), needed where the encoder is read.
    timer_resolution_s : float
        The time stamps' quantum q, s (eq. 3; 0: the revolution scatter alone weights).
    line_errors_counts : ndarray, shape (counts_per_rev,), or None
        The identified encoder graduation error e_c, counts, taken out of every trial's stamps.
    friction_nm : float
        Coulomb friction the brake does not absorb, N m.
    lines_per_count : int
        The encoder lines each count of the trials is the mean over (`MotorInfo.lines_per_count`).
    """

    identified: Identified
    source: TorqueSource = TorqueSource.SENSOR
    inertia_kgm2: float = 0.0
    timer_resolution_s: float = 0.0
    line_errors_counts: np.ndarray | None = None
    friction_nm: float = 0.0
    lines_per_count: int = 1

    def __post_init__(self) -> None:
        if self.source.reads_encoder and not (np.isfinite(self.inertia_kgm2) and self.inertia_kgm2 > 0):
            raise ValueError(f"the encoder-derived torque needs the inertia, got {self.inertia_kgm2!r} kg m^2")

    def gain(self, calibration: SensorCalibration) -> float:
        """The response's scalar part while the controller uses ``calibration``: delta, or 1 in N m."""
        return 1.0 if self.source.reads_encoder else self.identified.delta_at(calibration)

    def response(self, harmonics: np.ndarray, speed_hz: float, calibration: SensorCalibration) -> np.ndarray:
        """Measured over true torque at each harmonic of a trial at ``speed_hz`` with ``calibration``."""
        if self.source.reads_encoder:
            return np.ones(np.shape(harmonics))
        return self.sensor_response(harmonics, speed_hz, calibration)

    def sensor_response(self, harmonics: np.ndarray, speed_hz: float, calibration: SensorCalibration
                        ) -> np.ndarray:
        """The torque sensor's column over true torque: delta at ``calibration`` times the identified high-pass and
        delay (`Identified.sensor_response`; delta alone at h = 0)."""
        return self.identified.delta_at(calibration) * self.identified.sensor_response(harmonics, speed_hz)

    def mean_torque_nm(self, request: TrialRequest) -> float:
        """The true mean torque the identification predicts for ``request``: epsilon alpha-mean x set point."""
        return request.torque_setpoint_nm * float(np.mean(self.identified.epsilon_alpha_at(request.calibration)))

    def encoder_spectrum(self, trial: TrialData, counts_per_rev: int, max_harmonic: int) -> TorqueSpectrum:
        """The encoder-derived torque of ``trial`` (whose ``request`` is set) as a `TorqueSpectrum` in N m.

        The torque at the lines, as a torque sensor samples it: the currents' staircase taken out (eq. 5 of
        `ilcpmac.signals.encoder_torque`, with the identified current loop at the trial's calibration). Its
        variance is the fit's weight (`EncoderTorqueSpectrum.weight_variance_nm2`: the larger of the revolution
        scatter and the quantisation floor, eq. 3); ``rest_rms_nm`` the revolution-to-revolution scatter's RMS
        within the band 1..H.
        """
        return self.encoder_spectrum_and_bias(trial, counts_per_rev, max_harmonic)[0]

    def encoder_spectrum_and_bias(self, trial: TrialData, counts_per_rev: int, max_harmonic: int
                                  ) -> tuple[TorqueSpectrum, np.ndarray]:
        """`encoder_spectrum`, and the bound on its bias per harmonic 0..H that "both" weights it with (`fused`),
        N m: what eq. 5 took out of it plus what the identified graduation error took out, |m_h e_h| (eq. 4): an
        applied correction is known no better than its own size (a graduation error detected where there is
        none, from the noise of a few harmonics, would otherwise pass into the fused torque as m_h e_h, which
        grows as h^2)."""
        spectrum, corrected = self._encoder_spectra(trial, counts_per_rev, max_harmonic)
        rest = float(np.sqrt(corrected.revolutions * np.sum(corrected.variance_nm2[1:]) / 2.0))
        bias = np.abs(spectrum.harmonics_nm - corrected.harmonics_nm)
        if self.line_errors_counts is not None:
            error_counts = harmonic_amplitudes(self.line_errors_counts, max_harmonic)
            bias = bias + np.abs(corrected.encoder_error_gain() * error_counts)
        return TorqueSpectrum(corrected.harmonics_nm, corrected.weight_variance_nm2, rest, counts_per_rev), bias

    def _encoder_spectra(self, trial: TrialData, counts_per_rev: int, max_harmonic: int
                         ) -> tuple[EncoderTorqueSpectrum, EncoderTorqueSpectrum]:
        """The encoder-derived torque of ``trial`` (its stamps corrected for `line_errors_counts`, the brake's
        viscous part added), before and after eq. 5 takes the currents' staircase out."""
        request = trial.requested()
        spectrum = EncoderTorqueSpectrum.of(trial.count, trial.time_s, counts_per_rev, max_harmonic,
                                            self.inertia_kgm2, self.timer_resolution_s, 0.0, self.line_errors_counts)
        spectrum = with_viscous(spectrum, brake_viscous_nm_s(self.mean_torque_nm(request),
                                                             spectrum.speed_harmonics_rad_s[0].real, self.friction_nm))
        return spectrum, without_staircase(spectrum, request.torque_reference_nm(),
                                           self.identified.epsilon_alpha_at(request.calibration),
                                           self.identified.loop_at(request.calibration), self.lines_per_count)

    def graduation_error(self, trials: list[TrialData], counts_per_rev: int, max_harmonic: int
                         ) -> tuple[np.ndarray, np.ndarray]:
        """The encoder's graduation error e_h, h = 0..H, counts, and its variance, from ``trials`` (their
        ``request`` set) that both the torque sensor and the encoder read, at two or more speeds.

        The sensor sees no graduation error, and the true torque, whatever ripple it holds at whatever speed or
        load, is the same in both: per trial k the encoder-derived torque less the sensor's in true units is
        c_h + m_h,k e_h (eq. 4) plus the two noises, c_h what the two share at every speed (the identified
        sensor gain's error times a position-fixed ripple, cogging say). `separate_encoder_error` of these
        differences gives e_h with no model of the torque (the joint identification's separation must assume
        one: there a torque ripple that changes with speed or load passes for encoder error). What else the
        differences hold is fitted with the separation (docs/sensorless.md, "The graduation error, against the
        sensor"): each trial's error of its brake's viscous b (omega_h times it), and the error of the sensor's
        identified gain, common to all (the sensor's harmonics where they stand out of its noise by
        `SENSOR_GAIN_SNR`, times it); the sensor's slow trend is fitted to what is not periodic in position, as the
        identification reduces a trial, so that the few revolutions' ripple does not bias it (`TorqueSpectrum.of`).
        """
        from ilcpmac.identify.reduction import TREND_DEGREE  # deferred: the identification's package is heavy

        if not self.source.fuses or self.line_errors_counts is not None:
            raise ValueError("the graduation error is measured against the sensor by a fusing measurement that "
                             "corrects none yet")
        h = np.arange(max_harmonic + 1)
        differences, brakes, gains = [], [], []
        for trial in trials:
            if trial.torque_nm is None:
                raise ValueError(f"the trial at {trial.torque_setpoint_nm:g} N m has no torque sensor column")
            raw, encoder = self._encoder_spectra(trial, counts_per_rev, max_harmonic)
            sensor = TorqueSpectrum.of(trial.count, trial.time_s, trial.torque_nm, counts_per_rev, max_harmonic,
                                       TREND_DEGREE)
            sensor = sensor.divided_by(self.sensor_response(h, raw.mean_speed_hz, trial.requested().calibration))
            differences.append(replace(raw, harmonics_nm=encoder.harmonics_nm - sensor.harmonics_nm,
                                       variance_nm2=encoder.weight_variance_nm2 + sensor.variance_nm2,
                                       quantisation_variance_nm2=np.zeros(h.size)))
            brakes.append(raw.speed_harmonics_rad_s[None, :])
            resolved = np.abs(sensor.harmonics_nm) ** 2 > SENSOR_GAIN_SNR * sensor.variance_nm2
            gains.append(np.where(resolved, sensor.harmonics_nm, 0.0)[None, :])
        separation = separate_encoder_error(differences, brakes, gains)
        return separation.encoder_error_counts, separation.encoder_error_variance_counts2

    def in_true_units(self, spectrum: TorqueSpectrum, speed_hz: float, calibration: SensorCalibration
                      ) -> TorqueSpectrum:
        """``spectrum`` of this measurement divided by its `response`."""
        return spectrum.divided_by(self.response(np.arange(spectrum.max_harmonic + 1), speed_hz, calibration))


@dataclass(frozen=True)
class TrialAnalysis:
    """The analysis of one finished trial.

    Attributes
    ----------
    measured : TorqueSpectrum or None
        Of the measured torque (`TorqueMeasurement`: the sensor's ``torque_nm`` in its units, or N m from the
        encoder or both): the joint fit and the measured ripple. None before the identification when the trial
        has no torque column.
    true : TorqueSpectrum or None
        Of the simulator's true torque, when the trial has one: the true ripple.
    true_mean_nm : float or None
        The true torque's mean over the trial, N m (the true ripple's reference).
    """

    measured: TorqueSpectrum | None
    true: TorqueSpectrum | None = None
    true_mean_nm: float | None = None

    @classmethod
    def of(cls, trial: TrialData, counts_per_rev: int, max_harmonic: int,
           measurement: TorqueMeasurement | None = None) -> TrialAnalysis:
        """Analyse ``trial`` up to harmonic ``max_harmonic`` (H), measured by ``measurement`` (None: the sensor's
        torque column as it is, where the trial has one).

        Raises `IlcpmacError` when the measurement reads a torque column the trial does not have.
        """
        sensor = measurement is None or measurement.source.reads_sensor
        if sensor and trial.torque_nm is None and measurement is not None:
            raise IlcpmacError(f"[campaign] torque_source = {measurement.source.value!r}: the trial at "
                               f"{trial.torque_setpoint_nm:g} N m, {trial.speed_setpoint_hz:g} Hz has no torque "
                               "column (no torque sensor): use \"encoder\"")
        torques = [t for t in (trial.torque_nm if sensor else None, trial.torque_true_nm) if t is not None]
        spectra = TorqueSpectrum.of_each(trial.count, trial.time_s, torques, counts_per_rev, max_harmonic) \
            if torques else []
        measured = spectra.pop(0) if sensor and trial.torque_nm is not None else None
        if measurement is not None and measurement.source.reads_encoder:
            encoder, bias = measurement.encoder_spectrum_and_bias(trial, counts_per_rev, max_harmonic)
            if measurement.source.fuses:
                if measured is None:
                    raise IlcpmacError(f"torque source {measurement.source.value!r}: the trial at "
                                       f"{trial.torque_setpoint_nm:g} N m, {trial.speed_setpoint_hz:g} Hz has no "
                                       "sensor torque to fuse")
                response = measurement.sensor_response(np.arange(max_harmonic + 1),
                                                       trial.mean_speed_hz(counts_per_rev),
                                                       trial.requested().calibration)
                encoder = fused(measured.divided_by(response), encoder, bias)
            measured = encoder
        if trial.torque_true_nm is None:
            return cls(measured)
        return cls(measured, spectra[0], float(trial.torque_true_nm.mean()))
