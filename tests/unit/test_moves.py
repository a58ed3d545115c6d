"""Moves: the shared accept/reject, the stretch move and the Gaussian move."""

import numpy as np
import pytest

from seqbayes.moves import (GaussianMove, StretchMove, combine, metropolis_accept, next_step_size,
                            paper_target_acceptance, stretch_sweep)


def test_metropolis_accept_handles_infinities():
    rng = np.random.default_rng(0)
    current = np.array([0.0, -np.inf, -np.inf, 0.0, 0.0])
    proposal = np.array([-np.inf, 0.0, -np.inf, np.nan, 10.0])
    accept = metropolis_accept(current, proposal, np.zeros(5), rng)
    np.testing.assert_array_equal(accept, [False, True, False, False, True])


def test_metropolis_accept_rate_matches_ratio():
    rng = np.random.default_rng(1)
    n = 200_000
    accept = metropolis_accept(np.zeros(n), np.full(n, np.log(0.3)), np.zeros(n), rng)
    assert accept.mean() == pytest.approx(0.3, abs=5 * np.sqrt(0.21 / n))


def test_stretch_proposal_distribution():
    # lambda ~ g on [1/u, u] with density ~ 1/sqrt(lambda): E[lambda] = (u^1.5 - u^-1.5) / (3 (sqrt u - 1/sqrt u))
    rng = np.random.default_rng(2)
    u, n = 3.0, 200_000
    walkers = np.ones((n, 1))
    complement = np.zeros((1, 1))
    proposals, log_hastings, identical = StretchMove(u).propose(walkers, complement, rng)
    lam = proposals[:, 0]
    assert lam.min() >= 1 / u and lam.max() <= u
    expected = (u**1.5 - u**-1.5) / (3 * (np.sqrt(u) - 1 / np.sqrt(u)))
    assert lam.mean() == pytest.approx(expected, abs=5 * lam.std() / np.sqrt(n))
    np.testing.assert_allclose(log_hastings, 0.0)  # d = 1: lambda^(d-1) = 1
    assert not identical.any()


def test_stretch_sweep_rejects_outside_support_and_counts_identical_partners():
    rng = np.random.default_rng(3)
    walkers = np.zeros((10, 2))  # all identical: every partner is identical, nothing can move
    comps = np.zeros((10, 1))
    calls = []
    new, new_comps, stats = stretch_sweep(walkers, comps, lambda p: calls.append(len(p)) or np.zeros((len(p), 1)),
                                          np.ones(1), StretchMove(2.0), rng, np.array([[-1, 1], [-1, 1.0]]))
    assert stats.n_proposed == 10 and stats.n_accepted == 0 and stats.n_identical_partner == 10
    assert sum(calls) == 0  # no wasted likelihood evaluations
    # a box that excludes every proposal: nothing evaluated, nothing accepted
    walkers = np.random.default_rng(4).uniform(0.9, 1.0, size=(20, 2))
    _, _, stats = stretch_sweep(walkers, np.zeros((20, 1)), lambda p: np.zeros((len(p), 1)), np.ones(1),
                                StretchMove(5.0), rng, np.array([[0.95, 0.951], [0.95, 0.951]]))
    assert stats.n_accepted == 0


def test_gaussian_move_singular_covariance_does_not_fail():
    move = GaussianMove(np.array([[1.0, 0.0], [0.0, 0.0]]))
    proposals, log_hastings = move.propose(np.zeros((1000, 2)), np.random.default_rng(5))
    assert np.all(np.isfinite(proposals)) and np.all(log_hastings == 0)
    assert proposals[:, 0].std() == pytest.approx(1.0, rel=0.1)
    assert proposals[:, 1].std() < 1e-5


def test_combine_and_step_size_rule():
    comps = np.array([[1.0, 2.0], [-np.inf, 0.0]])
    np.testing.assert_allclose(combine(comps, [0.5, 1.0]), [2.5, -np.inf])
    assert paper_target_acceptance(4) == pytest.approx(0.2825)
    assert next_step_size(2.0, 0.0, 1.0) == pytest.approx(max(2 * np.exp(-1), 1.01))
    assert next_step_size(1.02, 0.0, 0.9) == 1.01  # Algorithm 2 line 15
    assert next_step_size(2.0, 0.6, 0.3) == pytest.approx(2 * np.exp(0.3))
