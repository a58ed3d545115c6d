"""Where the path-space step loses its tail: the step-13 path cloud of the 2 % drop (frequency likelihood, jump
kernel, SEMC, N = 1000) against the exact grid posterior (docs/jump_kernels.md, "Why the path cloud's tail is light").

Per seed, one JSON line: the cloud's mass below the exact 1, 2.5, 5, 50 and 95 % quantiles and its mean exact CDF
(`final`); the same for the bridge's and the stored paths' tempered clouds and the stored start before its moves
(`stored_weighed`, importance-weighted), each followed by its Rao-Blackwellised P(jump into the last step),
`E[p T_slab / T]` over the paths (exact: the grid's P(jump)); the importance sweeps' clouds (`is_in`, `is_out`);
the likelihood evaluations of the step (`evals`). VARIANT: `base` (the code as it is), `nostop` (the rounds' stop
rule off), `indep60` (60 importance sweeps), `widet` (the defensive t with 4x its covariance).

    PYTHONPATH=src python benchmarks/diagnose_path_tail.py base 10,11,12,13,14,15,16,17,18,19
"""
import json, sys, os, warnings
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import numpy as np
import bench_moderate_damage as B
from seqbayes.reference import kernel_grid_filter
from scipy import stats
import seqbayes.predictive.paths as P
import seqbayes.moves.schedule as S

variant = sys.argv[1]
seeds = [int(s) for s in sys.argv[2].split(",")]
STEP = 13
_, datasets = B.simulate(2.0, "frequency")
ll = B.log_likelihood("frequency")
steps, jumps = kernel_grid_filter(datasets[:STEP], lambda axes, y: ll(axes[0][:, None], y), B.kernels()["jump"],
                                  [[0.2, 1.8]], log_prior=lambda axes: stats.norm(1.0, 0.1).logpdf(axes[0]))
g = steps[STEP - 1]
x = g.axes[0]; p = np.exp(g.log_density); 
cdf = np.concatenate([[0], np.cumsum(0.5 * (p[1:] + p[:-1]) * np.diff(x))]); cdf /= cdf[-1]
F = lambda t: np.interp(t, x, cdf)
LEVELS = [0.01, 0.025, 0.05, 0.5, 0.95]
KERN = B.kernels()["jump"]
def rjump(paths):   # the last transition's slab responsibility along flattened paths (M, 10)
    a, b = paths[:, -2:-1], paths[:, -1:]
    slab = np.log(0.05) + stats.norm.logpdf(b[:, 0], a[:, 0] - 0.1, np.hypot(0.004, 0.08))
    return np.exp(slab - KERN.logpdf(b, a))
def wmean(v, lw):
    w = np.exp(lw - lw.max()); w /= w.sum(); return float(np.sum(w * v))
def tail(theta, lw):
    w = np.exp(lw - lw.max()); w /= w.sum(); u = F(theta)
    return [float(np.sum(w * (u < a))) for a in LEVELS] + [float(np.sum(w * u))]

record = {}
STASH = {}
orig_init_s = P.PathStep.__init__
def init_s(self, state, *a, **kw):
    orig_init_s(self, state, *a, **kw)
    STASH["p"] = self.window[0].prior
    STASH["ds_ok"] = all(np.array_equal(np.asarray(w.dataset), datasets[STEP - 10 + i]) for i, w in enumerate(self.window))
P.PathStep.__init__ = init_s
orig_estimate = P.PathStep.estimate
def estimate(self, tempered, weighed, likelihood, rng):
    c = tempered.cloud
    record.setdefault("bridge", []).append(tail(c.particles[:, -1], c.log_weights) + [wmean(rjump(c.particles), c.log_weights)])
    out = orig_estimate(self, tempered, weighed, likelihood, rng)
    return out
P.PathStep.estimate = estimate
orig_stored = P.PathStep._stored_temper
def stored(self, weighed, rng):
    c = weighed.cloud
    lw_ = c.log_weights + np.where(np.isfinite(c.components[:, 0]), c.components[:, 0], -np.inf)
    record.setdefault("stored_weighed", []).append(tail(c.particles[:, -1], lw_) + [wmean(rjump(c.particles), lw_), float(1 / np.sum(np.exp(2 * (lw_ - np.logaddexp.reduce(lw_)))))])
    t = orig_stored(self, weighed, rng)
    record.setdefault("stored", []).append(tail(t.cloud.particles[:, -1], t.cloud.log_weights) + [wmean(rjump(t.cloud.particles), t.cloud.log_weights)])
    return t
P.PathStep._stored_temper = stored

import seqbayes.predictive.evidence as E
orig_is = E.importance_step
def importance_step(posterior, log_weights, *a, **kw):
    record.setdefault("is_in", []).append(tail(posterior[:, -1], log_weights))
    if posterior.shape[1] == 10 and kw.get("other") is not None:   # the path step's proposal: its tail against pi's
        from seqbayes.priors import BoxTransform
        from seqbayes.moves.proposals import PooledProposal, clustered_parts
        prior_logpdf, loglike, support = a[1], a[2], a[3]
        tr = BoxTransform(support); oth = kw["other"]
        qrng = np.random.default_rng(99)
        q = PooledProposal(*clustered_parts([(tr.forward(posterior), log_weights), (tr.forward(oth[0]), oth[1])], qrng)[:2])
        draws = q.sample(5000, qrng)
        theta, inside, comps, lt = E._target_at(draws, tr, support, loglike, prior_logpdf)
        lw = lt - q.logpdf(draws)
        wq = np.exp(lw - lw[np.isfinite(lw)].max()); wq[~np.isfinite(lw)] = 0; wq /= wq.sum()
        u13 = F(theta[:, -1])
        ok = np.isfinite(lt)
        p = STASH["p"]; th = theta[ok]
        mine = np.asarray(p.logpdf(th[:, :1]), float).copy()
        for t in range(1, 10):
            mine += KERN.logpdf(th[:, t:t + 1], th[:, t - 1:t])
        for t in range(10):
            mine += ll(th[:, t:t + 1], datasets[STEP - 10 + t])
        diff = comps[ok].sum(axis=1) - mine
        record.setdefault("target_check", []).append([float(np.mean(diff)), float(np.std(diff)), int(ok.sum())])
        record.setdefault("q_mass", []).append([float(np.mean(u13 < a)) for a in LEVELS] + [float(np.mean(rjump(theta))), float(np.sum(wq * rjump(theta))), wmean(rjump(posterior), log_weights), wmean(rjump(oth[0]), oth[1])])
        record.setdefault("pi_is", []).append([float(np.sum(wq * (u13 < a))) for a in LEVELS] + [float(1 / np.sum(wq**2))])
    out = orig_is(posterior, log_weights, *a, **kw)
    record.setdefault("is_out", []).append(tail(out[2][:, -1], log_weights) + [out[4], out[1]] + ([wmean(rjump(out[2]), log_weights)] if posterior.shape[1] == 10 else []))
    return out
E.importance_step = importance_step
if "widet" in variant:   # the defensive t with 4x (not 2x) the covariance in every proposal
    import seqbayes.moves.proposals as Q
    orig_parts = Q.defensive_parts
    def parts(u, log_weights, n_components=None, gaussian=False):
        kde, t = orig_parts(u, log_weights, n_components, gaussian)
        return kde, stats.multivariate_t(loc=t.loc, shape=float(os.environ.get("TSCALE", "4")) * t.shape, df=t.df, allow_singular=True)
    Q.defensive_parts = parts
if "nostop" in variant:      # the rounds' stop rule off: every stage makes its max rounds
    S.JUMP_TARGET = float("inf")
if variant == "nobridge":
    orig_init0 = P.PathStep.__init__
    def init0(self, state, dataset, mixture, likelihood, bridge):
        orig_init0(self, state, dataset, mixture, likelihood, False)
    P.PathStep.__init__ = init0
if variant.startswith("indep"):   # more independence sweeps in the estimate
    k = int(variant[5:])
    orig_init = P.PathStep.__init__
    from dataclasses import replace
    def init(self, *a, **kw):
        orig_init(self, *a, **kw)
        self.config = replace(self.config, evidence=replace(self.config.evidence, sweeps=k))
    P.PathStep.__init__ = init

for seed in seeds:
    record.clear()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = B.SEMC(B.prior(), B.kernels()["jump"], ll, n_samples=1000, rng=np.random.default_rng(seed)).run(datasets[:STEP])
    r = res.steps[STEP - 1]
    info = r.info
    out = dict(variant=variant, seed=seed, path_steps=int(info.path_steps), evals=int(info.n_loglike_evals),
               final=tail(r.posterior[:, 0], r.log_weights), pj=float(info.jump_probability),
               exact_pj=float(jumps[STEP - 1, 0]), ds_ok=STASH.get("ds_ok"), **{k: (v if k.startswith('is_') else v[-1]) for k, v in record.items()})
    print(json.dumps(out), flush=True)
