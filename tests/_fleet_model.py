"""Small simulated fleets for the fleet tests and benchmarks/bench_fleet.py.

A fleet of ``n_stores`` run stores of the straight line y = a + b t + N(0, 0.1^2) (``_user_model.line_model``),
each with its own seed and its own drifting (a, b), laid out as the fleet folder convention says::

    ROOT/model/MODULE.py, ROOT/model/sK.toml    the likelihood and each store's configuration
    ROOT/initial/sK.nc                          each store as created (no step), copied from here
    ROOT/fleet/sK.nc, ROOT/fleet/sK/dJ.csv      the fleet: each store beside the folder of its datasets

:func:`store_fingerprint` hashes everything a run store holds that the numbers of its steps determine (the
samples, weights, predictive draws, sampler states, generator states, step sizes, dataset hashes and names,
and every step diagnostic except the wall time), so two stores updated by different drivers compare bit
for bit.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import shutil
from pathlib import Path

import numpy as np

from _user_model import line_model

CONFIG = """
[model]
name = "line-{k}"
likelihood = "{module}:loglike"
[data]
columns = ["t", "y"]
[priors]
a = {{ dist = "uniform", loc = 0, scale = 4 }}
b = {{ dist = "uniform", loc = -1, scale = 2 }}
[kernel]
a = {{ type = "drift", rate = 0.02, noise_std = 0.01 }}
[sampler]
type = "SEMC"
n_samples = {n_samples}
seed = {seed}
predictive = "transition"
"""

RAISING = """
def loglike(theta, data):
    if abs(data[0, 1] - {value!r}) < 1e-12:
        raise RuntimeError("sensor model out of range")
    return _line(theta, data)
"""


def stream(seed: int, n_datasets: int, n_rows: int = 8) -> list:
    """``n_datasets`` tables (n_rows, 2) of t, y = a_s + b_s t + N(0, 0.1^2), a and b drifting."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0.0, 1.0, n_rows)
    a = 1.0 + np.cumsum(0.02 + 0.01 * rng.standard_normal(n_datasets))
    b = 0.5 + 0.005 * np.cumsum(rng.standard_normal(n_datasets))
    return [np.column_stack([t, a[s] + b[s] * t + 0.1 * rng.standard_normal(n_rows)]) for s in range(n_datasets)]


def write_table(path: Path, table) -> None:
    np.savetxt(path, table, delimiter=",", header="t,y", comments="", fmt="%.17g")


def make_fleet(root: Path, n_stores: int, n_datasets: int, *, module: str = "fleetline", n_samples: int = 30,
               raising: dict | None = None) -> dict:
    """Write the fleet under ``root`` (module docstring); returns ``{name: [dataset paths]}``.

    ``raising`` maps a store's index to the dataset (1-based) from which its likelihood raises: that store
    gets its own module, whose ``loglike`` raises ``RuntimeError`` on that dataset (found by its first y).
    """
    from seqbayes.store import RunStore, load_config

    model, initial, fleet = root / "model", root / "initial", root / "fleet"
    for folder in (model, initial, fleet):
        folder.mkdir(parents=True, exist_ok=True)
    (model / f"{module}.py").write_text(line_model(0.1))
    plan = {}
    for k in range(n_stores):
        name = f"s{k}"
        tables = stream(1000 + k, n_datasets)
        this_module = module
        if raising and k in raising:
            this_module = f"{module}_raising{k}"
            (model / f"{this_module}.py").write_text(line_model(0.1).replace("def loglike", "def _line")
                                                     + RAISING.format(value=float(tables[raising[k] - 1][0, 1])))
        (model / f"{name}.toml").write_text(CONFIG.format(k=k, module=this_module, n_samples=n_samples,
                                                          seed=100 + k))
        if not (initial / f"{name}.nc").exists():
            RunStore.create(initial / f"{name}.nc", load_config(model / f"{name}.toml"))
        shutil.copyfile(initial / f"{name}.nc", fleet / f"{name}.nc")
        (fleet / name).mkdir(exist_ok=True)
        plan[name] = []
        for s, table in enumerate(tables):
            path = fleet / name / f"d{s + 1}.csv"
            write_table(path, table)
            plan[name].append(path)
    return plan


def copy_initial(root: Path, target: Path) -> None:
    """The fleet's stores as created (no step) into ``target`` (a fresh folder)."""
    target.mkdir(parents=True, exist_ok=True)
    for store in sorted((root / "initial").glob("*.nc")):
        shutil.copyfile(store, target / store.name)


def serial_updates(root: Path, plan: dict, target: Path) -> dict:
    """Every store updated alone by ``seqbayes update STORE D1 ... Dn -q`` in this process (copies of the
    created stores in ``target``; the lines it prints are discarded); returns ``{name: exit code}``."""
    import contextlib
    import io

    from seqbayes import cli

    copy_initial(root, target)
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        return {name: cli.main(["update", str(target / f"{name}.nc"), *map(str, paths), "-q"])
                for name, paths in plan.items()}


def store_fingerprint(path) -> str:
    """SHA-256 of what a run store's steps hold (module docstring)."""
    from seqbayes.store import RunStore

    store = RunStore.open(path)
    h = hashlib.sha256()

    def add(value):
        array = np.ascontiguousarray(value)
        h.update(json.dumps([str(array.dtype), list(array.shape)]).encode())
        h.update(array.tobytes())

    for record in store.result.steps:
        for values in (record.posterior, record.log_weights, record.predictive):
            add(values)
        info = dataclasses.asdict(record.info)
        info.pop("wall_time")
        h.update(json.dumps(info, sort_keys=True, default=str).encode())
    for arrays in store.states:
        for name in sorted(arrays):
            h.update(name.encode())
            add(arrays[name])
    h.update(json.dumps([store.rng_states, store.step_sizes, store.digests, store.sources], default=str).encode())
    return h.hexdigest()
