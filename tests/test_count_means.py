"""Records of count means (ilcpmac.core.binning): each count the mean over the b encoder lines centred on it.

Against known answers: a harmonic's count means are the harmonic times `bin_response`; the loop's response seen as
count means is the time-domain model's; a simulated record of means keeps the noise of every line (where one line
in b would double it) and identifies the loop it ran on.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest
from campaign_helpers import SMALL_CAMPAIGN

import ilcpmac.api as ilc
from ilcpmac.core.binning import bin_response, count_means, sample_means
from ilcpmac.core.current_loop import CurrentLoop, lagged_phase
from ilcpmac.core.records import TrialRequest
from ilcpmac.sim.simulator import Simulator


@pytest.mark.parametrize("b", [1, 2, 3, 4, 8])
def test_the_count_means_of_a_harmonic_are_the_harmonic_times_the_bin_response(b):
    lines = 4096
    for h in (1, 42, 150, 600):
        phase = 2 * np.pi * h * np.arange(lines) / lines + 0.3
        means = count_means(np.cos(phase), b)
        np.testing.assert_allclose(means, bin_response(h, lines, b) * np.cos(phase[::b]), atol=1e-12)
    assert bin_response(0, lines, b) == 1.0 and np.all(bin_response(np.arange(10), lines, 1) == 1.0)


def test_sample_means_leave_out_a_count_missing_a_line_and_the_records_edges():
    b, n = 4, 6
    line = np.arange(-2, n * b - 2)  # lines -2 .. 21: every count's lines 4c - 2 .. 4c + 2 but the last's
    line = line[line != 9]           # count 2 (lines 6 .. 10) misses line 9
    values = 10.0 * line + 1.0
    kept, (means,) = sample_means(line, [values], b, n)
    assert kept.tolist() == [0, 1, 3, 4]
    np.testing.assert_allclose(means, 10.0 * b * kept + 1.0)  # a linear column's mean is its centre's value


@pytest.mark.parametrize("delay_s", [2.5e-5, -1e-4])
def test_the_loops_response_seen_as_count_means_is_the_time_domain_models(delay_s):
    """`CurrentLoop.response` with lines_per_count b: the staircase held over each count's b lines, through the
    per-line recursion, its count means (what the joint fit computes, `lagged_phase` per line)."""
    counts, b, speed_hz, tau = 512, 4, 1.0, 1.1e-3
    loop = CurrentLoop(np.full(3, tau), delay_s)
    for h in (1, 16, 48, 96, 150):
        x = np.cos(2 * np.pi * h * np.arange(counts) / counts)[None, :]
        period = np.full((1, counts * b), 1.0 / (counts * b * speed_hz))
        means = count_means(lagged_phase(np.repeat(x, b, axis=1), period, tau, delay_s), b)[0]
        measured = np.fft.rfft(means)[h] / (counts / 2)
        assert loop.response(np.array([h]), speed_hz, counts, b)[0, 0] == pytest.approx(measured, abs=1e-9)
        assert loop.response(np.array([h]), speed_hz, counts, b)[0, 0] != pytest.approx(
            loop.response(np.array([h]), speed_hz, counts)[0, 0], abs=1e-3)  # not the counts' edges'


def _noise_per_harmonic(trial, counts: int) -> float:
    """The revolution-to-revolution scatter of the torque column's harmonics 20..150, N m (mean over them)."""
    revolutions = trial.count.size // counts
    table = trial.torque_nm[: revolutions * counts].reshape(revolutions, counts)
    spectra = np.fft.rfft(table - table.mean(axis=1, keepdims=True), axis=1)[:, 20:151] * 2 / counts
    return float(np.mean(np.std(spectra, axis=0)))


def test_a_simulated_record_of_count_means_keeps_every_lines_noise_where_one_line_in_b_doubles_it(small_model):
    """The torque sensor's noise, sampled at each of 1024 lines: recorded as 256 means of 4 lines its harmonics
    scatter as in the per-line record; recorded at one line in 4 (a decimated encoder) twice as much."""
    model = dataclasses.replace(small_model, torque_sensor=dataclasses.replace(small_model.torque_sensor,
                                                                               noise_nm=0.05))
    coarse = dataclasses.replace(model, encoder=model.encoder.recorded_at(256))
    noise = {}
    for name, simulator in (("lines", Simulator(model)), ("means", Simulator(model, record_counts_per_rev=256)),
                            ("decimated", Simulator(coarse))):
        counts = simulator.record_counts_per_rev
        request = TrialRequest(2.0, 0.9, 24, np.zeros(counts), np.zeros(counts),
                               model.controller.calibration(), seed=11)
        trial = simulator.run_trial(request)
        assert trial.count.tolist() == list(range(24 * counts))
        noise[name] = _noise_per_harmonic(trial, counts)
    assert noise["means"] == pytest.approx(noise["lines"], rel=0.15)
    assert noise["decimated"] == pytest.approx(2.0 * noise["lines"], rel=0.15)


def test_a_bench_of_count_means_identifies_the_loop_and_the_gains(tmp_path):
    """The small campaign's grid (1024 lines, 0.6 and 0.9 Hz) simulated as 512 means of 2 lines (seed 4): the joint
    fit models the currents as the record holds them, and finds the gains and each phase's loop (time constant
    eps alpha_p / (2 pi 140 Hz), near the 1.1 ms a count lasts: over seeds 4, 5 and 6 within 13 % of it on means,
    as within 20 % on the 1024 edges)."""
    changes = copy.deepcopy(SMALL_CAMPAIGN)
    changes["bench"]["record_counts_per_rev"] = 512
    simulated = ilc.simulate_bench(ilc.write_config(tmp_path / "means.toml", changes), tmp_path / "means", seed=4)
    means, truth = ilc.identify(simulated.folder), simulated.truth
    assert means.epsilon == pytest.approx(truth.epsilon, rel=0.01)
    assert means.delta == pytest.approx(truth.delta, rel=0.01)
    np.testing.assert_allclose(means.alpha, truth.alpha, atol=0.01)
    assert truth.current_loop is not None and means.current_loop is not None
    np.testing.assert_allclose(means.current_loop.time_constant_s, truth.current_loop.time_constant_s, rtol=0.2)
