"""The user's likelihood as the engine calls it: validated, counted, on read-only views.

:class:`ValidatedLikelihood` is the one wrapper: every evaluation of the engine (the step's dataset, the
history prior's past datasets, their running statistics, the path-space remedy's window) goes through it,
so that shapes are checked, NaN counts as zero likelihood (``-inf``, counted in ``StepInfo.n_nan``),
``+inf`` is an error, every evaluated row is counted (``StepInfo.n_loglike_evals``) and the user's code
sees read-only views (:func:`read_only`) that it cannot make writable again: views of a
copy of ``theta`` (``setflags(write=True)`` then changes only the copy) and of the dataset frozen in an
immutable buffer (:func:`frozen`; ``setflags(write=True)`` raises). The path-space views
(:meth:`ValidatedLikelihood.of_last_state`, :meth:`ValidatedLikelihood.over_window`) are thin compositions
of it on flattened paths ``(M, T d)``.
"""

from __future__ import annotations

import copy
from functools import partial

import numpy as np


__all__ = ["ValidatedLikelihood", "check_dataset", "frozen", "row_hashes", "kept_copy", "read_only", "call_loglike"]

#: Odd 64-bit multipliers of the row hash in :func:`row_hashes`.
_HASH_MULTIPLIERS = np.random.default_rng(20231).integers(0, 2**63, size=64, dtype=np.uint64) * 2 + 1


def row_hashes(samples) -> np.ndarray | None:
    """``(N,)`` uint64 hashes of the bit patterns of the rows of ``samples (N, d)`` (None above d = 64): rows that
    differ in one coordinate never collide (odd multipliers), others with probability ~``2^-64`` a pair."""
    d = samples.shape[1]
    if d > _HASH_MULTIPLIERS.size:
        return None
    bits = np.ascontiguousarray(samples + 0.0).view(np.uint64)  # + 0.0 maps -0.0 to 0.0
    return bits @ _HASH_MULTIPLIERS[:d]  # wraps modulo 2^64, silently for integer arrays

#: What a likelihood must be, for the errors of one that is not vectorised.
_VECTORISED = ("the likelihood is called once for all samples: theta has shape {shape} = (N, d), one row per "
               "sample (theta[:, 0] is the first parameter of every sample), and it must return an (N,) array")


def read_only(value):
    """``value`` as user code may see it: arrays as read-only views, dicts, lists and tuples rebuilt
    around read-only views (so the caller's containers cannot be changed either); others as they are.

    >>> a = np.zeros(2)
    >>> read_only(a).flags.writeable, a.flags.writeable
    (False, True)
    """
    if isinstance(value, np.ndarray):
        view = value.view()
        view.flags.writeable = False
        return view
    if isinstance(value, dict):
        return {key: read_only(item) for key, item in value.items()}
    if type(value) in (list, tuple):
        return type(value)(read_only(item) for item in value)
    return value


def call_loglike(loglike, theta, dataset):
    """The user's ``loglike`` on read-only views; its values as a new float array."""
    try:
        values = loglike(read_only(theta), read_only(dataset))
    except ValueError as err:
        if "read-only" not in str(err):
            raise
        raise ValueError(f"loglike: wrote into its input theta or data ({err}); they are read-only so that "
                         f"the run cannot be corrupted: copy them first (np.array(theta)) to change them") from err
    if np.iscomplexobj(values):
        raise ValueError("loglike: returned complex values; a log-likelihood is real")
    return np.array(values, dtype=float)  # a copy: never a view of theta


def frozen(value):
    """``value`` with every array moved into an immutable ``bytes`` buffer, so that no view of it can be made
    writable again (``setflags(write=True)`` on a view of a read-only array that owns its memory succeeds;
    on one of a ``bytes`` object it raises). Dicts, lists and tuples are rebuilt; other values returned as
    they are. An array already frozen is returned as it is (no copy).

    >>> a = frozen(np.arange(3.0))
    >>> a.flags.writeable
    False
    >>> a.setflags(write=True)
    Traceback (most recent call last):
    ValueError: cannot set WRITEABLE flag to True of this array
    """
    if isinstance(value, np.ndarray):
        root = value
        while isinstance(root, np.ndarray):
            root = root.base
        if isinstance(root, bytes) or value.dtype.hasobject:
            return value
        return np.frombuffer(np.ascontiguousarray(value).tobytes(), dtype=value.dtype).reshape(value.shape)
    if isinstance(value, dict):
        return {key: frozen(item) for key, item in value.items()}
    if type(value) in (list, tuple):
        return type(value)(frozen(item) for item in value)
    return value


def check_dataset(dataset, step: int) -> None:
    """Raise ``ValueError`` for a missing or empty dataset of ``step``."""
    if dataset is None:
        raise ValueError(f"dataset: step {step} got None")
    size = getattr(dataset, "size", None)
    if size is not None and np.ndim(size) == 0 and size == 0:
        raise ValueError(f"dataset: step {step} got an empty array")
    if hasattr(dataset, "__len__") and not isinstance(dataset, (str, bytes)) and len(dataset) == 0:
        raise ValueError(f"dataset: step {step} got an empty dataset")


class ValidatedLikelihood:
    """The user's ``loglike(theta (N, d), dataset) -> (N,)`` with validation and counting.

    Parameters
    ----------
    loglike : callable ``(theta (N, d), dataset) -> (N,)``
    dataset : object, optional
        The step's dataset, for :meth:`loglike`.
    step : int
        The step, for error messages.
    executor : object with ``evaluate(loglike, theta, dataset)``, optional
        Evaluates on workers (:class:`seqbayes.parallel.Workers`); ``None``: here.
    history : RunningStatistics, optional
        Evaluates past datasets from their summed statistics (:meth:`summary_loglike`).
    on_evaluated : callable ``(n_rows) -> None``, optional
        Told the number of rows of every evaluation (a progress bar's ``update``).

    Calling the object as ``(theta, dataset)`` evaluates any dataset, so it can stand in for the user's
    function wherever one is expected.
    """

    def __init__(self, loglike, dataset=None, step: int = 0, *, executor=None, history=None, on_evaluated=None):
        self.function, self.dataset, self.step = loglike, frozen(dataset), step
        self.executor, self.history, self.on_evaluated = executor, history, on_evaluated
        self.n_evals = 0
        self.n_nan = 0

    @classmethod
    def for_step(cls, problem, dataset, step: int, on_evaluated=None) -> "ValidatedLikelihood":
        """The likelihood of ``problem`` (a :class:`~seqbayes.core.state.Problem`) for ``dataset`` at ``step``."""
        return cls(problem.loglike, dataset, step, executor=problem.executor, history=problem.history,
                   on_evaluated=on_evaluated)

    def __call__(self, theta, dataset) -> np.ndarray:
        return self.loglike_on(theta, dataset)

    def loglike(self, theta) -> np.ndarray:
        """``log L(theta)`` of the step's dataset, ``(N, d) -> (N,)``."""
        return self.loglike_on(theta, self.dataset)

    def loglike_on(self, theta, dataset) -> np.ndarray:
        """The log-likelihood of any dataset (past ones for :class:`~seqbayes.predictive.history.HistoryPrior`)."""
        # theta is copied (N d floats, less than any likelihood reads) so that a likelihood that makes its
        # view writable changes only the copy; the dataset is frozen (once per step for the step's own)
        try:
            theta, dataset = np.array(theta, dtype=float), frozen(dataset)
            values = (call_loglike(self.function, theta, dataset) if self.executor is None
                      else self.executor.evaluate(self.function, theta, dataset))
        except ValueError as err:
            if "values to unpack" in str(err):  # `a, b, c = theta`: a likelihood written for one sample
                raise ValueError(f"loglike: {err}: {_VECTORISED.format(shape=theta.shape)}") from err
            if "WRITEABLE" in str(err):
                raise ValueError(f"loglike: tried to make its data writable ({err}); the data are read-only so "
                                 f"that the run cannot be corrupted: copy them first (np.array(data))") from err
            raise
        return self._checked(values, theta, "loglike")

    def summary_loglike(self, theta, summary) -> np.ndarray:
        """``log prod_k L_k(theta)`` over past datasets from their summed statistics (one call; see
        :class:`~seqbayes.predictive.history.RunningStatistics`), counted as one evaluation per row."""
        values = self.history.loglike(read_only(np.array(theta, dtype=float)), read_only(frozen(summary)))
        return self._checked(np.asarray(values, dtype=float), theta, "history.loglike")

    def add_along_paths(self, out, states, datasets, memos=None) -> np.ndarray:
        """Add ``sum_t log L_t(theta_t)`` (dataset ``t`` at state ``t`` of ``states (M, T, d)``) to ``out (M,)`` in
        place, one call per dataset for the paths still finite (a path with one zero likelihood stops there);
        returns ``out``. ``memos``: one :class:`StateMemo` per dataset, which evaluates only the states it lacks."""
        for t, dataset in enumerate(datasets):
            alive = np.isfinite(out)
            if not alive.any():
                break
            rows = states[alive, t]
            out[alive] += (self.loglike_on(rows, dataset) if memos is None
                           else memos[t].loglike(rows, partial(self.loglike_on, dataset=dataset)))
        return out

    def of_last_state(self, dim: int) -> "LastStateLikelihood":
        """This likelihood on flattened paths ``(M, T d)``, read at their last state."""
        return LastStateLikelihood(self, dim)

    def over_window(self, datasets, dim: int, memo: bool = False) -> "WindowLikelihood":
        """``sum_t log L_t(theta_t)`` over ``datasets`` on flattened paths ``(M, T d)``, one state per dataset;
        ``memo``: a state evaluated once against its dataset is not evaluated again (:class:`StateMemo`)."""
        return WindowLikelihood(self, tuple(datasets), dim, memo)

    def _checked(self, values, theta, name):
        """``values (N,)`` of the user's function ``name`` at ``theta``, counted; +inf is an error, NaN -inf."""
        if values.shape != (theta.shape[0],):
            raise ValueError(f"{name}: returned shape {values.shape} for theta of shape {theta.shape}; "
                             f"expected ({theta.shape[0]},): {_VECTORISED.format(shape=theta.shape)}")
        self.n_evals += theta.shape[0]
        if self.on_evaluated is not None:
            self.on_evaluated(theta.shape[0])
        if (values < np.inf).all():  # the usual case: no NaN, no +inf
            return values
        if np.isposinf(values).any():
            raise ValueError(f"{name}: returned +inf at step {self.step}")
        nan = np.isnan(values)
        self.n_nan += int(nan.sum())
        return np.where(nan, -np.inf, values)


class LastStateLikelihood:
    """A :class:`ValidatedLikelihood` seen from the path space: ``loglike`` reads the last of the states."""

    def __init__(self, base: ValidatedLikelihood, dim: int):
        self.base, self.dim, self.step = base, dim, base.step

    n_evals = property(lambda self: self.base.n_evals, doc="Rows evaluated by the base likelihood.")
    n_nan = property(lambda self: self.base.n_nan, doc="NaN values it returned.")

    def loglike(self, walkers) -> np.ndarray:
        return self.base.loglike(walkers[:, -self.dim:])


class StateMemo:
    """The log-likelihoods of one dataset at the states already evaluated, found again by their exact bits.

    A proposal that redraws only a path's suffix (:meth:`seqbayes.predictive.paths.PathPrior.resimulate`) keeps
    the earlier states bit for bit; their likelihoods are read here, not recomputed (an expensive model's call
    saved, the sum unchanged). Sorted tables of :func:`row_hashes`, so that a lookup is vectorised over the
    rows (a dict would loop over them in Python), in runs of halving size (a table merges with the one before
    while that is at most twice its size: ``O(K log K)`` in all for ``K`` rows, where merging every batch into one
    table cost ``O(K^2 / M)``); a hit also compares the rows themselves."""

    def __init__(self):
        self.tables = []   # (keys, rows, values), each sorted by key

    def loglike(self, rows, evaluate) -> np.ndarray:
        """``(M,)`` log-likelihoods at ``rows (M, d)``: the stored ones, and ``evaluate(missing)`` (then stored)
        for the rest."""
        found, values = self.lookup(rows)
        if not found.all():
            values[~found] = evaluate(rows[~found])
            self.add(rows[~found], values[~found])
        return values

    def lookup(self, rows) -> tuple[np.ndarray, np.ndarray]:
        """``(found (M,) bool, values (M,))`` for ``rows (M, d)``: the stored log-likelihoods where found."""
        found, values = np.zeros(rows.shape[0], dtype=bool), np.full(rows.shape[0], np.nan)
        keys = row_hashes(rows)
        if keys is None:
            return found, values
        for table_keys, table_rows, table_values in self.tables:
            index = np.minimum(np.searchsorted(table_keys, keys), table_keys.size - 1)
            hit = ~found & (table_keys[index] == keys) & (table_rows[index] == rows).all(axis=1)
            values[hit] = table_values[index[hit]]
            found |= hit
        return found, values

    def add(self, rows, values) -> None:
        keys = row_hashes(rows)
        if keys is None or keys.size == 0:
            return
        order = np.argsort(keys)
        self.tables.append((keys[order], rows[order], values[order]))
        while len(self.tables) > 1 and self.tables[-2][0].size <= 2 * self.tables[-1][0].size:
            (k1, r1, v1), (k2, r2, v2) = self.tables.pop(), self.tables.pop()
            keys = np.concatenate([k2, k1])
            order = np.argsort(keys, kind="stable")
            self.tables.append((keys[order], np.concatenate([r2, r1])[order], np.concatenate([v2, v1])[order]))


class WindowLikelihood:
    """A :class:`ValidatedLikelihood` summed over a window of datasets, state ``t`` of a path against dataset ``t``
    (with ``memo``, each dataset's :class:`StateMemo`)."""

    def __init__(self, base: ValidatedLikelihood, datasets: tuple, dim: int, memo: bool = False):
        self.base, self.datasets, self.dim, self.step = base, datasets, dim, base.step
        self.memos = tuple(StateMemo() for _ in datasets) if memo else None

    n_evals = property(lambda self: self.base.n_evals, doc="Rows evaluated by the base likelihood.")
    n_nan = property(lambda self: self.base.n_nan, doc="NaN values it returned.")

    def loglike(self, walkers) -> np.ndarray:
        states = walkers.reshape(walkers.shape[0], len(self.datasets), self.dim)  # explicit: may have no rows
        return self.base.add_along_paths(np.zeros(walkers.shape[0]), states, self.datasets, self.memos)


def kept_copy(dataset):
    """A copy of a dataset that the sampler keeps (callers reuse their buffers): ``ndarray.copy``, else a deep copy."""
    return dataset.copy() if isinstance(dataset, np.ndarray) else copy.deepcopy(dataset)
