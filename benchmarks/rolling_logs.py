"""Benchmark of the rolling identification (issue 35, docs/rolling-logs.md): ours against the q current averaged by
position (the baseline, a drive's own anticogging), on the real ODrive logs and on simulated logs.

The real logs (tests/data/odrive-slow-velocity/): both velocity runs imported as they are (their mapping,
log-mapping.toml, routes them to a rolling folder) and identified; the holding current -tau_pos / K_t at the
512 counts map a holds, against map a with its own mean removed (correlation), ours beside the baseline's.

The simulated logs (``ilcpmac simulate --kind log`` of configs/seed-bench.toml and benchmarks/motors/' small
actuator and large servo): speed, position and current loops; 100 Hz, 1 kHz and 10 kHz; 12-, 14- and 20-bit
encoders, a magnetic one with its eccentricity and a magnet's orders; host jitter, latency and 1 ms stamps; a
position in wrapped counts; a soft loop that stick-slips; each imported as a rolling log and identified. Per case: the
correlation of the position torque with the truth (ours and the baseline's), its RMS error over the identified
orders in % of the truth's peak-to-peak (ours and the baseline's), the true RMS error over the stated one, and the
cogging band's RMS error in % of the true cogging's peak-to-peak (what a moteus export applies).

The wider grid (issue 35, item 1): a seeded sample of speeds 0.5-6 Hz x 100, 500, 1000 and 10000 rows/s x the
three motors x 12-, 14-, 20-bit and magnetic encoders x speed, position and current loops x host jitter 0-2 ms
with 1 ms stamps; its summary: the largest true / stated error and its quartiles, the per-harmonic z-scores
(true error over stated), the cases where ours falls back to the baseline (no correction taken), and every case
where ours is worse than the baseline in RMS error or correlation.

The floor (issue 35, item 3): the small actuator's 14-bit magnetic log of a speed loop, 10 s at 0.5-6 Hz, 1000 and
100 rows/s: the cogging band's RMS error (what a moteus export applies) against what the log can tell of it. Per
cogging order o, what the logged positions tell of J d2theta/dt2 there: sigma_o = J (o Omega)^2 |e_o|, e_o the
least-squares harmonic o of the position's true error at the rows (the drive's true angle, known in simulation:
the quantiser's pattern, locked to the rows' positions where they repeat from revolution to revolution); an order
the rows cannot tell from the one it folds onto (above the rows' Nyquist order, the rows' positions correlated
with the fold's) unresolved; the floor the RMS over the orders of what the Wiener estimate with the true signal's
size would leave, tau_o sigma_o / sqrt(tau_o^2 + sigma_o^2) (tau_o where unresolved).

Usage: python benchmarks/rolling_logs.py [--cases N [N ...]] [--grid N] [--no-floor]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))

from ilcpmac import api  # noqa: E402
from ilcpmac.bench.importer import read_mapping, write_rolling_folder  # noqa: E402
from ilcpmac.bench.rolling import read_rolling  # noqa: E402
from ilcpmac.config import load_config  # noqa: E402
from ilcpmac.identify.rolling import RollingEstimate, estimate_rolling  # noqa: E402
from ilcpmac.sim.drive_log import LogPlan, drive_log  # noqa: E402
from ilcpmac.sim.simulator import Simulator  # noqa: E402

SEED = ROOT / "configs" / "seed-bench.toml"
ODRIVE = ROOT / "tests" / "data" / "odrive-slow-velocity"

#: the motors: the seed bench and benchmarks/motors/'s (a small actuator: 7 pole pairs, 12 slots, J 1e-4 kg m^2;
#: a large servo: 4 pole pairs, 36 slots, J 0.05 kg m^2)
MOTORS = {"seed": SEED, "actuator": ROOT / "benchmarks" / "motors" / "small-actuator.toml",
          "servo": ROOT / "benchmarks" / "motors" / "large-servo.toml"}
#: a 14-bit magnetic encoder's error profile: 0.1 count of eccentricity and a magnet's second and fourth orders
MAGNETIC = {"encoder_bits": 14, "encoder_eccentricity_counts": 0.1, "encoder_harmonics": "2:0.3,4:0.1:0.5"}

#: (motor, log options): 10 s at 0.5 Hz unless the options say otherwise
CASES = [
    ("seed", {"rate_hz": 1000.0, "loop": "speed", "encoder_bits": 20}),
    ("seed", {"rate_hz": 1000.0, "loop": "speed", "encoder_bits": 14}),
    ("seed", {"rate_hz": 1000.0, "loop": "speed", "encoder_bits": 12}),
    ("seed", {"rate_hz": 10000.0, "loop": "speed", "encoder_bits": 14}),
    ("seed", {"rate_hz": 100.0, "loop": "speed", "encoder_bits": 14}),
    ("seed", {"rate_hz": 1000.0, "loop": "position", "encoder_bits": 14}),
    ("seed", {"rate_hz": 1000.0, "loop": "current", "encoder_bits": 14}),
    ("seed", {"rate_hz": 1000.0, "loop": "speed", "encoder_bits": 14, "jitter_s": 4e-4, "stamp_s": 1e-3}),
    ("seed", {"rate_hz": 1000.0, "loop": "speed", "encoder_bits": 14, "position_unit": "counts",
              "position_wrap": True}),
    ("seed", {"rate_hz": 500.0, "loop": "speed", "encoder_bits": 16, "speed_hz": 0.1, "speed_bandwidth_hz": 1.0,
              "duration_s": 30.0}),
    ("actuator", {"rate_hz": 1000.0, "loop": "speed", "speed_hz": 4.0, **MAGNETIC}),
    ("actuator", {"rate_hz": 1000.0, "loop": "speed", **MAGNETIC}),
    ("actuator", {"rate_hz": 100.0, "loop": "speed", **MAGNETIC}),
    ("actuator", {"rate_hz": 10000.0, "loop": "speed", "speed_hz": 4.0, "encoder_bits": 12}),
    ("actuator", {"rate_hz": 1000.0, "loop": "position", **MAGNETIC}),
    ("actuator", {"rate_hz": 1000.0, "loop": "current", **MAGNETIC}),
    ("actuator", {"rate_hz": 500.0, "loop": "speed", "jitter_s": 1e-3, "latency_s": 5e-4, "stamp_s": 1e-3,
                  **MAGNETIC}),
    ("servo", {"rate_hz": 1000.0, "loop": "speed", "encoder_bits": 16}),
    ("servo", {"rate_hz": 100.0, "loop": "speed", "encoder_bits": 12}),
    ("servo", {"rate_hz": 1000.0, "loop": "position", "encoder_bits": 20, "jitter_s": 2e-4}),
]


#: the wider grid's axes (module notes), sampled with this seed
GRID_SPEEDS_HZ = (0.5, 1.0, 2.0, 3.0, 4.0, 6.0)
GRID_RATES_HZ = (100.0, 500.0, 1000.0, 10000.0)
GRID_ENCODERS = {"12-bit": {"encoder_bits": 12}, "14-bit": {"encoder_bits": 14}, "20-bit": {"encoder_bits": 20},
                 "magnetic": MAGNETIC}
GRID_LOOPS = ("speed", "speed", "position", "current")
GRID_JITTERS_S = (0.0, 0.0, 5e-4, 1e-3, 2e-3)
GRID_SEED = 35
#: the floor's cases: the small actuator's magnetic log of a speed loop
FLOOR_SPEEDS_HZ = (0.5, 1.0, 2.0, 3.0, 4.0, 6.0)
FLOOR_RATES_HZ = (1000.0, 100.0)
#: an order o the rows cannot tell from the one it folds onto, o - k R (R rows a revolution): the mean of
#: e^{j k R theta} over the rows above this
UNRESOLVED_CORRELATION = 0.5


def grid(n: int, seed: int = GRID_SEED) -> list[tuple[str, dict]]:
    """``n`` cases of the wider grid (module notes), the motors in turn, the rest drawn with ``seed``."""
    rng = np.random.default_rng(seed)
    cases = []
    for k in range(n):
        options = {"rate_hz": float(rng.choice(GRID_RATES_HZ)), "speed_hz": float(rng.choice(GRID_SPEEDS_HZ)),
                   "loop": str(rng.choice(GRID_LOOPS)), **GRID_ENCODERS[str(rng.choice(list(GRID_ENCODERS)))]}
        jitter = float(rng.choice(GRID_JITTERS_S))
        cases.append((list(MOTORS)[k % 3], {**options, **({"jitter_s": jitter, "stamp_s": 1e-3} if jitter else {})}))
    return cases


def floor_cases() -> list[tuple[str, dict]]:
    """The floor's cases (module notes)."""
    return [("actuator", {"rate_hz": rate, "loop": "speed", "speed_hz": speed, **MAGNETIC})
            for rate in FLOOR_RATES_HZ for speed in FLOOR_SPEEDS_HZ]


def floor(motor: str, options: dict) -> float:
    """The floor of a case's cogging band (module notes), % of the true cogging's peak-to-peak: the drive's log
    simulated again (seed 1, 10 s unless said) for its true angle at the rows."""
    config = load_config(MOTORS[motor])
    simulator = Simulator(config.simulated_model())
    plan = LogPlan(seed=1, **{"duration_s": 10.0, **options})
    log = drive_log(simulator, plan)
    reading = log.columns["position"]
    if plan.position_unit == "counts":
        reading = reading * 2 * np.pi / 2**plan.encoder_bits
    time, error = log.columns["time"], np.mod(reading - log.angle_rad + np.pi, 2 * np.pi) - np.pi
    cogging = np.asarray(log.truth["cogging"]["torque"])
    harmonics = 2 * np.fft.rfft(cogging - cogging.mean()) / cogging.size
    rows_per_rev = plan.rate_hz / plan.speed_hz
    order = simulator.model.winding.cogging_order
    left = []
    for o in (order, 2 * order):
        design = np.column_stack([np.ones_like(time), time - time.mean(), np.cos(o * reading), np.sin(o * reading)])
        e_o = np.linalg.lstsq(design, error, rcond=None)[0][2:]
        sigma = log.truth["inertia_kgm2"] * (o * 2 * np.pi * plan.speed_hz) ** 2 * float(np.hypot(*e_o))
        wraps = round(o / rows_per_rev) * rows_per_rev  # e^{j o theta} is e^{j (o - wraps) theta} on locked rows
        resolved = o < rows_per_rev / 2 or abs(np.mean(np.exp(1j * wraps * reading))) < UNRESOLVED_CORRELATION
        tau = abs(harmonics[o])
        left.append(tau * sigma / np.hypot(tau, sigma) if resolved else tau)
    return 100 * float(np.sqrt(np.sum(np.square(left)) / 2)) / float(np.ptp(cogging))


def rms(x: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def identified(log: Path, mapping_file: Path, out: Path) -> RollingEstimate:
    """``log`` imported as a rolling log (its mapping with [log] kind = "rolling") and identified."""
    mapping = read_mapping(mapping_file)
    mapping = dataclasses.replace(mapping, layout=dataclasses.replace(mapping.layout, kind="rolling"))
    write_rolling_folder([log], mapping, out)
    return estimate_rolling(read_rolling(out))


def simulated(motor: str, options: dict, work: Path) -> dict:
    """One simulated case's figures (module notes)."""
    sim = work / "sim"
    api.simulate_log(MOTORS[motor], sim, seed=1, **{"duration_s": 10.0, **options})
    e = identified(sim / "drive_log.csv", sim / "mapping.toml", work / "rolling")
    truth = json.loads((sim / "truth.json").read_text())
    tau = np.asarray(truth["position_torque"]["torque"])
    tau = tau - tau.mean()
    cogging = np.asarray(truth["cogging"]["torque"])
    cogging = cogging - cogging.mean()
    n = tau.size
    spectrum = np.fft.rfft(tau)
    spectrum[e.harmonics_nm.size + 1:] = 0.0
    in_band = np.fft.irfft(spectrum, n=n)  # the truth over the orders identified
    ours, base = e.table_nm(), e.table_nm(e.baseline_nm)
    true_h = 2 * np.fft.rfft(tau)[1:e.harmonics_nm.size + 1] / n
    kept = e.estimated
    z = np.abs(e.harmonics_nm - true_h)[kept] / np.maximum(np.sqrt(e.variance_nm2[kept]), 1e-300)
    return {"corr": np.corrcoef(ours, tau)[0, 1], "corr_base": np.corrcoef(base, tau)[0, 1],
            "err": 100 * rms(ours - in_band) / np.ptp(tau), "err_base": 100 * rms(base - in_band) / np.ptp(tau),
            "ratio": rms(ours - in_band) / rms(e.table_std_nm()), "z": z,
            "cogging": 100 * rms(e.table_nm(cogging_only=True) - cogging) / np.ptp(cogging),
            "cogging_base": 100 * rms(e.table_nm(e.baseline_nm, cogging_only=True) - cogging) / np.ptp(cogging),
            "orders": e.harmonics_nm.size, "inertia": e.inertia_source, "filter_s": e.filter_s,
            "fallback": not np.any(e.weight > 0)}


def odrive(work: Path) -> list[tuple[str, float, float, RollingEstimate]]:
    """Per ODrive log: its name, our and the baseline's correlation with holding map a, and the estimate."""
    holding = np.load(ODRIVE / "holding_map_a.npy")
    held = np.arange(0, holding.size, 16)
    reference = holding[held] - holding[held].mean()
    out = []
    for name in ("velocity_0.1revs_anticogging_off.npy", "velocity_0.1revs_anticogging_on.npy"):
        e = identified(ODRIVE / name, ODRIVE / "log-mapping.toml", work / name.removesuffix(".npy"))
        k_t = e.torque_constant_nm_per_a
        ours, base = (-e.table_nm(h)[held] / k_t for h in (e.harmonics_nm, e.baseline_nm))
        out.append((name, float(np.corrcoef(ours, reference)[0, 1]), float(np.corrcoef(base, reference)[0, 1]), e))
    return out


def describe(options: dict) -> str:
    """A case's log in a few words."""
    extra = {"speed_hz": ("{:g} Hz", 1), "jitter_s": ("jitter {:g} ms", 1e3), "stamp_s": ("stamps {:g} ms", 1e3),
             "latency_s": ("latency {:g} ms", 1e3), "speed_bandwidth_hz": ("loop {:g} Hz", 1)}
    words = [options["loop"], f"{options['rate_hz']:g}/s", f"{options['encoder_bits']}-bit"]
    words += ["magnetic"] if options.get("encoder_harmonics") else []
    words += ["counts wrapped"] if options.get("position_wrap") else []
    words += [text.format(options[key] * scale) for key, (text, scale) in extra.items() if options.get(key)]
    return " ".join(words)


HEADER = (f"{'#':>2} {'motor':<9} {'log':<50} {'H':>3} {'corr':>7} {'base':>7} {'err %':>6} {'base %':>7} "
          f"{'true/st':>7} {'cog %':>6} {'base %':>7}")


def row(k: int, motor: str, options: dict, r: dict) -> str:
    """A case's line under `HEADER`."""
    return (f"{k:>2} {motor:<9} {describe(options):<50} {r['orders']:>3} {r['corr']:7.4f} {r['corr_base']:7.4f} "
            f"{r['err']:6.2f} {r['err_base']:7.2f} {r['ratio']:7.2f} {r['cogging']:6.2f} {r['cogging_base']:7.2f}")


def run_cases(cases: list[tuple[str, dict]], work: Path) -> list[dict]:
    """Each case simulated and identified (`simulated`), its line printed; the figures."""
    print(HEADER)
    results = []
    for k, (motor, options) in enumerate(cases):
        case = work / f"case{k}"
        case.mkdir(parents=True)
        results.append(simulated(motor, options, case))
        print(row(k, motor, options, results[-1]), flush=True)
    return results


def grid_summary(results: list[dict]) -> list[str]:
    """The wider grid's summary lines (module notes)."""
    ratios = np.array([r["ratio"] for r in results])
    z = np.concatenate([r["z"] for r in results])
    worse_rms = [k for k, r in enumerate(results) if r["err"] > r["err_base"]]
    worse_corr = [k for k, r in enumerate(results) if r["corr"] < r["corr_base"]]
    fallback = [k for k, r in enumerate(results) if r["fallback"]]
    q = np.percentile(ratios, [25, 50, 75])
    zq = np.percentile(z, [50, 90, 99])
    return [f"true / stated error: at most {ratios.max():.2f} (quartiles {q[0]:.2f}, {q[1]:.2f}, {q[2]:.2f}); "
            f"{int(np.sum(ratios > 2))} case(s) above 2",
            f"per harmonic, true error / stated ({z.size} harmonics): median {zq[0]:.2f}, 90 % {zq[1]:.2f}, 99 % "
            f"{zq[2]:.2f}, largest {z.max():.2f}; {int(np.sum(z > 3))} above 3",
            f"ours falls back to the baseline (no correction clears its errors) in {len(fallback)} of {len(results)} "
            "cases",
            "ours worse than the baseline in RMS error: " + (", ".join(f"#{k} ({results[k]['err']:.2f} against "
                                                                      f"{results[k]['err_base']:.2f} %)"
                                                                      for k in worse_rms) or "none"),
            "ours correlating worse than the baseline: " + (", ".join(f"#{k} ({results[k]['corr']:.3f} against "
                                                                     f"{results[k]['corr_base']:.3f})"
                                                                     for k in worse_corr) or "none")]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, nargs="*", default=None, help="the simulated cases to run (indices)")
    parser.add_argument("--grid", type=int, default=48, help="cases of the wider grid (0: none)")
    parser.add_argument("--no-floor", action="store_true", help="leave the floor's table out")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as folder:
        work = Path(folder)
        print("real logs (ODrive v3, 0.1 rev/s): the holding current against holding map a")
        print(f"{'log':<40} {'ours':>6} {'baseline':>9}  J, filter")
        for name, ours, base, e in odrive(work / "odrive"):
            print(f"{name:<40} {ours:6.3f} {base:9.3f}  J {e.inertia_source}, filter {e.filter_s:.3g} s "
                  f"({e.filter_source})")
        print()
        print("simulated logs (10 s at 0.5 Hz unless said): position torque against the truth")
        chosen = range(len(CASES)) if args.cases is None else args.cases
        print(HEADER)
        for k in chosen:
            motor, options = CASES[k]
            case = work / f"case{k}"
            case.mkdir()
            print(row(k, motor, options, simulated(motor, options, case)), flush=True)
        if args.grid:
            print()
            print(f"the wider grid ({args.grid} cases drawn with seed {GRID_SEED}, 10 s each)")
            for line in grid_summary(run_cases(grid(args.grid), work / "grid")):
                print(line)
        if not args.no_floor:
            print()
            print("the floor: the small actuator's 14-bit magnetic log of a speed loop, 10 s: the cogging band's RMS "
                  "error, % of the cogging's peak-to-peak (what a moteus export applies)")
            print(f"{'rows/s':>7} {'Hz':>4} {'H':>4} {'ours':>6} {'baseline':>9} {'floor':>6}")
            for k, (motor, options) in enumerate(floor_cases()):
                case = work / f"floor{k}"
                case.mkdir()
                r = simulated(motor, options, case)
                print(f"{options['rate_hz']:7g} {options['speed_hz']:4g} {r['orders']:4d} {r['cogging']:6.2f} "
                      f"{r['cogging_base']:9.2f} {floor(motor, options):6.2f}", flush=True)


if __name__ == "__main__":
    main()
