"""A one-minute tour: on-line updating of a drifting offset and a fixed slope,
checked against the exact Kalman-filter answer, and a comparison of two kernels.

    seqbayes example quickstart [--samples 2000] [--seed 0]
"""

from __future__ import annotations

import argparse

import numpy as np

import seqbayes
from seqbayes.models.linear_gaussian import LinearGaussianProblem, kalman_filter


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="seqbayes example quickstart", description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)

    problem = LinearGaussianProblem()
    datasets, truth = problem.simulate(5, rng=2024)
    exact = kalman_filter(problem, datasets)
    sampler = seqbayes.SEMC(problem.prior, problem.kernel, problem.loglike, n_samples=args.samples, rng=args.seed)
    print("step  parameter   truth   posterior mean +- sd     exact (Kalman)     log-evidence (exact)   acceptance")
    for s, dataset in enumerate(datasets):
        info = sampler.update(dataset)  # one dataset arrives: assimilate it on-line
        record = sampler.result.steps[-1]
        sd = np.sqrt(np.diag(exact[s].cov))
        for j, name in enumerate(problem.prior.names):
            # a step whose ESS stayed high moves nothing: no acceptance rate to show
            acceptance = "   -" if np.isnan(info.acceptance_rate) else f"{info.acceptance_rate:.2f}"
            tail = f"   {info.log_evidence:8.3f} ({exact[s].log_evidence:8.3f})    {acceptance}" if j == 0 else ""
            print(f"{s + 1:4d}  {name:9s} {truth[s, j]:7.3f}   {record.mean()[j]:7.3f} +- {record.std()[j]:5.3f}"
                  f"     {exact[s].mean[j]:7.3f} +- {sd[j]:5.3f}{tail}")
    forecast = sampler.predict(2)
    print(f"forecast of a two steps ahead: {forecast[1, :, 0].mean():.3f} +- {forecast[1, :, 0].std():.3f}")

    drift = seqbayes.MarkovKernel([seqbayes.Drift(0.5, noise_std=0.05), seqbayes.Static()])
    other = seqbayes.SEMC(problem.prior, drift, problem.loglike, n_samples=args.samples, rng=args.seed)
    print("\na second model class, a drifting by +0.5 a step, which the data contradict: expect warnings about it",
          flush=True)
    table = seqbayes.compare({"random walk": sampler.result, "drift +0.5": other.run(datasets)})
    print("\nmodel-class selection (cumulative log-evidence, posterior probability):")
    print(table.table())
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
