"""Issue 24 (high): an abrupt change must not brick the run. The engine's outputs and the run store's check on
open are one definition (:mod:`seqbayes.engine.drivers`): what the engine hands out, the store re-opens."""

from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import numpy as np
import pytest

from _user_model import line_model

from seqbayes.engine.drivers import OUTPUTS, InvalidStepError, allowed, check_step
from seqbayes.store import RunStore, StoreError, load_config, snapshot
from seqbayes.store.base import check_finite

MODEL = line_model(0.1)
CONFIG = """
[model]
likelihood = "linearmodel:loglike"
[data]
columns = ["t", "y"]
[priors]
a = { dist = "uniform", loc = 0, scale = 4 }
b = { dist = "uniform", loc = -1, scale = 2 }
[kernel]
a = { type = "drift", rate = 0.02, noise_std = 0.01 }
b = { type = "drift", rate = -0.01, noise_std = 0.005 }
[sampler]
type = "SEMC"
n_samples = N
seed = 8
"""


def linear_stream(seed: int, n_record: int = 60) -> dict:
    """Step -> (15, 2) table of t, y = a_s + b_s t + N(0, 0.1^2) over a simulated record whose a and b drift."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, 15)
    a = 1.0 + np.cumsum(0.02 + 0.01 * rng.standard_normal(n_record))
    b = 0.5 + np.cumsum(-0.01 + 0.005 * rng.standard_normal(n_record))
    return {s: np.column_stack([t, a[s - 1] + b[s - 1] * t + 0.1 * rng.standard_normal(t.size)])
            for s in range(1, n_record + 1)}


def linear_run(folder: Path, n: int = 100):
    (folder / "linearmodel.py").write_text(MODEL)
    (folder / "run.toml").write_text(CONFIG.replace("N", str(n)))
    return load_config(folder / "run.toml")


@pytest.mark.slow   # 7 SEMC steps of N = 100 through the path-space remedy: about 6 s of CPU
def test_datasets_out_of_order_store_an_unknown_variance_that_reopens_and_resumes(tmp_path, monkeypatch):
    """The issue's reproduction: steps 51, 1, 2, 52, 3, 53 of the stream, each through a store opened afresh.
    Step 53 follows step 3 (a jump of a and b) and is assimilated on the path space. When such a step's
    importance estimate is unreliable, its increment has no variance estimate and the cumulative variance is
    unknown (NaN); the store used to refuse itself from there on ("state_log_evidence_variance holds 1 NaN/inf
    value(s)"). Since the path-space stages stop on the distance travelled, this stream's step 53 has a reliable
    estimate, so the unknown variance is put there by the path step's own standard errors (the value they
    return for an unreliable estimate), and everything after is the store's and the engine's as they are."""
    from seqbayes.predictive import paths

    original, calls = paths._bridged_standard_errors, []

    def unknown_at_step_53(*args):
        calls.append(args[0].step)
        return (float("nan"),) * 3 if len(calls) == 5 else original(*args)
    monkeypatch.setattr(paths, "_bridged_standard_errors", unknown_at_step_53)
    cfg = linear_run(tmp_path)
    tables = linear_stream(8)
    RunStore.create(tmp_path / "run.nc", cfg)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")     # the conflict and unreliable-evidence warnings of these steps
        for step in (51, 1, 2, 52, 3, 53):
            RunStore.open(tmp_path / "run.nc").assimilate(tables[step], f"d{step}")
        assert calls == [1, 2, 3, 4, 5]      # steps 1, 2, 52, 3 and 53 took the path space; 53 the NaN
        store = RunStore.open(tmp_path / "run.nc")
        variances = [float(arrays["state_log_evidence_variance"]) for arrays in store.states]
        assert np.isfinite(variances[:5]).all() and np.isnan(variances[5]), variances
        assert np.isnan(store.result.steps[-1].info.log_evidence_se)
        assert np.isnan(store.state_at(6)[0].log_evidence_variance)
        # it resumes: the next dataset from a fresh object, the same as from the object that stored the step
        in_memory = store.assimilate(tables[4], "d4", write=False)
        resumed = RunStore.open(tmp_path / "run.nc").assimilate(tables[4], "d4")
    np.testing.assert_equal(dataclasses.asdict(dataclasses.replace(in_memory, wall_time=0)),
                            dataclasses.asdict(dataclasses.replace(resumed, wall_time=0)))
    assert RunStore.open(tmp_path / "run.nc").n_steps == 7


@pytest.mark.parametrize("variable, name", [
    ("state_log_evidence_variance", "log_evidence_variance"), ("posterior", "posterior"),
    ("predictive", "predictive"), ("log_weights", "log_weights"), ("initial_particles", "particles"),
    ("initial_log_weights", "log_weights"), ("dataset_values", "dataset"), ("nested_particles", "particles"),
    ("nested_log_weights", "log_weights"), ("nested_cloud_x", "cloud_x"), ("mixture_centres", "prior_centres"),
    ("mixsum_log_weights", "prior_log_weights"), ("state_log_prior", "log_prior"), ("state_paths", "paths"),
    ("diagnostics", "diagnostics")])
@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_the_store_refuses_on_open_exactly_what_the_engine_may_not_output(variable, name, value):
    """The store's check reads the engine's rule for each variable (snapshot.output_name), so they cannot drift
    apart: a value is refused on open if and only if the engine's rule for that output refuses it."""
    assert snapshot.output_name(variable) == name
    values = np.array([[0.5, value]])
    refused = bool(allowed(name).bad(values).any())
    if refused:
        with pytest.raises(StoreError, match=f"damaged run store: {variable} holds 1 NaN/inf"):
            check_finite(Path("run.nc"), {variable: values}, snapshot.output_name)
    else:
        check_finite(Path("run.nc"), {variable: values}, snapshot.output_name)
    # the rules themselves: samples finite, weights may be -inf, a variance NaN (unknown), nothing else NaN
    assert refused == (np.isnan(value) and name not in ("log_evidence_variance", "diagnostics")
                       or np.isinf(value) and name in ("posterior", "predictive", "particles", "dataset")
                       or value == np.inf and name == "log_weights"
                       or value == -np.inf and name == "log_evidence_variance")   # a variance is >= 0 or unknown
    assert set(OUTPUTS) >= {"posterior", "predictive", "particles", "log_weights", "log_evidence_variance"}


def test_the_engine_checks_every_step_against_the_same_rules(tmp_path):
    """check_step (run by assimilate after every step) passes a real step's state and refuses one holding
    what the store would refuse, naming the field; an unknown variance is allowed by both."""
    cfg = linear_run(tmp_path, n=40)
    sampler = cfg.build_sampler()
    sampler.update(linear_stream(1)[1])
    state, records, _ = sampler.snapshot()
    record = records[-1]
    check_step(state, record)
    check_step(dataclasses.replace(state, log_evidence_variance=float("nan")), record)
    bad = state.posterior.copy()
    bad[3, 1] = np.nan
    with pytest.raises(InvalidStepError, match=r"posterior holds 1 NaN/inf value\(s\), first at index \(3, 1\)"):
        check_step(dataclasses.replace(state, posterior=bad), record)
    with pytest.raises(InvalidStepError, match="log_weights holds 1"):
        check_step(state, dataclasses.replace(record, log_weights=np.where(np.arange(40) == 0, np.inf,
                                                                            record.log_weights)))
    centres = state.prior.centres.copy()
    centres[0, 0] = np.nan
    with pytest.raises(InvalidStepError, match="prior_centres holds 1"):
        check_step(dataclasses.replace(state, prior=dataclasses.replace(state.prior, centres=centres)), record)


def test_the_path_prior_density_of_no_walker_is_empty():
    """The property test's streams met a path-space step whose rejection round left no walker inside the box:
    the path prior's density of zero walkers is zero values, not a reshape error (which ended the update and,
    in tools/result_hash.py's oscillator run 0 under T6 with SEMC, the run at step 3)."""
    from types import SimpleNamespace

    from seqbayes.core.state import PastStep
    from seqbayes.kernels import Drift, MarkovKernel
    from seqbayes.predictive.paths import path_prior_logpdf

    prior = SimpleNamespace(logpdf=lambda theta: np.zeros(len(theta)))
    likelihood = SimpleNamespace(add_along_paths=lambda out, states, datasets, memos=None: out)
    window = (PastStep(np.zeros((3, 2)), prior, np.zeros((5, 2)), np.zeros(5), 0.0, 0.0),)
    kernel = MarkovKernel([Drift(0.0, noise_std=0.1), Drift(0.0, noise_std=0.1)])
    logpdf = path_prior_logpdf(window, kernel, likelihood, 2)
    assert logpdf(np.zeros((0, 4))).shape == (0,)
    np.testing.assert_array_equal(logpdf(np.zeros((3, 4))), kernel.logpdf(np.zeros((3, 2)), np.zeros((3, 2))))
