"""The import contract (.importlinter, run by ``lint-imports`` in CI) covers every module of the package.

import-linter checks the modules its layers name; a module outside every layer would escape it.
"""

from __future__ import annotations

import configparser
import pkgutil
from pathlib import Path

import ilcpmac

CONTRACT = Path(__file__).resolve().parents[1] / ".importlinter"


def layers() -> list[list[str]]:
    """The layers of the layers contract, top to bottom, each a list of its modules."""
    parser = configparser.ConfigParser()
    parser.read(CONTRACT)
    lines = parser["importlinter:contract:layers"]["layers"].split("\n")
    return [[name.strip() for name in line.split("|")] for line in lines if line.strip()]


def test_every_module_of_the_package_lies_in_exactly_one_layer():
    roots = [name for layer in layers() for name in layer]
    modules = [m.name for m in pkgutil.walk_packages(ilcpmac.__path__, "ilcpmac.")]
    placed = {m: [r for r in roots if m == r or m.startswith(r + ".")] for m in modules}
    assert {m: rs for m, rs in placed.items() if len(rs) != 1} == {}


def test_the_core_is_the_lowest_layer():
    assert layers()[-1] == ["ilcpmac.core"]


def test_the_api_is_the_layer_right_below_the_cli():
    """ilcpmac.api, the public facade, may import every layer but the CLI's; only the CLI may import it
    (docs/architecture.md)."""
    names = [layer[0] for layer in layers()]
    assert names.index("ilcpmac.api") == names.index("ilcpmac.cli") + 1
