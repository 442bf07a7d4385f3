"""A validation point's floor counts the error of interpolating the feed-forward between learned points
(`ilcpmac.campaign.floors.interpolation_error`; docs/campaign.md, "The noise floor"), checked against a known
truth: a ripple the same at every speed, cancelled at each learned speed through a known current loop."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from ilcpmac.campaign.floors import PointSpectra, interpolation_error, point_floors
from ilcpmac.compensation import interpolation_weights
from ilcpmac.core.records import SensorCalibration, TrialData, TrialRequest
from ilcpmac.pipeline.analysis import TorqueSpectrum, TrialAnalysis
from ilcpmac.signals.harmonics import harmonic_amplitudes, table_from_amplitudes

CPR, H = 256, 60
#: the ripple with no feed-forward, the same at every speed and torque (harmonics 0..H, N m)
RIPPLE = np.zeros(H + 1, complex)
RIPPLE[8], RIPPLE[48] = 0.004 - 0.002j, 0.05j


def loop(h: np.ndarray, speed_hz: float) -> np.ndarray:
    """A second-order current loop at 140 Hz: its inverse is not linear in speed, so the linearly interpolated
    tables miss."""
    return 1.0 / (1.0 + 1j * h * speed_hz / 140.0) ** 2


def ideal_tables(torques: np.ndarray, speeds: np.ndarray) -> np.ndarray:
    """At each learned point the table that cancels `RIPPLE` through `loop`: G u = -d."""
    h = np.arange(H + 1)
    per_speed = [table_from_amplitudes(np.where(h > 0, -RIPPLE / loop(h, s), 0.0), CPR) for s in speeds]
    return np.stack([per_speed] * torques.size)


def left(tables: np.ndarray, torques: np.ndarray, speeds: np.ndarray, point: tuple[float, float]) -> np.ndarray:
    """The truth: harmonics of what the compensation's bilinear feed-forward leaves at ``point``, d + G u."""
    h = np.arange(H + 1)
    u = harmonic_amplitudes(np.tensordot(interpolation_weights(torques, speeds, *point), tables, axes=2), H)
    return np.where(h > 0, RIPPLE + loop(h, point[1]) * u, 0.0)


@pytest.mark.parametrize("speeds", [(1.0,), (0.5, 1.5)])
def test_along_a_speed_axis_of_one_or_two_the_error_is_the_loops(speeds):
    torques, speeds = np.array([2.0, 4.0]), np.array(speeds)
    tables = ideal_tables(torques, speeds)
    for t in torques:
        for s in speeds:
            assert np.allclose(interpolation_error(tables, torques, speeds, (t, s), H, loop), 0.0, atol=1e-15)
    for point in [(3.0, 0.75), (2.0, 1.25), (4.0, 0.6)]:
        truth = left(tables, torques, speeds, point)
        assert np.abs(truth[48]) > 5e-4  # there is an error to find
        assert np.allclose(interpolation_error(tables, torques, speeds, point, H, loop), -truth, atol=1e-12)


def spectra(harmonics_nm: np.ndarray, variance_nm2: float, mean_nm: float) -> PointSpectra:
    spectrum = TorqueSpectrum(harmonics_nm, np.full(H + 1, variance_nm2), 0.0, CPR)
    return PointSpectra(spectrum, mean_nm, spectrum, mean_nm, np.zeros(H + 1, complex))


def test_a_validation_points_floor_is_the_expected_peak_to_peak_of_what_the_interpolation_leaves():
    """Learned points with nothing left and next to no noise; the validation trial's noise about what the
    bilinear tables leave there, drawn (another generator): its mean peak-to-peak is the floor."""
    torques, speeds = np.array([2.0]), np.array([0.5, 1.5])
    tables = ideal_tables(torques, speeds)
    nothing = np.zeros(H + 1, complex)
    learned = {(2.0, s): [spectra(nothing, 1e-16, 2.0)] * 3 for s in speeds}
    point, variance = (2.0, 1.0), 1e-8
    floor = point_floors(learned, {point: spectra(nothing, variance, 2.0)}, torques, speeds, tables, loop)[-1]
    rng = np.random.default_rng(37)
    draws = left(tables, torques, speeds, point)[:, None] + np.sqrt(variance / 2.0) * (
        rng.standard_normal((H + 1, 2000)) + 1j * rng.standard_normal((H + 1, 2000)))
    draws[0] = 0.0
    truth = np.ptp(table_from_amplitudes(draws, CPR), axis=0).mean() / 2.0
    assert not floor.learned
    assert floor.true_pp == floor.measured_pp == pytest.approx(truth, rel=0.03)


def test_a_trials_spectra_are_taken_at_the_speed_it_ran_at_as_the_stages_take_them():
    """A trial that ran 24 % below its set point's speed (a servo whose loop gives up torque to its back-EMF):
    its measured harmonics are converted and its feed-forward's torque taken at the 0.76 Hz it ran at, as
    `Pipeline.frame` does for the stages, not at the 1 Hz set; at the set speed the floor's estimate of its
    ripple was off by the response's change over that speed (13 % at a 60 Hz loop's cogging order 72)."""
    cpr, revolutions, ran_hz = 64, 4, 0.76
    count = np.arange(revolutions * cpr)
    trial = TrialData(8.0, 1.0, count, count / (cpr * ran_hz), np.zeros((count.size, 3)), np.zeros(count.size))
    ran = TrialRequest(8.0, 1.0, revolutions, np.zeros(cpr), np.zeros(cpr),
                       SensorCalibration(np.full(3, 14.0), np.zeros(3), 0.9))
    spectrum = TorqueSpectrum(np.ones(H + 1, complex), np.full(H + 1, 1e-6), 0.0, cpr)
    asked = []

    def response(h, speed_hz):
        asked.append(speed_hz)
        return loop(h, speed_hz)

    measurement = SimpleNamespace(in_true_units=lambda s, speed_hz, cal: s.divided_by(response(np.arange(H + 1),
                                                                                               speed_hz)),
                                  mean_torque_nm=lambda request: 7.0)
    pipeline = SimpleNamespace(delivered_nm=lambda request, speed_hz: response(np.arange(H + 1), speed_hz))
    got = PointSpectra.of(ran, trial, TrialAnalysis(spectrum), measurement, pipeline)
    np.testing.assert_allclose(asked, [ran_hz, ran_hz], rtol=1e-12)
    np.testing.assert_allclose(got.delivered_nm, loop(np.arange(H + 1), ran_hz))
    np.testing.assert_allclose(got.measured.harmonics_nm, 1.0 / loop(np.arange(H + 1), ran_hz))
