"""docs/real-bench.md runs: every command of the guide, in order, in an empty folder, with the simulated seed bench
standing in for the motor.

The stand-in: `ilcpmac emulate` of the small seed bench (1024 counts, the small campaign of campaign_helpers) is the
bench target at both the rehearsal's 127.0.0.1:5025 and "your bench" at 10.0.0.5:5025; ``configs/`` holds the seed
and real-bench configs made small the same way; the voltages of ``emf_log.csv``, the trials of ``my-bench``, the
logs ``run_2nm.csv``, ``run_4nm.csv``, the grid's logs without torque ``grid_log_*.csv`` and the standstill scan
``scan_log.csv`` (src/ilcpmac/sim/standstill.py) are simulated; the rolling log of the offline path is the guide's own
``ilcpmac simulate --kind log``. The guide's files (```python and ```toml blocks whose first line is ``# NAME``) are
written as shown, except ``counts_per_rev``, kept at the stand-in's; a second ``my-motor.toml`` block adds its keys
to the first. Only the commands of NOT_RUN are not run.

How they run: ``ilcpmac emulate`` as a process of this environment's console script (it serves until stopped);
``cp``, ``sed`` and any line with shell syntax (a redirection) through the shell; every other ``ilcpmac ...`` and
``python SCRIPT.py ...`` in this process (`run_in_process`). The console script is ``sys.exit(ilcpmac.cli.main())``
(checked) and python runs a script as ``__main__``: the same code on the same words, in the same folder and
environment, its exit status, stdout and stderr checked as a process's are. Only the interpreter's start-up and
imports (1-2 s a command, 20 of them) are not repeated.
"""

from __future__ import annotations

import contextlib
import dataclasses
import glob
import io
import json
import os
import re
import runpy
import select
import shlex
import shutil
import signal
import subprocess
import sys
import time
import tomllib
from importlib.metadata import entry_points
from pathlib import Path
from unittest import mock

import numpy as np
import pytest
from campaign_helpers import SMALL_CAMPAIGN, simulator_backend
from conftest import COUNTS_PER_REV, REAL_BENCH_CONFIG, SEED_CONFIG, toml_text

from ilcpmac.bench.format import write_backemf_csv
from ilcpmac.bench.importer import read_mapping
from ilcpmac.bench.standstill import SensorErrors
from ilcpmac.campaign.grid import grid_requests
from ilcpmac.cli import entry_point, main
from ilcpmac.config import load_config
from ilcpmac.model.tables import backemf_table
from ilcpmac.sim.simulator import Simulator
from ilcpmac.sim.standstill import ScanPlan, scan_log

GUIDE = Path(__file__).resolve().parents[1] / "docs" / "real-bench.md"
BIN = Path(sys.executable).parent
#: commands the test does not run, with the reason
NOT_RUN = {
    "python3 -m venv .venv && .venv/bin/pip install -e .": "installs the project; the test runs in its environment",
}
#: programs the guide's commands may start; a command starting another fails test_every_command_is_run_or_listed
PROGRAMS = {"ilcpmac", "python", "cp", "sed"}
#: the guide's bench addresses, all served by the one emulator
ADDRESSES = ("127.0.0.1:5025", "10.0.0.5:5025")
#: the guide's log layout (my-mapping.toml): 10 kHz rows, time in ms, a 16-bit single-turn position
LOG_RATE_HZ = 10_000.0
LOG_COUNTS_PER_REV = 2**16
LOG_HEADER = "t_ms,pos,ia_ref,ib_ref,ic_ref,torque_nm"
#: the imported logs: file -> (torque set point, N m; speed, Hz), as the guide's [[points]]
LOGS = {"run_2nm.csv": (2.0, 0.6), "run_4nm.csv": (4.0, 0.6)}
#: the logs without torque (encoder-mapping.toml): one per grid trial, a 24-bit position, the logger's 1 us clock
GRID_LOGS = "grid_log_*.csv"
ENCODER_LOG_COUNTS_PER_REV = 2**24
ENCODER_LOG_HEADER = "t_ms,pos,ia_ref,ib_ref,ic_ref"
#: the scan log (scan-mapping.toml): ms, the 16-bit position, the ramp's direction, the holding currents
SCAN_LOG_HEADER = "t_ms,pos,dir,ia_ref,ib_ref,ic_ref"
#: the guide's mapping files: each names the bench's counts per revolution once
MAPPINGS = ("my-mapping.toml", "encoder-mapping.toml", "scan-mapping.toml")
#: the open-circuit log: speed, Hz, and its slow ripple; duration, s; rate, Hz; voltage noise, V
EMF_SPEED_HZ, EMF_RIPPLE, EMF_DURATION_S, EMF_RATE_HZ, EMF_NOISE_V = 5.0, 0.003, 5.0, 20_000.0, 0.01
#: the fitted back-EMF table's largest error against the truth, relative to its peak (0.05 % measured)
BACKEMF_TOLERANCE = 2e-3
#: the logs without torque identified on the encoder: epsilon's relative error and the cogging's RMS error over its
#: RMS (1.6 % and 2.0 % measured on the stand-in's grid, 3 revolutions per trial), and the scan's cogging (0.23 %)
ENCODER_EPSILON_TOLERANCE, ENCODER_COGGING_TOLERANCE, SCAN_COGGING_TOLERANCE = 0.03, 0.04, 0.02
#: the offline path's rolling log (section 4e, simulated by the guide's own command): the identified position
#: torque's RMS error over the truth's, within the analysed harmonics (0.11 % measured at 1024 counts)
ROLLING_TOLERANCE = 0.01
COMMAND_TIMEOUT_S = 300
#: characters of a command line that only a shell understands (redirections, pipes, quotes, variables, lists)
SHELL_SYNTAX = set("<>|&;$`'\"\\(){}")


@dataclasses.dataclass(frozen=True)
class Command:
    line: str
    error: str | None  # the error line the guide shows under it: the command must fail with it


@dataclasses.dataclass(frozen=True)
class File:
    name: str
    text: str


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def guide_steps(text: str) -> list[Command | File]:
    """The guide's ```sh commands and named ```python / ```toml files, in order."""
    steps: list[Command | File] = []
    for lang, body in re.findall(r"^```(\w+)\n(.*?)^```$", text, flags=re.M | re.S):
        lines = body.splitlines()
        if lang in ("python", "toml") and lines and re.fullmatch(r"# [\w.-]+", lines[0]):
            steps.append(File(lines[0][2:], body))
        elif lang == "sh":
            for line in filter(None, (raw.strip() for raw in lines)):
                if line.startswith("# error: "):
                    assert steps and isinstance(steps[-1], Command) and steps[-1].error is None, line
                    steps[-1] = Command(steps[-1].line, line[2:])
                elif not line.startswith("#"):
                    steps.append(Command(line, None))
    return steps


@pytest.fixture(scope="module")
def steps() -> list[Command | File]:
    return guide_steps(GUIDE.read_text())


def test_every_command_is_run_or_listed(steps):
    commands = [s.line for s in steps if isinstance(s, Command)]
    assert len(commands) >= 12
    assert set(NOT_RUN) <= set(commands), "NOT_RUN lists a command the guide no longer has"
    for line in commands:
        if line not in NOT_RUN:
            assert shlex.split(line)[0] in PROGRAMS, f"the test does not know how to run: {line}"
    files = {s.name for s in steps if isinstance(s, File)}
    assert files == {"fit_backemf.py", "probe_target.py", "excitation_tables.py", "my-motor.toml", *MAPPINGS,
                     "scan_errors.py"}


def test_the_guides_mappings_are_read_as_written(steps, seed_config, tmp_path):
    model = seed_config.model
    write_backemf_csv(tmp_path / "backemf.csv", backemf_table(model.winding, model.backemf, 4096))
    read = {}
    for name in MAPPINGS:
        (tmp_path / name).write_text(next(s for s in steps if isinstance(s, File) and s.name == name).text)
        read[name] = read_mapping(tmp_path / name)
        assert read[name].motor.counts_per_rev == 4096 and read[name].motor.inertia_kgm2 == 0.01056
    mapping, encoder, scan = (read[name] for name in MAPPINGS)
    assert mapping.layout.position_counts_per_rev == LOG_COUNTS_PER_REV and mapping.layout.torque == "torque_nm"
    assert mapping.points == LOGS
    assert encoder.layout.torque is None and encoder.layout.timer_resolution_s == 1e-6 and not encoder.points
    assert encoder.layout.position_counts_per_rev == ENCODER_LOG_COUNTS_PER_REV
    assert scan.layout.kind == "scan" and scan.layout.direction == "dir" and scan.layout.torque is None
    assert scan.layout.position_counts_per_rev == LOG_COUNTS_PER_REV


def test_scan_errors_writes_the_identifications_errors(steps, tmp_path):
    """scan_errors.py on a result without delta (identified on the encoder): the [scan] table it prints holds the
    result's epsilon, alpha, beta and their standard errors, and no torque_sensor_gain."""
    script = next(s for s in steps if isinstance(s, File) and s.name == "scan_errors.py")
    (tmp_path / "scan_errors.py").write_text(script.text)
    result = {"epsilon": 0.69, "epsilon_std": 0.004, "alpha": [0.8, 1.1, 1.1], "alpha_std": [0.002, 0.001, 0.001],
              "beta": [1.0, -0.5, -0.5], "beta_std": [0.01, 0.01, 0.02], "torque_sensor_gain": None,
              "torque_sensor_gain_std": None}
    (tmp_path / "result.json").write_text(json.dumps(result))
    done = subprocess.run([sys.executable, "scan_errors.py", "result.json"], cwd=tmp_path, capture_output=True,
                          text=True, timeout=COMMAND_TIMEOUT_S)
    assert done.returncode == 0, done.stderr
    errors = SensorErrors.parse(tomllib.loads(done.stdout)["scan"], "scan-mapping.toml", "scan")
    assert errors == SensorErrors(epsilon=0.69, epsilon_std=0.004, alpha=(0.8, 1.1, 1.1),
                                  alpha_std=(0.002, 0.001, 0.001), beta_a=(1.0, -0.5, -0.5),
                                  beta_std_a=(0.01, 0.01, 0.02))


def emf_log(path: Path, model) -> np.ndarray:
    """Open-circuit phase voltages e_p = K_p(theta) omega of ``model`` turned near EMF_SPEED_HZ with a slow speed
    ripple, noisy, against an integer encoder count, as fit_backemf.py reads them; returns the true table."""
    cpr, fine = model.encoder.counts_per_rev, 2**16
    k_fine = backemf_table(model.winding, model.backemf, fine)
    t = np.arange(int(EMF_DURATION_S * EMF_RATE_HZ)) / EMF_RATE_HZ
    omega = 2 * np.pi * EMF_SPEED_HZ * (1 + EMF_RIPPLE * np.sin(2 * np.pi * 0.7 * t))
    theta = 0.3 + np.cumsum(omega) / EMF_RATE_HZ
    at = theta / (2 * np.pi) * fine
    volts = np.stack([np.interp(at, np.arange(fine), k_fine[:, p], period=fine) for p in range(3)], 1) * omega[:, None]
    volts += np.random.default_rng(13).normal(0.0, EMF_NOISE_V, volts.shape)
    position = np.floor(theta / (2 * np.pi) * cpr)
    np.savetxt(path, np.column_stack([t, position, volts]), delimiter=",", fmt="%.9g", comments="",
               header="time_s,position_counts,v_a,v_b,v_c")
    return backemf_table(model.winding, model.backemf, cpr)


def test_fit_backemf_recovers_the_table(steps, small_model, tmp_path, write_config):
    """The guide's script on voltages with speed ripple and noise: the table and its harmonics against the truth."""
    script = next(s for s in steps if isinstance(s, File) and s.name == "fit_backemf.py")
    (tmp_path / "fit_backemf.py").write_text(script.text)
    truth = emf_log(tmp_path / "emf_log.csv", small_model)
    config = write_config({"bench": {"counts_per_rev": COUNTS_PER_REV}}, name="my-motor.toml")
    done = run_in_process(f"python fit_backemf.py emf_log.csv {config.name} backemf.csv", tmp_path)
    assert done.returncode == 0, done.stderr
    fitted = np.loadtxt(tmp_path / "backemf.csv", delimiter=",", skiprows=1)[:, 1:]
    assert np.abs(fitted - truth).max() < BACKEMF_TOLERANCE * np.abs(truth).max()
    printed = tomllib.loads(done.stdout.split("\n", 1)[1])["bench"]["backemf"]
    backemf = small_model.backemf
    scale = 1 + np.mean(backemf.asymmetry)  # the fit's asymmetry has mean 0
    assert np.allclose(printed["amplitudes_nm_per_a"][:4], np.array(backemf.amplitudes_nm_per_a) * scale, atol=2e-4)
    assert np.allclose(printed["phases_rad"][:4], backemf.phases_rad, atol=0.02)
    assert np.allclose(printed["asymmetry"], (1 + np.array(backemf.asymmetry)) / scale - 1, atol=1e-3)
    backwards = tmp_path / "backwards.csv"
    rows = np.loadtxt(tmp_path / "emf_log.csv", delimiter=",", skiprows=1)[:2000]
    np.savetxt(backwards, rows[::-1], delimiter=",", header="t,p,a,b,c", comments="")
    refused = run_in_process(f"python fit_backemf.py {backwards.name} {config.name} x.csv", tmp_path)
    assert refused.returncode != 0 and "runs backwards" in refused.stderr and not (tmp_path / "x.csv").exists()


# ---- the whole guide


class Stand:
    """The stand-in for the engineer's motor, folder and bench: the files the guide's placeholders name, made
    on first use, and the emulator serving the bench."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        (folder / "configs").mkdir()
        for base in (SEED_CONFIG, REAL_BENCH_CONFIG):
            data = tomllib.loads(base.read_text())
            for table, values in SMALL_CAMPAIGN.items():
                if table in data or base == SEED_CONFIG:
                    data.setdefault(table, {}).update(values)
            (folder / "configs" / base.name).write_text(toml_text(data))
        self.config = load_config(folder / "configs" / SEED_CONFIG.name)
        self.backend = simulator_backend(self.config)
        self.emulator: subprocess.Popen | None = None
        self.address: str | None = None
        self.makers = {"emf_log.csv": self.emf_log, "my-bench": self.my_bench, "run_2nm.csv": self.logs,
                       "run_4nm.csv": self.logs, GRID_LOGS: self.grid_logs, "scan_log.csv": self.scan_log}

    def emf_log(self) -> None:
        self.emf_truth = emf_log(self.folder / "emf_log.csv", self.config.model)

    def my_bench(self) -> None:
        """The engineer's logged trials: the simulated example bench without its truth."""
        shutil.copytree(self.folder / "example-bench", self.folder / "my-bench",
                        ignore=shutil.ignore_patterns("truth.json"))

    def logs(self) -> None:
        """Grid trials of the stand-in logged at LOG_RATE_HZ in the guide's layout."""
        requests = grid_requests(self.config, self.backend.describe().calibration, 11, 4)
        simulator = Simulator(self.config.model)
        for name, (torque, speed) in LOGS.items():
            request = next(r for r in requests if (r.torque_setpoint_nm, r.speed_setpoint_hz) == (torque, speed))
            write_log(self.folder / name, simulator.run_trial(request), LOG_COUNTS_PER_REV, LOG_HEADER)

    def grid_logs(self) -> None:
        """The grid of excitation_tables.py run on the stand-in, one log per trial without torque, a 24-bit
        position."""
        config = self.config
        requests = grid_requests(config, self.backend.describe().calibration, config.grid.seed, config.grid.revolutions)
        simulator = Simulator(config.model)
        for i, request in enumerate(requests, 1):
            write_log(self.folder / f"grid_log_{i:02d}.csv", simulator.run_trial(request),
                      ENCODER_LOG_COUNTS_PER_REV, ENCODER_LOG_HEADER)

    def scan_log(self) -> None:
        """A simulated scan with holding currents (one revolution each way, 4 samples per count at 1 kHz) in the
        guide's layout: the ramp's positions are whole 16-bit counts."""
        columns, self.scan_truth = scan_log(Simulator(self.config.model), ScanPlan(seed=5))
        position = columns["position"] * LOG_COUNTS_PER_REV / COUNTS_PER_REV
        assert np.array_equal(position, np.round(position))
        np.savetxt(self.folder / "scan_log.csv", np.column_stack(
            [columns["time"] * 1e3, position, columns["direction"], columns["i_a"], columns["i_b"], columns["i_c"]]),
            delimiter=",", fmt="%.10g", header=SCAN_LOG_HEADER, comments="")

    def write(self, file: File) -> None:
        """A file of the guide: a script as shown; the config's keys merged into the copied template and the
        mapping as shown, both at the stand-in's counts per revolution."""
        path = self.folder / file.name
        if file.name == "my-motor.toml":
            data = tomllib.loads(path.read_text())
            for table, values in tomllib.loads(file.text).items():
                for key, value in values.items():
                    if isinstance(value, dict):
                        data.setdefault(table, {}).setdefault(key, {}).update(value)
                    else:
                        data.setdefault(table, {})[key] = value
            if "backemf_file" in data["bench"]:  # it replaces the template's [bench.backemf], as the guide says
                data["bench"].pop("backemf", None)
            data["bench"]["counts_per_rev"] = COUNTS_PER_REV
            path.write_text(toml_text(data))
        elif file.name in MAPPINGS:
            text, n = re.subn(r"^counts_per_rev = 4096$", f"counts_per_rev = {COUNTS_PER_REV}", file.text, flags=re.M)
            assert n == 1, file.name
            path.write_text(text)
        else:
            path.write_text(file.text)

    def backemf_fitted(self) -> None:
        """The fitted table is the stand-in's within BACKEMF_TOLERANCE; then it becomes the very table the
        emulator serves, as a real target serves the backemf.csv it is given."""
        served = self.backend.describe().backemf_nm_per_a
        fitted = np.loadtxt(self.folder / "backemf.csv", delimiter=",", skiprows=1)[:, 1:]
        assert np.abs(fitted - self.emf_truth).max() < BACKEMF_TOLERANCE * np.abs(served).max()
        assert np.array_equal(self.emf_truth, served)
        write_backemf_csv(self.folder / "backemf.csv", served)

    def start_emulator(self, line: str) -> None:
        assert self.emulator is None and "--port 5025" in line
        self.emulator = subprocess.Popen(shlex.split(line.replace("--port 5025", "--port 0")), cwd=self.folder,
                                         env=environment(), stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                         text=True)
        deadline = time.monotonic() + 60
        while self.address is None:
            ready, _, _ = select.select([self.emulator.stdout], [], [], max(deadline - time.monotonic(), 0))
            assert ready, "the emulator did not say where it listens within 60 s"
            line = self.emulator.stdout.readline()
            assert line, "the emulator stopped"
            if line.startswith("listening on "):
                self.address = line.split()[-1]

    def stop(self) -> None:
        if self.emulator is not None:
            self.emulator.terminate()
            try:
                self.emulator.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.emulator.kill()
                self.emulator.wait()

    def run(self, command: Command) -> None:
        if command.line.startswith("ilcpmac emulate "):
            self.start_emulator(command.line)
            return
        for name, make in self.makers.items():
            if re.search(rf"(^|\s){re.escape(name)}(\s|$)", command.line) and not any(self.folder.glob(name)):
                make()
        line = command.line
        for address in ADDRESSES:
            line = line.replace(address, self.address or address)
        started = time.monotonic()
        if runs_in_process(line):
            done = run_in_process(line, self.folder)
        else:
            done = subprocess.run(line, shell=True, cwd=self.folder, env=environment(), capture_output=True,
                                  text=True, timeout=COMMAND_TIMEOUT_S)
        print(f"{time.monotonic() - started:6.1f} s  {line}")
        said = f"{command.line}\n{done.stdout[-3000:]}\n{done.stderr[-3000:]}"
        if command.error is None:
            assert done.returncode == 0, said
        else:
            pattern = ".*".join(re.escape(part) for part in command.error.split("..."))
            assert done.returncode == 2, said
            assert re.fullmatch(pattern, done.stderr.strip().splitlines()[-1]), said
        if command.line.startswith("python fit_backemf.py "):
            self.backemf_fitted()


def write_log(path: Path, trial, position_counts_per_rev: int, header: str) -> None:
    """``trial`` logged at LOG_RATE_HZ from two rows before its first count to two past its last (the importer
    leaves out the first and last row interval): time in ms, the single-turn position in whole counts of
    ``position_counts_per_rev`` (on at the end counts' speed beyond the trial), the current references and, if
    ``header`` names it, the torque."""
    start, stop = np.floor(trial.time_s[0] * LOG_RATE_HZ) - 1, np.ceil(trial.time_s[-1] * LOG_RATE_HZ) + 1
    t = np.arange(start, stop + 1) / LOG_RATE_HZ
    counts = np.interp(t, trial.time_s, trial.count)
    for end, neighbour, outside in ((0, 1, t < trial.time_s[0]), (-1, -2, t > trial.time_s[-1])):
        speed = (trial.count[end] - trial.count[neighbour]) / (trial.time_s[end] - trial.time_s[neighbour])
        counts[outside] = trial.count[end] + (t[outside] - trial.time_s[end]) * speed
    position = np.floor(counts * position_counts_per_rev / COUNTS_PER_REV) % position_counts_per_rev
    torque = (trial.torque_nm,) if header.endswith(",torque_nm") else ()
    values = [np.interp(t, trial.time_s, v) for v in (*trial.i_ref_a.T, *torque)]
    np.savetxt(path, np.column_stack([t * 1e3, position, *values]), delimiter=",", fmt="%.10g", header=header,
               comments="")


def runs_in_process(line: str) -> bool:
    """Whether `run_in_process` runs ``line``: ``ilcpmac ...`` or ``python SCRIPT.py ...``, no shell syntax but
    globs."""
    words = shlex.split(line)
    return not set(line) & SHELL_SYNTAX and (words[0] == "ilcpmac" or words[0] == "python" and
                                             len(words) > 1 and words[1].endswith(".py"))


class CommandTimeout(BaseException):
    """A command run in this process outlived COMMAND_TIMEOUT_S (no command's ``except Exception`` takes it)."""


@contextlib.contextmanager
def deadline(seconds: int):
    """Raise `CommandTimeout` in the main thread if the block runs longer than ``seconds``."""
    def time_out(signum, frame):
        raise CommandTimeout(f"still running after {seconds} s")

    previous = signal.signal(signal.SIGALRM, time_out)
    signal.alarm(seconds)
    try:
        yield
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)


def run_in_process(line: str, folder: Path) -> subprocess.CompletedProcess:
    """``line`` (`runs_in_process`) run in this process as its program runs it: ``ilcpmac``, the console script of
    this environment, is `entry_point`: `main`, then the process's end (which stays out); ``python`` runs the script
    as ``__main__``, its folder first on sys.path. The words as the shell splits them, globs expanded as the shell
    expands them (sorted; a pattern matching nothing stays as typed); in ``folder``, with `environment()` and
    sys.argv the words (all restored after); stdout and stderr captured; stopped after COMMAND_TIMEOUT_S. The exit
    status is the `SystemExit`'s as Python makes it one (None: 0; a message: printed to stderr, 1); any other
    exception escapes, failing the test as its traceback would."""
    words = []
    for word in shlex.split(line):
        matches = sorted(glob.glob(word, root_dir=folder)) if set(word) & set("*?[") else []
        words += matches or [word]
    program, *args = words
    argv = args if program == "python" else [str(BIN / "ilcpmac"), *args]
    stdout, stderr = io.StringIO(), io.StringIO()
    with mock.patch.dict(os.environ, environment(), clear=True), contextlib.chdir(folder), \
            mock.patch.object(sys, "argv", argv), mock.patch.object(sys, "path", [str(folder), *sys.path]), \
            contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr), deadline(COMMAND_TIMEOUT_S):
        try:
            if program == "python":
                runpy.run_path(args[0], run_name="__main__")
            else:
                main(args, prog_name="ilcpmac")
            code = 0
        except SystemExit as exit:
            code = 0 if exit.code is None else exit.code if isinstance(exit.code, int) else 1
            if not isinstance(exit.code, int | None):
                print(exit.code, file=sys.stderr)
    return subprocess.CompletedProcess(line, code, stdout.getvalue(), stderr.getvalue())


def environment() -> dict[str, str]:
    """The commands' environment: this interpreter's `python` and `ilcpmac` first on the path, plots off-screen."""
    return {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}", "MPLBACKEND": "Agg"}


@pytest.mark.slow
def test_the_guide_runs_top_to_bottom(steps, tmp_path):
    assert (BIN / "ilcpmac").exists() and (BIN / "python").exists()
    assert entry_points(group="console_scripts", name="ilcpmac")["ilcpmac"].load() is entry_point
    stand = Stand(tmp_path)
    try:
        for step in steps:
            if isinstance(step, File):
                stand.write(step)
            elif step.line not in NOT_RUN:
                stand.run(step)
    finally:
        stand.stop()
    grid = (tmp_path / "grid" / "grid.csv").read_text().splitlines()
    assert len(grid) == 1 + 4 and len(list((tmp_path / "grid").glob("excitation_*.csv"))) == 4
    truth = json.loads((tmp_path / "example-bench" / "truth.json").read_text())
    for result, tolerance in (("my-bench.json", 0.005), ("imported.json", 0.02)):  # 0.26 % and 0.02 % measured
        gain = json.loads((tmp_path / result).read_text())["total_system_gain"]
        assert abs(gain / truth["total_system_gain"] - 1) < tolerance, (result, gain, truth["total_system_gain"])
    encoder = json.loads((tmp_path / "encoder.json").read_text())
    assert encoder["torque_source"] == "encoder" and encoder["total_system_gain"] is None
    assert abs(encoder["epsilon"] / truth["epsilon"] - 1) < ENCODER_EPSILON_TOLERANCE, encoder["epsilon"]
    true_cogging = np.asarray(truth["cogging"]["torque"])
    assert rms(np.asarray(encoder["cogging"]["torque"]) - true_cogging) < ENCODER_COGGING_TOLERANCE * rms(true_cogging)
    scan = json.loads((tmp_path / "scan.json").read_text())
    true_cogging = np.asarray(stand.scan_truth["cogging"]["torque"])
    assert rms(np.asarray(scan["cogging"]["torque"]) - true_cogging) < SCAN_COGGING_TOLERANCE * rms(true_cogging)
    for run, source in (("rehearsal", "sensor"), ("first", "sensor"), ("encoder", "encoder")):
        summary = json.loads((tmp_path / "runs" / run / "summary.json").read_text())
        assert summary["identification"]["torque_source"] == source, run
        if run != "rehearsal":
            config = tomllib.loads((tmp_path / "runs" / run / "campaign.toml").read_text())
            assert config["stages"]["cogging"]["start_from"] == "scan.json", run
    rolling, rolling_truth = (json.loads((tmp_path / name).read_text()) for name in ("rolling.json",
                                                                                       "drive-sim/truth.json"))
    spectrum = np.fft.rfft(rolling_truth["position_torque"]["torque"])
    spectrum[len(rolling["diagnostics"]["acceleration"]["harmonics"]) + 1:] = 0.0
    true_position = np.fft.irfft(spectrum, COUNTS_PER_REV)
    position_error = np.asarray(rolling["position_torque"]["torque"]) - true_position
    assert rms(position_error) < ROLLING_TOLERANCE * rms(true_position)
    assert [p.name for p in (tmp_path / "moteus").iterdir()] == ["moteus_cogging.txt"]
    assert (tmp_path / "harmonics" / "harmonics.csv").is_file()
    assert (tmp_path / "runs" / "first" / "compensation.json").is_file()
    assert list((tmp_path / "runs" / "first" / "plots").glob("*.png"))
    assert sorted(p.name for p in (tmp_path / "fw").iterdir()) == ["ilcpmac_compensation.c", "ilcpmac_compensation.h"]
    assert not (tmp_path / "runs" / "refused").exists()
