"""The user's likelihood as the engine calls it: validated, counted."""

from __future__ import annotations

import numpy as np

from ..parallel import evaluate_loglike

__all__ = ["ValidatedLikelihood", "ProgressLikelihood", "check_dataset"]


def check_dataset(dataset, step):
    if dataset is None:
        raise ValueError(f"dataset: step {step} got None")
    size = getattr(dataset, "size", None)
    if size is not None and np.ndim(size) == 0 and size == 0:
        raise ValueError(f"dataset: step {step} got an empty array")
    if hasattr(dataset, "__len__") and not isinstance(dataset, (str, bytes)) and len(dataset) == 0:
        raise ValueError(f"dataset: step {step} got an empty dataset")


class ValidatedLikelihood:
    """Evaluates the user's likelihood with validation, counting calls and NaNs."""

    def __init__(self, problem, dataset, step):
        self.problem, self.dataset, self.step = problem, dataset, step
        self.n_evals = 0
        self.n_nan = 0

    def loglike(self, theta):
        return self.loglike_on(theta, self.dataset)

    def loglike_on(self, theta, dataset):
        """The log-likelihood of any dataset (past ones for :class:`~seqbayes.predictive.history.HistoryPrior`)."""
        values = evaluate_loglike(self.problem.loglike, theta, dataset, self.problem.executor,
                                  self.problem.n_chunks)
        return self._checked(values, theta, "loglike")

    def summary_loglike(self, theta, summary):
        """``log prod_k L_k(theta)`` over past datasets from their summed statistics (one call; see
        :class:`~seqbayes.predictive.history.RunningStatistics`), counted as one evaluation per row."""
        return self._checked(np.asarray(self.problem.history.loglike(theta, summary), dtype=float), theta,
                             "history.loglike")

    def _checked(self, values, theta, name):
        """``values (N,)`` of the user's function ``name`` at ``theta``, counted; +inf is an error, NaN -inf."""
        if values.shape != (theta.shape[0],):
            raise ValueError(f"{name}: returned shape {values.shape} for theta of shape {theta.shape}; "
                             f"expected ({theta.shape[0]},)")
        self.n_evals += theta.shape[0]
        if (values < np.inf).all():  # the usual case: no NaN, no +inf
            return values
        if np.isposinf(values).any():
            raise ValueError(f"{name}: returned +inf at step {self.step}")
        nan = np.isnan(values)
        self.n_nan += int(nan.sum())
        return np.where(nan, -np.inf, values)


class ProgressLikelihood:
    """The likelihood, advancing a progress bar by the samples it evaluates (serial runs)."""

    def __init__(self, loglike, bar):
        self.loglike, self.bar = loglike, bar

    def __call__(self, theta, dataset):
        out = self.loglike(theta, dataset)
        self.bar.update(len(theta))
        return out
