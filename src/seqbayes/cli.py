"""The ``seqbayes`` command line.

Paper studies live in :mod:`seqbayes.studies`; each module there has a
``main(argv) -> int`` and is reached as ``seqbayes example NAME [options]``.
"""

from __future__ import annotations

import argparse
import importlib
import sys

#: name -> module with ``main(argv)``; each study module parses its own options.
EXAMPLES = {
    "quickstart": "seqbayes.studies.quickstart",
    "coulomb": "seqbayes.studies.coulomb",
    "oscillator": "seqbayes.studies.oscillator",
    "acceptance": "seqbayes.studies.acceptance",
    "resampling": "seqbayes.studies.resampling_illustration",
    "shake-table": "seqbayes.studies.shake_table",
}


def _run_example(name: str, argv: list[str]) -> int:
    if name not in EXAMPLES:
        print(f"seqbayes example: unknown example {name!r}; choose from {', '.join(sorted(EXAMPLES))}",
              file=sys.stderr)
        return 2
    module = importlib.import_module(EXAMPLES[name])
    return int(module.main(argv) or 0)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = argparse.ArgumentParser(prog="seqbayes", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    example = sub.add_parser("example", help="run one of the papers' studies", add_help=False)
    example.add_argument("name", help=f"one of: {', '.join(sorted(EXAMPLES))}")
    args, rest = parser.parse_known_args(argv)
    if args.command == "example":
        return _run_example(args.name, rest)
    parser.error(f"unknown command {args.command!r}")
    return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
