"""The reported log-evidence standard error against the spread over seeds (issue 14, item 4).

Exact problems (Kalman filter, :class:`~seqbayes.models.linear_gaussian.LinearGaussianStateSpace`):
two parameters, ten observations per dataset, 5 datasets; ``static`` (both static: the history
prior) and ``drifting`` (both random walks, process sd 0.1: the transition mixture). For each
sampler, ``--seeds`` runs (seeds 0..); per step, the sd over seeds of the log-evidence error
(increment and cumulative) against the root mean square of the reported standard errors; their
ratio should lie in [1/1.5, 1.5].

    .venv/bin/python benchmarks/bench_evidence_se.py                 # 20 seeds, N = 1000
    .venv/bin/python benchmarks/bench_evidence_se.py --seeds 5 --n 500
    .venv/bin/python benchmarks/bench_evidence_se.py --seeds 20 --steps 40 --kinds drifting --every 5

With ``--seeds k`` the sd over seeds is itself uncertain by about ``1 / sqrt(2 (k - 1))`` (1 sd):
7 % at 100 seeds, 16 % at 20.
"""

from __future__ import annotations

import argparse
import os

import numpy as np

from seqbayes import SEMC, SMC
from seqbayes.models.linear_gaussian import LinearGaussianStateSpace


def problem(kind):
    rng = np.random.default_rng(11)
    design = np.column_stack([np.ones(10), rng.normal(size=10)])
    if kind == "static":
        return LinearGaussianStateSpace(design, ("static", "static"), (0.0, 0.0), (0.0, 0.0), (0.0, 0.0),
                                        (1.0, 1.0), 0.5)
    return LinearGaussianStateSpace(design, ("drift", "drift"), (0.0, 0.0), (0.1, 0.1), (0.0, 0.0),
                                    (1.0, 1.0), 0.5)


def spread(kind, cls, n, seeds, n_steps=5):
    """Errors ``(seeds, steps, 2)`` (increment, cumulative) and reported se of the same shape."""
    model = problem(kind)
    data, _ = model.simulate(n_steps, rng=2024)
    exact = model.exact(data)
    exact_inc = np.array([e.log_evidence_increment for e in exact])
    exact_cum = np.array([e.log_evidence for e in exact])
    errors, reported = [], []
    for seed in seeds:
        sampler = cls(model.prior, model.kernel, model.loglike, n_samples=n, rng=seed)
        result = sampler.run(data)
        infos = [r.info for r in result.steps]
        inc = np.array([i.log_evidence_increment for i in infos])
        cum = np.array([i.log_evidence for i in infos])
        errors.append(np.column_stack([inc - exact_inc, cum - exact_cum]))
        reported.append(np.array([[i.log_evidence_increment_se, i.log_evidence_se] for i in infos]))
    return np.array(errors), np.array(reported)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--n", type=int, default=1000)
    parser.add_argument("--kinds", nargs="+", default=["static", "drifting"])
    parser.add_argument("--steps", type=int, default=5, help="datasets per run")
    parser.add_argument("--every", type=int, default=1, help="print every k-th step (and the last)")
    args = parser.parse_args(argv)
    print(f"\nN = {args.n}, seeds 0-{args.seeds - 1}, {args.steps} datasets; load average "
          f"{os.getloadavg()[0]:.1f}; the sd over seeds is uncertain by ~{100 / np.sqrt(2 * (args.seeds - 1)):.0f} %\n")
    print("| parameters | sampler | step | increment: sd over seeds | reported se (rms) | ratio "
          "| cumulative: sd over seeds | reported se (rms) | ratio | mean error (cumulative) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for kind in args.kinds:
        for cls in (SMC, SEMC):
            errors, reported = spread(kind, cls, args.n, range(args.seeds), args.steps)
            sd = errors.std(axis=0, ddof=1)
            rms = np.sqrt(np.mean(reported**2, axis=0))
            for s in range(errors.shape[1]):
                if (s + 1) % args.every and s + 1 != errors.shape[1]:
                    continue
                print(f"| {kind} | {cls.__name__} | {s + 1} | {sd[s, 0]:.4f} | {rms[s, 0]:.4f} | "
                      f"{rms[s, 0] / sd[s, 0]:.2f} | {sd[s, 1]:.4f} | {rms[s, 1]:.4f} | {rms[s, 1] / sd[s, 1]:.2f} | "
                      f"{errors[:, s, 1].mean():+.4f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
