"""What every command shares: the one-line error, bounded options, numeric warnings said once, output targets.

Every option that takes a number is parsed by :func:`bounded` or :func:`range_option`, so a value out of range is
one line at parse time; numpy's floating-point warnings are counted in :data:`NUMERIC` and said once when the
command ends (:func:`numeric_summary`); outputs are checked against the inputs and the stores
(:func:`check_targets`, :mod:`seqbayes.store.targets`).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import sys

#: Most sample-steps (horizon x N) a forecast or time-to-threshold of the command line simulates, and most
#: steps of a forecast: the forecast holds its draws in memory (8 d bytes each) and re-draws the paths that
#: leave the parameter space (up to 100 rounds of the whole horizon), so long horizons take minutes; beyond
#: these the command refuses in one line (docs/guide.md gives the bounds).
MAX_SIMULATED = 2_000_000
MAX_FORECAST_STEPS = 1000


class CommandError(Exception):
    """A user-facing error: printed as one line, exit status 2."""


def check_horizon(option: str, steps: int, n_samples: int) -> None:
    """Refuse a forecast horizon whose simulation would exceed :data:`MAX_SIMULATED` sample-steps."""
    limit = min(MAX_SIMULATED // n_samples, MAX_FORECAST_STEPS if option != "--horizon" else MAX_SIMULATED)
    if steps > limit:
        raise CommandError(f"{option} {steps}: the command line simulates at most {limit} steps ahead for N = "
                           f"{n_samples} samples (at most {MAX_FORECAST_STEPS} forecast steps and "
                           f"{MAX_SIMULATED:.0e} sample-steps: a longer horizon takes minutes); use the Python API "
                           f"(RunStore.predict, RunStore.time_to_threshold) for more")


def json_text(value) -> str:
    """``value`` as JSON text with NaN and infinities written ``null`` (bare ``NaN`` is not JSON)."""
    def clean(item):
        if isinstance(item, float):
            return item if item == item and abs(item) != float("inf") else None
        if isinstance(item, dict):
            return {key: clean(v) for key, v in item.items()}
        if isinstance(item, (list, tuple)):
            return [clean(v) for v in item]
        return item

    return json.dumps(clean(value), indent=1, allow_nan=False)


def show_warning(message, category, filename, lineno, file=None, line=None):
    """A warning as one line, ``seqbayes: warning: Category: text`` (no source line: the user did not write it)."""
    from ..store.datasets import printable

    if NUMERIC.messages is not None and is_numeric(message, category):
        NUMERIC.messages.append(str(message))     # said once, in our words, when the command ends
        return
    print(f"seqbayes: warning: {category.__name__}: {printable(message)}", file=file or sys.stderr)


#: numpy's floating-point warnings ("invalid value encountered in subtract"): counted, not printed raw
NUMPY_FLOAT = re.compile(r"(invalid value|divide by zero|overflow|underflow) encountered in [\w .]+")
NUMERIC_WORDS = {"invalid value": "an invalid value (NaN: inf - inf, 0 / 0, ...)",
                  "divide by zero": "a division by zero", "overflow": "an overflow", "underflow": "an underflow"}
class NumericWarnings:
    """The numeric warnings of the running command: ``messages`` is a list while :func:`seqbayes.cli.main`
    runs a command (each is said once, in our words, when it ends), None outside."""

    messages: list | None = None


#: the one instance, which :func:`seqbayes.cli.main` sets and restores
NUMERIC = NumericWarnings()


def is_numeric(message, category) -> bool:
    return issubclass(category, RuntimeWarning) and NUMPY_FLOAT.fullmatch(str(message)) is not None


def numeric_summary(messages) -> str:
    """One line on the numeric warnings a command met, in our words: how often each kind occurred."""
    counts = {}
    for text in messages:
        kind = NUMPY_FLOAT.fullmatch(text).group(1)
        counts[kind] = counts.get(kind, 0) + 1
    met = ", ".join(f"{NUMERIC_WORDS[kind]} {n} time{'s' if n > 1 else ''}" for kind, n in counts.items())
    return f"the computation met {met} (numpy floating-point warnings); check the data's units and the options"


# --------------------------------------------------------------------- bounded options
def bounded(kind, low=None, high=None, *, open_low=False, open_high=False, allow_inf=False):
    """An argparse type: a number of ``kind`` (int or float) within the bounds, else a one-line error saying
    what is expected (NaN is refused; inf only with ``allow_inf``)."""
    def parse(text):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {'an integer' if kind is int else 'a number'}, "
                                             f"got {text!r}") from None
        finite = value == value and abs(value) != float("inf")
        below = low is not None and (value <= low if open_low else value < low)
        above = high is not None and (value >= high if open_high else value > high)
        if not (finite or (allow_inf and value == float("inf"))) or below or above:
            lo = "" if low is None else f"{'>' if open_low else '>='} {low:g}"
            hi = "" if high is None else f"{'<' if open_high else '<='} {high:g}"
            raise argparse.ArgumentTypeError(f"expected {'an integer' if kind is int else 'a number'} "
                                             f"{' and '.join(b for b in (lo, hi) if b)}, got {text}")
        return value
    parse.__name__ = kind.__name__          # argparse names the type in its messages
    return parse


def range_option(low: float, high: float):
    """An argparse type for ``LOW,HIGH``: two finite numbers ``low <= LOW < HIGH <= high``."""
    def parse(text):
        try:
            first, second = (float(v) for v in text.split(","))
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected LOW,HIGH (two numbers), got {text!r}") from None
        if not low <= first < second <= high:
            raise argparse.ArgumentTypeError(f"expected LOW,HIGH with {low:g} <= LOW < HIGH <= {high:g}, got {text}")
        return first, second
    parse.__name__ = "range"
    return parse


class Parser(argparse.ArgumentParser):
    """argparse with its errors on one line (no usage block): ``seqbayes CMD: error: ... (see --help)``."""

    def error(self, message):
        from ..store.datasets import printable

        self.exit(2, f"{self.prog}: error: {printable(message)} (see {self.prog} --help)\n")



def progress_enabled() -> bool:
    return sys.stderr.isatty()


class CountingLikelihood:
    """Wraps the likelihood to advance a tqdm bar by the number of samples evaluated (serial runs only)."""

    def __init__(self, func, bar):
        self.func, self.bar = func, bar

    def __call__(self, theta, data):
        out = self.func(theta, data)
        self.bar.update(len(theta))
        return out




# ------------------------------------------------------------------ output targets
def check_targets(outputs, *, inputs=(), stores=(), force=False, run=None) -> dict:
    """Refuse output targets that are inputs, stores or files the command did not write
    (:func:`seqbayes.store.targets.check_outputs`); ``outputs``: the fields of ``Output``; ``run``:
    ``(name, path)`` of a run store to create, checked against the inputs only (``init --force`` decides
    on an existing store)."""
    from ..store.targets import Output, check_outputs, refuse_inputs

    if run is not None:
        refuse_inputs(*run, inputs=inputs)
    return check_outputs([Output(*o) for o in outputs], inputs=inputs, stores=stores, force=force)


def same_file(first, second) -> bool:
    """Whether two paths name one file (through links too); False if either does not exist."""
    try:
        return os.path.samefile(first, second)
    except (OSError, ValueError):
        return False


def store_inputs(store) -> list:
    """The user's files a run store names (its likelihood module): protected from outputs too."""
    user = store.user_code()
    return [user[1]] if user is not None and user[1] else []




# ----------------------------------------------------------------------- options
#: ``--lock-timeout`` of the commands that write a run store.
LOCK_TIMEOUT_OPTION = dict(type=bounded(float, 0, allow_inf=True), default=None, metavar="SECONDS",
                           help="how long to wait while another update holds the run store's lock (which says who "
                                "holds it) before giving up; 0: do not wait, inf: no limit (default: "
                                "$SEQBAYES_LOCK_TIMEOUT, else 3600)")
#: ``--level`` of the commands that print credible intervals.
LEVEL_OPTION = dict(type=bounded(float, 0, 1, open_low=True, open_high=True), default=0.95)
#: ``--force`` of the commands that write files besides a run store (:mod:`seqbayes.store.targets`).
FORCE_OPTION = dict(action="store_true", help="replace an existing output file that this command did not write "
                                              "(never an input or a run store)")
#: Most particles per model of ``seqbayes environment`` (the memory bound after reading the data is tighter).
MAX_PARTICLES = 10_000_000

