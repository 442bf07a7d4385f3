"""Issue 34, item 10: what an import cannot tell from its unit is judged against what the input declares of the
motor ([limits] of the mapping), and refused in one line naming the file and column (or key) and the likely cause;
an empty or constant file, or a log in UTF-16, is refused, never imported as something."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
from conftest import MAPPING_BENCH, PHASE_LOG
from test_import_garbage import native, one_line  # noqa: F401  (native: a fixture)
from test_import_moteus import MAPPING, cogging_file
from test_import_moteus import mapping_file as moteus_mapping  # noqa: F401  (a fixture)
from test_importer import Q_LOG, write_folder, write_phase_log, write_q_log
from test_standstill import LOG as SCAN_LOG

from ilcpmac.bench.format import write_backemf_csv
from ilcpmac.bench.importer import import_log, import_scan, read_mapping, write_scan_folder
from ilcpmac.bench.logs import LOG_LIMIT_FACTOR, ImportLimits
from ilcpmac.bench.standstill import logged_holding_nm
from ilcpmac.core.errors import BenchFormatError, ConfigError
from ilcpmac.sim.standstill import ScanPlan, write_scan_log


@pytest.mark.parametrize(("log_table", "writer", "expected"), [
    (Q_LOG.replace("current_a_per_unit = 0.01", "current_a_per_unit = 10.0"), write_q_log,
     r"line 4: iq -?\d{4}\.?\d* A once scaled, beyond 10x \[limits\] max_current_a = 30 A"),
    (Q_LOG.replace("current_a_per_unit = 0.01", "current_a_per_unit = 1.0"), write_q_log,
     r"line 4: iq -?\d{3}\.?\d* A once scaled, beyond 10x \[limits\] max_current_a = 30 A"),
    (PHASE_LOG + "current_a_per_unit = 1e3\n", write_phase_log, r"line \d+: ia -?\d+\.?\d* A once scaled"),
    (PHASE_LOG + "torque_nm_per_unit = 1e3\n", write_phase_log, r"line 2: tq \d+\.?\d* N m once scaled, beyond 10x "
                                                                r"\[limits\] max_torque_nm = 8 N m"),
])
def test_a_log_in_milli_units_is_refused_naming_the_column(tmp_path, native, log_table, writer,  # noqa: F811
                                                           expected):
    """A log in mA (or an i_q in 10 mA read as A, a torque in mN m) was imported: 718 N m for about 1."""
    trial, backemf = native
    log = writer(tmp_path / "log.csv", trial, 2_000.0)
    with pytest.raises(BenchFormatError) as e:
        import_log(log, read_mapping(write_folder(tmp_path, backemf, log_table)))
    message = one_line(e, log)
    assert re.search(expected, message), message
    assert "most values pass it: a unit 1000x too small (mA for A, mN m for N m?)" in message


def test_the_mappings_limits_judge_the_logged_values(tmp_path, native):  # noqa: F811
    """[limits] states the motor's: a log within LOG_LIMIT_FACTOR of them imports, beyond it is refused."""
    trial, backemf = native
    log = write_phase_log(tmp_path / "log.csv", trial, 2_000.0)
    peak_a = np.abs(trial.i_ref_a).max()
    within = f"\n[limits]\nmax_current_a = {1.01 * peak_a / LOG_LIMIT_FACTOR}\nmax_torque_nm = 8.0\n"
    assert import_log(log, read_mapping(write_folder(tmp_path, backemf, PHASE_LOG, within))).trial.n_samples > 0
    beyond = f"\n[limits]\nmax_current_a = {0.9 * peak_a / LOG_LIMIT_FACTOR}\nmax_torque_nm = 8.0\n"
    with pytest.raises(BenchFormatError, match=r"beyond 10x \[limits\] max_current_a = 0\.\d+ A"):
        import_log(log, read_mapping(write_folder(tmp_path, backemf, PHASE_LOG, beyond)))


@pytest.mark.parametrize(("limits", "expected"), [
    ("max_current_a = 0.0\n", r"\[limits\] max_current_a: invalid value 0"),
    ("max_speed_hz = 1.0\n", r"\[limits\] unknown key 'max_speed_hz' \(known: max_current_a, max_torque_nm\)"),
])
def test_a_mappings_limits_are_checked(tmp_path, native, limits, expected):  # noqa: F811
    _, backemf = native
    with pytest.raises(ConfigError, match=expected):
        read_mapping(write_folder(tmp_path, backemf, PHASE_LOG, "\n[limits]\n" + limits))


def test_without_limits_a_mapping_takes_a_campaigns_defaults(tmp_path, native):  # noqa: F811
    _, backemf = native
    assert read_mapping(write_folder(tmp_path, backemf, PHASE_LOG)).limits == ImportLimits(30.0, 8.0)


def moteus_file(tmp_path: Path, change) -> Path:
    path = cogging_file(tmp_path / "cogging.json", 2048, 3)
    path.write_text(json.dumps(change(json.loads(path.read_text()))))
    return path


@pytest.mark.parametrize(("change", "expected"), [
    (lambda d: {k: [1e3 * x for x in v] for k, v in d.items()},
     r"cogging.json: forward\[0\]: -?\d+\.\d+ A, a holding torque of -?\d+\.\d+ N m, beyond \[limits\] max_torque_nm "
     r"= 8 N m \(of \S+map.toml, its default if not given\): a motor holds its cogging and friction within its "
     r"torque range; most values pass it: a unit 1000x too small"),
    (lambda d: {**d, "forward": d["forward"][:100] + [9999.0] + d["forward"][101:]},
     r"cogging.json: forward\[100\]: 9999 A, a holding torque of 3000 N m, beyond .* an outlier \(a corrupt row or "
     r"bin\?\)"),
    (lambda d: {k: [0.0] * len(v) for k, v in d.items()}, r"every bin holds 0 A: no cogging, nothing to identify"),
    (lambda d: {k: [0.5] * len(v) for k, v in d.items()}, r"every bin holds 0.5 A: no cogging, nothing to identify"),
])
def test_a_moteus_file_in_ma_an_outlier_or_constant_is_refused(tmp_path, moteus_mapping, change,  # noqa: F811
                                                                expected):
    """In mA its cogging came out 47 N m for 0.047; a 9999 A bin made the order-48 cogging 63x too large; a
    constant file gave a cogging of 0."""
    path = moteus_file(tmp_path, change)
    with pytest.raises(BenchFormatError) as e:
        write_scan_folder([path], read_mapping(moteus_mapping), tmp_path / "scan")
    assert re.search(expected, one_line(e, path)), str(e.value)
    assert not (tmp_path / "scan").exists()


def test_a_moteus_file_in_a_small_motors_limits(tmp_path, moteus_mapping):  # noqa: F811
    """[limits] of the motor: the cogging file's holding torque (0.1 N m at most) within max_torque_nm 0.2
    imports, within 0.05 does not."""
    path = cogging_file(tmp_path / "cogging.json", 2048, 3)
    for limit, imports in ((0.2, True), (0.05, False)):
        mapping = moteus_mapping.with_name(f"map_{limit}.toml")
        mapping.write_text(MAPPING + f"\n[limits]\nmax_torque_nm = {limit}\n")
        if imports:
            write_scan_folder([path], read_mapping(mapping), tmp_path / f"scan_{limit}")
        else:
            with pytest.raises(BenchFormatError, match=r"beyond \[limits\] max_torque_nm = 0.05 N m"):
                write_scan_folder([path], read_mapping(mapping), tmp_path / f"scan_{limit}")


@pytest.mark.parametrize(("encoding", "expected"), [
    ("utf-16", r"UTF-16 text \(its byte-order mark\): save it as UTF-8 or ASCII"),
    ("utf-32", r"UTF-32 text \(its byte-order mark\)"),
    ("utf-16-le", r"line 1: a NUL byte \(UTF-16 or UTF-32 text, or not text\)"),
    ("utf-16-be", r"line 1: a NUL byte"),
])
def test_a_log_or_cogging_file_in_utf16_is_refused(tmp_path, native, moteus_mapping, encoding,  # noqa: F811
                                                   expected):
    """A moteus file in UTF-16 imported (json guesses the encoding); a log's message listed NUL-laden names."""
    trial, backemf = native
    log = write_phase_log(tmp_path / "log.csv", trial, 2_000.0)
    log.write_bytes(log.read_text().encode(encoding))
    with pytest.raises(BenchFormatError) as e:
        import_log(log, read_mapping(write_folder(tmp_path, backemf, PHASE_LOG)))
    assert re.search(expected, one_line(e, log))
    cogging = cogging_file(tmp_path / "cogging.json", 2048, 3)
    cogging.write_bytes(cogging.read_text().encode(encoding))
    with pytest.raises(BenchFormatError) as e:
        write_scan_folder([cogging], read_mapping(moteus_mapping), tmp_path / "scan")
    assert re.search(expected, one_line(e, cogging))


def test_a_log_with_a_utf8_byte_order_mark_imports(tmp_path, native):  # noqa: F811
    """A spreadsheet's "CSV UTF-8" starts with one: the first column was not found."""
    trial, backemf = native
    mapping = read_mapping(write_folder(tmp_path, backemf, PHASE_LOG))
    log = write_phase_log(tmp_path / "log.csv", trial, 2_000.0)
    plain = import_log(log, mapping).trial
    log.write_bytes(b"\xef\xbb\xbf" + log.read_bytes())
    np.testing.assert_array_equal(import_log(log, mapping).trial.i_ref_a, plain.i_ref_a)


@pytest.fixture(scope="module")
def scan_log(tmp_path_factory, small_simulator) -> Path:
    folder = tmp_path_factory.mktemp("scan")
    write_scan_log(folder / "scan_log.csv", small_simulator, ScanPlan(seed=5))
    write_backemf_csv(folder / "backemf.csv", small_simulator.backemf_counts)
    return folder / "scan_log.csv"


def test_a_scan_whose_holding_torque_passes_the_motors_range_is_refused(scan_log):
    """A scan holds the rotor against its cogging and friction, a small part of the torque range: a holding
    torque sum_p K_p i_p beyond [limits] max_torque_nm is a wrong unit or an outlier."""
    path = scan_log.parent / "map.toml"
    layout = MAPPING_BENCH + "\n" + SCAN_LOG + 'phase_currents = ["i_a", "i_b", "i_c"]\ndirection = "direction"\n'
    path.write_text(layout)
    mapping = read_mapping(path)
    peak_nm = np.abs(logged_holding_nm(import_scan(scan_log, mapping), mapping.backemf_nm_per_a)).max()
    path.write_text(layout + f"\n[limits]\nmax_torque_nm = {peak_nm / 2}\n")
    with pytest.raises(BenchFormatError) as e:
        import_scan(scan_log, read_mapping(path))
    assert re.search(r"scan_log.csv: line \d+: a holding torque of -?\d+\.?\d* N m, beyond \[limits\] "
                     r"max_torque_nm = \S+ N m \(of \S+map.toml, its default if not given\): a motor holds its cogging "
                     r"and friction within its torque range", one_line(e, scan_log))
