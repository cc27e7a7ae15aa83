"""Sharded evaluation (``evaluation.workers``): the sequential run's episodes, row for row, in episode order."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from srmpc.config.compose import ConfigError, compose_config, to_objects
from srmpc.episode_loop import evaluate, evaluate_in_workers
from srmpc.output_folder import read_finished_episodes
from srmpc.stages.evaluate import evaluation_workers, run_evaluation
from srmpc.tracking import Run
from tests.scripted_episodes import FAILING_SEED, SLOW_SEED, scripted_setup

ROOT = Path(__file__).resolve().parents[1]


def _config(controller, workers, episodes, seed=3):
    return to_objects(compose_config([
        "+experiment=smoke", f"controller={controller}", f"evaluation.episodes={episodes}",
        f"evaluation.workers={workers}", f"evaluation.seed={seed}", "tracking.enabled=false",
    ]))


@pytest.mark.parametrize("controller", ["lane_keeping", "ltv_mpc"])
def test_two_workers_write_the_sequential_episodes_csv_and_summary(tmp_path, controller):
    for workers in (1, 2):
        run_evaluation(_config(controller, workers, 4), "same\n", tmp_path / str(workers), Run(None), progress=False)
    sequential, sharded = tmp_path / "1", tmp_path / "2"
    assert (sharded / "episodes.csv").read_text() == (sequential / "episodes.csv").read_text()
    assert (sharded / "summary.json").read_text() == (sequential / "summary.json").read_text()
    records = read_finished_episodes(sharded / "episodes.csv")
    assert [(r.episode, r.seed) for r in records] == [(i, 3 + i) for i in range(4)]


def test_sharded_run_resumes_a_sequential_prefix(tmp_path):
    reference = run_evaluation(_config("lane_keeping", 1, 5), "same\n", tmp_path / "reference", Run(None),
                               progress=False)
    out = tmp_path / "resumed"
    run_evaluation(_config("lane_keeping", 1, 2), "same\n", out, Run(None), progress=False)
    assert run_evaluation(_config("lane_keeping", 2, 5), "same\n", out, Run(None), progress=False) == reference
    assert (out / "episodes.csv").read_text() == (tmp_path / "reference" / "episodes.csv").read_text()


def test_workers_default_to_every_core_and_at_most_one_per_episode():
    cores = len(os.sched_getaffinity(0))
    assert evaluation_workers(_config("lane_keeping", 0, 1000), 1000) == min(cores, 1000)
    assert evaluation_workers(_config("lane_keeping", 8, 1000), 3) == 3
    assert evaluation_workers(_config("lane_keeping", 8, 1000), 0) == 1
    with pytest.raises(ConfigError, match="evaluation.workers=-1"):
        evaluation_workers(_config("lane_keeping", -1, 10), 10)


def test_episodes_finishing_out_of_order_reach_on_episode_in_episode_order():
    seen = []
    records = evaluate_in_workers(scripted_setup, 6, SLOW_SEED, 2, on_episode=lambda r: seen.append(r.episode))
    assert seen == list(range(6))
    assert records == evaluate(*scripted_setup(), 6, SLOW_SEED)


def test_a_failing_episode_stops_the_workers_after_the_finished_prefix():
    seen = []
    with pytest.raises(ValueError, match=f"seed {FAILING_SEED}"):
        evaluate_in_workers(scripted_setup, 6, FAILING_SEED - 2, 2, on_episode=lambda r: seen.append(r.episode))
    assert seen == [0, 1]


def test_sigterm_stops_the_workers_and_keeps_the_finished_episodes(tmp_path):
    out = tmp_path / "eval"
    command = [sys.executable, "-m", "srmpc", "+experiment=smoke", "controller=lane_keeping",
               "evaluation.episodes=100000", "evaluation.workers=2", "tracking.enabled=false",
               f"evaluation.output_dir={out}", f"hydra.run.dir={tmp_path / 'hydra'}"]
    process = subprocess.Popen(command, cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                               start_new_session=True)
    try:
        deadline = time.monotonic() + 600
        while time.monotonic() < deadline and process.poll() is None and len(_rows(out)) < 4:
            time.sleep(0.2)
        assert len(_rows(out)) >= 4, process.communicate()[1][-2000:] if process.poll() is not None else "timeout"
        workers = _children(process.pid)
        process.send_signal(signal.SIGTERM)
        process.communicate(timeout=120)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.communicate()
    assert process.returncode == 128 + signal.SIGTERM
    assert len(workers) == 2
    deadline = time.monotonic() + 10
    while [pid for pid in workers if _alive(pid)] and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not [pid for pid in workers if _alive(pid)], "workers outlived the evaluation"
    records = read_finished_episodes(out / "episodes.csv")
    assert [r.episode for r in records] == list(range(len(records))) and len(records) >= 4
    assert _rows(out)[-1].endswith("\n")


def _rows(out):
    path = out / "episodes.csv"
    return path.read_text().splitlines(keepends=True)[1:] if path.exists() else []


def _children(pid):
    """The worker processes of ``pid`` (multiprocessing's spawned children, not its resource tracker)."""
    children = []
    for status in Path("/proc").glob("[0-9]*/status"):
        try:
            fields = dict(line.split(":\t", 1) for line in status.read_text().splitlines() if ":\t" in line)
            command = (status.parent / "cmdline").read_bytes()
        except OSError:
            continue
        if fields.get("PPid", "").strip() == str(pid) and b"spawn_main" in command:
            children.append(int(status.parent.name))
    return children


def _alive(pid):
    try:
        state = next(line for line in Path(f"/proc/{pid}/status").read_text().splitlines() if line.startswith("State"))
    except (OSError, StopIteration):
        return False
    return "zombie" not in state
