"""Proposal densities fitted to a weighted cloud: the Gaussian kernel mixture (:class:`KernelMixture`, whose
predictive-prior form is :class:`~seqbayes.predictive.mixture.GaussianMixture`), and the defensive proposal: half a
kernel density of the cloud's distinct points, half a Student t with twice its covariance (:class:`DefensiveProposal`),
or one per k-means cluster of several clouds (:class:`PooledProposal`). They drive the independence sweeps and the
importance-sampling evidence (:mod:`seqbayes.predictive.evidence`)."""

from __future__ import annotations

import inspect
from dataclasses import dataclass

import numpy as np
from scipy import stats
from scipy.cluster.vq import kmeans2

from ..gaussian_sum import TruncatedSum
from ..priors import as_samples
from ..weights import logsumexp, normalise
from .scaled import FittedGaussian

__all__ = ["KernelMixture", "silverman_bandwidth", "weighted_moments", "BLOCK_FLOATS", "TREE_MIN_CENTRES",
           "DefensiveProposal", "PooledProposal", "clustered_parts", "complement_halves", "defensive_parts",
           "thinned_components", "MAX_PROPOSAL_COMPONENTS"]


_T_DOF = 4.0


#: kmeans2's keyword for the random generator: ``rng`` from SciPy 1.15, ``seed`` before (both take a Generator).
_KMEANS_RNG = "rng" if "rng" in inspect.signature(kmeans2).parameters else "seed"


#: Most kernel-density components of the proposal (see docs/core.md, "Cost per update").
MAX_PROPOSAL_COMPONENTS = 1000


#: Largest block of the (queries x centres) matrix held at once, in floats (~64 MB).
BLOCK_FLOATS = 8_000_000

#: From this many centres on, a mixture is evaluated with a k-d tree where that saves work
#: (:mod:`seqbayes.gaussian_sum`); below, every pair is summed (as fast, and bit for bit as before).
TREE_MIN_CENTRES = 4096

def weighted_moments(samples, log_weights):
    """Weighted mean ``(d,)``, variance ``(d,)`` and effective sample size of ``samples (N, d)``."""
    w = np.exp(normalise(log_weights))
    mean = w @ samples
    var = w @ (samples - mean) ** 2
    n_eff = 1.0 / np.sum(w**2)
    return mean, var, n_eff


def silverman_bandwidth(samples: ArrayLike, log_weights: ArrayLike | None = None) -> np.ndarray:
    """Per-dimension Silverman bandwidth of Eq. (A10): ``sigma_j (4 / (N (d + 2)))^(1/(d + 4))``.

    With weights, ``N`` is the effective sample size and ``sigma_j`` the weighted std.
    A dimension with zero spread gets a tiny positive width (``1e-9 (1 + |mean|)``)
    so that the density stays finite.

    Parameters
    ----------
    samples : (N, d) array
    log_weights : (N,) array, optional

    Returns
    -------
    (d,) array
    """
    samples = as_samples(samples, name="samples")
    n, d = samples.shape
    log_weights = np.zeros(n) if log_weights is None else np.asarray(log_weights, dtype=float)
    mean, var, n_eff = weighted_moments(samples, log_weights)
    h = np.sqrt(var) * (4.0 / (n_eff * (d + 2))) ** (1.0 / (d + 4))  # Eq. (A10)
    return np.maximum(h, 1e-9 * (1.0 + np.abs(mean)))


@dataclass(frozen=True, eq=False)
class KernelMixture:
    """``sum_i W_i N(theta; centres_i, diag(bandwidth^2))``.

    Parameters
    ----------
    centres : (N, d) array
    bandwidth : (d,) array of positive widths
    log_weights : (N,) array, optional
        Unnormalised log mixture weights (equal if omitted).
    """

    centres: np.ndarray
    bandwidth: np.ndarray
    log_weights: np.ndarray | None = None

    def __post_init__(self):
        centres = as_samples(self.centres, name="centres")
        bandwidth = np.asarray(self.bandwidth, dtype=float)
        if bandwidth.shape != (centres.shape[1],) or not np.all(bandwidth > 0):
            raise ValueError(f"bandwidth: expected {centres.shape[1]} positive widths, got {self.bandwidth!r}")
        n = centres.shape[0]
        log_w = np.full(n, -np.log(n)) if self.log_weights is None else normalise(self.log_weights)
        if log_w.shape != (n,):
            raise ValueError(f"log_weights: expected shape ({n},), got {log_w.shape}")
        object.__setattr__(self, "centres", centres)
        object.__setattr__(self, "bandwidth", bandwidth)
        object.__setattr__(self, "log_weights", log_w)
        # evaluation cache: centres in bandwidth units about their mean, in single precision
        shift = centres.mean(axis=0)
        scaled = (centres - shift) / bandwidth
        object.__setattr__(self, "_shift", shift)
        object.__setattr__(self, "_scaled_centres", np.ascontiguousarray(scaled.T, dtype=np.float32))
        object.__setattr__(self, "_offset", (log_w - 0.5 * np.einsum("ij,ij->i", scaled, scaled)).astype(np.float32))
        object.__setattr__(self, "_const", -np.sum(np.log(bandwidth)) - 0.5 * centres.shape[1] * np.log(2.0 * np.pi))
        # centres within ~2.5 bandwidths of their mean on every axis: the truncation radius (~10 bandwidths,
        # gaussian_sum) holds them all, so no tree can save work (a tree only adds cost there)
        object.__setattr__(self, "_compact", bool(np.all(scaled.std(axis=0) < 2.5)))

    @property
    def dim(self) -> int:
        return self.centres.shape[1]

    def logpdf(self, theta: np.ndarray) -> np.ndarray:
        """Log density at ``theta (m, d)``, returns ``(m,)``; memory ``O(block x N)``.

        Below ``TREE_MIN_CENTRES`` centres every pair is summed (:meth:`_dense_logsum`). With more,
        the sum is truncated with a k-d tree (:class:`~seqbayes.gaussian_sum.TruncatedSum`: the
        dropped terms add up to less than ``e^-40`` of the kept sum, so it is the all-pairs value to
        rounding) wherever that saves work, i.e. where the bandwidth is narrow against the spread
        of the centres; elsewhere every pair is summed.
        """
        theta = as_samples(theta, self.dim)
        x = (theta - self._shift) / self.bandwidth  # centring keeps the expansion below accurate
        if self.centres.shape[0] < TREE_MIN_CENTRES or self._compact:
            return self._dense_logsum(x) + self._const
        truncated = self.__dict__.get("_truncated")
        if truncated is None:  # built on first use: a mixture that is only sampled never needs it
            truncated = TruncatedSum((self.centres - self._shift) / self.bandwidth, self.log_weights)
            object.__setattr__(self, "_truncated", truncated)
        return truncated(x, self._dense_logsum) + self._const

    def _dense_logsum(self, x) -> np.ndarray:
        """``log sum_i W_i exp(-|x - c_i|^2 / 2)`` over every centre, ``x (m, d)`` centred and in bandwidth units.

        The ``(m, N)`` exponent block is formed and exponentiated in single precision
        (2.3x faster than double): the log-density error is ~1e-6 near the bulk of the
        mixture and grows only where the density is negligible.
        """
        # log sum_i W_i exp(-|x - c_i|^2 / 2) = -|x|^2 / 2 + log sum_i exp(x.c_i - |c_i|^2 / 2 + log W_i)
        out = np.empty(x.shape[0])
        for rows, xb, scaled, peak in self._scaled_terms(x, np.float32):
            out[rows] = (np.log(scaled.sum(axis=1, dtype=np.float64)) + peak[:, 0]
                         - 0.5 * np.einsum("ij,ij->i", xb, xb))
        return out

    def _scaled_terms(self, x, dtype):
        """Blocks of the mixture's terms at ``x (m, d)`` (centred, in bandwidth units), memory ``O(block x N)``:
        yields ``(rows, x[rows], exp(e - peak), peak)`` with ``e_ki = x_k.c_i - |c_i|^2 / 2 + log W_i`` in
        ``dtype`` and ``peak (b, 1)`` its row maximum; never N x N x d."""
        centres = self._scaled_centres if dtype == np.float32 else self._scaled_centres.astype(dtype)
        block = max(1, BLOCK_FLOATS // max(1, self.centres.shape[0]))
        for start in range(0, x.shape[0], block):
            xb = x[start:start + block]
            exponent = xb.astype(dtype) @ centres
            exponent += self._offset
            peak = exponent.max(axis=1, keepdims=True)
            exponent -= peak
            np.exp(exponent, out=exponent)
            yield slice(start, start + xb.shape[0]), xb, exponent, peak

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` draws, shape ``(n, d)``."""
        index = rng.choice(self.centres.shape[0], size=int(n), p=np.exp(self.log_weights))
        return self.centres[index] + rng.standard_normal((int(n), self.dim)) * self.bandwidth

    def draw_one_per_component(self, rng: np.random.Generator) -> np.ndarray:
        """One draw from each component, ``(N, d)``: a stratified draw of the mixture."""
        return self.centres + rng.standard_normal(self.centres.shape) * self.bandwidth


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
    :func:`seqbayes.predictive.transition.PathSpace`). Fitted to both, the importance density covers both; its
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


import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from numpy.typing import ArrayLike
