"""``ilcpmac simulate``: a small campaign into a bench folder with truth.json; errors as one line, exit 2."""

from __future__ import annotations

import json
import math
import re
import subprocess
import sysconfig
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner, Result
from conftest import COUNTS_PER_REV

from ilcpmac.bench.format import read_bench
from ilcpmac.cli import main
from ilcpmac.core.errors import BenchFormatError
from ilcpmac.core.records import MotorInfo

#: two trials of two revolutions at 1024 counts per revolution
SMALL = {"bench": {"counts_per_rev": COUNTS_PER_REV},
         "trials": {"torque_setpoints_nm": [2.0], "speed_setpoints_hz": [0.5, 1.0], "revolutions": 2}}
TRUTH_KEYS = {"total_system_gain", "torque_sensor_gain", "epsilon", "alpha", "beta", "inertia_estimate", "cogging"}


def simulate(*args: str) -> Result:
    return CliRunner().invoke(main, ["simulate", *args])


def assert_one_error_line(stderr: str, output: str, path: Path) -> None:
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith("error: ") and str(path) in lines[0]
    assert "Traceback" not in output


def test_simulate_writes_bench_folder_and_truth(write_config, tmp_path):
    out = tmp_path / "bench"
    result = simulate(str(write_config(SMALL)), "--out", str(out))
    assert result.exit_code == 0, result.output
    assert f"wrote 2 trials ({2 * 2 * COUNTS_PER_REV} samples) and truth.json" in result.stderr
    assert {p.name for p in out.iterdir()} == {"bench.toml", "backemf.csv", "trial_01.csv", "trial_02.csv",
                                                "truth.json"}

    bench = read_bench(out)
    assert bench.motor == MotorInfo(8, 48, COUNTS_PER_REV, 0.01056)
    np.testing.assert_array_equal(bench.sensors.current_scale, [14.0, 14.0, 14.0])
    assert bench.sensors.torque_gain == 0.908
    assert [(t.torque_setpoint_nm, t.speed_setpoint_hz) for t in bench.trials] == [(2.0, 0.5), (2.0, 1.0)]
    for trial in bench.trials:
        np.testing.assert_array_equal(trial.count, np.arange(2 * COUNTS_PER_REV))
        assert trial.torque_true_nm is not None and trial.i_true_a.shape == (2 * COUNTS_PER_REV, 3)
    # K_a = 0.2 sin(8 theta) + 0.012 sin(24 theta + 0.3) + ... at count 0
    assert bench.backemf_nm_per_a[0, 0] == pytest.approx(0.012 * math.sin(0.3) + 0.006 * math.sin(-0.2)
                                                         + 0.003 * math.sin(0.5), abs=1e-12)

    truth = json.loads((out / "truth.json").read_text())
    assert TRUTH_KEYS <= truth.keys()
    assert truth["torque_sensor_gain"] == pytest.approx(0.822, rel=1e-12)
    assert truth["epsilon"] == pytest.approx(0.6868, rel=1e-12)
    assert truth["total_system_gain"] == pytest.approx(0.822 * 0.6868, rel=1e-12)
    np.testing.assert_allclose(truth["alpha"], np.array([0.8, 1.118, 1.118]) / (3.036 / 3), rtol=1e-12)
    np.testing.assert_allclose(truth["beta"], [1.0, -0.5, -0.5], rtol=1e-12)
    assert truth["inertia_estimate"] == pytest.approx(0.822 * 0.01056, rel=1e-12)
    theta = 2 * np.pi * np.arange(COUNTS_PER_REV) / COUNTS_PER_REV
    assert truth["cogging"]["count"] == list(range(COUNTS_PER_REV))
    np.testing.assert_allclose(truth["cogging"]["torque"],
                               0.5 * np.sin(48 * theta) + 0.08 * np.sin(96 * theta + 0.7), atol=1e-12)


def test_seed_and_revolutions_options(write_config, tmp_path):
    config = str(write_config(SMALL))
    for name, seed in [("a", "5"), ("b", "5"), ("c", "6")]:
        result = simulate(config, "--out", str(tmp_path / name), "--seed", seed, "--revolutions", "1")
        assert result.exit_code == 0, result.output
    assert read_bench(tmp_path / "a").trials[0].n_samples == COUNTS_PER_REV
    same = (tmp_path / "a" / "trial_01.csv").read_bytes() == (tmp_path / "b" / "trial_01.csv").read_bytes()
    other = (tmp_path / "a" / "trial_01.csv").read_bytes() == (tmp_path / "c" / "trial_01.csv").read_bytes()
    assert same and not other


@pytest.mark.parametrize("changes, message", [
    ({"bench": {"pole_pair": 8}}, r"\[bench\] unknown key 'pole_pair'"),
    ({"bench": {"inertia_kgm2": -1.0}}, r"\[bench\] inertia_kgm2: invalid value -1.0"),
])
def test_bad_config_exits_2_with_one_line(write_config, tmp_path, changes, message):
    config = write_config({**SMALL, **changes})
    result = simulate(str(config), "--out", str(tmp_path / "bench"))
    assert result.exit_code == 2
    assert_one_error_line(result.stderr, result.output, config)
    assert re.search(message, result.stderr)
    assert not (tmp_path / "bench").exists()


@pytest.mark.parametrize("changes, options, message", [
    # the former segfaults, MemoryError and AttributeError
    ({"simulator.controller": {"control_rate_hz": 0.001}},
     [], r"\[simulator\.controller\] control_rate_hz: invalid value 0.001"),
    ({"trials": {"speed_setpoints_hz": [1e-6]}}, [], r"\[trials\] speed_setpoints_hz: at 1e-06 Hz .* lasts 3e\+06 s"),
    ({"trials": {"revolutions": 20000}}, [], r"\[trials\] revolutions: 20000 x .*max_samples_per_trial"),
    ({"trials": {"torque_setpoints_nm": []}}, [], r"\[trials\] torque_setpoints_nm: invalid value \[\]"),
    # the command line's overrides are checked as the config's values are
    ({}, ["--revolutions", "20000"], r"\[trials\] revolutions: 20000 x .*max_samples_per_trial"),
    ({}, ["--seed", str(2**64)], r"\[trials\] seed: invalid value 18446744073709551616"),
])
def test_config_without_physical_sense_exits_2_with_one_line(write_config, tmp_path, changes, options, message):
    config = write_config({**SMALL, **{table: {**SMALL.get(table, {}), **values} for table, values in changes.items()}})
    result = simulate(str(config), "--out", str(tmp_path / "bench"), *options)
    assert result.exit_code == 2, result.output
    assert_one_error_line(result.stderr, result.output, config)
    assert re.search(message, result.stderr), result.stderr
    assert not (tmp_path / "bench").exists()


def test_console_script_former_segfault_exits_2(write_config, tmp_path):
    script = Path(sysconfig.get_path("scripts")) / "ilcpmac"
    config = write_config({**SMALL, "simulator.controller": {"control_rate_hz": 0.001}})
    done = subprocess.run([str(script), "simulate", str(config), "--out", str(tmp_path / "bench")],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr  # was -11 (SIGSEGV)
    assert_one_error_line(done.stderr, done.stdout + done.stderr, config)


def test_missing_config_exits_2(tmp_path):
    config = tmp_path / "absent.toml"
    result = simulate(str(config), "--out", str(tmp_path / "bench"))
    assert result.exit_code == 2
    assert_one_error_line(result.stderr, result.output, config)


def test_console_script_reports_bad_config_without_traceback(write_config, tmp_path):
    script = Path(sysconfig.get_path("scripts")) / "ilcpmac"
    config = write_config({**SMALL, "bench": {"slots": "48"}})
    done = subprocess.run([str(script), "simulate", str(config), "--out", str(tmp_path / "bench")],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert_one_error_line(done.stderr, done.stdout + done.stderr, config)
    assert "[bench] slots: expected an integer, got '48'" in done.stderr


def test_damaged_bench_folder_is_rejected_by_the_reader(write_config, tmp_path):
    out = tmp_path / "bench"
    assert simulate(str(write_config(SMALL)), "--out", str(out)).exit_code == 0
    trial = out / "trial_02.csv"
    lines = trial.read_text().splitlines(keepends=True)
    lines[9], lines[10] = lines[10], lines[9]  # counts 8 and 9 swapped: line 11 goes back
    trial.write_text("".join(lines))
    with pytest.raises(BenchFormatError, match=re.escape(str(trial)) + ": line 11: count does not increase"):
        read_bench(out)


def test_output_folder_that_cannot_be_made_exits_2(write_config, tmp_path):
    (tmp_path / "file").write_text("")
    out = tmp_path / "file" / "bench"  # a folder under a plain file: NotADirectoryError, was a traceback
    result = simulate(str(write_config(SMALL)), "--out", str(out))
    assert result.exit_code == 2
    assert_one_error_line(result.stderr, result.output, out)
