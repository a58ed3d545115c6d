"""Issue 11's acceptance in reduced form: run 9 of the damped-oscillator study (kernel T2), the
prior-data conflict of the issue, against the exact grid reference at every step.

``benchmarks/bench_abrupt.py`` (10 seeds, N = 1000; docs/prior_data_conflict.md): with the remedy (its bridge
from the path prior pooled with the stored paths' start) SMC's worst mean error over the six steps and ten seeds
is 0.08 exact sds and its worst cumulative log-evidence error 0.09 nats (0.17 and 0.10 starting from the stored
paths alone); without the remedy 9.4 sds and 119 nats. One seed here, held to the issue's bar (0.3 sd, 0.5 nats:
3.7 and 5.5 times the worst of those ten seeds).
"""

import warnings

import numpy as np

from seqbayes.engine.settings import from_flat
from seqbayes.models import oscillator as osc
from seqbayes import SMC, PriorDataConflictWarning


def test_run_9_follows_the_exact_grid_filter_through_the_conflict():
    problem = osc.study_problem(9)
    reference = osc.load_exact_references()[(9, "T2")]
    sampler = SMC(osc.prior(), problem.kernels["T2"].kernel, osc.log_likelihood, n_samples=1000, rng=0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = sampler.run(problem.datasets)
    assert any(issubclass(w.category, PriorDataConflictWarning) for w in caught)  # the diagnostic fires
    assert all(r.info.path_steps > 0 for r in result.steps[2:])                  # and the remedy ran
    errors = reference.errors(result.means(), result.stds(), [r.info.log_evidence for r in result.steps])
    assert np.all(np.abs(errors["mean_sd"]) < 0.3)
    assert np.all(np.abs(errors["log_evidence"]) < 0.5)


def test_run_9_under_a_losing_kernel_reaches_the_major_mode_of_the_path_posterior():
    # Under T3 (k x 0.46 a month; the data hold k at 1.47 from t = 4) no path fits every dataset and the window's
    # path posterior has one mode per choice of the dataset given up (docs/prior_data_conflict.md). Starting from
    # the stored paths (remedy_bridge=False) SMC ends in a minor mode, 24 exact sds and 41 nats off at step 6;
    # the bridge from the path prior (the default) weighs the modes afresh, and is pooled with the stored start,
    # which supplies the step-5 minor mode (~5 % of the mass) that the bridge alone lost: its sd of k at step 5
    # was 0.42 of the exact one (std_ratio -0.58). Seeds 0-9 (scratch script, this commit): std_ratio of k at
    # step 5 from -0.106 to +0.079, worst mean error 0.069 sds, worst evidence error 0.195 nats; one seed here,
    # held to the bar and to |std_ratio| < 0.3 (5 sds of that spread; the bridge alone fails it).
    problem = osc.study_problem(9)
    reference = osc.load_exact_references()[(9, "T3")]
    kernel = problem.kernels["T3"].kernel
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PriorDataConflictWarning)
        bridged = SMC(osc.prior(), kernel, osc.log_likelihood, n_samples=1000, rng=0).run(problem.datasets)
        stored = SMC(osc.prior(), kernel, osc.log_likelihood, n_samples=1000, rng=0, **from_flat("SMC", remedy_bridge=False)).run(problem.datasets)
    evidence = [r.info.log_evidence for r in bridged.steps]
    errors = reference.errors(bridged.means(), bridged.stds(), evidence)
    assert all(r.info.path_steps > 0 for r in bridged.steps[1:])
    assert np.all(np.abs(errors["mean_sd"]) < 0.3)
    assert np.all(np.abs(errors["log_evidence"]) < 0.5)
    assert abs(errors["std_ratio"][4, 0]) < 0.3  # the step-5 posterior holds both modes of the path posterior
    missed = reference.errors(stored.means(), stored.stds(), [r.info.log_evidence for r in stored.steps])
    assert np.abs(missed["mean_sd"][-1]).max() > 3.0 and missed["log_evidence"][-1] < -5.0  # the control misses
