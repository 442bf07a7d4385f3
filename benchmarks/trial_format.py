"""Trial-file encodings side by side (issue 26, item 3): bytes, write and read time of every trial of a run
directory and of the seed bench, in each encoding measured.

    python benchmarks/trial_format.py [--run RUN_DIR] [--bench BENCH_DIR] [--repeats N]

Without --run, the default campaign (``ilcpmac run``) is run into a temporary folder first; without --bench,
``ilcpmac simulate`` of the seed config. Their trials are read once (any encoding: the values are the same), then
written in memory in each encoding: the decimals ilcpmac wrote before, float64 in one encoding for every column,
and the writer's choice per column (`ilcpmac.bench.parquet.table_bytes`) at three zstd levels. Write: CPU seconds
to make every file's bytes; read: wall seconds of `read_columns` of every file from memory-backed files; each the
best of --repeats. The machine may be shared: times are upper bounds, sizes exact.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq

from ilcpmac.bench import parquet
from ilcpmac.bench.format import convert_bench

ROOT = Path(__file__).resolve().parents[1]
SEED = ROOT / "src" / "ilcpmac" / "configs" / "seed-bench.toml"
Trial = tuple[list[str], list[np.ndarray], list[int]]


def decimals(name: str) -> int:
    """The CSV's decimals of a trial column."""
    return 0 if name == "count" else 7 if name == "time" else 6


def trials(folder: Path) -> list[Trial]:
    """Every Parquet trial of ``folder``: header, columns (count as int64) and decimals."""
    out = []
    for path in sorted(folder.glob("*.parquet")):
        header, columns = parquet.read_columns(path, 1 << 22, set(pq.read_schema(path).names))
        out.append((header, [c.astype(np.int64) if n == "count" else c for n, c in zip(header, columns)],
                    [decimals(n) for n in header]))
    return out


def before(header: list[str], columns: list[np.ndarray], places: list[int]) -> bytes:
    """The encoding of ilcpmac before issue 26: DECIMAL(18, d) in INT64, delta-encoded, zstd (level 3)."""
    arrays = []
    for values, d in zip(columns, places):
        if d == 0:
            arrays.append(pa.array(values))
        else:
            ints = np.rint(values * 10.0**d).astype(np.int64)
            arrays.append(pa.Array.from_buffers(pa.decimal64(18, d), ints.size, [None, pa.py_buffer(ints)]))
    schema = pa.schema([pa.field(n, a.type, nullable=False) for n, a in zip(header, arrays)])
    sink = pa.BufferOutputStream()
    pq.write_table(pa.Table.from_arrays(arrays, schema=schema), sink, compression="zstd", use_dictionary=False,
                   store_decimal_as_integer=True, column_encoding="DELTA_BINARY_PACKED", store_schema=False,
                   write_statistics=False)
    return sink.getvalue().to_pybytes()


def every_column(encoding: str, level: int) -> Callable[[list[str], list[np.ndarray], list[int]], bytes]:
    """float64 in ``encoding`` for every column but count (int64, delta), zstd at ``level``."""
    def write(header: list[str], columns: list[np.ndarray], places: list[int]) -> bytes:
        arrays = [pa.array(c) if n == "count" else pa.array(parquet.rounded(c, d))
                  for n, c, d in zip(header, columns, places)]
        encodings = ["DELTA_BINARY_PACKED" if n == "count" else encoding for n in header]
        saved = parquet.ZSTD_LEVEL
        parquet.ZSTD_LEVEL = level
        try:
            return parquet._file(header, arrays, encodings)
        finally:
            parquet.ZSTD_LEVEL = saved
    return write


def chosen(level: int) -> Callable[[list[str], list[np.ndarray], list[int]], bytes]:
    """`parquet.table_bytes` (an encoding per column) at zstd ``level``."""
    def write(header: list[str], columns: list[np.ndarray], places: list[int]) -> bytes:
        saved = parquet.ZSTD_LEVEL
        parquet.ZSTD_LEVEL = level
        try:
            return parquet.table_bytes(header, columns, places)
        finally:
            parquet.ZSTD_LEVEL = saved
    return write


def measure(data: list[Trial], write, repeats: int, work: Path) -> tuple[int, float, float]:
    """Total bytes, best write CPU s and best read wall s of ``data`` in the encoding ``write``."""
    write_s, read_s, files = float("inf"), float("inf"), []
    for _ in range(repeats):
        start = time.process_time()
        files = [write(*trial) for trial in data]
        write_s = min(write_s, time.process_time() - start)
    paths = []
    for k, content in enumerate(files):
        paths.append(work / f"t{k}.parquet")
        paths[-1].write_bytes(content)
    for _ in range(repeats):
        start = time.perf_counter()
        for path, (header, _, _) in zip(paths, data):
            parquet.read_columns(path, 1 << 22, set(header))
        read_s = min(read_s, time.perf_counter() - start)
    return sum(len(f) for f in files), write_s, read_s


CANDIDATES = [("DECIMAL(18, d), delta, zstd 3 (before)", before),
              ("float64 plain, zstd 3", every_column("PLAIN", 3)),
              ("float64 byte-stream-split, zstd 3", every_column("BYTE_STREAM_SPLIT", 3)),
              ("float64 byte-stream-split, zstd 9", every_column("BYTE_STREAM_SPLIT", 9)),
              ("float64 dictionary, zstd 3", every_column(parquet.DICTIONARY, 3)),
              ("float64 per column (writer), zstd 3", chosen(3)),
              ("float64 per column (writer), zstd 4 (chosen)", chosen(4)),
              ("float64 per column (writer), zstd 6", chosen(6))]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", type=Path, help="a run directory (default: run the default campaign)")
    parser.add_argument("--bench", type=Path, help="a bench folder (default: simulate the seed bench)")
    parser.add_argument("--repeats", type=int, default=3, help="runs per time; the best counts (default 3)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        run, bench = args.run, args.bench
        if run is None:
            run = tmp / "run"
            subprocess.run([sys.executable, "-m", "ilcpmac", "run", "--out", str(run)], check=True,
                           capture_output=True)
        if bench is None:
            subprocess.run([sys.executable, "-m", "ilcpmac", "simulate", str(SEED), "--out", str(tmp / "seed")],
                           check=True, capture_output=True)
            bench = tmp / "seed-parquet"
            convert_bench(tmp / "seed", bench, ".parquet")
        folders = {"run directory": run, "seed bench": bench}
        work = tmp / "work"
        work.mkdir()
        print(f"{'trial encoding':<46}" + "".join(f"{name + ': MB, B/row, write s, read s':>48}" for name in folders))
        data = {name: trials(folder) for name, folder in folders.items()}
        rows = {name: sum(len(t[1][0]) for t in d) for name, d in data.items()}
        for label, write in CANDIDATES:
            cells = []
            for name, d in data.items():
                size, write_s, read_s = measure(d, write, args.repeats, work)
                cells.append(f"{size / 1e6:.2f} MB {size / rows[name]:6.2f} {write_s:6.2f} s {read_s:6.2f} s")
            print(f"{label:<46}" + "".join(f"{c:>48}" for c in cells), flush=True)
        for name, folder in folders.items():
            total = sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())
            trial_bytes = sum(p.stat().st_size for p in folder.glob("*.parquet"))
            print(f"{name}: {folder}, {len(data[name])} trials, {rows[name]} rows; {total / 1e6:.2f} MB in all, "
                  f"{(total - trial_bytes) / 1e6:.2f} MB of it not trials")


if __name__ == "__main__":
    main()
