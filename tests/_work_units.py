"""pytest-xdist work units: the tests that read one long run go to one worker, the slow ones first.

pytest-xdist's ``--dist loadgroup`` groups tests by the ``xdist_group`` mark through a suffix that it writes
into each item's node id; pytest 9.2 builds node ids from a structured record instead, so the suffix is
lost and every test became its own unit (pytest-xdist issue 1386, open): a module's fixture was computed
on both workers, and the Coulomb study twice. This module does the grouping itself, without touching
node ids:

- each worker, after collection, writes ``{node id: unit}`` to a file named by the test run's id
  (:func:`write_units`, from ``tests/conftest.py``'s ``pytest_collection_modifyitems``);
- the controller's scheduler (:func:`make_scheduler`, from conftest's ``pytest_xdist_make_scheduler``)
  reads it when every worker has collected, and sends each unit whole to one worker.

Two tests are in one unit when they read a common fixture that is computed once per module, class or
session: every such fixture defined in a test module, and the conftest fixtures named in
``SHARED_RUN_FIXTURES`` (pytest's own session fixtures, like ``tmp_path_factory``, group nothing). A test
in no unit with others is a unit alone. Units that hold a test marked ``slow`` are sent first, the
largest first, so that a long test does not start at the end of the run while the other worker idles.
"""

from __future__ import annotations

import inspect
import json
import tempfile
from pathlib import Path

_SHARED_SCOPES = {"class", "module", "package", "session"}


def _directory() -> Path:
    path = Path(tempfile.gettempdir()) / "seqbayes-xdist-units"
    path.mkdir(exist_ok=True)
    return path


def _fixture_keys(item, root: Path, shared_names: set[str]) -> set[str]:
    """The once-computed fixtures ``item`` reads, as ``path::name``."""
    keys = set()
    info = getattr(item, "_fixtureinfo", None)
    for name, definitions in (info.name2fixturedefs.items() if info is not None else ()):
        if not definitions:
            continue
        fixturedef = definitions[-1]                 # the one that applies to this item (the innermost)
        if fixturedef.scope not in _SHARED_SCOPES:
            continue
        try:
            source = Path(inspect.getsourcefile(fixturedef.func)).resolve()
            where = source.relative_to(root).as_posix()
        except (TypeError, ValueError):              # a plugin's fixture, outside the tests
            continue
        if source.name == "conftest.py" and name not in shared_names:
            continue
        if source.name != "conftest.py" and not source.name.startswith("test_"):
            continue
        keys.add(f"{where}::{name}")
    return keys


def units(items, root: Path, shared_names: set[str]) -> dict[str, str]:
    """``{node id: unit name}`` for the tests that share a fixture with another (union over shared fixtures)."""
    parent: dict[str, str] = {}

    def find(x):
        while parent.setdefault(x, x) != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    keyed = {}
    for item in items:
        keys = sorted(_fixture_keys(item, root, shared_names))
        if keys:
            keyed[item.nodeid] = keys
            for key in keys[1:]:
                a, b = find(keys[0]), find(key)
                if a != b:
                    parent[max(a, b)] = min(a, b)
    counts: dict[str, int] = {}
    for keys in keyed.values():
        counts[find(keys[0])] = counts.get(find(keys[0]), 0) + 1
    return {nodeid: find(keys[0]) for nodeid, keys in keyed.items() if counts[find(keys[0])] > 1}


def write_units(config, items, root: Path, shared_names: set[str]) -> None:
    """On a pytest-xdist worker: the units and the slow tests of its collection, for the controller."""
    workerinput = getattr(config, "workerinput", None)
    if workerinput is None:
        return
    record = {"units": units(items, root, shared_names),
              "slow": [item.nodeid for item in items if item.get_closest_marker("slow") is not None]}
    target = _directory() / f"{workerinput['testrunuid']}-{workerinput['workerid']}.json"
    partial = target.with_suffix(".tmp")
    partial.write_text(json.dumps(record))
    partial.replace(target)


def make_scheduler(config, log):
    """The controller's scheduler for ``--dist loadgroup`` (any other mode: pytest-xdist's own)."""
    if config.getvalue("dist") != "loadgroup":
        return None
    from collections import OrderedDict

    from xdist.scheduler import LoadScopeScheduling

    class SharedRunScheduling(LoadScopeScheduling):
        """LoadScopeScheduling whose scopes are :func:`units`, the units with slow tests first."""

        _units: dict[str, str] = {}

        def _split_scope(self, nodeid: str) -> str:
            return self._units.get(nodeid, nodeid)

        def _read_units(self) -> set[str]:
            slow: set[str] = set()
            for node in self.nodes:
                path = _directory() / f"{node.workerinput['testrunuid']}-{node.workerinput['workerid']}.json"
                try:
                    record = json.loads(path.read_text())
                except (OSError, ValueError):
                    continue
                finally:
                    path.unlink(missing_ok=True)
                self._units = record["units"]
                slow = set(record["slow"])
            return slow

        def schedule(self) -> None:
            assert self.collection_is_completed
            if self.collection is not None:
                for node in self.nodes:
                    self._reschedule(node)
                return
            if not self._check_nodes_have_same_collection():
                self.log("**Different tests collected, aborting run**")
                return
            self.collection = list(next(iter(self.registered_collections.values())))
            if not self.collection:
                return
            slow = self._read_units()
            queue: dict[str, dict[str, bool]] = {}
            for nodeid in self.collection:
                queue.setdefault(self._split_scope(nodeid), {})[nodeid] = False
            order = sorted(queue.items(), key=lambda kv: (not any(n in slow for n in kv[1]), -len(kv[1])))
            self.workqueue = OrderedDict(order)
            for _ in range(max(0, len(self.nodes) - len(self.workqueue))):
                unused, _assigned = self.assigned_work.popitem()
                unused.shutdown()
            for node in self.nodes:
                self._assign_work_unit(node)
            for node in self.nodes:
                self._reschedule(node)
            if not self.workqueue:
                for node in self.nodes:
                    node.shutdown()

    return SharedRunScheduling(config, log)
