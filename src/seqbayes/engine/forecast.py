"""Forecasts of the parameters through the Markov kernel, restricted to the parameter space."""

from __future__ import annotations

import numpy as np

from ..kernels import MarkovKernel
from ..priors import inside_space

__all__ = ["forecast"]


def forecast(samples, kernel: MarkovKernel, support, n_steps: int, rng: np.random.Generator,
             max_rounds: int = 100) -> np.ndarray:
    """Forecasts of the parameters ``1..n_steps`` steps ahead, restricted to the parameter space.

    The likelihood is zero outside the parameter space, so the model's forecast at horizon ``h``
    is the law of ``theta_{s+h}`` given the data and that ``theta_{s+1}, ..., theta_{s+h}`` all stay
    inside (the mass the kernel carries out is lost, as in the samplers' steps and the grid
    reference). It is drawn by rejection of whole paths: paths from ``samples`` through the kernel
    (Eq. A2), each kept for the horizons before it first leaves the space; more rounds re-draw
    from ``samples`` until every horizon has ``N`` paths. When the space is never left (or is
    unbounded) the first round is the plain propagation, draw for draw.

    Parameters
    ----------
    samples : (N, d) array
        Equal-weight posterior draws.
    kernel : MarkovKernel
    support : (d, 2) array
        The parameter space (box bounds, infinite allowed).
    n_steps : int
    rng : numpy.random.Generator
    max_rounds : int
        At most ``max_rounds * N`` paths; a horizon that has fewer than ``N`` inside paths then
        (but some) repeats them, one with none raises ``ValueError``.

    Returns
    -------
    (n_steps, N, d) array
    """
    samples = np.asarray(samples, dtype=float)
    n = samples.shape[0]
    out = np.empty((n_steps,) + samples.shape)
    filled = np.zeros(n_steps, dtype=int)
    for round_ in range(max_rounds):
        current = samples if round_ == 0 else samples[rng.integers(n, size=n)]
        alive = np.ones(n, dtype=bool)
        for h in range(n_steps):
            current = kernel.propagate(current, rng)
            alive &= inside_space(current, support)
            take = current[alive][: n - filled[h]]
            out[h, filled[h]:filled[h] + take.shape[0]] = take
            filled[h] += take.shape[0]
        if (filled == n).all():
            return out
    for h in np.flatnonzero(filled < n):
        if filled[h] == 0:
            raise ValueError(f"predict: none of {max_rounds * n} forecast paths stays inside the parameter space "
                             f"for {h + 1} steps; the kernel carries the posterior out of it")
        out[h, filled[h]:] = out[h, rng.integers(filled[h], size=n - filled[h])]
    return out
