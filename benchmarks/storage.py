"""Storage and wall-time benchmark (issue 10): run-directory size, identification and campaign wall time.

    python benchmarks/storage.py [--repeats N] [--cold-repeats N] [--baseline REF]

Everything runs as a user runs it, as whole processes with a warm numba cache
(one warm-up run first), best of N, each run of the work tree alternating with
one of the revision it is compared with:

1. the seed bench (``ilcpmac simulate``) as CSV and as Parquet: folder size,
   and ``ilcpmac identify`` of each (target <= 2 s, either format);
2. issue 10's default campaign (``ilcpmac run``), the one-speed campaign
   (benchmarks/campaign.py's ONE_SPEED variant of the seed config; a tree
   whose config has no operating range runs its default as it is):
   run-directory size (target <= 60 MB) and wall time, warm (target <= 4 s)
   and with an empty numba cache (cold, target <= 15 s, best of
   --cold-repeats);
3. the same with the code of git revision REF (default BEFORE_REVISION, the
   revision issue 10's item 3 started from; read with ``git archive``, nothing
   in the work tree changes): the figures before beside the figures after.
   ``--baseline ''`` skips it; the figures recorded at BEFORE_REVISION
   (BEFORE_FIGURES) are printed in any case.

"Warm" means what a second run finds on any machine: the numba cache and
Python's bytecode cache filled by the warm-up run. This sandbox sets
PYTHONDONTWRITEBYTECODE=1, so Python never caches the bytecode of ilcpmac's
own modules (an editable install: pip compiled the libraries' at install) and
compiles about 90 modules on every start, about 0.4 s of CPU; the timed runs
therefore keep their bytecode under a PYTHONPYCACHEPREFIX of their own, and
the campaign is also timed as this sandbox runs it ("no bytecode cache").

The machine may be shared (two cores here): beside each figure is the CPU
that other processes used during its best run (from /proc/stat: the machine's
busy time less the run's own), and a figure whose best run shared the machine
with more than a fifth of a core is marked "contended": an upper bound.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

from campaign import ONE_SPEED

ROOT = Path(__file__).resolve().parents[1]
TARGET_MB, TARGET_IDENTIFY_S, TARGET_WARM_S, TARGET_COLD_S = 60.0, 2.0, 4.0, 15.0
#: the revision the wall-time work of issue 10 (item 3) started from
BEFORE_REVISION = "1a9f043"
#: its figures, measured with this benchmark before that work (best of 3; load average 2.3-2.7 on 2 cores)
BEFORE_FIGURES = {"identify CSV s": 3.86, "identify Parquet s": 3.74, "campaign warm s": 8.50,
                  "campaign cold s": 13.62, "run directory MB": 42.60}


def seed_config(tree: Path) -> Path:
    """The seed-bench config of the source tree ``tree`` (packaged, or in configs/ in older trees)."""
    for path in (tree / "src" / "ilcpmac" / "configs" / "seed-bench.toml",
                 tree / "ilcpmac" / "configs" / "seed-bench.toml", tree / "configs" / "seed-bench.toml"):
        if path.is_file():
            return path
    sys.exit(f"{tree}: no seed-bench.toml")


def one_speed_config(tree: Path, work: Path) -> list[str]:
    """``ilcpmac run``'s config argument for issue 10's default campaign in ``tree``: its seed config made the
    one-speed campaign (`campaign.ONE_SPEED`), or nothing (the tree's default) where it has no such keys."""
    text = seed_config(tree).read_text()
    for key, value in ONE_SPEED.items():
        text, n = re.subn(rf"(?m)^{key} = .*$", f"{key} = {value}", text)
        if n != 1:
            return []
    path = work / "one-speed.toml"
    path.write_text(text)
    return [str(path)]


#: the ``ilcpmac`` executable of any tree (`ilcpmac.cli.entry_point`, or `main` in trees before it)
ENTRY_POINT = "import ilcpmac.cli as cli; getattr(cli, 'entry_point', cli.main)()"
#: CPU seconds of other processes during a run above which its figure is "contended"
CONTENDED_CPU_S = 0.2


def busy_s() -> float:
    """CPU seconds the whole machine has been busy since boot (/proc/stat; 0 where there is none)."""
    try:
        fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]
    except OSError:
        return 0.0
    user, nice, system, _idle, _iowait, irq, softirq, steal = (int(f) for f in fields[:8])
    return (user + nice + system + irq + softirq + steal) / os.sysconf("SC_CLK_TCK")


def python_path(tree: Path) -> str:
    """The folder of ``tree`` that holds the package: src/ in a src layout, the tree itself before."""
    return str(tree / "src" if (tree / "src" / "ilcpmac").is_dir() else tree)


def ilcpmac(tree: Path, args: list[str], cache: Path, bytecode: Path | None) -> tuple[float, float]:
    """Run ``ilcpmac ARGS`` from the source tree ``tree`` with the numba cache ``cache`` and Python's bytecode
    cache under ``bytecode`` (None: as this environment runs Python); return its wall time and the CPU time
    other processes used meanwhile, s."""
    env = dict(os.environ, PYTHONPATH=python_path(tree), NUMBA_CACHE_DIR=str(cache))
    if bytecode is not None:
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        env["PYTHONPYCACHEPREFIX"] = str(bytecode)
    before_cpu, before_busy = os.times(), busy_s()
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", ENTRY_POINT, *args], cwd=tree, env=env, capture_output=True,
                          text=True)
    elapsed = time.perf_counter() - start
    after_cpu, after_busy = os.times(), busy_s()
    if done.returncode != 0:
        sys.exit(f"ilcpmac {' '.join(args)} failed ({done.returncode}): {done.stderr.strip().splitlines()[-1:]}")
    own = (after_cpu.children_user + after_cpu.children_system - before_cpu.children_user
           - before_cpu.children_system)
    return elapsed, max(after_busy - before_busy - own, 0.0)


def machine_speed_s() -> float:
    """Best of three of a fixed pure-Python loop, s: how fast the machine runs Python at the moment (on this machine it
    changed by up to 1.8x within a day, with nothing else running)."""
    best = float("inf")
    for _ in range(3):
        start, total = time.perf_counter(), 0
        for i in range(10_000_000):
            total += i
        best = min(best, time.perf_counter() - start)
    return best


def size_mb(folder: Path) -> float:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) / 1e6


@dataclass(frozen=True)
class Subject:
    """A source tree measured, its working folder and its column's label."""

    tree: Path
    work: Path
    label: str

    @property
    def cache(self) -> Path:
        return self.work / "numba-cache"

    @property
    def bytecode(self) -> Path:
        return self.work / "bytecode"

    @property
    def run(self) -> Path:
        return self.work / "run"


def prepare(subject: Subject) -> tuple[dict, dict]:
    """``subject``'s seed bench (simulated, converted to Parquet in-process), its campaign config and a warm-up
    run of each timed command (numba's cache and the bytecode filled); the figures so far and the commands."""
    tree, work = subject.tree, subject.work
    bench = work / "bench"
    ilcpmac(tree, ["simulate", str(seed_config(tree)), "--out", str(bench)], subject.cache, subject.bytecode)
    code = ("import sys; from ilcpmac.bench.format import convert_bench; "
            "convert_bench(sys.argv[1], sys.argv[2], '.parquet')")
    converted = work / "bench-parquet"
    env = dict(os.environ, PYTHONPATH=python_path(tree))
    has_parquet = subprocess.run([sys.executable, "-c", code, str(bench), str(converted)], cwd=tree, env=env,
                                 capture_output=True).returncode == 0
    figures, commands = {"label": subject.label, "bench": {}}, {}
    for kind, folder in (("CSV", bench), ("Parquet", converted if has_parquet else None)):
        if folder is not None:
            figures["bench"][kind] = size_mb(folder)
            commands[kind] = ["identify", str(folder), "--output", str(work / "result.json")]
    commands["campaign"] = ["run", *one_speed_config(tree, work), "--out", str(subject.run)]
    for args in commands.values():
        shutil.rmtree(subject.run, ignore_errors=True)
        ilcpmac(tree, args, subject.cache, subject.bytecode)
    figures["run_mb"] = size_mb(subject.run)
    figures["run_format"] = "Parquet" if any(subject.run.glob("trial_*.parquet")) else "CSV"
    return figures, commands


def interleaved(subjects: list[Subject], commands: list[dict], kind: str, repeats: int, bytecode: bool = True,
                cold: bool = False) -> list[tuple[float, float]]:
    """Per subject, the best wall time of ``repeats`` runs of its command ``kind`` and the CPU other processes
    used during that run; the subjects' runs alternate, so that the machine's changes of speed (tens of per
    cent over minutes here) fall on all alike. ``cold``: an empty numba cache each time, and the bytecode as
    this environment keeps it (a first run)."""
    runs = [[] for _ in subjects]
    for _ in range(repeats):
        for subject, done, command in zip(subjects, runs, commands):
            if kind not in command:
                continue
            shutil.rmtree(subject.run, ignore_errors=True)
            cache = subject.work / "cold-cache" if cold else subject.cache
            if cold:
                shutil.rmtree(cache, ignore_errors=True)
            done.append(ilcpmac(subject.tree, command[kind], cache, subject.bytecode if bytecode and not cold
                                else None))
    return [min(done) if done else None for done in runs]


def measure(subjects: list[Subject], repeats: int, cold_repeats: int) -> list[dict]:
    """Every figure of every subject (`prepare`, then each timed command `interleaved`)."""
    prepared = [prepare(subject) for subject in subjects]
    figures, commands = [p[0] for p in prepared], [p[1] for p in prepared]
    for kind in ("CSV", "Parquet"):
        for f, timing in zip(figures, interleaved(subjects, commands, kind, repeats)):
            if timing is not None:
                f["bench"][kind] = (f["bench"][kind], *timing)
    for key, options in (("warm", {}), ("warm_sandbox", {"bytecode": False}),
                         ("cold", {"cold": True})):
        count = cold_repeats if key == "cold" else repeats
        for f, timing in zip(figures, interleaved(subjects, commands, "campaign", count, **options)):
            f[key] = timing
    return figures


def verdict(ok: bool) -> str:
    return "PASS" if ok else "MISS"


def report(columns: list[dict]) -> None:
    width = 44
    names = ["recorded before"] + [c["label"] for c in columns]
    print(f"\n{'':<42}" + "".join(f"{n:>{width}}" for n in names) + "   target")

    def bench(kind: str, timing: bool):
        return lambda c: None if kind not in c["bench"] else (c["bench"][kind][1:] if timing else
                                                                  (c["bench"][kind][0], None))

    rows = [("seed bench as CSV: size MB", bench("CSV", False), None, None),
            ("seed bench as CSV: identify s (best)", bench("CSV", True), "identify CSV s", TARGET_IDENTIFY_S),
            ("seed bench as Parquet: size MB", bench("Parquet", False), None, None),
            ("seed bench as Parquet: identify s (best)", bench("Parquet", True), "identify Parquet s",
             TARGET_IDENTIFY_S),
            ("one-speed run directory MB", lambda c: (c["run_mb"], None), "run directory MB", TARGET_MB),
            ("one-speed campaign warm s (best)", lambda c: c["warm"], "campaign warm s", TARGET_WARM_S),
            ("  the same, no bytecode cache (sandbox)", lambda c: c["warm_sandbox"], None, TARGET_WARM_S),
            ("one-speed campaign cold s (best)", lambda c: c["cold"], "campaign cold s", TARGET_COLD_S)]
    contended = False
    for name, get, before, bound in rows:
        figures = [(BEFORE_FIGURES[before], None) if before else None] + [get(c) for c in columns]
        cells = []
        for figure in figures:
            if figure is None:
                cells.append("-")
                continue
            value, others_s = figure
            text = f"{value:.2f}" + ("" if bound is None else f" {verdict(value <= bound)}")
            if others_s is not None:  # a timing: the CPU other processes used during its best run
                busy = others_s > CONTENDED_CPU_S
                text += f" (others {others_s:.1f} s{', contended' if busy else ''})"
                contended |= busy
            cells.append(text)
        print(f"{name:<42}" + "".join(f"{c:>{width}}" for c in cells) + f"   {'' if bound is None else bound}")
    print("run-directory trials: " + ", ".join(f"{c['label']}: {c['run_format']}" for c in columns))
    print("others: CPU seconds other processes used during the best run (/proc/stat)")
    if contended:
        print(f"contended: other processes used more than {CONTENDED_CPU_S} s of CPU during some best runs; "
              "those figures are upper bounds")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3, help="runs per figure; the best counts (default 3)")
    parser.add_argument("--cold-repeats", type=int, default=1,
                        help="cold campaign runs (empty numba cache each); the best counts (default 1)")
    parser.add_argument("--baseline", default=BEFORE_REVISION,
                        help=f"git revision to compare with (default {BEFORE_REVISION}; '' for none)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        subjects = []
        if args.baseline:
            old = tmp / "baseline-tree"
            old.mkdir()
            archive = subprocess.run(["git", "archive", args.baseline], cwd=ROOT, capture_output=True, check=True)
            subprocess.run(["tar", "-x", "-C", str(old)], input=archive.stdout, check=True)
            subjects.append(Subject(old, tmp / "baseline", f"{args.baseline} (before)"))
        subjects.append(Subject(ROOT, tmp / "new", "work tree (after)"))
        for subject in subjects:
            subject.work.mkdir()
        before = machine_speed_s()
        columns = measure(subjects, args.repeats, args.cold_repeats)
        after = machine_speed_s()
    report(columns)
    print(f"machine speed: a 10^7-step Python loop took {before:.2f} s before the runs and {after:.2f} s "
          "after (best of 3); figures measured at other speeds compare only as ratios")


if __name__ == "__main__":
    main()
