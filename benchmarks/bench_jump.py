"""Jump kernels on the synthetic abrupt drop (issue 11): is sudden damage told from smooth decay?

    python benchmarks/bench_jump.py [--seeds 10] [--samples 1000] [--workers 2] [--exact] [--out FILE]
                                    [--runs-json FILE] [--refs-json FILE] [--refs-only]

For each seed, :func:`seqbayes.studies.abrupt_drop.simulate` makes two 8-inspection histories of
the damped oscillator with the same noise: one whose stiffness drops 30 % at step 5, one with
smooth decay only. Each is assimilated by SEMC and SMC (N = 1000) under the four candidate
kernels of :func:`~seqbayes.studies.abrupt_drop.candidate_kernels` (decay, drift, jump,
jump-heavy); the kernel with the largest cumulative log-evidence is selected. Printed per
sampler and variant: how often a jump kernel is selected, the jump kernel's posterior jump
probability at the drop step and its largest at the other steps (issue 11's acceptance: a jump
kernel in at least 9 of 10 seeds on the drop with the probability above 0.9 at the drop step and
below 0.1 elsewhere; a smooth kernel in at least 9 of 10 on the smooth variant).

With ``--exact`` the exact grid reference (:func:`~seqbayes.studies.abrupt_drop.exact_reference`)
of every history under the decay and jump kernels is computed too, and the samplers' errors
against it are printed: posterior means in exact sds, cumulative log-evidence in nats and the
jump probability, the worst over the 8 steps, and the exact selection between decay and jump.

``--out`` saves every run's and reference's numbers as JSON; ``--runs-json`` / ``--refs-json``
read them back instead of recomputing (``--refs-only`` computes the references alone), so the
two halves can run as separate processes.

Every (seed, variant, kernel, sampler) task has its own seed
(``SeedSequence(seed, spawn_key=(variant, kernel, sampler))``); the history is drawn from
``default_rng(seed)``.
"""

from __future__ import annotations

import argparse
import json
import os
import time
import warnings
from concurrent.futures import ProcessPoolExecutor

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from seqbayes import SEMC, SMC  # noqa: E402
from seqbayes.models import oscillator as osc  # noqa: E402
from seqbayes.studies import abrupt_drop as ad  # noqa: E402

VARIANTS = ("drop", "smooth")
KERNELS = ("decay", "drift", "jump", "jump-heavy")
SAMPLERS = {"SEMC": SEMC, "SMC": SMC}
JUMP_KERNELS = ("jump", "jump-heavy")


def history(seed: int, variant: str):
    return ad.simulate(np.random.default_rng(seed), drop_step=ad.DROP_STEP if variant == "drop" else None)


def run_task(args):
    seed, variant, kernel, sampler, n = args
    data = history(seed, variant)
    rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(VARIANTS.index(variant), KERNELS.index(kernel),
                                                                       list(SAMPLERS).index(sampler))))
    start = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        smp = SAMPLERS[sampler](osc.prior(), ad.candidate_kernels()[kernel], osc.log_likelihood, n_samples=n, rng=rng)
        result = smp.run(data.datasets)
    infos = [s.info for s in result.steps]
    return {"seed": seed, "variant": variant, "kernel": kernel, "sampler": sampler,
            "log_evidence": [i.log_evidence for i in infos], "jump_probability": [i.jump_probability for i in infos],
            "jump_size": [i.jump_size for i in infos], "jump_size_sd": [i.jump_size_sd for i in infos],
            "mean": result.means().tolist(), "std": result.stds().tolist(),
            "path_steps": [getattr(i, "path_steps", 0) for i in infos], "wall_time": time.perf_counter() - start}


def reference_task(args):
    seed, variant, kernel = args
    ref = ad.exact_reference(history(seed, variant).datasets, ad.candidate_kernels()[kernel])
    return {"seed": seed, "variant": variant, "kernel": kernel, "mean": ref.grid.mean.tolist(),
            "std": ref.grid.std.tolist(), "log_evidence": ref.grid.log_evidence.tolist(),
            "jump_probability": ref.jump_probability[:, 0].tolist()}


def summarise(runs, refs, seeds):
    drop = ad.DROP_STEP - 1
    others = [s for s in range(ad.N_STEPS) if s not in (0, drop)]
    lines = ["| sampler | variant | jump kernel selected | P(jump) at the drop step (min) | "
             "P(jump) elsewhere (max) | selected (per seed) |", "|---|---|---|---|---|---|"]
    verdict = {}
    for sampler in SAMPLERS:
        for variant in VARIANTS:
            chosen, at_drop, elsewhere = [], [], []
            for seed in seeds:
                rows = {r["kernel"]: r for r in runs if (r["seed"], r["variant"], r["sampler"]) == (seed, variant, sampler)}
                chosen.append(max(KERNELS, key=lambda k: rows[k]["log_evidence"][-1]))
                p = np.array(rows["jump"]["jump_probability"])
                at_drop.append(p[drop])
                elsewhere.append(np.max(p[others] if variant == "drop" else p[1:]))
            n_jump = sum(c in JUMP_KERNELS for c in chosen)
            verdict[(sampler, variant)] = (n_jump, min(at_drop), max(elsewhere))
            drop_cell = f"{min(at_drop):.3f}" if variant == "drop" else "-"
            lines.append(f"| {sampler} | {variant} | {n_jump} of {len(seeds)} | {drop_cell} | {max(elsewhere):.3f} | "
                         + " ".join(chosen) + " |")
    margin = ["", "| sampler | variant | log B (jump vs best smooth): min | median | max |", "|---|---|---|---|---|"]
    for sampler in SAMPLERS:
        for variant in VARIANTS:
            b = []
            for seed in seeds:
                rows = {r["kernel"]: r["log_evidence"][-1] for r in runs
                        if (r["seed"], r["variant"], r["sampler"]) == (seed, variant, sampler)}
                b.append(max(rows[k] for k in JUMP_KERNELS) - max(rows["decay"], rows["drift"]))
            margin.append(f"| {sampler} | {variant} | {min(b):.2f} | {np.median(b):.2f} | {max(b):.2f} |")
    lines += margin
    if refs:
        lines += ["", "| sampler | variant | kernel | max abs mean error [exact sd] | max abs log Z error [nats] | "
                  "max abs P(jump) error | path-space steps |", "|---|---|---|---|---|---|---|"]
        for sampler in SAMPLERS:
            for variant in VARIANTS:
                for kernel in ("decay", "jump"):
                    err_m, err_z, err_p, paths = 0.0, 0.0, 0.0, 0
                    for seed in seeds:
                        run = next(r for r in runs if (r["seed"], r["variant"], r["kernel"], r["sampler"])
                                   == (seed, variant, kernel, sampler))
                        ref = next(r for r in refs if (r["seed"], r["variant"], r["kernel"]) == (seed, variant, kernel))
                        err_m = max(err_m, np.max(np.abs((np.array(run["mean"]) - ref["mean"]) / np.array(ref["std"]))))
                        err_z = max(err_z, np.max(np.abs(np.array(run["log_evidence"]) - ref["log_evidence"])))
                        if kernel == "jump":
                            err_p = max(err_p, np.nanmax(np.abs(np.array(run["jump_probability"])
                                                                - ref["jump_probability"])))
                        paths += sum(1 for p in run["path_steps"] if p)
                    cell = f"{err_p:.4f}" if kernel == "jump" else "-"
                    lines.append(f"| {sampler} | {variant} | {kernel} | {err_m:.2f} | {err_z:.2f} | {cell} | {paths} |")
        exact = []
        for variant in VARIANTS:
            n_jump = sum(next(r for r in refs if (r["seed"], r["variant"], r["kernel"]) == (s, variant, "jump"))
                         ["log_evidence"][-1] > next(r for r in refs if (r["seed"], r["variant"], r["kernel"])
                                                     == (s, variant, "decay"))["log_evidence"][-1] for s in seeds)
            exact.append(f"{variant}: jump over decay in {n_jump} of {len(seeds)}")
        lines += ["", "Exact evidence: " + "; ".join(exact)]
    return "\n".join(lines), verdict


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--samples", type=int, default=1000)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--exact", action="store_true", help="also the exact grid references (decay, jump)")
    parser.add_argument("--out", help="write every run's numbers as JSON here")
    parser.add_argument("--runs-json", help="read the sampler runs from this --out file instead of running them")
    parser.add_argument("--refs-json", help="read the exact references from this --out file")
    parser.add_argument("--refs-only", action="store_true", help="compute the exact references alone (with --out)")
    args = parser.parse_args()
    seeds = list(range(args.seeds))
    tasks = [(s, v, k, smp, args.samples) for s in seeds for v in VARIANTS for k in KERNELS for smp in SAMPLERS]
    ref_tasks = [(s, v, k) for s in seeds for v in VARIANTS for k in ("decay", "jump")]
    start = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as pool:
        if args.runs_json:
            with open(args.runs_json) as fh:
                runs = json.load(fh)["runs"]
        else:
            runs = [] if args.refs_only else list(pool.map(run_task, tasks, chunksize=1))
        if args.refs_json:
            with open(args.refs_json) as fh:
                refs = json.load(fh)["refs"]
        else:
            refs = list(pool.map(reference_task, ref_tasks, chunksize=1)) if args.exact or args.refs_only else []
    if args.out:
        with open(args.out, "w") as fh:
            json.dump({"runs": runs, "refs": refs}, fh)
    if args.refs_only:
        print(f"{len(refs)} references in {time.perf_counter() - start:.0f} s")
        return
    table, verdict = summarise(runs, refs, seeds)
    print(table)
    n = len(seeds)
    need = int(np.ceil(0.9 * n))
    for sampler in SAMPLERS:
        j_drop, p_drop, p_else = verdict[(sampler, "drop")]
        j_smooth, _, p_smooth = verdict[(sampler, "smooth")]
        ok = j_drop >= need and p_drop > 0.9 and p_else < 0.1 and n - j_smooth >= need
        print(f"{sampler}: drop -> jump kernel {j_drop}/{n}, P(jump) at the drop step >= {p_drop:.3f}, "
              f"elsewhere <= {p_else:.3f}; smooth -> smooth kernel {n - j_smooth}/{n} "
              f"(P(jump) <= {p_smooth:.3f}): {'met' if ok else 'NOT met'}")
    print(f"sampler time {sum(r['wall_time'] for r in runs):.0f} s in {len(runs)} runs"
          + ("" if args.runs_json else f"; total wall {time.perf_counter() - start:.0f} s with {args.workers} workers"))


if __name__ == "__main__":
    main()
