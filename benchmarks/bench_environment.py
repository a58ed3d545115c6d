"""A year of monitoring under temperature (issue 25): simulate years, run the workflow on them.

Simulate (the files of docs/environment.md)::

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_environment.py simulate --out DIR --years 20 --seed 0

writes ``damaged_00.csv`` ... (5 % loss of a random storey from the start of a random day in
183..350) and ``healthy_00.csv`` ..., each with a ``.json`` truth sidecar
(:func:`seqbayes.studies.environment.simulate_years`).
"""

from __future__ import annotations

import argparse
import sys

from seqbayes.studies.environment import simulate_years


def simulate_main(argv) -> None:
    parser = argparse.ArgumentParser(prog="bench_environment.py simulate", description="Write simulated years.")
    parser.add_argument("--out", required=True, help="output directory")
    parser.add_argument("--years", type=int, default=20, help="number of years (half damaged, half healthy)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--damage-size", type=float, default=0.05)
    args = parser.parse_args(argv)
    for path in simulate_years(args.out, args.years, args.seed, damage_size=args.damage_size):
        print(path)


if __name__ == "__main__":
    if sys.argv[1:2] == ["simulate"]:
        simulate_main(sys.argv[2:])
