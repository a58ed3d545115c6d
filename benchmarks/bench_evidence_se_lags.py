"""The lag of the evidence standard error's backward terms, chosen by measurement (issue 14, item 4).

For the drifting problem of ``bench_evidence_se.py``, the fixed-lag estimate of the increment and
cumulative variances with lags 1..L, computed outside the sampler from its states after every step
(dense N x N responsibilities, so N ~ 1000): with ``b^(s)_k`` the mass that step ``s``'s posterior gives
to the particles of step ``s - k`` (backwards through the exact responsibilities of the mixtures) and
``W^(s-k)`` their weights, the increment's variance is the importance term plus
``sum_{k <= lag} |b^(s)_k - b^(s-1)_k|^2`` and the cumulative one the importance terms plus
``sum_{k <= lag} |b^(s)_k - W^(s-k)|^2`` plus, for the older steps, their last such term (frozen).
Lag 1 is the estimator before issue 14's item 4, lag 2 the sampler's (``GaussianMixture.backward_spread``).
Prints the ratio of the rms of each estimate to the sd over seeds.

    .venv/bin/python benchmarks/bench_evidence_se_lags.py --seeds 30 --steps 40 --every 5
"""

from __future__ import annotations

import argparse

import numpy as np
from scipy.special import logsumexp

from bench_evidence_se import problem
from seqbayes import SEMC, SMC


def responsibilities(mixture, points):
    """``(m, N)`` responsibilities of the components of ``mixture`` for ``points``."""
    x = points[:, None, :] - mixture.centres[None]
    log_terms = -0.5 * np.sum((x / mixture.bandwidth) ** 2, axis=2) + mixture.log_weights[None]
    return np.exp(log_terms - logsumexp(log_terms, axis=1, keepdims=True))


def run(cls, seed, n, n_steps, lags):
    """Per step: increment error, cumulative error, increment variance (lags 1..L), cumulative variance (lags 1..L)."""
    model = problem("drifting")
    data, _ = model.simulate(n_steps, rng=2024)
    exact = model.exact(data)
    sampler = cls(model.prior, model.kernel, model.loglike, n_samples=n, rng=seed)
    states, back = [sampler.state], []   # back[t]: step t+1's posterior's responsibilities under its prior
    frozen, importance = np.zeros(lags + 1), 0.0
    rows = []
    for t, dataset in enumerate(data):
        info = sampler.update(dataset)
        states.append(sampler.state)
        new, old = states[-1], states[-2]
        step_importance = max(1.0 / info.evidence_ess - 1.0 / n, 0.0)
        importance += step_importance
        back.append(responsibilities(old.prior, new.posterior) if t >= 1 else None)
        increment, terms = np.full(lags + 1, step_importance), np.zeros(lags + 1)
        if t >= 1:
            after = np.exp(new.posterior_log_weights - logsumexp(new.posterior_log_weights)) @ back[t]
            before = np.exp(old.posterior_log_weights)
            for k in range(1, lags + 1):
                weights = np.exp(states[t + 1 - k].posterior_log_weights)
                increment[k:] += np.sum((after - before) ** 2)
                terms[k] = np.sum((after - weights) ** 2)
                if t - k < 1:
                    break
                after, before = after @ back[t - k], before @ back[t - k]
        cumulative = [importance + frozen[lag] + terms[1:lag + 1].sum() for lag in range(lags + 1)]
        frozen[1:] += terms[1:]
        rows.append([info.log_evidence_increment - exact[t].log_evidence_increment,
                     info.log_evidence - exact[t].log_evidence] + list(increment[1:]) + list(cumulative[1:]))
    return np.array(rows)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=30)
    parser.add_argument("--n", type=int, default=1000)
    parser.add_argument("--steps", type=int, default=40)
    parser.add_argument("--lags", type=int, default=5)
    parser.add_argument("--every", type=int, default=5)
    parser.add_argument("--samplers", nargs="+", default=["SMC"], choices=["SMC", "SEMC"])
    args = parser.parse_args(argv)
    lags = args.lags
    print(f"\nN = {args.n}, seeds 0-{args.seeds - 1}, {args.steps} datasets, drifting; ratio rms(reported) / sd "
          f"over seeds (uncertain by ~{100 / np.sqrt(2 * (args.seeds - 1)):.0f} %)\n")
    lag_names = " | ".join(f"lag {k}" for k in range(1, lags + 1))
    print(f"| sampler | step | increment: {lag_names} | cumulative: {lag_names} |")
    print("|---|---|" + "---|" * (2 * lags))
    for name in args.samplers:
        cls = {"SMC": SMC, "SEMC": SEMC}[name]
        out = np.array([run(cls, seed, args.n, args.steps, lags) for seed in range(args.seeds)])
        sd = out[:, :, :2].std(axis=0, ddof=1)
        for s in range(args.steps):
            if (s + 1) % args.every and s + 1 != args.steps:
                continue
            increment = np.sqrt(out[:, s, 2:2 + lags].mean(axis=0)) / sd[s, 0]
            cumulative = np.sqrt(out[:, s, 2 + lags:].mean(axis=0)) / sd[s, 1]
            print(f"| {name} | {s + 1} | " + " | ".join(f"{r:.2f}" for r in increment) + " | "
                  + " | ".join(f"{r:.2f}" for r in cumulative) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
