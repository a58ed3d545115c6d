"""Exactness of the pseudo-marginal moves (issue 14, item 1): drifting runs against the Kalman filter.

A linear-Gaussian problem with every parameter a random walk (``LinearGaussianStateSpace``,
d = 2 by default, 10 observations per dataset, noise sd 0.5, process noise sd 0.1, prior N(0, 1)),
``--steps`` datasets, ``--seeds`` seeds. Each seed runs the sampler with the pseudo-marginal moves
(``pseudo_marginal_from = --from``) and, unless ``--no-exact``, with exact evaluation of the mixture
(``pseudo_marginal_from = 0``) on the same data and seed. Per variant: the RMS over seeds and steps of
the posterior mean error (in exact posterior sds, every parameter), of the sd ratio error
``sd / exact sd - 1`` and of the log-evidence increment error, the cumulative log-evidence error at
the last step against its reported standard error, the mean increment error over the steps with
a mixture prior (a bias check), and the share of steps whose moves were
pseudo-marginal.

    .venv/bin/python benchmarks/bench_pseudo_marginal.py --n 2000 --from 1000 --seeds 10
    .venv/bin/python benchmarks/bench_pseudo_marginal.py --n 16000 --seeds 4 --no-exact
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from seqbayes.engine.settings import from_flat
from seqbayes import SEMC, SMC
from seqbayes.predictive import pseudo_marginal as density
from seqbayes.models.linear_gaussian import LinearGaussianStateSpace


def problem(dim=2, m=10, seed=3):
    rng = np.random.default_rng(seed)
    return LinearGaussianStateSpace(rng.normal(size=(m, dim)), ("drift",) * dim, rates=np.zeros(dim),
                                    process_std=np.full(dim, 0.1), prior_mean=np.zeros(dim),
                                    prior_std=np.ones(dim), noise_std=0.5)


def run_errors(model, data, exact, sampler, n, seed, pseudo_marginal_from):
    """Per step: mean errors (d,) in sds, sd ratio errors (d,), increment error, cumulative error and its
    reported se, and whether the step's moves were pseudo-marginal."""
    used = []
    original = density.SubsampledPrior.start

    def start(self, *args, **kwargs):
        out = original(self, *args, **kwargs)
        used.append(self.n_terms is not None)
        return out

    density.SubsampledPrior.start = start
    try:
        cls = SMC if sampler == "smc" else SEMC
        s = cls(model.prior, model.kernel, model.loglike, n_samples=n, rng=seed, **from_flat(cls.__name__, pseudo_marginal_from=pseudo_marginal_from))
        rows = []
        for k, (y, e) in enumerate(zip(data, exact)):
            n_used = len(used)
            info = s.update(y)
            record = s.result.steps[-1]
            sd = np.sqrt(np.diag(e.cov))
            rows.append((*((record.mean() - e.mean) / sd), *(record.std() / sd - 1),
                         info.log_evidence_increment - e.log_evidence_increment,
                         info.log_evidence - e.log_evidence, info.log_evidence_se,
                         float(len(used) > n_used and used[-1])))
    finally:
        density.SubsampledPrior.start = original
    return np.array(rows)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--n", type=int, default=2000)
    parser.add_argument("--from", dest="start", type=int, default=None,
                        help="pseudo_marginal_from of the pseudo-marginal variant (default: the library's)")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--steps", type=int, default=20)
    parser.add_argument("--dim", type=int, default=2)
    parser.add_argument("--sampler", choices=("smc", "semc"), default="smc")
    parser.add_argument("--no-exact", action="store_true", help="skip the exact-evaluation runs")
    args = parser.parse_args(argv)
    from seqbayes.predictive.transition import Transition

    start = Transition().pseudo_marginal_from if args.start is None else args.start
    model = problem(args.dim)
    variants = [("pseudo-marginal", start)] + ([] if args.no_exact else [("exact", 0)])
    results = {name: [] for name, _ in variants}
    began = time.perf_counter()
    for seed in range(args.seeds):
        data, _ = model.simulate(args.steps, rng=1000 + seed)
        exact = model.exact(data)
        for name, value in variants:
            results[name].append(run_errors(model, data, exact, args.sampler, args.n, seed, value))
    d = args.dim
    print(f"\n{args.sampler.upper()}, N = {args.n}, d = {d} random walks, {args.steps} steps x {args.seeds} seeds; "
          f"pseudo_marginal_from = {start}; {time.perf_counter() - began:.0f} s, load average "
          f"{os.getloadavg()[0]:.1f}\n")
    print("| moves | steps pseudo-marginal | mean error, sds (RMS) | sd ratio error (RMS) | increment error, nats "
          "(RMS) | increment error, nats: mean +- se (steps >= 2) | log-evidence error at the last step: RMS over "
          "seeds | its reported se (RMS) | z = error / se: mean, RMS |\n|---|---|---|---|---|---|---|---|---|")
    for name, _ in variants:
        r = np.stack(results[name])                                  # (seeds, steps, columns)
        last, se = r[:, -1, 2 * d + 1], r[:, -1, 2 * d + 2]
        z = last / se
        later = r[:, 1:, 2 * d]                                      # increments under the mixture prior
        # se of the mean from the seeds' means (steps of one seed are correlated)
        bias, bias_se = later.mean(), later.mean(axis=1).std(ddof=1) / np.sqrt(later.shape[0])
        print(f"| {name} | {100 * r[..., -1].mean():.0f} % | {np.sqrt(np.mean(r[..., :d] ** 2)):.4f} | "
              f"{np.sqrt(np.mean(r[..., d:2 * d] ** 2)):.4f} | {np.sqrt(np.mean(r[..., 2 * d] ** 2)):.4f} | "
              f"{bias:+.4f} +- {bias_se:.4f} | "
              f"{np.sqrt(np.mean(last ** 2)):.4f} | {np.sqrt(np.mean(se ** 2)):.4f} | "
              f"{z.mean():+.2f}, {np.sqrt(np.mean(z ** 2)):.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
