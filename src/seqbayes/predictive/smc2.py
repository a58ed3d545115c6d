"""SMC^2: exact on-line inference when static and drifting parameters are tracked together.

The transition mixture of :mod:`seqbayes.predictive.mixture` carries the posterior of a static
parameter through a kernel density every step; over hundreds of steps that
re-summarisation collapses the static posterior (``docs/core.md`` measures it). SMC^2
(Chopin, Jacob and Papaspiliopoulos 2013) avoids it by never propagating a static
parameter through a density at all:

- outer particles ``phi_i`` carry the static parameters (the kernel's :class:`~seqbayes.Static`
  components) with weights ``W_i``;
- each carries an inner filter over the drifting parameters ``x`` built from the user's
  :class:`~seqbayes.MarkovKernel` and likelihood: a bootstrap particle filter of ``M`` particles
  (:class:`ParticleInnerFilter`, any model), or a Kalman filter when the user declares the
  observation linear-Gaussian in ``x`` (:class:`KalmanInnerFilter`, exact);
- the inner filter's likelihood estimate ``p^(D^s | D^{1:s-1}, phi_i)`` reweights ``phi_i``
  (unbiased, so the outer target is exact whatever ``M``), with adaptive tempering of that
  estimate when one step would leave ESS < ``tempering_threshold * N`` (density tempering,
  Duan and Fulop 2015);
- when the ESS falls the outer particles are resampled and moved by particle-marginal
  Metropolis-Hastings: a proposal ``phi'`` (the sampler's own move: SMC's Gaussian random walk
  or SEMC's stretch move with its adaptive step size, in log/logit coordinates of bounded
  parameters) re-runs its inner filter over every dataset so far, and is accepted with the
  ratio of ``p_0(phi) p^(D^{1:s-1} | phi) p^(D^s | D^{1:s-1}, phi)^beta``. A re-run costs O(s), so
  the sweeps are queued and each update spends at most a fixed budget on them
  (:mod:`seqbayes.predictive.pmmh`, exact): the cost of an update is bounded over any horizon
  (``docs/benchmarks.md``, long streams);
- the evidence increment is the weighted mean of the likelihood estimates (Eq. 1 over the
  tempering stages).

Per step the record holds one draw of ``(phi_i, x_i)`` per outer particle (``x_i`` from its
inner filter), so the drifting parameters' filtering posterior, forecasts through the kernel
and the cumulative log-evidence come out as from the other samplers; its mean and sd are
Rao-Blackwellised over every inner filter (:func:`nested_moments`).

Why by hand: ``particles`` has SMC^2, but its inner filters are Python objects, one per outer
particle, and its models are per-particle classes; here every inner filter of every outer
particle advances in one vectorised ``(N, M, d)`` call of the user's ``loglike(theta, data)``.
"""

from __future__ import annotations

import sys
import warnings
from dataclasses import dataclass, field, replace
from functools import partial

import numpy as np

from ..core.errors import InnerFilterWarning, ZeroLikelihoodError, prior_name, zero_likelihood_message
from ..core.likelihood import kept_copy
from ..core.state import Cloud, Estimate, Failure, Outcome, SamplerState, Tempered, Weighed, stored_as
from ..moves.base import MoveTally
from ..priors import JointPrior
from ..weights import resample
from ..results import ConflictInfo, EvidenceInfo, NestedInfo
from ..core.tempering import temper
from .inner import KalmanInnerFilter, ParticleInnerFilter, joint_columns, nested_split
from .particle import ParticlePredictive, prior_data_conflict
from .pmmh import MOVE_BUDGET, RESTORE_LIMIT, Budget, Refilter, Rejuvenation, outer_logpdf, rejuvenate, rerun_cost

__all__ = ["SMC2", "ParticleInnerFilter", "KalmanInnerFilter", "NestedState", "nested_split", "start_nested",
           "after_joint_first_step", "NestedPredictive", "JointFirstStep", "nested_state_arrays", "nested_state_from_arrays",
           "nested_guide", "nested_record_moments", "nested_moments", "warn_rejuvenation", "LOW_ACCEPTANCE"]


def _take(cloud: dict, index) -> dict:
    return {key: value[index] for key, value in cloud.items()}


@dataclass(frozen=True)
class SMC2:
    """SMC^2 as the predictive of a kernel with static and drifting components (the module docstring): the outer
    particles carry the static parameters, each an inner filter over the drifting ones.

    Parameters
    ----------
    inner : ParticleInnerFilter or KalmanInnerFilter
        The filter over the drifting parameters (``ParticleInnerFilter(100)``).
    move_budget : float or None
        The PMMH evaluations one update may spend on deferrable moves, in units of ``N M`` (``M`` the inner
        particles, 1 for the Kalman inner filter; :data:`~seqbayes.predictive.pmmh.MOVE_BUDGET` = 5). Moves beyond
        it wait for later updates (:mod:`seqbayes.predictive.pmmh`), which bounds the cost per update over a long
        stream. Deferrable are only the moves of an untempered update, and after a resampling only once the copies
        it left are as diverse as its weights were (up to ``pmmh.RESTORE_LIMIT`` = 4 budgets more). ``None``:
        every rejuvenation completes in its update.
    strict_budget : bool
        ``True`` makes ``move_budget`` a hard cap on every update's PMMH moves: a tempered update's stages share one
        budget, restoring the copies' diversity spends from it, and SEMC's PMMH proposes by differential evolution,
        which travels further per inner-filter re-run (docs/benchmarks.md, "Coulomb at 50,000 calls"). ``False``
        (default): tempered updates complete their moves.
    """

    inner: ParticleInnerFilter | KalmanInnerFilter = ParticleInnerFilter()
    move_budget: float | None = MOVE_BUDGET
    strict_budget: bool = False

    method = "smc2"

    def __post_init__(self):
        if not (hasattr(self.inner, "advance") and hasattr(self.inner, "draws")):
            raise TypeError("inner: expected a seqbayes.ParticleInnerFilter or KalmanInnerFilter")
        budget = self.move_budget
        if budget is not None and not (isinstance(budget, (int, float)) and not isinstance(budget, bool)
                                       and budget > 0 and np.isfinite(budget)):
            raise ValueError(f"move_budget: expected None or a finite number > 0, got {budget!r}")
        if self.strict_budget not in (True, False):
            raise ValueError(f"strict_budget: expected True or False, got {self.strict_budget!r}")

    def resolve(self, kernel) -> "SMC2":
        """This predictive, checked against ``kernel`` (static and drifting components, no jumps)."""
        if kernel.has_jumps:  # the inner filters assume a Gaussian transition
            raise ValueError("predictive: SMC2 does not support Jump components; use Transition()")
        if nested_split(kernel) is None:
            raise ValueError("predictive: SMC2 needs a kernel of components with both Static and drifting ones")
        return self

    def predictive(self, state, problem, config):
        """The step's predictive: :class:`NestedPredictive`, or for the first dataset with ``joint_first_step``
        :class:`JointFirstStep` from a :class:`~seqbayes.core.state.SamplerState` over every parameter."""
        if state.step > 0 or not problem.inner_filter.joint_first_step:
            return NestedPredictive(problem, config), state
        return JointFirstStep(problem, config, "joint"), SamplerState(0, state.particles, state.log_weights,
                                                                       problem.prior, 0.0, state.step_size)


def _fill_nested(arrays: dict, n_samples: int) -> None:
    """Complete (in place) a full SMC^2 state of a store written before budgeted PMMH: nothing pending."""
    if "nested_particles" in arrays and "nested_pmmh_queue" not in arrays:  # a full state (format 5 keeps two)
        arrays["nested_pmmh_queue"] = np.full(n_samples, -1.0)
        arrays["nested_pmmh_tally"] = np.zeros(4)
        arrays["nested_pmmh_moved"] = np.zeros(n_samples)
        arrays["nested_moments"] = np.vstack(nested_moments(arrays["nested_particles"],
                                                            arrays["nested_log_weights"], None, []))


@stored_as("nested", "nested_", needs_datasets=True, whole=True, fill=_fill_nested,
           every_step=("nested_guide_used", "nested_guide_mean", "nested_guide_cov", "nested_moments"))
@dataclass(frozen=True, eq=False)
class NestedState:
    """Everything SMC^2 needs to assimilate the next dataset.

    Attributes
    ----------
    step : int
    outer : (N, d_o) array
        Outer particles: the static parameters, and with :class:`ParticleInnerFilter` the drifting
        parameters' first value (columns ``inner.outer_columns``).
    cloud : dict of arrays with leading axis N
        The inner filters after the last dataset.
    log_weights : (N,) array
        Normalised outer log-weights.
    log_prior : (N,) array
        ``log p_0`` of the outer particles.
    log_likelihood : (N,) array
        ``log p^(D^{1:s} | outer)``, the inner filters' running likelihood estimates.
    datasets : tuple
        ``D^1 .. D^s`` (PMMH re-runs the inner filters over them).
    log_evidence, step_size : float
    particles : (N, d) array
        One joint draw per outer particle (the last posterior; the prior draws before the first step).
    predictive : (N, d) array or None
        Those draws propagated through the kernel (the record's predictive), the reference of the
        next step's prior-data conflict diagnostic.
    guides : tuple
        Per step, the inner filters' guide ``(mean, cov)`` or ``None`` (:meth:`ParticleInnerFilter.fit_guide`);
        PMMH re-runs use the same guides, which keeps their likelihood estimates unbiased.
    pending : Rejuvenation
        The PMMH moves still to make since the last resampling (:mod:`seqbayes.predictive.pmmh`).
    n_evals_total : int
        Likelihood evaluations of every step so far (the amortised cost is this over ``step``).
    moments : tuple ``(mean (d,), sd (d,))`` or None
        The step's posterior moments with the drifting parameters Rao-Blackwellised (:func:`nested_moments`).
    """

    step: int
    outer: np.ndarray
    cloud: dict
    log_weights: np.ndarray
    log_prior: np.ndarray
    log_likelihood: np.ndarray
    datasets: tuple
    log_evidence: float
    step_size: float
    particles: np.ndarray = field(default=None)
    predictive: np.ndarray | None = None
    guides: tuple = ()
    pending: Rejuvenation = field(default_factory=Rejuvenation)
    n_evals_total: int = 0
    moments: tuple | None = None

    def to_arrays(self) -> dict:
        """The run store's arrays: :func:`nested_state_arrays`, each name prefixed ``nested_``."""
        return {"nested_" + key: value for key, value in nested_state_arrays(self).items()}

    @classmethod
    def from_arrays(cls, arrays_by_step, datasets) -> "NestedState":
        """The state after step ``s`` from the :meth:`to_arrays` of steps ``1 .. s`` (the earlier steps' guides only)
        and the datasets ``D^1 .. D^s``."""
        def strip(arrays):
            return {key[len("nested_"):]: value for key, value in arrays.items()}
        guides = tuple(nested_guide(strip(a)) for a in arrays_by_step[:-1])
        return nested_state_from_arrays(strip(arrays_by_step[-1]), tuple(datasets), guides)

    @property
    def prior_draws(self) -> np.ndarray:
        """Draws of the next step's prior (the last posterior propagated; the prior before step 1)."""
        return self.predictive if self.predictive is not None else self.particles

    @property
    def posterior(self) -> np.ndarray | None:
        return self.particles if self.step else None

    @property
    def posterior_log_weights(self) -> np.ndarray | None:
        return self.log_weights if self.step else None


def start_nested(prior: JointPrior, columns: np.ndarray, draws: np.ndarray, step_size: float) -> NestedState:
    """The state before the first dataset, from ``draws (N, d)`` of the prior; ``columns`` are the
    outer particles' columns."""
    n = draws.shape[0]
    outer = draws[:, columns]
    return NestedState(0, outer, {}, np.full(n, -np.log(n)), outer_logpdf(prior, columns, outer),
                       np.zeros(n), (), 0.0, float(step_size), draws)


def after_joint_first_step(split: tuple[np.ndarray, np.ndarray], n_inner: int, particles: np.ndarray, log_weights: np.ndarray,
                           components: np.ndarray, dataset: Any, log_evidence: float, step_size: float,
                           posterior: np.ndarray, predictive: np.ndarray, n_evals: int = 0) -> NestedState:
    """The state after a first step done jointly over every parameter (``joint_first_step``):
    ``components`` are ``(log L_1, log p_0)`` at ``particles (N, d)``; each inner filter holds
    ``n_inner`` copies of its outer particle's drifting values; ``n_evals`` is the step's evaluations."""
    n = particles.shape[0]
    x = np.repeat(particles[:, None, split[1]], n_inner, axis=1)
    return NestedState(1, particles, {"x": x, "log_w": np.full((n, n_inner), -np.log(n_inner)), "ess": np.ones(n)},
                       log_weights, components[:, 1].copy(), components[:, 0].copy(), (kept_copy(dataset),),
                       float(log_evidence), float(step_size), posterior, predictive, (None,), Rejuvenation(),
                       int(n_evals))


@dataclass(frozen=True, eq=False)
class OuterCloud(Cloud):
    """The outer particles between stages (``particles`` the static parameters, ``components`` the ``(N, 3)`` of
    :func:`~seqbayes.predictive.pmmh.rejuvenate`) with their inner filters (``inner``) and the pending moves."""

    inner: dict | None = None
    pending: Rejuvenation = field(default_factory=Rejuvenation)
    concluded: float = float("nan")


@dataclass(frozen=True, eq=False)
class OuterWeighed(Weighed):
    """:class:`~seqbayes.core.state.Weighed` with what SMC^2's later stages need: the datasets and guides so far
    and the inner filters' mean ESS."""

    datasets: tuple = ()
    guides: tuple = ()
    inner_ess: float = float("nan")


@dataclass(frozen=True, eq=False)
class _Rejuvenating:
    """SMC^2's particles between the stages of the tempering loop: the outer cloud, the moves so far (``n_virtual``:
    the PMMH batches), the evaluations spent on them in this update and whether the last stage resampled."""

    cloud: OuterCloud
    moves: MoveTally
    spent: int = 0
    resampled: bool = False


class NestedPredictive:
    """SMC^2 as a step's predictive (:class:`~seqbayes.predictive.particle.Predictive`): the inner filters' likelihood
    estimates weigh the outer particles; they are resampled when the ESS has fallen and moved by PMMH within a
    per-update budget (:func:`~seqbayes.predictive.pmmh.rejuvenate`); the evidence increment is the tempering
    path's (Eq. 1)."""

    def __init__(self, problem, config):
        self.problem, self.config = problem, config
        self.split, self.inner = nested_split(problem.kernel), problem.inner_filter

    def remedy(self, state, dataset, likelihood, outcome):
        return None

    def weigh(self, state, dataset, likelihood, rng) -> OuterWeighed | Failure:
        problem, split, inner, step = self.problem, self.split, self.inner, state.step + 1
        guide = (inner.fit_guide(problem, split, state.outer, state.log_weights, state.cloud, dataset, likelihood, rng)
                 if step > 1 else None)
        log_increment, cloud = inner.advance(problem, split, state.outer, state.cloud or None, dataset, step == 1,
                                             likelihood, rng, guide)
        inner_ess = float(np.exp(state.log_weights) @ cloud["ess"]) if "ess" in cloud else float("nan")
        components = np.column_stack([log_increment, state.log_prior, state.log_likelihood])
        if not np.isfinite(log_increment).any():
            return Failure(ZeroLikelihoodError(zero_likelihood_message(step, prior_name(step), likelihood)))
        return OuterWeighed(OuterCloud(state.outer, state.log_weights, components, inner=cloud, pending=state.pending),
                            None, MoveTally(step_size=state.step_size), n_found=self.config.n_samples,
                            datasets=state.datasets + (kept_copy(dataset),), guides=state.guides + (guide,),
                            inner_ess=inner_ess)

    def temper(self, state, dataset, weighed, likelihood, rng) -> Tempered | Failure:
        """Reweight by the likelihood estimates' ``delta`` powers (density tempering) through the one tempering loop
        (:func:`~seqbayes.core.tempering.temper`); when the ESS falls, resample and schedule PMMH sweeps
        (:meth:`_resample_rejuvenate`). A tempered update completes them at every stage; an untempered one restores
        the copies' diversity to the ESS before the resampling, then spends what is left of
        ``SamplerConfig.move_budget x N M`` evaluations and defers the rest (:mod:`seqbayes.predictive.pmmh`)."""
        cloud = weighed.cloud
        annealed = temper(_Rejuvenating(cloud, MoveTally(step_size=weighed.moves.step_size)), cloud.components[:, 0],
                          cloud.log_weights, self.config.tempering,
                          partial(self._resample_rejuvenate, weighed=weighed, likelihood=likelihood, rng=rng),
                          likelihood.step)
        if annealed.decision is not None:  # a stage's Failure
            return annealed.decision
        staged = annealed.particles
        return Tempered(staged.cloud, annealed.log_z, annealed.temperatures, staged.moves, staged.resampled,
                        annealed.last.ess)

    def _resample_rejuvenate(self, staged, loglike, stage, weighed, likelihood, rng):
        """SMC^2's mutation (:class:`~seqbayes.core.tempering.Mutation`): resample at an intermediate stage, or at the
        last when the ESS is below ``ess_threshold * N`` (which concludes the last rejuvenation and schedules the
        next), then the PMMH attempts the budget allows (:func:`~seqbayes.predictive.pmmh.rejuvenate`)."""
        config, n, beta, smc2 = self.config, self.config.n_samples, stage.beta, self.config.predictive
        outer, log_weights = staged.cloud, stage.log_weights
        static, components, cloud = outer.particles, outer.components, outer.inner
        pending, concluded = outer.pending, outer.concluded
        resampled = beta < 1.0 or stage.ess < config.tempering.resample_below * n
        if resampled:
            index = resample(config.tempering.scheme, stage.weights, rng, n)
            static, components, cloud = static[index], components[index], _take(cloud, index)
            log_weights = np.full(n, -np.log(n))
            if pending.n_proposed >= n // 2:  # the previous rejuvenation ends here: judged if it made half a sweep
                concluded = pending.acceptance
            pending = pending.restarted(config.moves.max_sweeps, n)
        moves, spent = staged.moves, staged.spent
        if pending.pending:
            budget = (sys.maxsize if smc2.move_budget is None  # None: the rejuvenation completes in this update
                      else int(smc2.move_budget * n * int(getattr(self.inner, "n_inner", 1))))
            was_pending = pending.n_proposed
            # a tempered update completes its moves (each exponent is chosen from the particles' ESS, which
            # copies overstate); an untempered one first brings the copies back to the ESS the weights had
            # before the resampling, then defers what exceeds the budget
            # (with strict_budget, a tempered update too: its stages share one budget, restoring included)
            tempered = beta < 1.0 or stage.index > 1
            allowed = sys.maxsize if tempered and not smc2.strict_budget else budget
            allowance = Budget(allowed, restore=stage.ess / n if resampled else 0.0,
                               spent=spent if smc2.strict_budget else 0,
                               restore_limit=1.0 if smc2.strict_budget else RESTORE_LIMIT)
            static, cloud, components, sweep, step_size, batches, pending = rejuvenate(
                Refilter(self.problem, self.inner, self.split, weighed.datasets, weighed.guides), config, static,
                log_weights, cloud, components, beta, moves.step_size, pending, allowance, likelihood, rng)
            spent += sweep.n_evaluations * rerun_cost(self.inner, weighed.datasets)   # the budget's units: M s per re-run
            moves = MoveTally(moves.stats + sweep, config.moves.step_size_after(step_size, moves.step_size),
                              moves.n_virtual + batches)
            if not pending.pending and pending.n_proposed > was_pending:
                concluded = pending.acceptance
        outer = OuterCloud(static, log_weights, components, inner=cloud, pending=pending, concluded=concluded)
        return _Rejuvenating(outer, moves, spent, resampled), components[:, 0], log_weights, None

    def estimate(self, tempered, weighed, likelihood, rng) -> Estimate:
        """The tempering path's estimate (Eq. 1): the likelihood estimates are unbiased, so is it."""
        return Estimate(tempered.cloud, tempered.log_z, float("nan"), 0, False, tempered.moves)

    def propagate(self, state, weighed, tempered, estimate, dataset, likelihood, rng) -> Outcome:
        """One joint draw per outer particle (its drifting values from its inner filter), propagated; the record's
        moments are Rao-Blackwellised over every inner filter (:func:`nested_moments`)."""
        kernel, split, config = self.problem.kernel, self.split, self.config
        outer = estimate.cloud
        static, cloud, components, log_weights = outer.particles, outer.inner, outer.components, outer.log_weights
        if static.shape[1] == kernel.dim:  # the outer particles hold every column: replace the drifting ones
            posterior = static.copy()
            posterior[:, split[1]] = self.inner.draws(cloud, rng)
        else:
            posterior = joint_columns(static, self.inner.draws(cloud, rng), split, kernel.dim)
        log_evidence = float(state.log_evidence + estimate.log_increment)
        conflict = prior_data_conflict(state.prior_draws, state.log_weights, posterior, log_weights)
        predictive = kernel.propagate(posterior, rng)
        step_size = estimate.moves.step_size
        pending, step = outer.pending, state.step + 1
        n_evals_total = state.n_evals_total + likelihood.n_evals
        moments = nested_moments(posterior, log_weights, self.inner.moments(cloud), split[1])
        new_state = NestedState(step, static, cloud, log_weights, components[:, 1],
                                components[:, 2] + components[:, 0], weighed.datasets, log_evidence, float(step_size),
                                posterior, predictive, weighed.guides, pending, n_evals_total, moments)
        # a rejuvenation the budget spreads over many updates concludes rarely: judge it by its running acceptance
        # once it has proposed enough to tell 0.2 from well above it (50: binomial se 0.06), while it still runs
        running = not np.isfinite(outer.concluded) and pending.n_proposed >= MIN_RUNNING_PROPOSALS
        warn_rejuvenation(step, pending.acceptance if running else outer.concluded, weighed.inner_ess,
                          len(weighed.datasets), int(getattr(self.inner, "n_inner", 0)), running)
        records = dict(evidence=EvidenceInfo(float(tempered.log_z), estimate.evidence_ess, estimate.n_independent),
                       conflict=ConflictInfo(float(conflict.max()), int(conflict.argmax())),
                       nested=NestedInfo(weighed.inner_ess, n_evals_total / step,
                                         pending.acceptance if pending.n_proposed else outer.concluded,
                                         int(pending.queue.size + pending.sweeps_left * config.n_samples)))  # at most
        return Outcome(new_state, posterior, log_weights, predictive, static, log_evidence,
                       float(config.moves.step_size_after(step_size, float("nan"))), records, moments=moments)


#: A rejuvenation whose PMMH acceptance ends below this draws a warning: the inner likelihood estimates are too
#: noisy for the moves to keep the outer particles diverse at a bounded cost.
LOW_ACCEPTANCE = 0.2
#: Proposals a running (not yet concluded) rejuvenation needs before its acceptance draws that warning.
MIN_RUNNING_PROPOSALS = 50


def warn_rejuvenation(step: int, acceptance: float, inner_ess: float, n_datasets: int, n_inner: int,
                      running: bool = False) -> None:
    """One line when a rejuvenation ended with a PMMH acceptance below :data:`LOW_ACCEPTANCE`, or (``running``) one
    that the move budget carries over updates is below it so far, saying what to change."""
    if not acceptance < LOW_ACCEPTANCE:
        return
    advice = (f"raise n_inner (now {n_inner}; the variance of the inner filters' log-likelihood estimates grows "
              f"like s / n_inner, so doubling n_inner halves it)" if n_inner else "the Kalman inner filter is exact: the static parameters' proposal is "
              "too wide; use SEMC, whose step size adapts")
    if n_inner and inner_ess < 0.1:
        advice += (f"; the inner filters keep only {100 * inner_ess:.0f} % of their particles per step, so a kernel "
                   f"noise closer to the drift the data show, or a KalmanInnerFilter if the model is linear-Gaussian "
                   f"in the drifting parameters, pays more than n_inner")
    which = ("so far in the rejuvenation that the move budget spreads over updates" if running
             else "over the last rejuvenation")
    warnings.warn(f"step {step}: SMC^2's PMMH moves accepted {100 * acceptance:.0f} % of proposals {which} (at s = "
                  f"{n_datasets}); each accepted move costs ~{1 / max(acceptance, 1e-3):.0f} "
                  f"re-runs of an inner filter over the whole history: {advice}", InnerFilterWarning, stacklevel=2)


def nested_moments(posterior: np.ndarray, log_weights: np.ndarray,
                   inner_moments: tuple[np.ndarray, np.ndarray] | None, drifting: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The posterior's mean and sd ``(d,)``, the drifting columns Rao-Blackwellised: from each outer particle's whole
    inner filter (its weighted mean and variance ``inner_moments``, each ``(N, d_x)``) instead of its one draw.

    ``E[x] = sum_i W_i m_i`` and ``Var[x] = sum_i W_i (v_i + m_i^2) - E[x]^2`` (the law of total variance);
    ``inner_moments=None``: every column from the draws."""
    w = np.exp(log_weights - log_weights.max())
    w /= w.sum()
    mean = w @ posterior
    var = w @ (posterior - mean) ** 2
    if inner_moments is None:
        return mean, np.sqrt(var)
    m, v = inner_moments
    mean[drifting] = w @ m
    var[drifting] = np.maximum(w @ (v + (m - mean[drifting]) ** 2), 0.0)
    return mean, np.sqrt(var)


class JointFirstStep(ParticlePredictive):
    """SMC^2's first dataset with a particle inner filter (``joint_first_step``): with no dynamics yet, a static
    step in every parameter, whose particles then seed the outer particles and their inner filters."""

    def next_prior(self, state, cloud, dataset, log_increment, log_evidence, rng):
        return None, self.problem.kernel.propagate(cloud.particles, rng), None

    def propagate(self, state, weighed, tempered, estimate, dataset, likelihood, rng) -> Outcome:
        outcome = super().propagate(state, weighed, tempered, estimate, dataset, likelihood, rng)
        cloud = estimate.cloud
        nested = after_joint_first_step(nested_split(self.problem.kernel), self.problem.inner_filter.n_inner,
                                        cloud.particles, cloud.log_weights, cloud.components, dataset,
                                        outcome.log_evidence, outcome.state.step_size, cloud.particles,
                                        outcome.predictive, likelihood.n_evals)
        moments = nested_moments(outcome.posterior, outcome.log_weights, None, np.zeros(0, dtype=int))
        records = dict(outcome.records, nested=NestedInfo(amortised_evals=float(likelihood.n_evals)))
        return replace(outcome, state=replace(nested, moments=moments), records=records, moments=moments)


def nested_state_arrays(state: NestedState) -> dict:
    """The arrays that, with the datasets, rebuild ``state`` (:func:`nested_state_from_arrays`), for the
    run store: every value is a float array; the inner filter's cloud keys are prefixed ``cloud_``."""
    out = {"outer": state.outer, "log_weights": state.log_weights, "log_prior": state.log_prior,
           "log_likelihood": state.log_likelihood, "particles": state.particles,
           **({"predictive": state.predictive} if state.predictive is not None else {}),
           "scalars": np.array([state.step, state.log_evidence, state.step_size], dtype=float)}
    out.update({f"cloud_{key}": value for key, value in state.cloud.items()})
    d_x = (state.cloud["x"] if "x" in state.cloud else state.cloud["mean"]).shape[-1]  # drifting parameters
    guide = state.guides[-1] if state.guides else None
    out["guide_used"] = np.array(float(guide is not None))  # this step's guide only: the store keeps every step
    out["guide_mean"] = guide[0] if guide is not None else np.zeros(d_x)
    out["guide_cov"] = guide[1] if guide is not None else np.zeros((d_x, d_x))
    pending = state.pending  # the queue padded with -1 to a fixed (N,), so that every step's arrays have one shape
    queue = np.full(state.log_weights.size, -1.0)
    queue[:pending.queue.size] = pending.queue
    out["pmmh_queue"] = queue
    out["pmmh_tally"] = np.array([pending.sweeps_left, pending.n_proposed, pending.n_accepted, state.n_evals_total])
    out["pmmh_moved"] = pending.moved if pending.moved.size else np.zeros(queue.size, dtype=bool)
    out["moments"] = np.vstack(state.moments if state.moments is not None
                               else nested_moments(state.particles, state.log_weights, None, np.zeros(0, dtype=int)))
    return {key: np.asarray(value, dtype=float) for key, value in out.items()}


def nested_guide(arrays: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """The guide of the step whose :func:`nested_state_arrays` are ``arrays`` (``None`` if unguided)."""
    if "guide_used" not in arrays or not float(arrays["guide_used"]):
        return None
    return np.array(arrays["guide_mean"]), np.array(arrays["guide_cov"])


def nested_state_from_arrays(arrays: dict, datasets: tuple, guides: tuple = ()) -> NestedState:
    """The inverse of :func:`nested_state_arrays`; ``datasets`` are ``D^1 .. D^s`` and ``guides`` the
    guides of steps ``1 .. s - 1`` (:func:`nested_guide` of their arrays)."""
    step, log_evidence, step_size = np.asarray(arrays["scalars"], dtype=float)
    if int(step) != len(datasets):
        raise ValueError(f"datasets: {len(datasets)} datasets for a state at step {int(step)}")
    cloud = {key[len("cloud_"):]: np.array(value) for key, value in arrays.items() if key.startswith("cloud_")}
    if len(guides) != int(step) - 1:
        raise ValueError(f"guides: {len(guides)} guides for a state at step {int(step)} (expected {int(step) - 1})")
    pending, n_evals_total = Rejuvenation(), 0
    if "pmmh_queue" in arrays:  # stores of earlier formats have no pending moves
        queue = np.asarray(arrays["pmmh_queue"], dtype=float)
        sweeps_left, n_proposed, n_accepted, n_evals_total = (int(v) for v in np.asarray(arrays["pmmh_tally"]))
        moved = np.asarray(arrays.get("pmmh_moved", np.zeros(queue.size)), dtype=float) > 0
        pending = Rejuvenation(queue[queue >= 0].astype(int), sweeps_left, n_proposed, n_accepted, moved)
    moments = nested_record_moments(arrays)
    return NestedState(int(step), np.array(arrays["outer"]), cloud, np.array(arrays["log_weights"]),
                       np.array(arrays["log_prior"]), np.array(arrays["log_likelihood"]), tuple(datasets),
                       float(log_evidence), float(step_size), np.array(arrays["particles"]),
                       np.array(arrays["predictive"]) if "predictive" in arrays else None,
                       tuple(guides) + (nested_guide(arrays),), pending, n_evals_total, moments)


def nested_record_moments(arrays: dict) -> tuple[np.ndarray, np.ndarray] | None:
    """The Rao-Blackwellised ``(mean, sd)`` kept in a step's :func:`nested_state_arrays` (``None`` if not kept)."""
    moments = np.asarray(arrays.get("moments", np.nan), dtype=float)
    if moments.ndim != 2 or not np.all(np.isfinite(moments)):
        return None
    return moments[0].copy(), moments[1].copy()

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from typing import Any

    from ..core.state import Problem
