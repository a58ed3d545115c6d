"""SIGKILL ``seqbayes update`` at random moments, many times, and check the store after each kill.

The machinery is that of ``tests/unit/test_kill_resume.py`` (forked CLI children, so a kill
lands in the likelihood evaluations or the write rather than in imports). One run assimilates
``--steps`` datasets; every update is killed after a random delay, drawn from
``uniform(0, 1.1)`` (half the kills) or ``uniform(0.85, 1.05)`` (the other half, near the
write) times the duration of that step's update in a run nobody kills, until one completes; then the next dataset
follows. After every kill the store must load, hold only completed steps, each
bit-identical to an uninterrupted in-process run, with the generator states and step sizes
of that run; a run that reaches the last dataset must equal the uninterrupted run bit for
bit. Runs are repeated until ``--kills`` kills have been made.

After every kill, before seqbayes looks at the store, a forked child tries to read it with xarray
(what another program sees); then ``seqbayes status`` runs (any command that opens the store
writes a committed journal into it), and xarray must read the whole file, with the steps and
samples seqbayes sees.

    python benchmarks/bench_kill.py --kills 200

prints the number of kills, how many landed before the step was stored (and of those, how many left
a half-written temporary file of a whole write or a torn journal of an append) and after it (and
of those, how many left a complete journal), how many kills left a file that xarray could not read
or read without the committed step before seqbayes opened it, that xarray read every file after
``seqbayes status``, the number of completed runs and the time taken.
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

from _user_model import decay_tables, write_config, write_model  # noqa: E402
from test_kill_resume import assert_prefix_of_reference, assert_xarray_reads, fork_cli, wait  # noqa: E402

from seqbayes import cli  # noqa: E402
from seqbayes.store import RunStore, load_config  # noqa: E402
from seqbayes.store.files import read_journal  # noqa: E402


def setup(folder: Path, n_steps: int) -> RunStore:
    """The model, config and data files in ``folder``; returns the uninterrupted reference run."""
    write_model(folder, "benchkillmodel")
    write_config(folder / "run.toml", "benchkillmodel", kernel='a = { type = "drift", rate = -0.05, noise_std = 0.02 }',
                 n_samples=120, seed=21)
    with open(folder / "run.toml", "a") as fh:
        fh.write('predictive = "transition"\n')
    tables = decay_tables([1.5 - 0.05 * s for s in range(n_steps)], np.linspace(0, 3, 15), 0.1, seed=4)
    for s, table in enumerate(tables):
        np.savetxt(folder / f"d{s + 1}.csv", table, delimiter=",", header="t,y", comments="")
    reference = RunStore.create(folder / "reference.nc", load_config(folder / "run.toml"))
    for s in range(n_steps):
        reference.update(folder / f"d{s + 1}.csv")
    return reference


def xarray_steps_in_child(path: Path) -> int:
    """The ``n_steps`` xarray reads from the file, in a forked child (a torn file must not harm this
    process); -1 when xarray cannot read it, -2 when it had not returned after 120 s (HDF5 can loop
    for ever on a torn file: the child's alarm ends it)."""
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        code = 255
        signal.alarm(120)
        try:
            import xarray as xr

            with xr.open_dataset(path, engine="h5netcdf") as ds:
                ds.load()
                code = int(ds.attrs["n_steps"])
        except BaseException:
            code = 255
        finally:
            os._exit(code)
    code = wait(pid)
    return -1 if code == 255 else -2 if code < 0 else code


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kills", type=int, default=200, help="SIGKILLs to make (default 200)")
    parser.add_argument("--steps", type=int, default=6, help="datasets per run (default 6)")
    parser.add_argument("--seed", type=int, default=20240611)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        reference = setup(folder, args.steps)
        run = folder / "killed.nc"
        kills = lost = stored = torn = runs = torn_journal = committed_journal = 0
        unreadable = hung = stale = 0          # what xarray saw before seqbayes opened the store
        journal = folder / f".{run.name}.journal"
        # the duration of each step's update, from one run nobody kills (the kill delays are drawn from it)
        durations = {}
        assert cli.main(["init", str(folder / "run.toml"), str(folder / "timing.nc")]) == 0
        for s in range(1, args.steps + 1):
            t0 = time.perf_counter()
            assert wait(fork_cli(["update", str(folder / "timing.nc"), str(folder / f"d{s}.csv")])) == 0
            durations[s] = time.perf_counter() - t0
        while kills < args.kills:
            assert cli.main(["init", str(folder / "run.toml"), str(run), "--force"]) == 0
            for s in range(1, args.steps + 1):
                while RunStore.open(run).n_steps < s:
                    before = RunStore.open(run).n_steps
                    assert not journal.exists()             # the open above completed any journal
                    pid = fork_cli(["update", str(run), str(folder / f"d{s}.csv")])
                    if kills < args.kills:
                        # half the kills anywhere in the update, half near its end, where the store is written
                        late = rng.uniform() < 0.5
                        time.sleep((rng.uniform(0.85, 1.05) if late else rng.uniform(0.0, 1.1)) * durations[s])
                        with contextlib.suppress(ProcessLookupError):
                            os.kill(pid, signal.SIGKILL)
                    code = wait(pid)
                    if code != 0:
                        assert code == -signal.SIGKILL, code
                        kills += 1
                        left = journal.exists()
                        complete = left and read_journal(run) is not None
                        seen = xarray_steps_in_child(run)     # another program, before seqbayes opens the store
                        torn += (folder / f".{run.name}.tmp-{pid}").exists()   # this child's own temporary file
                        assert wait(fork_cli(["status", str(run)])) == 0      # any seqbayes command
                        assert not journal.exists()
                    store = RunStore.open(run)               # loads whatever the kill hit
                    assert store.n_steps in (before, before + 1), (before, store.n_steps)
                    assert_xarray_reads(run, store)          # other programs read the whole file
                    if code != 0:
                        lost += store.n_steps == before
                        stored += store.n_steps == before + 1
                        committed_journal += complete
                        torn_journal += left and not complete
                        assert not left or complete == (store.n_steps == before + 1)
                        unreadable += seen == -1
                        hung += seen == -2
                        stale += 0 <= seen != store.n_steps
                    assert_prefix_of_reference(store, reference)
            final = RunStore.open(run)
            assert final.n_steps == args.steps
            assert_prefix_of_reference(final, reference)
            np.testing.assert_array_equal(final.result.log_evidence, reference.result.log_evidence)
            runs += 1
            print(f"run {runs}: complete and bit-identical to the uninterrupted run; {kills} kills so far",
                  flush=True)
    elapsed = time.perf_counter() - start
    print(f"{kills} SIGKILLs of `seqbayes update` ({lost} before the step was stored, of which {torn} left a "
          f"half-written temporary file and {torn_journal} a torn journal; {stored} after the step was committed, "
          f"of which {committed_journal} left its complete journal); before seqbayes opened the store, xarray "
          f"could not read it after {unreadable} kills, hung on it after {hung} and read it without the committed "
          f"step after {stale}; after "
          f"`seqbayes status` xarray read every file whole, with seqbayes' steps; after each kill "
          f"the store loaded and every stored step was bit-identical; "
          f"{runs} runs of {args.steps} datasets completed bit for bit; one update takes "
          f"{np.median(list(durations.values())):.2f} s; {elapsed:.0f} s in all")
    return 0


if __name__ == "__main__":
    sys.exit(main())
