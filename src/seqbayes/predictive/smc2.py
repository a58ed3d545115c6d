"""SMC^2: exact on-line inference when static and drifting parameters are tracked together.

The transition mixture of :mod:`seqbayes.predictive.mixture` carries the posterior of a static
parameter through a kernel density every step; over hundreds of steps that
re-summarisation collapses the static posterior (``docs/core.md`` measures it). SMC^2
(Chopin, Jacob and Papaspiliopoulos 2013) avoids it by never propagating a static
parameter through a density at all:

- outer particles ``phi_i`` carry the static parameters (the kernel's :class:`~seqbayes.Static`
  components) with weights ``W_i``;
- each carries an inner filter over the drifting parameters ``x`` built from the user's
  :class:`~seqbayes.MarkovKernel` and likelihood: a bootstrap particle filter of ``M`` particles
  (:class:`ParticleInnerFilter`, any model), or a Kalman filter when the user declares the
  observation linear-Gaussian in ``x`` (:class:`KalmanInnerFilter`, exact);
- the inner filter's likelihood estimate ``p^(D^s | D^{1:s-1}, phi_i)`` reweights ``phi_i``
  (unbiased, so the outer target is exact whatever ``M``), with adaptive tempering of that
  estimate when one step would leave ESS < ``tempering_threshold * N`` (density tempering,
  Duan and Fulop 2015);
- when the ESS falls the outer particles are resampled and moved by particle-marginal
  Metropolis-Hastings: a proposal ``phi'`` (the sampler's own move: SMC's Gaussian random walk
  or SEMC's stretch move with its adaptive step size, in log/logit coordinates of bounded
  parameters) re-runs its inner filter over every dataset so far, and is accepted with the
  ratio of ``p_0(phi) p^(D^{1:s-1} | phi) p^(D^s | D^{1:s-1}, phi)^beta``. A re-run costs O(s), so
  the sweeps are queued and each update spends at most a fixed budget on them
  (:mod:`seqbayes.predictive.pmmh`, exact): the cost of an update is bounded over any horizon
  (``docs/benchmarks.md``, long streams);
- the evidence increment is the weighted mean of the likelihood estimates (Eq. 1 over the
  tempering stages).

Per step the record holds one draw of ``(phi_i, x_i)`` per outer particle (``x_i`` from its
inner filter), so the drifting parameters' filtering posterior, forecasts through the kernel
and the cumulative log-evidence come out as from the other samplers; its mean and sd are
Rao-Blackwellised over every inner filter (:func:`nested_moments`).

Why by hand: ``particles`` has SMC^2, but its inner filters are Python objects, one per outer
particle, and its models are per-particle classes; here every inner filter of every outer
particle advances in one vectorised ``(N, M, d)`` call of the user's ``loglike(theta, data)``.
"""

from __future__ import annotations

import sys
import warnings
from dataclasses import dataclass, field, replace
from functools import partial

import numpy as np

from ..core.errors import InnerFilterWarning, ZeroLikelihoodError, prior_name, zero_likelihood_message
from ..core.state import Cloud, Estimate, Failure, MoveTally, Outcome, Tempered, Weighed, kept_copy
from ..kernels import Decay, Drift, MarkovKernel, Static
from ..priors import JointPrior, inside_support
from ..resampling import resample
from ..results import prior_data_conflict
from ..core.tempering import next_increment, temper
from .particle import ParticlePredictive
from .pmmh import RESTORE_LIMIT, Rejuvenation, outer_logpdf, rejuvenate, rerun_cost

__all__ = ["ParticleInnerFilter", "KalmanInnerFilter", "NestedState", "nested_split", "start_nested",
           "after_joint_first_step", "NestedPredictive", "JointFirstStep", "nested_state_arrays", "nested_state_from_arrays",
           "nested_guide", "nested_record_moments", "nested_moments", "warn_rejuvenation", "LOW_ACCEPTANCE"]


def nested_split(kernel: MarkovKernel) -> tuple[np.ndarray, np.ndarray] | None:
    """Column indices ``(static, drifting)`` when the kernel has both :class:`~seqbayes.Static`
    components and others, else ``None`` (SMC^2 does not apply)."""
    if not kernel.components:
        return None
    static = np.array([isinstance(c, Static) for c in kernel.components])
    if static.all() or not static.any():
        return None
    return np.flatnonzero(static), np.flatnonzero(~static)


def _joint(static, drifting, split, dim) -> np.ndarray:
    """Rows ``theta (K, d)`` from static ``(K, d_s)`` and drifting ``(K, d_x)`` columns."""
    theta = np.empty((static.shape[0], dim))
    theta[:, split[0]] = static
    theta[:, split[1]] = drifting
    return theta


def _take(cloud: dict, index) -> dict:
    return {key: value[index] for key, value in cloud.items()}


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
        prev = _joint(outer[rows][:, split[0]], cloud["x"][rows, cols], split, dim)
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
        previous = _joint(phi, x.reshape(k * m, -1), split, dim)
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


@dataclass(frozen=True, eq=False)
class NestedState:
    """Everything SMC^2 needs to assimilate the next dataset.

    Attributes
    ----------
    step : int
    outer : (N, d_o) array
        Outer particles: the static parameters, and with :class:`ParticleInnerFilter` the drifting
        parameters' first value (columns ``inner.outer_columns``).
    cloud : dict of arrays with leading axis N
        The inner filters after the last dataset.
    log_weights : (N,) array
        Normalised outer log-weights.
    log_prior : (N,) array
        ``log p_0`` of the outer particles.
    log_likelihood : (N,) array
        ``log p^(D^{1:s} | outer)``, the inner filters' running likelihood estimates.
    datasets : tuple
        ``D^1 .. D^s`` (PMMH re-runs the inner filters over them).
    log_evidence, step_size : float
    particles : (N, d) array
        One joint draw per outer particle (the last posterior; the prior draws before the first step).
    predictive : (N, d) array or None
        Those draws propagated through the kernel (the record's predictive), the reference of the
        next step's prior-data conflict diagnostic.
    guides : tuple
        Per step, the inner filters' guide ``(mean, cov)`` or ``None`` (:meth:`ParticleInnerFilter.fit_guide`);
        PMMH re-runs use the same guides, which keeps their likelihood estimates unbiased.
    pending : Rejuvenation
        The PMMH moves still to make since the last resampling (:mod:`seqbayes.predictive.pmmh`).
    n_evals_total : int
        Likelihood evaluations of every step so far (the amortised cost is this over ``step``).
    moments : tuple ``(mean (d,), sd (d,))`` or None
        The step's posterior moments with the drifting parameters Rao-Blackwellised (:func:`nested_moments`).
    """

    step: int
    outer: np.ndarray
    cloud: dict
    log_weights: np.ndarray
    log_prior: np.ndarray
    log_likelihood: np.ndarray
    datasets: tuple
    log_evidence: float
    step_size: float
    particles: np.ndarray = field(default=None)
    predictive: np.ndarray | None = None
    guides: tuple = ()
    pending: Rejuvenation = field(default_factory=Rejuvenation)
    n_evals_total: int = 0
    moments: tuple | None = None

    @property
    def prior_draws(self) -> np.ndarray:
        """Draws of the next step's prior (the last posterior propagated; the prior before step 1)."""
        return self.predictive if self.predictive is not None else self.particles

    @property
    def posterior(self) -> np.ndarray | None:
        return self.particles if self.step else None

    @property
    def posterior_log_weights(self) -> np.ndarray | None:
        return self.log_weights if self.step else None


def start_nested(prior: JointPrior, columns: np.ndarray, draws: np.ndarray, step_size: float) -> NestedState:
    """The state before the first dataset, from ``draws (N, d)`` of the prior; ``columns`` are the
    outer particles' columns."""
    n = draws.shape[0]
    outer = draws[:, columns]
    return NestedState(0, outer, {}, np.full(n, -np.log(n)), outer_logpdf(prior, columns, outer),
                       np.zeros(n), (), 0.0, float(step_size), draws)


def after_joint_first_step(split: tuple[np.ndarray, np.ndarray], n_inner: int, particles: np.ndarray, log_weights: np.ndarray,
                           components: np.ndarray, dataset: Any, log_evidence: float, step_size: float,
                           posterior: np.ndarray, predictive: np.ndarray, n_evals: int = 0) -> NestedState:
    """The state after a first step done jointly over every parameter (``joint_first_step``):
    ``components`` are ``(log L_1, log p_0)`` at ``particles (N, d)``; each inner filter holds
    ``n_inner`` copies of its outer particle's drifting values; ``n_evals`` is the step's evaluations."""
    n = particles.shape[0]
    x = np.repeat(particles[:, None, split[1]], n_inner, axis=1)
    return NestedState(1, particles, {"x": x, "log_w": np.full((n, n_inner), -np.log(n_inner)), "ess": np.ones(n)},
                       log_weights, components[:, 1].copy(), components[:, 0].copy(), (kept_copy(dataset),),
                       float(log_evidence), float(step_size), posterior, predictive, (None,), Rejuvenation(),
                       int(n_evals))


@dataclass(frozen=True, eq=False)
class OuterCloud(Cloud):
    """The outer particles between stages (``particles`` the static parameters, ``components`` the ``(N, 3)`` of
    :func:`~seqbayes.predictive.pmmh.rejuvenate`) with their inner filters (``inner``) and the pending moves."""

    inner: dict | None = None
    pending: Rejuvenation = field(default_factory=Rejuvenation)
    concluded: float = float("nan")


@dataclass(frozen=True, eq=False)
class OuterWeighed(Weighed):
    """:class:`~seqbayes.core.state.Weighed` with what SMC^2's later stages need: the datasets and guides so far
    and the inner filters' mean ESS."""

    datasets: tuple = ()
    guides: tuple = ()
    inner_ess: float = float("nan")


@dataclass(frozen=True, eq=False)
class _Rejuvenating:
    """SMC^2's particles between the stages of the tempering loop: the outer cloud, the moves so far (``n_virtual``:
    the PMMH batches), the evaluations spent on them in this update and whether the last stage resampled."""

    cloud: OuterCloud
    moves: MoveTally
    spent: int = 0
    resampled: bool = False


class NestedPredictive:
    """SMC^2 as a step's predictive (:class:`~seqbayes.predictive.particle.Predictive`): the inner filters' likelihood
    estimates weigh the outer particles; they are resampled when the ESS has fallen and moved by PMMH within a
    per-update budget (:func:`~seqbayes.predictive.pmmh.rejuvenate`); the evidence increment is the tempering
    path's (Eq. 1)."""

    def __init__(self, problem, config):
        self.problem, self.config = problem, config
        self.split, self.inner = nested_split(problem.kernel), problem.inner_filter

    def remedy(self, state, dataset, likelihood, outcome):
        return None

    def weigh(self, state, dataset, likelihood, rng) -> OuterWeighed | Failure:
        problem, split, inner, step = self.problem, self.split, self.inner, state.step + 1
        guide = (inner.fit_guide(problem, split, state.outer, state.log_weights, state.cloud, dataset, likelihood, rng)
                 if step > 1 else None)
        log_increment, cloud = inner.advance(problem, split, state.outer, state.cloud or None, dataset, step == 1,
                                             likelihood, rng, guide)
        inner_ess = float(np.exp(state.log_weights) @ cloud["ess"]) if "ess" in cloud else float("nan")
        components = np.column_stack([log_increment, state.log_prior, state.log_likelihood])
        if not np.isfinite(log_increment).any():
            return Failure(ZeroLikelihoodError(zero_likelihood_message(step, prior_name(step), likelihood)))
        return OuterWeighed(OuterCloud(state.outer, state.log_weights, components, inner=cloud, pending=state.pending),
                            None, MoveTally(step_size=state.step_size), n_found=self.config.n_samples,
                            datasets=state.datasets + (kept_copy(dataset),), guides=state.guides + (guide,),
                            inner_ess=inner_ess)

    def temper(self, state, dataset, weighed, likelihood, rng) -> Tempered | Failure:
        """Reweight by the likelihood estimates' ``delta`` powers (density tempering) through the one tempering loop
        (:func:`~seqbayes.core.tempering.temper`); when the ESS falls, resample and schedule PMMH sweeps
        (:meth:`_resample_rejuvenate`). A tempered update completes them at every stage; an untempered one restores
        the copies' diversity to the ESS before the resampling, then spends what is left of
        ``SamplerConfig.move_budget x N M`` evaluations and defers the rest (:mod:`seqbayes.predictive.pmmh`)."""
        cloud = weighed.cloud
        annealed = temper(_Rejuvenating(cloud, MoveTally(step_size=weighed.moves.step_size)), cloud.components[:, 0],
                          cloud.log_weights, self.config.tempering_rule(),
                          partial(self._resample_rejuvenate, weighed=weighed, likelihood=likelihood, rng=rng),
                          likelihood.step)
        if annealed.decision is not None:  # a stage's Failure
            return annealed.decision
        staged = annealed.particles
        return Tempered(staged.cloud, annealed.log_z, annealed.temperatures, staged.moves, staged.resampled,
                        annealed.last.ess)

    def _resample_rejuvenate(self, staged, loglike, stage, weighed, likelihood, rng):
        """SMC^2's mutation (:class:`~seqbayes.core.tempering.Mutation`): resample at an intermediate stage, or at the
        last when the ESS is below ``ess_threshold * N`` (which concludes the last rejuvenation and schedules the
        next), then the PMMH attempts the budget allows (:func:`~seqbayes.predictive.pmmh.rejuvenate`)."""
        config, n, beta = self.config, self.config.n_samples, stage.beta
        outer, log_weights = staged.cloud, stage.log_weights
        static, components, cloud = outer.particles, outer.components, outer.inner
        pending, concluded = outer.pending, outer.concluded
        resampled = beta < 1.0 or stage.ess < config.ess_threshold * n
        if resampled:
            index = resample(config.resampling, stage.weights, rng, n)
            static, components, cloud = static[index], components[index], _take(cloud, index)
            log_weights = np.full(n, -np.log(n))
            if pending.n_proposed >= n // 2:  # the previous rejuvenation ends here: judged if it made half a sweep
                concluded = pending.acceptance
            pending = pending.restarted(config.max_virtual if config.move == "stretch" else config.max_moves, n)
        moves, spent = staged.moves, staged.spent
        if pending.pending:
            budget = (sys.maxsize if config.move_budget is None  # None: the rejuvenation completes in this update
                      else int(config.move_budget * n * int(getattr(self.inner, "n_inner", 1))))
            was_pending = pending.n_proposed
            # a tempered update completes its moves (each exponent is chosen from the particles' ESS, which
            # copies overstate); an untempered one first brings the copies back to the ESS the weights had
            # before the resampling, then defers what exceeds the budget
            # (with strict_budget, a tempered update too: its stages share one budget, restoring included)
            tempered = beta < 1.0 or stage.index > 1
            allowed = sys.maxsize if tempered and not config.strict_budget else budget
            static, cloud, components, sweep, step_size, batches, pending = rejuvenate(
                self.problem, config, self.inner, self.split, weighed.datasets, weighed.guides, static,
                log_weights, cloud, components, beta, moves.step_size, pending, allowed, likelihood, rng,
                restore=stage.ess / n if resampled else 0.0, spent=spent if config.strict_budget else 0,
                restore_limit=1.0 if config.strict_budget else RESTORE_LIMIT)
            spent += sweep.n_evaluations * rerun_cost(self.inner, weighed.datasets)   # the budget's units: M s per re-run
            moves = MoveTally(moves.stats + sweep, step_size if config.move == "stretch" else moves.step_size,
                              moves.n_virtual + batches)
            if not pending.pending and pending.n_proposed > was_pending:
                concluded = pending.acceptance
        outer = OuterCloud(static, log_weights, components, inner=cloud, pending=pending, concluded=concluded)
        return _Rejuvenating(outer, moves, spent, resampled), components[:, 0], log_weights, None

    def estimate(self, tempered, weighed, likelihood, rng) -> Estimate:
        """The tempering path's estimate (Eq. 1): the likelihood estimates are unbiased, so is it."""
        return Estimate(tempered.cloud, tempered.log_z, float("nan"), 0, False, tempered.moves)

    def propagate(self, state, weighed, tempered, estimate, dataset, likelihood, rng) -> Outcome:
        """One joint draw per outer particle (its drifting values from its inner filter), propagated; the record's
        moments are Rao-Blackwellised over every inner filter (:func:`nested_moments`)."""
        kernel, split, config = self.problem.kernel, self.split, self.config
        outer = estimate.cloud
        static, cloud, components, log_weights = outer.particles, outer.inner, outer.components, outer.log_weights
        if static.shape[1] == kernel.dim:  # the outer particles hold every column: replace the drifting ones
            posterior = static.copy()
            posterior[:, split[1]] = self.inner.draws(cloud, rng)
        else:
            posterior = _joint(static, self.inner.draws(cloud, rng), split, kernel.dim)
        log_evidence = float(state.log_evidence + estimate.log_increment)
        conflict = prior_data_conflict(state.prior_draws, state.log_weights, posterior, log_weights)
        predictive = kernel.propagate(posterior, rng)
        step_size = estimate.moves.step_size
        pending, step = outer.pending, state.step + 1
        n_evals_total = state.n_evals_total + likelihood.n_evals
        moments = nested_moments(posterior, log_weights, self.inner.moments(cloud), split[1])
        new_state = NestedState(step, static, cloud, log_weights, components[:, 1],
                                components[:, 2] + components[:, 0], weighed.datasets, log_evidence, float(step_size),
                                posterior, predictive, weighed.guides, pending, n_evals_total, moments)
        # a rejuvenation the budget spreads over many updates concludes rarely: judge it by its running acceptance
        # once it has proposed enough to tell 0.2 from well above it (50: binomial se 0.06), while it still runs
        running = not np.isfinite(outer.concluded) and pending.n_proposed >= MIN_RUNNING_PROPOSALS
        warn_rejuvenation(step, pending.acceptance if running else outer.concluded, weighed.inner_ess,
                          len(weighed.datasets), int(getattr(self.inner, "n_inner", 0)), running)
        fields = dict(prior_data_conflict=float(conflict.max()), conflict_parameter=int(conflict.argmax()),
                      inner_ess=weighed.inner_ess, amortised_evals=n_evals_total / step,
                      pmmh_acceptance=pending.acceptance if pending.n_proposed else outer.concluded,
                      pending_moves=int(pending.queue.size + pending.sweeps_left * config.n_samples))  # at most
        return Outcome(new_state, posterior, log_weights, predictive, static, log_evidence,
                       float(step_size) if config.move == "stretch" else float("nan"), fields, moments=moments)


#: A rejuvenation whose PMMH acceptance ends below this draws a warning: the inner likelihood estimates are too
#: noisy for the moves to keep the outer particles diverse at a bounded cost.
LOW_ACCEPTANCE = 0.2
#: Proposals a running (not yet concluded) rejuvenation needs before its acceptance draws that warning.
MIN_RUNNING_PROPOSALS = 50


def warn_rejuvenation(step: int, acceptance: float, inner_ess: float, n_datasets: int, n_inner: int,
                      running: bool = False) -> None:
    """One line when a rejuvenation ended with a PMMH acceptance below :data:`LOW_ACCEPTANCE`, or (``running``) one
    that the move budget carries over updates is below it so far, saying what to change."""
    if not acceptance < LOW_ACCEPTANCE:
        return
    advice = (f"raise n_inner (now {n_inner}; the variance of the inner filters' log-likelihood estimates grows "
              f"like s / n_inner, so doubling n_inner halves it)" if n_inner else "the Kalman inner filter is exact: the static parameters' proposal is "
              "too wide; use SEMC, whose step size adapts")
    if n_inner and inner_ess < 0.1:
        advice += (f"; the inner filters keep only {100 * inner_ess:.0f} % of their particles per step, so a kernel "
                   f"noise closer to the drift the data show, or a KalmanInnerFilter if the model is linear-Gaussian "
                   f"in the drifting parameters, pays more than n_inner")
    which = ("so far in the rejuvenation that the move budget spreads over updates" if running
             else "over the last rejuvenation")
    warnings.warn(f"step {step}: SMC^2's PMMH moves accepted {100 * acceptance:.0f} % of proposals {which} (at s = "
                  f"{n_datasets}); each accepted move costs ~{1 / max(acceptance, 1e-3):.0f} "
                  f"re-runs of an inner filter over the whole history: {advice}", InnerFilterWarning, stacklevel=2)


def nested_moments(posterior: np.ndarray, log_weights: np.ndarray,
                   inner_moments: tuple[np.ndarray, np.ndarray] | None, drifting: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The posterior's mean and sd ``(d,)``, the drifting columns Rao-Blackwellised: from each outer particle's whole
    inner filter (its weighted mean and variance ``inner_moments``, each ``(N, d_x)``) instead of its one draw.

    ``E[x] = sum_i W_i m_i`` and ``Var[x] = sum_i W_i (v_i + m_i^2) - E[x]^2`` (the law of total variance);
    ``inner_moments=None``: every column from the draws."""
    w = np.exp(log_weights - log_weights.max())
    w /= w.sum()
    mean = w @ posterior
    var = w @ (posterior - mean) ** 2
    if inner_moments is None:
        return mean, np.sqrt(var)
    m, v = inner_moments
    mean[drifting] = w @ m
    var[drifting] = np.maximum(w @ (v + (m - mean[drifting]) ** 2), 0.0)
    return mean, np.sqrt(var)


class JointFirstStep(ParticlePredictive):
    """SMC^2's first dataset with a particle inner filter (``joint_first_step``): with no dynamics yet, a static
    step in every parameter, whose particles then seed the outer particles and their inner filters."""

    def next_prior(self, state, cloud, dataset, log_increment, log_evidence, rng):
        return None, self.problem.kernel.propagate(cloud.particles, rng), None

    def propagate(self, state, weighed, tempered, estimate, dataset, likelihood, rng) -> Outcome:
        outcome = super().propagate(state, weighed, tempered, estimate, dataset, likelihood, rng)
        cloud = estimate.cloud
        nested = after_joint_first_step(nested_split(self.problem.kernel), self.problem.inner_filter.n_inner,
                                        cloud.particles, cloud.log_weights, cloud.components, dataset,
                                        outcome.log_evidence, outcome.state.step_size, cloud.particles,
                                        outcome.predictive, likelihood.n_evals)
        moments = nested_moments(outcome.posterior, outcome.log_weights, None, np.zeros(0, dtype=int))
        fields = dict(outcome.fields, amortised_evals=float(likelihood.n_evals))
        return replace(outcome, state=replace(nested, moments=moments), fields=fields, moments=moments)


def nested_state_arrays(state: NestedState) -> dict:
    """The arrays that, with the datasets, rebuild ``state`` (:func:`nested_state_from_arrays`), for the
    run store: every value is a float array; the inner filter's cloud keys are prefixed ``cloud_``."""
    out = {"outer": state.outer, "log_weights": state.log_weights, "log_prior": state.log_prior,
           "log_likelihood": state.log_likelihood, "particles": state.particles,
           **({"predictive": state.predictive} if state.predictive is not None else {}),
           "scalars": np.array([state.step, state.log_evidence, state.step_size], dtype=float)}
    out.update({f"cloud_{key}": value for key, value in state.cloud.items()})
    d_x = (state.cloud["x"] if "x" in state.cloud else state.cloud["mean"]).shape[-1]  # drifting parameters
    guide = state.guides[-1] if state.guides else None
    out["guide_used"] = np.array(float(guide is not None))  # this step's guide only: the store keeps every step
    out["guide_mean"] = guide[0] if guide is not None else np.zeros(d_x)
    out["guide_cov"] = guide[1] if guide is not None else np.zeros((d_x, d_x))
    pending = state.pending  # the queue padded with -1 to a fixed (N,), so that every step's arrays have one shape
    queue = np.full(state.log_weights.size, -1.0)
    queue[:pending.queue.size] = pending.queue
    out["pmmh_queue"] = queue
    out["pmmh_tally"] = np.array([pending.sweeps_left, pending.n_proposed, pending.n_accepted, state.n_evals_total])
    out["pmmh_moved"] = pending.moved if pending.moved.size else np.zeros(queue.size, dtype=bool)
    out["moments"] = np.vstack(state.moments if state.moments is not None
                               else nested_moments(state.particles, state.log_weights, None, np.zeros(0, dtype=int)))
    return {key: np.asarray(value, dtype=float) for key, value in out.items()}


def nested_guide(arrays: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """The guide of the step whose :func:`nested_state_arrays` are ``arrays`` (``None`` if unguided)."""
    if "guide_used" not in arrays or not float(arrays["guide_used"]):
        return None
    return np.array(arrays["guide_mean"]), np.array(arrays["guide_cov"])


def nested_state_from_arrays(arrays: dict, datasets: tuple, guides: tuple = ()) -> NestedState:
    """The inverse of :func:`nested_state_arrays`; ``datasets`` are ``D^1 .. D^s`` and ``guides`` the
    guides of steps ``1 .. s - 1`` (:func:`nested_guide` of their arrays)."""
    step, log_evidence, step_size = np.asarray(arrays["scalars"], dtype=float)
    if int(step) != len(datasets):
        raise ValueError(f"datasets: {len(datasets)} datasets for a state at step {int(step)}")
    cloud = {key[len("cloud_"):]: np.array(value) for key, value in arrays.items() if key.startswith("cloud_")}
    if len(guides) != int(step) - 1:
        raise ValueError(f"guides: {len(guides)} guides for a state at step {int(step)} (expected {int(step) - 1})")
    pending, n_evals_total = Rejuvenation(), 0
    if "pmmh_queue" in arrays:  # stores written before issue 23 have no pending moves
        queue = np.asarray(arrays["pmmh_queue"], dtype=float)
        sweeps_left, n_proposed, n_accepted, n_evals_total = (int(v) for v in np.asarray(arrays["pmmh_tally"]))
        moved = np.asarray(arrays.get("pmmh_moved", np.zeros(queue.size)), dtype=float) > 0
        pending = Rejuvenation(queue[queue >= 0].astype(int), sweeps_left, n_proposed, n_accepted, moved)
    moments = nested_record_moments(arrays)
    return NestedState(int(step), np.array(arrays["outer"]), cloud, np.array(arrays["log_weights"]),
                       np.array(arrays["log_prior"]), np.array(arrays["log_likelihood"]), tuple(datasets),
                       float(log_evidence), float(step_size), np.array(arrays["particles"]),
                       np.array(arrays["predictive"]) if "predictive" in arrays else None,
                       tuple(guides) + (nested_guide(arrays),), pending, n_evals_total, moments)


def nested_record_moments(arrays: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """The Rao-Blackwellised ``(mean, sd)`` kept in a step's :func:`nested_state_arrays` (``None`` if not kept)."""
    moments = np.asarray(arrays.get("moments", np.nan), dtype=float)
    if moments.ndim != 2 or not np.all(np.isfinite(moments)):
        return None
    return moments[0].copy(), moments[1].copy()

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from typing import Any

    from ..core.state import Problem
