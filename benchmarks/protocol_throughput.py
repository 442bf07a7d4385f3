"""Trial-data throughput of the bench protocol over loopback, against the >= 50 MB/s target.

Run ``python benchmarks/protocol_throughput.py`` (a few seconds) or add ``--quick``.

An in-process `BenchEmulator` serves a fixed synthetic trial of 300 000
samples with every column (count, time, three current references, torque,
three measured currents, true torque, three true currents, true speed:
112 bytes per sample, 33.6 MB per trial) on 127.0.0.1; `RemoteBackend`
requests it repeatedly. Each measurement is the wall time
(``time.perf_counter``) of one ``run_trial``: request, frame encoding and
CRC on the target, TCP loopback, CRC and sequence checks, assembly and the
whole-trial checksum on the client. Throughput = column bytes / wall time,
in MB/s (10^6 bytes per second); the best and the median of the repeats are
reported for several DATA frame sizes. Client and target share one Python
process (and its GIL), so a separate target process can only be faster.
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from ilcpmac.backends.base import BenchDescription, BenchLimits
from ilcpmac.backends.emulator import BenchEmulator
from ilcpmac.backends.remote import RemoteBackend
from ilcpmac.core.records import MotorInfo, SensorCalibration, TrialData, TrialRequest

TARGET_MB_S = 50.0
COUNTS_PER_REV = 4096
CALIBRATION = SensorCalibration([14.0, 14.0, 14.0], [0.0, 0.0, 0.0], 0.908)


class FixedTrial:
    """A backend that answers every request with the same prebuilt trial."""

    def __init__(self, trial: TrialData) -> None:
        self.trial = trial

    def describe(self) -> BenchDescription:
        theta = 2 * np.pi * np.arange(COUNTS_PER_REV) / COUNTS_PER_REV
        backemf = 0.2 * np.sin(8 * theta[:, None] - 2 * np.pi * np.arange(3) / 3)
        return BenchDescription(MotorInfo(8, 48, COUNTS_PER_REV, 0.01056), backemf, CALIBRATION,
                                BenchLimits(max_current_a=100.0, max_torque_nm=10.0, max_speed_hz=10.0))

    def run_trial(self, request: TrialRequest) -> TrialData:
        return self.trial


def synthetic_trial(n: int, seed: int = 0) -> TrialData:
    """n samples with every TrialData column filled with random numbers (time stamps increasing)."""
    rng = np.random.default_rng(seed)
    return TrialData(1.0, 1.0, count=np.arange(n, dtype=np.int64), time_s=np.cumsum(0.5 + rng.random(n)),
                     i_ref_a=rng.standard_normal((n, 3)), torque_nm=rng.standard_normal(n),
                     i_meas_a=rng.standard_normal((n, 3)), torque_true_nm=rng.standard_normal(n),
                     i_true_a=rng.standard_normal((n, 3)), speed_true_rad_s=rng.standard_normal(n))


def column_bytes(trial: TrialData) -> int:
    """Bytes of all the trial's columns."""
    return sum(getattr(trial, name).nbytes for name in
               ("count", "time_s", "i_ref_a", "torque_nm", "i_meas_a", "torque_true_nm", "i_true_a",
                "speed_true_rad_s"))


def measure(trial: TrialData, chunk_samples: int, repeats: int) -> list[float]:
    """Wall times of ``repeats`` remote trials, s (after one warm-up trial)."""
    revolutions = -(-trial.n_samples // COUNTS_PER_REV)
    request = TrialRequest(1.0, 1.0, revolutions, np.zeros(COUNTS_PER_REV), np.zeros(COUNTS_PER_REV), CALIBRATION)
    with BenchEmulator(FixedTrial(trial), "127.0.0.1", 0, chunk_samples=chunk_samples) as target:
        with RemoteBackend(target.address, read_timeout_s=30.0, retries=0) as backend:
            got = backend.run_trial(request)
            assert np.array_equal(got.i_true_a, trial.i_true_a) and np.array_equal(got.count, trial.count)
            times = []
            for _ in range(repeats):
                start = time.perf_counter()
                backend.run_trial(request)
                times.append(time.perf_counter() - start)
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer samples and repeats")
    args = parser.parse_args()
    n, repeats = (100_000, 3) if args.quick else (300_000, 7)
    trial = synthetic_trial(n)
    size = column_bytes(trial)
    print(f"trial: {n} samples, all 8 columns, {size / 1e6:.1f} MB of column data; {repeats} repeats each")
    print(f"{'DATA frame':>22} | {'best MB/s':>9} | {'median MB/s':>11} | target       | result")
    print("-" * 75)
    for chunk in (1024, 8192, 65536):
        times = measure(trial, chunk, repeats)
        best, median = size / min(times) / 1e6, size / statistics.median(times) / 1e6
        frame_kb = (24 + 112 * chunk) / 1e3
        verdict = "PASS" if median >= TARGET_MB_S else "MISS"
        print(f"{chunk:>7} samples {frame_kb:>7.1f} kB | {best:>9.0f} | {median:>11.0f} "
              f"| >= {TARGET_MB_S:.0f} MB/s  | {verdict}")


if __name__ == "__main__":
    main()
