"""Cost of one update per particle as N grows (issue 14, item 1).

d = 4 parameters, a cheap Gaussian likelihood (5 observations of every parameter per
dataset, noise sd 0.5, prior N(0, 1)), static parameters (default predictive: the
exact history prior) and drifting ones (random walk, noise sd 0.1: the exact
transition mixture of Eq. A3; from N = 2048 on (``--pseudo-marginal-from``), its moves are pseudo-marginal:
:class:`seqbayes.predictive.pseudo_marginal.SubsampledPrior`) and slowly drifting ones (noise sd 0.005: the mixture's
bandwidth is then ~1/20 of the posterior's spread, where its k-d tree truncation works). For each N, one sampler assimilates a first dataset
(untimed: its prior is the initial one) and then ``--steps`` more, each timed. The
sizes are run round-robin, ``--rounds`` times, in one process; the figure is the
median over rounds and steps of the time per update divided by N, and the ratio to
N = 1000's.

``--compare`` also runs, interleaved with it, the evidence proposal of the earlier
code (a kernel density of every distinct particle, ``MAX_PROPOSAL_COMPONENTS``
unlimited), so that the ratio old / new comes from the same load.

    .venv/bin/python benchmarks/bench_scale.py                       # N = 1000 4000 16000
    .venv/bin/python benchmarks/bench_scale.py --kinds static --compare
    .venv/bin/python benchmarks/bench_scale.py --sizes 500 2000 --rounds 1   # quick
    .venv/bin/python benchmarks/bench_scale.py --mixture     # the mixture alone: k-d tree vs all pairs
    .venv/bin/python benchmarks/bench_scale.py --profile drifting 4000   # cProfile of 3 updates
    .venv/bin/python benchmarks/bench_scale.py --kinds drifting --pseudo-marginal-from 2048

``--mixture`` times one evaluation of a 16,000-component mixture (d = 4, centres N(0, I)) at
16,000 points, by :meth:`GaussianMixture.logpdf` (the k-d tree truncation where it pays) and by
the all-pairs sum, interleaved, for bandwidths from 1/100 to 1 of the centres' spread, with the
largest error of each against a double-precision all-pairs sum at 400 of the points.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np
from scipy import stats

from seqbayes import SEMC, SMC, Drift, JointPrior, MarkovKernel, Static
from seqbayes.moves import proposals as evidence

DIM = 4
NOISE = 0.5


def loglike(theta, y):
    """``y (5, d)``: five observations of every parameter, noise sd 0.5."""
    return -0.5 * np.sum((y[None, :, :] - theta[:, None, :]) ** 2, axis=(1, 2)) / NOISE**2


def datasets(n_steps, seed=0):
    rng = np.random.default_rng(seed)
    truth = rng.normal(size=DIM)
    out = []
    for _ in range(n_steps):
        out.append(truth + NOISE * rng.standard_normal((5, DIM)))
        truth = truth + 0.1 * rng.standard_normal(DIM)
    return out


def run(kind, n, steps, sampler, components, **settings):
    """Seconds per update of steps 2 .. steps + 1 (list), with the proposal capped at ``components``
    (``settings``: further sampler settings)."""
    prior = JointPrior({f"theta_{j}": stats.norm(0, 1) for j in range(DIM)})
    drift = {"drifting": 0.1, "slow": 0.005}.get(kind)
    kernel = MarkovKernel([Static()] * DIM if kind == "static" else [Drift(0.0, noise_std=drift)] * DIM)
    cls = SMC if sampler == "smc" else SEMC
    saved = evidence.MAX_PROPOSAL_COMPONENTS
    evidence.MAX_PROPOSAL_COMPONENTS = components
    try:
        s = cls(prior, kernel, loglike, n_samples=n, rng=1, **settings)
        data = datasets(steps + 1)
        s.update(data[0])
        times = []
        for y in data[1:]:
            start = time.perf_counter()
            s.update(y)
            times.append(time.perf_counter() - start)
    finally:
        evidence.MAX_PROPOSAL_COMPONENTS = saved
    return times


def bench_mixture(n=16000, rounds=3):
    from seqbayes.predictive.mixture import GaussianMixture

    rng = np.random.default_rng(0)
    centres, log_w = rng.normal(size=(n, DIM)), rng.normal(size=n)
    points = rng.normal(size=(n, DIM)) * 1.1
    print(f"\nN = {n} centres and points, d = {DIM}, {rounds} interleaved rounds (median); load average "
          f"{os.getloadavg()[0]:.1f}\n")
    print("| bandwidth / spread | tree s | all pairs s | ratio | points the tree served | "
          "error, tree: median / max | error, all pairs (single precision): median / max |\n|---|---|---|---|---|---|---|")
    check = rng.choice(n, 400, replace=False)
    for width in (0.01, 0.02, 0.05, 0.1, 1.0):
        mixture = GaussianMixture(centres, np.full(DIM, width), log_w)
        scaled = (points - mixture._shift) / mixture.bandwidth
        dense_rows = []
        real = mixture._dense_logsum

        def counting(x, real=real):
            dense_rows.append(x.shape[0])
            return real(x)

        tree_t, dense_t = [], []
        for _ in range(rounds):
            object.__setattr__(mixture, "_dense_logsum", counting)
            dense_rows.clear()
            start = time.perf_counter()
            tree = mixture.logpdf(points)
            tree_t.append(time.perf_counter() - start)
            object.__setattr__(mixture, "_dense_logsum", real)
            start = time.perf_counter()
            dense = real(scaled) + mixture._const
            dense_t.append(time.perf_counter() - start)
        z = (points[check, None, :] - centres[None]) / width
        terms = -0.5 * np.einsum("qij,qij->qi", z, z) + mixture.log_weights[None]
        peak = terms.max(axis=1)
        exact = np.log(np.exp(terms - peak[:, None]).sum(axis=1)) + peak + mixture._const
        served = 1.0 - sum(dense_rows) / n
        print(f"| {width} | {np.median(tree_t):.3f} | {np.median(dense_t):.3f} | "
              f"{np.median(dense_t) / np.median(tree_t):.2f} | {100 * served:.0f} % | "
              f"{np.median(np.abs(tree[check] - exact)):.0e} / {np.abs(tree[check] - exact).max():.0e} | "
              f"{np.median(np.abs(dense[check] - exact)):.0e} / {np.abs(dense[check] - exact).max():.0e} |")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1000, 4000, 16000])
    parser.add_argument("--kinds", nargs="+", choices=("static", "drifting", "slow"),
                        default=["static", "drifting", "slow"])
    parser.add_argument("--sampler", choices=("smc", "semc"), default="smc")
    parser.add_argument("--steps", type=int, default=3, help="timed updates per run (after an untimed first)")
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--compare", action="store_true", help="interleave the all-particle proposal (old code)")
    parser.add_argument("--mixture", action="store_true", help="time the mixture evaluation alone")
    parser.add_argument("--pseudo-marginal-from", type=int, default=None,
                        help="the samplers' pseudo_marginal_from (default: the library's, 2048)")
    parser.add_argument("--profile", nargs=2, metavar=("KIND", "N"), help="cProfile of 3 updates (after the first)")
    args = parser.parse_args(argv)
    if args.mixture:
        bench_mixture()
        return 0
    if args.profile:
        import cProfile
        import pstats

        profiler = cProfile.Profile()
        profiler.runcall(run, args.profile[0], int(args.profile[1]), 3, args.sampler, evidence.MAX_PROPOSAL_COMPONENTS)
        pstats.Stats(profiler).sort_stats("cumulative").print_stats(18)
        return 0
    settings = {} if args.pseudo_marginal_from is None else {"pseudo_marginal_from": args.pseudo_marginal_from}
    variants = [("new", evidence.MAX_PROPOSAL_COMPONENTS)] + ([("old", 10**9)] if args.compare else [])
    times = {}
    for _ in range(args.rounds):
        for kind in args.kinds:
            for n in args.sizes:
                for name, components in variants:
                    times.setdefault((kind, n, name), []).extend(run(kind, n, args.steps, args.sampler, components,
                                                                                **settings))
    print(f"\n{args.sampler.upper()}, d = {DIM}, {args.steps} timed updates x {args.rounds} rounds per cell, "
          f"sizes round-robin in one process; {settings or 'default settings'}; load average "
          f"{os.getloadavg()[0]:.1f}\n")
    header = "| parameters | N | s per update | us per particle | ratio to N = {0} |".format(args.sizes[0])
    if args.compare:
        header += " old code, us per particle | old / new |"
    print(header + "\n|" + "---|" * (header.count("|") - 1))
    for kind in args.kinds:
        base = np.median(times[(kind, args.sizes[0], "new")]) / args.sizes[0]
        for n in args.sizes:
            t = np.median(times[(kind, n, "new")])
            row = f"| {kind} | {n} | {t:.3f} | {1e6 * t / n:.1f} | {t / n / base:.2f} |"
            if args.compare:
                old = np.median(times[(kind, n, "old")])
                row += f" {1e6 * old / n:.1f} | {old / t:.2f} |"
            print(row)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
