"""The standalone affine-invariant ensemble sampler (Algorithm 1) for batch
problems, sharing the vectorised stretch move with SEMC.

``log_prob`` is vectorised: ``(n, d) -> (n,)``. Each step is one sweep: every
walker gets one proposal, the two halves of the ensemble updated in turn.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .moves import StretchMove, stretch_sweep
from .priors import as_samples
from .rng import as_generator

__all__ = ["sample", "AIESResult"]


@dataclass(frozen=True, eq=False)
class AIESResult:
    """Output of :func:`sample`.

    Attributes
    ----------
    chain : (n_steps, n_walkers, d) array
    log_prob : (n_steps, n_walkers) array
    accepted : (n_steps,) int array
        Walkers that moved at each step.
    """

    chain: np.ndarray
    log_prob: np.ndarray
    accepted: np.ndarray

    @property
    def acceptance_rate(self) -> float:
        """True acceptance rate over all proposals."""
        return float(self.accepted.sum() / (self.chain.shape[0] * self.chain.shape[1]))

    def flat(self, burn: int = 0, thin: int = 1) -> np.ndarray:
        """Samples after ``burn`` steps, every ``thin``-th, flattened to ``(n, d)``."""
        return self.chain[burn::thin].reshape(-1, self.chain.shape[-1])


def sample(log_prob: Callable[[np.ndarray], np.ndarray], initial: ArrayLike, n_steps: int, rng: int | np.random.Generator | None = None,
           step_size: float = 2.0, support: ArrayLike | None = None) -> AIESResult:
    """Run the ensemble sampler.

    Parameters
    ----------
    log_prob : callable ``(n, d) -> (n,)``
    initial : (n_walkers, d) array
        Starting ensemble; needs ``n_walkers >= 2 d`` and finite ``log_prob``.
    n_steps : int
    rng : int or numpy.random.Generator
    step_size : float
        Stretch parameter ``u`` (``a`` in emcee), default 2.
    support : (d, 2) array, optional
        Box outside which proposals are rejected without evaluation.

    Returns
    -------
    AIESResult
    """
    rng = as_generator(rng)
    walkers = as_samples(initial, name="initial").copy()
    n_walkers, dim = walkers.shape
    if n_walkers < 2 * dim:
        raise ValueError(f"initial: the stretch move needs at least 2 d = {2 * dim} walkers, got {n_walkers}")
    if int(n_steps) < 1:
        raise ValueError(f"n_steps: must be >= 1, got {n_steps}")
    support = None if support is None else np.asarray(support, dtype=float)
    if support is not None and support.shape != (dim, 2):
        raise ValueError(f"support: expected shape ({dim}, 2), got {support.shape}")

    def component_fn(points):
        values = np.asarray(log_prob(points), dtype=float)
        if values.shape != (points.shape[0],):
            raise ValueError(f"log_prob: returned shape {values.shape} for {points.shape[0]} points")
        if np.isnan(values).any():
            values = np.where(np.isnan(values), -np.inf, values)
        return values[:, None]

    components = component_fn(walkers)
    if not np.all(np.isfinite(components)):
        raise ValueError("initial: every walker must have a finite log_prob")
    move = StretchMove(step_size)
    coefficients = np.ones(1)
    chain = np.empty((int(n_steps), n_walkers, dim))
    log_probs = np.empty((int(n_steps), n_walkers))
    accepted = np.empty(int(n_steps), dtype=np.int64)
    for t in range(int(n_steps)):
        walkers, components, stats = stretch_sweep(walkers, components, component_fn, coefficients, move, rng,
                                                   support)
        chain[t], log_probs[t], accepted[t] = walkers, components[:, 0], stats.n_accepted
    return AIESResult(chain, log_probs, accepted)

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from collections.abc import Callable
    from numpy.typing import ArrayLike
