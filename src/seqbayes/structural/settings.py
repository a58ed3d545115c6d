"""The structural samplers' settings as components: the resample-move schedule they share
(:class:`ResampleMoveSettings`), SG-EnMCMC's samplers (:class:`Exact`, the exact-posterior resample-move sampler;
:class:`Ensemble`, the paper's ensemble variant), its transitions (:class:`Transitions`) and the noise levels estimated
with the stiffness (:class:`NoiseScales`); and the map from the flat settings of a TOML ``[sampler]`` table or of
earlier scripts onto them (:func:`sg_from_flat`)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

__all__ = ["ResampleMoveSettings", "Exact", "Ensemble", "Transitions", "NoiseScales", "FLAT_SG", "flat_defaults",
           "sg_from_flat", "STATE_MOVES", "SAMPLERS", "PROPOSALS", "LIKELIHOODS", "NOISE_PARAMETERS"]

STATE_MOVES = ("regression", "shift", "inherit")
SAMPLERS = ("resample-move", "paper")
PROPOSALS = ("mixture", "independent", "random_walk")
LIKELIHOODS = ("kalman", "enkf")
NOISE_PARAMETERS = ("channel", "shared")


@dataclass(frozen=True)
class ResampleMoveSettings:
    """The resample-move schedule the structural samplers share (this module's exact sampler and the
    stiffness-drop monitor, :mod:`seqbayes.structural.stiffness_drop`).

    Parameters
    ----------
    ess_threshold : float
        The tempering keeps the ESS at ``ess_threshold * N`` before a resample-move (0.3).
    moves_per_particle : float
        Sweeps are repeated until the acceptance rates sum to this (1: each particle is expected to have moved once).
    max_sweeps : int
        At most this many Metropolis-Hastings sweeps per event (10).
    resampling : str
        Scheme of :mod:`seqbayes.weights` (systematic).
    """

    ess_threshold: float = 0.3
    moves_per_particle: float = 1.0
    max_sweeps: int = 10
    resampling: str = "systematic"

    def __post_init__(self):
        if not 0 < self.ess_threshold <= 1:
            raise ValueError(f"ess_threshold: must be in (0, 1], got {self.ess_threshold}")
        if not self.moves_per_particle > 0:
            raise ValueError(f"moves_per_particle: must be positive, got {self.moves_per_particle}")
        if not isinstance(self.max_sweeps, (int, np.integer)) or self.max_sweeps < 1:
            raise ValueError(f"max_sweeps: expected an integer >= 1, got {self.max_sweeps!r}")


@dataclass(frozen=True)
class Exact(ResampleMoveSettings):
    """The exact-posterior resample-move sampler (the default; the module docstring).

    Parameters
    ----------
    proposal : {"independent", "mixture", "random_walk"}
        Metropolis-Hastings proposal (independent: acceptance ~0.8 on the shear buildings measured).
    proposal_scale : float
        Scale of the independent proposal's covariance (sd factor).
    likelihood : {"kalman", "enkf"}
        Each particle's filter: the exact Kalman filter of the linear model, or a stochastic EnKF of ``enkf_members``
        members per particle (:class:`~seqbayes.structural.filters.enkf.EnKFBank`) for models without an exact filter:
        a random, biased likelihood estimate carried by each particle (pseudo-marginal form), so the target is the
        posterior under the EnKF likelihood, which approaches the exact one as ``enkf_members`` grows.
    enkf_members : int
        Ensemble size per particle with ``likelihood="enkf"``.
    ess_threshold, moves_per_particle, max_sweeps, resampling
        As :class:`ResampleMoveSettings`.
    """

    proposal: str = "independent"
    proposal_scale: float = 1.0
    likelihood: str = "kalman"
    enkf_members: int = 50

    name = "resample-move"

    def __post_init__(self):
        super().__post_init__()
        if self.proposal not in PROPOSALS:
            raise ValueError(f"proposal: expected one of {PROPOSALS}, got {self.proposal!r}")
        if not self.proposal_scale > 0:
            raise ValueError(f"proposal_scale: must be positive, got {self.proposal_scale}")
        if self.likelihood not in LIKELIHOODS:
            raise ValueError(f"likelihood: expected one of {LIKELIHOODS}, got {self.likelihood!r}")
        if not isinstance(self.enkf_members, (int, np.integer)) or self.enkf_members < 2:
            raise ValueError(f"enkf_members: expected an integer >= 2, got {self.enkf_members!r}")


@dataclass(frozen=True)
class Ensemble:
    """The paper's ensemble variant (:mod:`seqbayes.structural.ensemble`): one EnKF member per ``theta`` and a
    Liu-West kernel move in place of Eq. 27.

    Parameters
    ----------
    ess_threshold : float
        Resample when ESS < ``ess_threshold * N`` (0.5).
    shrinkage : float
        Liu-West ``a`` in (0, 1]; ``1`` disables the rejuvenation move (0.5, the measured calibration).
    conditional : bool
        Condition the EnKF moments on theta.
    centre : {"regression", "member"}
        Centre of each member's predictive density
        (:func:`~seqbayes.structural.filters.enkf.predictive_log_likelihood`).
    state_move : {"regression", "shift", "inherit"}
        State of a moved member: regenerated from the fitted ``E[X | theta]`` at its new ``theta`` plus a residual
        drawn without replacement from all members (default); the parent's state shifted along the fitted slope; or
        the parent's state unchanged (the paper's implicit choice).
    leverage_correction : bool
    resampling : str
        Scheme of :mod:`seqbayes.weights` (the paper's is multinomial).
    """

    ess_threshold: float = 0.5
    shrinkage: float = 0.5
    conditional: bool = True
    centre: str = "regression"
    state_move: str = "regression"
    leverage_correction: bool = True
    resampling: str = "systematic"

    name = "paper"

    def __post_init__(self):
        if not 0 < self.ess_threshold <= 1:
            raise ValueError(f"ess_threshold: must be in (0, 1], got {self.ess_threshold}")
        if not 0 < self.shrinkage <= 1:
            raise ValueError(f"shrinkage: must be in (0, 1], got {self.shrinkage}")
        if self.centre not in ("member", "regression"):
            raise ValueError(f"centre: expected 'member' or 'regression', got {self.centre!r}")
        if self.state_move not in STATE_MOVES:
            raise ValueError(f"state_move: expected one of {STATE_MOVES}, got {self.state_move!r}")
        if self.state_move != "inherit" and not self.conditional:
            raise ValueError("state_move: 'regression' and 'shift' need conditional=True")


@dataclass(frozen=True)
class Transitions:
    """How the transition matrices are computed.

    Parameters
    ----------
    level : int, None or "auto"
        Sparse-grid level of the transition matrices; ``None`` exact matrices; ``"auto"``: exact for the exact
        sampler, level 6 (the paper's) for the ensemble variant. With a Bouc-Wen building ``None``/``"auto"`` is the
        RK4 transition, an integer the exponential integrator with its linear part's matrices on a sparse grid.
    basis : str
        The sparse grid's hat basis (``"modified"``).
    surrogate : {None, "auto"}
        ``"auto"``: choose the transition by measurement at this run's sizes
        (:func:`seqbayes.structural.surrogate.choose_transition`), overriding ``level``; the choice and its reason
        are in the result's ``surrogate``. Timing-dependent: pin the chosen ``level`` to repeat a run elsewhere.
    surrogate_options : dict, optional
        Keyword arguments of :func:`~seqbayes.structural.surrogate.choose_transition` (for Bouc-Wen ``probe``,
        the run's ground acceleration, is required).
    given : SparseGridTransition or transition, optional
        A transition built beforehand, used as it is.
    """

    level: int | str | None = "auto"
    basis: str = "modified"
    surrogate: str | None = None
    surrogate_options: dict | None = None
    given: object = None

    def __post_init__(self):
        if self.surrogate is not None:
            if self.surrogate != "auto":
                raise ValueError(f"surrogate: expected None or 'auto', got {self.surrogate!r}")
            if self.given is not None:
                raise ValueError("surrogate: 'auto' chooses the transition; do not pass transition= as well")


@dataclass(frozen=True)
class NoiseScales:
    """The measurement noise estimated with the stiffness (the module docstring; the exact sampler with the Kalman
    likelihood): a log scale factor of ``measurement_noise`` per channel (``kind="channel"``) or one shared by all
    channels (``"shared"``), log-uniform over ``bounds`` (``lower < 1 < upper``)."""

    kind: str = "channel"
    bounds: tuple = (0.25, 4.0)

    def __post_init__(self):
        if self.kind not in NOISE_PARAMETERS:
            raise ValueError(f"noise_parameters: expected None or one of {NOISE_PARAMETERS}, got {self.kind!r}")
        lo, hi = (float(b) for b in self.bounds)
        if not 0 < lo < 1 < hi or not np.isfinite(hi):
            raise ValueError(f"noise_scale_bounds: need 0 < lower < 1 < upper, got {self.bounds}")


#: The flat keywords of SGEnMCMC before its components (a TOML ``[sampler]`` table keeps them):
#: ``name -> (component, field)``.
FLAT_SG = {"ess_threshold": ("sampler", "ess_threshold"), "resampling": ("sampler", "resampling"),
           "proposal": ("exact", "proposal"), "proposal_scale": ("exact", "proposal_scale"),
           "moves_per_particle": ("exact", "moves_per_particle"), "max_sweeps": ("exact", "max_sweeps"),
           "likelihood": ("exact", "likelihood"), "enkf_members": ("exact", "enkf_members"),
           "shrinkage": ("ensemble", "shrinkage"), "conditional": ("ensemble", "conditional"),
           "centre": ("ensemble", "centre"), "state_move": ("ensemble", "state_move"),
           "leverage_correction": ("ensemble", "leverage_correction"),
           "level": ("transitions", "level"), "basis": ("transitions", "basis"),
           "surrogate": ("transitions", "surrogate"), "surrogate_options": ("transitions", "surrogate_options"),
           "transition": ("transitions", "given"), "noise_parameters": ("noise", "kind"),
           "noise_scale_bounds": ("noise", "bounds"), "sampler": ("sampler", None)}


def flat_defaults() -> dict:
    """Each flat setting's default (None where the sampler decides: ``ess_threshold``, ``noise_parameters``)."""
    fields = {name: {f.name: f.default for f in dataclasses.fields(cls)}
              for name, cls in (("sampler", Exact), ("exact", Exact), ("ensemble", Ensemble),
                                ("transitions", Transitions), ("noise", NoiseScales))}
    out = {name: fields[part][f] for name, (part, f) in FLAT_SG.items() if f is not None}
    return {**out, "ess_threshold": None, "noise_parameters": None, "sampler": "resample-move"}


def sg_from_flat(**flat) -> dict:
    """The components of SGEnMCMC's flat settings (a TOML ``[sampler]`` table, earlier scripts), as its keywords:
    ``SGEnMCMC(building, dt, lower, upper, noise, **sg_from_flat(sampler="paper", level=4))``.

    Raises
    ------
    TypeError
        A name that is not one of :data:`FLAT_SG`.
    """
    unknown = sorted(set(flat) - set(FLAT_SG))
    if unknown:
        raise TypeError(f"{unknown[0]}: not a setting of SGEnMCMC (its flat settings: {', '.join(FLAT_SG)})")
    paper = flat.get("sampler", "resample-move") == "paper"
    if flat.get("sampler", "resample-move") not in SAMPLERS:
        raise ValueError(f"sampler: expected one of {SAMPLERS}, got {flat['sampler']!r}")
    parts = {}
    for name, value in flat.items():
        component, field_name = FLAT_SG[name]
        if field_name is not None:
            parts.setdefault(component, {})[field_name] = value
    sampler = parts.get("sampler", {})
    if sampler.get("ess_threshold") is None:
        sampler.pop("ess_threshold", None)
    exact, ensemble = Exact(**parts.get("exact", {})), Ensemble(**parts.get("ensemble", {}))  # both validated
    chosen = dataclasses.replace(ensemble if paper else exact, **sampler)
    noise = parts.get("noise")
    return {"sampler": chosen, "transitions": Transitions(**parts.get("transitions", {})),
            "noise": None if noise is None or noise.get("kind") is None else NoiseScales(**noise)}
