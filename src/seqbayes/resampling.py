"""Resampling schemes: draw ancestor indices with probabilities proportional to
normalised weights. All are unbiased (expected offspring count ``n * w_i``) and
vectorised; each takes an explicit :class:`numpy.random.Generator`.

The paper uses multinomial resampling; systematic is our default because it has
the lowest variance of the four and costs one uniform draw.
"""

from __future__ import annotations

import numpy as np

__all__ = ["multinomial", "systematic", "stratified", "residual", "resample", "SCHEMES"]


def _check(weights, n):
    weights = np.asarray(weights, dtype=float)
    if weights.ndim != 1 or weights.size == 0:
        raise ValueError(f"weights: expected a non-empty 1-D array, got shape {weights.shape}")
    if not np.all(np.isfinite(weights)) or np.any(weights < 0):
        raise ValueError("weights: must be finite and non-negative")
    total = weights.sum()
    if total <= 0:
        raise ValueError("weights: all weights are zero")
    n = weights.size if n is None else int(n)
    if n < 1:
        raise ValueError(f"n: must be at least 1, got {n}")
    return weights / total, n


def _inverse_cdf(weights, uniforms_sorted):
    cdf = np.cumsum(weights)
    cdf[-1] = 1.0  # guard against round-off
    return np.searchsorted(cdf, uniforms_sorted, side="right").clip(max=weights.size - 1)


def multinomial(weights, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """Independent draws from the categorical distribution (the paper's scheme)."""
    weights, n = _check(weights, n)
    return _inverse_cdf(weights, np.sort(rng.random(n)))


def systematic(weights, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """One uniform offset, ``n`` evenly spaced points."""
    weights, n = _check(weights, n)
    return _inverse_cdf(weights, (rng.random() + np.arange(n)) / n)


def stratified(weights, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """One uniform draw in each of ``n`` equal strata."""
    weights, n = _check(weights, n)
    return _inverse_cdf(weights, (rng.random(n) + np.arange(n)) / n)


def residual(weights, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """``floor(n w_i)`` copies of each, the remainder multinomially on the residuals."""
    weights, n = _check(weights, n)
    expected = n * weights
    copies = np.floor(expected).astype(np.int64)
    indices = np.repeat(np.arange(weights.size), copies)
    remaining = n - copies.sum()
    if remaining > 0:
        residuals = expected - copies
        indices = np.concatenate([indices, multinomial(residuals, rng, remaining)])
    return indices


SCHEMES = {
    "multinomial": multinomial,
    "systematic": systematic,
    "stratified": stratified,
    "residual": residual,
}


def resample(scheme: str, weights, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """Dispatch to a scheme by name (``"multinomial"``, ``"systematic"``, ...)."""
    try:
        function = SCHEMES[scheme]
    except KeyError:
        raise ValueError(f"resampling: unknown scheme {scheme!r}; choose from {sorted(SCHEMES)}") from None
    return function(weights, rng, n)
