"""Rolling-log folders and the import that makes them (issue 35, items 1 and 6): logs kept row by row, .npy logs,
wrapped positions, shared stamps, the steady part and the coverage; every bad file one line naming it."""

from __future__ import annotations

import io
import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner
from conftest import COUNTS_PER_REV, MAPPING_BENCH
from hypothesis import given, settings
from hypothesis import strategies as st

import ilcpmac.cli.import_  # noqa: F401  (registers the command on main)
from ilcpmac.bench.format import write_backemf_csv
from ilcpmac.bench.importer import import_rolling, read_mapping, write_rolling_folder
from ilcpmac.bench.rolling import (
    ROLLING_DATA_FILE,
    ROLLING_FILE,
    RollingData,
    RollingSettings,
    coverage,
    read_rolling,
    steady_rows,
    write_rolling,
)
from ilcpmac.cli import main
from ilcpmac.core.errors import BenchFormatError, ConfigError
from ilcpmac.core.records import MotorInfo

MOTOR = MotorInfo(8, 48, COUNTS_PER_REV, 0.01, torque_sensor=False)
#: a rolling [log] of an ODrive-like .npy log: rows time, pos_estimate (counts), Iq_measured
NPY_LOG = """\
[log]
kind = "rolling"
names = ["t", "pos", "iq"]
time = "t"
position = "pos"
position_unit = "counts"
position_counts_per_rev = 8192
i_q = "iq"
current = "measured"
"""


def _backemf() -> np.ndarray:
    theta_e = 8 * 2 * np.pi * np.arange(COUNTS_PER_REV) / COUNTS_PER_REV
    return 0.2 * np.sin(theta_e[:, None] - 2 * np.pi * np.arange(3) / 3)


def _mapping(folder: Path, log: str, extra: str = "") -> Path:
    write_backemf_csv(folder / "backemf.csv", _backemf())
    path = folder / "map.toml"
    path.write_text(MAPPING_BENCH + "\n" + log + extra)
    return path


def _rolling_motion(seconds: float = 4.0, rate_hz: float = 500.0, speed_hz: float = 0.5, start_s: float = 0.0,
                    seed: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(time s, position in counts of 8192, i_q A): a slow rolling motion with cogging ripple, from rest when
    ``start_s`` (a ramp of that length)."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * rate_hz)) / rate_hz + rng.uniform(0, 0.2 / rate_hz, int(seconds * rate_hz))
    speed = speed_hz * np.minimum(t / start_s, 1.0) if start_s else np.full(t.size, speed_hz)
    turns = np.concatenate([[0.0], np.cumsum(0.5 * (speed[1:] + speed[:-1]) * np.diff(t))])
    position = 8192 * (turns + 0.002 * np.sin(2 * np.pi * 48 * turns))
    current = 1.0 + 0.3 * np.sin(2 * np.pi * 48 * turns + 0.4) + 0.01 * rng.standard_normal(t.size)
    return t, position, current


def _save_npy(path: Path, *rows: np.ndarray) -> Path:
    np.save(path, np.vstack(rows))
    return path


# ---------------------------------------------------------------- the folder


def test_a_rolling_folder_reads_back_what_was_written(tmp_path):
    t, p, i = _rolling_motion()
    data = RollingData(np.concatenate([t, t + 10]), np.concatenate([p, p + 1e5]) / 8,
                       np.repeat([1, 2], t.size), np.concatenate([i, i]), None, np.concatenate([i, i]) * 0.1)
    settings = RollingSettings(current_filter_s=0.05, logs=("a.csv", "b.csv"), first_lines=(2, 2),
                               last_lines=(t.size + 1, t.size + 1), cut_start_s=(0.0, 0.5), cut_end_s=(0.0, 0.0))
    write_rolling(tmp_path / "r", MOTOR, _backemf(), None, settings, data)
    back = read_rolling(tmp_path / "r")
    assert back.settings == settings
    assert [rows.stop - rows.start for rows in back.data.segments] == [t.size, t.size]
    np.testing.assert_allclose(back.data.time_s, data.time_s, atol=1e-7)
    np.testing.assert_allclose(back.data.position_counts, data.position_counts, atol=1e-6)
    np.testing.assert_allclose(back.data.i_q_a, data.i_q_a, atol=1e-6)
    np.testing.assert_allclose(back.data.torque_nm, data.torque_nm, atol=1e-6)


@pytest.mark.parametrize("change, message", [
    (lambda d: d.replace("segment", "segmnt"), "no column 'segment'"),
    (lambda d: d.replace("\n0.0100000,", "\n0.0000000,", 1), "line 3: time does not increase"),
    (lambda d: d.replace(",1,", ",2,", 1), "segment must start at 1"),
    (lambda d: d.replace("i_q", "i_x"), "needs the column i_q or the columns i_a, i_b, i_c"),
    (lambda d: "\n".join(line.rsplit(",", 1)[0] + ",1.0" if k else line
                         for k, line in enumerate(d.splitlines())) + "\n", "the currents are the same at every"),
])
def test_a_bad_rolling_csv_is_one_line_naming_it(tmp_path, change, message):
    t = np.arange(40) * 0.01
    data = RollingData(t, t * 100.0, np.ones(40, np.int64), np.sin(t), None, None)
    write_rolling(tmp_path, MOTOR, _backemf(), None, RollingSettings(), data)
    samples = tmp_path / ROLLING_DATA_FILE
    samples.write_text(change(samples.read_text()))
    with pytest.raises(BenchFormatError, match=message) as e:
        read_rolling(tmp_path)
    assert str(samples) in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("toml, message", [
    ('[rolling]\nfile = "../outside.csv"\n', "file: invalid value"),
    ('[rolling]\nfilter = 1\n', "unknown key 'filter'"),
    ('[rolling]\ncurrent_filter_s = -1.0\n', "current_filter_s: invalid value"),
    ('[rolling]\nlogs = ["a.csv"]\nfirst_lines = [2, 3]\n', "must have equal lengths"),
    ("[rolling]\n[other]\n", "needs exactly the table [rolling]"),
])
def test_a_bad_rolling_toml_is_one_line_naming_its_key(tmp_path, toml, message):
    t = np.arange(40) * 0.01
    write_rolling(tmp_path, MOTOR, _backemf(), None, RollingSettings(),
                  RollingData(t, t * 100.0, np.ones(40, np.int64), np.sin(t), None, None))
    (tmp_path / ROLLING_FILE).write_text(toml)
    with pytest.raises(BenchFormatError, match=message.replace("[", r"\[").replace("]", r"\]")):
        read_rolling(tmp_path)


def test_coverage_counts_the_counts_passed_between_samples():
    assert coverage(np.array([0.0, 10.0, 20.0]), 100).counts_visited == 21
    assert coverage(np.array([0.0, 50.0, 99.6, 120.0]), 100).largest_gap_counts == 0
    partial = coverage(np.array([3.0, 60.0]), 100)
    assert (partial.counts_visited, partial.largest_gap_counts) == (58, 42)
    # two segments: the motion from one to the next passes nothing
    apart = coverage(np.array([0.0, 10.0, 50.0, 60.0]), 100, np.array([1, 1, 2, 2]))
    assert apart.counts_visited == 22


def test_the_steady_part_leaves_a_start_from_rest_out_and_keeps_a_steady_or_dithering_log():
    t, p, _ = _rolling_motion(seconds=8.0, start_s=1.0)
    first, last = steady_rows(t, p)
    assert 0.7 <= t[first] <= 1.0 and last == t.size - 1
    t, p, _ = _rolling_motion(seconds=8.0)
    assert steady_rows(t, p) == (0, t.size - 1)
    dither = 5.0 * np.sin(2 * np.pi * 3 * t)
    assert steady_rows(t, dither) == (0, t.size - 1)


# ---------------------------------------------------------------- the import


def test_an_npy_log_imports_as_a_rolling_folder_its_start_transient_stated(tmp_path):
    t, p, i = _rolling_motion(seconds=8.0, start_s=1.0)
    log = _save_npy(tmp_path / "run.npy", t, p, i)
    mapping = read_mapping(_mapping(tmp_path, NPY_LOG))
    (kept,) = write_rolling_folder([log], mapping, tmp_path / "r")
    assert 0.7 < kept.cut_start_s <= 1.0 and kept.cut_end_s == 0.0
    assert "left out (speed not settled)" in kept.text()
    back = read_rolling(tmp_path / "r")
    assert back.settings.logs == ("run.npy",) and back.settings.first_lines == (kept.lines[0],)
    assert back.data.time_s[0] == pytest.approx(t[kept.lines[0] - 2], abs=1e-7)
    np.testing.assert_allclose(back.data.position_counts[:5], p[kept.lines[0] - 2:][:5] / 8, atol=1e-6)
    # and kept whole when asked
    (whole,) = write_rolling_folder([log], read_mapping(_mapping(tmp_path, NPY_LOG, "cut_transients = false\n")),
                                    tmp_path / "whole")
    assert (whole.cut_start_s, whole.data.time_s.size) == (0.0, t.size)


def test_an_npy_log_of_columns_reads_as_one_of_rows(tmp_path):
    t, p, i = _rolling_motion()
    rows = import_rolling(_save_npy(tmp_path / "rows.npy", t, p, i), read_mapping(_mapping(tmp_path, NPY_LOG)))
    np.save(tmp_path / "columns.npy", np.column_stack([t, p, i]))
    columns = import_rolling(tmp_path / "columns.npy", read_mapping(_mapping(tmp_path, NPY_LOG)))
    np.testing.assert_array_equal(rows.data.i_q_a, columns.data.i_q_a)


def _npy_bytes(array: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, array, allow_pickle=True)
    return buffer.getvalue()


@pytest.mark.parametrize("content, message", [
    (b"t,pos,iq\n0,0,0\n", "not a .npy array file"),
    (_npy_bytes(np.array([[0, 1, 2]] * 3, dtype=object)), "not real numbers"),
    (_npy_bytes(np.zeros((4, 100))), "an array of shape (4, 100)"),
    (_npy_bytes(np.zeros((3, 3))), "n != 3"),
    (_npy_bytes(np.zeros((3, 100)))[:-8], "a truncated or padded file"),
    (_npy_bytes(np.zeros((3, 2))).replace(b"(3, 2)", b"(3, 999999999999)"), "samples; a log holds 3 to"),
    (_npy_bytes(np.zeros((3, 100), complex)), "not real numbers"),
    (_npy_bytes(np.array([[0.0, np.nan, 2, 3, 4]] * 3)), "line 3: t is not a finite number"),
])
def test_a_bad_npy_log_is_one_line_naming_it(tmp_path, content, message):
    log = tmp_path / "bad.npy"
    log.write_bytes(content)
    with pytest.raises(BenchFormatError, match=message.replace("(", r"\(").replace(")", r"\)")) as e:
        import_rolling(log, read_mapping(_mapping(tmp_path, NPY_LOG)))
    assert str(log) in str(e.value) and "\n" not in str(e.value)


def test_an_npy_log_needs_its_names_and_a_text_log_has_none(tmp_path):
    t, p, i = _rolling_motion()
    log = _save_npy(tmp_path / "run.npy", t, p, i)
    with pytest.raises(BenchFormatError, match="needs \\[log\\] names"):
        import_rolling(log, read_mapping(_mapping(tmp_path, NPY_LOG.replace('names = ["t", "pos", "iq"]\n', ""))))
    text = tmp_path / "run.csv"
    text.write_text("t,pos,iq\n" + "".join(f"{a},{b},{c}\n" for a, b, c in zip(t, p, i)))
    with pytest.raises(BenchFormatError, match="names: only for a .npy log"):
        import_rolling(text, read_mapping(_mapping(tmp_path, NPY_LOG)))


def test_a_position_that_wraps_at_a_counter_s_length_is_unwrapped_by_position_wraps_at(tmp_path):
    t = np.arange(4000) / 1000.0
    counts = 10000 * 0.8 * t  # 3.2 revolutions of a 10000-count encoder on a 16-bit counter
    wrapped = (50000 + counts) % 65536 - 32768  # as an int16 counter reads it, wrapping once in the log
    log = _save_npy(tmp_path / "run.npy", t, wrapped, 1.0 + 0.1 * np.sin(t * 7))
    layout = NPY_LOG.replace("8192", "10000")
    stated = import_rolling(log, read_mapping(_mapping(tmp_path, layout, "position_wraps_at = 65536.0\n")))
    travel = COUNTS_PER_REV * 3.2
    assert stated.data.position_counts[-1] - stated.data.position_counts[0] == pytest.approx(travel, rel=1e-3)
    with pytest.raises(BenchFormatError, match=r"lines 194[0-9]-194[0-9]: the position jumps: .* a counter that "
                                               r"wraps without \[log\] position_wraps_at"):
        import_rolling(log, read_mapping(_mapping(tmp_path, layout)))  # unwrapped once per revolution: a jump


def test_rows_sharing_a_stamp_are_spread_up_to_the_next_one(tmp_path):
    t, p, i = _rolling_motion(rate_hz=1500.0)
    stamps = np.floor(t / 1e-3) * 1e-3  # a host's 1 ms clock polled at 1500 rows per second
    assert np.any(np.diff(stamps) == 0)
    kept = import_rolling(_save_npy(tmp_path / "run.npy", stamps, p, i), read_mapping(_mapping(tmp_path, NPY_LOG)))
    assert np.all(np.diff(kept.data.time_s) > 0) and kept.shared_stamps == int(np.sum(np.diff(stamps) == 0))
    assert np.max(np.abs(kept.data.time_s - t)) < 1.5e-3
    going_back = stamps.copy()
    going_back[100] = going_back[98]
    with pytest.raises(BenchFormatError, match="line 102: t does not increase"):
        import_rolling(_save_npy(tmp_path / "back.npy", going_back, p, i), read_mapping(_mapping(tmp_path, NPY_LOG)))


def test_a_run_log_the_per_count_path_refuses_is_kept_as_a_rolling_log_and_says_so(tmp_path):
    t, p, i = _rolling_motion(seconds=6.0)
    p[300:330] -= 150 * np.sin(np.pi * np.arange(30) / 30) ** 2  # the rotor runs back smoothly: a reverse lap
    log = tmp_path / "run.csv"
    log.write_text("t,pos,iq\n" + "".join(f"{a:.7f},{b:.4f},{c:.6f}\n" for a, b, c in zip(t, p, i)))
    mapping = _mapping(tmp_path, NPY_LOG.replace('kind = "rolling"\n', "").replace('names = ["t", "pos", "iq"]\n', ""))
    result = CliRunner().invoke(main, ["import", str(log), "--map", str(mapping), "--out", str(tmp_path / "out")])
    assert result.exit_code == 0, result.output
    said = " ".join(result.output.split())
    assert "kept as a rolling log" in said and "lap of 0.301 revolutions between turns" in said, said
    assert (tmp_path / "out" / ROLLING_FILE).is_file() and not (tmp_path / "out-reverse").exists()


def test_rolling_keys_are_refused_where_they_do_not_apply(tmp_path):
    with pytest.raises(ConfigError, match="current_filter_s: only for a rolling log"):
        read_mapping(_mapping(tmp_path, NPY_LOG.replace('kind = "rolling"', 'kind = "scan"').replace(
            'i_q = "iq"\n', 'i_q = "iq"\ncurrent_filter_s = 0.1\n')))
    with pytest.raises(ConfigError, match="points\\]\\]: only for run logs \\(a rolling log"):
        read_mapping(_mapping(tmp_path, NPY_LOG, '\n[[points]]\nfile = "a.npy"\ntorque_setpoint_nm = 1.0\n'
                                                 "speed_setpoint_hz = 0.5\n"))


@settings(max_examples=60, deadline=None)
@given(st.binary(max_size=400), st.integers(0, 200))
def test_any_bytes_in_an_npy_log_are_read_or_refused_in_one_line(tmp_path_factory, tail, cut):
    folder = tmp_path_factory.mktemp("npy")
    t = np.arange(8) * 0.01
    valid = _npy_bytes(np.vstack([t, t * 100, np.sin(t)]))
    log = folder / "fuzz.npy"
    log.write_bytes(valid[:cut] + tail)
    mapping = read_mapping(_mapping(folder, NPY_LOG))
    try:
        import_rolling(log, mapping)
    except BenchFormatError as e:
        assert "\n" not in str(e)


PHASE_LOG = """\
[log]
kind = "rolling"
time = "t"
position = "theta"
position_unit = "rad"
phase_currents = ["ia", "ib", "ic"]
current = "measured"
"""


def _phase_log(path: Path, theta_of=lambda theta: theta) -> Path:
    """A rolling motion logged with the phase currents a drive commutates at 8 pole pairs, its position in rad
    (``theta_of`` of the true one)."""
    t, p, i = _rolling_motion(seconds=6.0)
    theta = 2 * np.pi * p / 8192
    phases = i[:, None] * np.sin(8 * theta[:, None] - 2 * np.pi * np.arange(3) / 3)
    rows = np.column_stack([t, theta_of(theta), phases])
    path.write_text("t,theta,ia,ib,ic\n" + "".join(",".join(f"{v:.9g}" for v in row) + "\n" for row in rows))
    return path


@pytest.mark.parametrize("theta_of, message", [
    (lambda theta: theta * 180 / np.pi,
     r"lines 2-3001: the phase currents do not turn \[bench\] pole_pairs = 8 electrical periods per revolution of "
     r"the position \(coherence 0\.\d+, below 0\.5\): a wrong pole_pairs, position unit or scale\?"),
    (lambda theta: np.where(np.arange(theta.size) == 1500, 0.0, theta),
     r"lines 1501-1503: the position jumps: -?[\d.e+]+ rad/s\^2 where 10 x \[limits\] max_torque_nm / \[bench\] "
     r"inertia_kgm2 allows [\d.e+]+ \(a glitch, a counter that wraps without \[log\] position_wraps_at, or a wrong "
     r"position unit or scale\?\)"),
    (lambda theta: theta / 10,
     r"lines 2-3001: the position spans 0\.\d+ revolutions of \d+ counts, fewer than 0\.5: no harmonic of the "
     r"revolution is told from the others \(a wrong position unit or scale\?\)"),
])
def test_a_rolling_log_at_odds_with_a_motor_s_motion_is_refused_in_one_line(tmp_path, theta_of, message):
    """Kept row by row, a log no longer had the per-count path's checks: a position in degrees, a glitch of one row
    and a span a tenth of the true one imported as rolling logs (benchmarks/fuzz.py's import group)."""
    good = _phase_log(tmp_path / "good.csv")
    mapping = _mapping(tmp_path, PHASE_LOG)
    import_rolling(good, read_mapping(mapping))  # the true motion imports
    bad = _phase_log(tmp_path / "bad.csv", theta_of)
    result = CliRunner().invoke(main, ["import", str(bad), "--map", str(mapping), "--out", str(tmp_path / "out")])
    assert result.exit_code == 2, result.output
    (line,) = result.output.splitlines()  # the error alone: "kept as a rolling log" came first
    assert re.fullmatch(rf"error: \S+bad\.csv: {message}", line), line
    assert not (tmp_path / "out").exists()
