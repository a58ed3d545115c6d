"""The HTML report in a real browser: headless Chromium (Debian's ``chromium``) opens it
without console messages, every embedded figure decodes, and a screenshot shows the figures.

Skipped (with the reason) when no Chromium is installed; CI installs it with
``apt-get install -y chromium``.
"""

from __future__ import annotations

import re
import shutil
import subprocess

import numpy as np
import pytest

from _user_model import decay_tables, write_config, write_model

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="headless Chromium not found (Debian: apt-get install -y "
                                                         "chromium); the report browser test needs it")

# Chromium logs every console message (console.error, uncaught exceptions, ...) as "...:CONSOLE..."
CONSOLE = re.compile(r":CONSOLE[:(]")


def chromium(tmp_path, url, *extra, name="profile"):
    """Start headless Chromium on ``url``; returns the Popen (stdout = DOM when --dump-dom)."""
    return subprocess.Popen(
        [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--no-first-run",
         "--enable-logging=stderr", "--v=0", f"--user-data-dir={tmp_path / name}", *extra, url],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def finish(proc):
    out, err = proc.communicate(timeout=120)
    return out, [line for line in err.splitlines() if CONSOLE.search(line)]


@pytest.fixture(scope="module")
def report(tmp_path_factory):
    from seqbayes.store.config import load_config
    from seqbayes.store.report import write_report
    from seqbayes.store import RunStore

    root = tmp_path_factory.mktemp("browser")
    write_model(root, "browsermodel", noise=0.05)
    tables = decay_tables((1.8, 1.65, 1.5), np.linspace(0, 4, 20), 0.05, seed=1)
    stores = []
    for name, kernel in [("drift", 'A = { type = "drift", rate = -0.15, noise_std = 0.02 }'), ("static", "")]:
        config = write_config(root / f"{name}.toml", "browsermodel", name=name, amplitude="A", kernel=kernel,
                              n_samples=60, seed=3)
        store = RunStore.create(root / f"{name}.nc", load_config(config))
        for i, table in enumerate(tables):
            store.assimilate(table, f"campaign{i + 1}.csv")
        stores.append(store)
    return write_report(stores[0], root / "report.html", others=stores[1:], forecast_steps=2)


def test_report_opens_in_headless_chromium_without_console_errors_and_shows_the_figures(report, tmp_path):
    from matplotlib.image import imread

    # a positive control: the same detection does see a console error and an uncaught exception
    bad = tmp_path / "bad.html"
    bad.write_text("<!DOCTYPE html><html><body><script>console.error('boom'); nope();</script></body></html>")
    # a copy of the report with a probe that checks every <img> decoded (complete, non-zero size)
    probe = tmp_path / "probe.html"
    probe.write_text(report.read_text().replace("</body>", """<script>
      window.addEventListener('load', () => {
        const imgs = Array.from(document.images);
        const ok = imgs.filter(i => i.complete && i.naturalWidth > 0 && i.naturalHeight > 0).length;
        document.body.setAttribute('data-images', ok + '/' + imgs.length);
      });</script></body>"""))
    shot = tmp_path / "shot.png"
    procs = {
        "report": chromium(tmp_path, report.as_uri(), "--window-size=1000,4200", f"--screenshot={shot}",
                           name="p1"),
        "probe": chromium(tmp_path, probe.as_uri(), "--dump-dom", "--virtual-time-budget=5000", name="p2"),
        "control": chromium(tmp_path, bad.as_uri(), "--dump-dom", name="p3"),
    }
    results = {k: finish(p) for k, p in procs.items()}

    _, control_console = results["control"]
    assert any("boom" in line for line in control_console) and any("nope" in line for line in control_console)
    _, report_console = results["report"]
    assert report_console == []                      # the report itself logs nothing at all
    dom, probe_console = results["probe"]
    assert probe_console == []
    assert "seqbayes report: drift" in dom
    assert 'data-images="4/4"' in dom                  # all four figures decoded by the browser

    # the screenshot shows the figures: plot colours (matplotlib's tab:blue lines and markers,
    # tab:orange forecast / second model) cover many pixels; the page's own CSS has only greys
    assert shot.is_file()
    image = imread(shot)[:, :, :3] * 255.0
    assert image.shape[1] == 1000

    def count(rgb, tol=12):
        return int(np.sum(np.all(np.abs(image - np.array(rgb)) <= tol, axis=2)))

    blue, orange = count((31, 119, 180)), count((255, 127, 14))
    assert blue > 2000, blue
    assert orange > 1000, orange
    # the four figures sit apart down the page: saturated (plot-coloured) rows form at least four
    # blocks separated by > 80 px of tables and text, the last one near the end of the content
    colored = (image.max(axis=2) - image.min(axis=2)) > 60
    rows = np.flatnonzero(colored.sum(axis=1) > 5)
    blocks = 1 + int(np.sum(np.diff(rows) > 80))
    content_end = np.flatnonzero((np.abs(image - 255.0).sum(axis=2) > 30).any(axis=1)).max()
    assert blocks >= 4, blocks
    assert rows.min() < 0.2 * content_end and rows.max() > 0.8 * content_end
