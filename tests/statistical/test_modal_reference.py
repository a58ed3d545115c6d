"""Updating from identified modes against exact references at every step (issue 38): the 4-storey shear
building against grid filters, the 750-DOF frame against the bundled importance-sampling reference.

The bars are the issue's: means within 0.3 posterior sds, sds within 20 %, cumulative log-evidence within
0.5 nats, at every step. ``benchmarks/bench_modal_reference.py --shear --frame`` measured the samplers'
spread over seeds (docs/modal.md): the largest errors there are a third of the bars or less, so one seed
per case here fails only for a real change. The references' own errors (grid convergence at 1.5x the
points, the importance sampler's Monte Carlo errors) are below 2 % of the bars and are checked too.

The frame runs SEMC at N = 500, half the benchmark's N (the run is the test's cost: 56 CPU-s at N = 1000,
32 at 500). At N = 500, seeds 0 and 1 (``frame_case()``, the bundled reference) erred by at most 0.139 and
0.117 sd on the means, 9.1 % and 5.5 % on the sds and 0.070 and 0.038 nats, against 0.073-0.086 sd, 5.9-6.3 %
and 0.073 nats at N = 1000 (docs/modal.md): the errors grow by about sqrt(2), and the worst is still below
half of each bar.
"""

import warnings

import numpy as np
import pytest

from seqbayes import SEMC, SMC
from seqbayes.structural.modal_references import (SHEAR_CASES, datasets_digest, frame_case, grid_reference,
                                                 read_importance_reference, shear_building_case)

pytestmark = pytest.mark.slow

BARS = {"mean_sd": 0.3, "std_ratio": 0.2, "log_evidence": 0.5}


def _check(ref, result):
    e = ref.errors(result.means(), result.stds(), result.log_evidence)
    worst = (np.abs(e["mean_sd"]).max(), np.abs(e["std_ratio"]).max(), np.abs(e["log_evidence"]).max())
    assert worst[0] < BARS["mean_sd"], worst
    assert worst[1] < BARS["std_ratio"], worst
    assert worst[2] < BARS["log_evidence"], worst


def _run(cls, case, seed=0, n_samples=1000):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return cls(case.prior, case.kernel, case.likelihood, n_samples=n_samples, rng=seed).run(case.datasets)


@pytest.mark.parametrize("name", list(SHEAR_CASES))
def test_shear_building_against_the_grid_filter(name):
    case = shear_building_case(name)
    n = 61 if len(case.names) == 3 else 121
    ref = grid_reference(case, n_points=n)
    fine = grid_reference(case, n_points=int(1.5 * n) | 1)
    assert np.abs(ref.log_evidence - fine.log_evidence).max() < 0.01
    assert np.abs((ref.mean - fine.mean) / fine.std).max() < 0.02
    for cls in (SEMC, SMC):
        _check(fine, _run(cls, case))


def test_frame_against_the_importance_sampling_reference():
    case = frame_case()
    ref, se, digest = read_importance_reference()
    assert digest == datasets_digest(case), "the frame case is not the one the bundled reference was computed for"
    assert np.max(se["mean"] / ref.std) < 0.01 and np.max(se["log_evidence"]) < 0.01
    _check(ref, _run(SEMC, case, n_samples=500))
