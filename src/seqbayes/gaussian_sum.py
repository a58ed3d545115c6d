"""Truncated sums of isotropic Gaussians, ``log sum_i exp(log w_i - |x - c_i|^2 / 2)``, exact to rounding.

The predictive prior of Eq. (A3) is such a sum over the N particles (in bandwidth units), and
it is evaluated at every MCMC proposal: ``O(N^2)`` per sweep when every pair is summed. When
the bandwidth is narrow against the spread of the centres (a slowly drifting parameter, a
kernel density of many samples) almost every term is negligible, and a k-d tree finds the ones
that are not:

* the nearest centre of every query gives a lower bound of its sum,
  ``lower_q = log w_nn - d_nn^2 / 2``;
* every centre farther than ``r_q``, ``r_q^2 = 2 (max log w + log N + 40 - lower_q)``, has a term
  below ``e^-40 lower_q / N``: together they are below ``e^-40 = 4e-18`` of the kept sum, so the
  sum over the centres within ``r_q`` is the all-pairs value to rounding;
* one radius ``R`` (the 90th percentile of ``r_q``) serves all queries in one vectorised
  pair search (:meth:`scipy.spatial.cKDTree.sparse_distance_matrix`); the queries that need
  more, and every query when the pairs within ``R`` would be more than 0.5 % of all pairs
  (a pair found by the tree costs ~100 times a pair of the dense sum, measured), go to the
  caller's dense evaluation; after a call where truncation did not pay, the sum gives up on
  it (the same mixture is queried again near the same bulk).

Measured against the double-precision all-pairs sum in ``tests/unit/test_density.py``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree


__all__ = ["TruncatedSum", "DROPPED_LOG_FRACTION"]

#: The terms dropped add up to less than ``exp(DROPPED_LOG_FRACTION)`` of the kept sum at every query.
DROPPED_LOG_FRACTION = -40.0

#: Truncation is tried only when the pairs within the common radius are at most this fraction of all pairs.
_MAX_PAIR_FRACTION = 0.005


@dataclass(frozen=True, eq=False)
class TruncatedSum:
    """``log sum_i exp(log w_i - |x - c_i|^2 / 2)`` over centres ``(N, d)`` with log-weights ``(N,)``.

    Parameters
    ----------
    centres : (N, d) array
        In the units in which the Gaussians are isotropic with unit variance.
    log_weights : (N,) array
        Finite or ``-inf``.
    """

    centres: np.ndarray
    log_weights: np.ndarray

    def __post_init__(self):
        weighted = np.isfinite(self.log_weights)  # zero-weight centres add nothing: the tree never sees them
        object.__setattr__(self, "_tree", cKDTree(self.centres[weighted]))
        object.__setattr__(self, "_log_weights", self.log_weights[weighted])
        object.__setattr__(self, "_max_log_weight", float(np.max(self.log_weights)))

    def __call__(self, x, dense, n_probe: int = 64) -> np.ndarray:
        """The sums at ``x (m, d)``; queries that truncation does not serve go to ``dense ((k, d) -> (k,))``.

        Returns
        -------
        (m,) array
        """
        if self.__dict__.get("_gave_up"):  # a previous call found that truncation saves nothing here
            return dense(x)
        m, n = x.shape[0], self._log_weights.size
        nearest, index = self._tree.query(x, k=1)
        lower = self._log_weights[index] - 0.5 * nearest**2
        # beyond radius r every term is below e^-40 of lower / N (Eq. A3's terms, bounded by the largest weight)
        radius2 = 2.0 * (self._max_log_weight + np.log(n) - DROPPED_LOG_FRACTION - lower)
        usable = np.isfinite(radius2)
        out = np.empty(m)
        if usable.sum() < 2:
            return dense(x)
        common = float(np.sqrt(np.quantile(radius2[usable], 0.9)))
        probe = np.linspace(0, m - 1, min(m, n_probe)).astype(int)  # evenly spaced: no random draw
        expected_pairs = self._tree.query_ball_point(x[probe], common, return_length=True).mean() * m
        if expected_pairs > _MAX_PAIR_FRACTION * m * n:
            object.__setattr__(self, "_gave_up", True)  # the same mixture is queried near the same bulk again
            return dense(x)
        served = usable & (radius2 <= common**2)
        rows = np.flatnonzero(served)
        pairs = cKDTree(x[rows]).sparse_distance_matrix(self._tree, common, output_type="ndarray")
        query, centre = pairs["i"], pairs["j"]
        # every term is at most max log w - d_nn^2 / 2: the exponentials below cannot overflow
        ceiling = self._max_log_weight - 0.5 * nearest[rows] ** 2
        terms = np.exp(self._log_weights[centre] - 0.5 * pairs["v"] ** 2 - ceiling[query])
        total = np.bincount(query, weights=terms, minlength=rows.size)
        with np.errstate(divide="ignore"):
            out[rows] = np.log(total) + ceiling
        underflow = total == 0.0  # weights spread beyond float64's exp range: leave it to the dense sum
        rest = np.concatenate([np.flatnonzero(~served), rows[underflow]])
        if rest.size:
            out[rest] = dense(x[rest])
        return out
