"""The moves of one tempering stage and when they stop (the schedule shared by SMC, SEMC and SMC^2's PMMH).

:func:`move_stage` targets ``L^beta p_s`` with SMC's Gaussian random walk (Eq. A6-A8) or SEMC's stretch move
with its adaptive step size and virtual iterations (Algorithm 2), or, for many parameters or with ``economy``,
the scaled rounds of :func:`scaled_rounds` (independence sweeps from a fitted density, then a local sweep).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..priors import inside_space
from ..weights import resample
from ..core.state import Cloud
from .base import HIGH_DIMENSION, MoveTally, NoScreen, SweepStats, combine, evaluate_inside, metropolis_accept
from .delayed import ModelScreen, QuadraticScreen, Screening, screened_sweep
from .gaussian import weighted_covariance
from .proposals import DefensiveProposal, complement_halves
from .scaled import FittedGaussian, SuffixMove, independence_sweep, whitened_jumps

__all__ = ["move_stage", "scaled_rounds", "stage_screen", "StageMoves", "prior_sweep", "Staged", "ResampleMove",
           "PathTarget"]
#: Scaled moves stop when the particles' mean squared whitened travel reaches this fraction of 2 d.
JUMP_TARGET, ECONOMY_JUMP_TARGET = 1.0, 0.5
#: ``economy``: the scaled moves stop once this fraction of the particles has moved (at most ``moved_fraction``).
ECONOMY_MOVED_FRACTION = 0.7
#: Acceptance rate the scaled moves' local step aims at (Eq. 9 adapts its scale within a stage; Roberts et al. 1997).
LOCAL_ACCEPTANCE = 0.234

#: The prior's redraws' share of the global sweep in a tempering's first round (:func:`scaled_rounds` with
#: ``resimulate``), and the bounds it adapts within.
PRIOR_SHARE, SHARE_BOUNDS = 0.5, (0.02, 0.9)


@dataclass(frozen=True, eq=False)
class StageMoves:
    """What the moves of one stage did: the particles ``walkers (N, d)`` and their ``components (N, 2)``
    after them, the sweeps' counts, SEMC's step size after them (NaN for SMC), the sweeps (rounds) made and the
    prior's redraws' share of the global sweep after them (:func:`scaled_rounds`; the next stage starts from it)."""

    walkers: np.ndarray
    components: np.ndarray
    stats: SweepStats
    step_size: float
    n_virtual: int
    prior_share: float = float("nan")


@dataclass(frozen=True, eq=False)
class Staged:
    """The particles of an SMC/SEMC step between the stages of the tempering loop
    (:func:`~seqbayes.core.tempering.temper`): the cloud, what the moves did so far, the prior's redraws' share
    (:func:`scaled_rounds`) and whether the last stage resampled."""

    cloud: Cloud
    moves: MoveTally
    prior_share: float = PRIOR_SHARE
    resampled: bool = False


@dataclass(frozen=True)
class PathTarget:
    """How the scaled rounds move a target (:func:`move_stage`): ``kernel_density``, the independence proposal is
    the kernel density at any dimension; ``prior_moves``, the target's prior when it can redraw part of a walker
    given the rest; ``path_states``, the walkers are paths of that many states. The defaults: a state's target."""

    kernel_density: bool = False
    prior_moves: object = None
    path_states: int = 1


class ResampleMove:
    """The particle predictives' mutation (:class:`~seqbayes.core.tempering.Mutation`): after each stage,
    resample (always at an intermediate stage; at the last when the ESS is below ``resample_below * N`` and the
    schedule does not defer it, IBIS's ``deferred``) and move (:func:`move_stage`) at every stage that resampled,
    or at every stage with ``move_every_stage``, and with the moves' ``economy`` once more at the last stage of a tempered
    step. ``stage_check(particles)`` is called with each intermediate stage's resampled particles; what it returns
    (``None`` to go on) stops the loop. ``target``: as :func:`move_stage`."""

    def __init__(self, problem, config, likelihood, prior_logpdf, move_every_stage: bool, deferred: bool, rng,
                 target: PathTarget = PathTarget(), stage_check=None):
        self.problem, self.config, self.likelihood, self.prior_logpdf = problem, config, likelihood, prior_logpdf
        self.move_every_stage, self.deferred, self.rng, self.stage_check = move_every_stage, deferred, rng, stage_check
        self.target = target

    def __call__(self, staged: Staged, loglike, stage):
        config, rng, beta = self.config, self.rng, stage.beta
        cloud = staged.cloud
        n = cloud.particles.shape[0]
        particles, components, labels, log_weights = cloud.particles, cloud.components, cloud.labels, stage.log_weights
        decision = None
        resampled = beta < 1.0 or (stage.ess < config.tempering.resample_below * n and not self.deferred)
        if resampled:
            index = resample(config.tempering.scheme, stage.weights, rng, n)
            particles, components = particles[index], components[index]
            labels = None if labels is None else labels[index]   # copies keep their initial draw's label
            log_weights = np.full(n, -np.log(n))
            if self.stage_check is not None and beta < 1.0:
                decision = self.stage_check(particles)
        moves, prior_share = staged.moves, staged.prior_share
        # economy: a tempered step's last moves are at the posterior itself (the intermediate stages' moves are cut short)
        if decision is None and (resampled or self.move_every_stage
                                 or (config.moves.economy and beta == 1.0 and stage.index > 1)):
            components = self.prior_logpdf.refreshed(particles, components)  # a pseudo-marginal estimate gone poor
            moved = move_stage(self.problem, config.moves, moves.step_size, particles, components, beta,
                               self.prior_logpdf, rng, self.likelihood.loglike, prior_share, self.target)
            particles, components, moves = moved.walkers, moved.components, moves.then(moved, config.moves)
            prior_share = moved.prior_share  # the prior's redraws only lose ground as beta grows
        staged = Staged(Cloud(particles, log_weights, components, labels), moves, prior_share, resampled)
        return staged, components[:, 0], log_weights, decision


def move_stage(problem, moves, state_step_size, walkers, components, beta, prior_logpdf, rng, loglike,
               prior_share: float = PRIOR_SHARE, target: PathTarget = PathTarget()):
    """The sampler's MCMC moves at one tempering stage, targeting ``L^beta p_s`` (``loglike`` is ``log L``): the
    ``moves`` component's stage (:meth:`~seqbayes.moves.stretch.Stretch.stage`,
    :meth:`~seqbayes.moves.gaussian.RandomWalk.stage`) or, for many parameters or with ``economy``, the scaled
    rounds of :func:`scaled_rounds`.

    With ``moves.transform`` the move works in unconstrained coordinates
    (:class:`~seqbayes.priors.BoxTransform`, with the log-Jacobian as a third
    target component); walkers that do not move keep their exact coordinates.
    ``target`` (:class:`PathTarget`): with ``kernel_density`` the scaled rounds' independence proposal is the kernel
    density at any dimension (:func:`scaled_rounds`); ``prior_moves``, the target's prior, when it can redraw part
    of a walker given the rest (``resimulate(theta (n, D), rng) -> (proposals (n, D), changed (n, D) bool)``, as
    :meth:`seqbayes.predictive.paths.PathPrior.resimulate`; ``prior_logpdf`` must be its exact log-density); the
    scaled rounds then mix in :func:`prior_sweep`, from ``prior_share`` (the last stage's
    :attr:`StageMoves.prior_share`); ``path_states``, the walkers are paths of that many states, whose scaled
    rounds' local sweep moves a random suffix of each (:func:`scaled_rounds`). Returns a :class:`StageMoves`.
    """
    kernel_density, prior_moves, path_states = target.kernel_density, target.prior_moves, target.path_states
    transform = problem.transform if moves.transform else None
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
    if moves.uses_scaled(walkers.shape[1]):
        resimulate = None if prior_moves is None else _resimulation_fn(prior_moves, transform, problem.support)
        position, components, stats, n_virtual, prior_share = scaled_rounds(
            moves, position, components, component_fn, coefficients, support, rng, kernel_density, resimulate,
            prior_share, path_states)
        step_size = moves.step_size_after(state_step_size, float("nan"))
    else:
        screening = NoScreen() if moves.screen is None else Screening(
            stage_screen(moves.screen, position, components, coefficients, beta, loglike,
                         None if transform is None else transform.inverse, support if transform is None else None),
            moves.screen == "auto")
        position, components, stats, step_size, n_virtual = moves.stage(position, components, component_fn,
                                                                         coefficients, support, rng, screening,
                                                                         state_step_size)
    if transform is not None:
        moved = np.any(position != start, axis=1)
        walkers = walkers.copy()
        walkers[moved] = transform.inverse(position[moved])
        components = components[:, :2]
    else:
        walkers = position
    return StageMoves(walkers, components, stats, step_size, n_virtual,
                      prior_share if prior_moves is not None else float("nan"))


def stage_screen(setting, position, components, coefficients, beta, loglike, to_theta, support):
    """The cheap log target of one stage's delayed acceptance (:attr:`~seqbayes.moves.base.Moves.screen`), or ``None``.

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


def _resimulation_fn(prior_moves, transform, box):
    """``resimulate(position, rng) -> (n, D)`` proposals of ``prior_moves.resimulate`` in the moves' coordinates:
    the coordinates it kept are the walkers' own, bit for bit; NaN rows where a proposal leaves the parameter
    space ``box`` under the transform (a proposal the target rejects)."""
    def resimulate(position, rng):
        theta = position if transform is None else transform.inverse(position)
        proposals, changed = prior_moves.resimulate(theta, rng)
        if transform is None:
            return np.where(changed, proposals, position)
        inside = inside_space(proposals, box)
        out = np.full(position.shape, np.nan)
        out[inside] = np.where(changed[inside], transform.forward(proposals[inside]), position[inside])
        return out
    return resimulate


def prior_sweep(walkers, components, component_fn, coefficients, resimulate, rng, support):
    """Every walker proposes to redraw part of itself from the target's prior given the rest (``resimulate``:
    the path prior's states from a random one on, forward through the kernel); accept with
    ``min(1, (L* / L)^beta)``, as the prior's factors and the proposal's cancel (and the transform's Jacobian
    with them, coordinate by coordinate). Where ``beta`` is small the prior is the target's dominant factor
    and a kernel density of the stage's particles is not: the path prior is a thin chain of transitions.
    Arguments and returns as :func:`~seqbayes.moves.scaled.independence_sweep`."""
    n = walkers.shape[0]
    proposals = resimulate(walkers, rng)
    valid = np.isfinite(proposals).all(axis=1)
    proposal_components = np.full(components.shape, -np.inf)
    proposal_components[valid], n_eval = evaluate_inside(component_fn, proposals[valid], support, components.shape[1])
    alive = np.isfinite(combine(proposal_components, coefficients))
    accept = metropolis_accept(coefficients[0] * components[:, 0],
                               np.where(alive, coefficients[0] * proposal_components[:, 0], -np.inf), 0.0, rng)
    walkers = np.where(accept[:, None], proposals, walkers)
    components = np.where(accept[:, None], proposal_components, components)
    return walkers, components, SweepStats(n, int(accept.sum()), 0, n_eval)


def _global_sweep(position, components, component_fn, coefficients, gaussian, resimulate, share, rng, support):
    """The round's global sweep: the independence sweep of :func:`_complement_sweep` (``gaussian``: from the
    fitted Gaussian, else the kernel density), or with ``resimulate`` a random
    scan of it and :func:`prior_sweep` (each walker takes the prior's with probability ``share``; each kernel
    keeps the target, so their mixture does). Returns the sweep's ``position, components, stats``, the next
    ``share`` (the prior's part of the two acceptance rates, within ``SHARE_BOUNDS``) and the prior's acceptance
    rate."""
    if resimulate is None:
        return (*_complement_sweep(position, components, component_fn, coefficients, rng, support, gaussian=gaussian),
                share, 0.0)
    chosen = rng.random(position.shape[0]) < share
    position, components = position.copy(), components.copy()
    stats, prior_rate, other_rate = SweepStats(), 0.0, 0.0
    if chosen.any():
        position[chosen], components[chosen], sweep = prior_sweep(position[chosen], components[chosen], component_fn,
                                                                  coefficients, resimulate, rng, support)
        stats, prior_rate = stats + sweep, sweep.acceptance_rate
    if not chosen.all():
        position, components, sweep = _complement_sweep(position, components, component_fn, coefficients, rng,
                                                        support, movable=~chosen, gaussian=gaussian)
        stats, other_rate = stats + sweep, sweep.acceptance_rate
    total = prior_rate + other_rate
    share = float(np.clip(prior_rate / total if total > 0 else share, *SHARE_BOUNDS))
    return position, components, stats, share, prior_rate


def scaled_rounds(moves, position, components, component_fn, coefficients, support, rng,
                  kernel_density: bool = False, resimulate=None, share: float = PRIOR_SHARE, path_states: int = 1):
    """The moves of :mod:`seqbayes.moves.scaled` at one stage (:attr:`~seqbayes.moves.base.Moves.scaled`), with the
    local move of the ``moves`` component (:meth:`~seqbayes.moves.stretch.Stretch.local_move`).

    Each round is an independence-MH sweep in which each half of the particles proposes from a density fitted to
    the other half (:func:`_complement_sweep`): ``N(mean, cov)`` above ``HIGH_DIMENSION``, or, up to it or with
    ``kernel_density``, the evidence's :class:`~seqbayes.moves.proposals.DefensiveProposal`; then a local sweep:
    SMC's random walk with
    ``2.38 / sqrt(d)`` times the covariance factor, or SEMC's differential-evolution move, each with a
    factor that follows Eq. (9) towards ``LOCAL_ACCEPTANCE`` from 1 at the stage's start. Rounds stop once
    the mean over particles of their accumulated squared whitened travel reaches ``JUMP_TARGET * 2 d``
    (``ECONOMY_JUMP_TARGET`` with ``economy``) and ``moved_fraction`` of them have moved
    (``ECONOMY_MOVED_FRACTION`` at most, with ``economy``), after at least ``n_moves`` rounds (1 with
    ``economy``) and at most ``max_moves`` (SMC) or ``max_virtual`` (SEMC).

    With ``resimulate`` (the path-space bridge: its early stages' targets are thin ridges of the path prior, where
    the kernel density and the local move accept almost nothing) each walker's global move is, at random, the
    prior's redraw (:func:`prior_sweep`, with probability ``share`` in the first round, then the prior's part of the
    last round's acceptances, within ``SHARE_BOUNDS``) or the independence sweep; and after the first round the
    local sweep gives way to a second :func:`prior_sweep` while the prior's redraws are accepted more often than
    the local move was. Each is an exact Metropolis-Hastings kernel of the stage's target.

    With ``path_states > 1`` (the path-space remedy) the local sweep moves each path from a random state on
    (:class:`~seqbayes.moves.scaled.SuffixMove`): a likelihood that keeps each state's value then evaluates only the
    moved states, and the later states, which the newest data pull hardest, move most often.

    Parameters
    ----------
    position : (N, d) array
        The particles (in the move's coordinates); ``components (N, k)`` their log-target components,
        ``component_fn``, ``coefficients`` and ``support`` as in :func:`~seqbayes.moves.stretch_sweep`.
    resimulate : callable, optional
        ``resimulate(position, rng) -> (N, d)`` proposals redrawing part of each walker from the prior given the
        rest, in the move's coordinates (NaN rows: outside the parameter space); see :func:`prior_sweep`.
    share : float
        The redraws' share of the first round's global sweep (with ``resimulate``).
    path_states : int
        The walkers are paths of that many states of equal dimension (1: the local sweep moves whole walkers).

    Returns
    -------
    position, components : arrays after the moves
    stats : SweepStats
        Of every sweep (independence and local).
    n_rounds : int
    share : float
        The redraws' share after the last round (``share`` itself without ``resimulate``).
    """
    n, d = position.shape
    fitted = _fitted_gaussian(position)
    # the global proposal, fitted afresh to the other half of the particles at each sweep (_complement_sweep): up to
    # d = 10 the importance density (kernel density + t), which follows a funnel, above it a Gaussian
    gaussian = d > HIGH_DIMENSION and not kernel_density
    target = (ECONOMY_JUMP_TARGET if moves.economy else JUMP_TARGET) * 2.0 * d
    min_rounds = 1 if moves.economy else moves.min_sweeps
    max_rounds = moves.max_sweeps
    moved_fraction = min(moves.moved_fraction, ECONOMY_MOVED_FRACTION) if moves.economy else moves.moved_fraction
    scale, stats, travelled, n_rounds = 1.0, SweepStats(), np.zeros(n), 0
    local_rate = 1.0
    while n_rounds < max_rounds:
        before = position
        position, components, sweep, share, prior_rate = _global_sweep(
            position, components, component_fn, coefficients, gaussian, resimulate, share, rng, support)
        stats = stats + sweep
        if resimulate is not None and n_rounds and prior_rate > local_rate:
            # the prior's redraws move more walkers than the local move did last: they take its sweep
            position, components, sweep = prior_sweep(position, components, component_fn, coefficients, resimulate,
                                                      rng, support)
        else:
            local, sweep_fn = moves.local_move(fitted.cov, scale, d)
            if path_states > 1:
                local = SuffixMove(local, path_states)
            position, components, sweep = sweep_fn(position, components, component_fn, coefficients, local, rng,
                                                   support)
            # Eq. (9)
            local_rate, scale = sweep.acceptance_rate, float(scale * np.exp(sweep.acceptance_rate - LOCAL_ACCEPTANCE))
        stats = stats + sweep
        travelled += whitened_jumps(before, position, fitted)
        n_rounds += 1
        if n_rounds >= min_rounds and travelled.mean() >= target and np.mean(travelled > 0) >= moved_fraction:
            break
    return position, components, stats, n_rounds, share


def _fitted_gaussian(points) -> FittedGaussian:
    """``N(mean, cov)`` of the equally weighted ``points (n, d)`` (the mean as a matrix-vector product, as
    :func:`~seqbayes.moves.gaussian.weighted_covariance` takes it)."""
    n = points.shape[0]
    return FittedGaussian(np.full(n, 1.0 / n) @ points, weighted_covariance(points))


def _complement_sweep(position, components, component_fn, coefficients, rng, support, movable=None,
                      gaussian: bool = False):
    """One independence sweep: each half of the particles proposes from the density fitted to the other half
    (:func:`~seqbayes.moves.proposals.complement_halves`, which says why), the
    :class:`~seqbayes.moves.proposals.DefensiveProposal` or, with ``gaussian``, the
    :class:`~seqbayes.moves.scaled.FittedGaussian` (above ``HIGH_DIMENSION``). Arguments and returns as
    :func:`~seqbayes.moves.scaled.independence_sweep`; ``movable`` (``(N,)`` bool): only those walkers move (the
    others still make up the densities).
    """
    position, components, stats = position.copy(), components.copy(), SweepStats()
    for active, passive in complement_halves(position.shape[0], rng):
        if movable is not None:
            active = active[movable[active]]
        if active.size == 0:
            continue
        if gaussian:
            proposal = _fitted_gaussian(position[passive])
        else:
            proposal = DefensiveProposal(position[passive], np.zeros(passive.size))
        moved, moved_components, sweep = independence_sweep(position[active], components[active], component_fn,
                                                            coefficients, proposal, rng, support)
        position[active], components[active] = moved, moved_components
        stats = stats + sweep
    return position, components, stats
