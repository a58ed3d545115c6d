"""High dimension on a structure: a 20-storey shear building's 20 stiffness ratios (issue 14, item 2).

    python benchmarks/bench_shear20.py [all | reference | run | cost] [--floors all | 4,8,12,16,20]
        [--reference PATH] [--walkers 100] [--steps 4000] [--burn 500] [--is-draws 200000]  (reference)
        [--samplers SMC SEMC] [--n 2000] [--seeds 0 1 2] [--economy] [--jsonl runs.jsonl]  (run)
    python benchmarks/bench_shear20.py table runs.jsonl

The problem (:class:`Shear20`): a linear 20-storey shear building (20 t floors, 16 t roof, storey
stiffness 36 -> 16 kN/mm bottom to top, Rayleigh damping 2 % / 4 % on modes 1 and 2; modes
0.47-12.7 Hz), storey stiffness ``k_i = theta_i k_i^u``. Prior: ``theta_i`` independent
lognormal with median 1 and log-sd 0.2. Truth: 0.95 everywhere, storey 3 at 0.75 and storey 11 at
0.85. One dataset: 3 s (150 samples at 50 Hz) of 0.5-22.5 Hz white-noise ground acceleration and
the absolute accelerations of every floor (``--floors``: a subset), each with Gaussian noise of
5 % of its RMS. The likelihood is the exact Kalman log-likelihood
(:func:`seqbayes.structural.filters.kalman.kalman_log_likelihood`) of the exact first-order-hold
discretisation, from rest with no process noise (so it is the output-error likelihood: the
filter's gain is zero). Rows whose highest mode is at or above Nyquist (25 Hz: only if some
``theta_i`` is several times its prior median, prior mass below 1e-10) get ``-inf``.

``reference`` computes the reference once and saves it (``.npz``):

(b) the log-evidence, posterior means and sds by importance sampling in ``log theta`` with a
    multivariate-t proposal (5 degrees of freedom, 1.2 times the scale of the Laplace
    approximation at the mode found by L-BFGS), ``--is-draws`` draws; standard errors by the
    delta method, the ESS, and the two halves of the sample as a check;
(a) emcee (``vectorize=True``, stretch move) started from an equal-weight resample of (b),
    ``--burn`` steps dropped; the Monte Carlo error of each mean is ``sd * sqrt(tau / (walkers *
    kept steps))`` with ``tau`` from ``emcee.autocorr.integrated_time``; its means and sds are
    compared with (b)'s.

``run`` runs SMC and SEMC (``from seqbayes import SMC, SEMC``, a static kernel, the defaults:
above d = 10 the scaled moves; ``--economy`` for ``economy=True``) and prints, per run, the
log-evidence error against (b), the largest |mean error| in reference posterior sds, the smallest
and largest ratio of the sampler's posterior sd to the reference's, the likelihood calls and the
wall time; ``--jsonl`` appends each run. ``table`` summarises a JSONL file per (sampler, N,
economy); ``cost`` times one batched likelihood evaluation. ``all`` (the default, e.g. under
``make bench``) builds the reference if the file is missing, then runs and tabulates.
Run with ``OPENBLAS_NUM_THREADS=1`` (set here if unset).
"""

from __future__ import annotations

import argparse
import json
import os
import tempfile
import time
import warnings

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from scipy import optimize, special, stats  # noqa: E402

from seqbayes.engine.settings import from_flat
import seqbayes  # noqa: E402
from seqbayes.structural.filters.kalman import kalman_log_likelihood  # noqa: E402
from seqbayes.structural.structures import Sensors, ShearBuilding, add_measurement_noise, discretise, simulate  # noqa: E402
from seqbayes.structural.structures.ground_motion import band_limited_white_noise  # noqa: E402

N_STOREYS = 20
DT = 0.02
N_SAMPLES = 150  # 3 s record
ALL_FLOORS = tuple(range(1, N_STOREYS + 1))
NOISE_FRACTION = 0.05
PRIOR_LOG_SD = 0.2
DEFAULT_REFERENCE = os.path.join(tempfile.gettempdir(), "seqbayes_shear20_reference.npz")


class Shear20:
    """The problem: building, record, prior and the vectorised log-likelihood.

    Attributes
    ----------
    building : ShearBuilding
    truth : (20,) array
        The stiffness ratios that generated the data.
    data : dict
        ``{"u": (T,) ground acceleration [m/s^2], "y": (T, p) measured accelerations [m/s^2]}``.
    noise_std : (p,) array
        Measurement noise standard deviations [m/s^2].
    """

    def __init__(self, floors=ALL_FLOORS, seed: int = 0):
        self.sensors = Sensors(accelerations=tuple(floors))
        masses = np.full(N_STOREYS, 2.0e4)
        masses[-1] = 1.6e4
        self.building = ShearBuilding(masses, np.linspace(3.6e7, 1.6e7, N_STOREYS), (0.02, 0.04))
        truth = np.full(N_STOREYS, 0.95)
        truth[[2, 10]] = [0.75, 0.85]
        self.truth = truth
        rng = np.random.default_rng([14, 20, seed])
        u = band_limited_white_noise((N_SAMPLES - 1) * DT, DT, rms_g=0.02, rng=rng).acceleration
        clean = simulate(discretise(self.building, truth, DT, channels=self.sensors), u)[0]
        y, self.noise_std = add_measurement_noise(clean, NOISE_FRACTION, rng)
        self.data = {"u": u, "y": y}
        self.nyquist = 0.5 / DT
        self.dim = N_STOREYS

    def prior(self) -> seqbayes.JointPrior:
        """Independent lognormal ``theta_i`` (median 1, log-sd 0.2)."""
        return seqbayes.JointPrior([stats.lognorm(PRIOR_LOG_SD)] * N_STOREYS,
                                   names=[f"theta_{i + 1}" for i in range(N_STOREYS)])

    def loglike(self, theta, data):
        """``log p(y | theta)`` for ``theta (N, 20)``; returns ``(N,)`` (``-inf`` where undefined)."""
        theta = np.atleast_2d(np.asarray(theta, dtype=float))
        out = np.full(theta.shape[0], -np.inf)
        ok = np.all(np.isfinite(theta) & (theta > 0), axis=1)
        if ok.any():
            idx = np.flatnonzero(ok)
            f_max = self.building.modes(theta[idx])[0][:, -1]
            idx = idx[f_max < self.nyquist]
        else:
            idx = np.zeros(0, dtype=int)
        if idx.size:
            model = discretise(self.building, theta[idx], DT, channels=self.sensors)
            out[idx] = kalman_log_likelihood(model, data["u"], data["y"], self.noise_std, 0.0)
        return out

    def log_posterior(self, theta):
        """Unnormalised ``log p(theta | y)``, ``(N, 20) -> (N,)``."""
        theta = np.atleast_2d(theta)
        if not hasattr(self, "_prior"):
            self._prior = self.prior()
        lp = self._prior.logpdf(np.where(theta > 0, theta, 1.0))
        lp = np.where(np.all(theta > 0, axis=1), lp, -np.inf)
        out = np.full(theta.shape[0], -np.inf)
        ok = np.isfinite(lp)
        if ok.any():
            out[ok] = lp[ok] + self.loglike(theta[ok], self.data)
        return out


# ----------------------------------------------------------------------------------- reference
def laplace_start(problem: Shear20):
    """Posterior mode by L-BFGS in ``log theta`` (batched central-difference gradient) from the
    prior median, and the inverse of a finite-difference Hessian there, in ``log theta``."""
    d = problem.dim
    h = 1e-4

    def f_and_grad(z):
        pts = np.exp(np.vstack([z, z + h * np.eye(d), z - h * np.eye(d)]))
        lp = problem.log_posterior(pts) + np.vstack([z, z + h * np.eye(d), z - h * np.eye(d)]).sum(1)
        return -lp[0], -(lp[1:d + 1] - lp[d + 1:]) / (2 * h)

    res = optimize.minimize(f_and_grad, np.zeros(d), jac=True, method="L-BFGS-B")
    z = res.x
    hh = 1e-3
    eye = np.eye(d) * hh
    plus = z + eye[:, None, :] + eye[None, :, :]  # (d, d, d): z + h e_i + h e_j
    pts = np.concatenate([plus.reshape(-1, d), (z + eye), (z - eye), z[None]], axis=0)
    vals = problem.log_posterior(np.exp(pts)) + pts.sum(1)
    fij = vals[:d * d].reshape(d, d)
    fi, fmi, f0 = vals[d * d:d * d + d], vals[d * d + d:d * d + 2 * d], vals[-1]
    hess = (fij - fi[:, None] - fi[None, :] + f0) / hh ** 2  # forward differences
    hess_diag = (fi - 2 * f0 + fmi) / hh ** 2
    hess[np.diag_indices(d)] = hess_diag
    hess = 0.5 * (hess + hess.T)
    cov = np.linalg.inv(-hess)
    return z, 0.5 * (cov + cov.T), res


def multivariate_t_logpdf(x, mean, chol, dof):
    d = mean.size
    z = np.linalg.solve(chol, (x - mean).T).T
    q = np.einsum("ij,ij->i", z, z)
    return (special.gammaln(0.5 * (dof + d)) - special.gammaln(0.5 * dof) - 0.5 * d * np.log(dof * np.pi)
            - np.log(np.diag(chol)).sum() - 0.5 * (dof + d) * np.log1p(q / dof))


def _weighted_moments(theta, log_w):
    """Self-normalised importance-sampling mean, sd and the delta-method se of the mean."""
    w = np.exp(log_w - log_w.max())
    wn = w / w.sum()
    mean = wn @ theta
    sd = np.sqrt(wn @ (theta - mean) ** 2)
    mean_se = np.sqrt((wn ** 2) @ (theta - mean) ** 2)
    return mean, sd, mean_se


def build_reference(problem: Shear20, path: str, walkers: int, steps: int, burn: int, is_draws: int, seed: int):
    """(b) then (a): importance sampling from a multivariate t(5) fitted to the Laplace
    approximation in ``log theta`` (scale 1.2x), which gives the reference log-evidence, means and
    sds with their own standard errors; then emcee started from the importance sample as an
    independent check of the means and sds (integrated autocorrelation times)."""
    import emcee

    t0 = time.perf_counter()
    rng = np.random.default_rng([14, 20, 1000 + seed])
    z_mode, cov_log, opt = laplace_start(problem)
    print(f"mode found ({opt.nfev} gradient evaluations, success {opt.success}): theta = "
          f"{np.round(np.exp(z_mode), 3).tolist()}; Laplace sds (log theta) "
          f"{np.round(np.sqrt(np.diag(cov_log)), 4).tolist()}; {time.perf_counter() - t0:.0f} s", flush=True)

    # (b) importance sampling in z = log theta: w = p(y | theta) p(theta) theta_1...theta_d / q(z)
    dof, inflation = 5.0, 1.2
    chol = np.linalg.cholesky(cov_log * inflation ** 2 * (dof - 2) / dof)  # the t's covariance = 1.44 x Laplace
    log_w = np.empty(is_draws)
    theta_all = np.empty((is_draws, problem.dim))
    t1 = time.perf_counter()
    batch = 2000
    for start in range(0, is_draws, batch):
        n = min(batch, is_draws - start)
        z = z_mode + (rng.standard_normal((n, problem.dim)) @ chol.T) * np.sqrt(dof / rng.chisquare(dof, n))[:, None]
        theta_all[start:start + n] = np.exp(z)
        log_w[start:start + n] = (problem.log_posterior(np.exp(z)) + z.sum(axis=1)
                                  - multivariate_t_logpdf(z, z_mode, chol, dof))
    shift = log_w.max()
    w = np.exp(log_w - shift)
    log_z = float(shift + np.log(w.mean()))
    log_z_se = float(w.std(ddof=1) / np.sqrt(is_draws) / w.mean())  # delta method
    ess = float(w.sum() ** 2 / (w ** 2).sum())
    mean, sd, mean_se = _weighted_moments(theta_all, log_w)
    parts = (slice(0, is_draws // 2), slice(is_draws // 2, None))
    halves = [_weighted_moments(theta_all[h], log_w[h]) for h in parts]
    print(f"importance sampling: {is_draws} t(5) draws in log theta, log Z = {log_z:.4f} +- {log_z_se:.4f}, "
          f"ESS {ess:.0f} ({100 * ess / is_draws:.1f} %), largest normalised weight {w.max() / w.sum():.2e}, "
          f"largest mean se {(mean_se / sd).max():.4f} sd; halves: log Z "
          f"{[round(float(shift + np.log(w[h].mean())), 4) for h in parts]}"
          f", sd ratio {(halves[0][1] / halves[1][1]).min():.4f}-{(halves[0][1] / halves[1][1]).max():.4f}; "
          f"{time.perf_counter() - t1:.0f} s", flush=True)

    # (a) emcee from an equal-weight resample of the importance sample
    start_idx = rng.choice(is_draws, size=walkers, replace=False, p=w / w.sum()) if ess > 2 * walkers else None
    if start_idx is None:
        raise SystemExit(f"importance sampling ESS {ess:.0f} too small to start {walkers} walkers")
    sampler = emcee.EnsembleSampler(walkers, problem.dim, problem.log_posterior, vectorize=True,
                                    moves=emcee.moves.StretchMove())
    sampler.random_state = np.random.RandomState(seed).get_state()  # emcee's own RNG, seeded
    t2 = time.perf_counter()
    sampler.run_mcmc(theta_all[start_idx], steps, progress=False)
    chain = sampler.get_chain(discard=burn)  # (kept, walkers, d)
    tau = emcee.autocorr.integrated_time(chain, quiet=True)
    kept = chain.shape[0]
    flat = chain.reshape(-1, problem.dim)
    mc_mean, mc_sd = flat.mean(0), flat.std(0, ddof=1)
    mc_mean_se = mc_sd * np.sqrt(tau / (walkers * kept))
    gap = (mc_mean - mean) / np.hypot(mc_mean_se, mean_se)
    print(f"emcee: {walkers} walkers x {steps} steps ({burn} burn), acceptance "
          f"{sampler.acceptance_fraction.mean():.3f}, tau {tau.min():.0f}-{tau.max():.0f} steps "
          f"(kept / tau >= {kept / tau.max():.1f}), {time.perf_counter() - t2:.0f} s", flush=True)
    print(f"emcee vs importance sampling: largest |mean difference| {(np.abs(mc_mean - mean) / sd).max():.3f} sd "
          f"= {np.abs(gap).max():.2f} combined se (rms {np.sqrt(np.mean(gap ** 2)):.2f}); sd ratios "
          f"{(mc_sd / sd).min():.3f}-{(mc_sd / sd).max():.3f}", flush=True)
    np.savez(path, mean=mean, sd=sd, mean_se=mean_se, log_z=log_z, log_z_se=log_z_se, ess=ess, is_draws=is_draws,
             mc_mean=mc_mean, mc_sd=mc_sd, mc_mean_se=mc_mean_se, tau=tau, walkers=walkers, steps=steps, burn=burn,
             acceptance=sampler.acceptance_fraction.mean(), mode=np.exp(z_mode), truth=problem.truth,
             floors=np.array(problem.sensors.accelerations), elapsed=time.perf_counter() - t0)
    print(f"saved {path} ({time.perf_counter() - t0:.0f} s)")


def load_reference(path: str) -> dict:
    if not os.path.exists(path):
        raise SystemExit(f"no reference at {path}: run `bench_shear20.py reference --reference {path}` first")
    return {k: v for k, v in np.load(path).items()}


# ----------------------------------------------------------------------------------- samplers
def one_run(name: str, problem: Shear20, ref: dict, n: int, seed: int, economy: bool) -> dict:
    kernel = seqbayes.MarkovKernel([seqbayes.Static()] * problem.dim)
    cls = getattr(seqbayes, name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sampler = cls(problem.prior(), kernel, problem.loglike, n_samples=n, rng=np.random.default_rng([7, seed]), **from_flat(cls.__name__, economy=economy))
        start = time.perf_counter()
        info = sampler.update(problem.data)
        elapsed = time.perf_counter() - start
    record = sampler.result.steps[0]
    mean_err = (record.mean() - ref["mean"]) / ref["sd"]
    sd_ratio = record.std() / ref["sd"]
    return {"sampler": name, "n": n, "seed": seed, "economy": economy,
            "log_z": float(info.log_evidence), "log_z_error": float(info.log_evidence - ref["log_z"]),
            "reported_se": float(info.log_evidence_se), "max_mean_error_sd": float(np.abs(mean_err).max()),
            "rms_mean_error_sd": float(np.sqrt(np.mean(mean_err ** 2))),
            "sd_ratio_min": float(sd_ratio.min()), "sd_ratio_max": float(sd_ratio.max()),
            "sd_ratio_mean": float(sd_ratio.mean()), "calls": int(info.n_loglike_evals), "time_s": elapsed,
            "stages": int(info.n_stages),
            "load": os.getloadavg()[0]}


def print_row(r: dict) -> None:
    print(f"{r['sampler']} N={r['n']} economy={r['economy']} seed={r['seed']}: log Z error {r['log_z_error']:+.3f} "
          f"(se {r['reported_se']:.3f}), max |mean error| {r['max_mean_error_sd']:.3f} sd "
          f"(rms {r['rms_mean_error_sd']:.3f}), sd ratio {r['sd_ratio_min']:.2f}-{r['sd_ratio_max']:.2f} "
          f"(mean {r['sd_ratio_mean']:.2f}), calls {r['calls']:,}, {r['stages']} stages, {r['time_s']:.0f} s",
          flush=True)


def table(rows: list[dict], dim: int) -> None:
    print("| sampler | N | economy | seeds | mean log Z error | sd | worst abs log Z error | mean reported se "
          "| worst mean error (sd) | sd ratio range | mean calls | calls / d | stages | mean time (s) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    keys = sorted({(r["sampler"], r["n"], r["economy"]) for r in rows}, key=lambda k: (k[2], -k[1], k[0] != "SMC"))
    for key in keys:
        sel = [r for r in rows if (r["sampler"], r["n"], r["economy"]) == key]
        z = np.array([r["log_z_error"] for r in sel])
        calls = np.mean([r["calls"] for r in sel])
        sd = f"{z.std(ddof=1):.3f}" if len(z) > 1 else "-"
        stages = sorted({r["stages"] for r in sel if "stages" in r})
        stages = "-" if not stages else (f"{stages[0]}" if len(stages) == 1 else f"{stages[0]}-{stages[-1]}")
        print(f"| {key[0]} | {key[1]} | {'yes' if key[2] else 'no'} | {len(sel)} | {z.mean():+.3f} | {sd} "
              f"| {np.abs(z).max():.3f} | {np.mean([r['reported_se'] for r in sel]):.3f} "
              f"| {max(r['max_mean_error_sd'] for r in sel):.3f} "
              f"| {min(r['sd_ratio_min'] for r in sel):.2f}-{max(r['sd_ratio_max'] for r in sel):.2f} "
              f"| {calls:,.0f} | {calls / dim:,.0f} | {stages} | {np.mean([r['time_s'] for r in sel]):.0f} |")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("command", nargs="?", default="all", choices=("all", "reference", "run", "table", "cost"),
                        help="all (default): the reference if missing, then run and table")
    parser.add_argument("jsonl_file", nargs="?", help="for table: the JSONL file of runs")
    parser.add_argument("--floors", default="all",
                        help="accelerometer floors, comma-separated (default all 20)")
    parser.add_argument("--reference", help=f"reference file (default {DEFAULT_REFERENCE} with the floors)")
    parser.add_argument("--walkers", type=int, default=100)
    parser.add_argument("--steps", type=int, default=4000)
    parser.add_argument("--burn", type=int, default=500)
    parser.add_argument("--is-draws", type=int, default=200000)
    parser.add_argument("--reference-seed", type=int, default=0)
    parser.add_argument("--samplers", nargs="+", default=["SMC", "SEMC"])
    parser.add_argument("--n", type=int, nargs="+", default=[2000], help="particles (cost: batch sizes)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--economy", action="store_true")
    parser.add_argument("--jsonl", help="append every run to this file")
    args = parser.parse_args()
    floors = ALL_FLOORS if args.floors == "all" else tuple(int(f) for f in args.floors.split(","))
    problem = Shear20(floors)
    if args.reference is None:
        tag = "all" if floors == ALL_FLOORS else "-".join(map(str, floors))
        args.reference = DEFAULT_REFERENCE.replace(".npz", f"_{tag}.npz")
    if args.command == "cost":
        rng = np.random.default_rng(0)
        for n in args.n:
            theta = problem.prior().sample(n, rng)
            problem.loglike(theta[:2], problem.data)
            times = []
            for _ in range(3):
                t0 = time.perf_counter()
                problem.loglike(theta, problem.data)
                times.append(time.perf_counter() - t0)
            print(f"N = {n}: best of 3 {min(times):.3f} s per batched evaluation, "
                  f"{1e3 * min(times) / n:.3f} ms per theta (load {os.getloadavg()[0]:.1f})")
        return
    if args.command == "table":
        if not args.jsonl_file:
            raise SystemExit("table: give the JSONL file of runs")
        with open(args.jsonl_file) as fh:
            table([json.loads(line) for line in fh if line.strip()], problem.dim)
        return
    if args.command == "reference" or (args.command == "all" and not os.path.exists(args.reference)):
        build_reference(problem, args.reference, args.walkers, args.steps, args.burn, args.is_draws,
                        args.reference_seed)
        if args.command == "reference":
            return
    ref = load_reference(args.reference)
    print(f"reference log Z {float(ref['log_z']):.3f} +- {float(ref['log_z_se']):.3f}; load {os.getloadavg()}",
          flush=True)
    rows = []
    for n in args.n:
        for seed in args.seeds:
            for name in args.samplers:
                r = one_run(name, problem, ref, n, seed, args.economy)
                rows.append(r)
                print_row(r)
                if args.jsonl:
                    with open(args.jsonl, "a") as fh:
                        fh.write(json.dumps(r) + "\n")
    table(rows, problem.dim)


if __name__ == "__main__":
    main()
