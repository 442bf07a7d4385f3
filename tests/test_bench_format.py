"""Bench folders (docs/bench-format.md): round trip, and every kind of bad input named by file and line or key."""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ilcpmac.bench import fastcsv, parquet
from ilcpmac.bench.fastcsv import format_rows, parse_rows
from ilcpmac.bench.format import (
    Bench,
    as_recorded,
    as_written,
    check_trial,
    convert_bench,
    read_bench,
    read_trial,
    torque_decimals,
    write_bench,
    write_trial,
)
from ilcpmac.core.errors import BenchFormatError
from ilcpmac.core.records import MotorInfo, SensorCalibration, TrialData

BENCH_TOML = """\
[motor]
pole_pairs = 1
slots = 3
counts_per_rev = 4
inertia = 0.01
backemf_file = "backemf.csv"

[sensors]
current_scale = [14.0, 14.0, 14.0]
current_offset = [0.0, 1.5, -1.5]
torque_gain = 0.9

[[trials]]
file = "trial_01.csv"
torque_setpoint = 1.0
speed_setpoint = 0.5
"""

BACKEMF_CSV = """\
count,k_a,k_b,k_c
0,0.0,-0.17,0.17
1,0.2,-0.1,-0.1
2,0.0,0.17,-0.17
3,-0.2,0.1,0.1
"""

TRIAL_CSV = """\
count,time,i_ref_a,i_ref_b,i_ref_c,torque
0,0.0000,0.0,-1.5,1.5,0.01
1,0.5000,3.3,-1.7,-1.7,-0.02
2,1.0000,0.0,1.5,-1.5,0.03
3,1.5000,-3.3,1.7,1.7,0.00
4,2.0000,0.0,-1.5,1.5,-0.01
"""

VALID = {"bench.toml": BENCH_TOML, "backemf.csv": BACKEMF_CSV, "trial_01.csv": TRIAL_CSV}
#: the per-sample arrays of a trial
COLUMNS = [f.name for f in dataclasses.fields(TrialData)
           if f.name not in ("torque_setpoint_nm", "speed_setpoint_hz", "request")]


def write_folder(folder: Path, edit: tuple[str, str, str] | None = None) -> Path:
    """Write the valid bench folder, with ``(file, old, new)`` replaced once in one file."""
    folder.mkdir(exist_ok=True)
    for name, text in VALID.items():
        if edit is not None and edit[0] == name:
            assert text.count(edit[1]) == 1, edit
            text = text.replace(edit[1], edit[2])
        (folder / name).write_text(text)
    return folder


def assert_trials_equal(actual: TrialData, expected: TrialData) -> None:
    """Bit-identical set points and columns; a column absent from ``expected`` is absent from ``actual``."""
    assert actual.torque_setpoint_nm == expected.torque_setpoint_nm
    assert actual.speed_setpoint_hz == expected.speed_setpoint_hz
    assert actual.count.dtype == np.int64
    for name in COLUMNS:
        a, e = getattr(actual, name), getattr(expected, name)
        if e is None:
            assert a is None, name
        else:
            np.testing.assert_array_equal(a, e, err_msg=name)


def assert_round_trip(actual: TrialData, original: TrialData) -> None:
    """``actual`` is exactly `as_written` of ``original``, and that is ``original`` to far below any noise."""
    expected = as_written(original)
    assert_trials_equal(actual, expected)
    for name in COLUMNS:
        if getattr(original, name) is not None:
            # half a unit of the last written decimal (1e-6 of the unit; 1e-7 s for times)
            np.testing.assert_allclose(getattr(expected, name), getattr(original, name), rtol=0,
                                       atol=0.5e-6 * (1 + 1e-9), err_msg=name)


def test_read_hand_written_folder(tmp_path):
    bench = read_bench(write_folder(tmp_path))
    assert bench.motor == MotorInfo(pole_pairs=1, slots=3, counts_per_rev=4, inertia_kgm2=0.01)
    assert bench.motor.cogging_order == 6  # lcm(3 slots, 2 poles)
    np.testing.assert_array_equal(bench.backemf_nm_per_a[1], [0.2, -0.1, -0.1])
    np.testing.assert_array_equal(bench.sensors.current_offset, [0.0, 1.5, -1.5])
    assert bench.sensors.torque_gain == 0.9
    assert bench.trial_files == ("trial_01.csv",)
    (trial,) = bench.trials
    assert (trial.torque_setpoint_nm, trial.speed_setpoint_hz) == (1.0, 0.5)
    np.testing.assert_array_equal(trial.count, [0, 1, 2, 3, 4])
    np.testing.assert_array_equal(trial.time_s, [0.0, 0.5, 1.0, 1.5, 2.0])
    np.testing.assert_array_equal(trial.i_ref_a[1], [3.3, -1.7, -1.7])
    np.testing.assert_array_equal(trial.torque_nm, [0.01, -0.02, 0.03, 0.0, -0.01])
    assert trial.i_meas_a is None and trial.torque_true_nm is None


def test_sensors_table_is_optional(tmp_path):
    start = BENCH_TOML.index("[sensors]")
    folder = write_folder(tmp_path, ("bench.toml", BENCH_TOML[start:BENCH_TOML.index("[[trials]]")], ""))
    assert read_bench(folder).sensors is None


def test_skipped_counts_are_accepted(tmp_path):
    folder = write_folder(tmp_path, ("trial_01.csv", "2,1.0000,0.0,1.5,-1.5,0.03\n", ""))
    np.testing.assert_array_equal(read_bench(folder).trials[0].count, [0, 1, 3, 4])


def test_columns_in_any_order_and_unknown_columns_ignored(tmp_path):
    rows = [line.split(",") for line in TRIAL_CSV.splitlines()]
    order = [5, 3, 0, 4, 2, 1]
    text = "\n".join(",".join([r[i] for i in order] + ["x" if k == 0 else "7"]) for k, r in enumerate(rows))
    (tmp_path / "shuffled").mkdir()
    folder = write_folder(tmp_path / "shuffled")
    (folder / "trial_01.csv").write_text(text + "\n")
    expected = read_bench(write_folder(tmp_path / "plain")).trials[0]
    assert_trials_equal(read_bench(folder).trials[0], expected)


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_round_trip_of_simulated_trials(tmp_path, small_simulator, small_model, make_request, suffix):
    requests = [make_request(small_model, 2.0, 0.5, seed=3), make_request(small_model, 1.0, 1.0, seed=4)]
    trials = small_simulator.run_trials(requests, workers=1)
    bench = Bench(
        motor=MotorInfo(8, 48, small_model.encoder.counts_per_rev, 0.01056),
        backemf_nm_per_a=small_simulator.backemf_counts,
        sensors=SensorCalibration([14.0, 14.5, 13.5], [0.25, -3.0, 1.0], 0.908),
        trials=tuple(trials), trial_files=("a" + suffix, "b" + suffix))
    write_bench(tmp_path, bench)
    back = read_bench(tmp_path)
    assert back.motor == bench.motor
    np.testing.assert_allclose(back.backemf_nm_per_a, bench.backemf_nm_per_a, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(back.sensors.current_scale, bench.sensors.current_scale)
    np.testing.assert_array_equal(back.sensors.current_offset, bench.sensors.current_offset)
    assert back.sensors.torque_gain == bench.sensors.torque_gain
    assert back.trial_files == ("a" + suffix, "b" + suffix)
    for actual, original in zip(back.trials, trials, strict=True):
        assert_round_trip(actual, original)


def test_round_trip_without_optional_parts(tmp_path):
    count = np.array([0, 1, 3])
    electrical = 2 * np.pi * (count[:, None] / 4 - np.arange(3) / 3)
    trial = TrialData(torque_setpoint_nm=0.2, speed_setpoint_hz=0.5, count=count,
                      time_s=np.array([0.0, 0.5, 1.5]), i_ref_a=np.sin(electrical) / 7,
                      torque_nm=np.array([0.1, -0.2, 1.0 / 3.0]))
    backemf = np.sin(2 * np.pi * (np.arange(4)[:, None] / 4 - np.arange(3) / 3 + 0.1))
    bench = Bench(MotorInfo(1, 6, 4, 0.5), backemf, None, (trial,), ("only.csv",))
    write_bench(tmp_path, bench)
    back = read_bench(tmp_path)
    assert back.sensors is None
    assert_round_trip(back.trials[0], trial)


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_round_trip_without_torque_sensor(tmp_path, suffix):
    """No torque column, [motor] torque_sensor = false and the timer resolution, in either format."""
    count = np.array([0, 1, 3])
    electrical = 2 * np.pi * (count[:, None] / 4 - np.arange(3) / 3)
    trial = TrialData(torque_setpoint_nm=0.2, speed_setpoint_hz=0.5, count=count,
                      time_s=np.array([0.0, 0.5, 1.5]), i_ref_a=np.sin(electrical) / 7, torque_nm=None)
    backemf = np.sin(2 * np.pi * (np.arange(4)[:, None] / 4 - np.arange(3) / 3 + 0.1))
    motor = MotorInfo(1, 6, 4, 0.5, torque_sensor=False, timer_resolution_s=2e-6)
    write_bench(tmp_path, Bench(motor, backemf, None, (trial,), ("only" + suffix,)))
    assert "torque_sensor = false\ntimer_resolution_s = 2e-06\n" in (tmp_path / "bench.toml").read_text()
    back = read_bench(tmp_path)
    assert back.motor == motor and back.trials[0].torque_nm is None
    assert_round_trip(back.trials[0], trial)
    assert as_written(trial).torque_nm is None


@pytest.mark.parametrize("edit, message", [
    # missing keys
    (("bench.toml", "slots = 3\n", ""), r"bench\.toml: \[motor\] slots: missing \(stator slots, 3\.\.2048\)$"),
    (("bench.toml", "torque_gain = 0.9\n", ""), r"bench\.toml: \[sensors\] torque_gain: missing \(g\*_t, V / N m"),
    (("bench.toml", "torque_setpoint = 1.0\n", ""),
     r"bench\.toml: \[\[trials\]\] #1 torque_setpoint: missing \(the torque set point, N m"),
    (("bench.toml", BENCH_TOML[:BENCH_TOML.index("[sensors]")], ""), r"bench\.toml: missing table \[motor\]"),
    # unknown keys, in every table and at the top level
    (("bench.toml", "[motor]", "[rotor]"), r"bench\.toml: unknown key 'rotor'"),
    (("bench.toml", "slots = 3\n", "slots = 3\nslot = 3\n"),
     r"bench\.toml: \[motor\] unknown key 'slot' \(known: pole_pairs, slots,"),
    (("bench.toml", "torque_gain = 0.9\n", "torque_gain = 0.9\ntorque_offset = 0.0\n"),
     r"bench\.toml: \[sensors\] unknown key 'torque_offset'"),
    (("bench.toml", "speed_setpoint = 0.5\n", "speed_setpoint = 0.5\nspeed = 0.5\n"),
     r"bench\.toml: \[\[trials\]\] #1 unknown key 'speed'"),
    (("bench.toml", "[motor]\n", "version = 1\n[motor]\n"), r"bench\.toml: unknown key 'version'"),
    # wrong values in bench.toml
    (("bench.toml", "counts_per_rev = 4", "counts_per_rev = 4.0"),
     r"bench\.toml: \[motor\] counts_per_rev: expected an integer, got 4\.0$"),
    (("bench.toml", "inertia = 0.01", "inertia = -0.01"),
     r"bench\.toml: \[motor\] inertia: invalid value -0\.01 \(J, kg m\^2, within \[1e-8, 1e4\]\)$"),
    (("bench.toml", "[14.0, 14.0, 14.0]", "[14.0, 14.0]"),
     r"bench\.toml: \[sensors\] current_scale: invalid value \[14\.0, 14\.0\] \(.*, three values\)$"),
    (("bench.toml", "speed_setpoint = 0.5", "speed_setpoint = nan"),
     r"bench\.toml: \[\[trials\]\] #1 speed_setpoint: expected a finite number, got nan$"),
    # malformed TOML: the parser's line
    (("bench.toml", "pole_pairs = 1", "pole_pairs = "), r"bench\.toml: not valid TOML \(.*line 2"),
    # backemf.csv
    (("backemf.csv", "3,-0.2,0.1,0.1\n", ""), r"backemf\.csv: has 3 rows, expected counts_per_rev = 4"),
    (("backemf.csv", "count,k_a,k_b,k_c", "count,ka,kb,kc"),
     r"backemf\.csv: line 1: header must be count,k_a,k_b,k_c$"),
    (("backemf.csv", "2,0.0,0.17", "5,0.0,0.17"), r"backemf\.csv: line 4: count must be 2, got 5"),
    # trial CSV
    (("trial_01.csv", ",torque", ",torq"), r"trial_01\.csv: line 1: missing column 'torque'"),
    (("trial_01.csv", "i_ref_c,", "i_ref_b,"), r"trial_01\.csv: line 1: missing column 'i_ref_c'"),
    (("trial_01.csv", "\n3,1.5", "\n2,1.5"), r"trial_01\.csv: line 5: count does not increase"),
    (("trial_01.csv", "\n1,0.5", "\n1.5,0.5"), r"trial_01\.csv: line 3: count must be an integer"),
    (("trial_01.csv", "0.03\n", "nan\n"), r"trial_01\.csv: line 4: torque is not a finite number"),
    (("trial_01.csv", "-3.3,1.7,1.7", "-3.3,inf,1.7"), r"trial_01\.csv: line 5: i_ref_b is not a finite number"),
    (("trial_01.csv", "3.3,-1.7,-1.7", "3.3,abc,-1.7"), r"trial_01\.csv: line 3, column 4 \(i_ref_b\): not a number$"),
    (("trial_01.csv", "0.0,1.5,-1.5,0.03\n", "0.0,1.5,0.03\n"),
     r"trial_01\.csv: line 4 has 5 fields, the header has 6"),
    (("trial_01.csv", "0.0,1.5,-1.5,0.03\n", "0.0,1.5,-1.5,0.03,9\n"),
     r"trial_01\.csv: line 4 has 7 fields, the header has 6"),
    (("trial_01.csv", "0.0,-1.5,1.5,0.01\n", "0.0,-1.5,1.5\n"),
     r"trial_01\.csv: line 2 has 5 fields, the header has 6"),
    (("trial_01.csv", TRIAL_CSV[TRIAL_CSV.index("\n1,"):], "\n"), r"trial_01\.csv: needs at least 2 rows, has 1"),
    # files that are not there
    (("bench.toml", 'file = "trial_01.csv"', 'file = "trial_02.csv"'), r"trial_02\.csv: no such file"),
    (("bench.toml", 'backemf_file = "backemf.csv"', 'backemf_file = "emf.csv"'), r"emf\.csv: no such file"),
])
def test_bad_folder_names_file_and_line_or_key(tmp_path, edit, message):
    folder = write_folder(tmp_path, edit)
    with pytest.raises(BenchFormatError, match=re.escape(str(folder)) + "/" + message):
        read_bench(folder)


def three_trials(folder: Path, bad: dict[int, str] | None = None) -> Path:
    """The valid folder with trial_01..03.csv, trial k's text with the edit ``bad[k]`` (a ``(old, new)`` pair) or
    its [[trials]] entry with ``bad[k]`` = "key" carrying an unknown key."""
    write_folder(folder)
    entries, bad = [], bad or {}
    for k in (1, 2, 3):
        text = TRIAL_CSV.replace("0.01\n", f"0.0{k}\n", 1)
        if isinstance(bad.get(k), tuple):
            text = text.replace(*bad[k])
        (folder / f"trial_0{k}.csv").write_text(text)
        entries.append(f'[[trials]]\nfile = "trial_0{k}.csv"\ntorque_setpoint = 1.{k}\nspeed_setpoint = 0.5\n'
                       + ("speed = 0.5\n" if bad.get(k) == "key" else ""))
    (folder / "bench.toml").write_text(BENCH_TOML[:BENCH_TOML.index("[[trials]]")] + "\n".join(entries))
    return folder


@pytest.mark.parametrize("bad, message", [
    ({2: ("0.03\n", "nan\n"), 3: ("0.03\n", "nan\n")}, r"trial_02\.csv: line 4: torque is not a finite number"),
    ({2: ("0.03\n", "nan\n"), 3: "key"}, r"trial_02\.csv: line 4: torque is not a finite number"),
    ({2: "key", 3: ("0.03\n", "nan\n")}, r"bench\.toml: \[\[trials\]\] #2 unknown key 'speed'"),
    ({1: ("-3.3,1.7,1.7", "-3.3,1.7e9,1.7"), 2: ("0.03\n", "nan\n")}, r"trial_01\.csv: sample 3: i_ref beyond"),
])
def test_trials_read_at_once_fail_as_read_in_order(tmp_path, bad, message):
    """`read_bench` reads trials two at a time, and raises the error a reading one by one meets first."""
    with pytest.raises(BenchFormatError, match=message):
        read_bench(three_trials(tmp_path, bad))


@pytest.mark.parametrize("entries", ["bad trial", "no trials"])
def test_a_bad_backemf_is_refused_before_the_trials_read_beside_it(tmp_path, entries):
    """backemf.csv is read while the trials are: its error still comes first, as in a reading in order."""
    folder = three_trials(tmp_path, {1: ("0.03\n", "nan\n")})
    if entries == "no trials":
        text = (folder / "bench.toml").read_text()
        (folder / "bench.toml").write_text(text[:text.index("[[trials]]")])
    (folder / "backemf.csv").write_text((folder / "backemf.csv").read_text().replace("count,", "position,", 1))
    with pytest.raises(BenchFormatError, match=r"backemf\.csv: line 1: header must be count,k_a,k_b,k_c"):
        read_bench(folder)


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_trials_keep_their_order_and_c_ordered_phases(tmp_path, suffix):
    convert_bench(three_trials(tmp_path / "in"), tmp_path / "out", suffix)
    bench = read_bench(tmp_path / "out")
    assert bench.trial_files == tuple(f"trial_0{k}{suffix}" for k in (1, 2, 3))
    assert [t.torque_setpoint_nm for t in bench.trials] == [1.1, 1.2, 1.3]
    assert [t.torque_nm[0] for t in bench.trials] == [0.01, 0.02, 0.03]
    for trial in bench.trials:
        assert trial.i_ref_a.shape == (5, 3) and trial.i_ref_a.flags.c_contiguous
        np.testing.assert_array_equal(trial.i_ref_a[1], [3.3, -1.7, -1.7])


@pytest.mark.parametrize("suffix", [".csv", ".parquet"])
def test_without_extras_the_simulators_columns_are_left_out(tmp_path, suffix):
    """read_bench(extras=False) gives the same trials less the simulator's columns; a Parquet trial's are never read,
    so that a NaN there goes unseen."""
    bench = read_bench(write_folder(tmp_path / "in"))
    trial = dataclasses.replace(bench.trials[0], i_meas_a=bench.trials[0].i_ref_a * 1.01,
                                torque_true_nm=bench.trials[0].torque_nm + 0.5)
    write_bench(tmp_path / "out", dataclasses.replace(bench, trials=(trial,), trial_files=("t" + suffix,)))
    full, lean = read_bench(tmp_path / "out"), read_bench(tmp_path / "out", extras=False)
    assert_trials_equal(full.trials[0], as_written(trial))
    assert_trials_equal(lean.trials[0], dataclasses.replace(as_written(trial), i_meas_a=None, torque_true_nm=None))
    if suffix == ".parquet":
        table = pq.read_table(tmp_path / "out" / "t.parquet")
        i_meas_b = table.column("i_meas_b").cast(pa.float64()).to_numpy().copy()
        i_meas_b[2] = np.nan
        pq.write_table(table.set_column(table.schema.get_field_index("i_meas_b"), "i_meas_b", pa.array(i_meas_b)),
                       tmp_path / "out" / "t.parquet")
        assert_trials_equal(read_bench(tmp_path / "out", extras=False).trials[0], lean.trials[0])
        with pytest.raises(BenchFormatError, match=r"t\.parquet: row 3: i_meas_b is not a finite number"):
            read_bench(tmp_path / "out")


@pytest.mark.parametrize("field, row, value, message", [
    ("time_s", 3, np.nan, "sample 3: time is not a finite number"),
    ("i_ref_a", 2, np.inf, "sample 2: i_ref is not a finite number"),
    ("torque_nm", 1, -np.inf, "sample 1: torque is not a finite number"),
    ("i_ref_a", 4, -2e4, "sample 4: i_ref beyond 10000 A"),
    ("torque_nm", 2, 2e5, "sample 2: torque beyond 100000 N m"),
])
def test_check_trial_names_the_first_bad_sample(tmp_path, field, row, value, message):
    """A trial built in memory (not read) with a bad value at ``row`` and another after it."""
    bench = read_bench(write_folder(tmp_path))
    values = getattr(bench.trials[0], field).copy()
    values[row] = value
    values[-1] = value
    trial = dataclasses.replace(bench.trials[0], **{field: values})
    with pytest.raises(BenchFormatError, match=f"^here: {re.escape(message)}"):
        check_trial(trial, bench.motor, "here")


def test_unreadable_trial_file(tmp_path):
    trial = write_folder(tmp_path) / "trial_01.csv"
    trial.write_bytes(b"count,time\xff\xfe,i_ref_a\n")
    with pytest.raises(BenchFormatError, match=re.escape(str(trial)) + r": line 1: the header is not UTF-8 text$"):
        read_bench(tmp_path)


def test_trial_listed_twice(tmp_path):
    trial = BENCH_TOML[BENCH_TOML.index("[[trials]]"):]
    folder = write_folder(tmp_path, ("bench.toml", trial, trial + "\n" + trial))
    with pytest.raises(BenchFormatError, match=r"bench\.toml: \[\[trials\]\] #2: file 'trial_01\.csv' is listed twice"):
        read_bench(folder)


def test_no_trials(tmp_path):
    folder = write_folder(tmp_path, ("bench.toml", BENCH_TOML[BENCH_TOML.index("[[trials]]"):], ""))
    with pytest.raises(BenchFormatError, match=r"bench\.toml: needs at least one \[\[trials\]\] entry"):
        read_bench(folder)


def test_missing_bench_toml(tmp_path):
    (write_folder(tmp_path) / "bench.toml").unlink()
    with pytest.raises(BenchFormatError, match=re.escape(str(tmp_path / "bench.toml")) + ": no such file"):
        read_bench(tmp_path)


def test_not_a_folder(tmp_path):
    with pytest.raises(BenchFormatError, match=re.escape(str(tmp_path / "absent")) + ": not a folder"):
        read_bench(tmp_path / "absent")


# ---------------------------------------------------------------- Parquet trials and the fast CSV parser

def test_csv_to_parquet_and_back_gives_the_same_files(tmp_path, small_simulator, small_model, make_request):
    trials = small_simulator.run_trials([make_request(small_model, 2.0, 0.5, seed=3)], workers=1)
    bench = Bench(MotorInfo(8, 48, small_model.encoder.counts_per_rev, 0.01056), small_simulator.backemf_counts,
                  None, tuple(trials), ("sub/t.csv",))
    write_bench(tmp_path / "csv", bench)
    convert_bench(tmp_path / "csv", tmp_path / "parquet", ".parquet")
    # every column of a simulated trial, noise in most: doubles take about half the CSV's bytes
    assert (tmp_path / "parquet" / "sub" / "t.parquet").stat().st_size < (tmp_path / "csv" / "sub" / "t.csv").stat(
        ).st_size * 0.6
    convert_bench(tmp_path / "parquet", tmp_path / "back", ".csv")
    for name in ("bench.toml", "backemf.csv", "sub/t.csv"):
        assert (tmp_path / "back" / name).read_bytes() == (tmp_path / "csv" / name).read_bytes(), name


@pytest.mark.parametrize("sigma_nm, decimals", [(0.02, 3), (0.0827, 3), (0.2, 2), (3e-4, 5), (1e-9, 6), (0.0, 6)])
def test_a_recorded_true_torque_keeps_the_decimals_its_noise_resolves_and_reads_back_as_recorded(tmp_path, sigma_nm,
                                                                                               decimals):
    """Issue 37: the simulator's true torque rounded to the power of ten at most a tenth of its noise (its variance
    0.08 % more), never finer than the file's 1e-6, whatever its ripple (here up to a quarter of the counts per
    revolution, where neighbouring samples differ most) and drift; the file then holds exactly the record, in a
    fraction of the bytes. The measured torque, which the campaign learns from, keeps its 1e-6."""
    rng = np.random.default_rng(5)
    n = 40000
    count = np.arange(n)
    ripple = 2.5 + 0.3 * np.sin(2 * np.pi * 24 * count / 4096) + 0.1 * np.cos(2 * np.pi * 1023 * count / 4096)
    ripple += 0.05 * count / n
    true = ripple + sigma_nm * rng.standard_normal(n)
    trial = TrialData(torque_setpoint_nm=2.0, speed_setpoint_hz=1.0, count=count, time_s=count * 2.4e-4,
                      i_ref_a=np.tile(np.sin(2 * np.pi * count / 512)[:, None], 3),
                      torque_nm=0.8 * true + 0.02 * rng.standard_normal(n), torque_true_nm=true)
    assert torque_decimals(count, true, 4096) == decimals
    recorded = as_recorded(trial, 4096)
    assert recorded.torque_true_nm is not None
    q = 10.0**-decimals
    np.testing.assert_allclose(recorded.torque_true_nm, true, rtol=0, atol=0.5 * q * (1 + 1e-9))
    if decimals < 6:  # the quantum from the noise, its rounding all but nothing beside it
        assert np.std(recorded.torque_true_nm - true) < 0.03 * sigma_nm
    np.testing.assert_array_equal(recorded.torque_nm, as_written(trial).torque_nm)
    path = tmp_path / "t.parquet"
    for f in (path, tmp_path / "t.csv"):
        write_trial(f, recorded)
        assert_trials_equal(read_trial(f, 2.0, 1.0), recorded)
    if decimals < 5:
        write_trial(tmp_path / "fine.parquet", as_written(trial))
        assert path.stat().st_size < 0.8 * (tmp_path / "fine.parquet").stat().st_size


def test_a_torque_record_too_short_or_without_the_truth_is_recorded_as_written():
    trial = TrialData(torque_setpoint_nm=1.0, speed_setpoint_hz=1.0, count=np.arange(2), time_s=np.array([0.0, 0.1]),
                      i_ref_a=np.zeros((2, 3)), torque_nm=np.array([0.1234567, 0.3]),
                      torque_true_nm=np.array([0.7654321, 0.3]))
    assert torque_decimals(trial.count, trial.torque_true_nm, 4) == 6
    assert_trials_equal(as_recorded(trial, 4), as_written(trial))
    without = dataclasses.replace(trial, torque_true_nm=None)
    assert_trials_equal(as_recorded(without, 4), as_written(without))


def test_parquet_trials_are_doubles_every_reader_takes_as_float64(tmp_path):
    """Required DOUBLE columns (count: INT64, no logical type) as docs/bench-format.md says, without an Arrow
    schema: Arrow reads float64 and int64, and the numbers are the CSV's."""
    folder = write_folder(tmp_path / "csv")
    convert_bench(folder, tmp_path / "parquet", ".parquet")
    path = tmp_path / "parquet" / "trial_01.parquet"
    f = pq.ParquetFile(path)
    columns = {f.schema.column(i).name: f.schema.column(i) for i in range(len(f.schema))}
    assert columns["count"].physical_type == "INT64" and columns["count"].logical_type.type == "NONE"
    assert f.schema_arrow.field("count").type == pa.int64()
    for name in ("time", "i_ref_a", "i_ref_b", "i_ref_c", "torque"):
        assert (columns[name].physical_type, columns[name].logical_type.type) == ("DOUBLE", "NONE")
        assert f.schema_arrow.field(name).type == pa.float64()
    assert all(column.max_definition_level == 0 for column in columns.values())  # required: never null
    assert b"ARROW:schema" not in (f.metadata.metadata or {})
    assert_trials_equal(read_bench(tmp_path / "parquet").trials[0], read_bench(folder).trials[0])


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_parquet_writer_refuses_nan_and_infinite_values(value):
    with pytest.raises(ValueError, match=r"^cannot write NaN or infinite values$"):
        parquet.table_bytes(["count", "x"], [np.arange(3), np.array([0.5, value, 1.0])], [0, 6])


def test_parquet_writer_rounds_half_to_even_as_the_csv_and_takes_empty_columns(tmp_path):
    path = tmp_path / "t.parquet"
    values = np.array([0.5, 1.5, -2.5, 999999999999.5, -0.25])
    path.write_bytes(parquet.table_bytes(["x", "y"], [values, values], [0, 1]))
    header, (x, y) = parquet.read_columns(path, 10, {"x", "y"})
    assert header == ["x", "y"]
    np.testing.assert_array_equal(x, [0.0, 2.0, -2.0, 1e12, -0.0])
    np.testing.assert_array_equal(y, [0.5, 1.5, -2.5, 999999999999.5, -0.2])
    path.write_bytes(parquet.table_bytes(["x"], [np.zeros(0)], [6]))
    assert [column.shape for column in parquet.read_columns(path, 10, {"x"})[1]] == [(0,)]


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-2.0**53, 2.0**53) | st.integers(-2**52, 2**52).map(lambda k: k + 0.5)
                | st.integers(-2**12, 2**12).map(lambda k: 2.0**51 + k / 2), min_size=1, max_size=40),
       st.sampled_from([0, 1, 3]))
def test_parquet_writer_rounds_every_value_as_numpy_does(tmp_path_factory, values, decimals):
    """Near and beyond 2^51, where the writer's one-addition rounding gives way to numpy's: half to even."""
    values = np.array(values) / 10.0**decimals
    path = tmp_path_factory.mktemp("rounding") / "t.parquet"
    path.write_bytes(parquet.table_bytes(["x"], [values], [decimals]))
    (x,) = parquet.read_columns(path, 100, {"x"})[1]
    scaled = values * 10.0**decimals
    np.testing.assert_array_equal(x, np.rint(scaled) / 10.0**decimals)
    counts = np.rint(scaled).astype(np.int64)
    path.write_bytes(parquet.table_bytes(["x"], [counts], [0]))
    np.testing.assert_array_equal(parquet.read_columns(path, 100, {"x"})[1][0], counts.astype(float))


def test_convert_refuses_an_unknown_format_and_trials_that_would_collide(tmp_path):
    folder = write_folder(tmp_path / "in")
    with pytest.raises(BenchFormatError, match=r"trial format must be \.csv or \.parquet, got '\.xlsx'"):
        convert_bench(folder, tmp_path / "out", ".xlsx")
    (folder / "trial_01.txt").write_text(TRIAL_CSV)
    trial = BENCH_TOML[BENCH_TOML.index("[[trials]]"):]
    (folder / "bench.toml").write_text(BENCH_TOML + "\n" + trial.replace("trial_01.csv", "trial_01.txt"))
    with pytest.raises(BenchFormatError, match=r"two trials differ only in their suffix"):
        convert_bench(folder, tmp_path / "out", ".csv")


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-1e6, 1e6), min_size=3, max_size=60), st.integers(0, 9))
def test_fast_csv_parser_gives_the_doubles_numpy_gives(values, decimals):
    """Written fixed-point text parses to the correctly rounded double, the one `as_written` computes."""
    table = np.array(values[: len(values) // 3 * 3]).reshape(-1, 3)
    body = format_rows(table, np.full(3, decimals))
    parsed = parse_rows(body, 3, table.shape[0])
    np.testing.assert_array_equal(parsed, np.loadtxt(body.decode().splitlines(), delimiter=",", ndmin=2))
    np.testing.assert_array_equal(parsed, np.round(table * 10.0**decimals) / 10.0**decimals)


@pytest.mark.parametrize("text, expected", [
    ("1,-2.5\n+3,4e2\n", [[1, -2.5], [3, 400]]),
    ("0.5e-3,-0\r\n1E+1,.5", [[0.0005, -0.0], [10, 0.5]]),
    ("9007199254740992,1e22\n", [[2.0**53, 1e22]]),
])
def test_fast_csv_parser_reads_plain_numbers(text, expected):
    parsed = parse_rows(text.encode(), 2, 10)
    np.testing.assert_array_equal(parsed, expected)
    assert np.signbit(parsed).tolist() == np.signbit(np.array(expected, float)).tolist()


@pytest.mark.parametrize("text", ["1, 2\n", "1,2\n\n3,4\n", "nan,1\n", "1,2,3\n", "1\n", "1,\n",
                                  "9007199254740993,1\n", "1e23,1\n", "1e-23,1\n", "0x10,1\n", "1,2#c\n",
                                  "1e,1\n", "1.2.3,1\n"])
def test_fast_csv_parser_leaves_anything_else_to_numpy(text):
    assert parse_rows(text.encode(), 2, 10) is None


def test_csv_beyond_the_fast_parser_reads_as_before(tmp_path):
    """Spaces and exponents: numpy parses them, to the same trial."""
    expected = read_bench(write_folder(tmp_path / "plain")).trials[0]
    odd = TRIAL_CSV.replace("0.5000", "5e-1").replace(",3.3,", ", 3.3 ,")
    folder = write_folder(tmp_path / "odd", ("trial_01.csv", TRIAL_CSV, odd))
    assert_trials_equal(read_bench(folder).trials[0], expected)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.floats(-1e6, 1e6) | st.integers(-2 * 10**6, 2 * 10**6).map(lambda k: k / 2e6), min_size=3,
                max_size=60), st.lists(st.integers(0, 9), min_size=3, max_size=3))
def test_small_tables_are_formatted_as_the_kernel_formats_them(values, decimals):
    """The Python path (no compilation for backemf.csv) writes the kernel's bytes, ties and -0 included."""
    table = np.array(values[: len(values) // 3 * 3]).reshape(-1, 3)
    decimals = np.array(decimals)
    assert fastcsv._format_small(table, decimals) == fastcsv._format_block(table, decimals)
