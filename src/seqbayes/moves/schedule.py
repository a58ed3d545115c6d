"""The moves of one tempering stage and when they stop (the schedule shared by SMC, SEMC and SMC^2's PMMH).

:func:`move_stage` targets ``L^beta p_s`` with SMC's Gaussian random walk (Eq. A6-A8) or SEMC's stretch move
with its adaptive step size and virtual iterations (Algorithm 2), or, for many parameters or with ``economy``,
the scaled rounds of :func:`scaled_rounds` (independence sweeps from a fitted density, then a local sweep).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..engine.settings import ECONOMY_JUMP_TARGET, ECONOMY_MOVED_FRACTION, HIGH_DIMENSION, JUMP_TARGET, LOCAL_ACCEPTANCE
from ..priors import inside_space
from .base import SweepStats, combine
from .delayed import ModelScreen, QuadraticScreen, Screening, screened_sweep
from .gaussian import GaussianMove, gaussian_sweep, weighted_covariance
from .proposals import DefensiveProposal
from .scaled import DifferentialMove, FittedGaussian, differential_sweep, independence_sweep, whitened_jumps
from .stretch import StretchMove, stretch_sweep
from .tuning import next_step_size

__all__ = ["move_stage", "scaled_rounds", "stage_done", "stage_screen", "StageMoves"]


@dataclass(frozen=True, eq=False)
class StageMoves:
    """What the moves of one stage did: the particles ``walkers (N, d)`` and their ``components (N, 2)``
    after them, the sweeps' counts, SEMC's step size after them (NaN for SMC) and the sweeps (rounds) made."""

    walkers: np.ndarray
    components: np.ndarray
    stats: SweepStats
    step_size: float
    n_virtual: int


def stage_done(config, n_sweeps: int, position, start, alpha: float = float("nan"),
               alpha_old: float = float("nan")) -> bool:
    """Whether the sweeps of one stage stop: the schedule of SMC, SEMC and SMC^2's PMMH alike.

    At most ``max_moves`` (SMC) or ``max_virtual`` (SEMC) sweeps; before that, at least ``n_moves`` and until
    ``moved_fraction`` of the particles have moved since ``start`` (every particle should have had a fair chance
    to move, cf. PyMC's SMC), and for SEMC's stretch move until its acceptance rate ``alpha`` has settled
    (Algorithm 2's virtual iterations: ``|alpha - alpha_old| < virtual_tolerance * alpha_tr``).

    Parameters
    ----------
    n_sweeps : int
        Sweeps done so far in the stage.
    position, start : (N, d) arrays
        The particles now and at the stage's start (in the moves' coordinates).
    """
    stretch = config.move == "stretch"
    if n_sweeps >= (config.max_virtual if stretch else config.max_moves):
        return True
    if stretch and not abs(alpha - alpha_old) < config.virtual_tolerance * config.target_acceptance:
        return False
    if n_sweeps < config.n_moves:
        return False
    return config.moved_fraction == 0 or np.mean(np.any(position != start, axis=1)) >= config.moved_fraction


def move_stage(problem, config, state_step_size, walkers, components, beta, prior_logpdf, rng, loglike,
               kernel_density: bool = False):
    """The sampler's MCMC move at one tempering stage, targeting ``L^beta p_s`` (``loglike`` is ``log L``).

    With ``config.transform`` the move works in unconstrained coordinates
    (:class:`~seqbayes.transforms.BoxTransform`, with the log-Jacobian as a third
    target component); walkers that do not move keep their exact coordinates.
    ``kernel_density``: the scaled rounds' independence proposal is the kernel density at any dimension
    (:func:`scaled_rounds`). Returns a :class:`StageMoves`.
    """
    transform = problem.transform if config.transform else None
    if transform is None:
        position, support = walkers, problem.support if problem.bounded else None
        coefficients = np.array([beta, 1.0])

        def component_fn(points):
            return np.column_stack([loglike(points), prior_logpdf(points)])
    else:
        position, support = transform.forward(walkers), None
        components = np.column_stack([components, transform.log_jacobian(position)])
        coefficients = np.array([beta, 1.0, 1.0])

        def component_fn(points):
            theta = transform.inverse(points)
            inside = inside_space(theta, problem.support)  # round-off can land on a bound
            out = np.full((points.shape[0], 3), -np.inf)
            out[inside] = np.column_stack([loglike(theta[inside]), prior_logpdf(theta[inside]),
                                           transform.log_jacobian(points[inside])])
            return out

    start = position
    screening = Screening(stage_screen(config.surrogate, position, components, coefficients, beta, loglike,
                                       None if transform is None else transform.inverse,
                                       support if transform is None else None), config.surrogate == "auto")
    if config.uses_scaled_moves(walkers.shape[1]):
        position, components, stats, n_virtual = scaled_rounds(config, position, components, component_fn,
                                                               coefficients, support, rng, kernel_density)
        step_size = state_step_size if config.move == "stretch" else float("nan")
    elif config.move == "gaussian":
        stats = SweepStats()
        n_done = 0
        while True:
            move = GaussianMove(weighted_covariance(position), config.proposal_scale)
            if screening.active():
                position, components, sweep = screened_sweep(position, components, component_fn, coefficients, move,
                                                             rng, support, screening.screen, halves=False)
            else:
                position, components, sweep = gaussian_sweep(position, components, component_fn, coefficients,
                                                             move, rng, support)
            screening.record(sweep)
            stats = stats + sweep
            n_done += 1
            if stage_done(config, n_done, position, start):
                break
        step_size, n_virtual = float("nan"), 0
    else:  # SEMC: Algorithm 2 lines 9-21, continuing the ensemble through the virtual iterations
        step_size = state_step_size
        alpha_old = config.target_acceptance
        stats = SweepStats()
        n_virtual = 0
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
            step_size = next_step_size(step_size, alpha, config.target_acceptance)  # Eq. (9)
            if stage_done(config, n_virtual, position, start, alpha, alpha_old):
                break
            alpha_old = alpha
    if transform is not None:
        moved = np.any(position != start, axis=1)
        walkers = walkers.copy()
        walkers[moved] = transform.inverse(position[moved])
        components = components[:, :2]
    else:
        walkers = position
    return StageMoves(walkers, components, stats, step_size, n_virtual)


def stage_screen(setting, position, components, coefficients, beta, loglike, to_theta, support):
    """The cheap log target of one stage's delayed acceptance (``SamplerConfig.surrogate``), or ``None``.

    A quadratic fitted to the particles' log targets, or, for a callable ``surrogate(theta, dataset)``,
    ``beta`` times it plus the quadratic fitted to the other components (the prior's). ``None`` when the
    particles are too few to fit it, or, for a callable, when the step's dataset is not at hand (the
    path-space remedy's window likelihoods)."""
    if setting is None:
        return None
    if not callable(setting):
        return QuadraticScreen.fit(position, combine(components, coefficients))
    # ``loglike`` is the step's ValidatedLikelihood.loglike, which holds the dataset the user's model needs
    dataset = getattr(getattr(loglike, "__self__", None), "dataset", None)
    rest = QuadraticScreen.fit(position, combine(components[:, 1:], coefficients[1:]))
    if dataset is None or rest is None:
        return None
    return ModelScreen(setting, dataset, float(beta), rest, to_theta, support)


def scaled_rounds(config, position, components, component_fn, coefficients, support, rng,
                  kernel_density: bool = False):
    """The moves of :mod:`seqbayes.moves.scaled` at one stage (``SamplerConfig.scaled_moves``).

    Each round is an independence-MH sweep from ``N(mean, cov)`` fitted to ``position`` once, before the
    stage's moves, above ``HIGH_DIMENSION``, or, up to it or with ``kernel_density``, from the evidence's
    :class:`~seqbayes.moves.proposals.DefensiveProposal` fitted to the other half of the particles
    (:func:`_complement_sweep`), then a local sweep: SMC's random walk with
    ``2.38 / sqrt(d)`` times the covariance factor, or SEMC's differential-evolution move, each with a
    factor that follows Eq. (9) towards ``LOCAL_ACCEPTANCE`` from 1 at the stage's start. Rounds stop once
    the mean over particles of their accumulated squared whitened travel reaches ``JUMP_TARGET * 2 d``
    (``ECONOMY_JUMP_TARGET`` with ``economy``) and ``moved_fraction`` of them have moved
    (``ECONOMY_MOVED_FRACTION`` at most, with ``economy``), after at least ``n_moves`` rounds (1 with
    ``economy``) and at most ``max_moves`` (SMC) or ``max_virtual`` (SEMC).

    Parameters
    ----------
    position : (N, d) array
        The particles (in the move's coordinates); ``components (N, k)`` their log-target components,
        ``component_fn``, ``coefficients`` and ``support`` as in :func:`~seqbayes.moves.stretch_sweep`.

    Returns
    -------
    position, components : arrays after the moves
    stats : SweepStats
        Of every sweep (independence and local).
    n_rounds : int
    """
    n, d = position.shape
    fitted = FittedGaussian(np.full(n, 1.0 / n) @ position, weighted_covariance(position))
    # the global proposal: up to d = 10 the importance density (kernel density + t), which follows a funnel; it is
    # fitted afresh to the other half of the particles at each sweep (:func:`_complement_sweep`)
    globally = fitted if d > HIGH_DIMENSION and not kernel_density else None
    target = (ECONOMY_JUMP_TARGET if config.economy else JUMP_TARGET) * 2.0 * d
    min_rounds = 1 if config.economy else config.n_moves
    max_rounds = config.max_moves if config.move == "gaussian" else config.max_virtual
    moved_fraction = min(config.moved_fraction, ECONOMY_MOVED_FRACTION) if config.economy else config.moved_fraction
    scale, stats, travelled, n_rounds = 1.0, SweepStats(), np.zeros(n), 0
    while n_rounds < max_rounds:
        before = position
        if globally is None:
            position, components, sweep = _complement_sweep(position, components, component_fn, coefficients, rng,
                                                             support)
        else:
            position, components, sweep = independence_sweep(position, components, component_fn, coefficients,
                                                             globally, rng, support)
        stats = stats + sweep
        if config.move == "gaussian":
            local = GaussianMove(fitted.cov, scale * 2.38 / np.sqrt(d))
            position, components, sweep = gaussian_sweep(position, components, component_fn, coefficients, local,
                                                         rng, support)
        else:
            position, components, sweep = differential_sweep(position, components, component_fn, coefficients,
                                                             DifferentialMove(scale), rng, support)
        scale = float(scale * np.exp(sweep.acceptance_rate - LOCAL_ACCEPTANCE))  # Eq. (9)
        stats = stats + sweep
        travelled += whitened_jumps(before, position, fitted)
        n_rounds += 1
        if n_rounds >= min_rounds and travelled.mean() >= target and np.mean(travelled > 0) >= moved_fraction:
            break
    return position, components, stats, n_rounds


def _complement_sweep(position, components, component_fn, coefficients, rng, support):
    """One independence sweep from the kernel density: each half of the particles proposes from the
    :class:`~seqbayes.moves.proposals.DefensiveProposal` fitted to the other half, the halves contiguous in the
    particles' order, cut at a random place.

    A kernel density fitted to the particles it moves has a kernel on each of them: the particle's own ``q`` is
    inflated, its ``pi / q`` deflated, most where the particles are sparse (a tail, a minor mode), so they leave
    it too readily and the sweep no longer leaves ``pi`` invariant (in d = 10 the inflation is many-fold). Fitted
    to the other half, ``q`` does not depend on the walkers it moves, and the sweep leaves ``pi^N`` invariant, as
    the stretch move's halves do. Contiguous halves keep a resampled particle's copies, and their descendants,
    together (the samplers' resampling returns sorted indices): a copy or a near copy in the other half would
    put the kernel back on the particle, and a random split measurably did (docs/jump_kernels.md, "Why the path
    cloud's tail is light"). Arguments and returns as :func:`~seqbayes.moves.scaled.independence_sweep`.
    """
    n = position.shape[0]
    order = np.roll(np.arange(n), -int(rng.integers(n)))
    halves = (order[: n // 2], order[n // 2:])
    position, components, stats = position.copy(), components.copy(), SweepStats()
    for active, passive in (halves, halves[::-1]):
        proposal = DefensiveProposal(position[passive], np.zeros(passive.size))
        moved, moved_components, sweep = independence_sweep(position[active], components[active], component_fn,
                                                            coefficients, proposal, rng, support)
        position[active], components[active] = moved, moved_components
        stats = stats + sweep
    return position, components, stats
