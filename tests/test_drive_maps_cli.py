"""A drive's own holding maps (issue 35, item 4) through the CLI and the API, end to end: ODrive's two maps of
tests/data/odrive-slow-velocity imported as they are (``ilcpmac import`` with map-mapping.toml), decomposed
(``ilcpmac identify``) and exported (``ilcpmac export``)."""

from __future__ import annotations

import contextlib
import json
import re
from pathlib import Path

import numpy as np
from click.testing import CliRunner, Result

import ilcpmac.api as ilc
from ilcpmac.bench.holding_map import MAP_DATA_FILE, MAP_FILE
from ilcpmac.cli import main
from ilcpmac.core.errors import BenchFormatError

DATA = Path(__file__).resolve().parent / "data" / "odrive-slow-velocity"
MAPPING = DATA / "map-mapping.toml"


def run(folder: Path, *words) -> Result:
    with contextlib.chdir(folder):
        result = CliRunner().invoke(main, [str(w) for w in words])
    assert result.exit_code == 0, f"{words}\n{result.output}"
    return result


def test_odrive_maps_import_decompose_and_export_through_the_cli(tmp_path):
    said = run(tmp_path, "import", DATA / "holding_map_a.npy", DATA / "holding_map_b.npy", "--map", MAPPING,
               "--out", "maps").output
    assert "2 holding maps" in said and "512 measured positions" in " ".join(said.split())
    assert {p.name for p in (tmp_path / "maps").iterdir()} >= {MAP_FILE, MAP_DATA_FILE}
    lines = " ".join(run(tmp_path, "identify", "maps", "--output", "decomposition.json").output.split())
    # the orders the issue names, each with its standard error
    for order in (7, 14):
        assert re.search(rf"\(order {order}: [\d.]+ ± [\d.]+ A at", lines), lines
    assert "at the next boot the offset calibration changes order 7" in lines
    json.loads((tmp_path / "decomposition.json").read_text())
    exported = run(tmp_path, "export", "decomposition.json", "--format", "moteus", "--out", "fw",
                   "--torque-constant", "0.03").output
    assert [p.name for p in (tmp_path / "fw").iterdir()] == ["moteus_cogging.txt"]
    assert "cogging_dq_scale" in (tmp_path / "fw" / "moteus_cogging.txt").read_text()
    assert "residual ripple of the moteus export" in exported


def test_map_b_imported_correlates_with_map_a_through_the_api(tmp_path):
    maps = {name: ilc.import_maps(DATA / f"holding_map_{name}.npy", MAPPING, tmp_path / name) for name in "ab"}
    a, b = (maps[name].values[0] - maps[name].values[0].mean() for name in "ab")
    np.testing.assert_array_equal(maps["a"].position_counts, maps["b"].position_counts)
    assert np.corrcoef(a, b)[0, 1] >= 0.998
    decomposed = ilc.identify(tmp_path / "a")
    assert decomposed.messages is not None and decomposed.to_json()


def test_the_api_routes_each_kind_of_log_to_its_import(tmp_path):
    log = DATA / "velocity_0.1revs_anticogging_off.npy"
    try:
        ilc.import_logs(log, DATA / "log-mapping.toml", tmp_path / "bench")
    except BenchFormatError as e:
        assert "import_rolling keeps such a log as it is" in str(e)
    else:
        raise AssertionError("a stick-slip log resampled per count")
    data = ilc.import_rolling(log, DATA / "log-mapping.toml", tmp_path / "rolling")
    assert data.time_s.size > 4000
    result = ilc.identify(tmp_path / "rolling")
    assert result.position_torque_nm is not None
    for wrong, mapping in ((ilc.import_logs, MAPPING), (ilc.import_rolling, MAPPING),
                           (ilc.import_maps, DATA / "log-mapping.toml")):
        try:
            wrong(log, mapping, tmp_path / "nothing")
        except BenchFormatError as e:
            assert "takes it" in str(e) or "not a holding map's mapping" in str(e), e
        else:
            raise AssertionError(f"{wrong.__name__} took {mapping.name}")
        assert not (tmp_path / "nothing").exists()
