"""MCMC moves: each proposes for a batch of walkers; accept/reject is shared."""

from ..core.state import SweepStats
from .base import combine, evaluate_inside, metropolis_accept
from .gaussian import GaussianMove, gaussian_sweep, weighted_covariance
from .stretch import StretchMove, stretch_sweep
from .tuning import MIN_STEP_SIZE, next_step_size, paper_target_acceptance

__all__ = ["SweepStats", "combine", "evaluate_inside", "metropolis_accept", "GaussianMove", "gaussian_sweep",
           "weighted_covariance", "StretchMove", "stretch_sweep", "MIN_STEP_SIZE", "next_step_size",
           "paper_target_acceptance"]
