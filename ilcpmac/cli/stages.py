"""``ilcpmac stages``: the compensation stages installed, and where each comes from."""

from __future__ import annotations

from rich import box
from rich.table import Table
from rich.text import Text

from ilcpmac.cli import main


@main.command()
def stages() -> None:
    """List the stages a config's [pipeline] may name.

    With what each does and where it comes from (entry-point group ilcpmac.stages).
    """
    # imported when the command runs (ilcpmac.cli's docstring says why)
    from rich.console import Console

    from ilcpmac.stages.registry import GROUP, installed_stages

    table = Table(title=f"stages (entry-point group {GROUP})", title_justify="left", header_style="bold",
                  box=box.SIMPLE_HEAD, pad_edge=False)
    table.add_column("stage", no_wrap=True)
    table.add_column("what it does; factory (distribution)", overflow="fold")
    for name, entry in sorted(installed_stages().items()):
        origin = "built-in" if entry.distribution == "ilcpmac" else entry.distribution
        table.add_row(name, Text.assemble(entry.description(), "\n", (f"{entry.value} ({origin})", "dim")))
    Console().print(table)
