"""Operational modal analysis: covariance-driven stochastic subspace identification (SSI-cov).

From an ambient-vibration record ``y (T, p)`` (accelerations at ``p`` floors, the input unmeasured
and broadband) to natural frequencies, damping ratios and mode shapes (Peeters & De Roeck 1999,
"Reference-based stochastic subspace identification for output-only modal analysis", with every
channel a reference):

1. output covariances ``R_i = E[y_{k+i} y_k^T]``, ``i = 1 .. 2s - 1`` (:func:`output_covariances`);
2. the block Toeplitz matrix ``T_s = [R_{s+a-b}]_{a,b=0..s-1} = O_s Gamma_s`` (``s`` block rows),
   whose rank is the state dimension of the stochastic state-space model
   ``x_{k+1} = A x_k + w_k``, ``y_k = C x_k + v_k`` (``R_i = C A^{i-1} G``);
3. at model order ``n``: ``O_s = U_n S_n^{1/2}`` from the SVD, ``C`` its first block row and
   ``A = O_s[:-p]^+ O_s[p:]`` from its shift invariance (:func:`ssi_poles`);
4. the eigenvalues ``mu`` of ``A`` give the continuous poles ``lambda = ln(mu) / dt``, hence
   ``f = |lambda| / 2 pi`` and ``zeta = -Re(lambda) / |lambda|``; the mode shapes are ``C psi``;
5. a stabilisation diagram over orders ``2, 4, .., max_order`` keeps the poles that persist from
   one order to the next (frequency, damping and MAC within tolerances), groups them by
   frequency, and reports the groups that are stable over most orders as the physical modes
   (:func:`stabilisation_diagram`, :func:`ssi_cov`).

:func:`record_row` turns one record, with its temperature and time, into the row
``day, temperature, f1 .. fn`` that the monitoring workflow's data files hold.

Why not pyoma-2: its wheel (1.4.3, MIT) requires pandas, pydantic, openpyxl, requests, tqdm and
scikit-learn at install time, four of which seqbayes does not otherwise need, for a method that
is one SVD and one eigenproblem per order. The ~150 lines here depend on numpy only, are checked
to round-off on exact covariances (tests/unit/test_oma.py) and within 0.5 % on simulated ambient
records (docs/oma.md).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..rng import as_generator
from .structures.shear_building import ShearBuilding, add_measurement_noise, check_dt, discretise, simulate

__all__ = ["Modes", "Poles", "output_covariances", "ssi_poles", "stabilisation_diagram", "ssi_cov",
           "record_row", "ambient_record"]


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
        Whether a pole of the previous order matches it (set by :func:`stabilisation_diagram`).
    """

    order: int
    frequencies: np.ndarray
    damping_ratios: np.ndarray
    shapes: np.ndarray
    stable: np.ndarray


@dataclass(frozen=True)
class Modes:
    """Physical modes picked from a stabilisation diagram.

    Attributes
    ----------
    frequencies : (k,) array
        Natural frequencies [Hz], ascending (median over the mode's stable poles).
    damping_ratios : (k,) array
        Median damping ratio over the mode's stable poles.
    shapes : (p, k) array
        Real mode shapes (the stable pole nearest the median frequency, rotated to its largest
        component and scaled so that it is +1).
    n_stable : (k,) int array
        How many model orders carry a stable pole of the mode.
    """

    frequencies: np.ndarray
    damping_ratios: np.ndarray
    shapes: np.ndarray
    n_stable: np.ndarray


def _check_record(y, dt) -> tuple[np.ndarray, float]:
    y = np.asarray(y, dtype=float)
    if y.ndim == 1:
        y = y[:, None]
    if y.ndim != 2 or y.shape[0] < 2:
        raise ValueError(f"y: expected a record of shape (T, p) with T >= 2, got {np.shape(y)}")
    if not np.all(np.isfinite(y)):
        raise ValueError("y: contains NaN or inf")
    return y, check_dt(dt)


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
    y, _ = _check_record(y, 1.0)
    max_lag = int(max_lag)
    if not 0 <= max_lag < y.shape[0]:
        raise ValueError(f"max_lag: expected 0 <= max_lag < T = {y.shape[0]}, got {max_lag}")
    y = y - y.mean(axis=0)
    T = y.shape[0]
    return np.stack([y[i:].T @ y[: T - i] / (T - i) for i in range(max_lag + 1)])


def _toeplitz(covariances: np.ndarray, block_rows: int) -> np.ndarray:
    """``T_s`` with block ``(a, b) = R_{s + a - b}`` (lags 1 .. 2s - 1), shape ``(s p, s p)``."""
    s = block_rows
    rows = [np.concatenate([covariances[s + a - b] for b in range(s)], axis=1) for a in range(s)]
    return np.concatenate(rows, axis=0)


def _check_covariances(covariances, block_rows) -> tuple[np.ndarray, int]:
    covariances = np.asarray(covariances, dtype=float)
    if covariances.ndim != 3 or covariances.shape[1] != covariances.shape[2]:
        raise ValueError(f"covariances: expected shape (L, p, p), got {covariances.shape}")
    block_rows = int(block_rows)
    if block_rows < 1 or covariances.shape[0] < 2 * block_rows:
        raise ValueError(f"block_rows: need 1 <= block_rows and lags up to 2 * block_rows - 1 = "
                         f"{2 * block_rows - 1}; covariances has lags up to {covariances.shape[0] - 1}")
    return covariances, block_rows


def _poles_from_svd(U, S, p, order, dt) -> Poles:
    """Step 3-4 of the module docstring at one order, from the SVD of ``T_s``."""
    observability = U[:, :order] * np.sqrt(S[:order])
    C = observability[:p]
    A = np.linalg.lstsq(observability[:-p], observability[p:], rcond=None)[0]
    mu, psi = np.linalg.eig(A)
    keep = np.abs(mu) > 0
    lam = np.log(mu[keep].astype(complex)) / dt
    psi = psi[:, keep]
    upper = lam.imag > 0  # one of each conjugate pair; real poles are not vibration modes
    lam, psi = lam[upper], psi[:, upper]
    shapes = C @ psi
    shapes = shapes / np.linalg.norm(shapes, axis=0)
    frequencies = np.abs(lam) / (2 * np.pi)
    order_index = np.argsort(frequencies)
    return Poles(order, frequencies[order_index], (-lam.real / np.abs(lam))[order_index],
                 shapes[:, order_index], np.zeros(order_index.size, dtype=bool))


def ssi_poles(covariances: ArrayLike, dt: float, order: int, block_rows: int) -> Poles:
    """The poles of the SSI-cov model of one order (steps 2-4 of the module docstring).

    Parameters
    ----------
    covariances : (L, p, p) array
        ``R_0 .. R_{L-1}`` (:func:`output_covariances`); lags up to ``2 block_rows - 1`` are used.
    dt : float
        Sampling step [s].
    order : int
        State dimension ``n`` (even; ``n / 2`` modes at most), at most ``block_rows * p``.
    block_rows : int
        ``s``, the block rows of the Toeplitz matrix.

    Returns
    -------
    Poles
    """
    covariances, block_rows = _check_covariances(covariances, block_rows)
    p = covariances.shape[1]
    order = int(order)
    if order < 1 or order > block_rows * p - p:
        raise ValueError(f"order: expected 1 <= order <= (block_rows - 1) * p = {(block_rows - 1) * p}, got {order}")
    dt = check_dt(dt)
    U, S, _ = np.linalg.svd(_toeplitz(covariances, block_rows))
    return _poles_from_svd(U, S, p, order, dt)


def _complex_mac(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``|a_i^H b_j|^2`` for unit-norm complex shapes, ``(ka, kb)``."""
    return np.abs(a.conj().T @ b) ** 2


def stabilisation_diagram(y: ArrayLike, dt: float, max_order: int = 40, block_rows: int | None = None,
                          frequency_tol: float = 0.01, damping_tol: float = 0.05, mac_tol: float = 0.98,
                          max_damping: float = 0.2) -> list[Poles]:
    """Poles at orders ``2, 4, .., max_order``, each flagged stable or not.

    A pole of order ``n`` is stable when a pole of order ``n - 2`` lies within ``frequency_tol``
    (relative) in frequency, ``damping_tol`` (relative) in damping ratio and has a MAC above
    ``mac_tol``, and its damping ratio is in ``(0, max_damping)``.

    Parameters
    ----------
    y : (T, p) array
        The record.
    dt : float
        Sampling step [s].
    max_order : int
        Highest (even) model order.
    block_rows : int, optional
        ``s``; default the smallest with ``(s - 1) p >= max_order``, at least 10.

    Returns
    -------
    list of Poles, one per order, ascending.
    """
    y, dt = _check_record(y, dt)
    p = y.shape[1]
    max_order = int(max_order)
    if max_order < 4 or max_order % 2:
        raise ValueError(f"max_order: expected an even order >= 4, got {max_order}")
    if block_rows is None:
        block_rows = max(10, -(-max_order // p) + 1)
    for name, value in (("frequency_tol", frequency_tol), ("damping_tol", damping_tol), ("mac_tol", mac_tol),
                        ("max_damping", max_damping)):
        if not 0 < value <= 1:
            raise ValueError(f"{name}: expected a value in (0, 1], got {value}")
    covariances, block_rows = _check_covariances(output_covariances(y, 2 * int(block_rows) - 1), block_rows)
    if max_order > (block_rows - 1) * p:
        raise ValueError(f"max_order: at most (block_rows - 1) * p = {(block_rows - 1) * p}, got {max_order}")
    U, S, _ = np.linalg.svd(_toeplitz(covariances, block_rows))
    diagram = []
    previous = None
    for order in range(2, max_order + 1, 2):
        poles = _poles_from_svd(U, S, p, order, dt)
        stable = np.zeros(poles.frequencies.size, dtype=bool)
        if previous is not None and previous.frequencies.size and poles.frequencies.size:
            with np.errstate(divide="ignore", invalid="ignore"):  # a zero damping ratio never matches
                df = np.abs(poles.frequencies[:, None] - previous.frequencies[None]) / poles.frequencies[:, None]
                dz = np.abs(poles.damping_ratios[:, None] - previous.damping_ratios[None]) / np.abs(
                    poles.damping_ratios[:, None])
            match = (df < frequency_tol) & (dz < damping_tol) & (_complex_mac(poles.shapes, previous.shapes) > mac_tol)
            stable = match.any(axis=1) & (poles.damping_ratios > 0) & (poles.damping_ratios < max_damping)
        poles = Poles(order, poles.frequencies, poles.damping_ratios, poles.shapes, stable)
        diagram.append(poles)
        previous = poles
    return diagram


def _real_shape(shape: np.ndarray) -> np.ndarray:
    """Rotate a complex shape so that its largest component is real and positive; keep the real part."""
    big = shape[np.argmax(np.abs(shape))]
    real = (shape * np.conj(big) / np.abs(big)).real
    return real / np.max(np.abs(real))


def ssi_cov(y: ArrayLike, dt: float, n_modes: int | None = None, max_order: int = 40,
            block_rows: int | None = None, min_stable_fraction: float = 0.5, **tolerances) -> Modes:
    """Identify the physical modes of an ambient record by SSI-cov and a stabilisation diagram.

    The stable poles of all orders (:func:`stabilisation_diagram`) are grouped by frequency: a
    group grows while the next stable frequency is within ``frequency_tol`` of the group's median.
    A group is a physical mode when stable poles of at least ``min_stable_fraction`` of the orders
    fall in it; with ``n_modes`` the ``n_modes`` groups with the most orders are kept instead.

    Parameters
    ----------
    y : (T, p) array
        Record (accelerations, one column per channel).
    dt : float
        Sampling step [s].
    n_modes : int, optional
        How many modes to return (``ValueError`` if the diagram has fewer stable groups).
    max_order, block_rows
        See :func:`stabilisation_diagram`.
    min_stable_fraction : float
        Share of the orders that a mode must be stable at (when ``n_modes`` is None).
    **tolerances
        ``frequency_tol``, ``damping_tol``, ``mac_tol``, ``max_damping`` of
        :func:`stabilisation_diagram`.

    Returns
    -------
    Modes
    """
    if not 0 < min_stable_fraction <= 1:
        raise ValueError(f"min_stable_fraction: expected a value in (0, 1], got {min_stable_fraction}")
    diagram = stabilisation_diagram(y, dt, max_order=max_order, block_rows=block_rows, **tolerances)
    frequency_tol = tolerances.get("frequency_tol", 0.01)
    f = np.concatenate([d.frequencies[d.stable] for d in diagram])
    z = np.concatenate([d.damping_ratios[d.stable] for d in diagram])
    orders = np.concatenate([np.full(int(d.stable.sum()), d.order) for d in diagram])
    shapes = np.concatenate([d.shapes[:, d.stable] for d in diagram], axis=1) if f.size else np.zeros((1, 0))
    sort = np.argsort(f)
    f, z, orders, shapes = f[sort], z[sort], orders[sort], shapes[:, sort]
    groups, start = [], 0
    for i in range(1, f.size + 1):  # split the sorted stable poles at gaps wider than frequency_tol
        if i == f.size or f[i] > np.median(f[start:i]) * (1 + frequency_tol):
            groups.append(np.arange(start, i))
            start = i
    counts = np.array([np.unique(orders[g]).size for g in groups], dtype=int)
    if n_modes is None:
        chosen = np.flatnonzero(counts >= min_stable_fraction * len(diagram))
    else:
        n_modes = int(n_modes)
        if n_modes < 1:
            raise ValueError(f"n_modes: expected a positive integer, got {n_modes}")
        if len(groups) < n_modes:
            raise ValueError(f"n_modes: the stabilisation diagram has {len(groups)} stable modes, "
                             f"fewer than the {n_modes} asked for (a longer record or a higher max_order may help)")
        chosen = np.sort(np.argsort(-counts, kind="stable")[:n_modes])
    freq, damp, real_shapes = [], [], []
    for g in (groups[i] for i in chosen):
        median = np.median(f[g])
        freq.append(median)
        damp.append(np.median(z[g]))
        real_shapes.append(_real_shape(shapes[:, g[np.argmin(np.abs(f[g] - median))]]))
    p = np.shape(y)[1] if np.ndim(y) == 2 else 1
    return Modes(np.array(freq), np.array(damp),
                 np.array(real_shapes).T if real_shapes else np.zeros((p, 0)), counts[chosen])


def record_row(y: ArrayLike, dt: float, day: float, temperature: float, n_modes: int, **options) -> np.ndarray:
    """One data-file row ``[day, temperature, f1, .., f_n_modes]`` from one ambient record.

    Parameters
    ----------
    y : (T, p) array
        The record (accelerations).
    dt : float
        Sampling step [s].
    day : float
        When the record was taken, in days (the data file's ``day`` column).
    temperature : float
        The temperature measured with it [degrees C].
    n_modes : int
        How many frequencies the row carries (``f1 .. f_n_modes``).
    **options
        Passed to :func:`ssi_cov`.

    Returns
    -------
    (2 + n_modes,) array
    """
    for name, value in (("day", day), ("temperature", temperature)):
        if not np.isfinite(float(value)):
            raise ValueError(f"{name}: must be finite, got {value}")
    modes = ssi_cov(y, dt, n_modes=n_modes, **options)
    return np.concatenate([[float(day), float(temperature)], modes.frequencies])


def ambient_record(building: ShearBuilding, theta: ArrayLike, duration: float, dt: float,
                   noise_fraction: float = 0.05, rng: int | np.random.Generator | None = None) -> np.ndarray:
    """A simulated ambient-vibration record: every floor's absolute acceleration under white-noise
    ground acceleration (unit variance per step, through the exact discretisation), plus white
    measurement noise of ``noise_fraction`` times each channel's RMS.

    Parameters
    ----------
    building : ShearBuilding
    theta : (n,) array
        Stiffness ratios of the record.
    duration : float
        Record length [s].
    dt : float
        Sampling step [s] (below the highest mode's Nyquist limit).
    noise_fraction : float
        Measurement noise relative to each channel's RMS.
    rng : seed or Generator

    Returns
    -------
    (T, n) array, ``T = round(duration / dt)``.
    """
    rng = as_generator(rng)
    dt = check_dt(dt)
    if not np.isfinite(duration) or duration < 10 * dt:
        raise ValueError(f"duration: expected at least 10 sampling steps ({10 * dt} s), got {duration}")
    theta = np.asarray(theta, dtype=float).reshape(1, -1)
    model = discretise(building, theta, dt)
    steps = int(round(duration / dt))
    clean = simulate(model, np.zeros(steps), process_noise_std=1.0, rng=rng)[0]
    return add_measurement_noise(clean, noise_fraction, rng)[0]


import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from numpy.typing import ArrayLike
