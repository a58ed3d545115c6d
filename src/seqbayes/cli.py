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
    seqbayes update FLEET [--workers N]       # a fleet (a folder of stores or a manifest): each store's new
                                              # datasets, one Dask task per store (seqbayes.fleet)
    seqbayes status FLEET [--json]            # each store's last step, alarm and errors

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
import sys
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
  seqbayes update FLEET [--workers N]       a fleet (a folder of stores NAME.nc beside folders NAME/ of
      [--scheduler ADDRESS] [--json OUT]    their new datasets, or a manifest): one Dask task per store
  seqbayes status FLEET [--json]            each store's last step, alarm and errors
  seqbayes environment YEAR.csv --masses .. --stiffness ..
                                            damage against temperature on identified frequencies:
                                            P(damage) per day, its storey, the alarm

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

    print(f"seqbayes: warning: {category.__name__}: {printable(message)}", file=file or sys.stderr)


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
    with store_lock(args.run, create=True, timeout=args.lock_timeout):
        store = create_run(args.run, config, overwrite=args.force)
    print(f"created {printable(store.describe())}")
    return 0


def cmd_update(args: argparse.Namespace) -> int:
    from tqdm.auto import tqdm

    from .store import BoundWarning, open_run
    from .store.datasets import printable
    from .store.files import store_lock

    if _fleet_given(args, "update"):   # a folder of stores or a manifest: one task per store (docs/fleet.md)
        from .fleet import update_command

        return update_command(args.run, workers=args.workers, scheduler=args.scheduler, json_path=args.json,
                              lock_timeout=args.lock_timeout, accept_model_change=args.accept_model_change)
    show = _progress_enabled() and not args.quiet
    with store_lock(args.run, timeout=args.lock_timeout):
        store = open_run(args.run)
        if args.replace_last:
            store.require("replace_last")
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
                    kind = "" if issubclass(warning.category, BoundWarning) else f"{warning.category.__name__}: "
                    print(f"seqbayes update: warning: {kind}{printable(warning.message)}", file=sys.stderr)
                args.replace_last = False
        finally:
            close()
    return 0


def _describe(err, store, done=()) -> str:
    """One line for an update that failed, saying what the run store holds now (shared with the fleet)."""
    from .fleet import describe_failure

    return describe_failure(err, store, done)


def _fleet_given(args, command) -> bool:
    """Whether RUN is a fleet (a folder or a .toml/.json manifest); refuses the options of the other form."""
    from .fleet import is_fleet

    fleet = is_fleet(args.run)
    if command == "update" and fleet and (args.datafiles or args.replace_last):
        raise CommandError(f"{args.run}: a fleet takes no {'DATAFILE' if args.datafiles else '--replace-last'}: "
                           f"its stores' datasets come from its folders or its manifest (docs/fleet.md)")
    if command == "update" and not fleet:
        if not args.datafiles:
            if not Path(args.run).exists():
                raise CommandError(f"{args.run}: no such run store or fleet folder")
            raise CommandError("update: give the data files to assimilate after RUN (or a fleet's folder or "
                               "manifest as RUN)")
        given = [o for o, v in (("--workers", args.workers), ("--scheduler", args.scheduler),
                                ("--json", args.json)) if v is not None]
        if given:
            raise CommandError(f"{given[0]}: only for a fleet update (RUN a folder of stores or a manifest)")
    return fleet


def cmd_status(args: argparse.Namespace) -> int:
    from .store import open_run

    if _fleet_given(args, "status"):
        from .fleet import status_command

        return status_command(args.run, as_json=args.json)
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
    import numpy as np
    import xarray as xr

    if path.suffix.lower() == ".csv":
        steps = np.repeat(np.arange(1, draws.shape[0] + 1) + store.n_steps, draws.shape[1])
        table = np.column_stack([steps, draws.reshape(-1, draws.shape[2])])
        # integer steps; the draws with 17 significant digits, so they read back bit for bit
        np.savetxt(path, table, delimiter=",", header=",".join(["step", *store.names]), comments="",
                   fmt=["%d"] + ["%.17g"] * draws.shape[2])
    else:
        xr.Dataset({"forecast": (("step", "sample", "parameter"), draws)},
                   coords={"step": np.arange(1, draws.shape[0] + 1) + store.n_steps,
                           "parameter": list(store.names)}).to_netcdf(path, engine="h5netcdf")


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


def cmd_environment(args: argparse.Namespace) -> int:
    """Damage against temperature on a year of identified frequencies (docs/environment.md)."""
    import numpy as np

    from .structural.environment import monitor_year, read_frequency_csv
    from .structural.structures import ShearBuilding

    def numbers(text, name):
        try:
            return [float(v) for v in text.split(",")]
        except ValueError:
            raise CommandError(f"{name}: expected comma-separated numbers, got {text!r}") from None

    building = ShearBuilding(numbers(args.masses, "--masses"), numbers(args.stiffness, "--stiffness"))
    table = read_frequency_csv(args.data)
    summary, monitor, days, records = monitor_year(building, table, rng=np.random.default_rng(args.seed),
                                                   n_particles=args.particles, threshold=args.threshold,
                                                   consecutive=args.consecutive)
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
    if args.json:
        Path(args.json).write_text(json.dumps(summary, indent=1) + "\n")
    if args.report:
        from .store.environment_report import write_environment_report

        out = write_environment_report(args.report, monitor, table, days, records, summary, source=args.data)
        print(f"report: {out}")
    return 0


# ----------------------------------------------------------------------- parser
#: ``--lock-timeout`` of the commands that write a run store.
LOCK_TIMEOUT_OPTION = dict(type=float, default=None, metavar="SECONDS",
                           help="how long to wait while another update holds the run store's lock (which says who "
                                "holds it) before giving up; 0: do not wait, inf: no limit (default: "
                                "$SEQBAYES_LOCK_TIMEOUT, else 3600)")
def build_parser() -> argparse.ArgumentParser:
    from ._version import __version__

    parser = argparse.ArgumentParser(prog="seqbayes", description=DESCRIPTION,
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
    p.add_argument("run", help="run store, or a fleet: a folder of stores or a .toml/.json manifest")
    p.add_argument("datafiles", nargs="*", metavar="DATAFILE")
    p.add_argument("--replace-last", action="store_true",
                   help="roll back the last step and assimilate the (first) dataset in its place")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bars")
    p.add_argument("--accept-model-change", action="store_true",
                   help="run the likelihood module although its file changed since the run recorded it "
                        "(the new hash is recorded)")
    p.add_argument("--lock-timeout", **LOCK_TIMEOUT_OPTION)
    p.add_argument("--workers", type=int, metavar="N", help="fleet: workers of the local Dask cluster (default: the "
                   "cores); 0: the stores one after another in this process, without Dask")
    p.add_argument("--scheduler", metavar="ADDRESS", help="fleet: the Dask scheduler to run the stores' tasks on")
    p.add_argument("--json", metavar="FILE", help="fleet: also write the update's outcome here (JSON)")
    p.set_defaults(func=cmd_update)

    p = sub.add_parser("status", help="table of steps: posterior mean, sd, credible intervals, diagnostics")
    p.add_argument("run")
    p.add_argument("--level", type=float, default=0.95, help="credible level (default 0.95)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_status)

    p = sub.add_parser("predict", help="forecast the parameters K steps ahead")
    p.add_argument("run")
    p.add_argument("--steps", type=int, required=True, metavar="K")
    p.add_argument("--level", type=float, default=0.95)
    p.add_argument("--json", action="store_true")
    p.add_argument("--output", "-o", help="also write the forecast draws (.csv or .nc)")
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
    p.add_argument("--forecast", type=int, default=3, metavar="K", help="forecast horizon (default 3, 0: none)")
    p.add_argument("--level", type=float, default=0.95)
    p.add_argument("--no-embed", action="store_true", help="write PNG files next to the page instead of base64")
    p.add_argument("--threshold", action="append", metavar="EXPR",
                   help='add the time to a threshold, "NAME<VALUE" or "NAME>VALUE" (repeatable)')
    p.add_argument("--horizon", type=int, default=20, metavar="H",
                   help="steps ahead for the time to a threshold (default 20)")
    p.add_argument("--data", metavar="DATAFILE",
                   help="one of the assimilated datasets, for the data-versus-fit panel (needs [model] predict in "
                        "the configuration; default: the last one when the run keeps its datasets)")
    p.add_argument("--modes", metavar="CSV",
                   help="SG-EnMCMC runs: identified mode shapes for the MAC (one row per floor, bottom to top, one "
                        "column per mode; default: the shapes of the configured building at ratios 1)")
    p.set_defaults(func=cmd_report)

    p = sub.add_parser("environment", help="damage against temperature on a CSV of identified frequencies "
                                            "(day,temperature,f1,...,fn)")
    p.add_argument("data", help="CSV with the header day,temperature,f1,...,fn; one update per whole day")
    p.add_argument("--masses", required=True, help="floor masses [kg], bottom to top, comma-separated")
    p.add_argument("--stiffness", required=True, help="nominal storey stiffnesses [N/m], comma-separated")
    p.add_argument("--particles", type=int, default=128, help="particles per model (default 128)")
    p.add_argument("--threshold", type=float, default=0.95, help="alarm when P(damage) exceeds this ...")
    p.add_argument("--consecutive", type=int, default=2, help="... on this many days in a row")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--every", type=int, default=30,
                   help="print every this many days (and the days P(damage) or the alarm changes state)")
    p.add_argument("--json", help="write P(damage) per day, the alarms and the learned model here")
    p.add_argument("--report", metavar="HTML", help="write the year's report here: frequencies against temperature "
                                                    "with the learned law, P(damage) and the alarm, day by day")
    p.set_defaults(func=cmd_environment)

    p = sub.add_parser("example", help="run one of the papers' studies (no NAME: list them)", add_help=False)
    p.add_argument("name", nargs="?", help=f"one of: {', '.join(EXAMPLES)}")
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args, rest = parser.parse_known_args(argv)
    if args.command == "example":
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning
            return _run_example(args.name, rest)
    if rest:
        parser.error(f"unrecognized arguments: {' '.join(rest)}")
    from .store import ConfigError, DataError, StoreError

    from .store.datasets import printable

    try:
        with warnings.catch_warnings():
            warnings.showwarning = _show_warning   # restored on leaving: main() is also called from Python
            return int(args.func(args) or 0)
    except (CommandError, ConfigError, DataError, StoreError, ValueError, TypeError) as err:
        if args.traceback:
            raise
        # the line quotes file names and fields from files the user was handed: no raw control characters
        print(f"seqbayes {args.command}: error: {printable(err)}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # `seqbayes status RUN | head`: the reader has what it wanted
        import os

        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    except OSError as err:  # a read-only folder, a full disk, a path that is a folder, ...
        if args.traceback:
            raise
        where = f"{err.filename}: " if err.filename else ""
        print(f"seqbayes {args.command}: error: {printable(f'{where}{err.strerror or err}')}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
