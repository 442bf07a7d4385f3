"""``ilcpmac stages``: the compensation stages installed, and where each comes from."""

from __future__ import annotations

from rich.table import Table

from ilcpmac.cli import main


@main.command()
def stages() -> None:
    """List the stages a config's [pipeline] may name (entry-point group ilcpmac.stages)."""
    from rich.console import Console

    from ilcpmac.stages.registry import GROUP, installed_stages

    table = Table(title=f"stages (entry-point group {GROUP})", title_justify="left", header_style="bold")
    for column in ("name", "distribution", "factory"):
        table.add_column(column)
    for name, entry in sorted(installed_stages().items()):
        table.add_row(name, entry.distribution + (" (built-in)" if entry.distribution == "ilcpmac" else ""),
                      entry.value)
    Console().print(table)
