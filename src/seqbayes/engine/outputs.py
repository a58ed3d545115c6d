"""What the numbers a step leaves behind may hold: one definition for the engine and the run store.

:func:`check_step` checks a step's state and record when :func:`~seqbayes.engine.pipeline.assimilate`
returns them, and the run store checks every array of a file it opens (:func:`seqbayes.store.base.check_finite`)
with the same rules (:data:`OUTPUTS`, looked up by :func:`allowed`). A state the engine hands out is
therefore always one the store re-opens: a step that would break this raises before anything is stored.

Names are the state's and record's attribute names (``posterior``, ``log_weights``,
``log_evidence_variance``, SMC^2's ``cloud_x`` ...); the store maps its variable names to them
(``state_log_evidence_variance`` -> ``log_evidence_variance``, :func:`seqbayes.store.snapshot.output_name`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np

__all__ = ["Allowed", "OUTPUTS", "allowed", "violation", "check_step", "InvalidStepError"]


class InvalidStepError(RuntimeError):
    """A step left a value its state or record may not hold (:data:`OUTPUTS`); nothing was stored."""


@dataclass(frozen=True)
class Allowed:
    """The non-finite values an array may hold."""

    nan: bool = False
    pos_inf: bool = False
    neg_inf: bool = False

    def bad(self, values: np.ndarray) -> np.ndarray:
        """Boolean mask of the entries of ``values`` (float) this rule refuses."""
        bad = np.zeros(values.shape, dtype=bool)
        if not self.nan:
            bad |= np.isnan(values)
        if not self.pos_inf:
            bad |= values == np.inf
        if not self.neg_inf:
            bad |= values == -np.inf
        return bad


FINITE = Allowed()
#: What an array not named in :data:`OUTPUTS` may hold: anything but NaN (a log-density may be -inf).
NOT_NAN = Allowed(pos_inf=True, neg_inf=True)

#: The rule of each named output.
OUTPUTS = {
    # samples are weighed and moved again when the run resumes
    "posterior": FINITE, "predictive": FINITE, "particles": FINITE, "dataset": FINITE,
    "log_weights": Allowed(neg_inf=True), "posterior_log_weights": Allowed(neg_inf=True),  # -inf: zero weight
    # NaN: not estimated (a multi-stage tempering path's increment, SMC^2; step_standard_errors), and then
    # unknown for the cumulative log-evidence of every later step too
    "log_evidence_variance": Allowed(nan=True, pos_inf=True),
    "diagnostics": Allowed(nan=True, pos_inf=True, neg_inf=True),  # NaN: a diagnostic not computed
}


def allowed(name: str) -> Allowed:
    """The rule of output ``name`` (:data:`OUTPUTS`, else :data:`NOT_NAN`)."""
    return OUTPUTS.get(name, NOT_NAN)


def violation(name: str, values, rule_name: str | None = None) -> str | None:
    """``None`` if ``values`` keeps the rule of output ``rule_name`` (default ``name``), else a message naming
    ``name``, the count of refused values and the first one's index."""
    values = np.asarray(values)
    if values.dtype.kind != "f":
        return None
    bad = allowed(name if rule_name is None else rule_name).bad(values)
    if not bad.any():
        return None
    where = np.argwhere(bad)[0] if bad.ndim else ()
    return f"{name} holds {int(bad.sum())} NaN/inf value(s), first at index {tuple(int(i) for i in where)}"


def _named_values(obj, prefix: str = ""):
    """``(name, value)`` of the float arrays and floats among a dataclass's fields (a dict field's entries named
    ``field_key``, a dataclass field's ``field_attr``), one level deep below the top."""
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        name = prefix + f.name
        if isinstance(value, dict):
            yield from ((f"{name}_{key}", v) for key, v in value.items() if isinstance(v, np.ndarray))
        elif isinstance(value, (np.ndarray, float)):
            yield name, value
        elif dataclasses.is_dataclass(value) and not isinstance(value, type) and not prefix:
            yield from _named_values(value, f"{name}_")


def check_step(state, record) -> None:
    """Raise :class:`InvalidStepError` if ``state`` (a dataclass: ``SamplerState``, SMC^2's ``NestedState``) or
    ``record`` (:class:`~seqbayes.results.StepRecord`) holds a value :data:`OUTPUTS` refuses.

    The state's prior is checked through its own fields (``prior_centres`` ...: by the rule of anything
    unnamed), the record's posterior, weights and predictive by theirs.
    """
    pairs = [("posterior", record.posterior), ("log_weights", record.log_weights), ("predictive", record.predictive),
             *_named_values(state)]
    for name, values in pairs:
        message = violation(name, values)
        if message is not None:
            raise InvalidStepError(f"step {record.info.step}: the sampler's new state is invalid: {message}; "
                                   f"nothing was stored (please report this with the datasets)")
