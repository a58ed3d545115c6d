"""Random-walk Metropolis-Hastings with a Gaussian proposal whose covariance is
``gamma^2`` times the weighted sample covariance (Eq. A6-A8): the SMC sampler's move, and its component
:class:`RandomWalk`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..weights import normalise
from .base import Moves, SweepStats, combine, evaluate_inside, metropolis_accept
from .delayed import screened_sweep

__all__ = ["RandomWalk", "GaussianMove", "FittedMove", "weighted_covariance", "gaussian_sweep"]


def weighted_covariance(samples, log_weights=None) -> np.ndarray:
    """``sum_i w_i (theta_i - mean)(theta_i - mean)^T`` (Eq. A6-A7 with gamma = 1), ``(d, d)``.

    Equal weights when ``log_weights`` is omitted."""
    if log_weights is None:
        n = samples.shape[0]
        centred = samples - np.full(n, 1.0 / n) @ samples  # a matrix-vector product: 5x faster than mean(axis=0)
        return centred.T @ centred / n
    w = np.exp(normalise(log_weights))
    mean = w @ samples  # Eq. (A6)
    centred = samples - mean
    return (centred.T * w) @ centred  # Eq. (A7)


@dataclass(frozen=True, eq=False)
class GaussianMove:
    """``theta* = theta + L z``, ``z ~ N(0, I)``, ``L L^T = gamma^2 Sigma`` (symmetric: log-Hastings 0).

    A singular ``Sigma`` (a collapsed dimension) is regularised by clipping its
    eigenvalues at ``1e-12`` times the largest (plus an absolute floor), instead of
    failing as a Cholesky factorisation would.
    """

    covariance: np.ndarray
    scale: float = 1.0

    def __post_init__(self):
        cov = np.atleast_2d(np.asarray(self.covariance, dtype=float))
        if cov.ndim != 2 or cov.shape[0] != cov.shape[1] or not np.all(np.isfinite(cov)):
            raise ValueError(f"covariance: expected a finite square matrix, got shape {cov.shape}")
        if not np.isfinite(self.scale) or self.scale <= 0:
            raise ValueError(f"scale: must be positive, got {self.scale}")
        values, vectors = np.linalg.eigh(0.5 * (cov + cov.T))
        floor = max(1e-12 * max(values.max(), 0.0), 1e-300)
        values = np.maximum(values, floor)
        object.__setattr__(self, "_factor", self.scale * vectors * np.sqrt(values))

    def propose(self, walkers, rng: np.random.Generator):
        """Returns ``(proposals (n, d), log_hastings (n,))``."""
        noise = rng.standard_normal(walkers.shape) @ self._factor.T
        return walkers + noise, np.zeros(walkers.shape[0])


class FittedMove:
    """The structural samplers' proposal from a weighted Gaussian fit ``N(mean, L L^T)``: for each walker either an
    independence draw ``mean + scale L z`` (Hastings term ``log q(x) - log q(x*)``, ``q = N(mean, scale^2 L L^T)``) or a
    random walk ``x + 2.38 / sqrt(d) L z`` (symmetric), as the caller's ``independent`` mask says (drawn independently
    of the walkers, so the mixture is a valid kernel).

    Parameters
    ----------
    mean : (d,) array
    chol : (d, d) array
        Lower Cholesky factor ``L`` of the fitted covariance.
    scale : float
        Scale of the independence proposal's spread.
    """

    def __init__(self, mean, chol, scale: float = 1.0):
        self.mean, self.chol, self.scale = mean, chol, scale
        self._chol_inv = np.linalg.inv(chol)

    def log_q(self, points) -> np.ndarray:
        """``log q`` of the independence proposal at ``points (n, d)``, up to its constant."""
        z = (points - self.mean) @ self._chol_inv.T / self.scale
        return -0.5 * np.einsum("nd,nd->n", z, z)

    def propose(self, walkers, noise, independent):
        """``(proposals (n, d), log_hastings (n,))`` for ``walkers (n, d)`` from standard normal ``noise (n, d)``, each
        an independence draw where ``independent (n,)`` is True, else a random-walk step."""
        step = noise @ self.chol.T
        d = walkers.shape[1]
        proposals = np.where(independent[:, None], self.mean + self.scale * step, walkers + 2.38 / np.sqrt(d) * step)
        return proposals, np.where(independent, self.log_q(walkers) - self.log_q(proposals), 0.0)


def gaussian_sweep(walkers, components, component_fn, coefficients, move: GaussianMove,
                   rng: np.random.Generator, support):
    """One MH proposal per walker (Eq. A8); arguments and returns as :func:`~seqbayes.moves.stretch_sweep`."""
    proposals, log_hastings = move.propose(walkers, rng)
    proposal_components, n_eval = evaluate_inside(component_fn, proposals, support, components.shape[1])
    accept = metropolis_accept(combine(components, coefficients), combine(proposal_components, coefficients),
                               log_hastings, rng)
    walkers = np.where(accept[:, None], proposals, walkers)
    components = np.where(accept[:, None], proposal_components, components)
    return walkers, components, SweepStats(walkers.shape[0], int(accept.sum()), 0, n_eval)


@dataclass(frozen=True)
class RandomWalk(Moves):
    """SMC's moves (Algorithm 4): the Gaussian random walk with ``scale^2`` times the particles' covariance (Eq. A7),
    ``min_sweeps`` to ``max_sweeps`` MH steps per stage (and the shared rules of :class:`~seqbayes.moves.base.Moves`).

    Parameters
    ----------
    scale : float
        ``gamma`` of Eq. (A7) (1).
    min_sweeps, max_sweeps, moved_fraction, every_stage, transform, scaled, economy, screen
        As :class:`~seqbayes.moves.base.Moves`.
    """

    scale: float = 1.0

    def __post_init__(self):
        super().__post_init__()
        if not self.scale > 0:
            raise ValueError(f"scale: must be positive, got {self.scale}")

    def stage(self, position, components, component_fn, coefficients, support, rng, screening, step_size):
        """One stage's MH steps: ``(position, components, stats, NaN, 0)`` after them (no step size is adapted);
        arguments as :meth:`~seqbayes.moves.stretch.Stretch.stage`."""
        start, stats, n_done = position, SweepStats(), 0
        while True:
            move = GaussianMove(weighted_covariance(position), self.scale)
            if screening.active():
                position, components, sweep = screened_sweep(position, components, component_fn, coefficients, move,
                                                             rng, support, screening.screen, halves=False)
            else:
                position, components, sweep = gaussian_sweep(position, components, component_fn, coefficients,
                                                             move, rng, support)
            screening.record(sweep)
            stats = stats + sweep
            n_done += 1
            if self.done(n_done, position, start):
                return position, components, stats, float("nan"), 0

    def local_move(self, cov, scale: float, dim: int):
        """The scaled rounds' local move: the random walk with ``2.38 / sqrt(d)`` times the covariance's factor."""
        return GaussianMove(cov, scale * 2.38 / np.sqrt(dim)), gaussian_sweep

    def pmmh_batch(self, k: int, n: int) -> int:
        return k

    def pmmh_proposals(self, position, active, log_weights, step_size, strict: bool, rng):
        """``(proposals, log_hastings, identical)`` for the PMMH batch ``active``: the random walk with the weighted
        particles' covariance."""
        move = GaussianMove(weighted_covariance(position, log_weights), self.scale)
        proposals, log_hastings = move.propose(position[active], rng)
        return proposals, log_hastings, np.zeros(active.size, dtype=bool)

    def pmmh_step_size(self, step_size: float, acceptance: float, strict: bool) -> float:
        return step_size
