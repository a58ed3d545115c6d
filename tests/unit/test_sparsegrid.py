"""Sparse grid: point counts (Eq. 17), exactness on the hat-basis span, error
decreasing with level, and interpolation of the shear-building transitions."""

from math import comb

import numpy as np
import pytest

from seqbayes.structural.sparsegrid import SparseGrid, interpolate, point_count
from seqbayes.structural.transitions import SparseGridTransition
from seqbayes.structural.structures import ShearBuilding, discretise


@pytest.mark.parametrize("d, n", [(1, 1), (1, 5), (2, 3), (3, 6), (4, 4), (6, 3)])
def test_point_count_matches_eq17_sum_and_the_grid(d, n):
    eq17 = sum(2 ** (j - d) * comb(j - 1, d - 1) for j in range(d, n + d))
    assert point_count(d, n) == eq17 == SparseGrid(d, n).n_points
    assert len({tuple(p) for p in SparseGrid(d, n).points}) == eq17  # distinct points


def test_eq17_closed_form_is_only_an_upper_bound():
    # the paper's 2^n (n+d-1)!/((d-1)! n!) overcounts, e.g. d = 1 gives 2^n, not 2^n - 1
    assert point_count(1, 4) == 15
    assert point_count(3, 6) < 2**6 * comb(6 + 3 - 1, 3 - 1)


@pytest.mark.parametrize("basis", ["hat", "modified"])
@pytest.mark.parametrize("d, n", [(1, 6), (2, 5), (3, 4)])
def test_exact_on_functions_in_the_basis_span(basis, d, n):
    grid = SparseGrid(d, n, basis)
    rng = np.random.default_rng(d * 10 + n)
    surpluses = rng.standard_normal((grid.n_points, 2))
    f = lambda x: grid.basis_matrix(x) @ surpluses  # noqa: E731 - a function in the span
    np.testing.assert_allclose(grid.hierarchise(f(grid.points)), surpluses, atol=1e-11)
    fit = interpolate(f, d, n, basis=basis)
    x = rng.random((300, d))
    np.testing.assert_allclose(fit(x), f(x), atol=1e-11)


def test_hat_basis_reproduces_eq19_surplus_in_1d():
    # c = f(x) - (f(x - h) + f(x + h)) / 2 with zero boundary values
    f = lambda x: np.sin(3 * x[:, 0]) + 1  # noqa: E731
    grid = SparseGrid(1, 3, "hat")
    c = grid.hierarchise(f(grid.points))[:, 0]
    x = grid.points[:, 0]
    h = 2.0 ** -grid.levels[:, 0]
    left = np.where(x - h > 0, f((x - h)[:, None]), 0.0)
    right = np.where(x + h < 1, f((x + h)[:, None]), 0.0)
    np.testing.assert_allclose(c, f(grid.points) - 0.5 * (left + right), atol=1e-14)


def test_modified_basis_is_exact_on_linear_functions_and_error_falls_with_level():
    lin = interpolate(lambda x: 1 + x @ np.array([1.0, -2.0, 0.5]), 3, 2)
    x = np.random.default_rng(0).random((200, 3))
    np.testing.assert_allclose(lin(x)[:, 0], 1 + x @ np.array([1.0, -2.0, 0.5]), atol=1e-12)
    f = lambda x: np.exp(-((x - 0.3) ** 2).sum(axis=1))  # noqa: E731
    errors = [np.abs(interpolate(f, 3, n)(x)[:, 0] - f(x)).max() for n in range(2, 7)]
    assert all(b < 0.6 * a for a, b in zip(errors, errors[1:]))


def test_bad_input():
    with pytest.raises(ValueError, match="level"):
        SparseGrid(2, 0)
    with pytest.raises(ValueError, match="basis"):
        SparseGrid(2, 2, "cubic")
    with pytest.raises(ValueError, match="x"):
        SparseGrid(2, 2).basis_matrix(np.zeros((3, 3)))


def test_transition_interpolation_error_falls_with_level():
    b = ShearBuilding(np.array([15.51, 15.32, 14.66]) * 1e3, np.array([20.85, 9.23, 8.37]) * 1e6)
    theta = 0.7 + 0.3 * np.random.default_rng(2).random((100, 3))
    exact = discretise(b, theta, 0.02).A
    errs = []
    for level in (3, 4, 5):
        A = SparseGridTransition(b, 0.02, [0.7] * 3, [1.0] * 3, level)(theta).A
        errs.append(np.abs(A - exact).max())
    assert errs[0] > errs[1] > errs[2]
    assert errs[2] < 0.01


@pytest.mark.parametrize("dim, level", [(32, 2), pytest.param(21, 3, marks=pytest.mark.slow)])
def test_no_cap_on_dim_times_level(dim, level):
    # dim * level = 64, 63 > 62: the point keys take two int64 words (11 storeys at level 6, 114,687
    # points, build the same way; too slow for the unit tests)
    from seqbayes.structural.sparsegrid import SparseGrid, fit

    grid = SparseGrid(dim, level)
    rng = np.random.default_rng(0)
    values = rng.standard_normal(grid.n_points)
    interp = fit(grid, values)
    np.testing.assert_allclose(interp(grid.points)[:, 0], values, rtol=0, atol=1e-9)  # interpolates its nodes
    slope = rng.standard_normal(dim)
    linear = fit(grid, grid.points @ slope + 0.5)
    x = rng.random((20, dim))
    np.testing.assert_allclose(linear(x)[:, 0], x @ slope + 0.5, rtol=0, atol=1e-9)  # modified basis: exact
