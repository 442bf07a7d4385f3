"""Issue 27, items 6 and 7: wrong data in a drive log or a bench folder is refused in one line naming the file
and the line, column or key; never dropped, interpolated over or echoed."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from conftest import COUNTS_PER_REV, PHASE_LOG
from test_bench_format import write_folder as write_bench_folder
from test_importer import scaled_column, write_folder, write_phase_log

from ilcpmac.bench import read_bench
from ilcpmac.bench.importer import import_log, read_mapping
from ilcpmac.core.errors import BenchFormatError, ConfigError
from ilcpmac.sim.simulator import Simulator

#: a file that is no back-EMF table, with text that must never show in a message
SECRET = "s3cr3t-hash"


@pytest.fixture(scope="module")
def native(small_model, make_request):
    """A trial of the small seed bench at 2 N m, 0.5 Hz, and its back-EMF table (as tests/test_importer.py's)."""
    simulator = Simulator(small_model)
    return simulator.run_trial(make_request(small_model, 2.0, 0.5)), simulator.backemf_counts


def one_line(error: pytest.ExceptionInfo, start: Path) -> str:
    message = str(error.value)
    assert "\n" not in message and message.startswith(str(start)), message
    return message


def quiet_row(log: Path) -> int:
    """The file line of a row whose two neighbouring intervals cross no encoder count: no count's value is
    interpolated from it."""
    theta = np.loadtxt(log, delimiter=",", skiprows=1)[:, 1]
    count = np.floor(theta * COUNTS_PER_REV / (2 * np.pi))
    quiet = np.flatnonzero((count[1:-1] == count[:-2]) & (count[1:-1] == count[2:])) + 1
    return int(quiet[len(quiet) // 2]) + 2


@pytest.mark.parametrize(("column", "value", "expected"), [
    (5, "1e300", r"tq beyond 1e\+05 N m once scaled"),
    (2, "1e5", r"ia beyond 1e\+04 A once scaled"),
])
def test_an_impossible_value_between_counts_is_refused_not_dropped(tmp_path, native, column, value, expected):
    """Item 6a: at 10 kHz (about 20 rows per count) a row between two counts feeds no count: it was dropped."""
    trial, backemf = native
    mapping = read_mapping(write_folder(tmp_path, backemf, PHASE_LOG))
    log = write_phase_log(tmp_path / "log.csv", trial, 10_000.0)
    line = quiet_row(log)
    lines = log.read_text().splitlines()
    fields = lines[line - 1].split(",")
    fields[column] = value
    lines[line - 1] = ",".join(fields)
    log.write_text("\n".join(lines) + "\n")
    with pytest.raises(BenchFormatError) as e:
        import_log(log, mapping)
    assert re.search(rf"log.csv: line {line}: {expected}", one_line(e, log))


def test_a_gap_in_the_time_column_is_refused_not_interpolated_over(tmp_path, native):
    """Item 6b: 10 s missing from a 2 kHz log of 0.5 Hz would make its speed set point about 0.14 Hz."""
    trial, backemf = native
    mapping = read_mapping(write_folder(tmp_path, backemf, PHASE_LOG))
    log = write_phase_log(tmp_path / "log.csv", trial, 2_000.0)
    table = np.loadtxt(log, delimiter=",", skiprows=1)
    table[3000:, 0] += 10.0
    np.savetxt(log, table, delimiter=",", header="t,theta,ia,ib,ic,tq", comments="", fmt="%.12g")
    with pytest.raises(BenchFormatError) as e:
        import_log(log, mapping)
    assert re.fullmatch(r"\S*log.csv: line 3002: t jumps by 10 s, 2e\+04 times the median row interval 0.0005 s "
                        r"\(more than 10: rows are missing; cut the log at the gap\)", one_line(e, log))


@pytest.mark.parametrize(("factor", "layout_change", "expected"), [
    (1e3, ("", ""), "t looks like ms, not s"),  # a column in ms read as s: 0.000485 Hz
    (1.0, ('time = "t"', 'time = "t"\ntime_s_per_unit = 1e-3'), "t looks like s, not ms"),  # 485 Hz
])
def test_a_time_column_off_by_1000_is_refused_naming_the_unit(tmp_path, native, factor, layout_change, expected):
    """Item 6c: the rows' rate (2 kHz logged) says which unit the time column is in."""
    trial, backemf = native
    mapping = read_mapping(write_folder(tmp_path, backemf, PHASE_LOG.replace(*layout_change)))
    log = scaled_column(write_phase_log(tmp_path / "log.csv", trial, 2_000.0), 0, factor)
    with pytest.raises(BenchFormatError) as e:
        import_log(log, mapping)
    message = one_line(e, log)
    assert re.search(r"log.csv: t gives \S+ rows per second and a mean speed of \S+ Hz; a drive logs 10 to 200000 "
                     rf"rows per second at 0.01 Hz or faster: {expected} \(\[log\] time_s_per_unit = \S+ in "
                     r"\S*map.toml\)$", message)


@pytest.mark.parametrize("text", [
    f"{SECRET}:x:0:0::/:/bin/sh\ndaemon:{SECRET}:19000:0:99999:7:::\n",
    f"count,k_a,k_b,k_c\n0,0.1,0.2,{SECRET}\n",
    f"count,k_a,k_b,{SECRET}\n0,0.1,0.2,0.3\n",
    f"count,k_a,k_b,k_c\n#{SECRET}\n",
])
def test_a_backemf_file_anywhere_is_never_echoed(tmp_path, native, text):
    """Item 6d: a mapping's backemf_file may be any path; what the file holds must not show in the error."""
    other = tmp_path / "other"
    other.mkdir()
    (other / "shadow").write_text(text)
    mapping = write_folder(tmp_path, native[1], PHASE_LOG)
    mapping.write_text(mapping.read_text().replace('"backemf.csv"', f'"{other / "shadow"}"'))
    with pytest.raises(ConfigError) as e:
        read_mapping(mapping)
    message = one_line(e, mapping)
    assert SECRET not in message and "daemon" not in message
    assert re.search(r"\[bench\] backemf_file: \S*shadow: line \d", message), message


@pytest.mark.parametrize(("old", "new", "expected"), [
    ("\n2,1.0000,", "\n#2,1.0000,", r"line 4, column 1 \(count\): not a number"),  # the row dropped as a comment
    ("-1.5,0.03\n", "-1.5,#0.03\n", r"line 4, column 6 \(torque\): not a number"),
])
def test_a_hash_in_a_trial_row_is_refused(tmp_path, old, new, expected):
    """Item 7a: a '#' is no comment in a trial file."""
    folder = write_bench_folder(tmp_path, ("trial_01.csv", old, new))
    with pytest.raises(BenchFormatError) as e:
        read_bench(folder)
    assert re.fullmatch(rf"\S*trial_01.csv: {expected}", one_line(e, folder / "trial_01.csv"))


@pytest.mark.parametrize("setpoint", ["0.07", "10.0"])
def test_a_torque_setpoint_10x_off_the_current_references_is_refused(tmp_path, setpoint):
    """Item 7b: the references ask for 0.706 N m on average; 1.0 N m passes, 10x either way does not."""
    folder = write_bench_folder(tmp_path, ("bench.toml", "torque_setpoint = 1.0", f"torque_setpoint = {setpoint}"))
    with pytest.raises(BenchFormatError) as e:
        read_bench(folder)
    assert re.fullmatch(
        rf"\S*bench.toml: \[\[trials\]\] #1 torque_setpoint: {setpoint.rstrip('0').rstrip('.')} N m, but the current "
        r"references of \S*trial_01.csv ask for 0.706 N m on average \(K . i_ref\), more than 2x apart \(wrong set "
        r"point, current unit or back-EMF table\?\)", one_line(e, folder / "bench.toml"))


def test_a_points_torque_setpoint_10x_off_is_refused(tmp_path, native):
    """Item 7b on import: [[points]] torque_setpoint_nm against the log's current references (2 N m)."""
    trial, backemf = native
    points = '\n[[points]]\nfile = "log.csv"\ntorque_setpoint_nm = 20.0\nspeed_setpoint_hz = 0.5\n'
    mapping = read_mapping(write_folder(tmp_path, backemf, PHASE_LOG, points))
    with pytest.raises(BenchFormatError) as e:
        import_log(write_phase_log(tmp_path / "log.csv", trial, 2_000.0), mapping)
    assert re.search(r"map.toml: \[\[points\]\] file 'log.csv' torque_setpoint_nm: 20 N m, but the current "
                     r"references of \S*log.csv ask for 2 N m on average", one_line(e, mapping.path))
