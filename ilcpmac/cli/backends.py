"""``ilcpmac backends``: the backends installed, each with a one-line description."""

from __future__ import annotations

from rich.table import Table

from ilcpmac.cli import main


@main.command()
def backends() -> None:
    """List the backends ilcpmac run --backend may name.

    They are registered in the entry-point group ilcpmac.backends.
    """
    # imported when the command runs (ilcpmac.cli's docstring says why)
    from rich.console import Console
    from rich.markup import escape

    from ilcpmac.backends.registry import GROUP, installed_backends

    table = Table(title=f"backends (entry-point group {GROUP})", title_justify="left", header_style="bold")
    for column in ("name", "distribution", "description"):
        table.add_column(column)
    for name, entry in sorted(installed_backends().items()):
        table.add_row(name, entry.distribution + (" (built-in)" if entry.distribution == "ilcpmac" else ""),
                      escape(entry.description()))
    Console().print(table)
