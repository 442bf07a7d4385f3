"""Benchmark of the offline path from a motor's logs to its firmware table (issue 24), against simulated truth.

For a speed-loop rolling log (``ilcpmac simulate --kind log``: 1 kHz, i_q, no torque sensor, 10 s at 0.5 Hz; at
one speed, and at 0.4 and 0.8 Hz together) and a standstill scan (``--kind scan``; scans with missing counts:
tests/test_standstill.py), run as a user would: ``simulate``, ``import``, ``identify`` (``--torque-source
encoder`` for the logs), then ``export`` as moteus lines, C (int16) and harmonics. It prints per path the RMS
error of the identified position torque (logs) or cogging (scans) against the truth, over the orders the
identification analyses and over the whole truth, and the largest error in standard errors; then the residual
ripple each export states.

Usage: python benchmarks/offline_path.py [--config CONFIG] [--seed N]
"""

from __future__ import annotations

import argparse
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
ILCPMAC = [sys.executable, "-m", "ilcpmac"]


def ilcpmac(*args: str) -> str:
    """Run ``ilcpmac ARGS``; its output (stdout and stderr); exit on failure."""
    done = subprocess.run([*ILCPMAC, *map(str, args)], capture_output=True, text=True)
    if done.returncode:
        sys.exit(f"ilcpmac {' '.join(map(str, args))} failed:\n{done.stdout}{done.stderr}")
    return done.stdout + done.stderr


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def band(table: np.ndarray, orders: np.ndarray) -> np.ndarray:
    """``table`` kept at ``orders`` only (its other harmonics removed)."""
    spectrum = np.fft.rfft(table)
    kept = np.zeros_like(spectrum)
    kept[orders] = spectrum[orders]
    return np.fft.irfft(kept, table.size)


def accuracy(result: dict, truth: dict, key: str) -> tuple[float, float, float]:
    """RMS error of the result's ``key`` table against the truth's, % of the truth's RMS, over the orders the
    result analyses and over the whole truth; and the largest per-count error in standard errors."""
    found = result[key]
    estimate, std = np.asarray(found["torque"]), np.asarray(found.get("std") or found.get("torque_std") or np.nan)
    true = np.asarray(truth[key]["torque"])
    nonzero = np.flatnonzero(np.abs(np.fft.rfft(estimate)) > 1e-12 * np.abs(np.fft.rfft(estimate)).max())
    in_band = band(true, nonzero[nonzero > 0])
    return (100 * rms(estimate - in_band) / rms(in_band), 100 * rms(estimate - true) / rms(true),
            float(np.max(np.abs(estimate - in_band) / std)) if np.all(np.isfinite(std)) else float("nan"))


def exports(result: Path, out: Path, torque_constant: float) -> dict[str, str]:
    """The residual line each export prints, by format."""
    lines = {}
    for fmt, extra in (("moteus", ["--torque-constant", torque_constant]), ("c", []),
                       ("harmonics", ["--torque-constant", torque_constant])):
        text = ilcpmac("export", result, "--format", fmt, "--out", out / fmt, *extra)
        (line,) = re.findall(r"residual ripple of the .*", " ".join(text.split()))
        lines[fmt] = line.split(": ", 1)[1]
    return lines


def log_path(config: Path, tmp: Path, speeds: list[float], seed: int) -> tuple[dict, dict, Path]:
    """Simulated logs at ``speeds`` imported into one bench and identified; the result, the truth, its file."""
    logs = []
    for speed in speeds:
        folder = tmp / f"log{speed:g}"
        ilcpmac("simulate", config, "--kind", "log", "--speed-hz", speed, "--seed", seed, "--out", folder)
        logs.append(folder)
    bench = tmp / f"bench-{'-'.join(f'{s:g}' for s in speeds)}"
    ilcpmac("import", *[f / "drive_log.csv" for f in logs], "--map", logs[0] / "mapping.toml", "--out", bench)
    result = tmp / f"{bench.name}.json"
    ilcpmac("identify", bench, "--torque-source", "encoder", "--output", result)
    return json.loads(result.read_text()), json.loads((logs[0] / "truth.json").read_text()), result


def scan_path(config: Path, tmp: Path, seed: int) -> tuple[dict, dict, Path]:
    """A simulated standstill scan, imported and identified; the result, the truth, its file."""
    folder = tmp / "scan"
    ilcpmac("simulate", config, "--kind", "scan", "--seed", seed, "--out", folder)
    ilcpmac("import", folder / "scan_log.csv", "--map", folder / "mapping.toml", "--out", tmp / "scanbench")
    result = tmp / "scan.json"
    ilcpmac("identify", tmp / "scanbench", "--output", result)
    return json.loads(result.read_text()), json.loads((folder / "truth.json").read_text()), result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", type=Path, default=ROOT / "src" / "ilcpmac" / "configs" / "seed-bench.toml")
    parser.add_argument("--seed", type=int, default=2009)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        rows, residuals = [], {}
        for name, (result, truth, path) in {
                "log, 0.5 Hz": log_path(args.config, tmp, [0.5], args.seed),
                "logs, 0.4 + 0.8 Hz": log_path(args.config, tmp, [0.4, 0.8], args.seed),
                "standstill scan": scan_path(args.config, tmp, args.seed)}.items():
            key = "position_torque" if result.get("position_torque") else "cogging"
            rows.append((name, key, *accuracy(result, truth, key)))
            k_t = truth.get("torque_constant_nm_per_a", 0.3)
            residuals[name] = exports(path, tmp / f"export-{len(residuals)}", k_t)
    print(f"\n{'path':<40} {'table':<16} {'RMS err, band':>14} {'RMS err, all':>13} {'max |err|/std':>14}")
    for name, key, in_band, whole, z in rows:
        print(f"{name:<40} {key:<16} {in_band:>12.3f} % {whole:>11.3f} % {z:>14.2f}")
    print("\nresidual ripple each export states (of the identified table, as its target samples it)")
    for name, lines in residuals.items():
        for fmt, line in lines.items():
            print(f"  {name:<40} {fmt:<10} {line}")


if __name__ == "__main__":
    main()
