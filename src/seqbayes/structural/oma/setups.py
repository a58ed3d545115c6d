"""Roving multi-setup tests merged through their reference channels (PoSER: post-separate estimation re-scaling).

A structure with more measurement points than sensors is tested in setups: a few reference
sensors stay in place while the others rove. Each setup is identified on its own
(:func:`~.identify.ssi_cov`); :func:`merge_setups` then

1. matches each setup's modes to the modes found so far (the setup with most modes first) by an
   assignment on ``|df| / f / frequency_tol + (1 - MAC_ref) / (1 - mac_tol)``, with MAC on the
   reference channels only, refusing pairs outside either tolerance (a mode of no match is new);
2. rescales each setup's shape by the least-squares factor that maps its reference part onto the
   reference part of the first setup holding the mode (``alpha = phi_ref^T psi_ref / psi_ref^T psi_ref``),
   and assembles the global shape: the roving channels from their setup, the reference channels
   averaged; it is normalised to its largest component +1;
3. combines the setups' frequencies and damping ratios by inverse-variance weights (their standard
   errors; a plain mean where one is missing) and reports disagreements beyond three standard errors.

A mode missing in a setup leaves NaN at that setup's roving channels, and says so.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from .identify import Modes, ssi_cov
from .settings import warn

__all__ = ["MergedModes", "merge_setups", "ssi_cov_setups"]


@dataclass(frozen=True)
class MergedModes:
    """Modes of a multi-setup test, with shapes over every channel of every setup.

    Attributes
    ----------
    frequencies, std_frequencies, damping_ratios, std_damping_ratios : (k,) arrays
    shapes, std_shapes : (c, k) arrays
        Over :attr:`channels` (NaN where the setup holding a channel did not find the mode).
    channels : tuple of str
        References first, then each setup's roving channels in order.
    found : (n_setups, k) bool array
    setups : tuple of Modes
    messages : tuple of str
    """

    frequencies: np.ndarray
    std_frequencies: np.ndarray
    damping_ratios: np.ndarray
    std_damping_ratios: np.ndarray
    shapes: np.ndarray
    std_shapes: np.ndarray
    channels: tuple
    found: np.ndarray
    setups: tuple
    messages: tuple


def _combine(values: np.ndarray, stds: np.ndarray) -> tuple[float, float, float]:
    """Inverse-variance mean, its standard error, and the largest standardised disagreement."""
    if values.size == 1:
        return float(values[0]), float(stds[0]), 0.0
    if np.all(np.isfinite(stds) & (stds > 0)):
        w = 1 / stds**2
        mean = float(np.sum(w * values) / np.sum(w))
        return mean, float(1 / np.sqrt(np.sum(w))), float(np.max(np.abs(values - mean) / stds))
    return float(np.mean(values)), float(np.std(values, ddof=1) / np.sqrt(values.size)), 0.0


def merge_setups(results, channels, references, frequency_tol: float = 0.02, mac_tol: float = 0.8) -> MergedModes:
    """Merge the modes of roving setups through their reference channels (module docstring).

    Parameters
    ----------
    results : list of Modes
        One per setup.
    channels : list of sequences of str
        Each setup's channel names, in the column order of its record.
    references : sequence of str
        The channels present in every setup.
    frequency_tol, mac_tol : float
        Largest relative frequency difference and smallest reference MAC of a match.

    Returns
    -------
    MergedModes
    """
    if len(results) != len(channels) or not results:
        raise ValueError(f"channels: expected one list of names per setup ({len(results)}), got {len(channels)}")
    references = list(references)
    if not references:
        raise ValueError("references: at least one channel must be in every setup")
    for j, (modes, names) in enumerate(zip(results, channels)):
        names = list(names)
        if len(names) != modes.shapes.shape[0] or len(set(names)) != len(names):
            raise ValueError(f"channels: setup {j + 1} names {len(names)} channels (distinct) for a record of "
                             f"{modes.shapes.shape[0]}")
        missing = [r for r in references if r not in names]
        if missing:
            raise ValueError(f"references: {missing} not among setup {j + 1}'s channels {names}")
    ref_rows = [[list(names).index(r) for r in references] for names in channels]
    order = sorted(range(len(results)), key=lambda j: -results[j].frequencies.size)
    groups = []  # each: {setup: column}
    for j in order:
        modes = results[j]
        if not groups:
            groups = [{j: i} for i in range(modes.frequencies.size)]
            continue
        anchor_f = np.array([results[next(iter(g))].frequencies[g[next(iter(g))]] for g in groups])
        anchor_phi = np.array([results[a].shapes[ref_rows[a], g[a]] for g in groups for a in [next(iter(g))]]).T
        mine = modes.shapes[ref_rows[j]]
        df = np.abs(modes.frequencies[:, None] - anchor_f[None]) / anchor_f[None]
        num = (mine.T @ anchor_phi) ** 2
        den = np.outer(np.sum(mine**2, axis=0), np.sum(anchor_phi**2, axis=0))
        mac = np.divide(num, den, out=np.zeros_like(num), where=den > 0)
        cost = df / frequency_tol + (1 - mac) / (1 - mac_tol)
        allowed = (df < frequency_tol) & (mac > mac_tol)
        rows, cols = linear_sum_assignment(np.where(allowed, cost, 1e6))
        taken = set()
        for r, c in zip(rows, cols):
            if allowed[r, c]:
                groups[c][j] = r
                taken.add(r)
        groups += [{j: i} for i in range(modes.frequencies.size) if i not in taken]
    all_channels = references + [c for names in channels for c in names if c not in references]
    index = {c: i for i, c in enumerate(all_channels)}
    k, messages = len(groups), []
    out = {name: np.full(k, np.nan) for name in ("f", "sf", "z", "sz")}
    shapes, std_shapes = np.full((len(all_channels), k), np.nan), np.full((len(all_channels), k), np.nan)
    found = np.zeros((len(results), k), dtype=bool)
    for m, group in enumerate(groups):
        anchor = next(iter(group))
        target = results[anchor].shapes[ref_rows[anchor], group[anchor]]
        f, sf, z, sz = (np.array([getattr(results[j], a)[i] for j, i in group.items()])
                        for a in ("frequencies", "std_frequencies", "damping_ratios", "std_damping_ratios"))
        (out["f"][m], out["sf"][m], worst), (out["z"][m], out["sz"][m], _) = _combine(f, sf), _combine(z, sz)
        if worst > 3:
            messages.append(f"mode at {out['f'][m]:.4g} Hz: the setups' frequencies differ by up to {worst:.1f} "
                            f"standard errors (the structure may have changed between setups)")
        ref_sum, ref_var, ref_n = np.zeros(len(references)), np.zeros(len(references)), 0
        for j, i in group.items():
            found[j, m] = True
            psi, spsi = results[j].shapes[:, i], results[j].std_shapes[:, i]
            psi_ref = psi[ref_rows[j]]
            alpha = float(target @ psi_ref / (psi_ref @ psi_ref))
            for row, name in enumerate(channels[j]):
                if name not in references:
                    shapes[index[name], m], std_shapes[index[name], m] = alpha * psi[row], abs(alpha) * spsi[row]
            ref_sum += alpha * psi_ref
            ref_var += (alpha * spsi[ref_rows[j]]) ** 2
            ref_n += 1
        shapes[:len(references), m] = ref_sum / ref_n
        std_shapes[:len(references), m] = np.sqrt(ref_var) / ref_n
        big = np.nanargmax(np.abs(shapes[:, m]))
        scale = shapes[big, m]
        shapes[:, m] /= scale
        std_shapes[:, m] /= abs(scale)
        absent = [str(j + 1) for j in range(len(results)) if not found[j, m]]
        if absent:
            messages.append(f"mode at {out['f'][m]:.4g} Hz was not found in setup{'s' if len(absent) > 1 else ''} "
                            f"{', '.join(absent)}: its shape is NaN at their roving channels")
    ascending = np.argsort(out["f"])
    warn(messages)
    return MergedModes(out["f"][ascending], out["sf"][ascending], out["z"][ascending], out["sz"][ascending],
                       shapes[:, ascending], std_shapes[:, ascending], tuple(all_channels), found[:, ascending],
                       tuple(results), tuple(messages))


def ssi_cov_setups(records, dt, channels, references, frequency_tol: float = 0.02, mac_tol: float = 0.8,
                   **options) -> MergedModes:
    """Identify every setup's record with :func:`~.identify.ssi_cov` and merge them (:func:`merge_setups`).

    Parameters
    ----------
    records : list of (T_j, p_j) arrays
    dt : float or list of floats
        Sampling step of every setup [s].
    channels, references
        See :func:`merge_setups`.
    **options
        Passed to :func:`~.identify.ssi_cov`.
    """
    steps = list(dt) if np.ndim(dt) else [dt] * len(records)
    if len(steps) != len(records):
        raise ValueError(f"dt: expected one step per setup ({len(records)}), got {len(steps)}")
    results: list[Modes] = [ssi_cov(y, step, **options) for y, step in zip(records, steps)]
    return merge_setups(results, channels, references, frequency_tol, mac_tol)
