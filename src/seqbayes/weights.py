"""Importance weights in the log domain: normalisation, effective sample size
and the evidence increment of Eq. (1) of Lye et al. (2023); and resampling.

The weight functions take log-weights of shape ``(N,)``; ``-inf`` means zero weight. The resampling schemes draw
ancestor indices with probabilities proportional to normalised weights: all are unbiased (expected offspring count
``n * w_i``) and vectorised, each with an explicit :class:`numpy.random.Generator`. The paper uses multinomial
resampling; systematic is our default because it has the lowest variance of the four and costs one uniform draw.
"""

from __future__ import annotations

import numpy as np

__all__ = ["logsumexp", "normalise", "ess", "log_mean_exp", "log_evidence_increment", "multinomial", "systematic",
           "stratified", "residual", "resample", "SCHEMES"]


def logsumexp(values, axis=None):
    """``log(sum(exp(values)))`` along ``axis``; ``-inf`` where every term is ``-inf``.

    A plain-numpy version: :func:`scipy.special.logsumexp` costs ~0.5 ms of
    array-API dispatch per call, which dominates the tempering bisection.

    >>> float(logsumexp(np.log([1.0, 3.0])))
    1.3862943611198906
    """
    values = np.asarray(values, dtype=float)
    if axis is None:
        peak = values.max()
        if np.isfinite(peak):  # the usual case: the peak term is exp(0) = 1, so the sum is >= 1
            return float(np.log(np.exp(values - peak).sum()) + peak)
    peak = np.max(values, axis=axis, keepdims=True)
    peak = np.where(np.isfinite(peak), peak, 0.0)
    with np.errstate(divide="ignore"):
        out = np.log(np.sum(np.exp(values - peak), axis=axis, keepdims=True)) + peak
    return out.item() if axis is None else np.squeeze(out, axis=axis)


def _check(log_weights: np.ndarray) -> np.ndarray:
    log_weights = np.asarray(log_weights, dtype=float)
    if not (log_weights < np.inf).all():  # one pass: False for NaN and +inf
        raise ValueError("log_weights: NaN or +inf log-weight")
    return log_weights


def normalise(log_weights: np.ndarray) -> np.ndarray:
    """Normalised log-weights, ``log w_i - logsumexp(log w)`` (Eq. A5).

    Raises
    ------
    ValueError
        If every weight is zero (all ``-inf``) or any is NaN / ``+inf``.
    """
    log_weights = _check(log_weights)
    total = logsumexp(log_weights)
    if not np.isfinite(total):
        raise ValueError("log_weights: every weight is zero")
    return log_weights - total


def ess(log_weights: np.ndarray) -> float:
    """Effective sample size ``1 / sum(w_hat^2) = (sum w)^2 / sum w^2`` of (unnormalised) log-weights.

    Examples
    --------
    >>> float(ess(np.zeros(10)))
    10.0
    """
    log_weights = _check(log_weights)
    peak = log_weights.max()
    if not np.isfinite(peak):
        raise ValueError("log_weights: every weight is zero")
    w = np.exp(log_weights - peak)
    return float(w.sum() ** 2 / np.dot(w, w))


def log_mean_exp(values: np.ndarray) -> float:
    """``log(mean(exp(values)))`` computed stably; ``-inf`` if all are ``-inf``."""
    values = np.asarray(values, dtype=float)
    if values.size == 0:
        raise ValueError("values: empty array")
    return float(logsumexp(values) - np.log(values.size))


def log_evidence_increment(log_weights_prev: np.ndarray, log_increments: np.ndarray) -> float:
    """``log sum_i w_hat_i exp(l_i)``: the evidence increment of one reweighting.

    With equal previous weights this is Eq. (1): ``log((1/N) sum_i w_i)``.

    Parameters
    ----------
    log_weights_prev : (N,) array
        Log-weights carried into the step (need not be normalised).
    log_increments : (N,) array
        Incremental log-weights (e.g. tempered log-likelihoods).
    """
    return float(logsumexp(normalise(log_weights_prev) + log_increments))


def _checked_weights(weights, n):
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
    weights, n = _checked_weights(weights, n)
    return _inverse_cdf(weights, np.sort(rng.random(n)))


def systematic(weights, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """One uniform offset, ``n`` evenly spaced points."""
    weights, n = _checked_weights(weights, n)
    return _inverse_cdf(weights, (rng.random() + np.arange(n)) / n)


def stratified(weights, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """One uniform draw in each of ``n`` equal strata."""
    weights, n = _checked_weights(weights, n)
    return _inverse_cdf(weights, (rng.random(n) + np.arange(n)) / n)


def residual(weights, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
    """``floor(n w_i)`` copies of each, the remainder multinomially on the residuals."""
    weights, n = _checked_weights(weights, n)
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
