"""Bench folders (docs/bench-format.md): the interchange format with real test benches."""

from ilcpmac.bench.format import (
    Bench,
    BenchHead,
    convert_bench,
    read_bench,
    read_bench_head,
    read_trial,
    read_trial_csv,
    write_bench,
    write_trial,
    write_trial_csv,
)

__all__ = ["Bench", "BenchHead", "convert_bench", "read_bench", "read_bench_head", "read_trial", "read_trial_csv",
           "write_bench", "write_trial", "write_trial_csv"]
