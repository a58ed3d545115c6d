"""Jump kernels (issue 11): the spike-and-slab transition, its exact predictive mixture, the
posterior probability and size of a jump, the TOML entry, and the samplers on a sudden drop."""

from __future__ import annotations

import tomllib
import warnings

import numpy as np
import pytest
from scipy import stats
from scipy.special import logsumexp

from seqbayes import SEMC, SMC, Decay, Drift, JointPrior, MarkovKernel, Static
from seqbayes.store.config import ConfigError, parse_config
from seqbayes.predictive.mixture import GaussianMixture, MixtureSum, predictive_density
from seqbayes.kernels import HEAVY_TAIL_SCALES, HEAVY_TAIL_WEIGHTS, Jump, jump_posterior
from seqbayes.predictive.base import resolve_predictive
from seqbayes.predictive.smc2 import SMC2

JUMP = Jump(Decay(0.02, noise_std=0.02), p=0.05, drop_mean=0.3, drop_sd=0.1, reference=3.0)


def mixture_pdf(x, gamma, p, q, mu, s, ref, scales=(1.0,), weights=(1.0,)):
    """The transition density as stated in Jump's docstring, from scipy."""
    out = (1 - p) * stats.norm.pdf(x, gamma, q)
    for scale, v in zip(scales, weights):
        out = out + p * v * stats.norm.pdf(x, gamma - mu * ref, np.sqrt(q**2 + (scale * s * ref) ** 2))
    return out


def test_jump_logpdf_is_the_stated_mixture_and_heavy_tail_its_scale_mixture():
    kernel = MarkovKernel([JUMP, Drift(-0.01, noise_std=0.005)])
    old = np.array([[3.0, 0.6], [2.5, 0.5]])
    new = np.array([[2.9, 0.59], [1.7, 0.49]])
    expected = (np.log(mixture_pdf(new[:, 0], np.exp(-0.02) * old[:, 0], 0.05, 0.02, 0.3, 0.1, 3.0))
                + stats.norm.logpdf(new[:, 1], old[:, 1] - 0.01, 0.005))
    np.testing.assert_allclose(kernel.logpdf(new, old), expected, rtol=1e-12)
    heavy = Jump.heavy_tailed(Drift(0.0, noise_std=0.01), p=0.1, drop_mean=0.0, drop_sd=0.2, reference=1.0)
    assert heavy.scales == HEAVY_TAIL_SCALES and heavy.scale_weights == HEAVY_TAIL_WEIGHTS
    x = np.linspace(-5, 5, 7)
    expected = np.log(mixture_pdf(x, 0.0, 0.1, 0.01, 0.0, 0.2, 1.0, (1, 3, 10), (0.6, 0.3, 0.1)))
    np.testing.assert_allclose(MarkovKernel([heavy]).logpdf(x[:, None], np.zeros((7, 1))), expected, rtol=1e-12)
    # the density integrates to one (Simpson on a wide, fine grid; the slab at 10 sds is 6 wide)
    grid = np.linspace(-30, 30, 600_001)
    mass = np.sum(np.exp(MarkovKernel([heavy]).logpdf(grid[:, None], np.zeros((grid.size, 1))))) * (grid[1] - grid[0])
    assert mass == pytest.approx(1.0, abs=1e-6)


def test_propagate_draws_the_transition_of_logpdf():
    kernel = MarkovKernel([JUMP, Decay(0.02, noise_std=0.005)])
    n = 200_000
    draws = kernel.propagate(np.tile([3.0, 0.6], (n, 1)), np.random.default_rng(4))
    gamma = 3.0 * np.exp(-0.02)
    # the CDF of the stated mixture at a few points, against the draws' fractions: a binomial
    # proportion has sd sqrt(P (1 - P) / n) <= 0.0011; 5 sds
    for x in (1.8, 2.2, 2.85, 2.93, 2.95):
        cdf = 0.95 * stats.norm.cdf(x, gamma, 0.02) + 0.05 * stats.norm.cdf(x, gamma - 0.9, np.hypot(0.02, 0.3))
        assert np.mean(draws[:, 0] <= x) == pytest.approx(cdf, abs=5 * np.sqrt(cdf * (1 - cdf) / n) + 1e-12)
    np.testing.assert_allclose(draws[:, 1].std(), 0.005, rtol=0.01)      # sd of a sd estimate: 1/sqrt(2n) = 0.16 %
    # a seed reproduces the draws bit for bit
    again = kernel.propagate(np.tile([3.0, 0.6], (n, 1)), np.random.default_rng(4))
    np.testing.assert_array_equal(draws, again)


def test_predictive_density_is_eq_a3_with_the_exact_transition():
    kernel = MarkovKernel([JUMP, Decay(0.02, noise_std=0.005)])
    rng = np.random.default_rng(1)
    posterior = rng.normal([2.8, 0.55], [0.05, 0.01], size=(40, 2))
    log_w = rng.normal(size=40)
    density, draws = predictive_density(posterior, log_w, kernel, rng)
    assert isinstance(density, MixtureSum) and draws.shape == (40, 2)
    x = np.array([[2.75, 0.54], [1.9, 0.54], [2.3, 0.53], [2.76, 0.6]])
    w = log_w - logsumexp(log_w)
    exact = np.array([logsumexp(w + kernel.logpdf(np.tile(row, (40, 1)), posterior)) for row in x])
    # GaussianMixture.logpdf works in single precision: ~1e-6 near the bulk
    np.testing.assert_allclose(density.logpdf(x), exact, atol=1e-4)
    np.testing.assert_allclose(density.logpdf(x), logsumexp(density.component_logpdfs(x), axis=1))


def test_mixture_sum_sample_and_one_draw_per_ancestor():
    kernel = MarkovKernel([JUMP])
    ancestors = np.full((100_000, 1), 3.0)
    density, _ = predictive_density(ancestors[:1000], np.zeros(1000), kernel, np.random.default_rng(0))
    for draws in (density.sample(100_000, np.random.default_rng(2)),
                  MixtureSum(tuple(GaussianMixture(m.centres[:1].repeat(100_000, 0), m.bandwidth)
                                   for m in density.mixtures), density.log_weights)
                  .draw_one_per_component(np.random.default_rng(3))):
        # fraction in the slab region below 2.5: 0.05 P(N(2.04, 0.30) < 2.5); binomial sd, 5 sds
        cdf = 0.95 * stats.norm.cdf(2.5, 3 * np.exp(-0.02), 0.02) + 0.05 * stats.norm.cdf(
            2.5, 3 * np.exp(-0.02) - 0.9, np.hypot(0.02, 0.3))
        assert np.mean(draws[:, 0] < 2.5) == pytest.approx(cdf, abs=5 * np.sqrt(cdf * (1 - cdf) / 100_000))
    with pytest.raises(ValueError, match="log_weights"):
        MixtureSum(density.mixtures, np.zeros(3))
    with pytest.raises(TypeError, match="mixtures"):
        MixtureSum((), np.zeros(0))


@pytest.mark.slow
def test_jump_posterior_matches_brute_force():
    """Branch responsibilities and the drop fraction's posterior, against a direct evaluation with
    the kernel's logpdf and a quadrature over f (deterministic: no Monte Carlo)."""
    heavy = Jump(Drift(-0.01, noise_std=0.03), p=0.1, drop_mean=0.25, drop_sd=0.1, reference=2.0,
                 scales=(1.0, 4.0), scale_weights=(0.7, 0.3))
    kernel = MarkovKernel([heavy, Decay(0.05, noise_std=0.01)])
    rng = np.random.default_rng(7)
    previous = rng.normal([2.0, 0.5], [0.05, 0.02], size=(30, 2))
    prev_w = rng.normal(size=30)
    density, _ = predictive_density(previous, prev_w, kernel, rng)
    posterior = np.column_stack([rng.normal(1.7, 0.2, 25), rng.normal(0.47, 0.02, 25)])
    post_w = rng.normal(size=25)
    got = jump_posterior(kernel, density, posterior, post_w)

    w0, v = np.exp(prev_w - logsumexp(prev_w)), np.exp(post_w - logsumexp(post_w))
    f = np.linspace(-3.0, 4.0, 70_001)
    jump_mass, f_first, f_second = 0.0, 0.0, 0.0
    for k in range(25):
        gamma = previous[:, 0] - 0.01
        c_term = stats.norm.pdf(posterior[k, 1], previous[:, 1] * np.exp(-0.05), 0.01)     # (30,)
        total = w0 @ (np.exp(kernel.logpdf(np.tile(posterior[k], (30, 1)), previous)))
        # joint density of (ancestor i, slab m, f) at theta_k, integrated over f on the grid
        for scale, weight in ((1.0, 0.7), (4.0, 0.3)):
            dens = (0.1 * weight * stats.norm.pdf(f[None, :], 0.25, 0.1 * scale)
                    * stats.norm.pdf(posterior[k, 0], gamma[:, None] - 2.0 * f[None, :], 0.03))    # (30, F)
            joint = (w0 * c_term) @ dens                                                      # (F,)
            df = f[1] - f[0]
            jump_mass += v[k] * joint.sum() * df / total
            f_first += v[k] * (joint * f).sum() * df / total
            f_second += v[k] * (joint * f * f).sum() * df / total
    assert got.probability[0] == pytest.approx(jump_mass, rel=1e-4)   # float32 mixture evaluation
    assert np.isnan(got.probability[1]) and np.isnan(got.size_mean[1])
    assert got.any_probability == pytest.approx(jump_mass, rel=1e-4)
    mean = f_first / jump_mass
    assert got.size_mean[0] == pytest.approx(mean, rel=1e-4)
    assert got.size_sd[0] == pytest.approx(np.sqrt(f_second / jump_mass - mean**2), rel=1e-3)
    fields = got.step_fields()
    assert fields["jump_parameter"] == 0 and fields["jump_probability"] == got.any_probability


def test_jump_validation_names_the_argument():
    base = Decay(0.02, noise_std=0.02)
    for kwargs, message in (({"p": 0.0}, "p: the jump probability"), ({"p": 1.0}, "p: the jump probability"),
                            ({"drop_sd": 0.0}, "drop_sd"), ({"reference": -1.0}, "reference"),
                            ({"drop_mean": np.nan}, "drop_mean"), ({"scales": (1.0, -2.0), "scale_weights": (1, 1)}, "scales"),
                            ({"scales": (1.0, 2.0)}, "scale_weights")):
        args = {"p": 0.05, "drop_mean": 0.3, "drop_sd": 0.1, "reference": 3.0, **kwargs}
        with pytest.raises(ValueError, match=message):
            Jump(base, **args)
    with pytest.raises(ValueError, match="base: a jump component needs a base with noise_std > 0"):
        Jump(Decay(0.02), 0.05, 0.3, 0.1, 3.0)
    with pytest.raises(TypeError, match="base"):
        Jump(Static(), 0.05, 0.3, 0.1, 3.0)
    with pytest.raises(TypeError, match="base"):
        Jump(JUMP, 0.05, 0.3, 0.1, 3.0)
    with pytest.raises(ValueError, match="kernel: expected a MarkovKernel with Jump"):
        jump_posterior(MarkovKernel([base]), None, np.zeros((2, 1)), np.zeros(2))


def test_predictive_choice_with_jumps():
    kernel = MarkovKernel([JUMP, Static()])
    assert resolve_predictive(None, kernel).method == "transition"     # SMC^2 assumes Gaussian transitions
    with pytest.raises(ValueError, match="predictive: SMC2 does not support Jump"):
        resolve_predictive(SMC2(), kernel)


def _toml(entry):
    text = f"""
[model]
likelihood = "m:loglike"
[data]
columns = ["y"]
[priors]
k = {{ dist = "uniform", loc = 0.0, scale = 10.0 }}
[kernel]
k = {entry}
"""
    return parse_config(tomllib.loads(text), "run.toml", check_likelihood=False)


def test_toml_jump_entry_builds_the_kernel_and_names_bad_keys():
    cfg = _toml('{ type = "jump", base = "decay", rate = 0.02, noise_std = 0.02, p = 0.05, drop_mean = 0.3, '
                'drop_sd = 0.1, reference = 3.0 }')
    kernel = cfg.build_kernel()
    (jump,) = kernel.components
    assert isinstance(jump, Jump) and isinstance(jump.base, Decay) and jump.p == 0.05 and jump.scales == (1.0,)
    x = np.array([[2.5]])
    np.testing.assert_array_equal(kernel.logpdf(x, x), MarkovKernel([JUMP]).logpdf(x, x))
    heavy = _toml('{ type = "jump", base = "drift", rate = 0.0, noise_std = 0.01, p = 0.1, drop_mean = 0.0, '
                  'drop_sd = 0.2, reference = 1.0, tail = "heavy" }').build_kernel().components[0]
    assert heavy.scales == HEAVY_TAIL_SCALES and isinstance(heavy.base, Drift)
    good = ('type = "jump", base = "decay", rate = 0.02, noise_std = 0.02, p = 0.05, drop_mean = 0.3, '
            'drop_sd = 0.1, reference = 3.0')
    for change, message in ((("p = 0.05", "p = 1.5"), "kernel.k.p: the jump probability"),
                            (("drop_sd = 0.1", "drop_sd = 0.0"), "kernel.k.drop_sd: must be positive"),
                            (("reference = 3.0", "reference = -3.0"), "kernel.k.reference: must be positive"),
                            (("noise_std = 0.02", "noise_std = 0.0"), "kernel.k.noise_std: a jump kernel needs"),
                            (('base = "decay"', 'base = "static"'), "kernel.k.base"),
                            (("p = 0.05, ", ""), "kernel.k.p: missing"),
                            (("reference = 3.0", 'reference = 3.0, tail = "fat"'), "kernel.k.tail"),
                            (("reference = 3.0", "reference = 3.0, scales = [1, 3]"), "kernel.k.scales"),
                            (("reference = 3.0", "reference = 3.0, scales = [1, 3], scale_weights = [1]"),
                             "kernel.k.scale_weights"),
                            (("reference = 3.0", "reference = 3.0, spike = 1"), "kernel.k.spike: unknown")):
        with pytest.raises(ConfigError, match=message):
            _toml("{ " + good.replace(*change) + " }")


def _drop_problem(drop_step):
    """A 1-D random walk seen through Gaussian data of sd 0.05: a sharp likelihood, the level drops 0.9
    at ``drop_step`` (None: never)."""
    rng = np.random.default_rng(11)
    level = 3.0 - 0.02 * np.arange(1, 7) + 0.02 * rng.standard_normal(6)
    if drop_step is not None:
        level[drop_step - 1:] -= 0.9
    data = [level[s] + 0.05 * rng.standard_normal(5) for s in range(6)]
    prior = JointPrior({"k": stats.uniform(0.0, 10.0)})
    loglike = lambda theta, y: stats.norm.logpdf(y[None, :], theta[:, :1], 0.05).sum(axis=1)  # noqa: E731
    return prior, loglike, data


@pytest.mark.slow
@pytest.mark.parametrize("cls", [SMC, SEMC])
def test_sampler_reports_the_jump_at_the_drop_step_only(cls):
    prior, loglike, data = _drop_problem(4)
    kernel = MarkovKernel([Jump(Drift(-0.02, noise_std=0.02), p=0.05, drop_mean=0.3, drop_sd=0.1, reference=3.0)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = cls(prior, kernel, loglike, n_samples=400, rng=3).run(data)
    probability = np.array([s.info.jump_probability for s in result.steps])
    assert np.isnan(probability[0])                                   # no transition into step 1
    assert probability[3] > 0.99                                       # 0.9 N/m at 0.022 sd: 40 sds
    assert np.all(probability[[1, 2, 4, 5]] < 0.01)
    # the drop fraction: 0.9 / 3 = 0.3 less the data's pull, within the posterior's own sd
    info = result.steps[3].info
    assert abs(info.jump_size - 0.3) < 3 * info.jump_size_sd + 0.02 and info.jump_parameter == 0
    again = cls(prior, kernel, loglike, n_samples=400, rng=3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        again.run(data)
    np.testing.assert_array_equal(again.result.steps[-1].posterior, result.steps[-1].posterior)


@pytest.mark.slow
@pytest.mark.parametrize("sampler", ["SEMC", "SMC"])
def test_run_store_resumes_a_jump_kernel_run_bit_for_bit(tmp_path, sampler):
    """A TOML jump kernel in the run store: reopened from disk before every step, the run is the
    uninterrupted one (posteriors, predictive draws and every diagnostic, the jump posterior included)."""
    import dataclasses
    import sys

    from _user_model import decay_tables, write_config, write_model

    from seqbayes.store.config import load_config
    from seqbayes.store.report import status_rows
    from seqbayes.store import RunStore

    write_model(tmp_path, "jumpstoremodel")
    kernel = ('a = { type = "jump", base = "drift", rate = -0.02, noise_std = 0.02, p = 0.1, drop_mean = 0.3, '
              'drop_sd = 0.1, reference = 1.5 }\nb = { type = "drift", rate = 0.0, noise_std = 0.01 }')
    cfg = load_config(write_config(tmp_path / "run.toml", "jumpstoremodel", kernel=kernel, sampler=sampler,
                                   n_samples=80, seed=5))     # SMC's run takes the conflict remedy at step 3
    data = decay_tables([1.5, 1.48, 1.0, 0.98], np.linspace(0, 3, 15), 0.05, 2)
    reference = cfg.build_sampler()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for d in data:
            reference.update(d)
        RunStore.create(tmp_path / "run.nc", cfg)
        for i, d in enumerate(data):
            RunStore.open(tmp_path / "run.nc").assimilate(d, f"d{i}")
    store = RunStore.open(tmp_path / "run.nc")
    for a, b in zip(reference.result.steps, store.result.steps):
        np.testing.assert_array_equal(a.posterior, b.posterior)
        np.testing.assert_array_equal(a.predictive, b.predictive)
        info_a, info_b = dataclasses.asdict(a.info), dataclasses.asdict(b.info)
        info_a.pop("wall_time"), info_b.pop("wall_time")                  # the only field allowed to differ
        np.testing.assert_equal(info_a, info_b)
    probability = [s.info.jump_probability for s in store.result.steps]
    assert np.isnan(probability[0]) and probability[2] > 0.9 and max(probability[1], probability[3]) < 0.1
    rows = status_rows(store)                                        # what `seqbayes status --json` prints
    assert [r["jump_probability"] for r in rows[1:]] == probability[1:] and rows[2]["jump_parameter"] == "a"
    se = [r["jump_probability_se"] for r in rows]                    # beside it: its Monte Carlo se (issue 26)
    assert np.isnan(se[0]) and se[1:] == [s.info.jump_probability_se for s in store.result.steps][1:]
    assert all(0 < x < 0.5 for x in se[1:])
    text = store.status()
    assert "P(jump)" in text and f"{rows[2]['jump_probability']:.4f}" in text
    from seqbayes.store.report import render_report
    assert "<h2>Jumps</h2>" in render_report(store, forecast_steps=0)
    sys.modules.pop("jumpstoremodel", None)
