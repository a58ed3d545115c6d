"""The monitor's cost and verdict on simulated years of 24 sets a day (issue 40 "Cost"), through
:func:`seqbayes.structural.monitor.table.monitor_table` (the matrix's entry point).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_monitor_cost.py [--particles 128 256] [--days 365]

The years are :func:`seqbayes.studies.environment.simulate_year`'s with the issue's misspecifications of the first
monitor: a 6 h thermal lag of the structure behind the air temperature the CSV gives, a healthy year and one with
a 5 % loss of storey 3 from day 300 (the first monitor alarmed on day 3 and day 6 of these). Printed per year and
particle count: the process CPU time (independent of the machine's load, which is printed too), the first alarm,
the located element, the size and day intervals at the alarm, the learned thermal lag, and the work (filter
updates per particle per day: 1 for a day without moves).
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np

from seqbayes.structural.monitor.model import MonitorSettings
from seqbayes.structural.monitor.table import monitor_table, verdicts
from seqbayes.structural.structures import ShearBuilding
from seqbayes.studies.environment import MASSES, STIFFNESSES, ThermalLaw, simulate_year

YEARS = {"healthy, 6 h lag": dict(law=ThermalLaw(thermal_lag_hours=6.0)),
         "5 % loss storey 3 day 300, 6 h lag": dict(law=ThermalLaw(thermal_lag_hours=6.0), damage_day=300.0, damage_storey=3,
                                                    damage_size=0.05)}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--particles", type=int, nargs="+", default=[128, 256])
    parser.add_argument("--days", type=int, default=365)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args(argv)
    building = ShearBuilding(MASSES, STIFFNESSES)
    print("| year | N | CPU-s | first alarm | element | loss [95 %] | first day [95 %] | lag h | updates/particle/day |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, options in YEARS.items():
        table, _ = simulate_year(np.random.default_rng(args.seed), n_days=args.days, **options)
        for n in args.particles:
            cpu = time.process_time()
            days = monitor_table(table, building, args.seed, MonitorSettings(n_particles=n))
            cpu = time.process_time() - cpu
            v = verdicts(days)
            alarm = np.flatnonzero(v["alarm"])
            at = int(alarm[0]) if alarm.size else None
            size = f"{100 * v['size'][at, 0]:.2f} [{100 * v['size'][at, 1]:.2f}, {100 * v['size'][at, 2]:.2f}]" \
                if at is not None else "-"
            onset = f"{v['onset'][at, 0]:.1f} [{v['onset'][at, 1]:.0f}, {v['onset'][at, 2]:.0f}]" if at is not None else "-"
            lag = days[-1].environment.static["thermal_lag_h"]
            work = np.mean([d.filter_updates for d in days]) / n
            print(f"| {name} | {n} | {cpu:.1f} | {v['day'][at] if at is not None else 'none'} | "
                  f"{v['element'][at] if at is not None else '-'} | {size} | {onset} | "
                  f"{lag.mean:.2f} [{lag.lower:.2f}, {lag.upper:.2f}] | {work:.1f} |", flush=True)
    print(f"({os.getloadavg()[0]:.1f} load average on {os.cpu_count()} cores)")


if __name__ == "__main__":
    main()
