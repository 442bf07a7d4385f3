"""``ilcpmac export`` of an identification's or a scan's position table: every format read back (moteus's table
sampled as its firmware samples it) reproduces the table within the residual it states, and states what it
leaves."""

from __future__ import annotations

import csv
import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from test_export import C_FLAGS, _compiler

from ilcpmac.cli import main
from ilcpmac.compensation import read_position_table
from ilcpmac.core.errors import BenchFormatError
from ilcpmac.core.records import IdentificationResult, SensorCalibration
from ilcpmac.export import MOTEUS_TABLE_SIZE, export

CPR, ORDER = 4096, 24
CALIBRATION = SensorCalibration([14.0, 14.2, 13.9], [1.5, -2.0, 0.25], 0.908)
THETA = 2.0 * np.pi * np.arange(CPR) / CPR
#: the cogging torque, N m: three multiples of the cogging order, 20 mN m at most
COGGING_NM = 0.02 * np.sin(ORDER * THETA + 0.3) + 0.008 * np.cos(2 * ORDER * THETA) + 0.003 * np.sin(3 * ORDER * THETA)
KT = 0.1


def result_json(folder: Path, cogging: np.ndarray | None = COGGING_NM) -> Path:
    path = folder / "result.json"
    result = IdentificationResult(delta=1.0, cogging_nm=cogging, calibration=CALIBRATION)
    path.write_text(json.dumps(result.to_json()))
    return path


def _rows(path: Path) -> list[list[str]]:
    with path.open(newline="") as f:
        return list(csv.reader(f))


def test_an_identification_reads_as_the_feedforward_that_cancels_its_cogging(tmp_path):
    table = read_position_table(result_json(tmp_path))
    assert table.content == "cogging" and table.counts_per_rev == CPR
    assert np.array_equal(table.feedforward_nm, -COGGING_NM)
    assert np.array_equal(table.orders, np.arange(ORDER, CPR // 2 + 1, ORDER))  # the order read off the table
    assert table.calibration.to_json() == CALIBRATION.to_json()
    a, b = table.coefficients_nm()[:3].T
    assert np.allclose(a, [-0.02 * np.sin(0.3), -0.008, 0.0], rtol=0, atol=1e-15)
    assert np.allclose(b, [-0.02 * np.cos(0.3), 0.0, -0.003], rtol=0, atol=1e-15)


def firmware_sample(values: list[int], scale: float, position: float) -> float:
    """moteus's fw/bldc_servo_control.h sampling, transcribed from its documented behaviour: entry
    min(size - 1, int(size p)), the next one modulo size, linear with the fraction (p - left / size) size."""
    size = len(values)
    left = min(size - 1, int(size * position))
    right = (left + 1) % size
    fraction = (position - left / size) * size
    return (values[right] * scale - values[left] * scale) * fraction + values[left] * scale


def test_the_moteus_lines_sampled_as_the_firmware_does_reproduce_the_table(tmp_path):
    table = read_position_table(result_json(tmp_path))
    exported = export(table, tmp_path / "out", "moteus", torque_constant_nm_per_a=KT)
    lines = (tmp_path / "out" / "moteus_cogging.txt").read_text().splitlines()
    assert len(lines) == 1 + MOTEUS_TABLE_SIZE
    prefix, scale_text = lines[0].rsplit(" ", 1)
    assert prefix == "conf set motor.cogging_dq_scale"
    scale = float(scale_text)
    assert scale == float(np.float32(scale))
    values = []
    for k, line in enumerate(lines[1:]):
        prefix, value = line.rsplit(" ", 1)
        assert prefix == f"conf set motor.cogging_dq_comp.{k}"
        values.append(int(value))
    assert max(abs(v) for v in values) == 127
    got_nm = np.array([firmware_sample(values, scale, c / CPR) for c in range(CPR)]) * KT
    error = got_nm - table.feedforward_nm
    residual = exported.residual
    assert residual.peak_nm == pytest.approx(np.abs(error).max(), rel=1e-9)
    assert residual.rms_nm == pytest.approx(np.sqrt(np.mean(error**2)), rel=1e-9)
    # int8: half a step at most, plus the linear interpolation's images at 1024 k +- n, k >= 1: amplitudes
    # A_n sin^2(pi x) / (pi (k -+ x))^2 with x = n / 1024, in all less than 2 zeta(2) A_n x^2 (1 + 2 x)
    step_nm = scale * KT
    x = np.array([1, 2, 3]) * ORDER / MOTEUS_TABLE_SIZE
    images_nm = float(np.sum(np.pi**2 / 3 * np.array([0.02, 0.008, 0.003]) * x**2 * (1 + 2 * x)))
    assert step_nm / 10 < residual.peak_nm <= step_nm / 2 + images_nm
    assert residual.reference == "the table's peak-to-peak" and residual.reference_nm == np.ptp(-COGGING_NM)


def test_the_harmonics_csv_sums_back_to_the_table(tmp_path):
    table = read_position_table(result_json(tmp_path))
    exported = export(table, tmp_path, "harmonics", torque_constant_nm_per_a=KT, rated_torque_nm=2.0)
    rows = _rows(tmp_path / "harmonics.csv")
    assert rows[0] == ["order", "cos_nm", "sin_nm", "amplitude_nm", "phase_rad", "cos_a_at_0.1_nm_per_a",
                       "sin_a_at_0.1_nm_per_a", "amplitude_a_at_0.1_nm_per_a"]
    data = np.array([[float(v) for v in row] for row in rows[1:]])
    orders = data[:, 0].astype(int)
    assert np.array_equal(orders, np.arange(ORDER, CPR // 2 + 1, ORDER))
    angle = np.outer(THETA, orders)
    summed = np.cos(angle) @ data[:, 1] + np.sin(angle) @ data[:, 2]
    as_phase = np.cos(angle - data[:, 4]) @ data[:, 3]  # a cos + b sin = amplitude cos(n theta - phase)
    assert np.abs(summed + COGGING_NM).max() < 1e-15 and np.abs(as_phase + COGGING_NM).max() < 1e-15
    assert np.allclose(data[:, 5:], data[:, [1, 2, 3]] / KT, rtol=1e-15, atol=0)
    assert exported.residual.peak_nm == pytest.approx(np.abs(summed - table.feedforward_nm).max(), abs=1e-18)
    assert exported.residual.peak_nm < 1e-15 and exported.residual.reference_nm == 2.0


def test_the_csv_and_json_read_back_to_the_same_numbers(tmp_path):
    table = read_position_table(result_json(tmp_path))
    exported = export(table, tmp_path / "csv", "csv")
    assert [p.name for p in exported.files] == ["calibration.csv", "torque_gain.csv", "feedforward.csv"]
    rows = _rows(tmp_path / "csv" / "feedforward.csv")
    assert rows[0] == ["count", "feedforward_nm"] and [int(r[0]) for r in rows[1:]] == list(range(CPR))
    assert np.array_equal([float(r[1]) for r in rows[1:]], -COGGING_NM)
    calibration = np.array([[float(v) for v in row[1:]] for row in _rows(tmp_path / "csv" / "calibration.csv")[1:]])
    assert np.array_equal(calibration[:, 0], CALIBRATION.current_scale)
    assert exported.residual.peak_nm == 0.0
    (path,) = export(table, tmp_path / "json", "json").files
    data = json.loads(path.read_text())
    assert data["kind"] == "position_table" and data["content"] == "cogging" and data["counts_per_rev"] == CPR
    assert np.array_equal(data["feedforward_nm"]["torque"], -COGGING_NM)
    assert data["harmonics"]["orders"][:2] == [ORDER, 2 * ORDER]


DRIVER = """\
#include <stdio.h>
#include "ilcpmac_position_table.h"

int main(void)
{
    uint32_t n;
    for (n = 0u; n < 2u * ILCPMAC_COUNTS_PER_REV; n++) {
        printf("%.9g\\n", (double)ilcpmac_position_feedforward_nm(n));
    }
    return 0;
}
"""


@pytest.mark.parametrize("c_type", ["int16", "float"])
def test_the_c_table_compiles_strict_and_reproduces_the_table(tmp_path, c_type):
    compiler = _compiler()
    table = read_position_table(result_json(tmp_path))
    exported = export(table, tmp_path, "c", c_type)
    (tmp_path / "driver.c").write_text(DRIVER)
    done = subprocess.run([compiler, *C_FLAGS, "-o", str(tmp_path / "driver"), str(tmp_path / "driver.c"),
                           str(tmp_path / "ilcpmac_position_table.c")], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    out = subprocess.run([str(tmp_path / "driver")], capture_output=True, text=True, check=True, timeout=60).stdout
    got = np.array([float(v) for v in out.split()]).astype(np.float32).astype(float)  # the floats printed
    assert np.array_equal(got[:CPR], got[CPR:])  # the count is taken modulo counts_per_rev
    error = got[:CPR] - table.feedforward_nm
    assert exported.residual.peak_nm == pytest.approx(np.abs(error).max(), rel=1e-6)
    peak = np.abs(COGGING_NM).max()
    assert exported.residual.peak_nm <= (peak / 30000 / 2 * 1.001 if c_type == "int16" else 1e-7 * peak)
    header = (tmp_path / "ilcpmac_position_table.h").read_text()
    assert "ilcpmac_current_scale_counts_per_a[3]" in header


def scan_json(folder: Path) -> Path:
    """A standstill scan's result: the cogging map and a position torque with a 5th harmonic beside it."""
    position = COGGING_NM + 0.004 * np.cos(5 * THETA)
    path = folder / "scan.json"
    path.write_text(json.dumps({"kind": "standstill_scan", "counts_per_rev": CPR, "cogging_order": ORDER,
                                "cogging": {"count": list(range(CPR)), "torque": COGGING_NM.tolist()},
                                "position_torque": {"count": list(range(CPR)), "torque": position.tolist()}}))
    return path


def test_a_scan_exports_its_cogging_or_its_whole_position_torque(tmp_path):
    path = scan_json(tmp_path)
    cogging = read_position_table(path)
    assert cogging.calibration is None and np.array_equal(cogging.orders, np.arange(ORDER, CPR // 2 + 1, ORDER))
    whole = read_position_table(path, "position-torque")
    assert np.array_equal(whole.orders, np.arange(1, CPR // 2 + 1))
    assert np.allclose(whole.coefficients_nm()[4], [-0.004, 0.0], atol=1e-15)
    assert [p.name for p in export(cogging, tmp_path / "csv", "csv").files] == ["feedforward.csv"]


def test_a_result_without_cogging_is_one_line_naming_the_file(tmp_path):
    path = result_json(tmp_path, cogging=None)
    with pytest.raises(BenchFormatError, match="^" + str(path) + ": no cogging table"):
        read_position_table(path)
    out = CliRunner().invoke(main, ["export", str(path), "--format", "moteus", "--out", str(tmp_path / "out"),
                                    "--torque-constant", "0.1"])
    assert out.exit_code == 2 and out.output.startswith(f"error: {path}: no cogging table")
    assert len(out.output.splitlines()) == 1 and not (tmp_path / "out").exists()


def test_export_moteus_from_a_result_prints_the_residual(tmp_path):
    path = result_json(tmp_path)
    out = CliRunner().invoke(main, ["export", str(path), "--format", "moteus", "--out", str(tmp_path / "m"),
                                    "--torque-constant", "0.1"])
    assert out.exit_code == 0, out.output
    lines = out.output.splitlines()
    assert lines[0].startswith("wrote 1 file, ") and lines[1].split()[0] == "moteus_cogging.txt"
    residual = export(read_position_table(path), tmp_path / "again", "moteus", torque_constant_nm_per_a=KT).residual
    assert [line.split(":")[0] for line in lines[2:4]] == ["bound", "bound"] and lines[4] == residual.line("moteus")
    assert lines[4].startswith("residual ripple of the moteus export: ") and "of the table's peak-to-peak" in lines[4]


def test_the_drive_formats_need_a_torque_constant_and_a_result(tmp_path):
    path = result_json(tmp_path)
    out = CliRunner().invoke(main, ["export", str(path), "--format", "harmonics", "--out", str(tmp_path / "h")])
    assert out.exit_code == 2 and len(out.output.splitlines()) == 1
    assert out.output.startswith("error: --format harmonics needs --torque-constant NM_PER_A > 0")
    assert not (tmp_path / "h").exists()


def test_a_result_exports_its_position_torque_or_says_it_holds_only_the_cogging(tmp_path):
    """The acceleration method's result: --content position-torque is its position_torque, a 5th harmonic
    beside the cogging; a result without one is refused in one line, never exported as its cogging."""
    position = COGGING_NM + 0.004 * np.cos(5 * THETA)
    path = tmp_path / "rolling.json"
    path.write_text(json.dumps(IdentificationResult(cogging_nm=COGGING_NM, position_torque_nm=position,
                                                    position_torque_std_nm=np.full(CPR, 1e-4)).to_json()))
    whole = read_position_table(path, "position-torque")
    assert whole.content == "position-torque" and np.array_equal(whole.feedforward_nm, -position)
    assert np.allclose(whole.coefficients_nm()[4], [-0.004, 0.0], atol=1e-15)
    assert np.array_equal(read_position_table(path).feedforward_nm, -COGGING_NM)
    only_cogging = result_json(tmp_path)
    out = CliRunner().invoke(main, ["export", str(only_cogging), "--format", "csv", "--content", "position-torque",
                                    "--out", str(tmp_path / "out")])
    assert out.exit_code == 2 and len(out.output.splitlines()) == 1, out.output
    assert out.output.startswith(f"error: {only_cogging}: no position torque") and "only the cogging" in out.output
    assert not (tmp_path / "out").exists()


def test_a_scan_without_cogging_says_so_and_exports_its_position_torque(tmp_path):
    """A scan whose cogging order is beyond its counts' Nyquist limit writes "cogging": null; its export read as
    "not a result of ilcpmac identify (TypeError ...)"."""
    path = scan_json(tmp_path)
    path.write_text(json.dumps({**json.loads(path.read_text()), "cogging": None}))
    with pytest.raises(BenchFormatError, match=r"scan.json: no cogging table \(key 'cogging' is missing or null\)"):
        read_position_table(path)
    assert read_position_table(path, "position-torque").feedforward_nm.size == CPR


def test_the_residual_line_says_it_is_the_format_s_and_what_is_known_of_the_table(tmp_path):
    """Issue 35, item 3: the moteus export's residual (1.1-2.7 %) read as the table's accuracy, 2.6x smaller than its
    true error. The line now says the residual is the format's, and gives the table's own standard error where its
    source states one."""
    path = scan_json(tmp_path)
    data = json.loads(path.read_text())
    data["cogging"]["std"] = [0.002] * CPR
    path.write_text(json.dumps(data))
    line = export(read_position_table(path), tmp_path / "with", "csv").residual.line("csv")
    assert "the format's, not the table's accuracy; the table itself is known to 0.002 N m RMS" in line
    del data["cogging"]["std"]
    path.write_text(json.dumps(data))
    line = export(read_position_table(path), tmp_path / "without", "csv").residual.line("csv")
    assert line.endswith("the format's, not the table's accuracy; its source states no standard error of the table")
    data["cogging"]["std"] = [-1.0] * CPR
    path.write_text(json.dumps(data))
    with pytest.raises(BenchFormatError, match=r"key 'cogging.std': needs one standard error >= 0 per value"):
        read_position_table(path)
