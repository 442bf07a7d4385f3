"""The ``ilcpmac`` command line: one module per command, registered here.

A command imports what it runs inside its function, not at the top of its module: numpy reads its thread
count when first imported, after `tune_process` has set it, and listing or starting one command does not
import the numba kernels, scipy, pyarrow, matplotlib or dask that another needs.
"""

from __future__ import annotations

import atexit
import errno
import os
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any, NoReturn

import click
from rich import box
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table
from rich.text import Text

from ilcpmac.core.errors import IlcpmacError
from ilcpmac.core.plugins import PluginEntry
from ilcpmac.core.runtime import tune_process

#: progress and messages go to stderr; results (tables) may go to stdout
console = Console(stderr=True)

#: ilcpmac.plotting.FORMATS, named here so that starting any command does not import matplotlib
FIGURE_FORMATS = ("png", "svg", "pdf")


#: errors of the file system rather than of the program: a full disk, a quota, a read-only place
_FILE_SYSTEM_ERRORS = {errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM}


def _usage_error(error: click.UsageError) -> NoReturn:
    """Report a usage error (an unknown command or option, a missing argument, a bad value) as one line on stderr,
    with the command whose ``--help`` says more, and exit with its status (2)."""
    message = " ".join(line.strip() for line in error.format_message().splitlines() if line.strip()).rstrip(".")
    see = "" if error.ctx is None else f" (see {error.ctx.command_path} --help)"
    click.echo(f"error: {message[:1].lower()}{message[1:]}{see}", err=True)
    sys.exit(error.exit_code)


class _Command(click.Command):
    """A command whose campaign config (its parameter ``config``) may name a packaged config from any folder
    (`ilcpmac.config.config_path`): the one taken is said on stderr before the command runs."""

    def invoke(self, ctx: click.Context):
        given = ctx.params.get("config")
        if isinstance(given, Path):
            from ilcpmac.config import config_path  # after tune_process: it imports numpy

            taken = config_path(given)
            if taken != given:
                click.echo(f"config: {given} is not here: the packaged {taken}", err=True)
                ctx.params["config"] = taken
        return super().invoke(ctx)


class _Group(click.Group):
    """Reports an `IlcpmacError`, or a file system's refusal (a path that cannot be made or written, a full
    disk, a quota, a read-only place), as one line on stderr and exit status 2, never a traceback; and so a usage
    error of the group or any command (`_usage_error`). Its commands are `_Command`s."""

    command_class = _Command

    def make_context(self, info_name: str | None, args: list[str], parent: click.Context | None = None,
                     **extra: Any) -> click.Context:
        if not args:  # no command: the help, as click writes it
            return super().make_context(info_name, args, parent, **extra)
        try:
            return super().make_context(info_name, args, parent, **extra)
        except click.UsageError as e:
            _usage_error(e)

    def invoke(self, ctx: click.Context):
        try:
            return super().invoke(ctx)
        except click.UsageError as e:
            _usage_error(e)
        except IlcpmacError as e:
            click.echo(f"error: {e}", err=True)
            sys.exit(2)
        except OSError as e:
            if e.filename is None and e.errno not in _FILE_SYSTEM_ERRORS:
                raise
            click.echo(f"error: {e.filename}: {e.strerror}" if e.filename else f"error: {e.strerror}", err=True)
            sys.exit(2)
        except KeyboardInterrupt:  # a command that can be continued says how itself (run, sweep)
            click.echo("error: interrupted", err=True)
            sys.exit(130)


def plugins_table(kind: str, group: str, entries: dict[str, PluginEntry]) -> Table:
    """The table ``ilcpmac stages`` and ``ilcpmac backends`` print: per installed plugin of entry-point ``group``,
    its name, what it does and, dimmed under it, its factory and where it comes from."""
    table = Table(title=f"{kind} (entry-point group {group})", title_justify="left", header_style="bold",
                  box=box.SIMPLE_HEAD, pad_edge=False)
    table.add_column(kind.rstrip("s"), no_wrap=True)
    table.add_column("what it does; factory (distribution)", overflow="fold")
    for name, entry in sorted(entries.items()):
        origin = "built-in" if entry.distribution == "ilcpmac" else entry.distribution
        table.add_row(name, Text.assemble(entry.description(), "\n", (f"{entry.value} ({origin})", "dim")))
    return table


@contextmanager
def progress_bar() -> Iterator[Progress]:
    """A rich progress bar on stderr, started for the ``with`` block, that leaves nothing behind when the work in it
    fails: the error is then the command's one line."""
    progress = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                        TimeElapsedColumn(), console=console, transient=False)
    with progress:
        try:
            yield progress
        except BaseException:
            progress.live.transient = True
            progress.live.stop()
            progress.disable = True  # its stop() would print the bar's last line (or a blank one, off a terminal)
            raise


@click.group(cls=_Group)
@click.version_option(package_name="ilcpmac")
def main() -> None:
    """Identify and compensate the torque ripple of PM AC motors (Grassens 2009 and beyond)."""
    tune_process()


def entry_point() -> NoReturn:
    """The ``ilcpmac`` executable and ``python -m ilcpmac``: `main`, then an exit that does not tear down the
    interpreter's objects one by one.

    After a campaign the process holds hundreds of megabytes of objects besides the libraries' modules, and a
    normal exit frees each: 0.45 s of the one-speed campaign's 5 (docs/campaign.md, "Wall time"). Once the
    command has returned, every file it wrote is closed (a run directory is written and synced before its
    command returns), so the output streams are flushed, the exit handlers run and the process ends with the
    command's status (`os._exit`, as mypy ends). While a thread that is no daemon still runs, for a status that
    is no number, or when the streams cannot be flushed (a closed pipe), the exit is Python's own.
    """
    try:
        main(prog_name="ilcpmac")
        status: int | None = 0
    except SystemExit as e:
        if not (e.code is None or isinstance(e.code, int)) or any(
                not t.daemon for t in threading.enumerate() if t is not threading.main_thread()):
            raise
        status = e.code
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):
        sys.exit(status)
    atexit._run_exitfuncs()
    os._exit(status or 0)


# Each command lives in its own module and registers itself on `main` when imported.
from ilcpmac.cli import (  # noqa: E402
    backends,  # noqa: E402,F401
    emulate,  # noqa: E402,F401
    export,  # noqa: E402,F401
    identify,  # noqa: E402,F401
    import_,  # noqa: E402,F401
    report,  # noqa: E402,F401
    run,  # noqa: E402,F401
    simulate,  # noqa: E402,F401
    stages,  # noqa: E402,F401
    sweep,  # noqa: E402,F401
)
