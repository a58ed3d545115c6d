"""A linear-Gaussian on-line problem with an exact answer, for validation.

Parameters ``theta_s = (a_s, b)``: the offset ``a`` drifts as a Gaussian random
walk, ``a_{s+1} = a_s + nu``, ``nu ~ N(0, q^2)``; the slope ``b`` is static.
Dataset ``s`` holds ``y_{s,k} = a_s + b x_k + eps``, ``eps ~ N(0, r^2)`` at known
covariates ``x_k``. With a Gaussian prior the filtering posterior and the
evidence are given exactly by the Kalman filter (:func:`kalman_filter`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from ..kernels import Drift, MarkovKernel, Static
from ..priors import JointPrior
from ..rng import as_generator

__all__ = ["LinearGaussianProblem", "kalman_filter", "KalmanStep"]


@dataclass(frozen=True)
class KalmanStep:
    """Exact filtering moments after one dataset."""

    mean: np.ndarray        # (2,)
    cov: np.ndarray         # (2, 2)
    log_evidence_increment: float
    log_evidence: float


@dataclass(frozen=True, eq=False)
class LinearGaussianProblem:
    """The problem's constants and a simulator.

    Attributes
    ----------
    prior_mean, prior_std : (2,) arrays
        Independent Gaussian prior on ``(a, b)``.
    drift_std : float
        ``q``, the random-walk std of ``a``.
    noise_std : float
        ``r``, the observation noise std.
    covariates : (m,) array
        ``x_k``.
    """

    prior_mean: np.ndarray = (0.0, 0.0)
    prior_std: np.ndarray = (1.0, 1.0)
    drift_std: float = 0.3
    noise_std: float = 0.5
    covariates: np.ndarray = tuple(np.linspace(-1.0, 1.0, 10))

    def __post_init__(self):
        for name in ("prior_mean", "prior_std", "covariates"):
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=float))

    @property
    def prior(self) -> JointPrior:
        return JointPrior({"a": stats.norm(self.prior_mean[0], self.prior_std[0]),
                           "b": stats.norm(self.prior_mean[1], self.prior_std[1])})

    @property
    def kernel(self) -> MarkovKernel:
        return MarkovKernel([Drift(0.0, noise_std=self.drift_std), Static()])

    def loglike(self, theta, y) -> np.ndarray:
        """``log p(y | a, b)`` for ``theta (N, 2)`` and one dataset ``y (m,)``; returns ``(N,)``."""
        y = np.asarray(y, dtype=float)
        mean = theta[:, :1] + theta[:, 1:2] * self.covariates[None, :]
        return stats.norm.logpdf(y[None, :], mean, self.noise_std).sum(axis=1)

    def simulate(self, n_steps: int, rng=None, truth=None):
        """Datasets ``(n_steps, m)`` and the true ``(n_steps, 2)`` parameter path."""
        rng = as_generator(rng)
        theta = np.array(truth, dtype=float) if truth is not None else rng.normal(self.prior_mean, self.prior_std)
        path, data = [], []
        for s in range(n_steps):
            if s > 0:
                theta = theta + np.array([rng.normal(0.0, self.drift_std), 0.0])
            path.append(theta.copy())
            data.append(theta[0] + theta[1] * self.covariates + rng.normal(0.0, self.noise_std, self.covariates.size))
        return np.array(data), np.array(path)


def kalman_filter(problem: LinearGaussianProblem, datasets) -> list[KalmanStep]:
    """Exact filtering posterior of ``(a_s, b)`` and the cumulative log-evidence."""
    mean = problem.prior_mean.copy()
    cov = np.diag(problem.prior_std**2)
    process = np.diag([problem.drift_std**2, 0.0])
    design = np.column_stack([np.ones_like(problem.covariates), problem.covariates])
    noise = problem.noise_std**2 * np.eye(problem.covariates.size)
    out, total = [], 0.0
    for s, y in enumerate(np.asarray(datasets, dtype=float)):
        if s > 0:
            cov = cov + process  # predict: F = I
        innovation_cov = design @ cov @ design.T + noise
        increment = stats.multivariate_normal.logpdf(y, design @ mean, innovation_cov)
        gain = np.linalg.solve(innovation_cov, design @ cov).T
        mean = mean + gain @ (y - design @ mean)
        cov = cov - gain @ design @ cov
        cov = 0.5 * (cov + cov.T)
        total += increment
        out.append(KalmanStep(mean.copy(), cov.copy(), float(increment), float(total)))
    return out
