"""Stages chained in the config's order; one joint fit per trial feeds them all.

The fit (`Pipeline.frame`) explains the torque the plant adds to what the trial's feed-forward u asks
for: the feed-forward's own torque is known through the identified response at the shaft G^
(`StageSetup.shaft_response`: the gain, the current loop and the speed's feedback at the set point) and
subtracted from the measured harmonics first, y - delta G^ u (the joint fit's model, eq. 1.13, with the
feed-forward moved to the known side), as the ILC stage estimates d = e - G^ u. A block's estimate c^ is
then the torque the motor makes as the shaft carries it at that set point (its speed's feedback
included), and a stage that feeds forward -c^ / G^ from it iterates c^_{k+1} = c + (G / G^ - 1) G^ u_k,
which converges to a delivered torque G u = -c while |1 - G / G^| < 1; were u's torque left in y, the
stage would read its own feed-forward as the plant's.

The measured harmonics relate to the true torque through the measurement's response
(`TorqueMeasurement.response`: the sensor's delta, high-pass and delay, or 1 for the encoder-derived
torque in N m): the fit divides out its shape per harmonic and keeps its scalar gain (delta, or 1),
which the stages see as `Frame.delta`. The stages never know which source measured the torque.

Every call into a stage goes through `BoundedStage`: in a thread of the stages' for at most `STAGE_CALL_S`, given
immutable copies of the trial and request (a stage cannot change the data it learns from, nor what is persisted;
it sees what a bench measures, not the simulator's truth: `shared_trial`), its columns and its state checked; what
it returns is copied into values the pipeline owns before anything checks it (`Pipeline.checked`)
(`MAX_COLUMNS`, `MAX_STATE_BYTES`). Whatever else it raises, SystemExit included, and a call that
does not return in time are a `StageError` naming the stage (docs/writing-a-stage.md, "What the pipeline bounds").
"""

from __future__ import annotations

import math
import queue
import threading
from dataclasses import replace
from typing import Any, Callable, TypeVar

import numpy as np

from ilcpmac.core.errors import IlcpmacError, SafetyError, StageError
from ilcpmac.core.records import BenchDescription, SensorCalibration, TrialData, TrialRequest, immutable
from ilcpmac.pipeline.analysis import TorqueMeasurement, TorqueSpectrum, TrialAnalysis
from ilcpmac.pipeline.regression import Regression
from ilcpmac.pipeline.safety import (
    FlowingCurrent,
    MalformedRequest,
    SafetyLimits,
    calibration_violation,
    clip_to_trust_region,
    enforce_limits,
    extent_violation,
    identified_truth,
    owned_request,
    torque_violation,
)
from ilcpmac.signals.harmonics import harmonic_amplitudes
from ilcpmac.stages.base import Block, Frame, Identified, Stage, StageSetup
from ilcpmac.stages.registry import build_stages

#: the wall time a call into a stage may take, s. On the seed bench the slowest is the current-sensor stage's factory
#: (1.2 s, importing its estimators cold), a call after a trial 46 ms at most (the ilc stage's state), growing with
#: the trial's samples to about 0.2 s at [limits] max_samples_per_trial: 30 s leaves a loaded machine 25 times the
#: slowest, and a hang stops the run within a trial or two
STAGE_CALL_S = 30.0
#: the JSON text a stage's state may take, bytes: it is saved with every trial (states/trial_NNN.json). The ilc
#: stage's counts 0.25 MB on the seed bench (nine points, H = 150); 32 MiB holds 130 times that (some 1200 points, or
#: nine at H = 15 000), while a hundred trials at the bound would write 3 GiB of states
MAX_STATE_BYTES = 32 << 20
#: a float's JSON text at its longest, separator included ("-2.2250738585072014e-308, "): the state's size is
#: counted so, without writing each float as text, which would take as long as encoding it
FLOAT_JSON_BYTES = 26
#: the columns a stage's ``columns`` may return: the fit's information is K x K over all stages' columns and each
#: block's marginal information inverts the others' (O(K^3)). The built-ins return 6 (current-sensor) and 2 per
#: cogging harmonic, and the fit tells apart at most 2 per harmonic it compares (36 on the seed bench, H = 150)
MAX_COLUMNS = 512

T = TypeVar("T")


class _StageThread:
    """A daemon thread that makes the stage calls of one calling thread, one at a time: a thread per call would
    cost about a millisecond each on a loaded machine, and a campaign makes some twenty a trial."""

    def __init__(self) -> None:
        self.calls: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self.outcomes: queue.SimpleQueue[Any] = queue.SimpleQueue()
        threading.Thread(target=self._serve, name="ilcpmac stages", daemon=True).start()

    def _serve(self) -> None:
        while True:
            call, args = self.calls.get()
            try:
                self.outcomes.put((True, call(*args)))
            except BaseException as e:  # reported by `bounded`, SystemExit and all
                self.outcomes.put((False, e))


#: each calling thread's `_StageThread`, replaced after a call it abandoned
_stage_threads = threading.local()


def bounded(stage: str, what: str, call: Callable[..., T], *args: Any) -> T:
    """``call(*args)``, stage ``stage``'s ``what``, in a thread of the stages' (`_StageThread`), waited for at most
    `STAGE_CALL_S`.

    An `IlcpmacError` (a stage's own one-line error, such as a `ConfigError` of its options) and a
    KeyboardInterrupt are raised as they are.

    Raises
    ------
    StageError
        Naming the stage and ``what``, for anything else the call raised (SystemExit included), and when it has
        not returned in time: Python cannot stop a thread, so the call is abandoned in its thread (a daemon, which
        the process's exit ends; later calls get a new one) and the run stops.
    """
    worker = getattr(_stage_threads, "worker", None) or _StageThread()
    _stage_threads.worker = worker
    worker.calls.put((call, args))
    try:
        returned, value = worker.outcomes.get(timeout=STAGE_CALL_S)
    except queue.Empty:
        _stage_threads.worker = None
        raise StageError(f"stage {stage!r}: {what} did not return within {STAGE_CALL_S:g} s (STAGE_CALL_S); "
                         "abandoned in its thread") from None
    if returned:
        answer: T = value
        return answer
    if isinstance(value, KeyboardInterrupt | IlcpmacError):
        raise value
    text = " ".join(str(value).split())[:200]
    raise StageError(f"stage {stage!r}: {what} raised {type(value).__name__}{': ' if text else ''}{text}") from value


def built_stages(names: list[str], setups: dict[str, StageSetup],
                 extra: dict[str, Callable[[StageSetup], Stage]] | None = None) -> list[Stage]:
    """`build_stages`, each stage's factory called as `bounded` calls a stage."""
    return [bounded(name, "its factory", build_stages, [name], {name: setups[name]}, extra)[0] for name in names]


def _shared_request(request: TrialRequest) -> TrialRequest:
    """``request`` as a stage is given it: `immutable` copies of its tables and calibration (a stage cannot change
    the request it shapes from, nor what the pipeline or another stage holds)."""
    cal = request.calibration
    return replace(request, feedforward_nm=immutable(request.feedforward_nm),
                   excitation_nm=immutable(request.excitation_nm),
                   calibration=SensorCalibration(immutable(cal.current_scale), immutable(cal.current_offset),
                                                 cal.torque_gain))


#: the columns of a trial a stage sees: what a bench measures; and those it sees as None: the simulator's truth
SHARED_COLUMNS = ("count", "time_s", "i_ref_a", "torque_nm", "i_meas_a")
TRUE_COLUMNS = ("torque_true_nm", "i_true_a", "speed_true_rad_s")


def shared_trial(trial: TrialData) -> TrialData:
    """``trial`` as the stages are given it: `immutable` copies of the columns a bench measures (`SHARED_COLUMNS`;
    the simulator's true columns None) and of its request. Nothing a stage does to it reaches what the campaign
    analyses, persists or sends; made once per trial, shared by every stage's calls."""
    columns: dict[str, Any] = dict.fromkeys(TRUE_COLUMNS)
    columns.update({name: immutable(value) for name in SHARED_COLUMNS if (value := getattr(trial, name)) is not None})
    return replace(trial, **columns, request=None if trial.request is None else _shared_request(trial.request))


def _json_copy(state: Any, stage: str) -> dict[str, Any]:
    """A copy of ``state`` as JSON holds it: objects with text keys, lists, text, finite numbers (integers within
    64 bits), booleans, null.

    Raises `StageError` naming the stage where it is not, or when its JSON text passes `MAX_STATE_BYTES`: counted
    as it is copied, before anything is encoded, each float at its longest (`FLOAT_JSON_BYTES`).
    """
    room = MAX_STATE_BYTES

    def take(size: int) -> None:
        nonlocal room
        room -= size
        if room < 0:
            raise StageError(f"stage {stage!r}: state is more than {MAX_STATE_BYTES / 2**20:g} MiB of JSON text "
                             "(MAX_STATE_BYTES)")

    def copy(value: Any, where: str) -> Any:
        if isinstance(value, float):
            if not math.isfinite(value):
                raise StageError(f"stage {stage!r}: state {where} is {value}, not a finite number")
            take(FLOAT_JSON_BYTES)
            return float(value)
        if isinstance(value, bool) or value is None:
            take(6)
            return value
        if isinstance(value, int):
            if value.bit_length() > 64:
                raise StageError(f"stage {stage!r}: state {where} is an integer beyond 64 bits")
            take(22)  # 20 digits and a sign at most, and its separator
            return int(value)
        if isinstance(value, str):
            take(len(value) + 4)
            return value
        if isinstance(value, list | tuple):
            take(2 * len(value))
            if all(type(item) is float for item in value):  # a table, the common case: at once
                if not all(map(math.isfinite, value)):
                    bad = next(i for i, item in enumerate(value) if not math.isfinite(item))
                    raise StageError(f"stage {stage!r}: state {where}.{bad} is {value[bad]}, not a finite number")
                take(FLOAT_JSON_BYTES * len(value))
                return list(value)
            return [copy(item, f"{where}.{i}") for i, item in enumerate(value)]
        if isinstance(value, dict):
            take(4 * len(value))
            if not all(isinstance(key, str) for key in value):
                raise StageError(f"stage {stage!r}: state is not JSON: {where or 'it'} has a key that is not text")
            return {key: copy(item, f"{where}.{key}" if where else key) for key, item in value.items()}
        raise StageError(f"stage {stage!r}: state is not JSON: {where or 'it'} holds {type(value).__name__}")

    if not isinstance(state, dict):
        raise StageError(f"stage {stage!r}: state returned {type(state).__name__}, not a dict")
    try:
        copied: dict[str, Any] = copy(state, "")
        return copied
    except RecursionError:
        raise StageError(f"stage {stage!r}: state is not JSON: nested too deeply") from None


class BoundedStage:
    """A stage as the pipeline calls it: each call `bounded`, given immutable copies of the trial (`shared_trial`)
    and request, its columns and state checked.

    Parameters
    ----------
    stage : the stage.
    counts_per_rev : the bench's encoder counts per revolution (the columns' rows).
    """

    def __init__(self, stage: Stage, counts_per_rev: int) -> None:
        self.stage = stage
        self.name = stage.name
        self.counts_per_rev = counts_per_rev

    def columns(self, trial: TrialData) -> np.ndarray | None:
        """The stage's regressors for ``trial`` (`shared_trial`), checked: real, finite, shape (counts_per_rev, k)
        with k <= `MAX_COLUMNS`."""
        table = bounded(self.name, "columns", self.stage.columns, trial)
        if table is None:
            return None
        cpr, name = self.counts_per_rev, self.name
        if not isinstance(table, np.ndarray) or table.dtype.kind not in "fiu":
            raise StageError(f"stage {name!r}: columns returned {type(table).__name__}"
                             f"{' of ' + str(table.dtype) if isinstance(table, np.ndarray) else ''}, not an array "
                             "of real numbers")
        if table.ndim != 2 or table.shape[0] != cpr or table.shape[1] > MAX_COLUMNS:
            raise StageError(f"stage {name!r}: columns returned {table.shape}, not ({cpr}, k) with k <= "
                             f"{MAX_COLUMNS}")
        if not np.isfinite(table).all():
            raise StageError(f"stage {name!r}: columns returned NaN or infinity")
        return table

    def shape(self, request: TrialRequest) -> Any:
        """What the stage returns for ``request``, given its `_shared_request` copy (`Pipeline.checked` checks the
        answer: a stage may return anything)."""
        return bounded(self.name, "shape", self.stage.shape, _shared_request(request))

    def learn(self, trial: TrialData, frame: Frame) -> None:
        """The stage learns from ``trial`` (`shared_trial`)."""
        bounded(self.name, "learn", self.stage.learn, trial, frame)

    def state(self) -> dict[str, Any]:
        """A copy of the stage's state, checked (`_json_copy`)."""
        return _json_copy(bounded(self.name, "state", self.stage.state), self.name)

    def restore(self, state: dict[str, Any]) -> None:
        """The stage restores ``state``."""
        bounded(self.name, "restore", self.stage.restore, state)

    def revert(self, state: dict[str, Any], key: str) -> None:
        """The stage's own ``revert`` of set point ``key``, or its whole `restore` when it has none."""
        revert = getattr(self.stage, "revert", None)
        if revert is None:
            self.restore(state)
        else:
            bounded(self.name, "revert", revert, state, key)


class Pipeline:
    """Shapes requests through every stage and teaches every stage from each trial.

    Parameters
    ----------
    stages : list of Stage, in the config's order; the pipeline calls each through a `BoundedStage` (``bounded``).
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
        #: the stages as the pipeline calls them (`BoundedStage`)
        self.bounded = [BoundedStage(stage, description.motor.counts_per_rev) for stage in stages]
        self.description = description
        self.identified = identified
        self.limits = limits
        self.max_harmonic = max_harmonic
        self.notify = notify
        self._truth = identified_truth(identified)
        self._setup = StageSetup(description, identified, max_harmonic)

    def shape(self, request: TrialRequest) -> TrialRequest:
        """Pass ``request`` through every stage, each output checked (`stage_by_stage`), then clip the
        feed-forward to the limits (`enforce_limits`)."""
        shaped = self.stage_by_stage(request)
        request = shaped[-1][1] if shaped else request
        flowing = FlowingCurrent.at(request.calibration, self._truth)
        return enforce_limits(request, self.description.backemf_nm_per_a, self.limits, flowing)

    def stage_by_stage(self, request: TrialRequest, notify: bool = True) -> list[tuple[str, TrialRequest]]:
        """Each stage's name and its answer, checked (`checked`; ``notify``: clipping told), as ``request`` passes
        through them in turn."""
        shaped = []
        for stage in self.bounded:
            request = self.checked(stage.shape(request), stage.name, notify)
            shaped.append((stage.name, request))
        return shaped

    def checked(self, answer: object, stage: str, notify: bool = True) -> TrialRequest:
        """Stage ``stage``'s answer as a request the pipeline owns (`owned_request`: a copy in plain values, which
        alone is checked and used), its calibration clipped into the trust region (told to ``notify`` unless
        ``notify`` is False).

        Raises `SafetyError` naming the stage for anything else out of bounds: no request, NaN or
        infinity, a wrong shape, a speed, length or duration beyond the limits, or a set point that
        with its excitation breaks the torque or current limits.
        """
        cpr = self.description.motor.counts_per_rev
        try:
            request = owned_request(answer, cpr)
        except MalformedRequest as e:
            raise SafetyError(f"stage {stage!r}: {e}") from None
        why = extent_violation(request, cpr, self.limits)
        if why is not None:
            raise SafetyError(f"stage {stage!r}: {why}")
        nominal = self.description.calibration
        calibration = clip_to_trust_region(request.calibration, nominal, self._truth, self.limits)
        if calibration is not request.calibration:
            if notify and self.notify is not None:
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

    def delivered_nm(self, request: TrialRequest, speed_hz: float) -> np.ndarray:
        """Harmonics 0..H of the true torque ``request``'s feed-forward delivers at ``speed_hz`` through the
        identified response at the shaft, M^ G^ u (`StageSetup.shaft_response`), N m; 0 at h = 0 (the mean is the
        set point's)."""
        h = np.arange(1, self.max_harmonic + 1)
        u = harmonic_amplitudes(request.feedforward_nm, self.max_harmonic)[1:]
        response = self._setup.shaft_response(h, speed_hz, request.calibration, request.torque_setpoint_nm)
        return np.concatenate([[0.0], response * u])

    def frame(self, trial: TrialData, learning_gain: float = 1.0, spectrum: TorqueSpectrum | None = None,
              shared: TrialData | None = None) -> Frame:
        """The joint fit and the measured ripple spectrum of a finished trial.

        The fit is of the measured harmonics, their response's shape divided out, less the feed-forward's
        torque through the identified response, gain G^ u (module docstring). ``spectrum``: the trial's
        measured `TorqueSpectrum` up to H (`TrialAnalysis.measured`), computed here when not given; ``shared``:
        the trial as the stages see it (`shared_trial`), made here when not given.
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
        known = gain * self.delivered_nm(request, speed_hz)[h]
        shared = shared_trial(trial) if shared is None else shared
        blocks = {s.name: harmonic_amplitudes(table)[h] for s in self.bounded
                  if (table := s.columns(shared)) is not None}
        regression = Regression(mean[h] - known, variance[h], blocks)
        fitted = {name: regression.block(name) for name in blocks}
        return Frame({name: Block(immutable(b.estimate), immutable(b.information)) for name, b in fitted.items()},
                     immutable(true.harmonics_nm), immutable(true.variance_nm2), gain, speed_hz, learning_gain)

    def learn(self, trial: TrialData, learning_gain: float = 1.0, spectrum: TorqueSpectrum | None = None) -> Frame:
        """Teach every stage from ``trial`` (whose ``request`` must be set), which they all see as one
        `shared_trial`; return the frame (`frame`), whose arrays they see immutable too."""
        shared = shared_trial(trial)
        frame = self.frame(trial, learning_gain, spectrum, shared)
        for stage in self.bounded:
            stage.learn(shared, frame)
        return frame

    def state(self) -> dict[str, Any]:
        """Every stage's state, by name, each a checked copy (`BoundedStage.state`)."""
        return {stage.name: stage.state() for stage in self.bounded}

    def restore(self, state: dict[str, Any]) -> None:
        """Restore every stage from `state`."""
        for stage in self.bounded:
            stage.restore(state[stage.name])

    def revert(self, state: dict[str, Any], key: str) -> None:
        """Go back to `state` (an earlier `state`) at set point ``key`` only: a stage with the optional
        ``revert`` reverts that key and keeps what it learned at other set points; any other is restored
        whole."""
        for stage in self.bounded:
            stage.revert(state[stage.name], key)
