"""In a real browser, the URL ``make ui`` prints opens on the results with their J_c and v_x (headless Chromium).

Chromium is driven over its DevTools protocol (``tests/chromium_devtools.py``): open the URL, wait, screenshot,
read the DOM; nothing is clicked and no browser state is set, so the page shows what a new user's browser shows.
Needs Chromium from Debian's packages (``apt-get install chromium``); skipped, saying so, without it.
Screenshots go to ``$SRMPC_UI_SCREENSHOT_DIR`` if set, else into the test's temporary directory.
"""

import asyncio
import base64
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from srmpc.tracking import METRICS_VIEW, PARENT_RUN_ENV, RESULTS_FILTER, RUNS_TABLE_COLUMNS, runs_table_url, tracked_run
from tests.chromium_devtools import CHROMIUM, chromium_page
from tests.mlflow_server import serve_mlflow

pytestmark = pytest.mark.slow

RUNS = {"evaluate-srmpc-paper-light": ("srmpc", 0.002), "evaluate-ltv_mpc-light": ("ltv_mpc", 0.041)}
J_C = "mean_event_cost"


@pytest.fixture
def mlflow_ui(tmp_path, monkeypatch):
    """``mlflow server`` on a free port over a temporary SQLite store holding the two runs; yields the
    runs-table URL on the ``metrics`` view (every run; no run is a row of the results table here)."""
    monkeypatch.delenv(PARENT_RUN_ENV, raising=False)
    uri, artifacts = f"sqlite:///{tmp_path / 'mlflow.db'}", str(tmp_path / "mlruns")
    for name, (controller, j_c) in RUNS.items():
        params = {"stage": "evaluate", "scenario": {"traffic": "light"},
                  "controller": {"name": controller}, "evaluation": {"seed": 0}}
        with tracked_run(True, uri, artifacts, "srmpc", name, params, "stage: evaluate\n") as run:
            run.log_metrics({J_C: j_c, "mean_vx": 21.5})
    import mlflow

    experiment_id = mlflow.MlflowClient(uri).get_experiment_by_name("srmpc").experiment_id
    mlflow.set_tracking_uri(None)
    with serve_mlflow(uri, artifacts, tmp_path / "server.log") as base:
        yield runs_table_url(base, experiment_id, METRICS_VIEW)


HEADER_JS = """[...document.querySelectorAll('.ag-header-cell[col-id]')]
  .map(cell => [cell.getBoundingClientRect().left, cell.getAttribute('col-id')])
  .sort((a, b) => a[0] - b[0]).map(([, id]) => id)"""
"""The col-ids of the runs table's header cells, left to right as drawn (ag-grid's DOM order may differ)."""
FIRST_COLUMNS = RUNS_TABLE_COLUMNS[:7]
"""The view's first tag and metric columns: method, traffic, J_c, v_x, rho_c, J_r, n_steps."""
assert FIRST_COLUMNS == ["tags.`method`", "tags.`traffic`", "metrics.`mean_event_cost`", "metrics.`mean_vx`",
                         "metrics.`cost_rate`", "metrics.`mean_return`", "metrics.`mean_n_steps`"]


def _tag_and_metric_columns(header: list[str]) -> list[str]:
    return [column for column in header if column.startswith(("tags.", "metrics."))]


async def _browse(url: str, profile: Path, screenshot: Path, deadline_s: float) -> tuple[str, list[str]]:
    """Open ``url`` in headless Chromium over the DevTools protocol (a fresh profile, nothing clicked), wait
    for the runs and the J_c column, save a screenshot; returns the page's DOM and header (:data:`HEADER_JS`)."""
    async with chromium_page(profile, deadline_s=deadline_s) as page:
        names = " && ".join(f"document.body.innerText.includes({json.dumps(n)})" for n in RUNS)
        await page.call("Page.navigate", url=url)
        await page.wait_for(f"document.body && {names} && document.body.innerText.includes({json.dumps(J_C)})",
                            "the J_c column")
        await asyncio.sleep(3)  # let the grid settle
        shot = await page.call("Page.captureScreenshot", format="png")
        screenshot.write_bytes(base64.b64decode(shot["data"]))
        return await page.evaluate("document.documentElement.outerHTML"), await page.evaluate(HEADER_JS)


@pytest.mark.timeout(2400)
def test_runs_table_shows_srmpc_and_ltv_mpc_with_their_j_c(mlflow_ui, tmp_path):
    if CHROMIUM is None:
        pytest.skip("Chromium is not installed; install it from Debian's packages: apt-get install chromium")
    screenshot = Path(os.environ.get("SRMPC_UI_SCREENSHOT_DIR", tmp_path)) / "mlflow_runs_table.png"
    screenshot.parent.mkdir(parents=True, exist_ok=True)
    dom, header = asyncio.run(_browse(mlflow_ui, tmp_path / "chromium", screenshot, deadline_s=900))
    assert screenshot.stat().st_size > 20_000, "screenshot missing or blank"
    # the view's column order (these runs log J_c and v_x only): method, traffic, J_c, v_x, then the other tags
    logged = [c for c in FIRST_COLUMNS if not c.startswith("metrics.") or c in ("metrics.`mean_event_cost`",
                                                                                 "metrics.`mean_vx`")]
    assert _tag_and_metric_columns(header)[:len(logged)] == logged, header

    assert "Model training" in dom and ">Runs<" in dom  # the runs table, not the GenAI traces overview
    for name in RUNS:
        assert name in dom, f"run {name} not in the runs table"
    assert f'col-id="metrics.`{J_C}`"' in dom, "no J_c (mean_event_cost) metric column"
    # each run's row (ag-grid: row-index shared by the pinned name cell and the metric cells) holds its J_c
    for name, (_, j_c) in RUNS.items():
        row = re.search(rf'row-index="(\d+)"(?:(?!row-index=).)*?{re.escape(name)}', dom, re.S)
        assert row, f"no row for {name}"
        cells = re.findall(rf'row-index="{row.group(1)}"(?:(?!row-index=).)*', dom, re.S)
        assert any(f">{j_c}<" in cell for cell in cells), f"J_c {j_c} of {name} not shown in its row"


ROOT = Path(__file__).resolve().parents[1]
CHARTS_JS = """[...document.querySelectorAll('.js-plotly-plot')].map(plot => {
  let card = plot;  // the chart's card: the nearest ancestor naming the series, "<run> (<metric>)"
  for (let i = 0; i < 8 && card.parentElement && !(card.innerText || '').includes('('); i++) card = card.parentElement;
  return {card: (card.innerText || '').slice(-200),
          xticks: [...plot.querySelectorAll('.xtick text')].map(t => t.textContent),
          vertices: [...plot.querySelectorAll('.scatterlayer path.js-line')].map(
            line => (line.getAttribute('d').match(/[ML]/g) || []).length)};
})"""
"""Each plotly chart of a run's metrics page: its card's text, its x tick labels, the vertices of its lines."""


def _mlflow_parent_run(*args: str, uri: str, artifacts: str) -> str:
    env = {k: v for k, v in os.environ.items() if k != PARENT_RUN_ENV}
    done = subprocess.run([sys.executable, "-m", "pipelines.mlflow_parent_run", *args, "--",
                           f"tracking.uri={uri}", f"tracking.artifact_location={artifacts}"],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=1800)
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout.strip()


def _ui_number(value: float) -> str:
    """How the runs table writes a metric: in full (JavaScript's number to string, for these plain values)."""
    return str(int(value)) if float(value).is_integer() else repr(float(value))


def _cells(dom: str, name: str, column: str) -> list[str]:
    """The text of ``column``'s cells in the row of run ``name`` (ag-grid: the pinned name cell and the
    metric cells share the row's row-index)."""
    row = re.search(rf'row-index="(\d+)"(?:(?!row-index=).)*?>{re.escape(name)}<', dom, re.S)
    assert row, f"no row for {name}"
    cells = "".join(re.findall(rf'row-index="{row.group(1)}"(?:(?!row-index=).)*', dom, re.S))
    return re.findall(rf'col-id="{re.escape(column)}"[^>]*>(?:<[^>]*>)*([^<]*)<', cells)


@pytest.fixture
def fresh_clone_ui(tmp_path):
    """What ``make reproduce`` does on a fresh clone with every stage up to date, into a temporary store:
    ``mlflow_parent_run start``, then ``import --parent`` (twice: the second imports nothing); then the UI.
    Yields (base URL, experiment id, parent run id, client)."""
    import mlflow
    import yaml

    from pipelines.mlflow_import import results_of

    uri, artifacts = f"sqlite:///{tmp_path / 'mlflow.db'}", str(tmp_path / "mlruns")
    expected = len(results_of(yaml.safe_load((ROOT / "dvc.lock").read_text())))
    parent = _mlflow_parent_run("start", "--name", "make reproduce", uri=uri, artifacts=artifacts).splitlines()[-1]
    first = _mlflow_parent_run("import", "--parent", parent, uri=uri, artifacts=artifacts)
    assert f"{expected} results imported from dvc.lock, 0 already there" in first, first
    second = _mlflow_parent_run("import", "--parent", parent, uri=uri, artifacts=artifacts)
    assert f"0 results imported from dvc.lock, {expected} already there" in second, second
    client = mlflow.MlflowClient(uri)
    experiment_id = client.get_experiment_by_name("srmpc").experiment_id
    assert len(client.search_runs([experiment_id], max_results=1000)) == expected + 1
    with serve_mlflow(uri, artifacts, tmp_path / "server.log") as base:
        yield base, experiment_id, parent, client


@pytest.mark.timeout(3600)
def test_the_url_make_ui_prints_shows_the_tables_rows_with_j_c_and_v_x_and_a_training_chart(fresh_clone_ui, tmp_path):
    """On a store like a fresh clone's after ``make reproduce``, the URL of ``mlflow_parent_run url`` (what
    ``make ui`` prints) shows, without a click, one row per method and traffic of results/table.json, flat (not
    under the collapsed parent), with the table's J_c and v_x; and a training's metrics page draws its curve."""
    if CHROMIUM is None:
        pytest.skip("Chromium is not installed; install it from Debian's packages: apt-get install chromium")
    base, experiment_id, parent, client = fresh_clone_ui
    table = json.loads((ROOT / "results" / "table.json").read_text())
    rows = {}  # run name -> (J_c, v_x) of the table's row it is
    for traffic, methods in table.items():
        for method, summary in methods.items():
            runs = client.search_runs([experiment_id], filter_string=f"tags.method = '{method}' AND "
                                      f"tags.traffic = '{traffic}' AND {RESULTS_FILTER}")
            assert len(runs) == 1, f"{method} {traffic}: {len(runs)} runs marked as the table's row"
            assert runs[0].data.metrics[J_C] == summary[J_C]
            assert runs[0].data.tags["mlflow.parentRunId"] == parent
            rows[runs[0].info.run_name] = (summary[J_C], summary["mean_vx"])
    assert len(rows) == sum(len(methods) for methods in table.values()) >= 12, rows
    (training,) = client.search_runs([experiment_id],
                                     filter_string="tags.output_dir = 'results/training/ppo_lsi/seed_0'")
    url = _mlflow_parent_run("url", "--base", base, uri=str(client.tracking_uri),
                             artifacts=str(tmp_path / "mlruns")).splitlines()[-1]
    assert url.startswith(f"{base}/#/experiments/{experiment_id}/runs?viewStateShareKey=results&"), url
    shots = Path(os.environ.get("SRMPC_UI_SCREENSHOT_DIR", tmp_path))
    shots.mkdir(parents=True, exist_ok=True)

    async def browse():
        async with chromium_page(tmp_path / "chromium", deadline_s=900, window="1800,1000") as page:
            names = " && ".join(f"document.body.innerText.includes({json.dumps(n)})" for n in rows)
            await page.call("Page.navigate", url=url)
            await page.wait_for(f"document.body && {names} && document.body.innerText.includes({json.dumps(J_C)})"
                                " && document.body.innerText.includes('mean_vx')",
                                "the table's runs with the J_c and v_x columns")
            await asyncio.sleep(3)  # let the grid settle
            shot = await page.call("Page.captureScreenshot", format="png")
            (shots / "mlflow_make_ui_url.png").write_bytes(base64.b64decode(shot["data"]))
            dom = await page.evaluate("document.documentElement.outerHTML")
            text = await page.evaluate("document.body.innerText")
            header = await page.evaluate(HEADER_JS)

            await page.call("Page.navigate", url=f"{base}/#/experiments/{experiment_id}/runs/"
                                                 f"{training.info.run_id}/model-metrics")
            await page.wait_for("document.querySelectorAll('.js-plotly-plot .scatterlayer path.js-line').length > 0 "
                                "&& document.body.innerText.includes('(episode/return)')", "the training charts")
            await asyncio.sleep(3)
            shot = await page.call("Page.captureScreenshot", format="png")
            (shots / "mlflow_fresh_clone_training.png").write_bytes(base64.b64decode(shot["data"]))
            return dom, text, header, await page.evaluate(CHARTS_JS)

    dom, text, header, charts = asyncio.run(browse())
    assert "Model training" in dom  # the runs table, not the GenAI traces overview
    # left to right: method, traffic, J_c, v_x, rho_c, J_r, n_steps (the view's columnOrder), then the other tags
    assert _tag_and_metric_columns(header)[:len(FIRST_COLUMNS)] == FIRST_COLUMNS, header
    assert "make reproduce" not in text, "the parent run is listed: the table's runs are not shown flat"
    for name, (j_c, v_x) in rows.items():
        assert _cells(dom, name, f"metrics.`{J_C}`") == [_ui_number(j_c)], f"{name}: J_c, the table's {j_c}"
        assert _cells(dom, name, "metrics.`mean_vx`") == [_ui_number(v_x)], f"{name}: v_x, the table's {v_x}"

    chart = [c for c in charts if c["card"].endswith(f"{training.info.run_name} (episode/return)")]
    assert len(chart) == 1, charts
    assert max(chart[0]["vertices"]) > 100, chart  # the curve over 610 iterations, not a point or a bar
    assert {"5M", "10M", "15M"} <= set(chart[0]["xticks"]), chart  # against env steps (20M), not iterations
