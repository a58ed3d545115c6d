"""The path-space step of the conflict remedy (:class:`~seqbayes.predictive.transition.PathSpace`): a step assimilated
on the joint posterior of the last ``L`` states, whose target is the model's exact one (:class:`PathStep`;
docs/prior_data_conflict.md)."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from ..core.likelihood import kept_copy
from ..core.state import (Cloud, Estimate, Failure, Outcome, PastStep, Problem, Reassimilate, RemedyMemory, SamplerState,
                          Tempered, Weighed)
from ..moves.base import MoveTally
from ..kernels import MarkovKernel
from ..moves.schedule import PathTarget, ResampleMove
from ..priors import as_samples, inside_space
from ..weights import resample
from ..results import ConflictInfo, EvidenceInfo, JumpInfo
from ..weights import logsumexp
from .jumps import jump_fields
from .evidence import step_standard_errors
from .lineage import (ancestor_draws, ancestor_mass, ancestor_terms, lineage_after, mass_spread, remedy_window,
                      variance_before)
from .mixture import GaussianMixture
from .particle import ExactPrior, restricted_draws, step_conflict, temper_stages

__all__ = ["PathStep", "PathPrior", "path_prior_logpdf"]


def _start_paths(state, kernel, length, rng):
    """``(N, length, d)`` paths over the window's steps ending at the posterior particles: the last
    path-space step's paths where kept, extended backwards by drawing ancestors (backward simulation
    with the exact transition) among the window's stored posteriors."""
    window = state.memory.window[-length:]
    n, d = state.posterior.shape
    paths = np.empty((n, length, d))
    known = 0 if state.memory.paths is None else min(length, state.memory.paths.shape[1])
    if known:
        paths[:, length - known:] = state.memory.paths[:, -known:]
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


def path_prior_logpdf(window, kernel, likelihood, dim, memos=None):
    """``log p(theta_{w:s-1} | D^{w:s-1}) + log T(theta_s | theta_{s-1})`` for flattened paths ``(M, L d)``.

    The window's first state has the prior its step used (exact from step 1 on), every later one
    the exact transition, every past state its dataset's likelihood; the log of the window's evidence
    ``sum_t log Z_t`` normalises it (the importance-sampling evidence needs a normalised prior).
    ``memos``: one :class:`~seqbayes.core.likelihood.StateMemo` per past dataset, which keeps each state's
    likelihood (a move of a path's suffix keeps the earlier states)."""
    normaliser = sum(past.log_evidence_increment for past in window)

    def logpdf(walkers):
        if walkers.shape[0] == 0:    # a sweep none of whose proposals is inside the box
            return np.zeros(0)
        states = walkers.reshape(walkers.shape[0], walkers.shape[1] // dim, dim)
        out = np.asarray(window[0].prior.logpdf(states[:, 0]), dtype=float) - normaliser
        _add_transitions(out, states, kernel)  # transitions into steps w+1..s
        # the past datasets'
        return likelihood.add_along_paths(out, states, [past.dataset for past in window], memos)

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

    def resimulate(self, walkers, rng):
        """Proposals that redraw each path ``walkers (M, (L + 1) d)`` from a state chosen uniformly on (``theta_w`` from
        ``first``, each later state through the kernel from the one before), and ``(M, (L + 1) d)`` bool: the
        coordinates redrawn. The prior's factors cancel against the proposal's in the Metropolis-Hastings ratio
        (:func:`~seqbayes.moves.schedule.prior_sweep`)."""
        m = walkers.shape[0]
        states = walkers.reshape(m, self.n_states, self.dim).copy()
        start = rng.integers(self.n_states, size=m)
        fresh = start == 0
        if fresh.any():
            states[fresh, 0] = as_samples(self.first.sample(int(fresh.sum()), rng), self.dim, "prior.sample(n, rng)")
        for t in range(1, self.n_states):
            redraw = start <= t
            if redraw.any():
                states[redraw, t] = self.kernel.propagate(states[redraw, t - 1], rng)
        changed = np.repeat(np.arange(self.n_states)[None, :] >= start[:, None], self.dim, axis=1)
        return states.reshape(m, -1), changed

    def logpdf(self, walkers):
        states = walkers.reshape(walkers.shape[0], self.n_states, self.dim)  # explicit: no draw may be inside
        return _add_transitions(np.asarray(self.first.logpdf(states[:, 0]), dtype=float).copy(), states, self.kernel)


def _bridged_standard_errors(state, window, cloud, n, evidence_ess, d):
    """``(increment_se, cumulative_se, cumulative_variance)`` of a bridged step (:func:`_bridge_from_path_prior`).

    Its cumulative log-evidence is ``log Z_hat_{1:w-1} + log Z_hat_{w:s}``: the window's evidence is estimated
    afresh (the importance estimate on the path space, variance ``1 / ESS - 1 / N``) from the window's first
    prior ``p_w``, so the cumulative variance continues from the one before step ``w``, not from step ``s - 1``'s
    (the stored increments of the window cancel). ``p_w`` is the initial prior when the window reaches step 1,
    else the mixture over step ``w - 1``'s particles, whose error is the spread of the paths' first states over
    its components (:meth:`GaussianMixture.ancestor_spread`, each particle its own label). The increment,
    ``log Z_hat_{w:s}`` minus the window's stored increments, adds their accumulated variance (the ordinary
    step's formula, with the conflict's ancestor ESS of a few particles, overstates it many times)."""
    variance = 1.0 / evidence_ess - 1.0 / n if np.isfinite(evidence_ess) and evidence_ess > 0 else float("nan")
    first = window[0]
    if isinstance(first.prior, GaussianMixture):
        variance += first.prior.ancestor_spread(cloud.particles[:, :d], cloud.log_weights, None).variance
    cumulative = first.log_evidence_variance + variance
    increment = variance + max(state.log_evidence_variance - first.log_evidence_variance, 0.0)
    return float(np.sqrt(increment)), float(np.sqrt(cumulative)), float(cumulative)


class PathStep:
    """The exact remedy for prior-data conflict: the step assimilated on the path space (a predictive of
    :class:`~seqbayes.predictive.particle.Predictive`, for one step).

    The predictive mixture ``sum_j W_j T(theta | theta_j)`` is exact only where the previous
    posterior's particles are: a posterior that lies several predictive sds out is made of that
    posterior's far tail, which N particles do not hold (docs/prior_data_conflict.md measures it).
    Here the target is the joint posterior of the last ``L`` states (Eq. A2-A3 unrolled),

        p(theta_{w:s} | D^{1:s}) prop. to p_w(theta_w) prod_{t=w}^{s} L_t(theta_t) prod_{t=w+1}^{s} T(theta_t | theta_{t-1}),

    whose marginal in ``theta_s`` is the model's exact posterior (``p_w`` is the initial prior when
    the window reaches step 1). With ``bridge`` (``SamplerConfig.remedy_bridge``, the default) the
    particles are drawn from the path prior ``p_w prod T`` and every likelihood of the window is
    tempered jointly (:meth:`_bridge_weigh`), so that every mode of the path posterior is weighed afresh;
    the stored paths' start (or, where it cannot carry the step, a second bridge) runs as well, each with half
    of the N particles, and the two clouds are pooled into N, each cluster given its importance-sampling share
    of the mass, before the importance sweeps (:meth:`estimate`), because a tempering can weigh a mode wrongly
    once the modes have separated (lose it, or end trapped in a minor one). Without it they start from the
    previous posterior's paths (kept from the last path-space step, or drawn backwards with the exact transition),
    are extended by ``theta_s ~ T(. | theta_{s-1})`` and tempered in ``L_s`` (Eq. A5) only. Either way they are
    moved on the whole path by the scaled rounds (:func:`~seqbayes.moves.schedule.scaled_rounds`, with the kernel
    density as the independence proposal, a local sweep on random path suffixes
    (:class:`~seqbayes.moves.scaled.SuffixMove`) and, in the bridge, redraws of path suffixes from the path prior:
    :meth:`PathPrior.resimulate`), which carry the earlier states into the tails the data call for. The evidence
    increment is Eq. (1) or the importance estimate of :mod:`seqbayes.predictive.evidence` on the path space. Every
    likelihood of the window goes through one memo per dataset, so a move costs one likelihood call per state it
    changes. The record has ``StepInfo.path_steps = L``.

    Parameters
    ----------
    state : SamplerState
        The state before the step (with its window of past steps).
    dataset : object
    mixture : ParticlePredictive
        The step's ordinary predictive (:class:`~seqbayes.predictive.transition.TransitionMixture`): it builds
        the next prior from the path posterior's last states.
    likelihood : ValidatedLikelihood
    bridge : bool
    """

    def __init__(self, state, dataset, mixture, likelihood, bridge: bool):
        problem, config = mixture.problem, mixture.config
        self.state, self.dataset, self.mixture, self.bridge, self.problem = state, dataset, mixture, bridge, problem
        kernel, d = problem.kernel, problem.kernel.dim
        self.window = remedy_window(state.memory.window, config.remedy.lag)
        self.length = length = len(self.window)
        self.path_problem = Problem(problem.prior, kernel, problem.loglike, np.tile(problem.support, (length + 1, 1)),
                                    problem.executor)
        self.path_likelihood = likelihood.of_last_state(d)
        # the bridge's likelihood of every state of the window, each state's value kept: a redraw of a path's suffix
        # from the path prior, or a local move of it, keeps the earlier states, whose likelihoods are not computed
        # again; the stored paths' prior reads the past datasets' through the same memos
        self.window_likelihood = likelihood.over_window([past.dataset for past in self.window] + [dataset], d,
                                                        memo=True)
        self.prior_logpdf = ExactPrior(path_prior_logpdf(self.window, kernel, likelihood, d,
                                                         self.window_likelihood.memos[:-1]))
        self.path_prior = PathPrior(self.window[0].prior, kernel, length + 1, d)  # the bridge's start and redraws
        # the evidence's moves follow the model's d, not the path's (L + 1) d (Moves.scaled)
        moves, importance = config.moves, config.evidence.importance
        self.config = replace(config, moves=replace(moves, scaled=moves.uses_scaled(d)))
        # the path's moves are the scaled rounds (an independence sweep from the kernel density fitted to the stage's
        # particles, then a local sweep), stopped once the particles' whitened travel amounts to an independent
        # draw: a random walk on (L + 1) d dimensions decorrelates only in O(L) sweeps of N (L + 1) calls each. At
        # most as many sweeps as the random walk's minimum before, 4 (L + 1) up to 30 (docs/benchmarks.md, the
        # oscillator's path-space section). With the importance evidence they stop as economy's do (half the
        # travel, 70 % moved; comment-ok: the stopping rule): the stages only carry the cloud to the posterior, where the importance sweeps' 2 (L + 1)
        # exact independence sweeps from the pooled fit decorrelate it; the path's evidence has no such sweeps
        rounds = max(1, min(moves.max_sweeps, 4 * (length + 1)) // 2)
        self.path_config = replace(config, moves=replace(moves, scaled=True, min_sweeps=1, max_sweeps=rounds,
                                                         economy=moves.economy or importance))
        # with the importance evidence the bridge and the stored paths' start are two independent starts of half the
        # particles each, whose union the importance sweeps start from (pooled_start draws N from it): the second
        # start guards the first against a lost or misweighed mode, for which half of N is enough, not a second N
        self.pooled = bridge and importance
        self.start_size = max(config.n_samples // 2, 1) if self.pooled else config.n_samples

    def remedy(self, state, dataset, likelihood, outcome):
        return None

    def weigh(self, state, dataset, likelihood, rng) -> Weighed | Failure:
        moves = MoveTally(step_size=state.step_size)
        return self._bridge_weigh(likelihood, moves, rng) if self.bridge else self._stored_weigh(moves, rng)

    def temper(self, state, dataset, weighed, likelihood, rng) -> Tempered | Failure:
        return self._bridge_temper(weighed, likelihood, rng) if self.bridge else self._stored_temper(weighed, rng)

    def estimate(self, tempered, weighed, likelihood, rng) -> Estimate | Failure:
        other, moves = None, tempered.moves
        if self.pooled:
            # a second cloud of the same target, pooled with the bridge's: the stored paths hold the modes the
            # previous particles held, which the bridge's tempering can lose; where they cannot carry the step,
            # a second bridge, as a bridge's tempering can also end trapped in a minor mode
            second = self._stored_weigh(moves, rng)
            if not isinstance(second, Failure):
                second = self._stored_temper(second, rng)
            if isinstance(second, Failure):
                second = self._bridge_weigh(likelihood, moves, rng)
                if not isinstance(second, Failure):
                    second = self._bridge_temper(second, likelihood, rng)
            if isinstance(second, Failure):
                return second
            other, moves = second.cloud, second.moves
        # at least 2 (L + 1) independence sweeps per fit, as the moves: fewer leave a transient through the
        # path's earlier states; every sweep's draws enter the estimate, whose fit on the path space has an ESS
        # below the refit threshold per sweep where all of them together are well above it. Four times the refits:
        # where both starts missed the posterior (small N, a drift towards the box's edge) each refit's sweeps carry
        # the cloud further towards it, and five left the estimate tens of nats short (docs/benchmarks.md)
        config, evidence = self.config, self.config.evidence
        if evidence.importance:
            evidence = replace(evidence, sweeps=max(evidence.sweeps, 2 * (self.length + 1)),
                               max_refits=4 * evidence.max_refits)
        n_found = weighed.n_found * config.n_samples / self.start_size  # in draws per N, as the restart's threshold
        cloud, log_increment, evidence_ess, n_independent = evidence.estimate(
            tempered.cloud, tempered.log_z, n_found, self.path_problem, config, self.path_likelihood,
            self.prior_logpdf, rng, other, pool_sweeps=True)
        return Estimate(cloud, log_increment, evidence_ess, n_independent,
                        evidence.importance and log_increment != tempered.log_z, moves)

    def propagate(self, state, weighed, tempered, estimate, dataset, likelihood, rng) -> Outcome:
        config, kernel, d, n = self.config, self.problem.kernel, self.problem.kernel.dim, self.config.n_samples
        cloud, log_increment = estimate.cloud, estimate.log_increment
        log_evidence = float(state.log_evidence + log_increment)
        posterior = cloud.particles[:, -d:]
        marginal = Cloud(posterior, cloud.log_weights, cloud.components)
        density, predictive, _ = self.mixture.next_prior(state, marginal, dataset, log_increment, log_evidence, rng)
        conflict = step_conflict(state.particles, state.log_weights, posterior, cloud.log_weights,
                                 self.problem.support)
        _, mass = ancestor_mass(kernel, posterior, state.posterior, state.posterior_log_weights,
                                later_log_weights=cloud.log_weights)
        spread = mass_spread(state, mass)
        if self.bridge:
            increment_se, evidence_se, evidence_variance = _bridged_standard_errors(
                state, self.window, cloud, n, estimate.evidence_ess if estimate.importance else float("nan"), d)
        else:
            ancestor_variance, covariance = ancestor_terms(state, spread)
            increment_se, evidence_se, evidence_variance = step_standard_errors(
                state.log_evidence_variance, n, estimate.importance, estimate.evidence_ess,
                np.exp(weighed.cloud.log_weights), cloud.log_weights, len(tempered.temperatures), tempered.resampled,
                ancestor_variance, self.mixture.method, covariance)
        moves = estimate.moves
        past = PastStep(kept_copy(dataset), state.prior, posterior, cloud.log_weights, float(log_increment),
                        variance_before(state), self.length + 1)
        window = remedy_window(state.memory.window + (past,), config.remedy.lag)
        new_state = SamplerState(step=state.step + 1, particles=predictive, log_weights=cloud.log_weights,
                                 prior=density, log_evidence=log_evidence,
                                 step_size=float(config.moves.step_size_after(moves.step_size, state.step_size)),
                                 posterior=posterior, posterior_log_weights=cloud.log_weights,
                                 memory=RemedyMemory(window,
                                                     cloud.particles.reshape(n, self.length + 1, d)[:, -len(window):],
                                                     lineage_after(state, cloud.labels)),
                                 log_evidence_variance=evidence_variance,
                                 previous_prior=state.prior if isinstance(state.prior, GaussianMixture) else None)
        records = dict(evidence=EvidenceInfo(float(tempered.log_z), estimate.evidence_ess, estimate.n_independent,
                                             increment_se, evidence_se),
                       conflict=ConflictInfo(float(conflict.max()), int(conflict.argmax()), spread.ess, self.length + 1),
                       # the mixture step's terms, with the ancestors' influence on an exact (not mixture) target
                       jumps=JumpInfo(**jump_fields(kernel, state, replace(cloud, particles=posterior),
                                                    mixture_target=False)))
        step_size = float(config.moves.step_size_after(moves.step_size, float("nan")))
        return Outcome(new_state, posterior, cloud.log_weights, predictive, posterior, log_evidence, step_size, records)

    def _bridge_weigh(self, likelihood, moves, rng) -> Weighed | Failure:
        """The bridge's start: draws of the window's path prior ``pi_0 = p_w prod T`` (``theta_w ~ p_w``, then the
        kernel), restricted to the parameter space by rejection, whose acceptance fraction enters the evidence as
        in :func:`~seqbayes.predictive.particle.restricted_draws`, weighed by every likelihood of the window.

        The path-space target (``w`` the window's first step, ``s`` this one),

            pi(theta_{w:s}) = p_w(theta_w) prod_{t=w+1}^{s} T(theta_t | theta_{t-1}) prod_{t=w}^{s} L_t(theta_t) / Z_{w:s},
            Z_{w:s} = p(D^{w:s} | D^{1:w-1}) = prod_{t=w}^{s} Z_t,

        is bridged from ``pi_0`` through ``pi_beta prop. to pi_0 [prod_{t=w}^{s} L_t(theta_t)]^beta`` by
        :meth:`_bridge_temper`. Every choice of which dataset a path gives up is weighed afresh, not inherited
        from the previous steps' particles, so a mode of ``pi`` whose earlier states the earlier data had ruled
        out given the stored paths is reached.
        """
        d, n = self.problem.kernel.dim, self.start_size
        path_prior, window_likelihood = self.path_prior, self.window_likelihood
        start = restricted_draws(path_prior, self.path_problem.support, n, rng, likelihood.step, window_likelihood,
                                 max_rounds=100 * self.config.n_samples // n)  # a half start is not starved sooner
        if isinstance(start, Failure):
            return start
        walkers, loglike, log_restricted_mass, n_found, labels = start
        components = np.column_stack([loglike, path_prior.logpdf(walkers)])
        cloud = Cloud(walkers, np.full(n, -np.log(n)), components, labels)  # labels: the path-prior draws
        return Weighed(cloud, ExactPrior(path_prior.logpdf), moves, log_restricted_mass, n_found)

    def _bridge_temper(self, weighed, likelihood, rng) -> Tempered | Failure:
        """The bridge's stages (Eq. A5, the moves on the whole path). The stages' product of mean weights
        (Eq. 1) estimates ``log Z_{w:s} = log m + sum_k log mean_i w_i^(k)``; the step's increment is that
        minus the window's stored increments ``sum_{t=w}^{s-1} log Z_t`` (the normaliser of
        :func:`path_prior_logpdf`), so the cumulative evidence becomes the window's own estimate. The
        components return to those of the stored paths' start, ``(log L_s, log pi_0 + sum_{t<s} log L_t -
        sum_{t=w}^{s-1} log Z_t)``, for the importance estimate."""
        d = self.problem.kernel.dim
        # every stage keeps tempering_ess of the ESS: the tempering_threshold shortcut to beta = 1 lets a cloud
        # gathered in a narrow minor mode of an early stage finish there
        config = replace(self.path_config, tempering=self.path_config.tempering.without_shortcut())
        # the early stages' targets are thin ridges of the path prior, its dominant factor: redraws of path suffixes
        # from it are accepted with (L* / L)^beta where the kernel density and the local move accept ~nothing
        tempered = temper_stages(weighed.cloud, weighed.moves, ResampleMove(
            self.path_problem, config, self.window_likelihood, weighed.prior_logpdf, True, False, rng,
            PathTarget(kernel_density=True, prior_moves=self.path_prior, path_states=self.length + 1)))
        if isinstance(tempered, Failure):
            return tempered
        cloud = tempered.cloud
        states = cloud.particles.reshape(cloud.particles.shape[0], self.length + 1, d)
        # read from the memo, where the stages left every final state's value; the rest is a difference
        last = likelihood.add_along_paths(np.zeros(states.shape[0]), states[:, -1:], [self.dataset],
                                          self.window_likelihood.memos[-1:])
        normaliser = sum(past.log_evidence_increment for past in self.window)
        cloud = Cloud(cloud.particles, cloud.log_weights,
                      np.column_stack([last, cloud.components[:, 1] + (cloud.components[:, 0] - last) - normaliser]),
                      cloud.labels)
        return replace(tempered, cloud=cloud, log_z=tempered.log_z + weighed.log_restricted_mass - normaliser)

    def _stored_weigh(self, moves, rng) -> Weighed | Failure:
        """The regular path-space start: the previous posterior's paths (:func:`_start_paths`) extended by
        ``theta_s ~ T(. | theta_{s-1})`` and weighed by ``L_s``; as :func:`~seqbayes.predictive.particle.weigh`, a
        restart from the path predictive restricted to ``{inside, L > 0}`` when few of them can carry the step.
        Components ``(log L_s, log path prior)``. With fewer particles than the posterior's (:attr:`start_size`),
        the paths are resampled to them."""
        state, kernel, config = self.state, self.problem.kernel, self.config
        d, n, support = kernel.dim, self.start_size, self.path_problem.support
        paths = _start_paths(state, kernel, self.length, rng)
        log_weights, labels = state.posterior_log_weights, np.arange(paths.shape[0])
        if n < paths.shape[0]:
            labels = resample(config.tempering.scheme, np.exp(log_weights - logsumexp(log_weights)), rng, n)
            paths, log_weights = paths[labels], np.full(n, -np.log(n))
        walkers = np.concatenate([paths, kernel.propagate(paths[:, -1], rng)[:, None]], axis=1).reshape(n, -1)
        log_restricted_mass, n_found = 0.0, n
        loglike = np.full(n, -np.inf)
        inside = inside_space(walkers, support)
        loglike[inside] = self.path_likelihood.loglike(walkers[inside])
        valid = np.isfinite(loglike)
        if not valid.all() and (not inside.all() or valid.sum() < config.tempering.min_valid_fraction * n):
            extended = _PathPredictive(paths.reshape(n, -1), log_weights, kernel, d)
            restart = restricted_draws(extended, support, n, rng, self.path_likelihood.step, self.path_likelihood)
            if isinstance(restart, Failure):
                return restart
            walkers, loglike, log_restricted_mass, n_found, labels = restart
            log_weights = np.full(n, -np.log(n))
        components = np.column_stack([loglike, np.full(n, -np.inf)])
        carried = np.isfinite(loglike)
        components[carried, 1] = self.prior_logpdf(walkers[carried])
        return Weighed(Cloud(walkers, log_weights, components, labels), self.prior_logpdf, moves,
                       log_restricted_mass, n_found)

    def _stored_temper(self, weighed, rng) -> Tempered | Failure:
        """The stored paths tempered in ``L_s`` (:func:`~seqbayes.predictive.particle.temper_stages`)."""
        tempered = temper_stages(weighed.cloud, weighed.moves, ResampleMove(
            self.path_problem, self.path_config, self.path_likelihood, weighed.prior_logpdf, True, False, rng,
            PathTarget(kernel_density=True, path_states=self.length + 1)))
        if isinstance(tempered, Failure):
            return tempered
        return replace(tempered, log_z=tempered.log_z + weighed.log_restricted_mass)
