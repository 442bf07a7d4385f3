"""Stage discovery: factories registered in the entry-point group ``ilcpmac.stages``.

The built-in stages register there too (see pyproject.toml), so a config names
a third-party stage exactly as it names a built-in one.
"""

from __future__ import annotations

from typing import Callable

from ilcpmac.config import CampaignConfig
from ilcpmac.core.errors import ConfigError
from ilcpmac.core.plugins import PluginEntry, installed
from ilcpmac.stages.base import Stage, StageSetup, check_options, parse_options

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


def check_options_of(name: str, factory: Callable[[StageSetup], Stage], options: dict) -> None:
    """Check stage ``name``'s ``[stages.NAME]`` ``options`` against what its factory declares, before any stage is
    built: ``options_schema``, a dataclass declared with the schema kit (`parse_options`); or, as plugins of
    earlier releases declare them, ``option_defaults`` (a dict of every key's default: an unknown key or a wrong
    type is refused) and optionally ``option_ranges`` (key -> (check, doc), `check_options`). A factory that
    declares none checks its options when it is built, after the identification grid."""
    schema = getattr(factory, "options_schema", None)
    if schema is not None:
        parse_options(options, schema, name)
        return
    defaults = getattr(factory, "option_defaults", None)
    if defaults is not None:
        check_options(options, defaults, getattr(factory, "option_ranges", {}), name)


def check_stage_options(config: CampaignConfig,
                        extra: dict[str, Callable[[StageSetup], Stage]] | None = None) -> None:
    """`check_options_of` every stage of ``config``'s ``[pipeline] stages`` (installed, or in ``extra``);
    `ConfigError` names the file."""
    available = installed_stages()
    for name in config.pipeline.stages:
        try:
            check_options_of(name, _factory(name, available, extra or {}), config.stage_options.get(name, {}))
        except ConfigError as e:
            raise ConfigError(f"{config.path}: {e}") from None
