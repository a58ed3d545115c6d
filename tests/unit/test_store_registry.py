"""The store registry: every run kind opens and is created through one door, and a backend refuses
what its kind cannot do with a message that names the alternative."""

import h5py
import numpy as np
import pytest
from _user_model import decay_tables, write_config, write_model

from seqbayes.store import RunStore, SGRunStore, StoreError, create_run, load_config, open_run, registry
from seqbayes.store.base import BaseStore
from _sg_model import sg_toml

SG_TOML = sg_toml("two-storey", 16, time=False)


@pytest.fixture
def runs(tmp_path):
    write_model(tmp_path, "regmodel")
    smc = create_run(tmp_path / "smc.nc", load_config(write_config(tmp_path / "run.toml", "regmodel", n_samples=40,
                                                                   seed=3)))
    (tmp_path / "sg.toml").write_text(SG_TOML)
    sg = create_run(tmp_path / "sg.nc", load_config(tmp_path / "sg.toml"))
    return smc, sg


def test_each_kind_has_its_backend(runs):
    smc, sg = runs
    assert type(smc) is RunStore and type(sg) is SGRunStore
    assert {"semc", "sgenmcmc"} <= set(registry.kinds())
    assert registry.run_kind(smc.path) == "semc" and registry.run_kind(sg.path) == "sgenmcmc"
    assert type(open_run(smc.path)) is RunStore and type(open_run(sg.path)) is SGRunStore
    for store in runs:
        assert isinstance(store, BaseStore) and registry.backend(store.kind) is type(store)


def test_a_backend_refuses_another_kind_and_an_unknown_kind(runs, tmp_path):
    smc, sg = runs
    with pytest.raises(StoreError, match="an SG-EnMCMC run store"):
        RunStore.open(sg.path)
    with pytest.raises(StoreError, match="an SEMC/SMC run store"):
        SGRunStore.open(smc.path)
    with h5py.File(sg.path, "r+") as f:
        f.attrs["run_kind"] = "fem"
    with pytest.raises(StoreError, match="run kind 'fem': this seqbayes has no store for it"):
        open_run(sg.path)


def test_what_a_kind_cannot_do_is_refused_with_the_alternative(runs):
    smc, sg = runs
    smc.require("predict", "compare", "replace_last")         # an SMC run does all of it
    with pytest.raises(StoreError, match="predict .* is for SEMC/SMC runs .*seqbayes status"):
        sg.predict(2)
    with pytest.raises(StoreError, match="--replace-last: not available for an SG-EnMCMC run"):
        sg.assimilate(np.zeros((4, 3)), replace_last=True)
    with pytest.raises(StoreError, match="an SG-EnMCMC report takes --modes"):
        sg.require("report --threshold")


def test_a_run_opened_for_another_model_names_the_fields(runs, tmp_path):
    smc, sg = runs
    other = load_config(write_config(tmp_path / "other.toml", "regmodel", n_samples=50, seed=3))
    with pytest.raises(StoreError, match="differing fields: n_samples"):
        RunStore.open(smc.path, other)
    (tmp_path / "sg2.toml").write_text(SG_TOML.replace("n_members = 16", "n_members = 20"))
    with pytest.raises(StoreError, match="differing fields: n_members"):
        SGRunStore.open(sg.path, load_config(tmp_path / "sg2.toml"))


def test_the_same_call_updates_either_kind(runs, tmp_path):
    smc, _ = runs
    table = decay_tables([1.5], np.linspace(0, 3, 15), 0.1, 0)[0]
    info = open_run(smc.path).assimilate(table, "d1", replace_last=False, executor=None, loglike=None,
                                         accept_model_change=False)
    store = open_run(smc.path)
    assert store.n_steps == 1 and store.step_summary(info, "d1").startswith("step 1 from d1: log-evidence")
    assert store.status_json()["steps"][0]["step"] == 1
