"""The moteus backend (docs/moteus.md): a moteus drive through mjbots' own library (``pip install 'ilcpmac[moteus]'``),
or an emulated one: `MoteusBackend` (ilcpmac.backends.moteus.backend), its options `MoteusSettings` (.settings),
and the emulated transport device `EmulatedMoteusDevice` (.emulated).

Only `from_setup`, the entry point, lives here: the package imports without the library, so that ``ilcpmac
backends`` lists the backend and ``--backend moteus`` says what to install where it is missing."""

from __future__ import annotations

from typing import TYPE_CHECKING

from ilcpmac.core.errors import ConfigError

if TYPE_CHECKING:
    from ilcpmac.backends.moteus.backend import MoteusBackend
    from ilcpmac.backends.registry import BackendSetup

__all__ = ["from_setup"]


def from_setup(setup: BackendSetup) -> MoteusBackend:
    """A moteus controller through mjbots' moteus library, or the emulated moteus ([backends.moteus])."""
    try:
        import moteus  # noqa: F401
    except ModuleNotFoundError:
        raise ConfigError("--backend moteus needs mjbots' moteus library, an optional extra: pip install "
                          "'ilcpmac[moteus]'") from None
    from ilcpmac.backends.moteus.backend import MoteusBackend

    return MoteusBackend.from_setup(setup)
