"""SMC^2's budgeted rejuvenation (seqbayes.predictive.pmmh), its cost fields and warnings, and the
Rao-Blackwellised drifting moments (issue 23)."""

import numpy as np
import pytest

from seqbayes.engine.settings import from_flat
from seqbayes import SMC
from seqbayes.core.errors import InnerFilterWarning
from seqbayes.models.linear_gaussian import LinearGaussianStateSpace
from seqbayes.moves import SweepStats
from seqbayes.predictive.pmmh import (MOVE_BUDGET, RESTORE_LIMIT, Budget, Refilter, Rejuvenation, distinct_ess,
                                     outer_logpdf, rejuvenate, run_inner)
from seqbayes.predictive.smc2 import (KalmanInnerFilter, NestedState, ParticleInnerFilter, nested_moments,
                                      nested_split, nested_state_arrays, nested_state_from_arrays,
                                      warn_rejuvenation)


@pytest.fixture(scope="module")
def mixed():
    problem = LinearGaussianStateSpace.mixed()
    data, _ = problem.simulate(40, rng=21)
    return problem, data


def test_nested_moments_are_those_of_every_inner_particle():
    """The Rao-Blackwellised moments equal the weighted moments of all N x M inner particles (law of total variance)."""
    rng = np.random.default_rng(0)
    n, m = 7, 5
    posterior = rng.normal(size=(n, 2))
    log_weights = rng.normal(size=n)
    cloud = {"x": rng.normal(size=(n, m, 1)), "log_w": rng.normal(size=(n, m))}
    mean, sd = nested_moments(posterior, log_weights, ParticleInnerFilter(m).moments(cloud), np.array([1]))
    w_outer = np.exp(log_weights) / np.exp(log_weights).sum()
    w_inner = np.exp(cloud["log_w"]) / np.exp(cloud["log_w"]).sum(axis=1, keepdims=True)
    w = (w_outer[:, None] * w_inner).ravel()
    x = cloud["x"].ravel()
    assert mean[1] == pytest.approx(w @ x, abs=1e-12)
    assert sd[1] == pytest.approx(np.sqrt(w @ (x - w @ x) ** 2), abs=1e-12)
    assert mean[0] == pytest.approx(w_outer @ posterior[:, 0], abs=1e-12)   # the static column from the draws


def test_update_cost_stays_within_the_budget_and_the_amortised_cost_is_reported(mixed):
    problem, data = mixed
    n = 100
    sampler = SMC(problem.prior, problem.kernel, problem.loglike, n_samples=n, rng=1, **from_flat("SMC", inner_filter=KalmanInnerFilter(problem.observe), move_budget=MOVE_BUDGET))
    infos = [sampler.update(y) for y in data]
    evals = np.array([i.n_loglike_evals for i in infos])
    steps = np.arange(1, len(data) + 1)
    # an update that neither tempered nor resampled: the advance (N), the moves' budget (MOVE_BUDGET N) and at most
    # one re-run over s datasets beyond it (a tempered update completes its moves, a resampling first restores the ESS)
    steady = np.array([i.n_stages == 1 and not i.resampled for i in infos])
    steady[0] = False
    assert steady.sum() > 20
    assert np.all(evals[steady] <= (MOVE_BUDGET + 1) * n + steps[steady]), evals
    assert any(i.pending_moves for i in infos)      # late rejuvenations did spread over updates
    np.testing.assert_allclose([i.amortised_evals for i in infos], np.cumsum(evals) / steps)
    moved = [i for i in infos[1:] if i.n_proposed]
    assert moved and all(0 < i.pmmh_acceptance <= 1 for i in moved)


def test_pending_moves_survive_the_state_arrays(mixed):
    """A state with moves still queued rebuilds from its arrays and resumes bit for bit."""
    problem, data = mixed

    def fresh():
        return SMC(problem.prior, problem.kernel, problem.loglike, n_samples=100, rng=4, **from_flat("SMC", inner_filter=KalmanInnerFilter(problem.observe), move_budget=MOVE_BUDGET))

    sampler = fresh()
    for s, y in enumerate(data[:30], start=1):
        info = sampler.update(y)
        if info.pending_moves and s > 5:
            break
    assert info.pending_moves
    state = sampler.state
    arrays = nested_state_arrays(state)
    rebuilt = nested_state_from_arrays(arrays, state.datasets, state.guides[:-1])
    assert isinstance(rebuilt, NestedState)
    np.testing.assert_array_equal(rebuilt.pending.queue, state.pending.queue)
    assert (rebuilt.pending.sweeps_left, rebuilt.pending.n_proposed, rebuilt.pending.n_accepted,
            rebuilt.n_evals_total) == (state.pending.sweeps_left, state.pending.n_proposed,
                                       state.pending.n_accepted, state.n_evals_total)
    other = fresh()
    other._state = rebuilt
    rng_state = sampler._rng.bit_generator.state
    other._rng.bit_generator.state = rng_state
    for y in data[s:s + 5]:
        a, b = sampler.update(y), other.update(y)
        assert a.log_evidence == b.log_evidence and a.n_loglike_evals == b.n_loglike_evals
    np.testing.assert_array_equal(sampler.state.outer, other.state.outer)


@pytest.mark.parametrize("surrogate", [None, "quadratic"])
def test_a_partial_rejuvenation_keeps_a_weighted_sample_of_the_exact_posterior(mixed, surrogate):
    """PMMH on a permutation-chosen subset of weighted particles: the static parameters' weighted mean and sd stay
    those of the exact (Kalman) posterior. Particles are drawn from a Gaussian 1.5x wider than it and weighted; the
    Kalman inner filter makes the likelihood exact. Tolerance: 5 Monte Carlo standard errors of the weighted
    estimate (sd / sqrt(ESS)). With ``surrogate="quadratic"`` every proposal is first screened by a quadratic fitted
    to the particles' log targets (delayed acceptance), and only the survivors re-run their inner filters."""
    problem, data = mixed
    data = data[:12]
    sampler = SMC(problem.prior, problem.kernel, problem.loglike, n_samples=4000, rng=0, **from_flat("SMC", inner_filter=KalmanInnerFilter(problem.observe), move_budget=MOVE_BUDGET, surrogate=surrogate))
    config, inner = sampler.config, sampler.problem.inner_filter
    split = nested_split(problem.kernel)
    exact = problem.exact(data)[-1]
    mean, cov = exact.mean[split[0]], exact.cov[np.ix_(split[0], split[0])]
    rng = np.random.default_rng(5)
    n = config.n_samples
    static = rng.multivariate_normal(mean, 2.25 * cov, size=n)
    likelihood = sampler_likelihood(sampler)
    past, last, cloud = run_inner(sampler.problem, inner, split, static, data, (None,) * len(data), likelihood, rng)
    prior = outer_logpdf(problem.prior, split[0], static)
    diff = static - mean
    log_q = -0.5 * np.einsum("ij,jk,ik->i", diff, np.linalg.inv(2.25 * cov), diff)
    log_weights = past + last + prior - log_q
    log_weights -= np.logaddexp.reduce(log_weights)
    components = np.column_stack([last, prior, past])
    pending = Rejuvenation().restarted(1, n)
    budget = (n // 2) * len(data)          # half a sweep
    out = rejuvenate(Refilter(sampler.problem, inner, split, data, (None,) * len(data)), config, static, log_weights,
                     cloud, components, 1.0, 1.0, pending, Budget(budget), likelihood, rng)
    moved_static, _, moved_components, stats, _, _, left = out
    assert isinstance(stats, SweepStats) and left.queue.size == n - stats.n_proposed and left.sweeps_left == 0
    assert 0.3 * n < stats.n_evaluations <= n // 2 and stats.n_accepted > 0.2 * stats.n_proposed   # the budget
    if surrogate is None:
        assert stats.n_screen_evaluations == 0 and stats.n_evaluations == stats.n_proposed
    else:   # the screen stopped some proposals before their re-run, so the budget attempted more particles
        assert stats.n_screened_out > 0.05 * stats.n_proposed
        assert stats.n_evaluations == stats.n_proposed - stats.n_screened_out
    w = np.exp(log_weights)
    ess = 1.0 / np.sum(w**2)
    sd = np.sqrt(np.diag(cov))
    for values in (static, moved_static):
        got = w @ values
        assert np.all(np.abs(got - mean) < 5 * sd / np.sqrt(ess)), (got, mean, sd, ess)
        got_sd = np.sqrt(w @ (values - got) ** 2)
        assert np.all(np.abs(got_sd / sd - 1) < 5 / np.sqrt(2 * ess)), (got_sd, sd)
    # the cached components of the moved particles are those of their new values
    rows = np.flatnonzero(np.any(moved_static != static, axis=1))[:50]
    past2, last2, _ = run_inner(sampler.problem, inner, split, moved_static[rows], data, (None,) * len(data),
                                likelihood, rng)
    np.testing.assert_allclose(moved_components[rows, 0], last2, rtol=1e-10)
    np.testing.assert_allclose(moved_components[rows, 2], past2, rtol=1e-10)


def test_distinct_ess_counts_copies():
    rows = np.arange(6.0).reshape(3, 2)
    assert distinct_ess(rows) == pytest.approx(3.0)
    copies = rows[[0, 0, 0, 1]]                       # groups of 3 and 1: 16 / (9 + 1)
    assert distinct_ess(copies) == pytest.approx(1.6)


def test_restoring_the_ess_after_a_resampling_goes_beyond_the_budget(mixed):
    """A cloud of copies (50 values, 4 copies each) with a budget of 20 particles' re-runs: with ``restore`` the moves
    go on beyond the budget, in batches of RESTORE_BATCH N, until the copies' ESS is back at ``restore N`` or they
    have spent RESTORE_LIMIT times the budget; without it they stop at the budget."""
    problem, data = mixed
    data = data[:5]
    sampler = SMC(problem.prior, problem.kernel, problem.loglike, n_samples=200, rng=0, **from_flat("SMC", inner_filter=KalmanInnerFilter(problem.observe)))
    config, inner = sampler.config, sampler.problem.inner_filter
    split = nested_split(problem.kernel)
    rng = np.random.default_rng(3)
    exact = problem.exact(data)[-1]
    mean, cov = exact.mean[split[0]], exact.cov[np.ix_(split[0], split[0])]
    static = np.repeat(rng.multivariate_normal(mean, cov, size=50), 4, axis=0)
    likelihood = sampler_likelihood(sampler)
    past, last, cloud = run_inner(sampler.problem, inner, split, static, data, (None,) * len(data), likelihood, rng)
    components = np.column_stack([last, outer_logpdf(problem.prior, split[0], static), past])
    log_weights = np.full(200, -np.log(200))
    assert distinct_ess(static) == pytest.approx(50.0)
    budget = 20 * len(data)
    for restore in (0.0, 0.6):
        pending = Rejuvenation().restarted(config.moves.max_sweeps, 200)
        out = rejuvenate(Refilter(sampler.problem, inner, split, data, (None,) * len(data)), config, static,
                         log_weights, cloud, components, 1.0, 1.0, pending, Budget(budget, restore=restore), likelihood,
                         rng)
        moved, stats, left = out[0], out[3], out[6]
        if not restore:
            assert stats.n_proposed == 20
        else:
            assert stats.n_proposed > 20 and stats.n_proposed % 20 == 0                  # batches of 0.1 N
            assert stats.n_proposed * len(data) <= RESTORE_LIMIT * budget + 20 * len(data)   # the limit, one batch over
            assert distinct_ess(moved) >= 0.6 * 200 or stats.n_proposed * len(data) >= RESTORE_LIMIT * budget
            assert distinct_ess(moved) > distinct_ess(static) + 10
        assert left.pending                  # the rest (the stage rule's sweeps) waits for later updates


def sampler_likelihood(sampler):
    from seqbayes.core.likelihood import ValidatedLikelihood

    return ValidatedLikelihood(sampler.problem.loglike, None, 1)


def test_a_low_acceptance_warns_and_says_what_to_change():
    with pytest.warns(InnerFilterWarning, match=r"accepted 12 % .* raise n_inner \(now 100"):
        warn_rejuvenation(200, 0.12, 0.5, 180, 100)
    with pytest.warns(InnerFilterWarning, match="KalmanInnerFilter"):
        warn_rejuvenation(200, 0.12, 0.05, 180, 100)
    with pytest.warns(InnerFilterWarning, match=r"accepted 12 % of proposals so far in the rejuvenation that the move "
                                                r"budget spreads over updates"):
        warn_rejuvenation(200, 0.12, 0.5, 180, 100, running=True)
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        warn_rejuvenation(200, 0.3, 0.5, 180, 100)
        warn_rejuvenation(200, float("nan"), 0.5, 180, 100)


@pytest.mark.slow
def test_the_store_keeps_the_moments_and_status_reports_the_cost(tmp_path):
    from _user_model import decay_tables, write_config, write_model

    from seqbayes.store import RunStore, load_config

    write_model(tmp_path, "budgetmodel")
    cfg = load_config(write_config(tmp_path / "run.toml", "budgetmodel", func="loglike", sampler="SMC", n_samples=80,
                                   seed=3, kernel='a = { type = "drift", rate = -0.05, noise_std = 0.02 }'))
    store = RunStore.create(tmp_path / "run.nc", cfg)
    for table in decay_tables([1.5, 1.45, 1.4], np.linspace(0, 3, 15), 0.1, 0):
        store.assimilate(table)
    loaded = RunStore.open(tmp_path / "run.nc")
    for a, b in zip(store.result.steps, loaded.result.steps):
        assert a.moments is not None
        np.testing.assert_array_equal(a.mean(), b.mean())
        np.testing.assert_array_equal(a.std(), b.std())
    last = loaded.result.steps[-1]
    w = np.exp(last.log_weights - np.logaddexp.reduce(last.log_weights))
    assert not np.array_equal(last.mean(), w @ last.posterior)      # the drifting column is Rao-Blackwellised
    evals = [r.info.n_loglike_evals for r in loaded.result.steps]
    text = loaded.status()
    assert f"likelihood evaluations: last update {evals[-1]:,}, amortised {sum(evals) / 3:,.0f} per update" in text
    assert loaded.result.steps[-1].info.amortised_evals == pytest.approx(sum(evals) / 3)


@pytest.mark.slow   # 25 SMC^2 updates at N = 200: about 5 s of CPU
def test_a_running_rejuvenation_with_a_low_acceptance_warns_before_it_concludes():
    # Two inner particles make the likelihood estimates so noisy that PMMH acceptance falls towards 0 as s grows,
    # and a budget of one N M per update spreads each rejuvenation over updates, so none concludes: the warning
    # comes from the running acceptance, at steps whose recorded acceptance is below the threshold
    import warnings

    import seqbayes
    from seqbayes.models.linear_gaussian import LinearGaussianProblem
    from seqbayes.predictive.smc2 import LOW_ACCEPTANCE, ParticleInnerFilter

    problem = LinearGaussianProblem()
    datasets, _ = problem.simulate(20, rng=3)
    kernel = seqbayes.MarkovKernel([seqbayes.Drift(0.0, noise_std=0.05), seqbayes.Static()])
    sampler = seqbayes.SMC(problem.prior, kernel, problem.loglike, n_samples=200, rng=1, **from_flat("SMC", inner_filter=ParticleInnerFilter(2, n_pilot=200), move_budget=1))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        infos = [sampler.update(d) for d in datasets]
    warned = [int(str(w.message).split(":")[0].split()[1]) for w in caught
              if issubclass(w.category, InnerFilterWarning) and "so far in the rejuvenation" in str(w.message)]
    assert warned, [round(i.pmmh_acceptance, 3) for i in infos]
    for step in warned:
        info = infos[step - 1]
        assert info.pmmh_acceptance < LOW_ACCEPTANCE and info.pending_moves > 0, (step, info.pmmh_acceptance)
