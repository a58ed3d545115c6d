"""The run store's cost per update as a run grows: time to open, time to write, bytes written.

An update opens the store, runs the sampler (whose cost does not depend on the run's length,
except for the history prior of all-static runs) and writes the store. This script measures
the store's share at step 5 and at step ``--steps`` (500 by default): a real run of 5 steps
(N = ``--samples``, 2 parameters) of 4 steps is extended with copies of its last step (each
with its own dataset hash), one step at a time, writing and reopening the store after each:
``--repeat`` steps from step 5 and the last ``--repeat`` steps up to ``--steps``.

    python benchmarks/bench_store.py

prints, around step 5 and step 500, the median time to write one more step (appended to a
kernel copy of the file, see :meth:`RunStore.write`), the file's growth per step (the bytes
HDF5 writes; on filesystems without reflinks the kernel also copies the file), the time to
open the store, and the ratios (issue 15 asks for time and bytes per update within 1.5x).
"""

from __future__ import annotations

import argparse
import hashlib
import os
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from _user_model import decay_tables, write_config, write_model  # noqa: E402

from seqbayes.config import load_config  # noqa: E402
from seqbayes.store import RunStore  # noqa: E402


def extend(store: RunStore, n_steps: int) -> None:
    """Append copies of the last step until the store holds ``n_steps`` steps (in memory)."""
    last = store.result.steps[-1]
    steps = list(store.result.steps)
    while len(steps) < n_steps:
        k = len(steps)
        steps.append(replace(last, info=replace(last.info, step=k + 1)))
        store.mixtures.append(store.mixtures[-1])
        store.step_sizes.append(store.step_sizes[-1])
        store.rng_states.append(store.rng_states[-1])
        store.digests.append(hashlib.sha256(str(k).encode()).hexdigest())
        store.sources.append(f"d{k + 1}.csv")
        store.module_hashes.append(store.module_hashes[-1])
    store.result = replace(store.result, steps=tuple(steps))


def measure(store: RunStore, repeat: int) -> dict:
    """Median time to write one more step (the store appends it) and to open the store, and the
    growth of the file per step (what HDF5 writes; the copy the kernel makes is not counted)."""
    writes, opens, growth = [], [], []
    for _ in range(repeat):
        size = os.path.getsize(store.path)
        extend(store, store.n_steps + 1)
        t0 = time.perf_counter()
        store.write()
        writes.append(time.perf_counter() - t0)
        growth.append(os.path.getsize(store.path) - size)
        t0 = time.perf_counter()
        store = RunStore.open(store.path)
        opens.append(time.perf_counter() - t0)
    return {"steps": f"{store.n_steps - repeat + 1}-{store.n_steps}", "open": float(np.median(opens)), "write": float(np.median(writes)),
            "growth": float(np.median(growth)), "size": os.path.getsize(store.path)}, store


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--samples", type=int, default=200)
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        write_model(folder, "benchstoremodel")
        path = write_config(folder / "run.toml", "benchstoremodel", n_samples=args.samples, seed=1,
                            kernel='a = { type = "drift", rate = -0.01, noise_std = 0.02 }')
        path.write_text(path.read_text() + 'predictive = "transition"\n')
        store = RunStore.create(folder / "run.nc", load_config(path))
        for table in decay_tables([1.5 - 0.01 * s for s in range(4)], np.linspace(0, 3, 15), 0.1, seed=2):
            store.assimilate(table)
        first, store = measure(store, args.repeat)
        extend(store, args.steps - args.repeat)
        store.write()
        store = RunStore.open(store.path)
        last, store = measure(store, args.repeat)
        rows = [first, last]
    print(f"run store, N = {args.samples}, 2 parameters, transition-density prior; median of {args.repeat}")
    print(f"{'steps':>8} {'open (ms)':>10} {'write (ms)':>11} {'file growth':>12} {'file size':>11}")
    for row in rows:
        print(f"{row['steps']:>8} {1e3 * row['open']:>10.1f} {1e3 * row['write']:>11.1f} {row['growth']:>12,.0f} "
              f"{row['size']:>11,}")
    print(f"ratio steps {last['steps']} / steps {first['steps']}: open {last['open'] / first['open']:.1f}x, write "
          f"{last['write'] / first['write']:.1f}x, file growth per step {last['growth'] / first['growth']:.1f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
