"""The path space's stopping rule (``scaled_rounds(..., kernel_density=True)``, docs/benchmarks.md, "Oscillator at
300,000 evaluations"): rounds stop once the particles' whitened travel amounts to an independent draw, and run to
their cap when nothing moves; the independence proposal is the kernel density above ``HIGH_DIMENSION`` too."""

import numpy as np
import pytest
from scipy import stats

from seqbayes.moves import RandomWalk, Stretch
from seqbayes.moves.base import HIGH_DIMENSION
from seqbayes.moves import schedule

D = HIGH_DIMENSION + 2  # a path of six states of a two-parameter model


def gaussian_components(points):
    return stats.multivariate_normal(np.zeros(D)).logpdf(points).reshape(-1, 1)


def rounds(kernel_density, component_fn, seed=0, cap=12):
    rng = np.random.default_rng(seed)
    walkers = rng.standard_normal((1000, D))
    config = RandomWalk(scaled=True, min_sweeps=1, max_sweeps=cap)
    return walkers, schedule.scaled_rounds(config, walkers, component_fn(walkers), component_fn, np.ones(1), None,
                                           rng, kernel_density)


def test_rounds_stop_once_the_particles_have_travelled_an_independent_draw():
    # exact draws of a 12-dimensional Gaussian: the kernel density's independence sweeps accept about half the
    # proposals, so a few rounds carry every particle an independent draw's whitened distance (2 d) on average
    walkers, (position, _, stats_, n_rounds, _) = rounds(True, gaussian_components)
    assert 1 <= n_rounds <= 4
    assert np.mean(np.any(position != walkers, axis=1)) >= 0.9
    # the moves leave the target invariant: moments of 1000 draws within 5 standard errors
    assert np.all(np.abs(position.mean(axis=0)) < 5 / np.sqrt(1000))
    assert np.all(np.abs(position.var(axis=0) - 1.0) < 5 * np.sqrt(2 / 1000))


def test_rounds_run_to_their_cap_when_nothing_moves():
    calls = []

    def nowhere(points):  # the particles' own values, then zero density at every proposal: nothing is accepted
        calls.append(points.shape[0])
        return gaussian_components(points) if len(calls) == 1 else np.full((points.shape[0], 1), -np.inf)

    walkers, (position, _, stats_, n_rounds, _) = rounds(True, nowhere, cap=5)
    assert n_rounds == 5 and stats_.n_accepted == 0
    np.testing.assert_array_equal(position, walkers)


# each half of the particles is swept with the density fitted to the other half: two sweeps a round
@pytest.mark.parametrize("kernel_density, proposal", [(True, ["DefensiveProposal"] * 2), (False, ["FittedGaussian"] * 2)])
def test_the_independence_proposal_above_high_dimension(monkeypatch, kernel_density, proposal):
    seen = []
    sweep = schedule.independence_sweep

    def recording(walkers, components, component_fn, coefficients, q, rng, support):
        seen.append(type(q).__name__)
        return sweep(walkers, components, component_fn, coefficients, q, rng, support)

    monkeypatch.setattr(schedule, "independence_sweep", recording)
    rounds(kernel_density, gaussian_components, cap=1)
    assert seen == proposal


def _chain_target(beta, q=0.5, r=0.5, y=(1.5, 2.0, 2.5)):
    """A three-state random walk ``x_0 ~ N(0, 1)``, ``x_t ~ N(x_{t-1}, q^2)`` (the path prior) times
    ``prod_t N(y_t; x_t, r^2)^beta``: the path prior, the log-likelihood and the exact tempered mean and covariance."""
    import seqbayes
    from seqbayes.predictive.paths import PathPrior

    prior = seqbayes.JointPrior({"a": stats.norm(0.0, 1.0)})
    path_prior = PathPrior(prior, seqbayes.MarkovKernel([seqbayes.Drift(0.0, noise_std=q)]), 3, 1)
    y = np.asarray(y)
    innovations = np.array([[1.0, 0.0, 0.0], [-1.0, 1.0, 0.0], [0.0, -1.0, 1.0]])
    precision = innovations.T @ np.diag([1.0, q**-2, q**-2]) @ innovations + beta / r**2 * np.eye(3)
    cov = np.linalg.inv(precision)

    def loglike(x):
        return stats.norm.logpdf(y[None, :], x, r).sum(axis=1)

    return path_prior, loglike, cov @ (beta / r**2 * y), cov


def _assert_moments(walkers, mean, cov):
    n = walkers.shape[0]  # 5 standard errors of each mean and variance (the walkers' chains are independent)
    sd = np.sqrt(np.diag(cov))
    assert np.all(np.abs(walkers.mean(axis=0) - mean) < 5 * sd / np.sqrt(n))
    assert np.all(np.abs(walkers.var(axis=0) / sd**2 - 1.0) < 5 * np.sqrt(2 / n))


SWEEPS = 200


def test_the_prior_sweep_redraws_path_suffixes_and_keeps_the_tempered_target():
    # exact MH: a suffix redrawn through the kernel is accepted with (L* / L)^beta alone. From the path prior's
    # draws 30 sweeps alone reach the tempered target's exact Gaussian moments; the kept prefixes are bit for bit
    path_prior, loglike, mean, cov = _chain_target(beta=0.3)
    rng = np.random.default_rng(1)
    walkers = path_prior.sample(4000, rng)
    proposals, changed = path_prior.resimulate(walkers, rng)
    np.testing.assert_array_equal(proposals[~changed], walkers[~changed])
    assert changed[:, -1].all() and 0.2 < changed[:, 0].mean() < 0.47  # every suffix ends at the last state

    def resimulate(position, generator):
        drawn, redrawn = path_prior.resimulate(position, generator)
        return np.where(redrawn, drawn, position)

    def component_fn(x):
        return np.column_stack([loglike(x), path_prior.logpdf(x)])

    coefficients = np.array([0.3, 1.0])
    components, rates = component_fn(walkers), []
    for _ in range(SWEEPS):
        walkers, components, sweep = schedule.prior_sweep(walkers, components, component_fn, coefficients,
                                                          resimulate, rng, None)
        rates.append(sweep.acceptance_rate)
    np.testing.assert_array_equal(components, component_fn(walkers))
    assert 0.2 < np.mean(rates) < 0.9
    _assert_moments(walkers, mean, cov)


def test_path_stages_with_the_prior_redraws_keep_the_tempered_target_in_the_box_coordinates():
    # move_stage with prior_moves: the rounds mix the prior's redraws, the kernel density's independence sweeps and
    # the random walk, in the box's logit coordinates (the prior's and the proposal's Jacobians cancel coordinate by
    # coordinate). The box [-30, 30]^3 holds the target's mass but for ~1e-100: its moments are the Gaussian's
    from seqbayes.core.state import Problem

    beta = 0.3
    path_prior, loglike, mean, cov = _chain_target(beta)
    problem = Problem(None, path_prior.kernel, None, np.tile([-30.0, 30.0], (3, 1)))
    config = RandomWalk(scaled=True, min_sweeps=1, max_sweeps=1)
    rng = np.random.default_rng(2)
    walkers = path_prior.sample(4000, rng)
    components = np.column_stack([loglike(walkers), path_prior.logpdf(walkers)])
    accepted = 0
    for _ in range(15):
        moved = schedule.move_stage(problem, config, 1.0, walkers, components, beta, path_prior.logpdf, rng, loglike,
                                    target=schedule.PathTarget(kernel_density=True, prior_moves=path_prior))
        walkers, components, accepted = moved.walkers, moved.components, accepted + moved.stats.n_accepted
    np.testing.assert_allclose(components, np.column_stack([loglike(walkers), path_prior.logpdf(walkers)]),
                               rtol=1e-10, atol=1e-10)
    assert accepted > 15 * 4000 * 0.3
    _assert_moments(walkers, mean, cov)


@pytest.mark.parametrize("move", ["stretch", "gaussian"])
def test_the_kernel_density_sweeps_leave_the_target_invariant_stage_after_stage(move):
    # exact draws of a 12-dimensional Gaussian moved by 20 stages of one round each, as a tempering's stages at
    # beta = 1: a kernel density fitted to the very particles it moves inflated its q at each of them and the
    # cloud drifted from the target (E|x|^2 / d 1.30 +- 0.03, 2.9 % beyond the 1 % quantiles, stretch, 4 seeds;
    # the path cloud's light tail, docs/jump_kernels.md). Tolerances: 5 Monte Carlo sds of 12,000 iid draws
    # (sqrt(2 / 12000) = 0.013 and sqrt(0.01 * 0.99 / 12000) = 0.0009); over 4 seeds the fixed sweeps gave
    # 0.990 +- 0.012 and 0.0098 +- 0.0006
    rng = np.random.default_rng(1)
    position = rng.standard_normal((1000, D))
    components = gaussian_components(position)
    config = (Stretch if move == "stretch" else RandomWalk)(scaled=True, min_sweeps=1, max_sweeps=1)
    for _ in range(20):
        position, components, _, _, _ = schedule.scaled_rounds(config, position, components, gaussian_components,
                                                            np.ones(1), None, rng, True)
    np.testing.assert_allclose(components[:, 0], gaussian_components(position)[:, 0])
    assert abs(np.mean(np.sum(position**2, axis=1)) / D - 1.0) < 5 * np.sqrt(2 / 12000)
    assert abs(np.mean(np.abs(position) > stats.norm.ppf(0.995)) - 0.01) < 5 * np.sqrt(0.01 * 0.99 / 12000)


def test_the_suffix_move_keeps_each_prefix_bit_for_bit_and_draws_the_suffix_uniformly():
    from seqbayes.moves.gaussian import GaussianMove
    from seqbayes.moves.scaled import SuffixMove
    from seqbayes.moves.stretch import DifferentialMove
    from seqbayes.moves.stretch import StretchMove

    rng = np.random.default_rng(3)
    walkers = rng.standard_normal((20000, 6))    # paths of three states of two parameters
    proposals, log_hastings = SuffixMove(GaussianMove(np.eye(6)), 3).propose(walkers, rng)
    moved = (proposals != walkers).reshape(-1, 3, 2)
    assert np.all(moved[..., 0] == moved[..., 1])               # a state moves whole
    first = np.argmax(moved[..., 0], axis=1)
    assert np.all(moved[..., 0] == (np.arange(3)[None, :] >= first[:, None]))  # from one state to the last
    # its first moved state is uniform on the three: 5 binomial sds of 20,000 draws
    assert np.all(np.abs(np.bincount(first, minlength=3) / 20000 - 1 / 3) < 5 * np.sqrt(2 / 9 / 20000))
    assert np.all(log_hastings == 0)
    complement = rng.standard_normal((50, 6))
    proposals, _, identical = SuffixMove(DifferentialMove(1.0), 3).propose(walkers[:100], complement, rng)
    assert not identical.any() and np.all(proposals[:, 4:] != walkers[:100, 4:])  # the last state always moves
    with pytest.raises(ValueError, match="symmetric"):
        SuffixMove(StretchMove(2.0), 3).propose(walkers[:100], complement, rng)


@pytest.mark.parametrize("move", ["gaussian", "differential"])
def test_suffix_sweeps_keep_the_chain_target(move):
    # exact MH: the suffix is drawn independently of the walker, so the restricted move stays symmetric. From the
    # path prior's draws the sweeps alone reach the tempered chain's exact Gaussian moments (5 standard errors)
    from seqbayes.moves.gaussian import GaussianMove, gaussian_sweep, weighted_covariance
    from seqbayes.moves.scaled import SuffixMove
    from seqbayes.moves.stretch import DifferentialMove, differential_sweep

    path_prior, loglike, mean, cov = _chain_target(beta=0.3)
    rng = np.random.default_rng(4)
    walkers = path_prior.sample(4000, rng)

    def component_fn(x):
        return np.column_stack([loglike(x), path_prior.logpdf(x)])

    coefficients = np.array([0.3, 1.0])
    components, accepted = component_fn(walkers), 0
    if move == "gaussian":
        local, sweep_fn = SuffixMove(GaussianMove(weighted_covariance(walkers), 2.38 / np.sqrt(3)), 3), gaussian_sweep
    else:
        local, sweep_fn = SuffixMove(DifferentialMove(1.0), 3), differential_sweep
    for _ in range(SWEEPS):
        walkers, components, sweep = sweep_fn(walkers, components, component_fn, coefficients, local, rng, None)
        accepted += sweep.n_accepted
    np.testing.assert_array_equal(components, component_fn(walkers))
    assert 0.2 < accepted / (SWEEPS * 4000) < 0.9
    _assert_moments(walkers, mean, cov)


def test_a_suffix_sweep_evaluates_only_the_moved_states_through_the_memo():
    # the window likelihood's memo holds every state of the walkers: a sweep's calls are its proposals' moved states
    from seqbayes.core.likelihood import ValidatedLikelihood
    from seqbayes.moves.gaussian import GaussianMove, gaussian_sweep
    from seqbayes.moves.scaled import SuffixMove

    rng = np.random.default_rng(5)
    base = ValidatedLikelihood(lambda theta, y: -0.5 * np.sum((theta - y) ** 2, axis=1))
    window = base.over_window([np.zeros(2), np.ones(2), np.full(2, 2.0)], 2, memo=True)
    walkers = rng.standard_normal((500, 6))
    components = window.loglike(walkers)[:, None]
    seen = []

    class Recording(SuffixMove):
        def propose(self, points, *args):
            out = super().propose(points, *args)
            seen.append((out[0] != points).reshape(-1, 3, 2).any(axis=2).sum())
            return out

    before = base.n_evals
    walkers, _, sweep = gaussian_sweep(walkers, components, window.loglike, np.ones(1),
                                       Recording(GaussianMove(np.eye(6), 0.3), 3), rng, None)
    assert base.n_evals - before == seen[0] < 3 * 500    # the kept states are read, not computed
    assert sweep.n_evaluations == 500                    # rows proposed, as the sweep counts them
