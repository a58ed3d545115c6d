"""Pseudo-marginal moves (``SubsampledPrior``) against the Kalman filter on a drifting linear-Gaussian problem.

Two random walks (process sd 0.1), 10 observations per dataset (noise sd 0.5), prior N(0, 1), 20
steps, N = 2000 with ``pseudo_marginal_from = 1000`` so that the pseudo-marginal path runs at a size
the suite can afford (the default switches it on from N = 4096).

Tolerances from ``benchmarks/bench_pseudo_marginal.py --n 2000 --from 1000 --seeds 10`` (SMC, 10
seeds, load 9): RMS over seeds and steps of the posterior mean error 0.031 sd with pseudo-marginal
moves (0.038 with exact evaluation), of the sd ratio error 0.020 (0.018), of the log-evidence
increment error 0.026 nats (0.030); pseudo-marginal moves in 95 % of the steps. The bounds below
are ~2x those RMS values over the 3 seeds tested here (a RMS over 60 step errors is within ~20 % of
its expectation), and the steps' moves must have been pseudo-marginal in at least 80 % of the steps.
"""

import numpy as np
import pytest

from seqbayes.engine.settings import from_flat
from seqbayes import SEMC, SMC
from seqbayes.predictive.pseudo_marginal import SubsampledPrior
from seqbayes.models.linear_gaussian import LinearGaussianStateSpace


def model():
    rng = np.random.default_rng(3)
    return LinearGaussianStateSpace(rng.normal(size=(10, 2)), ("drift", "drift"), rates=np.zeros(2),
                                    process_std=np.full(2, 0.1), prior_mean=np.zeros(2), prior_std=np.ones(2),
                                    noise_std=0.5)


@pytest.mark.parametrize("cls", [SMC, SEMC])
def test_pseudo_marginal_runs_match_the_kalman_filter(cls, monkeypatch):
    used = []
    original = SubsampledPrior.start

    def start(self, *args, **kwargs):
        out = original(self, *args, **kwargs)
        used.append(self.n_terms is not None)
        return out

    monkeypatch.setattr(SubsampledPrior, "start", start)
    lg = model()
    mean_err, sd_err, inc_err, z = [], [], [], []
    for seed in range(3):
        data, _ = lg.simulate(20, rng=1000 + seed)
        exact = lg.exact(data)
        sampler = cls(lg.prior, lg.kernel, lg.loglike, n_samples=2000, rng=seed, **from_flat(cls.__name__, pseudo_marginal_from=1000))
        for y, e in zip(data, exact):
            info = sampler.update(y)
            record = sampler.result.steps[-1]
            sd = np.sqrt(np.diag(e.cov))
            mean_err.append((record.mean() - e.mean) / sd)
            sd_err.append(record.std() / sd - 1.0)
            inc_err.append(info.log_evidence_increment - e.log_evidence_increment)
        z.append((info.log_evidence - e.log_evidence) / info.log_evidence_se)
    rms = lambda values: float(np.sqrt(np.mean(np.square(values))))   # noqa: E731
    assert np.mean(used) >= 0.8, used
    assert rms(mean_err) < 0.07, rms(mean_err)
    assert np.max(np.abs(mean_err)) < 0.25, np.max(np.abs(mean_err))
    assert rms(sd_err) < 0.045, rms(sd_err)
    assert rms(inc_err) < 0.06, rms(inc_err)
    assert np.all(np.abs(z) < 4.0), z   # the stated standard error of the cumulative log-evidence is honest
