"""The modal likelihood (seqbayes.structural.modal_likelihood) and its linear models
(seqbayes.structural.structures.linear, .frame): exact checks against closed forms and between solvers."""

from itertools import permutations

import numpy as np
import pytest

from seqbayes.structural.modal_likelihood import ByAssignment, ByMode, Fixed, Learned, ModalLikelihood, modal_data
from seqbayes.structural.structures import ShearBuilding
from seqbayes.structural.structures.frame import plane_frame
from seqbayes.structural.structures.linear import (DenseSolver, FunctionModel, LinearModel, ModeLevel, ReducedBasis,
                                                   ShearBuildingModel, SparseSolver)

BUILDING = ShearBuilding([2e5, 2e5, 2e5, 1.6e5], [3e8, 2.6e8, 2.2e8, 1.8e8])


def _normal_logpdf(x, mean, sd):
    return -0.5 * np.log(2 * np.pi * sd ** 2) - 0.5 * ((x - mean) / sd) ** 2


def _shear_as_linear(solver=None, n_modes=3):
    n = BUILDING.n_storeys
    influence = []
    for i in range(n):
        K = np.zeros((n, n))
        K[i, i] = 1.0
        if i > 0:
            K[i - 1, i - 1] += 1.0
            K[i - 1, i] = K[i, i - 1] = -1.0
        influence.append(K * BUILDING.stiffnesses[i])
    return LinearModel(np.diag(BUILDING.masses), np.zeros((n, n)), influence, n_modes, range(n), solver=solver)


def _unit_largest(shapes):
    """(p, q) columns scaled so that the largest component is +1."""
    return shapes / shapes[np.argmax(np.abs(shapes), axis=0), np.arange(shapes.shape[1])]


def test_frequency_terms_are_the_gaussian_density():
    like = ModalLikelihood(ModeLevel(3), frequency_error=Fixed((0.01, 0.02, 0.03)), std_scale=2.0)
    theta = np.array([[0.35, 0.62, 1.3], [0.36, 0.60, 1.4]])
    data = {"mode": np.array([3, 1]), "frequency_hz": np.array([1.31, 0.351]), "std_frequency_hz": np.array([0.01, 0.0])}
    expected = (_normal_logpdf(1.31, theta[:, 2], np.hypot(0.02, 0.03 * theta[:, 2]))
                + _normal_logpdf(0.351, theta[:, 0], 0.01 * theta[:, 0]))
    assert np.allclose(like(theta, data), expected, rtol=0, atol=1e-12)


def test_learned_error_is_read_from_theta():
    like = ModalLikelihood(ModeLevel(1), frequency_error=Learned(1), std_scale=0.0)
    theta = np.array([[1.0, 0.01], [1.0, 0.02]])
    got = like(theta, {"mode": [1], "frequency_hz": [1.01], "std_frequency_hz": [0.0]})
    assert np.allclose(got, _normal_logpdf(1.01, 1.0, theta[:, 1]))
    assert like.n_parameters == 2


def test_shape_term_is_the_mac_criterion_with_equal_variances():
    model = ShearBuildingModel(BUILDING)
    f, s = model.modes(np.ones((1, 4)))
    measured = _unit_largest(s[0][:, :2]).T + np.array([[0.03, -0.02, 0.01, 0.0], [0.0, 0.02, -0.04, 0.01]])
    data = {"mode": np.array([1, 2]), "frequency_hz": f[0, :2], "std_frequency_hz": np.zeros(2)}
    for c in range(4):
        data[f"phi_{c + 1}"], data[f"std_phi_{c + 1}"] = measured[:, c], np.zeros(2)
    e = 0.05
    with_shapes = ModalLikelihood(model, frequency_error=0.01, shape_error=e, pairing=ByMode())
    freq_only = ModalLikelihood(model, frequency_error=0.01)
    theta = np.array([[1.0, 1.0, 1.0, 1.0], [0.9, 1.1, 1.0, 0.95]])
    shape_part = with_shapes(theta, data) - freq_only(theta, data)
    _, pred = model.modes(theta)
    expected = 0.0
    for r in range(2):
        phi, hat = measured[r], pred[:, :, r]
        mac = (hat @ phi) ** 2 / ((hat ** 2).sum(axis=1) * (phi @ phi))
        expected = expected - 0.5 * (phi @ phi) * (1 - mac) / e ** 2 - 2 * np.log(2 * np.pi * e ** 2)
    assert np.allclose(shape_part, expected, rtol=1e-10)


class _Crossing:
    """Two modes whose order swaps at theta = 1: a fixed one (1 Hz, shape (1, 1)) and one at theta Hz with
    shape (1, -1); ``modes`` returns them in ascending order, as an eigensolver does."""

    channels = ("a", "b")
    n_parameters = 1

    def modes(self, theta):
        t = theta[:, 0]
        freqs = np.column_stack([np.minimum(t, 1.0), np.maximum(t, 1.0)])
        moving_first = (t < 1.0)[:, None]
        fixed, moving = np.array([1.0, 1.0]), np.array([1.0, -1.0])
        first = np.where(moving_first, moving, fixed)
        second = np.where(moving_first, fixed, moving)
        return freqs, np.stack([first, second], axis=2)


def test_pairing_by_assignment_follows_a_mode_swap():
    data = {"mode": np.array([1, 2]), "frequency_hz": np.array([0.8, 1.0]), "std_frequency_hz": np.zeros(2),
            "phi_a": np.array([1.0, 1.0]), "phi_b": np.array([-1.0, 1.0]),
            "std_phi_a": np.zeros(2), "std_phi_b": np.zeros(2)}
    like = ModalLikelihood(_Crossing(), frequency_error=0.05, shape_error=0.05, pairing=ByAssignment())
    theta = np.array([[0.8], [1.2]])       # below and above the crossing

    def correct(t):          # measured 1 (0.8 Hz, shape (1, -1)) is the moving mode, measured 2 the fixed one
        shape = -0.5 * 2 * np.log(2 * np.pi * 0.05 ** 2)
        return (_normal_logpdf(0.8, t, 0.05 * t) + shape + _normal_logpdf(1.0, 1.0, 0.05) + shape)

    assert np.allclose(like(theta, data), [correct(0.8), correct(1.2)])
    _, pairs = like.predicted(theta, data)
    assert pairs.tolist() == [[0, 1], [1, 0]]
    by_mode = ModalLikelihood(_Crossing(), frequency_error=0.05, shape_error=0.05, pairing=ByMode())
    assert by_mode(theta, data)[1] < correct(1.2) - 100          # the fixed pairing mistakes the swapped modes


def test_assignment_resolves_clashes_optimally():
    rng = np.random.default_rng(0)
    cost = rng.uniform(0, 1, (200, 3, 5))
    cost[:, :, 0] -= 2                                            # every particle's best is mode 0 for all three
    pairs = ByAssignment().pair(cost, np.arange(1, 4), 5)
    for n in range(200):
        best = min(permutations(range(5), 3), key=lambda p: sum(cost[n, r, p[r]] for r in range(3)))
        assert np.isclose(cost[n, np.arange(3), pairs[n]].sum(), sum(cost[n, r, best[r]] for r in range(3)))


def test_missing_modes_have_no_term():
    like = ModalLikelihood(ModeLevel(3), frequency_error=0.01)
    theta = np.array([[0.35, 0.62, 1.3]])
    full = {"mode": [1, 2, 3], "frequency_hz": [0.35, 0.63, 1.3], "std_frequency_hz": [0, 0, 0]}
    part = {"mode": [2], "frequency_hz": [0.63], "std_frequency_hz": [0]}
    assert np.isclose(like(theta, part), _normal_logpdf(0.63, 0.62, 0.0062))
    terms = [_normal_logpdf(f, t, 0.01 * t) for f, t in zip(full["frequency_hz"], theta[0])]
    assert np.isclose(like(theta, full), sum(terms))


def test_solvers_agree():
    theta = np.random.default_rng(1).uniform(0.6, 1.4, (6, 4))
    f_ref, s_ref = ShearBuildingModel(BUILDING).modes(theta)
    for solver in (DenseSolver(), SparseSolver()):
        f, s = _shear_as_linear(solver).modes(theta)
        assert np.allclose(f, f_ref[:, :3], rtol=1e-10)
        mac = np.einsum("npq,npq->nq", s, s_ref[:, :, :3]) ** 2 / (
            np.einsum("npq,npq->nq", s, s) * np.einsum("npq,npq->nq", s_ref[:, :, :3], s_ref[:, :, :3]))
        assert np.allclose(mac, 1, atol=1e-10)


def test_reduced_basis_of_the_frame_is_accurate():
    frame = plane_frame()
    assert frame.n_dofs == 750 and len(frame.influence) == 10
    model = LinearModel(frame.mass, frame.stiffness0, frame.influence, 7, frame.observed, frame.channels,
                        solver=SparseSolver())
    basis = ReducedBasis.from_snapshots(model, np.vstack([np.ones(10), 1 + 0.3 * np.eye(10)]), extra_modes=0,
                                        tol=1e-6)
    errors = basis.errors(np.random.default_rng(2).uniform(0.6, 1.4, (3, 10)))
    assert np.abs(errors["frequency"][:, :5]).max() < 1e-5
    assert errors["one_minus_mac"][:, :5].max() < 1e-7


def test_function_model_matches_and_reports_a_broken_function():
    model = ShearBuildingModel(BUILDING)

    def eigen(theta):
        f, s = model.modes(theta[None])
        return f[0], s[0]
    theta = np.random.default_rng(3).uniform(0.7, 1.3, (3, 4))
    f, s = FunctionModel(eigen, 4, 4, ("1", "2", "3", "4")).modes(theta)
    assert np.array_equal(f, model.modes(theta)[0])

    def broken(theta):
        raise RuntimeError("no OpenSees here")
    with pytest.raises(RuntimeError, match="no OpenSees"):
        FunctionModel(broken, 4, 4).modes(theta)


@pytest.mark.parametrize("data, match", [
    ({"mode": [1, 1], "frequency_hz": [0.3, 0.31]}, "mode 1 twice"),
    ({"mode": [], "frequency_hz": []}, "no measured mode"),
    ({"mode": [0], "frequency_hz": [0.3]}, "positive integer"),
    ({"frequency_hz": [0.3]}, "missing column"),
    ({"mode": [1], "frequency_hz": [-0.3]}, "positive"),
])
def test_bad_data_is_named(data, match):
    with pytest.raises(ValueError, match=match):
        modal_data(data)


def test_bad_settings_are_named():
    with pytest.raises(ValueError, match="no mode shapes"):
        ModalLikelihood(ModeLevel(2), shape_error=0.1)
    with pytest.raises(ValueError, match="both zero"):
        ModalLikelihood(ModeLevel(2), frequency_error=0.0, std_scale=0.0)
    like = ModalLikelihood(ShearBuildingModel(BUILDING), shape_error=0.1)
    data = {"mode": [1], "frequency_hz": [1.0], "phi_x": [1.0]}
    with pytest.raises(ValueError, match="channel.*x"):
        like(np.ones((1, 4)), data)
