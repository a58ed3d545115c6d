"""The drivers :class:`SMC` and :class:`SEMC`: they hold the current :class:`~seqbayes.core.state.SamplerState`
and call :func:`~seqbayes.engine.pipeline.assimilate`."""

from __future__ import annotations

import warnings
from dataclasses import fields

import numpy as np

from ..kernels import MarkovKernel
from ..core.tempering import Adaptive, Tempering
from ..moves import Moves, RandomWalk, Stretch
from ..parallel import Workers
from ..predictive.evidence import Importance
from ..predictive.paths import Conflict, PathSpace
from ..predictive.smc2 import nested_split, start_nested
from ..priors import as_samples, support_of
from ..results import Result, StepInfo, StepRecord
from ..rng import as_generator, generator_from_state, generator_state
from ..core.errors import InnerFilterWarning, PriorDataConflictWarning, documented
from .forecast import forecast
from .pipeline import assimilate
from .settings import SamplerConfig
from ..core.state import Problem, SamplerState
from ..core.tempering import blas_limit
from ..predictive.particle import step_conflict

__all__ = ["SMC", "SEMC"]


class _SequentialSampler:
    """The driver of SMC and SEMC: holds the state, calls :func:`~seqbayes.engine.pipeline.assimilate`, keeps the
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
        What a prior-data conflict calls for: the path-space remedy (:class:`~seqbayes.predictive.paths.PathSpace`,
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
        executor, n_chunks = (executor.executor, executor.n_chunks) if isinstance(executor, Workers) else (executor, None)
        if executor is not None and not hasattr(executor, "map"):
            raise TypeError("executor: expected an object with a map method (concurrent.futures or dask Client)")
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
        self.problem = Problem(prior, kernel, loglike, support_of(prior, dim), executor, n_chunks,
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
        prior = (self._state.prior_draws, self._state.log_weights)
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
        if record.info.inner_ess < 0.05:
            warnings.warn(f"step {record.info.step}: SMC^2's inner particle filters are degenerate (mean ESS "
                          f"{100 * record.info.inner_ess:.1f} % of n_inner = {self.problem.inner_filter.n_inner}): the data put the "
                          f"drifting parameters far from where the kernel predicts them, or pin them far more tightly "
                          f"than its noise, so the likelihood estimates are noisy and the moves rarely accept. A "
                          f"kernel the data contradict loses evidence anyway; otherwise raise n_inner, declare a "
                          f"KalmanInnerFilter if the model is linear-Gaussian in them, or for a short run use "
                          f"predictive=Transition() ({documented('core')})",
                          InnerFilterWarning, stacklevel=3)  # user -> update/run -> _update
        # either half of the diagnostic: the posterior mean's shift, or a posterior carried by a few of the predictive
        # mixture's components (the ancestor ESS, which catches conflicts the shift misses; docs/prior_data_conflict.md)
        threshold = self.config.remedy.threshold
        tail = record.info.ancestor_ess < self.config.remedy.ancestor_ess * self.config.n_samples
        if record.info.prior_data_conflict > threshold or tail:
            conflict = step_conflict(*prior, record.posterior, record.log_weights, self.problem.support)
            far = ", ".join(f"{name} {value:.1f}" for name, value in zip(self.names, conflict)
                            if value > threshold) or \
                f"{self.names[record.info.conflict_parameter]} {record.info.prior_data_conflict:.1f}"
            if np.isfinite(record.info.ancestor_ess):
                far += (f"; {record.info.ancestor_ess:.0f} of the {self.config.n_samples} previous posterior "
                        f"particles carry it (StepInfo.ancestor_ess)")
            remedy = (f"; assimilated on the path space of the last {record.info.path_steps} states, whose target is "
                      f"the model's exact one (StepInfo.path_steps)" if record.info.path_steps else
                      "; the predictive mixture's tail is a few particles there, so the sampler may be unreliable "
                      f"(the path-space remedy is off or does not apply; {documented('prior_data_conflict')})")
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
