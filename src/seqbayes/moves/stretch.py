"""SEMC's ensemble moves and the :class:`Stretch` component (Sec. 3.1, Algorithm 2).

The affine-invariant stretch move of Goodman and Weare (2010), Eq. (5)-(8) of Lye et al. (2023), is vectorised over
one half of the ensemble at a time against the other half. Updating a whole half at once against a fixed complement
keeps detailed balance (the serial walker-by-walker update of Algorithm 1 is the special case of halves of size one).
The step size adapts by Eq. (9) over Algorithm 2's virtual iterations. The differential-evolution move of ter Braak
(2006), ``x* = x + g (x_j - x_k)``, is the scaled moves' local move (:mod:`seqbayes.moves.scaled`) and the strict
budget's PMMH proposal (:mod:`seqbayes.predictive.pmmh`): affine invariant, as the stretch move, but its acceptance
does not decay with d.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .base import Moves, SweepStats, combine, evaluate_inside, metropolis_accept
from .delayed import screened_sweep

__all__ = ["Stretch", "StretchMove", "stretch_sweep", "DifferentialMove", "differential_sweep",
           "paper_target_acceptance", "next_step_size", "MIN_STEP_SIZE"]

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


@dataclass(frozen=True)
class DifferentialMove:
    """``x* = x + g (x_j - x_k)`` with ``g = scale * 2.38 / sqrt(2 d)`` (ter Braak 2006).

    Parameters
    ----------
    scale : float
        Factor on the optimal random-walk scale (adapted by Eq. 9 inside a stage).
    """

    scale: float = 1.0

    def __post_init__(self):
        if not np.isfinite(self.scale) or self.scale <= 0:
            raise ValueError(f"scale: must be positive, got {self.scale}")

    def propose(self, walkers, complement, rng: np.random.Generator):
        """Proposals for ``walkers (n, d)`` from two distinct partners in ``complement (m, d)``, m >= 2.

        Returns ``(proposals (n, d), log_hastings (n,), identical (n,) bool)``, the triple of
        :meth:`~seqbayes.moves.StretchMove.propose`: the move is symmetric given the complement, and
        ``identical`` is all False (a proposal that equals its walker, from two equal partners, is
        evaluated like any other).
        """
        n, d = walkers.shape
        m = complement.shape[0]
        if m < 2:
            raise ValueError(f"complement: the differential-evolution move needs at least 2 walkers, got {m} "
                             f"(n_samples >= 4)")
        first = rng.integers(m, size=n)
        second = (first + 1 + rng.integers(m - 1, size=n)) % m  # uniform over the others
        gamma = self.scale * 2.38 / np.sqrt(2.0 * d)
        return walkers + gamma * (complement[first] - complement[second]), np.zeros(n), np.zeros(n, dtype=bool)


def differential_sweep(walkers, components, component_fn, coefficients, move: DifferentialMove,
                       rng: np.random.Generator, support):
    """One sweep of :class:`DifferentialMove`, half of the walkers against the other half: the
    stretch move's sweep (:func:`~seqbayes.moves.stretch_sweep`, whose arguments and returns it
    shares) with this move's proposals."""
    return stretch_sweep(walkers, components, component_fn, coefficients, move, rng, support)


@dataclass(frozen=True)
class Stretch(Moves):
    """SEMC's moves (Algorithm 2): the stretch move with the step size adapted by Eq. (9) over virtual iterations,
    which stop when the acceptance rate has settled (and the shared rules of :class:`~seqbayes.moves.base.Moves`).

    Parameters
    ----------
    step_size : float
        Initial step size ``u > 1`` of Eq. (6) (2).
    target_acceptance : float or None
        The target acceptance rate ``alpha_tr`` of Eq. (9) (``None``: Eq. 10, ``0.21 / d + 0.23``).
    tolerance : float
        The virtual iterations stop once ``|alpha - alpha_old| < tolerance * alpha_tr`` (0.1).
    min_sweeps, max_sweeps, moved_fraction, every_stage, transform, scaled, economy, screen
        As :class:`~seqbayes.moves.base.Moves` (``max_sweeps``: the cap on virtual iterations per stage).
    """

    step_size: float = 2.0
    target_acceptance: float | None = None
    tolerance: float = 0.1

    def __post_init__(self):
        super().__post_init__()
        if not self.step_size > 1.0:
            raise ValueError(f"step_size: must be > 1, got {self.step_size}")
        if self.target_acceptance is not None and not 0.0 < self.target_acceptance <= 1.0:
            raise ValueError(f"target_acceptance: must lie in (0, 1], got {self.target_acceptance}")

    def resolved(self, n_samples: int, dim: int) -> "Stretch":
        if n_samples < 2 * dim:
            raise ValueError(f"n_samples: the stretch move needs at least 2 d = {2 * dim} walkers, got {n_samples}")
        if self.target_acceptance is None:
            return replace(self, target_acceptance=paper_target_acceptance(dim))  # Eq. (10)
        return self

    def done(self, n_sweeps, position, start, alpha=float("nan"), alpha_old=float("nan")) -> bool:
        if n_sweeps >= self.max_sweeps:
            return True
        if not abs(alpha - alpha_old) < self.tolerance * self.target_acceptance:
            return False
        return super().done(n_sweeps, position, start)

    @property
    def initial_step_size(self) -> float:
        return self.step_size

    def step_size_after(self, adapted: float, step_size: float) -> float:
        return adapted

    def stage(self, position, components, component_fn, coefficients, support, rng, screening, step_size):
        """One stage's sweeps (Algorithm 2 lines 9-21, continuing the ensemble through the virtual iterations):
        ``(position, components, stats, step_size, n_virtual)`` after them; arguments as
        :func:`stretch_sweep`, ``screening`` a :class:`~seqbayes.moves.delayed.Screening`."""
        start, alpha_old, stats, n_virtual = position, self.target_acceptance, SweepStats(), 0
        while True:
            if screening.active():
                position, components, sweep = screened_sweep(position, components, component_fn, coefficients,
                                                             StretchMove(step_size), rng, support, screening.screen,
                                                             halves=True)
            else:
                position, components, sweep = stretch_sweep(position, components, component_fn, coefficients,
                                                            StretchMove(step_size), rng, support)
            screening.record(sweep)
            n_virtual += 1
            stats = stats + sweep
            alpha = sweep.acceptance_rate
            step_size = next_step_size(step_size, alpha, self.target_acceptance)  # Eq. (9)
            if self.done(n_virtual, position, start, alpha, alpha_old):
                return position, components, stats, step_size, n_virtual
            alpha_old = alpha

    def local_move(self, cov, scale: float, dim: int):
        """The scaled rounds' local move (:func:`~seqbayes.moves.schedule.scaled_rounds`) and its sweep."""
        return DifferentialMove(scale), differential_sweep

    def pmmh_batch(self, k: int, n: int) -> int:
        """PMMH's batch: at most half the particles, the others their complement."""
        return min(k, n // 2)

    def pmmh_proposals(self, position, active, log_weights, step_size, strict: bool, rng):
        """``(proposals, log_hastings, identical)`` for the PMMH batch ``active`` of ``position (N, d)``: the stretch
        move against the particles outside the batch, or with ``strict`` (the strict budget) the
        differential-evolution move (:mod:`seqbayes.predictive.pmmh`)."""
        rest = np.ones(position.shape[0], dtype=bool)
        rest[active] = False
        move = DifferentialMove() if strict else StretchMove(step_size)
        return move.propose(position[active], position[rest], rng)

    def pmmh_step_size(self, step_size: float, acceptance: float, strict: bool) -> float:
        """The step size after a PMMH batch with ``acceptance`` (Eq. 9; fixed with ``strict``)."""
        return step_size if strict else next_step_size(step_size, acceptance, self.target_acceptance)


#: Algorithm 2 line 15: the step size never drops below 1.01.
MIN_STEP_SIZE = 1.01


def paper_target_acceptance(dim: int) -> float:
    """``0.21 / d + 0.23`` (Eq. 10), a random-walk rule of thumb (Roberts et al. 1997)."""
    if dim < 1:
        raise ValueError(f"dim: must be >= 1, got {dim}")
    return 0.21 / dim + 0.23


def next_step_size(step_size: float, acceptance: float, target: float) -> float:
    """``max(u exp(alpha - alpha_tr), 1.01)`` (Eq. 9 and Algorithm 2 line 15).

    >>> round(next_step_size(2.0, 0.5, 0.5), 6)
    2.0
    """
    if not np.isfinite(acceptance):
        return float(step_size)
    return float(max(step_size * np.exp(acceptance - target), MIN_STEP_SIZE))  # Eq. (9)
