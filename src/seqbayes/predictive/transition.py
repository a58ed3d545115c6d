"""The transition mixture of Eq. (A3) (or the paper's kernel density, Eq. A9) as a step's predictive prior
(:class:`TransitionMixture`, chosen by the components :class:`Transition` and :class:`KernelDensity`), and the
remedies of a prior-data conflict it asks what to do with a step: :class:`PathSpace`, which hands a conflicted step
to the path space (:class:`~seqbayes.predictive.paths.PathStep`), or :class:`Conflict`, which only detects it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.likelihood import kept_copy
from ..core.state import Failure, PastStep, Reassimilate
from .jumps import jump_fields
from .lineage import ancestor_mass, lagged_ancestor_variance, mass_spread, posterior_labels, remedy_window, variance_before
from .mixture import GaussianMixture, predictive_density
from .particle import ExactPrior, ParticlePredictive
from .evidence import STARVED_RESTART
from .paths import PathStep
from .pseudo_marginal import SubsampledPrior

__all__ = ["Transition", "KernelDensity", "TransitionMixture", "Conflict", "PathSpace", "REMEDY_ANCESTOR_SE"]


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


#: A conflict costs accuracy when the earlier posteriors' finite samples alone would make the step's log-evidence
#: uncertain by more than this (sd, nats): the tilt the new data give each earlier posterior the mixtures rest on,
#: times that posterior's sampling error, summed over the lags (:func:`~seqbayes.predictive.lineage.
#: lagged_ancestor_variance`; ``sqrt(1 / ancestor_ess - 1 / N)`` at lag 1 alone). The posterior inherits the same
#: error and carries it into every later step (docs/jump_kernels.md, moderate damage).
REMEDY_ANCESTOR_SE = 0.1


@dataclass(frozen=True)
class Conflict:
    """Prior-data conflict detected and reported (``PriorDataConflictWarning``), not remedied: the remedy component
    of a sampler without one (``remedy=None``).

    Parameters
    ----------
    threshold : float
        A step whose posterior mean lies more than this many prior sds from its prior's (``StepInfo.prior_data_conflict``)
        is a conflict (4).
    ancestor_ess : float
        Or whose posterior fewer than this fraction of the previous posterior's particles carry
        (``StepInfo.ancestor_ess``; 0.05; 0 turns that trigger off).
    """

    threshold: float = 4.0
    ancestor_ess: float = 0.05

    def __post_init__(self):
        if not self.threshold > 0:
            raise ValueError(f"threshold: must be positive, got {self.threshold}")
        if not 0.0 <= self.ancestor_ess <= 1.0:
            raise ValueError(f"ancestor_ess: must lie in [0, 1], got {self.ancestor_ess}")

    def applies(self, method: str, kernel) -> bool:
        """Whether the remedy can assimilate a step of the ``method`` predictive under ``kernel`` (never here)."""
        return False

    def stage_check(self, mixture, state, dataset, likelihood):
        """A check of the mixture step's intermediate stages (none here)."""
        return None

    def decide(self, mixture, state, dataset, likelihood, outcome):
        """What to do with the mixture step's ``outcome``: keep it (``None``, here always)."""
        return None


@dataclass(frozen=True)
class PathSpace(Conflict):
    """The exact remedy for prior-data conflict (docs/prior_data_conflict.md): a conflicted step is assimilated again
    on the path space of the last ``lag`` states, whose target is the model's exact one (:class:`PathStep`).

    Parameters
    ----------
    lag : int
        Steps kept for the path-space target (10): exact when the run has at most that many steps, else the
        window's first state takes the (mixture) prior that step used. After a path-space step the next ones reach
        back to its window's first step, up to ``2 lag`` states (:func:`~seqbayes.predictive.lineage.remedy_window`).
    bridge : bool
        How the path-space step reaches its target. ``True`` (default): from the window's path prior, tempering
        every likelihood of the window jointly, so that each mode of the path posterior is weighed afresh and the
        window's evidence estimated directly. ``False``: from the stored paths of the previous posterior, tempering
        only the new dataset (about half the cost; it cannot reach a mode whose earlier states the earlier steps
        ruled out).
    threshold, ancestor_ess
        As :class:`Conflict`: the triggers.
    """

    lag: int = 10
    bridge: bool = True

    def __post_init__(self):
        super().__post_init__()
        if isinstance(self.lag, bool) or int(self.lag) != self.lag or self.lag < 2:
            raise ValueError(f"lag: must be an integer >= 2, got {self.lag}")
        if self.bridge not in (True, False):
            raise ValueError(f"bridge: expected True or False, got {self.bridge!r}")

    def applies(self, method: str, kernel) -> bool:
        """The path-space remedy needs a transition density in every parameter (no static ones)."""
        return method in ("transition", "kde") and not kernel.static_mask.any()

    def threshold_of(self, state, n: int) -> float:
        """The ancestor ESS below which :meth:`decide` takes the path space: ``ancestor_ess * N`` (five times that
        right after a path-space step, whose mixture understates the conflict), at least so few that they alone
        make the increment's log-evidence uncertain by :data:`REMEDY_ANCESTOR_SE` nats."""
        threshold = self.ancestor_ess * (5.0 if state.memory.window[-1].path_states > 0 else 1.0) * n
        if self.ancestor_ess > 0:   # 0 turns the ancestor trigger off
            threshold = max(threshold, 1.0 / (REMEDY_ANCESTOR_SE**2 + 1.0 / n))
        return threshold

    def stage_check(self, mixture, state, dataset, likelihood):
        """The ancestor trigger of :meth:`decide` on each intermediate stage's particles of the ``mixture`` step
        (a :class:`~seqbayes.predictive.transition.TransitionMixture`): once they are below its threshold the step
        goes to the path space (a :class:`~seqbayes.core.state.Reassimilate` that stops the tempering loop) without
        its last stages, moves and evidence, which only serve the mixture step the remedy replaces; should the path
        space find nothing, the mixture step runs to its end without the check. Tempering further towards the data
        only concentrates the posterior on fewer ancestors (docs/benchmarks.md, "A decision before the ordinary
        step")."""
        if not (state.memory.window and self.ancestor_ess > 0 and self.applies(mixture.method, mixture.problem.kernel)):
            return None
        threshold = self.threshold_of(state, mixture.config.n_samples)

        def check(particles):
            n = particles.shape[0]
            if mixture.spread_over(state, particles, np.full(n, -np.log(n)))[0].ess < threshold:
                return Reassimilate(PathStep(state, dataset, mixture, likelihood, self.bridge),
                                    type(mixture)(mixture.problem, mixture.config, mixture.method, check_stages=False))
            return None

        return check

    def decide(self, mixture, state, dataset, likelihood, outcome):
        """The path-space step (:class:`PathStep`) where the mixture step's posterior lies in the predictive's far
        tail: fewer of the previous posterior's particles carry it than :meth:`threshold_of`, or so few at lag 1 or
        summed over the earlier posteriors the mixtures rest on that they make the increment's log-evidence uncertain
        by more than :data:`REMEDY_ANCESTOR_SE` nats (:func:`~seqbayes.predictive.lineage.lagged_ancestor_variance`),
        its mean shifted by more than ``threshold`` prior sds, or its restart found fewer than
        ``STARVED_RESTART * N`` draws inside ``{box, L > 0}`` (a posterior grown from copies of a few far-tail draws,
        whose evidence misses the mass between them). Where no predictive draw had a non-zero likelihood (the
        ``outcome`` a zero-likelihood :class:`~seqbayes.core.state.Failure`) only the bridge from the path prior can
        find the paths. Should the path space find nothing, the step keeps the ``outcome``."""
        if not (state.memory.window and self.applies(mixture.method, mixture.problem.kernel)):
            return None
        if isinstance(outcome, Failure):
            bridge = outcome.zero_likelihood and self.bridge
            return Reassimilate(PathStep(state, dataset, mixture, likelihood, True)) if bridge else None
        n = mixture.config.n_samples
        conflict, threshold = outcome.record.info.conflict, self.threshold_of(state, n)
        starved = outcome.weighed.n_found < STARVED_RESTART * n
        lagged = self.ancestor_ess > 0 and outcome.lagged_variance > REMEDY_ANCESTOR_SE**2
        if conflict.ancestor_ess < threshold or lagged or conflict.prior_data_conflict > self.threshold or starved:
            return Reassimilate(PathStep(state, dataset, mixture, likelihood, self.bridge))
        return None


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
            # lags that add less than 1 % of the trigger's variance cannot change its decision (comment-ok: design tolerance)
            lagged = lagged_ancestor_variance(state, spread, 0.01 * REMEDY_ANCESTOR_SE**2)
        window = remedy_window(state.memory.window + (PastStep(kept_copy(dataset), state.prior, cloud.particles,
                                                               cloud.log_weights, float(log_increment),
                                                               variance_before(state)),), remedy.lag)
        return ancestors, spread, window, None if paths is None else paths[:, -len(window):], lagged

    def spread_over(self, state, particles, log_weights, rng=None):
        """``(spread, index)``: the :class:`~seqbayes.predictive.mixture.AncestorSpread` of the last posterior's
        particles under ``particles (N, d)`` with ``log_weights``, and (with ``rng``, after a path-space step) an
        ancestor drawn for each particle."""
        if state.memory.paths is None and isinstance(state.prior, GaussianMixture):
            # the mixture's own components' responsibilities: one matrix product, not the pairwise transition density
            return state.prior.ancestor_spread(particles, log_weights, posterior_labels(state)), None
        index, mass = ancestor_mass(self.problem.kernel, particles, state.posterior, state.posterior_log_weights, rng,
                                    log_weights)
        return mass_spread(state, mass), index

    def stage_check(self, state, dataset, likelihood):
        """The remedy's check of the intermediate stages (:meth:`seqbayes.predictive.transition.PathSpace.stage_check`),
        unless this step replaces a path-space step that found nothing."""
        return self.config.remedy.stage_check(self, state, dataset, likelihood) if self.check_stages else None

    def remedy(self, state, dataset, likelihood, outcome):
        """The remedy's decision on the step's ``outcome`` (:meth:`seqbayes.predictive.transition.PathSpace.decide`)."""
        return self.config.remedy.decide(self, state, dataset, likelihood, outcome)
