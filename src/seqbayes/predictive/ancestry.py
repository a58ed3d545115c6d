"""How many of a mixture's components carry a distribution, and the evidence variance that follows
(:class:`AncestorSpread`, :func:`grouped_ancestor_variance`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import sparse

__all__ = ["AncestorSpread", "grouped_ancestor_variance", "label_groups", "grouped_sums"]


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
