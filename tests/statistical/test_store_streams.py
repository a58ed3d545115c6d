"""Property test of issue 24: whatever stream of datasets a run is fed, every state it stores re-opens and resumes.

Random streams of the linear model y = a + b t (15 points per dataset, noise sd 0.1) whose parameters drift
(the transition-mixture predictive) or may jump (a jump kernel: the mixture-sum predictive), with sudden
changes of (a, b), outlier datasets and datasets fed out of order, through the run store with a fresh
object opened from the file before every step (:meth:`RunStore.open` checks every stored value with the
engine's own rules, :mod:`seqbayes.engine.drivers`). An abrupt change used to leave a NaN
``state_log_evidence_variance`` that the store then refused. Every tenth stream is also run uninterrupted
in memory and must give the store's steps bit for bit.

The suite runs the first 20 of the seeded streams (they are drawn in sequence, so a prefix of the full
set): each of them stores unknown variances (the case above), 6 take the jump kernel and 6 SMC, and
streams 0 and 10 (SMC with drift, SEMC with the jump kernel) are also run in memory. About 2 s of CPU
a stream; ``SEQBAYES_STREAMS=200`` runs all 200 of issue 24.
"""

from __future__ import annotations

import os
import warnings

import numpy as np
import pytest

from _user_model import assert_same_steps, line_model

from seqbayes.store import RunStore, load_config

MODEL = line_model(0.1)
CONFIG = """
[model]
likelihood = "streammodel:loglike"
[data]
columns = ["t", "y"]
[priors]
a = {{ dist = "uniform", loc = -2.0, scale = 6.0 }}
b = {{ dist = "uniform", loc = -2.0, scale = 4.0 }}
[kernel]
a = {a_kernel}
b = {{ type = "drift", rate = -0.01, noise_std = 0.01 }}
[sampler]
type = "{sampler}"
n_samples = {n}
seed = {seed}
"""
DRIFT = '{ type = "drift", rate = 0.02, noise_std = 0.02 }'
JUMP = ('{ type = "jump", base = "drift", rate = 0.02, noise_std = 0.02, p = 0.05, drop_mean = 0.3, '
        'drop_sd = 0.1, reference = 2.0 }')
N_STREAMS = int(os.environ.get("SEQBAYES_STREAMS", "20"))


def stream(rng):
    """``(tables, config keywords)`` of one random stream: 3 datasets drawn from a simulated 60-step
    record with a jump of (a, b) at a random step, some taken out of order, one perhaps an outlier."""
    n_record = 60
    a = 1.0 + np.cumsum(0.02 + 0.02 * rng.standard_normal(n_record))
    b = 0.5 + np.cumsum(-0.01 + 0.01 * rng.standard_normal(n_record))
    jump = rng.integers(1, n_record)
    a[jump:] += rng.choice([-1, 1]) * rng.uniform(0.3, 2.0)
    b[jump:] += rng.uniform(-1.0, 1.0)
    n_steps = 3
    if rng.random() < 0.5:   # steps around the jump, shuffled
        lo = max(0, min(jump - n_steps // 2, n_record - n_steps))
        order = rng.permutation(np.arange(lo, lo + n_steps))
    else:                    # anywhere in the record, in any order
        order = rng.choice(n_record, n_steps, replace=False)
    t = np.linspace(0.0, 1.0, 15)
    tables = [np.column_stack([t, a[k] + b[k] * t + 0.1 * rng.standard_normal(t.size)]) for k in order]
    if rng.random() < 0.4:   # an outlier dataset: a few points off by 5 to 50 noise sds
        table = tables[rng.integers(len(tables))]
        hit = rng.choice(t.size, int(rng.integers(1, 5)), replace=False)
        table[hit, 1] += rng.choice([-1, 1], hit.size) * rng.uniform(0.5, 5.0, hit.size)
    keywords = dict(a_kernel=JUMP if rng.random() < 0.25 else DRIFT, sampler="SEMC" if rng.random() < 0.8 else "SMC",
                    n=20, seed=int(rng.integers(2**31)))
    return tables, keywords


@pytest.mark.slow
def test_every_stored_state_of_random_streams_reopens_and_resumes(tmp_path):
    rng = np.random.default_rng(2024)
    unknown_variance = 0           # stored states whose log-evidence variance was not estimated (NaN)
    for i in range(N_STREAMS):
        tables, keywords = stream(rng)
        folder = tmp_path / f"s{i}"
        folder.mkdir()
        (folder / "run.toml").write_text(CONFIG.format(**keywords))
        (folder / "streammodel.py").write_text(MODEL)
        cfg = load_config(folder / "run.toml")
        RunStore.create(folder / "run.nc", cfg)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")      # conflict and degeneracy warnings are expected here
            for k, table in enumerate(tables):
                store = RunStore.open(folder / "run.nc")          # every stored state re-opens ...
                assert store.n_steps == k
                store.assimilate(table, f"d{k}")                  # ... and resumes
            store = RunStore.open(folder / "run.nc")
            assert store.n_steps == len(tables), (i, keywords)
            unknown_variance += sum(not np.isfinite(float(s["state_log_evidence_variance"])) for s in store.states)
            if i % 10 == 0:
                reference = cfg.build_sampler()
                for table in tables:
                    reference.update(table)
                assert_same_steps(reference.result.steps, store.result.steps)
                assert store.rng_states[-1] == reference.snapshot()[2]
    # the case of issue 24 is among them: some stored variances are unknown, and those stores re-opened
    assert unknown_variance > 0
