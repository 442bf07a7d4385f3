"""Bench folders (docs/bench-format.md): the interchange format with real test benches."""

from ilcpmac.bench.format import (
    Bench,
    BenchHead,
    StaticTrial,
    convert_bench,
    read_bench,
    read_bench_head,
    read_static_csv,
    read_trial,
    read_trial_csv,
    write_bench,
    write_static_csv,
    write_trial,
    write_trial_csv,
)

__all__ = ["Bench", "BenchHead", "StaticTrial", "convert_bench", "read_bench", "read_bench_head", "read_static_csv",
           "read_trial", "read_trial_csv", "write_bench", "write_static_csv", "write_trial", "write_trial_csv"]
