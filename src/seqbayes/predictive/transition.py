"""The transition mixture of Eq. (A3) (or the paper's kernel density, Eq. A9) as a step's predictive prior:
:class:`TransitionMixture`, which also keeps what the path-space remedy needs and hands a conflicted step
to it (:class:`~seqbayes.predictive.paths.PathSpace`)."""

from __future__ import annotations

import numpy as np

from ..core.state import Failure, PastStep, Reassimilate, kept_copy, remedy_window, variance_before
from .lineage import ancestor_mass, lagged_ancestor_variance, mass_spread, posterior_labels
from .jumps import jump_fields
from .mixture import GaussianMixture, predictive_density
from .evidence import STARVED_RESTART
from .particle import ExactPrior, ParticlePredictive
from .paths import PathSpace, remedy_applies
from .pseudo_marginal import SubsampledPrior

__all__ = ["TransitionMixture", "REMEDY_ANCESTOR_SE"]

#: A conflict costs accuracy when the earlier posteriors' finite samples alone would make the step's log-evidence
#: uncertain by more than this (sd, nats): the tilt the new data give each earlier posterior the mixtures rest on,
#: times that posterior's sampling error, summed over the lags (:func:`~seqbayes.predictive.lineage.
#: lagged_ancestor_variance`; ``sqrt(1 / ancestor_ess - 1 / N)`` at lag 1 alone). The posterior inherits the same
#: error and carries it into every later step (docs/jump_kernels.md, moderate damage).
REMEDY_ANCESTOR_SE = 0.1


class TransitionMixture(ParticlePredictive):
    """``p_{s+1}(theta) = sum_i W_i T(theta | theta_i)`` over the step's posterior (``method="transition"``,
    with Liu-West shrinkage on static dimensions), or a kernel density of the propagated posterior
    (``method="kde"``); see :func:`~seqbayes.predictive.mixture.predictive_density`."""

    def prior_logpdf(self, state, likelihood, rng):
        config = self.config
        if (self.method == "transition" and isinstance(state.prior, GaussianMixture) and config.pseudo_marginal_from
                and config.n_samples >= config.pseudo_marginal_from and state.log_prior is None):
            return SubsampledPrior(state.prior, rng)  # pseudo-marginal moves where the pilot allows
        return ExactPrior(state.prior.logpdf)

    def next_prior(self, state, cloud, dataset, log_increment, log_evidence, rng):
        density, draws = predictive_density(cloud.particles, cloud.log_weights, self.problem.kernel, rng, self.method,
                                            self.config.shrink_static)
        return density, draws, None

    def ancestor_spread(self, state, cloud, rng):
        # Eq. (A3)'s N ancestors carry Z_s; none at the first step (its prior is the initial one)
        if isinstance(state.prior, GaussianMixture):
            return state.prior.ancestor_spread(cloud.particles, cloud.log_weights, posterior_labels(state))
        return None

    def previous_prior(self, state):
        return state.prior if isinstance(state.prior, GaussianMixture) else None

    def jump_fields(self, state, cloud) -> dict:
        return jump_fields(self.problem.kernel, state, cloud)

    def __init__(self, problem, config, method: str, check_stages: bool = True):
        super().__init__(problem, config, method)
        #: Whether :meth:`stage_check` checks the stages (not in the step that replaces a failed path-space step).
        self.check_stages = check_stages

    def remedy_fields(self, state, cloud, log_increment, dataset, rng):
        """The ancestor ESS of the posterior, the window (and paths, after a path-space step) kept for the remedy,
        and the lagged ancestor variance its decision reads (:meth:`remedy`)."""
        if not remedy_applies(self.config, self.method, self.problem.kernel):
            return float("nan"), None, (), None, float("nan")
        spread, ancestors, paths, lagged = None, float("nan"), None, float("nan")
        if state.memory.window:
            spread, index = self._ancestor_spread(state, cloud.particles, cloud.log_weights,
                                                  None if state.memory.paths is None else rng)
            ancestors = spread.ess
            if state.memory.paths is not None:
                paths = np.concatenate([state.memory.paths[index], cloud.particles[:, None]], axis=1)
        if spread is not None and self.config.remedy_ess > 0:
            # lags that add less than 1 % of the trigger's variance cannot change its decision
            lagged = lagged_ancestor_variance(state, spread, 0.01 * REMEDY_ANCESTOR_SE**2)
        window = remedy_window(state.memory.window + (PastStep(kept_copy(dataset), state.prior, cloud.particles,
                                                               cloud.log_weights, float(log_increment),
                                                               variance_before(state)),), self.config.remedy_lag)
        return ancestors, spread, window, None if paths is None else paths[:, -len(window):], lagged

    def _ancestor_spread(self, state, particles, log_weights, rng=None):
        """``(spread, index)``: the :class:`~seqbayes.predictive.ancestry.AncestorSpread` of the last posterior's
        particles under ``particles (N, d)`` with ``log_weights``, and (with ``rng``, after a path-space step) an
        ancestor drawn for each particle."""
        if state.memory.paths is None and isinstance(state.prior, GaussianMixture):
            # the mixture's own components' responsibilities: one matrix product, not the pairwise transition density
            return state.prior.ancestor_spread(particles, log_weights, posterior_labels(state)), None
        index, mass = ancestor_mass(self.problem.kernel, particles, state.posterior, state.posterior_log_weights, rng,
                                    log_weights)
        return mass_spread(state, mass), index

    def _ancestor_threshold(self, state) -> float:
        """The ancestor ESS below which :meth:`remedy` takes the path space."""
        config = self.config
        threshold = config.remedy_ess * (5.0 if state.memory.window[-1].path_space else 1.0) * config.n_samples
        if config.remedy_ess > 0:   # 0 turns the ancestor trigger off
            threshold = max(threshold, 1.0 / (REMEDY_ANCESTOR_SE**2 + 1.0 / config.n_samples))
        return threshold

    def stage_check(self, state, dataset, likelihood):
        """The ancestor trigger of :meth:`remedy` on each intermediate stage's particles: once they are below its
        threshold the step goes to the path space (a :class:`~seqbayes.core.state.Reassimilate` that stops the
        tempering loop) without its last stages, moves and evidence, which only serve the mixture step the remedy
        replaces; should the path space find nothing, this mixture step runs to its end without the check.
        Tempering further towards the data only concentrates the posterior on fewer ancestors (docs/benchmarks.md,
        "A decision before the ordinary step")."""
        config = self.config
        if not (self.check_stages and state.memory.window and config.remedy_ess > 0
                and remedy_applies(config, self.method, self.problem.kernel)):
            return None
        threshold = self._ancestor_threshold(state)

        def check(particles):
            n = particles.shape[0]
            if self._ancestor_spread(state, particles, np.full(n, -np.log(n)))[0].ess < threshold:
                return Reassimilate(PathSpace(state, dataset, self, likelihood, config.remedy_bridge),
                                    TransitionMixture(self.problem, config, self.method, check_stages=False))
            return None

        return check

    def remedy(self, state, dataset, likelihood, outcome):
        """The path-space step (:class:`~seqbayes.predictive.paths.PathSpace`) where the posterior lies in the
        predictive's far tail: few of the previous posterior's particles carry it (``ancestor_ess`` below
        ``remedy_ess * N``, five times that right after a path-space step, whose mixture understates the
        conflict) or so few that they alone make the increment's log-evidence uncertain by more than
        :data:`REMEDY_ANCESTOR_SE` nats (at lag 1 or summed over the earlier posteriors the mixtures rest on,
        :func:`~seqbayes.predictive.lineage.lagged_ancestor_variance`), its mean shifted by more than
        ``conflict_threshold`` prior sds, or its restart found fewer than ``STARVED_RESTART * N`` draws inside
        ``{box, L > 0}`` (the no-draw case short of zero: a posterior grown from copies of a few far-tail draws,
        whose evidence misses the mass between them). Where no predictive draw had a non-zero likelihood (the
        ``outcome`` a zero-likelihood :class:`~seqbayes.core.state.Failure`) only the bridge from the path prior can
        find the paths. Should the path space find nothing, the step keeps this ``outcome``."""
        config = self.config
        if not (state.memory.window and remedy_applies(config, self.method, self.problem.kernel)):
            return None
        if isinstance(outcome, Failure):
            bridge = outcome.zero_likelihood and config.remedy_bridge
            return Reassimilate(PathSpace(state, dataset, self, likelihood, True)) if bridge else None
        info, threshold = outcome.record.info, self._ancestor_threshold(state)
        starved = outcome.weighed.n_found < STARVED_RESTART * config.n_samples
        lagged = config.remedy_ess > 0 and outcome.lagged_variance > REMEDY_ANCESTOR_SE**2
        if (info.ancestor_ess < threshold or lagged or info.prior_data_conflict > config.conflict_threshold
                or starved):
            return Reassimilate(PathSpace(state, dataset, self, likelihood, config.remedy_bridge))
        return None
