"""Benchmark of the offline path from a motor's logs to its firmware table (issue 24), against simulated truth.

For a speed-loop rolling log (``ilcpmac simulate --kind log``: 1 kHz, i_q, no torque sensor, 10 s at 0.5 Hz; at
one speed, and at 0.4 and 0.8 Hz together) and a standstill scan (``--kind scan``; scans with missing counts:
tests/test_standstill.py), run as a user would: ``simulate``, ``import``, ``identify`` (``--torque-source
encoder`` for the logs), then ``export`` as moteus lines, C (int16) and harmonics. It prints per path the RMS
error of the identified position torque (logs) or cogging (scans) against the truth, over the orders the
identification analyses and over the whole truth, and the largest error in standard errors; then the residual
ripple each export states.

Then the rolling logs (docs/rolling-logs.md), each through the CLI as well: benchmarks/rolling_logs.py's cases and
its floor's (the small actuator's 14-bit magnetic log at 0.5-6 Hz, 1000 and 100 rows/s), ``simulate --kind log``
(seed 1, 10 s), ``import`` with the mapping's ``[log] kind = "rolling"``, ``identify``, and ``export --format
moteus`` of the result and of the same result with the baseline's cogging (the q current averaged by position, a
drive's own anticogging: the result's per-harmonic baseline, diagnostics.rolling, at the cogging orders);
moteus_cogging.txt read back and sampled as the firmware does at every count, its RMS error against the true cogging
(% of its peak-to-peak) beside the floor of what the log can tell (benchmarks/rolling_logs.py's notes); with the
position torque's correlation with the truth and its RMS error over the identified orders (% of the truth's
peak-to-peak), ours and the baseline's, and the true error over the stated one. The two real ODrive logs (``import``
routes them to rolling folders): their holding current against holding map a, ours and the baseline's. The holding
maps: map b and map a each imported and identified alone and together, map b's correlation with map a and the
decomposition's orders 7 (the current sensors' offsets) and 14.

Usage: python benchmarks/offline_path.py [--config CONFIG] [--seed N] [--no-rolling]
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
sys.path.insert(0, str(ROOT / "benchmarks"))

import rolling_logs  # noqa: E402  (the rolling cases, their motors, the floor)

from ilcpmac.config import load_config  # noqa: E402

ODRIVE = rolling_logs.ODRIVE
#: entries of moteus's cogging table (moteus_cogging.txt: its scale line, then one int8 line each)
MOTEUS_ENTRIES = 1024


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


def cli_options(options: dict) -> list[str]:
    """A simulated log's options (`ilcpmac.sim.drive_log.LogPlan`'s) as ``ilcpmac simulate`` flags."""
    flags = []
    for key, value in options.items():
        flag = "--" + key.replace("_", "-")
        flags += [flag] if value is True else [] if value is False else [flag, str(value)]
    return flags


def moteus_applied_nm(folder: Path, counts_per_rev: int, torque_constant: float) -> np.ndarray:
    """moteus_cogging.txt read back: its 1024 int8 entries times its scale, sampled at each count as moteus's
    firmware samples them (entry min(size - 1, int(size p)), the next one modulo size, linear in between;
    tests/test_export_identification.py), in N m at ``torque_constant``: the feed-forward it applies."""
    lines = (folder / "moteus_cogging.txt").read_text().splitlines()
    scale = float(lines[0].rsplit(" ", 1)[1])
    values = np.array([int(line.rsplit(" ", 1)[1]) for line in lines[1:]], float) * scale
    if values.size != MOTEUS_ENTRIES:
        sys.exit(f"{folder / 'moteus_cogging.txt'}: {values.size} entries, not {MOTEUS_ENTRIES}")
    position = np.arange(counts_per_rev) / counts_per_rev
    left = np.minimum(values.size - 1, (values.size * position).astype(int))
    fraction = (position - left / values.size) * values.size
    return (values[left] + (values[(left + 1) % values.size] - values[left]) * fraction) * torque_constant


def table(harmonics: list[dict], prefix: str, counts_per_rev: int, multiple_of: int = 1) -> np.ndarray:
    """The table per count of a rolling result's per-harmonic ``prefix``_re / _im (diagnostics.rolling), the
    estimated orders that are multiples of ``multiple_of``, N m."""
    theta = 2 * np.pi * np.arange(counts_per_rev) / counts_per_rev
    return sum((np.real((h[f"{prefix}_re"] + 1j * h[f"{prefix}_im"]) * np.exp(1j * h["order"] * theta))
                for h in harmonics if h["choice"] != "aliased" and h["order"] % multiple_of == 0),
               np.zeros(counts_per_rev))


def rolling_path(motor: str, options: dict, tmp: Path) -> dict:
    """One rolling case through the CLI (module notes): its figures."""
    sim, folder, result = tmp / "sim", tmp / "rolling", tmp / "result.json"
    ilcpmac("simulate", rolling_logs.MOTORS[motor], "--kind", "log", "--seed", 1, "--out", sim,
            *cli_options({"duration_s": 10.0, **options}))
    mapping = sim / "rolling-mapping.toml"  # beside the backemf.csv it names
    mapping.write_text((sim / "mapping.toml").read_text().replace("[log]\n", '[log]\nkind = "rolling"\n'))
    ilcpmac("import", sim / "drive_log.csv", "--map", mapping, "--out", folder)
    ilcpmac("identify", folder, "--output", result)
    found, truth = json.loads(result.read_text()), json.loads((sim / "truth.json").read_text())
    tau, cogging = (np.asarray(truth[key]["torque"]) - np.mean(truth[key]["torque"])
                    for key in ("position_torque", "cogging"))
    cpr, k_t = tau.size, truth["torque_constant_nm_per_a"]
    rolling = found["diagnostics"]["rolling"]
    ours = np.asarray(found["position_torque"]["torque"])
    base = table(rolling["harmonics"], "baseline", cpr)
    top = len(rolling["harmonics"])
    in_band = band(tau, np.arange(1, top + 1))
    order = load_config(rolling_logs.MOTORS[motor]).simulated_model().winding.cogging_order
    applied = {}
    for name, cogging_nm in (("ours", found["cogging"] and found["cogging"]["torque"]),
                             ("baseline", table(rolling["harmonics"], "baseline", cpr, order).tolist())):
        feedforward = np.zeros(cpr)  # no cogging order identified: no table to apply
        if found["cogging"] is not None:
            path = tmp / f"{name}.json"
            path.write_text(json.dumps({**found, "cogging": {"count": list(range(cpr)), "torque": cogging_nm}}))
            ilcpmac("export", path, "--format", "moteus", "--torque-constant", k_t, "--out", tmp / f"moteus-{name}")
            feedforward = moteus_applied_nm(tmp / f"moteus-{name}", cpr, k_t)
        applied[name] = 100 * rms(-feedforward - cogging) / np.ptp(cogging)
    return {"H": top, "table": found["cogging"] is not None,
            "corr": np.corrcoef(ours, tau)[0, 1], "corr_base": np.corrcoef(base, tau)[0, 1],
            "err": 100 * rms(ours - in_band) / np.ptp(tau), "err_base": 100 * rms(base - in_band) / np.ptp(tau),
            "ratio": rms(ours - in_band) / rms(np.asarray(found["position_torque"]["std"])),
            "moteus": applied["ours"], "moteus_base": applied["baseline"], "floor": rolling_logs.floor(motor, options)}


def rolling_cases() -> list[tuple[str, dict]]:
    """benchmarks/rolling_logs.py's cases, then its floor's not among them."""
    cases = list(rolling_logs.CASES)
    seen = [(motor, {"speed_hz": 0.5, **options}) for motor, options in cases]
    for motor, options in rolling_logs.floor_cases():
        if (motor, {"speed_hz": 0.5, **options}) not in seen:
            cases.append((motor, options))
    return cases


def odrive_rows(tmp: Path) -> list[tuple[str, float, float, str]]:
    """Per real ODrive log, through the CLI: its name, our and the baseline's holding current against holding map
    a's (correlation), and what the identification found of J and the filter."""
    holding = np.load(ODRIVE / "holding_map_a.npy")
    held = np.arange(0, holding.size, 16)
    reference = holding[held] - holding[held].mean()
    rows = []
    for name in ("velocity_0.1revs_anticogging_off.npy", "velocity_0.1revs_anticogging_on.npy"):
        folder, result = tmp / name.removesuffix(".npy"), tmp / f"{name}.json"
        ilcpmac("import", ODRIVE / name, "--map", ODRIVE / "log-mapping.toml", "--out", folder)
        ilcpmac("identify", folder, "--output", result)
        found = json.loads(result.read_text())
        rolling = found["diagnostics"]["rolling"]
        k_t = rolling["torque_constant_nm_per_a"]
        ours = -np.asarray(found["position_torque"]["torque"])[held] / k_t
        base = -table(rolling["harmonics"], "baseline", holding.size)[held] / k_t
        said = f"J {rolling['inertia']}, filter {rolling['current_filter_s']:.3g} s ({rolling['current_filter']})"
        rows.append((name, float(np.corrcoef(ours, reference)[0, 1]), float(np.corrcoef(base, reference)[0, 1]),
                     said))
    return rows


def map_rows(tmp: Path) -> list[tuple[str, float, str, str]]:
    """Holding maps a, b and both, through the CLI: each one's correlation with map a over the measured counts,
    and the decomposition's orders 7 and 14 (A, with their standard errors)."""
    mapping = ODRIVE / "map-mapping.toml"
    found = {}
    for name, files in (("map a", ["a"]), ("map b", ["b"]), ("maps a + b", ["a", "b"])):
        folder, result = tmp / name.replace(" ", "").replace("+", "-"), tmp / f"{name.replace(' ', '')}.json"
        ilcpmac("import", *[ODRIVE / f"holding_map_{f}.npy" for f in files], "--map", mapping, "--out", folder)
        ilcpmac("identify", folder, "--output", result)
        found[name] = json.loads(result.read_text())
    measured = np.arange(0, len(found["map a"]["position_torque"]["torque"]), 16)
    reference = np.asarray(found["map a"]["position_torque"]["torque"])[measured]
    rows = []
    for name, decomposition in found.items():
        parts = decomposition["parts"]
        order = {h["order"]: h for part in ("offsets", "scale") for h in parts[part]["harmonics"]}
        rows.append((name, float(np.corrcoef(np.asarray(decomposition["position_torque"]["torque"])[measured],
                                             reference)[0, 1]),
                     *(f"{order[o]['amplitude']:.4f} ± {order[o]['std']:.4f}" for o in (7, 14))))
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", type=Path, default=ROOT / "src" / "ilcpmac" / "configs" / "seed-bench.toml")
    parser.add_argument("--seed", type=int, default=2009)
    parser.add_argument("--no-rolling", action="store_true", help="leave the rolling logs and the maps out")
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
    if args.no_rolling:
        return
    with tempfile.TemporaryDirectory() as tmp_name:
        tmp = Path(tmp_name)
        print("\nrolling logs through the CLI (10 s at 0.5 Hz unless said): the position torque against the truth "
              "(correlation; RMS error over the identified orders, % of the truth's peak-to-peak; true / stated "
              "error), and the moteus export's applied table against the true cogging (RMS error, % of its "
              "peak-to-peak) beside the floor; ours / the baseline's")
        print(f"{'motor':<9} {'log':<50} {'H':>3} {'corr':>7} {'base':>7} {'err %':>6} {'base %':>7} {'true/st':>7} "
              f"{'moteus %':>8} {'base %':>7} {'floor %':>7}")
        for k, (motor, options) in enumerate(rolling_cases()):
            r = rolling_path(motor, options, tmp / f"case{k}")
            print(f"{motor:<9} {rolling_logs.describe(options):<50} {r['H']:>3} {r['corr']:7.4f} "
                  f"{r['corr_base']:7.4f} {r['err']:6.2f} {r['err_base']:7.2f} {r['ratio']:7.2f} {r['moteus']:8.2f}"
                  f"{' ' if r['table'] else '*'}{r['moteus_base']:7.2f} {r['floor']:7.2f}", flush=True)
        print("* no cogging order below the rows' Nyquist order: no table to export (the error of none)")
        print("\nreal logs (ODrive v3, 0.1 rev/s) through the CLI: the holding current against holding map a "
              "(correlation)")
        print(f"{'log':<40} {'ours':>6} {'baseline':>9}  found")
        for name, ours, base, found in odrive_rows(tmp / "odrive"):
            print(f"{name:<40} {ours:6.3f} {base:9.3f}  {found}")
        print("\nholding maps through the CLI: against map a (correlation over its 512 counts), and the "
              "decomposition's orders 7 (the current sensors' offsets) and 14, A")
        print(f"{'maps':<12} {'vs map a':>9} {'order 7':>18} {'order 14':>18}")
        for name, correlation, seventh, fourteenth in map_rows(tmp / "maps"):
            print(f"{name:<12} {correlation:9.4f} {seventh:>18} {fourteenth:>18}")


if __name__ == "__main__":
    main()
