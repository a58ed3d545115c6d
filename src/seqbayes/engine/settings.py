"""The settings of an on-line sampler (:class:`SamplerConfig`) and the thresholds the engine uses."""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..core.tempering import Adaptive, Single
from ..moves.schedule import HIGH_DIMENSION
from ..predictive.pmmh import MOVE_BUDGET
from ..resampling import SCHEMES

__all__ = ["SamplerConfig", "PREDICTIVE_METHODS", "HIGH_DIMENSION", "MOVE_BUDGET"]

#: ``"auto"`` resolves to ``"history"`` for a kernel whose every parameter is static, ``"smc2"`` (nested
#: filters, :mod:`seqbayes.predictive.smc2`) for one with static and drifting components, else ``"transition"``.
PREDICTIVE_METHODS = ("auto", "transition", "kde", "history", "smc2")


@dataclass(frozen=True)
class SamplerConfig:
    """Settings of an on-line sampler (validated on construction).

    Attributes
    ----------
    move : {"stretch", "gaussian"}
        SEMC's affine-invariant stretch move or SMC's Gaussian random walk.
    n_samples : int
    tempering : bool
        Adaptive tempering inside a step (default); ``False`` is the paper's single reweighting.
    tempering_ess : float
        Target ESS fraction of each tempering stage (0.5).
    max_stages : int
        Cap on tempering stages per step (1000). The stages grow about linearly with how far
        the data lie from the current samples (a dataset offset by 100 noise sds from the
        prediction takes ~200); beyond the cap the step stops with
        :class:`TemperingLimitError` (usually wrong units or a broken sensor) and the
        sampler's state is unchanged.
    tempering_threshold : float
        Tempering starts only when assimilating the rest of the dataset at once would leave
        less than this ESS fraction (0.1): a milder reweighting is done in one stage, whose
        resampled duplicates the moves then spread (fewer resamplings, less Monte Carlo
        error on static parameters).
    ess_threshold : float
        Resample at the last stage when ESS < ``ess_threshold * N`` (authors' code: 0.5).
    resampling : str
        ``"systematic"``, ``"multinomial"`` (the paper's), ``"stratified"`` or ``"residual"``.
    predictive : {"auto", "transition", "kde", "history", "smc2"}
        Predictive prior construction (see :mod:`seqbayes.predictive.mixture`). ``"auto"`` (default):
        ``"history"`` when every parameter is static (the exact prior, re-evaluating the past
        datasets as IBIS does; each evaluation costs one likelihood call per past dataset),
        ``"smc2"`` when the kernel has both static and drifting components (outer particles
        over the static parameters, each with an inner filter over the drifting ones:
        :mod:`seqbayes.predictive.smc2`), ``"transition"`` otherwise (every parameter drifts).
    shrink_static : bool
        Liu-West shrinkage of the static dimensions' kernel density.
    target_acceptance : float
        SEMC's target acceptance rate ``alpha_tr``.
    step_size : float
        SEMC's initial stretch step size ``u``.
    max_virtual : int
        Cap on SEMC virtual iterations (sweeps) per stage (30).
    virtual_tolerance : float
        Stop virtual iterations when ``|alpha - alpha_old| < virtual_tolerance * alpha_tr``.
    n_moves : int
        Minimum MH steps (SMC) or sweeps (SEMC) per stage (3, as the authors' ``thinchain``).
    moved_fraction : float
        Keep moving until this fraction of the particles has moved at least once in the
        stage (0.9; 0 disables), up to ``max_moves`` (SMC) or ``max_virtual`` (SEMC).
    max_moves : int
        Cap on SMC's MH steps per stage.
    move_every_stage : bool or None
        ``True`` moves the particles after every stage (the paper's Algorithm 4). ``False``
        moves only after a resampling, to rejuvenate its duplicates, as IBIS (Chopin 2002)
        and ``particles`` do: cheaper (no likelihood evaluation in a step that keeps its ESS),
        but duplicates from earlier resamplings are then moved less often. ``None`` (default):
        ``True``, except with the history prior, where the particles are resampled and moved
        only when the ESS falls below ``ess_threshold`` (every move re-evaluates the past
        datasets; moving only then spaces the moves out as the posterior concentrates and
        bounds the amortised cost of an update), and a step that did not move takes its
        evidence from the weights, not from the importance sampler. ``False`` also defers
        that resample-move to the next dataset's arrival, as ``particles`` does.
    n_independent : int
        Independence-MH sweeps (3) at the end of a step with ``evidence="importance"``
        (proposals from the posterior-fitted importance density; each sweep after the
        first costs N likelihood evaluations).
    min_evidence_ess, max_refits : float, int
        When the importance ESS is below ``min_evidence_ess * N`` (0.3), the importance
        density is refitted to the swept particles and the estimate repeated, up to
        ``max_refits`` (5) times.
        With 1 (the paper's SMC) the error of a static parameter after 5 steps grows ~1.5x.
    proposal_scale : float
        SMC's ``gamma`` of Eq. (A7).
    conflict_threshold : float
        A :class:`PriorDataConflictWarning` is issued when a step's posterior mean lies more than
        this many prior sds from its prior mean (``StepInfo.prior_data_conflict``; 4), or when it
        is carried by a few of the predictive mixture's components (``StepInfo.ancestor_ess``
        below ``remedy_ess * N``, which also starts the remedy; docs/prior_data_conflict.md).
    conflict_remedy : bool
        The exact remedy for prior-data conflict (on by default). A step whose posterior
        is carried by the far tail of the predictive mixture (``StepInfo.ancestor_ess`` below
        ``remedy_ess * N``, or ``StepInfo.prior_data_conflict`` above ``conflict_threshold``) is
        assimilated again on the path space of the last ``remedy_lag`` steps, whose target is the
        model's exact one (see :class:`~seqbayes.predictive.paths.PathSpace`); ``StepInfo.path_steps`` records it.
        Applies to the ``"transition"`` and ``"kde"`` predictives of kernels in which every
        parameter moves; ``"history"`` is exact already, and ``"smc2"`` is not covered.
    remedy_ess : float
        Fraction of N below which the ancestor ESS triggers the remedy (0.05; five times that
        right after a path-space step).
    remedy_lag : int
        Steps kept for the path-space target (10): exact when the run has at most that many steps,
        else the window's first state takes the (mixture) prior that step used. After a path-space
        step the next ones reach back to its window's first step, up to ``2 remedy_lag`` states
        (:func:`~seqbayes.core.state.remedy_window`).
    remedy_bridge : bool
        How the path-space step reaches its target. ``True`` (default): from the window's path prior
        (the window's first prior, then the kernel), tempering every likelihood of the window jointly, so
        that each mode of the path posterior (one per choice of the dataset a path gives up, under a
        kernel the data contradict) is weighed afresh and the window's evidence estimated directly.
        ``False``: from the stored paths of the previous posterior, tempering only the new dataset (about
        half the cost; it cannot reach a mode whose earlier states the earlier steps ruled out, which
        docs/prior_data_conflict.md shows costing exact sds and tens of nats). Both
        :class:`~seqbayes.predictive.paths.PathSpace`; docs/prior_data_conflict.md.
    n_inner : int
        SMC^2 (static and drifting parameters): particles of the default inner filter
        (:class:`~seqbayes.predictive.smc2.ParticleInnerFilter`) per outer particle (100).
    transform : bool
        Move in unconstrained coordinates (log / logit of bounded parameters; see
        :mod:`seqbayes.transforms`). ``False`` moves in the parameters' own
        coordinates, as the paper does.
    min_valid_fraction : float
        When fewer particles than this fraction have a non-zero likelihood, the step
        starts from draws of the prior restricted to the non-zero region (rejection
        sampling, at most 100 N likelihood evaluations; its mass enters the evidence).
        0 disables it (the paper's behaviour; advisable for very expensive likelihoods).
    evidence : {"importance", "path"}
        Estimator of the evidence increment: defensive importance sampling from the
        final posterior (:mod:`seqbayes.predictive.evidence`, N extra likelihood evaluations, whose
        draws also drive one independence-MH sweep of the particles), or the tempering
        path's product of mean weights alone (Eq. 1, the paper's). Both estimates are
        recorded in :class:`StepInfo`.
    pseudo_marginal_from : int
        From this many particles on (2048; 0 never), a step under the ``"transition"`` mixture prior
        (Eq. A3) lets its moves evaluate the prior by an unbiased estimate from a subsample of the
        mixture's components (pseudo-marginal moves, exact in distribution; ``O(N M)`` per sweep
        instead of ``O(N^2)``) where a pilot shows the estimate accurate, else exactly
        (:class:`~seqbayes.predictive.pseudo_marginal.SubsampledPrior`).
    scaled_moves : bool or None
        Moves that keep working as the dimension grows (:mod:`seqbayes.moves.scaled`). Each
        round at a stage is an independence-MH sweep (every particle proposes a fresh draw of a density
        fitted to the other half of the particles: the Gaussian of their mean and covariance above d = 10,
        the evidence's kernel density + Student t up to d = 10), then a local sweep (SMC: the
        random walk with ``2.38 / sqrt(d)`` times the particles' covariance factor; SEMC: the
        differential-evolution move, half against half; both scaled by a factor that Eq. 9 adapts towards
        acceptance 0.234). Rounds stop when the particles have travelled on average ``2 d`` squared
        whitened units (the distance between two independent draws; half that with ``economy``) and
        ``moved_fraction`` of them have moved, after at least ``n_moves`` rounds (1 with ``economy``) and
        at most ``max_moves`` (SMC) / ``max_virtual`` (SEMC). Above d = 10 the evidence's importance
        density uses the fitted Gaussian in place of the kernel density. ``None`` (default): on when
        d > 10 or with ``economy``, so that runs with up to 10 parameters are unchanged.
        ``proposal_scale``, ``step_size`` and ``target_acceptance`` do not apply to these moves.
    economy : bool
        Fewer likelihood calls for expensive models (docs/core.md, "Economy of likelihood calls"): the
        scaled moves (whatever d), stopped at half the travel and 70 % moved (or ``moved_fraction`` if
        lower), plus one more move at the last stage of a tempered step; no restart from the restricted
        prior while at least d + 1 particles have a non-zero likelihood (the restart's rejection sampling
        costs N / (valid fraction) calls); the importance density refitted once to the particles after
        ``n_independent`` independence sweeps, and the evidence estimated from all the sweeps' draws
        after that refit, sweeping on until the increment's standard error is below 0.02 nats (at most
        ``n_independent + 2 max_refits`` sweeps).
    surrogate : None, "quadratic", "auto" or callable
        Exact delayed acceptance of the moves (:mod:`seqbayes.moves.delayed`; Christen and Fox 2005): a cheap
        log target screens every proposal of the random-walk and stretch moves, and only the survivors are
        evaluated by the likelihood; a second accept/reject keeps the target exact. ``None`` (default): no
        screen. ``"quadratic"``: a quadratic fitted to the stage's particles' log targets. ``"auto"``: that
        quadratic, after a first plain sweep per stage, for as long as it yields more accepted moves per
        likelihood evaluation than the plain sweep did. A callable ``surrogate(theta (n, d), dataset) -> (n,)``:
        a cheap approximation of the log-likelihood (a coarser model), with the prior's part fitted by the
        quadratic. ``StepInfo.n_screen_evaluations`` and ``n_screened_out`` count the cheap calls and the
        proposals they stopped. SMC^2's PMMH moves are screened by the quadratic fitted to the outer particles' log
        targets (``"quadratic"``, and ``"auto"``, which there screens every sweep; a callable is not used there), so
        that only the survivors re-run their inner filters over the whole history (:mod:`seqbayes.predictive.pmmh`). Not applied to the scaled moves or to the path-space
        remedy's sweeps.
    move_budget : float or None
        SMC^2 only: the PMMH evaluations one update may spend on deferrable moves, in units of ``N M`` (``M`` the
        inner particles, 1 for the Kalman inner filter; default :data:`MOVE_BUDGET` = 5). Moves beyond it wait for
        later updates (:mod:`seqbayes.predictive.pmmh`), which bounds the cost per update over a long stream.
        Deferrable are only the moves of an untempered update, and after a resampling only once the copies it left
        are as diverse as its weights were (which may spend up to ``pmmh.RESTORE_LIMIT`` = 4 times the budget more):
        a tempered update (a dataset the predictive does not cover) completes its moves whatever the budget, since
        each of its stages chooses the next exponent from the particles' ESS. ``None``: every rejuvenation completes
        in its update.
    strict_budget : bool
        SMC^2 only: ``True`` makes ``move_budget`` a hard cap on every update's PMMH moves (about one batch of re-runs
        beyond it at most): a tempered update's stages share one budget instead of completing their moves, and
        restoring the copies' diversity after a resampling spends from it instead of up to ``pmmh.RESTORE_LIMIT``
        budgets more; the rest is deferred to later updates. An update then costs at most about
        ``(1 + move_budget) N M`` plus the guide's pilot, however far the data lie from the predictive. Exact as the
        default's deferral is, but a stream that the kernel contradicts (every update tempered far) loses accuracy
        with it (``docs/benchmarks.md``, "Coulomb at 50,000 calls"). SEMC's PMMH then proposes by differential
        evolution instead of the stretch move, which travels further per inner-filter re-run
        (:mod:`seqbayes.predictive.pmmh`). ``False`` (default): tempered updates complete their moves.
    """

    move: str
    n_samples: int = 1000
    tempering: bool = True
    tempering_ess: float = 0.5
    tempering_threshold: float = 0.1
    max_stages: int = 1000
    ess_threshold: float = 0.5
    resampling: str = "systematic"
    predictive: str = "auto"
    shrink_static: bool = True
    target_acceptance: float = 0.25
    step_size: float = 2.0
    max_virtual: int = 30
    virtual_tolerance: float = 0.1
    n_moves: int = 3
    proposal_scale: float = 1.0
    transform: bool = True
    min_valid_fraction: float = 0.5
    evidence: str = "importance"
    moved_fraction: float = 0.9
    max_moves: int = 30
    move_every_stage: bool | None = None
    n_independent: int = 3
    min_evidence_ess: float = 0.3
    max_refits: int = 5
    n_inner: int = 100
    conflict_threshold: float = 4.0
    conflict_remedy: bool = True
    remedy_ess: float = 0.05
    remedy_lag: int = 10
    remedy_bridge: bool = True
    pseudo_marginal_from: int = 2048
    scaled_moves: bool | None = None
    economy: bool = False
    surrogate: object = None
    move_budget: float | None = MOVE_BUDGET
    strict_budget: bool = False

    def __post_init__(self):
        self._check_run()
        self._check_tempering()
        self._check_moves()
        self._check_evidence()
        self._check_remedy()

    def _check_run(self):
        """The sampler, the number of particles, resampling, the predictive and the restart."""
        if self.move not in ("stretch", "gaussian"):
            raise ValueError(f"move: expected 'stretch' or 'gaussian', got {self.move!r}")
        if int(self.n_samples) != self.n_samples or self.n_samples < 2:
            raise ValueError(f"n_samples: must be an integer >= 2, got {self.n_samples}")
        if not 0.0 <= self.min_valid_fraction <= 1.0:
            raise ValueError(f"min_valid_fraction: must lie in [0, 1], got {self.min_valid_fraction}")
        if self.resampling not in SCHEMES:
            raise ValueError(f"resampling: unknown scheme {self.resampling!r}; choose from {sorted(SCHEMES)}")
        if self.predictive not in PREDICTIVE_METHODS:
            raise ValueError(f"predictive: expected one of {PREDICTIVE_METHODS}, got {self.predictive!r}")
        if _not_integer(self.n_inner, 1):
            raise ValueError(f"n_inner: must be an integer >= 1, got {self.n_inner}")
        if _not_integer(self.pseudo_marginal_from, 0):
            raise ValueError(f"pseudo_marginal_from: must be an integer >= 0, got {self.pseudo_marginal_from}")
        if self.economy not in (True, False):
            raise ValueError(f"economy: expected True or False, got {self.economy!r}")
        if not (self.surrogate is None or callable(self.surrogate) or self.surrogate in ("quadratic", "auto")):
            raise ValueError(f"surrogate: expected None, 'quadratic', 'auto' or a callable "
                             f"surrogate(theta, dataset), got {self.surrogate!r}")
        if self.move_budget is not None and not (isinstance(self.move_budget, (int, float))
                                                 and not isinstance(self.move_budget, bool) and self.move_budget > 0
                                                 and math.isfinite(self.move_budget)):
            raise ValueError(f"move_budget: expected None or a finite number > 0, got {self.move_budget!r}")
        if self.strict_budget not in (True, False):
            raise ValueError(f"strict_budget: expected True or False, got {self.strict_budget!r}")

    def _check_tempering(self):
        if not 0.0 < self.tempering_threshold <= self.tempering_ess:
            raise ValueError(f"tempering_threshold: must lie in (0, tempering_ess], got {self.tempering_threshold}")
        for name in ("tempering_ess", "ess_threshold"):
            value = getattr(self, name)
            if not 0.0 < value <= 1.0:
                raise ValueError(f"{name}: must lie in (0, 1], got {value}")
        if int(self.max_stages) != self.max_stages or self.max_stages < 1:
            raise ValueError(f"max_stages: must be an integer >= 1, got {self.max_stages}")

    def _check_moves(self):
        if not 0.0 < self.target_acceptance <= 1.0:
            raise ValueError(f"target_acceptance: must lie in (0, 1], got {self.target_acceptance}")
        if not self.step_size > 1.0:
            raise ValueError(f"step_size: must be > 1, got {self.step_size}")
        if self.max_virtual < 1 or self.n_moves < 1 or self.max_moves < 1:
            raise ValueError("max_virtual, max_moves and n_moves: must be >= 1")
        cap, cap_name = (self.max_moves, "max_moves") if self.move == "gaussian" else (self.max_virtual, "max_virtual")
        if self.n_moves > cap:
            raise ValueError(f"n_moves: {self.n_moves} exceeds {cap_name} {cap}")
        if not 0.0 <= self.moved_fraction <= 1.0:
            raise ValueError(f"moved_fraction: must lie in [0, 1], got {self.moved_fraction}")
        if not self.proposal_scale > 0:
            raise ValueError(f"proposal_scale: must be positive, got {self.proposal_scale}")
        if self.scaled_moves not in (None, True, False):
            raise ValueError(f"scaled_moves: expected True, False or None, got {self.scaled_moves!r}")

    def _check_evidence(self):
        if self.evidence not in ("importance", "path"):
            raise ValueError(f"evidence: expected 'importance' or 'path', got {self.evidence!r}")
        if not 0.0 <= self.min_evidence_ess <= 1.0 or self.max_refits < 0:
            raise ValueError("min_evidence_ess must lie in [0, 1] and max_refits be >= 0")
        if self.n_independent < 1:
            raise ValueError(f"n_independent: must be >= 1, got {self.n_independent}")

    def _check_remedy(self):
        if not self.conflict_threshold > 0:
            raise ValueError(f"conflict_threshold: must be positive, got {self.conflict_threshold}")
        if not 0.0 <= self.remedy_ess <= 1.0:
            raise ValueError(f"remedy_ess: must lie in [0, 1], got {self.remedy_ess}")
        if _not_integer(self.remedy_lag, 2):
            raise ValueError(f"remedy_lag: must be an integer >= 2, got {self.remedy_lag}")
        if self.remedy_bridge not in (True, False):
            raise ValueError(f"remedy_bridge: expected True or False, got {self.remedy_bridge!r}")

    def tempering_rule(self):
        """The tempering loop's rule (:class:`~seqbayes.core.tempering.Adaptive`, or :class:`~seqbayes.core.tempering.Single`
        without ``tempering``)."""
        if self.tempering:
            return Adaptive(self.max_stages, ess=self.tempering_ess, threshold=self.tempering_threshold)
        return Single(self.max_stages)

    def uses_scaled_moves(self, dim: int) -> bool:
        """Whether the moves of :mod:`seqbayes.moves.scaled` run for ``dim`` parameters (see ``scaled_moves``)."""
        if self.scaled_moves is not None:
            return bool(self.scaled_moves)
        return self.economy or dim > HIGH_DIMENSION


def _not_integer(value, minimum: int) -> bool:
    """Whether ``value`` is not an integer (``bool`` excluded) of at least ``minimum``."""
    return isinstance(value, bool) or int(value) != value or value < minimum
