"""The paper's ensemble variant of SG-EnMCMC (``SGEnMCMC(..., sampler=Ensemble())``), Lin et al. (2024).

The first implementation, kept as an option: one EnKF member per ``theta``,
importance weights from the per-member EnKF likelihood, resampling and a
Liu-West kernel move in place of Eq. 27. It has **no guarantee of reaching the
posterior**: on 4 storeys its means scatter by several tenths of an exact
posterior sd around the exact ones and its intervals miss the truth in most
seeds (docs/shake_table.md). The rest of this docstring describes it.

Each of the ``N`` members carries a parameter vector ``theta_i`` (storey
stiffness ratios) and a state ``X_i = [x, x']``. Per time step ``k``:

1. **Forecast** (Eq. 21): ``X_i <- A(theta_i) X_i + B0(theta_i) u_{k-1} +
   B1(theta_i) u_k + b(theta_i) eta_i``. The matrices of the exact (FOH)
   discretisation are interpolated over ``theta`` by a level-``n`` sparse
   grid built once on the prior box (Eqs. 12-20), so a batch of members costs
   one sparse-matrix product instead of one matrix exponential each. They are
   re-evaluated only for members whose ``theta`` changed.
2. **Moments and likelihood** (Eqs. 9, 25): predicted observations
   ``Y_i = H(theta_i) X_i``; per-member predictive log-likelihood
   ``l_i = log N(y_k; c_i, C_yy + R)``, centred at the least-squares fit of
   ``Y`` on ``theta`` evaluated at ``theta_i`` (``centre="regression"``,
   default: the ensemble's estimate of ``E[y_k | theta_i]``, free of the
   member's own state noise) or at ``Y_i`` (``centre="member"``, the
   paper's). With the regression centre, ``l_i`` gets the **leverage
   correction** ``+ h_i tr(S^-1 C_yy) / 2`` (``S = C_yy + R``, ``h_i`` the
   diagonal of the hat matrix of ``[1, theta]``): the fit is estimated from
   ``N`` members, its error at ``theta_i`` has covariance ``~ h_i C_yy``, and
   that error adds ``h_i tr(S^-1 C_yy)`` to the expected misfit, a spurious
   quadratic penalty in ``theta`` that accumulates over the steps and makes the
   posterior too narrow (calibration below). The spread ``C_yy`` is the sample
   covariance of the ``Y`` residuals after regressing on ``theta``
   (``conditional=True``, default; the spread of the state *given* theta) or
   the pooled sample covariance of the paper (``conditional=False``).
3. **Weighting and resampling of theta** (Eqs. 27-28): ``log w_i += l_i``;
   when the effective sample size falls below ``ess_threshold * N``, the
   members are resampled with probabilities ``w_i / sum w`` (Eq. 28), and
   then **rejuvenated** by a kernel move (Liu and West 2001):
   ``theta_i <- a theta_i + (1 - a) mean + h eps``, ``eps ~ N(0, Cov(theta))``,
   ``a^2 + h^2 = 1``, which keeps the ensemble mean and covariance and stops
   the parameter ensemble collapsing onto a few values. Moves that leave the
   prior box are reflected back inside. The state of a moved member is
   **regenerated** (``state_move="regression"``): ``X_i = mean(X) +
   beta^T (theta_i - mean(theta)) + e_pi(i)``, the least-squares fit of the
   states on theta (before resampling) at the new theta plus the residual
   ``e`` of a member drawn without replacement (a random permutation ``pi``).
   This is an exact draw from the conditional-Gaussian model ``X | theta ~
   N(alpha + beta^T theta, Sigma)`` that the conditional moments and the
   regression-centred likelihood already assume; the residuals carry no
   weight information (the likelihood depends on theta only through the
   fit), so the permutation loses no state diversity and every state is
   consistent with its own theta.
4. **State update** (Eq. 22): perturbed-observation EnKF with gain
   ``K = C_xy (C_yy + R)^-1`` from the same (conditional) sample moments.

What of Eq. 27 is approximated, and what we chose
-------------------------------------------------
Eq. 27 writes a Metropolis ratio between the EnKF likelihood of a candidate
at step ``k`` and that of the current value at ``k - 1``, and Eq. 28 turns
the ratios into resampling probabilities. Two parts are not computable as
written: (a) a candidate's likelihood ``p(y_k | y_{1:k-1}, theta*)`` needs
the whole history filtered with ``theta*``, which would cost a filter run
per candidate; (b) the ratio mixes two different time steps, so it is not a
valid Metropolis-Hastings ratio for ``p(theta | y_{1:k})``. We therefore
use the sequential importance weights ``w_i prop. to prod_k l_i`` of each
member's own filtered history (what ``alpha`` of Eq. 28 becomes when the
candidate is the member's own value), resample with them (Eq. 28), and
replace the Metropolis candidate move by the Liu-West kernel move. Eq. 27
implicitly keeps the parent's state for the candidate (``p(x_k | x_{k-1},
theta*) ~ p(x_k | x_{k-1}, theta)``); we regenerate it instead (above).

Calibration (why ``a = 0.5``, the state regeneration and the leverage correction)
-------------------------------------------------------------------------------------
A moved member that keeps its parent's state remembers its ancestors' ``theta``
for many steps, which attenuates the regression on ``theta``, makes the weights
noisy and lets the ensemble collapse: regenerated states and ``a = 0.5`` (a
mostly Gaussian refit) undo it. The fitted centre's finite-ensemble error
narrows the posterior; the leverage correction removes it. The measurements
behind these choices are in docs/shake_table.md.
"""

from __future__ import annotations

import time

import numpy as np
from scipy.linalg.lapack import dtrtri as _lapack_trtri

from ..weights import resample
from ..core.tempering import normalised_ess
from ..weights import normalise
from .filters.kalman import check_filter_inputs, measurement_covariance
from .structures.shear_building import DiscreteModel
from .summaries import SGEnMCMCResult, StageHistories

__all__ = ["run_ensemble", "liu_west_move", "EnsembleStage"]

_LOG_2PI = float(np.log(2 * np.pi))


def run_ensemble(identifier, theta, ground_acceleration, measurements, rng: np.random.Generator,
                 progress: bool = False) -> SGEnMCMCResult:
    """Run the paper's ensemble sampler (module docstring) over a whole record.

    Parameters
    ----------
    identifier : SGEnMCMC
        Its settings (transition, noise, ``shrinkage``, ``conditional``, ``centre``,
        ``state_move``, ``leverage_correction``, ``ess_threshold``, ``resampling``).
    theta : (N, d) array
        The members' initial stiffness ratios.
    ground_acceleration : (T,) array
    measurements : (T, p) array
    rng : numpy.random.Generator
    progress : bool
        Show a progress bar.
    """
    sg = identifier
    probe = sg.transition(sg.lower[None, :sg.n_theta])
    u, y = check_filter_inputs(probe, ground_acceleration, measurements)
    T = u.size
    N, d = sg.n_members, sg.lower.size
    p = probe.H.shape[1]
    R = measurement_covariance(sg.measurement_noise, p)
    chol_R = np.linalg.cholesky(R)
    start = time.perf_counter()
    m = probe.A.shape[1]
    X = np.zeros((N, m))
    logw = np.zeros(N)
    n = sg.building.n_storeys
    drift_op = np.eye(n) - np.eye(n, k=-1)
    stats = StageHistories(T, d, m, n, sg.lower, sg.upper)
    evid = np.empty(T)
    res_hist = np.zeros(T, bool)
    noise_scale = np.concatenate([[sg.process_noise_std], np.ones(p)])
    half_log_2pi_p = 0.5 * p * _LOG_2PI
    iterator = range(T)
    if progress:
        from tqdm import tqdm

        iterator = tqdm(iterator, desc="SG-EnMCMC", unit="step")
    stage = EnsembleStage(sg.transition(theta), theta, sg.conditional)
    for k in iterator:  # loop over time only
        noise = rng.standard_normal((N, 1 + p)) * noise_scale  # process noise | observation perturbation
        if k > 0:  # (1) forecast with the interpolated transition (Eq. 21), states and predictions at once
            W = stage.forecast(X, u[k - 1], u[k], noise[:, 0])
        else:
            W = np.concatenate([X, np.einsum("npm,nm->np", stage.model.H, X)], axis=1)
        X, Y = W[:, :m], W[:, m:]
        # (2) forecast moments, conditional on theta (Eq. 21 / Eq. 9)
        fitted_y, C_xy, C_yy = stage.moments(W, m)
        S = C_yy + R
        S_chol = np.linalg.cholesky(0.5 * (S + S.T))
        S_chol_inv, _ = _lapack_trtri(S_chol, lower=1)
        # (3) per-member EnKF predictive log-likelihood (Eq. 25)
        centres = fitted_y if sg.centre == "regression" else Y
        z = (y[k] - centres) @ S_chol_inv.T
        loglik = -0.5 * (z * z).sum(axis=1) - (np.log(np.diag(S_chol)).sum() + half_log_2pi_p)
        if sg.leverage_correction and sg.centre == "regression" and stage.centred is not None:
            # remove the expected extra misfit of an estimated fit (see module docstring):
            # E|noise_i|^2_{S^-1} = h_i tr(S^-1 C_yy), h_i the leverage of member i; centred
            # over members (a constant changes no weight and would bias the evidence)
            loglik += 0.5 * stage.leverage_centred * np.sum((S_chol_inv @ C_yy) * S_chol_inv)
        # weights (log domain) and the evidence increment log sum_i w_hat_i exp(l_i)
        shift = logw.max()
        w_prev = np.exp(logw - shift)
        w_prev /= w_prev.sum()
        top = loglik.max()
        evid[k] = float(np.log(w_prev @ np.exp(loglik - top)) + top)
        logw = logw + loglik
        w = np.exp(logw - logw.max())
        w /= w.sum()
        ess = normalised_ess(w)
        # (5) state update, gain from the sample moments, perturbed observations (Eq. 22)
        gain = C_xy @ (S_chol_inv.T @ S_chol_inv)  # K = C_xy S^-1
        perturbed = y[k] + noise[:, 1:] @ chol_R.T
        X = X + (perturbed - Y) @ gain.T
        drifts = X[:, :n] @ drift_op.T
        stats.record(k, w, ess, w @ X, w @ drifts, w @ drifts**2)
        # (4) resample theta with its state (Eq. 28) and rejuvenate
        if ess < sg.ess_threshold * N:
            stats.flush(stage.theta)
            idx = resample(sg.resampling, w, rng, N)
            parent = theta[idx]
            new_theta = liu_west_move(parent, sg.shrinkage, sg.lower, sg.upper, rng)
            if sg.state_move == "regression":
                # states from the fitted E[X | theta] at the new theta plus residuals
                # drawn without replacement from all members (see module docstring)
                X = stage.regenerate(X, new_theta, rng.permutation(N))
            elif sg.state_move == "shift":  # move each inherited state along E[X | theta]
                X = X[idx] + (new_theta - parent) @ stage.slope(X)
            else:
                X = X[idx]
            theta = new_theta
            stage = EnsembleStage(sg.transition(theta), theta, sg.conditional)
            logw = np.zeros(N)
            res_hist[k] = True
    stats.flush(stage.theta)
    final_w = np.exp(normalise(logw))
    idx = resample(sg.resampling, final_w, rng, N)
    elapsed = time.perf_counter() - start
    return SGEnMCMCResult(
        theta_mean=stats.mean, theta_var=stats.var, theta_mpv=stats.mpv, theta_quantiles=stats.quantiles,
        ess=stats.ess, resampled=res_hist, log_evidence_increments=evid, state_mean=stats.state_mean,
        drift_mean=stats.drift_mean, drift_std=stats.drift_std, final_theta=theta[idx],
        final_log_weights=np.zeros(N), elapsed=elapsed,
        names=tuple(f"theta_{j + 1}" for j in range(d)),
        surrogate={} if sg.surrogate_choice is None else sg.surrogate_choice.as_dict())


def liu_west_move(theta, shrinkage: float, lower, upper, rng: np.random.Generator) -> np.ndarray:
    """Liu-West kernel move of ``theta (N, d)``, reflected into the box ``[lower, upper]``.

    ``theta <- a theta + (1 - a) mean + sqrt(1 - a^2) eps``, ``eps ~ N(0, Cov(theta))``,
    ``a = shrinkage``: keeps the ensemble mean and covariance; ``a >= 1`` returns ``theta``.
    """
    a = shrinkage
    if a >= 1:
        return theta
    mean = theta.mean(axis=0)
    cov = np.atleast_2d(np.cov(theta.T))
    L = np.linalg.cholesky(cov + 1e-14 * np.eye(cov.shape[0]) * max(np.trace(cov), 1e-30))
    new = a * theta + (1 - a) * mean + np.sqrt(1 - a * a) * rng.standard_normal(theta.shape) @ L.T
    width = upper - lower
    z = np.mod(new - lower, 2 * width)  # reflect into the box
    return lower + np.where(z > width, 2 * width - z, z)


class EnsembleStage:
    """Everything fixed between two resamplings: the members' ``theta``, their
    transition and observation matrices stacked so one product gives the forecast
    states and predictions ``[X, Y]``, and the projection onto ``span(1, theta)``
    (factorised once, so a step needs no LAPACK call)."""

    def __init__(self, model: DiscreteModel, theta, conditional: bool):
        self.model, self.theta = model, theta
        H = model.H
        self.stacked_A = np.concatenate([model.A, H @ model.A], axis=1)  # (N, m + p, m)
        self.stacked_B0 = np.concatenate([model.B0, np.einsum("npm,nm->np", H, model.B0)], axis=1)
        self.stacked_B1 = np.concatenate([model.B1, np.einsum("npm,nm->np", H, model.B1)], axis=1)
        self.stacked_b = self.stacked_B0 + self.stacked_B1  # noise input b = B0 + B1
        N = theta.shape[0]
        if conditional:
            self.theta_mean = theta.mean(axis=0)
            self.centred = theta - self.theta_mean
            self.basis, _ = np.linalg.qr(np.column_stack([np.ones(N), self.centred]))
        else:
            self.centred = None
            self.basis = np.full((N, 1), 1 / np.sqrt(N))
        self.dof = N - self.basis.shape[1]  # N - 1 - q
        leverage = np.einsum("nq,nq->n", self.basis, self.basis)  # diagonal of the hat matrix
        self.leverage_centred = leverage - leverage.mean()

    def forecast(self, X, u_now, u_next, eta):
        """``[X', H X']`` with ``X' = A X + B0 u_now + B1 u_next + b eta`` (Eq. 21)."""
        return (np.einsum("nij,nj->ni", self.stacked_A, X) + self.stacked_B0 * u_now
                + self.stacked_B1 * u_next + self.stacked_b * eta[:, None])

    def moments(self, W, m: int):
        """Fitted ``Y (N, p)``, ``C_xy (m, p)``, ``C_yy (p, p)`` of ``W = [X, Y]`` given theta (Eq. 9)."""
        fitted = self.basis @ (self.basis.T @ W)
        E = W - fitted
        C = E.T @ E / self.dof
        return fitted[:, m:], C[:m, m:], C[m:, m:]

    def slope(self, X):
        """Least-squares slope ``(d, m)`` of ``X`` on ``theta``."""
        beta, *_ = np.linalg.lstsq(self.centred, X - X.mean(axis=0), rcond=None)
        return beta

    def regenerate(self, X, new_theta, order):
        """``mean(X) + slope^T (theta_new - mean(theta)) + residual[order]``."""
        residual = X - self.basis @ (self.basis.T @ X)
        return X.mean(axis=0) + (new_theta - self.theta_mean) @ self.slope(X) + residual[order]

