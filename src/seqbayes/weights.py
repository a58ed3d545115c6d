"""Importance weights in the log domain: normalisation, effective sample size
and the evidence increment of Eq. (1) of Lye et al. (2023).

All functions take log-weights of shape ``(N,)``; ``-inf`` means zero weight.
"""

from __future__ import annotations

import numpy as np

__all__ = ["logsumexp", "normalise", "ess", "log_mean_exp", "log_evidence_increment"]


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
