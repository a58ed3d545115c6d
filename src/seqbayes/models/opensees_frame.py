"""A nonlinear two-storey shear frame solved by OpenSees, monitored campaign by campaign.

The structure (units t, kN, m, s): two floors of mass ``MASS`` on two storeys, each a
bilinear hysteretic spring (OpenSees ``Steel01``: initial stiffness, yield force
``YIELD_FORCE``, post-yield hardening ratio ``HARDENING``) in a ``zeroLength`` element,
mass-proportional Rayleigh damping ``C = 2 zeta omega_1 M`` (``omega_1`` the undamaged
frame's first circular frequency, so ``zeta`` is its first-mode damping ratio), and a base
excitation applied as ``UniformExcitation``. Newmark's average-acceleration rule with Newton
iterations integrates it at the data's time step.

A campaign (one dataset) is a short shaking test: a window of the bundled El Centro 1940
record (N-S component, resampled to ``DT``) scaled to a peak of ``PGA_G``, with the two
floors' absolute accelerations measured with Gaussian noise of std ``sigma``. The first
storey yields in the stronger windows, so the response is nonlinear in the parameters.
Between campaigns the first storey loses stiffness.

Parameters, in the order of :data:`PARAMETER_NAMES`:

- ``kappa``: the first storey's stiffness as a fraction of ``STIFFNESS`` (drifting: a
  :class:`~seqbayes.Drift` of rate ``-0.01`` per campaign and noise ``0.01``);
- ``zeta``: the damping ratio (static);
- ``sigma``: the accelerometers' noise std in m/s^2 (static).

A parameter row costs one OpenSees model build and transient analysis: the whole
analysis runs inside OpenSees' Tcl interpreter (one call per row, not one per time step),
about 2-4 ms for a 1.5 s window here (docs/benchmarks.md). OpenSees keeps one model per
process, so rows are solved one after another in a process and in parallel across worker
processes (``[parallel] executor = "processes"``).

OpenSees comes from ``pip install opensees`` (the ``seqbayes[opensees]`` extra: OpenSeesRT,
whose ``opensees.openseespy`` module is the OpenSeesPy interface); it is imported on the
first solve, so this module imports without it.

:func:`grid_reference` computes the exact filtering posterior of a run on a tensor grid
(``docs/benchmarks.md`` states its resolution), the reference the samplers are checked against.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from scipy import stats
from scipy.special import logsumexp

from ..kernels import Drift, MarkovKernel, Static
from ..priors import JointPrior
from ..reference import GridReference, simpson_weights
from ..structural.structures.ground_motion import G, load_el_centro, resample

__all__ = ["PARAMETER_NAMES", "DT", "WINDOW_STEPS", "TRUE_ZETA", "TRUE_SIGMA", "KERNEL", "PRIOR_BOX",
           "prior", "kernel", "excitation", "response", "loglike", "simulate", "write_campaigns",
           "sum_of_squares", "grid_reference", "opensees_available"]

PARAMETER_NAMES = ("kappa", "zeta", "sigma")
MASS = 20.0                      # t, each floor
STIFFNESS = 8000.0               # kN/m, each storey undamaged
YIELD_FORCE = (60.0, 80.0)       # kN, storey 1 and 2
HARDENING = 0.05
#: The undamaged frame's first circular frequency: equal masses and storeys give
#: omega_1^2 = (3 - sqrt 5) / 2 k / m.
OMEGA_1 = float(np.sqrt(0.5 * (3.0 - np.sqrt(5.0)) * STIFFNESS / MASS))
DT = 0.02                        # s
WINDOW_STEPS = 76                # samples per campaign: 1.5 s (comment-ok: unit conversion)
PGA_G = 0.1
TRUE_ZETA, TRUE_SIGMA = 0.03, 0.3
#: ``(rate, noise_std)`` of the first storey's stiffness loss per campaign.
KERNEL = (-0.01, 0.01)
PRIOR_BOX = {"kappa": (0.6, 1.2), "zeta": (0.005, 0.08), "sigma": (0.05, 1.0)}
COLUMNS = ("t", "ground", "floor1", "floor2")

# One Tcl procedure per process: the model is built and the analysis run inside OpenSees'
# interpreter, which returns the floors' relative accelerations at t_1 .. t_{n-1}.
_PROCEDURE = """
proc seqbayes_frame {k1 k2 fy1 fy2 hardening mass alpha dt n} {
  global seqbayes_ground
  wipe
  model basic -ndm 1 -ndf 1
  node 0 0.0; node 1 0.0; node 2 0.0
  fix 0 1
  mass 1 $mass; mass 2 $mass
  uniaxialMaterial Steel01 1 $fy1 $k1 $hardening
  uniaxialMaterial Steel01 2 $fy2 $k2 $hardening
  element zeroLength 1 0 1 -mat 1 -dir 1
  element zeroLength 2 1 2 -mat 2 -dir 1
  timeSeries Path 1 -dt $dt -values $seqbayes_ground
  pattern UniformExcitation 1 1 -accel 1
  rayleigh $alpha 0.0 0.0 0.0
  constraints Plain; numberer Plain; system FullGeneral
  test NormDispIncr 1e-10 25; algorithm Newton; integrator Newmark 0.5 0.25
  analysis Transient
  set out {}
  for {set i 1} {$i < $n} {incr i} {
    if {[analyze 1 $dt] != 0} { return -code error "seqbayes_frame: no convergence at step $i" }
    lappend out [nodeAccel 1 1] [nodeAccel 2 1]
  }
  return $out
}
"""

_SESSION: dict = {"pid": None, "ops": None, "ground": None}


def opensees_available() -> bool:
    """Whether ``opensees.openseespy`` (OpenSeesRT) imports here."""
    try:
        import opensees.openseespy  # noqa: F401
    except Exception:  # ImportError, or a broken native library
        return False
    return True


def _interpreter():
    """This process's OpenSees interpreter, with the frame's procedure defined (once per process)."""
    if _SESSION["pid"] != os.getpid():
        try:
            from opensees import openseespy as ops
        except ImportError as err:
            raise ImportError("seqbayes.models.opensees_frame needs OpenSees: pip install opensees "
                              "(or pip install 'seqbayes[opensees]')") from err
        ops.eval(_PROCEDURE)
        _SESSION.update(pid=os.getpid(), ops=ops, ground=None)
    return _SESSION["ops"]


def prior() -> JointPrior:
    """Uniform priors on :data:`PRIOR_BOX`."""
    return JointPrior({name: stats.uniform(lo, hi - lo) for name, (lo, hi) in PRIOR_BOX.items()})


def kernel() -> MarkovKernel:
    """``kappa`` drifts (:data:`KERNEL`), ``zeta`` and ``sigma`` are static."""
    return MarkovKernel([Drift(KERNEL[0], noise_std=KERNEL[1]), Static(), Static()])


def excitation(campaign: int) -> np.ndarray:
    """Ground acceleration ``(WINDOW_STEPS,)`` in m/s^2 of campaign ``campaign`` (1, 2, ...).

    A 1.5 s window of El Centro 1940 N-S (resampled to :data:`DT`) starting at
    ``1 + 0.25 ((campaign - 1) mod 24)`` s, scaled to a peak of :data:`PGA_G`.
    """
    if isinstance(campaign, bool) or int(campaign) != campaign or campaign < 1:
        raise ValueError(f"campaign: expected an integer >= 1, got {campaign!r}")
    record = resample(load_el_centro("180"), DT).acceleration
    start = int(round((1.0 + 0.25 * ((int(campaign) - 1) % 24)) / DT))
    window = record[start:start + WINDOW_STEPS]
    return window * (PGA_G * G / np.abs(window).max())


def response(theta, ground) -> np.ndarray:
    """The floors' absolute accelerations at ``t_1 .. t_{n-1}``, ``(K, n - 1, 2)``, one OpenSees solve per row.

    Parameters
    ----------
    theta : (K, >= 2) array
        Rows ``(kappa, zeta, ...)``.
    ground : (n,) array
        Ground acceleration at ``t_0 = 0, DT, ...`` (m/s^2), at rest before ``t_0``.

    Returns
    -------
    (K, n - 1, 2) array
        NaN for a row whose analysis does not converge.
    """
    theta = np.atleast_2d(np.asarray(theta, dtype=float))
    ground = np.asarray(ground, dtype=float)
    if theta.ndim != 2 or theta.shape[1] < 2:
        raise ValueError(f"theta: expected shape (K, >= 2), got {theta.shape}")
    if ground.ndim != 1 or ground.size < 2 or not np.all(np.isfinite(ground)):
        raise ValueError(f"ground: expected a finite (n >= 2,) array, got shape {ground.shape}")
    ops = _interpreter()
    key = ground.tobytes()
    if _SESSION["ground"] != key:  # the record is sent to the interpreter once per dataset
        # the last value twice: a Path series is zero from its last time on, which the accumulated
        # analysis time reaches a rounding error early at the last step
        values = np.append(ground, ground[-1])
        ops.eval("set seqbayes_ground {" + " ".join(f"{a:.17g}" for a in values) + "}")
        _SESSION["ground"] = key
    n = ground.size
    out = np.full((theta.shape[0], n - 1, 2), np.nan)
    for row, (kappa, zeta) in enumerate(theta[:, :2]):  # one model per process: rows one after another
        command = (f"seqbayes_frame {kappa * STIFFNESS:.17g} {STIFFNESS:.17g} {YIELD_FORCE[0]:.17g} "
                   f"{YIELD_FORCE[1]:.17g} {HARDENING:.17g} {MASS:.17g} {2.0 * zeta * OMEGA_1:.17g} {DT:.17g} {n}")
        try:
            values = ops.eval(command)
        except Exception as err:  # a failed solve is a zero likelihood, not a failed run
            if "no convergence" not in str(err):
                raise
            continue
        out[row] = np.array(values.split(), dtype=float).reshape(n - 1, 2)
    return out + ground[1:, None]  # relative to absolute acceleration


def _check_data(data) -> np.ndarray:
    data = np.asarray(data, dtype=float)
    if data.ndim != 2 or data.shape[1] != len(COLUMNS) or data.shape[0] < 2:
        raise ValueError(f"data: expected an (n_rows >= 2, 4) array of columns {COLUMNS}, got shape {data.shape}")
    return data


def loglike(theta, data) -> np.ndarray:
    """Gaussian log-likelihood of the measured floor accelerations, ``(N,)``.

    Parameters
    ----------
    theta : (N, 3) array
        Rows ``(kappa, zeta, sigma)``.
    data : (n_rows, 4) array
        Columns ``t, ground, floor1, floor2`` (s, m/s^2); the floors' rows from the second on
        are compared with the model.
    """
    data = _check_data(data)
    theta = np.asarray(theta, dtype=float)
    if theta.ndim != 2 or theta.shape[1] != 3:
        raise ValueError(f"theta: expected shape (N, 3), got {theta.shape}")
    predicted = response(theta, data[:, 1])
    residual = data[1:, None, 2:4] - predicted.transpose(1, 0, 2)          # (n - 1, N, 2)
    sum_squares = np.sum(residual**2, axis=(0, 2))
    n_obs = 2 * (data.shape[0] - 1)
    sigma = theta[:, 2]
    return -n_obs * np.log(sigma) - 0.5 * n_obs * np.log(2.0 * np.pi) - 0.5 * sum_squares / sigma**2


def simulate(n_campaigns: int, rng: np.random.Generator, kappa_start: float = 0.98) -> tuple[list, np.ndarray]:
    """Campaigns simulated from the model: stiffness loss from the kernel, noisy floor accelerations.

    Returns
    -------
    datasets : list of (WINDOW_STEPS, 4) arrays
        Columns ``t, ground, floor1, floor2``.
    kappa : (n_campaigns,) array
        The true first-storey stiffness factor at each campaign.
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng: expected a numpy.random.Generator, got {type(rng).__name__}")
    rate, noise = KERNEL
    kappa = np.empty(n_campaigns)
    t = DT * np.arange(WINDOW_STEPS)
    datasets = []
    for s in range(n_campaigns):  # draws in campaign order: a shorter run is a prefix of a longer one
        kappa[s] = kappa_start if s == 0 else kappa[s - 1] + rate + noise * rng.standard_normal()
        ground = excitation(s + 1)
        floors = response([[kappa[s], TRUE_ZETA]], ground)[0]
        floors = floors + TRUE_SIGMA * rng.standard_normal(floors.shape)
        floors = np.vstack([np.zeros((1, 2)), floors])  # at rest at t_0
        datasets.append(np.column_stack([t, ground, floors]))
    return datasets, kappa


def write_campaigns(folder, n_campaigns: int = 20, seed: int = 2026) -> list[Path]:
    """Simulate ``n_campaigns`` campaigns (:func:`simulate`) into ``folder/campaignNN.csv``; their paths.

    The true stiffness path goes to ``folder/true_kappa.csv``.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    datasets, kappa = simulate(n_campaigns, np.random.default_rng(seed))
    paths = []
    for s, data in enumerate(datasets, start=1):
        path = folder / f"campaign{s:02d}.csv"
        np.savetxt(path, data, delimiter=",", header=",".join(COLUMNS), comments="", fmt="%.10g")
        paths.append(path)
    np.savetxt(folder / "true_kappa.csv", np.column_stack([np.arange(1, n_campaigns + 1), kappa]), delimiter=",",
               header="campaign,kappa", comments="", fmt=["%d", "%.10g"])
    return paths


def sum_of_squares(kappa_axis, zeta_axis, data, executor=None) -> np.ndarray:
    """Residual sum of squares of ``data`` at every ``(kappa, zeta)`` of a tensor grid, ``(n_kappa, n_zeta)``.

    ``executor``: an object with ``map`` (e.g. :class:`~seqbayes.parallel.ProcessWorkers`) to solve the
    rows in worker processes (one contiguous block per task).
    """
    data = _check_data(data)
    kk, zz = np.meshgrid(np.asarray(kappa_axis, float), np.asarray(zeta_axis, float), indexing="ij")
    theta = np.column_stack([kk.ravel(), zz.ravel()])
    if executor is None:
        blocks = [_block_sum_of_squares(theta, data)]
    else:
        parts = np.array_split(theta, max(1, 4 * getattr(executor, "n_workers", 2)))
        blocks = list(executor.map(_block_sum_of_squares, parts, [data] * len(parts)))
    return np.concatenate(blocks).reshape(kk.shape)


def _block_sum_of_squares(theta, data) -> np.ndarray:
    predicted = response(theta, data[:, 1])
    return np.sum((data[1:, None, 2:4] - predicted.transpose(1, 0, 2)) ** 2, axis=(0, 2))


def grid_reference(datasets, *, zeta_axis, sigma_axis, kappa_spacing: float = 1e-3, first_kappa_axis=None,
                   tail: float = 36.0, executor=None) -> GridReference:
    """The exact filtering posterior of every campaign on a tensor grid over ``(kappa, zeta, sigma)``.

    The target is the samplers' (uniform priors on :data:`PRIOR_BOX`, the :func:`kernel`, zero
    likelihood outside the box). ``zeta`` and ``sigma`` are static: their axes are fixed. ``kappa``
    drifts: each campaign's axis spans the predictive's support, the previous posterior's range
    where its log-density is within ``tail`` nats of the peak, moved by the kernel's rate and
    widened by ``sqrt(2 tail)`` noise sds, clipped to the box, at ``kappa_spacing``; the predictive
    is the convolution of the previous posterior with the Gaussian kernel (Simpson weights).
    Integrals are Simpson's rule on every axis (odd point counts). The likelihood needs one
    OpenSees solve per ``(kappa, zeta)`` point (:func:`sum_of_squares`); ``sigma`` enters in
    closed form.

    Parameters
    ----------
    datasets : sequence of (n_rows, 4) arrays
    zeta_axis, sigma_axis : 1-D arrays
        Uniform, odd lengths, inside the box, covering the posterior's mass at every campaign
        (checked: an axis end holding more than ``exp(-tail)`` of the peak density raises).
    kappa_spacing : float
    first_kappa_axis : 1-D array, optional
        The first campaign's axis (default: the whole box at ``kappa_spacing``).
    executor : object with ``map``, optional
        Worker processes for the solves.

    Returns
    -------
    GridReference
        Per campaign, the posterior mean and sd of ``(kappa, zeta, sigma)`` and the log-evidence.
    """
    zeta_axis, sigma_axis = np.asarray(zeta_axis, float), np.asarray(sigma_axis, float)
    for name, axis in (("zeta_axis", zeta_axis), ("sigma_axis", sigma_axis)):
        lo, hi = PRIOR_BOX[name.split("_")[0]]
        if axis.ndim != 1 or axis.size % 2 == 0 or axis[0] < lo or axis[-1] > hi:
            raise ValueError(f"{name}: expected an odd-length uniform axis inside {(lo, hi)}")
    rate, noise = KERNEL
    box_lo, box_hi = PRIOR_BOX["kappa"]
    log_volume = sum(np.log(hi - lo) for hi, lo in ((b[1], b[0]) for b in PRIOR_BOX.values()))
    w_zeta, w_sigma = simpson_weights(zeta_axis), simpson_weights(sigma_axis)
    log_sigma = np.log(sigma_axis)
    means, stds, increments = [], [], []
    log_post = kappa_axis = None
    for s, data in enumerate(datasets):
        data = _check_data(data)
        n_obs = 2 * (data.shape[0] - 1)
        if s == 0:
            new_axis = _odd_axis(box_lo, box_hi, kappa_spacing) if first_kappa_axis is None \
                else np.asarray(first_kappa_axis, float)
            log_prior = np.full((new_axis.size, zeta_axis.size, sigma_axis.size), -log_volume)
        else:
            marginal = logsumexp(log_post, axis=(1, 2))
            keep = kappa_axis[marginal > marginal.max() - tail]
            reach = np.sqrt(2.0 * tail) * noise
            lo, hi = max(keep[0] + rate - reach, box_lo), min(keep[-1] + rate + reach, box_hi)
            new_axis = _odd_axis(lo, hi, kappa_spacing)
            # Eq. (A2): pi_s(k') = int N(k'; k + rate, noise^2) p_{s-1}(k) dk, per (zeta, sigma)
            z = (new_axis[:, None] - kappa_axis[None, :] - rate) / noise
            log_t = -0.5 * z**2 - np.log(noise * np.sqrt(2.0 * np.pi)) + np.log(simpson_weights(kappa_axis))[None, :]
            peak = log_post.max()
            log_prior = np.log(np.maximum(np.einsum("ij,jab->iab", np.exp(log_t), np.exp(log_post - peak)),
                                          1e-300)) + peak
        kappa_axis = new_axis
        sse = sum_of_squares(kappa_axis, zeta_axis, data, executor)               # (n_kappa, n_zeta)
        log_like = (-n_obs * log_sigma[None, None, :] - 0.5 * n_obs * np.log(2.0 * np.pi)
                    - 0.5 * sse[:, :, None] / sigma_axis[None, None, :] ** 2)
        log_joint = log_prior + np.where(np.isfinite(log_like), log_like, -np.inf)
        log_w = (np.log(simpson_weights(kappa_axis))[:, None, None] + np.log(w_zeta)[None, :, None]
                 + np.log(w_sigma)[None, None, :])
        log_z = logsumexp(log_joint + log_w)
        log_post = log_joint - log_z
        mass = np.exp(log_post + log_w)
        _check_edges(mass, (zeta_axis, sigma_axis), tail, s)
        row_mean, row_std = [], []
        for axis_index, axis in enumerate((kappa_axis, zeta_axis, sigma_axis)):
            other = tuple(i for i in range(3) if i != axis_index)
            marginal = mass.sum(axis=other)
            m = marginal @ axis
            row_mean.append(m)
            row_std.append(np.sqrt(max(marginal @ (axis - m) ** 2, 0.0)))
        means.append(row_mean)
        stds.append(row_std)
        increments.append(log_z)
    increments = np.array(increments)
    settings = {"zeta_points": zeta_axis.size, "sigma_points": sigma_axis.size, "kappa_spacing": kappa_spacing,
                "tail_nats": tail}
    return GridReference(PARAMETER_NAMES, np.array(means), np.array(stds), np.cumsum(increments), increments, settings)


def _odd_axis(lo: float, hi: float, spacing: float) -> np.ndarray:
    n = int(np.ceil((hi - lo) / spacing)) + 1
    return np.linspace(lo, hi, n + (1 - n % 2))


def _check_edges(mass: np.ndarray, static_axes, tail: float, step: int) -> None:
    """Refuse a static axis whose end inside the box carries more than ``exp(-tail)`` of its marginal's peak."""
    for axis_index, axis in ((1, static_axes[0]), (2, static_axes[1])):
        other = tuple(i for i in range(3) if i != axis_index)
        marginal = mass.sum(axis=other)
        peak = marginal.max()
        name = PARAMETER_NAMES[axis_index]
        lo, hi = PRIOR_BOX[name]
        ends = [marginal[0] if axis[0] > lo else 0.0, marginal[-1] if axis[-1] < hi else 0.0]  # a box bound cuts the prior
        if max(ends) > np.exp(-tail) * peak:
            raise ValueError(f"{name}_axis: campaign {step + 1}'s posterior reaches the axis' end "
                             f"({axis[0]:.4g} .. {axis[-1]:.4g}); widen it")
