"""Sec. 2.1 and Fig. 1 of Lye et al. (2023): why reweighting and resampling
let the move step start inside the posterior.

Prior ``U(-2, 2)^2``; likelihood an equal mixture of two Gaussians centred at
``(0.5, 0.5)`` and ``(-0.5, -0.5)`` with covariance ``0.1 I``; ``N = 10,000``
prior samples. The figure shows (a) the prior samples coloured by their
normalised weight (Fig. 1 of the paper), (b) the samples after multinomial
resampling (the paper's scheme), (c) the posterior after one full step of the
SMC sampler (reweight, resample, one Metropolis-Hastings move; the paper's
single reweighting, no tempering) and (d) the same with the SEMC sampler.

Run with ``seqbayes example resampling [--samples 10000] [--seed 0] [--out DIR]``.
It prints the mass found in each mode (exact: 1/2 each) and the log-evidence
against its exact value (Gaussian masses of the box, below).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import stats
from scipy.special import logsumexp

from ..priors import JointPrior
from ..weights import multinomial
from ..rng import as_generator
from ..weights import log_mean_exp, normalise

__all__ = ["MODES", "COVARIANCE", "BOX", "prior", "log_likelihood", "exact_log_evidence",
           "Illustration", "run", "plot", "main"]

MODES = np.array([[0.5, 0.5], [-0.5, -0.5]])   #: centres of the two Gaussians
COVARIANCE = 0.1                               #: each is N(mode, 0.1 I)
BOX = (-2.0, 2.0)                              #: prior U(-2, 2)^2


def prior() -> JointPrior:
    lo, hi = BOX
    return JointPrior({"theta_1": stats.uniform(lo, hi - lo), "theta_2": stats.uniform(lo, hi - lo)})


def log_likelihood(theta, dataset=None) -> np.ndarray:
    """``log(0.5 N(theta; m1, 0.1 I) + 0.5 N(theta; m2, 0.1 I))``, ``(N, 2) -> (N,)``; ``dataset`` is unused."""
    theta = np.asarray(theta, dtype=float)
    sq = np.sum((theta[:, None, :] - MODES[None, :, :]) ** 2, axis=2)           # (N, 2)
    log_comp = -0.5 * sq / COVARIANCE - np.log(2 * np.pi * COVARIANCE)
    return logsumexp(log_comp, axis=1) + np.log(0.5)


def exact_log_evidence() -> float:
    """``log( (1/16) int_box L )``: each Gaussian's mass in the box is a product of normal CDF differences."""
    lo, hi = BOX
    sd = np.sqrt(COVARIANCE)
    mass = np.prod(stats.norm.cdf((hi - MODES) / sd) - stats.norm.cdf((lo - MODES) / sd), axis=1)
    return float(np.log(0.5 * mass.sum() / (hi - lo) ** 2))


def mode_fraction(samples, log_weights=None) -> float:
    """Weighted fraction of samples nearer the mode ``(0.5, 0.5)`` (i.e. ``theta_1 + theta_2 > 0``)."""
    upper = np.sum(samples, axis=1) > 0
    if log_weights is None:
        return float(upper.mean())
    w = np.exp(normalise(log_weights))
    return float(w[upper].sum())


@dataclass(frozen=True)
class Illustration:
    """Samples of the four panels and the numbers printed.

    Attributes
    ----------
    prior_samples : (N, 2) array
    normalised_weights : (N,) array
        ``w_hat_i`` of Eq. (A5).
    resampled : (N, 2) array
    posterior_smc, posterior_semc : (N, 2) arrays
        After one step of each sampler (single reweighting, no tempering).
    log_evidence : dict
        ``"importance"`` (Eq. 1 on the prior samples), ``"smc"``, ``"semc"``, ``"exact"``.
    upper_mode_fraction : dict
        Mass near ``(0.5, 0.5)`` for each stage; exact 0.5.
    acceptance : dict
        True acceptance rate of the move of each sampler.
    """

    prior_samples: np.ndarray
    normalised_weights: np.ndarray
    resampled: np.ndarray
    posterior_smc: np.ndarray
    posterior_semc: np.ndarray
    log_evidence: dict
    upper_mode_fraction: dict
    acceptance: dict


def run(n_samples: int = 10_000, rng=0) -> Illustration:
    """Draw the prior samples, weight them, resample, and run one step of SMC and SEMC."""
    from ..kernels import MarkovKernel, Static
    from ..core.tempering import Single
    from ..engine.drivers import SEMC, SMC
    from ..moves import RandomWalk, Stretch

    seeds = np.random.SeedSequence(as_generator(rng).integers(2**63)).spawn(3)
    gen = np.random.default_rng(seeds[0])
    the_prior = prior()
    samples = the_prior.sample(n_samples, gen)
    logw = log_likelihood(samples)                                            # Eq. (A4), log domain
    w_hat = np.exp(normalise(logw))                                           # Eq. (A5)
    resampled = samples[multinomial(w_hat, gen)]
    kernel = MarkovKernel([Static(), Static()])
    dataset = np.zeros(1)                     # the likelihood ignores it; one "dataset" = one step
    posteriors, evidence, acceptance = {}, {}, {}
    for name, cls, seed in (("smc", SMC, seeds[1]), ("semc", SEMC, seeds[2])):
        # the paper's single reweighting and one move (n_moves=1, no "moved fraction" rule); the
        # rest (log/logit coordinates, importance-sampling evidence) are the library's defaults
        moves = (Stretch if cls is SEMC else RandomWalk)(min_sweeps=1, moved_fraction=0.0)
        sampler = cls(the_prior, kernel, log_likelihood, n_samples=n_samples, rng=np.random.default_rng(seed),
                      moves=moves, tempering=Single())
        info = sampler.update(dataset)
        posteriors[name] = sampler.result.steps[-1].posterior
        evidence[name] = float(info.log_evidence)
        acceptance[name] = float(info.acceptance_rate)
    evidence["importance"] = log_mean_exp(logw)                               # Eq. (1)
    evidence["exact"] = exact_log_evidence()
    fractions = {"weighted prior": mode_fraction(samples, logw), "resampled": mode_fraction(resampled),
                 "smc": mode_fraction(posteriors["smc"]), "semc": mode_fraction(posteriors["semc"])}
    return Illustration(samples, w_hat, resampled, posteriors["smc"], posteriors["semc"],
                        evidence, fractions, acceptance)


def plot(result: Illustration, path):
    """Save the four-panel figure (Fig. 1 of the paper and what follows it) to ``path``."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 4, figsize=(13, 3.4), sharex=True, sharey=True, constrained_layout=True)
    order = np.argsort(result.normalised_weights)
    sc = axes[0].scatter(*result.prior_samples[order].T, c=result.normalised_weights[order], s=1.5,
                         cmap="viridis", rasterized=True)
    fig.colorbar(sc, ax=axes[0], label=r"$\hat w_i$", format="%.1e")
    axes[0].set_title("(a) prior samples by weight", fontsize=9)
    panels = ((result.resampled, "(b) after resampling"),
              (result.posterior_smc, "(c) SMC: resample + MH move"),
              (result.posterior_semc, "(d) SEMC: resample + stretch move"))
    for ax, (samples, title) in zip(axes[1:], panels):
        ax.scatter(*samples.T, s=1, alpha=0.3, color="C0", rasterized=True)
        ax.set_title(title, fontsize=9)
    for ax in axes:
        ax.plot(*MODES.T, "r+", ms=10, mew=2)
        ax.set_xlim(*BOX)
        ax.set_ylim(*BOX)
        ax.set_aspect("equal")
        ax.set_xlabel(r"$\theta_1$")
    axes[0].set_ylabel(r"$\theta_2$")
    fig.savefig(path, dpi=60)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="seqbayes example resampling", description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=10_000, help="number of samples N (default 10000)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("seqbayes-output/resampling"),
                        help="directory for the figure")
    args = parser.parse_args(argv)
    result = run(args.samples, args.seed)
    args.out.mkdir(parents=True, exist_ok=True)
    figure = args.out / "resampling_illustration.png"
    plot(result, figure)
    print(f"N = {args.samples}, seed = {args.seed}")
    print("mass near (0.5, 0.5) (exact 0.5): "
          + ", ".join(f"{k} {v:.3f}" for k, v in result.upper_mode_fraction.items()))
    print("log-evidence: " + ", ".join(f"{k} {v:.4f}" for k, v in result.log_evidence.items()))
    print("true acceptance rate of the move: "
          + ", ".join(f"{k} {v:.3f}" for k, v in result.acceptance.items()))
    print(f"figure: {figure}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
