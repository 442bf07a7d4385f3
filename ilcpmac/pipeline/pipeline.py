"""Stages chained in the config's order; one joint fit per trial feeds them all.

The fit (`Pipeline.frame`) explains the torque the plant adds to what the trial's feed-forward u asks
for: the feed-forward's own torque is known through the identified response G^
(`StageSetup.torque_response`) and subtracted from the measured harmonics first, y - delta G^ u (the
joint fit's model, eq. 1.13, with the feed-forward moved to the known side), as the ILC stage estimates
d = e - G^ u. A stage that feeds forward -c^ / G^ from its block's estimate c^ then iterates
c^_{k+1} = c + (G / G^ - 1) G^ u_k, which converges to a delivered torque G u = -c while
|1 - G / G^| < 1; were u's torque left in y, the stage would read its own feed-forward as the plant's.

The measured harmonics relate to the true torque through the measurement's response
(`TorqueMeasurement.response`: the sensor's delta, high-pass and delay, or 1 for the encoder-derived
torque in N m): the fit divides out its shape per harmonic and keeps its scalar gain (delta, or 1),
which the stages see as `Frame.delta`. The stages never know which source measured the torque.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from ilcpmac.core.errors import IlcpmacError
from ilcpmac.core.records import BenchDescription, TrialData, TrialRequest
from ilcpmac.pipeline.analysis import TorqueMeasurement, TorqueSpectrum, TrialAnalysis
from ilcpmac.pipeline.regression import Regression
from ilcpmac.pipeline.safety import (
    FlowingCurrent,
    SafetyError,
    SafetyLimits,
    calibration_violation,
    clip_to_trust_region,
    enforce_limits,
    extent_violation,
    form_violation,
    identified_truth,
    torque_violation,
)
from ilcpmac.signals.harmonics import harmonic_amplitudes
from ilcpmac.stages.base import Frame, Identified, Stage, StageSetup


class Pipeline:
    """Shapes requests through every stage and teaches every stage from each trial.

    Parameters
    ----------
    stages : list of Stage, in the config's order.
    description : the bench.
    identified : the identification the stages start from.
    limits : the safety limits every request obeys.
    max_harmonic : H, the ripple band.
    notify : told when the limits change what a stage asked for (a calibration clipped).
    measurement : what measures the torque (None: the torque sensor, `TorqueMeasurement`).
    """

    def __init__(self, stages: list[Stage], description: BenchDescription, identified: Identified,
                 limits: SafetyLimits, max_harmonic: int, notify: Callable[[str], None] | None = None,
                 measurement: TorqueMeasurement | None = None) -> None:
        self.measurement = measurement or TorqueMeasurement(identified)
        self.stages = stages
        self.description = description
        self.identified = identified
        self.limits = limits
        self.max_harmonic = max_harmonic
        self.notify = notify
        self._truth = identified_truth(identified)
        self._response = StageSetup(description, identified, max_harmonic).torque_response

    def shape(self, request: TrialRequest) -> TrialRequest:
        """Pass ``request`` through every stage, each output checked (`checked`), then clip the
        feed-forward to the limits (`enforce_limits`)."""
        for stage in self.stages:
            request = self.checked(stage.shape(request), stage.name)
        flowing = FlowingCurrent.at(request.calibration, self._truth)
        return enforce_limits(request, self.description.backemf_nm_per_a, self.limits, flowing)

    def checked(self, request: TrialRequest, stage: str) -> TrialRequest:
        """Stage ``stage``'s output, its calibration clipped into the trust region.

        Raises `SafetyError` naming the stage for anything else out of bounds: no request, NaN or
        infinity, a wrong shape, a speed, length or duration beyond the limits, or a set point that
        with its excitation breaks the torque or current limits.
        """
        if not isinstance(request, TrialRequest):
            raise SafetyError(f"stage {stage!r} returned {type(request).__name__}, not a TrialRequest")
        cpr = self.description.motor.counts_per_rev
        why = form_violation(request, cpr) or extent_violation(request, cpr, self.limits)
        if why is not None:
            raise SafetyError(f"stage {stage!r}: {why}")
        nominal = self.description.calibration
        calibration = clip_to_trust_region(request.calibration, nominal, self._truth, self.limits)
        if calibration is not request.calibration:
            if self.notify is not None:
                self.notify(f"limits: stage {stage!r} set a calibration outside the trust region: "
                            f"{calibration_violation(request.calibration, nominal, self._truth, self.limits)}; "
                            "clipped to the region around the identified sensors")
            request = request.with_changes(calibration=calibration)
        why = torque_violation(request.torque_setpoint_nm + request.excitation_nm, self.description.backemf_nm_per_a,
                               self.limits, FlowingCurrent.at(calibration, self._truth))
        if why is not None:
            raise SafetyError(f"stage {stage!r}: set point {request.torque_setpoint_nm:g} N m with its "
                              f"excitation: {why}")
        return request

    def claimed_harmonics(self) -> np.ndarray:
        """Harmonics the stages' models claim: multiples of the pole-pair count up to H."""
        pole_pairs = self.description.motor.pole_pairs
        return np.arange(pole_pairs, self.max_harmonic + 1, pole_pairs)

    def frame(self, trial: TrialData, learning_gain: float = 1.0, spectrum: TorqueSpectrum | None = None) -> Frame:
        """The joint fit and the measured ripple spectrum of a finished trial.

        The fit is of the measured harmonics, their response's shape divided out, less the feed-forward's
        torque through the identified response, gain G^ u (module docstring). ``spectrum``: the trial's
        measured `TorqueSpectrum` up to H (`TrialAnalysis.measured`), computed here when not given.
        """
        cpr = self.description.motor.counts_per_rev
        if spectrum is None:
            spectrum = TrialAnalysis.of(trial, cpr, self.max_harmonic, self.measurement).measured
        if spectrum is None:
            raise IlcpmacError(f"the trial at {trial.torque_setpoint_nm:g} N m, {trial.speed_setpoint_hz:g} Hz has "
                               "no measured torque to fit")
        request = trial.requested()
        speed_hz = trial.mean_speed_hz(cpr)
        gain = self.measurement.gain(request.calibration)
        true = self.measurement.in_true_units(spectrum, speed_hz, request.calibration)
        mean, variance = true.harmonics_nm * gain, true.variance_nm2 * gain**2
        h = self.claimed_harmonics()
        u = harmonic_amplitudes(request.feedforward_nm)[h]
        known = gain * self._response(h, speed_hz, request.calibration) * u
        blocks = {s.name: harmonic_amplitudes(table)[h] for s in self.stages
                  if (table := s.columns(trial)) is not None}
        regression = Regression(mean[h] - known, variance[h], blocks)
        return Frame({name: regression.block(name) for name in blocks}, true.harmonics_nm, true.variance_nm2, gain,
                     speed_hz, learning_gain)

    def learn(self, trial: TrialData, learning_gain: float = 1.0, spectrum: TorqueSpectrum | None = None) -> Frame:
        """Teach every stage from ``trial`` (whose ``request`` must be set); return the frame (`frame`)."""
        frame = self.frame(trial, learning_gain, spectrum)
        for stage in self.stages:
            stage.learn(trial, frame)
        return frame

    def state(self) -> dict:
        """Every stage's state, by name."""
        return {stage.name: stage.state() for stage in self.stages}

    def restore(self, state: dict) -> None:
        """Restore every stage from `state`."""
        for stage in self.stages:
            stage.restore(state[stage.name])

    def revert(self, state: dict, key: str) -> None:
        """Go back to `state` (an earlier `state`) at set point ``key`` only: a stage with the optional
        ``revert`` reverts that key and keeps what it learned at other set points; any other is restored
        whole."""
        for stage in self.stages:
            revert = getattr(stage, "revert", None)
            if revert is None:
                stage.restore(state[stage.name])
            else:
                revert(state[stage.name], key)
