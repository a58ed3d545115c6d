"""The on-line update: the drivers :class:`SMC` and :class:`SEMC`, which hold the current state and call the pure
function :func:`assimilate`, the pipeline :func:`run_step` that every predictive prior goes through
(:class:`~seqbayes.core.state.Predictive`), and what the numbers a step leaves behind may hold (:data:`OUTPUTS`,
:func:`check_step`).

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
   the final posterior (:mod:`seqbayes.predictive.evidence`), whose proposal also drives
   independence-MH sweeps; the stages' product of mean weights (Eq. 1) is kept
   as the "path" estimate.
5. The posterior is propagated through the Markov kernel (Eq. A2), and the
   predictive density (Eq. A3) becomes the next step's prior.

The parameter space is the initial prior's support and the likelihood is zero
outside it, so a kernel that predicts impossible parameters loses evidence.

What a step leaves behind: What the numbers a step leaves behind may hold: one definition for the engine and the run store.

:func:`check_step` checks a step's state and record when :func:`assimilate` returns them, and the run store checks every array of a file it opens (:func:`seqbayes.store.base.check_finite`)
with the same rules (:data:`OUTPUTS`, looked up by :func:`allowed`). A state the engine hands out is
therefore always one the store re-opens: a step that would break this raises before anything is stored.

Names are the state's and record's attribute names (``posterior``, ``log_weights``,
``log_evidence_variance``, SMC^2's ``cloud_x`` ...); the store maps its variable names to them
(``state_log_evidence_variance`` -> ``log_evidence_variance``, :func:`seqbayes.store.snapshot.output_name`).
"""

from __future__ import annotations

import dataclasses
import time
import warnings
from dataclasses import dataclass, fields

import numpy as np

from ..core.errors import InnerFilterWarning, PriorDataConflictWarning, documented
from ..core.likelihood import ValidatedLikelihood, check_dataset
from ..core.state import Assimilated, Failure, Problem, Reassimilate, SamplerState
from ..core.tempering import Adaptive, Tempering, blas_limit
from ..kernels import MarkovKernel
from ..moves import Moves, RandomWalk, Stretch
from ..parallel import Workers
from ..predictive.evidence import Importance
from ..predictive.particle import count_distinct, step_conflict
from ..predictive.smc2 import nested_split, start_nested
from ..predictive.transition import Conflict, PathSpace
from ..priors import as_samples, support_of
from ..results import MoveInfo, Result, StepInfo, StepRecord
from ..rng import as_generator, generator_from_state, generator_state
from .forecast import forecast
from .settings import SamplerConfig

__all__ = ["SMC", "SEMC", "assimilate", "run_step", "check_step", "InvalidStepError", "Allowed", "OUTPUTS", "allowed",
           "violation"]


class InvalidStepError(RuntimeError):
    """A step left a value its state or record may not hold (:data:`OUTPUTS`); nothing was stored."""


@dataclass(frozen=True)
class Allowed:
    """The non-finite values an array may hold."""

    nan: bool = False
    pos_inf: bool = False
    neg_inf: bool = False

    def bad(self, values: np.ndarray) -> np.ndarray:
        """Boolean mask of the entries of ``values`` (float) this rule refuses."""
        bad = np.zeros(values.shape, dtype=bool)
        if not self.nan:
            bad |= np.isnan(values)
        if not self.pos_inf:
            bad |= values == np.inf
        if not self.neg_inf:
            bad |= values == -np.inf
        return bad


FINITE = Allowed()
#: What an array not named in :data:`OUTPUTS` may hold: anything but NaN (a log-density may be -inf).
NOT_NAN = Allowed(pos_inf=True, neg_inf=True)

#: The rule of each named output.
OUTPUTS = {
    # samples are weighed and moved again when the run resumes
    "posterior": FINITE, "predictive": FINITE, "particles": FINITE, "dataset": FINITE,
    "log_weights": Allowed(neg_inf=True), "posterior_log_weights": Allowed(neg_inf=True),  # -inf: zero weight
    # NaN: not estimated (a multi-stage tempering path's increment, SMC^2; step_standard_errors), and then
    # unknown for the cumulative log-evidence of every later step too
    "log_evidence_variance": Allowed(nan=True, pos_inf=True),
    "diagnostics": Allowed(nan=True, pos_inf=True, neg_inf=True),  # NaN: a diagnostic not computed
}


def allowed(name: str) -> Allowed:
    """The rule of output ``name`` (:data:`OUTPUTS`, else :data:`NOT_NAN`)."""
    return OUTPUTS.get(name, NOT_NAN)


def violation(name: str, values, rule_name: str | None = None) -> str | None:
    """``None`` if ``values`` keeps the rule of output ``rule_name`` (default ``name``), else a message naming
    ``name``, the count of refused values and the first one's index."""
    values = np.asarray(values)
    if values.dtype.kind != "f":
        return None
    bad = allowed(name if rule_name is None else rule_name).bad(values)
    if not bad.any():
        return None
    where = np.argwhere(bad)[0] if bad.ndim else ()
    return f"{name} holds {int(bad.sum())} NaN/inf value(s), first at index {tuple(int(i) for i in where)}"


def _named_values(obj, prefix: str = ""):
    """``(name, value)`` of the float arrays and floats among a dataclass's fields (a dict field's entries named
    ``field_key``, a dataclass field's ``field_attr``), one level deep below the top."""
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        name = prefix + f.name
        if isinstance(value, dict):
            yield from ((f"{name}_{key}", v) for key, v in value.items() if isinstance(v, np.ndarray))
        elif isinstance(value, (np.ndarray, float)):
            yield name, value
        elif dataclasses.is_dataclass(value) and not isinstance(value, type) and not prefix:
            yield from _named_values(value, f"{name}_")


def check_step(state, record) -> None:
    """Raise :class:`InvalidStepError` if ``state`` (a dataclass: ``SamplerState``, SMC^2's ``NestedState``) or
    ``record`` (:class:`~seqbayes.results.StepRecord`) holds a value :data:`OUTPUTS` refuses.

    The state's prior is checked through its own fields (``prior_centres`` ...: by the rule of anything
    unnamed), the record's posterior, weights and predictive by theirs.
    """
    pairs = [("posterior", record.posterior), ("log_weights", record.log_weights), ("predictive", record.predictive),
             *_named_values(state)]
    for name, values in pairs:
        message = violation(name, values)
        if message is not None:
            raise InvalidStepError(f"step {record.info.step}: the sampler's new state is invalid: {message}; "
                                   f"nothing was stored (please report this with the datasets)")


def run_step(predictive: Predictive, state, dataset, likelihood: ValidatedLikelihood, rng: np.random.Generator,
             start: float) -> Assimilated | Failure | Reassimilate:
    """One step through ``predictive``: weigh -> temper/resample/move -> evidence -> propagate -> record.

    Returns the step (:class:`~seqbayes.core.state.Assimilated`: the new state, the record and what weighing found,
    for the remedy's decision), or what stopped it: a stage's :class:`~seqbayes.core.state.Failure` or a remedy's
    :class:`~seqbayes.core.state.Reassimilate`, decided between the tempering stages. ``start`` is the step's
    ``time.perf_counter()``."""
    weighed = predictive.weigh(state, dataset, likelihood, rng)
    if isinstance(weighed, Failure):
        return weighed
    tempered = predictive.temper(state, dataset, weighed, likelihood, rng)
    if isinstance(tempered, (Failure, Reassimilate)):
        return tempered
    estimate = predictive.estimate(tempered, weighed, likelihood, rng)
    if isinstance(estimate, Failure):
        return estimate
    outcome = predictive.propagate(state, weighed, tempered, estimate, dataset, likelihood, rng)
    moves, stats = estimate.moves, estimate.moves.stats
    info = StepInfo(
        step=state.step + 1, log_evidence_increment=float(estimate.log_increment), log_evidence=outcome.log_evidence,
        ess=float(tempered.stage_ess), resampled=bool(tempered.resampled or weighed.rejuvenated),
        temperatures=tempered.temperatures, n_loglike_evals=likelihood.n_evals, n_nan=likelihood.n_nan,
        n_distinct=count_distinct(outcome.distinct), wall_time=time.perf_counter() - start,
        moves=MoveInfo(stats.acceptance_rate, outcome.step_size, moves.n_virtual, stats.n_proposed, stats.n_accepted,
                       stats.n_identical_partner, stats.n_evaluations, stats.n_screen_evaluations, stats.n_screened_out),
        **outcome.records)
    record = StepRecord(info, outcome.posterior, outcome.log_weights, outcome.predictive, outcome.moments)
    return Assimilated(outcome.state, record, weighed, outcome.lagged_variance)


def assimilate(state, dataset: Any, problem: Problem, config: SamplerConfig, rng: np.random.Generator, *,
               on_evaluated: Callable[[int], None] | None = None) -> tuple[object, StepRecord]:
    """Assimilate one dataset (pure; ``state`` is not modified): :func:`run_step` through the step's predictive
    (the ``predictive`` component's, resolved for the run: :func:`~seqbayes.predictive.base.resolve_predictive`),
    then as its remedy decides.

    The remedy's decision is a value: ``None`` keeps the step, a :class:`~seqbayes.core.state.Reassimilate` runs the
    step again through another predictive (the path-space step, :class:`~seqbayes.predictive.transition.PathSpace`), and,
    should that find nothing, through its ``otherwise`` or back to the first outcome. The decision may come between
    the first step's tempering stages (then the first outcome is the decision itself) or after it. A failure that
    no remedy takes is raised.

    ``on_evaluated(n_rows)`` is told of every likelihood evaluation (a progress bar's ``update``).

    Returns
    -------
    new_state : SamplerState or NestedState
    record : StepRecord

    Raises
    ------
    ZeroLikelihoodError
        If every sample has zero likelihood.
    TemperingLimitError
        If the tempering took more than ``max_stages`` stages.
    InvalidStepError
        The new state or record holds a value the run store would refuse (:data:`OUTPUTS`).
    """
    start = time.perf_counter()
    check_dataset(dataset, state.step + 1)
    likelihood = ValidatedLikelihood.for_step(problem, dataset, state.step + 1, on_evaluated)
    predictive, start_state = config.predictive.predictive(state, problem, config)  # the run's resolved predictive
    first = run_step(predictive, start_state, dataset, likelihood, rng, start)
    decision = first if isinstance(first, Reassimilate) else predictive.remedy(state, dataset, likelihood, first)
    outcome = first
    if decision is not None:
        outcome = run_step(decision.predictive, state, dataset, likelihood, rng, start)
        if isinstance(outcome, Failure) and outcome.zero_likelihood:   # the paths' restart found nothing
            outcome = first if decision.otherwise is None else run_step(decision.otherwise, start_state, dataset,
                                                                        likelihood, rng, start)
    if isinstance(outcome, Failure):
        raise outcome.error
    check_step(outcome.state, outcome.record)  # what the run store re-opens (one definition: OUTPUTS)
    return outcome.state, outcome.record


class _SequentialSampler:
    """The driver of SMC and SEMC: holds the state, calls :func:`assimilate`, keeps the
    records. The two differ only in their default moves.

    Parameters
    ----------
    prior : JointPrior or object with ``logpdf`` and ``sample``
    kernel : MarkovKernel
    loglike : callable ``(theta (N, d), dataset) -> (N,)``
    n_samples : int
        Number of particles ``N`` (at least ``2 d`` for the stretch move).
    rng : int or numpy.random.Generator
    moves : Stretch or RandomWalk, optional
        The MCMC moves and their schedule (:mod:`seqbayes.moves`): SEMC's default ``Stretch()`` (Algorithm 2),
        SMC's ``RandomWalk()`` (Algorithm 4).
    tempering : Adaptive or Single
        How the likelihood enters a step and when the stages resample (:mod:`seqbayes.core.tempering`).
    evidence : Importance or PathEvidence
        The evidence increment's estimator (:mod:`seqbayes.predictive.evidence`); both estimates are recorded.
    predictive : predictive component, optional
        Each step's prior: ``None`` lets the kernel choose (:class:`~seqbayes.predictive.base.Auto`); else
        ``Transition()``, ``KernelDensity()``, ``History(running=...)`` or ``SMC2(inner=...)``.
    remedy : PathSpace, Conflict or None
        What a prior-data conflict calls for: the path-space remedy (:class:`~seqbayes.predictive.transition.PathSpace`,
        the default), or ``Conflict()`` / ``None``: detected and reported only.
    executor : object with ``map``, optional
        Evaluates likelihood chunks in parallel (a ``concurrent.futures`` executor, a ``dask.distributed.Client``,
        :class:`~seqbayes.parallel.ProcessWorkers`, or :class:`~seqbayes.parallel.Workers` with a chunk count).
    blas_threads : int or None
        BLAS threads inside :meth:`update` (1: the hot products have an inner dimension of d, where threads cost
        3x; ``None`` leaves BLAS as it is).

    The flat settings of a TOML ``[sampler]`` table or of earlier versions map onto the components with
    :func:`~seqbayes.engine.settings.from_flat`: ``SEMC(prior, kernel, loglike, **from_flat(tempering_ess=0.3))``.
    """

    _moves = Moves

    def __init__(self, prior: JointPrior, kernel: MarkovKernel, loglike: LogLikelihood, n_samples: int = 1000,
                 rng: int | np.random.Generator | None = None, *, moves: Moves | None = None,
                 tempering: Tempering = Adaptive(), evidence: Any = Importance(), predictive: Any = None,
                 remedy: Conflict | None = PathSpace(), executor: Any = None, blas_threads: int | None = 1):
        if not (hasattr(prior, "logpdf") and hasattr(prior, "sample")):
            raise TypeError("prior: expected an object with logpdf(theta) and sample(n, rng)")
        if not isinstance(kernel, MarkovKernel):
            raise TypeError(f"kernel: expected a seqbayes.MarkovKernel, got {type(kernel).__name__}")
        if not callable(loglike):
            raise TypeError("loglike: expected a callable loglike(theta (N, d), dataset) -> (N,)")
        if executor is not None and not isinstance(executor, Workers):
            if not hasattr(executor, "map"):
                raise TypeError("executor: expected an object with a map method (concurrent.futures or dask Client)")
            executor = Workers(executor)
        if blas_threads is not None and (isinstance(blas_threads, bool) or int(blas_threads) != blas_threads
                                         or blas_threads < 1):
            raise ValueError(f"blas_threads: expected an integer >= 1 or None, got {blas_threads!r}")
        self._blas_threads = blas_threads
        if isinstance(n_samples, bool) or not isinstance(n_samples, (int, np.integer, float)) \
                or int(n_samples) != n_samples or n_samples < 2:
            raise ValueError(f"n_samples: must be an integer >= 2, got {n_samples!r}")
        config = SamplerConfig(int(n_samples), self._moves() if moves is None else moves, tempering, evidence,
                               predictive, Conflict() if remedy is None else remedy)
        self._rng = as_generator(rng)
        initial = as_samples(prior.sample(int(n_samples), self._rng), name="prior.sample(n, rng)")
        dim = initial.shape[1]
        if initial.shape[0] != int(n_samples):
            raise ValueError(f"prior.sample: returned {initial.shape[0]} rows for n = {n_samples}")
        if dim != kernel.dim:
            raise ValueError(f"kernel: has {kernel.dim} parameters but the prior has {dim}")
        if not np.all(np.isfinite(initial)):
            raise ValueError("prior.sample: returned non-finite samples")
        self.config = config.resolved(kernel, dim)   # what "auto" chose, the moves' Eq. (10) target
        component = self.config.predictive
        self.problem = Problem(prior, kernel, loglike, support_of(prior, dim), executor,
                               getattr(component, "running", None), getattr(component, "inner", None))
        self.names = tuple(getattr(prior, "names", [f"theta_{j}" for j in range(dim)]))
        step_size = float(self.config.moves.initial_step_size)
        if component.method == "smc2":
            split = nested_split(kernel)
            component.inner.check(self.problem, split)
            self._state = start_nested(prior, component.inner.outer_columns(split, dim), initial, step_size)
        else:
            self._state = SamplerState(step=0, particles=initial, log_weights=np.full(int(n_samples), -np.log(n_samples)),
                                       prior=prior, log_evidence=0.0, step_size=step_size)
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
        before = self._state
        bar = None
        if progress and self.problem.executor is None:
            from tqdm.auto import tqdm

            bar = tqdm(desc=f"step {self._state.step + 1}", unit="eval", leave=leave)
        try:
            with blas_limit(self._blas_threads):
                state, record = assimilate(self._state, dataset, self.problem, self.config, self._rng,
                                           on_evaluated=None if bar is None else bar.update)
            if bar is not None:
                bar.set_postfix(ESS=f"{record.info.ess:.0f}", logZ=f"{record.info.log_evidence:.2f}")
        finally:
            if bar is not None:
                bar.close()
        self._state = state
        self._records.append(record)
        info = record.info
        if info.nested.inner_ess < 0.05:
            warnings.warn(f"step {info.step}: SMC^2's inner particle filters are degenerate (mean ESS "
                          f"{100 * info.nested.inner_ess:.1f} % of n_inner = {self.problem.inner_filter.n_inner}): the data put the "
                          f"drifting parameters far from where the kernel predicts them, or pin them far more tightly "
                          f"than its noise, so the likelihood estimates are noisy and the moves rarely accept. A "
                          f"kernel the data contradict loses evidence anyway; otherwise raise n_inner, declare a "
                          f"KalmanInnerFilter if the model is linear-Gaussian in them, or for a short run use "
                          f"predictive=Transition() ({documented('core')})",
                          InnerFilterWarning, stacklevel=3)  # user -> update/run -> _update
        # either half of the diagnostic: the posterior mean's shift, or a posterior carried by a few of the predictive
        # mixture's components (the ancestor ESS, which catches conflicts the shift misses; docs/prior_data_conflict.md)
        threshold, conflicted = self.config.remedy.threshold, info.conflict
        tail = conflicted.ancestor_ess < self.config.remedy.ancestor_ess * self.config.n_samples
        if conflicted.prior_data_conflict > threshold or tail:
            conflict = step_conflict(before.prior_draws, before.log_weights, record.posterior, record.log_weights,
                                     self.problem.support)
            far = ", ".join(f"{name} {value:.1f}" for name, value in zip(self.names, conflict)
                            if value > threshold) or \
                f"{self.names[conflicted.conflict_parameter]} {conflicted.prior_data_conflict:.1f}"
            if np.isfinite(conflicted.ancestor_ess):
                far += (f"; {conflicted.ancestor_ess:.0f} of the {self.config.n_samples} previous posterior "
                        f"particles carry it (StepInfo.ancestor_ess)")
            remedy = (f"; assimilated on the path space of the last {conflicted.path_steps} states, whose target is "
                      f"the model's exact one (StepInfo.path_steps)" if conflicted.path_steps else
                      "; the predictive mixture's tail is a few particles there, so the sampler may be unreliable "
                      f"(the path-space remedy is off or does not apply; {documented('prior_data_conflict')})")
            warnings.warn(f"step {info.step}: prior-data conflict: the posterior lies far in the tail of "
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
        meta = {"sampler": type(self).__name__, "config": {f.name: repr(getattr(self.config, f.name))
                                                             for f in fields(self.config)},
                "kernel": self.problem.kernel.describe(),
                "prior": self.problem.prior.describe() if hasattr(self.problem.prior, "describe") else repr(self.problem.prior)}
        return Result(self.names, tuple(self._records), meta)


class SEMC(_SequentialSampler):
    """Sequential Ensemble Monte Carlo (Algorithm 2): the stretch move with an adaptive step size
    (``moves=Stretch(...)``). Parameters as the driver's (:class:`SMC` shares them; ``moves`` may be any).

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

    _moves = Stretch


class SMC(_SequentialSampler):
    """Sequential Monte Carlo (Algorithm 4): the Gaussian random walk with the weighted covariance
    (``moves=RandomWalk(...)``). Parameters as :class:`SEMC`'s."""

    _moves = RandomWalk


import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from collections.abc import Callable, Iterable, Sequence
    from typing import Any

    from ..predictive.smc2 import KalmanInnerFilter
    from ..priors import JointPrior

    #: ``loglike(theta (N, d), dataset) -> (N,)``
    LogLikelihood = Callable[[np.ndarray, Any], np.ndarray]
