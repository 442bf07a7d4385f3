"""Issue 34, items 1, 2 and 5: check what is sent, send what was checked.

A stage's answer, and every request the guard passes on, is copied once into values the host owns (builtin
``float`` and ``int``, immutable float64 tables: `owned_request`); only that copy is checked and only it goes on.
A value whose class lies to comparisons, an array whose maker changes it after the check, or a stage writing
through the trial it was given cannot pass as one thing and run as another.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from ilcpmac.backends.guard import LimitGuard
from ilcpmac.core.errors import SafetyError, StageError
from ilcpmac.core.records import SensorCalibration, TrialRequest, immutable
from ilcpmac.pipeline.pipeline import Pipeline, shared_trial
from ilcpmac.pipeline.safety import identified_truth, owned_request

#: the operators a lying number answers for: comparisons and arithmetic, not its conversions
_OPERATORS = ("lt", "le", "gt", "ge", "eq", "ne", "add", "radd", "sub", "rsub", "mul", "rmul", "truediv", "rtruediv",
              "floordiv", "rfloordiv", "neg", "abs")


def claiming(base: type, claimed, operators: tuple[str, ...] = _OPERATORS) -> type:
    """A subclass of ``base`` whose instances are ``claimed`` to each of ``operators`` (comparisons and arithmetic),
    while the value they hold, as a kernel or a wire encoder reads it, is the one they were made with."""

    def forward(name):
        method = getattr(base, f"__{name}__", None)
        return None if method is None else (lambda self, *args: method(base(claimed), *args))

    methods = {f"__{name}__": f for name in operators if (f := forward(name)) is not None}
    return type(f"Claims{claimed}", (base,), methods)


#: a float claiming to be 1.0 Hz or N m, an int claiming to be 2 revolutions
LyingFloat = claiming(float, 1.0)
LyingInt = claiming(int, 2)


class QuietArray(np.ndarray):
    """An array that is zeros to every ufunc (np.abs, np.isfinite, comparisons, reductions): it looks harmless to a
    check, while the values it holds, as a wire encoder reads its buffer, are what it was made with."""

    def __array_ufunc__(self, ufunc, method, *inputs, **kwargs):
        zeros = [np.zeros(np.shape(x)) if isinstance(x, QuietArray) else x for x in inputs]
        return getattr(ufunc, method)(*zeros, **kwargs)


def held(value):
    """What ``value`` holds, read past its class's operators (as numba, struct or a buffer read it)."""
    if isinstance(value, np.ndarray):
        return np.ndarray.view(value, np.ndarray).copy()
    return float.__float__(value) if isinstance(value, float) else int.__int__(value)


class Recording:
    """A backend that keeps what reaches it (as it holds it: `held`) and calls ``during`` as the trial runs."""

    max_parallel_trials = 1

    def __init__(self, during=lambda: None) -> None:
        self.requests: list[TrialRequest] = []
        self.held: list[dict] = []
        self.during = during

    def run_trial(self, request):
        self.during()
        self.requests.append(request)
        self.held.append({f.name: held(getattr(request, f.name)) for f in dataclasses.fields(request)
                          if f.name != "calibration"})


def guard_of(limits_bench, backend) -> LimitGuard:
    _, description, identified, limits, _ = limits_bench
    guard = LimitGuard(backend, description, limits)
    guard.truth = identified_truth(identified)
    return guard


@pytest.mark.parametrize("changes, refused", [
    ({"speed_setpoint_hz": LyingFloat(2.27)}, r"speed set point 2.27 Hz exceeds 1.5 Hz"),
    ({"revolutions": LyingInt(600)}, r"the trial lasts 801.3 s \(1 warm-up and 600 revolutions at 0.75 Hz\), "
                                     r"beyond 600 s"),
    ({"revolutions": LyingInt(2000)}, r"2000 revolutions of 1024 counts \(2048000 samples\) exceed 2e\+06"),
    ({"feedforward_nm": np.full(1024, 50.0).view(QuietArray)}, r"torque reference 53 N m"),
])
def test_the_guard_checks_the_value_a_lying_class_holds(limits_bench, changes, refused):
    """Before, each passed the guard (its checks asked the lying objects) and the backend got the values they hold:
    2.27 Hz against 1.5, 600 revolutions (801 s) against 600 s, 50 N m of feed-forward past an 8 N m limit."""
    backend = Recording()
    with pytest.raises(SafetyError, match=refused):
        guard_of(limits_bench, backend).run_trial(limits_bench[4].with_changes(**changes))
    assert backend.requests == []


def test_what_the_guard_sends_is_plain_and_its_own(limits_bench):
    base = limits_bench[4]
    asked = base.with_changes(torque_setpoint_nm=LyingFloat(2.0), speed_setpoint_hz=np.float32(0.5),
                              revolutions=np.int64(2), seed=LyingInt(5),
                              feedforward_nm=np.full(1024, 0.1).view(QuietArray))
    sent = owned_request(asked, 1024)
    assert type(sent.torque_setpoint_nm) is float and type(sent.speed_setpoint_hz) is float
    assert type(sent.revolutions) is int and type(sent.seed) is int and sent.seed == 5
    for table in (sent.feedforward_nm, sent.excitation_nm, sent.calibration.current_scale,
                  sent.calibration.current_offset):
        assert type(table) is np.ndarray and table.dtype == np.float64 and not table.flags.writeable
        with pytest.raises(ValueError, match="WRITEABLE"):
            table.setflags(write=True)
    np.testing.assert_array_equal(np.asarray(sent.feedforward_nm), np.full(1024, 0.1))


def test_a_number_lying_in_its_conversion_too_is_sent_as_it_was_checked(limits_bench):
    """Converted once: whatever ``float()`` says is what is checked and what the backend gets (here 1 Hz)."""
    backend = Recording()
    speed = claiming(float, 1.0, (*_OPERATORS, "float"))(2.27)
    guard_of(limits_bench, backend).run_trial(limits_bench[4].with_changes(speed_setpoint_hz=speed))
    (sent,) = backend.requests
    assert type(sent.speed_setpoint_hz) is float and backend.held[0]["speed_setpoint_hz"] == 1.0


def test_a_calibration_changed_after_the_check_does_not_reach_the_backend(limits_bench):
    """Before, the guard passed its caller's request on: a writeable calibration array the stage still held,
    multiplied by 3 while the trial ran, put 3x the checked current scale on the bench."""
    base = limits_bench[4]
    held = np.array(base.calibration.current_scale)
    asked = base.with_changes(calibration=SensorCalibration(held, base.calibration.current_offset,
                                                            base.calibration.torque_gain))

    def meanwhile():
        held[:] *= 3.0  # the stage's thread, during the trial

    backend = Recording(meanwhile)
    guard_of(limits_bench, backend).run_trial(asked)
    (sent,) = backend.requests
    np.testing.assert_array_equal(sent.calibration.current_scale, base.calibration.current_scale)
    np.testing.assert_array_equal(held, 3.0 * base.calibration.current_scale)


class Stage:
    """A stage whose answer is ``change(request)``, learning with ``learn(trial)``."""

    def __init__(self, name, change=lambda r: r, learn=lambda trial: None) -> None:
        self.name, self.change, self._learn = name, change, learn

    def shape(self, request):
        return self.change(request)

    def columns(self, trial):
        return None

    def learn(self, trial, frame):
        self._learn(trial)


def test_the_pipeline_uses_the_values_it_checked(limits_bench):
    """A stage answering with a lying speed and an array it changes afterwards: the pipeline's request holds the
    plain values it checked (refused here, as the speed is beyond the limit), and a lying revolutions likewise."""
    _, description, identified, limits, base = limits_bench
    liar = Pipeline([Stage("liar", lambda r: r.with_changes(speed_setpoint_hz=LyingFloat(2.27)))],
                    description, identified, limits, 40)
    with pytest.raises(SafetyError, match=r"^stage 'liar': speed set point 2.27 Hz exceeds 1.5 Hz"):
        liar.shape(base)
    kept = np.zeros(1024)
    holder = Pipeline([Stage("holder", lambda r: r.with_changes(feedforward_nm=kept))], description, identified,
                      limits, 40)
    shaped = holder.shape(base)
    kept[:] = 1e3
    assert np.abs(shaped.feedforward_nm).max() == 0.0


def test_a_stage_cannot_write_through_the_trial_it_is_given(limits_bench):
    """Before, the stage's read-only view could be made writeable again (its base was the campaign's own array):
    a stage doubled the torque it learned from, and the run persisted the doubled trials, sealed."""
    backend, description, identified, limits, base = limits_bench
    trial = dataclasses.replace(backend.run_trial(base), request=base)
    torque = trial.torque_nm.copy()

    def doubles(shared):
        shared.torque_nm.setflags(write=True)
        shared.torque_nm[:] *= 2

    def through_its_base(shared):
        np.ndarray.setflags(shared.torque_nm.base, write=True)

    for learn in (doubles, through_its_base):
        pipeline = Pipeline([Stage("writer", learn=learn)], description, identified, limits, 40)
        with pytest.raises(StageError, match="^stage 'writer': learn raised"):
            pipeline.learn(trial)
    np.testing.assert_array_equal(trial.torque_nm, torque)


def test_stages_see_what_a_bench_measures(limits_bench):
    backend, _, _, _, base = limits_bench
    trial = dataclasses.replace(backend.run_trial(base), request=base)
    shared = shared_trial(trial)
    assert shared.torque_true_nm is None and shared.i_true_a is None and shared.speed_true_rad_s is None
    np.testing.assert_array_equal(shared.torque_nm, trial.torque_nm)
    assert not np.shares_memory(shared.torque_nm, trial.torque_nm)
    assert not shared.request.feedforward_nm.flags.writeable


def test_immutable_keeps_shape_and_dtype():
    for value in (np.arange(6.0).reshape(2, 3), np.arange(4), np.array(2.5), np.zeros((0, 3)),
                  np.arange(8.0)[::2], np.array([1 + 2j])):
        copy = immutable(value)
        assert copy.shape == value.shape and copy.dtype == value.dtype and not copy.flags.writeable
        np.testing.assert_array_equal(copy, value)
