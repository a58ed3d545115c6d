"""The sequential samplers' state as named arrays, and back: what the run store writes and resumes from.

The run store (:mod:`seqbayes.store`) keeps, per step, the arrays :func:`state_arrays` returns and hands them back
to :func:`state_from_arrays`; neither this module nor the store knows what a state's prior is. Each kind of state
says how it is stored: the class of a state's prior density (the Gaussian mixture of Eq. A3, a jump kernel's sum of
mixtures, the history prior of static parameters), or of a whole state of its own (SMC^2's), registers a
:class:`~seqbayes.core.state.Storage` (:func:`~seqbayes.core.state.stored_as`) with the prefix its array names share
and its ``to_arrays`` / ``from_arrays``; a new predictive density is one registration in its own module. The
particles, weights, posterior and log-evidence of the state after a step are the step's
:class:`~seqbayes.results.StepRecord` (:func:`check_state` verifies this identity whenever a state is stored).

Besides its prior's arrays a :class:`~seqbayes.core.state.SamplerState` keeps ``state_log_evidence_variance ()``,
the variance estimate of the cumulative log-evidence, and the conflict remedy's memory
(:meth:`~seqbayes.core.state.RemedyMemory.arrays`: ``state_window ()``, the length of the window of past steps,
rebuilt from the steps' records, datasets and priors, so a window needs the datasets; ``state_paths (L, N, d)``,
whose ``L`` changes over the steps, so the run store concatenates it, see :data:`RAGGED`; ``state_lineage (N, 2)``).
Stores written before them read as 0, no window and no lineage (every particle its own label, which changes only
the standard errors of the log-evidence). The state's ``previous_prior`` is the prior density of the step before,
rebuilt from that step's arrays.
"""

from __future__ import annotations

import numpy as np

from ..core.state import STORAGE, PastStep, RemedyMemory, SamplerState
from ..predictive import base as predictives  # noqa: F401  every predictive's module: their kinds of state register
from ..predictive.smc2 import start_nested
from ..results import StepRecord

__all__ = ["state_arrays", "state_from_arrays", "initial_state", "state_kind", "needs_datasets", "state_dims",
           "check_state", "is_state_variable", "fill_missing", "output_name", "per_step", "NESTED_PER_STEP",
           "UnsupportedState"]


class UnsupportedState(TypeError):
    """A sampler state this version cannot turn into arrays (a predictive density it does not know)."""


#: Arrays every SamplerState has besides its prior's (the remedy's memory and the evidence's variance).
_COMMON = ("state_log_evidence_variance", "state_window", "state_paths", "state_lineage")
#: Arrays whose first axis may have another length at every step: the run store concatenates them.
RAGGED = ("state_paths",)
#: Dimension names (after ``step``) of the common arrays.
_DIMS = {"state_paths": ("path_step", "sample", "parameter"), "state_lineage": ("sample", "lineage")}


def _kinds() -> dict:
    """kind -> Storage, of every registered kind."""
    return {storage.kind: storage for storage in STORAGE.values()}


#: SMC^2's arrays that every later step needs (its guides, which PMMH re-runs of that step use).
NESTED_PER_STEP = _kinds()["nested"].every_step


def _storage_of(state):
    """The :class:`~seqbayes.core.state.Storage` of ``state`` (a whole state's, else its prior's)."""
    storage = STORAGE.get(type(state)) or STORAGE.get(type(getattr(state, "prior", None)))
    if storage is None:
        kind = type(getattr(state, "prior", state)).__name__
        raise UnsupportedState(f"state: cannot store a sampler state whose prior is a {kind}")
    return storage


def state_arrays(state) -> dict:
    """The arrays (float64) that, with the step's record and (for some kinds) the datasets, rebuild ``state``.

    Parameters
    ----------
    state : SamplerState or NestedState
        The state after a step (``state.step >= 1``).

    Returns
    -------
    dict of str -> ndarray
        The run store's variable names (its kind's prefix, or the common ``state_*``).

    Raises
    ------
    UnsupportedState
        The state's prior is a density no module registered.
    """
    storage = _storage_of(state)
    if storage.whole:
        return state.to_arrays()
    arrays = {**storage.to_arrays(state.prior, state.log_prior),
              "state_log_evidence_variance": state.log_evidence_variance}
    arrays = {name: np.array(value, dtype=float) for name, value in arrays.items()}
    return {**arrays, **state.memory.arrays(*state.particles.shape)}


def is_state_variable(name: str) -> bool:
    """Whether a run-store variable ``name`` is one of :func:`state_arrays`' arrays."""
    return name in _COMMON or any(name.startswith(s.prefix) for s in STORAGE.values())


def _kind_of_name(name: str):
    return next((s for s in STORAGE.values() if name.startswith(s.prefix)), None)


def per_step(name: str) -> bool:
    """Whether state array ``name`` is needed at every step, not only to resume from its own step: all but the
    arrays a kind keeps for its last steps alone (SMC^2's outer particles, inner filters, likelihood estimates)."""
    storage = _kind_of_name(name)
    return storage is None or storage.every_step is None or name in storage.every_step


def output_name(variable: str) -> str:
    """The engine's name of a run-store ``variable`` (:mod:`seqbayes.engine.drivers`, whose rules the store's
    check on open shares with the engine's after every step): a state's own array without its prefix
    (``state_log_evidence_variance`` -> ``log_evidence_variance``, ``nested_cloud_x`` -> ``cloud_x``), a prior's arrays
    ``prior_*`` (``mixture_centres`` -> ``prior_centres``), the initial draws ``particles`` and ``log_weights``, the
    datasets ``dataset``."""
    if variable in _COMMON or variable == "state_log_prior":   # the history prior's values: the state's log_prior
        return variable[len("state_"):]
    storage = _kind_of_name(variable)
    if storage is not None and storage.whole:   # nested_full_x: the run store's copy kept for the last steps only
        return variable[len(storage.prefix):].removeprefix("full_")
    if storage is not None:
        return "prior_" + variable[len(storage.prefix):]
    return {"initial_particles": "particles", "initial_log_weights": "log_weights",
            "dataset_values": "dataset"}.get(variable, variable)


def fill_missing(arrays: dict, n_samples: int) -> None:
    """Add to a step's ``arrays`` (in place) what a store of an earlier version lacks: for a SamplerState written
    before ``state_lineage``, every particle its own label, which is how a state without lineage counts (so the
    store's steps keep one set of arrays and the next step is appended, not the whole file rewritten); for the
    others what their kind fills in."""
    storage = _kinds()[state_kind(arrays)]
    if not storage.whole and "state_lineage" not in arrays:
        arrays["state_lineage"] = np.repeat(np.arange(float(n_samples))[:, None], 2, axis=1)
    if storage.fill is not None:
        storage.fill(arrays, n_samples)


def state_kind(arrays) -> str:
    """The kind of state (``"mixture"``, ``"mixture_sum"``, ``"history"``, ``"nested"``, ...) from the names of
    ``arrays``.

    Raises
    ------
    ValueError
        The names match no kind, or more than one.
    """
    names = [name for name in arrays if name not in _COMMON]
    kinds = {storage.kind for name in names if (storage := _kind_of_name(name)) is not None}
    if len(kinds) != 1:
        raise ValueError(f"state arrays {sorted(names)}: expected the arrays of one kind of state, found "
                         f"{sorted(kinds) or 'none'}")
    return kinds.pop()


def needs_datasets(arrays) -> bool:
    """Whether resuming from ``arrays`` needs the assimilated datasets (the history prior re-evaluates
    them; SMC^2 re-runs its inner filters on them; the remedy's window keeps them)."""
    return _kinds()[state_kind(arrays)].needs_datasets or float(arrays.get("state_window", 0)) > 0


def state_dims(name: str, ndim: int) -> tuple:
    """Dimension names of array ``name`` (``ndim`` axes, after ``step``) in the run store."""
    storage = _kind_of_name(name)
    dims = _DIMS.get(name) or (storage.dims.get(name) if storage is not None else None)
    return dims if dims is not None and len(dims) == ndim else tuple(f"{name}_{axis}" for axis in range(1, ndim + 1))


def initial_state(predictive_method: str, prior, particles, log_weights, step_size):
    """The state before the first dataset, from the initial prior's draws ``particles (N, d)``.

    ``predictive_method`` is the sampler's resolved predictive (SMC^2 keeps its own state).
    """
    if predictive_method == "smc2":  # the default inner filter's outer particles hold every column
        return start_nested(prior, np.arange(particles.shape[1]), particles, step_size)
    return SamplerState(step=0, particles=particles, log_weights=log_weights, prior=prior, log_evidence=0.0,
                        step_size=step_size)


def state_from_arrays(arrays_by_step, records, step_size: float, initial_prior, datasets=()):
    """The inverse of :func:`state_arrays`: the state after step ``s = len(arrays_by_step)``.

    Parameters
    ----------
    arrays_by_step : sequence of dict
        :func:`state_arrays` of steps ``1 .. s`` (SMC^2 takes its earlier guides from them, the
        conflict remedy's window its steps' priors).
    records : sequence of StepRecord
        The records of steps ``1 .. s``.
    step_size : float
        The state's stretch step size.
    initial_prior : object with ``logpdf``
        The run's initial prior ``p_0``.
    datasets : tuple
        ``D^1 .. D^s`` as the likelihood takes them, when :func:`needs_datasets`.

    Returns
    -------
    SamplerState or NestedState
    """
    step = len(arrays_by_step)
    arrays = arrays_by_step[-1]
    storage = _kinds()[state_kind(arrays)]
    if needs_datasets(arrays) and len(datasets) != step:
        raise ValueError(f"datasets: {len(datasets)} datasets for a state at step {step}")
    if storage.whole:
        return storage.from_arrays(arrays_by_step, datasets)

    def prior_of(k):  # the prior density after step k (the one step k + 1 used), and its log_prior
        if k == 0:
            return initial_prior, None
        context = {"initial_prior": initial_prior, "datasets": datasets[:k],
                   "log_evidence": records[k - 1].info.log_evidence}
        return _kinds()[state_kind(arrays_by_step[k - 1])].from_arrays(arrays_by_step[k - 1], context)

    prior, log_prior = prior_of(step)
    record = records[step - 1]
    window_length = RemedyMemory.window_length(arrays, step)
    # the conflict remedy's window: the last steps' datasets, the priors they used, their posteriors
    # (the cumulative variance before each: the step before's reported se, squared)
    window = tuple(PastStep(datasets[k - 1], prior_of(k - 1)[0], records[k - 1].posterior, records[k - 1].log_weights,
                            records[k - 1].info.log_evidence_increment,
                            float(records[k - 2].info.log_evidence_se) ** 2 if k >= 2 else 0.0,
                            int(records[k - 1].info.path_steps))
                   for k in range(step - window_length + 1, step + 1))
    previous_prior = prior_of(step - 1)[0] if step >= 2 and state_kind(arrays_by_step[-2]) == "mixture" else None
    return SamplerState(step=step, particles=record.predictive, log_weights=record.log_weights,
                        prior=prior, log_evidence=record.info.log_evidence, step_size=float(step_size),
                        posterior=record.posterior, posterior_log_weights=record.log_weights, log_prior=log_prior,
                        memory=RemedyMemory.from_arrays(arrays, window),
                        log_evidence_variance=float(arrays.get("state_log_evidence_variance", 0.0)),
                        previous_prior=previous_prior)


def check_state(state, record: StepRecord) -> None:
    """Verify that ``state`` is what :func:`state_from_arrays` rebuilds from ``record``.

    Raises
    ------
    ValueError
        The state's particles, weights, posterior or log-evidence differ from the record's.
    """
    same = np.array_equal(state.log_weights, record.log_weights) and state.log_evidence == record.info.log_evidence
    if _storage_of(state).whole:  # a whole state (SMC^2) keeps its own arrays; its particles are the posterior
        same = same and np.array_equal(state.particles, record.posterior)
    else:
        same = (same and np.array_equal(state.particles, record.predictive)
                and np.array_equal(state.posterior, record.posterior))
    if not same:  # pragma: no cover - guards the identity state_from_arrays relies on
        raise ValueError("state: differs from its step record; seqbayes.store.snapshot needs updating")
