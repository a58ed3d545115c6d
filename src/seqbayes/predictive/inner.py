"""SMC^2's inner filters over the drifting parameters (:mod:`seqbayes.predictive.smc2`): a bootstrap particle filter
per outer particle, all of them advanced in one vectorised call of the user's likelihood
(:class:`ParticleInnerFilter`), or an exact Kalman filter when the observation is linear-Gaussian in the drifting
parameters (:class:`KalmanInnerFilter`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.tempering import next_increment
from ..kernels import Decay, Drift, MarkovKernel, Static
from ..priors import JointPrior, inside_support

__all__ = ["ParticleInnerFilter", "KalmanInnerFilter", "nested_split", "joint_columns"]


def nested_split(kernel: MarkovKernel) -> tuple[np.ndarray, np.ndarray] | None:
    """Column indices ``(static, drifting)`` when the kernel has both :class:`~seqbayes.Static`
    components and others, else ``None`` (SMC^2 does not apply)."""
    if not kernel.components:
        return None
    static = np.array([isinstance(c, Static) for c in kernel.components])
    if static.all() or not static.any():
        return None
    return np.flatnonzero(static), np.flatnonzero(~static)


def joint_columns(static, drifting, split, dim) -> np.ndarray:
    """Rows ``theta (K, d)`` from static ``(K, d_s)`` and drifting ``(K, d_x)`` columns."""
    theta = np.empty((static.shape[0], dim))
    theta[:, split[0]] = static
    theta[:, split[1]] = drifting
    return theta


def _systematic_rows(log_weights, rng) -> np.ndarray:
    """Systematic resampling of each row of ``log_weights (K, M)`` at once: ancestor indices ``(K, M)``."""
    k, m = log_weights.shape
    weights = np.exp(log_weights - log_weights.max(axis=1, keepdims=True))
    cdf = np.cumsum(weights, axis=1)
    cdf /= cdf[:, -1:]
    offsets = np.arange(k)[:, None]
    points = (rng.random((k, 1)) + np.arange(m)) / m + offsets
    index = np.searchsorted((cdf + offsets).ravel(), points.ravel(), side="right").reshape(k, m) - offsets * m
    return np.clip(index, 0, m - 1)


@dataclass(frozen=True)
class ParticleInnerFilter:
    """A bootstrap particle filter over the drifting parameters, one per outer particle, all at once.

    Parameters
    ----------
    n_inner : int
        Inner particles ``M`` per outer particle (100). The outer target is exact for any ``M``;
        a larger ``M`` lowers the noise of the likelihood estimates, which raises the PMMH
        acceptance over long histories (the variance of ``log p^(D^{1:s})`` grows like ``s / M``).
    ess_threshold : float
        An inner filter resamples when its ESS falls below this fraction of ``M`` (0.5).
    guided : bool
        Draw half of each step's inner particles from a Gaussian guide fitted to the data instead
        of from the kernel (True). Data that pin the drifting parameters far more tightly than the
        kernel's noise leave a bootstrap filter with almost no useful particle; the guide is fitted
        to ``n_pilot`` separate kernel draws weighted by the likelihood, tempered so that their ESS
        stays at a quarter (``L^beta``, so it covers the posterior with room), and fixed for that
        step (re-runs use the same guide), so the likelihood estimate stays unbiased: each particle
        carries ``L T / (T / 2 + G / 2)``.
    n_pilot : int
        Pilot draws of the guide (2000).
    """

    n_inner: int = 100
    ess_threshold: float = 0.5
    guided: bool = True
    n_pilot: int = 2000

    #: The outer particles carry the drifting parameters' first value too: the first dataset is then a
    #: static problem in every parameter (tempering, restarts and the importance evidence of the other
    #: samplers apply), and each inner filter starts from its outer particle's value instead of blind
    #: prior draws, which a sharp dataset would leave with one or no useful inner particle.
    joint_first_step = True

    def outer_columns(self, split: tuple[np.ndarray, np.ndarray], dim: int) -> np.ndarray:
        return np.arange(dim)

    def __post_init__(self):
        if int(self.n_inner) != self.n_inner or self.n_inner < 1:
            raise ValueError(f"n_inner: must be an integer >= 1, got {self.n_inner}")
        if not 0.0 <= self.ess_threshold <= 1.0:
            raise ValueError(f"ess_threshold: must lie in [0, 1], got {self.ess_threshold}")

    def check(self, problem: Problem, split: tuple[np.ndarray, np.ndarray]) -> None:
        if not isinstance(problem.prior, JointPrior):
            raise TypeError("prior: SMC^2 draws the drifting parameters from their own marginals; "
                            "give a seqbayes.JointPrior (independent marginals)")

    def fit_guide(self, problem: Problem, split: tuple[np.ndarray, np.ndarray], outer: np.ndarray, log_weights: np.ndarray,
                  cloud: dict | None, dataset: Any, likelihood: Any,
                  rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray] | None:
        """The step's Gaussian guide ``(mean (d_x,), cov (d_x, d_x))``, or ``None`` (not guided, a kernel
        without noise on a drifting parameter, or too few pilot draws with a non-zero likelihood).

        Pilot: ``n_pilot`` inner particles picked with the outer and inner weights and propagated
        through the kernel; a Gaussian ``P`` fitted to them stands for the predictive. Then up to
        four rounds of tempered adaptive importance sampling towards ``L P`` (none, and no guide,
        when the kernel's own draws keep a quarter of their ESS under ``L``): weigh the current
        draws by ``L^beta P / q`` with ``beta`` the largest exponent keeping a quarter of their ESS,
        fit the guide (weighted mean, twice the covariance), draw afresh from it; stop once
        ``beta`` reaches 1. The guide only has to cover the posterior: the particles' own weights
        use the exact transition density."""
        noise = problem.kernel.noise_std[split[1]]
        if not self.guided or not np.all(noise > 0):
            return None
        k, n_pilot, dim = outer.shape[0], int(self.n_pilot), problem.kernel.dim
        p = np.exp(log_weights - log_weights.max())
        rows = rng.choice(k, size=n_pilot, p=p / p.sum())
        cols = _categorical_rows(cloud["log_w"][rows], rng)
        prev = joint_columns(outer[rows][:, split[0]], cloud["x"][rows, cols], split, dim)
        theta = problem.kernel.propagate(prev, rng)
        x = theta[:, split[1]]
        mean, cov = x.mean(axis=0), np.cov(x, rowvar=False).reshape(x.shape[1], x.shape[1])
        cov = cov + np.diag(1e-12 * (1.0 + mean**2))
        log_predictive = _gaussian_logpdf(x, mean, cov)
        predictive = (mean, cov)
        log_proposal = log_predictive
        support = problem.support
        for round_ in range(4):
            inside = inside_support(theta, support)
            loglike = np.full(n_pilot, -np.inf)
            if inside.any():
                loglike[inside] = likelihood.loglike_on(theta[inside], dataset)
            if np.count_nonzero(np.isfinite(loglike)) < 2 * split[1].size + 2:
                return None
            base = log_predictive - log_proposal
            beta = next_increment(base, loglike, 1.0, 0.25, 0.25)
            if round_ == 0 and beta >= 1.0:  # the kernel's own draws keep a quarter of their ESS: no guide needed
                return None
            log_w = np.where(np.isfinite(loglike), base + beta * np.where(np.isfinite(loglike), loglike, 0.0), -np.inf)
            w = np.exp(log_w - log_w.max())
            w /= w.sum()
            mean = w @ x
            cov = 2.0 * ((x - mean).T * w) @ (x - mean) + np.diag(1e-12 * (1.0 + mean**2))
            if beta >= 1.0:
                break
            x = mean + rng.standard_normal(x.shape) @ np.linalg.cholesky(cov).T
            theta = theta.copy()
            theta[:, split[1]] = x
            log_proposal = _gaussian_logpdf(x, mean, cov)
            log_predictive = _gaussian_logpdf(x, *predictive)
        return mean, cov

    def advance(self, problem: Problem, split: tuple[np.ndarray, np.ndarray], outer: np.ndarray, cloud: dict | None, dataset: Any,
                first: bool, likelihood: Any, rng: np.random.Generator,
                guide: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, dict]:
        """One step of every inner filter.

        Parameters
        ----------
        outer : (K, d) array
            Outer particles: the static parameters and the drifting parameters' first value.
        cloud : dict or None
            ``{"x": (K, M, d_x), "log_w": (K, M)}`` after the last step (``None`` at ``first``).
        first : bool
            The first dataset: its likelihood at the outer particle itself.
        likelihood : object with ``loglike_on(theta (n, d), dataset) -> (n,)`` and ``n_evals``
            Evaluates (and counts) the user's likelihood.
        guide : tuple ``(mean, cov)`` or None
            The step's guide (:meth:`fit_guide`): half the particles are drawn from it.

        Returns
        -------
        log_increment : (K,) array
            ``log p^(D^s | D^{1:s-1}, phi)``; ``-inf`` where every inner particle has zero likelihood.
        cloud : dict
        """
        k, m, dim = outer.shape[0], int(self.n_inner), problem.kernel.dim
        support = problem.support
        if first:  # the outer particle holds the first value of the drifting parameters
            inside = inside_support(outer, support)
            log_increment = np.full(k, -np.inf)
            if inside.any():
                log_increment[inside] = likelihood.loglike_on(outer[inside], dataset)
            return log_increment, {"x": outer[:, None, split[1]].copy(), "log_w": np.zeros((k, 1)), "ess": np.ones(k)}
        x, log_w = cloud["x"], cloud["log_w"]
        if x.shape[1] != m:  # one value per outer particle after the first step: M children each
            x, log_w = np.repeat(x, m, axis=1), np.full((k, m), -np.log(m))
        phi = np.repeat(outer[:, split[0]], m, axis=0)
        previous = joint_columns(phi, x.reshape(k * m, -1), split, dim)
        theta = problem.kernel.propagate(previous, rng)  # Eq. (A2)
        correction = 0.0
        if guide is not None:  # half from the guide G: weight L T / q with q = T / 2 + G / 2
            mean, cov = guide
            chol = np.linalg.cholesky(cov)
            guided = rng.random(k * m) < 0.5
            draws = mean + rng.standard_normal((int(guided.sum()), mean.size)) @ chol.T
            theta[np.ix_(guided, split[1])] = draws
            nominal = problem.kernel.nominal(previous)[:, split[1]]
            noise = problem.kernel.noise_std[split[1]]
            z = (theta[:, split[1]] - nominal) / noise
            log_t = -0.5 * np.sum(z**2, axis=1) - np.sum(np.log(noise))
            log_g = _gaussian_logpdf(theta[:, split[1]], mean, cov)
            correction = (log_t - np.logaddexp(log_t, log_g) + np.log(2.0)).reshape(k, m)
        inside = inside_support(theta, support)
        loglike = np.full(k * m, -np.inf)
        if inside.all():
            loglike = likelihood.loglike_on(theta, dataset)
        elif inside.any():
            loglike[inside] = likelihood.loglike_on(theta[inside], dataset)
        loglike = loglike.reshape(k, m) + correction
        with np.errstate(invalid="ignore"):
            joint = log_w + loglike
            peak = np.max(joint, axis=1, keepdims=True)
            alive = np.isfinite(peak[:, 0])
            log_increment = np.full(k, -np.inf)
            log_increment[alive] = (np.log(np.exp(joint[alive] - peak[alive]).sum(axis=1)) + peak[alive, 0])
        log_w = np.where(alive[:, None], joint - np.where(alive, log_increment, 0.0)[:, None], -np.log(m))
        x = theta[:, split[1]].reshape(k, m, -1)
        ess = 1.0 / np.sum(np.exp(2.0 * log_w), axis=1)
        rows = np.flatnonzero(alive & (ess < self.ess_threshold * m))
        if rows.size:
            index = _systematic_rows(log_w[rows], rng)
            x[rows] = x[rows[:, None], index]
            log_w[rows] = -np.log(m)
        # "ess": each inner filter's ESS fraction after weighting, before resampling (a health diagnostic)
        return log_increment, {"x": x, "log_w": log_w, "ess": np.where(alive, ess, 0.0) / m}

    def moments(self, cloud: dict) -> tuple[np.ndarray, np.ndarray]:
        """Each inner filter's weighted mean and variance of the drifting parameters, ``(K, d_x)`` each."""
        w = np.exp(cloud["log_w"] - cloud["log_w"].max(axis=1, keepdims=True))
        w /= w.sum(axis=1, keepdims=True)
        mean = np.einsum("km,kmj->kj", w, cloud["x"])
        return mean, np.einsum("km,kmj->kj", w, (cloud["x"] - mean[:, None]) ** 2)

    def draws(self, cloud: dict, rng: np.random.Generator) -> np.ndarray:
        """One draw of the drifting parameters from each inner filter, ``(K, d_x)``."""
        index = _categorical_rows(cloud["log_w"], rng)
        return cloud["x"][np.arange(index.size), index]


def _gaussian_logpdf(x, mean, cov) -> np.ndarray:
    """``log N(x; mean, cov)`` up to the ``2 pi`` constant, for ``x (n, k)``."""
    chol = np.linalg.cholesky(cov)
    u = np.linalg.solve(chol, (x - mean).T)
    return -0.5 * np.sum(u**2, axis=0) - np.sum(np.log(np.diag(chol)))


def _categorical_rows(log_weights, rng) -> np.ndarray:
    """One index per row of ``log_weights (K, M)``, drawn with those weights."""
    weights = np.exp(log_weights - log_weights.max(axis=1, keepdims=True))
    cdf = np.cumsum(weights, axis=1)
    u = rng.random(weights.shape[0]) * cdf[:, -1]
    return np.minimum((cdf < u[:, None]).sum(axis=1), weights.shape[1] - 1)


@dataclass(frozen=True, eq=False)
class KalmanInnerFilter:
    """An exact inner filter for drifting parameters that enter the observation linearly.

    The user declares ``y = H(phi, D) x + b(phi, D) + e``, ``e ~ N(0, diag(r(phi, D)))``; the
    drifting parameters ``x`` then have a Gaussian filtering posterior given each ``phi`` when
    their kernel components are :class:`~seqbayes.Drift` or :class:`~seqbayes.Decay` (linear, with
    Gaussian noise) and their prior marginals are normal. The likelihood estimate is then the
    exact ``p(D^s | D^{1:s-1}, phi)`` (Rao-Blackwellised SMC^2), so PMMH is exact MH.

    Parameters
    ----------
    observe : callable ``(phi (K, d_s), dataset) -> (H, b, r, y)``
        ``H (K, m, d_x)``, ``b (K, m)``, ``r (K, m)`` (noise variances) and ``y (m,)``.
    """

    observe: object

    joint_first_step = False

    def outer_columns(self, split: tuple[np.ndarray, np.ndarray], dim: int) -> np.ndarray:
        return split[0]

    def check(self, problem: Problem, split: tuple[np.ndarray, np.ndarray]) -> None:
        prior, kernel = problem.prior, problem.kernel
        if not isinstance(prior, JointPrior):
            raise TypeError("prior: KalmanInnerFilter needs a seqbayes.JointPrior with normal drifting marginals")
        for j in split[1]:
            dist = prior.distributions[j]
            if getattr(getattr(dist, "dist", None), "name", None) != "norm":
                raise ValueError(f"prior: {prior.names[j]!r} must be normal for KalmanInnerFilter")
            if not isinstance(kernel.components[j], (Drift, Decay)):
                raise ValueError(f"kernel: {prior.names[j]!r} must be Drift or Decay for KalmanInnerFilter")

    def fit_guide(self, *args: Any, **kwargs: Any) -> None:
        """The Kalman filter needs no guide."""
        return None

    def advance(self, problem: Problem, split: tuple[np.ndarray, np.ndarray], static: np.ndarray, cloud: dict | None, dataset: Any,
                first: bool, likelihood: Any, rng: np.random.Generator,
                guide: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, dict]:
        """One Kalman step per outer particle (``static (K, d_s)``, the static parameters); arguments and returns as :meth:`ParticleInnerFilter.advance`
        (the cloud is ``{"mean": (K, d_x), "cov": (K, d_x, d_x)}``; each step counts as K evaluations)."""
        k, d_x = static.shape[0], split[1].size
        if first:
            dists = [problem.prior.distributions[j] for j in split[1]]
            mean = np.tile([d.mean() for d in dists], (k, 1))
            cov = np.tile(np.diag([d.var() for d in dists]), (k, 1, 1))
        else:  # predict through the linear kernel, Eq. (A2)
            components = [problem.kernel.components[j] for j in split[1]]
            gain = np.array([1.0 if isinstance(c, Drift) else np.exp(-c.rate) for c in components])
            shift = np.array([c.rate if isinstance(c, Drift) else 0.0 for c in components])
            noise = np.array([c.noise_std for c in components]) ** 2
            mean = cloud["mean"] * gain + shift
            cov = cloud["cov"] * np.outer(gain, gain) + np.diag(noise)
        design, offset, noise_var, y = self.observe(static, dataset)
        design = np.broadcast_to(np.asarray(design, dtype=float), (k,) + np.shape(design)[-2:])
        if design.shape[2] != d_x:
            raise ValueError(f"observe: H has {design.shape[2]} columns, there are {d_x} drifting parameters")
        innovation = np.asarray(y, dtype=float) - offset - np.einsum("kmj,kj->km", design, mean)
        precision_noise = 1.0 / np.broadcast_to(np.asarray(noise_var, dtype=float), innovation.shape)
        # information form (d_x x d_x, never m x m): posterior precision P^-1 + H^T R^-1 H
        information = np.einsum("kmi,km,kmj->kij", design, precision_noise, design)
        projected = np.einsum("kmi,km->ki", design, precision_noise * innovation)
        posterior_cov = np.linalg.inv(np.linalg.inv(cov) + information)
        posterior_cov = 0.5 * (posterior_cov + posterior_cov.transpose(0, 2, 1))
        correction = np.einsum("kij,kj->ki", posterior_cov, projected)
        # log N(v; 0, S) with S = H P H^T + R, by the determinant lemma and Woodbury's identity
        log_det = (-np.log(precision_noise).sum(axis=1) + np.linalg.slogdet(cov)[1]
                   - np.linalg.slogdet(posterior_cov)[1])
        quadratic = np.sum(precision_noise * innovation**2, axis=1) - np.einsum("ki,ki->k", projected, correction)
        log_increment = -0.5 * (quadratic + log_det + innovation.shape[1] * np.log(2.0 * np.pi))
        likelihood.n_evals += k
        mean, cov = mean + correction, posterior_cov
        return log_increment, {"mean": mean, "cov": cov}

    def moments(self, cloud: dict) -> tuple[np.ndarray, np.ndarray]:
        """Each filter's mean and marginal variances, ``(K, d_x)`` each."""
        return cloud["mean"], np.diagonal(cloud["cov"], axis1=1, axis2=2).copy()

    def draws(self, cloud: dict, rng: np.random.Generator) -> np.ndarray:
        chol = np.linalg.cholesky(cloud["cov"] + 1e-300 * np.eye(cloud["cov"].shape[1]))
        return cloud["mean"] + np.einsum("kij,kj->ki", chol, rng.standard_normal(cloud["mean"].shape))


import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from typing import Any

    from ..core.state import Problem
