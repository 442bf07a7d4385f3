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

Usage: python benchmarks/rolling_logs.py [--cases N [N ...]]
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
from ilcpmac.identify.rolling import RollingEstimate, estimate_rolling  # noqa: E402

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
    return {"corr": np.corrcoef(ours, tau)[0, 1], "corr_base": np.corrcoef(base, tau)[0, 1],
            "err": 100 * rms(ours - in_band) / np.ptp(tau), "err_base": 100 * rms(base - in_band) / np.ptp(tau),
            "ratio": rms(ours - in_band) / rms(e.table_std_nm()),
            "cogging": 100 * rms(e.table_nm(cogging_only=True) - cogging) / np.ptp(cogging),
            "cogging_base": 100 * rms(e.table_nm(e.baseline_nm, cogging_only=True) - cogging) / np.ptp(cogging),
            "orders": e.harmonics_nm.size, "inertia": e.inertia_source, "filter_s": e.filter_s}


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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", type=int, nargs="*", default=None, help="the simulated cases to run (indices)")
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
        print(f"{'#':>2} {'motor':<9} {'log':<50} {'H':>3} {'corr':>7} {'base':>7} {'err %':>6} {'base %':>7} "
              f"{'true/st':>7} {'cog %':>6} {'base %':>7}")
        for k in range(len(CASES)) if args.cases is None else args.cases:
            motor, options = CASES[k]
            case = work / f"case{k}"
            case.mkdir()
            r = simulated(motor, options, case)
            print(f"{k:>2} {motor:<9} {describe(options):<50} {r['orders']:>3} {r['corr']:7.4f} {r['corr_base']:7.4f} "
                  f"{r['err']:6.2f} {r['err_base']:7.2f} {r['ratio']:7.2f} {r['cogging']:6.2f} "
                  f"{r['cogging_base']:7.2f}", flush=True)


if __name__ == "__main__":
    main()
