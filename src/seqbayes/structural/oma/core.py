"""SSI-cov at one model order: record checks, output covariances, the block Toeplitz matrix and its poles.

Covariance-driven stochastic subspace identification (Peeters & De Roeck 1999, every channel a
reference): the output covariances ``R_i = E[y_{k+i} y_k^T]`` fill the block Toeplitz matrix
``T_s = [R_{s+a-b}]_{a,b=0..s-1} = O_s Gamma_s`` of ``s`` block rows, whose rank is the state
dimension of ``x_{k+1} = A x_k + w_k``, ``y_k = C x_k + v_k``. At order ``n`` the observability
matrix is spanned by the ``n`` leading left singular vectors ``U_n``; ``C`` is its first block row
and ``A = O[:-p]^+ O[p:]`` follows from its shift invariance. The eigenvalues ``mu`` of ``A`` give
``lambda = ln(mu) / dt``, ``f = |lambda| / 2 pi``, ``zeta = -Re(lambda) / |lambda|`` and the shapes
``C psi``. The poles and shapes do not depend on the basis of the subspace, so ``O = U_n`` is used
(no ``S_n^{1/2}``), which is also what the perturbation in :mod:`.uncertainty` differentiates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..structures.shear_building import check_dt

__all__ = ["Poles", "check_record", "check_sampling_step", "output_covariances", "toeplitz", "poles_at_order",
           "ssi_poles", "complex_mac", "phase_collinearity", "real_shapes", "MIN_RATE_HZ", "MAX_RATE_HZ"]

#: Sampling rates accepted [Hz]: from one sample per 100 s (long-period towers, slowly sampled) to 1 MHz (comment-ok: accepted range).
MIN_RATE_HZ, MAX_RATE_HZ = 1e-2, 1e6


@dataclass(frozen=True)
class Poles:
    """The poles of one model order (one of each complex-conjugate pair, ascending frequency).

    Attributes
    ----------
    order : int
        State dimension ``n`` of the identified model.
    frequencies : (k,) array
        Natural frequencies [Hz].
    damping_ratios : (k,) array
    shapes : (p, k) complex array
        Mode shapes ``C psi`` at the ``p`` channels, each scaled to unit norm.
    stable : (k,) bool array
        Whether a pole of the previous order matches it (set by the stabilisation diagram).
    mpc : (k,) array
        Modal phase collinearity of each shape (1 for a real shape).
    mpd : (k,) array
        Mean phase deviation of each shape [degrees] (0 for a real shape).
    """

    order: int
    frequencies: np.ndarray
    damping_ratios: np.ndarray
    shapes: np.ndarray
    stable: np.ndarray
    mpc: np.ndarray | None = None
    mpd: np.ndarray | None = None


def check_sampling_step(dt) -> float:
    """``dt`` as a float, refused outside ``1 / MAX_RATE_HZ .. 1 / MIN_RATE_HZ`` seconds with one line."""
    dt = check_dt(dt)
    if not 1.0 / MAX_RATE_HZ <= dt <= 1.0 / MIN_RATE_HZ:
        raise ValueError(f"dt: {dt:g} s is a sampling rate of {1 / dt:.3g} Hz, outside the {MIN_RATE_HZ:g} Hz to "
                         f"{MAX_RATE_HZ:.0e} Hz that OMA accepts; give the sampling step in seconds (dt = 1 / fs)")
    return dt


def check_record(y, dt=1.0, min_channels: int = 1) -> tuple[np.ndarray, float]:
    """The record as a finite float array ``(T, p)`` and ``dt``, or a one-line ``ValueError`` naming the problem.

    A 1-D record is one channel. A record with more channels than samples is refused as transposed.
    """
    try:
        y = np.asarray(y, dtype=float)
    except (TypeError, ValueError):
        raise TypeError("y: expected a numeric array of shape (T, p)") from None
    if y.ndim == 1:
        y = y[:, None]
    if y.ndim != 2 or y.shape[0] < 2 or y.shape[1] < 1:
        raise ValueError(f"y: expected a record of shape (T samples, p channels) with T >= 2, got {np.shape(y)}")
    T, p = y.shape
    if p > T:
        raise ValueError(f"y: shape {y.shape} has more channels ({p}) than samples ({T}); a record is (T samples, "
                         f"p channels): this one looks transposed (pass y.T)")
    bad = ~np.isfinite(y)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        count = int(bad.sum())
        raise ValueError(f"y: {count} value{'s are' if count > 1 else ' is'} NaN or infinite (the first at sample {row}, "
                         f"channel {col}); "
                         "fill or cut the gap before OMA")
    if p < min_channels:
        raise ValueError(f"y: {p} channel{'s' if p > 1 else ''}; OMA needs at least {min_channels} channels (mode "
                         f"shapes, and close modes told apart by them)")
    return y, check_sampling_step(dt)


def output_covariances(y: ArrayLike, max_lag: int) -> np.ndarray:
    """Unbiased sample output covariances ``R_i = sum_k y_{k+i} y_k^T / (T - i)``, ``i = 0 .. max_lag``.

    Parameters
    ----------
    y : (T, p) array
        The record; each channel's mean is removed first.
    max_lag : int
        Largest lag, below ``T``.

    Returns
    -------
    (max_lag + 1, p, p) array

    Examples
    --------
    >>> output_covariances(np.array([1.0, -1.0, 1.0, -1.0]), 1)[:, 0, 0].tolist()
    [1.0, -1.0]
    """
    y, _ = check_record(y, 1.0)
    max_lag = int(max_lag)
    if not 0 <= max_lag < y.shape[0]:
        raise ValueError(f"max_lag: expected 0 <= max_lag < T = {y.shape[0]} (the record's samples), got {max_lag}")
    y = y - y.mean(axis=0)
    T = y.shape[0]
    return np.stack([y[i:].T @ y[: T - i] / (T - i) for i in range(max_lag + 1)])


def toeplitz(covariances: np.ndarray, block_rows: int) -> np.ndarray:
    """``T_s`` with block ``(a, b) = R_{s + a - b}`` (lags 1 .. 2s - 1), shape ``(s p, s p)``."""
    s = block_rows
    rows = [np.concatenate([covariances[s + a - b] for b in range(s)], axis=1) for a in range(s)]
    return np.concatenate(rows, axis=0)


def check_covariances(covariances, block_rows) -> tuple[np.ndarray, int]:
    covariances = np.asarray(covariances, dtype=float)
    if covariances.ndim != 3 or covariances.shape[1] != covariances.shape[2]:
        raise ValueError(f"covariances: expected shape (L, p, p), got {covariances.shape}")
    block_rows = int(block_rows)
    if block_rows < 1 or covariances.shape[0] < 2 * block_rows:
        raise ValueError(f"block_rows: need 1 <= block_rows and lags up to 2 * block_rows - 1 = "
                         f"{2 * block_rows - 1}; covariances has lags up to {covariances.shape[0] - 1}")
    return covariances, block_rows


def complex_mac(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``|a_i^H b_j|^2 / (|a_i|^2 |b_j|^2)`` for complex shapes as columns, ``(ka, kb)``."""
    na = np.sum(np.abs(a) ** 2, axis=0)
    nb = np.sum(np.abs(b) ** 2, axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.nan_to_num(np.abs(a.conj().T @ b) ** 2 / np.outer(na, nb))


def phase_collinearity(shapes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Modal phase collinearity (Pappa et al. 1993) and mean phase deviation [degrees] of complex shapes ``(p, k)``.

    MPC is ``((l1 - l2) / (l1 + l2))^2`` for the eigenvalues ``l1 >= l2`` of the 2x2 covariance of the
    real and imaginary parts; MPD is the magnitude-weighted mean angle of the components from the
    straight line that fits them best in the complex plane.
    """
    re, im = shapes.real, shapes.imag
    sxx, syy, sxy = np.sum(re * re, axis=0), np.sum(im * im, axis=0), np.sum(re * im, axis=0)
    half_trace, root = (sxx + syy) / 2, np.sqrt(((sxx - syy) / 2) ** 2 + sxy**2)
    with np.errstate(divide="ignore", invalid="ignore"):
        mpc = np.nan_to_num((2 * root / (2 * half_trace)) ** 2)
    angle = 0.5 * np.arctan2(2 * sxy, sxx - syy)  # direction of the best straight line
    direction = np.cos(angle) + 1j * np.sin(angle)
    magnitude = np.abs(shapes)
    with np.errstate(divide="ignore", invalid="ignore"):
        cosine = np.clip(np.abs((shapes * np.conj(direction)).real) / magnitude, 0.0, 1.0)
        mpd = np.nan_to_num(np.sum(magnitude * np.degrees(np.arccos(np.nan_to_num(cosine, nan=1.0))), axis=0)
                            / np.sum(magnitude, axis=0))
    return mpc, mpd


def real_shapes(shapes: np.ndarray) -> np.ndarray:
    """``Re(phi / phi_max)`` per column: rotated so that the largest component is real and +1 (``(p, k)``)."""
    shapes = np.asarray(shapes)
    if shapes.shape[1] == 0:
        return np.zeros(shapes.shape)
    big = shapes[np.argmax(np.abs(shapes), axis=0), np.arange(shapes.shape[1])]
    return (shapes / big).real


def poles_at_order(U: np.ndarray, p: int, order: int, dt: float, with_eigen: bool = False):
    """Step 3-4 of the module docstring at one order, from the leading left singular vectors ``U`` of ``T_s``.

    Returns the :class:`Poles` (positive-frequency poles only), and with ``with_eigen`` also
    ``(A, mu, V, keep)``: the state matrix, all its eigenvalues and eigenvectors, and the indices
    of the kept eigenvalues in ascending frequency.
    """
    observability = U[:, :order]
    C = observability[:p]
    A = np.linalg.lstsq(observability[:-p], observability[p:], rcond=None)[0]
    mu, V = np.linalg.eig(A)
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = np.log(mu.astype(complex)) / dt
    keep = np.flatnonzero((np.abs(mu) > 0) & (lam.imag > 0))  # one of each pair; real poles are no modes
    lam = lam[keep]
    frequencies = np.abs(lam) / (2 * np.pi)
    ascending = np.argsort(frequencies)
    keep, lam, frequencies = keep[ascending], lam[ascending], frequencies[ascending]
    shapes = C @ V[:, keep]
    shapes = shapes / np.linalg.norm(shapes, axis=0)
    mpc, mpd = phase_collinearity(shapes)
    poles = Poles(order, frequencies, -lam.real / np.abs(lam), shapes, np.zeros(keep.size, dtype=bool), mpc, mpd)
    return (poles, (A, mu, V, keep)) if with_eigen else poles


def ssi_poles(covariances: ArrayLike, dt: float, order: int, block_rows: int) -> Poles:
    """The poles of the SSI-cov model of one order.

    Parameters
    ----------
    covariances : (L, p, p) array
        ``R_0 .. R_{L-1}`` (:func:`output_covariances`); lags up to ``2 block_rows - 1`` are used.
    dt : float
        Sampling step [s].
    order : int
        State dimension ``n`` (even; ``n / 2`` modes at most), at most ``(block_rows - 1) * p``.
    block_rows : int
        ``s``, the block rows of the Toeplitz matrix.

    Returns
    -------
    Poles
    """
    covariances, block_rows = check_covariances(covariances, block_rows)
    p = covariances.shape[1]
    order = int(order)
    if order < 1 or order > block_rows * p - p:
        raise ValueError(f"order: expected 1 <= order <= (block_rows - 1) * p = {(block_rows - 1) * p}, got {order}")
    dt = check_sampling_step(dt)
    U, _, _ = np.linalg.svd(toeplitz(covariances, block_rows))
    return poles_at_order(U, p, order, dt)


import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from numpy.typing import ArrayLike
