"""The OpenSees frame example through the command line, against its exact grid reference (issue 23, item 4).

    python benchmarks/bench_opensees.py reference [--workers 2] [--out examples/opensees/frame_reference.csv]
    python benchmarks/bench_opensees.py cli [--workers 1 2] [--campaigns 20] [--keep FOLDER] [--seed S] [--move-budget B]
    python benchmarks/bench_opensees.py compare RUN.nc [RUN.nc ...]
    python benchmarks/bench_opensees.py summary RUN.nc [RUN.nc ...]

``reference`` computes the exact filtering posterior of the example's 20 campaigns on a tensor grid
(:func:`seqbayes.models.opensees_frame.grid_reference`; one OpenSees solve per (kappa, zeta) grid
point and campaign) and writes it as CSV; ``--coarse`` halves the resolution, to measure the grid's
own error.

``cli`` runs the example as a user would, in a fresh folder per worker count: ``seqbayes init
frame.toml run.nc``, one ``seqbayes update run.nc campaignNN.csv`` per campaign, then ``seqbayes
status`` and ``seqbayes report``. It prints per update the likelihood calls and the wall time
(of the ``update`` process, start-up included), the totals, whether the runs with different worker
counts stored bit-identical posteriors, and each campaign's posterior against the reference:
mean error in exact sds, sd ratio - 1 and the cumulative log-evidence error. ``compare`` does the
last for stores kept with ``--keep``, with where each update's calls went (stages, PMMH proposals,
moves pending), and checks that they hold the same posteriors and calls over their common steps (e.g. a 20-campaign run on 2 workers and a 5-campaign run on 1). ``--seed`` replaces
the TOML's sampler seed (the campaigns stay those of seed 2026, which the reference is for) and
``summary`` prints one row per kept store (e.g. of different seeds and budgets): its calls, median and
largest update and its worst and RMS errors against the reference. ``--move-budget`` sets ``[sampler] move_budget`` (SMC^2's PMMH evaluations per update in units of
``N M``; a huge value such as 1e9 lets every rejuvenation complete in its update, as before the budget).
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from seqbayes.models import opensees_frame as frame  # noqa: E402
from seqbayes.parallel import ProcessWorkers  # noqa: E402
from seqbayes.reference import read_reference_table, reference_table  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "examples" / "opensees"
SUMMARY = re.compile(r"(\d+) likelihood evaluations in ([0-9.]+) s")


def reference(args) -> None:
    datasets, _ = frame.simulate(args.campaigns, np.random.default_rng(2026))
    factor = 2 if args.coarse else 1
    zeta = np.linspace(*frame.PRIOR_BOX["zeta"], 100 // factor + 1)
    sigma = np.linspace(0.15, 0.55, 200 // factor + 1)
    start = time.perf_counter()
    with ProcessWorkers(args.workers) as pool:
        ref = frame.grid_reference(datasets, zeta_axis=zeta, sigma_axis=sigma, kappa_spacing=0.002 * factor,
                                   tail=30.0, executor=pool)
    seconds = time.perf_counter() - start
    text = reference_table({("coarse" if args.coarse else "fine",): ref}, ["grid"])
    header = (f"# seqbayes.models.opensees_frame.grid_reference of campaigns 1-{args.campaigns} (seed 2026): "
              f"zeta {zeta.size} points on the box, sigma {sigma.size} points on [0.15, 0.55], "
              f"kappa spacing {0.002 * factor}, tail 30 nats; {seconds:.0f} s on {args.workers} workers\n"
              f"# python benchmarks/bench_opensees.py reference{' --coarse' if args.coarse else ''}\n")
    Path(args.out).write_text(header + text)
    print(header + text)


def _seqbayes(*args, cwd) -> tuple[str, float, float]:
    """Run ``seqbayes ARGS``: its output, wall seconds and CPU seconds (the process and its worker processes)."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "seqbayes.cli", *args], cwd=cwd, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if done.returncode != 0:
        raise RuntimeError(f"seqbayes {' '.join(args)} failed ({done.returncode}):\n{done.stdout}\n{done.stderr}")
    return done.stdout, seconds, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def cli(args) -> None:
    runs = {}
    for workers in args.workers:
        folder = Path(tempfile.mkdtemp(prefix=f"opensees-w{workers}-"))
        try:
            paths = frame.write_campaigns(folder, args.campaigns, seed=2026)
            toml = (EXAMPLE / "frame.toml").read_text()
            toml = re.sub(r"workers = \d+", f"workers = {workers}", toml)
            toml = re.sub(r"seed = \d+", f"seed = {args.seed}", toml)
            if args.move_budget is not None:
                toml = toml.replace("[parallel]", f"move_budget = {args.move_budget!r}\n\n[parallel]")
            (folder / "frame.toml").write_text(toml)
            _seqbayes("init", "frame.toml", "run.nc", cwd=folder)
            rows = []
            for path in paths:
                out, seconds, cpu = _seqbayes("update", "-q", "run.nc", path.name, cwd=folder)
                calls, inside = SUMMARY.search(out).groups()
                rows.append((int(calls), float(inside), seconds, cpu))
                print(f"<!-- workers {workers}: {out.strip()} ({seconds:.1f} s with start-up, {cpu:.1f} s CPU in all "
                      f"processes, load {os.getloadavg()[0]:.1f}) -->", flush=True)
            status, _, _ = _seqbayes("status", "run.nc", cwd=folder)
            _seqbayes("report", "run.nc", "-o", "run.html", cwd=folder)
            from seqbayes.store import open_run

            store = open_run(folder / "run.nc")
            result = store.result
            runs[workers] = (rows, result, status)
            if args.keep:  # the run store, for another comparison later
                tag = (f"_seed{args.seed}" if args.seed != 2026 else "") + (
                    f"_budget{args.move_budget:g}" if args.move_budget is not None else "")
                shutil.copy(folder / "run.nc", Path(args.keep) / f"opensees_run_w{workers}{tag}.nc")
        finally:
            shutil.rmtree(folder, ignore_errors=True)
    load = os.getloadavg()
    print(f"\nload average at the end {load[0]:.1f} / {load[1]:.1f} / {load[2]:.1f} (1, 5, 15 min) on {os.cpu_count()} cores\n")
    print("| update | calls | " + " | ".join(f"wall s, {w} worker{'s' * (w > 1)} | CPU s ({w})" for w in runs) + " |")
    print("|---|---|" + "---|---|" * len(runs))
    first = next(iter(runs))
    for s in range(args.campaigns):
        print(f"| {s + 1} | {runs[first][0][s][0]:,} | "
              + " | ".join(f"{runs[w][0][s][2]:.1f} | {runs[w][0][s][3]:.1f}" for w in runs) + " |")
    print(f"| total | {sum(r[0] for r in runs[first][0]):,} | "
          + " | ".join(f"{sum(r[2] for r in runs[w][0]):.0f} | {sum(r[3] for r in runs[w][0]):.0f}" for w in runs) + " |")
    print(f"| median | {int(np.median([r[0] for r in runs[first][0]])):,} | "
          + " | ".join(f"{np.median([r[2] for r in runs[w][0]]):.1f} | {np.median([r[3] for r in runs[w][0]]):.1f}"
                       for w in runs) + " |")
    if len(runs) > 1:
        same_calls = all([r[0] for r in runs[w][0]] == [r[0] for r in runs[first][0]] for w in runs)
        print(f"\nthe same likelihood calls with every worker count: {'yes' if same_calls else 'NO'}")
    results = [runs[w][1] for w in runs]
    if len(results) > 1:
        identical = all(np.array_equal(a.steps[s].posterior, results[0].steps[s].posterior)
                        for a in results[1:] for s in range(args.campaigns))
        print(f"\nposteriors bit-identical across worker counts: {'yes' if identical else 'NO'}")
    print(runs[next(iter(runs))][2])
    compare(results[0], args.reference, args.campaigns)


def compare(result, reference_file, campaigns) -> None:
    """Each campaign's posterior of ``result`` against the grid reference in ``reference_file``."""
    if not (reference_file and Path(reference_file).exists()):
        print(f"no reference at {reference_file}: run `python benchmarks/bench_opensees.py reference` first")
        return
    ref = next(iter(read_reference_table(Path(reference_file).read_text(), ["grid"], frame.PARAMETER_NAMES).values()))
    errors = ref.errors(result.means(), result.stds(), [rec.info.log_evidence for rec in result.steps])
    print("\n| campaign | exact kappa | mean err / sd (kappa, zeta, sigma) | sd ratio - 1 | log Z err |")
    print("|---|---|---|---|---|")
    for s in range(campaigns):
        print(f"| {s + 1} | {ref.mean[s, 0]:.4f} +- {ref.std[s, 0]:.4f} | "
              f"{', '.join(f'{e:+.2f}' for e in errors['mean_sd'][s])} | "
              f"{', '.join(f'{e:+.2f}' for e in errors['std_ratio'][s])} | {errors['log_evidence'][s]:+.2f} |")
    print(f"\nworst |mean err| {np.abs(errors['mean_sd']).max():.2f} sd, worst |sd ratio - 1| "
          f"{np.abs(errors['std_ratio']).max():.2f}, worst |log Z err| {np.abs(errors['log_evidence']).max():.2f} nats")


def summary(paths, reference_file) -> None:
    """One row per run store: seed, budget, calls, median and largest update, errors against the reference."""
    from seqbayes.engine.settings import MOVE_BUDGET
    from seqbayes.store import open_run

    ref = next(iter(read_reference_table(Path(reference_file).read_text(), ["grid"], frame.PARAMETER_NAMES).values()))
    print("| seed | move_budget | calls | median update | largest update (campaign, stages) | worst mean err / sd "
          "(parameter, campaign) | RMS mean err / sd | worst sd ratio - 1 | worst log Z err |")
    print("|---|---|---|---|---|---|---|---|---|")
    for path in paths:
        store = open_run(path)
        result = store.result
        errors = ref.errors(result.means(), result.stds(), [rec.info.log_evidence for rec in result.steps])
        calls = np.array([rec.info.n_loglike_evals for rec in result.steps])
        big = int(calls.argmax())
        mean_sd = errors["mean_sd"]
        s, p = np.unravel_index(np.abs(mean_sd).argmax(), mean_sd.shape)
        print(f"| {store.config.seed} | {store.config.settings.get('move_budget', MOVE_BUDGET):g} | {calls.sum():,} | "
              f"{int(np.median(calls)):,} | {calls[big]:,} ({big + 1}, {result.steps[big].info.n_stages}) | "
              f"{mean_sd[s, p]:+.2f} ({frame.PARAMETER_NAMES[p]}, {s + 1}) | {np.sqrt(np.mean(mean_sd ** 2)):.2f} | "
              f"{np.abs(errors['std_ratio']).max():.2f} | {np.abs(errors['log_evidence']).max():.2f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="what", required=True)
    p = sub.add_parser("reference")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--campaigns", type=int, default=20)
    p.add_argument("--coarse", action="store_true")
    p.add_argument("--out", default=str(EXAMPLE / "frame_reference.csv"))
    p = sub.add_parser("cli")
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    p.add_argument("--campaigns", type=int, default=20)
    p.add_argument("--reference", default=str(EXAMPLE / "frame_reference.csv"))
    p.add_argument("--keep", metavar="FOLDER", help="copy each run store there")
    p.add_argument("--seed", type=int, default=2026, help="the sampler's seed (the campaigns stay seed 2026's)")
    p.add_argument("--move-budget", type=float, help="[sampler] move_budget (default: the TOML's, i.e. the library's)")
    p = sub.add_parser("compare", help="kept run stores: identical to each other, and the first against the reference")
    p.add_argument("runs", nargs="+")
    p.add_argument("--reference", default=str(EXAMPLE / "frame_reference.csv"))
    p = sub.add_parser("summary", help="kept run stores (seeds, budgets): calls and errors against the reference")
    p.add_argument("runs", nargs="+")
    p.add_argument("--reference", default=str(EXAMPLE / "frame_reference.csv"))
    args = parser.parse_args()
    if args.what == "reference":
        reference(args)
    elif args.what == "cli":
        cli(args)
    elif args.what == "summary":
        summary(args.runs, args.reference)
    else:
        from seqbayes.store import open_run

        results = sorted((open_run(run).result for run in args.runs), key=lambda r: -len(r.steps))
        common = min(len(r.steps) for r in results)
        identical = all(np.array_equal(r.steps[s].posterior, results[0].steps[s].posterior)
                        and r.steps[s].info.n_loglike_evals == results[0].steps[s].info.n_loglike_evals
                        for r in results[1:] for s in range(common))
        print(f"posteriors and likelihood calls identical over their {common} common steps: "
              f"{'yes' if identical else 'NO'}")
        costs(results[0])
        compare(results[0], args.reference, len(results[0].steps))


def costs(result) -> None:
    """Where each update's likelihood calls went, from the store's ``StepInfo``: tempering stages, the moves
    proposed (from update 2 on SMC^2's PMMH moves, each re-running one outer particle's inner filter over every
    campaign so far), the PMMH acceptance since the last resampling (below 0.2 at the end of a rejuvenation, the
    update warns: ``InnerFilterWarning``) and the moves the budget left pending for later updates."""
    print("\n| update | calls | stages | moves proposed (accepted) | PMMH acceptance | moves pending after | amortised calls |")
    print("|---|---|---|---|---|---|---|")
    for s, rec in enumerate(result.steps):
        info = rec.info
        print(f"| {s + 1} | {info.n_loglike_evals:,} | {info.n_stages} | {info.n_proposed} ({info.n_accepted}) | "
              f"{info.pmmh_acceptance:.2f} | {info.pending_moves} | {info.amortised_evals:,.0f} |")


if __name__ == "__main__":
    main()
