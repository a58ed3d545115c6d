"""Step records and the run :class:`Result`, with xarray, NetCDF and ArviZ I/O.

Every record is frozen. A :class:`Result` holds one :class:`StepRecord` per
assimilated dataset; ``Result.to_xarray()`` lays them out as
``(step, sample, parameter)`` arrays plus per-step diagnostics.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from .weights import normalise

if TYPE_CHECKING:
    import os

    import arviz as az
    import xarray as xr

__all__ = ["StepInfo", "MoveInfo", "EvidenceInfo", "ConflictInfo", "JumpInfo", "NestedInfo", "StepRecord", "Result",
           "weighted_quantile"]


@dataclass(frozen=True)
class MoveInfo:
    """What the step's moves did (the ``moves`` component's diagnostics).

    Attributes
    ----------
    acceptance_rate : float
        True rate over the step's moves: accepted proposals / proposals made.
    step_size : float
        Stretch-move step size ``u`` after the step (NaN for SMC).
    n_virtual : int
        Virtual iterations (SEMC sweeps) in the step, all stages.
    n_proposed, n_accepted, n_identical_partner : int
        Move counts; ``n_identical_partner`` are stretch proposals whose partner was an identical copy of the walker.
    n_move_evaluations : int
        Likelihood evaluations made by the moves (part of ``StepInfo.n_loglike_evals``).
    n_screen_evaluations, n_screened_out : int
        Delayed acceptance (the moves' ``screen``): the cheap screen's evaluations and the proposals it rejected
        without a likelihood call.
    """

    acceptance_rate: float = float("nan")
    step_size: float = float("nan")
    n_virtual: int = 0
    n_proposed: int = 0
    n_accepted: int = 0
    n_identical_partner: int = 0
    n_move_evaluations: int = 0
    n_screen_evaluations: int = 0
    n_screened_out: int = 0


@dataclass(frozen=True)
class EvidenceInfo:
    """The evidence increment's diagnostics (the ``evidence`` component's).

    Attributes
    ----------
    log_evidence_increment_path : float
        The tempering path's estimate of the increment (Eq. 1); equals ``StepInfo.log_evidence_increment`` with
        ``PathEvidence``.
    evidence_ess : float
        Effective sample size of the importance-sampling evidence (NaN for the path's); small values (say below
        N / 10) flag an unreliable increment.
    n_independent_accepted : int
        Particles moved by the independence-MH sweeps that reuse the importance draws.
    log_evidence_increment_se, log_evidence_se : float
        Standard errors of the increment and of the cumulative log-evidence
        (:func:`~seqbayes.predictive.evidence.step_standard_errors`; NaN for SMC^2 and multi-stage path estimates).
    """

    log_evidence_increment_path: float = float("nan")
    evidence_ess: float = float("nan")
    n_independent_accepted: int = 0
    log_evidence_increment_se: float = float("nan")
    log_evidence_se: float = float("nan")


@dataclass(frozen=True)
class ConflictInfo:
    """Prior-data conflict and its remedy (the ``remedy`` component's diagnostics).

    Attributes
    ----------
    prior_data_conflict : float
        How far the step's posterior lies in the tail of its prior (the predictive distribution restricted to the
        parameter space for ``s > 1``): the largest over parameters of ``|posterior mean - prior mean| / prior sd``
        (:func:`~seqbayes.predictive.particle.prior_data_conflict`). Under the model this exceeds 4 with probability below ~1e-4 per parameter;
        larger values flag an abrupt change or a kernel too narrow for the data.
    conflict_parameter : int
        The parameter (column) where it is largest.
    ancestor_ess : float
        How many of the predictive mixture's components (Eq. A3) carry this step's posterior, ``1 / sum_j a_j^2``
        (:meth:`~seqbayes.predictive.mixture.GaussianMixture.ancestor_ess`; NaN at step 1 and where the remedy does
        not apply). Small values mean the posterior lies in the far tail of the mixture.
    path_steps : int
        0: the step's target was the predictive mixture (Eq. A3). ``L > 0``: the remedy assimilated it on the path
        space of the last ``L`` states (:class:`~seqbayes.predictive.paths.PathStep`).
    """

    prior_data_conflict: float = float("nan")
    conflict_parameter: int = 0
    ancestor_ess: float = float("nan")
    path_steps: int = 0


@dataclass(frozen=True)
class JumpInfo:
    """A jump kernel's posterior (:class:`~seqbayes.kernels.Jump` components; NaN at step 1 and without jumps).

    Attributes
    ----------
    jump_probability : float
        The posterior probability that some parameter jumped between the previous step and this one
        (:func:`~seqbayes.kernels.jump_posterior`).
    jump_parameter : int
        The jump parameter (column) most likely to have jumped.
    jump_size, jump_size_sd : float
        Posterior mean and sd of its drop fraction given that it jumped (the drop is ``jump_size * reference``).
    jump_probability_se : float
        Monte Carlo standard error of ``jump_probability`` (:func:`~seqbayes.predictive.jumps.jump_probability_se`).
    """

    jump_probability: float = float("nan")
    jump_parameter: int = 0
    jump_size: float = float("nan")
    jump_size_sd: float = float("nan")
    jump_probability_se: float = float("nan")


@dataclass(frozen=True)
class NestedInfo:
    """SMC^2's diagnostics (the ``SMC2`` predictive's; NaN and 0 otherwise).

    Attributes
    ----------
    inner_ess : float
        The particle inner filters' mean ESS after weighting, as a fraction of their size. Below ~0.02 the
        likelihood estimates are too noisy for the PMMH moves (raise ``n_inner``; see docs/core.md).
    amortised_evals : float
        Likelihood evaluations per update so far, ``sum of n_loglike_evals / step``.
    pmmh_acceptance : float
        PMMH acceptance of the current rejuvenation so far, or of the one that ended in this step (NaN when none has
        run). Below ~0.2 the moves cost more than they diversify (raise ``n_inner``).
    pending_moves : int
        At most this many PMMH attempts are still scheduled for later updates (:mod:`seqbayes.predictive.pmmh`).
    """

    inner_ess: float = float("nan")
    amortised_evals: float = float("nan")
    pmmh_acceptance: float = float("nan")
    pending_moves: int = 0


#: StepInfo's records: its field -> the record's class.
RECORDS = {"moves": MoveInfo, "evidence": EvidenceInfo, "conflict": ConflictInfo, "jumps": JumpInfo,
           "nested": NestedInfo}


@dataclass(frozen=True)
class StepInfo:
    """Diagnostics of one on-line step (one dataset): the step's own, and one record per component.

    The records' fields are read as attributes of the step too (``info.acceptance_rate`` is
    ``info.moves.acceptance_rate``), as stores and scripts of earlier versions name them; :meth:`to_dict` and
    :meth:`from_dict` are the flat form the run store keeps, derived from the records' fields.

    Attributes
    ----------
    step : int
        1-based index of the dataset.
    log_evidence_increment : float
        ``log p(D^s | D^{1:s-1})``, summed over tempering stages (Eq. 1) or estimated by importance sampling.
    log_evidence : float
        Cumulative ``log p(D^{1:s})``.
    ess : float
        Effective sample size after the last reweighting, before resampling.
    resampled : bool
        Whether the last stage resampled (with the IBIS schedule, the moves' ``every_stage=False`` and a static
        kernel: whether the step began with the deferred resample-move).
    temperatures : tuple of float
        Tempering exponents reached, ending with 1.0 (``n_stages`` of them).
    n_loglike_evals : int
        Likelihood evaluations (samples) in the step.
    n_nan : int
        Likelihood values that were NaN (counted as zero likelihood).
    n_distinct : int
        Distinct posterior samples at the end of the step.
    wall_time : float
        Seconds spent in the step.
    moves, evidence, conflict, jumps, nested : MoveInfo, EvidenceInfo, ConflictInfo, JumpInfo, NestedInfo
        The components' diagnostics.
    """

    step: int
    log_evidence_increment: float
    log_evidence: float
    ess: float
    resampled: bool
    temperatures: tuple
    n_loglike_evals: int
    n_nan: int
    n_distinct: int
    wall_time: float
    moves: MoveInfo = MoveInfo()
    evidence: EvidenceInfo = EvidenceInfo()
    conflict: ConflictInfo = ConflictInfo()
    jumps: JumpInfo = JumpInfo()
    nested: NestedInfo = NestedInfo()

    @property
    def n_stages(self) -> int:
        """Tempering stages (1 without tempering)."""
        return len(self.temperatures)

    def __getattr__(self, name: str):
        owner = _OWNER.get(name)   # only for names missing on the step itself: a record's field
        if owner is None:
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
        return getattr(self.__dict__[owner], name)

    @classmethod
    def of(cls, **values) -> "StepInfo":
        """A record from flat values (the step's own and any record's fields, by name), as they are; missing record
        fields take their defaults."""
        parts = {name: {} for name in RECORDS}
        own = {}
        for name, value in values.items():
            owner = _OWNER.get(name)
            (own if owner is None else parts[owner])[name] = value
        return cls(**own, **{name: RECORDS[name](**part) for name, part in parts.items()})

    def to_dict(self) -> dict:
        """The flat form: the step's own fields (and ``n_stages``), then every record's fields."""
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name not in RECORDS}
        out["n_stages"] = self.n_stages
        for name in RECORDS:
            out.update(dataclasses.asdict(getattr(self, name)))
        return out

    @classmethod
    def from_dict(cls, values: dict) -> "StepInfo":
        """A record from stored flat values (:meth:`to_dict`), tolerant of diagnostics added or removed since it was
        written: a missing field becomes NaN, 0, False or ``()``; an unknown one is dropped."""
        defaults = {"float": float("nan"), "int": 0, "bool": False, "tuple": ()}
        kwargs = {}
        for name, kind in _TYPES.items():
            value = values.get(name, defaults.get(kind, float("nan")))
            kwargs[name] = (tuple(value) if kind == "tuple" else bool(value) if kind == "bool"
                            else int(value) if kind == "int" else float(value))
        return cls.of(**kwargs)


def _type_name(f) -> str:
    return f.type if isinstance(f.type, str) else getattr(f.type, "__name__", "float")


#: Each record field -> the StepInfo field of its record; each flat field -> its type's name.
_OWNER = {f.name: name for name, record in RECORDS.items() for f in dataclasses.fields(record)}
_TYPES = {**{f.name: _type_name(f) for f in dataclasses.fields(StepInfo) if f.name not in RECORDS},
          **{f.name: _type_name(f) for record in RECORDS.values() for f in dataclasses.fields(record)}}


def weighted_quantile(samples: ArrayLike, log_weights: ArrayLike, q: ArrayLike) -> np.ndarray:
    """Weighted quantiles ``(len(q), d)`` of ``samples (N, d)``."""
    samples = np.asarray(samples, dtype=float)
    q = np.atleast_1d(np.asarray(q, dtype=float))
    if np.any((q < 0) | (q > 1)):
        raise ValueError(f"q: quantiles must lie in [0, 1], got {q}")
    w = np.exp(normalise(log_weights))
    out = np.empty((q.size, samples.shape[1]))
    for j in range(samples.shape[1]):  # loop over parameters, not samples
        order = np.argsort(samples[:, j])
        cdf = np.cumsum(w[order]) - 0.5 * w[order]
        out[:, j] = np.interp(q, cdf, samples[order, j])
    return out


@dataclass(frozen=True, eq=False)
class StepRecord:
    """Samples and diagnostics of one step.

    Attributes
    ----------
    info : StepInfo
    posterior : (N, d) array
        Samples of ``p(theta_s | D^{1:s})``.
    log_weights : (N,) array
        Their normalised log-weights (all equal after resampling).
    predictive : (N, d) array
        Samples of ``p(theta_{s+1} | D^{1:s})`` (Eq. A3), the next step's prior.
    moments : tuple ``(mean (d,), sd (d,))`` or None
        Posterior moments better than the samples' (SMC^2: the drifting parameters' over every inner
        filter, Rao-Blackwellised), which :meth:`mean` and :meth:`std` return; ``None``: from the samples.
        Not kept by the run store.
    """

    info: StepInfo
    posterior: np.ndarray
    log_weights: np.ndarray
    predictive: np.ndarray
    moments: tuple | None = None

    def _w(self):
        return np.exp(normalise(self.log_weights))

    def mean(self) -> np.ndarray:
        """Weighted posterior mean, ``(d,)``."""
        if self.moments is not None:
            return self.moments[0].copy()
        return self._w() @ self.posterior

    def std(self) -> np.ndarray:
        """Weighted posterior standard deviation, ``(d,)``."""
        if self.moments is not None:
            return self.moments[1].copy()
        return np.sqrt(self._w() @ (self.posterior - self.mean()) ** 2)

    def quantile(self, q: ArrayLike) -> np.ndarray:
        """Weighted posterior quantiles, ``(len(q), d)``."""
        return weighted_quantile(self.posterior, self.log_weights, q)

    def equal_weight_samples(self, rng: np.random.Generator, n: int | None = None) -> np.ndarray:
        """Resampled (systematic) equal-weight posterior samples, ``(n, d)``."""
        from .weights import systematic

        return self.posterior[systematic(self._w(), rng, n)]


@dataclass(frozen=True, eq=False)
class Result:
    """All steps of one run.

    Attributes
    ----------
    names : tuple of str
        Parameter names.
    steps : tuple of StepRecord
    meta : dict
        Sampler name and settings, kernel and prior descriptions.
    """

    names: tuple
    steps: tuple = ()
    meta: dict = field(default_factory=dict)

    @property
    def infos(self) -> tuple:
        return tuple(r.info for r in self.steps)

    @property
    def log_evidence(self) -> np.ndarray:
        """Cumulative log-evidence per step, ``(S,)``."""
        return np.array([r.info.log_evidence for r in self.steps])

    @property
    def log_evidence_se(self) -> np.ndarray:
        """Standard error of the cumulative log-evidence at every step (``StepInfo.log_evidence_se``)."""
        return np.array([r.info.log_evidence_se for r in self.steps])

    @property
    def log_evidence_increments(self) -> np.ndarray:
        return np.array([r.info.log_evidence_increment for r in self.steps])

    def means(self) -> np.ndarray:
        """Posterior means per step, ``(S, d)``."""
        return np.array([r.mean() for r in self.steps])

    def stds(self) -> np.ndarray:
        """Posterior standard deviations per step, ``(S, d)``."""
        return np.array([r.std() for r in self.steps])

    def to_xarray(self) -> xr.Dataset:
        """An :class:`xarray.Dataset` with dims ``(step, sample, parameter)``."""
        import xarray as xr

        if not self.steps:
            raise ValueError("result: no steps to convert")
        steps = np.array([r.info.step for r in self.steps])
        coords = {"step": steps, "sample": np.arange(self.steps[0].posterior.shape[0]),
                  "parameter": list(self.names)}
        data = {
            "posterior": (("step", "sample", "parameter"), np.stack([r.posterior for r in self.steps])),
            "log_weights": (("step", "sample"), np.stack([r.log_weights for r in self.steps])),
            "predictive": (("step", "sample", "parameter"), np.stack([r.predictive for r in self.steps])),
        }
        for name in self.steps[0].info.to_dict():
            if name in ("step", "temperatures"):
                continue
            values = np.array([getattr(r.info, name) for r in self.steps])
            data[name] = (("step",), values.astype(np.int8) if values.dtype == bool else values)
        ds = xr.Dataset(data, coords=coords)
        ds.attrs["temperatures"] = json.dumps([list(r.info.temperatures) for r in self.steps])
        ds.attrs["meta"] = json.dumps(self.meta, default=str)
        ds.attrs["seqbayes_result_version"] = 1
        return ds

    @classmethod
    def from_xarray(cls, ds: xr.Dataset) -> Result:
        """Inverse of :meth:`to_xarray`."""
        if ds.attrs.get("seqbayes_result_version") != 1:
            raise ValueError("dataset: not a seqbayes Result (missing or unknown seqbayes_result_version)")
        temperatures = json.loads(ds.attrs["temperatures"])
        records = []
        for i, step in enumerate(ds["step"].values):
            values = {name: ds[name].values[i] for name in ds.data_vars if ds[name].dims == ("step",)}
            values.update(step=int(step), temperatures=temperatures[i])
            records.append(StepRecord(StepInfo.from_dict(values), ds["posterior"].values[i],
                                      ds["log_weights"].values[i], ds["predictive"].values[i]))
        return cls(tuple(str(n) for n in ds["parameter"].values), tuple(records), json.loads(ds.attrs["meta"]))

    def to_netcdf(self, path: str | os.PathLike) -> None:
        """Write to NetCDF-4 (HDF5) via xarray and h5netcdf."""
        self.to_xarray().to_netcdf(path, engine="h5netcdf")

    @classmethod
    def from_netcdf(cls, path: str | os.PathLike) -> Result:
        import xarray as xr

        with xr.open_dataset(path, engine="h5netcdf") as ds:
            return cls.from_xarray(ds.load())

    def to_arviz(self, step: int | None = None, rng: int | np.random.Generator | None = None, *,
                 prior: Any = None, pointwise_loglike: Callable[[np.ndarray, Any], np.ndarray] | None = None,
                 dataset: Any = None, loglike_step: int = -1, runs: Sequence[Result] = ()) -> az.InferenceData:
        """The run as :class:`arviz.InferenceData`, with a ``step`` dimension.

        ArviZ's conventions for SMC (PyMC's SMC does the same): a ``chain`` is one independent run
        (this one, then each of ``runs``), the step is a dimension of every variable (not a chain),
        and the sampler's own diagnostics (importance ESS, log-evidence, acceptance) are in
        ``sample_stats``. R-hat compares chains, so it means something only across independent
        runs (``runs``); with one run ``az.summary`` warns about the single chain and reports R-hat
        NaN. ``ess_bulk``/``ess_tail`` treat the draws as a Markov chain, which resampled draws are
        not: use ``sample_stats.ess`` and ``n_distinct`` instead. ``az.plot_trace`` draws one line per
        step (the steps are not chains): select a step with ``coords={"step": s}``.

        Groups (``chain`` has length ``1 + len(runs)``, ``draw`` length ``N``):

        - ``posterior``: one variable per parameter, ``(chain, draw, step)``: each step's
          ``N`` equal-weight draws (systematic resampling of the weighted particles). They are
          not a Markov chain, and draw ``i`` of one step has no link to draw ``i`` of another:
          use ArviZ's summaries, densities and pair plots per step, not R-hat.
        - ``prior``: the same layout for each step's prior ``p(theta_s | D^{1:s-1})``: the
          predictive draws of the step before (Eq. A2-A3); step 1's only when ``prior`` is given.
        - ``sample_stats``: per step ``(chain, step)``: ``log_evidence``,
          ``log_evidence_increment``, ``ess`` (importance weights at the last tempering stage,
          before resampling), ``n_distinct`` (distinct samples after the step),
          ``acceptance_rate``, ``step_size``, ``n_stages``, ``evidence_ess``,
          ``prior_data_conflict``; and ``temperatures`` ``(chain, step, stage)`` (the tempering
          exponents, NaN-padded).
        - ``log_likelihood`` (only with ``pointwise_loglike`` and ``dataset``): ``y``
          ``(chain, draw, observation)``, the log-likelihood of each observation of ``dataset``
          (the dataset assimilated at ``loglike_step``) at that step's posterior draws, so that
          ``az.loo`` / ``az.waic`` estimate how well the step's posterior predicts each
          observation of its own dataset left out. A run keeps only each dataset's total
          log-likelihood, so the per-observation values need the model's help: there is no
          honest way to split a dataset's likelihood into observations without it.

        With an integer ``step`` the groups hold that step alone (no ``step`` dimension; the
        posterior's attributes record the step, its log-evidence, ESS and acceptance rate).
        Requires the optional ``arviz`` extra.

        Parameters
        ----------
        step : int, optional
            Index into :attr:`steps` (``-1``: the last); ``None`` (default): every step.
        rng : int or numpy.random.Generator, optional
            For the resampling (default seed 0, so the conversion is reproducible).
        prior : array (M, d) or object with ``sample(n, rng)``, optional
            Step 1's prior: draws, or the prior to draw ``N`` of them from.
        pointwise_loglike : callable ``(theta (N, d), dataset) -> (N, n_obs)``, optional
            The model's log-likelihood of each observation (summing over the last axis gives
            the likelihood the run used).
        dataset : optional
            The dataset of ``loglike_step``, as given to the likelihood.
        loglike_step : int
            Index into :attr:`steps` of ``dataset`` (``-1``: the last).
        runs : sequence of Result
            Independent runs of the same model on the same datasets (other seeds), one chain each,
            so that R-hat compares runs. Each needs this run's parameters, sample size and steps.

        Returns
        -------
        arviz.InferenceData

        Raises
        ------
        ValueError
            No steps, a ``step`` or ``loglike_step`` out of range, ``pointwise_loglike`` without
            ``dataset`` (or the reverse), a pointwise log-likelihood of the wrong shape, or a run of
            ``runs`` with other parameters, sample size or steps.
        """
        try:
            import arviz as az
        except ImportError as err:  # pragma: no cover - depends on the environment
            raise ImportError("to_arviz: install the optional extra, pip install 'seqbayes[arviz]'") from err
        import xarray as xr

        from .rng import as_generator

        rng = as_generator(0 if rng is None else rng)
        groups = self._arviz_groups(step, rng, prior, pointwise_loglike, dataset, loglike_step)
        for k, run in enumerate(runs, start=1):
            shape = (run.names, len(run.steps), run.steps[0].posterior.shape[0] if run.steps else 0)
            if shape != (self.names, len(self.steps), self.steps[0].posterior.shape[0]):
                raise ValueError(f"runs[{k - 1}]: expected a run of {self.names} with {len(self.steps)} steps of "
                                 f"N = {self.steps[0].posterior.shape[0]}, got {shape[0]} with {shape[1]} steps of "
                                 f"N = {shape[2]}")
            other = run._arviz_groups(step, rng, prior, pointwise_loglike, dataset, loglike_step)
            # runs differ in their number of tempering stages: the shorter ones' temperatures are padded with NaN
            groups = {key: xr.concat([ds, other[key].assign_coords(chain=[k])], dim="chain", combine_attrs="override",
                                     join="outer", fill_value=np.nan)
                      for key, ds in groups.items() if key in other}
        if step is not None:
            info = self.steps[int(step) % len(self.steps)].info
            groups = {key: ds.isel(step=0) if "step" in ds.dims else ds for key, ds in groups.items()}
            groups["posterior"].attrs.update({"step": int(info.step), "log_evidence": float(info.log_evidence),
                                              "ess": float(info.ess), "acceptance_rate": float(info.acceptance_rate)})
        for ds in groups.values():
            ds.attrs.update({"inference_library": "seqbayes", "created_by": "seqbayes.Result.to_arviz",
                             "chain": "one independent SMC run per chain; step: the dataset index"})
        return az.InferenceData(**groups)

    def _arviz_groups(self, step, rng, prior, pointwise_loglike, dataset, loglike_step) -> dict:
        """:meth:`to_arviz`'s groups for this run alone, as one chain, with the ``step`` dimension."""
        import xarray as xr

        if not self.steps:
            raise ValueError("result: no steps to convert")
        n_total = len(self.steps)
        for name, value in (("step", step), ("loglike_step", loglike_step)):
            if value is not None and not -n_total <= int(value) < n_total:
                raise ValueError(f"{name}: must index one of the {n_total} steps, got {value}")
        if (pointwise_loglike is None) != (dataset is None):
            raise ValueError("pointwise_loglike and dataset: give both (the log-likelihood of each observation "
                             "of that dataset) or neither")
        chosen = list(range(n_total)) if step is None else [int(step) % n_total]
        records = [self.steps[i] for i in chosen]
        n = records[0].posterior.shape[0]
        steps = np.array([r.info.step for r in records])
        draws = np.stack([r.equal_weight_samples(rng) for r in records], axis=1)       # (N, S, d)

        def by_parameter(values, step_coords):                                      # (N, S, d) -> Dataset
            return xr.Dataset({name: (("chain", "draw", "step"), values[None, :, :, j])
                               for j, name in enumerate(self.names)},
                              coords={"chain": [0], "draw": np.arange(values.shape[0]), "step": step_coords})

        groups = {"posterior": by_parameter(draws, steps)}
        prior_draws, prior_steps = [], []
        for i in chosen:
            if i > 0:
                before = self.steps[i - 1]
                prior_draws.append(StepRecord(before.info, before.predictive, before.log_weights,
                                              before.predictive).equal_weight_samples(rng, n))
            elif prior is not None:
                first = (np.asarray(prior.sample(n, rng), dtype=float) if hasattr(prior, "sample")
                         else np.asarray(prior, dtype=float))
                if first.ndim != 2 or first.shape[1] != len(self.names):
                    raise ValueError(f"prior: expected draws of shape (M, {len(self.names)}) or an object with "
                                     f"sample(n, rng), got shape {first.shape}")
                prior_draws.append(first[np.linspace(0, first.shape[0] - 1, n).round().astype(int)]
                                   if first.shape[0] != n else first)
            else:
                continue
            prior_steps.append(self.steps[i].info.step)
        if prior_draws:
            groups["prior"] = by_parameter(np.stack(prior_draws, axis=1), np.array(prior_steps))

        stats = {}
        for name in ("log_evidence", "log_evidence_increment", "ess", "n_distinct", "acceptance_rate", "step_size",
                     "n_stages", "evidence_ess", "prior_data_conflict"):
            stats[name] = (("chain", "step"), np.array([[getattr(r.info, name) for r in records]]))
        n_stage = max(len(r.info.temperatures) for r in records)
        temperatures = np.full((1, len(records), max(n_stage, 1)), np.nan)
        for k, r in enumerate(records):
            temperatures[0, k, :len(r.info.temperatures)] = r.info.temperatures
        stats["temperatures"] = (("chain", "step", "stage"), temperatures)
        groups["sample_stats"] = xr.Dataset(stats, coords={"chain": [0], "step": steps,
                                                           "stage": np.arange(temperatures.shape[2])})

        if pointwise_loglike is not None:
            at = int(loglike_step) % n_total
            record = self.steps[at]
            # the posterior group's draws of that step when it holds them, so both groups describe one sample
            theta = draws[:, chosen.index(at)] if at in chosen else record.equal_weight_samples(rng, n)
            values = np.asarray(pointwise_loglike(theta, dataset), dtype=float)
            if values.ndim != 2 or values.shape[0] != n:
                raise ValueError(f"pointwise_loglike: returned shape {values.shape} for theta of shape {theta.shape}; "
                                 f"expected ({n}, n_observations)")
            groups["log_likelihood"] = xr.Dataset(
                {"y": (("chain", "draw", "observation"), values[None])},
                coords={"chain": [0], "draw": np.arange(n), "observation": np.arange(values.shape[1])},
                attrs={"step": int(record.info.step)})
        return groups
