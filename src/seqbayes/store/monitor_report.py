"""What ``seqbayes status`` (text and ``--json``) and ``seqbayes report`` show of a monitor run
(:mod:`seqbayes.store.monitor`): per day P(damage), the location (where the model gives one), the size and the
first day of the loss with their 95 % intervals, the alarm state, and the environmental law learned by the last
day (thermal lag, freezing knee, discrepancy, each mode's temperature coefficient with its interval)."""

from __future__ import annotations

from pathlib import Path

from .pages import page, table_html, write_page

__all__ = ["damage_text", "format_status", "status_record", "write_monitor_report", "environment_rows"]


def _interval(estimate, scale: float = 1.0, digits: int = 3) -> str:
    if estimate is None:
        return "-"
    return (f"{scale * estimate['mean']:.{digits}g} [{scale * estimate['lower']:.{digits}g}, "
            f"{scale * estimate['upper']:.{digits}g}]")


def damage_text(info: dict) -> str:
    """``P(damage) p`` and, where a loss is likely (above 0.5), where, how large and since when."""
    damage = info["damage"]
    text = f"P(damage) {info['p_damage']:.3g}"
    if info["p_damage"] > 0.5 and damage["size"] is not None:
        where = f" in element {damage['location']}" if damage["location"] is not None else (
            f" in mode(s) {', '.join(str(i + 1) for i, p in enumerate(damage['class_probabilities']) if p > 0.5)}")
        text += (f"{where}, loss {_interval(damage['size'], 100)} %, since day {_interval(damage['day'])}")
    return text


def environment_rows(info: dict) -> list:
    """``(quantity, mean, 2.5 %, 97.5 %)`` rows of the learned environment in a day's record."""
    env = info["environment"]
    rows = [(name, e["mean"], e["lower"], e["upper"]) for name, e in env["static"].items()]
    rows += [(f"coefficient {name}", e["mean"], e["lower"], e["upper"]) for name, e in env["coefficients"].items()]
    return rows


def format_status(store) -> str:
    """The status table: one line per day, then the alarm state and the learned environment."""
    c = store.config
    lines = [store.describe()]
    if not store.n_steps:
        return "\n".join(lines + ["no dataset assimilated yet"])
    lines.append(f"{'step':>5} {'day':>5} {'sets':>5} {'P(damage)':>10} {'where':>8} {'loss % [95 %]':>22} "
                 f"{'first day [95 %]':>20} {'alarm':>5}")
    for info in store.infos:
        d = info["damage"]
        likely = info["p_damage"] > 0.5 and d["size"] is not None
        where = (d["location"] if d["location"] is not None else
                 ",".join(str(i + 1) for i, p in enumerate(d["class_probabilities"]) if p > 0.5)) if likely else "-"
        lines.append(f"{info['step']:>5} {info['day']:>5} {info['n_sets']:>5} {info['p_damage']:>10.3g} "
                     f"{where or '-':>8} {_interval(d['size'], 100) if likely else '-':>22} "
                     f"{_interval(d['day']) if likely else '-':>20} {'YES' if info['alarm'] else 'no':>5}")
    last = store.infos[-1]
    lines.append(f"alarm: {'RAISED' if last['alarm'] else 'not raised'} (P(damage) > {c.threshold:g} for "
                 f"{last['days_above']} day(s) in a row; the rule needs {c.consecutive}); log-evidence "
                 f"{last['log_evidence']:.4f}")
    lines.append("learned environment (posterior mean [95 % interval]; coefficients in log-frequency per degC, "
                 "given no damage):")
    lines += [f"  {name:<28} {mean:.4g} [{lo:.4g}, {hi:.4g}]" for name, mean, lo, hi in environment_rows(last)]
    return "\n".join(lines)


def status_record(store) -> dict:
    """What ``seqbayes status --json`` prints: the run, each day's record, the alarm and the environment."""
    last = store.infos[-1] if store.infos else None
    return {"run": str(store.path), "model": store.config.name, "kind": "monitor", "steps": store.infos,
            "alarm": bool(last["alarm"]) if last else False,
            "p_damage": last["p_damage"] if last else None,
            "damage": last["damage"] if last else None,
            "environment": last["environment"] if last else None}


def _render(store, image_dir=None) -> str:
    c = store.config
    sections = [f"<p>{store.describe()}</p>"]
    if not store.n_steps:
        return page(f"Monitor {c.name}", sections + ["<p>No dataset assimilated yet.</p>"])
    rows = []
    for info in store.infos:
        d = info["damage"]
        rows.append((info["step"], info["day"], info["n_sets"], f"{info['p_damage']:.3g}", d["location"] or "-",
                     _interval(d["size"], 100), _interval(d["day"]), "ALARM" if info["alarm"] else ""))
    last = store.infos[-1]
    sections += [f"<h2>Alarm: {'raised' if last['alarm'] else 'not raised'}</h2>",
                 "<h2>Days</h2>", table_html(("step", "day", "sets", "P(damage)", "element", "loss % [95 %]",
                                              "first day [95 %]", "alarm"), rows),
                 "<h2>Learned environment (last day)</h2>",
                 table_html(("quantity", "mean", "2.5 %", "97.5 %"),
                            [(n, f"{m:.4g}", f"{lo:.4g}", f"{hi:.4g}") for n, m, lo, hi in environment_rows(last)])]
    return page(f"Monitor {c.name}", sections)


def write_monitor_report(store, output: Path, embed: bool = True) -> Path:
    """Write the report page atomically (:func:`seqbayes.store.pages.write_page`)."""
    return write_page(output, lambda image_dir=None: _render(store, image_dir), embed)
