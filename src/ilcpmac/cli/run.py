"""``ilcpmac run``: the full campaign (identify, learn over the operating range, validate) with a live table
of the ripple."""

from __future__ import annotations

import math
import shlex
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

import click
from rich.console import Console, ConsoleOptions, RenderResult
from rich.live import Live
from rich.text import Text

from ilcpmac.cli import console, main

if TYPE_CHECKING:
    from ilcpmac.campaign.events import CampaignMessage, CampaignStart
    from ilcpmac.campaign.plan import CampaignPlan, Step
    from ilcpmac.campaign.record import TrialRecord

#: the live display's refreshes per second (one spinner frame each)
REFRESH_HZ = 4
_SPINNER = "⠋⠙⠹⠸⠼⠴⠦⠧⠇⠏"


def duration(seconds: float) -> str:
    """``seconds`` for people: "7.4 s", "3m05s", "2h07m"."""
    if seconds < 60:
        return f"{seconds:.1f} s"
    minutes = int(seconds // 60)
    return f"{minutes}m{int(seconds % 60):02d}s" if minutes < 60 else f"{minutes // 60}h{minutes % 60:02d}m"


class CampaignView:
    """The live display of ``ilcpmac run`` and the campaign's events (`CampaignEvents`): the table of trials
    laid out for the console's width, under it a status line with the trial running, how far it is where the
    backend reports it, its elapsed time, and what is left at most: the trials and the motor's running time
    (the plan's), and beside them the wall time (the trials left at the mean time of those so far: on the
    simulator far less than the motor's).

    Parameters
    ----------
    console : where messages go.
    plan : the campaign's plan.
    title : the table's title.
    records : the trials done so far; None when not yet known (a resume loads them).
    clock : seconds, monotonic.
    source : what the measured figures come from ([campaign] torque_source, resolved).
    """

    def __init__(self, console: Console, plan: CampaignPlan, title: str, records: list[TrialRecord] | None,
                 clock: Callable[[], float] = time.monotonic, source: str = "sensor") -> None:
        self.console = console
        self.plan = plan
        self.title = title
        self.source = source
        self.records = records
        self.clock = clock
        self.started_s = self.last_s = clock()
        #: wall seconds of each trial finished in this process, grid trials (run in parallel) apart
        self.seconds: dict[bool, list[float]] = {True: [], False: []}
        #: the fraction of the running trial done, as the backend last reported it; None if not reported
        self.fraction: float | None = None
        self.ended: str | None = None
        #: the plan's steps after the records they were derived from (`steps_left`)
        self._left: tuple[list[TrialRecord], list[Step]] | None = None

    def steps_left(self) -> list[Step]:
        """The plan's steps after the trials done (`CampaignPlan.steps_left`), derived once per trial finished:
        the status line, redrawn 4 times a second, reads them three times (about 10 ms each on the seed bench)."""
        assert self.records is not None
        if self._left is None or self._left[0] is not self.records:
            self._left = (self.records, self.plan.steps_left(self.records))
        return self._left[1]

    def trial(self, record: TrialRecord, records: list[TrialRecord]) -> None:
        """A trial finished."""
        now = self.clock()
        self.seconds[record.role == "grid"].append(now - self.last_s)
        self.last_s = now
        self.fraction = None
        self.records = list(records)

    def progress(self, fraction: float) -> None:
        """The running trial is ``fraction`` (0..1) done (from any thread); anything else is ignored."""
        if 0.0 <= fraction <= 1.0:
            self.fraction = fraction

    def message(self, message: CampaignMessage) -> None:
        """Say ``message`` above the display (`say`). The torque source chosen names the table's figures from then
        on."""
        from ilcpmac.campaign.events import TorqueSourceChosen

        if isinstance(message, TorqueSourceChosen):
            self.source = message.choice.source.value
        say(self.console, message)

    def end(self, how: str) -> None:
        """The campaign is over ("done", "stopped"): the status line says so from now on."""
        self.ended = how

    def time_left_s(self) -> float | None:
        """At most how long the campaign still runs: the plan's bound on the grid trials and the others left,
        each at the mean time of its kind so far in this process, the running trial at the pace of its
        progress where reported (which then stands for its kind until one has finished); None while a kind
        left has no time yet."""
        if self.records is None:
            return None
        grid_left = max(len(self.plan.grid) - len(self.records), 0)
        left = {True: grid_left, False: len(self.steps_left()) - grid_left}
        mean_s = {grid: sum(s) / len(s) for grid, s in self.seconds.items() if s}
        kind = grid_left > 0  # the running trial's
        correction_s = 0.0  # the running trial's time left, less the mean counted for it
        if self.fraction and left[kind]:
            elapsed_s = self.clock() - self.last_s
            mean_s.setdefault(kind, elapsed_s / self.fraction)
            correction_s = elapsed_s * (1.0 - self.fraction) / self.fraction - mean_s[kind]
        if any(n and grid not in mean_s for grid, n in left.items()):
            return None
        return sum(n * mean_s[grid] for grid, n in left.items() if n) + correction_s

    def motor_time_left_s(self, running: Step | None) -> float:
        """How long the motor still runs, at most: the plan's bench time of the steps left (`steps_left`), less
        the part of the ``running`` trial the backend reported done."""
        left = sum(self.plan.bench_seconds(step.request) for step in self.steps_left())
        if running is not None and self.fraction is not None:
            left -= self.fraction * self.plan.bench_seconds(running.request)
        return left

    def status(self, width: int = 80) -> str:
        """The status line, within ``width`` characters: the running trial's speed, then the trials done and
        the time elapsed, are left out if need be."""
        now = self.clock()
        elapsed = duration(now - self.started_s)
        if self.ended is not None:
            return f"{self.ended}: {len(self.records)} trials, {elapsed}" if self.records is not None else \
                f"{self.ended} after {elapsed}"
        if self.records is None:
            return f"{_SPINNER[0]} starting, {elapsed}"
        done = len(self.records)
        step = self.plan.next_step(self.records)
        speed = percent = ""
        if step is None:
            running = "writing the summary"
        else:
            if step.role == "grid":
                running = f"trial {done + 1}/{len(self.plan.grid)} grid"
            else:
                running = f"trial {done + 1} {step.role} {step.request.torque_setpoint_nm:g} N m"
                speed = f" {step.request.speed_setpoint_hz:g} Hz"
            if self.fraction is not None:
                percent = f" {math.floor(100 * self.fraction)} %"
        spinner = _SPINNER[int(now * REFRESH_HZ) % len(_SPINNER)]
        trial = duration(now - self.last_s)
        left = self.time_left_s()
        bound = (f"≤ {len(self.steps_left())} to go, motor {duration(self.motor_time_left_s(step))}"
                 + ("" if left is None else f" (wall ~{duration(left)})"))
        lines = [f"{spinner} {running}{speed}{percent}, {trial} | {done} done, {elapsed} | {bound}",
                 f"{spinner} {running}{percent}, {trial} | {done} done, {elapsed} | {bound}",
                 f"{spinner} {running}{percent}, {trial} | {bound}"]
        return next((line for line in lines if len(line) <= width), lines[-1])

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        # imported when the command runs (ilcpmac.cli's docstring says why)
        from ilcpmac.report.table import trials_table

        records, width = self.records or [], options.max_width

        def table(hidden: int):
            return trials_table(records, width, self.title, self.source, hidden)

        shown, hidden = table(0), 0
        if console.is_terminal:  # never taller than the terminal: a taller live display floods the scrollback
            room, rows = console.height - 1, sum(r.role != "grid" for r in records)  # the status line below
            # every row is one line (no cell wraps); leaving rows out adds to the caption: measured again
            while (excess := len(console.render_lines(shown, options, pad=False)) - room) > 0 and hidden < rows:
                hidden = min(hidden + excess, rows)
                shown = table(hidden)
        yield shown
        yield Text(self.status(width))


def say(console: Console, message: CampaignMessage) -> None:
    """Print ``message`` in bold; unwrapped where the console is no terminal (a file, a pipe), so that no line
    breaks mid-sentence at a width nobody reads it at."""
    console.print(Text(message.text, style="bold"), soft_wrap=not console.is_terminal)


def files_written(path: Path) -> tuple[int, int]:
    """How many files a run directory holds and their total bytes (its lock files left out)."""
    files = [p for p in path.rglob("*") if p.is_file() and not p.name.startswith(".lock")]
    return len(files), sum(p.stat().st_size for p in files)


class LiveTable(Live):
    """The live table of trials; like rich's Progress, it ends its last line when the console is not a
    terminal, so that what follows (an error too) starts on a line of its own."""

    def stop(self) -> None:
        started = self.is_started
        super().stop()
        if started and not self.console.is_terminal:
            self.console.line()


class LiveCampaign:
    """The campaign's events (`CampaignEvents`) as ``ilcpmac run`` shows them: from its start, a `CampaignView`
    in a `LiveTable`, until its end.

    Parameters
    ----------
    console : where the live table and the messages go.
    """

    #: the view and its live table, from the start
    view: CampaignView
    live: LiveTable

    def __init__(self, console: Console) -> None:
        self.console = console
        #: the run directory, once the campaign starts
        self.path: Path | None = None

    def start(self, start: CampaignStart) -> None:
        self.path = start.path
        self.view = CampaignView(self.console, start.plan, f"ilcpmac run  {start.path}",
                                 None if start.resumed else [], source=start.torque_source.value)
        self.live = LiveTable(self.view, console=self.console, refresh_per_second=REFRESH_HZ,
                              vertical_overflow="visible")
        self.live.start(refresh=True)

    def trial(self, record: TrialRecord, records: list[TrialRecord]) -> None:
        self.view.trial(record, records)

    def message(self, message: CampaignMessage) -> None:
        if self.path is None:  # before the campaign's start (a campaign in both directions states its plan)
            say(self.console, message)
            return
        self.view.message(message)

    def progress(self, fraction: float) -> None:
        self.view.progress(fraction)

    def end(self, how: str) -> None:
        self.view.end(how)
        self.live.stop()


@main.command()
@click.argument("config", required=False, type=click.Path(dir_okay=False, path_type=Path))
@click.option("--out", "out_dir", type=click.Path(file_okay=False, path_type=Path),
              help="Run directory to create (default runs/<config name>-<date>-<time>).")
@click.option("--backend", "backend_kind", default=None,
              help="Where trials run: any installed backend (ilcpmac backends lists them): sim, the simulator; "
                   "remote, a bench target (docs/protocol.md); moteus, a moteus drive (docs/moteus.md). Default: "
                   "the config's [campaign] backend, sim if it names none.")
@click.option("--address", help="Where the bench is, for backends that need it (remote: HOST:PORT).")
@click.option("--trials", type=click.IntRange(min=1), default=None,
              help="Most learning trials per learned point (overrides [campaign] learn_trials).")
@click.option("--seed", type=click.IntRange(min=0), default=None, help="Override [trials] seed.")
# max: ilcpmac.campaign.plan.MAX_BUDGET_MIN, not imported here (the command imports the campaign when it runs;
# tests/test_bench_time.py checks the two agree)
@click.option("--budget", "budget_min", type=click.FloatRange(min=0.0, min_open=True, max=1e5), default=None,
              metavar="MINUTES",
              help="Plan the campaign to this much motor running time: the trials after the grid as long as fit "
                   "(docs/campaign.md, \"Bench time\"); the plan says before the first trial what it takes.")
@click.option("--resume", "resume_dir", type=click.Path(file_okay=False, path_type=Path), default=None,
              help="Continue the run in this directory from its last complete trial.")
@click.option("--write-config", is_flag=True,
              help="A drive campaign ([drive], docs/moteus.md) writes its final table into the drive's flash "
                   "(moteus: conf write); without it nothing persists in the drive.")
def run(config: Path | None, out_dir: Path | None, backend_kind: str | None, address: str | None,
        trials: int | None, seed: int | None, budget_min: float | None, resume_dir: Path | None,
        write_config: bool) -> None:
    """Run a campaign: identify, learn, validate a compensation.

    With no CONFIG, runs the packaged seed-bench.toml on the simulator. Every trial is
    persisted as it finishes in the run directory (a bench folder); see
    docs/campaign.md.
    """
    # imported when the command runs (ilcpmac.cli's docstring says why)
    import ilcpmac.campaign
    from ilcpmac.campaign.floors import floors_of
    from ilcpmac.campaign.mean_torque import mean_torques_of
    from ilcpmac.campaign.quadrants import MIRROR_NOTE, QuadrantsResult, is_quadrants_dir
    from ilcpmac.campaign.service import DEFAULT_CONFIG
    from ilcpmac.config import FORWARD, REVERSE, load_config, packaged_config
    from ilcpmac.report.table import FINAL_TITLE, SUMMARY_TITLE, final_lines, summary_table

    loaded = None if resume_dir is not None else load_config(config or packaged_config(DEFAULT_CONFIG))
    if loaded is not None and loaded.drive_options is not None:
        from ilcpmac.cli.drive import run_drive

        given = [name for name, value in (("--trials", trials), ("--seed", seed), ("--budget", budget_min))
                 if value is not None]
        if given:
            raise click.UsageError(f"{', '.join(given)}: not for a drive campaign ({loaded.path} has [drive]: its "
                                   "[drive] table sets its trials and motor time)")
        run_drive(loaded, out_dir, backend_kind, address, write_config)
        return
    if write_config:
        raise click.UsageError("--write-config: only for a drive campaign (a config with a [drive] table, "
                               "docs/moteus.md)")
    events = LiveCampaign(console)
    both = is_quadrants_dir(resume_dir) if resume_dir is not None else loaded is not None and \
        loaded.directions() != (FORWARD,)
    start = ilcpmac.campaign.run_quadrants if both else ilcpmac.campaign.run
    try:
        result = start(loaded or config, out=out_dir, backend=backend_kind, address=address, trials=trials,
                       seed=seed, budget_min=budget_min, resume=resume_dir, events=events)
    except KeyboardInterrupt:
        if events.path is None:
            raise
        # every finished trial is on disk: the run goes on from the next
        top = events.path.parent if both else events.path
        click.echo(f"error: interrupted; continue with ilcpmac run --resume {shlex.quote(str(top))}", err=True)
        sys.exit(130)
    campaigns = result.directions if isinstance(result, QuadrantsResult) else {"": result}
    for direction, campaign in campaigns.items():
        title = SUMMARY_TITLE if not direction else f"{SUMMARY_TITLE} {direction}" + (
            f" ({MIRROR_NOTE})" if direction == REVERSE else "")
        console.print(Text(title))
        console.print(summary_table(campaign.records, campaign.plan.learned, campaign.plan.validated,
                                    floors_of(campaign.summary), console.width, mean_torques_of(campaign.summary)))
        lines = final_lines(campaign.summary)
        if lines:
            console.print(Text("\n  ".join([FINAL_TITLE, *lines])))
    count, size = files_written(result.path)
    reports = [result.path / d if d else result.path for d in campaigns]
    # not wrapped: the path and the command stay whole, to copy
    console.print(Text(f"wrote {count} files, {size / 1e6:.1f} MB, in {result.path}\n"
                       + "\n".join(f"next: ilcpmac report {shlex.quote(str(p))}" for p in reports)), soft_wrap=True)
