"""The path-space remedy for prior-data conflict: a step assimilated on the joint posterior of the last
``L`` states, whose target is the model's exact one (:func:`assimilate_paths`; docs/prior_data_conflict.md)."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from ..engine.errors import TemperingLimitError, ZeroLikelihoodError
from ..engine.evidence import estimate_increment, step_standard_errors
from ..engine.stages import count_distinct, restricted_draws, step_conflict, temper_resample_move
from ..engine.state import Cloud, MoveTally, PastStep, Problem, SamplerState, kept_copy, variance_before
from ..kernels import MarkovKernel
from ..priors import as_samples, inside_space
from ..results import StepInfo, StepRecord
from ..weights import logsumexp
from .lineage import ancestor_draws, ancestor_mass, ancestor_terms, lineage_after, mass_spread
from .base import propagate
from .mixture import GaussianMixture, jump_step_fields

__all__ = ["assimilate_paths", "remedy_applies", "PathPrior", "path_prior_logpdf"]


def remedy_applies(config, method, kernel) -> bool:
    """The path-space remedy needs a transition density in every parameter (no static ones)."""
    return config.conflict_remedy and method in ("transition", "kde") and not kernel.static_mask.any()


def _start_paths(state, kernel, length, rng):
    """``(N, length, d)`` paths over the window's steps ending at the posterior particles: the last
    path-space step's paths where kept, extended backwards by drawing ancestors (backward simulation
    with the exact transition) among the window's stored posteriors."""
    window = state.window[-length:]
    n, d = state.posterior.shape
    paths = np.empty((n, length, d))
    known = 0 if state.paths is None else min(length, state.paths.shape[1])
    if known:
        paths[:, length - known:] = state.paths[:, -known:]
    else:
        paths[:, -1] = state.posterior
        known = 1
    for t in range(length - known - 1, -1, -1):
        index, _ = ancestor_draws(kernel, paths[:, t + 1], window[t].posterior, window[t].log_weights, rng)
        paths[:, t] = window[t].posterior[index]
    return paths


@dataclass(frozen=True, eq=False)
class _PathPredictive:
    """Draws of ``(theta_{w:s-1}, theta_s)``: a weighted path, extended by the kernel (for restarts)."""

    paths: np.ndarray
    log_weights: np.ndarray
    kernel: MarkovKernel
    dim: int

    def sample(self, n, rng):
        index = rng.choice(self.paths.shape[0], size=int(n), p=np.exp(self.log_weights - logsumexp(self.log_weights)))
        last = self.paths[index, -self.dim:]
        return np.concatenate([self.paths[index], self.kernel.propagate(last, rng)], axis=1)


def _add_transitions(out, states, kernel):
    """Add ``sum_{t>=1} log T(theta_t | theta_{t-1})`` along paths ``states (M, T, d)`` to ``out (M,)`` in place,
    for the paths still finite (the rest stay -inf); returns ``out``."""
    for t in range(1, states.shape[1]):
        alive = np.isfinite(out)
        if not alive.any():
            break
        out[alive] += kernel.logpdf(states[alive, t], states[alive, t - 1])
    return out


def path_prior_logpdf(window, kernel, likelihood, dim):
    """``log p(theta_{w:s-1} | D^{w:s-1}) + log T(theta_s | theta_{s-1})`` for flattened paths ``(M, L d)``.

    The window's first state has the prior its step used (exact from step 1 on), every later one
    the exact transition, every past state its dataset's likelihood; the log of the window's evidence
    ``sum_t log Z_t`` normalises it (the importance-sampling evidence needs a normalised prior)."""
    normaliser = sum(past.log_evidence_increment for past in window)

    def logpdf(walkers):
        states = walkers.reshape(walkers.shape[0], -1, dim)
        out = np.asarray(window[0].prior.logpdf(states[:, 0]), dtype=float) - normaliser
        _add_transitions(out, states, kernel)  # transitions into steps w+1..s
        return likelihood.add_along_paths(out, states, [past.dataset for past in window])  # the past datasets'

    return logpdf


@dataclass(frozen=True, eq=False)
class PathPrior:
    """The window's path prior ``p_w(theta_w) prod_{t=w+1}^{s} T(theta_t | theta_{t-1})`` on flattened paths
    ``(M, (L + 1) d)``: draws (``theta_w`` from ``first``, the rest forward through the kernel) and log-density."""

    first: object
    kernel: MarkovKernel
    n_states: int
    dim: int

    def sample(self, n, rng):
        states = [as_samples(self.first.sample(int(n), rng), self.dim, "prior.sample(n, rng)")]
        for _ in range(1, self.n_states):
            states.append(self.kernel.propagate(states[-1], rng))
        return np.concatenate(states, axis=1)

    def logpdf(self, walkers):
        states = walkers.reshape(walkers.shape[0], self.n_states, self.dim)  # explicit: no draw may be inside
        return _add_transitions(np.asarray(self.first.logpdf(states[:, 0]), dtype=float).copy(), states, self.kernel)


def _bridge_from_path_prior(window, dataset, kernel, path_problem, path_config, likelihood, moves, rng):
    """The window's posterior reached from its path PRIOR by tempering all its likelihoods jointly.

    The path-space target of :func:`assimilate_paths` (``w`` the window's first step, ``s`` this one),

        pi(theta_{w:s}) = p_w(theta_w) prod_{t=w+1}^{s} T(theta_t | theta_{t-1}) prod_{t=w}^{s} L_t(theta_t) / Z_{w:s},
        Z_{w:s} = p(D^{w:s} | D^{1:w-1}) = prod_{t=w}^{s} Z_t,

    is bridged from the path prior ``pi_0 = p_w prod T`` (sampled forward: ``theta_w ~ p_w``, then the
    kernel; restricted to the parameter space by rejection, whose acceptance fraction ``m`` enters the
    evidence as in :func:`restricted_draws`) through

        pi_beta prop. to pi_0(theta_{w:s}) [prod_{t=w}^{s} L_t(theta_t)]^beta,   0 = beta_0 < ... < beta_K = 1,

    with the sampler's own reweight-resample-move stages (Eq. A5, the moves on the whole path). Every
    choice of which dataset a path gives up is weighed afresh, not inherited from the previous steps'
    particles, so a mode of ``pi`` whose earlier states the earlier data had ruled out given the stored
    paths is reached. The stages' product of mean weights (Eq. 1) estimates ``log Z_{w:s} = log m +
    sum_k log mean_i w_i^(k)``; the step's increment is that minus the window's stored increments
    ``sum_{t=w}^{s-1} log Z_t`` (the normaliser of :func:`path_prior_logpdf`), so the cumulative evidence
    becomes the window's own estimate.

    Returns
    -------
    cloud : Cloud
        Equal-weight (or weighted) paths ``(N, (L + 1) d)`` of ``pi``, with the components of the stored
        paths' start, ``(log L_s, log pi_0 + sum_{t<s} log L_t - sum_{t=w}^{s-1} log Z_t)``.
    log_increment : float
        The step's increment by the tempering path, ``log Z_{w:s}`` (with the restricted mass) minus the
        window's stored increments.
    temperatures, moves, resampled, stage_ess, n_found
        As :func:`temper_resample_move`; ``n_found`` distinct draws of the restricted path prior.
    """
    d, n = kernel.dim, path_config.n_samples
    # every stage keeps tempering_ess of the ESS: no shortcut to beta = 1 at a mere tempering_threshold (10 %) of N,
    # which a cloud gathered in a narrow minor mode of an early stage passes (run 9, T6, the study's SMC seed, step 4:
    # from beta = 0.05 to 1 in one stage, 24 exact sds and 44 nats off)
    path_config = replace(path_config, tempering_threshold=path_config.tempering_ess)
    path_prior = PathPrior(window[0].prior, kernel, len(window) + 1, d)
    window_likelihood = likelihood.over_window([past.dataset for past in window] + [dataset], d)
    walkers, loglike, log_restricted_mass, n_found, labels = restricted_draws(
        path_prior, path_problem.support, n, rng, likelihood.step, window_likelihood)
    components = np.column_stack([loglike, path_prior.logpdf(walkers)])
    cloud = Cloud(walkers, np.full(n, -np.log(n)), components, labels)  # labels: the path-prior draws
    cloud, log_z, temperatures, moves, resampled, stage_ess = temper_resample_move(
        cloud, path_problem, path_config, window_likelihood, path_prior.logpdf, moves, True, False, rng)
    # back to the decomposition of the stored paths' start, (log L_s, log of the normalised path prior of
    # assimilate_paths), for the importance estimate of the increment: log L_s costs N calls, the rest is a difference
    last = likelihood.of_last_state(d).loglike(cloud.particles)
    normaliser = sum(past.log_evidence_increment for past in window)
    cloud = Cloud(cloud.particles, cloud.log_weights,
                   np.column_stack([last, cloud.components[:, 1] + (cloud.components[:, 0] - last) - normaliser]),
                   cloud.labels)
    return cloud, log_z + log_restricted_mass - normaliser, temperatures, moves, resampled, stage_ess, n_found


def _paths_from_previous(state, dataset, kernel, path_problem, path_likelihood, prior_logpdf, config, rng):
    """The regular path-space start: the previous posterior's paths (:func:`_start_paths`) extended by
    ``theta_s ~ T(. | theta_{s-1})`` and weighed by ``L_s``; as :func:`weigh`, a restart from the path
    predictive restricted to ``{inside, L > 0}`` when few of them can carry the step.

    Returns the cloud (components ``(log L_s, log path prior)``), its log-weights before the step, the log
    of the restricted mass (0 without restart) and the number of distinct restart draws (N without)."""
    d, n = kernel.dim, config.n_samples
    length = path_problem.support.shape[0] // d - 1
    paths = _start_paths(state, kernel, length, rng)
    walkers = np.concatenate([paths, kernel.propagate(paths[:, -1], rng)[:, None]], axis=1).reshape(
        paths.shape[0], -1)
    log_weights, log_restricted_mass, n_found, labels = state.posterior_log_weights, 0.0, n, np.arange(n)
    loglike = np.full(n, -np.inf)
    inside = inside_space(walkers, path_problem.support)
    loglike[inside] = path_likelihood.loglike(walkers[inside])
    valid = np.isfinite(loglike)
    if not valid.all() and (not inside.all() or valid.sum() < config.min_valid_fraction * n):
        # as weigh: restart from the path predictive restricted to {inside, L > 0}, its mass in the evidence
        extended = _PathPredictive(paths.reshape(n, -1), log_weights, kernel, d)
        walkers, loglike, log_restricted_mass, n_found, labels = restricted_draws(
            extended, path_problem.support, n, rng, path_likelihood.step, path_likelihood)
        log_weights = np.full(n, -np.log(n))
    components = np.column_stack([loglike, np.full(n, -np.inf)])
    carried = np.isfinite(loglike)
    components[carried, 1] = prior_logpdf(walkers[carried])
    return Cloud(walkers, log_weights, components, labels), log_weights, log_restricted_mass, n_found


def _stored_paths_start(state, dataset, kernel, path_problem, path_likelihood, prior_logpdf, config, path_config, moves,
                        rng):
    """The path-space step from the stored paths (:func:`_paths_from_previous`) tempered in ``L_s``
    (:func:`temper_resample_move`). Returns the cloud, the increment by the tempering path (with the restart's
    restricted mass), the temperatures, moves, whether the last stage resampled, its ESS, the number of distinct
    restart draws and the log-weights before the step."""
    cloud, log_weights, log_restricted_mass, n_found = _paths_from_previous(state, dataset, kernel, path_problem,
                                                                            path_likelihood, prior_logpdf, config, rng)
    cloud, log_z, temperatures, moves, resampled, stage_ess = temper_resample_move(
        cloud, path_problem, path_config, path_likelihood, prior_logpdf, moves, True, False, rng)
    return cloud, log_z + log_restricted_mass, temperatures, moves, resampled, stage_ess, n_found, log_weights


def _bridged_standard_errors(state, window, cloud, n, evidence_ess, d):
    """``(increment_se, cumulative_se, cumulative_variance)`` of a bridged step (:func:`_bridge_from_path_prior`).

    Its cumulative log-evidence is ``log Z_hat_{1:w-1} + log Z_hat_{w:s}``: the window's evidence is estimated
    afresh (the importance estimate on the path space, variance ``1 / ESS - 1 / N``) from the window's first
    prior ``p_w``, so the cumulative variance continues from the one before step ``w``, not from step ``s - 1``'s
    (the stored increments of the window cancel). ``p_w`` is the initial prior when the window reaches step 1,
    else the mixture over step ``w - 1``'s particles, whose error is the spread of the paths' first states over
    its components (:meth:`GaussianMixture.ancestor_spread`, each particle its own label). The increment,
    ``log Z_hat_{w:s}`` minus the window's stored increments, adds their accumulated variance.
    Before this the ordinary step's formula was used, with the ancestor ESS of the conflict (1-4 of N): 0.6-0.76
    nats reported on run 9 (T3) where the increments' errors were 0.01-0.11."""
    variance = 1.0 / evidence_ess - 1.0 / n if np.isfinite(evidence_ess) and evidence_ess > 0 else float("nan")
    first = window[0]
    if isinstance(first.prior, GaussianMixture):
        variance += first.prior.ancestor_spread(cloud.particles[:, :d], cloud.log_weights, None).variance
    cumulative = first.log_evidence_variance + variance
    increment = variance + max(state.log_evidence_variance - first.log_evidence_variance, 0.0)
    return float(np.sqrt(increment)), float(np.sqrt(cumulative)), float(cumulative)


def assimilate_paths(state: SamplerState, dataset, problem: Problem, config: SamplerConfig, rng, likelihood,
                     method: str, start: float, bridge: bool = False) -> tuple[SamplerState, StepRecord, Cloud]:
    """The exact remedy for prior-data conflict: assimilate ``dataset`` on the path space.

    The predictive mixture ``sum_j W_j T(theta | theta_j)`` is exact only where the previous
    posterior's particles are: a posterior that lies several predictive sds out is made of that
    posterior's far tail, which N particles do not hold (on run 9 of the oscillator study the
    mixture's own posterior of ``k`` at step 3 is 2.7 exact sds low at N = 1000 and 1.4 at 16000).
    Here the target is the joint posterior of the last ``L`` states (Eq. A2-A3 unrolled),

        p(theta_{w:s} | D^{1:s}) prop. to p_w(theta_w) prod_{t=w}^{s} L_t(theta_t) prod_{t=w+1}^{s} T(theta_t | theta_{t-1}),

    whose marginal in ``theta_s`` is the model's exact posterior (``p_w`` is the initial prior when
    the window reaches step 1). With ``bridge`` (``SamplerConfig.remedy_bridge``, the default) the
    particles are drawn from the path prior ``p_w prod T`` and every likelihood of the window is
    tempered jointly (:func:`_bridge_from_path_prior`), so that every mode of the path posterior is
    weighed afresh; the stored paths' start below (or, where it cannot carry the step, a second bridge)
    runs as well, and the two clouds are pooled, each cluster given its importance-sampling share of the
    mass, before the importance sweeps (:func:`estimate_increment`), because a tempering can weigh a mode wrongly
    once the modes have separated (lose it, or end trapped in a minor one). Without it they start from the
    previous posterior's paths (kept from the last path-space step, or drawn backwards with the exact
    transition), are extended by
    ``theta_s ~ T(. | theta_{s-1})`` and tempered in ``L_s`` (Eq. A5) only. Either way they are moved
    by the sampler's own MCMC move on the whole path, which carries the earlier states into the tails
    the data call for. The evidence increment is Eq. (1) or the importance estimate of
    :mod:`seqbayes.engine.evidence` on the path space; the cost of a move is one likelihood call per state of
    the window.

    Returns the new state (with the paths), the record (``StepInfo.path_steps = L``) and the cloud.
    """
    step = state.step + 1
    kernel, d = problem.kernel, problem.kernel.dim
    length = min(len(state.window), config.remedy_lag - 1)
    window = state.window[-length:]
    path_problem = Problem(problem.prior, kernel, problem.loglike, np.tile(problem.support, (length + 1, 1)),
                           problem.executor, problem.n_chunks)
    path_likelihood = likelihood.of_last_state(d)
    prior_logpdf = path_prior_logpdf(window, kernel, likelihood, d)
    n = config.n_samples
    moves = MoveTally(step_size=state.step_size)
    # L + 1 times as many dimensions: SMC's random-walk scale goes as 1 / sqrt(dim) (Roberts, Gelman & Gilks
    # 1997), so gamma for d dimensions becomes gamma / sqrt(L + 1), and a path decorrelates in O(dim) moves: at
    # least 2 (L + 1) per stage. benchmarks/bench_abrupt.py, 10 seeds, worst mean error over the steps of run 9
    # (T2) / the abrupt drop, SEMC and SMC: 0.44, 0.35 / 0.25, 0.36 exact sds with L + 1 moves, 0.22, 0.17 /
    # 0.31, 0.26 with 2 (L + 1), at twice the cost of a path-space step. SEMC's stretch move mixes more slowly
    # in the 2 (L + 1) path dimensions (its autocorrelation grows with the dimension): with 2 (L + 1) sweeps its
    # mean of k at the abrupt drop's step 5 was biased by +0.09 +- 0.02 exact sds over 20 seeds (worst 0.31), with
    # 4 (L + 1) by +0.05 +- 0.02 (bench_abrupt.py --per-seed; SMC's moves keep 2 (L + 1))
    # The bridge from the path prior (remedy_bridge) makes 4 (L + 1) moves per stage with either sampler: its first
    # stages hold the whole prior's spread along the window's likelihood ridges, where SMC's random walk at
    # gamma / sqrt(L + 1) with 2 (L + 1) moves let the paths collapse (run 9, T4, sampler seed 0, step 5: importance
    # ESS 7 of 1000, 1.75 exact sds and 35 nats off; with 4 (L + 1): 0.03 sds, 0.01 nats)
    per_state = 4 if config.move == "stretch" or bridge else 2
    # the moves' kind follows the model's d, not the path's (L + 1) d (SamplerConfig.scaled_moves)
    config = replace(config, scaled_moves=config.uses_scaled_moves(d))
    path_config = replace(config, proposal_scale=config.proposal_scale / np.sqrt(length + 1),
                          n_moves=max(config.n_moves, min(config.max_moves, config.max_virtual,
                                                          per_state * (length + 1))))
    if bridge:
        cloud, log_z, temperatures, moves, resampled, stage_ess, n_found = _bridge_from_path_prior(
            window, dataset, kernel, path_problem, path_config, likelihood, moves, rng)
        # a second cloud of the same target, which estimate_increment pools with the bridge's (each given its share of the mass,
        # then independence sweeps with a proposal fitted to both): the stored paths' start (the branch below) holds
        # the modes the previous particles held, which the bridge's tempering can lose (run 9, T3, step 5: a 5 % mode
        # with k_5 ~ 0.87, where the bridge put 0.04 % of its weight and sat 0.26 exact sds off at every seed); where
        # the stored paths cannot carry the step (T6: the drift takes every extended path out of the box), a second
        # bridge, as a bridge's tempering can also end trapped in a minor mode (run 9, T6, step 6: 6.3 sds, 89 nats)
        try:
            other, _, _, moves, *_ = _stored_paths_start(state, dataset, kernel, path_problem, path_likelihood,
                                                         prior_logpdf, config, path_config, moves, rng)
        except (ZeroLikelihoodError, TemperingLimitError):
            other, _, _, moves, _, _, _ = _bridge_from_path_prior(window, dataset, kernel, path_problem, path_config,
                                                                  likelihood, moves, rng)
    else:
        cloud, log_z, temperatures, moves, resampled, stage_ess, n_found, log_weights = _stored_paths_start(
            state, dataset, kernel, path_problem, path_likelihood, prior_logpdf, config, path_config, moves, rng)
        other = None
    # at least 2 (L + 1) independence sweeps per fit, as the moves: with 3, run 9 under T5 ended step 6 0.3-0.5 exact
    # sds off in c at every seed, from a start within 0.02 sds (the sweeps' transient through the path's earlier
    # states); with 10 (= 2 (L + 1) there), within 0.03 at seeds 1, 2, 4 (SMC, SEMC, SMC)
    evidence_config = replace(config, n_independent=max(config.n_independent, 2 * (length + 1)))
    cloud, log_increment, evidence_ess, n_independent = estimate_increment(
        cloud, log_z, n_found, path_problem, evidence_config, path_likelihood, prior_logpdf,
        config.evidence == "importance", rng, other)
    log_evidence = float(state.log_evidence + log_increment)
    posterior = cloud.particles[:, -d:]
    marginal = Cloud(posterior, cloud.log_weights, cloud.components)
    density, predictive, _ = propagate(state, marginal, dataset, log_increment, log_evidence, method, problem,
                                        config, rng)
    conflict = step_conflict(state.particles, state.log_weights, posterior, cloud.log_weights, problem.support)
    _, mass = ancestor_mass(kernel, posterior, state.posterior, state.posterior_log_weights,
                             later_log_weights=cloud.log_weights)
    spread = mass_spread(state, mass)
    ancestors = spread.ess
    importance = config.evidence == "importance" and log_increment != log_z
    if bridge:
        increment_se, evidence_se, evidence_variance = _bridged_standard_errors(
            state, window, cloud, n, evidence_ess if importance else float("nan"), d)
    else:
        ancestor_variance, covariance = ancestor_terms(state, spread)
        increment_se, evidence_se, evidence_variance = step_standard_errors(
            state.log_evidence_variance, n, importance, evidence_ess, np.exp(log_weights), cloud.log_weights,
            len(temperatures), resampled, ancestor_variance, method, covariance)
    step_size = moves.step_size if config.move == "stretch" else float("nan")
    info = StepInfo(
        step=step, log_evidence_increment=float(log_increment), log_evidence=log_evidence, ess=float(stage_ess),
        resampled=bool(resampled), acceptance_rate=moves.stats.acceptance_rate, step_size=float(step_size),
        n_virtual=moves.n_virtual, n_stages=len(temperatures), temperatures=temperatures,
        n_loglike_evals=likelihood.n_evals, n_nan=likelihood.n_nan, n_distinct=count_distinct(posterior),
        n_proposed=moves.stats.n_proposed, n_accepted=moves.stats.n_accepted,
        n_identical_partner=moves.stats.n_identical_partner, log_evidence_increment_path=float(log_z),
        evidence_ess=evidence_ess, n_independent_accepted=n_independent,
        n_move_evaluations=moves.stats.n_evaluations, wall_time=time.perf_counter() - start,
        prior_data_conflict=float(conflict.max()), conflict_parameter=int(conflict.argmax()),
        ancestor_ess=ancestors, path_steps=length + 1,
        log_evidence_increment_se=increment_se, log_evidence_se=evidence_se,
        **jump_step_fields(kernel, state.prior, posterior, cloud.log_weights))
    record = StepRecord(info, posterior, cloud.log_weights, predictive)
    past = PastStep(kept_copy(dataset), state.prior, posterior, cloud.log_weights, float(log_increment), True,
                    variance_before(state))
    keep = config.remedy_lag - 1
    new_state = SamplerState(step=step, particles=predictive, log_weights=cloud.log_weights, prior=density,
                             log_evidence=log_evidence,
                             step_size=float(moves.step_size if config.move == "stretch" else state.step_size),
                             posterior=posterior, posterior_log_weights=cloud.log_weights,
                             window=(state.window + (past,))[-keep:],
                             paths=cloud.particles.reshape(n, length + 1, d)[:, -keep:],
                             log_evidence_variance=evidence_variance, lineage=lineage_after(state, cloud.labels),
                             previous_prior=state.prior if isinstance(state.prior, GaussianMixture) else None)
    return new_state, record, marginal

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from ..engine.settings import SamplerConfig
