"""Storage and wall-time benchmark (issue 10): run-directory size, identification and campaign wall time.

    python benchmarks/storage.py [--repeats N] [--cold-repeats N] [--baseline REF]

Everything runs as a user runs it, as whole processes with a warm numba cache
(one warm-up run first), best of N:

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

The machine may be shared (two cores here): the load average before each
figure's runs is printed beside it, and a figure measured while the machine
was busier than its cores is marked "contended" (best-of-N keeps the least
disturbed run, but a contended figure is an upper bound).
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
    for path in (tree / "ilcpmac" / "configs" / "seed-bench.toml", tree / "configs" / "seed-bench.toml"):
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


def ilcpmac(tree: Path, args: list[str], cache: Path) -> float:
    """Run ``ilcpmac ARGS`` from the source tree ``tree``; return its wall time, s."""
    env = dict(os.environ, PYTHONPATH=str(tree), NUMBA_CACHE_DIR=str(cache))
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", "from ilcpmac.cli import main; main()", *args], cwd=tree, env=env,
                          capture_output=True, text=True)
    elapsed = time.perf_counter() - start
    if done.returncode != 0:
        sys.exit(f"ilcpmac {' '.join(args)} failed ({done.returncode}): {done.stderr.strip().splitlines()[-1:]}")
    return elapsed


def size_mb(folder: Path) -> float:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) / 1e6


def best(tree: Path, args: list[str], cache: Path, repeats: int, fresh: Path | None = None,
         cold: bool = False) -> tuple[float, float]:
    """Best wall time of ``repeats`` runs and the highest 1-minute load average before one of them.

    ``fresh`` is removed before each run (a run's --out); ``cold`` empties the numba cache before each.
    """
    times, loads = [], []
    for _ in range(repeats):
        if fresh is not None:
            shutil.rmtree(fresh, ignore_errors=True)
        if cold:
            shutil.rmtree(cache, ignore_errors=True)
        loads.append(os.getloadavg()[0])
        times.append(ilcpmac(tree, args, cache))
    return min(times), max(loads)


def measure(tree: Path, work: Path, repeats: int, cold_repeats: int, label: str) -> dict:
    """Every figure for the source tree ``tree``; its seed bench is converted to the other format in-process."""
    cache = work / "numba-cache"
    bench = work / "bench"
    ilcpmac(tree, ["simulate", str(seed_config(tree)), "--out", str(bench)], cache)
    figures = {"label": label, "bench": {}}
    code = ("import sys; from ilcpmac.bench.format import convert_bench; "
            "convert_bench(sys.argv[1], sys.argv[2], '.parquet')")
    converted = work / "bench-parquet"
    has_parquet = subprocess.run([sys.executable, "-c", code, str(bench), str(converted)], cwd=tree,
                                 env=dict(os.environ, PYTHONPATH=str(tree)), capture_output=True).returncode == 0
    for kind, folder in (("CSV", bench), ("Parquet", converted if has_parquet else None)):
        if folder is None:
            continue
        args = ["identify", str(folder), "--output", str(work / "result.json")]
        ilcpmac(tree, args, cache)  # warm-up: numba compiles into the cache
        figures["bench"][kind] = (size_mb(folder), *best(tree, args, cache, repeats))
    run = work / "run"
    campaign = ["run", *one_speed_config(tree, work), "--out", str(run)]
    figures["cold"] = best(tree, campaign, work / "cold-cache", cold_repeats, fresh=run, cold=True)
    shutil.rmtree(work / "cold-cache", ignore_errors=True)
    figures["warm"] = best(tree, campaign, cache, repeats, fresh=run)
    figures["run_mb"] = size_mb(run)
    figures["run_format"] = "Parquet" if any(run.glob("trial_*.parquet")) else "CSV"
    return figures


def verdict(ok: bool) -> str:
    return "PASS" if ok else "MISS"


def report(columns: list[dict]) -> None:
    cores = os.cpu_count() or 1
    width = 34
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
            ("one-speed campaign cold s (best)", lambda c: c["cold"], "campaign cold s", TARGET_COLD_S)]
    contended = False
    for name, get, before, bound in rows:
        figures = [(BEFORE_FIGURES[before], None) if before else None] + [get(c) for c in columns]
        cells = []
        for figure in figures:
            if figure is None:
                cells.append("-")
                continue
            value, load = figure
            text = f"{value:.2f}" + ("" if bound is None else f" {verdict(value <= bound)}")
            if load is not None:  # a timing: the load average before its runs
                text += f" (load {load:.1f}{', contended' if load > cores else ''})"
                contended |= load > cores
            cells.append(text)
        print(f"{name:<42}" + "".join(f"{c:>{width}}" for c in cells) + f"   {'' if bound is None else bound}")
    print("run-directory trials: " + ", ".join(f"{c['label']}: {c['run_format']}" for c in columns))
    if contended:
        print(f"contended: the load average exceeded the {cores} cores before some runs (other processes); "
              "those figures are upper bounds")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3, help="runs per figure; the best counts (default 3)")
    parser.add_argument("--cold-repeats", type=int, default=1,
                        help="cold campaign runs (empty numba cache each); the best counts (default 1)")
    parser.add_argument("--baseline", default=BEFORE_REVISION,
                        help=f"git revision to compare with (default {BEFORE_REVISION}; '' for none)")
    args = parser.parse_args()
    print(f"load average before: {os.getloadavg()[0]:.2f} ({os.cpu_count()} cores)")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        columns = []
        if args.baseline:
            old = tmp / "baseline-tree"
            old.mkdir()
            archive = subprocess.run(["git", "archive", args.baseline], cwd=ROOT, capture_output=True, check=True)
            subprocess.run(["tar", "-x", "-C", str(old)], input=archive.stdout, check=True)
            (tmp / "baseline").mkdir()
            columns.append(measure(old, tmp / "baseline", args.repeats, args.cold_repeats,
                                   f"{args.baseline} (before)"))
            shutil.rmtree(tmp / "baseline")
        (tmp / "new").mkdir()
        columns.append(measure(ROOT, tmp / "new", args.repeats, args.cold_repeats, "work tree (after)"))
    report(columns)
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
