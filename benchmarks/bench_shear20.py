"""High dimension on a structure: a 20-storey shear building's 20 stiffness ratios (issue 14, item 2).

    python benchmarks/bench_shear20.py [all | reference | run | cost] [--reference PATH]
        [--walkers 100] [--steps 10000] [--burn 2000] [--is-draws 200000]     (reference)
        [--samplers SMC SEMC] [--n 2000] [--seeds 0 1 2] [--economy] [--jsonl runs.jsonl]   (run)
    python benchmarks/bench_shear20.py table runs.jsonl

The problem (:func:`problem`): a linear 20-storey shear building (20 t floors, 16 t roof, storey
stiffness 36 -> 16 kN/mm bottom to top, Rayleigh damping 2 % / 4 % on modes 1 and 2; modes
0.47-12.7 Hz), storey stiffness ``k_i = theta_i k_i^u``. Prior: ``theta_i`` independent
lognormal with median 1 and log-sd 0.2. Truth: 0.95 everywhere, storey 3 at 0.75 and storey 11 at
0.85. One dataset: 3 s (150 samples at 50 Hz) of 0.5-22.5 Hz white-noise ground acceleration,
absolute accelerations of floors 4, 8, 12, 16 and 20, each with Gaussian noise of 5 % of its RMS.
The likelihood is the exact Kalman log-likelihood
(:func:`seqbayes.filters.kalman.kalman_log_likelihood`) of the exact first-order-hold
discretisation, from rest with no process noise (so it is the output-error likelihood; the
filter's gain is zero). Rows whose highest mode is at or above Nyquist (25 Hz: only if some
``theta_i`` is several times its prior median, prior mass below 1e-10) get ``-inf``.

``reference`` computes the reference once and saves it (``.npz``):

(a) posterior means and sds from emcee (``vectorize=True``, stretch move), walkers started from a
    Laplace approximation at the posterior mode (L-BFGS in log theta), ``--burn`` steps dropped;
    the Monte Carlo error of each mean is ``sd * sqrt(tau / (walkers * kept steps))`` with the
    integrated autocorrelation time ``tau`` from ``emcee.autocorr.integrated_time``; the sds'
    errors from the two halves of the kept chain.
(b) the log-evidence by importance sampling with a multivariate-t proposal (5 degrees of
    freedom) fitted to (a)'s samples, ``--is-draws`` draws; its standard error by the delta
    method, its ESS, and its own posterior means and sds (a check on (a)).

``run`` runs SMC and SEMC (``from seqbayes import SMC, SEMC``, a static kernel, the defaults:
above d = 10 the scaled moves; ``--economy`` for ``economy=True``) and prints, per run, the
log-evidence error, the largest |mean error| in reference posterior sds, the smallest and largest
ratio of the sampler's posterior sd to the reference's, the likelihood calls and the wall time;
``--jsonl`` appends each run. ``table`` summarises a JSONL file per (sampler, N, economy); ``cost`` times one batched
likelihood evaluation. ``all`` (the default, e.g. under ``make bench``) builds the reference if
the file is missing, then runs and tabulates (~15 min for the reference, ~2 min per default run).
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

import seqbayes  # noqa: E402
from seqbayes.filters.kalman import kalman_log_likelihood  # noqa: E402
from seqbayes.structures import Sensors, ShearBuilding, add_measurement_noise, discretise, simulate  # noqa: E402
from seqbayes.structures.ground_motion import band_limited_white_noise  # noqa: E402

N_STOREYS = 20
DT = 0.02
N_SAMPLES = 150  # 3 s record
SENSORS = Sensors(accelerations=(4, 8, 12, 16, 20))
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
        ``{"u": (T,) ground acceleration [m/s^2], "y": (T, 5) measured accelerations [m/s^2]}``.
    noise_std : (5,) array
        Measurement noise standard deviations [m/s^2].
    """

    def __init__(self, seed: int = 0):
        masses = np.full(N_STOREYS, 2.0e4)
        masses[-1] = 1.6e4
        self.building = ShearBuilding(masses, np.linspace(3.6e7, 1.6e7, N_STOREYS), (0.02, 0.04))
        truth = np.full(N_STOREYS, 0.95)
        truth[[2, 10]] = [0.75, 0.85]
        self.truth = truth
        rng = np.random.default_rng([14, 20, seed])
        u = band_limited_white_noise((N_SAMPLES - 1) * DT, DT, rms_g=0.02, rng=rng).acceleration
        clean = simulate(discretise(self.building, truth, DT, channels=SENSORS), u)[0]
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
            model = discretise(self.building, theta[idx], DT, channels=SENSORS)
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


def build_reference(problem: Shear20, path: str, walkers: int, steps: int, burn: int, is_draws: int, seed: int):
    import emcee

    t0 = time.perf_counter()
    z_mode, cov_log, opt = laplace_start(problem)
    print(f"mode found ({opt.nfev} gradient evaluations, success {opt.success}): theta = "
          f"{np.round(np.exp(z_mode), 3).tolist()}; Laplace sds (log theta) "
          f"{np.round(np.sqrt(np.diag(cov_log)), 3).tolist()}; {time.perf_counter() - t0:.0f} s", flush=True)
    rng = np.random.default_rng([14, 20, 1000 + seed])
    start = np.exp(rng.multivariate_normal(z_mode, cov_log, size=walkers))
    sampler = emcee.EnsembleSampler(walkers, problem.dim, problem.log_posterior, vectorize=True,
                                    moves=emcee.moves.StretchMove())
    sampler.random_state = np.random.RandomState(seed).get_state()  # emcee's own RNG, seeded
    t1 = time.perf_counter()
    sampler.run_mcmc(start, steps, progress=False)
    chain = sampler.get_chain(discard=burn)  # (kept, walkers, d)
    tau = emcee.autocorr.integrated_time(chain, quiet=True)
    kept = chain.shape[0]
    flat = chain.reshape(-1, problem.dim)
    mean, sd = flat.mean(0), flat.std(0, ddof=1)
    mean_se = sd * np.sqrt(tau / (walkers * kept))
    half = kept // 2
    sd_halves = np.array([chain[:half].reshape(-1, problem.dim).std(0, ddof=1),
                          chain[half:].reshape(-1, problem.dim).std(0, ddof=1)])
    mean_halves = np.array([chain[:half].reshape(-1, problem.dim).mean(0),
                            chain[half:].reshape(-1, problem.dim).mean(0)])
    print(f"emcee: {walkers} walkers x {steps} steps ({burn} burn), acceptance "
          f"{sampler.acceptance_fraction.mean():.3f}, tau {tau.min():.0f}-{tau.max():.0f} steps "
          f"(kept / tau >= {kept / tau.max():.0f}), {time.perf_counter() - t1:.0f} s", flush=True)

    # (b) importance sampling with a multivariate t fitted to the chain
    dof = 5.0
    prop_mean = mean
    prop_cov = np.cov(flat.T) * (dof - 2) / dof  # the t's covariance equals the chain's
    chol = np.linalg.cholesky(prop_cov)
    log_w = np.empty(is_draws)
    draws_mean = np.zeros(problem.dim)
    t2 = time.perf_counter()
    batch = 2000
    theta_all = np.empty((is_draws, problem.dim))
    for start_i in range(0, is_draws, batch):
        n = min(batch, is_draws - start_i)
        g = rng.standard_normal((n, problem.dim))
        chi = rng.chisquare(dof, n)
        x = prop_mean + (g @ chol.T) * np.sqrt(dof / chi)[:, None]
        theta_all[start_i:start_i + n] = x
        log_w[start_i:start_i + n] = problem.log_posterior(x) - multivariate_t_logpdf(x, prop_mean, chol, dof)
    shift = log_w.max()
    w = np.exp(log_w - shift)
    log_z = float(shift + np.log(w.mean()))
    log_z_se = float(w.std(ddof=1) / np.sqrt(is_draws) / w.mean())
    ess = float(w.sum() ** 2 / (w ** 2).sum())
    wn = w / w.sum()
    is_mean = wn @ theta_all
    is_sd = np.sqrt(wn @ (theta_all - is_mean) ** 2)
    del draws_mean
    print(f"importance sampling: {is_draws} t(5) draws, log Z = {log_z:.3f} +- {log_z_se:.3f}, ESS {ess:.0f} "
          f"({100 * ess / is_draws:.1f} %), largest weight {wn.max():.2e}, {time.perf_counter() - t2:.0f} s",
          flush=True)
    mean_gap = np.abs(is_mean - mean) / sd
    print(f"IS vs emcee: largest |mean difference| {mean_gap.max():.3f} sd, sd ratios "
          f"{(is_sd / sd).min():.3f}-{(is_sd / sd).max():.3f}; emcee halves: largest |mean difference| "
          f"{(np.abs(mean_halves[0] - mean_halves[1]) / sd).max():.3f} sd, sd ratio "
          f"{(sd_halves[0] / sd_halves[1]).min():.3f}-{(sd_halves[0] / sd_halves[1]).max():.3f}", flush=True)
    np.savez(path, mean=mean, sd=sd, mean_se=mean_se, tau=tau, sd_halves=sd_halves, mean_halves=mean_halves,
             log_z=log_z, log_z_se=log_z_se, ess=ess, is_draws=is_draws, is_mean=is_mean, is_sd=is_sd,
             walkers=walkers, steps=steps, burn=burn, acceptance=sampler.acceptance_fraction.mean(),
             mode=np.exp(z_mode), truth=problem.truth, elapsed=time.perf_counter() - t0)
    print(f"saved {path}")


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
        sampler = cls(problem.prior(), kernel, problem.loglike, n_samples=n, rng=np.random.default_rng([7, seed]),
                      economy=economy)
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
            "load": os.getloadavg()[0]}


def print_row(r: dict) -> None:
    print(f"{r['sampler']} N={r['n']} economy={r['economy']} seed={r['seed']}: log Z error {r['log_z_error']:+.3f} "
          f"(se {r['reported_se']:.3f}), max |mean error| {r['max_mean_error_sd']:.3f} sd "
          f"(rms {r['rms_mean_error_sd']:.3f}), sd ratio {r['sd_ratio_min']:.2f}-{r['sd_ratio_max']:.2f} "
          f"(mean {r['sd_ratio_mean']:.2f}), calls {r['calls']:,}, {r['time_s']:.0f} s", flush=True)


def table(rows: list[dict], dim: int) -> None:
    print("| sampler | N | economy | seeds | mean log Z error | sd | worst abs log Z error | mean reported se "
          "| worst mean error (sd) | sd ratio range | mean calls | calls / d | mean time (s) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    keys = sorted({(r["sampler"], r["n"], r["economy"]) for r in rows}, key=lambda k: (k[2], -k[1], k[0] != "SMC"))
    for key in keys:
        sel = [r for r in rows if (r["sampler"], r["n"], r["economy"]) == key]
        z = np.array([r["log_z_error"] for r in sel])
        calls = np.mean([r["calls"] for r in sel])
        sd = f"{z.std(ddof=1):.3f}" if len(z) > 1 else "-"
        print(f"| {key[0]} | {key[1]} | {'yes' if key[2] else 'no'} | {len(sel)} | {z.mean():+.3f} | {sd} "
              f"| {np.abs(z).max():.3f} | {np.mean([r['reported_se'] for r in sel]):.3f} "
              f"| {max(r['max_mean_error_sd'] for r in sel):.3f} "
              f"| {min(r['sd_ratio_min'] for r in sel):.2f}-{max(r['sd_ratio_max'] for r in sel):.2f} "
              f"| {calls:,.0f} | {calls / dim:,.0f} | {np.mean([r['time_s'] for r in sel]):.0f} |")


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("command", nargs="?", default="all", choices=("all", "reference", "run", "table", "cost"),
                        help="all (default): the reference if missing, then run and table")
    parser.add_argument("jsonl_file", nargs="?", help="for table: the JSONL file of runs")
    parser.add_argument("--reference", default=DEFAULT_REFERENCE)
    parser.add_argument("--walkers", type=int, default=100)
    parser.add_argument("--steps", type=int, default=10000)
    parser.add_argument("--burn", type=int, default=2000)
    parser.add_argument("--is-draws", type=int, default=200000)
    parser.add_argument("--reference-seed", type=int, default=0)
    parser.add_argument("--samplers", nargs="+", default=["SMC", "SEMC"])
    parser.add_argument("--n", type=int, nargs="+", default=[2000], help="particles (cost: batch sizes)")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--economy", action="store_true")
    parser.add_argument("--jsonl", help="append every run to this file")
    args = parser.parse_args()
    problem = Shear20()
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
