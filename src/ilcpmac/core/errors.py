"""The project's errors: each names the file, line or key at fault.

The CLI prints ``str(error)`` on one line and exits with status 2.
"""


class IlcpmacError(Exception):
    """Base class of every error the CLI reports without a traceback."""


class ConfigError(IlcpmacError):
    """A campaign configuration (TOML) is missing a key, has an unknown key or a bad value."""


class BenchFormatError(IlcpmacError):
    """A bench folder does not follow docs/bench-format.md."""


class SimulationError(IlcpmacError):
    """The simulator was asked for something it cannot run."""


class IdentificationError(IlcpmacError):
    """The data cannot support an estimate; the message says which and why."""


class BackendError(IlcpmacError):
    """A backend cannot run a trial: refused request, unreachable target, broken protocol."""


class SafetyError(IlcpmacError):
    """A request would break the safety limits, or a stage produced an invalid one; nothing was sent."""


class OptionError(IlcpmacError):
    """An option or argument (of a simulated log or scan, or of an ``ilcpmac.api`` function) is unknown, of the
    wrong type or out of its range: ``name``, ``why``."""

    def __init__(self, name: str, why: str) -> None:
        super().__init__(f"{name}: {why}")
        self.name, self.why = name, why


class StageError(IlcpmacError):
    """A stage raised, returned something the pipeline refuses, or did not return in time; the message names it."""
