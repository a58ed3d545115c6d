"""What an SG-EnMCMC run reports: the result record and the weighted summaries of its histories.

Per step the identifiers record the weighted mean, variance, quantiles and most probable value
(MPV) of the particles. The particles stay fixed between two resamplings (a *stage*), so the
weights of a stage's steps are buffered in :class:`StageHistories` and summarised together (one
sort per stage, :func:`stage_quantiles` and :func:`stage_modes`); :func:`weighted_quantiles` and
:func:`weighted_mode` are the one-weight-vector forms.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..results import weighted_quantile

__all__ = ["SGEnMCMCResult", "StageHistories", "convergence_step", "weighted_quantiles",
           "weighted_mode", "stage_quantiles", "stage_modes"]


@dataclass(frozen=True)
class SGEnMCMCResult:
    """Histories of an SG-EnMCMC run over ``T`` steps with ``N`` members, ``d`` parameters.

    Attributes
    ----------
    theta_mean, theta_var, theta_mpv : (T, d) arrays
        Weighted mean, variance and most probable value (mode of a
        per-parameter histogram of the weighted members) after step ``k``.
    theta_quantiles : (T, 3, d) array
        Weighted 2.5 %, 50 % and 97.5 % quantiles.
    ess : (T,) array
        Effective sample size after weighting at step ``k`` (before resampling).
    resampled : (T,) bool array
    log_evidence_increments : (T,) array
        ``log sum_i w_hat_i exp(l_i)``; their sum estimates ``log p(y | model)``.
    state_mean : (T, m) array
        Weighted mean of the updated states.
    drift_mean, drift_std : (T, n) arrays
        Inter-storey drifts of the updated states (mean and spread).
    final_theta : (N, d) array
        The final members (after a last resampling, equally weighted).
    final_log_weights : (N,) array
    elapsed : float
        Wall-clock seconds of the run.
    names : tuple of str
    sampler : str
        ``"resample-move"`` or ``"paper"``.
    move_steps, move_exponents, move_acceptance, move_sweeps : (E,) arrays
        Resample-move only: for each of the ``E`` resample-move events, the
        step, the tempering exponent ``phi`` of that step's data it targeted,
        the mean acceptance rate per sweep and the number of sweeps.
    surrogate : dict
        With ``surrogate="auto"``: the transition chosen and why
        (:meth:`seqbayes.structural.surrogate.SurrogateChoice.as_dict`); empty otherwise.
    """

    theta_mean: np.ndarray
    theta_var: np.ndarray
    theta_mpv: np.ndarray
    theta_quantiles: np.ndarray
    ess: np.ndarray
    resampled: np.ndarray
    log_evidence_increments: np.ndarray
    state_mean: np.ndarray
    drift_mean: np.ndarray
    drift_std: np.ndarray
    final_theta: np.ndarray
    final_log_weights: np.ndarray
    elapsed: float
    names: tuple = field(default=())
    sampler: str = "paper"
    move_steps: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    move_exponents: np.ndarray = field(default_factory=lambda: np.zeros(0))
    move_acceptance: np.ndarray = field(default_factory=lambda: np.zeros(0))
    move_sweeps: np.ndarray = field(default_factory=lambda: np.zeros(0, int))
    surrogate: dict = field(default_factory=dict)

    @property
    def log_evidence(self) -> float:
        return float(self.log_evidence_increments.sum())

    def convergence_step(self, truth: ArrayLike, tol: float = 0.01) -> np.ndarray:
        """First step after which the mean stays within ``tol`` of ``truth``, per parameter
        (``T`` if never)."""
        return convergence_step(self.theta_mean, truth, tol)


def convergence_step(history: ArrayLike, truth: ArrayLike, tol: float) -> np.ndarray:
    """First step after which ``history (T, d)`` stays within ``tol`` of ``truth (d,)``, per column:
    ``(d,)`` ints, ``T`` where it never settles."""
    ok = np.abs(np.asarray(history) - np.asarray(truth)) <= tol  # (T, d)
    T = ok.shape[0]
    # last step that is outside, +1
    bad = ~ok
    last_bad = np.where(bad.any(axis=0), T - 1 - np.argmax(bad[::-1], axis=0), -1)
    return last_bad + 1


def weighted_quantiles(samples, weights, probs) -> np.ndarray:
    """Per-column weighted quantiles: ``samples (N, d)``, ``weights (N,)`` -> ``(len(probs), d)``
    (:func:`seqbayes.results.weighted_quantile` with plain weights)."""
    with np.errstate(divide="ignore"):
        return weighted_quantile(samples, np.log(weights), probs)


def weighted_mode(samples, weights, lower, upper, bins: int = 60, limits=None) -> np.ndarray:
    """Most probable value per parameter: centre of the heaviest bin of a weighted
    histogram over the ensemble's weighted 1st-99th percentile range (one bincount);
    ``limits = (lo, hi)`` gives that range if already known."""
    lo, hi = weighted_quantiles(samples, weights, [0.01, 0.99]) if limits is None else limits
    lo = np.maximum(lo, lower)
    hi = np.maximum(np.minimum(hi, upper), lo + 1e-12)
    d = samples.shape[1]
    b = np.clip(((samples - lo) / (hi - lo) * bins).astype(np.int64), 0, bins - 1)  # (N, d)
    counts = np.bincount((b + bins * np.arange(d)).ravel(), weights=np.repeat(weights, d),
                         minlength=bins * d).reshape(d, bins)
    i = np.argmax(counts, axis=1)
    return lo + (i + 0.5) * (hi - lo) / bins


class StageHistories:
    """Per-step summaries of an identification. Weights are buffered over a stage (fixed members)
    and the weighted mean, variance, quantiles and MPV of all its steps are computed at once when
    the stage ends (:meth:`flush`, one sort per stage).

    Parameters
    ----------
    T, d, m, n : int
        Steps, parameters, states and storeys.
    lower, upper : (d,) arrays
        The prior box (the MPV histograms stay inside it).
    bins : int
        Histogram bins of the MPV.
    """

    def __init__(self, T, d, m, n, lower, upper, bins: int = 60):
        self.mean, self.var, self.mpv = np.empty((T, d)), np.empty((T, d)), np.empty((T, d))
        self.quantiles = np.empty((T, 3, d))
        self.ess = np.empty(T)
        self.state_mean, self.drift_mean, self.drift_std = np.empty((T, m)), np.empty((T, n)), np.empty((T, n))
        self.lower, self.upper, self.bins = lower, upper, bins
        self.steps, self.weights = [], []

    def extend(self, steps: int) -> None:
        """Room for ``steps`` more steps (on-line use)."""
        for name in ("mean", "var", "mpv", "quantiles", "ess", "state_mean", "drift_mean", "drift_std"):
            old = getattr(self, name)
            setattr(self, name, np.concatenate([old, np.empty((steps,) + old.shape[1:])]))

    def record(self, k, w, ess, state_mean, drift_mean, drift_second_moment):
        """Step ``k``: buffer its weights ``w (N,)`` and store its ESS, weighted state mean ``(m,)``
        and drift mean and second moment ``(n,)``."""
        self.steps.append(k)
        self.weights.append(w)
        self.ess[k], self.state_mean[k], self.drift_mean[k] = ess, state_mean, drift_mean
        self.drift_std[k] = np.sqrt(np.maximum(drift_second_moment - drift_mean**2, 0))

    def flush(self, theta):
        """End the stage of the members ``theta (N, d)``: summarise its buffered steps."""
        if not self.steps:
            return
        steps, W = np.array(self.steps), np.array(self.weights)  # (L,), (L, N)
        # einsum, not W @ theta: BLAS blocks by the number of rows L, and the same step must give the
        # same bits however the steps were grouped (on-line updates are bit-identical to one run)
        mean = np.einsum("ln,nd->ld", W, theta)
        self.mean[steps] = mean
        self.var[steps] = np.maximum(np.einsum("ln,nd->ld", W, theta**2) - mean**2, 0)
        q = stage_quantiles(theta, W, [0.01, 0.025, 0.5, 0.975, 0.99])  # (L, 5, d)
        self.quantiles[steps] = q[:, 1:4]
        self.mpv[steps] = stage_modes(theta, W, self.lower, self.upper, q[:, 0], q[:, 4], self.bins)
        self.steps, self.weights = [], []


def stage_quantiles(samples, weights, probs) -> np.ndarray:
    """Weighted quantiles of fixed ``samples (N, d)`` under many weight vectors
    ``(L, N)``: ``(L, len(probs), d)``, the same midpoint rule as
    :func:`weighted_quantiles` (linear interpolation of the sorted values at the
    mid-cumulative weights, clamped at the ends)."""
    probs = np.asarray(probs, float)
    L, N = weights.shape
    out = np.empty((L, probs.size, samples.shape[1]))
    rows = np.arange(L)[:, None]
    for j in range(samples.shape[1]):  # loop over parameters (d)
        order = np.argsort(samples[:, j])
        xs = samples[order, j]
        ws = weights[:, order]
        cw = np.cumsum(ws, axis=1)
        cw = (cw - 0.5 * ws) / cw[:, -1:]
        hi = np.clip((cw[:, None, :] < probs[None, :, None]).sum(axis=2), 1, N - 1)  # (L, P)
        c0, c1 = cw[rows, hi - 1], cw[rows, hi]
        frac = np.clip((probs[None, :] - c0) / np.where(c1 > c0, c1 - c0, 1.0), 0.0, 1.0)
        out[:, :, j] = xs[hi - 1] + frac * (xs[hi] - xs[hi - 1])
    return out


def stage_modes(samples, weights, lower, upper, lo, hi, bins: int = 60) -> np.ndarray:
    """MPV of fixed ``samples (N, d)`` under weights ``(L, N)``: :func:`weighted_mode`
    for every row at once, with per-row histogram ranges ``lo, hi (L, d)``."""
    L, N = weights.shape
    d = samples.shape[1]
    lo = np.maximum(lo, lower)
    hi = np.maximum(np.minimum(hi, upper), lo + 1e-12)
    b = np.clip(((samples[None] - lo[:, None]) / (hi - lo)[:, None] * bins).astype(np.int64), 0, bins - 1)
    flat = b + bins * (np.arange(d) + d * np.arange(L)[:, None])[:, None, :]  # (L, N, d)
    counts = np.bincount(flat.ravel(), weights=np.repeat(weights.ravel(), d),
                         minlength=L * d * bins).reshape(L, d, bins)
    i = np.argmax(counts, axis=2)
    return lo + (i + 0.5) * (hi - lo) / bins

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from numpy.typing import ArrayLike
