"""Suite-wide set-up: ``tests/`` on ``sys.path``, a CPU-time report, and long runs shared by the tests
that read them.

``tests/`` goes on ``sys.path`` so the test files can ``import _user_model`` (and ``_shared_runs``)
whichever ``--import-mode`` pytest runs with (the default, "prepend", already does it for this file).
BLAS runs one thread per process (``OPENBLAS_NUM_THREADS=1`` unless set): the workers use the cores.

**CPU time per test** (``pytest --cpu-durations=25``): the CPU seconds of each test's setup, call and
teardown, with the worker processes and subprocesses it waited for, the slowest first, and the
total. Wall durations (``--durations``) on a shared machine measure the load as much as the test;
CPU time does not. ``make test`` prints both.

**A long run shared by several tests** (a study, a long stream, a docs page's run): compute it once
per test run, in a session fixture through :func:`_shared_runs.shared_run`, and list the fixture in
:data:`SHARED_RUN_FIXTURES` here. Every test that uses the fixture then gets the pytest-xdist group of
that name, and ``make test`` runs with ``--dist loadgroup``, so the readers of one run share one
worker and the run is computed once, not once per worker (a session fixture runs once per worker).
``shared_run`` also keeps the result in a file keyed by the code's hash, under a lock, so a second
worker that does need it waits for the first one's file instead of recomputing it::

    # tests/conftest.py (or the one test module that reads it)
    @pytest.fixture(scope="session")
    def oma_campaign_study():
        return shared_run("oma-campaign", oma_study.run, n_records=12, seed=3)

    SHARED_RUN_FIXTURES = {..., "oma_campaign_study"}

A run read by the tests of one module only can stay a module fixture; list it here as well, so
that the module's tests stay on one worker. A result must pickle (xarray Datasets, dataclasses of
arrays and the samplers' results do).
"""

from __future__ import annotations

import os
import resource
import sys
from pathlib import Path

# One BLAS thread per process, set before anything imports numpy: the pytest-xdist workers already use
# every core, and OpenBLAS's own threads would compete with them (and spin while they wait).
for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_variable, "1")

import pytest  # noqa: E402

if str(Path(__file__).parent) not in sys.path:
    sys.path.insert(0, str(Path(__file__).parent))

import _shared_runs  # noqa: E402
from _shared_runs import shared_run  # noqa: E402

#: Fixtures that are long runs read by several tests: their readers get one pytest-xdist group
#: (``--dist loadgroup``), named after the fixture. A session fixture (defined here) by its name; a
#: module's own fixture as ``path::name``.
SHARED_RUN_FIXTURES = {"oscillator_reduced_study", "tests/studies/test_coulomb_study.py::study"}


# ---------------------------------------------------------------- shared long runs

@pytest.fixture(scope="session")
def oscillator_reduced_study():
    """The reduced damped-oscillator study (2 runs x 6 kernels x 2 samplers, N = 300, seed 0, one
    process): docs/damped_oscillator.md shows its account (``tools/docgen.py oscillator_reduced``) and
    tests/studies/test_oscillator_study.py checks its T1 and T2 part."""
    from seqbayes.studies import oscillator

    return shared_run("oscillator-reduced", oscillator.run_study, **_docgen().OSCILLATOR_REDUCED)


def _docgen():
    """tools/docgen.py, which holds the settings of the runs the docs show."""
    tools = str(Path(__file__).resolve().parents[1] / "tools")
    sys.path.insert(0, tools)
    try:
        import docgen
    finally:
        sys.path.remove(tools)
    return docgen


def pytest_configure(config):
    cache = getattr(config, "cache", None)
    if cache is not None:   # without it (-p no:cacheprovider) a run is kept in each process's memory only
        _shared_runs.configure(cache.mkdir("shared-runs"))


def pytest_collection_modifyitems(config, items):
    root = Path(__file__).resolve().parents[1]
    for item in items:
        names = set(getattr(item, "fixturenames", ()))
        module = Path(str(item.fspath)).resolve().relative_to(root).as_posix() if item.fspath else ""
        names |= {f"{module}::{name}" for name in names}
        for group in sorted(SHARED_RUN_FIXTURES & names):
            item.add_marker(pytest.mark.xdist_group(group))
            break


# ---------------------------------------------------------------- CPU time per test

def pytest_addoption(parser):
    parser.addoption("--cpu-durations", type=int, default=None, metavar="N",
                     help="report the N tests of largest CPU time (setup + call + teardown, with their "
                          "subprocesses), and the total; 0 for every test")


def _cpu_seconds() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_setup(item):
    item._cpu_start = _cpu_seconds()
    yield


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item, call):
    outcome = yield
    report = outcome.get_result()
    start = getattr(item, "_cpu_start", None)
    if start is not None:
        now = _cpu_seconds()
        report.user_properties.append(("cpu_seconds", now - start))
        item._cpu_start = now


_CPU: dict[str, float] = {}


def pytest_runtest_logreport(report):
    for key, value in report.user_properties:
        if key == "cpu_seconds":
            _CPU[report.nodeid] = _CPU.get(report.nodeid, 0.0) + value


def pytest_terminal_summary(terminalreporter, exitstatus, config):
    count = config.getoption("--cpu-durations")
    if count is None or not _CPU:
        return
    ranked = sorted(_CPU.items(), key=lambda kv: -kv[1])
    shown = ranked if count == 0 else ranked[:count]
    terminalreporter.write_sep("=", f"largest CPU times ({len(shown)} of {len(ranked)} tests)")
    for nodeid, seconds in shown:
        terminalreporter.write_line(f"{seconds:8.2f}s cpu  {nodeid}")
    total = sum(_CPU.values())
    terminalreporter.write_line(f"{total:8.1f}s cpu  in all tests ({total / 60:.1f} CPU minutes), "
                                f"at load {os.getloadavg()[0]:.1f} now")
