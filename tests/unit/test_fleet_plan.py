"""The fleet's pure parts: the planner (folder and manifest), the outcome records, the pending datasets.

No store is opened and nothing runs a sampler here, so every test takes milliseconds.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from types import SimpleNamespace

import pytest

from seqbayes.fleet import (FleetError, StepOutcome, StoreOutcome, StoreTask, collect, is_fleet, pending_datasets,
                            plan_fleet)
from seqbayes.fleet.outputs import record_path
from seqbayes.fleet.plan import natural_key
from seqbayes.fleet.records import OUTCOME_MARKER


def touch(path: Path, text: str = "t,y\n0,1\n") -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(text)
    return path


# ----------------------------------------------------------------------------- the folder convention
def test_a_folder_pairs_each_store_with_its_folder_of_datasets_in_natural_order(tmp_path):
    for name in ("b.nc", "a.nc", "c10.nc", "c9.nc"):
        touch(tmp_path / name, "")
    for name in ("d10.csv", "d2.csv", "d1.nc", "notes.txt", ".d3.csv.swp", ".hidden.csv"):
        touch(tmp_path / "a" / name)
    (tmp_path / "a" / "archive").mkdir()
    touch(tmp_path / "a" / "archive" / "d0.csv")            # sub-folders are not looked at
    touch(tmp_path / "b" / "README")
    touch(tmp_path / ".a.nc.journal", "")                    # a store's side files are not stores
    touch(tmp_path / "a.nc.lock", "")
    touch(tmp_path / "mymodel.py", "")
    (tmp_path / "__pycache__").mkdir()
    plan = plan_fleet(tmp_path)
    assert plan.kind == "folder" and plan.source == tmp_path
    assert [t.name for t in plan.tasks] == ["a", "b", "c9", "c10"]
    a, b, c9, _ = plan.tasks
    assert [p.name for p in a.datasets] == ["d1.nc", "d2.csv", "d10.csv"]
    assert all(p.is_absolute() for p in a.datasets) and a.store == tmp_path / "a.nc"
    assert a.ignored == ("notes.txt",) and a.problem is None
    assert b.datasets == () and b.ignored == ("README",)
    assert c9.datasets == () and c9.problem is None          # a store without a folder has nothing new
    assert is_fleet(tmp_path) and not is_fleet(tmp_path / "a.nc")
    assert is_fleet(tmp_path / "fleet.toml") and is_fleet(tmp_path / "fleet.JSON")


def test_a_folder_of_datasets_without_its_store_is_a_problem_of_that_entry_only(tmp_path):
    touch(tmp_path / "a.nc", "")
    touch(tmp_path / "orphan" / "d1.csv")
    (tmp_path / "empty").mkdir()                             # no data files: not an entry
    plan = plan_fleet(tmp_path)
    assert [t.name for t in plan.tasks] == ["a", "orphan"]
    assert plan.tasks[0].problem is None
    assert "a folder of datasets without its store orphan.nc beside it" in plan.tasks[1].problem
    assert "seqbayes init" in plan.tasks[1].problem


def test_natural_order_compares_numbers_as_numbers():
    names = ["2026-11-10.csv", "2026-11-9.csv", "d100.csv", "d20.csv", "d3.csv", "a.csv"]
    assert sorted(names, key=natural_key) == ["2026-11-9.csv", "2026-11-10.csv", "a.csv", "d3.csv", "d20.csv",
                                              "d100.csv"]


# ------------------------------------------------------------------------------------- manifests
def test_a_toml_manifest_lists_stores_with_files_or_a_folder(tmp_path):
    touch(tmp_path / "data" / "t3" / "x2.csv")
    touch(tmp_path / "data" / "t3" / "x1.csv")
    manifest = touch(tmp_path / "fleet.toml", """
[[store]]
path = "stores/bridge-17.nc"
datasets = ["data/b17/2026-11-02.csv", "data/b17/2026-11-01.csv"]
[[store]]
path = "stores/tower-3.nc"
datasets = "data/t3"
name = "tower 3"
[[store]]
path = "/abs/elsewhere.nc"
""")
    plan = plan_fleet(manifest)
    assert plan.kind == "manifest"
    bridge, tower, other = plan.tasks
    assert bridge.name == "bridge-17" and bridge.store == tmp_path / "stores" / "bridge-17.nc"
    # the manifest's order is kept (it is the user's), not sorted
    assert [p.name for p in bridge.datasets] == ["2026-11-02.csv", "2026-11-01.csv"]
    assert tower.name == "tower 3" and [p.name for p in tower.datasets] == ["x1.csv", "x2.csv"]
    assert other.store == Path("/abs/elsewhere.nc") and other.datasets == ()
    assert os.path.realpath(manifest) in plan.inputs and os.path.realpath(bridge.datasets[0]) in plan.inputs
    assert os.path.realpath(tmp_path / "stores" / ".bridge-17.nc.journal") in plan.inputs
    assert record_path(plan) == tmp_path / ".fleet.toml.outcome.json"


def test_a_json_manifest_is_the_same_plan(tmp_path):
    touch(tmp_path / "fleet.json", json.dumps({"store": [{"path": "s.nc", "datasets": ["a.csv", "b.csv"]}]}))
    (task,) = plan_fleet(tmp_path / "fleet.json").tasks
    assert task == StoreTask("s", tmp_path / "s.nc", (tmp_path / "a.csv", tmp_path / "b.csv"))


def test_a_missing_folder_of_datasets_is_that_store_s_problem(tmp_path):
    touch(tmp_path / "fleet.toml", '[[store]]\npath = "a.nc"\ndatasets = "nowhere"\n[[store]]\npath = "b.nc"\n')
    a, b = plan_fleet(tmp_path / "fleet.toml").tasks
    assert "nowhere: no such folder of datasets (store[1] of" in a.problem and b.problem is None


@pytest.mark.parametrize("content, message", [
    ('[[store]]\npath = "a.nc"\ndatasets = ["x.csv"]\nseed = 3\n', r"store\[1\]: unknown key 'seed'"),
    ('[[store]]\ndatasets = ["x.csv"]\n', r"store\[1\].path: expected the run store's file name"),
    ('[[store]]\npath = "a.nc"\ndatasets = [1, 2]\n', r"store\[1\].datasets: expected a list of data file names"),
    ('[[store]]\npath = "a.nc"\n[[store]]\npath = "./a.nc"\n', r"store\[2\].path: ./a.nc is the same store as "
                                                               r"store\[1\]"),
    ('[[store]]\npath = "x/a.nc"\n[[store]]\npath = "y/a.nc"\n', r"two stores are called 'a'"),
    ('[[store]]\npath = "a.nc"\nname = ""\n', r"store\[1\].name: expected a short text"),
    ('[fleet]\nname = "x"\n', r"unknown key 'fleet'"),
    ('store = 3\n', r"store: expected a list of entries"),
    ('[[store]\npath = "a.nc"\n', r"the fleet manifest does not parse"),
])
def test_a_bad_manifest_is_one_line_naming_the_entry(tmp_path, content, message):
    touch(tmp_path / "fleet.toml", content)
    with pytest.raises(FleetError, match=message):
        plan_fleet(tmp_path / "fleet.toml")


def test_manifests_that_are_not_files_are_refused_without_waiting(tmp_path):
    with pytest.raises(FleetError, match="missing.toml: no such file"):
        plan_fleet(tmp_path / "missing.toml")
    os.mkfifo(tmp_path / "pipe.toml")
    with pytest.raises(FleetError, match=r"is a FIFO \(named pipe\), not a regular file; a fleet manifest is read"):
        plan_fleet(tmp_path / "pipe.toml")          # a FIFO: refused at once, not waited on
    (tmp_path / "binary.json").write_bytes(b"\xff\xfe{}")
    with pytest.raises(FleetError, match="not UTF-8 text"):
        plan_fleet(tmp_path / "binary.json")
    touch(tmp_path / "list.json", "[1, 2]")
    with pytest.raises(FleetError, match="expected a table of"):
        plan_fleet(tmp_path / "list.json")
    with pytest.raises(FleetError, match="a fleet is a folder of run stores or a .toml/.json manifest"):
        plan_fleet(touch(tmp_path / "store.nc", ""))


# -------------------------------------------------------------------------------- outcome records
def outcome(name, status="updated", n=2, **fields):
    steps = tuple(StepOutcome(f"d{s}.csv", s, f"step {s} from d{s}.csv: ...") for s in range(1, n + 1))
    return StoreOutcome(name, f"/f/{name}.nc", status, steps if status != "current" else (), n_steps=n, **fields)


def test_outcomes_say_what_they_are_and_refuse_contradictions():
    assert outcome("a").line() == "a: 2 datasets assimilated (steps 1-2) in 0.0 s"
    assert outcome("a", n=1).line() == "a: 1 dataset assimilated (step 1) in 0.0 s"
    assert outcome("a", "current", skipped=("d1.csv",)).line() == ("a: up to date (2 steps, 1 of its datasets "
                                                                     "already assimilated)")
    failed = outcome("a", "failed", n=1, error="d2.csv: bad")
    assert failed.line() == "a: FAILED (1 dataset assimilated before it): d2.csv: bad" and not failed.ok
    with pytest.raises(ValueError, match="a failed outcome needs its error line"):
        StoreOutcome("a", "a.nc", "failed")
    with pytest.raises(ValueError, match="an outcome of status 'updated' has no error line"):
        StoreOutcome("a", "a.nc", "updated", error="x")
    with pytest.raises(ValueError, match="status: expected"):
        StoreOutcome("a", "a.nc", "done")
    with pytest.raises(ValueError, match="a current store's task assimilated nothing"):
        StoreOutcome("a", "a.nc", "current", steps=(StepOutcome("d1.csv", 1, "..."),))
    with pytest.raises(AttributeError):
        failed.error = None                                        # frozen


def test_collect_orders_by_the_plan_and_reports_a_missing_outcome():
    tasks = [StoreTask(n, Path(f"/f/{n}.nc")) for n in ("a", "b", "c")]
    fleet = collect(tasks, [outcome("c"), outcome("a", "failed", n=0, error="x")], source="/f", seconds=2.0)
    assert [o.name for o in fleet.outcomes] == ["a", "b", "c"]
    assert [o.status for o in fleet.outcomes] == ["failed", "failed", "updated"]
    assert "no outcome came back for it" in fleet.outcomes[1].error
    assert fleet.exit_code == 1 and [o.name for o in fleet.failed] == ["a", "b"]
    assert fleet.stores_per_minute() == 90.0
    assert fleet.summary() == "3 stores of /f: 1 updated (2 datasets), 0 up to date, 2 failed; 2.0 s"
    content = json.loads(json.dumps(fleet.to_json()))
    assert content[OUTCOME_MARKER] == 1 and content["failed"] == ["a", "b"]
    assert content["stores"][2]["steps"][1] == {"source": "d2.csv", "step": 2, "summary": "step 2 from d2.csv: ...",
                                                "warnings": []}
    assert collect(tasks, [outcome(n) for n in "abc"], source="/f").exit_code == 0
    with pytest.raises(ValueError, match="two outcomes for the store 'a'"):
        collect(tasks, [outcome("a"), outcome("a")])
    with pytest.raises(ValueError, match="'z' is not a store of the plan"):
        collect(tasks, [outcome("z")])


# ----------------------------------------------------------------------------- pending datasets
class HeldStore(SimpleNamespace):
    """What pending_datasets asks of a store: the digests it holds and the digest of a table."""

    def digest_of(self, table):
        return f"h{table}"


def test_datasets_the_store_holds_are_skipped_when_they_lead_the_list_in_its_order():
    store = HeldStore(digests=["h0", "h1", "h2"])
    pending, skipped = pending_datasets(store, ["d1", "d2", "d3", "d4"], [1, 2, 3, 4])
    assert pending == [("d3", 3), ("d4", 4)] and skipped == ["d1", "d2"]
    assert pending_datasets(store, ["d1"], [1]) == ([], ["d1"])
    assert pending_datasets(HeldStore(digests=[]), ["d1"], [1]) == ([("d1", 1)], [])


@pytest.mark.parametrize("tables, message", [
    ([3, 1], r"d2: already assimilated as step 2, although d1, before it in the list, is not"),
    ([2, 1], r"d2: assimilated as step 2, before d1 \(step 3\), which the list puts first"),
    ([3, 3], r"d2: the same data as d1, earlier in the list"),
])
def test_a_list_that_contradicts_the_store_s_order_assimilates_nothing(tables, message):
    with pytest.raises(ValueError, match=message + ".*nothing was assimilated"):
        pending_datasets(HeldStore(digests=["h0", "h1", "h2"]), ["d1", "d2"], tables)
