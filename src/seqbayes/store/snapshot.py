"""The sequential samplers' state as named arrays, and back: what the run store writes and resumes from.

The run store (:mod:`seqbayes.store`) keeps, per step, the arrays :func:`state_arrays`
returns and hands them back to :func:`state_from_arrays`; it does not know what a
:class:`~seqbayes.predictive.mixture.GaussianMixture`, a :class:`~seqbayes.predictive.mixture.MixtureSum`, a
:class:`~seqbayes.predictive.history.HistoryPrior` or SMC^2's :class:`~seqbayes.predictive.smc2.NestedState` is.
Only the step's prior density (or SMC^2's nested state) needs arrays of its own: the
particles, weights, posterior and log-evidence of the state after a step are the
step's :class:`~seqbayes.results.StepRecord` (:func:`check_state` verifies this identity
whenever a state is stored).

Each kind of state has one pair of functions in :data:`_KINDS` (``to_arrays``,
``from_arrays``) and a prefix its array names share, so a new predictive density
(another mixture, ...) is one more entry. Array names are the run store's variable
names; :func:`state_dims` names their dimensions after ``step``.

The kinds and their arrays (after the ``step`` dimension):

- ``mixture`` (the Gaussian mixture of Eq. A3): ``mixture_centres (N, d)``,
  ``mixture_bandwidth (d,)``, ``mixture_log_weights (N,)``.
- ``mixture_sum`` (a jump kernel's weighted sum of mixtures): ``mixsum_centres (C, N, d)``,
  ``mixsum_bandwidth (C, d)``, ``mixsum_component_log_weights (C, N)``, ``mixsum_log_weights (C,)``.
- ``history`` (the exact history prior of static parameters): ``state_log_prior (N,)``, its
  values at the particles; resuming needs the assimilated datasets.
- ``nested`` (SMC^2): ``nested_*``, the outer particles, inner filters and likelihood
  estimates of :func:`~seqbayes.predictive.smc2.nested_state_arrays`; resuming needs the datasets, and
  of the steps before only their guides (:data:`NESTED_PER_STEP`, :func:`per_step`).

Every kind but ``nested`` also has ``state_log_evidence_variance ()``, the variance estimate of
the cumulative log-evidence, ``state_window ()``, the length of the conflict remedy's window of
past steps (:class:`~seqbayes.core.state.PastStep`: rebuilt from the steps' records, datasets and
priors, so a window needs the datasets), and ``state_paths (L, N, d)``, the particle paths the
remedy carries forward (``L = 0`` until it first runs; ``L`` changes over the steps, so the run
store concatenates these arrays, see :data:`RAGGED`). Stores written before them read as 0 and
no window. ``state_lineage (N, 2)``: the labels of the last two posteriors' particles
(:attr:`~seqbayes.core.state.RemedyMemory.lineage`, integers stored as floats); a store written
before it reads as no lineage (every particle its own label), which changes only the standard
errors of the log-evidence. The state's ``previous_prior`` is the prior density of the step before,
rebuilt from that step's arrays.
"""

from __future__ import annotations

import numpy as np

from ..predictive.history import HistoryPrior
from ..predictive.mixture import GaussianMixture, MixtureSum
from ..predictive.smc2 import NestedState, nested_guide, nested_moments, nested_state_arrays, nested_state_from_arrays, start_nested
from ..results import StepRecord
from ..core.state import PastStep, RemedyMemory, SamplerState

__all__ = ["state_arrays", "state_from_arrays", "initial_state", "state_kind", "needs_datasets", "state_dims",
           "check_state", "is_state_variable", "fill_missing", "output_name", "per_step", "NESTED_PER_STEP",
           "UnsupportedState"]


class UnsupportedState(TypeError):
    """A sampler state this version cannot turn into arrays (a predictive density it does not know)."""


def _exact_mixture(centres, bandwidth, log_weights) -> GaussianMixture:
    """A :class:`GaussianMixture` with the stored normalised weights kept bit for bit (normalising
    twice may move the last ulp)."""
    mixture = GaussianMixture(np.array(centres), np.array(bandwidth), log_weights)
    object.__setattr__(mixture, "log_weights", np.array(log_weights, dtype=float))
    return mixture


# ------------------------------------------------------------------ one pair per kind
def _mixture_arrays(prior: GaussianMixture, log_prior) -> dict:
    return {"mixture_centres": prior.centres, "mixture_bandwidth": prior.bandwidth,
            "mixture_log_weights": prior.log_weights}


def _mixture_prior(arrays: dict, context: dict):
    return _exact_mixture(arrays["mixture_centres"], arrays["mixture_bandwidth"], arrays["mixture_log_weights"]), None


def _mixture_sum_arrays(prior: MixtureSum, log_prior) -> dict:
    return {"mixsum_centres": np.stack([m.centres for m in prior.mixtures]),
            "mixsum_bandwidth": np.stack([m.bandwidth for m in prior.mixtures]),
            "mixsum_component_log_weights": np.stack([m.log_weights for m in prior.mixtures]),
            "mixsum_log_weights": prior.log_weights}


def _mixture_sum_prior(arrays: dict, context: dict):
    mixtures = tuple(_exact_mixture(c, h, w) for c, h, w in zip(
        arrays["mixsum_centres"], arrays["mixsum_bandwidth"], arrays["mixsum_component_log_weights"]))
    prior = MixtureSum(mixtures, arrays["mixsum_log_weights"])
    object.__setattr__(prior, "log_weights", np.array(arrays["mixsum_log_weights"], dtype=float))
    return prior, None


def _history_arrays(prior: HistoryPrior, log_prior) -> dict:
    return {"state_log_prior": log_prior}


def _history_prior(arrays: dict, context: dict):
    return (HistoryPrior(context["initial_prior"], tuple(context["datasets"]), context["log_evidence"]),
            np.array(arrays["state_log_prior"]))


#: kind -> (the prefix of its array names, the prior's type, (prior, log_prior) -> arrays, arrays -> (prior, log_prior),
#: whether resuming needs the assimilated datasets). SMC^2's nested state is handled apart (it is not a
#: SamplerState with a prior density).
_KINDS = {
    "mixture": ("mixture_", GaussianMixture, _mixture_arrays, _mixture_prior, False),
    "mixture_sum": ("mixsum_", MixtureSum, _mixture_sum_arrays, _mixture_sum_prior, False),
    "history": ("state_log_prior", HistoryPrior, _history_arrays, _history_prior, True),
}
_NESTED = "nested_"
#: Arrays every SamplerState kind has besides its prior's: the variance estimate of the cumulative
#: log-evidence (its standard error carries over the steps), the length of the conflict remedy's
#: window of past steps (rebuilt from the steps' records, datasets and priors) and the paths of the
#: last path-space step carried forward (``(L, N, d)``, ``L`` of 0 before the remedy first ran).
_COMMON = ("state_log_evidence_variance", "state_window", "state_paths", "state_lineage")
#: Arrays whose first axis may have another length at every step: the run store concatenates them.
RAGGED = ("state_paths",)
#: SMC^2's arrays that every later step needs (its guide, which PMMH re-runs of that step use); the others
#: (outer particles, inner filters, ...) rebuild the state after their own step only, so the run store keeps
#: them for the last two steps alone (:func:`per_step`).
NESTED_PER_STEP = ("nested_guide_used", "nested_guide_mean", "nested_guide_cov", "nested_moments")

#: Dimension names (after ``step``) of the arrays whose axes have a meaning a NetCDF reader can use.
_DIMS = {"mixture_centres": ("sample", "parameter"), "mixture_bandwidth": ("parameter",),
         "mixture_log_weights": ("sample",), "state_log_prior": ("sample",),
         "mixsum_centres": ("branch", "sample", "parameter"), "mixsum_bandwidth": ("branch", "parameter"),
         "mixsum_component_log_weights": ("branch", "sample"), "mixsum_log_weights": ("branch",),
         "state_paths": ("path_step", "sample", "parameter"), "state_lineage": ("sample", "lineage")}


def state_arrays(state) -> dict:
    """The arrays (float64) that, with the step's record and (for some kinds) the datasets, rebuild ``state``.

    Parameters
    ----------
    state : SamplerState or NestedState
        The state after a step (``state.step >= 1``).

    Returns
    -------
    dict of str -> ndarray
        Names as in the module docstring's list.

    Raises
    ------
    UnsupportedState
        The state's prior is a density this module does not know.
    """
    if isinstance(state, NestedState):
        return {_NESTED + key: value for key, value in nested_state_arrays(state).items()}
    if isinstance(state, SamplerState):
        for _, cls, to_arrays, _, _ in _KINDS.values():
            if type(state.prior) is cls:
                arrays = {**to_arrays(state.prior, state.log_prior),
                          "state_log_evidence_variance": state.log_evidence_variance}
                arrays = {name: np.array(value, dtype=float) for name, value in arrays.items()}
                return {**arrays, **state.memory.arrays(*state.particles.shape)}
    kind = type(state.prior).__name__ if isinstance(state, SamplerState) else type(state).__name__
    raise UnsupportedState(f"state: cannot store a sampler state whose prior is a {kind}")


def is_state_variable(name: str) -> bool:
    """Whether a run-store variable ``name`` is one of :func:`state_arrays`' arrays."""
    return (name in _COMMON or name.startswith(_NESTED)
            or any(name.startswith(prefix) for prefix, *_ in _KINDS.values()))


def per_step(name: str) -> bool:
    """Whether state array ``name`` is needed at every step, not only to resume from its own step: all but
    SMC^2's full state (outer particles, inner filters, likelihood estimates; :data:`NESTED_PER_STEP`)."""
    return not name.startswith(_NESTED) or name in NESTED_PER_STEP


def output_name(variable: str) -> str:
    """The engine's name of a run-store ``variable`` (:mod:`seqbayes.engine.outputs`, whose rules the store's
    check on open shares with the engine's after every step): a state's own array without its prefix
    (``state_log_evidence_variance`` -> ``log_evidence_variance``, ``nested_cloud_x`` -> ``cloud_x``), a mixture
    prior's arrays ``prior_*`` (``mixture_centres`` -> ``prior_centres``), the initial draws ``particles`` and
    ``log_weights``, the datasets ``dataset``."""
    if variable in _COMMON or variable == "state_log_prior":   # the history prior's values: the state's log_prior
        return variable[len("state_"):]
    if variable.startswith(_NESTED):   # nested_full_x: the run store's copy kept for the last steps only
        return variable[len(_NESTED):].removeprefix("full_")
    for prefix, *_ in _KINDS.values():
        if variable.startswith(prefix):
            return "prior_" + variable[len(prefix):]
    return {"initial_particles": "particles", "initial_log_weights": "log_weights",
            "dataset_values": "dataset"}.get(variable, variable)


def fill_missing(arrays: dict, n_samples: int) -> None:
    """Add to a step's ``arrays`` (in place) what a store written before ``state_lineage`` lacks: every
    particle its own label, which is how a state without lineage counts (so the store's steps keep one
    set of arrays and the next step is appended, not the whole file rewritten)."""
    if "state_lineage" not in arrays and state_kind(arrays) != "nested":
        arrays["state_lineage"] = np.repeat(np.arange(float(n_samples))[:, None], 2, axis=1)
    if (state_kind(arrays) == "nested" and _NESTED + "particles" in arrays  # a full state (format 5 keeps two)
            and _NESTED + "pmmh_queue" not in arrays):  # written before budgeted PMMH: nothing pending
        arrays[_NESTED + "pmmh_queue"] = np.full(n_samples, -1.0)
        arrays[_NESTED + "pmmh_tally"] = np.zeros(4)
        arrays[_NESTED + "pmmh_moved"] = np.zeros(n_samples)
        arrays[_NESTED + "moments"] = np.vstack(nested_moments(arrays[_NESTED + "particles"],
                                                               arrays[_NESTED + "log_weights"], None, []))


def state_kind(arrays) -> str:
    """``"mixture"``, ``"mixture_sum"``, ``"history"`` or ``"nested"``, from the names of ``arrays``.

    Raises
    ------
    ValueError
        The names match no kind, or more than one.
    """
    names = [name for name in arrays if name not in _COMMON]
    kinds = {kind for kind, (prefix, *_) in _KINDS.items() for name in names if name.startswith(prefix)}
    if any(name.startswith(_NESTED) for name in names):
        kinds.add("nested")
    if len(kinds) != 1:
        raise ValueError(f"state arrays {sorted(names)}: expected the arrays of one kind of state, found "
                         f"{sorted(kinds) or 'none'}")
    return kinds.pop()


def needs_datasets(arrays) -> bool:
    """Whether resuming from ``arrays`` needs the assimilated datasets (the history prior re-evaluates
    them; SMC^2 re-runs its inner filters on them)."""
    kind = state_kind(arrays)
    return kind == "nested" or _KINDS[kind][4] or float(arrays.get("state_window", 0)) > 0


def state_dims(name: str, ndim: int) -> tuple:
    """Dimension names of array ``name`` (``ndim`` axes, after ``step``) in the run store."""
    dims = _DIMS.get(name)
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
    kind = state_kind(arrays)
    if needs_datasets(arrays) and len(datasets) != step:
        raise ValueError(f"datasets: {len(datasets)} datasets for a state at step {step}")
    if kind == "nested":
        def strip(a):
            return {key[len(_NESTED):]: value for key, value in a.items()}
        guides = tuple(nested_guide(strip(a)) for a in arrays_by_step[:-1])
        return nested_state_from_arrays(strip(arrays), tuple(datasets), guides)

    def prior_of(k):  # the prior density after step k (the one step k + 1 used), and its log_prior
        if k == 0:
            return initial_prior, None
        context = {"initial_prior": initial_prior, "datasets": datasets[:k],
                   "log_evidence": records[k - 1].info.log_evidence}
        return _KINDS[state_kind(arrays_by_step[k - 1])][3](arrays_by_step[k - 1], context)

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
    if isinstance(state, NestedState):  # SMC^2 keeps its own arrays; its posterior is the record's
        same = (np.array_equal(state.particles, record.posterior) and np.array_equal(state.log_weights, record.log_weights)
                and state.log_evidence == record.info.log_evidence)
    else:
        same = (np.array_equal(state.particles, record.predictive)
                and np.array_equal(state.log_weights, record.log_weights)
                and np.array_equal(state.posterior, record.posterior) and state.log_evidence == record.info.log_evidence)
    if not same:  # pragma: no cover - guards the identity state_from_arrays relies on
        raise ValueError("state: differs from its step record; seqbayes.store.snapshot needs updating")
