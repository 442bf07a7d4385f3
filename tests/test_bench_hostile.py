"""Hostile bench folders (issue 8): each mutation ends in one error line naming the file and line or key.

A small simulated bench folder (two trials of two revolutions at 1024 counts)
is mutated one way per test: damaged data, files that are not files, paths
that leave the folder, and plausible garbage. Nothing may end in a
traceback, a hang, unbounded memory or a non-finite number in JSON.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from identify_helpers import other_bench

from ilcpmac.bench.format import (
    Bench,
    MotorInfo,
    read_bench,
    read_trial_csv,
    write_backemf_csv,
    write_bench,
    write_trial_csv,
)
from ilcpmac.cli import main
from ilcpmac.errors import BenchFormatError, IdentificationError
from ilcpmac.identify import identify_bench
from ilcpmac.records import SensorCalibration

from conftest import COUNTS_PER_REV

#: what a file outside the bench folder holds: no message may ever show it
SECRET = "daemon:*:19000:0:secret-hash-7f3a"


@pytest.fixture(scope="module")
def small_bench(small_simulator, small_model, make_request) -> Bench:
    """Two trials of the small seed bench at two set points, in memory."""
    requests = [make_request(small_model, 2.0, 0.5, seed=3), make_request(small_model, 1.0, 1.0, seed=4)]
    trials = small_simulator.run_trials(requests, workers=1)
    return Bench(MotorInfo(8, 48, COUNTS_PER_REV, 0.01056), small_simulator.backemf_counts,
                 SensorCalibration([14.0, 14.0, 14.0], [0.0, 0.0, 0.0], 0.908), tuple(trials),
                 ("trial_01.csv", "trial_02.csv"))


@pytest.fixture(scope="module")
def pristine(small_bench, tmp_path_factory) -> Path:
    """``small_bench`` written once as a bench folder."""
    folder = tmp_path_factory.mktemp("pristine") / "bench"
    write_bench(folder, small_bench)
    return folder


@pytest.fixture
def bench_dir(pristine, tmp_path) -> Path:
    """A fresh copy of the pristine folder, to mutate; a sibling folder ``outside`` holds a secret."""
    (tmp_path / "outside").mkdir()
    (tmp_path / "outside" / "passwd").write_text(f"root:x:0:0\n{SECRET}\n")
    return Path(shutil.copytree(pristine, tmp_path / "bench"))


def edit_toml(folder: Path, old: str, new: str) -> None:
    text = (folder / "bench.toml").read_text()
    assert old in text, old
    (folder / "bench.toml").write_text(text.replace(old, new, 1))


def edit_trial(folder: Path, **changes) -> None:
    """Rewrite trial_01.csv with some columns replaced: ``changes`` maps a TrialData field to a function of it."""
    trial = read_trial_csv(folder / "trial_01.csv", 1.0, 1.0)
    trial = dataclasses.replace(trial, **{k: f(getattr(trial, k)) for k, f in changes.items()})
    write_trial_csv(folder / "trial_01.csv", trial)


def assert_refused(folder: Path, error: type, pattern: str) -> None:
    """``read_bench`` refuses ``folder`` with one line matching ``pattern`` that shows no outside data."""
    with pytest.raises(error) as caught:
        read_bench(folder)
    message = str(caught.value)
    assert re.search(pattern, message), message
    assert "\n" not in message and SECRET not in message and "root:x" not in message


def swap_two(a: np.ndarray) -> np.ndarray:
    a = a.copy()
    a[[10, 11]] = a[[11, 10]]
    return a


# ------------------------------------------------------------ damaged data (item 8)

@pytest.mark.parametrize("changes, pattern", [
    ({"time_s": swap_two}, r"trial_01\.csv: line 13: time does not increase"),
    ({"time_s": lambda t: t[::-1].copy()}, r"trial_01\.csv: line 3: time does not increase"),
    ({"time_s": lambda t: 1000.0 * t},
     r"trial_01\.csv: counts and time stamps give 0\.000\d+ revolutions per second at \[motor\] counts_per_rev "
     r"= 1024, but speed_setpoint = 0\.5 Hz"),
    ({"time_s": lambda t: 1e-3 * t}, r"trial_01\.csv: counts and time stamps give 4\d\d\.\d revolutions per second"),
    ({"torque_nm": lambda t: np.full_like(t, 1.5)}, r"trial_01\.csv: torque is 1\.5 on every line"),
    ({"count": lambda c: np.where(np.arange(c.size) >= 500, c + 10**15, c)},
     r"trial_01\.csv: line 502: count jumps by 1000000000000001; a trial's counts may span at most 4 per row"),
    ({"count": lambda c: c + 2**56}, r"trial_01\.csv: line 2: count must be an integer of magnitude at most 2\^53"),
    ({"i_ref_a": lambda i: 1e6 * i}, r"trial_01\.csv: sample \d+: i_ref beyond 10000 A"),
    ({"torque_nm": lambda t: 1e6 * t}, r"trial_01\.csv: sample \d+: torque beyond 100000 N m"),
    ({"i_ref_a": np.zeros_like}, r"trial_01\.csv: i_ref_a is zero on every line"),
    ({"i_ref_a": lambda i: np.column_stack([i[:, 0], np.zeros(len(i)), i[:, 2]])},
     r"trial_01\.csv: i_ref_b is zero on every line"),
])
def test_damaged_trial_is_refused(bench_dir, changes, pattern):
    edit_trial(bench_dir, **changes)
    assert_refused(bench_dir, BenchFormatError, pattern)


@pytest.mark.parametrize("content, pattern", [
    (bytes(range(256)) * 8, r"bench\.toml: line \d+: not UTF-8 text"),
    (b"a = " + b"[" * 100_000 + b"]" * 100_000 + b"\n", r"bench\.toml: not valid TOML \(nested too deeply\)"),
])
def test_binary_or_deeply_nested_bench_toml_is_refused(bench_dir, content, pattern):
    (bench_dir / "bench.toml").write_bytes(content)
    assert_refused(bench_dir, BenchFormatError, pattern)


def test_zero_backemf_is_refused(bench_dir, small_bench):
    write_backemf_csv(bench_dir / "backemf.csv", np.zeros_like(small_bench.backemf_nm_per_a))
    assert_refused(bench_dir, BenchFormatError, r"backemf\.csv: k_a is zero at every count")


def test_fifo_trial_is_refused_without_opening_it(bench_dir):
    fifo_trial(bench_dir)
    assert_refused(bench_dir, BenchFormatError, r"trial_01\.csv: not a regular file")


def test_folder_listed_as_backemf_is_refused(bench_dir):
    (bench_dir / "emf").mkdir()
    edit_toml(bench_dir, 'backemf_file = "backemf.csv"', 'backemf_file = "emf"')
    assert_refused(bench_dir, BenchFormatError, r"bench/emf: not a regular file")


def test_sparse_2_gb_trial_is_refused_before_it_is_read(bench_dir):
    """The size (st_size) is checked against the rows a trial may have before a byte is read."""
    os.truncate(bench_dir / "trial_02.csv", 2 * 2**30)
    assert_refused(bench_dir, BenchFormatError,
                   r"trial_02\.csv: 2147483648 bytes, more than the \d+ its rows may take")


def test_too_many_rows_are_refused_before_parsing(bench_dir):
    """Short rows fit the byte bound: their number is checked too (1024 revolutions of 1024 counts at most)."""
    (bench_dir / "trial_01.csv").write_text("count,time,i_ref_a,i_ref_b,i_ref_c,torque\n" + "1\n" * (2**20 + 1))
    assert_refused(bench_dir, BenchFormatError, r"trial_01\.csv: more than 1048576 rows")


def test_header_without_end_is_refused(bench_dir):
    (bench_dir / "trial_01.csv").write_bytes(b"count" * 1000)
    assert_refused(bench_dir, BenchFormatError, r"trial_01\.csv: line 1: no end of the header line in 4096 bytes")


# ------------------------------------------------------------ paths (item 9)

@pytest.mark.parametrize("old, new, pattern", [
    ('file = "trial_01.csv"', 'file = "{outside}/passwd"',
     r"bench\.toml: \[\[trials\]\] #1: key 'file' must be a relative path inside the bench folder"),
    ('file = "trial_01.csv"', 'file = "../outside/passwd"',
     r"bench\.toml: \[\[trials\]\] #1: key 'file' must be a relative path inside the bench folder"),
    ('file = "trial_01.csv"', 'file = "sub/../../outside/passwd"', r"#1: key 'file' must be a relative path"),
    ('backemf_file = "backemf.csv"', 'backemf_file = "/etc/passwd"',
     r"bench\.toml: \[motor\]: key 'backemf_file' must be a relative path inside the bench folder"),
    ('file = "trial_02.csv"', 'file = "./trial_01.csv"',
     r"bench\.toml: \[\[trials\]\] #2: file 'trial_01\.csv' is listed twice \(also \[\[trials\]\] #1\)"),
    ('file = "trial_02.csv"', 'file = ".//trial_01.csv"', r"#2: file 'trial_01\.csv' is listed twice"),
])
def test_paths_stay_inside_the_folder(bench_dir, old, new, pattern):
    edit_toml(bench_dir, old, new.format(outside=bench_dir.parent / "outside"))
    assert_refused(bench_dir, BenchFormatError, pattern)


@pytest.mark.parametrize("name, target", [
    ("trial_01.csv", "../outside/passwd"),
    ("trial_01.csv", "/dev/zero"),
    ("backemf.csv", "{outside}/passwd"),
    ("bench.toml", "../outside/passwd"),
])
def test_symlink_out_of_the_folder_is_refused_unread(bench_dir, name, target):
    (bench_dir / name).unlink()
    (bench_dir / name).symlink_to(target.format(outside=bench_dir.parent / "outside"))
    assert_refused(bench_dir, BenchFormatError,
                   re.escape(str(bench_dir / name)) + ": is a symbolic link to outside the bench folder")


def test_symlinks_inside_the_folder_are_followed_and_count_once(bench_dir):
    (bench_dir / "data").mkdir()
    (bench_dir / "trial_02.csv").rename(bench_dir / "data" / "second.csv")
    (bench_dir / "trial_02.csv").symlink_to("data/second.csv")
    edit_toml(bench_dir, 'file = "trial_01.csv"', 'file = "./trial_01.csv"')
    bench = read_bench(bench_dir)
    assert bench.trial_files == ("trial_01.csv", "trial_02.csv")
    (bench_dir / "again.csv").symlink_to("trial_01.csv")
    edit_toml(bench_dir, 'file = "trial_02.csv"', 'file = "again.csv"')
    assert_refused(bench_dir, BenchFormatError, r"#2: file 'again\.csv' is listed twice \(also \[\[trials\]\] #1\)")


# ------------------------------------------------------------ plausible garbage (item 10)

@pytest.mark.parametrize("old, new, pattern", [
    ("current_offset = [0.0, 0.0, 0.0]", "current_offset = [0.0, inf, 0.0]",
     r"\[sensors\]: key 'current_offset' must be a list of 3 finite numbers"),
    ("current_scale = [14.0, 14.0, 14.0]", "current_scale = [14.0, nan, 14.0]",
     r"\[sensors\]: key 'current_scale' must be a list of 3 finite numbers"),
    ("inertia = 0.01056", "inertia = 1e300", r"\[motor\]: key 'inertia' must lie in \[1e-08, 10000\.0\], got 1e\+300"),
    ("pole_pairs = 8", "pole_pairs = 1000000", r"\[motor\]: key 'pole_pairs' must lie in \[1, 256\], got 1000000"),
    ("slots = 48", "slots = 1", r"\[motor\]: key 'slots' must lie in \[3, 2048\]"),
    ("counts_per_rev = 1024", "counts_per_rev = 16",
     r"\[motor\]: key 'counts_per_rev' must be at least 4 per electrical period \(4 x pole_pairs = 32\)"),
    ("pole_pairs = 8", "pole_pairs = 4",
     r"backemf\.csv: the back-EMF repeats 8 times per revolution of 1024 counts, but \[motor\] pole_pairs = 4"),
    ("torque_setpoint = 2.0", "torque_setpoint = 0.0", r"\[\[trials\]\] #1: key 'torque_setpoint' must lie in \(0, 100000\]"),
    ("torque_setpoint = 2.0", "torque_setpoint = -2.0", r"\[\[trials\]\] #1: key 'torque_setpoint' must lie in \(0, "),
    ("torque_setpoint = 2.0", "torque_setpoint = 1e300", r"\[\[trials\]\] #1: key 'torque_setpoint' must lie in \(0, "),
    ("torque_gain = 0.908", "torque_gain = 1e300", r"\[sensors\]: key 'torque_gain' must lie in \(0, 1e\+09\]"),
    ("speed_setpoint = 0.5", "speed_setpoint = 0.0", r"\[\[trials\]\] #1: key 'speed_setpoint' must lie in \(0, 1000\]"),
    ("speed_setpoint = 0.5", "speed_setpoint = -0.5", r"\[\[trials\]\] #1: key 'speed_setpoint' must lie in \(0, "),
    ("speed_setpoint = 0.5", "speed_setpoint = 1.0",
     r"trial_01\.csv: counts and time stamps give 0\.4\d+ revolutions per second .* speed_setpoint = 1 Hz"),
])
def test_implausible_bench_toml_is_refused(bench_dir, old, new, pattern):
    edit_toml(bench_dir, old, new)
    assert_refused(bench_dir, BenchFormatError, pattern)


def test_counts_per_rev_half_the_recorded_one_is_refused(bench_dir, small_bench):
    """Data recorded at 1024 counts per revolution declared as 512 (the issue's 2048 on 4096)."""
    edit_toml(bench_dir, "counts_per_rev = 1024", "counts_per_rev = 512")
    write_backemf_csv(bench_dir / "backemf.csv", small_bench.backemf_nm_per_a[::2])
    assert_refused(bench_dir, BenchFormatError,
                   r"trial_01\.csv: counts and time stamps give 0\.9\d+ revolutions per second at \[motor\] "
                   r"counts_per_rev = 512, but speed_setpoint = 0\.5 Hz")


def test_electrical_period_against_pole_pairs(bench_dir, small_bench):
    """A current reference at the wrong electrical period, on a bench whose speed fits."""
    theta = 2 * np.pi * np.arange(2 * COUNTS_PER_REV) / COUNTS_PER_REV
    edit_trial(bench_dir, i_ref_a=lambda i: np.column_stack([np.sin(5 * theta + k) for k in range(3)]))
    assert_refused(bench_dir, BenchFormatError,
                   r"trial_01\.csv: the current references repeat 5 times per revolution of 1024 counts, "
                   r"but \[motor\] pole_pairs = 8")


# ------------------------------------------------------------ identification never ends in a traceback

def replaced(bench: Bench, index: int, **changes) -> Bench:
    trials = list(bench.trials)
    trials[index] = dataclasses.replace(trials[index], **changes)
    return dataclasses.replace(bench, trials=tuple(trials))


def test_non_finite_sample_in_memory_is_named(small_bench):
    torque = small_bench.trials[0].torque_nm.copy()
    torque[7] = np.nan
    with pytest.raises(IdentificationError, match=r"trial_01\.csv left out: sample 7: torque is not a finite number"):
        identify_bench(replaced(small_bench, 0, torque_nm=torque))


@pytest.mark.parametrize("target, step", [
    ("ilcpmac.identify.reduction.slow_trend", "trial_01.csv left out"),
    ("ilcpmac.identify.decouple", "decoupling (ch. 4)"),
    ("ilcpmac.identify.fit_joint", "joint fit"),
])
def test_numerical_failure_becomes_a_message(monkeypatch, target, step):
    """A LinAlgError (SVD did not converge) in a step, once: that step's message, the other estimates kept."""
    module, name = target.rsplit(".", 1)
    original = getattr(importlib.import_module(module), name)
    calls = []

    def fail_once(*args, **kwargs):
        calls.append(1)
        if len(calls) == 1:
            raise np.linalg.LinAlgError("SVD did not converge in Linear Least Squares")
        return original(*args, **kwargs)

    bench, _ = other_bench()
    monkeypatch.setattr(target, fail_once)
    result = identify_bench(bench)
    assert (f"{step}: degenerate data - constant, collinear or non-finite columns (SVD did not converge in "
            "Linear Least Squares)") in result.messages
    assert result.delta is not None
    json.dumps(result.to_json(), allow_nan=False)


@pytest.mark.parametrize("changes, pattern", [
    ({"time_s": lambda t: t[::-1].copy()}, r"trial_0\d\.csv left out: counts and time stamps give -"),
    ({"torque_nm": lambda t: np.zeros_like(t)}, r"trial_0\d\.csv left out: torque is 0 on every line"),
    ({"i_ref_a": np.zeros_like}, r"trial_0\d\.csv left out: i_ref_a is zero on every line"),
])
def test_in_memory_bench_gets_the_reader_checks(small_bench, changes, pattern):
    bench = small_bench
    for k in range(len(bench.trials)):
        bench = replaced(bench, k, **{name: f(getattr(bench.trials[k], name)) for name, f in changes.items()})
    with pytest.raises(IdentificationError, match="no trial can be used: " + pattern):
        identify_bench(bench)


def test_zero_backemf_in_memory_is_an_identification_error(small_bench):
    bench = dataclasses.replace(small_bench, backemf_nm_per_a=np.zeros_like(small_bench.backemf_nm_per_a))
    with pytest.raises(IdentificationError, match="back-EMF: k_a is zero at every count"):
        identify_bench(bench)


# ------------------------------------------------------------ the CLI: exit 2, one line; JSON without NaN

def identify_cli(folder: Path, output: Path):
    return CliRunner().invoke(main, ["identify", str(folder), "--output", str(output)])


def fifo_trial(folder: Path) -> None:
    (folder / "trial_01.csv").unlink()
    os.mkfifo(folder / "trial_01.csv")


@pytest.mark.parametrize("mutate, pattern", [
    (fifo_trial, r"trial_01\.csv: not a regular file"),
    (lambda d: edit_trial(d, count=lambda c: np.where(np.arange(c.size) >= 500, c + 10**15, c)),
     r"trial_01\.csv: line 502: count jumps"),
    (lambda d: edit_toml(d, "current_offset = [0.0, 0.0, 0.0]", "current_offset = [0.0, inf, 0.0]"),
     r"\[sensors\]: key 'current_offset' must be a list of 3 finite numbers"),
    (lambda d: edit_toml(d, 'file = "trial_01.csv"', 'file = "../outside/passwd"'),
     r"#1: key 'file' must be a relative path inside the bench folder"),
])
def test_cli_exits_2_with_one_line(bench_dir, tmp_path, mutate, pattern):
    mutate(bench_dir)
    out = identify_cli(bench_dir, tmp_path / "result.json")
    assert out.exit_code == 2, out.output
    errors = [line for line in out.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and re.search(pattern, errors[0]), out.stderr
    assert "Traceback" not in out.output and SECRET not in out.output
    assert not (tmp_path / "result.json").exists()


def test_cli_writes_null_not_nan(tmp_path):
    """One set point: no scatter over set points, so the report's standard errors are unknown (NaN before)."""
    bench, _ = other_bench()
    write_bench(tmp_path / "bench", dataclasses.replace(bench, trials=bench.trials[:1],
                                                        trial_files=bench.trial_files[:1]))
    out = identify_cli(tmp_path / "bench", tmp_path / "result.json")
    assert out.exit_code == 0, out.output
    data = json.loads((tmp_path / "result.json").read_text(), parse_constant=lambda c: pytest.fail(c))
    assert data["methods"]["report"]["alpha_std"] is None
    assert any("alpha_std" in m and "reported as null" in m for m in data["messages"])


def test_non_finite_diagnostics_become_null():
    bench, _ = other_bench()
    result = identify_bench(dataclasses.replace(bench, trials=bench.trials[:1], trial_files=bench.trial_files[:1]))
    result = dataclasses.replace(result, diagnostics={"chi2": float("inf"), "per_trial": [np.float64("nan"), 1.0]})
    data = json.loads(json.dumps(result.to_json(), allow_nan=False))
    assert data["diagnostics"] == {"chi2": None, "per_trial": [None, 1.0]}
