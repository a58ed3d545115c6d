"""The affine-invariant stretch move of Goodman and Weare (2010), Eq. (5)-(8) of
Lye et al. (2023), vectorised over one half of the ensemble at a time against
the other half. Updating a whole half at once against a fixed complement keeps
detailed balance (the serial walker-by-walker update of Algorithm 1 is the
special case of halves of size one).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.state import SweepStats
from .base import combine, evaluate_inside, metropolis_accept

__all__ = ["StretchMove", "stretch_sweep"]


@dataclass(frozen=True)
class StretchMove:
    """Proposal ``theta* = theta_c + lambda (theta_k - theta_c)``, ``lambda ~ g(lambda)`` (Eq. 5-6).

    Parameters
    ----------
    step_size : float
        ``u > 1`` of Eq. (6): ``lambda`` lies in ``[1/u, u]``.
    """

    step_size: float = 2.0

    def __post_init__(self):
        if not np.isfinite(self.step_size) or self.step_size <= 1.0:
            raise ValueError(f"step_size: must be > 1, got {self.step_size}")

    def propose(self, walkers, complement, rng: np.random.Generator):
        """Proposals for ``walkers (n, d)`` from partners in ``complement (m, d)``.

        Returns
        -------
        proposals : (n, d) array
        log_hastings : (n,) array
            ``(d - 1) log lambda`` of Eq. (8).
        identical : (n,) bool array
            The partner equals the walker, so the proposal is the walker itself.
        """
        n, d = walkers.shape
        u = self.step_size
        partners = complement[rng.integers(complement.shape[0], size=n)]
        # inverse-CDF draw from g(lambda) ~ 1/sqrt(lambda) on [1/u, u] (Eq. 6)
        stretch = ((u - 1.0) * rng.random(n) + 1.0) ** 2 / u
        proposals = partners + stretch[:, None] * (walkers - partners)  # Eq. (5)
        identical = np.all(partners == walkers, axis=1)
        return proposals, (d - 1) * np.log(stretch), identical


def stretch_sweep(walkers, components, component_fn, coefficients, move: StretchMove,
                  rng: np.random.Generator, support):
    """One sweep: every walker gets one stretch proposal, half against half.

    Parameters
    ----------
    walkers : (N, d) array
    components : (N, k) array
        Log-target components at ``walkers`` (e.g. log-likelihood and log-prior);
        the target is ``components @ coefficients``.
    component_fn : callable ``(n, d) -> (n, k)``
    coefficients : (k,) array
    move : StretchMove or DifferentialMove
        Any move whose ``propose(walkers, complement, rng)`` returns ``(proposals, log_hastings,
        identical)``.
    rng : numpy.random.Generator
    support : (d, 2) array
        Proposals outside are rejected without evaluation.

    Returns
    -------
    walkers, components : new arrays (inputs are not modified)
    stats : SweepStats
        A proposal is accepted when the walker moves; a proposal whose partner is
        an identical copy of the walker is counted as made and not accepted.
    """
    walkers = walkers.copy()
    components = components.copy()
    log_target = combine(components, coefficients)
    n, k = components.shape
    order = rng.permutation(n)
    halves = (order[: n // 2], order[n // 2:])
    n_accepted = n_identical = n_evaluations = 0
    for active, passive in (halves, halves[::-1]):
        proposals, log_hastings, identical = move.propose(walkers[active], walkers[passive], rng)
        if identical.any():  # the proposal is the walker itself: nothing to evaluate
            candidate = ~identical
            proposal_components = np.full((active.size, k), -np.inf)
            values, n_eval = evaluate_inside(component_fn, proposals[candidate], support, k)
            proposal_components[candidate] = values
        else:
            candidate = True
            proposal_components, n_eval = evaluate_inside(component_fn, proposals, support, k)
        proposal_target = combine(proposal_components, coefficients)
        accept = metropolis_accept(log_target[active], proposal_target, log_hastings, rng) & candidate
        moved = active[accept]
        walkers[moved] = proposals[accept]
        components[moved] = proposal_components[accept]
        log_target[moved] = proposal_target[accept]
        n_accepted += int(np.count_nonzero(accept))
        n_identical += int(np.count_nonzero(identical))
        n_evaluations += n_eval
    return walkers, components, SweepStats(n, n_accepted, n_identical, n_evaluations)
