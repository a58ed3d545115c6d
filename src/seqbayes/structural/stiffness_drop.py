"""On-line detection of a storey stiffness drop during the shaking, and its
attribution to a storey by the evidence.

Lin et al. (2024) identify constant stiffness ratios. Here the record is
monitored block by block (:meth:`StiffnessDropMonitor.update`) and compared
on-line between ``d + 1`` model classes of the linear shear building:

``M_0`` (no change)
    ``theta`` constant, uniform prior on the box ``[lower, upper]`` (as
    :class:`~seqbayes.structural.sgenmcmc.SGEnMCMC`).
``M_j``, ``j = 1..d`` (a drop in storey ``j``)
    ``theta`` constant except that at an unknown change time ``tau`` storey
    ``j``'s ratio drops to ``theta_j (1 - delta)``: the jump kernel

        ``theta_k = theta_{k-1} (1 - delta e_j)`` with probability ``h`` at each change boundary, if not yet dropped;
        ``theta_k = theta_{k-1}`` otherwise,

    with ``delta ~ U(drop_range)``, change boundaries every ``change_every``
    steps, ``h = change_rate * change_every * dt`` (``change_rate``: prior
    changes per second), so ``P(tau = b-th boundary) = h (1 - h)^(b - 1)``. At
    most one drop per class. The structure's state is continuous through the
    change: the new stiffness acts from the transition into step ``tau`` on
    (and on the accelerometers, whose ``H`` depends on ``theta``, from step
    ``tau``).

Prior over classes: ``P(M_0) = prior_no_change``, ``P(M_j) = (1 - prior_no_change) / d``.

Per class, a resample-move SMC sampler over ``(theta, delta, tau)`` with an exact
Kalman filter per particle (the state integrated out; the Rao-Blackwellised
form of a particle filter for the jump kernel), the same scheme as the default
sampler of :mod:`seqbayes.structural.sgenmcmc`:

1. At a change boundary ``k``, every particle that has not dropped yet drops
   with probability ``q = jump_proposal`` (more often than the prior ``h``, so
   that a few particles try each boundary), with ``delta`` from its prior; the
   weights get the importance ratio ``h / q`` (dropped) or ``(1 - h) / (1 - q)``
   (kept). The dropped particles' filters continue from their state with the
   new matrices.
2. Reweight by ``phi p(y_k | y_{0:k-1}, path_i)`` (exact Kalman predictive
   density), ``phi`` tempered so the ESS stays at ``ess_threshold * N``.
3. When ``phi < 1``: resample, and Metropolis-Hastings sweeps targeting the
   (tempered) posterior of the path given all data so far: ``theta`` of the
   particles that have not dropped, ``(theta, delta)`` of those that have, at
   their fixed ``tau`` (a kernel on each part of the space leaves the joint
   posterior invariant). A candidate's likelihood re-filters the history with
   its own switch at ``tau`` (:func:`~seqbayes.structural.drop_paths.path_log_likelihood`).
4. When a part (not dropped / dropped) holds mostly copies of a few particles
   (after the one particle that proposed the right drop took all the weight),
   the same sweeps at ``phi = 1``: copies weigh the same, so the ESS would never
   trigger them and ``delta`` would stay at the proposed value.

The evidence of each class is the product of the stage normalisers
``sum_i W_i r_i``; the per-block increments are reported. The probability that
a change has happened by step ``k``:

    ``P(changed | y_{0:k}) = sum_j P(M_j | y_{0:k}) P(tau <= k | M_j, y_{0:k})``

and a change is *detected* at the end of the first block where it exceeds
``threshold``; it is *attributed* to the storey of the most probable change
class.

Pruning (``prune_below``): a class whose posterior probability stays below
``prune_below`` for ``prune_after`` consecutive steps stops being updated (its log-evidence is
kept as it was) and is left out of the class probabilities from then on, the
beam pruning of multiple-model trackers. The wait matters: right after a
drop, a wrong storey's class can explain the first few steps better than the
right one, whose particles need a few change boundaries to propose a drop of
the right size, so pruning after a single step can remove the right class.
Without pruning, after a drop the wrong classes keep re-fitting data they
cannot explain, which is most of the cost; with ``prune_below=0`` every class
runs to the end. Validated against the exact evidence (quadrature over ``theta`` and
``delta`` and a sum over the change boundaries, each term an exact Kalman
likelihood) in ``tests/statistical/test_stiffness_drop.py``; detection and
false alarms measured in ``benchmarks/bench_drop.py`` (docs/shake_table.md).

A session is stopped and resumed with :meth:`StiffnessDropMonitor.snapshot`
(named numpy arrays, ``np.savez``-able without pickle) and
:meth:`StiffnessDropMonitor.restore` on a monitor built with the same
arguments; the continuation is bit-identical to an uninterrupted run
(``tests/unit/test_stiffness_drop_resume.py``).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, fields, replace
from functools import partial

import numpy as np

from ..weights import resample
from ..rng import as_generator, generator_from_state, generator_state
from ..selection import ModelBank
from ..core.tempering import TargetESS, between_stages, blas_limit, temper
from ..moves.base import accepted
from ..moves.gaussian import FittedMove
from ..weights import logsumexp, normalise
from .drop_paths import effective_theta, path_log_likelihood
from .filters.kalman import KalmanBank, check_filter_inputs, measurement_covariance
from .settings import ResampleMoveSettings
from .structures.shear_building import DiscreteModel, ShearBuilding, discretise

__all__ = ["StiffnessDropMonitor", "DropBlock", "DropModel", "Detection", "monitor_from_flat", "FLAT_MONITOR"]


@dataclass(frozen=True)
class DropBlock:
    """The monitor's summary at the end of one block of the record (``C = d + 1`` classes:
    index 0 is no change, index ``j`` a drop in storey ``j``).

    Attributes
    ----------
    stop : int
        Steps processed so far (the block ended at step ``stop - 1``).
    time : float
        Record time of the block's last sample, ``(stop - 1) dt`` [s].
    log_evidence : (C,) array
        ``log p(y_{0:stop-1} | M_c)``.
    log_evidence_increments : (C,) array
        Of this block: ``log p(y_block | y_before, M_c)``.
    class_probabilities : (C,) array
        ``P(M_c | y_{0:stop-1})``.
    changed : (C,) array
        ``P(tau <= stop - 1 | M_c, y)`` (0 for ``M_0``).
    change_probability : float
        ``P(changed by now | y)``, the detection statistic.
    detected : bool
        ``change_probability > threshold`` at this block.
    storey : int
        1-based storey of the most probable change class.
    drop_mean, change_time_mean : (C,) arrays
        Posterior mean of ``delta`` and of the change time ``tau dt`` [s] given
        a change has happened (NaN where no particle has changed; NaN for ``M_0``).
    theta_mean : (C, d) array
        Posterior mean of the *current* stiffness ratios per class.
    active : (C,) bool array
        Classes still updated (the others were pruned; probability 0 here).
    seconds : float
        Wall time of the block's update.
    """

    stop: int
    time: float
    log_evidence: np.ndarray
    log_evidence_increments: np.ndarray
    class_probabilities: np.ndarray
    changed: np.ndarray
    change_probability: float
    detected: bool
    storey: int
    drop_mean: np.ndarray
    change_time_mean: np.ndarray
    theta_mean: np.ndarray
    active: np.ndarray
    seconds: float


@dataclass(frozen=True)
class _ClassState:
    """One class's particles: ``theta (N, d)`` before any drop, ``delta (N,)``,
    change step ``tau (N,)`` (``-1``: not dropped), their Kalman filters (``bank``,
    filtered ``mean (N, m)``, ``cov (N, m, m)`` at the last step), running
    ``past (N,)`` log-likelihoods, log-weights and the class's log-evidence."""

    storey: int
    theta: np.ndarray
    delta: np.ndarray
    tau: np.ndarray
    bank: KalmanBank
    mean: np.ndarray
    cov: np.ndarray
    past: np.ndarray
    logw: np.ndarray
    log_evidence: float
    events: int


@dataclass(frozen=True)
class DropModel:
    """The change classes' model (module docstring): ``delta ~ U(drop_range)``, a prior rate of a drop per second
    (``change_rate``, per change class) at change boundaries every ``change_every`` steps (the resolution of ``tau``),
    the per-boundary probability with which a particle tries a drop (``jump_proposal``; ``None``:
    ``max(h, 4 / n_particles)``, about four particles per boundary) and ``P(M_0) = prior_no_change``."""

    drop_range: tuple = (0.02, 0.5)
    change_rate: float = 0.01
    change_every: int = 1
    jump_proposal: float | None = None
    prior_no_change: float = 0.5

    def __post_init__(self):
        lo, hi = (float(x) for x in self.drop_range)
        if not 0 <= lo < hi < 1:
            raise ValueError(f"drop_range: need 0 <= low < high < 1, got {self.drop_range}")
        object.__setattr__(self, "drop_range", (lo, hi))
        object.__setattr__(self, "change_rate", float(self.change_rate))
        if not isinstance(self.change_every, (int, np.integer)) or self.change_every < 1:
            raise ValueError(f"change_every: expected a positive integer, got {self.change_every!r}")
        object.__setattr__(self, "change_every", int(self.change_every))
        if not 0 < self.prior_no_change < 1:
            raise ValueError(f"prior_no_change: must be in (0, 1), got {self.prior_no_change}")
        object.__setattr__(self, "prior_no_change", float(self.prior_no_change))


@dataclass(frozen=True)
class Detection:
    """When a change is detected (``P(changed | y) > threshold`` at the end of a block) and which classes stop being
    updated (module docstring: below ``prune_below`` for ``prune_after`` consecutive steps; 0: never)."""

    threshold: float = 0.99
    prune_below: float = 1e-10
    prune_after: int = 25

    def __post_init__(self):
        if not 0 < self.threshold < 1:
            raise ValueError(f"threshold: must be in (0, 1), got {self.threshold}")
        if not isinstance(self.prune_after, (int, np.integer)) or self.prune_after < 1:
            raise ValueError(f"prune_after: expected a positive integer, got {self.prune_after!r}")
        object.__setattr__(self, "threshold", float(self.threshold))
        object.__setattr__(self, "prune_below", float(self.prune_below))
        object.__setattr__(self, "prune_after", int(self.prune_after))


#: The monitor's flat keywords before its components (a TOML ``[monitor]`` table keeps them) -> component.
FLAT_MONITOR = {**{name: "changes" for name in ("drop_range", "change_rate", "change_every", "jump_proposal",
                                                 "prior_no_change")},
                **{name: "detection" for name in ("threshold", "prune_below", "prune_after")},
                **{name: "sampler" for name in ("ess_threshold", "moves_per_particle", "max_sweeps", "resampling")}}


def monitor_from_flat(**flat) -> dict:
    """The monitor's components of its flat settings, as its keywords:
    ``StiffnessDropMonitor(building, dt, lower, upper, noise, **monitor_from_flat(threshold=0.95))``."""
    unknown = sorted(set(flat) - set(FLAT_MONITOR))
    if unknown:
        raise TypeError(f"{unknown[0]}: not a setting of StiffnessDropMonitor ({', '.join(FLAT_MONITOR)})")
    parts = {"changes": {}, "detection": {}, "sampler": {}}
    for name, value in flat.items():
        parts[FLAT_MONITOR[name]][name] = value
    return {"changes": DropModel(**parts["changes"]), "detection": Detection(**parts["detection"]),
            "sampler": ResampleMoveSettings(**parts["sampler"])}


class StiffnessDropMonitor:
    """On-line stiffness-drop detection and storey attribution (module docstring).

    Parameters
    ----------
    building : ShearBuilding
    dt : float
        Sampling step [s].
    lower, upper : float or (d,) arrays
        Uniform prior box of the stiffness ratios before any change.
    measurement_noise : (p,) stds or (p, p) covariance
    process_noise_std : float
        Std of the unmeasured ground-acceleration noise (m/s^2).
    n_particles : int
        Particles per class.
    changes : DropModel
        The change classes' model: the drop's prior, the change boundaries and their rate, the jump proposal,
        ``P(M_0)``.
    detection : Detection
        The detection threshold and the pruning of improbable classes.
    sampler : ResampleMoveSettings
        Each class's resample-move schedule (as :class:`~seqbayes.structural.sgenmcmc.SGEnMCMC`'s exact sampler).
    blas_threads : int or None
        As :class:`~seqbayes.structural.sgenmcmc.SGEnMCMC`.
    channels : str
    """

    def __init__(self, building: ShearBuilding, dt: float, lower, upper, measurement_noise,
                 process_noise_std: float = 0.0, n_particles: int = 200, *, changes: DropModel = DropModel(),
                 detection: Detection = Detection(), sampler: ResampleMoveSettings = ResampleMoveSettings(),
                 channels: str = "absolute_acceleration", blas_threads: int | None = 1):
        d = building.n_storeys
        self.building, self.dt, self.channels = building, float(dt), channels
        self.lower = np.broadcast_to(np.asarray(lower, float), (d,)).copy()
        self.upper = np.broadcast_to(np.asarray(upper, float), (d,)).copy()
        if np.any(self.lower <= 0) or np.any(self.upper <= self.lower):
            raise ValueError(f"lower, upper: need 0 < lower < upper, got {self.lower}, {self.upper}")
        if not isinstance(n_particles, (int, np.integer)) or n_particles < 4 * (d + 1):
            raise ValueError(f"n_particles: expected an integer >= {4 * (d + 1)}, got {n_particles!r}")
        hazard = changes.change_rate * changes.change_every * self.dt
        if not 0 < hazard < 1:
            raise ValueError(f"change_rate: change_rate * change_every * dt must be in (0, 1), got {hazard}")
        q = max(hazard, 4.0 / n_particles) if changes.jump_proposal is None else float(changes.jump_proposal)
        if not 0 < q < 1:
            raise ValueError(f"jump_proposal: must be in (0, 1), got {changes.jump_proposal}")
        if not 0 <= detection.prune_below < 1 / (d + 1):
            raise ValueError(f"prune_below: must be in [0, 1 / {d + 1}), got {detection.prune_below}")
        if process_noise_std < 0:
            raise ValueError(f"process_noise_std: must be non-negative, got {process_noise_std}")
        self.measurement_noise, self.process_noise_std = measurement_noise, float(process_noise_std)
        self.n_particles, self.drop_range = int(n_particles), changes.drop_range
        self.hazard, self.jump_proposal, self.change_every = hazard, q, changes.change_every
        self.change_rate, self.prior_no_change = changes.change_rate, changes.prior_no_change
        self.threshold, self.prune_below = detection.threshold, detection.prune_below
        self.prune_after = detection.prune_after
        self.ess_threshold, self.moves_per_particle = float(sampler.ess_threshold), float(sampler.moves_per_particle)
        self.max_sweeps, self.resampling, self.blas_threads = int(sampler.max_sweeps), sampler.resampling, blas_threads
        self.log_prior_classes = np.log(np.concatenate([[self.prior_no_change],
                                                        np.full(d, (1 - self.prior_no_change) / d)]))
        self._run = None

    # ------------------------------------------------------------------ driver
    def reset(self, rng=None) -> None:
        """Start monitoring: every class's particles from the prior, structure at rest."""
        rng = as_generator(rng)
        N, d = self.n_particles, self.lower.size
        probe = discretise(self.building, self.lower, self.dt, channels=self.channels)
        R = measurement_covariance(self.measurement_noise, probe.H.shape[1])
        classes = []
        for storey in range(d + 1):
            theta = self.lower + (self.upper - self.lower) * rng.random((N, d))
            bank = KalmanBank(self._model(theta), R, self.process_noise_std)
            mean, cov = bank.initial_state()
            classes.append(_ClassState(storey, theta, np.zeros(N), np.full(N, -1), bank, mean, cov, np.zeros(N),
                                       np.zeros(N), 0.0, 0))
        self._run = {"rng": rng, "R": R, "probe": probe, "u": np.zeros(0), "y": np.zeros((0, R.shape[0])),
                     "classes": classes, "bank": ModelBank(self.log_prior_classes, np.zeros(d + 1), np.ones(d + 1, bool),
                                                           np.zeros(d + 1, int)),
                     "history": []}

    def update(self, ground_acceleration, measurements) -> DropBlock:
        """Process the next block ``measurements (n, p)`` under ``ground_acceleration (n,)``;
        returns (and records in :attr:`history`) the block's :class:`DropBlock`."""
        run = self._run
        if run is None:
            raise ValueError("update: call reset() first")
        u_new, y_new = check_filter_inputs(run["probe"], ground_acceleration, measurements)
        started = time.perf_counter()
        first = run["u"].size
        run["u"] = np.concatenate([run["u"], u_new])
        run["y"] = np.concatenate([run["y"], y_new])
        before = np.array([c.log_evidence for c in run["classes"]])
        with blas_limit(self.blas_threads):
            for k in range(first, run["u"].size):  # loop over time only
                run["classes"] = [self._class_step(c, k, run) if on else c
                                  for c, on in zip(run["classes"], run["bank"].active)]
                run["bank"] = run["bank"].updated([c.log_evidence for c in run["classes"]], self.prune_below,
                                                  self.prune_after)
        block = self._summary(run, before, time.perf_counter() - started)
        run["history"].append(block)
        return block

    @property
    def history(self) -> tuple:
        """The :class:`DropBlock` of every block so far."""
        return tuple(self._run["history"]) if self._run is not None else ()

    def detection(self) -> DropBlock | None:
        """The first block at which a change was detected (None if none yet)."""
        return next((b for b in self.history if b.detected), None)

    # ------------------------------------------------------- stop and resume
    #: DropBlock fields with one value per class (stacked over blocks as ``(B, C)``).
    _PER_CLASS = ("log_evidence", "log_evidence_increments", "class_probabilities", "changed", "drop_mean",
                  "change_time_mean", "active")
    #: Per-class sampler arrays of the snapshot (``class_<name>``, stacked over classes).
    _CLASS_ARRAYS = ("theta", "delta", "tau", "mean", "cov", "past", "logw")

    def _settings(self) -> dict:
        """The constructor arguments a snapshot must agree on, as arrays, keyed by
        argument name (the order is the order of the checks in :meth:`restore`)."""
        b = self.building
        R = measurement_covariance(self.measurement_noise, discretise(b, self.lower, self.dt,
                                                                      channels=self.channels).H.shape[1])
        channels = self.channels if isinstance(self.channels, str) else repr(self.channels)  # a Sensors layout
        values = {"n_storeys": b.n_storeys, "n_particles": self.n_particles, "channels": channels,
                  "dt": self.dt,
                  "building": np.concatenate([b.masses, b.stiffnesses, np.asarray(b.damping_ratios, float),
                                              np.asarray(b.damping_modes, float)]),
                  "lower": self.lower, "upper": self.upper, "measurement_noise": R,
                  "process_noise_std": self.process_noise_std, "drop_range": np.array(self.drop_range),
                  "change_rate": self.change_rate, "change_every": self.change_every,
                  "jump_proposal": self.jump_proposal, "prior_no_change": self.prior_no_change,
                  "threshold": self.threshold, "prune_below": self.prune_below, "prune_after": self.prune_after,
                  "ess_threshold": self.ess_threshold, "moves_per_particle": self.moves_per_particle,
                  "max_sweeps": self.max_sweeps, "resampling": str(self.resampling)}
        return {name: np.array(value) for name, value in values.items()}

    def snapshot(self) -> dict:
        """The monitoring session's state as named numpy arrays (no objects), so
        that ``np.savez(path, **snapshot)`` and ``dict(np.load(path))`` (no pickle)
        carry it: :meth:`restore` on a monitor built with the same arguments
        continues bit for bit as this one would have.

        Returns
        -------
        dict
            ``setting_<argument>``: the constructor arguments the run depends on
            (checked by :meth:`restore`); ``rng_state``: the bit generator's state
            as a JSON string (0-d unicode array); the record so far ``u (T,)``,
            ``y (T, p)``; the pruning state ``active (C,)``, ``low_steps (C,)``;
            per class (stacked, ``C = d + 1``, ``N`` particles) ``class_theta (C, N, d)``,
            ``class_delta (C, N)``, ``class_tau (C, N)``, the filtered moments
            ``class_mean (C, N, m)``, ``class_cov (C, N, m, m)``, ``class_past``,
            ``class_logw (C, N)``, ``class_log_evidence (C,)``, ``class_events (C,)``
            and the Kalman bank's matrices ``class_A``, ``class_B0``, ``class_B1``,
            ``class_H``; and every :class:`DropBlock` so far as ``history_<field>``
            (stacked over the ``B`` blocks). The arrays are copies.
        """
        run = self._run
        if run is None:
            raise ValueError("snapshot: nothing to snapshot; call reset() first")
        classes = run["classes"]
        out = {f"setting_{name}": value for name, value in self._settings().items()}
        out["rng_state"] = np.array(json.dumps(generator_state(run["rng"])))
        out.update(u=run["u"], y=run["y"], active=run["bank"].active, low_steps=run["bank"].low_steps)
        for name in self._CLASS_ARRAYS:
            out[f"class_{name}"] = np.stack([getattr(c, name) for c in classes])
        out["class_log_evidence"] = np.array([c.log_evidence for c in classes], float)
        out["class_events"] = np.array([c.events for c in classes], int)
        for name in ("A", "B0", "B1", "H"):
            out[f"class_{name}"] = np.stack([getattr(c.bank.model, name) for c in classes])
        C, d, history = len(classes), self.lower.size, run["history"]
        for f in fields(DropBlock):
            shape = (-1, C) if f.name in self._PER_CLASS else (-1, C, d) if f.name == "theta_mean" else (-1,)
            out[f"history_{f.name}"] = np.array([getattr(b, f.name) for b in history]).reshape(shape)
        return {key: np.array(value, copy=True) for key, value in out.items()}

    def restore(self, snapshot) -> None:
        """Continue the monitoring session of a :meth:`snapshot` (bit for bit).

        Parameters
        ----------
        snapshot : mapping
            As returned by :meth:`snapshot`, or loaded back from ``np.savez``
            (an ``NpzFile`` or a dict of its arrays).

        Raises
        ------
        ValueError
            A key is missing, or the snapshot was made with other constructor
            arguments (the message names the first that differs).
        """
        settings = self._settings()
        required = [f"setting_{name}" for name in settings] + [
            "rng_state", "u", "y", "active", "low_steps", "class_log_evidence", "class_events"] + [
            f"class_{name}" for name in self._CLASS_ARRAYS + ("A", "B0", "B1", "H")] + [
            f"history_{f.name}" for f in fields(DropBlock)]
        missing = [key for key in required if key not in snapshot]
        if missing:
            raise ValueError(f"snapshot: missing {missing}")
        for name, own in settings.items():
            theirs = np.asarray(snapshot[f"setting_{name}"])
            if theirs.shape != own.shape or not np.array_equal(theirs, own):
                raise ValueError(f"restore: the snapshot was made with {name}={theirs.tolist()}, this monitor has "
                                 f"{name}={own.tolist()}")
        state = snapshot["rng_state"]
        rng = generator_from_state(json.loads(str(state)) if not isinstance(state, dict) else state)
        probe = discretise(self.building, self.lower, self.dt, channels=self.channels)
        R = measurement_covariance(self.measurement_noise, probe.H.shape[1])
        log_z = np.asarray(snapshot["class_log_evidence"], float)
        events = np.asarray(snapshot["class_events"], int)
        classes = []
        for c in range(self.lower.size + 1):
            matrices = {name: np.array(snapshot[f"class_{name}"][c], float) for name in ("A", "B0", "B1", "H")}
            model = DiscreteModel(**matrices, dt=probe.dt, hold=probe.hold)
            arrays = {name: np.array(snapshot[f"class_{name}"][c]) for name in self._CLASS_ARRAYS}
            arrays["tau"] = arrays["tau"].astype(int)
            classes.append(_ClassState(storey=c, bank=KalmanBank(model, R, self.process_noise_std),
                                       log_evidence=float(log_z[c]), events=int(events[c]), **arrays))
        history = []
        n_blocks = np.asarray(snapshot["history_stop"]).shape[0]
        for i in range(n_blocks):
            values = {f.name: np.array(snapshot[f"history_{f.name}"][i]) for f in fields(DropBlock)}
            for name, kind in (("stop", int), ("storey", int), ("time", float), ("change_probability", float),
                               ("seconds", float), ("detected", bool)):
                values[name] = kind(values[name])
            history.append(DropBlock(**values))
        self._run = {"rng": rng, "R": R, "probe": probe, "u": np.array(snapshot["u"], float),
                     "y": np.array(snapshot["y"], float).reshape(-1, R.shape[0]), "classes": classes,
                     "bank": ModelBank(self.log_prior_classes, log_z.copy(), np.array(snapshot["active"], bool),
                                       np.array(snapshot["low_steps"], int)),
                     "history": history}

    def _summary(self, run, before, seconds) -> DropBlock:
        classes = run["classes"]
        C = len(classes)
        log_z = np.array([c.log_evidence for c in classes])
        active = run["bank"].active.copy()
        probs = np.exp(run["bank"].log_probabilities())
        changed, drop_mean, time_mean = np.zeros(C), np.full(C, np.nan), np.full(C, np.nan)
        theta_mean = np.empty((C, self.lower.size))
        for c, st in enumerate(classes):
            w = np.exp(normalise(st.logw))
            theta_mean[c] = w @ effective_theta(st.theta, st.delta, st.tau, st.storey)
            dropped = st.tau >= 0
            changed[c] = w[dropped].sum()
            if c > 0 and changed[c] > 0:
                wd = w[dropped] / changed[c]
                drop_mean[c] = wd @ st.delta[dropped]
                time_mean[c] = wd @ st.tau[dropped] * self.dt
        p_change = float(probs @ changed)
        stop = run["u"].size
        return DropBlock(stop=stop, time=(stop - 1) * self.dt, log_evidence=log_z, log_evidence_increments=log_z - before,
                         class_probabilities=probs, changed=changed, change_probability=p_change,
                         detected=p_change > self.threshold, storey=int(np.argmax(probs[1:])) + 1,
                         drop_mean=drop_mean, change_time_mean=time_mean, theta_mean=theta_mean, active=active, seconds=seconds)

    # --------------------------------------------------------------- the step
    def _model(self, theta) -> DiscreteModel:
        return discretise(self.building, theta, self.dt, channels=self.channels)

    def _class_step(self, st: _ClassState, k: int, run: dict) -> _ClassState:
        """One step of one class's resample-move sampler (module docstring); returns the new state."""
        rng, R, u, y = run["rng"], run["R"], run["u"], run["y"]
        N = self.n_particles
        theta, delta, tau, logw, bank = st.theta, st.delta, st.tau, st.logw, st.bank
        evidence = st.log_evidence
        if st.storey > 0 and k > 0 and k % self.change_every == 0:  # (1) jump proposal at a change boundary
            free = tau < 0
            jump = free & (rng.random(N) < self.jump_proposal)
            correction = np.where(jump, np.log(self.hazard / self.jump_proposal),
                                  np.log1p(-self.hazard) - np.log1p(-self.jump_proposal))
            correction = np.where(free, correction, 0.0)
            evidence += logsumexp(normalise(logw) + correction)
            logw = logw + correction
            if jump.any():
                delta, tau = delta.copy(), tau.copy()
                delta[jump] = rng.uniform(*self.drop_range, size=int(jump.sum()))
                tau[jump] = k
                bank = self._replace_members(bank, jump, effective_theta(theta[jump], delta[jump], tau[jump],
                                                                         st.storey), R)
        inputs = (u[k - 1], u[k]) if k > 0 else (None, None)
        mean_k, cov_k, inc = bank.step(st.mean, st.cov, y[k], *inputs)
        particles = (theta, delta, tau, st.past, mean_k, cov_k, bank, st.events)
        annealed = temper(particles, inc, logw, TargetESS(self.ess_threshold * N),  # (2) tempering, (3) moves
                          between_stages(partial(self._resample_move, st.storey, k, run)), log_z=evidence)
        logw, inc, particles, evidence = annealed.log_weights, annealed.loglike, annealed.particles, annealed.log_z
        theta, delta, tau, past, mean_k, cov_k, bank, events = particles
        if self._collapsed(theta, delta, tau):  # (4) spread a part that is copies of a few particles
            w = np.exp(normalise(logw))
            theta, delta, past, inc, mean_k, cov_k = self._move(st.storey, theta, delta, tau, past, inc, mean_k,
                                                                cov_k, 1.0, k, u, y, self._fits(theta, delta, tau, w),
                                                                rng)
            bank = KalmanBank(self._model(effective_theta(theta, delta, tau, st.storey)), R, self.process_noise_std)
            events += 1
        return replace(st, theta=theta, delta=delta, tau=tau, bank=bank, mean=mean_k, cov=cov_k, past=past + inc,
                       logw=logw, log_evidence=evidence, events=events)

    def _resample_move(self, storey: int, k: int, run: dict, logw, inc, phi: float, particles):
        """Resample and move with Metropolis-Hastings targeting
        ``p(path | y_{0:k-1}) p(y_k | y_{0:k-1}, path)^phi``: the ``resample_move`` of
        :func:`~seqbayes.core.tempering.temper`."""
        theta, delta, tau, past, mean_k, cov_k, bank, events = particles
        rng, R, u, y = run["rng"], run["R"], run["u"], run["y"]
        w = np.exp(normalise(logw))
        fits = self._fits(theta, delta, tau, w)
        idx = resample(self.resampling, w, rng, self.n_particles)
        theta, delta, tau, past, inc = theta[idx], delta[idx], tau[idx], past[idx], inc[idx]
        mean_k, cov_k = mean_k[idx], cov_k[idx]
        theta, delta, past, inc, mean_k, cov_k = self._move(storey, theta, delta, tau, past, inc, mean_k, cov_k, phi,
                                                            k, u, y, fits, rng)
        bank = KalmanBank(self._model(effective_theta(theta, delta, tau, storey)), R, self.process_noise_std)
        return inc, (theta, delta, tau, past, mean_k, cov_k, bank, events + 1)

    @staticmethod
    def _collapsed(theta, delta, tau) -> bool:
        """Whether a part (not dropped / dropped) of at least 20 particles has fewer than a
        tenth as many distinct values: its weights cannot show it (copies weigh the same), so
        no resampling would trigger the moves; an MH kernel that leaves the current posterior
        invariant may be applied at any step."""
        for part in (tau < 0, tau >= 0):
            count = int(part.sum())
            if count >= 20:
                x = np.column_stack([theta[part], delta[part]])
                if np.unique(x, axis=0).shape[0] < count // 10:
                    return True
        return False

    def _replace_members(self, bank: KalmanBank, which, theta_new, R) -> KalmanBank:
        """The bank with the matrices of members ``which`` replaced by those at ``theta_new``."""
        model, new = bank.model, self._model(theta_new)
        fields = {}
        for name in ("A", "B0", "B1", "H"):
            array = getattr(model, name).copy()
            array[which] = getattr(new, name)
            fields[name] = array
        return KalmanBank(DiscreteModel(dt=model.dt, hold=model.hold, **fields), R, self.process_noise_std)

    def _fits(self, theta, delta, tau, w):
        """Weighted Gaussian fits (mean, Cholesky factor) of the particles that have not
        dropped (over ``theta``) and of those that have (over ``[theta, delta]``), for the
        proposals; ``None`` for an empty part."""
        fits = []
        for part, x in ((tau < 0, theta), (tau >= 0, np.column_stack([theta, delta]))):
            wp = w[part]
            if wp.sum() <= 0:
                fits.append(None)
                continue
            wp = wp / wp.sum()
            xs = x[part]
            mean = wp @ xs
            centred = xs - mean
            cov = (centred * wp[:, None]).T @ centred / max(1.0 - float(wp @ wp), 1e-3)
            width = np.concatenate([self.upper - self.lower, [self.drop_range[1] - self.drop_range[0]]])[: x.shape[1]]
            # floor: a part with fewer distinct particles than dimensions + 2 (e.g. all the copies of the one
            # particle that proposed the right drop) has no covariance; 1 % of the prior width lets the moves
            # spread it (a far smaller floor keeps the copies together and delta is never refined; comment-ok: design floor)
            distinct = np.unique(xs[wp > 0], axis=0).shape[0]
            floor = 1e-2 if distinct < x.shape[1] + 2 else 1e-4
            cov = cov + np.diag((floor * width) ** 2)
            fits.append((mean, np.linalg.cholesky(cov)))
        return fits

    def _move(self, storey, theta, delta, tau, past, inc, mean_k, cov_k, phi, k, u, y, fits, rng):
        """Metropolis-Hastings sweeps on all particles at once: independent Gaussian or
        random-walk proposal from the fit of the particle's part, and for the dropped part
        also a wide random walk of ``delta`` alone (symmetric)."""
        N, d = theta.shape
        lo, hi = self.drop_range
        acceptance_total, sweeps = 0.0, 0
        while acceptance_total < self.moves_per_particle and sweeps < self.max_sweeps:
            x = np.column_stack([theta, delta])
            candidate = x.copy()
            log_hastings = np.zeros(N)
            kind = rng.random(N)  # the proposal of each particle, drawn independently of its state
            z_all = rng.standard_normal((N, d + 1))
            for part, dim, fit in ((tau < 0, d, fits[0]), (tau >= 0, d + 1, fits[1])):
                if fit is None or not part.any():
                    continue
                # not dropped: independent or random walk (1/2 each); dropped: independent 0.4, random walk
                # 0.4, and 0.2 a wide random walk of delta alone (sd 10 % of its prior range; comment-ok: design width): a cloud that
                # collapsed away from the mode of delta cannot reach it with proposals fitted to itself
                ind = kind[part] < (0.5 if dim == d else 0.4)
                current = x[part, :dim]
                proposed, log_hastings[part] = FittedMove(*fit).propose(current, z_all[part, :dim], ind)
                if dim > d:
                    wide = kind[part] >= 0.8
                    proposed[wide, :d] = current[wide, :d]
                    proposed[wide, d] = current[wide, d] + 0.1 * (hi - lo) * z_all[part, d][wide]
                candidate[np.ix_(np.flatnonzero(part), np.arange(dim))] = proposed
            c_theta, c_delta = candidate[:, :d], candidate[:, d]
            inside = np.all((c_theta > self.lower) & (c_theta < self.upper), axis=1)
            inside &= (tau < 0) | ((c_delta > lo) & (c_delta < hi))  # uniform priors
            log_u = np.log(rng.random(N))
            accept = np.zeros(N, bool)
            if inside.any():
                where_in = np.flatnonzero(inside)
                c_past, c_inc, c_mean, c_cov = self._candidate_terms(storey, c_theta[inside], c_delta[inside],
                                                                      tau[inside], k, u, y)
                ok = accepted(log_u[inside], past[inside] + phi * inc[inside], c_past + phi * c_inc,
                              log_hastings[inside])
                where = where_in[ok]
                accept[where] = True
                theta, delta = theta.copy(), delta.copy()
                past, inc, mean_k, cov_k = past.copy(), inc.copy(), mean_k.copy(), cov_k.copy()
                theta[where], delta[where] = c_theta[where], c_delta[where]
                past[where], inc[where], mean_k[where], cov_k[where] = c_past[ok], c_inc[ok], c_mean[ok], c_cov[ok]
            acceptance_total += float(accept.mean())
            sweeps += 1
        return theta, delta, past, inc, mean_k, cov_k

    def _candidate_terms(self, storey, theta, delta, tau, k, u, y):
        """``log p(y_{0:k-1} | path)``, the increment of step ``k``, and the filtered
        mean and covariance at ``k`` for candidate paths (one re-filter of the history)."""
        R = self._run["R"]
        now = KalmanBank(self._model(effective_theta(theta, delta, tau, storey)), R, self.process_noise_std)
        if k == 0:
            mean, cov = now.initial_state()
            mean_k, cov_k, inc = now.step(mean, cov, y[0])
            return np.zeros(theta.shape[0]), inc, mean_k, cov_k
        # a change at step k acts on the prediction into k: the history y_{0:k-1} has none
        tau_past = np.where(tau < k, tau, -1)
        past, mean, cov = path_log_likelihood(self.building, self.dt, theta, delta, tau_past, storey, u[:k], y[:k],
                                              R, self.process_noise_std, self.channels, return_state=True)
        mean_k, cov_k, inc = now.step(mean, cov, y[k], u[k - 1], u[k])
        return past, inc, mean_k, cov_k
