"""Log an ODrive turning at a slow constant speed, or read its anticogging map, for ilcpmac (docs/real-bench.md,
section 4e).

    pip install odrive
    python examples/log_odrive.py log --slots 12 --inertia-kgm2 2.5e-4 --speed-hz 0.5 --out odrive-log
    ilcpmac import odrive-log/odrive_log.csv --map odrive-log/mapping.toml --out rolling
    python examples/log_odrive.py map --out anticogging_map.npy

For ODrive's open-source firmware, 0.4.x and 0.5.x (ODrive v3; Firmware/odrive-interface.yaml of
odriverobotics/ODrive names the properties). ``log`` runs the axis in velocity control and polls, row after row,
the encoder's position estimate in counts (``encoder.pos_estimate`` on 0.4, ``encoder.pos_estimate_counts`` on 0.5,
where ``pos_estimate`` is in turns) and then ``motor.current_control.Iq_measured``, A. Each read is one USB round
trip: a row is stamped with the host's `time.perf_counter` half-way through the position's read, ``round_trip_s``
is that read's length, and I_q is read one round trip later. Every 200 rows the axis's state is checked; the axis
goes to idle on every way out (the end, an error, the axis dropping out of closed loop, Ctrl-C), its control and
input modes restored, and the CSV holds every row read. mapping.toml (pole pairs, counts per revolution and, on 0.5,
K_t read off the drive; slots and inertia from the options) makes ilcpmac read it; its ``timer_resolution_s`` is
the median round trip of the position's read. A ``motor.current_control.I_measured_report_filter_k`` other than 1
(the default) filters the I_q read: the script says so.

``map`` saves the anticogging map of firmware 0.5.6 or later (``controller.get_anticogging_value``, 3600 entries a
turn of ``pos_estimate``, N m) as a float64 .npy of the holding q current, A (over ``motor.config.torque_constant``):
entry k is what the calibration held at k / 3600 turn and what the firmware adds over [k, k + 1) / 3600.

The odrive package is imported in `main` only: the module imports without it (tests/test_drive_scripts.py drives
`run` and `read_map` with a fake ODrive).
"""

from __future__ import annotations

import argparse
import csv
import math
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np

from ilcpmac.bench.format import MAX_TIMER_RESOLUTION_S

#: the files written by ``log`` in --out
LOG_FILE, MAPPING_FILE = "odrive_log.csv", "mapping.toml"
#: the CSV's columns, in order
COLUMNS = ("time_s", "position_counts", "i_q_a", "round_trip_s")
#: enum values, the same on firmware 0.4 and 0.5 (tools/odrive/enums.py)
AXIS_STATE_IDLE, AXIS_STATE_CLOSED_LOOP_CONTROL = 1, 8
CONTROL_MODE_VELOCITY_CONTROL, INPUT_MODE_PASSTHROUGH = 2, 1
#: rows between two checks of the axis's state (each check is one more round trip)
CHECK_EVERY = 200
#: entries of firmware 0.5's anticogging map a turn (Encoder::getCoggingRatio() = 1 / 3600)
COGGING_MAP_ENTRIES = 3600
#: the first firmware with controller.get_anticogging_value
MAP_FIRMWARE = (0, 5, 6)


class DriveError(Exception):
    """The firmware or the axis cannot do what was asked: one line, exit status 2."""


@dataclass(frozen=True)
class Motor:
    """What mapping.toml says of the motor: [bench] as docs/bench-format.md, "The mapping file", reads it."""

    pole_pairs: int
    slots: int
    counts_per_rev: int
    inertia_kgm2: float
    torque_constant_nm_per_a: float


@dataclass
class Log:
    """What `record` logged: each row's stamp and round trip, s."""

    stamps_s: list[float] = field(default_factory=list)
    round_trips_s: list[float] = field(default_factory=list)

    def summary(self, path: Path) -> str:
        """One line: the rows, their rate and round trips."""
        if len(self.stamps_s) < 2:
            return f"{len(self.stamps_s)} rows in {path}"
        rate = (len(self.stamps_s) - 1) / (self.stamps_s[-1] - self.stamps_s[0])
        return (f"{len(self.stamps_s)} rows in {path}, {rate:.4g} per second; position reads "
                f"{statistics.median(self.round_trips_s):.3g} s median, {max(self.round_trips_s):.3g} s longest")


def positive(kind: Callable[[str], Any]) -> Callable[[str], Any]:
    """An argparse type: ``kind`` of the text, finite and > 0."""
    def parse(text: str) -> Any:
        value = kind(text)
        if not (math.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"{text}: not a finite number > 0")
        return value
    parse.__name__ = kind.__name__
    return parse


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    """The command line; a bad value exits with status 2 naming the option."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    log = commands.add_parser("log", help="log a slow run in velocity control")
    drive = commands.add_parser("map", help="save the anticogging map (firmware 0.5.6 or later) as .npy")
    for sub in (log, drive):
        sub.add_argument("--axis", type=int, choices=(0, 1), default=0, help="axis0 or axis1 (default 0)")
        sub.add_argument("--serial", default=None, help="the ODrive's serial number (default: the first found)")
        sub.add_argument("--torque-constant", type=positive(float), default=None,
                         help="K_t, N m per A of q current (default: motor.config.torque_constant; firmware 0.4 has "
                              "none)")
    log.add_argument("--speed-hz", type=positive(float), default=0.5,
                     help="rotor speed, rev/s (default 0.5): slow, but fast enough to turn smoothly")
    log.add_argument("--duration-s", type=positive(float), default=20.0, help="logged time, s (default 20)")
    log.add_argument("--settle-s", type=float, default=2.0, help="time at speed before the first row, s (default 2)")
    log.add_argument("--slots", type=positive(int), required=True, help="the motor's stator slots")
    log.add_argument("--inertia-kgm2", type=positive(float), required=True,
                     help="the rotor's inertia with what turns with it, kg m^2 (docs/real-bench.md, section 2.3)")
    log.add_argument("--counts-per-rev", type=positive(int), default=4096,
                     help="the counts ilcpmac resamples onto ([bench] counts_per_rev, default 4096)")
    log.add_argument("--out", type=Path, default=Path("odrive-log"), help="the folder written (default odrive-log)")
    drive.add_argument("--out", type=Path, default=Path("anticogging_map.npy"),
                       help="the .npy written (default anticogging_map.npy)")
    args = parser.parse_args(argv)
    if args.command == "log" and not (math.isfinite(args.settle_s) and args.settle_s >= 0):
        log.error(f"argument --settle-s: {args.settle_s}: not a finite number >= 0")
    return args


def firmware(odrv: Any) -> tuple[int, int, int]:
    """The firmware's version; one the script does not know raises `DriveError`."""
    version = (int(odrv.fw_version_major), int(odrv.fw_version_minor), int(odrv.fw_version_revision))
    if version[:2] != (0, 4) and not (0, 5, 1) <= version < (0, 6, 0):
        raise DriveError(f"firmware {'.'.join(map(str, version))}: this script reads the properties of ODrive's "
                         "open-source firmware 0.4.x and 0.5.1-0.5.x (0.5.1 moved positions to turns)")
    return version


def torque_constant(axis: Any, version: tuple[int, int, int], given: float | None) -> float:
    """K_t, N m / A: ``given``, else the drive's ``motor.config.torque_constant`` (firmware 0.5)."""
    if given is not None:
        return given
    if version[:2] == (0, 4):
        raise DriveError("firmware 0.4 has no motor.config.torque_constant: give --torque-constant")
    return float(axis.motor.config.torque_constant)


def mapping_text(motor: Motor, encoder_counts_per_rev: int, round_trips_s: Sequence[float]) -> str:
    """mapping.toml for odrive_log.csv: a sinusoidal back-EMF whose q-axis torque constant is K_t (k_1 = 2 K_t / 3,
    amplitude-invariant i_q as ODrive's), the position in the encoder's counts, the measured q current;
    ``timer_resolution_s`` the median round trip, at most the mapping's bound (left out without rows)."""
    lines = ["# ilcpmac import mapping of odrive_log.csv, written by examples/log_odrive.py", "[bench]",
             f"pole_pairs = {motor.pole_pairs}", f"slots = {motor.slots}", f"counts_per_rev = {motor.counts_per_rev}",
             f"inertia_kgm2 = {motor.inertia_kgm2!r}", "", "[bench.backemf]", "harmonics = [1]",
             f"amplitudes_nm_per_a = [{2.0 * motor.torque_constant_nm_per_a / 3.0!r}]", "", "[log]",
             'time = "time_s"', 'position = "position_counts"', 'position_unit = "counts"',
             f"position_counts_per_rev = {encoder_counts_per_rev}", 'i_q = "i_q_a"', 'current = "measured"']
    stamp_s = min(statistics.median(round_trips_s), MAX_TIMER_RESOLUTION_S) if round_trips_s else 0.0
    if stamp_s > 0.0:
        lines.append(f"timer_resolution_s = {float(f'{stamp_s:.2g}')!r}")
    return "\n".join(lines) + "\n"


def axis_errors(axis: Any) -> str:
    """The axis's and its parts' error codes."""
    parts = {"axis": axis, "motor": axis.motor, "encoder": axis.encoder, "controller": axis.controller}
    return ", ".join(f"{name}.error = {int(part.error):#x}" for name, part in parts.items())


def record(axis: Any, position: Callable[[], float], args: argparse.Namespace, out: IO[str], log: Log,
           clock: Callable[[], float] = time.perf_counter) -> None:
    """Poll ``position()`` and I_q for --settle-s, then for --duration-s more, writing a row to ``out`` per poll and
    its stamp and round trip to ``log``; an axis that leaves closed-loop control raises `DriveError`."""
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(COLUMNS)
    start = clock() + args.settle_s
    polls = 0
    while True:
        before = clock()
        if before - start >= args.duration_s:
            return
        if polls % CHECK_EVERY == 0 and int(axis.current_state) != AXIS_STATE_CLOSED_LOOP_CONTROL:
            raise DriveError(f"axis{args.axis} left closed-loop control ({axis_errors(axis)}) after "
                             f"{len(log.stamps_s)} rows")
        counts = position()
        read = clock()
        i_q = axis.motor.current_control.Iq_measured
        polls += 1
        stamp = (before + read) / 2.0 - start
        if stamp >= 0.0:
            writer.writerow([repr(stamp), repr(float(counts)), repr(float(i_q)), repr(read - before)])
            log.stamps_s.append(stamp)
            log.round_trips_s.append(read - before)


def run(odrv: Any, args: argparse.Namespace, clock: Callable[[], float] = time.perf_counter) -> Log:
    """Velocity control at --speed-hz, logged (`record`) into --out, the axis idle and its modes restored on every
    way out; the mapping written."""
    version = firmware(odrv)
    axis = getattr(odrv, f"axis{args.axis}")
    cpr = int(axis.encoder.config.cpr)
    motor = Motor(int(axis.motor.config.pole_pairs), args.slots, args.counts_per_rev, args.inertia_kgm2,
                  torque_constant(axis, version, args.torque_constant))
    if float(axis.motor.current_control.I_measured_report_filter_k) != 1.0:
        print("note: motor.current_control.I_measured_report_filter_k is not 1: the I_q read is low-pass filtered "
              "(1 leaves it as measured)", file=sys.stderr)
    config = axis.controller.config
    modes = {"control_mode": config.control_mode} | ({} if version[:2] == (0, 4) else {"input_mode": config.input_mode})
    args.out.mkdir(parents=True, exist_ok=True)
    log = Log()
    try:
        config.control_mode = CONTROL_MODE_VELOCITY_CONTROL
        if version[:2] == (0, 4):
            axis.controller.set_vel_setpoint(args.speed_hz * cpr, 0.0)  # counts/s, current feed-forward

            def position() -> float:
                return axis.encoder.pos_estimate
        else:
            config.input_mode = INPUT_MODE_PASSTHROUGH
            axis.controller.input_vel = args.speed_hz  # turn/s

            def position() -> float:
                return axis.encoder.pos_estimate_counts
        axis.requested_state = AXIS_STATE_CLOSED_LOOP_CONTROL
        with open(args.out / LOG_FILE, "w", newline="") as out:
            record(axis, position, args, out, log, clock)
    finally:
        axis.requested_state = AXIS_STATE_IDLE
        if version[:2] == (0, 4):
            axis.controller.set_vel_setpoint(0.0, 0.0)
        else:
            axis.controller.input_vel = 0.0
        for name, value in modes.items():
            setattr(config, name, value)
        (args.out / MAPPING_FILE).write_text(mapping_text(motor, cpr, log.round_trips_s))
        print(log.summary(args.out / LOG_FILE), file=sys.stderr)
    return log


def read_map(odrv: Any, args: argparse.Namespace) -> np.ndarray:
    """The axis's anticogging map as holding q currents, A: `COGGING_MAP_ENTRIES` a turn of ``pos_estimate``."""
    version = firmware(odrv)
    if version < MAP_FIRMWARE:
        raise DriveError(f"firmware {'.'.join(map(str, version))} does not give its anticogging map "
                         f"(controller.get_anticogging_value came in {'.'.join(map(str, MAP_FIRMWARE))})")
    axis = getattr(odrv, f"axis{args.axis}")
    if not axis.controller.anticogging_valid:
        raise DriveError(f"axis{args.axis}: controller.anticogging_valid is false: no map (run "
                         "controller.start_anticogging_calibration() first)")
    k_t = torque_constant(axis, version, args.torque_constant)
    return np.array([axis.controller.get_anticogging_value(k) for k in range(COGGING_MAP_ENTRIES)]) / k_t


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    import odrive

    try:
        odrv = odrive.find_any(serial_number=args.serial)
        if args.command == "map":
            current_a = read_map(odrv, args)
            np.save(args.out, current_a)
            print(f"{args.out}: {current_a.size} holding q currents, A: entry k at k / {current_a.size} turn of "
                  f"axis{args.axis}.encoder.pos_estimate, {np.ptp(current_a):.4g} A peak-to-peak", file=sys.stderr)
        else:
            run(odrv, args)
    except DriveError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("interrupted: the axis is idle" + (f", {args.out / LOG_FILE} holds the rows logged"
                                                 if args.command == "log" else ""), file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
