"""Model-class selection from log-evidence: each candidate Markov kernel (or
model) is a class ``M_j``; with equal prior model probabilities,
``P(M_j | D^{1:s}) = exp(log Z_j) / sum_k exp(log Z_k)`` (log-sum-exp).

One bank of model classes (:class:`ModelBank`: prior probabilities, evidences, the classes still running) serves
the comparison of finished runs (:func:`compare`) and the on-line damage monitors, which prune classes that stay
improbable (:class:`~seqbayes.structural.stiffness_drop.StiffnessDropMonitor`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .weights import normalise

__all__ = ["compare", "ModelComparison", "ModelBank"]


@dataclass(frozen=True, eq=False)
class ModelBank:
    """Model classes compared by their evidence, on-line.

    Attributes
    ----------
    log_prior : (C,) array
        Log prior probabilities of the classes.
    log_evidence : (C,) array
        Each class's cumulative log-evidence.
    active : (C,) bool array
        The classes still updated (the others were pruned and have probability 0).
    low_steps : (C,) int array
        Consecutive updates each class has spent below the pruning threshold.
    """

    log_prior: np.ndarray
    log_evidence: np.ndarray
    active: np.ndarray
    low_steps: np.ndarray

    @classmethod
    def start(cls, prior_probabilities) -> "ModelBank":
        """Every class active, with no evidence yet."""
        log_prior = np.log(np.asarray(prior_probabilities, dtype=float))
        c = log_prior.size
        return cls(log_prior, np.zeros(c), np.ones(c, bool), np.zeros(c, int))

    def log_probabilities(self) -> np.ndarray:
        """``log P(M_c | data)`` among the active classes (``-inf`` for pruned ones), ``(C,)``."""
        return normalise(np.where(self.active, self.log_prior + self.log_evidence, -np.inf))

    def updated(self, log_evidence, prune_below: float = 0.0, prune_after: int = 1) -> "ModelBank":
        """The bank with the classes' new ``log_evidence``; with ``prune_below > 0`` a class whose probability stays
        below it for ``prune_after`` consecutive updates stops being active (the beam pruning of multiple-model
        trackers)."""
        bank = ModelBank(self.log_prior, np.asarray(log_evidence, dtype=float), self.active, self.low_steps)
        if prune_below <= 0:
            return bank
        low = np.exp(bank.log_probabilities()) < prune_below
        low_steps = np.where(low, self.low_steps + 1, 0)
        return ModelBank(self.log_prior, bank.log_evidence, self.active & (low_steps < prune_after), low_steps)


@dataclass(frozen=True, eq=False)
class ModelComparison:
    """Per-step comparison of model classes.

    Attributes
    ----------
    names : tuple of str
    log_evidence : (S, M) array
        Cumulative log-evidence per step and model.
    log_evidence_increments : (S, M) array
    probabilities : (S, M) array
        Posterior model probabilities per step.
    """

    names: tuple
    log_evidence: np.ndarray
    log_evidence_increments: np.ndarray
    probabilities: np.ndarray

    @property
    def best(self) -> str:
        """The most probable model after the last step."""
        return self.names[int(np.argmax(self.log_evidence[-1]))]

    def log_bayes_factor(self, a: str, b: str) -> np.ndarray:
        """``log Z_a - log Z_b`` per step, ``(S,)``."""
        ia, ib = self.names.index(a), self.names.index(b)
        return self.log_evidence[:, ia] - self.log_evidence[:, ib]

    def table(self) -> str:
        """A plain-text table: cumulative log-evidence and probability per step and model."""
        head = "step  " + "  ".join(f"{n + ' logZ':>14s} {'P(' + n + ')':>9s}" for n in self.names)
        rows = [head]
        for s in range(self.log_evidence.shape[0]):
            cells = "  ".join(f"{self.log_evidence[s, j]:14.3f} {self.probabilities[s, j]:9.3f}"
                              for j in range(len(self.names)))
            rows.append(f"{s + 1:4d}  {cells}")
        rows.append(f"most probable: {self.best}")
        return "\n".join(rows)

    def __str__(self) -> str:
        return self.table()


def compare(results: Mapping[str, Any], prior_probabilities: ArrayLike | None = None) -> ModelComparison:
    """Compare model classes by log-evidence.

    Parameters
    ----------
    results : mapping name -> Result (or -> (S,) array of cumulative log-evidence)
        All with the same number of steps.
    prior_probabilities : mapping name -> float, optional
        Prior model probabilities (equal by default).

    Returns
    -------
    ModelComparison
    """
    if not results:
        raise ValueError("results: at least one model is needed")
    names = tuple(results)
    columns = []
    for name in names:
        r = results[name]
        values = np.asarray(r.log_evidence if hasattr(r, "log_evidence") else r, dtype=float)
        if values.ndim != 1 or values.size == 0:
            raise ValueError(f"results[{name!r}]: expected a non-empty 1-D log-evidence per step")
        columns.append(values)
    lengths = {c.size for c in columns}
    if len(lengths) != 1:
        raise ValueError(f"results: models have different numbers of steps {sorted(lengths)}")
    log_z = np.column_stack(columns)
    increments = np.diff(np.vstack([np.zeros(len(names)), log_z]), axis=0)
    prior = np.full(len(names), 1.0 / len(names))
    if prior_probabilities is not None:
        prior = np.array([float(prior_probabilities[n]) for n in names])
        if np.any(prior <= 0):
            raise ValueError("prior_probabilities: must be positive")
    bank = ModelBank.start(prior / prior.sum())
    probabilities = np.array([np.exp(bank.updated(row).log_probabilities()) for row in log_z])
    return ModelComparison(names, log_z, increments, probabilities)

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from collections.abc import Mapping
    from typing import Any
    from numpy.typing import ArrayLike
