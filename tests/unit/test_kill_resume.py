"""Crash safety and resume equivalence of ``seqbayes update`` across processes.

* Resume equivalence: 4 updates in 4 separate processes give bit-identical samples,
  weights, evidence, mixture densities and generator states to 4 updates in one process.
* SIGKILL during ``update``, several times: at each fault-injection point of the write
  (an append through the journal: before writing, a torn journal, before applying it, half
  applied, after; a whole write: before writing, a torn temporary file, before the rename,
  after the rename) and at
  random times drawn from a seeded generator. After every kill the store loads, holds
  every completed step (bit-identical to the uninterrupted run), and rerunning
  ``update`` completes the run with the uninterrupted run's numbers. Once a seqbayes
  command has opened the store, xarray reads it whole (a committed journal was written
  into it), with the steps seqbayes sees.

The assertions hold wherever a random kill lands (that is the property tested), so
the test does not depend on timing; the fault-injection points make sure the write
window itself is hit every time.
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from seqbayes import cli
from seqbayes.store import RunStore, load_config, snapshot
from seqbayes.store.files import FAULT_ENV

from _user_model import decay_tables, write_config, write_model


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    root = tmp_path_factory.mktemp("killresume")
    write_model(root, "killmodel")
    write_config(root / "run.toml", "killmodel", kernel='a = { type = "drift", rate = -0.05, noise_std = 0.02 }',
                 n_samples=120, seed=21)
    tables = decay_tables([1.5 - 0.05 * s for s in range(4)], np.linspace(0, 3, 15), 0.1, seed=4)
    for s, table in enumerate(tables):
        np.savetxt(root / f"d{s + 1}.csv", table, delimiter=",", header="t,y", comments="")
    # the uninterrupted run: 4 updates in this one process
    store = RunStore.create(root / "reference.nc", load_config(root / "run.toml"))
    for s in range(4):
        store.update(root / f"d{s + 1}.csv")
    return root


def spawn(workdir, *args):
    """``seqbayes ARGS`` in a fresh interpreter."""
    env = dict(os.environ)
    env.pop(FAULT_ENV, None)
    return subprocess.Popen([sys.executable, "-m", "seqbayes.cli", *args], cwd=workdir, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def fork_cli(args, fault=None) -> int:
    """``seqbayes ARGS`` in a forked child (no start-up cost, so random kills land in the work
    and the write, not in imports); returns the child's pid."""
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        code = 70
        try:
            os.environ.pop(FAULT_ENV, None)
            if fault:
                os.environ[FAULT_ENV] = fault
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, 1)
            os.dup2(devnull, 2)
            code = cli.main(list(args))
        finally:
            os._exit(code)
    return pid


def wait(pid) -> int:
    """Exit code of a child (``-9`` when SIGKILLed)."""
    return os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])


def assert_xarray_reads(path, store):
    """Another program (xarray, h5netcdf) reads the whole file, with the steps and samples seqbayes sees."""
    import xarray as xr

    with xr.open_dataset(path, engine="h5netcdf") as ds:
        ds.load()
        assert int(ds.attrs["n_steps"]) == store.n_steps
        if store.n_steps:
            np.testing.assert_array_equal(ds["posterior"].values, np.stack([s.posterior for s in store.result.steps]))


def assert_prefix_of_reference(store, reference):
    """Every stored step is bit-identical to the uninterrupted run's step."""
    assert store.n_steps <= reference.n_steps
    for a, b in zip(store.result.steps, reference.result.steps):
        np.testing.assert_array_equal(a.posterior, b.posterior)
        np.testing.assert_array_equal(a.log_weights, b.log_weights)
        np.testing.assert_array_equal(a.predictive, b.predictive)
        assert a.info.log_evidence == b.info.log_evidence
    for mine, theirs in zip(store.states, reference.states):
        # SMC^2's full state is kept for each store's last two steps only: compare what both hold
        assert {n for n in mine if snapshot.per_step(n)} == {n for n in theirs if snapshot.per_step(n)}
        for name in set(mine) & set(theirs):
            np.testing.assert_array_equal(mine[name], theirs[name])
    assert store.rng_states == reference.rng_states[:store.n_steps + 1]
    assert store.step_sizes == reference.step_sizes[:store.n_steps]


@pytest.mark.slow
def test_four_updates_in_four_processes_equal_four_in_one(workdir):
    assert cli.main(["init", str(workdir / "run.toml"), str(workdir / "separate.nc")]) == 0
    for s in range(4):
        proc = spawn(workdir, "update", "separate.nc", f"d{s + 1}.csv")
        out, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, err
        assert f"step {s + 1} from d{s + 1}.csv" in out
    separate = RunStore.open(workdir / "separate.nc")
    reference = RunStore.open(workdir / "reference.nc")
    assert separate.n_steps == 4
    assert_prefix_of_reference(separate, reference)
    np.testing.assert_array_equal(separate.result.log_evidence, reference.result.log_evidence)


@pytest.mark.slow
def test_sigkill_at_each_write_stage_keeps_the_store_and_rerun_completes(workdir):
    run = workdir / "faults.nc"
    journal = workdir / f".{run.name}.journal"
    reference = RunStore.open(workdir / "reference.nc")
    assert cli.main(["init", str(workdir / "run.toml"), str(run)]) == 0
    assert cli.main(["update", str(run), str(workdir / "d1.csv")]) == 0

    def killed(args, point, steps, journal_left):
        assert wait(fork_cli(args, fault=point)) == -signal.SIGKILL
        assert journal.exists() == journal_left, point
        store = RunStore.open(run)                        # still loads, and completes a committed journal
        assert store.n_steps == steps, point              # every completed step, nothing torn
        assert_prefix_of_reference(store, reference)
        assert not journal.exists(), point
        assert_xarray_reads(run, store)

    # a step is appended through the journal: killed before the journal is complete (before-write,
    # a torn journal) the store is unchanged; once it is complete the step is committed, and readers
    # lay the journal over the store until the next writer applies it
    update = [["update", str(run), str(workdir / f"d{s}.csv")] for s in range(5)]
    killed(update[2], "before-write", 1, False)
    killed(update[2], "mid-write", 1, True)
    killed(update[2], "before-replace", 2, True)
    assert cli.main(update[2]) == 2                       # a duplicate: refused
    killed(update[3], "mid-apply", 3, True)               # half its pages written into the store
    assert cli.main(update[3]) == 2 and not journal.exists()
    killed(update[4], "after-replace", 4, False)
    # a whole write (here: replacing the last step) goes through a temporary file and os.replace
    replace_d4 = update[4] + ["--replace-last"]
    for point in ("before-write", "mid-write", "before-replace", "after-replace"):
        killed(replace_d4, point, 4, False)
        leftover = [p for p in workdir.iterdir() if p.name.startswith(f".{run.name}.tmp-")]
        assert len(leftover) == (1 if point in ("mid-write", "before-replace") else 0), point
    # the run ends with the uninterrupted run's numbers
    assert cli.main(update[4]) == 2
    final = RunStore.open(run)
    assert final.n_steps == 4
    assert_prefix_of_reference(final, reference)
    assert sorted(p.name for p in workdir.iterdir() if p.name.startswith(f".{run.name}")) == []


@pytest.mark.slow
def test_sigkill_at_random_times(workdir):
    run = workdir / "random.nc"
    reference = RunStore.open(workdir / "reference.nc")
    assert cli.main(["init", str(workdir / "run.toml"), str(run)]) == 0
    # duration of one normal update, to spread the kills over the work and the write
    start = time.perf_counter()
    assert wait(fork_cli(["update", str(run), str(workdir / "d1.csv")])) == 0
    duration = time.perf_counter() - start
    rng = np.random.default_rng(20240611)
    for s in (2, 3, 4):
        for _ in range(2):                                 # two random kills per step
            before = RunStore.open(run).n_steps
            if before >= s:
                break
            pid = fork_cli(["update", str(run), str(workdir / f"d{s}.csv")])
            time.sleep(rng.uniform(0.0, 1.2) * duration)
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
            code = wait(pid)
            store = RunStore.open(run)                     # loads whatever the kill hit
            assert_xarray_reads(run, store)
            if code == 0:                                  # the kill came too late: the step is stored
                assert store.n_steps == before + 1
            assert store.n_steps in (before, before + 1)
            assert_prefix_of_reference(store, reference)
        if RunStore.open(run).n_steps < s:
            assert cli.main(["update", str(run), str(workdir / f"d{s}.csv")]) == 0   # the rerun
    final = RunStore.open(run)
    assert final.n_steps == 4
    assert_prefix_of_reference(final, reference)
