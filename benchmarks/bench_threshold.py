"""Time to a threshold against the exact answer on a linear-Gaussian drift problem (issue 11).

The problem (``seqbayes.models.linear_gaussian``): an offset ``a`` drifting as a Gaussian random
walk (sd 0.3 per step) and a static slope ``b``, 15 datasets of 10 points with noise sd 0.5. Its
filtering posterior is the Kalman filter's, so the first-passage probabilities of ``a`` below
``threshold = E[a_15] - 1`` over the next 1..20 steps are known exactly
(:func:`seqbayes.prognostics.gaussian_first_passage`, grid error < 1e-5).

Three estimates are compared with them, at every horizon 1..20:

1. a direct simulation from the exact posterior (200,000 walks): the acceptance check of issue 11;
2. :func:`seqbayes.time_to_threshold` fed with 20,000 draws of the exact posterior;
3. the same fed with the posterior of SMC and of SEMC (N = 1000, the library's defaults), over
   ``--seeds`` seeds: their error includes the samplers' Monte Carlo error, which the reported
   standard error (that of independent draws) does not, so their spread over seeds is printed
   beside the mean reported standard error.

Usage: ``OPENBLAS_NUM_THREADS=1 python benchmarks/bench_threshold.py [--seeds 5]``. Not a timing
benchmark: it prints errors in units of Monte Carlo standard errors.
"""

from __future__ import annotations

import argparse
import warnings

import numpy as np

from seqbayes import SEMC, SMC, time_to_threshold
from seqbayes.models.linear_gaussian import LinearGaussianProblem, kalman_filter
from seqbayes.prognostics import gaussian_first_passage

HORIZON = 20


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--samples", type=int, default=1000)
    args = parser.parse_args(argv)

    problem = LinearGaussianProblem(drift_std=0.3, noise_std=0.5)
    data, _ = problem.simulate(15, rng=np.random.default_rng(11))
    last = kalman_filter(problem, data)[-1]
    mean, sd = last.mean[0], float(np.sqrt(last.cov[0, 0]))
    threshold = mean - 1.0
    exact = gaussian_first_passage(mean, sd, 0.0, problem.drift_std, threshold, HORIZON)
    print(f"exact posterior of a_15: N({mean:.4f}, {sd:.4f}^2); threshold {threshold:.4f}; "
          f"P(not crossed by 20) = {1 - exact.sum():.4f}")

    # 1. direct simulation from the exact posterior
    rng = np.random.default_rng(2024)
    n_direct = 200_000
    a = rng.normal(mean, sd, n_direct)[:, None] + problem.drift_std * np.cumsum(
        rng.standard_normal((n_direct, HORIZON)), axis=1)
    crossed = a < threshold
    first = np.where(crossed.any(axis=1), crossed.argmax(axis=1) + 1, 0)
    direct = np.bincount(first, minlength=HORIZON + 1)[1:] / n_direct
    z_direct = (direct - exact) / np.sqrt(exact * (1 - exact) / n_direct)
    print(f"direct simulation, {n_direct} walks from the exact posterior: max |z| over h = 1..20 "
          f"{np.abs(z_direct).max():.2f}, sum z^2 {np.sum(z_direct ** 2):.1f} (chi2(20): 99.9 % below 45.3)")

    # 2. time_to_threshold on exact posterior draws
    draws = rng.multivariate_normal(last.mean, last.cov, size=20_000)
    out = time_to_threshold(draws, problem.kernel, 0, threshold, HORIZON, rng=rng)
    z = (out.probability - exact) / out.standard_error
    print(f"time_to_threshold on 20000 exact posterior draws: max |z| {np.abs(z).max():.2f}, "
          f"sum z^2 {np.sum(z ** 2):.1f}")

    # 3. the samplers' posteriors
    print(f"\nsampler posteriors, N = {args.samples}, {args.seeds} seeds: per horizon, the error of the "
          f"probability of a first crossing there")
    print(f"{'sampler':<6} {'max |err|':>9} {'rms err':>8} {'mean reported se':>17} {'sd over seeds':>14} "
          f"{'max |err| / sd':>15}")
    for cls in (SMC, SEMC):
        estimates, errors = [], []
        for seed in range(args.seeds):
            sampler = cls(problem.prior, problem.kernel, problem.loglike, n_samples=args.samples, rng=seed)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                result = sampler.run(data)
            samples = result.steps[-1].equal_weight_samples(np.random.default_rng(seed))
            passage = time_to_threshold(samples, problem.kernel, 0, threshold, HORIZON, rng=seed)
            estimates.append(passage.probability)
            errors.append(passage.standard_error)
        estimates, errors = np.array(estimates), np.array(errors)
        err = estimates - exact
        spread = estimates.std(axis=0, ddof=1)
        print(f"{cls.__name__:<6} {np.abs(err).max():9.4f} {np.sqrt(np.mean(err ** 2)):8.4f} "
              f"{errors.mean():17.4f} {spread.mean():14.4f} {np.max(np.abs(err.mean(axis=0)) / (spread / np.sqrt(args.seeds))):15.2f}")
    print("(last column: the seeds' mean error at each horizon in standard errors of that mean, the largest of 20)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
