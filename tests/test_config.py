"""Campaign configuration: the seed file reads, every bad file raises ConfigError naming file, table and key."""

from __future__ import annotations

import math
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
from conftest import MAPPING_BENCH, PHASE_LOG, SEED_CONFIG

from ilcpmac.bench.importer import read_mapping
from ilcpmac.config import CampaignSettings, LimitSettings, PipelineSettings, config_reference, load_config
from ilcpmac.core.errors import ConfigError
from ilcpmac.core.schema import toml_text
from ilcpmac.model.tables import backemf_table


def test_seed_config_values(seed_config):
    m = seed_config.model
    assert m.winding.pole_pairs == 8
    assert m.winding.cogging_order == math.lcm(48, 16) == 48
    assert m.backemf.harmonics == (1, 3, 5, 7)
    assert m.encoder.counts_per_rev == 4096
    assert m.mechanics.inertia_kgm2 == 0.01056
    assert seed_config.grid.torque_setpoints_nm == (1.0, 2.0, 3.0, 4.0, 5.0)
    assert seed_config.excitation.harmonics == 144
    assert seed_config.path == SEED_CONFIG


def test_alpha_is_normalised_to_mean_one(seed_config):
    alpha = np.array(seed_config.model.current_sensors.alpha)
    np.testing.assert_allclose(alpha, np.array([0.8, 1.118, 1.118]) / (3.036 / 3), rtol=1e-12)
    assert alpha.mean() == pytest.approx(1.0, abs=1e-15)


def test_integer_accepted_where_a_number_is_expected(write_config):
    cfg = load_config(write_config({"bench": {"inertia_kgm2": 1}}))
    assert cfg.model.mechanics.inertia_kgm2 == 1.0
    assert isinstance(cfg.model.mechanics.inertia_kgm2, float)


def test_run_tables_are_optional(write_config, seed_config):
    cfg = load_config(write_config(drop=("campaign", "limits", "pipeline", "stages")))
    assert (cfg.campaign, cfg.limits, cfg.pipeline) == (CampaignSettings(), LimitSettings(), PipelineSettings())
    assert cfg.stage_options == {}
    assert seed_config.stage_options["ilc"]["learning_gain"] == 1.0


@pytest.mark.parametrize("changes, drop, message", [
    # unknown table and unknown key
    ({"windings": {"slots": 48}}, (), r"unknown table \[windings\]"),
    ({"bench": {"pole_pair": 8}}, (), r"\[bench\] unknown key 'pole_pair'"),
    # missing table and missing key
    (None, ("simulator.cogging",), r"missing table \[simulator.cogging\]"),
    (None, ("bench.slots",), r"\[bench\] slots: missing"),
    (None, ("simulator.current_sensors.beta_a",), r"\[simulator\.current_sensors\] beta_a: missing"),
    # wrong type
    ({"bench": {"slots": "48"}}, (), r"\[bench\] slots: expected an integer, got '48'"),
    ({"bench": {"counts_per_rev": True}}, (), r"\[bench\] counts_per_rev: expected an integer"),
    ({"bench": {"inertia_kgm2": "0.01"}}, (), r"\[bench\] inertia_kgm2: expected a finite number"),
    ({"bench.backemf": {"harmonics": 1}}, (), r"\[bench\.backemf\] harmonics: expected a list"),
    ({"bench.backemf": {"harmonics": [1, 3.5, 5, 7]}},
     (), r"\[bench\.backemf\] harmonics: expected an integer, got 3.5"),
    ({"excitation": {"phases": 1}}, (), r"\[excitation\] phases: expected a string"),
    # bad value
    ({"bench": {"inertia_kgm2": -0.01}}, (), r"\[bench\] inertia_kgm2: invalid value -0.01"),
    ({"bench": {"inertia_kgm2": math.nan}}, (), r"\[bench\] inertia_kgm2: expected a finite number"),
    ({"bench.backemf": {"phases_rad": [0.0, math.inf, 0.0, 0.0]}}, (),
     r"\[bench\.backemf\] phases_rad: expected a finite number"),
    ({"simulator.current_sensors": {"alpha": [1.0, 1.0]}},
     (), r"\[simulator\.current_sensors\] alpha: invalid value \[1.0, 1.0\]"),
    ({"simulator.torque_sensor": {"noise_nm": -0.1}}, (), r"\[simulator\.torque_sensor\] noise_nm: invalid value"),
    ({"excitation": {"phases": "square"}}, (), r"\[excitation\] phases: invalid value 'square'"),
    ({"simulator.cogging": {"amplitudes_nm": [0.5]}}, (),
     r"\[simulator\.cogging\] multiples, amplitudes_nm, phases_rad: must have equal lengths"),
    ({"excitation": {"harmonics": 2048}}, (), r"\[excitation\] harmonics: 2048 is beyond the Nyquist limit"),
    ({"bench.backemf": {"harmonics": [3, 5, 7, 9]}},
     (), r"\[bench\.backemf\] harmonics: must include the fundamental 1"),
    ({"campaign": {"ripple_harmonics": 2048}}, (), r"\[campaign\] ripple_harmonics: 2048 is beyond the Nyquist"),
    ({"stages": {"shaper": {"gain": 1.0}}}, (),
     r"\[stages.shaper\] configures a stage that \[pipeline\] stages does not list"),
])
def test_bad_config_names_file_table_and_key(write_config, changes, drop, message):
    path = write_config(changes, drop)
    with pytest.raises(ConfigError, match=re.escape(str(path)) + ": " + message):
        load_config(path)


def test_malformed_toml_names_file_and_line(tmp_path):
    path = tmp_path / "broken.toml"
    path.write_text("[winding]\npole_pairs = \n")
    with pytest.raises(ConfigError, match=re.escape(str(path)) + r": not valid TOML \(.*line 2"):
        load_config(path)


def test_missing_file(tmp_path):
    path = tmp_path / "absent.toml"
    with pytest.raises(ConfigError, match=re.escape(str(path)) + ": no such file"):
        load_config(path)


def test_learn_revolutions_are_one_number_or_one_per_learned_torque(write_config):
    cfg = load_config(write_config({"campaign": {"learn_revolutions": [40]}}))
    assert [cfg.trial_revolutions((t, 0.5)) for t in (1.0, 3.0, 5.0)] == [40, 40, 40]
    cfg = load_config(write_config({"campaign": {"learn_revolutions": [64, 32, 16]}}))
    assert [cfg.trial_revolutions((t, 0.5)) for t in (1.0, 3.0, 5.0)] == [64, 32, 16]
    # faster trials last as long as at the slowest learned speed (0.5 Hz); validation trials likewise
    assert [cfg.trial_revolutions((1.0, s)) for s in (0.5, 1.0, 1.5)] == [64, 128, 192]
    assert [cfg.trial_revolutions((2.0, s)) for s in (0.5, 0.75, 1.5)] == [10, 15, 30]
    with pytest.raises(ConfigError, match=r"campaign.toml: \[campaign\] learn_revolutions: give one number"):
        load_config(write_config({"campaign": {"learn_revolutions": [64, 32]}}))


def test_learning_trials_grow_by_learn_growth_up_to_learn_revolutions(write_config):
    cfg = load_config(write_config({"campaign": {"learn_revolutions": [40, 12, 6], "learn_trials": 4,
                                                 "learn_growth": 2.0}}))
    # the compensation trial (0) then learning trials 1..4: halving back from the last, never under 3
    assert [cfg.trial_revolutions((1.0, 0.5), k) for k in range(5)] == [3, 5, 10, 20, 40]
    assert [cfg.trial_revolutions((1.0, 1.5), k) for k in range(5)] == [8, 15, 30, 60, 120]
    assert [cfg.trial_revolutions((3.0, 0.5), k) for k in range(5)] == [3, 3, 3, 6, 12]
    assert cfg.trial_revolutions((1.0, 0.5), 9) == 40  # past learn_trials (a resumed run's extra trial): the last
    flat = load_config(write_config({"campaign": {"learn_revolutions": [40], "learn_growth": 1.0}}))
    assert {flat.trial_revolutions((5.0, 0.5), k) for k in range(5)} == {40}
    with pytest.raises(ConfigError, match=r"\[campaign\] learn_growth: invalid value 0.5"):
        load_config(write_config({"campaign": {"learn_growth": 0.5}}))
    with pytest.raises(ConfigError, match=r"\[campaign\] baseline_revolutions: invalid value 2 .*at least 3"):
        load_config(write_config({"campaign": {"baseline_revolutions": 2}}))


def test_the_operating_points_are_derived_from_the_grid_and_limits_when_not_given(write_config):
    keys = ("learn_torques_nm", "learn_speeds_hz", "validate_torques_nm", "validate_speeds_hz")
    cfg = load_config(write_config(drop=[f"campaign.{key}" for key in keys]))
    assert cfg.learned_points() == [(t, s) for t in (1.0, 3.0, 5.0) for s in (0.5, 1.0, 1.5)]
    assert cfg.validation_points() == [(t, s) for t in (2.0, 4.0) for s in (0.5, 1.0, 1.5)]
    # an empty validation list: no validation; an empty learned one is refused
    assert load_config(write_config({"campaign": {"validate_speeds_hz": []}})).validation_points() == []
    with pytest.raises(ConfigError, match=r"\[campaign\] learn_speeds_hz: invalid value \[\]"):
        load_config(write_config({"campaign": {"learn_speeds_hz": []}}))


def test_the_seed_config_learns_at_nine_points_and_validates_at_six_others(seed_config):
    assert seed_config.learned_points() == [(t, s) for t in (1.0, 3.0, 5.0) for s in (0.5, 1.0, 1.5)]
    assert seed_config.validation_points() == [(t, s) for t in (2.0, 4.0) for s in (0.5, 1.0, 1.5)]


@pytest.mark.parametrize("changes, message", [
    ({"ilc_trials": 3}, r"\[campaign\] ilc_trials is now learn_trials"),
    ({"ilc_speed_setpoint_hz": 0.75}, r"\[campaign\] ilc_speed_setpoint_hz is now learn_speeds_hz \(a list\)"),
    ({"validate_torques_nm": [3.0], "validate_speeds_hz": [0.5]},
     r"\[campaign\] validate_torques_nm, validate_speeds_hz: 3 N m at 0.5 Hz is a learned point"),
    ({"validate_speeds_hz": [2.0]}, r"\[campaign\] validate_speeds_hz: 2 is beyond \[limits\] max_speed_hz 1.5"),
])
def test_campaign_keys_of_the_operating_range_are_checked(write_config, changes, message):
    with pytest.raises(ConfigError, match=message):
        load_config(write_config({"campaign": changes}))


@pytest.mark.parametrize("changes, drop, message", [
    ({"simulator.winding": {"pole_pairs": 8}}, (),
     r"\[simulator.winding\] pole_pairs: the controller knows it: give it as \[bench\] pole_pairs"),
    ({"simulator.controller": {"torque_gain_v_per_nm": 0.9}}, (),
     r"\[simulator.controller\] torque_gain_v_per_nm: the controller knows it: give it as \[bench.calibration\]"),
    ({"simulator.backemf": {"harmonics": [1]}}, (), r"unknown table \[simulator.backemf\]"),
    (None, ("bench.backemf",), r"\[bench.backemf\]: missing \(the simulated drive needs it\)"),
    (None, ("bench.calibration",), r"\[bench.calibration\]: missing \(the simulated drive needs it\)"),
    (None, ("bench.inertia_kgm2",), r"\[bench\] inertia_kgm2: missing \(the simulated drive needs it\)"),
    (None, ("bench",), r"missing table \[bench\]"),
])
def test_the_simulated_truth_is_apart_from_what_the_controller_knows(write_config, changes, drop, message):
    path = write_config(changes, drop)
    with pytest.raises(ConfigError, match=re.escape(str(path)) + ": " + message):
        load_config(path)


def test_a_config_without_the_simulated_truth_needs_only_bench_and_run_tables(write_config):
    """Issue 9: a real bench's config holds [bench], [trials], [excitation] and the run tables only."""
    path = write_config(drop=("simulator", "bench.backemf", "bench.calibration", "bench.inertia_kgm2"))
    cfg = load_config(path)
    assert cfg.model is None and cfg.bench.inertia_kgm2 is None and cfg.bench.backemf is None
    with pytest.raises(ConfigError, match=re.escape(str(path)) + r": no \[simulator\] tables"):
        cfg.simulated_model()
    with pytest.raises(ConfigError, match=r"\[bench.backemf\] harmonics: mechanical order 2400"):
        load_config(write_config({"bench.backemf": {"harmonics": [1, 300], "amplitudes_nm_per_a": [0.2, 0.01],
                                                    "phases_rad": [0.0, 0.0], "asymmetry": [0.0, 0.0, 0.0]}},
                                 drop=("simulator",)))


@pytest.mark.parametrize("text", ["/runs/a\nb/backemf.csv", 'quote " and back\\slash', "tab\tdel\x7f é"])
def test_toml_text_writes_any_string_as_tomllib_reads_it(text):
    """A sweep's task config holds the base config's folder, which may be named with a newline: its TOML
    writer once wrote that as a raw newline, which is not TOML."""
    data = {"bench": {"backemf_file": text, "pole_pairs": 8, "backemf": {"harmonics": [1, 3]}}}
    assert tomllib.loads(toml_text(data)) == data


def test_backemf_phases_and_asymmetry_default_to_zeros(write_config, tmp_path):
    """A plain sinusoid needs only [bench.backemf] harmonics and amplitudes, in a config and in an import
    mapping: the phases are zeros, one per harmonic, and the asymmetry zero, as if given."""
    plain = {"harmonics": [1, 3], "amplitudes_nm_per_a": [0.2, 0.01]}
    explicit = {**plain, "phases_rad": [0.0, 0.0], "asymmetry": [0.0, 0.0, 0.0]}
    short = load_config(write_config({"bench.backemf": plain}, name="short.toml",
                                     drop=("bench.backemf.phases_rad", "bench.backemf.asymmetry"))).model
    full = load_config(write_config({"bench.backemf": explicit}, name="full.toml")).model
    assert short.backemf == full.backemf and short.backemf.phases_rad == (0.0, 0.0)
    cpr = full.encoder.counts_per_rev
    assert np.array_equal(backemf_table(short.winding, short.backemf, cpr),
                          backemf_table(full.winding, full.backemf, cpr))
    tables = []
    for name, backemf in (("short", plain), ("full", explicit)):
        bench = MAPPING_BENCH.replace('backemf_file = "backemf.csv"\n', "")
        (tmp_path / f"{name}-map.toml").write_text(f"{bench}\n[bench.backemf]\n{toml_text(backemf)}\n{PHASE_LOG}")
        tables.append(read_mapping(tmp_path / f"{name}-map.toml").backemf_nm_per_a)
    assert np.array_equal(*tables) and np.abs(tables[0]).max() > 0.1
    with pytest.raises(ConfigError, match=r"\[bench\.backemf\] harmonics, amplitudes_nm_per_a, phases_rad: must have "
                                          r"equal lengths"):
        load_config(write_config({"bench.backemf": {**plain, "phases_rad": [0.0]}}, name="bad.toml",
                                 drop=("bench.backemf.asymmetry",)))


def test_the_config_reference_is_generated_from_the_declarations():
    """docs/config-reference.md is what `config_reference` writes: regenerate it with
    ``python -c "from ilcpmac.config import config_reference; print(config_reference(), end='')"
    > docs/config-reference.md`` after changing a key."""
    assert (Path(__file__).resolve().parents[1] / "docs" / "config-reference.md").read_text() == config_reference()


def test_the_config_reference_names_every_key_a_config_may_hold():
    reference = config_reference()
    data = tomllib.loads(SEED_CONFIG.read_text())
    tables = {f"[{name}]": keys for name, keys in data.items() if name not in ("simulator", "stages")}
    tables |= {f"[simulator.{name}]": keys for name, keys in data["simulator"].items()}
    for table, keys in tables.items():
        section = reference.split(f"### {table}\n", 1)[1].split("###", 1)[0]
        for key, value in keys.items():
            if not isinstance(value, dict):
                assert f"| `{key}` |" in section, (table, key)


def test_a_config_of_its_bench_and_limits_alone_derives_the_seed_benchs_set_points(write_config):
    from ilcpmac.config import LEARN_SECONDS, VALIDATE_SECONDS

    cfg = load_config(write_config(drop=["trials.torque_setpoints_nm", "trials.speed_setpoints_hz",
                                         "limits.max_correction_nm", "campaign.learn_torques_nm",
                                         "campaign.learn_speeds_hz", "campaign.learn_revolutions",
                                         "campaign.validate_torques_nm", "campaign.validate_speeds_hz",
                                         "campaign.validate_revolutions"]))
    assert cfg.grid.torque_setpoints_nm == (1.0, 2.0, 3.0, 4.0, 5.0)  # eighths of max_torque_nm 8
    assert cfg.grid.speed_setpoints_hz == (0.5, 0.75, 1.0)  # sixths of max_speed_hz 1.5
    assert cfg.limits.correction_nm() == 1.5  # 0.1875 x 8
    assert cfg.learned_points() == load_config(SEED_CONFIG).learned_points()
    # lengths in seconds at any speed: 80 s at the least learned torque, T_least / T of it elsewhere
    assert cfg.trial_revolutions((1.0, 0.5)) == round(LEARN_SECONDS * 0.5)
    assert cfg.trial_revolutions((1.0, 1.5)) == round(LEARN_SECONDS * 1.5)
    assert cfg.trial_revolutions((5.0, 1.5)) == math.ceil(LEARN_SECONDS / 5 * 1.5)
    assert cfg.trial_revolutions((2.0, 1.0)) == round(VALIDATE_SECONDS * 1.0)
    # --budget scales the seconds
    assert cfg.with_trial_lengths(0.5).trial_revolutions((1.0, 1.5)) == round(LEARN_SECONDS * 1.5 / 2)


def test_learn_seconds_are_one_or_one_per_learned_torque(write_config):
    path = write_config({"campaign": {"learn_seconds": [10.0, 20.0]}}, drop=["campaign.learn_revolutions"])
    with pytest.raises(ConfigError, match=r"\[campaign\] learn_seconds: give one number, or one per learned "
                                          r"torque \(3: 1, 3, 5 N m\)"):
        load_config(path)


@pytest.mark.parametrize("counts, speed_hz, rate_hz, recorded", [
    (4096, 1.5, 20000.0, 4096),         # the seed bench: every count
    (2**20, 1.5, 20000.0, 4096),        # a 20-bit encoder: every 256th line
    (2**16, 6.0, 20000.0, 1024),        # 6144 rows / s at 6 Hz
    (3000, 1.5, 20000.0, 3000),
    (4096, 1.5, 2000.0, 512),           # half the control rate over the speed: 666, and 4096's divisor below it
    (2**14, 30.0, 20000.0, 256),        # 4 x ripple_harmonics = 600 wanted, but 20 kHz / 2 / 30 Hz = 333 allow 256
])
def test_the_recorded_counts_follow_the_encoder_the_speed_and_the_ripple_band(write_config, counts, speed_hz,
                                                                               rate_hz, recorded):
    changes = {"bench": {"counts_per_rev": counts}, "limits": {"max_speed_hz": speed_hz},
               "simulator.controller": {"control_rate_hz": rate_hz, "bandwidth_hz": min(140.0, rate_hz / 20)},
               "simulator.encoder": {"eccentricity_counts": 0.2, "line_std_counts": 0.05}}
    path = write_config(changes, drop=["trials.speed_setpoints_hz", "campaign.learn_speeds_hz",
                                       "campaign.validate_speeds_hz"])
    if recorded < 2 * 145:  # the excitation's 144 harmonics need more: the config says so, naming the key
        with pytest.raises(ConfigError, match=r"\[excitation\] harmonics: 144 is beyond the Nyquist limit of "
                                              rf"\[bench\] record_counts_per_rev \(left out: derived\) {recorded}"):
            load_config(path)
        return
    cfg = load_config(path)
    assert cfg.recorded_counts_per_rev() == recorded == cfg.sampled_counts_per_rev()
    encoder = cfg.sampled_model().encoder
    assert encoder.counts_per_rev == recorded
    b = counts // recorded
    assert encoder.eccentricity_counts == pytest.approx(0.2 / b) and encoder.line_std_counts == pytest.approx(0.05 / b)


def test_a_recorded_resolution_below_the_lines_sampled_samples_a_multiple_of_it(write_config):
    """[bench] record_counts_per_rev 1024 of the seed bench's 4096 lines: every line sampled, 4 per recorded count
    (their means, docs/campaign.md); 3000 lines recorded at 600 counts, 3000 sampled (5 per count)."""
    cfg = load_config(write_config({"bench": {"record_counts_per_rev": 1024}}))
    assert (cfg.sampled_counts_per_rev(), cfg.recorded_counts_per_rev()) == (4096, 1024)
    cfg = load_config(write_config({"bench": {"counts_per_rev": 3000, "record_counts_per_rev": 600}}))
    assert (cfg.sampled_counts_per_rev(), cfg.recorded_counts_per_rev()) == (3000, 600)


def test_the_ripple_band_left_out_holds_the_coggings_first_two_multiples(write_config):
    """7 pole pairs and 12 slots cog at lcm(12, 14) = 84 per revolution: the band left out is 1..168; given, it is
    what is given; on the seed bench (order 48) the default 150 holds both."""
    actuator = {"bench": {"pole_pairs": 7, "slots": 12}}
    assert load_config(write_config(actuator, drop=["campaign.ripple_harmonics"])).campaign.ripple_harmonics == 168
    assert load_config(write_config(actuator)).campaign.ripple_harmonics == 150
    assert load_config(write_config(drop=["campaign.ripple_harmonics"])).campaign.ripple_harmonics == 150


def test_a_simulated_order_beyond_the_recorded_resolution_is_refused_naming_the_recorded_counts(write_config):
    """2^18 counts at up to 12 Hz record 512 per revolution: an unexplained order of 300 lies beyond their
    Nyquist limit, and the error names the derived recorded counts, not the encoder's."""
    path = write_config({"bench": {"counts_per_rev": 2**18}, "limits": {"max_speed_hz": 12.0},
                         "simulator.unexplained": {"orders": [20, 36, 300]}},
                        drop=["trials.speed_setpoints_hz", "campaign.learn_speeds_hz", "campaign.validate_speeds_hz"])
    with pytest.raises(ConfigError, match=r"\[simulator\.unexplained\] orders: mechanical order 300 \(order\) is "
                                          r"beyond the Nyquist limit of \[bench\] record_counts_per_rev \(left out: "
                                          r"derived\) 512$"):
        load_config(path)
