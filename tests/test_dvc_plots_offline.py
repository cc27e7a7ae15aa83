"""``dvc plots show`` writes a page that renders with no network (pipelines/vega_offline_template.py).

The repository's ``.dvc/config`` names ``pipelines/vega/offline.html`` as DVC's HTML template: dvc-render's
page with vega, vega-lite and vega-embed inlined at the versions DVC would load from its CDN. The page
``dvc plots show`` writes from the committed results is opened in headless Chromium with its network cut
off; every plot of dvc.yaml is drawn: its canvas, and in vega's scene graph one line per training run (a
point per row of its metrics.csv) or one symbol per episode. DVC's own template, offline, draws nothing (so
the cut-off is real). Skipped, saying so, without Chromium (``apt-get install chromium``); ~10 s.
"""

from __future__ import annotations

import asyncio
import configparser
import csv
import hashlib
import importlib.util
import os
import re
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest
import yaml

from tests.chromium_devtools import CHROMIUM, chromium_page

ROOT = Path(__file__).resolve().parents[1]
DVC = Path(sys.executable).with_name("dvc") if Path(sys.executable).with_name("dvc").exists() else "dvc"
SPEC = importlib.util.spec_from_file_location("vega_offline_template", ROOT / "pipelines" / "vega_offline_template.py")
builder = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(builder)

needs_chromium = pytest.mark.skipif(CHROMIUM is None, reason="Chromium is not installed; install it from "
                                    "Debian's packages (apt-get install chromium) to run the browser test")

HOOK = """(() => {
  // DVC's page calls vegaEmbed(...) and drops the promise; keep each one to read its view's scene graph.
  window.__embeds = [];
  let embed;
  Object.defineProperty(window, 'vegaEmbed', {configurable: true, get() { return embed; }, set(f) {
    embed = (el, spec, opt) => { const p = f(el, spec, opt); window.__embeds.push({el, p}); return p; };
  }});
})()"""

DRAWN = """Promise.all(window.__embeds.map(({el, p}) => p.then(result => {
  const marks = [];
  const walk = (mark) => {
    if (mark.marktype !== 'group') marks.push([mark.marktype, mark.role, mark.items.length]);
    else for (const item of mark.items) for (const m of (item.items || [])) walk(m);
  };
  walk(result.view.scenegraph().root);
  const div = document.querySelector(el), canvas = div.querySelector('canvas');
  let ink = 0;
  if (canvas && canvas.width && canvas.height) {
    const px = canvas.getContext('2d').getImageData(0, 0, canvas.width, canvas.height).data;
    for (let i = 0; i < px.length; i += 4) if (px[i + 3] > 0 && Math.min(px[i], px[i + 1], px[i + 2]) < 200) ink++;
  }
  return {id: div.id, embedded: div.classList.contains('vega-embed'), marks, ink,
          canvas: canvas ? [canvas.width, canvas.height] : null};
})))"""
"""Per plot: its div, whether vega-embed took it, the scene graph's marks (type, role, items), the canvas
size and how many of its pixels are drawn (not transparent, not near white)."""

STATE = """({vegaEmbed: typeof vegaEmbed, canvases: document.querySelectorAll('canvas').length,
  svgs: document.querySelectorAll('svg').length,
  divs: [...document.querySelectorAll('body > div[id]')].map(d => d.id)})"""


def _plots() -> dict[str, dict]:
    """dvc.yaml's plots: id -> definition."""
    return {pid: spec for entry in yaml.safe_load((ROOT / "dvc.yaml").read_text())["plots"]
            for pid, spec in entry.items()}


def _rows(path: str, column: str) -> int:
    with (ROOT / path).open() as handle:
        return sum(1 for row in csv.DictReader(handle) if row[column] not in ("", None))


def _plots_show(out: Path, *args: str) -> str:
    subprocess.run([str(DVC), "plots", "show", "-o", str(out), *args], cwd=ROOT, check=True,
                   capture_output=True, text=True, timeout=300)
    return (out / "index.html").read_text(encoding="utf-8")


async def _open_offline(url: str, profile: Path, screenshot: Path | None = None):
    """The page at ``url`` in Chromium with no network: (what each plot drew, the page's state, the
    requests it made that were not to files)."""
    async with chromium_page(profile, deadline_s=120, offline=True, window="1400,1800") as page:
        await page.call("Network.enable")
        await page.call("Network.emulateNetworkConditions", offline=True, latency=0, downloadThroughput=-1,
                        uploadThroughput=-1)
        await page.call("Page.enable")
        await page.call("Page.addScriptToEvaluateOnNewDocument", source=HOOK)
        await page.call("Page.navigate", url=url)
        await page.wait_for("document.readyState === 'complete'", "the page to load")
        drawn = await page.evaluate(DRAWN, await_promise=True)
        state = await page.evaluate(STATE)
        if screenshot is not None:
            import base64

            shot = await page.call("Page.captureScreenshot", format="png", captureBeyondViewport=True)
            screenshot.write_bytes(base64.b64decode(shot["data"]))
        requests = [e["params"]["request"]["url"] for e in page.events if e["method"] == "Network.requestWillBeSent"]
        return drawn, state, [u for u in requests if not u.startswith(("file:", "data:", "blob:"))]


def test_template_is_dvcs_default_and_inlines_the_pinned_libraries_dvc_loads():
    config = configparser.ConfigParser()
    config.read(ROOT / ".dvc" / "config")
    assert (ROOT / ".dvc" / config["plots"]["html_template"]).resolve() == builder.TEMPLATE

    template = builder.TEMPLATE.read_text(encoding="utf-8")
    # dvc-render fills {plot_divs} (required) and {refresh_tag}; its {scripts} would add the CDN's tags
    assert "{plot_divs}" in template and "{refresh_tag}" in template and "{scripts}" not in template
    assert '<meta charset="utf-8">' in template  # the minified code is UTF-8; file:// pages have no header
    assert not re.search(r"<script[^>]*\bsrc\s*=", template), "a script loaded from elsewhere"

    from dvc_render.vega import VegaRenderer

    cdn = dict(re.findall(r'src="https://cdn\.jsdelivr\.net/npm/([\w-]+)@([\d.]+)"', VegaRenderer.SCRIPTS))
    assert cdn == {name: version for name, (version, _) in builder.PINS.items()}, (
        f"dvc-render now loads {cdn}: update PINS and rebuild (pipelines/vega_offline_template.py)")
    scripts = re.findall(r"<script>(.*?)</script>", template, flags=re.S)
    assert len(scripts) == len(builder.PINS)
    for script, (name, (version, integrity)) in zip(scripts, builder.PINS.items(), strict=True):
        banner = builder.BANNER.match(script)
        assert banner, f"no banner on the script for {name}"
        assert (banner["name"], banner["version"], banner["integrity"]) == (name, version, integrity)
        body = script[banner.end():]
        assert hashlib.sha256(body.encode("utf-8")).hexdigest() == banner["sha256"], f"{name}'s code was edited"
        assert len(body) > 50_000 and "sourceMappingURL" not in body
        assert (ROOT / "pipelines" / "vega" / f"LICENSE.{name}").read_text().startswith("Copyright")


@needs_chromium
@pytest.mark.timeout(600)
def test_dvc_plots_show_draws_every_plot_with_no_network(tmp_path):
    html = _plots_show(tmp_path / "plots")  # the repository's default template (.dvc/config)
    assert not re.search(r"""<script[^>]*\bsrc\s*=\s*["']?(https?:)?//""", html), "a script from the network"
    assert not re.search(r"""<(link|img|iframe)[^>]*\b(src|href)\s*=\s*["']?(https?:)?//""", html)
    assert "cdn.jsdelivr.net" not in html

    screenshot = Path(os.environ.get("SRMPC_PLOTS_SCREENSHOT", tmp_path / "dvc_plots.png"))
    drawn, state, requests = asyncio.run(_open_offline((tmp_path / "plots" / "index.html").as_uri(),
                                                       tmp_path / "chromium", screenshot))
    assert requests == [], f"the page asked the network for {requests}"
    plots = _plots()
    assert [d["id"] for d in drawn] == state["divs"] == list(plots), (drawn, state)
    for plot in drawn:
        spec = plots[plot["id"]]
        assert plot["embedded"] and plot["canvas"] and min(plot["canvas"]) > 200, plot
        assert plot["ink"] > 5_000, f"{plot['id']}: its canvas is (nearly) blank: {plot['ink']} pixels drawn"
        assert ["text", "title-text", 1] in plot["marks"], f"{plot['id']}: no title"
        if spec["template"] == "training_curves":  # per series, one line per run, raw and its running mean
            ((path, _),) = spec["y"].items()
            with (ROOT / path).open() as handle:
                runs = Counter((row["agent"], row["seed"], row["series"]) for row in csv.DictReader(handle))
            assert len(runs) == 13 * 3 and min(runs.values()) > 100  # PPO, PPO-L-SI, SB3, PPO-L-RSS x 3 seeds + 1
            lines = Counter(n for marktype, _, n in plot["marks"] if marktype == "line")
            expected = Counter()
            for points in runs.values():
                expected[points] += 2
            assert all(lines[n] >= k for n, k in expected.items()), (plot["id"], lines, expected)
        else:  # scatter: one symbol per episode of every method
            expected = [_rows(path, column) for path, column in spec["y"].items()]
            symbols = [n for marktype, role, n in plot["marks"] if marktype == "symbol" and role == "mark"]
            assert symbols == [sum(expected)], (plot["id"], symbols, expected)
    assert screenshot.stat().st_size > 50_000


@needs_chromium
@pytest.mark.timeout(600)
def test_dvcs_own_cdn_template_draws_nothing_offline(tmp_path):
    """The control: the browser really is offline, so the page above drew from the inlined libraries."""
    from dvc_render.html import PAGE_HTML

    (tmp_path / "cdn.html").write_text(PAGE_HTML)
    html = _plots_show(tmp_path / "plots", "--html-template", str(tmp_path / "cdn.html"))
    assert html.count('src="https://cdn.jsdelivr.net/npm/') == 3
    drawn, state, requests = asyncio.run(_open_offline((tmp_path / "plots" / "index.html").as_uri(),
                                                       tmp_path / "chromium"))
    assert drawn == [] and state["vegaEmbed"] == "undefined" and state["canvases"] == 0, state
    assert state["divs"] == list(_plots())
    assert sorted(requests) == sorted(f"https://cdn.jsdelivr.net/npm/{name}@{version}"
                                      for name, (version, _) in builder.PINS.items()), requests
