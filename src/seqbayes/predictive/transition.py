"""The transition mixture of Eq. (A3) (or the paper's kernel density, Eq. A9) as a step's predictive prior
(:class:`TransitionMixture`, chosen by the components :class:`Transition` and :class:`KernelDensity`); it keeps what
the conflict remedy needs and asks it what to do with a step (:mod:`seqbayes.predictive.paths`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.state import PastStep, kept_copy, remedy_window, variance_before
from .jumps import jump_fields
from .lineage import ancestor_mass, lagged_ancestor_variance, mass_spread, posterior_labels
from .mixture import GaussianMixture, predictive_density
from .particle import ExactPrior, ParticlePredictive
from .paths import REMEDY_ANCESTOR_SE
from .pseudo_marginal import SubsampledPrior

__all__ = ["Transition", "KernelDensity", "TransitionMixture"]


@dataclass(frozen=True)
class Transition:
    """The transition mixture ``sum_i W_i T(theta | theta_i)`` of Eq. (A3) as each step's prior (the default with
    process noise).

    Parameters
    ----------
    shrink_static : bool
        Liu-West shrinkage of the static dimensions' kernel (True; :func:`~seqbayes.predictive.mixture.predictive_density`).
    pseudo_marginal_from : int
        From this many particles on (2048; 0 never) the moves evaluate the mixture by an unbiased estimate from a
        subsample of its components (pseudo-marginal moves, exact in distribution; ``O(N M)`` per sweep instead of
        ``O(N^2)``) where a pilot shows the estimate accurate
        (:class:`~seqbayes.predictive.pseudo_marginal.SubsampledPrior`).
    """

    shrink_static: bool = True
    pseudo_marginal_from: int = 2048

    method = "transition"

    def __post_init__(self):
        if self.shrink_static not in (True, False):
            raise ValueError(f"shrink_static: expected True or False, got {self.shrink_static!r}")
        if (isinstance(self.pseudo_marginal_from, bool) or int(self.pseudo_marginal_from) != self.pseudo_marginal_from
                or self.pseudo_marginal_from < 0):
            raise ValueError(f"pseudo_marginal_from: must be an integer >= 0, got {self.pseudo_marginal_from}")

    def resolve(self, kernel) -> "Transition":
        """This predictive for ``kernel`` (any kernel)."""
        return self

    def predictive(self, state, problem, config):
        """The step's :class:`~seqbayes.core.state.Predictive` and the state it starts from."""
        return TransitionMixture(problem, config, self.method), state


@dataclass(frozen=True)
class KernelDensity(Transition):
    """The paper's predictive prior (Eq. A9-A10): a kernel density of the propagated posterior, Silverman's bandwidth
    on every dimension."""

    method = "kde"


class TransitionMixture(ParticlePredictive):
    """``p_{s+1}(theta) = sum_i W_i T(theta | theta_i)`` over the step's posterior (``method="transition"``,
    with Liu-West shrinkage on static dimensions), or a kernel density of the propagated posterior
    (``method="kde"``); see :func:`~seqbayes.predictive.mixture.predictive_density`. The conflict remedy
    (``SamplerConfig.remedy``) decides after the step, or between its stages (:meth:`stage_check`), whether it is
    assimilated again on the path space."""

    def __init__(self, problem, config, method: str, check_stages: bool = True):
        super().__init__(problem, config, method)
        #: Whether :meth:`stage_check` checks the stages (not in the step that replaces a failed path-space step).
        self.check_stages = check_stages

    def prior_logpdf(self, state, likelihood, rng):
        config, pseudo_marginal_from = self.config, self.config.predictive.pseudo_marginal_from
        if (self.method == "transition" and isinstance(state.prior, GaussianMixture) and pseudo_marginal_from
                and config.n_samples >= pseudo_marginal_from and state.log_prior is None):
            return SubsampledPrior(state.prior, rng)  # pseudo-marginal moves where the pilot allows
        return ExactPrior(state.prior.logpdf)

    def next_prior(self, state, cloud, dataset, log_increment, log_evidence, rng):
        density, draws = predictive_density(cloud.particles, cloud.log_weights, self.problem.kernel, rng, self.method,
                                            self.config.predictive.shrink_static)
        return density, draws, None

    def ancestor_spread(self, state, cloud, rng):
        # Eq. (A3)'s N ancestors carry Z_s; none at the first step (its prior is the initial one)
        if isinstance(state.prior, GaussianMixture):
            return state.prior.ancestor_spread(cloud.particles, cloud.log_weights, posterior_labels(state))
        return None

    def previous_prior(self, state):
        return state.prior if isinstance(state.prior, GaussianMixture) else None

    def jump_fields(self, state, cloud) -> dict:
        return jump_fields(self.problem.kernel, state, cloud) if self.problem.kernel.has_jumps else {}

    def remedy_fields(self, state, cloud, log_increment, dataset, rng):
        """The ancestor ESS of the posterior, the window (and paths, after a path-space step) kept for the remedy,
        and the lagged ancestor variance its decision reads."""
        remedy = self.config.remedy
        if not remedy.applies(self.method, self.problem.kernel):
            return float("nan"), None, (), None, float("nan")
        spread, ancestors, paths, lagged = None, float("nan"), None, float("nan")
        if state.memory.window:
            spread, index = self.spread_over(state, cloud.particles, cloud.log_weights,
                                             None if state.memory.paths is None else rng)
            ancestors = spread.ess
            if state.memory.paths is not None:
                paths = np.concatenate([state.memory.paths[index], cloud.particles[:, None]], axis=1)
        if spread is not None and remedy.ancestor_ess > 0:
            # lags that add less than 1 % of the trigger's variance cannot change its decision
            lagged = lagged_ancestor_variance(state, spread, 0.01 * REMEDY_ANCESTOR_SE**2)
        window = remedy_window(state.memory.window + (PastStep(kept_copy(dataset), state.prior, cloud.particles,
                                                               cloud.log_weights, float(log_increment),
                                                               variance_before(state)),), remedy.lag)
        return ancestors, spread, window, None if paths is None else paths[:, -len(window):], lagged

    def spread_over(self, state, particles, log_weights, rng=None):
        """``(spread, index)``: the :class:`~seqbayes.predictive.ancestry.AncestorSpread` of the last posterior's
        particles under ``particles (N, d)`` with ``log_weights``, and (with ``rng``, after a path-space step) an
        ancestor drawn for each particle."""
        if state.memory.paths is None and isinstance(state.prior, GaussianMixture):
            # the mixture's own components' responsibilities: one matrix product, not the pairwise transition density
            return state.prior.ancestor_spread(particles, log_weights, posterior_labels(state)), None
        index, mass = ancestor_mass(self.problem.kernel, particles, state.posterior, state.posterior_log_weights, rng,
                                    log_weights)
        return mass_spread(state, mass), index

    def stage_check(self, state, dataset, likelihood):
        """The remedy's check of the intermediate stages (:meth:`seqbayes.predictive.paths.PathSpace.stage_check`),
        unless this step replaces a path-space step that found nothing."""
        return self.config.remedy.stage_check(self, state, dataset, likelihood) if self.check_stages else None

    def remedy(self, state, dataset, likelihood, outcome):
        """The remedy's decision on the step's ``outcome`` (:meth:`seqbayes.predictive.paths.PathSpace.decide`)."""
        return self.config.remedy.decide(self, state, dataset, likelihood, outcome)
