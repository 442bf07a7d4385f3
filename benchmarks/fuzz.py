"""Hostile-input campaign: mutated bench folders, configs, arguments, drive logs, standstill scans and sweep
specs, protocol attacks both ways.

Run ``python benchmarks/fuzz.py [--quick] [--seed N]`` with the project's
virtualenv (on two shared cores 8 to 15 minutes for groups 1 to 3 below and
about 14 more for groups 4 to 6; ``--quick`` about a quarter; ``--only`` and
``--match`` pick cases). Everything is generated deterministically from the
seed in a temporary folder:

1. bench folders: a small simulated bench (2 x 2 set points, 2 revolutions:
   one ``ilcpmac identify`` takes about 2 s) copied and mutated, each copy run
   as ``ilcpmac identify DIR --output OUT.json``;
2. configs and arguments: configs/seed-bench.toml reduced the same way and
   mutated, run as ``ilcpmac simulate`` (drive, grid and excitation keys) or
   ``ilcpmac run --trials 1`` (campaign, limits, pipeline and stage keys);
3. hostile clients against ``ilcpmac emulate`` and hostile targets answering
   ``RemoteBackend`` (benchmarks/fuzz_targets.py);
4. drive logs: two trials of the bench of 1. logged at 2 kHz as a drive logs
   them (phase currents, position in rad; and a q-axis log: ms, a wrapping
   16-bit position, ';', three header lines) with their mapping files, mutated
   and run as ``ilcpmac import LOG... --map MAPPING.toml --out DIR``;
5. standstill scans: the small config's drive scanned by
   ``ilcpmac.sim.standstill`` (holding currents and holding torque, one
   revolution each way, 4 rows per count), imported as scan folders, mutated
   and run as ``ilcpmac identify SCAN_DIR --output OUT.json``; and the scan
   logs imported under mutated ``[log] kind = "scan"`` mappings;
6. sweep specs: a two-task spec over the small config, mutated, and hostile
   arguments and sweep folders, run as ``ilcpmac sweep CONFIG --spec SPEC
   --out DIR --workers 1``. A spec must be refused before any cluster starts:
   a spec case is stopped (accepted) once the sweep prints that its tasks are
   ready, since a cluster and its tasks take longer than the fuzz waits;
7. stages (issue 27): the small campaign of tests/campaign_helpers.py with a
   broken plugin stage after the built-ins (fuzz_targets.BROKEN_STAGES: one
   that raises in its factory, shape, learn, state or columns, returns NaN or
   oversized columns, a state that is no JSON, NaN or 64 MiB, writes into its
   trial or request, raises SystemExit(0) or hangs, STAGE_CALL_S lowered to
   FUZZ_STAGE_CALL_S), run as ``ilcpmac run CONFIG --out DIR`` in the probe
   (below): one ``error: stage ...`` line, exit 2, every trial sent on disk;
8. resume tampering: a finished run of that campaign and one stopped at trial
   PARTIAL_AT, changed (epsilon / 3 and x 10 in states/identification.json, a
   NaN in a state, trial files swapped, a grid Parquet truncated, files
   deleted; and an edit resealed as the run seals it; issue 34: every seal
   removed, campaign.toml with higher [limits] or another learning grid, the
   seed edited in states/run.json, the finished run's trial and state, run.json
   or identification.json mixed in, a trial and its state copied over the
   next; and --seed, --trials, --budget, --out given with --resume), run as
   ``ilcpmac run --resume DIR`` in the probe: refused in one line before any
   trial;
9. import units and gaps: the drive logs of 4. with the time in ms read as s
   and in s read as ms, a gap of 10 s, a 1e300 N m or 1e5 A row (also between
   two counts, at 10 kHz), a ``#`` in a row, backemf_file at /etc/passwd,
   currents in mA and a torque in mN m (judged against the mapping's
   [limits]), logs in UTF-16, a moteus cogging file of the base bench's motor
   in mA, with a 9999 A bin, of zeros, constant, in UTF-16: one line naming
   the file, exit 2, nothing written and no *.tmp left; and ``ilcpmac
   identify`` on what its model does not describe (issue 34): a campaign's
   run directory (its grid identified, exit 0), the torque and i_ref_a
   swapped (with and without noise) and a folder without bench.toml (one
   line, nothing before it), a scan whose cogging order is beyond the counts'
   Nyquist limit (exit 0, saying so); never a Python or LAPACK warning;
10. sweep: ``--scheduler`` at TCP ports that are no Dask scheduler (HTTP,
   echo, silent, closing) and [magnets] out of range: one line, exit 2;
11. export tables: a run's compensation.json (in a copy of its run directory)
   and an identification's result.json with JSON ``true`` in a table,
   duplicate keys, NaN, 1e400, tables beyond their bounds and of the wrong
   shape, run as ``ilcpmac export``: one line naming the file, exit 2, nothing
   written; export bounds (issue 34): calibrations out of range, torque
   constants of 1e-300, 1e300, inf, tables of 1e5 N m or 3.3 x the run's
   max_correction_nm, of the wrong length, scales a C float cannot hold:
   refused the same way; source folders named ``x*/ ... /*``, ``run*`` or no
   UTF-8, an output folder named no UTF-8: written, the C compiling (gcc) and
   inert; and full-disk export, every format into an empty folder and over an
   earlier export, on a tmpfs with one page free (root; else an emulated full
   disk): one line naming the file, the folder as it was.

12. api arguments (issue 34): every function of ``ilcpmac.api`` called with
   arguments of the wrong type (True or 1.5 for an integer, "no" for a bool,
   NaN, inf and strings for numbers, an empty list of logs, unknown choices,
   NUL and bytes in paths, garbage config changes, options of the wrong type),
   each in a Python process whose wrapper prints an `IlcpmacError` as its
   ``error:`` lines and exits 2 (anything else is a traceback): one line naming
   the argument, exit 2, nothing written; and numpy numbers taken as the
   builtin ones (a campaign, a simulated bench and scan, a config): exit 0.

13. lying values (issue 34): the small campaign of 7. with a stage whose
   answer lies to the checks (a float subclass for the speed or the set point
   and an int subclass for the revolutions that claim harmless values to every
   comparison and arithmetic operator; ndarray subclasses claiming other values
   to every ufunc for the feed-forward and the current scales; current scales
   the stage keeps and triples from a thread during the trial), run in the
   probe, which reads what the simulator received as the values hold them:
   refused in one line naming the stage, or run within every limit.

Groups 7 to 11 take about 4 minutes on two shared cores. The probe
(``python benchmarks/fuzz_targets.py probe ... -- ARGS``, fuzz_targets.probe_main)
runs ``ilcpmac ARGS`` as its executable does, with every simulated trial
counted and its true phase currents kept (and the broken stage installed).

Every subprocess gets TIMEOUT_S and an address-space cap (RLIMIT_AS of
MEMORY_CAP_BYTES); its peak RSS comes from wait4's rusage (the emulator's
from /proc VmHWM). At most JOBS subprocesses run at once. Each case declares
whether its input must be rejected, and ends as one of

- OK: exit 0 with finite output, or exit 2 with exactly one ``error:`` line;
- TRACEBACK: a traceback, an exit status other than 0 and 2, a signal, an
  exit 2 without exactly one ``error:`` line, or a dead emulator;
- HANG: no exit within TIMEOUT_S, twice (a hanging case is run again alone;
  for the emulator: a well-formed client no longer gets its DESCRIBE);
- NON-FINITE: NaN or Infinity in a JSON or CSV file written;
- ACCEPTED-GARBAGE: exit 0 (or an ACCEPT, DESCRIBE or open connection, or a
  sweep whose tasks are ready) on an input that must be rejected, or the
  contents of a file outside the bench folder echoed;
- LIMIT-BREACH: a trial (in the probe) whose true phase current passed
  [limits] max_current_a by more than BREACH_TOLERANCE_A, or whose speed,
  torque reference or duration, as the simulator received them, passed the
  limits;
- WRONG-STATE: a refusal that left the wrong files (a trial that ran missing
  from the run directory, a trial run on a changed one, an output or a *.tmp
  written) or whose error line names the wrong thing (`Run.problem`).

The targets are 0 of each but OK, and every process's peak RSS under PEAK_RSS_BOUND_MIB.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import fuzz_targets as ft  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
REAL_CONFIG = ROOT / "configs" / "real-bench.toml"
SEED_CONFIG = ROOT / "configs" / "seed-bench.toml"
TIMEOUT_S = 30.0
MEMORY_CAP_BYTES = 4 << 30
#: every case's process under this peak RSS: a small campaign (the stage and resume groups) peaks at about 280 MiB,
#: an import of 2^22 rows or an export of 4M table values a few hundred; 1 GiB is over 3x the largest expected, what
#: a laptop running a campaign beside other work can spare; a case above it grows with its hostile input
PEAK_RSS_BOUND_MIB = 1024
#: a trial's true phase current may pass [limits] max_current_a by this much, A (docs/safety.md: the current loop's
#: lag and the sensors' noise, 0.09 A measured at worst; tests/test_limits_property.py allows the same); beyond it is
#: a LIMIT-BREACH
BREACH_TOLERANCE_A = 0.25
JOBS = 2
#: written into files outside the bench folder; seeing it in any output means their contents leaked
SECRET = "SECRET-7f3a9c-do-not-echo"
OUTCOMES = ("OK", "TRACEBACK", "HANG", "NON-FINITE", "ACCEPTED-GARBAGE", "LIMIT-BREACH", "WRONG-STATE")
#: every case's environment; unbuffered, so that a case stopped at a line of its output (stop_at) sees it at once
_ENV = {**os.environ, "NO_COLOR": "1", "TERM": "dumb", "COLUMNS": "200", "PYTHONUNBUFFERED": "1"}


def _ilcpmac() -> str:
    local = Path(sys.executable).parent / "ilcpmac"
    return str(local) if local.exists() else shutil.which("ilcpmac") or "ilcpmac"


ILCPMAC = _ilcpmac()


# ---------------------------------------------------------------- running and classifying


@dataclass
class Run:
    """What one case did.

    code: exit status (negative: killed by that signal; None: a process still
    serving). accepted: the input was taken as valid. written: a file or
    folder the case wrote (scanned for NaN/Infinity). peak_current_a and
    limit_a: the largest true phase current of any trial that ran and
    [limits] max_current_a (a case run in the probe; nan: no trial ran).
    breach: a speed, torque reference or duration beyond the limits that the
    simulator received, in the values the request held (the probe).
    problem: what the case found wrong in what was left (a trial that ran
    missing from the run directory, a file written or a *.tmp left by a
    refused input, an error line that names the wrong thing).
    """

    code: int | None
    timed_out: bool
    text: str
    peak_rss_kib: int
    accepted: bool
    written: Path | None = None
    seconds: float = 0.0
    peak_current_a: float | None = None
    limit_a: float | None = None
    problem: str | None = None
    breach: str | None = None


@dataclass(frozen=True)
class Case:
    """One hostile input: ``run(folder)`` executes it in its own empty ``folder``."""

    category: str
    name: str
    must_reject: bool
    run: Callable[[Path], Run]


@dataclass
class Verdict:
    case: Case
    outcome: str
    detail: str
    peak_rss_kib: int
    seconds: float


def run_process(argv: list[str], folder: Path, written: Path | None = None, cwd: Path = ROOT,
                stop_at: bytes | None = None) -> Run:
    """Run ``argv`` with the time and memory caps; stdout and stderr go to files in ``folder``.

    With ``stop_at``, the process is killed as soon as its output holds that text: the input was accepted
    (code None), and what would follow is not waited for.
    """
    start = time.monotonic()
    with open(folder / "stdout", "wb") as fo, open(folder / "stderr", "wb") as fe:
        proc = subprocess.Popen(argv, cwd=cwd, stdout=fo, stderr=fe, stdin=subprocess.DEVNULL, env=_ENV,
                                preexec_fn=ft.limit_memory(MEMORY_CAP_BYTES), start_new_session=True)
    timed_out = stopped = False
    while True:
        pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
        if pid:
            break
        stopped = stop_at is not None and any(stop_at in (folder / name).read_bytes() for name in ("stdout", "stderr"))
        timed_out = time.monotonic() - start > TIMEOUT_S
        if stopped or timed_out:
            os.killpg(proc.pid, signal.SIGKILL)
            pid, status, usage = os.wait4(proc.pid, 0)
            break
        time.sleep(0.02)
    proc.returncode = None if stopped else os.waitstatus_to_exitcode(status)
    try:
        os.killpg(proc.pid, signal.SIGKILL)  # nothing the case started outlives it
    except OSError:
        pass
    text = ((folder / "stdout").read_bytes()[-200_000:] + b"\n"
            + (folder / "stderr").read_bytes()[-200_000:]).decode("utf-8", "replace")
    return Run(proc.returncode, timed_out, text, usage.ru_maxrss, stopped or proc.returncode == 0, written,
               time.monotonic() - start)


def ilcpmac(*args, folder: Path, written: Path | None = None, stop_at: bytes | None = None) -> Run:
    return run_process([ILCPMAC, *map(str, args)], folder, written, stop_at=stop_at)


_NON_FINITE = re.compile(rb"(?i)(?<![\w.])(nan|-?inf|-?infinity)(?![\w.])")


def non_finite(path: Path | None) -> str | None:
    """The first JSON or CSV file under ``path`` that holds NaN or Infinity (relative name), or None."""
    if path is None or not path.exists():
        return None
    files = [path] if path.is_file() else sorted(p for p in path.rglob("*") if p.suffix in (".json", ".csv"))
    for f in files:
        if f.is_file() and f.stat().st_size < 500_000_000 and _NON_FINITE.search(f.read_bytes()):
            return f.name
    return None


def _error_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.lower().startswith("error:")]


def _traceback_line(text: str) -> str:
    """The exception line of the last traceback in ``text``."""
    tail = text[text.rfind("Traceback"):].splitlines()
    for line in tail[1:]:  # the first unindented "module.Name: message" after the frames
        if re.match(r"[A-Za-z_][\w.]*(: |$)", line):
            return line.strip()
    return next((line.strip() for line in reversed(tail) if line.strip()), "Traceback")


_SCRATCH = re.compile(re.escape(tempfile.gettempdir()) + r"/ilcpmac-fuzz-[^/\s]+/(case-[^/\s]+/)?")


def classify(case: Case, run: Run) -> tuple[str, str]:
    """(outcome, one line saying why, scratch paths left out) for a case and what it did."""
    outcome, detail = _classify(case, run)
    return outcome, _SCRATCH.sub("", detail)


def _classify(case: Case, run: Run) -> tuple[str, str]:
    if run.peak_current_a is not None and run.peak_current_a > run.limit_a + BREACH_TOLERANCE_A:
        return "LIMIT-BREACH", f"a true phase current of {run.peak_current_a:.3g} A, [limits] {run.limit_a:g} A"
    if run.breach is not None:
        return "LIMIT-BREACH", run.breach
    if run.timed_out:
        if run.code is None:
            return "HANG", run.text.strip().splitlines()[-1][:200]
        return "HANG", f"no exit within {TIMEOUT_S:g} s"
    if "Traceback" in run.text:
        return "TRACEBACK", _traceback_line(run.text)[:200]
    if run.code is not None and run.code < 0:
        return "TRACEBACK", f"killed by {signal.Signals(-run.code).name}"
    if run.code is not None and run.code not in (0, 2):
        last = [line for line in run.text.splitlines() if line.strip()]
        return "TRACEBACK", f"exit {run.code}: {last[-1][:180] if last else ''}"
    errors = _error_lines(run.text)
    if run.code == 2 and len(errors) != 1:
        return "TRACEBACK", f"exit 2 with {len(errors)} error: lines"
    if SECRET in run.text:
        return "ACCEPTED-GARBAGE", "echoed the contents of a file outside the bench folder"
    bad = non_finite(run.written)
    if bad:
        return "NON-FINITE", f"NaN or Infinity in {bad}"
    if run.accepted and case.must_reject:
        return "ACCEPTED-GARBAGE", run.text.strip().splitlines()[-1][:200] if run.code is None else "exit 0"
    if run.problem is not None:
        return "WRONG-STATE", run.problem[:200]
    if errors or run.code is not None:
        return "OK", errors[0][:200] if errors else ""
    return "OK", run.text.strip().splitlines()[-1][:200]


def execute(case: Case, scratch: Path) -> Verdict:
    folder = Path(tempfile.mkdtemp(dir=scratch, prefix="case-"))
    try:
        run = case.run(folder)
    except Exception as e:  # a failure of the fuzz itself: reported, never hidden
        return Verdict(case, "TRACEBACK", f"in the fuzz harness: {type(e).__name__}: {e}", 0, 0.0)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return Verdict(case, *classify(case, run), run.peak_rss_kib, run.seconds)


# ---------------------------------------------------------------- text helpers


def toml_set(text: str, table: str, key: str, value: str | None) -> str:
    """``text`` with ``key = value`` in ``[table]`` (``trials.K``: the K-th [[trials]]); None deletes the key.

    A key the table lacks is added under its header.
    """
    lines = text.splitlines()
    name, _, index = table.partition(".") if table.startswith("trials.") else (table, "", "")
    headers = [i for i, line in enumerate(lines) if line.strip().split("#")[0].strip() in
               (f"[{name}]", f"[[{name}]]")]
    if not headers:
        raise KeyError(f"no table [{table}]")
    start = headers[int(index) if index else 0]
    end = next((i for i in range(start + 1, len(lines)) if lines[i].lstrip().startswith("[")), len(lines))
    for i in range(start + 1, end):
        if re.match(rf"\s*{re.escape(key)}\s*=", lines[i]):
            if value is None:
                del lines[i]
            else:
                lines[i] = f"{key} = {value}"
            return "\n".join(lines) + "\n"
    if value is not None:
        lines.insert(start + 1, f"{key} = {value}")
    return "\n".join(lines) + "\n"


def edit(path: Path, fn: Callable[[str], str]) -> None:
    path.write_text(fn(path.read_text()))


def read_csv(path: Path) -> tuple[list[str], list[list[str]]]:
    lines = path.read_text().splitlines()
    return lines[0].split(","), [line.split(",") for line in lines[1:]]


def write_csv(path: Path, header: list[str], rows: list[list[str]]) -> None:
    path.write_text("\n".join([",".join(header), *(",".join(r) for r in rows)]) + "\n")


# ---------------------------------------------------------------- 1. bench folders

TRIALS = ("trial_01.csv", "trial_02.csv", "trial_03.csv", "trial_04.csv")
T1 = TRIALS[0]


def bench_toml(d: Path, table: str, key: str, value: str | None) -> None:
    edit(d / "bench.toml", lambda t: toml_set(t, table, key, value))


def column(name: str, fn: Callable[[np.ndarray], np.ndarray], files=(T1,)) -> Callable:
    """A mutation replacing column ``name`` of trial files by ``fn(values)`` (as %.10g text)."""
    def mutate(d: Path, rng) -> None:
        for f in files:
            header, rows = read_csv(d / f)
            j = header.index(name)
            values = fn(np.array([float(r[j]) for r in rows]))
            for r, v in zip(rows, values):
                r[j] = f"{v:.10g}" if name != "count" or not float(v).is_integer() else str(int(v))
            write_csv(d / f, header, rows)
    return mutate


def rows_edit(fn: Callable[[list[str], list[list[str]]], tuple], file: str = T1) -> Callable:
    def mutate(d: Path, rng) -> None:
        header, rows = read_csv(d / file)
        write_csv(d / file, *fn(header, rows))
    return mutate


def cell(row: int, name: str, text: str, file: str = T1) -> Callable:
    def fn(header, rows):
        rows[row][header.index(name)] = text
        return header, rows
    return rows_edit(fn, file)


def raw(file: str, fn: Callable[[bytes], bytes]) -> Callable:
    def mutate(d: Path, rng) -> None:
        (d / file).write_bytes(fn((d / file).read_bytes()))
    return mutate


def key(table: str, name: str, value: str | None) -> Callable:
    return lambda d, rng: bench_toml(d, table, name, value)


STATIC_HEADER = "count,i_ref_a,i_ref_b,i_ref_c,torque"


def static_trial(rows: list[str] | None, file: str = "static.csv", table: str | None = None) -> Callable:
    """A mutation giving the bench a static trial: bench.toml's [static] (``table``: its text instead) naming
    ``file``, written with ``rows`` under the static trial's header (None: not written)."""
    def mutate(d: Path, rng) -> None:
        edit(d / "bench.toml", lambda t: t.replace("[[trials]]", (table or f'[static]\nfile = "{file}"\n') +
                                                   "\n[[trials]]", 1))
        if rows is not None:
            (d / file).write_text("\n".join([STATIC_HEADER, *rows]) + "\n")
    return mutate


def _secret(d: Path) -> Path:
    """A file outside the bench folder whose contents must never be read out."""
    path = d.parent / "secret.csv"
    path.write_text(f"{SECRET},k_a,k_b,k_c\n{SECRET},1,2,3\n")
    return path


def _outside_copy(d: Path) -> Path:
    """A valid trial outside the folder: accepted only if the path escape is followed."""
    path = d.parent / "outside.csv"
    shutil.copy(d / T1, path)
    return path


def _swap_headers(a: str, b: str) -> Callable:
    def fn(header, rows):
        i, j = header.index(a), header.index(b)
        header[i], header[j] = header[j], header[i]
        return header, rows
    return rows_edit(fn)


def _fifo_file(name: str) -> Callable:
    def mutate(d: Path, rng) -> None:
        (d / name).unlink()
        os.mkfifo(d / name)
    return mutate


def _symlink(target: str | Callable[[Path], Path], file: str = T1) -> Callable:
    def mutate(d: Path, rng) -> None:
        pointee = target(d) if callable(target) else target
        (d / file).unlink()
        (d / file).symlink_to(pointee)
    return mutate


def _sparse(name: str, size_bytes: int) -> Callable:
    """File ``name`` grown to ``size_bytes`` without writing them (a sparse file)."""
    def mutate(d: Path, rng) -> None:
        with open(d / name, "r+b") as f:
            f.truncate(size_bytes)
    return mutate


def _directory(name: str) -> Callable:
    def mutate(d: Path, rng) -> None:
        (d / name).unlink()
        (d / name).mkdir()
    return mutate


def _remove(name: str) -> Callable:
    return lambda d, rng: (d / name).unlink()


def _cpr(cpr: int) -> Callable:
    """counts_per_rev changed with a back-EMF table of that many rows; the trial data stay at 4096."""
    def mutate(d: Path, rng) -> None:
        header, rows = read_csv(d / "backemf.csv")
        rows = [[str(i), *rows[i * len(rows) // cpr][1:]] for i in range(cpr)]
        write_csv(d / "backemf.csv", header, rows)
        bench_toml(d, "motor", "counts_per_rev", str(cpr))
    return mutate


def _dotted_twice(d: Path, rng) -> None:
    edit(d / "bench.toml", lambda t: t + '\n[[trials]]\nfile = "./trial_01.csv"\ntorque_setpoint = 1.0\n'
                                          'speed_setpoint = 0.8\n')


def _listed_twice(d: Path, rng) -> None:
    edit(d / "bench.toml", lambda t: t + '\n[[trials]]\nfile = "trial_01.csv"\ntorque_setpoint = 1.0\n'
                                          'speed_setpoint = 0.8\n')


def _only_trials(n: int) -> Callable:
    def mutate(d: Path, rng) -> None:
        text = (d / "bench.toml").read_text()
        head, *entries = text.split("[[trials]]")
        (d / "bench.toml").write_text(head + "".join("[[trials]]" + e for e in entries[:n]))
    return mutate


def _rename(new: str) -> Callable:
    def mutate(d: Path, rng) -> None:
        (d / T1).rename(d / new)
        bench_toml(d, "trials.0", "file", f'"{new}"')
    return mutate


def _both(*mutations: Callable) -> Callable:
    def mutate(d: Path, rng) -> None:
        for m in mutations:
            m(d, rng)
    return mutate


def _zero_i_ref(d: Path, rng) -> None:
    for ph in "abc":
        column(f"i_ref_{ph}", np.zeros_like, TRIALS)(d, rng)


def _duplicate_row(header, rows):
    return header, rows[:50] + [rows[49]] + rows[50:]


def _swap_rows(header, rows):
    rows[10], rows[11] = rows[11], rows[10]
    return header, rows


#: (name, must be rejected, mutation(folder, rng)) of the structured bench mutations
BENCH_MUTATIONS: list[tuple[str, bool, Callable]] = [
    # time stamps
    ("time reversed", True, column("time", lambda t: t[::-1])),
    ("time scaled by 1e9", True, column("time", lambda t: t * 1e9)),
    ("time scaled by 1e-9", True, column("time", lambda t: t * 1e-9)),
    ("time in ms (x1000)", True, column("time", lambda t: t * 1e3)),
    ("time constant", True, column("time", lambda t: np.full_like(t, 1.5))),
    ("time and torque headers swapped", True, _swap_headers("time", "torque")),
    ("time of trial 4 in trial 1", False, lambda d, rng: column(
        "time", lambda t: np.array([float(r[1]) for r in read_csv(d / TRIALS[3])[1]]))(d, rng)),
    ("time with one backward step", True, cell(100, "time", "0.0")),
    # torque and currents
    ("torque constant", True, column("torque", lambda t: np.full_like(t, 1.0), TRIALS)),
    ("torque all zero", True, column("torque", np.zeros_like, TRIALS)),
    ("torque 1e300 in one row", True, cell(7, "torque", "1e300")),
    ("torque 1e308 everywhere", True, column("torque", lambda t: np.full_like(t, 1e308))),
    ("i_ref all zero", True, _zero_i_ref),
    ("i_ref scaled by 1e6", True, column("i_ref_a", lambda t: t * 1e6)),
    ("i_ref phases a and b swapped", False, _swap_headers("i_ref_a", "i_ref_b")),
    # counts
    ("count gap of 10^15", True, column("count", lambda c: c + (np.arange(c.size) >= 4000) * 1e15)),
    ("count gap of 2^62", True, column("count", lambda c: c + (np.arange(c.size) >= 4000) * 2.0**62)),
    ("count starting at -2^62", False, column("count", lambda c: c - 2.0**62)),
    ("count rows swapped", True, rows_edit(_swap_rows)),
    ("count duplicated row", True, rows_edit(_duplicate_row)),
    ("count 1.5", True, cell(20, "count", "1.5")),
    ("count every other (skips)", False, rows_edit(lambda h, r: (h, r[::2]))),
    ("count and time headers swapped", True, _swap_headers("count", "time")),
    ("count as hex 0x10", True, cell(20, "count", "0x10")),
    # non-finite and malformed cells
    ("NaN torque", True, cell(300, "torque", "nan")),
    ("inf i_ref_b", True, cell(301, "i_ref_b", "inf")),
    ("-inf time", True, cell(302, "time", "-inf")),
    ("NaN count", True, cell(303, "count", "NaN")),
    ("empty field", True, cell(304, "torque", "")),
    ("text field", True, cell(305, "torque", "abc")),
    ("extra field in a row", True, rows_edit(lambda h, r: (h, r[:5] + [r[5] + ["1"]] + r[6:]))),
    ("missing field in a row", True, rows_edit(lambda h, r: (h, r[:5] + [r[5][:-1]] + r[6:]))),
    # header
    ("header missing torque", True, rows_edit(lambda h, r: ([x if x != "torque" else "torq" for x in h], r))),
    ("header duplicated column", True, rows_edit(lambda h, r: ([x if x != "i_meas_a" else "time" for x in h], r))),
    ("header with a BOM", False, raw(T1, lambda b: b"\xef\xbb\xbf" + b)),
    ("header upper case", False, raw(T1, lambda b: b.split(b"\n", 1)[0].upper() + b"\n" + b.split(b"\n", 1)[1])),
    ("header only", True, raw(T1, lambda b: b.split(b"\n", 1)[0] + b"\n")),
    ("one data row", True, raw(T1, lambda b: b"\n".join(b.split(b"\n")[:2]) + b"\n")),
    ("empty trial file", True, raw(T1, lambda b: b"")),
    ("binary trial file", True, raw(T1, lambda b: bytes(range(256)) * 64)),
    ("CRLF line endings", False, raw(T1, lambda b: b.replace(b"\n", b"\r\n"))),
    ("columns reordered", False, rows_edit(lambda h, r: (h[::-1], [x[::-1] for x in r]))),
    ("extra unknown column", False, rows_edit(lambda h, r: (h + ["note"], [x + ["0"] for x in r]))),
    ("10 MB single line", True, raw(T1, lambda b: b.split(b"\n", 1)[0] + b"\n" + b"1" * 10_000_000 + b"\n")),
    ("trial concatenated twice", True, raw(T1, lambda b: b + b.split(b"\n", 1)[1])),
    # files that are not regular files, and paths
    ("trial is a FIFO", True, _fifo_file(T1)),
    ("trial symlink to /dev/zero", True, _symlink("/dev/zero")),
    ("trial 2 GiB sparse file", True, _sparse(T1, 2 << 30)),
    ("trial is a directory", True, _directory(T1)),
    ("trial missing", True, _remove(T1)),
    ("trial absolute path outside the folder", True,
     lambda d, rng: bench_toml(d, "trials.0", "file", f'"{_outside_copy(d)}"')),
    ("trial ../ path outside the folder", True,
     lambda d, rng: bench_toml(d, "trials.0", "file", f'"../{_outside_copy(d).name}"')),
    ("trial symlink outside the folder", True, _symlink(_outside_copy)),
    ("trial absolute path to a secret", True, lambda d, rng: bench_toml(d, "trials.0", "file", f'"{_secret(d)}"')),
    ("backemf absolute path to a secret", True, lambda d, rng: bench_toml(d, "motor", "backemf_file",
                                                                          f'"{_secret(d)}"')),
    ("backemf symlink to a secret", True, _symlink(_secret, "backemf.csv")),
    ("backemf ../ path outside the folder", True, lambda d, rng: (
        shutil.copy(d / "backemf.csv", d.parent / "outside_backemf.csv"),
        bench_toml(d, "motor", "backemf_file", '"../outside_backemf.csv"'))),
    ("./trial_01.csv and trial_01.csv", True, _dotted_twice),
    ("trial listed twice", True, _listed_twice),
    ("file name with spaces and unicode", False, _rename("essai n° 1.csv")),
    ("file = '.'", True, key("trials.0", "file", '"."')),
    ("file = ''", True, key("trials.0", "file", '""')),
    ("file = 42", True, key("trials.0", "file", "42")),
    # back-EMF table
    ("backemf all zero", True, _both(*(column(k, np.zeros_like, ("backemf.csv",)) for k in ("k_a", "k_b", "k_c")))),
    ("backemf NaN", True, rows_edit(lambda h, r: (h, r[:3] + [[r[3][0], "nan", *r[3][2:]]] + r[4:]), "backemf.csv")),
    ("backemf header wrong", True, raw("backemf.csv", lambda b: b"count,ka,kb,kc" + b[b.index(b"\n"):])),
    ("backemf rows missing", True, raw("backemf.csv", lambda b: b"\n".join(b.split(b"\n")[:100]) + b"\n")),
    ("backemf counts shuffled", True, rows_edit(lambda h, r: (h, r[1:2] + r[:1] + r[2:]), "backemf.csv")),
    # [motor] and [sensors]
    ("counts_per_rev 2048 on 4096-count data", True, _cpr(2048)),
    ("counts_per_rev 8192 on 4096-count data", True, _cpr(8192)),
    ("counts_per_rev 0", True, key("motor", "counts_per_rev", "0")),
    ("counts_per_rev -1", True, key("motor", "counts_per_rev", "-1")),
    ("counts_per_rev 2^62", True, key("motor", "counts_per_rev", str(2**62))),
    ("inertia 1e300", True, key("motor", "inertia", "1e300")),
    ("inertia 0", True, key("motor", "inertia", "0.0")),
    ("inertia nan", True, key("motor", "inertia", "nan")),
    ("inertia as text", True, key("motor", "inertia", '"0.01"')),
    ("pole_pairs 10^6", True, key("motor", "pole_pairs", "1000000")),
    ("pole_pairs 0", True, key("motor", "pole_pairs", "0")),
    ("pole_pairs 2.5", True, key("motor", "pole_pairs", "2.5")),
    ("pole_pairs true", True, key("motor", "pole_pairs", "true")),
    ("slots 0", True, key("motor", "slots", "0")),
    ("slots 10^18", True, key("motor", "slots", str(10**18))),
    ("current_offset inf", True, key("sensors", "current_offset", "[inf, 0.0, 0.0]")),
    ("current_offset nan", True, key("sensors", "current_offset", "[nan, 0.0, 0.0]")),
    ("current_scale with a 0", True, key("sensors", "current_scale", "[0.0, 14.0, 14.0]")),
    ("current_scale 2 values", True, key("sensors", "current_scale", "[14.0, 14.0]")),
    ("torque_gain 0", True, key("sensors", "torque_gain", "0.0")),
    ("torque_gain 1e300", True, key("sensors", "torque_gain", "1e300")),
    ("[sensors] removed", False, lambda d, rng: edit(d / "bench.toml", lambda t: re.sub(
        r"\[sensors\][^\[]*", "", t))),
    # a static trial ([static], static.csv)
    ("static.csv outside the folder", True, lambda d, rng: static_trial(None, file=f"../{_secret(d).name}")(d, rng)),
    ("static.csv missing", True, static_trial(None)),
    ("[static] without file", True, static_trial(None, table="[static]\n")),
    ("[static] with an unknown key", True, static_trial(["10,1,0,-1,0.2", "10,2,0,-2,0.4"],
                                                        table='[static]\nfile = "static.csv"\ngain = 2\n')),
    ("static.csv count beyond the revolution", True, static_trial(["5000,1,0,-1,0.2", "5000,2,0,-2,0.4"])),
    ("static.csv count not whole", True, static_trial(["10.5,1,0,-1,0.2", "10,2,0,-2,0.4"])),
    ("static.csv torque nan", True, static_trial(["10,1,0,-1,nan", "10,2,0,-2,0.4"])),
    ("static.csv current 1e300", True, static_trial(["10,1e300,0,-1,0.2", "10,2,0,-2,0.4"])),
    ("static.csv header only", True, static_trial([])),
    ("static.csv one current per count", True, static_trial(["10,1,0,-1,0.2", "20,1,0,-1,0.2", "30,1,0,-1,0.2"])),
    ("static.csv binary garbage", True, lambda d, rng: (static_trial([])(d, rng), (d / "static.csv").write_bytes(
        bytes(np.random.default_rng(38).integers(0, 256, 4096, dtype=np.uint8))))),
    # [[trials]] set points
    ("torque_setpoint 0", True, key("trials.0", "torque_setpoint", "0.0")),
    ("torque_setpoint -1", True, key("trials.0", "torque_setpoint", "-1.0")),
    ("torque_setpoint 1e300", True, key("trials.0", "torque_setpoint", "1e300")),
    ("torque_setpoint nan", True, key("trials.0", "torque_setpoint", "nan")),
    ("speed_setpoint 0", True, key("trials.0", "speed_setpoint", "0.0")),
    ("speed_setpoint -0.8", True, key("trials.0", "speed_setpoint", "-0.8")),
    ("speed_setpoint 1e-9", True, key("trials.0", "speed_setpoint", "1e-9")),
    ("speed_setpoint 100 on 0.8 Hz data", True, key("trials.0", "speed_setpoint", "100.0")),
    ("set points swapped between trials", False, _both(key("trials.0", "torque_setpoint", "3.0"),
                                                        key("trials.2", "torque_setpoint", "1.0"))),
    ("only one trial listed", False, _only_trials(1)),
    ("no trials listed", True, _only_trials(0)),
    # bench.toml structure
    ("missing key inertia", True, key("motor", "inertia", None)),
    ("missing key backemf_file", True, key("motor", "backemf_file", None)),
    ("missing key torque_setpoint", True, key("trials.1", "torque_setpoint", None)),
    ("missing [motor]", True, lambda d, rng: edit(d / "bench.toml", lambda t: t.replace("[motor]", "[moto]"))),
    ("duplicated key pole_pairs", True, lambda d, rng: edit(d / "bench.toml", lambda t: t.replace(
        "[motor]", "[motor]\npole_pairs = 8"))),
    ("unknown key", True, key("motor", "polepairs", "8")),
    ("trials as a table", True, lambda d, rng: edit(d / "bench.toml", lambda t: t.replace(
        "[[trials]]", "[trials]", 1).replace("[[trials]]", "[trials2]"))),
    ("bench.toml binary", True, raw("bench.toml", lambda b: b"\xff\xfe\x00" + bytes(range(256)) * 8)),
    ("bench.toml UTF-16", True, raw("bench.toml", lambda b: b.decode().encode("utf-16"))),
    ("bench.toml nested 100000 deep", True, raw("bench.toml", lambda b: b + b"x = " + b"[" * 100_000
                                                + b"]" * 100_000 + b"\n")),
    ("bench.toml empty", True, raw("bench.toml", lambda b: b"")),
    ("bench.toml cut in a key", True, raw("bench.toml", lambda b: b[:b.index(b"inertia") + 4])),
    ("bench.toml missing", True, _remove("bench.toml")),
    ("bench.toml is a directory", True, _directory("bench.toml")),
    ("bench.toml symlink to /dev/zero", True, _symlink("/dev/zero", "bench.toml")),
]


def _random_bench_mutations(rng: np.random.Generator, n: int) -> list[tuple[str, bool, Callable]]:
    """Seeded random damage: byte flips, truncations, NaN/inf and huge values, column swaps, dropped rows."""
    out: list[tuple[str, bool, Callable]] = []
    columns = ["count", "time", "i_ref_a", "i_ref_b", "i_ref_c", "torque"]
    for k in range(n):
        kind = k % 7
        s = int(rng.integers(2**31))
        if kind == 0:
            flips = int(rng.integers(1, 20))
            out.append((f"{flips} random byte flips in a trial (s{s})", False, raw(T1, _flipper(s, flips))))
        elif kind == 1:
            out.append((f"random byte flips in bench.toml (s{s})", False, raw("bench.toml", _flipper(s, 2))))
        elif kind == 2:
            out.append((f"trial truncated at a random byte (s{s})", False,
                        raw(T1, lambda b, s=s: b[:np.random.default_rng(s).integers(1, len(b))])))
        elif kind == 3:
            value = ["nan", "inf", "-inf", "NaN", "Infinity"][s % 5]
            name = columns[s % 6]
            out.append((f"{value} in {name} at a random row (s{s})", True, cell(1 + s % 8000, name, value)))
        elif kind == 4:
            a, b = rng.choice(columns, 2, replace=False)
            out.append((f"columns {a} and {b} swapped", bool({"count", "time"} & {a, b}), _swap_headers(a, b)))
        elif kind == 5:
            value, name = ["1e300", "-1e300", "1e-300"][s % 3], columns[1 + s % 5]
            out.append((f"{value} in {name} at a random row (s{s})", value != "1e-300",
                        cell(1 + s % 8000, name, value)))
        else:
            out.append((f"random rows deleted (s{s})", False, rows_edit(
                lambda h, r, s=s: (h, [x for x, keep in zip(r, np.random.default_rng(s).random(len(r)) > 0.01)
                                       if keep]))))
    return out


def _flipper(seed: int, flips: int) -> Callable[[bytes], bytes]:
    def flip(data: bytes) -> bytes:
        rng = np.random.default_rng(seed)
        buf = bytearray(data)
        for i in rng.integers(0, len(buf), flips):
            buf[i] ^= 1 << int(rng.integers(8))
        return bytes(buf)
    return flip


def bench_cases(base: Path, seed: int) -> list[Case]:
    rng = np.random.default_rng(seed)

    def make(name: str, must_reject: bool, mutate: Callable) -> Case:
        def run(folder: Path) -> Run:
            d = folder / "bench"
            shutil.copytree(base, d, symlinks=True)
            mutate(d, rng)
            out = folder / "result.json"
            return ilcpmac("identify", d, "--output", out, folder=folder, written=out)
        return Case("bench folders", name, must_reject, run)

    return [make(*m) for m in BENCH_MUTATIONS + _random_bench_mutations(rng, 35)]


# ---------------------------------------------------------------- 2. configs and arguments

#: tables whose keys ``ilcpmac run`` exercises (the others: ``ilcpmac simulate``)
RUN_TABLES = ("campaign", "limits", "pipeline", "stages.ilc")


def small_config(text: str) -> str:
    """The seed bench reduced: a 2 x 2 grid, 2 revolutions, 2 learned points of 3 revolutions, one validation
    point of 3 (the fewest [campaign] takes), the torque from the sensor (the encoder's needs 3 revolutions a
    trial)."""
    for table, name, value in (("campaign", "torque_source", '"sensor"'),
                               ("trials", "torque_setpoints_nm", "[1.0, 3.0]"),
                               ("trials", "speed_setpoints_hz", "[0.8, 1.0]"), ("trials", "revolutions", "2"),
                               ("campaign", "learn_torques_nm", "[1.0, 3.0]"),
                               ("campaign", "learn_speeds_hz", "[0.8]"), ("campaign", "learn_revolutions", "[3]"),
                               ("campaign", "validate_torques_nm", "[2.0]"),
                               ("campaign", "validate_speeds_hz", "[0.8]"),
                               ("campaign", "validate_revolutions", "3")):
        text = toml_set(text, table, name, value)
    return text


def config_case(name: str, must_reject: bool, text_fn: Callable[[str], str | bytes], base: str,
                command: str = "simulate") -> Case:
    def run(folder: Path) -> Run:
        cfg = folder / "mutated.toml"
        text = text_fn(base)
        cfg.write_bytes(text if isinstance(text, bytes) else text.encode())
        out = folder / "out"
        if command == "run":
            return ilcpmac("run", cfg, "--trials", "1", "--out", out, folder=folder, written=out)
        return ilcpmac("simulate", cfg, "--out", out, folder=folder, written=out)
    return Case("configs & args", name, must_reject, run)


def arg_case(name: str, args: Callable[[Path], list], must_reject: bool = True) -> Case:
    def run(folder: Path) -> Run:
        return ilcpmac(*args(folder), folder=folder, written=folder)
    return Case("configs & args", name, must_reject, run)


#: (name, must be rejected, table, key, value) of the structured config mutations
CONFIG_KEYS: list[tuple[str, bool, str, str, str | None]] = [
    ("learning_gain nan", True, "stages.ilc", "learning_gain", "nan"),
    ("learning_gain 1e6", False, "stages.ilc", "learning_gain", "1e6"),
    ("significance -5", True, "stages.ilc", "significance", "-5.0"),
    ("q_cutoff_harmonic 0", True, "stages.ilc", "q_cutoff_harmonic", "0"),
    ("estimation bogus", True, "stages.ilc", "estimation", '"bogus"'),
    ("control_rate_hz 0.001", True, "simulator.controller", "control_rate_hz", "0.001"),
    ("control_rate_hz 1e12", True, "simulator.controller", "control_rate_hz", "1e12"),
    ("bandwidth_hz 1e9", True, "simulator.controller", "bandwidth_hz", "1e9"),
    ("voltage_limit_v 0", True, "simulator.controller", "voltage_limit_v", "0.0"),
    ("speed set points [1e-6]", True, "trials", "speed_setpoints_hz", "[1e-6]"),
    ("speed set points [-1]", True, "trials", "speed_setpoints_hz", "[-1.0]"),
    ("torque set points []", True, "trials", "torque_setpoints_nm", "[]"),
    ("speed set points []", True, "trials", "speed_setpoints_hz", "[]"),
    ("torque set points [1e300]", True, "trials", "torque_setpoints_nm", "[1e300]"),
    ("revolutions 20000", True, "trials", "revolutions", "20000"),
    ("revolutions 0", True, "trials", "revolutions", "0"),
    ("warmup_revolutions 10^6", True, "trials", "warmup_revolutions", "1000000"),
    ("seed -1", True, "trials", "seed", "-1"),
    ("seed 2^40", False, "trials", "seed", str(2**40)),  # valid: each trial seed is derived, 32-bit
    ("counts_per_rev 0", True, "bench", "counts_per_rev", "0"),
    ("counts_per_rev 2^40", True, "bench", "counts_per_rev", str(2**40)),
    ("timer_resolution_s 10", True, "simulator.encoder", "timer_resolution_s", "10.0"),
    ("inertia 0", True, "bench", "inertia_kgm2", "0.0"),
    ("inertia -1", True, "bench", "inertia_kgm2", "-1.0"),
    ("inertia 1e300", True, "bench", "inertia_kgm2", "1e300"),
    ("pole_pairs 0", True, "bench", "pole_pairs", "0"),
    ("pole_pairs 10^6", True, "bench", "pole_pairs", "1000000"),
    ("phase_inductance_h 0", True, "simulator.winding", "phase_inductance_h", "0.0"),
    ("phase_resistance_ohm -0.5", True, "simulator.winding", "phase_resistance_ohm", "-0.5"),
    ("alpha [0, 0, 0]", True, "simulator.current_sensors", "alpha", "[0.0, 0.0, 0.0]"),
    ("epsilon 0", True, "simulator.current_sensors", "epsilon", "0.0"),
    ("delta 0", True, "simulator.torque_sensor", "delta", "0.0"),
    ("noise_nm -1", True, "simulator.torque_sensor", "noise_nm", "-1.0"),
    ("highpass_hz 1e6", True, "simulator.torque_sensor", "highpass_hz", "1e6"),
    ("backemf without the fundamental", True, "bench.backemf", "harmonics", "[2, 3, 5, 7]"),
    ("backemf amplitudes all zero", True, "bench.backemf", "amplitudes_nm_per_a", "[0.0, 0.0, 0.0, 0.0]"),
    ("backemf lists of unequal length", True, "bench.backemf", "phases_rad", "[0.0]"),
    ("cogging multiple 0", True, "simulator.cogging", "multiples", "[0, 2]"),
    ("unexplained orders empty", False, "simulator.unexplained", "orders", "[]"),
    ("excitation fraction 1e6", True, "excitation", "fraction", "1e6"),
    ("excitation phases bogus", True, "excitation", "phases", '"bogus"'),
    ("excitation harmonics 0", False, "excitation", "harmonics", "0"),
    ("learn_revolutions [20000]", True, "campaign", "learn_revolutions", "[20000]"),
    ("learn speed 1e-6 Hz", True, "campaign", "learn_speeds_hz", "[1e-6]"),
    ("learn torques [0]", True, "campaign", "learn_torques_nm", "[0.0]"),
    ("learn torque 100 N m", True, "campaign", "learn_torques_nm", "[100.0]"),
    ("validate speed 9 Hz", True, "campaign", "validate_speeds_hz", "[9.0]"),
    ("reverse learn speed -1e-6 Hz", True, "campaign", "learn_speeds_hz", "[-1e-6, 0.8]"),
    ("reverse learn speed -9 Hz", True, "campaign", "learn_speeds_hz", "[-9.0, 0.8]"),
    ("reverse learn speeds [-0.8, -0.8]", True, "campaign", "learn_speeds_hz", "[-0.8, -0.8]"),
    ("reverse generating on the brake", True, "campaign", "learn_speeds_hz", "[-0.8, 0.8]"),
    ("reverse validate speed with none learned", True, "campaign", "validate_speeds_hz", "[-0.8]"),
    ("old key ilc_trials", True, "campaign", "ilc_trials", "3"),
    ("min_improvement 2", True, "campaign", "min_improvement", "2.0"),
    ("ripple_harmonics 0", True, "campaign", "ripple_harmonics", "0"),
    ("torque_source both with 2 grid revolutions", True, "campaign", "torque_source", '"both"'),
    ("torque_source encoder with 2 grid revolutions", True, "campaign", "torque_source", '"encoder"'),
    ("max_current_a nan", True, "limits", "max_current_a", "nan"),
    ("max_speed_hz 0", True, "limits", "max_speed_hz", "0.0"),
    ("max_torque_nm -1", True, "limits", "max_torque_nm", "-1.0"),
    ("stages [nope]", True, "pipeline", "stages", '["nope"]'),
    ("stages [ilc, ilc]", True, "pipeline", "stages", '["ilc", "ilc"]'),
    ("stages []", False, "pipeline", "stages", "[]"),
]


def _whole_file_mutations() -> list[tuple[str, bool, Callable[[str], str | bytes]]]:
    return [
        ("config binary", True, lambda t: b"\xff\xfe\x00\x01" + bytes(range(256)) * 16),
        ("config UTF-16", True, lambda t: t.encode("utf-16")),
        ("config nested 100000 deep", True, lambda t: t + "x = " + "[" * 100_000 + "]" * 100_000 + "\n"),
        ("config empty", True, lambda t: ""),
        ("config cut mid-line", True, lambda t: t[:t.index("control_rate_hz") + 8]),
        ("config duplicated key", True, lambda t: t.replace("[bench]", "[bench]\npole_pairs = 8", 1)),
        ("config unknown table", True, lambda t: t + "\n[bogus]\nx = 1\n"),
        ("config unknown key", True, lambda t: toml_set(t, "bench", "inertia_kg", "0.01")),
        ("config missing [bench]", True, lambda t: t.replace("[bench]", "[benchx]", 1)),
        ("config missing key bandwidth_hz", True, lambda t: toml_set(t, "simulator.controller", "bandwidth_hz", None)),
        ("config 1 MB comment", False, lambda t: "#" + "x" * 1_000_000 + "\n" + t),
        ("[stages.nope] for an unlisted stage", True, lambda t: t + "\n[stages.nope]\nx = 1\n"),
    ]


#: hostile TOML values and whether a key set to one must be rejected (a list key: its first element)
HOSTILE_VALUES = (("nan", True), ("inf", True), ("-inf", True), ("-1", False), ("0", False), ("1e300", True),
                  ("-1e300", True), ('"text"', True), ("true", True), ("{ a = 1 }", True),
                  ("9223372036854775807", True), ("1e-300", False), ("[]", None))


def _random_config_mutations(rng: np.random.Generator, base: str, n: int):
    import tomllib

    def leaves(table: dict, name: str):
        for k, v in table.items():
            if isinstance(v, dict):
                yield from leaves(v, f"{name}.{k}" if name else k)
            elif name:
                yield name, k, v

    keys = list(leaves(tomllib.loads(base), ""))
    out = []
    for _ in range(n):
        table, name, current = keys[int(rng.integers(len(keys)))]
        value, must = HOSTILE_VALUES[int(rng.integers(len(HOSTILE_VALUES)))]
        if isinstance(current, list):
            if must is None:
                continue
            rest = ", ".join(repr(x) if not isinstance(x, str) else f'"{x}"' for x in current[1:])
            value = f"[{value}{', ' if rest else ''}{rest}]"
        must = bool(must) if must is not None else True
        if name.endswith("seed") and value == "9223372036854775807":
            must = False  # a seed may take any 63-bit value
        out.append((f"[{table}] {name} = {value}", must, table, name, value))
    return out


def config_cases(base: str, bench: Path, seed: int) -> list[Case]:
    """Config mutations of ``base`` (TOML text) and argument mutations (``bench``: a valid bench folder)."""
    rng = np.random.default_rng(seed + 1)
    cases = []
    for name, must, table, k, value in CONFIG_KEYS + _random_config_mutations(rng, base, 22):
        command = "run" if table in RUN_TABLES else "simulate"
        cases.append(config_case(name, must, lambda t, table=table, k=k, value=value: toml_set(t, table, k, value),
                                 base, command))
    for name, must, fn in _whole_file_mutations():
        cases.append(config_case(name, must, fn, base))

    def good(folder: Path) -> Path:
        (folder / "good.toml").write_text(base)
        return folder / "good.toml"

    cases += [
        arg_case("simulate --revolutions 0", lambda f: ["simulate", good(f), "--out", f / "o", "--revolutions", 0]),
        arg_case("simulate --revolutions 100000", lambda f: ["simulate", good(f), "--out", f / "o",
                                                             "--revolutions", 100000]),
        arg_case("simulate --seed -1", lambda f: ["simulate", good(f), "--out", f / "o", "--seed", -1]),
        arg_case("simulate --seed 2^64", lambda f: ["simulate", good(f), "--out", f / "o", "--seed", 2**64]),
        arg_case("simulate --out under /dev/null", lambda f: ["simulate", good(f), "--out", "/dev/null/x"]),
        arg_case("simulate a missing config", lambda f: ["simulate", f / "missing.toml", "--out", f / "o"]),
        arg_case("run --trials 0", lambda f: ["run", good(f), "--trials", 0, "--out", f / "o"]),
        arg_case("run --backend remote without --address", lambda f: ["run", good(f), "--backend", "remote",
                                                                     "--out", f / "o"]),
        arg_case("run --address nonsense", lambda f: ["run", good(f), "--backend", "remote", "--address", "a:b:c",
                                                      "--out", f / "o"]),
        arg_case("run --address with nobody listening", lambda f: ["run", good(f), "--backend", "remote",
                                                                   "--address", "127.0.0.1:9", "--out", f / "o"]),
        arg_case("run --resume a missing folder", lambda f: ["run", "--resume", f / "missing"]),
        arg_case("run --resume a folder that is not a run", lambda f: ["run", "--resume", f]),
        arg_case("run CONFIG --resume", lambda f: ["run", good(f), "--resume", f]),
        arg_case("identify a missing folder", lambda f: ["identify", f / "missing", "--output", f / "r.json"]),
        arg_case("identify --output under /proc", lambda f: ["identify", bench, "--output", "/proc/nope/r.json"]),
        arg_case("identify --output is a folder", lambda f: ["identify", bench, "--output", f]),
        arg_case("emulate --port 70000", lambda f: ["emulate", "--port", 70000]),
        arg_case("emulate with a broken config", lambda f: ["emulate", "--port", 0, "--config", f / "none.toml"]),
    ]
    return cases


# ---------------------------------------------------------------- 3. protocol, both directions


def target_case(tc: ft.TargetCase, config: Path) -> Case:
    def run(folder: Path) -> Run:
        target = ft.HostileTarget(tc.behaviour)
        try:
            if tc.cli:
                out = folder / "run"
                return ilcpmac("run", config, "--backend", "remote", "--address", target.address,
                               "--trials", "1", "--out", out, folder=folder, written=out)
            out = folder / "trial.json"
            return run_process([sys.executable, str(Path(ft.__file__)), "client", target.address, str(out)],
                               folder, written=out)
        finally:
            target.stop()
    return Case("remote client vs hostile targets", tc.name, tc.must_reject, run)


class EmulatorCampaign:
    """Runs the hostile clients against one ``ilcpmac emulate`` (restarted if an attack kills it)."""

    def __init__(self, config: Path, scratch: Path) -> None:
        self.argv = [ILCPMAC, "emulate", "--port", "0", "--config", str(config), "--heartbeat", "0.5"]
        self.scratch = scratch
        self.emulator = ft.Emulator(self.argv, scratch, MEMORY_CAP_BYTES, _ENV)

    def attack(self, attack: ft.Attack) -> Run:
        em = self.emulator
        start = time.monotonic()
        try:
            accepted, note = attack.run(em)
        except OSError as e:
            accepted, note = False, f"attack failed: {type(e).__name__}: {e}"
        return self._after(em, accepted, note, start)

    def _after(self, em: ft.Emulator, accepted: bool, note: str, start: float) -> Run:
        alive = em.proc.poll() is None
        live = alive and ft.describes(em)
        text = em.new_output() + "\n" + (note if live or not alive else
                                         f"{note}; then a well-formed client got no DESCRIBE within 5 s")
        run = Run(None if alive else em.proc.returncode, alive and not live, text, em.peak_rss_kib(), accepted,
                  seconds=time.monotonic() - start)
        if not live:
            em.stop()
            self.emulator = ft.Emulator(self.argv, self.scratch, MEMORY_CAP_BYTES, _ENV)
        return run

    def idle_attacks(self, attacks: tuple[ft.Attack, ...]) -> list[Run]:
        """The attacks that wait out ft.IDLE_CLOSE_S, all at once."""
        em = self.emulator
        start = time.monotonic()
        results: dict[int, tuple[bool, str]] = {}

        def one(i: int, attack: ft.Attack) -> None:
            try:
                results[i] = attack.run(em)
            except OSError as e:
                results[i] = (False, f"attack failed: {type(e).__name__}: {e}")

        threads = [threading.Thread(target=one, args=(i, a)) for i, a in enumerate(attacks)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        runs = []
        for i in range(len(attacks)):
            accepted, note = results[i]
            if accepted:
                note += f" (must be closed within {ft.IDLE_CLOSE_S:g} s)"
            runs.append(self._after(self.emulator, accepted, note, start))
        return runs

    def close(self) -> None:
        self.emulator.stop()


def emulator_verdicts(config: Path, scratch: Path, quick: bool, match: str) -> list[Verdict]:
    attacks = [a for a in (ft.ATTACKS[::3] if quick else ft.ATTACKS) if match in a.name]
    idle = tuple(a for a in (ft.IDLE_ATTACKS[:1] if quick else ft.IDLE_ATTACKS) if match in a.name)
    campaign = EmulatorCampaign(config, scratch)
    verdicts = []
    try:
        for attack in attacks:
            case = Case("emulator vs hostile clients", attack.name, attack.must_reject, lambda f: None)
            run = campaign.attack(attack)
            verdicts.append(Verdict(case, *classify(case, run), run.peak_rss_kib, run.seconds))
            progress(verdicts[-1])
        for attack, run in zip(idle, campaign.idle_attacks(idle)):
            case = Case("emulator vs hostile clients", attack.name, attack.must_reject, lambda f: None)
            verdicts.append(Verdict(case, *classify(case, run), run.peak_rss_kib, run.seconds))
            progress(verdicts[-1])
    finally:
        campaign.close()
    return verdicts


# ---------------------------------------------------------------- 4. ilcpmac import: mappings and logs

#: the drive logs' rate, Hz: 1.6 to 2 counts a row on the base bench (harmonics up to 1024 resolved)
LOG_RATE_HZ = 2000.0
#: base bench trials logged as drive logs (1 N m at 0.8 Hz, 3 N m at 1 Hz), and the logs' names
LOGGED = {"log_a.csv": "trial_01.csv", "log_b.csv": "trial_04.csv"}
LOG_A, LOG_B = LOGGED
#: the q-axis log (of trial_01): time in ms, a wrapping 16-bit position, i_q in 10 mA, ';', three header lines
LOG_Q, LOG_Q_COUNTS_PER_REV = "log_q.csv", 2**16
#: log_a's trial at 50 Hz: about 66 counts between rows, harmonics up to 31 resolved (fewer than 150)
LOG_COARSE, COARSE_RATE_HZ = "log_50hz.csv", 50.0
MAP, MAP_Q = "map.toml", "map_q.toml"
PHASE_LAYOUT = """[log]
time = "t"
position = "theta"
position_unit = "rad"
phase_currents = ["ia", "ib", "ic"]
torque = "tq"
"""
Q_LAYOUT = f"""[log]
delimiter = ";"
header_lines = 3
time = "t_ms"
time_s_per_unit = 1e-3
position = "pos"
position_unit = "counts"
position_counts_per_rev = {LOG_Q_COUNTS_PER_REV}
i_q = "iq"
current_a_per_unit = 0.01
torque = "tq"
"""


def mapping_bench(bench: Path) -> str:
    """The [bench] table of a mapping for the motor of bench folder ``bench`` (its backemf.csv beside the
    mapping)."""
    import tomllib

    motor = tomllib.loads((bench / "bench.toml").read_text())["motor"]
    return (f"[bench]\npole_pairs = {motor['pole_pairs']}\nslots = {motor['slots']}\n"
            f"counts_per_rev = {motor['counts_per_rev']}\ninertia_kgm2 = {motor['inertia']}\n"
            'backemf_file = "backemf.csv"\n\n')


def logged(trial: Path, rate_hz: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A bench trial as a drive logs it: rows at ``rate_hz`` from two rows before its first count to two past
    its last (an importer leaves out the first and last row interval).

    Returns time s, shape (n,); position in counts, shape (n,) (on at the end counts' speed beyond them);
    i_ref a, b, c and torque linearly interpolated, shape (n, 4).
    """
    count, time_s, *values = np.loadtxt(trial, delimiter=",", skiprows=1, usecols=range(6), unpack=True)
    t = time_s[0] + np.arange(-2, int(np.ceil((time_s[-1] - time_s[0]) * rate_hz)) + 3) / rate_hz
    position = np.interp(t, time_s, count)
    before, after = t < time_s[0], t > time_s[-1]
    position[before] = count[0] + (t[before] - time_s[0]) / (time_s[1] - time_s[0])
    position[after] = count[-1] + (t[after] - time_s[-1]) / (time_s[-1] - time_s[-2])
    return t, position, np.column_stack([np.interp(t, time_s, v) for v in values])


def write_phase_log(path: Path, trial: Path, cpr: int, rate_hz: float = LOG_RATE_HZ) -> None:
    """``trial`` logged at ``rate_hz`` with the position in rad and the phase currents (PHASE_LAYOUT)."""
    t, position, values = logged(trial, rate_hz)
    np.savetxt(path, np.column_stack([t, position * 2 * np.pi / cpr, values]), delimiter=",",
               header="t,theta,ia,ib,ic,tq", comments="", fmt="%.12g")


def write_q_log(path: Path, trial: Path, cpr: int, pole_pairs: int) -> None:
    """``trial`` logged as Q_LAYOUT reads it: i_q by the amplitude-invariant Park transform at theta_e =
    pole_pairs theta."""
    t, position, values = logged(trial, LOG_RATE_HZ)
    theta_e = pole_pairs * 2 * np.pi * position / cpr
    i_q = 2 / 3 * sum(values[:, p] * np.sin(theta_e - 2 * np.pi * p / 3) for p in range(3))
    wrapped = np.mod(position * LOG_Q_COUNTS_PER_REV / cpr, LOG_Q_COUNTS_PER_REV)
    np.savetxt(path, np.column_stack([1e3 * t, wrapped, 100 * i_q, values[:, 3]]), delimiter=";",
               header="drive log\nrate 2 kHz\nt_ms;pos;iq;tq", comments="", fmt="%.12g")


def make_import_base(bench: Path, folder: Path) -> None:
    """Drive logs of the base bench's trials and their mappings (phase currents; q axis) in ``folder``."""
    import tomllib

    motor = tomllib.loads((bench / "bench.toml").read_text())["motor"]
    folder.mkdir()
    shutil.copy(bench / "backemf.csv", folder / "backemf.csv")
    for log, trial in LOGGED.items():
        write_phase_log(folder / log, bench / trial, motor["counts_per_rev"])
    write_q_log(folder / LOG_Q, bench / LOGGED[LOG_A], motor["counts_per_rev"], motor["pole_pairs"])
    write_phase_log(folder / LOG_COARSE, bench / LOGGED[LOG_A], motor["counts_per_rev"], COARSE_RATE_HZ)
    (folder / MAP).write_text(mapping_bench(bench) + PHASE_LAYOUT)
    (folder / MAP_Q).write_text(mapping_bench(bench) + Q_LAYOUT)


def mapping(table: str, name: str, value: str | None, file: str = MAP) -> Callable:
    """A mutation setting ``name = value`` in [table] of a mapping (None deletes it)."""
    return lambda d, rng: edit(d / file, lambda t: toml_set(t, table, name, value))


def mapping_text(fn: Callable[[str], str | bytes], file: str = MAP) -> Callable:
    def mutate(d: Path, rng) -> None:
        text = fn((d / file).read_text())
        (d / file).write_bytes(text if isinstance(text, bytes) else text.encode())
    return mutate


def _point(file: str, torque: str = "1.0", speed: str = "0.8", extra: str = "") -> Callable[[str], str]:
    """A [[points]] table for log ``file`` appended to a mapping."""
    return lambda t: (t + f'\n[[points]]\nfile = "{file}"\ntorque_setpoint_nm = {torque}\n'
                      f"speed_setpoint_hz = {speed}\n{extra}")


def _log_lines(fn: Callable[[list[bytes]], list[bytes]], file: str = LOG_A) -> Callable:
    def mutate(d: Path, rng) -> None:
        (d / file).write_bytes(b"\n".join(fn((d / file).read_bytes().split(b"\n"))))
    return mutate


def _many_rows(d: Path, rng) -> None:
    """2^22 + 1 rows of zeros after the header (54 MB): one row more than a log may hold."""
    (d / LOG_A).write_bytes(b"t,theta,ia,ib,ic,tq\n" + b"0,0,0,0,0,0\n" * (2**22 + 1))


#: the logs and mapping of a case: a function of the case's logs folder
Args = Callable[[Path], list]
PHASE_ARGS: Args = lambda d: [d / LOG_A, d / LOG_B, "--map", d / MAP]  # noqa: E731
Q_ARGS: Args = lambda d: [d / LOG_Q, "--map", d / MAP_Q]  # noqa: E731

#: (name, must be rejected, mutation(folder, rng), logs and mapping) of the structured import mutations
IMPORT_MUTATIONS: list[tuple[str, bool, Callable, Args]] = [
    ("two phase-current logs as logged", False, lambda d, rng: None, PHASE_ARGS),
    ("q-axis log: ms, wrapping 16-bit counts, ';', 3 header lines", False, lambda d, rng: None, Q_ARGS),
    ("--format parquet", False, lambda d, rng: None, lambda d: [*PHASE_ARGS(d), "--format", "parquet"]),
    ("[[points]] for both logs", False, mapping_text(lambda t: _point(LOG_B, "3.0", "1.0")(_point(LOG_A)(t))),
     PHASE_ARGS),
    ("[bench.calibration] given", False, mapping_text(lambda t: t + "\n[bench.calibration]\n"
                                                     "current_scale_counts_per_a = [14.0, 14.0, 14.0]\n"
                                                     "current_offset_counts = [0.0, 0.0, 0.0]\n"
                                                     "torque_gain_v_per_nm = 0.908\n"), PHASE_ARGS),
    ('current = "measured"', False, mapping("log", "current", '"measured"'), PHASE_ARGS),
    # the mapping: tables and keys
    ("mapping unknown table [logs]", True, mapping_text(lambda t: t + "\n[logs]\nx = 1\n"), PHASE_ARGS),
    ("mapping unknown key in [log]", True, mapping("log", "speed_units", "2"), PHASE_ARGS),
    ("mapping unknown key in [bench]", True, mapping("bench", "inertia", "0.01"), PHASE_ARGS),
    ("mapping missing [log]", True, mapping_text(lambda t: t.replace("[log]", "[logg]")), PHASE_ARGS),
    ("mapping missing [bench]", True, mapping_text(lambda t: t.replace("[bench]", "[bnch]")), PHASE_ARGS),
    ("mapping missing inertia_kgm2", True, mapping("bench", "inertia_kgm2", None), PHASE_ARGS),
    ("mapping [log] as an array of tables", True, mapping_text(lambda t: t.replace("[log]", "[[log]]")), PHASE_ARGS),
    ("mapping [points] a table", True, mapping_text(lambda t: t + '\n[points]\nfile = "log_a.csv"\n'), PHASE_ARGS),
    ("mapping [scan] on a run", True, mapping_text(lambda t: t + "\n[scan]\nepsilon = 0.7\n"), PHASE_ARGS),
    ("mapping backemf file missing", True, mapping("bench", "backemf_file", '"nope.csv"'), PHASE_ARGS),
    ("mapping backemf file and [bench.backemf]", True, mapping_text(
        lambda t: t + "\n[bench.backemf]\nharmonics = [1]\namplitudes_nm_per_a = [0.2]\nphases_rad = [0.0]\n"),
     PHASE_ARGS),
    ("mapping backemf file is a directory", True, _both(mapping("bench", "backemf_file", '"sub"'),
                                                        lambda d, rng: (d / "sub").mkdir()), PHASE_ARGS),
    ("mapping counts_per_rev 2^40", True, mapping("bench", "counts_per_rev", str(2**40)), PHASE_ARGS),
    ("mapping counts_per_rev 1024 (backemf of 4096)", True, mapping("bench", "counts_per_rev", "1024"), PHASE_ARGS),
    ("mapping binary", True, mapping_text(lambda t: b"\xff\xfe\x00" + bytes(range(256)) * 8), PHASE_ARGS),
    ("mapping UTF-16", True, mapping_text(lambda t: t.encode("utf-16")), PHASE_ARGS),
    ("mapping empty", True, mapping_text(lambda t: ""), PHASE_ARGS),
    ("mapping nested 100000 deep", True, mapping_text(lambda t: t + "x = " + "[" * 100_000 + "]" * 100_000 + "\n"),
     PHASE_ARGS),
    ("mapping 2 MB comment", True, mapping_text(lambda t: "#" + "x" * 2_000_000 + "\n" + t), PHASE_ARGS),
    ("mapping is a directory", True, lambda d, rng: (d / "dir.toml").mkdir(),
     lambda d: [d / LOG_A, "--map", d / "dir.toml"]),
    ("mapping missing", True, lambda d, rng: None, lambda d: [d / LOG_A, "--map", d / "none.toml"]),
    ("mapping is a FIFO", True, lambda d, rng: os.mkfifo(d / "fifo.toml"),
     lambda d: [d / LOG_A, "--map", d / "fifo.toml"]),
    ("mapping symlink to /dev/zero", True, lambda d, rng: (d / "zero.toml").symlink_to("/dev/zero"),
     lambda d: [d / LOG_A, "--map", d / "zero.toml"]),
    # [log] types, units and scales
    ("time = 3 (not a name)", True, mapping("log", "time", "3"), PHASE_ARGS),
    ("phase_currents two names", True, mapping("log", "phase_currents", '["ia", "ib"]'), PHASE_ARGS),
    ("phase_currents and i_q", True, mapping("log", "i_q", '"ia"'), PHASE_ARGS),
    ("neither phase_currents nor i_q", True, mapping("log", "phase_currents", None), PHASE_ARGS),
    ('position_unit "deg"', True, mapping("log", "position_unit", '"deg"'), PHASE_ARGS),
    ("time_s_per_unit 0", True, mapping("log", "time_s_per_unit", "0.0"), PHASE_ARGS),
    ("time_s_per_unit -1", True, mapping("log", "time_s_per_unit", "-1.0"), PHASE_ARGS),
    ("time_s_per_unit nan", True, mapping("log", "time_s_per_unit", "nan"), PHASE_ARGS),
    ("time_s_per_unit 1e300", True, mapping("log", "time_s_per_unit", "1e300"), PHASE_ARGS),
    ("time_s_per_unit 1e-9 (s read as ns)", True, mapping("log", "time_s_per_unit", "1e-9"), PHASE_ARGS),
    ("time_s_per_unit 1e3 (s read as ks)", False, mapping("log", "time_s_per_unit", "1e3"), PHASE_ARGS),
    ("current_a_per_unit 0", True, mapping("log", "current_a_per_unit", "0.0"), PHASE_ARGS),
    ("current_a_per_unit nan", True, mapping("log", "current_a_per_unit", "nan"), PHASE_ARGS),
    ("current_a_per_unit inf", True, mapping("log", "current_a_per_unit", "inf"), PHASE_ARGS),
    ("current_a_per_unit 1e9", True, mapping("log", "current_a_per_unit", "1e9"), PHASE_ARGS),
    ("current_a_per_unit 1e-300", True, mapping("log", "current_a_per_unit", "1e-300"), PHASE_ARGS),
    ("current_a_per_unit -1 (sign flipped)", True, mapping("log", "current_a_per_unit", "-1.0"), PHASE_ARGS),
    ("torque_nm_per_unit 0", True, mapping("log", "torque_nm_per_unit", "0.0"), PHASE_ARGS),
    ("torque_nm_per_unit 1e9", True, mapping("log", "torque_nm_per_unit", "1e9"), PHASE_ARGS),
    ("torque_nm_per_unit -1 (sign flipped)", False, mapping("log", "torque_nm_per_unit", "-1.0"), PHASE_ARGS),
    ('current = "both"', True, mapping("log", "current", '"both"'), PHASE_ARGS),
    ("angle_offset_rad 7", True, mapping("log", "angle_offset_rad", "7.0", MAP_Q), Q_ARGS),
    ("angle_offset_rad nan", True, mapping("log", "angle_offset_rad", "nan", MAP_Q), Q_ARGS),
    ("highest_harmonic 0", True, mapping("log", "highest_harmonic", "0"), PHASE_ARGS),
    # rows too coarse for the harmonics asked are kept as a rolling log, which resolves what they can (issue 35)
    ("highest_harmonic 2048 on 2 kHz rows", False, mapping("log", "highest_harmonic", "2048"), PHASE_ARGS),
    ("highest_harmonic 2049 (beyond Nyquist)", True, mapping("log", "highest_harmonic", "2049"), PHASE_ARGS),
    ('kind = "scan" on run logs', True, mapping("log", "kind", '"scan"'), PHASE_ARGS),
    ("direction on a run", True, mapping("log", "direction", '"tq"'), PHASE_ARGS),
    ("no torque column (a bench without a torque sensor)", False, mapping("log", "torque", None), PHASE_ARGS),
    # columns
    ("column missing from the log", True, mapping("log", "torque", '"torque"'), PHASE_ARGS),
    ("the same column for three phases", True, mapping("log", "phase_currents", '["ia", "ia", "ia"]'), PHASE_ARGS),
    ("time and position the same column", True, mapping("log", "position", '"t"'), PHASE_ARGS),
    ("torque is a current column", True, mapping("log", "torque", '"ia"'), PHASE_ARGS),
    ("log header names a column twice", True, _log_lines(lambda ls: [b"t,theta,ia,ib,ia,tq"] + ls[1:]),
     PHASE_ARGS),
    ("column names quoted", False, _log_lines(lambda ls: [b'"t","theta","ia","ib","ic","tq"'] + ls[1:]),
     PHASE_ARGS),
    ("header with a BOM", False, raw(LOG_A, lambda b: b"\xef\xbb\xbf" + b), PHASE_ARGS),
    # delimiters and header lines
    ("delimiter ';' on a ',' log", True, mapping("log", "delimiter", '";"'), PHASE_ARGS),
    ("delimiter ' ' on a ',' log", True, mapping("log", "delimiter", '" "'), PHASE_ARGS),
    ("delimiter ''", True, mapping("log", "delimiter", '""'), PHASE_ARGS),
    ("delimiter ',,'", True, mapping("log", "delimiter", '",,"'), PHASE_ARGS),
    ("delimiter '.'", True, mapping("log", "delimiter", '"."'), PHASE_ARGS),
    ("delimiter newline", True, mapping("log", "delimiter", '"\\n"'), PHASE_ARGS),
    ("delimiter ',' on a ';' log", True, mapping("log", "delimiter", '","', MAP_Q), Q_ARGS),
    ("header_lines 0", True, mapping("log", "header_lines", "0"), PHASE_ARGS),
    ("header_lines 1001", True, mapping("log", "header_lines", "1001"), PHASE_ARGS),
    ("header_lines 2 (a data row named)", True, mapping("log", "header_lines", "2"), PHASE_ARGS),
    ("header_lines beyond the file", True, _both(mapping("log", "header_lines", "500"),
                                                 _log_lines(lambda ls: ls[:100] + [b""])), PHASE_ARGS),
    ("header_lines 1 on a 3-line header", True, mapping("log", "header_lines", "1", MAP_Q), Q_ARGS),
    # position
    ("position_counts_per_rev absent with counts", True, mapping("log", "position_counts_per_rev", None, MAP_Q),
     Q_ARGS),
    ("position_counts_per_rev with rad", True, mapping("log", "position_counts_per_rev", "4096"), PHASE_ARGS),
    ("position_counts_per_rev 0", True, mapping("log", "position_counts_per_rev", "0", MAP_Q), Q_ARGS),
    ("position_counts_per_rev 1", True, mapping("log", "position_counts_per_rev", "1", MAP_Q), Q_ARGS),
    ("position_counts_per_rev 2^40", True, mapping("log", "position_counts_per_rev", str(2**40), MAP_Q), Q_ARGS),
    ("position_counts_per_rev 2^41", True, mapping("log", "position_counts_per_rev", str(2**41), MAP_Q), Q_ARGS),
    ("position_counts_per_rev 1.5", True, mapping("log", "position_counts_per_rev", "1.5", MAP_Q), Q_ARGS),
    # an i_q log states no electrical angle: 16 times its position's speed is a plausible motion, which the log
    # alone cannot tell from its own (the per-count path refused it as too coarse, by the way; a phase log is
    # refused: "position in degrees")
    ("position_counts_per_rev 4096 on a 16-bit position", False,
     mapping("log", "position_counts_per_rev", "4096", MAP_Q), Q_ARGS),
    ('position_unit "counts" on rad (a 12-count trial)', False, _both(
        mapping("log", "position_unit", '"counts"'), mapping("log", "position_counts_per_rev", "4096")), PHASE_ARGS),
    ('position_unit "rad" on counts', True, _both(mapping("log", "position_unit", '"rad"', MAP_Q),
                                                   mapping("log", "position_counts_per_rev", None, MAP_Q)), Q_ARGS),
    ("position frozen", True, column("theta", lambda p: np.full_like(p, p[0]), (LOG_A,)), PHASE_ARGS),
    # running backwards is a reverse lap, imported mirrored into BENCH_DIR-reverse; a partial one is refused
    ("position reversed (a reverse lap)", False, column("theta", lambda p: p[::-1], (LOG_A,)), PHASE_ARGS),
    # a log that turns and runs back is a rolling log, both directions kept (issue 35)
    ("position turns back for its last 1000 rows", False, column(
        "theta", lambda p: np.concatenate([p[:-1000], 2 * p[-1001] - p[-1000:]]), (LOG_A,)), PHASE_ARGS),
    # its currents commutate for +theta: a reverse lap of the motor with phases b and c swapped, which no log
    # format can tell from a real one (as "i_ref phases a and b swapped" of a bench folder)
    ("position negated (a reverse lap)", False, column("theta", lambda p: -p, (LOG_A,)), PHASE_ARGS),
    ("position one step back", True, cell(300, "theta", "0.0", LOG_A), PHASE_ARGS),
    ("position in degrees", True, column("theta", lambda p: p * 180 / np.pi, (LOG_A,)), PHASE_ARGS),
    ("position 1e300", True, column("theta", lambda p: p * 1e300, (LOG_A,)), PHASE_ARGS),
    ("position stalls for 500 rows", False, column("theta", lambda p: np.concatenate(
        [p[:1000], np.full(500, p[1000]), p[1000:-500]]), (LOG_A,)), PHASE_ARGS),
    ("position wraps every revolution", False, column("theta", lambda p: np.mod(p, 2 * np.pi), (LOG_A,)),
     PHASE_ARGS),
    ("too coarse: 50 Hz log", False, lambda d, rng: None, lambda d: [d / LOG_COARSE, "--map", d / MAP]),
    ("a 1 s gap in the time column (kept as a rolling log, its gap stated)", False,
     lambda d, rng: _gap(1.0, 3000)(d, rng), PHASE_ARGS),
    # time
    ("time going back one row", True, cell(200, "t", "0.0", LOG_A), PHASE_ARGS),
    ("time reversed", True, column("t", lambda t: t[::-1], (LOG_A,)), PHASE_ARGS),
    ("time constant", True, column("t", lambda t: np.full_like(t, 1.0), (LOG_A,)), PHASE_ARGS),
    ("time in ms (unit not given)", False, column("t", lambda t: t * 1e3, (LOG_A,)), PHASE_ARGS),
    ("time in ms, [[points]] at the logged speed", True, _both(column("t", lambda t: t * 1e3, (LOG_A,)),
                                                               mapping_text(_point(LOG_A))), PHASE_ARGS),
    ("time 1e300", True, column("t", lambda t: t * 1e300, (LOG_A,)), PHASE_ARGS),
    ("time 1e-300 steps", True, column("t", lambda t: t * 1e-300, (LOG_A,)), PHASE_ARGS),
    # values
    ("NaN torque", True, cell(400, "tq", "nan", LOG_A), PHASE_ARGS),
    ("inf current", True, cell(401, "ib", "inf", LOG_A), PHASE_ARGS),
    ("-inf time", True, cell(402, "t", "-inf", LOG_A), PHASE_ARGS),
    ("NaN position", True, cell(403, "theta", "NaN", LOG_A), PHASE_ARGS),
    ("text cell", True, cell(404, "tq", "abc", LOG_A), PHASE_ARGS),
    ("empty cell", True, cell(405, "ia", "", LOG_A), PHASE_ARGS),
    ("hex cell", True, cell(406, "ia", "0x10", LOG_A), PHASE_ARGS),
    ("torque constant", True, column("tq", lambda v: np.full_like(v, 1.0), (LOG_A,)), PHASE_ARGS),
    ("currents all zero", True, _both(*(column(c, np.zeros_like, (LOG_A,)) for c in ("ia", "ib", "ic"))),
     PHASE_ARGS),
    ("currents 1e300", True, column("ia", lambda v: v * 1e300, (LOG_A,)), PHASE_ARGS),
    ("NaN in a column not mapped", False, _both(
        rows_edit(lambda h, r: (h + ["note"], [x + ["0"] for x in r]), LOG_A), cell(10, "note", "nan", LOG_A)),
     PHASE_ARGS),
    # rows and bytes
    ("row cut short", True, _log_lines(lambda ls: ls[:500] + [ls[500].rsplit(b",", 1)[0]] + ls[501:]), PHASE_ARGS),
    ("row with an extra field", True, _log_lines(lambda ls: ls[:500] + [ls[500] + b",1"] + ls[501:]), PHASE_ARGS),
    ("last row cut mid-field", False, raw(LOG_A, lambda b: b[:-5]), PHASE_ARGS),
    ("header only", True, _log_lines(lambda ls: ls[:1] + [b""]), PHASE_ARGS),
    ("two rows", True, _log_lines(lambda ls: ls[:3] + [b""]), PHASE_ARGS),
    ("empty log", True, raw(LOG_A, lambda b: b""), PHASE_ARGS),
    ("binary log", True, raw(LOG_A, lambda b: bytes(range(256)) * 64), PHASE_ARGS),
    ("log in UTF-16", True, raw(LOG_A, lambda b: b.decode().encode("utf-16")), PHASE_ARGS),
    ("10 MB header line", True, raw(LOG_A, lambda b: b"t," * 5_000_000 + b"\n" + b.split(b"\n", 1)[1]),
     PHASE_ARGS),
    ("10 MB single row", True, raw(LOG_A, lambda b: b.split(b"\n", 1)[0] + b"\n" + b"1" * 10_000_000 + b"\n"),
     PHASE_ARGS),
    ("CRLF line endings", False, raw(LOG_A, lambda b: b.replace(b"\n", b"\r\n")), PHASE_ARGS),
    ("blank lines between rows", False, _log_lines(lambda ls: [x + b"\n" for x in ls]), PHASE_ARGS),
    ("log concatenated twice", True, raw(LOG_A, lambda b: b + b.split(b"\n", 1)[1]), PHASE_ARGS),
    ("2^22 + 1 rows", True, _many_rows, PHASE_ARGS),
    ("1 GiB sparse log", True, _sparse(LOG_A, 1 << 30), PHASE_ARGS),
    # files
    ("log is a FIFO", True, _fifo_file(LOG_A), PHASE_ARGS),
    ("log symlink to /dev/zero", True, _symlink("/dev/zero", LOG_A), PHASE_ARGS),
    ("log symlink to /dev/urandom", True, _symlink("/dev/urandom", LOG_A), PHASE_ARGS),
    ("log is a directory", True, _directory(LOG_A), PHASE_ARGS),
    ("log missing", True, _remove(LOG_A), PHASE_ARGS),
    ("the same log twice", True, lambda d, rng: None, lambda d: [d / LOG_A, d / LOG_A, "--map", d / MAP]),
    ("[[points]] naming a missing file", True, mapping_text(_point("nope.csv")), PHASE_ARGS),
    ("[[points]] a file twice", True, mapping_text(lambda t: _point(LOG_A)(_point(LOG_A)(t))), PHASE_ARGS),
    ("[[points]] torque 0", True, mapping_text(_point(LOG_A, "0.0")), PHASE_ARGS),
    ("[[points]] torque nan", True, mapping_text(_point(LOG_A, "nan")), PHASE_ARGS),
    ("[[points]] speed 1e4", True, mapping_text(_point(LOG_A, speed="1e4")), PHASE_ARGS),
    ("[[points]] speed 10x the log's", True, mapping_text(_point(LOG_A, speed="8.0")), PHASE_ARGS),
    ("[[points]] unknown key", True, mapping_text(_point(LOG_A, extra="note = 1\n")), PHASE_ARGS),
    ("[[points]] without file", True, mapping_text(lambda t: t + "\n[[points]]\ntorque_setpoint_nm = 1.0\n"
                                                   "speed_setpoint_hz = 0.8\n"), PHASE_ARGS),
    # the command line
    ("--out holds a bench.toml", True, lambda d, rng: (d / "bench.toml").write_text("[motor]\n"),
     lambda d: [*PHASE_ARGS(d), "--out", d]),
    ("--out is a file", True, lambda d, rng: None, lambda d: [*PHASE_ARGS(d), "--out", d / LOG_B]),
    ("--out under /dev/null", True, lambda d, rng: None, lambda d: [*PHASE_ARGS(d), "--out", "/dev/null/x"]),
    ("--format xlsx", True, lambda d, rng: None, lambda d: [*PHASE_ARGS(d), "--format", "xlsx"]),
    ("no logs", True, lambda d, rng: None, lambda d: ["--map", d / MAP]),
    ("no --map", True, lambda d, rng: None, lambda d: [d / LOG_A]),
]


# ---------------------------------------------------------------- 5. standstill scans

#: the simulated scan logs (`ilcpmac.sim.standstill`): holding currents (with i_q) and holding torque
SCAN_LOG, SCAN_TORQUE_LOG = "scan_log.csv", "scan_torque_log.csv"
MAP_SCAN, MAP_SCAN_Q, MAP_SCAN_TORQUE = "map_scan.toml", "map_scan_q.toml", "map_scan_torque.toml"
SCAN_CSV, SCAN_TOML = "scan.csv", "scan.toml"
SCAN_LAYOUTS = {
    MAP_SCAN: 'phase_currents = ["i_a", "i_b", "i_c"]\ndirection = "direction"\n',
    MAP_SCAN_Q: 'i_q = "i_q"\n',
    MAP_SCAN_TORQUE: 'torque = "torque"\ndirection = "direction"\n',
}


def make_scan_logs(config: Path, bench: Path, folder: Path, seed: int) -> None:
    """Scan logs of the simulated drive of ``config`` (one revolution each way, 4 rows per count) and their
    mappings, with the sensors' true errors in [scan], in ``folder``."""
    from ilcpmac.config import load_config
    from ilcpmac.sim.simulator import Simulator
    from ilcpmac.sim.standstill import ScanPlan, write_scan_log

    model = load_config(config).model
    simulator = Simulator(model)
    folder.mkdir()
    shutil.copy(bench / "backemf.csv", folder / "backemf.csv")
    write_scan_log(folder / SCAN_LOG, simulator, ScanPlan(seed=seed))
    write_scan_log(folder / SCAN_TORQUE_LOG, simulator, ScanPlan(holding="torque", seed=seed + 1))
    t = simulator.truth(model.controller.calibration())
    head = (mapping_bench(bench) + '[log]\nkind = "scan"\ntime = "time"\nposition = "position"\n'
            f'position_unit = "counts"\nposition_counts_per_rev = {model.encoder.counts_per_rev}\n')
    errors = f"\n[scan]\nepsilon = {t.epsilon}\nalpha = {t.alpha.tolist()}\nbeta_a = {t.beta_a.tolist()}\n"
    for name, layout in SCAN_LAYOUTS.items():
        (folder / name).write_text(head + layout + (f"\n[scan]\ntorque_sensor_gain = {t.delta}\n"
                                                    if name == MAP_SCAN_TORQUE else errors))


def scan_csv(fn: Callable[[list[str], list[list[str]]], tuple]) -> Callable:
    return rows_edit(fn, SCAN_CSV)


def scan_toml(name: str, value: str | None) -> Callable:
    return lambda d, rng: edit(d / SCAN_TOML, lambda t: toml_set(t, "scan", name, value))


def _keep_rows(keep: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> Callable:
    """scan.csv with the rows ``keep(position, direction)`` selects."""
    def fn(header, rows):
        position = np.array([float(r[header.index("position")]) for r in rows])
        direction = np.array([float(r[header.index("direction")]) for r in rows])
        return header, [r for r, k in zip(rows, keep(position, direction)) if k]
    return scan_csv(fn)


def _add_column(name: str, value: str) -> Callable:
    return scan_csv(lambda h, r: (h + [name], [x + [value] for x in r]))


def _drop_column(name: str) -> Callable:
    def fn(header, rows):
        j = header.index(name)
        return header[:j] + header[j + 1:], [r[:j] + r[j + 1:] for r in rows]
    return scan_csv(fn)


def _scan_outside(d: Path, rng) -> None:
    shutil.copy(d / SCAN_CSV, d.parent / "outside.csv")
    scan_toml("file", '"../outside.csv"')(d, rng)


#: (name, must be rejected, mutation(folder, rng), the torque scan's folder) of the scan folder mutations
SCAN_MUTATIONS: list[tuple[str, bool, Callable, bool]] = [
    ("holding-currents scan as imported", False, lambda d, rng: None, False),
    ("holding-torque scan as imported", False, lambda d, rng: None, True),
    # directions
    ("direction 0 in a row", True, cell(100, "direction", "0", SCAN_CSV), False),
    ("direction 2 in a row", True, cell(101, "direction", "2", SCAN_CSV), False),
    ("direction 0.5 in a row", True, cell(102, "direction", "0.5", SCAN_CSV), False),
    ("direction NaN in a row", True, cell(103, "direction", "nan", SCAN_CSV), False),
    ("direction text", True, cell(104, "direction", "fwd", SCAN_CSV), False),
    ("direction all forward", True, column("direction", np.abs, (SCAN_CSV,)), False),
    ("direction all reverse", True, column("direction", lambda s: -np.abs(s), (SCAN_CSV,)), True),
    ("directions swapped", False, column("direction", np.negative, (SCAN_CSV,)), False),
    ("forward rows only", True, _keep_rows(lambda p, s: s > 0), False),
    ("reverse rows only", True, _keep_rows(lambda p, s: s < 0), True),
    ("direction column missing", True, _drop_column("direction"), False),
    # counts and samples
    # a count without a sample is filled from its neighbours, said in a warning (docs/standstill.md, issue 24)
    ("count 100 without samples", False, _keep_rows(lambda p, s: np.round(p) % 4096 != 100), False),
    ("count 7 without reverse samples", False, _keep_rows(lambda p, s: (s > 0) | (np.round(p) % 4096 != 7)), True),
    ("counts 300-350 without samples", True, _keep_rows(lambda p, s: (np.round(p) % 4096 < 300)
                                                         | (np.round(p) % 4096 > 350)), False),
    ("one sample per count and direction", True, _keep_rows(lambda p, s: np.arange(p.size) % 4 == 0), False),
    ("half a revolution", True, _keep_rows(lambda p, s: p < 2048), False),
    ("position shifted by one revolution", False, column("position", lambda p: p + 4096, (SCAN_CSV,)), False),
    ("position shifted by 2^41 counts", True, column("position", lambda p: p + 2.0**41, (SCAN_CSV,)), False),
    ("position 1e300 in a row", True, cell(105, "position", "1e300", SCAN_CSV), False),
    ("position negated", False, column("position", np.negative, (SCAN_CSV,)), False),
    ("position frozen", True, column("position", lambda p: np.full_like(p, 5.0), (SCAN_CSV,)), False),
    ("position missing", True, _drop_column("position"), False),
    ("time going back", False, cell(106, "time", "0", SCAN_CSV), False),
    ("time constant", False, column("time", np.zeros_like, (SCAN_CSV,)), False),
    # values
    ("NaN current", True, cell(107, "i_b", "nan", SCAN_CSV), False),
    ("inf torque", True, cell(108, "torque", "inf", SCAN_CSV), True),
    ("NaN time", True, cell(109, "time", "nan", SCAN_CSV), False),
    ("NaN position", True, cell(110, "position", "NaN", SCAN_CSV), False),
    ("empty cell", True, cell(111, "i_a", "", SCAN_CSV), False),
    ("current 1e6 A", True, cell(112, "i_c", "1e6", SCAN_CSV), False),
    ("torque 1e300", True, cell(113, "torque", "1e300", SCAN_CSV), True),
    ("currents all zero", False, _both(*(column(c, np.zeros_like, (SCAN_CSV,)) for c in ("i_a", "i_b", "i_c"))),
     False),
    ("torque constant", False, column("torque", np.ones_like, (SCAN_CSV,)), True),
    ("both currents and torque", True, _add_column("torque", "0.5"), False),
    ("neither currents nor torque", True, _drop_column("torque"), True),
    ("one current missing", True, _drop_column("i_c"), False),
    ("extra unknown column", False, _add_column("note", "1"), False),
    ("columns reordered", False, scan_csv(lambda h, r: (h[::-1], [x[::-1] for x in r])), False),
    ("row cut short", True, scan_csv(lambda h, r: (h, r[:50] + [r[50][:-1]] + r[51:])), False),
    # files
    ("scan.csv empty", True, raw(SCAN_CSV, lambda b: b""), False),
    ("scan.csv header only", True, raw(SCAN_CSV, lambda b: b.split(b"\n", 1)[0] + b"\n"), False),
    ("scan.csv binary", True, raw(SCAN_CSV, lambda b: bytes(range(256)) * 64), False),
    ("scan.csv UTF-16", True, raw(SCAN_CSV, lambda b: b.decode().encode("utf-16")), False),
    ("scan.csv CRLF", False, raw(SCAN_CSV, lambda b: b.replace(b"\n", b"\r\n")), False),
    ("scan.csv is a FIFO", True, _fifo_file(SCAN_CSV), False),
    ("scan.csv symlink to /dev/zero", True, _symlink("/dev/zero", SCAN_CSV), False),
    ("scan.csv is a directory", True, _directory(SCAN_CSV), False),
    ("scan.csv missing", True, _remove(SCAN_CSV), False),
    ("scan.csv 2 GiB sparse", True, _sparse(SCAN_CSV, 2 << 30), False),
    ("scan.csv symlink outside the folder", True, _symlink(lambda d: shutil.copy(d / SCAN_CSV, d.parent / "o.csv"),
                                                           SCAN_CSV), False),
    # scan.toml
    ("scan.toml unknown key", True, scan_toml("epsilonn", "0.7"), False),
    ("scan.toml unknown table", True, lambda d, rng: edit(d / SCAN_TOML, lambda t: t + "\n[scan2]\nx = 1\n"), False),
    ("scan.toml file '../outside.csv'", True, _scan_outside, False),
    ("scan.toml file absolute path to a secret", True, lambda d, rng: scan_toml("file", f'"{_secret(d)}"')(d, rng),
     False),
    ("scan.toml file 42", True, scan_toml("file", "42"), False),
    ("scan.toml file ''", True, scan_toml("file", '""'), False),
    ("scan.toml file '.'", True, scan_toml("file", '"."'), False),
    ("scan.toml file renamed", False, _both(lambda d, rng: (d / SCAN_CSV).rename(d / "other.csv"),
                                            scan_toml("file", '"other.csv"')), False),
    ("scan.toml epsilon 0", True, scan_toml("epsilon", "0.0"), False),
    ("scan.toml epsilon nan", True, scan_toml("epsilon", "nan"), False),
    ("scan.toml epsilon 1e300", True, scan_toml("epsilon", "1e300"), False),
    ("scan.toml alpha two values", True, scan_toml("alpha", "[1.0, 1.0]"), False),
    ("scan.toml beta_a 1e300", True, scan_toml("beta_a", "[1e300, 0.0, 0.0]"), False),
    ("scan.toml epsilon_std -1", True, scan_toml("epsilon_std", "-1.0"), False),
    ("scan.toml torque_sensor_gain 0", True, scan_toml("torque_sensor_gain", "0.0"), True),
    ("scan.toml [scan] empty", False, raw(SCAN_TOML, lambda b: b"[scan]\n"), False),
    ("scan.toml empty", True, raw(SCAN_TOML, lambda b: b""), False),
    ("scan.toml binary", True, raw(SCAN_TOML, lambda b: b"\xff\xfe\x00" + bytes(range(256)) * 8), False),
    ("scan.toml nested 100000 deep", True, raw(SCAN_TOML, lambda b: b + b"x = " + b"[" * 100_000 + b"]" * 100_000),
     False),
    ("scan.toml is a directory", True, _directory(SCAN_TOML), False),
    ("scan.toml symlink to /dev/zero", True, _symlink("/dev/zero", SCAN_TOML), False),
    ("scan.toml missing", True, _remove(SCAN_TOML), False),
    # bench.toml and backemf.csv of a scan folder
    ("[[trials]] in a scan folder", True, lambda d, rng: edit(d / "bench.toml", lambda t: t + (
        '\n[[trials]]\nfile = "scan.csv"\ntorque_setpoint = 1.0\nspeed_setpoint = 0.8\n')), False),
    ("counts_per_rev 1024 on 4096-count data (4 revolutions each way)", False, _cpr(1024), False),
    ("counts_per_rev 8192 on 4096-count data", False, _cpr(8192), False),
    ("backemf.csv missing", True, _remove("backemf.csv"), False),
    ("backemf NaN", True, rows_edit(lambda h, r: (h, r[:3] + [[r[3][0], "nan", *r[3][2:]]] + r[4:]), "backemf.csv"),
     False),
    ("bench.toml missing", True, _remove("bench.toml"), False),
    ("pole_pairs 0", True, key("motor", "pole_pairs", "0"), False),
    ("slots 10^18", True, key("motor", "slots", str(10**18)), False),
]


def _split_scan(d: Path, rng) -> None:
    """The scan log as two logs: the forward revolution (4096 counts x 4 rows), then the way back."""
    header, *rows = (d / SCAN_LOG).read_bytes().split(b"\n")
    (d / "fwd.csv").write_bytes(b"\n".join([header, *rows[:16384], b""]))
    (d / "back.csv").write_bytes(b"\n".join([header, *rows[16384:]]))


#: (name, must be rejected, mutation(folder, rng), logs and mapping) of ``ilcpmac import`` on scan logs
SCAN_ARGS: Args = lambda d: [d / SCAN_LOG, "--map", d / MAP_SCAN]  # noqa: E731
SCAN_IMPORTS: list[tuple[str, bool, Callable, Args]] = [
    ("scan log of holding currents, direction column", False, lambda d, rng: None, SCAN_ARGS),
    ("scan log of i_q, direction from the motion", False, lambda d, rng: None,
     lambda d: [d / SCAN_LOG, "--map", d / MAP_SCAN_Q]),
    ("scan log of holding torque", False, lambda d, rng: None,
     lambda d: [d / SCAN_TORQUE_LOG, "--map", d / MAP_SCAN_TORQUE]),
    ("scan in two logs, forward and back", False, _split_scan, lambda d: [d / "fwd.csv", d / "back.csv", "--map",
                                                                            d / MAP_SCAN]),
    ("scan log forward only", False, _log_lines(lambda ls: ls[:16385], SCAN_LOG), SCAN_ARGS),
    ("scan mapping with currents and torque", True, mapping("log", "torque", '"i_q"', MAP_SCAN), SCAN_ARGS),
    ("scan mapping with neither", True, mapping("log", "phase_currents", None, MAP_SCAN), SCAN_ARGS),
    ("scan mapping with i_q and phase currents", True, mapping("log", "i_q", '"i_q"', MAP_SCAN), SCAN_ARGS),
    ("scan direction column missing from the log", True, mapping("log", "direction", '"dir"', MAP_SCAN), SCAN_ARGS),
    ("scan direction 0 in a row", True, cell(500, "direction", "0", SCAN_LOG), SCAN_ARGS),
    ("scan direction NaN in a row", True, cell(501, "direction", "nan", SCAN_LOG), SCAN_ARGS),
    ("scan direction 5 and -5", False, column("direction", lambda s: 5 * s, (SCAN_LOG,)), SCAN_ARGS),
    ("scan position frozen, no direction column", True, column("position", np.zeros_like, (SCAN_LOG,)),
     lambda d: [d / SCAN_LOG, "--map", d / MAP_SCAN_Q]),
    ("scan NaN current", True, cell(502, "i_a", "nan", SCAN_LOG), SCAN_ARGS),
    ("scan current_a_per_unit 1e6", True, mapping("log", "current_a_per_unit", "1e6", MAP_SCAN), SCAN_ARGS),
    ("scan torque_nm_per_unit 1e9", True, mapping("log", "torque_nm_per_unit", "1e9", MAP_SCAN_TORQUE),
     lambda d: [d / SCAN_TORQUE_LOG, "--map", d / MAP_SCAN_TORQUE]),
    ("scan position_counts_per_rev 1", False, mapping("log", "position_counts_per_rev", "1", MAP_SCAN), SCAN_ARGS),
    ("scan [scan] unknown key", True, mapping("scan", "gain", "1.0", MAP_SCAN), SCAN_ARGS),
    ("scan [scan] epsilon 0", True, mapping("scan", "epsilon", "0.0", MAP_SCAN), SCAN_ARGS),
    ("scan [scan] alpha nan", True, mapping("scan", "alpha", "[nan, 1.0, 1.0]", MAP_SCAN), SCAN_ARGS),
    ("scan [scan] beta_a a string", True, mapping("scan", "beta_a", '"0"', MAP_SCAN), SCAN_ARGS),
    ("scan [scan] as an array of tables", True, mapping_text(lambda t: t.replace("[scan]", "[[scan]]"), MAP_SCAN),
     SCAN_ARGS),
    ('scan kind "stand"', True, mapping("log", "kind", '"stand"', MAP_SCAN), SCAN_ARGS),
    ("scan log binary", True, raw(SCAN_LOG, lambda b: bytes(range(256)) * 64), SCAN_ARGS),
    ("scan log header only", True, _log_lines(lambda ls: ls[:1] + [b""], SCAN_LOG), SCAN_ARGS),
    ("scan torque log under the currents mapping", True, lambda d, rng: None,
     lambda d: [d / SCAN_TORQUE_LOG, "--map", d / MAP_SCAN]),
]


# ---------------------------------------------------------------- 6. sweep specs

#: a valid spec over the small config: two identifications with the current sensors' gain drawn
SWEEP_SPEC = """[sweep]
kind = "identify"
tasks = 2
seed = 14

[draw."simulator.current_sensors.epsilon"]
distribution = "normal"
relative_std = 0.02
"""
#: what ``ilcpmac sweep`` prints once the spec and every task's draws are checked, before any cluster starts: a
#: case is stopped there (accepted), since a cluster and its tasks take longer than the fuzz waits
SWEEP_ACCEPTED = b"tasks; their configs are in"
EPSILON = 'draw."simulator.current_sensors.epsilon"'


def _draw(key: str, body: str) -> Callable[[str], str]:
    """The spec with the table [draw."KEY"] of ``body`` (lines) added."""
    return lambda t: t + f'\n[draw."{key}"]\n{body}\n'


def _spec_set(table: str, name: str, value: str | None) -> Callable[[str], str]:
    return lambda t: toml_set(t, table, name, value)


def _grid(n: int) -> Callable[[str], str]:
    """Three grid draws of ``n`` values each: n^3 tasks."""
    values = "[" + ", ".join(f"{100.0 + i * 1e-3:.4f}" for i in range(n)) + "]"
    return lambda t: t + "".join(f'\n[draw."{k}"]\ndistribution = "grid"\nvalues = {values}\n' for k in (
        "simulator.controller.bandwidth_hz", "simulator.controller.voltage_limit_v",
        "simulator.winding.phase_resistance_ohm"))


#: (name, must be rejected, spec text from the valid one) of the spec mutations
SPEC_MUTATIONS: list[tuple[str, bool, Callable[[str], str | bytes]]] = [
    ("valid spec (stopped once accepted)", False, lambda t: t),
    ("spec empty (one task, nothing drawn)", False, lambda t: ""),
    ("spec not TOML", True, lambda t: "this is [not toml\n"),
    ("spec binary", True, lambda t: b"\xff\xfe\x00" + bytes(range(256)) * 8),
    ("spec UTF-16", True, lambda t: t.encode("utf-16")),
    ("spec nested 100000 deep", True, lambda t: t + "x = " + "[" * 100_000 + "]" * 100_000 + "\n"),
    ("spec 2 MB comment", True, lambda t: "#" + "x" * 2_000_000 + "\n" + t),
    ("spec cut mid-table", True, lambda t: t[:t.index("distribution") + 6]),
    ("unknown table [sweeps]", True, lambda t: t + "\n[sweeps]\ntasks = 2\n"),
    ("[sweep] unknown key", True, _spec_set("sweep", "workers", "2")),
    ("[sweep] a list", True, lambda t: t.replace("[sweep]", "[[sweep]]")),
    ('kind "bogus"', True, _spec_set("sweep", "kind", '"bogus"')),
    ("kind 3", True, _spec_set("sweep", "kind", "3")),
    ("tasks 0", True, _spec_set("sweep", "tasks", "0")),
    ("tasks -1", True, _spec_set("sweep", "tasks", "-1")),
    ("tasks 1.5", True, _spec_set("sweep", "tasks", "1.5")),
    ("tasks true", True, _spec_set("sweep", "tasks", "true")),
    ("tasks nan", True, _spec_set("sweep", "tasks", "nan")),
    ("tasks 10^12", True, _spec_set("sweep", "tasks", str(10**12))),
    ("tasks 2^64", True, _spec_set("sweep", "tasks", str(2**64))),
    ("tasks 100001", True, _spec_set("sweep", "tasks", "100001")),
    ("seed -1", True, _spec_set("sweep", "seed", "-1")),
    ("seed 2^64", True, _spec_set("sweep", "seed", str(2**64))),
    ("seed a string", True, _spec_set("sweep", "seed", '"14"')),
    # distributions
    ('distribution "poisson"', True, _spec_set(EPSILON, "distribution", '"poisson"')),
    ("distribution missing", True, _spec_set(EPSILON, "distribution", None)),
    ("distribution 3", True, _spec_set(EPSILON, "distribution", "3")),
    ("normal std and relative_std", True, _spec_set(EPSILON, "std", "0.01")),
    ("normal neither std", True, _spec_set(EPSILON, "relative_std", None)),
    ("normal std -1", True, lambda t: _spec_set(EPSILON, "std", "-1.0")(_spec_set(EPSILON, "relative_std", None)(t))),
    ("normal relative_std -0.5", True, _spec_set(EPSILON, "relative_std", "-0.5")),
    ("normal std nan", True, lambda t: _spec_set(EPSILON, "std", "nan")(_spec_set(EPSILON, "relative_std", None)(t))),
    ("normal std inf", True, lambda t: _spec_set(EPSILON, "std", "inf")(_spec_set(EPSILON, "relative_std", None)(t))),
    ("normal std 1e300", True,
     lambda t: _spec_set(EPSILON, "std", "1e300")(_spec_set(EPSILON, "relative_std", None)(t))),
    ("normal mean -1 (draws out of range)", True, _spec_set(EPSILON, "mean", "-1.0")),
    ("normal mean a string", True, _spec_set(EPSILON, "mean", '"0.7"')),
    ("normal mean 1e308", True, _spec_set(EPSILON, "mean", "1e308")),
    ("normal unknown key", True, _spec_set(EPSILON, "sigma", "0.1")),
    ("normal with values", True, _spec_set(EPSILON, "values", "[1.0]")),
    ("uniform low > high", True, _draw("simulator.controller.bandwidth_hz",
                                       'distribution = "uniform"\nlow = 200.0\nhigh = 100.0')),
    ("uniform missing high", True, _draw("simulator.controller.bandwidth_hz", 'distribution = "uniform"\nlow = 1.0')),
    ("uniform relative and low", True, _draw("simulator.controller.bandwidth_hz",
                                             'distribution = "uniform"\nrelative = 0.1\nlow = 1.0')),
    ("uniform relative 3 (reaching below zero; each task's draw is checked)", False,
     _draw("simulator.controller.bandwidth_hz", 'distribution = "uniform"\nrelative = 3.0')),
    ("uniform low -inf", True, _draw("simulator.controller.bandwidth_hz",
                                     'distribution = "uniform"\nlow = -inf\nhigh = 100.0')),
    ("uniform -1e308 to 1e308", True, _draw("simulator.controller.bandwidth_hz",
                                            'distribution = "uniform"\nlow = -1e308\nhigh = 1e308')),
    ("uniform on a list, 2 lows for 3", True, _draw("simulator.current_sensors.alpha",
                                                    'distribution = "uniform"\nlow = [0.9, 0.9]\nhigh = 1.1')),
    ("uniform on a string key", True, _draw("stages.ilc.estimation", 'distribution = "uniform"\nrelative = 0.1')),
    ("choice values []", True, _draw("simulator.controller.bandwidth_hz", 'distribution = "choice"\nvalues = []')),
    ("choice values a string", True, _draw("simulator.controller.bandwidth_hz",
                                           'distribution = "choice"\nvalues = "100"')),
    ("choice of texts on a number", True, _draw("simulator.controller.bandwidth_hz",
                                                'distribution = "choice"\nvalues = ["a", "b"]')),
    ("choice of lists on a number", True, _draw("simulator.controller.bandwidth_hz",
                                                'distribution = "choice"\nvalues = [[1.0, 2.0]]')),
    ("choice values of tables", True, _draw("simulator.controller.bandwidth_hz",
                                            'distribution = "choice"\nvalues = [{ a = 1 }]')),
    ("choice pole_pairs [0]", True, _draw("bench.pole_pairs", 'distribution = "choice"\nvalues = [0]')),
    ("choice stages [['nope']]", True, _draw("pipeline.stages", 'distribution = "choice"\nvalues = [["nope"]]')),
    ("choice backemf_file of a missing file", True, _draw("bench.backemf_file",
                                                          'distribution = "choice"\nvalues = ["/nonexistent.csv"]')),
    ("choice trials.seed [-1]", True, _draw("trials.seed", 'distribution = "choice"\nvalues = [-1]')),
    ("grid counts_per_rev [0, 4096]", True, _draw("bench.counts_per_rev", 'distribution = "grid"\nvalues = [0, 4096]')),
    ("grid of 10^9 tasks (3 x 1000 values)", True, _grid(1000)),
    ("grid values nan", True, _draw("simulator.controller.bandwidth_hz", 'distribution = "grid"\nvalues = [nan]')),
    # keys
    ("key the config lacks: simulator.mechanics.nope", True, _draw("simulator.mechanics.nope",
                                                                    'distribution = "normal"\nstd = 0.1')),
    ("key of no table: nope.key", True, _draw("nope.key", 'distribution = "normal"\nstd = 0.1')),
    ("key without a table", True, _draw("epsilon", 'distribution = "normal"\nstd = 0.1')),
    ("key empty", True, _draw("", 'distribution = "normal"\nstd = 0.1')),
    ("key a table: simulator.current_sensors", True, _draw("simulator.current_sensors",
                                                           'distribution = "normal"\nstd = 0.1')),
    ("key alpha[3] of 3", True, _draw("simulator.current_sensors.alpha[3]", 'distribution = "normal"\nstd = 0.1')),
    ("key alpha[-1]", True, _draw("simulator.current_sensors.alpha[-1]", 'distribution = "normal"\nstd = 0.1')),
    ("key alpha[99999999999999999999]", True, _draw("simulator.current_sensors.alpha[99999999999999999999]",
                                                    'distribution = "normal"\nstd = 0.1')),
    ("key epsilon[0] of a number", True, _draw("simulator.current_sensors.epsilon[0]",
                                               'distribution = "normal"\nstd = 0.1')),
    ("key the controller knows: simulator.mechanics.inertia_kgm2", True,
     _draw("simulator.mechanics.inertia_kgm2", 'distribution = "normal"\nrelative_std = 0.1')),
    ("key the same twice", True, lambda t: t + f"\n[{EPSILON}]\ndistribution = \"normal\"\nstd = 0.1\n"),
    ("draw a number, not a table", True, lambda t: t + '\n[draw]\n"simulator.controller.bandwidth_hz" = 3\n'),
    ("[draw] a list", True, lambda t: t.replace(f"[{EPSILON}]", "[[draw]]")),
    # [magnets]
    ("magnets rise [80, 0]", True, lambda t: t + "\n[magnets]\ntemperature_rise_k = [80.0, 0.0]\n"
                                                 "coefficient_per_k = -0.001\n"),
    ("magnets make the back-EMF vanish", True, lambda t: t + "\n[magnets]\ntemperature_rise_k = [0.0, 80.0]\n"
                                                             "coefficient_per_k = -0.1\n"),
    ("magnets coefficient missing", True, lambda t: t + "\n[magnets]\ntemperature_rise_k = [0.0, 80.0]\n"),
    ("magnets rise nan", True, lambda t: t + "\n[magnets]\ntemperature_rise_k = [nan, 80.0]\n"
                                             "coefficient_per_k = -0.001\n"),
    ("magnets unknown key", True, lambda t: t + "\n[magnets]\ntemperature_rise_k = [0.0, 80.0]\n"
                                                "coefficient_per_k = -0.001\nmaterial = \"NdFeB\"\n"),
    ("magnets over a backemf_scale draw out of range", True, lambda t: t + (
        '\n[draw."simulator.winding.backemf_scale"]\ndistribution = "choice"\nvalues = [20.0]\n'
        "\n[magnets]\ntemperature_rise_k = [0.0, 80.0]\ncoefficient_per_k = -0.001\n")),
    # the most tasks allowed: every task's draws are checked before anything runs (its config when submitted)
    ("tasks 100000 (the most allowed)", False, _spec_set("sweep", "tasks", "100000")),
]


def _random_log_mutations(rng: np.random.Generator, n: int) -> list[tuple[str, bool, Callable, Args]]:
    """Seeded random damage to a drive log: byte flips, truncations, NaN/inf cells, dropped rows."""
    out: list[tuple[str, bool, Callable, Args]] = []
    names = ["t", "theta", "ia", "ib", "ic", "tq"]
    for k in range(n):
        s = int(rng.integers(2**31))
        if k % 4 == 0:
            flips = int(rng.integers(1, 20))
            out.append((f"{flips} random byte flips in a log (s{s})", False, raw(LOG_A, _flipper(s, flips)),
                        PHASE_ARGS))
        elif k % 4 == 1:
            out.append((f"log truncated at a random byte (s{s})", False,
                        raw(LOG_A, lambda b, s=s: b[:np.random.default_rng(s).integers(1, len(b))]), PHASE_ARGS))
        elif k % 4 == 2:
            value, name = ["nan", "inf", "-inf", "NaN", "Infinity"][s % 5], names[s % 6]
            out.append((f"{value} in {name} at a random row (s{s})", True, cell(1 + s % 4900, name, value, LOG_A),
                        PHASE_ARGS))
        else:
            out.append((f"random log rows deleted (s{s})", False, rows_edit(
                lambda h, r, s=s: (h, [x for x, keep in zip(r, np.random.default_rng(s).random(len(r)) > 0.01)
                                       if keep]), LOG_A), PHASE_ARGS))
    return out


def import_case(category: str, base: Path, name: str, must_reject: bool, mutate: Callable, args: Args) -> Case:
    """``ilcpmac import`` of ``args(folder)`` (logs, mapping), in a copy of ``base`` mutated; --out a new folder
    unless ``args`` gives one."""
    def run(folder: Path) -> Run:
        d = folder / "logs"
        shutil.copytree(base, d, symlinks=True)
        mutate(d, None)
        argv = [str(a) for a in args(d)]
        out = folder / "out"
        if "--out" not in argv:
            argv += ["--out", str(out)]
        return ilcpmac("import", *argv, folder=folder, written=out)
    return Case(category, name, must_reject, run)


def import_cases(base: Path, seed: int) -> list[Case]:
    rng = np.random.default_rng(seed + 3)
    return [import_case("import: mappings & logs", base, *m)
            for m in IMPORT_MUTATIONS + _random_log_mutations(rng, 16)]


def _random_scan_mutations(rng: np.random.Generator, n: int) -> list[tuple[str, bool, Callable, bool]]:
    """Seeded random damage to scan.csv: byte flips, NaN/inf cells, dropped rows."""
    out: list[tuple[str, bool, Callable, bool]] = []
    names = ["time", "position", "direction", "i_a", "i_b", "i_c"]
    for k in range(n):
        s = int(rng.integers(2**31))
        if k % 3 == 0:
            flips = int(rng.integers(1, 20))
            out.append((f"{flips} random byte flips in scan.csv (s{s})", False, raw(SCAN_CSV, _flipper(s, flips)),
                        False))
        elif k % 3 == 1:
            value, name = ["nan", "inf", "-inf", "NaN", "Infinity"][s % 5], names[s % 6]
            out.append((f"{value} in {name} of scan.csv at a random row (s{s})", True,
                        cell(1 + s % 32000, name, value, SCAN_CSV), False))
        else:
            out.append((f"random scan rows deleted (s{s})", False, rows_edit(
                lambda h, r, s=s: (h, [x for x, keep in zip(r, np.random.default_rng(s).random(len(r)) > 0.01)
                                       if keep]), SCAN_CSV), False))
    return out


def scan_cases(currents: Path, torque: Path, logs: Path, seed: int) -> list[Case]:
    """Scan folders (``currents`` and ``torque``, as imported) mutated and identified; scan logs (``logs``)
    imported under mutated mappings."""
    rng = np.random.default_rng(seed + 4)

    def make(name: str, must_reject: bool, mutate: Callable, on_torque: bool) -> Case:
        def run(folder: Path) -> Run:
            d = folder / "scan"
            shutil.copytree(torque if on_torque else currents, d, symlinks=True)
            mutate(d, None)
            out = folder / "scan.json"
            return ilcpmac("identify", d, "--output", out, folder=folder, written=out)
        return Case("standstill scans", name, must_reject, run)

    return [make(*m) for m in SCAN_MUTATIONS + _random_scan_mutations(rng, 9)] + [
        import_case("standstill scans", logs, *m) for m in SCAN_IMPORTS]


def _resume_folder(result: Callable[[Path], None], spec: str, config: Path) -> Callable[[Path], Path]:
    """A sweep folder of the one-task ``spec`` over ``config`` whose results/task_0000.parquet is made by
    ``result(path)``; returns the folder."""
    def make(folder: Path) -> Path:
        out = folder / "sweep"
        (out / "results").mkdir(parents=True)
        (out / "sweep.toml").write_text(spec)
        (out / "config.toml").write_text(config.read_text())
        result(out / "results" / "task_0000.parquet")
        return out
    return make


def _parquet_of_another_table(path: Path) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    pq.write_table(pa.table({"x": [1.0]}), path)


def sweep_cases(config: Path) -> list[Case]:
    """Hostile specs and arguments of ``ilcpmac sweep CONFIG --spec SPEC --out DIR --workers 1``.

    Each spec case is stopped once the sweep prints that its tasks are ready (`SWEEP_ACCEPTED`); the
    resume and scheduler cases, which may end before any cluster starts, run to their end.
    """
    one_task = toml_set(SWEEP_SPEC, "sweep", "tasks", "1")

    def spec_case(name: str, must_reject: bool, fn: Callable[[str], str | bytes]) -> Case:
        def run(folder: Path) -> Run:
            spec = folder / "spec.toml"
            text = fn(SWEEP_SPEC)
            spec.write_bytes(text if isinstance(text, bytes) else text.encode())
            out = folder / "sweep"
            return ilcpmac("sweep", config, "--spec", spec, "--out", out, "--workers", 1, folder=folder, written=out,
                           stop_at=SWEEP_ACCEPTED)
        return Case("sweep specs", name, must_reject, run)

    def arg_case(name: str, args: Callable[[Path], list], stop: bool = True) -> Case:
        def run(folder: Path) -> Run:
            (folder / "spec.toml").write_text(one_task)
            return ilcpmac("sweep", *args(folder), folder=folder, written=folder,
                           stop_at=SWEEP_ACCEPTED if stop else None)
        return Case("sweep specs", name, True, run)

    def resume(name: str, result: Callable[[Path], None]) -> Case:
        folder_of = _resume_folder(result, one_task, config)
        return arg_case(name, lambda f: [config, "--spec", f / "spec.toml", "--out", folder_of(f), "--resume"],
                        stop=False)

    spec = lambda f: ["--spec", f / "spec.toml"]  # noqa: E731
    return [spec_case(*m) for m in SPEC_MUTATIONS] + [
        arg_case("--spec is a directory", lambda f: [config, "--spec", f, "--out", f / "o", "--workers", 1]),
        arg_case("--spec missing", lambda f: [config, "--spec", f / "none.toml", "--out", f / "o", "--workers", 1]),
        arg_case("--spec is a FIFO", lambda f: (os.mkfifo(f / "fifo.toml"), [
            config, "--spec", f / "fifo.toml", "--out", f / "o", "--workers", 1])[1]),
        arg_case("--spec symlink to /dev/zero", lambda f: ((f / "z.toml").symlink_to("/dev/zero"), [
            config, "--spec", f / "z.toml", "--out", f / "o", "--workers", 1])[1]),
        arg_case("CONFIG missing", lambda f: [f / "none.toml", *spec(f), "--out", f / "o", "--workers", 1]),
        arg_case("CONFIG is the spec", lambda f: [f / "spec.toml", *spec(f), "--out", f / "o", "--workers", 1]),
        arg_case("CONFIG without [simulator] (a real bench)", lambda f: [REAL_CONFIG, *spec(f), "--out", f / "o",
                                                                         "--workers", 1]),
        arg_case("--out is a file", lambda f: [config, *spec(f), "--out", f / "spec.toml", "--workers", 1]),
        arg_case("--out under /dev/null", lambda f: [config, *spec(f), "--out", "/dev/null/x", "--workers", 1]),
        arg_case("--workers 0", lambda f: [config, *spec(f), "--out", f / "o", "--workers", 0]),
        arg_case("--workers 10^6", lambda f: [config, *spec(f), "--out", f / "o", "--workers", 10**6]),
        arg_case("--scheduler with --workers", lambda f: [config, *spec(f), "--out", f / "o", "--workers", 1,
                                                           "--scheduler", "tcp://127.0.0.1:9"]),
        arg_case("--scheduler a:b:c", lambda f: [config, *spec(f), "--out", f / "o", "--scheduler", "a:b:c"],
                 stop=False),
        arg_case("--scheduler with nobody listening", lambda f: [config, *spec(f), "--out", f / "o",
                                                                 "--scheduler", "tcp://127.0.0.1:9"], stop=False),
        arg_case("--resume a missing folder", lambda f: [config, *spec(f), "--out", f / "none", "--resume"]),
        arg_case("--resume a folder that is not a sweep", lambda f: [config, *spec(f), "--out", f, "--resume"]),
        arg_case("--resume a sweep of another spec", lambda f: [
            config, "--spec", f / "spec.toml", "--out",
            _resume_folder(lambda p: None, SWEEP_SPEC, config)(f), "--resume"]),
        arg_case("--out holds results, no --resume", lambda f: [
            config, *spec(f), "--out", _resume_folder(lambda p: p.write_bytes(b"x"), one_task, config)(f)]),
        resume("--resume with a corrupt Parquet result", lambda p: p.write_bytes(b"PAR1" + bytes(range(256)) * 4)),
        resume("--resume with an empty result file", lambda p: p.write_bytes(b"")),
        resume("--resume with a Parquet result of another table", _parquet_of_another_table),
        resume("--resume with a result that is a directory", lambda p: p.mkdir()),
        resume("--resume with a result symlink to /dev/zero", lambda p: p.symlink_to("/dev/zero")),
    ]


# ---------------------------------------------------------------- 7. plugin stages that break

#: the wall time a stage call may take in the hanging-stage cases, s (STAGE_CALL_S lowered in the probe's process:
#: 30 s would outlast TIMEOUT_S). It bounds the built-ins' calls too: the slowest, the current-sensor stage's
#: factory, takes 1.2 s cold (ilcpmac.pipeline.pipeline) and at 1 s it timed out here; 5 s is 4x that
FUZZ_STAGE_CALL_S = 5.0
SMALL_CAMPAIGN_TOML, STAGE_CAMPAIGN_TOML = "small-campaign.toml", "stage-campaign.toml"


def campaign_toml(changes: dict) -> str:
    """configs/seed-bench.toml with ``changes`` ({dotted table: {key: value}}, as tests/conftest.py's
    write_config takes them) as TOML text."""
    import tomllib

    from ilcpmac.core.schema import toml_text

    data = tomllib.loads(SEED_CONFIG.read_text())
    for table, values in changes.items():
        node = data
        for part in table.split("."):
            node = node.setdefault(part, {})
        node.update(values)
    return toml_text(data)


def make_campaign_configs(scratch: Path) -> None:
    """The small campaign of tests/campaign_helpers.py (1024 counts, a 2 x 2 grid, 18 trials, about 3 s), and
    the same with two learning trials per point and the broken stage after the built-ins (as
    tests/test_stage_failures.py runs it), in ``scratch``."""
    sys.path.insert(0, str(ROOT / "tests"))
    from campaign_helpers import SMALL_CAMPAIGN

    (scratch / SMALL_CAMPAIGN_TOML).write_text(campaign_toml(SMALL_CAMPAIGN))
    (scratch / STAGE_CAMPAIGN_TOML).write_text(campaign_toml({
        **SMALL_CAMPAIGN, "pipeline": {"stages": ["current-sensor", "cogging", "ilc", ft.BROKEN_STAGE]},
        "campaign": {**SMALL_CAMPAIGN["campaign"], "learn_trials": 2}}))


_PROBE_LINE = re.compile(rf"{ft.PROBE} requests (\d+) peak_true_current_a (\S+) max_current_a (\S+)")
_PROBE_BREACH = re.compile(rf"{ft.PROBE}-breach (.+)")


def probe(*args, folder: Path, opts: tuple = (), written: Path | None = None) -> tuple[Run, int | None]:
    """``ilcpmac ARGS`` in the probe (fuzz_targets.probe_main): the run, with the largest true phase current of
    any trial and the limit filled in, and the number of trials sent (None: the probe printed nothing)."""
    run = run_process([sys.executable, str(Path(ft.__file__)), "probe", *map(str, opts), "--", *map(str, args)],
                      folder, written)
    found = _PROBE_LINE.search(run.text)
    if found is None:
        return run, None
    run.peak_current_a, run.limit_a = float(found[2]), float(found[3])
    breach = _PROBE_BREACH.search(run.text)
    run.breach = None if breach is None else breach[1]
    return run, int(found[1])


def trials_on_disk(run_dir: Path) -> tuple[int, int, int]:
    """(trial files, trial states, [[trials]] listed in bench.toml) of a run directory."""
    bench = run_dir / "bench.toml"
    listed = bench.read_text().count("[[trials]]") if bench.is_file() else 0
    return (len(list(run_dir.glob("trial_*.parquet"))), len(list((run_dir / "states").glob("trial_*.json"))),
            listed)


def stage_case(name: str, config: Path, category: str = "stages", must_reject: bool = True) -> Case:
    """The small campaign with the broken stage ``name`` (ft.BROKEN_STAGES, or a lying one, ft.LYING_STAGES): one
    error line naming the stage, exit 2 (or, where not ``must_reject``, the run to its end), every trial sent on
    disk (its file, its state, listed in bench.toml), and never a value beyond the limits received by the
    simulator (the probe)."""
    def run(folder: Path) -> Run:
        out = folder / "run"
        opts = ("--stage", name) + (("--stage-call-s", FUZZ_STAGE_CALL_S) if "hangs" in name else ())
        done, sent = probe("run", config, "--out", out, folder=folder, opts=opts, written=out)
        errors = _error_lines(done.text)
        if sent is None:
            done.problem = "the probe printed no count of the trials sent"
        elif trials_on_disk(out) != (sent,) * 3:
            done.problem = f"{sent} trials sent; trial files, states, listed in bench.toml: {trials_on_disk(out)}"
        elif errors and not errors[0].startswith(f"error: stage '{ft.BROKEN_STAGE}'"):
            done.problem = f"not an error naming the stage: {errors[0][:150]}"
        return done
    return Case(category, name, must_reject, run)


def stage_cases(config: Path) -> list[Case]:
    return [stage_case(name, config) for name in ft.BROKEN_STAGES]


def lying_cases(config: Path) -> list[Case]:
    return [stage_case(name, config, "lying values", must_reject)
            for name, (_, must_reject) in ft.LYING_STAGES.items()]


# ---------------------------------------------------------------- 8. a run directory changed before --resume

#: a partial run is stopped (Ctrl-C) at this trial: 8 complete (the grid, baselines, compensation, learning)
PARTIAL_AT = 9


def make_runs(config: Path, scratch: Path) -> str | None:
    """A finished run of the small campaign (scratch/run-finished) and one stopped at trial PARTIAL_AT
    (scratch/run-partial); a message if either cannot be made."""
    for name, opts, code in (("run-finished", (), 0), ("run-partial", ("--interrupt-at", PARTIAL_AT), 130)):
        made, _ = probe("run", config, "--out", scratch / name, folder=scratch, opts=opts)
        if made.code != code:
            return f"cannot make the base run {name} (exit {made.code}):\n{made.text[-2000:]}"
    return None


def _identification(fn: Callable[[float], float], reseal: bool = False) -> Callable[[Path], None]:
    """states/identification.json with epsilon ``fn(epsilon)``; ``reseal``: its sha256 digest recomputed as the
    run writes it (an edit the digest cannot show)."""
    import hashlib
    import json

    def tamper(run: Path) -> None:
        path = run / "states" / "identification.json"
        data = json.loads(path.read_text())
        data["result"]["epsilon"] = fn(data["result"]["epsilon"])
        if reseal:
            data.pop("sha256")
            data["sha256"] = hashlib.sha256(json.dumps(data, allow_nan=False).encode()).hexdigest()
        path.write_text(json.dumps(data))
    return tamper


def _nan_state(index: int) -> Callable[[Path], None]:
    import json

    def tamper(run: Path) -> None:
        path = run / "states" / f"trial_{index:03d}.json"
        data = json.loads(path.read_text())
        data["gains"] = {"2@0.9": float("nan")}
        path.write_text(json.dumps(data))
    return tamper


def _swap(a: str, b: str) -> Callable[[Path], None]:
    def tamper(run: Path) -> None:
        (run / a).rename(run / "swap")
        (run / b).rename(run / a)
        (run / "swap").rename(run / b)
    return tamper


def _truncate(name: str, n_bytes: int) -> Callable[[Path], None]:
    return lambda run: (run / name).write_bytes((run / name).read_bytes()[:-n_bytes])


def _delete(name: str) -> Callable[[Path], None]:
    return lambda run: (run / name).unlink()


def _both_changes(*changes: Callable[[Path], None]) -> Callable[[Path], None]:
    return lambda run: [change(run) for change in changes] and None


def _unsealed(run: Path) -> None:
    """states/run.json saying the run was made before digests."""
    import json

    path = run / "states" / "run.json"
    path.write_text(json.dumps({**json.loads(path.read_text()), "sealed": False}))


def _seal_removed(run: Path) -> None:
    """Every seal removed, as a run before digests and seals had none: run.json's and the states'."""
    import json

    for path in [run / "states" / "run.json", *(run / "states").glob("*.json")]:
        data = json.loads(path.read_text())
        for key in ("sealed", "sha256", "trial_sha256", "trials_sha256", "run_id", "config_sha256", "index"):
            data.pop(key, None)
        path.write_text(json.dumps(data))


def _json_key(name: str, key: str, value) -> Callable[[Path], None]:
    import json

    def tamper(run: Path) -> None:
        data = json.loads((run / name).read_text())
        data[key] = value
        (run / name).write_text(json.dumps(data))
    return tamper


def _config(table: str, key: str, value: str) -> Callable[[Path], None]:
    """campaign.toml with ``key = value`` in ``[table]``."""
    return lambda run: (run / "campaign.toml").write_text(toml_set((run / "campaign.toml").read_text(), table, key,
                                                                    value))


def _from_finished(*names: str) -> Callable[[Path], None]:
    """Files of the finished run (another run of the same config) copied into this one."""
    def tamper(run: Path) -> None:
        for name in names:
            shutil.copy(run.parent / "run-finished-source" / name, run / name)
    return tamper


def _copied(source: str, target: str) -> Callable[[Path], None]:
    return lambda run: shutil.copy(run / source, run / target)


#: (name, base run "partial" or "finished", must be refused, change) of the run directory changes
RESUME_CHANGES: list[tuple[str, str, bool, Callable[[Path], None]]] = [
    ("partial run untouched", "partial", False, lambda run: None),
    ("finished run untouched", "finished", False, lambda run: None),
    ("identification epsilon / 3", "partial", True, _identification(lambda e: e / 3)),
    ("identification epsilon x 10", "partial", True, _identification(lambda e: e * 10)),
    ("finished: identification epsilon / 3", "finished", True, _identification(lambda e: e / 3)),
    ("finished: identification epsilon x 10", "finished", True, _identification(lambda e: e * 10)),
    ("NaN in the state of trial 8", "partial", True, _nan_state(8)),
    ("finished: NaN in the state of trial 15", "finished", True, _nan_state(15)),
    ("trial files 7 and 8 swapped", "partial", True, _swap("trial_007.parquet", "trial_008.parquet")),
    ("finished: trial files 7 and 8 swapped", "finished", True, _swap("trial_007.parquet", "trial_008.parquet")),
    ("grid trial 2 Parquet truncated by 100 bytes", "partial", True, _truncate("trial_002.parquet", 100)),
    ("finished: grid trial 2 Parquet truncated", "finished", True, _truncate("trial_002.parquet", 100)),
    ("state of trial 5 deleted", "partial", True, _delete("states/trial_005.json")),
    ("finished: state of trial 5 deleted", "finished", True, _delete("states/trial_005.json")),
    # derived from the grid trials, whose digests are checked: identified again
    ("states/identification.json deleted", "partial", False, _delete("states/identification.json")),
    ("grid trial 3 Parquet deleted", "partial", True, _delete("trial_003.parquet")),
    ("states/run.json deleted", "partial", True, _delete("states/run.json")),
    # run.json says whether the states carry digests ("sealed"): without it, or with false, none is checked
    ("states/run.json deleted, then epsilon / 3", "partial", True, _both_changes(
        _delete("states/run.json"), _identification(lambda e: e / 3))),
    ('"sealed": false in states/run.json, then epsilon / 3', "partial", True, _both_changes(
        _unsealed, _identification(lambda e: e / 3))),
    # beyond what a digest can show: the edit resealed as the run seals it; the limits must hold all the same
    ("identification epsilon / 3, digest recomputed", "partial", False, _identification(lambda e: e / 3, True)),
    ("identification epsilon x 10, digest recomputed", "partial", False, _identification(lambda e: e * 10, True)),
    # issue 34, items 3 and 4: a resume goes on under the config, limits, seed and files it began with
    ("every seal removed, then epsilon / 3", "partial", True, _both_changes(
        _seal_removed, _identification(lambda e: e / 3))),
    ("campaign.toml with [limits] max_current_a 72", "partial", True, _config("limits", "max_current_a", "72.0")),
    ("finished: campaign.toml with [limits] max_current_a 72", "finished", True,
     _config("limits", "max_current_a", "72.0")),
    ("campaign.toml with another learning grid", "partial", True, _config("campaign", "learn_torques_nm",
                                                                          "[1.0, 3.0]")),
    ("seed 8 in states/run.json", "partial", True, _json_key("states/run.json", "seed", 8)),
    ("the finished run's trial 8 and its state mixed in", "partial", True, _from_finished(
        "trial_008.parquet", "states/trial_008.json")),
    ("the finished run's states/run.json copied in", "partial", True, _from_finished("states/run.json")),
    ("the finished run's states/identification.json copied in", "partial", True, _from_finished(
        "states/identification.json")),
    ("trial 7 and its state copied over trial 8", "partial", True, _both_changes(
        _copied("trial_007.parquet", "trial_008.parquet"), _copied("states/trial_007.json", "states/trial_008.json"))),
]


def resume_case(name: str, base: Path, must_reject: bool, change: Callable[[Path], None],
                args: tuple[str, ...] = ()) -> Case:
    """``ilcpmac run --resume`` (with ``args``) of a copy of ``base`` changed: refused in one line before any trial;
    any trial that runs keeps its true currents within [limits] max_current_a (the probe)."""
    def run(folder: Path) -> Run:
        run_dir = folder / "run"
        shutil.copytree(base, run_dir, symlinks=True)
        (folder / "run-finished-source").symlink_to(base.parent / "run-finished")
        change(run_dir)
        done, sent = probe("run", "--resume", run_dir, *args, folder=folder,
                           written=None if must_reject else run_dir)
        if sent is None:
            done.problem = "the probe printed no count of the trials sent"
        elif must_reject and sent:
            done.problem = f"{sent} trials ran on a changed run directory"
        return done
    return Case("resume tampering", name, must_reject, run)


#: options that would change a resumed run: refused (they were silently ignored)
RESUME_OPTIONS = [("--seed", "8"), ("--trials", "1"), ("--budget", "5"), ("--out", "elsewhere")]


def resume_cases(scratch: Path) -> list[Case]:
    return [*(resume_case(name, scratch / f"run-{base}", must, change) for name, base, must, change in RESUME_CHANGES),
            *(resume_case(f"--resume with {' '.join(option)}", scratch / "run-partial", True, lambda run: None, option)
              for option in RESUME_OPTIONS)]


# ---------------------------------------------------------------- 9. import: units, gaps, impossible rows

#: log_a's trial at 10 kHz (about 3 rows per count): rows between two counts feed no count's value
LOG_10K = "log_10k.csv"
#: a moteus cogging file of the base bench's motor (8192 bins, two per count) and its mapping
COGGING, MAP_COGGING = "cogging.json", "map_cogging.toml"
#: the small campaign's config and run directory (`ilcpmac run`: the grid, then compensated trials)
RUN_CONFIG, RUN = "campaign.toml", "run"


def make_units_base(bench: Path, folder: Path) -> str | None:
    """The import group's logs (make_import_base), LOG_10K, a moteus cogging file and its mapping, and a run
    directory of the small campaign, in ``folder``; a message if the run cannot be made."""
    import tomllib

    sys.path.insert(0, str(ROOT / "tests"))
    from campaign_helpers import SMALL_CAMPAIGN

    make_import_base(bench, folder)
    motor = tomllib.loads((bench / "bench.toml").read_text())["motor"]
    write_phase_log(folder / LOG_10K, bench / LOGGED[LOG_A], motor["counts_per_rev"], 10_000.0)
    write_cogging_file(folder / COGGING, bench, motor["pole_pairs"])
    (folder / MAP_COGGING).write_text(mapping_bench(bench) + '[log]\nkind = "moteus-cogging"\n')
    (folder / RUN_CONFIG).write_text(campaign_toml(SMALL_CAMPAIGN))
    made = run_process([ILCPMAC, "run", str(folder / RUN_CONFIG), "--out", str(folder / RUN)], folder)
    return None if made.code == 0 else f"cannot make the units group's run directory:\n{made.text[-2000:]}"


def write_cogging_file(path: Path, bench: Path, pole_pairs: int, bins: int = 8192) -> None:
    """A moteus cogging file of bench folder ``bench``'s motor ({"reverse": [...], "forward": [...]}, A): the
    holding current k_q i_q = -tau_c + s f of a 20 mN m cogging at orders 48 and 96 and 30 mN m of friction,
    plus 2 mA of seeded scatter per bin."""
    import json

    from ilcpmac.bench.moteus import q_torque_constant

    k_q = q_torque_constant(np.loadtxt(bench / "backemf.csv", delimiter=",", skiprows=1)[:, 1:], pole_pairs)
    theta = 2 * np.pi * (np.arange(bins) + 0.5) / bins
    cogging = 0.02 * np.sin(48 * theta + 0.3) + 0.01 * np.cos(96 * theta)
    rng = np.random.default_rng(34)
    path.write_text(json.dumps({key: ((-cogging + sign * 0.03) / k_q + 2e-3 * rng.standard_normal(bins)).tolist()
                                for key, sign in (("reverse", -1.0), ("forward", 1.0))}))


def _cogging_values(fn: Callable[[list[float]], list[float]], key: str = "forward") -> Callable:
    """The moteus cogging file's ``key`` list (every list: "both") changed by ``fn``."""
    def mutate(d: Path, rng) -> None:
        import json

        data = json.loads((d / COGGING).read_text())
        (d / COGGING).write_text(json.dumps({k: fn(v) if key in (k, "both") else v for k, v in data.items()}))
    return mutate


def _encoded(file: str, encoding: str) -> Callable:
    """``file`` re-encoded from UTF-8 to ``encoding``."""
    def mutate(d: Path, rng) -> None:
        (d / file).write_bytes((d / file).read_text().encode(encoding))
    return mutate


def _quiet_cell(name: str, value: str, file: str = LOG_10K) -> Callable:
    """``value`` in column ``name`` of a row whose two neighbouring intervals cross no encoder count."""
    def mutate(d: Path, rng) -> None:
        header, rows = read_csv(d / file)
        count = np.floor(np.array([float(r[header.index("theta")]) for r in rows]) / (2 * np.pi) * 4096)
        quiet = np.flatnonzero((count[1:-1] == count[:-2]) & (count[1:-1] == count[2:])) + 1
        rows[int(quiet[len(quiet) // 2])][header.index(name)] = value
        write_csv(d / file, header, rows)
    return mutate


def _gap(seconds: float, row: int) -> Callable:
    return column("t", lambda t: t + seconds * (np.arange(t.size) >= row), (LOG_A,))


def _passwd_like(d: Path, rng) -> None:
    """A /etc/passwd-like file holding SECRET outside the logs folder, as the mapping's backemf_file."""
    path = d.parent / "shadow"
    path.write_text(f"{SECRET}:x:0:0::/:/bin/sh\ndaemon:{SECRET}:19000:0:99999:7:::\n")
    mapping("bench", "backemf_file", f'"{path}"')(d, rng)


LOG_10K_ARGS: Args = lambda d: [d / LOG_10K, "--map", d / MAP]  # noqa: E731
COGGING_ARGS: Args = lambda d: [d / COGGING, "--map", d / MAP_COGGING]  # noqa: E731

#: (name, mutation, logs and mapping, the file the error line must name) of the import cases; each must be refused
UNIT_MUTATIONS: list[tuple[str, Callable, Args, str]] = [
    ("time in ms read as s", column("t", lambda t: t * 1e3, (LOG_A,)), PHASE_ARGS, LOG_A),
    ("time in s read as ms (time_s_per_unit 1e-3)", mapping("log", "time_s_per_unit", "1e-3"), PHASE_ARGS, LOG_A),
    ("time in us read as s", column("t", lambda t: t * 1e6, (LOG_A,)), PHASE_ARGS, LOG_A),
    ("a 10 s gap in the time column", _gap(10.0, 3000), PHASE_ARGS, LOG_A),
    ("a 10 s gap at the second row", _gap(10.0, 1), PHASE_ARGS, LOG_A),
    ("torque 1e300 N m in a row between counts (10 kHz)", _quiet_cell("tq", "1e300"), LOG_10K_ARGS, LOG_10K),
    ("torque 1e300 N m in a row (2 kHz)", cell(500, "tq", "1e300", LOG_A), PHASE_ARGS, LOG_A),
    ("current 1e5 A in a row between counts (10 kHz)", _quiet_cell("ia", "1e5"), LOG_10K_ARGS, LOG_10K),
    ("current 1e5 A in a row (2 kHz)", cell(501, "ib", "1e5", LOG_A), PHASE_ARGS, LOG_A),
    ("current -1e5 A in a row between counts (10 kHz)", _quiet_cell("ic", "-1e5"), LOG_10K_ARGS, LOG_10K),
    ("'#' starting a data row", _log_lines(lambda ls: ls[:400] + [b"#" + ls[400]] + ls[401:]), PHASE_ARGS, LOG_A),
    ("'#' inside a field of a data row", cell(402, "tq", "#0.5", LOG_A), PHASE_ARGS, LOG_A),
    ("'#' starting a row between counts (10 kHz)", _quiet_cell("t", "#0"), LOG_10K_ARGS, LOG_10K),
    ("backemf_file = /etc/passwd", mapping("bench", "backemf_file", '"/etc/passwd"'), PHASE_ARGS, MAP),
    ("backemf_file a passwd-like file outside the folder", _passwd_like, PHASE_ARGS, MAP),
    # currents and torque in a unit the mapping does not say (issue 34, item 10): judged against [limits]
    ("i_q in 10 mA read as A (100x)", mapping("log", "current_a_per_unit", "1.0", MAP_Q), Q_ARGS, LOG_Q),
    ("i_q in mA read as A (1000x)", mapping("log", "current_a_per_unit", "10.0", MAP_Q), Q_ARGS, LOG_Q),
    ("phase currents in mA read as A", mapping("log", "current_a_per_unit", "1e3"), PHASE_ARGS, LOG_A),
    ("torque in mN m read as N m", mapping("log", "torque_nm_per_unit", "1e3"), PHASE_ARGS, LOG_A),
    ("i_q in mA read as A, [limits] of the motor given", _both(
        mapping("log", "current_a_per_unit", "10.0", MAP_Q),
        mapping_text(lambda t: t + "\n[limits]\nmax_current_a = 5.0\nmax_torque_nm = 4.0\n", MAP_Q)), Q_ARGS, LOG_Q),
    ("a log in UTF-16 (its byte-order mark)", _encoded(LOG_A, "utf-16"), PHASE_ARGS, LOG_A),
    ("a log in UTF-16 LE without a byte-order mark", _encoded(LOG_A, "utf-16-le"), PHASE_ARGS, LOG_A),
    ("a q-axis log in UTF-16 BE", _encoded(LOG_Q, "utf-16-be"), Q_ARGS, LOG_Q),
    ("moteus cogging file in mA", _cogging_values(lambda v: [1e3 * x for x in v], "both"), COGGING_ARGS, COGGING),
    ("moteus cogging file with one bin of 9999 A", _cogging_values(lambda v: v[:100] + [9999.0] + v[101:]),
     COGGING_ARGS, COGGING),
    ("moteus cogging file of zeros", _cogging_values(lambda v: [0.0] * len(v), "both"), COGGING_ARGS, COGGING),
    ("moteus cogging file of 0.5 A in every bin", _cogging_values(lambda v: [0.5] * len(v), "both"), COGGING_ARGS,
     COGGING),
    ("moteus cogging file in UTF-16", _encoded(COGGING, "utf-16"), COGGING_ARGS, COGGING),
    ("moteus cogging file in UTF-32", _encoded(COGGING, "utf-32"), COGGING_ARGS, COGGING),
]


def _nothing_written(folder: Path, out: Path) -> str | None:
    """What a refused case left: a file in ``out``, or a *.tmp anywhere in ``folder``."""
    tmp = sorted(p.name for p in folder.rglob("*.tmp"))
    if tmp:
        return f"left {', '.join(tmp[:3])}"
    made = sorted(p.name for p in out.rglob("*")) if out.is_dir() else [out.name] if out.exists() else []
    return f"wrote {', '.join(made[:3])} into the output" if made else None


def _stray_output(run: Run) -> str | None:
    """A warning of Python's or of LAPACK's in the output (never the user's to read)."""
    stray = [line for line in run.text.splitlines() if "Warning:" in line or "** On entry to" in line]
    return f"printed {stray[0].strip()[:150]}" if stray else None


def _refusal_problem(run: Run, names: str) -> str | None:
    """A refusal's error line that does not name ``names``, that shows /etc/passwd, or that other output
    precedes (a progress line, a warning: the error is the command's one line)."""
    if "root:x:" in run.text or "/bin/bash" in run.text:
        return "echoed /etc/passwd"
    errors = _error_lines(run.text)
    if errors and names not in errors[0]:
        return f"the error line names no {names}: {errors[0][:150]}"
    others = [line for line in run.text.splitlines() if line.strip() and line not in errors]
    if errors and others:
        return f"a line besides the error: {others[0].strip()[:150]}"
    return _stray_output(run)


def unit_case(base: Path, name: str, mutate: Callable, args: Args, names: str) -> Case:
    def run(folder: Path) -> Run:
        d = folder / "logs"
        shutil.copytree(base, d, symlinks=True)
        mutate(d, None)
        out = folder / "out"
        done = ilcpmac("import", *args(d), "--out", out, folder=folder, written=out)
        done.problem = _refusal_problem(done, names) or _nothing_written(folder, out)
        return done
    return Case("import units & gaps", name, True, run)


def hash_in_trial_case(bench: Path) -> Case:
    """A '#' in a bench folder's trial row (no comment there), identified."""
    def run(folder: Path) -> Run:
        d = folder / "bench"
        shutil.copytree(bench, d, symlinks=True)
        _log_lines(lambda ls: ls[:3] + [b"#" + ls[3]] + ls[4:], T1)(d, None)
        out = folder / "result.json"
        done = ilcpmac("identify", d, "--output", out, folder=folder, written=out)
        done.problem = _refusal_problem(done, T1) or _nothing_written(folder, out)
        return done
    return Case("import units & gaps", "'#' starting a row of a bench folder's trial (identify)", True, run)


def _swapped_torque(noise_nm: float) -> Callable[[Path], None]:
    """Every trial's torque and i_ref_a columns swapped (their headers), the torque column then given
    ``noise_nm`` of seeded scatter (0: none; a simulated current reference repeats exactly)."""
    def mutate(d: Path) -> None:
        rng = np.random.default_rng(34)
        for trial in TRIALS:
            header, rows = read_csv(d / trial)
            i, j = header.index("i_ref_a"), header.index("torque")
            header[i], header[j] = header[j], header[i]
            for row in rows if noise_nm else ():
                row[i] = f"{float(row[i]) + noise_nm * rng.standard_normal():.6f}"
            write_csv(d / trial, header, rows)
    return mutate


def identify_case(name: str, source: Path, change: Callable[[Path], None], must_reject: bool,
                  check: Callable[[Run], str | None]) -> Case:
    """``ilcpmac identify`` of a copy of folder ``source`` changed by ``change``; ``check`` says what is wrong
    with what it did (and `_stray_output`)."""
    def run(folder: Path) -> Run:
        d = folder / "bench"
        shutil.copytree(source, d, symlinks=True)
        change(d)
        out = folder / "result.json"
        done = ilcpmac("identify", d, "--output", out, folder=folder, written=out)
        done.problem = check(done) or _stray_output(done)
        return done
    return Case("import units & gaps", name, must_reject, run)


def _says(text: str, code: int) -> Callable[[Run], str | None]:
    """A check: exit ``code`` with ``text`` in the output (for exit 2 in the error line, and nothing else)."""
    def check(run: Run) -> str | None:
        if run.code != code or text not in run.text:
            last = [line for line in run.text.splitlines() if line.strip()]
            return f"exit {run.code} without {text!r}: {last[-1][:150] if last else ''}"
        return _refusal_problem(run, text) if code == 2 else None
    return check


def _scan_of(base: Path, mapping_change: Callable[[str], str]) -> Callable[[Path], Path]:
    """A scan folder of the units group's moteus cogging file, imported under its mapping changed by
    ``mapping_change``."""
    def make(folder: Path) -> Path:
        logs = folder / "logs"
        shutil.copytree(base, logs, symlinks=True, ignore=shutil.ignore_patterns(RUN))
        edit(logs / MAP_COGGING, mapping_change)
        made = run_process([ILCPMAC, "import", *map(str, COGGING_ARGS(logs)), "--out", str(folder / "scan")],
                           folder)
        if made.code != 0:
            raise RuntimeError(f"cannot import the scan: {made.text[-500:]}")
        return folder / "scan"
    return make


def scan_identify_case(name: str, make: Callable[[Path], Path], check: Callable[[Run], str | None]) -> Case:
    """``ilcpmac identify`` of the scan folder ``make(folder)`` makes (a valid scan: its import is no case)."""
    def run(folder: Path) -> Run:
        scan = make(folder)
        out = folder / "scan.json"
        done = ilcpmac("identify", scan, "--output", out, folder=folder, written=out)
        done.problem = check(done) or _stray_output(done)
        return done
    return Case("import units & gaps", name, False, run)


def identify_garbage_cases(base: Path, bench: Path) -> list[Case]:
    """``ilcpmac identify`` on what its model does not describe (issue 34, items 10 and 17)."""
    nyquist = _scan_of(base, lambda t: toml_set(t, "bench", "slots", "2047"))
    return [
        identify_case("a campaign's run directory (its grid identified)", base / RUN, lambda d: None, False,
                      _says("grid trials identified", 0)),
        identify_case("torque and i_ref_a swapped in every trial", bench, _swapped_torque(0.0), True,
                      _says("the torque repeats exactly", 2)),
        identify_case("torque and i_ref_a swapped, the torque with 20 mN m of noise", bench, _swapped_torque(0.02),
                      True, _says("nothing can be identified from this torque", 2)),
        identify_case("a bench folder without bench.toml: one line", bench, lambda d: (d / "bench.toml").unlink(),
                      True, _says("bench.toml", 2)),
        scan_identify_case("a scan whose cogging order is beyond the counts' Nyquist limit (slots 2047)", nyquist,
                           _says("cogging: not identified", 0)),
        scan_identify_case("a moteus scan as written (control)", _scan_of(base, lambda t: t),
                           _says("cogging (orders 48, 96, ...): ", 0)),
    ]


def unit_cases(base: Path, bench: Path) -> list[Case]:
    return ([unit_case(base, *m) for m in UNIT_MUTATIONS] + [hash_in_trial_case(bench)]
            + identify_garbage_cases(base, bench))


# ---------------------------------------------------------------- 10. sweep: schedulers that are none, magnets


def scheduler_case(name: str, behaviour: Callable, timeout_s: float | None) -> Callable[[Path], Case]:
    """``ilcpmac sweep --scheduler`` at a TCP port served by ``behaviour`` (``--connect-timeout timeout_s``, None:
    its default), run to its end."""
    def make(config: Path) -> Case:
        def run(folder: Path) -> Run:
            (folder / "spec.toml").write_text(toml_set(SWEEP_SPEC, "sweep", "tasks", "1"))
            target = ft.HostileTarget(behaviour)
            try:
                wait = () if timeout_s is None else ("--connect-timeout", timeout_s)
                done = ilcpmac("sweep", config, "--spec", folder / "spec.toml", "--out", folder / "out",
                               "--scheduler", f"tcp://{target.address}", *wait, folder=folder, written=folder / "out")
            finally:
                target.stop()
            done.problem = _refusal_problem(done, "--scheduler")
            return done
        return Case("sweep: schedulers & magnets", name, True, run)
    return make


SCHEDULERS = [
    scheduler_case("--scheduler at an HTTP server", ft.http_reply, None),
    scheduler_case("--scheduler at a TCP echo port", ft.echo, None),
    scheduler_case("--scheduler at a silent port (default --connect-timeout)", ft.swallow, None),
    scheduler_case("--scheduler at a silent port, --connect-timeout 0.5", ft.swallow, 0.5),
    scheduler_case("--scheduler at a port that closes at once", lambda w, stop: None, None),
]

#: (name, the [magnets] table's lines) of the magnets out of range
MAGNETS = [
    ("magnets coefficient 0.0856 per K (backemf x 7.85 at 80 K)", "temperature_rise_k = [0.0, 80.0]\n"
                                                                   "coefficient_per_k = 0.0856"),
    ("magnets 150 K at -0.004 per K (scale 0.4)", "temperature_rise_k = [0.0, 150.0]\ncoefficient_per_k = -0.004"),
    ("magnets -200 K at -0.003 per K (scale 1.6)", "temperature_rise_k = [-200.0, 0.0]\ncoefficient_per_k = -0.003"),
    ("magnets coefficient -1 per K", "temperature_rise_k = [0.0, 80.0]\ncoefficient_per_k = -1.0"),
    ("magnets coefficient 1e300", "temperature_rise_k = [0.0, 80.0]\ncoefficient_per_k = 1e300"),
    ("magnets coefficient inf", "temperature_rise_k = [0.0, 80.0]\ncoefficient_per_k = inf"),
    ("magnets rise 1e300 K", "temperature_rise_k = [0.0, 1e300]\ncoefficient_per_k = -0.001"),
]


def magnets_case(name: str, table: str, config: Path) -> Case:
    """A spec with [magnets] ``table``, stopped once its tasks are ready (accepted): refused naming [magnets]."""
    def run(folder: Path) -> Run:
        spec = folder / "spec.toml"
        spec.write_text(f"{SWEEP_SPEC}\n[magnets]\n{table}\n")
        out = folder / "sweep"
        done = ilcpmac("sweep", config, "--spec", spec, "--out", out, "--workers", 1, folder=folder, written=out,
                       stop_at=SWEEP_ACCEPTED)
        done.problem = _refusal_problem(done, "[magnets]")
        return done
    return Case("sweep: schedulers & magnets", name, True, run)


def scheduler_cases(config: Path) -> list[Case]:
    return [make(config) for make in SCHEDULERS] + [magnets_case(name, table, config) for name, table in MAGNETS]


# ---------------------------------------------------------------- 11. export: compensation.json and result.json


def make_result(bench: Path, scratch: Path) -> str | None:
    """scratch/result.json: ``ilcpmac identify`` of the base bench; a message if it cannot be made."""
    made = run_process([ILCPMAC, "identify", str(bench), "--output", str(scratch / "result.json")], scratch)
    return None if made.code == 0 else f"cannot identify the base bench:\n{made.text[-2000:]}"


def _json_edit(fn: Callable[[dict], object]) -> Callable[[str], str]:
    """The JSON text with its object changed in place by ``fn`` (what it returns is ignored)."""
    import json

    def change(text: str) -> str:
        data = json.loads(text)
        fn(data)
        return json.dumps(data)
    return change


def _set(path: str, value) -> Callable[[str], str]:
    """The JSON text with the value at ``path`` ("a.b.0.3") set to ``value``."""
    def fn(data: dict) -> None:
        *parents, last = path.split(".")
        node = data
        for part in parents:
            node = node[int(part)] if isinstance(node, list) else node[part]
        node[int(last) if isinstance(node, list) else last] = value
    return _json_edit(fn)


def _duplicate(key: str, value: str, inside: str = "{") -> Callable[[str], str]:
    """The JSON text with ``"key": value`` inserted after the first ``inside`` (a key given twice)."""
    return lambda t: t.replace(inside, f'{inside}"{key}": {value}, ', 1)


def _huge_tables(n_torques: int) -> Callable[[str], str]:
    """``n_torques`` ascending torques, each with a table of zeros: n_torques x 1 x 1024 values."""
    def fn(data: dict) -> None:
        data["torques_nm"] = np.linspace(-7.0, 7.0, n_torques).tolist()
        data["tables_nm"] = [[[0.0] * data["counts_per_rev"]] for _ in range(n_torques)]
    return _json_edit(fn)


def _counts(n: int) -> Callable[[str], str]:
    """A result whose cogging table has ``n`` counts."""
    def fn(data: dict) -> None:
        data["cogging"] = {"count": list(range(n)), "torque": np.sin(np.arange(n) * 2 * np.pi * 48 / n).tolist()}
    return _json_edit(fn)


_WHOLE_FILE = [
    ("empty file", lambda t: ""),
    ("null", lambda t: "null"),
    ("a list", lambda t: "[1, 2, 3]"),
    ("nested 100000 deep", lambda t: "[" * 100_000 + "]" * 100_000),
    ("binary", lambda t: b"\xff\xfe\x00" + bytes(range(256)) * 8),
    ("UTF-16", lambda t: t.encode("utf-16")),
    ("cut in the middle", lambda t: t[:len(t) // 2]),
]

#: (name, change of compensation.json's text) of the compensation cases; each must be refused
COMPENSATION_CHANGES: list[tuple[str, Callable[[str], str | bytes]]] = [
    ("true in tables_nm", _set("tables_nm.0.0.5", True)),
    ("false in tables_nm", _set("tables_nm.1.0.0", False)),
    ("true as counts_per_rev", _set("counts_per_rev", True)),
    ("true in torques_nm", _set("torques_nm.0", True)),
    ("true as the torque gain", _set("calibration.torque_gain", True)),
    ("true in current_scale", _set("calibration.current_scale.1", True)),
    ("true as fade.full_hz", _set("fade.full_hz", True)),
    ("text in tables_nm", _set("tables_nm.0.0.7", "0.1")),
    ("null in tables_nm", _set("tables_nm.0.0.8", None)),
    ("duplicate key counts_per_rev", _duplicate("counts_per_rev", "2048")),
    ("duplicate key tables_nm", _duplicate("tables_nm", "[]")),
    ("duplicate key in calibration", _duplicate("torque_gain", "0.5", '"calibration": {')),
    ("NaN in tables_nm", _set("tables_nm.0.0.3", float("nan"))),
    ("Infinity in speeds_hz", _set("speeds_hz.0", float("inf"))),
    ("-Infinity in current_offset", _set("calibration.current_offset.0", float("-inf"))),
    ("1e400 (overflows to inf) in tables_nm", lambda t: _set("tables_nm.0.0.4", 12345.678)(t).replace(
        "12345.678", "1e400", 1)),
    ("1e308 in tables_nm", _set("tables_nm.0.0.2", 1e308)),
    ("tables_nm of 4097 x 1 x 1024 values (beyond MAX_TABLE_VALUES)", _huge_tables(4097)),
    ("torques_nm of 10^6 values", _json_edit(lambda d: d.update(torques_nm=np.linspace(-7, 7, 10**6).tolist()))),
    ("tables_nm one level short", _json_edit(lambda d: d.update(tables_nm=[t[0] for t in d["tables_nm"]]))),
    ("tables_nm ragged (a table of 1023 counts)", _json_edit(lambda d: d["tables_nm"][1][0].pop())),
    ("tables_nm a number", _set("tables_nm", 0.0)),
    ("tables_nm an object", _set("tables_nm", {"0": [0.0]})),
    ("torques_nm nested", _json_edit(lambda d: d.update(torques_nm=[d["torques_nm"]]))),
    ("torques_nm descending", _json_edit(lambda d: d.update(torques_nm=d["torques_nm"][::-1]))),
    ("current_scale 2 values", _json_edit(lambda d: d["calibration"]["current_scale"].pop())),
    ("counts_per_rev 2048 over tables of 1024", _set("counts_per_rev", 2048)),
    ("counts_per_rev 2^62", _set("counts_per_rev", 2**62)),
    ("format 2", _set("format", 2)),
    ("unknown key", _json_edit(lambda d: d.update(note=1))),
    *((f"file {name}", fn) for name, fn in _WHOLE_FILE),
]

#: (name, change of result.json's text) of the result cases; each must be refused
RESULT_CHANGES: list[tuple[str, Callable[[str], str | bytes]]] = [
    ("true in the cogging table", _set("cogging.torque.5", True)),
    ("true as the cogging table", _set("cogging.torque", True)),
    ("true as epsilon", _set("epsilon", True)),
    ("true in alpha", _set("alpha.0", True)),
    ("true as the calibration", _set("calibration", True)),
    ("duplicate key cogging", _duplicate("cogging", '{"count": [0], "torque": [1.0]}')),
    ("duplicate key epsilon", _duplicate("epsilon", "0.5")),
    ("NaN in the cogging table", _set("cogging.torque.3", float("nan"))),
    ("Infinity as epsilon", _set("epsilon", float("inf"))),
    ("1e400 (overflows to inf) in the cogging table", lambda t: _set("cogging.torque.4", 12345.678)(t).replace(
        "12345.678", "1e400", 1)),
    ("cogging of 2^22 counts (beyond MAX_RESULT_BYTES)", _counts(2**22)),
    ("cogging of 2^20 + 1 counts", _counts(2**20 + 1)),
    ("cogging torque and count lists of unequal length", _json_edit(lambda d: d["cogging"]["count"].pop())),
    ("cogging table nested", _json_edit(lambda d: d["cogging"].update(torque=[d["cogging"]["torque"]]))),
    ("cogging table a number", _set("cogging.torque", 0.5)),
    ("cogging a list", _json_edit(lambda d: d.update(cogging=d["cogging"]["torque"]))),
    ("cogging table constant", _json_edit(lambda d: d["cogging"].update(torque=[0.1] * len(d["cogging"]["torque"])))),
    ("alpha 2 values", _json_edit(lambda d: d["alpha"].pop())),
    *((f"file {name}", fn) for name, fn in _WHOLE_FILE),
]


#: the files of a run directory that export reads besides compensation.json: its [limits] and its encoder
RUN_LIMIT_FILES = ("campaign.toml", "bench.toml", "backemf.csv")


def _placed(source: Path, change: Callable[[str], str | bytes], folder: Path, run_dir: Path | None) -> Path:
    """``source`` changed by ``change``, written into ``folder`` (made if missing), with the files of the run
    directory ``run_dir`` that export reads (None: outside a run directory)."""
    folder.mkdir(parents=True, exist_ok=True)
    for name in RUN_LIMIT_FILES if run_dir is not None else ():
        shutil.copy(run_dir / name, folder / name)
    text = change(source.read_text())
    path = folder / source.name
    path.write_bytes(text if isinstance(text, bytes) else text.encode())
    return path


def export_case(name: str, source: Path, change: Callable[[str], str | bytes], must_reject: bool = True,
                fmt: str = "json", args: tuple = (), category: str = "export tables", place: str = "",
                run_dir: Path | None = None, out_name: str = "out") -> Case:
    """``ilcpmac export`` of ``source`` (a run's compensation.json, given as its run directory, or a result JSON)
    changed by ``change``, with ``args``: refused in one line naming it, nothing written; or (``must_reject``
    False) written, its C compiling and inert. It is written into the folder ``place`` (default: "run" for a
    compensation, the case's folder for a result) with the limit files of its run directory (a compensation's
    own, a result's ``run_dir``: None, outside one)."""
    def run(folder: Path) -> Run:
        is_run = source.name == "compensation.json"
        within = source.parent if is_run else run_dir
        path = _placed(source, change, folder / (place or ("run" if within else "")), within)
        out = folder / out_name
        done = ilcpmac("export", path.parent if is_run else path, "--format", fmt, *args, "--out", out,
                       folder=folder, written=out)
        done.problem = (_refusal_problem(done, source.name) or _nothing_written(folder, out) if must_reject else
                        _c_problem(out) if done.code == 0 else None)
        return done
    return Case(category, f"{source.stem}: {name}", must_reject, run)


def _c_problem(out: Path) -> str | None:
    """The first C source of an export that does not compile (C99, every warning an error), or None."""
    compiler = shutil.which("gcc") or shutil.which("cc")
    for source in sorted(out.glob("*.c")) if compiler else ():
        done = subprocess.run([compiler, "-std=c99", "-pedantic", "-Wall", "-Wextra", "-Werror", "-fsyntax-only",
                               str(source)], capture_output=True, text=True, timeout=60)
        if done.returncode != 0:
            return f"{source.name} does not compile: {done.stderr.strip().splitlines()[0][:150]}"
    if compiler and any("ilcpmac_injected" in p.read_text().replace("*\\/ int ilcpmac_injected", "")
                        for p in out.glob("*.[ch]")):
        return "a source path's text is live code in the C"
    return None


def _cogging(n: int, peak_nm: float) -> Callable[[str], str]:
    """A result whose cogging table has ``n`` counts (order 48) and the peak ``peak_nm``."""
    def fn(data: dict) -> None:
        data["cogging"] = {"count": list(range(n)),
                           "torque": (peak_nm * np.sin(np.arange(n) * 2 * np.pi * 48 / n)).tolist()}
    return _json_edit(fn)


def _peak(key: str, peak_nm: Callable[[float], float]) -> Callable[[str], str]:
    """The JSON text with the table at ``key`` ("tables_nm" or "cogging.torque") scaled to the peak
    ``peak_nm(its peak)``."""
    def fn(data: dict) -> None:
        *parents, last = key.split(".")
        node = data
        for part in parents:
            node = node[part]
        table = np.asarray(node[last])
        peak = np.abs(table).max()
        node[last] = (table * (peak_nm(peak) / peak)).tolist()
    return _json_edit(fn)


def _calibration(current_scale_b: float) -> Callable[[str], str]:
    """A result with a calibration whose phase b current scale is ``current_scale_b``."""
    return _json_edit(lambda d: d.update(calibration={"current_scale": [14.0, current_scale_b, 13.9],
                                                      "current_offset": [1.5, -2.0, 0.25], "torque_gain": 0.9}))


def _as_scan(short_by: int) -> Callable[[str], str]:
    """The result as a standstill scan's of its counts_per_rev, its cogging table ``short_by`` values short."""
    def fn(data: dict) -> None:
        torque = data["cogging"]["torque"]
        kept = torque[:len(torque) - short_by]
        data.clear()
        data.update({"kind": "standstill_scan", "counts_per_rev": len(torque), "cogging_order": 1,
                     "cogging": {"count": list(range(len(kept))), "torque": kept}})
    return _json_edit(fn)


def _cut_tables(data: dict) -> None:
    """counts_per_rev one less, and every table one count shorter: a record consistent in itself."""
    data["counts_per_rev"] -= 1
    for row in data["tables_nm"]:
        for table in row:
            table.pop()


#: --torque-constant values a drive format must refuse: a current infinite, nothing, or no number
BAD_TORQUE_CONSTANTS = ("1e-300", "1e300", "inf", "nan", "0", "-0.1")
#: a source folder that closes the C comment and opens a declaration (the issue's), a result's folder named run*
INJECTING, STARRED = "x*/ int ilcpmac_injected = 1; /*", "run*"


def export_bound_cases(compensation: Path, result: Path) -> list[Case]:
    """Export bounds (issue 34, items 6 to 8): a calibration out of range, a torque constant that makes the q-axis
    current infinite or nothing, tables beyond the run's [limits] or the drive's current, of the wrong length,
    scales a C float cannot hold: refused; source paths that would break the C, names that are no UTF-8: written,
    the C compiling and inert."""
    from ilcpmac.config import LimitSettings
    from ilcpmac.core.schema import read_toml

    run_dir = compensation.parent
    limit = read_toml(run_dir / "campaign.toml").get("limits", {}).get("max_correction_nm",
                                                                        LimitSettings().max_correction_nm)
    counts = read_toml(run_dir / "bench.toml")["motor"]["counts_per_rev"]

    def case(name: str, source: Path, change: Callable[[str], str | bytes], fmt: str = "json", *args: str,
             must_reject: bool = True, **kw) -> Case:
        options = " ".join((f"--format {fmt}",) * (fmt != "json") + args)
        return export_case(", ".join(filter(None, (name, options))), source, change, must_reject, fmt, args,
                           "export bounds", **kw)

    unchanged = lambda t: t  # noqa: E731
    cases = [case(f"calibration current_scale {v!r}", result, _calibration(v), fmt)
             for v in (0.0, -27.5, 1e10) for fmt in ("csv", "c")]
    cases += [case("current_scale 1e-300 (0 as a C float)", compensation, _set("calibration.current_scale.1", 1e-300),
                   "c"),
              case("current_scale 1e-300 (exact in CSV)", compensation, _set("calibration.current_scale.1", 1e-300),
                   "csv", must_reject=False),
              case("torque_gain 1e-300", compensation, _set("calibration.torque_gain", 1e-300), "c")]
    cases += [case("", result, unchanged, fmt, "--torque-constant", kt) for fmt in ("moteus", "harmonics")
              for kt in BAD_TORQUE_CONSTANTS]
    tiny = _peak("tables_nm", lambda _: 1e-36)
    cases += [case("cogging table of 1e5 N m", result, _peak("cogging.torque", lambda _: 1e5), "moteus",
                   "--torque-constant", "0.3"),
              *(case(f"tables_nm at 3.3 x max_correction_nm {limit:g} N m", compensation,
                     _peak("tables_nm", lambda _: 3.3 * limit), fmt) for fmt in ("json", "c")),
              case(f"cogging of {counts} counts at 3.3 x max_correction_nm in the run directory", result,
                   _cogging(counts, 3.3 * limit), "moteus", "--torque-constant", "0.3", run_dir=run_dir),
              case(f"cogging of {counts} counts asking 1e3 A in the run directory", result,
                   _cogging(counts, 0.5 * limit), "harmonics", "--torque-constant", f"{0.5 * limit / 1e3!r}",
                   run_dir=run_dir),
              case(f"cogging of {counts + 1} counts in a run of {counts}", result, _cogging(counts + 1, 0.1), "c",
                   run_dir=run_dir),
              case(f"counts_per_rev and tables of {counts - 1} in a run of {counts}", compensation,
                   _json_edit(_cut_tables), "csv"),
              case("a scan's cogging one value short of its counts_per_rev", result, _as_scan(1), "c"),
              case("position_torque one count longer than cogging", result, _json_edit(lambda d: d.update(
                  position_torque={"count": list(range(len(d["cogging"]["torque"]) + 1)),
                                   "torque": d["cogging"]["torque"] + [0.0]}))),
              case("tables_nm peaking at 1e-36 N m (an int16 scale of 0)", compensation, tiny, "c"),
              case("tables_nm peaking at 1e-36 N m", compensation, tiny, "c", "--c-type", "float", must_reject=False),
              case("torques_nm one float apart", compensation, _json_edit(lambda d: d.update(
                  torques_nm=[d["torques_nm"][0], d["torques_nm"][0] * (1 + 1e-9)])), "c"),
              case("fade.zero_hz 1e300 (inf as a C float)", compensation, _json_edit(lambda d: d.update(
                  fade={"full_hz": 0.5, "zero_hz": 1e300})), "c")]
    cases += [case(f"in a folder {INJECTING!r}", compensation, unchanged, "c", must_reject=False, place=INJECTING),
              case(f"in a folder {INJECTING!r}", result, unchanged, "c", must_reject=False, place=INJECTING),
              case(f"in a folder {STARRED!r}", result, unchanged, "c", must_reject=False, place=STARRED),
              case("in a folder whose name is no UTF-8", result, unchanged, "c", must_reject=False,
                   place=os.fsdecode(b"src-\xff"))]
    cases += [case("into a folder whose name is no UTF-8", source, unchanged, fmt, *args, must_reject=False,
                   out_name=os.fsdecode(b"out-\xff"))
              for source, fmt, args in ((compensation, "json", ()), (compensation, "csv", ()), (compensation, "c", ()),
                                        (result, "harmonics", ("--torque-constant", "0.3")),
                                        (result, "moteus", ("--torque-constant", "0.3")))]
    return cases


#: what the full disk of the full-disk cases has free, bytes: one page of a tmpfs, or the emulated disk's budget
FULL_DISK_FREE = 4096
#: ``python -c`` of an emulated full disk (the fallback where no tmpfs can be mounted): ``ilcpmac ARGS`` whose
#: writes through ilcpmac.core.files (`atomic_write`, `check_writable`) stop at ENOSPC after argv[1] bytes in all
#: (tests/test_output_and_sweep_garbage.py's full_disk, with a budget)
_EMULATED_FULL_DISK = """\
import builtins, errno, os, sys
import ilcpmac.core.files as files
left = [int(sys.argv[1])]
class Full:
    def __init__(self, f): self.f = f
    def __enter__(self): return self
    def __exit__(self, *exc): self.f.close()
    def __getattr__(self, name): return getattr(self.f, name)
    def write(self, data):
        n = min(len(data), left[0])
        self.f.write(data[:n])
        left[0] -= n
        if n < len(data): raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return n
def open_(file, mode="r", *args, **kwargs):
    f = builtins.open(file, mode, *args, **kwargs)
    return Full(f) if "w" in mode else f
files.open = open_
from ilcpmac.cli import entry_point
sys.argv = ["ilcpmac", *sys.argv[2:]]
entry_point()
"""


def _mount_tmpfs(folder: Path) -> bool:
    """A 4 MiB tmpfs mounted on ``folder`` (root only); False where none can be."""
    if os.geteuid() != 0 or shutil.which("mount") is None:
        return False
    return subprocess.run(["mount", "-t", "tmpfs", "-o", "size=4m", "tmpfs", str(folder)],
                          capture_output=True).returncode == 0


def _fill(disk: Path) -> None:
    """Fill the tmpfs ``disk`` but `FULL_DISK_FREE` bytes."""
    page = 4096
    with open(disk / "filler", "wb", buffering=0) as f:
        try:
            while True:
                f.write(b"\0" * page)
        except OSError:
            pass
    size = (disk / "filler").stat().st_size
    os.truncate(disk / "filler", (-(-size // page) - -(-FULL_DISK_FREE // page)) * page)


def _files(out: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(out.iterdir())} if out.is_dir() else {}


def full_disk_case(source: Path, fmt: str, args: tuple, earlier: Callable[[str], str] | None) -> Case:
    """``ilcpmac export`` of ``source`` onto a full disk (`FULL_DISK_FREE` bytes free: a tmpfs, else emulated),
    into an empty folder or over the files of an earlier export of ``earlier(source)``, a smaller record (so that
    writing in place cannot reuse the old files' room): one line naming the file, exit 2, and the folder as it
    was (no file truncated, none new beside old ones, no temporary)."""
    is_run = source.name == "compensation.json"

    def run(folder: Path) -> Run:
        path = _placed(source, earlier or (lambda t: t), folder / ("run" if is_run else ""),
                       source.parent if is_run else None)
        target = path.parent if is_run else path
        disk = folder / "disk"
        disk.mkdir()
        mounted = _mount_tmpfs(disk)
        out = disk / "out"
        command = ["export", str(target), "--format", fmt, *args, "--out", str(out)]
        try:
            if earlier is not None:
                first = ilcpmac(*command, folder=folder)
                if first.code != 0:
                    first.problem = f"the earlier export failed: {first.text.strip()[-150:]}"
                    return first
                shutil.copy(source, path)
            old = _files(out)
            if mounted:
                _fill(disk)
                done = ilcpmac(*command, folder=folder)
            else:
                done = run_process([sys.executable, "-c", _EMULATED_FULL_DISK, str(FULL_DISK_FREE), *command], folder)
            errors = _error_lines(done.text)
            left = sorted(p.name for p in out.glob("*") if p.suffix in (".tmp", ".new"))
            done.problem = (f"left {', '.join(left)}" if left else
                            "the folder is not as it was" if _files(out) != old else
                            f"the error names no file in the output: {errors[0][:150]}"
                            if errors and not errors[0].startswith(f"error: {out}/") else None)
            return done
        finally:
            if mounted:
                subprocess.run(["umount", str(disk)], capture_output=True)
    return Case("export full disk", f"{source.stem} --format {fmt}{' ' if args else ''}{' '.join(args)}"
                f"{' over an earlier export' if earlier else ''}", True, run)


def full_disk_cases(compensation: Path, result: Path) -> list[Case]:
    """Full-disk export (issue 34, item 9): every format into an empty folder, and those whose files grow with
    the record over an earlier export of a smaller one (tables of zeros; a cogging table of 1024 counts): moteus
    has 1024 entries whatever the table, harmonics a row per harmonic of the cogging order."""
    kt = ("--torque-constant", "0.3")
    zeros, short = _peak("tables_nm", lambda _: 0.0), _cogging(1024, 0.02)
    formats = ((compensation, "json", (), zeros), (compensation, "csv", (), zeros), (compensation, "c", (), zeros),
               (result, "c", (), short), (result, "harmonics", kt, None), (result, "moteus", kt, None))
    return [full_disk_case(source, fmt, args, None) for source, fmt, args, _ in formats] + [
        full_disk_case(source, fmt, args, earlier) for source, fmt, args, earlier in formats if earlier is not None]


def export_cases(compensation: Path, result: Path) -> list[Case]:
    return [export_case("as written", compensation, lambda t: t, False),
            export_case("as written, --format c", compensation, lambda t: t, False, "c"),
            export_case("as written", result, lambda t: t, False),
            # a result names no counts_per_rev but by its tables' length: 1023 counts is a valid encoder's
            export_case("cogging table and counts cut to 1023", result, _json_edit(
                lambda d: (d["cogging"]["torque"].pop(), d["cogging"]["count"].pop())), False),
            *(export_case(name, compensation, change) for name, change in COMPENSATION_CHANGES),
            export_case("true in tables_nm, --format c", compensation, _set("tables_nm.0.0.5", True), fmt="c"),
            export_case("NaN in tables_nm, --format csv", compensation, _set("tables_nm.0.0.3", float("nan")),
                        fmt="csv"),
            *(export_case(name, result, change) for name, change in RESULT_CHANGES),
            *export_bound_cases(compensation, result), *full_disk_cases(compensation, result)]


# ---------------------------------------------------------------- the campaign


# ---------------------------------------------------------------- 12. api arguments


#: a case's Python process: the call, an `IlcpmacError` printed as ``error:`` lines (one per line of its message)
#: and exit 2; any other exception is a traceback
API_SNIPPET = """import sys
from pathlib import Path

import numpy as np

import ilcpmac.api as ilc
from ilcpmac.core.errors import IlcpmacError

config = {config!r}
try:
{call}
except IlcpmacError as e:
    for line in str(e).splitlines() or [""]:
        print(f"error: {{line}}", file=sys.stderr)
    sys.exit(2)
"""

#: (name, call, must be rejected, the argument the error line names): each call in a case's empty folder, the
#: small config as ``config``
API_CALLS: list[tuple[str, str, bool, str]] = [
    ("run seed True", "ilc.run(config, out='run', seed=True)", True, "seed"),
    ("run seed 2.0", "ilc.run(config, out='run', seed=2.0)", True, "seed"),
    ("run trials 1.5", "ilc.run(config, out='run', trials=1.5)", True, "trials"),
    ("run trials '2'", "ilc.run(config, out='run', trials='2')", True, "trials"),
    ("run budget_min nan", "ilc.run(config, out='run', budget_min=float('nan'))", True, "budget_min"),
    ("run budget_min '5'", "ilc.run(config, out='run', budget_min='5')", True, "budget_min"),
    ("run budget_min 1e6", "ilc.run(config, out='run', budget_min=1e6)", True, "budget_min"),
    ("run backend 5", "ilc.run(config, out='run', backend=5)", True, "backend"),
    ("run backend ''", "ilc.run(config, out='run', backend='')", True, "backend"),
    ("run address 5", "ilc.run(config, out='run', backend='remote', address=5)", True, "address"),
    ("run on_event 'print'", "ilc.run(config, out='run', on_event='print')", True, "on_event"),
    ("run out NUL", "ilc.run(config, out='a\\x00b')", True, "out"),
    ("run out bytes", "ilc.run(config, out=b'run')", True, "out"),
    ("run config 5", "ilc.run(5, out='run')", True, "config"),
    ("run config ''", "ilc.run('', out='run')", True, "config"),
    ("run resume []", "ilc.run(resume=[])", True, "resume"),
    ("load_run 5", "ilc.load_run(5)", True, "run_dir"),
    ("load_run lone surrogate", "ilc.load_run('\\ud800')", True, "run_dir"),
    ("trial True", "ilc.RunResults(Path('run'), (), {}, 0.0, (), None, None).trial(True)", True, "index"),
    ("trial_frame 1.0", "ilc.RunResults(Path('run'), (), {}, 0.0, (), None, None).trial_frame(1.0)", True, "index"),
    ("print_event 5", "ilc.print_event(5)", True, "event"),
    ("print_event None", "ilc.print_event(None)", True, "event"),
    ("write_config changes 5", "ilc.write_config('c.toml', 5)", True, "changes"),
    ("write_config changes a list", "ilc.write_config('c.toml', [('trials', {})])", True, "changes"),
    ("write_config an object", "ilc.write_config('c.toml', {'trials': {'seed': object()}})", True, "changes"),
    ("write_config a set", "ilc.write_config('c.toml', {'trials': {'seed': {1, 2}}})", True, "changes"),
    ("write_config int key", "ilc.write_config('c.toml', {1: {}})", True, "changes"),
    ("write_config lone surrogate key", "ilc.write_config('c.toml', {'\\ud800': {}})", True, "changes"),
    ("write_config 2-D array", "ilc.write_config('c.toml', {'trials': {'seed': np.zeros((3, 3))}})", True,
     "changes"),
    ("write_config nested 100 deep", "d = {}\n    for _ in range(100):\n        d = {'t': d}\n"
     "    ilc.write_config('c.toml', d)", True, "changes"),
    ("write_config cyclic", "d = {}\n    d['t'] = d\n    ilc.write_config('c.toml', d)", True, "changes"),
    ("write_config base 5", "ilc.write_config('c.toml', {}, base=5)", True, "base"),
    ("write_config path NUL", "ilc.write_config('a\\x00.toml', {})", True, "path"),
    ("simulate_bench torque_sensor 'no'", "ilc.simulate_bench(config, 'b', torque_sensor='no')", True,
     "torque_sensor"),
    ("simulate_bench torque_sensor 0", "ilc.simulate_bench(config, 'b', torque_sensor=0)", True, "torque_sensor"),
    ("simulate_bench seed 1.5", "ilc.simulate_bench(config, 'b', seed=1.5)", True, "seed"),
    ("simulate_bench revolutions True", "ilc.simulate_bench(config, 'b', revolutions=True)", True, "revolutions"),
    ("simulate_bench on_trial 5", "ilc.simulate_bench(config, 'b', on_trial=5)", True, "on_trial"),
    ("simulate_bench config a dict", "ilc.simulate_bench({'trials': {}}, 'b')", True, "config"),
    ("simulate_scan reverse 'no'", "ilc.simulate_scan(config, 's', reverse='no')", True, "reverse"),
    ("simulate_scan skipped [1.5]", "ilc.simulate_scan(config, 's', skipped_forward=[1.5])", True,
     "skipped_forward"),
    ("simulate_scan skipped 3", "ilc.simulate_scan(config, 's', skipped_reverse=3)", True, "skipped_reverse"),
    ("simulate_scan revolutions 2.0", "ilc.simulate_scan(config, 's', revolutions=2.0)", True, "revolutions"),
    ("simulate_scan holding 5", "ilc.simulate_scan(config, 's', holding=5)", True, "holding"),
    ("simulate_scan rate_hz '1000'", "ilc.simulate_scan(config, 's', rate_hz='1000')", True, "rate_hz"),
    ("simulate_log duration_s inf", "ilc.simulate_log(config, 'l', duration_s=float('inf'))", True, "duration_s"),
    ("simulate_log encoder_bits '16'", "ilc.simulate_log(config, 'l', encoder_bits='16')", True, "encoder_bits"),
    ("simulate_log loop None", "ilc.simulate_log(config, 'l', loop=None)", True, "loop"),
    ("simulate_log seed True", "ilc.simulate_log(config, 'l', seed=True)", True, "seed"),
    ("identify torque_source 'piezo'", "ilc.identify('bench', torque_source='piezo')", True, "torque_source"),
    ("identify torque_source array", "ilc.identify('bench', torque_source=np.zeros(3))", True, "torque_source"),
    ("identify bench_dir 5", "ilc.identify(5)", True, "bench_dir"),
    ("identify output bytes", "ilc.identify('bench', output=b'r.json')", True, "output"),
    ("torque_constant bench_dir None", "ilc.torque_constant_nm_per_a(None)", True, "bench_dir"),
    ("import_logs []", "ilc.import_logs([], 'm.toml', 'o')", True, "logs"),
    ("import_logs [5]", "ilc.import_logs([5], 'm.toml', 'o')", True, "logs"),
    ("import_logs 2-D array", "ilc.import_logs(np.array([['a', 'b']]), 'm.toml', 'o')", True, "logs"),
    ("import_logs trial_format 'xls'", "ilc.import_logs('log.csv', 'm.toml', 'o', trial_format='xls')", True,
     "trial_format"),
    ("import_logs mapping 5", "ilc.import_logs('log.csv', 5, 'o')", True, "mapping"),
    ("import_scan logs ()", "ilc.import_scan((), 'm.toml', 'o')", True, "logs"),
    ("import_scan out None", "ilc.import_scan('log.csv', 'm.toml', None)", True, "out"),
    ("export c_type int8", "ilc.export('run', 'c', 'fw', c_type='int8')", True, "c_type"),
    ("export fmt 'xml'", "ilc.export('run', 'xml', 'fw')", True, "fmt"),
    ("export fmt None", "ilc.export('run', None, 'fw')", True, "fmt"),
    ("export torque_constant inf", "ilc.export('r.json', 'moteus', 'fw', torque_constant_nm_per_a=float('inf'))",
     True, "torque_constant_nm_per_a"),
    ("export torque_constant True", "ilc.export('r.json', 'moteus', 'fw', torque_constant_nm_per_a=True)", True,
     "torque_constant_nm_per_a"),
    ("export rated_torque -1", "ilc.export('run', 'json', 'fw', rated_torque_nm=-1.0)", True, "rated_torque_nm"),
    ("export content 5", "ilc.export('r.json', 'csv', 'fw', content=5)", True, "content"),
    ("write_config numpy values", "ilc.write_config('c.toml', {'trials': {'seed': np.int64(4), "
     "'torque_setpoints_nm': np.array([1.0, 3.0])}}, base=config)", False, ""),
    ("simulate_scan numpy options", "ilc.simulate_scan(config, 's', seed=np.int64(3), revolutions=np.int64(1), "
     "rate_hz=np.float32(1000.0), reverse=np.bool_(True))", False, ""),
    ("simulate_bench numpy seed", "ilc.simulate_bench(config, 'b', seed=np.int64(7), revolutions=np.int64(2), "
     "torque_sensor=np.bool_(False))", False, ""),
    # the campaign's grid at 3 revolutions, as its other trials: 2 may hold one whole revolution, too few
    ("run numpy seed and trials", "ilc.write_config('c.toml', {'trials': {'revolutions': 3}}, base=config)\n"
     "    ilc.run('c.toml', out='run', seed=np.int64(7), trials=np.int64(1))", False, ""),
]


def api_case(name: str, call: str, must_reject: bool, argument: str, config: Path) -> Case:
    """``call`` in a Python process (`API_SNIPPET`) in the case's empty folder: refused in one line naming
    ``argument``, nothing written; or (``must_reject`` False) done, exit 0."""
    def run(folder: Path) -> Run:
        snippet = API_SNIPPET.format(config=str(config), call="    " + call)
        done = run_process([sys.executable, "-c", snippet], folder, written=folder, cwd=folder)
        if done.code == 2 and must_reject:
            line = _error_lines(done.text)[-1:]
            written = sorted(p.name for p in folder.iterdir() if p.name not in ("stdout", "stderr"))
            if not line or not line[0].startswith(f"error: {argument}: "):
                done.problem = f"the error line names no {argument}: {line[0] if line else ''}"
            elif written:
                done.problem = f"refused, yet wrote {', '.join(written)}"
        return done
    return Case("api arguments", name, must_reject, run)


def api_cases(config: Path) -> list[Case]:
    return [api_case(name, call, must_reject, argument, config) for name, call, must_reject, argument in API_CALLS]


def progress(v: Verdict) -> None:
    print(f"  {v.outcome:<16} {v.seconds:5.1f} s  {v.case.name}: {v.detail[:110]}", flush=True)


def run_cases(cases: list[Case], scratch: Path) -> list[Verdict]:
    """Every case, JOBS at a time; a HANG is run again alone and counts only if it hangs again
    (on a shared machine a slow start under load can pass for a hang)."""
    with ThreadPoolExecutor(JOBS) as pool:
        futures = [pool.submit(execute, c, scratch) for c in cases]
        verdicts = []
        for f in futures:
            verdicts.append(f.result())
            progress(verdicts[-1])
    for i, v in enumerate(verdicts):
        if v.outcome == "HANG":
            verdicts[i] = execute(v.case, scratch)
            print("  again, alone:", end="")
            progress(verdicts[i])
    return verdicts


def report(verdicts: list[Verdict], wall: dict[str, float]) -> None:
    mib = lambda kib: kib / 1024  # noqa: E731
    categories = list(dict.fromkeys(v.case.category for v in verdicts))
    head = (f"{'category':<34}{'cases':>6}" + "".join(f"{o:>{len(o) + 2}}" for o in OUTCOMES)
            + f"{'peak MiB':>10}{'wall s':>8}")
    print("\n" + head + "\n" + "-" * len(head))
    for cat in categories + ["total"]:
        vs = [v for v in verdicts if cat in ("total", v.case.category)]
        seconds = sum(wall.values()) if cat == "total" else wall.get(cat, 0.0)
        print(f"{cat:<34}{len(vs):>6}" + "".join(f"{sum(v.outcome == o for v in vs):>{len(o) + 2}}" for o in OUTCOMES)
              + f"{mib(max(v.peak_rss_kib for v in vs)):>10.0f}{seconds:>8.0f}")
    over = [v for v in verdicts if mib(v.peak_rss_kib) > PEAK_RSS_BOUND_MIB]
    peak = max(verdicts, key=lambda v: v.peak_rss_kib)
    print(f"\ntargets: traceback {sum(v.outcome == 'TRACEBACK' for v in verdicts)} (0), "
          f"hang {sum(v.outcome == 'HANG' for v in verdicts)} (0), "
          f"non-finite {sum(v.outcome == 'NON-FINITE' for v in verdicts)} (0), "
          f"accepted garbage {sum(v.outcome == 'ACCEPTED-GARBAGE' for v in verdicts)} (0), "
          f"limit breach {sum(v.outcome == 'LIMIT-BREACH' for v in verdicts)} (0), "
          f"wrong state {sum(v.outcome == 'WRONG-STATE' for v in verdicts)} (0); "
          f"peak RSS {mib(peak.peak_rss_kib):.0f} MiB ({peak.case.name}), bound {PEAK_RSS_BOUND_MIB} MiB: "
          f"{len(over)} over")
    failing = [v for v in verdicts if v.outcome != "OK"] + over
    if failing:
        print(f"\nfailing cases ({len(failing)}):")
    for v in failing:
        outcome = v.outcome if v.outcome != "OK" else f"PEAK {mib(v.peak_rss_kib):.0f} MiB"
        print(f"  [{v.case.category}] {v.case.name}: {outcome}: {v.detail}")


#: the groups of cases ``--only`` picks
GROUPS = ["bench", "config", "emulator", "targets", "import", "scan", "sweep", "stages", "lying", "resume", "units",
          "scheduler", "export", "api"]


def make_inputs(only: set[str], scratch: Path, config: Path, base: Path, seed: int) -> str | None:
    """The base inputs of the import and scan groups in ``scratch``, from the base bench ``base`` and the
    small ``config``; a message if the scan folders cannot be imported."""
    if "import" in only:
        make_import_base(base, scratch / "import-base")
    if "units" in only:
        made = make_units_base(base, scratch / "units-base")
        if made is not None:
            return made
    if only & {"stages", "lying", "resume", "export"}:
        make_campaign_configs(scratch)
    if only & {"resume", "export"}:
        made = make_runs(scratch / SMALL_CAMPAIGN_TOML, scratch)
        if made is not None:
            return made
    if "export" in only:
        made = make_result(base, scratch)
        if made is not None:
            return made
    if "scan" not in only:
        return None
    logs = scratch / "scan-logs"
    make_scan_logs(config, base, logs, seed)
    for name, log, mapping_file in (("scan-currents", SCAN_LOG, MAP_SCAN), ("scan-torque", SCAN_TORQUE_LOG,
                                                                            MAP_SCAN_TORQUE)):
        made = run_process([ILCPMAC, "import", str(logs / log), "--map", str(logs / mapping_file), "--out",
                            str(scratch / name)], scratch)
        if made.code != 0:
            return f"cannot import the base scan folder {name}:\n{made.text[-2000:]}"
    return None


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="about a quarter of the cases")
    parser.add_argument("--seed", type=int, default=2009, help="seed of every random mutation")
    parser.add_argument("--only", choices=GROUPS, action="append", help="run only these categories (repeatable)")
    parser.add_argument("--match", default="", help="run only cases whose name contains this text")
    args = parser.parse_args()
    only = set(args.only or GROUPS)
    pick = lambda cases: [c for c in (cases[::4] if args.quick else cases) if args.match in c.name]  # noqa: E731

    verdicts: list[Verdict] = []
    wall: dict[str, float] = {}
    with tempfile.TemporaryDirectory(prefix="ilcpmac-fuzz-") as tmp:
        scratch = Path(tmp)
        config_text = small_config(SEED_CONFIG.read_text())
        config = scratch / "small.toml"
        config.write_text(config_text)
        # what the controller knows alone (the real-bench template): a hostile target's bench is checked against
        # [bench] only where the config gives it, so its attacks reach the trials
        remote = scratch / "remote.toml"
        remote.write_text(small_config(REAL_CONFIG.read_text()))
        base = scratch / "base-bench"
        made = run_process([ILCPMAC, "simulate", str(config), "--out", str(base)], scratch)
        if made.code != 0:
            print(f"cannot simulate the base bench folder:\n{made.text[-2000:]}")
            return 1
        (base / "truth.json").unlink()
        made = make_inputs(only, scratch, config, base, args.seed)
        if made is not None:
            print(made)
            return 1
        stages: list[tuple[str, str, Callable[[], list[Verdict]]]] = [
            ("bench", "bench folders", lambda: run_cases(pick(bench_cases(base, args.seed)), scratch)),
            ("config", "configs & args", lambda: run_cases(pick(config_cases(config_text, base, args.seed)), scratch)),
            ("emulator", "emulator vs hostile clients",
             lambda: emulator_verdicts(config, scratch, args.quick, args.match)),
            ("targets", "remote client vs hostile targets",
             lambda: run_cases(pick([target_case(t, remote) for t in ft.TARGETS]), scratch)),
            ("import", "import: mappings & logs",
             lambda: run_cases(pick(import_cases(scratch / "import-base", args.seed)), scratch)),
            ("scan", "standstill scans", lambda: run_cases(pick(scan_cases(
                scratch / "scan-currents", scratch / "scan-torque", scratch / "scan-logs", args.seed)), scratch)),
            ("sweep", "sweep specs", lambda: run_cases(pick(sweep_cases(config)), scratch)),
            ("stages", "stages", lambda: run_cases(pick(stage_cases(scratch / STAGE_CAMPAIGN_TOML)), scratch)),
            ("lying", "lying values", lambda: run_cases(pick(lying_cases(scratch / STAGE_CAMPAIGN_TOML)), scratch)),
            ("resume", "resume tampering", lambda: run_cases(pick(resume_cases(scratch)), scratch)),
            ("units", "import units & gaps", lambda: run_cases(pick(unit_cases(scratch / "units-base", base)),
                                                               scratch)),
            ("scheduler", "sweep: schedulers & magnets", lambda: run_cases(pick(scheduler_cases(config)), scratch)),
            ("export", "export tables", lambda: run_cases(pick(export_cases(
                scratch / "run-finished" / "compensation.json", scratch / "result.json")), scratch)),
            ("api", "api arguments", lambda: run_cases(pick(api_cases(config)), scratch)),
        ]
        for flag, category, stage in stages:
            if flag not in only:
                continue
            print(f"{category}:", flush=True)
            start = time.monotonic()
            verdicts += stage()
            wall[category] = time.monotonic() - start
    if not verdicts:
        print("no case selected")
        return 1
    report(verdicts, wall)
    return 0


if __name__ == "__main__":
    sys.exit(main())
