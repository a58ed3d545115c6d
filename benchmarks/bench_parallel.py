"""Speed-up of distributed likelihood evaluation with an expensive likelihood (issue 14, item 5).

An expensive model (a finite-element solve) is emulated by a likelihood costing ``--cost``
seconds per sample (default 50 ms): ``--mode sleep`` waits (an external solver: no CPU used
here, so the figure does not depend on the machine's load), ``--mode busy`` spins the CPU
(needs a free core per worker). One SEMC step and one SMC step (N = 32, d = 2, no tempering,
3 sweeps / MH steps, the default importance evidence) run serially, with
:class:`seqbayes.parallel.ProcessWorkers` (2 worker processes) and with a Dask ``LocalCluster`` of 2
worker processes (one thread each, bound to 127.0.0.1, no dashboard), in interleaved rounds
(serial, processes, Dask, serial, ...) in one process. The figure is the median over rounds of
the per-round ratio serial / parallel; the numbers of every run are checked to be identical
to the serial run's.

    .venv/bin/python benchmarks/bench_parallel.py                   # 50 ms sleep, 3 rounds
    .venv/bin/python benchmarks/bench_parallel.py --mode busy
    .venv/bin/python benchmarks/bench_parallel.py --cost 0.0 --n 2000   # a cheap batched likelihood
    .venv/bin/python benchmarks/bench_parallel.py --round-trip         # the cost of one round trip

``--round-trip`` times 20 calls that send two chunks of 8 samples to the workers and do nothing
there: the fixed cost that a chunk's work must dwarf for the pool to pay (with Dask: through the
actors seqbayes uses, and through ``Client.map`` as before).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from scipy import stats

from seqbayes.engine.settings import from_flat  # noqa: E402
from seqbayes import SEMC, SMC, Drift, JointPrior, MarkovKernel, Static
from seqbayes.parallel import ProcessWorkers


def slow_loglike(theta, data):
    """Gaussian regression, made to cost ``cost`` seconds per sample."""
    x, y, cost, mode = data
    if mode == "sleep":
        time.sleep(cost * theta.shape[0])
    else:
        end = time.perf_counter() + cost * theta.shape[0]
        while time.perf_counter() < end:
            pass
    pred = theta[:, [0]] + theta[:, [1]] * x[None, :]
    return -0.5 * np.sum((y[None, :] - pred) ** 2, axis=1) / 0.2 ** 2


def run(cls, executor, args):
    prior = JointPrior({"a": stats.norm(0, 2), "b": stats.uniform(-3, 6)})
    kernel = MarkovKernel([Drift(-0.1, noise_std=0.05), Static()])
    settings = dict(tempering=False, n_moves=args.moves, predictive="transition")
    settings["max_virtual" if cls is SEMC else "max_moves"] = args.moves
    sampler = cls(prior, kernel, slow_loglike, n_samples=args.n, rng=1, executor=executor,
                  **from_flat(cls.__name__, **settings))
    rng = np.random.default_rng(0)
    x = np.linspace(-1, 1, 10)
    data = (x, 0.5 + 1.2 * x + 0.2 * rng.standard_normal(x.size), args.cost, args.mode)
    start = time.perf_counter()
    sampler.update(data)
    return time.perf_counter() - start, sampler.result.steps[-1]


def identical(a, b) -> bool:
    return (np.array_equal(a.posterior, b.posterior) and np.array_equal(a.log_weights, b.log_weights)
            and a.info.log_evidence == b.info.log_evidence and a.info.n_loglike_evals == b.info.n_loglike_evals)


def _nothing(theta, data):
    return np.zeros(theta.shape[0])


def round_trips(pool, client, repeats=20):
    from seqbayes import parallel

    saved, parallel.MIN_CHUNK_SECONDS = parallel.MIN_CHUNK_SECONDS, 0.0  # always to the workers
    theta = np.zeros((16, 2))
    calls = {"ProcessWorkers": lambda: parallel.evaluate_loglike(_nothing, theta, None, pool),
             "Dask client (actors, what seqbayes does)": lambda: parallel.evaluate_loglike(_nothing, theta, None, client),
             "Dask client.map + gather (before)": lambda: client.gather(
                 client.map(_nothing, np.array_split(theta, 2), [None] * 2, pure=False))}
    times = {name: [] for name in calls}
    try:
        for _ in range(repeats):  # interleaved
            for name, call in calls.items():
                start = time.perf_counter()
                call()
                times[name].append(time.perf_counter() - start)
    finally:
        parallel.MIN_CHUNK_SECONDS = saved
    print(f"\nround trip of two chunks of 8 samples, a likelihood that does nothing, {repeats} interleaved "
          f"calls; load average {os.getloadavg()[0]:.1f}\n")
    print("| executor | median ms | 90th percentile ms |\n|---|---|---|")
    for name, t in times.items():
        print(f"| {name} | {1e3 * np.median(t):.1f} | {1e3 * np.quantile(t, 0.9):.1f} |")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=32, help="ensemble size N (default 32)")
    parser.add_argument("--cost", type=float, default=0.05, help="seconds per likelihood sample (default 0.05)")
    parser.add_argument("--mode", choices=("sleep", "busy"), default="sleep")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--moves", type=int, default=3, help="MCMC sweeps per step (default 3)")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--samplers", nargs="+", default=["SEMC", "SMC"])
    parser.add_argument("--round-trip", action="store_true", help="time empty round trips only")
    args = parser.parse_args(argv)
    from distributed import Client, LocalCluster

    cluster = LocalCluster(n_workers=args.workers, processes=True, threads_per_worker=1, host="127.0.0.1",
                           dashboard_address=None)
    client = Client(cluster)
    pool = ProcessWorkers(args.workers)
    try:
        client.run(lambda: None)  # workers up before timing
        pool.map(abs, range(args.workers))  # worker processes up before timing
        if args.round_trip:
            round_trips(pool, client)
            return 0
        print(f"\nN = {args.n}, {args.cost * 1e3:.0f} ms per sample ({args.mode}), {args.moves} sweep(s), "
              f"{args.workers} workers, {args.rounds} interleaved rounds; load average at start "
              f"{os.getloadavg()[0]:.1f}\n")
        print("| sampler | evaluations | serial s (median) | processes s | Dask s | speed-up processes | "
              "speed-up Dask | identical |\n|---|---|---|---|---|---|---|---|")
        for name in args.samplers:
            cls = {"SEMC": SEMC, "SMC": SMC}[name]
            times = {"serial": [], "processes": [], "dask": []}
            same = True
            for _ in range(args.rounds):
                t, reference = run(cls, None, args)
                times["serial"].append(t)
                for label, executor in (("processes", pool), ("dask", client)):
                    t, record = run(cls, executor, args)
                    times[label].append(t)
                    same &= identical(reference, record)
            serial = np.array(times["serial"])
            ratios = {k: np.median(serial / np.array(times[k])) for k in ("processes", "dask")}
            print(f"| {name} | {reference.info.n_loglike_evals} | {np.median(serial):.2f} | "
                  f"{np.median(times['processes']):.2f} | {np.median(times['dask']):.2f} | "
                  f"{ratios['processes']:.2f} | {ratios['dask']:.2f} | {'yes' if same else 'NO'} |")
            if not same:
                raise SystemExit("results differ between serial and parallel runs")
        print(f"\nload average at the end {os.getloadavg()[0]:.1f}")
    finally:
        pool.shutdown()
        client.close()
        cluster.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
