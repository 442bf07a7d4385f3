"""Log a moteus turning at a slow constant speed, for ilcpmac's offline path (docs/real-bench.md, section 4e).

    pip install moteus
    python examples/log_moteus.py --slots 12 --inertia-kgm2 6e-5 --torque-constant 0.09 --out moteus-log
    ilcpmac import moteus-log/moteus_log.csv --map moteus-log/mapping.toml --out rolling

The motor turns in moteus's position mode with the position NaN and a velocity (what moteus's own
utils/compensate_cogging.py commands), and every command's reply carries the row: the commutation encoder's
position (``Register.ENCODER_<n>_POSITION`` of ``motor_position.commutation_source``, the position moteus indexes
``motor.cogging_dq_comp`` by, not ``Register.POSITION``, which is the output's), the measured q current
(``Register.Q_CURRENT``: in a reply only with ``QueryResolution.q_current`` set), that encoder's velocity, the board
temperature, the fault code and the mode. A row is stamped with the host's `time.perf_counter` half-way between the
command and its reply; ``round_trip_s`` is how far apart those were. The motor is stopped on every way out (the end,
an error, a fault or a position timeout of the drive, Ctrl-C), and the CSV holds every row received.
mapping.toml (pole pairs from ``motor.poles``; slots, inertia and K_t from the options) makes ilcpmac read it;
its ``timer_resolution_s`` is the median round trip, the width of the stamps' uncertainty.

The moteus library is imported in `main` only: the module imports without it (tests/test_drive_scripts.py drives
`run` with a fake controller).
"""

from __future__ import annotations

import argparse
import asyncio
import csv
import math
import statistics
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from ilcpmac.bench.format import MAX_TIMER_RESOLUTION_S

#: the files written in --out
LOG_FILE, MAPPING_FILE = "moteus_log.csv", "mapping.toml"
#: the CSV's columns, in order
COLUMNS = ("time_s", "position_rad", "i_q_a", "velocity_hz", "temperature_c", "fault", "mode", "round_trip_s")
#: the acceleration limit of the velocity command, output rev/s^2 (the "a4" of moteus's compensate_cogging.py)
ACCEL_LIMIT = 4.0


class DriveError(Exception):
    """The drive did not answer, or answered in a mode that is not turning the motor: one line, exit status 2."""


@dataclass(frozen=True)
class Registers:
    """Where a reply's values are (moteus.Register numbers) and the modes that end the log (moteus.Mode)."""

    position: int
    velocity: int
    q_current: int
    temperature: int
    fault: int
    mode: int
    halted: tuple[int, ...]

    @classmethod
    def of(cls, register: Any, mode: Any, commutation_source: int) -> Registers:
        """The registers of moteus.Register ``register`` for commutation source 0, 1 or 2."""
        if commutation_source not in (0, 1, 2):
            raise DriveError(f"motor_position.commutation_source = {commutation_source}: not a source 0, 1 or 2")
        return cls(getattr(register, f"ENCODER_{commutation_source}_POSITION"),
                   getattr(register, f"ENCODER_{commutation_source}_VELOCITY"), register.Q_CURRENT,
                   register.TEMPERATURE, register.FAULT, register.MODE, (mode.FAULT, mode.TIMEOUT))


@dataclass(frozen=True)
class Motor:
    """What mapping.toml says of the motor: [bench] as docs/bench-format.md, "The mapping file", reads it."""

    pole_pairs: int
    slots: int
    counts_per_rev: int
    inertia_kgm2: float
    torque_constant_nm_per_a: float


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
    parser.add_argument("--id", type=int, default=1, help="the controller's CAN id (default 1)")
    parser.add_argument("--speed-hz", type=positive(float), default=0.5,
                        help="rotor speed, rev/s (default 0.5): slow, but fast enough to turn smoothly")
    parser.add_argument("--duration-s", type=positive(float), default=20.0, help="logged time, s (default 20)")
    parser.add_argument("--settle-s", type=float, default=2.0,
                        help="time at speed before the first row, s (default 2)")
    parser.add_argument("--max-torque-nm", type=positive(float), default=None,
                        help="the command's maximum_torque, N m at the output (default: the drive's limits)")
    parser.add_argument("--slots", type=positive(int), required=True, help="the motor's stator slots")
    parser.add_argument("--inertia-kgm2", type=positive(float), required=True,
                        help="the rotor's inertia with what turns with it, kg m^2 (docs/real-bench.md, section 2.3)")
    parser.add_argument("--torque-constant", type=positive(float), required=True,
                        help="K_t, N m per A of q current")
    parser.add_argument("--counts-per-rev", type=positive(int), default=4096,
                        help="the counts ilcpmac resamples onto ([bench] counts_per_rev, default 4096)")
    parser.add_argument("--out", type=Path, default=Path("moteus-log"), help="the folder written (default moteus-log)")
    args = parser.parse_args(argv)
    if not (math.isfinite(args.settle_s) and args.settle_s >= 0):
        parser.error(f"argument --settle-s: {args.settle_s}: not a finite number >= 0")
    return args


def mapping_text(motor: Motor, round_trips_s: Sequence[float]) -> str:
    """mapping.toml for moteus_log.csv: a sinusoidal back-EMF whose q-axis torque constant is K_t (k_1 = 2 K_t / 3,
    amplitude-invariant i_q as moteus's), the position in rad, the measured q current; ``timer_resolution_s`` the
    median round trip, at most the mapping's bound (left out without rows)."""
    lines = ["# ilcpmac import mapping of moteus_log.csv, written by examples/log_moteus.py", "[bench]",
             f"pole_pairs = {motor.pole_pairs}", f"slots = {motor.slots}", f"counts_per_rev = {motor.counts_per_rev}",
             f"inertia_kgm2 = {motor.inertia_kgm2!r}", "", "[bench.backemf]", "harmonics = [1]",
             f"amplitudes_nm_per_a = [{2.0 * motor.torque_constant_nm_per_a / 3.0!r}]", "", "[log]",
             'time = "time_s"', 'position = "position_rad"', 'position_unit = "rad"', 'i_q = "i_q_a"',
             'current = "measured"']
    stamp_s = min(statistics.median(round_trips_s), MAX_TIMER_RESOLUTION_S) if round_trips_s else 0.0
    if stamp_s > 0.0:
        lines.append(f"timer_resolution_s = {float(f'{stamp_s:.2g}')!r}")
    return "\n".join(lines) + "\n"


async def config_value(stream: Any, name: str) -> float:
    """``conf get NAME`` on moteus's diagnostic stream (as utils/compensate_cogging.py reads its configuration)."""
    reply = await stream.command(f"conf get {name}".encode(), allow_any_response=True)
    try:
        return float(reply.decode("latin1"))
    except ValueError:
        raise DriveError(f"conf get {name}: {reply!r} is not a number") from None


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
        return (f"{len(self.stamps_s)} rows in {path}, {rate:.4g} per second; round trips "
                f"{statistics.median(self.round_trips_s):.3g} s median, {max(self.round_trips_s):.3g} s longest")


async def record(controller: Any, registers: Registers, velocity: float, args: argparse.Namespace, out: IO[str],
                 log: Log, clock: Callable[[], float] = time.perf_counter) -> None:
    """Command ``velocity`` (output rev/s) in position mode with the position NaN for --settle-s, then for
    --duration-s more, writing a row to ``out`` per reply and its stamp and round trip to ``log``. A missing reply,
    or a mode in ``registers.halted``, raises `DriveError`."""
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(COLUMNS)
    start = clock() + args.settle_s
    while True:
        sent = clock()
        if sent - start >= args.duration_s:
            return
        reply = await controller.set_position(position=math.nan, velocity=velocity, accel_limit=ACCEL_LIMIT,
                                              maximum_torque=args.max_torque_nm, query=True)
        received = clock()
        if reply is None:
            raise DriveError(f"moteus id {args.id}: no reply")
        values = reply.values
        if values[registers.mode] in registers.halted:
            raise DriveError(f"moteus id {args.id}: mode {values[registers.mode]} (fault or position timeout), "
                             f"fault code {values[registers.fault]}, after {len(log.stamps_s)} rows")
        stamp = (sent + received) / 2.0 - start
        if stamp >= 0.0:
            writer.writerow([repr(stamp), repr(2.0 * math.pi * float(values[registers.position])),
                             *(repr(float(values[key])) for key in (registers.q_current, registers.velocity,
                                                                     registers.temperature)),
                             int(values[registers.fault]), int(values[registers.mode]), repr(received - sent)])
            log.stamps_s.append(stamp)
            log.round_trips_s.append(received - sent)


async def run(stream: Any, connect: Callable[[int], tuple[Any, Registers]], args: argparse.Namespace,
              clock: Callable[[], float] = time.perf_counter) -> Log:
    """Read the drive's configuration on moteus's diagnostic ``stream``, ``connect`` (a controller querying the
    commutation source's registers), log (`record`) into --out with the motor stopped on every way out, and write
    the mapping."""
    pole_pairs = await config_value(stream, "motor.poles") / 2.0
    if pole_pairs < 1 or pole_pairs != int(pole_pairs):
        raise DriveError(f"motor.poles = {2 * pole_pairs:g}: not an even number of poles (calibrate the motor first)")
    ratio = await config_value(stream, "motor_position.rotor_to_output_ratio")
    controller, registers = connect(int(await config_value(stream, "motor_position.commutation_source")))
    if await config_value(stream, "motor.cogging_dq_scale") != 0.0:
        print("note: motor.cogging_dq_scale is not 0: in position mode the drive adds its cogging table to the q "
              "current, and the logged q current holds it", file=sys.stderr)
    motor = Motor(int(pole_pairs), args.slots, args.counts_per_rev, args.inertia_kgm2, args.torque_constant)
    args.out.mkdir(parents=True, exist_ok=True)
    log = Log()
    try:
        await controller.set_stop()  # clears a latched position timeout
        with open(args.out / LOG_FILE, "w", newline="") as out:
            await record(controller, registers, args.speed_hz * ratio, args, out, log, clock)
    finally:
        await controller.set_stop()
        (args.out / MAPPING_FILE).write_text(mapping_text(motor, log.round_trips_s))
        print(log.summary(args.out / LOG_FILE), file=sys.stderr)
    return log


def main(argv: Sequence[str] | None = None) -> int:
    args = parse_args(argv)
    import moteus

    def connect(source: int) -> tuple[Any, Registers]:
        registers = Registers.of(moteus.Register, moteus.Mode, source)
        query = moteus.QueryResolution()
        query.q_current = query.temperature = moteus.F32
        query._extra = {registers.position: moteus.F32, registers.velocity: moteus.F32}
        return moteus.Controller(id=args.id, query_resolution=query), registers

    try:
        asyncio.run(run(moteus.Stream(moteus.Controller(id=args.id)), connect, args))
    except DriveError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"interrupted: the motor is stopped, {args.out / LOG_FILE} holds the rows logged", file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
