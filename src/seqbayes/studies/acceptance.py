"""Sec. 4 and Fig. 2 of Lye et al. (2023): are there bounds on the SEMC acceptance rate?

The paper runs SEMC on the Coulomb-friction problem (Sec. 6, kernel T1, four
datasets, ``d = 4``) with target acceptance rates
``{0.100, 0.283, 0.440, 0.800, 0.900, 1.000}`` and starting step sizes
``{40, 40, 8, 2, 2, 2}`` and observes that the acceptance rate never falls below
about 0.30 nor rises above about 0.85, whatever the target.

The authors' rate is not the true one. Their ``EMCMCsampler`` does
``ThinChain = 3`` stretch sweeps per call and returns
``1 - rejected / totcount`` with ``totcount`` *starting at N* (so the
denominator is ``4N`` for ``3N`` proposals), and a walker whose partner is an
identical copy (common after resampling) proposes itself, which passes their
test with probability ``min(1, lambda^(d-1))`` and is counted as accepted
although nothing moves. Their rate is therefore

    alpha_authors = 1/4 + 3/4 * (n_accepted + p_id(u, d) n_identical) / n_proposed,

``p_id(u, d) = E[min(1, lambda^(d-1))]`` under ``g(lambda)`` of Eq. (6). With
no identical partners that is ``0.25 + 0.75 alpha_true``: a floor of 0.25 by
construction. Their code also redraws proposals that leave the prior box
instead of rejecting them, which raises the rate further when ``u`` is large;
``alpha_authors_redraw`` divides by the proposals that landed inside the box.

This study runs our SEMC (true rate, proposals outside the box rejected) over
several seeds and reports, per target and step, the true rate and both
emulations of the authors' counter, for ``N`` in ``{500, 1000, 4000}``, with and
without adaptive tempering, and on a 2-D problem (the damped oscillator of
Sec. 5, run 0, kernel T1).

Sampler settings. The question is what the paper's adaptive step size does, so
SEMC runs with the paper's Algorithm 2 (:data:`PAPER_SETTINGS`): stretch moves in
the parameters' own coordinates (a proposal outside the prior box is rejected;
with the library's default log/logit coordinates no proposal ever leaves the box
and ``u`` means something else), virtual iterations of one sweep until
``|alpha - alpha_old| < 0.1 alpha_tr`` with no minimum number of sweeps and no
"90% of the particles moved" rule (which at target 0.1 alone adds some 20 sweeps
per stage and would dominate the step-size loop), the tempering path's evidence
(no importance-sampling draws, whose independence-MH sweep would refresh
identical copies) and no restricted restart when few particles have a non-zero
likelihood. Tempering (when on) starts as soon as a one-stage reweighting would
leave less than 50% of the ESS (``tempering_threshold=0.5``, as the Coulomb
study): the core's default of 10% is relative to the particles with a non-zero
likelihood, and without the restricted restart only ~1.5% of the Coulomb prior
draws have one, so at N = 500 the default takes step 1 in one stage in most
runs and the ensemble collapses onto 1-10 points, as untempered (measured:
docs/acceptance_rates.md). One configuration runs with the library defaults
for comparison.

``seqbayes example acceptance [--seeds 5] [--out DIR] [--quick]``
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from ._runner import map_tasks

__all__ = ["TARGETS", "START_STEP_SIZES", "PAPER_SETTINGS", "SETTINGS", "identical_partner_acceptance", "authors_rate",
           "run_config", "run_study", "bounds_table", "plot", "main"]

TARGETS = (0.100, 0.283, 0.440, 0.800, 0.900, 1.000)
START_STEP_SIZES = (40.0, 40.0, 8.0, 2.0, 2.0, 2.0)
#: SEMC settings that make the library's sampler the paper's Algorithm 2 (see the module doc)
#: (the transition-mixture predictive moves the ensemble at every step, as Algorithm 2 does; the
#: library's default for the Coulomb kernel, SMC^2, moves only when the ESS falls, which leaves
#: most steps with no acceptance rate to study)
PAPER_SETTINGS = {"transform": False, "moved_fraction": 0.0, "n_moves": 1, "evidence": "path",
                  "min_valid_fraction": 0.0, "tempering_threshold": 0.5, "predictive": "transition"}
#: named sampler settings a configuration can use ("defaults": the library's SamplerConfig defaults, with
#: the transition-mixture predictive for the reason above)
SETTINGS = {"paper": PAPER_SETTINGS, "defaults": {"predictive": "transition"}}
#: (problem, N, tempering, settings) configurations of the full study
CONFIGS = (("coulomb", 500, True, "paper"), ("coulomb", 1000, True, "paper"), ("coulomb", 4000, True, "paper"),
           ("coulomb", 1000, False, "paper"), ("oscillator", 1000, True, "paper"),
           ("coulomb", 1000, True, "defaults"))
QUICK_CONFIGS = (("coulomb", 500, True, "paper"), ("oscillator", 500, True, "paper"))


def identical_partner_acceptance(step_size, dim: int) -> np.ndarray:
    """``E[min(1, lambda^(d-1))]`` for ``lambda ~ g`` of Eq. (6) on ``[1/u, u]``.

    The probability that the authors' stretch move "accepts" a walker whose
    partner is an identical copy (the proposal is the walker itself).

    ``g(lambda) = lambda^(-1/2) / (2 (sqrt(u) - 1/sqrt(u)))``, so
    ``P(lambda >= 1) = 2 (sqrt(u) - 1) / Z`` and
    ``int_{1/u}^1 lambda^(d-1) g = (1 - u^-(d-1/2)) / ((d - 1/2) Z)``, ``Z = 2 (sqrt(u) - 1/sqrt(u))``.

    >>> float(identical_partner_acceptance(2.0, 1))
    1.0
    """
    u = np.asarray(step_size, dtype=float)
    if np.any(u <= 1):
        raise ValueError(f"step_size: must be > 1, got {step_size}")
    if dim < 1:
        raise ValueError(f"dim: must be >= 1, got {dim}")
    z = 2.0 * (np.sqrt(u) - 1.0 / np.sqrt(u))
    power = dim - 0.5
    return (2.0 * (np.sqrt(u) - 1.0) + (1.0 - u ** (-power)) / power) / z


def authors_rate(n_accepted, n_identical, n_proposed, step_size, dim: int, n_outside=0):
    """The acceptance rate as the authors' code reports it (see module doc).

    Parameters
    ----------
    n_accepted, n_identical, n_proposed : array_like
        True accepted moves, proposals with an identical partner, proposals made.
    step_size : array_like
        Stretch step size ``u``.
    dim : int
    n_outside : array_like
        Proposals outside the prior box; the authors redraw these, so they are
        removed from the denominator (0: counter artifact only).
    """
    n_accepted, n_identical, n_proposed = (np.asarray(x, dtype=float) for x in (n_accepted, n_identical, n_proposed))
    counted = n_accepted + identical_partner_acceptance(step_size, dim) * n_identical
    return 0.25 + 0.75 * counted / (n_proposed - np.asarray(n_outside, dtype=float))


def _problem(name):
    if name == "coulomb":
        from ..models import coulomb

        return coulomb.prior(), coulomb.kernel("T1"), coulomb.loglike, coulomb.load_experiment()
    if name == "oscillator":
        from ..models import oscillator as osc
        from .oscillator import problem_seed

        problem = osc.make_problem(np.random.default_rng(problem_seed(0, 0)))
        return osc.prior(), problem.kernels["T1"].kernel, osc.log_likelihood, problem.datasets
    raise ValueError(f"problem: expected 'coulomb' or 'oscillator', got {name!r}")


def run_config(problem: str, n_samples: int, tempering: bool, target: float, step_size: float, seed: int,
               settings: str = "paper") -> dict:
    """One SEMC run; returns per-step counts and rates (arrays of length S).

    ``settings`` names an entry of :data:`SETTINGS` (``"paper"``: Algorithm 2 as
    printed, the study's default; ``"defaults"``: the library's defaults).
    """
    from ..engine.drivers import SEMC
    from ..engine.settings import from_flat
    from ..core.errors import ZeroLikelihoodError

    if settings not in SETTINGS:
        raise ValueError(f"settings: expected one of {sorted(SETTINGS)}, got {settings!r}")
    prior, kernel, loglike, datasets = _problem(problem)
    dim = prior.support.shape[0]
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(int(1000 * target), n_samples)))
    sampler = SEMC(prior, kernel, loglike, n_samples=n_samples, rng=rng,
                   **from_flat("SEMC", target_acceptance=target, step_size=step_size, tempering=tempering,
                               **SETTINGS[settings]))
    rows = []
    failed_step = 0
    for s, dataset in enumerate(datasets):
        try:
            info = sampler.update(dataset)
        except ZeroLikelihoodError:
            # every particle has zero likelihood (seen untempered, when step 1 missed the
            # posterior); the remaining steps are NaN and the failure is counted
            failed_step = s + 1
            rows += [(np.nan,) * 9] * (len(datasets) - s)
            break
        # a proposal outside the prior box is rejected without a likelihood evaluation, so the
        # out-of-box proposals are those made minus identical-partner ones (not evaluated either)
        # minus those the stretch sweeps evaluated (StepInfo.n_move_evaluations, which excludes
        # the starting, restart and importance-sampling evaluations)
        n_outside = info.n_proposed - info.n_identical_partner - info.n_move_evaluations
        rows.append((info.acceptance_rate, info.n_accepted, info.n_identical_partner, info.n_proposed, n_outside,
                     info.step_size, info.n_virtual, info.n_stages, info.n_distinct))
    arr = np.array(rows, dtype=float)
    true, n_acc, n_id, n_prop, n_out, u = arr[:, :6].T
    return {"true": true, "authors": authors_rate(n_acc, n_id, n_prop, u, dim),
            "authors_redraw": authors_rate(n_acc, n_id, n_prop, u, dim, n_out),
            "identical_fraction": n_id / n_prop, "outside_fraction": n_out / n_prop,
            "step_size": u, "n_virtual": arr[:, 6], "n_stages": arr[:, 7], "n_distinct": arr[:, 8],
            "failed": np.arange(1, len(rows) + 1) >= failed_step if failed_step else np.zeros(len(rows), bool)}


def _star(args):
    return args, run_config(*args)


def run_study(configs=CONFIGS, seeds: int = 5, workers: int | None = None, progress: bool | None = None):
    """All configurations x targets x seeds; returns an :class:`xarray.Dataset`.

    Dims ``config, target, seed, step``; variables ``true``, ``authors``,
    ``authors_redraw``, ``identical_fraction``, ``outside_fraction``,
    ``step_size``, ``n_virtual``, ``n_stages``, ``n_distinct``.
    """
    import xarray as xr

    if int(seeds) < 1:
        raise ValueError(f"seeds: must be at least 1, got {seeds}")
    workers = min(2, os.cpu_count() or 1) if workers is None else int(workers)
    progress = sys.stderr.isatty() if progress is None else progress
    configs = tuple(tuple(c) + (("paper",) if len(c) == 3 else ()) for c in configs)
    tasks = [(p, n, t, target, u, seed, st) for (p, n, t, st) in configs
             for target, u in zip(TARGETS, START_STEP_SIZES) for seed in range(seeds)]
    # longest first so that the two workers finish together
    tasks.sort(key=lambda task: -task[1])
    start = time.perf_counter()
    results = dict(map_tasks(_star, tasks, workers, "acceptance study", "run", progress))
    names = [f"{p} N={n}" + ("" if t else " untempered") + ("" if st == "paper" else f" ({st})")
             for (p, n, t, st) in configs]
    n_steps = {p: len(_problem(p)[3]) for p in {c[0] for c in configs}}
    S = max(n_steps.values())
    variables = next(iter(results.values())).keys()
    data = {v: np.full((len(configs), len(TARGETS), seeds, S), np.nan) for v in variables}
    for (p, n, t, target, u, seed, st), res in results.items():
        c = configs.index((p, n, t, st))
        i = TARGETS.index(target)
        for v in variables:
            data[v][c, i, seed, : len(res[v])] = res[v]
    ds = xr.Dataset({v: (("config", "target", "seed", "step"), a) for v, a in data.items()},
                    coords={"config": names, "target": list(TARGETS), "seed": np.arange(seeds),
                            "step": np.arange(1, S + 1),
                            "start_step_size": ("target", list(START_STEP_SIZES)),
                            "dim": ("config", [4 if c[0] == "coulomb" else 2 for c in configs]),
                            "settings": ("config", [c[3] for c in configs])})
    ds.attrs["wall_time"] = time.perf_counter() - start
    ds.attrs["workers"] = workers
    return ds


def bounds_table(ds) -> str:
    """Markdown: per configuration and target, min / mean / max of each rate over steps and seeds."""
    lines = ["| configuration | target | u(s=1) | true min / mean / max | authors' counter min / mean / max "
             "| + box redraw min / mean / max | identical partners | outside box | failed runs |",
             "|:---|---:|---:|:---|:---|:---|---:|---:|---:|"]
    for c in ds["config"].values:
        for t, u in zip(ds["target"].values, ds["start_step_size"].values):
            sub = ds.sel(config=c, target=t)
            cells = []
            for v in ("true", "authors", "authors_redraw"):
                a = sub[v].values
                a = a[np.isfinite(a)]                                   # failed runs leave NaN
                cells.append(f"{a.min():.3f} / {a.mean():.3f} / {a.max():.3f}" if a.size else "- (all failed)")
            failed = int(np.any(sub["failed"].values == 1, axis=1).sum())
            lines.append(f"| {c} | {t:.3f} | {u:g} | " + " | ".join(cells)
                         + f" | {float(sub['identical_fraction'].mean()):.3f} | {float(sub['outside_fraction'].mean()):.3f}"
                         + f" | {failed} |")
    return "\n".join(lines)


def overall_bounds(ds) -> str:
    """Per configuration: the lowest and highest rate over every target, step and seed."""
    lines = ["| configuration | true: lowest / highest | authors' counter: lowest / highest "
             "| + box redraw: lowest / highest | failed runs |",
             "|:---|:---|:---|:---|---:|"]
    for c in ds["config"].values:
        sub = ds.sel(config=c)
        cells = [f"{float(sub[v].min()):.3f} / {float(sub[v].max()):.3f}" for v in ("true", "authors", "authors_redraw")]
        cells.append(str(int(np.any(sub["failed"].values == 1, axis=-1).sum())))
        lines.append(f"| {c} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot(ds, path, config=None, dpi: int = 70):
    """Fig. 2: acceptance rate per step for each target (mean over seeds, band min-max), true and authors' way."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    configs = list(ds["config"].values) if config is None else [config]
    fig, axes = plt.subplots(2, len(configs), figsize=(3.2 * len(configs), 5.2), squeeze=False,
                             sharey=True, constrained_layout=True)
    steps = ds["step"].values
    for col, c in enumerate(configs):
        for row, (v, title) in enumerate((("true", "true rate"), ("authors", "authors' counter"))):
            ax = axes[row, col]
            for i, t in enumerate(ds["target"].values):
                a = ds[v].sel(config=c, target=t).values                       # (seeds, S)
                ok = ~np.all(np.isnan(a), axis=0)                              # problems differ in S
                a = a[:, ok]
                ax.plot(steps[ok], np.mean(a, 0), "o-", color=f"C{i}", ms=3, lw=1,
                        label=f"{t:.3f} (u={ds['start_step_size'].values[i]:g})")
                ax.fill_between(steps[ok], np.min(a, 0), np.max(a, 0), color=f"C{i}", alpha=0.15)
            ax.axhspan(0.30, 0.85, color="0.92", zorder=0)
            ax.set_ylim(0, 1)
            ax.set_xticks(steps)
            ax.set_title(f"{c}\n{title}", fontsize=8)
            ax.tick_params(labelsize=7)
            if row == 1:
                ax.set_xlabel("step s", fontsize=8)
        axes[0, col].set_ylabel("acceptance rate", fontsize=8) if col == 0 else None
        axes[1, col].set_ylabel("acceptance rate", fontsize=8) if col == 0 else None
    axes[0, 0].legend(title="target", fontsize=6, title_fontsize=6, loc="upper left")
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="seqbayes example acceptance",
                                     description="SEMC acceptance-rate bounds (Lye et al. 2023, Sec. 4, Fig. 2)")
    parser.add_argument("--seeds", type=int, default=5, help="repetitions per configuration and target (default 5)")
    parser.add_argument("--workers", type=int, default=None, help="worker processes (default min(2, cores))")
    parser.add_argument("--out", type=Path, default=Path("seqbayes-output/acceptance"))
    parser.add_argument("--quick", action="store_true", help="N = 500 only, 2 seeds (a smoke test)")
    args = parser.parse_args(argv)
    configs, seeds = (QUICK_CONFIGS, 2) if args.quick else (CONFIGS, args.seeds)
    ds = run_study(configs, seeds, args.workers)
    args.out.mkdir(parents=True, exist_ok=True)
    ds.to_netcdf(args.out / "acceptance_study.nc", engine="h5netcdf")
    report = (f"SEMC acceptance rates, {seeds} seeds per configuration and target; wall time "
              f"{ds.attrs['wall_time']:.1f} s on {ds.attrs['workers']} worker(s)\n\n"
              + overall_bounds(ds) + "\n\n" + bounds_table(ds))
    (args.out / "report.md").write_text(report + "\n")
    print(report)
    figure = args.out / "acceptance_rates.png"
    plot(ds, figure)
    print(f"figure: {figure}")
    print(f"data: {args.out / 'acceptance_study.nc'}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
