"""The Coulomb-friction study against its exact grid reference at every step (issue 10, bullet 3).

    python benchmarks/bench_coulomb_exact.py [--runs 10] [--n 1000] [--inner 100] [--predictive auto]
                                             [--surrogate quadratic] [--economy] [--pilot 2000]
                                             [--budget 5] [--strict-budget] [--samplers SEMC,SMC] [--seed 2023]
    python benchmarks/bench_coulomb_exact.py --inner-sd [--seed 7]
    python benchmarks/bench_coulomb_exact.py --pmmh-jumps --runs 3 --inner 8 --pilot 500
    python benchmarks/bench_coulomb_exact.py --first-step-bias --runs 40 --inner 8 --pilot 500 --seed 31337 \
        [--independent 6] [--samplers SEMC,SMC] [--virtual-tolerance 0.1]

For T1 and T2, SEMC and SMC, ``--runs`` independent runs over the four datasets; per step the
largest |mean error| over the four parameters in exact posterior sds, the largest |sd ratio - 1|
and the cumulative log-evidence error, against ``seqbayes.models.coulomb.load_exact_reference``
(the bundled grid filter). Prints the worst over runs (and the mean over runs of each error) and
the time of the runs, and the likelihood calls per update (expensive, and the delayed-acceptance screen's cheap
ones with ``--surrogate``). ``--predictive transition`` measures the older Liu-West predictive.

``--inner-sd``: the sd of the inner filters' log-likelihood estimate ``log p^(D^{1:s} | phi)`` at the posterior, per
step and inner filter size M: after each update of one run (30 inner particles, screened PMMH), 200 outer particles
drawn with the weights each re-run their inner filter 20 times at M = 5, 8, 10, 15 and 30 over the datasets so far;
the rms over particles of the 20 estimates' sd (and its 90th percentile). The cost-optimal M puts it near 1
(Pitt et al. 2012; Doucet et al. 2015).

``--pmmh-jumps`` and ``--first-step-bias`` (issue 23, the study's bounded settings): what SEMC's and SMC's PMMH
moves buy per expensive call at each SMC^2 update (:func:`pmmh_jumps`), and the first update's average errors over
many seeds (:func:`first_step_bias`).
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from seqbayes.engine.settings import from_flat
import seqbayes  # noqa: E402
from seqbayes.models import coulomb as model  # noqa: E402
from seqbayes.predictive.smc2 import ParticleInnerFilter  # noqa: E402


def run(args):
    data = model.load_experiment()
    print("| sampler | kernel | step | worst mean err / sd | worst sd err | worst log Z err | "
          "rms mean err / sd | rms sd err | mean over runs of (mean err / sd) per parameter | all runs within 0.2 sd, 15 % |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    total_time, n_fail = 0.0, 0
    for cls in (getattr(seqbayes, name) for name in args.samplers.split(",")):
        for kernel in ("T1", "T2"):
            exact = model.load_exact_reference(kernel)
            errs, times, calls = [], [], []
            for run_index in range(args.runs):
                settings = {"predictive": args.predictive, "n_independent": args.independent,
                            "surrogate": args.surrogate, "economy": args.economy}
                if args.strict_budget:
                    settings["strict_budget"] = True
                if args.budget is not None:
                    settings["move_budget"] = args.budget
                if args.predictive in ("auto", "smc2"):
                    settings["inner_filter"] = ParticleInnerFilter(args.inner, n_pilot=args.pilot)
                start = time.perf_counter()
                sampler = cls(model.prior(), model.kernel(kernel), model.loglike, n_samples=args.n,
                              rng=np.random.default_rng([args.seed, run_index]), **from_flat(cls.__name__, **settings))
                result = sampler.run(data)
                times.append(time.perf_counter() - start)
                calls.append([(rec.info.n_loglike_evals, rec.info.n_screen_evaluations) for rec in result.steps])
                errs.append([((rec.mean() - exact.mean[s]) / exact.std[s], rec.std() / exact.std[s] - 1.0,
                              rec.info.log_evidence - exact.log_evidence[s]) for s, rec in enumerate(result.steps)])
            total_time += sum(times)
            for s in range(4):
                mean_err = np.array([e[s][0] for e in errs])
                sd_err = np.array([e[s][1] for e in errs])
                z_err = np.array([e[s][2] for e in errs])
                ok = np.sum((np.abs(mean_err).max(axis=1) < 0.2) & (np.abs(sd_err).max(axis=1) < 0.15))
                n_fail += len(errs) - ok
                print(f"| {cls.__name__} | {kernel} | {s + 1} | {np.abs(mean_err).max():.3f} | {np.abs(sd_err).max():.3f} | "
                      f"{np.abs(z_err).max():.3f} | {np.sqrt(np.mean(mean_err**2)):.3f} | {np.sqrt(np.mean(sd_err**2)):.3f} | "
                      f"{np.array2string(mean_err.mean(axis=0), precision=3)} | "
                      f"{ok}/{len(errs)} |", flush=True)
            print(f"<!-- {cls.__name__} {kernel}: run time {np.median(times):.2f} s median, {max(times):.2f} s max -->",
                  flush=True)
            calls = np.array(calls)   # (runs, steps, 2): expensive and cheap calls per update
            print(f"<!-- {cls.__name__} {kernel}: expensive calls per update (mean over runs) "
                  f"{np.round(calls[:, :, 0].mean(axis=0)).astype(int).tolist()}, largest {calls[:, :, 0].max(axis=0).tolist()}; "
                  f"screen calls {np.round(calls[:, :, 1].mean(axis=0)).astype(int).tolist()} -->", flush=True)
    print(f"\nsum of run times {total_time:.1f} s (one core); runs x steps outside the tolerances: {n_fail}")


def inner_sd(args):
    from seqbayes.core.likelihood import ValidatedLikelihood
    from seqbayes.predictive.pmmh import run_inner
    from seqbayes.predictive.smc2 import nested_split

    data = model.load_experiment()
    sizes = (5, 8, 10, 15, 30)
    print("| sampler | kernel | step | " + " | ".join(f"M = {m}" for m in sizes) + " |")
    print("|---|---|---|" + "---|" * len(sizes))
    for name, kernel in (("SMC", "T1"), ("SEMC", "T2")):
        sampler = getattr(seqbayes, name)(model.prior(), model.kernel(kernel), model.loglike, n_samples=args.n, rng=np.random.default_rng(args.seed), **from_flat(name, n_independent=6, inner_filter=ParticleInnerFilter(30), surrogate="quadratic"))
        split, likelihood = nested_split(sampler.problem.kernel), ValidatedLikelihood(model.loglike)
        rng = np.random.default_rng([args.seed, 1])
        for step, dataset in enumerate(data, start=1):
            sampler.update(dataset)
            if step == 1:
                continue
            state = sampler.state
            w = np.exp(state.log_weights - state.log_weights.max())
            phi = state.outer[rng.choice(w.size, 200, p=w / w.sum())]
            cells = []
            for m in sizes:
                estimates = np.array([sum(run_inner(sampler.problem, ParticleInnerFilter(m), split, phi, state.datasets,
                                                    state.guides, likelihood, rng)[:2]) for _ in range(20)])
                sd = estimates.std(axis=0, ddof=1)
                cells.append(f"{np.sqrt(np.mean(sd**2)):.2f} ({np.quantile(sd, 0.9):.2f})")
            print(f"| {name} | {kernel} | {step} | " + " | ".join(cells) + " |", flush=True)

def _bounded(inner: int, pilot: int, independent: int) -> dict:
    """The study's bounded-cost settings (``coulomb.BOUNDED_COST``) with the given inner filter and sweeps."""
    from seqbayes.studies.coulomb import BOUNDED_COST

    return {**BOUNDED_COST, "n_independent": independent, "inner_filter": ParticleInnerFilter(inner, n_pilot=pilot)}


def pmmh_jumps(args):
    """Per SMC^2 update, what the PMMH moves buy per expensive call under the study's bounded settings: acceptance per
    proposal, the fraction the screen stopped, acceptances per re-run, and the squared jump of the moved particles
    whitened by the weighted covariance before the moves (in the moves' coordinates), per accepted move and per 1,000
    expensive calls. SEMC with the stretch move (its PMMH without ``strict_budget``, the budget still strict), with
    differential evolution (the library's choice under ``strict_budget``) and with SMC's Gaussian random walk; SMC."""
    import dataclasses

    from seqbayes.predictive import smc2
    from seqbayes.predictive.pmmh import rerun_cost
    from seqbayes.priors import BoxTransform

    data = model.load_experiment()
    original = smc2.rejuvenate
    print("| PMMH move | kernel | step | acceptance per proposal | screened out | accepted per re-run | "
          "whitened sq. jump per accepted move | per 1,000 expensive calls |")
    print("|---|---|---|---|---|---|---|---|")
    for label, name, override in (("stretch (SEMC)", "SEMC", {"strict_budget": False}),
                                  ("differential evolution (SEMC)", "SEMC", {}),
                                  ("Gaussian random walk (SEMC)", "SEMC", {"move": "gaussian"}),
                                  ("Gaussian random walk (SMC)", "SMC", {})):
        for kernel in ("T1", "T2"):
            tally = {}

            def measured(problem, config, inner, split, datasets, *rest, **kw):
                static, log_weights = rest[1], rest[2]
                columns = inner.outer_columns(split, problem.kernel.dim)
                transform = BoxTransform(problem.support[columns])
                before = transform.forward(static)
                w = np.exp(log_weights - log_weights.max())
                w /= w.sum()
                centred = before - w @ before
                factor = np.linalg.cholesky(centred.T @ (centred * w[:, None]))
                out = original(problem, dataclasses.replace(config, **override), inner, split, datasets, *rest, **kw)
                jumps = np.linalg.solve(factor, (transform.forward(out[0]) - before).T)
                stats, row = out[3], tally.setdefault(len(datasets), np.zeros(6))
                row += (stats.n_proposed, stats.n_screened_out, stats.n_evaluations, stats.n_accepted,
                        stats.n_evaluations * rerun_cost(inner, datasets), float(np.sum(jumps**2)))
                return out

            smc2.rejuvenate = measured
            try:
                for run_index in range(args.runs):
                    getattr(seqbayes, name)(model.prior(), model.kernel(kernel), model.loglike, n_samples=args.n,
                                            rng=np.random.default_rng([args.seed, run_index]),
                                            **_bounded(args.inner, args.pilot, args.independent)).run(data)
            finally:
                smc2.rejuvenate = original
            for step, (proposed, out, reruns, accepted, calls, jump) in sorted(tally.items()):
                print(f"| {label} | {kernel} | {step} | {accepted / proposed:.2f} | {out / proposed:.2f} | "
                      f"{accepted / reruns:.2f} | {jump / accepted:.2f} | {1000 * jump / calls:.0f} |", flush=True)


def first_step_bias(args):
    """The first (all-static) update's errors against the exact grid over ``--runs`` seeds (``[args.seed, i]``), the
    study's bounded settings with ``--independent`` sweeps (and SEMC's ``--virtual-tolerance``): per parameter the mean over seeds of the mean error in
    exact sds and of the sd ratio - 1, with the standard error of that mean."""
    data = model.load_experiment()
    exact = model.load_exact_reference("T2")
    for name in args.samplers.split(","):
        errors, settings = [], _bounded(args.inner, args.pilot, args.independent)
        if args.virtual_tolerance is not None:
            settings["virtual_tolerance"] = args.virtual_tolerance
        for run_index in range(args.runs):
            sampler = getattr(seqbayes, name)(model.prior(), model.kernel("T2"), model.loglike, n_samples=args.n,
                                              rng=np.random.default_rng([args.seed, run_index]),
                                              **from_flat(name, **settings))
            sampler.update(data[0])
            record = sampler.result.steps[0]
            errors.append(np.concatenate([(record.mean() - exact.mean[0]) / exact.std[0],
                                          record.std() / exact.std[0] - 1.0]))
        errors = np.array(errors)
        mean, se = errors.mean(axis=0), errors.std(axis=0, ddof=1) / np.sqrt(len(errors))
        cells = [f"{m:+.3f} +- {e:.3f}" for m, e in zip(mean, se)]
        p = len(model.PARAMETER_NAMES)
        print(f"| {name} | {args.independent} | {len(errors)} | " + " | ".join(cells[:p]) + " | "
              + " | ".join(cells[p:]) + " |", flush=True)


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--runs", type=int, default=10)
    parser.add_argument("--n", type=int, default=1000)
    parser.add_argument("--inner", type=int, default=100, help="inner particles per outer particle (SMC^2)")
    parser.add_argument("--predictive", default="auto")
    parser.add_argument("--independent", type=int, default=6, help="independence sweeps (the study's 6)")
    parser.add_argument("--seed", type=int, default=2023)
    parser.add_argument("--surrogate", default=None, help="delayed acceptance: quadratic or auto (default: none)")
    parser.add_argument("--economy", action="store_true", help="economy=True")
    parser.add_argument("--pilot", type=int, default=2000, help="the inner filters' guide pilot draws (n_pilot)")
    parser.add_argument("--samplers", default="SEMC,SMC", help="comma-separated: SEMC, SMC")
    parser.add_argument("--strict-budget", action="store_true", help="strict_budget=True")
    parser.add_argument("--budget", type=float, default=None, help="move_budget (default: the library's)")
    parser.add_argument("--inner-sd", action="store_true",
                        help="print the inner log-likelihood estimate's sd per step and inner filter size instead")
    parser.add_argument("--pmmh-jumps", action="store_true",
                        help="print the PMMH moves' acceptance and jumps per expensive call per update instead")
    parser.add_argument("--first-step-bias", action="store_true",
                        help="print the first update's mean errors over --runs seeds instead")
    parser.add_argument("--virtual-tolerance", type=float, default=None,
                        help="SEMC's virtual_tolerance (--first-step-bias only; default: the library's)")
    args = parser.parse_args()
    if args.inner_sd:
        inner_sd(args)
    elif args.pmmh_jumps:
        pmmh_jumps(args)
    elif args.first_step_bias:
        first_step_bias(args)
    else:
        run(args)


if __name__ == "__main__":
    main()
