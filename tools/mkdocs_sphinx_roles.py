"""MkDocs hook: render the Sphinx cross-reference roles of the numpydoc docstrings.

The docstrings follow numpydoc and write references as Sphinx roles (``:class:`~seqbayes.SEMC```,
``:func:`time_to_threshold```, ``:mod:`seqbayes.store```), which mkdocstrings treats as Markdown
and shows raw (``:class:<code>SEMC</code>``). This hook, named in ``mkdocs.yml`` under
``hooks:``, rewrites each role in the built page to its target in code font, linked to the
object's anchor when the page documents it (mkdocstrings gives every object the id of its full
path, e.g. ``seqbayes.sequential.SEMC``). ``~a.b.C`` shows ``C``, as in Sphinx.

A target is resolved, in order, as the full id, as ``seqbayes.<target>``, then as the
shortest id that ends with ``.<target>`` (without a leading ``seqbayes.``, so that a name the
package re-exports finds its module's entry); an unresolved target (numpy, scipy, an
attribute not rendered) is shown in code font without a link.
"""

from __future__ import annotations

import html
import re

ROLES = ("mod", "class", "func", "meth", "attr", "data", "exc", "obj")
_ROLE_TEXT = "|".join(ROLES)
#: a role whose target Markdown turned into a code span: ``:class:<code>~seqbayes.SEMC</code>``
_ROLE_CODE = re.compile(rf":(?:py:)?(?:{_ROLE_TEXT}):<code>([^<]+)</code>")
#: a role left with its backticks (inside a code span, e.g. a parameter's type line)
_ROLE_TICKS = re.compile(rf":(?:py:)?(?:{_ROLE_TEXT}):`([^`]+)`")
_ID = re.compile(r'\bid="([A-Za-z_][\w.]*)"')


def _display(target: str) -> str:
    target = target.strip()
    return target[1:].rsplit(".", 1)[-1] if target.startswith("~") else target.lstrip(".")


def _resolve(target: str, ids: set, by_suffix: dict) -> str | None:
    name = target.strip().lstrip("~.").removesuffix("()")
    for candidate in (name, f"seqbayes.{name}"):
        if candidate in ids:
            return candidate
    # a name re-exported by the package (``seqbayes.SEMC``) is documented in its module
    tail = name.removeprefix("seqbayes.")
    matches = [m for m in by_suffix.get(tail.rsplit(".", 1)[-1], []) if m.endswith("." + tail)]
    return min(matches, key=len) if matches else None


def render_roles(text: str) -> str:
    """``text`` (a page's HTML) with every Sphinx role replaced by a code span, linked where possible.

    >>> render_roles('<h2 id="seqbayes.sequential.SEMC">x</h2> see :class:<code>~seqbayes.SEMC</code>')
    '<h2 id="seqbayes.sequential.SEMC">x</h2> see <a href="#seqbayes.sequential.SEMC"><code>SEMC</code></a>'
    """
    ids = set(_ID.findall(text))
    by_suffix: dict[str, list[str]] = {}
    for anchor in ids:
        by_suffix.setdefault(anchor.rsplit(".", 1)[-1], []).append(anchor)

    def linked(match):
        target = html.unescape(match.group(1))
        code = f"<code>{html.escape(_display(target))}</code>"
        anchor = _resolve(target, ids, by_suffix)
        return f'<a href="#{anchor}">{code}</a>' if anchor else code

    text = _ROLE_CODE.sub(linked, text)
    return _ROLE_TICKS.sub(lambda m: html.escape(_display(html.unescape(m.group(1)))), text)


def on_page_content(html_text, page, config, files):  # noqa: ARG001 - MkDocs hook signature
    return render_roles(html_text)
