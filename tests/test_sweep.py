"""ilcpmac sweep: the spec and its draws, the truth keys it sweeps, a 4-task sweep on a local Dask cluster."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from campaign_helpers import SMALL_CAMPAIGN
from click.testing import CliRunner

from ilcpmac.cli import main
from ilcpmac.config import load_config
from ilcpmac.core.seeds import trial_seed
from ilcpmac.sim.bench import simulated_description
from ilcpmac.sim.simulator import Simulator
from ilcpmac.sweep.results import SweepResultsError, read_results, result_file
from ilcpmac.sweep.runner import SweepRunError, SweepRunner, local_client
from ilcpmac.sweep.spec import SweepSpecError, load_spec

#: four identification tasks: two per friction value; 100 N m of friction stops the rotor (a failing task)
SPEC = """
[sweep]
kind = "identify"
tasks = 2
seed = 7

[draw."simulator.mechanics.inertia_scale"]
distribution = "uniform"
relative = 0.2

[draw."simulator.current_sensors.beta_a[1]"]
distribution = "normal"
std = 0.05

[draw."simulator.mechanics.coulomb_friction_nm"]
distribution = "grid"
values = [0.0, 100.0]

[magnets]
temperature_rise_k = [0.0, 80.0]
coefficient_per_k = -0.001
"""


@pytest.fixture
def small_config(write_config) -> Path:
    return write_config(SMALL_CAMPAIGN)


@pytest.fixture
def spec_file(tmp_path: Path) -> Path:
    path = tmp_path / "sweep.toml"
    path.write_text(SPEC)
    return path


def test_draws_are_seeded_per_task_and_land_in_each_config(spec_file, small_config, tmp_path):
    spec = load_spec(spec_file, small_config)
    assert spec.task_count == 4
    more = load_spec(spec_file, small_config)
    more = dataclasses.replace(more, tasks_per_point=3)
    # task k's random draws depend on (seed, k) only, not on how many tasks there are
    assert spec.draw(1).parameters[:2] == more.draw(1).parameters[:2]
    assert spec.draw(0).parameters != spec.draw(1).parameters
    draw = spec.draw(3)
    assert draw.seed == trial_seed(7, 3)
    values = dict(draw.parameters)
    assert values["simulator.mechanics.coulomb_friction_nm"] == 100.0
    assert 0.8 <= values["simulator.mechanics.inertia_scale"] <= 1.2
    assert 0.0 <= values["magnet_temperature_rise_k"] <= 80.0
    path = tmp_path / "task.toml"
    path.write_text(spec.task_config(draw))
    cfg = spec.check_task(draw, path)
    assert cfg.grid.seed == draw.seed
    assert cfg.model.mechanics.inertia_scale == pytest.approx(values["simulator.mechanics.inertia_scale"])
    assert cfg.model.winding.backemf_scale == pytest.approx(1 - 0.001 * values["magnet_temperature_rise_k"])
    assert cfg.model.current_sensors.beta_a[1] == pytest.approx(values["simulator.current_sensors.beta_a[1]"])
    assert cfg.model.current_sensors.beta_a[0] == 1.0  # the other elements as the base config gives them


@pytest.mark.parametrize("table, expected", [
    ('[sweep]\nkinds = "identify"', 'spec.toml: [sweep] unknown key'),
    ('[sweep]\nkind = "fit"',
     "[sweep] kind: invalid value 'fit' (what a task runs: \"identify\" (the grid and identify_bench) or \"campaign\""),
    ('[sweep]\ntasks = 0', "[sweep] tasks: invalid value 0 (tasks per point of the grid draws, 1..100000)"),
    ('[sweep]\nseed = 1.5', "[sweep] seed: expected an integer, got 1.5"),
    ('[draw."simulator.mechanics.mass"]\ndistribution = "normal"\nstd = 1.0',
     '[draw."simulator.mechanics.mass"]: [simulator.mechanics] has no key \'mass\''),
    ('[draw."simulator.mechanics.inertia_kgm2"]\ndistribution = "normal"\nstd = 1.0',
     "the controller knows it: draw [bench] inertia_kgm2"),
    ('[draw."simulator.current_sensors.alpha"]\ndistribution = "gauss"', "distribution: 'gauss' is not one of"),
    ('[draw."simulator.current_sensors.alpha"]\ndistribution = "normal"\nstd = [0.1, 0.1]',
     "std: expected a finite number or a list of 3"),
    ('[draw."simulator.current_sensors.alpha[3]"]\ndistribution = "normal"\nstd = 0.1', "has no element 3"),
    ('[draw."simulator.winding.backemf_scale"]\ndistribution = "uniform"\nlow = 1.0', "high: missing"),
    ('[draw."excitation.phases"]\ndistribution = "normal"\nstd = 0.1', "is not a number: draw it with choice"),
    ('[magnets]\ntemperature_rise_k = [0, 80]\ncoefficient_per_k = -0.02',
     "[magnets] coefficient_per_k: -0.02 per K is out of range"),
    ('[draw."simulator.controller.bandwidth_hz"]\ndistribution = "uniform"\nlow = -1e308\nhigh = 1e308',
     '[draw."simulator.controller.bandwidth_hz"]: its spread is beyond the range of a double'),
    ('[draw."simulator.controller.bandwidth_hz"]\ndistribution = "normal"\nmean = 1.0\nrelative_std = 1e307',
     "its spread is beyond the range of a double"),
    ('[draw."simulator.controller.bandwidth_hz"]\ndistribution = "choice"\nvalues = [100.0, "b"]',
     '[draw."simulator.controller.bandwidth_hz"] values[1]: expected a finite number, got \'b\''),
    ('[draw."simulator.controller.bandwidth_hz"]\ndistribution = "choice"\nvalues = [{ a = 1 }]',
     "values[0]: expected a finite number, got {'a': 1}"),
    ('[draw."simulator.controller.bandwidth_hz"]\ndistribution = "grid"\nvalues = [[1.0, 2.0]]',
     "values[0]: expected a finite number, got [1.0, 2.0]"),
    ('[draw."simulator.current_sensors.alpha"]\ndistribution = "choice"\nvalues = [1.0]',
     "values[0]: expected a list, got 1.0"),
    ('[draw."simulator.current_sensors.alpha[1]"]\ndistribution = "grid"\nvalues = [true]',
     "values[0]: expected a finite number, got True"),
    ('[draw."bench.pole_pairs"]\ndistribution = "choice"\nvalues = [8.5]', "values[0]: expected an integer, got 8.5"),
    ('[draw."pipeline.stages"]\ndistribution = "choice"\nvalues = ["ilc"]', "values[0]: expected a list, got 'ilc'"),
])
def test_spec_errors_are_one_line_naming_the_key(tmp_path, small_config, table, expected):
    path = tmp_path / "spec.toml"
    path.write_text(table)
    with pytest.raises(SweepSpecError) as error:
        load_spec(path, small_config)
    assert expected in str(error.value) and "\n" not in str(error.value)


def test_choice_values_of_the_key_type_are_taken_as_the_config_takes_them(tmp_path, small_config):
    path = tmp_path / "spec.toml"
    path.write_text('[draw."simulator.controller.bandwidth_hz"]\ndistribution = "choice"\nvalues = [100, 150.5]\n'
                    '[draw."simulator.current_sensors.alpha"]\ndistribution = "grid"\nvalues = [[1, 1.01, 0.99]]\n')
    spec = load_spec(path, small_config)
    assert spec.draws[0].values == (100.0, 150.5) and isinstance(spec.draws[0].values[0], float)
    assert spec.draws[1].values == ((1.0, 1.01, 0.99),)


def test_a_draw_out_of_range_names_the_key_and_the_task(tmp_path, small_config):
    spec_path = tmp_path / "spec.toml"
    spec_path.write_text('[sweep]\ntasks = 50\nseed = 1\n[draw."simulator.current_sensors.epsilon"]\n'
                         'distribution = "normal"\nmean = 0.1\nstd = 0.1\n')
    result = CliRunner().invoke(main, ["sweep", str(small_config), "--spec", str(spec_path),
                                       "--out", str(tmp_path / "out")])
    assert result.exit_code == 2
    message = result.output.strip()
    assert '[draw."simulator.current_sensors.epsilon"] task ' in message and "out of range" in message
    assert len(message.splitlines()) == 1


def test_true_backemf_and_inertia_differ_from_what_the_controller_knows(small_model, make_request):
    nominal = Simulator(small_model)
    changed = dataclasses.replace(
        small_model, winding=dataclasses.replace(small_model.winding, backemf_scale=1.1),
        mechanics=dataclasses.replace(small_model.mechanics, inertia_scale=1.5))
    sim = Simulator(changed)
    assert changed.mechanics.true_inertia_kgm2 == pytest.approx(1.5 * small_model.mechanics.inertia_kgm2)
    assert simulated_description(sim, None).motor.inertia_kgm2 == small_model.mechanics.inertia_kgm2
    np.testing.assert_array_equal(sim.backemf_counts, nominal.backemf_counts)  # the controller's table
    request = make_request(changed, torque_nm=3.0)
    a, b = nominal.run_trial(request), sim.run_trial(request)
    assert b.torque_true_nm.mean() / a.torque_true_nm.mean() == pytest.approx(1.1, rel=0.01)


def test_sweep_on_a_local_cluster_records_failures_and_resumes(spec_file, small_config, tmp_path):
    out = tmp_path / "out"
    spec = load_spec(spec_file, small_config)
    runner = SweepRunner(spec, out)
    tasks = runner.prepare(resume=False)
    # the first task's config is checked whole before anything runs; each other's is written as it is submitted
    assert sorted(p.name for p in (out / "tasks").iterdir()) == ["task_0000.toml"]
    assert load_config(out / "tasks" / "task_0000.toml").grid.seed == tasks[0].seed

    class Recorder:
        """The sweep's events, kept."""

        def __init__(self):
            self.starts, self.indices = [], []

        def started(self, total, done):
            self.starts.append((total, done))

        def finished(self, result):
            self.indices.append(result.task.index)

    events = Recorder()
    client = local_client(1)  # one worker process: a second only repeats its start-up and warm-up, seconds each
    try:
        runner.run(client, tasks[:1] + tasks[2:3], events)  # one good and one failing task, then stop
        first = {i: result_file(out, i).stat().st_mtime_ns for i in (0, 2)}
        with pytest.raises(SweepRunError, match="holds a sweep's results"):
            SweepRunner(spec, out).prepare(resume=False)
        resumed = SweepRunner(spec, out)
        runner_tasks = resumed.prepare(resume=True)
        resumed.run(client, runner_tasks, events)
    finally:
        client.close()
        client.cluster.close()
    assert events.starts[1] == (4, 2) and sorted(events.indices) == [0, 1, 2, 3]
    assert sorted(p.name for p in (out / "tasks").iterdir()) == [f"task_{i:04d}.toml" for i in range(4)]
    assert load_config(out / "tasks" / "task_0003.toml").grid.seed == tasks[3].seed
    assert {i: result_file(out, i).stat().st_mtime_ns for i in (0, 2)} == first  # not run again
    table = read_results(out)
    rows = table.to_pylist()
    assert [r["task"] for r in rows] == [0, 1, 2, 3]
    assert [r["seed"] for r in rows] == [trial_seed(7, i) for i in range(4)]
    assert [r["status"] for r in rows] == ["ok", "ok", "failed", "failed"]
    assert all("not enough to turn the rotor against friction" in r["reason"] for r in rows[2:])
    for r in rows[:2]:
        assert abs(r["id_error:alpha"]) < 0.05 and np.isfinite(r["id_error:cogging"])
        assert r["draw:simulator.mechanics.coulomb_friction_nm"] == 0.0
    assert rows[2]["id_error:alpha"] is None


def test_cli_resume_of_a_finished_sweep_writes_its_table_summary_and_plots(spec_file, small_config, tmp_path,
                                                                          monkeypatch):
    """With every result there, the resume starts no cluster (it took 2 s for nothing)."""
    def no_cluster(workers):
        raise AssertionError("a cluster was started with nothing left to run")

    monkeypatch.setattr("ilcpmac.sweep.runner.local_client", no_cluster)
    out = tmp_path / "out"
    spec = load_spec(spec_file, small_config)
    runner = SweepRunner(spec, out)
    tasks = runner.prepare(resume=False)
    from ilcpmac.sweep.results import write_result
    from ilcpmac.sweep.task import run_task

    for draw in tasks:
        write_result(out, run_task(runner.task(draw)))  # the same results a cluster would give, run here
    result = CliRunner().invoke(main, ["sweep", str(small_config), "--spec", str(spec_file), "--out", str(out),
                                       "--resume", "--workers", "1", "--table-format", "csv"])
    assert result.exit_code == 0, result.output
    assert "sweep: 2 of 4 tasks ok" in result.output
    assert f"rerun: ilcpmac simulate {out}/tasks/task_0002.toml" in result.output
    assert (out / "results.csv").read_text().count("\n") == 5
    assert (out / "plots" / "distribution.png").is_file()
    import json

    summary = json.loads((out / "summary.json").read_text())
    assert [f["task"] for f in summary["failed"]] == [2, 3]
    assert summary["main_figure"] == "id_error:delta_epsilon"


def test_summary_names_failures_percentiles_and_the_worst_tasks_in_order():
    import pyarrow as pa

    from ilcpmac.sweep.results import summarize

    table = pa.table({"task": [0, 1, 2, 3], "seed": [10, 11, 12, 13],
                      "status": ["ok", "failed", "ok", "ok"], "reason": [None, "diverged", None, None],
                      "final_pp_true": [0.001, None, 0.003, 0.002]})
    summary = summarize(table, "campaign", 5, lambda i: f"rerun {i}", worst=2)
    assert (summary.tasks, summary.finished, summary.main_figure) == (5, 4, "final_pp_true")
    assert [(t.task, t.seed, t.detail, t.rerun) for t in summary.failed] == [(1, 11, "diverged", "rerun 1")]
    assert [(t.task, t.detail) for t in summary.worst] == [(2, 0.003), (3, 0.002)]
    (final,) = [p for p in summary.spread if p.column == "final_pp_true"]
    assert (final.count, final.median, final.worst) == (3, 0.002, 0.003)
    json = summary.to_json()
    assert json["failed"] == [{"task": 1, "seed": 11, "reason": "diverged", "rerun": "rerun 1"}]
    assert json["worst"][0] == {"task": 2, "seed": 12, "value": 0.003, "rerun": "rerun 2"}


def test_preparing_checks_every_draw_but_loads_the_first_config_only(tmp_path, small_config):
    """2000 tasks: every task's draws are checked (task 1999's out of range is refused before anything runs),
    one config is written and loaded; a task whose draws make its whole config invalid (3 N m of torque limit
    under the grid's 4 N m set point) fails as it is made, naming the spec and the task."""
    spec_path = tmp_path / "spec.toml"
    spec_path.write_text('[sweep]\ntasks = 1000\n[draw."limits.max_torque_nm"]\ndistribution = "grid"\n'
                         "values = [8.0, 3.0]\n")
    runner = SweepRunner(load_spec(spec_path, small_config), tmp_path / "out")
    draws = runner.prepare(resume=False)
    assert len(draws) == 2000 and [p.name for p in (tmp_path / "out" / "tasks").iterdir()] == ["task_0000.toml"]
    with pytest.raises(SweepSpecError, match=r"spec.toml: task 1000 \(seed \d+\): its draws make an invalid config: "
                                             r".*max_torque_nm"):
        runner.task(draws[1000])
    assert "ilcpmac simulate" in runner.rerun_command(1000) and "task_1000.toml" in runner.rerun_command(1000)
    spec_path.write_text('[sweep]\ntasks = 2000\nseed = 1\n[draw."simulator.current_sensors.epsilon"]\n'
                         'distribution = "uniform"\nlow = 0.5\nhigh = 10.02\n')
    spec = load_spec(spec_path, small_config)
    beyond = [i for i in range(2000) if dict(spec.draw(i).parameters)["simulator.current_sensors.epsilon"] > 10]
    assert beyond and beyond[0] > 100  # found only by checking (nearly) every task
    with pytest.raises(SweepSpecError, match=rf"task {beyond[0]} \(seed \d+\): the draw 10.0\d+ is out of range"):
        SweepRunner(spec, tmp_path / "out2").prepare(resume=False)
    assert not (tmp_path / "out2" / "tasks").exists()


@pytest.mark.parametrize(("args", "expected"), [
    (["--scheduler", "a:b:c"], r"error: --scheduler a:b:c: not a scheduler's address, tcp://HOST:PORT \(.+\)"),
    (["--scheduler", "tcp://127.0.0.1:9", "--connect-timeout", "0.2"],
     r"error: --scheduler tcp://127.0.0.1:9: no scheduler answered within 0.2 s \(.+\)"),
    (["--workers", "1000000"], r"error: --workers 1000000: a local cluster takes 1 to \d+ worker processes \(4 per "
                               r"core\)"),
])
def test_a_scheduler_or_workers_the_sweep_cannot_use_is_one_line(spec_file, small_config, tmp_path, monkeypatch,
                                                                   args, expected):
    def no_cluster(workers):
        raise AssertionError("a local cluster was started")

    monkeypatch.setattr("ilcpmac.sweep.runner.local_client", no_cluster)
    result = CliRunner().invoke(main, ["sweep", str(small_config), "--spec", str(spec_file), "--out",
                                       str(tmp_path / "out"), *args])
    assert result.exit_code == 2, result.output
    # the error alone: the tasks' line waits for the cluster (it came first, the fuzz's scheduler group found)
    (line,) = result.output.splitlines()
    assert re.fullmatch(expected, line), result.output


@pytest.mark.parametrize(("make", "expected"), [
    (lambda p: pq.write_table(pa.table({"x": [1.0]}), p), r"not a task's result \(no column 'task' of the right"),
    (lambda p: pq.write_table(pa.table({"task": ["0"], "seed": [1], "kind": ["identify"], "status": ["ok"],
                                        "reason": [""], "seconds": [1.0], "config": ["c"]}), p),
     r"not a task's result \(no column 'task' of the right type"),
    (lambda p: pq.write_table(pa.table({"task": [5], "seed": [1], "kind": ["identify"], "status": ["ok"],
                                        "reason": [""], "seconds": [1.0], "config": ["c"]}), p),
     r"not task 0's result \(1 rows, task \[5\]\)"),
    (lambda p: p.mkdir(), "not a regular file"),
    (lambda p: p.symlink_to("/dev/zero"), "not a regular file"),
    (lambda p: p.write_bytes(b"PAR1" + bytes(range(256))), "unreadable result"),
])
def test_a_result_file_that_is_not_a_task_result_is_refused_naming_it(spec_file, small_config, tmp_path, make,
                                                                      expected):
    out = tmp_path / "out"
    SweepRunner(load_spec(spec_file, small_config), out).prepare(resume=False)
    path = result_file(out, 0)
    path.parent.mkdir()
    make(path)
    with pytest.raises(SweepResultsError, match=rf"^{re.escape(str(path))}: {expected}"):
        read_results(out)
    with pytest.raises(SweepResultsError, match=re.escape(str(path))):
        SweepRunner(load_spec(spec_file, small_config), out).prepare(resume=True)


def test_a_config_that_extends_another_sweeps_as_the_config_it_makes(tmp_path, small_config, spec_file):
    """Each task's config stands alone: the tables of what the base config extends merged in (the spec read the base
    config's own text, so a task's config held an ``extends`` relative to a folder it is not in)."""
    child = tmp_path / "child" / "child.toml"
    child.parent.mkdir()
    child.write_text(f'extends = "../{small_config.name}"\n\n[campaign]\nlearn_trials = 3\n')
    spec = load_spec(spec_file, child)
    text = spec.task_config(spec.draw(0))
    assert "extends =" not in text and "learn_trials = 3" in text and "learn_torques_nm" in text
    task = tmp_path / "elsewhere" / "task.toml"
    task.parent.mkdir()
    task.write_text(text)
    assert load_config(task).campaign.learn_trials == 3
