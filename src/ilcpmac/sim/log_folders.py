"""Simulated drive logs as a user's folder holds them: the log, the import mapping, backemf.csv and truth.json.

``ilcpmac import LOG --map mapping.toml --out BENCH`` accepts each folder's mapping as it is
(docs/bench-format.md, "The mapping file"); truth.json holds what the simulator knows (`write_scan_log`,
`write_drive_log` list its keys).
"""

from __future__ import annotations

import json
from pathlib import Path

from ilcpmac.bench.format import write_backemf_csv
from ilcpmac.core.files import atomic_write
from ilcpmac.core.schema import toml_text
from ilcpmac.sim.drive_log import LogPlan, write_drive_log
from ilcpmac.sim.simulator import Simulator
from ilcpmac.sim.standstill import ScanPlan, write_scan_log

__all__ = ["DRIVE_LOG", "MAPPING", "SCAN_LOG", "write_simulated_log", "write_simulated_scan"]

#: the files a folder gets besides backemf.csv and truth.json
MAPPING, SCAN_LOG, DRIVE_LOG = "mapping.toml", "scan_log.csv", "drive_log.csv"


#: the smallest relative uncertainty of the inertia a mapping states
MIN_INERTIA_UNCERTAINTY = 0.01


def _bench_table(simulator: Simulator) -> dict:
    """[bench] of a mapping: the motor as its controller knows it, the back-EMF in backemf.csv; the inertia the
    controller's, its uncertainty the truth's relative difference ([simulator.mechanics] inertia_scale - 1), at
    least `MIN_INERTIA_UNCERTAINTY`."""
    info = simulator.model.motor_info()
    uncertainty = max(abs(simulator.model.mechanics.inertia_scale - 1.0), MIN_INERTIA_UNCERTAINTY)
    return {"pole_pairs": info.pole_pairs, "slots": info.slots, "counts_per_rev": info.counts_per_rev,
            "inertia_kgm2": info.inertia_kgm2, "inertia_uncertainty": float(f"{uncertainty:.3g}"),
            "backemf_file": "backemf.csv"}


def _write(out: Path, simulator: Simulator, mapping: dict, truth: dict) -> None:
    write_backemf_csv(out / "backemf.csv", simulator.backemf_counts)
    atomic_write(out / MAPPING, toml_text(mapping))
    atomic_write(out / "truth.json", json.dumps(truth, indent=1))


def write_simulated_scan(out: str | Path, simulator: Simulator, plan: ScanPlan) -> dict:
    """A standstill scan holding currents (`write_scan_log`) in ``out``: scan_log.csv, mapping.toml with the
    phase currents, the direction column and [scan] the true current-sensor errors at the controller's
    calibration, backemf.csv, truth.json; returns the truth."""
    out = Path(out)
    truth = write_scan_log(out / SCAN_LOG, simulator, plan)
    cpr = simulator.model.encoder.counts_per_rev
    errors = simulator.truth(simulator.model.controller.calibration())
    log: dict[str, object] = {"kind": "scan", "time": "time", "position": "position", "position_unit": "counts",
           "position_counts_per_rev": cpr, "direction": "direction"}
    log |= ({"torque": "torque"} if plan.holding == "torque" else {"phase_currents": ["i_a", "i_b", "i_c"]})
    scan = ({"torque_sensor_gain": errors.delta} if plan.holding == "torque" else
            {"epsilon": errors.epsilon, "alpha": errors.alpha.tolist(), "beta_a": errors.beta_a.tolist()})
    _write(out, simulator, {"bench": _bench_table(simulator), "log": log, "scan": scan}, truth)
    return truth


def write_simulated_log(out: str | Path, simulator: Simulator, plan: LogPlan) -> dict:
    """A rolling drive log (`write_drive_log`) in ``out``: drive_log.csv, mapping.toml (the position's unit, in
    lines of the drive's encoder its lines per revolution; the host clock's tick as the stamps' quantum when it
    has one; measured currents, no torque column, the inertia's uncertainty), backemf.csv, truth.json; returns
    the truth."""
    out = Path(out)
    truth = write_drive_log(out / DRIVE_LOG, simulator, plan)
    log: dict[str, object] = {"time": "time", "position": "position", "position_unit": plan.position_unit,
                              "current": "measured"}
    if plan.position_unit == "counts":
        log["position_counts_per_rev"] = 2**plan.encoder_bits
    if plan.stamp_s > 0:
        log["timer_resolution_s"] = plan.stamp_s
    log |= ({"i_q": "i_q"} if plan.current_column == "q" else {"phase_currents": ["i_a", "i_b", "i_c"]})
    _write(out, simulator, {"bench": _bench_table(simulator), "log": log}, truth)
    return truth
