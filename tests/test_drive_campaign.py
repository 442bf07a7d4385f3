"""The drive campaign (campaign/drive.py, issue 36): [drive] settings errors name the key, the plan is refused
beyond the drive's limits and the motor time before any trial, the motor time stated is the trials', the learning
law converges on a drive whose k_q the campaign knows 10 % wrong, and nothing reaches the flash without
write_config. The drive is `EmulatedDrive` run directly by a test-only `DriveBackend` (no moteus library)."""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np
import pytest

from ilcpmac.backends.drive import DriveLimits, DriveTrial
from ilcpmac.bench.rolling import RollingData
from ilcpmac.campaign.drive import (
    DRIVE_RESULT_FILE,
    DriveSettings,
    drive_settings,
    floor_table,
    lagged_a,
    learned_table,
    run_drive_campaign,
    unapplied,
    zero_table,
)
from ilcpmac.config import CampaignConfig, load_config
from ilcpmac.core.errors import BackendError, ConfigError
from ilcpmac.core.records import BenchDescription, DriveTrialRequest, TrialData, TrialRequest
from ilcpmac.export import MOTEUS_FILE, MOTEUS_TABLE_SIZE, MoteusTable
from ilcpmac.model.tables import q_axis
from ilcpmac.sim.moteus_drive import DriveSpec, EmulatedDrive
from ilcpmac.sim.simulator import Simulator

ROOT = Path(__file__).resolve().parents[1]
ACTUATOR = ROOT / "benchmarks" / "motors" / "small-actuator.toml"
#: the host's polling: rows a second and the jitter of each poll's instant, s
ROW_RATE_HZ, JITTER_S = 1000.0, 2e-4
#: the inertia's relative standard uncertainty the description states (the estimate's prior on J)
INERTIA_UNCERTAINTY = 0.05
#: a stop command's watchdog: the drive stops by itself this long after the last command, s
WATCHDOG_S = 0.1


class EmulatedDriveBackend:
    """A `DriveBackend` that runs `EmulatedDrive` in process: the table uploaded with ``conf set``, a velocity
    command (position NaN) re-sent within its watchdog, the drive polled at ``row_rate_hz`` with ``jitter_s``, a
    stop command on every path; the description's back-EMF ``backemf_scale`` times the true one (the campaign's
    k_q that much wrong)."""

    max_parallel_trials = 1

    def __init__(self, config: CampaignConfig, spec: DriveSpec | None = None, backemf_scale: float = 1.0,
                 row_rate_hz: float = ROW_RATE_HZ, jitter_s: float = JITTER_S, seed: int = 1) -> None:
        model = config.simulated_model()
        spec = spec or DriveSpec()
        self.drive = EmulatedDrive(model, spec, seed)
        self.spec, self.row_rate_hz, self.jitter_s = spec, row_rate_hz, jitter_s
        motor = dataclasses.replace(model.motor_info(), log_rate_hz=row_rate_hz,
                                    inertia_uncertainty=INERTIA_UNCERTAINTY)
        self.description = BenchDescription(motor, backemf_scale * Simulator(model).backemf_counts,
                                            model.controller.calibration(), config.limits.bench_limits())
        self.requests: list[DriveTrialRequest] = []
        self.rng = np.random.default_rng(seed)

    def describe(self) -> BenchDescription:
        return self.description

    def drive_limits(self) -> DriveLimits:
        return DriveLimits(self.spec.max_current_a, self.spec.max_velocity_hz,
                           min(self.spec.fault_temperature_c, self.spec.motor_fault_temperature_c),
                           self.drive.config["servo.pid_dq_hz"])

    def _upload(self, request: DriveTrialRequest) -> None:
        self.drive.set_config("motor.cogging_dq_scale", request.table_scale_a)
        for k, value in enumerate(request.table_values.tolist()):
            self.drive.set_config(f"motor.cogging_dq_comp.{k}", value)

    def _run(self, seconds: float, speed_hz: float) -> None:
        end = self.drive.time_s + seconds
        while self.drive.time_s < end - 1e-12:
            self.drive.command_position(speed_hz, watchdog_timeout_s=WATCHDOG_S)
            self.drive.advance(min(WATCHDOG_S / 2, end - self.drive.time_s))

    def run_drive_trial(self, request: DriveTrialRequest) -> DriveTrial:
        self.requests.append(request)
        self._upload(request)
        try:
            self._run(request.settle_s, request.speed_hz)
            self.drive.truth_reset()
            rows = int(request.seconds * self.row_rate_hz)
            start = self.drive.time_s
            stamps = start + (np.arange(rows) + 0.5) / self.row_rate_hz
            stamps += self.rng.uniform(-self.jitter_s, self.jitter_s, rows)
            position, current, temperature = np.empty(rows), np.empty(rows), -math.inf
            for n, t in enumerate(stamps):
                if n % 20 == 0:
                    self.drive.command_position(request.speed_hz, watchdog_timeout_s=WATCHDOG_S)
                self.drive.advance(t - self.drive.time_s)
                status = self.drive.status()
                position[n], current[n] = status.encoder0_position_rev, status.q_current_a
                temperature = max(temperature, status.temperature_c)
            cpr = self.description.motor.counts_per_rev
            residual, tau = self.drive.truth(cpr)
        finally:
            self.drive.command_stop()
        data = RollingData(stamps - start, np.unwrap(position, period=1.0) * cpr, np.ones(rows, np.int64), current)
        return DriveTrial(request, data, rows, 0, temperature, residual, tau)

    def run_trial(self, request: TrialRequest) -> TrialData:
        raise BackendError("the emulated drive runs drive trials only")

    def store_table(self, request: DriveTrialRequest) -> None:
        self._upload(request)
        self.drive.write_flash()

    def close(self) -> None:
        pass


@pytest.fixture(scope="module")
def actuator() -> CampaignConfig:
    return load_config(ACTUATOR)


def with_drive(config: CampaignConfig, **drive) -> CampaignConfig:
    return dataclasses.replace(config, drive_options=drive)


# ---------------------------------------------------------------- settings and plan


@pytest.mark.parametrize(("table", "key"), [
    ({"speeds_hz": [0.5, -1.0]}, "speeds_hz"), ({"speeds_hz": []}, "speeds_hz"), ({"speeds_hz": [1, 1]}, "speeds_hz"),
    ({"speeds_hz": "fast"}, "speeds_hz"), ({"seconds": 0}, "seconds"), ({"seconds": math.inf}, "seconds"),
    ({"settle_s": -1}, "settle_s"), ({"iterations": 1.5}, "iterations"), ({"iterations": -1}, "iterations"),
    ({"gain": 0}, "gain"), ({"gain": 1.5}, "gain"), ({"max_motor_time_s": 0}, "max_motor_time_s"),
    ({"verify": 1}, "verify"), ({"rounds": 3}, "unknown key 'rounds'")])
def test_settings_errors_are_one_line_naming_the_key(actuator, table, key):
    with pytest.raises(ConfigError) as e:
        drive_settings(with_drive(actuator, **table))
    text = str(e.value)
    assert f"[drive] {key}" in text and "\n" not in text and str(ACTUATOR) in text


def test_settings_left_out_are_the_defaults(actuator):
    assert drive_settings(actuator) == DriveSettings()


@pytest.mark.parametrize(("spec", "drive", "what"), [
    (DriveSpec(max_velocity_hz=0.4), {"speeds_hz": [0.5, 1.0]}, "max speed (0.4 Hz"),
    (DriveSpec(max_current_a=10.0), {}, "max_current_a = 12 A is beyond the drive's own max current (10 A"),
    (DriveSpec(), {"seconds": 100.0}, "max_motor_time_s"),
    (DriveSpec(), {"seconds": 1.0, "speeds_hz": [0.5]}, "revolutions"),
    (DriveSpec(), {"speeds_hz": [7.0]}, "[limits] max_speed_hz"),
    (None, {}, "[bench] inertia_uncertainty")])
def test_a_plan_beyond_the_limits_is_refused_before_any_trial(actuator, tmp_path, spec, drive, what):
    backend = EmulatedDriveBackend(actuator, spec)
    if spec is None:
        motor = dataclasses.replace(backend.description.motor, inertia_uncertainty=None)
        backend.description = dataclasses.replace(backend.description, motor=motor)
    with pytest.raises(ConfigError) as e:
        run_drive_campaign(with_drive(actuator, **drive), backend, tmp_path)
    assert what in str(e.value) and "\n" not in str(e.value)
    assert backend.requests == [] and backend.drive.time_s == 0.0 and not (tmp_path / DRIVE_RESULT_FILE).exists()


# ---------------------------------------------------------------- the law, exactly


def test_the_law_with_an_exact_residual_reaches_the_floor_in_one_step(actuator):
    """Eq. (2) with rho^ = rho exact and L = 1 gives the table of -tau / k_q: within 20 % of the best table of the
    format (`floor_table`), and each step at L < 1 lowers the residual by about 1 - L."""
    description = EmulatedDriveBackend(actuator).description
    cpr = description.motor.counts_per_rev
    theta = 2 * np.pi * np.arange(cpr) / cpr
    k_q = np.sum(description.backemf_nm_per_a * q_axis(7 * theta), axis=1)
    tau = 0.02 * np.sin(84 * theta + 0.3) + 0.004 * np.sin(168 * theta) + 0.002 * np.sin(3 * theta)

    def left(table: MoteusTable) -> float:
        rho = tau + k_q * table.sample_a(np.arange(cpr) / cpr)
        return float(np.sqrt(np.mean((rho - rho.mean()) ** 2)))

    floor = left(floor_table([tau], k_q, (1.0,), None))
    assert floor < 0.03 * left(zero_table())
    assert left(learned_table(zero_table(), tau, k_q, 1.0)) < 1.2 * floor
    table = zero_table()
    for _ in range(3):
        before = left(table)
        table = learned_table(table, tau + k_q * table.sample_a(np.arange(cpr) / cpr), k_q, 0.5)
        assert left(table) == pytest.approx(0.5 * before, rel=0.05)
    assert table.values.size == MOTEUS_TABLE_SIZE


def test_one_table_for_both_directions_leaves_the_sine_of_the_current_s_lag(actuator):
    """Eq. (3): harmonic h of the table's current flows times 1 / (1 + j h f / f_c), one way forward and the other
    in reverse; the best one table (`floor_table`) leaves sin(atan(h f / f_c)) of tau_h at each of +-f."""
    cpr = EmulatedDriveBackend(actuator).description.motor.counts_per_rev
    theta = 2 * np.pi * np.arange(cpr) / cpr
    k_q = np.full(cpr, 0.075)
    tau = 0.02 * np.sin(84 * theta + 0.3)
    bandwidth_hz, speed_hz = 1000.0, 1000.0 * 0.1 / 84  # tan(lag) = 0.1 at order 84
    flowing = lagged_a(np.sin(84 * theta), speed_hz, bandwidth_hz)
    expected = np.imag(np.exp(1j * 84 * theta) / (1 + 0.1j))
    np.testing.assert_allclose(flowing, expected, atol=1e-12)
    np.testing.assert_allclose(lagged_a(np.sin(84 * theta), -speed_hz, bandwidth_hz),
                               np.imag(np.exp(1j * 84 * theta) / (1 - 0.1j)), atol=1e-12)
    speeds = (speed_hz, -speed_hz)
    best = floor_table([tau, tau], k_q, speeds, bandwidth_hz).sample_a(np.arange(cpr) / cpr)
    for v in speeds:
        left = tau + k_q * lagged_a(best, v, bandwidth_hz)
        assert np.sqrt(np.mean(left**2)) == pytest.approx(0.02 / np.sqrt(2) * np.sin(np.arctan(0.1)), rel=0.05)


def test_what_one_table_cannot_apply_is_stated_with_what_it_would_gain(actuator):
    """`unapplied`: a table per direction would cancel the order-84 term the one table leaves sin(atan(0.1)) of;
    the table's torque at orders p and 2p (the current sensors' ripple) is stated."""
    cpr = EmulatedDriveBackend(actuator).description.motor.counts_per_rev
    theta = 2 * np.pi * np.arange(cpr) / cpr
    k_q = np.full(cpr, 0.075)
    tau = 0.02 * np.sin(84 * theta + 0.3)
    speed_hz = 1000.0 * 0.1 / 84
    table = MoteusTable.of(0.003 / 0.075 * np.sin(7 * np.arange(MOTEUS_TABLE_SIZE) * 2 * np.pi / MOTEUS_TABLE_SIZE),
                           "test")
    said = unapplied([tau, tau], k_q, table, (speed_hz, -speed_hz), 7, 1000.0)
    for one, own in zip(said.one_table_nm, said.own_table_nm):
        # its own table leaves the format's floor alone: order 84's interpolation images, 1.2 % of it
        assert one == pytest.approx(0.02 / np.sqrt(2) * np.sin(np.arctan(0.1)), rel=0.05)
        assert own == pytest.approx(0.012 * 0.02 / np.sqrt(2), rel=0.2)
    assert said.electrical_nm == pytest.approx(0.003 / np.sqrt(2), rel=0.01)
    unknown = unapplied([tau, tau], k_q, table, (speed_hz, -speed_hz), 7, None)
    assert unknown.one_table_nm is None and "states no current loop bandwidth" in unknown.lines((1.0, -1.0))[0]


# ---------------------------------------------------------------- campaigns on the emulated drive


def test_the_motor_time_stated_is_the_trials_and_nothing_persists_without_write_config(actuator, tmp_path):
    backend = EmulatedDriveBackend(actuator)
    flash = dict(backend.drive.flash)
    events: list[str] = []
    config = with_drive(actuator, speeds_hz=[1.0], seconds=3.0, settle_s=0.5, iterations=1)
    result = run_drive_campaign(config, backend, tmp_path, events.append)
    # the campaign's trials, then the floor's table once per speed and direction (the emulated drive's truth)
    durations = [r.duration_s for r in backend.requests[:3 * 2]]
    assert len(backend.requests) == 3 * 2 + 2 and result.plan.motor_time_s == pytest.approx(sum(durations))
    assert result.motor_time_used_s == pytest.approx(sum(durations))
    assert f"{sum(durations):.4g} s of motor time" in events[0]
    assert backend.drive.flash == flash and not result.stored
    written = json.loads((tmp_path / DRIVE_RESULT_FILE).read_text())
    assert written["motor_time_planned_s"] == pytest.approx(sum(durations))
    lines = (tmp_path / MOTEUS_FILE).read_text().splitlines()
    assert len(lines) == 1 + MOTEUS_TABLE_SIZE and lines[0].startswith("conf set motor.cogging_dq_scale ")
    assert (tmp_path / "drive_residual.png").exists()


def test_write_config_stores_the_final_table(actuator, tmp_path):
    backend = EmulatedDriveBackend(actuator)
    config = with_drive(actuator, speeds_hz=[1.0], seconds=3.0, settle_s=0.5, iterations=0, verify=False)
    result = run_drive_campaign(config, backend, tmp_path, write_config=True)
    assert result.stored
    assert backend.drive.flash["motor.cogging_dq_scale"] == pytest.approx(result.table.scale_a, rel=1e-6)
    assert [backend.drive.flash[f"motor.cogging_dq_comp.{k}"] for k in range(MOTEUS_TABLE_SIZE)] \
        == result.table.values.tolist()


def test_the_law_converges_with_k_q_known_10_percent_wrong(actuator, tmp_path):
    """At 0.5 Hz, where the current loop's lag (500 Hz, reversing with the direction) leaves about 1/12 of the
    ripple that no position table cancels in both directions."""
    backend = EmulatedDriveBackend(actuator, backemf_scale=1.1)
    config = with_drive(actuator, speeds_hz=[0.5], seconds=8.0, settle_s=0.5, iterations=3, gain=0.8)
    events: list[str] = []
    result = run_drive_campaign(config, backend, tmp_path, events.append)
    print("\n".join(events))
    for point in result.points:
        assert point.true_final_nm < point.true_uncompensated_nm / 8


def test_the_api_runs_a_drive_campaign_into_a_new_folder_and_refuses_a_grid_config(actuator, tmp_path):
    import ilcpmac.api as ilc
    from ilcpmac.core.errors import OptionError

    config = with_drive(actuator, speeds_hz=[1.0], seconds=3.0, settle_s=0.5, iterations=0)
    lines: list[str] = []
    result = ilc.run_drive(config, out=tmp_path / "run", backend=EmulatedDriveBackend(actuator), on_event=lines.append)
    assert result.path == tmp_path / "run" and (result.path / DRIVE_RESULT_FILE).is_file()
    assert lines[0].startswith("drive campaign: 2 rounds") and len(result.points) == 2
    with pytest.raises(ConfigError, match="exists and is not an empty directory"):
        ilc.run_drive(config, out=tmp_path / "run", backend=EmulatedDriveBackend(actuator))
    with pytest.raises(ConfigError, match=r"no \[drive\] table: run_drive runs a drive campaign"):
        ilc.run_drive(actuator, out=tmp_path / "grid")
    with pytest.raises(OptionError, match="write_config"):
        ilc.run_drive(config, out=tmp_path / "other", write_config="yes")  # type: ignore[arg-type]
