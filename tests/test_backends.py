"""Backends are plugins: the entry-point group ilcpmac.backends, ``ilcpmac run --backend NAME``,
``ilcpmac backends``; the bench a backend describes is checked against the config's [bench]; the optional
progress reports reach the campaign through the guard."""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import pytest
from campaign_helpers import SMALL_CAMPAIGN, simulator_backend
from click.testing import CliRunner
from conftest import REAL_BENCH_CONFIG

from ilcpmac.backends.base import Backend, ProgressThrottle, report_progress_to
from ilcpmac.backends.guard import LimitGuard
from ilcpmac.backends.registry import BackendSetup, build_backend, installed_backends
from ilcpmac.backends.remote import RemoteBackend
from ilcpmac.bench.format import read_bench, write_backemf_csv
from ilcpmac.campaign.runner import CampaignPlan
from ilcpmac.cli import main
from ilcpmac.config import load_config
from ilcpmac.core.errors import BackendError, ConfigError

#: trials run by every `CountingBackend`, and whether it was closed
RUNS: dict[str, int] = {}


class CountingBackend:
    """A backend as a third party writes one: the simulator of the config, counting its trials."""

    max_parallel_trials = 1

    def __init__(self, setup: BackendSetup) -> None:
        self.simulator = simulator_backend(setup.config)
        RUNS.update(trials=0, closed=0)

    def describe(self):
        return self.simulator.describe()

    def run_trial(self, request):
        RUNS["trials"] += 1
        return self.simulator.run_trial(request)

    def close(self) -> None:
        RUNS["closed"] += 1


def counting(setup: BackendSetup) -> CountingBackend:
    """The simulator, counting its trials (tests)."""
    return CountingBackend(setup)


def not_a_backend(setup: BackendSetup) -> object:
    """Returns something that is no backend (tests)."""
    return object()


@pytest.fixture
def plugin(tmp_path, monkeypatch):
    """Install this module's factories as the entry points of a distribution "test-backends"."""
    dist = tmp_path / "site" / "test_backends_plugin-0.1.dist-info"
    dist.mkdir(parents=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: test-backends-plugin\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[ilcpmac.backends]\ncounting = test_backends:counting\n"
                                           "broken = test_backends:not_a_backend\n"
                                           "missing = test_backends_absent:factory\n")
    monkeypatch.syspath_prepend(str(tmp_path / "site"))


def test_the_built_in_backends_are_entry_points_and_implement_the_protocol(seed_config):
    found = installed_backends()
    assert {"sim", "remote"} <= set(found)
    assert found["sim"].distribution == found["remote"].distribution == "ilcpmac"
    assert isinstance(build_backend("sim", BackendSetup(seed_config)), Backend)
    assert isinstance(build_backend("remote", BackendSetup(seed_config, "127.0.0.1:9")), RemoteBackend)
    with pytest.raises(BackendError, match="--backend remote needs --address HOST:PORT"):
        build_backend("remote", BackendSetup(seed_config))


def test_the_simulator_refuses_an_address(seed_config):
    """Issue 34, item 14: ``ilcpmac run --address 127.0.0.1:5999`` without ``--backend remote`` ran the simulated
    campaign, exit 0, while the bench engineer believed the motor ran."""
    with pytest.raises(ConfigError, match=r"^--address 127.0.0.1:5999: the sim backend runs the simulator in this "
                                          r"process and takes no address; for a bench at that address give "
                                          r"--backend remote"):
        build_backend("sim", BackendSetup(seed_config, "127.0.0.1:5999"))
    done = CliRunner().invoke(main, ["run", "--address", "127.0.0.1:5999", "--out", "unused"])
    assert done.exit_code == 2 and done.output.count("error:") == 1 and "--backend remote" in done.output


def test_ilcpmac_backends_lists_each_with_its_description(plugin):
    done = CliRunner().invoke(main, ["backends"], env={"COLUMNS": "200"})
    assert done.exit_code == 0, done.output
    # as ilcpmac stages lists stages: the name and what it does, under it the factory and its distribution
    rows = {line.split()[0]: (line, below) for line, below in zip(done.output.splitlines(),
                                                                  done.output.splitlines()[1:])
            if line.startswith(" ") and line.split() and not line.startswith("  ")}
    assert "numba simulator of the config's [bench] and [simulator.*]" in rows["sim"][0]
    assert "(built-in)" in rows["sim"][1]
    assert "bench protocol" in rows["remote"][0]
    assert "counting its trials" in rows["counting"][0] and "test-backends-plugin" in rows["counting"][1]
    assert "fails to load: ModuleNotFoundError" in rows["missing"][0]


@pytest.mark.parametrize("name, message", [
    ("nosuch", r"--backend: no backend named 'nosuch' is installed \(installed: .*remote, sim"),
    ("broken", r"--backend broken: test_backends:not_a_backend returned a object, which lacks describe, "
               r"run_trial, close, max_parallel_trials of the Backend protocol"),
    ("missing", r"--backend missing: failed to load test_backends_absent:factory \(ModuleNotFoundError"),
])
def test_a_backend_that_is_not_there_or_broken_is_one_line(plugin, seed_config, name, message):
    with pytest.raises(ConfigError, match=message):
        build_backend(name, BackendSetup(seed_config))


@pytest.mark.slow
def test_a_backend_defined_in_the_tests_runs_a_campaign_through_the_cli(plugin, write_config, tmp_path):
    config = write_config(SMALL_CAMPAIGN)
    done = CliRunner().invoke(main, ["run", str(config), "--backend", "counting", "--out", str(tmp_path / "run")])
    assert done.exit_code == 0, done.output
    assert RUNS["trials"] == len(read_bench(tmp_path / "run").trials) > 4
    assert RUNS["closed"] == 1


def test_the_simulator_needs_the_simulated_truth(tmp_path):
    done = CliRunner().invoke(main, ["run", str(REAL_BENCH_CONFIG), "--out", str(tmp_path / "run")])
    assert done.exit_code == 2
    assert done.output.strip().startswith("error: ") and len(done.output.strip().splitlines()) == 1
    assert "real-bench.toml: no [simulator] tables: the simulator backend and ilcpmac emulate need" in done.output
    assert not (tmp_path / "run").exists()


def test_python_dash_m_runs_the_packaged_config_from_any_folder(tmp_path):
    """No CONFIG: the packaged seed bench is read wherever the command runs (it then stops at the backend)."""
    done = subprocess.run([sys.executable, "-m", "ilcpmac", "run", "--backend", "nosuch", "--out", "run"],
                          cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 2, done.stderr
    assert done.stderr.startswith("error: --backend: no backend named 'nosuch'"), done.stderr
    assert not (tmp_path / "run").exists()


# ------------------------------------------------------------------ the bench against [bench]


@pytest.fixture(scope="module")
def small(seed_config):
    """The small campaign's config (1024 counts) and its simulator's description."""
    bench = dataclasses.replace(seed_config.bench, counts_per_rev=1024)
    model = dataclasses.replace(seed_config.model, encoder=dataclasses.replace(seed_config.model.encoder,
                                                                               counts_per_rev=1024))
    cfg = dataclasses.replace(seed_config, bench=bench, model=model,
                              excitation=dataclasses.replace(seed_config.excitation, harmonics=100),
                              campaign=dataclasses.replace(seed_config.campaign, ripple_harmonics=100))
    return cfg, simulator_backend(cfg).describe()


@pytest.mark.parametrize("changes, message", [
    ({"pole_pairs": 4}, r"\[bench\] pole_pairs 4 differs from the bench's 8"),
    ({"slots": 36}, r"\[bench\] slots 36 differs from the bench's 48"),
    ({"counts_per_rev": 2048}, r"\[bench\] counts_per_rev 2048 differs from the bench's 1024"),
    ({"inertia_kgm2": 0.02}, r"\[bench\] inertia_kgm2 0.02 differs from the bench's 0.01056"),
    ({"backemf": "amplitude"}, r"\[bench.backemf\] differs from the bench's back-EMF table by 0.00\d+ N m / A at "
                               r"count \d+, phase [abc]"),
    ({"calibration": "offset"}, r"\[bench.calibration\] current_offset_counts \[0.0, 0.5, 0.0\] differs from the "
                                r"bench's \[0.0, 0.0, 0.0\]"),
])
def test_a_bench_unlike_the_config_is_refused_before_any_trial(small, changes, message):
    cfg, description = small
    if changes.get("backemf"):
        emf = cfg.bench.backemf
        changes = {"backemf": dataclasses.replace(emf, amplitudes_nm_per_a=(0.201, *emf.amplitudes_nm_per_a[1:]))}
    if changes.get("calibration"):
        changes = {"calibration": dataclasses.replace(cfg.bench.calibration, current_offset_counts=(0.0, 0.5, 0.0))}
    with pytest.raises(ConfigError, match=message):
        CampaignPlan.build(dataclasses.replace(cfg, bench=dataclasses.replace(cfg.bench, **changes)), description, 1)


def test_the_grid_takes_the_calibration_of_the_bench(small):
    """The bench's calibration, not the config's (a bench without [bench.calibration] has only its own)."""
    cfg, description = small
    theirs = dataclasses.replace(description.calibration, current_offset=np.array([1.0, 2.0, 3.0]))
    plan = CampaignPlan.build(dataclasses.replace(cfg, bench=dataclasses.replace(cfg.bench, calibration=None)),
                              dataclasses.replace(description, calibration=theirs), 1)
    assert all(r.calibration is theirs for r in plan.grid)


def test_a_back_emf_file_is_checked_against_the_bench(small, tmp_path):
    """[bench] backemf_file: the bench's own table passes; a table 1 % off in phase b is refused, naming the file."""
    cfg, description = small
    cfg = dataclasses.replace(cfg, path=tmp_path / "campaign.toml")
    with_file = dataclasses.replace(cfg, bench=dataclasses.replace(cfg.bench, backemf=None, backemf_file="k.csv"))
    write_backemf_csv(tmp_path / "k.csv", description.backemf_nm_per_a)
    CampaignPlan.build(with_file, description, 1)
    write_backemf_csv(tmp_path / "k.csv", description.backemf_nm_per_a * [1.0, 1.01, 1.0])
    with pytest.raises(ConfigError, match=r"\[bench\] backemf_file k.csv differs from the bench's back-EMF table "
                                          r"by 0.00\d+ N m / A at count \d+, phase b"):
        CampaignPlan.build(with_file, description, 1)


def test_a_back_emf_given_twice_is_refused(write_config):
    config = write_config({"bench": {"backemf_file": "k.csv"}})
    with pytest.raises(ConfigError, match=r"\[bench\] backemf_file and \[bench.backemf\] both give the back-EMF"):
        load_config(config)


# ------------------------------------------------------------------ progress within a trial


class Reporting(CountingBackend):
    """A backend with the optional progress capability: it keeps what `set_progress` gives it."""

    def __init__(self, setup: BackendSetup) -> None:
        super().__init__(setup)
        self.callbacks: list = []

    def set_progress(self, callback) -> None:
        self.callbacks.append(callback)


def test_the_guard_forwards_progress_to_a_backend_that_reports_it(small):
    cfg, description = small
    inner = Reporting(BackendSetup(cfg))
    guard = LimitGuard(inner, description, CampaignPlan.build(cfg, description, 1).limits)
    fractions: list[float] = []
    report_progress_to(guard, fractions.append)
    guard.set_progress(None)
    assert inner.callbacks == [fractions.append, None]


def test_a_backend_without_progress_runs_unchanged_behind_the_guard(small):
    cfg, description = small
    plan = CampaignPlan.build(cfg, description, 1)
    guard = LimitGuard(simulator_backend(cfg), description, plan.limits)
    fractions: list[float] = []
    report_progress_to(guard, fractions.append)
    trial = guard.run_trial(plan.grid[0])
    assert fractions == [] and not hasattr(guard.backend, "set_progress")
    assert np.array_equal(trial.torque_nm, simulator_backend(cfg).run_trial(plan.grid[0]).torque_nm)


def test_the_progress_throttle_passes_a_fraction_per_interval_and_every_start_and_end():
    now = [0.0]
    passed: list[float] = []
    throttle = ProgressThrottle(passed.append, interval_s=0.1, clock=lambda: now[0])
    for t, fraction in [(0.0, 0.0), (0.01, 0.1), (0.05, 0.2), (0.12, 0.3), (0.15, 0.4), (0.16, 1.0),
                        (0.17, 1.0), (0.18, 0.0), (0.19, 0.1), (0.30, 0.1), (0.31, 0.5)]:
        now[0] = t
        throttle(fraction)
    assert passed == [0.0, 0.3, 1.0, 0.0, 0.1]


def test_a_fine_encoder_is_recorded_at_the_derived_resolution_and_a_bench_that_records_every_count_says_so(
        write_config):
    """A 2^16-count encoder records 4096 counts per revolution (every 16th line): the simulator backend describes
    and runs them, the plan accepts them; a bench describing every count is refused naming the key."""
    from ilcpmac.backends.simulated import SimulatorBackend
    from ilcpmac.campaign.grid import grid_requests

    cfg = load_config(write_config({"bench": {"counts_per_rev": 2**16},
                                    "simulator.encoder": {"eccentricity_counts": 0.3}}))
    backend = SimulatorBackend.from_setup(BackendSetup(cfg))
    description = backend.describe()
    assert description.motor.counts_per_rev == 4096 == cfg.recorded_counts_per_rev()
    plan = CampaignPlan.build(cfg, description, 1)
    trial = backend.run_trial(dataclasses.replace(grid_requests(cfg, description.calibration, 1, 3)[0], seed=1))
    assert plan.grid[0].excitation_nm.shape == (4096,) and trial.count.max() < 3 * 4096 + 4096
    native = SimulatorBackend(cfg.simulated_model(), cfg.limits.bench_limits()).describe()
    with pytest.raises(ConfigError, match=r"\[bench\] counts_per_rev 65536 recorded at 4096 \(\[bench\] "
                                          r"record_counts_per_rev\) differs from the bench's 65536 \(it records "
                                          r"them: record_counts_per_rev = 65536\)"):
        CampaignPlan.build(cfg, native, 1)


def test_a_record_of_fewer_counts_than_the_lines_sampled_holds_count_means_and_says_so(write_config):
    """[bench] record_counts_per_rev 1024 of a 2^16-count encoder sampled at 4096 lines: the simulator records
    each count as the mean over 4 lines and its description says so; a bench recording the counts' edges, or
    means over other lines, is refused naming the key."""
    from ilcpmac.backends.simulated import SimulatorBackend
    from ilcpmac.campaign.grid import grid_requests

    cfg = load_config(write_config({"bench": {"counts_per_rev": 2**16, "record_counts_per_rev": 1024},
                                    "simulator.encoder": {"eccentricity_counts": 0.3}}))
    backend = SimulatorBackend.from_setup(BackendSetup(cfg))
    description = backend.describe()
    assert (description.motor.counts_per_rev, description.motor.lines_per_count) == (1024, 4)
    assert cfg.sampled_counts_per_rev() == 4096
    plan = CampaignPlan.build(cfg, description, 1)
    trial = backend.run_trial(dataclasses.replace(grid_requests(cfg, description.calibration, 1, 3)[0], seed=1))
    assert plan.grid[0].excitation_nm.shape == (1024,) and trial.count.max() == 3 * 1024 - 1
    for lines in (1, 2):
        other = dataclasses.replace(description, motor=dataclasses.replace(description.motor, lines_per_count=lines))
        with pytest.raises(ConfigError, match=rf"\[bench\] counts_per_rev 65536, recorded at 1024 counts as means "
                                              rf"over 4 lines each, differs from the bench's 1024 counts as means over "
                                              rf"{lines} lines each"):
            CampaignPlan.build(cfg, other, 1)


@pytest.mark.parametrize("name", ["sim", "remote"])
def test_a_backend_that_takes_no_options_refuses_a_misspelt_one_naming_the_key(write_config, tmp_path, name):
    """[backends.sim] or [backends.remote] holds nothing they read: a key there (a typo for another backend's, or
    an option the user believes they take) was ignored; now `ilcpmac run` stops on it before any motion."""
    import ilcpmac.campaign

    path = write_config({f"backends.{name}": {"adress": "localhost:1"}})
    with pytest.raises(ConfigError, match=rf"\[backends.{name}\] adress: the {name} backend takes no options"):
        ilcpmac.campaign.run(path, out=tmp_path / "run", backend=name, address="localhost:1" if name == "remote"
                             else None)
    assert not (tmp_path / "run").exists()
