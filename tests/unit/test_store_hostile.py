"""The run store against hostile and careless files (issue 24).

* The likelihood's whole package is hashed, and the bytes hashed are the bytes run.
* The journal is read only as a bounded regular file, opened without following links; a
  committed journal is written into the store by the next command that opens it (so other
  programs read the file whole), and a store that may not be written says so in one line.
* Declared sizes are checked against the file before anything is allocated.
* The journal, the lock and temporary files take the store's permission bits and never follow
  a link; a symlinked store is written through to its target.
* The lock says who holds it and is given up after a timeout; a missing store, a missing folder
  and a symlink loop are one line each.
"""

from __future__ import annotations

import dataclasses
import os
import re
import shutil
import signal
import stat
import warnings

import numpy as np
import pytest

from seqbayes import cli
from seqbayes.store import DataError, ModelChangedError, RunStore, StoreError, load_config
from seqbayes.store import files
from seqbayes.store.errors import StoreLockTimeout, StoreWarning
from seqbayes.store.modules import load_located, locate_module

from _user_model import decay_tables, write_config, write_model
from test_kill_resume import fork_cli, wait


#: a drifting amplitude
DRIFT = 'a = { type = "drift", rate = -0.05, noise_std = 0.02 }'


def config_file(path, module):
    """The decay model's configuration with the drifting amplitude and the transition-density predictive (fast)."""
    path = write_config(path, module, n_samples=24, seed=3, kernel=DRIFT)
    path.write_text(path.read_text() + 'predictive = "transition"\n')
    return path


def tables(n=3, seed=0):
    return decay_tables([1.5 - 0.05 * s for s in range(n)], np.linspace(0, 3, 15), 0.1, seed)


@pytest.fixture(scope="module")
def template(tmp_path_factory):
    """A run of one step, made once and copied by :func:`run_dir` (the tests need its files, not a sampler)."""
    folder = tmp_path_factory.mktemp("template")
    write_model(folder, "hostmodel")
    path = config_file(folder / "run.toml", "hostmodel")
    for k, table in enumerate(tables(3)):
        np.savetxt(folder / f"d{k + 1}.csv", table, delimiter=",", header="t,y", comments="")
    RunStore.create(folder / "run.nc", load_config(path)).update(folder / "d1.csv")
    (folder / "d2.csv").rename(folder / "next.csv")
    return folder


@pytest.fixture
def run_dir(template, tmp_path):
    """A copy of the template run in this test's folder: ``run.nc`` (step 1 from d1.csv), next.csv, d3.csv."""
    for name in ("hostmodel.py", "run.toml", "run.nc", "d1.csv", "next.csv", "d3.csv"):
        shutil.copy(template / name, tmp_path / name)
    return tmp_path


def one_line_error(capsys, argv, pattern):
    assert cli.main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    assert re.search(pattern, err), err
    return err


# --------------------------------------------------------------- the likelihood's package
PACKAGE_MODEL = """
import numpy as np
from . import helper

def loglike(theta, data):
    from . import lazy                      # imported at call time, from the bytes hashed at load
    t, y = data[:, 0], data[:, 1]
    pred = theta[:, [0]] * np.exp(-theta[:, [1]] * t[None, :])
    return -0.5 * np.sum((y - pred) ** 2, axis=1) / helper.NOISE ** 2 + lazy.SHIFT
"""


def write_package(folder, name, noise=0.1, shift=0.0):
    pkg = folder / name
    pkg.mkdir(parents=True, exist_ok=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "model.py").write_text(PACKAGE_MODEL)
    (pkg / "helper.py").write_text(f"NOISE = {noise}\n")
    (pkg / "lazy.py").write_text(f"SHIFT = {shift}\n")


@pytest.mark.slow
def test_an_edit_of_another_file_of_the_package_is_refused(tmp_path):
    write_package(tmp_path, "hostpkg_a")
    config = config_file(tmp_path / "run.toml", "hostpkg_a.model")
    store = RunStore.create(tmp_path / "run.nc", load_config(config))     # records the package's hash
    recorded = store.config.likelihood_sha256
    for edited in ("helper.py", "lazy.py"):       # neither is the named module
        original = (tmp_path / "hostpkg_a" / edited).read_text()
        (tmp_path / "hostpkg_a" / edited).write_text(original.replace("0", "3"))
        with pytest.raises(ModelChangedError, match=r"changed since the run recorded it.*the package of "
                                                    r"\S*model.py \(4 .py files\) has sha256 [0-9a-f]{12}"):
            RunStore.open(tmp_path / "run.nc").assimilate(tables(1)[0], "first")
        (tmp_path / "hostpkg_a" / edited).write_text(original)
    assert RunStore.open(tmp_path / "run.nc").n_steps == 0
    # accepted on purpose: the package's new hash is recorded
    (tmp_path / "hostpkg_a" / "helper.py").write_text("NOISE = 0.2\n")
    store = RunStore.open(tmp_path / "run.nc")
    store.assimilate(tables(1)[0], "first", accept_model_change=True)
    assert store.config.likelihood_sha256 != recorded
    assert RunStore.open(tmp_path / "run.nc").module_hashes[-1] == locate_module("hostpkg_a.model", tmp_path).sha256


def test_a_plain_module_keeps_the_hash_sha256sum_prints(tmp_path):
    import hashlib

    write_model(tmp_path, "hostplain_a")
    found = locate_module("hostplain_a", tmp_path)
    assert found.sha256 == hashlib.sha256((tmp_path / "hostplain_a.py").read_bytes()).hexdigest()
    assert found.legacy_sha256 == found.sha256


def test_a_store_that_recorded_the_named_files_only_goes_on_with_a_warning(tmp_path):
    write_package(tmp_path, "hostpkg_b")
    config = config_file(tmp_path / "run.toml", "hostpkg_b.model")
    store = RunStore.create(tmp_path / "run.nc", load_config(config))
    found = locate_module("hostpkg_b.model", tmp_path)
    assert found.legacy_sha256 != found.sha256
    # what an older seqbayes recorded: the hash of the package's __init__.py and model.py only
    store.config = dataclasses.replace(store.config, likelihood_sha256=found.legacy_sha256)
    store.module_hashes = []
    with pytest.warns(StoreWarning, match="own files only; its package's 4 files are hashed from this step on"):
        store.assimilate(tables(1)[0], "first")
    assert store.config.likelihood_sha256 == found.sha256


def test_the_bytes_that_run_are_the_bytes_that_were_hashed(tmp_path):
    import hashlib

    write_package(tmp_path, "hostpkg_c", noise=0.1, shift=0.0)
    source = locate_module("hostpkg_c.model", tmp_path)
    # another process rewrites the package between the hash and the import (and before a lazy import)
    (tmp_path / "hostpkg_c" / "helper.py").write_text("NOISE = 1000.0\n")
    (tmp_path / "hostpkg_c" / "lazy.py").write_text("SHIFT = 1e9\n")
    (tmp_path / "hostpkg_c" / "model.py").write_text("raise SystemExit('not the hashed bytes')\n")
    loglike = load_located("hostpkg_c.model:loglike", source)
    import sys

    model = sys.modules["hostpkg_c.model"]
    assert model.helper.NOISE == 0.1
    theta, data = np.array([[1.0, 0.4]]), tables(1)[0]
    expected = -0.5 * np.sum((data[:, 1] - np.exp(-0.4 * data[:, 0])) ** 2) / 0.1 ** 2
    assert loglike(theta, data)[0] == pytest.approx(expected, rel=1e-12)   # SHIFT is still 0.0
    assert sys.modules["hostpkg_c.lazy"].SHIFT == 0.0
    assert model.__seqbayes_sha256__ == hashlib.sha256(source.sources["hostpkg_c.model"][1]).hexdigest()
    # located again, the new bytes are hashed and run (the old modules are replaced)
    (tmp_path / "hostpkg_c" / "model.py").write_text(PACKAGE_MODEL)
    again = locate_module("hostpkg_c.model", tmp_path)
    assert again.sha256 != source.sha256
    load_located("hostpkg_c.model:loglike", again)
    assert sys.modules["hostpkg_c.helper"].NOISE == 1000.0


# ------------------------------------------------------------------------- the journal
@pytest.fixture
def alarm():
    """A hang fails the test instead of stalling the suite."""
    def timeout(*_):
        raise TimeoutError("hung")

    old = signal.signal(signal.SIGALRM, timeout)
    signal.alarm(60)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, old)


@pytest.mark.parametrize("kind", ["dev-zero", "fifo", "dangling", "huge"])
def test_a_journal_that_is_not_a_bounded_regular_file_is_never_read(run_dir, kind, alarm):
    run = run_dir / "run.nc"
    journal = files.journal_path(run)
    before = run.read_bytes()
    elsewhere = run_dir / "elsewhere"
    if kind == "dev-zero":
        journal.symlink_to("/dev/zero")
    elif kind == "fifo":
        os.mkfifo(journal)
    elif kind == "dangling":
        journal.symlink_to(elsewhere)
    else:   # a sparse regular file beyond twice the store plus 64 MiB
        with open(journal, "wb") as fh:
            fh.truncate(2 * len(before) + (65 << 20))
    assert files.read_journal(run) is None
    # a reader that may not write the store ignores it (laying nothing over the store)
    assert RunStore.open(run).n_steps == 1
    assert not elsewhere.exists()
    # an update removes the entry itself (never its target) and writes its own journal
    assert cli.main(["update", str(run), str(run_dir / "next.csv")]) == 0
    assert RunStore.open(run).n_steps == 2
    assert not os.path.lexists(journal) and not elsewhere.exists()
    assert os.path.exists("/dev/zero")


def test_a_journal_with_pages_outside_its_size_is_not_a_journal(run_dir):
    run = run_dir / "run.nc"
    size = run.stat().st_size
    good = files._encode_journal(size, size, [(0, run.read_bytes()[:4096])])
    files.journal_path(run).write_bytes(good)
    assert files.read_journal(run) is not None
    for bad in ([(4096, b"x" * 4096)], [(1, b"x")], [(0, b"x" * 5000)]):
        files.journal_path(run).write_bytes(files._encode_journal(size, 4096 if bad[0][0] == 4096 else size, bad))
        assert files.read_journal(run) is None, bad


def killed_with_committed_journal(tmp_path):
    """A store of 1 step whose update of step 2 was killed with half its pages written into the store."""
    run = tmp_path / "run.nc"
    assert wait(fork_cli(["update", str(run), str(tmp_path / "next.csv")], fault="mid-apply")) == -signal.SIGKILL
    assert files.read_journal(run) is not None
    return run


def xarray_steps(run):
    import xarray as xr

    with xr.open_dataset(run, engine="h5netcdf") as ds:
        ds.load()
        return int(ds.attrs["n_steps"]), ds["posterior"].values


def test_the_next_command_that_opens_the_store_completes_the_journal(run_dir, capsys):
    run = killed_with_committed_journal(run_dir)
    assert cli.main(["status", str(run)]) == 0                # any command: here status
    assert "d1.csv" in capsys.readouterr().out
    assert not os.path.lexists(files.journal_path(run))
    n_steps, posterior = xarray_steps(run)                    # other programs read the file whole
    store = RunStore.open(run)
    assert n_steps == store.n_steps == 2
    np.testing.assert_array_equal(posterior, np.stack([s.posterior for s in store.result.steps]))


def test_a_store_that_may_not_be_written_keeps_its_journal_and_says_so(run_dir, monkeypatch):
    run = killed_with_committed_journal(run_dir)
    monkeypatch.setattr(files.os, "access", lambda *a, **k: False)   # as a user without write permission
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        store = RunStore.open(run)
    assert store.n_steps == 2                                 # read through the journal
    [warning] = [w for w in caught if issubclass(w.category, StoreWarning)]
    text = str(warning.message)
    assert "\n" not in text and "could not be written into the store (no permission" in text
    assert files.read_journal(run) is not None
    monkeypatch.undo()
    assert RunStore.open(run).n_steps == 2 and not os.path.lexists(files.journal_path(run))


# ----------------------------------------------------------------------- declared sizes
def test_a_store_declaring_more_than_it_holds_is_refused_before_reading(run_dir):
    import h5py

    run = run_dir / "run.nc"
    with h5py.File(run, "r+") as f:                          # 2.4 GB declared, nothing written
        f.create_dataset("ghost", shape=(300_000_000,), dtype="f8", chunks=(1_000_000,))
    assert run.stat().st_size < 2_000_000
    with pytest.raises(StoreError, match=r"run.nc: damaged run store: its variables declare [\d,]+ bytes "
                                         r"\('ghost' alone \(300000000,\), 2,400,000,000 bytes\), more than the "
                                         r"whole file of [\d,]+ bytes holds"):
        RunStore.open(run)


def test_a_data_file_declaring_more_than_it_holds_is_one_line(run_dir, capsys):
    import h5netcdf

    data = run_dir / "big.nc"
    with h5netcdf.File(data, "w") as f:                      # 2 x 3.2 GB declared in a few KB
        f.dimensions = {"row": 400_000_000}
        for name in ("t", "y"):
            f.create_variable(name, ("row",), "f8", chunks=(1_000_000,))
    assert data.stat().st_size < 100_000
    with pytest.raises(DataError, match=r"big.nc: variable 't' declares 400000000 values \(3,200,000,000 bytes\), "
                                        r"more than the file of [\d,]+ bytes holds"):
        RunStore.open(run_dir / "run.nc").read_datafile(data)
    one_line_error(capsys, ["update", run_dir / "run.nc", data], "declares 400000000 values")


# --------------------------------------------------------------- permissions and links
def test_the_journal_lock_and_temporary_files_take_the_stores_permissions(run_dir, monkeypatch):
    run = run_dir / "run.nc"
    os.chmod(run, 0o600)
    modes = {}
    real_write = files.write_file

    def write_file(path, content, mode=None):
        real_write(path, content, mode)
        modes[path.name.split("-")[0]] = stat.S_IMODE(os.stat(path).st_mode)

    monkeypatch.setattr(files, "write_file", write_file)
    old_umask = os.umask(0o022)
    try:
        RunStore.open(run).update(run_dir / "next.csv")                       # an append: the journal
        RunStore.open(run).update(run_dir / "next.csv", replace_last=True)    # a whole write: the temporary file
    finally:
        os.umask(old_umask)
    assert modes == {".run.nc.journal": 0o600, ".run.nc.tmp": 0o600}
    assert stat.S_IMODE(os.stat(run_dir / "run.nc.lock").st_mode) == 0o600
    assert stat.S_IMODE(os.stat(run).st_mode) == 0o600


def test_a_dangling_lock_link_is_not_followed(run_dir, capsys):
    lock = run_dir / "run.nc.lock"
    lock.symlink_to(run_dir / "elsewhere.lock")
    one_line_error(capsys, ["update", run_dir / "run.nc", run_dir / "next.csv"],
                   r"run.nc.lock is a symbolic link, which seqbayes does not follow \(remove it\)")
    assert not (run_dir / "elsewhere.lock").exists()


def test_a_symlinked_store_is_written_through(run_dir):
    link = run_dir / "link.nc"
    link.symlink_to(run_dir / "run.nc")
    assert cli.main(["update", str(link), str(run_dir / "next.csv"), "--replace-last"]) == 0
    assert link.is_symlink()
    assert RunStore.open(run_dir / "run.nc").sources == ["next.csv"]
    assert cli.main(["update", str(link), str(run_dir / "d1.csv")]) == 0   # an append through the link
    assert link.is_symlink() and RunStore.open(run_dir / "run.nc").sources == ["next.csv", "d1.csv"]
    assert not (run_dir / "link.nc.lock").exists() and not os.path.lexists(run_dir / ".link.nc.journal")


# ------------------------------------------------------------------------------ the lock
def test_a_held_lock_says_who_holds_it_and_is_given_up(run_dir, capsys):
    run = run_dir / "run.nc"
    ready_r, ready_w = os.pipe()
    done_r, done_w = os.pipe()
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child holds the lock until told
        try:
            with files.store_lock(run):
                os.write(ready_w, b"x")
                os.read(done_r, 1)
        finally:
            os._exit(0)
    try:
        assert os.read(ready_r, 1) == b"x"
        said = []
        with pytest.raises(StoreLockTimeout, match=rf"run.nc: gave up after 0.2 s waiting for the lock .*run.nc.lock, "
                                                   rf"held by pid {pid} on host \S+ since \S+; the run store is "
                                                   rf"unchanged"):
            with files.store_lock(run, timeout=0.2, notify=said.append):
                pass
        assert len(said) == 1 and f"waiting for up to 0.2 s for the lock run.nc.lock, held by pid {pid}" in said[0]
        before = run.read_bytes()
        one_line_error(capsys, ["update", run, run_dir / "next.csv", "--lock-timeout", "0"],
                       rf"gave up after 0 s waiting for the lock .*held by pid {pid} on host")
        assert run.read_bytes() == before
    finally:
        os.write(done_w, b"x")
        assert wait(pid) == 0
    assert (run_dir / "run.nc.lock").read_bytes() == b""         # released: nobody named
    assert cli.main(["update", str(run), str(run_dir / "next.csv"), "--lock-timeout", "0"]) == 0


def test_the_lock_timeout_setting(monkeypatch):
    monkeypatch.delenv(files.LOCK_TIMEOUT_ENV, raising=False)
    assert files.lock_timeout() == 3600.0
    monkeypatch.setenv(files.LOCK_TIMEOUT_ENV, "inf")
    assert files.lock_timeout() == float("inf")
    assert files.lock_timeout(5) == 5.0
    for bad in ("soon", "-1", "nan"):
        monkeypatch.setenv(files.LOCK_TIMEOUT_ENV, bad)
        with pytest.raises(StoreError, match=rf"SEQBAYES_LOCK_TIMEOUT: expected a number of seconds >= 0 \(or inf\), "
                                             rf"got '{bad}'"):
            files.lock_timeout()


def test_missing_stores_folders_and_link_loops_are_one_line(run_dir, capsys):
    one_line_error(capsys, ["update", run_dir / "nothere.nc", run_dir / "next.csv"],
                   r"nothere.nc: no such run store \(create one with `seqbayes init CONFIG")
    assert not (run_dir / "nothere.nc.lock").exists()
    one_line_error(capsys, ["update", run_dir / "nofolder" / "run.nc", run_dir / "next.csv"],
                   r"run.nc: the folder .*nofolder does not exist")
    one_line_error(capsys, ["init", run_dir / "run.toml", run_dir / "nofolder" / "run.nc"],
                   r"the folder .*nofolder does not exist")
    loop = run_dir / "loop.nc"
    loop.symlink_to(loop)
    for argv in (["init", run_dir / "run.toml", loop], ["update", loop, run_dir / "next.csv"], ["status", loop]):
        one_line_error(capsys, argv, r"loop.nc: a loop of symbolic links")
    assert not (run_dir / "loop.nc.lock").exists()
