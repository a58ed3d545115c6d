"""Exact delayed acceptance (``surrogate=``, issue 23 item 2): likelihood calls saved and accuracy kept.

    python benchmarks/bench_delayed.py [--seeds 5] [--n 1000]

Two all-static problems with exact answers, SEMC and SMC, ``surrogate`` None / "quadratic" / "auto"
(and, for the linear model, a coarser model as a callable), ``--seeds`` runs each:

- linear-Gaussian: a line ``a + b x`` through three datasets of 20 points, N(0, 2^2) priors; the
  closed-form posterior after the third dataset;
- Coulomb friction, first dataset, every parameter static (``seqbayes.models.coulomb``, Table 3 box
  prior, 4 parameters, a nonlinear model); ``coulomb.reference_posterior`` (quadrature) is exact.

Per setting: the likelihood calls of the whole run (expensive: ``n_loglike_evals``), the screen's calls
(cheap: ``n_screen_evaluations``), the proposals the screen stopped (``n_screened_out``), and the worst
over seeds and parameters of |mean error| in exact sds and |sd ratio - 1|, and |log Z error|.
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402

from seqbayes.engine.settings import from_flat  # noqa: E402
from seqbayes import SEMC, SMC, JointPrior, MarkovKernel, Static  # noqa: E402
from seqbayes.models import coulomb  # noqa: E402

X = np.linspace(-1.0, 1.0, 20)
NOISE = 0.3


def _line(theta, y):
    predicted = theta[:, [0]] + theta[:, [1]] * X
    return -0.5 * np.sum((y - predicted) ** 2, axis=1) / NOISE**2 - X.size * np.log(NOISE * np.sqrt(2 * np.pi))


def _coarse_line(theta, y):
    """The line on every other point, its squares doubled: a cheaper, inexact model."""
    predicted = theta[:, [0]] + theta[:, [1]] * X[::2]
    return -np.sum((y[::2] - predicted) ** 2, axis=1) / NOISE**2 - X.size * np.log(NOISE * np.sqrt(2 * np.pi))


def linear_problem():
    rng = np.random.default_rng(1)
    datasets = [0.5 - 1.0 * X + NOISE * rng.standard_normal(X.size) for _ in range(3)]
    design = np.column_stack([np.ones(X.size), X])
    precision, shift, log_z = np.eye(2) / 4.0, np.zeros(2), 0.0
    cov = np.eye(2) * 4.0
    mean = np.zeros(2)
    for y in datasets:  # the evidence of each dataset under the current Gaussian posterior
        predictive = design @ cov @ design.T + NOISE**2 * np.eye(X.size)
        log_z += stats.multivariate_normal(design @ mean, predictive).logpdf(y)
        precision = precision + design.T @ design / NOISE**2
        shift = shift + design.T @ y / NOISE**2
        cov = np.linalg.inv(precision)
        mean = cov @ shift
    prior = JointPrior({"a": stats.norm(0, 2), "b": stats.norm(0, 2)})
    return prior, MarkovKernel([Static(), Static()]), _line, datasets, mean, np.sqrt(np.diag(cov)), log_z


def coulomb_problem():
    data = coulomb.load_experiment()[:1]
    exact = coulomb.reference_posterior(data[0])
    kernel = MarkovKernel([Static()] * 4)
    return coulomb.prior(), kernel, coulomb.loglike, data, exact.mean, exact.std, exact.log_evidence


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--n", type=int, default=1000)
    args = parser.parse_args()
    print("| problem | sampler | surrogate | expensive calls (mean) | cheap calls | screened out | "
          "worst mean err / sd | worst sd err | worst log Z err |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, problem in (("linear-Gaussian, 3 datasets", linear_problem), ("Coulomb, dataset 1", coulomb_problem)):
        prior, kernel, loglike, datasets, mean, sd, log_z = problem()
        settings = [None, "quadratic", "auto"] + ([_coarse_line] if loglike is _line else [])
        for sampler in (SEMC, SMC):
            for surrogate in settings:
                calls, cheap, out, mean_err, sd_err, z_err = [], [], [], [], [], []
                for seed in range(args.seeds):
                    run = sampler(prior, kernel, loglike, n_samples=args.n, rng=seed,
                                  **from_flat(sampler.__name__, surrogate=surrogate))
                    for data in datasets:
                        run.update(data)
                    infos = [r.info for r in run.result.steps]
                    calls.append(sum(i.n_loglike_evals for i in infos))
                    cheap.append(sum(i.n_screen_evaluations for i in infos))
                    out.append(sum(i.n_screened_out for i in infos))
                    record = run.result.steps[-1]
                    mean_err.append(np.abs((record.mean() - mean) / sd).max())
                    sd_err.append(np.abs(record.std() / sd - 1.0).max())
                    z_err.append(abs(infos[-1].log_evidence - log_z))
                label = "coarser model" if callable(surrogate) else str(surrogate)
                print(f"| {name} | {sampler.__name__} | {label} | {np.mean(calls):,.0f} | {np.mean(cheap):,.0f} | "
                      f"{np.mean(out):,.0f} | {max(mean_err):.3f} | {max(sd_err):.3f} | {max(z_err):.3f} |", flush=True)


if __name__ == "__main__":
    main()
