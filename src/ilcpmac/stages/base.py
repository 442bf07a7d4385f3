"""The stage plugin API: a name and five methods, discovered through entry points.

A stage is built by a factory ``factory(setup: StageSetup) -> Stage``
registered in the entry-point group ``ilcpmac.stages``. Before each trial the
pipeline passes the request through every stage's `Stage.shape`; after it, one
joint least-squares fit over every stage's `Stage.columns` gives each stage
its block (`Frame.block`) in `Stage.learn`. Stages never reach into each other.
A stage whose memory is per set point may add the optional ``revert(state, key)``
(`Stage`); the campaign's guard then reverts that set point only (`Pipeline.revert`).

A factory declares in its attribute ``needs`` (a tuple of
`ilcpmac.core.records.IdentificationResult` field names, e.g. ``("cogging_nm",)``)
what it needs from the identification beyond `PIPELINE_NEEDS`; the campaign
refuses to start the stages when the identification could not estimate one.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any, Callable, Protocol, TypeVar, runtime_checkable

import numpy as np

from ilcpmac.core.current_loop import CurrentLoop, backemf_power, speed_feedback
from ilcpmac.core.errors import ConfigError, IdentificationError
from ilcpmac.core.records import (
    BenchDescription,
    IdentificationResult,
    SensorCalibration,
    TrialData,
    TrialRequest,
    frozen,
)
from ilcpmac.core.schema import parse_section, shown
from ilcpmac.core.torque_sensor import harmonic_response

#: a stage's options schema (`parse_options`)
T = TypeVar("T")

#: the identification's estimates the pipeline itself needs (the trial's delta, the identified sensors
#: bounding the flowing current); a stage declares what more it needs in its ``needs``
PIPELINE_NEEDS = ("delta", "epsilon", "alpha", "beta")
#: what it needs when the torque comes from the encoder alone ([campaign] torque_source = "encoder"): no delta
SENSORLESS_PIPELINE_NEEDS = ("epsilon", "alpha", "beta")


@dataclass(frozen=True)
class Identified:
    """What the identification phase found, at the calibration its data were recorded with.

    Attributes follow `ilcpmac.core.records.IdentificationResult` (eqs. 1.4-1.7); ``cogging_nm`` is None
    and ``current_loop`` the ideal loop where the identification gave none; ``delta`` is 1 where it had no
    torque sensor (the encoder-derived torque is true torque, and the torque gain stays the bench's).
    ``sensor_highpass_hz`` and ``sensor_delay_s`` are the torque sensor's high-pass corner (Hz) and delay (s)
    the identification found (0: none identified); ``winding_conductance_s`` and ``winding_time_constant_s`` the
    winding's 1 / R (S) and L / R (s), which the speed's feedback rests on (0: none identified, no feedback);
    ``saturation_per_a2`` the torque constant's fall with current, c of K_p i_p (1 - c i_p^2), per A^2 (0: none
    identified); ``epsilon_pinned`` whether eps came from a static trial (`ilcpmac.identify.static`), not from the
    inertia the bench gives; ``loop_winding_covariance`` that of the loop's time constants and delay and the
    winding's L / R and conductance (`IdentificationResult.loop_winding_covariance`; zeros: not known).
    """

    delta: float
    epsilon: float
    alpha: np.ndarray
    beta_a: np.ndarray
    cogging_nm: np.ndarray | None
    calibration: SensorCalibration
    delta_std: float = 0.0
    epsilon_std: float = 0.0
    alpha_std: np.ndarray = field(default_factory=lambda: np.zeros(3))
    beta_std_a: np.ndarray = field(default_factory=lambda: np.zeros(3))
    current_loop: CurrentLoop = field(default_factory=CurrentLoop)
    sensor_highpass_hz: float = 0.0
    sensor_delay_s: float = 0.0
    winding_conductance_s: float = 0.0
    winding_time_constant_s: float = 0.0
    saturation_per_a2: float = 0.0
    epsilon_pinned: bool = False
    loop_winding_covariance: np.ndarray = field(default_factory=lambda: np.zeros((6, 6)))

    def __post_init__(self) -> None:
        """Every array read-only (`frozen`): each stage shares them."""
        for name in ("alpha", "beta_a", "cogging_nm", "alpha_std", "beta_std_a", "loop_winding_covariance"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, frozen(getattr(self, name)))
        object.__setattr__(self, "current_loop", CurrentLoop(frozen(self.current_loop.time_constant_s),
                                                             self.current_loop.delay_s))
        object.__setattr__(self, "calibration", self.calibration.read_only())

    @classmethod
    def from_result(cls, result: IdentificationResult | dict, calibration: SensorCalibration) -> Identified:
        """From the identification (or its JSON, e.g. a simulator's truth), which must hold `PIPELINE_NEEDS`, or
        `SENSORLESS_PIPELINE_NEEDS` on the encoder-derived torque.

        Raises
        ------
        IdentificationError
            When the identification has no eps.
        """
        if isinstance(result, dict):
            result = IdentificationResult.from_json(result)
        if result.epsilon is None:
            raise IdentificationError("the pipeline needs eps, which the identification could not estimate")

        def std(value, default):
            return np.asarray(default if value is None else value, float)

        return cls(
            delta=1.0 if result.delta is None else float(result.delta), epsilon=float(result.epsilon),
            alpha=np.asarray(result.alpha, float),
            beta_a=np.asarray(result.beta, float), cogging_nm=result.cogging_nm, calibration=calibration,
            delta_std=float(std(result.delta_std, 0.0)), epsilon_std=float(std(result.epsilon_std, 0.0)),
            alpha_std=std(result.alpha_std, np.zeros(3)), beta_std_a=std(result.beta_std, np.zeros(3)),
            current_loop=result.current_loop or CurrentLoop(),
            sensor_highpass_hz=float(result.torque_sensor_highpass_hz or 0.0),
            sensor_delay_s=float(result.torque_sensor_delay_s or 0.0),
            winding_conductance_s=float(result.winding_conductance_s or 0.0),
            winding_time_constant_s=float(result.winding_time_constant_s or 0.0),
            saturation_per_a2=float(result.saturation_per_a2 or 0.0), epsilon_pinned="static" in result.methods,
            loop_winding_covariance=std(result.loop_winding_covariance, np.zeros((6, 6))))

    def loop_at(self, calibration: SensorCalibration) -> CurrentLoop:
        """The current loop while the controller uses ``calibration``.

        The PI loop closes on the measured current, (G*_s^-1 G_s)^-1 = 1 / (epsilon alpha_p)
        times the true one, so each phase's time constant scales with epsilon alpha_p.
        """
        return self.current_loop.scaled(self.epsilon_alpha_at(calibration) / self.epsilon_alpha_at(self.calibration))

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

    def sensor_response(self, harmonics: np.ndarray, speed_hz: float) -> np.ndarray:
        """The torque sensor's shape per harmonic at a speed, its gain delta aside: the identified high-pass and
        delay (`ilcpmac.core.torque_sensor.harmonic_response`); 1 at h = 0 (the mean is not measured)."""
        return harmonic_response(harmonics, speed_hz, self.sensor_highpass_hz, self.sensor_delay_s)

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

    def __post_init__(self) -> None:
        """The stage's bench with a read-only calibration (`SensorCalibration.read_only`; its back-EMF table and
        the identification are read-only already)."""
        object.__setattr__(self, "description", replace(self.description,
                                                        calibration=self.description.calibration.read_only()))

    @cached_property
    def _backemf_power(self) -> tuple[np.ndarray, np.ndarray]:
        """The bench's back-EMF harmonics and their power (`ilcpmac.core.current_loop.backemf_power`)."""
        return backemf_power(self.description.backemf_nm_per_a)

    def torque_response(self, harmonics: np.ndarray, speed_hz: float, calibration: SensorCalibration,
                        loop_scale: float = 1.0) -> np.ndarray:
        """Torque reference to true torque at mechanical harmonics h, while the controller uses
        ``calibration``: the phases' mean of epsilon alpha_p times the identified current loop
        (`CurrentLoop.response`, its time constants times ``loop_scale``), before the speed's feedback
        (`shaft_response`)."""
        ident = self.identified
        loop = ident.loop_at(calibration).scaled(loop_scale)
        motor = self.description.motor
        response = loop.response(harmonics, speed_hz, motor.counts_per_rev, motor.lines_per_count)
        return np.mean(ident.epsilon_alpha_at(calibration) * response, axis=1)

    def shaft_response(self, harmonics: np.ndarray, speed_hz: float, calibration: SensorCalibration,
                       torque_nm: float, loop_scale: float = 1.0) -> np.ndarray:
        """`torque_response` times the speed's feedback at the set point (``torque_nm``, ``speed_hz``): the
        torque reference to the torque the shaft carries and the trial measures, G^ = M G: what a stage
        learning from the measured torque (or from its block of the pipeline's fit) divides by."""
        loop = self.identified.loop_at(calibration).scaled(loop_scale)
        return (self.torque_response(harmonics, speed_hz, calibration, loop_scale)
                * self.speed_feedback(harmonics, speed_hz, torque_nm, loop))

    def speed_feedback(self, harmonics: np.ndarray, speed_hz: float, torque_nm: float,
                       loop: CurrentLoop) -> np.ndarray:
        """M(h): the part of a torque ripple at mechanical harmonic h that reaches the shaft at a set point
        (``torque_nm``, ``speed_hz``) once its speed ripple's back-EMF has passed the current ``loop``
        (`ilcpmac.core.current_loop.speed_feedback`): the bench's inertia and back-EMF table, the identified
        winding, and the brake set for the speed, b = |torque| / (2 pi |speed|) (infinite at standstill)."""
        ident = self.identified
        brake = abs(torque_nm) / (2.0 * np.pi * abs(speed_hz)) if speed_hz else np.inf
        return speed_feedback(harmonics, abs(speed_hz), loop, self._backemf_power,
                              ident.winding_conductance_s, ident.winding_time_constant_s,
                              self.description.motor.inertia_kgm2, brake)


@dataclass(frozen=True)
class Block:
    """A stage's part of a trial's joint fit.

    Attributes
    ----------
    estimate : ndarray, shape (k,)
        The block's coefficients (minimum-norm where not identifiable).
    information : ndarray, shape (k, k)
        Marginal Fisher information; singular in directions the trial cannot see.
    """

    estimate: np.ndarray
    information: np.ndarray


@dataclass(frozen=True)
class Frame:
    """What a finished trial tells the stages.

    Attributes
    ----------
    blocks : dict of name -> Block
        Each stage's block of the trial's joint fit over all stages' columns, of the measured torque
        less the trial's feed-forward through the identified response (ilcpmac.pipeline.pipeline).
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

    blocks: dict[str, Block]
    torque_harmonics_nm: np.ndarray
    torque_harmonics_var: np.ndarray
    delta: float
    speed_hz: float
    learning_gain: float = 1.0

    def block(self, name: str) -> Block:
        """Stage ``name``'s block of the joint fit."""
        return self.blocks[name]


@runtime_checkable
class Stage(Protocol):
    """A compensation stage.

    Optional: ``revert(self, state: dict, key: str) -> None``: go back to ``state`` (what `state`
    returned after an earlier trial) for set point ``key`` only; what was learned at other set points
    stays (a set point ``state`` does not know is unlearned). The guard uses it through
    `ilcpmac.pipeline.pipeline.Pipeline.revert`; a stage without it is restored whole (`restore`).

    The pipeline makes each call in a thread of the stages' for a bounded time, gives it read-only arrays (the
    trial, the request, the frame) and checks what it returns (`ilcpmac.pipeline.pipeline.BoundedStage`); a
    failure stops the run with one line naming the stage (docs/writing-a-stage.md, "What the pipeline bounds").
    """

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


@dataclass(frozen=True)
class NoOptions:
    """The options schema of a stage that takes none: any key in its ``[stages.NAME]`` is refused."""


def parse_options(options: dict, schema: type[T], stage: str) -> T:
    """A stage's ``[stages.NAME]`` ``options`` as its ``schema``, a frozen dataclass whose fields are declared with
    the schema kit (`ilcpmac.core.schema.setting`: check, doc, default; `param` for a required one), as a config's
    keys are: an unknown key, a wrong type or a value out of range raises one `ConfigError` naming
    ``[stages.NAME] key``. A factory that names it ``options_schema`` has its options checked with the config,
    before the first trial (`ilcpmac.stages.registry.check_options_of`)."""
    parsed: T = parse_section(options, schema, "", f"stages.{stage}")
    return parsed


def read_options(options: dict, defaults: dict[str, Any], stage: str) -> dict[str, Any]:
    """A stage's options over its defaults; unknown keys and wrong types raise `ConfigError` (an option whose
    default is None, left out, is typed by its range's check)."""
    unknown = sorted(set(options) - set(defaults))
    if unknown:
        raise ConfigError(f"[stages.{stage}] unknown key {unknown[0]!r} (known: {', '.join(defaults)})")
    values = dict(defaults)
    for key, value in options.items():
        if defaults[key] is None:  # an option left out by default: its range checks what it may be
            values[key] = value
            continue
        kind = type(defaults[key])
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if type(value) is not kind:
            raise ConfigError(f"[stages.{stage}] {key}: expected {kind.__name__}, got {value!r}")
        values[key] = value
    return values


def check_options(options: dict, defaults: dict[str, Any], ranges: Mapping[str, tuple[Callable, str]],
                  stage: str) -> dict[str, Any]:
    """A stage's options over its defaults (`read_options`), each within its range.

    ``ranges`` maps a key to ``(check, doc)``; a value its check refuses raises
    `ConfigError` naming ``[stages.NAME] key``.
    """
    values = read_options(options, defaults, stage)
    for key, (check, doc) in ranges.items():
        if not check(values[key]):
            raise ConfigError(f"[stages.{stage}] {key}: invalid value {shown(values[key])} ({doc})")
    return values
