"""Status tables, forecasts tables and the HTML report of monitoring runs.

:func:`status_rows` / :func:`format_status` give the per-step table of the
``seqbayes status`` command, :func:`forecast_rows` the ``predict`` table and
:func:`write_report` the self-contained HTML page of ``seqbayes report`` (the
figures are embedded as base64 PNG, so the page is one file that opens
anywhere without network access and without JavaScript).
"""

from __future__ import annotations

import html
import math
import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from .. import plotting
from .datasets import printable
from .pages import figure_html, fmt, page, table_html, text, write_page

if TYPE_CHECKING:
    import os

    from ..prognostics import FirstPassage, Threshold
    from ..selection import ModelComparison
    from .base import BaseStore

__all__ = ["status_rows", "format_status", "forecast_rows", "format_forecast", "comparison_rows",
           "first_passage_rows", "first_passage_json", "format_first_passage", "describe_prior", "describe_kernel",
           "write_report", "render_report", "ESS_NOTE"]

#: What the ESS shown by ``status``, ``update`` and the report is.
ESS_NOTE = ("ESS: effective sample size (sum w)^2 / sum w^2 of the importance weights at the step's last "
            "tempering stage, before resampling (N for equal weights, 1 when one sample holds all the weight). "
            "distinct: distinct samples in the step's final set, after resampling and moves.")


def _tails(level):
    if not 0.0 < level < 1.0:
        raise ValueError(f"level: must lie in (0, 1), got {level}")
    tail = 0.5 * (1.0 - level)
    return tail, 1.0 - tail


def status_rows(store: BaseStore, level: float = 0.95) -> list[dict]:
    """One dict per step: dataset, diagnostics, and per-parameter mean, sd and credible interval.

    Keys: ``step, dataset, likelihood_sha256, acceptance_rate, ess, n_distinct, resampled, log_evidence_increment,
    log_evidence, step_size, n_loglike_evals, wall_time, prior_data_conflict, conflict_parameter, inner_ess,
    jump_probability, jump_parameter, jump_size, jump_size_sd, jump_probability_se, parameters`` where
    ``parameters`` maps each name to ``{mean, sd, lower, upper}`` (the central
    ``level`` interval).
    """
    lo, hi = _tails(level)
    rows = []
    for i, record in enumerate(store.result.steps):
        info = record.info
        mean, sd, q = record.mean(), record.std(), record.quantile([lo, hi])
        rows.append({
            "step": int(info.step), "dataset": store.sources[i],
            "likelihood_sha256": store.module_hashes[i] if i < len(getattr(store, "module_hashes", ())) else "",
            "acceptance_rate": float(info.acceptance_rate),
            "ess": float(info.ess), "n_distinct": int(info.n_distinct), "resampled": bool(info.resampled),
            "log_evidence_increment": float(info.log_evidence_increment), "log_evidence": float(info.log_evidence),
            "step_size": float(info.step_size), "n_loglike_evals": int(info.n_loglike_evals),
            "wall_time": float(info.wall_time),
            # posterior-mean shift in prior sds (> 4: prior-data conflict) and its parameter; SMC^2's inner ESS
            "prior_data_conflict": float(info.prior_data_conflict),
            "conflict_parameter": store.names[int(info.conflict_parameter)], "inner_ess": float(info.inner_ess),
            # jump kernels: P(a jump into this step), the parameter, its drop fraction (NaN without jumps)
            "jump_probability": float(info.jump_probability), "jump_parameter": store.names[int(info.jump_parameter)],
            "jump_size": float(info.jump_size), "jump_size_sd": float(info.jump_size_sd),
            "jump_probability_se": float(getattr(info, "jump_probability_se", float("nan"))),
            "parameters": {name: {"mean": float(mean[j]), "sd": float(sd[j]), "lower": float(q[0, j]),
                                  "upper": float(q[1, j])} for j, name in enumerate(store.names)},
        })
    return rows


#: What ``-`` in an acceptance column means (``status`` and the report say the same).
NO_MOVES_NOTE = "accept '-': the step moved no samples (SMC^2 moves them only when their ESS falls)."


def _acceptance(rate: float) -> str:
    """A step's acceptance rate as ``status`` and the report print it: ``-`` for a step without moves (NaN)."""
    return "-" if np.isnan(rate) else f"{rate:.3f}"


def format_status(store: BaseStore, level: float = 0.95) -> str:
    """The ``status`` command's plain-text tables."""
    cfg = store.config
    # names from files (the store's path, the config, data file names) are escaped for the terminal
    lines = [f"run {printable(store.path)}  model '{printable(cfg.name)}'  likelihood {printable(cfg.likelihood)}  "
             f"sampler {printable(cfg.sampler)} N={cfg.n_samples} seed={cfg.seed}  steps: {store.n_steps}"]
    if store.n_steps == 0:
        lines.append("no dataset assimilated yet (use `seqbayes update RUN DATAFILE`)")
        return "\n".join(lines)
    rows = status_rows(store, level)
    n = cfg.n_samples
    lines.append("")
    lines.append(f"{'step':>4}  {'dataset':<24} {'accept':>7} {'ESS':>8} {'ESS/N':>6} {'distinct':>8} {'log Z_s':>11}"
                 f" {'log Z':>11} {'conflict':>8}")
    for r in rows:
        flag = f" (!{r['conflict_parameter']})" if r["prior_data_conflict"] > 4 else ""
        accept = _acceptance(r["acceptance_rate"])
        lines.append(f"{r['step']:>4}  {printable(r['dataset'])[:24]:<24} {accept:>7} {r['ess']:8.1f} "
                     f"{r['ess'] / n:6.3f} {r['n_distinct']:8d} {r['log_evidence_increment']:11.4f} "
                     f"{r['log_evidence']:11.4f} {r['prior_data_conflict']:8.2f}{flag}")
    note = f"({ESS_NOTE} conflict: posterior-mean shift in prior sds, flagged above 4."
    if any(np.isnan(r["acceptance_rate"]) for r in rows):
        note += " " + NO_MOVES_NOTE
    lines += textwrap.wrap(note + ")", 100)
    previous = rows[0]["likelihood_sha256"]
    for r in rows[1:]:   # an edited likelihood module accepted with --accept-model-change
        if r["likelihood_sha256"] != previous:
            lines.append(f"note: the likelihood module changed at step {r['step']} (sha256 {previous[:12] or '?'} -> "
                         f"{r['likelihood_sha256'][:12] or '?'})")
            previous = r["likelihood_sha256"]
    lines += _jump_lines(rows)
    pct = f"{level:.0%}"
    lines.append("")
    lines.append(f"{'step':>4}  {'parameter':<14} {'mean':>11} {'sd':>11} {pct + ' lower':>11} {pct + ' upper':>11}")
    for r in rows:
        for name, p in r["parameters"].items():
            lines.append(f"{r['step']:>4}  {printable(name)[:14]:<14} {fmt(p['mean']):>11} {fmt(p['sd']):>11} "
                         f"{fmt(p['lower']):>11} {fmt(p['upper']):>11}")
    return "\n".join(lines)


def _jump_rows(rows) -> list[list]:
    """``[step, P(jump), se, parameter, drop fraction, its sd]`` of the steps with a jump probability."""
    return [[r["step"], f"{r['jump_probability']:.4f}", fmt(r["jump_probability_se"]), r["jump_parameter"],
             fmt(r["jump_size"]), fmt(r["jump_size_sd"])] for r in rows if np.isfinite(r["jump_probability"])]


def _jump_lines(rows) -> list[str]:
    jumps = _jump_rows(rows)
    if not jumps:
        return []
    out = ["", f"{'step':>4}  {'P(jump)':>8} {'+- se':>8}  {'parameter':<14} {'drop':>9} {'sd':>9}"]
    out += [f"{j[0]:>4}  {j[1]:>8} {j[2]:>8}  {j[3][:14]:<14} {j[4]:>9} {j[5]:>9}" for j in jumps]
    return out + ["(P(jump): posterior probability of a jump into the step, +- its Monte Carlo standard error; "
                  "drop: the fraction of the reference, given a jump.)"]


def forecast_rows(store: BaseStore, n_steps: int, level: float = 0.95,
                  forecast: np.ndarray | None = None) -> list[dict]:
    """Forecast summary ``K`` steps ahead: one dict per (ahead, parameter) with mean, sd, interval."""
    lo, hi = _tails(level)
    draws = store.predict(n_steps) if forecast is None else forecast
    rows = []
    for k in range(draws.shape[0]):
        q = np.quantile(draws[k], [lo, hi], axis=0)
        for j, name in enumerate(store.names):
            rows.append({"step": store.n_steps + k + 1, "ahead": k + 1, "parameter": name,
                         "mean": float(draws[k, :, j].mean()), "sd": float(draws[k, :, j].std()),
                         "lower": float(q[0, j]), "upper": float(q[1, j])})
    return rows


def format_forecast(rows: Sequence[dict], level: float = 0.95) -> str:
    pct = f"{level:.0%}"
    lines = [f"{'step':>4} {'ahead':>5}  {'parameter':<14} {'mean':>11} {'sd':>11} {pct + ' lower':>11} "
             f"{pct + ' upper':>11}"]
    for r in rows:
        lines.append(f"{r['step']:>4} {r['ahead']:>5}  {r['parameter'][:14]:<14} {fmt(r['mean']):>11} "
                     f"{fmt(r['sd']):>11} {fmt(r['lower']):>11} {fmt(r['upper']):>11}")
    return "\n".join(lines)


def _num(x) -> str:
    return f"{x:.4g}"


def describe_prior(spec: dict) -> str:
    """A configuration's prior ``{"dist", "args", "kwds"}`` in the usual notation.

    ``uniform`` -> ``U(lower, upper)``, ``norm`` -> ``N(mean, sd)``, ``lognorm`` ->
    ``LogN(mu, sigma)`` (of the logarithm), ``truncnorm`` -> ``N(mean, sd) on [a, b]``,
    ``expon``, ``gamma``, ``beta``, ``halfnorm``; any other scipy.stats name as
    ``name(shape=..., loc=..., scale=...)``.

    Examples
    --------
    >>> describe_prior({"dist": "uniform", "args": [], "kwds": {"loc": 0.0, "scale": 5.0}})
    'U(0, 5)'
    >>> describe_prior({"dist": "norm", "args": [1.0, 0.2], "kwds": {}})
    'N(1, 0.2)'
    """
    from scipy import stats

    name = spec["dist"]
    dist = getattr(stats, name, None)
    shapes = [p.strip() for p in (getattr(dist, "shapes", None) or "").split(",") if p.strip()]
    values = dict(zip([*shapes, "loc", "scale"], spec.get("args", ())))
    values.update(spec.get("kwds", {}))
    loc, scale = float(values.pop("loc", 0.0)), float(values.pop("scale", 1.0))
    if name == "uniform" and not values:
        return f"U({_num(loc)}, {_num(loc + scale)})"
    if name == "norm" and not values:
        return f"N({_num(loc)}, {_num(scale)})"
    if name == "lognorm" and set(values) == {"s"} and loc == 0.0:
        return f"LogN({_num(math.log(scale))}, {_num(values['s'])})"
    if name == "truncnorm" and set(values) == {"a", "b"}:
        return (f"N({_num(loc)}, {_num(scale)}) on [{_num(loc + values['a'] * scale)}, "
                f"{_num(loc + values['b'] * scale)}]")
    if name == "halfnorm" and not values and loc == 0.0:
        return f"HalfN({_num(scale)})"
    if name == "expon" and not values and loc == 0.0:
        return f"Exp(mean {_num(scale)})"
    if name == "gamma" and set(values) == {"a"} and loc == 0.0:
        return f"Gamma({_num(values['a'])}, scale {_num(scale)})"
    if name == "beta" and set(values) == {"a", "b"} and (loc, scale) == (0.0, 1.0):
        return f"Beta({_num(values['a'])}, {_num(values['b'])})"
    parts = [f"{k}={_num(float(v))}" for k, v in values.items()]
    parts += [f"loc={_num(loc)}"] * (loc != 0.0) + [f"scale={_num(scale)}"] * (scale != 1.0)
    return f"{name}({', '.join(parts)})"


def describe_kernel(spec: dict) -> str:
    """A configuration's kernel entry ``{"type", "rate", "noise_std"}`` as its transition.

    Examples
    --------
    >>> describe_kernel({"type": "drift", "rate": -0.05, "noise_std": 0.02})
    'x - 0.05 + N(0, 0.02)'
    >>> describe_kernel({"type": "static", "rate": 0.0, "noise_std": 0.0})
    'static'
    >>> describe_kernel({"type": "jump", "base": "decay", "rate": 0.02, "noise_std": 0.02, "p": 0.05,
    ...                  "drop_mean": 0.3, "drop_sd": 0.1, "reference": 3.0, "scales": [1.0], "scale_weights": [1.0]})
    'exp(-0.02) x + N(0, 0.02); w.p. 0.05 minus 3 x N(0.3, 0.1)'
    """
    kind, rate, noise = spec["type"], float(spec.get("rate", 0.0)), float(spec.get("noise_std", 0.0))
    if kind == "jump":   # the base's transition, and the drop with its probability
        tail = "" if list(spec["scales"]) == [1.0] else f", slab sds x {list(spec['scales'])} w {list(spec['scale_weights'])}"
        return (describe_kernel({"type": spec["base"], "rate": rate, "noise_std": noise})
                + f"; w.p. {_num(spec['p'])} minus {_num(spec['reference'])} x N({_num(spec['drop_mean'])}, "
                  f"{_num(spec['drop_sd'])}){tail}")
    if kind == "static":
        return "static"
    if kind == "drift":
        base = f"x {'-' if rate < 0 else '+'} {_num(abs(rate))}"
    elif kind == "decay":
        base = f"exp(-{_num(rate)}) x"
    else:
        base = f"{kind}(rate {_num(rate)})"
    return f"{base} + N(0, {_num(noise)})" if noise > 0 else base


def first_passage_rows(store: BaseStore, threshold: Threshold, passage: FirstPassage) -> list[dict]:
    """Per future step ``h``: the step, ``P(first crossing at h)``, ``P(crossed by h)`` and their Monte
    Carlo standard errors."""
    return [{"step": store.n_steps + h + 1, "ahead": h + 1, "probability": float(passage.probability[h]),
             "standard_error": float(passage.standard_error[h]), "cumulative": float(passage.cumulative[h]),
             "cumulative_standard_error": float(passage.cumulative_standard_error[h])}
            for h in range(passage.horizon)]


def first_passage_json(store: BaseStore, threshold: Threshold, passage: FirstPassage) -> dict:
    """The time to ``threshold`` (a :class:`~seqbayes.prognostics.Threshold`) as a JSON-able dict."""
    median = passage.quantile(0.5)
    return {"parameter": threshold.name, "direction": threshold.direction, "threshold": threshold.value,
            "from_step": store.n_steps, "beyond_now": passage.beyond_now, "not_crossed": passage.not_crossed,
            "not_crossed_standard_error": passage.not_crossed_standard_error, "n_paths": passage.n_paths,
            "median_step": None if math.isinf(median) else store.n_steps + int(median),
            "left_support": None if math.isnan(passage.left_support) else passage.left_support,
            "steps": first_passage_rows(store, threshold, passage)}


def _passage_summary(store: BaseStore, threshold: Threshold, passage: FirstPassage) -> str:
    median = passage.quantile(0.5)
    when = (f"median first crossing at step {store.n_steps + int(median)}" if math.isfinite(median)
            else f"median first crossing after step {store.n_steps + passage.horizon}")
    return (f"time to {threshold} from step {store.n_steps} ({passage.n_paths} kernel paths): {when}; "
            f"P(not crossed by step {store.n_steps + passage.horizon}) = {passage.not_crossed:.4f} +- "
            f"{passage.not_crossed_standard_error:.4f}; already beyond now: {passage.beyond_now:.4f}"
            + (f"; {passage.left_support:.4f} of the paths left the parameter space before crossing (the "
               f"probabilities are the kernel's, unrestricted)" if passage.left_support > 0 else ""))


def format_first_passage(store: BaseStore, threshold: Threshold, passage: FirstPassage) -> str:
    """The ``predict --threshold`` plain-text table (``+-`` one Monte Carlo standard error)."""
    lines = [_passage_summary(store, threshold, passage),
             f"{'step':>4} {'ahead':>5} {'P(first at step)':>18} {'+-':>7} {'P(crossed by step)':>19} {'+-':>7}"]
    for r in first_passage_rows(store, threshold, passage):
        lines.append(f"{r['step']:>4} {r['ahead']:>5} {r['probability']:18.4f} {r['standard_error']:7.4f} "
                     f"{r['cumulative']:19.4f} {r['cumulative_standard_error']:7.4f}")
    return "\n".join(lines)


def comparison_rows(comparison: ModelComparison) -> list[dict]:
    """Per step and model: cumulative log-evidence, increment, probability."""
    rows = []
    for s in range(comparison.log_evidence.shape[0]):
        for j, name in enumerate(comparison.names):
            rows.append({"step": s + 1, "model": name, "log_evidence": float(comparison.log_evidence[s, j]),
                         "log_evidence_increment": float(comparison.log_evidence_increments[s, j]),
                         "probability": float(comparison.probabilities[s, j])})
    return rows


# ------------------------------------------------------------------ HTML report
def _threshold_section(store, thresholds, horizon, image_dir) -> str:
    """The report's time-to-threshold section: a summary and a table per threshold, one CDF figure."""
    passages = [(t, store.time_to_threshold(t.name, t.value, horizon, direction=t.direction)) for t in thresholds]
    out = ["<h2>Time to a threshold</h2>",
           f"<p>The last posterior propagated {horizon} steps through the kernel: the probability that the "
           f"parameter first crosses the threshold at each future step, and that it has crossed by then, "
           f"+- one Monte Carlo standard error (the band in the figure is +- 2).</p>"]
    out.append(figure_html(plotting.plot_first_passage([(str(t), p) for t, p in passages], start_step=store.n_steps),
                            "Time to a threshold: P(crossed by step) with +- 2 Monte Carlo standard errors",
                            "fig-threshold", image_dir))
    for threshold, passage in passages:
        out.append(f"<p>{html.escape(_passage_summary(store, threshold, passage))}</p>")
        out.append(table_html(["step", "ahead", "P(first at step)", "+-", "P(crossed by step)", "+-"],
                               [[r["step"], r["ahead"], f"{r['probability']:.4f}", f"{r['standard_error']:.4f}",
                                 f"{r['cumulative']:.4f}", f"{r['cumulative_standard_error']:.4f}"]
                                for r in first_passage_rows(store, threshold, passage)], left=()))
    return "\n".join(out)


def _fit_section(store: BaseStore, fit_data: tuple[int, np.ndarray] | None, level: float,
                 image_dir: Path | None) -> str:
    """The data-versus-fit panel: a dataset and the model's prediction at that step's posterior draws."""
    from .datasets import as_likelihood_data

    cfg = store.config
    out = ["<h2>Data versus fit</h2>"]
    if cfg.predict is None:
        return "\n".join(out + ["<p>Not shown: name a prediction function in the configuration "
                                 "(<code>[model] predict = \"predict\"</code>, a function of the likelihood's module, "
                                 "<code>predict(theta (N, d), data) -&gt; (N, n_rows)</code>).</p>"])
    if fit_data is None and len(store.tables) == store.n_steps:
        fit_data = (store.n_steps - 1, np.asarray(store.tables[-1]))
    if fit_data is None:
        return "\n".join(out + ["<p>Not shown: this run does not keep its datasets; give one of them "
                                 "(<code>seqbayes report RUN --data FILE</code>).</p>"])
    index, table = fit_data
    record = store.result.steps[index]
    observed = cfg.observed or cfg.columns[-1]
    column = cfg.columns.index(observed)
    abscissa = cfg.columns[0] if cfg.columns[0] != observed else None
    theta = record.equal_weight_samples(np.random.default_rng(0), min(200, record.posterior.shape[0]))
    values = np.asarray(store.load_predict()(theta, as_likelihood_data(table, cfg)), dtype=float)
    if values.shape != (theta.shape[0], table.shape[0]):
        raise ValueError(f"predict: {cfg.predict} returned shape {values.shape} for theta of shape {theta.shape} and "
                         f"{table.shape[0]} data rows; expected ({theta.shape[0]}, {table.shape[0]})")
    x = table[:, 0] if abscissa else np.arange(1, table.shape[0] + 1)
    fig = plotting.plot_data_fit(x, table[:, column], values, level=level, xlabel=abscissa or "row", ylabel=observed)
    caption = (f"Step {record.info.step} ({store.sources[index]}): the data of column {observed!r} and the model's "
               f"prediction ({cfg.predict}) at {theta.shape[0]} draws of the step's posterior: mean and {level:.0%} "
               f"band (the posterior's uncertainty, without the observation noise)")
    out.append(figure_html(fig, caption, "fig-fit", image_dir))
    return "\n".join(out)


def render_report(store: BaseStore, *, others: Sequence[BaseStore] = (), forecast_steps: int = 3,
                  level: float = 0.95, image_dir: Path | None = None,
                  thresholds: Sequence[Threshold] = (), horizon: int = 20,
                  fit_data: tuple[int, np.ndarray] | None = None) -> str:
    """The HTML text of the report for ``store`` (and, for model comparison, ``others``).

    Parameters
    ----------
    store : RunStore
    others : sequence of RunStore
        Competing model classes on the same datasets (their evidence and probabilities are shown).
    forecast_steps : int
        Forecast horizon drawn after the last step (0: none).
    level : float
        Credible level of the bands and intervals.
    image_dir : pathlib.Path, optional
        Write figures as PNG files there instead of embedding them as base64.
    thresholds : sequence of Threshold
        Add the time to each threshold (:func:`seqbayes.prognostics.parse_threshold`).
    horizon : int
        Steps ahead simulated for the time to a threshold.
    fit_data : (int, (n_rows, n_columns) array), optional
        A step index and the dataset it assimilated, for the data-versus-fit panel (needs the
        configuration's ``[model] predict``); default: the last dataset when the store keeps the
        datasets (static or SMC^2 runs), else no panel.
    """
    from ..selection import compare

    if store.n_steps == 0:
        raise ValueError(f"{store.path}: no step to report yet (run `seqbayes update` first)")
    cfg = store.config
    parts = []
    # every field of a stored configuration is text from a file someone was handed: escaped, all of it
    parts.append(f"<p>Run <code>{text(store.path)}</code>: likelihood <code>{text(cfg.likelihood)}</code>, sampler "
                 f"{text(cfg.sampler)} with N = {text(cfg.n_samples)}, seed {text(cfg.seed)}; {store.n_steps} "
                 f"dataset(s) assimilated. Model fingerprint <code>{text(cfg.fingerprint()[:12])}</code>.</p>")
    kernel_rows = [[n, describe_prior(cfg.priors[n]), describe_kernel(cfg.kernel[n])] for n in cfg.names]
    parts.append("<h2>Model</h2>" + table_html(["parameter", "prior", "evolution between steps"], kernel_rows,
                                                left=(0, 1, 2)))
    parts.append("<p>U(lower, upper): uniform; N(mean, sd): normal; LogN(mu, sigma): log-normal, "
                 "mu and sigma of the logarithm. Evolution: x is the parameter at the step before; "
                 "N(0, sd) the kernel's process noise.</p>")

    forecast = store.predict(forecast_steps) if forecast_steps > 0 else None
    parts.append("<h2>Parameter evolution</h2>")
    fig = plotting.plot_parameter_evolution(store.result, level=level, forecast=forecast)
    caption = (f"Posterior mean and {level:.0%} credible band per step"
               + (f", with the {forecast_steps}-step forecast (dashed)" if forecast is not None else ""))
    parts.append(figure_html(fig, caption, "fig-parameters", image_dir))

    rows = status_rows(store, level)
    pct = f"{level:.0%}"
    param_rows = [[r["step"], name, fmt(p["mean"]), fmt(p["sd"]), fmt(p["lower"]), fmt(p["upper"])]
                  for r in rows for name, p in r["parameters"].items()]
    parts.append(table_html(["step", "parameter", "mean", "sd", f"{pct} lower", f"{pct} upper"], param_rows,
                             left=(1,)))
    if _jump_rows(rows):
        parts.append("<h2>Jumps</h2>" + table_html(["step", "P(jump)", "+- se", "parameter", "drop fraction", "sd"],
                                                   _jump_rows(rows), left=(3,)))
    if forecast is not None:
        parts.append("<h2>Forecast</h2>")
        frows = forecast_rows(store, forecast_steps, level, forecast)
        parts.append(table_html(["step", "ahead", "parameter", "mean", "sd", f"{pct} lower", f"{pct} upper"],
                                 [[r["step"], r["ahead"], r["parameter"], fmt(r["mean"]), fmt(r["sd"]),
                                   fmt(r["lower"]), fmt(r["upper"])] for r in frows], left=(2,)))
    if thresholds:
        parts.append(_threshold_section(store, thresholds, horizon, image_dir))
    parts.append(_fit_section(store, fit_data, level, image_dir))

    runs = {store.config.name: store.result}
    for other in others:
        name = other.config.name
        if name in runs:
            name = f"{name} ({other.path.name})"
        runs[name] = other.result
    parts.append("<h2>Sampler diagnostics</h2>")
    target = cfg.settings.get("target_acceptance")
    if target is None and cfg.sampler == "SEMC":
        target = 0.21 / len(cfg.names) + 0.23  # Eq. (10), the sampler's default
    parts.append(figure_html(plotting.plot_sampler_diagnostics(runs, target_acceptance=target),
                              "Acceptance rate and effective sample size (ESS / N, last tempering stage, before "
                              "resampling) per step", "fig-diagnostics", image_dir))
    parts.append(table_html(["step", "dataset", "acceptance", "ESS", "distinct", "log Z_s", "log Z"],
                             [[r["step"], r["dataset"], _acceptance(r["acceptance_rate"]), f"{r['ess']:.1f}",
                               r["n_distinct"], f"{r['log_evidence_increment']:.4f}", f"{r['log_evidence']:.4f}"]
                              for r in rows], left=(1,)))
    parts.append(f"<p>{html.escape(ESS_NOTE)} N = {text(cfg.n_samples)}."
                 + (f" {NO_MOVES_NOTE}" if any(np.isnan(r["acceptance_rate"]) for r in rows) else "") + "</p>")
    parts.append("<h2>Evidence and model probabilities</h2>")
    parts.append(figure_html(plotting.plot_evidence(runs), "Cumulative log-evidence and per-step increments",
                              "fig-evidence", image_dir))
    n_common = min(len(r.steps) for r in runs.values())
    comparison = compare({k: v.log_evidence[:n_common] for k, v in runs.items()})
    parts.append(figure_html(plotting.plot_model_probabilities(comparison),
                              "Posterior model probabilities (equal prior probabilities)", "fig-probabilities",
                              image_dir))
    parts.append(table_html(["step", "model", "log Z", "probability"],
                             [[r["step"], r["model"], f"{r['log_evidence']:.4f}", f"{r['probability']:.4f}"]
                              for r in comparison_rows(comparison)], left=(1,)))
    parts.append(f"<p>Most probable model after step {n_common}: <strong>{html.escape(comparison.best)}</strong></p>")
    return page(f"seqbayes report: {cfg.name}", parts)


def write_report(store: BaseStore, output: str | os.PathLike, **kwargs: Any) -> Path:
    """Write :func:`render_report` to ``output`` (an ``.html`` file; ``embed=False``: the figures as PNG files in
    ``<output stem>_figures/``); returns its path."""
    return write_page(output, lambda **k: render_report(store, **k), **kwargs)
