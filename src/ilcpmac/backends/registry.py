"""Backend discovery: factories registered in the entry-point group ``ilcpmac.backends``.

The built-in backends (``sim``, ``remote``) register there too (see
pyproject.toml), so ``ilcpmac run --backend NAME`` picks a third-party backend
exactly as it picks a built-in one. A factory is ``factory(setup: BackendSetup)
-> Backend``; the first line of its docstring describes it in ``ilcpmac backends``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from ilcpmac.backends.base import Backend
from ilcpmac.config import CampaignConfig
from ilcpmac.core.errors import ConfigError
from ilcpmac.core.plugins import PluginEntry, installed

GROUP = "ilcpmac.backends"


@dataclass(frozen=True)
class BackendSetup:
    """What a backend factory is given.

    Attributes
    ----------
    config : the campaign config (its [bench], [limits] and [trials]; `CampaignConfig.sampled_model` and
        `CampaignConfig.recorded_counts_per_rev` for a simulator).
    address : where the bench is (``--address``), for backends that need one; None if not given.
    options : the backend's own ``[backends.NAME]`` table of the config, as read (the backend parses and checks
        it, with the schema kit, before any motion); empty if the config has none.
    write_config : the user's word that the backend may write the drive's flash (``--write-config``).
    """

    config: CampaignConfig
    address: str | None = None
    options: dict = field(default_factory=dict)
    write_config: bool = False

    def refuse_options(self, name: str) -> None:
        """`ConfigError` naming the first key of ``options`` for a backend ``name`` that takes none (a misspelt
        option of it must not pass unseen)."""
        if self.options:
            key = sorted(self.options)[0]
            raise ConfigError(f"{self.config.path}: [backends.{name}] {key}: the {name} backend takes no options")


def installed_backends() -> dict[str, PluginEntry]:
    """Every backend in the entry-point group, by name."""
    return installed(GROUP)


def build_backend(name: str, setup: BackendSetup) -> Backend:
    """The backend ``name`` built for ``setup``; an unknown name, a broken plugin or a factory that returns
    something other than a `Backend` raises `ConfigError`."""
    available = installed_backends()
    if name not in available:
        raise ConfigError(f"--backend: no backend named {name!r} is installed "
                          f"(installed: {', '.join(sorted(available))})")
    try:
        factory = available[name].load()
    except Exception as e:  # a broken plugin must not crash the command with a traceback
        raise ConfigError(f"--backend {name}: failed to load {available[name].value} ({type(e).__name__}: {e})") \
            from None
    backend = factory(setup)
    if not isinstance(backend, Backend):
        missing = [m for m in ("describe", "run_trial", "close", "max_parallel_trials") if not hasattr(backend, m)]
        raise ConfigError(f"--backend {name}: {available[name].value} returned a {type(backend).__name__}, which "
                          f"lacks {', '.join(missing)} of the Backend protocol")
    return backend
