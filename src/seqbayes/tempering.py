"""Adaptive tempering: the next exponent from the effective sample size, and the BLAS thread limit.

Every tempered sampler in the package (SMC / SEMC steps, SMC^2's guide, SG-EnMCMC's resampling and
the stiffness-drop monitor) chooses its next exponent here, so that one ESS rule and one bisection
serve them all. Written by hand because the rule is three lines over a scalar root-finder whose
tolerance and end convention the samplers need exactly (scipy's ``brentq`` would change the
exponents, and with them every result, in the last bits).
"""

from __future__ import annotations

import contextlib

import numpy as np

__all__ = ["tempered_ess", "bisect_increment", "next_increment", "next_exponent", "blas_limit"]


def tempered_ess(log_weights: np.ndarray, increments: np.ndarray, delta: float) -> float:
    """ESS ``(sum w)^2 / sum w^2`` of ``w = exp(log_weights + delta * increments)`` (peak taken out).

    Parameters
    ----------
    log_weights, increments : (N,) arrays
        Finite log-weights and log-likelihood increments.
    delta : float
        Exponent increment.
    """
    w = log_weights + delta * increments
    w = np.exp(w - w.max())
    return w.sum() ** 2 / np.dot(w, w)


def bisect_increment(log_weights, increments, remaining: float, target_ess: float, tol: float) -> tuple[float, float]:
    """Bisection for the largest ``delta in [0, remaining]`` with ``tempered_ess(delta) >= target_ess``.

    Returns the final bracket ``(lo, hi)``, ``hi - lo <= tol``: ``lo`` keeps the target, ``hi`` does
    not (unless it is ``remaining``). The ESS decreases in ``delta`` for a non-constant increment.
    """
    lo, hi = 0.0, remaining
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        if tempered_ess(log_weights, increments, mid) >= target_ess:
            lo = mid
        else:
            hi = mid
    return lo, hi


def next_increment(log_weights, loglike, remaining: float, target_fraction: float, threshold_fraction: float) -> float:
    """The next tempering increment of an SMC / SEMC step (Sec. 3.2 of Lye et al., 2023).

    The whole ``remaining`` exponent is taken when it keeps ESS >= ``threshold_fraction * N``;
    otherwise the largest increment keeping ESS >= ``target_fraction`` of ESS(0+) (the ESS once
    zero-likelihood particles drop out), found by bisection to ``1e-9`` of ``remaining``.

    Parameters
    ----------
    log_weights, loglike : (N,) arrays
        Current log-weights and log-likelihoods (``-inf`` allowed in either).
    remaining : float
        Exponent left to reach 1.
    """
    finite = np.isfinite(loglike) & np.isfinite(log_weights)
    if not finite.any():  # no weighted particle has a non-zero likelihood: the caller reports it
        return remaining
    base, slope = log_weights[finite], loglike[finite]
    if tempered_ess(base, slope, remaining) >= threshold_fraction * loglike.size:  # of N: a few survivors never qualify
        return remaining
    target = target_fraction * tempered_ess(base, slope, 0.0)
    lo, hi = bisect_increment(base, slope, remaining, target, 1e-9 * remaining)
    return lo if lo > 0 else hi


def next_exponent(log_weights, increments, phi: float, target_ess: float, tol: float = 1e-10) -> float:
    """Largest ``phi' in (phi, 1]`` with ``ESS(log_weights + (phi' - phi) increments) >= target_ess``.

    1 if the whole remainder fits; always advances by at least ``min(tol, 1 - phi)``.

    Parameters
    ----------
    log_weights, increments : (N,) arrays
        Finite log-weights and log-likelihood increments.
    phi : float
        Current exponent in ``[0, 1)``.
    target_ess : float
        Absolute ESS to keep.
    """
    remaining = 1.0 - phi
    if tempered_ess(log_weights, increments, remaining) >= target_ess:
        return 1.0
    lo, _ = bisect_increment(log_weights, increments, remaining, target_ess, tol * max(remaining, 1e-300))
    return phi + max(lo, min(tol, remaining))


_THREADPOOLS: list = []  # one threadpoolctl controller per process: finding the libraries is the slow part


def blas_limit(n_threads: int | None):
    """A context limiting BLAS to ``n_threads`` threads (``None``: no limit).

    The samplers' matrix products have an inner dimension of a handful of parameters, where BLAS
    threads cost more than they give (docs/benchmarks.md measures it).
    """
    if n_threads is None:
        return contextlib.nullcontext()
    if not _THREADPOOLS:
        from threadpoolctl import ThreadpoolController

        _THREADPOOLS.append(ThreadpoolController())
    return _THREADPOOLS[0].limit(limits=int(n_threads), user_api="blas")
