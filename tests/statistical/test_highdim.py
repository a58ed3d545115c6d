"""SMC and SEMC in 20 and 50 dimensions against a closed-form posterior and evidence (issue 14, item 2).

:class:`~seqbayes.models.correlated_gaussian.CorrelatedGaussian` (AR(1) prior correlation 0.8, one
dataset 2.5-10 times narrower than the prior in every direction). Above d = 10 the samplers use the
scaled moves (:mod:`seqbayes.moves.scaled`); the paper's moves fail here (at d = 50, N = 2000,
10 seeds: SMC -9.6 +- 8.0 nats, SEMC -48 +- 11; ``benchmarks/bench_highdim.py --moves paper``).

Tolerances from the measured Monte Carlo error at N = 1000 (``benchmarks/bench_highdim.py``, seeds
other than these): at d = 20 the reported standard error of log Z is 0.025-0.027 nats and the worst
of the 20 mean errors 0.07-0.11 posterior sd; at d = 50 the standard error is 0.09-0.11 nats (the
fitted importance density's ESS is ~100 of 1000) and the worst mean error 0.07-0.09 sd. The bounds are
0.15 nats (~6 se) and 0.25 sd at d = 20, 0.5 nats (the issue's bound, ~5 se) and 0.25 sd at d = 50.
Seeds fixed before looking at the results.
"""

import warnings

import numpy as np
import pytest

from seqbayes.engine.settings import from_flat
import seqbayes
from seqbayes.models.correlated_gaussian import CorrelatedGaussian


def first_update(cls, dim, seed, n=1000, strict=True, **settings):
    gauss = CorrelatedGaussian(dim)
    kernel = seqbayes.MarkovKernel([seqbayes.Static()] * dim)
    with warnings.catch_warnings():
        warnings.simplefilter("error" if strict else "ignore")  # strict: no fallback to the path estimate
        sampler = cls(gauss.prior(), kernel, gauss.loglike, n_samples=n, rng=np.random.default_rng([99, seed]),
                      **from_flat(cls.__name__, **settings))
        info = sampler.update(gauss.data)
    return gauss.errors(sampler.result.steps[0]), info


@pytest.mark.parametrize("cls", [seqbayes.SMC, seqbayes.SEMC])
@pytest.mark.parametrize("seed", [0, 1])
def test_d20_evidence_and_means(cls, seed):
    (z_err, mean_err), info = first_update(cls, 20, seed)
    assert abs(z_err) < 0.15, (z_err, info.log_evidence_se)
    assert mean_err < 0.25, mean_err
    assert info.log_evidence_se < 0.05  # the importance density fits: no degenerate weights


@pytest.mark.parametrize("cls", [seqbayes.SMC, seqbayes.SEMC])
def test_d50_evidence_and_means(cls):
    (z_err, mean_err), info = first_update(cls, 50, 0)
    assert abs(z_err) < 0.5, (z_err, info.log_evidence_se)
    assert mean_err < 0.25, mean_err


def test_d50_the_paper_moves_fail_where_the_scaled_ones_hold():
    """The reason for the switch: forced back to the paper's random walk (gamma = 1), SMC's evidence is
    off by far more than its tolerance at d = 50 (measured at N = 2000: -9.6 +- 8.0 nats over 10 seeds; here one run, N = 500)."""
    (z_paper, _), _ = first_update(seqbayes.SMC, 50, 0, n=500, strict=False, scaled_moves=False,
                                   max_moves=5)
    assert abs(z_paper) > 1.0, z_paper
