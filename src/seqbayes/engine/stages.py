"""The stages of one update that every predictive shares: weigh the prior particles by the likelihood
(with a restart from the restricted prior), reweight by tempering increments, resample and move."""

from __future__ import annotations

import numpy as np

from ..moves.schedule import PRIOR_SHARE, move_stage
from ..priors import inside_space
from ..resampling import resample
from ..results import prior_data_conflict
from ..tempering import next_increment
from ..weights import ess, logsumexp
from .errors import TemperingLimitError, ZeroLikelihoodError, zero_likelihood_message
from .likelihood import row_hashes
from .state import Cloud, Tempered

__all__ = ["ExactPrior", "weigh", "restricted_draws", "rejuvenate_deferred", "reweight_stage", "temper_resample_move",
           "count_distinct", "step_conflict", "prior_name"]


class ExactPrior:
    """A step's prior density as the stages evaluate it, exactly: ``prior(theta (M, d)) -> (M,)``, its values at
    the step's particles (:meth:`start`) and, between stages, nothing to refresh. The pseudo-marginal
    :class:`~seqbayes.predictive.pseudo_marginal.SubsampledPrior` has the same three methods."""

    def __init__(self, logpdf):
        self.logpdf = logpdf

    def __call__(self, theta) -> np.ndarray:
        return self.logpdf(theta)

    def start(self, particles, log_weights, loglike, own_draws: bool = True) -> np.ndarray:
        """``(N,)`` prior values of the particles, where their likelihood is non-zero (``-inf`` elsewhere)."""
        out = np.full(particles.shape[0], -np.inf)
        carried = np.isfinite(loglike)
        out[carried] = self.logpdf(particles[carried])
        return out

    def refreshed(self, particles, components) -> np.ndarray:
        return components


def count_distinct(samples) -> int:
    """Number of distinct rows of ``samples (N, d)``, by a 64-bit hash of their bit patterns.

    8x faster than ``np.unique(samples, axis=0)``: rows that differ in one coordinate never
    collide (odd multipliers), others with probability ~``N^2 / 2^65``.
    """
    samples = np.asarray(samples, dtype=float)
    hashes = row_hashes(samples)
    if hashes is None:
        return int(np.unique(samples, axis=0).shape[0])
    hashes.sort()
    return 1 + int(np.count_nonzero(hashes[1:] != hashes[:-1]))


def prior_name(step: int) -> str:
    """What the particles of ``step`` were drawn from, for error messages."""
    return "prior" if step == 1 else "predictive distribution"


def step_conflict(prior, prior_log_weights, posterior, posterior_log_weights, support) -> np.ndarray:
    """``StepInfo.prior_data_conflict`` per parameter, ``(d,)``: how many sds of the step's prior the
    posterior mean lies from the prior mean (:func:`seqbayes.results.prior_data_conflict`).

    The step's prior is the predictive restricted to the parameter space (the likelihood is zero
    outside, so that mass is lost, as in the samplers' steps and the exact grid references): its
    moments are those of the prior draws inside ``support`` (all of them when fewer than two are inside:
    one draw has no spread, and its sd of 0 would report a conflict of ~1e150). A predictive that spills
    over a bound (a drift taking a damping below 0) thus does not count as a conflict with the data (the
    unrestricted moments raise false alarms: docs/prior_data_conflict.md).
    """
    inside = inside_space(prior, support)
    if np.count_nonzero(inside) > 1 and not inside.all():
        prior, prior_log_weights = prior[inside], prior_log_weights[inside]
    return prior_data_conflict(prior, prior_log_weights, posterior, posterior_log_weights)


def restricted_draws(prior, support, n, rng, step, likelihood, max_rounds=100):
    """``n`` equal-weight draws of ``prior`` restricted to ``{theta in the parameter space, L(theta) > 0}``
    by rejection, their log-likelihoods, the log of the restricted prior mass (the acceptance
    fraction of the rejection sampler), the number of distinct draws found and ``(n,)`` labels
    (:attr:`SamplerState.lineage`): the index of each draw among the distinct ones (copies share it)."""
    kept, kept_ll, n_drawn, n_kept = [], [], 0, 0
    while n_kept < n and n_drawn < max_rounds * n:
        draws = prior.sample(n, rng)
        loglike = np.full(n, -np.inf)
        inside = inside_space(draws, support)
        loglike[inside] = likelihood.loglike(draws[inside])
        ok = np.isfinite(loglike)
        kept.append(draws[ok])
        kept_ll.append(loglike[ok])
        n_drawn, n_kept = n_drawn + n, n_kept + int(ok.sum())
    if n_kept == 0 and 0 < likelihood.n_evals <= likelihood.n_nan:  # the model failed, the prior is not to blame
        raise ZeroLikelihoodError(zero_likelihood_message(step, prior_name(step), likelihood))
    if n_kept == 0:
        raise ZeroLikelihoodError(
            f"step {step}: every sample has zero likelihood (0 of {n_drawn} draws of the "
            f"{prior_name(step)} are inside the parameter space with a "
            f"non-zero likelihood); the {prior_name(step)} is too far "
            f"from the data")
    kept, kept_ll = np.concatenate(kept), np.concatenate(kept_ll)
    labels = np.arange(n)
    if n_kept < n:  # almost no mass: duplicate what there is (the caller is told through n_kept)
        index = rng.integers(n_kept, size=n)
        kept, kept_ll, labels = kept[index], kept_ll[index], index
    return kept[:n], kept_ll[:n], float(np.log(n_kept / n_drawn)), n_kept, labels


def rejuvenate_deferred(state, problem, config, prior_logpdf, moves, rng):
    """IBIS's schedule: the last step's resample-move, deferred to this dataset's arrival (its target
    is this step's prior, the last posterior). Returns the particles, their log-weights, their prior
    values (or None), the moves, whether it ran and the particles' labels (the index of the last
    posterior's particle each descends from)."""
    n = config.n_samples
    particles, log_weights = state.particles, state.log_weights
    if ess(log_weights) >= config.ess_threshold * n:
        return particles, log_weights, state.log_prior, moves, False, np.arange(n)
    index = resample(config.resampling, np.exp(log_weights), rng, n)
    values = prior_logpdf(particles) if state.log_prior is None else state.log_prior
    moved = move_stage(problem, config, moves.step_size, particles[index],
                       np.column_stack([np.zeros(n), values[index]]), 0.0, prior_logpdf, rng,
                       lambda theta: np.zeros(theta.shape[0]))
    return (moved.walkers, np.full(n, -np.log(n)), moved.components[:, 1], moves.then(moved, config.move), True,
            index)


def weigh(state, particles, log_weights, log_prior, problem, config, likelihood, prior_logpdf, rng, labels=None,
          exact_prior=False):
    """Stage 1: the likelihood at the prior particles (Eq. A4). When few of them can carry the step
    (predictive mass outside the parameter space, or a zero-likelihood region such as stick-slip)
    the step restarts from the prior restricted to ``{inside, L > 0}``.

    ``labels (N,)``: the particles' labels (the index of the last posterior's particle each is the
    draw of; ``arange(N)`` if omitted), the cloud's unless the step restarts (then the restart draws').

    ``exact_prior``: the step's prior is exact (the history prior), so the step never restarts.

    Returns the cloud, the log of the restricted prior mass (0 without restart) and the number of
    distinct restart draws (N without restart)."""
    n, step = config.n_samples, likelihood.step
    inside = inside_space(particles, problem.support)
    if inside.all():
        loglike = likelihood.loglike(particles)
    else:
        loglike = np.full(n, -np.inf)
        loglike[inside] = likelihood.loglike(particles[inside])
    valid = np.isfinite(loglike)
    log_restricted_mass, n_found, restarted = 0.0, n, False
    labels = np.arange(n) if labels is None else labels
    if not valid.any() and (inside.all() or exact_prior):
        raise ZeroLikelihoodError(zero_likelihood_message(step, prior_name(step), likelihood))
    if not exact_prior and not valid.all() and (not inside.all() or valid.sum() < _min_valid(config, particles)):
        particles, loglike, log_restricted_mass, n_found, labels = restricted_draws(state.prior, problem.support,
                                                                                     n, rng, step, likelihood)
        log_weights, restarted = np.full(n, -np.log(n)), True
    if log_prior is not None:
        components = np.column_stack([loglike, log_prior])
    else:  # every particle is inside now; the prior is only needed where the likelihood is non-zero
        components = np.column_stack([loglike, np.full(n, -np.inf)])
        components[:, 1] = prior_logpdf.start(particles, log_weights, loglike, own_draws=not restarted)
    return Cloud(particles, log_weights, components, labels), log_restricted_mass, n_found


def _min_valid(config, particles) -> float:
    """Fewest particles with a non-zero likelihood that start a step without the restricted-prior restart
    (``min_valid_fraction * N``; with ``economy`` at most ``d + 1``, enough for a full-rank fitted covariance:
    the restart's rejection sampling costs N / (valid fraction) likelihood calls, 65,000 of them at N = 1000
    for the Coulomb experiment's first dataset, where the tempering's resample-move spreads the ~15 valid
    particles instead)."""
    threshold = config.min_valid_fraction * particles.shape[0]
    return min(threshold, particles.shape[1] + 1.0) if config.economy else threshold


def reweight_stage(log_weights, loglike, beta, n_stages, config, step):
    """One stage of Eq. (A5): reweight by ``L^delta`` with the next tempering increment ``delta``.

    Parameters
    ----------
    log_weights : (N,) array
        Normalised log-weights before the stage.
    loglike : (N,) array
        ``log L`` (or SMC^2's log-likelihood estimates), ``-inf`` allowed.
    beta : float
        Exponent reached so far; ``n_stages`` stages done.

    Returns
    -------
    beta, stage_log_z, log_weights, weights, ess
        The new exponent, the stage's log mean weight (Eq. 1), the new normalised log-weights,
        their weights and ESS.
    """
    if n_stages >= config.max_stages:
        raise TemperingLimitError(
            f"step {step}: tempering reached exponent {beta:.3g} after max_stages = {config.max_stages} "
            f"stages; the dataset lies very far from the {prior_name(step)}"
            f" (check its units and the model), or raise max_stages")
    remaining = 1.0 - beta
    delta = (next_increment(log_weights, loglike, remaining, config.tempering_ess, config.tempering_threshold)
             if config.tempering else remaining)
    if remaining - delta < 1e-12:
        delta = remaining
    finite = np.isfinite(loglike)
    increment = np.where(finite, delta * np.where(finite, loglike, 0.0), -np.inf)
    stage_log_z = logsumexp(log_weights + increment)  # Eq. (1), one stage
    if not np.isfinite(stage_log_z):  # the particles with a non-zero likelihood all have zero weight
        raise ZeroLikelihoodError(f"step {step}: every sample with a non-zero weight has zero likelihood; the "
                                  f"{prior_name(step)} is too far from the data")
    beta = 1.0 if delta == remaining else beta + delta
    log_weights = log_weights + increment - stage_log_z  # normalised: the carried weights sum to one
    weights = np.exp(log_weights)
    return beta, stage_log_z, log_weights, weights, float(1.0 / np.dot(weights, weights))


def temper_resample_move(cloud, problem, config, likelihood, prior_logpdf, moves, move_every_stage, deferred, rng,
                         kernel_density=False, prior_moves=None, path_states=1, stage_check=None):
    """Stages 2-4: reweight by ``L^delta`` (Eq. A5, one stage or adaptive tempering), resample, move
    (``kernel_density``, ``prior_moves``, ``path_states``: as :func:`~seqbayes.moves.schedule.move_stage`).
    ``stage_check(particles)`` is called with each intermediate stage's resampled particles (it may raise
    :class:`~seqbayes.engine.errors.PlainConflict`).

    Returns a :class:`~seqbayes.engine.state.Tempered` whose ``log_z`` is the path's log-evidence (Eq. 1) without
    any restricted mass (the caller's)."""
    n, step = config.n_samples, likelihood.step
    particles, log_weights, components, labels = cloud.particles, cloud.log_weights, cloud.components, cloud.labels
    beta, log_z, temperatures, prior_share = 0.0, 0.0, [], PRIOR_SHARE
    while beta < 1.0:
        beta, stage_log_z, log_weights, weights, stage_ess = reweight_stage(log_weights, components[:, 0], beta,
                                                                            len(temperatures), config, step)
        log_z += stage_log_z
        temperatures.append(beta)
        resampled = beta < 1.0 or (stage_ess < config.ess_threshold * n and not deferred)
        if resampled:
            index = resample(config.resampling, weights, rng, n)
            particles, components = particles[index], components[index]
            labels = None if labels is None else labels[index]   # copies keep their initial draw's label
            log_weights = np.full(n, -np.log(n))
            if stage_check is not None and beta < 1.0:
                stage_check(particles)
        # economy: a tempered step's last moves are at the posterior itself (the intermediate stages' moves are cut short)
        if resampled or move_every_stage or (config.economy and beta == 1.0 and len(temperatures) > 1):
            components = prior_logpdf.refreshed(particles, components)  # a pseudo-marginal estimate gone poor
            moved = move_stage(problem, config, moves.step_size, particles, components, beta, prior_logpdf, rng,
                               likelihood.loglike, kernel_density, prior_moves, prior_share, path_states)
            particles, components, moves = moved.walkers, moved.components, moves.then(moved, config.move)
            prior_share = moved.prior_share  # the prior's redraws only lose ground as beta grows
    return Tempered(Cloud(particles, log_weights, components, labels), log_z, tuple(temperatures), moves, resampled,
                    stage_ess)
