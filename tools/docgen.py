"""Keep the documentation's outputs and tables equal to what the current code produces.

Two mechanisms, rewritten by ``make docs-regen`` (``python tools/docgen.py --write``) and checked
against a rerun by ``make docs-check`` (``python tools/docgen.py sections``) and by the tests
(``tests/docs/test_guide.py``, ``tests/studies/test_coulomb_study.py``, and the reduced oscillator
study in ``tests/studies/test_oscillator_study.py``):

1. **Executable guide.** ``docs/guide.md`` (and the README and ``docs/run_store.md``) is run top to
   bottom in an empty folder. An HTML
   comment right before a fenced block says what the block is (the comments do not show in the
   rendered site):

   - ``<!-- file: beam.py -->``: the block is written to that file;
   - ``<!-- run -->``: the Python block is executed (one namespace for the whole guide, the
     folder as working directory); when the next block is preceded by ``<!-- output -->`` it must
     equal what the Python block printed;
   - ``<!-- shell: CMD -->`` (no block needed): a set-up command run silently;
   - every ``console`` block is run: each ``$ command`` line is executed and the lines after it,
     up to the next ``$``, must equal its output (stdout and stderr, as a terminal shows them).

   Durations (``in 0.47 s``) are the only text not compared: they depend on the machine.

2. **Generated sections** of any page, between ``<!-- generated: KEY -->`` and
   ``<!-- end generated -->``, hold text that a producer registered under ``KEY`` renders
   (for example the Coulomb study's tables from :func:`seqbayes.studies.coulomb.tables_markdown`).

Written here rather than with a doctest or ``pytest-markdown`` plugin because the guide mixes
shell sessions of an installed command, files the later commands read, and Python blocks whose
printed output is shown in a separate block; no maintained plugin runs all three in one folder.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GUIDE = ROOT / "docs" / "guide.md"

_FENCE = re.compile(r"^```(\w*)\s*$")
_DIRECTIVE = re.compile(r"^<!--\s*(file|run|output|shell|norun|tolerance)\s*:?\s*(.*?)\s*-->\s*$")
_DURATION = re.compile(r"\b\d+(?:\.\d+)? (?:s|ms)\b")
# a file's content hash depends on the machine's floating-point bits when the file holds simulated numbers
_HASH = re.compile(r"\b(sha256:? )[0-9a-f]{8,64}\b")


@dataclass(frozen=True)
class Block:
    """A fenced block of a Markdown page: its language, body lines, the directive before it,
    and the line range ``[start, stop)`` of its body in the page."""

    lang: str
    body: tuple[str, ...]
    directive: tuple[str, str] | None
    start: int
    stop: int
    tolerance: str = ""


@dataclass(frozen=True)
class Mismatch:
    """Where the page and the current code differ."""

    where: str
    expected: str
    actual: str
    differences: tuple[str, ...] = ()

    def __str__(self) -> str:
        why = "".join(f"\n  {d}" for d in self.differences)
        return f"{self.where}:{why}\n--- page\n{self.expected}\n+++ current code\n{self.actual}"


def parse(lines: list[str]) -> list[Block | tuple[str, str]]:
    """The page's fenced blocks and stand-alone ``shell`` directives, in order."""
    items: list[Block | tuple[str, str]] = []
    pending = None
    tolerance = ""
    i = 0
    while i < len(lines):
        line = lines[i]
        directive = _DIRECTIVE.match(line)
        if directive:
            kind, arg = directive.group(1), directive.group(2)
            if kind == "shell":
                items.append(("shell", arg))
            elif kind == "tolerance":
                parse_tolerance(arg)          # a malformed rule fails here, naming itself
                tolerance = arg
            else:
                pending = (kind, arg)
            i += 1
            continue
        fence = _FENCE.match(line)
        if fence:
            stop = i + 1
            while stop < len(lines) and lines[stop].rstrip() != "```":
                stop += 1
            if stop == len(lines):
                raise ValueError(f"line {i + 1}: unclosed code fence")
            items.append(Block(fence.group(1), tuple(lines[i + 1:stop]), pending, i + 1, stop, tolerance))
            pending, tolerance = None, ""
            i = stop + 1
            continue
        if line.strip():
            pending, tolerance = None, ""
        i += 1
    return items


def normalise(text: str) -> str:
    """Text as compared: durations and content hashes masked, trailing blanks and blank end lines
    dropped."""
    lines = [_HASH.sub(r"\1<hash>", _DURATION.sub("<duration>", line.rstrip())) for line in text.splitlines()]
    while lines and not lines[-1]:
        lines.pop()
    return "\n".join(lines)


# ---------------------------------------------------------------- numbers to their precision

#: A number as printed: optional sign (not after a letter or digit: ``0-199`` is a range), digits with
#: optional thousands commas, decimals and exponent; not part of a name (``T1``, ``theta_1``, ``month1``).
_NUMBER = re.compile(r"(?<![\w.])(?:(?<![\w)\]])[-+])?(?:\d{1,3}(?:,\d{3})+|\d+)(?:\.\d+)?(?:[eE][-+]?\d+)?(?![\w.]\w)(?!\w)")
_TOLERANCE_RULE = re.compile(
    r'^\s*(?:"(?P<regex>(?:[^"\\]|\\.)*)")?\s*(?:col\s+(?P<col>\d+)(?:-(?P<col_to>\d+))?)?\s*'
    r'(?P<tol>(?:(?:abs|rel|factor|se)\s+[-+.\deE]+\s*|times\s+[-+.\deE]+\s+col\s+\d+\s*)+|exact|any|line)\s*$')
_PLUS_MINUS = re.compile(r"^\s*\+-\s*")


@dataclass(frozen=True)
class ToleranceRule:
    """Which numbers of a block a tolerance is for, and the tolerance.

    ``regex`` is searched in the number's line with that number written ``@`` (``"ESS @"``,
    ``"@ likelihood evaluations"``); ``columns`` are whitespace-separated fields of the line, from 1.
    A number passes when ``|actual - page| <= abs + rel |page| + se S`` (``S``: the number printed
    after ``+-`` right behind it on the page, its standard error), or when both are positive and
    within a ``factor`` of each other, beyond the printed numbers' own rounding. A ``line`` rule
    (its regex searched in the page's line) lets the whole line differ."""

    regex: re.Pattern | None
    columns: tuple[int, int] | None
    abs: float = 0.0
    rel: float = 0.0
    factor: float = 0.0
    se: float = 0.0
    kind: str = "numbers"      # or "exact", "any", "line"
    times: tuple[float, int] | None = None    # (K, C): K times the number in column C of the page's line

    def selects(self, marked_line: str, column: int) -> bool:
        if self.kind == "line" or (self.regex is not None and not self.regex.search(marked_line)):
            return False
        return self.columns is None or self.columns[0] <= column <= self.columns[1]

    def width(self, page: str, after: str = "", line: str = "") -> float:
        """How far a number may move from the page's ``page`` (beyond the printed digits' rounding;
        a ``factor`` aside); ``after`` is the page's text behind it, ``line`` its whole line."""
        e = _value(page)
        width = self.abs + self.rel * abs(e)
        if self.se:
            behind = _PLUS_MINUS.match(after)
            error = _NUMBER.match(after, behind.end()) if behind else None
            if error is not None:
                width += self.se * _value(error.group())
        if self.times:
            other = _column_number(line, self.times[1])
            if other is not None:
                width += self.times[0] * abs(_value(other))
        return width

    def accepts(self, page: str, actual: str, after: str = "", line: str = "") -> bool:
        """Whether ``actual`` passes for the page's ``page`` (see :meth:`width`)."""
        if self.kind == "any" or page == actual:
            return True
        if self.kind == "exact":
            return False
        e, a = _value(page), _value(actual)
        slack = (_resolution(page) + _resolution(actual)) * (1 + 1e-9)   # the printed digits' rounding
        if abs(a - e) <= self.width(page, after, line) + slack:
            return True
        return bool(self.factor) and e > 0 and a > 0 and max(a / e, e / a) <= self.factor * (1 + slack / min(a, e))

    def describe(self) -> str:
        if self.kind != "numbers":
            return self.kind
        parts = [f"{name} {getattr(self, name):g}" for name in ("abs", "rel", "se", "factor") if getattr(self, name)]
        if self.times:
            parts.append(f"{self.times[0]:g} x col {self.times[1]}")
        return "within " + " + ".join(parts) if parts else "exactly"


def parse_tolerance(spec: str) -> list[ToleranceRule]:
    """The rules of a ``<!-- tolerance: RULE; RULE; ... -->`` directive, first match wins.

    A rule is ``[SELECTOR] TOLERANCE``. The selector, ``"REGEX"`` and/or ``col N`` (``col N-M``),
    picks numbers (none: every number); the tolerance is one or more of ``abs X``, ``rel X``,
    ``se K``, ``times K col C`` (summed: ``|actual - page| <= X + X |page| + K S + K |column C|``,
    column C of the same line on the page: a posterior table's mean within K of its row's sd) and
    ``factor X`` (or within that factor), or ``exact``, ``any`` (any number), ``line`` (lines whose
    page text the regex finds may differ as a whole). A number no rule selects is compared exactly, digit for digit. A last item
    ``why: ...`` (to the end, semicolons included) says where the tolerances come from.

    >>> [(r.regex.pattern if r.regex else None, r.columns, r.abs, r.rel) for r in parse_tolerance('"ESS @" rel 0.3; col 2-3 abs 0.01')]
    [('ESS @', None, 0.0, 0.3), (None, (2, 3), 0.01, 0.0)]
    """
    rules = []
    for part in filter(str.strip, _split_rules(spec)):
        if part.strip().startswith("why:"):       # the measurement behind the rules, for the reader
            break
        found = _TOLERANCE_RULE.match(part)
        if not found:
            raise ValueError(f"tolerance rule {part.strip()!r}: expected [\"REGEX\"] [col N[-M]] "
                             "(abs X | rel X | se K | factor X)... | exact | any | line")
        regex = re.compile(found["regex"].replace('\\"', '"')) if found["regex"] is not None else None
        columns = (int(found["col"]), int(found["col_to"] or found["col"])) if found["col"] else None
        tol = found["tol"].split()
        if tol[0] in ("exact", "any", "line"):
            if tol[0] == "line" and (regex is None or columns is not None):
                raise ValueError(f"tolerance rule {part.strip()!r}: a line rule takes a regex and no columns")
            rules.append(ToleranceRule(regex, columns, kind=tol[0]))
            continue
        times = re.search(r"times\s+(\S+)\s+col\s+(\d+)", found["tol"])
        plain = re.sub(r"times\s+\S+\s+col\s+\d+", "", found["tol"]).split()
        values = dict(zip(plain[::2], map(float, plain[1::2])))
        rules.append(ToleranceRule(regex, columns, values.get("abs", 0.0), values.get("rel", 0.0),
                                   values.get("factor", 0.0), values.get("se", 0.0),
                                   times=(float(times.group(1)), int(times.group(2))) if times else None))
    return rules


def _split_rules(spec: str) -> list[str]:
    """Split at ``;`` outside quotes."""
    parts, current, quoted = [], [], False
    for i, ch in enumerate(spec):
        if ch == '"' and (i == 0 or spec[i - 1] != "\\"):
            quoted = not quoted
        if ch == ";" and not quoted:
            parts.append("".join(current))
            current = []
        else:
            current.append(ch)
    parts.append("".join(current))
    return parts


def _column_number(line: str, column: int) -> str | None:
    """The (first) number in whitespace-separated field ``column`` (from 1) of ``line``."""
    fields = line.split()
    found = _NUMBER.search(fields[column - 1]) if 0 < column <= len(fields) else None
    return found.group() if found else None


def _value(text: str) -> float:
    return float(text.replace(",", ""))


def _resolution(text: str) -> float:
    """Half a unit of the last printed digit (``0.989``: 0.0005; ``1.6e-26``: 0.05e-26)."""
    mantissa, _, exponent = text.replace(",", "").lower().partition("e")
    decimals = len(mantissa.partition(".")[2])
    return 0.5 * 10.0 ** (int(exponent or 0) - decimals)


def numbers(line: str) -> list[re.Match]:
    """The numbers of a line as printed (see :data:`_NUMBER`)."""
    return list(_NUMBER.finditer(line))


def _skeleton(line: str) -> str:
    """A line with its numbers replaced by ``#`` and its blanks removed (columns shift, and numpy
    pads arrays differently, when a number's width changes)."""
    return "".join(_NUMBER.sub("\0", line).split())


def compare_numbers(page: str, actual: str, rules: list[ToleranceRule] | str = ()) -> list[str]:
    """Where ``actual`` differs from ``page`` beyond the tolerance ``rules``: the text around the
    numbers must be equal (blanks aside), and each number must pass the first rule that selects it
    (exactly equal when none does). Durations and content hashes are masked first.

    Returns
    -------
    list of str
        One line per difference (empty: the texts agree to the stated precision).
    """
    if isinstance(rules, str):
        rules = parse_tolerance(rules)
    page_lines, actual_lines = normalise(page).splitlines(), normalise(actual).splitlines()
    if len(page_lines) != len(actual_lines):
        return [f"{len(actual_lines)} lines, the page shows {len(page_lines)}"]
    line_rules = [r for r in rules if r.kind == "line"]
    found = []
    for number, (p_line, a_line) in enumerate(zip(page_lines, actual_lines), start=1):
        if any(r.regex.search(p_line) for r in line_rules):
            continue
        if _skeleton(p_line) != _skeleton(a_line):
            found.append(f"line {number}: the text differs: {a_line.strip()!r}")
            continue
        for p_num, a_num, marked, column in _numbered(p_line, a_line):
            rule = next((r for r in rules if r.selects(marked, column)), None)
            if rule is None:
                ok = p_num.group() == a_num.group()
            else:
                ok = rule.accepts(p_num.group(), a_num.group(), p_line[p_num.end():], p_line)
            if not ok:
                found.append(f"line {number}: {a_num.group()} where the page shows {p_num.group()} "
                             f"(to be equal {rule.describe() if rule else 'exactly'}) in {marked.strip()!r}")
    return found


def _numbered(p_line: str, a_line: str):
    """The numbers of a page line and of the current line with the same text, each with the page
    line marked at it (``@``) and its column (whitespace-separated field, from 1)."""
    fields = [m.end() for m in re.finditer(r"\S+", p_line)]
    for p_num, a_num in zip(numbers(p_line), numbers(a_line)):
        marked = p_line[:p_num.start()] + "@" + p_line[p_num.end():]
        yield p_num, a_num, marked, 1 + sum(end <= p_num.start() for end in fields)


def _command(line: str, folder: Path) -> str:
    """Run one shell line in ``folder`` with this interpreter's ``seqbayes`` first on the PATH;
    stdout and stderr together, as a terminal shows them."""
    env = dict(os.environ, PYTHONUNBUFFERED="1", OPENBLAS_NUM_THREADS="1", MPLBACKEND="Agg",
               COLUMNS="100", NO_COLOR="1")
    env["PATH"] = os.pathsep.join([str(Path(sys.executable).parent), env.get("PATH", "")])
    done = subprocess.run(["bash", "-c", line], cwd=folder, env=env, stdin=subprocess.DEVNULL,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, timeout=600)
    return done.stdout


def _console(block: Block, folder: Path) -> list[str]:
    """Run a console block; return it with the current outputs in place of the page's."""
    out: list[str] = []
    for line in block.body:
        if line.startswith("$ "):
            out.append(line)
            out.extend(_command(line[2:], folder).rstrip("\n").splitlines())
    return out


def _run_python(code: str, namespace: dict) -> str:
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        exec(compile(code, "<guide>", "exec"), namespace)  # noqa: S102 - the guide's own code
    return buffer.getvalue()


def run_page(path: Path, folder: Path | None = None, text: str | None = None) -> list[tuple[Block, list[str]]]:
    """Run a page top to bottom in ``folder`` (a fresh temporary one by default); return each
    compared block (an ``output`` block or a ``console`` block) with what the current code printed
    for it. ``text`` runs that text in place of the page's (``spread`` runs it with other seeds)."""
    lines = (path.read_text() if text is None else text).splitlines()
    items = parse(lines)
    results: list[tuple[Block, list[str]]] = []
    with contextlib.ExitStack() as stack:
        if folder is None:
            folder = Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="seqbayes-guide-")))
        old_cwd = Path.cwd()
        os.chdir(folder)
        stack.callback(os.chdir, old_cwd)
        import matplotlib

        matplotlib.use("Agg")
        namespace: dict = {"__name__": "__guide__"}
        sys.path.insert(0, str(folder))  # `from beam import loglike` in the guide's API section
        stack.callback(sys.path.remove, str(folder))
        last_printed = None
        for item in items:
            if isinstance(item, tuple):
                _command(item[1], folder)
                continue
            kind = item.directive[0] if item.directive else None
            if kind == "file":
                (folder / item.directive[1]).write_text("\n".join(item.body) + "\n")
            elif kind == "run":
                last_printed = _run_python("\n".join(item.body), namespace)
                continue
            elif kind == "output":
                if last_printed is None:
                    raise ValueError(f"{path.name}:{item.start}: an output block must follow a run block")
                results.append((item, last_printed.rstrip("\n").splitlines()))
            elif item.lang == "console" and kind != "norun":
                results.append((item, _console(item, folder)))
            last_printed = None
    return results


def run_guide(path: Path = GUIDE, write: bool = False, folder: Path | None = None) -> list[Mismatch]:
    """Run the guide; return what differs beyond each block's tolerance (and, with ``write``,
    rewrite the page with the current outputs).

    Parameters
    ----------
    path : Path
        The Markdown page.
    write : bool
        Replace the page's outputs with the current ones (durations included).
    folder : Path, optional
        Working folder (a fresh temporary one by default).
    """
    lines = path.read_text().splitlines()
    mismatches: list[Mismatch] = []
    replacements: dict[tuple[int, int], list[str]] = {}
    for block, actual in run_page(path, folder):
        differences = compare_numbers("\n".join(block.body), "\n".join(actual), block.tolerance)
        if differences:
            mismatches.append(Mismatch(f"{path.name}:{block.start}", "\n".join(block.body), "\n".join(actual),
                                       tuple(differences)))
        replacements[(block.start, block.stop)] = actual
    if write and replacements:
        new = list(lines)
        for (start, stop), body in sorted(replacements.items(), reverse=True):
            new[start:stop] = body
        path.write_text("\n".join(new) + "\n")
    return mismatches


def _with_seeds(text: str, seeds: list[str], offset: int) -> str:
    """The page's text with every occurrence of each ``seeds`` text (``"seed = 2024"``) given the
    number it holds plus ``offset``; ``"OLD->NEW"`` replaces OLD by NEW with ``{r}`` the offset
    (``"--every 15->--every 15 --seed {r}"``)."""
    for seed in seeds:
        if "->" in seed:
            seed, other = seed.split("->", 1)
            other = other.replace("{r}", str(offset))
        else:
            found = _NUMBER.search(seed)
            if found is None:
                raise ValueError(f"--seed {seed!r}: no number in it")
            other = seed[:found.start()] + str(int(found.group()) + offset) + seed[found.end():]
        if seed not in text:
            raise ValueError(f"--seed {seed!r}: not in the page")
        text = text.replace(seed, other)
    return text


def spread(path: Path, seeds: list[str], replicates: int = 8, sigmas: float = 4.0,
           keep: Path | None = None) -> tuple[list[str], bool]:
    """How far each number of the page's compared blocks moves when only the samplers' seeds change.

    The page is run ``replicates`` times, with its own seeds and with the ``seeds`` texts given other
    numbers (:func:`_with_seeds`); for every number of every compared block, the standard deviation
    over the replicates is its Monte Carlo error. See :func:`spread_report`. ``keep``: a JSON file
    that keeps the replicates' outputs, read instead of rerunning while the page's text (tolerance
    lines aside) and the seeds are the same, so tolerances can be revised without rerunning.
    """
    import json

    text = path.read_text()
    stripped = "\n".join(line for line in text.splitlines() if not line.startswith("<!-- tolerance"))
    key = {"page": stripped, "seeds": seeds, "replicates": replicates}
    outputs = None
    if keep is not None and keep.exists():
        kept = json.loads(keep.read_text())
        if kept["key"] == key:
            outputs = kept["outputs"]
    if outputs is None:
        outputs = [["\n".join(out) for _, out in run_page(path, text=_with_seeds(text, seeds, r))]
                   for r in range(replicates)]                 # r = 0: the page's own seeds
        if keep is not None:
            keep.write_text(json.dumps({"key": key, "outputs": outputs}))
    blocks = [item for item in parse(text.splitlines()) if isinstance(item, Block)
              and ((item.directive or ("",))[0] == "output" or (item.lang == "console" and
                                                                (item.directive or ("",))[0] != "norun"))]
    report, covered = [], True
    printed = tuple(m.group() for seed in seeds for m in numbers(seed.split("->")[0]))
    printed += tuple(str(int(v) + r) for v in printed if v.isdigit() for r in range(replicates))
    for b, block in enumerate(blocks):
        lines, ok = spread_report(f"{path.name}:{block.start}", block.tolerance, "\n".join(block.body),
                                  [run[b] for run in outputs], sigmas, printed)
        report += lines
        covered &= ok
    return report, covered


def spread_report(where: str, tolerance: str, page: str, replicates: list[str], sigmas: float = 4.0,
                  seeds: tuple[str, ...] = ()) -> tuple[list[str], bool]:
    """Each number of ``page`` that moves over the ``replicates`` (the same output from other seeds):
    its standard deviation ``sd`` there, and whether the ``tolerance`` covers a difference of
    ``sigmas`` standard deviations of the difference of two runs (``sigmas sqrt(2) sd``: the page is
    one run, a rerun on another machine another); also the lines whose text changes with the seed,
    which only a ``line`` rule covers. Command lines (``$ ...``) and the printed ``seeds`` (on a line
    that says ``seed``) are left out: they change with the seeds by construction. Returns the report's
    lines and whether everything is covered.
    """
    import numpy as np

    rules = parse_tolerance(tolerance)
    line_rules = [r for r in rules if r.kind == "line"]
    body = normalise(page).splitlines()
    outputs = [normalise(text).splitlines() for text in replicates]
    report, covered = [f"{where} (tolerance: {tolerance or 'none, every digit'})"], True
    for i, p_line in enumerate(body):
        if not numbers(p_line) or p_line.startswith("$ ") or any(r.regex.search(p_line) for r in line_rules):
            continue
        same = [o[i] for o in outputs if len(o) == len(body) and _skeleton(o[i]) == _skeleton(p_line)]
        if len(same) < len(outputs):
            covered = False
            report.append(f"  line {i + 1}: the text changes with the seed in {len(outputs) - len(same)} "
                          f"of {len(outputs)} replicates: {p_line.strip()[:90]!r}")
        if len(same) < 2:
            continue
        values = np.array([[_value(m.group()) for m in numbers(o)] for o in same])
        for k, (p_num, _, marked, column) in enumerate(_numbered(p_line, p_line)):
            sd = float(values[:, k].std(ddof=1))
            worst = float(np.abs(values[:, k] - _value(p_num.group())).max())
            if worst == 0.0 or ("seed" in p_line and p_num.group() in seeds):
                continue
            rule = next((r for r in rules if r.selects(marked, column)), None)
            probe = f"{_value(p_num.group()) + sigmas * math.sqrt(2.0) * sd:.12g}"
            ok = rule is not None and rule.accepts(p_num.group(), probe, p_line[p_num.end():], p_line)
            covered &= ok
            report.append(f"  line {i + 1} col {column}: {p_num.group()} sd {sd:.3g} (max dev {worst:.3g}), "
                          f"{'covered' if ok else 'NOT covered'} in {marked.strip()[:80]!r}")
    return report, covered


# ---------------------------------------------------------------- generated sections

_BEGIN = "<!-- generated: {key} -->"
_END = "<!-- end generated -->"


def _split_section(page: Path, key: str) -> tuple[str, str, str]:
    """The page's text before, inside and after the section ``key`` (markers in the outer parts)."""
    text = page.read_text()
    begin = _BEGIN.format(key=key)
    if begin not in text:
        raise ValueError(f"{page}: no section '{begin}'")
    head, rest = text.split(begin, 1)
    if _END not in rest:
        raise ValueError(f"{page}: section {key!r} has no '{_END}'")
    body, tail = rest.split(_END, 1)
    return head + begin, body, _END + tail


def generated_section(page: Path, key: str) -> str:
    """The text between ``<!-- generated: key -->`` and the next ``<!-- end generated -->``."""
    return _split_section(page, key)[1].strip("\n")


def section_tolerance(page: Path, key: str) -> str:
    """The tolerance rules of a generated section: a ``<!-- tolerance: ... -->`` line right before its
    ``<!-- generated: key -->`` line ("" if there is none: every digit is compared)."""
    head = _split_section(page, key)[0]
    before = head[:-len(_BEGIN.format(key=key))].rstrip("\n").splitlines()
    found = _DIRECTIVE.match(before[-1]) if before else None
    if found and found.group(1) == "tolerance":
        parse_tolerance(found.group(2))
        return found.group(2)
    return ""


def compare_section(page: Path, key: str, content: str) -> list[str]:
    """Where ``content`` differs from the section ``key`` of ``page`` beyond its tolerance
    (:func:`section_tolerance`, :func:`compare_numbers`)."""
    return compare_numbers(generated_section(page, key), content.strip("\n"), section_tolerance(page, key))


def write_generated_section(page: Path, key: str, content: str) -> None:
    """Replace the section's text with ``content``."""
    head, _, tail = _split_section(page, key)
    page.write_text(f"{head}\n{content.strip(chr(10))}\n{tail}")


def coulomb_tables(write: bool = False, replicate: int = 0) -> str:
    """The Coulomb study's tables as ``docs/coulomb_friction.md`` shows them: the full study at the
    command's defaults (10 runs, seed 2023; ``replicate`` r: seed 2023 + r). With ``write`` its
    figures replace the page's."""
    from seqbayes.studies import coulomb

    with tempfile.TemporaryDirectory(prefix="seqbayes-coulomb-") as out:
        study = coulomb.run_study(progress=False, out_dir=Path(out), seed=2023 + replicate)
        if write:
            for figure in Path(out).glob("fig*.png"):  # the figures the page shows
                target = ROOT / "docs" / "figures" / f"coulomb_{figure.name}"
                if target.exists():
                    shutil.copyfile(figure, target)
        return coulomb.tables_markdown(study)


@contextlib.contextmanager
def _oscillator_replicate(replicate: int):
    """The oscillator study with independent sampler seeds (``replicate`` > 0) on the same problems
    (data and exact references): every task's seed gets the replicate in its spawn key, as
    :func:`seqbayes.studies.oscillator.run_task` does for one task. In-process runs only."""
    from seqbayes.studies import oscillator

    if not replicate:
        yield
        return
    original = oscillator._task_seed
    oscillator._task_seed = lambda seed, run, kernel, sampler, rep=0: original(seed, run, kernel, sampler,
                                                                            rep + 1000 * replicate)
    try:
        yield
    finally:
        oscillator._task_seed = original


def oscillator_correctness(write: bool = False, replicate: int = 0) -> str:
    """The damped-oscillator study's timing-free results (against the exact grid reference, and the
    checks) for the command's defaults (10 runs, N = 1000, seed 0), as docs/damped_oscillator.md shows;
    ``replicate`` > 0: other sampler seeds, in one process."""
    from seqbayes.studies import oscillator

    with _oscillator_replicate(replicate):
        return oscillator.correctness_report(oscillator.run_study(progress=False,
                                                                  **({"workers": 1} if replicate else {})))


#: The reduced oscillator study that ``make test`` reruns (tests/conftest.py's ``oscillator_reduced_study``).
OSCILLATOR_REDUCED = dict(runs=2, n_samples=300, seed=0, workers=1, progress=False)


def oscillator_reduced(write: bool = False, replicate: int = 0, study=None) -> str:
    """The same account for the reduced study that ``make test`` reruns (2 runs x 6 kernels x 2
    samplers, N = 300, seed 0, one process): run 0 takes the conflict remedy, so the path-space step
    is covered too. The default study (about 8 CPU minutes) is checked by ``make docs-check``.
    ``study``: the study already run (the tests share one); ``replicate``: other sampler seeds."""
    from seqbayes.studies import oscillator

    if study is None:
        with _oscillator_replicate(replicate):
            study = oscillator.run_study(**OSCILLATOR_REDUCED)
    return oscillator.correctness_report(study)


SECTIONS = {("coulomb_friction.md", "coulomb-tables"): coulomb_tables,
            ("damped_oscillator.md", "oscillator-correctness"): oscillator_correctness,
            ("damped_oscillator.md", "oscillator-reduced"): oscillator_reduced}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--write", action="store_true", help="rewrite the pages with the current outputs")
    parser.add_argument("what", nargs="*", default=["guide", "sections"],
                        help="guide and/or sections; or `spread PAGE` (with --seed), or `spread-section KEY`")
    parser.add_argument("--seed", action="append", default=[],
                        help="spread: a text of the page holding a sampler seed (`seed = 2024`), repeatable")
    parser.add_argument("--replicates", type=int, default=8, help="spread: runs, the page's own seeds first")
    parser.add_argument("--keep", type=Path, help="spread: keep the replicates' outputs in this JSON file (reused)")
    args = parser.parse_args(argv)
    if args.what[:1] == ["spread"]:
        if len(args.what) != 2 or not args.seed:
            parser.error("spread takes one page and at least one --seed")
        report, covered = spread(Path(args.what[1]).resolve(), args.seed, args.replicates, keep=args.keep)
        print("\n".join(report))
        return 0 if covered else 1
    if args.what[:1] == ["spread-section"]:
        keys = {key: (page, render) for (page, key), render in SECTIONS.items()}
        if len(args.what) != 2 or args.what[1] not in keys:
            parser.error(f"spread-section takes one of {sorted(keys)}")
        page, render = keys[args.what[1]]
        path = ROOT / "docs" / page
        import json

        kept = json.loads(args.keep.read_text()) if args.keep and args.keep.exists() else {}
        if kept.get("replicates") != args.replicates:
            kept = {"replicates": args.replicates, "outputs": [render(replicate=r) for r in range(args.replicates)]}
            if args.keep:
                args.keep.write_text(json.dumps(kept))
        report, covered = spread_report(f"docs/{page} [{args.what[1]}]", section_tolerance(path, args.what[1]),
                                        generated_section(path, args.what[1]), kept["outputs"])
        print("\n".join(report))
        return 0 if covered else 1
    failed = False
    if "guide" in args.what:
        for page in (GUIDE, ROOT / "README.md", ROOT / "docs" / "run_store.md"):
            mismatches = run_guide(page, write=args.write)
            for m in mismatches:
                print(m, "\n")
            print(f"{page.relative_to(ROOT)}: {len(mismatches)} block(s) differ{' (rewritten)' if args.write else ''}")
            failed |= bool(mismatches) and not args.write
    if "sections" in args.what:
        for (page, key), render in SECTIONS.items():
            path = ROOT / "docs" / page
            content = render(write=args.write)
            differences = compare_section(path, key, content)
            if args.write and content.strip("\n") != generated_section(path, key):
                write_generated_section(path, key, content)
            for line in differences:
                print(f"  {line}")
            state = "differs" if differences else "same to its tolerance"
            print(f"docs/{page} [{key}]: {state}{' (rewritten)' if args.write else ''}")
            failed |= bool(differences) and not args.write
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
