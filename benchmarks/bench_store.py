"""The run store's cost per update as a run grows: time to open, time and bytes to write one step.

An update opens the store, runs the sampler (whose cost does not depend on the run's length,
except for the history prior of all-static runs) and writes the store. This script measures
the store's share at step 5 and at step ``--steps`` (500 by default). A real run of 4 steps
(N = ``--samples``, 2 parameters, transition-density prior) is extended in memory with copies
of its last step (each with its own dataset hash) to 5 and to ``--steps`` steps and written
once each; then, ``--repeat`` times, in interleaved pairs (the short store, then the long one):
the saved file is copied into place (not timed), opened (timed), given one more step and
written (timed; the step is appended through the journal, see :mod:`seqbayes.store.files`), and the
bytes written are read from ``/proc/self/io``: ``wchar``, what the store passed to write calls
(the journal, then the same pages in the store), and ``write_bytes``, what the kernel sent to
storage for it (whole page-cache folios: readahead makes them larger in a larger file, so this
grows with the file although the store writes the same pages); the copy is not counted.

    python benchmarks/bench_store.py

prints the medians of both stores, the median of the per-pair ratios and the file sizes
(issue 15 asks for time and bytes per update at step 500 within 1.5x of step 5). With
``--full`` each step is a real update of a new dataset (open, the sampler's step, the write),
the time a user waits for ``seqbayes update``. With ``--smc2`` the run is SMC^2 (the default
predictive of static plus drifting parameters): y = a exp(-b t) + c with a and c drifting and b
static, 3 parameters; the store keeps the sampler's full state (the inner filters) for the last two
steps only, so the file grows by the posterior record per step (issue 24):

    python benchmarks/bench_store.py --smc2 --samples 500 --repeat 3
"""

from __future__ import annotations

import argparse
import hashlib
import os
import shutil
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

from _user_model import decay_tables, write_config, write_model  # noqa: E402

from seqbayes.store import RunStore, load_config  # noqa: E402


#: The likelihood of ``--smc2``: y = a exp(-b t) + c, noise sd 0.1 (the decay model with an offset).
SMC2_MODEL = """
def offset_loglike(theta, data):
    t, y = data[:, 0], data[:, 1]
    pred = theta[:, [0]] * np.exp(-theta[:, [1]] * t[None, :]) + theta[:, [2]]
    return -0.5 * np.sum((y - pred) ** 2, axis=1) / 0.1 ** 2
"""


def extend(store: RunStore, n_steps: int) -> None:
    """Append copies of the last step until the store holds ``n_steps`` steps (in memory)."""
    last = store.result.steps[-1]
    steps = list(store.result.steps)
    while len(steps) < n_steps:
        k = len(steps)
        steps.append(replace(last, info=replace(last.info, step=k + 1)))
        store.states.append(store.states[-1])
        if store.tables:                       # the datasets the state needs (the conflict remedy's window)
            store.tables.append(store.tables[-1])
        store.step_sizes.append(store.step_sizes[-1])
        store.rng_states.append(store.rng_states[-1])
        store.digests.append(hashlib.sha256(str(k).encode()).hexdigest())
        store.sources.append(f"d{k + 1}.csv")
        store.module_hashes.append(store.module_hashes[-1])
    store.result = replace(store.result, steps=tuple(steps))


def written_bytes() -> tuple[int, int]:
    """``(wchar, write_bytes)`` of this process (``/proc/self/io``, Linux): the bytes it passed to
    write calls, and the bytes it caused to be sent to storage (the kernel counts whole page-cache
    folios, which readahead may have made larger than the pages written)."""
    with open("/proc/self/io") as fh:
        fields = dict(line.split(":") for line in fh)
    return int(fields["wchar"]), int(fields["write_bytes"])


def one_update(saved: Path, path: Path, table=None) -> dict:
    """Copy ``saved`` to ``path``, open it, add a step and write it: the times and bytes written.
    With ``table`` the step is a real update (the sampler assimilates it; ``write`` then times the
    sampler and the write together)."""
    shutil.copyfile(saved, path)
    with open(path, "rb+") as fh:               # the copy on disk before the update starts
        os.fsync(fh.fileno())
    t0 = time.perf_counter()
    store = RunStore.open(path)
    t1 = time.perf_counter()
    if table is None:
        extend(store, store.n_steps + 1)
    before = written_bytes()
    t2 = time.perf_counter()
    if table is None:
        store.write()
    else:
        store.assimilate(table, "new.csv")
    t3 = time.perf_counter()
    after = written_bytes()
    return {"open": t1 - t0, "write": t3 - t2, "calls": after[0] - before[0], "bytes": after[1] - before[1],
            "size": path.stat().st_size, "steps": store.n_steps}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=500)
    parser.add_argument("--samples", type=int, default=200)
    parser.add_argument("--repeat", type=int, default=15)
    parser.add_argument("--full", action="store_true",
                        help="time whole updates: open, assimilate a new dataset (the sampler runs), write")
    parser.add_argument("--smc2", action="store_true",
                        help="an SMC^2 run of 3 parameters (2 drifting, 1 static) instead of the transition prior")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        write_model(folder, "benchstoremodel", extra=SMC2_MODEL)
        path = write_config(folder / "run.toml", "benchstoremodel", n_samples=args.samples, seed=1,
                            kernel='a = { type = "drift", rate = -0.01, noise_std = 0.02 }')
        if args.smc2:
            path.write_text(path.read_text().replace('likelihood = "benchstoremodel:loglike"',
                                                     'likelihood = "benchstoremodel:offset_loglike"')
                            .replace("[kernel]", 'c = { dist = "uniform", loc = -0.5, scale = 1.0 }\n[kernel]\n'
                                     'c = { type = "drift", rate = 0.0, noise_std = 0.01 }'))
        else:
            path.write_text(path.read_text() + 'predictive = "transition"\n')
        config = load_config(path)
        store = RunStore.create(folder / "run.nc", config)
        for table in decay_tables([1.5 - 0.01 * s for s in range(4)], np.linspace(0, 3, 15), 0.1, seed=2):
            store.assimilate(table)
        saved = {}
        for n in (5, args.steps):
            extend(store, n)
            store.write()
            saved[n] = folder / f"saved{n}.nc"
            shutil.copyfile(store.path, saved[n])
        rows = {5: [], args.steps: []}
        new = decay_tables([1.45], np.linspace(0, 3, 15), 0.1, seed=3)[0] if args.full else None
        for _ in range(args.repeat):             # interleaved pairs: the machine's load hits both alike
            for n in rows:
                rows[n].append(one_update(saved[n], folder / f"work{n}.nc", new))
    short, long = rows[5], rows[args.steps]
    prior = ("3 parameters, SMC^2" if args.smc2 else "2 parameters, transition-density prior")
    print(f"run store, N = {args.samples}, {prior} ({config.predictive_method}); median of {args.repeat} "
          f"interleaved pairs" + ("; whole updates: 'write' is the sampler's step and the write" if args.full else ""))
    print(f"{'update':>10} {'file size':>11} {'open (ms)':>10} {'write (ms)':>11} {'open+write':>11} "
          f"{'written':>10} {'to storage':>11}")
    for runs in (short, long):
        med = {key: float(np.median([r[key] for r in runs])) for key in ("open", "write", "calls", "bytes")}
        both = float(np.median([r["open"] + r["write"] for r in runs]))
        print(f"{runs[0]['steps'] - 1:>4} -> {runs[0]['steps']:<4}{runs[0]['size']:>11,} {1e3 * med['open']:>10.1f} "
              f"{1e3 * med['write']:>11.1f} {1e3 * both:>11.1f} {med['calls']:>10,.0f} {med['bytes']:>11,.0f}")

    def ratio(key):
        if key == "both":
            return float(np.median([(b["open"] + b["write"]) / (a["open"] + a["write"]) for a, b in zip(short, long)]))
        return float(np.median([b[key] / a[key] for a, b in zip(short, long)]))

    growth = (long[0]["size"] - short[0]["size"]) / (long[0]["steps"] - short[0]["steps"])
    print(f"file growth: {growth:,.0f} bytes per step between steps {short[0]['steps']} and {long[0]['steps']}")
    print(f"median ratio step {args.steps} / step 5 (per pair): open {ratio('open'):.2f}x, write "
          f"{ratio('write'):.2f}x, open+write {ratio('both'):.2f}x, bytes written {ratio('calls'):.2f}x, bytes to "
          f"storage {ratio('bytes'):.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
