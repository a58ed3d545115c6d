"""Synthetic sudden damage on the damped oscillator (issue 11): eight monthly
inspections of a structure whose stiffness decays slowly and, at one step, drops by
30 %; and the smooth-decay variant without the drop.

The physics, data and likelihood are those of :mod:`seqbayes.models.oscillator`
(Eq. 12 of Lye et al. 2023, noise std 0.005 m), with two differences. The
likelihood std is the record's RMSE itself (``likelihood_scale = 1``, the true noise
model), not the paper's 7 x: with 7 x, one inspection pins ``k`` only to about
0.35 N/m (one sd; ``osc._likelihood_mode`` on seed 0), so a 30 % drop (0.84 N/m) is
2.4 sds and even the exact filter cannot be sure of it at the drop step (a jump kernel
gave it probability 0.35 there). And the degradation replaces the paper's random
staircases:

    k_s = exp(-r_k) k_{s-1} + q_k z_{s,k},   c_s = exp(-r_c) c_{s-1} + q_c z_{s,c}
    k_s <- (1 - drop_fraction) k_s           at s = drop_step (the drop is permanent)

with ``k_0 = 3 N/m``, ``c_0 = 0.6 Ns/m``, ``z`` standard normal, ``s = 1..n_steps``
(inspection ``s`` at month ``s``). Draw order, fixed: the ``(n_steps, 2)`` process
noise ``z``, then the inspections' measurement noise; so :func:`simulate` with and
without a drop and the same seed give the same noise, and the two variants differ
only by the drop.

>>> import numpy as np
>>> drop = simulate(np.random.default_rng(1))
>>> smooth = simulate(np.random.default_rng(1), drop_step=None)
>>> len(drop.datasets), drop.drop_step, smooth.drop_step
(8, 5, None)
>>> float(np.round(drop.truth[4, 0] / smooth.truth[4, 0], 6))
0.7
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..models import oscillator as osc
from ..rng import as_generator

__all__ = ["N_STEPS", "DROP_STEP", "DROP_FRACTION", "DECAY_RATE", "PROCESS_STD", "LIKELIHOOD_SCALE",
           "AbruptDropData", "simulate"]

N_STEPS = 8                   #: inspections (months 1..8)
DROP_STEP = 5                 #: the inspection (1-based) at which the stiffness has dropped
DROP_FRACTION = 0.3           #: k loses this fraction at the drop
DECAY_RATE = (0.02, 0.02)     #: r_k, r_c per month: k, c *= exp(-r) each month
PROCESS_STD = (0.02, 0.005)   #: q_k [N/m], q_c [Ns/m]: the monthly random wander of k, c
LIKELIHOOD_SCALE = 1.0        #: likelihood std = this x the record's RMSE (the paper's study: 7)


@dataclass(frozen=True)
class AbruptDropData:
    """One simulated history and its inspections.

    Attributes
    ----------
    truth : (n_steps, 2) array
        True ``(k, c)`` at each inspection.
    datasets : tuple of n_steps OscillatorDataset
        One noisy free-vibration record per inspection (months ``1..n_steps``).
    drop_step : int or None
        The 1-based step at which ``k`` dropped; ``None`` for the smooth variant.
    drop_fraction : float
    decay_rate, process_std : (2,) arrays
        ``(r_k, r_c)`` and ``(q_k, q_c)`` used.
    """

    truth: np.ndarray
    datasets: tuple
    drop_step: int | None
    drop_fraction: float
    decay_rate: np.ndarray
    process_std: np.ndarray

    def __post_init__(self):
        for name in ("truth", "decay_rate", "process_std"):
            value = np.array(getattr(self, name), dtype=float)
            value.setflags(write=False)
            object.__setattr__(self, name, value)

    @property
    def path(self) -> osc.DegradationPath:
        """The history as a staircase (value ``s`` holds from month ``s``), for :mod:`seqbayes.models.oscillator`."""
        n = self.truth.shape[0]
        times = np.tile(np.arange(n + 1, dtype=float), (2, 1))
        values = np.column_stack([[osc.K0, osc.C0], self.truth.T])
        return osc.DegradationPath(times, values)


def simulate(rng, *, n_steps: int = N_STEPS, drop_step: int | None = DROP_STEP,
             drop_fraction: float = DROP_FRACTION, decay_rate=DECAY_RATE, process_std=PROCESS_STD,
             k0: float = osc.K0, c0: float = osc.C0, likelihood_scale: float = LIKELIHOOD_SCALE) -> AbruptDropData:
    """Simulate one history of slow decay with (or, ``drop_step=None``, without) a sudden drop of ``k``.

    Parameters
    ----------
    rng : numpy.random.Generator or seed
    n_steps : int
        Inspections, at months ``1..n_steps`` (at least 2).
    drop_step : int or None
        Step ``2..n_steps`` at which ``k`` is first seen dropped; ``None``: smooth decay only.
    drop_fraction : float
        Fraction of ``k`` lost at the drop, in ``(0, 1)``.
    decay_rate : (2,) array_like
        Monthly decay rates ``(r_k, r_c) >= 0``.
    process_std : (2,) array_like
        Monthly process-noise stds ``(q_k, q_c) >= 0``.
    k0, c0 : float
        Values at month 0.
    likelihood_scale : float
        Likelihood std in units of each record's RMSE about the true response (> 0).

    Returns
    -------
    AbruptDropData
    """
    rng = as_generator(rng)
    n_steps = int(n_steps)
    if n_steps < 2:
        raise ValueError(f"n_steps: must be at least 2, got {n_steps}")
    if drop_step is not None and not 2 <= int(drop_step) <= n_steps:
        raise ValueError(f"drop_step: expected None or 2..{n_steps}, got {drop_step}")
    if not 0.0 < float(drop_fraction) < 1.0:
        raise ValueError(f"drop_fraction: must be in (0, 1), got {drop_fraction}")
    rate = np.asarray(decay_rate, dtype=float)
    noise = np.asarray(process_std, dtype=float)
    for name, value in (("decay_rate", rate), ("process_std", noise)):
        if value.shape != (2,) or not np.all(np.isfinite(value)) or np.any(value < 0):
            raise ValueError(f"{name}: expected two finite values >= 0 (k, c), got {value.tolist()}")
    if not (k0 > 0 and c0 > 0):
        raise ValueError(f"k0, c0: must be > 0, got {k0}, {c0}")
    z = rng.standard_normal((n_steps, 2))                      # process noise first (see module doc)
    truth = np.empty((n_steps, 2))
    state = np.array([k0, c0], dtype=float)
    for s in range(n_steps):
        state = np.exp(-rate) * state + noise * z[s]
        if drop_step is not None and s + 1 == int(drop_step):
            state[0] *= 1.0 - float(drop_fraction)
        truth[s] = state
    if np.any(truth <= 0):
        raise ValueError("process_std: the simulated k or c went negative; use a smaller noise")
    times = tuple(range(1, n_steps + 1))
    data = AbruptDropData(truth, (), None if drop_step is None else int(drop_step), float(drop_fraction), rate, noise)
    if not likelihood_scale > 0:
        raise ValueError(f"likelihood_scale: must be > 0, got {likelihood_scale}")
    datasets = osc.simulate_inspections(data.path, rng, times=times, likelihood_scale=float(likelihood_scale))
    return AbruptDropData(truth, datasets, data.drop_step, data.drop_fraction, rate, noise)
