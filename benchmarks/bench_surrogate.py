"""Where does the sparse-grid surrogate pay? (issue 12 item 3; quoted in
docs/benchmarks.md, section surrogate, and docs/shake_table.md).

A. Linear shear building, 2-20 storeys: the exact discretisation (batched
   matrix exponential of ``N = 500`` thetas per call) against the sparse grid
   of the lowest level whose ``A, B0, B1`` are within ``--tol`` (relative,
   per block) of the exact ones at 64 random thetas of the box U(0.7, 1).
   Per-row times are medians of ``--pairs`` interleaved pairs (exact, grid)
   in one process; the grid's build time and the break-even number of rows
   (build / saving per row) are given; a level whose grid would exceed
   ``--max-points`` points is not built. For up to 8 storeys the Kalman
   log-likelihood of a 500-step record with the grid's matrices is compared
   with the exact one at 16 thetas near the truth (0.82-0.88). Default
   ``--tol`` 3e-6, the default of ``surrogate="auto"``.
B. Bouc-Wen storeys (yield drift 4 mm, alpha 0.3; the record is scaled so
   the drifts reach 2-3x the yield), 2, 4 and 8 storeys: time of one
   ensemble step of ``100 x 20`` states (the EnKF likelihood's forecast) for
   RK4 (4, 2 and 1 sub-steps), the exponential integrator (1, 2, 4 sub-steps,
   exact matrices) and its sparse-grid form; accuracy = largest relative
   error of the channels over 300 steps at 8 thetas against RK4 with 32
   sub-steps. Times are medians of interleaved rounds.

Each case also shows what ``surrogate="auto"``
(:func:`seqbayes.structural.surrogate.choose_transition`) picks on this machine.

Run: ``OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_surrogate.py
[--storeys 2,3,4,6,8,12,16,20] [--bw-storeys 2,4,8] [--pairs 7] [--json out.json]``
"""

from __future__ import annotations

import argparse
import json
import os
import time

import numpy as np

from seqbayes.structural import sparsegrid
from seqbayes.structural.filters.kalman import kalman_log_likelihood
from seqbayes.structural.transitions import ExactTransition, SparseGridTransition
from seqbayes.structural.structures import ShearBuilding, discretise, simulate
from seqbayes.structural.structures.bouc_wen import BoucWenBuilding, BoucWenExponential, BoucWenRK4, simulate_bouc_wen
from seqbayes.structural.surrogate import Measurement, choose_transition

DT = 0.02


def building(n: int) -> ShearBuilding:
    """n storeys, 20 t floors (16 t roof), stiffness 36 -> 16 kN/mm, 2 % / 4 % Rayleigh;
    scaled so the highest mode stays below Nyquist at 50 Hz."""
    masses = np.full(n, 2.0e4)
    masses[-1] = 1.6e4
    stiff = np.linspace(3.6e7, 1.6e7, n)
    b = ShearBuilding(masses, stiff, (0.02, 0.04))
    f_max = float(b.modes(np.ones(n))[0].max())
    if f_max > 0.4 / DT:
        b = ShearBuilding(masses, stiff * (0.4 / DT / f_max) ** 2, (0.02, 0.04))
    return b


def timed(function):
    start = time.perf_counter()
    function()
    return time.perf_counter() - start


def block_error(approx, exact, m):
    out = 0.0
    for sl in (slice(0, m * m), slice(m * m, m * m + m), slice(m * m + m, m * m + 2 * m)):
        out = max(out, float(np.abs(approx[:, sl] - exact[:, sl]).max() / np.abs(exact[:, sl]).max()))
    return out


def linear_case(n, tol, pairs, max_points, rng):
    b = building(n)
    m = b.state_dim
    batch = 0.7 + 0.3 * rng.random((500, n))
    test = 0.7 + 0.3 * rng.random((64, n))
    ref = discretise(b, test, DT)
    ref_flat = np.concatenate([ref.A.reshape(64, -1), ref.B0, ref.B1], axis=1)
    errors, grid, build, level = {}, None, None, None
    for lv in range(1, 8):
        points = sparsegrid.point_count(n, lv)
        if points > max_points:
            errors[lv] = f"{points} pts: not built"
            break
        start = time.perf_counter()
        g = SparseGridTransition(b, DT, np.full(n, 0.7), np.full(n, 1.0), lv)
        elapsed = time.perf_counter() - start
        errors[lv] = block_error(g.interpolant(test), ref_flat, m)
        if errors[lv] <= tol:
            grid, build, level = g, elapsed, lv
            break
    exact = ExactTransition(b, DT)
    t_exact, t_grid = [], []
    for _ in range(pairs):  # interleaved pairs
        t_exact.append(timed(lambda: exact(batch)))
        if grid is not None:
            t_grid.append(timed(lambda: grid(batch)))
    row = {"storeys": n, "level": level, "points": None if grid is None else grid.n_points,
           "errors": {k: (v if isinstance(v, str) else float(v)) for k, v in errors.items()},
           "exact_us_per_row": float(np.median(t_exact)) / 500 * 1e6}
    if grid is not None:
        row["grid_us_per_row"] = float(np.median(t_grid)) / 500 * 1e6
        row["speedup"] = row["exact_us_per_row"] / row["grid_us_per_row"]
        row["build_s"] = build
        saving = (row["exact_us_per_row"] - row["grid_us_per_row"]) * 1e-6
        row["break_even_rows"] = build / saving if saving > 0 else float("inf")
        if n <= 8:
            u = np.random.default_rng(1).standard_normal(500)
            y = simulate(discretise(b, np.full((1, n), 0.85), DT), u)[0]
            y = y + 0.05 * y.std(axis=0) * np.random.default_rng(2).standard_normal(y.shape)
            std = 0.05 * y.std(axis=0)
            th = 0.82 + 0.06 * rng.random((16, n))  # near the posterior (truth 0.85)
            ll_exact = kalman_log_likelihood(discretise(b, th, DT), u, y, std, 0.05)
            ll_grid = kalman_log_likelihood(grid(th), u, y, std, 0.05)
            row["max_abs_dloglik"] = float(np.abs(ll_grid - ll_exact).max())
    choice = choose_transition(b, DT, 0.7, 1.0, 500, measurement=Measurement(tol=tol, max_points=max_points))
    row["auto"] = choice.kind if choice.level is None else f"{choice.kind} {choice.level}"
    row["auto_reason"] = choice.reason
    return row


def bouc_wen_case(n, pairs, rng):
    b = building(n)
    bw = BoucWenBuilding.from_yield_drift(b, 0.004, alpha=0.3)
    u = np.random.default_rng(3).standard_normal(300)
    theta = 0.7 + 0.3 * rng.random((8, n))
    # scale the record so the largest drift at theta = 0.85 is ~2.5x the yield drift
    _, X = simulate_bouc_wen(BoucWenRK4(bw, DT, 8), np.full(n, 0.85), u, return_states=True)
    peak = np.abs(np.diff(X[0, :, :n], axis=-1, prepend=0.0)).max()
    u = u * 2.5 * 0.004 / peak  # (approximate: the response is not linear in the input)
    _, X = simulate_bouc_wen(BoucWenRK4(bw, DT, 8), np.full(n, 0.85), u, return_states=True)
    ductility = float(np.abs(np.diff(X[0, :, :n], axis=-1, prepend=0.0)).max() / 0.004)
    reference = simulate_bouc_wen(BoucWenRK4(bw, DT, 32), theta, u)
    scale = np.abs(reference).max()
    candidates = {"rk4 x4": BoucWenRK4(bw, DT, 4), "rk4 x2": BoucWenRK4(bw, DT, 2), "rk4 x1": BoucWenRK4(bw, DT, 1)}
    for s in (1, 2, 4):
        candidates[f"exp x{s}"] = BoucWenExponential(bw, DT, substeps=s)
    builds = {}
    for s in (2, 4):
        for lv in range(1, 6):
            if sparsegrid.point_count(n, lv) > 20000:
                break
            start = time.perf_counter()
            g = BoucWenExponential(bw, DT, lv, 0.7, 1.0, substeps=s)
            elapsed = time.perf_counter() - start
            exact = bw.exponential_matrices(theta, DT / s)
            if np.abs(g.matrices(theta) - exact).max() / np.abs(exact).max() <= 1e-4:
                candidates[f"exp x{s} grid {lv}"] = g
                builds[f"exp x{s} grid {lv}"] = elapsed
                break
    batch = 0.7 + 0.3 * rng.random((100, n))
    ensemble = 1e-3 * rng.standard_normal((100, 20, 3 * n))
    models = {k: t(batch) for k, t in candidates.items()}
    times = {k: [] for k in candidates}
    for _ in range(pairs):  # interleaved rounds
        for k, model in models.items():
            times[k].append(timed(lambda: model.propagate(ensemble, 0.1, 0.2)))
    matrices = {k: float(np.median([timed(lambda: t(batch)) for _ in range(3)])) for k, t in candidates.items()}
    rows = []
    for k, t in candidates.items():
        err = float(np.abs(simulate_bouc_wen(t, theta, u) - reference).max() / scale)
        rows.append({"storeys": n, "transition": k, "ms_per_step": float(np.median(times[k])) * 1e3,
                     "matrices_ms": matrices[k] * 1e3, "build_s": builds.get(k, 0.0), "error": err,
                     "ductility": ductility})
    choice = choose_transition(bw, DT, 0.7, 1.0, 100, probe=u, enkf_members=20)
    return rows, {"storeys": n, "auto": choice.integrator + ("" if choice.level is None else f" grid {choice.level}"),
                  "reason": choice.reason}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--storeys", default="2,3,4,6,8,12,16,20")
    parser.add_argument("--bw-storeys", default="2,4,8")
    parser.add_argument("--tol", type=float, default=3e-6)
    parser.add_argument("--pairs", type=int, default=7)
    parser.add_argument("--max-points", type=int, default=20000)
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    out = {"load_before": os.getloadavg()}
    print(f"load average (1, 5, 15 min): {os.getloadavg()}")
    linear = []
    print(f"\nA. linear: exact vs the lowest grid level within {args.tol:g} (500 rows per call)\n")
    print("| storeys | level (points) | grid errors by level | exact us/row | grid us/row | speed-up | build s "
          "| break-even rows | max dloglik | auto |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for n in [int(s) for s in args.storeys.split(",") if s]:
        r = linear_case(n, args.tol, args.pairs, args.max_points, rng)
        linear.append(r)
        errs = ", ".join(f"{k}: {v if isinstance(v, str) else f'{v:.1e}'}" for k, v in r["errors"].items())
        if r["level"] is None:
            print(f"| {n} | none | {errs} | {r['exact_us_per_row']:.1f} | - | - | - | - | - | {r['auto']} |",
                  flush=True)
        else:
            dll = f"{r['max_abs_dloglik']:.1e}" if "max_abs_dloglik" in r else "-"
            print(f"| {n} | {r['level']} ({r['points']}) | {errs} | {r['exact_us_per_row']:.1f} | "
                  f"{r['grid_us_per_row']:.1f} | {r['speedup']:.2f}x | {r['build_s']:.2f} | "
                  f"{r['break_even_rows']:.0f} | {dll} | {r['auto']} |", flush=True)
    out["linear"] = linear
    print(f"\nB. Bouc-Wen: one ensemble step of 100 x 20 states; error vs RK4 x32 over 300 steps, 8 thetas\n")
    print("| storeys | transition | ms/step | matrices ms/call | build s | rel. error | peak drift / yield |")
    print("|---|---|---|---|---|---|---|")
    bw_rows, autos = [], []
    for n in [int(s) for s in args.bw_storeys.split(",") if s]:
        rows, auto = bouc_wen_case(n, args.pairs, rng)
        bw_rows += rows
        autos.append(auto)
        for r in rows:
            print(f"| {n} | {r['transition']} | {r['ms_per_step']:.2f} | {r['matrices_ms']:.2f} | "
                  f"{r['build_s']:.2f} | {r['error']:.1e} | {r['ductility']:.1f} |", flush=True)
    out["bouc_wen"], out["bouc_wen_auto"] = bw_rows, autos
    print()
    for a in autos:
        print(f"auto, {a['storeys']} storeys: {a['auto']} -- {a['reason']}")
    for r in linear:
        print(f"auto, linear {r['storeys']} storeys: {r['auto_reason']}")
    out["load_after"] = os.getloadavg()
    print(f"\nload average after: {os.getloadavg()}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(out, fh, indent=1, default=str)


if __name__ == "__main__":
    main()
