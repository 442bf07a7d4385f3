"""Stage discovery: factories registered in the entry-point group ``ilcpmac.stages``.

The built-in stages register there too (see pyproject.toml), so a config names
a third-party stage exactly as it names a built-in one.
"""

from __future__ import annotations

from typing import Any, Callable

from ilcpmac.errors import ConfigError
from ilcpmac.model.motor import shown
from ilcpmac.plugins import PluginEntry, installed
from ilcpmac.stages.base import Stage, StageSetup, read_options

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


def check_options(options: dict, defaults: dict[str, Any], ranges: dict[str, tuple[Callable, str]],
                  stage: str) -> dict[str, Any]:
    """A stage's options over its defaults (`read_options`), each within its range.

    ``ranges`` maps a key to ``(check, doc)``; a value its check refuses raises
    `ConfigError` naming ``[stages.NAME] key``.
    """
    values = read_options(options, defaults, stage)
    for key, (check, doc) in ranges.items():
        if not check(values[key]):
            raise ConfigError(f"[stages.{stage}] {key}: invalid value {shown(values[key])} ({doc})")
    return values


def check_builtin_options(name: str, options: dict) -> None:
    """Check the options of stage ``name`` if it is a built-in one, before any stage is built.

    A campaign config is checked when it is read, not after the identification;
    other stages check their options when they are built.
    """
    from ilcpmac.stages import cogging, ilc, replay, sensor  # they import this module

    builtin = {"ilc": ilc, "cogging": cogging, "current-sensor": sensor, "replay": replay}
    if name in builtin:
        check_options(options, builtin[name].DEFAULTS, builtin[name].RANGES, name)
