"""The folders ``ilcpmac identify`` takes besides a bench folder, each told by the file that makes it one: a standstill
scan (docs/standstill.md), a rolling log kept row by row (docs/rolling-logs.md), a drive's own holding maps
(docs/drive-maps.md). The command and `ilcpmac.api.identify` dispatch through `folder_kind` alone."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ilcpmac.bench.holding_map import MAP_FILE
from ilcpmac.bench.rolling import ROLLING_FILE
from ilcpmac.bench.standstill import SCAN_FILE

__all__ = ["FOLDER_KINDS", "FolderKind", "folder_kind"]


def _scan(folder: Path) -> Any:
    from ilcpmac.bench.standstill import read_scan, reduce_scan

    return reduce_scan(read_scan(folder))


def _identify_scan(folder: Path, output: Path) -> tuple[Any, list[str]]:
    from ilcpmac.bench.standstill import identify_scan

    return identify_scan(folder, output)


def _rolling(folder: Path) -> Any:
    # numba and the fit: only when it runs
    from ilcpmac.bench.rolling import read_rolling
    from ilcpmac.identify.rolling import estimate_rolling, rolling_result

    return rolling_result(estimate_rolling(read_rolling(folder)))


def _identify_rolling(folder: Path, output: Path) -> tuple[Any, list[str]]:
    from ilcpmac.identify.rolling import identify_rolling

    return identify_rolling(folder, output)


def _maps(folder: Path) -> Any:
    from ilcpmac.bench.holding_map import read_holding_maps
    from ilcpmac.identify.map_decomposition import decompose_map

    return decompose_map(read_holding_maps(folder), str(folder))


def _identify_maps(folder: Path, output: Path) -> tuple[Any, list[str]]:
    from ilcpmac.identify.map_decomposition import identify_map

    return identify_map(folder, output)


@dataclass(frozen=True)
class FolderKind:
    """One kind of folder ``ilcpmac identify`` takes.

    Attributes
    ----------
    marker : the file that makes a folder one.
    what : its name in words, e.g. "a standstill scan folder".
    result : its result, written nowhere (the API's): a record with ``messages`` and ``to_json()``.
    identify : the command's: the result JSON written to the output path, the result and the lines to print.
    """

    marker: str
    what: str
    result: Callable[[Path], Any]
    identify: Callable[[Path, Path], tuple[Any, list[str]]]


FOLDER_KINDS = (FolderKind(SCAN_FILE, "a standstill scan folder", _scan, _identify_scan),
                FolderKind(ROLLING_FILE, "a rolling folder", _rolling, _identify_rolling),
                FolderKind(MAP_FILE, "a holding-map folder", _maps, _identify_maps))


def folder_kind(folder: Path) -> FolderKind | None:
    """The kind of ``folder`` by the file it holds, or None (a bench folder)."""
    return next((kind for kind in FOLDER_KINDS if (folder / kind.marker).exists()), None)
