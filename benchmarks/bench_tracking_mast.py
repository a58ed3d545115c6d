"""The guyed mast's three weeks (issue 38): every hourly record's poles tracked into modes, the coverage and
scatter per mode, the tracked frequencies against temperature, and the tracked table through a run store.

    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_tracking_mast.py [--figure docs/figures/mast_tracking.png]
    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_tracking_mast.py --run [--samples 300]
    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_tracking_mast.py --synthetic [--seeds 10]
    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_tracking_mast.py --samplers [--hours 60]
    OPENBLAS_NUM_THREADS=1 .venv/bin/python benchmarks/bench_tracking_mast.py --remedy [--hours 20]

The data are the bundled ``seqbayes/data/guyed_mast`` files (Marwitz, Bauhaus-Universitat Weimar, MIT licence;
PROVENANCE.md beside them). Without options: the tracker's modes, fitted noise, the per-mode table
(docs/modal.md), the correlation of each mode's tracked frequency with the temperature and its slope, the
consistency checks of the close pairs, and the figure. With ``--run``: ``seqbayes track`` into a temporary
folder, ``seqbayes init`` of the run.toml it writes and ``seqbayes update`` of every hour in one command
(timed), then the run's posterior against the exact filter of the same model (the mode-level posterior
factorises over the modes: one 1-D grid filter per mode, :func:`seqbayes.structural.modal_references.mode_level_reference`).
With ``--samplers``: the first ``--hours`` of the same run through the Python API with other sampler
settings (N, SMC, more moves), each against the exact filter. With ``--remedy``: the first ``--hours`` with the
path-space remedy on and off (the run.toml turns it off): likelihood evaluations and time per step. With ``--synthetic``: the tracker on simulated
poles with known modes
(:func:`seqbayes.structural.modal_references.simulate_poles`, 7 days each): modes found, poles given to
another mode, clutter accepted.
"""

import argparse
import contextlib
import io
import os
import tempfile
import time
from importlib import resources
from pathlib import Path

import numpy as np

from seqbayes.structural.modes_table import read_covariates, read_modes_table
from seqbayes.structural.tracking import track_poles

MAST = resources.files("seqbayes") / "data" / "guyed_mast"
#: hourly slices the authors' OMA ran on (PROVENANCE.md; 468 of them kept poles)
SLICES = 495


def _load():
    try:
        return f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores"
    except OSError:
        return "load unknown"


def _temperature(tracked):
    day, values = read_covariates(MAST / "temperature_60min.csv")
    stacked = np.column_stack(list(values.values()))
    counts = np.isfinite(stacked).sum(axis=1)
    mean = np.where(counts > 0, np.nansum(stacked, axis=1) / np.maximum(counts, 1), np.nan)
    index = np.array([np.argmin(np.abs(day - d)) for d in tracked.day])
    return mean[index], day.size, int(np.isfinite(mean).sum())


def summary(figure=None):
    start = time.perf_counter()
    poles = read_modes_table(MAST / "poles_60min.csv")
    tracked = track_poles(poles)
    seconds = time.perf_counter() - start
    ref = tracked.reference
    temperature, n_hours, n_with_temperature = _temperature(tracked)
    print(f"{len(tracked.rows)} records with poles ({n_hours} hourly slices in the temperature file, "
          f"{n_with_temperature} with a temperature), {poles.n_rows} poles; tracked in {seconds:.2f} s ({_load()})")
    print(f"modes found in the first 3 days: {', '.join(f'{f:.4f}' for f in ref.frequencies)} Hz")
    print("fitted per track: drift per hour " + ", ".join(f"{v:.2g}" for v in ref.drift) + " Hz; scatter "
          + ", ".join(f"{v:.2g}" for v in ref.scatter) + " Hz; weight of the SSI's own sd "
          + ", ".join(f"{v:.2g}" for v in ref.std_scale))
    rel = poles.std_frequency / poles.frequency
    print(f"the SSI's own standard errors: median {100 * np.median(rel):.2f} % of the frequency, against a "
          f"scatter about the tracks of {100 * np.median(ref.scatter / ref.frequencies):.2f} % (median over modes)")
    spurious = int(tracked.spurious.sum())
    print(f"poles assigned to no mode: {spurious} ({100 * spurious / poles.n_rows:.1f} %)")
    print()
    print(tracked.summary())
    print()
    print(f"| mode | coverage of all {SLICES} slices | correlation with temperature | slope [%/degC] |")
    print("|---|---|---|---|")
    for j in range(ref.n_modes):
        f = tracked.frequency[:, j]
        ok = np.isfinite(f) & np.isfinite(temperature)
        r = np.corrcoef(f[ok], temperature[ok])[0, 1]
        slope = np.polyfit(temperature[ok], f[ok], 1)[0] / np.mean(f[ok])
        print(f"| {j + 1} | {100 * np.isfinite(f).sum() / SLICES:.1f} % | {r:.2f} | {100 * slope:.3f} |")
    for a, b in ((0, 1), (2, 3)):
        both = np.isfinite(tracked.frequency[:, a]) & np.isfinite(tracked.frequency[:, b])
        crossed = int(np.sum(tracked.frequency[both, a] >= tracked.frequency[both, b]))
        gap = np.median(tracked.frequency[both, b] / tracked.frequency[both, a] - 1)
        print(f"close pair {a + 1}/{b + 1}: both in {both.sum()} records, median gap {100 * gap:.2f} %, "
              f"{crossed} records with the lower mode above the upper; the tracks cross "
              f"{int(np.sum(tracked.track_mean[:, a] >= tracked.track_mean[:, b]))} times")
    if figure:
        _figure(tracked, temperature, figure)
        print(f"figure: {figure}")
    return tracked


def _figure(tracked, temperature, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    m = tracked.n_modes
    fig, axes = plt.subplots(2, (m + 1) // 2, figsize=(3.0 * ((m + 1) // 2) + 1.5, 6.0), squeeze=False,
                             layout="constrained")
    for j, ax in enumerate(axes.flat):
        if j >= m:
            ax.axis("off")
            continue
        f = tracked.frequency[:, j]
        ok = np.isfinite(f) & np.isfinite(temperature)
        sc = ax.scatter(temperature[ok], f[ok], c=tracked.day[ok], s=5, cmap="viridis")
        fit = np.polyfit(temperature[ok], f[ok], 1)
        t = np.linspace(np.min(temperature[ok]), np.max(temperature[ok]), 2)
        ax.plot(t, np.polyval(fit, t), "k-", lw=1)
        ax.set_title(f"mode {j + 1} ({100 * ok.mean():.0f} %), r = {np.corrcoef(f[ok], temperature[ok])[0, 1]:.2f}",
                     fontsize=9)
        ax.set_xlabel("temperature [degC]", fontsize=8)
        ax.set_ylabel("frequency [Hz]", fontsize=8)
        ax.tick_params(labelsize=7)
    fig.colorbar(sc, ax=axes.ravel().tolist(), label="day")
    fig.suptitle("Guyed mast: tracked modes against the mean temperature (Marwitz, BU Weimar, MIT)", fontsize=10)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(n_samples: int):
    import glob
    import warnings

    from seqbayes.cli import main
    from seqbayes.store import open_run
    from seqbayes.structural.modal_references import mode_level_reference

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp)
        main(["track", str(MAST / "poles_60min.csv"), "--temperature", str(MAST / "temperature_60min.csv"),
              "--out", str(out), "--prefix", "hour"])
        toml = (out / "run.toml").read_text().replace("n_samples = 300", f"n_samples = {n_samples}")
        (out / "run.toml").write_text(toml)
        hours = sorted(glob.glob(str(out / "hour_*.csv")))
        main(["init", str(out / "run.toml"), str(out / "mast.nc")])
        start = time.perf_counter()
        with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()):   # the 465 step lines
            warnings.simplefilter("ignore")
            code = main(["update", str(out / "mast.nc"), *hours, "-q"])
        seconds = time.perf_counter() - start
        store = open_run(out / "mast.nc")
        infos = [s.info for s in store.result.steps]
        print(f"seqbayes update of {len(hours)} hourly datasets: exit {code}, {store.n_steps} steps in {seconds:.0f} s "
              f"({_load()}); {sum(i.n_loglike_evals for i in infos):,} likelihood evaluations (per step median "
              f"{np.median([i.n_loglike_evals for i in infos]):,.0f}, largest {max(i.n_loglike_evals for i in infos):,});"
              f" a step's sampler time median {np.median([i.wall_time for i in infos]):.2f} s, largest "
              f"{max(i.wall_time for i in infos):.2f} s")
        config = store.config
        like = config.build_likelihood()
        data = [{"mode": t.mode, "frequency_hz": t.frequency, "std_frequency_hz": np.nan_to_num(t.std_frequency)}
                for t in map(read_modes_table, hours)]
        box = np.array([[config.priors[n]["kwds"]["loc"], config.priors[n]["kwds"]["loc"]
                         + config.priors[n]["kwds"]["scale"]] for n in config.names])
        noise = np.array([config.kernel[n]["noise_std"] for n in config.names])
        ref = mode_level_reference(like, data, box, noise)
    result = store.result
    e = ref.errors(result.means(), result.stds(), result.log_evidence)
    seen = np.zeros(e["mean_sd"].shape, dtype=bool)
    for s, d in enumerate(data):
        seen[s, d["mode"] - 1] = True
    for label, mask in (("modes in the hour's dataset", seen), ("modes missing from it", ~seen)):
        m, sd = np.abs(e["mean_sd"][mask]), np.abs(e["std_ratio"][mask])
        print(f"against the exact filter, {label}: mean error median {np.median(m):.2f} sd, 95th percentile "
              f"{np.percentile(m, 95):.2f}, largest {m.max():.2f}; sd error median {100 * np.median(sd):.0f} %, "
              f"95th percentile {100 * np.percentile(sd, 95):.0f} %")
    print(f"cumulative log-evidence: run {result.log_evidence[-1]:.1f}, exact {ref.log_evidence[-1]:.1f} "
          f"(after 24 hours: {result.log_evidence[23]:.1f} vs {ref.log_evidence[23]:.1f})")


def _mast_problem(hours: int):
    """The tracked mast's first ``hours`` datasets, its run configuration and the exact filter."""
    from seqbayes.store import load_config
    from seqbayes.store.modal_files import track_to_folder
    from seqbayes.structural.modal_references import mode_level_reference

    with tempfile.TemporaryDirectory() as tmp:
        track_to_folder(MAST / "poles_60min.csv", tmp, prefix="hour")
        config = load_config(Path(tmp) / "run.toml")
        tables = [read_modes_table(p) for p in sorted(Path(tmp).glob("hour_*.csv"))[:hours]]
    data = [{"mode": t.mode, "frequency_hz": t.frequency, "std_frequency_hz": np.nan_to_num(t.std_frequency)}
            for t in tables]
    box = np.array([[config.priors[n]["kwds"]["loc"], config.priors[n]["kwds"]["loc"]
                     + config.priors[n]["kwds"]["scale"]] for n in config.names])
    noise = np.array([config.kernel[n]["noise_std"] for n in config.names])
    return config, data, mode_level_reference(config.build_likelihood(), data, box, noise)


def samplers(hours: int):
    import warnings

    from seqbayes import SEMC, SMC

    config, data, ref = _mast_problem(hours)
    print(f"the mast's first {hours} hourly datasets, the run.toml of seqbayes track (conflict_remedy off), against "
          f"the exact filter ({_load()}):")
    for label, cls, n, extra in (("SEMC, N = 300 (the run.toml)", SEMC, 300, {}),
                                 ("SEMC, N = 1000", SEMC, 1000, {}), ("SMC, N = 300", SMC, 300, {}),
                                 ("SEMC, N = 300, n_moves = 10", SEMC, 300, {"n_moves": 10}),
                                 ("SMC, N = 300, scaled moves", SMC, 300, {"scaled_moves": True})):
        start = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sampler = cls(config.build_prior(), config.build_kernel(), config.build_likelihood(), n_samples=n, rng=0,
                          **{**config.settings, **extra})
            result = sampler.run(data)
        e = ref.errors(result.means(), result.stds(), result.log_evidence)
        print(f"  {label}: mean error median {np.median(np.abs(e['mean_sd'])):.2f} sd, largest "
              f"{np.abs(e['mean_sd']).max():.2f}; sd error median {100 * np.median(np.abs(e['std_ratio'])):.0f} %, "
              f"largest {100 * np.abs(e['std_ratio']).max():.0f} %; log-evidence after {hours} hours "
              f"{e['log_evidence'][-1]:+.1f} nats; {time.perf_counter() - start:.0f} s")


def remedy(hours: int):
    import warnings

    from seqbayes import SEMC

    config, data, ref = _mast_problem(hours)
    print(f"the mast's first {hours} hours, SEMC N = {config.n_samples}, seed 0 ({_load()}):")
    for on in (False, True):
        settings = {**config.settings, "conflict_remedy": on}
        sampler = SEMC(config.build_prior(), config.build_kernel(), config.build_likelihood(),
                       n_samples=config.n_samples, rng=0, **settings)
        evals, seconds = [], []
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for dataset in data:
                start = time.perf_counter()
                info = sampler.update(dataset)
                seconds.append(time.perf_counter() - start)
                evals.append(info.n_loglike_evals)
        e = ref.errors(sampler.result.means(), sampler.result.stds(), sampler.result.log_evidence)
        print(f"  conflict_remedy = {str(on).lower()}: likelihood evaluations per step median {np.median(evals):,.0f}, "
              f"largest {max(evals):,} (step {int(np.argmax(evals)) + 1}); time per step median "
              f"{np.median(seconds):.2f} s, largest {max(seconds):.1f} s; mean error largest "
              f"{np.abs(e['mean_sd']).max():.2f} sd, log-evidence after {hours} hours {e['log_evidence'][-1]:+.1f} nats")


def synthetic(seeds: int):
    from seqbayes.structural.modal_references import simulate_poles

    rows = []
    for seed in range(seeds):
        table, truth = simulate_poles(np.random.default_rng(seed), days=7.0)
        tracked = track_poles(table)
        a = tracked.assignment
        wrong = (a > 0) & (truth != 0) & (np.abs(truth) != a)
        kept = np.mean([np.mean(a[truth == j] == j) for j in range(1, 7)]) if tracked.n_modes == 6 else np.nan
        rows.append((tracked.n_modes, wrong.sum() / (truth > 0).sum(), np.mean(a[truth == 0] > 0),
                     np.mean(a[truth < 0] > 0), kept))
    r = np.array(rows)
    print(f"simulated poles, {seeds} seeds of 7 days (6 modes, two pairs 1 % apart, duplicates 10 %, 2 clutter "
          f"poles a record): modes found {sorted(set(int(v) for v in r[:, 0]))}; poles given to another mode: mean "
          f"{100 * r[:, 1].mean():.2f} %, largest {100 * r[:, 1].max():.2f} %; clutter accepted: mean "
          f"{100 * r[:, 2].mean():.2f} %, largest {100 * r[:, 2].max():.2f} %; a true pole kept for its mode: "
          f"smallest share {np.nanmin(r[:, 4]):.3f} (a duplicate may stand in for it: duplicates accepted "
          f"{100 * r[:, 3].mean():.0f} %)")


def main_(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--figure", help="write the frequency-temperature figure here")
    parser.add_argument("--run", action="store_true", help="the tracked table through seqbayes init/update")
    parser.add_argument("--samples", type=int, default=300)
    parser.add_argument("--synthetic", action="store_true", help="the tracker on simulated poles with known modes")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--samplers", action="store_true", help="other sampler settings on the first hours")
    parser.add_argument("--hours", type=int, default=60)
    parser.add_argument("--remedy", action="store_true", help="the path-space remedy on and off, the first hours")
    args = parser.parse_args(argv)
    if args.remedy:
        remedy(args.hours)
        return
    if args.synthetic:
        synthetic(args.seeds)
        return
    if args.samplers:
        samplers(args.hours)
        return
    summary(args.figure)
    if args.run:
        print()
        run(args.samples)


if __name__ == "__main__":
    main_()
