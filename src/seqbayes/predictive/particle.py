"""The particle predictives: :class:`ParticlePredictive`, the shared stages of the predictives whose particles are
draws of the step's prior (the :class:`~seqbayes.core.state.Predictive` protocol that the pipeline,
:func:`~seqbayes.engine.drivers.run_step`, goes through), and the stages every particle predictive shares: weigh the
prior particles by the likelihood (with a restart from the restricted prior), temper/resample/move through the one
tempering loop (:func:`~seqbayes.core.tempering.temper`, :func:`temper_stages`).

Each method takes the step's validated likelihood (:class:`~seqbayes.core.likelihood.ValidatedLikelihood`) and the
generator, and returns the frozen record of its stage (:mod:`seqbayes.core.state`). An instance serves one step.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..core.errors import ZeroLikelihoodError, prior_name, zero_likelihood_message
from ..core.likelihood import row_hashes
from ..core.state import Cloud, Estimate, Failure, Outcome, Reassimilate, RemedyMemory, SamplerState, Tempered, Weighed
from ..moves.base import MoveTally
from ..core.tempering import temper
from ..moves.schedule import ResampleMove, Staged, move_stage
from ..priors import inside_space
from ..weights import resample
from ..results import ConflictInfo, EvidenceInfo, JumpInfo
from ..weights import ess, normalise
from .evidence import step_standard_errors
from .lineage import ancestor_terms, lineage_after

__all__ = ["ParticlePredictive", "ExactPrior", "weigh", "restricted_draws", "rejuvenate_deferred", "temper_stages",
           "count_distinct", "step_conflict", "prior_data_conflict"]


class ParticlePredictive:
    """The stages shared by the predictives that keep a :class:`~seqbayes.core.state.SamplerState`.

    Subclasses say how the step's prior is evaluated (:meth:`prior_logpdf`), whether the moves run at every
    stage (:meth:`moves_every_stage`), whether the evidence needs the importance sampler (:meth:`uses_importance`)
    and what the next prior is (:meth:`next_prior`); :meth:`remedy_fields` keeps what the path-space remedy needs.

    Parameters
    ----------
    problem : Problem
    config : SamplerConfig
    method : str
        The resolved predictive (``SamplerConfig.predictive``), as :func:`~seqbayes.predictive.evidence.step_standard_errors`
        names it.
    """

    #: IBIS's schedule: the last stage's resample-move waits for the next dataset.
    deferred = False

    def __init__(self, problem, config, method: str):
        self.problem, self.config, self.method = problem, config, method

    # ---- hooks
    def prior_logpdf(self, state, likelihood, rng):
        """The step's prior density as a function of ``theta (M, d)`` alone (an
        :class:`~seqbayes.predictive.particle.ExactPrior` or the like)."""
        return ExactPrior(state.prior.logpdf)

    def exact_prior(self, state) -> bool:
        """Whether the step's prior is exact, so that its particles never restart from the restricted prior."""
        return False

    def moves_every_stage(self) -> bool:
        """The moves' ``every_stage``; when ``None``, True (the paper's Algorithm 4)."""
        every = self.config.moves.every_stage
        return True if every is None else every

    def evidence(self, moves: MoveTally):
        """The step's evidence component (``SamplerConfig.evidence``)."""
        return self.config.evidence

    def next_prior(self, state, cloud, dataset, log_increment, log_evidence, rng):
        """``(density, draws, their log prior or None)`` of the next step (Eq. A2-A3)."""
        raise NotImplementedError

    def ancestor_spread(self, state, cloud, rng):
        """The spread of the step's posterior over the previous posterior's particles, for the evidence's
        standard error and the remedy (:class:`~seqbayes.predictive.mixture.AncestorSpread` or None)."""
        return None

    def remedy_fields(self, state, cloud, log_increment, dataset, rng):
        """``(ancestor_ess, spread, window, paths, lagged_variance)`` kept for the path-space remedy (none by
        default; :attr:`~seqbayes.core.state.Outcome.lagged_variance`)."""
        return float("nan"), None, (), None, float("nan")

    def previous_prior(self, state):
        """The mixture prior this step used, for the next increment's standard error (None by default)."""
        return None

    def remedy(self, state, dataset, likelihood, outcome):
        return None

    # ---- the stages
    def start(self, state, prior_logpdf, rng):
        """The particles to weigh: ``(particles, log_weights, log_prior or None, moves, rejuvenated, labels or None)``."""
        return state.particles, state.log_weights, None, MoveTally(step_size=state.step_size), False, None

    def weigh(self, state, dataset, likelihood, rng) -> Weighed | Failure:
        prior_logpdf = self.prior_logpdf(state, likelihood, rng)
        particles, log_weights, log_prior, moves, rejuvenated, labels = self.start(state, prior_logpdf, rng)
        weighed = weigh(state, particles, log_weights, log_prior, self.problem, self.config, likelihood, prior_logpdf,
                        rng, labels, self.exact_prior(state))
        if isinstance(weighed, Failure):
            return weighed
        cloud, log_restricted_mass, n_found = weighed
        return Weighed(cloud, prior_logpdf, moves, log_restricted_mass, n_found, rejuvenated)

    def stage_check(self, state, dataset, likelihood):
        """A check of each intermediate stage's particles (:func:`temper_stages`: ``check(particles) -> decision or
        None``), or None (the default)."""
        return None

    def temper(self, state, dataset, weighed, likelihood, rng) -> Tempered | Failure | Reassimilate:
        tempered = temper_stages(weighed.cloud, weighed.moves, ResampleMove(
            self.problem, self.config, likelihood, weighed.prior_logpdf, self.moves_every_stage(), self.deferred, rng,
            stage_check=self.stage_check(state, dataset, likelihood)))
        if not isinstance(tempered, Tempered):
            return tempered
        # Z = P(inside, L > 0) E[L | inside, L > 0]
        return replace(tempered, log_z=tempered.log_z + weighed.log_restricted_mass)

    def estimate(self, tempered, weighed, likelihood, rng) -> Estimate:
        evidence = self.evidence(tempered.moves)
        cloud, log_increment, evidence_ess, n_independent = evidence.estimate(
            tempered.cloud, tempered.log_z, weighed.n_found, self.problem, self.config, likelihood,
            weighed.prior_logpdf, rng)
        return Estimate(cloud, log_increment, evidence_ess, n_independent,
                        evidence.importance and log_increment != tempered.log_z, tempered.moves)

    def propagate(self, state, weighed, tempered, estimate, dataset, likelihood, rng) -> Outcome:
        config, cloud = self.config, estimate.cloud
        log_evidence = float(state.log_evidence + estimate.log_increment)
        density, draws, next_log_prior = self.next_prior(state, cloud, dataset, estimate.log_increment, log_evidence,
                                                         rng)
        conflict = step_conflict(weighed.cloud.particles, weighed.cloud.log_weights, cloud.particles,
                                 cloud.log_weights, self.problem.support)
        ancestors, spread, window, paths, lagged = self.remedy_fields(state, cloud, estimate.log_increment, dataset,
                                                                      rng)
        if spread is None:
            spread = self.ancestor_spread(state, cloud, rng)
        ancestor_variance, covariance = ancestor_terms(state, spread)
        increment_se, evidence_se, evidence_variance = step_standard_errors(
            state.log_evidence_variance, config.n_samples, estimate.importance, estimate.evidence_ess,
            np.exp(weighed.cloud.log_weights), cloud.log_weights, len(tempered.temperatures), tempered.resampled,
            ancestor_variance, self.method, covariance)
        moves = estimate.moves
        new_state = SamplerState(step=state.step + 1, particles=draws, log_weights=cloud.log_weights, prior=density,
                                 log_evidence=log_evidence,
                                 step_size=float(config.moves.step_size_after(moves.step_size, state.step_size)),
                                 posterior=cloud.particles, posterior_log_weights=cloud.log_weights,
                                 log_prior=next_log_prior,
                                 memory=RemedyMemory(window, paths, lineage_after(state, cloud.labels)),
                                 log_evidence_variance=evidence_variance, previous_prior=self.previous_prior(state))
        records = dict(evidence=EvidenceInfo(float(tempered.log_z), estimate.evidence_ess, estimate.n_independent,
                                             increment_se, evidence_se),
                       conflict=ConflictInfo(float(conflict.max()), int(conflict.argmax()), ancestors),
                       jumps=JumpInfo(**self.jump_fields(state, cloud)))
        step_size = float(config.moves.step_size_after(moves.step_size, float("nan")))
        return Outcome(new_state, cloud.particles, cloud.log_weights, draws, cloud.particles, log_evidence, step_size,
                       records, lagged_variance=lagged)

    def jump_fields(self, state, cloud) -> dict:
        """The :class:`~seqbayes.results.JumpInfo` fields of a jump kernel's posterior (none by default)."""
        return {}


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


def prior_data_conflict(prior: np.ndarray, prior_log_weights: np.ndarray, posterior: np.ndarray,
                        posterior_log_weights: np.ndarray) -> np.ndarray:
    """``|posterior mean - prior mean| / prior sd`` per parameter, ``(d,)``.

    Parameters
    ----------
    prior, posterior : (N, d) arrays
        The step's prior particles (before the likelihood) and its posterior particles.
    prior_log_weights, posterior_log_weights : (N,) arrays
    """
    w0, w1 = np.exp(normalise(prior_log_weights)), np.exp(normalise(posterior_log_weights))
    mean0 = w0 @ prior
    sd0 = np.sqrt(np.maximum(w0 @ (prior - mean0) ** 2, 1e-300))
    return np.abs(w1 @ posterior - mean0) / sd0


def step_conflict(prior, prior_log_weights, posterior, posterior_log_weights, support) -> np.ndarray:
    """``StepInfo.prior_data_conflict`` per parameter, ``(d,)``: how many sds of the step's prior the
    posterior mean lies from the prior mean (:func:`prior_data_conflict`).

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
    (:attr:`~seqbayes.core.state.RemedyMemory.lineage`): the index of each draw among the distinct ones (copies
    share it); a :class:`~seqbayes.core.state.Failure` when no draw is found."""
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
        return Failure(ZeroLikelihoodError(zero_likelihood_message(step, prior_name(step), likelihood)))
    if n_kept == 0:
        return Failure(ZeroLikelihoodError(
            f"step {step}: every sample has zero likelihood (0 of {n_drawn} draws of the "
            f"{prior_name(step)} are inside the parameter space with a "
            f"non-zero likelihood); the {prior_name(step)} is too far "
            f"from the data"))
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
    if ess(log_weights) >= config.tempering.resample_below * n:
        return particles, log_weights, state.log_prior, moves, False, np.arange(n)
    index = resample(config.tempering.scheme, np.exp(log_weights), rng, n)
    values = prior_logpdf(particles) if state.log_prior is None else state.log_prior
    moved = move_stage(problem, config.moves, moves.step_size, particles[index],
                       np.column_stack([np.zeros(n), values[index]]), 0.0, prior_logpdf, rng,
                       lambda theta: np.zeros(theta.shape[0]))
    return (moved.walkers, np.full(n, -np.log(n)), moved.components[:, 1], moves.then(moved, config.moves), True,
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
    distinct restart draws (N without restart), or a :class:`~seqbayes.core.state.Failure` when no particle can
    carry the step."""
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
        return Failure(ZeroLikelihoodError(zero_likelihood_message(step, prior_name(step), likelihood)))
    if not exact_prior and not valid.all() and (not inside.all() or valid.sum() < _min_valid(config, particles)):
        restart = restricted_draws(state.prior, problem.support, n, rng, step, likelihood)
        if isinstance(restart, Failure):
            return restart
        particles, loglike, log_restricted_mass, n_found, labels = restart
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
    threshold = config.tempering.min_valid_fraction * particles.shape[0]
    return min(threshold, particles.shape[1] + 1.0) if config.moves.economy else threshold


def temper_stages(cloud, moves, mutate: ResampleMove) -> Tempered:
    """Stages 2-4: reweight by ``L^delta`` (Eq. A5, one stage or adaptive tempering), resample, move: the one
    tempering loop (:func:`~seqbayes.core.tempering.temper`) with the particle predictives' mutation ``mutate``
    (:class:`~seqbayes.moves.schedule.ResampleMove`, which holds the configuration and the step's likelihood),
    from ``cloud`` and the update's ``moves`` tally.

    Returns a :class:`~seqbayes.core.state.Tempered` whose ``log_z`` is the path's log-evidence (Eq. 1) without
    any restricted mass (the caller's), or what stopped the stages (a :class:`~seqbayes.core.state.Failure`, the
    stage check's decision)."""
    annealed = temper(Staged(cloud, moves), cloud.components[:, 0], cloud.log_weights, mutate.config.tempering,
                      mutate, mutate.likelihood.step)
    if annealed.decision is not None:  # a Failure, or the stage check's decision
        return annealed.decision
    staged = annealed.particles
    return Tempered(staged.cloud, annealed.log_z, annealed.temperatures, staged.moves, staged.resampled,
                    annealed.last.ess)


