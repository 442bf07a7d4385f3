"""A sweep's results: one Parquet file per finished task, the combined table, and its percentiles.

Each task's row is written to DIR/results/task_NNNN.parquet as it finishes (atomically: a file there is a
finished task, which ``--resume`` skips); `combine` joins them into DIR/results.parquet (or .csv).
"""

from __future__ import annotations

import math
import os
import stat
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Generic, TypeVar

import numpy as np
import pyarrow as pa
import pyarrow.csv as pacsv
import pyarrow.parquet as pq

from ilcpmac.core.errors import IlcpmacError
from ilcpmac.sweep.task import TaskResult

__all__ = ["RESULTS_DIR", "RESULT_COLUMNS", "SUMMARY_FILE", "TABLE_FORMATS", "Percentiles", "SweepResultsError",
           "SweepSummary", "TaskOutcome", "column_values", "combine", "finished_tasks", "main_figure", "percentiles",
           "read_result", "read_results", "result_file", "summarize", "worst_tasks", "write_result"]

#: DIR/results: one file per finished task
RESULTS_DIR = "results"
#: DIR/summary.json: `SweepSummary.to_json`
SUMMARY_FILE = "summary.json"
#: the combined table's formats
TABLE_FORMATS = ("parquet", "csv")
#: the percentiles of the summary, %
LEVELS = (50.0, 95.0, 99.0)
#: the columns every task's row has (`TaskResult.row`), and their kind
RESULT_COLUMNS: dict[str, Callable[[pa.DataType], bool]] = {
    "task": pa.types.is_integer, "seed": pa.types.is_integer, "kind": pa.types.is_string,
    "status": pa.types.is_string, "reason": pa.types.is_string, "seconds": pa.types.is_floating,
    "config": pa.types.is_string}


class SweepResultsError(IlcpmacError):
    """A sweep folder's results cannot be read."""


def result_file(out_dir: Path, index: int) -> Path:
    """DIR/results/task_NNNN.parquet."""
    return out_dir / RESULTS_DIR / f"task_{index:04d}.parquet"


def write_result(out_dir: Path, result: TaskResult) -> Path:
    """Write ``result``'s row, atomically (a temporary file renamed), and return its path."""
    path = result_file(out_dir, result.task.index)
    path.parent.mkdir(parents=True, exist_ok=True)
    partial = path.with_name(f".{path.name}.partial")
    pq.write_table(pa.Table.from_pylist([result.row()]), partial)
    os.replace(partial, path)
    return path


def finished_tasks(out_dir: Path) -> set[int]:
    """The indices of the tasks whose results DIR/results holds."""
    folder = out_dir / RESULTS_DIR
    if not folder.is_dir():
        return set()
    return {int(p.stem.removeprefix("task_")) for p in folder.glob("task_*.parquet")
            if p.stem.removeprefix("task_").isdigit()}


def read_result(out_dir: Path, index: int) -> pa.Table:
    """Task ``index``'s row: DIR/results/task_NNNN.parquet must be a regular file of one row holding every
    column of `RESULT_COLUMNS`, its task ``index``; anything else raises `SweepResultsError` naming the file."""
    path = result_file(out_dir, index)
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            raise SweepResultsError(f"{path}: not a regular file: not a task's result")
        table = pq.read_table(path)
    except (OSError, pa.ArrowException) as e:
        reason = " ".join(str(e).split())
        raise SweepResultsError(f"{path}: unreadable result ({reason[:200]})") from None
    for name, kind in RESULT_COLUMNS.items():
        if name not in table.column_names or not kind(table.schema.field(name).type):
            raise SweepResultsError(f"{path}: not a task's result (no column {name!r} of the right type; a result "
                                    f"has {', '.join(RESULT_COLUMNS)})")
    if table.num_rows != 1 or table.column("task")[0].as_py() != index:
        raise SweepResultsError(f"{path}: not task {index}'s result ({table.num_rows} rows, task "
                                f"{table.column('task').to_pylist()[:3]})")
    return table


def read_results(out_dir: Path) -> pa.Table:
    """Every finished task's row (`read_result`), by task number; columns a task lacks are null in its row."""
    tables = [read_result(out_dir, i) for i in sorted(finished_tasks(out_dir))]
    if not tables:
        return pa.table({})
    try:
        return pa.concat_tables(tables, promote_options="permissive").sort_by("task")
    except pa.ArrowException as e:
        raise SweepResultsError(f"{out_dir / RESULTS_DIR}: results of different tables ({e})") from None


def combine(out_dir: Path, fmt: str = "parquet") -> Path:
    """Write every finished task's row to DIR/results.parquet or DIR/results.csv; return its path."""
    table = read_results(out_dir)
    path = out_dir / f"results.{fmt}"
    partial = path.with_name(f".{path.name}.partial")
    if fmt == "csv":
        pacsv.write_csv(table, partial)
    else:
        pq.write_table(table, partial)
    os.replace(partial, path)
    return path


@dataclass(frozen=True)
class Percentiles:
    """One column's spread over the tasks that gave it.

    Attributes
    ----------
    column : the results table's column; identification errors are taken as magnitudes.
    count : tasks with a finite value.
    median, p95, p99, worst : in the column's unit (ripple: fraction of mean torque).
    """

    column: str
    count: int
    median: float
    p95: float
    p99: float
    worst: float

    def to_json(self) -> dict:
        """Its object in summary.json."""
        return {"column": self.column, "count": self.count, "median": self.median, "p95": self.p95,
                "p99": self.p99, "worst": self.worst}


def column_values(table: pa.Table, column: str) -> np.ndarray:
    """Column ``column`` as floats, NaN where null; an identification error as its magnitude."""
    x = np.array([np.nan if v is None else v for v in table.column(column).to_pylist()], float)
    return np.abs(x) if column.startswith("id_error:") else x


def percentiles(table: pa.Table) -> tuple[Percentiles, ...]:
    """The median, 95th and 99th percentile (linear between order statistics) and the worst of every figure
    column: final and validation ripple, each point's ripple, trials, guard events, identification errors."""
    out = []
    for column in table.column_names:
        if not (column.startswith(("id_error:", "pp_true:")) or column in (
                "final_pp_true", "validation_pp_true", "trials", "guard_events", "worse_points")):
            continue
        x = column_values(table, column)
        x = x[np.isfinite(x)]
        if len(x):
            median, p95, p99 = (float(v) for v in np.percentile(x, LEVELS))
            out.append(Percentiles(column, len(x), median, p95, p99, float(x.max())))
    return tuple(out)


def main_figure(table: pa.Table) -> str | None:
    """The column that says whether a task went well: a campaign's final true ripple at its learned points,
    else the identification's delta epsilon error; None if no task gave either."""
    for column in ("final_pp_true", "id_error:delta_epsilon"):
        if column in table.column_names and np.isfinite(column_values(table, column)).any():
            return column
    return None


def worst_tasks(table: pa.Table, column: str, n: int) -> list[tuple[int, int, float]]:
    """The ``n`` tasks with the largest ``column`` (magnitude for an error): (task, seed, value), worst first."""
    x = column_values(table, column)
    tasks, seeds = table.column("task").to_pylist(), table.column("seed").to_pylist()
    order = [i for i in np.argsort(-np.nan_to_num(x, nan=-math.inf)) if np.isfinite(x[i])][:n]
    return [(tasks[i], seeds[i], float(x[i])) for i in order]


#: what a `TaskOutcome` tells of its task: a failure's reason (str) or a main figure's value (float)
Detail = TypeVar("Detail", str, float)


@dataclass(frozen=True)
class TaskOutcome(Generic[Detail]):
    """One task named in the summary: a failure (``detail`` its reason) or one of the worst (``detail`` its
    value of the main figure), with the command that reruns it alone."""

    task: int
    seed: int
    detail: Detail
    rerun: str


@dataclass(frozen=True)
class SweepSummary:
    """What summary.json holds: the tasks' spread, failures and worst cases.

    Attributes
    ----------
    kind : "campaign" or "identify".
    tasks, finished : the sweep's tasks, and how many have a result (failed ones included).
    failed : the failed tasks, in task order, ``detail`` their one-line reason.
    spread : the `Percentiles` of every figure column.
    main_figure : `main_figure`'s column, or None.
    worst : the tasks with the largest main figure, worst first, ``detail`` the value.
    """

    kind: str
    tasks: int
    finished: int
    failed: tuple[TaskOutcome[str], ...]
    spread: tuple[Percentiles, ...]
    main_figure: str | None
    worst: tuple[TaskOutcome[float], ...]

    def to_json(self) -> dict:
        """Its summary.json object."""
        def named(outcome: TaskOutcome[str] | TaskOutcome[float], detail: str) -> dict:
            return {"task": outcome.task, "seed": outcome.seed, detail: outcome.detail, "rerun": outcome.rerun}

        return {"kind": self.kind, "tasks": self.tasks, "finished": self.finished,
                "failed": [named(o, "reason") for o in self.failed],
                "percentiles": [p.to_json() for p in self.spread], "main_figure": self.main_figure,
                "worst": [named(o, "value") for o in self.worst]}


def summarize(table: pa.Table, kind: str, tasks: int, rerun: Callable[[int], str], worst: int) -> SweepSummary:
    """The summary of results ``table`` of a sweep of ``tasks`` tasks of ``kind``, naming its ``worst`` worst
    tasks; ``rerun(task)`` is the command that reruns a task alone."""
    columns = [table.column(name).to_pylist() for name in ("task", "seed", "reason", "status")]
    failed = tuple(TaskOutcome(i, s, r, rerun(i)) for i, s, r, status in zip(*columns) if status == "failed")
    column = main_figure(table)
    worst_list = worst_tasks(table, column, worst) if column is not None else []
    return SweepSummary(kind, tasks, table.num_rows, failed, percentiles(table), column,
                        tuple(TaskOutcome(i, s, v, rerun(i)) for i, s, v in worst_list))
