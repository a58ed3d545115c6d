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

The poles table and the covariates are read through the store's strict reader first
(:func:`~seqbayes.store.datasets.read_datafile` with a :class:`~seqbayes.store.datasets.TableSpec`: a regular
file within the size bound, UTF-8 text without NUL bytes or comments, ``,``-separated, ``day`` finite, within
:data:`DAY_LIMIT` and in time order, ``frequency_hz`` positive and within :data:`POLE_FREQUENCIES`); every
file is then checked as an output target (:func:`~seqbayes.store.targets.check_outputs`: never an input,
never a file another program wrote unless ``force``) before the first is written, and each is written
atomically (:func:`~seqbayes.store.targets.write_output`).

:func:`read_record` reads the record of ``seqbayes oma`` the same way: a ``.npy`` array through
:func:`~seqbayes.store.datasets.read_regular`, a CSV with a header row of channel names through
:func:`~seqbayes.store.datasets.read_datafile` (every column, the time column increasing).
"""

from __future__ import annotations

import csv
import io
import re
from pathlib import Path

import numpy as np

from .datasets import TableSpec, printable, read_datafile, read_regular
from .targets import Output, check_outputs, read_head, starts_with, write_output

__all__ = ["track_to_folder", "run_toml", "read_poles", "read_record", "DAY_LIMIT", "POLE_FREQUENCIES"]

#: Days accepted in a poles or covariates table: within 100 years either side of the first monitored day (a day
#: of 1e20 or a gap of 1e9 days is a broken clock, not a monitoring period).
DAY_LIMIT = 36525.0
#: Frequencies of poles accepted [Hz]: an identified structural mode outside this is a unit error.
POLE_FREQUENCIES = (1e-3, 1e4)
_PREFIX = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")

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
                    frequencies=None, n_samples: int = 300, seed: int = 0, force: bool = False) -> str:
    """Track ``poles_path`` and write the datasets, ``tracking.csv`` and ``run.toml`` in ``out`` (module docstring).

    Returns
    -------
    str
        What was found and written (a few lines and the per-mode table).
    """
    from ..structural.modes_table import modes_table_text, read_covariates
    from ..structural.tracking import TrackerSettings, reference_from_poles, track_poles

    if not isinstance(prefix, str) or not _PREFIX.fullmatch(prefix):
        raise ValueError(f"--prefix: expected a plain file-name stem (letters, digits, '_', '.', '-'; no folder), "
                         f"got {printable(prefix, 40)!r}")
    settings = settings or TrackerSettings()
    poles = read_poles(poles_path)
    covariates = None
    if covariates_path:
        read_datafile(covariates_path, TableSpec(("day",), time="day", time_range=(-DAY_LIMIT, DAY_LIMIT),
                                                 describe="day and one column per sensor"))
        covariates = _with_temperature(read_covariates(covariates_path))
    reference = reference_from_poles(poles, settings, frequencies)
    tracked = track_poles(poles, reference, settings)
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {printable(out)}: is a file, not a folder; give a folder for the datasets")
    tables = tracked.datasets(covariates)
    width = max(3, len(str(len(tables))))
    contents = {f"{prefix}_{i + 1:0{width}d}.csv": modes_table_text(t) for i, t in enumerate(tables)}
    contents["tracking.csv"] = _tracking_text(tracked, covariates)
    contents["run.toml"] = run_toml(tracked, f"{Path(poles_path).stem}-modes", n_samples, seed)
    recognise = {"tracking.csv": starts_with(b"day,poles,spurious"), "run.toml": starts_with(b"# A modal run of the")}
    # every file checked before the first is written: a refusal leaves the folder as it was
    check_outputs([Output("--out", out / name, recognise.get(name, starts_with(b"time_start,day,slot,mode,")),
                          creates_folder=True) for name in contents],
                  inputs=[p for p in (poles_path, covariates_path) if p], force=force)
    stale = _stale_datasets(out, prefix, contents, force)
    out.mkdir(parents=True, exist_ok=True)
    for name, text in contents.items():
        write_output(out / name, text, "--out")
    for path in stale:          # an earlier run's datasets beyond this run's: `update DIR/prefix_*.csv` would read them
        path.unlink(missing_ok=True)
    files = [out / name for name in contents if name.endswith(".csv") and name != "tracking.csv"]
    found = ", ".join(f"{f:.4g}" for f in reference.frequencies)
    total = poles.n_rows
    spurious = int(tracked.spurious.sum())
    removed = f"; removed {len(stale)} datasets of an earlier run beyond these" if stale else ""
    lines = [f"{len(tracked.rows)} records, {total} poles: {reference.n_modes} modes tracked (starting at {found} Hz), "
             f"{spurious} poles ({100 * spurious / total:.0f} %) assigned to no mode",
             tracked.summary(),
             f"wrote {len(files)} datasets ({files[0].name} .. {files[-1].name}), tracking.csv and run.toml in {out}"
             f"{removed}" if files else f"no record holds a tracked mode: no dataset; wrote tracking.csv and run.toml in {out}"]
    return "\n".join(lines)


def _stale_datasets(out: Path, prefix: str, contents: dict, force: bool) -> list[Path]:
    """``out``'s ``<prefix>_*.csv`` that this run does not write: earlier datasets of this command, to remove (a
    later ``seqbayes update DIR/<prefix>_*.csv`` would read them as records); another file of that name is
    refused unless ``force`` (then left alone)."""
    if not out.is_dir():
        return []
    recognise = starts_with(b"time_start,day,slot,mode,")
    stale = []
    for path in sorted(out.glob(f"{prefix}_*.csv")):
        if path.name in contents or not re.fullmatch(re.escape(prefix) + r"_\d+\.csv", path.name):
            continue
        head = read_head(path)
        if head is not None and recognise(head):
            stale.append(path)
        elif not force:
            raise ValueError(f"--out {printable(path)}: matches the datasets' names ({prefix}_NNN.csv) but is not one "
                             f"this command wrote, and `seqbayes update {printable(out)}/{prefix}_*.csv` would read it; "
                             f"move it, give another --prefix or --out, or --force to leave it")
    return stale


def _tracking_text(tracked, covariates) -> str:
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
    return "\n".join(lines) + "\n"


def read_poles(path):
    """A poles (modes) table (:func:`seqbayes.structural.modes_table.read_modes_table`) after the strict reader
    has checked its file and its ``day`` and ``frequency_hz`` columns (the module docstring)."""
    from ..structural.modes_table import read_modes_table

    lo, hi = POLE_FREQUENCIES
    spec = TableSpec(("day", "frequency_hz"), time="day", time_range=(-DAY_LIMIT, DAY_LIMIT), time_order="grouped",
                     ranges={"frequency_hz": POLE_FREQUENCIES}, positive=("frequency_hz",),
                     describe="time_start, day, slot, frequency_hz, std_frequency_hz, ... (docs/modal.md)",
                     hints={"day": f" (days since the first monitored day, within +-{DAY_LIMIT:g})",
                            "frequency_hz": f" (Hz; a structural mode lies within {lo:g}-{hi:g} Hz)"})
    read_datafile(path, spec)
    header = next(csv.reader(io.StringIO((read_head(path) or b"").decode("utf-8-sig", "replace").split("\n", 1)[0])), [])
    if any(not h.strip() for h in header):
        raise ValueError(f"{printable(path)}: column {[h.strip() for h in header].index('') + 1} of the header has no "
                         f"name (a trailing ','?); name every column")
    return read_modes_table(path)


_SEPARATORS = (";", "\t", "|")


def read_record(path, max_bytes: int | None = None):
    """Read the record file of ``seqbayes oma`` through the strict reader (module docstring).

    Returns
    -------
    y : (T, p) array
    channels : tuple of str
    dt_from_time : float or None
        The step of the file's time column [s], if it has one.
    """
    from ..structural.oma.io import MAX_RECORD_BYTES, record_from_npy, record_from_table, time_column

    path = Path(path)
    limit = MAX_RECORD_BYTES if max_bytes is None else int(max_bytes)
    head = read_head(path)
    if head is None or path.suffix.lower() == ".npy" or head[:6] == b"\x93NUMPY":
        data = read_regular(path, "record", limit)          # a FIFO, a device, a missing file: refused here
        if path.suffix.lower() == ".npy" or data[:6] == b"\x93NUMPY":
            return record_from_npy(data, path)
        head = data[:1 << 16]
    text = head.decode("utf-8-sig", errors="replace")
    header = [h.strip() for h in next(csv.reader(io.StringIO(text.split("\n", 1)[0].rstrip("\r"))), [])]
    problem = None
    if not header or any(not h for h in header) or len(set(header)) != len(header):
        problem = (f"the header row must name each column once (got {', '.join(repr(printable(h, 24)) for h in header[:8])}"
                   f"{', ...' if len(header) > 8 else ''})")
    elif "\ufffd" in header[0] or "\0" in header[0]:
        problem = "not a text CSV file (its first line is not UTF-8 text)"
    elif len(header) == 1 and any(sep in header[0] for sep in _SEPARATORS):
        problem = "its header seems separated by ';', tabs or '|': the columns of a record CSV are separated by ','"
    elif all(_is_number(h) for h in header):
        problem = ("line 1 holds numbers, not channel names: a record CSV starts with a header row naming its "
                   "columns (e.g. time,a1,a2; the time column is optional)")
    if problem is not None:
        read_regular(path, "record", limit)                  # the file's own problems (size, kind) first
        raise ValueError(f"RECORD: {printable(path)}: {problem}")
    t = time_column(header)
    spec = TableSpec(tuple(header), time=None if t is None else header[t], time_order="increasing",
                     describe="a header row of channel names")
    table = read_datafile(path, spec)
    return record_from_table(header, table, path)


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True
