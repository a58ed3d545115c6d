"""MCMC moves: each proposes for a batch of walkers; accept/reject is shared. The components a sampler is given
(``moves=Stretch(...)``, ``moves=RandomWalk(...)``) choose the moves and own their settings."""

from .base import Moves, MoveTally, SweepStats, combine, evaluate_inside, metropolis_accept
from .gaussian import GaussianMove, RandomWalk, gaussian_sweep, weighted_covariance
from .stretch import MIN_STEP_SIZE, Stretch, StretchMove, next_step_size, paper_target_acceptance, stretch_sweep

__all__ = ["Moves", "Stretch", "RandomWalk", "SweepStats", "combine", "evaluate_inside", "metropolis_accept",
           "GaussianMove", "gaussian_sweep", "weighted_covariance", "StretchMove", "stretch_sweep", "MIN_STEP_SIZE",
           "next_step_size", "paper_target_acceptance"]
