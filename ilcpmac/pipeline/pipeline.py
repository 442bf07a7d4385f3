"""Stages chained in the config's order; one joint fit per trial feeds them all."""

from __future__ import annotations

import numpy as np

from ilcpmac.backends.base import BenchDescription
from ilcpmac.pipeline.regression import Regression
from ilcpmac.pipeline.safety import SafetyLimits, enforce_limits
from ilcpmac.records import TrialData, TrialRequest
from ilcpmac.signals.harmonics import harmonic_amplitudes, revolution_harmonics
from ilcpmac.stages.base import Frame, Identified, Stage
from ilcpmac.stages.sensor import trial_speed_hz


def drift_columns(time_s: np.ndarray) -> np.ndarray:
    """Nuisance regressors of a piezo torque sensor: DC level and linear drift."""
    span = max(time_s[-1] - time_s[0], 1e-12)
    return np.column_stack([np.ones_like(time_s), (time_s - time_s.mean()) / span])


class Pipeline:
    """Shapes requests through every stage and teaches every stage from each trial.

    Parameters
    ----------
    stages : list of Stage, in the config's order.
    description : the bench.
    identified : the identification the stages start from.
    limits : the safety limits every request obeys.
    max_harmonic : H, the ripple band.
    """

    def __init__(self, stages: list[Stage], description: BenchDescription, identified: Identified,
                 limits: SafetyLimits, max_harmonic: int) -> None:
        self.stages = stages
        self.description = description
        self.identified = identified
        self.limits = limits
        self.max_harmonic = max_harmonic

    def shape(self, request: TrialRequest) -> TrialRequest:
        """Pass ``request`` through every stage, then clip it to the limits."""
        for stage in self.stages:
            request = stage.shape(request)
        return enforce_limits(request, self.description.backemf_nm_per_a, self.limits)

    def claimed_harmonics(self) -> np.ndarray:
        """Harmonics the stages' models claim: multiples of the pole-pair count up to H."""
        pole_pairs = self.description.motor.pole_pairs
        return np.arange(pole_pairs, self.max_harmonic + 1, pole_pairs)

    def frame(self, trial: TrialData, learning_gain: float = 1.0) -> Frame:
        """The joint fit and the measured ripple spectrum of a finished trial."""
        cpr = self.description.motor.counts_per_rev
        nuisance = drift_columns(trial.time_s)
        trend = nuisance @ np.linalg.lstsq(nuisance, trial.torque_nm, rcond=None)[0]
        mean, variance = revolution_harmonics(trial.count, trial.torque_nm - trend, cpr, self.max_harmonic)
        h = self.claimed_harmonics()
        blocks = {s.name: harmonic_amplitudes(table)[h] for s in self.stages
                  if (table := s.columns(trial)) is not None}
        regression = Regression(mean[h], variance[h], blocks)
        delta = self.identified.delta_at(trial.request.calibration)
        return Frame(regression, mean / delta, variance / delta**2, delta, trial_speed_hz(trial, cpr),
                     learning_gain)

    def learn(self, trial: TrialData, learning_gain: float = 1.0) -> Frame:
        """Teach every stage from ``trial`` (whose ``request`` must be set); return the frame."""
        frame = self.frame(trial, learning_gain)
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
