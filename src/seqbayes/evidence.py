"""Evidence of one step by defensive importance sampling from the posterior.

The tempering path gives ``log p(D^s | D^{1:s-1})`` as a by-product (Eq. 1),
but its estimate is only as good as the mixing of every intermediate stage:
when a tempered target is a funnel (a noise std over three decades and the
parameter it scales, as in the Coulomb-friction problem) the moves miss mass and
the path estimate comes out several nats low although the final posterior is
right. This module estimates the same increment from the final posterior:

    Z = E_q[ L(theta(u)) p_s(theta(u)) |d theta / d u| / q(u) ]

with ``q`` fitted to the posterior particles in unconstrained coordinates ``u``
(:class:`~seqbayes.transforms.BoxTransform`): half a Gaussian kernel density of
the distinct particles (follows several modes; beyond ``MAX_PROPOSAL_COMPONENTS`` = 1000
distinct particles, of 1000 of them chosen by systematic selection, so that the cost stays
``O(N)``: the proposal need not be exact, only the target), half a multivariate Student t
(nu = 4) with twice the posterior covariance (heavy tails, so the weights have
finite variance). The effective sample size of the importance weights is
returned as a diagnostic.

The same draws then serve as proposals of an independence Metropolis-Hastings
sweep over the particles (further sweeps draw afresh from the same ``q``) (particle ``i`` proposes draw ``i``; accept with
``min(1, w(new) / w(old))``, ``w = pi / q``). The draws are independent of the
particles, so the sweep leaves the posterior invariant; it costs no extra
likelihood evaluation and moves particles across a funnel that the local moves
cross slowly. Why by hand: no library offers defensive importance sampling
against an arbitrary vectorised prior density.

Two clouds of the same posterior (the conflict remedy's bridge and stored-path
start, :func:`seqbayes.sequential.assimilate_paths`) are pooled: :func:`clustered_parts`
fits one defensive proposal per k-means cluster of each (SciPy's ``kmeans2``),
:func:`pooled_start` gives each cluster its importance-sampling share of the mass,
and :func:`importance_step` sweeps with the :class:`PooledProposal` of all of them.
"""

from __future__ import annotations

import inspect

import numpy as np
from scipy import stats
from scipy.cluster.vq import kmeans2

from .density import GaussianMixture, silverman_bandwidth
from .priors import inside_support
from .transforms import BoxTransform
from .moves import metropolis_accept
from .moves.scaled import FittedGaussian
from .resampling import resample
from .weights import logsumexp, normalise

__all__ = ["importance_step", "pooled_start", "clustered_parts", "step_standard_errors", "DefensiveProposal",
           "PooledProposal"]

_T_DOF = 4.0

#: kmeans2's keyword for the random generator: ``rng`` from SciPy 1.15, ``seed`` before (both take a Generator).
_KMEANS_RNG = "rng" if "rng" in inspect.signature(kmeans2).parameters else "seed"

#: Most kernel-density components of the proposal (see docs/core.md, "Cost per update").
MAX_PROPOSAL_COMPONENTS = 1000


def _thinned(points, log_weights, n_components):
    """At most ``n_components`` weighted centres representing the weighted ``points (N, d)``.

    Systematic selection with the fixed offset 1/2 (deterministic: no random draw, so the run's
    random stream does not depend on it), duplicates merged into their counts. With at most
    ``n_components`` points they are returned as they are.
    """
    if points.shape[0] <= n_components:
        return points, log_weights
    w = np.exp(normalise(log_weights))
    cumulative = np.cumsum(w)
    cumulative[-1] = 1.0
    index = np.searchsorted(cumulative, (np.arange(n_components) + 0.5) / n_components)
    index, counts = np.unique(index, return_counts=True)
    return points[index], np.log(counts.astype(float))


def _proposal(u, log_weights, n_components=None, gaussian=False):
    """The defensive proposal's two halves, fitted to ``u (N, d)``: a kernel density of at most
    ``n_components`` distinct particles (``O(N n_components)`` to evaluate at N draws, where the
    kernel density of all N particles cost ``O(N^2)``) and a multivariate Student t.

    ``gaussian=True`` replaces the kernel density by the Gaussian with the particles' mean and
    covariance (the scaled moves' choice, for high dimension: there a kernel density's bandwidth
    inflates every direction, at d = 50 by ~1.5x in variance, and its importance weights degenerate,
    while the fitted Gaussian bounds them by twice target / Gaussian)."""
    w = np.exp(normalise(log_weights))
    if gaussian:
        mean = w @ u
        cov = ((u - mean) * w[:, None]).T @ (u - mean)
        cov = cov + np.diag(1e-9 * np.maximum(np.diag(cov), 1e-24 * (1.0 + mean**2)))
        t = stats.multivariate_t(loc=mean, shape=2.0 * cov * (_T_DOF - 2.0) / _T_DOF, df=_T_DOF, allow_singular=True)
        return FittedGaussian(mean, cov), t
    distinct, inverse = np.unique(u, axis=0, return_inverse=True)
    inverse = np.asarray(inverse).reshape(-1)
    summed = np.bincount(inverse, weights=w, minlength=distinct.shape[0])
    keep = summed > 0
    distinct, log_w = _thinned(distinct[keep], np.log(summed[keep]), n_components or MAX_PROPOSAL_COMPONENTS)
    mean = w @ u
    cov = ((u - mean) * w[:, None]).T @ (u - mean)
    scale = np.maximum(np.diag(cov), 1e-24 * (1.0 + mean**2))
    cov = cov + np.diag(1e-9 * scale)  # keep it positive definite when a dimension is collapsed
    kde = GaussianMixture(distinct, silverman_bandwidth(distinct, log_w), log_w)
    t = stats.multivariate_t(loc=mean, shape=2.0 * cov * (_T_DOF - 2.0) / _T_DOF, df=_T_DOF, allow_singular=True)
    return kde, t


class DefensiveProposal:
    """The importance density: half the kernel density (or fitted Gaussian), half the Student t of
    :func:`_proposal`, fitted to the weighted points ``u (N, d)`` (unconstrained coordinates).

    Also the independence proposal of the economy setting's moves at d <= 10
    (:func:`seqbayes.sequential._scaled_moves`): it follows a funnel's shape where one Gaussian cannot.
    """

    def __init__(self, u, log_weights, gaussian: bool = False):
        self.dim = u.shape[1]
        self.kde, self.t = _proposal(u, log_weights, gaussian=gaussian)

    def logpdf(self, points) -> np.ndarray:
        """``(n,)`` log-density at ``points (n, d)``."""
        return np.logaddexp(np.log(0.5) + self.kde.logpdf(points), np.log(0.5) + self.t.logpdf(points))

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``(n, d)`` draws: a binomial split between the halves, in random order."""
        n_kde = int(rng.binomial(n, 0.5))
        draws = np.concatenate([self.kde.sample(n_kde, rng),
                                np.atleast_2d(self.t.rvs(size=n - n_kde, random_state=rng)).reshape(-1, self.dim)])
        return draws[rng.permutation(n)]  # the two halves in random order: the pairing in the sweeps is random


class PooledProposal:
    """A mixture of :class:`DefensiveProposal` s, each fitted to one cluster of one of several clouds of the same
    posterior (:func:`clustered_parts`).

    Two samplers of one posterior may each hold a different mode, or weigh two modes differently (on the path
    space: the bridge from the path prior and the start from the stored paths,
    :func:`seqbayes.sequential.assimilate_paths`). Fitted to both, the importance density covers both; its
    independence sweeps then move particles between the modes, which no local move does, and its estimate counts
    both modes' mass. One fit to a two-mode cloud would not do: its kernel bandwidth and its t's covariance come
    from the spread between the modes (run 9, T3, SEMC seed 5, step 5: importance ESS 3-9 of 1000).

    Parameters
    ----------
    parts : sequence of DefensiveProposal
    log_weights : (K,) array
        The parts' log-weights in the mixture (normalised here).
    """

    def __init__(self, parts, log_weights):
        self.parts = tuple(parts)
        self.log_weights = normalise(np.asarray(log_weights, dtype=float))
        self.dim = self.parts[0].dim

    def part_logpdfs(self, points) -> np.ndarray:
        """``(K, n)``: each part's log-density plus its log-weight at ``points (n, d)``."""
        return np.stack([part.logpdf(points) for part in self.parts]) + self.log_weights[:, None]

    def logpdf(self, points) -> np.ndarray:
        """``(n,)`` log-density at ``points (n, d)``."""
        return logsumexp(self.part_logpdfs(points), axis=0)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``(n, d)`` draws: a multinomial split between the parts, in random order."""
        counts = rng.multinomial(n, np.exp(self.log_weights))
        draws = np.concatenate([part.sample(int(m), rng) for part, m in zip(self.parts, counts) if m])
        return draws[rng.permutation(n)]


def clustered_parts(clouds, rng, gaussian: bool = False, n_clusters: int = 2):
    """The parts of a :class:`PooledProposal` for weighted clouds in unconstrained coordinates.

    Each cloud ``(u (M_i, d), log_weights (M_i,))`` is split into ``n_clusters`` clusters by k-means
    (:func:`scipy.cluster.vq.kmeans2`, k-means++ start from ``rng``, in coordinates scaled by the cloud's sds);
    a cluster with fewer than ``2 (d + 1)`` particles joins the largest. A one-mode cloud is cut in two, which
    costs nothing but a slightly narrower fit to each half; a two-mode cloud gets one fit per mode. Each cloud
    has the same total weight in the mixture, shared among its clusters by their weight.

    Returns
    -------
    parts : list of DefensiveProposal
    log_weights : (K,) array
        The parts' log-weights in the mixture.
    members : list of (cloud index, (M,) bool array)
        Which particles of which cloud each part was fitted to.
    """
    parts, log_weights, members = [], [], []
    for c, (u, lw) in enumerate(clouds):
        m, d = u.shape
        scale = np.std(u, axis=0)
        scale[~(scale > 0)] = 1.0
        labels = np.zeros(m, dtype=int)
        if m >= 2 * n_clusters * (d + 1):
            _, labels = kmeans2(u / scale, n_clusters, minit="++", **{_KMEANS_RNG: rng})
            sizes = np.bincount(labels, minlength=n_clusters)
            small = sizes < 2 * (d + 1)
            labels[small[labels]] = int(np.argmax(sizes))
        w = np.exp(normalise(lw))
        for label in np.unique(labels):
            member = labels == label
            mass = w[member].sum()
            if not mass > 0:
                continue
            parts.append(DefensiveProposal(u[member], lw[member], gaussian=gaussian))
            log_weights.append(np.log(mass) - np.log(len(clouds)))
            members.append((c, member))
    return parts, np.array(log_weights), members


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


def pooled_start(clouds, prior_logpdf, loglike, support, rng, gaussian: bool = False):
    """One cloud of N particles from several clouds of the same posterior, each cluster of each given its share
    of the mass.

    Two samplers of one posterior may each hold a different mode, weigh two modes differently, or one may be
    trapped in a minor one (on the path space: the bridge from the path prior and the start from the stored
    paths, :func:`seqbayes.sequential.assimilate_paths`). The share of each part of the
    :class:`PooledProposal` ``q = sum_c alpha_c q_c`` fitted to the clusters of the clouds
    (:func:`clustered_parts`) is estimated by importance sampling: N draws of ``q``, weights ``w = pi / q``,
    and part ``c``'s share is ``sum w r_c / sum w`` with ``r_c`` the draw's responsibility, ``alpha_c q_c / q``
    with the first cloud's parts' terms multiplied by ``FIRST_CLOUD_PREFERENCE``: where the clouds overlap the
    first one's particles carry the mass, and another's only where the first has none. The first cloud is the
    one trusted within a mode (the bridge; the stored paths' start tempers one dataset and its particles sat
    0.3-0.5 exact sds from the bridge's within the shared mode on run 9, T5, step 6, which an even split of the
    mass between the clouds carried into the start). The particles, each weighted by its part's share times
    its own weight within the part, are resampled (systematic) to N. The independence sweeps of
    :func:`importance_step` then correct what the shares leave off (the start is only an approximation; the
    sweeps leave the posterior invariant).

    Parameters
    ----------
    clouds : sequence of (points (M_i, d), log_weights (M_i,))
        The clouds; N is the first one's size.
    prior_logpdf, loglike, support, rng, gaussian
        As :func:`importance_step`.

    Returns
    -------
    index : (N,) array of int
        Indices into the clouds' concatenation.
    shares : (K,) array
        The parts' estimated shares (each part its cloud's weight when no draw has a finite target).
    """
    n = clouds[0][0].shape[0]
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


def importance_step(posterior, log_weights, components, prior_logpdf, loglike, support, rng, n_sweeps: int = 1,
                    gaussian: bool = False, se_target: float | None = None, max_sweeps: int | None = None,
                    min_fraction: float = 0.0, other=None):
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
        Independence sweeps, each with N fresh draws; the first sweep's draws give the evidence.
    gaussian : bool
        The proposal's first half is the fitted Gaussian instead of the kernel density (:func:`_proposal`).
    se_target : float, optional
        Economy (``SamplerConfig.economy``): every sweep's draws enter the evidence (one importance
        estimate over all of them, as they are independent draws of the same proposal), and sweeps continue
        after ``n_sweeps`` while the estimate's standard error ``sqrt(1 / ESS - 1 / M)`` (M draws)
        exceeds ``se_target``, up to ``max_sweeps``, and while the pooled ESS is at least ``min_fraction``
        of the draws (below it the caller refits the proposal rather than pool a poor one's draws).
    other : tuple of (M, d) array and (M,) array, optional
        Another cloud of the same posterior (points, log-weights), which may hold a mode ``posterior``
        lacks: the proposal is then the :class:`PooledProposal` of both (:func:`clustered_parts`).

    Returns
    -------
    log_evidence : float
    ess : float
        Effective sample size of the first sweep's importance weights (out of N); with ``se_target``,
        the pooled estimate's equivalent for N draws, ``1 / (1 / ESS_M - 1 / M + 1 / N)``, which has the
        same variance ``1 / ESS - 1 / N``.
    posterior, components : arrays after the sweeps
    n_accepted : int
        Particle moves accepted over all sweeps.
    """
    n = posterior.shape[0]
    transform = BoxTransform(support)
    u = transform.forward(posterior)
    if other is None:
        q = DefensiveProposal(u, log_weights, gaussian=gaussian)
    else:
        q = PooledProposal(*clustered_parts([(u, log_weights), (transform.forward(other[0]), other[1])], rng,
                                            gaussian)[:2])
    log_q = q.logpdf

    posterior, components = posterior.copy(), components.copy()
    current = components.sum(axis=1) + transform.log_jacobian(u) - log_q(u)  # log(target / q) at the particles
    log_evidence, ess, n_accepted = -np.inf, 0.0, 0
    pooled = []
    sweep = 0
    while sweep < n_sweeps or (se_target is not None and sweep < max(max_sweeps or 0, n_sweeps)
                               and ess >= min_fraction * n * sweep  # a poor fit: refit rather than pool
                               and np.sqrt(max(1.0 / max(ess, 1e-300) - 1.0 / (n * sweep), 0.0)) > se_target):
        draws = q.sample(n, rng)
        theta, inside, new_components, log_target = _target_at(draws, transform, support, loglike, prior_logpdf)
        log_terms = log_target - log_q(draws)
        if sweep == 0 or se_target is not None:
            pooled.append(log_terms)
            every = np.concatenate(pooled)
            total = logsumexp(every)
            if not np.isfinite(total):
                if sweep == 0:
                    return -np.inf, 0.0, posterior, components, 0
            else:
                ess = float(np.exp(2.0 * total - logsumexp(2.0 * every)))  # of M = every.size draws
                log_evidence = float(total - np.log(every.size))
        # independence Metropolis-Hastings with w = target / q (the draws are independent of the particles)
        accept = metropolis_accept(current, log_terms, np.zeros(n), rng) & inside
        posterior[accept] = theta[accept]
        components[accept] = new_components[accept]
        current[accept] = log_terms[accept]
        n_accepted += int(accept.sum())
        sweep += 1
    if se_target is not None and ess > 0:
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
      (:func:`seqbayes.sequential._ancestor_terms`):

      - the last posterior's particles: ``Z_s = sum_j W_j g_j`` (``g_j`` the evidence through
        ancestor ``j``) has relative variance ``sum_j W_j^2 (g_j / Z_s - 1)^2 = sum_j (a_j - W_j)^2``,
        ``a_j = W_j g_j / Z_s`` the posterior probability of ancestor ``j``, for independent ancestors.
        Ancestors that descend from one initial draw of their step (copies made by resampling) are
        not independent: their terms are summed per draw first, ``sum_e (A_e - V_e)^2`` (the
        genealogy estimator of Chan & Lai 2013 and Lee & Whiteley 2018, as Du & Guyader 2021 use it
        for adaptive SMC with MCMC moves; :meth:`~seqbayes.density.GaussianMixture.ancestor_spread`,
        labels in :attr:`~seqbayes.sequential.SamplerState.lineage`). With distinct labels and equal
        weights it is ``1 / ESS_a - 1 / N``.
      - the posterior's before, through the mixture the last step used: ``Z_s`` is the ratio of the
        two- and one-step evidence through those particles, which makes consecutive increments'
        errors negatively correlated; its term is ``sum_j (b_j - a'_j)^2``, with ``b_j`` and ``a'_j`` the
        masses that the posteriors of steps ``s`` and ``s - 1`` give to particle ``j`` of step ``s - 2``,
        computed backwards through the exact responsibilities
        (:meth:`~seqbayes.density.GaussianMixture.backward_spread`). The lag is fixed at two steps, as in
        the fixed-lag variance estimator of Olsson & Douc (2019), so it does not degenerate over many steps.

      (The carried-weights increment already contains it: each prior particle is a draw through its own
      ancestor.)

    The cumulative variance adds the increment's and twice ``ancestor_covariance``, the covariance of
    this increment's error with the last one's through the particles of step ``s - 2``
    (:meth:`~seqbayes.density.GaussianMixture.backward_spread`); without it the sum of the increments'
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
