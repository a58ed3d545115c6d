"""SMC^2 with ``strict_budget=True`` against the Kalman filter (issue 23).

The hard cap defers moves that a tempered update would otherwise complete. Each move is still a PMMH kernel that
leaves the current target invariant, applied to particles chosen by a permutation (seqbayes.predictive.pmmh), so the
run stays exact; what the cap can cost is Monte Carlo error. The mixed linear-Gaussian stream (two static, one
drifting, one decaying parameter; 30 datasets; its first update tempers from the prior in several stages) with the
exact Kalman inner filter, N = 500, the default budget, seeds 0-3. Measured (rms over seeds, steps and parameters
of the mean error in exact sds; rms and worst log-evidence error in nats):

- SMC: 0.061 strict against 0.071 without; sd error 0.034 against 0.036; log Z 0.26 (worst 0.58) against 0.18 (0.40);
- SEMC: 0.106 strict against 0.073; sd error 0.052 against 0.047; log Z 0.42 (worst 0.77) against 0.19 (0.41). Under
  the strict budget SEMC's PMMH proposes by differential evolution; with the stretch move it was 0.164, 0.062 and
  0.64 (worst 1.44): the stretch move travels half as far per PMMH re-run (docs/benchmarks.md, "Coulomb at 50,000
  calls");
- a budget too small to restore the cloud after the first update's resamplings (``move_budget=0.5``, SMC) leaves it
  degenerate: 1.16 sd and 8.1 nats rms (worst 21.6 nats).

The bars sit at twice the measured values, well below the degenerate run's.
"""

import warnings

import numpy as np
import pytest

from seqbayes.engine.settings import from_flat
import seqbayes
from seqbayes.models.linear_gaussian import LinearGaussianStateSpace
from seqbayes.predictive.smc2 import KalmanInnerFilter

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("name, mean_bar, sd_bar, log_z_bar", [("SMC", 0.12, 0.07, 0.5), ("SEMC", 0.21, 0.11, 0.85)])
def test_a_strict_budget_keeps_the_kalman_posterior(name, mean_bar, sd_bar, log_z_bar):
    problem = LinearGaussianStateSpace.mixed()
    data, _ = problem.simulate(30, rng=21)
    exact = problem.exact(data)
    mean_err, sd_err, log_z_err = [], [], []
    for seed in range(4):
        sampler = getattr(seqbayes, name)(problem.prior, problem.kernel, problem.loglike, n_samples=500, rng=seed, **from_flat(name, inner_filter=KalmanInnerFilter(problem.observe), strict_budget=True))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            infos = [sampler.update(y) for y in data]
        assert infos[0].n_stages > 1
        for k, (info, record) in enumerate(zip(infos, sampler.result.steps)):
            sd = np.sqrt(np.diag(exact[k].cov))
            mean_err.append((record.mean() - exact[k].mean) / sd)
            sd_err.append(record.std() / sd - 1)
            log_z_err.append(info.log_evidence - exact[k].log_evidence)
    rms = lambda x: float(np.sqrt(np.mean(np.square(x))))  # noqa: E731
    assert rms(mean_err) < mean_bar, rms(mean_err)
    assert rms(sd_err) < sd_bar, rms(sd_err)
    assert rms(log_z_err) < log_z_bar, rms(log_z_err)
