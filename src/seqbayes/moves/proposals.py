"""Defensive proposal densities fitted to a weighted cloud: half a Gaussian kernel density of its distinct
points, half a Student t with twice its covariance (:class:`DefensiveProposal`), or one per k-means cluster
of several clouds (:class:`PooledProposal`). They drive the independence sweeps and the importance-sampling
evidence (:mod:`seqbayes.predictive.evidence`)."""

from __future__ import annotations

import inspect

import numpy as np
from scipy import stats
from scipy.cluster.vq import kmeans2

from ..gaussian_sum import KernelMixture, silverman_bandwidth
from ..weights import logsumexp, normalise
from .scaled import FittedGaussian

__all__ = ["DefensiveProposal", "PooledProposal", "clustered_parts", "complement_halves", "defensive_parts",
           "thinned_components", "MAX_PROPOSAL_COMPONENTS"]


_T_DOF = 4.0


#: kmeans2's keyword for the random generator: ``rng`` from SciPy 1.15, ``seed`` before (both take a Generator).
_KMEANS_RNG = "rng" if "rng" in inspect.signature(kmeans2).parameters else "seed"


#: Most kernel-density components of the proposal (see docs/core.md, "Cost per update").
MAX_PROPOSAL_COMPONENTS = 1000


def complement_halves(n: int, rng: np.random.Generator):
    """Two halves of ``n`` particles for sweeps whose proposal is fitted to the other half: contiguous in the
    particles' order, cut at a random place, as ``((active, passive), (passive, active))`` index pairs (none for
    ``n < 2``).

    A proposal fitted to the particles it moves has a kernel (or an O(1/N) share of its moments) on each of them:
    the particle's own ``q`` is inflated, its ``pi / q`` deflated, most where the particles are sparse, and the
    sweep no longer leaves ``pi`` invariant (in d = 10 a kernel density's inflation is many-fold). Fitted to the
    other half, ``q`` does not depend on the particles it moves and each half's sweep leaves ``pi^N`` invariant, as
    the stretch move's halves do. Contiguous halves keep a resampled particle's copies, and their descendants,
    together (the samplers' resampling returns sorted indices): a copy in the other half would put the kernel back
    on the particle.
    """
    order = np.roll(np.arange(n), -int(rng.integers(n)))
    if n < 2:  # one particle has no other half to fit a proposal to: no sweep (the caller keeps it as it is)
        return ()
    first, second = order[: n // 2], order[n // 2:]
    return (first, second), (second, first)


def thinned_components(points, log_weights, n_components):
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


def defensive_parts(u, log_weights, n_components=None, gaussian=False):
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
    distinct, log_w = thinned_components(distinct[keep], np.log(summed[keep]), n_components or MAX_PROPOSAL_COMPONENTS)
    mean = w @ u
    cov = ((u - mean) * w[:, None]).T @ (u - mean)
    scale = np.maximum(np.diag(cov), 1e-24 * (1.0 + mean**2))
    cov = cov + np.diag(1e-9 * scale)  # keep it positive definite when a dimension is collapsed
    kde = KernelMixture(distinct, silverman_bandwidth(distinct, log_w), log_w)
    t = stats.multivariate_t(loc=mean, shape=2.0 * cov * (_T_DOF - 2.0) / _T_DOF, df=_T_DOF, allow_singular=True)
    return kde, t


class DefensiveProposal:
    """The importance density: half the kernel density (or fitted Gaussian), half the Student t of
    :func:`defensive_parts`, fitted to the weighted points ``u (N, d)`` (unconstrained coordinates).

    Also the independence proposal of the economy setting's moves at d <= 10
    (:func:`seqbayes.moves.schedule.scaled_rounds`): it follows a funnel's shape where one Gaussian cannot.
    """

    def __init__(self, u, log_weights, gaussian: bool = False):
        self.dim = u.shape[1]
        self.kde, self.t = defensive_parts(u, log_weights, gaussian=gaussian)

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
    :func:`seqbayes.predictive.paths.PathSpace`). Fitted to both, the importance density covers both; its
    independence sweeps then move particles between the modes, which no local move does, and its estimate counts
    both modes' mass. One fit to a two-mode cloud would not do: its kernel bandwidth and its t's covariance come
    from the spread between the modes, and its importance ESS collapses to a few particles.

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
