"""One update of an on-line sampler: the pure function :func:`assimilate`.

One dataset ``D^s`` is assimilated (docs/core.md explains each choice):

1. The prior particles (prior draws at ``s = 1``, predictive draws of Eq. A3
   after) are weighted by the likelihood (Eq. A4-A5). If few of them have a
   non-zero likelihood, or the kernel carried some out of the parameter space,
   the step restarts from the prior restricted to ``{inside, L > 0}``.
2. The likelihood enters in one stage, or, when that would leave less than 10 %
   of the ESS, in adaptive tempering stages ``0 < beta_1 < ... < 1`` chosen by
   bisection on the ESS.
3. After each stage the particles are resampled (always at an intermediate
   stage; at the last when the ESS is below the threshold) and moved by an MCMC
   kernel that leaves ``L^beta p_s`` invariant (:mod:`seqbayes.moves.schedule`).
4. The evidence increment is estimated by defensive importance sampling from
   the final posterior (:mod:`seqbayes.engine.evidence`), whose proposal also drives
   independence-MH sweeps; the stages' product of mean weights (Eq. 1) is kept
   as the "path" estimate.
5. The posterior is propagated through the Markov kernel (Eq. A2), and the
   predictive density (Eq. A3) becomes the next step's prior.

The parameter space is the initial prior's support and the likelihood is zero
outside it, so a kernel that predicts impossible parameters loses evidence.
"""

from __future__ import annotations

import time

import numpy as np

from ..predictive.base import propagate, resolve_predictive
from ..predictive.history import HistoryPrior
from ..predictive.lineage import ancestor_mass, ancestor_terms, lineage_after, mass_spread, posterior_labels
from ..predictive.mixture import GaussianMixture, jump_step_fields
from ..predictive.paths import assimilate_paths, remedy_applies
from ..predictive.pseudo_marginal import SubsampledPrior
from ..predictive.smc2 import NestedState, after_joint_first_step, assimilate_nested, nested_split
from ..results import StepInfo, StepRecord
from .errors import ZeroLikelihoodError
from .evidence import estimate_increment, step_standard_errors
from .likelihood import ValidatedLikelihood, check_dataset
from .stages import count_distinct, moves_every_stage, rejuvenate_deferred, step_conflict, temper_resample_move, weigh
from .state import MoveTally, PastStep, SamplerState, kept_copy, variance_before

__all__ = ["assimilate"]


def _prior_logpdf(prior, likelihood):
    """The step's prior log-density as a function of ``theta (M, d)`` alone."""
    if isinstance(prior, HistoryPrior):
        return lambda theta: prior.logpdf(theta, likelihood.loglike_on, likelihood.summary_loglike)
    return prior.logpdf


def assimilate(state: SamplerState, dataset: Any, problem: Problem, config: SamplerConfig,
               rng: np.random.Generator, *, on_evaluated: Callable[[int], None] | None = None,
               ) -> tuple[SamplerState, StepRecord]:
    """Assimilate one dataset (pure; ``state`` is not modified): weigh the prior particles, temper,
    resample and move, estimate the evidence, propagate through the kernel.

    Returns
    -------
    new_state : SamplerState
    record : StepRecord

    Raises
    ------
    ZeroLikelihoodError
        If every sample has zero likelihood.
    """
    start = time.perf_counter()
    step = state.step + 1
    check_dataset(dataset, step)
    likelihood = ValidatedLikelihood.for_step(problem, dataset, step, on_evaluated)
    if isinstance(state, NestedState):
        if step > 1 or not problem.inner_filter.joint_first_step:
            return assimilate_nested(state, dataset, problem, config, likelihood, rng)
        # the first dataset has no dynamics yet: a static problem in every parameter
        joint = SamplerState(0, state.particles, state.log_weights, problem.prior, 0.0, state.step_size)
        _, record, cloud = _assimilate_particles(joint, dataset, problem, config, rng, likelihood, "joint", start)
        new_state = after_joint_first_step(nested_split(problem.kernel), problem.inner_filter.n_inner,
                                           cloud.particles, cloud.log_weights,
                                           cloud.components, dataset, record.info.log_evidence,
                                           state.step_size if np.isnan(record.info.step_size) else record.info.step_size,
                                           cloud.particles, record.predictive)
        return new_state, record
    method = resolve_predictive(config.predictive, problem.kernel)
    try:
        new_state, record, _ = _assimilate_particles(state, dataset, problem, config, rng, likelihood, method, start)
    except ZeroLikelihoodError as error:
        # No predictive draw of the mixture lands where the likelihood is non-zero (run 9 of the oscillator study
        # under T6: the drift takes every predicted k below 0), yet the model's path posterior may have mass there,
        # paths whose earlier states the data put elsewhere: the bridge from the path prior can find them
        if not (config.remedy_bridge and state.window and remedy_applies(config, method, problem.kernel)):
            raise
        try:
            new_state, record, _ = assimilate_paths(state, dataset, problem, config, rng, likelihood, method, start,
                                                    bridge=True)
        except ZeroLikelihoodError:
            raise error from None
        return new_state, record
    info = record.info
    # after a path-space step the mixture's own posterior understates the conflict (its target cannot reach
    # the tail, so fewer ancestors look involved): stay on the path space until 5x the threshold
    threshold = config.remedy_ess * (5.0 if state.window and state.window[-1].path_space else 1.0)
    if state.window and remedy_applies(config, method, problem.kernel) and (
            info.ancestor_ess < threshold * config.n_samples or info.prior_data_conflict > config.conflict_threshold):
        try:
            new_state, record, _ = assimilate_paths(state, dataset, problem, config, rng, likelihood, method, start,
                                                    bridge=config.remedy_bridge)
        except ZeroLikelihoodError:  # the paths' restart found nothing the mixture's did: keep the mixture's step
            pass
    return new_state, record


def _assimilate_particles(state, dataset, problem, config, rng, likelihood, method, start):
    """Stages 1-6 for a :class:`SamplerState`; ``method`` is the resolved predictive (``"joint"``: the
    first step of SMC^2 with a particle inner filter, propagated but with no density built).
    Returns the new state, the record and the final cloud."""
    step = state.step + 1
    prior_logpdf = _prior_logpdf(state.prior, likelihood)
    if (method == "transition" and isinstance(state.prior, GaussianMixture) and config.pseudo_marginal_from
            and config.n_samples >= config.pseudo_marginal_from and state.log_prior is None):
        prior_logpdf = SubsampledPrior(state.prior, rng)  # pseudo-marginal moves where the pilot allows
    history = isinstance(state.prior, HistoryPrior)  # static parameters: the particles are the last posterior
    move_every_stage = moves_every_stage(config, method)
    # IBIS's schedule exactly (particles'): the last stage's resample-move waits for the next dataset
    deferred = method == "history" and config.move_every_stage is False
    moves = MoveTally(step_size=state.step_size)
    particles, log_weights, log_prior, rejuvenated = state.particles, state.log_weights, None, False
    if history:
        log_prior = state.log_prior
        if deferred:
            particles, log_weights, log_prior, moves, rejuvenated, labels = rejuvenate_deferred(
                state, problem, config, prior_logpdf, moves, rng)
    cloud, log_restricted_mass, n_found = weigh(state, particles, log_weights, log_prior, problem, config, likelihood,
                                                 prior_logpdf, rng, labels if rejuvenated else None)
    weights_before = np.exp(cloud.log_weights)
    weighed = cloud  # the step's prior draws (restricted to {inside, L > 0} after a restart)
    cloud, log_z, temperatures, moves, resampled, stage_ess = temper_resample_move(
        cloud, problem, config, likelihood, prior_logpdf, moves, move_every_stage, deferred, rng)
    log_increment_path = log_z + log_restricted_mass  # Z = P(inside, L > 0) E[L | inside, L > 0]
    # with the history prior a step that kept its particles needs no fitted proposal: its weights are the
    # importance weights of the exact prior (and a proposal would re-evaluate the past, at O(s) cost)
    use_importance = config.evidence == "importance" and not (method == "history" and moves.stats.n_proposed == 0)
    cloud, log_increment, evidence_ess, n_independent = estimate_increment(
        cloud, log_increment_path, n_found, problem, config, likelihood, prior_logpdf, use_importance, rng)
    log_evidence = float(state.log_evidence + log_increment)
    density, predictive, next_log_prior = propagate(state, cloud, dataset, log_increment, log_evidence, method,
                                                     problem, config, rng)
    step_size = moves.step_size if config.move == "stretch" else float("nan")
    conflict = step_conflict(weighed.particles, weighed.log_weights, cloud.particles, cloud.log_weights,
                             problem.support)
    ancestors, spread, window, paths = float("nan"), None, (), None
    ancestor_labels = posterior_labels(state)
    if remedy_applies(config, method, problem.kernel):  # keep what the path-space remedy needs
        keep = config.remedy_lag - 1
        if state.window and state.paths is None and isinstance(state.prior, GaussianMixture):
            # how many of the mixture's own components carry the posterior (the exact transition's with
            # "transition"), by one matrix product instead of the pairwise transition density: run 0 (T1) with
            # SMC, 4 interleaved pairs, CPU time with / without the remedy 1.53x -> 0.92x (within noise)
            spread = state.prior.ancestor_spread(cloud.particles, cloud.log_weights, ancestor_labels)
            ancestors = spread.ess
        elif state.window:
            index, mass = ancestor_mass(problem.kernel, cloud.particles, state.posterior, state.posterior_log_weights,
                                         None if state.paths is None else rng, cloud.log_weights)
            spread = mass_spread(state, mass)
            ancestors = spread.ess
            if state.paths is not None:
                paths = np.concatenate([state.paths[index], cloud.particles[:, None]], axis=1)[:, -keep:]
        window = (state.window + (PastStep(kept_copy(dataset), state.prior, cloud.particles, cloud.log_weights,
                                           float(log_increment), False, variance_before(state)),))[-keep:]
    # the evidence's standard error; Eq. (A3)'s N ancestors carry Z_s (the remedy's pass gave their spread if it ran)
    if spread is None and isinstance(state.prior, GaussianMixture):
        spread = state.prior.ancestor_spread(cloud.particles, cloud.log_weights, ancestor_labels)
    ancestor_variance, covariance = ancestor_terms(state, spread)
    increment_se, evidence_se, evidence_variance = step_standard_errors(
        state.log_evidence_variance, config.n_samples, use_importance and log_increment != log_increment_path,
        evidence_ess, weights_before, cloud.log_weights, len(temperatures), resampled, ancestor_variance, method,
        covariance)
    info = StepInfo(
        step=step, log_evidence_increment=float(log_increment),
        log_evidence=log_evidence, ess=float(stage_ess), resampled=bool(resampled or rejuvenated),
        acceptance_rate=moves.stats.acceptance_rate, step_size=float(step_size),
        n_virtual=moves.n_virtual, n_stages=len(temperatures), temperatures=temperatures,
        n_loglike_evals=likelihood.n_evals, n_nan=likelihood.n_nan, n_distinct=count_distinct(cloud.particles),
        n_proposed=moves.stats.n_proposed, n_accepted=moves.stats.n_accepted,
        n_identical_partner=moves.stats.n_identical_partner,
        log_evidence_increment_path=float(log_increment_path), evidence_ess=evidence_ess,
        n_independent_accepted=n_independent, n_move_evaluations=moves.stats.n_evaluations,
        wall_time=time.perf_counter() - start, prior_data_conflict=float(conflict.max()),
        conflict_parameter=int(conflict.argmax()), ancestor_ess=ancestors,
        log_evidence_increment_se=increment_se, log_evidence_se=evidence_se,
        **jump_step_fields(problem.kernel, state.prior, cloud.particles, cloud.log_weights))
    record = StepRecord(info, cloud.particles, cloud.log_weights, predictive)
    new_state = SamplerState(step=step, particles=predictive, log_weights=cloud.log_weights, prior=density,
                             log_evidence=log_evidence,
                             step_size=float(moves.step_size if config.move == "stretch" else state.step_size),
                             posterior=cloud.particles, posterior_log_weights=cloud.log_weights,
                             log_prior=next_log_prior, window=window, paths=paths,
                             log_evidence_variance=evidence_variance,
                             lineage=lineage_after(state, cloud.labels),
                             previous_prior=state.prior if isinstance(state.prior, GaussianMixture) else None)
    return new_state, record, cloud

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from collections.abc import Callable
    from typing import Any

    from .settings import SamplerConfig
    from .state import Problem
