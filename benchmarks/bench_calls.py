"""Likelihood calls for a given evidence accuracy, against pocomc's defaults (issue 14, item 3).

    python benchmarks/bench_calls.py [--seeds 10] [--problems coulomb gauss10] [--methods ...]
                                     [--jsonl FILE] [--table-only]
    python benchmarks/bench_calls.py --study 3

Two first updates with an exact log-evidence:

* ``coulomb``: the Coulomb-friction experiment's first dataset (4 parameters, the paper's Table 3
  box prior, every parameter static at s = 1), exact log-evidence from the bundled grid reference
  (``seqbayes.models.coulomb.load_exact_reference``);
* ``gauss10``: :class:`seqbayes.models.correlated_gaussian.CorrelatedGaussian` with d = 10.

Methods: ``pocomc`` (pocomc's ``Sampler`` and ``run`` at their defaults, vectorised likelihood,
``random_state`` = the seed; its prior is the product of the marginals, so the correlated Gaussian's
prior correction goes into its likelihood, which leaves posterior and evidence unchanged), and
seqbayes' ``SMC`` / ``SEMC`` at their defaults (N = 1000, the Coulomb study's six independence
sweeps there) and with ``economy=True``. Seed ``i`` is used by every method (paired seeds).

Per problem and method: the mean and sd over seeds of the log-evidence error, the mean
reported standard error, the mean number of likelihood calls (pocomc: ``Sampler.calls``, which
counts its importance draws too) and the wall time. Each run is appended to ``--jsonl`` as it
finishes (so the slow pocomc runs can go in the background); ``--table-only`` prints the table
of a finished file. ``--study S``: the likelihood calls of every update of the full four-step Coulomb
study (kernel T1, the study's settings), defaults against ``economy=True``, mean over S seeds.
"""

from __future__ import annotations

import argparse
import json
import os
import time
import warnings

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from scipy import stats  # noqa: E402

from seqbayes.engine.settings import from_flat  # noqa: E402
import seqbayes  # noqa: E402
from seqbayes.models import coulomb  # noqa: E402
from seqbayes.models.correlated_gaussian import CorrelatedGaussian  # noqa: E402

METHODS = ("pocomc", "SMC", "SEMC", "SMC-economy", "SEMC-economy")


def problem(name):
    """``(prior, loglike(theta) -> (n,), exact log-evidence, per-problem sampler settings)``."""
    if name == "coulomb":
        data = coulomb.load_experiment()[0]
        exact = float(coulomb.load_exact_reference("T1").log_evidence[0])
        return coulomb.prior(), (lambda theta: coulomb.loglike(theta, data)), exact, {"n_independent": 6}
    if name.startswith("gauss"):
        gauss = CorrelatedGaussian(int(name[5:]))
        return gauss.prior(), (lambda theta: gauss.loglike(theta, gauss.data)), gauss.log_evidence, {}
    raise ValueError(f"problem: unknown {name!r}")


def run_pocomc(name, seed):
    import pocomc

    prior, loglike, exact, _ = problem(name)
    if name == "coulomb":
        pc_prior = pocomc.Prior(list(prior.distributions))

        def pc_like(theta):  # seqbayes maps a NaN (outside the model's domain) to -inf; pocomc needs it done
            values = np.asarray(loglike(np.atleast_2d(theta)), dtype=float)
            return np.where(np.isnan(values), -np.inf, values)
    else:  # independent marginals for pocomc; the correlation enters its likelihood (same posterior and evidence)
        sd = np.sqrt(np.diag(prior.cov))
        pc_prior = pocomc.Prior([stats.norm(m, s) for m, s in zip(prior.mean, sd)])

        def pc_like(theta):
            theta = np.atleast_2d(theta)
            return loglike(theta) + prior.logpdf(theta) - stats.norm.logpdf(theta, prior.mean, sd).sum(axis=1)
    sampler = pocomc.Sampler(pc_prior, pc_like, vectorize=True, random_state=seed)
    start = time.perf_counter()
    sampler.run(progress=False)
    logz, logz_err = sampler.evidence()
    return {"error": float(logz - exact), "se": float(logz_err), "calls": int(sampler.calls),
            "time": time.perf_counter() - start}


def run_ours(name, method, seed, n_samples):
    prior, loglike, exact, settings = problem(name)
    cls = seqbayes.SMC if method.startswith("SMC") else seqbayes.SEMC
    settings = dict(settings)
    if method.endswith("economy"):
        settings = {"economy": True}
    dim = prior.sample(1, np.random.default_rng(0)).shape[1]
    kernel = seqbayes.MarkovKernel([seqbayes.Static()] * dim)
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sampler = cls(prior, kernel, lambda theta, _: loglike(theta), n_samples=n_samples,
                      rng=np.random.default_rng([2024, seed]), **from_flat(cls.__name__, **settings))
        info = sampler.update(0)  # the dataset is bound in loglike
    return {"error": info.log_evidence - exact, "se": info.log_evidence_se, "calls": info.n_loglike_evals,
            "time": time.perf_counter() - start}


def study_calls(seeds):
    """Likelihood calls per update over the Coulomb study's four datasets (kernel T1, the study's settings:
    SMC^2 with 30 inner particles after the first step), at the defaults and with ``economy=True``."""
    from seqbayes.studies.coulomb import SAMPLER_SETTINGS

    data = coulomb.load_experiment()
    exact = coulomb.load_exact_reference("T1")
    print("| sampler | setting | calls at s = 1 | s = 2 | s = 3 | s = 4 | total | worst log Z error, s = 1..4 |")
    print("|---|---|---|---|---|---|---|---|")
    for name in ("SMC", "SEMC"):
        for economy in (False, True):
            calls, errors = [], []
            for seed in range(seeds):
                settings = dict(SAMPLER_SETTINGS[name], economy=economy)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    sampler = getattr(seqbayes, name)(coulomb.prior(), coulomb.kernel("T1"), coulomb.loglike,
                                                      n_samples=1000, rng=np.random.default_rng([2024, seed]),
                                                      **from_flat(name, **settings))
                    result = sampler.run(data)
                calls.append([rec.info.n_loglike_evals for rec in result.steps])
                errors.append([rec.info.log_evidence - exact.log_evidence[s] for s, rec in enumerate(result.steps)])
            mean = np.mean(calls, axis=0)
            print(f"| {name} | {'economy' if economy else 'defaults'} | "
                  + " | ".join(f"{c:,.0f}" for c in mean) + f" | {mean.sum():,.0f} | "
                  + " ".join(f"{e:.3f}" for e in np.abs(errors).max(axis=0)) + " |", flush=True)


def table(rows):
    print("| problem | method | seeds | mean error | sd of error | mean reported se | mean calls | mean time (s) |")
    print("|---|---|---|---|---|---|---|---|")
    keys = sorted({(r["problem"], r["method"]) for r in rows}, key=lambda k: (k[0], METHODS.index(k[1])))
    for prob, method in keys:
        sel = [r for r in rows if r["problem"] == prob and r["method"] == method]
        err = np.array([r["error"] for r in sel])
        print(f"| {prob} | {method} | {len(sel)} | {err.mean():+.3f} | {err.std(ddof=1) if len(sel) > 1 else float('nan'):.3f} "
              f"| {np.nanmean([r['se'] for r in sel]):.3f} | {np.mean([r['calls'] for r in sel]):,.0f} "
              f"| {np.mean([r['time'] for r in sel]):.1f} |")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--problems", nargs="+", default=["coulomb", "gauss10"])
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    parser.add_argument("--n", type=int, default=1000, help="seqbayes particles at the defaults")
    parser.add_argument("--jsonl", default=None, help="append each run here (and read it for the table)")
    parser.add_argument("--table-only", action="store_true")
    parser.add_argument("--study", type=int, default=0, metavar="SEEDS",
                        help="instead: calls per update of the full 4-step Coulomb study over SEEDS seeds")
    args = parser.parse_args()
    if args.study:
        study_calls(args.study)
        return
    rows = []
    if args.jsonl and os.path.exists(args.jsonl):
        with open(args.jsonl) as fh:
            rows = [json.loads(line) for line in fh if line.strip()]
    if not args.table_only:
        for seed in range(args.seeds):  # seeds outermost: every problem and method gets its first seeds first
            for prob in args.problems:
                for method in args.methods:
                    if any(r["problem"] == prob and r["method"] == method and r["seed"] == seed for r in rows):
                        continue
                    out = run_pocomc(prob, seed) if method == "pocomc" else run_ours(prob, method, seed, args.n)
                    row = {"problem": prob, "method": method, "seed": seed, **out}
                    rows.append(row)
                    print(json.dumps(row), flush=True)
                    if args.jsonl:
                        with open(args.jsonl, "a") as fh:
                            fh.write(json.dumps(row) + "\n")
    table([r for r in rows if r["problem"] in args.problems and r["method"] in args.methods])


if __name__ == "__main__":
    main()
