"""A holding map decomposed (ilcpmac.identify.map_decomposition): synthetic maps of known parts and noise (seeded),
a map made by the sensor errors' physics, and ODrive's real maps of a 7-pole-pair, 12-slot motor; the result's
cogging and whole map exported through `read_position_table`."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ilcpmac.bench.holding_map import HoldingMaps, MapSettings, holding_map_mapping, import_holding_maps
from ilcpmac.bench.logs import ImportLimits
from ilcpmac.compensation import read_position_table
from ilcpmac.config import BenchSettings
from ilcpmac.core.errors import BenchFormatError
from ilcpmac.export import export
from ilcpmac.identify.map_decomposition import MAX_SCALE_IMBALANCE, decompose_map, identify_map

DATA = Path(__file__).parent / "data" / "odrive-slow-velocity"
P, SLOTS, CPR, POINTS = 7, 12, 8192, 512
K_Q = 0.03
#: the synthetic map's harmonics, A: offsets (7), 2p (14), cogging (84, 168, 252) and a rest (28, 36)
TRUTH = {7: (0.5, -0.3), 14: (0.1, 0.2), 84: (0.05, -0.02), 168: (0.01, 0.01), 252: (0.004, -0.003),
         28: (0.2, 0.1), 36: (-0.1, 0.05)}


def series(terms: dict[int, tuple[float, float]], theta: np.ndarray) -> np.ndarray:
    return sum(a * np.cos(h * theta) + b * np.sin(h * theta) for h, (a, b) in terms.items())


def synthetic(seed: int, maps: int, noise_a: float, first: float = 5.0, points: int = POINTS) -> HoldingMaps:
    """``maps`` maps of the TRUTH and a mean of 0.1 A on ``points`` even positions from ``first``, each with its own
    white noise of ``noise_a`` per point."""
    rng = np.random.default_rng(seed)
    position = first + np.arange(points) * CPR / points
    clean = 0.1 + series(TRUTH, 2 * np.pi * position / CPR)
    return HoldingMaps(MapSettings(P, SLOTS, CPR, tuple(f"map{k}.npy" for k in range(maps)), "current", K_Q),
                       position, clean + noise_a * rng.standard_normal((maps, points)))


@pytest.mark.parametrize("maps", [1, 2, 4])
def test_known_parts_come_out_within_their_standard_errors_which_match_the_noise(maps):
    noise_a = 0.02
    z, ratios = [], []
    for seed in range(12):
        d = decompose_map(synthetic(seed, maps, noise_a))
        assert [h.order for h in d.offsets.harmonics] == [7] and [h.order for h in d.scale.harmonics] == [14]
        assert [h.order for h in d.cogging.harmonics] == [84, 168, 252]
        assert [h.order for h in d.rest.harmonics[:2]] == [28, 36]
        for part in (d.offsets, d.scale, d.cogging, d.rest):
            for h in part.harmonics[:2] if part is d.rest else part.harmonics:
                a, b = TRUTH[h.order]
                z += [(h.cos - a) / h.std, (h.sin - b) / h.std]
                ratios.append(h.std / (noise_a * np.sqrt(2 / POINTS / maps)))
    z = np.asarray(z)
    # measured (12 seeds): z RMS 0.92-1.05, largest |z| 2.6-3.8; standard errors 0.99-1.01x the truth's on average,
    # each 0.67-1.30x
    assert 0.8 < np.sqrt(np.mean(z**2)) < 1.25 and np.max(np.abs(z)) < 4.5
    assert 0.85 < np.mean(ratios) < 1.15 and 0.6 < np.min(ratios) and np.max(ratios) < 1.5


def test_power_shares_tables_and_recalibration_add_up():
    maps = synthetic(3, 1, 0.002)
    d = decompose_map(maps)
    shares = [part.power_share for part in d.parts.values()]
    assert sum(shares) == pytest.approx(1.0, abs=1e-9)
    assert d.offsets.power_share == pytest.approx((0.5**2 + 0.3**2) / 2 / d.rms**2, rel=0.01)
    removed = d.recalibrations[0]
    assert removed.removes == "offsets" and removed.power_removed == pytest.approx(d.offsets.power_share, abs=1e-9)
    # the whole map per count is the map at its measured counts (position torque = -k_q (i - mean))
    on_counts = synthetic(3, 1, 0.002, first=0.0)
    measured = on_counts.position_counts.astype(int)
    np.testing.assert_allclose(decompose_map(on_counts).position_torque_nm[measured],
                               -K_Q * (on_counts.values[0] - on_counts.values.mean()), atol=1e-12)
    # the cogging table is the cogging orders' series, negated, in N m
    theta = 2 * np.pi * np.arange(CPR) / CPR
    cogging = -K_Q * series({h: TRUTH[h] for h in (84, 168, 252)}, theta)
    assert np.sqrt(np.mean((d.cogging_nm - cogging) ** 2)) < 0.02 * np.sqrt(np.mean(cogging**2))
    assert d.cogging_std_nm[0] == pytest.approx(K_Q * np.sqrt(3 * 2 * 0.002**2 / POINTS), rel=0.4)


@pytest.mark.parametrize("eps", [0.02, 0.05])
def test_a_scale_imbalance_is_found_within_its_bound(eps):
    """The map of a motor whose current sensors' scales differ (g = 1 + eps cos(2p theta + 0.7)) and offsets
    give order p: the drive holds k_q i g - k_q b = holding torque, so i = (h / k_q + b) / g."""
    rng = np.random.default_rng(1)
    position = np.arange(POINTS) * CPR / POINTS
    theta = 2 * np.pi * position / CPR
    holding = 0.1 + 0.05 * np.cos(84 * theta) + 0.2 * np.cos(28 * theta + 0.3) + 0.1 * np.sin(36 * theta)
    current = (holding + 0.4 * np.cos(7 * theta + 1.0)) / (1 + eps * np.cos(14 * theta + 0.7))
    maps = HoldingMaps(MapSettings(P, SLOTS, CPR, ("x.npy",), "current", K_Q), position,
                       current[None] + 0.002 * rng.standard_normal((1, POINTS)))
    d = decompose_map(maps)
    # measured: 0.0173 for eps 0.02, 0.0433 for eps 0.05: the bound holds, and names the imbalance's size
    assert 0.6 * eps < d.scale_imbalance_min <= eps
    assert not any("position-locked" in m for m in d.messages)
    assert d.recalibrations[1].removes == "offsets and scale"
    assert d.recalibrations[1].power_removed > d.recalibrations[0].power_removed


def test_a_2p_torque_too_large_for_the_sensors_is_said_to_be_position_locked():
    d = decompose_map(synthetic(2, 1, 0.002))  # order 14 of 0.22 A on a mean of 0.1 A and order 28 of 0.22 A
    assert d.scale_imbalance_min == pytest.approx(np.hypot(0.1, 0.2) / (0.1 + np.hypot(0.2, 0.1) / 2), rel=0.02)
    (message,) = [m for m in d.messages if "position-locked" in m]
    assert f"at most {MAX_SCALE_IMBALANCE / d.scale_imbalance_min:.0%} of it is the current sensors' scale" in message


def test_orders_the_points_do_not_resolve_are_said_and_too_few_points_refused():
    d = decompose_map(synthetic(1, 2, 0.002, points=64))  # orders 1-31: p and 2p, no cogging order
    assert d.cogging is None and d.cogging_nm is None
    assert any("cogging: order 84 is beyond the 64 points' resolution (orders 1-31)" in m for m in d.messages)
    with pytest.raises(BenchFormatError, match="tiny: 6 orders to measure the noise from, fewer than 8"):
        decompose_map(synthetic(1, 1, 0.002, points=16), "tiny")


def _odrive(tmp_path: Path, names: str) -> Path:
    path = tmp_path / "map.toml"
    path.write_text('[bench]\npole_pairs = 7\nslots = 12\ncounts_per_rev = 8192\n[log]\nkind = "holding-map"\n'
                    f"torque_constant_nm_per_a = {K_Q}\n")
    bench = BenchSettings(pole_pairs=7, slots=12, counts_per_rev=8192)
    mapping = holding_map_mapping({"log": {"kind": "holding-map", "torque_constant_nm_per_a": K_Q}}, bench,
                                  ImportLimits(), path)
    out = tmp_path / f"map-{names}"
    import_holding_maps([DATA / f"holding_map_{name}.npy" for name in names], mapping, out)
    return out


def test_odrive_map_a_names_its_order_7_and_14_parts_with_standard_errors(tmp_path):
    d, lines = identify_map(_odrive(tmp_path, "a"), tmp_path / "a.json")
    (offsets,), (twice,) = d.offsets.harmonics, d.scale.harmonics
    # measured: 0.8694 ± 0.0073 A at 105.5 ± 0.48 deg; 0.3508 ± 0.0073 A at -93.5 ± 1.2 deg
    assert offsets.order == 7 and offsets.amplitude == pytest.approx(0.869, abs=0.002) and 0 < offsets.std < 0.01
    assert twice.order == 14 and twice.amplitude == pytest.approx(0.351, abs=0.002) and 0 < twice.std < 0.01
    assert d.offsets.power_share + d.scale.power_share == pytest.approx(0.63, abs=0.01)  # the 64 %
    assert [h.order for h in d.rest.harmonics[:3]] == [28, 36, 12]
    assert d.scale_imbalance_min > 0.8  # order 14 is no scale imbalance at a mean holding current of 0.12 A
    assert any(line.startswith("current-sensor offsets (order 7: 0.8694 ± 0.0073 A") for line in lines)
    assert any(line.startswith("scale imbalance or a 2p torque (order 14: 0.3508 ± 0.0073 A") for line in lines)
    data = json.loads((tmp_path / "a.json").read_text())
    assert data["kind"] == "holding_map" and data["parts"]["offsets"]["harmonics"][0]["std"] == offsets.std


def test_odrive_maps_a_and_b_together_measure_their_noise_and_see_the_offsets_move(tmp_path):
    d, _ = identify_map(_odrive(tmp_path, "ab"), tmp_path / "ab.json")
    (offsets,) = d.offsets.harmonics
    # measured: 0.8655 ± 0.0013 A; the two maps' order 7 differ by 0.025 A, 7.1 times their noise
    assert offsets.amplitude == pytest.approx(0.866, abs=0.002) and 0 < offsets.std < 0.003
    assert ("offsets", 7) in [(name, h.order) for name, h in d.changed] and offsets.moved > 4
    assert d.noise_estimator.startswith("the scatter of 2 maps")


@pytest.mark.parametrize(("content", "orders"), [("cogging", [84, 168, 252]), ("position-torque", None)])
def test_the_result_exports_as_a_position_table(tmp_path, content, orders):
    out = _odrive(tmp_path, "ab")
    d, _ = identify_map(out, tmp_path / "ab.json")
    table = read_position_table(tmp_path / "ab.json", content)
    expected = d.cogging_nm if content == "cogging" else d.position_torque_nm
    np.testing.assert_allclose(table.feedforward_nm, -expected)
    if orders is not None:  # the multiples of 84 the counts hold; those beyond the map's points are 0
        coefficients = np.abs(table.coefficients_nm()).max(axis=1)
        assert table.orders[coefficients > 1e-12].tolist() == orders
    exported = export(table, tmp_path / f"export-{content}", "moteus", torque_constant_nm_per_a=K_Q)
    assert exported.files and exported.residual is not None


def test_the_result_is_read_as_per_count_tables_with_their_cogging_order(tmp_path):
    identify_map(_odrive(tmp_path, "a"), tmp_path / "a.json")
    data = json.loads((tmp_path / "a.json").read_text())
    data["cogging"]["count"] = data["cogging"]["count"][::-1]
    (tmp_path / "bad.json").write_text(json.dumps(data))
    with pytest.raises(BenchFormatError, match=r"key 'cogging.count': must be the counts 0 .. 8191"):
        read_position_table(tmp_path / "bad.json")


def test_copies_of_one_map_measure_no_noise_and_are_refused():
    maps = synthetic(1, 1, 0.002)
    copies = HoldingMaps(maps.settings, maps.position_counts, np.repeat(maps.values, 2, axis=0))
    with pytest.raises(BenchFormatError, match="copied: the noise of order 1 measures 0 .*no standard error"):
        decompose_map(copies, "copied")
