"""Speed-up of distributed likelihood evaluation with an artificially slow likelihood.

An expensive model (a finite-element solve) is emulated by a likelihood costing
``--cost`` seconds per sample (default 20 ms): ``--mode sleep`` waits (an external
solver, no CPU used here), ``--mode busy`` spins the CPU. One SEMC step (and one SMC
step) on a small ensemble is timed serially and with a local Dask cluster of
``--workers`` worker processes (``distributed.LocalCluster(processes=True,
threads_per_worker=1)``); the numbers of both runs are checked to be identical.

    .venv/bin/python benchmarks/bench_parallel.py               # full (about 8 s serial per sampler)
    .venv/bin/python benchmarks/bench_parallel.py --quick       # CI-sized (a few seconds)
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from scipy import stats

from seqbayes import SEMC, SMC, Drift, JointPrior, MarkovKernel, Static

COST = {"seconds": 0.02, "mode": "sleep"}


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
    settings = dict(tempering=False, n_moves=args.moves)
    if cls is SEMC:
        settings["max_virtual"] = args.moves
    sampler = cls(prior, kernel, slow_loglike, n_samples=args.n, rng=1, executor=executor, **settings)
    rng = np.random.default_rng(0)
    x = np.linspace(-1, 1, 10)
    data = (x, 0.5 + 1.2 * x + 0.2 * rng.standard_normal(x.size), args.cost, args.mode)
    start = time.perf_counter()
    info = sampler.update(data)
    return time.perf_counter() - start, info, sampler.result.steps[-1]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=32, help="ensemble size N (default 32)")
    parser.add_argument("--cost", type=float, default=0.02, help="seconds per likelihood sample (default 0.02)")
    parser.add_argument("--mode", choices=("sleep", "busy"), default="sleep")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--moves", type=int, default=3, help="MCMC sweeps per step (default 3)")
    parser.add_argument("--quick", action="store_true", help="N = 16, 5 ms per sample, 1 sweep")
    args = parser.parse_args(argv)
    if args.quick:
        args.n, args.cost, args.moves = 16, 0.005, 1
    from distributed import Client, LocalCluster

    cluster = LocalCluster(n_workers=args.workers, processes=True, threads_per_worker=1, dashboard_address=":0")
    client = Client(cluster)
    try:
        client.run(lambda: None)  # workers up before timing
        print(f"N = {args.n}, {args.cost * 1e3:.0f} ms per sample ({args.mode}), {args.moves} sweep(s), "
              f"{args.workers} Dask worker processes")
        print(f"{'sampler':<6} {'evals':>6} {'serial s':>9} {'dask s':>8} {'speed-up':>8} {'ideal':>6}  identical")
        for cls in (SEMC, SMC):
            t_serial, info, rec_serial = run(cls, None, args)
            t_dask, info_dask, rec_dask = run(cls, client, args)
            same = (np.array_equal(rec_serial.posterior, rec_dask.posterior)
                    and info.log_evidence == info_dask.log_evidence)
            ideal = args.workers
            print(f"{cls.__name__:<6} {info.n_loglike_evals:>6} {t_serial:9.2f} {t_dask:8.2f} "
                  f"{t_serial / t_dask:8.2f} {ideal:6.1f}  {same}")
            if not same:
                raise SystemExit("results differ between serial and Dask runs")
    finally:
        client.close()
        cluster.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
