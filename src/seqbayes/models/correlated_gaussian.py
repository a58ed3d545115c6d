"""A d-dimensional correlated Gaussian problem with a closed-form posterior and evidence.

Prior ``theta ~ N(m0, S0)`` with ``S0 = D R D``: standard deviations ``D`` spread over
``[0.5, 2]`` and an AR(1) correlation ``R_ij = rho^|i - j|`` (``rho = 0.8``). One dataset
observes every parameter with independent Gaussian noise, ``y = theta + eps``,
``eps ~ N(0, G)``, ``G = diag(g^2)``, with ``g`` spread over ``[0.1, 0.4]`` times the prior
sds, so that the posterior is 2.5-10 times narrower than the prior in every direction (about
2 nats of information per parameter: tempering crosses ``~ 2 d`` nats). Exactly:

* posterior ``N(m, S)``, ``S = (S0^-1 + G^-1)^-1``, ``m = S (S0^-1 m0 + G^-1 y)``;
* evidence ``p(y) = N(y; m0, S0 + G)``.

It is the problem of the high-dimension benchmark and of the moderate-dimension statistical test
(docs/benchmarks.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from ..rng import as_generator

__all__ = ["CorrelatedGaussian"]


class _GaussianPrior:
    """``N(mean, cov)`` with the prior protocol: ``logpdf (N, d) -> (N,)``, ``sample(n, rng) -> (n, d)``."""

    def __init__(self, mean, cov):
        self.mean = np.asarray(mean, dtype=float)
        self.cov = np.asarray(cov, dtype=float)
        self._chol = np.linalg.cholesky(self.cov)
        self._dist = stats.multivariate_normal(self.mean, self.cov)
        self.names = tuple(f"theta_{j}" for j in range(self.mean.size))

    def logpdf(self, theta):
        return np.atleast_1d(self._dist.logpdf(np.atleast_2d(theta)))

    def sample(self, n, rng):
        return self.mean + rng.standard_normal((int(n), self.mean.size)) @ self._chol.T


@dataclass(frozen=True, eq=False)
class CorrelatedGaussian:
    """The problem in ``dim`` dimensions with data drawn from ``seed``.

    Attributes
    ----------
    dim : int
    rho : float
        AR(1) correlation of the prior.
    seed : int
        Seed of the true parameter and the data (the problem, not the sampler).
    """

    dim: int
    rho: float = 0.8
    seed: int = 0

    def __post_init__(self):
        d = int(self.dim)
        if d < 1 or d != self.dim:
            raise ValueError(f"dim: must be an integer >= 1, got {self.dim}")
        rng = as_generator(self.seed)
        sd = np.linspace(0.5, 2.0, d) if d > 1 else np.ones(1)
        lags = np.abs(np.subtract.outer(np.arange(d), np.arange(d)))
        prior_cov = sd[:, None] * self.rho ** lags * sd[None, :]
        noise_sd = sd * np.linspace(0.1, 0.4, d)[::-1] if d > 1 else 0.2 * sd
        prior_mean = np.zeros(d)
        truth = prior_mean + np.linalg.cholesky(prior_cov) @ rng.standard_normal(d)
        data = truth + noise_sd * rng.standard_normal(d)
        precision = np.linalg.inv(prior_cov) + np.diag(noise_sd ** -2.0)
        post_cov = np.linalg.inv(precision)
        post_cov = 0.5 * (post_cov + post_cov.T)
        post_mean = post_cov @ (np.linalg.solve(prior_cov, prior_mean) + data / noise_sd ** 2)
        log_evidence = float(stats.multivariate_normal(prior_mean, prior_cov + np.diag(noise_sd ** 2)).logpdf(data))
        for name, value in (("prior_cov", prior_cov), ("noise_sd", noise_sd), ("prior_mean", prior_mean),
                            ("data", data), ("posterior_mean", post_mean), ("posterior_cov", post_cov),
                            ("log_evidence", log_evidence)):
            object.__setattr__(self, name, value)

    @property
    def posterior_sd(self) -> np.ndarray:
        """``(d,)`` exact posterior standard deviations."""
        return np.sqrt(np.diag(self.posterior_cov))

    def prior(self) -> _GaussianPrior:
        """The prior, an object with ``logpdf`` and ``sample``."""
        return _GaussianPrior(self.prior_mean, self.prior_cov)

    def loglike(self, theta, data):
        """``log N(data; theta, G)`` for ``theta (N, d)``, ``data (d,)``; returns ``(N,)``."""
        z = (np.asarray(data)[None, :] - theta) / self.noise_sd
        return -0.5 * np.einsum("ij,ij->i", z, z) - np.log(self.noise_sd).sum() - 0.5 * self.dim * np.log(2 * np.pi)

    def errors(self, record) -> tuple[float, float]:
        """``(log-evidence error, max |mean error| in posterior sds)`` of a step record (first update)."""
        mean_err = np.max(np.abs(record.mean() - self.posterior_mean) / self.posterior_sd)
        return float(record.info.log_evidence - self.log_evidence), float(mean_err)
