"""Benches that cannot support an estimate: a clear message, the other estimates still reported; the CLI."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from click.testing import CliRunner
from identify_helpers import OTHER_MOTOR, OTHER_SENSORS, other_bench, other_campaign

from ilcpmac.bench.format import write_bench
from ilcpmac.cli import main
from ilcpmac.core.errors import IdentificationError
from ilcpmac.identify import identify_bench
from ilcpmac.identify.plots import IDENTIFICATION_FIGURES
from ilcpmac.sim.reduced import ReducedCampaign, reduced_bench


def _shortened(bench, keep_counts: int, indices):
    """``bench`` with the trials at ``indices`` cut to their first ``keep_counts`` samples."""
    trials = list(bench.trials)
    for i in indices:
        t = trials[i]
        trials[i] = dataclasses.replace(t, count=t.count[:keep_counts], time_s=t.time_s[:keep_counts],
                                        i_ref_a=t.i_ref_a[:keep_counts], torque_nm=t.torque_nm[:keep_counts])
    return dataclasses.replace(bench, trials=tuple(trials))


def test_a_trial_with_too_few_revolutions_is_left_out():
    bench, truth = other_bench()
    short = _shortened(bench, int(1.5 * bench.motor.counts_per_rev), [0])
    result = identify_bench(short)
    assert any("trial_01.csv" in m and "revolution" in m for m in result.messages)
    assert result.delta_epsilon == pytest.approx(truth["total_system_gain"], rel=0.01)


def test_no_trial_long_enough_is_an_error():
    bench, _ = other_bench()
    short = _shortened(bench, bench.motor.counts_per_rev, range(len(bench.trials)))
    with pytest.raises(IdentificationError, match="no trial can be used"):
        identify_bench(short)


def test_no_excitation_keeps_the_inertia_estimate():
    bench, truth = reduced_bench(OTHER_MOTOR, OTHER_SENSORS, other_campaign(
        3, excitation=dataclasses.replace(ReducedCampaign().excitation, fraction=0.0)))
    result = identify_bench(bench)
    assert any("total system gain" in m and "no excitation" in m for m in result.messages)
    assert result.delta_epsilon is None and result.alpha is None
    assert result.delta == pytest.approx(truth["torque_sensor_gain"], rel=0.03)


def test_single_set_point_falls_back_to_the_report():
    """One trial: no inertia average and no joint fit; the report's ch. 2 and ch. 4 still answer."""
    bench, truth = reduced_bench(OTHER_MOTOR, OTHER_SENSORS, other_campaign(
        4, torque_setpoints_nm=(2.0,), speed_setpoints_hz=(0.8,)))
    result = identify_bench(bench)
    assert any("torque-sensor gain" in m and "single set point" in m for m in result.messages)
    assert any("joint fit" in m and "single trial" in m for m in result.messages)
    assert result.delta is None and result.beta is None and result.calibration is None
    assert result.delta_epsilon == result.methods["report"].delta_epsilon
    assert result.delta_epsilon == pytest.approx(truth["total_system_gain"], rel=0.01)
    np.testing.assert_allclose(result.alpha, truth["alpha"], atol=0.05)


def test_cli_writes_the_result_and_a_table(tmp_path):
    bench, truth = other_bench()
    write_bench(tmp_path / "bench", bench)
    runner = CliRunner()
    out = runner.invoke(main, ["identify", str(tmp_path / "bench"), "--output", str(tmp_path / "result.json"),
                               "--plots", str(tmp_path / "plots")])
    assert out.exit_code == 0, out.output
    data = json.loads((tmp_path / "result.json").read_text())
    assert data["total_system_gain"] == pytest.approx(truth["total_system_gain"], rel=0.005)
    assert "delta*eps" in out.output
    assert {p.stem for p in (tmp_path / "plots").glob("*.png")} == set(IDENTIFICATION_FIGURES)


def test_cli_reports_an_invalid_folder_in_one_line(tmp_path):
    out = CliRunner().invoke(main, ["identify", str(tmp_path / "missing"), "--output", str(tmp_path / "r.json")])
    assert out.exit_code == 2
    errors = [line for line in out.output.splitlines() if line.startswith("error:")]
    assert errors == [f"error: {tmp_path / 'missing'}: not a folder"]


def test_count_periods_of_two_rippling_revolutions_are_exact_and_positive():
    """A straight line through two revolutions of a strong speed ripple tilts with the ripple's phase and made
    the period at the wrap negative (a NaN in the joint fit later); the mean revolution gives it exactly."""
    from ilcpmac.identify.reduction import revolution_averages

    cpr, period_s, ripple_s = 64, 1.0, 0.1
    count = np.arange(2 * cpr)
    time_s = count * period_s / cpr + ripple_s * np.sin(2 * np.pi * count / cpr + 0.3) / (2 * np.pi)
    speed_hz, _, count_period_s = revolution_averages(count, time_s, np.zeros((count.size, 3)), cpr)
    assert speed_hz == pytest.approx(1.0 / period_s, rel=1e-12)
    np.testing.assert_allclose(count_period_s, np.diff(time_s[:cpr + 1]), rtol=1e-9)
    with pytest.raises(IdentificationError, match=r"^count \d+: mean time to the next count .* not positive"):
        revolution_averages(count, count * period_s / cpr + 2 * np.sin(2 * np.pi * count / cpr), np.zeros((2 * cpr, 3)),
                            cpr)


def test_trials_of_two_revolutions_keep_the_reports_sensor_gain(write_config):
    """The corrected ch. 3 fit needs two whole revolutions of count intervals, which two revolutions of samples
    are not; delta then comes from the report's fit (a sweep's warm-up campaign has such trials), and the
    messages say why."""
    from ilcpmac.campaign.service import simulated_bench
    from ilcpmac.config import load_config
    from ilcpmac.identify import identify_bench

    config = load_config(write_config({"bench": {"counts_per_rev": 1024},
                                       "trials": {"torque_setpoints_nm": [2.0, 4.0], "speed_setpoints_hz": [0.8, 1.0],
                                                  "revolutions": 2}}))
    bench, truth = simulated_bench(config)
    result = identify_bench(bench)
    assert result.delta == pytest.approx(truth["torque_sensor_gain"], rel=0.1)
    assert any("needs at least 2 whole revolutions" in m and "the report's ch. 3 fit is used" in m
               for m in result.messages), result.messages
