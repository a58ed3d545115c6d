"""The ``seqbayes`` command line: on-line monitoring of one's own model, and the papers' studies.

Monitoring commands (a run is one NetCDF file, see :mod:`seqbayes.store`)::

    seqbayes init CONFIG.toml RUN.nc          # a new run from a TOML config (seqbayes.store.config; a [building]
                                              # section: an SG-EnMCMC run of a shear building, seqbayes.store.sg_config)
    seqbayes update RUN.nc DATA.csv [...]     # assimilate datasets (CSV or NetCDF), one step each
    seqbayes status RUN.nc                    # per step: mean, sd, credible interval, acceptance, ESS, evidence
    seqbayes predict RUN.nc --steps K         # forecast K steps ahead through the Markov kernel
    seqbayes predict RUN.nc --steps K --threshold "k<0.7"   # and the time to a threshold
    seqbayes compare RUN1.nc RUN2.nc ...      # model-class selection by evidence
    seqbayes report RUN.nc -o report.html     # HTML page with the figures

Paper studies live in :mod:`seqbayes.studies`; each module there has a
``main(argv) -> int`` and is reached as ``seqbayes example NAME [options]``
(``seqbayes example`` alone lists them).

Errors in user input (config, data file, likelihood, store) print one line
``seqbayes COMMAND: error: ...`` naming the file, field or shape, and exit with
status 2; the run store is left unchanged. ``--traceback`` shows the full trace.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import re
import sys
import traceback
import warnings
from pathlib import Path

#: The command's description in ``seqbayes --help`` (plain text: argparse does not render reST).
DESCRIPTION = """\
On-line Bayesian model updating: monitor one's own model, or run the papers' studies.

monitoring (a run is one NetCDF file):
  seqbayes init CONFIG.toml RUN.nc          a new run from a TOML configuration (with a [building]
                                            section: SG-EnMCMC of a shear building, one block per update)
  seqbayes update RUN.nc DATA.csv [...]     assimilate datasets (CSV or NetCDF), one step each
  seqbayes status RUN.nc                    per step: posterior mean, sd, interval, ESS, evidence
  seqbayes predict RUN.nc --steps K         forecast K steps ahead through the Markov kernel
      [--threshold "k<0.7"]                 ... and the distribution of the time to a threshold
  seqbayes compare RUN1.nc RUN2.nc ...      model-class selection by evidence
  seqbayes report RUN.nc -o report.html     HTML page with the figures
  seqbayes environment YEAR.csv --masses .. --stiffness ..
                                            damage against temperature on identified frequencies:
                                            P(damage) per day, its storey, the alarm
  seqbayes oma RECORD --fs FS [--out modes.csv] [--json modes.json] [--diagram d.png]
                                            modes with standard errors from an ambient record
  seqbayes track POLES.csv --out DIR        poles of many records tracked into modes: one modal dataset
                                            per record and a run.toml for seqbayes init (docs/modal.md)

studies:
  seqbayes example                          list the papers' studies
  seqbayes example NAME [options]           run one (NAME --help for its options)

Errors in user input print one line and exit with status 2; --traceback shows the trace."""

#: name -> (module with ``main(argv)``, one line for ``seqbayes example``); each module parses its own options.
EXAMPLES = {
    "quickstart": ("seqbayes.studies.quickstart",
                   "one-minute tour: a drifting offset and a fixed slope against the exact Kalman filter"),
    "coulomb": ("seqbayes.studies.coulomb",
                "Lye et al. (2023) Sec. 6: Coulomb friction from real measurements, kernels T1 vs T2"),
    "oscillator": ("seqbayes.studies.oscillator",
                   "Lye et al. (2023) Sec. 5: damped-oscillator degradation, six candidate kernels"),
    "acceptance": ("seqbayes.studies.acceptance",
                   "Lye et al. (2023) Sec. 4, Fig. 2: bounds on the SEMC acceptance rate"),
    "resampling": ("seqbayes.studies.resampling_illustration",
                   "Lye et al. (2023) Sec. 2.1, Fig. 1: why reweighting and resampling come before the moves"),
    "shake-table": ("seqbayes.studies.shake_table",
                    "Lin et al. (2024): SG-EnMCMC on the two shake-table case studies (synthetic replicas)"),
}

#: What the ESS printed by ``update``, ``status`` and the report is (one sentence, shown with it).
ESS_NOTE = ("ESS: effective sample size of the importance weights at the step's last tempering stage, "
            "before resampling (N for equal weights, 1 when one sample holds all the weight); "
            "'distinct': distinct samples in the final set, after resampling and moves")


#: Most sample-steps (horizon x N) a forecast or time-to-threshold of the command line simulates, and most
#: steps of a forecast: the forecast holds its draws in memory (8 d bytes each) and re-draws the paths that
#: leave the parameter space (up to 100 rounds of the whole horizon), so long horizons take minutes; beyond
#: these the command refuses in one line (docs/guide.md gives the bounds).
MAX_SIMULATED = 2_000_000
MAX_FORECAST_STEPS = 1000


class CommandError(Exception):
    """A user-facing error: printed as one line, exit status 2."""


def _check_horizon(option: str, steps: int, n_samples: int) -> None:
    """Refuse a forecast horizon whose simulation would exceed :data:`MAX_SIMULATED` sample-steps."""
    limit = min(MAX_SIMULATED // n_samples, MAX_FORECAST_STEPS if option != "--horizon" else MAX_SIMULATED)
    if steps > limit:
        raise CommandError(f"{option} {steps}: the command line simulates at most {limit} steps ahead for N = "
                           f"{n_samples} samples (at most {MAX_FORECAST_STEPS} forecast steps and "
                           f"{MAX_SIMULATED:.0e} sample-steps: a longer horizon takes minutes); use the Python API "
                           f"(RunStore.predict, RunStore.time_to_threshold) for more")


def _json(value) -> str:
    """``value`` as JSON text with NaN and infinities written ``null`` (bare ``NaN`` is not JSON)."""
    def clean(item):
        if isinstance(item, float):
            return item if item == item and abs(item) != float("inf") else None
        if isinstance(item, dict):
            return {key: clean(v) for key, v in item.items()}
        if isinstance(item, (list, tuple)):
            return [clean(v) for v in item]
        return item

    return json.dumps(clean(value), indent=1, allow_nan=False)


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """A warning as one line, ``seqbayes: warning: Category: text`` (no source line: the user did not write it)."""
    from .store.datasets import printable

    if _NUMERIC_WARNINGS is not None and _numeric(message, category):
        _NUMERIC_WARNINGS.append(str(message))     # said once, in our words, when the command ends
        return
    print(f"seqbayes: warning: {category.__name__}: {printable(message)}", file=file or sys.stderr)


#: numpy's floating-point warnings ("invalid value encountered in subtract"): counted, not printed raw
_NUMPY_FLOAT = re.compile(r"(invalid value|divide by zero|overflow|underflow) encountered in [\w .]+")
_NUMERIC_WORDS = {"invalid value": "an invalid value (NaN: inf - inf, 0 / 0, ...)",
                  "divide by zero": "a division by zero", "overflow": "an overflow", "underflow": "an underflow"}
#: the numeric warnings of the running command (None outside main())
_NUMERIC_WARNINGS: list | None = None


def _numeric(message, category) -> bool:
    return issubclass(category, RuntimeWarning) and _NUMPY_FLOAT.fullmatch(str(message)) is not None


def _numeric_summary(messages) -> str:
    """One line on the numeric warnings a command met, in our words: how often each kind occurred."""
    counts = {}
    for text in messages:
        kind = _NUMPY_FLOAT.fullmatch(text).group(1)
        counts[kind] = counts.get(kind, 0) + 1
    met = ", ".join(f"{_NUMERIC_WORDS[kind]} {n} time{'s' if n > 1 else ''}" for kind, n in counts.items())
    return f"the computation met {met} (numpy floating-point warnings); check the data's units and the options"


# --------------------------------------------------------------------- bounded options
def _bounded(kind, low=None, high=None, *, open_low=False, open_high=False, allow_inf=False):
    """An argparse type: a number of ``kind`` (int or float) within the bounds, else a one-line error saying
    what is expected (NaN is refused; inf only with ``allow_inf``)."""
    def parse(text):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {'an integer' if kind is int else 'a number'}, "
                                             f"got {text!r}") from None
        finite = value == value and abs(value) != float("inf")
        below = low is not None and (value <= low if open_low else value < low)
        above = high is not None and (value >= high if open_high else value > high)
        if not (finite or (allow_inf and value == float("inf"))) or below or above:
            lo = "" if low is None else f"{'>' if open_low else '>='} {low:g}"
            hi = "" if high is None else f"{'<' if open_high else '<='} {high:g}"
            raise argparse.ArgumentTypeError(f"expected {'an integer' if kind is int else 'a number'} "
                                             f"{' and '.join(b for b in (lo, hi) if b)}, got {text}")
        return value
    parse.__name__ = kind.__name__          # argparse names the type in its messages
    return parse


def _range_option(low: float, high: float):
    """An argparse type for ``LOW,HIGH``: two finite numbers ``low <= LOW < HIGH <= high``."""
    def parse(text):
        try:
            first, second = (float(v) for v in text.split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected LOW,HIGH (two numbers), got {text!r}") from None
        if not low <= first < second <= high:
            raise argparse.ArgumentTypeError(f"expected LOW,HIGH with {low:g} <= LOW < HIGH <= {high:g}, got {text}")
        return first, second
    parse.__name__ = "range"
    return parse


class _Parser(argparse.ArgumentParser):
    """argparse with its errors on one line (no usage block): ``seqbayes CMD: error: ... (see --help)``."""

    def error(self, message):
        from .store.datasets import printable

        self.exit(2, f"{self.prog}: error: {printable(message)} (see {self.prog} --help)\n")


def list_examples() -> str:
    """The ``seqbayes example`` listing: one line per study."""
    width = max(map(len, EXAMPLES))
    lines = ["usage: seqbayes example NAME [options]   (NAME --help for a study's options)", "", "examples:"]
    lines += [f"  {name:<{width}}  {line}" for name, (_, line) in EXAMPLES.items()]
    return "\n".join(lines)


def _run_example(name: str | None, argv: list[str]) -> int:
    if name is None or name in ("-h", "--help"):
        print(list_examples())
        return 0
    if name not in EXAMPLES:
        print(f"seqbayes example: unknown example {name!r}; choose from {', '.join(EXAMPLES)} "
              f"(run 'seqbayes example' to list them)", file=sys.stderr)
        return 2
    module = importlib.import_module(EXAMPLES[name][0])
    return int(module.main(argv) or 0)


def _progress_enabled() -> bool:
    return sys.stderr.isatty()


class _CountingLikelihood:
    """Wraps the likelihood to advance a tqdm bar by the number of samples evaluated (serial runs only)."""

    def __init__(self, func, bar):
        self.func, self.bar = func, bar

    def __call__(self, theta, data):
        out = self.func(theta, data)
        self.bar.update(len(theta))
        return out


# --------------------------------------------------------------------- commands
# Every command opens the run through the store registry (seqbayes.store.open_run) and asks its backend;
# what a kind of run cannot do, its backend refuses (BaseStore.require) with a message naming the alternative.
def cmd_init(args: argparse.Namespace) -> int:
    from .store import create_run, load_config
    from .store.datasets import printable
    from .store.files import store_lock

    config = load_config(args.config)
    _check_targets([], inputs=[args.config, getattr(config, "likelihood_file", None)], stores=(),
                   run=("RUN", args.run))
    with store_lock(args.run, create=True, timeout=args.lock_timeout):
        store = create_run(args.run, config, overwrite=args.force)
    print(f"created {printable(store.describe())}")
    return 0


def cmd_update(args: argparse.Namespace) -> int:
    from tqdm.auto import tqdm

    from .store import BoundWarning, open_run
    from .store.datasets import printable
    from .store.files import store_lock

    show = _progress_enabled() and not args.quiet
    with store_lock(args.run, timeout=args.lock_timeout):
        store = open_run(args.run)
        if args.replace_last:
            store.require("replace_last")
        for path in args.datafiles:
            if _same_file(path, args.run):
                raise CommandError(f"{path}: is the run store {args.run} itself, not a data file")
        tables = [store.read_datafile(path) for path in args.datafiles]  # all files checked first
        executor, close = store.make_executor()
        done = []
        try:
            for path, table in tqdm(list(zip(args.datafiles, tables)), desc="datasets", unit="dataset",
                                    disable=not show or len(tables) < 2):
                with tqdm(desc=f"step {store.n_steps + (0 if args.replace_last else 1)}: likelihood",
                          unit="eval", disable=not show or executor is not None or not store.evaluates_likelihood,
                          leave=False) as bar, warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always", BoundWarning)
                    try:
                        loglike = (_CountingLikelihood(store.load_likelihood(args.accept_model_change), bar)
                                   if not bar.disable else None)
                        info = store.assimilate(table, Path(path).name, replace_last=args.replace_last,
                                                executor=executor, loglike=loglike,
                                                accept_model_change=args.accept_model_change)
                    except (KeyboardInterrupt, SystemExit):
                        raise
                    except Exception as err:
                        raise CommandError(f"{path}: {_describe(err, store, done)}") from err
                done.append(f"{Path(path).name} (step {store.n_steps})")
                tqdm.write(printable(f"{args.run}: {store.step_summary(info, Path(path).name)}"), file=sys.stdout)
                for warning in caught:  # one line each (BoundWarning says what it is in its text)
                    if _NUMERIC_WARNINGS is not None and _numeric(warning.message, warning.category):
                        _NUMERIC_WARNINGS.append(str(warning.message))   # counted, said once at the end
                        continue
                    kind = "" if issubclass(warning.category, BoundWarning) else f"{warning.category.__name__}: "
                    print(f"seqbayes update: warning: {kind}{printable(warning.message)}", file=sys.stderr)
                args.replace_last = False
        finally:
            close()
    return 0


def _raised_in(err, files) -> bool:
    """Whether the exception passed through one of ``files`` (the user's likelihood module)."""
    files = {str(Path(f).resolve()) for f in files if f}
    return any(str(Path(frame.filename).resolve()) in files for frame in traceback.extract_tb(err.__traceback__))


def _describe(err, store, done=()) -> str:
    """One line for an update that failed, saying what the run store holds now."""
    from .store import ConfigError, DataError, StoreError

    if done:
        unchanged = (f"the run store keeps the steps committed before it ({', '.join(done)}); this file and the "
                     f"ones after it were not assimilated")
    else:
        unchanged = "the run store is unchanged"
    text = str(err)
    if isinstance(err, (StoreError, ConfigError, DataError)):
        return text if "previous store is kept" in text else f"{text}; {unchanged}"
    if isinstance(err, OSError):
        where = f" ({err.filename})" if err.filename else ""
        return f"{err.strerror or text}{where}; {unchanged}"
    user = store.user_code()        # (module:function, file) of the user's likelihood, if the run has one
    if user is not None and isinstance(err, ValueError) and text.startswith("loglike"):
        return f"likelihood {user[0]}: {text}; {unchanged}"
    if user is not None and _raised_in(err, [user[1]]):
        return f"the likelihood {user[0]} raised {type(err).__name__}: {text}; {unchanged}"
    if isinstance(err, ValueError) or type(err).__name__ in ("ZeroLikelihoodError", "TemperingLimitError"):
        return f"{text}; {unchanged}"
    return (f"{type(err).__name__} in seqbayes: {text} (a bug: please report it with --traceback); "
            f"{unchanged}")


def cmd_status(args: argparse.Namespace) -> int:
    from .store import open_run

    store = open_run(args.run)
    if args.json:
        print(_json(store.status_json(args.level)))
    else:
        print(store.status(args.level))
    return 0


def cmd_predict(args: argparse.Namespace) -> int:
    from .prognostics import parse_threshold
    from .store import open_run
    from .store.report import first_passage_json, forecast_rows, format_first_passage, format_forecast
    from .store.targets import forecast_file

    store = open_run(args.run)
    store.require("predict")
    if store.n_steps == 0:
        raise CommandError(f"{args.run}: no dataset assimilated yet; nothing to forecast from")
    if args.steps < 1:
        raise CommandError(f"--steps: must be >= 1, got {args.steps}")
    _check_horizon("--steps", args.steps, store.config.n_samples)
    if args.output and Path(args.output).is_dir():
        raise CommandError(f"{args.output}: is a folder; give the forecast's file name, e.g. "
                           f"{Path(args.output) / 'forecast.csv'}")
    _check_targets([("--output", args.output, forecast_file(store.names))], inputs=_store_inputs(store),
                   stores=[args.run], force=args.force)
    thresholds = [parse_threshold(text, store.names) for text in args.threshold or ()]
    draws = store.predict(args.steps)
    rows = forecast_rows(store, args.steps, args.level, draws)
    passages = [(t, store.time_to_threshold(t.name, t.value, args.steps, direction=t.direction))
                for t in thresholds]
    if args.output:
        _write_forecast(Path(args.output), store, draws)
    if args.json:
        if passages:  # with thresholds the output is an object; without, the forecast rows as before
            print(_json({"forecast": rows, "thresholds": [first_passage_json(store, t, p) for t, p in passages]}))
        else:
            print(_json(rows))
    else:
        print(f"forecast from step {store.n_steps} of {args.run} ({store.config.name!r}), {draws.shape[1]} draws")
        print(format_forecast(rows, args.level))
        for threshold, passage in passages:
            print()
            print(format_first_passage(store, threshold, passage))
    return 0


def _write_forecast(path, store, draws):
    """The forecast draws as CSV or NetCDF, built in memory and written atomically (:mod:`seqbayes.store.targets`)."""
    import io

    import numpy as np
    import xarray as xr

    from .store.files import netcdf_bytes
    from .store.targets import write_output

    if path.suffix.lower() == ".csv":
        steps = np.repeat(np.arange(1, draws.shape[0] + 1) + store.n_steps, draws.shape[1])
        table = np.column_stack([steps, draws.reshape(-1, draws.shape[2])])
        # integer steps; the draws with 17 significant digits, so they read back bit for bit
        text = io.StringIO()
        np.savetxt(text, table, delimiter=",", header=",".join(["step", *store.names]), comments="",
                   fmt=["%d"] + ["%.17g"] * draws.shape[2])
        content = text.getvalue()
    else:
        content = netcdf_bytes(xr.Dataset({"forecast": (("step", "sample", "parameter"), draws)},
                                          coords={"step": np.arange(1, draws.shape[0] + 1) + store.n_steps,
                                                  "parameter": list(store.names)}), encoding={})
    write_output(path, content, "--output")


# ------------------------------------------------------------------ output targets
def _check_targets(outputs, *, inputs=(), stores=(), force=False, run=None) -> dict:
    """Refuse output targets that are inputs, stores or files the command did not write
    (:func:`seqbayes.store.targets.check_outputs`); ``outputs``: the fields of ``Output``; ``run``:
    ``(name, path)`` of a run store to create, checked against the inputs only (``init --force`` decides
    on an existing store)."""
    from .store.targets import Output, check_outputs, refuse_inputs

    if run is not None:
        refuse_inputs(*run, inputs=inputs)
    return check_outputs([Output(*o) for o in outputs], inputs=inputs, stores=stores, force=force)


def _same_file(first, second) -> bool:
    """Whether two paths name one file (through links too); False if either does not exist."""
    try:
        return os.path.samefile(first, second)
    except (OSError, ValueError):
        return False


def _store_inputs(store) -> list:
    """The user's files a run store names (its likelihood module): protected from outputs too."""
    user = store.user_code()
    return [user[1]] if user is not None and user[1] else []


def _open_for_comparison(paths, first=None):
    """The runs of ``paths`` (``first``: the first one, already open), their display names and the number
    of steps they share; each must be a run kind that compares by evidence."""
    from .store import open_run

    stores = []
    for i, path in enumerate(paths):
        store = first if i == 0 and first is not None else open_run(path)
        store.require("compare")
        stores.append(store)
    from .store.datasets import printable

    names = []
    for store in stores:  # shown in the comparison table: escaped like every name read from a file
        name = printable(store.config.name if store.config.name not in names
                         else f"{store.config.name} ({store.path.name})")
        names.append(name)
    n_common = min(s.n_steps for s in stores)
    if n_common == 0:
        raise CommandError("compare: every run needs at least one assimilated dataset")
    ref = stores[0]
    for store in stores[1:]:
        for s in range(n_common):
            if store.digests[s] != ref.digests[s]:
                raise CommandError(f"compare: step {s + 1} of {store.path} assimilated {store.sources[s]!r}, which "
                                   f"differs from {ref.sources[s]!r} in {ref.path}; models can only be compared "
                                   f"on the same datasets")
    return stores, names, n_common


def cmd_compare(args: argparse.Namespace) -> int:
    from .selection import compare
    from .store.report import comparison_rows

    stores, names, n_common = _open_for_comparison(args.runs)
    comparison = compare({n: s.result.log_evidence[:n_common] for n, s in zip(names, stores)})
    if args.json:
        print(_json({"steps": n_common, "best": comparison.best, "rows": comparison_rows(comparison)}))
        return 0
    if len({s.n_steps for s in stores}) > 1:
        print(f"note: runs have {', '.join(str(s.n_steps) for s in stores)} steps; comparing the first {n_common}")
    print(comparison.table())
    best = comparison.best
    for name in comparison.names:
        if name != best:
            print(f"log Bayes factor {best} vs {name}: {comparison.log_bayes_factor(best, name)[-1]:.3f}")
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from .prognostics import parse_threshold
    from .store import open_run
    from .store.targets import html_page, png_figure

    store = open_run(args.run)
    store.require(*[f"report --{name}" for name in ("compare", "threshold", "data") if getattr(args, name)])
    others = []
    if args.compare:
        stores, _, _ = _open_for_comparison([args.run, *args.compare], first=store)
        others = stores[1:]
    n_samples = getattr(store.config, "n_samples", None) or store.config.n_members   # SG-EnMCMC: n_members
    for option, steps in (("--forecast", args.forecast), ("--horizon", args.horizon if args.threshold else 0)):
        if steps < 0 or (option == "--horizon" and args.threshold and steps < 1):
            raise CommandError(f"{option}: must be >= {0 if option == '--forecast' else 1}, got {steps}")
        _check_horizon(option, steps, n_samples)
    output = Path(args.output) if args.output else Path(args.run).with_suffix(".html")
    if output.is_dir():
        raise CommandError(f"{output}: is a folder; give the report's file name, e.g. {output / 'report.html'}")
    figures = output.parent / f"{output.stem}_figures"          # --no-embed: the PNG files of the page
    if args.no_embed and os.path.lexists(figures) and not figures.is_dir():
        raise CommandError(f"{figures}: is not a folder; the report's figures go there (--no-embed)")
    old_figures = sorted(figures.glob("fig-*.png")) if args.no_embed and figures.is_dir() else []
    _check_targets([("--output", output, html_page, True), *[("--no-embed", f, png_figure) for f in old_figures]],
                   inputs=[args.data, args.modes, *_store_inputs(store)], stores=[args.run, *(args.compare or ())],
                   force=args.force)
    try:
        thresholds = [parse_threshold(text, store.names) for text in args.threshold or ()]
        store.write_report(output, level=args.level, embed=not args.no_embed, others=others,
                           forecast_steps=args.forecast, thresholds=thresholds, horizon=args.horizon,
                           fit_data=_assimilated_dataset(store, args.data) if args.data else None, modes=args.modes)
    except ValueError as err:
        raise CommandError(str(err)) from err
    print(f"report written to {output}")
    return 0


def _assimilated_dataset(store, path) -> tuple:
    """``(step index, table)`` of a data file the run assimilated (found by its content's hash)."""
    from .store.datasets import dataset_digest

    if store.config.predict is None:
        raise CommandError(f"--data: {store.path}'s configuration names no [model] predict function, so there is no "
                           f"fit to draw")
    table = store.read_datafile(path)
    digest = dataset_digest(table, store.config.columns)
    if digest not in store.digests:
        raise CommandError(f"--data: {path} was not assimilated by {store.path} (its steps: "
                           f"{', '.join(store.sources)})")
    return store.digests.index(digest), table


#: Text appended to the messages of the year CSV's checks: the options that change each rule.
ENVIRONMENT_HINTS = {"day": " (days since the first monitored day; --max-day sets the upper bound)",
                     "temperature": " (degC; --temperature-range LOW,HIGH sets the bounds)",
                     "frequency": " (Hz; --frequency-range LOW,HIGH sets the bounds)",
                     "extra": "; name the columns to read with --columns DAY,TEMPERATURE,F1,...,Fn",
                     "header": "; or name the file's columns with --columns DAY,TEMPERATURE,F1,...,Fn",
                     "ascending": " (mode 1 is the lowest; check the column order)"}
def cmd_environment(args: argparse.Namespace) -> int:
    """Damage against temperature on a year of identified frequencies (docs/environment.md)."""
    import numpy as np

    from .store.datasets import read_datafile
    from .store.environment_report import write_environment_report
    from .store.targets import html_page, json_with_keys, write_output
    from .structural.environment import monitor_year
    from .structural.structures import ShearBuilding
    from .studies.environment import check_against_building, check_days, check_memory, year_spec

    def numbers(text, name):
        try:
            values = [float(v) for v in text.split(",")]
        except ValueError:
            raise CommandError(f"{name}: expected comma-separated numbers, got {text!r}") from None
        if not all(0 < v < float("inf") for v in values):
            raise CommandError(f"{name}: expected positive finite numbers, got {text!r}")
        return values

    masses, stiffness = numbers(args.masses, "--masses"), numbers(args.stiffness, "--stiffness")
    if len(stiffness) != len(masses):
        raise CommandError(f"--stiffness: expected {len(masses)} values (one per storey, as --masses), got "
                           f"{len(stiffness)}")
    building = ShearBuilding(masses, stiffness)
    n = building.n_storeys
    targets = _check_targets([("--json", args.json, json_with_keys("alarm_day", "p_damage", "environment")),
                              ("--report", args.report, html_page)], inputs=[args.data], force=args.force)
    columns = None if args.columns is None else [c.strip() for c in args.columns.split(",")]
    if columns is not None and len(columns) != n + 2:
        raise CommandError(f"--columns: expected {n + 2} names (time, temperature and {n} frequencies for a "
                           f"{n}-storey building), got {len(columns)}")
    spec = year_spec(n, columns=columns, day_range=(0.0, args.max_day), temperature_range=args.temperature_range,
                     frequency_range=args.frequency_range, hints=ENVIRONMENT_HINTS)
    values = read_datafile(args.data, spec)
    table = {name: values[:, i] for i, name in enumerate(["day", "temperature"] + [f"f{r + 1}" for r in range(n)])}
    check_against_building(args.data, building, table, spec.columns[2:])
    check_memory(n, args.particles, len(np.unique(np.floor(table["day"]))))
    start = len(_NUMERIC_WARNINGS) if _NUMERIC_WARNINGS is not None else 0
    summary, monitor, days, records = monitor_year(building, table, rng=np.random.default_rng(args.seed),
                                                   n_particles=args.particles, threshold=args.threshold,
                                                   consecutive=args.consecutive)
    numeric = (_NUMERIC_WARNINGS or [])[start:]
    check_days(args.data, days, records, _numeric_summary(numeric).split(" (numpy")[0] if numeric else "")
    print(f"{'day':>5} {'P(damage)':>10} {'storey':>6} {'loss':>7}  P(M0), P(M1), ...")
    previous = None
    for day, record in zip(days, records):
        above = record.p_damage > args.threshold
        changed = previous is not None and (above != (previous.p_damage > args.threshold)
                                            or record.alarm != previous.alarm)
        previous = record
        if day % args.every == 0 or changed or day == days[-1]:  # and the days the rule's state changes
            damaged = record.storey is not None and record.p_damage > 0.5  # storey and loss mean little below
            storey, loss = (str(record.storey), f"{record.damage_size:.3f}") if damaged else ("-", "-")
            print(f"{day:>5} {record.p_damage:>10.3g} {storey:>6} {loss:>7}  "
                  f"{', '.join(f'{p:.3g}' for p in record.model_probabilities)}{'  ALARM' if record.alarm else ''}")
    environment = summary["environment"]
    print(f"alarm day: {summary['alarm_day']}, storey: {summary['storey']}; learned under M{environment['model']}: "
          f"alpha = {environment['alpha']:.3e}, beta = {environment['beta']:.3e}, sigma = {environment['sigma']:.3e}")
    if "--json" in targets:
        write_output(targets["--json"], json.dumps(summary, indent=1) + "\n", "--json")
    if "--report" in targets:
        out = write_environment_report(targets["--report"], monitor, table, days, records, summary, source=args.data)
        print(f"report: {out}")
    return 0


def cmd_oma(args: argparse.Namespace) -> int:
    """Operational modal analysis of one ambient record: modes with standard errors (docs/oma.md)."""
    from .structural.oma.io import run

    return run(args.record, dt=args.dt, fs=args.fs, band=args.band, out=args.out, json_path=args.json,
               diagram=args.diagram, day=args.day)
def cmd_track(args: argparse.Namespace) -> int:
    """Poles of many records tracked into one modal dataset per record (docs/modal.md)."""
    from .store.modal_files import track_to_folder
    from .structural.tracking import TrackerSettings

    frequencies = None
    if args.reference:
        try:
            frequencies = [float(v) for v in args.reference.split(",")]
        except ValueError:
            raise CommandError(f"--reference: expected comma-separated frequencies [Hz], got {args.reference!r}") from None
    settings = TrackerSettings(gate=args.gate, initial_days=args.initial_days, min_presence=args.min_presence)
    print(track_to_folder(args.poles, args.out, covariates_path=args.temperature, prefix=args.prefix,
                          settings=settings, frequencies=frequencies))
    return 0


# ----------------------------------------------------------------------- parser
#: ``--lock-timeout`` of the commands that write a run store.
LOCK_TIMEOUT_OPTION = dict(type=_bounded(float, 0, allow_inf=True), default=None, metavar="SECONDS",
                           help="how long to wait while another update holds the run store's lock (which says who "
                                "holds it) before giving up; 0: do not wait, inf: no limit (default: "
                                "$SEQBAYES_LOCK_TIMEOUT, else 3600)")
#: ``--level`` of the commands that print credible intervals.
LEVEL_OPTION = dict(type=_bounded(float, 0, 1, open_low=True, open_high=True), default=0.95)
#: ``--force`` of the commands that write files besides a run store (:mod:`seqbayes.store.targets`).
FORCE_OPTION = dict(action="store_true", help="replace an existing output file that this command did not write "
                                              "(never an input or a run store)")
#: Most particles per model of ``seqbayes environment`` (the memory bound after reading the data is tighter).
MAX_PARTICLES = 10_000_000


def build_parser() -> argparse.ArgumentParser:
    from ._version import __version__
    from .studies.environment import DAY_RANGE, FREQUENCY_RANGE, TEMPERATURE_RANGE

    parser = _Parser(prog="seqbayes", description=DESCRIPTION,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"seqbayes {__version__}")
    parser.add_argument("--traceback", action="store_true", help="show the full traceback on errors")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("init", help="create a run from a TOML config")
    p.add_argument("config", help="TOML run configuration (see seqbayes.store.config)")
    p.add_argument("run", help="run store to create (a .nc file)")
    p.add_argument("--force", action="store_true", help="overwrite an existing run store")
    p.add_argument("--lock-timeout", **LOCK_TIMEOUT_OPTION)
    p.set_defaults(func=cmd_init)

    p = sub.add_parser("update", help="assimilate one or more datasets (CSV or NetCDF), one step each")
    p.add_argument("run")
    p.add_argument("datafiles", nargs="+", metavar="DATAFILE")
    p.add_argument("--replace-last", action="store_true",
                   help="roll back the last step and assimilate the (first) dataset in its place")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    p.add_argument("--accept-model-change", action="store_true",
                   help="run the likelihood module although its file changed since the run recorded it "
                        "(the new hash is recorded)")
    p.add_argument("--lock-timeout", **LOCK_TIMEOUT_OPTION)
    p.set_defaults(func=cmd_update)

    p = sub.add_parser("status", help="table of steps: posterior mean, sd, credible intervals, diagnostics")
    p.add_argument("run")
    p.add_argument("--level", **LEVEL_OPTION, help="credible level (default 0.95)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_status)

    p = sub.add_parser("predict", help="forecast the parameters K steps ahead")
    p.add_argument("run")
    p.add_argument("--steps", type=_bounded(int, 1), required=True, metavar="K")
    p.add_argument("--level", **LEVEL_OPTION)
    p.add_argument("--json", action="store_true")
    p.add_argument("--output", "-o", help="also write the forecast draws (.csv or .nc)")
    p.add_argument("--force", **FORCE_OPTION)
    p.add_argument("--threshold", action="append", metavar="EXPR",
                   help='time to a threshold over the K steps: "NAME<VALUE" (the parameter falls below VALUE) or '
                        '"NAME>VALUE"; repeat for several. Quote it: < and > are shell redirections')
    p.set_defaults(func=cmd_predict)

    p = sub.add_parser("compare", help="model-class selection between runs on the same datasets")
    p.add_argument("runs", nargs="+", metavar="RUN")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("report", help="HTML report with figures")
    p.add_argument("run")
    p.add_argument("--output", "-o", help="HTML file (default: RUN with suffix .html)")
    p.add_argument("--compare", nargs="+", metavar="RUN", help="competing runs shown in the evidence figures")
    p.add_argument("--forecast", type=_bounded(int, 0), default=3, metavar="K",
                   help="forecast horizon (default 3, 0: none)")
    p.add_argument("--level", **LEVEL_OPTION)
    p.add_argument("--no-embed", action="store_true", help="write PNG files next to the page instead of base64")
    p.add_argument("--threshold", action="append", metavar="EXPR",
                   help='add the time to a threshold, "NAME<VALUE" or "NAME>VALUE" (repeatable)')
    p.add_argument("--horizon", type=_bounded(int, 1), default=20, metavar="H",
                   help="steps ahead for the time to a threshold (default 20)")
    p.add_argument("--data", metavar="DATAFILE",
                   help="one of the assimilated datasets, for the data-versus-fit panel (needs [model] predict in "
                        "the configuration; default: the last one when the run keeps its datasets)")
    p.add_argument("--modes", metavar="CSV",
                   help="SG-EnMCMC runs: identified mode shapes for the MAC (one row per floor, bottom to top, one "
                        "column per mode; default: the shapes of the configured building at ratios 1)")
    p.add_argument("--force", **FORCE_OPTION)
    p.set_defaults(func=cmd_report)

    p = sub.add_parser("environment", help="damage against temperature on a CSV of identified frequencies "
                                            "(day,temperature,f1,...,fn)")
    p.add_argument("data", help="CSV with the header day,temperature,f1,...,fn; one update per whole day")
    p.add_argument("--masses", required=True, help="floor masses [kg], bottom to top, comma-separated")
    p.add_argument("--stiffness", required=True, help="nominal storey stiffnesses [N/m], comma-separated")
    p.add_argument("--particles", type=_bounded(int, 10, MAX_PARTICLES), default=128,
                   help="particles per model (default 128)")
    p.add_argument("--threshold", type=_bounded(float, 0, 1, open_low=True, open_high=True), default=0.95,
                   help="alarm when P(damage) exceeds this ...")
    p.add_argument("--consecutive", type=_bounded(int, 1, 100_000), default=2, help="... on this many days in a row")
    p.add_argument("--seed", type=_bounded(int, 0, 2 ** 63 - 1), default=0)
    p.add_argument("--every", type=_bounded(int, 1, 10 ** 9), default=30,
                   help="print every this many days (and the days P(damage) or the alarm changes state)")
    p.add_argument("--columns", metavar="NAMES",
                   help="the file's columns to read, comma-separated: time [days], temperature [degC] and the n "
                        "frequencies [Hz], ascending (default: the header day,temperature,f1,...,fn, and no other "
                        "column; with --columns other columns are ignored)")
    p.add_argument("--max-day", type=_bounded(float, 0, 1e8, open_low=True), default=DAY_RANGE[1], metavar="DAYS",
                   help=f"latest day accepted (default {DAY_RANGE[1]:g}: 100 years); days start at 0 and must "
                        f"increase from row to row")
    p.add_argument("--temperature-range", type=_range_option(-1e4, 1e4), default=TEMPERATURE_RANGE,
                   metavar="LOW,HIGH", help=f"temperatures accepted [degC] (default {TEMPERATURE_RANGE[0]:g},"
                                            f"{TEMPERATURE_RANGE[1]:g})")
    p.add_argument("--frequency-range", type=_range_option(1e-9, 1e9), default=FREQUENCY_RANGE, metavar="LOW,HIGH",
                   help=f"frequencies accepted [Hz] (default {FREQUENCY_RANGE[0]:g},{FREQUENCY_RANGE[1]:g})")
    p.add_argument("--json", help="write P(damage) per day, the alarms and the learned model here")
    p.add_argument("--report", metavar="HTML", help="write the year's report here: frequencies against temperature "
                                                    "with the learned law, P(damage) and the alarm, day by day")
    p.add_argument("--force", **FORCE_OPTION)
    p.set_defaults(func=cmd_environment)

    p = sub.add_parser("oma", help="modes with standard errors from an ambient record (automated SSI-cov)")
    p.add_argument("record", help="CSV (header of channel names, optional time column) or .npy array (T, p)")
    rate = p.add_mutually_exclusive_group(required=True)
    rate.add_argument("--dt", type=float, help="sampling step [s]")
    rate.add_argument("--fs", type=float, help="sampling rate [Hz]")
    p.add_argument("--band", metavar="LO,HI", help="frequencies sought [Hz] (default: derived from the spectrum)")
    p.add_argument("--out", metavar="CSV", help="write the modes table here (docs/oma.md: the mast poles' columns "
                                                "and phi_<channel>, std_phi_<channel>)")
    p.add_argument("--json", metavar="JSON", help="write the modes, the settings chosen and the messages here")
    p.add_argument("--diagram", metavar="PNG", help="draw the stabilisation diagram here")
    p.add_argument("--day", type=float, help="the record's start in days (the table's day column)")
    p.set_defaults(func=cmd_oma)
    p = sub.add_parser("track", help="track the poles of many records into modes: one modal dataset per record")
    p.add_argument("poles", help="modes table of many records (time_start, day, slot, frequency_hz, std_frequency_hz, "
                                 "..., phi_<channel>...; docs/modal.md), e.g. an automated OMA's output")
    p.add_argument("--out", required=True, metavar="DIR", help="folder for the datasets, tracking.csv and run.toml")
    p.add_argument("--temperature", metavar="CSV", help="covariates per record (a day column and one column per "
                                                        "sensor): copied into the datasets, with their mean as "
                                                        "temperature")
    p.add_argument("--prefix", default="record", help="dataset file names: PREFIX_001.csv, ... (default record)")
    p.add_argument("--reference", metavar="F1,F2,...", help="the modes to track [Hz] (default: found in the first days)")
    p.add_argument("--initial-days", type=float, default=3.0, help="days the modes and their noise are found in (3)")
    p.add_argument("--gate", type=float, default=3.5, help="a pole joins a mode within this many sds (3.5)")
    p.add_argument("--min-presence", type=float, default=0.25,
                   help="a mode must be seen in this share of the first days' records (0.25)")
    p.set_defaults(func=cmd_track)

    p = sub.add_parser("example", help="run one of the papers' studies (no NAME: list them)", add_help=False)
    p.add_argument("name", nargs="?", help=f"one of: {', '.join(EXAMPLES)}")
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args, rest = parser.parse_known_args(argv)
    if args.command != "example" and rest:
        parser.error(f"unrecognized arguments: {' '.join(rest)}")
    from .store import ConfigError, DataError, StoreError

    from .store.datasets import printable

    global _NUMERIC_WARNINGS
    name = args.command if args.command != "example" else f"example {args.name or ''}".strip()
    outer, _NUMERIC_WARNINGS = _NUMERIC_WARNINGS, []
    numeric = _NUMERIC_WARNINGS
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning   # restored on leaving: main() is also called from Python
            # every one of numpy's floating-point warnings reaches _show_warning, to be counted (not only the first)
            warnings.filterwarnings("always", message=_NUMPY_FLOAT.pattern, category=RuntimeWarning)
            if args.command == "example":
                code = _run_example(args.name, rest)
            else:
                code = int(args.func(args) or 0)
        if numeric:
            print(f"seqbayes {name}: warning: {_numeric_summary(numeric)}", file=sys.stderr)
        return code
    except (CommandError, ConfigError, DataError, StoreError, ValueError, TypeError) as err:
        if args.traceback:
            raise
        # the line quotes file names and fields from files the user was handed: no raw control characters
        print(f"seqbayes {name}: error: {printable(err)}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # `seqbayes status RUN | head`: the reader has what it wanted
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as err:  # a read-only folder, a full disk, a path that is a folder, ...
        if args.traceback:
            raise
        where = f"{err.filename}: " if err.filename else ""
        print(f"seqbayes {name}: error: {printable(f'{where}{err.strerror or err}')}", file=sys.stderr)
        return 2
    except MemoryError:
        if args.traceback:
            raise
        print(f"seqbayes {name}: error: not enough memory for this run; reduce the sizes asked for (samples, "
              f"particles, steps ahead)", file=sys.stderr)
        return 2
    except (KeyboardInterrupt, SystemExit):
        raise
    except Exception as err:  # a bug: one line still, the trace on request
        if args.traceback:
            raise
        print(f"seqbayes {name}: error: {type(err).__name__} in seqbayes: {printable(err, 200)} (a bug: please "
              f"report it with the output of --traceback)", file=sys.stderr)
        return 2
    finally:
        _NUMERIC_WARNINGS = outer


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
