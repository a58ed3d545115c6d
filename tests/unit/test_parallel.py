"""Distributed likelihood evaluation: a local Dask cluster of 2 worker processes (and
concurrent.futures executors) gives results identical to the serial run with the same seed,
and the work really runs in the workers."""

from __future__ import annotations

import os
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor

import numpy as np
import pytest
from scipy import stats

from seqbayes.engine.settings import from_flat
from seqbayes import SEMC, SMC, Drift, JointPrior, MarkovKernel, Static
from seqbayes import parallel
from seqbayes.parallel import ProcessWorkers

distributed = pytest.importorskip("distributed")


@pytest.fixture(autouse=True)
def every_batch_to_the_workers(monkeypatch):
    """The tests below check that the work really runs in the workers: no batch is kept here for being
    cheap (``MIN_CHUNK_SECONDS = 0``), except in the test of that rule, which sets it back."""
    monkeypatch.setattr(parallel, "MIN_CHUNK_SECONDS", 0.0)


def loglike(theta, data):
    """Gaussian regression y = a + b x + noise; ``data = (x, y, pid_dir or None)``."""
    x, y, pid_dir = data
    if pid_dir is not None:  # record which process evaluated this chunk
        with open(os.path.join(pid_dir, f"{os.getpid()}.pid"), "a") as fh:
            fh.write(f"{theta.shape[0]}\n")
    pred = theta[:, [0]] + theta[:, [1]] * x[None, :]
    return -0.5 * np.sum((y[None, :] - pred) ** 2, axis=1) / 0.2 ** 2


def datasets(pid_dir=None):
    rng = np.random.default_rng(3)
    x = np.linspace(-1, 1, 12)
    return [(x, 0.5 - 0.1 * s + 1.2 * x + 0.2 * rng.standard_normal(x.size), pid_dir) for s in range(2)]


def make(cls, executor=None, n_chunks=None):
    prior = JointPrior({"a": stats.norm(0, 2), "b": stats.uniform(-3, 6)})
    kernel = MarkovKernel([Drift(-0.1, noise_std=0.05), Static()])
    # few sweeps per stage: each sweep is a round trip to the cluster, and identity needs no more
    limits = dict(moved_fraction=0.0) | (dict(max_virtual=4) if cls is SEMC else dict(max_moves=4))
    return cls(prior, kernel, loglike, n_samples=40, rng=17, executor=parallel.Workers(executor, n_chunks),
               **from_flat(cls.__name__, **limits))


def assert_identical(a, b):
    assert len(a.steps) == len(b.steps)
    for ra, rb in zip(a.steps, b.steps):
        np.testing.assert_array_equal(ra.posterior, rb.posterior)
        np.testing.assert_array_equal(ra.log_weights, rb.log_weights)
        np.testing.assert_array_equal(ra.predictive, rb.predictive)
        assert ra.info.log_evidence == rb.info.log_evidence
        assert ra.info.n_loglike_evals == rb.info.n_loglike_evals


@pytest.fixture(scope="module")
def client():
    cluster = distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1, dashboard_address=":0")
    client = distributed.Client(cluster)
    yield client
    client.close()
    cluster.close()


@pytest.fixture(scope="module")
def serial():
    return {cls.__name__: make(cls).run(datasets()) for cls in (SEMC, SMC)}


@pytest.mark.slow
@pytest.mark.parametrize("cls, n_chunks", [(SEMC, None), (SMC, 7)])
def test_dask_cluster_of_two_processes_gives_the_serial_numbers(client, serial, cls, n_chunks, tmp_path):
    """Default chunking (one chunk per worker) and 7 uneven chunks (40 samples -> 6 and 5)."""
    worker_pids = set(client.run(os.getpid).values())
    assert len(worker_pids) == 2 and os.getpid() not in worker_pids
    result = make(cls, executor=client, n_chunks=n_chunks).run(datasets(str(tmp_path)))
    assert_identical(serial[cls.__name__], result)
    # every chunk was evaluated in a worker process, and both workers took part
    pids = {int(p.stem) for p in tmp_path.glob("*.pid")}
    assert pids == worker_pids
    evaluated = sum(int(n) for p in tmp_path.glob("*.pid") for n in p.read_text().split())
    assert evaluated == sum(r.info.n_loglike_evals for r in result.steps)


def test_concurrent_futures_executors_give_the_serial_numbers(serial):
    with ThreadPoolExecutor(max_workers=2) as pool:
        assert_identical(serial["SEMC"], make(SEMC, executor=pool).run(datasets()))
    with ProcessPoolExecutor(max_workers=2) as pool:
        assert_identical(serial["SMC"], make(SMC, executor=pool).run(datasets()))


@pytest.mark.slow
def test_run_store_with_a_dask_client_resumes_identically(client, tmp_path):
    """A monitoring run whose updates are evaluated on the cluster stores the serial numbers."""
    import textwrap

    from seqbayes.store.config import load_config
    from seqbayes.store import RunStore

    (tmp_path / "parmodel.py").write_text(textwrap.dedent("""
        import numpy as np
        def loglike(theta, data):
            pred = theta[:, [0]] + theta[:, [1]] * data[:, 0][None, :]
            return -0.5 * np.sum((data[:, 1][None, :] - pred) ** 2, axis=1) / 0.2 ** 2
    """))
    (tmp_path / "run.toml").write_text(textwrap.dedent("""
        [model]
        likelihood = "parmodel:loglike"
        [data]
        columns = ["x", "y"]
        [priors]
        a = { dist = "norm", loc = 0, scale = 2 }
        b = { dist = "uniform", loc = -3, scale = 6 }
        [kernel]
        a = { type = "drift", rate = -0.1, noise_std = 0.05 }
        [sampler]
        n_samples = 40
        seed = 5
        [parallel]
        executor = "processes"
        workers = 2
    """))
    cfg = load_config(tmp_path / "run.toml")
    tables = [np.column_stack(d[:2]) for d in datasets()]
    local = RunStore.create(tmp_path / "serial.nc", cfg)
    RunStore.create(tmp_path / "dask.nc", cfg)  # the store the parallel updates continue
    pool, close = cfg.make_executor()   # [parallel] executor = "processes"
    try:
        for i, table in enumerate(tables):
            local.assimilate(table)
            # the workers import the user's module from the config's folder
            RunStore.open(tmp_path / "dask.nc").assimilate(table, executor=client if i % 2 else pool)
    finally:
        close()
    assert_identical(local.result, RunStore.open(tmp_path / "dask.nc").result)


@pytest.mark.slow
def test_history_prior_evaluates_past_datasets_on_the_executor_with_the_serial_numbers(client, tmp_path):
    """Static parameters: the exact history prior re-evaluates past datasets, on the workers too."""
    prior = JointPrior({"a": stats.norm(0, 2), "b": stats.uniform(-3, 6)})

    def run(executor=None, pid_dir=None):
        data = datasets(pid_dir) + [d for d in datasets(pid_dir)[:1]]  # three steps: two past datasets at s = 3
        return SMC(prior, MarkovKernel([Static(), Static()]), loglike, n_samples=40, rng=5, executor=executor, **from_flat("SMC", max_moves=4, moved_fraction=0.0)).run(data)

    serial = run()
    with ProcessPoolExecutor(max_workers=2) as pool:
        assert_identical(serial, run(pool))
    result = run(client, str(tmp_path))
    assert_identical(serial, result)
    evaluated = sum(int(n) for p in tmp_path.glob("*.pid") for n in p.read_text().split())
    assert evaluated == sum(r.info.n_loglike_evals for r in result.steps)


class CountedLoglike:
    """The regression likelihood; every unpickling (a delivery to a worker) leaves a file in ``folder``."""

    def __init__(self, folder):
        self.folder = folder

    def __call__(self, theta, data):
        with open(os.path.join(self.folder, f"eval-{os.getpid()}-{os.urandom(4).hex()}"), "w") as fh:
            fh.write(str(theta.shape[0]))
        return loglike(theta, data[:2] + (None,))

    def __setstate__(self, state):
        self.__dict__.update(state)
        open(os.path.join(self.folder, f"delivery-{os.getpid()}-{os.urandom(4).hex()}"), "w").close()


def counted_run(executor, folder):
    return SEMC(JointPrior({"a": stats.norm(0, 2), "b": stats.uniform(-3, 6)}), MarkovKernel([Drift(-0.1, noise_std=0.05), Static()]), CountedLoglike(str(folder)), n_samples=40, rng=17, executor=executor, **from_flat("SEMC", moved_fraction=0.0, max_virtual=4)).run(datasets())


def test_process_workers_get_the_likelihood_and_each_dataset_once(serial, tmp_path):
    """Two datasets, two workers: four deliveries, however many batches (the plain executor ships per chunk)."""
    with ProcessWorkers(2) as pool:
        assert_identical(serial["SEMC"], make(SEMC, executor=pool).run(datasets()))
        result = counted_run(pool, tmp_path)
        worker_pids = set(pool.map(os.getpid, *[[]]) or []) | {int(p.name.split("-")[1]) for p in tmp_path.glob("eval-*")}
    assert_identical(serial["SEMC"], result)
    deliveries = list(tmp_path.glob("delivery-*"))
    assert len(deliveries) == 4
    assert os.getpid() not in {int(p.name.split("-")[1]) for p in deliveries}
    n_batches = len(list(tmp_path.glob("eval-*"))) // 2
    assert n_batches > 10  # many calls, each chunk evaluated in a worker from what it kept
    evaluated = sum(int(p.read_text()) for p in tmp_path.glob("eval-*"))
    assert evaluated == sum(r.info.n_loglike_evals for r in result.steps)
    assert len(worker_pids) == 2


@pytest.mark.parametrize("kind", ["processes", pytest.param("dask", marks=pytest.mark.slow)])
def test_workers_find_every_payload_when_a_kept_dataset_is_used_again(kind, request):
    """More datasets than a pool keeps, the first used again in between (SMC^2's pattern: the current dataset
    between re-runs over the history), each call on one chunk (one worker) or two: every call finds its payload
    and gives the serial numbers. When this process refreshed a used key and the workers did not, the last call
    raised KeyError in the worker (the OpenSees example's update at campaign 19, 1 worker)."""
    kept = parallel._KEPT_PAYLOADS
    x = np.linspace(-1, 1, 12)
    data = [(x, 0.1 * i + 1.2 * x, None) for i in range(kept + 1)]
    theta = np.array([[0.5, 1.2], [0.2, -1.0], [0.0, 0.3]])
    order = [0, *range(1, kept), 0, kept, 0]   # 0 is used again when it is the oldest kept, then pushed out
    pool = ProcessWorkers(2) if kind == "processes" else request.getfixturevalue("client")
    try:
        for call, i in enumerate(order):
            got = parallel.evaluate_loglike(loglike, theta, data[i], executor=pool, n_chunks=1 + call % 2)
            np.testing.assert_array_equal(got, loglike(theta, data[i]))
    finally:
        if kind == "processes":
            pool.shutdown()


@pytest.mark.slow
def test_dask_workers_get_the_likelihood_and_each_dataset_once(client, serial, tmp_path):
    result = counted_run(client, tmp_path)
    assert_identical(serial["SEMC"], result)
    deliveries = {int(p.name.split("-")[1]) for p in tmp_path.glob("delivery-*")}
    assert deliveries <= set(client.run(os.getpid).values())
    assert len(list(tmp_path.glob("delivery-*"))) <= 4  # at most once per worker and dataset
    evaluated = sum(int(p.read_text()) for p in tmp_path.glob("eval-*"))
    assert evaluated == sum(r.info.n_loglike_evals for r in result.steps)


def test_a_cheap_likelihood_stays_in_this_process_with_the_same_numbers(serial, tmp_path, monkeypatch):
    """A batch whose chunks would take less than MIN_CHUNK_SECONDS is evaluated here. The threshold is set
    so high that every batch counts as cheap whatever the machine's load (a test may not depend on
    timing): every evaluation then happens in this process, and the numbers are the serial ones."""
    monkeypatch.setattr(parallel, "MIN_CHUNK_SECONDS", 1e9)
    with ProcessWorkers(2) as pool:
        result = counted_run(pool, tmp_path)
    assert_identical(serial["SEMC"], result)
    in_workers = [p for p in tmp_path.glob("eval-*") if int(p.name.split("-")[1]) != os.getpid()]
    assert in_workers == []
    assert len(list(tmp_path.glob("eval-*"))) > 20  # many calls, all here
    assert not list(tmp_path.glob("delivery-*"))     # nothing was even sent to the workers


def test_process_workers_bad_input():
    with pytest.raises(ValueError, match="n_workers"):
        ProcessWorkers(0)
