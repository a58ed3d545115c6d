"""The settings of an on-line sampler: its components (:class:`SamplerConfig`) and the flat settings of a TOML
``[sampler]`` table or an earlier script, mapped onto the same components (:func:`from_flat`).

A sampler is composed of objects, each owning its settings and their validation: the moves
(:class:`~seqbayes.moves.stretch.Stretch`, :class:`~seqbayes.moves.gaussian.RandomWalk`), the tempering
(:class:`~seqbayes.core.tempering.Adaptive`, :class:`~seqbayes.core.tempering.Single`), the evidence
(:class:`~seqbayes.predictive.evidence.Importance`, :class:`~seqbayes.predictive.evidence.PathEvidence`), the predictive
prior (:class:`~seqbayes.predictive.base.Auto`, :class:`~seqbayes.predictive.transition.Transition`,
:class:`~seqbayes.predictive.history.History`, :class:`~seqbayes.predictive.smc2.SMC2`, ...) and the conflict remedy
(:class:`~seqbayes.predictive.transition.PathSpace`, :class:`~seqbayes.predictive.transition.Conflict`). Each setting is
declared once, as a field of its component; :data:`FLAT` names the component field each flat name maps to.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

from ..core.tempering import Adaptive, Single, Tempering
from ..moves.base import Moves
from ..moves.gaussian import RandomWalk
from ..moves.stretch import Stretch
from ..predictive.base import Auto, resolve_predictive
from ..predictive.evidence import Importance, PathEvidence
from ..predictive.history import History
from ..predictive.transition import Conflict, PathSpace
from ..predictive.smc2 import SMC2, ParticleInnerFilter
from ..predictive.transition import KernelDensity, Transition

__all__ = ["SamplerConfig", "FLAT", "OBJECTS", "from_flat", "flat_names"]


@dataclass(frozen=True)
class SamplerConfig:
    """What a sampler is made of: its sample size and its components, validated on construction.

    Attributes
    ----------
    n_samples : int
    moves : Moves
    tempering : Tempering
    evidence : Importance or PathEvidence
    predictive : predictive component
        Resolved against the kernel (:func:`~seqbayes.predictive.base.resolve_predictive`) by the driver.
    remedy : Conflict or PathSpace
    """

    n_samples: int = 1000
    moves: Moves = field(default_factory=Stretch)
    tempering: Tempering = field(default_factory=Adaptive)
    evidence: object = field(default_factory=Importance)
    predictive: object = field(default_factory=Auto)
    remedy: Conflict = field(default_factory=PathSpace)

    def __post_init__(self):
        if isinstance(self.n_samples, bool) or int(self.n_samples) != self.n_samples or self.n_samples < 2:
            raise ValueError(f"n_samples: must be an integer >= 2, got {self.n_samples!r}")
        for name, kind, example in (("moves", Moves, "Stretch() or RandomWalk()"),
                                    ("tempering", Tempering, "Adaptive() or Single()"),
                                    ("evidence", (Importance, PathEvidence), "Importance() or PathEvidence()"),
                                    ("remedy", Conflict, "PathSpace() or Conflict()")):
            if not isinstance(getattr(self, name), kind):
                raise TypeError(f"{name}: expected a component such as {example}, got {getattr(self, name)!r}")

    def resolved(self, kernel, dim: int) -> "SamplerConfig":
        """These settings for a run of ``dim`` parameters under ``kernel``: the predictive chosen and checked, the
        moves' defaults that depend on the dimension filled in."""
        return replace(self, moves=self.moves.resolved(int(self.n_samples), dim),
                       predictive=resolve_predictive(self.predictive, kernel))


#: Each flat setting (a TOML ``[sampler]`` key, a keyword of earlier versions) -> ``(component, field, type)``:
#: the component it configures ("moves" of either sampler, "stretch" or "walk" of one, "tempering", "adaptive",
#: "evidence", "remedy", "paths", "transition", "smc2") and its field there. The selectors (``tempering``,
#: ``evidence``, ``predictive``, ``conflict_remedy``, ``n_inner``) choose the component itself.
FLAT = {
    "n_moves": ("moves", "min_sweeps", "int"), "moved_fraction": ("moves", "moved_fraction", "float"),
    "move_every_stage": ("moves", "every_stage", "bool"), "transform": ("moves", "transform", "bool"),
    "scaled_moves": ("moves", "scaled", "bool"), "economy": ("moves", "economy", "bool"),
    "surrogate": ("moves", "screen", "any"),
    "step_size": ("stretch", "step_size", "float"), "target_acceptance": ("stretch", "target_acceptance", "float"),
    "max_virtual": ("stretch", "max_sweeps", "int"), "virtual_tolerance": ("stretch", "tolerance", "float"),
    "proposal_scale": ("walk", "scale", "float"), "max_moves": ("walk", "max_sweeps", "int"),
    "tempering": ("tempering", None, "bool"), "max_stages": ("tempering", "max_stages", "int"),
    "ess_threshold": ("tempering", "resample_below", "float"), "resampling": ("tempering", "scheme", "str"),
    "min_valid_fraction": ("tempering", "min_valid_fraction", "float"),
    "tempering_ess": ("adaptive", "ess", "float"), "tempering_threshold": ("adaptive", "threshold", "float"),
    "evidence": ("evidence", None, "str"), "n_independent": ("evidence", "sweeps", "int"),
    "min_evidence_ess": ("evidence", "min_ess", "float"), "max_refits": ("evidence", "max_refits", "int"),
    "conflict_remedy": ("remedy", None, "bool"), "conflict_threshold": ("remedy", "threshold", "float"),
    "remedy_ess": ("remedy", "ancestor_ess", "float"),
    "remedy_lag": ("paths", "lag", "int"), "remedy_bridge": ("paths", "bridge", "bool"),
    "predictive": ("predictive", None, "str"), "shrink_static": ("transition", "shrink_static", "bool"),
    "pseudo_marginal_from": ("transition", "pseudo_marginal_from", "int"),
    "n_inner": ("smc2", None, "int"), "move_budget": ("smc2", "move_budget", "float"),
    "strict_budget": ("smc2", "strict_budget", "bool"),
}
_PREDICTIVES = {"transition": Transition, "kde": KernelDensity, "history": History, "smc2": SMC2}
#: Keywords of earlier versions' drivers that :func:`from_flat` also maps (objects, not TOML settings): SMC^2's inner
#: filter and the history prior's running statistics.
OBJECTS = ("inner_filter", "history")


def flat_names(kind: str) -> tuple:
    """The flat settings a sampler of ``kind`` (``"SEMC"`` or ``"SMC"``) takes."""
    other = "walk" if kind == "SEMC" else "stretch"
    return tuple(name for name, (component, _, _) in FLAT.items() if component != other)


def from_flat(kind: str = "SEMC", **flat) -> dict:
    """The components of flat settings, as keywords of :class:`~seqbayes.SEMC` (``kind="SEMC"``) or
    :class:`~seqbayes.SMC`: ``SEMC(prior, kernel, loglike, **from_flat(tempering_ess=0.3, remedy_lag=5))``. The
    TOML ``[sampler]`` table maps onto the components this way, so that old configurations and stores keep their
    meaning; earlier scripts' ``inner_filter`` and ``history`` (:data:`OBJECTS`) map onto SMC^2's and the history
    prior's components.

    >>> from_flat("SMC", max_moves=5, evidence="path")["moves"]
    RandomWalk(min_sweeps=3, max_sweeps=5, moved_fraction=0.9, every_stage=None, transform=True, scaled=None, economy=False, screen=None, scale=1.0)

    Raises
    ------
    TypeError
        A name that is not a flat setting of ``kind`` (naming it).
    ValueError
        A value a component refuses (naming the component's field).
    """
    if kind not in ("SEMC", "SMC"):
        raise ValueError(f"kind: expected 'SEMC' or 'SMC', got {kind!r}")
    unknown = sorted(set(flat) - set(flat_names(kind)) - set(OBJECTS))
    if unknown:
        raise TypeError(f"{unknown[0]}: not a setting of {kind} (its flat settings: {', '.join(flat_names(kind))})")
    parts, named = {}, {}
    for name, value in flat.items():
        component, name_there, _ = FLAT.get(name, (None, None, None))
        if name_there is not None:
            part = "moves" if component in ("stretch", "walk") else component
            parts.setdefault(part, {})[name_there] = value
            named.setdefault(part, {})[name_there] = name

    def make(cls, *keys, **extra):
        """``cls`` of the parts ``keys``, a refused value named by its flat setting."""
        try:
            return cls(**{k: v for key in keys for k, v in parts.get(key, {}).items()}, **extra)
        except (TypeError, ValueError) as err:
            field_name = str(err).split(":", 1)[0]
            names = {k: v for key in keys for k, v in named.get(key, {}).items()}
            if field_name not in names:
                raise
            raise type(err)(names[field_name] + str(err)[len(field_name):]) from None

    moves = make(Stretch if kind == "SEMC" else RandomWalk, "moves")
    tempering = make(Adaptive, "tempering", "adaptive") if flat.get("tempering", True) else make(Single, "tempering")
    evidence = flat.get("evidence", "importance")
    if evidence not in ("importance", "path"):
        raise ValueError(f"evidence: expected 'importance' or 'path', got {evidence!r}")
    evidence = make(Importance, "evidence") if evidence == "importance" else PathEvidence()
    remedy = make(PathSpace, "remedy", "paths") if flat.get("conflict_remedy", True) else make(Conflict, "remedy")
    inner = flat.get("inner_filter", ParticleInnerFilter(flat["n_inner"]) if "n_inner" in flat else None)
    smc2 = make(SMC2, "smc2", **({} if inner is None else {"inner": inner}))
    method = flat.get("predictive", "auto")
    transition = make(KernelDensity if method == "kde" else Transition, "transition")
    choices = {"auto": Auto(transition=transition, history=History(flat.get("history")), smc2=smc2), "transition": transition, "kde": transition,
               "history": History(flat.get("history")), "smc2": smc2}
    if method not in choices:
        raise ValueError(f"predictive: expected one of {('auto', *_PREDICTIVES)}, got {method!r}")
    return {"moves": moves, "tempering": tempering, "evidence": evidence, "predictive": choices[method],
            "remedy": remedy}
