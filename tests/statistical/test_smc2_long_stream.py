"""SMC^2 over a long stream at a bounded cost, against the exact grid filter (issue 23): a reduced form of
``benchmarks/bench_longstream.py nonlinear`` (300 datasets, N = 1000, M = 100, 3 seeds per sampler; docs/benchmarks.md).

Here 100 datasets of the nonlinear static + drifting problem (:class:`~seqbayes.models.sine_phase.SinePhase`), the
particle inner filter with M = 50 and N = 500, one seed per sampler. The accuracy bounds are the issue's (0.3 sd,
20 %, 0.5 nats); the benchmark's worst errors at N = 1000 are about half of them, and halving N raises Monte Carlo
errors by sqrt(2). The cost bounds are those of the design: an update that neither tempers nor resamples spends at most
``MOVE_BUDGET N M`` evaluations on moves besides the advance ``N M`` and the guide's pilot (at most 4 x 2000), no
update spends more than 20x the median, and PMMH acceptance stays at or above 0.2 in every rejuvenation.
"""

import numpy as np
import pytest

from seqbayes.engine.settings import from_flat
from seqbayes import SEMC, SMC
from seqbayes.models.sine_phase import SinePhase
from seqbayes.predictive.pmmh import MOVE_BUDGET

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def stream():
    problem = SinePhase()
    data = problem.simulate(100, rng=4100)
    return problem, data, problem.exact(data, n_points=(801, 151))   # ~9 points per posterior sd at s = 100


@pytest.mark.parametrize("cls", [SMC, SEMC])
def test_a_long_stream_stays_exact_at_a_bounded_cost(cls, stream):
    problem, data, grid = stream
    n, m = 500, 50
    log_z = np.cumsum([g.log_evidence_increment for g in grid])
    sampler = cls(problem.prior, problem.kernel, problem.loglike, n_samples=n, rng=3, **from_flat(cls.__name__, n_inner=m))  # the budget is the default
    infos = []
    for s, y in enumerate(data, start=1):
        info = sampler.update(y)
        infos.append(info)
        if s in (30, 100):
            record, g = sampler.result.steps[-1], grid[s - 1]
            assert np.all(np.abs(record.mean() - g.mean) < 0.3 * g.std), (s, record.mean(), g.mean, g.std)
            assert np.all(np.abs(record.std() / g.std - 1) < 0.2), (s, record.std(), g.std)
            assert abs(info.log_evidence - log_z[s - 1]) < 0.5, (s, info.log_evidence, log_z[s - 1])
    evals = np.array([i.n_loglike_evals for i in infos])
    steady = np.array([i.n_stages == 1 and not i.resampled for i in infos])   # a resampling first restores the ESS
    steady[0] = False
    assert np.all(evals[steady] <= (1 + MOVE_BUDGET) * n * m + 8000 + np.arange(1, 101)[steady] * m), evals
    assert evals.max() <= 20 * np.median(evals)
    # each rejuvenation's acceptance over all its attempts: its tally at the step before the next one starts
    starts = [i.step for i in infos[1:] if i.resampled]
    ends = [infos[s - 2] for s in starts[1:]] + [infos[-1]]
    acceptances = [i.pmmh_acceptance for i in ends]
    assert len(starts) >= 3 and min(acceptances) >= 0.2, list(zip(starts, acceptances))
