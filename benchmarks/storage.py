"""Storage benchmark (issue 10): run-directory size, identification and campaign wall time, CSV beside Parquet.

    python benchmarks/storage.py [--repeats N] [--baseline REF]

Everything runs as a user runs it, as whole processes with a warm numba cache
(one warm-up run first), best of N:

1. the seed bench (``ilcpmac simulate``) as CSV and as Parquet: folder size,
   and ``ilcpmac identify`` of each (target <= 2 s, either format);
2. the default campaign (``ilcpmac run``): run-directory size (target <= 60 MB)
   and wall time, warm (target <= 4 s) and once with an empty numba cache
   (cold, target <= 15 s);
3. the same with the code of git revision REF (default HEAD, read with
   ``git archive``; nothing in the work tree changes), whose run directories
   hold CSV trials: today's figures beside the new ones. ``--baseline ''``
   skips it.

The machine may be shared: the load average is printed with the figures, and
best-of-N keeps the least disturbed run.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TARGET_MB, TARGET_IDENTIFY_S, TARGET_WARM_S, TARGET_COLD_S = 60.0, 2.0, 4.0, 15.0


def seed_config(tree: Path) -> Path:
    """The seed-bench config of the source tree ``tree`` (packaged, or in configs/ in older trees)."""
    for path in (tree / "ilcpmac" / "configs" / "seed-bench.toml", tree / "configs" / "seed-bench.toml"):
        if path.is_file():
            return path
    sys.exit(f"{tree}: no seed-bench.toml")


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


def best(tree: Path, args: list[str], cache: Path, repeats: int, fresh: Path | None = None) -> float:
    """Best wall time of ``repeats`` runs (``fresh`` is removed before each: a run's --out)."""
    times = []
    for _ in range(repeats):
        if fresh is not None:
            shutil.rmtree(fresh, ignore_errors=True)
        times.append(ilcpmac(tree, args, cache))
    return min(times)


def measure(tree: Path, work: Path, repeats: int, label: str) -> dict:
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
        figures["bench"][kind] = (size_mb(folder), best(tree, args, cache, repeats))
    cold_cache = work / "cold-cache"
    run = work / "run"
    figures["cold_s"] = ilcpmac(tree, ["run", "--out", str(run)], cold_cache)
    shutil.rmtree(cold_cache, ignore_errors=True)
    figures["warm_s"] = best(tree, ["run", "--out", str(run)], cache, repeats, fresh=run)
    figures["run_mb"] = size_mb(run)
    figures["run_format"] = "Parquet" if any(run.glob("trial_*.parquet")) else "CSV"
    return figures


def verdict(ok: bool) -> str:
    return "PASS" if ok else "MISS"


def report(columns: list[dict]) -> None:
    width = 26
    print(f"\n{'':<44}" + "".join(f"{c['label']:>{width}}" for c in columns) + "   target")
    rows = [("seed bench as CSV: size MB", lambda c: c["bench"].get("CSV", (None,))[0], "", None),
            ("seed bench as CSV: identify s (best)", lambda c: c["bench"].get("CSV", (None, None))[1], "<= 2 s",
             TARGET_IDENTIFY_S),
            ("seed bench as Parquet: size MB", lambda c: c["bench"].get("Parquet", (None,))[0], "", None),
            ("seed bench as Parquet: identify s (best)", lambda c: c["bench"].get("Parquet", (None, None))[1],
             "<= 2 s", TARGET_IDENTIFY_S),
            ("default run directory MB", lambda c: c["run_mb"], "<= 60 MB", TARGET_MB),
            ("default campaign warm s (best)", lambda c: c["warm_s"], "<= 4 s", TARGET_WARM_S),
            ("default campaign cold s", lambda c: c["cold_s"], "<= 15 s", TARGET_COLD_S)]
    for name, get, target, bound in rows:
        cells = []
        for c in columns:
            value = get(c)
            text = "-" if value is None else f"{value:.2f}"
            if value is not None and bound is not None:
                text += f" {verdict(value <= bound)}"
            cells.append(f"{text:>{width}}")
        print(f"{name:<44}" + "".join(cells) + f"   {target}")
    print("run-directory trials: " + ", ".join(f"{c['label']}: {c['run_format']}" for c in columns))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=3, help="runs per figure; the best counts (default 3)")
    parser.add_argument("--baseline", default="HEAD", help="git revision to compare with ('' for none)")
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
            columns.append(measure(old, tmp / "baseline", args.repeats, f"{args.baseline} (today)"))
            shutil.rmtree(tmp / "baseline")
        (tmp / "new").mkdir()
        columns.append(measure(ROOT, tmp / "new", args.repeats, "work tree"))
    report(columns)
    print(f"load average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
