"""``ilcpmac export`` within the bounds a record came from and a drive's format holds (issue 34, items 6 to 9): a
calibration out of range, a torque constant that makes the drive's current infinite or zero, a table beyond its run
directory's [limits] or of the wrong length, a scale a C float cannot hold: one line naming the file and the key,
nothing written. A source path that would close a C comment stays inert; a name that is no UTF-8 is no traceback;
on a full disk no file is left truncated and the error names it."""

from __future__ import annotations

import dataclasses
import json
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from test_export import CALIBRATION, compensation
from test_export_garbage import _refused
from test_export_identification import CPR, KT, result_json
from test_output_and_sweep_garbage import full_disk

from ilcpmac.bench.format import BENCH_FILE, bench_toml_text, write_backemf_csv
from ilcpmac.cli import main
from ilcpmac.compensation import Compensation, FadeOut, PositionTable, read_position_table
from ilcpmac.core.errors import BenchFormatError
from ilcpmac.core.records import IdentificationResult, MotorInfo, SensorCalibration
from ilcpmac.export import FORMATS, RUN_CONFIG, export

#: the [limits] max_correction_nm of the run directories below, N m; compensation()'s peak is 0.06 N m
MAX_CORRECTION_NM = 0.1


def invoke(*args: str):
    return CliRunner().invoke(main, ["export", *map(str, args)])


def run_directory(folder: Path, record: Compensation | None = None, counts_per_rev: int = 64,
                  limits: str = f"max_correction_nm = {MAX_CORRECTION_NM}\nmax_current_a = 2.0\n") -> Path:
    """A run directory as export reads it: campaign.toml with ``limits``, bench.toml and backemf.csv of a
    ``counts_per_rev`` encoder, and ``record`` as its compensation.json."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / RUN_CONFIG).write_text(f"[limits]\n{limits}")
    motor = MotorInfo(pole_pairs=4, slots=6, counts_per_rev=counts_per_rev, inertia_kgm2=1e-3)
    theta = 4 * 2 * np.pi * np.arange(counts_per_rev) / counts_per_rev
    write_backemf_csv(folder / "backemf.csv", 0.1 * np.sin(theta[:, None] - 2 * np.pi * np.arange(3) / 3))
    (folder / BENCH_FILE).write_text(bench_toml_text(motor, None, []))
    if record is not None:
        (folder / "compensation.json").write_text(json.dumps(record.to_json()))
    return folder


def _result(folder: Path, change) -> Path:
    """result_json's result with ``change(data)`` applied."""
    path = result_json(folder)
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))
    return path


# ---------------------------------------------------------------- item 6: an identification's calibration


@pytest.mark.parametrize("scale", [0.0, -27.5, 1e10])
@pytest.mark.parametrize("fmt", ["json", "csv", "c"])
def test_an_identifications_calibration_out_of_range_is_refused(tmp_path, scale, fmt):
    path = _result(tmp_path, lambda d: d["calibration"]["current_scale"].__setitem__(1, scale))
    message = (f"{path}: key 'calibration.current_scale': invalid value [14.0, {scale!r}, 13.9] ((G*_s)^-1 per "
               "phase, counts / A, within (0, 1e9], three values)")
    with pytest.raises(BenchFormatError) as e:
        read_position_table(path)
    assert str(e.value) == message
    _refused(path, tmp_path / "out", fmt, message)


def test_a_position_table_checks_its_calibration_itself():
    with pytest.raises(ValueError, match=r"key 'calibration.torque_gain': invalid value 0.0"):
        PositionTable("cogging", np.ones(8), np.arange(1, 5), SensorCalibration([1.0] * 3, [0.0] * 3, 0.0), "here")


@pytest.mark.parametrize("calibration, key", [
    (SensorCalibration([1e-300, 14.2, 13.9], [0.0] * 3, 0.9), "'calibration.current_scale': value [0]"),
    (SensorCalibration([14.0, 14.2, 13.9], [0.0] * 3, 1e-300), "'calibration.torque_gain'")])
def test_a_calibration_a_c_float_cannot_hold_is_refused_by_the_c_export(tmp_path, calibration, key):
    """1e-300 is within the calibration's range, but a C float would hold 0: a drive dividing by it."""
    c = compensation()
    (tmp_path / "compensation.json").write_text(json.dumps(dataclasses.replace(c, calibration=calibration).to_json()))
    result = invoke(tmp_path, "--format", "c", "--out", tmp_path / "out")
    assert result.exit_code == 2 and result.output.startswith(
        f"error: {tmp_path / 'compensation.json'}: key {key}: 1e-300 is no normal float32"), result.output
    assert len(result.output.splitlines()) == 1 and not (tmp_path / "out").exists()
    assert invoke(tmp_path, "--format", "csv", "--out", tmp_path / "csv").exit_code == 0  # CSV holds it exactly


# ---------------------------------------------------------------- item 7: the drive formats' current


@pytest.mark.parametrize("fmt", ["moteus", "harmonics"])
@pytest.mark.parametrize("kt, expected", [
    ("1e-300", "at --torque-constant 1e-300 N m per A: |q-axis current| 2.48"),
    ("1e300", "at --torque-constant 1e+300 N m per A: the q-axis current peaks at 2.4"),
    ("inf", None), ("nan", None), ("0", None), ("-0.1", None)])
def test_a_torque_constant_that_makes_the_current_infinite_or_nothing_is_refused(tmp_path, fmt, kt, expected):
    path = result_json(tmp_path)
    result = invoke(path, "--format", fmt, "--torque-constant", kt, "--out", tmp_path / "out")
    assert result.exit_code == 2 and len(result.output.splitlines()) == 1, result.output
    start = (f"error: {path}: {expected}" if expected is not None else
             f"error: --format {fmt} needs --torque-constant NM_PER_A > 0 and finite")
    assert result.output.startswith(start), result.output
    assert not (tmp_path / "out").exists()


def test_a_table_of_1e5_nm_is_no_current_a_drive_applies(tmp_path):
    """1e5 N m is within a result's range; at 0.3 N m per A it asks 334 kA of q-axis current (the 1024 entries a
    little more: the sinc^2 of their interpolation)."""
    path = _result(tmp_path, lambda d: d["cogging"].update(torque=(1e5 * np.sin(24 * 2 * np.pi * np.arange(CPR) / CPR)
                                                                     ).tolist()))
    result = invoke(path, "--format", "moteus", "--torque-constant", "0.3", "--out", tmp_path / "out")
    assert result.output == (f"error: {path}: at --torque-constant 0.3 N m per A: |q-axis current| 3.339e+05 A is "
                             "beyond 10000 A (the bench format's largest current)\n")
    assert not (tmp_path / "out").exists()


def test_the_drive_formats_state_the_current_they_ask(tmp_path):
    path = result_json(tmp_path)
    for fmt in ("moteus", "harmonics"):
        result = invoke(path, "--format", fmt, "--torque-constant", KT, "--out", tmp_path / fmt)
        assert result.exit_code == 0, result.output
        lines = result.output.splitlines()
        assert lines[2] == ("bound: |feed-forward| at most 0.02481 N m, within 100000 N m (the record's range: no run "
                            "directory, so no [limits])")
        assert lines[3].startswith("bound: |q-axis current| at most 0.24") and lines[3].endswith(
            " A, within 10000 A (the bench format's largest current)")


# ---------------------------------------------------------------- item 7: a run directory's [limits]


@pytest.mark.parametrize("fmt", ["json", "csv", "c"])
def test_a_compensation_beyond_its_runs_max_correction_is_refused(tmp_path, fmt):
    c = compensation()
    tables = c.tables_nm.copy()
    tables[1, 0, 17] = 3.3 * MAX_CORRECTION_NM
    run = run_directory(tmp_path / "run", Compensation(64, CALIBRATION, c.torques_nm, c.speeds_hz, tables, c.fade))
    _refused(run, tmp_path / "out", fmt,
             f"{run / 'compensation.json'}: key 'tables_nm': value [1, 0, 17]: |feed-forward| 0.33 N m is beyond "
             f"0.1 N m ([limits] max_correction_nm of {run / RUN_CONFIG})")
    _refused(run / "compensation.json", tmp_path / "out", fmt,
             f"{run / 'compensation.json'}: key 'tables_nm': value [1, 0, 17]: |feed-forward| 0.33 N m is beyond "
             f"0.1 N m ([limits] max_correction_nm of {run / RUN_CONFIG})")


def test_a_compensation_within_its_runs_limits_says_which(tmp_path):
    run = run_directory(tmp_path / "run", compensation(), limits="max_correction_nm = 0.1\nmax_torque_nm = 4\n")
    result = invoke(run, "--format", "c", "--out", tmp_path / "out")
    assert result.exit_code == 0, result.output
    config = run / RUN_CONFIG
    assert result.output.splitlines()[3:6] == [
        f"bound: |feed-forward| at most 0.06 N m, within 0.1 N m ([limits] max_correction_nm of {config})",
        f"bound: |torque set point| at most 3 N m, within 4 N m ([limits] max_torque_nm of {config})",
        f"bound: |speed set point| at most 0.8333 Hz, within 1.5 Hz ([limits] max_speed_hz of {config})"]
    _refused(run_directory(tmp_path / "slow", compensation(), limits="max_speed_hz = 0.5\n"), tmp_path / "no", "json",
             f"{tmp_path / 'slow' / 'compensation.json'}: key 'speeds_hz': |speed set point| 0.8333 Hz is beyond "
             f"0.5 Hz ([limits] max_speed_hz of {tmp_path / 'slow' / RUN_CONFIG})")


def test_a_result_in_a_run_directory_is_bounded_by_its_limits(tmp_path):
    """A position table at 0.33 N m from a run whose feed-forward was clipped to 0.1 N m, and its current."""
    run = run_directory(tmp_path / "run", counts_per_rev=CPR)
    path = _result(run, lambda d: d["cogging"].update(torque=(0.33 * np.sin(24 * 2 * np.pi * np.arange(CPR) / CPR)
                                                                ).tolist()))
    result = invoke(path, "--format", "moteus", "--torque-constant", KT, "--out", tmp_path / "out")
    assert result.exit_code == 2 and result.output.startswith(
        f"error: {path}: key 'cogging.torque': value [") and result.output.endswith(
        f"]: |feed-forward| 0.33 N m is beyond 0.1 N m ([limits] max_correction_nm of {run / RUN_CONFIG})\n")
    path = result_json(run)  # 24.8 mN m at 0.01 N m per A: 2.5 A, beyond the run's 2 A
    result = invoke(path, "--format", "moteus", "--torque-constant", "0.01", "--out", tmp_path / "out")
    assert result.exit_code == 2 and result.output.startswith(
        f"error: {path}: at --torque-constant 0.01 N m per A: |q-axis current| 2.4") and result.output.endswith(
        f" A is beyond 2 A ([limits] max_current_a of {run / RUN_CONFIG})\n")
    assert not (tmp_path / "out").exists()


def test_a_run_directory_whose_limits_cannot_be_read_is_one_line(tmp_path):
    run = run_directory(tmp_path / "run", compensation(), limits="max_correction_nm = -1\n")
    result = invoke(run, "--out", tmp_path / "out")
    assert result.exit_code == 2 and result.output.startswith(f"error: {run / RUN_CONFIG}: [limits] max_correction_nm")
    assert len(result.output.splitlines()) == 1 and not (tmp_path / "out").exists()


# ---------------------------------------------------------------- item 8: lengths, tiny scales, names


def test_a_compensation_for_another_encoder_than_its_runs_is_refused(tmp_path):
    run = run_directory(tmp_path / "run", compensation(cpr=63), counts_per_rev=64)
    _refused(run, tmp_path / "out", "csv", f"{run / 'compensation.json'}: 63 counts per revolution, but the run's "
                                           f"encoder has 64 ({run / BENCH_FILE})")


def test_a_scans_table_of_the_wrong_length_is_refused(tmp_path):
    """A scan states its counts_per_rev: 4095 entries for 4096 counts is refused, whatever its own count list."""
    scan = {"kind": "standstill_scan", "counts_per_rev": CPR, "cogging_order": 24,
            "cogging": {"count": list(range(CPR - 1)), "torque": np.sin(24 * 2 * np.pi * np.arange(CPR - 1) / CPR)
                        .tolist()}}
    path = tmp_path / "scan.json"
    path.write_text(json.dumps(scan))
    _refused(path, tmp_path / "out", "c", f"{path}: key 'cogging.torque': 4095 values, but key 'counts_per_rev' "
                                          "gives 4096 counts per revolution (one value per count)")
    scan["counts_per_rev"] = CPR - 1
    scan["cogging"]["count"] = list(range(CPR))
    path.write_text(json.dumps(scan))
    _refused(path, tmp_path / "out", "c", f"{path}: key 'cogging.count': must be the counts 0 .. 4094, one per value "
                                          "of 'cogging.torque'")


def test_a_results_tables_of_different_lengths_are_refused(tmp_path):
    path = tmp_path / "rolling.json"
    theta = 2 * np.pi * np.arange(CPR) / CPR
    path.write_text(json.dumps(IdentificationResult(cogging_nm=0.01 * np.sin(24 * theta[:-1]),
                                                    position_torque_nm=0.01 * np.sin(24 * theta)).to_json()))
    _refused(path, tmp_path / "out", "json", f"{path}: key 'cogging.torque': 4095 values, but key "
                                             "'position_torque.torque' gives 4096 counts per revolution (one value "
                                             "per count)")


def test_tables_too_small_for_an_int16_scale_are_refused_and_float_holds_them(tmp_path):
    c = compensation()
    tiny = Compensation(64, CALIBRATION, c.torques_nm, c.speeds_hz, c.tables_nm * 1e-35, c.fade)
    with pytest.raises(BenchFormatError, match=r"^compensation.json: key 'tables_nm': the int16 tables' N m per LSB "
                                               r".*: 2e-41 is no normal float32"):
        export(tiny, tmp_path / "out", "c")
    assert not (tmp_path / "out").exists()
    assert export(tiny, tmp_path / "float", "c", "float").residual.peak_nm <= 1e-37


def test_a_grid_that_is_one_float_in_c_is_refused(tmp_path):
    c = compensation()
    close = Compensation(64, CALIBRATION, np.array([1.0, 1.0 + 1e-9]), c.speeds_hz, c.tables_nm, c.fade)
    with pytest.raises(BenchFormatError, match=r"^compensation.json: key 'torques_nm': values 0 and 1 \(1.0, "
                                               r"1.000000001\) are one float in the C export"):
        export(close, tmp_path / "out", "c")


def test_a_fade_out_beyond_the_speed_range_is_refused():
    """A fade speed of 1e300 Hz was a C float of inf, "inff": a source that does not compile."""
    with pytest.raises(ValueError, match=r"key 'fade': needs 0 <= full_hz <= zero_hz <= 1000, or both infinite"):
        FadeOut(3.0, 1e300)


def _compiles(folder: Path) -> None:
    compiler = shutil.which("gcc") or shutil.which("cc")
    if compiler is None:
        pytest.skip("no C compiler")
    for source in folder.glob("*.c"):
        done = subprocess.run([compiler, "-std=c99", "-pedantic", "-Wall", "-Wextra", "-Werror", "-fsyntax-only",
                               str(source)], capture_output=True, text=True, timeout=60)
        assert done.returncode == 0, done.stderr


@pytest.mark.parametrize("name", ["run*", "x*/ int ilcpmac_injected = 1; /*", "a/*b", "tab\tand\u00e9",
                                  "not utf-8 \udcff"])
def test_a_source_path_stays_inert_in_the_c_comments(tmp_path, name):
    folder = tmp_path / name
    (folder / "identified").mkdir(parents=True)
    for source in (run_directory(folder, compensation()) / "compensation.json", result_json(folder / "identified")):
        out = tmp_path / f"out-{source.stem}"
        result = invoke(source, "--format", "c", "--out", out)
        assert result.exit_code == 0, result.output
        _compiles(out)
        text = "".join(p.read_text() for p in out.iterdir())
        assert "ilcpmac_injected = 1" not in text.replace("*\\/ int ilcpmac_injected", "")
        assert text.isascii()


@pytest.mark.parametrize("fmt", FORMATS)
def test_an_output_folder_whose_name_is_no_utf8_is_written(tmp_path, fmt):
    out = tmp_path / "out \udcff"
    result = invoke(result_json(tmp_path), "--format", fmt, "--torque-constant", KT, "--out", out)
    assert result.exit_code == 0, result.output
    assert all(p.stat().st_size > 0 for p in out.iterdir())


# ---------------------------------------------------------------- item 9: a full disk


EXPORTS = [("json", ["compensation.json"]), ("csv", ["calibration.csv", "torque_gain.csv", "feedforward.csv",
                                                     "map.csv"]),
           ("c", ["ilcpmac_compensation.h", "ilcpmac_compensation.c"])]


@pytest.mark.parametrize("fmt, names", EXPORTS)
@pytest.mark.parametrize("before", [False, True])
def test_export_on_a_full_disk_leaves_the_files_as_they_were(tmp_path, monkeypatch, fmt, names, before):
    """The last file of the export hits a full disk: the error names it, and the folder holds what it held (the
    previous export's files, or nothing): no file truncated, none new beside old ones, no temporary."""
    run = run_directory(tmp_path / "run", compensation())
    out = tmp_path / "out"
    if before:
        assert invoke(run, "--format", fmt, "--out", out).exit_code == 0
    old = {p.name: p.read_bytes() for p in out.iterdir()} if before else {}
    (run / "compensation.json").write_text(json.dumps(compensation(seed=2).to_json()))
    full_disk(monkeypatch, names[-1])
    result = invoke(run, "--format", fmt, "--out", out)
    assert result.exit_code == 2 and result.output == f"error: {out / names[-1]}: No space left on device\n"
    assert {p.name: p.read_bytes() for p in out.iterdir()} == old


@pytest.mark.parametrize("fmt, file", [("harmonics", "harmonics.csv"), ("moteus", "moteus_cogging.txt"),
                                       ("c", "ilcpmac_position_table.h")])
def test_a_position_export_on_a_full_disk_names_its_file(tmp_path, monkeypatch, fmt, file):
    full_disk(monkeypatch, file)
    out = tmp_path / "out"
    result = invoke(result_json(tmp_path), "--format", fmt, "--torque-constant", KT, "--out", out)
    assert result.exit_code == 2 and result.output == f"error: {out / file}: No space left on device\n"
    assert list(out.iterdir()) == []
