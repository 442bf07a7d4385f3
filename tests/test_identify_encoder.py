"""Benches without a torque sensor, and the identification on the encoder-derived torque (issue 12).

Small simulated benches (1024 counts, 3 and 5 N m at 1 and 1.5 Hz, 6 revolutions; slower, the
cogging's speed ripple, +-40 % at 1 N m and 0.5 Hz, makes the dwell per count alias at 1024 counts)
with a known encoder error: the
bench format reads and writes them, `identify_bench` recovers the sensors and the cogging within stated
bounds, the encoder error within 10 % from two speeds, and says what it cannot identify.
"""

from __future__ import annotations

import dataclasses
import io
import json
import tomllib
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import SEED_CONFIG, toml_text
from rich.console import Console

from ilcpmac.bench.format import Bench, convert_bench, read_bench
from ilcpmac.campaign.service import simulate_bench
from ilcpmac.cli import main
from ilcpmac.cli.identify import estimates_table
from ilcpmac.config import load_config
from ilcpmac.core.current_loop import CurrentLoop
from ilcpmac.core.errors import BenchFormatError, IdentificationError
from ilcpmac.core.records import IdentificationResult
from ilcpmac.core.torque_source import TorqueSource
from ilcpmac.identify import DEFAULT_LOOP, identify_bench
from ilcpmac.identify.encoder import timer_resolution_s
from ilcpmac.identify.joint import (
    LINEAR,
    NONLINEAR,
    SENSOR_PARAMETERS,
    _covariance,
    _fit_nonlinear,
    _JointProblem,
    fit_joint,
    harmonic_sets,
)
from ilcpmac.identify.reduction import BenchTables
from ilcpmac.signals.encoder_torque import (
    EncoderTorqueSpectrum,
    encoder_error_summary,
    encoder_error_table,
    encoder_error_torque_nm,
    separate_encoder_error,
    significant_encoder_error,
    with_viscous,
)
from ilcpmac.signals.harmonics import harmonic_amplitudes

#: the encoder error of the test benches: 0.05 counts once per revolution, 0.01 counts RMS per line
ECCENTRICITY_COUNTS = 0.05
LINE_STD_COUNTS = 0.01
#: the current offsets of the pure-sine bench: a common part of 0.2 A, differential [1, -0.5, -0.5] A
PURE_SINE_BETA_A = [1.2, -0.3, -0.3]
#: the campaign's ripple band (configs/seed-bench.toml [campaign] ripple_harmonics)
RIPPLE_HARMONICS = 150


def _config(folder: Path, speeds_hz: list[float], perfect: bool = False, pure_sine: bool = False) -> Path:
    """The test bench; ``perfect``: no encoder error; ``pure_sine``: a symmetric, purely sinusoidal back-EMF
    (sum_p K_p = 0) and current offsets with a common part of 0.2 A."""
    data = tomllib.loads(SEED_CONFIG.read_text())
    data["bench"]["counts_per_rev"] = 1024
    data["trials"].update(torque_setpoints_nm=[3.0, 5.0], speed_setpoints_hz=speeds_hz, revolutions=6)
    data["simulator"]["encoder"].update(eccentricity_counts=0.0 if perfect else ECCENTRICITY_COUNTS,
                                        eccentricity_phase_rad=0.7, line_std_counts=0.0 if perfect else LINE_STD_COUNTS,
                                        line_seed=3)
    if pure_sine:
        data["bench"]["backemf"].update(harmonics=[1], amplitudes_nm_per_a=[0.2], phases_rad=[0.0],
                                        asymmetry=[0.0, 0.0, 0.0])
        data["simulator"]["current_sensors"]["beta_a"] = PURE_SINE_BETA_A
    path = folder / "campaign.toml"
    path.write_text(toml_text(data))
    return path


def _bench(folder: Path, speeds_hz: list[float], torque_sensor: bool = False, **kinds) -> tuple[Path, dict]:
    folder.mkdir(parents=True, exist_ok=True)
    simulate_bench(load_config(_config(folder, speeds_hz, **kinds)), folder / "bench", torque_sensor=torque_sensor)
    return folder / "bench", json.loads((folder / "bench" / "truth.json").read_text())


@pytest.fixture(scope="module")
def two_speeds(tmp_path_factory) -> tuple[Path, dict]:
    return _bench(tmp_path_factory.mktemp("two"), [1.0, 1.5])


@pytest.fixture(scope="module")
def identified(two_speeds) -> tuple[IdentificationResult, dict]:
    folder, truth = two_speeds
    return identify_bench(read_bench(folder)), truth


@pytest.fixture(scope="module")
def perfect(tmp_path_factory) -> tuple[IdentificationResult, dict]:
    folder, truth = _bench(tmp_path_factory.mktemp("perfect"), [1.0, 1.5], perfect=True)
    return identify_bench(read_bench(folder)), truth


@pytest.fixture(scope="module")
def pure_sine(tmp_path_factory) -> tuple[Bench, dict]:
    folder, truth = _bench(tmp_path_factory.mktemp("sine"), [1.0, 1.5], torque_sensor=True, perfect=True,
                           pure_sine=True)
    return read_bench(folder), truth


@pytest.fixture(scope="module")
def one_speed(tmp_path_factory) -> tuple[IdentificationResult, dict]:
    folder, truth = _bench(tmp_path_factory.mktemp("one"), [1.25])
    return identify_bench(read_bench(folder)), truth


# ---------------------------------------------------------------- the bench format


def test_a_bench_without_torque_column_reads_and_writes_in_csv_and_parquet(two_speeds, tmp_path):
    folder, _ = two_speeds
    assert "torque_sensor = false" in (folder / "bench.toml").read_text()
    assert "torque," not in (folder / "trial_01.csv").read_text().splitlines()[0] + ","
    bench = read_bench(folder)
    assert not bench.motor.torque_sensor and bench.motor.timer_resolution_s == 1e-6
    assert all(t.torque_nm is None and t.torque_true_nm is not None for t in bench.trials)
    parquet = convert_bench(folder, tmp_path / "parquet", ".parquet")
    back = read_bench(tmp_path / "parquet")
    assert back.motor == bench.motor == parquet.motor
    for a, b in zip(bench.trials, back.trials):
        assert b.torque_nm is None
        np.testing.assert_array_equal(a.time_s, b.time_s)
    convert_bench(tmp_path / "parquet", tmp_path / "csv", ".csv")
    assert (tmp_path / "csv" / "trial_01.csv").read_bytes() == (folder / "trial_01.csv").read_bytes()


def _edited(folder: Path, tmp_path: Path, old: str, new: str) -> Path:
    copy = tmp_path / "edited"
    convert_bench(folder, copy, ".csv")
    text = (copy / "bench.toml").read_text()
    assert old in text
    (copy / "bench.toml").write_text(text.replace(old, new))
    return copy


@pytest.mark.parametrize(("old", "new", "message"), [
    ("torque_sensor = false\n", "", r"trial_01\.csv: line 1: missing column 'torque' \(a bench without a torque "
                                    r"sensor says \[motor\] torque_sensor = false\)$"),
    ("torque_sensor = false", "torque_sensor = 0", r"\[motor\] torque_sensor: expected true or false, got 0$"),
    ("timer_resolution_s = 1e-06", "timer_resolution_s = 0.5",
     r"\[motor\] timer_resolution_s: invalid value 0\.5 \(time-stamp quantum, s, within \(0, 1e-3\]\)$"),
])
def test_a_declaration_at_odds_with_the_files_is_one_line(two_speeds, tmp_path, old, new, message):
    with pytest.raises(BenchFormatError, match=message):
        read_bench(_edited(two_speeds[0], tmp_path, old, new))


def test_a_torque_column_on_a_bench_without_sensor_is_one_line(tmp_path):
    folder, _ = _bench(tmp_path / "sensor", [1.0, 1.5], torque_sensor=True)
    line = 'backemf_file = "backemf.csv"\n'
    copy = _edited(folder, tmp_path, line, line + "torque_sensor = false\n")
    with pytest.raises(BenchFormatError, match=r"trial_01\.csv: line 1: has a 'torque' column, but bench\.toml says "
                                               r"\[motor\] torque_sensor = false$"):
        read_bench(copy)
    # the same bench in memory: its trials are checked against the declaration before any reduction
    bench = read_bench(folder)
    trials = tuple(dataclasses.replace(t, torque_nm=None) for t in bench.trials)
    with pytest.raises(IdentificationError, match="missing column 'torque'"):
        identify_bench(dataclasses.replace(bench, trials=trials))
    assert identify_bench(bench, torque_source=TorqueSource.ENCODER).torque_source is TorqueSource.ENCODER


def test_the_timer_resolution_is_read_off_the_stamps_when_not_stated(two_speeds):
    bench = read_bench(two_speeds[0])
    assert timer_resolution_s(bench) == 1e-6
    unstated = dataclasses.replace(bench, motor=dataclasses.replace(bench.motor, timer_resolution_s=None))
    assert timer_resolution_s(unstated) == pytest.approx(1e-6, rel=1e-6)


# ---------------------------------------------------------------- the identification


def test_the_encoder_derived_torque_recovers_the_sensors_and_the_cogging(identified):
    result, truth = identified
    assert result.torque_source is TorqueSource.ENCODER
    assert abs(result.epsilon / truth["epsilon"] - 1.0) < 0.02
    assert np.abs(result.alpha - truth["alpha"]).max() < 0.005
    assert np.abs(result.beta - truth["beta"]).max() < 0.03
    true = np.asarray(truth["cogging"]["torque"])
    assert np.sqrt(np.mean((result.cogging_nm - true) ** 2) / np.mean(true**2)) < 0.03


def test_what_needs_a_torque_sensor_is_none_with_its_reason(identified):
    result, _ = identified
    for name in ("delta", "delta_epsilon", "inertia_estimate"):
        assert getattr(result, name) is None
        assert all(getattr(m, name) is None for m in result.methods.values())
    text = "\n".join(result.messages)
    assert "torque-sensor gain (ch. 3): not identified" in text and "Coulomb friction: not identified" in text
    assert result.diagnostics["joint"]["torque_sensor_highpass_hz"] is None
    assert result.diagnostics["encoder"]["inertia_given"] == pytest.approx(0.01056)
    assert result.calibration.torque_gain == 0.908


def test_the_encoder_error_is_recovered_from_two_speeds(identified):
    """The once-per-revolution amplitude within 10 %; the line errors, where inertia dominates the mechanics
    (h J Omega >> b, here h >= 50), within twice their standard error. Below, the brake makes the apparent
    torque m_h e_h ~ -j h Delta tau_0 e_h scale with the mean torque, not the speed (docs/identification.md)."""
    result, truth = identified
    encoder = truth["encoder_error"]
    assert encoder["eccentricity_counts"] == pytest.approx(ECCENTRICITY_COUNTS, rel=0.05)
    assert abs(result.encoder_eccentricity_counts / encoder["eccentricity_counts"] - 1.0) < 0.10
    assert result.encoder_error_counts.shape == (1024,)
    error = harmonic_amplitudes(result.encoder_error_counts - encoder["error_counts"])[50:]
    variance = result.details.encoder.encoder_error_variance_counts2[50:]
    assert np.sqrt(np.mean(np.abs(error) ** 2)) < 2.0 * np.sqrt(np.mean(variance))
    assert np.sqrt(np.mean(np.abs(error) ** 2)) < 0.1 * np.sqrt(np.mean(np.abs(harmonic_amplitudes(
        np.asarray(encoder["error_counts"]))[50:]) ** 2))


def _left_pp_nm(line_errors_counts: np.ndarray, torque_nm: float, speed_hz: float) -> float:
    """Eq. 4's apparent torque of an error left in the stamps at a campaign point, peak to peak, N m."""
    speed = 2.0 * np.pi * speed_hz
    return float(np.ptp(encoder_error_torque_nm(line_errors_counts, RIPPLE_HARMONICS, 0.01056, speed,
                                                torque_nm / speed)))


def test_a_perfect_encoder_gets_no_encoder_error(perfect):
    """The estimate's noise and misfit stand out nowhere: 0 is applied (the bound: exactly 0), so a campaign's
    trial at 1 N m and 1.5 Hz keeps none of it; applied as estimated it would leave several % pp there."""
    result, _ = perfect
    assert result.encoder_eccentricity_counts == 0.0 and result.encoder_eccentricity_phase_rad is None
    assert result.encoder_line_rms_counts == 0.0 and not np.any(result.encoder_error_counts)
    assert 0.0 < result.encoder_eccentricity_std_counts < 0.02
    assert any(m.startswith("encoder error: 0 - no harmonic stands out") for m in result.messages)
    assert _left_pp_nm(result.encoder_error_counts, 1.0, 1.5) < 5e-4
    estimated = encoder_error_table(result.details.encoder.estimated_error_counts, 1024)
    assert _left_pp_nm(estimated, 1.0, 1.5) > 0.01
    assert abs(result.epsilon / perfect[1]["epsilon"] - 1.0) < 0.02


def test_the_encoder_error_applied_keeps_a_real_error(identified):
    """On the bench with 0.05 counts eccentricity and 0.01 counts per line, what is applied keeps the line
    RMS within 10 % and takes out 90 % of the error's apparent torque at 1 N m and 1.5 Hz."""
    result, truth = identified
    assert abs(result.encoder_line_rms_counts / truth["encoder_error"]["line_rms_counts"] - 1.0) < 0.10
    true_error = np.asarray(truth["encoder_error"]["error_counts"])
    assert _left_pp_nm(result.encoder_error_counts - true_error, 1.0, 1.5) < 0.1 * _left_pp_nm(true_error, 1.0, 1.5)


@pytest.mark.parametrize("source", [TorqueSource.ENCODER, TorqueSource.SENSOR])
def test_a_pure_sine_backemf_leaves_the_common_offset_not_identified(pure_sine, source):
    """sum_p K_p = 0: an offset common to the phases makes no torque. Both paths say so and fit the
    differential offsets (within 0.03 A), eps (2 %) and alpha (0.005); beta's mean is 0 by constraint."""
    bench, truth = pure_sine
    result = identify_bench(bench, torque_source=source)
    assert any(m.startswith("current offsets: the common offset (mean of beta over the phases) not identified - "
                            "the back-EMFs sum to zero") for m in result.messages)
    assert not result.details.joint.common_offset_identified
    true_beta = np.asarray(truth["beta"])
    assert true_beta.mean() == pytest.approx(0.2)
    assert abs(result.beta.mean()) < 1e-9
    assert np.abs(result.beta - (true_beta - true_beta.mean())).max() < 0.03
    assert np.all(result.methods["joint"].beta_std < 0.03)
    assert abs(result.epsilon / truth["epsilon"] - 1.0) < 0.02
    assert np.abs(result.alpha - truth["alpha"]).max() < 0.005


def test_the_common_offset_is_identified_where_the_backemfs_do_not_sum_to_zero(identified):
    result, _ = identified
    assert result.details.joint.common_offset_identified
    assert not any(m.startswith("current offsets:") for m in result.messages)


def _fit(tables: BenchTables) -> dict[str, np.ndarray]:
    """The joint fit's estimates and standard errors on ``tables``, by name."""
    joint = fit_joint(tables, DEFAULT_LOOP)
    return {"theta": joint.theta, "theta_std": joint.theta_std, "beta": joint.beta_star_a,
            "beta_std": joint.beta_star_std, "saturation": joint.saturation_per_a2,
            "saturation_std": joint.saturation_std, "loop": joint.loop.time_constant_s, "delay": joint.loop.delay_s,
            "loop_std": joint.loop_std, "winding": joint.winding_time_constant_s,
            "cogging": np.array([joint.position_table[h] for h in joint.cogging_harmonics])}


def test_the_encoder_fit_does_not_move_under_a_one_ulp_change_of_the_backemf(identified):
    """Without a sensor the high-pass and the torque's delay have no effect: left in the fit, the solver wandered
    along them and a one-ulp change of K moved eps's standard error by 1e-4 and the loop's delay by 3e-4."""
    tables = identified[0].details.tables
    base = _fit(tables)
    nudged = _fit(dataclasses.replace(tables, backemf_nm_per_a=tables.backemf_nm_per_a * (1.0 + 2.0**-52)))
    for name, value in base.items():
        np.testing.assert_allclose(nudged[name], value, rtol=1e-8, atol=0.0, err_msg=name)


def test_the_encoder_fit_holds_no_sensor_parameter(identified):
    """The sensor's corner and delay: not fitted, not in the covariance, not reported (None)."""
    joint = identified[0].details.joint
    assert not {"highpass_hz", "torque_delay_s"} & set(joint.parameter_names)
    assert set(NONLINEAR) - {"highpass_hz", "torque_delay_s"} <= set(joint.parameter_names)
    assert joint.covariance.shape == joint.bound_covariance.shape == (len(joint.parameter_names),) * 2
    assert np.all(np.diag(joint.bound_covariance) > 0.0)
    assert joint.highpass_hz is None and joint.highpass_std is None and joint.torque_delay_s is None
    np.testing.assert_array_equal(joint.sensor_response(np.arange(1, 9), 1.0), 1.0)


def test_the_encoder_fit_with_the_ideal_loop_has_the_linear_parameters_alone(identified):
    """The ideal loop leaves no nonlinear parameter to fit on the encoder-derived torque: the linear fit, its
    covariance over LINEAR."""
    tables = identified[0].details.tables
    problem = _JointProblem(tables, harmonic_sets(tables))
    _, phi, active, saturation, x, rest = _fit_nonlinear(problem, CurrentLoop(),
                                                        SENSOR_PARAMETERS & problem.identifiable)
    assert not active.any() and phi[4] == phi[6] == 0.0
    covariance, _, names, _, _ = _covariance(problem, phi, active, saturation, x, rest)
    assert names == LINEAR and covariance.shape == (len(LINEAR), len(LINEAR))
    assert np.all(np.diag(covariance) > 0.0)


def test_one_speed_leaves_the_encoder_error_not_identified(one_speed):
    result, _ = one_speed
    assert result.encoder_error_counts is None and result.encoder_eccentricity_counts is None
    assert any(m.startswith("encoder error: not identified - every trial runs at 1.25 Hz") for m in result.messages)
    assert result.epsilon is not None


def test_the_result_json_holds_the_encoder_error(identified):
    result, _ = identified
    data = json.loads(json.dumps(result.to_json(), allow_nan=False))
    assert data["torque_source"] == "encoder" and data["torque_sensor_gain"] is None
    back = IdentificationResult.from_json(data)
    np.testing.assert_allclose(back.encoder_error_counts, result.encoder_error_counts)
    assert back.encoder_eccentricity_counts == result.encoder_eccentricity_counts
    assert back.torque_source is TorqueSource.ENCODER


def test_a_sensor_source_on_a_bench_without_one_is_refused(two_speeds):
    with pytest.raises(IdentificationError, match="torque source 'sensor': the bench has no torque sensor"):
        identify_bench(read_bench(two_speeds[0]), torque_source=TorqueSource.SENSOR)


# ---------------------------------------------------------------- the estimator's helpers


def test_with_viscous_is_the_spectrum_at_that_brake():
    rng = np.random.default_rng(5)
    cpr, speed_hz = 256, 1.0
    theta = 2.0 * np.pi * np.arange(4 * cpr) / cpr
    time_s = (theta + 0.01 * np.sin(3 * theta)) / (2.0 * np.pi * speed_hz) + rng.normal(0.0, 1e-7, theta.size)
    count = np.arange(theta.size)
    direct = EncoderTorqueSpectrum.of(count, time_s, cpr, 20, 0.01, 1e-6, 0.3)
    moved = with_viscous(EncoderTorqueSpectrum.of(count, time_s, cpr, 20, 0.01, 1e-6, 0.0), 0.3)
    for name in ("harmonics_nm", "variance_nm2", "quantisation_variance_nm2"):
        np.testing.assert_allclose(getattr(moved, name), getattr(direct, name), rtol=1e-12, atol=1e-18)


def test_the_significance_rule_keeps_a_real_error_and_drops_noise():
    """Per octave: pure noise gives 0; a white error 10x its noise in power is kept within 10 %; one harmonic
    far out of its noise in an octave of noise (a misfit the model missed) does not carry the octave."""
    rng = np.random.default_rng(7)
    size = 512
    variance = np.full(size, 1e-8)
    noise = np.sqrt(variance / 2.0) * (rng.standard_normal(size) + 1j * rng.standard_normal(size))
    assert not np.any(significant_encoder_error(noise, variance))
    error = np.sqrt(10 * variance / 2.0) * (rng.standard_normal(size) + 1j * rng.standard_normal(size))
    kept = significant_encoder_error(error + noise, variance)
    assert np.sqrt(np.sum(np.abs(kept[1:] - error[1:]) ** 2) / np.sum(np.abs(error[1:]) ** 2)) < 0.4
    assert np.sum(np.abs(kept[1:]) ** 2) == pytest.approx(np.sum(np.abs(error[1:]) ** 2), rel=0.2)
    outlier = noise.copy()
    outlier[48] = 100.0 * np.sqrt(variance[48])
    assert not np.any(significant_encoder_error(outlier, variance))
    eccentric = noise.copy()
    eccentric[1] = 10.0 * np.sqrt(variance[1])
    assert abs(significant_encoder_error(eccentric, variance)[1]) == pytest.approx(abs(eccentric[1]), rel=0.02)


def _spectrum(speed_hz: float, harmonics_nm: np.ndarray, variance_nm2: np.ndarray) -> EncoderTorqueSpectrum:
    size = harmonics_nm.size
    return EncoderTorqueSpectrum(harmonics_nm, variance_nm2, variance_nm2, np.zeros(size, complex), np.zeros(size),
                                 speed_hz, 8, 256, 0.01, 1.0 / (2.0 * np.pi * speed_hz), 1e-6)


def test_the_separation_inflates_its_errors_by_the_trials_misfit():
    """Trials that differ by their noise alone: chi2 about 1, no inflation; a trial-dependent ripple three
    times the noise in the octave 32-63: the octave's variances grow about 1 + 9 (chi2 of the residual)."""
    rng = np.random.default_rng(3)
    size, speeds = 100, np.array([0.5, 0.7, 0.9, 1.1, 1.3, 1.5])
    variance = np.full(size, 1e-6)
    shared = 1e-3 * np.exp(1j * rng.uniform(0, 2 * np.pi, size))

    def spectra(misfit: float):
        out = []
        for speed in speeds:
            noise = np.sqrt(variance / 2.0) * (rng.standard_normal(size) + 1j * rng.standard_normal(size))
            extra = np.zeros(size, complex)
            extra[32:64] = misfit * np.sqrt(variance[32:64]) * np.exp(1j * rng.uniform(0, 2 * np.pi, 32))
            out.append(_spectrum(speed, shared + noise + extra, variance))
        return out

    clean = separate_encoder_error(spectra(0.0))
    assert np.mean(clean.misfit_chi2[1:]) == pytest.approx(1.0, abs=0.15)
    off = separate_encoder_error(spectra(3.0))
    inflation = off.encoder_error_variance_counts2[1:] / clean.encoder_error_variance_counts2[1:]
    assert np.median(inflation[31:63]) > 5.0 and np.median(inflation[69:]) == pytest.approx(1.0, abs=0.3)


def test_the_summary_gives_the_once_per_revolution_sine_and_the_rest():
    c = np.arange(512)
    rest = 0.01 * np.random.default_rng(1).standard_normal(512)
    rest -= harmonic_amplitudes(rest)[1].real * np.cos(2 * np.pi * c / 512) \
        - harmonic_amplitudes(rest)[1].imag * np.sin(2 * np.pi * c / 512) + rest.mean()
    errors = 0.05 * np.sin(2 * np.pi * c / 512 - 1.2) + rest
    amplitude, std, phase, line_rms = encoder_error_summary(harmonic_amplitudes(errors)[:256])
    assert amplitude == pytest.approx(0.05) and phase == pytest.approx(-1.2) and std == 0.0
    nyquist = harmonic_amplitudes(rest)[256].real
    assert line_rms == pytest.approx(np.sqrt(np.mean(rest**2) - nyquist**2), rel=1e-9)


# ---------------------------------------------------------------- the commands


def test_the_identify_table_shows_the_encoder_lines_within_80_columns(identified):
    result, truth = identified
    console = Console(width=80, file=io.StringIO(), color_system=None)
    console.print(estimates_table(result, IdentificationResult.from_json(truth)))
    lines = console.file.getvalue().splitlines()
    assert max(len(line) for line in lines) <= 80 and not any("…" in line for line in lines)
    text = "\n".join(lines)
    assert "enc. 1x (cnt)" in text and "enc. lines (cnt)" in text
    assert [line for line in lines if line.startswith("│ delta ")][0].count("not identified") == 3


def test_simulate_without_torque_sensor_then_identify_by_command(tmp_path):
    config = _config(tmp_path, [1.0, 1.5])
    runner = CliRunner()
    out = runner.invoke(main, ["simulate", str(config), "--out", str(tmp_path / "b"), "--no-torque-sensor",
                               "--revolutions", "4"])
    assert out.exit_code == 0, out.output
    out = runner.invoke(main, ["identify", str(tmp_path / "b"), "--output", str(tmp_path / "r.json"),
                               "--torque-source", "sensor"])
    assert out.exit_code == 2 and out.output.splitlines()[-1].startswith("error: torque source 'sensor': the bench "
                                                                         "has no torque sensor")
    out = runner.invoke(main, ["identify", str(tmp_path / "b"), "--output", str(tmp_path / "r.json")],
                        terminal_width=80)
    assert out.exit_code == 0, out.output
    assert "enc. 1x (cnt)" in out.output and json.loads((tmp_path / "r.json").read_text())["encoder_error"]
