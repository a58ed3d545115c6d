"""Reading a CSV dataset: the vectorised reader against the cell-by-cell one (issue 13, item 7).

:func:`seqbayes.store.datasets._read_csv` counts the separators of every line with numpy and parses
the numbers with :func:`numpy.loadtxt`; :func:`seqbayes.store.datasets._read_csv_cells` (its fallback
for files it refuses, and the reader before) converts one cell at a time. Both read the same
file of ``--rows`` rows and 3 columns (2 of them taken), ``--repeat`` interleaved pairs:

    python benchmarks/bench_csv.py

prints the median times, the median of the per-pair ratios, and checks that both give the same
array bit for bit.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from seqbayes.store.datasets import TableSpec, _csv_header, _read_csv, _read_csv_cells, read_regular


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=200_000)
    parser.add_argument("--repeat", type=int, default=7)
    args = parser.parse_args(argv)
    columns = ("t", "y")
    spec = TableSpec(columns)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "data.csv"
        values = np.random.default_rng(1).standard_normal((args.rows, 3))
        np.savetxt(path, values, delimiter=",", header="t,y,z", comments="")
        fast, cells = [], []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            a, _ = _read_csv(path, read_regular(path), spec)
            t1 = time.perf_counter()
            text = read_regular(path).decode("utf-8")
            header = text.split("\n", 1)[0].split(",")
            b, _ = _read_csv_cells(path, text, columns, header, _csv_header(path, header, spec))
            t2 = time.perf_counter()
            fast.append(t1 - t0)
            cells.append(t2 - t1)
            assert np.array_equal(a, b) and a.shape == (args.rows, 2)
    ratio = float(np.median(np.array(cells) / np.array(fast)))
    print(f"CSV of {args.rows:,} rows x 3 columns (2 read), median of {args.repeat} interleaved pairs: "
          f"vectorised {np.median(fast):.3f} s, cell by cell {np.median(cells):.3f} s, {ratio:.1f}x faster; "
          f"identical arrays")
    return 0


if __name__ == "__main__":
    sys.exit(main())
