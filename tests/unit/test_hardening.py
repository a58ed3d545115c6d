"""Trust boundaries and hardening of the run store (issue 15).

* A store runs only the likelihood module it recorded and hashed: a store copied next to
  another module of the same name does not run it; ``predict`` and ``report`` import no
  likelihood at all; an edited module is noticed and refused unless accepted; nothing is
  put on ``sys.path``.
* User code gets read-only views of ``theta`` and the data.
* Concurrent API updates are all stored; temporary files are matched exactly.
* Bad stores, settings, datasets and priors are refused with one message naming the file
  or the argument.
"""

from __future__ import annotations

import hashlib
import shutil
import sys

import numpy as np
import pytest

from seqbayes.config import DataError, load_config
from seqbayes.store import ModelChangedError, RunStore, StoreError

from _user_model import decay_tables, write_config, write_model

# a module that leaves a mark when it is run: proves whether a command ran it
MARKER = """
import pathlib as _pathlib
_pathlib.Path(__file__).with_suffix(".ran").write_text("ran")
"""


def tables(n=3, seed=0):
    return decay_tables([1.5 - 0.05 * s for s in range(n)], np.linspace(0, 3, 15), 0.1, seed)


def write_cfg(folder, module, **kwargs):
    """The decay model's config with a drifting amplitude and the transition-density predictive prior."""
    kwargs.setdefault("kernel", 'a = { type = "drift", rate = -0.05, noise_std = 0.02 }')
    path = write_config(folder / "run.toml", module, n_samples=40, seed=3, **kwargs)
    path.write_text(path.read_text() + 'predictive = "transition"\n')
    return path


def make_run(folder, module, n_steps=1, extra=""):
    folder.mkdir(parents=True, exist_ok=True)
    write_model(folder, module, extra=extra)
    cfg = load_config(write_cfg(folder, module))
    store = RunStore.create(folder / "run.nc", cfg)
    for table in tables(n_steps):
        store.assimilate(table)
    return store


def sha(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


# ------------------------------------------------------------------ item 1: code from where a store lies
def test_a_copied_store_runs_no_module_it_did_not_record(tmp_path):
    home, elsewhere = tmp_path / "home", tmp_path / "elsewhere"
    store = make_run(home, "trustmodel_a")
    elsewhere.mkdir()
    shutil.copy(home / "run.nc", elsewhere / "run.nc")
    shutil.rmtree(home)                                   # the recorded folder is gone, as on another machine
    # a different module of the same name lies next to the copy
    write_model(elsewhere, "trustmodel_a", noise=0.3, extra=MARKER)
    copy = RunStore.open(elsewhere / "run.nc")
    before = sha(elsewhere / "run.nc")
    draws = copy.predict(2)                               # forecasts need no likelihood
    np.testing.assert_array_equal(draws, store.predict(2))
    with pytest.raises(ModelChangedError, match=r"run.nc: the likelihood module changed since the run recorded it "
                                                r"\(sha256 [0-9a-f]{12} .*trustmodel_a.py has sha256 [0-9a-f]{12}.*"
                                                r"it is not run"):
        copy.assimilate(tables(2)[1])
    assert not (elsewhere / "trustmodel_a.ran").exists()  # never executed
    assert sha(elsewhere / "run.nc") == before
    # the very file the run recorded, copied next to the store, is run
    write_model(elsewhere, "trustmodel_a")
    RunStore.open(elsewhere / "run.nc").assimilate(tables(2)[1])
    assert RunStore.open(elsewhere / "run.nc").n_steps == 2


def test_a_store_whose_module_is_nowhere_says_where_it_was(tmp_path):
    make_run(tmp_path / "home", "trustmodel_b")
    (tmp_path / "home" / "trustmodel_b.py").unlink()
    store = RunStore.open(tmp_path / "home" / "run.nc")
    with pytest.raises(ModelChangedError, match=r"the likelihood module 'trustmodel_b' the run recorded "
                                                r"\(.*trustmodel_b.py, sha256 [0-9a-f]{12}\) is not there"):
        store.assimilate(tables(2)[1])
    assert store.predict(1).shape == (1, 40, 2)


def test_predict_and_report_import_no_likelihood(tmp_path):
    store = make_run(tmp_path, "trustmodel_c", extra=MARKER)
    (tmp_path / "trustmodel_c.ran").unlink()
    sys.modules.pop("trustmodel_c", None)
    opened = RunStore.open(tmp_path / "run.nc")
    opened.predict(3)
    from seqbayes.report import render_report

    assert "<html" in render_report(opened, forecast_steps=2)
    assert not (tmp_path / "trustmodel_c.ran").exists() and "trustmodel_c" not in sys.modules
    assert store.n_steps == 1


def test_an_edited_module_is_noticed_and_its_hash_recorded_per_step_once_accepted(tmp_path):
    store = make_run(tmp_path, "trustmodel_d")
    first = store.module_hashes[0]
    assert first == sha(tmp_path / "trustmodel_d.py") == store.config.likelihood_sha256
    write_model(tmp_path, "trustmodel_d", noise=0.2)      # the user edits the model
    with pytest.raises(ModelChangedError, match="--accept-model-change"):
        RunStore.open(tmp_path / "run.nc").assimilate(tables(2)[1])
    accepted = RunStore.open(tmp_path / "run.nc")
    accepted.assimilate(tables(2)[1], accept_model_change=True)
    reopened = RunStore.open(tmp_path / "run.nc")
    assert reopened.module_hashes == [first, sha(tmp_path / "trustmodel_d.py")]
    assert reopened.config.likelihood_sha256 == sha(tmp_path / "trustmodel_d.py")
    reopened.assimilate(tables(3)[2])                     # the new content is now the recorded one


def test_loading_the_likelihood_leaves_sys_path_alone_and_shadows_nothing(tmp_path):
    before = list(sys.path)
    (tmp_path / "json.py").write_text("raise RuntimeError('a json.py next to a config was imported')\n")
    store = make_run(tmp_path, "trustmodel_e", n_steps=2)
    assert sys.path == before
    import json

    assert json.dumps([1]) == "[1]" and store.n_steps == 2


def test_a_garbled_or_edited_search_path_does_not_pass(tmp_path):
    store = make_run(tmp_path, "trustmodel_f")
    ds = store.to_xarray()
    ds.attrs["config"] = ds.attrs["config"].replace(str(tmp_path), "/somewhere/else")
    ds.to_netcdf(tmp_path / "edited.nc", engine="h5netcdf")
    with pytest.raises(StoreError, match="edited.nc: damaged run store: the content hash"):
        RunStore.open(tmp_path / "edited.nc")


# ------------------------------------------------------------------ item 3: user code cannot corrupt the run
WRITES_THETA = """
def writes_theta(theta, data):
    theta[:, 1] = abs(theta[:, 1])       # "just making sure b is positive"
    return loglike(theta, data)
"""


def test_a_likelihood_that_writes_into_theta_fails_clearly_and_changes_nothing(tmp_path):
    write_model(tmp_path, "mutatingmodel", extra=WRITES_THETA)
    cfg = load_config(write_cfg(tmp_path, "mutatingmodel", func="writes_theta"))
    store = RunStore.create(tmp_path / "run.nc", cfg)
    before, particles = sha(tmp_path / "run.nc"), store.initial_particles.copy()
    with pytest.raises(ValueError, match=r"loglike: wrote into its input theta or data \(assignment destination is "
                                         r"read-only\); .*copy them first"):
        store.assimilate(tables(1)[0])
    assert sha(tmp_path / "run.nc") == before
    np.testing.assert_array_equal(store.initial_particles, particles)


def test_user_code_gets_read_only_views_of_theta_and_every_kind_of_data():
    from concurrent.futures import ThreadPoolExecutor

    from seqbayes.parallel import evaluate_loglike

    theta, table = np.ones((6, 2)), np.arange(4.0).reshape(2, 2)
    columns = {"t": np.arange(3.0), "y": np.ones(3)}
    seen = []

    def inspect(th, data):
        seen.append((th.flags.writeable, *(a.flags.writeable for a in (data.values() if isinstance(data, dict)
                                                                        else [data]))))
        if isinstance(data, dict):
            data["extra"] = 1.0                       # a new key in the likelihood's own dict only
        return th[:, 0]                               # a view of theta: returned as a copy

    for data in (table, columns):
        for executor in (None, ThreadPoolExecutor(2)):
            values = evaluate_loglike(inspect, theta, data, executor)
            values[:] = -1.0                          # the sampler may write into the result ...
            assert theta[0, 0] == 1.0                 # ... without touching theta
    assert seen and not any(any(flags) for flags in seen)
    assert set(columns) == {"t", "y"} and theta.flags.writeable and table.flags.writeable
    with pytest.raises(ValueError, match="loglike: returned complex values"):
        evaluate_loglike(lambda th, d: th[:, 0] + 1j, theta, table)


def test_the_dask_cluster_a_config_starts_listens_on_localhost_only(tmp_path, monkeypatch):
    distributed = pytest.importorskip("distributed")
    seen = {}

    class FakeCluster:
        def __init__(self, **kwargs):
            seen.update(kwargs)

        def close(self):
            pass

    class FakeClient:
        def __init__(self, cluster):
            pass

        def close(self):
            pass

    monkeypatch.setattr(distributed, "LocalCluster", FakeCluster)
    monkeypatch.setattr(distributed, "Client", FakeClient)
    write_model(tmp_path, "daskcfgmodel")
    path = write_cfg(tmp_path, "daskcfgmodel")
    path.write_text(path.read_text() + '[parallel]\nexecutor = "dask"\n')
    client, close = load_config(path).make_executor()
    close()
    assert seen["dashboard_address"].startswith("127.0.0.1:") and seen["host"] == "127.0.0.1"
