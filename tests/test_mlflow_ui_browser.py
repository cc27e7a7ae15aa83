"""In a real browser, the MLflow UI lists an SRMPC and an LTV-MPC run with their J_c (headless Chromium).

Chromium is driven over its DevTools protocol (``tests/chromium_devtools.py``): open the
runs table, choose the metric columns (MLflow 3.17 shows none by default), reload, screenshot, read the DOM.
Needs Chromium from Debian's packages (``apt-get install chromium``); skipped, saying so, without it.
The screenshot goes to ``$SRMPC_UI_SCREENSHOT`` if set, else into the test's temporary directory.
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

from srmpc.tracking import PARENT_RUN_ENV, RUNS_TABLE_COLUMNS, runs_table_url, tracked_run
from tests.chromium_devtools import CHROMIUM, chromium_page
from tests.mlflow_server import serve_mlflow

pytestmark = pytest.mark.slow

RUNS = {"evaluate-srmpc-paper-light": ("srmpc", 0.002), "evaluate-ltv_mpc-light": ("ltv_mpc", 0.041)}
J_C = "mean_event_cost"


@pytest.fixture
def mlflow_ui(tmp_path, monkeypatch):
    """``mlflow server`` on a free port over a temporary SQLite store holding the two runs; yields the
    runs-table URL (MLflow 3.17 opens experiments in its GenAI view unless told ``workflowType``)."""
    monkeypatch.delenv(PARENT_RUN_ENV, raising=False)
    uri, artifacts = f"sqlite:///{tmp_path / 'mlflow.db'}", str(tmp_path / "mlruns")
    for name, (controller, j_c) in RUNS.items():
        params = {"stage": "evaluate", "scenario": {"traffic": "light"},
                  "evaluation": {"controller": controller, "seed": 0}, "srmpc": {"variant": "paper"}}
        with tracked_run(True, uri, artifacts, "srmpc", name, params, "stage: evaluate\n") as run:
            run.log_metrics({J_C: j_c, "mean_vx": 21.5})
    import mlflow

    experiment_id = mlflow.MlflowClient(uri).get_experiment_by_name("srmpc").experiment_id
    mlflow.set_tracking_uri(None)
    with serve_mlflow(uri, artifacts, tmp_path / "server.log") as base:
        yield runs_table_url(base, experiment_id)


RUNS_TABLE_STATE_JS = """(() => {
  // The runs table keeps its state (selectedColumns among it) as JSON in localStorage; MLflow 3.17 shows
  // no metric column until one is chosen, so choose the paper's view here, as Columns -> Metrics would.
  // EXPANDED: the parent runs to show expanded ({} for none; imported runs are a parent's children).
  let changed = 0;
  for (let i = 0; i < localStorage.length; i++) {
    const key = localStorage.key(i);
    let state;
    try { state = JSON.parse(localStorage.getItem(key)); } catch (e) { continue; }
    if (state && Array.isArray(state.selectedColumns)) {
      state.selectedColumns = COLUMNS;
      Object.assign(state, EXPANDED);
      localStorage.setItem(key, JSON.stringify(state));
      changed++;
    }
  }
  return changed;
})()"""


def runs_table_state(parent: str | None = None) -> str:
    """``RUNS_TABLE_STATE_JS`` selecting the paper's metric columns (and expanding ``parent``)."""
    columns = json.dumps([c for c in RUNS_TABLE_COLUMNS if c.startswith("metrics.")])
    expanded = json.dumps({"runsExpanded": {parent: True}} if parent else {})
    return RUNS_TABLE_STATE_JS.replace("COLUMNS", columns).replace("EXPANDED", expanded)


async def _browse(url: str, profile: Path, screenshot: Path, deadline_s: float) -> str:
    """Open ``url`` in headless Chromium over the DevTools protocol, select the paper's columns, reload,
    save a screenshot; returns the page's DOM."""
    async with chromium_page(profile, deadline_s=deadline_s) as page:
        names = " && ".join(f"document.body.innerText.includes({json.dumps(n)})" for n in RUNS)
        await page.call("Page.navigate", url=url)
        await page.wait_for(f"document.body && {names}", "the runs table")
        assert await page.evaluate(runs_table_state()) >= 1, "no runs-table state"
        await page.call("Page.reload")
        await page.wait_for(f"document.body && {names} && document.body.innerText.includes({json.dumps(J_C)})",
                            "the J_c column")
        await asyncio.sleep(3)  # let the grid settle
        shot = await page.call("Page.captureScreenshot", format="png")
        screenshot.write_bytes(base64.b64decode(shot["data"]))
        return await page.evaluate("document.documentElement.outerHTML")


@pytest.mark.timeout(2400)
def test_runs_table_shows_srmpc_and_ltv_mpc_with_their_j_c(mlflow_ui, tmp_path):
    if CHROMIUM is None:
        pytest.skip("Chromium is not installed; install it from Debian's packages: apt-get install chromium")
    screenshot = Path(os.environ.get("SRMPC_UI_SCREENSHOT", tmp_path / "mlflow_runs_table.png"))
    screenshot.parent.mkdir(parents=True, exist_ok=True)
    dom = asyncio.run(_browse(mlflow_ui, tmp_path / "chromium", screenshot, deadline_s=900))
    assert screenshot.stat().st_size > 20_000, "screenshot missing or blank"

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
    """How the runs table writes a metric (JavaScript's number to string, for these plain values)."""
    return str(int(value)) if float(value).is_integer() else repr(float(value))


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
def test_fresh_clone_runs_table_shows_the_tables_methods_with_their_j_c_and_a_training_chart(fresh_clone_ui, tmp_path):
    if CHROMIUM is None:
        pytest.skip("Chromium is not installed; install it from Debian's packages: apt-get install chromium")
    base, experiment_id, parent, client = fresh_clone_ui
    from pipelines.reporting import CONFIRMATION, EVALUATION  # the table's rows: the twin's runs, the confirmation's

    table = json.loads((ROOT / "results" / "table.json").read_text())
    rows = {}  # run name -> the J_c the paper's table gives its method and traffic
    for traffic, methods in table.items():
        for method, summary in methods.items():
            recommended = method == "srmpc_recommended"  # the confirmation's run of srmpc=track_rollout
            directory = f"{CONFIRMATION if recommended else EVALUATION}/{method}_{traffic}"
            runs = client.search_runs([experiment_id], filter_string=f"tags.output_dir = '{directory}'")
            assert len(runs) == 1, f"{directory}: {len(runs)} runs"
            tagged = "srmpc_track_rollout" if recommended else method
            assert runs[0].data.tags["method"] == tagged and runs[0].data.tags["traffic"] == traffic
            assert runs[0].data.tags["mlflow.parentRunId"] == parent
            rows[runs[0].info.run_name] = summary[J_C]
    assert len(rows) >= 6, rows
    (training,) = client.search_runs([experiment_id],
                                     filter_string="tags.output_dir = 'results/training/ppo_lsi/seed_0'")
    shots = Path(os.environ.get("SRMPC_UI_SCREENSHOT_DIR", tmp_path))
    shots.mkdir(parents=True, exist_ok=True)

    async def browse():
        async with chromium_page(tmp_path / "chromium", deadline_s=900, window="1800,2600") as page:
            names = " && ".join(f"document.body.innerText.includes({json.dumps(n)})" for n in rows)
            await page.call("Page.navigate", url=runs_table_url(base, experiment_id))
            await page.wait_for("document.body && document.body.innerText.includes('make reproduce')", "the parent")
            assert await page.evaluate(runs_table_state(parent)) >= 1, "no runs-table state"
            await page.call("Page.reload")
            await page.wait_for(f"document.body && {names} && document.body.innerText.includes({json.dumps(J_C)})",
                                "the imported runs and the J_c column")
            await asyncio.sleep(3)  # let the grid settle
            shot = await page.call("Page.captureScreenshot", format="png")
            (shots / "mlflow_fresh_clone_runs.png").write_bytes(base64.b64decode(shot["data"]))
            dom = await page.evaluate("document.documentElement.outerHTML")

            await page.call("Page.navigate", url=f"{base}/#/experiments/{experiment_id}/runs/"
                                                 f"{training.info.run_id}/model-metrics")
            await page.wait_for("document.querySelectorAll('.js-plotly-plot .scatterlayer path.js-line').length > 0 "
                                "&& document.body.innerText.includes('(episode/return)')", "the training charts")
            await asyncio.sleep(3)
            shot = await page.call("Page.captureScreenshot", format="png")
            (shots / "mlflow_fresh_clone_training.png").write_bytes(base64.b64decode(shot["data"]))
            return dom, await page.evaluate(CHARTS_JS)

    dom, charts = asyncio.run(browse())
    for name, j_c in rows.items():  # each run's row (ag-grid's row-index, shared by its cells) holds its J_c
        row = re.search(rf'row-index="(\d+)"(?:(?!row-index=).)*?>{re.escape(name)}<', dom, re.S)
        assert row, f"no row for {name}"
        cells = "".join(re.findall(rf'row-index="{row.group(1)}"(?:(?!row-index=).)*', dom, re.S))
        shown = re.findall(rf'col-id="metrics.`{J_C}`"[^>]*>(?:<[^>]*>)*([^<]*)<', cells)
        assert shown == [_ui_number(j_c)], f"{name}: J_c shown {shown}, the table's {j_c}"

    chart = [c for c in charts if c["card"].endswith(f"{training.info.run_name} (episode/return)")]
    assert len(chart) == 1, charts
    assert max(chart[0]["vertices"]) > 100, chart  # the curve over 610 iterations, not a point or a bar
    assert {"5M", "10M", "15M"} <= set(chart[0]["xticks"]), chart  # against env steps (20M), not iterations
