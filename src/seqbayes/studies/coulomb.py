"""Sec. 6.4 of Lye et al. (2023): on-line identification of a Coulomb friction force from
real measurements, and selection between the kernels T1 (linear drift) and T2
(exponential decay).

``run_study`` repeats ``n_runs`` independent runs of each sampler (SEMC, SMC) with each
kernel (T1, T2) over the 4 datasets, writes the analogues of the paper's Tables 4-13
(mean and std over runs of the cumulative log-evidence and of the posterior means per
step), the figures of Figs. 8-13 and every run as NetCDF, and returns a
:class:`CoulombStudy`. ``main`` is the command ``seqbayes example coulomb``.

Command line::

    seqbayes example coulomb [--runs 10] [--samples 1000] [--out DIR] [--quick] [--seed S] [--workers W]
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._runner import map_tasks
from ..models import coulomb as model
from ..predictive.smc2 import ParticleInnerFilter

__all__ = ["SAMPLER_SETTINGS", "BOUNDED_COST", "PAPER", "PAPER_STD", "CoulombStudy", "run_study", "summary", "main", "single_blas_thread"]

#: SMC^2 at a bounded cost per update: 8 inner particles (Pitt et al. 2012 put the cost optimum near an inner
#: log-likelihood sd of 1), a pilot of 500 draws for the inner filters' guide, every PMMH proposal screened by the
#: quadratic fitted to the particles' log targets (delayed acceptance) and a hard budget of 5 N M re-run evaluations
#: per update, tempered updates included (``strict_budget``): an update then costs at most about N M + 2,000 + 5 N M
#: calls (comment-ok: the budget's arithmetic).
BOUNDED_COST = {"inner_filter": ParticleInnerFilter(8, n_pilot=500), "surrogate": "quadratic", "move_budget": 5,
                "strict_budget": True}

#: Settings passed to the samplers (flat, :func:`seqbayes.engine.settings.from_flat`) on top of the core's
#: defaults. F_mu drifts and the other three are static, so the defaults run SMC^2
#: (:mod:`seqbayes.predictive.smc2`) at the bounded cost above. The static first step gets more independence-MH
#: sweeps than the default (six for SMC, twelve for SEMC, whose stages stop moving before the cloud has mixed);
#: SMC^2 uses them only at s = 1. Their accuracy against the exact grid and their cost: docs/coulomb_friction.md
#: and docs/benchmarks.md (the Coulomb sections).
SAMPLER_SETTINGS = {"SEMC": {"n_independent": 12, **BOUNDED_COST},
                    "SMC": {"n_independent": 6, **BOUNDED_COST}}

#: The paper's tables (Tables 4-13), mean over the paper's runs, per step 1..4: {(table, sampler, kernel): values}.
PAPER = {
    ("log_evidence", "SEMC", "T1"): (-23.614, -37.486, -51.988, -65.276),
    ("log_evidence", "SEMC", "T2"): (-23.574, -38.913, -53.311, -67.125),
    ("log_evidence", "SMC", "T1"): (-23.493, -44.599, -61.712, -75.096),
    ("log_evidence", "SMC", "T2"): (-23.543, -45.435, -64.471, -82.697),
    ("F_mu", "SEMC", "T1"): (1.409, 0.975, 0.622, 0.233),
    ("F_mu", "SEMC", "T2"): (1.387, 0.929, 0.624, 0.250),
    ("F_mu", "SMC", "T1"): (1.421, 1.027, 0.667, 0.274),
    ("F_mu", "SMC", "T2"): (1.382, 0.929, 0.659, 0.322),
    ("omega_n", "SEMC", "T1"): (20.943, 20.737, 20.791, 20.771),
    ("omega_n", "SEMC", "T2"): (21.056, 21.252, 21.145, 21.155),
    ("omega_n", "SMC", "T1"): (65.762, 23.725, 21.450, 21.045),
    ("omega_n", "SMC", "T2"): (46.800, 24.748, 21.735, 21.668),
    ("sigma_phi", "SEMC", "T1"): (3.492, 3.471, 3.495, 3.482),
    ("sigma_phi", "SEMC", "T2"): (3.559, 3.440, 3.466, 3.456),
    ("sigma_phi", "SMC", "T1"): (6.600, 6.921, 6.934, 6.479),
    ("sigma_phi", "SMC", "T2"): (6.584, 5.646, 6.030, 5.949),
    ("sigma_r", "SEMC", "T1"): (0.383, 0.378, 0.366, 0.366),
    ("sigma_r", "SEMC", "T2"): (0.383, 0.357, 0.357, 0.356),
    ("sigma_r", "SMC", "T1"): (0.393, 0.248, 0.170, 0.156),
    ("sigma_r", "SMC", "T2"): (0.408, 0.311, 0.203, 0.161),
}

#: The "Stdev." columns of the paper's Tables 4-13, same keys as :data:`PAPER`.
PAPER_STD = {
    ("log_evidence", "SEMC", "T1"): (5.210, 9.020, 13.738, 18.829),
    ("log_evidence", "SEMC", "T2"): (5.212, 13.052, 19.356, 25.783),
    ("log_evidence", "SMC", "T1"): (5.212, 8.399, 15.436, 30.674),
    ("log_evidence", "SMC", "T2"): (5.209, 10.501, 18.207, 26.252),
    ("F_mu", "SEMC", "T1"): (0.019, 0.012, 0.007, 0.004),
    ("F_mu", "SEMC", "T2"): (0.024, 0.007, 0.003, 0.003),
    ("F_mu", "SMC", "T1"): (0.070, 0.094, 0.108, 0.095),
    ("F_mu", "SMC", "T2"): (0.108, 0.026, 0.056, 0.083),
    ("omega_n", "SEMC", "T1"): (1.198, 1.220, 1.202, 1.198),
    ("omega_n", "SEMC", "T2"): (1.590, 1.583, 1.504, 1.531),
    ("omega_n", "SMC", "T1"): (1.844, 1.750, 1.540, 1.025),
    ("omega_n", "SMC", "T2"): (1.908, 1.741, 1.237, 1.978),
    ("sigma_phi", "SEMC", "T1"): (0.199, 0.183, 0.190, 0.196),
    ("sigma_phi", "SEMC", "T2"): (0.275, 0.296, 0.295, 0.294),
    ("sigma_phi", "SMC", "T1"): (0.686, 0.686, 0.638, 0.660),
    ("sigma_phi", "SMC", "T2"): (0.683, 0.658, 0.665, 0.682),
    ("sigma_r", "SEMC", "T1"): (0.053, 0.052, 0.054, 0.052),
    ("sigma_r", "SEMC", "T2"): (0.108, 0.111, 0.119, 0.118),
    ("sigma_r", "SMC", "T1"): (0.144, 0.140, 0.149, 0.140),
    ("sigma_r", "SMC", "T2"): (0.252, 0.246, 0.267, 0.226),
}

_QUANTITIES = ("log_evidence",) + model.PARAMETER_NAMES


def single_blas_thread():
    """Context manager limiting BLAS to one thread (``threadpoolctl``; a no-op without it).

    The samplers' predictive-mixture density is a single-precision matrix product with an
    inner dimension of 4 (the parameters). On the shared 2-core machine at load ~9, one SMC
    run with OpenBLAS's default two threads took 2.8-3.2 s (CPU 1.9-2.1 s) against 1.4 s
    (CPU 0.9 s) with one; at load ~3.5 the two were equal within noise
    (``benchmarks/bench_coulomb.py --blas-threads``). The study's two worker processes with
    two BLAS threads each would oversubscribe the two cores whatever the load.
    """
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - optional
        return contextlib.nullcontext()
    return threadpool_limits(limits=1, user_api="blas")


def _run_file(runs_dir, sampler: str, kernel: str, run: int) -> Path:
    return Path(runs_dir) / f"{sampler}_{kernel}_run{run:02d}.nc"


def _one_run(task):
    """Worker: one sampler run over the 4 datasets, written to NetCDF in the worker when
    ``runs_dir`` is given (so the two processes share the ~0.2 s per file of h5netcdf).
    ``task = (sampler, kernel, run, seed, n_samples, settings, runs_dir)``."""
    import seqbayes
    from seqbayes.engine.settings import from_flat

    sampler_name, kernel_name, run, seed, n_samples, settings, runs_dir = task
    cls = {"SEMC": seqbayes.SEMC, "SMC": seqbayes.SMC}[sampler_name]
    with single_blas_thread():
        start = time.perf_counter()
        sampler = cls(model.prior(), model.kernel(kernel_name), model.loglike, n_samples=n_samples,
                      rng=np.random.default_rng(seed), **from_flat(sampler_name, **settings))
        result = sampler.run(model.load_experiment())
        elapsed = time.perf_counter() - start
    if runs_dir is not None:
        result.to_netcdf(_run_file(runs_dir, sampler_name, kernel_name, run))
    return sampler_name, kernel_name, run, result, elapsed


@dataclass(frozen=True)
class CoulombStudy:
    """Everything :func:`run_study` computed.

    Attributes
    ----------
    results : dict (sampler, kernel) -> tuple of Result
        All runs.
    run_times : dict (sampler, kernel) -> ndarray (n_runs,)
        Wall time of each sampler run [s].
    tables : dict (quantity, sampler, kernel) -> ndarray (2, S)
        Mean (row 0) and std (row 1) over runs, per step, of the cumulative
        log-evidence and of the posterior means of F_mu, omega_n, sigma_phi, sigma_r.
    acceptance : dict (sampler, kernel) -> ndarray (n_runs, S)
    reference : seqbayes.models.coulomb.ReferencePosterior
        Exact posterior at s = 1 (Table 3 prior).
    wall_time : float
        Seconds for the runs and the exact reference (not the writing of the outputs).
    out_dir : Path or None
    """

    results: dict
    run_times: dict
    tables: dict
    acceptance: dict
    reference: object
    wall_time: float
    out_dir: Path | None = None
    settings: dict = field(default_factory=dict)

    def log_bayes_factor(self, sampler: str = "SEMC", a: str = "T1", b: str = "T2") -> np.ndarray:
        """``log Z_a - log Z_b`` at the last step for each pair of runs (run i of a with run i of b), ``(n_runs,)``."""
        za = np.array([r.log_evidence[-1] for r in self.results[(sampler, a)]])
        zb = np.array([r.log_evidence[-1] for r in self.results[(sampler, b)]])
        return za - zb


def _tables(results):
    tables, acceptance = {}, {}
    for (sampler, kernel), runs in results.items():
        z = np.array([r.log_evidence for r in runs])                  # (R, S)
        means = np.array([r.means() for r in runs])                  # (R, S, d)
        tables[("log_evidence", sampler, kernel)] = np.array([z.mean(0), z.std(0, ddof=1 if len(runs) > 1 else 0)])
        for j, name in enumerate(model.PARAMETER_NAMES):
            m = means[:, :, j]
            tables[(name, sampler, kernel)] = np.array([m.mean(0), m.std(0, ddof=1 if len(runs) > 1 else 0)])
        acceptance[(sampler, kernel)] = np.array([[i.acceptance_rate for i in r.infos] for r in runs])
    return tables, acceptance


def run_study(n_runs: int = 10, n_samples: int = 1000, samplers=("SEMC", "SMC"), kernels=("T1", "T2"),
              seed: int = 2023, out_dir=None, progress: bool = True, workers: int | None = None,
              settings: dict | None = None, figures: bool = True) -> CoulombStudy:
    """Sec. 6.4: ``n_runs`` independent runs x samplers x kernels over the 4 datasets.

    Parameters
    ----------
    n_runs : int
        Independent runs per (sampler, kernel) (the paper: 10).
    n_samples : int
        Samples per run (the paper: 1000).
    samplers : sequence of {"SEMC", "SMC"}
    kernels : sequence of {"T1", "T2"}
    seed : int
        Root seed; every (sampler, run) gets its own child stream (``SeedSequence.spawn``),
        shared by the kernels (common random numbers for the kernel comparison).
    out_dir : path, optional
        Where to write ``tables.md``, ``tables.csv``, the figures and ``runs/*.nc``.
    progress : bool
        tqdm bar over runs (shown only when stderr is a terminal).
    workers : int, optional
        Processes (default: ``min(2, cpu count)``; 1 runs in this process).
    settings : dict sampler -> dict, optional
        Sampler settings; default :data:`SAMPLER_SETTINGS`.
    figures : bool
        Write the figures (needs ``out_dir``).

    Returns
    -------
    CoulombStudy
    """
    n_runs, n_samples = int(n_runs), int(n_samples)
    if n_runs < 1:
        raise ValueError(f"n_runs: must be >= 1, got {n_runs}")
    if n_samples < 8:
        raise ValueError(f"n_samples: must be >= 8 (2 d walkers), got {n_samples}")
    samplers, kernels = tuple(samplers), tuple(kernels)
    for s in samplers:
        if s not in ("SEMC", "SMC"):
            raise ValueError(f"samplers: expected 'SEMC' or 'SMC', got {s!r}")
    for k in kernels:
        if k not in model.KERNELS:
            raise ValueError(f"kernels: expected 'T1' or 'T2', got {k!r}")
    settings = {**SAMPLER_SETTINGS, **(settings or {})}
    start = time.perf_counter()
    combos = [(s, k) for s in samplers for k in kernels]
    # One child stream per (sampler, run), shared by the kernels: the kernel enters only
    # after step 1, so T1 and T2 runs of the same index see the identical s = 1 posterior
    # and their log Bayes factor measures steps 2-4 only (common random numbers).
    children = np.random.SeedSequence(seed).spawn(len(samplers) * n_runs)
    runs_dir = None
    if out_dir is not None:
        runs_dir = Path(out_dir) / "runs"
        runs_dir.mkdir(parents=True, exist_ok=True)
    tasks = [(s, k, run, children[samplers.index(s) * n_runs + run], n_samples, settings[s], runs_dir)
             for s, k in combos for run in range(n_runs)]
    workers = min(2, os.cpu_count() or 1) if workers is None else int(workers)
    collected = {(s, k, run): (result, dt)
                 for s, k, run, result, dt in map_tasks(_one_run, tasks, workers, "coulomb runs", "run", progress)}
    results = {(s, k): tuple(collected[(s, k, r)][0] for r in range(n_runs)) for s, k in combos}
    run_times = {(s, k): np.array([collected[(s, k, r)][1] for r in range(n_runs)]) for s, k in combos}
    tables, acceptance = _tables(results)
    reference = model.reference_posterior(model.load_experiment()[0], n_grid=20001)
    study = CoulombStudy(results, run_times, tables, acceptance, reference, time.perf_counter() - start,
                         Path(out_dir) if out_dir is not None else None, settings)
    if out_dir is not None:
        write_outputs(study, figures=figures, runs=False)   # the workers wrote the runs
    return study


# --------------------------------------------------------------------------- outputs

_TITLES = {
    "log_evidence": ("Tables 4-5", "cumulative log-evidence log p(D^{1:s} | M)"),
    "F_mu": ("Tables 6-7", "posterior mean of F_mu [N]"),
    "omega_n": ("Tables 8-9", "posterior mean of omega_n [rad/s]"),
    "sigma_phi": ("Tables 10-11", "posterior mean of sigma_phi [deg]"),
    "sigma_r": ("Tables 12-13", "posterior mean of sigma_r"),
}
_TRUE = {"F_mu": model.MEASURED_FORCES, "omega_n": (model.OMEGA_N,) * 4}


def tables_markdown(study: CoulombStudy) -> str:
    """The analogues of Tables 4-13 (mean +- std over runs), with the paper's mean +- Stdev. and the
    exact grid filter's values (:func:`seqbayes.models.coulomb.load_exact_reference`) beside."""
    combos = list(study.results)
    kernels = sorted({k for _, k in combos})
    exact = {k: model.load_exact_reference(k) for k in kernels}

    def exact_value(q, k, step):
        if q == "log_evidence":
            return exact[k].log_evidence[step]
        return exact[k].mean[step, model.PARAMETER_NAMES.index(q)]

    n_runs = len(next(iter(study.results.values())))
    lines = [f"Runs per (sampler, kernel): {n_runs}; samples per run: "
             f"{study.results[combos[0]][0].steps[0].posterior.shape[0]}.", ""]
    for q in _QUANTITIES:
        label, what = _TITLES[q]
        lines += [f"### {label}: {what}", ""]
        head = "| s |" + ("  true |" if q in _TRUE else "") + "".join(f" exact {k} |" for k in kernels)
        rule = "|---|" + ("---|" if q in _TRUE else "") + "---|" * len(kernels)
        for s, k in combos:
            head += f" {s} {k} (ours) | paper |"
            rule += "---|---|"
        lines += [head, rule]
        n_steps = study.tables[(q, *combos[0])].shape[1]
        for step in range(n_steps):
            fmt = ".4f" if q == "sigma_r" else ".3f"
            row = f"| {step + 1} |" + (f" {_TRUE[q][step]:.4g} |" if q in _TRUE else "")
            row += "".join(f" {exact_value(q, k, step):{fmt}} |" for k in kernels)
            for s, k in combos:
                m, sd = study.tables[(q, s, k)][:, step]
                paper, paper_sd = PAPER.get((q, s, k)), PAPER_STD.get((q, s, k))
                fmt = ".4f" if q == "sigma_r" else ".3f"
                cell = f"{paper[step]:{fmt}} +- {paper_sd[step]:{fmt}}" if paper else "-"
                row += f" {m:{fmt}} +- {sd:{fmt}} | {cell} |"
            lines.append(row)
        lines.append("")
    if {"T1", "T2"} <= set(kernels):   # runs of one index share their stream, so the factor measures steps 2-4
        n_steps = study.tables[("log_evidence", *combos[0])].shape[1]
        exact_factor = exact["T1"].log_evidence[n_steps - 1] - exact["T2"].log_evidence[n_steps - 1]
        factors = []
        for sampler in dict.fromkeys(s for s, _ in combos):
            if (sampler, "T1") in study.results and (sampler, "T2") in study.results:
                diff = np.array([a.steps[-1].info.log_evidence - b.steps[-1].info.log_evidence for a, b in
                                 zip(study.results[(sampler, "T1")], study.results[(sampler, "T2")])])
                factors.append(f"{diff.mean():.2f} +- {diff.std(ddof=1) if diff.size > 1 else 0.0:.2f} ({sampler})")
        lines += [f"Log Bayes factor of T1 over T2 at s = {n_steps}: " + ", ".join(factors)
                  + f"; exact {exact_factor:.3f}.", ""]
    ref = study.reference
    lines += ["Exact posterior at s = 1 (Table 3 prior, quadrature): log-evidence "
              f"{ref.log_evidence:.3f}; means " + ", ".join(
                  f"{n} {m:.4g} +- {sd:.2g}" for n, m, sd in zip(model.PARAMETER_NAMES, ref.mean, ref.std)), ""]
    return "\n".join(lines)


def _write_csv(study, path):
    with open(path, "w") as fh:
        fh.write("quantity,sampler,kernel,step,mean,std,paper_mean,paper_std\n")
        for (q, s, k), arr in study.tables.items():
            paper, paper_sd = PAPER.get((q, s, k)), PAPER_STD.get((q, s, k))
            for step in range(arr.shape[1]):
                p = "," if paper is None else f"{paper[step]},{paper_sd[step]}"
                fh.write(f"{q},{s},{k},{step + 1},{arr[0, step]:.6g},{arr[1, step]:.6g},{p}\n")


def write_outputs(study: CoulombStudy, figures: bool = True, runs: bool = True) -> None:
    """Write tables (markdown, csv), figures (PNG) and runs (NetCDF, ``runs/``; skipped with
    ``runs=False``) into ``study.out_dir``."""
    out = study.out_dir
    out.mkdir(parents=True, exist_ok=True)
    (out / "tables.md").write_text(tables_markdown(study))
    _write_csv(study, out / "tables.csv")
    (out / "summary.txt").write_text(summary(study))
    if runs:
        (out / "runs").mkdir(exist_ok=True)
        for (s, k), results in study.results.items():
            for i, result in enumerate(results):
                result.to_netcdf(_run_file(out / "runs", s, k, i))
    if figures:
        write_figures(study, out)


def write_figures(study: CoulombStudy, out) -> list:
    """Figs. 8-13 as PNG files in ``out``; returns their paths."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out = Path(out)
    combos = list(study.results)
    samplers = sorted({s for s, _ in combos}, key=("SEMC", "SMC").index)
    kernels = sorted({k for _, k in combos})
    steps = np.arange(1, study.tables[("log_evidence", *combos[0])].shape[1] + 1)
    colours = {"T1": "tab:blue", "T2": "tab:red"}
    paths = []

    def save(fig, name):
        path = out / name
        fig.tight_layout()
        fig.savefig(path, dpi=110)
        plt.close(fig)
        paths.append(path)

    # Fig. 8: log-evidence
    fig, axes = plt.subplots(1, len(samplers), figsize=(5 * len(samplers), 4), squeeze=False)
    for ax, s in zip(axes[0], samplers):
        for k in kernels:
            m, sd = study.tables[("log_evidence", s, k)]
            ax.errorbar(steps + (0.05 if k == "T2" else 0), m, sd, marker="s", capsize=3, color=colours[k], label=k)
        ax.set(title=f"{s}: cumulative log-evidence", xlabel="s", ylabel="log p(D^{1:s} | M)", xticks=steps)
        ax.legend()
    save(fig, "fig08_log_evidence.png")
    # Fig. 9: acceptance rates
    fig, axes = plt.subplots(1, len(samplers), figsize=(5 * len(samplers), 4), squeeze=False)
    for ax, s in zip(axes[0], samplers):
        for k in kernels:
            acc = study.acceptance[(s, k)]
            ax.errorbar(steps + (0.05 if k == "T2" else 0), acc.mean(0), acc.std(0), marker="s", capsize=3,
                        color=colours[k], label=k)
        ax.axhline(0.21 / 4 + 0.23, color="c", label="target 0.283")
        ax.axhline(0.15, color="k", lw=0.8)
        ax.axhline(0.50, color="k", lw=0.8)
        ax.set(title=f"{s}: acceptance rate", xlabel="s", ylim=(0, 1), xticks=steps)
        ax.legend()
    save(fig, "fig09_acceptance.png")
    # Fig. 10: F_mu with one-sigma bars (mean over runs of the posterior mean and std)
    fig, axes = plt.subplots(1, len(kernels), figsize=(5 * len(kernels), 4), squeeze=False)
    for ax, k in zip(axes[0], kernels):
        ax.plot(steps, model.MEASURED_FORCES, "kx", ms=9, mew=2, label="measured")
        for s in samplers:
            runs = study.results[(s, k)]
            m = np.mean([r.means()[:, 0] for r in runs], axis=0)
            sd = np.mean([r.stds()[:, 0] for r in runs], axis=0)
            ax.errorbar(steps + (0.05 if s == "SMC" else 0), m, sd, marker="s", capsize=3, label=s)
        ax.set(title=f"F_mu, kernel {k}", xlabel="s", ylabel="F_mu [N]", xticks=steps)
        ax.legend()
    save(fig, "fig10_friction.png")
    # Fig. 11: predictions of F_mu(t_{s+1}) from the posterior at s (pooled over runs), first sampler
    s0 = samplers[0]
    fig, axes = plt.subplots(1, len(kernels), figsize=(5 * len(kernels), 4), squeeze=False)
    for ax, k in zip(axes[0], kernels):
        runs = study.results[(s0, k)]
        for i, colour in zip(range(len(steps)), ("tab:red", "tab:green", "tab:blue", "gold")):
            pred = np.concatenate([r.steps[i].predictive[:, 0] for r in runs])
            ax.hist(pred, bins=60, alpha=0.55, color=colour, density=True, label=f"from s = {i + 1}")
        for f in model.MEASURED_FORCES:
            ax.axvline(f, color="k", ls=":")
        ax.set(title=f"{s0}, {k}: predicted F_mu(t_(s+1))", xlabel="F_mu [N]")
        ax.legend(fontsize=8)
    save(fig, "fig11_predictions.png")
    # Figs. 12-13: time-invariant parameters, one figure per kernel
    refs = {"omega_n": model.OMEGA_N, "sigma_phi": study.reference.mean[2], "sigma_r": study.reference.mean[3]}
    for k, name in zip(kernels, ("fig12_static_T1.png", "fig13_static_T2.png")):
        fig, axes = plt.subplots(1, 3, figsize=(14, 4))
        for ax, (j, p) in zip(axes, [(1, "omega_n"), (2, "sigma_phi"), (3, "sigma_r")]):
            for s in samplers:
                runs = study.results[(s, k)]
                m = np.mean([r.means()[:, j] for r in runs], axis=0)
                sd = np.mean([r.stds()[:, j] for r in runs], axis=0)
                ax.errorbar(steps + (0.05 if s == "SMC" else 0), m, sd, marker="s", capsize=3, label=s)
            ax.axhline(refs[p], color="k", ls="--",
                       label="measured" if p == "omega_n" else "exact posterior mean, s = 1")
            ax.set(title=f"{p}, kernel {k}", xlabel="s", xticks=steps)
            ax.legend(fontsize=8)
        save(fig, name)
    return paths


def kernel_legend() -> str:
    """One line naming the candidate kernels T1 and T2 (Eqs. 21-22) from their settings in the model.

    >>> kernel_legend()
    'T1 = linear drift, F_mu - 0.375 + N(0, 0.04^2) (Eq. 21); T2 = exponential decay, exp(-0.47) F_mu + N(0, 0.09^2) (Eq. 22)'
    """
    (_, drift, drift_sd), (_, decay, decay_sd) = model.KERNELS["T1"], model.KERNELS["T2"]
    return (f"T1 = linear drift, F_mu {'-' if drift < 0 else '+'} {abs(drift):g} + N(0, {drift_sd:g}^2) (Eq. 21); "
            f"T2 = exponential decay, exp(-{decay:g}) F_mu + N(0, {decay_sd:g}^2) (Eq. 22)")


def summary(study: CoulombStudy) -> str:
    """Plain-text summary: the most probable kernel per sampler and the posterior of F_mu per step."""
    combos = list(study.results)
    samplers = sorted({s for s, _ in combos}, key=("SEMC", "SMC").index)
    kernels = sorted({k for _, k in combos})
    n_runs = len(study.results[combos[0]])
    lines = [f"Coulomb-friction study (Sec. 6.4): {n_runs} run(s) x {', '.join(samplers)} x {', '.join(kernels)}, "
             f"{study.results[combos[0]][0].steps[0].posterior.shape[0]} samples, 4 steps, "
             f"{study.wall_time:.1f} s", ""]
    lines += [f"Kernels (how the friction force F_mu may change between datasets): {kernel_legend()}", ""]
    lines.append("Model selection (cumulative log-evidence at s = 4, mean +- std over runs):")
    best = {}
    for s in samplers:
        z = {k: study.tables[("log_evidence", s, k)][:, -1] for k in kernels}
        best[s] = max(kernels, key=lambda k: z[k][0])
        cells = "   ".join(f"{k}: {z[k][0]:8.2f} +- {z[k][1]:.2f}" for k in kernels)
        extra = ""
        if {"T1", "T2"} <= set(kernels):
            lnb = study.log_bayes_factor(s, "T1", "T2")
            extra = (f"   log B(T1:T2) = {lnb.mean():.2f} +- {lnb.std(ddof=1) if lnb.size > 1 else 0:.2f}"
                     f"   P(T1) = {1 / (1 + np.exp(-lnb.mean())):.3f}")
        lines.append(f"  {s:4s}  {cells}{extra}   most probable: {best[s]}")
    lines.append("")
    s0 = samplers[0]
    k0 = best[s0]
    lines.append(f"Posterior of F_mu per step ({s0}, most probable kernel {k0}; mean over runs of the "
                 "posterior mean and std):")
    runs = study.results[(s0, k0)]
    m = np.mean([r.means()[:, 0] for r in runs], axis=0)
    sd = np.mean([r.stds()[:, 0] for r in runs], axis=0)
    lines.append("   s   measured   posterior mean +- std")
    for i in range(m.size):
        lines.append(f"   {i + 1}   {model.MEASURED_FORCES[i]:8.3f}   {m[i]:.3f} +- {sd[i]:.3f}")
    lines.append("")
    lines.append("Prior-data conflict (largest posterior-mean shift in prior sds over runs and steps 2-4; "
                 "flagged above 4):")
    for s in samplers:
        cells = []
        for k in kernels:
            shifts = [(r.steps[i].info.prior_data_conflict, i + 1, r.steps[i].info.conflict_parameter)
                      for r in study.results[(s, k)] for i in range(1, len(r.steps))]
            worst = max(shifts, key=lambda c: np.nan_to_num(c[0], nan=-np.inf))
            flag = f" at s = {worst[1]} ({worst[2]}) FLAGGED" if worst[0] > 4 else ""
            cells.append(f"{k}: {worst[0]:.2f}{flag}")
        lines.append(f"  {s:4s}  " + "   ".join(cells))
    ref = study.reference
    lines.append("")
    lines.append(f"Exact posterior at s = 1: log-evidence {ref.log_evidence:.2f}, F_mu {ref.mean[0]:.3f} +- "
                 f"{ref.std[0]:.3f} N, omega_n {ref.mean[1]:.3f} +- {ref.std[1]:.3f} rad/s")
    times = np.concatenate(list(study.run_times.values()))
    lines.append(f"Per sampler run (4 steps): {times.mean():.2f} s mean, {times.max():.2f} s max")
    if study.out_dir is not None:
        lines.append(f"Tables, figures and runs (NetCDF) in {study.out_dir}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """``seqbayes example coulomb``: run the study and print the summary."""
    parser = argparse.ArgumentParser(prog="seqbayes example coulomb",
                                     description="Coulomb-friction experiment of Lye et al. (2023), Sec. 6.4")
    parser.add_argument("--runs", type=int, default=10, help="independent runs per sampler and kernel (10)")
    parser.add_argument("--samples", type=int, default=1000, help="samples per run (1000)")
    parser.add_argument("--out", default="coulomb_results", help="output folder (coulomb_results)")
    parser.add_argument("--quick", action="store_true", help="2 runs instead of --runs (the README's first command)")
    parser.add_argument("--seed", type=int, default=2023, help="root seed (2023)")
    parser.add_argument("--workers", type=int, default=None, help="processes (default: up to 2)")
    parser.add_argument("--no-figures", action="store_true", help="skip the figures")
    args = parser.parse_args(argv)
    n_runs = 2 if args.quick else args.runs
    start = time.perf_counter()
    study = run_study(n_runs=n_runs, n_samples=args.samples, seed=args.seed, out_dir=args.out,
                      workers=args.workers, figures=not args.no_figures)
    print(summary(study))
    print(f"Wall time with tables, figures and NetCDF: {time.perf_counter() - start:.1f} s")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
