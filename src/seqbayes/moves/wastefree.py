"""Waste-free resample-move (Dau & Chopin 2022): resample a few starts and keep every state of their chains.

A standard SMC stage resamples N particles and moves each with k MCMC steps, keeping only the last state: N k
likelihood calls, of which N (k - 1) serve only to mix. Waste-free SMC resamples ``M = N / P`` starts and runs a
chain of ``P - 1`` steps from each; all ``M P`` states, starts included, are the stage's particles (Dau & Chopin
2022, Algorithm 2): ``2 (N - M)`` calls a stage here (two kernels a step), and the chain states are as good as
independent once the chains mix. On the 10-D Gaussian with an exact evidence (``benchmarks/bench_calls.py``) the
economy setting's scaled rounds spent ``4 N`` calls a stage for about 60 % of the particles moved; the chains here
spend ``1.8 N`` (docs/benchmarks.md, "Waste-free economy"). One kernel a step (``0.9 N``) was enough for the
Gaussian but not for the Coulomb funnel: over 10 seeds its first update's worst posterior means were 0.43-0.52
exact sd off (6-7 of 10 runs within 0.2 sd and 15 %), against 0.08-0.26 (9-10 of 10) with both.

Each step of a chain is two kernels of the stage's target ``L^beta p``, each exact, one after the other (2 calls):

* an independence Metropolis-Hastings step from the
  :class:`~seqbayes.moves.proposals.DefensiveProposal` fitted to the stage's weighted particles of the *other*
  half (:func:`~seqbayes.moves.proposals.complement_halves`): a start's own kernel is then not in its proposal,
  which keeps the step exact (the fix of the independence sweeps); the proposal is fixed during the stage, so
  every step of the chain keeps the target;
* the moves component's local move (:meth:`~seqbayes.moves.gaussian.RandomWalk.local_move`: SMC's random walk
  with ``2.38 / sqrt(d)`` times the weighted covariance's factor, SEMC's differential evolution among the chains'
  heads), its scale following Eq. (9) from one step to the next.

Why by hand: particles' ``smc_samplers`` implements waste-free SMC for its own ``FKSMCsampler`` models and moves
(a random walk, no independence proposal), not for a tempering loop with a mutation protocol such as
:func:`seqbayes.core.tempering.temper`.
"""

from __future__ import annotations

import numpy as np

from ..weights import resample
from .base import HIGH_DIMENSION, SweepStats
from .gaussian import weighted_covariance
from .proposals import DefensiveProposal, complement_halves
from .scaled import independence_sweep

__all__ = ["CHAIN_LENGTH", "waste_free_chains"]

#: States per chain (``P``, starts included). Dau & Chopin (2022) find the variance flat over a wide range of P
#: once the chains mix; the independence step moves ~half the chains each step at d <= 10.
CHAIN_LENGTH = 10
#: Acceptance rate the local step's scale aims at (Eq. 9; Roberts et al. 1997).
LOCAL_ACCEPTANCE = 0.234


def _half_proposal(position, log_weights, part, gaussian: bool):
    """The defensive proposal fitted to the weighted particles ``part`` (equal weights when they carry none)."""
    weights = log_weights[part]
    if not np.isfinite(weights).any():
        weights = np.zeros(part.size)
    keep = np.isfinite(weights)
    return DefensiveProposal(position[part][keep], weights[keep], gaussian=gaussian)


def waste_free_chains(moves, position, components, log_weights, component_fn, coefficients, support, rng,
                      scheme: str = "systematic", chain_length: int = CHAIN_LENGTH):
    """One waste-free resample-move stage: ``ceil(N / P)`` starts resampled from the weighted particles, a chain of
    ``P - 1`` steps from each, and the first N of the chains' states (chain by chain, so that a chain's states stay
    together for the halves of later sweeps).

    Parameters
    ----------
    moves : Moves
        The sampler's moves component (its ``local_move``).
    position : (N, d) array
        The stage's particles in the moves' coordinates, before resampling.
    components : (N, k) array
        Their log-target components; ``coefficients (k,)`` weigh them into the stage's log target.
    log_weights : (N,) array
        The stage's normalised log-weights.
    component_fn, support
        As :func:`~seqbayes.moves.stretch.stretch_sweep`.
    rng : numpy.random.Generator
    scheme : str
        The resampling scheme of the starts.
    chain_length : int
        ``P``, states per chain including its start.

    Returns
    -------
    position : (N, d) array
        The chains' states, equally weighted.
    components : (N, k) array
    index : (N,) array of int
        Each state's start among the input particles (its ancestor).
    stats : SweepStats
        Of every step.
    n_steps : int
        Steps per chain (``P - 1``).
    """
    n, d = position.shape
    chain_length = max(1, min(int(chain_length), n))
    n_chains = -(-n // chain_length)
    weights = np.exp(log_weights - np.max(log_weights))
    starts = resample(scheme, weights / weights.sum(), rng, n_chains)
    gaussian = d > HIGH_DIMENSION  # only with waste_free_chains called directly above it
    # each chain proposes from the half of the particles its start is not in (complement_halves says why)
    halves = complement_halves(n, rng)
    in_first = np.zeros(n, dtype=bool)
    groups = []
    if halves:
        (first, second), _ = halves
        in_first[first] = True
        groups = [(np.flatnonzero(in_first[starts]), _half_proposal(position, log_weights, second, gaussian)),
                  (np.flatnonzero(~in_first[starts]), _half_proposal(position, log_weights, first, gaussian))]
    cov = weighted_covariance(position, log_weights)
    heads, head_components = position[starts].copy(), components[starts].copy()
    states, state_components = [heads.copy()], [head_components.copy()]
    stats, scale = SweepStats(), 1.0
    for _ in range(1, chain_length):
        for members, proposal in groups:
            if members.size:
                heads[members], head_components[members], sweep = independence_sweep(
                    heads[members], head_components[members], component_fn, coefficients, proposal, rng, support)
                stats = stats + sweep
        local, sweep_fn = moves.local_move(cov, scale, d)
        heads, head_components, sweep = sweep_fn(heads, head_components, component_fn, coefficients, local, rng,
                                                 support)
        stats = stats + sweep
        scale = float(scale * np.exp(sweep.acceptance_rate - LOCAL_ACCEPTANCE))  # Eq. (9)
        states.append(heads.copy())
        state_components.append(head_components.copy())
    # (P, chains, d) -> chain by chain
    chained = np.stack(states, axis=1).reshape(-1, d)[:n]
    chained_components = np.stack(state_components, axis=1).reshape(-1, components.shape[1])[:n]
    index = np.repeat(starts, chain_length)[:n]
    return chained, chained_components, index, stats, chain_length - 1
