"""The identification on benches of another motor generated from eqs. (1.3) and (3.1), with known truth."""

from __future__ import annotations

import json

import numpy as np
import pytest
from identify_helpers import assert_targets, identified, relative_error

from ilcpmac.bench.format import read_bench, write_bench
from ilcpmac.identify import identify_bench


def test_other_motor_meets_the_targets():
    result, truth = identified("other")
    assert_targets(result, truth)
    assert result.current_loop_bandwidth_hz is None  # the currents follow the references: no lag to report


def test_skipped_counts_drift_and_highpass():
    """1 % of the counts skipped, a 0.05 Hz piezo high-pass, DC level and drift: the same targets."""
    result, truth = identified("other", None, 0.01, 0.05)
    assert_targets(result, truth)
    assert result.diagnostics["joint"]["torque_sensor_highpass_hz"] == pytest.approx(0.05, rel=0.3)


def test_current_loop_lag_near_the_top_harmonic():
    """A 110 Hz first-order lag; the top excitation harmonic (100) lies at 100 Hz at 1 Hz."""
    result, truth = identified("other", 110.0)
    assert relative_error(result.delta_epsilon, truth["total_system_gain"]) < 0.03
    assert relative_error(result.delta, truth["torque_sensor_gain"]) < 0.03
    assert np.abs(result.alpha - truth["alpha"]).max() < 0.01
    np.testing.assert_allclose(result.current_loop_bandwidth_per_phase_hz, 110.0, rtol=0.05)
    # the report's method, blind to the lag, is biased by it
    report = result.methods["report"]
    assert relative_error(report.delta_epsilon, truth["total_system_gain"]) > 0.03


def test_result_json_has_the_bench_format_keys(tmp_path):
    result, truth = identified("other")
    data = json.loads(json.dumps(result.to_json()))
    for key in ("total_system_gain", "torque_sensor_gain", "epsilon", "alpha", "beta", "inertia_estimate"):
        assert data[key] is not None and data[key + "_std"] is not None
    assert data["cogging"]["count"] == list(range(len(truth["cogging"]["count"])))
    assert set(data["calibration"]) == {"current_scale", "current_offset", "torque_gain"}
    np.testing.assert_allclose(data["calibration"]["current_scale"], truth["calibration"]["current_scale"], rtol=0.02)
    assert set(data["methods"]) == {"report", "joint"}


def test_bench_folder_round_trip(tmp_path):
    """Identification of the written and re-read folder gives the same result as in memory."""
    from identify_helpers import other_bench

    bench, _ = other_bench()
    write_bench(tmp_path, bench)
    again = identify_bench(read_bench(tmp_path))
    result, _ = identified("other")
    assert again.delta_epsilon == pytest.approx(result.delta_epsilon, rel=1e-4)
    np.testing.assert_allclose(again.alpha, result.alpha, atol=1e-4)
