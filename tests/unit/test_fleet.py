"""A fleet update equals serial updates bit for bit, isolates a poisoned store, and says so.

One small fleet (tests/_fleet_model.py: four stores of the straight-line model, N = 20, two datasets
each) is built once with its serial reference, ``seqbayes update STORE D1 D2`` of each store alone.
Store s2's likelihood raises on its second dataset and store s3's second data file holds a NaN: the
serial updates keep s2's first step and leave s3 unchanged, and so must the fleet, while s0 and s1
complete. Each test copies the fleet (created stores and data) to its own folder and runs it through
the serial driver, a Dask LocalCluster (threads: fast), or the command line.
"""

from __future__ import annotations

import fcntl
import hashlib
import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from _fleet_model import make_fleet, serial_updates, store_fingerprint, write_table

from seqbayes import cli
from seqbayes.fleet import TaskOptions, plan_fleet, run_dask, run_serial, run_task
from seqbayes.fleet.outputs import record_path

NAMES = ("s0", "s1", "s2", "s3")


@pytest.fixture(scope="module")
def fleet_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("fleet")
    plan = make_fleet(root, 4, 2, module="fleetunit", n_samples=20, raising={2: 2})
    bad = root / "fleet" / "s3" / "d2.csv"
    bad.write_text("t,y\n0,1.0\n0.5,nan\n1,1.2\n")
    codes = serial_updates(root, plan, root / "serial")
    assert codes == {"s0": 0, "s1": 0, "s2": 2, "s3": 2}
    return root


@pytest.fixture(scope="module")
def reference(fleet_root):
    """The fingerprint of every store updated alone (serial ``seqbayes update``)."""
    return {name: store_fingerprint(fleet_root / "serial" / f"{name}.nc") for name in NAMES}


def fresh(fleet_root, folder: Path) -> Path:
    """A copy of the created fleet (stores without steps, data folders) in ``folder``."""
    shutil.copytree(fleet_root / "fleet", folder)
    return folder


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def assert_poisoned_outcomes(outcomes, fleet):
    by_name = {o.name: o for o in outcomes}
    assert [by_name[n].status for n in NAMES] == ["updated", "updated", "failed", "failed"]
    assert [len(by_name[n].steps) for n in NAMES] == [2, 2, 1, 0]
    assert by_name["s2"].n_steps == 1 and by_name["s3"].n_steps == 0
    assert by_name["s2"].error.startswith(f"{fleet / 's2' / 'd2.csv'}: the likelihood fleetunit_raising2:loglike "
                                          f"raised RuntimeError: sensor model out of range; the run store keeps "
                                          f"the steps committed before it (d1.csv (step 1))")
    assert by_name["s3"].error == (f"{fleet / 's3' / 'd2.csv'}: column 'y' has 1 NaN/inf value(s), first at data "
                                   f"row 2 (line 3)")
    assert by_name["s0"].steps[1].summary.startswith("step 2 from d2.csv: log-evidence increment")


@pytest.mark.slow
def test_the_serial_driver_equals_serial_updates_bit_for_bit_and_isolates_the_poisoned(fleet_root, reference,
                                                                                       tmp_path):
    fleet = fresh(fleet_root, tmp_path / "fleet")
    outcomes = run_serial(plan_fleet(fleet).tasks)
    assert_poisoned_outcomes(outcomes, fleet)
    assert {n: store_fingerprint(fleet / f"{n}.nc") for n in NAMES} == reference
    # run again: every store holds its datasets already (s2 and s3 fail again, on the same files)
    again = {o.name: o for o in run_serial(plan_fleet(fleet).tasks)}
    assert again["s0"].status == "current" and again["s0"].skipped == ("d1.csv", "d2.csv")
    assert again["s2"].skipped == ("d1.csv",) and again["s2"].status == "failed"
    assert {n: store_fingerprint(fleet / f"{n}.nc") for n in NAMES} == reference


def test_a_dask_local_cluster_equals_serial_updates_bit_for_bit(fleet_root, reference, tmp_path):
    from distributed import Client, LocalCluster

    fleet = fresh(fleet_root, tmp_path / "fleet")
    seen = []
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster, \
            Client(cluster) as client:
        outcomes = run_dask(plan_fleet(fleet).tasks, client, on_outcome=seen.append)
    assert sorted(o.name for o in seen) == list(NAMES) and seen == outcomes
    assert_poisoned_outcomes(outcomes, fleet)
    assert {n: store_fingerprint(fleet / f"{n}.nc") for n in NAMES} == reference


@pytest.mark.slow
def test_the_command_line_on_a_running_scheduler_equals_serial_updates(fleet_root, reference, tmp_path, capsys):
    """``--scheduler ADDRESS``: the tasks go to a cluster the command did not start (here one in this process)."""
    from distributed import LocalCluster

    fleet = fresh(fleet_root, tmp_path / "fleet")
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        code = cli.main(["update", str(fleet), "--scheduler", cluster.scheduler_address])
    out = capsys.readouterr().out
    assert code == 1 and f"(dask scheduler {cluster.scheduler_address})" in out
    assert {n: store_fingerprint(fleet / f"{n}.nc") for n in NAMES} == reference


@pytest.mark.slow
def test_a_locked_store_is_reported_with_its_holder_and_the_others_complete(fleet_root, reference, tmp_path):
    fleet = fresh(fleet_root, tmp_path / "fleet")
    before = sha(fleet / "s1.nc")
    with open(fleet / "s1.nc.lock", "w") as lock:            # another update holds s1 (another open file)
        fcntl.flock(lock, fcntl.LOCK_EX)
        lock.write("pid 4242 on host lab-3 since 2026-11-27T18:40:00+00:00\n")
        lock.flush()
        tasks = [t for t in plan_fleet(fleet).tasks if t.name in ("s0", "s1")]
        s0, s1 = run_serial(tasks, TaskOptions(lock_timeout=0))
    assert s0.status == "updated" and store_fingerprint(fleet / "s0.nc") == reference["s0"]
    assert s1.status == "failed" and s1.n_steps is None
    assert "gave up after 0 s waiting for the lock" in s1.error and "held by pid 4242 on host lab-3" in s1.error
    assert sha(fleet / "s1.nc") == before


@pytest.mark.slow
@pytest.mark.parametrize("damage", ["flip", "truncate"])
def test_a_damaged_store_is_one_line_and_the_others_complete(fleet_root, reference, tmp_path, damage):
    fleet = fresh(fleet_root, tmp_path / "fleet")
    data = bytearray((fleet / "s0.nc").read_bytes())
    if damage == "flip":
        data[len(data) // 2] ^= 0x10
    else:
        data = data[:len(data) // 2]
    (fleet / "s0.nc").write_bytes(bytes(data))
    tasks = [t for t in plan_fleet(fleet).tasks if t.name in ("s0", "s1")]
    s0, s1 = run_serial(tasks)
    assert s0.status == "failed" and str(fleet / "s0.nc") in s0.error and "\n" not in s0.error
    assert bytes(data) == (fleet / "s0.nc").read_bytes()                   # left as it was
    assert s1.status == "updated" and store_fingerprint(fleet / "s1.nc") == reference["s1"]


@pytest.mark.slow
def test_a_stopped_fleet_resumes_where_each_store_stopped(fleet_root, reference, tmp_path):
    """Stores part-way (as a killed fleet update leaves them: a prefix of their datasets) finish bit for bit."""
    fleet = fresh(fleet_root, tmp_path / "fleet")
    tasks = {t.name: t for t in plan_fleet(fleet).tasks}
    partial = run_task(tasks["s0"].__class__(tasks["s0"].name, tasks["s0"].store, tasks["s0"].datasets[:1]))
    assert partial.status == "updated" and partial.n_steps == 1
    s0, s1 = run_serial([tasks["s0"], tasks["s1"]])
    assert s0.skipped == ("d1.csv",) and [s.step for s in s0.steps] == [2]
    assert store_fingerprint(fleet / "s0.nc") == reference["s0"]
    assert store_fingerprint(fleet / "s1.nc") == reference["s1"]


# ---------------------------------------------------------------------------------- the command line
def test_the_command_line_updates_the_fleet_and_its_status_lists_the_errors(fleet_root, reference, tmp_path,
                                                                            capsys, monkeypatch):
    fleet = fresh(fleet_root, tmp_path / "fleet")
    code = cli.main(["update", str(fleet), "--workers", "0", "--json", str(tmp_path / "out.json")])
    out, err = capsys.readouterr()
    assert code == 1                                     # some stores failed, the others completed
    assert "s0: 2 datasets assimilated (steps 1-2)" in out and "s3: FAILED: " in out
    assert "4 stores of " + str(fleet) + ": 2 updated (5 datasets), 0 up to date, 2 failed" in out
    errors = [line for line in err.splitlines() if not line.startswith("seqbayes update: warning: ")]
    assert [line.split(": FAILED")[0] for line in errors] == [f"seqbayes update: error: {n}" for n in ("s2", "s3")]
    assert {n: store_fingerprint(fleet / f"{n}.nc") for n in NAMES} == reference
    written = json.loads((tmp_path / "out.json").read_text())
    assert written == json.loads(record_path(plan_fleet(fleet)).read_text())
    assert written["failed"] == ["s2", "s3"] and [s["status"] for s in written["stores"]] == [
        "updated", "updated", "failed", "failed"]

    assert cli.main(["status", str(fleet)]) == 1
    text = capsys.readouterr().out
    rows = {line.split()[0]: line.split() for line in text.splitlines()[2:6]}
    assert rows["s0"][1:] == ["semc", "2", "d2.csv", "0", "-", "0"]
    assert rows["s2"][1:] == ["semc", "1", "d1.csv", "1", "-", "1"]
    assert rows["s3"][1:] == ["semc", "0", "-", "2", "-", "2"]
    assert "s3: " + str(fleet / "s3" / "d2.csv") + ": column 'y' has 1 NaN/inf value(s)" in text
    assert "s2: the last fleet update (" in text and "raised RuntimeError: sensor model out of range" in text

    from seqbayes.store import RunStore
    from seqbayes.store.base import AlarmState

    monkeypatch.setattr(RunStore, "alarm_state", lambda self: AlarmState(self.n_steps == 2, 2 if self.n_steps == 2
                                                                          else None, "a drop in storey 2"))
    assert cli.main(["status", str(fleet), "--json"]) == 1
    status = json.loads(capsys.readouterr().out)
    by_name = {s["name"]: s for s in status["stores"]}
    assert by_name["s0"]["alarm"] == {"raised": True, "step": 2, "text": "a drop in storey 2"}
    assert by_name["s2"]["alarm"] == {"raised": False, "step": None, "text": "a drop in storey 2"}
    assert by_name["s1"]["steps"] == 2 and by_name["s1"]["errors"] == [] and by_name["s1"]["pending"] == 0
    assert by_name["s2"]["last_update"]["status"] == "failed" and len(by_name["s3"]["errors"]) == 2
    assert status["with_errors"] == ["s2", "s3"] and status["alarms"] == ["s0", "s1"]
    assert cli.main(["status", str(fleet)]) == 1
    assert "s0: alarm at step 2: a drop in storey 2" in capsys.readouterr().out


@pytest.mark.slow
def test_a_manifest_fleet_and_the_options_of_the_two_forms(fleet_root, reference, tmp_path, capsys):
    fleet = fresh(fleet_root, tmp_path / "fleet")
    manifest = tmp_path / "fleet.toml"
    manifest.write_text('[[store]]\npath = "fleet/s1.nc"\ndatasets = ["fleet/s1/d1.csv", "fleet/s1/d2.csv"]\n'
                        '[[store]]\npath = "fleet/s0.nc"\ndatasets = "fleet/s0"\n')
    assert cli.main(["update", str(manifest), "--workers", "0"]) == 0
    assert ": 2 updated (4 datasets)" in capsys.readouterr().out
    assert store_fingerprint(fleet / "s0.nc") == reference["s0"] and store_fingerprint(fleet / "s1.nc") == \
        reference["s1"]
    assert (tmp_path / ".fleet.toml.outcome.json").is_file()
    assert cli.main(["status", str(manifest), "--json"]) == 0
    assert [s["steps"] for s in json.loads(capsys.readouterr().out)["stores"]] == [2, 2]


def test_the_options_of_the_two_forms_are_refused_in_one_line(fleet_root, tmp_path, capsys):
    fleet = fresh(fleet_root, tmp_path / "fleet")
    manifest = tmp_path / "fleet.toml"
    manifest.write_text('[[store]]\npath = "fleet/s0.nc"\ndatasets = "fleet/s0"\n')
    before = {p: sha(p) for p in sorted(fleet.rglob("*")) if p.is_file()}
    for args, message in [
        (["update", str(manifest), str(fleet / "s0" / "d1.csv")], "a fleet takes no DATAFILE"),
        (["update", str(manifest), "--replace-last"], "a fleet takes no --replace-last"),
        (["update", str(fleet / "s0.nc")], "update: give the data files to assimilate after RUN"),
        (["update", str(fleet / "s0.nc"), str(fleet / "s0" / "d1.csv"), "--workers", "2"],
         "--workers: only for a fleet update"),
        (["update", str(manifest), "--workers", "2", "--scheduler", "tcp://127.0.0.1:1"],
         "--workers: the cluster at --scheduler has its own workers"),
        (["update", str(tmp_path / "empty.json")], "empty.json: no such file"),
        (["update", str(tmp_path / "nowhere")], "nowhere: no such run store or fleet folder"),
    ]:
        assert cli.main(args) == 2, args
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and message in err, (args, err)
    for option, value, message in [("--workers", "-1", "argument --workers: expected an integer >= 0"),
                                   ("--workers", "257", "argument --workers: expected an integer >= 0 and <= 256"),
                                   ("--workers", "two", "argument --workers: expected an integer, got 'two'"),
                                   ("--lock-timeout", "-3", "argument --lock-timeout: expected a number >= 0")]:
        with pytest.raises(SystemExit) as stop:      # the parser's bounds: one line too
            cli.main(["update", str(manifest), option, value])
        err = capsys.readouterr().err
        assert stop.value.code == 2 and len(err.strip().splitlines()) == 1 and message in err, (value, err)
    assert {p: sha(p) for p in sorted(fleet.rglob("*")) if p.is_file()} == before


# ------------------------------------------------------------------------------ the fleet's outputs
def test_an_output_target_that_is_an_input_or_a_foreign_file_is_refused_and_no_store_is_touched(
        fleet_root, tmp_path, capsys):
    fleet = fresh(fleet_root, tmp_path / "fleet")
    before = {p: sha(p) for p in sorted(fleet.rglob("*")) if p.is_file()}
    foreign = tmp_path / "notes.json"
    foreign.write_text('{"mine": 1}\n')
    pipe = tmp_path / "pipe.json"
    os.mkfifo(pipe)
    for target, message in [
        (fleet / "s0" / "d1.csv", "is the input"),
        (fleet / "s1.nc", "is the run store"),
        (fleet / "s1.nc.lock", "is the run store's lock"),
        (fleet / ".s1.nc.journal", "is the run store's journal"),
        (pipe, "is not a regular file (a FIFO, a device or a socket)"),
        (foreign, "exists and is not a file this command wrote; give another name, or --force"),
        (fleet / "s0", "is a folder"),
        (tmp_path / "missing" / "out.json", "does not exist"),
    ]:
        assert cli.main(["update", str(fleet), "--workers", "0", "--json", str(target)]) == 2, target
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and message in err, (target, err)
        after = {p: sha(p) for p in sorted(fleet.rglob("*")) if p.is_file()}
        assert after == before, target                    # no store, lock or data file touched or created
    assert foreign.read_text() == '{"mine": 1}\n'
    assert not list(tmp_path.rglob("*.tmp-*"))
    assert cli.main(["update", str(fleet), "--workers", "0", "--json", str(foreign), "--force"]) == 1   # s2, s3 fail
    assert json.loads(foreign.read_text())["seqbayes_fleet_outcome"] == 1


@pytest.mark.slow
def test_a_damaged_record_is_said_by_status_and_replaced_by_the_next_update(fleet_root, tmp_path, capsys):
    fleet = fresh(fleet_root, tmp_path / "fleet")
    record = record_path(plan_fleet(fleet))
    record.write_text('{"seqbayes_fleet_outcome": 1, "stores": [{"na')        # torn (not by seqbayes)
    assert cli.main(["status", str(fleet)]) == 1
    assert "record: " + str(record) + ": not a fleet update's record (damaged" in capsys.readouterr().out
    tasks = [t for t in plan_fleet(fleet).tasks if t.name == "s1"]
    (fleet / "s0").rename(tmp_path / "away0")
    for name in ("s2", "s3"):
        (fleet / f"{name}.nc").unlink()
        shutil.rmtree(fleet / name)
    assert tasks and cli.main(["update", str(fleet), "--workers", "0"]) == 0
    assert json.loads(record.read_text())["failed"] == []


def test_status_to_a_full_disk_is_one_line(fleet_root, tmp_path, capsys, monkeypatch):
    fleet = fresh(fleet_root, tmp_path / "fleet")
    full = open("/dev/full", "w")
    monkeypatch.setattr("sys.stdout", full)
    try:
        code = cli.main(["status", str(fleet), "--json"])
    finally:
        monkeypatch.undo()
        with pytest.raises(OSError):
            full.close()
    err = capsys.readouterr().err
    assert code == 2 and err.strip() == "seqbayes status: error: No space left on device"


@pytest.mark.slow
def test_an_outcome_that_cannot_be_written_after_the_run_is_one_line(fleet_root, reference, tmp_path, capsys,
                                                                     monkeypatch):
    """The room was taken before the run; should the write fail anyway, the line says the stores were
    updated, and the previous record stays whole."""
    fleet = fresh(fleet_root, tmp_path / "fleet")
    for name in ("s2", "s3"):
        (fleet / f"{name}.nc").unlink()
        shutil.rmtree(fleet / name)
    assert cli.main(["update", str(fleet), "--workers", "0"]) == 0
    record = record_path(plan_fleet(fleet))
    kept = record.read_bytes()
    write_table(fleet / "s0" / "d3.csv", np.column_stack([np.linspace(0, 1, 8), np.ones(8)]))

    from types import SimpleNamespace

    from seqbayes.store import targets

    def no_room(path):    # the disk filled after the room was taken: write_output's own check sees it
        return SimpleNamespace(total=1 << 30, used=1 << 30, free=0)
    monkeypatch.setattr(targets, "shutil", SimpleNamespace(disk_usage=no_room))
    assert cli.main(["update", str(fleet), "--workers", "0"]) == 2
    errors = [line for line in capsys.readouterr().err.splitlines() if " warning: " not in line]
    assert len(errors) == 1 and errors[0].startswith(f"seqbayes update: error: the fleet's record {record}: not "
                                                     f"enough free space in {fleet}")
    assert errors[0].endswith("(No space left on device); nothing was written; the stores "
                              "were updated as the lines above say"), errors[0]
    assert record.read_bytes() == kept and not list(fleet.glob(".*.tmp-*"))
    from seqbayes.store import RunStore

    assert RunStore.open(fleet / "s0.nc").n_steps == 3


# ------------------------------------------------------------- full and read-only disks (a small tmpfs)
from test_hardening import fill, small_disk  # noqa: E402,F401  (the store's own fixture: a 2 MiB tmpfs)


def test_json_targets_on_a_full_or_read_only_disk_are_one_line_and_touch_no_store(fleet_root, tmp_path,
                                                                                  small_disk, capsys):
    import subprocess

    fleet = fresh(fleet_root, tmp_path / "fleet")
    before = {p: sha(p) for p in sorted(fleet.rglob("*")) if p.is_file()}
    fill(small_disk, 4096)
    assert cli.main(["update", str(fleet), "--workers", "0", "--json", str(small_disk / "out.json")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1
    assert f"--json {small_disk / 'out.json'}: cannot take" in err and "No space left on device" in err
    assert "no store was touched" in err
    (small_disk / "filler").unlink()
    subprocess.run(["mount", "-o", "remount,ro", str(small_disk)], check=True)
    assert cli.main(["update", str(fleet), "--workers", "0", "--json", str(small_disk / "out.json")]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "cannot write in" in err and "Read-only file system" in err
    assert {p: sha(p) for p in sorted(fleet.rglob("*")) if p.is_file()} == before   # nothing created either
    assert list(small_disk.iterdir()) == []


@pytest.mark.slow
def test_a_fleet_on_a_full_or_read_only_disk_refuses_before_touching_a_store(fleet_root, small_disk, capsys):
    """The fleet's own record lies in its folder: no room or no write access there is one line up front."""
    import subprocess

    fleet = small_disk / "fleet"
    fleet.mkdir()
    for name in ("s0", "s1"):
        shutil.copyfile(fleet_root / "fleet" / f"{name}.nc", fleet / f"{name}.nc")
        shutil.copytree(fleet_root / "fleet" / name, fleet / name)
    before = {p: sha(p) for p in sorted(fleet.rglob("*")) if p.is_file()}
    fill(small_disk, 16 * 1024)                              # less than the record's room (64 KiB + per store)
    assert cli.main(["update", str(fleet), "--workers", "0"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "the fleet's record" in err and "No space left on device" in err
    assert {p: sha(p) for p in sorted(fleet.rglob("*")) if p.is_file()} == before
    (small_disk / "filler").unlink()
    subprocess.run(["mount", "-o", "remount,ro", str(small_disk)], check=True)
    assert cli.main(["update", str(fleet), "--workers", "0"]) == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "Read-only file system" in err and "no store was touched" in err
    assert cli.main(["status", str(fleet)]) == 0               # reading needs no write access
    assert "0 stores with errors" in capsys.readouterr().out


@pytest.mark.slow
def test_an_sg_enmcmc_store_in_g_resumes_in_a_fleet_as_serial_updates(tmp_path):
    """Another backend through the same task: an SG-EnMCMC store whose blocks are in g (its recorded digests are
    of the SI blocks, BaseStore.digest_of as SGRunStore defines it), its first block assimilated before the
    fleet runs; the fleet skips that block and ends with the store a serial update of all three gives."""
    from test_sgstore import TOML, assert_same_store, record

    from seqbayes.store import load_config
    from seqbayes.structural.structures.records import UNITS

    (tmp_path / "g.toml").write_text(TOML.replace('time = "t"', 'time = "t"\nunits = "g"'))
    config = load_config(tmp_path / "g.toml")
    t, ag, y = record(config)
    table = np.column_stack([t, ag / UNITS["g"], y / UNITS["g"]])
    fleet = tmp_path / "fleet"
    (fleet / "bldg").mkdir(parents=True)
    for k, block in enumerate(np.array_split(table, 3)):
        np.savetxt(fleet / "bldg" / f"b{k + 1}.csv", block, delimiter=",", header="t,ag,a1,a2", comments="",
                   fmt="%.17g")
    blocks = [str(fleet / "bldg" / f"b{k}.csv") for k in (1, 2, 3)]
    for run in (fleet / "bldg.nc", tmp_path / "serial.nc"):
        assert cli.main(["init", str(tmp_path / "g.toml"), str(run)]) == 0
    assert cli.main(["update", str(tmp_path / "serial.nc"), *blocks]) == 0
    assert cli.main(["update", str(fleet / "bldg.nc"), blocks[0]]) == 0
    (outcome,) = run_serial(plan_fleet(fleet).tasks)
    assert outcome.status == "updated" and outcome.skipped == ("b1.csv",) and [s.step for s in outcome.steps] == [2, 3]
    assert_same_store(fleet / "bldg.nc", tmp_path / "serial.nc")
