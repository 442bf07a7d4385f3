"""``ilcpmac emulate``: a bench target emulator serving the simulator over the bench protocol."""

from __future__ import annotations

import logging
import signal
import threading
from pathlib import Path

import click

from ilcpmac.cli import console, main

_FAULT_HELP = "N: on trial N only; N+: on trial N and every later one (trials counted as requests arrive)."


@main.command()
@click.option("--port", required=True, type=click.IntRange(0, 65535),
              help="TCP port to listen on (0: any free port; the address is printed).")
@click.option("--host", default="127.0.0.1", show_default=True, help="Address to listen on.")
@click.option("--config", "config", default=None, type=click.Path(dir_okay=False, path_type=Path),
              help="Campaign config whose drive ([bench] and [simulator.*]) is simulated "
                   "[default: the packaged seed-bench.toml].")
@click.option("--max-current", default=30.0, show_default=True, type=click.FloatRange(min=0, min_open=True),
              help="Current limit the target announces and enforces, A.")
@click.option("--max-torque", default=8.0, show_default=True, type=click.FloatRange(min=0, min_open=True),
              help="Torque limit the target announces and enforces, N m.")
@click.option("--max-speed", default=1.5, show_default=True, type=click.FloatRange(min=0, min_open=True),
              help="Speed limit the target announces and enforces, Hz (mechanical).")
@click.option("--chunk-samples", default=8192, show_default=True, type=click.IntRange(min=1),
              help="Samples per DATA frame.")
@click.option("--heartbeat", "heartbeat_s", default=1.0, show_default=True,
              type=click.FloatRange(min=0, min_open=True), help="HEARTBEAT interval while a trial runs, s.")
@click.option("--drop", metavar="N[+]", default=None, help=f"Close the connection mid-trial. {_FAULT_HELP}")
@click.option("--stall", metavar="N[+]", default=None, help=f"Go silent mid-trial. {_FAULT_HELP}")
@click.option("--stall-seconds", "stall_s", default=30.0, show_default=True, type=click.FloatRange(min=0),
              help="Length of a stall, s.")
@click.option("--corrupt", metavar="N[+]", default=None, help=f"Corrupt a DATA frame. {_FAULT_HELP}")
@click.option("--wrong-version", metavar="N[+]", default=None,
              help=f"Answer with protocol version + 1. {_FAULT_HELP}")
@click.option("--restart", metavar="N[+]", default=None,
              help=f"Reboot mid-trial: close all connections, forget them, listen again. {_FAULT_HELP}")
@click.option("--restart-delay", "restart_delay_s", default=0.5, show_default=True, type=click.FloatRange(min=0),
              help="How long a restart keeps the target unreachable, s.")
@click.option("--idle-timeout", "idle_timeout_s", default=20.0, show_default=True,
              type=click.FloatRange(min=0, min_open=True),
              help="Disconnect a client that sends no frame for this long (before HELLO or between trials), s.")
@click.option("--frame-timeout", "frame_timeout_s", default=10.0, show_default=True,
              type=click.FloatRange(min=0, min_open=True),
              help="Disconnect a client that takes longer to send a frame, or to take one sent to it, s.")
@click.option("--max-connections", default=4, show_default=True, type=click.IntRange(min=1),
              help="Connections open at once; a new one takes the slot of the oldest still before its HELLO "
                   "(closed), or, with none such, is answered ERROR BUSY and closed.")
@click.option("--pace", type=click.FloatRange(min=0, min_open=True), default=None,
              help="Play each trial back at this many times a bench's speed (1: as a bench records it, so a "
                   "client shows its progress) [default: as fast as the client takes it].")
@click.option("--max-samples", "max_trial_samples", default=None, type=click.IntRange(min=2),
              help="Largest trial (revolutions x counts per revolution); larger requests get LIMIT_EXCEEDED "
                   "[default: the bench format's 4194304 rows].")
def emulate(port: int, host: str, config: Path | None, max_current: float, max_torque: float, max_speed: float,
            chunk_samples: int, heartbeat_s: float, drop: str | None, stall: str | None, stall_s: float,
            corrupt: str | None, wrong_version: str | None, restart: str | None, restart_delay_s: float,
            idle_timeout_s: float, frame_timeout_s: float, max_connections: int, pace: float | None,
            max_trial_samples: int | None) -> None:
    """Serve the simulated drive of --config as a bench target.

    It speaks the bench protocol of docs/protocol.md.

    Prints "listening on HOST:PORT" on stdout once it accepts connections;
    runs until Ctrl-C or SIGTERM. One client controls it at a time: another
    gets ERROR BUSY.
    """
    # imported when the command runs (ilcpmac.cli's docstring says why)
    from rich.logging import RichHandler

    from ilcpmac.backends.base import BenchLimits
    from ilcpmac.backends.emulator import BenchEmulator, Fault, FaultPlan
    from ilcpmac.backends.simulated import SimulatorBackend
    from ilcpmac.config import load_config, packaged_config

    cfg = load_config(config or packaged_config("seed-bench.toml"))
    faults = FaultPlan(
        **{name: Fault.parse(spec) for name, spec in
           [("drop", drop), ("stall", stall), ("corrupt", corrupt), ("wrong_version", wrong_version),
            ("restart", restart)] if spec is not None},
        stall_s=stall_s)
    # DESCRIBE tells no count means (docs/protocol.md): the target records the edge of every line it samples
    backend = SimulatorBackend(cfg.sampled_model(), BenchLimits(max_current, max_torque, max_speed),
                               cfg.grid.warmup_revolutions)
    logging.basicConfig(level=logging.INFO, format="%(message)s",
                        handlers=[RichHandler(console=console, show_path=False)])
    limits = {} if max_trial_samples is None else {"max_trial_samples": max_trial_samples}
    emulator = BenchEmulator(backend, host, port, faults=faults, chunk_samples=chunk_samples, pace=pace,
                             heartbeat_s=heartbeat_s, restart_delay_s=restart_delay_s, idle_timeout_s=idle_timeout_s,
                             frame_timeout_s=frame_timeout_s, max_connections=max_connections, **limits).start()
    stopped = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stopped.set())
    click.echo(f"listening on {emulator.address}")
    try:
        while not stopped.wait(0.5):
            pass
    except KeyboardInterrupt:
        pass
    finally:
        emulator.stop()
    console.print(f"bench emulator stopped after {emulator.requests_received} trial requests")
