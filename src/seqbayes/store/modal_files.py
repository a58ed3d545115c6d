"""``seqbayes track``: a poles table tracked into one modal dataset per record, and a run to update with them.

:func:`track_to_folder` reads a modes table of many records (:mod:`seqbayes.structural.modes_table`),
tracks its poles (:func:`seqbayes.structural.tracking.track_poles`) and writes, in one folder:

- ``<prefix>_001.csv`` ...: one tracked modes table per record that holds a tracked mode (with the
  ``mode`` column and, given a covariates table, the record's covariates and ``temperature``, their mean
  over the sensors that gave a value), in time order: the datasets of ``seqbayes update``;
- ``tracking.csv``: one row per record: ``day``, the poles it had, those assigned to no mode, the tracked
  frequency of each mode (empty where missing) and ``temperature``;
- ``run.toml``: a modal run of the tracked modes (each mode's frequency a parameter drifting by a random
  walk from record to record, its noise and prediction error from the tracker's fit), so that
  ``seqbayes init run.toml run.nc`` and ``seqbayes update run.nc <prefix>_*.csv`` need no hand-written step.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["track_to_folder", "run_toml"]

#: half-width of the uniform prior box of each mode's frequency, relative (the box is the parameter space: it
#: must hold the whole period's range of each tracked mode)
PRIOR_HALF_WIDTH = 0.05


def run_toml(tracked, name: str, n_samples: int = 300, seed: int = 0) -> str:
    """The text of a mode-level modal run of ``tracked``'s modes (:class:`~seqbayes.structural.tracking.TrackedModes`)."""
    ref = tracked.reference
    f = ref.frequencies
    rel = np.maximum(ref.scatter / f, 1e-4)
    lines = [f"# A modal run of the {ref.n_modes} modes tracked by seqbayes track (docs/modal.md): mode j's frequency",
             "# fj [Hz] drifts by a random walk from record to record; the kernel noise is each track's fitted drift per",
             "# record, frequency_error its fitted scatter (relative), the prior a box of +-5 % about its start.",
             "[model]", f'name = "{name}"', 'likelihood = "modal"', "", "[modal]", 'model = "modes"',
             "frequency_error = [" + ", ".join(f"{v:.2g}" for v in rel) + "]",
             f"# the OMA's std_frequency_hz are not used: the tracker weighs them by {np.median(ref.std_scale):.2g} "
             f"(median over modes)",
             "std_scale = 0.0", "", "[priors]"]
    for j, fj in enumerate(f):
        lines.append(f'f{j + 1} = {{ dist = "uniform", lower = {fj * (1 - PRIOR_HALF_WIDTH):.5g}, '
                     f'upper = {fj * (1 + PRIOR_HALF_WIDTH):.5g} }}')
    lines += ["", "[kernel]"]
    for j in range(ref.n_modes):
        lines.append(f'f{j + 1} = {{ type = "drift", rate = 0.0, noise_std = {max(ref.drift[j], 1e-6 * f[j]):.2g} }}')
    lines += ["", "[sampler]", 'type = "SEMC"', f"n_samples = {int(n_samples)}", f"seed = {int(seed)}",
              "# a mode missing for some records returns with a wide predictive; the path-space remedy for abrupt",
              "# changes would re-assimilate 10 records at every such return (docs/modal.md)",
              "conflict_remedy = false", ""]
    return "\n".join(lines)


def _with_temperature(covariates):
    day, values = covariates
    stacked = np.column_stack(list(values.values()))
    counts = np.isfinite(stacked).sum(axis=1)
    with np.errstate(invalid="ignore"):
        mean = np.where(counts > 0, np.nansum(stacked, axis=1) / np.maximum(counts, 1), np.nan)
    return day, {**values, "temperature": mean}


def track_to_folder(poles_path, out, *, covariates_path=None, prefix: str = "record", settings=None,
                    frequencies=None, n_samples: int = 300, seed: int = 0) -> str:
    """Track ``poles_path`` and write the datasets, ``tracking.csv`` and ``run.toml`` in ``out`` (module docstring).

    Returns
    -------
    str
        What was found and written (a few lines and the per-mode table).
    """
    from ..structural.modes_table import read_covariates, read_modes_table
    from ..structural.tracking import TrackerSettings, reference_from_poles, track_poles

    settings = settings or TrackerSettings()
    poles = read_modes_table(poles_path)
    covariates = _with_temperature(read_covariates(covariates_path)) if covariates_path else None
    reference = reference_from_poles(poles, settings, frequencies)
    tracked = track_poles(poles, reference, settings)
    out = Path(out)
    files = tracked.write_datasets(out, prefix, covariates)
    _write_tracking(out / "tracking.csv", tracked, covariates)
    (out / "run.toml").write_text(run_toml(tracked, f"{Path(poles_path).stem}-modes", n_samples, seed))
    found = ", ".join(f"{f:.4g}" for f in reference.frequencies)
    total = poles.n_rows
    spurious = int(tracked.spurious.sum())
    lines = [f"{len(tracked.rows)} records, {total} poles: {reference.n_modes} modes tracked (starting at {found} Hz), "
             f"{spurious} poles ({100 * spurious / total:.0f} %) assigned to no mode",
             tracked.summary(),
             f"wrote {len(files)} datasets ({files[0].name} .. {files[-1].name}), tracking.csv and run.toml in {out}"
             if files else f"no record holds a tracked mode; nothing written in {out}"]
    return "\n".join(lines)


def _write_tracking(path: Path, tracked, covariates) -> None:
    from ..structural.tracking import covariates_at

    m = tracked.n_modes
    header = ["day", "poles", "spurious"] + [f"f{j + 1}" for j in range(m)] + (["temperature"] if covariates else [])
    lines = [",".join(header)]
    for r, rows in enumerate(tracked.rows):
        cells = [f"{tracked.day[r]:.6f}", str(rows.size), str(int(tracked.spurious[r]))]
        cells += ["" if not np.isfinite(v) else f"{v:.6f}" for v in tracked.frequency[r]]
        if covariates:
            t = covariates_at(tracked.day[r], covariates, tracked.reference.spacing)["temperature"]
            cells.append("" if not np.isfinite(t) else f"{float(t):.3f}")
        lines.append(",".join(cells))
    path.write_text("\n".join(lines) + "\n")
