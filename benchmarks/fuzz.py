"""Hostile-input campaign: mutated bench folders, configs and arguments, protocol attacks both ways.

Run ``python benchmarks/fuzz.py [--quick] [--seed N]`` with the project's
virtualenv (8 to 15 minutes on two shared cores; ``--quick`` about a
quarter; ``--only`` and ``--match`` pick cases). Everything is
generated deterministically from the seed in a temporary folder:

1. bench folders: a small simulated bench (2 x 2 set points, 2 revolutions:
   one ``ilcpmac identify`` takes about 2 s) copied and mutated, each copy run
   as ``ilcpmac identify DIR --output OUT.json``;
2. configs and arguments: configs/seed-bench.toml reduced the same way and
   mutated, run as ``ilcpmac simulate`` (drive, grid and excitation keys) or
   ``ilcpmac run --trials 1`` (campaign, limits, pipeline and stage keys);
3. hostile clients against ``ilcpmac emulate`` and hostile targets answering
   ``RemoteBackend`` (benchmarks/fuzz_targets.py).

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
- ACCEPTED-GARBAGE: exit 0 (or an ACCEPT, DESCRIBE or open connection) on an
  input that must be rejected, or the contents of a file outside the bench
  folder echoed.

The targets are 0, 0, 0, 0 and every process's peak RSS under PEAK_RSS_BOUND_MIB.
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
PEAK_RSS_BOUND_MIB = 1024
JOBS = 2
#: written into files outside the bench folder; seeing it in any output means their contents leaked
SECRET = "SECRET-7f3a9c-do-not-echo"
OUTCOMES = ("OK", "TRACEBACK", "HANG", "NON-FINITE", "ACCEPTED-GARBAGE")
_ENV = {**os.environ, "NO_COLOR": "1", "TERM": "dumb", "COLUMNS": "200"}


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
    folder the case wrote (scanned for NaN/Infinity).
    """

    code: int | None
    timed_out: bool
    text: str
    peak_rss_kib: int
    accepted: bool
    written: Path | None = None
    seconds: float = 0.0


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


def run_process(argv: list[str], folder: Path, written: Path | None = None, cwd: Path = ROOT) -> Run:
    """Run ``argv`` with the time and memory caps; stdout and stderr go to files in ``folder``."""
    start = time.monotonic()
    with open(folder / "stdout", "wb") as fo, open(folder / "stderr", "wb") as fe:
        proc = subprocess.Popen(argv, cwd=cwd, stdout=fo, stderr=fe, stdin=subprocess.DEVNULL, env=_ENV,
                                preexec_fn=ft.limit_memory(MEMORY_CAP_BYTES), start_new_session=True)
    timed_out = False
    while True:
        pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
        if pid:
            break
        if time.monotonic() - start > TIMEOUT_S:
            timed_out = True
            os.killpg(proc.pid, signal.SIGKILL)
            pid, status, usage = os.wait4(proc.pid, 0)
            break
        time.sleep(0.02)
    proc.returncode = os.waitstatus_to_exitcode(status)
    try:
        os.killpg(proc.pid, signal.SIGKILL)  # nothing the case started outlives it
    except OSError:
        pass
    text = ((folder / "stdout").read_bytes()[-200_000:] + b"\n"
            + (folder / "stderr").read_bytes()[-200_000:]).decode("utf-8", "replace")
    return Run(proc.returncode, timed_out, text, usage.ru_maxrss, proc.returncode == 0, written,
               time.monotonic() - start)


def ilcpmac(*args, folder: Path, written: Path | None = None) -> Run:
    return run_process([ILCPMAC, *map(str, args)], folder, written)


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
    for line in reversed(tail):
        if re.match(r"^\s*[\w.]+(Error|Exception|Interrupt|Exit|Warning)\b|^\s*\w+Error", line):
            return line.strip()
    return next((line.strip() for line in reversed(tail) if line.strip()), "Traceback")


_SCRATCH = re.compile(re.escape(tempfile.gettempdir()) + r"/ilcpmac-fuzz-[^/\s]+/(case-[^/\s]+/)?")


def classify(case: Case, run: Run) -> tuple[str, str]:
    """(outcome, one line saying why, scratch paths left out) for a case and what it did."""
    outcome, detail = _classify(case, run)
    return outcome, _SCRATCH.sub("", detail)


def _classify(case: Case, run: Run) -> tuple[str, str]:
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


def cell(row: int, name: str, text: str) -> Callable:
    def fn(header, rows):
        rows[row][header.index(name)] = text
        return header, rows
    return rows_edit(fn)


def raw(file: str, fn: Callable[[bytes], bytes]) -> Callable:
    def mutate(d: Path, rng) -> None:
        (d / file).write_bytes(fn((d / file).read_bytes()))
    return mutate


def key(table: str, name: str, value: str | None) -> Callable:
    return lambda d, rng: bench_toml(d, table, name, value)


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


def _fifo(d: Path, rng) -> None:
    (d / T1).unlink()
    os.mkfifo(d / T1)


def _symlink(target: str | Callable[[Path], Path], file: str = T1) -> Callable:
    def mutate(d: Path, rng) -> None:
        pointee = target(d) if callable(target) else target
        (d / file).unlink()
        (d / file).symlink_to(pointee)
    return mutate


def _sparse(d: Path, rng) -> None:
    with open(d / T1, "r+b") as f:
        f.truncate(2 << 30)


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
    ("trial is a FIFO", True, _fifo),
    ("trial symlink to /dev/zero", True, _symlink("/dev/zero")),
    ("trial 2 GiB sparse file", True, _sparse),
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
    """The seed bench reduced: a 2 x 2 grid, 2 revolutions, 2 learned points of 2 revolutions, one validation
    point."""
    for table, name, value in (("trials", "torque_setpoints_nm", "[1.0, 3.0]"),
                               ("trials", "speed_setpoints_hz", "[0.8, 1.0]"), ("trials", "revolutions", "2"),
                               ("campaign", "learn_torques_nm", "[1.0, 3.0]"),
                               ("campaign", "learn_speeds_hz", "[0.8]"), ("campaign", "learn_revolutions", "[2]"),
                               ("campaign", "validate_torques_nm", "[2.0]"),
                               ("campaign", "validate_speeds_hz", "[0.8]"),
                               ("campaign", "validate_revolutions", "2")):
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
    ("old key ilc_trials", True, "campaign", "ilc_trials", "3"),
    ("min_improvement 2", True, "campaign", "min_improvement", "2.0"),
    ("ripple_harmonics 0", True, "campaign", "ripple_harmonics", "0"),
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
        for i, a in enumerate(attacks):
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


# ---------------------------------------------------------------- the campaign


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
    head = f"{'category':<34}{'cases':>6}" + "".join(f"{o:>18}" for o in OUTCOMES) + f"{'peak MiB':>10}{'wall s':>8}"
    print("\n" + head + "\n" + "-" * len(head))
    for cat in categories + ["total"]:
        vs = [v for v in verdicts if cat in ("total", v.case.category)]
        seconds = sum(wall.values()) if cat == "total" else wall.get(cat, 0.0)
        print(f"{cat:<34}{len(vs):>6}" + "".join(f"{sum(v.outcome == o for v in vs):>18}" for o in OUTCOMES)
              + f"{mib(max(v.peak_rss_kib for v in vs)):>10.0f}{seconds:>8.0f}")
    over = [v for v in verdicts if mib(v.peak_rss_kib) > PEAK_RSS_BOUND_MIB]
    peak = max(verdicts, key=lambda v: v.peak_rss_kib)
    print(f"\ntargets: traceback {sum(v.outcome == 'TRACEBACK' for v in verdicts)} (0), "
          f"hang {sum(v.outcome == 'HANG' for v in verdicts)} (0), "
          f"non-finite {sum(v.outcome == 'NON-FINITE' for v in verdicts)} (0), "
          f"accepted garbage {sum(v.outcome == 'ACCEPTED-GARBAGE' for v in verdicts)} (0); "
          f"peak RSS {mib(peak.peak_rss_kib):.0f} MiB ({peak.case.name}), bound {PEAK_RSS_BOUND_MIB} MiB: "
          f"{len(over)} over")
    failing = [v for v in verdicts if v.outcome != "OK"] + over
    if failing:
        print(f"\nfailing cases ({len(failing)}):")
    for v in failing:
        outcome = v.outcome if v.outcome != "OK" else f"PEAK {mib(v.peak_rss_kib):.0f} MiB"
        print(f"  [{v.case.category}] {v.case.name}: {outcome}: {v.detail}")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="about a quarter of the cases")
    parser.add_argument("--seed", type=int, default=2009, help="seed of every random mutation")
    parser.add_argument("--only", choices=["bench", "config", "emulator", "targets"], action="append",
                        help="run only these categories (repeatable)")
    parser.add_argument("--match", default="", help="run only cases whose name contains this text")
    args = parser.parse_args()
    only = set(args.only or ["bench", "config", "emulator", "targets"])
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
        stages: list[tuple[str, str, Callable[[], list[Verdict]]]] = [
            ("bench", "bench folders", lambda: run_cases(pick(bench_cases(base, args.seed)), scratch)),
            ("config", "configs & args", lambda: run_cases(pick(config_cases(config_text, base, args.seed)), scratch)),
            ("emulator", "emulator vs hostile clients",
             lambda: emulator_verdicts(config, scratch, args.quick, args.match)),
            ("targets", "remote client vs hostile targets",
             lambda: run_cases(pick([target_case(t, remote) for t in ft.TARGETS]), scratch)),
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
