"""Model-class selection from log-evidence: each candidate Markov kernel (or
model) is a class ``M_j``; with equal prior model probabilities,
``P(M_j | D^{1:s}) = exp(log Z_j) / sum_k exp(log Z_k)`` (log-sum-exp).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .weights import logsumexp

__all__ = ["compare", "ModelComparison"]


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
    log_prior = np.zeros(len(names)) - np.log(len(names))
    if prior_probabilities is not None:
        p = np.array([float(prior_probabilities[n]) for n in names])
        if np.any(p <= 0):
            raise ValueError("prior_probabilities: must be positive")
        log_prior = np.log(p / p.sum())
    log_post = log_z + log_prior
    probabilities = np.exp(log_post - logsumexp(log_post, axis=1)[:, None])
    return ModelComparison(names, log_z, increments, probabilities)

import typing as _typing  # noqa: E402

if _typing.TYPE_CHECKING:  # names used only in annotations
    from collections.abc import Mapping
    from typing import Any
    from numpy.typing import ArrayLike
