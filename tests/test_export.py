"""``ilcpmac export``: the JSON and CSV read back to the record's numbers; the C lookup compiles and agrees with
`Compensation.feedforward_nm`; the command's errors."""

from __future__ import annotations

import csv
import math
import shutil
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from ilcpmac.cli import main
from ilcpmac.compensation import Compensation, FadeOut
from ilcpmac.core.records import SensorCalibration
from ilcpmac.export import INT16_FULL_SCALE, Int16Tables, export, feedforward_column, write_json

CALIBRATION = SensorCalibration([14.0, 14.2, 13.9], [1.5, -2.0, 0.25], 0.908)
#: C compiler flags: strict C99, every warning an error
C_FLAGS = ["-std=c99", "-pedantic", "-Wall", "-Wextra", "-Wconversion", "-Werror", "-O2"]
#: the fade-out of compensation() by default
FADE = FadeOut(3.0, 5.0)


def compensation(n_torques: int = 2, n_speeds: int = 2, fade: FadeOut = FADE, cpr: int = 64,
                 seed: int = 1) -> Compensation:
    """Tables of 10 mN m scale with a 60 mN m peak, torques from 1 N m, speeds from 0.5 Hz (a third apart:
    not float32 numbers)."""
    rng = np.random.default_rng(seed)
    tables = rng.normal(0.0, 0.01, (n_torques, n_speeds, cpr))
    tables[0, 0, 0] = -0.06
    return Compensation(cpr, CALIBRATION, 1.0 + 2.0 * np.arange(n_torques), 0.5 + np.arange(n_speeds) / 3.0, tables,
                        fade)


def assert_same(a: Compensation, b: Compensation) -> None:
    assert a.counts_per_rev == b.counts_per_rev and a.fade == b.fade
    assert a.calibration.to_json() == b.calibration.to_json()
    for name in ("torques_nm", "speeds_hz", "tables_nm"):
        assert np.array_equal(getattr(a, name), getattr(b, name))


# ---------------------------------------------------------------- JSON and CSV


@pytest.mark.parametrize("fade", [FadeOut(3.0, 5.0), FadeOut(math.inf, math.inf)])
def test_the_json_export_reads_back_to_the_record(tmp_path, fade):
    c = compensation(fade=fade)
    (path,) = export(c, tmp_path / "out", "json").files
    assert path.name == "compensation.json" and path.read_text().startswith('{\n "format": 1,\n "units": {')
    assert_same(Compensation.read(path), c)


def _rows(path: Path) -> list[list[str]]:
    with path.open(newline="") as f:
        return list(csv.reader(f))


def test_the_csv_export_reads_back_to_the_same_numbers(tmp_path):
    c = compensation(n_torques=3, n_speeds=2, fade=FadeOut(math.inf, math.inf))
    files = export(c, tmp_path, "csv").files
    assert [p.name for p in files] == ["calibration.csv", "torque_gain.csv", "feedforward.csv", "map.csv"]
    calibration = _rows(tmp_path / "calibration.csv")
    assert calibration[0] == ["phase", "current_scale_counts_per_a", "current_offset_counts"]
    assert [row[0] for row in calibration[1:]] == ["a", "b", "c"]
    cal = np.array([[float(v) for v in row[1:]] for row in calibration[1:]])
    assert np.array_equal(cal[:, 0], c.calibration.current_scale)
    assert np.array_equal(cal[:, 1], c.calibration.current_offset)
    assert _rows(tmp_path / "torque_gain.csv") == [["torque_gain_v_per_nm"], ["0.908"]]

    grid = _rows(tmp_path / "map.csv")
    assert grid[0] == ["name", "index", "value"]
    values = {}
    for name, index, value in grid[1:]:
        values.setdefault(name, {})[int(index)] = float(value)
    assert values["counts_per_rev"] == {0: 64}
    torques = np.array([values["torques_nm"][i] for i in range(3)])
    speeds = np.array([values["speeds_hz"][i] for i in range(2)])
    assert np.array_equal(torques, c.torques_nm) and np.array_equal(speeds, c.speeds_hz)
    assert values["fade_full_hz"] == {0: math.inf} and values["fade_zero_hz"] == {0: math.inf}

    feedforward = _rows(tmp_path / "feedforward.csv")
    header = feedforward[0]
    assert header[0] == "count" and len(feedforward) == 1 + c.counts_per_rev
    assert header[1:] == [feedforward_column(t, s) for t in torques for s in speeds]
    assert header[2] == "feedforward_nm_at_1.0_nm_0.8333333333333333_hz"
    assert [int(row[0]) for row in feedforward[1:]] == list(range(c.counts_per_rev))
    table = np.array([[float(v) for v in row[1:]] for row in feedforward[1:]])
    assert np.array_equal(table.T.reshape(c.tables_nm.shape), c.tables_nm)


# ---------------------------------------------------------------- C


def test_int16_tables_use_the_range_and_state_their_error():
    c = compensation()
    q = Int16Tables.of(c.tables_nm)
    assert q.values.dtype == np.int16 and np.abs(q.values).max() == INT16_FULL_SCALE
    assert q.nm_per_lsb == float(np.float32(q.nm_per_lsb))
    assert q.error_nm == np.abs(c.tables_nm - q.values * q.nm_per_lsb).max() <= q.nm_per_lsb / 2
    zero = Int16Tables.of(np.zeros((1, 1, 8)))
    assert not np.any(zero.values) and zero.error_nm == 0.0 and zero.nm_per_lsb > 0


def _compiler() -> str:
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        pytest.skip("no C compiler (cc or gcc) on PATH: the generated C cannot be compiled here")
    return compiler


DRIVER = """\
#include <stdio.h>
#include "ilcpmac_compensation.h"

static const uint32_t counts[] = {%s};
static const float torques[] = {%s};
static const float speeds[] = {%s};

int main(void)
{
    unsigned i;
    for (i = 0u; i < sizeof counts / sizeof counts[0]; i++) {
        printf("%%.9g\\n", (double)ilcpmac_feedforward_nm(counts[i], torques[i], speeds[i]));
    }
    return 0;
}
"""


def lookup_points(c: Compensation, n: int = 200, seed: int = 7) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``n`` (count, torque, speed): every grid point and its edges, then random ones from below the grid to
    beyond the fade-out, as float32 numbers (what the C function takes)."""
    rng = np.random.default_rng(seed)
    t_grid, s_grid = np.meshgrid(c.torques_nm, c.speeds_hz, indexing="ij")
    edges_t = np.concatenate([t_grid.ravel(), [c.torques_nm[0] - 1.0, c.torques_nm[-1] + 1.0]])
    edges_s = np.concatenate([s_grid.ravel(), [0.1, 9.0]])
    k = len(edges_t)
    torques = np.concatenate([edges_t, rng.uniform(c.torques_nm[0] - 2.0, c.torques_nm[-1] + 2.0, n - k)])
    speeds = np.concatenate([edges_s, rng.uniform(0.05, 7.0, n - k)])
    counts = rng.integers(0, 2**32, n, dtype=np.uint64)
    return counts, torques.astype(np.float32), speeds.astype(np.float32)


def run_c(c: Compensation, folder: Path, c_type: str, points) -> tuple[np.ndarray, float | None]:
    """The generated C's lookup at ``points``, and the stated quantisation error."""
    compiler = _compiler()
    exported = export(c, folder, "c", c_type)
    counts, torques, speeds = points
    (folder / "driver.c").write_text(DRIVER % (", ".join(f"{n}u" for n in counts),
                                               ", ".join(f"{t}f" for t in torques),
                                               ", ".join(f"{s}f" for s in speeds)))
    binary = folder / "driver"
    done = subprocess.run([compiler, *C_FLAGS, "-o", str(binary), str(folder / "driver.c"),
                           str(folder / "ilcpmac_compensation.c")], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    out = subprocess.run([str(binary)], capture_output=True, text=True, check=True, timeout=60).stdout
    return np.array([float(v) for v in out.split()]), exported.quantisation_error_nm


@pytest.mark.parametrize("c_type", ["int16", "float"])
@pytest.mark.parametrize("shape, fade", [((2, 2), FadeOut(3.0, 5.0)), ((3, 1), FadeOut(2.0, 2.0)),
                                         ((1, 3), FadeOut(math.inf, math.inf))])
def test_the_c_lookup_agrees_with_the_record(tmp_path, c_type, shape, fade):
    c = compensation(*shape, fade)
    points = lookup_points(c)
    got, error_nm = run_c(c, tmp_path, c_type, points)
    counts, torques, speeds = points
    want = np.array([c.feedforward_nm(float(t), float(s))[int(n) % c.counts_per_rev]
                     for n, t, s in zip(counts, torques, speeds)])
    peak = np.abs(c.tables_nm).max()
    if c_type == "int16":
        assert 0 < error_nm <= peak / INT16_FULL_SCALE / 2
        tolerance = error_nm + 1e-6 * peak  # the stated error, and float arithmetic
        assert f"max |float - int16| = {error_nm:.3g} N m" in (tmp_path / "ilcpmac_compensation.h").read_text()
    else:
        assert error_nm is None
        tolerance = 1e-5 * peak
    assert got.shape == want.shape and np.abs(got - want).max() <= tolerance
    faded = speeds >= fade.zero_hz
    assert np.all(got[faded] == 0) and np.any(got[~faded] != 0)


@pytest.mark.parametrize("c_type", ["int16", "float"])
def test_the_c_lookup_of_both_directions_agrees_and_fades_by_speed_size(tmp_path, c_type):
    """A four-quadrant record (speeds -2..2 Hz): the C lookup interpolates through 0 Hz as the record does and
    fades beyond 5 Hz either way (it compared the signed speed: no reverse speed ever faded)."""
    base = compensation(2, 4, FADE)
    c = replace(base, speeds_hz=np.array([-2.0, -0.5, 0.5, 2.0]))
    rng = np.random.default_rng(11)
    counts = rng.integers(0, 2**32, 120, dtype=np.uint64)
    torques = rng.uniform(0.0, 4.0, 120).astype(np.float32)
    speeds = np.concatenate([[-9.0, -4.0, -0.5, 0.0, 0.5, 4.0, 9.0], rng.uniform(-7.0, 7.0, 113)]).astype(np.float32)
    got, error_nm = run_c(c, tmp_path, c_type, (counts, torques, speeds))
    want = np.array([c.feedforward_nm(float(t), float(s))[int(n) % c.counts_per_rev]
                     for n, t, s in zip(counts, torques, speeds)])
    tolerance = (error_nm or 0.0) + 1e-5 * np.abs(c.tables_nm).max()
    assert np.abs(got - want).max() <= tolerance
    faded = np.abs(speeds) >= FADE.zero_hz
    assert np.all(got[faded] == 0) and np.any(got[faded & (speeds < 0)] == 0) and np.all(want[faded] == 0)
    assert np.any(got[~faded] != 0)


def test_the_c_files_need_only_stdint(tmp_path):
    export(compensation(), tmp_path, "c")
    text = (tmp_path / "ilcpmac_compensation.h").read_text() + (tmp_path / "ilcpmac_compensation.c").read_text()
    includes = [line for line in text.splitlines() if line.startswith("#include")]
    assert includes == ["#include <stdint.h>", '#include "ilcpmac_compensation.h"']
    assert "malloc" not in text and "float ilcpmac_feedforward_nm(uint32_t count, float torque_nm, float speed_hz)" \
        in text


# ---------------------------------------------------------------- the command


def test_export_writes_the_c_files_and_says_the_quantisation_error(tmp_path):
    c = compensation()
    write_json(c, tmp_path)
    out = CliRunner().invoke(main, ["export", str(tmp_path), "--format", "c", "--out", str(tmp_path / "fw")])
    assert out.exit_code == 0, out.output
    error = Int16Tables.of(c.tables_nm).error_nm
    lines = out.output.splitlines()
    assert lines[0].startswith("wrote 2 files, ") and lines[0].endswith(f"in {tmp_path / 'fw'}")
    assert lines[1].split()[0] == "ilcpmac_compensation.h" and lines[2].split()[0] == "ilcpmac_compensation.c"
    assert lines[3] == ("bound: |feed-forward| at most 0.06 N m, within 100000 N m (the record's range: no run "
                        "directory, so no [limits])")
    assert lines[4].startswith("residual ripple of the c export: ") and f", {error:.3g} N m peak (" in lines[4]
    assert sorted(p.name for p in (tmp_path / "fw").iterdir()) == ["ilcpmac_compensation.c", "ilcpmac_compensation.h"]


def test_export_csv_lists_its_four_files(tmp_path):
    write_json(compensation(), tmp_path)
    out = CliRunner().invoke(main, ["export", str(tmp_path), "--format", "csv", "--out", str(tmp_path / "csv")])
    assert out.exit_code == 0, out.output
    assert out.output.startswith("wrote 4 files, ")
    assert [line.split()[0] for line in out.output.splitlines()[1:-2]] == [
        "calibration.csv", "torque_gain.csv", "feedforward.csv", "map.csv"]
    assert out.output.splitlines()[-2].startswith("bound: |feed-forward| at most ")
    assert out.output.splitlines()[-1].startswith("residual ripple of the csv export: 0 N m RMS, 0 N m peak (0 %, ")


def test_export_of_a_run_without_compensation_is_one_line(tmp_path):
    out = CliRunner().invoke(main, ["export", str(tmp_path), "--out", str(tmp_path / "out")])
    assert out.exit_code == 2
    assert out.output == (f"error: {tmp_path} has no compensation.json (a campaign writes it when its learning "
                          "phase ends)\n")
    assert not (tmp_path / "out").exists()


def test_export_of_a_bad_compensation_is_one_line(tmp_path):
    (tmp_path / "compensation.json").write_text('{"format": 1}')
    out = CliRunner().invoke(main, ["export", str(tmp_path), "--out", str(tmp_path / "out")])
    assert out.exit_code == 2
    assert out.output == f"error: {tmp_path / 'compensation.json'}: missing key 'units'\n"


def test_export_refuses_an_unknown_format_with_a_usage_error(tmp_path):
    out = CliRunner().invoke(main, ["export", str(tmp_path), "--format", "xml", "--out", str(tmp_path)])
    assert out.exit_code == 2
    assert "invalid value for '--format'" in out.output.lower() and "'xml'" in out.output


def test_the_commands_choices_are_the_writers():
    """The command names the formats and C types itself (starting the CLI does not import the writers); they are
    the writers'."""
    from ilcpmac.export import C_TYPES, FORMATS

    params = {p.name: p for p in main.commands["export"].params}
    assert tuple(params["fmt"].type.choices) == FORMATS and tuple(params["c_type"].type.choices) == C_TYPES


def test_an_unknown_format_is_refused_before_anything_is_written(tmp_path):
    """A format with no branch in `export` once fell through to the C writer."""
    with pytest.raises(ValueError, match="export format must be one of json, csv, c, harmonics, moteus, got 'tsv'"):
        export(compensation(), tmp_path / "out", "tsv")
    assert not (tmp_path / "out").exists()


def test_an_unknown_c_type_is_refused_before_anything_is_written(tmp_path):
    """Issue 34, item 11: ``c_type='int8'`` wrote float tables; the CLI and the API refuse it, and so does export."""
    with pytest.raises(ValueError, match="C table type must be one of int16, float, got 'int8'"):
        export(compensation(), tmp_path / "out", "c", c_type="int8")
    assert not (tmp_path / "out").exists()
