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

from .priors import as_samples
from .weights import normalise

__all__ = ["TruncatedSum", "KernelMixture", "silverman_bandwidth", "weighted_moments", "DROPPED_LOG_FRACTION",
           "BLOCK_FLOATS", "TREE_MIN_CENTRES"]

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
        underflow = total == 0.0  # weights spread over more than ~700 nats: leave it to the dense sum
        rest = np.concatenate([np.flatnonzero(~served), rows[underflow]])
        if rest.size:
            out[rest] = dense(x[rest])
        return out


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
        the sum is truncated with a k-d tree (:class:`TruncatedSum`: the
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


import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from numpy.typing import ArrayLike
