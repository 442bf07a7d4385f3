"""moteus's own one-shot anticogging, one pass of ours and the whole drive campaign, side by side on the emulated
moteus of configs/moteus-emulated.toml (a small actuator, 7 pole pairs, 12 slots, its current loop at 1 kHz), in
one run through mjbots' moteus library (issue 36).

- moteus's one shot (mjbots/moteus utils/compensate_cogging.py, reimplemented from its description): per
  direction the mean q current in 1024 equal bins of the commutation position, the two directions averaged,
  entry k bin k's mean, int8 x scale with scale = max |mean| / 127 and int() truncation; at its own default speed
  (--speed 2 electrical rev/s, split_count 8: 2 x 57 s) and on our uncompensated trials;
- one pass of ours: the uncompensated trials' estimate as the table (eq. 2 of campaign/drive.py with L = 1);
- the whole campaign (`run_drive_campaign`, [drive] defaults: 600 s of motor time), and the floor: the
  least-squares table of the format for every speed and direction, through the current's lag, run on the drive.

Each table but the campaign's is verified by one trial per speed and direction. Printed per speed and direction:
the residual ripple RMS, true (the emulated drive's) and as measured, and each method's motor time.

    .venv/bin/python benchmarks/moteus.py [--in-process]

``--in-process`` runs the trials on the test-style backend of tests/test_drive_campaign.py (the emulated drive
without the library: faster) instead of through the library's Controller and the emulated transport.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
# this file's folder off the path: its name would hide the moteus library
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != ROOT / "benchmarks"]
sys.path.insert(0, str(ROOT / "tests"))

from test_drive_campaign import EmulatedDriveBackend  # noqa: E402

from ilcpmac.backends.drive import DriveTrial  # noqa: E402
from ilcpmac.backends.guard import LimitGuard  # noqa: E402
from ilcpmac.campaign.drive import (  # noqa: E402
    DrivePlan,
    drive_plan,
    drive_settings,
    learned_table,
    measured_trial,
    ripple_rms,
    run_drive_campaign,
    zero_table,
)
from ilcpmac.config import CampaignConfig, load_config  # noqa: E402
from ilcpmac.core.records import DriveTrialRequest  # noqa: E402
from ilcpmac.export import MOTEUS_INT8_MAX, MOTEUS_TABLE_SIZE, MoteusTable  # noqa: E402
from ilcpmac.pipeline.safety import SafetyLimits  # noqa: E402

EMULATED = ROOT / "configs" / "moteus-emulated.toml"


def moteus_one_shot(trials: list[DriveTrial], counts_per_rev: int) -> MoteusTable:
    """compensate_cogging.py's table from uncompensated trials: each direction's mean q current per bin of the
    commutation position, the directions averaged, int8 by truncation."""
    means = []
    for sign in (1.0, -1.0):
        rows = [t.data for t in trials if np.sign(t.request.speed_hz) == sign]
        position = np.concatenate([d.position_counts for d in rows]) / counts_per_rev % 1.0
        current = np.concatenate([np.asarray(d.i_q_a) for d in rows])
        bins = np.minimum((position * MOTEUS_TABLE_SIZE).astype(np.int64), MOTEUS_TABLE_SIZE - 1)
        means.append(np.bincount(bins, current, MOTEUS_TABLE_SIZE) / np.bincount(bins, None, MOTEUS_TABLE_SIZE))
    average = np.nan_to_num(np.mean(means, axis=0))
    scale = float(np.max(np.abs(average))) / MOTEUS_INT8_MAX
    return MoteusTable(np.trunc(average / scale).astype(np.int8), scale)


def _round(guard: LimitGuard, plan: DrivePlan, index: int, table: MoteusTable) -> list[DriveTrial]:
    return [guard.run_drive_trial(request) for request in plan.requests(index, table)]


def _backend(config: CampaignConfig, in_process: bool):
    if in_process:
        backend = EmulatedDriveBackend(config)
        backend.drive.set_config("servo.pid_dq_hz", config.simulated_model().controller.bandwidth_hz)
        return backend
    from ilcpmac.backends.moteus import from_setup
    from ilcpmac.backends.registry import BackendSetup

    return from_setup(BackendSetup(config, options=config.backend_options["moteus"]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--in-process", action="store_true",
                        help="the test-style backend of tests/test_drive_campaign.py instead of the moteus library")
    parser.add_argument("--backemf-scale", type=float, default=1.0,
                        help="the true back-EMF over the config's ([simulator.winding] backemf_scale): 0.9, the "
                             "motor's K_t 10 %% below what the campaign is told")
    args = parser.parse_args()
    config = load_config(EMULATED)
    model = config.simulated_model()
    config = dataclasses.replace(config, model=dataclasses.replace(
        model, winding=dataclasses.replace(model.winding, backemf_scale=args.backemf_scale)))
    backend = _backend(config, args.in_process)
    description = backend.describe()
    limits = SafetyLimits.of_campaign(config.limits, description.limits, 0)
    guard = LimitGuard(backend, description, limits)
    drive = backend.drive_limits()
    plan = drive_plan(drive_settings(config), config, description, drive, limits)
    cpr, bandwidth_hz = description.motor.counts_per_rev, drive.current_bandwidth_hz
    started = time.monotonic()
    uncompensated = _round(guard, plan, 0, zero_table())
    measured = [measured_trial(t, description, zero_table(), bandwidth_hz) for t in uncompensated]
    ours = learned_table(zero_table(), np.mean([m.residual_nm for m in measured], axis=0), measured[0].k_q, 1.0)
    # moteus's own at its default speed: --speed 2 electrical rev/s over motor.poles (2 pole pairs), split_count 8
    # x average_count 1 / speed seconds per direction
    own_hz = 2.0 / (2 * description.motor.pole_pairs)
    own_s = 8.0 / own_hz
    own = [guard.run_drive_trial(DriveTrialRequest(v, plan.settle_s, own_s, zero_table().values.astype(np.int64),
                                                   0.0)) for v in (-own_hz, own_hz)]
    tables = {f"moteus one shot, at {own_hz:.2g} Hz": moteus_one_shot(own, cpr),
              "moteus one shot, at our speeds": moteus_one_shot(uncompensated, cpr), "ours, one pass": ours}
    rows: dict[str, list[tuple[float, float]]] = {"uncompensated": [(ripple_rms(np.asarray(t.true_residual_nm)),
                                                                     ripple_rms(m.residual_nm))
                                                                    for t, m in zip(uncompensated, measured)]}
    round_s = len(plan.signed_speeds_hz) * (plan.settle_s + plan.seconds)
    motor_s = {"uncompensated": round_s, f"moteus one shot, at {own_hz:.2g} Hz": 2 * (plan.settle_s + own_s),
               "moteus one shot, at our speeds": round_s, "ours, one pass": round_s}
    for name, table in tables.items():
        trials = _round(guard, plan, len(plan.rounds) - 1, table)
        rows[name] = [(ripple_rms(np.asarray(t.true_residual_nm)),
                       ripple_rms(measured_trial(t, description, table, bandwidth_hz).residual_nm)) for t in trials]
    backend.close()
    with tempfile.TemporaryDirectory() as out:
        result = run_drive_campaign(config, _backend(config, args.in_process), Path(out))
    rows["ours, campaign"] = [(p.true_final_nm or np.nan, p.final_nm) for p in result.points]
    rows["floor (the best one table, run)"] = [(p.true_floor_nm or np.nan, np.nan) for p in result.points]
    motor_s["ours, campaign"] = result.motor_time_used_s
    speeds = "".join(f" | {s:+g} Hz true / measured" for s in plan.signed_speeds_hz)
    print(f"{EMULATED.name}: emulated moteus{' in process' if args.in_process else ' through the moteus library'}, "
          f"true back-EMF {args.backemf_scale:g} x the config's; "
          f"current loop {bandwidth_hz:g} Hz; trials of {plan.settle_s:g} + {plan.seconds:.4g} s; residual ripple "
          f"RMS, mN m; without the current's lag the format's floor is {1e3 * (result.format_floor_nm or np.nan):.3g}")
    print(f"| method{speeds} | motor time s |")
    print("|---" * (len(plan.signed_speeds_hz) + 2) + "|")
    for name, values in rows.items():
        cells = "".join(f" | {1e3 * true:.3g} / {1e3 * seen:.3g}" for true, seen in values)
        print(f"| {name}{cells} | {motor_s.get(name, math.nan):.4g} |")
    print(f"wall time {time.monotonic() - started:.1f} s")


if __name__ == "__main__":
    main()
