"""Long streams against the exact Kalman-filter answer (issue 10).

Usage (each prints a markdown table for docs/benchmarks.md):

    python benchmarks/bench_longstream.py mixed  [--seeds 10] [--steps 1000] [--n 1000]
    python benchmarks/bench_longstream.py static [--seeds 10] [--steps 1000] [--n 1000]
    python benchmarks/bench_longstream.py predictive [--seeds 2] [--steps 300]
    python benchmarks/bench_longstream.py particles [--seeds 10] [--steps 100]
    python benchmarks/bench_longstream.py nonlinear [--seeds 3] [--steps 300]
    python benchmarks/bench_longstream.py drifting [--seeds 10] [--steps 30] [--n 200]

``mixed``: one AR(1)-decaying, one drifting and two static parameters
(:meth:`~seqbayes.models.linear_gaussian.LinearGaussianStateSpace.mixed`), ``predictive="auto"``
(SMC^2) with the Kalman inner filter (the model declared linear-Gaussian) and, with
``--inner pf``, the bootstrap particle inner filter. At s = 10, 100, 1000: the largest
|mean error| in exact posterior sds, the largest |sd ratio - 1| and |log-evidence error|;
median and worst over seeds, for SEMC and SMC.

``static``: the same design with four static parameters (history prior, the defaults), with and
without :class:`~seqbayes.RunningStatistics`: the same errors, and the mean time and likelihood
evaluations per update over s = 900-1000 against s = 10-20.

``predictive``: the older predictives (Liu-West transition mixture, the paper's KDE) on the
mixed problem, for their long-stream errors.

``particles``: against ``particles``' SMC^2 (``make bench`` installs it) on the mixed problem,
paired per seed, the same N_x and bootstrap inner filters; particles with its defaults (waste-free,
chains of 10) and with 5 PMMH steps per rejuvenation, ours at N and 4 N.

``nonlinear`` (issue 23): ``y_j = a sin(x_s + u_j) + e_j`` with a static amplitude ``a`` and a drifting phase
``x_s`` (random walk, sd 0.05), five observations per dataset, uniform priors; the defaults (N = 1000, particle
inner filter with M = 100) against the exact grid filter at s = 10, 30, 100, 200, 300, and the cost: total
evaluations, the largest update over the median, the PMMH acceptance of every rejuvenation.

``drifting`` (issue 23): the drifting parameters' posterior on the mixed problem, from one inner draw per outer
particle against the Rao-Blackwellised moments over every inner filter (the record's ``mean()``/``std()``), in the
same runs; RMS over seeds and steps of the |mean error| in exact posterior sds and of |sd ratio - 1|.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from seqbayes.engine.settings import from_flat
import seqbayes  # noqa: E402
from seqbayes.models.linear_gaussian import LinearGaussianStateSpace  # noqa: E402
from seqbayes.models.sine_phase import SinePhase  # noqa: E402
from seqbayes.predictive.smc2 import KalmanInnerFilter, ParticleInnerFilter  # noqa: E402

CHECKPOINTS = (10, 100, 1000)


def errors(mean, std, log_evidence, exact_step):
    sd = np.sqrt(np.diag(exact_step.cov))
    return (float(np.max(np.abs(mean - exact_step.mean) / sd)), float(np.max(np.abs(std / sd - 1.0))),
            float(abs(log_evidence - exact_step.log_evidence)))


def run_stream(sampler, data, exact, checkpoints):
    """Errors at the checkpoints, and per-update wall time and likelihood evaluations."""
    out, times, evals = {}, [], []
    for s, y in enumerate(data, start=1):
        info = sampler.update(y)
        times.append(info.wall_time)
        evals.append(info.n_loglike_evals)
        if s in checkpoints:
            record = sampler.result.steps[-1]
            out[s] = errors(record.mean(), record.std(), info.log_evidence, exact[s - 1])
    return out, np.array(times), np.array(evals)


def summary_table(rows, checkpoints, title):
    print(f"\n### {title}\n")
    print("| sampler | s | mean err / sd (median, worst) | sd err (median, worst) | log Z err (median, worst) "
          "| within 0.3 sd, 15 %, 0.5 nats |")
    print("|---|---|---|---|---|---|")
    for label, per_seed in rows.items():
        for s in checkpoints:
            e = np.array([r[s] for r in per_seed if s in r])
            if not e.size:
                continue
            ok = np.sum((e[:, 0] < 0.3) & (e[:, 1] < 0.15) & (e[:, 2] < 0.5))
            print(f"| {label} | {s} | {np.median(e[:, 0]):.3f}, {e[:, 0].max():.3f} | "
                  f"{np.median(e[:, 1]):.3f}, {e[:, 1].max():.3f} | {np.median(e[:, 2]):.3f}, {e[:, 2].max():.3f} | "
                  f"{ok}/{len(e)} |")


def mixed(args):
    problem = LinearGaussianStateSpace.mixed()
    checkpoints = tuple(c for c in CHECKPOINTS if c <= args.steps)
    rows = {}
    for cls in (seqbayes.SEMC, seqbayes.SMC):
        label = f"{cls.__name__}, {args.inner} inner"
        rows[label] = []
        for seed in range(args.seeds):
            data, _ = problem.simulate(args.steps, rng=1000 + seed)
            exact = problem.exact(data)
            inner = KalmanInnerFilter(problem.observe) if args.inner == "kalman" else ParticleInnerFilter(args.m)
            sampler = cls(problem.prior, problem.kernel, problem.loglike, n_samples=args.n, rng=seed, **from_flat(cls.__name__, inner_filter=inner))
            start = time.perf_counter()
            errs, times, evals = run_stream(sampler, data, exact, checkpoints)
            rows[label].append(errs)
            print(f"{label} seed {seed}: {time.perf_counter() - start:.1f} s, "
                  + ", ".join(f"s={s}: {e[0]:.3f} sd {e[1]:.3f} {e[2]:.3f} nats" for s, e in errs.items()), flush=True)
    summary_table(rows, checkpoints, f"Mixed static + drifting, SMC^2, N = {args.n}, {args.seeds} seeds")


def static(args):
    base = LinearGaussianStateSpace.mixed()
    problem = LinearGaussianStateSpace(base.design, ("static",) * 4, np.zeros(4), np.zeros(4), base.prior_mean,
                                       base.prior_std, base.noise_std)
    checkpoints = tuple(c for c in CHECKPOINTS if c <= args.steps)
    early, late = slice(9, 20), slice(max(0, args.steps - 101), args.steps)
    rows, costs = {}, {}
    for cls in (seqbayes.SEMC, seqbayes.SMC):
        for running in (False, True):
            label = f"{cls.__name__}, {'running statistics' if running else 'past datasets'}"
            rows[label], costs[label] = [], []
            for seed in range(args.seeds):
                data, _ = problem.simulate(args.steps, rng=2000 + seed)
                exact = problem.exact(data)
                sampler = cls(problem.prior, problem.kernel, problem.loglike, n_samples=args.n, rng=seed, **from_flat(cls.__name__, history=problem.running_statistics() if running else None))
                errs, times, evals = run_stream(sampler, data, exact, checkpoints)
                rows[label].append(errs)
                ratio_t = times[late].mean() / times[early].mean()
                ratio_e = evals[late].mean() / evals[early].mean()
                costs[label].append((times[early].mean(), times[late].mean(), ratio_t, evals[early].mean(),
                                     evals[late].mean(), ratio_e))
                print(f"{label} seed {seed}: total {times.sum():.1f} s; per update s=10-20 {1e3 * times[early].mean():.1f} ms, "
                      f"s={late.start + 1}-{late.stop} {1e3 * times[late].mean():.1f} ms (x{ratio_t:.2f}); evals "
                      f"{evals[early].mean():.0f} -> {evals[late].mean():.0f} (x{ratio_e:.2f}); "
                      + ", ".join(f"s={s}: {e[0]:.3f} sd {e[1]:.3f} {e[2]:.3f} nats" for s, e in errs.items()),
                      flush=True)
    summary_table(rows, checkpoints, f"All static, history prior (defaults), N = {args.n}, {args.seeds} seeds")
    print("\n| sampler | ms/update s=10-20 | ms/update late | time ratio (median, worst) | evals/update s=10-20 "
          "| evals/update late | evals ratio (median, worst) |")
    print("|---|---|---|---|---|---|---|")
    for label, c in costs.items():
        c = np.array(c)
        print(f"| {label} | {1e3 * np.median(c[:, 0]):.2f} | {1e3 * np.median(c[:, 1]):.2f} | "
              f"{np.median(c[:, 2]):.2f}, {c[:, 2].max():.2f} | {np.median(c[:, 3]):.0f} | {np.median(c[:, 4]):.0f} | "
              f"{np.median(c[:, 5]):.2f}, {c[:, 5].max():.2f} |")


def predictive(args):
    problem = LinearGaussianStateSpace.mixed()
    checkpoints = tuple(c for c in (10, 50, 100, 300, 1000) if c <= args.steps)
    rows = {}
    for method in ("transition", "kde"):
        for cls in (seqbayes.SEMC, seqbayes.SMC):
            label = f"{cls.__name__}, predictive={method!r}"
            rows[label] = []
            for seed in range(args.seeds):
                data, _ = problem.simulate(args.steps, rng=1000 + seed)
                exact = problem.exact(data)
                sampler = cls(problem.prior, problem.kernel, problem.loglike, n_samples=args.n, rng=seed, **from_flat(cls.__name__, predictive=method))
                try:
                    errs, _, _ = run_stream(sampler, data, exact, checkpoints)
                except Exception as error:  # a collapsed run is itself the measurement
                    errs = {}
                    print(f"{label} seed {seed}: stopped: {type(error).__name__}: {error}")
                rows[label].append(errs)
                print(f"{label} seed {seed}: " + ", ".join(f"s={s}: {e[0]:.3f} sd {e[1]:.3f} {e[2]:.3f} nats"
                                                           for s, e in errs.items()), flush=True)
    summary_table(rows, checkpoints, f"Older predictives on the mixed problem, N = {args.n}, {args.seeds} seeds")


def particles_comparison(args):
    import particles
    from particles import smc_samplers as ssp
    from particles import state_space_models as ssm
    from particles import distributions as dists

    problem = LinearGaussianStateSpace.mixed()
    design, noise = problem.design, problem.noise_std
    gain_a, q = problem.gains[0], problem.process_std

    class Mixed(ssm.StateSpaceModel):
        """particles' model: state (a, b), static (c, e) as parameters."""
        default_params = {"c": 0.0, "e": 0.0}

        def PX0(self):
            return dists.IndepProd(dists.Normal(problem.prior_mean[0], problem.prior_std[0]),
                                   dists.Normal(problem.prior_mean[1], problem.prior_std[1]))

        def PX(self, t, xp):
            return dists.IndepProd(dists.Normal(gain_a * xp[:, 0], q[0]), dists.Normal(xp[:, 1], q[1]))

        def PY(self, t, xp, x):
            mean = (x[:, 0:1] * design[:, 0] + x[:, 1:2] * design[:, 1]
                    + self.c * design[:, 2] + self.e * design[:, 3])
            return dists.IndepProd(*[dists.Normal(mean[:, k], noise) for k in range(design.shape[0])])

    prior = dists.StructDist({"c": dists.Normal(problem.prior_mean[2], problem.prior_std[2]),
                              "e": dists.Normal(problem.prior_mean[3], problem.prior_std[3])})
    particles_settings = {"particles SMC^2, 5 PMMH steps (not waste-free)": {"wastefree": False, "len_chain": 5}}
    if args.particles_defaults:  # waste-free chains of 10: ~800 s a seed at N = 500 on this machine
        particles_settings["particles SMC^2, defaults (waste-free)"] = {}
    ours = {f"seqbayes {cls.__name__} (SMC^2), N = {n}": (cls, n) for n in (args.n, 4 * args.n)
            for cls in (seqbayes.SMC, seqbayes.SEMC)}
    rows = {label: [] for label in (*particles_settings, *ours)}
    times = {k: [] for k in rows}

    def record_errors(label, mean, std, log_evidence, final):
        sd = np.sqrt(np.diag(final.cov))[2:]
        rows[label].append((float(np.max(np.abs(mean - final.mean[2:]) / sd)), float(np.max(np.abs(std / sd - 1))),
                            float(abs(log_evidence - final.log_evidence))))

    for seed in range(args.seeds):
        data, _ = problem.simulate(args.steps, rng=3000 + seed)
        final = problem.exact(data)[-1]
        for label, settings in particles_settings.items():
            np.random.seed(seed)  # particles draws from numpy's global generator
            fk = ssp.SMC2(ssm_cls=Mixed, prior=prior, data=[y for y in data], init_Nx=args.m,
                          ar_to_increase_Nx=-1.0, **settings)  # a fixed N_x, as ours
            pf = particles.SMC(fk=fk, N=args.n, collect=[], verbose=False)
            start = time.perf_counter()
            pf.run()
            times[label].append(time.perf_counter() - start)
            theta = np.column_stack([pf.X.theta["c"], pf.X.theta["e"]])
            mean = pf.W @ theta
            record_errors(label, mean, np.sqrt(pf.W @ (theta - mean) ** 2), pf.logLt, final)
        for label, (cls, n) in ours.items():
            sampler = cls(problem.prior, problem.kernel, problem.loglike, n_samples=n, rng=seed, **from_flat(cls.__name__, inner_filter=ParticleInnerFilter(args.m)))
            start = time.perf_counter()
            last = sampler.run(data).steps[-1]
            times[label].append(time.perf_counter() - start)
            record_errors(label, last.mean()[2:], last.std()[2:], last.info.log_evidence, final)
        print(f"seed {seed}: " + "; ".join(f"{k}: {times[k][-1]:.1f} s, {rows[k][-1][0]:.3f} sd, {rows[k][-1][2]:.3f} nats"
                                           for k in rows), flush=True)
    print(f"\n### Against particles' SMC^2: mixed problem, {args.steps} datasets, N_x = {args.m}, "
          f"{args.seeds} paired seeds (static parameters' errors at the last step)\n")
    print("| sampler | wall time, s (median) | time / particles (5 PMMH steps), median of paired ratios | "
          "RMS mean err / sd | RMS sd err | RMS log Z err |")
    print("|---|---|---|---|---|---|")
    base = np.array(times["particles SMC^2, 5 PMMH steps (not waste-free)"])
    for label, e in rows.items():
        e, t = np.array(e), np.array(times[label])
        rms = np.sqrt(np.mean(e**2, axis=0))
        print(f"| {label} | {np.median(t):.1f} | {np.median(t / base):.3f} | {rms[0]:.3f} | {rms[1]:.3f} | {rms[2]:.3f} |")


def nonlinear(args):
    problem = SinePhase()  # y_j = a sin(x_s + u_j) + e_j, a static, x drifting
    checkpoints = tuple(c for c in (10, 30, 100, 200, 300) if c <= args.steps)
    rows, cost_rows = {}, []
    for cls in [c for c in (seqbayes.SMC, seqbayes.SEMC) if c.__name__ in args.samplers]:
        label = cls.__name__
        rows[label] = []
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            data = problem.simulate(args.steps, rng=4000 + seed)
            grid = problem.exact(data)
            log_z = np.cumsum([g.log_evidence_increment for g in grid])
            sampler = cls(problem.prior, problem.kernel, problem.loglike, n_samples=args.n, rng=seed)  # defaults
            errs, evals, rejuvenations, tempered = {}, [], [], []
            start = time.perf_counter()
            for s, y in enumerate(data, start=1):
                info = sampler.update(y)
                evals.append(info.n_loglike_evals)
                if info.n_stages > 1 and s > 1:
                    tempered.append(s)
                if info.resampled and s > 1:
                    rejuvenations.append((s, info.pmmh_acceptance))
                if s in checkpoints:
                    record, g = sampler.result.steps[-1], grid[s - 1]
                    errs[s] = (float(np.max(np.abs(record.mean() - g.mean) / g.std)),
                               float(np.max(np.abs(record.std() / g.std - 1.0))), float(abs(info.log_evidence - log_z[s - 1])))
            evals = np.array(evals)
            # a rejuvenation's acceptance over all its attempts: the tally at the step before the next one starts
            acceptances = [sampler.result.steps[s - 2].info.pmmh_acceptance for s, _ in rejuvenations[1:]]
            acceptances.append(info.pmmh_acceptance)
            rows[label].append(errs)
            cost_rows.append((label, seed, evals.sum(), evals.max() / np.median(evals), np.median(evals),
                              np.nanmin(acceptances) if acceptances else float("nan"), len(rejuvenations),
                              time.perf_counter() - start))
            print(f"{label} seed {seed}: {cost_rows[-1][-1]:.0f} s, {evals.sum():.3g} evals, max/median "
                  f"{cost_rows[-1][3]:.1f} (largest at s = {int(np.argmax(evals[1:])) + 2}), tempered updates "
                  f"{tempered}, acceptance per rejuvenation "
                  + " ".join(f"{s}:{a:.2f}" for (s, _), a in zip(rejuvenations, acceptances)) + "; "
                  + ", ".join(f"s={s}: {e[0]:.3f} sd {e[1]:.3f} {e[2]:.3f} nats" for s, e in errs.items()), flush=True)
    print(f"\n### Nonlinear static + drifting, SMC^2 defaults (M = 100), N = {args.n}, {args.seeds} seeds\n")
    print("| sampler | s | mean err / sd (median, worst) | sd err (median, worst) | log Z err (median, worst) "
          "| within 0.3 sd, 20 %, 0.5 nats |")
    print("|---|---|---|---|---|---|")
    for label, per_seed in rows.items():
        for s in checkpoints:
            e = np.array([r[s] for r in per_seed])
            ok = np.sum((e[:, 0] < 0.3) & (e[:, 1] < 0.2) & (e[:, 2] < 0.5))
            print(f"| {label} | {s} | {np.median(e[:, 0]):.3f}, {e[:, 0].max():.3f} | {np.median(e[:, 1]):.3f}, "
                  f"{e[:, 1].max():.3f} | {np.median(e[:, 2]):.3f}, {e[:, 2].max():.3f} | {ok}/{len(e)} |")
    print("\n| sampler | seed | evaluations | largest update / median | median update | lowest PMMH acceptance "
          "| rejuvenations | wall time, s |")
    print("|---|---|---|---|---|---|---|---|")
    for label, seed, total, ratio, median, lowest, n_rej, wall in cost_rows:
        print(f"| {label} | {seed} | {total:.3g} | {ratio:.1f} | {median:.0f} | {lowest:.2f} | {n_rej} | {wall:.0f} |")


def drifting(args):
    problem = LinearGaussianStateSpace.mixed()
    split = (np.array([2, 3]), np.array([0, 1]))
    out = {}
    for cls in (seqbayes.SMC, seqbayes.SEMC):
        for name in ("pf", "kalman"):
            errs = {"one draw": [], "Rao-Blackwellised": []}
            for seed in range(args.seeds):
                data, _ = problem.simulate(args.steps, rng=5000 + seed)
                exact = problem.exact(data)
                inner = KalmanInnerFilter(problem.observe) if name == "kalman" else ParticleInnerFilter(args.m)
                result = cls(problem.prior, problem.kernel, problem.loglike, n_samples=args.n, rng=seed, **from_flat(cls.__name__, inner_filter=inner)).run(data)
                for record, e in zip(result.steps, exact):
                    sd = np.sqrt(np.diag(e.cov))[split[1]]
                    w = np.exp(record.log_weights - np.logaddexp.reduce(record.log_weights))
                    draws = record.posterior[:, split[1]]
                    mean = w @ draws
                    for label, (m, s) in {"one draw": (mean, np.sqrt(w @ (draws - mean) ** 2)),
                                          "Rao-Blackwellised": (record.mean()[split[1]], record.std()[split[1]])}.items():
                        errs[label].append(np.r_[np.abs(m - e.mean[split[1]]) / sd, np.abs(s / sd - 1)])
            for label, e in errs.items():
                e = np.array(e)
                out[(cls.__name__, name, label)] = np.sqrt(np.mean(e**2, axis=0))
            print(cls.__name__, name, {k[2]: np.round(v, 3) for k, v in out.items() if k[:2] == (cls.__name__, name)},
                  flush=True)
    print(f"\n### Drifting parameters, mixed problem, N = {args.n}, {args.steps} datasets, {args.seeds} seeds "
          f"(RMS over seeds and steps)\n")
    print("| sampler | inner filter | moments | mean err / sd (a, b) | sd err (a, b) |")
    print("|---|---|---|---|---|")
    for (cls, name, label), v in out.items():
        inner = "Kalman" if name == "kalman" else f"particle, M = {args.m}"
        print(f"| {cls} | {inner} | {label} | {v[0]:.3f}, {v[1]:.3f} | {v[2]:.3f}, {v[3]:.3f} |")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("case", choices=("mixed", "static", "predictive", "particles", "nonlinear", "drifting"))
    parser.add_argument("--seeds", type=int, default=None)
    parser.add_argument("--steps", type=int, default=None)
    parser.add_argument("--n", type=int, default=1000)
    parser.add_argument("--m", type=int, default=100, help="inner particles (particle inner filter)")
    parser.add_argument("--inner", choices=("kalman", "pf"), default="kalman")
    parser.add_argument("--first-seed", type=int, default=0, help="nonlinear: the first seed (seeds run from it)")
    parser.add_argument("--samplers", nargs="+", default=["SMC", "SEMC"], help="nonlinear: which samplers to run")
    parser.add_argument("--particles-defaults", action="store_true",
                        help="particles: also run particles' default SMC^2 (waste-free, ~800 s a seed)")
    args = parser.parse_args()
    defaults = {"mixed": (10, 1000), "static": (10, 1000), "predictive": (2, 300), "particles": (5, 30),
                "nonlinear": (3, 300), "drifting": (10, 30)}[args.case]
    args.seeds = defaults[0] if args.seeds is None else args.seeds
    args.steps = defaults[1] if args.steps is None else args.steps
    {"mixed": mixed, "static": static, "predictive": predictive, "particles": particles_comparison,
     "nonlinear": nonlinear, "drifting": drifting}[args.case](args)


if __name__ == "__main__":
    main()
