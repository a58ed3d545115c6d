"""Standard errors of identified frequencies, damping ratios and shapes: first-order perturbation of SSI-cov.

The route of Reynders, Pintelon & De Roeck (2008) and Döhler & Mevel (2013): the covariance of
the block Toeplitz matrix ``T_s`` is estimated from ``nb`` contiguous blocks of the record,
``cov(vec T_s) = sum_k vec(dT_k) vec(dT_k)^T / (nb (nb - 1))`` with ``dT_k = T_k - mean(T)``,
and every modal parameter is propagated through the linearised map ``T_s -> U_n -> A -> (mu, psi)
-> (f, zeta, phi)``. Each block's ``dT_k`` is one direction of that map, so the variance of a
parameter ``g`` is ``sum_k (dg/dT . dT_k)^2 / (nb (nb - 1))`` (no ``(sp)^2 x (sp)^2`` matrix is formed).

The derivatives, with ``T_s = U S V^T`` (full SVD) and ``G = U^T dT V``:

- the leading subspace ``O = U[:, :n]`` moves by ``dO = U[:, n:] X`` with
  ``X_ij = (G_ij s_j + s_i G_ji) / (s_j^2 - s_i^2)`` (first-order perturbation of the eigenvectors of
  ``T T^T``; a rotation inside the subspace changes no pole);
- ``A = (O_up^T O_up)^{-1} O_up^T O_down``:
  ``dA = (O_up^T O_up)^{-1} [dO_up^T (O_down - O_up A) + O_up^T (dO_down - dO_up A)]``;
- ``dmu_j = (V^{-1} dA V)_jj`` and ``dv_j = sum_{m != j} v_m (V^{-1} dA V)_mj / (mu_j - mu_m)``;
- ``dlambda = dmu / (mu dt)``, ``df = Re(conj(lambda) dlambda) / (2 pi |lambda|)``,
  ``dzeta = -Re(dlambda) / |lambda| + Re(lambda) Re(conj(lambda) dlambda) / |lambda|^3``;
- ``phi = C v`` (``C = O[:p]``) normalised as ``Re(phi / phi_r)`` at its largest component ``r``.

``tests/unit/test_oma_uncertainty.py`` checks these derivatives against finite differences of the
full identification; ``benchmarks/bench_oma_sweep.py`` checks the standard errors against the
spread over 20 seeds (docs/oma.md, "Calibration").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .core import complex_mac, output_covariances, poles_at_order, toeplitz

__all__ = ["ToeplitzBlocks", "toeplitz_blocks", "pole_derivatives", "pole_standard_errors", "settled_standard_errors",
           "jackknife_clusters"]


@dataclass(frozen=True)
class ToeplitzBlocks:
    """``T_s`` of the whole record, its SVD, and the projections of the block deviations.

    Attributes
    ----------
    U, singular_values : (m, m), (m,) arrays
        Full SVD of ``T_s`` (``m = s p``).
    left, right : (nb, m, q), (nb, q, m) arrays
        ``G_k[:, :q]`` and ``G_k[:q, :]`` with ``G_k = U^T (T_k - mean T) V``, ``q`` the highest order kept.
    n_blocks : int
    jackknife : (nb, m, q) array or None
        Leading left singular vectors of each delete-one-block Toeplitz matrix
        ``T - (T_k - mean T) / (nb - 1)`` (centred on the whole record's ``T``), when asked for.
    """

    U: np.ndarray
    singular_values: np.ndarray
    left: np.ndarray | None
    right: np.ndarray | None
    n_blocks: int
    jackknife: np.ndarray | None = None


def toeplitz_blocks(y: np.ndarray, block_rows: int, max_order: int, n_blocks: int,
                    jackknife: bool = False) -> ToeplitzBlocks:
    """The SVD of ``T_s`` from the whole record ``y (T, p)`` and the block deviations up to ``max_order``.

    ``n_blocks < 2`` skips the blocks (no standard errors); ``jackknife`` also decomposes each
    delete-one-block Toeplitz matrix (for :func:`jackknife_clusters`; ``nb`` more SVDs).
    """
    s = block_rows
    H = toeplitz(output_covariances(y, 2 * s - 1), s)
    U, S, Vt = np.linalg.svd(H)
    if n_blocks < 2:
        return ToeplitzBlocks(U, S, None, None, 0)
    length = y.shape[0] // n_blocks
    blocks = np.stack([toeplitz(output_covariances(y[k * length:(k + 1) * length], 2 * s - 1), s)
                       for k in range(n_blocks)])
    mean = blocks.mean(axis=0)
    deviation = blocks - mean
    q = min(max_order + 1, U.shape[0])
    G_left = np.einsum("im,kmj->kij", U.T, deviation @ Vt[:q].T)     # U^T dT V[:, :q]
    G_right = U[:, :q].T @ deviation @ Vt.T                            # U[:, :q]^T dT V
    if jackknife:
        jackknife = np.stack([np.linalg.svd(H - deviation[k] / (n_blocks - 1))[0][:, :q] for k in range(n_blocks)])
    return ToeplitzBlocks(U, S, G_left, G_right, n_blocks, jackknife if jackknife is not False else None)


def settled_standard_errors(blocks: ToeplitzBlocks, p: int, dt: float, modes: list) -> list:
    """First-order standard errors of modes, each at the least sensitive of its candidate orders.

    Parameters
    ----------
    blocks : ToeplitzBlocks
    p : int
        Channels.
    dt : float
    modes : list of (orders (c,), frequencies (c,))
        Each mode's poles in the whole record at its candidate orders (its lowest settled orders).

    Returns
    -------
    list of (std_f, std_zeta, std_shape (p,), order) per mode
        The first-order standard errors (:func:`pole_standard_errors`) of the mode's pole at the candidate
        order where its frequency's is smallest, and that order. The first-order error of a pole is the
        sum of what the mode carries at every order and of the rotation of noise singular vectors across the
        cut, which grows without bound where two of them nearly coincide (at some orders above the true
        one) but is specific to its order; the mode, read from several orders that agree, does not carry it
        (docs/oma.md, "Calibration").
    """
    wanted = {}
    for m, (orders, frequencies) in enumerate(modes):
        for order, f0 in zip(orders, frequencies):
            wanted.setdefault(int(order), []).append((m, float(f0)))
    results = [[] for _ in modes]
    for order, items in sorted(wanted.items()):
        poles = poles_at_order(blocks.U, p, order, dt)
        if poles.frequencies.size == 0:
            continue
        index = np.array([int(np.argmin(np.abs(poles.frequencies - f0))) for _, f0 in items])
        sf, sz, sphi = pole_standard_errors(blocks, p, order, dt, index)
        for j, (m, _) in enumerate(items):
            results[m].append((sf[j], sz[j], sphi[:, j], order))
    out = []
    for rows in results:
        finite = [r for r in rows if np.isfinite(r[0])]
        out.append(min(finite, key=lambda r: r[0]) if finite else (np.nan, np.nan, np.full(p, np.nan), 0))
    return out


def jackknife_clusters(blocks: ToeplitzBlocks, p: int, dt: float, clusters: list, used: int | None = None,
                       frequency_gate: float = 0.01, mac_gate: float = 0.9) -> list:
    """Delete-one-block jackknife of modes that are averages of poles over several orders.

    Parameters
    ----------
    blocks : ToeplitzBlocks
    p : int
        Channels.
    dt : float
    clusters : list of (orders (c,), frequencies (c,), shapes (p, c), reference)
        Each mode's poles (one per order) in the whole record, in order of preference: the ``used`` poles the
        mode averages first, then the orders that may stand in for one of them; and the channel its shapes
        are normalised at.
    used : int, optional
        How many poles each mode averages (default: all given).
    frequency_gate, mac_gate : float
        A left-out block's pole is the mode's at an order when it lies within ``frequency_gate`` (relative)
        of the whole record's pole and has a MAC above ``mac_gate`` with it.

    Returns
    -------
    list of (std_f, std_zeta, std_shape (p,)) per cluster
        Each left-out block's model is re-identified at the mode's orders and each pole matched on
        ``|df| / f + 1 - MAC``; where the mode's pole at one of its orders has left the gate (it swapped
        with a noise pole), the next order of preference stands in, as the whole record's identification
        would have taken another order; the mode's mean over ``used`` orders is recomputed, and the
        jackknife variance ``(nb - 1) / nb sum_k (g_k - mean g)^2`` taken (:func:`_jackknife_std`).
    """
    if blocks.jackknife is None:
        raise ValueError("blocks: no delete-one-block decompositions; build them with toeplitz_blocks(..., jackknife=True)")
    values = [[] for _ in clusters]
    for U in blocks.jackknife:
        cache = {}
        for c, (orders, frequencies, shapes, reference) in enumerate(clusters):
            want = len(orders) if used is None else min(int(used), len(orders))
            f, z, phi = [], [], []
            for order, f0, shape in zip(orders, frequencies, shapes.T):
                order = int(order)
                if order not in cache:
                    cache[order] = poles_at_order(U, p, order, dt)
                poles = cache[order]
                if poles.frequencies.size == 0:
                    continue
                mac = complex_mac(poles.shapes, shape[:, None])[:, 0]
                pick = int(np.argmin(np.abs(poles.frequencies - f0) / f0 + 1 - mac))
                if abs(poles.frequencies[pick] / f0 - 1) >= frequency_gate or mac[pick] <= mac_gate:
                    continue
                f.append(poles.frequencies[pick])
                z.append(poles.damping_ratios[pick])
                phi.append((poles.shapes[:, pick] / poles.shapes[reference, pick]).real)
                if len(f) == want:
                    break
            values[c].append((np.mean(f), np.mean(z), np.mean(phi, axis=0)) if len(f) == want else None)
    out = []
    for rows in values:
        rows = [r for r in rows if r is not None]
        if len(rows) < max(3, blocks.n_blocks // 2):
            out.append((np.nan, np.nan, np.full(p, np.nan)))
            continue
        out.append(tuple(_jackknife_std(np.array([r[i] for r in rows]), blocks.n_blocks) for i in range(3)))
    return out


def _jackknife_std(values: np.ndarray, n_blocks: int) -> np.ndarray:
    """``sqrt((nb - 1) / nb sum_k (g_k - mean g)^2)`` over the left-out blocks that kept the mode (``values``
    ``(k, ...)``, ``k <= nb``), the sum scaled up to ``nb`` terms."""
    k = values.shape[0]
    return np.sqrt((n_blocks - 1) / n_blocks * np.sum((values - values.mean(axis=0)) ** 2, axis=0) * n_blocks / k)


def pole_derivatives(blocks: ToeplitzBlocks, p: int, order: int, dt: float, index: np.ndarray,
                     max_rotation: float = np.inf):
    """Directional derivatives of chosen poles of one order along every block deviation.

    Parameters
    ----------
    blocks : ToeplitzBlocks
    p : int
        Channels.
    order : int
    dt : float
    index : (j,) int array
        Which poles of :func:`~.core.poles_at_order` at this order (ascending frequency).
    max_rotation : float
        Leave out the singular-vector pairs across the cut whose first-order rotation at one standard
        error of ``T_s`` exceeds this [rad] (default: none left out, the exact first-order map).

    Returns
    -------
    poles : Poles
        All poles of the order.
    d_frequency, d_damping : (nb, j) arrays
    d_shape : (nb, p, j) array
        Of the real shapes ``Re(phi / phi_r)``.
    """
    U, S = blocks.U, blocks.singular_values
    poles, (A, mu, V, keep) = poles_at_order(U, p, order, dt, with_eigen=True)
    index = np.asarray(index, dtype=int)
    n, m = order, U.shape[0]
    s = np.zeros(m)
    s[:S.size] = S
    s_in, s_out = s[:n], s[n:]
    with np.errstate(divide="ignore", invalid="ignore"):
        gap = 1.0 / (s_in[None, :] ** 2 - s_out[:, None] ** 2)
    gap = np.nan_to_num(gap, posinf=0.0, neginf=0.0)
    X = (blocks.left[:, n:, :n] * s_in + s_out[:, None] * np.swapaxes(blocks.right[:, :n, n:], 1, 2)) * gap
    # a pair of singular vectors across the cut whose first-order rotation (one standard error of T_s) is not
    # small is not resolved by the data: its linearisation grows without bound as the two singular values meet
    rotation = np.sqrt(np.sum(X**2, axis=0) / (blocks.n_blocks * (blocks.n_blocks - 1)))
    X = np.where(rotation < max_rotation, X, 0.0)
    O = U[:, :n]
    dO = U[:, n:] @ X                                                  # (nb, m, n)
    up, down = O[:-p], O[p:]
    d_up, d_down = dO[:, :-p], dO[:, p:]
    gram_inv = np.linalg.inv(up.T @ up)
    residual = down - up @ A
    dA = gram_inv @ (np.swapaxes(d_up, 1, 2) @ residual + up.T @ (d_down - d_up @ A))
    V_inv = np.linalg.inv(V)
    M = V_inv @ dA @ V                                                 # (nb, n, n)
    j = keep[index]
    d_mu = M[:, j, j]                                                  # (nb, k)
    lam = np.log(mu[j].astype(complex)) / dt
    d_lam = d_mu / (mu[j] * dt)
    absolute = np.abs(lam)
    proj = (np.conj(lam) * d_lam).real
    d_frequency = proj / (2 * np.pi * absolute)
    d_damping = -d_lam.real / absolute + lam.real * proj / absolute**3
    differences = mu[j][None, :] - mu[:, None]                         # (n, k): mu_j - mu_m
    with np.errstate(divide="ignore", invalid="ignore"):
        weights = np.where(np.arange(n)[:, None] == j[None, :], 0.0, 1.0 / differences)
    dv = V @ (M[:, :, j] * weights)                                    # (nb, n, k)
    C = O[:p]
    phi = C @ V[:, j]                                                  # (p, k)
    d_phi = dO[:, :p] @ V[:, j] + C @ dv                               # (nb, p, k)
    r = np.argmax(np.abs(phi), axis=0)
    ref, d_ref = phi[r, np.arange(j.size)], d_phi[:, r, np.arange(j.size)]
    d_shape = ((d_phi * ref - phi * d_ref[:, None, :]) / ref**2).real
    return poles, d_frequency, d_damping, d_shape


def pole_standard_errors(blocks: ToeplitzBlocks, p: int, order: int, dt: float, index: np.ndarray,
                         max_rotation: float = np.inf):
    """First-order standard errors ``(std_f (j,), std_zeta (j,), std_shape (p, j))`` of chosen poles of one order."""
    _, d_f, d_z, d_phi = pole_derivatives(blocks, p, order, dt, index, max_rotation)
    scale = 1.0 / (blocks.n_blocks * (blocks.n_blocks - 1))
    return (np.sqrt(scale * np.sum(d_f**2, axis=0)), np.sqrt(scale * np.sum(d_z**2, axis=0)),
            np.sqrt(scale * np.sum(d_phi**2, axis=0)))
