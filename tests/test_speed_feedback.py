"""The speed's feedback through the current loop (`ilcpmac.core.current_loop.speed_feedback`) against the
simulator's truth, and the identified winding it rests on."""

from __future__ import annotations

import dataclasses
import tomllib

import numpy as np
import pytest
from conftest import SEED_CONFIG
from identify_helpers import identified

from ilcpmac.campaign.service import simulated_bench
from ilcpmac.config import load_config
from ilcpmac.core.current_loop import CurrentLoop, backemf_power, speed_feedback
from ilcpmac.core.records import LOOP_WINDING, IdentificationResult, ResultKeyError
from ilcpmac.core.schema import toml_text
from ilcpmac.identify import identify_bench
from ilcpmac.identify.joint import harmonic_sets
from ilcpmac.signals.harmonics import harmonic_amplitudes
from ilcpmac.sim.simulator import Simulator
from ilcpmac.stages.base import Identified

#: a light rotor on the ideal small seed bench, lightly braked: its feedback is far from 1 at low harmonics
LIGHT_INERTIA_KGM2 = 1.1e-4
TORQUE_NM, SPEED_HZ = 0.5, 2.0
HARMONICS = (8, 24, 48)


def test_a_light_rotor_delivers_what_the_feedback_says(ideal_model, make_request):
    """The true torque a cosine feed-forward at h adds, over the loop's response G0 at the trial's speed, is M(h)
    from the truth (R, L, loop, inertia, brake, back-EMF table); at the electrical frequency (h 8) the timing
    term makes half of it."""
    light = dataclasses.replace(ideal_model, mechanics=dataclasses.replace(
        ideal_model.mechanics, inertia_scale=LIGHT_INERTIA_KGM2 / ideal_model.mechanics.inertia_kgm2))
    cpr, w = light.encoder.counts_per_rev, light.winding
    sim = Simulator(light)
    loop = CurrentLoop(np.full(3, 1.0 / (2.0 * np.pi * light.controller.bandwidth_hz)),
                       0.5 / light.controller.control_rate_hz)
    for h in HARMONICS:
        delivered = []
        for table in (np.zeros(cpr), 0.02 * np.cos(2.0 * np.pi * h * np.arange(cpr) / cpr)):
            trial = sim.run_trial(dataclasses.replace(
                make_request(light, TORQUE_NM, SPEED_HZ, feedforward_nm=table), revolutions=4))
            delivered.append(harmonic_amplitudes(trial.torque_true_nm[trial.count >= cpr].reshape(-1, cpr)
                                                 .mean(axis=0), h)[h])
        speed_hz = trial.mean_speed_hz(cpr)
        measured = (delivered[1] - delivered[0]) / 0.02 / loop.response(np.array([h]), speed_hz, cpr)[0, 0]
        expected = speed_feedback(np.array([h]), speed_hz, loop, backemf_power(sim.backemf_lines * w.backemf_scale),
                                  1.0 / w.phase_resistance_ohm, w.phase_inductance_h / w.phase_resistance_ohm,
                                  LIGHT_INERTIA_KGM2, TORQUE_NM / (2.0 * np.pi * SPEED_HZ))[0]
        assert abs(expected - 1.0) > 0.2  # a case where the feedback matters
        assert abs(measured / expected - 1.0) < 0.04, h


def test_no_feedback_without_a_loop_or_a_winding():
    h = np.array([1, 10])
    backemf = np.column_stack([np.cos(2.0 * np.pi * (np.arange(64) / 64 - p / 3)) for p in range(3)])
    assert np.all(speed_feedback(h, 1.0, CurrentLoop(), backemf_power(backemf), 2.0, 1e-3, 1e-4, 0.0) == 1.0)
    lag = CurrentLoop(np.full(3, 1e-3), 0.0)
    assert np.all(speed_feedback(h, 1.0, lag, backemf_power(backemf), 0.0, 1e-3, 1e-4, 0.0) == 1.0)
    assert np.allclose(speed_feedback(h, 1.0, lag, backemf_power(backemf), 2.0, 1e-3, 1e3, 0.0), 1.0, atol=1e-4)


def test_the_seed_bench_identifies_its_winding():
    result, _ = identified("seed")
    assert result.winding_conductance_s == pytest.approx(1.0 / 0.5, rel=0.05)
    assert result.winding_time_constant_s == pytest.approx(0.002 / 0.5, rel=0.15)
    again = IdentificationResult.from_json(result.to_json())
    assert (again.winding_conductance_s, again.winding_time_constant_s) == (
        result.winding_conductance_s, result.winding_time_constant_s)
    stages = Identified.from_result(again, result.calibration)
    assert stages.winding_conductance_s == result.winding_conductance_s


@pytest.mark.parametrize("value", ["2.0", -1.0, float("inf"), float("nan"), True, [2.0]])
@pytest.mark.parametrize("name", ["winding_conductance_s", "winding_time_constant_s"])
def test_a_hostile_winding_in_a_result_is_one_error_naming_its_key(name, value):
    """The speed's feedback rests on these: a string, a negative or non-finite number, a boolean or a list is a
    ResultKeyError naming diagnostics.joint's key, never a feedback of NaN or a TypeError."""
    result, _ = identified("seed")
    data = result.to_json()
    data["diagnostics"]["joint"][name] = value
    with pytest.raises(ResultKeyError, match=f"diagnostics.joint.{name}"):
        IdentificationResult.from_json(data)


@pytest.mark.parametrize("diagnostics", [["joint"], {"joint": [1.0]}, "x"])
def test_diagnostics_that_are_not_objects_are_one_error(diagnostics):
    data = identified("seed")[0].to_json()
    data["diagnostics"] = diagnostics
    with pytest.raises(ResultKeyError, match="diagnostics"):
        IdentificationResult.from_json(data)


#: a large servo (4 pole pairs, L / R 25 ms, a 60 Hz loop) with a position-locked disturbance at order 20, its
#: back-EMF's 5x electrical: T(20) is not free by the back-EMF's content, and without the shared-residual test
#: the winding's L / R came out 11-14 % long and eps 1.4-3.9 % off
SERVO = {"bench": {"pole_pairs": 4, "slots": 36, "inertia_kgm2": 0.05},
         "bench.backemf": {"amplitudes_nm_per_a": [1.5, 0.09, 0.045, 0.02]},
         "simulator.winding": {"phase_resistance_ohm": 0.2, "phase_inductance_h": 0.005},
         "simulator.controller": {"bandwidth_hz": 60.0, "voltage_limit_v": 300.0},
         "simulator.unexplained": {"orders": [20], "amplitudes_nm": [0.1], "phases_rad": [1.1]},
         "simulator.torque_sensor": {"noise_nm": 0.2, "dc_level_nm": 2.0, "drift_nm_per_s": 0.02},
         "limits": {"max_current_a": 40.0, "max_torque_nm": 64.0, "max_speed_hz": 1.0},
         "trials": {"torque_setpoints_nm": [8.0, 24.0, 40.0], "speed_setpoints_hz": [0.5, 1.0]}}


@pytest.mark.parametrize("seed", [1, 2])
def test_a_disturbance_at_an_electrical_order_is_the_tables_not_the_windings(seed, tmp_path):
    data = tomllib.loads(SEED_CONFIG.read_text())
    data.pop("campaign")
    for dotted, values in SERVO.items():
        table = data
        for part in dotted.split("."):
            table = table[part]
        table.update(values)
    path = tmp_path / "servo.toml"
    path.write_text(toml_text(data))
    bench, truth = simulated_bench(load_config(path), seed=seed)
    result = identify_bench(bench)
    joint = result.details.joint
    freed = joint.sets.fit[joint.sets.table_free & ~harmonic_sets(result.details.tables).table_free]
    assert freed.tolist() == [20]
    assert result.winding_time_constant_s == pytest.approx(0.005 / 0.2, rel=0.05)
    assert result.winding_conductance_s == pytest.approx(1.0 / 0.2, rel=0.05)
    assert result.epsilon == pytest.approx(truth["epsilon"], rel=0.02)


def test_the_seed_bench_frees_no_back_emf_harmonic():
    """Its unexplained orders (20, 36, 100) are none of its back-EMF's (8, 24, 40, 56): nothing shared to free."""
    result, _ = identified("seed")
    joint = result.details.joint
    assert np.array_equal(joint.sets.table_free, harmonic_sets(result.details.tables).table_free)


def test_the_loop_and_winding_covariance_reads_back_and_refuses_what_is_no_covariance():
    """The mean torque's standard error rests on it (`ilcpmac.stages.mean_torque`): it survives the result JSON,
    its diagonal the joint fit's variances; anything but a symmetric 6 x 6 of finite numbers with a diagonal >= 0
    (or null) is one error naming diagnostics.joint's key."""
    result, _ = identified("seed")
    covariance = result.loop_winding_covariance
    assert covariance is not None and covariance.shape == (6, 6) and np.all(np.diag(covariance) > 0)
    joint = result.details.joint
    mine, fitted = LOOP_WINDING.index("winding_tau_s"), list(joint.parameter_names).index("winding_tau_s")
    assert covariance[mine, mine] == pytest.approx(joint.covariance[fitted, fitted])
    np.testing.assert_array_equal(IdentificationResult.from_json(result.to_json()).loop_winding_covariance, covariance)
    asymmetric = covariance.copy()
    asymmetric[0, 1] *= 2.0
    negative = covariance.copy()
    negative[2, 2] = -1.0
    for value in ([[1.0]], "x", np.full((6, 6), np.nan).tolist(), asymmetric.tolist(), negative.tolist()):
        data = result.to_json()
        data["diagnostics"]["joint"]["loop_winding_covariance"] = value
        with pytest.raises(ResultKeyError, match="diagnostics.joint.loop_winding_covariance"):
            IdentificationResult.from_json(data)


def test_a_covariance_asymmetric_by_rounding_reads_back():
    """The small actuator's joint fit left 7e-9 (relative) between its elements (3, 4) and (4, 3), seven orders
    below its largest variance: read with 1e-9 of the element itself, its result was refused and ``ilcpmac run``
    ended on a traceback after its last trial. Rounding is now measured against sqrt(C_ii C_jj)."""
    from ilcpmac.core.records import _loop_winding_covariance

    rng = np.random.default_rng(3)
    root = rng.normal(size=(6, 6)) * np.array([3e-6, 3e-6, 3e-6, 3e-6, 1e-5, 0.5])[:, None]
    covariance = root @ root.T
    covariance[3, 4] *= 1.0 + 7e-9  # what the fit's products leave
    np.testing.assert_array_equal(_loop_winding_covariance({"loop_winding_covariance": covariance.tolist()}),
                                  covariance)
    covariance[3, 4] *= 1.01
    with pytest.raises(ResultKeyError, match="diagnostics.joint.loop_winding_covariance"):
        _loop_winding_covariance({"loop_winding_covariance": covariance.tolist()})
