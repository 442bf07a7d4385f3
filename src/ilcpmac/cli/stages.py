"""``ilcpmac stages``: the compensation stages installed, and where each comes from."""

from __future__ import annotations

from ilcpmac.cli import main, plugins_table


@main.command()
def stages() -> None:
    """List the stages a config's [pipeline] may name.

    With what each does and where it comes from (entry-point group ilcpmac.stages).
    """
    # imported when the command runs (ilcpmac.cli's docstring says why)
    from rich.console import Console

    from ilcpmac.stages.registry import GROUP, installed_stages

    table = plugins_table("stages", GROUP, installed_stages())
    Console().print(table)
