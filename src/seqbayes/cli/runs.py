"""The commands of one run store: ``init``, ``update``, ``status``, ``predict``, ``compare``, ``report``.

Every command opens the run through the store registry (:func:`seqbayes.store.open_run`) and asks its backend;
what a kind of run cannot do, its backend refuses (``BaseStore.require``) with a message naming the alternative.
"""

from __future__ import annotations

import argparse
import os
import sys
import warnings
from pathlib import Path

from .common import (FORCE_OPTION, LEVEL_OPTION, LOCK_TIMEOUT_OPTION, NUMERIC, CommandError, CountingLikelihood,
                     bounded, check_horizon, check_targets, is_numeric, json_text, progress_enabled, same_file,
                     store_inputs)


def cmd_init(args: argparse.Namespace) -> int:
    from ..store import create_run, load_config
    from ..store.datasets import printable
    from ..store.files import store_lock

    config = load_config(args.config)
    check_targets([], inputs=[args.config, getattr(config, "likelihood_file", None)], stores=(),
                   run=("RUN", args.run))
    with store_lock(args.run, create=True, timeout=args.lock_timeout):
        store = create_run(args.run, config, overwrite=args.force)
    print(f"created {printable(store.describe())}")
    return 0


def cmd_update(args: argparse.Namespace) -> int:
    from tqdm.auto import tqdm

    from ..store import BoundWarning, open_run
    from ..store.datasets import printable
    from ..store.files import store_lock

    if fleet_given(args, "update"):   # a folder of stores or a manifest: one task per store (docs/fleet.md)
        from ..fleet import update_command

        return update_command(args.run, workers=args.workers, scheduler=args.scheduler, json_path=args.json,
                              lock_timeout=args.lock_timeout, accept_model_change=args.accept_model_change,
                              force=args.force)
    show = progress_enabled() and not args.quiet
    with store_lock(args.run, timeout=args.lock_timeout):
        store = open_run(args.run)
        if args.replace_last:
            store.require("replace_last")
        for path in args.datafiles:
            if same_file(path, args.run):
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
                        loglike = (CountingLikelihood(store.load_likelihood(args.accept_model_change), bar)
                                   if not bar.disable else None)
                        info = store.assimilate(table, Path(path).name, replace_last=args.replace_last,
                                                executor=executor, loglike=loglike,
                                                accept_model_change=args.accept_model_change)
                    except (KeyboardInterrupt, SystemExit):
                        raise
                    except Exception as err:
                        raise CommandError(f"{path}: {describe_failure(err, store, done)}") from err
                done.append(f"{Path(path).name} (step {store.n_steps})")
                tqdm.write(printable(f"{args.run}: {store.step_summary(info, Path(path).name)}"), file=sys.stdout)
                for warning in caught:  # one line each (BoundWarning says what it is in its text)
                    if NUMERIC.messages is not None and is_numeric(warning.message, warning.category):
                        NUMERIC.messages.append(str(warning.message))   # counted, said once at the end
                        continue
                    kind = "" if issubclass(warning.category, BoundWarning) else f"{warning.category.__name__}: "
                    print(f"seqbayes update: warning: {kind}{printable(warning.message)}", file=sys.stderr)
                args.replace_last = False
        finally:
            close()
    return 0


def describe_failure(err, store, done=()) -> str:
    """One line for an update that failed, saying what the run store holds now (shared with the fleet)."""
    from ..fleet import describe_failure as describe

    return describe(err, store, done)


def fleet_given(args, command) -> bool:
    """Whether RUN is a fleet (a folder or a .toml/.json manifest); refuses the options of the other form."""
    from ..fleet import is_fleet

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
    from ..store import open_run

    if fleet_given(args, "status"):
        from ..fleet import status_command

        return status_command(args.run, as_json=args.json)
    store = open_run(args.run)
    if args.json:
        print(json_text(store.status_json(args.level)))
    else:
        print(store.status(args.level))
    return 0


def cmd_predict(args: argparse.Namespace) -> int:
    from ..prognostics import parse_threshold
    from ..store import open_run
    from ..store.report import first_passage_json, forecast_rows, format_first_passage, format_forecast
    from ..store.targets import forecast_file

    store = open_run(args.run)
    store.require("predict")
    if store.n_steps == 0:
        raise CommandError(f"{args.run}: no dataset assimilated yet; nothing to forecast from")
    if args.steps < 1:
        raise CommandError(f"--steps: must be >= 1, got {args.steps}")
    check_horizon("--steps", args.steps, store.config.n_samples)
    if args.output and Path(args.output).is_dir():
        raise CommandError(f"{args.output}: is a folder; give the forecast's file name, e.g. "
                           f"{Path(args.output) / 'forecast.csv'}")
    check_targets([("--output", args.output, forecast_file(store.names))], inputs=store_inputs(store),
                   stores=[args.run], force=args.force)
    thresholds = [parse_threshold(text, store.names) for text in args.threshold or ()]
    draws = store.predict(args.steps)
    rows = forecast_rows(store, args.steps, args.level, draws)
    passages = [(t, store.time_to_threshold(t.name, t.value, args.steps, direction=t.direction))
                for t in thresholds]
    if args.output:
        write_forecast(Path(args.output), store, draws)
    if args.json:
        if passages:  # with thresholds the output is an object; without, the forecast rows as before
            print(json_text({"forecast": rows, "thresholds": [first_passage_json(store, t, p) for t, p in passages]}))
        else:
            print(json_text(rows))
    else:
        print(f"forecast from step {store.n_steps} of {args.run} ({store.config.name!r}), {draws.shape[1]} draws")
        print(format_forecast(rows, args.level))
        for threshold, passage in passages:
            print()
            print(format_first_passage(store, threshold, passage))
    return 0


def write_forecast(path, store, draws):
    """The forecast draws as CSV or NetCDF, built in memory and written atomically (:mod:`seqbayes.store.targets`)."""
    import io

    import numpy as np
    import xarray as xr

    from ..store.files import netcdf_bytes
    from ..store.targets import write_output

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




def open_for_comparison(paths, first=None):
    """The runs of ``paths`` (``first``: the first one, already open), their display names and the number
    of steps they share; each must be a run kind that compares by evidence."""
    from ..store import open_run

    stores = []
    for i, path in enumerate(paths):
        store = first if i == 0 and first is not None else open_run(path)
        store.require("compare")
        stores.append(store)
    from ..store.datasets import printable

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
    from ..selection import compare
    from ..store.report import comparison_rows

    stores, names, n_common = open_for_comparison(args.runs)
    comparison = compare({n: s.result.log_evidence[:n_common] for n, s in zip(names, stores)})
    if args.json:
        print(json_text({"steps": n_common, "best": comparison.best, "rows": comparison_rows(comparison)}))
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
    from ..prognostics import parse_threshold
    from ..store import open_run
    from ..store.targets import html_page, png_figure

    store = open_run(args.run)
    store.require(*[f"report --{name}" for name in ("compare", "threshold", "data") if getattr(args, name)])
    others = []
    if args.compare:
        stores, _, _ = open_for_comparison([args.run, *args.compare], first=store)
        others = stores[1:]
    n_samples = getattr(store.config, "n_samples", None) or store.config.n_members   # SG-EnMCMC: n_members
    for option, steps in (("--forecast", args.forecast), ("--horizon", args.horizon if args.threshold else 0)):
        if steps < 0 or (option == "--horizon" and args.threshold and steps < 1):
            raise CommandError(f"{option}: must be >= {0 if option == '--forecast' else 1}, got {steps}")
        check_horizon(option, steps, n_samples)
    output = Path(args.output) if args.output else Path(args.run).with_suffix(".html")
    if output.is_dir():
        raise CommandError(f"{output}: is a folder; give the report's file name, e.g. {output / 'report.html'}")
    figures = output.parent / f"{output.stem}_figures"          # --no-embed: the PNG files of the page
    if args.no_embed and os.path.lexists(figures) and not figures.is_dir():
        raise CommandError(f"{figures}: is not a folder; the report's figures go there (--no-embed)")
    old_figures = sorted(figures.glob("fig-*.png")) if args.no_embed and figures.is_dir() else []
    check_targets([("--output", output, html_page, True), *[("--no-embed", f, png_figure) for f in old_figures]],
                   inputs=[args.data, args.modes, *store_inputs(store)], stores=[args.run, *(args.compare or ())],
                   force=args.force)
    try:
        thresholds = [parse_threshold(text, store.names) for text in args.threshold or ()]
        store.write_report(output, level=args.level, embed=not args.no_embed, others=others,
                           forecast_steps=args.forecast, thresholds=thresholds, horizon=args.horizon,
                           fit_data=assimilated_dataset(store, args.data) if args.data else None, modes=args.modes)
    except ValueError as err:
        raise CommandError(str(err)) from err
    print(f"report written to {output}")
    return 0


def assimilated_dataset(store, path) -> tuple:
    """``(step index, table)`` of a data file the run assimilated (found by its content's hash)."""
    from ..store.datasets import dataset_digest

    if store.config.predict is None:
        raise CommandError(f"--data: {store.path}'s configuration names no [model] predict function, so there is no "
                           f"fit to draw")
    table = store.read_datafile(path)
    digest = dataset_digest(table, store.config.columns)
    if digest not in store.digests:
        raise CommandError(f"--data: {path} was not assimilated by {store.path} (its steps: "
                           f"{', '.join(store.sources)})")
    return store.digests.index(digest), table




def add_commands(sub) -> None:
    """Register this module's commands on the ``seqbayes`` subparsers."""
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
    p.add_argument("--workers", type=bounded(int, 0, 256), metavar="N",
                   help="fleet: workers of the local Dask cluster (default: the cores); 0: the stores one after "
                        "another in this process, without Dask")
    p.add_argument("--scheduler", metavar="ADDRESS", help="fleet: the Dask scheduler to run the stores' tasks on")
    p.add_argument("--json", metavar="FILE", help="fleet: also write the update's outcome here (JSON)")
    p.add_argument("--force", **FORCE_OPTION)
    p.set_defaults(func=cmd_update)

    p = sub.add_parser("status", help="table of steps: posterior mean, sd, credible intervals, diagnostics")
    p.add_argument("run")
    p.add_argument("--level", **LEVEL_OPTION, help="credible level (default 0.95)")
    p.add_argument("--json", action="store_true", help="machine-readable output")
    p.set_defaults(func=cmd_status)

    p = sub.add_parser("predict", help="forecast the parameters K steps ahead")
    p.add_argument("run")
    p.add_argument("--steps", type=bounded(int, 1), required=True, metavar="K")
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
    p.add_argument("--forecast", type=bounded(int, 0), default=3, metavar="K",
                   help="forecast horizon (default 3, 0: none)")
    p.add_argument("--level", **LEVEL_OPTION)
    p.add_argument("--no-embed", action="store_true", help="write PNG files next to the page instead of base64")
    p.add_argument("--threshold", action="append", metavar="EXPR",
                   help='add the time to a threshold, "NAME<VALUE" or "NAME>VALUE" (repeatable)')
    p.add_argument("--horizon", type=bounded(int, 1), default=20, metavar="H",
                   help="steps ahead for the time to a threshold (default 20)")
    p.add_argument("--data", metavar="DATAFILE",
                   help="one of the assimilated datasets, for the data-versus-fit panel (needs [model] predict in "
                        "the configuration; default: the last one when the run keeps its datasets)")
    p.add_argument("--modes", metavar="CSV",
                   help="SG-EnMCMC runs: identified mode shapes for the MAC (one row per floor, bottom to top, one "
                        "column per mode; default: the shapes of the configured building at ratios 1)")
    p.add_argument("--force", **FORCE_OPTION)
    p.set_defaults(func=cmd_report)
