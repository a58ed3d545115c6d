"""The on-line engine shared by :class:`SMC` and :class:`SEMC`.

One dataset ``D^s`` is assimilated by the pure function :func:`assimilate`
(docs/core.md explains each choice with its measurements):

1. The prior particles (prior draws at ``s = 1``, predictive draws of Eq. A3
   after) are weighted by the likelihood (Eq. A4-A5). If few of them have a
   non-zero likelihood, or the kernel carried some out of the parameter space,
   the step restarts from the prior restricted to ``{inside, L > 0}``.
2. The likelihood enters in one stage, or, when that would leave less than 10 %
   of the ESS, in adaptive tempering stages ``0 < beta_1 < ... < 1`` chosen by
   bisection on the ESS.
3. After each stage the particles are resampled (always at an intermediate
   stage; at the last when the ESS is below the threshold) and moved by an MCMC
   kernel that leaves ``L^beta p_s`` invariant, in log/logit coordinates of
   bounded parameters: Gaussian random-walk MH for SMC (Eq. A6-A8), stretch-move
   sweeps with the adaptive step size and "virtual iterations" of Algorithm 2
   for SEMC.
4. The evidence increment is estimated by defensive importance sampling from
   the final posterior (:mod:`seqbayes.evidence`), whose proposal also drives
   independence-MH sweeps; the stages' product of mean weights (Eq. 1) is kept
   as the "path" estimate.
5. The posterior is propagated through the Markov kernel (Eq. A2), and the
   predictive density (Eq. A3) becomes the next step's prior.

The parameter space is the initial prior's support and the likelihood is zero
outside it, so a kernel that predicts impossible parameters loses evidence.

The drivers :class:`SMC` and :class:`SEMC` hold the current :class:`SamplerState`
and call :func:`assimilate`.
"""

from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, fields, replace

import numpy as np

from .density import (PREDICTIVE_METHODS, GaussianMixture, HistoryPrior, RunningStatistics, SubsampledPrior,
                      predictive_density)
from .evidence import DefensiveProposal, importance_step, pooled_start, step_standard_errors
from .kernels import MarkovKernel, jump_step_fields
from .nested import (NestedState, ParticleInnerFilter, after_joint_first_step, assimilate_nested, nested_split,
                     start_nested)
from .moves import (GaussianMove, StretchMove, SweepStats, gaussian_sweep, next_step_size,
                    paper_target_acceptance, stretch_sweep, weighted_covariance)
from .moves.scaled import (DifferentialMove, FittedGaussian, differential_sweep, independence_sweep,
                           whitened_jumps)
from .parallel import evaluate_loglike
from .density import AncestorSpread, grouped_ancestor_variance, kept_copy
from .priors import as_samples, inside_support, support_of
from .resampling import SCHEMES, resample
from .results import Result, StepInfo, StepRecord, prior_data_conflict
from .rng import as_generator, generator_from_state, generator_state
from .tempering import blas_limit, next_increment
from .transforms import BoxTransform
from .weights import ess, logsumexp

__all__ = ["SMC", "SEMC", "SamplerConfig", "SamplerState", "assimilate", "assimilate_paths", "ancestor_draws",
           "forecast", "PastStep", "resolve_predictive", "ZeroLikelihoodError",
           "TemperingLimitError", "PriorDataConflictWarning", "InnerFilterWarning"]


class ZeroLikelihoodError(RuntimeError):
    """Every sample has zero likelihood for a dataset."""


class PriorDataConflictWarning(RuntimeWarning):
    """A step's posterior lies far in the tail of its prior (``StepInfo.prior_data_conflict``)."""


class InnerFilterWarning(RuntimeWarning):
    """SMC^2's inner particle filters are degenerate (``StepInfo.inner_ess`` below 0.05)."""


class TemperingLimitError(RuntimeError):
    """Bridging to a dataset took more tempering stages than allowed (``max_stages``)."""


#: Above this many parameters the default moves are the scaled ones (``SamplerConfig.scaled_moves``).
HIGH_DIMENSION = 10
#: Scaled moves stop when the particles' mean squared whitened travel reaches this fraction of 2 d.
JUMP_TARGET, ECONOMY_JUMP_TARGET = 1.0, 0.5
#: ``economy``: the importance sweeps continue until the increment's standard error is below this.
ECONOMY_EVIDENCE_SE = 0.02
#: ``economy``: the scaled moves stop once this fraction of the particles has moved (at most ``moved_fraction``).
ECONOMY_MOVED_FRACTION = 0.7
#: Acceptance rate the scaled moves' local step aims at (Eq. 9 adapts its scale within a stage; Roberts et al. 1997).
LOCAL_ACCEPTANCE = 0.234


@dataclass(frozen=True)
class SamplerConfig:
    """Settings of an on-line sampler (validated on construction).

    Attributes
    ----------
    move : {"stretch", "gaussian"}
        SEMC's affine-invariant stretch move or SMC's Gaussian random walk.
    n_samples : int
    tempering : bool
        Adaptive tempering inside a step (default); ``False`` is the paper's single reweighting.
    tempering_ess : float
        Target ESS fraction of each tempering stage (0.5).
    max_stages : int
        Cap on tempering stages per step (1000). The stages grow about linearly with how far
        the data lie from the current samples (a dataset offset by 100 noise sds from the
        prediction takes ~200); beyond the cap the step stops with
        :class:`TemperingLimitError` (usually wrong units or a broken sensor) and the
        sampler's state is unchanged.
    tempering_threshold : float
        Tempering starts only when assimilating the rest of the dataset at once would leave
        less than this ESS fraction (0.1): a milder reweighting is done in one stage, whose
        resampled duplicates the moves then spread (fewer resamplings, less Monte Carlo
        error on static parameters).
    ess_threshold : float
        Resample at the last stage when ESS < ``ess_threshold * N`` (authors' code: 0.5).
    resampling : str
        ``"systematic"``, ``"multinomial"`` (the paper's), ``"stratified"`` or ``"residual"``.
    predictive : {"auto", "transition", "kde", "history", "smc2"}
        Predictive prior construction (see :mod:`seqbayes.density`). ``"auto"`` (default):
        ``"history"`` when every parameter is static (the exact prior, re-evaluating the past
        datasets as IBIS does; each evaluation costs one likelihood call per past dataset),
        ``"smc2"`` when the kernel has both static and drifting components (outer particles
        over the static parameters, each with an inner filter over the drifting ones:
        :mod:`seqbayes.nested`), ``"transition"`` otherwise (every parameter drifts).
    shrink_static : bool
        Liu-West shrinkage of the static dimensions' kernel density.
    target_acceptance : float
        SEMC's target acceptance rate ``alpha_tr``.
    step_size : float
        SEMC's initial stretch step size ``u``.
    max_virtual : int
        Cap on SEMC virtual iterations (sweeps) per stage (30).
    virtual_tolerance : float
        Stop virtual iterations when ``|alpha - alpha_old| < virtual_tolerance * alpha_tr``.
    n_moves : int
        Minimum MH steps (SMC) or sweeps (SEMC) per stage (3, as the authors' ``thinchain``).
    moved_fraction : float
        Keep moving until this fraction of the particles has moved at least once in the
        stage (0.9; 0 disables), up to ``max_moves`` (SMC) or ``max_virtual`` (SEMC).
    max_moves : int
        Cap on SMC's MH steps per stage.
    move_every_stage : bool or None
        ``True`` moves the particles after every stage (the paper's Algorithm 4). ``False``
        moves only after a resampling, to rejuvenate its duplicates, as IBIS (Chopin 2002)
        and ``particles`` do: cheaper (no likelihood evaluation in a step that keeps its ESS),
        but duplicates from earlier resamplings are then moved less often. ``None`` (default):
        ``True``, except with the history prior, where the particles are resampled and moved
        only when the ESS falls below ``ess_threshold`` (every move re-evaluates the past
        datasets; moving only then spaces the moves out as the posterior concentrates and
        bounds the amortised cost of an update), and a step that did not move takes its
        evidence from the weights, not from the importance sampler. ``False`` also defers
        that resample-move to the next dataset's arrival, as ``particles`` does.
    n_independent : int
        Independence-MH sweeps (3) at the end of a step with ``evidence="importance"``
        (proposals from the posterior-fitted importance density; each sweep after the
        first costs N likelihood evaluations).
    min_evidence_ess, max_refits : float, int
        When the importance ESS is below ``min_evidence_ess * N`` (0.3), the importance
        density is refitted to the swept particles and the estimate repeated, up to
        ``max_refits`` (5) times.
        With 1 (the paper's SMC) the error of a static parameter after 5 steps grows ~1.5x.
    proposal_scale : float
        SMC's ``gamma`` of Eq. (A7).
    conflict_threshold : float
        A :class:`PriorDataConflictWarning` is issued when a step's posterior mean lies more than
        this many prior sds from its prior mean (``StepInfo.prior_data_conflict``; 4), or when it
        is carried by a few of the predictive mixture's components (``StepInfo.ancestor_ess``
        below ``remedy_ess * N``, which also starts the remedy; docs/prior_data_conflict.md).
    conflict_remedy : bool
        The exact remedy for prior-data conflict (issue 11; on by default). A step whose posterior
        is carried by the far tail of the predictive mixture (``StepInfo.ancestor_ess`` below
        ``remedy_ess * N``, or ``StepInfo.prior_data_conflict`` above ``conflict_threshold``) is
        assimilated again on the path space of the last ``remedy_lag`` steps, whose target is the
        model's exact one (see :func:`assimilate_paths`); ``StepInfo.path_steps`` records it.
        Applies to the ``"transition"`` and ``"kde"`` predictives of kernels in which every
        parameter moves; ``"history"`` is exact already, and ``"smc2"`` is not covered.
    remedy_ess : float
        Fraction of N below which the ancestor ESS triggers the remedy (0.05; five times that
        right after a path-space step).
    remedy_lag : int
        Steps kept for the path-space target (10): exact when the run has at most that many steps,
        else the window's first state takes the (mixture) prior that step used.
    remedy_bridge : bool
        How the path-space step reaches its target. ``True`` (default): from the window's path prior
        (the window's first prior, then the kernel), tempering every likelihood of the window jointly, so
        that each mode of the path posterior (one per choice of the dataset a path gives up, under a
        kernel the data contradict) is weighed afresh and the window's evidence estimated directly.
        ``False``: from the stored paths of the previous posterior, tempering only the new dataset (about
        half the cost; it cannot reach a mode whose earlier states the earlier steps ruled out: run 9 of
        the oscillator study under T3-T5 ended 1-24 exact sds and ~40 nats off). Both
        :func:`assimilate_paths`; docs/prior_data_conflict.md.
    n_inner : int
        SMC^2 (static and drifting parameters): particles of the default inner filter
        (:class:`~seqbayes.nested.ParticleInnerFilter`) per outer particle (100).
    transform : bool
        Move in unconstrained coordinates (log / logit of bounded parameters; see
        :mod:`seqbayes.transforms`). ``False`` moves in the parameters' own
        coordinates, as the paper does.
    min_valid_fraction : float
        When fewer particles than this fraction have a non-zero likelihood, the step
        starts from draws of the prior restricted to the non-zero region (rejection
        sampling, at most 100 N likelihood evaluations; its mass enters the evidence).
        0 disables it (the paper's behaviour; advisable for very expensive likelihoods).
    evidence : {"importance", "path"}
        Estimator of the evidence increment: defensive importance sampling from the
        final posterior (:mod:`seqbayes.evidence`, N extra likelihood evaluations, whose
        draws also drive one independence-MH sweep of the particles), or the tempering
        path's product of mean weights alone (Eq. 1, the paper's). Both estimates are
        recorded in :class:`StepInfo`.
    pseudo_marginal_from : int
        From this many particles on (2048; 0 never), a step under the ``"transition"`` mixture prior
        (Eq. A3) lets its moves evaluate the prior by an unbiased estimate from a subsample of the
        mixture's components (pseudo-marginal moves, exact in distribution; ``O(N M)`` per sweep
        instead of ``O(N^2)``) where a pilot shows the estimate accurate, else exactly
        (:class:`~seqbayes.density.SubsampledPrior`).
    scaled_moves : bool or None
        Moves that keep working as the dimension grows (:mod:`seqbayes.moves.scaled`, issue 14). Each
        round at a stage is an independence-MH sweep (every particle proposes a fresh draw of a density
        fitted to the particles before the stage's moves: the Gaussian of their mean and covariance above
        d = 10, the evidence's kernel density + Student t up to d = 10), then a local sweep (SMC: the
        random walk with ``2.38 / sqrt(d)`` times the particles' covariance factor; SEMC: the
        differential-evolution move, half against half; both scaled by a factor that Eq. 9 adapts towards
        acceptance 0.234). Rounds stop when the particles have travelled on average ``2 d`` squared
        whitened units (the distance between two independent draws; half that with ``economy``) and
        ``moved_fraction`` of them have moved, after at least ``n_moves`` rounds (1 with ``economy``) and
        at most ``max_moves`` (SMC) / ``max_virtual`` (SEMC). Above d = 10 the evidence's importance
        density uses the fitted Gaussian in place of the kernel density. ``None`` (default): on when
        d > 10 or with ``economy``, so that runs with up to 10 parameters are unchanged.
        ``proposal_scale``, ``step_size`` and ``target_acceptance`` do not apply to these moves.
    economy : bool
        Fewer likelihood calls for expensive models (docs/core.md, "Economy of likelihood calls"): the
        scaled moves (whatever d), stopped at half the travel and 70 % moved (or ``moved_fraction`` if
        lower), plus one more move at the last stage of a tempered step; no restart from the restricted
        prior while at least d + 1 particles have a non-zero likelihood (the restart's rejection sampling
        costs N / (valid fraction) calls); the importance density refitted once to the particles after
        ``n_independent`` independence sweeps, and the evidence estimated from all the sweeps' draws
        after that refit, sweeping on until the increment's standard error is below 0.02 nats (at most
        ``n_independent + 2 max_refits`` sweeps).
    """

    move: str
    n_samples: int = 1000
    tempering: bool = True
    tempering_ess: float = 0.5
    tempering_threshold: float = 0.1
    max_stages: int = 1000
    ess_threshold: float = 0.5
    resampling: str = "systematic"
    predictive: str = "auto"
    shrink_static: bool = True
    target_acceptance: float = 0.25
    step_size: float = 2.0
    max_virtual: int = 30
    virtual_tolerance: float = 0.1
    n_moves: int = 3
    proposal_scale: float = 1.0
    transform: bool = True
    min_valid_fraction: float = 0.5
    evidence: str = "importance"
    moved_fraction: float = 0.9
    max_moves: int = 30
    move_every_stage: bool | None = None
    n_independent: int = 3
    min_evidence_ess: float = 0.3
    max_refits: int = 5
    n_inner: int = 100
    conflict_threshold: float = 4.0
    conflict_remedy: bool = True
    remedy_ess: float = 0.05
    remedy_lag: int = 10
    remedy_bridge: bool = True
    pseudo_marginal_from: int = 2048
    scaled_moves: bool | None = None
    economy: bool = False

    def __post_init__(self):
        if self.move not in ("stretch", "gaussian"):
            raise ValueError(f"move: expected 'stretch' or 'gaussian', got {self.move!r}")
        if int(self.n_samples) != self.n_samples or self.n_samples < 2:
            raise ValueError(f"n_samples: must be an integer >= 2, got {self.n_samples}")
        if self.evidence not in ("importance", "path"):
            raise ValueError(f"evidence: expected 'importance' or 'path', got {self.evidence!r}")
        if not 0.0 <= self.min_valid_fraction <= 1.0:
            raise ValueError(f"min_valid_fraction: must lie in [0, 1], got {self.min_valid_fraction}")
        if not 0.0 < self.tempering_threshold <= self.tempering_ess:
            raise ValueError(f"tempering_threshold: must lie in (0, tempering_ess], got {self.tempering_threshold}")
        for name in ("tempering_ess", "ess_threshold"):
            value = getattr(self, name)
            if not 0.0 < value <= 1.0:
                raise ValueError(f"{name}: must lie in (0, 1], got {value}")
        if self.resampling not in SCHEMES:
            raise ValueError(f"resampling: unknown scheme {self.resampling!r}; choose from {sorted(SCHEMES)}")
        if self.predictive not in PREDICTIVE_METHODS:
            raise ValueError(f"predictive: expected one of {PREDICTIVE_METHODS}, got {self.predictive!r}")
        if not 0.0 < self.target_acceptance <= 1.0:
            raise ValueError(f"target_acceptance: must lie in (0, 1], got {self.target_acceptance}")
        if not self.step_size > 1.0:
            raise ValueError(f"step_size: must be > 1, got {self.step_size}")
        if int(self.max_stages) != self.max_stages or self.max_stages < 1:
            raise ValueError(f"max_stages: must be an integer >= 1, got {self.max_stages}")
        if self.max_virtual < 1 or self.n_moves < 1 or self.max_moves < 1:
            raise ValueError("max_virtual, max_moves and n_moves: must be >= 1")
        if self.move == "gaussian" and self.n_moves > self.max_moves:
            raise ValueError(f"n_moves: {self.n_moves} exceeds max_moves {self.max_moves}")
        if not 0.0 <= self.min_evidence_ess <= 1.0 or self.max_refits < 0:
            raise ValueError("min_evidence_ess must lie in [0, 1] and max_refits be >= 0")
        if self.n_independent < 1:
            raise ValueError(f"n_independent: must be >= 1, got {self.n_independent}")
        if not 0.0 <= self.moved_fraction <= 1.0:
            raise ValueError(f"moved_fraction: must lie in [0, 1], got {self.moved_fraction}")
        if self.move == "stretch" and self.n_moves > self.max_virtual:
            raise ValueError(f"n_moves: {self.n_moves} exceeds max_virtual {self.max_virtual}")
        if not self.proposal_scale > 0:
            raise ValueError(f"proposal_scale: must be positive, got {self.proposal_scale}")
        if not self.conflict_threshold > 0:
            raise ValueError(f"conflict_threshold: must be positive, got {self.conflict_threshold}")
        if not 0.0 <= self.remedy_ess <= 1.0:
            raise ValueError(f"remedy_ess: must lie in [0, 1], got {self.remedy_ess}")
        if isinstance(self.remedy_lag, bool) or int(self.remedy_lag) != self.remedy_lag or self.remedy_lag < 2:
            raise ValueError(f"remedy_lag: must be an integer >= 2, got {self.remedy_lag}")
        if self.remedy_bridge not in (True, False):
            raise ValueError(f"remedy_bridge: expected True or False, got {self.remedy_bridge!r}")
        if isinstance(self.n_inner, bool) or int(self.n_inner) != self.n_inner or self.n_inner < 1:
            raise ValueError(f"n_inner: must be an integer >= 1, got {self.n_inner}")
        if (isinstance(self.pseudo_marginal_from, bool) or int(self.pseudo_marginal_from) != self.pseudo_marginal_from
                or self.pseudo_marginal_from < 0):
            raise ValueError(f"pseudo_marginal_from: must be an integer >= 0, got {self.pseudo_marginal_from}")
        if self.scaled_moves not in (None, True, False):
            raise ValueError(f"scaled_moves: expected True, False or None, got {self.scaled_moves!r}")
        if self.economy not in (True, False):
            raise ValueError(f"economy: expected True or False, got {self.economy!r}")

    def uses_scaled_moves(self, dim: int) -> bool:
        """Whether the moves of :mod:`seqbayes.moves.scaled` run for ``dim`` parameters (see ``scaled_moves``)."""
        if self.scaled_moves is not None:
            return bool(self.scaled_moves)
        return self.economy or dim > HIGH_DIMENSION


@dataclass(frozen=True, eq=False)
class SamplerState:
    """Everything needed to assimilate the next dataset.

    Attributes
    ----------
    step : int
        Datasets assimilated so far.
    particles : (N, d) array
        Draws of the current prior (the predictive distribution for ``s > 1``).
    log_weights : (N,) array
        Their normalised log-weights.
    prior : object with ``logpdf``
        The current prior density: the initial prior, then a :class:`~seqbayes.density.GaussianMixture`
        or, for static parameters, a :class:`~seqbayes.density.HistoryPrior`.
    log_evidence : float
        Cumulative log-evidence.
    step_size : float
        Current stretch step size (SEMC).
    posterior, posterior_log_weights : arrays or None
        The last step's posterior (for forecasts).
    log_prior : (N,) array or None
        ``prior.logpdf(particles)`` when known (a :class:`~seqbayes.density.HistoryPrior` at
        the last posterior: its target values, so the past datasets are not re-evaluated).
    window : tuple of PastStep
        The last ``remedy_lag`` steps (datasets, priors, posteriors) for the conflict remedy.
    paths : (N, L, d) array or None
        After a path-space step: the paths over the last ``L`` steps of the posterior particles
        (``paths[:, -1]`` is ``posterior``); ``None`` until the remedy first runs.
    log_evidence_variance : float
        Estimated variance of ``log_evidence`` (:func:`~seqbayes.evidence.step_standard_errors`).
    lineage : (N, 2) int array or None
        Labels of the last two posteriors' particles, for the evidence's standard error
        (:func:`~seqbayes.evidence.step_standard_errors`): column 0 of ``posterior``'s, the index of the
        step's initial draw each particle descends from (the predictive draw, restart draw or path-space
        walker; resampling copies it, moves keep it), column 1 the previous posterior's (the components of
        ``previous_prior``). ``None`` (before the first step, a state from an older run store) counts every
        particle as its own.
    previous_prior : GaussianMixture or None
        The mixture prior the last step used (components: the previous posterior's particles), for the
        part of the next increment's standard error that comes from it
        (:meth:`~seqbayes.density.GaussianMixture.backward_spread`); ``None`` for any other prior.
    """

    step: int
    particles: np.ndarray
    log_weights: np.ndarray
    prior: object
    log_evidence: float
    step_size: float
    posterior: np.ndarray | None = None
    posterior_log_weights: np.ndarray | None = None
    log_prior: np.ndarray | None = None
    window: tuple = ()
    paths: np.ndarray | None = None
    log_evidence_variance: float = 0.0
    lineage: np.ndarray | None = None
    previous_prior: object = None

    @property
    def prior_draws(self) -> np.ndarray:
        """Draws of the next step's prior: the particles themselves."""
        return self.particles


@dataclass(frozen=True, eq=False)
class Problem:
    """The model: initial prior, Markov kernel, likelihood and parameter space."""

    prior: object
    kernel: MarkovKernel
    loglike: object
    support: np.ndarray
    executor: object = None
    n_chunks: int | None = None
    history: object = None
    inner_filter: object = None

    def __post_init__(self):
        bounded = bool(np.isfinite(self.support).any())  # else the move transform is the identity
        object.__setattr__(self, "bounded", bounded)
        object.__setattr__(self, "transform", BoxTransform(self.support) if bounded else None)


def _check_dataset(dataset, step):
    if dataset is None:
        raise ValueError(f"dataset: step {step} got None")
    size = getattr(dataset, "size", None)
    if size is not None and np.ndim(size) == 0 and size == 0:
        raise ValueError(f"dataset: step {step} got an empty array")
    if hasattr(dataset, "__len__") and not isinstance(dataset, (str, bytes)) and len(dataset) == 0:
        raise ValueError(f"dataset: step {step} got an empty dataset")


def _mutate(problem, config, state_step_size, walkers, components, beta, prior_logpdf, rng, loglike):
    """The sampler's MCMC move at one tempering stage, targeting ``L^beta p_s`` (``loglike`` is ``log L``).

    With ``config.transform`` the move works in unconstrained coordinates
    (:class:`~seqbayes.transforms.BoxTransform`, with the log-Jacobian as a third
    target component); walkers that do not move keep their exact coordinates.
    Returns walkers, components, stats, step size and virtual-iteration count.
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
            inside = _inside(theta, problem.support)  # round-off can land on a bound
            out = np.full((points.shape[0], 3), -np.inf)
            out[inside] = np.column_stack([loglike(theta[inside]), prior_logpdf(theta[inside]),
                                           transform.log_jacobian(points[inside])])
            return out

    start = position

    def enough(n_done):  # every particle should have had a fair chance to move (cf. PyMC's SMC)
        if n_done < config.n_moves:
            return False
        return config.moved_fraction == 0 or np.mean(np.any(position != start, axis=1)) >= config.moved_fraction

    if config.uses_scaled_moves(walkers.shape[1]):
        position, components, stats, n_virtual = _scaled_moves(config, position, components, component_fn,
                                                               coefficients, support, rng)
        step_size = state_step_size if config.move == "stretch" else float("nan")
    elif config.move == "gaussian":
        stats = SweepStats()
        n_done = 0
        while not enough(n_done) and n_done < config.max_moves:
            move = GaussianMove(weighted_covariance(position), config.proposal_scale)
            position, components, sweep = gaussian_sweep(position, components, component_fn, coefficients, move,
                                                         rng, support)
            stats = stats + sweep
            n_done += 1
        step_size, n_virtual = float("nan"), 0
    else:  # SEMC: Algorithm 2 lines 9-21, continuing the ensemble through the virtual iterations
        step_size = state_step_size
        alpha_old = config.target_acceptance
        stats = SweepStats()
        n_virtual = 0
        while True:
            position, components, sweep = stretch_sweep(position, components, component_fn, coefficients,
                                                        StretchMove(step_size), rng, support)
            n_virtual += 1
            stats = stats + sweep
            alpha = sweep.acceptance_rate
            step_size = next_step_size(step_size, alpha, config.target_acceptance)  # Eq. (9)
            converged = abs(alpha - alpha_old) < config.virtual_tolerance * config.target_acceptance
            if (converged and enough(n_virtual)) or n_virtual >= config.max_virtual:
                break
            alpha_old = alpha
    if transform is not None:
        moved = np.any(position != start, axis=1)
        walkers = walkers.copy()
        walkers[moved] = transform.inverse(position[moved])
        components = components[:, :2]
    else:
        walkers = position
    return walkers, components, stats, step_size, n_virtual


def _scaled_moves(config, position, components, component_fn, coefficients, support, rng):
    """The moves of :mod:`seqbayes.moves.scaled` at one stage (``SamplerConfig.scaled_moves``).

    Parameters
    ----------
    position : (N, d) array
        The particles (in the move's coordinates); ``components (N, k)`` their log-target components,
        ``component_fn``, ``coefficients`` and ``support`` as in :func:`~seqbayes.moves.stretch_sweep`.

    Each round is an independence-MH sweep from a density fitted to ``position`` once, before the
    stage's moves (``N(mean, cov)`` above ``HIGH_DIMENSION``, the evidence's
    :class:`~seqbayes.evidence.DefensiveProposal` up to it), then a local sweep: SMC's random walk with
    ``2.38 / sqrt(d)`` times the covariance factor, or SEMC's differential-evolution move, each with a
    factor that follows Eq. (9) towards ``LOCAL_ACCEPTANCE`` from 1 at the stage's start. Rounds stop once
    the mean over particles of their accumulated squared whitened travel reaches ``JUMP_TARGET * 2 d``
    (``ECONOMY_JUMP_TARGET`` with ``economy``) and ``moved_fraction`` of them have moved
    (``ECONOMY_MOVED_FRACTION`` at most, with ``economy``), after at least ``n_moves`` rounds (1 with
    ``economy``) and at most ``max_moves`` (SMC) or ``max_virtual`` (SEMC).

    Returns
    -------
    position, components : arrays after the moves
    stats : SweepStats
        Of every sweep (independence and local).
    n_rounds : int
    """
    n, d = position.shape
    fitted = FittedGaussian(np.full(n, 1.0 / n) @ position, weighted_covariance(position))
    # the global proposal: up to d = 10 the importance density (kernel density + t), which follows a funnel
    globally = fitted if d > HIGH_DIMENSION else DefensiveProposal(position, np.zeros(n))
    target = (ECONOMY_JUMP_TARGET if config.economy else JUMP_TARGET) * 2.0 * d
    min_rounds = 1 if config.economy else config.n_moves
    max_rounds = config.max_moves if config.move == "gaussian" else config.max_virtual
    moved_fraction = min(config.moved_fraction, ECONOMY_MOVED_FRACTION) if config.economy else config.moved_fraction
    scale, stats, travelled, n_rounds = 1.0, SweepStats(), np.zeros(n), 0
    while n_rounds < max_rounds:
        before = position
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


class _Counter:
    """Evaluates the user's likelihood with validation, counting calls and NaNs."""

    def __init__(self, problem, dataset, step):
        self.problem, self.dataset, self.step = problem, dataset, step
        self.n_evals = 0
        self.n_nan = 0

    def loglike(self, theta):
        return self.loglike_on(theta, self.dataset)

    def loglike_on(self, theta, dataset):
        """The log-likelihood of any dataset (past ones for :class:`~seqbayes.density.HistoryPrior`)."""
        values = evaluate_loglike(self.problem.loglike, theta, dataset, self.problem.executor,
                                  self.problem.n_chunks)
        return self._checked(values, theta, "loglike")

    def summary_loglike(self, theta, summary):
        """``log prod_k L_k(theta)`` over past datasets from their summed statistics (one call; see
        :class:`~seqbayes.density.RunningStatistics`), counted as one evaluation per row."""
        return self._checked(np.asarray(self.problem.history.loglike(theta, summary), dtype=float), theta,
                             "history.loglike")

    def _checked(self, values, theta, name):
        """``values (N,)`` of the user's function ``name`` at ``theta``, counted; +inf is an error, NaN -inf."""
        if values.shape != (theta.shape[0],):
            raise ValueError(f"{name}: returned shape {values.shape} for theta of shape {theta.shape}; "
                             f"expected ({theta.shape[0]},)")
        self.n_evals += theta.shape[0]
        if (values < np.inf).all():  # the usual case: no NaN, no +inf
            return values
        if np.isposinf(values).any():
            raise ValueError(f"{name}: returned +inf at step {self.step}")
        nan = np.isnan(values)
        self.n_nan += int(nan.sum())
        return np.where(nan, -np.inf, values)


def resolve_predictive(method: str, kernel: MarkovKernel) -> str:
    """The predictive construction to use: ``"auto"`` is ``"history"`` for a static kernel, ``"smc2"`` for
    one with both static and drifting components, else ``"transition"`` (always for a kernel with jumps)."""
    if kernel.has_jumps and method in ("auto", "smc2"):  # SMC^2's inner filters assume a Gaussian transition
        if method == "smc2":
            raise ValueError("predictive: 'smc2' does not support Jump components; use 'transition'")
        return "transition"
    if method == "auto":
        return "history" if kernel.is_static else "smc2" if nested_split(kernel) is not None else "transition"
    if method == "smc2" and nested_split(kernel) is None:
        raise ValueError("predictive: 'smc2' needs a kernel of components with both Static and drifting ones")
    if method == "history" and not kernel.is_static:
        raise ValueError("predictive: 'history' (the exact prior p_0 x past likelihoods) needs a kernel whose "
                         "every parameter is Static; with process noise use 'transition' or 'kde'")
    return method


def _prior_logpdf(prior, counter):
    """The step's prior log-density as a function of ``theta (M, d)`` alone."""
    if isinstance(prior, HistoryPrior):
        return lambda theta: prior.logpdf(theta, counter.loglike_on, counter.summary_loglike)
    return prior.logpdf


#: Odd 64-bit multipliers of the row hash in :func:`count_distinct`.
_HASH_MULTIPLIERS = np.random.default_rng(20231).integers(0, 2**63, size=64, dtype=np.uint64) * 2 + 1


def count_distinct(samples) -> int:
    """Number of distinct rows of ``samples (N, d)``, by a 64-bit hash of their bit patterns.

    8x faster than ``np.unique(samples, axis=0)``: rows that differ in one coordinate never
    collide (odd multipliers), others with probability ~``N^2 / 2^65``.
    """
    samples = np.asarray(samples, dtype=float)
    d = samples.shape[1]
    if d > _HASH_MULTIPLIERS.size:
        return int(np.unique(samples, axis=0).shape[0])
    bits = np.ascontiguousarray(samples + 0.0).view(np.uint64)  # + 0.0 maps -0.0 to 0.0
    hashes = bits @ _HASH_MULTIPLIERS[:d]  # wraps modulo 2^64, silently for integer arrays
    hashes.sort()
    return 1 + int(np.count_nonzero(hashes[1:] != hashes[:-1]))


def _prior_name(step: int) -> str:
    """What the particles of ``step`` were drawn from, for error messages."""
    return "prior" if step == 1 else "predictive distribution"


def _inside(points, support) -> np.ndarray:
    if np.isneginf(support[:, 0]).all() and np.isposinf(support[:, 1]).all():
        return np.ones(points.shape[0], dtype=bool)
    return inside_support(points, support)


def step_conflict(prior, prior_log_weights, posterior, posterior_log_weights, support) -> np.ndarray:
    """``StepInfo.prior_data_conflict`` per parameter, ``(d,)``: how many sds of the step's prior the
    posterior mean lies from the prior mean (:func:`seqbayes.results.prior_data_conflict`).

    The step's prior is the predictive restricted to the parameter space (the likelihood is zero
    outside, so that mass is lost, as in the samplers' steps and the exact grid references): its
    moments are those of the prior draws inside ``support`` (all of them when none is inside). A
    predictive that spills over a bound (a drift taking a damping below 0) thus does not count as a
    conflict with the data; on the damped-oscillator study the unrestricted moments fired on run 0
    (T6, 4.05 prior sds at step 6, with no predictive draw inside the box) where the exact shift is
    at most 3.0 (benchmarks/bench_conflict.py --exact).
    """
    inside = _inside(prior, support)
    if inside.any() and not inside.all():
        prior, prior_log_weights = prior[inside], prior_log_weights[inside]
    return prior_data_conflict(prior, prior_log_weights, posterior, posterior_log_weights)


def _restricted_draws(prior, support, n, rng, step, counter, max_rounds=100):
    """``n`` equal-weight draws of ``prior`` restricted to ``{theta in the parameter space, L(theta) > 0}``
    by rejection, their log-likelihoods, the log of the restricted prior mass (the acceptance
    fraction of the rejection sampler), the number of distinct draws found and ``(n,)`` labels
    (:attr:`SamplerState.lineage`): the index of each draw among the distinct ones (copies share it)."""
    kept, kept_ll, n_drawn, n_kept = [], [], 0, 0
    while n_kept < n and n_drawn < max_rounds * n:
        draws = prior.sample(n, rng)
        loglike = np.full(n, -np.inf)
        inside = _inside(draws, support)
        loglike[inside] = counter.loglike(draws[inside])
        ok = np.isfinite(loglike)
        kept.append(draws[ok])
        kept_ll.append(loglike[ok])
        n_drawn, n_kept = n_drawn + n, n_kept + int(ok.sum())
    if n_kept == 0:
        raise ZeroLikelihoodError(
            f"step {step}: every sample has zero likelihood (0 of {n_drawn} draws of the "
            f"{_prior_name(step)} are inside the parameter space with a "
            f"non-zero likelihood); the {_prior_name(step)} is too far "
            f"from the data")
    kept, kept_ll = np.concatenate(kept), np.concatenate(kept_ll)
    labels = np.arange(n)
    if n_kept < n:  # almost no mass: duplicate what there is (the caller is told through n_kept)
        index = rng.integers(n_kept, size=n)
        kept, kept_ll, labels = kept[index], kept_ll[index], index
    return kept[:n], kept_ll[:n], float(np.log(n_kept / n_drawn)), n_kept, labels


@dataclass(frozen=True, eq=False)
class _Cloud:
    """The weighted particles of one step between stages, with their ``(log L, log p_s)`` components and
    their labels: the index of the step's initial draw each descends from (resampling copies it, moves keep it;
    :attr:`SamplerState.lineage`)."""

    particles: np.ndarray
    log_weights: np.ndarray
    components: np.ndarray
    labels: np.ndarray | None = None


@dataclass(frozen=True)
class _Moves:
    """What the moves of one step did: counts, SEMC's step size, virtual iterations."""

    stats: SweepStats = SweepStats()
    step_size: float = float("nan")
    n_virtual: int = 0

    def then(self, stats, step_size, n_virtual, move) -> "_Moves":
        return _Moves(self.stats + stats, step_size if move == "stretch" else self.step_size,
                      self.n_virtual + n_virtual)


def _rejuvenate_deferred(state, problem, config, prior_logpdf, moves, rng):
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
    particles, components, stats, step_size, n_virtual = _mutate(
        problem, config, moves.step_size, particles[index], np.column_stack([np.zeros(n), values[index]]), 0.0,
        prior_logpdf, rng, lambda theta: np.zeros(theta.shape[0]))
    return (particles, np.full(n, -np.log(n)), components[:, 1], moves.then(stats, step_size, n_virtual, config.move),
            True, index)


def _weigh(state, particles, log_weights, log_prior, problem, config, counter, prior_logpdf, rng, labels=None):
    """Stage 1: the likelihood at the prior particles (Eq. A4). When few of them can carry the step
    (predictive mass outside the parameter space, or a zero-likelihood region such as stick-slip)
    the step restarts from the prior restricted to ``{inside, L > 0}``.

    ``labels (N,)``: the particles' labels (the index of the last posterior's particle each is the
    draw of; ``arange(N)`` if omitted), the cloud's unless the step restarts (then the restart draws').

    Returns the cloud, the log of the restricted prior mass (0 without restart) and the number of
    distinct restart draws (N without restart)."""
    n, step = config.n_samples, counter.step
    exact_prior = isinstance(state.prior, HistoryPrior)
    inside = _inside(particles, problem.support)
    if inside.all():
        loglike = counter.loglike(particles)
    else:
        loglike = np.full(n, -np.inf)
        loglike[inside] = counter.loglike(particles[inside])
    valid = np.isfinite(loglike)
    log_restricted_mass, n_found, restarted = 0.0, n, False
    labels = np.arange(n) if labels is None else labels
    if not valid.any() and (inside.all() or exact_prior):
        raise ZeroLikelihoodError(f"step {step}: every sample has zero likelihood; the "
                                  f"{_prior_name(step)} is too far from the data")
    if not exact_prior and not valid.all() and (not inside.all() or valid.sum() < _min_valid(config, particles)):
        particles, loglike, log_restricted_mass, n_found, labels = _restricted_draws(state.prior, problem.support,
                                                                                     n, rng, step, counter)
        log_weights, restarted = np.full(n, -np.log(n)), True
    if log_prior is not None:
        components = np.column_stack([loglike, log_prior])
    else:  # every particle is inside now; the prior is only needed where the likelihood is non-zero
        components = np.column_stack([loglike, np.full(n, -np.inf)])
        carried = np.isfinite(loglike)
        if isinstance(prior_logpdf, SubsampledPrior):  # chooses exact or pseudo-marginal evaluation for the step
            components[:, 1] = prior_logpdf.start(particles, log_weights, loglike, own_draws=not restarted)
        else:
            components[carried, 1] = prior_logpdf(particles[carried])
    return _Cloud(particles, log_weights, components, labels), log_restricted_mass, n_found


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
            f"stages; the dataset lies very far from the {_prior_name(step)}"
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
                                  f"{_prior_name(step)} is too far from the data")
    beta = 1.0 if delta == remaining else beta + delta
    log_weights = log_weights + increment - stage_log_z  # normalised: the carried weights sum to one
    weights = np.exp(log_weights)
    return beta, stage_log_z, log_weights, weights, float(1.0 / np.dot(weights, weights))


def _temper_resample_move(cloud, problem, config, counter, prior_logpdf, moves, move_every_stage, deferred, rng):
    """Stages 2-4: reweight by ``L^delta`` (Eq. A5, one stage or adaptive tempering), resample, move.

    Returns the cloud, the path's log-evidence (Eq. 1), the temperatures, the moves, whether the last
    stage resampled and the last stage's ESS (before resampling)."""
    n, step = config.n_samples, counter.step
    particles, log_weights, components, labels = cloud.particles, cloud.log_weights, cloud.components, cloud.labels
    beta, log_z, temperatures = 0.0, 0.0, []
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
        # economy: a tempered step's last moves are at the posterior itself (the intermediate stages' moves are cut short)
        if resampled or move_every_stage or (config.economy and beta == 1.0 and len(temperatures) > 1):
            if isinstance(prior_logpdf, SubsampledPrior):  # back to exact evaluation if the estimate got poor
                components = prior_logpdf.refreshed(particles, components)
            particles, components, stats, step_size, n_virtual = _mutate(
                problem, config, moves.step_size, particles, components, beta, prior_logpdf, rng, counter.loglike)
            moves = moves.then(stats, step_size, n_virtual, config.move)
    return _Cloud(particles, log_weights, components, labels), log_z, tuple(temperatures), moves, resampled, stage_ess


def _moves_every_stage(config, method) -> bool:
    """``move_every_stage``, where ``None`` (auto) is False for the exact history prior (IBIS's schedule:
    a move re-evaluates every past dataset, so moving only after a resampling, when the ESS has fallen,
    spaces the moves out as the posterior concentrates and bounds the amortised cost per update)."""
    if config.move_every_stage is not None:
        return config.move_every_stage
    return method != "history"


def _evidence(cloud, log_increment_path, n_found, problem, config, counter, prior_logpdf, use_importance, rng,
              other=None):
    """Stage 5: the evidence increment, by defensive importance sampling from the final posterior
    (:mod:`seqbayes.evidence`; its draws drive independence-MH sweeps) or the path's Eq. (1).

    ``other``: another :class:`_Cloud` of the same target. The particles then start from the union of the two,
    each cluster of each given its estimated share of the mass (:func:`~seqbayes.evidence.pooled_start`), and every
    proposal is fitted to the clusters of both (:class:`~seqbayes.evidence.PooledProposal`).

    When no fit reaches ``min_evidence_ess`` the estimates of all the fits are pooled, each weighted by its ESS
    (each is unbiased for ``Z``, its variance ~ ``Z^2 / ESS``):
    the last fit alone, as before, was as poor as any (run 9, T3, SMC seed 7, step 6: six fits with ESS
    73-118 and estimates within 0.27 nats of the exact increment, then one with ESS 10 and 0.71 nats high).

    Returns the cloud after the sweeps, the increment, the importance ESS and the sweeps' accepted moves."""
    n, step = config.n_samples, counter.step
    if not use_importance:
        return cloud, log_increment_path, float("nan"), 0
    n_independent = 0
    scaled = {}  # the defaults' proposal and single-sweep estimate, unchanged up to d = 10
    if config.uses_scaled_moves(cloud.particles.shape[1]):
        scaled["gaussian"] = cloud.particles.shape[1] > HIGH_DIMENSION
        if config.economy:
            scaled.update(se_target=ECONOMY_EVIDENCE_SE, max_sweeps=config.n_independent + 2 * config.max_refits,
                          min_fraction=config.min_evidence_ess)
    # economy: the first n_independent sweeps only move the particles (their fit is to the cut-short moves' cloud;
    # where it was poor, 1 in 5 Coulomb seeds, the posterior means were 0.3-0.45 sd off); q is refitted to the
    # swept particles for the estimate, which costs n_independent N calls and brings those means within 0.15 sd
    if other is not None:
        index, _ = pooled_start([(c.particles, c.log_weights) for c in (cloud, other)], prior_logpdf,
                                counter.loglike, problem.support, rng, scaled.get("gaussian", False))
        labels = None
        if cloud.labels is not None and other.labels is not None:
            labels = np.concatenate([cloud.labels, other.labels + cloud.labels.max() + 1])[index]
        cloud = _Cloud(np.concatenate([cloud.particles, other.particles])[index], np.full(n, -np.log(n)),
                       np.concatenate([cloud.components, other.components])[index], labels)
    also_fit = None if other is None else (other.particles, other.log_weights)  # half of every proposal
    particles, components = cloud.particles, cloud.components
    warm_up = 1 if config.economy else 0
    reliable = max(10.0, 0.01 * n)  # the least ESS of an estimate used on its own (else the path's, below)
    estimates = []
    for attempt in range(warm_up + 1 + config.max_refits):
        # a poor fit (low ESS) still improves the particles through its independence sweeps: refit q to
        # them and estimate again (each q is independent of its own draws, so every estimate is valid)
        log_increment, evidence_ess, particles, components, accepted = importance_step(
            particles, cloud.log_weights, components, prior_logpdf, counter.loglike, problem.support, rng,
            config.n_independent, other=also_fit,
            **(scaled if attempt >= warm_up else {"gaussian": scaled.get("gaussian", False)}))
        n_independent += accepted
        if attempt >= warm_up:
            if evidence_ess >= config.min_evidence_ess * n:
                break
            estimates.append((log_increment, evidence_ess))
    else:
        pooled = [(z, e) for z, e in estimates if np.isfinite(z) and e > 0]
        # only when one fit at least is reliable on its own: six fits of a collapsed posterior with ESS 2 each are
        # not one of ESS 12
        if len(pooled) > 1 and max(e for _, e in pooled) >= reliable:
            log_z, fit_ess = np.array(pooled).T
            total = float(fit_ess.sum())
            log_increment = float(logsumexp(log_z + np.log(fit_ess)) - np.log(total))
            # the N draws' equivalent of the pooled variance 1 / sum ESS - 1 / (K N), as importance_step's economy
            evidence_ess = 1.0 / (1.0 / total - 1.0 / (n * len(pooled)) + 1.0 / n)
    # A collapsed posterior cannot be fitted (tiny ESS), and one rebuilt from fewer than N / 10 restart draws
    # fits a proposal to duplicates whose ESS looks healthy: there, the rejection mass (path) is the estimate.
    if not evidence_ess >= reliable or n_found < 0.1 * n:
        warnings.warn(f"step {step}: importance-sampling evidence unreliable (ESS {evidence_ess:.1f} of {n}, "
                      f"{n_found} distinct restart draws); using the tempering path's estimate and the "
                      f"posterior may be degenerate", RuntimeWarning, stacklevel=4)
        log_increment = log_increment_path
    return _Cloud(particles, cloud.log_weights, components, cloud.labels), log_increment, evidence_ess, n_independent


def _propagate(state, cloud, dataset, log_increment, log_evidence, method, problem, config, rng):
    """Stage 6: the next step's prior (Eq. A2-A3). Returns the density, its particles and their prior
    values (known for the history prior: the particles are the posterior itself)."""
    if method == "joint":
        return None, problem.kernel.propagate(cloud.particles, rng), None
    if method == "history":  # the next prior is this posterior, exactly: keep the particles and their weights
        density = state.prior.extended(dataset, log_evidence) if isinstance(state.prior, HistoryPrior) else \
            HistoryPrior.start(problem.prior, problem.history, dataset, log_evidence)
        next_log_prior = cloud.components[:, 0] + cloud.components[:, 1] - float(log_increment)  # no +inf: no NaN
        return density, cloud.particles, next_log_prior
    density, predictive = predictive_density(cloud.particles, cloud.log_weights, problem.kernel, rng, method,
                                             config.shrink_static)
    return density, predictive, None


@dataclass(frozen=True, eq=False)
class PastStep:
    """One assimilated step, kept for the path-space target of the conflict remedy.

    Attributes
    ----------
    dataset : object
        The step's dataset (a kept copy).
    prior : object with ``logpdf``
        The prior the step used (the initial prior at step 1, else the predictive mixture).
    posterior : (N, d) array
    log_weights : (N,) array
        The step's posterior particles and their normalised log-weights.
    log_evidence_increment : float
        ``log p(D^s | D^{1:s-1})`` as estimated at the step.
    path_space : bool
        Whether the step was assimilated on the path space.
    log_evidence_variance : float
        The cumulative log-evidence's variance before the step (``SamplerState.log_evidence_variance``);
        a bridged step (:func:`assimilate_paths`) estimates the window's evidence afresh from it.
    """

    dataset: object
    prior: object
    posterior: np.ndarray
    log_weights: np.ndarray
    log_evidence_increment: float
    path_space: bool = False
    log_evidence_variance: float = 0.0


def _lineage(state, labels) -> np.ndarray:
    """``(N, 2)`` :attr:`SamplerState.lineage` after a step whose posterior particles descend from the
    initial draws ``labels (N,)``: those, and the labels of the last posterior (distinct without lineage)."""
    labels = np.asarray(labels, dtype=np.intp)
    previous = _posterior_labels(state)
    return np.column_stack([labels, np.arange(labels.shape[0]) if previous is None else previous])


def _posterior_labels(state, column=0):
    """Column ``column`` of ``state``'s lineage (0: the last posterior's labels, 1: the one's before), or
    ``None`` (every particle its own) without lineage of the posterior's size."""
    if state.lineage is None or state.posterior is None or state.lineage.shape[0] != state.posterior.shape[0]:
        return None
    return state.lineage[:, column]


def _mass_spread(state, mass) -> AncestorSpread:
    """The :class:`~seqbayes.density.AncestorSpread` of the last posterior's particles from the mass ``a (N,)``
    that this step's posterior gives them (the exact transition's responsibilities, :func:`_ancestor_mass`)."""
    return AncestorSpread(float(1.0 / np.dot(mass, mass)),
                          grouped_ancestor_variance(mass, np.exp(state.posterior_log_weights), _posterior_labels(state)),
                          mass=mass)


def _ancestor_terms(state, spread):
    """``(variance, covariance)`` of the step's increment error from the ancestors of :func:`step_standard_errors`:
    the last posterior's (``spread``, an :class:`~seqbayes.density.AncestorSpread` or None) and, through the
    mixture the last step used, the posterior's before (:meth:`GaussianMixture.backward_spread`)."""
    if spread is None:
        return float("nan"), 0.0
    variance, covariance = spread.variance, 0.0
    if isinstance(state.previous_prior, GaussianMixture) and state.posterior is not None:
        backward, covariance = state.previous_prior.backward_spread(state.posterior, state.posterior_log_weights,
                                                                    spread, _posterior_labels(state, 1))
        variance += backward
    return variance, covariance


def _remedy_applies(config, method, kernel) -> bool:
    """The path-space remedy needs a transition density in every parameter (no static ones)."""
    return config.conflict_remedy and method in ("transition", "kde") and not kernel.static_mask.any()


#: Most (query, ancestor) pairs of the transition density evaluated at once.
_PAIR_BLOCK = 250_000


def ancestor_draws(kernel, later, earlier, earlier_log_weights, rng=None, later_log_weights=None):
    """Ancestors of ``later`` among the weighted particles ``earlier`` under the exact transition.

    With ``p(theta) = sum_j W_j T(theta | earlier_j)`` (Eq. A3 with the kernel's own density), the
    ancestor of a point ``theta_i`` is ``j`` with probability ``r_ij = W_j T(theta_i | earlier_j) / p(theta_i)``.
    Evaluated in blocks of rows (memory ``O(block x M)``), sampled by the Gumbel-max trick.

    Parameters
    ----------
    kernel : MarkovKernel
        Its ``logpdf(new, old)`` is the transition density.
    later : (N, d) array
    earlier : (M, d) array
    earlier_log_weights : (M,) array
        Normalised log-weights ``log W_j``.
    rng : numpy.random.Generator, optional
        When given, one ancestor index per row of ``later`` is drawn.
    later_log_weights : (N,) array, optional
        When given, the ancestor ESS ``1 / sum_j a_j^2`` with ``a_j = sum_i v_i r_ij`` is returned:
        how many of the earlier particles carry the later (posterior) distribution.

    Returns
    -------
    index : (N,) int array or None
    ancestor_ess : float
        NaN without ``later_log_weights``.
    """
    index, mass = _ancestor_mass(kernel, later, earlier, earlier_log_weights, rng, later_log_weights)
    return index, (float(1.0 / np.dot(mass, mass)) if mass is not None else float("nan"))


def _ancestor_mass(kernel, later, earlier, earlier_log_weights, rng=None, later_log_weights=None):
    """:func:`ancestor_draws` with the mass ``a (M,)`` (None without ``later_log_weights``) in place of its ESS."""
    n, m = later.shape[0], earlier.shape[0]
    block = max(1, _PAIR_BLOCK // m)
    index = np.empty(n, dtype=np.intp) if rng is not None else None
    mass = np.zeros(m) if later_log_weights is not None else None
    for start in range(0, n, block):
        rows = later[start:start + block]
        b = rows.shape[0]
        log_r = kernel.logpdf(np.repeat(rows, m, axis=0), np.tile(earlier, (b, 1))).reshape(b, m)
        log_r += earlier_log_weights[None, :]
        peak = np.max(log_r, axis=1, keepdims=True)
        peak[~np.isfinite(peak)] = 0.0
        if rng is not None:
            index[start:start + b] = np.argmax(log_r + rng.gumbel(size=(b, m)), axis=1)
        if mass is not None:
            r = np.exp(log_r - peak)
            r /= np.maximum(r.sum(axis=1, keepdims=True), 1e-300)
            mass += np.exp(later_log_weights[start:start + b]) @ r
    return index, mass


def _start_paths(state, kernel, length, rng):
    """``(N, length, d)`` paths over the window's steps ending at the posterior particles: the last
    path-space step's paths where kept, extended backwards by drawing ancestors (backward simulation
    with the exact transition) among the window's stored posteriors."""
    window = state.window[-length:]
    n, d = state.posterior.shape
    paths = np.empty((n, length, d))
    known = 0 if state.paths is None else min(length, state.paths.shape[1])
    if known:
        paths[:, length - known:] = state.paths[:, -known:]
    else:
        paths[:, -1] = state.posterior
        known = 1
    for t in range(length - known - 1, -1, -1):
        index, _ = ancestor_draws(kernel, paths[:, t + 1], window[t].posterior, window[t].log_weights, rng)
        paths[:, t] = window[t].posterior[index]
    return paths


@dataclass(frozen=True, eq=False)
class _PathPredictive:
    """Draws of ``(theta_{w:s-1}, theta_s)``: a weighted path, extended by the kernel (for restarts)."""

    paths: np.ndarray
    log_weights: np.ndarray
    kernel: MarkovKernel
    dim: int

    def sample(self, n, rng):
        index = rng.choice(self.paths.shape[0], size=int(n), p=np.exp(self.log_weights - logsumexp(self.log_weights)))
        last = self.paths[index, -self.dim:]
        return np.concatenate([self.paths[index], self.kernel.propagate(last, rng)], axis=1)


class _PathCounter:
    """The step's likelihood counter seen from the path space: ``loglike`` reads the last state."""

    def __init__(self, counter, dim):
        self.counter, self.dim, self.step = counter, dim, counter.step

    def loglike(self, walkers):
        return self.counter.loglike(walkers[:, -self.dim:])


def _add_transitions(out, states, kernel):
    """Add ``sum_{t>=1} log T(theta_t | theta_{t-1})`` along paths ``states (M, T, d)`` to ``out (M,)`` in place,
    for the paths still finite (the rest stay -inf); returns ``out``."""
    for t in range(1, states.shape[1]):
        alive = np.isfinite(out)
        if not alive.any():
            break
        out[alive] += kernel.logpdf(states[alive, t], states[alive, t - 1])
    return out


def _add_loglikes(out, states, datasets, counter):
    """Add ``sum_t log L_t(theta_t)`` (dataset ``t`` at state ``t`` of ``states (M, T, d)``) to ``out (M,)`` in place,
    one likelihood call per dataset for the paths still finite; returns ``out``."""
    for t, dataset in enumerate(datasets):
        alive = np.isfinite(out)
        if not alive.any():
            break
        out[alive] += counter.loglike_on(states[alive, t], dataset)
    return out


def _path_prior(window, kernel, counter, dim):
    """``log p(theta_{w:s-1} | D^{w:s-1}) + log T(theta_s | theta_{s-1})`` for flattened paths ``(M, L d)``.

    The window's first state has the prior its step used (exact from step 1 on), every later one
    the exact transition, every past state its dataset's likelihood; the log of the window's evidence
    ``sum_t log Z_t`` normalises it (the importance-sampling evidence needs a normalised prior)."""
    normaliser = sum(past.log_evidence_increment for past in window)

    def logpdf(walkers):
        states = walkers.reshape(walkers.shape[0], -1, dim)
        out = np.asarray(window[0].prior.logpdf(states[:, 0]), dtype=float) - normaliser
        _add_transitions(out, states, kernel)  # transitions into steps w+1..s
        return _add_loglikes(out, states, [past.dataset for past in window], counter)  # the past datasets'

    return logpdf


@dataclass(frozen=True, eq=False)
class _PathPriorDraws:
    """The window's path prior ``p_w(theta_w) prod_{t=w+1}^{s} T(theta_t | theta_{t-1})`` on flattened paths
    ``(M, (L + 1) d)``: draws (``theta_w`` from ``first``, the rest forward through the kernel) and log-density."""

    first: object
    kernel: MarkovKernel
    n_states: int
    dim: int

    def sample(self, n, rng):
        states = [as_samples(self.first.sample(int(n), rng), self.dim, "prior.sample(n, rng)")]
        for _ in range(1, self.n_states):
            states.append(self.kernel.propagate(states[-1], rng))
        return np.concatenate(states, axis=1)

    def logpdf(self, walkers):
        states = walkers.reshape(walkers.shape[0], self.n_states, self.dim)  # explicit: no draw may be inside
        return _add_transitions(np.asarray(self.first.logpdf(states[:, 0]), dtype=float).copy(), states, self.kernel)


class _WindowCounter:
    """The likelihood of every dataset of the window and the new one on flattened paths:
    ``sum_{t=w}^{s} log L_t(theta_t)`` (one call per state; a path with one zero likelihood stops there)."""

    def __init__(self, counter, datasets, dim):
        self.counter, self.datasets, self.dim, self.step = counter, tuple(datasets), dim, counter.step

    def loglike(self, walkers):
        states = walkers.reshape(walkers.shape[0], len(self.datasets), self.dim)  # explicit: may have no rows
        return _add_loglikes(np.zeros(walkers.shape[0]), states, self.datasets, self.counter)


def _bridge_from_path_prior(window, dataset, kernel, path_problem, path_config, counter, moves, rng):
    """The window's posterior reached from its path PRIOR by tempering all its likelihoods jointly.

    The path-space target of :func:`assimilate_paths` (``w`` the window's first step, ``s`` this one),

        pi(theta_{w:s}) = p_w(theta_w) prod_{t=w+1}^{s} T(theta_t | theta_{t-1}) prod_{t=w}^{s} L_t(theta_t) / Z_{w:s},
        Z_{w:s} = p(D^{w:s} | D^{1:w-1}) = prod_{t=w}^{s} Z_t,

    is bridged from the path prior ``pi_0 = p_w prod T`` (sampled forward: ``theta_w ~ p_w``, then the
    kernel; restricted to the parameter space by rejection, whose acceptance fraction ``m`` enters the
    evidence as in :func:`_restricted_draws`) through

        pi_beta prop. to pi_0(theta_{w:s}) [prod_{t=w}^{s} L_t(theta_t)]^beta,   0 = beta_0 < ... < beta_K = 1,

    with the sampler's own reweight-resample-move stages (Eq. A5, the moves on the whole path). Every
    choice of which dataset a path gives up is weighed afresh, not inherited from the previous steps'
    particles, so a mode of ``pi`` whose earlier states the earlier data had ruled out given the stored
    paths is reached. The stages' product of mean weights (Eq. 1) estimates ``log Z_{w:s} = log m +
    sum_k log mean_i w_i^(k)``; the step's increment is that minus the window's stored increments
    ``sum_{t=w}^{s-1} log Z_t`` (the normaliser of :func:`_path_prior`), so the cumulative evidence
    becomes the window's own estimate.

    Returns
    -------
    cloud : _Cloud
        Equal-weight (or weighted) paths ``(N, (L + 1) d)`` of ``pi``, with the components of the stored
        paths' start, ``(log L_s, log pi_0 + sum_{t<s} log L_t - sum_{t=w}^{s-1} log Z_t)``.
    log_increment : float
        The step's increment by the tempering path, ``log Z_{w:s}`` (with the restricted mass) minus the
        window's stored increments.
    temperatures, moves, resampled, stage_ess, n_found
        As :func:`_temper_resample_move`; ``n_found`` distinct draws of the restricted path prior.
    """
    d, n = kernel.dim, path_config.n_samples
    # every stage keeps tempering_ess of the ESS: no shortcut to beta = 1 at a mere tempering_threshold (10 %) of N,
    # which a cloud gathered in a narrow minor mode of an early stage passes (run 9, T6, the study's SMC seed, step 4:
    # from beta = 0.05 to 1 in one stage, 24 exact sds and 44 nats off)
    path_config = replace(path_config, tempering_threshold=path_config.tempering_ess)
    path_prior = _PathPriorDraws(window[0].prior, kernel, len(window) + 1, d)
    window_counter = _WindowCounter(counter, [past.dataset for past in window] + [dataset], d)
    walkers, loglike, log_restricted_mass, n_found, labels = _restricted_draws(
        path_prior, path_problem.support, n, rng, counter.step, window_counter)
    components = np.column_stack([loglike, path_prior.logpdf(walkers)])
    cloud = _Cloud(walkers, np.full(n, -np.log(n)), components, labels)  # labels: the path-prior draws
    cloud, log_z, temperatures, moves, resampled, stage_ess = _temper_resample_move(
        cloud, path_problem, path_config, window_counter, path_prior.logpdf, moves, True, False, rng)
    # back to the decomposition of the stored paths' start, (log L_s, log of the normalised path prior of
    # assimilate_paths), for the importance estimate of the increment: log L_s costs N calls, the rest is a difference
    last = _PathCounter(counter, d).loglike(cloud.particles)
    normaliser = sum(past.log_evidence_increment for past in window)
    cloud = _Cloud(cloud.particles, cloud.log_weights,
                   np.column_stack([last, cloud.components[:, 1] + (cloud.components[:, 0] - last) - normaliser]),
                   cloud.labels)
    return cloud, log_z + log_restricted_mass - normaliser, temperatures, moves, resampled, stage_ess, n_found


def _paths_from_previous(state, dataset, kernel, path_problem, path_counter, prior_logpdf, config, rng):
    """The regular path-space start: the previous posterior's paths (:func:`_start_paths`) extended by
    ``theta_s ~ T(. | theta_{s-1})`` and weighed by ``L_s``; as :func:`_weigh`, a restart from the path
    predictive restricted to ``{inside, L > 0}`` when few of them can carry the step.

    Returns the cloud (components ``(log L_s, log path prior)``), its log-weights before the step, the log
    of the restricted mass (0 without restart) and the number of distinct restart draws (N without)."""
    d, n = kernel.dim, config.n_samples
    length = path_problem.support.shape[0] // d - 1
    paths = _start_paths(state, kernel, length, rng)
    walkers = np.concatenate([paths, kernel.propagate(paths[:, -1], rng)[:, None]], axis=1).reshape(
        paths.shape[0], -1)
    log_weights, log_restricted_mass, n_found, labels = state.posterior_log_weights, 0.0, n, np.arange(n)
    loglike = np.full(n, -np.inf)
    inside = _inside(walkers, path_problem.support)
    loglike[inside] = path_counter.loglike(walkers[inside])
    valid = np.isfinite(loglike)
    if not valid.all() and (not inside.all() or valid.sum() < config.min_valid_fraction * n):
        # as _weigh: restart from the path predictive restricted to {inside, L > 0}, its mass in the evidence
        extended = _PathPredictive(paths.reshape(n, -1), log_weights, kernel, d)
        walkers, loglike, log_restricted_mass, n_found, labels = _restricted_draws(
            extended, path_problem.support, n, rng, path_counter.step, path_counter)
        log_weights = np.full(n, -np.log(n))
    components = np.column_stack([loglike, np.full(n, -np.inf)])
    carried = np.isfinite(loglike)
    components[carried, 1] = prior_logpdf(walkers[carried])
    return _Cloud(walkers, log_weights, components, labels), log_weights, log_restricted_mass, n_found


def _stored_paths_start(state, dataset, kernel, path_problem, path_counter, prior_logpdf, config, path_config, moves,
                        rng):
    """The path-space step from the stored paths (:func:`_paths_from_previous`) tempered in ``L_s``
    (:func:`_temper_resample_move`). Returns the cloud, the increment by the tempering path (with the restart's
    restricted mass), the temperatures, moves, whether the last stage resampled, its ESS, the number of distinct
    restart draws and the log-weights before the step."""
    cloud, log_weights, log_restricted_mass, n_found = _paths_from_previous(state, dataset, kernel, path_problem,
                                                                            path_counter, prior_logpdf, config, rng)
    cloud, log_z, temperatures, moves, resampled, stage_ess = _temper_resample_move(
        cloud, path_problem, path_config, path_counter, prior_logpdf, moves, True, False, rng)
    return cloud, log_z + log_restricted_mass, temperatures, moves, resampled, stage_ess, n_found, log_weights


def _variance_before(state) -> float:
    """:attr:`PastStep.log_evidence_variance` of the step after ``state``: its cumulative variance, as the square of
    the se the last record reports, which is what a restored run rebuilds it from (:mod:`seqbayes.snapshot`), so that
    resumed runs stay bit-identical."""
    return float(np.sqrt(state.log_evidence_variance)) ** 2


def _bridged_standard_errors(state, window, cloud, n, evidence_ess, d):
    """``(increment_se, cumulative_se, cumulative_variance)`` of a bridged step (:func:`_bridge_from_path_prior`).

    Its cumulative log-evidence is ``log Z_hat_{1:w-1} + log Z_hat_{w:s}``: the window's evidence is estimated
    afresh (the importance estimate on the path space, variance ``1 / ESS - 1 / N``) from the window's first
    prior ``p_w``, so the cumulative variance continues from the one before step ``w``, not from step ``s - 1``'s
    (the stored increments of the window cancel). ``p_w`` is the initial prior when the window reaches step 1,
    else the mixture over step ``w - 1``'s particles, whose error is the spread of the paths' first states over
    its components (:meth:`GaussianMixture.ancestor_spread`, each particle its own label). The increment,
    ``log Z_hat_{w:s}`` minus the window's stored increments, adds their accumulated variance.
    Before this the ordinary step's formula was used, with the ancestor ESS of the conflict (1-4 of N): 0.6-0.76
    nats reported on run 9 (T3) where the increments' errors were 0.01-0.11."""
    variance = 1.0 / evidence_ess - 1.0 / n if np.isfinite(evidence_ess) and evidence_ess > 0 else float("nan")
    first = window[0]
    if isinstance(first.prior, GaussianMixture):
        variance += first.prior.ancestor_spread(cloud.particles[:, :d], cloud.log_weights, None).variance
    cumulative = first.log_evidence_variance + variance
    increment = variance + max(state.log_evidence_variance - first.log_evidence_variance, 0.0)
    return float(np.sqrt(increment)), float(np.sqrt(cumulative)), float(cumulative)


def assimilate_paths(state: SamplerState, dataset, problem: Problem, config: SamplerConfig, rng, counter,
                     method: str, start: float, bridge: bool = False) -> tuple[SamplerState, StepRecord, _Cloud]:
    """The exact remedy for prior-data conflict: assimilate ``dataset`` on the path space.

    The predictive mixture ``sum_j W_j T(theta | theta_j)`` is exact only where the previous
    posterior's particles are: a posterior that lies several predictive sds out is made of that
    posterior's far tail, which N particles do not hold (on run 9 of the oscillator study the
    mixture's own posterior of ``k`` at step 3 is 2.7 exact sds low at N = 1000 and 1.4 at 16000).
    Here the target is the joint posterior of the last ``L`` states (Eq. A2-A3 unrolled),

        p(theta_{w:s} | D^{1:s}) prop. to p_w(theta_w) prod_{t=w}^{s} L_t(theta_t) prod_{t=w+1}^{s} T(theta_t | theta_{t-1}),

    whose marginal in ``theta_s`` is the model's exact posterior (``p_w`` is the initial prior when
    the window reaches step 1). With ``bridge`` (``SamplerConfig.remedy_bridge``, the default) the
    particles are drawn from the path prior ``p_w prod T`` and every likelihood of the window is
    tempered jointly (:func:`_bridge_from_path_prior`), so that every mode of the path posterior is
    weighed afresh; the stored paths' start below (or, where it cannot carry the step, a second bridge)
    runs as well, and the two clouds are pooled, each cluster given its importance-sampling share of the
    mass, before the importance sweeps (:func:`_evidence`), because a tempering can weigh a mode wrongly
    once the modes have separated (lose it, or end trapped in a minor one). Without it they start from the
    previous posterior's paths (kept from the last path-space step, or drawn backwards with the exact
    transition), are extended by
    ``theta_s ~ T(. | theta_{s-1})`` and tempered in ``L_s`` (Eq. A5) only. Either way they are moved
    by the sampler's own MCMC move on the whole path, which carries the earlier states into the tails
    the data call for. The evidence increment is Eq. (1) or the importance estimate of
    :mod:`seqbayes.evidence` on the path space; the cost of a move is one likelihood call per state of
    the window.

    Returns the new state (with the paths), the record (``StepInfo.path_steps = L``) and the cloud.
    """
    step = state.step + 1
    kernel, d = problem.kernel, problem.kernel.dim
    length = min(len(state.window), config.remedy_lag - 1)
    window = state.window[-length:]
    path_problem = Problem(problem.prior, kernel, problem.loglike, np.tile(problem.support, (length + 1, 1)),
                           problem.executor, problem.n_chunks)
    path_counter = _PathCounter(counter, d)
    prior_logpdf = _path_prior(window, kernel, counter, d)
    n = config.n_samples
    moves = _Moves(step_size=state.step_size)
    # L + 1 times as many dimensions: SMC's random-walk scale goes as 1 / sqrt(dim) (Roberts, Gelman & Gilks
    # 1997), so gamma for d dimensions becomes gamma / sqrt(L + 1), and a path decorrelates in O(dim) moves: at
    # least 2 (L + 1) per stage. benchmarks/bench_abrupt.py, 10 seeds, worst mean error over the steps of run 9
    # (T2) / the abrupt drop, SEMC and SMC: 0.44, 0.35 / 0.25, 0.36 exact sds with L + 1 moves, 0.22, 0.17 /
    # 0.31, 0.26 with 2 (L + 1), at twice the cost of a path-space step. SEMC's stretch move mixes more slowly
    # in the 2 (L + 1) path dimensions (its autocorrelation grows with the dimension): with 2 (L + 1) sweeps its
    # mean of k at the abrupt drop's step 5 was biased by +0.09 +- 0.02 exact sds over 20 seeds (worst 0.31), with
    # 4 (L + 1) by +0.05 +- 0.02 (bench_abrupt.py --per-seed; SMC's moves keep 2 (L + 1))
    # The bridge from the path prior (remedy_bridge) makes 4 (L + 1) moves per stage with either sampler: its first
    # stages hold the whole prior's spread along the window's likelihood ridges, where SMC's random walk at
    # gamma / sqrt(L + 1) with 2 (L + 1) moves let the paths collapse (run 9, T4, sampler seed 0, step 5: importance
    # ESS 7 of 1000, 1.75 exact sds and 35 nats off; with 4 (L + 1): 0.03 sds, 0.01 nats)
    per_state = 4 if config.move == "stretch" or bridge else 2
    # the moves' kind follows the model's d, not the path's (L + 1) d (SamplerConfig.scaled_moves)
    config = replace(config, scaled_moves=config.uses_scaled_moves(d))
    path_config = replace(config, proposal_scale=config.proposal_scale / np.sqrt(length + 1),
                          n_moves=max(config.n_moves, min(config.max_moves, config.max_virtual,
                                                          per_state * (length + 1))))
    if bridge:
        cloud, log_z, temperatures, moves, resampled, stage_ess, n_found = _bridge_from_path_prior(
            window, dataset, kernel, path_problem, path_config, counter, moves, rng)
        # a second cloud of the same target, which _evidence pools with the bridge's (each given its share of the mass,
        # then independence sweeps with a proposal fitted to both): the stored paths' start (the branch below) holds
        # the modes the previous particles held, which the bridge's tempering can lose (run 9, T3, step 5: a 5 % mode
        # with k_5 ~ 0.87, where the bridge put 0.04 % of its weight and sat 0.26 exact sds off at every seed); where
        # the stored paths cannot carry the step (T6: the drift takes every extended path out of the box), a second
        # bridge, as a bridge's tempering can also end trapped in a minor mode (run 9, T6, step 6: 6.3 sds, 89 nats)
        try:
            other, _, _, moves, *_ = _stored_paths_start(state, dataset, kernel, path_problem, path_counter,
                                                         prior_logpdf, config, path_config, moves, rng)
        except (ZeroLikelihoodError, TemperingLimitError):
            other, _, _, moves, _, _, _ = _bridge_from_path_prior(window, dataset, kernel, path_problem, path_config,
                                                                  counter, moves, rng)
    else:
        cloud, log_z, temperatures, moves, resampled, stage_ess, n_found, log_weights = _stored_paths_start(
            state, dataset, kernel, path_problem, path_counter, prior_logpdf, config, path_config, moves, rng)
        other = None
    # at least 2 (L + 1) independence sweeps per fit, as the moves: with 3, run 9 under T5 ended step 6 0.3-0.5 exact
    # sds off in c at every seed, from a start within 0.02 sds (the sweeps' transient through the path's earlier
    # states); with 10 (= 2 (L + 1) there), within 0.03 at seeds 1, 2, 4 (SMC, SEMC, SMC)
    evidence_config = replace(config, n_independent=max(config.n_independent, 2 * (length + 1)))
    cloud, log_increment, evidence_ess, n_independent = _evidence(
        cloud, log_z, n_found, path_problem, evidence_config, path_counter, prior_logpdf,
        config.evidence == "importance", rng, other)
    log_evidence = float(state.log_evidence + log_increment)
    posterior = cloud.particles[:, -d:]
    marginal = _Cloud(posterior, cloud.log_weights, cloud.components)
    density, predictive, _ = _propagate(state, marginal, dataset, log_increment, log_evidence, method, problem,
                                        config, rng)
    conflict = step_conflict(state.particles, state.log_weights, posterior, cloud.log_weights, problem.support)
    _, mass = _ancestor_mass(kernel, posterior, state.posterior, state.posterior_log_weights,
                             later_log_weights=cloud.log_weights)
    spread = _mass_spread(state, mass)
    ancestors = spread.ess
    importance = config.evidence == "importance" and log_increment != log_z
    if bridge:
        increment_se, evidence_se, evidence_variance = _bridged_standard_errors(
            state, window, cloud, n, evidence_ess if importance else float("nan"), d)
    else:
        ancestor_variance, covariance = _ancestor_terms(state, spread)
        increment_se, evidence_se, evidence_variance = step_standard_errors(
            state.log_evidence_variance, n, importance, evidence_ess, np.exp(log_weights), cloud.log_weights,
            len(temperatures), resampled, ancestor_variance, method, covariance)
    step_size = moves.step_size if config.move == "stretch" else float("nan")
    info = StepInfo(
        step=step, log_evidence_increment=float(log_increment), log_evidence=log_evidence, ess=float(stage_ess),
        resampled=bool(resampled), acceptance_rate=moves.stats.acceptance_rate, step_size=float(step_size),
        n_virtual=moves.n_virtual, n_stages=len(temperatures), temperatures=temperatures,
        n_loglike_evals=counter.n_evals, n_nan=counter.n_nan, n_distinct=count_distinct(posterior),
        n_proposed=moves.stats.n_proposed, n_accepted=moves.stats.n_accepted,
        n_identical_partner=moves.stats.n_identical_partner, log_evidence_increment_path=float(log_z),
        evidence_ess=evidence_ess, n_independent_accepted=n_independent,
        n_move_evaluations=moves.stats.n_evaluations, wall_time=time.perf_counter() - start,
        prior_data_conflict=float(conflict.max()), conflict_parameter=int(conflict.argmax()),
        ancestor_ess=ancestors, path_steps=length + 1,
        log_evidence_increment_se=increment_se, log_evidence_se=evidence_se,
        **jump_step_fields(kernel, state.prior, posterior, cloud.log_weights))
    record = StepRecord(info, posterior, cloud.log_weights, predictive)
    past = PastStep(kept_copy(dataset), state.prior, posterior, cloud.log_weights, float(log_increment), True,
                    _variance_before(state))
    keep = config.remedy_lag - 1
    new_state = SamplerState(step=step, particles=predictive, log_weights=cloud.log_weights, prior=density,
                             log_evidence=log_evidence,
                             step_size=float(moves.step_size if config.move == "stretch" else state.step_size),
                             posterior=posterior, posterior_log_weights=cloud.log_weights,
                             window=(state.window + (past,))[-keep:],
                             paths=cloud.particles.reshape(n, length + 1, d)[:, -keep:],
                             log_evidence_variance=evidence_variance, lineage=_lineage(state, cloud.labels),
                             previous_prior=state.prior if isinstance(state.prior, GaussianMixture) else None)
    return new_state, record, marginal


def forecast(samples, kernel: MarkovKernel, support, n_steps: int, rng: np.random.Generator,
             max_rounds: int = 100) -> np.ndarray:
    """Forecasts of the parameters ``1..n_steps`` steps ahead, restricted to the parameter space.

    The likelihood is zero outside the parameter space, so the model's forecast at horizon ``h``
    is the law of ``theta_{s+h}`` given the data and that ``theta_{s+1}, ..., theta_{s+h}`` all stay
    inside (the mass the kernel carries out is lost, as in the samplers' steps and the grid
    reference). It is drawn by rejection of whole paths: paths from ``samples`` through the kernel
    (Eq. A2), each kept for the horizons before it first leaves the space; more rounds re-draw
    from ``samples`` until every horizon has ``N`` paths. When the space is never left (or is
    unbounded) the first round is the plain propagation, draw for draw.

    Parameters
    ----------
    samples : (N, d) array
        Equal-weight posterior draws.
    kernel : MarkovKernel
    support : (d, 2) array
        The parameter space (box bounds, infinite allowed).
    n_steps : int
    rng : numpy.random.Generator
    max_rounds : int
        At most ``max_rounds * N`` paths; a horizon that has fewer than ``N`` inside paths then
        (but some) repeats them, one with none raises ``ValueError``.

    Returns
    -------
    (n_steps, N, d) array
    """
    samples = np.asarray(samples, dtype=float)
    n = samples.shape[0]
    out = np.empty((n_steps,) + samples.shape)
    filled = np.zeros(n_steps, dtype=int)
    for round_ in range(max_rounds):
        current = samples if round_ == 0 else samples[rng.integers(n, size=n)]
        alive = np.ones(n, dtype=bool)
        for h in range(n_steps):
            current = kernel.propagate(current, rng)
            alive &= _inside(current, support)
            take = current[alive][: n - filled[h]]
            out[h, filled[h]:filled[h] + take.shape[0]] = take
            filled[h] += take.shape[0]
        if (filled == n).all():
            return out
    for h in np.flatnonzero(filled < n):
        if filled[h] == 0:
            raise ValueError(f"predict: none of {max_rounds * n} forecast paths stays inside the parameter space "
                             f"for {h + 1} steps; the kernel carries the posterior out of it")
        out[h, filled[h]:] = out[h, rng.integers(filled[h], size=n - filled[h])]
    return out


def assimilate(state: SamplerState, dataset: Any, problem: Problem, config: SamplerConfig,
               rng: np.random.Generator) -> tuple[SamplerState, StepRecord]:
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
    _check_dataset(dataset, step)
    counter = _Counter(problem, dataset, step)
    if isinstance(state, NestedState):
        if step > 1 or not problem.inner_filter.joint_first_step:
            return assimilate_nested(state, dataset, problem, config, counter, rng)
        # the first dataset has no dynamics yet: a static problem in every parameter
        joint = SamplerState(0, state.particles, state.log_weights, problem.prior, 0.0, state.step_size)
        _, record, cloud = _assimilate_particles(joint, dataset, problem, config, rng, counter, "joint", start)
        new_state = after_joint_first_step(nested_split(problem.kernel), problem.inner_filter.n_inner,
                                           cloud.particles, cloud.log_weights,
                                           cloud.components, dataset, record.info.log_evidence,
                                           state.step_size if np.isnan(record.info.step_size) else record.info.step_size,
                                           cloud.particles, record.predictive)
        return new_state, record
    method = resolve_predictive(config.predictive, problem.kernel)
    try:
        new_state, record, _ = _assimilate_particles(state, dataset, problem, config, rng, counter, method, start)
    except ZeroLikelihoodError as error:
        # No predictive draw of the mixture lands where the likelihood is non-zero (run 9 of the oscillator study
        # under T6: the drift takes every predicted k below 0), yet the model's path posterior may have mass there,
        # paths whose earlier states the data put elsewhere: the bridge from the path prior can find them
        if not (config.remedy_bridge and state.window and _remedy_applies(config, method, problem.kernel)):
            raise
        try:
            new_state, record, _ = assimilate_paths(state, dataset, problem, config, rng, counter, method, start,
                                                    bridge=True)
        except ZeroLikelihoodError:
            raise error from None
        return new_state, record
    info = record.info
    # after a path-space step the mixture's own posterior understates the conflict (its target cannot reach
    # the tail, so fewer ancestors look involved): stay on the path space until 5x the threshold
    threshold = config.remedy_ess * (5.0 if state.window and state.window[-1].path_space else 1.0)
    if state.window and _remedy_applies(config, method, problem.kernel) and (
            info.ancestor_ess < threshold * config.n_samples or info.prior_data_conflict > config.conflict_threshold):
        try:
            new_state, record, _ = assimilate_paths(state, dataset, problem, config, rng, counter, method, start,
                                                    bridge=config.remedy_bridge)
        except ZeroLikelihoodError:  # the paths' restart found nothing the mixture's did: keep the mixture's step
            pass
    return new_state, record


def _assimilate_particles(state, dataset, problem, config, rng, counter, method, start):
    """Stages 1-6 for a :class:`SamplerState`; ``method`` is the resolved predictive (``"joint"``: the
    first step of SMC^2 with a particle inner filter, propagated but with no density built).
    Returns the new state, the record and the final cloud."""
    step = state.step + 1
    prior_logpdf = _prior_logpdf(state.prior, counter)
    if (method == "transition" and isinstance(state.prior, GaussianMixture) and config.pseudo_marginal_from
            and config.n_samples >= config.pseudo_marginal_from and state.log_prior is None):
        prior_logpdf = SubsampledPrior(state.prior, rng)  # pseudo-marginal moves where the pilot allows
    history = isinstance(state.prior, HistoryPrior)  # static parameters: the particles are the last posterior
    move_every_stage = _moves_every_stage(config, method)
    # IBIS's schedule exactly (particles'): the last stage's resample-move waits for the next dataset
    deferred = method == "history" and config.move_every_stage is False
    moves = _Moves(step_size=state.step_size)
    particles, log_weights, log_prior, rejuvenated = state.particles, state.log_weights, None, False
    if history:
        log_prior = state.log_prior
        if deferred:
            particles, log_weights, log_prior, moves, rejuvenated, labels = _rejuvenate_deferred(
                state, problem, config, prior_logpdf, moves, rng)
    cloud, log_restricted_mass, n_found = _weigh(state, particles, log_weights, log_prior, problem, config, counter,
                                                 prior_logpdf, rng, labels if rejuvenated else None)
    weights_before = np.exp(cloud.log_weights)
    weighed = cloud  # the step's prior draws (restricted to {inside, L > 0} after a restart)
    cloud, log_z, temperatures, moves, resampled, stage_ess = _temper_resample_move(
        cloud, problem, config, counter, prior_logpdf, moves, move_every_stage, deferred, rng)
    log_increment_path = log_z + log_restricted_mass  # Z = P(inside, L > 0) E[L | inside, L > 0]
    # with the history prior a step that kept its particles needs no fitted proposal: its weights are the
    # importance weights of the exact prior (and a proposal would re-evaluate the past, at O(s) cost)
    use_importance = config.evidence == "importance" and not (method == "history" and moves.stats.n_proposed == 0)
    cloud, log_increment, evidence_ess, n_independent = _evidence(
        cloud, log_increment_path, n_found, problem, config, counter, prior_logpdf, use_importance, rng)
    log_evidence = float(state.log_evidence + log_increment)
    density, predictive, next_log_prior = _propagate(state, cloud, dataset, log_increment, log_evidence, method,
                                                     problem, config, rng)
    step_size = moves.step_size if config.move == "stretch" else float("nan")
    conflict = step_conflict(weighed.particles, weighed.log_weights, cloud.particles, cloud.log_weights,
                             problem.support)
    ancestors, spread, window, paths = float("nan"), None, (), None
    ancestor_labels = _posterior_labels(state)
    if _remedy_applies(config, method, problem.kernel):  # keep what the path-space remedy needs
        keep = config.remedy_lag - 1
        if state.window and state.paths is None and isinstance(state.prior, GaussianMixture):
            # how many of the mixture's own components carry the posterior (the exact transition's with
            # "transition"), by one matrix product instead of the pairwise transition density: run 0 (T1) with
            # SMC, 4 interleaved pairs, CPU time with / without the remedy 1.53x -> 0.92x (within noise)
            spread = state.prior.ancestor_spread(cloud.particles, cloud.log_weights, ancestor_labels)
            ancestors = spread.ess
        elif state.window:
            index, mass = _ancestor_mass(problem.kernel, cloud.particles, state.posterior, state.posterior_log_weights,
                                         None if state.paths is None else rng, cloud.log_weights)
            spread = _mass_spread(state, mass)
            ancestors = spread.ess
            if state.paths is not None:
                paths = np.concatenate([state.paths[index], cloud.particles[:, None]], axis=1)[:, -keep:]
        window = (state.window + (PastStep(kept_copy(dataset), state.prior, cloud.particles, cloud.log_weights,
                                           float(log_increment), False, _variance_before(state)),))[-keep:]
    # the evidence's standard error; Eq. (A3)'s N ancestors carry Z_s (the remedy's pass gave their spread if it ran)
    if spread is None and isinstance(state.prior, GaussianMixture):
        spread = state.prior.ancestor_spread(cloud.particles, cloud.log_weights, ancestor_labels)
    ancestor_variance, covariance = _ancestor_terms(state, spread)
    increment_se, evidence_se, evidence_variance = step_standard_errors(
        state.log_evidence_variance, config.n_samples, use_importance and log_increment != log_increment_path,
        evidence_ess, weights_before, cloud.log_weights, len(temperatures), resampled, ancestor_variance, method,
        covariance)
    info = StepInfo(
        step=step, log_evidence_increment=float(log_increment),
        log_evidence=log_evidence, ess=float(stage_ess), resampled=bool(resampled or rejuvenated),
        acceptance_rate=moves.stats.acceptance_rate, step_size=float(step_size),
        n_virtual=moves.n_virtual, n_stages=len(temperatures), temperatures=temperatures,
        n_loglike_evals=counter.n_evals, n_nan=counter.n_nan, n_distinct=count_distinct(cloud.particles),
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
                             lineage=_lineage(state, cloud.labels),
                             previous_prior=state.prior if isinstance(state.prior, GaussianMixture) else None)
    return new_state, record, cloud


class _CountedLikelihood:
    """The likelihood, advancing a progress bar by the samples it evaluates (serial runs)."""

    def __init__(self, loglike, bar):
        self.loglike, self.bar = loglike, bar

    def __call__(self, theta, dataset):
        out = self.loglike(theta, dataset)
        self.bar.update(len(theta))
        return out


def _settings(values: dict) -> dict:
    """The :class:`SamplerConfig` fields among a driver's keyword arguments."""
    names = {f.name for f in fields(SamplerConfig)} - {"move", "n_samples"}
    return {k: v for k, v in values.items() if k in names}


class _SequentialSampler:
    """Driver: holds the state, calls :func:`assimilate`, keeps the records. The public
    classes :class:`SEMC` and :class:`SMC` spell their settings out as keyword arguments."""

    _move = ""

    def __init__(self, prior: JointPrior, kernel: MarkovKernel, loglike: LogLikelihood, n_samples: int = 1000,
                 rng: int | np.random.Generator | None = None, *, executor: Any = None, n_chunks: int | None = None,
                 history: RunningStatistics | None = None,
                 inner_filter: ParticleInnerFilter | KalmanInnerFilter | None = None,
                 blas_threads: int | None = 1, **settings: Any):
        if not (hasattr(prior, "logpdf") and hasattr(prior, "sample")):
            raise TypeError("prior: expected an object with logpdf(theta) and sample(n, rng)")
        if not isinstance(kernel, MarkovKernel):
            raise TypeError(f"kernel: expected a seqbayes.MarkovKernel, got {type(kernel).__name__}")
        if not callable(loglike):
            raise TypeError("loglike: expected a callable loglike(theta (N, d), dataset) -> (N,)")
        if executor is not None and not hasattr(executor, "map"):
            raise TypeError("executor: expected an object with a map method (concurrent.futures or dask Client)")
        if blas_threads is not None and (isinstance(blas_threads, bool) or int(blas_threads) != blas_threads
                                         or blas_threads < 1):
            raise ValueError(f"blas_threads: expected an integer >= 1 or None, got {blas_threads!r}")
        self._blas_threads = blas_threads
        if isinstance(n_samples, bool) or not isinstance(n_samples, (int, np.integer, float)) \
                or int(n_samples) != n_samples or n_samples < 2:
            raise ValueError(f"n_samples: must be an integer >= 2, got {n_samples!r}")
        self._rng = as_generator(rng)
        initial = as_samples(prior.sample(int(n_samples), self._rng), name="prior.sample(n, rng)")
        dim = initial.shape[1]
        if initial.shape[0] != int(n_samples):
            raise ValueError(f"prior.sample: returned {initial.shape[0]} rows for n = {n_samples}")
        if dim != kernel.dim:
            raise ValueError(f"kernel: has {kernel.dim} parameters but the prior has {dim}")
        if not np.all(np.isfinite(initial)):
            raise ValueError("prior.sample: returned non-finite samples")
        if self._move == "stretch" and int(n_samples) < 2 * dim:
            raise ValueError(f"n_samples: the stretch move needs at least 2 d = {2 * dim} walkers, got {n_samples}")
        if "target_acceptance" not in settings or settings["target_acceptance"] is None:
            settings["target_acceptance"] = paper_target_acceptance(dim)  # Eq. (10)
        config = SamplerConfig(move=self._move, n_samples=int(n_samples), **settings)
        # record what "auto" chose; a 'history' prior needs a static kernel
        self.config = replace(config, predictive=resolve_predictive(config.predictive, kernel))
        if history is not None and not isinstance(history, RunningStatistics):
            raise TypeError("history: expected a seqbayes.RunningStatistics(summarise, loglike)")
        if self.config.predictive == "smc2":
            inner_filter = ParticleInnerFilter(self.config.n_inner) if inner_filter is None else inner_filter
            if not (hasattr(inner_filter, "advance") and hasattr(inner_filter, "draws")):
                raise TypeError("inner_filter: expected a seqbayes.ParticleInnerFilter or KalmanInnerFilter")
        elif inner_filter is not None:
            raise ValueError(f"inner_filter: only used with predictive='smc2' (static and drifting parameters), "
                             f"this run uses {self.config.predictive!r}")
        self.problem = Problem(prior, kernel, loglike, support_of(prior, dim), executor, n_chunks, history,
                               inner_filter)
        self.names = tuple(getattr(prior, "names", [f"theta_{j}" for j in range(dim)]))
        if self.config.predictive == "smc2":
            split = nested_split(kernel)
            inner_filter.check(self.problem, split)
            self._state = start_nested(prior, inner_filter.outer_columns(split, dim), initial,
                                       float(self.config.step_size))
        else:
            self._state = SamplerState(step=0, particles=initial, log_weights=np.full(int(n_samples), -np.log(n_samples)),
                                       prior=prior, log_evidence=0.0, step_size=float(self.config.step_size))
        self._records: list[StepRecord] = []

    @property
    def state(self) -> SamplerState:
        return self._state

    def snapshot(self) -> tuple[SamplerState, tuple, dict]:
        """``(state, records, rng_state)``: everything needed to resume this run elsewhere."""
        return self._state, tuple(self._records), generator_state(self._rng)

    def restore(self, state: SamplerState, records: Sequence[StepRecord], rng_state: dict) -> None:
        """Continue from a :meth:`snapshot`: the next :meth:`update` gives the same numbers as
        it would have in the original process."""
        particles = as_samples(state.particles, self.problem.kernel.dim, "state.particles")
        if particles.shape[0] != self.config.n_samples:
            raise ValueError(f"state.particles: {particles.shape[0]} samples, the sampler has {self.config.n_samples}")
        records = list(records)
        if len(records) != state.step:
            raise ValueError(f"records: {len(records)} records for a state at step {state.step}")
        self._rng = generator_from_state(rng_state)
        self._state = state
        self._records = records

    @property
    def rng(self) -> np.random.Generator:
        return self._rng

    def update(self, dataset: Any, *, progress: bool = False) -> StepInfo:
        """Assimilate one dataset ``D^s`` and return its :class:`~seqbayes.results.StepInfo`.

        With ``progress=True`` a tqdm bar counts the step's likelihood evaluations (the number of
        tempering stages is adaptive, so a single step has no total; :meth:`run` shows one over
        the datasets) and ends with the step's ESS and log-evidence. Not with an ``executor``,
        whose workers evaluate the likelihood elsewhere.
        """
        return self._update(dataset, progress, leave=True)

    def _update(self, dataset, progress: bool, leave: bool) -> StepInfo:
        prior = (self._state.prior_draws, self._state.log_weights)
        problem, bar = self.problem, None
        if progress and self.problem.executor is None:
            from tqdm.auto import tqdm

            bar = tqdm(desc=f"step {self._state.step + 1}", unit="eval", leave=leave)
            problem = replace(problem, loglike=_CountedLikelihood(problem.loglike, bar))
        try:
            with blas_limit(self._blas_threads):
                state, record = assimilate(self._state, dataset, problem, self.config, self._rng)
            if bar is not None:
                bar.set_postfix(ESS=f"{record.info.ess:.0f}", logZ=f"{record.info.log_evidence:.2f}")
        finally:
            if bar is not None:
                bar.close()
        self._state = state
        self._records.append(record)
        if record.info.inner_ess < 0.05:
            warnings.warn(f"step {record.info.step}: SMC^2's inner particle filters are degenerate (mean ESS "
                          f"{100 * record.info.inner_ess:.1f} % of n_inner = {self.config.n_inner}): the data put the "
                          f"drifting parameters far from where the kernel predicts them, or pin them far more tightly "
                          f"than its noise, so the likelihood estimates are noisy and the moves rarely accept. A "
                          f"kernel the data contradict loses evidence anyway; otherwise raise n_inner, declare a "
                          f"KalmanInnerFilter if the model is linear-Gaussian in them, or for a short run use "
                          f"predictive='transition'",
                          InnerFilterWarning, stacklevel=3)  # user -> update/run -> _update
        # either half of the diagnostic: the posterior mean's shift, or a posterior carried by a few of the predictive
        # mixture's components (the ancestor ESS below remedy_ess * N, which also starts the remedy; NaN where the
        # remedy does not apply). On the oscillator study before the remedy the ancestor ESS is below it on run 9
        # under all six kernels (0.001-0.004 N) and at least 0.06 N on runs 0-8 except run 3 under T6 (0.003 N, a
        # true conflict: exact shift 9.5), where the shift alone misses run 9 under T5 (3.5 against an exact 17.0)
        # (benchmarks/bench_conflict.py --off). Not every path-space step: after one the remedy stays on up to 5x.
        tail = record.info.ancestor_ess < self.config.remedy_ess * self.config.n_samples
        if record.info.prior_data_conflict > self.config.conflict_threshold or tail:
            conflict = step_conflict(*prior, record.posterior, record.log_weights, self.problem.support)
            far = ", ".join(f"{name} {value:.1f}" for name, value in zip(self.names, conflict)
                            if value > self.config.conflict_threshold) or \
                f"{self.names[record.info.conflict_parameter]} {record.info.prior_data_conflict:.1f}"
            if np.isfinite(record.info.ancestor_ess):
                far += (f"; {record.info.ancestor_ess:.0f} of the {self.config.n_samples} previous posterior "
                        f"particles carry it (StepInfo.ancestor_ess)")
            remedy = (f"; assimilated on the path space of the last {record.info.path_steps} states, whose target is "
                      f"the model's exact one (StepInfo.path_steps)" if record.info.path_steps else
                      "; the predictive mixture's tail is a few particles there, so the sampler may be unreliable "
                      "(the path-space remedy is off or does not apply: docs/prior_data_conflict.md)")
            warnings.warn(f"step {record.info.step}: prior-data conflict: the posterior lies far in the tail of "
                          f"the step's prior (posterior-mean shift in prior sds: {far}); an abrupt change or a "
                          f"kernel too narrow for the data{remedy}",
                          PriorDataConflictWarning, stacklevel=3)
        return record.info

    def run(self, datasets: Iterable[Any], *, progress: bool = False) -> Result:
        """Assimilate each dataset in turn; returns :attr:`result`.

        With ``progress=True`` (as emcee's ``run_mcmc``) a tqdm bar over the datasets shows the
        total, the elapsed time, the ETA from the mean time per step so far and, after each step,
        its ESS, acceptance rate and cumulative log-evidence.
        """
        if not progress:
            for dataset in datasets:
                self._update(dataset, False, leave=True)
            return self.result
        from tqdm.auto import tqdm

        total = len(datasets) if hasattr(datasets, "__len__") else None
        with tqdm(datasets, total=total, desc=type(self).__name__, unit="step") as bar:
            for dataset in bar:
                info = self._update(dataset, True, leave=False)
                bar.set_postfix(ESS=f"{info.ess:.0f}", accept=f"{info.acceptance_rate:.2f}",
                                logZ=f"{info.log_evidence:.2f}")
        return self.result

    def predict(self, n_steps: int) -> np.ndarray:
        """Forecast: the posterior propagated ``1..n_steps`` steps through the kernel (Eq. A2).

        Returns
        -------
        (n_steps, N, d) array
            Equal-weight draws of each horizon's forecast restricted to the parameter space, as the
            model defines it (:func:`forecast`).
        """
        if self._state.posterior is None:
            raise ValueError("predict: no dataset assimilated yet")
        if int(n_steps) < 1:
            raise ValueError(f"n_steps: must be >= 1, got {n_steps}")
        return forecast(self._records[-1].equal_weight_samples(self._rng), self.problem.kernel,
                        self.problem.support, int(n_steps), self._rng)

    @property
    def result(self) -> Result:
        meta = {"sampler": type(self).__name__, "config": {k: v for k, v in vars(self.config).items()},
                "kernel": self.problem.kernel.describe(),
                "prior": self.problem.prior.describe() if hasattr(self.problem.prior, "describe") else repr(self.problem.prior)}
        return Result(self.names, tuple(self._records), meta)


class SEMC(_SequentialSampler):
    """Sequential Ensemble Monte Carlo (Algorithm 2): stretch moves with an adaptive step size.

    Parameters
    ----------
    prior : JointPrior or object with ``logpdf`` and ``sample``
    kernel : MarkovKernel
    loglike : callable ``(theta (N, d), dataset) -> (N,)``
    n_samples : int
        Ensemble size ``N`` (at least ``2 d``).
    rng : int or numpy.random.Generator
    executor : object with ``map``, optional
        Evaluates likelihood chunks in parallel (``concurrent.futures`` executor or ``dask.distributed.Client``).
    history : RunningStatistics, optional
        With every parameter static: the likelihood's additive statistics, so that the exact
        history prior evaluates every past dataset in one call (bounded cost per update).
    inner_filter : ParticleInnerFilter or KalmanInnerFilter, optional
        With static and drifting parameters (SMC^2, :mod:`seqbayes.nested`): the filter over the
        drifting ones (default ``ParticleInnerFilter(100)``).
    blas_threads : int or None
        BLAS threads inside :meth:`update` (1: the hot products have an inner dimension of d,
        where threads cost 3x; ``None`` leaves BLAS as it is).
    target_acceptance : float, optional
        SEMC's target acceptance rate ``alpha_tr`` (default: Eq. 10, ``0.21 / d + 0.23``).
    step_size : float
        Initial stretch-move step size ``u`` (2).
    max_virtual, virtual_tolerance : int, float
        Cap on virtual iterations (sweeps) per stage and their stopping tolerance.
    tempering, tempering_ess, tempering_threshold, max_stages, ess_threshold, resampling, \
predictive, shrink_static, n_moves, transform, min_valid_fraction, evidence, moved_fraction, \
move_every_stage, n_independent, min_evidence_ess, max_refits, n_inner, conflict_threshold, \
conflict_remedy, remedy_ess, remedy_lag, remedy_bridge, pseudo_marginal_from, scaled_moves, economy
        The fields of :class:`SamplerConfig` of the same names, with its defaults and
        validation (see there for what each does).

    Examples
    --------
    >>> import numpy as np, seqbayes
    >>> from scipy import stats
    >>> prior = seqbayes.JointPrior({"a": stats.norm(0, 1)})
    >>> kernel = seqbayes.MarkovKernel([seqbayes.Static()])
    >>> loglike = lambda theta, y: stats.norm.logpdf(y, theta[:, 0], 1.0)
    >>> sampler = seqbayes.SEMC(prior, kernel, loglike, n_samples=200, rng=1)
    >>> info = sampler.update(0.5)
    >>> info.step
    1
    """

    _move = "stretch"

    def __init__(self, prior: JointPrior, kernel: MarkovKernel, loglike: LogLikelihood, n_samples: int = 1000,
                 rng: int | np.random.Generator | None = None, *, executor: Any = None, n_chunks: int | None = None,
                 history: RunningStatistics | None = None,
                 inner_filter: ParticleInnerFilter | KalmanInnerFilter | None = None, blas_threads: int | None = 1,
                 target_acceptance: float | None = None, step_size: float = 2.0, max_virtual: int = 30,
                 virtual_tolerance: float = 0.1, tempering: bool = True, tempering_ess: float = 0.5,
                 tempering_threshold: float = 0.1, max_stages: int = 1000, ess_threshold: float = 0.5,
                 resampling: str = "systematic", predictive: str = "auto", shrink_static: bool = True,
                 n_moves: int = 3, transform: bool = True, min_valid_fraction: float = 0.5,
                 evidence: str = "importance", moved_fraction: float = 0.9, move_every_stage: bool | None = None,
                 n_independent: int = 3, min_evidence_ess: float = 0.3, max_refits: int = 5, n_inner: int = 100,
                 conflict_threshold: float = 4.0, conflict_remedy: bool = True, remedy_ess: float = 0.05,
                 remedy_lag: int = 10, remedy_bridge: bool = True, pseudo_marginal_from: int = 2048,
                 scaled_moves: bool | None = None, economy: bool = False):
        super().__init__(prior, kernel, loglike, n_samples, rng, executor=executor, n_chunks=n_chunks,
                         history=history, inner_filter=inner_filter, blas_threads=blas_threads,
                         **_settings(locals()))


class SMC(_SequentialSampler):
    """Sequential Monte Carlo (Algorithm 4): Gaussian random-walk MH with the weighted covariance.

    Parameters as :class:`SEMC`, without its stretch-move settings (``target_acceptance``,
    ``step_size``, ``max_virtual``, ``virtual_tolerance``), and:

    Parameters
    ----------
    proposal_scale : float
        ``gamma`` of Eq. (A7) (1).
    max_moves : int
        Cap on MH steps per stage (30); ``n_moves`` is the minimum (3; the paper uses 1).
    """

    _move = "gaussian"

    def __init__(self, prior: JointPrior, kernel: MarkovKernel, loglike: LogLikelihood, n_samples: int = 1000,
                 rng: int | np.random.Generator | None = None, *, executor: Any = None, n_chunks: int | None = None,
                 history: RunningStatistics | None = None,
                 inner_filter: ParticleInnerFilter | KalmanInnerFilter | None = None, blas_threads: int | None = 1,
                 proposal_scale: float = 1.0, max_moves: int = 30, tempering: bool = True, tempering_ess: float = 0.5,
                 tempering_threshold: float = 0.1, max_stages: int = 1000, ess_threshold: float = 0.5,
                 resampling: str = "systematic", predictive: str = "auto", shrink_static: bool = True,
                 n_moves: int = 3, transform: bool = True, min_valid_fraction: float = 0.5,
                 evidence: str = "importance", moved_fraction: float = 0.9, move_every_stage: bool | None = None,
                 n_independent: int = 3, min_evidence_ess: float = 0.3, max_refits: int = 5, n_inner: int = 100,
                 conflict_threshold: float = 4.0, conflict_remedy: bool = True, remedy_ess: float = 0.05,
                 remedy_lag: int = 10, remedy_bridge: bool = True, pseudo_marginal_from: int = 2048,
                 scaled_moves: bool | None = None, economy: bool = False):
        super().__init__(prior, kernel, loglike, n_samples, rng, executor=executor, n_chunks=n_chunks,
                         history=history, inner_filter=inner_filter, blas_threads=blas_threads,
                         **_settings(locals()))

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from collections.abc import Callable, Iterable, Sequence
    from typing import Any

    from .nested import KalmanInnerFilter, ParticleInnerFilter
    from .priors import JointPrior

    #: ``loglike(theta (N, d), dataset) -> (N,)``
    LogLikelihood = Callable[[np.ndarray, Any], np.ndarray]
