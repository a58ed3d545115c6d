"""Exact references for updating from identified modes (docs/modal.md, "Exact references").

Each :class:`ModalCase` is a sequence of simulated records of identified modes (frequencies with the
OMA's standard error and, optionally, shapes), a :class:`~seqbayes.structural.modal_likelihood.ModalLikelihood`,
a uniform prior box and a per-parameter kernel, so that the samplers (``seqbayes.SMC/SEMC``) and an
exact reference see the same problem:

- :func:`shear_building_case`: the 4-storey shear building with 1-3 storey stiffness ratios, static or
  drifting, or with the relative frequency error learned; its reference is a grid filter
  (:func:`grid_reference`, :func:`seqbayes.reference.grid_filter`) at every step;
- :func:`frame_case`: the 750-DOF plane frame (:func:`~seqbayes.structural.structures.frame.plane_frame`)
  with 10 storey influence matrices, 5 modes with shapes at 10 floors, static parameters, its modes by a
  reduced basis (error measured against the sparse solver); its reference is a long importance-sampling
  run per step (:func:`importance_reference`) from a Student-t fitted at the posterior mode (Laplace),
  with Monte Carlo errors;
- :func:`mode_level_reference`: the mast's mode-level run, whose posterior factorises over the modes,
  as one 1-D grid filter per mode;
- :func:`simulate_poles`: hourly poles of modes like the mast's with known truth, for the tracker.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from importlib import resources

import numpy as np
from scipy import stats
from scipy.optimize import minimize
from scipy.special import logsumexp

from .. import reference
from ..kernels import Drift, MarkovKernel, Static
from ..priors import JointPrior
from .modal_likelihood import Fixed, Learned, ModalLikelihood
from .modes_table import PoleTable
from .structures import ShearBuilding
from .structures.frame import plane_frame
from .structures.linear import LinearModel, ReducedBasis, ShearBuildingModel, SparseSolver

__all__ = ["ModalCase", "shear_building_case", "frame_case", "grid_reference", "importance_reference",
           "mode_level_reference", "BUILDING", "SHEAR_CASES", "datasets_digest", "read_importance_reference",
           "FRAME_REFERENCE", "simulate_poles"]

#: The bundled importance-sampling reference of :func:`frame_case` (``benchmarks/bench_modal_reference.py``)
FRAME_REFERENCE = "data/modal_frame_reference.csv"

BUILDING = ShearBuilding([2e5, 2e5, 2e5, 1.6e5], [3e8, 2.6e8, 2.2e8, 1.8e8])
#: name -> (storeys, drift rate and noise of each stiffness ratio per record, learned error, shapes, records)
SHEAR_CASES = {
    "static-3": ((1, 2, 3), (0.0, 0.0), False, True, 4),
    "drift-2": ((1, 2), (-0.02, 0.01), False, True, 5),
    "learned-error": ((1,), (-0.02, 0.015), True, False, 5),
}


@dataclass(frozen=True)
class ModalCase:
    """A simulated updating problem: ``datasets`` (one dict of modes-table columns per record), the
    ``likelihood``, the ``box (d, 2)`` of the uniform prior, the per-parameter ``rates`` and ``noise``
    of the kernel (``x' = x + rate + N(0, noise^2)``; noise 0 static), the ``truth (S, d)`` and ``names``."""

    name: str
    names: tuple
    likelihood: ModalLikelihood
    datasets: tuple
    box: np.ndarray
    rates: np.ndarray
    noise: np.ndarray
    truth: np.ndarray

    @property
    def prior(self) -> JointPrior:
        return JointPrior({n: stats.uniform(lo, hi - lo) for n, (lo, hi) in zip(self.names, self.box)})

    @property
    def kernel(self) -> MarkovKernel:
        return MarkovKernel([Drift(r, noise_std=q) if q > 0 else Static() for r, q in zip(self.rates, self.noise)])


def _records(modes, truth, rng, frequency_sd, shape_sd, channels, n_measured):
    """One dataset per row of ``truth``: the model's modes with Gaussian noise, reported sds attached."""
    out = []
    freqs, shapes = modes(truth)
    for s in range(truth.shape[0]):
        f = freqs[s, :n_measured]
        data = {"mode": np.arange(1, n_measured + 1, dtype=float),
                "frequency_hz": f * (1 + frequency_sd * rng.standard_normal(n_measured)),
                "std_frequency_hz": frequency_sd * f}
        if shape_sd is not None:
            phi = shapes[s][:, :n_measured]
            phi = phi / phi[np.argmax(np.abs(phi), axis=0), np.arange(n_measured)]
            phi = phi + shape_sd * rng.standard_normal(phi.shape)
            for c, name in enumerate(channels):
                data[f"phi_{name}"] = phi[c]
                data[f"std_phi_{name}"] = np.full(n_measured, shape_sd)
        out.append(data)
    return tuple(out)


def shear_building_case(name: str, seed: int = 0) -> ModalCase:
    """The 4-storey shear building case ``name`` of :data:`SHEAR_CASES` (frequencies measured to 0.5 %, shapes
    at the four floors to 0.02, prediction errors 0.5 % and 0.02 or, for ``"learned-error"``, the relative
    frequency error a parameter ``U(0.001, 0.03)``)."""
    storeys, (rate, noise), learned, shapes, n_records = SHEAR_CASES[name]
    rng = np.random.default_rng(seed)
    model = ShearBuildingModel(BUILDING, storeys)
    d_model = len(storeys)
    start = np.array([0.9, 1.05, 0.95][:d_model])
    truth = start[None, :] + rate * np.arange(n_records)[:, None]
    if noise > 0:
        truth = truth + np.cumsum(noise * rng.standard_normal(truth.shape), axis=0)
    datasets = _records(model.modes, truth, rng, 0.005, 0.02 if shapes else None, model.channels, 4)
    names = tuple(f"k{s}" for s in storeys)
    box = np.tile([0.5, 1.5], (d_model, 1))
    rates, noises = np.full(d_model, rate), np.full(d_model, noise)
    if learned:
        like = ModalLikelihood(model, frequency_error=Learned(d_model), std_scale=0.0)
        names, box = names + ("e_f",), np.vstack([box, [0.001, 0.03]])
        rates, noises = np.r_[rates, 0.0], np.r_[noises, 0.0]
        truth = np.column_stack([truth, np.full(n_records, 0.005)])
    else:
        like = ModalLikelihood(model, frequency_error=Fixed(0.005), shape_error=0.02 if shapes else None)
    return ModalCase(name, names, like, datasets, box, rates, noises, truth)


def frame_case(seed: int = 0, n_records: int = 3, basis_tol: float = 1e-6) -> ModalCase:
    """The plane frame (750 DOFs, 10 storey influence matrices), 5 measured modes with shapes at the 10
    floors: frequencies to 0.2 % (and 0.2 % prediction error), shapes to 0.01 (and 0.01); static stiffness
    ratios in ``U(0.5, 1.5)``; the modes by a reduced basis of the exact modes at the centre and at 1.3 on
    each axis (``basis_tol``: the singular values kept)."""
    rng = np.random.default_rng(seed)
    frame = plane_frame()
    exact = LinearModel(frame.mass, frame.stiffness0, frame.influence, 7, frame.observed, frame.channels,
                        solver=SparseSolver())
    d = exact.n_parameters
    basis = ReducedBasis.from_snapshots(exact, np.vstack([np.ones(d), 1 + 0.3 * np.eye(d)]), extra_modes=0,
                                        tol=basis_tol)
    model = LinearModel(frame.mass, frame.stiffness0, frame.influence, 7, frame.observed, frame.channels)
    model.solver = ReducedBasis(model, basis.basis)
    truth = np.tile(rng.uniform(0.8, 1.2, d), (n_records, 1))
    datasets = _records(exact.modes, truth, rng, 0.002, 0.01, frame.channels, 5)
    like = ModalLikelihood(model, frequency_error=Fixed(0.002), shape_error=Fixed(0.01))
    return ModalCase("frame", tuple(f"k{j + 1}" for j in range(d)), like, datasets, np.tile([0.5, 1.5], (d, 1)),
                     np.zeros(d), np.zeros(d), truth)


def _grid_loglike(case: ModalCase, chunk: int = 20000):
    def log_likelihood(axes, dataset):
        mesh = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(axes))
        out = np.concatenate([case.likelihood(mesh[i:i + chunk], dataset) for i in range(0, mesh.shape[0], chunk)])
        return out.reshape(tuple(a.size for a in axes))
    return log_likelihood


def grid_reference(case: ModalCase, n_points: int = 61, n_coarse: int = 41, tail_mass: float = 1e-40):
    """The exact filter of ``case`` on adaptive tensor grids (:func:`seqbayes.reference.grid_filter`): a
    :class:`~seqbayes.reference.GridReference` of every step (a learned error's axis is geometric)."""
    nominals = [lambda x, r=r: x + r for r in case.rates]
    log_axes = [name.startswith("e_") for name in case.names]
    steps = reference.grid_filter(case.datasets, _grid_loglike(case), case.box, nominals, case.noise, n_points,
                                  resolution=reference.Resolution(n_coarse=n_coarse, tail_mass=tail_mass,
                                                                  log_axes=log_axes))
    return reference.reference_from_steps(steps, case.names, len(case.datasets),
                                          {"n_points": n_points, "n_coarse": n_coarse, "tail_mass": tail_mass})


def _laplace(log_post, start, box):
    bounds = [tuple(b) for b in box]
    fit = minimize(lambda x: -log_post(x[None])[0], start, method="L-BFGS-B", bounds=bounds)
    x = fit.x
    d = x.size
    h = 1e-4 * np.maximum(np.abs(x), 1.0)
    # the Hessian by central differences, all 4 d^2 points in one batched call
    E = np.eye(d) * h
    plus_plus = x + E[:, None, :] + E[None, :, :]
    plus_minus = x + E[:, None, :] - E[None, :, :]
    pts = np.concatenate([plus_plus.reshape(-1, d), plus_minus.reshape(-1, d), (2 * x - plus_minus).reshape(-1, d),
                          (2 * x - plus_plus).reshape(-1, d)])
    v = -log_post(pts).reshape(4, d, d)
    H = (v[0] - v[1] - v[2] + v[3]) / (4 * h[:, None] * h[None, :])
    H = 0.5 * (H + H.T)
    return x, np.linalg.inv(H)


def importance_reference(case: ModalCase, n_draws: int = 200000, rng: int | np.random.Generator = 0,
                         df: float = 5.0, inflate: float = 1.2, chunk: int = 2000) -> tuple:
    """Posterior moments and log-evidence of every step of a case with static parameters, by importance
    sampling from a Student-t (``df``) at the step's posterior mode with ``inflate``^2 times the Laplace
    covariance, ``n_draws`` draws per step.

    Returns
    -------
    reference : seqbayes.reference.GridReference
    errors : dict
        Monte Carlo standard errors per step: ``"mean" (S, d)``, ``"std" (S, d)`` (of the sd),
        ``"log_evidence" (S,)`` (of the cumulative value, which each step estimates from its own draws) and
        the importance ``"ess" (S,)``.
    """
    if np.any(case.noise > 0):
        raise ValueError("case: importance_reference needs static parameters (every kernel noise 0)")
    rng = np.random.default_rng(rng)
    box = case.box
    log_volume = float(np.sum(np.log(box[:, 1] - box[:, 0])))
    S, d = len(case.datasets), box.shape[0]
    mean, std, inc = np.zeros((S, d)), np.zeros((S, d)), np.zeros(S)
    se = {"mean": np.zeros((S, d)), "std": np.zeros((S, d)), "log_evidence": np.zeros(S), "ess": np.zeros(S)}
    start = box.mean(axis=1)
    log_z_prev, var_prev = 0.0, 0.0
    for s in range(S):
        data = case.datasets[:s + 1]

        def log_post(theta, data=data):
            inside = np.all((theta >= box[:, 0]) & (theta <= box[:, 1]), axis=1)
            out = np.full(theta.shape[0], -np.inf)
            if inside.any():
                t = theta[inside]
                modes = case.likelihood.predict(t)
                out[inside] = sum(case.likelihood(t, x, modes=modes) for x in data) - log_volume
            return out
        centre, cov = _laplace(log_post, start, box)
        start = centre
        scale = inflate ** 2 * cov
        proposal = stats.multivariate_t(loc=centre, shape=scale, df=df)
        log_w = np.empty(n_draws)
        draws = np.empty((n_draws, d))
        for i in range(0, n_draws, chunk):
            x = proposal.rvs(size=min(chunk, n_draws - i), random_state=rng).reshape(-1, d)
            draws[i:i + x.shape[0]] = x
            log_w[i:i + x.shape[0]] = log_post(x) - proposal.logpdf(x)
        log_z = logsumexp(log_w) - np.log(n_draws)               # cumulative log p(D_1..s)
        w = np.exp(log_w - logsumexp(log_w))
        m = w @ draws
        c = draws - m
        v = w @ c ** 2
        mean[s], std[s] = m, np.sqrt(v)
        inc[s] = log_z - log_z_prev
        ratio = np.exp(log_w - np.max(log_w))
        var_log_z = np.var(ratio) / (n_draws * np.mean(ratio) ** 2)   # delta method
        se["log_evidence"][s] = np.sqrt(var_log_z)
        se["mean"][s] = np.sqrt(w ** 2 @ c ** 2)
        se["std"][s] = np.sqrt(w ** 2 @ (c ** 2 - v) ** 2) / (2 * np.sqrt(v))
        se["ess"][s] = 1.0 / np.sum(w ** 2)
        log_z_prev = log_z
    ref = reference.GridReference(case.names, mean, std, np.cumsum(inc), inc,
                                  {"n_draws": n_draws, "df": df, "inflate": inflate})
    return ref, se


def mode_level_reference(likelihood: ModalLikelihood, datasets, box, noise, n_points: int = 201):
    """The exact filter of a mode-level run (:class:`~seqbayes.structural.structures.linear.ModeLevel`, random-walk
    kernel of sds ``noise``, uniform ``box``): the posterior factorises over the modes, so it is one 1-D
    grid filter per mode (the log-evidences add). Returns a :class:`~seqbayes.reference.GridReference`."""
    from .modal_likelihood import modal_data

    box = np.asarray(box, dtype=float)
    d = box.shape[0]
    S = len(datasets)
    mean, std, inc = np.full((S, d), np.nan), np.full((S, d), np.nan), np.zeros(S)
    parsed = [modal_data(x) for x in datasets]
    error = likelihood.frequency_error
    for j in range(d):
        def log_likelihood(axes, data, j=j):
            f = axes[0]
            keep = data.mode == j + 1
            if not keep.any():
                return np.zeros(f.size)
            sd_model = np.broadcast_to(error.values(np.zeros((1, d)), data.mode), (1, data.mode.size))[0, keep][0]
            var = (likelihood.std_scale * data.std_frequency[keep][0]) ** 2 + (sd_model * f) ** 2
            return -0.5 * (np.log(2 * np.pi * var) + (data.frequency[keep][0] - f) ** 2 / var)
        steps = reference.grid_filter(parsed, log_likelihood, box[[j]], [lambda x: x], [noise[j]], n_points,
                                      resolution=reference.Resolution(n_coarse=101))
        ref = reference.reference_from_steps(steps, (f"f{j + 1}",), S, {"n_points": n_points})
        mean[:, j], std[:, j] = ref.mean[:, 0], ref.std[:, 0]
        inc += ref.log_evidence_increment
    names = tuple(f"f{j + 1}" for j in range(d))
    return reference.GridReference(names, mean, std, np.cumsum(inc), inc, {"n_points": n_points})


def datasets_digest(case: ModalCase) -> str:
    """SHA-256 of a case's datasets to 8 significant digits (the same whatever the BLAS), to check that a
    stored reference is of the case rebuilt here."""
    h = hashlib.sha256()
    for data in case.datasets:
        for key in sorted(data):
            h.update((key + ":" + ",".join(f"{v:.8e}" for v in np.asarray(data[key], dtype=float))).encode())
    return h.hexdigest()


def read_importance_reference(text: str | None = None) -> tuple:
    """``(GridReference, se, digest)`` of a reference table written by ``benchmarks/bench_modal_reference.py
    --frame-reference`` (default: the bundled :data:`FRAME_REFERENCE`): columns ``step, quantity, mean,
    std, se_mean, se_std``, the datasets' digest in a ``# datasets sha256`` comment line."""
    if text is None:
        text = resources.files("seqbayes").joinpath(FRAME_REFERENCE).read_text()
    lines = text.splitlines()
    digest = next((line.split()[-1] for line in lines if line.startswith("# datasets sha256")), "")
    rows = [line.split(",") for line in lines if line and not line.startswith("#")][1:]
    names = list(dict.fromkeys(r[1] for r in rows if r[1] != "log_evidence"))
    S = max(int(r[0]) for r in rows)
    mean, std, se_m, se_s = (np.zeros((S, len(names))) for _ in range(4))
    log_z, se_z = np.zeros(S), np.zeros(S)
    for r in rows:
        s = int(r[0]) - 1
        if r[1] == "log_evidence":
            log_z[s], se_z[s] = float(r[2]), float(r[4])
        else:
            j = names.index(r[1])
            mean[s, j], std[s, j], se_m[s, j], se_s[s, j] = map(float, r[2:6])
    ref = reference.GridReference(tuple(names), mean, std, log_z, np.diff(log_z, prepend=0.0), {})
    return ref, {"mean": se_m, "std": se_s, "log_evidence": se_z}, digest


def simulate_poles(rng: np.random.Generator, days: float = 4.0, presence=(0.85, 0.8, 0.8, 0.8, 0.55, 0.4),
                   noise: float = 0.0015, duplicate: float = 0.1, clutter: float = 2.0) -> tuple:
    """Hourly poles of modes like the mast's six lowest (two pairs 1 % apart) under a daily temperature cycle
    of +-0.25 %: mode ``j`` seen with probability ``presence[j]`` (pole error ``noise``, relative), a second
    pole of a seen mode with probability ``duplicate``, Poisson(``clutter``) spurious poles per record
    (log-uniform in 0.1-5 Hz), the SSI's sds unrelated to the errors (about 2 %, as the mast's).

    Returns
    -------
    table : PoleTable
        Rows unsorted within each record.
    truth : (n,) int array
        Each pole's mode (1-based); 0 for clutter, ``-j`` for a duplicate of mode ``j``.
    """
    f0 = np.array([0.351, 0.355, 0.620, 0.626, 1.31, 2.04])
    rows = []
    for h in range(int(days * 24)):
        t = h / 24
        f = f0 * (1 - 0.0005 * 5 * np.sin(2 * np.pi * t))
        for j in range(f0.size):
            if rng.random() < presence[j]:
                rows.append((t, f[j] * (1 + noise * rng.standard_normal()), j + 1))
                if rng.random() < duplicate:
                    rows.append((t, f[j] * (1 + noise * rng.standard_normal()), -(j + 1)))
        rows += [(t, np.exp(rng.uniform(np.log(0.1), np.log(5))), 0) for _ in range(rng.poisson(clutter))]
    r = np.array(rows)
    r = r[np.lexsort((rng.random(len(r)), r[:, 0]))]           # unsorted within a record
    std = r[:, 1] * np.exp(rng.normal(np.log(0.02), 0.7, len(r)))
    n = r.shape[0]
    nan = np.full(n, np.nan)
    table = PoleTable(day=r[:, 0], frequency=r[:, 1], std_frequency=std, damping_pct=nan, std_damping_pct=nan,
                      mpc=nan, mpd=nan, model_order=nan, slot=np.zeros(n))
    return table, r[:, 2].astype(int)
