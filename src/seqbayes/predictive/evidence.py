"""Evidence of one step by defensive importance sampling from the posterior.

The tempering path gives ``log p(D^s | D^{1:s-1})`` as a by-product (Eq. 1),
but its estimate is only as good as the mixing of every intermediate stage:
when a tempered target is a funnel (a noise std over three decades and the
parameter it scales, as in the Coulomb-friction problem) the moves miss mass and
the path estimate comes out several nats low although the final posterior is
right. This module estimates the same increment from the final posterior:

    Z = E_q[ L(theta(u)) p_s(theta(u)) |d theta / d u| / q(u) ]

with ``q`` fitted to the posterior particles in unconstrained coordinates ``u``
(:class:`~seqbayes.priors.BoxTransform`): half a Gaussian kernel density of
the distinct particles (follows several modes; beyond ``MAX_PROPOSAL_COMPONENTS`` = 1000
distinct particles, of 1000 of them chosen by systematic selection, so that the cost stays
``O(N)``: the proposal need not be exact, only the target), half a multivariate Student t
(nu = 4) with twice the posterior covariance (heavy tails, so the weights have
finite variance). The effective sample size of the importance weights is
returned as a diagnostic.

The same draws then serve as proposals of an independence Metropolis-Hastings
sweep over the particles (accept with ``min(1, w(new) / w(old))``, ``w = pi / q``).
For the sweep to leave the posterior invariant ``q`` must not depend on the
particles it moves: each half of the particles proposes from the ``q`` fitted to
the other half (:func:`~seqbayes.moves.proposals.complement_halves`), and the
evidence pools the two halves' draws, each term an unbiased estimate of ``Z``.
The sweep costs no extra likelihood evaluation and moves particles across a
funnel that the local moves cross slowly. Why by hand: no library offers defensive importance sampling
against an arbitrary vectorised prior density.

Two clouds of the same posterior (the conflict remedy's bridge and stored-path
start, :func:`seqbayes.predictive.transition.PathSpace`) are pooled: :func:`clustered_parts`
fits one defensive proposal per k-means cluster of each (SciPy's ``kmeans2``),
:func:`pooled_start` gives each cluster its importance-sampling share of the mass,
and :func:`importance_step` sweeps with the :class:`PooledProposal` of all of them.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from ..core.state import Cloud
from ..moves import metropolis_accept
from ..moves.proposals import DefensiveProposal, PooledProposal, clustered_parts, complement_halves
from ..priors import inside_support
from ..weights import resample
from ..priors import BoxTransform
from ..weights import logsumexp, normalise
from ..moves.base import HIGH_DIMENSION

__all__ = ["Importance", "PathEvidence", "Precision", "importance_step", "pooled_start", "step_standard_errors",
           "STARVED_RESTART"]

#: ``economy``: the importance sweeps continue until the increment's standard error is below this.
ECONOMY_EVIDENCE_SE = 0.02
#: Fewest distinct draws, as a fraction of N, a restart from the restricted prior may rest on: below it the
#: step's evidence and posterior rest on a handful of draws of the prior's far tail.
STARVED_RESTART = 0.1



def _target_at(draws, transform, support, loglike, prior_logpdf):
    """The target at proposal draws ``(M, d)`` in unconstrained coordinates: the draws in the parameter space
    ``theta``, which of them are inside, their components ``(log L, log p)`` (``(M, 2)``, -inf outside) and
    ``log target = log L + log p + log |d theta / d u|`` (-inf outside or where NaN)."""
    n = draws.shape[0]
    theta = transform.inverse(draws)
    inside = inside_support(theta, support) & np.isfinite(theta).all(axis=1)
    components = np.full((n, 2), -np.inf)
    log_target = np.full(n, -np.inf)
    if inside.any():
        ti = theta[inside]
        components[inside] = np.column_stack([loglike(ti), prior_logpdf(ti)])
        log_target[inside] = components[inside].sum(axis=1) + transform.log_jacobian(draws[inside])
    log_target[np.isnan(log_target)] = -np.inf
    return theta, inside, components, log_target


#: How much more the first cloud of :func:`pooled_start` is trusted where the clouds overlap (a factor on its parts'
#: responsibilities): its particles keep a mode that both hold, another cloud's fill only what it lacks.
FIRST_CLOUD_PREFERENCE = 30.0


def pooled_start(clouds, prior_logpdf, loglike, support, rng, gaussian: bool = False, n: int | None = None):
    """One cloud of ``n`` particles from several clouds of the same posterior, each cluster of each given its share
    of the mass.

    Two samplers of one posterior may each hold a different mode, weigh two modes differently, or one may be
    trapped in a minor one (on the path space: the bridge from the path prior and the start from the stored
    paths, :func:`seqbayes.predictive.transition.PathSpace`). The share of each part of the
    :class:`PooledProposal` ``q = sum_c alpha_c q_c`` fitted to the clusters of the clouds
    (:func:`clustered_parts`) is estimated by importance sampling: N draws of ``q``, weights ``w = pi / q``,
    and part ``c``'s share is ``sum w r_c / sum w`` with ``r_c`` the draw's responsibility, ``alpha_c q_c / q``
    with the first cloud's parts' terms multiplied by ``FIRST_CLOUD_PREFERENCE``: where the clouds overlap the
    first one's particles carry the mass, and another's only where the first has none. The first cloud is the
    one trusted within a mode (the bridge; the stored paths' start tempers one dataset only, and an even split of
    the mass carried its offset within the shared mode into the start). The particles, each weighted by its part's share times
    its own weight within the part, are resampled (systematic) to N. The independence sweeps of
    :func:`importance_step` then correct what the shares leave off (the start is only an approximation; the
    sweeps leave the posterior invariant).

    Parameters
    ----------
    clouds : sequence of (points (M_i, d), log_weights (M_i,))
        The clouds.
    prior_logpdf, loglike, support, rng, gaussian
        As :func:`importance_step`.
    n : int, optional
        The particles returned (and the importance draws that weigh the parts); the first cloud's size by default.

    Returns
    -------
    index : (n,) array of int
        Indices into the clouds' concatenation.
    shares : (K,) array
        The parts' estimated shares (each part its cloud's weight when no draw has a finite target).
    """
    n = clouds[0][0].shape[0] if n is None else int(n)
    transform = BoxTransform(support)
    parts, part_log_weights, members = clustered_parts(
        [(transform.forward(points), log_weights) for points, log_weights in clouds], rng, gaussian)
    q = PooledProposal(parts, part_log_weights)
    draws = q.sample(n, rng)
    by_part = q.part_logpdfs(draws)
    log_w = _target_at(draws, transform, support, loglike, prior_logpdf)[3] - logsumexp(by_part, axis=0)
    if np.isfinite(logsumexp(log_w)):
        preferred = by_part + np.log(FIRST_CLOUD_PREFERENCE) * np.array([c == 0 for c, _ in members])[:, None]
        responsibilities = preferred - logsumexp(preferred, axis=0)
        shares = np.exp(logsumexp(responsibilities + log_w, axis=1) - logsumexp(log_w))
    else:
        shares = np.exp(q.log_weights)
    offsets = np.cumsum([0] + [points.shape[0] for points, _ in clouds])
    weights = np.zeros(offsets[-1])
    for share, (c, member) in zip(shares, members):
        within = np.exp(normalise(clouds[c][1][member]))
        weights[offsets[c]:offsets[c + 1]][member] = share * within
    return resample("systematic", weights / weights.sum(), rng, n), shares


@dataclass(frozen=True)
class Precision:
    """Economy's evidence sweeps (``SamplerConfig.economy``; :func:`importance_step`): sweeps continue while the
    pooled estimate's standard error exceeds ``se``, up to ``max_sweeps``, and while the pooled ESS is at least
    ``min_fraction`` of the draws."""

    se: float
    max_sweeps: int | None = None
    min_fraction: float = 0.0


def importance_step(posterior, log_weights, components, prior_logpdf, loglike, support, rng, n_sweeps: int = 1,
                    gaussian: bool = False, until: Precision | None = None, other=None, pool_sweeps: bool = False):
    """Evidence by defensive importance sampling, then independence-MH sweeps with the same proposal.

    Parameters
    ----------
    posterior : (N, d) array
        Posterior samples of ``L(theta) p(theta)`` (the step's final particles).
    log_weights : (N,) array
    components : (N, 2) array
        ``(log L, log p)`` at ``posterior``.
    prior_logpdf : callable ``(M, d) -> (M,)``
        The step's prior density ``p`` (untruncated).
    loglike : callable ``(M, d) -> (M,)``
        The step's log-likelihood (NaN already mapped to ``-inf``).
    support : (d, 2) array
        Parameter space; the likelihood is zero outside.
    rng : numpy.random.Generator
    n_sweeps : int
        Independence sweeps, each with N fresh draws, half from the proposal fitted to each half of the
        particles (:func:`~seqbayes.moves.proposals.complement_halves`); the first sweep's draws give the evidence
        (every sweep's with ``pool_sweeps`` or ``until``).
    gaussian : bool
        The proposal's first half is the fitted Gaussian instead of the kernel density (:func:`_proposal`).
    until : Precision, optional
        Economy (``SamplerConfig.economy``): every sweep's draws enter the evidence (one importance
        estimate over all of them, as they are independent draws of the same proposal), and sweeps continue
        after ``n_sweeps`` while the estimate's standard error ``sqrt(1 / ESS - 1 / M)`` (M draws)
        exceeds ``until.se``, up to ``until.max_sweeps``, and while the pooled ESS is at least
        ``until.min_fraction`` of the draws (below it the caller refits the proposal rather than pool a poor
        one's draws).
    other : tuple of (M, d) array and (M,) array, optional
        Another cloud of the same posterior (points, log-weights), which may hold a mode ``posterior``
        lacks: the proposal is then the :class:`PooledProposal` of both (:func:`clustered_parts`).
    pool_sweeps : bool
        Every sweep's draws enter the evidence, as with ``until`` but without sweeps beyond ``n_sweeps``
        (each sweep's terms are unbiased given its proposal, which is fitted before its draws), and the ESS is
        reported as with ``until``.

    Returns
    -------
    log_evidence : float
    ess : float
        Effective sample size of the first sweep's importance weights (out of N); with ``until``,
        the pooled estimate's equivalent for N draws, ``1 / (1 / ESS_M - 1 / M + 1 / N)``, which has the
        same variance ``1 / ESS - 1 / N``.
    posterior, components : arrays after the sweeps
    n_accepted : int
        Particle moves accepted over all sweeps.
    """
    n = posterior.shape[0]
    se_target, max_sweeps, min_fraction = (None, None, 0.0) if until is None else (until.se, until.max_sweeps,
                                                                                   until.min_fraction)
    transform = BoxTransform(support)
    u = transform.forward(posterior)
    other_u = None if other is None else (transform.forward(other[0]), other[1])

    def fitted(part):
        # the proposal of the other half's particles (complement_halves: one fitted to the particles it moves is
        # not an exact kernel); `other` is fixed during the sweeps, so its part of q may stay
        weights = log_weights[part] if np.isfinite(logsumexp(log_weights[part])) else np.zeros(part.size)
        if other_u is None:
            return DefensiveProposal(u[part], weights, gaussian=gaussian)
        return PooledProposal(*clustered_parts([(u[part], weights), other_u], rng, gaussian)[:2])

    posterior, components = posterior.copy(), components.copy()
    log_target = components.sum(axis=1) + transform.log_jacobian(u)  # in u, at the particles
    log_evidence, ess, n_accepted = -np.inf, 0.0, 0
    pool_sweeps = pool_sweeps or se_target is not None
    pooled = []
    sweep = 0
    while sweep < n_sweeps or (se_target is not None and sweep < max(max_sweeps or 0, n_sweeps)
                               and ess >= min_fraction * n * sweep  # a poor fit: refit rather than pool
                               and np.sqrt(max(1.0 / max(ess, 1e-300) - 1.0 / (n * sweep), 0.0)) > se_target):
        terms = []
        for active, passive in complement_halves(n, rng):  # none for one particle (the caller falls back to the path)
            q = fitted(passive)
            draws = q.sample(active.size, rng)
            theta, inside, new_components, new_target = _target_at(draws, transform, support, loglike, prior_logpdf)
            log_terms = new_target - q.logpdf(draws)  # log(target / q): each an unbiased estimate of Z
            terms.append(log_terms)
            # independence Metropolis-Hastings with w = target / q (q is independent of the active half)
            accept = metropolis_accept(log_target[active] - q.logpdf(u[active]), log_terms, np.zeros(active.size),
                                       rng) & inside
            moved = active[accept]
            posterior[moved], components[moved] = theta[accept], new_components[accept]
            u[moved], log_target[moved] = draws[accept], new_target[accept]
            n_accepted += int(accept.sum())
        if sweep == 0 or pool_sweeps:
            pooled.extend(terms)
            every = np.concatenate(pooled) if pooled else np.full(1, -np.inf)
            total = logsumexp(every)
            if not np.isfinite(total):
                if sweep == 0:
                    return -np.inf, 0.0, posterior, components, 0
            else:
                ess = float(np.exp(2.0 * total - logsumexp(2.0 * every)))  # of M = every.size draws
                log_evidence = float(total - np.log(every.size))
        sweep += 1
    if pool_sweeps and ess > 0:
        # the ESS that N draws would need for the pooled estimate's variance 1 / ESS - 1 / M: the caller's
        # refit rule and standard error (1 / ESS - 1 / N, step_standard_errors) then stay valid
        ess = 1.0 / (1.0 / ess - 1.0 / (n * sweep) + 1.0 / n)
    return log_evidence, ess, posterior, components, n_accepted




def step_standard_errors(previous_variance: float, n_samples: int, importance: bool, evidence_ess: float,
                         weights_before, log_weights_after, n_stages: int, resampled: bool, ancestor_variance: float,
                         method: str, ancestor_covariance: float = 0.0) -> tuple[float, float, float]:
    """Standard errors of one step's log-evidence increment and of the cumulative log-evidence.

    Delta method: an average ``Z_hat = sum_i W_i l_i`` of independent terms has
    ``var(log Z_hat) ~ sum_i W_i^2 (l_i / Z_hat - 1)^2``. Hence:

    * the importance-sampling increment (N independent draws from the fitted proposal, equal
      weights): ``1 / ESS - 1 / N`` with ``ESS = evidence_ess``;
    * an increment from the carried weights ``W`` in one stage without resampling: with ``W'`` the
      weights after the step's reweighting, ``W'_i = W_i l_i / Z_hat``, the variance is
      ``sum_i (W'_i - W_i)^2``;
    * a prior that is a mixture over the last posterior's N particles (Eq. A3, ``"transition"``
      or ``"kde"``) adds to the importance increment the error of that particle approximation,
      ``ancestor_variance``, the sum of two terms computed by the caller
      (:func:`seqbayes.predictive.lineage.ancestor_terms`):

      - the last posterior's particles: ``Z_s = sum_j W_j g_j`` (``g_j`` the evidence through
        ancestor ``j``) has relative variance ``sum_j W_j^2 (g_j / Z_s - 1)^2 = sum_j (a_j - W_j)^2``,
        ``a_j = W_j g_j / Z_s`` the posterior probability of ancestor ``j``, for independent ancestors.
        Ancestors that descend from one initial draw of their step (copies made by resampling) are
        not independent: their terms are summed per draw first, ``sum_e (A_e - V_e)^2`` (the
        genealogy estimator of Chan & Lai 2013 and Lee & Whiteley 2018, as Du & Guyader 2021 use it
        for adaptive SMC with MCMC moves; :meth:`~seqbayes.predictive.mixture.GaussianMixture.ancestor_spread`,
        labels in :attr:`~seqbayes.core.state.RemedyMemory.lineage`). With distinct labels and equal
        weights it is ``1 / ESS_a - 1 / N``.
      - the posterior's before, through the mixture the last step used: ``Z_s`` is the ratio of the
        two- and one-step evidence through those particles, which makes consecutive increments'
        errors negatively correlated; its term is ``sum_j (b_j - a'_j)^2``, with ``b_j`` and ``a'_j`` the
        masses that the posteriors of steps ``s`` and ``s - 1`` give to particle ``j`` of step ``s - 2``,
        computed backwards through the exact responsibilities
        (:meth:`~seqbayes.predictive.mixture.GaussianMixture.backward_spread`). The lag is fixed at two steps, as in
        the fixed-lag variance estimator of Olsson & Douc (2019), so it does not degenerate over many steps.

      (The carried-weights increment already contains it: each prior particle is a draw through its own
      ancestor.)

    The cumulative variance adds the increment's and twice ``ancestor_covariance``, the covariance of
    this increment's error with the last one's through the particles of step ``s - 2``
    (:meth:`~seqbayes.predictive.mixture.GaussianMixture.backward_spread`); without it the sum of the increments'
    variances over-stated the cumulative one by up to 1.36x on the drifting Kalman problem (benchmarks
    "evidence se"). With the history prior (``"history"``, the exact prior ``p_0 prod_{k<s} L_k / Z_hat_{1:s-1}``)
    an importance step estimates the whole ``Z_{1:s}`` afresh (``Z_hat_{1:s-1}`` cancels), so the cumulative
    variance restarts from its own (and the increment's is its own plus the previous cumulative one); the
    reweighting steps after it form with it one importance estimate with the accumulated weights,
    whose variance grows by ``1 / ESS' - 1 / ESS`` per step. A multi-stage tempering path
    (``evidence="path"``) is not covered (NaN), nor is SMC^2.

    Parameters
    ----------
    previous_variance : float
        The cumulative variance before the step (0 before the first).
    n_samples : int
    importance : bool
        Whether the increment came from the importance sampler.
    evidence_ess : float
        ESS of the importance weights.
    weights_before : (N,) array
        The carried normalised weights ``W`` before the step's reweighting.
    log_weights_after : (N,) array
        The normalised log-weights at the end of the step.
    n_stages : int
    resampled : bool
        Whether the step's last stage resampled.
    ancestor_variance : float
        NaN for a prior that is not a mixture over the last posterior's particles.
    method : str
        The resolved predictive.
    ancestor_covariance : float
        Covariance of this increment's error with the last one's (0: none).

    Returns
    -------
    increment_se, cumulative_se, cumulative_variance : float
        The variance is what the next step continues from (``SamplerState.log_evidence_variance``).

    References
    ----------
    Chan, H. P. & Lai, T. L. (2013). A general theory of particle filters in hidden Markov models and some
    applications. Annals of Statistics 41(6).
    Lee, A. & Whiteley, N. (2018). Variance estimation in the particle filter. Biometrika 105(3).
    Olsson, J. & Douc, R. (2019). Numerically stable online estimation of variance in particle filters.
    Bernoulli 25(2).
    Du, Q. & Guyader, A. (2021). Variance estimation in adaptive sequential Monte Carlo. Annals of Applied
    Probability 31(3).
    """
    n = float(n_samples)
    history = method == "history"
    if importance:
        variance = max(1.0 / evidence_ess - 1.0 / n, 0.0)
        if history:
            increment, cumulative = variance + previous_variance, variance
        else:
            covariance = 0.0
            if np.isfinite(ancestor_variance):
                variance += max(ancestor_variance, 0.0)
                covariance = float(ancestor_covariance) if np.isfinite(ancestor_covariance) else 0.0
            # a covariance estimate can overshoot: the cumulative variance never falls below this step's importance term's
            increment = variance
            cumulative = max(previous_variance + variance + 2.0 * covariance, max(1.0 / evidence_ess - 1.0 / n, 0.0))
    elif n_stages == 1 and not resampled:
        before, after = np.asarray(weights_before, dtype=float), np.exp(log_weights_after)
        increment = float(np.sum((after - before) ** 2))
        # history: the accumulated weights' variance 1 / ESS - 1 / N replaces the one before
        cumulative = previous_variance + (np.dot(after, after) - np.dot(before, before) if history else increment)
    else:
        return float("nan"), float("nan"), float("nan")
    return float(np.sqrt(increment)), float(np.sqrt(cumulative)), float(cumulative)


@dataclass(frozen=True)
class PathEvidence:
    """The evidence increment from the tempering path alone: the stages' product of mean weights (Eq. 1, the
    paper's estimate)."""

    importance = False

    def estimate(self, cloud, log_increment_path, n_found, problem, config, likelihood, prior_logpdf, rng, other=None,
                 pool_sweeps: bool = False):
        """The path's increment: ``(cloud, log_increment_path, NaN, 0)`` (the arguments as :meth:`Importance.estimate`)."""
        return cloud, log_increment_path, float("nan"), 0


@dataclass(frozen=True)
class Importance:
    """The evidence increment by defensive importance sampling from the final posterior (the module docstring; N extra
    likelihood evaluations per sweep, whose draws also drive independence-MH sweeps of the particles). The path's
    estimate (Eq. 1) is kept as ``StepInfo.log_evidence_increment_path``.

    Parameters
    ----------
    sweeps : int
        Independence sweeps per fitted proposal (3).
    min_ess : float
        A fit whose importance ESS is below this fraction of N is refitted to the swept particles (0.3).
    max_refits : int
        At most this many refits (5); when none reaches ``min_ess`` the fits' estimates are pooled by their ESS.
    """

    sweeps: int = 3
    min_ess: float = 0.3
    max_refits: int = 5

    importance = True

    def __post_init__(self):
        if isinstance(self.sweeps, bool) or int(self.sweeps) != self.sweeps or self.sweeps < 1:
            raise ValueError(f"sweeps: must be an integer >= 1, got {self.sweeps}")
        if not 0.0 <= self.min_ess <= 1.0:
            raise ValueError(f"min_ess: must lie in [0, 1], got {self.min_ess}")
        if isinstance(self.max_refits, bool) or int(self.max_refits) != self.max_refits or self.max_refits < 0:
            raise ValueError(f"max_refits: must be an integer >= 0, got {self.max_refits}")

    def estimate(self, cloud, log_increment_path, n_found, problem, config, likelihood, prior_logpdf, rng, other=None,
                 pool_sweeps: bool = False):
        """Stage 5: the evidence increment, by defensive importance sampling from the final posterior (its draws
        drive independence-MH sweeps; ``n_found`` the distinct restart draws, ``config`` the sampler's settings,
        whose ``n_samples`` and moves it follows).

        ``other``: another :class:`Cloud` of the same target. The N particles then start from the union of the two (of any
        sizes), each cluster of each given its estimated share of the mass (:func:`~seqbayes.predictive.evidence.pooled_start`),
        and every proposal is fitted to the clusters of both (:class:`~seqbayes.moves.proposals.PooledProposal`).
        ``pool_sweeps``: every independence sweep's draws enter each fit's estimate (:func:`importance_step`).

        When no fit reaches ``min_evidence_ess`` the estimates of all the fits are pooled, each weighted by its ESS
        (each is unbiased for ``Z``, its variance ~ ``Z^2 / ESS``): the last fit alone can be as poor as any.

        Returns the cloud after the sweeps, the increment, the importance ESS and the sweeps' accepted moves."""
        n, step, moves = config.n_samples, likelihood.step, config.moves
        n_independent = 0
        scaled = {}  # the defaults' proposal and single-sweep estimate, unchanged up to d = 10
        if moves.uses_scaled(cloud.particles.shape[1]):
            scaled["gaussian"] = cloud.particles.shape[1] > HIGH_DIMENSION
            if moves.economy:
                scaled["until"] = Precision(ECONOMY_EVIDENCE_SE, self.sweeps + 2 * self.max_refits, self.min_ess)
        # economy: the first n_independent sweeps only move the particles (a fit to the cut-short moves' cloud can be
        # poor); q is refitted to the swept particles for the estimate (docs/core.md, "Economy of likelihood calls")
        if other is not None:
            index, _ = pooled_start([(c.particles, c.log_weights) for c in (cloud, other)], prior_logpdf,
                                    likelihood.loglike, problem.support, rng, scaled.get("gaussian", False), n)
            labels = None
            if cloud.labels is not None and other.labels is not None:
                labels = np.concatenate([cloud.labels, other.labels + cloud.labels.max() + 1])[index]
            cloud = Cloud(np.concatenate([cloud.particles, other.particles])[index], np.full(n, -np.log(n)),
                           np.concatenate([cloud.components, other.components])[index], labels)
        also_fit = None if other is None else (other.particles, other.log_weights)  # half of every proposal
        particles, components = cloud.particles, cloud.components
        warm_up = 1 if moves.economy else 0
        reliable = max(10.0, 0.01 * n)  # the least ESS of an estimate used on its own (else the path's, below)
        estimates = []
        for attempt in range(warm_up + 1 + self.max_refits):
            # a poor fit (low ESS) still improves the particles through its independence sweeps: refit q to
            # them and estimate again (each q is independent of its own draws, so every estimate is valid)
            log_increment, evidence_ess, particles, components, accepted = importance_step(
                particles, cloud.log_weights, components, prior_logpdf, likelihood.loglike, problem.support, rng,
                self.sweeps, other=also_fit, pool_sweeps=pool_sweeps,
                **(scaled if attempt >= warm_up else {"gaussian": scaled.get("gaussian", False)}))
            n_independent += accepted
            if attempt >= warm_up:
                if evidence_ess >= self.min_ess * n:
                    break
                estimates.append((log_increment, evidence_ess))
        else:
            pooled = [(z, e) for z, e in estimates if np.isfinite(z) and e > 0]
            # only when one fit at least is reliable on its own: six fits of a collapsed posterior with ESS 2 each are
            # not one of ESS 12
            if len(pooled) > 1 and max(e for _, e in pooled) >= reliable:
                log_z, fit_ess = np.array(pooled).T
                total = float(fit_ess.sum())
                log_increment = float(logsumexp(log_z + np.log(fit_ess)) - np.log(total))
                # the N draws' equivalent of the pooled variance 1 / sum ESS - 1 / (K N), as importance_step's economy
                evidence_ess = 1.0 / (1.0 / total - 1.0 / (n * len(pooled)) + 1.0 / n)
        # A collapsed posterior cannot be fitted (tiny ESS), and one rebuilt from fewer than N / 10 restart draws
        # fits a proposal to duplicates whose ESS looks healthy: there, the rejection mass (path) is the estimate.
        if not evidence_ess >= reliable or n_found < STARVED_RESTART * n:
            warnings.warn(f"step {step}: importance-sampling evidence unreliable (ESS {evidence_ess:.1f} of {n}, "
                          f"{n_found} distinct restart draws); using the tempering path's estimate and the "
                          f"posterior may be degenerate", RuntimeWarning, stacklevel=4)
            log_increment = log_increment_path
        return Cloud(particles, cloud.log_weights, components, cloud.labels), log_increment, evidence_ess, n_independent
