"""Parquet trial files as numbers (issue 26, item 3): pandas and polars read float64 (count int64) with no
conversion, ilcpmac reads back the very doubles written, earlier DECIMAL files still read, and a NaN or infinite
value in a float column is refused naming the file, the row and the column (docs/bench-format.md)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd
import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import given, seed, settings
from hypothesis import strategies as st

from ilcpmac.bench import parquet
from ilcpmac.bench.format import as_written, read_trial, write_trial
from ilcpmac.core.errors import BenchFormatError
from ilcpmac.core.records import TrialData

#: every column of a simulated trial file and the TrialData attribute it comes from (phase k of a 3-wide one)
FILE_COLUMNS = {"count": ("count", None), "time": ("time_s", None), "torque": ("torque_nm", None),
                "torque_true": ("torque_true_nm", None), "speed_true": ("speed_true_rad_s", None),
                **{f"{prefix}_{p}": (f"{prefix}_a", k) for prefix in ("i_ref", "i_meas", "i_true")
                   for k, p in enumerate("abc")}}


@pytest.fixture(scope="module")
def simulated(small_simulator, small_model, make_request) -> TrialData:
    """A simulated trial (every column the simulator gives) exactly as the files hold it."""
    return as_written(small_simulator.run_trials([make_request(small_model, 2.0, 0.5, seed=5)], workers=1)[0])


def column(trial: TrialData, name: str) -> np.ndarray:
    attr, phase = FILE_COLUMNS[name]
    values = getattr(trial, attr)
    return values if phase is None else values[:, phase]


def test_pandas_and_polars_read_every_column_as_numbers(tmp_path, simulated):
    path = tmp_path / "trial.parquet"
    write_trial(path, simulated)
    frame = pd.read_parquet(path)
    assert set(frame.columns) == set(FILE_COLUMNS)
    assert frame["count"].dtype == np.int64
    polars = pl.read_parquet(path)
    assert polars.schema["count"] == pl.Int64
    for name in FILE_COLUMNS:
        if name != "count":
            assert frame[name].dtype == np.float64, name
            assert polars.schema[name] == pl.Float64, name
        expected = column(simulated, name)
        np.testing.assert_array_equal(frame[name].to_numpy(), expected, err_msg=name)
        np.testing.assert_array_equal(polars[name].to_numpy(), expected, err_msg=name)
    spectrum = np.fft.rfft(frame["torque"])  # DECIMAL columns gave pandas objects: a TypeError here
    assert spectrum.dtype == np.complex128 and spectrum.size == frame.shape[0] // 2 + 1


def test_a_trial_reads_back_bit_for_bit(tmp_path, simulated):
    path = tmp_path / "trial.parquet"
    negative_zero = dataclasses.replace(simulated, torque_nm=np.where(np.arange(simulated.count.size) == 3, -0.0,
                                                                      simulated.torque_nm))
    write_trial(path, negative_zero)
    back = read_trial(path, simulated.torque_setpoint_nm, simulated.speed_setpoint_hz)
    for name in FILE_COLUMNS:
        assert np.array_equal(column(back, name).view(np.int64) if name != "count" else column(back, name),
                              column(negative_zero, name).view(np.int64) if name != "count" else
                              column(negative_zero, name)), name


@seed(2026)
@settings(max_examples=80, deadline=None)
@given(st.lists(st.floats(-1e5, 1e5), min_size=1, max_size=300), st.sampled_from([0, 3, 6, 7]),
       st.integers(1, 4))
def test_any_column_round_trips_exactly_as_rounded(tmp_path_factory, values, decimals, repeats):
    """Whatever encoding the writer picks (values repeated: a dictionary), ilcpmac reads back exactly `rounded`
    of what was given, -0.0 included, and rounding what was read changes nothing."""
    values = np.tile(np.array(values), repeats)
    path = tmp_path_factory.mktemp("round-trip") / "t.parquet"
    path.write_bytes(parquet.table_bytes(["x"], [values], [decimals]))
    (back,) = parquet.read_columns(path, values.size, {"x"})[1]
    expected = parquet.rounded(values, decimals)
    assert np.array_equal(back.view(np.int64), expected.view(np.int64))
    assert np.array_equal(parquet.rounded(back, decimals).view(np.int64), back.view(np.int64))
    assert pd.read_parquet(path)["x"].dtype == np.float64


@pytest.mark.parametrize("make, encoding", [
    (lambda n: np.tile(np.sin(np.arange(64) / 10), n // 64), "RLE_DICTIONARY"),  # repeats: a dictionary
    (lambda n: 2.0 + np.arange(n) * 4.89e-4, "BYTE_STREAM_SPLIT"),  # time stamps
    (lambda n: np.random.default_rng(1).normal(0, 0.01, n), "PLAIN"),  # noise about zero
])
def test_each_column_gets_the_encoding_that_suits_it(tmp_path, make, encoding):
    values = parquet.rounded(make(12288), 6)
    path = tmp_path / "t.parquet"
    path.write_bytes(parquet.table_bytes(["x"], [values], [6]))
    assert encoding in pq.ParquetFile(path).metadata.row_group(0).column(0).encodings
    np.testing.assert_array_equal(parquet.read_columns(path, values.size, {"x"})[1][0], values)


def decimal_file(path: Path, trial: TrialData) -> None:
    """``trial`` as ilcpmac wrote it before issue 26: DECIMAL(18, d) in INT64 (time 7 decimals, the rest 6),
    delta-encoded, zstd, no Arrow schema."""
    arrays, fields = [], []
    for name in ("count", "time", "i_ref_a", "i_ref_b", "i_ref_c", "torque", "torque_true"):
        values = column(trial, name)
        if name == "count":
            arrays.append(pa.array(values))
        else:
            d = 7 if name == "time" else 6
            ints = np.rint(values * 10.0**d).astype(np.int64)
            arrays.append(pa.Array.from_buffers(pa.decimal64(18, d), ints.size, [None, pa.py_buffer(ints)]))
        fields.append(pa.field(name, arrays[-1].type, nullable=False))
    pq.write_table(pa.Table.from_arrays(arrays, schema=pa.schema(fields)), path, compression="zstd",
                   use_dictionary=False, store_decimal_as_integer=True, column_encoding="DELTA_BINARY_PACKED",
                   store_schema=False, write_statistics=False)


def test_a_decimal_trial_of_earlier_versions_reads_as_before(tmp_path, simulated):
    kept = dataclasses.replace(simulated, i_meas_a=None, i_true_a=None, speed_true_rad_s=None)
    old, new = tmp_path / "old.parquet", tmp_path / "new.parquet"
    decimal_file(old, kept)
    assert pq.ParquetFile(old).schema.column(5).logical_type.type == "DECIMAL"
    write_trial(new, kept)
    before = read_trial(old, kept.torque_setpoint_nm, kept.speed_setpoint_hz)
    after = read_trial(new, kept.torque_setpoint_nm, kept.speed_setpoint_hz)
    for name in ("count", "time", "i_ref_a", "i_ref_b", "i_ref_c", "torque", "torque_true"):
        np.testing.assert_array_equal(column(before, name), column(kept, name), err_msg=name)
        np.testing.assert_array_equal(column(after, name), column(before, name), err_msg=name)
    assert before.i_meas_a is None and after.i_meas_a is None


@pytest.mark.parametrize("name, value", [("torque", np.nan), ("time", np.inf), ("i_ref_b", -np.inf),
                                         ("torque_true", np.nan)])
@pytest.mark.parametrize("encoding", ["PLAIN", "BYTE_STREAM_SPLIT", "RLE_DICTIONARY"])
def test_a_float_column_holding_nan_or_infinity_is_refused_naming_file_row_and_column(tmp_path, simulated, name,
                                                                                     value, encoding):
    path = tmp_path / "trial.parquet"
    write_trial(path, dataclasses.replace(simulated, i_meas_a=None, i_true_a=None, speed_true_rad_s=None))
    table = pq.read_table(path)
    bad = table.column(name).to_numpy().copy()
    bad[[7, 40]] = value
    table = table.set_column(table.schema.get_field_index(name), name, pa.array(bad))
    dictionary = encoding == "RLE_DICTIONARY"
    pq.write_table(table, path, use_dictionary=dictionary, column_encoding=None if dictionary else encoding)
    with pytest.raises(BenchFormatError) as error:
        read_trial(path, simulated.torque_setpoint_nm, simulated.speed_setpoint_hz)
    assert str(error.value) == f"{path}: row 8: {name} is not a finite number"
