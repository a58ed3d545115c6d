"""Tempering: the next exponent from the effective sample size, the one tempering loop with its mutation
protocol, and the BLAS thread limit.

Every tempered sampler in the package (SMC / SEMC steps, SMC^2, SMC^2's guide, SG-EnMCMC's resampling and the
stiffness-drop monitor) goes through :func:`temper`: reweight by the next tempering increment (a rule,
:class:`Adaptive`, :class:`Single` or :class:`TargetESS`, chooses it and does the reweighting's arithmetic), then
hand the particles to the sampler's mutation (resample and move, or nothing), until the exponent reaches 1. One
ESS rule and one bisection serve them all. Written by hand because the rule is three lines over a scalar
root-finder whose tolerance and end convention the samplers need exactly (scipy's ``brentq`` would change the
exponents, and with them every result, in the last bits).
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, replace
from typing import Any, Protocol

import numpy as np

from ..weights import SCHEMES
from ..weights import logsumexp, normalise
from .errors import TemperingLimitError, ZeroLikelihoodError, prior_name
from .state import Failure

__all__ = ["tempered_ess", "bisect_increment", "next_increment", "next_exponent", "Stage", "Mutation", "Tempering",
           "Adaptive", "Single", "TargetESS", "Annealed", "temper", "between_stages", "normalised_ess", "blas_limit"]

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


@dataclass(frozen=True, eq=False)
class Stage:
    """One stage of :func:`temper`: the exponent ``beta`` reached, the stage's log mean weight ``log_z`` (Eq. 1,
    one stage), the log-weights after the reweighting (normalised by :class:`Adaptive`, not by
    :class:`TargetESS`), their weights and ESS (where the rule computes them) and the stages so far (``index``,
    this one included)."""

    beta: float
    log_z: float
    log_weights: np.ndarray
    index: int
    weights: np.ndarray | None = None
    ess: float = float("nan")


class Mutation(Protocol):
    """What a sampler does to its particles after each stage of :func:`temper`.

    ``mutate(particles, loglike, stage) -> (particles, loglike, log_weights, decision)``: ``particles`` is the
    sampler's own record (the loop never looks inside), ``loglike (N,)`` the values the next stage reweights by,
    ``log_weights (N,)`` the weights after it (``stage.log_weights`` when it does not resample), and ``decision``
    ``None`` to go on, or a value that stops the loop and is handed back to the caller (a remedy's decision to
    assimilate the step otherwise).
    """

    def __call__(self, particles: Any, loglike: np.ndarray, stage: Stage) -> tuple:
        ...


@dataclass(frozen=True)
class Tempering:
    """Where a step's stages resample and when they give up: the resampling ``scheme``
    (:mod:`seqbayes.weights`), the ESS fraction ``resample_below`` under which the last stage resamples,
    ``max_stages`` and ``min_valid_fraction`` (a step whose prior particles have fewer with a non-zero likelihood
    starts from the prior restricted to them, :func:`~seqbayes.predictive.particle.weigh`; 0: never). The rules
    (:class:`Adaptive`, :class:`Single`) say how far each stage goes."""

    max_stages: int = 1000
    resample_below: float = 0.5
    scheme: str = "systematic"
    min_valid_fraction: float = 0.5

    def __post_init__(self):
        if isinstance(self.max_stages, bool) or int(self.max_stages) != self.max_stages or self.max_stages < 1:
            raise ValueError(f"max_stages: must be an integer >= 1, got {self.max_stages}")
        if not 0.0 < self.resample_below <= 1.0:
            raise ValueError(f"resample_below: must lie in (0, 1], got {self.resample_below}")
        if self.scheme not in SCHEMES:
            raise ValueError(f"scheme: unknown resampling scheme {self.scheme!r}; choose from {sorted(SCHEMES)}")
        if not 0.0 <= self.min_valid_fraction <= 1.0:
            raise ValueError(f"min_valid_fraction: must lie in [0, 1], got {self.min_valid_fraction}")

    def increment(self, log_weights, loglike, remaining: float) -> float:
        """The next exponent increment (all of ``remaining`` here: the paper's single reweighting)."""
        return remaining

    def without_shortcut(self) -> "Tempering":
        """This rule with every stage keeping its ESS target (:class:`Adaptive`'s ``threshold`` at ``ess``)."""
        return self

    def stage(self, log_weights, loglike, beta: float, n_stages: int, step: int) -> Stage:
        """One stage of Eq. (A5): reweight the normalised ``log_weights (N,)`` by ``L^delta`` (``loglike (N,)``,
        ``-inf`` allowed) with the next increment ``delta`` from ``beta``, after ``n_stages`` stages of ``step``.

        Returns a :class:`Stage`, or a :class:`~seqbayes.core.state.Failure` when ``max_stages`` stages did not reach
        ``beta = 1`` (:class:`TemperingLimitError`) or every particle with a non-zero weight has zero likelihood
        (:class:`ZeroLikelihoodError`).
        """
        if n_stages >= self.max_stages:
            return Failure(TemperingLimitError(
                f"step {step}: tempering reached exponent {beta:.3g} after max_stages = {self.max_stages} "
                f"stages; the dataset lies very far from the {prior_name(step)}"
                f" (check its units and the model), or raise max_stages"))
        remaining = 1.0 - beta
        delta = self.increment(log_weights, loglike, remaining)
        if remaining - delta < 1e-12:
            delta = remaining
        finite = np.isfinite(loglike)
        increment = np.where(finite, delta * np.where(finite, loglike, 0.0), -np.inf)
        stage_log_z = logsumexp(log_weights + increment)  # Eq. (1), one stage
        if not np.isfinite(stage_log_z):  # the particles with a non-zero likelihood all have zero weight
            return Failure(ZeroLikelihoodError(f"step {step}: every sample with a non-zero weight has zero likelihood; "
                                               f"the {prior_name(step)} is too far from the data"))
        beta = 1.0 if delta == remaining else beta + delta
        log_weights = log_weights + increment - stage_log_z  # normalised: the carried weights sum to one
        weights = np.exp(log_weights)
        return Stage(beta, stage_log_z, log_weights, n_stages + 1, weights, float(1.0 / np.dot(weights, weights)))


@dataclass(frozen=True)
class Single(Tempering):
    """No tempering: the likelihood enters in one stage (the paper's single reweighting, ``tempering=False``)."""


@dataclass(frozen=True)
class Adaptive(Tempering):
    """Adaptive tempering (Sec. 3.2 of Lye et al., 2023): the whole remaining exponent when it keeps the ESS at
    least ``threshold * N``, else the largest increment that keeps ``ess`` of the ESS the particles with a
    non-zero likelihood had (:func:`next_increment`)."""

    ess: float = 0.5
    threshold: float = 0.1

    def __post_init__(self):
        super().__post_init__()
        if not 0.0 < self.ess <= 1.0:
            raise ValueError(f"ess: must lie in (0, 1], got {self.ess}")
        if not 0.0 < self.threshold <= self.ess:
            raise ValueError(f"threshold: must lie in (0, ess], got {self.threshold}")

    def increment(self, log_weights, loglike, remaining: float) -> float:
        return next_increment(log_weights, loglike, remaining, self.ess, self.threshold)

    def without_shortcut(self) -> "Adaptive":
        return replace(self, threshold=self.ess)


@dataclass(frozen=True)
class TargetESS:
    """The structural samplers' rule: the largest exponent that keeps the ESS at ``target`` (absolute), by
    :func:`next_exponent`, on weights it leaves unnormalised (the caller's convention)."""

    target: float

    def stage(self, log_weights, loglike, beta: float, n_stages: int, step: int = 0) -> Stage:
        new_beta = next_exponent(log_weights, loglike, beta, self.target)
        tempered = (new_beta - beta) * loglike
        log_z = logsumexp(normalise(log_weights) + tempered)  # log sum_i W_i exp(dphi l_i)
        return Stage(new_beta, log_z, log_weights + tempered, n_stages + 1)


@dataclass(frozen=True, eq=False)
class Annealed:
    """What :func:`temper` leaves: the particles, their ``loglike`` and ``log_weights``, the path's log-evidence
    ``log_z`` (Eq. 1, from the ``log_z`` it was given), the exponents reached, the last :class:`Stage` and what
    stopped the loop: the mutation's decision or a stage's :class:`~seqbayes.core.state.Failure` (``None``: it
    reached ``beta = 1``)."""

    particles: Any
    loglike: np.ndarray
    log_weights: np.ndarray
    log_z: float
    temperatures: tuple
    last: Stage
    decision: Any = None


def temper(particles, loglike, log_weights, rule, mutate, step: int = 0, log_z: float = 0.0) -> Annealed:
    """The one tempering loop: raise the likelihood's exponent from 0 to 1 in the stages ``rule`` chooses
    (:class:`Adaptive`, :class:`Single`, :class:`TargetESS`), handing the particles to ``mutate`` (a
    :class:`Mutation`: resample and move, or nothing) after each stage.

    Parameters
    ----------
    particles : object
        The sampler's particle record, handed to ``mutate`` and returned.
    loglike, log_weights : (N,) arrays
        The log-likelihood (or increment) the stages reweight by, and the weights.
    rule : Tempering or TargetESS
    mutate : Mutation
    step : int
        The step, for error messages.
    log_z : float
        The log-evidence the stages' log mean weights are added to, one by one.

    Returns
    -------
    Annealed
    """
    beta, temperatures, stage = 0.0, [], None
    while beta < 1.0:
        reached = rule.stage(log_weights, loglike, beta, len(temperatures), step)
        if isinstance(reached, Failure):
            return Annealed(particles, loglike, log_weights, log_z, tuple(temperatures), stage, reached)
        stage = reached
        log_z += stage.log_z
        beta = stage.beta
        temperatures.append(beta)
        particles, loglike, log_weights, decision = mutate(particles, loglike, stage)
        if decision is not None:
            return Annealed(particles, loglike, log_weights, log_z, tuple(temperatures), stage, decision)
    return Annealed(particles, loglike, log_weights, log_z, tuple(temperatures), stage)


def between_stages(resample_move):
    """The structural samplers' :class:`Mutation` from their ``resample_move(log_weights, loglike, beta, particles)
    -> (loglike, particles)``: resample and move toward the target tempered at ``beta`` at each intermediate stage,
    after which the particles weigh the same (log-weights 0); nothing at the last stage."""
    def mutate(particles, loglike, stage: Stage):
        if stage.beta >= 1.0:
            return particles, loglike, stage.log_weights, None
        loglike, particles = resample_move(stage.log_weights, loglike, stage.beta, particles)
        return particles, loglike, np.zeros_like(stage.log_weights), None
    return mutate
