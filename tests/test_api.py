"""ilcpmac.api, the public facade (docs/api.md): each function against what it must equal (summary.json, the CLI's
files, the simulator's truth), and every bad path or argument as the one-line error the CLI prints."""

from __future__ import annotations

import inspect
import json
import subprocess
import sys

import numpy as np
import pytest
from campaign_helpers import SMALL_CAMPAIGN
from click.testing import CliRunner

import ilcpmac.api as ilc
from ilcpmac.campaign.events import CampaignStart
from ilcpmac.campaign.record import TrialRecord, records_of
from ilcpmac.campaign.rundir import RunDirError, RunFiles
from ilcpmac.cli import main
from ilcpmac.core.errors import BenchFormatError, ConfigError, IlcpmacError
from ilcpmac.core.records import IdentificationResult
from ilcpmac.export import FORMATS


@pytest.fixture(scope="module")
def work(tmp_path_factory):
    """A folder with the small campaign's config (``small.toml``), its run (``run``, seed 3, its events kept) and a
    simulated bench of it (``bench``)."""
    folder = tmp_path_factory.mktemp("api")
    config = ilc.write_config(folder / "small.toml", SMALL_CAMPAIGN)
    events: list = []
    result = ilc.run(config, out=folder / "run", seed=3, on_event=events.append)
    simulated = ilc.simulate_bench(config, folder / "bench", seed=3)
    return {"folder": folder, "config": config, "run": result, "events": events, "simulated": simulated}


def cli_error(args: list[str]) -> str:
    """The one line ``ilcpmac ARGS`` ends with for its error (exit status 2), without its ``error: ``."""
    out = CliRunner().invoke(main, [str(a) for a in args])
    assert out.exit_code == 2, out.output
    last = out.output.splitlines()[-1]  # after the progress bar, if any
    assert last.startswith("error: "), out.output
    return last.removeprefix("error: ")


# ---------------------------------------------------------------- the module


def test_every_public_name_is_there_and_documented():
    for name in ilc.__all__:
        value = getattr(ilc, name)
        if inspect.isfunction(value) or inspect.isclass(value):
            assert inspect.getdoc(value), name
    functions = [getattr(ilc, n) for n in ilc.__all__ if inspect.isfunction(getattr(ilc, n))]
    for function in functions:
        doc = inspect.getdoc(function)
        assert "Parameters\n----------" in doc and "Returns\n-------" in doc, function.__name__


def test_importing_ilcpmac_imports_nothing_and_the_api_no_numba():
    code = ("import sys, ilcpmac; assert 'numpy' not in sys.modules, 'numpy'; import ilcpmac.api; "
            "assert 'numba' not in sys.modules and 'scipy' not in sys.modules, 'numba'")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr


# ---------------------------------------------------------------- run and load_run


def test_load_run_gives_summary_jsons_figures(work):
    run_dir = work["run"].path
    summary = json.loads((run_dir / "summary.json").read_text())
    loaded = ilc.load_run(run_dir)
    assert len(loaded.points) == len(summary["points"]) == 3
    for point, data in zip(loaded.points, summary["points"]):
        assert (point.torque_setpoint_nm, point.speed_setpoint_hz, point.learned) == (
            data["torque_setpoint"], data["speed_setpoint"], data["learned"])
        for name, key in (("ripple_pp", "ripple_pp"), ("uncompensated_pp", "uncompensated_pp"),
                          ("floor_pp", "floor_pp")):
            assert getattr(point, f"{name}_percent") == 100 * data[f"{key}_measured"]
            assert getattr(point, f"{name}_true_percent") == 100 * data[f"{key}_true"]
        assert point.reduction_factor == data["reduction_factor"]
        assert point.worse_than_uncompensated == data["worse_than_uncompensated"]
        assert (point.uncompensated_trial, point.compensated_trial) == (data["uncompensated_trial"],
                                                                        data["compensated_trial"])
    assert loaded.motor_time_s == {k: v for k, v in summary["motor_time_s"].items() if k != "all"}
    assert loaded.motor_time_total_s == summary["motor_time_s"]["all"]
    assert list(loaded.records) == records_of(summary)
    assert loaded.compensation_file == run_dir / "compensation.json"
    assert loaded.identification is not None
    assert loaded.identification.to_json() == summary["identification"]
    # run returns what load_run reads
    assert work["run"].points == loaded.points and work["run"].records == loaded.records


def test_run_passes_its_events_to_on_event(work):
    events = work["events"]
    assert isinstance(events[0], CampaignStart) and events[0].path == work["run"].path
    trials = [e for e in events if isinstance(e, TrialRecord)]
    assert [t.index for t in trials] == list(range(1, len(work["run"].records) + 1))
    assert all(hasattr(e, "text") for e in events[1:] if not isinstance(e, TrialRecord))


def test_print_event_prints_one_line_per_event(work, capsys):
    for event in work["events"]:
        ilc.print_event(event)
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith(f"campaign in {work['run'].path}: 2 learned, 1 validated points")
    assert any(line.startswith("trial 18 (validate, validate) at 3 N m, 0.9 Hz: ripple ") for line in out)


def test_a_trial_is_float64_columns_equal_to_its_file(work):
    results = work["run"]
    record = results.records[4]
    trial = results.trial(5)
    data = RunFiles(results.path).read_trial(5, record.torque_setpoint_nm, record.speed_setpoint_hz)
    assert trial.record == record
    assert list(trial.columns) == ["count", "time", "i_ref_a", "i_ref_b", "i_ref_c", "torque", "torque_true"]
    assert all(v.dtype == np.float64 and v.shape == (data.n_samples,) for v in trial.columns.values())
    np.testing.assert_array_equal(trial.columns["count"], data.count)
    np.testing.assert_array_equal(trial.columns["i_ref_b"], data.i_ref_a[:, 1])
    np.testing.assert_array_equal(trial.columns["torque"], data.torque_nm)
    assert trial.units["time"] == "s" and trial.units["torque"] == "N m"
    table = trial.table()
    assert table.column_names == list(trial.columns) and table.schema.field("i_ref_a").metadata == {b"unit": b"A"}


def test_a_trial_frame_without_pandas_says_how_to_install_it(work, monkeypatch):
    monkeypatch.setitem(sys.modules, "pandas", None)
    with pytest.raises(ImportError, match="pip install pandas") as e:
        work["run"].trial_frame(1)
    assert "\n" not in str(e.value)


def test_a_trial_frame_holds_the_columns(work):
    pytest.importorskip("pandas")
    trial = work["run"].trial(2)
    frame = work["run"].trial_frame(2)
    assert list(frame.columns) == list(trial.columns) and frame.attrs["units"] == trial.units
    np.testing.assert_array_equal(frame["torque"].to_numpy(), trial.columns["torque"])


def test_a_trial_that_is_not_there_is_one_line(work):
    with pytest.raises(IlcpmacError, match=r"no trial 19 \(its trials are 1\.\.18\)$"):
        work["run"].trial(19)


def test_load_run_of_no_run_is_the_clis_line(tmp_path):
    with pytest.raises(RunDirError) as e:
        ilc.load_run(tmp_path)
    assert str(e.value) == cli_error(["report", tmp_path])


def test_run_refuses_a_bad_config_before_anything_runs(tmp_path):
    with pytest.raises(ConfigError) as e:
        ilc.run(tmp_path / "missing.toml", out=tmp_path / "run")
    assert str(e.value) == cli_error(["run", tmp_path / "missing.toml", "--out", tmp_path / "run"])
    assert not (tmp_path / "run").exists()
    with pytest.raises(ConfigError, match="bench"):
        ilc.write_config(tmp_path / "bad.toml", {"bench": {"counts_per_rev": -1}})


# ---------------------------------------------------------------- simulate and identify


def test_identify_recovers_the_simulated_benchs_truth(work, tmp_path):
    simulated = work["simulated"]
    truth = simulated.truth
    result = ilc.identify(simulated.folder, output=tmp_path / "result.json")
    assert isinstance(result, IdentificationResult)
    # the small bench (3 revolutions per trial, 2 x 2 grid): the gains within 1 %, alpha within 0.01, beta 0.02 A
    assert result.epsilon == pytest.approx(truth.epsilon, rel=0.01)
    assert result.delta == pytest.approx(truth.delta, rel=0.01)
    np.testing.assert_allclose(result.alpha, truth.alpha, atol=0.01)
    np.testing.assert_allclose(result.beta, truth.beta, atol=0.02)
    cogging_error = np.sqrt(np.mean((result.cogging_nm - truth.cogging_nm) ** 2) / np.mean(truth.cogging_nm ** 2))
    assert cogging_error < 0.05
    assert json.loads((tmp_path / "result.json").read_text()) == json.loads(json.dumps(result.to_json()))


def test_identify_on_the_encoder_needs_no_sensor_column(work):
    result = ilc.identify(work["simulated"].folder, torque_source="encoder")
    assert result.delta is None and result.cogging_nm is not None


def test_identify_errors_are_the_clis_lines(work, tmp_path):
    with pytest.raises(BenchFormatError) as e:
        ilc.identify(tmp_path / "none")
    assert str(e.value) == cli_error(["identify", tmp_path / "none", "--output", tmp_path / "r.json"])
    with pytest.raises(IlcpmacError, match="^torque_source: expected 'sensor', 'encoder' or a TorqueSource, got "
                                           "'piezo'$"):
        ilc.identify(work["simulated"].folder, torque_source="piezo")


def test_simulate_bench_takes_a_path_or_a_loaded_config_alike(work, tmp_path):
    from ilcpmac.config import load_config

    again = ilc.simulate_bench(load_config(work["config"]), tmp_path / "b", seed=3)
    for name in ("bench.toml", "backemf.csv", "truth.json", *again.bench.trial_files):
        assert (tmp_path / "b" / name).read_bytes() == (work["simulated"].folder / name).read_bytes(), name
    with pytest.raises(ConfigError, match="revolutions"):
        ilc.simulate_bench(work["config"], tmp_path / "c", revolutions=0)


def test_a_simulated_log_imports_and_identifies(work):
    folder = work["folder"]
    log = ilc.simulate_log(work["config"], folder / "log", seed=3, duration_s=10.0)
    assert log.log.is_file() and log.mapping.is_file() and log.truth["torque_constant_nm_per_a"] > 0
    (imported,) = ilc.import_logs(log.log, log.mapping, folder / "imported")
    assert imported.folder == folder / "imported" and len(imported.bench.trials) == 1
    assert 0 < imported.laps[0].error.current_a < 1.0
    result = ilc.identify(imported.folder)
    assert result.position_torque_nm is not None and result.position_torque_nm.shape == (1024,)


def test_simulate_log_options_are_checked(work, tmp_path):
    with pytest.raises(IlcpmacError, match="^speed: not an option of simulate_log"):
        ilc.simulate_log(work["config"], tmp_path / "log", speed=1.0)
    with pytest.raises(IlcpmacError, match="^duration_s: invalid value"):
        ilc.simulate_log(work["config"], tmp_path / "log", duration_s=-1.0)
    assert not (tmp_path / "log").exists()


def test_a_simulated_scan_imports_and_identifies_its_cogging(work):
    folder = work["folder"]
    scan = ilc.simulate_scan(work["config"], folder / "scan", seed=3)
    with pytest.raises(BenchFormatError, match='kind = "scan": not for import_logs \\(import_scan takes it\\)'):
        ilc.import_logs(scan.log, scan.mapping, folder / "not-a-bench")
    data = ilc.import_scan(scan.log, scan.mapping, folder / "scan-folder")
    assert data.currents_a is not None and data.time_s.size > 0
    result = ilc.identify(folder / "scan-folder")
    assert isinstance(result, ilc.ScanResult)
    true = np.asarray(scan.truth["cogging"]["torque"])
    true = true - true.mean()
    assert np.sqrt(np.mean((result.cogging_nm - true) ** 2) / np.mean(true ** 2)) < 0.1
    with pytest.raises(IlcpmacError, match="torque_source: not for a standstill scan folder"):
        ilc.identify(folder / "scan-folder", torque_source="sensor")


# ---------------------------------------------------------------- export


@pytest.mark.parametrize("fmt", [f for f in FORMATS if f not in ("harmonics", "moteus")])
def test_export_of_a_run_is_the_clis_files(work, tmp_path, fmt):
    run_dir = work["run"].path
    exported = ilc.export(run_dir, fmt, tmp_path / "api")
    out = CliRunner().invoke(main, ["export", str(run_dir), "--format", fmt, "--out", str(tmp_path / "cli")])
    assert out.exit_code == 0, out.output
    assert exported.residual is not None and out.output.splitlines()[-1] == exported.residual.line(fmt)
    names = sorted(p.name for p in (tmp_path / "cli").iterdir())
    assert names == sorted(p.name for p in exported.files)
    for name in names:
        assert (tmp_path / "api" / name).read_bytes() == (tmp_path / "cli" / name).read_bytes(), name
    # the run's compensation.json itself, alike
    ilc.export(run_dir / "compensation.json", fmt, tmp_path / "file")
    for name in names:
        assert (tmp_path / "file" / name).read_bytes() == (tmp_path / "cli" / name).read_bytes(), name


def test_export_of_an_identification_to_moteus_is_the_clis(work, tmp_path):
    result_json = tmp_path / "result.json"
    ilc.identify(work["simulated"].folder, output=result_json)
    k_q = ilc.torque_constant_nm_per_a(work["simulated"].folder)
    backemf = work["simulated"].bench.backemf_nm_per_a
    assert k_q == pytest.approx(1.5 * np.abs(np.fft.rfft(backemf, axis=0)[8]).mean() * 2 / len(backemf))
    exported = ilc.export(result_json, "moteus", tmp_path / "api", torque_constant_nm_per_a=k_q)
    out = CliRunner().invoke(main, ["export", str(result_json), "--format", "moteus", "--out", str(tmp_path / "cli"),
                                    "--torque-constant", repr(k_q)])
    assert out.exit_code == 0, out.output
    assert [p.name for p in exported.files] == ["moteus_cogging.txt"]
    moteus = "moteus_cogging.txt"
    assert (tmp_path / "api" / moteus).read_bytes() == (tmp_path / "cli" / moteus).read_bytes()


@pytest.mark.parametrize("case", ["no run", "no compensation", "bad result", "moteus of a run", "content of a run",
                                  "no torque constant"])
def test_export_errors_are_the_clis_lines(work, tmp_path, case):
    run_dir = work["run"].path
    (tmp_path / "bad.json").write_text("[1, 2]")
    source, fmt, options, flags = {
        "no run": (tmp_path / "missing", "json", {}, []),
        "no compensation": (tmp_path, "json", {}, []),
        "bad result": (tmp_path / "bad.json", "csv", {}, []),
        "moteus of a run": (run_dir, "moteus", {"torque_constant_nm_per_a": 0.3}, ["--torque-constant", "0.3"]),
        "content of a run": (run_dir, "csv", {"content": "cogging"}, ["--content", "cogging"]),
        "no torque constant": (work["folder"] / "bench-result.json", "harmonics", {}, []),
    }[case]
    if case == "no torque constant":
        ilc.identify(work["simulated"].folder, output=source)
    with pytest.raises(IlcpmacError) as e:
        ilc.export(source, fmt, tmp_path / "out", **options)
    assert str(e.value) == cli_error(["export", source, "--format", fmt, "--out", tmp_path / "out", *flags])
    assert not (tmp_path / "out").exists()
