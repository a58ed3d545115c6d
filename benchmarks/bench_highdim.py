"""High dimension: the first update of a correlated Gaussian with an exact answer (issue 14, item 2).

    python benchmarks/bench_highdim.py [--dims 2 5 10 20 50] [--seeds 10] [--n 2000] [--economy]
                                       [--moves auto|paper|scaled]

:class:`seqbayes.models.correlated_gaussian.CorrelatedGaussian` (AR(1) prior correlation 0.8, the
posterior 2.5-10 times narrower than the prior in every direction, closed-form posterior and
evidence). For every dimension, sampler (SMC, SEMC) and seed: the log-evidence error, the largest
|posterior mean error| over the d parameters in exact posterior sds, and the likelihood calls of
the update. Prints one row per run (``--rows``) and a summary table per dimension and sampler:
seeds within 0.5 nats and 0.2 sd, mean and sd of the evidence error, worst mean error, mean calls,
calls per dimension. ``--moves paper`` forces the paper's moves (``scaled_moves=False``),
``scaled`` the scaled ones (``scaled_moves=True``); ``auto`` is the default switch (scaled above
d = 10).
"""

from __future__ import annotations

import argparse
import os
import time
import warnings

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

import seqbayes  # noqa: E402
from seqbayes.engine.settings import from_flat  # noqa: E402
from seqbayes.models.correlated_gaussian import CorrelatedGaussian  # noqa: E402


def one_run(cls, gauss, n, seed, settings):
    kernel = seqbayes.MarkovKernel([seqbayes.Static()] * gauss.dim)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sampler = cls(gauss.prior(), kernel, gauss.loglike, n_samples=n, rng=np.random.default_rng([7, seed]),
                      **from_flat(cls.__name__, **settings))
        start = time.perf_counter()
        info = sampler.update(gauss.data)
    z_err, mean_err = gauss.errors(sampler.result.steps[0])
    return z_err, mean_err, info.n_loglike_evals, info.log_evidence_se, time.perf_counter() - start


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dims", type=int, nargs="+", default=[2, 5, 10, 20, 50])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--n", type=int, default=2000)
    parser.add_argument("--economy", action="store_true")
    parser.add_argument("--moves", choices=("auto", "paper", "scaled"), default="auto")
    parser.add_argument("--samplers", nargs="+", default=["SMC", "SEMC"])
    parser.add_argument("--rows", action="store_true", help="print every run")
    args = parser.parse_args()
    settings = {"economy": args.economy}
    if args.moves != "auto":
        settings["scaled_moves"] = args.moves == "scaled"
    print(f"N = {args.n}, {args.seeds} seeds, settings {settings}")
    print("| d | sampler | within 0.5 nats and 0.2 sd | mean log Z error | sd | worst abs log Z error "
          "| worst mean error (sd) | mean reported se | mean calls | calls / d | time (s) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for dim in args.dims:
        gauss = CorrelatedGaussian(dim)
        for name in args.samplers:
            runs = np.array([one_run(getattr(seqbayes, name), gauss, args.n, seed, settings)
                             for seed in range(args.seeds)])
            if args.rows:
                for seed, (z, m, calls, se, t) in enumerate(runs):
                    print(f"<!-- d={dim} {name} seed={seed} log Z error {z:+.3f} max mean error {m:.3f} sd "
                          f"calls {calls:.0f} se {se:.3f} -->")
            z, m, calls = runs[:, 0], runs[:, 1], runs[:, 2]
            ok = int(np.sum((np.abs(z) < 0.5) & (m < 0.2)))
            print(f"| {dim} | {name} | {ok}/{len(runs)} | {z.mean():+.3f} | {z.std(ddof=1):.3f} | {np.abs(z).max():.3f} "
                  f"| {m.max():.3f} | {np.nanmean(runs[:, 3]):.3f} | {calls.mean():,.0f} | {calls.mean() / dim:,.0f} "
                  f"| {runs[:, 4].mean():.1f} |", flush=True)


if __name__ == "__main__":
    main()
