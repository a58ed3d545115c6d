"""A fleet on Dask: bit-identity with serial updates, a poisoned store's isolation, throughput with 1, 2 and 4 workers.

    python benchmarks/bench_fleet.py [--stores 200] [--datasets 30] [--batch 24] [--rounds 3]
    python benchmarks/bench_fleet.py kill [--kills 50] [--stores 6] [--datasets 8]

The fleet (tests/_fleet_model.py): ``--stores`` run stores of the straight-line model y = a + b t + noise with a
drifting, SEMC with N = ``--samples``, each fed ``--datasets`` datasets of 8 rows.

1. **Serial reference.** Every store updated alone, ``seqbayes update STORE D1 ... Dn`` (``cli.main`` in two
   worker processes, stores independent).
2. **Throughput**, stores per minute with 1, 2 and 4 workers, measured interleaved in this one run: three local
   clusters stay up, and each round updates fresh copies of ``--batch`` stores on each (the order rotates
   between rounds); the clock runs from the first task sent to the last outcome (the clusters' start-up and
   the workers' imports are not counted). The ratio to one worker is taken per round. Each store is checked
   against its serial reference too. The load average is printed before and after every measurement.
3. **Two fleet updates of every store through the Dask path** (``seqbayes update FLEET --workers 2``, a
   LocalCluster), each with one poisoned store, s57: a bad data file (its 12th dataset holds a cell that is
   not a number), then a likelihood that raises on its 12th dataset. Every store must equal its serial
   reference bit for bit (tests/_fleet_model.store_fingerprint: samples, weights, predictive draws, sampler
   and generator states, every diagnostic but the wall time); the poisoned store fails with its one line
   (the serial update fails the same way and leaves the same store), the other stores complete.

``kill`` SIGKILLs the whole process group of ``seqbayes update FLEET --workers 2`` (the driver and its cluster's
workers) ``--kills`` times after random delays (``uniform(0, 1.1)`` times an uninterrupted update's duration) and
reruns it; after every kill each store must load and hold a prefix of its serial reference bit for bit (and
xarray read it whole once ``seqbayes status`` has opened it); every fleet that completes must equal the
reference bit for bit with no journal or temporary file left (tests/unit/test_fleet_kill.py's machinery).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import shutil
import statistics
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "tests" / "unit")]

from _fleet_model import make_fleet, store_fingerprint  # noqa: E402

from seqbayes import cli  # noqa: E402
from seqbayes.fleet import dask_client, plan_fleet, run_dask  # noqa: E402

POISONED = "s57"


def load() -> str:
    return "/".join(f"{v:.1f}" for v in os.getloadavg())


def _serial_update(args) -> tuple:
    """In a pool process: ``seqbayes update STORE D1 ... Dn -q`` (its output discarded); (name, exit code)."""
    name, store, datasets = args
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return name, cli.main(["update", store, *datasets, "-q"])


def serial_reference(jobs: list, processes: int = 2) -> dict:
    """``{name: exit code}`` of every store updated alone (jobs: (name, store, datasets))."""
    import multiprocessing

    with ProcessPoolExecutor(processes, mp_context=multiprocessing.get_context("spawn")) as pool:
        return dict(pool.map(_serial_update, jobs))


def copy_fleet(root: Path, names, target: Path, initial: Path | None = None) -> Path:
    """Fresh copies of the created stores ``names`` and their data folders in ``target``."""
    target.mkdir(parents=True)
    for name in names:
        shutil.copyfile((initial or root / "initial") / f"{name}.nc", target / f"{name}.nc")
        shutil.copytree(root / "fleet" / name, target / name)
    return target


def throughput_batches(args) -> list:
    """The stores of each throughput round (the same batch for every worker count of a round)."""
    names = [f"s{k}" for k in range(args.stores) if f"s{k}" != POISONED]
    return [[names[(r * args.batch + i) % len(names)] for i in range(args.batch)] for r in range(args.rounds)]


def setup(folder: Path, args) -> tuple[Path, Path, dict]:
    """The fleet, the poisoned variants and the serial references of the stores the run uses (every store, or
    with ``--skip-poisoned`` those of the throughput rounds); returns (root, poisoned root, fingerprints)."""
    start = time.perf_counter()
    root = folder / "fleet-root"
    plan = make_fleet(root, args.stores, args.datasets, module="benchfleet", n_samples=args.samples)
    # the raising variant of the poisoned store: its own configuration and likelihood, the same data stream
    raising_root = folder / "raising-root"
    k = int(POISONED[1:])
    make_fleet(raising_root, k + 1, args.datasets, module="benchfleet", n_samples=args.samples, raising={k: 12})
    bad = folder / "bad" / POISONED
    shutil.copytree(root / "fleet" / POISONED, bad)
    (bad / "d12.csv").write_text("t,y\n0,1.0\n0.5,n/a\n1,1.2\n")
    print(f"setup: {args.stores} stores of {args.datasets} datasets, N = {args.samples}, "
          f"{time.perf_counter() - start:.0f} s (load {load()})", flush=True)

    start = time.perf_counter()
    serial = folder / "serial"
    serial.mkdir()
    jobs = []
    needed = set(plan) if not args.skip_poisoned else {n for batch in throughput_batches(args) for n in batch}
    plan = {name: paths for name, paths in plan.items() if name in needed}
    for name, paths in plan.items():
        shutil.copyfile(root / "initial" / f"{name}.nc", serial / f"{name}.nc")
        jobs.append((name, str(serial / f"{name}.nc"), [str(p) for p in paths]))
    for variant, initial, data in (("bad", root / "initial", bad), ("raising", raising_root / "initial",
                                                                     raising_root / "fleet" / POISONED)):
        (serial / variant).mkdir()
        shutil.copyfile(initial / f"{POISONED}.nc", serial / variant / f"{POISONED}.nc")
        jobs.append((variant, str(serial / variant / f"{POISONED}.nc"),
                     [str(data / f"d{s}.csv") for s in range(1, args.datasets + 1)]))
    codes = serial_reference(jobs)
    assert all(codes[name] == 0 for name in plan), {n: c for n, c in codes.items() if c}
    assert codes["bad"] == 2 and codes["raising"] == 2, codes
    fingerprints = {name: store_fingerprint(serial / f"{name}.nc") for name in plan}
    for variant in ("bad", "raising"):
        fingerprints[variant] = store_fingerprint(serial / variant / f"{POISONED}.nc")
    print(f"serial reference: {len(jobs)} stores updated alone by `seqbayes update` in 2 processes, "
          f"{time.perf_counter() - start:.0f} s (load {load()})", flush=True)
    return root, raising_root, fingerprints


def poisoned_run(folder: Path, root: Path, raising_root: Path, fingerprints: dict, variant: str, args) -> None:
    """One fleet update of every store through ``seqbayes update FLEET --workers 2``, s57 poisoned."""
    names = [f"s{k}" for k in range(args.stores)]
    fleet = copy_fleet(root, [n for n in names if n != POISONED], folder / f"fleet-{variant}")
    if variant == "bad":
        shutil.copyfile(root / "initial" / f"{POISONED}.nc", fleet / f"{POISONED}.nc")
        shutil.copytree(folder / "bad" / POISONED, fleet / POISONED)
    else:
        shutil.copyfile(raising_root / "initial" / f"{POISONED}.nc", fleet / f"{POISONED}.nc")
        shutil.copytree(raising_root / "fleet" / POISONED, fleet / POISONED)
    before = load()
    start = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()) as out, contextlib.redirect_stderr(io.StringIO()):
        code = cli.main(["update", str(fleet), "--workers", "2", "--json", str(folder / f"{variant}.json")])
    wall = time.perf_counter() - start
    outcome = json.loads((folder / f"{variant}.json").read_text())
    assert code == 1 and outcome["failed"] == [POISONED], (code, outcome["failed"])
    stores = {s["name"]: s for s in outcome["stores"]}
    completed = [n for n in names if n != POISONED and stores[n]["status"] == "updated"
                 and stores[n]["n_steps"] == args.datasets]
    identical = [n for n in names if n != POISONED and store_fingerprint(fleet / f"{n}.nc") == fingerprints[n]]
    poisoned_same = store_fingerprint(fleet / f"{POISONED}.nc") == fingerprints[variant]
    assert len(completed) == len(identical) == args.stores - 1 and poisoned_same
    summary = out.getvalue().strip().splitlines()[-1]
    print(f"fleet update, {POISONED} poisoned by {'a bad file' if variant == 'bad' else 'a raising likelihood'}: "
          f"exit code {code}; {POISONED} failed with: {stores[POISONED]['error'][:160]}... "
          f"(kept {stores[POISONED]['n_steps']} steps, as its serial update); {len(completed)} other stores "
          f"completed {args.datasets} steps and all {len(identical) + 1} stores are bit-identical to their serial "
          f"updates; {wall:.0f} s with the cluster's start (load {before} -> {load()})", flush=True)
    print(f"  {summary}", flush=True)
    shutil.rmtree(fleet)


def throughput(folder: Path, root: Path, fingerprints: dict, args) -> None:
    counts = (1, 2, 4)
    rates = {w: [] for w in counts}
    with contextlib.ExitStack() as stack:
        clients = {}
        for w in counts:
            start = time.perf_counter()
            clients[w] = stack.enter_context(dask_client(w))
            print(f"LocalCluster of {w} workers up in {time.perf_counter() - start:.1f} s", flush=True)
        for r in range(args.rounds):
            order = counts[r % 3:] + counts[:r % 3]
            batch = throughput_batches(args)[r]
            for w in order:
                fleet = copy_fleet(root, batch, folder / f"tp-{r}-{w}")
                tasks = plan_fleet(fleet).tasks
                before = load()
                start = time.perf_counter()
                outcomes = run_dask(tasks, clients[w])
                wall = time.perf_counter() - start
                assert all(o.status == "updated" and o.n_steps == args.datasets for o in outcomes), \
                    [o.line() for o in outcomes if not o.ok]
                same = sum(store_fingerprint(fleet / f"{n}.nc") == fingerprints[n] for n in batch)
                assert same == len(batch)
                rate = 60.0 * len(batch) / wall
                rates[w].append(rate)
                print(f"round {r + 1}, {w} worker{'s' * (w > 1)}: {len(batch)} stores in {wall:.1f} s, "
                      f"{rate:.2f} stores/min, all bit-identical to their serial updates (load {before} -> "
                      f"{load()})", flush=True)
                shutil.rmtree(fleet)
    print()
    print("| workers | stores per minute (per round) | median | ratio to 1 worker (per round) | median ratio |")
    print("|---:|:---|---:|:---|---:|")
    for w in counts:
        ratios = [a / b for a, b in zip(rates[w], rates[1])]
        print(f"| {w} | {', '.join(f'{v:.2f}' for v in rates[w])} | {statistics.median(rates[w]):.2f} | "
              f"{', '.join(f'{v:.2f}x' for v in ratios)} | {statistics.median(ratios):.2f}x |")


def kill_mode(args) -> int:
    from test_fleet_kill import build_kill_fleet, kill_and_resume, uninterrupted_duration

    with tempfile.TemporaryDirectory() as tmp:
        start = time.perf_counter()
        root = build_kill_fleet(Path(tmp) / "root", args.stores, args.datasets, "benchkillfleet",
                                n_samples=args.samples)
        duration = uninterrupted_duration(root, Path(tmp) / "timing", str(args.workers))
        print(f"{args.stores} stores of {args.datasets} datasets (the last one's likelihood raises on its third): "
              f"an uninterrupted `seqbayes update FLEET --workers {args.workers}` takes {duration:.1f} s (load "
              f"{load()})", flush=True)

        def report(counts):
            if counts["kills"] % 10 == 0:
                print(f"{counts['kills']} kills, {counts['fleets']} fleets completed (load {load()})", flush=True)
        counts = kill_and_resume(root, Path(tmp), args.kills, np.random.default_rng(args.seed), duration,
                                 str(args.workers), report, keep=Path(args.keep) if args.keep else None)
        total = args.stores * args.datasets - (args.datasets - 2)
        kept = counts["steps_kept"]
        print(f"{counts['kills']} SIGKILLs of the fleet update's process group; after each, every store loaded and "
              f"held only steps bit-identical to its serial update, and xarray read every store whole once `seqbayes "
              f"status` had opened it; {counts['part_way']} kills left the fleet part-way (steps kept per kill: "
              f"median {int(np.median(kept))} of {total}, from {min(kept)} to {max(kept)}); {counts['fleets']} "
              f"fleets completed bit-identical to the serial updates, with no journal or temporary file left; "
              f"{time.perf_counter() - start:.0f} s in all (load {load()})")
    return 0


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mode", nargs="?", choices=("throughput", "kill"), default="throughput")
    parser.add_argument("--stores", type=int, default=None, help="stores (default 200; kill: 6)")
    parser.add_argument("--datasets", type=int, default=None, help="datasets per store (default 30; kill: 8)")
    parser.add_argument("--samples", type=int, default=20, help="N per store (default 20)")
    parser.add_argument("--batch", type=int, default=24, help="stores per throughput measurement (default 24)")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved throughput rounds (default 3)")
    parser.add_argument("--kills", type=int, default=50)
    parser.add_argument("--workers", type=int, default=2, help="kill: workers of the fleet update (default 2)")
    parser.add_argument("--seed", type=int, default=20261207)
    parser.add_argument("--keep", metavar="DIR", help="kill: copy the fleet a kill left here (before and after the "
                                                      "checks) when a check fails")
    parser.add_argument("--skip-poisoned", action="store_true", help="only the throughput rounds")
    args = parser.parse_args(argv)
    if args.mode == "kill":
        args.stores, args.datasets = args.stores or 6, args.datasets or 8
        return kill_mode(args)
    args.stores, args.datasets = args.stores or 200, args.datasets or 30
    assert args.stores > int(POISONED[1:]) and args.datasets >= 12
    print(f"load average {load()} on {os.cpu_count()} cores", flush=True)
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        root, raising_root, fingerprints = setup(folder, args)
        throughput(folder, root, fingerprints, args)
        if not args.skip_poisoned:
            for variant in ("bad", "raising"):
                poisoned_run(folder, root, raising_root, fingerprints, variant, args)
    print(f"{time.perf_counter() - start:.0f} s in all (load {load()})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
