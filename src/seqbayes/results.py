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

__all__ = ["StepInfo", "StepRecord", "Result", "weighted_quantile", "prior_data_conflict"]


@dataclass(frozen=True)
class StepInfo:
    """Diagnostics of one on-line step (one dataset).

    Attributes
    ----------
    step : int
        1-based index of the dataset.
    log_evidence_increment : float
        ``log p(D^s | D^{1:s-1})``, summed over tempering stages (Eq. 1).
    log_evidence : float
        Cumulative ``log p(D^{1:s})``.
    ess : float
        Effective sample size after the last reweighting, before resampling.
    resampled : bool
        Whether the last stage resampled (with the IBIS schedule, ``move_every_stage=False`` and
        a static kernel: whether the step began with the deferred resample-move).
    acceptance_rate : float
        True rate over the step's moves: accepted proposals / proposals made.
    step_size : float
        Stretch-move step size ``u`` after the step (NaN for SMC).
    n_virtual : int
        Virtual iterations (SEMC sweeps) in the step, all stages.
    n_stages : int
        Tempering stages (1 without tempering).
    temperatures : tuple of float
        Tempering exponents reached, ending with 1.0.
    n_loglike_evals : int
        Likelihood evaluations (samples) in the step.
    n_nan : int
        Likelihood values that were NaN (counted as zero likelihood).
    n_distinct : int
        Distinct posterior samples at the end of the step.
    n_proposed, n_accepted, n_identical_partner : int
        Move counts; ``n_identical_partner`` are stretch proposals whose partner
        was an identical copy of the walker.
    log_evidence_increment_path : float
        The tempering path's estimate of the increment (Eq. 1); equals
        ``log_evidence_increment`` when ``evidence="path"``.
    evidence_ess : float
        Effective sample size of the importance-sampling evidence (NaN for ``"path"``);
        small values (say below N / 10) flag an unreliable increment.
    n_independent_accepted : int
        Particles moved by the independence-MH sweep that reuses the importance draws
        (not counted in ``acceptance_rate``, which is the sampler's own move).
    n_move_evaluations : int
        Likelihood evaluations made by the sampler's own moves (part of ``n_loglike_evals``,
        which also counts the initial, restart and importance evaluations).
    wall_time : float
        Seconds spent in the step.
    prior_data_conflict : float
        How far the step's posterior lies in the tail of its prior (the predictive distribution
        restricted to the parameter space for ``s > 1``): the largest over parameters of
        ``|posterior mean - prior mean| / prior sd`` (``seqbayes.predictive.particle.step_conflict``).
        Under the model this exceeds 4 with probability below ~1e-4 per parameter; larger values
        flag an abrupt change or a kernel too narrow for the data (see :func:`prior_data_conflict`).
    conflict_parameter : int
        The parameter (column) where it is largest.
    inner_ess : float
        SMC^2 with a particle inner filter: the inner filters' mean ESS after weighting, as a
        fraction of their size (NaN otherwise). Below ~0.02 the likelihood estimates are too
        noisy for the PMMH moves (raise ``n_inner``; see docs/core.md).
    ancestor_ess : float
        How many of the predictive mixture's components (Eq. A3: the previous posterior's
        particles through the exact transition with ``"transition"``) carry this step's posterior,
        ``1 / sum_j a_j^2`` (:meth:`~seqbayes.predictive.mixture.GaussianMixture.ancestor_ess`, or
        :func:`~seqbayes.predictive.lineage.ancestor_draws` once paths are carried; NaN at step 1 and where
        the conflict remedy does not apply). Small values mean the posterior lies in the far tail
        of the mixture, which N particles do not represent.
    path_steps : int
        0: the step's target was the predictive mixture (Eq. A3). ``L > 0``: the conflict remedy
        assimilated it on the path space of the last ``L`` states (the exact target;
        :func:`~seqbayes.predictive.paths.PathSpace`).
    jump_probability : float
        With a kernel with :class:`~seqbayes.kernels.Jump` components: the posterior probability
        that some parameter jumped between the previous step and this one (NaN at step 1 and
        without jumps; :func:`~seqbayes.kernels.jump_posterior`).
    jump_parameter : int
        The jump parameter (column) most likely to have jumped.
    jump_size, jump_size_sd : float
        Posterior mean and sd of its drop fraction given that it jumped (the drop is
        ``jump_size * reference``).
    log_evidence_increment_se, log_evidence_se : float
        Standard errors of ``log_evidence_increment`` and of the cumulative ``log_evidence``
        (:func:`~seqbayes.predictive.evidence.step_standard_errors`; NaN for SMC^2 and multi-stage path estimates).
    n_screen_evaluations, n_screened_out : int
        Delayed acceptance (``SamplerConfig.surrogate``): the cheap screen's evaluations and the proposals it
        rejected without a likelihood call. The expensive calls are ``n_loglike_evals`` (of which the moves'
        are ``n_move_evaluations``).
    amortised_evals : float
        SMC^2: likelihood evaluations per update so far, ``sum of n_loglike_evals / step`` (NaN otherwise).
    pmmh_acceptance : float
        SMC^2: PMMH acceptance of the current rejuvenation so far, or of the one that ended in this step
        (NaN when none has run). Below ~0.2 the moves cost more than they diversify (raise ``n_inner``).
    pending_moves : int
        SMC^2: at most this many PMMH attempts are still scheduled for later updates (a rejuvenation
        spreads its sweeps over updates within a budget, :mod:`seqbayes.predictive.pmmh`).
    jump_probability_se : float
        Monte Carlo standard error of ``jump_probability``
        (:func:`~seqbayes.predictive.jumps.jump_probability_se`; NaN where that is).
    """

    step: int
    log_evidence_increment: float
    log_evidence: float
    ess: float
    resampled: bool
    acceptance_rate: float
    step_size: float
    n_virtual: int
    n_stages: int
    temperatures: tuple
    n_loglike_evals: int
    n_nan: int
    n_distinct: int
    n_proposed: int
    n_accepted: int
    n_identical_partner: int
    log_evidence_increment_path: float
    evidence_ess: float
    n_independent_accepted: int
    n_move_evaluations: int
    wall_time: float
    prior_data_conflict: float = float("nan")
    conflict_parameter: int = 0
    inner_ess: float = float("nan")
    ancestor_ess: float = float("nan")
    path_steps: int = 0
    jump_probability: float = float("nan")
    jump_parameter: int = 0
    jump_size: float = float("nan")
    jump_size_sd: float = float("nan")
    log_evidence_increment_se: float = float("nan")
    log_evidence_se: float = float("nan")
    n_screen_evaluations: int = 0
    n_screened_out: int = 0
    amortised_evals: float = float("nan")
    pmmh_acceptance: float = float("nan")
    pending_moves: int = 0
    jump_probability_se: float = float("nan")

    @classmethod
    def from_dict(cls, values: dict) -> "StepInfo":
        """A record from stored values, tolerant of diagnostics added or removed since it was
        written: a missing field becomes NaN, 0, False or ``()``; an unknown one is dropped."""
        defaults = {"float": float("nan"), "int": 0, "bool": False, "tuple": ()}
        kwargs = {}
        for f in dataclasses.fields(cls):
            type_name = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", "float")
            value = values.get(f.name, defaults.get(type_name, float("nan")))
            kwargs[f.name] = (tuple(value) if type_name == "tuple" else bool(value) if type_name == "bool"
                              else int(value) if type_name == "int" else float(value))
        return cls(**kwargs)


def prior_data_conflict(prior: np.ndarray, prior_log_weights: np.ndarray, posterior: np.ndarray,
                        posterior_log_weights: np.ndarray) -> np.ndarray:
    """``|posterior mean - prior mean| / prior sd`` per parameter, ``(d,)``.

    Parameters
    ----------
    prior, posterior : (N, d) arrays
        The step's prior particles (before the likelihood) and its posterior particles.
    prior_log_weights, posterior_log_weights : (N,) arrays
    """
    w0, w1 = np.exp(normalise(prior_log_weights)), np.exp(normalise(posterior_log_weights))
    mean0 = w0 @ prior
    sd0 = np.sqrt(np.maximum(w0 @ (prior - mean0) ** 2, 1e-300))
    return np.abs(w1 @ posterior - mean0) / sd0


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
        from .resampling import systematic

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
        for f in dataclasses.fields(StepInfo):
            if f.name in ("step", "temperatures"):
                continue
            values = np.array([getattr(r.info, f.name) for r in self.steps])
            data[f.name] = (("step",), values.astype(np.int8) if values.dtype == bool else values)
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
