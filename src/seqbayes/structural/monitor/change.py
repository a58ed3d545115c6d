"""Damage as a lasting step, summed out exactly: the change bank (Willsky and Jones' generalised likelihood ratio)
and the patterns a loss leaves across the modes.

Damage from day ``d`` adds ``-m g_i`` to mode ``i``'s log-frequency on every later set (``m > 0``; ``g`` the
pattern: a loss of log-stiffness ``m`` in element ``j`` has ``g_i = d log f_i / d log k_j``). The filters of
:mod:`~seqbayes.structural.monitor.daily_filter` are linear, so their innovations under the step are the no-damage
innovations minus ``m g_i`` times the innovations' response to a unit level step from ``d``, and::

    log p(data | d, m) - log p(data | no damage) = -m a_d - m^2 b_d / 2,
    a_d = sum_i g_i A_id,   b_d = sum_i g_i^2 B_id,
    A_id = sum_{k >= d} delta_k^T beta_k,   B_id = sum_{k >= d} delta_k^T Omega_k delta_k

with ``delta`` the state's error under the step (``e_level`` at ``d``, then ``G^-1`` through each chunk, its day
effect zeroed at each new day) and ``beta``, ``Omega`` per chunk (:func:`~seqbayes.structural.monitor.daily_filter.
chunk_update`). On-line, a *bank* carries ``A``, ``B`` and ``delta`` of every candidate day (:func:`bank_chunk`);
over a whole history they come from one backward recursion (:func:`backward_bank`), so re-weighing a particle over
its whole history costs one pass whatever the number of candidate days.

``m`` has a truncated normal prior (``m >= minimum``; :class:`LossPrior`), integrated in closed form
(:func:`log_bayes_factor`); the day has a geometric prior by calendar day; the pattern is an element's
(:class:`ElementLoss`, from a linear model's eigen-sensitivities) or, without a structural model, a loss in any
subset of the modes (:class:`ModeShift`: each mode independently with probability ``p``, at least one).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import log_ndtr, logsumexp

from .daily_filter import DAY, LEVEL

__all__ = ["LossPrior", "ElementLoss", "ModeShift", "Bank", "empty_bank", "bank_chunk", "backward_bank",
           "log_bayes_factor", "sensitivities", "ChangePosterior", "change_posterior", "log_day_prior", "log_subtract"]


@dataclass(frozen=True)
class LossPrior:
    """``m ~ N(0, sd^2)`` truncated to ``m >= minimum``: the size of a loss in log units."""

    minimum: float
    sd: float

    def __post_init__(self):
        if not (math.isfinite(self.minimum) and self.minimum >= 0 and math.isfinite(self.sd) and self.sd > 0):
            raise ValueError(f"minimum, sd: expected minimum >= 0 and sd > 0, got {self.minimum!r}, {self.sd!r}")


def log_bayes_factor(a, b, prior: LossPrior):
    """``log E_prior[exp(-m a - m^2 b / 2)]`` in closed form, with the posterior of ``m`` (a truncated normal).

    Returns
    -------
    log_bf, mean, sd : arrays of ``a``'s shape
        The log Bayes factor, and the posterior's mean and sd before its truncation at ``minimum``.
    """
    a = np.asarray(a, dtype=float)
    precision = np.asarray(b, dtype=float) + 1.0 / prior.sd ** 2
    mean = -a / precision
    sd = 1.0 / np.sqrt(precision)
    log_bf = (-0.5 * np.log(prior.sd ** 2 * precision) + 0.5 * a * a / precision
              + log_ndtr((mean - prior.minimum) / sd) - log_ndtr(-prior.minimum / prior.sd))
    return log_bf, mean, sd


@dataclass(frozen=True, eq=False)
class ElementLoss:
    """A loss in one of ``J`` elements: mode ``i``'s log-frequency drops by ``m g[i, j]``.

    Attributes
    ----------
    patterns : (n, J) array
        ``d log f_i / d log k_j`` at the reference (:func:`sensitivities`).
    names : tuple of str
        The elements' names.
    prior : LossPrior
        Of the log-stiffness loss ``m = -log(1 - loss)``.
    """

    patterns: np.ndarray
    names: tuple
    prior: LossPrior = LossPrior(-math.log(0.99), 0.1)

    def __post_init__(self):
        g = np.atleast_2d(np.asarray(self.patterns, dtype=float))
        if not np.all(np.isfinite(g)) or not np.any(g != 0, axis=0).all():
            raise ValueError("patterns: expected finite sensitivities, each element moving at least one mode")
        object.__setattr__(self, "patterns", g)
        if len(self.names) != g.shape[1]:
            raise ValueError(f"names: expected {g.shape[1]} element names, got {len(self.names)}")
        object.__setattr__(self, "names", tuple(str(n) for n in self.names))

    @property
    def n_classes(self) -> int:
        return self.patterns.shape[1]

    def log_terms(self, A, B):
        """``log BF (N, J, C)`` of each element and candidate day, with the loss posterior's mean and sd."""
        g = self.patterns
        a = np.einsum("ij,nic->njc", g, A)
        b = np.einsum("ij,nic->njc", g * g, B)
        return log_bayes_factor(a, b, self.prior)

    def log_combined(self, A, B):
        """``log BF (N, C)`` of a loss at each candidate day, the elements equally likely."""
        log_bf, _, _ = self.log_terms(A, B)
        return logsumexp(log_bf, axis=1) - math.log(self.n_classes)


@dataclass(frozen=True, eq=False)
class ModeShift:
    """No structural model: a lasting loss in each mode independently with probability ``probability``, given
    that at least one mode lost (the mode-level model); a mode's loss ``m_i`` is in log-frequency."""

    n_modes: int
    probability: float = 0.5
    prior: LossPrior = LossPrior(0.002, 0.05)

    def __post_init__(self):
        if not 0 < self.probability < 1:
            raise ValueError(f"probability: expected a value in (0, 1), got {self.probability!r}")

    @property
    def n_classes(self) -> int:
        return self.n_modes

    @property
    def names(self) -> tuple:
        return tuple(f"mode {i + 1}" for i in range(self.n_modes))

    def log_terms(self, A, B):
        """Per-mode ``log BF (N, n, C)`` and the loss posterior's mean and sd."""
        return log_bayes_factor(A, B, self.prior)

    def log_combined(self, A, B):
        """``log BF (N, C)``: ``(prod_i (1 - p + p BF_i) - (1 - p)^n) / (1 - (1 - p)^n)``."""
        log_bf, _, _ = self.log_terms(A, B)
        p = self.probability
        each = np.logaddexp(math.log1p(-p), math.log(p) + log_bf)             # (N, n, C)
        total = each.sum(axis=1)
        none = self.n_modes * math.log1p(-p)
        return log_subtract(total, none) - log_subtract(0.0, none)


def log_subtract(x, y):
    """``log(exp(x) - exp(y))`` for ``x >= y``."""
    x = np.asarray(x, dtype=float)
    with np.errstate(divide="ignore"):
        return x + np.log(-np.expm1(np.minimum(y - x, 0.0)))


def sensitivities(model, n_modes: int, step: float = 1e-4) -> np.ndarray:
    """``d log f_i / d log theta_j (n_modes, d)`` of a linear model (``modes(theta) -> (f, shapes)``) at
    ``theta = 1``, by central differences in ``log theta``."""
    d = model.n_parameters
    base = np.ones((1, d))
    shifts = np.exp(step * np.eye(d))
    plus, _ = model.modes(np.concatenate([base * shifts, base / shifts]))
    plus = np.log(np.asarray(plus, dtype=float)[:, :n_modes])
    g = (plus[:d] - plus[d:]).T / (2 * step)
    if not np.all(np.isfinite(g)):
        raise ValueError("model: its frequencies are not finite about theta = 1; the sensitivities need them")
    return g


# --------------------------------------------------------------------------------------------- the bank
@dataclass(frozen=True, eq=False)
class Bank:
    """The change bank of ``N`` particles over ``C`` candidate days.

    Attributes
    ----------
    A, B : (N, n, C) arrays
        Each mode's linear and quadratic terms of each candidate day.
    delta : (N, n, p, C) array
        The state's error under a unit level step from each candidate day, before the next chunk.
    days : (C,) int array
        The candidates' calendar days.
    """

    A: np.ndarray
    B: np.ndarray
    delta: np.ndarray
    days: np.ndarray

    def take(self, index) -> "Bank":
        return Bank(self.A[index], self.B[index], self.delta[index], self.days)


def empty_bank(n_particles: int, n_modes: int, p: int) -> Bank:
    return Bank(np.zeros((n_particles, n_modes, 0)), np.zeros((n_particles, n_modes, 0)),
                np.zeros((n_particles, n_modes, p, 0)), np.zeros(0, dtype=int))


def bank_chunk(bank: Bank, g_inv, beta, omega, new_day: bool, candidate: int | None) -> Bank:
    """The bank after one chunk: at a new day the candidates' day-effect errors restart at 0 and ``candidate``
    (a calendar day, or None) joins with ``delta = e_level``; then every candidate takes the chunk's terms."""
    delta, A, B, days = bank.delta, bank.A, bank.B, bank.days
    if new_day:
        delta = delta.copy()
        delta[..., DAY, :] = 0.0
    if candidate is not None:
        n_particles, n_modes, p, _ = delta.shape
        fresh = np.zeros((n_particles, n_modes, p, 1))
        fresh[..., LEVEL, :] = 1.0
        delta = np.concatenate([delta, fresh], axis=3)
        A = np.concatenate([A, np.zeros((n_particles, n_modes, 1))], axis=2)
        B = np.concatenate([B, np.zeros((n_particles, n_modes, 1))], axis=2)
        days = np.append(days, int(candidate))
    A = A + (beta[..., None] * delta).sum(axis=2)
    B = B + ((omega @ delta) * delta).sum(axis=2)
    delta = g_inv @ delta
    return Bank(A, B, delta, days)


def backward_bank(g_inv, beta, omega, new_day, candidates, end: int) -> Bank:
    """The bank after chunk ``end - 1`` from a whole history's chunk terms, by one backward recursion.

    Parameters
    ----------
    g_inv, omega : (K, N, n, p, p) arrays
    beta : (K, N, n, p) array
    new_day : (K,) bool array
        Chunk ``k`` starts a new day.
    candidates : (K,) int array
        The calendar day of the candidate that starts at chunk ``k``, -1 for none.
    end : int
        Chunks ``0 .. end - 1`` are used.

    Returns
    -------
    Bank
        Equal (up to rounding) to :func:`bank_chunk` applied to chunks ``0 .. end - 1`` in turn.
    """
    _, n_particles, n_modes, p = beta.shape
    starts = [k for k in range(end) if candidates[k] >= 0]
    lam = np.zeros((n_particles, n_modes, p))
    psi = np.zeros((n_particles, n_modes, p, p))
    carry = None                                   # Y_k: the step's error map from chunk k to after chunk end-1
    A, B, delta = {}, {}, {}
    for k in range(end - 1, -1, -1):
        if k + 1 < end and new_day[k + 1]:         # R: the day effect's error restarts at 0
            lam = lam.copy()
            lam[..., DAY] = 0.0
            psi = psi.copy()
            psi[..., DAY, :] = 0.0
            psi[..., :, DAY] = 0.0
            carry = carry.copy()
            carry[..., :, DAY] = 0.0
        gt = np.swapaxes(g_inv[k], -1, -2)
        lam = beta[k] + (gt @ lam[..., None])[..., 0]
        psi = omega[k] + gt @ psi @ g_inv[k]
        carry = g_inv[k].copy() if carry is None else carry @ g_inv[k]
        if candidates[k] >= 0:
            A[k] = lam[..., LEVEL]
            B[k] = psi[..., LEVEL, LEVEL]
            delta[k] = carry[..., :, LEVEL]
    if not starts:
        return empty_bank(n_particles, n_modes, p)
    return Bank(np.stack([A[k] for k in starts], axis=2), np.stack([B[k] for k in starts], axis=2),
                np.stack([delta[k] for k in starts], axis=3), np.array([candidates[k] for k in starts], dtype=int))


# ------------------------------------------------------------------------------------ the posterior
def log_day_prior(days, last_day: int, hazard: float):
    """``log P(change in (previous candidate, d])`` for the candidates ``days (C,)`` (calendar days >= 1, the
    previous candidate's day, or 0, excluded) and ``log P(no change by last_day)``, with the geometric prior
    ``P(change on day c) = h (1 - h)^(c - 1)``."""
    days = np.asarray(days, dtype=int)
    previous = np.concatenate([[0], days[:-1]]) if days.size else days
    log_keep = math.log1p(-hazard)
    # (1 - h)^prev - (1 - h)^d = (1 - h)^prev (1 - (1 - h)^(d - prev))
    log_prior = previous * log_keep + np.log(-np.expm1((days - previous) * log_keep))
    return log_prior, last_day * log_keep


@dataclass(frozen=True, eq=False)
class ChangePosterior:
    """Per particle: ``log_bracket (N,)`` = ``log[P(no change) + sum_d P(d) BF_d]`` (the change's factor of the
    likelihood) and ``log_p_change (N,)`` = ``log P(a change by now | static parameters, data)``."""

    log_bracket: np.ndarray
    log_p_change: np.ndarray


def change_posterior(bank: Bank, pattern, last_day: int, hazard: float) -> ChangePosterior:
    """The change's factor of each particle's likelihood from its bank (``pattern``: :class:`ElementLoss` or
    :class:`ModeShift`; ``last_day`` the calendar day of the data's last chunk)."""
    log_prior, log_none = log_day_prior(bank.days, last_day, hazard)
    n_particles = bank.A.shape[0]
    if bank.days.size == 0:
        return ChangePosterior(np.zeros(n_particles), np.full(n_particles, -np.inf))
    log_changed = logsumexp(pattern.log_combined(bank.A, bank.B) + log_prior[None, :], axis=1)
    log_bracket = np.logaddexp(log_none, log_changed)
    return ChangePosterior(log_bracket, log_changed - log_bracket)
