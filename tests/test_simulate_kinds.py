"""``ilcpmac simulate --kind grid|scan|log``: the grid unchanged; a scan that imports and identifies the cogging
within its stated uncertainty; a rolling log that imports and whose truth its motion obeys."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from click.testing import CliRunner, Result
from conftest import COUNTS_PER_REV

import ilcpmac.cli.identify  # noqa: F401  (registers the commands on main)
import ilcpmac.cli.import_  # noqa: F401
import ilcpmac.cli.simulate  # noqa: F401
from ilcpmac.bench.importer import read_mapping
from ilcpmac.campaign import simulate_bench
from ilcpmac.cli import main
from ilcpmac.config import load_config

#: two trials of two revolutions at 1024 counts per revolution (tests/test_cli_simulate.py's)
SMALL = {"bench": {"counts_per_rev": COUNTS_PER_REV},
         "trials": {"torque_setpoints_nm": [2.0], "speed_setpoints_hz": [0.5, 1.0], "revolutions": 2}}


def run(*args: str) -> Result:
    return CliRunner().invoke(main, list(args))


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def test_grid_is_the_library_grid(write_config, tmp_path):
    config = write_config(SMALL)
    result = run("simulate", str(config), "--out", str(tmp_path / "cli"), "--kind", "grid")
    assert result.exit_code == 0, result.output
    simulate_bench(load_config(config), tmp_path / "library")
    names = sorted(p.name for p in (tmp_path / "library").iterdir())
    assert sorted(p.name for p in (tmp_path / "cli").iterdir()) == names
    for name in names:
        assert (tmp_path / "cli" / name).read_bytes() == (tmp_path / "library" / name).read_bytes(), name


def test_scan_imports_and_identifies_the_cogging_within_its_uncertainty(write_config, tmp_path):
    """tests/test_standstill.py's bounds, on the folder the command writes and the mapping as it is."""
    out = tmp_path / "sim"
    result = run("simulate", str(write_config(SMALL)), "--out", str(out), "--kind", "scan", "--seed", "5")
    assert result.exit_code == 0, result.output
    assert {p.name for p in out.iterdir()} == {"scan_log.csv", "mapping.toml", "backemf.csv", "truth.json"}
    folder = tmp_path / "scan"
    result = run("import", str(out / "scan_log.csv"), "--map", str(out / "mapping.toml"), "--out", str(folder))
    assert result.exit_code == 0, result.output
    shutil.copy(out / "truth.json", folder / "truth.json")
    result = run("identify", str(folder), "--output", str(tmp_path / "scan.json"))
    assert result.exit_code == 0, result.output
    truth = json.loads((out / "truth.json").read_text())
    data = json.loads((tmp_path / "scan.json").read_text())
    true = np.asarray(truth["cogging"]["torque"])
    cogging, std = np.asarray(data["cogging"]["torque"]), np.asarray(data["cogging"]["std"])
    assert rms(cogging - true) < 0.02 * rms(true)
    z = (cogging - true) / std
    assert rms(z) < 1.5 and np.abs(z).max() < 4.5
    harmonics = data["cogging_harmonics"]
    c = np.fft.rfft(true) / COUNTS_PER_REV * 2
    orders = np.asarray(harmonics["orders"])
    for key, value in (("cos", c.real[orders]), ("sin", -c.imag[orders])):
        assert np.all(np.abs(np.asarray(harmonics[f"{key}_nm"]) - value) < 3 * np.asarray(harmonics[f"{key}_std_nm"]))


@pytest.fixture(scope="module")
def rolling_log(tmp_path_factory):
    """The seed bench's speed-loop log (a 20-bit position in rad, imported onto 4096 counts; 0.5 Hz, 1 kHz, 10 s),
    imported."""
    from conftest import SEED_CONFIG

    tmp = tmp_path_factory.mktemp("log")
    result = run("simulate", str(SEED_CONFIG), "--out", str(tmp / "sim"), "--kind", "log")
    assert result.exit_code == 0, result.output
    imported = run("import", str(tmp / "sim" / "drive_log.csv"), "--map", str(tmp / "sim" / "mapping.toml"), "--out",
                   str(tmp / "bench"))
    data = np.genfromtxt(tmp / "sim" / "drive_log.csv", delimiter=",", names=True)
    return data, json.loads((tmp / "sim" / "truth.json").read_text()), imported


def test_log_imports_as_it_is(rolling_log):
    _, _, imported = rolling_log
    assert imported.exit_code == 0, imported.output
    assert "no torque column" in imported.output


def test_a_log_of_phase_currents_imports_and_identifies_as_the_i_q_log(rolling_log, tmp_path):
    """The same speed-loop log with phase currents: their largest harmonic is a sideband of the cogging order, and
    the electrical-period check (refusing it once) reads the period off their space vector instead."""
    from conftest import SEED_CONFIG

    _, truth, _ = rolling_log
    done = run("simulate", str(SEED_CONFIG), "--out", str(tmp_path / "sim"), "--kind", "log", "--current-column",
               "phases")
    assert done.exit_code == 0, done.output
    done = run("import", str(tmp_path / "sim" / "drive_log.csv"), "--map", str(tmp_path / "sim" / "mapping.toml"),
               "--out", str(tmp_path / "bench"))
    assert done.exit_code == 0, done.output
    done = run("identify", str(tmp_path / "bench"), "--torque-source", "encoder", "--output", str(tmp_path / "r.json"))
    assert done.exit_code == 0, done.output
    cogging = np.asarray(json.loads((tmp_path / "r.json").read_text())["cogging"]["torque"])
    true = np.asarray(truth["cogging"]["torque"])
    assert rms(cogging - true) < 0.05 * rms(true)


def test_log_obeys_its_truths_equation_of_motion(rolling_log):
    """The position's second difference against J domega/dt = k_q i_q + tau_pos - (F + L) from the truth, at
    the cogging order: within 5 %, and a 20 % wrong inertia is seen."""
    data, truth, _ = rolling_log
    t, theta, i_q = data["time"], data["position"], data["i_q"]
    cpr = len(truth["cogging"]["count"])
    grid = 2 * np.pi * np.arange(cpr + 1) / cpr

    def table(values):  # a per-count table at the logged position (the nearest of the drive's 2^20 lines)
        return np.interp(theta % (2 * np.pi), grid, np.append(values, values[0]))

    torque = (table(truth["torque_per_ampere"]["nm_per_a"]) * i_q + table(truth["position_torque"]["torque"])
              - truth["coulomb_friction_nm"] - truth["load_nm"])
    period = t[1] - t[0]
    acceleration = (theta[2:] - 2 * theta[1:-1] + theta[:-2]) / period**2
    speed = (theta[-1] - theta[0]) / (t[-1] - t[0])
    weights = np.hanning(acceleration.size) * np.exp(-48j * speed * t[1:-1])
    predicted, measured = np.sum(weights * torque[1:-1]), np.sum(weights * acceleration)
    inertia = truth["inertia_kgm2"]
    assert abs(measured - predicted / inertia) < 0.05 * abs(predicted / inertia)
    assert abs(measured - predicted / (1.2 * inertia)) > 0.1 * abs(predicted / inertia)


def test_speed_loop_ripple_at_the_cogging_order_exceeds_the_mean(rolling_log):
    data, truth, _ = rolling_log
    i_q = data["i_q"]
    ripple = 2 * abs(np.mean(i_q * np.exp(-48j * data["position"])))
    assert ripple > 2 * i_q.mean()
    assert i_q.mean() == pytest.approx(truth["load_nm"] / truth["torque_constant_nm_per_a"], rel=0.2)


def test_the_log_holds_its_encoders_nearest_line_and_the_mapping_states_the_inertia(write_config, tmp_path):
    """A 12-bit log holds the nearest line of the true angle (not truncated; the drive commutates at that
    reading, so its motion is not a 24-bit log's); the mapping gives the controller's J and its relative error
    as uncertainty."""
    from ilcpmac.sim.drive_log import LogPlan, drive_log
    from ilcpmac.sim.simulator import Simulator

    config = write_config({**SMALL, "simulator": {"mechanics": {"coulomb_friction_nm": 0.0, "inertia_scale": 1.04}}})
    out = tmp_path / "12"
    result = run("simulate", str(config), "--out", str(out), "--kind", "log", "--loop", "current", "--duration-s", "1",
                 "--encoder-bits", "12")
    assert result.exit_code == 0, result.output
    position = np.genfromtxt(out / "drive_log.csv", delimiter=",", names=True)["position"]
    log = drive_log(Simulator(load_config(config).model), LogPlan(loop="current", duration_s=1.0, encoder_bits=12))
    np.testing.assert_allclose(position, log.columns["position"], rtol=0, atol=1e-9)
    lines, true = position * 2**12 / (2 * np.pi), log.angle_rad * 2**12 / (2 * np.pi)
    assert np.abs(lines - np.round(lines)).max() < 1e-4
    assert np.array_equal(np.round(lines), np.round(true))
    mapping = read_mapping(out / "mapping.toml")
    truth = json.loads((out / "truth.json").read_text())
    assert mapping.motor.inertia_kgm2 * 1.04 == pytest.approx(truth["inertia_kgm2"], rel=1e-12)
    assert mapping.motor.inertia_uncertainty == pytest.approx(0.04)


def test_a_log_in_wrapped_lines_on_a_1_ms_clock_says_so_in_its_mapping(write_config, tmp_path):
    """The position in lines of the drive's 16-bit encoder, wrapped once per revolution, and stamps in whole
    milliseconds: the mapping names the unit, the lines per revolution and the clock's tick; the encoder's truth is
    in truth.json."""
    out = tmp_path / "log"
    result = run("simulate", str(write_config(SMALL)), "--out", str(out), "--kind", "log", "--duration-s", "4",
                 "--speed-hz", "1", "--position-unit", "counts", "--position-wrap", "--stamp-s", "0.001",
                 "--jitter-s", "0.002", "--latency-s", "0.0005", "--encoder-bits", "16",
                 "--encoder-eccentricity-counts", "0.5", "--encoder-harmonics", "2:0.2:1.0")
    assert result.exit_code == 0, result.output
    data = np.genfromtxt(out / "drive_log.csv", delimiter=",", names=True)
    assert np.array_equal(data["position"], np.round(data["position"]))
    assert data["position"].min() >= 0 and data["position"].max() < 2**16 and np.any(np.diff(data["position"]) < 0)
    assert np.all(np.diff(data["time"]) > 0) and np.allclose(data["time"] * 1e3, np.round(data["time"] * 1e3))
    layout = read_mapping(out / "mapping.toml").layout
    assert (layout.position_unit, layout.position_counts_per_rev, layout.timer_resolution_s) == ("counts", 2**16, 1e-3)
    truth = json.loads((out / "truth.json").read_text())
    assert truth["host"]["rows"] == data.size and truth["host"]["rows"] + truth["host"]["rows_left_out"] == 4000
    assert f"{data.size} rows, {truth['host']['rows_left_out']} left out" in " ".join(result.output.split())
    encoder = truth["drive_encoder"]
    assert encoder["harmonics"] == {"orders": [2], "counts": [0.2], "phases_rad": [1.0]}
    theta = 2 * np.pi * np.arange(COUNTS_PER_REV) / COUNTS_PER_REV
    np.testing.assert_allclose(encoder["error"]["drive_counts"], 0.5 * np.sin(theta) + 0.2 * np.sin(2 * theta + 1.0),
                               rtol=0, atol=1e-12)


@pytest.mark.parametrize("options, message", [
    (["--kind", "log", "--encoder-bits", "30"], "--encoder-bits: invalid value 30 (the drive's encoder"),
    (["--kind", "scan", "--speed-hz", "1"], "--speed-hz: not for --kind scan"),
    (["--kind", "scan", "--position-wrap"], "--position-wrap: not for --kind scan"),
    (["--kind", "grid", "--rate-hz", "100"], "--rate-hz: not for --kind grid"),
    (["--kind", "log", "--rate-hz", "20000"], "--rate-hz: 20000 Hz is more than half the control rate 20000 Hz"),
    (["--kind", "log", "--jitter-s", "0.02"], "--jitter-s: invalid value 0.02 (each request"),
    (["--kind", "log", "--stamp-s", "0.01"], "--stamp-s: invalid value 0.01 (the host clock's tick"),
    (["--kind", "log", "--duration-s", "0.0001"], "--duration-s: 0.0001 s x 1000 Hz is 0 rows, not within"),
    (["--kind", "log", "--speed-hz", "11"], "--speed-hz: 11 Hz x the tables' highest order 100 is more than"),
    (["--kind", "log", "--speed-bandwidth-hz", "300"], "--speed-bandwidth-hz: 300 Hz is more than the control rate"),
    (["--kind", "log", "--encoder-harmonics", "2:x"], "--encoder-harmonics: invalid value '2:x' (the drive encoder"),
    (["--kind", "log", "--encoder-bits", "8", "--encoder-eccentricity-counts", "30"],
     "--encoder-eccentricity-counts: the error's slope E + sum k A_k = 30 lines per rad is more than"),
])
def test_bad_options_exit_2_with_one_line_before_writing(write_config, tmp_path, options, message):
    result = run("simulate", str(write_config(SMALL)), "--out", str(tmp_path / "out"), *options)
    assert result.exit_code == 2
    (line,) = result.stderr.strip().splitlines()
    assert line.startswith(f"error: {message}"), line
    assert not (tmp_path / "out").exists()


def test_a_log_on_a_full_disk_names_its_file_and_leaves_none_truncated(write_config, tmp_path, monkeypatch):
    """drive_log.csv was written in place: a full disk left a truncated log, and an error naming no file."""
    from test_output_and_sweep_garbage import full_disk

    full_disk(monkeypatch, "drive_log.csv")
    out = tmp_path / "out"
    result = run("simulate", str(write_config(SMALL)), "--out", str(out), "--kind", "log", "--duration-s", "1")
    assert result.exit_code == 2, result.output
    assert result.stderr.strip() == f"error: {out / 'drive_log.csv'}: No space left on device"
    assert not (out / "drive_log.csv").exists() and not list(out.glob("*.tmp"))
