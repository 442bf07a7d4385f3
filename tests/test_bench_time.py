"""Bench time and noise floors (docs/campaign.md, "Bench time" and "The noise floor"): the plan's motor time, the
learning schedule, ``--budget``, the floor estimators against known answers, and configs that extend others."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ilcpmac.campaign.floors import (
    PointFloor,
    PointSpectra,
    RippleEstimate,
    floors_of,
    interpolation_error,
    learning_floors,
)
from ilcpmac.campaign.plan import CampaignPlan
from ilcpmac.compensation import interpolation_weights
from ilcpmac.config import config_tables, config_text, load_config
from ilcpmac.core.errors import ConfigError
from ilcpmac.pipeline.analysis import TorqueSpectrum
from ilcpmac.signals.harmonics import expected_noise_pp, pooled_variance, table_from_amplitudes, table_harmonics

# ---------------------------------------------------------------- the noise floor's estimators


def test_the_expected_noise_pp_is_the_mean_peak_to_peak_of_such_noise():
    """Against an independent Monte-Carlo (another generator, 4000 draws) of white and of coloured noise."""
    rng = np.random.default_rng(11)
    cpr, H = 1024, 100
    for variance in (np.full(H + 1, 4e-6), 1e-5 / (1.0 + np.arange(H + 1)) ** 2):
        sd = np.sqrt(variance[1:] / 2)
        draws = np.zeros((H + 1, 4000), complex)
        draws[1:] = sd[:, None] * (rng.standard_normal((H, 4000)) + 1j * rng.standard_normal((H, 4000)))
        truth = np.ptp(table_from_amplitudes(draws, cpr), axis=0).mean()
        assert expected_noise_pp(variance, cpr) == pytest.approx(truth, rel=0.03)


def test_a_known_ripple_with_no_noise_has_its_own_peak_to_peak():
    mean = np.zeros(51, complex)
    mean[7] = 0.02j
    assert expected_noise_pp(np.zeros(51), 4096, mean) == pytest.approx(0.04, rel=1e-3)


def test_the_floor_of_a_noisy_trial_is_the_peak_to_peak_its_noise_leaves_in_the_average():
    """Truth first: trials of pure noise of a known variance per sample; the floor estimated from each trial's
    own revolution scatter (`TorqueSpectrum`) predicts the peak-to-peak the noise leaves in its average."""
    rng = np.random.default_rng(5)
    cpr, revolutions, H = 512, 12, 60
    count = np.arange(revolutions * cpr)
    time_s = count / (cpr * 0.5)
    observed, predicted = [], []
    for _ in range(200):
        torque = 0.02 * rng.standard_normal(count.size)
        spectrum = TorqueSpectrum.of(count, time_s, torque, cpr, H)
        observed.append(np.ptp(spectrum.ripple_table()))
        predicted.append(expected_noise_pp(spectrum.variance_nm2, cpr))
    assert np.mean(predicted) == pytest.approx(np.mean(observed), rel=0.05)


def test_a_short_trials_noise_is_pooled_over_neighbouring_harmonics_and_weights_right():
    """Truth first: pure noise over 3 revolutions, white and steeply coloured (h^4, as the encoder torque's): one
    harmonic's own scatter has 4 degrees of freedom, so 1 / v^ overstates the information about twice (E = k /
    (k - 2)); pooled with its neighbours (`pooled_variance`) v^ is right within 6 % and 1 / v^ within 10 % (44
    degrees of freedom leave k / (k - 2) = 1.05, and the ends' shorter windows a little more). A harmonic
    whose amplitude changes from revolution to revolution keeps its own, larger scatter."""
    rng = np.random.default_rng(29)
    cpr, revolutions, H, draws = 512, 3, 60, 300
    for colour in (np.ones(cpr // 2 + 1), (1.0 + np.arange(cpr // 2 + 1) / 8.0) ** 2):
        own, pooled = [], []
        for _ in range(draws):
            noise = np.fft.irfft(np.fft.rfft(rng.standard_normal((revolutions, cpr)), axis=-1) * colour, cpr, axis=-1)
            _, variance = table_harmonics(noise, H)
            own.append(variance[1:])
            pooled.append(pooled_variance(variance, revolutions)[1:])
        truth = np.mean(own, axis=0)
        assert np.mean(np.asarray(own) / truth) == pytest.approx(1.0, abs=0.02)  # the scatter is unbiased...
        assert np.mean(truth / np.asarray(own)) > 1.8  # ...its inverse is not
        assert np.mean(np.asarray(pooled) / truth) == pytest.approx(1.0, abs=0.06)
        assert np.mean(truth / np.asarray(pooled)) == pytest.approx(1.0, abs=0.1)
    table = 1e-3 * rng.standard_normal((revolutions, cpr))
    table += np.array([0.0, 0.5, 1.0])[:, None] * np.cos(2 * np.pi * 7 * np.arange(cpr) / cpr)
    _, variance = table_harmonics(table, H)
    assert pooled_variance(variance, revolutions)[7] == variance[7] > 1e3 * np.median(variance[1:])


def spectrum(harmonics: np.ndarray, variance: np.ndarray) -> TorqueSpectrum:
    return TorqueSpectrum(np.asarray(harmonics, complex), np.asarray(variance, float), 0.0, 256)


def complex_noise(rng: np.random.Generator, variance: np.ndarray) -> np.ndarray:
    return (rng.standard_normal(variance.shape) + 1j * rng.standard_normal(variance.shape)) * np.sqrt(variance / 2)


def test_the_learning_floor_finds_the_ripple_with_no_feed_forward_and_the_power_it_cannot_resolve():
    """Truth first: a ripple d (harmonics 1-2 large, 3-4002 a broadband 0.65 standard deviations each), seen by
    a compensation trial and two learning trials whose feed-forward (known, G^ u) removed part of it. The estimate
    is d within its noise, and the learning floor P_h where d stands out; over the broadband ripple no single
    harmonic shows, the floor's learning part (P_h where one stands out by chance, the power of the rest) is
    within 10 % of the least error of any learner that knew its power, the Wiener bound sum D P / (D + P) (0 if
    it were not counted)."""
    rng = np.random.default_rng(41)
    H = 4002
    v = np.full(H + 1, 1e-6)
    d = np.zeros(H + 1, complex)
    d[1], d[2] = 0.05, 0.01j
    d[3:] = np.sqrt(0.42 * 0.2e-6) * np.exp(2j * np.pi * rng.random(H - 2))
    trials = []
    for k, scale in enumerate((1.0, 0.5, 0.5)):
        delivered = np.zeros(H + 1, complex)
        delivered[1:3] = -d[1:3] * (1 - 0.1**k)
        measured = spectrum(d + delivered + complex_noise(rng, scale * v), scale * v)
        trials.append(PointSpectra(measured, 1.0, delivered_nm=delivered))
    estimate = RippleEstimate.of(trials)
    P = 1.0 / (1.0 / 1e-6 + 2.0 / 0.5e-6)
    assert estimate.variance_nm2 == pytest.approx(np.full(H + 1, P))
    assert np.abs(estimate.estimate_nm[1:3] - d[1:3]) == pytest.approx([0, 0], abs=5 * np.sqrt(P))
    learning = learning_floors({(1.0, 1.0): estimate})[(1.0, 1.0)].total_nm2
    assert learning[1:3] == pytest.approx([P, P]) and learning[0] == 0.0
    D = np.abs(d[3:]) ** 2
    assert learning[3:].sum() == pytest.approx(np.sum(D * P / (D + P)), rel=0.1)


def test_what_the_points_share_is_learned_pooled_and_what_one_point_has_of_its_own_at_its_noise():
    """Truth first: nine points share a ripple of 0.9 standard deviations of each one's estimate at harmonics
    1-200 (none shows it, their mean does, at 2.7: the floor there is near the pooled variance A = P / 9, with
    what the mean misses, under 0.3 P: not the ripple's power 0.81 P, nor the Wiener bound of one point alone,
    0.45 P); one point also has a large ripple of its own at harmonic 201, of which the
    points' mean carries a ninth: there every point learns its own, at its own P."""
    rng = np.random.default_rng(25)
    H, n, P = 201, 9, 1e-6
    shared = np.zeros(H + 1, complex)
    shared[1:201] = 0.9 * np.sqrt(P) * np.exp(2j * np.pi * rng.random(200))
    estimates = {}
    for k in range(n):
        d = shared.copy()
        d[201] = 0.1 if k == 0 else 0.0
        estimates[(float(k), 1.0)] = RippleEstimate(d + complex_noise(rng, np.full(H + 1, P)), np.full(H + 1, P))
    floors = {p: f.total_nm2 for p, f in learning_floors(estimates).items()}
    for point in estimates:
        assert 0.5 * P / n < np.mean(floors[point][1:201]) < 0.3 * P
        assert floors[point][201] == P
    alone = {p: f.total_nm2 for p, f in learning_floors(dict(list(estimates.items())[:2])).items()}  # no pooling
    assert np.mean(alone[(0.0, 1.0)][1:201]) > 0.4 * P


def test_the_ripple_nobody_resolved_is_estimated_over_the_points_not_from_one_point_s_noise():
    """Truth first: nine points of different noise P_k share a ripple of 0.15 standard deviations of the least
    noisy one's estimate at each of 150 harmonics, and each has its own of 0.35: next to nothing stands out, so
    all of it stays. Each point's estimate of what stays is 0.5-1.25 of the truth. Summed over one point's 150
    harmonics, the noise of |d^|^2 is about sqrt(150) P_k, as much as the ripple's power: estimated from each
    point alone (the floor of earlier releases) it came out 0 at two points and 2.2x the truth at another. (The
    pooled estimate falls short by about a quarter here: the noise left where nothing stood out is less than m
    times the noise when a ripple is under it.)"""
    rng = np.random.default_rng(27)
    H, n, P = 150, 9, 1e-6
    shared = np.zeros(H + 1, complex)
    shared[1:] = 0.15 * np.sqrt(P) * np.exp(2j * np.pi * rng.random(H))
    estimates, truth = {}, {}
    for k in range(n):
        d = shared.copy()
        d[1:] += 0.35 * np.sqrt(P) * np.exp(2j * np.pi * rng.random(H))
        variance = np.full(H + 1, P * (1 + k / 4))
        estimates[(float(k), 1.0)] = RippleEstimate(d + complex_noise(rng, variance), variance)
        truth[(float(k), 1.0)] = d
    for point, floor in learning_floors(estimates).items():
        quiet = floor.noise_nm2 == 0  # all but a few that stand out by chance
        quiet[0] = False
        assert quiet.sum() > 130
        assert 0.5 < floor.unresolved_nm2.sum() / np.sum(np.abs(truth[point][quiet]) ** 2) < 1.25


def test_summary_json_floors_read_back_as_written_and_entries_without_one_have_none():
    floors = [PointFloor((1.0, 0.5), True, 0.004, 0.001), PointFloor((2.0, 1.0), False, 0.003, None)]
    points = [{"torque_setpoint": f.point[0], "speed_setpoint": f.point[1], "learned": f.learned, **f.to_json()}
              for f in floors]
    earlier = {"torque_setpoint": 3.0, "speed_setpoint": 1.0, "learned": True}
    assert floors_of({"points": [*points, earlier]}) == {f.point: f for f in floors}
    assert floors[0].pp("true") == 0.001 and floors[1].pp("true") is None


def test_the_interpolation_error_is_zero_where_learned_and_exact_for_a_quadratic_in_torque():
    cpr, H = 256, 20
    torques, speeds = np.array([1.0, 3.0, 5.0]), np.array([0.5, 1.0])
    shape = np.zeros(H + 1, complex)
    shape[8], shape[16] = 0.01, 0.004j
    base = table_from_amplitudes(shape, cpr)

    def truth(t: float) -> np.ndarray:
        return (0.2 + 0.3 * t + 0.05 * t**2) * base

    tables = np.stack([[truth(t)] * speeds.size for t in torques])
    for t in torques:
        assert np.allclose(interpolation_error(tables, torques, speeds, (t, 0.5), H), 0.0, atol=1e-15)
    for t in (2.0, 4.0):
        bilinear = np.tensordot(interpolation_weights(torques, speeds, t, 0.75), tables, axes=2)
        error = interpolation_error(tables, torques, speeds, (t, 0.75), H)
        assert np.allclose(table_from_amplitudes(error, cpr), truth(t) - bilinear, atol=1e-12)
        assert np.abs(error).max() > 1e-4  # there is an error to find


# ---------------------------------------------------------------- the plan's motor time


def test_the_plans_motor_time_is_its_trials_warm_ups_and_revolutions_at_their_speeds(plan):
    c, warmup = plan.config.campaign, plan.config.grid.warmup_revolutions
    steps = plan.steps_left([])
    assert len(steps) == plan.most_remaining([]) == len(plan.grid) + (2 + c.learn_trials) * len(plan.learned) + 2
    expected = sum((warmup + s.request.revolutions) / s.request.speed_setpoint_hz for s in steps)
    assert plan.motor_time_s() == pytest.approx(expected)
    assert list(plan.bench_time_left([])) == ["identify", "compensate", "learn", "validate"]
    learning = [s.request.revolutions for s in steps if s.role in ("compensate", "learn")
                and s.request.torque_setpoint_nm == 2.0]
    assert learning == sorted(learning) and learning[-1] == plan.config.trial_revolutions((2.0, 0.9))
    assert {s.request.revolutions for s in steps if s.role == "baseline"} == {c.baseline_revolutions}


def test_a_budget_sizes_the_trials_after_the_grid_to_fit_or_says_what_the_shortest_takes(write_config):
    from campaign_helpers import SMALL_CAMPAIGN, simulator_backend

    cfg = load_config(write_config(SMALL_CAMPAIGN))
    description = simulator_backend(cfg).describe()
    full = CampaignPlan.build(cfg, description, 7).motor_time_s()
    for budget in (0.95 * full, full, 3.0 * full):
        plan = CampaignPlan.within_budget(cfg, description, 7, budget)
        assert plan.motor_time_s() <= budget and plan.budget_s == budget
        longer = CampaignPlan.build(cfg.with_trial_lengths(plan.scale * 2 ** (1 / 8)), description, 7)
        assert longer.motor_time_s() > budget  # the longest that fits
    assert CampaignPlan.within_budget(cfg, description, 7, 3.0 * full).scale > 1.0
    with pytest.raises(ConfigError, match=r"^--budget 0.01 min: the shortest plan of .* takes [\d.]+ min of motor "
                                          r"time \(identify [\d.]+, compensate"):
        CampaignPlan.within_budget(cfg, description, 7, 0.6)


@pytest.mark.slow
def test_a_campaign_runs_as_long_as_its_plan_said_and_reports_every_point_against_its_floor(tmp_path, write_config):
    """The small campaign on the simulator: the motor time summary.json gives per phase is the plan's, trial by
    trial; every point has a floor below its uncompensated ripple, and its final ripple is not far below it: the
    floor is an expected peak-to-peak, which the final trial's own scatter and the floor's estimate (of the ripple
    no trial resolved) spread about (0.48-2.0x at the 240 points of benchmarks/other_motors.py --seeds)."""
    from campaign_helpers import SMALL_CAMPAIGN

    import ilcpmac.campaign

    cfg = load_config(write_config(SMALL_CAMPAIGN))
    result = ilcpmac.campaign.run(cfg, out=tmp_path / "run", seed=7)
    motor = result.summary["motor_time_s"]
    assert motor["all"] == pytest.approx(result.plan.motor_time_s())
    assert {k: v for k, v in motor.items() if k != "all"} == pytest.approx(result.plan.bench_time_left([]))
    assert all(r.motor_time_s == pytest.approx(result.plan.bench_seconds(result.plan.base_request(
        r.point, 0, json.loads((tmp_path / "run" / "states" / f"trial_{r.index:03d}.json").read_text())
        ["request"]["revolutions"]))) for r in result.records)
    points = result.summary["points"]
    assert len(points) == len(result.plan.learned) + len(result.plan.validated)
    for p in points:
        for kind in ("measured", "true"):
            assert 0 < p[f"floor_pp_{kind}"] < p[f"uncompensated_pp_{kind}"]
            assert p[f"ripple_pp_{kind}"] > 0.45 * p[f"floor_pp_{kind}"]


# ---------------------------------------------------------------- configs that extend others


def test_a_config_extends_another_table_by_table_and_a_run_keeps_them_merged(tmp_path):
    from conftest import SEED_CONFIG

    (tmp_path / "seed.toml").write_text(SEED_CONFIG.read_text())
    quick = tmp_path / "quick.toml"
    quick.write_text('extends = "seed.toml"\n[trials]\nrevolutions = 4\n[campaign]\nlearn_trials = 2\n')
    cfg = load_config(quick)
    seed = load_config(tmp_path / "seed.toml")
    assert cfg.grid.revolutions == 4 and cfg.grid.speed_setpoints_hz == seed.grid.speed_setpoints_hz
    assert cfg.campaign.learn_trials == 2 and cfg.campaign.learn_revolutions == seed.campaign.learn_revolutions
    assert cfg.model == seed.model
    kept = tmp_path / "kept.toml"
    kept.write_text(config_text(cfg))
    assert config_tables(kept) == config_tables(quick) and load_config(kept).grid == cfg.grid
    assert config_text(seed) == SEED_CONFIG.read_text()  # a config that extends nothing is kept as written


@pytest.mark.parametrize("text, message", [
    ('extends = "loop.toml"\n', r"loop.toml: extends: 'loop.toml' extends itself"),
    ('extends = 3\n', r"loop.toml: extends: a config's file name, relative to .*, got 3"),
    ('extends = "missing.toml"\n', r"missing.toml: no such file"),
])
def test_a_config_that_extends_wrongly_is_one_line(tmp_path, text, message):
    path = tmp_path / "loop.toml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_config(path)


def test_the_quick_preset_is_the_seed_bench_with_a_shorter_campaign():
    from conftest import SEED_CONFIG

    quick = load_config(SEED_CONFIG.parent / "quick.toml")
    seed = load_config(SEED_CONFIG)
    assert quick.model == seed.model and quick.bench == seed.bench and quick.limits == seed.limits
    assert quick.campaign.learn_trials < seed.campaign.learn_trials


def test_the_final_lines_give_each_set_of_points_against_its_floor_and_the_motor_time():
    from ilcpmac.campaign.record import TrialRecord
    from ilcpmac.report.table import final_lines
    from ilcpmac.signals.harmonics import RippleFigures

    # summary.json's entries as the campaign writes them (`PointResult.to_json` with its two trials' indices,
    # `PointFloor.to_json` always holding the measured floor)
    trials, points = [], []
    for t, learned, ripple, floor in ((1.0, True, 0.0009, 0.0009), (3.0, True, 0.0006, 0.0005),
                                      (2.0, False, 0.0017, 0.0013)):
        for pp, role in ((0.02, "baseline"), (ripple, "learn" if learned else "validate")):
            trials.append(TrialRecord(len(trials) + 1, "learn" if learned else "validate", role, t, 1.0,
                                      RippleFigures(pp, *(0.0,) * 7), RippleFigures(pp, *(0.0,) * 7)).to_json())
        points.append({"torque_setpoint": t, "speed_setpoint": 1.0, "learned": learned,
                       "uncompensated_trial": len(trials) - 1, "compensated_trial": len(trials),
                       "floor_pp_measured": 0.004, "floor_pp_true": floor})
    summary = {"trials": trials, "points": points,
               "motor_time_s": {"identify": 132.0, "learn": 708.0, "all": 840.0}}
    assert final_lines(summary) == [
        "learned: true ripple 0.0900 % of mean torque at worst (1 N m, 1 Hz); each point 1.00-1.20x its floor",
        "learned: measured ripple 0.0900 % of mean torque at worst (1 N m, 1 Hz); each point 0.150-0.225x its floor",
        "validation: true ripple 0.170 % of mean torque at worst (2 N m, 1 Hz); each point 1.31-1.31x its floor",
        "validation: measured ripple 0.170 % of mean torque at worst (2 N m, 1 Hz); each point 0.425-0.425x its floor",
        "motor time: 14.0 min (identify 2.2, learn 11.8 min; warm-ups included)"]


@pytest.mark.slow
def test_the_readmes_figures_are_what_the_default_campaign_prints(tmp_path):
    """The README's main job (trials, motor minutes, MB) and its ripple row (the worst learned and validation
    points, their range against the floors) against a fresh default run: they drifted before (12 s, 121 trials,
    160 MB said; 46 s, 113 trials, 147 MB printed)."""
    import re
    import subprocess
    import sys
    from pathlib import Path

    readme = (Path(__file__).resolve().parents[1] / "README.md").read_text()
    # as the README's command runs it: a process of its own (the identification's last bits, and so what the
    # campaign's discrete decisions make of them, depend on the process's numerical libraries' threads)
    done = subprocess.run([sys.executable, "-m", "ilcpmac", "run", "--out", str(tmp_path / "run")],
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-500:]
    summary = json.loads((tmp_path / "run" / "summary.json").read_text())
    job = re.search(r"(\d+) trials, ([\d.]+) min of the motor's\s+running time on a real bench, about \d+ s on the "
                    r"simulator, (\d+) MB", readme)
    assert job is not None
    size_mb = sum(p.stat().st_size for p in (tmp_path / "run").rglob("*") if p.is_file()) / 1e6
    assert int(job[1]) == len(summary["trials"])
    assert float(job[2]) == round(summary["motor_time_s"]["all"] / 60, 1)
    assert abs(int(job[3]) - size_mb) < 1.0
    row = re.search(r"true ripple <= ([\d.]+) % pp at the 9 learned points .*?, <= ([\d.]+) % at 6 points never "
                    r"learned, each ([\d.]+)-([\d.]+)x its noise floor, in ([\d.]+) min", readme)
    assert row is not None
    points = summary["points"]
    worst = [max(100 * p["ripple_pp_true"] for p in points if p["learned"] == learned) for learned in (True, False)]
    ratios = [p["ripple_pp_true"] / p["floor_pp_true"] for p in points]
    assert [float(row[1]), float(row[2])] == [round(w, 3) for w in worst]
    assert [float(row[3]), float(row[4])] == [round(min(ratios), 2), round(max(ratios), 2)]
    assert float(row[5]) == float(job[2])


def test_the_budget_option_takes_the_plan_s_range():
    """cli/run.py states ``--budget``'s range without importing the campaign: it must be the plan's."""
    from ilcpmac.campaign.plan import MAX_BUDGET_MIN
    from ilcpmac.cli.run import run

    (budget,) = [p for p in run.params if p.name == "budget_min"]
    assert (budget.type.min, budget.type.max, budget.type.min_open) == (0.0, MAX_BUDGET_MIN, True)
