"""The MkDocs hook that renders the docstrings' Sphinx roles (tools/mkdocs_sphinx_roles.py)."""

import importlib.util
from pathlib import Path

import pytest

HOOK = Path(__file__).resolve().parents[2] / "tools" / "mkdocs_sphinx_roles.py"


@pytest.fixture(scope="module")
def hook():
    spec = importlib.util.spec_from_file_location("mkdocs_sphinx_roles", HOOK)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


PAGE = ('<h2 id="seqbayes.sequential.SEMC">SEMC</h2><h3 id="seqbayes.sequential.SEMC.restore">restore</h3>'
        '<h2 id="seqbayes.prognostics.time_to_threshold">t</h2><h2 id="seqbayes.store">store</h2>')


def test_roles_become_linked_code(hook):
    cases = {
        ":class:<code>~seqbayes.SEMC</code>": '<a href="#seqbayes.sequential.SEMC"><code>SEMC</code></a>',
        ":meth:<code>SEMC.restore</code>": '<a href="#seqbayes.sequential.SEMC.restore"><code>SEMC.restore</code></a>',
        ":meth:<code>~seqbayes.sequential.SEMC.restore</code>":
            '<a href="#seqbayes.sequential.SEMC.restore"><code>restore</code></a>',
        ":func:<code>time_to_threshold</code>":
            '<a href="#seqbayes.prognostics.time_to_threshold"><code>time_to_threshold</code></a>',
        ":mod:<code>seqbayes.store</code>": '<a href="#seqbayes.store"><code>seqbayes.store</code></a>',
        # not documented on the page: code font, no link
        ":class:<code>numpy.random.Generator</code>": "<code>numpy.random.Generator</code>",
        ":func:<code>~scipy.special.logsumexp</code>": "<code>logsumexp</code>",
        # a role left inside a code span (a parameter's type line): its text only
        "<code>see :func:`~seqbayes.structures.discretise` and</code>": "<code>see discretise and</code>",
    }
    for raw, rendered in cases.items():
        assert hook.render_roles(PAGE + raw) == PAGE + rendered, raw


def test_text_without_roles_is_unchanged(hook):
    text = PAGE + '<p><code>module:function</code> and a:b:c, <code>"mymodel:loglike"</code></p>'
    assert hook.render_roles(text) == text
