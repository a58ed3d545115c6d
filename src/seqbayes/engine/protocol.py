"""The predictive-prior protocol that the pipeline (:func:`~seqbayes.engine.pipeline.run_step`) goes through,
and :class:`ParticlePredictive`, the shared stages of the predictives whose particles are draws of the step's prior.

A predictive says how a step weighs its particles, how it tempers and moves them, how it estimates the evidence
and what it propagates to the next step. Each method takes the step's validated likelihood
(:class:`~seqbayes.engine.likelihood.ValidatedLikelihood`) and the generator, and returns the frozen record of
its stage (:mod:`seqbayes.engine.state`). An instance serves one step.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Protocol

import numpy as np

from ..predictive.lineage import ancestor_terms, lineage_after
from .evidence import estimate_increment, step_standard_errors
from .stages import ExactPrior, step_conflict, temper_resample_move, weigh
from .state import Estimate, MoveTally, Outcome, SamplerState, Tempered, Weighed

__all__ = ["Predictive", "ParticlePredictive"]


class Predictive(Protocol):
    """What one step's predictive prior does at each stage of the pipeline."""

    def weigh(self, state, dataset, likelihood, rng) -> Weighed:
        """Stage 1: the prior particles and their likelihoods (Eq. A4)."""

    def temper(self, weighed: Weighed, likelihood, rng) -> Tempered:
        """Stages 2-4: reweight by ``L^delta`` (Eq. A5), resample, move."""

    def estimate(self, tempered: Tempered, weighed: Weighed, likelihood, rng) -> Estimate:
        """Stage 5: the evidence increment."""

    def propagate(self, state, weighed: Weighed, tempered: Tempered, estimate: Estimate, dataset, likelihood,
                  rng) -> Outcome:
        """Stage 6: the next state (Eq. A2-A3) and the record's diagnostics."""

    def remedy(self, state, dataset, likelihood, info, weighed) -> Predictive | None:
        """The predictive to assimilate the step with again, given its ``info`` and what :meth:`weigh` found
        (both ``None``: no particle had a non-zero likelihood), or ``None`` to keep the step."""


class ParticlePredictive:
    """The stages shared by the predictives that keep a :class:`~seqbayes.engine.state.SamplerState`.

    Subclasses say how the step's prior is evaluated (:meth:`prior_logpdf`), whether the moves run at every
    stage (:meth:`moves_every_stage`), whether the evidence needs the importance sampler (:meth:`uses_importance`)
    and what the next prior is (:meth:`next_prior`); :meth:`remedy_fields` keeps what the path-space remedy needs.

    Parameters
    ----------
    problem : Problem
    config : SamplerConfig
    method : str
        The resolved predictive (``SamplerConfig.predictive``), as :func:`~seqbayes.engine.evidence.step_standard_errors`
        names it.
    """

    #: IBIS's schedule: the last stage's resample-move waits for the next dataset.
    deferred = False

    def __init__(self, problem, config, method: str):
        self.problem, self.config, self.method = problem, config, method

    # ---- hooks
    def prior_logpdf(self, state, likelihood, rng):
        """The step's prior density as a function of ``theta (M, d)`` alone (an
        :class:`~seqbayes.engine.stages.ExactPrior` or the like)."""
        return ExactPrior(state.prior.logpdf)

    def exact_prior(self, state) -> bool:
        """Whether the step's prior is exact, so that its particles never restart from the restricted prior."""
        return False

    def moves_every_stage(self) -> bool:
        """``SamplerConfig.move_every_stage``; when ``None``, True (the paper's Algorithm 4)."""
        return True if self.config.move_every_stage is None else self.config.move_every_stage

    def uses_importance(self, moves: MoveTally) -> bool:
        return self.config.evidence == "importance"

    def next_prior(self, state, cloud, dataset, log_increment, log_evidence, rng):
        """``(density, draws, their log prior or None)`` of the next step (Eq. A2-A3)."""
        raise NotImplementedError

    def ancestor_spread(self, state, cloud, rng):
        """The spread of the step's posterior over the previous posterior's particles, for the evidence's
        standard error and the remedy (:class:`~seqbayes.predictive.ancestry.AncestorSpread` or None)."""
        return None

    def remedy_fields(self, state, cloud, log_increment, dataset, rng):
        """``(ancestor_ess, spread, window, paths)`` kept for the path-space remedy (none by default)."""
        return float("nan"), None, (), None

    def previous_prior(self, state):
        """The mixture prior this step used, for the next increment's standard error (None by default)."""
        return None

    def remedy(self, state, dataset, likelihood, info, weighed):
        return None

    # ---- the stages
    def start(self, state, prior_logpdf, rng):
        """The particles to weigh: ``(particles, log_weights, log_prior or None, moves, rejuvenated, labels or None)``."""
        return state.particles, state.log_weights, None, MoveTally(step_size=state.step_size), False, None

    def weigh(self, state, dataset, likelihood, rng) -> Weighed:
        prior_logpdf = self.prior_logpdf(state, likelihood, rng)
        particles, log_weights, log_prior, moves, rejuvenated, labels = self.start(state, prior_logpdf, rng)
        cloud, log_restricted_mass, n_found = weigh(state, particles, log_weights, log_prior, self.problem,
                                                    self.config, likelihood, prior_logpdf, rng, labels,
                                                    self.exact_prior(state))
        return Weighed(cloud, prior_logpdf, moves, log_restricted_mass, n_found, rejuvenated)

    def stage_check(self):
        """A check of each intermediate stage's particles (:func:`~seqbayes.engine.stages.temper_resample_move`), or
        None (the default)."""
        return None

    def temper(self, weighed, likelihood, rng) -> Tempered:
        tempered = temper_resample_move(weighed.cloud, self.problem, self.config, likelihood, weighed.prior_logpdf,
                                        weighed.moves, self.moves_every_stage(), self.deferred, rng,
                                        stage_check=self.stage_check())
        # Z = P(inside, L > 0) E[L | inside, L > 0]
        return replace(tempered, log_z=tempered.log_z + weighed.log_restricted_mass)

    def estimate(self, tempered, weighed, likelihood, rng) -> Estimate:
        use_importance = self.uses_importance(tempered.moves)
        cloud, log_increment, evidence_ess, n_independent = estimate_increment(
            tempered.cloud, tempered.log_z, weighed.n_found, self.problem, self.config, likelihood,
            weighed.prior_logpdf, use_importance, rng)
        return Estimate(cloud, log_increment, evidence_ess, n_independent,
                        use_importance and log_increment != tempered.log_z, tempered.moves)

    def propagate(self, state, weighed, tempered, estimate, dataset, likelihood, rng) -> Outcome:
        config, cloud = self.config, estimate.cloud
        log_evidence = float(state.log_evidence + estimate.log_increment)
        density, draws, next_log_prior = self.next_prior(state, cloud, dataset, estimate.log_increment, log_evidence,
                                                         rng)
        conflict = step_conflict(weighed.cloud.particles, weighed.cloud.log_weights, cloud.particles,
                                 cloud.log_weights, self.problem.support)
        ancestors, spread, window, paths = self.remedy_fields(state, cloud, estimate.log_increment, dataset, rng)
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
                                 step_size=float(moves.step_size if config.move == "stretch" else state.step_size),
                                 posterior=cloud.particles, posterior_log_weights=cloud.log_weights,
                                 log_prior=next_log_prior, window=window, paths=paths,
                                 log_evidence_variance=evidence_variance, lineage=lineage_after(state, cloud.labels),
                                 previous_prior=self.previous_prior(state))
        fields = dict(prior_data_conflict=float(conflict.max()), conflict_parameter=int(conflict.argmax()),
                      ancestor_ess=ancestors, log_evidence_increment_se=increment_se, log_evidence_se=evidence_se,
                      **self.jump_fields(state, cloud))
        step_size = float(moves.step_size if config.move == "stretch" else float("nan"))
        return Outcome(new_state, cloud.particles, cloud.log_weights, draws, cloud.particles, log_evidence, step_size,
                       fields)

    def jump_fields(self, state, cloud) -> dict:
        """The :class:`~seqbayes.results.StepInfo` fields of a jump kernel's posterior (none by default)."""
        return {}
