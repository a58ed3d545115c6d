"""Linear structural models for the modal likelihood: ``theta -> (frequencies, shapes)`` over particles.

Every model here has ``n_parameters``, ``channels`` (the names of the degrees of freedom its shapes are
given at; empty for a model without shapes) and ``modes(theta (N, d)) -> (frequencies (N, q) [Hz],
shapes (N, p, q) or None)``, the lowest ``q`` modes in ascending order.

- :class:`LinearModel`: mass and stiffness matrices ``K(theta) = K0 + sum_j theta_j K_j`` (SciPy sparse
  influence matrices, any size), solved by a :class:`DenseSolver` (batched :func:`numpy.linalg.eigh` of
  ``L^-1 K L^-T``, ``M = L L^T``: small models), a :class:`SparseSolver` (:func:`scipy.sparse.linalg.eigsh` in
  shift-invert mode, one particle at a time: the exact solve of a large model) or a :class:`ReducedBasis`
  (Rayleigh-Ritz on a fixed basis of exact modes at training parameters, then a batched dense eigh of the
  ``r x r`` reduced matrices: the fast solve of a large model, its error measured against the exact one,
  docs/modal.md).
- :class:`ShearBuildingModel`: the shear building's storeys (some of them) as the parameters.
- :class:`ModeLevel`: no structural model: each tracked mode's frequency is a parameter.
- :class:`FunctionModel`: a user function ``theta (d,) -> (frequencies (q,), shapes (p, q))``, e.g. an
  OpenSees eigen analysis, called once per particle.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from .shear_building import ShearBuilding

__all__ = ["LinearModel", "DenseSolver", "SparseSolver", "ReducedBasis", "ShearBuildingModel", "ModeLevel",
           "FunctionModel"]

_TWO_PI = 2 * np.pi


def _hz(eigenvalues: np.ndarray) -> np.ndarray:
    """Natural frequencies [Hz] from ``omega^2`` (negative round-off clipped; a negative eigenvalue beyond
    round-off, a stiffness matrix that is not positive definite, gives NaN: zero likelihood)."""
    w2 = np.where(eigenvalues < 0, np.where(eigenvalues > -1e-9 * np.abs(eigenvalues).max(initial=1), 0, np.nan),
                  eigenvalues)
    return np.sqrt(w2) / _TWO_PI


@dataclass(frozen=True)
class DenseSolver:
    """Batched dense eigensolution: ``chunk`` particles at a time, ``(chunk, n, n)`` matrices in memory."""

    chunk: int = 64

    def __call__(self, model: LinearModel, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        L = model._mass_cholesky()
        A0, Aj = model._whitened()
        q = model.n_modes
        freqs = np.empty((theta.shape[0], q))
        shapes = np.empty((theta.shape[0], len(model.observed), q))
        for start in range(0, theta.shape[0], self.chunk):
            t = theta[start:start + self.chunk]
            w2, v = np.linalg.eigh(A0[None] + np.einsum("nj,jab->nab", t, Aj))
            freqs[start:start + t.shape[0]] = _hz(w2[:, :q])
            phi = scipy.linalg.solve_triangular(L.T, v[:, :, :q].transpose(1, 0, 2).reshape(L.shape[0], -1),
                                                lower=False).reshape(L.shape[0], t.shape[0], q)
            shapes[start:start + t.shape[0]] = phi[model.observed].transpose(1, 0, 2)
        return freqs, shapes


@dataclass(frozen=True)
class SparseSolver:
    """:func:`scipy.sparse.linalg.eigsh` in shift-invert mode about ``shift`` [rad^2/s^2] (default 0: the
    lowest modes), one particle at a time (a sparse LU of ``K - shift M`` and a Lanczos run each, from the
    model's fixed starting vector: ARPACK's default is random)."""

    shift: float = 0.0
    tol: float = 0.0

    def __call__(self, model: LinearModel, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = model.n_modes
        freqs = np.full((theta.shape[0], q), np.nan)
        shapes = np.full((theta.shape[0], len(model.observed), q), np.nan)
        for i, t in enumerate(theta):
            K = model.stiffness(t)
            try:
                w2, v = spla.eigsh(K, k=q, M=model.mass, sigma=self.shift, which="LM", tol=self.tol,
                                   v0=model.start_vector)
            except (RuntimeError, spla.ArpackNoConvergence, ValueError):   # singular or indefinite K: zero likelihood
                continue
            order = np.argsort(w2)
            freqs[i] = _hz(w2[order])
            shapes[i] = v[model.observed][:, order]
        return freqs, shapes


class ReducedBasis:
    """Rayleigh-Ritz on a fixed basis ``V (n, r)`` (M-orthonormal) of one model: ``(V^T K(theta) V) y = w^2 y``.

    The reduced matrices ``V^T K_j V`` are formed once; a particle then costs a dense ``r x r`` eigh
    (batched). Build it with :meth:`from_snapshots` (the exact modes at training parameters). The Ritz
    frequencies are upper bounds of the exact ones; :meth:`errors` measures the difference.

    Parameters
    ----------
    model : LinearModel
    basis : (n, r) array
        M-orthonormal columns (``V^T M V = I``).
    chunk : int
        Particles per batched eigh.
    """

    def __init__(self, model: LinearModel, basis: np.ndarray, chunk: int = 512):
        basis = np.asarray(basis, dtype=float)
        if basis.ndim != 2 or basis.shape[0] != model.n_dofs or basis.shape[1] < model.n_modes:
            raise ValueError(f"basis: expected shape ({model.n_dofs}, r) with r >= {model.n_modes}, got {basis.shape}")
        gram = basis.T @ (model.mass @ basis)
        if not np.allclose(gram, np.eye(basis.shape[1]), atol=1e-8):
            raise ValueError("basis: its columns are not M-orthonormal (V^T M V != I)")
        self.model, self.basis, self.chunk = model, basis, int(chunk)
        self.terms = np.stack([basis.T @ (k @ basis) for k in model.stiffness_terms])
        self.observed_basis = basis[model.observed]

    @property
    def size(self) -> int:
        """``r``, the basis size."""
        return self.basis.shape[1]

    @classmethod
    def from_snapshots(cls, model: LinearModel, thetas: np.ndarray, extra_modes: int = 2, tol: float = 1e-10,
                       chunk: int = 512) -> ReducedBasis:
        """A basis from the exact modes (``n_modes + extra_modes`` each, by :func:`scipy.sparse.linalg.eigsh`)
        at the training parameters ``thetas (S, d)``, M-orthonormalised, directions below ``tol`` of the
        largest singular value dropped."""
        thetas = np.atleast_2d(np.asarray(thetas, dtype=float))
        k = model.n_modes + int(extra_modes)
        X = np.hstack([spla.eigsh(model.stiffness(t), k=k, M=model.mass, sigma=0.0, which="LM", v0=model.start_vector)[1]
                       for t in thetas])
        L = model._mass_cholesky()
        U, s, _ = np.linalg.svd(L.T @ X, full_matrices=False)      # M-inner products become Euclidean
        U = U[:, s > tol * s[0]]
        return cls(model, scipy.linalg.solve_triangular(L.T, U, lower=False), chunk)

    def __call__(self, model: LinearModel, theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if model is not self.model:
            raise ValueError("solver: this reduced basis was built for another model")
        q = model.n_modes
        freqs = np.empty((theta.shape[0], q))
        shapes = np.empty((theta.shape[0], self.observed_basis.shape[0], q))
        for start in range(0, theta.shape[0], self.chunk):
            t = theta[start:start + self.chunk]
            w2, y = np.linalg.eigh(self.terms[0][None] + np.einsum("nj,jab->nab", t, self.terms[1:]))
            freqs[start:start + t.shape[0]] = _hz(w2[:, :q])
            shapes[start:start + t.shape[0]] = np.einsum("pr,nrq->npq", self.observed_basis, y[:, :, :q])
        return freqs, shapes

    def errors(self, thetas: np.ndarray) -> dict:
        """Relative frequency errors and ``1 - MAC`` of the shapes against :class:`SparseSolver` at ``thetas``:
        ``{"frequency": (S, q), "one_minus_mac": (S, q)}``."""
        thetas = np.atleast_2d(np.asarray(thetas, dtype=float))
        f_exact, s_exact = SparseSolver()(self.model, thetas)
        f, s = self(self.model, thetas)
        dot = np.einsum("npq,npq->nq", s, s_exact) ** 2
        mac = dot / (np.einsum("npq,npq->nq", s, s) * np.einsum("npq,npq->nq", s_exact, s_exact))
        return {"frequency": f / f_exact - 1, "one_minus_mac": 1 - mac}


class LinearModel:
    """``M`` and ``K(theta) = K0 + sum_j theta_j K_j``: the lowest ``n_modes`` modes, shapes at ``observed`` DOFs.

    Parameters
    ----------
    mass : (n, n) sparse or dense
        Symmetric positive definite.
    stiffness0 : (n, n) sparse or dense
        ``K0`` (the part not updated; may be zero).
    influence : sequence of d (n, n) sparse or dense matrices
        ``K_j``, symmetric.
    n_modes : int
        ``q``, the modes computed (at least the measured ones, and spare ones for pairing).
    observed : sequence of int
        The DOFs the mode shapes are given at (the sensors).
    channels : sequence of str, optional
        Their names, as in the modes table's ``phi_<channel>`` columns (default ``"1" .. "p"``).
    solver : DenseSolver, SparseSolver or ReducedBasis
        Default: dense for at most 200 DOFs, else sparse.
    """

    def __init__(self, mass, stiffness0, influence: Sequence, n_modes: int, observed: Sequence[int],
                 channels: Sequence[str] | None = None, solver=None):
        self.mass = sp.csc_matrix(mass, dtype=float)
        n = self.mass.shape[0]
        if self.mass.shape != (n, n):
            raise ValueError(f"mass: expected a square matrix, got shape {self.mass.shape}")
        matrices = [sp.csc_matrix(stiffness0, dtype=float)] + [sp.csc_matrix(k, dtype=float) for k in influence]
        for j, k in enumerate(matrices):
            name = "stiffness0" if j == 0 else f"influence[{j - 1}]"
            if k.shape != (n, n):
                raise ValueError(f"{name}: expected shape ({n}, {n}), got {k.shape}")
            asym = abs(k - k.T)
            if asym.nnz and asym.max() > 1e-10 * max(abs(k).max(), 1e-300):
                raise ValueError(f"{name}: not symmetric")
        if len(matrices) < 2:
            raise ValueError("influence: expected at least one influence matrix (one per parameter)")
        self.stiffness_terms = tuple(matrices)
        if int(n_modes) != n_modes or not 1 <= n_modes < n:
            raise ValueError(f"n_modes: expected an integer in [1, {n - 1}], got {n_modes!r}")
        self.n_modes = int(n_modes)
        self.observed = np.asarray(observed, dtype=int).reshape(-1)
        if self.observed.size == 0 or self.observed.min() < 0 or self.observed.max() >= n:
            raise ValueError(f"observed: expected DOF indices in [0, {n - 1}], got {observed!r}")
        self.channels = tuple(channels) if channels is not None else tuple(str(i + 1) for i in range(self.observed.size))
        if len(self.channels) != self.observed.size:
            raise ValueError(f"channels: expected {self.observed.size} names (one per observed DOF), "
                             f"got {len(self.channels)}")
        self.solver = solver if solver is not None else (DenseSolver() if n <= 200 else SparseSolver())
        self._cholesky = None
        self._whitened_terms = None

    @property
    def n_parameters(self) -> int:
        return len(self.stiffness_terms) - 1

    @property
    def n_dofs(self) -> int:
        return self.mass.shape[0]

    @property
    def start_vector(self) -> np.ndarray:
        """ARPACK's starting vector (fixed, so that a solve gives the same numbers every time)."""
        return np.linspace(1.0, 2.0, self.n_dofs)

    def stiffness(self, theta: np.ndarray) -> sp.csc_matrix:
        """``K(theta)`` of one parameter vector ``(d,)``, sparse."""
        out = self.stiffness_terms[0].copy()
        for t, k in zip(theta, self.stiffness_terms[1:]):
            out = out + t * k
        return out.tocsc()

    def _mass_cholesky(self) -> np.ndarray:
        if self._cholesky is None:
            self._cholesky = np.linalg.cholesky(self.mass.toarray())
        return self._cholesky

    def _whitened(self) -> tuple[np.ndarray, np.ndarray]:
        """``L^-1 K0 L^-T (n, n)`` and ``L^-1 K_j L^-T (d, n, n)``, formed once (:class:`DenseSolver`)."""
        if self._whitened_terms is None:
            L = self._mass_cholesky()
            A = [scipy.linalg.solve_triangular(L, scipy.linalg.solve_triangular(L, k.toarray(), lower=True).T,
                                               lower=True) for k in self.stiffness_terms]
            self._whitened_terms = (A[0], np.stack(A[1:]))
        return self._whitened_terms

    def modes(self, theta) -> tuple[np.ndarray, np.ndarray]:
        """``(frequencies (N, q) [Hz], shapes (N, p, q))`` of ``theta (N, d)`` by the model's solver."""
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        if theta.shape[1] != self.n_parameters:
            raise ValueError(f"theta: expected shape (N, {self.n_parameters}), got {theta.shape}")
        return self.solver(self, theta)


class ShearBuildingModel:
    """The shear building's storey stiffness ratios of ``storeys`` (1-based) as the parameters (the others 1);
    shapes at every floor (channels ``"1" .. "n"``, bottom to top). Batched dense eigh (``n x n``)."""

    def __init__(self, building: ShearBuilding, storeys: Sequence[int] | None = None,
                 channels: Sequence[str] | None = None):
        self.building = building
        n = building.n_storeys
        self.storeys = np.arange(n) if storeys is None else np.asarray(storeys, dtype=int) - 1
        if self.storeys.size == 0 or self.storeys.min() < 0 or self.storeys.max() >= n or \
                np.unique(self.storeys).size != self.storeys.size:
            raise ValueError(f"storeys: expected distinct storeys in 1..{n}, got {storeys!r}")
        self.channels = tuple(channels) if channels is not None else tuple(str(i + 1) for i in range(n))
        if len(self.channels) != n:
            raise ValueError(f"channels: expected {n} names (one per floor), got {len(self.channels)}")
        self.n_modes = n

    @property
    def n_parameters(self) -> int:
        return int(self.storeys.size)

    def modes(self, theta) -> tuple[np.ndarray, np.ndarray]:
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        if theta.shape[1] != self.n_parameters:
            raise ValueError(f"theta: expected shape (N, {self.n_parameters}), got {theta.shape}")
        full = np.ones((theta.shape[0], self.building.n_storeys))
        full[:, self.storeys] = theta
        bad = ~np.all(full > 0, axis=1)
        full[bad] = 1.0
        f, shapes = self.building.modes(full)
        f[bad] = np.nan                                   # a non-positive stiffness: zero likelihood
        return f, shapes


class ModeLevel:
    """No structural model: parameter ``j`` is the frequency [Hz] of tracked mode ``j + 1``; no shapes."""

    channels: tuple = ()

    def __init__(self, n_modes: int):
        if int(n_modes) != n_modes or n_modes < 1:
            raise ValueError(f"n_modes: expected a positive integer, got {n_modes!r}")
        self.n_modes = int(n_modes)

    @property
    def n_parameters(self) -> int:
        return self.n_modes

    def modes(self, theta) -> tuple[np.ndarray, None]:
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        if theta.shape[1] != self.n_modes:
            raise ValueError(f"theta: expected shape (N, {self.n_modes}), got {theta.shape}")
        return np.where(theta > 0, theta, np.nan), None


class FunctionModel:
    """A user's eigen analysis ``function(theta (d,)) -> (frequencies (q,) [Hz], shapes (p, q) or None)``,
    called once per particle (a finite-element program does not batch); an exception or a non-finite
    result for a particle gives it zero likelihood.

    Parameters
    ----------
    function : callable
    n_parameters, n_modes : int
    channels : sequence of str
        Names of the ``p`` shape components (empty: the function gives no shapes).
    """

    def __init__(self, function: Callable, n_parameters: int, n_modes: int, channels: Sequence[str] = ()):
        if not callable(function):
            raise TypeError(f"function: expected a callable, got {type(function).__name__}")
        self.function, self._d, self.n_modes, self.channels = function, int(n_parameters), int(n_modes), tuple(channels)

    @property
    def n_parameters(self) -> int:
        return self._d

    def modes(self, theta) -> tuple[np.ndarray, np.ndarray | None]:
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        if theta.shape[1] != self._d:
            raise ValueError(f"theta: expected shape (N, {self._d}), got {theta.shape}")
        p, q = len(self.channels), self.n_modes
        freqs = np.full((theta.shape[0], q), np.nan)
        shapes = np.full((theta.shape[0], p, q), np.nan) if p else None
        first_error = None
        for i, t in enumerate(theta):
            try:
                out = self.function(t)
                f = np.asarray(out[0], dtype=float).reshape(-1)
                if f.size < q:
                    raise ValueError(f"function: returned {f.size} frequencies, expected at least {q}")
                freqs[i] = f[:q]
                if p:
                    shapes[i] = np.asarray(out[1], dtype=float).reshape(p, -1)[:, :q]
            except Exception as err:   # a failed analysis of one particle is its zero likelihood ...
                freqs[i] = np.nan
                first_error = first_error or err
        if first_error is not None and np.all(np.isnan(freqs)):
            raise first_error            # ... but when every particle fails the function is wrong: say so
        return freqs, shapes
