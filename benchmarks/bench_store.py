"""The run store's cost per update as a run grows: time to open, time to write, bytes written.

An update opens the store, runs the sampler (whose cost does not depend on the run's length,
except for the history prior of all-static runs) and writes the store. This script measures
the store's share at step 5 and at step ``--steps`` (500 by default): a real run of 5 steps
(N = ``--samples``, 2 parameters) is extended with copies of its last step (each with its own
dataset hash), and at each measured length the store is opened and written ``--repeat`` times.

    python benchmarks/bench_store.py

prints, per length, the median open and write time and the bytes written per update, and the
ratio of step 500 to step 5 (issue 15 asks for time and bytes per update within 1.5x).
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
    writes, opens = [], []
    for _ in range(repeat):
        t0 = time.perf_counter()
        store.write()
        writes.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        RunStore.open(store.path)
        opens.append(time.perf_counter() - t0)
    return {"steps": store.n_steps, "open": float(np.median(opens)), "write": float(np.median(writes)),
            "bytes": os.path.getsize(store.path)}


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
        for table in decay_tables([1.5 - 0.01 * s for s in range(5)], np.linspace(0, 3, 15), 0.1, seed=2):
            store.assimilate(table)
        rows = [measure(store, args.repeat)]
        extend(store, args.steps)
        rows.append(measure(store, args.repeat))
    print(f"run store, N = {args.samples}, 2 parameters, transition-density prior; median of {args.repeat}")
    print(f"{'step':>6} {'open (ms)':>10} {'write (ms)':>11} {'bytes per update':>17}")
    for row in rows:
        print(f"{row['steps']:>6} {1e3 * row['open']:>10.1f} {1e3 * row['write']:>11.1f} {row['bytes']:>17,}")
    first, last = rows
    print(f"ratio step {last['steps']} / step {first['steps']}: open {last['open'] / first['open']:.1f}x, write "
          f"{last['write'] / first['write']:.1f}x, bytes {last['bytes'] / first['bytes']:.1f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
