"""moteus cogging files (utils/compensate_cogging.py of mjbots/moteus): imported as a scan folder and identified.

The synthetic files follow the script and the firmware: {"reverse": [...], "forward": [...]}, per direction the
mean q-axis current (A) of each of 128 x split_count equal bins of a revolution, taken at constant speed in
position control: k_q i_q = -tau_pos(theta) + s f(theta) averaged over the bin.
"""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import ilcpmac.cli.identify  # noqa: F401  (registers the commands on main)
import ilcpmac.cli.import_  # noqa: F401
from ilcpmac.bench.format import write_backemf_csv
from ilcpmac.bench.importer import read_mapping, write_scan_folder
from ilcpmac.bench.moteus import MoteusMapping, cogging_scan
from ilcpmac.cli import main
from ilcpmac.core.errors import BenchFormatError, ConfigError

COUNTS_PER_REV = 1024
POLE_PAIRS = 8
#: amplitude of the back-EMF's fundamental, N m / A: k_q = 1.5 x 0.2
K1_NM_PER_A = 0.2
K_Q = 1.5 * K1_NM_PER_A
#: the cogging of 48 slots and 8 pole pairs (order 48): harmonic -> (cos, sin) N m
COGGING = {48: (0.040, -0.025), 96: (0.012, 0.018), 144: (-0.006, 0.004), 192: (0.003, -0.002),
           240: (0.004, 0.003)}
#: position torque that is not cogging (an eccentric rotor), and Coulomb friction with a position-dependent part
OTHER = {1: (0.010, 0.004), 2: (-0.003, 0.002)}
FRICTION_NM = 0.03
MAPPING = f"""\
[bench]
pole_pairs = {POLE_PAIRS}
slots = 48
counts_per_rev = {COUNTS_PER_REV}
inertia_kgm2 = 0.01
backemf_file = "backemf.csv"

[log]
kind = "moteus-cogging"
"""


def series(terms: dict[int, tuple[float, float]], theta: np.ndarray) -> np.ndarray:
    return sum(a * np.cos(h * theta) + b * np.sin(h * theta) for h, (a, b) in terms.items())


def cogging_file(path: Path, bins: int, seed: int, noise_a: float = 2e-3) -> Path:
    """A moteus cogging file of ``bins`` bins a direction: each the mean of 64 samples evenly spread over it
    (constant speed), plus the scatter of the bin's mean, ``noise_a``."""
    rng = np.random.default_rng(seed)
    theta = 2 * np.pi * (np.arange(bins * 64) + 0.5) / (bins * 64)
    position_torque = series(COGGING, theta) + series(OTHER, theta)
    friction = FRICTION_NM + 0.005 * np.sin(theta + 0.3)
    data = {}
    for key, sign in (("reverse", -1.0), ("forward", 1.0)):  # the script's order: -speed, then +speed
        i_q = (-position_torque + sign * friction) / K_Q
        data[key] = (i_q.reshape(bins, 64).mean(axis=1) + noise_a * rng.standard_normal(bins)).tolist()
    path.write_text(json.dumps(data))
    return path


@pytest.fixture
def mapping_file(tmp_path) -> Path:
    theta_e = POLE_PAIRS * 2 * np.pi * np.arange(COUNTS_PER_REV) / COUNTS_PER_REV
    write_backemf_csv(tmp_path / "backemf.csv",
                      K1_NM_PER_A * np.column_stack([np.sin(theta_e - 2 * np.pi * p / 3) for p in range(3)]))
    path = tmp_path / "map.toml"
    path.write_text(MAPPING)
    return path


@pytest.mark.parametrize("seed", [3, 4])
def test_a_moteus_cogging_file_imports_and_identifies_its_cogging(tmp_path, mapping_file, seed):
    log = cogging_file(tmp_path / "cogging.json", 2048, seed)  # split_count 16: two bins a count
    out = tmp_path / "scan"
    imported = CliRunner().invoke(main, ["import", str(log), "--map", str(mapping_file), "--out", str(out)])
    assert imported.exit_code == 0, imported.output
    output = " ".join(imported.output.split())
    assert "2048 forward and 2048 reverse samples, holding torque" in output
    assert "k_q = 0.3 N m / A" in output
    identified = CliRunner().invoke(main, ["identify", str(out), "--output", str(tmp_path / "scan.json")])
    assert identified.exit_code == 0, identified.output
    result = json.loads((tmp_path / "scan.json").read_text())
    harmonics = result["cogging_harmonics"]
    assert harmonics["orders"] == list(range(48, 513, 48))
    true = np.array([COGGING.get(h, (0.0, 0.0)) for h in harmonics["orders"]])
    got = np.column_stack([harmonics["cos_nm"], harmonics["sin_nm"]])
    std = np.column_stack([harmonics["cos_std_nm"], harmonics["sin_std_nm"]])
    error = got - true
    # bins of 2 mA scatter (0.6 mN m of holding torque): 2.4e-5 N m per coefficient; the reduction's
    # correction for samples a quarter count off their count leaves harmonic 240 (of 0.005 N m) 1.5 % low
    assert np.abs(error).max() < 1e-4
    assert np.abs(error[:4]).max() < 4 * std[:4].min()
    cogging = np.asarray(result["cogging"]["torque"])
    truth = series(COGGING, 2 * np.pi * np.arange(COUNTS_PER_REV) / COUNTS_PER_REV)
    assert np.sqrt(np.mean((cogging - truth) ** 2)) < 0.005 * np.sqrt(np.mean(truth**2))
    assert abs(result["friction_mean_nm"] - FRICTION_NM) < 1e-4


@pytest.mark.parametrize("bins", [1024, 2048])
def test_the_samples_are_the_holding_torque_at_the_bin_centres(tmp_path, mapping_file, bins):
    mapping = read_mapping(mapping_file)
    assert isinstance(mapping, MoteusMapping)
    mapping = dataclasses.replace(mapping, motor=dataclasses.replace(mapping.motor, counts_per_rev=bins // 2))
    scan = cogging_scan(cogging_file(tmp_path / "cogging.json", bins, 0, noise_a=0.0), mapping)
    theta = 2 * np.pi * scan.position_counts / (bins // 2)
    position_torque = series(COGGING, theta) + series(OTHER, theta)
    friction = FRICTION_NM + 0.005 * np.sin(theta + 0.3)
    truth = -position_torque + scan.direction * friction
    np.testing.assert_array_equal(scan.direction, np.repeat([1.0, -1.0], bins))
    np.testing.assert_allclose(scan.position_counts[:bins], (np.arange(bins) + 0.5) / 2)
    np.testing.assert_allclose(scan.position_counts[bins:], scan.position_counts[bins - 1::-1])
    # the bins' averaging undone: harmonic 240 of 1024 bins would otherwise be sinc(240 / 1024) = 9 % low
    assert np.abs(scan.torque_nm - truth).max() < 1e-5 * np.abs(truth).max()


def test_the_bins_must_give_two_samples_a_count(tmp_path, mapping_file):
    log = cogging_file(tmp_path / "cogging.json", 1024, 1)  # the script's default split_count 8
    with pytest.raises(BenchFormatError, match=r"cogging.json: 1024 bins a revolution, fewer than two per count of "
                       r"\[bench\] counts_per_rev = 1024 .*counts_per_rev 512 or fewer\)$") as e:
        write_scan_folder([log], read_mapping(mapping_file), tmp_path / "scan")
    assert "\n" not in str(e.value)
    assert not (tmp_path / "scan").exists()


def good(bins: int = 2048) -> dict:
    return {"reverse": [0.01] * bins, "forward": [0.02] * bins}


def with_value(key: str, index: int, value) -> str:
    data = good()
    data[key][index] = value
    return json.dumps(data)


@pytest.mark.parametrize(("text", "expected"), [
    (json.dumps({"reverse": [0.01] * 2048}), r"missing key 'forward'"),
    (json.dumps({**good(), "speed": 2}), r"unknown key 'speed' \(a moteus cogging file holds forward, reverse\)"),
    (json.dumps({"reverse": [0.01] * 2000, "forward": [0.02] * 2000}),
     r"forward: must be a list of 128 x split_count numbers, at most 65536, got 2000 values"),
    (json.dumps({"reverse": [0.01] * 2048, "forward": {"0": 1}}), r"forward: must be a list .* got a dict"),
    (json.dumps({"reverse": [0.01] * 2048, "forward": [0.02] * 4096}), r"forward has 4096 values, reverse 2048"),
    (with_value("forward", 17, float("nan")), r"forward\[17\]: nan is not a finite current within \+-10000 A"),
    (with_value("reverse", 5, float("inf")), r"reverse\[5\]: inf is not a finite current"),
    (with_value("forward", 3, "0.1"), r"forward\[3\]: '0.1' is not a finite current"),
    (with_value("forward", 3, True), r"forward\[3\]: True is not a finite current"),
    (with_value("forward", 9, 2e4), r"forward\[9\]: 20000.0 is not a finite current"),
    ('{"forward": [0.1], "forward": [0.2], "reverse": [0.3]}', r"key 'forward' given twice"),
    ('{"forward": [0.1, ', r"line 1: not JSON \(Expecting value\)"),
    ("[1, 2]", r"not a JSON object with the keys forward, reverse"),
    ("[" * 100_000, r"nested too deeply"),
])
def test_a_malformed_cogging_file_gives_one_line_naming_the_file_and_key(tmp_path, mapping_file, text, expected):
    log = tmp_path / "cogging.json"
    log.write_text(text)
    result = CliRunner().invoke(main, ["import", str(log), "--map", str(mapping_file), "--out",
                                       str(tmp_path / "scan")])
    assert result.exit_code == 2, result.output
    message = " ".join(result.output.split())
    assert re.search(expected, message), message
    assert str(log) in message and "Traceback" not in result.output
    with pytest.raises(BenchFormatError, match=expected) as e:
        write_scan_folder([log], read_mapping(mapping_file), tmp_path / "scan")
    assert "\n" not in str(e.value) and str(e.value).startswith(str(log))


@pytest.mark.parametrize(("extra", "expected"), [
    ('time = "t"\n', r"\[log\] unknown key 'time'"),
    ('\n[[points]]\nfile = "cogging.json"\ntorque_setpoint_nm = 1.0\nspeed_setpoint_hz = 1.0\n',
     r"\[\[points\]\]: only for run logs"),
])
def test_a_moteus_mapping_takes_the_kind_alone(tmp_path, mapping_file, extra, expected):
    mapping_file.write_text(MAPPING + extra)
    with pytest.raises(ConfigError, match=expected) as e:
        read_mapping(mapping_file)
    assert "\n" not in str(e.value) and str(e.value).startswith(str(mapping_file))


def test_a_moteus_mapping_keeps_the_scan_errors(tmp_path, mapping_file):
    mapping_file.write_text(MAPPING + "\n[scan]\ntorque_sensor_gain = 1.05\ntorque_sensor_gain_std = 0.01\n")
    mapping = read_mapping(mapping_file)
    assert isinstance(mapping, MoteusMapping) and mapping.motor.torque_sensor
    assert (mapping.scan_errors.torque_sensor_gain, mapping.scan_errors.torque_sensor_gain_std) == (1.05, 0.01)
