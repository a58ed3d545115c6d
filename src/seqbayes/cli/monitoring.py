"""The monitoring commands beside the run store: ``environment`` (a year of identified frequencies), ``oma``
(modes from an ambient record) and ``track`` (poles of many records into modal datasets)."""

from __future__ import annotations

import argparse
import json

from .common import (FORCE_OPTION, MAX_PARTICLES, NUMERIC, CommandError, bounded, check_targets, numeric_summary,
                     range_option)


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

    from ..store.datasets import read_datafile
    from ..store.environment_report import write_environment_report
    from ..store.targets import html_page, json_with_keys, write_output
    from ..structural.environment import monitor_year
    from ..structural.structures import ShearBuilding
    from ..studies.environment import check_against_building, check_days, check_memory, year_spec

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
    targets = check_targets([("--json", args.json, json_with_keys("alarm_day", "p_damage", "environment")),
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
    start = len(NUMERIC.messages) if NUMERIC.messages is not None else 0
    summary, monitor, days, records = monitor_year(building, table, rng=np.random.default_rng(args.seed),
                                                   n_particles=args.particles, threshold=args.threshold,
                                                   consecutive=args.consecutive)
    numeric = (NUMERIC.messages or [])[start:]
    check_days(args.data, days, records, numeric_summary(numeric).split(" (numpy")[0] if numeric else "")
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
    from ..structural.oma.io import run

    return run(args.record, dt=args.dt, fs=args.fs, band=args.band, out=args.out, json_path=args.json,
               diagram=args.diagram, day=args.day)
def cmd_track(args: argparse.Namespace) -> int:
    """Poles of many records tracked into one modal dataset per record (docs/modal.md)."""
    from ..store.modal_files import track_to_folder
    from ..structural.tracking import TrackerSettings

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




def add_commands(sub) -> None:
    """Register this module's commands on the ``seqbayes`` subparsers."""
    from ..studies.environment import DAY_RANGE, FREQUENCY_RANGE, TEMPERATURE_RANGE

    p = sub.add_parser("environment", help="damage against temperature on a CSV of identified frequencies "
                                            "(day,temperature,f1,...,fn)")
    p.add_argument("data", help="CSV with the header day,temperature,f1,...,fn; one update per whole day")
    p.add_argument("--masses", required=True, help="floor masses [kg], bottom to top, comma-separated")
    p.add_argument("--stiffness", required=True, help="nominal storey stiffnesses [N/m], comma-separated")
    p.add_argument("--particles", type=bounded(int, 10, MAX_PARTICLES), default=128,
                   help="particles per model (default 128)")
    p.add_argument("--threshold", type=bounded(float, 0, 1, open_low=True, open_high=True), default=0.95,
                   help="alarm when P(damage) exceeds this ...")
    p.add_argument("--consecutive", type=bounded(int, 1, 100_000), default=2, help="... on this many days in a row")
    p.add_argument("--seed", type=bounded(int, 0, 2 ** 63 - 1), default=0)
    p.add_argument("--every", type=bounded(int, 1, 10 ** 9), default=30,
                   help="print every this many days (and the days P(damage) or the alarm changes state)")
    p.add_argument("--columns", metavar="NAMES",
                   help="the file's columns to read, comma-separated: time [days], temperature [degC] and the n "
                        "frequencies [Hz], ascending (default: the header day,temperature,f1,...,fn, and no other "
                        "column; with --columns other columns are ignored)")
    p.add_argument("--max-day", type=bounded(float, 0, 1e8, open_low=True), default=DAY_RANGE[1], metavar="DAYS",
                   help=f"latest day accepted (default {DAY_RANGE[1]:g}: 100 years); days start at 0 and must "
                        f"increase from row to row")
    p.add_argument("--temperature-range", type=range_option(-1e4, 1e4), default=TEMPERATURE_RANGE,
                   metavar="LOW,HIGH", help=f"temperatures accepted [degC] (default {TEMPERATURE_RANGE[0]:g},"
                                            f"{TEMPERATURE_RANGE[1]:g})")
    p.add_argument("--frequency-range", type=range_option(1e-9, 1e9), default=FREQUENCY_RANGE, metavar="LOW,HIGH",
                   help=f"frequencies accepted [Hz] (default {FREQUENCY_RANGE[0]:g},{FREQUENCY_RANGE[1]:g})")
    p.add_argument("--json", help="write P(damage) per day, the alarms and the learned model here")
    p.add_argument("--report", metavar="HTML", help="write the year's report here: frequencies against temperature "
                                                    "with the learned law, P(damage) and the alarm, day by day")
    p.add_argument("--force", **FORCE_OPTION)
    p.set_defaults(func=cmd_environment)

    p = sub.add_parser("oma", help="modes with standard errors from an ambient record (automated SSI-cov)")
    p.add_argument("record", help="CSV (header of channel names, optional time column) or .npy array (T, p)")
    rate = p.add_mutually_exclusive_group(required=True)
    rate.add_argument("--dt", type=bounded(float), help="sampling step [s]")
    rate.add_argument("--fs", type=bounded(float), help="sampling rate [Hz]")
    p.add_argument("--band", metavar="LO,HI", help="frequencies sought [Hz] (default: derived from the spectrum)")
    p.add_argument("--out", metavar="CSV", help="write the modes table here (docs/oma.md: the mast poles' columns "
                                                "and phi_<channel>, std_phi_<channel>)")
    p.add_argument("--json", metavar="JSON", help="write the modes, the settings chosen and the messages here")
    p.add_argument("--diagram", metavar="PNG", help="draw the stabilisation diagram here")
    p.add_argument("--day", type=bounded(float, 0, 1e8), help="the record's start in days (the table's day column)")
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
    p.add_argument("--initial-days", type=bounded(float, 0, 1e4, open_low=True), default=3.0, help="days the modes and their noise are found in (3)")
    p.add_argument("--gate", type=bounded(float, 0, 100, open_low=True), default=3.5, help="a pole joins a mode within this many sds (3.5)")
    p.add_argument("--min-presence", type=bounded(float, 0, 1, open_low=True), default=0.25,
                   help="a mode must be seen in this share of the first days' records (0.25)")
    p.set_defaults(func=cmd_track)
