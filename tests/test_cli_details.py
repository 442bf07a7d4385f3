"""CLI details: the identification table against the truth at 80 columns, stage descriptions, help texts."""

from __future__ import annotations

import io
import json
import os
import subprocess
import sys

import click
import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st
from identify_helpers import cogging_error, identified, other_bench
from rich.console import Console

from ilcpmac.bench.format import write_bench
from ilcpmac.cli import main
from ilcpmac.cli.identify import estimates_table
from ilcpmac.core.current_loop import CurrentLoop
from ilcpmac.core.records import IdentificationResult, MethodEstimates
from ilcpmac.stages.registry import installed_stages

WIDTH = 80


def rendered(table) -> list[str]:
    """The table's lines as a Console of WIDTH columns prints them."""
    console = Console(width=WIDTH, file=io.StringIO(), color_system=None)
    console.print(table)
    return console.file.getvalue().splitlines()


def body(lines: list[str]) -> list[list[str]]:
    """The cells of each line between the header rule and the bottom rule."""
    start = next(i for i, line in enumerate(lines) if line.startswith("┡"))
    end = next(i for i, line in enumerate(lines) if line.startswith("└"))  # a caption may follow
    return [[cell.strip() for cell in line.strip("│").split("│")] for line in lines[start + 1:end]]


@pytest.fixture(scope="module")
def small():
    return identified("other")


def test_the_table_with_the_truth_fits_80_columns_one_line_per_estimate(small):
    result, truth = small
    table = estimates_table(result, IdentificationResult.from_json(truth))
    lines = rendered(table)
    assert max(len(line) for line in lines) <= WIDTH
    assert not any("…" in line for line in lines)
    rows = body(lines)
    assert len(rows) == table.row_count  # no cell wrapped onto a second line
    labels = [row[0] for row in rows]
    assert labels[:10] == ["delta*eps", "delta", "eps", "alpha a", "alpha b", "alpha c", "beta a (A)", "beta b (A)",
                           "beta c (A)", "J* (kg m²)"]
    assert [cell for cell in rows[0]][1:3] == [f"{result.methods['report'].delta_epsilon:.4g} ± "
                                               f"{result.methods['report'].delta_epsilon_std:.2g}",
                                               f"{result.delta_epsilon:.4g} ± {result.delta_epsilon_std:.2g} *"]


def test_the_truth_column_gives_each_estimates_error(small):
    result, truth = small
    rows = {row[0]: row[-1] for row in body(rendered(estimates_table(result, IdentificationResult.from_json(truth))))}
    assert rows["delta*eps"] == f"{100 * (result.delta_epsilon / truth['total_system_gain'] - 1):+.2g} %"
    assert rows["delta"] == f"{100 * (result.delta / truth['torque_sensor_gain'] - 1):+.2g} %"
    assert rows["alpha b"] == f"{result.alpha[1] - truth['alpha'][1]:+.2g}"
    assert rows["beta c (A)"] == f"{result.beta[2] - truth['beta'][2]:+.2g}"
    assert rows["cogging (mN m)"] == f"{100 * cogging_error(result.cogging_nm, truth):.2g} % RMS"


def test_without_truth_there_is_no_truth_column(small):
    result, _ = small
    lines = rendered(estimates_table(result))
    assert "vs truth" not in "\n".join(lines)
    assert {len(row) for row in body(lines)} == {3}


#: an estimate of any sign and size the table shows, and a standard error
_values = st.floats(1e-7, 1e4).flatmap(lambda v: st.sampled_from([v, -v]))
_stds = st.floats(1e-9, 1e3)


def _estimates(draw, values, stds) -> dict:
    vector = st.lists(values, min_size=3, max_size=3).map(np.array)
    fields = {name: draw(values) for name in ("delta_epsilon", "delta", "epsilon", "inertia_estimate")}
    fields |= {name: draw(vector) for name in ("alpha", "beta")}
    fields |= {f"{name}_std": draw(stds if name not in ("alpha", "beta") else
                                   st.lists(stds, min_size=3, max_size=3).map(np.array)) for name in fields}
    return fields | {"cogging_nm": draw(values) * np.sin(np.arange(64) / 3.0)}


@st.composite
def results(draw) -> IdentificationResult:
    """Two methods' estimates of any size, the result taking the joint one's, a current loop."""
    joint = _estimates(draw, _values, _stds)
    report = MethodEstimates(**_estimates(draw, _values, _stds))
    loop = CurrentLoop(np.array(draw(st.lists(st.floats(1e-7, 1.0), min_size=3, max_size=3))), 0.0)
    return IdentificationResult(**joint, current_loop=loop, methods={"report": report,
                                                                      "joint": MethodEstimates(**joint)})


@settings(max_examples=40, deadline=None)
@given(result=results(), truth=results())
def test_the_table_fits_80_columns_whatever_the_numbers(result, truth):
    lines = rendered(estimates_table(result, truth))
    assert max(len(line) for line in lines) <= WIDTH
    rows = body(lines)
    assert len(rows) == 14 and all(row[2].endswith(" *") for row in rows)


def test_identify_compares_with_the_benchs_truth_json(tmp_path):
    bench, truth = other_bench()
    write_bench(tmp_path / "bench", bench)
    (tmp_path / "bench" / "truth.json").write_text(json.dumps(truth))
    out = CliRunner().invoke(main, ["identify", str(tmp_path / "bench"), "--output", str(tmp_path / "r.json")],
                             terminal_width=WIDTH)
    assert out.exit_code == 0, out.output
    assert "vs truth" in out.output and "% RMS" in out.output


def test_an_unreadable_truth_json_is_one_line_before_the_identification(tmp_path):
    (tmp_path / "truth.json").write_text("{not json")
    out = CliRunner().invoke(main, ["identify", str(tmp_path), "--output", str(tmp_path / "r.json")])
    assert out.exit_code == 2
    assert out.output.startswith(f"error: {tmp_path / 'truth.json'}: unreadable (")
    assert len(out.output.splitlines()) == 1


def test_stages_describes_each_stage_in_a_line():
    out = CliRunner().invoke(main, ["stages"], terminal_width=WIDTH)
    assert out.exit_code == 0, out.output
    text = " ".join(out.output.split())
    descriptions = {name: entry.description() for name, entry in installed_stages().items()}
    assert descriptions["cogging"].startswith("Cogging feed-forward: subtract the estimated cogging torque")
    assert descriptions["ilc"].startswith("Iterative learning control of the residual ripple")
    assert descriptions["current-sensor"].startswith("Current-sensor correction")
    assert descriptions["harmonic-canceller"] == ("Cancel the torque ripple at chosen harmonics: an example ilcpmac "
                                                  "stage plugin.")
    for name, description in descriptions.items():
        assert "\n" not in description
        assert f"{name} {description}" in text


def _commands() -> list[str]:
    return sorted(main.commands)


@pytest.mark.parametrize("command", ["", *_commands()])
def test_help_fits_80_columns_and_nothing_is_cut(command):
    """Nothing wider than 80 columns, no text cut with "..." (the usage line's "[ARGS]..." aside; the list of
    commands is checked below)."""
    out = CliRunner().invoke(main, [*command.split(), "--help"], terminal_width=WIDTH)
    assert out.exit_code == 0, out.output
    usage, *lines = out.output.split("\nCommands:\n")[0].splitlines()
    assert usage.startswith("Usage:") and len(usage) <= WIDTH
    for line in lines:
        assert len(line) <= WIDTH, line
        assert not line.rstrip().endswith(("...", "…")), line


@pytest.mark.parametrize("command", _commands())
def test_the_command_list_shows_each_commands_first_sentence_whole(command):
    out = CliRunner().invoke(main, ["--help"], terminal_width=WIDTH)
    (line,) = [line for line in out.output.splitlines() if line.strip().startswith(command + " ")]
    first = click.unstyle(main.commands[command].help).split(".")[0]
    assert " ".join(line.split()[1:]) == " ".join(first.split()) + "."


def test_the_cli_offers_the_plot_formats_without_importing_matplotlib():
    """FIGURE_FORMATS is plotting.FORMATS; starting the CLI imports neither matplotlib nor numba."""
    from ilcpmac.cli import FIGURE_FORMATS
    from ilcpmac.plotting import FORMATS

    assert FIGURE_FORMATS == FORMATS
    code = "import sys, ilcpmac.cli; print(sorted({'matplotlib', 'numba'} & set(sys.modules)))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.stdout.strip() == "[]", done.stdout + done.stderr


def test_the_cli_offers_the_export_formats_and_contents_the_export_knows():
    """cli/export.py names them apart, so that starting the CLI imports no numpy: a format added to one only was
    refused by click or crashed the export."""
    from ilcpmac.cli import export as cli_export
    from ilcpmac.compensation import CONTENTS
    from ilcpmac.export import FORMATS

    assert cli_export.FORMATS == FORMATS and cli_export.CONTENTS == CONTENTS


def test_starting_the_cli_leaves_numpy_to_be_imported_after_tune_process():
    """numpy reads OPENBLAS_NUM_THREADS when first imported: the CLI's modules import it only inside the
    commands, after `main` has run `tune_process` (ilcpmac.core's package once imported every record)."""
    code = "import sys, ilcpmac.cli; print('numpy' in sys.modules)"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.stdout.strip() == "False", done.stdout + done.stderr


FAULTS_PROBE = """
import resource, sys
import numpy as np
from ilcpmac.core.runtime import keep_freed_memory
if sys.argv[1] == "kept":
    keep_freed_memory()
x, s = np.ones(2**18), np.ones((2, 1))
for _ in range(3):
    x * s + s  # two temporaries of 4 MiB, as `linear_trend` makes of a trial
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
for _ in range(50):
    x * s + s
print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before)
"""


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's malloc")
def test_the_cli_has_malloc_reuse_a_trials_worth_of_freed_memory_instead_of_faulting_it_in_again():
    """50 times two temporaries of 4 MiB: freed, malloc gives them back to the system by default and faults
    their 1024 pages in again the next time; it reuses them once `keep_freed_memory` has run (as every command
    does)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    faults = {how: int(subprocess.run([sys.executable, "-c", FAULTS_PROBE, how], env=env, capture_output=True,
                                      text=True, check=True).stdout) for how in ("default", "kept")}
    assert faults["default"] > 50 * 512
    assert faults["kept"] < 50 * 16


# ---------------------------------------------------------------- the executable's exit


class _Ended(Exception):
    """Raised by the stand-in for os._exit."""


@pytest.fixture
def fast_exit(monkeypatch):
    """entry_point's exit recorded instead of taken: {"status": ..., "handlers": ...}."""
    import ilcpmac.cli as cli

    ended = {}

    def _exit(status):
        ended["status"] = status
        raise _Ended

    monkeypatch.setattr(cli.os, "_exit", _exit)
    monkeypatch.setattr(cli.atexit, "_run_exitfuncs", lambda: ended.setdefault("handlers", True))
    return ended


@pytest.mark.parametrize("argv, status", [(["backends"], 0), (["stages", "extra"], 2)])
def test_the_executable_ends_with_the_commands_status_after_its_exit_handlers(fast_exit, monkeypatch, capsys, argv,
                                                                             status):
    from ilcpmac.cli import entry_point

    monkeypatch.setattr(sys, "argv", ["ilcpmac", *argv])
    with pytest.raises(_Ended):
        entry_point()
    assert fast_exit == {"status": status, "handlers": True}
    assert ("backends (entry-point group" in capsys.readouterr().out) == (status == 0)


def test_the_executable_exits_as_python_does_while_a_thread_still_runs(fast_exit, monkeypatch):
    import threading

    from ilcpmac.cli import entry_point

    release = threading.Event()
    worker = threading.Thread(target=release.wait)
    worker.start()
    try:
        monkeypatch.setattr(sys, "argv", ["ilcpmac", "backends"])
        with pytest.raises(SystemExit) as stopped:
            entry_point()
    finally:
        release.set()
        worker.join()
    assert stopped.value.code == 0 and fast_exit == {}


def test_the_executable_flushes_what_it_printed_and_gives_its_status():
    """The whole process: a pipe gets the full output, an error its status."""
    listed = subprocess.run([sys.executable, "-m", "ilcpmac", "backends"], capture_output=True, text=True)
    refused = subprocess.run([sys.executable, "-m", "ilcpmac", "stages", "extra"], capture_output=True, text=True)
    assert listed.returncode == 0 and "sim" in listed.stdout.split() and listed.stdout.endswith("\n")
    assert refused.returncode == 2 and "unexpected extra argument" in refused.stderr
