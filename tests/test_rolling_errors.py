"""The rolling identification's stated errors and its choice against the baseline (issue 35): the stated standard
error covers the true one, and the position torque is never worse than the q current averaged by position, on
synthetic logs whose noise is known and on a sample of simulated logs (benchmarks/rolling_logs.py's grid); a
14-bit encoder at 1 kHz gives the cogging within 3 % where the rows allow it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from test_rolling_identify import identified, in_band, rms

from ilcpmac import api
from ilcpmac.bench.rolling import Rolling, RollingData, RollingSettings
from ilcpmac.config import BackEmf
from ilcpmac.core.records import MotorInfo
from ilcpmac.identify.rolling import RollingEstimate, estimate_rolling
from ilcpmac.model.tables import backemf_table

ROOT = Path(__file__).resolve().parents[1]
MOTORS = {"seed": ROOT / "configs" / "seed-bench.toml",
          "actuator": ROOT / "benchmarks" / "motors" / "small-actuator.toml",
          "servo": ROOT / "benchmarks" / "motors" / "large-servo.toml"}
#: benchmarks/rolling_logs.py's 14-bit magnetic encoder
MAGNETIC = {"encoder_bits": 14, "encoder_eccentricity_counts": 0.1, "encoder_harmonics": "2:0.3,4:0.1:0.5"}

CPR, INERTIA, K_T = 4096, 1e-2, 0.075


def synthetic(time_s: np.ndarray, read_s: np.ndarray, position_noise_rad: float, seed: int,
              torque_nm: float = 0.004, speed_hz: float = 0.5) -> tuple[Rolling, np.ndarray]:
    """A steady log of a 7-pole-pair, 12-slot motor (J 0.01 kg m^2 given at 1 %) whose balance holds exactly: a
    position torque ``torque_nm`` at order 3 and its ripple, positions read at ``read_s`` (with white noise of
    ``position_noise_rad``) and stamped ``time_s``; the folder and the true harmonics (1..10)."""
    motor = MotorInfo(7, 12, CPR, INERTIA, torque_sensor=False, inertia_uncertainty=0.01)
    backemf = backemf_table(motor, BackEmf((1,), (2 * K_T / 3,), (0.0,), (0.0, 0.0, 0.0)), CPR)
    omega = 2 * np.pi * speed_hz
    ripple = torque_nm / (INERTIA * (3 * omega) ** 2)  # the order-3 torque's speed ripple, the current held
    theta = omega * read_s - ripple * np.sin(3 * omega * read_s)
    current = np.full(time_s.size, 0.2 / K_T)  # the position torque all in the acceleration: a current loop's
    rng = np.random.default_rng(seed)
    logged = theta + position_noise_rad * rng.standard_normal(theta.size)
    data = RollingData(time_s, logged / (2 * np.pi) * CPR, np.ones(time_s.size, np.int64), current, None, None)
    truth = np.zeros(10, complex)
    truth[2] = -1j * torque_nm  # tau = torque_nm sin(3 theta): the rotor's ripple above is J a = tau
    return Rolling(Path("synthetic"), motor, backemf, None, RollingSettings(current_filter_s=0.0), data), truth


def test_the_stated_error_of_a_correction_holds_the_noise_the_inertial_gain_divides_out():
    """Sparse rows (21 a revolution, the cogging orders folding onto 0): A_b passes the orders near their Nyquist
    order at half their gain or less, which eq. (3) divides out of the motion and, with it, out of A_b's noise:
    the stated errors say so."""
    t = np.arange(1260) / 10.5
    errors, stated = [], []
    for seed in range(12):
        rolling, truth = synthetic(t, t, 2e-4, seed)
        e = estimate_rolling(rolling)
        top = e.harmonics_nm.size
        errors.append(np.abs(e.corrected_nm - truth[:top]) ** 2)
        stated.append(e.correction_variance_nm2)
    ratio = np.sqrt(np.mean(errors, axis=0) / np.mean(stated, axis=0))
    near = np.arange(1, ratio.size + 1) >= 6  # g_h < 0.7
    assert np.all((ratio[near] > 0.6) & (ratio[near] < 1.4)), ratio


def test_a_correction_of_noise_alone_is_not_taken():
    """A log without a position torque, its positions noisy: every correction is noise, and none is taken; the
    result is the baseline, said so."""
    t = np.arange(1260) / 10.5
    rolling, _ = synthetic(t, t, 2e-3, 0, torque_nm=0.0)
    e = estimate_rolling(rolling)
    assert not np.any(e.weight > 0) and np.array_equal(e.table_nm(), e.table_nm(e.baseline_nm))
    assert "the result is the baseline's" in " ".join(e.messages)


def test_stamps_even_in_time_do_not_hide_a_hosts_jitter_from_the_inertia():
    """A host stamps its requests evenly but reads the positions 3 ms either side: the positions' noise about
    their stamps is the jitter's, not the stamps' quantum (0), and J stays the given one: the data's would be
    pulled towards 0 by that noise."""
    t = np.arange(2400) / 100.0
    rng = np.random.default_rng(5)
    rolling, truth = synthetic(t, t + rng.uniform(-3e-3, 3e-3, t.size), 0.0, 0)
    e = estimate_rolling(rolling)
    assert e.inertia_kgm2 == pytest.approx(INERTIA, rel=0.03)
    assert abs(e.harmonics_nm[2] - truth[2]) <= 2.0 * np.sqrt(e.variance_nm2[2])


def simulated(motor: str, tmp_path: Path, **options) -> tuple[RollingEstimate, np.ndarray, np.ndarray]:
    """A simulated log of ``motor`` (10 s, seed 1) imported as a rolling log and identified; the estimate, the
    true position torque and the true cogging (their means removed)."""
    sim = tmp_path / "sim"
    api.simulate_log(MOTORS[motor], sim, seed=1, duration_s=10.0, **options)
    e = identified(sim / "drive_log.csv", sim / "mapping.toml", tmp_path / "rolling")
    truth = json.loads((sim / "truth.json").read_text())
    tau, cogging = (np.asarray(truth[key]["torque"]) for key in ("position_torque", "cogging"))
    return e, tau - tau.mean(), cogging - cogging.mean()


@pytest.mark.parametrize("motor, options", [
    # a 14-bit position at 100 rows/s and 2 Hz: the currents' torque ripple at order 42 folds onto 8
    ("actuator", {"rate_hz": 100.0, "speed_hz": 2.0, "loop": "speed", **MAGNETIC}),
    ("actuator", {"rate_hz": 100.0, "speed_hz": 2.0, "loop": "position", "encoder_bits": 14}),
    # a 12-bit quantiser's sawtooth at 4096 mod 250 = 96, the second cogging order
    ("seed", {"rate_hz": 500.0, "speed_hz": 2.0, "loop": "position", "encoder_bits": 12}),
    # a 12-bit quantiser's error, scattered over the orders by a ripple below its quanta, at 6 Hz on 0.05 kg m^2
    ("servo", {"rate_hz": 1000.0, "speed_hz": 6.0, "loop": "speed", "encoder_bits": 12}),
    # 1 ms stamps on jittered reads at 6 Hz and 16 rows a revolution: every correction noise
    ("seed", {"rate_hz": 100.0, "speed_hz": 6.0, "loop": "speed", "encoder_bits": 20, "jitter_s": 1e-3,
              "stamp_s": 1e-3}),
    ("seed", {"rate_hz": 1000.0, "speed_hz": 0.5, "loop": "speed", "encoder_bits": 14, "jitter_s": 4e-4,
              "stamp_s": 1e-3}),
])
def test_the_stated_error_covers_and_ours_is_never_worse_than_the_baseline(tmp_path, motor, options):
    e, tau, _ = simulated(motor, tmp_path, **options)
    truth = in_band(tau, e.harmonics_nm.size)
    ours, base = e.table_nm(), e.table_nm(e.baseline_nm)
    assert rms(ours - truth) <= 2.0 * rms(e.table_std_nm())
    assert rms(ours - truth) <= rms(base - truth)


def test_a_14_bit_encoder_at_1_khz_gives_the_cogging_within_3_percent_at_1_hz(tmp_path):
    """Issue 35's target where the rows and the encoder allow it (benchmarks/rolling_logs.py, the floor: 1.9 % at
    1 Hz from the quantiser's error at orders 84 and 168; above 3 % from 2 Hz on, docs/rolling-logs.md)."""
    e, _, cogging = simulated("actuator", tmp_path, rate_hz=1000.0, speed_hz=1.0, loop="speed", **MAGNETIC)
    assert rms(e.table_nm(cogging_only=True) - cogging) < 0.03 * np.ptp(cogging)
