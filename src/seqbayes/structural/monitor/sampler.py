"""IBIS over the monitor's static parameters: each particle carries its exact per-mode filters and change bank.

The target after chunk ``K`` is ``p(u) p(data | u)`` with ``p(data | u) = p0(data | u) [P(no change) + sum_d
P(d) BF_d(u)]`` (:mod:`~seqbayes.structural.monitor.change`): the no-damage filters' likelihood times the change's
factor, exact given the static parameters ``u`` (:mod:`~seqbayes.structural.monitor.law`). A new dataset's chunks
advance every particle's filters and bank (:func:`advance`: a few operations per chunk); the increments of the log
target are then taken in by the one tempering loop (:func:`seqbayes.tempering.temper`), which resamples and moves
the particles whenever the ESS would fall below ``ess * N``. A move is a random-walk Metropolis sweep in ``u`` with
the particles' covariance; a proposal is weighed by a pass over the whole history (:func:`history_pass`: the
filters forward, the bank by one backward recursion), so a move costs one pass per sweep however many candidate
days the bank holds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ...core.tempering import TargetESS, between_stages, temper
from ...moves.base import metropolis_accept
from ...moves.scaled import FittedGaussian
from ...weights import normalise, resample
from .change import Bank, backward_bank, bank_chunk, change_posterior, empty_bank
from .daily_filter import FilterState, chunk_statistics, chunk_update, initial_state, new_day
from .law import design, lagged

__all__ = ["Static", "Cache", "Particles", "MonitorState", "start", "advance", "history_pass", "assimilate",
           "StepInfo", "prior_state", "total_loglike"]

#: Floor of a log-likelihood increment (the tempering needs finite increments).
_FLOOR = -1e250


@dataclass(frozen=True, eq=False)
class Static:
    """The static parameters of ``N`` particles in natural units."""

    tau_hours: np.ndarray
    knee_location: np.ndarray
    knee_width: np.ndarray
    level_var: np.ndarray
    day_var: np.ndarray
    noise_var: np.ndarray

    @classmethod
    def of(cls, u: np.ndarray) -> "Static":
        u = np.atleast_2d(u)
        return cls(np.exp(u[:, 0]), u[:, 1], np.exp(u[:, 2]), np.exp(2 * u[:, 3]), np.exp(2 * u[:, 4]),
                   np.exp(2 * u[:, 5:]))


@dataclass(frozen=True, eq=False)
class Cache:
    """Per particle: the filters after the last chunk, the structure temperature at the last set, the change
    bank and the no-damage log-likelihood so far."""

    filters: FilterState
    structure_temperature: np.ndarray
    bank: Bank
    loglike0: np.ndarray

    def take(self, index) -> "Cache":
        return Cache(self.filters.take(index), self.structure_temperature[index], self.bank.take(index),
                     self.loglike0[index])


def _join(caches) -> Cache:
    return Cache(FilterState(np.concatenate([c.filters.mean for c in caches]),
                             np.concatenate([c.filters.cov for c in caches])),
                 np.concatenate([c.structure_temperature for c in caches]),
                 Bank(np.concatenate([c.bank.A for c in caches]), np.concatenate([c.bank.B for c in caches]),
                      np.concatenate([c.bank.delta for c in caches]), caches[0].bank.days),
                 np.concatenate([c.loglike0 for c in caches]))


def _put(cache: Cache, index, new: Cache) -> Cache:
    """``cache`` with the particles ``index`` replaced by ``new``'s."""
    def put(a, b):
        a = a.copy()
        a[index] = b
        return a
    f = FilterState(put(cache.filters.mean, new.filters.mean), put(cache.filters.cov, new.filters.cov))
    bank = Bank(put(cache.bank.A, new.bank.A), put(cache.bank.B, new.bank.B), put(cache.bank.delta, new.bank.delta),
                cache.bank.days)
    return Cache(f, put(cache.structure_temperature, new.structure_temperature), bank,
                 put(cache.loglike0, new.loglike0))


@dataclass(frozen=True, eq=False)
class Particles:
    """What the tempering loop hands to the moves: coordinates ``u (N, d)``, the caches, the log target's
    likelihood before the step's data (``loglike_previous``) and after (``loglike``)."""

    u: np.ndarray
    cache: Cache
    loglike_previous: np.ndarray
    loglike: np.ndarray

    def take(self, index) -> "Particles":
        return Particles(self.u[index], self.cache.take(index), self.loglike_previous[index], self.loglike[index])


@dataclass(frozen=True, eq=False)
class MonitorState:
    """The sampler after the last chunk: the particles, their log-weights and the log-evidence so far."""

    particles: Particles
    log_weights: np.ndarray
    log_evidence: float

    @property
    def weights(self) -> np.ndarray:
        return np.exp(normalise(self.log_weights))


@dataclass(frozen=True)
class StepInfo:
    """What one assimilation did: its chunks, tempering stages, sweeps (passes over the history), acceptance,
    the ESS after it, and its work: ``filter_updates``, the per-particle chunk updates of the filters (the new
    chunks for every particle, then each sweep's pass over the whole history for every proposal inside the
    prior's box)."""

    n_chunks: int
    n_stages: int
    n_sweeps: int
    acceptance: float
    ess: float
    log_evidence_increment: float
    filter_updates: int = 0


# ------------------------------------------------------------------------------------ the likelihood
def _chunk_terms(model, static: Static, history, k: int, ts):
    """The regressors and information of chunk ``k`` for particles with ``static`` and lagged temperatures
    ``ts (N, S_k)``."""
    rows = history.rows(k)
    h = design(ts, static.knee_location, static.knee_width, history.covariates[rows],
               model.prior.reference_temperature, model.covariate_reference)
    return chunk_statistics(h, history.y[rows], history.oma_var[rows], static.noise_var)


def start(model, u: np.ndarray) -> Cache:
    """The caches of particles ``u`` before any set."""
    static = Static.of(u)
    n = u.shape[0]
    filters = initial_state(n, model.n_modes, model.prior.level0_sd, static.day_var,
                            model.prior.static_sds(len(model.covariates)))
    p = filters.mean.shape[-1]
    return Cache(filters, np.full(n, np.nan), empty_bank(n, model.n_modes, p), np.zeros(n))


def advance(model, u: np.ndarray, cache: Cache, history, first: int) -> Cache:
    """The caches after chunks ``first ..`` of ``history`` (those before are in ``cache``), chunk by chunk."""
    static = Static.of(u)
    filters, bank, loglike0, ts_last = cache.filters, cache.bank, cache.loglike0.copy(), cache.structure_temperature
    for k in range(first, history.n_chunks):
        rows = history.rows(k)
        prev = None if rows.start == 0 else (ts_last, history.times[rows.start - 1])
        ts = lagged(history.times[rows], history.air[rows], static.tau_hours, *(prev or (None, None)))
        if history.new_day(k):
            filters = new_day(filters, history.days_passed(k), static.level_var, static.day_var)
        filters, loglike, g_inv, beta, omega = chunk_update(filters, *_chunk_terms(model, static, history, k, ts))
        loglike0 = loglike0 + loglike.sum(axis=1)
        candidate = history.candidate(k)
        bank = bank_chunk(bank, g_inv, beta, omega, history.new_day(k), None if candidate < 0 else candidate)
        ts_last = ts[:, -1]
    return Cache(filters, ts_last, bank, loglike0)


def total_loglike(model, cache: Cache, last_day: int, hazard: float) -> np.ndarray:
    """``log p(data | u) (N,)``: the no-damage log-likelihood plus the change's log factor."""
    return cache.loglike0 + change_posterior(cache.bank, model.pattern, last_day, hazard).log_bracket


def history_pass(model, u: np.ndarray, history, cut: int, hazard: float, block: int = 128):
    """``(loglike at chunk cut, loglike at the end, caches at the end)`` of particles ``u`` over the whole
    history, in blocks of ``block`` particles (the filters forward, the banks by :func:`backward_bank`)."""
    out_cut, out_end, caches = [], [], []
    for start_row in range(0, u.shape[0], block):
        part = u[start_row:start_row + block]
        static = Static.of(part)
        ts_all = lagged(history.times, history.air, static.tau_hours)
        filters = start(model, part).filters
        terms = []
        loglike0 = np.zeros(part.shape[0])
        loglike0_cut = loglike0
        for k in range(history.n_chunks):
            if k == cut:
                loglike0_cut = loglike0.copy()
            rows = history.rows(k)
            if history.new_day(k):
                filters = new_day(filters, history.days_passed(k), static.level_var, static.day_var)
            filters, loglike, g_inv, beta, omega = chunk_update(
                filters, *_chunk_terms(model, static, history, k, ts_all[:, rows]))
            loglike0 = loglike0 + loglike.sum(axis=1)
            terms.append((g_inv, beta, omega))
        if cut == history.n_chunks:
            loglike0_cut = loglike0
        g_inv, beta, omega = (np.stack([t[i] for t in terms]) for i in range(3))
        new = np.array([history.new_day(k) for k in range(history.n_chunks)])
        candidates = history.candidates()
        bank_end = backward_bank(g_inv, beta, omega, new, candidates, history.n_chunks)
        cache = Cache(filters, ts_all[:, -1], bank_end, loglike0)
        out_end.append(total_loglike(model, cache, int(history.chunk_day[-1]), hazard))
        if cut == history.n_chunks:
            out_cut.append(out_end[-1])
        elif cut == 0:
            out_cut.append(np.zeros(part.shape[0]))
        else:
            bank_cut = backward_bank(g_inv, beta, omega, new, candidates, cut)
            out_cut.append(total_loglike(model, Cache(filters, ts_all[:, -1], bank_cut, loglike0_cut),
                                         int(history.chunk_day[cut - 1]), hazard))
        caches.append(cache)
    return np.concatenate(out_cut), np.concatenate(out_end), _join(caches)


# ------------------------------------------------------------------------------------ the sampler
def prior_state(model, settings, rng: np.random.Generator) -> MonitorState:
    """Particles from the prior, before any data."""
    u = model.prior.sample(settings.n_particles, model.n_modes, rng)
    zeros = np.zeros(u.shape[0])
    return MonitorState(Particles(u, start(model, u), zeros, zeros), zeros, 0.0)


def _finite(x):
    return np.maximum(np.nan_to_num(x, nan=_FLOOR, neginf=_FLOOR), _FLOOR)


def _proposals(move: FittedGaussian, walk: FittedGaussian, u, rng):
    """Half the walkers (at random) draw afresh from the fitted Gaussian ``move`` (an independence proposal),
    the others step by ``walk`` (the same covariance scaled by ``2.38^2 / d``): proposals and log-Hastings terms."""
    independent = rng.random(u.shape[0]) < 0.5
    fresh = move.sample(u.shape[0], rng)
    steps = walk.sample(u.shape[0], rng)
    proposal = np.where(independent[:, None], fresh, u + steps)
    log_hastings = np.where(independent, move.logpdf(u) - move.logpdf(proposal), 0.0)
    return proposal, log_hastings


def _fitted(u):
    """The independence and random-walk proposals fitted to equally weighted particles ``u (N, d)``."""
    d = u.shape[1]
    cov = np.cov(u, rowvar=False).reshape(d, d)
    return FittedGaussian(u.mean(axis=0), cov), FittedGaussian(np.zeros(d), cov * (2.38 ** 2 / d))


def assimilate(state: MonitorState, model, settings, history, first: int, rng: np.random.Generator):
    """Take in chunks ``first ..`` of ``history`` (the new dataset's): returns ``(state, StepInfo)``."""
    parts = state.particles
    last_day = int(history.chunk_day[-1])
    cache = advance(model, parts.u, parts.cache, history, first)
    loglike = total_loglike(model, cache, last_day, settings.hazard)
    parts = Particles(parts.u, cache, parts.loglike, loglike)
    box = model.prior.box(model.n_modes)
    dim = box.shape[0]
    tally = {"stages": 0, "sweeps": 0, "proposed": 0, "accepted": 0, "passes": 0}

    def resample_move(log_weights, increments, beta, particles):
        tally["stages"] += 1
        index = resample("systematic", np.exp(normalise(log_weights)), rng)
        particles = particles.take(index)
        u = particles.u
        log_prior = model.prior.logpdf(u, model.n_modes)
        target = log_prior + particles.loglike_previous + beta * (particles.loglike - particles.loglike_previous)
        begin = u.copy()
        move, walk = _fitted(u)           # fitted once per stage: the kernel does not depend on the walkers
        for sweep in range(settings.max_sweeps):
            proposal, log_hastings = _proposals(move, walk, u, rng)
            inside = np.all((proposal > box[:, 0]) & (proposal < box[:, 1]), axis=1)
            new_target = np.full(u.shape[0], -np.inf)
            index_in = np.flatnonzero(inside)
            if index_in.size:
                prev, end, new_cache = history_pass(model, proposal[index_in], history, first, settings.hazard,
                                                    settings.chunk_particles)
                new_target[index_in] = (model.prior.logpdf(proposal[index_in], model.n_modes) + prev
                                        + beta * (end - prev))
                tally["passes"] += index_in.size * history.n_chunks
            accept = metropolis_accept(target, new_target, log_hastings, rng)
            tally["sweeps"] += 1
            tally["proposed"] += u.shape[0]
            tally["accepted"] += int(accept.sum())
            if accept.any():
                pos = np.flatnonzero(accept)
                local = np.searchsorted(index_in, pos)
                u = u.copy()
                u[pos] = proposal[pos]
                target = np.where(accept, new_target, target)
                lp, le = particles.loglike_previous.copy(), particles.loglike.copy()
                lp[pos], le[pos] = prev[local], end[local]
                particles = Particles(u, _put(particles.cache, pos, new_cache.take(local)), lp, le)
            moved = np.mean(np.any(u != begin, axis=1))
            if sweep + 1 >= settings.min_sweeps and moved >= settings.moved_fraction:
                break
        return _finite(particles.loglike - particles.loglike_previous), particles

    increments = _finite(parts.loglike - parts.loglike_previous)
    annealed = temper(parts, increments, state.log_weights, TargetESS(settings.ess * settings.n_particles),
                      between_stages(resample_move), log_z=state.log_evidence)
    log_weights, parts, log_evidence = normalise(annealed.log_weights), annealed.particles, annealed.log_z
    parts = replace(parts, loglike_previous=parts.loglike)
    new = MonitorState(parts, log_weights, float(log_evidence))
    w = new.weights
    acceptance = tally["accepted"] / tally["proposed"] if tally["proposed"] else float("nan")
    info = StepInfo(history.n_chunks - first, tally["stages"], tally["sweeps"], acceptance, float(1.0 / (w @ w)),
                    float(log_evidence - state.log_evidence),
                    int(parts.u.shape[0] * (history.n_chunks - first) + tally["passes"]))
    return new, info
