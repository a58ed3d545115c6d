"""The monitoring commands beside the run store: ``environment`` (a year of identified frequencies), ``oma``
(modes from an ambient record) and ``track`` (poles of many records into modal datasets)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from .common import (FORCE_OPTION, MAX_PARTICLES, NUMERIC, CommandError, bounded, check_targets, numeric_summary,
                     range_option)


#: Text appended to the messages of the year CSV's checks: the options that change each rule.
ENVIRONMENT_HINTS = {"day": " (days since the first monitored day; --max-day sets the upper bound)",
                     "temperature": " (degC; --temperature-range LOW,HIGH sets the bounds)",
                     "frequency": " (Hz; --frequency-range LOW,HIGH sets the bounds)",
                     "extra": "; name the columns to read with --columns DAY,TEMPERATURE,F1,...,Fn",
                     "header": "; or name the file's columns with --columns DAY,TEMPERATURE,F1,...,Fn",
                     "ascending": " (mode 1 is the lowest; check the column order)"}
def _numbers(text, name):
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise CommandError(f"{name}: expected comma-separated numbers, got {text!r}") from None
    if not all(0 < v < float("inf") for v in values):
        raise CommandError(f"{name}: expected positive finite numbers, got {text!r}")
    return values


def _environment_config(args):
    """The monitor configuration of the replay: a shear building (--masses, --stiffness) or the mode-level
    model (--frequencies)."""
    from ..store.monitor_config import MonitorRunConfig

    if args.frequencies is not None:
        if args.masses or args.stiffness:
            raise CommandError("--frequencies: give either --frequencies (no structural model) or --masses and "
                               "--stiffness (a shear building), not both")
        frequencies = _numbers(args.frequencies, "--frequencies")
        if any(b <= a for a, b in zip(frequencies, frequencies[1:])):
            raise CommandError(f"--frequencies: expected increasing frequencies (mode 1 lowest), got {args.frequencies!r}")
        return MonitorRunConfig("environment", "modes", frequencies=tuple(frequencies), n_particles=args.particles,
                                seed=args.seed, threshold=args.threshold, consecutive=args.consecutive)
    if not args.masses or not args.stiffness:
        raise CommandError("--masses, --stiffness: the shear building's floor masses and storey stiffnesses are "
                           "needed (or --frequencies for the mode-level model without a structure)")
    masses, stiffness = _numbers(args.masses, "--masses"), _numbers(args.stiffness, "--stiffness")
    if len(stiffness) != len(masses):
        raise CommandError(f"--stiffness: expected {len(masses)} values (one per storey, as --masses), got "
                           f"{len(stiffness)}")
    return MonitorRunConfig("environment", "shear_building", masses=tuple(masses), stiffnesses=tuple(stiffness),
                            n_particles=args.particles, seed=args.seed, threshold=args.threshold,
                            consecutive=args.consecutive)


def cmd_environment(args: argparse.Namespace) -> int:
    """A year CSV of identified frequencies replayed day by day through a monitor run store (docs/environment.md):
    a temporary store, or ``--store`` (created, kept)."""
    import dataclasses
    from pathlib import Path

    import numpy as np

    from ..store.datasets import read_datafile
    from ..store.monitor import MonitorRunStore, check_memory
    from ..store.targets import html_page, json_with_keys, write_output
    from ..studies.environment import check_against_building, year_spec

    config = _environment_config(args)
    n = config.n_modes
    stores = [args.store] if args.store else []
    targets = check_targets([("--json", args.json, json_with_keys("alarm_day", "p_damage", "environment")),
                              ("--report", args.report, html_page)], inputs=[args.data], stores=stores,
                             force=args.force, run=("--store", args.store) if args.store else None)
    columns = None if args.columns is None else [c.strip() for c in args.columns.split(",")]
    if columns is not None and len(columns) != n + 2:
        what = f"for a {n}-storey building" if config.model == "shear_building" else f"of the {n} modes"
        raise CommandError(f"--columns: expected {n + 2} names (time, temperature and {n} frequencies {what}), got "
                           f"{len(columns)}")
    spec = year_spec(n, columns=columns, day_range=(0.0, args.max_day), temperature_range=args.temperature_range,
                     frequency_range=args.frequency_range, hints=ENVIRONMENT_HINTS)
    spec = dataclasses.replace(spec, missing=spec.columns[2:])          # an empty cell: a mode not identified
    values = read_datafile(args.data, spec)
    calendar = np.floor(values[:, 0]).astype(int)
    check_memory(args.particles, n, np.unique(calendar).size)
    if config.model == "shear_building":
        from ..structural.structures import ShearBuilding

        frequencies = values[:, 2:]
        check_against_building(args.data, ShearBuilding(list(config.masses), list(config.stiffnesses)),
                               {f"f{r + 1}": frequencies[np.isfinite(frequencies[:, r]), r] for r in range(n)},
                               spec.columns[2:])
    path = Path(args.store) if args.store else None
    store = (MonitorRunStore.create(path, config, overwrite=bool(args.force)) if path is not None
             else MonitorRunStore.in_memory(config))
    table = np.full((values.shape[0], len(config.columns)), np.nan)
    table[:, :values.shape[1]] = values
    infos = []
    name = Path(args.data).name
    print(f"{'day':>5} {'P(damage)':>10} {'where':>6} {'loss %':>16} {'first day':>14}")
    previous = None
    for d in np.unique(calendar):
        info = store.assimilate(table[calendar == d], f"{name} day {d}", write=False)
        infos.append(info)
        above = info["p_damage"] > args.threshold
        changed = previous is not None and (above != (previous["p_damage"] > args.threshold)
                                            or info["alarm"] != previous["alarm"])
        previous = info
        if d % args.every == 0 or changed or d == calendar[-1]:
            damage = info["damage"]
            likely = info["p_damage"] > 0.5 and damage["size"] is not None
            where = (damage["location"] or ",".join(str(i + 1) for i, p in enumerate(damage["class_probabilities"])
                                                    if p > 0.5)) if likely else "-"
            loss = (f"{100 * damage['size']['mean']:.2f} [{100 * damage['size']['lower']:.2f}, "
                    f"{100 * damage['size']['upper']:.2f}]") if likely else "-"
            first = (f"{damage['day']['mean']:.1f} [{damage['day']['lower']:.0f}, {damage['day']['upper']:.0f}]"
                     if likely else "-")
            print(f"{d:>5} {info['p_damage']:>10.3g} {where or '-':>6} {loss:>16} {first:>14}"
                  f"{'  ALARM' if info['alarm'] else ''}")
    if path is not None:
        store.write()
    alarms = [i["day"] for i in infos if i["alarm"]]
    first_alarm = alarms[0] if alarms else None
    at = infos[[i["day"] for i in infos].index(first_alarm)] if alarms else infos[-1]
    environment = infos[-1]["environment"]
    coefficients = ", ".join(f"{e['mean']:.3e}" for k, e in environment["coefficients"].items()
                             if k.startswith("temperature_"))
    lag = environment["static"]["thermal_lag_h"]
    print(f"alarm day: {first_alarm}, {'element' if config.model == 'shear_building' else 'modes'}: "
          f"{at['damage']['location'] if alarms else None}; learned: thermal lag {lag['mean']:.3g} h "
          f"[{lag['lower']:.3g}, {lag['upper']:.3g}], temperature coefficients {coefficients} per degC")
    if args.store:
        print(f"run store: {path} ({store.n_steps} days; seqbayes status / update / report take it)")
    if "--json" in targets:
        summary = {"alarm_day": first_alarm, "alarm_days": alarms,
                   "element": at["damage"]["location"] if alarms else None,
                   "days": [i["day"] for i in infos], "p_damage": [i["p_damage"] for i in infos],
                   "environment": environment, "store": str(path) if args.store else None,
                   "daily": [{k: v for k, v in i.items() if k != "environment"} for i in infos]}
        write_output(targets["--json"], json.dumps(summary, indent=1) + "\n", "--json")
    if "--report" in targets:
        store.write_report(targets["--report"])
        print(f"report: {targets['--report']}")
    return 0


def cmd_oma(args: argparse.Namespace) -> int:
    """Operational modal analysis of one ambient record: modes with standard errors (docs/oma.md).

    Exit status 0 with modes, 1 when no mode was identified (after the line saying why), 2 on a bad record
    or option. The outputs are checked before the record is read and written atomically."""
    from ..store.modal_files import read_record
    from ..store.targets import json_with_keys, png_figure, starts_with, write_output
    from ..structural.oma import ssi_cov
    from ..structural.oma.core import check_sampling_step
    from ..structural.oma.io import diagram_png, modes_csv, modes_json, parse_band, summary_lines

    targets = check_targets([("--out", args.out, starts_with(b"time_start,day,slot,")),
                             ("--json", args.json, json_with_keys("settings", "modes", "candidates_hz")),
                             ("--diagram", args.diagram, png_figure)], inputs=[args.record], force=args.force)
    dt = check_sampling_step(1.0 / args.fs if args.fs is not None else args.dt)
    band = parse_band(args.band)
    y, channels, dt_time = read_record(args.record)
    if dt_time is not None and abs(dt_time - dt) > 1e-3 * dt:
        raise CommandError(f"--dt/--fs: the record's time column steps by {dt_time:g} s ({1 / dt_time:.6g} Hz), not "
                           f"the {dt:g} s ({1 / dt:.6g} Hz) given: a wrong sampling rate")
    modes = ssi_cov(y, dt, band=band)
    print("\n".join(summary_lines(Path(args.record).name, y.shape, dt, modes)))
    day = float("nan") if args.day is None else float(args.day)
    for option, label, content in (("--out", "modes", lambda: modes_csv(modes, channels, day)),
                                   ("--json", "json", lambda: modes_json(modes, channels, day, args.record)),
                                   ("--diagram", "diagram", lambda: diagram_png(modes))):
        if option in targets:
            write_output(targets[option], content(), option)
            print(f"{label}: {targets[option]}")
    return 1 if modes.status == "empty" else 0


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
        if not all(0 < f < float("inf") for f in frequencies):
            raise CommandError(f"--reference: expected positive finite frequencies [Hz], got {args.reference!r}")
    settings = TrackerSettings(gate=args.gate, initial_days=args.initial_days, min_presence=args.min_presence)
    print(track_to_folder(args.poles, args.out, covariates_path=args.temperature, prefix=args.prefix,
                          settings=settings, frequencies=frequencies, force=args.force))
    return 0


def add_commands(sub) -> None:
    """Register this module's commands on the ``seqbayes`` subparsers."""
    from ..studies.environment import DAY_RANGE, FREQUENCY_RANGE, TEMPERATURE_RANGE

    p = sub.add_parser("environment", help="damage under a learned environment: a CSV of identified frequencies "
                                            "(day,temperature,f1,...,fn) replayed day by day through a monitor run "
                                            "store")
    p.add_argument("data", help="CSV with the header day,temperature,f1,...,fn (an empty cell: a mode not identified "
                                "in that set); one update per whole day")
    p.add_argument("--masses", help="floor masses [kg], bottom to top, comma-separated (a shear building)")
    p.add_argument("--stiffness", help="nominal storey stiffnesses [N/m], comma-separated")
    p.add_argument("--frequencies", metavar="F1,F2,...",
                   help="no structural model: each mode's reference frequency [Hz] (a loss is a lasting drop of "
                        "modes, not located)")
    p.add_argument("--store", metavar="NC", help="keep the monitor run store here (default: a temporary one); "
                                                 "seqbayes update continues it day by day")
    p.add_argument("--particles", type=bounded(int, 10, MAX_PARTICLES), default=128,
                   help="particles over the environmental law's static parameters (default 128)")
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
    rate.add_argument("--dt", type=bounded(float, 0, open_low=True), help="sampling step [s]")
    rate.add_argument("--fs", type=bounded(float, 0, open_low=True), help="sampling rate [Hz]")
    p.add_argument("--band", metavar="LO,HI", help="frequencies sought [Hz] (default: derived from the spectrum)")
    p.add_argument("--out", metavar="CSV", help="write the modes table here (docs/oma.md: the mast poles' columns "
                                                "and phi_<channel>, std_phi_<channel>)")
    p.add_argument("--json", metavar="JSON", help="write the modes, the settings chosen and the messages here")
    p.add_argument("--diagram", metavar="PNG", help="draw the stabilisation diagram here")
    p.add_argument("--day", type=bounded(float, 0, 1e8), help="the record's start in days (the table's day column)")
    p.add_argument("--force", **FORCE_OPTION)
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
    p.add_argument("--force", **FORCE_OPTION)
    p.set_defaults(func=cmd_track)
