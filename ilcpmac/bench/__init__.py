"""Bench folders (docs/bench-format.md): the interchange format with real test benches."""

from ilcpmac.bench.format import Bench, MotorInfo, read_bench, read_trial_csv, write_bench, write_trial_csv

__all__ = ["Bench", "MotorInfo", "read_bench", "read_trial_csv", "write_bench", "write_trial_csv"]
