"""Exact checks of the monitor's linear-Gaussian parts against brute force (docs/environment.md, "Validation").

- The per-mode daily filter's log-likelihood equals the dense Gaussian density of all sets of a mode (level random
  walk, day effects, static coefficients, missing sets, OMA variances, chunks of a day).
- The change bank's ``-m a_d - m^2 b_d / 2`` equals the log-likelihood ratio of the filter run on data with the
  step added, for every candidate day and several sizes; the backward recursion equals the on-line bank.
- The truncated-normal integral over the size, and the mode-level model's sum over subsets of modes.
"""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy import integrate
from scipy.stats import multivariate_normal

from seqbayes.structural.monitor.change import (ElementLoss, LossPrior, ModeShift, backward_bank, bank_chunk,
                                                empty_bank, log_bayes_factor, log_day_prior, sensitivities)
from seqbayes.structural.monitor.daily_filter import chunk_statistics, chunk_update, initial_state, new_day
from seqbayes.structural.monitor.law import design, knee, lagged


def small_history(rng, n_days=4, n_modes=2, chunks_per_day=(1, 2, 1, 2), days=(0, 1, 3, 4)):
    """Chunks of sets: calendar day, times, air temperature, covariate, centred log-f (NaN missing), OMA var."""
    chunks = []
    for c, day in enumerate(days[:n_days]):
        for part in range(chunks_per_day[c]):
            s = int(rng.integers(2, 5))
            times = day + (part * 0.5 + np.sort(rng.uniform(0, 0.45, s)))
            air = rng.normal(5, 6, s)
            cov = rng.normal(0, 1, (s, 1))
            y = rng.normal(0, 0.01, (s, n_modes))
            y[rng.random((s, n_modes)) < 0.25] = np.nan
            oma = np.where(rng.random((s, n_modes)) < 0.5, 0.0, rng.uniform(1e-6, 4e-5, (s, n_modes)))
            chunks.append(dict(day=day, times=times, air=air, cov=cov, y=y, oma=oma))
    return chunks


PARAMS = dict(tau=np.array([3.0, 0.1, 12.0]), T0=np.array([0.5, -1.0, 2.0]), w=np.array([1.0, 0.3, 2.0]),
              level_var=np.array([1e-6, 4e-8, 2.5e-5]), day_var=np.array([1e-6, 1e-8, 9e-6]),
              noise_var=np.array([[1e-5, 4e-5], [2e-6, 1e-5], [9e-6, 9e-6]]))
STATIC = np.array([0.005, 0.03, 0.01])
LEVEL0 = 0.1


def designs(chunks, k):
    """(N, S, p) regressors of every chunk, with the lag carried over the whole history."""
    times = np.concatenate([c["times"] for c in chunks])
    air = np.concatenate([c["air"] for c in chunks])
    ts = lagged(times, air, PARAMS["tau"])
    out, start = [], 0
    for c in chunks:
        s = c["times"].size
        out.append(design(ts[:, start:start + s], PARAMS["T0"], PARAMS["w"], c["cov"], 10.0, np.zeros(1)))
        start += s
    return out


def run_filter(chunks, shift=None):
    """Filter log-likelihood (N, n) and the per-chunk terms; ``shift(k, chunk) -> (S, n)`` is added to y."""
    n_particles, n_modes = PARAMS["noise_var"].shape
    hs = designs(chunks, None)
    state = initial_state(n_particles, n_modes, LEVEL0, PARAMS["day_var"], STATIC)
    total = np.zeros((n_particles, n_modes))
    terms, previous_day = [], None
    for k, (c, h) in enumerate(zip(chunks, hs)):
        is_new = previous_day != c["day"]
        if is_new:
            gap = 0 if previous_day is None else c["day"] - previous_day
            state = new_day(state, gap, PARAMS["level_var"], PARAMS["day_var"])
        y = c["y"] if shift is None else c["y"] + shift(k, c)
        stats = chunk_statistics(h, y, c["oma"], PARAMS["noise_var"])
        state, loglike, g_inv, beta, omega = chunk_update(state, *stats)
        total += loglike
        candidate = c["day"] if (is_new and c["day"] >= 1) else None
        terms.append((g_inv, beta, omega, is_new, candidate))
        previous_day = c["day"]
    return total, terms, state


def dense_loglike(chunks, particle, mode):
    """The Gaussian density of all of a mode's observed sets, from the model written out in full."""
    hs = designs(chunks, None)
    days = sorted({c["day"] for c in chunks})
    rows, ys, variances = [], [], []
    for c, h in zip(chunks, hs):
        d = days.index(c["day"])
        for s in range(c["times"].size):
            if not np.isfinite(c["y"][s, mode]):
                continue
            level = np.zeros(len(days))
            level[:d + 1] = 1.0                                # c_0 + the random-walk steps up to day d
            day = np.zeros(len(days))
            day[d] = 1.0
            rows.append(np.concatenate([level, day, h[particle, s, 2:]]))
            ys.append(c["y"][s, mode])
            variances.append(c["oma"][s, mode] + PARAMS["noise_var"][particle, mode])
    gaps = np.diff(days)
    prior = np.concatenate([[LEVEL0 ** 2], gaps * PARAMS["level_var"][particle],
                            np.full(len(days), PARAMS["day_var"][particle]), STATIC ** 2])
    Z = np.array(rows)
    cov = Z @ np.diag(prior) @ Z.T + np.diag(variances)
    return multivariate_normal(np.zeros(len(ys)), cov).logpdf(np.array(ys))


def test_filter_loglike_equals_the_dense_gaussian_density():
    chunks = small_history(np.random.default_rng(3))
    total, _, _ = run_filter(chunks)
    for particle in range(3):
        for mode in range(2):
            assert total[particle, mode] == pytest.approx(dense_loglike(chunks, particle, mode), abs=1e-8)


def test_a_whole_day_at_once_equals_its_records_one_by_one():
    rng = np.random.default_rng(5)
    chunks = small_history(rng)
    merged, by_day = [], {}
    for c in chunks:
        by_day.setdefault(c["day"], []).append(c)
    for day, parts in by_day.items():
        merged.append({key: (day if key == "day" else np.concatenate([p[key] for p in parts]))
                       for key in parts[0]})
    a, _, _ = run_filter(chunks)
    b, _, _ = run_filter(merged)
    np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)


def test_bank_terms_equal_the_likelihood_ratio_of_a_step_in_the_data():
    chunks = small_history(np.random.default_rng(7))
    base, terms, _ = run_filter(chunks)
    bank = empty_bank(3, 2, terms[0][0].shape[-1])
    for t in terms:
        bank = bank_chunk(bank, *t)
    assert bank.days.tolist() == [1, 3, 4]
    g = np.array([0.7, -0.4])
    for c, day in enumerate(bank.days):
        for m in (0.003, 0.02, -0.01):
            # p(y | step of -m g from day) is the no-damage filter's density of y with the step taken out
            shifted, _, _ = run_filter(chunks, lambda k, ch: np.full(ch["y"].shape, m * g) * (ch["day"] >= day))
            ratio = (shifted - base).sum(axis=1)
            expected = -m * (bank.A[:, :, c] @ g) - 0.5 * m * m * (bank.B[:, :, c] @ g ** 2)
            np.testing.assert_allclose(ratio, expected, rtol=1e-7, atol=1e-8)


def test_backward_recursion_equals_the_online_bank():
    chunks = small_history(np.random.default_rng(11))
    _, terms, _ = run_filter(chunks)
    g_inv = np.stack([t[0] for t in terms])
    beta = np.stack([t[1] for t in terms])
    omega = np.stack([t[2] for t in terms])
    new = np.array([t[3] for t in terms])
    cand = np.array([-1 if t[4] is None else t[4] for t in terms])
    for end in (len(terms), len(terms) - 1, 3):
        bank = empty_bank(3, 2, g_inv.shape[-1])
        for t in terms[:end]:
            bank = bank_chunk(bank, *t)
        back = backward_bank(g_inv, beta, omega, new, cand, end)
        assert back.days.tolist() == bank.days.tolist()
        np.testing.assert_allclose(back.A, bank.A, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(back.B, bank.B, rtol=1e-9, atol=1e-6)
        np.testing.assert_allclose(back.delta, bank.delta, rtol=1e-9, atol=1e-12)


@pytest.mark.parametrize("a,b", [(50.0, 4e4), (-300.0, 1e5), (0.0, 10.0), (-2e3, 2e5)])
def test_size_integral_equals_quadrature(a, b):
    prior = LossPrior(0.01, 0.1)
    log_bf, mean, sd = log_bayes_factor(a, b, prior)

    def density(m):
        return math.exp(-m * a - 0.5 * m * m * b - 0.5 * (m / prior.sd) ** 2) / math.sqrt(2 * math.pi) / prior.sd

    z = math.erfc(prior.minimum / prior.sd / math.sqrt(2)) / 2
    peak = max(prior.minimum, -a / (b + prior.sd ** -2))
    value = sum(integrate.quad(density, lo, hi, limit=200)[0]
                for lo, hi in ((prior.minimum, peak), (peak, peak + 1), (peak + 1, np.inf)) if hi > lo)
    assert float(log_bf) == pytest.approx(math.log(value / z), abs=1e-7)


def test_mode_shift_sums_over_every_nonempty_subset_of_modes():
    rng = np.random.default_rng(2)
    A = rng.normal(0, 100, (2, 3, 4))
    B = rng.uniform(1e3, 1e5, (2, 3, 4))
    shift = ModeShift(3, probability=0.3)
    log_bf, _, _ = shift.log_terms(A, B)
    bf = np.exp(log_bf)
    total = np.zeros((2, 4))
    for subset in itertools.product([0, 1], repeat=3):
        if not any(subset):
            continue
        weight = np.prod([0.3 if s else 0.7 for s in subset])
        product = np.ones((2, 4))
        for i, s in enumerate(subset):
            product = product * (bf[:, i] if s else 1.0)
        total += weight * product
    total /= 1 - 0.7 ** 3
    np.testing.assert_allclose(shift.log_combined(A, B), np.log(total), rtol=1e-12)


def test_day_prior_sums_to_one_with_no_change():
    log_prior, log_none = log_day_prior(np.array([1, 2, 5, 6]), 6, 0.01)
    assert math.fsum(np.exp(log_prior)) + math.exp(log_none) == pytest.approx(1.0, abs=1e-14)
    assert math.exp(log_prior[2]) == pytest.approx(0.99 ** 2 - 0.99 ** 5)


def test_sensitivities_of_a_shear_building_sum_to_one_half():
    from seqbayes.structural.structures import ShearBuilding
    from seqbayes.structural.structures.linear import ShearBuildingModel

    model = ShearBuildingModel(ShearBuilding([2e5, 2e5, 2e5, 1.6e5], [3e8, 2.6e8, 2.2e8, 1.8e8]))
    g = sensitivities(model, 4)
    np.testing.assert_allclose(g.sum(axis=1), 0.5, atol=1e-7)      # every k scaled by c: every f by sqrt(c)
    assert np.all(g > -1e-9)
    pattern = ElementLoss(g, ("1", "2", "3", "4"))
    assert pattern.n_classes == 4


def test_lag_and_knee():
    times = np.arange(48) / 24
    air = np.where(times < 1, 0.0, 10.0)
    ts = lagged(times, air, np.array([6.0, 0.05]))
    assert ts[0, 24] == pytest.approx(10 * (1 - math.exp(-1 / 6)))
    assert ts[1, 24] == pytest.approx(10.0)
    assert ts[0, 47] == pytest.approx(10 * (1 - math.exp(-24 / 6)))
    np.testing.assert_allclose(knee(np.array([-5.0, 5.0]), 0.0, 1e-3), [5.0, 0.0], atol=1e-9)
