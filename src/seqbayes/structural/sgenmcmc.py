"""SG-EnMCMC: on-line stiffness identification of a shear building (Lin et al.
2024, Sec. 2 and Algorithm 1), with two samplers.

``sampler=Exact()`` (default, ``"resample-move"``): exact posterior
===================================================================
Sequential Monte Carlo over the stiffness ratios ``theta`` (IBIS, Chopin 2002;
resample-move, Gilks and Berzuini 2001), annealed over the record step by step
and, within a step whose data would degenerate the weights, tempered. Each of
the ``N`` particles ``theta_i`` carries an exact Kalman filter of the linear
shear building (:class:`~seqbayes.structural.filters.kalman.KalmanBank`), which gives the
exact predictive density ``l_i = p(y_k | y_{0:k-1}, theta_i)``. Per step ``k``:

1. **Reweight** ``log w_i += phi l_i``, with the largest ``phi <= 1`` that keeps
   the effective sample size at ``ess_threshold * N`` (bisection; ``phi = 1``
   when the whole step fits). The evidence increment is
   ``log sum_i W_i exp(phi l_i)``.
2. If ``phi < 1``: **resample** (Eq. 28 with the importance weights) and
   **move** every particle by Metropolis-Hastings steps whose target is the
   (tempered) posterior given *all* data so far,
   ``pi_phi(theta) = p(theta) p(y_{0:k-1} | theta) p(y_k | y_{0:k-1}, theta)^phi``;
   then continue with the rest of the step (``phi`` to 1).

The corrected Eq. 27. For a candidate ``theta*`` drawn from ``q(theta* | theta)``
the acceptance probability of a valid Metropolis-Hastings step targeting the
posterior at step ``k`` is::

    alpha = min{1, [p(theta*) L_k(theta*) q(theta | theta*)] / [p(theta) L_k(theta) q(theta* | theta)]},
    L_k(theta) = p(y_{0:k} | theta) = prod_{j <= k} p(y_j | y_{0:j-1}, theta)        (tempered: last factor ^phi)

with **both** likelihoods the marginal likelihood of the same data ``y_{0:k}``,
each from its own filter run over the whole history (the state integrated
out, not a one-step density with the parent's state). The printed Eq. 27
divides the candidate's one-step density at ``k`` by the current value's at
``k - 1`` and multiplies by state-transition densities of one sampled state:
that ratio does not leave ``p(theta | y_{0:k})`` invariant. Eq. 28 then
resamples the candidates in proportion to ``alpha``, which is not a
Metropolis step either. Here the candidate's ``L_k`` costs one batched Kalman
pass over ``y_{0:k-1}`` for all candidates
(:func:`~seqbayes.structural.filters.kalman.kalman_log_likelihood`, steady-state gain once
the covariance has converged) plus one step of the bank; the current value's
``L_k`` is the particle's running sum, kept exactly.

Proposals (``proposal``): ``"independent"`` (default) draws ``theta*`` from the
Gaussian fitted to the weighted particles before resampling (scaled by
``proposal_scale``; Hastings term ``log q(theta) - log q(theta*)``);
``"random_walk"`` from ``N(theta, (2.38^2 / d) Sigma)`` (symmetric);
``"mixture"`` picks one of the two per particle and sweep with
probability 1/2 each (a mixture of valid kernels is valid: the choice does not
depend on the state). Candidates outside the prior box have zero prior density
and are rejected without a filter run. Sweeps are repeated until the
acceptance rates sum to ``moves_per_particle`` (every particle is expected to
have moved that many times) or ``max_sweeps`` is reached.

Likelihood: the exact Kalman filter of the linear model (``likelihood="kalman"``,
default), or in general a stochastic EnKF per particle (``likelihood="enkf"``:
each particle carries its own random likelihood estimate, and a candidate gets
a fresh one from an EnKF run over the history, the pseudo-marginal form; the
target is then the posterior under the EnKF likelihood, exact as the ensemble
grows). Transition matrices: the exact discretisation by default
(``level="auto"`` with this sampler: at a few storeys the batched matrix
exponential is as fast as the sparse grid, docs/shake_table.md); a
sparse-grid level can be given.

Noise levels as parameters (``noise_parameters="channel"`` or ``"shared"``,
exact Kalman likelihood): the particles carry, after the ``d`` stiffness
ratios, the log scale factors ``log s`` of the channel noise stds (one per
channel, or one for all), ``sd_c = s_c * measurement_noise_c`` with a uniform
prior on ``log s`` over ``log noise_scale_bounds`` (default 1/4 to 4 times the
nominal level); each particle's Kalman filter has its own ``R = diag(sd^2)``
and the same Metropolis-Hastings moves act on the joint vector. Candidates'
histories are filtered by a bank with per-candidate noise (one time loop).
Checked against the exact joint posterior in tests/statistical/test_noise_parameters.py
(accuracy in docs/shake_table.md).

On-line use: :meth:`SGEnMCMC.reset` then :meth:`SGEnMCMC.update` with each new
block of the record (bit-identical to :meth:`SGEnMCMC.run` on the whole record);
:meth:`SGEnMCMC.snapshot` / :meth:`SGEnMCMC.restore` stop and resume a run bit
for bit (plain named arrays and the generator state). A stiffness that drops
during the shaking is detected and attributed to a storey by
:class:`seqbayes.structural.stiffness_drop.StiffnessDropMonitor`.

Accuracy against the exact posterior and cost: docs/shake_table.md
(benchmarks/bench_sgenmcmc.py).

``sampler=Ensemble()`` (``"paper"``): the ensemble variant of Lin et al.
========================================================================
The first implementation, kept as an option: one EnKF member per ``theta`` and a Liu-West
kernel move in place of Eq. 27, with no guarantee of reaching the posterior. It is described,
with its calibration, in :mod:`seqbayes.structural.ensemble`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from functools import partial

import numpy as np

from ..weights import resample
from ..rng import as_generator, generator_from_state, generator_state
from ..core.tempering import TargetESS, between_stages, blas_limit, normalised_ess, temper
from ..moves.base import accepted
from ..moves.gaussian import FittedMove
from ..weights import normalise
from .ensemble import run_ensemble
from .filters.enkf import EnKFBank, enkf_log_likelihood
from .filters.kalman import KalmanBank, check_filter_inputs, kalman_log_likelihood, measurement_covariance
from .structures.bouc_wen import BoucWenBuilding, bouc_wen_transition
from .structures.shear_building import DiscreteModel, ShearBuilding
from .summaries import SGEnMCMCResult, StageHistories
from .surrogate import Measurement, choose_transition
from .settings import (FLAT_SG, LIKELIHOODS, NOISE_PARAMETERS, PROPOSALS, SAMPLERS, STATE_MOVES, Ensemble, Exact,
                       NoiseScales, ResampleMoveSettings, Transitions, sg_from_flat)
from .transitions import ExactTransition, SparseGridTransition

_STEADY_TOL = 1e-11  # relative change of the filter covariance below which it is frozen (as kalman_log_likelihood)


__all__ = ["SGEnMCMC", "Exact", "Ensemble", "Transitions", "NoiseScales", "ResampleMoveSettings", "sg_from_flat",
           "FLAT_SG", "STATE_MOVES", "SAMPLERS", "PROPOSALS", "LIKELIHOODS", "NOISE_PARAMETERS"]


class SGEnMCMC:
    """The SG-EnMCMC identifier (Algorithm 1) with a choice of sampler (module docstring).

    Parameters
    ----------
    building : ShearBuilding or BoucWenBuilding
        The linear shear building, or one with Bouc-Wen hysteretic storeys
        (:mod:`seqbayes.structural.structures.bouc_wen`; needs the EnKF likelihood: the exact Kalman likelihood does
        not apply).
    dt : float
        Sampling step [s] (0.02 s = 50 Hz in the paper).
    lower, upper : (d,) arrays
        Uniform prior box of the stiffness ratios (paper: 0.7 and 1).
    measurement_noise : (p,) stds or (p, p) covariance
    process_noise_std : float
        Std of the unmeasured ground-acceleration noise of the model (m/s^2).
    n_members : int
        Number of particles / ensemble members ``N`` (paper: 500).
    sampler : Exact or Ensemble
        The exact-posterior SMC sampler (default ``Exact()``) or the paper-like ensemble variant ``Ensemble()``.
    transitions : Transitions
        How the transition matrices are computed (exact, a sparse-grid level, or chosen by measurement).
    noise : NoiseScales or None
        Estimate the measurement noise with the stiffness (the exact sampler with the Kalman likelihood). The
        particles, histories and ``names`` then have ``d + r`` columns (``log_noise_scale...`` last).
    channels : str
        Measured channels (default floor absolute accelerations).
    blas_threads : int or None
        BLAS threads while running (``threadpoolctl``; ``None``: no limit). Default 1: the products here are batches of
        small matrices, where a second thread costs CPU and gains no wall time (docs/shake_table.md).

    The flat settings of earlier versions and of a TOML ``[sampler]`` table map onto the components with
    :func:`sg_from_flat`.
    """

    def __init__(self, building: ShearBuilding, dt: float, lower: ArrayLike, upper: ArrayLike,
                 measurement_noise: ArrayLike, process_noise_std: float = 0.0, n_members: int = 500, *,
                 sampler: Exact | Ensemble = Exact(), transitions: Transitions = Transitions(),
                 noise: NoiseScales | None = None, channels: str = "absolute_acceleration",
                 blas_threads: int | None = 1):
        d = building.n_storeys
        self.lower = np.broadcast_to(np.asarray(lower, float), (d,)).copy()
        self.upper = np.broadcast_to(np.asarray(upper, float), (d,)).copy()
        if np.any(self.lower <= 0) or np.any(self.upper <= self.lower):
            raise ValueError(f"lower, upper: need 0 < lower < upper, got {self.lower}, {self.upper}")
        if not isinstance(n_members, (int, np.integer)) or n_members < 4 * d:
            raise ValueError(f"n_members: expected an integer >= {4 * d}, got {n_members!r}")
        if process_noise_std < 0:
            raise ValueError(f"process_noise_std: must be non-negative, got {process_noise_std}")
        if not isinstance(sampler, (Exact, Ensemble)):
            raise TypeError(f"sampler: expected Exact() or Ensemble(), got {sampler!r}")
        exact = isinstance(sampler, Exact)
        # the sampler's settings as the methods read them (the other sampler's defaults where it has none)
        exact_settings, paper = (sampler, Ensemble()) if exact else (Exact(), sampler)
        self.sampler, self.ess_threshold, self.resampling = sampler.name, sampler.ess_threshold, sampler.resampling
        self.proposal, self.proposal_scale = exact_settings.proposal, exact_settings.proposal_scale
        self.moves_per_particle = float(exact_settings.moves_per_particle)
        self.max_sweeps = int(exact_settings.max_sweeps)
        self.likelihood, self.enkf_members = exact_settings.likelihood, int(exact_settings.enkf_members)
        self.shrinkage, self.conditional = float(paper.shrinkage), bool(paper.conditional)
        self.centre, self.state_move = paper.centre, paper.state_move
        self.leverage_correction = bool(paper.leverage_correction)
        if blas_threads is not None and (isinstance(blas_threads, bool)
                                         or not isinstance(blas_threads, (int, np.integer)) or blas_threads < 1):
            raise ValueError(f"blas_threads: expected a positive integer or None, got {blas_threads!r}")
        self.blas_threads = blas_threads
        self.building = building
        self.dt = float(dt)
        self.n_members = int(n_members)
        self.measurement_noise = measurement_noise
        self.process_noise_std = float(process_noise_std)
        self.channels = channels
        self.surrogate_choice = None
        level, transition = transitions.level, transitions.given
        if transitions.surrogate is not None:
            options = dict(transitions.surrogate_options or {})
            if isinstance(building, BoucWenBuilding):
                options.setdefault("enkf_members", self.enkf_members)
            self.surrogate_choice = choose_transition(building, dt, self.lower, self.upper, int(n_members),
                                                      channels=channels, **Measurement.keywords(options))
            transition = self.surrogate_choice.transition
        if isinstance(building, BoucWenBuilding):
            # no exact filter for the hysteretic model: the EnKF likelihood (module docstring)
            if not exact or self.likelihood != "enkf":
                raise ValueError("building: a BoucWenBuilding needs sampler='resample-move' and likelihood='enkf'")
            if level == "auto":
                level = None
            if transition is None:
                transition = (bouc_wen_transition(building, dt, "rk4", channels=channels) if level is None else
                              bouc_wen_transition(building, dt, "exponential", level, self.lower, self.upper,
                                                  channels=channels))
        if level == "auto":
            level = None if exact else 6
        if transition is not None:
            self.transition = transition
        elif level is None:
            self.transition = ExactTransition(building, dt, channels=channels)
        else:
            self.transition = SparseGridTransition(building, dt, self.lower, self.upper, level,
                                                   channels=channels, basis=transitions.basis)
        self.n_theta = d
        self._setup_noise_parameters(None if noise is None else noise.kind, (0.25,
                                                                             4.0) if noise is None else noise.bounds)

    def _setup_noise_parameters(self, noise_parameters, bounds):
        """Noise levels as parameters (module docstring): extend the prior box by the
        log scale factors of the channel noise stds."""
        self.noise_parameters = noise_parameters
        self.noise_scale_bounds = tuple(float(b) for b in bounds)
        if noise_parameters is None:
            self.n_noise = 0
            return
        if self.sampler != "resample-move" or self.likelihood != "kalman":
            raise ValueError("noise_parameters: needs sampler='resample-move' and likelihood='kalman'")
        lo, hi = self.noise_scale_bounds
        p = self.transition(self.lower[None, :]).H.shape[1]
        R = measurement_covariance(self.measurement_noise, p)
        if np.any(R != np.diag(np.diag(R))):
            raise ValueError("measurement_noise: noise parameters need independent channels (stds, not a full "
                             "covariance)")
        self.nominal_noise_std = np.sqrt(np.diag(R))
        self.n_noise = p if noise_parameters == "channel" else 1
        self.lower = np.concatenate([self.lower, np.full(self.n_noise, np.log(lo))])
        self.upper = np.concatenate([self.upper, np.full(self.n_noise, np.log(hi))])

    @property
    def parameter_names(self) -> tuple:
        """Names of the columns of the particles: ``theta_j``, then the noise scales."""
        names = tuple(f"theta_{j + 1}" for j in range(self.n_theta))
        if self.n_noise == 1:
            return names + ("log_noise_scale",)
        return names + tuple(f"log_noise_scale_{c + 1}" for c in range(self.n_noise))

    def noise_std(self, parameters: ArrayLike) -> np.ndarray:
        """Channel noise stds ``(N, p)`` of particles ``(N, d + r)`` (nominal stds times
        the particles' scale factors)."""
        parameters = np.atleast_2d(np.asarray(parameters, float))
        return self.nominal_noise_std * np.exp(parameters[:, self.n_theta:])

    def run(self, ground_acceleration: ArrayLike, measurements: ArrayLike, rng: int | np.random.Generator | None = None,
            progress: bool = False, initial_theta: ArrayLike | None = None) -> SGEnMCMCResult:
        """Identify ``theta`` on-line from ``measurements (T, p)`` under ``ground_acceleration (T,)``.

        The structure starts at rest; ``y_0`` is the first measurement.
        ``initial_theta (N, d)`` replaces the prior draw of the particles.
        """
        rng = as_generator(rng)
        if self.sampler == "resample-move":
            return self._run_resample_move(ground_acceleration, measurements, rng, progress, initial_theta)
        with blas_limit(self.blas_threads):
            return run_ensemble(self, self._initial_theta(initial_theta, rng), ground_acceleration, measurements, rng,
                                progress)

    def _initial_theta(self, initial_theta, rng):
        N, d = self.n_members, self.lower.size
        if initial_theta is None:
            return self.lower + (self.upper - self.lower) * rng.random((N, d))  # uniform prior
        theta = np.array(initial_theta, float)
        if theta.shape != (N, d):
            raise ValueError(f"initial_theta: expected shape ({N}, {d}), got {theta.shape}")
        return theta

    # ------------------------------------------------------------ resample-move
    def _run_resample_move(self, ground_acceleration, measurements, rng, progress,
                           initial_theta) -> SGEnMCMCResult:
        self.reset(rng, initial_theta)
        self.update(ground_acceleration, measurements, progress=progress)
        return self.result()

    # ------------------------------------------------------------------ on-line
    def reset(self, rng: int | np.random.Generator | None = None, initial_theta: ArrayLike | None = None) -> None:
        """Start an on-line identification (``sampler="resample-move"``): draw the
        particles from the prior (or take ``initial_theta (N, d)``), structure at
        rest. Then call :meth:`update` with each new block of the record.
        ``reset`` + ``update`` over any split of a record gives bit for bit the
        numbers of :meth:`run` on the whole record with the same ``rng``."""
        if self.sampler != "resample-move":
            raise ValueError("reset/update: the on-line interface needs sampler='resample-move'")
        rng = as_generator(rng)
        probe = self.transition(self.lower[None, :self.n_theta])
        p, m = probe.H.shape[1], probe.H.shape[2]
        theta = self._initial_theta(initial_theta, rng)
        R = measurement_covariance(self.measurement_noise, p)
        bank = self._bank(theta, R, rng)
        mean, cov = bank.initial_state()
        N, d, n = self.n_members, self.lower.size, self.building.n_storeys
        self._online = _Online(
            rng=rng, R=R, probe=probe, theta=theta, bank=bank, mean=mean, cov=cov, past=np.zeros(N),
            logw=np.zeros(N), u=np.zeros(0), y=np.zeros((0, p)),
            stats=StageHistories(0, d, m, n, self.lower, self.upper), evid=np.zeros(0), resampled=np.zeros(0, bool),
            events=[], elapsed=0.0)

    def update(self, ground_acceleration: ArrayLike, measurements: ArrayLike,
               progress: bool = False) -> SGEnMCMCResult:
        """Process the next block of the record: ``measurements (n, p)`` under
        ``ground_acceleration (n,)``, continuing from the previous blocks (call
        :meth:`reset` first). Returns :meth:`result` (histories of all steps so far)."""
        state = getattr(self, "_online", None)
        if state is None:
            raise ValueError("update: call reset() first (or run() for a whole record)")
        u_new, y_new = check_filter_inputs(state.probe, ground_acceleration, measurements)
        started = time.perf_counter()
        first = state.u.size
        state.u = np.concatenate([state.u, u_new])
        state.y = np.concatenate([state.y, y_new])
        state.stats.extend(u_new.size)
        state.evid = np.concatenate([state.evid, np.zeros(u_new.size)])
        state.resampled = np.concatenate([state.resampled, np.zeros(u_new.size, bool)])
        iterator = range(first, state.u.size)
        if progress:
            from tqdm import tqdm

            iterator = tqdm(iterator, desc="SG-EnMCMC (resample-move)", unit="step")
        with blas_limit(self.blas_threads):
            for k in iterator:  # loop over time only
                self._step(state, k)
        state.elapsed += time.perf_counter() - started
        return self.result()

    def _step(self, state, k: int) -> None:
        """One step of the resample-move sampler (module docstring), in place on ``state``."""
        N = self.n_members
        n = self.building.n_storeys
        u, y = state.u, state.y
        theta, past, logw, bank, mean, cov = state.theta, state.past, state.logw, state.bank, state.mean, state.cov
        inputs = (u[k - 1], u[k]) if k > 0 else (None, None)
        mean_k, cov_k, inc = bank.step(mean, cov, y[k], *inputs)
        annealed = temper((theta, past, mean_k, cov_k, bank), inc, logw, TargetESS(self.ess_threshold * N),
                          between_stages(partial(self._resample_move, state, k)), log_z=state.evid[k])
        (theta, past, mean_k, cov_k, bank), inc, logw = annealed.particles, annealed.loglike, annealed.log_weights
        state.evid[k] = annealed.log_z
        past = past + inc
        if bank.can_freeze and bank.frozen is None and k % 10 == 1 and not state.resampled[k]:  # steady test
            change = np.abs(cov_k - cov).max(axis=(1, 2)) / np.abs(cov_k).max(axis=(1, 2)).clip(1e-300)
            if np.all(change < _STEADY_TOL):
                bank = bank.freeze(cov_k)
        w = np.exp(normalise(logw))
        drift_op = np.eye(n) - np.eye(n, k=-1)
        state_mean, state_cov = bank.moments(mean_k, cov_k)
        drifts = state_mean[:, :n] @ drift_op.T
        drift_var = np.einsum("ij,njk,ik->ni", drift_op, state_cov[:, :n, :n], drift_op)
        state.stats.record(k, w, normalised_ess(w), w @ state_mean, w @ drifts, w @ (drifts**2 + drift_var))
        state.theta, state.past, state.logw, state.bank, state.mean, state.cov = theta, past, logw, bank, mean_k, cov_k

    def _resample_move(self, state, k: int, logw, inc, phi: float, particles):
        """Resample (Eq. 28) and move with Metropolis-Hastings targeting
        ``p(theta | y_{0:k-1}) p(y_k | y_{0:k-1}, theta)^phi``: the ``resample_move`` of
        the mutation of :func:`~seqbayes.core.tempering.temper`
        (:func:`~seqbayes.core.tempering.between_stages`), recording the event on ``state``."""
        theta, past, mean_k, cov_k, bank = particles
        N, R, rng = self.n_members, state.R, state.rng
        state.stats.flush(theta)
        w = np.exp(normalise(logw))
        fit_mean, fit_cov = _weighted_fit(theta, w)
        idx = resample(self.resampling, w, rng, N)
        theta, past, inc, mean_k, cov_k = theta[idx], past[idx], inc[idx], mean_k[idx], cov_k[idx]
        theta, past, inc, mean_k, cov_k, acceptance, moved_steady = self._move(
            theta, past, inc, mean_k, cov_k, phi, k, state.u, state.y, R, fit_mean, fit_cov, rng)
        frozen = bank.frozen is not None and moved_steady
        bank = self._bank(theta, R, rng)
        if frozen:  # every covariance (kept and moved) is in its steady state
            bank = bank.freeze(cov_k)
        state.resampled[k] = True
        state.events.append((k, phi, float(np.mean(acceptance)), len(acceptance)))
        return inc, (theta, past, mean_k, cov_k, bank)

    _HISTORY_ARRAYS = ("mean", "var", "mpv", "quantiles", "ess", "state_mean", "drift_mean", "drift_std")

    def snapshot(self) -> dict:
        """The on-line run's state as plain named arrays plus the generator's state
        (what a run store writes): :meth:`restore` on an identifier built with the
        same arguments continues bit for bit as this one would.

        Returns
        -------
        dict
            ``theta (N, d)``, ``filter_mean``, ``filter_cov`` (the particles' filtered
            moments; an ensemble ``(N, M, m)`` with the EnKF likelihood), ``past (N,)``,
            ``log_weights (N,)``, ``frozen`` (the Kalman bank is in its steady
            state, rebuilt from ``filter_cov``), the record so far ``u (T,)``,
            ``y (T, p)``, ``log_evidence_increments (T,)``, ``resampled (T,)``,
            ``events (E, 4)``, ``elapsed``, the histories ``history_<name>`` and the
            buffered stage ``buffer_steps (L,)``, ``buffer_weights (L, N)``, and
            ``rng_state`` (a dict, :func:`seqbayes.rng.generator_state`). The
            arrays are copies.
        """
        state = getattr(self, "_online", None)
        if state is None:
            raise ValueError("snapshot: nothing to snapshot; call reset() and update() first")
        stats = state.stats
        out = {"theta": state.theta, "filter_mean": state.mean, "filter_cov": state.cov, "past": state.past,
               "log_weights": state.logw, "frozen": np.array(state.bank.frozen is not None), "u": state.u,
               "y": state.y, "log_evidence_increments": state.evid, "resampled": state.resampled,
               "events": np.array(state.events, dtype=float).reshape(-1, 4), "elapsed": np.array(state.elapsed),
               "buffer_steps": np.array(stats.steps, dtype=int),
               "buffer_weights": np.array(stats.weights, dtype=float).reshape(-1, self.n_members)}
        out.update({f"history_{name}": getattr(stats, name) for name in self._HISTORY_ARRAYS})
        out = {key: np.array(value, copy=True) for key, value in out.items()}
        out["rng_state"] = generator_state(state.rng)
        return out

    def restore(self, snapshot: dict) -> None:
        """Continue the on-line run whose :meth:`snapshot` is given (bit for bit)."""
        missing = [key for key in ("theta", "filter_mean", "filter_cov", "past", "log_weights", "frozen", "u", "y",
                                   "rng_state") if key not in snapshot]
        if missing:
            raise ValueError(f"snapshot: missing {missing}")
        if self.sampler != "resample-move":
            raise ValueError("restore: the on-line interface needs sampler='resample-move'")
        theta = np.array(snapshot["theta"], float)
        if theta.shape != (self.n_members, self.lower.size):
            raise ValueError(f"snapshot: theta has shape {theta.shape}, this identifier expects "
                             f"({self.n_members}, {self.lower.size})")
        rng = generator_from_state(snapshot["rng_state"])
        probe = self.transition(self.lower[None, :self.n_theta])
        p, m = probe.H.shape[1], probe.H.shape[2]
        R = measurement_covariance(self.measurement_noise, p)
        cov = np.array(snapshot["filter_cov"], float)
        bank = self._bank(theta, R, rng)
        if bool(snapshot["frozen"]):
            bank = bank.freeze(cov)
        stats = StageHistories(0, self.lower.size, m, self.building.n_storeys, self.lower, self.upper)
        for name in self._HISTORY_ARRAYS:
            setattr(stats, name, np.array(snapshot[f"history_{name}"], float))
        stats.steps = [int(k) for k in snapshot["buffer_steps"]]
        stats.weights = [np.array(w, float) for w in snapshot["buffer_weights"]]
        self._online = _Online(
            rng=rng, R=R, probe=probe, theta=theta, bank=bank, mean=np.array(snapshot["filter_mean"], float),
            cov=cov, past=np.array(snapshot["past"], float), logw=np.array(snapshot["log_weights"], float),
            u=np.array(snapshot["u"], float), y=np.array(snapshot["y"], float).reshape(-1, p), stats=stats,
            evid=np.array(snapshot["log_evidence_increments"], float),
            resampled=np.array(snapshot["resampled"], bool),
            events=[tuple(row) for row in np.asarray(snapshot["events"], float).reshape(-1, 4).tolist()],
            elapsed=float(snapshot["elapsed"]))

    def result(self) -> SGEnMCMCResult:
        """Histories of the on-line identification so far (after :meth:`update`).

        ``final_theta`` is a resample of the current particles drawn from a copy
        of the generator's state, so asking for a result does not change later
        updates."""
        state = getattr(self, "_online", None)
        if state is None:
            raise ValueError("result: nothing identified yet; call reset() and update()")
        state.stats.flush(state.theta)
        N = self.n_members
        copy = np.random.Generator(type(state.rng.bit_generator)())
        copy.bit_generator.state = state.rng.bit_generator.state
        idx = resample(self.resampling, np.exp(normalise(state.logw)), copy, N)
        stats = state.stats
        ev = np.array(state.events, dtype=float).reshape(-1, 4)
        return SGEnMCMCResult(
            theta_mean=stats.mean.copy(), theta_var=stats.var.copy(), theta_mpv=stats.mpv.copy(),
            theta_quantiles=stats.quantiles.copy(), ess=stats.ess.copy(), resampled=state.resampled.copy(),
            log_evidence_increments=state.evid.copy(), state_mean=stats.state_mean.copy(),
            drift_mean=stats.drift_mean.copy(), drift_std=stats.drift_std.copy(), final_theta=state.theta[idx],
            final_log_weights=np.zeros(N), elapsed=state.elapsed,
            names=self.parameter_names, sampler="resample-move",
            move_steps=ev[:, 0].astype(int), move_exponents=ev[:, 1], move_acceptance=ev[:, 2],
            move_sweeps=ev[:, 3].astype(int),
            surrogate={} if self.surrogate_choice is None else self.surrogate_choice.as_dict())

    def _bank(self, theta, R, rng):
        """The particles' filters: exact Kalman or EnKF (``likelihood``)."""
        model = self.transition(theta[:, :self.n_theta])
        if self.likelihood == "enkf":
            return EnKFBank(model, R, self.process_noise_std, self.enkf_members, rng)
        if self.n_noise:
            return KalmanBank(model, R, self.process_noise_std, member_noise_std=self.noise_std(theta))
        return KalmanBank(model, R, self.process_noise_std)

    def _history_likelihood(self, theta, phi, k, u, y, R, rng):
        """Tempered log-target terms of candidates ``theta (M, d)`` at step ``k``: one
        batched Kalman pass over ``y_{0:k-1}`` and one step of a bank on ``y_k``.

        Returns ``past (M,)``, the increment ``(M,)``, the filtered mean and
        covariance at step ``k``, and whether their covariances had reached the
        steady state."""
        bank = self._bank(theta, R, rng)
        model = bank.model
        if k == 0:
            mean, cov = bank.initial_state()
            past = np.zeros(theta.shape[0])
            mean_k, cov_k, inc = bank.step(mean, cov, y[0])
            return past, inc, mean_k, cov_k, False
        if self.likelihood == "enkf":
            past, mean, cov = enkf_log_likelihood(model, u[:k], y[:k], R, self.process_noise_std,
                                                  self.enkf_members, rng)
            mean_k, cov_k, inc = bank.step(mean, cov, y[k], u[k - 1], u[k])
            return past, inc, mean_k, cov_k, False
        if self.n_noise:  # per-candidate noise levels: the bank over the history (steady test as in _step)
            past, steady, mean, cov = _bank_history(bank, u, y, k)
            mean_k, cov_k, inc = bank.step(mean, cov, y[k], u[k - 1], u[k])
            return past, inc, mean_k, cov_k, steady
        past, steady_step, mean, cov = kalman_log_likelihood(model, u[:k], y[:k], R, self.process_noise_std,
                                                             return_steady_step=True, return_state=True)
        mean_k, cov_k, inc = bank.step(mean, cov, y[k], u[k - 1], u[k])
        return past, inc, mean_k, cov_k, steady_step < k

    def _move(self, theta, past, inc, mean_k, cov_k, phi, k, u, y, R, fit_mean, fit_cov, rng):
        """Metropolis-Hastings sweeps (the corrected Eq. 27, module docstring) on all
        particles at once, targeting ``log p(theta) + past + phi * inc``."""
        N, d = theta.shape
        jitter = 1e-12 * max(float(np.trace(fit_cov)) / d, 1e-30) * np.eye(d)
        move = FittedMove(fit_mean, np.linalg.cholesky(fit_cov + jitter), self.proposal_scale)
        acceptance = []
        total = 0.0
        steady = True
        while total < self.moves_per_particle and len(acceptance) < self.max_sweeps:
            noise = rng.standard_normal((N, d))
            if self.proposal == "independent":
                independent = np.ones(N, bool)
            elif self.proposal == "random_walk":
                independent = np.zeros(N, bool)
            else:
                independent = rng.random(N) < 0.5
            candidate, log_hastings = move.propose(theta, noise, independent)
            inside = np.all((candidate > self.lower) & (candidate < self.upper), axis=1)  # uniform prior
            log_u = np.log(rng.random(N))  # drawn before the candidates' filters run (an EnKF draws too)
            accept = np.zeros(N, bool)
            if inside.any():
                c_past, c_inc, c_mean, c_cov, c_steady = self._history_likelihood(candidate[inside], phi, k, u, y,
                                                                                  R, rng)
                steady = steady and c_steady
                ok = accepted(log_u[inside], past[inside] + phi * inc[inside], c_past + phi * c_inc,
                              log_hastings[inside])
                where = np.flatnonzero(inside)[ok]
                accept[where] = True
                theta = theta.copy()
                past, inc, mean_k, cov_k = past.copy(), inc.copy(), mean_k.copy(), cov_k.copy()
                theta[where], past[where], inc[where] = candidate[where], c_past[ok], c_inc[ok]
                mean_k[where], cov_k[where] = c_mean[ok], c_cov[ok]
            rate = float(accept.mean())
            acceptance.append(rate)
            total += rate
        return theta, past, inc, mean_k, cov_k, np.array(acceptance), steady


def _bank_history(bank, u, y, k):
    """Run ``bank`` over ``y_{0:k-1}``: log-likelihoods ``(N,)``, whether the filters
    reached their steady state, and the filtered mean and covariance at ``k - 1``."""
    mean, cov = bank.initial_state()
    total = np.zeros(bank.n_members)
    for j in range(k):  # loop over time only
        new_mean, new_cov, inc = bank.step(mean, cov, y[j], *((u[j - 1], u[j]) if j else (None, None)))
        total += inc
        if bank.frozen is None and j % 10 == 1:
            change = np.abs(new_cov - cov).max(axis=(1, 2)) / np.abs(new_cov).max(axis=(1, 2)).clip(1e-300)
            if np.all(change < _STEADY_TOL):
                bank = bank.freeze(new_cov)
        mean, cov = new_mean, new_cov
    return total, bank.frozen is not None, mean, cov


def _weighted_fit(theta, w):
    """Weighted mean ``(d,)`` and covariance ``(d, d)`` of particles ``theta (N, d)``."""
    mean = w @ theta
    centred = theta - mean
    cov = (centred * w[:, None]).T @ centred / max(1.0 - float(w @ w), 1e-12)
    return mean, np.atleast_2d(cov)


@dataclass
class _Online:
    """Mutable state of an on-line resample-move identification (held by
    :class:`SGEnMCMC` between :meth:`SGEnMCMC.update` calls): the generator,
    the particles with their exact Kalman filters and running log-likelihoods,
    the record so far (the moves re-filter it) and the histories."""

    rng: np.random.Generator
    R: np.ndarray
    probe: DiscreteModel
    theta: np.ndarray
    bank: KalmanBank
    mean: np.ndarray
    cov: np.ndarray
    past: np.ndarray
    logw: np.ndarray
    u: np.ndarray
    y: np.ndarray
    stats: StageHistories
    evid: np.ndarray
    resampled: np.ndarray
    events: list
    elapsed: float


import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from numpy.typing import ArrayLike
