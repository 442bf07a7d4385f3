"""Hostile bench folders (issue 8): each mutation ends in one error line naming the file and line or key.

A small simulated bench folder (two trials of two revolutions at 1024 counts)
is mutated one way per test: damaged data, files that are not files, paths
that leave the folder, and plausible garbage. Nothing may end in a
traceback, a hang, unbounded memory or a non-finite number in JSON.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import os
import re
import shutil
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from click.testing import CliRunner
from conftest import COUNTS_PER_REV
from identify_helpers import other_bench

from ilcpmac.bench.format import (
    Bench,
    convert_bench,
    read_bench,
    read_trial,
    read_trial_csv,
    write_backemf_csv,
    write_bench,
    write_trial,
    write_trial_csv,
)
from ilcpmac.cli import main
from ilcpmac.core.errors import BenchFormatError, IdentificationError
from ilcpmac.core.records import MotorInfo, SensorCalibration
from ilcpmac.identify import identify_bench

#: what a file outside the bench folder holds: no message may ever show it
SECRET = "daemon:*:19000:0:secret-hash-7f3a"


@pytest.fixture(scope="module")
def small_bench(small_simulator, small_model, make_request) -> Bench:
    """Two trials of the small seed bench at two set points, in memory."""
    requests = [make_request(small_model, 2.0, 0.5, seed=3), make_request(small_model, 1.0, 1.0, seed=4)]
    trials = small_simulator.run_trials(requests, workers=1)
    return Bench(MotorInfo(8, 48, COUNTS_PER_REV, 0.01056), small_simulator.backemf_counts,
                 SensorCalibration([14.0, 14.0, 14.0], [0.0, 0.0, 0.0], 0.908), tuple(trials),
                 ("trial_01.csv", "trial_02.csv"))


@pytest.fixture(scope="module")
def pristine(small_bench, tmp_path_factory) -> Path:
    """``small_bench`` written once as a bench folder."""
    folder = tmp_path_factory.mktemp("pristine") / "bench"
    write_bench(folder, small_bench)
    return folder


@pytest.fixture
def bench_dir(pristine, tmp_path) -> Path:
    """A fresh copy of the pristine folder, to mutate; a sibling folder ``outside`` holds a secret."""
    (tmp_path / "outside").mkdir()
    (tmp_path / "outside" / "passwd").write_text(f"root:x:0:0\n{SECRET}\n")
    return Path(shutil.copytree(pristine, tmp_path / "bench"))


def edit_toml(folder: Path, old: str, new: str) -> None:
    text = (folder / "bench.toml").read_text()
    assert old in text, old
    (folder / "bench.toml").write_text(text.replace(old, new, 1))


def edit_trial(folder: Path, **changes) -> None:
    """Rewrite trial_01.csv with some columns replaced: ``changes`` maps a TrialData field to a function of it."""
    trial = read_trial_csv(folder / "trial_01.csv", 1.0, 1.0)
    trial = dataclasses.replace(trial, **{k: f(getattr(trial, k)) for k, f in changes.items()})
    write_trial_csv(folder / "trial_01.csv", trial)


def assert_refused(folder: Path, error: type, pattern: str) -> None:
    """``read_bench`` refuses ``folder`` with one line matching ``pattern`` that shows no outside data."""
    with pytest.raises(error) as caught:
        read_bench(folder)
    message = str(caught.value)
    assert re.search(pattern, message), message
    assert "\n" not in message and SECRET not in message and "root:x" not in message


def swap_two(a: np.ndarray) -> np.ndarray:
    a = a.copy()
    a[[10, 11]] = a[[11, 10]]
    return a


# ------------------------------------------------------------ damaged data (item 8)

@pytest.mark.parametrize("changes, pattern", [
    ({"time_s": swap_two}, r"trial_01\.csv: line 13: time does not increase"),
    ({"time_s": lambda t: t[::-1].copy()}, r"trial_01\.csv: line 3: time does not increase"),
    ({"time_s": lambda t: 1000.0 * t},
     r"trial_01\.csv: counts and time stamps give 0\.000\d+ revolutions per second at \[motor\] counts_per_rev "
     r"= 1024, but speed_setpoint = 0\.5 Hz"),
    ({"time_s": lambda t: 1e-3 * t}, r"trial_01\.csv: counts and time stamps give 4\d\d\.\d revolutions per second"),
    ({"torque_nm": lambda t: np.full_like(t, 1.5)}, r"trial_01\.csv: torque is 1\.5 on every line"),
    ({"count": lambda c: np.where(np.arange(c.size) >= 500, c + 10**15, c)},
     r"trial_01\.csv: line 502: count jumps by 1000000000000001; a trial's counts may span at most 4 per row"),
    ({"count": lambda c: c + 2**56}, r"trial_01\.csv: line 2: count must be an integer of magnitude at most 2\^53"),
    ({"i_ref_a": lambda i: 1e6 * i}, r"trial_01\.csv: sample \d+: i_ref beyond 10000 A"),
    ({"torque_nm": lambda t: 1e6 * t}, r"trial_01\.csv: sample \d+: torque beyond 100000 N m"),
    ({"i_ref_a": np.zeros_like}, r"trial_01\.csv: i_ref_a is zero on every line"),
    ({"i_ref_a": lambda i: np.column_stack([i[:, 0], np.zeros(len(i)), i[:, 2]])},
     r"trial_01\.csv: i_ref_b is zero on every line"),
])
def test_damaged_trial_is_refused(bench_dir, changes, pattern):
    edit_trial(bench_dir, **changes)
    assert_refused(bench_dir, BenchFormatError, pattern)


@pytest.mark.parametrize("content, pattern", [
    (bytes(range(256)) * 8, r"bench\.toml: line \d+: not UTF-8 text"),
    (b"a = " + b"[" * 100_000 + b"]" * 100_000 + b"\n", r"bench\.toml: not valid TOML \(nested too deeply\)"),
])
def test_binary_or_deeply_nested_bench_toml_is_refused(bench_dir, content, pattern):
    (bench_dir / "bench.toml").write_bytes(content)
    assert_refused(bench_dir, BenchFormatError, pattern)


def test_zero_backemf_is_refused(bench_dir, small_bench):
    write_backemf_csv(bench_dir / "backemf.csv", np.zeros_like(small_bench.backemf_nm_per_a))
    assert_refused(bench_dir, BenchFormatError, r"backemf\.csv: k_a is zero at every count")


def test_fifo_trial_is_refused_without_opening_it(bench_dir):
    fifo_trial(bench_dir)
    assert_refused(bench_dir, BenchFormatError, r"trial_01\.csv: not a regular file")


def test_folder_listed_as_backemf_is_refused(bench_dir):
    (bench_dir / "emf").mkdir()
    edit_toml(bench_dir, 'backemf_file = "backemf.csv"', 'backemf_file = "emf"')
    assert_refused(bench_dir, BenchFormatError, r"bench/emf: not a regular file")


def test_sparse_2_gb_trial_is_refused_before_it_is_read(bench_dir):
    """The size (st_size) is checked against the rows a trial may have before a byte is read."""
    os.truncate(bench_dir / "trial_02.csv", 2 * 2**30)
    assert_refused(bench_dir, BenchFormatError,
                   r"trial_02\.csv: 2147483648 bytes, more than the \d+ its rows may take")


def test_too_many_rows_are_refused_before_parsing(bench_dir):
    """Short rows fit the byte bound: their number is checked too (1024 revolutions of 1024 counts at most)."""
    (bench_dir / "trial_01.csv").write_text("count,time,i_ref_a,i_ref_b,i_ref_c,torque\n" + "1\n" * (2**20 + 1))
    assert_refused(bench_dir, BenchFormatError, r"trial_01\.csv: more than 1048576 rows")


def test_header_without_end_is_refused(bench_dir):
    (bench_dir / "trial_01.csv").write_bytes(b"count" * 1000)
    assert_refused(bench_dir, BenchFormatError, r"trial_01\.csv: line 1: no end of the header line in 4096 bytes")


# ------------------------------------------------------------ Parquet trials (issue 10)

@pytest.fixture
def parquet_dir(pristine, tmp_path) -> Path:
    """``pristine`` with its trials as Parquet (trial_01.parquet, trial_02.parquet)."""
    (tmp_path / "outside").mkdir()
    (tmp_path / "outside" / "passwd").write_text(f"root:x:0:0\n{SECRET}\n")
    convert_bench(pristine, tmp_path / "bench", ".parquet")
    return tmp_path / "bench"


def write_table(path: Path, columns: dict, **options) -> None:
    pq.write_table(pa.table(columns), path, **options)


def trial_columns(folder: Path) -> dict:
    """trial_01.parquet's columns as Arrow arrays, to damage one."""
    table = pq.read_table(folder / "trial_01.parquet")
    return {name: table.column(name) for name in table.column_names}


def test_parquet_trials_read_as_their_csv(pristine, parquet_dir):
    csv, binary = read_bench(pristine), read_bench(parquet_dir)
    assert binary.trial_files == ("trial_01.parquet", "trial_02.parquet")
    for a, b in zip(csv.trials, binary.trials, strict=True):
        for field in ("count", "time_s", "i_ref_a", "torque_nm", "i_meas_a", "torque_true_nm", "i_true_a",
                      "speed_true_rad_s"):
            np.testing.assert_array_equal(getattr(a, field), getattr(b, field), err_msg=field)


@pytest.mark.parametrize("changes, pattern", [
    ({"time_s": swap_two}, r"trial_01\.parquet: row 12: time does not increase"),
    ({"count": lambda c: np.where(np.arange(c.size) >= 500, c + 10**15, c)},
     r"trial_01\.parquet: row 501: count jumps by 1000000000000001"),
    ({"count": lambda c: c + 2**56}, r"trial_01\.parquet: row 1: count must be an integer of magnitude at most 2\^53"),
    ({"torque_nm": lambda t: np.full_like(t, 1.5)}, r"trial_01\.parquet: torque is 1\.5 on every line"),
    ({"i_ref_a": lambda i: 1e6 * i}, r"trial_01\.parquet: sample \d+: i_ref beyond 10000 A"),
])
def test_damaged_parquet_trial_is_refused(parquet_dir, changes, pattern):
    path = parquet_dir / "trial_01.parquet"
    trial = read_trial(path, 1.0, 1.0)
    write_trial(path, dataclasses.replace(trial, **{k: f(getattr(trial, k)) for k, f in changes.items()}))
    assert_refused(parquet_dir, BenchFormatError, pattern)


def test_truncated_parquet_is_refused(parquet_dir):
    path = parquet_dir / "trial_01.parquet"
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    assert_refused(parquet_dir, BenchFormatError, r"trial_01\.parquet: not a readable Parquet file \(")


@pytest.mark.parametrize("content", [b"", b"PAR1", b"count,time\n0,1\n", bytes(range(256)) * 4])
def test_a_file_that_is_not_parquet_is_refused(parquet_dir, content):
    (parquet_dir / "trial_02.parquet").write_bytes(content)
    assert_refused(parquet_dir, BenchFormatError, r"trial_02\.parquet: not a readable Parquet file \(")


def test_parquet_without_a_required_column_is_refused(parquet_dir):
    columns = trial_columns(parquet_dir)
    del columns["torque"]
    write_table(parquet_dir / "trial_01.parquet", columns)
    assert_refused(parquet_dir, BenchFormatError, r"trial_01\.parquet: schema: missing column 'torque'")


@pytest.mark.parametrize("make, pattern", [
    (lambda c: c.cast(pa.string()), r"column 'torque' holds string, not numbers"),
    (lambda c: pa.array([[v] for v in c.cast(pa.float64()).to_pylist()]),
     r"column 'torque' holds list<\w+: double>, not numbers"),
    (lambda c: pa.array(c.cast(pa.float64()).to_numpy() > 0), r"column 'torque' holds bool, not numbers"),
    (lambda c: c.cast(pa.decimal128(30, 6)), r"column 'torque' is decimal128\(30, 6\); decimals may have at most 18"),
])
def test_parquet_column_of_the_wrong_type_is_refused(parquet_dir, make, pattern):
    columns = trial_columns(parquet_dir)
    columns["torque"] = make(columns["torque"])
    write_table(parquet_dir / "trial_01.parquet", columns)
    assert_refused(parquet_dir, BenchFormatError, r"trial_01\.parquet: " + pattern)


def test_parquet_decimal_beyond_its_digits_is_refused(parquet_dir):
    """DECIMAL(18, 6) in 13 bytes (legal Parquet) holding a 20-digit value: written as DECIMAL(30, 6), then the
    footer's precision patched from 30 to 18."""
    columns = trial_columns(parquet_dir)
    n = len(columns["torque"])
    words = np.zeros((n, 2), np.int64)
    words[:, 0] = np.arange(n) % 7 + 1
    words[5, 1] = 1  # 2^64 + 6
    columns["torque"] = pa.Array.from_buffers(pa.decimal128(30, 6), n, [None, pa.py_buffer(words)])
    path = parquet_dir / "trial_01.parquet"
    write_table(path, columns, store_schema=False)
    scale_6_precision_30 = b"\x0c\x15\x3c"  # thrift compact: scale 6, then precision 30 (zigzag varints)
    assert path.read_bytes().count(scale_6_precision_30) == 2  # the schema element and its logical type
    path.write_bytes(path.read_bytes().replace(scale_6_precision_30, b"\x0c\x15\x24"))
    assert pq.read_schema(path).field("torque").type == pa.decimal128(18, 6)
    assert_refused(parquet_dir, BenchFormatError, r"trial_01\.parquet: row 6: torque holds more than its 18 digits")


def test_parquet_of_floats_and_integers_is_read(parquet_dir, pristine):
    """Another writer's types (int32, float32, float64) are numbers too."""
    trial = read_bench(pristine).trials[0]
    write_table(parquet_dir / "trial_01.parquet", {
        "count": pa.array(trial.count, pa.int32()), "time": trial.time_s, "torque": trial.torque_nm,
        **{f"i_ref_{p}": pa.array(trial.i_ref_a[:, k], pa.float32()) for k, p in enumerate("abc")}})
    back = read_bench(parquet_dir).trials[0]
    np.testing.assert_array_equal(back.torque_nm, trial.torque_nm)
    np.testing.assert_array_equal(back.i_ref_a, trial.i_ref_a.astype(np.float32))
    assert back.i_meas_a is None


@pytest.mark.parametrize("kind", [pa.decimal32(9, 6), pa.decimal64(18, 6), pa.decimal256(18, 6)])
def test_parquet_decimals_of_every_arrow_width_are_read(parquet_dir, kind):
    """Another writer's stored Arrow schema may name any decimal width: the same numbers."""
    before = read_bench(parquet_dir).trials[0]
    columns = trial_columns(parquet_dir)
    columns["torque"] = columns["torque"].cast(kind)
    write_table(parquet_dir / "trial_01.parquet", columns)
    assert pq.read_schema(parquet_dir / "trial_01.parquet").field("torque").type == kind
    np.testing.assert_array_equal(read_bench(parquet_dir).trials[0].torque_nm, before.torque_nm)


@pytest.mark.parametrize("value, pattern", [(np.nan, r"row 8: torque is not a finite number"),
                                            (np.inf, r"row 8: torque is not a finite number"),
                                            (None, r"row 8: torque is empty")])
def test_parquet_nan_or_empty_value_is_named(parquet_dir, value, pattern):
    columns = trial_columns(parquet_dir)
    torque = columns["torque"].cast(pa.float64()).to_pylist()
    torque[7] = value
    columns["torque"] = pa.array(torque, pa.float64())
    write_table(parquet_dir / "trial_01.parquet", columns)
    assert_refused(parquet_dir, BenchFormatError, r"trial_01\.parquet: " + pattern)


def test_parquet_column_twice_is_refused(parquet_dir):
    table = pq.read_table(parquet_dir / "trial_01.parquet")
    pq.write_table(table.append_column("torque", table.column("torque")), parquet_dir / "trial_01.parquet")
    assert_refused(parquet_dir, BenchFormatError, r"trial_01\.parquet: column 'torque' appears twice")


def test_parquet_declaring_too_many_rows_is_refused_before_its_data_is_read(parquet_dir, monkeypatch):
    """A few kilobytes that declare a million rows (delta-encoded ramps): refused from the footer alone."""
    n = 2**20 + 1
    ramp = np.arange(n, dtype=np.int64)
    write_table(parquet_dir / "trial_01.parquet", {name: ramp for name in ("count", "time", "i_ref_a", "i_ref_b",
                                                                           "i_ref_c", "torque")},
                compression="zstd", use_dictionary=False, column_encoding="DELTA_BINARY_PACKED")
    assert (parquet_dir / "trial_01.parquet").stat().st_size < 100_000
    monkeypatch.setattr(pq.ParquetFile, "read", lambda *a, **k: pytest.fail("the data was read"))
    assert_refused(parquet_dir, BenchFormatError, r"trial_01\.parquet: declares 1048577 rows, more than 1048576")


def test_parquet_column_larger_than_its_rows_may_take_is_refused_unread(parquet_dir, monkeypatch):
    """Two rows whose text column is 64 MB once decompressed is never read (only numeric columns are), and a
    numeric column declaring more bytes than its rows may take is refused from the footer."""
    columns = trial_columns(parquet_dir)
    columns["note"] = pa.array(["x" * 2**16] * len(columns["count"]))
    write_table(parquet_dir / "trial_01.parquet", columns, compression="zstd")
    bench = read_bench(parquet_dir)
    assert bench.trials[0].torque_nm.size == len(columns["count"])
    monkeypatch.setattr("ilcpmac.bench.parquet._COLUMN_ROW_BYTES", 0)
    monkeypatch.setattr("ilcpmac.bench.parquet._COLUMN_SLACK_BYTES", 64)
    assert_refused(parquet_dir, BenchFormatError,
                   r"trial_01\.parquet: column 'count' declares \d+ bytes, more than its 2048 rows may take")


def test_sparse_2_gb_parquet_and_fifo_are_refused_unopened(parquet_dir):
    os.truncate(parquet_dir / "trial_02.parquet", 2 * 2**30)
    assert_refused(parquet_dir, BenchFormatError, r"trial_02\.parquet: 2147483648 bytes, more than the \d+")
    (parquet_dir / "trial_01.parquet").unlink()
    os.mkfifo(parquet_dir / "trial_01.parquet")
    assert_refused(parquet_dir, BenchFormatError, r"trial_01\.parquet: not a regular file")


def test_parquet_symlink_out_of_the_folder_is_refused_unread(parquet_dir):
    (parquet_dir / "trial_01.parquet").unlink()
    (parquet_dir / "trial_01.parquet").symlink_to("../outside/passwd")
    assert_refused(parquet_dir, BenchFormatError, r"trial_01\.parquet: is a symbolic link to outside the bench")


# ------------------------------------------------------------ paths (item 9)

@pytest.mark.parametrize("old, new, pattern", [
    ('file = "trial_01.csv"', 'file = "{outside}/passwd"',
     r"bench\.toml: \[\[trials\]\] #1 file: invalid value '/.*' \(the trial's file, a relative path inside "
     r"the bench folder \(no leading '/', no '\.\.'\)\)$"),
    ('file = "trial_01.csv"', 'file = "../outside/passwd"',
     r"bench\.toml: \[\[trials\]\] #1 file: invalid value '\.\./outside/passwd' \(the trial's file, a relative path "
     r"inside the bench folder"),
    ('file = "trial_01.csv"', 'file = "sub/../../outside/passwd"', r"#1 file: invalid value .* a relative path"),
    ('backemf_file = "backemf.csv"', 'backemf_file = "/etc/passwd"',
     r"bench\.toml: \[motor\] backemf_file: invalid value '/etc/passwd' \(the back-EMF table \(backemf\.csv\), a "
     r"relative path inside the bench folder"),
    ('file = "trial_02.csv"', 'file = "./trial_01.csv"',
     r"bench\.toml: \[\[trials\]\] #2: file 'trial_01\.csv' is listed twice \(also \[\[trials\]\] #1\)"),
    ('file = "trial_02.csv"', 'file = ".//trial_01.csv"', r"#2: file 'trial_01\.csv' is listed twice"),
])
def test_paths_stay_inside_the_folder(bench_dir, old, new, pattern):
    edit_toml(bench_dir, old, new.format(outside=bench_dir.parent / "outside"))
    assert_refused(bench_dir, BenchFormatError, pattern)


@pytest.mark.parametrize("name, target", [
    ("trial_01.csv", "../outside/passwd"),
    ("trial_01.csv", "/dev/zero"),
    ("backemf.csv", "{outside}/passwd"),
    ("bench.toml", "../outside/passwd"),
])
def test_symlink_out_of_the_folder_is_refused_unread(bench_dir, name, target):
    (bench_dir / name).unlink()
    (bench_dir / name).symlink_to(target.format(outside=bench_dir.parent / "outside"))
    assert_refused(bench_dir, BenchFormatError,
                   re.escape(str(bench_dir / name)) + ": is a symbolic link to outside the bench folder")


def test_symlinks_inside_the_folder_are_followed_and_count_once(bench_dir):
    (bench_dir / "data").mkdir()
    (bench_dir / "trial_02.csv").rename(bench_dir / "data" / "second.csv")
    (bench_dir / "trial_02.csv").symlink_to("data/second.csv")
    edit_toml(bench_dir, 'file = "trial_01.csv"', 'file = "./trial_01.csv"')
    bench = read_bench(bench_dir)
    assert bench.trial_files == ("trial_01.csv", "trial_02.csv")
    (bench_dir / "again.csv").symlink_to("trial_01.csv")
    edit_toml(bench_dir, 'file = "trial_02.csv"', 'file = "again.csv"')
    assert_refused(bench_dir, BenchFormatError, r"#2: file 'again\.csv' is listed twice \(also \[\[trials\]\] #1\)")


# ------------------------------------------------------------ plausible garbage (item 10)

@pytest.mark.parametrize("old, new, pattern", [
    ("current_offset = [0.0, 0.0, 0.0]", "current_offset = [0.0, inf, 0.0]",
     r"\[sensors\] current_offset: expected a finite number, got inf$"),
    ("current_scale = [14.0, 14.0, 14.0]", "current_scale = [14.0, nan, 14.0]",
     r"\[sensors\] current_scale: expected a finite number, got nan$"),
    ("inertia = 0.01056", "inertia = 1e300",
     r"\[motor\] inertia: invalid value 1e\+300 \(J, kg m\^2, within \[1e-8, 1e4\]\)$"),
    ("pole_pairs = 8", "pole_pairs = 1000000", r"\[motor\] pole_pairs: invalid value 1000000 \(.*, 1\.\.256\)$"),
    ("slots = 48", "slots = 1", r"\[motor\] slots: invalid value 1 \(stator slots, 3\.\.2048\)$"),
    ("counts_per_rev = 1024", "counts_per_rev = 16",
     r"\[motor\] counts_per_rev: must be at least 4 per electrical period \(4 x pole_pairs = 32\), got 16$"),
    ("pole_pairs = 8", "pole_pairs = 4",
     r"backemf\.csv: the back-EMF repeats 8 times per revolution of 1024 counts, but \[motor\] pole_pairs = 4"),
    ("torque_setpoint = 2.0", "torque_setpoint = 0.0",
     r"\[\[trials\]\] #1 torque_setpoint: invalid value 0\.0 \(the torque set point, N m, within \[-100000, 100000\], "
     r"not 0 \(negative: generating, at a positive speed\)\)$"),
    # a generating set point is one, but not where the current references ask for the opposite torque
    ("torque_setpoint = 2.0", "torque_setpoint = -2.0",
     r"\[\[trials\]\] #1 torque_setpoint: -2 N m, but the current references of .* ask for 2(\.\d+)? N m on average"),
    ("torque_setpoint = 2.0", "torque_setpoint = 1e300", r"\[\[trials\]\] #1 torque_setpoint: invalid value 1e\+300 "),
    ("torque_gain = 0.908", "torque_gain = 1e300",
     r"\[sensors\] torque_gain: invalid value 1e\+300 \(g\*_t, V / N m, within \(0, 1e\+09\]\)$"),
    ("speed_setpoint = 0.5", "speed_setpoint = 0.0",
     r"\[\[trials\]\] #1 speed_setpoint: invalid value 0\.0 \(the speed set point, Hz, within \(0, 1000\]\)$"),
    ("speed_setpoint = 0.5", "speed_setpoint = -0.5", r"\[\[trials\]\] #1 speed_setpoint: invalid value -0\.5 "),
    ("speed_setpoint = 0.5", "speed_setpoint = 1.0",
     r"trial_01\.csv: counts and time stamps give 0\.4\d+ revolutions per second .* speed_setpoint = 1 Hz"),
])
def test_implausible_bench_toml_is_refused(bench_dir, old, new, pattern):
    edit_toml(bench_dir, old, new)
    assert_refused(bench_dir, BenchFormatError, pattern)


def test_counts_per_rev_half_the_recorded_one_is_refused(bench_dir, small_bench):
    """Data recorded at 1024 counts per revolution declared as 512 (the issue's 2048 on 4096)."""
    edit_toml(bench_dir, "counts_per_rev = 1024", "counts_per_rev = 512")
    write_backemf_csv(bench_dir / "backemf.csv", small_bench.backemf_nm_per_a[::2])
    assert_refused(bench_dir, BenchFormatError,
                   r"trial_01\.csv: counts and time stamps give 0\.9\d+ revolutions per second at \[motor\] "
                   r"counts_per_rev = 512, but speed_setpoint = 0\.5 Hz")


def test_electrical_period_against_pole_pairs(bench_dir, small_bench):
    """A current reference at the wrong electrical period, on a bench whose speed fits."""
    theta = 2 * np.pi * np.arange(2 * COUNTS_PER_REV) / COUNTS_PER_REV
    edit_trial(bench_dir, i_ref_a=lambda i: np.column_stack([np.sin(5 * theta + k) for k in range(3)]))
    assert_refused(bench_dir, BenchFormatError,
                   r"trial_01\.csv: the current references repeat 5 times per revolution of 1024 counts, "
                   r"but \[motor\] pole_pairs = 8")


# ------------------------------------------------------------ identification never ends in a traceback

def replaced(bench: Bench, index: int, **changes) -> Bench:
    trials = list(bench.trials)
    trials[index] = dataclasses.replace(trials[index], **changes)
    return dataclasses.replace(bench, trials=tuple(trials))


def test_non_finite_sample_in_memory_is_named(small_bench):
    torque = small_bench.trials[0].torque_nm.copy()
    torque[7] = np.nan
    with pytest.raises(IdentificationError, match=r"trial_01\.csv left out: sample 7: torque is not a finite number"):
        identify_bench(replaced(small_bench, 0, torque_nm=torque))


@pytest.mark.parametrize("target, step", [
    ("ilcpmac.identify.reduction.slow_trend", "trial_01.csv left out"),
    ("ilcpmac.identify.decouple", "decoupling (ch. 4)"),
    ("ilcpmac.identify.fit_joint", "joint fit"),
])
def test_numerical_failure_becomes_a_message(monkeypatch, target, step):
    """A LinAlgError (SVD did not converge) in a step, once: that step's message, the other estimates kept."""
    module, name = target.rsplit(".", 1)
    original = getattr(importlib.import_module(module), name)
    calls = []

    def fail_once(*args, **kwargs):
        calls.append(1)
        if len(calls) == 1:
            raise np.linalg.LinAlgError("SVD did not converge in Linear Least Squares")
        return original(*args, **kwargs)

    bench, _ = other_bench()
    monkeypatch.setattr(target, fail_once)
    result = identify_bench(bench)
    assert (f"{step}: degenerate data - constant, collinear or non-finite columns (SVD did not converge in "
            "Linear Least Squares)") in result.messages
    assert result.delta is not None
    json.dumps(result.to_json(), allow_nan=False)


@pytest.mark.parametrize("changes, pattern", [
    ({"time_s": lambda t: t[::-1].copy()}, r"trial_0\d\.csv left out: counts and time stamps give -"),
    ({"torque_nm": lambda t: np.zeros_like(t)}, r"trial_0\d\.csv left out: torque is 0 on every line"),
    ({"i_ref_a": np.zeros_like}, r"trial_0\d\.csv left out: i_ref_a is zero on every line"),
])
def test_in_memory_bench_gets_the_reader_checks(small_bench, changes, pattern):
    bench = small_bench
    for k in range(len(bench.trials)):
        bench = replaced(bench, k, **{name: f(getattr(bench.trials[k], name)) for name, f in changes.items()})
    with pytest.raises(IdentificationError, match="no trial can be used: " + pattern):
        identify_bench(bench)


def test_zero_backemf_in_memory_is_an_identification_error(small_bench):
    bench = dataclasses.replace(small_bench, backemf_nm_per_a=np.zeros_like(small_bench.backemf_nm_per_a))
    with pytest.raises(IdentificationError, match="back-EMF: k_a is zero at every count"):
        identify_bench(bench)


# ------------------------------------------------------------ the CLI: exit 2, one line; JSON without NaN

def identify_cli(folder: Path, output: Path):
    return CliRunner().invoke(main, ["identify", str(folder), "--output", str(output)])


def fifo_trial(folder: Path) -> None:
    (folder / "trial_01.csv").unlink()
    os.mkfifo(folder / "trial_01.csv")


@pytest.mark.parametrize("mutate, pattern", [
    (fifo_trial, r"trial_01\.csv: not a regular file"),
    (lambda d: edit_trial(d, count=lambda c: np.where(np.arange(c.size) >= 500, c + 10**15, c)),
     r"trial_01\.csv: line 502: count jumps"),
    (lambda d: edit_toml(d, "current_offset = [0.0, 0.0, 0.0]", "current_offset = [0.0, inf, 0.0]"),
     r"\[sensors\] current_offset: expected a finite number, got inf$"),
    (lambda d: edit_toml(d, 'file = "trial_01.csv"', 'file = "../outside/passwd"'),
     r"#1 file: invalid value '\.\./outside/passwd' \(the trial's file, a relative path inside the bench folder"),
])
def test_cli_exits_2_with_one_line(bench_dir, tmp_path, mutate, pattern):
    mutate(bench_dir)
    out = identify_cli(bench_dir, tmp_path / "result.json")
    assert out.exit_code == 2, out.output
    errors = [line for line in out.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and re.search(pattern, errors[0]), out.stderr
    assert "Traceback" not in out.output and SECRET not in out.output
    assert not (tmp_path / "result.json").exists()


def test_cli_writes_null_not_nan(tmp_path):
    """One set point: no scatter over set points, so the report's standard errors are unknown (NaN before)."""
    bench, _ = other_bench()
    write_bench(tmp_path / "bench", dataclasses.replace(bench, trials=bench.trials[:1],
                                                        trial_files=bench.trial_files[:1]))
    out = identify_cli(tmp_path / "bench", tmp_path / "result.json")
    assert out.exit_code == 0, out.output
    data = json.loads((tmp_path / "result.json").read_text(), parse_constant=lambda c: pytest.fail(c))
    assert data["methods"]["report"]["alpha_std"] is None
    assert any("alpha_std" in m and "reported as null" in m for m in data["messages"])


def test_non_finite_diagnostics_become_null():
    bench, _ = other_bench()
    result = identify_bench(dataclasses.replace(bench, trials=bench.trials[:1], trial_files=bench.trial_files[:1]))
    result = dataclasses.replace(result, diagnostics={"chi2": float("inf"), "per_trial": [np.float64("nan"), 1.0]})
    data = json.loads(json.dumps(result.to_json(), allow_nan=False))
    assert data["diagnostics"] == {"chi2": None, "per_trial": [None, 1.0]}
