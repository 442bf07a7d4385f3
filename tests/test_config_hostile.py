"""Hostile campaign configs: every value without physical sense, and every unreadable file, is one ConfigError line.

Each case mutates configs/seed-bench.toml and asserts a `ConfigError` whose
message is one short line naming the file and the key (or the file alone when
the file itself is at fault).
"""

from __future__ import annotations

import math
import os
import re
import tempfile
import tomllib
from pathlib import Path

import pytest
from conftest import SEED_CONFIG
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ilcpmac.bench.format import read_bench
from ilcpmac.campaign.service import load_campaign_config
from ilcpmac.config import load_config
from ilcpmac.core.errors import BenchFormatError, ConfigError
from ilcpmac.core.schema import MAX_TOML_BYTES, read_toml, toml_text


def assert_one_line(error: Exception, path: Path, pattern: str) -> None:
    message = str(error)
    assert "\n" not in message and len(message) < 500, message
    assert message.startswith(f"{path}: "), message
    assert re.search(pattern, message), message


@pytest.mark.parametrize("changes, pattern", [
    # issue 8, item 3: values that make no physical sense
    ({"stages": {"ilc": {"learning_gain": math.nan}}},
     r"\[stages\.ilc\] learning_gain: expected a finite number, got nan"),
    ({"stages": {"ilc": {"learning_gain": 0.0}}}, r"\[stages\.ilc\] learning_gain"),
    ({"stages": {"ilc": {"significance": -5.0}}}, r"\[stages\.ilc\] significance: invalid value -5"),
    ({"stages": {"ilc": {"process_noise_nm": math.inf}}}, r"\[stages\.ilc\] process_noise_nm"),
    ({"stages": {"ilc": {"model_uncertainty": 1.5}}}, r"\[stages\.ilc\] model_uncertainty"),
    ({"stages": {"ilc": {"q_cutoff_harmonic": 10**30}}}, r"\[stages\.ilc\] q_cutoff_harmonic"),
    ({"stages": {"cogging": {"prior_std_nm": -0.01}}}, r"\[stages\.cogging\] prior_std_nm"),
    ({"stages": {"current-sensor": {"process_noise_rel": math.nan}}},
     r"\[stages\.current-sensor\] process_noise_rel"),
    ({"stages": {"current-sensor": {"trials_per_point": -1}}},
     r"\[stages\.current-sensor\] trials_per_point: invalid value -1"),
    ({"stages": {"current-sensor": {"trials_per_point": 2.5}}},
     r"\[stages\.current-sensor\] trials_per_point: expected an integer, got 2.5"),
    ({"pipeline": {"stages": ["ilc", "ilc"]}}, r"\[pipeline\] stages: invalid value \['ilc', 'ilc'\]"),
    ({"simulator.controller": {"control_rate_hz": 0.001}},
     r"\[simulator\.controller\] control_rate_hz: invalid value 0.001"),
    ({"simulator.controller": {"control_rate_hz": 1e12}},
     r"\[simulator\.controller\] control_rate_hz: invalid value 1000000000000\.0"),
    ({"trials": {"speed_setpoints_hz": [1e-6]}},
     r"\[trials\] speed_setpoints_hz: at 1e-06 Hz .* lasts 4e\+06 s, beyond \[limits\] max_trial_duration_s"),
    ({"campaign": {"learn_speeds_hz": [1e-6]}},
     r"\[campaign\] learn_speeds_hz: .*\[limits\] max_trial_duration_s"),
    ({"limits": {"max_trial_duration_s": 5.0}}, r"\[trials\] speed_setpoints_hz: .*max_trial_duration_s 5"),
    ({"limits": {"max_trial_duration_s": 10.0}},
     r"\[campaign\] learn_speeds_hz: at 0.5 Hz .* lasts 82 s, .*max_trial_duration_s 10"),
    ({"trials": {"torque_setpoints_nm": []}}, r"\[trials\] torque_setpoints_nm: invalid value \[\]"),
    ({"trials": {"speed_setpoints_hz": []}}, r"\[trials\] speed_setpoints_hz: invalid value \[\]"),
    ({"campaign": {"learn_torques_nm": [0.0]}}, r"\[campaign\] learn_torques_nm: invalid value \[0.0\]"),
    ({"campaign": {"learn_revolutions": []}}, r"\[campaign\] learn_revolutions: invalid value \[\]"),
    ({"trials": {"revolutions": 20000}},
     r"\[trials\] revolutions: 20000 x \[bench\] counts_per_rev 4096 = 81920000 samples, "
     r"beyond \[limits\] max_samples_per_trial 2000000"),
    ({"campaign": {"learn_revolutions": [20000]}}, r"\[campaign\] learn_revolutions: .*max_samples_per_trial"),
    ({"campaign": {"validate_revolutions": 20000}}, r"\[campaign\] validate_revolutions: .*max_samples_per_trial"),
    ({"limits": {"max_samples_per_trial": 10000}}, r"\[trials\] revolutions: .*max_samples_per_trial 10000"),
    # issue 8, item 10
    ({"bench": {"inertia_kgm2": 1e300}}, r"\[bench\] inertia_kgm2: invalid value 1e\+300"),
    ({"bench": {"inertia_kgm2": 10**400}}, r"\[bench\] inertia_kgm2: expected a finite number"),
    ({"bench": {"pole_pairs": 1000000}}, r"\[bench\] pole_pairs: invalid value 1000000"),
    ({"trials": {"torque_setpoints_nm": [0.0, 1.0]}}, r"\[trials\] torque_setpoints_nm: invalid value"),
    ({"trials": {"torque_setpoints_nm": [-1.0]}}, r"\[trials\] torque_setpoints_nm: invalid value"),
    ({"trials": {"speed_setpoints_hz": [0.0]}}, r"\[trials\] speed_setpoints_hz: invalid value"),
    ({"trials": {"speed_setpoints_hz": [-0.5]}}, r"\[trials\] speed_setpoints_hz: invalid value"),
    ({"campaign": {"learn_torques_nm": [1.0, -3e4, 5.0]}}, r"\[campaign\] learn_torques_nm"),
    ({"campaign": {"learn_torques_nm": [1.0, 1.0, 5.0]}}, r"\[campaign\] learn_torques_nm: .*distinct"),
    ({"campaign": {"learn_speeds_hz": [0.0]}}, r"\[campaign\] learn_speeds_hz"),
    ({"campaign": {"validate_speeds_hz": [math.nan]}}, r"\[campaign\] validate_speeds_hz"),
    ({"campaign": {"validate_torques_nm": list(range(1, 40))}}, r"\[campaign\] validate_torques_nm"),
    # every other key's range
    ({"bench": {"slots": 0}}, r"\[bench\] slots"),
    ({"simulator.winding": {"phase_resistance_ohm": 0.0}}, r"\[simulator\.winding\] phase_resistance_ohm"),
    ({"simulator.winding": {"phase_inductance_h": 1e9}}, r"\[simulator\.winding\] phase_inductance_h"),
    ({"bench.backemf": {"amplitudes_nm_per_a": [0.0, 0.012, 0.006, 0.003]}},
     r"\[bench\.backemf\] harmonics: must include the fundamental 1, with a non-zero amplitude"),
    ({"bench.backemf": {"asymmetry": [-1.0, 0.0, 0.0]}}, r"\[bench\.backemf\] asymmetry"),
    ({"bench.backemf": {"phases_rad": [0.0, 100.0, 0.0, 0.0]}}, r"\[bench\.backemf\] phases_rad"),
    ({"bench.backemf": {"harmonics": list(range(1, 101))}}, r"\[bench\.backemf\] harmonics: invalid value \[1, 2, 3"),
    ({"bench.backemf": {"harmonics": [1, 3, 5, 300]}},
     r"\[bench\.backemf\] harmonics: mechanical order 2400 \(harmonic 300 x \[bench\] pole_pairs 8\) is beyond the "
     r"Nyquist limit of \[bench\] counts_per_rev 4096"),
    ({"bench": {"pole_pairs": 200, "counts_per_rev": 2048}},
     r"\[bench\.backemf\] harmonics: .*\[bench\] pole_pairs 200"),
    ({"simulator.cogging": {"multiples": [1, 50]}},
     r"\[simulator\.cogging\] multiples: mechanical order 2400 .*\[bench\] slots"),
    ({"simulator.unexplained": {"orders": [20, 36, 3000]}},
     r"\[simulator\.unexplained\] orders: mechanical order 3000"),
    ({"simulator.unexplained": {"saturation_per_a2": 0.01}},
     r"\[simulator\.unexplained\] saturation_per_a2: times \[limits\] max_current_a squared is 9"),
    ({"simulator.mechanics": {"coulomb_friction_nm": -1.0}}, r"\[simulator\.mechanics\] coulomb_friction_nm"),
    ({"simulator.controller": {"bandwidth_hz": 5000.0}},
     r"\[simulator\.controller\] bandwidth_hz: 5000 Hz is above control_rate_hz / 10"),
    ({"simulator.controller": {"voltage_limit_v": 0.0}}, r"\[simulator\.controller\] voltage_limit_v"),
    ({"bench.calibration": {"current_scale_counts_per_a": [14.0, 0.0, 14.0]}},
     r"\[bench\.calibration\] current_scale_counts_per_a"),
    ({"bench.calibration": {"current_offset_counts": [0.0, 1e300, 0.0]}},
     r"\[bench\.calibration\] current_offset_counts"),
    ({"bench.calibration": {"torque_gain_v_per_nm": -0.9}}, r"\[bench\.calibration\] torque_gain_v_per_nm"),
    ({"simulator.controller": {"control_rate_hz": 2000.0, "bandwidth_hz": 100.0},
      "bench": {"record_counts_per_rev": 4096}},
     r"\[trials\] speed_setpoints_hz: 1 Hz x \[bench\] record_counts_per_rev 4096 is more than half of "
     r"\[simulator\.controller\] control_rate_hz 2000"),
    ({"bench": {"record_counts_per_rev": 1000}}, r"\[bench\] record_counts_per_rev: 1000 does not divide "
                                                 r"counts_per_rev 4096"),
    ({"bench": {"record_counts_per_rev": 256}},
     r"\[excitation\] harmonics: 144 is beyond the Nyquist limit of \[bench\] record_counts_per_rev 256"),
    ({"campaign": {"learn_seconds": [10.0], "learn_revolutions": [4]}},
     r"\[campaign\] learn_revolutions, learn_seconds: give one of them"),
    ({"campaign": {"validate_seconds": -1.0}}, r"\[campaign\] validate_seconds: invalid value -1"),
    ({"limits": {"max_correction_fraction": 1.5}}, r"\[limits\] max_correction_fraction: invalid value 1\.5"),
    ({"simulator.current_sensors": {"epsilon": 0.0}}, r"\[simulator\.current_sensors\] epsilon"),
    ({"simulator.current_sensors": {"alpha": [0.0, 1.0, 1.0]}}, r"\[simulator\.current_sensors\] alpha"),
    ({"simulator.current_sensors": {"noise_counts": -1.0}}, r"\[simulator\.current_sensors\] noise_counts"),
    ({"simulator.torque_sensor": {"delta": 0.0}}, r"\[simulator\.torque_sensor\] delta"),
    ({"simulator.torque_sensor": {"highpass_hz": 1e9}}, r"\[simulator\.torque_sensor\] highpass_hz"),
    ({"bench": {"counts_per_rev": 2}}, r"\[bench\] counts_per_rev: invalid value 2 "),
    ({"bench": {"counts_per_rev": 2**25}}, r"\[bench\] counts_per_rev: invalid value 33554432"),
    ({"bench": {"counts_per_rev": 256}}, r"\[excitation\] harmonics: 144 is beyond the Nyquist limit of "
                                           r"\[bench\] counts_per_rev 256"),
    ({"simulator.encoder": {"timer_resolution_s": 0.0}}, r"\[simulator\.encoder\] timer_resolution_s"),
    ({"excitation": {"fraction": 2.0}}, r"\[excitation\] fraction"),
    ({"trials": {"torque_setpoints_nm": [1.0, 9.0]}},
     r"\[trials\] torque_setpoints_nm: 9 is beyond \[limits\] max_torque_nm 8"),
    ({"trials": {"speed_setpoints_hz": [0.5, 2.0]}},
     r"\[trials\] speed_setpoints_hz: 2 is beyond \[limits\] max_speed_hz"),
    ({"campaign": {"learn_torques_nm": [1.0, 3.0, 9.0]}},
     r"\[campaign\] learn_torques_nm: 9 is beyond \[limits\] max_torque_nm"),
    ({"trials": {"torque_setpoints_nm": [(i + 1) / 100 for i in range(200)]}}, r"\[trials\] torque_setpoints_nm"),
    ({"trials": {"warmup_revolutions": 0}}, r"\[trials\] warmup_revolutions"),
    ({"trials": {"seed": -1}}, r"\[trials\] seed"),
    ({"trials": {"seed": 2**64}}, r"\[trials\] seed"),
    ({"campaign": {"learn_trials": 0}}, r"\[campaign\] learn_trials"),
    ({"campaign": {"learn_trials": 10**6}}, r"\[campaign\] learn_trials"),
    ({"campaign": {"patience": 0}}, r"\[campaign\] patience"),
    ({"campaign": {"min_improvement": math.nan}}, r"\[campaign\] min_improvement"),
    # hostile shapes and sizes: the message stays one short line
    ({"bench": {"slots": "x" * 100_000}}, r"\[bench\] slots: expected an integer, got 'xxxxx.*\.\.\."),
    ({"bench": {"x" * 100_000: 1}}, r"\[bench\] unknown key 'xxxx.*\.\.\."),
    ({"excitation": {"phases": "random\n"}}, r"\[excitation\] phases: invalid value 'random\\n'"),
])
def test_values_without_physical_sense_are_one_line_naming_the_key(write_config, changes, pattern):
    path = write_config(changes)
    with pytest.raises(ConfigError) as caught:
        load_campaign_config(path)
    assert_one_line(caught.value, path, pattern)


@pytest.mark.parametrize("edit, pattern", [
    (lambda text: "stages = 5\n" + text.split("[stages.ilc]")[0],
     r"\[stages\] must be a table of \[stages\.NAME\] tables"),
    (lambda text: text.replace("[bench]\n", '[bench]\n"slots\\nfake line" = 1\n'),
     r"\[bench\] unknown key 'slots\\nfake line'"),
    (lambda text: text + '\n["a\\nb"]\nc = 1\n', r"unknown table \['a\\nb'\]"),
    (lambda text: text.replace("[stages.ilc]", '[stages."i\\nlc"]'), r"\[stages\.'i\\nlc'\] configures a stage"),
])
def test_hostile_names_stay_on_one_line(tmp_path, edit, pattern):
    path = tmp_path / "campaign.toml"
    path.write_text(edit(SEED_CONFIG.read_text()))
    with pytest.raises(ConfigError) as caught:
        load_config(path)
    assert_one_line(caught.value, path, pattern)


# ------------------------------------------------------------------ files that are not small UTF-8 TOML


@pytest.mark.parametrize("content, pattern", [
    (bytes(range(256)) * 4, r"line 2: not UTF-8 text \(byte 0x80\)"),
    (SEED_CONFIG.read_bytes().replace(b"# 16 magnets", b"# 16 \xff magnets"), r"line 9: not UTF-8 text \(byte 0xff\)"),
    (b"a = " + b"[" * 100_000 + b"]" * 100_000, r"not valid TOML \(nested too deeply\)"),
    (b"a = " + b"{b = " * 50_000 + b"1" + b"}" * 50_000, r"not valid TOML \(nested too deeply\)"),
    (b"# " + b"x" * MAX_TOML_BYTES, rf"more than {MAX_TOML_BYTES} bytes \(refused\)"),
    (b"a = 1\x00\n", r"not valid TOML"),
])
def test_unreadable_config_files_are_one_line_naming_the_file(tmp_path, content, pattern):
    path = tmp_path / "campaign.toml"
    path.write_bytes(content)
    with pytest.raises(ConfigError) as caught:
        load_config(path)
    assert_one_line(caught.value, path, pattern)


def test_a_fifo_is_refused_without_being_opened_for_a_blocking_read(tmp_path):
    path = tmp_path / "campaign.toml"
    os.mkfifo(path)  # no writer: a blocking open or read would hang the test
    with pytest.raises(ConfigError) as caught:
        load_config(path)
    assert_one_line(caught.value, path, r"not a regular file")


@pytest.mark.parametrize("path", [Path("/dev/zero"), Path("/dev/null"), Path(tempfile.gettempdir())])
def test_devices_and_folders_are_refused(path):
    with pytest.raises(ConfigError) as caught:
        read_toml(path)
    assert_one_line(caught.value, path, r"not a regular file \(a folder, FIFO or device is refused\)")


def test_binary_bench_toml_is_a_bench_format_error(tmp_path):
    (tmp_path / "bench.toml").write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)))
    with pytest.raises(BenchFormatError) as caught:
        read_bench(tmp_path)
    assert_one_line(caught.value, tmp_path / "bench.toml", r"not UTF-8 text")


# ------------------------------------------------------------------ any number in any numeric key


def _numeric_keys() -> list[tuple[str, str]]:
    data = tomllib.loads(SEED_CONFIG.read_text())
    keys = []
    for table, values in data.items():
        for key, value in values.items():
            if isinstance(value, dict):
                keys += [(f"{table}.{key}", k) for k, v in value.items() if isinstance(v, (int, float))]
            elif isinstance(value, (int, float)) and not isinstance(value, bool):
                keys.append((table, key))
    return keys


NUMERIC_KEYS = _numeric_keys()


@settings(max_examples=150, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(where=st.sampled_from(NUMERIC_KEYS),
       value=st.one_of(st.floats(), st.integers(-2**70, 2**70), st.sampled_from([0, -1, 1e-300, 1e300])))
def test_any_number_in_any_key_loads_or_is_one_line_naming_that_key(where, value):
    table, key = where
    data = tomllib.loads(SEED_CONFIG.read_text())
    node = data
    for part in table.split("."):
        node = node[part]
    node[key] = value
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "campaign.toml"
        path.write_text(toml_text(data))
        try:
            load_config(path)
        except ConfigError as e:
            assert_one_line(e, path, re.escape(key))
