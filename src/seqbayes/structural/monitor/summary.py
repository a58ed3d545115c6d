"""What the monitor reports after a day, from the weighted particles: P(damage), where (when a model gives a
location), how large and since when, and the environmental law it has learned.

Every number is an average over the particles of an exact per-particle answer: the change's posterior over
element (or modes), day and size given the static parameters (:mod:`~seqbayes.structural.monitor.change`), and
the per-mode coefficients' Gaussian posterior given no damage (the filters of
:mod:`~seqbayes.structural.monitor.daily_filter`). Intervals are central 95 % ones of those mixtures.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
from scipy.special import log_ndtr, logsumexp, ndtr

from ...results import weighted_quantile
from .change import ElementLoss, change_posterior, log_subtract, log_day_prior
from .sampler import Static

__all__ = ["Estimate", "DamageSummary", "EnvironmentSummary", "damage_summary", "environment_summary",
           "mixture_quantiles", "COEFFICIENTS"]

#: The per-mode coefficients reported (after the level and the day effect), before the covariates.
COEFFICIENTS = ("temperature", "knee")
_LEVEL = 0.95


@dataclass(frozen=True)
class Estimate:
    """A posterior mean and central 95 % interval."""

    mean: float
    lower: float
    upper: float


@dataclass(frozen=True)
class DamageSummary:
    """The change's posterior after a day.

    Attributes
    ----------
    p_damage : float
        ``P(a loss by the end of the day | data)``.
    classes : tuple of str
        The elements (with a structural model) or the modes (without).
    class_probabilities : tuple of float
        ``P(element j | damage)``, or ``P(mode i lost | damage)`` (the modes' do not sum to 1).
    location : str or None
        The most probable element; None without a structural model.
    size : Estimate or None
        The loss in the most probable class given damage there: the stiffness lost (a fraction), or the mode's
        relative frequency drop. None when ``p_damage`` is 0.
    day : Estimate or None
        The calendar day the loss began (0: the first monitored day).
    day_mode : int or None
        The most probable first day.
    location_index : int
        1-based index of ``location`` in ``classes`` (0: none).
    """

    p_damage: float
    classes: tuple
    class_probabilities: tuple
    location: str | None
    size: Estimate | None
    day: Estimate | None
    day_mode: int | None
    location_index: int = 0


@dataclass(frozen=True)
class EnvironmentSummary:
    """The learned environmental law: the static parameters (``thermal_lag_h``, ``knee_location``, ``knee_width``,
    ``discrepancy_sd_per_day``, ``day_effect_sd``, ``noise_sd`` per mode) and each mode's coefficients given no
    damage (``temperature`` and ``knee`` in log-frequency per degC, then the covariates per unit), with the
    posterior probability of a thermal lag over one hour."""

    static: dict
    coefficients: dict
    p_lag: float


def mixture_quantiles(weights, means, sds, probs, lower_bound: float = -np.inf, iterations: int = 80) -> np.ndarray:
    """Quantiles of ``sum_k w_k N(mean_k, sd_k^2)`` truncated each to ``>= lower_bound``, by bisection."""
    w = np.asarray(weights, dtype=float).reshape(-1)
    mu = np.asarray(means, dtype=float).reshape(-1)
    sd = np.maximum(np.asarray(sds, dtype=float).reshape(-1), 1e-300)
    keep = w > 1e-12 * w.max()
    w, mu, sd = w[keep] / w[keep].sum(), mu[keep], sd[keep]
    floor = ndtr((lower_bound - mu) / sd) if np.isfinite(lower_bound) else np.zeros_like(mu)
    mass = 1.0 - floor

    def cdf(x):
        return np.sum(w * (ndtr((x - mu) / sd) - floor) / np.maximum(mass, 1e-300))

    out = []
    lo0 = max(lower_bound, float(np.min(mu - 12 * sd)))
    hi0 = float(np.max(mu + 12 * sd))
    for q in np.atleast_1d(probs):
        lo, hi = lo0, max(hi0, lo0 + 1e-300)
        for _ in range(iterations):
            mid = 0.5 * (lo + hi)
            if cdf(mid) < q:
                lo = mid
            else:
                hi = mid
        out.append(0.5 * (lo + hi))
    return np.array(out)


def _exp_mean(mu, sd, a):
    """``E[exp(-m)]`` for ``m ~ N(mu, sd^2)`` truncated to ``>= a``."""
    return np.exp(-mu + 0.5 * sd * sd + log_ndtr((mu - sd * sd - a) / sd) - log_ndtr((mu - a) / sd))


def damage_summary(state, model, settings, last_day: int) -> DamageSummary:
    """The change's posterior from the particles' banks (:class:`DamageSummary`)."""
    parts = state.particles
    bank = parts.cache.bank
    pattern = model.pattern
    classes = tuple(pattern.names)
    none = DamageSummary(0.0, classes, tuple([0.0] * len(classes)), None, None, None, None)
    if bank.days.size == 0:
        return none
    posterior = change_posterior(bank, pattern, last_day, settings.hazard)
    log_w = np.log(np.maximum(state.weights, 1e-300))
    log_prior, _ = log_day_prior(bank.days, last_day, settings.hazard)
    log_bf, mean, sd = pattern.log_terms(bank.A, bank.B)                       # (N, J, C)
    base = log_w[:, None] + log_prior[None, :] - posterior.log_bracket[:, None]   # (N, C)
    minimum = pattern.prior.minimum
    if isinstance(pattern, ElementLoss):
        joint = base[:, None, :] + log_bf - math.log(pattern.n_classes)          # log P(n, j, c | data)
        log_p = logsumexp(joint)
        if not np.isfinite(log_p):
            return none
        post = np.exp(joint - log_p)
        class_p = post.sum(axis=(0, 2))
        best = int(np.argmax(class_p))
        size_w = post[:, best, :].ravel()
        size_mu, size_sd = mean[:, best, :].ravel(), sd[:, best, :].ravel()
        day_p = post.sum(axis=(0, 1))
    else:
        combined = pattern.log_combined(bank.A, bank.B)                            # (N, C)
        joint = base + combined
        log_p = logsumexp(joint)
        if not np.isfinite(log_p):
            return none
        post = np.exp(joint - log_p)                                             # P(n, c | damage)
        p = pattern.probability
        each = np.logaddexp(math.log1p(-p), math.log(p) + log_bf)                # (N, n, C)
        lost = math.log(p) + log_bf - each                                       # log P(i lost | subsets, n, c)
        total = each.sum(axis=1)
        with np.errstate(divide="ignore"):
            at_least_one = log_subtract(total, pattern.n_modes * math.log1p(-p))   # log(T - (1 - p)^n)
        # P(i lost | at least one lost, n, c), at most 1 where T - (1 - p)^n underflows (those weigh nothing)
        class_given = np.exp(np.minimum(lost + (total - at_least_one)[:, None, :], 0.0))
        class_p = np.einsum("nc,nic->i", post, class_given)
        best = int(np.argmax(class_p))
        size_w = (post * class_given[:, best, :]).ravel()
        size_mu, size_sd = mean[:, best, :].ravel(), sd[:, best, :].ravel()
        day_p = post.sum(axis=0)
    p_damage = float(np.exp(log_p))
    if size_w.sum() <= 0:
        return none
    keep = size_w > 1e-10 * size_w.max()
    sw, smu, ssd = size_w[keep] / size_w[keep].sum(), size_mu[keep], size_sd[keep]
    m_lo, m_hi = mixture_quantiles(sw, smu, ssd, [(1 - _LEVEL) / 2, (1 + _LEVEL) / 2], lower_bound=minimum)
    # the stiffness fraction lost (or a mode's relative frequency drop): 1 - exp(-m)
    size = Estimate(float(1 - sw @ _exp_mean(smu, ssd, minimum)), float(-math.expm1(-m_lo)),
                    float(-math.expm1(-m_hi)))
    days = bank.days.astype(float)
    day_p = day_p / day_p.sum()
    cdf = np.cumsum(day_p)
    lower = days[min(int(np.searchsorted(cdf, (1 - _LEVEL) / 2)), days.size - 1)]
    upper = days[min(int(np.searchsorted(cdf, (1 + _LEVEL) / 2)), days.size - 1)]
    location = classes[best] if isinstance(pattern, ElementLoss) else None
    return DamageSummary(p_damage, classes, tuple(float(c) for c in class_p), location, size,
                         Estimate(float(day_p @ days), float(lower), float(upper)), int(days[int(np.argmax(day_p))]),
                         best + 1 if location is not None else 0)


def _weighted_estimate(values, weights) -> Estimate:
    with np.errstate(divide="ignore"):
        q = weighted_quantile(values[:, None], np.log(weights), [(1 - _LEVEL) / 2, (1 + _LEVEL) / 2])
    return Estimate(float(weights @ values), float(q[0, 0]), float(q[1, 0]))


def environment_summary(state, model) -> EnvironmentSummary:
    """The learned law (:class:`EnvironmentSummary`)."""
    parts = state.particles
    w = state.weights
    static = Static.of(parts.u)
    values = {"thermal_lag_h": static.tau_hours, "knee_location": static.knee_location,
              "knee_width": static.knee_width, "discrepancy_sd_per_day": np.sqrt(static.level_var),
              "day_effect_sd": np.sqrt(static.day_var)}
    out = {name: _weighted_estimate(v, w) for name, v in values.items()}
    for i in range(model.n_modes):
        out[f"noise_sd_{i + 1}"] = _weighted_estimate(np.sqrt(static.noise_var[:, i]), w)
    names = COEFFICIENTS + model.covariates
    mean, cov = parts.cache.filters.mean, parts.cache.filters.cov
    coefficients = {}
    for i in range(model.n_modes):
        for j, name in enumerate(names):
            mu, sd = mean[:, i, 2 + j], np.sqrt(np.maximum(cov[:, i, 2 + j, 2 + j], 0.0))
            lo, hi = mixture_quantiles(w, mu, sd, [(1 - _LEVEL) / 2, (1 + _LEVEL) / 2])
            coefficients[f"{name}_{i + 1}"] = Estimate(float(w @ mu), float(lo), float(hi))
    return EnvironmentSummary(out, coefficients, float(w @ (static.tau_hours > 1.0)))


def as_dict(record) -> dict:
    """A summary record as plain JSON values."""
    return asdict(record)
