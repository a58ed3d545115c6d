"""The real guyed mast's three weeks through a monitor run store, day by day, with the mode-level model (issue 40).

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_monitor_mast.py [--days 21] [--particles 256] [--seed 0]

``seqbayes track`` of the bundled poles (``seqbayes/data/guyed_mast``, Marwitz, Bauhaus-Universitat Weimar, MIT
licence; PROVENANCE.md beside them) with the Pt100 temperatures writes one tracked modes table per hourly record;
the records of each calendar day are joined into one day's dataset (``day, mode, frequency_hz, temperature``: the
mean of the sensors that gave a value; records without any temperature are left out and counted). A monitor run
(``[monitor] model = "modes"``, the tracked modes' reference frequencies: the median of each mode over the first
three days) is created with ``seqbayes init`` and updated with ``seqbayes update`` once per day. Printed: each
day's P(damage) and alarm state, the CPU time, and each mode's learned temperature coefficient (d ln f / dT,
per degC, given no damage) with its 95 % interval, the thermal lag and the discrepancy's scale (docs/environment.md,
"The guyed mast").

The OMA's ``std_frequency_hz`` are left out: on the mast they are about 50 times the record-to-record scatter of
the tracked frequencies (mode 1: 0.047 Hz against 0.0009 Hz; docs/modal.md found the same), so the set noise is
learned per mode instead.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import os
import tempfile
import time
from importlib import resources
from pathlib import Path

import numpy as np

from seqbayes import cli

MAST = resources.files("seqbayes") / "data" / "guyed_mast"


def _load():
    try:
        return f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    except OSError:
        return "load unknown"


def _quiet(argv):
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        code = cli.main([str(a) for a in argv])
    if code != 0:
        raise SystemExit(f"seqbayes {' '.join(map(str, argv))} failed ({code}):\n{out.getvalue()}")
    return out.getvalue()


def day_datasets(folder: Path, n_days: int) -> tuple[list, np.ndarray, int]:
    """Track the mast, join each day's records: (day files, reference frequencies, records left out)."""
    with resources.as_file(MAST / "poles_60min.csv") as poles, resources.as_file(MAST / "temperature_60min.csv") as temp:
        _quiet(["track", poles, "--temperature", temp, "--out", folder / "tracked"])
    rows, dropped = [], 0
    for path in sorted((folder / "tracked").glob("record_*.csv")):
        lines = path.read_text().splitlines()
        header = lines[0].split(",")
        at = {name: header.index(name) for name in ("day", "mode", "frequency_hz", "temperature")}
        for line in lines[1:]:
            cells = line.split(",")
            values = [cells[at[name]] for name in ("day", "mode", "frequency_hz", "temperature")]
            if not values[3].strip() or values[3].strip().lower() == "nan":
                dropped += 1
                continue
            rows.append([float(v) for v in values])
    table = np.array(rows)
    calendar = np.floor(table[:, 0]).astype(int)
    modes = int(table[:, 1].max())
    first = table[calendar < 3]
    reference = np.array([np.median(first[first[:, 1] == m + 1, 2]) for m in range(modes)])
    files = []
    for d in np.unique(calendar)[:n_days]:
        path = folder / f"day_{d:02d}.csv"
        day = table[calendar == d]
        path.write_text("day,mode,frequency_hz,temperature\n" + "".join(
            f"{float(r[0])!r},{int(r[1])},{float(r[2])!r},{float(r[3])!r}\n" for r in day))
        files.append(path)
    return files, reference, dropped


def run(n_days: int = 21, particles: int = 256, seed: int = 0, folder: Path | None = None) -> dict:
    """The mast through a monitor store; returns the status record (``seqbayes status --json``) and timings."""
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(folder or tmp)
        files, reference, dropped = day_datasets(folder, n_days)
        (folder / "monitor.toml").write_text(
            "[model]\nname = \"guyed-mast\"\n[monitor]\nmodel = \"modes\"\nfrequencies = ["
            + ", ".join(f"{f:.6g}" for f in reference) + f"]\nn_particles = {particles}\nseed = {seed}\n")
        store = folder / "mast.nc"
        _quiet(["init", folder / "monitor.toml", store])
        cpu, wall = time.process_time(), time.perf_counter()
        for path in files:
            _quiet(["update", store, path, "-q"])
        cpu, wall = time.process_time() - cpu, time.perf_counter() - wall
        status = json.loads(_quiet(["status", store, "--json"]))
    return {"status": status, "reference": reference.tolist(), "dropped": dropped, "days": len(files),
            "cpu_seconds": cpu, "wall_seconds": wall, "update_cpu": sum(s["cpu_seconds"] for s in status["steps"])}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--days", type=int, default=21)
    parser.add_argument("--particles", type=int, default=256)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    result = run(args.days, args.particles, args.seed)
    status = result["status"]
    print(f"guyed mast: {result['days']} days, {sum(s['n_sets'] for s in status['steps'])} records "
          f"({result['dropped']} mode rows without temperature left out), {len(result['reference'])} modes "
          f"(reference {', '.join(f'{f:.4f}' for f in result['reference'])} Hz); N = {args.particles}, seed {args.seed}")
    print(f"{'day':>4} {'sets':>5} {'P(damage)':>10} {'alarm':>6} {'cpu s':>6}")
    for s in status["steps"]:
        print(f"{s['day']:>4} {s['n_sets']:>5} {s['p_damage']:>10.3g} {'YES' if s['alarm'] else 'no':>6} "
              f"{s['cpu_seconds']:>6.2f}")
    raised = [s["day"] for s in status["steps"] if s["alarm"]]
    print(f"alarm: {'raised on day(s) ' + ', '.join(map(str, raised)) if raised else 'never raised'} (days with "
          f"P(damage) > 0.95: {sum(s['p_damage'] > 0.95 for s in status['steps'])}); max P(damage) "
          f"{max(s['p_damage'] for s in status['steps']):.3g} on day "
          f"{max(status['steps'], key=lambda s: s['p_damage'])['day']}")
    env = status["environment"]
    print("| mode | reference [Hz] | temperature coefficient [1e-4 / degC] | 95 % interval | set noise sd [%] |")
    print("|---|---|---|---|---|")
    for i, f in enumerate(result["reference"]):
        c = env["coefficients"][f"temperature_{i + 1}"]
        noise = env["static"][f"noise_sd_{i + 1}"]
        print(f"| {i + 1} | {f:.4f} | {1e4 * c['mean']:.2f} | [{1e4 * c['lower']:.2f}, {1e4 * c['upper']:.2f}] | "
              f"{100 * noise['mean']:.3f} |")
    for name in ("thermal_lag_h", "knee_location", "discrepancy_sd_per_day", "day_effect_sd"):
        e = env["static"][name]
        print(f"{name}: {e['mean']:.4g} [{e['lower']:.4g}, {e['upper']:.4g}]")
    print(f"updates: {result['update_cpu']:.1f} CPU-s inside the monitor, {result['cpu_seconds']:.1f} CPU-s and "
          f"{result['wall_seconds']:.1f} s wall for the {result['days']} seqbayes update calls ({_load()})")


if __name__ == "__main__":
    main()
