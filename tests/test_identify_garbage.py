"""Issue 34, items 10 and 17: `ilcpmac identify` on data its model does not describe (a campaign's compensated
trials, the torque and a current reference swapped, a cogging order the counts cannot resolve, an outlier in a
scan) identifies what it can or refuses in one line; never a RuntimeWarning, never a progress line before the
error, never a result too uncertain to use presented as taken."""

from __future__ import annotations

import dataclasses
import json
import re
import tomllib
import warnings
from pathlib import Path

import numpy as np
import pytest
from campaign_helpers import SMALL_CAMPAIGN
from click.testing import CliRunner
from conftest import SEED_CONFIG
from identify_helpers import other_bench
from test_import_moteus import MAPPING, cogging_file
from test_import_moteus import mapping_file as moteus_mapping  # noqa: F401  (a fixture)

import ilcpmac.cli.identify  # noqa: F401  (registers the commands on main)
import ilcpmac.cli.import_  # noqa: F401
import ilcpmac.cli.run  # noqa: F401
from ilcpmac.bench.format import Bench, read_bench, write_bench
from ilcpmac.campaign.service import simulated_bench
from ilcpmac.cli import main
from ilcpmac.config import load_config
from ilcpmac.core.errors import IdentificationError
from ilcpmac.core.schema import toml_text
from ilcpmac.identify import identify_bench
from ilcpmac.identify.reduction import reduce_bench
from ilcpmac.identify.system_gain import TorqueNotFollowing, estimate_system_gain


def seed_config(folder: Path, changes: dict) -> Path:
    """configs/seed-bench.toml with ``changes`` ({table: {key: value}}) in ``folder``."""
    data = tomllib.loads(SEED_CONFIG.read_text())
    for table, values in changes.items():
        data.setdefault(table, {}).update(values)
    path = folder / "campaign.toml"
    path.write_text(toml_text(data))
    return path


@pytest.fixture(scope="module")
def small_grid(tmp_path_factory) -> Bench:
    """The seed bench at 1024 counts: a 2 x 2 grid of 2 revolutions (the fuzz's bench folder)."""
    return simulated_bench(load_config(seed_config(tmp_path_factory.mktemp("grid"), {
        "bench": {"counts_per_rev": 1024},
        "trials": {"torque_setpoints_nm": [1.0, 3.0], "speed_setpoints_hz": [0.8, 1.0], "revolutions": 2}})))[0]


def swapped(bench: Bench, noise_nm: float) -> Bench:
    """Every trial's torque and i_ref_a swapped, the torque then given ``noise_nm`` of seeded scatter."""
    rng = np.random.default_rng(34)

    def swap(t):
        i_ref = t.i_ref_a.copy()
        i_ref[:, 0] = t.torque_nm
        return dataclasses.replace(t, i_ref_a=i_ref,
                                   torque_nm=t.i_ref_a[:, 0] + noise_nm * rng.standard_normal(t.n_samples))

    return dataclasses.replace(bench, trials=tuple(swap(t) for t in bench.trials))


def identify_cli(folder: Path, output: Path):
    return CliRunner().invoke(main, ["identify", str(folder), "--output", str(output)])


def test_the_torque_and_a_current_reference_swapped_is_refused_in_one_line(tmp_path, small_grid):
    """It identified delta 494 % off (with RuntimeWarnings and LAPACK's complaints on the terminal): a simulated
    current reference repeats exactly from revolution to revolution, which no torque sensor's reading does."""
    write_bench(tmp_path / "bench", swapped(small_grid, 0.0))
    out = identify_cli(tmp_path / "bench", tmp_path / "r.json")
    assert out.exit_code == 2
    lines = [line for line in out.output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("error: no trial can be used: trial_01.csv left out: the torque "
                                                   "repeats exactly from revolution to revolution"), out.output
    assert not (tmp_path / "r.json").exists()


def test_with_noise_the_swapped_torque_follows_no_loop_and_is_refused(tmp_path, small_grid):
    """The response of the torque to the references has no loop's phase (ch. 2) and the joint fit's gain is too
    uncertain to take: nothing can be identified from that torque; one line, nothing written (it took delta
    16 +- 7.6)."""
    bench = swapped(small_grid, 0.02)
    ch2 = (r"total system gain \(ch. 2\): not identified - the torque does not follow the current references as one "
           r"gain and loop, which misfit its response by [\d.]+ % of its RMS beyond its noise \(more than 50 %: a "
           r"position-locked part the report's model lacks, or no torque of theirs, a current in the torque "
           r"column\?\)")
    with pytest.raises(TorqueNotFollowing, match=ch2):
        estimate_system_gain(reduce_bench(bench))
    expected = ch2 + "; the joint fit's gain is too uncertain to take: nothing can be identified from this torque"
    # its covariance's diagonal once held -1.7e-15 (round-off): a NaN standard error, and numpy's warning
    with pytest.raises(IdentificationError, match=expected), warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        identify_bench(bench)
    write_bench(tmp_path / "bench", bench)
    out = identify_cli(tmp_path / "bench", tmp_path / "r.json")
    assert out.exit_code == 2
    lines = [line for line in out.output.splitlines() if line.strip()]
    assert len(lines) == 1 and re.fullmatch("error: " + expected, lines[0]), out.output
    assert not (tmp_path / "r.json").exists()


def test_the_grids_response_is_a_loops(small_grid):
    assert estimate_system_gain(reduce_bench(small_grid)).delta_epsilon > 0.0


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory) -> Path:
    """A finished run of the small campaign (tests/campaign_helpers.py): 4 grid trials, then 14 compensated."""
    folder = tmp_path_factory.mktemp("campaign")
    out = CliRunner().invoke(main, ["run", str(seed_config(folder, SMALL_CAMPAIGN)), "--out", str(folder / "run")])
    assert out.exit_code == 0, out.output
    return folder / "run"


def test_identify_of_a_run_directory_identifies_its_grid_as_the_campaign_did(run_dir, tmp_path):
    """It identified every trial, compensated ones included: alpha -2.83e4 +- 2e4 and a RuntimeWarning."""
    out = identify_cli(run_dir, tmp_path / "r.json")
    assert out.exit_code == 0, out.output
    assert ("a run directory: its 4 grid trials identified, as the campaign did (its other 14 ran with a "
            "compensation, which the identification does not model)") in " ".join(out.output.split())
    assert "Warning" not in out.output
    identified = json.loads((tmp_path / "r.json").read_text())
    campaign = json.loads((run_dir / "states" / "identification.json").read_text())["result"]
    for key in ("total_system_gain", "torque_sensor_gain", "epsilon", "alpha", "beta"):
        np.testing.assert_allclose(identified[key], campaign[key], rtol=1e-9, err_msg=key)


def test_every_trial_of_a_run_identifies_without_a_runtime_warning(run_dir):
    """Trials without excitation (the compensated ones) divided by a zero excitation in ch. 2."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        identify_bench(read_bench(run_dir, extras=False))


def test_an_error_of_identify_is_its_one_line(tmp_path, small_grid):
    """A progress line preceded the error."""
    write_bench(tmp_path / "bench", small_grid)
    (tmp_path / "bench" / "bench.toml").unlink()
    out = identify_cli(tmp_path / "bench", tmp_path / "r.json")
    assert out.exit_code == 2
    assert [line for line in out.output.splitlines() if line.strip()] == [
        f"error: {tmp_path / 'bench' / 'bench.toml'}: no such file (a bench folder needs bench.toml)"]


def test_a_cogging_order_beyond_the_counts_nyquist_limit_is_not_identified():
    """Slots 2047: order 16376 at 2048 counts; the cogging came out 0, taken."""
    bench, _ = other_bench()
    result = identify_bench(dataclasses.replace(bench, motor=dataclasses.replace(bench.motor, slots=2047)))
    assert result.cogging_nm is None and all(m.cogging_nm is None for m in result.methods.values())
    assert ("cogging: not identified - its order 16376 (lcm(slots, 2 pole_pairs)) is beyond the Nyquist limit of 2048 "
            "counts per revolution (1024): no cogging harmonic is resolved") in result.messages


def import_and_identify(folder: Path, mapping: Path, cogging: Path):
    out = CliRunner().invoke(main, ["import", str(cogging), "--map", str(mapping), "--out", str(folder / "scan")])
    assert out.exit_code == 0, out.output
    return identify_cli(folder / "scan", folder / "scan.json")


def test_a_scans_cogging_order_beyond_the_counts_nyquist_limit_says_so(tmp_path, moteus_mapping):  # noqa: F811
    """A moteus file at 1024 counts of a motor of slots 1021: its cogging (orders 16336, ...) was printed as 0 mN m
    RMS, without a word."""
    moteus_mapping.write_text(MAPPING.replace("slots = 48", "slots = 1021"))
    out = import_and_identify(tmp_path, moteus_mapping, cogging_file(tmp_path / "cogging.json", 2048, 3))
    assert out.exit_code == 0, out.output
    text = " ".join(out.output.split())
    assert ("warning: cogging: not identified - its order 16336 (lcm(slots, 2 pole_pairs)) is beyond the Nyquist limit "
            "of 1024 counts per revolution (512): no cogging harmonic is resolved; the position torque and friction "
            "are") in text
    assert "cogging (orders 16336, 32672, ...): not identified (see the warning)" in text
    data = json.loads((tmp_path / "scan.json").read_text())
    assert data["cogging"] is None and data["cogging_harmonics"]["orders"] == []
    assert data["position_torque"]["torque"] and "too_uncertain" not in data


def test_an_outlier_within_the_limits_leaves_a_scans_cogging_too_uncertain(tmp_path, moteus_mapping):  # noqa: F811
    """One bin of 9999 A (a motor of 5000 N m may hold 3000 N m): the order-48 cogging came out 63x too large; its
    standard error says it is noise, and the command ends with that, exit 2, the result written."""
    moteus_mapping.write_text(MAPPING + "\n[limits]\nmax_torque_nm = 5000.0\n")
    cogging = cogging_file(tmp_path / "cogging.json", 2048, 3)
    data = json.loads(cogging.read_text())
    data["forward"][100] = 9999.0
    cogging.write_text(json.dumps(data))
    out = import_and_identify(tmp_path, moteus_mapping, cogging)
    assert out.exit_code == 2
    errors = [line for line in out.output.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and re.fullmatch(
        r"error: \S+scan: cogging too uncertain to take: [\d.e+]+ mN m RMS ± [\d.e+]+ mN m per count, a standard error "
        r"beyond 0.5 of its size - the scan's scatter hides it \(an outlier, or too few samples\)", errors[0]), errors
    assert json.loads((tmp_path / "scan.json").read_text())["too_uncertain"] == errors[0].split(": ", 2)[2]


def test_the_api_identifies_a_run_directory_on_its_grid_too(run_dir):
    import ilcpmac.api as ilc

    result = ilc.identify(run_dir)
    assert result.messages[0].startswith("a run directory: its 4 grid trials identified")
    campaign = json.loads((run_dir / "states" / "identification.json").read_text())["result"]
    np.testing.assert_allclose(result.epsilon, campaign["epsilon"], rtol=1e-9)
