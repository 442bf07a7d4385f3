"""The Python API end to end (docs/api.md) on a small simulated campaign, in a few seconds.

    python examples/api_tour.py [WORK_DIR]

Writes a small config, runs a campaign on the simulator, loads its results,
simulates and identifies a bench, imports a simulated drive log and exports
the compensation, all into WORK_DIR (default: a temporary folder, removed at
the end), printing a few figures of each step.
"""

import json
import sys
import tempfile
import tomllib
from pathlib import Path

import numpy as np

import ilcpmac.campaign
from ilcpmac.bench.format import read_bench
from ilcpmac.bench.importer import import_logs, read_mapping
from ilcpmac.campaign.rundir import RunFiles
from ilcpmac.compensation import Compensation, read_position_table
from ilcpmac.config import load_config, packaged_config
from ilcpmac.core.schema import toml_text
from ilcpmac.export import export
from ilcpmac.identify import identify_bench
from ilcpmac.sim.drive_log import LogPlan
from ilcpmac.sim.log_folders import DRIVE_LOG, MAPPING, write_simulated_log
from ilcpmac.sim.simulator import Simulator

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
    data = tomllib.loads(packaged_config("seed-bench.toml").read_text())
    for table, values in SMALL.items():
        for key, value in values.items():
            if isinstance(value, dict):
                data[table][key].update(value)
            else:
                data[table][key] = value
    path = folder / "small.toml"
    path.write_text(toml_text(data))
    return path


def tour(work: Path) -> None:
    config_path = small_config(work)

    # 1. a campaign on the simulator: identify, learn, validate
    result = ilcpmac.campaign.run(config_path, out=work / "run", seed=3)
    print(f"campaign: {len(result.records)} trials in {result.path}")
    for point in result.points:
        torque_setpoint_nm, speed_setpoint_hz = point.point
        print(f"  {torque_setpoint_nm:g} N m, {speed_setpoint_hz:g} Hz ({'learned' if point.learned else 'validated'}):"
              f" ripple {100 * point.before.measured.pp:.3g} % pp -> {100 * point.after.measured.pp:.3g} % pp")

    # 2. its results from the files: summary.json (units named) and the trials as arrays
    summary = json.loads((result.path / "summary.json").read_text())
    units = summary["units"]
    for p in summary["points"]:
        print(f"  summary: {p['torque_setpoint']:g} {units['torque_setpoint']}: ripple {p['ripple_pp_measured']:.3g}, "
              f"floor {p['floor_pp_measured']:.3g} ({units['ripple_pp_measured']})")
    motor_time_s = summary["motor_time_s"]  # per phase, and "all"
    print(f"motor time: {motor_time_s['all']:.1f} s, of which learning {motor_time_s['ilc']:.1f} s")
    trial = read_bench(result.path).trials[0]
    print(f"trial 1: {trial.n_samples} samples, i_ref_a {trial.i_ref_a.shape}, "
          f"torque {trial.torque_nm.std() if trial.torque_nm is not None else float('nan'):.3g} N m RMS about its mean")

    # 3. a simulated bench, identified
    config = load_config(config_path)
    ilcpmac.campaign.simulate_bench(config, work / "bench", seed=3)
    identification = identify_bench(read_bench(work / "bench"))
    truth = json.loads((work / "bench" / "truth.json").read_text())
    print(f"identified: epsilon {identification.epsilon:.4f} (truth {truth['epsilon']:.4f}), "
          f"delta {identification.delta:.4f} (truth {truth['torque_sensor_gain']:.4f})")
    result_json = work / "result.json"
    result_json.write_text(json.dumps(identification.to_json()))

    # 4. a drive log (here simulated, as ilcpmac simulate --kind log), imported and identified
    (work / "log").mkdir()
    write_simulated_log(work / "log", Simulator(config.simulated_model()), LogPlan(seed=3, duration_s=10.0))
    imported = import_logs([work / "log" / DRIVE_LOG], read_mapping(work / "log" / MAPPING), work / "imported")
    lap = imported[0].laps[0]
    print(f"imported: {len(imported[0].bench.trials)} trial(s), interpolation error {lap.error.current_a:.3g} A")
    from_log = identify_bench(imported[0].bench)
    assert from_log.position_torque_nm is not None
    print(f"from the log: position torque {np.ptp(from_log.position_torque_nm):.3g} N m pp")

    # 5. exports: the campaign's compensation as C, the identification's cogging as CSV
    exported = export(Compensation.read(RunFiles(result.path).compensation), work / "firmware", "c")
    assert exported.residual is not None
    print(f"exported {', '.join(p.name for p in exported.files)}: {exported.residual.rms_nm:.3g} N m RMS residual")
    cogging = export(read_position_table(result_json), work / "cogging", "csv")
    print(f"exported {', '.join(p.name for p in cogging.files)}")


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
