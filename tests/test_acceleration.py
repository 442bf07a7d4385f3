"""The acceleration method on rolling drive logs: one speed, a speed loop's i_q, no torque sensor (issue 24)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

import ilcpmac.cli.identify  # noqa: F401  (registers the command on main)
import ilcpmac.cli.import_  # noqa: F401
from ilcpmac.bench import read_bench
from ilcpmac.bench.format import write_backemf_csv
from ilcpmac.bench.importer import import_logs, read_mapping
from ilcpmac.cli import main
from ilcpmac.core.records import CURRENTS_FROM_I_Q, IdentificationResult
from ilcpmac.core.torque_source import TorqueSource
from ilcpmac.identify import identify_bench
from ilcpmac.signals.harmonics import harmonic_amplitudes

POLE_PAIRS, SLOTS, COUNTS_PER_REV = 8, 48, 1024
#: the log's 20-bit position (a 16-bit one does not resolve the motion's ripple at order 96: 0.5 of its quantum)
LOG_COUNTS_PER_REV = 2**20
#: back-EMF amplitude per phase, N m/A: K.i = 1.5 K i_q
BACKEMF_NM_PER_A = 0.1
TORQUE_CONSTANT = 1.5 * BACKEMF_NM_PER_A
INERTIA = 0.002
COULOMB_NM = 0.02
#: the position-locked torque: (order, amplitude N m, phase rad); 48 and 96 the cogging, the rest not
POSITION_TORQUE = ((1, 0.03, 0.5), (3, 0.008, -0.7), (16, 0.006, 0.2), (48, 0.04, 0.3), (96, 0.01, 1.1))
CONTROL_HZ = 10_000.0


def position_torque_nm(theta: np.ndarray | float) -> np.ndarray | float:
    return sum(a * np.sin(h * theta + phi) for h, a, phi in POSITION_TORQUE)


def rolling_log(path: Path, speed_hz: float, duration_s: float, rate_hz: float, seed: int,
                bandwidth_hz: float = 40.0) -> Path:
    """A drive log of a PI speed loop at CONTROL_HZ: J domega/dt = K_t i_q + tau_pos(theta) - C sign(omega),
    the speed fed back with noise, logged at ``rate_hz`` (time s, the position in 16-bit counts, i_q with
    noise A), after 1 s of settling."""
    rng = np.random.default_rng(seed)
    dt = 1.0 / CONTROL_HZ
    target = 2 * math.pi * speed_hz
    kp = INERTIA * 2 * math.pi * bandwidth_hz / TORQUE_CONSTANT
    ki = kp * 2 * math.pi * bandwidth_hz / 5
    theta, omega, integral = 0.0, target, COULOMB_NM / TORQUE_CONSTANT
    settle = int(CONTROL_HZ)
    steps = settle + int(duration_s * CONTROL_HZ)
    every = int(round(CONTROL_HZ / rate_hz))
    speed_noise = rng.normal(0.0, 0.005, steps)
    rows = []
    for n in range(steps):
        error = target - (omega + speed_noise[n])
        integral += ki * error * dt
        i_q = kp * error + integral
        if n >= settle and (n - settle) % every == 0:
            rows.append((n * dt, theta, i_q))
        torque = TORQUE_CONSTANT * i_q - COULOMB_NM * math.copysign(1.0, omega)
        for h, a, phi in POSITION_TORQUE:
            torque += a * math.sin(h * theta + phi)
        omega += torque / INERTIA * dt
        theta += omega * dt
    t, position, i_q = np.array(rows).T
    counts = np.round(position / (2 * np.pi) * LOG_COUNTS_PER_REV)
    i_q = i_q + rng.normal(0.0, 0.01, i_q.size)
    np.savetxt(path, np.column_stack([t, counts, i_q]), delimiter=",", header="t,pos,iq", comments="",
               fmt="%.12g")
    return path


def mapping(folder: Path, inertia_kgm2: float, highest_harmonic: int = 150, uncertainty: float = 0.05) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    theta_e = POLE_PAIRS * 2 * np.pi * np.arange(COUNTS_PER_REV) / COUNTS_PER_REV
    write_backemf_csv(folder / "backemf.csv", BACKEMF_NM_PER_A * np.sin(
        theta_e[:, None] - 2 * np.pi * np.arange(3) / 3))
    path = folder / "map.toml"
    path.write_text(f"""\
[bench]
pole_pairs = {POLE_PAIRS}
slots = {SLOTS}
counts_per_rev = {COUNTS_PER_REV}
inertia_kgm2 = {inertia_kgm2!r}
inertia_uncertainty = {uncertainty!r}
backemf_file = "backemf.csv"

[log]
time = "t"
position = "pos"
position_unit = "counts"
position_counts_per_rev = {LOG_COUNTS_PER_REV}
i_q = "iq"
highest_harmonic = {highest_harmonic}
""")
    return path


def truth_nm() -> np.ndarray:
    return np.asarray(position_torque_nm(2 * np.pi * np.arange(COUNTS_PER_REV) / COUNTS_PER_REV))


@pytest.fixture(scope="module")
def rolling_bench(tmp_path_factory) -> Path:
    """10 s of one log at 0.5 Hz, logged at 1 kHz, imported with J given 5 % high (stated uncertainty 5 %)."""
    folder = tmp_path_factory.mktemp("rolling")
    log = rolling_log(folder / "log.csv", 0.5, 10.0, 1000.0, seed=3)
    (imported,) = import_logs([log], read_mapping(mapping(folder, 1.05 * INERTIA)), folder / "bench")
    return imported.folder


def test_an_i_q_log_with_a_cogging_ripple_larger_than_its_mean_imports_and_reads_back(rolling_bench):
    bench = read_bench(rolling_bench)
    assert bench.motor.currents == CURRENTS_FROM_I_Q and bench.motor.inertia_uncertainty == 0.05
    assert bench.motor.log_rate_hz == pytest.approx(1000.0)
    i_q = np.sum(bench.backemf_nm_per_a[bench.trials[0].count % COUNTS_PER_REV] * bench.trials[0].i_ref_a,
                 axis=1) / TORQUE_CONSTANT
    ripple = np.abs(harmonic_amplitudes(i_q[:COUNTS_PER_REV], 48)[48])
    assert ripple > np.mean(i_q)  # the speed loop's ripple at the cogging order dominates


def test_the_position_torque_within_5_percent_and_covered_by_its_standard_errors(rolling_bench):
    result = identify_bench(read_bench(rolling_bench), torque_source=TorqueSource.ENCODER)
    truth = truth_nm()
    error = result.position_torque_nm - truth
    rms = np.sqrt(np.mean(error**2)) / np.sqrt(np.mean(truth**2))
    assert rms < 0.05, rms
    assert np.all(np.abs(error) < 3 * result.position_torque_std_nm)
    estimate = result.details
    h = np.flatnonzero(estimate.resolved)
    assert set(h) >= {order for order, _, _ in POSITION_TORQUE}
    true_h = harmonic_amplitudes(truth, estimate.harmonics_nm.size - 1)
    # |error| over the standard error: Exp(1) squared for the noise, at most about 1 for J's error
    assert np.all(np.abs(estimate.harmonics_nm[h] - true_h[h]) < 3 * np.sqrt(estimate.variance_nm2[h]))
    cogging = harmonic_amplitudes(result.cogging_nm, 96)
    assert np.flatnonzero(np.abs(cogging) > 1e-9).tolist() == [48, 96]
    friction = result.diagnostics["acceleration"]
    assert abs(friction["coulomb_friction_nm"] - COULOMB_NM) < 3 * friction["coulomb_friction_std_nm"] + 1e-3
    assert any("inertia: taken as given" in m for m in result.messages)
    assert any("viscous friction b: not identifiable at one speed" in m for m in result.messages)
    assert any("encoder graduation error" in m for m in result.messages)


def test_identify_cli_writes_an_exportable_result(rolling_bench, tmp_path):
    out = tmp_path / "result.json"
    run = CliRunner().invoke(main, ["identify", str(rolling_bench), "--torque-source", "encoder", "--output",
                                    str(out), "--plots", str(tmp_path / "plots")])
    assert run.exit_code == 0, run.output
    assert "acceleration method at 0.5 Hz" in run.output and "order 48:" in run.output
    assert (tmp_path / "plots" / "acceleration_position_torque.png").is_file()
    result = IdentificationResult.from_json(json.loads(out.read_text()))
    assert result.position_torque_nm is not None and result.cogging_nm is not None
    exported = CliRunner().invoke(main, ["export", str(out), "--out", str(tmp_path / "export")])
    assert exported.exit_code == 0, exported.output


def test_a_log_too_coarse_for_the_cogging_says_so(tmp_path):
    """At 0.5 Hz a 40 Hz log resolves harmonics below 40: the cogging (48, 96) is not estimated, nor where it
    folds (80 rows per revolution: onto 32 and 16), and the result says so."""
    log = rolling_log(tmp_path / "log.csv", 0.5, 10.0, 40.0, seed=5)
    (imported,) = import_logs([log], read_mapping(mapping(tmp_path, INERTIA, highest_harmonic=16)), tmp_path / "b")
    result = identify_bench(read_bench(imported.folder), torque_source=TorqueSource.ENCODER)
    assert result.cogging_nm is None
    assert any("above the log's Nyquist limit" in m and "not estimated, taken as 0" in m for m in result.messages)
    assert any("48 -> 32, 96 -> 16" in m for m in result.messages)
    assert any(m.startswith("cogging orders 48, 96: not estimated") for m in result.messages)
    estimate = result.details
    assert not estimate.resolved[[15, 16, 17, 31, 32, 33]].any() and not estimate.resolved[41:].any()
    assert estimate.resolved[[1, 3]].all()
    true_h = harmonic_amplitudes(truth_nm(), 3)
    assert np.all(np.abs(estimate.harmonics_nm[[1, 3]] - true_h[[1, 3]]) < 3 * np.sqrt(estimate.variance_nm2[[1, 3]]))


def test_the_noise_standard_errors_cover_the_error_over_seeds(tmp_path):
    """J exact and stated so: the error of each reported harmonic is noise alone, |error|^2 / v_h ~ Exp(1) with
    v_h the noise part (a) (the resolution bound (c) only adds, and the quantiser is dithered here)."""
    ratios = []
    for seed in range(8):
        folder = tmp_path / str(seed)
        log = rolling_log(folder.with_suffix(".csv"), 0.5, 10.0, 1000.0, seed=seed)
        (imported,) = import_logs([log], read_mapping(mapping(folder, INERTIA, uncertainty=0.0)), folder / "b")
        estimate = identify_bench(read_bench(imported.folder), torque_source=TorqueSource.ENCODER).details
        h = np.flatnonzero(estimate.resolved)
        true_h = harmonic_amplitudes(truth_nm(), estimate.harmonics_nm.size - 1)
        ratios += list(np.abs(estimate.harmonics_nm[h] - true_h[h]) ** 2 / estimate.noise_variance_nm2[h])
    assert len(ratios) >= 40
    assert 0.3 < np.mean(ratios) < 2.0, np.mean(ratios)  # 0.6 over these seeds: the pooling leans high
    assert np.mean(np.array(ratios) < np.log(20)) > 0.85  # P(Exp(1) < ln 20) = 95 %


def test_a_simulated_drive_log_reports_only_what_it_resolves(tmp_path, seed_config):
    """Through the simulator's rolling logs (`ilcpmac.sim.drive_log`, the seed bench): every harmonic reported
    lies within 3 standard errors of the true position torque, and a cogging not reported is said to be."""
    from ilcpmac.sim.drive_log import LogPlan
    from ilcpmac.sim.log_folders import DRIVE_LOG, MAPPING, write_simulated_log
    from ilcpmac.sim.simulator import Simulator

    (tmp_path / "sim").mkdir()
    truth = write_simulated_log(tmp_path / "sim", Simulator(seed_config.model), LogPlan(seed=1))
    (imported,) = import_logs([tmp_path / "sim" / DRIVE_LOG], read_mapping(tmp_path / "sim" / MAPPING),
                              tmp_path / "bench")
    result = identify_bench(read_bench(imported.folder), torque_source=TorqueSource.ENCODER)
    estimate = result.details
    true_h = harmonic_amplitudes(np.asarray(truth["position_torque"]["torque"]), estimate.harmonics_nm.size - 1)
    h = np.flatnonzero(estimate.resolved)
    assert np.all(np.abs(estimate.harmonics_nm[h] - true_h[h]) < 3 * np.sqrt(estimate.variance_nm2[h]))
    if result.cogging_nm is None:
        assert any(m.startswith("cogging orders 48, 96: not estimated") for m in result.messages)


def test_a_reverse_rolling_log_gives_the_position_torque_in_the_motors_coordinates(tmp_path):
    log = rolling_log(tmp_path / "log.csv", -0.5, 10.0, 1000.0, seed=7)
    (imported,) = import_logs([log], read_mapping(mapping(tmp_path, INERTIA)), tmp_path / "bench")
    assert imported.bench.motor.mirrored
    result = identify_bench(read_bench(imported.folder), torque_source=TorqueSource.ENCODER)
    error = result.position_torque_nm - truth_nm()
    assert np.sqrt(np.mean(error**2) / np.mean(truth_nm() ** 2)) < 0.02
    assert np.all(np.abs(error) < 3 * result.position_torque_std_nm)


@pytest.fixture(scope="module")
def two_speed_bench(tmp_path_factory) -> Path:
    """10 s at 0.4 Hz and 10 s at 0.8 Hz, logged at 1 kHz, imported into one bench with J given 20 % high
    (stated uncertainty 20 %: a loose prior)."""
    folder = tmp_path_factory.mktemp("two_speeds")
    logs = [rolling_log(folder / f"log_{i}.csv", speed, 10.0, 1000.0, seed=11 + i)
            for i, speed in enumerate((0.4, 0.8))]
    (imported,) = import_logs(logs, read_mapping(mapping(folder, 1.2 * INERTIA, uncertainty=0.2)), folder / "bench")
    return imported.folder


def test_two_speeds_identify_the_inertia_and_the_friction(two_speed_bench):
    bench = read_bench(two_speed_bench)
    assert len(bench.trials) == 2
    result = identify_bench(bench, torque_source=TorqueSource.ENCODER)
    estimate = result.details
    assert estimate.inertia_identified and estimate.inertia_given_kgm2 == pytest.approx(1.2 * INERTIA)
    j_std = estimate.inertia_uncertainty * estimate.inertia_kgm2
    assert abs(estimate.inertia_kgm2 - INERTIA) < 3 * j_std, (estimate.inertia_kgm2, j_std)
    assert abs(estimate.inertia_kgm2 / INERTIA - 1) < 0.05
    truth = truth_nm()
    error = result.position_torque_nm - truth
    assert np.sqrt(np.mean(error**2) / np.mean(truth**2)) < 0.05
    assert np.all(np.abs(error) < 3 * result.position_torque_std_nm)
    summary = result.diagnostics["acceleration"]
    assert summary["inertia"] == "identified"
    assert abs(summary["coulomb_friction_nm"] - COULOMB_NM) < 3 * summary["coulomb_friction_std_nm"]
    assert abs(summary["viscous_friction_nm_s"]) < 3 * summary["viscous_friction_std_nm_s"]  # b = 0 in the logs
    assert any(m.startswith("inertia: identified from 2 speeds") for m in result.messages)
    assert any(m.startswith("viscous friction b: identified") for m in result.messages)


def test_identify_cli_at_two_speeds(two_speed_bench, tmp_path):
    run = CliRunner().invoke(main, ["identify", str(two_speed_bench), "--torque-source", "encoder", "--output",
                                    str(tmp_path / "result.json"), "--plots", str(tmp_path / "plots")])
    assert run.exit_code == 0, run.output
    assert "J identified" in run.output and "viscous friction" in run.output
    assert (tmp_path / "plots" / "acceleration_position_torque.png").is_file()
