"""The exact prior of static parameters: the initial prior times the past datasets' likelihoods
(:class:`HistoryPrior`, as IBIS), with running statistics for a bounded cost per update."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.likelihood import kept_copy
from ..core.state import stored_as
from ..moves.base import MoveTally
from .evidence import PathEvidence
from .particle import ExactPrior, ParticlePredictive, rejuvenate_deferred

__all__ = ["History", "HistoryPrior", "RunningStatistics", "ExactHistory"]


@dataclass(frozen=True, eq=False)
class RunningStatistics:
    """A likelihood whose product over datasets depends on them only through additive statistics.

    With it the history prior evaluates ``prod_{k<s} L_k(theta)`` in one call whatever ``s``, so
    an update costs the same at step 1000 as at step 10 (the re-evaluation of the past that IBIS
    pays grows linearly with ``s`` otherwise).

    Parameters
    ----------
    summarise : callable ``dataset -> dict[str, array]``
        The statistics of one dataset; the statistics of several are their sums (e.g. for a
        linear-Gaussian model ``X^T X``, ``X^T y``, ``y^T y`` and the row count).
    loglike : callable ``(theta (N, d), statistics) -> (N,)``
        ``sum_k log L_k(theta)`` from the summed statistics of datasets ``k``.

    Examples
    --------
    >>> import numpy as np
    >>> stats = RunningStatistics(lambda y: {"n": np.array(y.size), "sum": y.sum(), "sq": y @ y},
    ...                           lambda theta, t: -0.5 * (t["sq"] - 2 * theta[:, 0] * t["sum"] + t["n"] * theta[:, 0] ** 2))
    >>> total = stats.add(stats.add(None, np.array([1.0, 2.0])), np.array([3.0]))
    >>> float(total["sum"]), int(total["n"])
    (6.0, 3)
    """

    summarise: object
    loglike: object

    def __post_init__(self):
        if not (callable(self.summarise) and callable(self.loglike)):
            raise TypeError("RunningStatistics: summarise and loglike must be callables")

    def add(self, summary: dict, dataset: Any) -> dict:
        """``summary`` (``None`` for none yet) plus the statistics of ``dataset``."""
        new = self.summarise(dataset)
        if not isinstance(new, dict) or not new:
            raise TypeError("history.summarise: must return a non-empty dict of arrays")
        new = {key: np.asarray(value, dtype=float) for key, value in new.items()}
        if summary is None:
            return new
        if set(summary) != set(new):
            raise ValueError(f"history.summarise: returned keys {sorted(new)}, earlier datasets gave {sorted(summary)}")
        return {key: summary[key] + new[key] for key in summary}


@stored_as("history", "state_log_prior", needs_datasets=True, dims={"state_log_prior": ("sample",)})
@dataclass(frozen=True, eq=False)
class HistoryPrior:
    """The exact prior of step ``s`` for static parameters: ``p_0(theta) prod_{k<s} L_k(theta) / Z_{1:s-1}``.

    Parameters
    ----------
    initial : object with ``logpdf``
        The initial prior ``p_0``.
    datasets : tuple
        The datasets ``D^1 .. D^{s-1}`` already assimilated.
    log_normaliser : float
        ``log Z_{1:s-1}``, the running log-evidence estimate, so that the density is
        normalised up to that estimate's error (an importance estimate of the next
        increment then estimates the whole ``log Z_{1:s}`` afresh).
    running : RunningStatistics, optional
        Evaluates the past in one call from ``summary`` instead of one call per dataset.
    summary : dict, optional
        The summed statistics of ``datasets`` (with ``running``).
    """

    initial: object
    datasets: tuple
    log_normaliser: float
    running: RunningStatistics | None = None
    summary: dict | None = None

    @classmethod
    def start(cls, initial, running, dataset, log_normaliser) -> "HistoryPrior":
        """The prior after the first dataset."""
        return cls(initial, (), 0.0, running, None).extended(dataset, log_normaliser)

    def extended(self, dataset, log_normaliser) -> "HistoryPrior":
        """The prior after one more dataset (a copy is kept: callers reuse buffers)."""
        kept = kept_copy(dataset)
        summary = self.running.add(self.summary, kept) if self.running is not None else None
        return HistoryPrior(self.initial, self.datasets + (kept,), float(log_normaliser), self.running, summary)

    def to_arrays(self, log_prior) -> dict:
        """The run store's arrays: ``state_log_prior (N,)``, the prior's values at the particles (the density itself
        is rebuilt from the initial prior and the datasets)."""
        return {"state_log_prior": log_prior}

    @classmethod
    def from_arrays(cls, arrays: dict, context: dict):
        """``(prior, log_prior)`` from :meth:`to_arrays` and ``context``: the ``initial_prior``, the ``datasets``
        assimilated and the ``log_evidence`` after them."""
        return (cls(context["initial_prior"], tuple(context["datasets"]), context["log_evidence"]),
                np.array(arrays["state_log_prior"]))

    def logpdf(self, theta, loglike, summary_loglike=None) -> np.ndarray:
        """Log density at ``theta (m, d)``; returns ``(m,)``.

        Parameters
        ----------
        theta : (m, d) array
        loglike : callable ``(theta (k, d), dataset) -> (k,)``
            Used per past dataset; rows that reach ``-inf`` are not evaluated on later datasets.
        summary_loglike : callable ``(theta (k, d), summary) -> (k,)``, optional
            Used instead, in one call, when the prior has running statistics.
        """
        out = np.asarray(self.initial.logpdf(theta), dtype=float) - self.log_normaliser
        if self.running is not None and self.summary is not None:
            alive = np.isfinite(out)
            if alive.any():
                out[alive] += (summary_loglike or self.running.loglike)(theta[alive], self.summary)
            return out
        for dataset in self.datasets:
            alive = np.isfinite(out)
            if alive.all():
                out = out + loglike(theta, dataset)
            elif alive.any():
                out[alive] += loglike(theta[alive], dataset)
            else:
                break
        return out

@dataclass(frozen=True)
class History:
    """The exact prior of static parameters as each step's prior (the default when every parameter is static):
    ``p_0 prod_{k<s} L_k / Z_{1:s-1}`` (:class:`HistoryPrior`, as IBIS).

    Parameters
    ----------
    running : RunningStatistics, optional
        The likelihood's additive statistics, so that the prior evaluates every past dataset in one call (a bounded
        cost per update); without them each past dataset is evaluated anew.
    """

    running: RunningStatistics | None = None

    method = "history"

    def __post_init__(self):
        if self.running is not None and not isinstance(self.running, RunningStatistics):
            raise TypeError("running: expected a seqbayes.RunningStatistics(summarise, loglike)")

    def resolve(self, kernel) -> "History":
        """This predictive, checked against ``kernel`` (every parameter static)."""
        if not kernel.is_static:
            raise ValueError("predictive: History (the exact prior p_0 x past likelihoods) needs a kernel whose every "
                             "parameter is Static; with process noise use Transition()")
        return self

    def predictive(self, state, problem, config):
        return ExactHistory(problem, config, self.method), state


class ExactHistory(ParticlePredictive):
    """The exact prior of static parameters as a step's predictive: the last posterior itself, its particles
    kept with their weights and their prior values (:class:`HistoryPrior`).

    IBIS's schedule: the particles are resampled and moved only when the ESS falls below ``ess_threshold``
    (a move re-evaluates every past dataset, so spacing the moves out as the posterior concentrates bounds
    the amortised cost per update); with ``move_every_stage=False`` that resample-move waits for the next
    dataset (:func:`~seqbayes.predictive.particle.rejuvenate_deferred`). A step that kept its particles takes its
    evidence from the weights, which are the exact prior's importance weights.
    """

    def __init__(self, problem, config, method: str = "history"):
        super().__init__(problem, config, method)
        self.deferred = config.moves.every_stage is False

    def exact_prior(self, state) -> bool:
        return isinstance(state.prior, HistoryPrior)  # the initial prior at the first step

    def moves_every_stage(self) -> bool:
        """The moves' ``every_stage``; when ``None``, False: moves only after a resampling."""
        every = self.config.moves.every_stage
        return False if every is None else every

    def prior_logpdf(self, state, likelihood, rng):
        if self.exact_prior(state):
            return ExactPrior(lambda theta: state.prior.logpdf(theta, likelihood.loglike_on, likelihood.summary_loglike))
        return ExactPrior(state.prior.logpdf)

    def start(self, state, prior_logpdf, rng):
        moves = MoveTally(step_size=state.step_size)
        if not self.exact_prior(state):
            return state.particles, state.log_weights, None, moves, False, None
        if not self.deferred:
            return state.particles, state.log_weights, state.log_prior, moves, False, None
        particles, log_weights, log_prior, moves, rejuvenated, labels = rejuvenate_deferred(
            state, self.problem, self.config, prior_logpdf, moves, rng)
        return particles, log_weights, log_prior, moves, rejuvenated, labels if rejuvenated else None

    def evidence(self, moves):
        # a step that kept its particles needs no fitted proposal (which would re-evaluate the past, at O(s) cost)
        return self.config.evidence if moves.stats.n_proposed != 0 else PathEvidence()

    def next_prior(self, state, cloud, dataset, log_increment, log_evidence, rng):
        """This posterior, exactly: the particles and their weights are kept, with their prior values."""
        density = state.prior.extended(dataset, log_evidence) if self.exact_prior(state) else \
            HistoryPrior.start(self.problem.prior, self.problem.history, dataset, log_evidence)
        next_log_prior = cloud.components[:, 0] + cloud.components[:, 1] - float(log_increment)  # no +inf: no NaN
        return density, cloud.particles, next_log_prior


import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from typing import Any
