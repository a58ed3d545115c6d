"""``SMC2(strict_budget=True)``: SMC^2's move budget as a hard cap on every update, tempered ones included
(seqbayes.predictive.pmmh, issue 23). Its accuracy against the Kalman filter is in
tests/statistical/test_smc2_strict_budget.py."""

import warnings

import numpy as np
import pytest

from seqbayes.engine.settings import from_flat
from seqbayes import SMC
from seqbayes.predictive.pmmh import MOVE_BUDGET
from seqbayes.models.linear_gaussian import LinearGaussianStateSpace
from seqbayes.predictive.pmmh import RESTORE_BATCH
from seqbayes.predictive.smc2 import KalmanInnerFilter


def test_strict_budget_is_checked():
    with pytest.raises(ValueError, match="strict_budget: expected True or False"):
        from_flat("SMC", strict_budget="yes")


def test_a_strict_budget_caps_the_tempered_updates_too():
    """The first update tempers from the prior (several stages): by default it completes its moves, beyond the
    budget; with ``strict_budget`` its stages share one budget, so every update costs at most the advance (N), the
    budget (``move_budget x N``, M = 1 for the Kalman inner filter) and one restoring batch of re-runs beyond it
    (``RESTORE_BATCH x N`` particles, ``s`` evaluations each)."""
    problem = LinearGaussianStateSpace.mixed()
    data, _ = problem.simulate(6, rng=21)
    n = 200
    evals, stages = {}, {}
    for strict in (False, True):
        sampler = SMC(problem.prior, problem.kernel, problem.loglike, n_samples=n, rng=3, **from_flat("SMC", inner_filter=KalmanInnerFilter(problem.observe), strict_budget=strict))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            infos = [sampler.update(y) for y in data]
        evals[strict] = np.array([i.n_loglike_evals for i in infos])
        stages[strict] = np.array([i.n_stages for i in infos])
    steps = np.arange(1, len(data) + 1)
    cap = n + MOVE_BUDGET * n + np.ceil(RESTORE_BATCH * n) * steps
    assert stages[True][0] > 1 and stages[False][0] > 1           # the first update tempers in both runs
    assert evals[False][0] > cap[0], (evals[False], cap)           # ... and by default spends beyond the cap
    assert np.all(evals[True] <= cap), (evals[True], cap)
    assert evals[True][0] > n                                      # it did move within the cap
