"""The HTML of the reports every run kind writes (:mod:`seqbayes.store.report`, :mod:`seqbayes.store.sg_report`,
:mod:`seqbayes.store.environment_report`): one self-contained page of sections (tables, figures embedded as base64
PNG or written next to the page), every value taken from a stored file escaped."""

from __future__ import annotations

import html
import urllib.parse
from pathlib import Path

import numpy as np

from .. import plotting
from .targets import write_output

__all__ = ["CSS", "table_html", "figure_html", "page", "write_page", "fmt", "text"]

CSS = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 960px; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.2em; border-bottom: 1px solid #ccc; margin-top: 2em; }
table { border-collapse: collapse; font-size: 0.85em; margin: 0.5em 0; }
th, td { border: 1px solid #ddd; padding: 0.2em 0.5em; text-align: right; }
th { background: #f4f4f4; } td.l, th.l { text-align: left; }
figure { margin: 1em 0; } figure img { max-width: 100%; height: auto; border: 1px solid #eee; }
figcaption { font-size: 0.85em; color: #555; } code { background: #f4f4f4; padding: 0 0.2em; }
"""



def fmt(x) -> str:
    """A number as the tables print it (4 significant digits, ``nan``)."""
    return f"{x:.4g}" if np.isfinite(x) else "nan"


def text(value) -> str:
    """``value`` as HTML text (a stored configuration is text from a file someone was handed)."""
    return html.escape(str(value))


def table_html(header, rows, left=(0,)):
    """An HTML table of ``rows`` under ``header``; the columns ``left`` are aligned left."""
    out = ["<table><thead><tr>"]
    out += [f"<th class='{'l' if i in left else ''}'>{html.escape(str(h))}</th>" for i, h in enumerate(header)]
    out.append("</tr></thead><tbody>")
    for row in rows:
        out.append("<tr>" + "".join(f"<td class='{'l' if i in left else ''}'>{html.escape(str(c))}</td>"
                                    for i, c in enumerate(row)) + "</tr>")
    out.append("</tbody></table>")
    return "".join(out)


def figure_html(fig, caption, fig_id, image_dir=None):
    """A figure, embedded (``image_dir`` None) or written there as ``<fig_id>.png``, with its caption."""
    if image_dir is None:
        src = plotting.to_data_uri(fig)
    else:
        image_dir.mkdir(parents=True, exist_ok=True)
        write_output(image_dir / f"{fig_id}.png", plotting.to_png(fig, dpi=100))
        src = urllib.parse.quote(f"{image_dir.name}/{fig_id}.png")   # the output's stem is the user's text
    return (f"<figure id='{fig_id}'><img src='{html.escape(src, quote=True)}' alt='{html.escape(caption)}'>"
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def page(title: str, sections) -> str:
    """The page: its title, then the HTML ``sections`` in order."""
    return "\n".join([f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>{html.escape(title)}</title>",
                      f"<style>{CSS}</style></head><body>", f"<h1>{html.escape(title)}</h1>", *sections,
                      "</body></html>"])


def write_page(output, render, embed: bool = True, **kwargs) -> Path:
    """Write ``render(image_dir=..., **kwargs)`` to ``output`` (an ``.html`` file; ``embed=False``: the figures as
    PNG files in ``<output stem>_figures/`` next to it); returns its path."""
    output = Path(output)
    image_dir = None if embed else output.parent / f"{output.stem}_figures"
    text_ = render(image_dir=image_dir, **kwargs)
    output.parent.mkdir(parents=True, exist_ok=True)
    return write_output(output, text_)   # atomic: a reader never sees half a page
