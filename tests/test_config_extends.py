"""A config that builds on another (``extends``, ``drop``), and the packaged configs by name from any folder:
every error names the chain down to the file and key that hold it, on one line."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner
from conftest import SEED_CONFIG

from ilcpmac.cli import main
from ilcpmac.config import config_path, config_tables, config_text, load_config, packaged_config
from ilcpmac.core.errors import ConfigError


@pytest.fixture
def seed(tmp_path):
    """The seed bench's config as ``seed.toml`` in a folder of its own."""
    path = tmp_path / "seed.toml"
    path.write_text(SEED_CONFIG.read_text())
    return path


def refused(path) -> str:
    with pytest.raises(ConfigError) as e:
        load_config(path)
    assert "\n" not in str(e.value)
    return str(e.value)


# ---------------------------------------------------------------- extends: one line naming the file and key


@pytest.mark.parametrize("name", ["a\u0000b.toml", "\u0000", "configs/\u0000/seed.toml"])
def test_extends_with_a_nul_byte_is_one_line_naming_the_file_and_key(tmp_path, name):
    path = tmp_path / "nul.toml"
    escaped = name.replace("\0", "\\u0000")
    path.write_text(f'extends = "{escaped}"\n')
    message = refused(path)
    assert message.startswith(f"{path}: extends: a config's file name") and message.endswith(f"got {name!r}")


def test_a_bad_key_of_the_extended_file_names_the_chain_file_and_key(tmp_path, seed):
    seed.write_text(seed.read_text().replace("revolutions = 3\n", 'revolutions = "x"\n', 1))
    quick = tmp_path / "quick.toml"
    quick.write_text('extends = "seed.toml"\n[campaign]\nlearn_trials = 2\n')
    assert refused(quick) == (f"{quick} extends seed.toml: {seed}: [trials] revolutions: expected an integer, "
                              "got 'x'")
    top = tmp_path / "top.toml"
    top.write_text('extends = "quick.toml"\n')
    assert refused(top) == (f"{top} extends quick.toml: {quick} extends seed.toml: {seed}: [trials] revolutions: "
                            "expected an integer, got 'x'")
    # a key the extending file gives is its own: the base's bad value is replaced
    quick.write_text('extends = "seed.toml"\n[trials]\nrevolutions = 4\n')
    assert load_config(top).grid.revolutions == 4
    quick.write_text('extends = "seed.toml"\n[trials]\nrevolutions = 0\n')
    assert refused(top).startswith(f"{top} extends quick.toml: {quick}: [trials] revolutions: invalid value 0")


@pytest.mark.parametrize("edit, message", [
    (lambda t: t.replace("[trials]", "[trails]", 1), "unknown table [trails]"),
    (lambda t: t.replace("\nrevolutions = 3\n", "\nrevolution = 3\n", 1), "[trials] unknown key 'revolution'"),
    (lambda t: t.replace("\n[simulator.encoder]", "\n[simulator.encoder]\ncounts_per_rev = 8\n#", 1),
     "[simulator.encoder] counts_per_rev: the controller knows it"),
    (lambda t: t + "\n[stages.nosuch]\nx = 1\n", "[stages.nosuch] configures a stage"),
])
def test_every_error_of_a_table_or_key_of_the_extended_file_names_it(tmp_path, seed, edit, message):
    seed.write_text(edit(seed.read_text()))
    child = tmp_path / "child.toml"
    child.write_text('extends = "seed.toml"\n')
    assert refused(child).startswith(f"{child} extends seed.toml: {seed}: {message}")


def test_an_unreadable_or_missing_extended_file_or_a_cycle_names_the_chain(tmp_path, seed):
    a, b = tmp_path / "a.toml", tmp_path / "b.toml"
    a.write_text('extends = "b.toml"\n')
    b.write_text('extends = "seed.toml"\n[trials\n')
    assert refused(a).startswith(f"{a} extends b.toml: {b}: not valid TOML (") and "line 2" in refused(a)
    b.write_text('extends = "missing.toml"\n')
    assert refused(a) == f"{a} extends b.toml: {b} extends missing.toml: {tmp_path / 'missing.toml'}: no such file"
    b.write_text('extends = "a.toml"\n')
    assert refused(a) == f"{a} extends b.toml: {b}: extends: 'a.toml' extends itself"


# ---------------------------------------------------------------- drop


def test_drop_leaves_an_inherited_stage_table_out(tmp_path, seed):
    child = tmp_path / "child.toml"
    child.write_text('extends = "seed.toml"\n[pipeline]\nstages = ["current-sensor", "cogging"]\n')
    assert refused(child) == (f"{child} extends seed.toml: {seed}: [stages.ilc] configures a stage that [pipeline] "
                              'stages does not list (drop = ["stages.ilc"] leaves it out)')
    child.write_text('extends = "seed.toml"\ndrop = ["stages.ilc"]\n'
                     '[pipeline]\nstages = ["current-sensor", "cogging"]\n')
    config = load_config(child)
    assert config.pipeline.stages == ("current-sensor", "cogging") and "ilc" not in config.stage_options
    # the run directory keeps the tables merged, what was dropped left out
    kept = tmp_path / "kept.toml"
    kept.write_text(config_text(config))
    assert config_tables(kept) == config_tables(child) and load_config(kept).stage_options == config.stage_options


def test_drop_takes_a_key_back_to_its_default_and_replaces_a_table_whole(tmp_path, seed):
    base = load_config(seed)
    assert base.campaign.validate_torques_nm is not None and base.stage_options["ilc"]
    child = tmp_path / "child.toml"
    child.write_text('extends = "seed.toml"\ndrop = ["campaign.validate_torques_nm", "stages.ilc"]\n'
                     '[stages.ilc]\nlearning_gain = 0.5\n')
    config = load_config(child)
    assert config.campaign.validate_torques_nm is None  # left out: derived again
    assert config.campaign.validate_speeds_hz == base.campaign.validate_speeds_hz
    assert config.stage_options["ilc"] == {"learning_gain": 0.5}


@pytest.mark.parametrize("text, message", [
    ('extends = "seed.toml"\ndrop = ["stages.nosuch"]\n', "drop: 'stages.nosuch': no such table or key in seed.toml"),
    ('extends = "seed.toml"\ndrop = ["trials.revolutions.x"]\n', "drop: 'trials.revolutions.x': no such table"),
    ('extends = "seed.toml"\ndrop = "stages.ilc"\n', "drop: tables and keys of what it extends left out"),
    ('extends = "seed.toml"\ndrop = ["stages..ilc"]\n', "drop: tables and keys of what it extends left out"),
    ('drop = ["stages.ilc"]\n', "drop: leaves out tables of the config it extends, and it extends none"),
])
def test_a_drop_that_drops_nothing_is_one_line(tmp_path, seed, text, message):
    child = tmp_path / "child.toml"
    child.write_text(text)
    assert refused(child).startswith(f"{child}: {message}")


# ---------------------------------------------------------------- the packaged configs by name


@pytest.mark.parametrize("given", ["configs/quick.toml", "quick.toml", "configs/seed-bench.toml", "real-bench.toml"])
def test_a_packaged_config_is_found_by_name_from_any_folder(tmp_path, monkeypatch, given):
    monkeypatch.chdir(tmp_path)
    packaged = packaged_config(given.removeprefix("configs/"))
    assert config_path(given) == packaged
    if given != "real-bench.toml":  # a template: its [bench.backemf] is the user's to give
        assert load_config(given).path == packaged


def test_a_config_that_exists_wins_over_the_packaged_one(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "configs").mkdir()
    (tmp_path / "configs" / "quick.toml").write_text(SEED_CONFIG.read_text())
    assert load_config("configs/quick.toml").path.resolve() == (tmp_path / "configs" / "quick.toml").resolve()
    for other in ("elsewhere/quick.toml", "configs/nosuch.toml", str(tmp_path / "quick.toml")):
        assert config_path(other) == Path(other)
        assert refused(other).endswith("no such file")


def test_ilcpmac_run_says_which_packaged_config_it_took(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    done = CliRunner().invoke(main, ["run", "configs/quick.toml", "--backend", "nosuch", "--out", "run"])
    assert done.exit_code == 2
    note, error = done.output.splitlines()
    assert note == f"config: configs/quick.toml is not here: the packaged {packaged_config('quick.toml')}"
    assert error.startswith("error: --backend: no backend named 'nosuch'")
