"""The rolling identification (issue 35, items 2 and 3): on simulated logs with their truth, the position torque is
never worse than the q current averaged by position and its stated standard error covers its true error; the
harmonics a sparse log resolves are chosen, not refused; a drive's report filter on the logged current is found;
the inertial gain of sparse rows is divided out exactly."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import SEED_CONFIG

import ilcpmac.cli.identify  # noqa: F401  (registers the command on main)
from ilcpmac import api
from ilcpmac.bench.importer import read_mapping, write_rolling_folder
from ilcpmac.bench.rolling import Rolling, RollingData, RollingSettings, read_rolling
from ilcpmac.cli import main
from ilcpmac.config import BackEmf
from ilcpmac.core.errors import IdentificationError
from ilcpmac.core.records import IdentificationResult, MotorInfo
from ilcpmac.identify.rolling import RollingEstimate, estimate_rolling
from ilcpmac.model.tables import backemf_table


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


#: a small actuator's changes to the seed config: 7 pole pairs, 12 slots (cogging order 84), J 1e-4 kg m^2
ACTUATOR = {"bench": {"pole_pairs": 7, "slots": 12, "inertia_kgm2": 1e-4},
            "bench.backemf": {"amplitudes_nm_per_a": [0.05, 0.001, 0.0005, 0.0]},
            "simulator.cogging": {"amplitudes_nm": [0.02, 0.004]},
            "simulator.unexplained": {"orders": [7, 14, 28], "amplitudes_nm": [0.004, 0.003, 0.002]}}


def simulated(tmp_path: Path, current_filter_s: float = 0.0, config: Path = SEED_CONFIG, **options
              ) -> tuple[Path, Path, np.ndarray]:
    """A seed-bench drive log (``ilcpmac simulate --kind log``, 4 s at 0.5 Hz), its logged current through a
    first-order filter of ``current_filter_s`` when given (a drive's report filter, run on the current between
    the rows as well: linear there); (log, mapping, true position torque minus its mean)."""
    sim = tmp_path / "sim"
    api.simulate_log(config, sim, seed=3, duration_s=options.pop("duration_s", 4.0), **options)
    log = sim / "drive_log.csv"
    if current_filter_s:
        header, *lines = log.read_text().splitlines()
        rows = np.array([[float(v) for v in line.split(",")] for line in lines])
        step = np.diff(rows[:, 0])
        a = np.exp(-step / current_filter_s)
        current = rows[:, 2].copy()
        for k in range(1, rows.shape[0]):
            slope = (current[k] - current[k - 1]) / step[k - 1]
            rows[k, 2] = (a[k - 1] * rows[k - 1, 2] + current[k] - a[k - 1] * current[k - 1]
                          - slope * current_filter_s * (1 - a[k - 1]))
        log.write_text(header + "\n" + "\n".join(",".join(f"{v:.9g}" for v in row) for row in rows) + "\n")
    tau = np.asarray(json.loads((sim / "truth.json").read_text())["position_torque"]["torque"])
    return log, sim / "mapping.toml", tau - tau.mean()


def identified(log: Path, mapping: Path, out: Path, **log_keys) -> RollingEstimate:
    """The log imported as a rolling log ([log] kind = "rolling" and ``log_keys``) and identified."""
    parsed = read_mapping(mapping)
    parsed = dataclasses.replace(parsed, layout=dataclasses.replace(parsed.layout, kind="rolling", **log_keys))
    write_rolling_folder([log], parsed, out)
    return estimate_rolling(read_rolling(out))


def in_band(tau: np.ndarray, top: int) -> np.ndarray:
    """The truth over harmonics 1..top (what the identification estimates)."""
    spectrum = np.fft.rfft(tau)
    spectrum[top + 1:] = 0.0
    return np.fft.irfft(spectrum, n=tau.size)


@pytest.mark.parametrize("bits, of_baseline", [(20, 0.05), (12, 0.5)])
def test_a_speed_loop_log_beats_the_currents_averaged_by_position_within_its_stated_error(tmp_path, bits,
                                                                                         of_baseline):
    log, mapping, tau = simulated(tmp_path, rate_hz=1000.0, encoder_bits=bits)
    e = identified(log, mapping, tmp_path / "rolling")
    ours, base = e.table_nm(), e.table_nm(e.baseline_nm)
    truth = in_band(tau, e.harmonics_nm.size)
    assert np.corrcoef(ours, tau)[0, 1] > np.corrcoef(base, tau)[0, 1] + 0.3
    assert rms(ours - truth) < of_baseline * rms(base - truth)
    assert rms(ours - truth) <= 2.0 * rms(e.table_std_nm())
    # a 12-bit position read once per row repeats its quantisation with position: a bias, stated
    assert (np.max(e.encoder_bias_nm) > 1e-2) == (bits == 12)


def test_a_sparse_log_resolves_the_orders_below_its_nyquist_order_and_is_not_refused(tmp_path):
    log, mapping, tau = simulated(tmp_path, rate_hz=60.0, encoder_bits=16, duration_s=10.0)
    e = identified(log, mapping, tmp_path / "rolling")
    assert e.harmonics_nm.size == 58 == e.nyquist_order  # 120 rows per revolution: orders below 0.98 x 60
    said = " ".join(e.messages)
    assert "harmonics 1..58 resolved (of 96)" in said and "96 -> 24" in said  # the second cogging order folds
    assert not e.estimated[22:25].any() and e.harmonics_nm[23] == 0
    ours, base = e.table_nm(), e.table_nm(e.baseline_nm)
    assert np.corrcoef(ours, tau)[0, 1] > np.corrcoef(base, tau)[0, 1] + 0.3


def test_what_folds_from_above_the_nyquist_order_of_sparse_rows_is_in_the_standard_errors(tmp_path, write_config):
    """A small actuator logged at 100 Hz at 0.5 Hz: its cogging's second order (168) and the currents above
    order 100 fold onto the orders below; the stated errors hold them."""
    log, mapping, tau = simulated(tmp_path, config=write_config(ACTUATOR), rate_hz=100.0, encoder_bits=14,
                                  duration_s=10.0)
    e = identified(log, mapping, tmp_path / "rolling")
    truth = in_band(tau, e.harmonics_nm.size)
    assert e.folded_nm2 > 0 and "folds onto every harmonic" in " ".join(e.messages)
    assert rms(e.table_nm() - truth) <= 2.0 * rms(e.table_std_nm())
    assert np.corrcoef(e.table_nm(), tau)[0, 1] > np.corrcoef(e.table_nm(e.baseline_nm), tau)[0, 1] + 0.5


def test_a_drives_report_filter_on_the_logged_current_is_found_and_undone(tmp_path):
    log, mapping, tau = simulated(tmp_path, current_filter_s=0.05, rate_hz=1000.0, encoder_bits=20)
    found = identified(log, mapping, tmp_path / "found")
    ignored = identified(log, mapping, tmp_path / "ignored", current_filter_s=0.0)
    assert found.filter_source == "fitted" and found.filter_s == pytest.approx(0.05, rel=0.3)
    assert ignored.filter_source == "none"
    truth = in_band(tau, found.harmonics_nm.size)
    assert rms(found.table_nm() - truth) < 0.2 * rms(ignored.table_nm() - truth)
    unfiltered = identified(*simulated(tmp_path / "plain", rate_hz=1000.0, encoder_bits=20)[:2], tmp_path / "plain")
    assert unfiltered.filter_source == "none" and unfiltered.filter_s == 0.0


@pytest.mark.parametrize("rate_hz, order", [(200.0, 168), (1000.0, 84)])
def test_the_inertial_gain_of_sparse_rows_is_divided_out(rate_hz, order):
    """A synthetic steady log whose balance holds exactly: the position torque comes out exact near the rows'
    Nyquist order, where the currents averaged by position are off by the inertial torque."""
    cpr, inertia, k_t, speed_hz = 4096, 1e-4, 0.075, 0.5
    motor = MotorInfo(7, 12, cpr, inertia, torque_sensor=False, inertia_uncertainty=0.01)
    backemf = backemf_table(motor, BackEmf((1,), (2 * k_t / 3,), (0.0,), (0.0, 0.0, 0.0)), cpr)
    t = np.arange(int(10 * rate_hz)) / rate_hz
    omega = 2 * np.pi * speed_hz
    theta = omega * t + 2e-4 * np.sin(order * omega * t)
    acceleration = -2e-4 * (order * omega) ** 2 * np.sin(order * omega * t)
    tau = 0.004 * np.sin(order * theta)
    current = (inertia * acceleration - tau + 0.2) / k_t
    data = RollingData(t, theta / (2 * np.pi) * cpr, np.ones(t.size, np.int64), current, None, None)
    e = estimate_rolling(Rolling(Path("synthetic"), motor, backemf, None, RollingSettings(current_filter_s=0.0), data))
    assert e.corrected_nm[order - 1] == pytest.approx(-0.004j, abs=2e-6)
    assert abs(e.baseline_nm[order - 1] + 0.004j) > 1e-3
    assert abs(e.harmonics_nm[order - 1] + 0.004j) <= 2.0 * math.sqrt(e.variance_nm2[order - 1])


def test_a_current_loop_log_gets_its_position_torque_from_the_acceleration_alone(tmp_path):
    log, mapping, tau = simulated(tmp_path, rate_hz=1000.0, encoder_bits=20, loop="current")
    e = identified(log, mapping, tmp_path / "rolling")
    truth = in_band(tau, e.harmonics_nm.size)
    assert rms(e.table_nm() - truth) < 0.05 * np.ptp(tau) < rms(e.table_nm(e.baseline_nm) - truth)


def test_api_and_cli_identify_a_rolling_folder(tmp_path):
    log, mapping, _ = simulated(tmp_path, rate_hz=1000.0, encoder_bits=20, duration_s=3.0)
    identified(log, mapping, tmp_path / "rolling")
    result = api.identify(tmp_path / "rolling", output=tmp_path / "result.json")
    assert isinstance(result, IdentificationResult) and result.position_torque_nm is not None
    back = IdentificationResult.from_json(json.loads((tmp_path / "result.json").read_text()))
    np.testing.assert_allclose(back.position_torque_nm, result.position_torque_nm, atol=1e-12)
    assert back.diagnostics["method"] == "rolling" and set(back.methods) == {"rolling", "baseline"}
    for option in (["--torque-source", "encoder"], ["--plots", str(tmp_path / "plots")]):
        refused = CliRunner().invoke(main, ["identify", str(tmp_path / "rolling"), "--output",
                                            str(tmp_path / "cli.json"), *option])
        assert refused.exit_code == 2 and "not for a rolling folder" in refused.output
        assert "Traceback" not in refused.output


def test_a_log_that_does_not_turn_is_one_line():
    motor = MotorInfo(8, 48, 1024, 0.01, torque_sensor=False)
    t = np.arange(2000) / 1000.0
    data = RollingData(t, 3.0 * np.sin(t), np.ones(t.size, np.int64), 1.0 + 0.1 * np.cos(9 * t), None, None)
    backemf = np.zeros((1024, 3))
    backemf[:, 0] = 0.2
    with pytest.raises(IdentificationError, match=r"moves .* revolutions .*needs a mean speed") as e:
        estimate_rolling(Rolling(Path("still"), motor, backemf, None, RollingSettings(), data))
    assert "\n" not in str(e.value) and math.isfinite(len(str(e.value)))
