"""Benchmark of ``ilcpmac sweep`` on a local Dask cluster (issue 14, items 1-3).

1. Speed-up: the same identification-only tasks of the seed bench (its 5 x 6 grid simulated, then
   ``identify_bench``) on a local cluster of 1 worker process and of 2, side by side, best of two each; the
   time runs from the first task submitted to the last result written (each cluster started and its workers
   warmed before). Target: 2 workers >= 1.7x faster than 1 on a 2-core machine.
2. Spread: identification-only tasks and whole campaigns (``ilcpmac run``'s) on draws around the seed bench:
   true inertia +-20 % and back-EMF constant +-10 % (uniform; the controller keeps the nominal), the current
   sensors' epsilon (5 % relative std), alpha (0.02 std per phase) and beta (0.1 A std per phase) and the
   torque sensor's delta (5 % relative std) drawn around the report's, magnets over 0-80 K at -0.1 %/K. It
   prints the percentile tables and every failure. Target: 99th-percentile final true ripple <= 0.2 % pp.

Usage: python benchmarks/sweep.py [--identify-tasks N] [--campaign-tasks N] [--speedup-tasks N] (0 skips a part)
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from ilcpmac.config import packaged_config  # noqa: E402
from ilcpmac.sweep.results import percentiles, read_results  # noqa: E402
from ilcpmac.sweep.runner import SweepRunner, local_client  # noqa: E402
from ilcpmac.sweep.spec import load_spec  # noqa: E402

SPREAD = """
[sweep]
kind = "{kind}"
tasks = {tasks}
seed = 14

[draw."simulator.mechanics.inertia_scale"]
distribution = "uniform"
low = 0.8
high = 1.2

[draw."simulator.winding.backemf_scale"]
distribution = "uniform"
low = 0.9
high = 1.1

[draw."simulator.current_sensors.epsilon"]
distribution = "normal"
relative_std = 0.05

[draw."simulator.current_sensors.alpha"]
distribution = "normal"
std = 0.02

[draw."simulator.current_sensors.beta_a"]
distribution = "normal"
std = 0.1

[draw."simulator.torque_sensor.delta"]
distribution = "normal"
relative_std = 0.05

[magnets]
temperature_rise_k = [0.0, 80.0]
coefficient_per_k = -0.001
"""


class Clock:
    """Sweep events that note when the first task is submitted (the workers warmed)."""

    def started(self, total: int, done: int) -> None:
        self.started_s = time.perf_counter()

    def finished(self, result) -> None:
        pass


def sweep(folder: Path, kind: str, tasks: int, client) -> tuple[float, object]:
    """Run a spread sweep of ``tasks`` tasks of ``kind`` on ``client``; its wall time from the first task submitted
    and its results table."""
    folder.mkdir(parents=True, exist_ok=True)
    spec_path = folder / f"{kind}.toml"
    spec_path.write_text(SPREAD.format(kind=kind, tasks=tasks))
    runner = SweepRunner(load_spec(spec_path, packaged_config("seed-bench.toml")), folder / kind)
    todo = runner.prepare(resume=False)
    clock = Clock()
    runner.run(client, todo, clock)
    return time.perf_counter() - clock.started_s, read_results(folder / kind)


def show(title: str, table) -> None:
    print(f"\n{title}")
    print(f"  {'figure':<32} {'tasks':>5} {'median':>10} {'95th':>10} {'99th':>10} {'worst':>10}")
    for p in percentiles(table):
        scale, unit = (100.0, " %") if "pp_true" in p.column else (1.0, "")
        print(f"  {p.column:<32} {p.count:>5} " + " ".join(f"{scale * v:>8.3g}{unit:2}" for v in
                                                         (p.median, p.p95, p.p99, p.worst)))
    for row in table.to_pylist():
        if row["status"] == "failed":
            print(f"  FAILED task {row['task']} (seed {row['seed']}): {row['reason']}")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--identify-tasks", type=int, default=200)
    parser.add_argument("--campaign-tasks", type=int, default=20)
    parser.add_argument("--speedup-tasks", type=int, default=8)
    args = parser.parse_args()
    print(f"cores: {os.cpu_count()}, load average before: {os.getloadavg()[0]:.2f}", flush=True)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        best = {}
        for workers in (1, 2) if args.speedup_tasks else ():
            client = local_client(workers)
            try:
                times = []
                for attempt in range(2):
                    seconds, table = sweep(tmp / f"speedup-{workers}-{attempt}", "identify", args.speedup_tasks,
                                           client)
                    times.append(seconds)
                best[workers] = min(times)
            finally:
                client.close()
                client.cluster.close()
            print(f"{args.speedup_tasks} identification tasks on {workers} worker(s): "
                  f"{', '.join(f'{t:.1f} s' for t in times)} (load average {os.getloadavg()[0]:.2f})", flush=True)
        if best:
            print(f"speed-up of 2 workers over 1: {best[1] / best[2]:.2f}x (target >= 1.7x)", flush=True)
        client = local_client(2)
        try:
            for kind, n in (("identify", args.identify_tasks), ("campaign", args.campaign_tasks)):
                if not n:
                    continue
                seconds, table = sweep(tmp / "spread", kind, n, client)
                show(f"{kind}: {n} tasks on 2 workers in {seconds:.0f} s", table)
                sys.stdout.flush()
        finally:
            client.close()
            client.cluster.close()
    print("\ntarget: 99th-percentile final_pp_true <= 0.2 % (campaign)")


if __name__ == "__main__":
    main()
