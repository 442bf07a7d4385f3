"""The compensation record: its interpolation and fade-out, its JSON and its hostile variants; the replay stage."""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from ilcpmac.backends.base import BenchLimits
from ilcpmac.backends.simulated import SimulatorBackend
from ilcpmac.compensation import MAX_TABLE_VALUES, Compensation, FadeOut
from ilcpmac.core.errors import BenchFormatError, ConfigError
from ilcpmac.core.records import SensorCalibration, TrialRequest
from ilcpmac.pipeline.pipeline import Pipeline
from ilcpmac.pipeline.safety import SafetyLimits
from ilcpmac.sim.bench import true_result
from ilcpmac.stages.base import Identified, StageSetup
from ilcpmac.stages.registry import build_stages, installed_stages
from ilcpmac.stages.replay import Replay

CPR = 64
TORQUES_NM = np.array([1.0, 3.0, 5.0])
SPEEDS_HZ = np.array([0.5, 2.0])
CALIBRATION = SensorCalibration([14.0, 14.2, 13.9], [1.5, -2.0, 0.25], 0.908)
NEVER = FadeOut(math.inf, math.inf)


def bilinear_tables(seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Per count coefficients (a, b, c, d) and tables a + b T + c S + d T S at the grid points: bilinear
    interpolation gives that function exactly anywhere inside the grid."""
    coef = np.random.default_rng(seed).normal(0.0, 0.01, (4, CPR))
    T, S = TORQUES_NM[:, None, None], SPEEDS_HZ[None, :, None]
    return coef, coef[0] + coef[1] * T + coef[2] * S + coef[3] * T * S


def make(fade: FadeOut = NEVER, seed: int = 1) -> Compensation:
    return Compensation(CPR, CALIBRATION, TORQUES_NM, SPEEDS_HZ, bilinear_tables(seed)[1], fade)


def bilinear(coef: np.ndarray, torque_nm: float, speed_hz: float) -> np.ndarray:
    return coef[0] + coef[1] * torque_nm + coef[2] * speed_hz + coef[3] * torque_nm * speed_hz


# ---------------------------------------------------------------- interpolation and fade-out


def test_the_feedforward_is_each_table_exactly_at_its_grid_point():
    c = make()
    for i, t in enumerate(TORQUES_NM):
        for k, s in enumerate(SPEEDS_HZ):
            assert np.array_equal(c.feedforward_nm(t, s), c.tables_nm[i, k])


@given(st.floats(1.0, 5.0), st.floats(0.5, 2.0))
def test_the_feedforward_is_bilinear_between_the_points(torque_nm, speed_hz):
    coef = bilinear_tables()[0]
    np.testing.assert_allclose(make().feedforward_nm(torque_nm, speed_hz), bilinear(coef, torque_nm, speed_hz),
                               rtol=0, atol=1e-15)


@given(st.floats(-1e5, 1e5), st.floats(1e-3, 1e3))
def test_the_feedforward_is_clamped_into_the_grid(torque_nm, speed_hz):
    coef = bilinear_tables()[0]
    clamped = bilinear(coef, np.clip(torque_nm, 1.0, 5.0), np.clip(speed_hz, 0.5, 2.0))
    np.testing.assert_allclose(make().feedforward_nm(torque_nm, speed_hz), clamped, rtol=0, atol=1e-15)


def test_an_axis_of_one_point_is_constant_along_it():
    tables = np.random.default_rng(2).normal(0.0, 0.01, (1, 2, CPR))
    c = Compensation(CPR, CALIBRATION, [3.0], SPEEDS_HZ, tables, NEVER)
    for torque_nm in (-7.0, 3.0, 40.0):
        assert np.array_equal(c.feedforward_nm(torque_nm, 0.5), tables[0, 0])
        np.testing.assert_allclose(c.feedforward_nm(torque_nm, 1.25), tables[0].mean(axis=0), atol=1e-16)


@pytest.mark.parametrize("fade, factors", [
    (FadeOut(3.0, 5.0), {0.0: 1.0, 3.0: 1.0, 3.5: 0.75, 4.0: 0.5, 5.0: 0.0, 9.0: 0.0}),
    (FadeOut(3.0, 3.0), {2.9: 1.0, 3.0: 1.0, 3.0 + 1e-12: 0.0}),
    (NEVER, {0.0: 1.0, 1e300: 1.0, math.inf: 1.0}),
    (FadeOut(0.0, 1.0), {0.0: 1.0, 0.25: 0.75, 1.0: 0.0}),
])
def test_the_fade_out_factor(fade, factors):
    assert {speed: fade.factor(speed) for speed in factors} == factors


@pytest.mark.parametrize("full_hz, zero_hz", [(5.0, 3.0), (-1.0, 2.0), (math.nan, 2.0), (1.0, math.nan),
                                              (1.0, math.inf)])
def test_a_fade_out_that_is_not_one_is_refused(full_hz, zero_hz):
    with pytest.raises(ValueError, match="key 'fade'"):
        FadeOut(full_hz, zero_hz)


def test_the_fade_out_takes_the_unclamped_speed():
    c = make(FadeOut(3.0, 5.0))
    top = c.tables_nm[:, -1]
    np.testing.assert_array_equal(c.feedforward_nm(3.0, 2.5), top[1])
    np.testing.assert_allclose(c.feedforward_nm(3.0, 4.5), 0.25 * top[1], rtol=1e-15)
    assert not np.any(c.feedforward_nm(3.0, 5.0))


def test_a_record_of_both_directions_interpolates_through_zero_speed_and_fades_by_its_size():
    """Tables cogging + S lag per count at -2, -0.5, 0.5 and 2 Hz (the loop's inverse is linear in the signed
    speed): the record gives that function at every speed between -2 and 2 Hz, the cogging alone at 0 Hz, and fades
    alike at -4.5 and 4.5 Hz."""
    rng = np.random.default_rng(5)
    cogging, lag = rng.normal(0.0, 0.01, (2, CPR))
    speeds = np.array([-2.0, -0.5, 0.5, 2.0])
    tables = np.stack([cogging + s * lag for s in speeds])[None]
    c = Compensation(CPR, CALIBRATION, np.array([2.0]), speeds, tables, FadeOut(3.0, 5.0))
    for s in (-1.7, -0.5, -0.1, 0.0, 0.3, 1.2):
        np.testing.assert_allclose(c.feedforward_nm(2.0, s), cogging + s * lag, rtol=0, atol=1e-15)
    np.testing.assert_allclose(c.feedforward_nm(2.0, -4.5), 0.25 * tables[0, 0], rtol=1e-15)
    np.testing.assert_allclose(c.feedforward_nm(2.0, 4.5), 0.25 * tables[0, -1], rtol=1e-15)
    assert not np.any(c.feedforward_nm(2.0, -5.0)) and not np.any(c.feedforward_nm(2.0, 5.0))


def test_apply_sets_the_calibration_and_adds_the_feedforward():
    c = make(FadeOut(3.0, 5.0))
    before = np.random.default_rng(3).normal(0.0, 0.01, CPR)
    request = TrialRequest(2.0, 1.0, 4, before, np.zeros(CPR), SensorCalibration(np.ones(3), np.zeros(3), 1.0), 9)
    applied = c.apply(request)
    assert applied.calibration is CALIBRATION
    np.testing.assert_array_equal(applied.feedforward_nm, before + c.feedforward_nm(2.0, 1.0))
    kept = (applied.torque_setpoint_nm, applied.speed_setpoint_hz, applied.revolutions, applied.seed)
    assert kept == (2.0, 1.0, 4, 9)
    with pytest.raises(ValueError, match="32 counts per revolution"):
        c.apply(request.with_changes(feedforward_nm=np.zeros(32)))


# ---------------------------------------------------------------- JSON


def assert_same(a: Compensation, b: Compensation) -> None:
    assert a.counts_per_rev == b.counts_per_rev and a.fade == b.fade
    for name in ("current_scale", "current_offset", "torque_gain"):
        assert np.array_equal(getattr(a.calibration, name), getattr(b.calibration, name))
    for name in ("torques_nm", "speeds_hz", "tables_nm"):
        assert np.array_equal(getattr(a, name), getattr(b, name))


@pytest.mark.parametrize("fade", [FadeOut(3.0, 5.0), FadeOut(2.5, 2.5), NEVER])
def test_json_round_trip_is_exact(fade):
    c = make(fade)
    data = json.loads(json.dumps(c.to_json(), allow_nan=False))
    assert data["format"] == 1 and data["units"]["tables_nm"].startswith("N m")
    assert_same(Compensation.from_json(data), c)


def test_read_gives_the_record_written(tmp_path):
    c = make(FadeOut(3.0, 5.0))
    path = tmp_path / "compensation.json"
    path.write_text(json.dumps(c.to_json(), indent=1))
    assert_same(Compensation.read(path), c)


def valid() -> dict:
    return json.loads(json.dumps(make(FadeOut(3.0, 5.0)).to_json()))


def changed(path: str, value=None, delete: bool = False) -> dict:
    """The valid record with the key at dotted ``path`` set to ``value`` (or deleted)."""
    data = valid()
    *parents, key = path.split(".")
    target = data
    for part in parents:
        target = target[part]
    if delete:
        del target[key]
    else:
        target[key] = value
    return data


def one_line_error(data, match: str) -> str:
    with pytest.raises(BenchFormatError) as e:
        Compensation.from_json(data, "run/compensation.json")
    message = str(e.value)
    assert message.startswith("run/compensation.json: ") and "\n" not in message and len(message) < 400, message
    assert match in message, message
    return message


HOSTILE = [
    (changed("format", delete=True), "missing key 'format'"),
    (changed("calibration.torque_gain", delete=True), "missing key 'calibration.torque_gain'"),
    (changed("fade.zero_hz", delete=True), "missing key 'fade.zero_hz'"),
    (changed("extra", 1), "unknown key 'extra'"),
    (changed("fade.middle_hz", 1.0), "unknown key 'fade.middle_hz'"),
    (changed("format", 2), "key 'format'"),
    (changed("format", True), "key 'format'"),
    (changed("units", {}), "key 'units'"),
    (changed("units.tables_nm", "mN m"), "key 'units'"),
    (changed("counts_per_rev", 64.0), "key 'counts_per_rev'"),
    (changed("counts_per_rev", 3), "key 'counts_per_rev'"),
    (changed("counts_per_rev", 2**21), "key 'counts_per_rev'"),
    (changed("counts_per_rev", 65), "key 'tables_nm'"),
    (changed("torques_nm", [3.0, 1.0, 5.0]), "key 'torques_nm': must be strictly ascending"),
    (changed("torques_nm", [1.0, 1.0, 5.0]), "key 'torques_nm': must be strictly ascending"),
    (changed("torques_nm", []), "key 'torques_nm'"),
    (changed("torques_nm", [1.0, "3", 5.0]), "key 'torques_nm'"),
    (changed("torques_nm", [1.0, True, 5.0]), "key 'torques_nm'"),
    (changed("torques_nm", [1.0, None, 5.0]), "key 'torques_nm'"),
    (changed("torques_nm", [1.0, 1e999, 5.0]), "key 'torques_nm': value [1] is not finite"),
    (changed("torques_nm", [1.0, 3.0, 10**400]), "key 'torques_nm'"),
    (changed("torques_nm", [1.0, 3.0, 2e5]), "key 'torques_nm'"),
    (changed("torques_nm", 3.0), "key 'torques_nm'"),
    (changed("torques_nm", [[1.0, 3.0, 5.0]]), "key 'torques_nm'"),
    (changed("speeds_hz", [0.0, 2.0]), "key 'speeds_hz': a table is learned turning, never at 0 Hz"),
    (changed("speeds_hz", [-2e3, 2.0]), "key 'speeds_hz': value 0 must lie in"),
    (changed("speeds_hz", [2.0, 0.5]), "key 'speeds_hz': must be strictly ascending"),
    (changed("speeds_hz", list(np.linspace(0.1, 10.0, 101))), "key 'speeds_hz': needs 1 to 100 values"),
    (changed("tables_nm", [[[0.0] * CPR] * 2] * 2), "key 'tables_nm': shape (2, 2, 64), expected (3, 2, 64)"),
    (changed("tables_nm", [[[0.0] * CPR, [0.0] * 63]] * 3), "key 'tables_nm'"),
    (changed("tables_nm", [[[0.0] * CPR] * 2] * 2 + [[[0.0] * CPR, [1e999] * CPR]]), "value [2, 1, 0] is not finite"),
    (changed("tables_nm", {"a": 1}), "key 'tables_nm'"),
    (changed("calibration.current_scale", [14.0, 14.0]), "key 'calibration.current_scale'"),
    (changed("calibration.current_scale", [14.0, -1.0, 14.0]), "key 'calibration.current_scale'"),
    (changed("calibration.current_offset", [0.0, 0.0, 2e9]), "key 'calibration.current_offset'"),
    (changed("calibration.torque_gain", 0.0), "key 'calibration.torque_gain'"),
    (changed("calibration.torque_gain", "0.9"), "key 'calibration.torque_gain'"),
    (changed("calibration", [1, 2, 3]), "key 'calibration' must be an object"),
    (changed("fade.full_hz", 6.0), "key 'fade'"),
    (changed("fade.zero_hz", None), "key 'fade'"),
    (changed("fade.full_hz", "3"), "key 'fade.full_hz'"),
    ([valid()], "the file must be an object"),
]


@pytest.mark.parametrize("data, match", HOSTILE, ids=[m for _, m in HOSTILE])
def test_hostile_json_is_one_line_naming_the_file_and_key(data, match):
    one_line_error(data, match)


def test_a_table_of_too_many_values_is_refused_before_it_is_read():
    data = changed("speeds_hz", list(np.linspace(0.1, 10.0, 100)))
    data["torques_nm"] = list(np.linspace(0.0, 99.0, 100))
    data["counts_per_rev"] = MAX_TABLE_VALUES // 10_000 + 1
    data["tables_nm"] = None
    one_line_error(data, f"more than {MAX_TABLE_VALUES}")


JSON_VALUES = st.recursive(st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=5),
                           lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=5), inner,
                                                                                       max_size=3),
                           max_leaves=12)


def _paths(data: dict, prefix: str = "") -> list[str]:
    out = []
    for key, value in data.items():
        out.append(prefix + key)
        if isinstance(value, dict) and key != "units":
            out += _paths(value, prefix + key + ".")
    return out


@given(st.sampled_from(_paths(valid())), JSON_VALUES, st.booleans())
def test_any_changed_key_is_refused_in_one_line_or_read_whole(path, value, delete):
    data = changed(path, value, delete)
    try:
        c = Compensation.from_json(data, "run/compensation.json")
    except BenchFormatError as e:
        message = str(e)
        assert message.startswith("run/compensation.json: ") and "\n" not in message and len(message) < 400
        assert path.split(".")[0] in message or "the file" in message, message
    else:  # what it read is a whole record: finite, ascending, of its shapes
        assert np.all(np.isfinite(c.tables_nm)) and np.all(np.diff(c.torques_nm) > 0)
        assert c.tables_nm.shape == (c.torques_nm.size, c.speeds_hz.size, c.counts_per_rev)


@pytest.mark.parametrize("content, match", [
    (b'{"format": NaN}', "not valid JSON (NaN is not a JSON number"),
    (b'{"format": 1,', "not valid JSON"),
    (b'\xff\xfe', "not UTF-8"),
    (b"[" * 100_000 + b"]" * 100_000, "nested too deeply"),
    (b"[]", "the file must be an object"),
])
def test_a_file_that_is_not_a_record_is_one_line(tmp_path, content, match):
    path = tmp_path / "compensation.json"
    path.write_bytes(content)
    with pytest.raises(BenchFormatError, match=r"^" + str(path).replace(".", r"\.") + ": ") as e:
        Compensation.read(path)
    assert match in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("path", ["counts_per_rev", "calibration.torque_gain", "fade.zero_hz"])
def test_a_key_given_twice_is_refused_not_the_last_kept(tmp_path, path):
    """json.loads keeps the last of two equal keys; compensation.json refuses the file instead."""
    text = json.dumps(valid())
    key = path.rsplit(".", 1)[-1]
    first = text.index(f'"{key}": ')
    path_file = tmp_path / "compensation.json"
    path_file.write_text(text[:first] + f'"{key}": 1, ' + text[first:])
    with pytest.raises(BenchFormatError, match=rf"^{path_file}: not valid JSON \(key '{key}' given twice\)$"):
        Compensation.read(path_file)


@pytest.mark.parametrize("path", ["calibration.torque_gain", "fade.full_hz", "counts_per_rev"])
def test_json_true_is_not_the_number_one(path):
    one_line_error(changed(path, True), f"key '{path}'")


def test_read_refuses_a_folder_a_fifo_a_missing_and_a_too_large_file(tmp_path, monkeypatch):
    with pytest.raises(BenchFormatError, match="not a regular file"):
        Compensation.read(tmp_path)
    os.mkfifo(tmp_path / "fifo")
    with pytest.raises(BenchFormatError, match="not a regular file"):
        Compensation.read(tmp_path / "fifo")
    with pytest.raises(BenchFormatError, match="no such file"):
        Compensation.read(tmp_path / "missing.json")
    path = tmp_path / "compensation.json"
    path.write_text(json.dumps(valid()))
    monkeypatch.setattr("ilcpmac.compensation.MAX_FILE_BYTES", path.stat().st_size - 1)
    with pytest.raises(BenchFormatError, match="bytes \\(refused\\)"):
        Compensation.read(path)


# ---------------------------------------------------------------- the replay stage

H = 150


@pytest.fixture(scope="module")
def fast(small_model) -> SimulatorBackend:
    return SimulatorBackend(small_model, BenchLimits(30.0, 8.0, 1.5))


def setup_of(backend: SimulatorBackend, options: dict) -> StageSetup:
    d = backend.describe()
    truth = true_result(backend.simulator, d.calibration)
    return StageSetup(d, Identified.from_result(truth, d.calibration), H, options)


def bench_compensation(backend: SimulatorBackend) -> Compensation:
    """A compensation for the small seed bench: its controller's calibration, 10 mN m tables."""
    d = backend.describe()
    cpr = d.motor.counts_per_rev
    tables = np.random.default_rng(4).normal(0.0, 0.01, (2, 2, cpr))
    return Compensation(cpr, d.calibration, [1.0, 5.0], [0.5, 1.0], tables, FadeOut(1.2, 1.5))


def test_replay_is_a_built_in_stage():
    entry = installed_stages()["replay"]
    assert entry.distribution == "ilcpmac" and entry.load() is Replay
    assert Replay.needs == ()


def test_a_pipeline_of_replay_alone_shapes_as_the_record_applies(fast, tmp_path, monkeypatch):
    c = bench_compensation(fast)
    (tmp_path / "comp.json").write_text(json.dumps(c.to_json()))
    monkeypatch.chdir(tmp_path)  # the file is relative to the working directory
    setup = setup_of(fast, {"file": "comp.json"})
    stages = build_stages(["replay"], {"replay": setup})
    pipeline = Pipeline(stages, setup.description, setup.identified,
                        SafetyLimits(max_correction_nm=1.5, max_current_a=30.0, max_torque_nm=8.0), H)
    d = fast.describe()
    cpr = d.motor.counts_per_rev
    request = TrialRequest(3.0, 0.75, 2, np.zeros(cpr), np.zeros(cpr), SensorCalibration(d.calibration.current_scale,
                                                                                       np.zeros(3), 0.9), seed=5)
    shaped = pipeline.shape(request)
    expected = c.apply(request)
    assert np.any(expected.feedforward_nm) and shaped.calibration.to_json() == c.calibration.to_json()
    # the limits clip the feed-forward as (set point + feed-forward) - set point: the same torque reference
    np.testing.assert_array_equal(shaped.torque_reference_nm(), expected.torque_reference_nm())
    np.testing.assert_allclose(shaped.feedforward_nm, expected.feedforward_nm, rtol=0, atol=1e-15)
    trial = fast.run_trial(shaped)
    np.testing.assert_array_equal(trial.request.torque_reference_nm(), expected.torque_reference_nm())
    pipeline.learn(trial)
    assert stages[0].state() == {} and stages[0].columns(trial) is None
    np.testing.assert_array_equal(pipeline.shape(request).torque_reference_nm(), expected.torque_reference_nm())


@pytest.mark.parametrize("options, error, match", [
    ({}, ConfigError, r"\[stages.replay\] file: missing \(the compensation.json to replay"),
    ({"file": ""}, ConfigError, r"\[stages.replay\] file: invalid value ''"),
    ({"file": 3}, ConfigError, r"\[stages.replay\] file: expected a string, got 3"),
    ({"file": "x.json", "gain": 1.0}, ConfigError, r"\[stages.replay\] unknown key 'gain'"),
    ({"file": "missing.json"}, BenchFormatError, "missing.json: no such file"),
    ({"file": "other.json"}, ConfigError,
     r"\[stages.replay\] file: other.json has counts_per_rev = 64, the bench 1024"),
])
def test_replay_options_are_checked_in_one_line(fast, tmp_path, monkeypatch, options, error, match):
    (tmp_path / "other.json").write_text(json.dumps(make().to_json()))
    monkeypatch.chdir(tmp_path)
    with pytest.raises(error, match=match):
        Replay(setup_of(fast, options))

