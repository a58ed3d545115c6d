"""A fleet update killed at any moment resumes bit for bit (issue 42: the fleet path under the store's discipline).

The machinery is that of tests/unit/test_kill_resume.py and benchmarks/bench_kill.py (the same checks of a
store after a kill: it loads, every stored step is bit-identical to the uninterrupted run's, and once a
seqbayes command has opened it xarray reads it whole), applied to every store of a fleet:

* SIGKILL at each fault point of a store's write, with the serial driver (the process kills itself at the
  first write that reaches the point): the whole write of a store's first step, and the journal of an
  append (stores that already hold a step);
* SIGKILL of the whole process group of a Dask fleet update (the driver and its LocalCluster's worker
  processes) at random moments drawn from a seeded generator, rerun until it completes;
* two fleet updates of the same fleet at once (each store's lock orders them; every dataset is
  assimilated once).

After the final rerun every store equals the serial reference bit for bit, no journal or temporary file
is left, and the fleet's record is a whole outcome. ``benchmarks/bench_fleet.py kill --kills 50`` makes 50
random kills with the same checks. Each test starts Python processes, so all are slow.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from _fleet_model import make_fleet, serial_updates, store_fingerprint
from test_kill_resume import assert_prefix_of_reference, assert_xarray_reads

from seqbayes import cli
from seqbayes.store import RunStore
from seqbayes.store.files import FAULT_ENV

N_STORES, N_DATASETS = 3, 4


def build_kill_fleet(root: Path, n_stores: int, n_datasets: int, module: str, n_samples: int = 24) -> Path:
    """The fleet under ``root`` (tests/_fleet_model.py), whose last store's likelihood raises on its third
    dataset, with its serial reference in ``root/serial`` and ``root/expected.json`` (stores, failed)."""
    poisoned = n_stores - 1
    plan = make_fleet(root, n_stores, n_datasets, module=module, n_samples=n_samples, raising={poisoned: 3})
    codes = serial_updates(root, plan, root / "serial")
    assert codes == {name: 2 if name == f"s{poisoned}" else 0 for name in plan}
    (root / "expected.json").write_text(json.dumps({"stores": list(plan), "failed": [f"s{poisoned}"]}))
    return root


@pytest.fixture(scope="module")
def kill_root(tmp_path_factory):
    return build_kill_fleet(tmp_path_factory.mktemp("fleetkill"), N_STORES, N_DATASETS, "fleetkillmodel")


def spawn_fleet(fleet: Path, *options, fault: str | None = None) -> subprocess.Popen:
    """``seqbayes update FLEET OPTIONS`` in a fresh interpreter leading its own process group (so that a kill
    of the group reaches a local cluster's workers too)."""
    env = dict(os.environ)
    env.pop(FAULT_ENV, None)
    if fault:
        env[FAULT_ENV] = fault
    return subprocess.Popen([sys.executable, "-m", "seqbayes.cli", "update", str(fleet), *options], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, start_new_session=True)


def group_alive(pgid: int) -> bool:
    """Whether a live (not zombie) process of the group ``pgid`` remains."""
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            with contextlib.suppress(OSError, IndexError, ValueError):
                fields = Path(f"/proc/{entry}/stat").read_text().rsplit(")", 1)[1].split()
                if int(fields[2]) == pgid and fields[0] != "Z":
                    return True
    return False


def kill_group(proc: subprocess.Popen, timeout: float = 60.0) -> int:
    """SIGKILL the process group of ``proc``; its exit code once no member of the group is left."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)
    code = proc.wait()
    deadline = time.monotonic() + timeout
    while group_alive(proc.pid):
        assert time.monotonic() < deadline, "a process of the killed fleet update survived"
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        time.sleep(0.05)
    return code


def check_fleet_after_kill(fleet: Path, references: dict) -> dict:
    """Every store loads (whatever the kill hit) and holds a prefix of its reference, bit for bit; the record is
    absent or a whole outcome. Then a seqbayes command opens every store (``status``), after which xarray reads
    each file whole. Returns ``{name: steps}``."""
    record = fleet / ".seqbayes-fleet.json"
    if record.exists():
        assert json.loads(record.read_text())["seqbayes_fleet_outcome"] == 1
    steps = {}
    for name, reference in references.items():
        store = RunStore.open(fleet / f"{name}.nc")
        assert_prefix_of_reference(store, reference)
        steps[name] = store.n_steps
    with contextlib.redirect_stdout(open(os.devnull, "w")):
        assert cli.main(["status", str(fleet)]) in (0, 1)
    for name in references:
        assert not (fleet / f".{name}.nc.journal").exists()
        assert_xarray_reads(fleet / f"{name}.nc", RunStore.open(fleet / f"{name}.nc"))
    return steps


def assert_complete(fleet: Path, kill_root: Path) -> None:
    """The fleet ends as the serial reference, bit for bit, with no journal or temporary file left."""
    expected = json.loads((kill_root / "expected.json").read_text())
    for name in expected["stores"]:
        assert store_fingerprint(fleet / f"{name}.nc") == store_fingerprint(kill_root / "serial" / f"{name}.nc")
    left = [p.name for p in fleet.iterdir() if p.name.endswith(".journal") or ".tmp-" in p.name]
    assert left == []
    outcome = json.loads((fleet / ".seqbayes-fleet.json").read_text())
    assert outcome["failed"] == expected["failed"]


def references(kill_root: Path) -> dict:
    names = json.loads((kill_root / "expected.json").read_text())["stores"]
    return {name: RunStore.open(kill_root / "serial" / f"{name}.nc") for name in names}


@pytest.mark.slow
@pytest.mark.parametrize("stepped", [False, True], ids=["whole-write", "journal"])
def test_sigkill_at_each_write_stage_of_a_fleet_update_resumes_bit_for_bit(kill_root, tmp_path, stepped):
    """A store's first step is written whole (temporary file, rename); a later step is appended through the
    journal. The serial driver's process kills itself at the fault point of the first write reaching it."""
    refs = references(kill_root)
    points = (("before-write", "mid-write", "before-replace", "mid-apply", "after-replace") if stepped
              else ("before-write", "mid-write", "before-replace", "after-replace"))
    for point in points:
        fleet = tmp_path / point
        shutil.copytree(kill_root / "fleet", fleet)
        if stepped:                             # every store holds its first dataset: the fleet appends
            for k in range(N_STORES):
                assert cli.main(["update", str(fleet / f"s{k}.nc"), str(fleet / f"s{k}" / "d1.csv"), "-q"]) == 0
        proc = spawn_fleet(fleet, "--workers", "0", fault=point)
        assert proc.wait(timeout=300) == -signal.SIGKILL, (point, proc.stderr.read())
        steps = check_fleet_after_kill(fleet, refs)
        # the first store took the kill in its first write (kept once committed: a whole write once renamed,
        # an append once its journal is complete); the others were not reached yet
        first = 1 if stepped else 0
        committed = ("before-replace", "mid-apply", "after-replace") if stepped else ("after-replace",)
        assert steps["s0"] == first + (point in committed), (point, steps)
        assert steps["s1"] == steps["s2"] == first, point
        proc = spawn_fleet(fleet, "--workers", "0")
        assert proc.wait(timeout=300) == 1, proc.stderr.read()   # s2's likelihood raises: the exit says so
        assert_complete(fleet, kill_root)


def kill_and_resume(kill_root: Path, folder: Path, kills: int, rng, duration: float, workers: str = "2",
                    report=None, keep: Path | None = None) -> dict:
    """Fleet updates of fresh copies of the fleet, each killed (the whole process group) after a random delay of
    ``uniform(0, 1.1) * duration`` and rerun, until ``kills`` kills were made; every attempt that completes
    must leave the fleet as the serial reference, bit for bit (:func:`assert_complete`), and then a fresh copy
    follows. Returns counts: kills, completed fleets, kills that found stores part-way (some step stored, not
    all), and the steps kept per kill. With ``keep``, a fleet that fails a check is copied there first."""
    refs = references(kill_root)
    counts = {"kills": 0, "fleets": 0, "part_way": 0, "steps_kept": []}
    total = sum(r.n_steps for r in refs.values())
    while counts["kills"] < kills:
        fleet = folder / f"fleet{counts['fleets']}"
        shutil.copytree(kill_root / "fleet", fleet)
        while True:
            proc = spawn_fleet(fleet, "--workers", workers)
            killing = counts["kills"] < kills
            if killing:
                time.sleep(rng.uniform(0.0, 1.1) * duration)
            code = kill_group(proc) if killing else proc.wait(timeout=900)
            if code == -signal.SIGKILL:
                counts["kills"] += 1
                if keep is not None:
                    snapshot = keep / "before-check"
                    shutil.rmtree(snapshot, ignore_errors=True)
                    shutil.copytree(fleet, snapshot)       # the fleet as the kill left it
                try:
                    steps = sum(check_fleet_after_kill(fleet, refs).values())
                except BaseException:
                    if keep is not None:
                        shutil.copytree(fleet, keep / "after-check", dirs_exist_ok=True)
                        fresh_reads(keep)
                    raise
                counts["steps_kept"].append(steps)
                counts["part_way"] += 0 < steps < total
                if report is not None:
                    report(counts)
                continue
            assert code == 1, proc.stderr.read()      # complete: the last store's likelihood raises
            assert_complete(fleet, kill_root)
            counts["fleets"] += 1
            shutil.rmtree(fleet)
            break
    return counts


#: Reads every store of a kept fleet with xarray in a fresh interpreter: whether a failed xarray check is the
#: file's (the fresh read fails too) or the checking process's (it passes).
_FRESH_READ = """import sys, glob, xarray as xr
for path in sorted(glob.glob(sys.argv[1] + '/*/*.nc')):
    try:
        with xr.open_dataset(path, engine='h5netcdf') as ds:
            ds.load()
            print(path, 'read whole:', {k: ds[k].dims for k in ('dataset_sha256',) if k in ds})
    except Exception as err:
        print(path, 'fails:', type(err).__name__, str(err)[:300])
"""


def fresh_reads(keep: Path) -> None:
    """Write ``keep/fresh-reads.txt``: each kept store read by xarray in a fresh interpreter (:data:`_FRESH_READ`)."""
    result = subprocess.run([sys.executable, "-c", _FRESH_READ, str(keep)], capture_output=True, text=True,
                            timeout=600)
    (keep / "fresh-reads.txt").write_text(result.stdout + result.stderr)
    print(f"fresh reads of the kept fleet:\n{result.stdout}{result.stderr}", flush=True)


def uninterrupted_duration(kill_root: Path, folder: Path, workers: str = "2") -> float:
    """Seconds of one uninterrupted fleet update in a fresh interpreter (start-up and cluster included)."""
    shutil.copytree(kill_root / "fleet", folder)
    start = time.perf_counter()
    proc = spawn_fleet(folder, "--workers", workers)
    assert proc.wait(timeout=900) == 1, proc.stderr.read()
    duration = time.perf_counter() - start
    assert_complete(folder, kill_root)
    return duration


@pytest.mark.slow
def test_sigkill_of_a_dask_fleet_update_at_random_moments_resumes_bit_for_bit(kill_root, tmp_path):
    duration = uninterrupted_duration(kill_root, tmp_path / "timing")
    counts = kill_and_resume(kill_root, tmp_path, 2, np.random.default_rng(20261207), duration)
    assert counts["kills"] == 2 and counts["fleets"] >= 1


@pytest.mark.slow
def test_two_fleet_updates_at_once_assimilate_every_dataset_once(kill_root, tmp_path):
    """Each store's lock orders the two; the second finds each store's datasets already there and skips them."""
    fleet = tmp_path / "fleet"
    shutil.copytree(kill_root / "fleet", fleet)
    procs = [spawn_fleet(fleet, "--workers", "0", "--lock-timeout", "300") for _ in range(2)]
    assert [p.wait(timeout=600) for p in procs] == [1, 1], [p.stderr.read() for p in procs]
    assert_complete(fleet, kill_root)
    for name in ("s0", "s1"):
        store = RunStore.open(fleet / f"{name}.nc")
        assert store.sources == [f"d{s}.csv" for s in range(1, N_DATASETS + 1)]


@pytest.mark.slow
def test_a_likelihood_that_kills_its_worker_fails_its_store_only(kill_root, tmp_path):
    """A worker process dies under a task (here the likelihood ends its process on s1's third dataset): Dask runs
    the task again on other workers, where it dies again, then reports it; that store keeps its committed steps,
    the others complete bit for bit."""
    fleet = tmp_path / "fleet"
    shutil.copytree(kill_root / "fleet", fleet)
    module = kill_root / "model" / "fleetkillmodel_dies.py"
    third = float(np.loadtxt(fleet / "s1" / "d3.csv", delimiter=",", skiprows=1)[0, 1])
    module.write_text((kill_root / "model" / "fleetkillmodel.py").read_text().replace("def loglike", "def _line")
                      + f"\nimport os\ndef loglike(theta, data):\n    if abs(data[0, 1] - {third!r}) < 1e-12:\n"
                        f"        os._exit(3)\n    return _line(theta, data)\n")
    config = (kill_root / "model" / "s1.toml").read_text().replace("fleetkillmodel:", "fleetkillmodel_dies:")
    (tmp_path / "s1.toml").write_text(config)
    shutil.copyfile(module, tmp_path / "fleetkillmodel_dies.py")
    assert cli.main(["init", str(tmp_path / "s1.toml"), str(fleet / "s1.nc"), "--force"]) == 0
    proc = spawn_fleet(fleet, "--workers", "2")
    assert proc.wait(timeout=900) == 1, proc.stderr.read()
    outcome = {s["name"]: s for s in json.loads((fleet / ".seqbayes-fleet.json").read_text())["stores"]}
    assert outcome["s1"]["status"] == "failed" and "did not complete on the cluster (KilledWorker" in \
        outcome["s1"]["error"]
    assert RunStore.open(fleet / "s1.nc").n_steps == 2             # the steps committed before the crash
    assert outcome["s0"]["status"] == "updated"
    assert store_fingerprint(fleet / "s0.nc") == store_fingerprint(kill_root / "serial" / "s0.nc")
