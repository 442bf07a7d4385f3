"""[backends.moteus] and [backends.moteus.emulated]: the moteus backend's options (docs/moteus.md), declared on the
schema kit and checked before anything connects."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from ilcpmac.core.errors import ConfigError
from ilcpmac.core.schema import in_range, parse_section, setting, unknown_key
from ilcpmac.sim.moteus_drive import DriveSpec

__all__ = ["EmulatedLink", "MoteusSettings", "SECTION", "TRANSPORTS", "parse_settings"]

#: the table of the config that holds the options
SECTION = "backends.moteus"
#: how the host reaches the drive: this process's emulated moteus, or one of the moteus library's transports
TRANSPORTS = ("emulated", "fdcanusb", "pi3hat", "socketcan")


@dataclass(frozen=True)
class EmulatedLink:
    """The emulated bus's part of [backends.moteus.emulated] (the rest is the drive's `DriveSpec`)."""

    round_trip_s: float = setting(in_range(0.0, 0.01), "one transaction's round trip, command to reply (CAN-FD "
                                  "through an fdcanusb: about 0.2 ms), s, within [0, 0.01]", 2e-4)
    jitter_s: float = setting(in_range(0.0, 0.01), "a round trip's random extra, uniform in [0, jitter_s], s", 5e-5)
    seed: int = setting(in_range(0, 2**32 - 1), "seed of the jitter and of the emulated drive's own random draws",
                        0)


@dataclass(frozen=True)
class MoteusSettings:
    """[backends.moteus]: which controller, through which transport, polled how (optional; defaults shown); ``link``
    and ``drive`` come from [backends.moteus.emulated] (the emulated transport only)."""

    id: int = setting(in_range(1, 126), "the controller's CAN id (its id.id), within [1, 126]", 1)
    transport: str = setting(
        lambda x: x in TRANSPORTS, '"fdcanusb" (mjbots\' USB adapter), "pi3hat" (its Raspberry Pi hat; needs '
        'moteus_pi3hat), "socketcan" (a Linux CAN interface, through python-can) or "emulated" (this process\'s '
        "emulated moteus on the config's [simulator] motor, [backends.moteus.emulated])", "fdcanusb")
    device: str | None = setting(lambda x: 0 < len(x) <= 256, "fdcanusb: its serial port (left out: the one the "
                                 "library finds); socketcan: the interface (left out: can0)", None)
    query_rate_hz: float = setting(in_range(10.0, 4000.0), "the host's polling rate while a trial runs (each poll "
                                   "renews the velocity command and reads the drive), Hz, within [10, 4000]", 1000.0)
    watchdog_timeout_s: float = setting(in_range(0.005, 1.0), "the drive stops by itself when no command came for "
                                        "this long (the command's watchdog_timeout), s, within [0.005, 1]", 0.1)
    poll_timeout_s: float = setting(in_range(1e-4, 1.0), "the longest wait for one poll's reply; later, the poll "
                                    "counts as lost, s, within [1e-4, 1]", 0.01)
    max_lost_polls: int = setting(in_range(1, 10_000), "consecutive unanswered polls that mean a lost connection "
                                  "(the trial stops and fails)", 20)
    console_timeout_s: float = setting(in_range(0.05, 30.0), "the longest wait for the answer of one console "
                                       "command (conf get, conf set, conf write), s, within [0.05, 30]", 2.0)
    link: EmulatedLink = dataclasses.field(default=EmulatedLink(), metadata={"doc": "[backends.moteus.emulated]"})
    drive: DriveSpec = dataclasses.field(default=DriveSpec(), metadata={"doc": "[backends.moteus.emulated]"})


def parse_settings(options: dict, source: str) -> MoteusSettings:
    """[backends.moteus] (``options``, as the config read it, from file ``source``) with its sub-table
    [backends.moteus.emulated]; every problem is a `ConfigError` naming the file, the table and the key."""
    if not isinstance(options, dict):
        raise ConfigError(f"{source}: [{SECTION}] must be a table")
    table = dict(options)
    emulated = table.pop("emulated", None)
    link, drive = (EmulatedLink(), DriveSpec()) if emulated is None else _emulated(emulated, source)
    settings = parse_section(table, MoteusSettings, source, SECTION, given={"link": link, "drive": drive})
    if emulated is not None and settings.transport != "emulated":
        raise ConfigError(f"{source}: [{SECTION}.emulated] configures the emulated moteus, but [{SECTION}] "
                          f"transport is {settings.transport!r}")
    return settings


def _emulated(table: object, source: str) -> tuple[EmulatedLink, DriveSpec]:
    section = f"{SECTION}.emulated"
    if not isinstance(table, dict):
        raise ConfigError(f"{source}: [{section}] must be a table")
    link_keys = [f.name for f in dataclasses.fields(EmulatedLink)]
    drive_keys = [f.name for f in dataclasses.fields(DriveSpec)]
    problem = unknown_key(table, link_keys + drive_keys)
    if problem is not None:
        raise ConfigError(f"{source}: [{section}] {problem}")
    link = parse_section({k: v for k, v in table.items() if k in link_keys}, EmulatedLink, source, section)
    spec = parse_section({k: v for k, v in table.items() if k in drive_keys}, DriveSpec, source, section)
    return link, spec
