"""One update of an on-line sampler: the pure function :func:`assimilate`, and the pipeline :func:`run_step`
that every predictive prior goes through (:class:`~seqbayes.predictive.particle.Predictive`).

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
"""


from __future__ import annotations

import time

from ..predictive.base import predictive_for
from ..results import StepInfo, StepRecord
from ..core.likelihood import ValidatedLikelihood, check_dataset
from ..core.state import Assimilated, Failure, Reassimilate
from .outputs import check_step
from ..predictive.particle import count_distinct

__all__ = ["assimilate", "run_step"]


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
    moves = estimate.moves
    info = StepInfo.of(
        step=state.step + 1, log_evidence_increment=float(estimate.log_increment), log_evidence=outcome.log_evidence,
        ess=float(tempered.stage_ess), resampled=bool(tempered.resampled or weighed.rejuvenated),
        acceptance_rate=moves.stats.acceptance_rate, step_size=outcome.step_size, n_virtual=moves.n_virtual,
        temperatures=tempered.temperatures,
        n_loglike_evals=likelihood.n_evals, n_nan=likelihood.n_nan, n_distinct=count_distinct(outcome.distinct),
        n_proposed=moves.stats.n_proposed, n_accepted=moves.stats.n_accepted,
        n_identical_partner=moves.stats.n_identical_partner, log_evidence_increment_path=float(tempered.log_z),
        evidence_ess=estimate.evidence_ess, n_independent_accepted=estimate.n_independent,
        n_move_evaluations=moves.stats.n_evaluations, n_screen_evaluations=moves.stats.n_screen_evaluations,
        n_screened_out=moves.stats.n_screened_out, wall_time=time.perf_counter() - start, **outcome.fields)
    record = StepRecord(info, outcome.posterior, outcome.log_weights, outcome.predictive, outcome.moments)
    return Assimilated(outcome.state, record, weighed, outcome.lagged_variance)


def assimilate(state, dataset: Any, problem: Problem, config: SamplerConfig, rng: np.random.Generator, *,
               on_evaluated: Callable[[int], None] | None = None) -> tuple[object, StepRecord]:
    """Assimilate one dataset (pure; ``state`` is not modified): :func:`run_step` through the step's predictive
    (:func:`~seqbayes.predictive.base.predictive_for`), then as its remedy decides.

    The remedy's decision is a value: ``None`` keeps the step, a :class:`~seqbayes.core.state.Reassimilate` runs the
    step again through another predictive (the path-space step, :class:`~seqbayes.predictive.paths.PathSpace`), and,
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
        The new state or record holds a value the run store would refuse (:mod:`seqbayes.engine.outputs`).
    """
    start = time.perf_counter()
    check_dataset(dataset, state.step + 1)
    likelihood = ValidatedLikelihood.for_step(problem, dataset, state.step + 1, on_evaluated)
    predictive, start_state = predictive_for(state, problem, config)
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
    check_step(outcome.state, outcome.record)  # what the run store re-opens (one definition: engine.outputs)
    return outcome.state, outcome.record


import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from collections.abc import Callable
    from typing import Any

    import numpy as np

    from ..core.state import Predictive
    from .settings import SamplerConfig
    from ..core.state import Problem, Weighed
