"""tests/_work_units.py: the tests that read one once-computed fixture are one pytest-xdist work unit."""

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

TESTS = Path(__file__).resolve().parents[1]

CONFTEST = f"""
import sys
sys.path.insert(0, {str(TESTS)!r})
import pytest
import _work_units
from pathlib import Path

SHARED_RUN_FIXTURES = {{"shared"}}

@pytest.fixture(scope="session")
def shared():
    return 1

@pytest.fixture(scope="session")
def unlisted():
    return 2

def pytest_collection_modifyitems(config, items):
    _work_units.write_units(config, items, Path(__file__).resolve().parent, SHARED_RUN_FIXTURES)

@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config, log):
    return _work_units.make_scheduler(config, log)
"""

MODULE = """
import os
import pytest

@pytest.fixture(scope="module")
def once():
    return 0

@pytest.mark.parametrize("i", range(4))
def test_reads_the_module_fixture(once, i):
    print("UNIT module-" + __name__, os.environ["PYTEST_XDIST_WORKER"])

@pytest.mark.parametrize("i", range(3))
def test_reads_the_listed_session_fixture(shared, i):
    print("UNIT shared", os.environ["PYTEST_XDIST_WORKER"])

@pytest.mark.parametrize("i", range(6))
def test_alone(unlisted, tmp_path_factory, i):
    print("UNIT alone", os.environ["PYTEST_XDIST_WORKER"])
"""


@pytest.mark.slow
def test_the_readers_of_a_shared_fixture_run_on_one_worker(tmp_path):
    pytest.importorskip("xdist")
    (tmp_path / "conftest.py").write_text(CONFTEST)
    (tmp_path / "test_a.py").write_text(MODULE)
    (tmp_path / "test_b.py").write_text(MODULE.replace("def once", "def once_b").replace("(once,", "(once_b,"))
    done = subprocess.run([sys.executable, "-m", "pytest", "-n", "2", "--dist", "loadgroup", "-rA", "-q",
                           "-p", "no:cacheprovider", "-p", "no:randomly", str(tmp_path)],
                          cwd=tmp_path, capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    seen = {}
    for line in done.stdout.splitlines():
        if "UNIT " in line:
            _, kind, worker = line[line.index("UNIT "):].split()
            seen.setdefault(kind, []).append(worker)
    assert [len(seen[k]) for k in ("module-test_a", "module-test_b", "shared", "alone")] == [4, 4, 6, 12], seen
    # the shared session fixture's readers in both modules: one worker; each module fixture's: one worker each
    assert all(len(set(seen[k])) == 1 for k in ("module-test_a", "module-test_b", "shared")), seen
    # pytest's own session fixtures and a conftest fixture not listed group nothing: both workers take some
    assert set(seen["alone"]) == {"gw0", "gw1"}, seen


class _Def:
    def __init__(self, func, scope):
        self.func, self.scope = func, scope


class _Item:
    def __init__(self, nodeid, **fixtures):
        self.nodeid = nodeid
        self._fixtureinfo = type("Info", (), {"name2fixturedefs": {k: [v] for k, v in fixtures.items()}})()


def test_units_join_the_readers_of_module_fixtures_and_listed_session_fixtures():
    import _work_units

    def module_fixture():   # defined in this test module
        pass

    module = _Def(module_fixture, "module")
    function = _Def(module_fixture, "function")
    listed = _Def(pytest.fixture, "session")          # defined outside the tests: a plugin's
    items = [_Item("a", x=module), _Item("b", x=module, y=function), _Item("c", y=function),
             _Item("d", z=listed), _Item("e", z=listed)]
    units = _work_units.units(items, TESTS.parent, {"z"})
    assert units["a"] == units["b"] == "tests/unit/test_work_units.py::x"
    assert "c" not in units and "d" not in units and "e" not in units   # function scope; a plugin's fixture
