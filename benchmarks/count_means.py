"""Count means against every line (docs/campaign.md, "Recorded resolution"): the seed bench's default campaign
recorded at every one of its 4096 lines and as 1024 means of 4, per seed, side by side: the worst true learned and
validation ripple (% pp of the mean torque), every point against its floor, the run directory's size and the wall
time of the campaign (one run each, alternately: the machine is shared; compare the ratios).

Usage: python benchmarks/count_means.py [--seeds N [N ...]] [--out DIR]
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import ilcpmac.api as ilc
import ilcpmac.campaign

#: the recorded counts compared: every line (the default) and means of 4
RECORDS = {"every line": None, "means of 4": 1024}


def _size_mb(folder: Path) -> float:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) / 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[2009, 11, 12, 13])
    parser.add_argument("--out", type=Path, default=None, help="where the runs go (default: a temp dir)")
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="count-means-"))
    print(f"{'record':<12}{'seed':>6}{'learned %':>11}{'valid. %':>10}{'learned / floor':>17}"
          f"{'valid. / floor':>16}{'MB':>7}{'wall s':>8}")
    for seed in args.seeds:
        for name, record in RECORDS.items():
            folder = out / f"{name.replace(' ', '-')}-{seed}"
            changes = {} if record is None else {"bench": {"record_counts_per_rev": record}}
            config = ilc.write_config(out / f"{name.replace(' ', '-')}.toml", changes)
            start = time.perf_counter()
            summary = ilcpmac.campaign.run(config, out=folder, seed=seed).summary
            wall = time.perf_counter() - start
            row = {}
            for learned in (True, False):
                points = [p for p in summary["points"] if p["learned"] == learned]
                ratios = [p["ripple_pp_true"] / p["floor_pp_true"] for p in points]
                row[learned] = (100 * max(p["ripple_pp_true"] for p in points),  # fractions of the mean torque
                                f"{min(ratios):.2f}-{max(ratios):.2f}")
            print(f"{name:<12}{seed:>6}{row[True][0]:>11.3f}{row[False][0]:>10.3f}{row[True][1]:>17}"
                  f"{row[False][1]:>16}{_size_mb(folder):>7.1f}{wall:>8.1f}")


if __name__ == "__main__":
    main()
