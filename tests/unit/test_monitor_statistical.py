"""Statistical and reproducibility tiers of the monitor (docs/environment.md, "Validation").

- The IBIS posterior of the static parameters (thermal lag, each mode's set noise) and its P(damage) and
  log-evidence against a midpoint grid over the same prior on a short history (the grid is converged: 32 and 64
  points per axis agree to 1e-4 in every mean). The tolerance is the Monte Carlo error measured in the test
  itself: the spread of eight independent IBIS runs.
- Reproducibility: a seed reproduces a run bit for bit, and the driver fed day by day gives the bits of
  :func:`monitor_table` over the whole table (the store's day-by-day updates are checked against it in
  tests/unit/test_monitor_store.py).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.special import logsumexp

from seqbayes.structural.monitor.change import change_posterior
from seqbayes.structural.monitor.history import History, prepare_sets
from seqbayes.structural.monitor.law import MonitorPrior
from seqbayes.structural.monitor.model import MonitorModel, MonitorSettings
from seqbayes.structural.monitor.sampler import history_pass
from seqbayes.structural.monitor.table import Monitor, monitor_table
from seqbayes.weights import normalise

HAZARD = 1 / 365


def short_history(seed=0, shift=0.996):
    """Four days of six sets of two modes, a 0.4 % drop of mode 2 from day 2."""
    rng = np.random.default_rng(seed)
    days = []
    for d in range(4):
        t = d + np.arange(6) / 6
        air = 5 + 8 * np.sin(2 * np.pi * t) + rng.normal(0, 1, t.size)
        f = np.array([2.0, 5.5]) * np.exp(-0.0008 * (air[:, None] - 10) + rng.normal(0, 0.003, (t.size, 2)))
        if d >= 2:
            f[:, 1] *= shift
        days.append((t, air, f))
    return days


def _fixed(value):
    return (value, value * (1 + 1e-9))


PRIOR = MonitorPrior(tau_hours=(0.05, 12.0), knee_location=(-1e-9, 1e-9), knee_width=_fixed(1.0),
                     level_sd=_fixed(1e-4), day_sd=_fixed(3e-4), noise_sd=(1e-3, 0.01))
FREE = [0, 5, 6]     # log tau, log noise sd of modes 1 and 2; the others are fixed by a box of width ~1e-9


@pytest.mark.slow
def test_ibis_posterior_equals_a_grid_over_the_static_parameters():
    model = MonitorModel.mode_level([2.0, 5.5], prior=PRIOR)
    days = short_history()
    history = History.empty(2, 0)
    for t, air, f in days:
        history = history.extended(*prepare_sets(model, t, air, f))
    box = PRIOR.box(2)
    g = 32
    axes = [box[i, 0] + (np.arange(g) + 0.5) / g * (box[i, 1] - box[i, 0]) for i in FREE]
    mesh = np.meshgrid(*axes, indexing="ij")
    u = np.tile(box.mean(axis=1), (g ** 3, 1))
    for k, i in enumerate(FREE):
        u[:, i] = mesh[k].ravel()
    _, loglike, cache = history_pass(model, u, history, history.n_chunks, HAZARD, block=4096)
    w = np.exp(normalise(loglike))
    grid_mean = (w @ u)[FREE]
    grid_p = w @ np.exp(change_posterior(cache.bank, model.pattern, int(history.chunk_day[-1]), HAZARD).log_p_change)
    grid_log_z = logsumexp(loglike) - np.log(loglike.size)       # the prior is uniform in u: the grid's mean

    runs = []
    for seed in range(8):
        monitor = Monitor(model, MonitorSettings(n_particles=500), np.random.default_rng(seed))
        for t, air, f in days:
            day = monitor.update(t, air, f)
        state = monitor.state
        runs.append(np.concatenate([(state.weights @ state.particles.u)[FREE], [day.p_damage, state.log_evidence]]))
    runs = np.array(runs)
    mean, error = runs.mean(axis=0), runs.std(axis=0, ddof=1) / np.sqrt(len(runs))
    reference = np.concatenate([grid_mean, [grid_p, grid_log_z]])
    # 4 standard errors of the eight runs' mean (their spread: log tau 0.4, noise 0.05, P(damage) 6e-4, log Z 0.4)
    assert np.all(np.abs(mean - reference) < 4 * error + 1e-3), (mean, reference, error)
    assert 0.05 < error[0] < 0.5 and error[3] < 0.3      # the tolerance is not vacuous


def _table(n_days=3, seed=4):
    rng = np.random.default_rng(seed)
    day = np.concatenate([d + np.sort(rng.uniform(0, 1, 5)) for d in range(n_days)])
    air = 4 + 6 * np.sin(2 * np.pi * day) + rng.normal(0, 1, day.size)
    f = np.array([2.0, 5.5]) * np.exp(-0.0008 * (air[:, None] - 10) + rng.normal(0, 0.003, (day.size, 2)))
    f[rng.random(f.shape) < 0.2] = np.nan
    return {"day": day, "temperature": air, "f1": f[:, 0], "f2": f[:, 1]}


def _bits(days):
    return [(d.p_damage, d.log_evidence, d.ess, d.environment.coefficients["temperature_2"].mean) for d in days]


def test_a_seed_reproduces_the_run_bit_for_bit():
    model = MonitorModel.mode_level([2.0, 5.5])
    settings = MonitorSettings(n_particles=64)
    a = monitor_table(_table(), model, 3, settings)
    b = monitor_table(_table(), model, 3, settings)
    c = monitor_table(_table(), model, 4, settings)
    assert _bits(a) == _bits(b)
    assert _bits(a) != _bits(c)


def test_day_by_day_equals_the_whole_table():
    model = MonitorModel.mode_level([2.0, 5.5])
    settings = MonitorSettings(n_particles=64)
    table = _table()
    whole = monitor_table(table, model, 3, settings)
    monitor = Monitor(model, settings, np.random.default_rng(3))
    rows = np.floor(table["day"]).astype(int)
    days = []
    for d in np.unique(rows):
        pick = rows == d
        days.append(monitor.update(table["day"][pick], table["temperature"][pick],
                                   np.column_stack([table["f1"][pick], table["f2"][pick]])))
    assert _bits(days) == _bits(whole)
