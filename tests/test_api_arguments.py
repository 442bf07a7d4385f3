"""Every argument of ilcpmac.api is checked where the function is called: a value of the wrong type is one
`OptionError` line naming the argument, before anything is read, simulated or written; numpy numbers are the
builtin numbers they are."""

from __future__ import annotations

import inspect
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from campaign_helpers import SMALL_CAMPAIGN
from hypothesis import given, settings
from hypothesis import strategies as st

import ilcpmac.api as ilc
from ilcpmac.core.errors import IlcpmacError, OptionError

#: valid arguments of every public function (the paths need not exist: the arguments are checked first)
VALID: dict[str, dict] = {
    "write_config": {"path": "c.toml", "changes": {}, "base": "base.toml"},
    "run": {"config": "c.toml", "out": "run", "backend": "sim", "address": "localhost:1", "seed": 1, "trials": 1,
            "budget_min": 5.0, "resume": None, "on_event": print},
    "run_quadrants": {"config": "c.toml", "out": "run", "backend": "sim", "address": "localhost:1", "seed": 1,
                      "trials": 1, "budget_min": 5.0, "resume": None, "on_event": print},
    "run_drive": {"config": "c.toml", "out": "run", "backend": "moteus", "address": "/dev/ttyACM0",
                  "write_config": False, "on_event": print},
    "print_event": {"event": None},  # no valid event without a campaign: its only argument is always hostile
    "load_run": {"run_dir": "run"},
    "identify": {"bench_dir": "bench", "torque_source": "sensor", "output": "r.json"},
    "torque_constant_nm_per_a": {"bench_dir": "bench"},
    "simulate_bench": {"config": "c.toml", "out": "b", "seed": 1, "revolutions": 3, "torque_sensor": True,
                       "static_trial": False, "on_trial": print},
    "simulate_scan": {"config": "c.toml", "out": "s", "seed": 1},
    "simulate_log": {"config": "c.toml", "out": "l", "seed": 1},
    "import_logs": {"logs": ["log.csv"], "mapping": "m.toml", "out": "o", "trial_format": "csv"},
    "import_scan": {"logs": "log.csv", "mapping": "m.toml", "out": "o"},
    "import_rolling": {"logs": "log.csv", "mapping": "m.toml", "out": "o"},
    "import_maps": {"logs": "map.npy", "mapping": "m.toml", "out": "o"},
    "export": {"source": "run", "fmt": "c", "out": "fw", "c_type": "int16", "content": "cogging",
               "torque_constant_nm_per_a": 0.3, "rated_torque_nm": 5.0},
}

PATHS = ("path", "base", "out", "resume", "run_dir", "bench_dir", "output", "source", "config", "mapping")
INTEGERS = ("seed", "trials", "revolutions")
NUMBERS = ("budget_min", "torque_constant_nm_per_a", "rated_torque_nm")
CHOICES = ("fmt", "c_type", "content", "trial_format", "torque_source")

#: values of the wrong type for arguments of each kind
HOSTILE: dict[tuple[str, ...], list] = {
    PATHS: [5, 1.5, True, b"x", "", "a\0b", "\ud800", [], {}, object(), np.float64(1.0)],
    ("logs",): [[], [5], 5, b"x", [""], ["a\0b"], [[]], np.zeros((2, 2)), np.array([], dtype=str), {"a": 1}],
    INTEGERS: [True, False, 1.5, 2.0, "3", np.float64(2.0), np.bool_(True), float("nan"), [], np.array([1]), 1j],
    NUMBERS: [True, "5", float("inf"), float("-inf"), float("nan"), -1.0, 0, [], 1j, np.array([1.0]), 10**400],
    ("torque_sensor", "static_trial", "write_config"): ["no", "yes", "", 0, 1, np.int64(1), 1.0, [], object()],
    CHOICES: ["int8", "", "CSV", 5, True, b"csv", ["csv"], np.zeros(3), object()],
    ("backend",): [5, "", b"sim", object(), ["sim"], "a\0b"],
    ("address",): [5, b"x", "a\0b", ["h:1"]],
    ("on_event", "on_trial"): [5, "print", True, [print]],
    ("changes",): [5, "x", [], {1: {}}, {"trials": object()}, {"trials": {"seed": {1, 2}}}, {"trials": {b"k": 1}},
                   {"trials": {"seed": np.zeros((2, 2))}}, {"a\0": {}}],
    ("event",): [5, "x", None, object()],
}


@pytest.fixture(autouse=True, scope="module")
def in_a_scratch_folder(tmp_path_factory):
    """Every test runs in an empty folder, which stays empty: a refused call writes nothing."""
    folder = tmp_path_factory.mktemp("cwd")
    with pytest.MonkeyPatch.context() as patch:
        patch.chdir(folder)
        yield
    assert list(folder.iterdir()) == []


def hostile(name: str) -> list:
    (values,) = [values for names, values in HOSTILE.items() if name in names]
    return values


def public_functions() -> list[str]:
    return [name for name in ilc.__all__ if inspect.isfunction(getattr(ilc, name))]


def calls() -> list[tuple[str, str]]:
    """(function, argument) of every argument of every public function."""
    return [(function, name) for function in public_functions()
            for name, p in inspect.signature(getattr(ilc, function)).parameters.items() if p.kind is not p.VAR_KEYWORD]


def assert_refused(function: Callable, arguments: dict, name: str, value) -> None:
    """``function(**arguments)``, ``arguments[name]`` being ``value``, raises one `OptionError` line naming it."""
    with pytest.raises(OptionError) as e:
        function(**arguments)
    message = str(e.value)
    assert e.value.name == name and message.startswith(f"{name}: ") and "\n" not in message, (value, message)
    assert "Traceback" not in message and len(message) < 400, message


def test_every_public_function_and_argument_has_valid_arguments_here():
    assert sorted(VALID) == sorted(public_functions())
    for function, name in calls():
        assert name in VALID[function], (function, name)
        hostile(name)  # a hostile value for each


@pytest.mark.parametrize("function, name", calls())
def test_every_argument_of_the_wrong_type_is_one_line_naming_it(function, name):
    for value in hostile(name):
        assert_refused(getattr(ilc, function), {**VALID[function], name: value}, name, value)


@settings(max_examples=60, deadline=None)
@given(value=st.one_of(st.booleans(), st.floats(), st.text(max_size=8), st.binary(max_size=8),
                       st.lists(st.integers(), max_size=3), st.floats().map(np.float64)),
       name=st.sampled_from(INTEGERS))
def test_an_integer_argument_takes_integers_alone(value, name):
    function = ilc.run if name == "trials" else ilc.simulate_bench
    assert_refused(function, {**VALID[function.__name__], name: value}, name, value)


@settings(max_examples=60, deadline=None)
@given(value=st.one_of(st.integers(), st.floats(), st.binary(), st.booleans(), st.just(""),
                       st.text(max_size=6).map(lambda text: f"{text}\0{text}"),
                       st.lists(st.text(min_size=1, max_size=3), max_size=2)),
       name=st.sampled_from(["bench_dir", "output", "out"]))
def test_a_path_argument_takes_a_path_alone(value, name):
    function = ilc.import_scan if name == "out" else ilc.identify
    assert_refused(function, {**VALID[function.__name__], name: value}, name, value)


@pytest.fixture(scope="module")
def small_config(tmp_path_factory) -> Path:
    return ilc.write_config(tmp_path_factory.mktemp("small") / "small.toml", SMALL_CAMPAIGN)


@pytest.mark.parametrize("kind", ["scan", "log"])
def test_every_option_of_a_simulated_log_of_the_wrong_type_is_one_line_naming_it(kind, small_config, tmp_path):
    from ilcpmac.sim.drive_log import LogPlan
    from ilcpmac.sim.standstill import ScanPlan

    function = ilc.simulate_scan if kind == "scan" else ilc.simulate_log
    plan = ScanPlan() if kind == "scan" else LogPlan()
    wrong = {int: [1.5, True, "3"], float: ["1", float("inf"), True], bool: ["no", 1], str: [5, b"x", None],
             tuple: [[1.5], 3, "12", [True]]}
    for name, default in vars(plan).items():
        if name == "seed":
            continue
        for value in wrong[type(default)]:
            assert_refused(function, {"config": small_config, "out": tmp_path / "out", name: value}, name, value)
    assert not (tmp_path / "out").exists()


def test_a_trial_index_is_an_integer():
    results = ilc.RunResults(Path("run"), (), {}, 0.0, (), None, None)
    for value in (True, 1.5, "1", None, np.float64(1.0)):
        assert_refused(results.trial, {"index": value}, "index", value)
        assert_refused(results.trial_frame, {"index": value}, "index", value)
    with pytest.raises(IlcpmacError, match=r"no trial 1 \(its trials are 1\.\.0\)$"):
        results.trial(np.int64(1))


def test_numpy_numbers_are_passed_on_as_builtin_ones(monkeypatch):
    seen: dict = {}

    def service_run(config, **kwargs):
        seen.update(kwargs)
        raise IlcpmacError("stopped here")

    monkeypatch.setattr(ilc.service, "run", service_run)
    with pytest.raises(IlcpmacError, match="stopped here"):
        ilc.run("c.toml", seed=np.int64(7), trials=np.int32(2), budget_min=np.float32(5.0))
    assert (seen["seed"], seen["trials"], seen["budget_min"]) == (7, 2, 5.0)
    assert (type(seen["seed"]), type(seen["trials"]), type(seen["budget_min"])) == (int, int, float)


def test_numpy_values_of_a_configs_changes_are_written_as_numbers(tmp_path):
    path = ilc.write_config(tmp_path / "c.toml", {"trials": {"seed": np.int64(4),
                                                             "torque_setpoints_nm": np.array([1.0, 2.5])}})
    from ilcpmac.config import load_config

    grid = load_config(path).grid
    assert grid.seed == 4 and grid.torque_setpoints_nm == (1.0, 2.5)


def test_a_simulated_logs_numpy_options_are_builtin_numbers(small_config, tmp_path):
    log = ilc.simulate_log(small_config, tmp_path / "log", seed=np.int64(3), duration_s=np.float64(2.0),
                           encoder_bits=np.int64(16))
    assert (type(log.plan.seed), type(log.plan.duration_s), type(log.plan.encoder_bits)) == (int, float, int)
