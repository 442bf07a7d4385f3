"""``ilcpmac backends``: the backends installed, each with a one-line description."""

from __future__ import annotations

from ilcpmac.cli import main, plugins_table


@main.command()
def backends() -> None:
    """List the backends ilcpmac run --backend may name.

    They are registered in the entry-point group ilcpmac.backends.
    """
    # imported when the command runs (ilcpmac.cli's docstring says why)
    from rich.console import Console

    from ilcpmac.backends.registry import GROUP, installed_backends

    table = plugins_table("backends", GROUP, installed_backends())
    Console().print(table)
