"""Synthetic sudden damage on the damped oscillator: eight monthly
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
           "JUMP_P", "DROP_MEAN", "DROP_SD", "AbruptDropData", "simulate", "candidate_kernels", "JumpReference",
           "exact_reference"]

N_STEPS = 8                   #: inspections (months 1..8)
DROP_STEP = 5                 #: the inspection (1-based) at which the stiffness has dropped
DROP_FRACTION = 0.3           #: k loses this fraction at the drop
DECAY_RATE = (0.02, 0.02)     #: r_k, r_c per month: k, c *= exp(-r) each month
PROCESS_STD = (0.02, 0.005)   #: q_k [N/m], q_c [Ns/m]: the monthly random wander of k, c
LIKELIHOOD_SCALE = 1.0        #: likelihood std = this x the record's RMSE (the paper's study: 7)
JUMP_P = 0.05                 #: candidate jump kernels: jump probability per step
DROP_MEAN, DROP_SD = 0.3, 0.1  #: and the drop fraction's mean and sd (of k0)


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


def candidate_kernels(decay_rate=DECAY_RATE, process_std=PROCESS_STD, *, p: float = JUMP_P,
                      drop_mean: float = DROP_MEAN, drop_sd: float = DROP_SD, k0: float = osc.K0,
                      c0: float = osc.C0) -> dict:
    """The kernels compared on this problem, each moving ``k`` and ``c`` (``c`` always by the smooth decay).

    - ``"decay"``: ``theta *= exp(-r) + N(0, q^2)``, the smooth truth without the drop;
    - ``"drift"``: ``theta -= theta_0 (1 - exp(-r)) + N(0, q^2)``, the same first-month loss, additive;
    - ``"jump"``: ``k``'s decay with probability ``1 - p``, a drop by ``f k0`` with
      ``f ~ N(drop_mean, drop_sd^2)`` with probability ``p`` (:class:`~seqbayes.kernels.Jump`);
    - ``"jump-heavy"``: the same with the heavy-tailed slab (:meth:`~seqbayes.kernels.Jump.heavy_tailed`).

    Returns
    -------
    dict name -> MarkovKernel
    """
    from ..kernels import Decay, Drift, Jump, MarkovKernel

    (rk, rc), (qk, qc) = np.asarray(decay_rate, dtype=float), np.asarray(process_std, dtype=float)
    decay_k, decay_c = Decay(rk, noise_std=qk), Decay(rc, noise_std=qc)
    return {
        "decay": MarkovKernel([decay_k, decay_c]),
        "drift": MarkovKernel([Drift(-k0 * -np.expm1(-rk), noise_std=qk), Drift(-c0 * -np.expm1(-rc), noise_std=qc)]),
        "jump": MarkovKernel([Jump(decay_k, p, drop_mean, drop_sd, k0), decay_c]),
        "jump-heavy": MarkovKernel([Jump.heavy_tailed(decay_k, p, drop_mean, drop_sd, k0), decay_c]),
    }


# ------------------------------------------------------------ exact reference with a jump kernel

def _axis_transition(new_axis, old_axis, component, slab_only: bool = False) -> np.ndarray:
    """One parameter's per-axis transition matrix (:func:`seqbayes.reference.component_transition`)."""
    from ..reference import component_transition

    return component_transition(np.asarray(new_axis), np.asarray(old_axis), component, slab_only)


def _propagate(log_density, old_axes, new_axes, components, slab_axis=None) -> np.ndarray:
    """Log predictive density on ``new_axes`` (the transition acts on each axis separately)."""
    from ..reference import apply_axis_transitions

    return apply_axis_transitions(log_density, [
        _axis_transition(np.asarray(new_axes[j]), np.asarray(old_axes[j]), component, j == slab_axis)
        for j, component in enumerate(components)])


@dataclass(frozen=True)
class JumpReference:
    """Exact per-step summaries of one dataset sequence under one kernel (:func:`exact_reference`).

    Attributes
    ----------
    grid : seqbayes.reference.GridReference
        Posterior ``mean``, ``std`` ``(S, 2)`` and cumulative ``log_evidence (S,)``.
    jump_probability : (S, 2) array
        Posterior probability that ``k`` (column 0) or ``c`` jumped into each step (NaN at step 1 and
        for components that are not jumps).
    """

    grid: object
    jump_probability: np.ndarray


def exact_reference(datasets, kernel, *, n_points: int = 201, points_per_sd: float = 5.0,
                    tail_mass: float = 1e-100, n_coarse: int = 201, max_points: int = 2001,
                    widen: float = 20.0) -> JumpReference:
    """Exact posterior moments, cumulative log-evidence and jump probabilities of ``(k, c)`` at every step.

    The grid filter of :mod:`seqbayes.reference` (Eq. 12's likelihood on an adaptive tensor grid,
    the uniform box prior of :mod:`seqbayes.models.oscillator`, Simpson quadrature) with the
    transition of any kernel whose components act on one parameter each, including
    :class:`~seqbayes.kernels.Jump`'s Gaussian mixture: the predictive of Eq. (A3) is the
    convolution of the last grid posterior with each axis's mixture. The probability that
    parameter ``j`` jumped into step ``s`` is ``int L_s pi_s^{slab j} / Z_s``, ``pi_s^{slab j}``
    the predictive with only the jump branches of ``j`` (times their probability).

    Step 1's grid is centred on the likelihood's mode (``+- 60`` of its sds, within the box; the
    likelihood there is sharper than the paper's by 7 x, see the module doc). The tails are kept
    down to ``tail_mass = 1e-100`` as in :func:`seqbayes.models.oscillator.exact_grid_reference`:
    under a smooth kernel the step after the drop is made of the previous posterior's far tail, and
    with ``1e-40`` the log-evidence of step 4 (seed 3, drop at step 3, decay kernel) was 0.077 nats
    off; with ``1e-100`` and ``1e-150`` it equals that function's to 1e-13 nats. Under the jump
    kernel (seed 0, drop at step 3) grids of ``n_points = 151`` and ``201``, ``points_per_sd = 3``
    and ``5`` agree to 1e-12 nats and 1e-15 in the means.

    Parameters
    ----------
    datasets : sequence of OscillatorDataset
    kernel : MarkovKernel
        Two components (``k``, ``c``), each with process noise.
    n_points, points_per_sd, tail_mass, n_coarse, max_points
        As :func:`seqbayes.reference.adaptive_axes`.
    widen : float
        A later step's window is the previous grid carried through each branch, widened by
        ``widen`` of that branch's sds.

    Returns
    -------
    JumpReference
    """
    from .. import reference
    from ..kernels import Jump, MarkovKernel

    datasets = tuple(datasets)
    if not isinstance(kernel, MarkovKernel) or len(kernel.components) != 2 or np.any(kernel.noise_std == 0):
        raise ValueError("kernel: expected a MarkovKernel with two components (k, c), both with noise")
    components = kernel.components
    box = np.array([osc.PRIOR_BOUNDS["k"], osc.PRIOR_BOUNDS["c"]])
    log_volume = float(np.sum(np.log(box[:, 1] - box[:, 0])))

    def grid_loglike(axes, dataset):
        kk, cc = np.meshgrid(axes[0], axes[1], indexing="ij")
        return osc.log_likelihood(np.column_stack([kk.ravel(), cc.ravel()]), dataset).reshape(kk.shape)

    branches = [c.branches() if isinstance(c, Jump) else (np.zeros(1), np.zeros(1), np.array([c.noise_std]))
                for c in components]
    scales = np.empty(2)
    for j, c in enumerate(components):
        ends = np.asarray(c.nominal(box[j]), dtype=float)
        scales[j] = c.noise_std * (box[j, 1] - box[j, 0]) / abs(ends[1] - ends[0])
    settings = dict(n_coarse=n_coarse, tail_mass=tail_mass, points_per_sd=points_per_sd, scales=scales,
                    max_points=max_points, log_axes=(True, True))
    steps, jumps = [], np.full((len(datasets), 2), np.nan)
    for s, dataset in enumerate(datasets):
        if s == 0:
            mode, sd, _ = osc._likelihood_mode(dataset)
            window = np.column_stack([np.maximum(mode - 60 * sd, box[:, 0]), np.minimum(mode + 60 * sd, box[:, 1])])

            def log_target(axes, dataset=dataset):
                return grid_loglike(axes, dataset) - log_volume
        else:
            prev = steps[-1]
            window = np.empty((2, 2))
            for j, c in enumerate(components):
                ends = np.asarray(c.nominal(prev.axes[j][[0, -1]]), dtype=float)
                _, shift, sd = branches[j]
                window[j] = (ends.min() + np.min(shift - widen * sd), ends.max() + np.max(shift + widen * sd))

            def log_target(axes, dataset=dataset, prev=prev):
                return _propagate(prev.log_density, prev.axes, axes, components) + grid_loglike(axes, dataset)
        step = reference.grid_update(log_target, window, n_points, hard=box, **settings)
        if s > 0:
            for j, c in enumerate(components):
                if isinstance(c, Jump):
                    slab = _propagate(prev.log_density, prev.axes, step.axes, components, slab_axis=j)
                    log_mass = reference.log_integral(slab + grid_loglike(step.axes, dataset), step.axes)
                    jumps[s, j] = np.exp(log_mass - step.log_evidence_increment)
        steps.append(step)
    grid = reference.reference_from_steps(steps, osc.PARAMETER_NAMES, len(datasets),
                                          {"n_points": n_points, "points_per_sd": points_per_sd,
                                           "tail_mass": tail_mass, "kernel": kernel.describe()})
    jumps.setflags(write=False)
    return JumpReference(grid, jumps)
