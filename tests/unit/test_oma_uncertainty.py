"""The standard errors of OMA (issue 38, part 1): the first-order derivatives of every modal parameter with
respect to the block Toeplitz matrix against finite differences of the whole identification, and the
delete-one-block jackknife against that first-order propagation where the model has the right order."""

import numpy as np
import pytest

from seqbayes.structural.oma import building_3d, modal_record
from seqbayes.structural.oma.core import output_covariances, poles_at_order, real_shapes, toeplitz
from seqbayes.structural.oma.settings import normalise
from seqbayes.structural.oma.uncertainty import (
    jackknife_clusters,
    pole_derivatives,
    pole_standard_errors,
    toeplitz_blocks,
)

MODEL = building_3d(3, (2.6, 2.626, 3.6), damping=0.01, max_frequency=8.0,
                    sensors=[(3, "A", "X"), (3, "A", "Y"), (2, "B", "X")])
DT, S, NB = 0.05, 20, 20


@pytest.fixture(scope="module")
def record():
    return normalise(modal_record(MODEL, 600.0, DT, rng=np.random.default_rng(1)))


def test_first_order_derivatives_match_finite_differences(record):
    """Along two blocks' deviations, at an order above the true one (16 > 10 states): frequencies, damping
    ratios and real shapes of all 8 poles to 1e-5 relative (central differences, step 1e-6; measured 1e-8)."""
    blocks = toeplitz_blocks(record, S, 40, NB)
    H = toeplitz(output_covariances(record, 2 * S - 1), S)
    L = record.shape[0] // NB
    each = np.stack([toeplitz(output_covariances(record[k * L:(k + 1) * L], 2 * S - 1), S) for k in range(NB)])
    deviation = each - each.mean(axis=0)
    order = 16
    base = poles_at_order(blocks.U, 3, order, DT)
    _, d_f, d_z, d_phi = pole_derivatives(blocks, 3, order, DT, np.arange(base.frequencies.size))
    for k in (0, 3):
        sides = []
        for sign in (1, -1):
            poles = poles_at_order(np.linalg.svd(H + sign * 1e-6 * deviation[k])[0], 3, order, DT)
            j = [int(np.argmin(np.abs(poles.frequencies - f))) for f in base.frequencies]
            sides.append((poles.frequencies[j], poles.damping_ratios[j], real_shapes(poles.shapes[:, j])))
        for analytic, plus, minus in zip((d_f[k], d_z[k], d_phi[k]), sides[0], sides[1]):
            numeric = (plus - minus) / 2e-6
            np.testing.assert_allclose(analytic, numeric, rtol=1e-5, atol=1e-5 * np.max(np.abs(numeric)))


def test_jackknife_agrees_with_first_order_propagation_at_the_true_order(record):
    """At order 10 (the model's 5 modes and nothing else) both estimate the same standard errors: the
    frequencies' within 40 % (measured ratios 0.71-1.29: the jackknife takes the spread of its 20
    pseudo-values robustly, by their median absolute deviation, whose own relative error is about 25 %)."""
    blocks = toeplitz_blocks(record, S, 40, NB)
    poles = poles_at_order(blocks.U, 3, 10, DT)
    assert poles.frequencies.size == 5
    linear = pole_standard_errors(blocks, 3, 10, DT, np.arange(5))[0]
    jobs = [([10], poles.frequencies[[i]], poles.shapes[:, [i]], int(np.argmax(np.abs(poles.shapes[:, i]))))
            for i in range(5)]
    jack = np.array([r[0] for r in jackknife_clusters(blocks, 3, DT, jobs)])
    np.testing.assert_allclose(jack, linear, rtol=0.4)
    assert np.all(linear / poles.frequencies < 0.005)
