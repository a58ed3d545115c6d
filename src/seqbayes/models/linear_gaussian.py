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

__all__ = ["LinearGaussianProblem", "LinearGaussianStateSpace", "kalman_filter", "KalmanStep", "errors_against"]


@dataclass(frozen=True)
class KalmanStep:
    """Exact filtering moments after one dataset."""

    mean: np.ndarray        # (2,)
    cov: np.ndarray         # (2, 2)
    log_evidence_increment: float
    log_evidence: float


def errors_against(result, exact: list[KalmanStep]) -> np.ndarray:
    """A sampler's run against the exact filter, per step.

    Parameters
    ----------
    result : seqbayes.Result
        The run (its first ``len(exact)`` steps are compared).
    exact : list of KalmanStep
        The exact posterior of each step (:func:`kalman_filter`, :meth:`LinearGaussianStateSpace.exact`).

    Returns
    -------
    (S, 3) array
        Per step: the largest |mean error| in exact posterior sds, the largest |std / exact std - 1|,
        and |log-evidence error| in nats.
    """
    out = []
    for record, step in zip(result.steps, exact):
        sd = np.sqrt(np.diag(step.cov))
        out.append((np.max(np.abs(record.mean() - step.mean) / sd), np.max(np.abs(record.std() / sd - 1)),
                    abs(record.info.log_evidence - step.log_evidence)))
    return np.array(out)


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


@dataclass(frozen=True, eq=False)
class LinearGaussianStateSpace:
    """A linear-Gaussian on-line problem with any mix of static and drifting parameters.

    Dataset ``s`` holds ``y_s = X theta_s + eps``, ``eps ~ N(0, r^2 I)``, with a fixed design
    ``X (m, d)``; each parameter evolves as ``theta_{s+1, j} = g_j theta_{s, j} + c_j + nu_j``,
    ``nu_j ~ N(0, q_j^2)`` (``g = 1, c = 0, q = 0``: static; ``g = 1, q > 0``: a random walk,
    :class:`~seqbayes.Drift`; ``g = exp(-rate)``: AR(1) decay, :class:`~seqbayes.Decay`). With
    independent Gaussian priors the Kalman filter gives the exact filtering posterior and evidence
    (:meth:`exact`) at every step, however long the stream.

    Attributes
    ----------
    design : (m, d) array
    kinds : tuple of str
        Per parameter: ``"static"``, ``"drift"`` or ``"decay"``.
    rates : (d,) array
        Drift rate ``c_j`` or decay rate (``g_j = exp(-rate)``); ignored for static parameters.
    process_std : (d,) array
        ``q_j`` (0 for static parameters).
    prior_mean, prior_std : (d,) arrays
    noise_std : float
    """

    design: np.ndarray
    kinds: tuple
    rates: np.ndarray
    process_std: np.ndarray
    prior_mean: np.ndarray
    prior_std: np.ndarray
    noise_std: float = 0.5

    def __post_init__(self):
        for name in ("design", "rates", "process_std", "prior_mean", "prior_std"):
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=float))
        d = self.design.shape[1]
        if len(self.kinds) != d or any(k not in ("static", "drift", "decay") for k in self.kinds):
            raise ValueError(f"kinds: expected {d} of 'static', 'drift', 'decay', got {self.kinds}")

    @classmethod
    def mixed(cls, m: int = 10, seed: int = 7) -> "LinearGaussianStateSpace":
        """The long-stream problem: one AR(1)-decaying, one drifting and two static
        parameters, ``m`` observations per dataset."""
        rng = np.random.default_rng(seed)
        design = np.column_stack([rng.normal(size=(m, 3)), np.ones(m)])
        return cls(design, ("decay", "drift", "static", "static"), rates=(0.1, 0.0, 0.0, 0.0),
                   process_std=(0.1, 0.05, 0.0, 0.0), prior_mean=(0.0, 0.0, 0.0, 0.0),
                   prior_std=(1.0, 1.0, 1.0, 1.0), noise_std=0.5)

    @property
    def gains(self) -> np.ndarray:
        return np.array([np.exp(-r) if k == "decay" else 1.0 for k, r in zip(self.kinds, self.rates)])

    @property
    def shifts(self) -> np.ndarray:
        return np.array([r if k == "drift" else 0.0 for k, r in zip(self.kinds, self.rates)])

    @property
    def names(self) -> tuple:
        return tuple(f"theta_{j}" for j in range(self.design.shape[1]))

    @property
    def prior(self) -> JointPrior:
        return JointPrior({n: stats.norm(m, s) for n, m, s in zip(self.names, self.prior_mean, self.prior_std)})

    @property
    def kernel(self) -> MarkovKernel:
        from ..kernels import Decay

        parts = []
        for kind, rate, q in zip(self.kinds, self.rates, self.process_std):
            parts.append(Static() if kind == "static" else Drift(rate, noise_std=q) if kind == "drift"
                         else Decay(rate, noise_std=q))
        return MarkovKernel(parts)

    def loglike(self, theta, y) -> np.ndarray:
        """``log p(y | theta)`` for ``theta (N, d)`` and one dataset ``y (m,)``; returns ``(N,)``."""
        residual = np.asarray(y, dtype=float)[None, :] - theta @ self.design.T
        return (-0.5 * np.einsum("ij,ij->i", residual, residual) / self.noise_std**2
                - y.size * (np.log(self.noise_std) + 0.5 * np.log(2.0 * np.pi)))

    def observe(self, static, y):
        """The declaration for :class:`~seqbayes.predictive.smc2.KalmanInnerFilter`: ``(H, b, r, y)`` given the
        static parameters ``static (K, d_s)``."""
        is_static = np.array([k == "static" for k in self.kinds])
        offset = static @ self.design[:, is_static].T
        noise = np.full(offset.shape, self.noise_std**2)
        return self.design[None, :, ~is_static], offset, noise, np.asarray(y, dtype=float)

    def simulate(self, n_steps: int, rng=None):
        """Datasets ``(n_steps, m)`` and the true ``(n_steps, d)`` parameter path."""
        rng = as_generator(rng)
        theta = rng.normal(self.prior_mean, self.prior_std)
        path, data = [], []
        for s in range(n_steps):
            if s > 0:
                theta = self.gains * theta + self.shifts + self.process_std * rng.standard_normal(theta.size)
            path.append(theta.copy())
            data.append(self.design @ theta + self.noise_std * rng.standard_normal(self.design.shape[0]))
        return np.array(data), np.array(path)

    def exact(self, datasets) -> list[KalmanStep]:
        """The Kalman filter: exact filtering moments and cumulative log-evidence at every step."""
        mean, cov = self.prior_mean.copy(), np.diag(self.prior_std**2)
        gains, process = self.gains, np.diag(self.process_std**2)
        noise = self.noise_std**2 * np.eye(self.design.shape[0])
        out, total = [], 0.0
        for s, y in enumerate(np.asarray(datasets, dtype=float)):
            if s > 0:
                mean = gains * mean + self.shifts
                cov = cov * np.outer(gains, gains) + process
            innovation_cov = self.design @ cov @ self.design.T + noise
            increment = stats.multivariate_normal.logpdf(y, self.design @ mean, innovation_cov)
            gain = np.linalg.solve(innovation_cov, self.design @ cov).T
            mean = mean + gain @ (y - self.design @ mean)
            cov = cov - gain @ self.design @ cov
            cov = 0.5 * (cov + cov.T)
            total += increment
            out.append(KalmanStep(mean.copy(), cov.copy(), float(increment), float(total)))
        return out

    def running_statistics(self):
        """The likelihood's additive statistics (``sum y``, ``X^T y``, the dataset count), so that the
        history prior of an all-static run evaluates every past dataset in one call
        (:class:`~seqbayes.RunningStatistics`)."""
        from ..predictive.history import RunningStatistics

        design, noise = self.design, self.noise_std
        gram = design.T @ design
        constant = design.shape[0] * (np.log(noise) + 0.5 * np.log(2.0 * np.pi))

        def summarise(y):
            y = np.asarray(y, dtype=float)
            return {"count": 1.0, "yy": y @ y, "xy": design.T @ y}

        def loglike(theta, t):
            quadratic = t["yy"] - 2.0 * theta @ t["xy"] + t["count"] * np.einsum("ij,jk,ik->i", theta, gram, theta)
            return -0.5 * quadratic / noise**2 - t["count"] * constant

        return RunningStatistics(summarise, loglike)
