"""The records of the engine: the sampler's state between datasets, the model, a step's weighted cloud
and what its moves did, the records each stage of the pipeline hands to the next (:class:`Weighed`,
:class:`Tempered`, :class:`Estimate`, :class:`Outcome`), the past steps kept for the path-space remedy, and the
protocol of a step's predictive prior (:class:`Predictive`) that the pipeline goes through."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol

import numpy as np

from ..kernels import MarkovKernel
from .errors import ZeroLikelihoodError
from ..priors import BoxTransform

__all__ = ["SamplerState", "RemedyMemory", "Problem", "PastStep", "Cloud", "Weighed",
           "Tempered", "Estimate", "Outcome", "Failure", "Reassimilate", "Assimilated", "Predictive", "Storage",
           "STORAGE", "stored_as"]


@dataclass(frozen=True, eq=False)
class RemedyMemory:
    """What the conflict remedy keeps from one step to the next, as one record that says how it is stored.

    Attributes
    ----------
    window : tuple of PastStep
        The last ``lag`` steps (datasets, priors, posteriors) of the path-space target.
    paths : (N, L, d) array or None
        After a path-space step: the paths over the last ``L`` steps of the posterior particles
        (``paths[:, -1]`` is the posterior); ``None`` until the remedy first runs.
    lineage : (N, 2) int array or None
        Labels of the last two posteriors' particles, for the ancestors' spread and the evidence's standard error
        (:func:`~seqbayes.predictive.evidence.step_standard_errors`): column 0 of the posterior's, the index of the
        step's initial draw each particle descends from (the predictive draw, restart draw or path-space
        walker; resampling copies it, moves keep it), column 1 the previous posterior's (the components of
        ``SamplerState.previous_prior``). ``None`` (before the first step, a state from an older run store) counts
        every particle as its own.
    """

    window: tuple = ()
    paths: np.ndarray | None = None
    lineage: np.ndarray | None = None

    def arrays(self, n: int, d: int) -> dict:
        """The run store's arrays (float64): ``state_window ()`` (the window's length: its steps are rebuilt from the
        store's records, datasets and priors), ``state_paths (L, N, d)`` (``L`` varies over the steps; 0 before
        the remedy first runs) and ``state_lineage (N, 2)`` when known."""
        paths = np.zeros((0, n, d)) if self.paths is None else np.transpose(self.paths, (1, 0, 2))
        out = {"state_window": len(self.window), "state_paths": paths}
        if self.lineage is not None:
            out["state_lineage"] = self.lineage
        return {name: np.array(value, dtype=float) for name, value in out.items()}

    @classmethod
    def from_arrays(cls, arrays: dict, window: tuple) -> "RemedyMemory":
        """The inverse of :meth:`arrays`, given the ``window`` rebuilt from the store (of ``state_window`` steps)."""
        paths, lineage = arrays.get("state_paths"), arrays.get("state_lineage")
        return cls(window, None if paths is None or not len(paths) else np.transpose(paths, (1, 0, 2)),
                   None if lineage is None else np.asarray(lineage).astype(np.intp))

    @staticmethod
    def window_length(arrays: dict, step: int) -> int:
        """The stored window's length at ``step`` (0 for a store written before the remedy kept one)."""
        length = float(arrays.get("state_window", 0))
        if not (length == int(length) and 0 <= length <= step):
            raise ValueError(f"state_window: the conflict remedy's window at step {step} holds {length:g} steps; "
                             f"expected an integer in [0, {step}] (the store was edited)")
        return int(length)


@dataclass(frozen=True, eq=False)
class Failure:
    """A stage that cannot go on, as a value: the error it would raise (:class:`~seqbayes.core.errors.ZeroLikelihoodError`,
    :class:`~seqbayes.core.errors.TemperingLimitError`). The pipeline decides what follows (a remedy, the first
    outcome, or raising it to the caller)."""

    error: Exception

    @property
    def zero_likelihood(self) -> bool:
        return isinstance(self.error, ZeroLikelihoodError)


@dataclass(frozen=True, eq=False)
class Reassimilate:
    """A remedy's decision: assimilate the step through ``predictive`` instead; should that fail, through
    ``otherwise`` (``None``: keep the first outcome, or raise its failure)."""

    predictive: object
    otherwise: object = None


@dataclass(frozen=True, eq=False)
class Assimilated:
    """A step that went through the pipeline: the new state, its record, what weighing found, and what the
    predictive's remedy reads from it (``lagged_variance``: :attr:`Outcome.lagged_variance`)."""

    state: object
    record: object
    weighed: object
    lagged_variance: float = float("nan")


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
        The current prior density: the initial prior, then a :class:`~seqbayes.predictive.mixture.GaussianMixture`
        or, for static parameters, a :class:`~seqbayes.predictive.history.HistoryPrior`.
    log_evidence : float
        Cumulative log-evidence.
    step_size : float
        Current stretch step size (SEMC).
    posterior, posterior_log_weights : arrays or None
        The last step's posterior (for forecasts).
    log_prior : (N,) array or None
        ``prior.logpdf(particles)`` when known (a :class:`~seqbayes.predictive.history.HistoryPrior` at
        the last posterior: its target values, so the past datasets are not re-evaluated).
    memory : RemedyMemory
        What the conflict remedy keeps from step to step (the window of past steps, the paths, the lineage).
    log_evidence_variance : float
        Estimated variance of ``log_evidence`` (:func:`~seqbayes.predictive.evidence.step_standard_errors`).
    previous_prior : GaussianMixture or None
        The mixture prior the last step used (components: the previous posterior's particles), for the
        part of the next increment's standard error that comes from it
        (:meth:`~seqbayes.predictive.mixture.GaussianMixture.backward_spread`); ``None`` for any other prior.
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
    memory: RemedyMemory = field(default_factory=lambda: RemedyMemory())
    log_evidence_variance: float = 0.0
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
    history: object = None
    inner_filter: object = None

    def __post_init__(self):
        bounded = bool(np.isfinite(self.support).any())  # else the move transform is the identity
        object.__setattr__(self, "bounded", bounded)
        object.__setattr__(self, "transform", BoxTransform(self.support) if bounded else None)


@dataclass(frozen=True, eq=False)
class Cloud:
    """The weighted particles of one step between stages, with their ``(log L, log p_s)`` components and
    their labels: the index of the step's initial draw each descends from (resampling copies it, moves keep it;
    :attr:`RemedyMemory.lineage`)."""

    particles: np.ndarray
    log_weights: np.ndarray
    components: np.ndarray
    labels: np.ndarray | None = None


@dataclass(frozen=True, eq=False)
class Weighed:
    """Stage 1 of a step: the prior particles weighed by the likelihood.

    Attributes
    ----------
    cloud : Cloud
        The step's prior draws (the restricted prior's after a restart) with their components.
    prior_logpdf : callable ``theta (M, d) -> (M,)``
        The step's prior density as the moves and the evidence evaluate it.
    moves : MoveTally
        Moves made before weighing (IBIS's deferred resample-move), else none.
    log_restricted_mass : float
        Log of the restricted prior's mass after a restart (0 without).
    n_found : int
        Distinct restart draws (N without restart).
    rejuvenated : bool
        Whether a deferred resample-move ran.
    """

    cloud: Cloud
    prior_logpdf: object
    moves: MoveTally
    log_restricted_mass: float = 0.0
    n_found: int = 0
    rejuvenated: bool = False


@dataclass(frozen=True, eq=False)
class Tempered:
    """Stages 2-4: the cloud after tempering, resampling and moving.

    ``log_z`` is the tempering path's log-evidence increment (Eq. 1, with the restricted mass),
    ``stage_ess`` the last stage's ESS before resampling.
    """

    cloud: Cloud
    log_z: float
    temperatures: tuple
    moves: MoveTally
    resampled: bool
    stage_ess: float


@dataclass(frozen=True, eq=False)
class Estimate:
    """Stage 5: the evidence increment and the cloud after the importance sweeps.

    ``importance`` says whether ``log_increment`` is the importance estimate (else the path's);
    ``moves`` include those of any second cloud the estimate pooled.
    """

    cloud: Cloud
    log_increment: float
    evidence_ess: float
    n_independent: int
    importance: bool
    moves: MoveTally


@dataclass(frozen=True, eq=False)
class Outcome:
    """Stage 6: the next state and what the step's record holds besides the stage records.

    Attributes
    ----------
    state : SamplerState or NestedState
    posterior : (N, d) array
    log_weights : (N,) array
    predictive : (N, d) array
        The record's predictive draws.
    distinct : (N, k) array
        The particles whose distinct rows ``StepInfo.n_distinct`` counts.
    log_evidence : float
    step_size : float
        The record's step size (SEMC's adapted one; NaN where none is adapted).
    records : dict
        The :class:`~seqbayes.results.StepInfo` records the predictive fills (``evidence``, ``conflict``, ``jumps``,
        ``nested``; the others take their defaults).
    moments : tuple of two (d,) arrays or None
        The posterior's mean and sd when the predictive knows them better than the draws do (SMC^2's
        Rao-Blackwellised drifting parameters); ``None``: from the weighted draws.
    lagged_variance : float
        The earlier posteriors' share of the increment's variance, for the remedy's decision
        (:func:`~seqbayes.predictive.lineage.lagged_ancestor_variance`; NaN where not computed).
    """

    state: object
    posterior: np.ndarray
    log_weights: np.ndarray
    predictive: np.ndarray
    distinct: np.ndarray
    log_evidence: float
    step_size: float
    records: dict
    moments: tuple | None = None
    lagged_variance: float = float("nan")


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
    log_evidence_variance : float
        The cumulative log-evidence's variance before the step (``SamplerState.log_evidence_variance``);
        a bridged step (:class:`~seqbayes.predictive.transition.PathSpace`) estimates the window's evidence afresh from it.
    path_states : int
        A path-space step's number of states (``StepInfo.path_steps``; its window's first step is ``path_states - 1``
        steps back), 0 for a mixture step.
    """

    dataset: object
    prior: object
    posterior: np.ndarray
    log_weights: np.ndarray
    log_evidence_increment: float
    log_evidence_variance: float = 0.0
    path_states: int = 0

    @property
    def path_space(self) -> bool:
        """Whether the step was assimilated on the path space."""
        return self.path_states > 0


class Predictive(Protocol):
    """What one step's predictive prior does at each stage of the pipeline. A stage that cannot go on returns a
    :class:`Failure`; :meth:`temper` may also return a remedy's :class:`Reassimilate`, decided between its stages."""

    def weigh(self, state, dataset, likelihood, rng) -> Weighed | Failure:
        """Stage 1: the prior particles and their likelihoods (Eq. A4)."""

    def temper(self, state, dataset, weighed: Weighed, likelihood, rng) -> Tempered | Failure | Reassimilate:
        """Stages 2-4: reweight by ``L^delta`` (Eq. A5), resample, move."""

    def estimate(self, tempered: Tempered, weighed: Weighed, likelihood, rng) -> Estimate | Failure:
        """Stage 5: the evidence increment."""

    def propagate(self, state, weighed: Weighed, tempered: Tempered, estimate: Estimate, dataset, likelihood,
                  rng) -> Outcome:
        """Stage 6: the next state (Eq. A2-A3) and the record's diagnostics."""

    def remedy(self, state, dataset, likelihood, outcome: Assimilated | Failure) -> Reassimilate | None:
        """What to do with the step's ``outcome``: ``None`` keeps it (or raises its failure), a
        :class:`Reassimilate` assimilates the step again through another predictive."""


@dataclass(frozen=True)
class Storage:
    """How one kind of state is kept in the run store (:mod:`seqbayes.store.snapshot`), registered by its class
    (:func:`stored_as`): a state's prior density (the mixtures, the history prior), whose arrays complete the
    :class:`SamplerState`, or a whole state of its own (``whole``: SMC^2's).

    Attributes
    ----------
    kind : str
        The kind's name (``"mixture"``, ``"history"``, ``"nested"``, ...).
    prefix : str
        What its array names (the run store's variable names) begin with.
    to_arrays : callable
        ``obj.<to_arrays>(log_prior) -> dict`` of float arrays (``obj`` the prior; a whole state takes no argument).
    from_arrays : callable
        ``from_arrays(arrays, context) -> (prior, log_prior)``; a whole state's
        ``from_arrays(arrays_by_step, datasets) -> state``.
    needs_datasets : bool
        Resuming needs the assimilated datasets.
    dims : dict
        Dimension names (after ``step``) of its arrays whose axes have a meaning a NetCDF reader can use.
    every_step : tuple or None
        The arrays every later step needs (the others rebuild the state after their own step only: the store
        keeps them for the last steps alone); ``None``: all of them.
    fill : callable or None
        ``fill(arrays, n_samples)`` adds (in place) what a store of an earlier version lacks.
    """

    kind: str
    prefix: str
    to_arrays: object
    from_arrays: object
    needs_datasets: bool = False
    dims: dict = field(default_factory=dict)
    every_step: tuple | None = None
    fill: object = None
    whole: bool = False


#: The registered kinds: class -> :class:`Storage` (:func:`stored_as`).
STORAGE: dict = {}


def stored_as(kind: str, prefix: str, **options):
    """A class decorator: instances of the class are stored as ``kind`` (:class:`Storage`), through its methods
    ``to_arrays`` and classmethod ``from_arrays``; ``options`` the other fields of :class:`Storage`."""
    def register(cls):
        STORAGE[cls] = Storage(kind, prefix, cls.to_arrays, cls.from_arrays, **options)
        return cls
    return register
