"""On-line stiffness-drop detection and storey attribution (issue 12, acceptance
bullet 3; quoted in docs/shake_table.md, section "Stiffness drop during the shaking").

The 4-storey building of case b4 in bench_sgenmcmc.py (masses 24/20/20/16 t,
stiffness 36/30/24/16 kN/mm, Rayleigh 2 % / 4 %, truth 0.91/0.85/0.78/0.94), a new
20 s Kanai-Tajimi record per seed (2.5 Hz, 0.07 g, 50 Hz), unmeasured input
noise 5 % of the input RMS, 3 % measurement noise on the four floor
accelerations. With a drop: storey 2 loses ``--fraction`` (20 %) of its
stiffness from step 502 (10.04 s, half-way, and deliberately not on the
monitor's 0.1 s change grid). Without: the same record and noise draws with no
drop (false alarms). :class:`seqbayes.structural.stiffness_drop.StiffnessDropMonitor` at
default settings is fed blocks of ``--block`` steps (25 = 0.5 s).

Reported per seed: the detection time (end of the first block with P(change) >
0.99) and its delay after the drop, the storey of the most probable class
there and the log Bayes factor of storey 2's class against the best other
one, P(M_2) 2 s after the drop, the posterior mean drop fraction and change
time at the end, and for the record without a drop the largest P(change) over
all blocks (a false alarm if above 0.99); wall and CPU seconds.

``--evidence``: instead, the per-block log-evidence of both classes of a
one-storey building (5 Hz, 4 s Kanai-Tajimi record, 30 % noise, a 30 % drop at
step 100, change boundaries every 25 steps with h = 0.1, blocks of 25 steps,
200 particles) against the exact evidence
(:func:`seqbayes.structural.drop_paths.grid_log_evidence`) over ``--seeds`` sampler
seeds: the Monte Carlo errors behind the tolerances of
tests/statistical/test_stiffness_drop.py.

Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_drop.py [--seeds 10] [--json out.json]
[--figure docs/figures/shake_table_drop.png]`` (the figure: seed 0, with and without the drop).
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from seqbayes.structural.drop_paths import grid_log_evidence, simulate_drop
from seqbayes.structural.stiffness_drop import StiffnessDropMonitor, monitor_from_flat
from seqbayes.structural.structures import ShearBuilding, add_measurement_noise, kanai_tajimi

DT = 0.02
TRUTH = np.array([0.91, 0.85, 0.78, 0.94])
BUILDING = dict(masses=(24.0, 20.0, 20.0, 16.0), stiffness=(36.0, 30.0, 24.0, 16.0), damping=(0.02, 0.04))


def drop_record(seed: int, fraction: float, storey: int = 2, seconds: float = 20.0, drop_step: int = 502,
                noise: float = 0.03) -> dict:
    """Record of one seed; ``fraction = 0``: the same draws without a drop."""
    building = ShearBuilding(np.array(BUILDING["masses"]) * 1e3, np.array(BUILDING["stiffness"]) * 1e6,
                             damping_ratios=BUILDING["damping"])
    rng = np.random.default_rng([12, seed])
    u = kanai_tajimi(seconds, DT, 0.07, ground_frequency_hz=2.5, rng=rng).acceleration
    sw = 0.05 * float(np.sqrt(np.mean(u**2)))
    y, drifts = simulate_drop(building, DT, TRUTH, storey, fraction, drop_step, u, sw, rng)
    y, std = add_measurement_noise(y, noise, rng)
    return {"building": building, "u": u, "y": y, "noise_std": std, "process_noise_std": sw,
            "drop_time": drop_step * DT, "storey": storey, "fraction": fraction}


def monitor(data: dict, seed: int, block: int, **options) -> dict:
    mon = StiffnessDropMonitor(data["building"], DT, 0.7, 1.0, data["noise_std"], data["process_noise_std"],
                               **monitor_from_flat(**options))
    mon.reset(rng=np.random.default_rng([13, seed]))
    t0, c0 = time.perf_counter(), time.process_time()
    u, y = data["u"], data["y"]
    for start in range(0, u.size, block):  # the record arrives block by block
        mon.update(u[start : start + block], y[start : start + block])
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    history = mon.history
    hit = mon.detection()
    out = {"wall": wall, "cpu": cpu, "max_change_probability": max(b.change_probability for b in history),
           "detected_at": None if hit is None else hit.time}
    if hit is not None:
        log_post = np.log(np.maximum(hit.class_probabilities, 1e-300)) - mon.log_prior_classes
        others = np.delete(hit.log_evidence, [0, data["storey"]])
        out.update(storey=hit.storey, probabilities=hit.class_probabilities.tolist(),
                   log_bayes_factor=float(hit.log_evidence[data["storey"]] - max(others.max(), hit.log_evidence[0])),
                   log_posterior_odds=log_post.tolist())
    later = [b for b in history if b.time >= data["drop_time"] + 2.0]
    if later:
        out["p_storey_2s_after"] = float(later[0].class_probabilities[data["storey"]])
    final = history[-1]
    out["final_drop_mean"] = float(final.drop_mean[data["storey"]])
    out["final_change_time"] = float(final.change_time_mean[data["storey"]])
    out["final_probabilities"] = final.class_probabilities.tolist()
    out["history"] = history
    return out


def figure(path, rows, drop_time):
    """P(change), the class probabilities and storey 2's current ratio, block by block (seed 0)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    for label, style in (("drop", "C3"), ("no_drop", "C0")):
        history = rows[0][label]["history"]
        t = np.array([b.time for b in history])
        axes[0].semilogy(t, np.clip([b.change_probability for b in history], 1e-12, 1), style,
                         label=f"P(change), {label.replace('_', ' ')}")
    history = rows[0]["drop"]["history"]
    t = np.array([b.time for b in history])
    probs = np.array([b.class_probabilities for b in history])
    for c in range(probs.shape[1]):
        axes[1].plot(t, probs[:, c], label="no change" if c == 0 else f"drop in storey {c}")
    theta2 = np.array([b.theta_mean[2, 1] for b in history])
    axes[2].plot(t, theta2, "C1", label="storey-2 class: posterior mean of the current theta_2")
    axes[2].axhline(TRUTH[1], color="k", lw=0.8)
    axes[2].axhline(TRUTH[1] * 0.8, color="k", lw=0.8, ls="--")
    for ax in axes:
        ax.axvline(drop_time, color="0.5", lw=0.8, ls=":")
        ax.legend(fontsize=7, loc="best")
    axes[0].axhline(0.99, color="k", lw=0.6, ls="--")
    axes[0].set_ylabel("P(change | y)")
    axes[1].set_ylabel("P(class | y)")
    axes[2].set_ylabel("theta_2")
    axes[2].set_xlabel("record time [s] (end of each 0.5 s block)")
    fig.suptitle("On-line stiffness-drop detection, 4 storeys, seed 0 (benchmarks/bench_drop.py)")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def bench_evidence(seeds: int, particles: int = 200) -> dict:
    """Per-block log-evidence errors against the exact one (module docstring, --evidence)."""
    building = ShearBuilding([1e4], [1e7], (0.03, 0.03))
    rng = np.random.default_rng(0)
    T = 200
    u = kanai_tajimi((T - 1) * DT, DT, 0.07, ground_frequency_hz=4.0, rng=rng).acceleration
    sw = 0.05 * float(np.sqrt(np.mean(u**2)))
    y, _ = simulate_drop(building, DT, [0.85], 1, 0.3, T // 2, u, sw, rng)
    y, std = add_measurement_noise(y, 0.3, rng)
    ends = np.arange(24, T, 25)
    t0 = time.perf_counter()
    exact = np.column_stack(grid_log_evidence(building, DT, u, y, std, sw, ends, change_every=25, hazard=0.1))
    fine = np.column_stack(grid_log_evidence(building, DT, u, y, std, sw, ends, change_every=25, hazard=0.1,
                                             grid=(301, 201)))
    print(f"exact evidence: {time.perf_counter() - t0:.1f} s (both grids); grid error (vs twice as fine) "
          f"{np.abs(exact - fine).max():.1e}; exact log Z (no change / drop) at the block ends:\n"
          f"{np.round(fine.T, 2).tolist()}", flush=True)
    errors = []
    for seed in range(seeds):
        mon = StiffnessDropMonitor(building, DT, 0.7, 1.0, std, sw, n_particles=particles,
                                   **monitor_from_flat(change_every=25, change_rate=0.2, prune_below=0))
        mon.reset(rng=seed)
        for start in range(0, T, 25):
            mon.update(u[start : start + 25], y[start : start + 25])
        errors.append(np.array([b.log_evidence for b in mon.history]) - fine)
    errors = np.array(errors)  # (seeds, blocks, 2)
    before = ends < T // 2
    for c, label in enumerate(("no change (M_0)", "drop (M_1)")):
        e = errors[:, :, c]
        print(f"{label}: error per block, mean {np.round(e.mean(axis=0), 2).tolist()}, sd "
              f"{np.round(e.std(axis=0), 2).tolist()}; before the drop max |error| {np.abs(e[:, before]).max():.2f}, "
              f"after {np.abs(e[:, ~before]).max():.2f}")
    return {"exact": fine.tolist(), "errors": errors.tolist(), "ends": ends.tolist()}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=0, help="seeds first-seed .. first-seed + seeds - 1")
    parser.add_argument("--fraction", type=float, default=0.2)
    parser.add_argument("--block", type=int, default=25, help="steps per update (25 = 0.5 s)")
    parser.add_argument("--json", default=None)
    parser.add_argument("--figure", default=None, help="write the seed-0 figure here")
    parser.add_argument("--evidence", action="store_true", help="the exact-evidence check instead")
    args = parser.parse_args(argv)
    if args.evidence:
        out = bench_evidence(args.seeds)
        if args.json:
            with open(args.json, "w") as f:
                json.dump(out, f, indent=1)
        return
    print(f"load average (1, 5, 15 min): {os.getloadavg()}", flush=True)
    rows = []
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        drop = drop_record(seed, args.fraction)
        calm = drop_record(seed, 0.0)
        row = {"seed": seed, "drop": monitor(drop, seed, args.block), "no_drop": monitor(calm, seed, args.block)}
        rows.append(row)
        d, c = row["drop"], row["no_drop"]
        delay = None if d["detected_at"] is None else d["detected_at"] - drop["drop_time"]
        print(f"seed {seed}: detected at {d['detected_at']} s (delay {delay if delay is None else round(delay, 2)} s), "
              f"storey {d.get('storey')}, log BF {d.get('log_bayes_factor', float('nan')):.1f}, "
              f"P(M_2) 2 s after {d.get('p_storey_2s_after', float('nan')):.4f}, drop {d['final_drop_mean']:.3f} "
              f"at {d['final_change_time']:.2f} s; {d['wall']:.1f} s wall / {d['cpu']:.1f} s CPU | no drop: max "
              f"P(change) {c['max_change_probability']:.2e}, detected {c['detected_at']}; {c['wall']:.1f} s wall",
              flush=True)
    delays = [r["drop"]["detected_at"] - drop["drop_time"] for r in rows if r["drop"]["detected_at"] is not None]
    within = sum(1 for dl in delays if dl <= 2.0)
    attributed = sum(1 for r in rows if r["drop"].get("storey") == 2)
    false_alarms = sum(1 for r in rows if r["no_drop"]["detected_at"] is not None)
    print(f"detected within 2 s: {within}/{len(rows)} (delays {np.round(delays, 2).tolist()} s); attributed to "
          f"storey 2: {attributed}/{len(rows)}; false alarms on records without a drop: {false_alarms}/{len(rows)} "
          f"(max P(change) {max(r['no_drop']['max_change_probability'] for r in rows):.2e}); median wall "
          f"{np.median([r['drop']['wall'] for r in rows]):.1f} s (drop) / "
          f"{np.median([r['no_drop']['wall'] for r in rows]):.1f} s (no drop); load average {os.getloadavg()}")
    if args.figure:
        figure(args.figure, rows, drop_record(0, args.fraction)["drop_time"])
    if args.json:
        for r in rows:
            for label in ("drop", "no_drop"):
                r[label].pop("history")
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
