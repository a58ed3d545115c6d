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

__all__ = ["ToeplitzBlocks", "toeplitz_blocks", "pole_derivatives", "pole_standard_errors", "jackknife_clusters"]


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
    jackknife : (nb, m, q) array
        Leading left singular vectors of each delete-one-block Toeplitz matrix
        ``(nb mean(T) - T_k) / (nb - 1)``.
    """

    U: np.ndarray
    singular_values: np.ndarray
    left: np.ndarray | None
    right: np.ndarray | None
    n_blocks: int
    jackknife: np.ndarray | None = None


def toeplitz_blocks(y: np.ndarray, block_rows: int, max_order: int, n_blocks: int) -> ToeplitzBlocks:
    """The SVD of ``T_s`` from the whole record ``y (T, p)`` and the block deviations up to ``max_order``.

    ``n_blocks < 2`` skips the blocks (no standard errors).
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
    jackknife = np.stack([np.linalg.svd(mean - deviation[k] / (n_blocks - 1))[0][:, :q] for k in range(n_blocks)])
    return ToeplitzBlocks(U, S, G_left, G_right, n_blocks, jackknife)


def jackknife_clusters(blocks: ToeplitzBlocks, p: int, dt: float, clusters: list) -> list:
    """Delete-one-block jackknife of modes that are averages of poles over several orders.

    Parameters
    ----------
    blocks : ToeplitzBlocks
    p : int
        Channels.
    dt : float
    clusters : list of (orders (c,), frequencies (c,), shapes (p, c), reference)
        Each mode's poles (one per order) in the whole record and the channel its shapes are normalised at.

    Returns
    -------
    list of (std_f, std_zeta, std_shape (p,)) per cluster
        Each left-out block's model of every order is re-identified, each pole matched on
        ``|df| / f + 1 - MAC``, the mode's mean over its orders recomputed, and the jackknife variance
        ``(nb - 1) / nb sum_k (g_k - mean g)^2`` taken robustly (:func:`_jackknife_std`).
    """
    nb = blocks.n_blocks
    needed = sorted({int(o) for orders, *_ in clusters for o in orders})
    values = [[] for _ in clusters]
    for U in blocks.jackknife:
        per_order = {order: poles_at_order(U, p, order, dt) for order in needed}
        for c, (orders, frequencies, shapes, reference) in enumerate(clusters):
            f, z, phi = [], [], []
            for order, f0, shape in zip(orders, frequencies, shapes.T):
                poles = per_order[int(order)]
                if poles.frequencies.size == 0:
                    continue
                cost = np.abs(poles.frequencies - f0) / f0 + 1 - complex_mac(poles.shapes, shape[:, None])[:, 0]
                pick = int(np.argmin(cost))
                f.append(poles.frequencies[pick])
                z.append(poles.damping_ratios[pick])
                phi.append((poles.shapes[:, pick] / poles.shapes[reference, pick]).real)
            values[c].append((np.mean(f), np.mean(z), np.mean(phi, axis=0)) if f else None)
    out = []
    for rows in values:
        if any(r is None for r in rows):
            out.append((np.nan, np.nan, np.full(p, np.nan)))
            continue
        out.append(tuple(_jackknife_std(np.array([r[i] for r in rows])) for i in range(3)))
    return out


def _jackknife_std(values: np.ndarray) -> np.ndarray:
    """``sqrt((nb - 1) / nb sum_k (g_k - mean g)^2)`` with the spread of the pseudo-values taken robustly
    (1.4826 times their median absolute deviation, so that a block whose removal swaps a pole with a
    noise pole does not dominate): ``sqrt(nb - 1) * 1.4826 * MAD``."""
    nb = values.shape[0]
    mad = np.median(np.abs(values - np.median(values, axis=0)), axis=0)
    return np.sqrt(nb - 1) * 1.4826 * mad


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
