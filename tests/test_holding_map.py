"""Drives' own holding maps imported as a map folder (ilcpmac.bench.holding_map): ODrive's map as it is (zeros
where it did not measure), any per-count array (npy, CSV, JSON list) in A or N m, read bounded and checked."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ilcpmac.bench.holding_map import (
    MAP_DATA_FILE,
    MAP_FILE,
    HoldingMapLog,
    HoldingMapMapping,
    MapSettings,
    holding_map_mapping,
    import_holding_maps,
    import_lines,
    read_holding_maps,
    read_map_file,
)
from ilcpmac.bench.logs import ImportLimits
from ilcpmac.config import BenchSettings
from ilcpmac.core.errors import BenchFormatError, ConfigError
from ilcpmac.core.schema import key_table, parse_section, read_toml

DATA = Path(__file__).parent / "data" / "odrive-slow-velocity"
BENCH = "[bench]\npole_pairs = 7\nslots = 12\ncounts_per_rev = 8192\n"
LOG = '[log]\nkind = "holding-map"\ntorque_constant_nm_per_a = 0.03\n'


def mapping(tmp_path: Path, text: str = BENCH + LOG, backemf: np.ndarray | None = None) -> HoldingMapMapping:
    """A mapping parsed as `ilcpmac.bench.importer.read_mapping` hands a holding map's to `holding_map_mapping`."""
    path = tmp_path / "map.toml"
    path.write_text(text)
    data = read_toml(path)
    bench = parse_section(data["bench"], BenchSettings, str(path), "bench")
    limits = parse_section(data.get("limits", {}), ImportLimits, str(path), "limits")
    return holding_map_mapping(data, bench, limits, path, backemf)


def test_odrive_maps_import_as_they_are_and_map_b_correlates_with_map_a(tmp_path):
    folders = {}
    for name in "ab":
        imported = import_holding_maps([DATA / f"holding_map_{name}.npy"], mapping(tmp_path), tmp_path / name)
        folders[name] = read_holding_maps(tmp_path / name)
        np.testing.assert_array_equal(folders[name].position_counts, imported.position_counts)
    raw = np.load(DATA / "holding_map_a.npy")
    a, b = folders["a"], folders["b"]
    np.testing.assert_array_equal(a.position_counts, np.arange(0, 8192, 16))
    np.testing.assert_allclose(a.values[0], raw[::16], atol=5e-10)
    assert a.unit == "A" and a.nm_per_unit == 0.03 and a.cogging_order == 84
    correlation = np.corrcoef(a.values[0], b.values[0])[0, 1]
    assert correlation >= 0.998  # measured: 0.99871
    assert import_lines(a, tmp_path / "a")[0] == ("1 holding map -> holding_map.csv: 512 measured positions a "
                                                  "revolution of 8192 counts, from count 0, holding current in A, "
                                                  "k_q = 0.03 N m / A")


def test_every_format_and_unit_gives_the_same_folder(tmp_path):
    raw = np.load(DATA / "holding_map_a.npy")
    (tmp_path / "m.csv").write_text("".join(f"{1000 * float(v)!r}\n" for v in raw))
    (tmp_path / "h.csv").write_text("count,iq_ma\n" + "".join(f"{c},{1000 * float(v)!r}\n" for c, v in enumerate(raw)))
    (tmp_path / "m.json").write_text(json.dumps((1000 * raw).tolist()))
    np.save(tmp_path / "m.npy", 1000 * raw)
    milli = BENCH + LOG + "value_per_unit = 1e-3\n"
    reference = import_holding_maps([DATA / "holding_map_a.npy"], mapping(tmp_path), tmp_path / "ref").values
    for name, text in (("m.csv", milli), ("h.csv", milli + 'column = "iq_ma"\n'), ("m.json", milli),
                       ("m.npy", milli)):
        values = import_holding_maps([tmp_path / name], mapping(tmp_path, text), tmp_path / f"out-{name}").values
        np.testing.assert_allclose(values, reference, rtol=1e-12, atol=1e-15)


def test_a_torque_map_on_a_map_of_other_entries_sits_at_its_counts(tmp_path):
    entries = 3600
    theta = 2 * np.pi * np.arange(entries) / entries
    np.save(tmp_path / "t.npy", 0.01 * np.cos(84 * theta) + 0.002)
    text = BENCH + '[log]\nkind = "holding-map"\nquantity = "torque"\ncounts_per_rev = 3600\nmeasured_every = 1\n'
    maps = import_holding_maps([tmp_path / "t.npy"], mapping(tmp_path, text), tmp_path / "out")
    back = read_holding_maps(tmp_path / "out")
    np.testing.assert_allclose(back.position_counts, np.arange(entries) * 8192 / 3600, atol=1e-6)
    np.testing.assert_allclose(back.values, maps.values, atol=1e-9)
    assert back.unit == "N m" and back.nm_per_unit == 1.0


def test_measured_every_takes_zeros_on_the_grid_which_the_non_zero_entries_refuse(tmp_path):
    raw = np.load(DATA / "holding_map_a.npy").copy()
    raw[4096] = 0.0
    np.save(tmp_path / "z.npy", raw)
    with pytest.raises(BenchFormatError, match=r"z.npy: entry 4096 is 0 on the grid of every 16th entry from 0 .*"
                                               r"measured_every = 16"):
        import_holding_maps([tmp_path / "z.npy"], mapping(tmp_path), tmp_path / "out")
    maps = import_holding_maps([tmp_path / "z.npy"], mapping(tmp_path, BENCH + LOG + "measured_every = 16\n"),
                               tmp_path / "out")
    assert maps.values.shape == (1, 512) and maps.values[0, 256] == 0.0


def test_a_back_emf_table_gives_k_q_and_mapping_keys_are_checked(tmp_path):
    theta_e = 7 * 2 * np.pi * np.arange(8192) / 8192
    table = 0.02 * np.column_stack([np.sin(theta_e - 2 * np.pi * k / 3) for k in range(3)])
    plain = BENCH + '[log]\nkind = "holding-map"\n'
    assert mapping(tmp_path, plain, table).torque_constant_nm_per_a == pytest.approx(0.03)
    cases = [(plain, None, "needs the torque constant k_q"),
             (BENCH + LOG, table, "not both"),
             (BENCH + '[log]\nkind = "holding-map"\nquantity = "torque"\ntorque_constant_nm_per_a = 1\n', None,
              'not for a map of holding torques'),
             (BENCH + LOG + "measured_first = 3\n", None, "measured_first: only with measured_every"),
             (BENCH + LOG + "[[points]]\nfile = 'a'\n", None, r"\[points\]: not for holding maps"),
             (BENCH + LOG + "measured_every = 0\n", None, r"\[log\] measured_every"),
             (BENCH + LOG + 'quantity = "flux"\n', None, r"\[log\] quantity"),
             (BENCH + LOG + "time = 'x'\n", None, r"\[log\] unknown key 'time'")]
    for text, backemf, message in cases:
        with pytest.raises(ConfigError, match=message):
            mapping(tmp_path, text, backemf)


@pytest.mark.parametrize(("name", "content", "message"), [
    ("m.txt", b"1\n2\n", r"a holding map is \.npy, \.csv, \.json"),
    ("m.json", b"[1, 2, 3]", r"holds 3 values \(3\), one map needs 8192"),
    ("m.json", json.dumps([True] * 8192).encode(), "entry 0: True is not a number"),
    ("m.json", b'{"map": [1, 2]}', "holds a JSON dict, not a list of numbers"),
    ("m.json", b"[" * 100000, "not a JSON list of numbers|not JSON"),
    ("m.csv", "\ufeff1\n".encode("utf-16"), "UTF-16 text"),
    ("m.csv", b"1\nx\n" + b"1\n" * 8190, "line 2, column 1"),
    ("m.csv", b"1,2\n" * 8192, "has 2 fields"),
    ("m.npy", b"\x93NUMPY garbage", "not a NumPy array file"),
])
def test_hostile_map_files_are_one_line_errors(tmp_path, name, content, message):
    (tmp_path / name).write_bytes(content)
    with pytest.raises(BenchFormatError, match=message):
        import_holding_maps([tmp_path / name], mapping(tmp_path), tmp_path / "out")
    assert not (tmp_path / "out").exists()


def test_pickles_shapes_and_non_finite_values_are_refused(tmp_path):
    np.save(tmp_path / "o.npy", np.array([{"a": 1}] * 8192, dtype=object), allow_pickle=True)
    np.save(tmp_path / "two.npy", np.ones((2, 8192)))
    bad = np.load(DATA / "holding_map_a.npy").copy()
    bad[32] = np.nan
    np.save(tmp_path / "nan.npy", bad)
    np.save(tmp_path / "bool.npy", np.ones(8192, bool))
    for name, message in (("o.npy", "not a NumPy array file"), ("two.npy", r"holds 16384 values \(2x8192\)"),
                          ("nan.npy", "entry 32: nan is not a finite number"), ("bool.npy", "not real numbers")):
        with pytest.raises(BenchFormatError, match=message):
            read_map_file(tmp_path / name, 8192)


def test_magnitudes_are_judged_against_the_limits(tmp_path):
    raw = np.load(DATA / "holding_map_a.npy")
    np.save(tmp_path / "ma.npy", 1000 * raw)  # mA read as A
    spike = raw.copy()
    spike[160] = 25.0
    np.save(tmp_path / "spike.npy", spike)
    np.save(tmp_path / "flat.npy", np.where(raw != 0, 0.5, 0.0))
    cases = [("ma.npy", BENCH + LOG, r"entry 0: a holding current of 331\.2 A, beyond \[limits\] max_current_a = 30 "
                                     r"A .*most values pass it"),
             ("spike.npy", BENCH + LOG + "[limits]\nmax_current_a = 30\nmax_torque_nm = 0.5\n",
              r"entry 160: a holding torque of 0\.75 N m, beyond \[limits\] max_torque_nm = 0\.5 N m.*an outlier"),
             ("flat.npy", BENCH + LOG, "every measured entry holds 0.5: no position torque")]
    for name, text, message in cases:
        with pytest.raises(BenchFormatError, match=message):
            import_holding_maps([tmp_path / name], mapping(tmp_path, text), tmp_path / "out")


def test_maps_of_one_import_measure_the_same_entries_and_an_old_folder_is_kept(tmp_path):
    raw = np.load(DATA / "holding_map_a.npy")
    np.save(tmp_path / "shifted.npy", np.roll(raw, 8))
    with pytest.raises(BenchFormatError, match="measure the same entries"):
        import_holding_maps([DATA / "holding_map_a.npy", tmp_path / "shifted.npy"], mapping(tmp_path),
                            tmp_path / "out")
    import_holding_maps([DATA / "holding_map_a.npy"], mapping(tmp_path), tmp_path / "out")
    with pytest.raises(BenchFormatError, match="holds a holding_map.toml already"):
        import_holding_maps([DATA / "holding_map_b.npy"], mapping(tmp_path), tmp_path / "out")


def test_a_map_folder_edited_by_hand_is_refused(tmp_path):
    import_holding_maps([DATA / "holding_map_a.npy"], mapping(tmp_path), tmp_path / "out")
    data = (tmp_path / "out" / MAP_DATA_FILE).read_text().splitlines()
    cases = [(data[:3] + ["40.5,0.1"] + data[4:], "line 4: position 40.5 is off the even grid of 512 points"),
             (["position,map_1,map_2"] + data[1:], "line 1 must be position,map_1"),
             (data[:2] + ["16.0,20000.5"] + data[3:], "line 3: map_1 beyond"),
             (data[:2] + ["16.0,abc"] + data[3:], "plain decimal numbers")]
    original = (tmp_path / "out" / MAP_DATA_FILE).read_text()
    for lines, message in cases:
        (tmp_path / "out" / MAP_DATA_FILE).write_text("\n".join(lines) + "\n")
        with pytest.raises(BenchFormatError, match=message):
            read_holding_maps(tmp_path / "out")
    (tmp_path / "out" / MAP_DATA_FILE).write_text(original)
    toml = (tmp_path / "out" / MAP_FILE).read_text()
    (tmp_path / "out" / MAP_FILE).write_text(toml.replace("torque_constant_nm_per_a = 0.03\n", ""))
    with pytest.raises(BenchFormatError, match="torque_constant_nm_per_a: given when, and only when"):
        read_holding_maps(tmp_path / "out")


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(content=st.binary(max_size=300), suffix=st.sampled_from([".npy", ".csv", ".json"]))
def test_any_bytes_are_a_map_or_one_bench_format_error(tmp_path, content, suffix):
    path = tmp_path / f"any{suffix}"
    path.write_bytes(content)
    try:
        values = read_map_file(path, 4)
    except BenchFormatError as e:
        assert "\n" not in str(e) and str(path) in str(e)
    else:
        assert values.shape == (4,) and np.all(np.isfinite(values))


def test_the_guide_documents_the_keys_from_their_declaration():
    guide = (Path(__file__).resolve().parents[1] / "docs" / "drive-maps.md").read_text()
    assert key_table(HoldingMapLog, "log") in guide
    assert key_table(MapSettings, "map", heading="### [map] (holding_map.toml)") in guide


def test_one_map_twice_is_no_repeat(tmp_path):
    (tmp_path / "copy").mkdir()
    copy = tmp_path / "copy" / "holding_map_a.npy"
    copy.write_bytes((DATA / "holding_map_a.npy").read_bytes())
    with pytest.raises(BenchFormatError, match=r"copy/holding_map_a.npy: the same values as .*holding_map_a.npy: a "
                                               "repeat measures the motor again"):
        import_holding_maps([DATA / "holding_map_a.npy", copy], mapping(tmp_path), tmp_path / "out")
