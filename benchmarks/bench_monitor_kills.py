"""SIGKILL ``seqbayes update`` of a monitor run store at random moments, many times, and check the store after each
kill (issue 40 "Kills", issue 42 item 4).

The machinery is that of ``tests/unit/test_kill_resume.py`` (forked CLI children, so a kill lands in the
monitor's work or the write rather than in imports). One run takes ``--days`` daily datasets of a simulated
two-mode year; every update is killed after a random delay, drawn from ``uniform(0, 1.1)`` (half the kills) or
``uniform(0.85, 1.05)`` (the other half, near the write) times the duration of that day's update in a run nobody
kills, until one completes; then the next day follows. After every kill the store must open, hold only completed
days, each identical to the uninterrupted run's (the day's record but its CPU time, and the generator's state
after it); a run that reaches the last day must equal the uninterrupted run bit for bit (the sampler's whole
state). Runs are repeated until ``--kills`` kills have been made.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_monitor_kills.py --kills 100

prints the kills, how many landed before the day was stored and after it, how many left a temporary file, the
completed runs and the time taken.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT / "tests"), str(ROOT / "tests" / "unit")]

from test_kill_resume import fork_cli, wait  # noqa: E402

from seqbayes import cli  # noqa: E402
from seqbayes.store import open_run  # noqa: E402

TOML = """[model]
name = "kills"
[monitor]
model = "modes"
frequencies = [2.0, 5.5]
n_particles = {particles}
seed = 11
"""


def write_days(folder: Path, n_days: int, seed: int = 3) -> list:
    """A simulated two-mode year's first days, one year-CSV file per day (20 % of the modes missing, a 2 % drop
    of mode 2 from day 3)."""
    rng = np.random.default_rng(seed)
    paths = []
    for d in range(n_days):
        day = d + np.sort(rng.uniform(0, 1, 12))
        air = 5 + 8 * np.sin(2 * np.pi * day) + rng.normal(0, 1, day.size)
        f = np.array([2.0, 5.5]) * np.exp(-0.0008 * (air[:, None] - 10) + rng.normal(0, 0.003, (day.size, 2)))
        if d >= 3:
            f[:, 1] *= 0.98
        f[rng.random(f.shape) < 0.2] = np.nan
        cells = [[repr(float(x)) if np.isfinite(x) else "" for x in row]
                 for row in np.column_stack([day, air, f])]
        path = folder / f"day{d}.csv"
        path.write_text("day,temperature,f1,f2\n" + "".join(",".join(c) + "\n" for c in cells))
        paths.append(path)
    return paths


def day_records(store) -> list:
    return [{k: v for k, v in info.items() if k != "cpu_seconds"} for info in store.infos]


def state_equal(a, b) -> bool:
    sa, sb = a.state, b.state
    pairs = [(sa.particles.u, sb.particles.u), (sa.log_weights, sb.log_weights),
             (sa.particles.cache.filters.mean, sb.particles.cache.filters.mean),
             (sa.particles.cache.filters.cov, sb.particles.cache.filters.cov),
             (sa.particles.cache.bank.A, sb.particles.cache.bank.A),
             (sa.particles.cache.bank.delta, sb.particles.cache.bank.delta)]
    return all(np.array_equal(x, y) for x, y in pairs) and sa.log_evidence == sb.log_evidence


def check_prefix(store, reference) -> None:
    n = store.n_steps
    assert n <= reference.n_steps
    assert day_records(store) == day_records(reference)[:n], "a stored day differs from the uninterrupted run's"
    assert store.rng_states == reference.rng_states[:n + 1]
    assert store.digests == reference.digests[:n]


def run_kills(n_kills: int, n_days: int = 5, particles: int = 48, seed: int = 20261208, folder=None) -> dict:
    """Kill updates until ``n_kills`` kills; returns the counts (asserting every check on the way)."""
    rng = np.random.default_rng(seed)
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(folder or tmp)
        (folder / "monitor.toml").write_text(TOML.format(particles=particles))
        paths = write_days(folder, n_days)
        assert cli.main(["init", str(folder / "monitor.toml"), str(folder / "reference.nc")]) == 0
        durations = []
        for path in paths:                    # the uninterrupted run, one process per day, timed
            t0 = time.perf_counter()
            assert wait(fork_cli(["update", str(folder / "reference.nc"), str(path)])) == 0
            durations.append(time.perf_counter() - t0)
        reference = open_run(folder / "reference.nc")
        run = folder / "killed.nc"
        kills = lost = stored = temporary = runs = 0
        while kills < n_kills:
            assert cli.main(["init", str(folder / "monitor.toml"), str(run), "--force"]) == 0
            for d, path in enumerate(paths):
                while open_run(run).n_steps <= d:
                    before = open_run(run).n_steps
                    pid = fork_cli(["update", str(run), str(path)])
                    if kills < n_kills:
                        late = rng.uniform() < 0.5
                        time.sleep((rng.uniform(0.85, 1.05) if late else rng.uniform(0.0, 1.1)) * durations[d])
                        with contextlib.suppress(ProcessLookupError):
                            os.kill(pid, signal.SIGKILL)
                    code = wait(pid)
                    if code != 0:
                        assert code == -signal.SIGKILL, code
                        kills += 1
                        temporary += (folder / f".{run.name}.tmp-{pid}").exists()
                    store = open_run(run)             # whatever the kill hit, the store opens
                    assert store.n_steps in (before, before + 1), (before, store.n_steps)
                    check_prefix(store, reference)
                    if code != 0:
                        lost += store.n_steps == before
                        stored += store.n_steps == before + 1
            final = open_run(run)
            assert final.n_steps == reference.n_steps and state_equal(final, reference)
            runs += 1
    return {"kills": kills, "before_stored": lost, "after_stored": stored, "temporary_files": temporary,
            "completed_runs": runs, "seconds": time.perf_counter() - start}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kills", type=int, default=100)
    parser.add_argument("--days", type=int, default=5)
    parser.add_argument("--particles", type=int, default=48)
    parser.add_argument("--seed", type=int, default=20261208)
    args = parser.parse_args(argv)
    out = run_kills(args.kills, args.days, args.particles, args.seed)
    try:
        load = f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    except OSError:
        load = "load unknown"
    print(f"{out['kills']} SIGKILLs during monitor updates ({args.days} days, N = {args.particles}): "
          f"{out['before_stored']} before the day was stored, {out['after_stored']} after it "
          f"({out['temporary_files']} left a temporary file, removed by the next write); every kill resumed to "
          f"the uninterrupted run's days; {out['completed_runs']} completed runs, each bit for bit the "
          f"uninterrupted run's state; {out['seconds']:.0f} s ({load})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
