"""The torque source as a strategy, the torque sensor's response in one place, and the identification's typed
sensor dynamics (issue "One house again")."""

import numpy as np
import pytest

from ilcpmac.core.current_loop import CurrentLoop
from ilcpmac.core.records import IdentificationResult, SensorCalibration
from ilcpmac.core.torque_sensor import harmonic_response, highpass, sensor_response
from ilcpmac.core.torque_source import TorqueSource
from ilcpmac.stages.base import Identified


@pytest.mark.parametrize("source, sensor, encoder, fuses", [(TorqueSource.SENSOR, True, False, False),
                                                            (TorqueSource.ENCODER, False, True, False),
                                                            (TorqueSource.BOTH, True, True, True)])
def test_each_source_says_what_it_reads(source, sensor, encoder, fuses):
    assert (source.reads_sensor, source.reads_encoder, source.fuses) == (sensor, encoder, fuses)
    assert TorqueSource(source.value) is source


def test_the_default_source_follows_the_torque_sensor():
    assert TorqueSource.default(True) is TorqueSource.SENSOR
    assert TorqueSource.default(False) is TorqueSource.ENCODER


def test_the_sensor_response_is_the_high_pass_and_the_delay():
    w = 2 * np.pi * np.array([0.5, 1.0, 7.0])
    expected = 1j * w / (1j * w + 2 * np.pi * 0.05) * np.exp(-1j * w * 1e-3)
    np.testing.assert_array_equal(sensor_response(w, 0.05, 1e-3), expected)
    np.testing.assert_allclose(harmonic_response(np.arange(1, 4), w[0] / (2 * np.pi), 0.05, 1e-3),
                               sensor_response(w[0] * np.arange(1, 4), 0.05, 1e-3), rtol=1e-15)
    assert harmonic_response(np.arange(3), 1.0, 0.0, 0.0)[0] == 1.0  # the mean taken as it is, no 0 / 0
    np.testing.assert_array_equal(highpass(w, 0.0), np.ones(3))


def test_the_identified_sensor_dynamics_are_fields_that_survive_the_json():
    calibration = SensorCalibration(np.ones(3), np.zeros(3), 1.0)
    result = IdentificationResult(epsilon=1.0, alpha=np.ones(3), beta=np.zeros(3), torque_sensor_highpass_hz=0.05,
                                  torque_sensor_delay_s=2e-6,
                                  diagnostics={"joint": {"torque_sensor_highpass_hz": 0.05,
                                                         "torque_sensor_delay_s": 2e-6}})
    data = result.to_json()
    assert "torque_sensor_highpass_hz" not in data and data["torque_source"] == "sensor"
    back = IdentificationResult.from_json(data)
    assert (back.torque_sensor_highpass_hz, back.torque_sensor_delay_s) == (0.05, 2e-6)
    assert back.torque_source is TorqueSource.SENSOR
    identified = Identified.from_result(result, calibration)
    assert (identified.sensor_highpass_hz, identified.sensor_delay_s) == (0.05, 2e-6)
    resumed = Identified.from_result(back, calibration)
    assert (resumed.sensor_highpass_hz, resumed.sensor_delay_s) == (0.05, 2e-6)


def test_the_loops_decays_are_the_responses():
    """`CurrentLoop.count_decays`, shared by the loop's response and the encoder's staircase bias."""
    for delay in (2e-5, -1e-9):
        loop = CurrentLoop(np.array([1e-3, 1.1e-3, 0.9e-3]), delay)
        dt = 1.0 / (1024 * 3.0)
        a, b = loop.count_decays(dt)
        np.testing.assert_array_equal(a, np.exp(-dt / loop.time_constant_s))
        np.testing.assert_allclose(b, np.exp(-(dt - delay) / loop.time_constant_s) if delay >= 0
                                   else np.exp(delay / loop.time_constant_s), rtol=1e-15)
