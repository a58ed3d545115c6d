"""Adaptive tempering: the next exponent from the effective sample size, one tempered reweighting
loop, and the BLAS thread limit.

Every tempered sampler in the package (SMC / SEMC steps, SMC^2's guide, SG-EnMCMC's resampling and
the stiffness-drop monitor) chooses its next exponent here, so that one ESS rule and one bisection
serve them all. Written by hand because the rule is three lines over a scalar root-finder whose
tolerance and end convention the samplers need exactly (scipy's ``brentq`` would change the
exponents, and with them every result, in the last bits).
"""

from __future__ import annotations

import contextlib

import numpy as np

from .weights import logsumexp, normalise

__all__ = ["tempered_ess", "bisect_increment", "next_increment", "next_exponent", "temper", "normalised_ess", "blas_limit"]


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


def normalised_ess(weights: np.ndarray) -> float:
    """ESS ``1 / sum_i w_i^2`` of normalised weights ``w (N,)`` (summing to 1).

    >>> normalised_ess(np.full(4, 0.25))
    4.0
    """
    return float(1.0 / (weights @ weights))


def temper(log_weights, increments, target_ess: float, resample_move, particles, log_evidence: float = 0.0):
    """Weigh particles by one step's log-likelihood increments, tempered so that the ESS stays at ``target_ess``.

    The exponent ``phi`` of the increments rises from 0 to 1 in the steps :func:`next_exponent`
    allows. At each, the evidence gains ``log sum_i W_i exp((phi' - phi) l_i)`` and the weights
    are updated; while ``phi < 1`` the particles are then resampled and moved toward the target
    tempered at ``phi`` (``resample_move``), after which they weigh the same.

    Parameters
    ----------
    log_weights, increments : (N,) arrays
        Finite log-weights and log-likelihood increments ``l_i`` of the step's data.
    target_ess : float
        Absolute ESS to keep.
    resample_move : callable
        ``resample_move(log_weights, increments, phi, particles) -> (increments, particles)``:
        resample by ``log_weights``, move toward the target at ``phi`` and return the moved
        particles with their increments.
    particles : object
        The caller's particle state, handed to ``resample_move`` and returned.
    log_evidence : float
        Running log-evidence; the increments are added to it one by one.

    Returns
    -------
    log_weights : (N,) array
    increments : (N,) array
    particles : object
    log_evidence : float
    """
    phi = 0.0
    while True:
        new_phi = next_exponent(log_weights, increments, phi, target_ess)
        tempered = (new_phi - phi) * increments
        log_evidence += logsumexp(normalise(log_weights) + tempered)  # log sum_i W_i exp(dphi l_i)
        log_weights = log_weights + tempered
        phi = new_phi
        if phi >= 1.0:
            return log_weights, increments, particles, log_evidence
        increments, particles = resample_move(log_weights, increments, phi, particles)
        log_weights = np.zeros_like(log_weights)
