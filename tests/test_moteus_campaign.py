"""`ilcpmac run` of a [drive] config through mjbots' moteus library against the emulated moteus (issue 36): the
whole drive campaign, and its refusals before any motion."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from click.testing import CliRunner

pytest.importorskip("moteus")

from ilcpmac.campaign.drive import DRIVE_RESULT_FILE  # noqa: E402
from ilcpmac.cli import main  # noqa: E402
from ilcpmac.export import MOTEUS_FILE  # noqa: E402

EMULATED = Path(__file__).resolve().parents[1] / "configs" / "moteus-emulated.toml"


def _config(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "drive.toml"
    path.write_text(f'extends = "{EMULATED}"\n{text}')
    return path


def _run(*args: object) -> tuple[int, str]:
    result = CliRunner().invoke(main, ["run", *map(str, args)])
    return result.exit_code, result.output


@pytest.mark.slow
def test_a_drive_campaign_through_the_moteus_library_learns_the_drive_s_own_table(tmp_path):
    """A short campaign (one speed, both directions, two learning rounds, 40 s of motor time): the true ripple the
    table leaves falls at least 10x at each direction and within 2x of the floor (measured: 15x, 1.3x), the
    measured one with it, and the table is written; the flash is not (no --write-config)."""
    config = _config(tmp_path, "[drive]\nspeeds_hz = [0.59]\niterations = 2\nseconds = 4.0\n"
                               "max_motor_time_s = 40.0\n")
    code, output = _run(config, "--out", tmp_path / "run")
    assert code == 0, output
    said = " ".join(output.split())
    assert "drive campaign: 4 rounds (uncompensated, learning 1, learning 2, verification) x speeds +-0.59 Hz, " \
           "8 trials of 1 s settling + 4 s recorded: 40 s of motor time" in said
    assert "the drive's flash is unchanged" in said
    result = json.loads((tmp_path / "run" / DRIVE_RESULT_FILE).read_text())
    assert result["motor_time_used_s"] == result["motor_time_planned_s"] == 40.0 and not result["stored"]
    for point in result["points"]:  # issue 36's targets: 10x below uncompensated, within 2x of the floor
        assert point["true_final_nm"] < point["true_uncompensated_nm"] / 10, point
        assert point["true_final_nm"] < 2 * point["true_floor_nm"], point
        assert point["final_nm"] < point["uncompensated_nm"] / 10, point
    assert len((tmp_path / "run" / MOTEUS_FILE).read_text().splitlines()) == 1025


@pytest.mark.parametrize("extra, args, message", [
    ("[limits]\nmax_current_a = 30.0\n", (), r"\[limits\] max_current_a = 30 A is beyond the drive's own max current "
                                             r"\(20 A, servo.max_current_A\): lower it"),
    ("[drive]\nspeeds_hz = [25.0]\n[limits]\nmax_speed_hz = 30.0\n", (),
     r"\[drive\] speeds_hz: 25 Hz is beyond the drive's own max speed \(20 Hz, servo.max_velocity\)"),
    ("[drive]\nmax_motor_time_s = 10.0\n", (),
     r"\[drive\] seconds: .* records .* revolutions; a trial needs 2 or more"),
    ("[drive]\nspeed = 1.0\n", (), r"\[drive\] unknown key 'speed'"),
    ("[backends.moteus]\nid = 200\n", (), r"\[backends.moteus\] id"),
    *[(f"[drive]\n{key} = {value}\n", (), rf"\[drive\] {key}") for key, value in (
        ("speeds_hz", "[nan]"), ("speeds_hz", "[0.0]"), ("speeds_hz", "[1.0, 1.0]"), ("speeds_hz", "[1e308]"),
        ("iterations", "-1"), ("iterations", "1.5"), ("gain", "0.0"), ("gain", "inf"), ("seconds", "1e9"),
        ("settle_s", "61.0"), ("max_motor_time_s", "-1.0"), ("verify", '"yes"'))],
    *[(f"[backends.moteus]\n{key} = {value}\n", (), rf"\[backends.moteus\] {key}") for key, value in (
        ("query_rate_hz", "1e9"), ("transport", '"serial"'), ("watchdog_timeout_s", "0.0"), ("max_lost_polls", "0"),
        ("poll_timeout_s", "nan"))],
    ("[backends.moteus.emulated]\nmax_current_a = -1.0\n", (), r"max_current_a"),
    ("", ("--trials", "3"), r"--trials: not for a drive campaign"),
    ("", ("--backend", "sim"), r"the SimulatorBackend backend drives no drive without a load"),
])
def test_a_drive_campaign_asking_what_it_must_not_is_refused_before_any_motion(tmp_path, extra, args, message):
    code, output = _run(_config(tmp_path, extra), "--out", tmp_path / "run", *args)
    assert code == 2, output
    (line,) = output.strip().splitlines()
    assert line.startswith("error: ") and re.search(message, line), output
    assert not (tmp_path / "run" / DRIVE_RESULT_FILE).exists()


def test_write_config_is_only_for_a_drive_campaign_and_a_run_folder_is_not_overwritten(tmp_path):
    code, output = _run("configs/quick.toml", "--write-config", "--out", tmp_path / "run")
    assert code == 2 and "--write-config: only for a drive campaign" in output, output
    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "keep.txt").write_text("mine")
    code, output = _run(EMULATED, "--out", tmp_path / "run")
    assert code == 2 and "exists and is not an empty directory" in output, output
    assert (tmp_path / "run" / "keep.txt").read_text() == "mine"
