"""Jump kernel on the abrupt drop (issue 11) against the exact grid filter: posterior means,
cumulative log-evidence and the posterior probability of a jump at every step, for SMC and SEMC.

The reference (:func:`seqbayes.studies.abrupt_drop.exact_reference`) is checked first against
the oscillator's own grid filter on a smooth kernel (the same filter; they must agree to
round-off), then the samplers against it. Tolerances come from the measured Monte Carlo error:
``benchmarks/bench_jump.py --exact`` (10 drop histories x SEMC and SMC, N = 1000) gave, over the 8
steps of the jump kernel's runs, worst errors of 0.20 posterior sds in the means, 0.40 nats in
the cumulative log-evidence and 0.005 in the jump probability (20 runs); the tolerances below
are 1.5 times those, rounded up. The test runs a reduced history (5 steps, the drop at step 3),
whose worst error over fewer steps is no larger in distribution.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from seqbayes import SEMC, SMC
from seqbayes.models import oscillator as osc
from seqbayes.studies import abrupt_drop as ad

MEAN_TOL_SD, LOGZ_TOL, P_TOL = 0.3, 0.6, 0.0075


def test_reference_is_the_oscillator_grid_filter_on_a_smooth_kernel():
    data = ad.simulate(np.random.default_rng(5), n_steps=3, drop_step=None)
    kernel = ad.candidate_kernels()["decay"]
    ours = ad.exact_reference(data.datasets, kernel)
    theirs = osc.exact_grid_reference(data.datasets, kernel)
    np.testing.assert_allclose(ours.grid.log_evidence, theirs.log_evidence, rtol=0, atol=1e-8)
    np.testing.assert_allclose(ours.grid.mean, theirs.mean, rtol=1e-10)
    np.testing.assert_allclose(ours.grid.std, theirs.std, rtol=1e-8)
    assert np.all(np.isnan(ours.jump_probability))        # no jump component


@pytest.fixture(scope="module")
def drop_reference():
    data = ad.simulate(np.random.default_rng(0), n_steps=5, drop_step=3)
    return data, ad.exact_reference(data.datasets, ad.candidate_kernels()["jump"])


def test_exact_jump_probability_singles_out_the_drop_step(drop_reference):
    data, ref = drop_reference
    p = ref.jump_probability[:, 0]
    assert np.isnan(p[0])
    assert p[data.drop_step - 1] > 0.999
    assert np.all(np.delete(p, [0, data.drop_step - 1]) < 0.01)


@pytest.mark.parametrize("cls", [SMC, SEMC])
def test_sampler_matches_the_exact_reference(drop_reference, cls):
    data, ref = drop_reference
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = cls(osc.prior(), ad.candidate_kernels()["jump"], osc.log_likelihood, n_samples=1000,
                     rng=np.random.default_rng(21)).run(data.datasets)
    errors = ref.grid.errors(result.means(), result.stds(), [s.info.log_evidence for s in result.steps])
    assert np.max(np.abs(errors["mean_sd"])) < MEAN_TOL_SD
    assert np.max(np.abs(errors["log_evidence"])) < LOGZ_TOL
    p = np.array([s.info.jump_probability for s in result.steps])
    assert np.isnan(p[0])
    np.testing.assert_allclose(p[1:], ref.jump_probability[1:, 0], rtol=0, atol=P_TOL)
