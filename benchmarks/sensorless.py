"""Campaigns without a torque sensor on the seed bench, side by side with the sensor-based one (issue 12).

    python benchmarks/sensorless.py [--encoder-error] [--sources sensor,encoder,both] [--identify-on-sensor]
        [--no-identification]

1. The seed bench's grid, with an encoder error, identified on the sensor and on the encoder's time stamps
(benchmarks/sensorless_identification.py; ``--no-identification`` leaves it out): targets cogging within 3 % RMS,
eps within 2 % given J, the encoder error's once-per-revolution amplitude within 10 %.

2. Runs the seed campaign (configs/seed-bench.toml, validation left out) three times in one process, with
[campaign] torque_source = "sensor", "encoder" (the torque sensor removed: the campaign never reads it) and
"both", and prints per learned operating point the true ripple before (the uncompensated trial) and after
(the last trial), the reduction factor, and the trials used there (compensation and learning). Targets:

- "encoder": true ripple >= 100x below uncompensated at every learned point, in <= 15 trials per point;
- "both": no worse than "sensor" alone, in the pp and in the RMS less the part the trial's noise leaves in its
  average (`RippleFigures.rms_repeatable`): near that floor the pp of one trial scatters by about +-12 % from
  trial to trial (1 N m, 0.5 Hz).

Then the floor the time stamps imply (eq. 3 of src/ilcpmac/signals/encoder_torque.py, `quantisation_variance_nm2`,
the RMS over harmonics 1..H of the last trial's revolutions and speed, b included) against the true RMS ripple
the encoder campaign reached. ``--encoder-error`` gives the simulated encoder [simulator.encoder]
eccentricity_counts = 0.05 and line_std_counts = 0.01 (the identification must then identify it: needs
``identify_bench(..., torque_source=...)`` and ``IdentificationResult.encoder_error_counts``).
``--identify-on-sensor`` identifies every campaign on the sensor, with no encoder error: the learning alone.
"""

from __future__ import annotations

import argparse
import inspect
import re
import tempfile
import time
from pathlib import Path

import numpy as np
from sensorless_identification import identification_report

from ilcpmac.backends.registry import BackendSetup, build_backend
from ilcpmac.campaign.plan import records_at
from ilcpmac.campaign.record import TrialRecord
from ilcpmac.campaign.rundir import RunDir
from ilcpmac.campaign.runner import CampaignRunner
from ilcpmac.config import load_config
from ilcpmac.core.torque_source import TorqueSource
from ilcpmac.identify import identify_bench
from ilcpmac.signals.encoder_torque import brake_viscous_nm_s, quantisation_variance_nm2

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "configs" / "seed-bench.toml"
SOURCES = ("sensor", "encoder", "both")
#: identify_bench takes the torque source once the encoder identification is in the tree
IDENTIFY_TAKES_SOURCE = "torque_source" in inspect.signature(identify_bench).parameters


class Quiet:
    def trial(self, record, records) -> None:
        pass

    def message(self, text: str) -> None:
        pass

    def progress(self, fraction: float) -> None:
        pass


def identify(bench, torque_source: TorqueSource | None = None):
    """`identify_bench` on ``torque_source`` where it takes one, else on the sensor."""
    if IDENTIFY_TAKES_SOURCE:
        return identify_bench(bench, torque_source=torque_source)
    return identify_bench(bench)


def identify_on_sensor(bench, torque_source: TorqueSource | None = None):
    """`identify_bench` on the sensor, whatever the campaign's source."""
    return identify_bench(bench)


def config_text(source: str, encoder_error: bool) -> str:
    """The seed config with ``torque_source``, no validation and, with ``encoder_error``, a real encoder's errors."""
    text = re.sub(r"(?m)^torque_source = .*$", "", CONFIG.read_text())  # the seed config's own: replaced
    text = text.replace("[campaign]\n", f"[campaign]\ntorque_source = {source!r}\n")
    text = re.sub(r"(?m)^validate_(torques_nm|speeds_hz) = \[[^]]*\]", r"validate_\1 = []", text)
    if encoder_error:
        text = re.sub(r"(?m)^eccentricity_counts = [0-9.]+", "eccentricity_counts = 0.05", text)
        text = re.sub(r"(?m)^line_std_counts = [0-9.]+", "line_std_counts = 0.01", text)
    return text


def run(source: str, encoder_error: bool, out: Path, on_sensor: bool) -> tuple[float, CampaignRunner]:
    path = out / f"{source}.toml"
    path.write_text(config_text(source, encoder_error))
    cfg = load_config(path)
    backend = build_backend("sim", BackendSetup(cfg, None))
    run_dir = RunDir.create(out / source, backend.describe(), path.read_text())
    runner = CampaignRunner(cfg, backend, run_dir, cfg.grid.seed, identify_on_sensor if on_sensor else identify,
                            Quiet())
    start = time.perf_counter()
    runner.run()
    return time.perf_counter() - start, runner


def point_rows(runner: CampaignRunner) -> dict:
    """Per learned point: (true pp before, true pp after, reduction, trials, last record)."""
    rows = {}
    for point in runner.plan.learned:
        before = records_at(runner.records, point, ("baseline",))[0]
        done = records_at(runner.records, point, ("compensate", "learn"))
        after = done[-1]
        rows[point] = (before.true.pp, after.true.pp, before.true.pp / after.true.pp, len(done), after)
    return rows


def floor_rms(runner: CampaignRunner, record: TrialRecord) -> float:
    """The RMS ripple (fraction of the mean torque) eq. 3 leaves over harmonics 1..H at the record's point."""
    cfg, motor = runner.config, runner.description.motor
    point = (record.torque_setpoint_nm, record.speed_setpoint_hz)
    measurement = runner.measurement
    h = np.arange(1, cfg.campaign.ripple_harmonics + 1)
    request = runner.plan.base_request(point, 0)
    mean_nm = measurement.mean_torque_nm(request)
    b = brake_viscous_nm_s(mean_nm, 2.0 * np.pi * point[1])
    variance = quantisation_variance_nm2(h, motor.counts_per_rev, measurement.timer_resolution_s,
                                         motor.inertia_kgm2, point[1], cfg.trial_revolutions(point), b)
    return float(np.sqrt(np.sum(variance) / 2.0)) / mean_nm


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--encoder-error", action="store_true", help="a simulated encoder with graduation errors")
    parser.add_argument("--sources", default=",".join(SOURCES), help="the campaigns run, comma-separated")
    parser.add_argument("--identify-on-sensor", action="store_true", help="identify every campaign on the sensor")
    parser.add_argument("--no-identification", action="store_true",
                        help="leave out part 1 (the identification on the sensor and on the encoder)")
    args = parser.parse_args()
    if not args.no_identification:
        print("1. identification of the seed bench's grid, with an encoder error of 0.05 counts once per revolution "
              "and 0.01 counts per line (benchmarks/sensorless_identification.py)")
        print("\n".join(identification_report(0.05, 0.01)))
        print("\n2. campaigns")
    sources = [s for s in SOURCES if s in args.sources.split(",")]
    where = ("on the campaign's torque source" if IDENTIFY_TAKES_SOURCE and not args.identify_on_sensor
             else "on the sensor, no encoder error")
    encoder = "with graduation errors (0.05 eccentricity, 0.01 lines)" if args.encoder_error else "perfect"
    print(f"identification: {where}; encoder {encoder}")
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for source in sources:
            elapsed, runner = run(source, args.encoder_error, Path(tmp), args.identify_on_sensor)
            results[source] = (elapsed, runner, point_rows(runner))
            print(f"{source}: {len(runner.records)} trials in {elapsed:.1f} s")
    print("\ntrue ripple pp, % of mean torque: before -> after (reduction, trials at the point)")
    print(f"{'N m':>4} {'Hz':>4} | " + " | ".join(f"{s:^30}" for s in sources))
    for point in results[sources[0]][1].plan.learned:
        cells = []
        for source in sources:
            before, after, factor, trials, _ = results[source][2][point]
            cells.append(f"{100 * before:6.1f} -> {100 * after:7.4f} ({factor:6.0f}x, {trials:2d})")
        print(f"{point[0]:4g} {point[1]:4g} | " + " | ".join(cells))
    if "encoder" in results:
        encoder_targets(results["encoder"][1], results["encoder"][2])
    print("\ntrue RMS ripple after, % of mean torque: repeatable / the non-repeatable part left in the average "
          "(the current sensors' noise, revolution-to-revolution scatter)")
    print(f"{'N m':>4} {'Hz':>4} | " + " | ".join(f"{s:^17}" for s in sources))
    for point in results[sources[0]][1].plan.learned:
        cells = []
        for source in sources:
            true = results[source][2][point][4].true
            cells.append(f"{100 * true.rms_repeatable:7.4f} / {100 * noise_rms(true):6.4f}")
        print(f"{point[0]:4g} {point[1]:4g} | " + " | ".join(cells))
    if "both" in results and "sensor" in results:
        rows, sensor = results["both"][2], results["sensor"][2]
        for name, worse in (("pp", [p for p in rows if rows[p][1] > sensor[p][1]]),
                            ("repeatable RMS", [p for p in rows if rows[p][4].true.rms_repeatable
                                                > sensor[p][4].true.rms_repeatable])):
            print(f"both: {name} worse than the sensor alone at {len(worse)} of {len(rows)} points"
                  + (f" ({', '.join(f'{p[0]:g} N m {p[1]:g} Hz' for p in worse)})" if worse else ""))


def noise_rms(figures) -> float:
    """The RMS the non-repeatable part leaves in a trial's average (fraction of the mean torque): what
    `RippleFigures.rms_repeatable` took out of ``rms``."""
    return float(np.sqrt(max(figures.rms**2 - figures.rms_repeatable**2, 0.0)))


def encoder_targets(enc_runner: CampaignRunner, enc_rows: dict) -> None:
    """The encoder campaign against its targets, and the true RMS ripple it reached against eq. 3's floor."""
    worst = min(r[2] for r in enc_rows.values())
    most = max(r[3] for r in enc_rows.values())
    print(f"\nencoder: worst reduction {worst:.0f}x (target >= 100x): {'met' if worst >= 100 else 'NOT met'}; "
          f"most trials per point {most} (target <= 15): {'met' if most <= 15 else 'NOT met'}")
    print("encoder: true RMS ripple reached vs the timer's floor (eq. 3), % of mean torque")
    for point, (_, _, _, _, last) in enc_rows.items():
        floor = floor_rms(enc_runner, last)
        print(f"{point[0]:4g} N m {point[1]:4g} Hz: reached {100 * last.true.rms:.5f}, floor {100 * floor:.5f} "
              f"({last.true.rms / floor:.2g}x the floor)")


if __name__ == "__main__":
    main()
