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
import os
import sys
import warnings

from . import monitoring, runs
from .common import (MAX_FORECAST_STEPS, MAX_SIMULATED, NUMERIC, NUMPY_FLOAT, CommandError, Parser, numeric_summary,
                     show_warning)

__all__ = ["main", "build_parser", "list_examples", "CommandError", "EXAMPLES", "MAX_SIMULATED", "MAX_FORECAST_STEPS"]

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



def list_examples() -> str:
    """The ``seqbayes example`` listing: one line per study."""
    width = max(map(len, EXAMPLES))
    lines = ["usage: seqbayes example NAME [options]   (NAME --help for a study's options)", "", "examples:"]
    lines += [f"  {name:<{width}}  {line}" for name, (_, line) in EXAMPLES.items()]
    return "\n".join(lines)


def run_example(name: str | None, argv: list[str]) -> int:
    if name is None or name in ("-h", "--help"):
        print(list_examples())
        return 0
    if name not in EXAMPLES:
        print(f"seqbayes example: unknown example {name!r}; choose from {', '.join(EXAMPLES)} "
              f"(run 'seqbayes example' to list them)", file=sys.stderr)
        return 2
    module = importlib.import_module(EXAMPLES[name][0])
    return int(module.main(argv) or 0)


def build_parser() -> argparse.ArgumentParser:
    from .._version import __version__

    parser = Parser(prog="seqbayes", description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"seqbayes {__version__}")
    parser.add_argument("--traceback", action="store_true", help="show the full traceback on errors")
    sub = parser.add_subparsers(dest="command", required=True)

    runs.add_commands(sub)
    monitoring.add_commands(sub)

    p = sub.add_parser("example", help="run one of the papers' studies (no NAME: list them)", add_help=False)
    p.add_argument("name", nargs="?", help=f"one of: {', '.join(EXAMPLES)}")
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    args, rest = parser.parse_known_args(argv)
    if args.command != "example" and rest:
        parser.error(f"unrecognized arguments: {' '.join(rest)}")
    from ..store import ConfigError, DataError, StoreError
    from ..store.datasets import printable

    name = args.command if args.command != "example" else f"example {args.name or ''}".strip()
    outer, NUMERIC.messages = NUMERIC.messages, []
    numeric = NUMERIC.messages
    try:
        with warnings.catch_warnings():
            warnings.showwarning = show_warning   # restored on leaving: main() is also called from Python
            # every one of numpy's floating-point warnings reaches show_warning, to be counted (not only the first)
            warnings.filterwarnings("always", message=NUMPY_FLOAT.pattern, category=RuntimeWarning)
            if args.command == "example":
                code = run_example(args.name, rest)
            else:
                code = int(args.func(args) or 0)
        if numeric:
            print(f"seqbayes {name}: warning: {numeric_summary(numeric)}", file=sys.stderr)
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
        NUMERIC.messages = outer

