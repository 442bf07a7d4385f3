"""Stage discovery: factories registered in the entry-point group ``ilcpmac.stages``.

The built-in stages register there too (see pyproject.toml), so a config names
a third-party stage exactly as it names a built-in one.
"""

from __future__ import annotations

from typing import Callable

from ilcpmac.config import CampaignConfig
from ilcpmac.core.errors import ConfigError
from ilcpmac.core.plugins import PluginEntry, installed
from ilcpmac.stages import cogging, ilc, replay, sensor
from ilcpmac.stages.base import Stage, StageSetup, check_options

GROUP = "ilcpmac.stages"


def installed_stages() -> dict[str, PluginEntry]:
    """Every stage in the entry-point group, by name."""
    return installed(GROUP)


def _factory(name: str, available: dict[str, PluginEntry],
             extra: dict[str, Callable[[StageSetup], Stage]]) -> Callable[[StageSetup], Stage]:
    """Stage ``name``'s factory from ``extra`` or the installed stages; `ConfigError` if it has none."""
    if name not in available and name not in extra:
        raise ConfigError(f"[pipeline] stages: no stage named {name!r} is installed "
                          f"(installed: {', '.join(sorted(available))})")
    try:
        return extra[name] if name in extra else available[name].load()
    except Exception as e:  # a plugin that fails to import must not crash the run with a traceback
        raise ConfigError(f"[pipeline] stages: stage {name!r} failed to load: {e}") from None


def stage_needs(names: list[str], extra: dict[str, Callable[[StageSetup], Stage]] | None = None
                ) -> dict[str, tuple[str, ...]]:
    """What each named stage needs from the identification beyond `PIPELINE_NEEDS`: its factory's ``needs``."""
    available = installed_stages()
    return {name: tuple(getattr(_factory(name, available, extra or {}), "needs", ())) for name in names}


def build_stages(names: list[str], setups: dict[str, StageSetup],
                 extra: dict[str, Callable[[StageSetup], Stage]] | None = None) -> list[Stage]:
    """Build the named stages in order; an unknown name or a broken plugin raises `ConfigError`.

    ``extra`` maps names to factories defined in the calling script (they take
    precedence over installed stages), for stages that are not packaged.
    """
    available = installed_stages()
    stages = []
    for name in names:
        stage = _factory(name, available, extra or {})(setups[name])
        if not isinstance(stage, Stage):
            raise ConfigError(f"[pipeline] stages: {name!r} does not implement the Stage protocol")
        stages.append(stage)
    return stages


#: the built-in stages' modules, whose options are declared (DEFAULTS, RANGES) apart from their classes
_BUILTIN = {"ilc": ilc, "cogging": cogging, "current-sensor": sensor, "replay": replay}


def check_builtin_options(name: str, options: dict) -> None:
    """Check the options of stage ``name`` if it is a built-in one, before any stage is built.

    A campaign config is checked when it is read, not after the identification;
    other stages check their options when they are built.
    """
    if name in _BUILTIN:
        check_options(options, _BUILTIN[name].DEFAULTS, _BUILTIN[name].RANGES, name)


def check_stage_options(config: CampaignConfig) -> None:
    """`check_builtin_options` for every ``[stages.NAME]`` table of ``config``; `ConfigError` names the file."""
    for name, options in config.stage_options.items():
        try:
            check_builtin_options(name, options)
        except ConfigError as e:
            raise ConfigError(f"{config.path}: {e}") from None
