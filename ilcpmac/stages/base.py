"""The stage plugin API: four methods and a name, discovered through entry points.

A stage is built by a factory ``factory(setup: StageSetup) -> Stage``
registered in the entry-point group ``ilcpmac.stages``. Before each trial the
pipeline passes the request through every stage's `Stage.shape`; after it, one
joint least-squares fit over every stage's `Stage.columns` gives each stage
its block (`Frame.block`) in `Stage.learn`. Stages never reach into each other.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from ilcpmac.backends.base import BenchDescription
from ilcpmac.pipeline.regression import Block, Regression
from ilcpmac.records import SensorCalibration, TrialData, TrialRequest


@dataclass(frozen=True)
class Identified:
    """What the identification phase found, at the calibration its data were recorded with.

    Attributes follow the result keys of docs/bench-format.md (eqs. 1.4-1.7, 3.3).
    """

    delta: float
    epsilon: float
    alpha: np.ndarray
    beta_a: np.ndarray
    cogging_nm: np.ndarray
    calibration: SensorCalibration
    delta_std: float = 0.0
    epsilon_std: float = 0.0
    alpha_std: np.ndarray = field(default_factory=lambda: np.zeros(3))
    beta_std_a: np.ndarray = field(default_factory=lambda: np.zeros(3))
    current_loop_bandwidth_per_phase_hz: np.ndarray | None = None

    @classmethod
    def from_result(cls, result: dict, calibration: SensorCalibration) -> "Identified":
        """Build from an identification result JSON (docs/bench-format.md keys, plus the current loop's
        ``current_loop_bandwidth_per_phase_hz`` or ``current_loop_bandwidth_hz`` when identified)."""

        def std(key, default):
            value = result.get(key + "_std")
            return np.asarray(default if value is None else value, float)

        bandwidth = result.get("current_loop_bandwidth_per_phase_hz") or result.get("current_loop_bandwidth_hz")
        return cls(
            delta=float(result["torque_sensor_gain"]), epsilon=float(result["epsilon"]),
            alpha=np.asarray(result["alpha"], float), beta_a=np.asarray(result["beta"], float),
            cogging_nm=np.asarray(result["cogging"]["torque"], float), calibration=calibration,
            delta_std=float(std("torque_sensor_gain", 0.0)), epsilon_std=float(std("epsilon", 0.0)),
            alpha_std=std("alpha", np.zeros(3)), beta_std_a=std("beta", np.zeros(3)),
            current_loop_bandwidth_per_phase_hz=None if bandwidth is None else np.broadcast_to(
                np.asarray(bandwidth, float), (3,)).copy())

    def loop_bandwidth_at(self, calibration: SensorCalibration) -> np.ndarray | None:
        """Each phase's current-loop corner while the controller uses ``calibration``, Hz.

        The PI loop closes on the measured current, (G*_s^-1 G_s)^-1 = 1 / (epsilon alpha_p)
        times the true one, so its corner scales with 1 / (epsilon alpha_p).
        """
        if self.current_loop_bandwidth_per_phase_hz is None:
            return None
        return (self.current_loop_bandwidth_per_phase_hz * self.epsilon_alpha_at(self.calibration)
                / self.epsilon_alpha_at(calibration))

    def mean_loop_bandwidth_at(self, calibration: SensorCalibration) -> float | None:
        """The phases' mean current-loop corner at ``calibration``, Hz (None if not identified)."""
        bandwidth = self.loop_bandwidth_at(calibration)
        return None if bandwidth is None else float(np.mean(bandwidth))

    @property
    def sensor_gain(self) -> np.ndarray:
        """G_s per phase, A per count: G*_s^-1 G_s = epsilon alpha (eqs. 1.5, 1.6)."""
        return self.epsilon * self.alpha / self.calibration.current_scale

    @property
    def torque_gain_v_per_nm(self) -> float:
        """g_t = delta g*_t (eq. 1.4)."""
        return self.delta * self.calibration.torque_gain

    def delta_at(self, calibration: SensorCalibration) -> float:
        """delta = g_t / g*_t while the controller uses ``calibration``."""
        return self.torque_gain_v_per_nm / calibration.torque_gain

    def epsilon_alpha_at(self, calibration: SensorCalibration) -> np.ndarray:
        """epsilon alpha_p = G*_s^-1 G_s per phase while the controller uses ``calibration``."""
        return calibration.current_scale * self.sensor_gain


@dataclass(frozen=True)
class StageSetup:
    """What a stage may know: the bench, the identification, the ripple band and its options.

    Attributes
    ----------
    description : BenchDescription
    identified : Identified
    max_harmonic : int
        H, the ripple band 1..H (docs/campaign.md).
    options : dict
        The stage's own ``[stages.NAME]`` table from the campaign config.
    """

    description: BenchDescription
    identified: Identified
    max_harmonic: int
    options: dict = field(default_factory=dict)

    def torque_response(self, harmonics: np.ndarray, speed_hz: float,
                        calibration: SensorCalibration) -> np.ndarray:
        """Torque reference to true torque at mechanical harmonics h, while the controller uses
        ``calibration``: mean(epsilon alpha) times the identified current loop and the reference hold."""
        ident = self.identified
        gain = float(np.mean(ident.epsilon_alpha_at(calibration)))
        return gain * plant_response(harmonics, speed_hz, ident.mean_loop_bandwidth_at(calibration),
                                     self.description.motor.counts_per_rev)


@dataclass(frozen=True)
class Frame:
    """What a finished trial tells the stages.

    Attributes
    ----------
    regression : Regression
        The trial's joint fit over all stages' columns.
    torque_harmonics_nm : ndarray of complex, shape (H + 1,)
        Synchronous-average harmonics of the measured torque, converted to
        true torque units (divided by the trial's delta).
    torque_harmonics_var : ndarray, shape (H + 1,)
        Variance of each of those harmonics (revolution-to-revolution scatter).
    delta : float
        The torque-sensor gain while this trial ran.
    speed_hz : float
        Mean mechanical speed of the trial.
    learning_gain : float
        The pipeline's factor on every learning step at this set point (the guard halves it).
    """

    regression: Regression
    torque_harmonics_nm: np.ndarray
    torque_harmonics_var: np.ndarray
    delta: float
    speed_hz: float
    learning_gain: float = 1.0

    def block(self, name: str) -> Block:
        """Stage ``name``'s block of the joint fit."""
        return self.regression.block(name)


@runtime_checkable
class Stage(Protocol):
    """A compensation stage."""

    name: str

    def columns(self, trial: TrialData) -> np.ndarray | None:
        """Its regressors for the trial's joint fit over one revolution, shape (counts_per_rev, k), or None.

        Regressors are per encoder count (position-periodic within a trial);
        the pipeline compares their harmonics with the measured torque's.
        """
        ...

    def shape(self, request: TrialRequest) -> TrialRequest:
        """The next trial's request, with this stage's correction applied."""
        ...

    def learn(self, trial: TrialData, frame: Frame) -> None:
        """Update the stage from a finished trial."""
        ...

    def state(self) -> dict[str, Any]:
        """JSON-able state (for the run directory and --resume)."""
        ...

    def restore(self, state: dict[str, Any]) -> None:
        """Set the state saved by `state`."""
        ...


def read_options(options: dict, defaults: dict[str, Any], stage: str) -> dict[str, Any]:
    """A stage's options over its defaults; unknown keys and wrong types raise `ConfigError`."""
    from ilcpmac.errors import ConfigError

    unknown = sorted(set(options) - set(defaults))
    if unknown:
        raise ConfigError(f"[stages.{stage}] unknown key {unknown[0]!r} (known: {', '.join(defaults)})")
    values = dict(defaults)
    for key, value in options.items():
        kind = type(defaults[key])
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if type(value) is not kind:
            raise ConfigError(f"[stages.{stage}] {key}: expected {kind.__name__}, got {value!r}")
        values[key] = value
    return values


def plant_response(harmonics: np.ndarray, speed_hz: float, bandwidth_hz: float | None,
                   counts_per_rev: int) -> np.ndarray:
    """Current reference to current at mechanical harmonics h (per unit).

    The controller holds each count's reference until the next count (a
    half-count delay, exp(-j pi h / counts_per_rev)), and the current loop
    lags it as a first order 1 / (1 + j h f_m / f_bw) at frequency h f_m (no
    lag when no bandwidth was identified).
    """
    h = np.asarray(harmonics, float)
    hold = np.exp(-1j * np.pi * h / counts_per_rev)
    if bandwidth_hz is None:
        return hold
    return hold / (1.0 + 1j * h * speed_hz / bandwidth_hz)
