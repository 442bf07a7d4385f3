"""A drive trial (no load, the drive's own table) passes the one gate as a bench trial does: `LimitGuard` copies it
(`owned_drive_request`), checks the copy (`drive_violation`) and sends exactly it; hostile requests never reach
the drive."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ilcpmac.backends.drive import DriveBackend, DriveLimits, DriveTrial
from ilcpmac.backends.guard import LimitGuard
from ilcpmac.bench.rolling import RollingData
from ilcpmac.core.errors import SafetyError
from ilcpmac.core.records import BenchDescription, BenchLimits, DriveTrialRequest, MotorInfo, SensorCalibration
from ilcpmac.pipeline.safety import SafetyLimits

CPR = 64
K_PHASE = 0.05  # N m / A of each phase's back-EMF amplitude
THETA_E = 7 * 2 * np.pi * np.arange(CPR) / CPR
BACKEMF = K_PHASE * np.column_stack([np.sin(THETA_E - 2 * np.pi * p / 3) for p in range(3)])
#: the most torque an ampere makes whatever the commutation: max over counts of sum_p |K_p|
TORQUE_PER_A = float(np.max(np.sum(np.abs(BACKEMF), axis=1)))
DESCRIPTION = BenchDescription(MotorInfo(7, 12, CPR, 1e-4, torque_sensor=False), BACKEMF,
                               SensorCalibration(np.ones(3), np.zeros(3), 1.0), BenchLimits(10.0, 1.0, 5.0))
LIMITS = SafetyLimits(max_correction_nm=0.2, max_current_a=10.0, max_torque_nm=1.0, max_speed_hz=5.0,
                      max_trial_duration_s=30.0, from_config=True)
GOOD = DriveTrialRequest(2.0, 1.0, 10.0, np.rint(127 * np.sin(2 * np.pi * np.arange(1024) / 1024)).astype(np.int8),
                         0.01, seed=3)


class Recording:
    """A drive that records what reaches it."""

    max_parallel_trials = 1

    def __init__(self) -> None:
        self.sent: list[DriveTrialRequest] = []

    def describe(self) -> BenchDescription:
        return DESCRIPTION

    def run_trial(self, request):
        raise AssertionError("a drive campaign sends no bench trial")

    def close(self) -> None:
        pass

    def drive_limits(self) -> DriveLimits:
        return DriveLimits(10.0, 5.0, 80.0)

    def run_drive_trial(self, request: DriveTrialRequest) -> DriveTrial:
        self.sent.append(request)
        rows = RollingData(np.arange(3.0), np.arange(3.0), np.ones(3, np.int64), np.zeros(3))
        return DriveTrial(request, rows, 3, 0, 30.0)

    def store_table(self, request: DriveTrialRequest) -> None:
        self.sent.append(request)


def test_the_recording_drive_is_a_drive_backend():
    assert isinstance(Recording(), DriveBackend)


def test_a_request_within_the_limits_reaches_the_drive_as_the_copy_checked():
    drive = Recording()
    trial = LimitGuard(drive, DESCRIPTION, LIMITS).run_drive_trial(GOOD)
    (sent,) = drive.sent
    assert trial.request is sent and sent is not GOOD
    np.testing.assert_array_equal(sent.table_values, GOOD.table_values)
    with pytest.raises(ValueError):
        sent.table_values[0] = 5  # the copy sent is immutable: nobody changes it after the check
    assert (sent.speed_hz, sent.settle_s, sent.seconds, sent.table_scale_a, sent.seed) == (2.0, 1.0, 10.0, 0.01, 3)


@pytest.mark.parametrize("changes, message", [
    ({"speed_hz": -5.5}, r"drive trial at -5\.5 Hz refused before it reached the backend: speed -5\.5 Hz exceeds "
                         r"5 Hz \(\[limits\] max_speed_hz or the bench's\) in magnitude"),
    ({"seconds": 29.5}, r"the trial runs 30\.5 s \(1 s settling, 29\.5 s recorded\), beyond 30 s "
                        r"\(\[limits\] max_trial_duration_s\)"),
    ({"table_scale_a": 0.1}, r"the table asks 12\.7 A of q current, beyond 10 A \(\[limits\] max_current_a"),
    ({"table_scale_a": 0.03}, r"the table's 3\.81 A make up to 0\.\d+ N m, beyond 0\.2 N m "
                              r"\(\[limits\] max_correction_nm\)"),
    ({"speed_hz": 0.0}, r"a drive trial refused before it reached the backend: speed must be finite and not 0"),
    ({"speed_hz": math.nan}, r"speed must be finite and not 0, got nan Hz"),
    ({"settle_s": -1.0}, r"settle_s must be 0 to 60 s"),
    ({"seconds": math.inf}, r"seconds must be positive and finite"),
    ({"table_scale_a": -0.01}, r"table_scale_a must be finite and not negative"),
    ({"table_values": np.full(1024, 128)}, r"table_values must be whole numbers within \[-127, 127\] \(int8\)"),
    ({"table_values": np.full(1024, 0.5)}, r"table_values must be whole numbers within"),
    ({"table_values": np.zeros((2, 512))}, r"table_values must be an array of 1 to 65536 entries"),
    ({"table_values": [0] * 1024}, r"table_values must be an array of 1 to 65536 entries"),
    ({"table_values": np.array(["a"] * 1024)}, r"table_values must be an array of real numbers"),
    ({"speed_hz": True}, r"speed must be a real number, got True"),
    ({"seed": 2**32}, r"seed must be a 32-bit unsigned integer"),
])
def test_a_request_beyond_a_limit_or_malformed_never_reaches_the_drive(changes, message):
    drive = Recording()
    with pytest.raises(SafetyError, match=message):
        LimitGuard(drive, DESCRIPTION, LIMITS).run_drive_trial(dataclasses.replace(GOOD, **changes))
    with pytest.raises(SafetyError, match=message.replace("drive trial", "drive table")):
        LimitGuard(drive, DESCRIPTION, LIMITS).store_table(dataclasses.replace(GOOD, **changes))
    assert drive.sent == []


def test_a_backend_that_drives_no_drive_refuses_a_drive_trial():
    class Bench(Recording):
        run_drive_trial = None  # type: ignore[assignment]
    with pytest.raises(SafetyError, match="the Bench backend drives no drive without a load"):
        LimitGuard(Bench(), DESCRIPTION, LIMITS).run_drive_trial(GOOD)


@settings(max_examples=300, derandomize=True, deadline=None, database=None,
          suppress_health_check=[HealthCheck.too_slow])
@given(speed=st.floats(-20, 20), scale=st.floats(0, 1), entries=st.lists(st.integers(-127, 127), min_size=1,
                                                                         max_size=64))
def test_whatever_reaches_the_drive_is_within_every_limit(speed, scale, entries):
    drive = Recording()
    request = DriveTrialRequest(speed, 1.0, 5.0, np.array(entries), scale)
    try:
        LimitGuard(drive, DESCRIPTION, LIMITS).run_drive_trial(request)
    except SafetyError:
        assert drive.sent == []
        return
    (sent,) = drive.sent
    peak_a = float(np.max(np.abs(sent.table_current_a())))
    assert 0 < abs(sent.speed_hz) <= LIMITS.max_speed_hz * (1 + 1e-9)
    assert peak_a <= LIMITS.max_current_a * (1 + 1e-9)
    assert peak_a * TORQUE_PER_A <= LIMITS.max_correction_nm * (1 + 1e-9)
