"""Stage discovery: factories registered in the entry-point group ``ilcpmac.stages``.

The built-in stages register there too (see pyproject.toml), so a config names
a third-party stage exactly as it names a built-in one.
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import Callable

from ilcpmac.errors import ConfigError
from ilcpmac.stages.base import Stage, StageSetup

GROUP = "ilcpmac.stages"


@dataclass(frozen=True)
class StageEntry:
    """An installed stage: its name, where it comes from, and how to load it."""

    name: str
    value: str
    distribution: str

    def load(self) -> Callable[[StageSetup], Stage]:
        """Import the factory."""
        (ep,) = entry_points(group=GROUP, name=self.name)
        return ep.load()


def installed_stages() -> dict[str, StageEntry]:
    """Every stage in the entry-point group, by name."""
    found = {}
    for ep in entry_points(group=GROUP):
        dist = ep.dist.name if ep.dist is not None else "?"
        found[ep.name] = StageEntry(ep.name, ep.value, dist)
    return found


def build_stages(names: list[str], setups: dict[str, StageSetup],
                 extra: dict[str, Callable[[StageSetup], Stage]] | None = None) -> list[Stage]:
    """Build the named stages in order; an unknown name or a broken plugin raises `ConfigError`.

    ``extra`` maps names to factories defined in the calling script (they take
    precedence over installed stages), for stages that are not packaged.
    """
    available = installed_stages()
    extra = extra or {}
    stages = []
    for name in names:
        if name not in available and name not in extra:
            raise ConfigError(f"[pipeline] stages: no stage named {name!r} is installed "
                              f"(installed: {', '.join(sorted(available))})")
        try:
            factory = extra[name] if name in extra else available[name].load()
        except Exception as e:  # a plugin that fails to import must not crash the run with a traceback
            raise ConfigError(f"[pipeline] stages: stage {name!r} failed to load: {e}") from None
        stage = factory(setups[name])
        if not isinstance(stage, Stage):
            raise ConfigError(f"[pipeline] stages: {name!r} does not implement the Stage protocol")
        stages.append(stage)
    return stages
