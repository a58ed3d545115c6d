"""Benchmarks and Monte Carlo spreads of the core samplers (issue 2).

    python benchmarks/bench_core.py stretch     # vectorised stretch move vs emcee (N=1000, d=4)
    python benchmarks/bench_core.py particles   # on-line SMC vs particles' IBIS, 20 seeds
    python benchmarks/bench_core.py exact       # spread of errors vs the Kalman filter, 20 seeds
    python benchmarks/bench_core.py static      # the same with static parameters (exact history prior)
    python benchmarks/bench_core.py wide        # prior 10x wider: tempered default vs untempered
    python benchmarks/bench_core.py mixture     # Sec. 2.1 mixture: mode mass and evidence over 20 seeds
    python benchmarks/bench_core.py all

Everything is measured side by side in one process; timings are medians of repeats.
Output is Markdown, pasted into docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from seqbayes.engine.settings import from_flat  # noqa: E402
import seqbayes
from seqbayes.models.linear_gaussian import LinearGaussianProblem, kalman_filter


#: The paper's configuration: single reweighting, Eq. (1) evidence, one move per step, KDE prior.
PAPER_SETTINGS = dict(tempering=False, evidence="path", n_moves=1, moved_fraction=0.0, transform=False,
                      min_valid_fraction=0.0, predictive="kde", resampling="multinomial")


def median_time(fn, repeats=5):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        times.append(time.perf_counter() - start)
    return float(np.median(times))


def bench_stretch(n_walkers=1000, dim=4, n_steps=200, pairs=9):
    """Ours and emcee alternate, ``pairs`` times; the machine is shared, so the ratio of each
    back-to-back pair is the robust figure (its median is quoted), beside the fastest times."""
    import emcee

    cov_inv = np.linalg.inv(0.5 * np.eye(dim) + 0.5)

    def log_prob(x):
        return -0.5 * np.einsum("ij,jk,ik->i", x, cov_inv, x)

    init = np.random.default_rng(0).normal(size=(n_walkers, dim))
    t_lp = median_time(lambda: log_prob(init), repeats=50)

    def run_emcee():
        sampler = emcee.EnsembleSampler(n_walkers, dim, log_prob, vectorize=True)
        sampler.run_mcmc(init, n_steps, progress=False)

    ours, theirs = [], []
    for _ in range(pairs):
        ours.append(median_time(lambda: seqbayes.aies.sample(log_prob, init, n_steps, rng=1), repeats=1) / n_steps)
        theirs.append(median_time(run_emcee, repeats=1) / n_steps)
    ours, theirs = np.array(ours), np.array(theirs)
    print(f"\n### Stretch move, N = {n_walkers} walkers, d = {dim}, {n_steps} ensemble steps, {pairs} alternating pairs\n")
    print("| sampler | ms per ensemble step (N proposals), fastest | median |\n|---|---|---|")
    print(f"| seqbayes.aies | {1e3 * ours.min():.3f} | {1e3 * np.median(ours):.3f} |")
    print(f"| emcee 3 (vectorize=True) | {1e3 * theirs.min():.3f} | {1e3 * np.median(theirs):.3f} |")
    print(f"| log-density alone (N points) | {1e3 * t_lp:.3f} | |")
    print(f"\nspeed-up over emcee: **{np.median(theirs / ours):.1f}x** (median of paired ratios; "
          f"fastest-to-fastest {theirs.min() / ours.min():.1f}x)")


def _particles_ibis(problem, data, n, seed):
    import particles
    from particles import distributions as dists
    from particles import smc_samplers as ssp

    class Model(ssp.StaticModel):
        def logpyt(self, theta, t):
            arr = np.column_stack([theta["a"], theta["b"]])
            return problem.loglike(arr, self.data[t])

    prior = dists.StructDist({"a": dists.Normal(problem.prior_mean[0], problem.prior_std[0]),
                              "b": dists.Normal(problem.prior_mean[1], problem.prior_std[1])})
    np.random.seed(seed)  # particles draws from numpy's global state
    fk = ssp.IBIS(Model(data=list(data), prior=prior), wastefree=False, len_chain=2)  # one MH step
    alg = particles.SMC(fk=fk, N=n, ESSrmin=0.5, verbose=False)
    alg.run()
    return alg.logLt


#: Our SMC with particles' IBIS settings: one MH step, and only after a resampling, which is decided
#: when the next dataset arrives (``move_every_stage=False``); Eq. (1) evidence; no tempering.
IBIS_SETTINGS = dict(n_moves=1, moved_fraction=0.0, move_every_stage=False, evidence="path", tempering=False)


def bench_particles(n=1000, seeds=20):
    """Each seed runs every variant once, back to back, so that machine noise hits them alike;
    the time ratio quoted is the median over seeds of (variant / particles) for the same seed."""
    # particles' IBIS handles static parameters only: the comparison problem has no drift (q = 0).
    problem = LinearGaussianProblem(drift_std=0.0)
    prior = problem.prior  # built once, as a user would
    kernel = seqbayes.MarkovKernel([seqbayes.Static(), seqbayes.Static()])
    data, _ = problem.simulate(5, rng=7)
    exact = kalman_filter(problem, data)[-1].log_evidence

    def ours(cls, **settings):
        return lambda s: cls(prior, kernel, problem.loglike, n, rng=s,
                             **from_flat(cls.__name__, **settings)).run(data).log_evidence[-1]

    variants = {
        "particles IBIS (1 MH step per resampling)": lambda s: _particles_ibis(problem, data, n, s),
        "seqbayes SMC, particles' settings (`IBIS_SETTINGS`)": ours(seqbayes.SMC, **IBIS_SETTINGS),
        "seqbayes SMC, particles' settings + tempering": ours(seqbayes.SMC, **dict(IBIS_SETTINGS, tempering=True)),
        "seqbayes SMC, the paper's configuration (`PAPER_SETTINGS`)": ours(seqbayes.SMC, **PAPER_SETTINGS),
        "seqbayes SMC, defaults": ours(seqbayes.SMC),
        "seqbayes SEMC, defaults": ours(seqbayes.SEMC),
        # last, so that their large arrays do not disturb the timing of the pairs above
        f"particles IBIS, N = {10 * n}": lambda s: _particles_ibis(problem, data, 10 * n, s),
        f"particles IBIS, N = {100 * n}": lambda s: _particles_ibis(problem, data, 100 * n, s),
    }
    times = {name: [] for name in variants}
    errors = {name: [] for name in variants}
    for seed in range(seeds):
        for name, fn in variants.items():
            start = time.perf_counter()
            value = fn(seed)
            times[name].append(time.perf_counter() - start)
            errors[name].append(value - exact)
    reference = np.array(times[next(iter(variants))])
    print(f"\n### On-line SMC vs particles, static linear-Gaussian problem, N = {n}, 5 datasets, {seeds} seeds\n")
    print("| sampler | ms per dataset (median) | time / particles (median of paired ratios) "
          "| RMS log-evidence error (+- its standard error) | mean error |\n|---|---|---|---|---|")
    for name in variants:
        t, e = np.array(times[name]), np.array(errors[name])
        rms = np.sqrt(np.mean(e**2))
        rms_se = np.std(e**2, ddof=1) / np.sqrt(e.size) / (2 * rms)  # delta method
        print(f"| {name} | {1e3 * np.median(t) / len(data):.2f} | {np.median(t / reference):.2f} "
              f"| {rms:.3f} +- {rms_se:.3f} | {e.mean():+.3f} |")


def bench_static(seeds=20):
    """The static linear-Gaussian problem (q = 0), where ``predictive="auto"`` is the exact history prior."""
    problem = LinearGaussianProblem(drift_std=0.0)
    data, _ = problem.simulate(5, rng=2024)
    for label, settings in (("defaults (history prior)", {}), ("particles' settings (`IBIS_SETTINGS`)", IBIS_SETTINGS),
                            ("the kernel-density prior, `predictive=\"transition\"`", {"predictive": "transition"})):
        _print_spread(f"Static problem (q = 0), N = 2000, {seeds} seeds: {label}",
                      _spread(problem, data, seeds, **settings), floor="predictive" in settings)


def _errors(result, exact):
    out = []
    for record, step in zip(result.steps, exact):
        sd = np.sqrt(np.diag(step.cov))
        out.append(np.r_[(record.mean() - step.mean) / sd, record.std() / sd - 1,
                         record.info.log_evidence - step.log_evidence])
    return np.array(out)  # steps x 5: mean err a, b; std err a, b; evidence err


def _spread(problem, data, seeds, **settings):
    exact = kalman_filter(problem, data)
    kernel = problem.kernel if problem.drift_std > 0 else seqbayes.MarkovKernel([seqbayes.Static()] * 2)
    out = {}
    for cls in (seqbayes.SEMC, seqbayes.SMC):
        errs = np.array([_errors(cls(problem.prior, kernel, problem.loglike, 2000, rng=s,
                                     **from_flat(cls.__name__, **settings))
                                 .run(data), exact) for s in range(seeds)])
        out[cls.__name__] = errs
    return out


def _print_spread(title, spreads, floor=True):
    print(f"\n### {title}\n")
    print("| sampler | worst |mean err|/sd: median, 90%, max | worst |std err|: median, 90%, max "
          "| worst |log Z err|: median, 90%, max | runs within (0.1 sd, 10 %, 0.25 nats) |")
    print("|---|---|---|---|---|")
    for name, errs in spreads.items():
        worst = np.stack([np.abs(errs[:, :, :2]).max(axis=(1, 2)), np.abs(errs[:, :, 2:4]).max(axis=(1, 2)),
                          np.abs(errs[:, :, 4]).max(axis=1)], axis=1)
        ok = (worst[:, 0] < 0.1) & (worst[:, 1] < 0.1) & (worst[:, 2] < 0.25)
        cells = [", ".join(f"{v:.3f}" for v in (np.median(c), np.quantile(c, 0.9), c.max())) for c in worst.T]
        print(f"| {name} | {cells[0]} | {cells[1]} | {cells[2]} | {ok.sum()}/{len(ok)} |")
    sd_static = {name: errs[:, -1, 1].std() for name, errs in spreads.items()}
    print("\nstd over seeds of the static parameter's mean error at step 5 (in posterior sd): "
          + ", ".join(f"{k} {v:.3f}" for k, v in sd_static.items())
          + ("; the floor for perfect sampling is sqrt(3/N) = 0.039" if floor else ""))


def bench_exact(seeds=20):
    problem = LinearGaussianProblem()
    data, _ = problem.simulate(5, rng=2024)
    _print_spread(f"Errors against the Kalman filter, N = 2000, 5 datasets, {seeds} seeds (defaults)",
                  _spread(problem, data, seeds))


def bench_wide(seeds=20):
    base = LinearGaussianProblem()
    data, _ = base.simulate(5, rng=2024)
    first = kalman_filter(base, data)[0]
    sd = np.sqrt(np.diag(first.cov))
    for scale in (10, 100):
        problem = LinearGaussianProblem(prior_mean=first.mean + 3 * sd, prior_std=scale * sd)
        for label, settings in (("defaults (tempered)", {}), ("tempering=False, other defaults", {"tempering": False}),
                                ("the paper's configuration", PAPER_SETTINGS)):
            _print_spread(f"Prior {scale}x wider than the first posterior: {label}, {seeds} seeds",
                          _spread(problem, data, seeds, **settings))


def bench_mixture(seeds=20):
    from scipy import integrate, stats

    means = np.array([[0.5, 0.5], [-0.5, -0.5]])

    def loglike(theta, _):
        a = stats.multivariate_normal(means[0], 0.1 * np.eye(2)).logpdf(theta)
        b = stats.multivariate_normal(means[1], 0.1 * np.eye(2)).logpdf(theta)
        return np.logaddexp(a, b) + np.log(0.5)

    exact = np.log(integrate.dblquad(lambda y, x: float(np.exp(loglike(np.array([[x, y]]), None))) / 16,
                                     -2, 2, -2, 2, epsabs=1e-12)[0])
    prior = seqbayes.JointPrior([stats.uniform(-2, 4), stats.uniform(-2, 4)])
    kernel = seqbayes.MarkovKernel([seqbayes.Static(), seqbayes.Static()])
    print(f"\n### Sec. 2.1 two-mode mixture, N = 10,000, {seeds} seeds (exact log Z = {exact:.4f})\n")
    print("| sampler | upper-mode mass: mean, std | log Z error: mean, std |\n|---|---|---|")
    for cls in (seqbayes.SEMC, seqbayes.SMC):
        mass, err = [], []
        for s in range(seeds):
            sampler = cls(prior, kernel, loglike, 10_000, rng=s)
            info = sampler.update("data")
            rec = sampler.result.steps[0]
            mass.append(np.exp(rec.log_weights) @ (rec.posterior.sum(axis=1) > 0))
            err.append(info.log_evidence - exact)
        print(f"| {cls.__name__} | {np.mean(mass):.4f}, {np.std(mass):.4f} | {np.mean(err):+.4f}, {np.std(err):.4f} |")


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", nargs="?", default="all", choices=["stretch", "particles", "exact", "static", "wide", "mixture", "all"])
    parser.add_argument("--seeds", type=int, default=20)
    args = parser.parse_args()
    print(f"<!-- python benchmarks/bench_core.py {args.what}; load average {os.getloadavg()[0]:.1f} -->")
    todo = ["stretch", "particles", "exact", "static", "wide", "mixture"] if args.what == "all" else [args.what]
    for what in todo:
        if what == "stretch":
            bench_stretch()
        elif what == "particles":
            bench_particles(seeds=args.seeds)
        elif what == "exact":
            bench_exact(args.seeds)
        elif what == "static":
            bench_static(args.seeds)
        elif what == "wide":
            bench_wide(args.seeds)
        else:
            bench_mixture(args.seeds)


if __name__ == "__main__":
    main()
