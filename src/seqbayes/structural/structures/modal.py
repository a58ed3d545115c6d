"""Modal results from posterior samples of the stiffness ratios: natural
frequencies, damping ratios and mode shapes of the shear building, with the
modal assurance criterion (MAC) against identified mode shapes.

For each sample ``theta_s`` the undamped modes solve ``K(theta_s) phi = w^2 M phi``
(:meth:`~seqbayes.structural.structures.ShearBuilding.modes`); the damping ratios follow
from the Rayleigh damping, ``zeta = a0 / (2 w) + a1 w / 2``. Shapes are scaled
to unit Euclidean norm and their signs aligned with the shape at the posterior
mean before averaging.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .shear_building import ShearBuilding

__all__ = ["mac", "ModalSummary", "modal_summary"]


def mac(shapes_a: ArrayLike, shapes_b: ArrayLike) -> np.ndarray:
    """Modal assurance criterion ``|a_i^T b_j|^2 / ((a_i^T a_i)(b_j^T b_j))``.

    Parameters
    ----------
    shapes_a : (n, ka) array
        Mode shapes as columns (``n`` degrees of freedom).
    shapes_b : (n, kb) array

    Returns
    -------
    (ka, kb) array in [0, 1]

    Examples
    --------
    >>> mac(np.eye(2), np.array([[1.0], [1.0]])).round(2).tolist()
    [[0.5], [0.5]]
    """
    a = np.asarray(shapes_a, float)
    b = np.asarray(shapes_b, float)
    a = a[:, None] if a.ndim == 1 else a
    b = b[:, None] if b.ndim == 1 else b
    if a.ndim != 2 or b.ndim != 2 or a.shape[0] != b.shape[0]:
        raise ValueError(f"shapes_a, shapes_b: expected (n, ka) and (n, kb) with the same n, got {a.shape}, {b.shape}")
    norm_a = np.einsum("ni,ni->i", a, a)
    norm_b = np.einsum("nj,nj->j", b, b)
    if np.any(norm_a == 0) or np.any(norm_b == 0):
        raise ValueError("shapes_a, shapes_b: a mode shape is zero")
    return (a.T @ b) ** 2 / np.outer(norm_a, norm_b)


@dataclass(frozen=True)
class ModalSummary:
    """Posterior summaries of the modal properties (``n`` modes, ascending frequency).

    Attributes
    ----------
    frequencies : (S, n) array
        Natural frequencies [Hz] of every sample.
    damping_ratios : (S, n) array
    frequency_mean, frequency_sd : (n,) arrays
    frequency_interval : (2, n) array
        Weighted 2.5 % and 97.5 % quantiles.
    damping_mean, damping_sd : (n,) arrays
    damping_interval : (2, n) array
    shapes : (n, n) array
        Posterior mean mode shapes as columns (unit norm, signs aligned, largest
        component positive).
    shape_mac : (n,) array
        Posterior mean MAC between each sample's shape and ``shapes`` (1: no
        spread in the shape).
    mac_identified : (n, k) array or None
        MAC between ``shapes`` and the ``k`` identified shapes, if given.
    """

    frequencies: np.ndarray
    damping_ratios: np.ndarray
    frequency_mean: np.ndarray
    frequency_sd: np.ndarray
    frequency_interval: np.ndarray
    damping_mean: np.ndarray
    damping_sd: np.ndarray
    damping_interval: np.ndarray
    shapes: np.ndarray
    shape_mac: np.ndarray
    mac_identified: np.ndarray | None

    def table(self) -> str:
        """Markdown table: one row per mode."""
        rows = ["| mode | frequency [Hz] mean (sd) | 95 % interval | damping ratio mean (sd) | mean MAC to mean shape"
                + (" | best MAC to identified |" if self.mac_identified is not None else " |"),
                "|---|---|---|---|---" + ("|---|" if self.mac_identified is not None else "|")]
        for r in range(self.frequency_mean.size):
            row = (f"| {r + 1} | {self.frequency_mean[r]:.4f} ({self.frequency_sd[r]:.2e}) | "
                   f"[{self.frequency_interval[0, r]:.4f}, {self.frequency_interval[1, r]:.4f}] | "
                   f"{self.damping_mean[r]:.4f} ({self.damping_sd[r]:.1e}) | {self.shape_mac[r]:.6f} |")
            if self.mac_identified is not None:
                row += f" {self.mac_identified[r].max():.4f} |"
            rows.append(row)
        return "\n".join(rows)


def _weighted_quantiles(x, w, probs):
    order = np.argsort(x, axis=0)
    xs = np.take_along_axis(x, order, axis=0)
    cw = np.cumsum(w[order], axis=0)
    cw = (cw - 0.5 * w[order]) / cw[-1]
    return np.array([[np.interp(p, cw[:, j], xs[:, j]) for j in range(x.shape[1])] for p in probs])


def modal_summary(building: ShearBuilding, theta_samples: ArrayLike, weights: ArrayLike | None = None,
                  identified_shapes: ArrayLike | None = None) -> ModalSummary:
    """Modal properties of the posterior samples of ``theta``.

    Parameters
    ----------
    building : ShearBuilding
    theta_samples : (S, d) array
        Posterior samples (e.g. ``SGEnMCMCResult.final_theta``).
    weights : (S,) array, optional
        Non-negative sample weights (default equal).
    identified_shapes : (n, k) array, optional
        Mode shapes identified from the measurements (e.g. by an operational
        modal analysis), as columns; at the floors, bottom to top.

    Returns
    -------
    ModalSummary
    """
    theta = np.atleast_2d(np.asarray(theta_samples, float))
    S, n = theta.shape
    if n != building.n_storeys:
        raise ValueError(f"theta_samples: expected shape (S, {building.n_storeys}), got {theta.shape}")
    w = np.full(S, 1.0 / S) if weights is None else np.asarray(weights, float)
    if w.shape != (S,) or np.any(w < 0) or not np.isfinite(w).all() or w.sum() <= 0:
        raise ValueError(f"weights: expected {S} non-negative finite weights with a positive sum")
    w = w / w.sum()
    freqs, shapes = building.modes(theta)  # (S, n), (S, n, n) columns = modes
    damping = building.modal_damping_ratios(theta)
    shapes = shapes / np.linalg.norm(shapes, axis=1, keepdims=True)
    _, reference = building.modes(w @ theta)
    reference = reference[0] / np.linalg.norm(reference[0], axis=0, keepdims=True)
    signs = np.sign(np.einsum("snr,nr->sr", shapes, reference))
    shapes = shapes * np.where(signs == 0, 1.0, signs)[:, None, :]
    mean_shape = np.einsum("s,snr->nr", w, shapes)
    mean_shape /= np.linalg.norm(mean_shape, axis=0, keepdims=True)
    largest = mean_shape[np.argmax(np.abs(mean_shape), axis=0), np.arange(n)]
    mean_shape *= np.sign(largest)
    # MAC of every sample's shape r with the mean shape r (unit norms)
    spread = w @ np.einsum("snr,nr->sr", shapes, mean_shape) ** 2
    identified = None
    if identified_shapes is not None:
        identified_shapes = np.asarray(identified_shapes, float)
        identified_shapes = identified_shapes[:, None] if identified_shapes.ndim == 1 else identified_shapes
        if identified_shapes.shape[0] != n:
            raise ValueError(f"identified_shapes: expected ({n}, k) (one row per floor), got {identified_shapes.shape}")
        identified = mac(mean_shape, identified_shapes)

    def moments(x):
        mean = w @ x
        return mean, np.sqrt(np.maximum(w @ (x - mean) ** 2, 0))

    f_mean, f_sd = moments(freqs)
    z_mean, z_sd = moments(damping)
    return ModalSummary(frequencies=freqs, damping_ratios=damping, frequency_mean=f_mean, frequency_sd=f_sd,
                        frequency_interval=_weighted_quantiles(freqs, w, [0.025, 0.975]), damping_mean=z_mean,
                        damping_sd=z_sd, damping_interval=_weighted_quantiles(damping, w, [0.025, 0.975]),
                        shapes=mean_shape, shape_mac=spread, mac_identified=identified)

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from numpy.typing import ArrayLike
