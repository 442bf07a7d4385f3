"""Plugins found through entry points: compensation stages (``ilcpmac.stages``) and backends
(``ilcpmac.backends``), built-in ones registered exactly as a third party's."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from importlib.metadata import entry_points
from typing import Any

__all__ = ["PluginEntry", "installed"]


@dataclass(frozen=True)
class PluginEntry:
    """An installed plugin: its entry-point group and name, where it comes from, and how to load it."""

    group: str
    name: str
    value: str
    distribution: str

    def load(self) -> Any:
        """Import the factory (its import error propagates: the caller says what failed to load)."""
        (ep,) = entry_points(group=self.group, name=self.name)
        return ep.load()

    def description(self) -> str:
        """What the plugin does, in one line: the first line of its factory's docstring, else of the module
        that defines the factory; why it cannot be loaded if it cannot."""
        try:
            factory = self.load()
        except Exception as e:  # a broken plugin is listed, not fatal
            return f"fails to load: {type(e).__name__}: {e}"
        module = sys.modules.get(getattr(factory, "__module__", ""))
        for doc in (getattr(factory, "__doc__", None), getattr(module, "__doc__", None)):
            if doc and doc.strip():
                first: str = doc.strip().splitlines()[0]
                return first
        return "(no description)"


def installed(group: str) -> dict[str, PluginEntry]:
    """Every plugin of entry-point ``group``, by name."""
    return {ep.name: PluginEntry(group, ep.name, ep.value, ep.dist.name if ep.dist is not None else "?")
            for ep in entry_points(group=group)}
