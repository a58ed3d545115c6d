"""The predictive prior for step ``s > 1`` (Eq. A3): a weighted mixture of
axis-aligned Gaussians, ``p(theta) = sum_i W_i N(theta; c_i, diag(h^2))``.

Two constructions are offered (see :func:`predictive_density`):

``"kde"`` (the paper's, Eq. A9-A10)
    Centres are the propagated samples ``Gamma(theta_i) + nu_i``; bandwidth by
    Silverman's rule on every dimension. Adds ``h^2`` of spurious variance to
    the drifting parameters on top of the process noise.
``"transition"`` (exact on noisy dimensions; the default with process noise)
    The transition mixture ``sum_i W_i T(theta | theta_i)`` of Eq. (A3) itself:
    centres ``Gamma(theta_i)``, width = process-noise std on noisy dimensions.
    Static dimensions have a delta transition, so they get a Silverman kernel,
    with Liu-West shrinkage of the centres towards the mean so that the
    mixture keeps the posterior's mean and variance instead of inflating it
    by ``(1 + h^2)`` per step.
    With :class:`~seqbayes.kernels.Jump` components the transition of each ancestor is
    a mixture of Gaussian branches with shared shifts and widths, so Eq. (A3) is a
    :class:`MixtureSum`: one such mixture per branch combination, weighted by its
    probability.

``"history"`` (exact; the default when every parameter is static)
    With an identity kernel the prior of step ``s`` is the last posterior,
    ``p_0(theta) prod_{k<s} L_k(theta) / Z_{1:s-1}``, evaluated exactly by
    :class:`HistoryPrior` from the past datasets (as IBIS does, Chopin 2002):
    no kernel density, no ``O(N^2)`` evaluation, but every evaluation costs one
    likelihood call per past dataset.

Why by hand: scipy's ``gaussian_kde`` has no per-dimension diagonal bandwidth
with per-point weights *and* chunked evaluation; evaluating it at N = 10,000
points against 10,000 centres allocates ``N x N x d``. Here evaluation goes
through ``(m, N)`` blocks via one matrix product (never ``N x N x d``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

from ..core.state import stored_as
from ..moves.proposals import TREE_MIN_CENTRES, KernelMixture, silverman_bandwidth, weighted_moments
from ..priors import as_samples
from ..weights import logsumexp, normalise

__all__ = ["GaussianMixture", "MixtureSum", "silverman_bandwidth", "predictive_density", "systematic_selection",
           "backward_masses", "AncestorSpread", "grouped_ancestor_variance",
           "grouped_sums", "label_groups"]


#: From this many centres on, :meth:`GaussianMixture.ancestor_ess` is estimated from this many rows
#: (``O(rows x N)`` instead of ``O(N^2)``); below, every row is used (bit for bit as before).
_ANCESTOR_ROWS = 512


#: Most points at which :meth:`GaussianMixture.backward_spread` sums every row of the responsibilities; beyond, it
#: selects ``2 x _ANCESTOR_ROWS`` rows (as costly as every row at 1024 points; at N = 4000 every row doubled the
#: time of a drifting update, measured).
_BACKWARD_ROWS = 2048

#: Fractional part of the golden ratio: the stratified positions of :meth:`GaussianMixture.ancestor_spread`'s draws.
_GOLDEN = 0.6180339887498949


def label_groups(labels, n):
    """The ``(n, G)`` 0/1 membership matrix (sparse) of the ``G`` distinct ``labels (n,)`` and each column's group
    index; ``None`` for ``labels=None`` or ``n`` distinct labels (every column its own group)."""
    if labels is None:
        return None
    labels = np.asarray(labels)
    if labels.shape != (n,) or labels.dtype.kind not in "iu" or (n and labels.min() < 0):
        raise ValueError(f"labels: expected ({n},) non-negative integers, got shape {labels.shape}, dtype {labels.dtype}")
    _, inverse = np.unique(labels, return_inverse=True)
    inverse = np.asarray(inverse).reshape(-1)
    n_groups = int(inverse.max()) + 1 if n else 0
    if n_groups == n:
        return None
    return sparse.csr_matrix((np.ones(n), (np.arange(n), inverse)), shape=(n, n_groups)), inverse, n_groups


def grouped_sums(values, groups):
    """Sums of ``values`` (``(n,)`` or ``(k, n)``) over the groups of :func:`label_groups` along the last axis."""
    if groups is None:
        return values
    membership, inverse, n_groups = groups
    if values.ndim == 1:
        return np.bincount(inverse, weights=values, minlength=n_groups)
    # dense (k, n) @ sparse (n, G): ~10x faster than (membership.T @ values.T).T, which copies the transpose
    return np.asarray(values @ membership.astype(values.dtype, copy=False))


def grouped_ancestor_variance(mass: np.ndarray, weights: np.ndarray, labels: np.ndarray | None = None) -> float:
    """``sum_e (A_e - V_e)^2``: the relative variance of the evidence carried by dependent ancestors.

    ``A_e = sum_{j: labels_j = e} mass_j`` is the later posterior's mass on the ancestors labelled ``e``
    and ``V_e`` their weight (both sum to one). The label of an ancestor is the index of the initial draw
    it descends from (:attr:`~seqbayes.core.state.RemedyMemory.lineage`), so ancestors that resampling
    copied from one draw form one group (Chan & Lai 2013; Lee & Whiteley 2018). With distinct labels it
    is ``sum_j (mass_j - W_j)^2``, ``1 / ESS_a - 1 / N`` for equal weights.

    Parameters
    ----------
    mass, weights : (N,) arrays
    labels : (N,) int array, optional
        Distinct if omitted.

    Returns
    -------
    float

    Examples
    --------
    >>> round(grouped_ancestor_variance(np.array([0.5, 0.3, 0.2, 0.0]), np.full(4, 0.25)), 12)
    0.13
    >>> round(grouped_ancestor_variance(np.array([0.5, 0.3, 0.2, 0.0]), np.full(4, 0.25), np.array([0, 0, 1, 1])), 12)
    0.18
    """
    mass, weights = np.asarray(mass, dtype=float), np.asarray(weights, dtype=float)
    groups = label_groups(labels, mass.shape[0])
    difference = grouped_sums(mass, groups) - grouped_sums(weights, groups)
    return float(np.dot(difference, difference))


@dataclass(frozen=True, eq=False)
class AncestorSpread:
    """How a later posterior spreads over a mixture's components (:meth:`GaussianMixture.ancestor_spread`).

    Attributes
    ----------
    ess : float
        ``1 / sum_i a_i^2``, ``a_i`` the later posterior's mass on component ``i``.
    variance : float
        ``sum_e (A_e - V_e)^2`` over the components' labels (:func:`grouped_ancestor_variance`).
    mass : (N,) array or None
        ``a`` itself, when every row was summed.
    draws : (K,) int array or None
        Else one component per selected row, drawn (stratified, no random draw) from its
        responsibilities: ``a`` is their empirical distribution in expectation.
    """

    ess: float
    variance: float
    mass: np.ndarray | None = None
    draws: np.ndarray | None = None


@stored_as("mixture", "mixture_", dims={"mixture_centres": ("sample", "parameter"), "mixture_bandwidth": ("parameter",),
                                        "mixture_log_weights": ("sample",)})
@dataclass(frozen=True, eq=False)
class GaussianMixture(KernelMixture):
    """``sum_i W_i N(theta; centres_i, diag(bandwidth^2))`` as the predictive prior of Eq. (A3): the density and
    draws of :class:`~seqbayes.moves.proposals.KernelMixture`, and how the components carry a weighted cloud (its
    ancestors, for the evidence's standard error and the conflict remedy).

    Parameters
    ----------
    centres : (N, d) array
    bandwidth : (d,) array of positive widths
    log_weights : (N,) array, optional
        Unnormalised log mixture weights (equal if omitted).
    """

    def to_arrays(self, log_prior=None) -> dict:
        """The run store's arrays: ``mixture_centres (N, d)``, ``mixture_bandwidth (d,)``, ``mixture_log_weights (N,)``."""
        return {"mixture_centres": self.centres, "mixture_bandwidth": self.bandwidth,
                "mixture_log_weights": self.log_weights}

    @classmethod
    def from_arrays(cls, arrays: dict, context: dict | None = None):
        """``(mixture, None)`` from :meth:`to_arrays`, the stored normalised weights kept bit for bit (normalising
        twice may move the last ulp)."""
        return cls.exact(arrays["mixture_centres"], arrays["mixture_bandwidth"], arrays["mixture_log_weights"]), None

    @classmethod
    def exact(cls, centres, bandwidth, log_weights) -> "GaussianMixture":
        """The mixture with these normalised ``log_weights`` as they are."""
        mixture = cls(np.array(centres), np.array(bandwidth), log_weights)
        object.__setattr__(mixture, "log_weights", np.array(log_weights, dtype=float))
        return mixture

    def ancestor_ess(self, theta: np.ndarray, log_weights: np.ndarray | None = None) -> float:
        """How many components carry the weighted points ``theta (m, d)``: ``1 / sum_i a_i^2``.

        ``a_i = sum_k v_k r_ki`` is the mass that the points (weights ``v``) give to component ``i``,
        ``r_ki = W_i N(theta_k; c_i, h^2) / p(theta_k)`` its responsibility for point ``k``. For a
        posterior under the predictive prior of Eq. (A3), ``a_i`` is the posterior probability of
        ancestor ``i``. The first value of :meth:`ancestor_spread` (see there for the cost).

        Parameters
        ----------
        theta : (m, d) array
        log_weights : (m,) array, optional
            The points' log-weights (equal if omitted).

        Returns
        -------
        float
        """
        return self.ancestor_spread(theta, log_weights).ess

    def ancestor_spread(self, theta: np.ndarray, log_weights: np.ndarray | None = None,
                        labels: np.ndarray | None = None) -> AncestorSpread:
        """The ancestor ESS ``1 / sum_i a_i^2`` (:meth:`ancestor_ess`) and the grouped variance
        ``sum_e (A_e - V_e)^2`` of the weighted points ``theta (m, d)``, in one pass.

        ``A_e = sum_{i: labels_i = e} a_i`` and ``V_e = sum_{i: labels_i = e} W_i`` (the components'
        weights): :func:`grouped_ancestor_variance`, the relative variance of the evidence that the
        components carry when components with one label are dependent (copies of one draw,
        :attr:`~seqbayes.core.state.RemedyMemory.lineage`; :func:`~seqbayes.predictive.evidence.step_standard_errors`).

        With fewer than ``TREE_MIN_CENTRES`` (4096) centres or points every row is summed, ``O(m N)``
        in blocks. With more, ``K = _ANCESTOR_ROWS`` (512) rows ``k_1..k_K`` are selected with
        probabilities ``v`` (systematic selection, fixed offset 1/2: no random draw) and
        ``sum_i a_i^2 = E[r_k . r_k']`` (``k, k'`` independent draws of ``v``) is estimated by the
        U-statistic ``(|sum_p r_p|^2 - sum_p |r_p|^2) / (K (K - 1))`` over distinct pairs of the
        selected rows, ``O(K N)`` (measured against all rows in ``tests/unit/test_density.py``); the
        grouped variance likewise, ``sum_e A_e^2`` by the U-statistic of the rows' responsibilities
        summed per label (``R_pe``), ``sum_e A_e V_e`` by ``sum_p R_p . V / K``; each selected row also
        draws one component from its responsibilities (at the stratified position ``frac((p + 1/2) g)``,
        ``g`` the golden ratio's fractional part: no random draw) for :meth:`backward_spread`.

        Parameters
        ----------
        theta : (m, d) array
        log_weights : (m,) array, optional
            The points' log-weights (equal if omitted).
        labels : (N,) int array, optional
            One label per component (distinct if omitted).

        Returns
        -------
        AncestorSpread
            With the mass ``a`` when every row was summed, else the selected rows' draws.
        """
        theta = as_samples(theta, self.dim)
        m, n = theta.shape[0], self.centres.shape[0]
        groups = label_groups(labels, n)
        v = np.full(m, 1.0 / m) if log_weights is None else np.exp(normalise(log_weights))
        weight = grouped_sums(np.exp(self.log_weights), groups)                     # V_e
        x = (theta - self._shift) / self.bandwidth
        if min(m, n) >= TREE_MIN_CENTRES:
            cumulative = np.cumsum(v)
            cumulative[-1] = 1.0
            rows = np.searchsorted(cumulative, (np.arange(_ANCESTOR_ROWS) + 0.5) / _ANCESTOR_ROWS)
            total, grouped_total = np.zeros(n), np.zeros(weight.shape[0])
            squares = grouped_squares = 0.0
            draws = np.empty(_ANCESTOR_ROWS, dtype=np.intp)
            position = np.modf((np.arange(_ANCESTOR_ROWS) + 0.5) * _GOLDEN)[0]
            for block, _, scaled, _ in self._scaled_terms(x[rows], np.float64):
                scaled /= scaled.sum(axis=1, keepdims=True)   # responsibilities r_ki of the selected rows
                cumulative = np.cumsum(scaled, axis=1)
                draws[block] = np.minimum((cumulative < position[block, None] * cumulative[:, -1:]).sum(axis=1), n - 1)
                total += scaled.sum(axis=0)
                squares += float(np.einsum("ij,ij->", scaled, scaled))
                if groups is not None:
                    scaled = grouped_sums(scaled, groups)        # R_pe: a row's responsibilities per label
                    grouped_total += scaled.sum(axis=0)
                    grouped_squares += float(np.einsum("ij,ij->", scaled, scaled))
            if groups is None:
                grouped_total, grouped_squares = total, squares
            k = float(_ANCESTOR_ROWS)
            sum_squares = (np.dot(total, total) - squares) / (k * (k - 1.0))
            grouped_sum_squares = (np.dot(grouped_total, grouped_total) - grouped_squares) / (k * (k - 1.0))
            variance = grouped_sum_squares - 2.0 * np.dot(grouped_total, weight) / k + np.dot(weight, weight)
            return AncestorSpread(float(1.0 / max(sum_squares, 1.0 / n)), float(max(variance, 0.0)), draws=draws)
        mass = np.zeros(n)
        for rows, _, scaled, _ in self._scaled_terms(x, np.float64):
            scaled /= scaled.sum(axis=1, keepdims=True)   # responsibilities r_ki
            mass += v[rows] @ scaled
        difference = grouped_sums(mass, groups) - weight
        return AncestorSpread(float(1.0 / np.dot(mass, mass)), float(np.dot(difference, difference)), mass=mass)

    def _responsibilities(self, points, dtype=np.float64):
        """Blocks ``(rows, r)`` of the responsibilities ``r (b, N)`` of the components for ``points (m, d)``, in
        ``dtype``; ``np.float32`` (relative error ~1e-6: for the selected rows of :meth:`backward_spread`, an
        estimate) is 1.7x faster with the label grouping after it (512 + 512 rows x 16,000 components)."""
        x = (as_samples(points, self.dim) - self._shift) / self.bandwidth
        for rows, _, scaled, _ in self._scaled_terms(x, dtype):
            scaled /= scaled.sum(axis=1, keepdims=True)
            yield rows, scaled

    def backward_spread(self, points: np.ndarray, log_weights: np.ndarray, later: AncestorSpread,
                        labels: np.ndarray | None = None) -> tuple[float, float]:
        """The part of the next evidence increment's error that comes from this mixture's components, two steps back.

        This mixture is the prior of step ``s - 1`` (components: the posterior particles ``x_j`` of step
        ``s - 2``, weights ``W_j``); ``points (N, d)`` with ``log_weights`` are the posterior of step ``s - 1``
        (weights ``W'_i``), whose particles are the components of step ``s``'s mixture, and ``later`` says how
        step ``s``'s posterior spreads over them (:meth:`ancestor_spread`, mass ``a``). With ``R`` the
        responsibilities of this mixture's components for ``points``, ``c = a - W'`` and ``u = c R``:

        * ``variance = sum_e U_e^2`` (``U_e`` the sum of ``u_j`` over the components labelled ``e``): the
          increment ``Z_s = Z_{s-1:s} / Z_{s-1}`` depends on the components of step ``s - 1``'s mixture
          through ``sum_j W_j h_j / sum_j W_j g_j`` (``h_j``, ``g_j`` the two- and one-step evidence through
          ``x_j``), whose relative variance is ``sum_j (b_j - a'_j)^2`` with ``b = a R`` and ``a' = W' R``
          the posterior masses of ``x_j`` after steps ``s`` and ``s - 1`` (backward, with the exact
          responsibilities: the sampled genealogy is cut by the independence sweeps);
        * ``covariance = sum_e (A'_e - V_e) U_e``: the same components' share of the covariance of the
          increments ``s - 1`` and ``s`` (the first is ``sum_e (A'_e - V_e)^2``).

        Every row of ``R`` is summed when ``later`` has the mass and there are at most ``_BACKWARD_ROWS``
        (2048) points (``O(N^2)`` in blocks). Else ``K = 512`` rows drawn from ``a`` (``later.draws``, or a
        systematic selection by the mass) and ``K`` selected by ``W'`` (systematic, offset 1/2) give ``u`` as
        the difference of two row means and both sums by U-statistics over distinct pairs, ``O(K N)``.

        Parameters
        ----------
        points : (N, d) array
        log_weights : (N,) array
        later : AncestorSpread
        labels : (M,) int array, optional
            One label per component (distinct if omitted).

        Returns
        -------
        variance, covariance : float
        """
        points = as_samples(points, self.dim)
        n_points = points.shape[0]
        groups = label_groups(labels, self.centres.shape[0])
        weights = np.exp(normalise(log_weights))
        weight = grouped_sums(np.exp(self.log_weights), groups)                     # V_e
        if later.mass is not None and n_points <= _BACKWARD_ROWS:
            change = later.mass - weights                                       # c = a - W'
            u, previous = np.zeros(self.centres.shape[0]), np.zeros(self.centres.shape[0])
            for rows, r in self._responsibilities(points):
                u += change[rows] @ r
                previous += weights[rows] @ r                                   # a' = W' R
            u, difference = grouped_sums(u, groups), grouped_sums(previous, groups) - weight
            return float(np.dot(u, u)), float(np.dot(difference, u))
        if later.draws is not None:
            draws = later.draws
        else:
            with np.errstate(divide="ignore"):
                draws = systematic_selection(np.log(later.mass), _ANCESTOR_ROWS)
        k = draws.shape[0]
        rows = np.concatenate([draws, systematic_selection(log_weights, k)])
        selected = np.empty((2 * k, weight.shape[0]))
        for block, r in self._responsibilities(points[rows], np.float32):
            selected[block] = grouped_sums(r, groups)
        after, before = selected[:k], selected[k:]                              # rows of b = a R and of a' = W' R
        sum_after, sum_before = after.sum(axis=0), before.sum(axis=0)
        pairs = float(k * (k - 1))
        square_after = (np.dot(sum_after, sum_after) - np.einsum("ij,ij->", after, after)) / pairs
        square_before = (np.dot(sum_before, sum_before) - np.einsum("ij,ij->", before, before)) / pairs
        cross = np.dot(sum_after, sum_before) / float(k * k)
        variance = square_after - 2.0 * cross + square_before                  # |b - a'|^2
        covariance = cross - square_before - np.dot(weight, sum_after - sum_before) / k   # (a' - V) . (b - a')
        return float(max(variance, 0.0)), float(covariance)

    def _ancestor_proposal(self) -> dict:
        """The clusters of the centres that :meth:`subsample_logpdf` draws its components through (built once).

        The centres (in bandwidth units) are split into ``K ~ sqrt(N)`` leaves of a k-d tree (median
        splits of the widest side, level by level); cluster ``k`` gets its weight ``W_k``, the weighted
        mean ``mu_k`` and per-axis variance ``V_k`` of its centres, so that its contribution to the
        mixture at ``x`` is approximately ``W_k N(x; mu_k, I + V_k)``.
        """
        cache = self.__dict__.get("_proposal_cache")
        if cache is not None:
            return cache
        n = self.centres.shape[0]
        scaled = (self.centres - self._shift) / self.bandwidth
        order, bounds = _kd_leaves(scaled, 2 ** int(round(np.log2(max(2.0, _LEAVES_PER_ROOT * np.sqrt(n))))))
        starts, sizes = bounds[:-1], np.diff(bounds)
        n_clusters = starts.size
        weights = np.exp(self.log_weights)[order]
        cluster_weights = np.add.reduceat(weights, starts)
        moment_weights = np.where(np.repeat(cluster_weights > 0, sizes), weights, 1.0)  # weightless: unweighted
        points = scaled[order]
        total = np.add.reduceat(moment_weights, starts)[:, None]
        mean = np.add.reduceat(moment_weights[:, None] * points, starts, axis=0) / total
        var = np.maximum(np.add.reduceat(moment_weights[:, None] * points**2, starts, axis=0) / total - mean**2, 0.0)
        precision = 1.0 / (1.0 + var)                                     # (K, d)
        cumulative = np.cumsum(weights)
        cumulative /= cumulative[-1]
        cumulative[-1] = 1.0                                              # u < 1 always stops at the last centre
        cluster_of = np.empty(n, dtype=np.intp)
        cluster_of[order] = np.repeat(np.arange(n_clusters), sizes)
        cache = {
            "scaled": scaled, "scaled32": scaled.astype(np.float32), "order": order, "bounds": bounds, "cluster_of": cluster_of,
            "cluster_weights": cluster_weights,
            # log W_k + the terms of log N(x; mu_k, I + V_k) that do not depend on x
            # log N_k(x) + log W_k = x^2 . (-precision / 2) + x . (mean precision) + offset_k, in single precision
            "half_precision32": np.ascontiguousarray((-0.5 * precision).T, dtype=np.float32),
            "scaled_mean32": np.ascontiguousarray((mean * precision).T, dtype=np.float32),
            "offset32": (np.where(cluster_weights > 0, np.log(np.maximum(cluster_weights, 1e-300)), -np.inf)
                         + 0.5 * np.sum(np.log(precision / (2.0 * np.pi)) - mean**2 * precision, axis=1)
                         ).astype(np.float32),
            "cumulative": cumulative,
            "membership": sparse.csr_matrix((np.ones(n), (np.arange(n), cluster_of)), shape=(n, n_clusters)),
            "cluster_start": np.concatenate([[0.0], cumulative[bounds[1:-1] - 1]]),
            "cluster_end": cumulative[bounds[1:] - 1],
            "guide": np.searchsorted(cumulative, np.arange(n) / n, side="right"),
        }
        object.__setattr__(self, "_proposal_cache", cache)
        return cache

    def _proposal(self, x) -> np.ndarray:
        """The ancestor proposal's cluster probabilities ``q (m, K)`` at ``x (m, d)`` (centred, bandwidth units).

        ``q_k = _CLUSTER_SHARE W_k N_k(x) / sum_l W_l N_l(x) + (1 - _CLUSTER_SHARE) W_k`` with
        ``N_k(x) = N(x; mu_k, I + V_k)`` (:meth:`_ancestor_proposal`): mostly the clusters' approximate
        contributions at ``x``, defensively their weights. The exponents are formed in single precision
        (it is a proposal: the estimate stays unbiased whatever it is, as long as the draws and the
        weights use the same ``q``, which is double precision from here on).
        """
        cache = self._ancestor_proposal()
        x32 = x.astype(np.float32)
        exponent = (x32 * x32) @ cache["half_precision32"] + x32 @ cache["scaled_mean32"] + cache["offset32"]
        exponent -= exponent.max(axis=1, keepdims=True)
        np.exp(exponent, out=exponent)
        q = exponent.astype(np.float64)
        q *= _CLUSTER_SHARE / q.sum(axis=1, keepdims=True)
        q += (1.0 - _CLUSTER_SHARE) * cache["cluster_weights"]
        return q

    def log_second_moment(self, theta: np.ndarray) -> np.ndarray:
        """``log(E_q[w_A(theta)^2] / p(theta)^2)`` at ``theta (m, d)``, exactly, returns ``(m,)``.

        ``w_a(theta) = W_a T(theta | c_a) / q_a(theta)`` is the one-term estimate of ``p(theta)`` that
        :meth:`subsample_logpdf` averages, ``A`` drawn from the ancestor proposal ``q(theta)``; its
        relative variance is ``exp(result) - 1`` and that of the ``M``-term estimate ``(exp(result) - 1) / M``.
        ``sum_j W_j T_j^2 / g_k(j) / p^2`` with ``g_k = q_k / W_k`` (:meth:`_proposal`), ``O(m N)`` in blocks.
        """
        theta = as_samples(theta, self.dim)
        cache = self._ancestor_proposal()
        x = (theta - self._shift) / self.bandwidth
        with np.errstate(divide="ignore", invalid="ignore"):   # g_k = q_k / W_k (a weightless cluster: never drawn)
            factors = np.where(cache["cluster_weights"] > 0, self._proposal(x) / cache["cluster_weights"], np.inf)
        inverse_weights = np.where(self.log_weights > -700.0, np.exp(-np.maximum(self.log_weights, -700.0)), 0.0)
        out = np.empty(theta.shape[0])
        for rows, _, scaled, _ in self._scaled_terms(x, np.float64):
            # W_j T_j / p = scaled_j / sum(scaled): sum_j W_j (T_j / p)^2 / g = sum_k (1 / g_k) sum_{j in k} scaled_j^2 / W_j / sum^2
            first = scaled.sum(axis=1)
            scaled *= scaled
            scaled *= inverse_weights
            per_cluster = (cache["membership"].T @ scaled.T).T                # (b, K)
            out[rows] = np.log(np.einsum("ij,ij->i", per_cluster, 1.0 / factors[rows])) - 2.0 * np.log(first)
        return out

    def subsample_logpdf(self, theta: np.ndarray, n_terms: int, rng: np.random.Generator,
                         first: np.ndarray | None = None) -> np.ndarray:
        """An unbiased estimate of the density, on the log scale: ``log((1/M) sum_m W_a T(theta | c_a) / q_a)``.

        The components ``a_1..a_M`` are drawn independently, for every row afresh at every call, from
        the ancestor proposal ``q(theta)`` (:meth:`_proposal`: a cluster of centres by its
        approximate contribution at ``theta``, or by its weight, then a centre of it by its weight), so
        ``E[p_hat(theta)] = sum_j W_j T(theta | c_j) = p(theta)`` (Eq. A3): the estimate a
        pseudo-marginal chain needs (Andrieu & Roberts 2009). ``O(m (K + M))`` with ``K ~ sqrt(N)``
        clusters, not ``O(m N)``.

        Parameters
        ----------
        theta : (m, d) array
        n_terms : int
            ``M``.
        rng : numpy.random.Generator
        first : (m,) int array, optional
            Fixes ``a_1`` per row: a point drawn from component ``first[k]`` (chosen with probability
            ``W``) then carries a draw of the pseudo-marginal's extended target, whose ``a_1`` given
            ``theta`` has the exact responsibilities ``W_j T(theta | c_j) / p(theta)``.

        Returns
        -------
        (m,) array
        """
        theta = as_samples(theta, self.dim)
        cache = self._ancestor_proposal()
        m, n_terms = theta.shape[0], int(n_terms)
        n_clusters = cache["bounds"].size - 1
        x = (theta - self._shift) / self.bandwidth
        q = self._proposal(x)                                             # (m, K), rows sum to 1
        # clusters: inverse CDF of q per row, all rows in one search (row r's CDF shifted to [r, r + 1])
        cdf = np.cumsum(q, axis=1)
        cdf[:, -1] = 1.0
        row = np.arange(m)[:, None]
        u = np.sort(rng.random((m, n_terms)), axis=1) + row             # sorted queries: a cache-friendly search
        cluster = np.searchsorted((cdf + row).ravel(), u.ravel(), side="right").reshape(m, n_terms) - row * n_clusters
        cluster = np.clip(cluster, 0, n_clusters - 1)
        # a centre of the cluster by its weight: inverse CDF of W within the cluster's span (guide table)
        target = cache["cluster_start"][cluster] + rng.random((m, n_terms)) * (
            cache["cluster_end"][cluster] - cache["cluster_start"][cluster])
        position = self._search(cache, target)
        position = np.clip(position, cache["bounds"][cluster], cache["bounds"][cluster + 1] - 1)
        index = cache["order"][position]
        if first is not None:
            index[:, 0] = first
            cluster[:, 0] = cache["cluster_of"][first]
        # one-term weight W_a T_a / q_a with q_a = q_k W_a / W_k: T_a W_k / q_k
        log_factor = np.log(np.take_along_axis(q, cluster, axis=1) / cache["cluster_weights"][cluster])
        # the terms exp(-|x - c_a|^2 / 2) / g in single precision (as the dense sum's exponent block): each
        # is at most 1 / (1 - _CLUSTER_SHARE), so their sum cannot overflow and needs no peak subtracted
        scaled, x32, log_factor32 = cache["scaled32"], x.astype(np.float32), log_factor.astype(np.float32)
        total = np.empty(m)
        block = max(1, (1 << 18) // max(1, n_terms * self.dim))          # temporaries of ~1 MB: in cache
        for start in range(0, m, block):
            rows = slice(start, start + block)
            diff = x32[rows, None, :] - scaled[index[rows]]                # (b, M, d)
            terms = np.einsum("bmd,bmd->bm", diff, diff)
            terms *= -0.5
            terms -= log_factor32[rows]
            np.exp(terms, out=terms)
            total[rows] = terms.sum(axis=1, dtype=np.float64)
        with np.errstate(divide="ignore"):
            out = np.log(total)
        faint = np.flatnonzero(total < 1e-30)   # every term near single precision's underflow: in double
        if faint.size:
            diff = x[faint, None, :] - cache["scaled"][index[faint]]
            out[faint] = logsumexp(-0.5 * np.einsum("bmd,bmd->bm", diff, diff) - log_factor[faint], axis=1)
        return out - np.log(n_terms) + self._const

    @staticmethod
    def _search(cache, target):
        """First centre (in cluster order) whose cumulative weight exceeds ``target`` (any shape): a guide
        table (Chen & Asau 1974) then a few vectorised steps; 7x faster than :func:`numpy.searchsorted`
        at N = 16,000 (random queries miss the cache)."""
        cumulative, guide = cache["cumulative"], cache["guide"]
        n = cumulative.size
        position = guide[np.clip((target * n).astype(np.intp), 0, n - 1)]
        flat, values = position.reshape(-1), target.reshape(-1)
        behind = np.flatnonzero(cumulative[flat] <= values)
        while behind.size:   # a loop over the few steps of the search, not over the draws
            flat[behind] = np.minimum(flat[behind] + 1, n - 1)
            behind = behind[(cumulative[flat[behind]] <= values[behind]) & (flat[behind] < n - 1)]
        return position

#: Share of the ancestor proposal that follows the clusters' approximate contributions at theta (the rest
#: draws clusters by their weights: a defensive mixture, so no one-term weight exceeds 10 x its W-draw's).
_CLUSTER_SHARE = 0.9
#: Clusters of the ancestor proposal: ``2^round(log2(_LEAVES_PER_ROOT sqrt(N)))``.
_LEAVES_PER_ROOT = 0.5
def _kd_leaves(points, n_leaves):
    """The leaves of a k-d tree over ``points (N, d)``: each level splits every leaf at the median of its
    widest side (all leaves of a level at once, by one sort). Returns ``order (N,)``, the points sorted
    leaf by leaf, and ``bounds (K + 1,)``, the leaves' spans in it (sizes differ by at most one)."""
    n = points.shape[0]
    order, bounds = np.arange(n), np.array([0, n])
    while bounds.size - 1 < n_leaves and np.diff(bounds).min() >= 2:   # a loop over levels, not points
        starts, sizes = bounds[:-1], np.diff(bounds)
        ordered = points[order]
        spread = np.maximum.reduceat(ordered, starts, axis=0) - np.minimum.reduceat(ordered, starts, axis=0)
        leaf = np.repeat(np.arange(starts.size), sizes)
        key = ordered[np.arange(n), spread.argmax(axis=1)[leaf]]
        order = order[np.lexsort((key, leaf))]
        bounds = np.sort(np.concatenate([bounds, starts + sizes // 2]))
    return order, bounds


def systematic_selection(log_weights, k):
    """``k`` row indices selected with probabilities ``exp(log_weights)`` (systematic, offset 1/2: no random draw)."""
    cumulative = np.cumsum(np.exp(normalise(log_weights)))
    cumulative[-1] = 1.0
    return np.searchsorted(cumulative, (np.arange(k) + 0.5) / k)


@stored_as("mixture_sum", "mixsum_", dims={"mixsum_centres": ("branch", "sample", "parameter"),
                                           "mixsum_bandwidth": ("branch", "parameter"),
                                           "mixsum_component_log_weights": ("branch", "sample"),
                                           "mixsum_log_weights": ("branch",)})
@dataclass(frozen=True, eq=False)
class MixtureSum:
    """``sum_c V_c p_c(theta)``: a weighted sum of :class:`GaussianMixture` s over the same ancestors.

    The predictive prior of Eq. (A3) under a kernel with jump components
    (:class:`~seqbayes.kernels.Jump`): one mixture per branch combination ``c`` of the
    transition, ``p_c(theta) = sum_i W_i N(theta; Gamma(theta_i) + shift_c, diag(h_c^2))``,
    weighted by the branch probabilities ``V_c``.

    Parameters
    ----------
    mixtures : sequence of C GaussianMixture
        Each with the same number ``N`` of centres (centre ``i`` of every mixture belongs to
        ancestor ``i``) and the same weights.
    log_weights : (C,) array
        Unnormalised log branch weights ``log V_c``.
    """

    mixtures: tuple
    log_weights: np.ndarray

    def __post_init__(self):
        mixtures = tuple(self.mixtures)
        if not mixtures or not all(isinstance(m, GaussianMixture) for m in mixtures):
            raise TypeError("mixtures: expected a non-empty sequence of GaussianMixture")
        n, d = mixtures[0].centres.shape
        for c, m in enumerate(mixtures):
            if m.centres.shape != (n, d):
                raise ValueError(f"mixtures[{c}]: {m.centres.shape} centres, mixtures[0] has {(n, d)}")
        log_w = normalise(np.atleast_1d(np.asarray(self.log_weights, dtype=float)))
        if log_w.shape != (len(mixtures),):
            raise ValueError(f"log_weights: expected shape ({len(mixtures)},), got {log_w.shape}")
        object.__setattr__(self, "mixtures", mixtures)
        object.__setattr__(self, "log_weights", log_w)

    @property
    def dim(self) -> int:
        return self.mixtures[0].dim

    def to_arrays(self, log_prior=None) -> dict:
        """The run store's arrays: ``mixsum_centres (C, N, d)``, ``mixsum_bandwidth (C, d)``,
        ``mixsum_component_log_weights (C, N)``, ``mixsum_log_weights (C,)``."""
        return {"mixsum_centres": np.stack([m.centres for m in self.mixtures]),
                "mixsum_bandwidth": np.stack([m.bandwidth for m in self.mixtures]),
                "mixsum_component_log_weights": np.stack([m.log_weights for m in self.mixtures]),
                "mixsum_log_weights": self.log_weights}

    @classmethod
    def from_arrays(cls, arrays: dict, context: dict | None = None):
        """``(prior, None)`` from :meth:`to_arrays`, the stored weights kept bit for bit."""
        mixtures = tuple(GaussianMixture.exact(c, h, w) for c, h, w in zip(
            arrays["mixsum_centres"], arrays["mixsum_bandwidth"], arrays["mixsum_component_log_weights"]))
        prior = cls(mixtures, arrays["mixsum_log_weights"])
        object.__setattr__(prior, "log_weights", np.array(arrays["mixsum_log_weights"], dtype=float))
        return prior, None

    def component_logpdfs(self, theta: np.ndarray) -> np.ndarray:
        """``log V_c + log p_c(theta)`` for each branch, ``(m, d) -> (m, C)``."""
        theta = as_samples(theta, self.dim)
        return np.column_stack([lw + m.logpdf(theta) for lw, m in zip(self.log_weights, self.mixtures)])

    def logpdf(self, theta: np.ndarray) -> np.ndarray:
        """Log density at ``theta (m, d)`` (log-sum-exp over the branches), returns ``(m,)``."""
        return logsumexp(self.component_logpdfs(theta), axis=1)

    def sample(self, n: int, rng: np.random.Generator) -> np.ndarray:
        """``n`` draws, shape ``(n, d)``: a branch per draw, then a draw of that branch's mixture."""
        branch = rng.choice(len(self.mixtures), size=int(n), p=np.exp(self.log_weights))
        out = np.empty((int(n), self.dim))
        for c, mixture in enumerate(self.mixtures):   # a loop over the few branches, not over samples
            rows = branch == c
            out[rows] = mixture.sample(int(rows.sum()), rng)
        return out

    def draw_one_per_component(self, rng: np.random.Generator) -> np.ndarray:
        """One draw per ancestor ``i``, ``(N, d)``: its branch ``c_i ~ V``, then ``N(centre_ci, h_ci^2)``
        (a draw of the transition from every ancestor)."""
        branch = rng.choice(len(self.mixtures), size=self.mixtures[0].centres.shape[0], p=np.exp(self.log_weights))
        centres = np.stack([m.centres for m in self.mixtures])            # (C, N, d)
        widths = np.stack([m.bandwidth for m in self.mixtures])           # (C, d)
        rows = np.arange(branch.size)
        return centres[branch, rows] + rng.standard_normal(centres.shape[1:]) * widths[branch]


def backward_masses(prior, points: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """The masses that weightings of ``points`` give to the components of ``prior``, through their exact
    responsibilities: ``weights (k, m) @ R``, ``R_ij = sum_c V_c W_j N_c(points_i; c_j) / p(points_i)``.

    ``prior`` is a :class:`GaussianMixture` or a :class:`MixtureSum` (its branches summed per ancestor);
    every row of ``R`` is formed, in blocks of ``O(block x N)`` (never ``N x N x d``).

    Parameters
    ----------
    prior : GaussianMixture or MixtureSum
    points : (m, d) array
    weights : (k, m) array

    Returns
    -------
    (k, N) array
    """
    mixtures, log_v = (prior.mixtures, prior.log_weights) if isinstance(prior, MixtureSum) else ((prior,), (0.0,))
    points = as_samples(points, mixtures[0].dim)
    weights = np.atleast_2d(np.asarray(weights, dtype=float))
    out = np.zeros((weights.shape[0], mixtures[0].centres.shape[0]))
    blocks = [m._scaled_terms((points - m._shift) / m.bandwidth, np.float64) for m in mixtures]
    for parts in zip(*blocks):   # the same row blocks in every branch (one size per N)
        rows = parts[0][0]
        # branch c's row factor: V_c exp(peak - |x|^2 / 2) / prod(h_c), relative to the largest branch's
        level = np.stack([lv + m._const + peak[:, 0] - 0.5 * np.einsum("ij,ij->i", xb, xb)
                          for lv, m, (_, xb, _, peak) in zip(log_v, mixtures, parts)])
        level = np.exp(level - level.max(axis=0))
        r = sum(f[:, None] * scaled for f, (_, _, scaled, _) in zip(level, parts))
        r /= r.sum(axis=1, keepdims=True)
        out += weights[:, rows] @ r
    return out


def predictive_density(posterior: np.ndarray, log_weights: np.ndarray, kernel: MarkovKernel,
                       rng: np.random.Generator, method: str = "transition",
                       shrink_static: bool = True) -> tuple[GaussianMixture, np.ndarray]:
    """The predictive prior of Eq. (A3) and the samples that represent it.

    Parameters
    ----------
    posterior : (N, d) array
        Posterior samples at step ``s``.
    log_weights : (N,) array
        Their log-weights.
    kernel : MarkovKernel
    rng : numpy.random.Generator
    method : {"transition", "kde"}
        See the module docstring.
    shrink_static : bool
        Liu-West shrinkage on the static dimensions (``"transition"`` only).

    Returns
    -------
    density : GaussianMixture or MixtureSum
        The prior density for step ``s + 1`` (a :class:`MixtureSum` for a kernel with jumps, ``"transition"``).
    samples : (N, d) array
        Predictive samples; their log-weights are ``log_weights`` (carried over).
    """
    posterior = as_samples(posterior, kernel.dim, "posterior")
    if method == "kde":  # Eq. (A9): KDE over the propagated samples, weights carried
        samples = kernel.propagate(posterior, rng)
        return GaussianMixture(samples, silverman_bandwidth(samples, log_weights), log_weights), samples
    if method != "transition":
        raise ValueError(f"predictive: unknown method {method!r}; choose from ('transition', 'kde')")
    centres = kernel.nominal(posterior)
    static = kernel.static_mask
    bandwidth = kernel.noise_std.copy()
    if static.any():
        h = silverman_bandwidth(centres[:, static], log_weights)
        if shrink_static:  # Liu & West (2001): a = sqrt(1 - h^2 / sigma^2) keeps mean and variance
            mean, var, _ = weighted_moments(centres[:, static], log_weights)
            a = np.sqrt(np.clip(1.0 - h**2 / np.maximum(var, 1e-300), 0.0, 1.0))
            centres[:, static] = mean + a * (centres[:, static] - mean)
        bandwidth[static] = h
    if getattr(kernel, "has_jumps", False):  # Eq. (A3) with a mixture transition: one mixture per branch
        branches, noisy = kernel.branches, ~static
        mixtures = []
        for shift, sd in zip(branches.shifts, branches.sds):
            width = bandwidth.copy()
            width[noisy] = sd[noisy]
            mixtures.append(GaussianMixture(centres + shift, width, log_weights))
        density = MixtureSum(mixtures, branches.log_weights)
    else:
        density = GaussianMixture(centres, bandwidth, log_weights)
    return density, density.draw_one_per_component(rng)

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from numpy.typing import ArrayLike

    from ..kernels import MarkovKernel
