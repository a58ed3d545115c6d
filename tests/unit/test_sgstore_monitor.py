"""The stiffness-drop monitor driven by the SG-EnMCMC run store ([monitor] section): a store
reopened before every block holds the same monitor as one uninterrupted StiffnessDropMonitor
(bit for bit), status shows the class probabilities and the detection, and a bad [monitor]
setting is a one-line error naming it."""

from __future__ import annotations

import os
import signal
from dataclasses import fields

import numpy as np
import pytest

from seqbayes import cli
from seqbayes.store.config import ConfigError, load_config
from seqbayes.rng import as_generator
from seqbayes.store.sg_report import format_sg_status
from seqbayes.store import SGRunStore
from seqbayes.store.sg_config import parse_sg_config
from seqbayes.structural.drop_paths import simulate_drop
from seqbayes.structural.stiffness_drop import DropBlock
from seqbayes.store.files import FAULT_ENV
from _sg_model import sg_toml

TOML = sg_toml("two-storey-drop", 24, extra="""
[monitor]
n_particles = 24
change_every = 5
change_rate = 0.5
prune_after = 10
prune_below = 1e-6
""")
N_BLOCKS = 3


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """Storey 2 loses 30 % at step 130 of 240 (in block 2); blocks of 80 steps as CSV."""
    root = tmp_path_factory.mktemp("sgmonitor")
    (root / "run.toml").write_text(TOML)
    config = load_config(root / "run.toml")
    rng = np.random.default_rng(0)
    ag = rng.standard_normal(240)
    y, _ = simulate_drop(config.build_building(), config.dt, [0.9, 0.8], 2, 0.3, 130, ag)
    y = y + 0.05 * rng.standard_normal(y.shape)
    table = np.column_stack([np.arange(240) * config.dt, ag, y])
    for k, block in enumerate(np.array_split(table, N_BLOCKS)):
        np.savetxt(root / f"b{k + 1}.csv", block, delimiter=",", header="t,ag,a1,a2", comments="", fmt="%.17g")
    return root, config, table


def direct(config, table, start=0, monitor=None):
    """An uninterrupted StiffnessDropMonitor over the blocks (seeded as the store seeds it)."""
    if monitor is None:
        monitor = config.build_monitor()
        monitor.reset(as_generator(config.monitor["seed"]))
    for block in np.array_split(table, N_BLOCKS)[start:]:
        monitor.update(block[:, 1], block[:, 2:])
    return monitor


def assert_same_blocks(ours, reference):
    assert len(ours) == len(reference)
    for a, b in zip(ours, reference):
        for f in fields(DropBlock):
            if f.name != "seconds":
                x, y = getattr(a, f.name), getattr(b, f.name)
                assert type(x) is type(y), f.name
                assert np.array_equal(x, y, equal_nan=np.asarray(x).dtype.kind == "f"), (f.name, a.stop, x, y)


@pytest.mark.slow
def test_store_reopened_before_every_block_equals_one_monitor(workdir, tmp_path, capsys):
    root, config, table = workdir
    assert config.monitor["seed"] == 8  # default: the sampler's seed + 1
    run = tmp_path / "run.nc"
    assert cli.main(["init", str(root / "run.toml"), str(run)]) == 0
    for k in range(N_BLOCKS):
        SGRunStore.open(run).update(root / f"b{k + 1}.csv")
    store = SGRunStore.open(run)
    whole = direct(config, table)
    assert_same_blocks(store.monitor().history, whole.history)
    assert whole.detection() is not None and whole.detection().storey == 2  # the test case shows a detection
    # restored at an earlier step, it continues as the uninterrupted one
    resumed = direct(config, table, start=1, monitor=store.monitor(1))
    assert_same_blocks(resumed.history, whole.history)
    assert [info["monitor"]["class_probabilities"] for info in store.infos] == [
        b.class_probabilities.tolist() for b in whole.history]
    text = format_sg_status(store)
    assert "stiffness-drop monitor" in text
    assert (f"change first detected at the end of step {whole.detection().stop // 80} "
            f"(t = {whole.detection().time:.2f} s), attributed to storey 2") in text
    assert cli.main(["status", str(run)]) == 0
    assert "attributed to storey 2" in capsys.readouterr().out


def test_a_run_without_monitor_has_none(workdir, tmp_path):
    import tomllib

    raw = tomllib.loads(TOML)
    raw.pop("monitor")
    config = parse_sg_config(raw, "run.toml")
    assert config.monitor is None and "monitor" not in config.to_dict()
    store = SGRunStore.create(tmp_path / "plain.nc", config)
    with pytest.raises(ValueError, match=r"no \[monitor\]"):
        store.monitor()


@pytest.mark.parametrize("edit, match", [({"n_particles": 3}, "monitor: n_particles"),
                                         ({"threshold": 2.0}, "monitor: threshold"),
                                         ({"window": 3}, "monitor"), ({"seed": -1}, "monitor.seed")])
def test_monitor_errors_name_the_setting(edit, match):
    import tomllib

    raw = tomllib.loads(TOML)
    raw["monitor"].update(edit)
    with pytest.raises(ConfigError, match=match):
        parse_sg_config(raw, "run.toml")


def fork_update(run, block, fault):
    """``seqbayes update`` in a child killed at the journal's fault point ``fault`` (as test_sgstore)."""
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        code = 70
        try:
            os.environ[FAULT_ENV] = fault
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, 1)
            os.dup2(devnull, 2)
            code = cli.main(["update", str(run), str(block)])
        finally:
            os._exit(code)
    _, status = os.waitpid(pid, 0)
    return status


@pytest.mark.slow
@pytest.mark.parametrize("fault", ["mid-write", "mid-apply"])
def test_killed_update_keeps_the_monitor_bit_identical(workdir, tmp_path, fault):
    root, config, table = workdir
    run = tmp_path / "run.nc"
    SGRunStore.create(run, config).update(root / "b1.csv")
    status = fork_update(run, root / "b2.csv", fault)  # the append of step 2 is killed
    assert os.WIFSIGNALED(status) and os.WTERMSIG(status) == signal.SIGKILL
    after = SGRunStore.open(run)
    assert after.n_steps == (2 if fault == "mid-apply" else 1)
    for k in range(after.n_steps + 1, N_BLOCKS + 1):
        assert cli.main(["update", str(run), str(root / f"b{k}.csv")]) == 0
    assert_same_blocks(SGRunStore.open(run).monitor().history, direct(config, table).history)
