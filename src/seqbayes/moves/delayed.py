"""Exact delayed acceptance (Christen and Fox 2005): a cheap approximation screens every proposal.

A move's proposal ``x'`` from ``x`` first faces the cheap log target ``s``:

    stage 1:  accept with  min(1, exp(s(x') - s(x) + log_hastings)),

and only the survivors are evaluated by the expensive model (the log target ``t``):

    stage 2:  accept with  min(1, exp(t(x') - t(x) - s(x') + s(x))).

The product of the two stages satisfies detailed balance with respect to ``exp(t)`` whatever ``s`` is
(the proposal's Hastings term cancels in stage 2), so the target stays exact; a good ``s`` only saves
the expensive calls of proposals stage 1 rejects. ``s`` must stay fixed while a sweep runs; here it is
refitted between tempering stages, as the moves' step sizes are adapted between sweeps.

Screens (``SamplerConfig.surrogate``):

- :class:`QuadraticScreen`: a quadratic fitted by least squares to the log target of the stage's particles
  in the moves' coordinates (the evaluations already made; ``1 + d + d (d + 1) / 2`` coefficients);
- :class:`ModelScreen`: the user's cheap model ``surrogate(theta, dataset)`` in place of the
  log-likelihood, plus the quadratic fit of the other components (the prior, which for static
  parameters holds the past datasets' likelihoods).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .base import SweepStats, combine, evaluate_inside, metropolis_accept

__all__ = ["QuadraticScreen", "ModelScreen", "Screening", "screened_sweep", "pays"]


def _features(points: np.ndarray) -> np.ndarray:
    """``[1, x, x_i x_j (i <= j)]`` of ``points (n, d)``: ``(n, 1 + d + d (d + 1) / 2)``."""
    n, d = points.shape
    rows, cols = np.triu_indices(d)
    return np.column_stack([np.ones(n), points, points[:, rows] * points[:, cols]])


@dataclass(frozen=True, eq=False)
class QuadraticScreen:
    """A quadratic ``s(x) = c . features(x)`` fitted to log-target values; ``(n, d) -> (n,)``.

    Attributes
    ----------
    coefficients : (1 + d + d (d + 1) / 2,) array
    centre, scale : (d,) arrays
        The fit is made in ``(x - centre) / scale`` (conditioning).
    """

    coefficients: np.ndarray
    centre: np.ndarray
    scale: np.ndarray

    @classmethod
    def fit(cls, points: np.ndarray, values: np.ndarray) -> "QuadraticScreen | None":
        """Least squares over the distinct finite rows; ``None`` when they are too few (fewer than twice the
        coefficients) to determine it."""
        finite = np.isfinite(values)
        points, values = points[finite], values[finite]
        if points.shape[0] == 0:
            return None
        points, first = np.unique(points, axis=0, return_index=True)
        values = values[first]
        d = points.shape[1]
        if points.shape[0] < 2 * (1 + d + d * (d + 1) // 2):
            return None
        centre = points.mean(axis=0)
        scale = points.std(axis=0)
        scale[scale == 0] = 1.0
        coefficients, *_ = np.linalg.lstsq(_features((points - centre) / scale), values - values.max(), rcond=None)
        return cls(coefficients, centre, scale)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        return _features((np.asarray(points, dtype=float) - self.centre) / self.scale) @ self.coefficients


@dataclass(frozen=True, eq=False)
class ModelScreen:
    """``beta * surrogate(theta(x), dataset) + rest(x)``: the user's cheap model for the log-likelihood and a
    :class:`QuadraticScreen` ``rest`` for the other log-target components; ``(n, d) -> (n,)``."""

    surrogate: object
    dataset: object
    beta: float
    rest: QuadraticScreen
    to_theta: object = None   # the moves' coordinates to the parameters (None: the same)
    support: np.ndarray | None = None   # (d, 2): the model is not called outside (None: everywhere)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        theta = points if self.to_theta is None else self.to_theta(points)
        inside = np.ones(points.shape[0], dtype=bool) if self.support is None else \
            np.all((theta >= self.support[:, 0]) & (theta <= self.support[:, 1]), axis=1)
        values = np.full(points.shape[0], -np.inf)
        if inside.any():
            values[inside] = np.asarray(self.surrogate(theta[inside], self.dataset), dtype=float).reshape(-1)
        with np.errstate(invalid="ignore"):
            out = self.beta * values + self.rest(points)
        return np.where(np.isnan(out), -np.inf, out)


class Screening:
    """One stage's use of a screen: on every sweep, or (``auto``) after a first plain sweep that measures the
    moves' acceptance per likelihood evaluation, for as long as screening does better (:func:`pays`)."""

    def __init__(self, screen, auto: bool):
        self.screen, self.auto = screen, auto
        self.plain, self.screened = SweepStats(), SweepStats()
        self.on = screen is not None

    def active(self) -> bool:
        """Whether the next sweep is screened."""
        return self.on and not (self.auto and self.plain.n_proposed == 0)

    def record(self, stats: SweepStats) -> None:
        """Count a sweep's ``stats`` (screened when it made screen evaluations); ``auto`` stops screening once
        it does not pay."""
        if stats.n_screen_evaluations:
            self.screened = self.screened + stats
            if self.auto and not pays(self.plain, self.screened):
                self.on = False
        else:
            self.plain = self.plain + stats


def pays(plain: SweepStats, screened: SweepStats) -> bool:
    """Whether screening pays: more accepted moves per expensive evaluation than the plain sweeps made
    (``screened`` with no evaluation at all pays only if it still accepted something)."""
    if screened.n_evaluations == 0:
        return screened.n_accepted > 0
    if plain.n_evaluations == 0:
        return True
    return screened.n_accepted / screened.n_evaluations > plain.n_accepted / plain.n_evaluations


def screened_sweep(walkers, components, component_fn, coefficients, move, rng: np.random.Generator, support, screen,
                   halves: bool):
    """One sweep of ``move`` with delayed acceptance: every walker gets one proposal, screened by ``screen``.

    Parameters
    ----------
    walkers, components, component_fn, coefficients, rng, support
        As :func:`~seqbayes.moves.stretch_sweep`.
    move : StretchMove, DifferentialMove or GaussianMove
    screen : callable ``(n, d) -> (n,)``
        The cheap log target ``s``.
    halves : bool
        Ensemble moves (``propose(walkers, complement, rng)``, half against half, as
        :func:`~seqbayes.moves.stretch_sweep`); else ``propose(walkers, rng)`` for all walkers at once.

    Returns
    -------
    walkers, components : new arrays
    stats : SweepStats
        ``n_evaluations`` counts the expensive calls (stage-1 survivors inside the support),
        ``n_screen_evaluations`` the cheap ones, ``n_screened_out`` the proposals stage 1 rejected.
    """
    walkers = walkers.copy()
    components = components.copy()
    log_target = combine(components, coefficients)
    cheap = np.asarray(screen(walkers), dtype=float)
    n, k = components.shape
    if halves:
        order = rng.permutation(n)
        batches = ((order[: n // 2], order[n // 2:]), (order[n // 2:], order[: n // 2]))
    else:
        batches = ((np.arange(n), None),)
    n_accepted = n_identical = n_evaluations = n_out = 0
    n_cheap = n
    for active, passive in batches:
        if passive is None:
            proposals, log_hastings = move.propose(walkers[active], rng)
            identical = np.zeros(active.size, dtype=bool)
        else:
            proposals, log_hastings, identical = move.propose(walkers[active], walkers[passive], rng)
        candidate = ~identical
        proposal_cheap = np.full(active.size, -np.inf)
        proposal_cheap[candidate] = screen(proposals[candidate])
        n_cheap += int(np.count_nonzero(candidate))
        # stage 1: the cheap target with the proposal's Hastings term
        first = metropolis_accept(cheap[active], proposal_cheap, log_hastings, rng) & candidate
        proposal_components = np.full((active.size, k), -np.inf)
        values, n_eval = evaluate_inside(component_fn, proposals[first], support, k)
        proposal_components[first] = values
        proposal_target = combine(proposal_components, coefficients)
        # stage 2: t(x') - t(x) - s(x') + s(x); the Hastings term has cancelled (Christen and Fox 2005, Eq. 2)
        accept = np.zeros(active.size, dtype=bool)
        with np.errstate(invalid="ignore"):
            accept[first] = metropolis_accept(log_target[active][first] - cheap[active][first],
                                              proposal_target[first] - proposal_cheap[first], 0.0, rng)
        moved = active[accept]
        walkers[moved] = proposals[accept]
        components[moved] = proposal_components[accept]
        log_target[moved] = proposal_target[accept]
        cheap[moved] = proposal_cheap[accept]
        n_accepted += int(np.count_nonzero(accept))
        n_identical += int(np.count_nonzero(identical))
        n_evaluations += n_eval
        n_out += int(np.count_nonzero(candidate & ~first))
    return walkers, components, SweepStats(n, n_accepted, n_identical, n_evaluations, n_cheap, n_out)
