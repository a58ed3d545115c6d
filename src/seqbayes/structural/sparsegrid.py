"""Smolyak sparse-grid interpolation with a hierarchical piecewise-linear basis
(Lin et al. 2024, Eqs. 12-20), on ``[0, 1]^d`` or on a box.

Grid (Eq. 12): 1-D nodes ``x_{l,j} = j 2^-l`` with ``l >= 1`` and odd
``j = 1, 3, ..., 2^l - 1`` (no boundary nodes). A subspace ``W_l`` (Eq. 14)
holds the tensor products of the 1-D functions of levels ``l = (l_1..l_d)``;
the sparse grid of level ``n`` is the sum of the ``W_l`` with
``|l|_1 <= n + d - 1`` (Eq. 16), with ``sum_{j=d}^{n+d-1} 2^(j-d) C(j-1, d-1)``
points (Eq. 17, first equality; the paper's closed form
``2^n (n+d-1)! / ((d-1)! n!)`` is an upper bound, not an equality: for
``d = 1`` the count is ``2^n - 1``).

Basis (Eq. 13): ``basis="hat"`` is the paper's hat ``phi((x - j h) / h)``,
which vanishes on the boundary of the cube, so a function that is non-zero
there is poorly represented near the faces. ``basis="modified"`` (the default;
Pflueger's modified linear basis, same nodes and point count) replaces the
level-1 function by the constant 1 and the outermost hats of each level by
functions that extrapolate linearly to the boundary; it is what makes the
interpolant usable on a whole prior box.

Surpluses (Eqs. 19-20) are computed by dimension-wise hierarchisation: in
each dimension the 1-D stencil ``c = v - (v_left + v_right) / 2`` (the
``[-1/2, 1, -1/2]`` of Eq. 19; boundary values 0 for the hat basis, linear
extrapolation for the modified basis) is applied to all points at once.

Evaluation at ``M`` points touches one basis function per subspace per
point, so it costs ``O(M * S * (d + K))`` for ``S`` subspaces and ``K``
outputs, done as one sparse-matrix product.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from itertools import combinations
from math import comb

import numpy as np
import scipy.sparse as sp

__all__ = ["point_count", "SparseGrid", "SparseGridInterpolant", "fit", "interpolate", "BASES"]

BASES = ("modified", "hat")


def point_count(dim: int, level: int) -> int:
    """Number of points of the level-``level`` sparse grid in ``dim`` dimensions (Eq. 17).

    ``|V_n| = sum_{j=d}^{n+d-1} 2^(j-d) * C(j-1, d-1)``.

    Examples
    --------
    >>> point_count(1, 3), point_count(2, 3), point_count(3, 6)
    (7, 17, 1023)
    """
    dim, level = _check_dim_level(dim, level)
    return sum(2 ** (j - dim) * comb(j - 1, dim - 1) for j in range(dim, level + dim))


def _check_dim_level(dim, level):
    if not isinstance(dim, (int, np.integer)) or dim < 1:
        raise ValueError(f"dim: expected a positive integer, got {dim!r}")
    if not isinstance(level, (int, np.integer)) or level < 1:
        raise ValueError(f"level: expected a positive integer, got {level!r}")
    return int(dim), int(level)


def _compositions(total: int, parts: int):
    """All tuples of ``parts`` positive integers summing to ``total``."""
    for cuts in combinations(range(1, total), parts - 1):
        bounds = (0,) + cuts + (total,)
        yield tuple(bounds[i + 1] - bounds[i] for i in range(parts))


def _trailing_zeros(n: np.ndarray) -> np.ndarray:
    """Number of trailing zero bits of positive integers (vectorised)."""
    n = n.astype(np.int64)
    return np.log2(n & -n).round().astype(np.int64)


@dataclass(frozen=True)
class SparseGrid:
    """The nodes of a level-``level`` sparse grid on ``[0, 1]^dim``.

    Attributes
    ----------
    dim, level : int
    basis : str
        ``"modified"`` (default) or ``"hat"``.
    subspace_levels : (S, d) int array
        Level vectors ``l`` of the subspaces ``W_l`` with ``|l|_1 <= n + d - 1``,
        ordered by ``|l|_1``.
    levels, indices : (P, d) int arrays
        Level ``l_t`` and odd index ``j_t`` of every point.
    points : (P, d) array
        Coordinates ``j_t 2^-l_t``.

    Examples
    --------
    >>> g = SparseGrid(2, 2)
    >>> g.points.tolist()
    [[0.5, 0.5], [0.5, 0.25], [0.5, 0.75], [0.25, 0.5], [0.75, 0.5]]
    """

    dim: int
    level: int
    basis: str = "modified"
    subspace_levels: np.ndarray = field(init=False, repr=False)
    subspace_offsets: np.ndarray = field(init=False, repr=False)
    subspace_strides: np.ndarray = field(init=False, repr=False)
    levels: np.ndarray = field(init=False, repr=False)
    indices: np.ndarray = field(init=False, repr=False)
    points: np.ndarray = field(init=False, repr=False)
    _keys_sorted: np.ndarray = field(init=False, repr=False)
    _key_order: np.ndarray = field(init=False, repr=False)

    def __post_init__(self):
        dim, level = _check_dim_level(self.dim, self.level)
        if self.basis not in BASES:
            raise ValueError(f"basis: expected one of {BASES}, got {self.basis!r}")
        subspaces = [c for total in range(dim, level + dim) for c in _compositions(total, dim)]
        subspace_levels = np.array(subspaces, dtype=np.int64).reshape(-1, dim)
        sizes = 2 ** (subspace_levels - 1)  # points per dimension in W_l
        counts = sizes.prod(axis=1)
        offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])
        strides = np.ones_like(sizes)  # C order inside a subspace
        for t in range(dim - 2, -1, -1):
            strides[:, t] = strides[:, t + 1] * sizes[:, t + 1]
        lv, ix = [], []
        for s in range(subspace_levels.shape[0]):
            grids = np.meshgrid(*[np.arange(sz) for sz in sizes[s]], indexing="ij")
            cell = np.stack([g.reshape(-1) for g in grids], axis=1)  # (count, d)
            lv.append(np.broadcast_to(subspace_levels[s], cell.shape))
            ix.append(2 * cell + 1)
        levels = np.concatenate(lv).astype(np.int64)
        indices = np.concatenate(ix).astype(np.int64)
        object.__setattr__(self, "dim", dim)
        object.__setattr__(self, "level", level)
        object.__setattr__(self, "subspace_levels", subspace_levels)
        object.__setattr__(self, "subspace_offsets", offsets)
        object.__setattr__(self, "subspace_strides", strides)
        object.__setattr__(self, "levels", levels)
        object.__setattr__(self, "indices", indices)
        object.__setattr__(self, "points", indices / 2.0**levels)
        keys = self._keys(levels, indices)
        order = np.argsort(keys)
        object.__setattr__(self, "_keys_sorted", keys[order])
        object.__setattr__(self, "_key_order", order)

    @property
    def n_points(self) -> int:
        return self.points.shape[0]

    def _keys(self, levels, indices) -> np.ndarray:
        """One sortable key per point: the heap positions per dimension (``< 2^level``)
        packed ``level`` bits each into int64 words of at most 62 bits; a single word
        when ``dim * level <= 62``, else a structured array of words (lexicographic
        order), so there is no cap on ``dim * level``."""
        pos = 2 ** (levels - 1) + (indices - 1) // 2  # heap position per dimension, < 2^level
        per_word = max(1, 62 // self.level)
        words = []
        for start in range(0, self.dim, per_word):  # loop over key words (usually one)
            stop = min(start + per_word, self.dim)
            shifts = np.arange(stop - start, dtype=np.int64) * self.level
            words.append((pos[..., start:stop] << shifts).sum(axis=-1))
        if len(words) == 1:
            return words[0]
        stacked = np.ascontiguousarray(np.stack(words, axis=-1))
        dtype = np.dtype([(f"w{i}", "<i8") for i in range(len(words))])
        return stacked.view(dtype)[..., 0]

    def _lookup(self, levels, indices) -> np.ndarray:
        keys = self._keys(levels, indices)
        where = np.searchsorted(self._keys_sorted, keys)
        where = np.clip(where, 0, self._keys_sorted.size - 1)
        if not np.all(self._keys_sorted[where] == keys):  # pragma: no cover - grid is downward closed
            raise RuntimeError("sparse grid: a hierarchical parent is missing")
        return self._key_order[where]

    # ------------------------------------------------------------ hierarchisation
    def _parent(self, t, level_t, numerator):
        """Point ids of the nodes ``numerator * 2^-level_t`` in dimension ``t`` (others kept);
        ``-1`` where the node is on the boundary."""
        out = np.full(numerator.shape, -1, dtype=np.int64)
        inside = (numerator > 0) & (numerator < 2**level_t)
        if np.any(inside):
            n_in = numerator[inside]
            tz = _trailing_zeros(n_in)
            lv = self.levels[inside].copy()
            ix = self.indices[inside].copy()
            lv[:, t] = level_t[inside] - tz
            ix[:, t] = n_in >> tz
            out[inside] = self._lookup(lv, ix)
        return out

    def hierarchise(self, values: ArrayLike) -> np.ndarray:
        """Hierarchical surpluses ``c`` (Eqs. 19-20) from nodal values.

        Parameters
        ----------
        values : (P,) or (P, K) array
            Function values at :attr:`points`.

        Returns
        -------
        surpluses : (P, K) array
        """
        values = np.asarray(values, dtype=float)
        if values.ndim == 1:
            values = values[:, None]
        if values.ndim != 2 or values.shape[0] != self.n_points:
            raise ValueError(f"values: expected shape ({self.n_points}, K), got {values.shape}")
        c = values.copy()
        zero = np.zeros((1, c.shape[1]))
        for t in range(self.dim):  # Eq. 20: product of 1-D stencils, one dimension at a time
            l = self.levels[:, t]
            j = self.indices[:, t]
            padded = np.vstack([c, zero])  # index -1 -> boundary value 0
            if self.basis == "hat":
                left = self._parent(t, l, j - 1)
                right = self._parent(t, l, j + 1)
                c = c - 0.5 * (padded[left] + padded[right])  # Eq. 19
                continue
            # modified basis: level 1 constant; level 2: lower interpolant is the constant;
            # outermost nodes: linear extrapolation of the two nearest coarser nodes.
            new = c.copy()
            lev2 = l == 2
            centre = self._parent(t, np.ones_like(l), np.ones_like(l))
            new[lev2] -= padded[centre[lev2]]
            deep = l >= 3
            first = deep & (j == 1)
            last = deep & (j == 2**l - 1)
            inner = deep & ~first & ~last
            left = self._parent(t, l, j - 1)
            right = self._parent(t, l, j + 1)
            new[inner] -= 0.5 * (padded[left[inner]] + padded[right[inner]])
            if np.any(first):
                a = self._parent(t, l, np.full_like(j, 2))  # node 2h
                b = self._parent(t, l, np.full_like(j, 4))  # node 4h
                new[first] -= 1.5 * padded[a[first]] - 0.5 * padded[b[first]]
            if np.any(last):
                a = self._parent(t, l, 2**l - 2)
                b = self._parent(t, l, 2**l - 4)
                new[last] -= 1.5 * padded[a[last]] - 0.5 * padded[b[last]]
            c = new
        return c

    # ----------------------------------------------------------------- evaluation
    def basis_matrix(self, x: ArrayLike) -> sp.csr_matrix:
        """Sparse ``(M, P)`` matrix of basis values ``phi_p(x_m)`` (Eq. 18).

        Each row has one non-zero per subspace (the cell of ``x`` in ``W_l``).
        """
        x = np.asarray(x, dtype=float)
        if x.ndim == 1 and self.dim == 1:
            x = x[:, None]
        if x.ndim != 2 or x.shape[1] != self.dim:
            raise ValueError(f"x: expected shape (M, {self.dim}), got {x.shape}")
        if not np.all(np.isfinite(x)):
            raise ValueError("x: contains NaN or inf")
        x = np.clip(x, 0.0, 1.0)
        L = self.subspace_levels[None]  # (1, S, d)
        scale = 2.0**L
        size = 2 ** (L - 1)
        cell = np.clip(np.floor(x[:, None, :] * size), 0, size - 1).astype(np.int64)  # (M, S, d)
        j = 2 * cell + 1
        u = x[:, None, :] * scale  # coordinate in units of h_l
        phi = np.clip(1.0 - np.abs(u - j), 0.0, None)  # Eq. 13 hat
        if self.basis == "modified":
            top = 2**L - 1
            phi = np.where((j == 1) & (L >= 2), np.clip(2.0 - u, 0.0, None), phi)
            phi = np.where((j == top) & (L >= 2), np.clip(u - top + 1.0, 0.0, None), phi)
            phi = np.where(L == 1, 1.0, phi)
        values = phi.prod(axis=2)  # (M, S): tensor product
        cols = self.subspace_offsets[None] + (cell * self.subspace_strides[None]).sum(axis=2)
        M, S = values.shape
        indptr = np.arange(0, M * S + 1, S)
        return sp.csr_matrix((values.reshape(-1), cols.reshape(-1), indptr), shape=(M, self.n_points))


@dataclass(frozen=True)
class SparseGridInterpolant:
    """A fitted interpolant ``u(x) = sum_p c_p phi_p(x)`` (Eq. 18), possibly on a box.

    Attributes
    ----------
    grid : SparseGrid
    surpluses : (P, K) array
    lower, upper : (d,) arrays
        The box mapped to ``[0, 1]^d`` (``x01 = (x - lower) / (upper - lower)``).
    """

    grid: SparseGrid
    surpluses: np.ndarray
    lower: np.ndarray
    upper: np.ndarray

    @property
    def n_outputs(self) -> int:
        return self.surpluses.shape[1]

    def normalise(self, x: ArrayLike) -> np.ndarray:
        x = np.asarray(x, dtype=float)
        if x.ndim == 1:
            x = x[None, :] if self.grid.dim > 1 else x[:, None]
        return (x - self.lower) / (self.upper - self.lower)

    def __call__(self, x) -> np.ndarray:
        """Evaluate at ``x (M, d)`` (in box coordinates); returns ``(M, K)``.

        Points outside the box are clamped to it.
        """
        return self.grid.basis_matrix(self.normalise(x)) @ self.surpluses


def fit(grid: SparseGrid, values: ArrayLike, lower: ArrayLike | None = None,
        upper: ArrayLike | None = None) -> SparseGridInterpolant:
    """Interpolant from values ``(P, K)`` at ``grid.points`` (mapped to the box)."""
    lower = np.zeros(grid.dim) if lower is None else np.asarray(lower, dtype=float).reshape(-1)
    upper = np.ones(grid.dim) if upper is None else np.asarray(upper, dtype=float).reshape(-1)
    if lower.shape != (grid.dim,) or upper.shape != (grid.dim,) or np.any(upper <= lower):
        raise ValueError(f"lower, upper: expected ({grid.dim},) arrays with upper > lower")
    return SparseGridInterpolant(grid, grid.hierarchise(values), lower, upper)


def interpolate(function: Callable[[np.ndarray], np.ndarray], dim: int, level: int, lower: ArrayLike | None = None,
                upper: ArrayLike | None = None, basis: str = "modified") -> SparseGridInterpolant:
    """Build the sparse-grid interpolant of a batch function on a box.

    Parameters
    ----------
    function : callable
        ``function(x (P, d)) -> (P,)`` or ``(P, K)``, vectorised over points.
    dim, level : int
    lower, upper : (d,) arrays, optional
        Box (default the unit cube).
    basis : {"modified", "hat"}

    Examples
    --------
    >>> f = interpolate(lambda x: x[:, 0] + 2 * x[:, 1], 2, 3)
    >>> round(float(f([[0.3, 0.1]])[0, 0]), 12)  # linear functions are exact with the modified basis
    0.5
    """
    grid = SparseGrid(dim, level, basis)
    lower = np.zeros(dim) if lower is None else np.asarray(lower, dtype=float)
    upper = np.ones(dim) if upper is None else np.asarray(upper, dtype=float)
    x = lower + grid.points * (upper - lower)
    values = np.asarray(function(x), dtype=float)
    if values.ndim == 1:
        values = values[:, None]
    if values.shape[0] != grid.n_points:
        raise ValueError(f"function: returned {values.shape[0]} rows for {grid.n_points} points")
    return fit(grid, values, lower, upper)

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from collections.abc import Callable
    from numpy.typing import ArrayLike
