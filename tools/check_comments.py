"""Keep measurements and history out of source comments: they belong in docs/ and commit messages.

A comment says why the code is the way it is. A figure that a run produced (``0.12 nats``, ``3.2 s``,
``seed 4``, ``run 0``), an issue number or a commit hash in a comment goes stale the day the code or
the machine changes, and nobody reruns a comment. This checker reads every ``#`` comment (``#:``
attribute comments included; docstrings are not read) of the Python files given, and flags the
ones that match one of five rules:

==============  ==================================================================================
``measure``     a number followed by a unit of a run's result: ``nats``, ``sd``/``sds``, ``s``,
                ``ms``, ``seconds``, ``minutes``, ``%``, ``calls``, ``evaluations``
                (``0.12 nats``, ``+- 0.006 sd``, ``16 -> 9 ms``, ``50,000 calls``, ``15 %``)
``seed``        ``seed N``, ``seeds N`` or ``N seeds`` (``seed 0: 0.17 sd``, ``over 40 seeds``)
``run``         ``run N``, ``replicate N``, ``N runs`` or ``N replicates`` (``run 0 under T6``)
``issue``       ``issue N``, ``issues N`` or ``#N`` (``issue 11 item 4``, ``#23``)
``commit``      a commit hash: 7 to 40 hexadecimal characters with at least one digit and one
                letter (``bcc66ad``)
==============  ==================================================================================

A comment is one ``#`` line, or a block of ``#`` lines on consecutive lines at the same column (a
figure split over two lines is still seen). A justified exception is written in the comment itself:
``comment-ok: REASON`` (a reason of at least two words) exempts the comment or block it is in, e.g.
``WINDOW = 76  # samples per campaign, 1.5 s at 50 Hz (comment-ok: a unit conversion, not a result)``.

Usage::

    python tools/check_comments.py            # src/: one line per flagged comment, exit 1 if any
    python tools/check_comments.py --count    # the number of flagged comments only
    python tools/check_comments.py FILE_OR_DIR ...
    python tools/check_comments.py --docstrings  # also class/function docstrings (a survey, not CI)

``tests/unit/test_check_comments.py`` runs it over ``src/`` in CI (``make check`` and ``make test``).
"""

from __future__ import annotations

import argparse
import ast
import io
import re
import sys
import tokenize
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_NUMBER = r"(?<![\w.])[-+]?\d[\d,]*(?:\.\d+)?(?:[eE][-+]?\d+)?"
RULES: dict[str, re.Pattern] = {
    "measure": re.compile(_NUMBER + r"\s*(?:nats?|sds?|s|ms|seconds?|minutes?|%|calls|evaluations)(?![\w])"),
    "seed": re.compile(r"\bseeds?\s*=?\s*\d+|\b\d+\s+seeds\b", re.IGNORECASE),
    "run": re.compile(r"\b(?:run|replicates?)\s+\d+\b|\b\d+\s+(?:runs|replicates)\b", re.IGNORECASE),
    "issue": re.compile(r"\bissues?\s+#?\d+|(?<![\w&])#\d+\b", re.IGNORECASE),
    "commit": re.compile(r"\b(?=[0-9a-f]*\d)(?=[0-9a-f]*[a-f])[0-9a-f]{7,40}\b"),
}
_EXCEPTION = re.compile(r"comment-ok:\s*\S+\s+\S+")


@dataclass(frozen=True)
class Flag:
    """One flag: the line of the match, the rule, the text that matched, and the comment (or
    docstring paragraph) it is in, with that comment's first line."""

    path: str
    line: int
    rule: str
    match: str
    comment: str
    first_line: int

    def __str__(self) -> str:
        return f"{self.path}:{self.line}: {self.rule}: {self.match!r} in {self.comment!r}"


def comments(source: str) -> list[tuple[int, list[str]]]:
    """The comments of a Python source as ``(first line, [text of each line])``, the ``#`` (or
    ``#:``) markers removed. A ``#`` line that stands alone, right below a comment at the same
    column, continues that comment (a trailing comment can be continued that way; two trailing
    comments on consecutive code lines stay two)."""
    blocks: list[tuple[int, int, int, list[str]]] = []   # (first line, last line, column, texts)
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type != tokenize.COMMENT:
            continue
        (row, col), text = token.start, token.string.lstrip("#").removeprefix(":").strip()
        alone = token.line.lstrip().startswith("#")
        if alone and blocks and blocks[-1][1] == row - 1 and blocks[-1][2] == col:
            first, _, _, texts = blocks[-1]
            blocks[-1] = (first, row, col, texts + [text])
        else:
            blocks.append((row, row, col, [text]))
    return [(first, texts) for first, _, _, texts in blocks]


def docstrings(source: str) -> list[tuple[int, list[str]]]:
    """The paragraphs of the class and function docstrings of a Python source as ``(first line,
    [text of each line])``. Module docstrings are left out: the design rules ask a hand-written
    module to justify itself there with a measurement."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, (ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) or not node.body:
            continue
        first = node.body[0]
        if not (isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant)
                and isinstance(first.value.value, str)):
            continue
        paragraph: list[str] = []
        for offset, text in enumerate(first.value.value.split("\n") + [""]):
            if text.strip():
                if not paragraph:
                    start = first.lineno + offset
                paragraph.append(text.strip())
            elif paragraph:
                found.append((start, paragraph))
                paragraph = []
    return sorted(found)


def check_source(source: str, path: str = "<source>", include_docstrings: bool = False) -> list[Flag]:
    """Every flag of one source (at most one per rule per comment); with ``include_docstrings``
    the paragraphs of its class and function docstrings are read too."""
    flags = []
    for first_line, lines in comments(source) + (docstrings(source) if include_docstrings else []):
        text = " ".join(lines)
        if _EXCEPTION.search(text):
            continue
        ends = [sum(len(t) + 1 for t in lines[:i + 1]) for i in range(len(lines))]
        for rule, pattern in RULES.items():
            found = pattern.search(text)
            if found:
                line = first_line + sum(end <= found.start() for end in ends)
                flags.append(Flag(path, line, rule, found.group(0).strip(), text, first_line))
    return flags


def check_paths(paths: list[Path], include_docstrings: bool = False) -> list[Flag]:
    """Every flag of the ``.py`` files under ``paths`` (files or folders)."""
    files = sorted(f for p in paths for f in ([p] if p.is_file() else p.rglob("*.py")))
    flags = []
    for file in files:
        shown = file.relative_to(ROOT) if file.is_relative_to(ROOT) else file
        flags.extend(check_source(file.read_text(encoding="utf-8"), str(shown), include_docstrings))
    return flags


def flagged_comments(flags: list[Flag]) -> int:
    """The number of distinct comments flagged (a comment matching two rules counts once)."""
    return len({(f.path, f.first_line) for f in flags})


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("paths", nargs="*", type=Path, default=[ROOT / "src"])
    parser.add_argument("--count", action="store_true", help="print the number of flagged comments only")
    parser.add_argument("--docstrings", action="store_true",
                        help="read class and function docstrings too (a survey; CI checks comments only)")
    args = parser.parse_args(argv)
    flags = check_paths([p.resolve() for p in args.paths], args.docstrings)
    if args.count:
        print(flagged_comments(flags))
    else:
        for flag in flags:
            print(flag)
        by_rule = {rule: sum(f.rule == rule for f in flags) for rule in RULES}
        print(f"{flagged_comments(flags)} comment(s) flagged: "
              + ", ".join(f"{rule} {n}" for rule, n in by_rule.items()), file=sys.stderr)
    return 1 if flags else 0


if __name__ == "__main__":
    raise SystemExit(main())
