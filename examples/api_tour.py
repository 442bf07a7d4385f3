"""The Python API end to end (docs/api.md) on a small simulated campaign, in a few seconds.

    python examples/api_tour.py [WORK_DIR]

With ``ilcpmac.api`` alone: writes a small config, runs a campaign on the
simulator, loads its results and a trial's spectrum, simulates and identifies a
bench, imports a simulated drive log and exports the compensation (C) and the
cogging (CSV, moteus), all into WORK_DIR (default: a temporary folder, removed
at the end), printing a few figures of each step.
"""

import sys
import tempfile
from pathlib import Path

import numpy as np

import ilcpmac.api as ilc

#: the seed bench shrunk (as tests/campaign_helpers.py SMALL_CAMPAIGN): 1024 counts, a 2 x 2 grid, two learned
#: points at one speed, one validated point, few trials
SMALL = {
    "bench": {"counts_per_rev": 1024},
    "excitation": {"harmonics": 100},
    "trials": {"torque_setpoints_nm": [2.0, 4.0], "speed_setpoints_hz": [0.6, 0.9], "revolutions": 3},
    "campaign": {"learn_torques_nm": [2.0, 4.0], "learn_speeds_hz": [0.9], "learn_revolutions": [6],
                 "learn_trials": 4, "ripple_harmonics": 100, "validate_torques_nm": [3.0],
                 "validate_speeds_hz": [0.9], "validate_revolutions": 6, "torque_source": "sensor"},
    "stages": {"ilc": {"learning_gain": 1.0, "q_cutoff_harmonic": 100, "estimation": "kalman"}},
}


def small_config(folder: Path) -> Path:
    """The packaged seed-bench.toml with the `SMALL` tables merged in, written to ``folder``: its path."""
    return ilc.write_config(folder / "small.toml", SMALL)


def tour(work: Path) -> None:
    config_path = small_config(work)

    # 1. a campaign on the simulator: identify, learn, validate (on_event=ilc.print_event shows it live)
    run = ilc.run(config_path, out=work / "run", seed=3)
    print(f"campaign: {len(run.records)} trials in {run.path}")

    # 2. its results: every point's final ripple against its noise floor (% of the mean torque), the motor time
    run = ilc.load_run(work / "run")  # the same, read back from the run directory
    for p in run.points:
        print(f"  {p.torque_setpoint_nm:g} N m, {p.speed_setpoint_hz:g} Hz ({'learned' if p.learned else 'validated'}):"
              f" ripple {p.uncompensated_pp_percent:.3g} % pp -> {p.ripple_pp_percent:.3g} % pp, "
              f"floor {p.floor_pp_percent:.3g} %")
    phases = ", ".join(f"{phase} {t:.1f} s" for phase, t in run.motor_time_s.items())
    print(f"motor time: {run.motor_time_total_s:.1f} s ({phases})")

    # 3. a trial as columns (float64 arrays, one value per encoder count) and the spectrum of its torque
    trial = run.trial(1)
    count, torque_nm = trial.columns["count"], trial.columns["torque"]
    print(f"trial 1: {count.size} samples, columns {', '.join(trial.columns)}")
    counts_per_rev = SMALL["bench"]["counts_per_rev"]
    revolutions = count.size // counts_per_rev
    ripple_nm = torque_nm[:revolutions * counts_per_rev] - torque_nm.mean()
    amplitude_nm = 2 * np.abs(np.fft.rfft(ripple_nm)) / ripple_nm.size  # per revolution harmonic k at k * revolutions
    per_rev = amplitude_nm[::revolutions][1:]
    top = np.argsort(per_rev)[::-1][:3] + 1
    print("  largest revolution harmonics: " + ", ".join(f"{k}x {1000 * per_rev[k - 1]:.3g} mN m" for k in top))
    # with pandas installed, the same as a DataFrame: run.trial_frame(1)

    # 4. a simulated bench, identified against its truth
    simulated = ilc.simulate_bench(config_path, work / "bench", seed=3)
    identification = ilc.identify(simulated.folder, output=work / "result.json")
    truth = simulated.truth
    print(f"identified: epsilon {identification.epsilon:.4f} (truth {truth.epsilon:.4f}), "
          f"delta {identification.delta:.4f} (truth {truth.delta:.4f})")

    # 5. a drive log (here simulated, as ilcpmac simulate --kind log), imported and identified
    log = ilc.simulate_log(config_path, work / "log", seed=3, duration_s=10.0)
    (imported, *_) = ilc.import_logs(log.log, log.mapping, work / "imported")
    lap = imported.laps[0]
    print(f"imported: {len(imported.bench.trials)} trial(s), interpolation error {lap.error.current_a:.3g} A")
    from_log = ilc.identify(imported.folder)
    print(f"from the log: position torque {np.ptp(from_log.position_torque_nm):.3g} N m pp")

    # 6. exports: the campaign's compensation as C, the identification's cogging as CSV and for moteus
    exported = ilc.export(run.path, "c", work / "firmware")
    print(f"exported {', '.join(p.name for p in exported.files)}: {exported.residual.rms_nm:.3g} N m RMS residual")
    cogging = ilc.export(work / "result.json", "csv", work / "cogging")
    print(f"exported {', '.join(p.name for p in cogging.files)}")
    k_q = ilc.torque_constant_nm_per_a(simulated.folder)
    moteus = ilc.export(work / "result.json", "moteus", work / "moteus", torque_constant_nm_per_a=k_q)
    print(f"exported {', '.join(p.name for p in moteus.files)} at k_q {k_q:.4g} N m / A")
    print(f"  {moteus.residual.line('moteus')}")


def main() -> None:
    if len(sys.argv) > 1:
        work = Path(sys.argv[1])
        work.mkdir(parents=True, exist_ok=True)
        tour(work)
    else:
        with tempfile.TemporaryDirectory() as folder:
            tour(Path(folder))


if __name__ == "__main__":
    main()
