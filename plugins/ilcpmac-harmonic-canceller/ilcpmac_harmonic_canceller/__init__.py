"""Cancel the torque ripple at chosen harmonics: an example ilcpmac stage plugin.

Per set point and chosen harmonic h, a Kalman filter (across trials)
estimates the disturbance d_h from z_h = e_h - G(h) c_h, where e_h is the
measured torque harmonic in true units, c_h the correction the trial carried
and G the identified response at the shaft (`StageSetup.shaft_response`); the next
correction moves to -d_h / G(h) by the pipeline's learning gain.
Other harmonics are left alone.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ilcpmac.core.errors import ConfigError
from ilcpmac.core.records import TrialData, TrialRequest
from ilcpmac.core.schema import in_range, setting
from ilcpmac.estimators import KalmanEstimator
from ilcpmac.stages import Frame, StageSetup
from ilcpmac.stages.base import parse_options


@dataclass(frozen=True)
class CancellerOptions:
    """[stages.harmonic-canceller] (all optional; defaults shown)."""

    orders: tuple[int, ...] = setting(lambda x: len(x) > 0, "the harmonics cancelled, distinct, within the ripple "
                                      "band (checked when the stage is built)", (1,))
    process_noise_nm: float = setting(in_range(0.0, 1e3), "N m per trial, within [0, 1e3]", 1e-5)


class HarmonicCanceller:
    """Cancel the torque ripple at chosen harmonics: an example ilcpmac stage plugin.

    Stage ``harmonic-canceller``: options ``orders`` and ``process_noise_nm``.
    """

    name = "harmonic-canceller"
    #: its options, checked before the campaign's first trial (docs/writing-a-stage.md)
    options_schema = CancellerOptions

    def __init__(self, setup: StageSetup) -> None:
        opts = parse_options(setup.options, CancellerOptions, self.name)
        orders = list(opts.orders)
        if (not orders or not all(type(h) is int and 1 <= h <= setup.max_harmonic for h in orders)
                or len(set(orders)) != len(orders)):
            raise ConfigError(f"[stages.{self.name}] orders: need distinct integer harmonics in "
                              f"1..{setup.max_harmonic}, got {orders!r}")
        self.orders = np.array(orders, int)
        self._setup = setup
        self._q = opts.process_noise_nm ** 2
        self._cpr = setup.description.motor.counts_per_rev
        self._theta = 2.0 * np.pi * np.arange(self._cpr) / self._cpr
        self._correction: dict[str, np.ndarray] = {}  # complex amplitude per order, N m, per set point
        self._kalman: dict[str, KalmanEstimator] = {}

    def _filter(self, key: str) -> KalmanEstimator:
        n = 2 * self.orders.size
        return self._kalman.setdefault(key, KalmanEstimator(np.zeros(n), np.full(n, 1.0), self._q))

    def columns(self, trial: TrialData) -> None:
        return None

    def shape(self, request: TrialRequest) -> TrialRequest:
        c = self._correction.get(request.setpoint_key)
        if c is None:
            return request
        table = np.real(np.exp(1j * np.outer(self._theta, self.orders)) @ c)
        return request.with_changes(feedforward_nm=request.feedforward_nm + table)

    def learn(self, trial: TrialData, frame: Frame) -> None:
        request = trial.requested()
        if np.any(request.excitation_nm):
            return  # an identification trial: its ripple is mostly the excitation
        key = request.setpoint_key
        g = self._setup.shaft_response(self.orders, frame.speed_hz, request.calibration, request.torque_setpoint_nm)
        applied = self._correction.get(key, np.zeros(self.orders.size, complex))
        z = frame.torque_harmonics_nm[self.orders] - g * applied
        var = frame.torque_harmonics_var[self.orders] / 2.0  # per real component
        kalman = self._filter(key)
        kalman.update(np.concatenate([z.real, z.imag]), np.concatenate([var, var]))
        d = kalman.x[: self.orders.size] + 1j * kalman.x[self.orders.size:]
        # move towards -d / G, by the pipeline's learning gain (the guard halves it)
        self._correction[key] = applied + frame.learning_gain * (-d / g - applied)

    def state(self) -> dict:
        return {key: {"re": c.real.tolist(), "im": c.imag.tolist(), "kalman": self._kalman[key].state()}
                for key, c in self._correction.items()}

    def restore(self, state: dict) -> None:
        self._correction, self._kalman = {}, {}
        for key, s in state.items():
            self._set(key, s)

    def revert(self, state: dict, key: str) -> None:
        """Set point ``key`` as in `state`, unlearned if `state` has none of it; other set points stay."""
        self._correction.pop(key, None)
        self._kalman.pop(key, None)
        if key in state:
            self._set(key, state[key])

    def _set(self, key: str, s: dict) -> None:
        self._correction[key] = np.array(s["re"]) + 1j * np.array(s["im"])
        self._filter(key).restore(s["kalman"])
