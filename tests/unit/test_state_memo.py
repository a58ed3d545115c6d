"""The path-space likelihood's memo (:class:`seqbayes.core.likelihood.StateMemo`): a state evaluated once against
its dataset is read back, bit for bit, and counted once; everything else is evaluated as before."""

import numpy as np
import pytest

from seqbayes.core.likelihood import StateMemo, ValidatedLikelihood, row_hashes
from seqbayes.core.state import Problem


def _likelihood():
    def loglike(theta, data):  # a zero likelihood (NaN) where theta[:, 0] < 0: the path stops there
        return np.where(theta[:, 0] < 0, np.nan, -0.5 * np.sum((theta - data) ** 2, axis=1))
    problem = Problem(None, None, loglike, np.array([[-10.0, 10.0]] * 2))
    return ValidatedLikelihood.for_step(problem, np.zeros(2), 3)


def test_memo_finds_exactly_the_stored_rows():
    memo = StateMemo()
    rows = np.random.default_rng(0).normal(size=(50, 2))
    memo.add(rows, np.arange(50.0))
    queries = np.concatenate([rows[::-1], rows[:5] + 1e-15, [[0.0, 0.0]], -0.0 * np.ones((1, 2))])
    found, values = memo.lookup(queries)
    np.testing.assert_array_equal(found, [True] * 50 + [False] * 7)
    np.testing.assert_array_equal(values[:50], np.arange(50.0)[::-1])
    assert np.isnan(values[50:]).all()
    memo.add(np.zeros((1, 2)), np.array([7.0]))   # -0.0 and 0.0 are one state
    assert memo.lookup(-0.0 * np.ones((1, 2)))[1][0] == 7.0
    assert row_hashes(np.zeros((3, 65))) is None and not StateMemo().lookup(np.zeros((3, 65)))[0].any()


@pytest.mark.parametrize("seed", [0, 1])
def test_window_likelihood_with_memo_is_bit_identical_and_evaluates_each_state_once(seed):
    rng = np.random.default_rng(seed)
    datasets = [rng.normal(size=2) for _ in range(4)]
    plain, memoised = _likelihood(), _likelihood()
    window, remembered = plain.over_window(datasets, 2), memoised.over_window(datasets, 2, memo=True)
    walkers = np.abs(rng.normal(size=(200, 8)))
    walkers[:20, 2] = -1.0                       # zero likelihood at the second state: later states not evaluated
    proposals = walkers.copy()
    start = rng.integers(4, size=200)             # a suffix redraw from a random state on, as PathPrior.resimulate
    redraw = np.repeat(np.arange(4)[None, :] >= start[:, None], 2, axis=1)
    proposals[redraw] = np.abs(rng.normal(size=redraw.sum()))
    for batch in (walkers, proposals):
        np.testing.assert_array_equal(remembered.loglike(batch), window.loglike(batch))
    states = np.concatenate([walkers, proposals]).reshape(-1, 4, 2)
    alive = np.ones(400, dtype=bool)
    distinct = 0                                 # distinct (state, dataset) pairs on paths alive up to that state
    for t in range(4):
        distinct += np.unique(states[alive, t], axis=0).shape[0]
        alive &= states[:, t, 0] >= 0
    assert memoised.n_evals == distinct < plain.n_evals
