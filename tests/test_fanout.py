"""SRMPC_FANOUT (srmpc.fanout): shards and trainings as jobs give the rows and results of the local run; a bad
switch, a missing sbatch and a failed job each end in one line. The real-SLURM tests are marked slow and need a
SLURM on PATH (``bash ../shared/tools/local_slurm.sh start`` runs one on localhost)."""

import functools
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
import yaml

from srmpc.config.compose import ConfigError, compose_config, to_objects
from srmpc.episode_loop import evaluate
from srmpc.errors import JobFailed
from srmpc.fanout import (
    EvaluationShard,
    Executor,
    FanoutSettings,
    complete_rows,
    evaluate_in_jobs,
    read_settings,
    settings_from_environment,
    shard_ranges,
)
from srmpc.numerics import SUMMARY_KEY
from srmpc.output_folder import EPISODES_NAME
from srmpc.stages.evaluate import run_evaluation
from srmpc.tracking import Run
from tests.scripted_episodes import FAILING_SEED, scripted_setup

ROOT = Path(__file__).resolve().parents[1]
NO_SLURM = "no SLURM here (no sbatch on PATH): bash ../shared/tools/local_slurm.sh start runs one on localhost"
needs_slurm = pytest.mark.skipif(shutil.which("sbatch") is None, reason=NO_SLURM)


def _config(controller, episodes, seed=3):
    return to_objects(compose_config([
        "+experiment=smoke", f"controller={controller}", f"evaluation.episodes={episodes}", "evaluation.workers=1",
        f"evaluation.seed={seed}", "tracking.enabled=false",
    ]))


def _settings_file(tmp_path, text):
    path = tmp_path / "fanout.yaml"
    path.write_text(text)
    return {"SRMPC_FANOUT": str(path), "PATH": os.environ["PATH"]}


@pytest.mark.parametrize(("text", "message"), [
    ("executor: cluster\n", "executor='cluster': must be one of slurm, local"),
    ("executor: slurm\n", "partition: missing (executor: slurm needs a partition)"),
    ("executor: local\nshard_size: 10\n", "unknown key 'shard_size'"),
    ("executor: local\nshard_episodes: 0\n", "shard_episodes=0: must be an integer >= 1"),
    ("- slurm\n", "must be a mapping of settings"),
])
def test_a_bad_settings_file_is_one_line_naming_the_key(tmp_path, text, message):
    environ = _settings_file(tmp_path, text)
    with pytest.raises(ConfigError, match=None) as error:
        settings_from_environment(environ)
    assert message in str(error.value) and "\n" not in str(error.value)
    assert str(error.value).startswith(f"SRMPC_FANOUT={environ['SRMPC_FANOUT']}: ")


def test_no_sbatch_on_path_is_one_line(tmp_path):
    environ = {**_settings_file(tmp_path, "executor: slurm\npartition: cpu\n"), "PATH": str(tmp_path)}
    with pytest.raises(ConfigError, match="executor: slurm, but there is no sbatch on PATH"):
        settings_from_environment(environ)
    assert settings_from_environment({}) is None and settings_from_environment({"SRMPC_FANOUT": ""}) is None
    settings = read_settings(tmp_path / "fanout.yaml")
    assert (settings.executor, settings.partition, settings.shard_episodes) == (Executor.slurm, "cpu", 50)


def test_shards_keep_their_boundaries_and_a_torn_row_is_not_read(tmp_path):
    assert shard_ranges(0, 5, 2) == [(0, 2), (2, 4), (4, 5)]
    assert shard_ranges(3, 10, 4) == [(3, 4), (4, 8), (8, 10)]  # resumed mid-shard: the same boundaries
    assert shard_ranges(10, 10, 4) == []
    path = tmp_path / "shard.csv"
    EvaluationShard(scripted_setup, 0, 3, 5, path)()
    text = path.read_text()
    path.write_text(text[:-3])  # the last row torn mid-value: it still parses, but has no line end
    assert [r.episode for r in complete_rows(path)] == [0, 1]


def test_a_local_job_resumes_a_shard_and_finished_shards_are_not_rerun(tmp_path):
    """Episodes 0-3 in shards of 2: shard 0 finished and shard 1 half done by an interrupted run (in this
    process, as its job would); one local job finishes shard 1, and the rows are the sequential run's."""
    config = _config("lane_keeping", 4)
    run_evaluation(config, "same\n", tmp_path / "sequential", Run(None), progress=False)
    settings = FanoutSettings(executor=Executor.local, shard_episodes=2, max_jobs=2, work_dir=str(tmp_path / "work"))
    from srmpc.controller_factory import make_env_and_controller
    from srmpc.fanout import shard_dir
    from srmpc.stages.evaluate import identity_yaml

    out = tmp_path / "jobs"
    rows = shard_dir(Path(settings.work_dir), out, identity_yaml(config, "same\n"))
    rows.mkdir(parents=True)
    setup = functools.partial(make_env_and_controller, config)
    EvaluationShard(setup, 0, 2, 3, rows / "shard_000000.csv")()
    EvaluationShard(setup, 2, 3, 3, rows / "shard_000001.csv")()
    run_evaluation(config, "same\n", out, Run(None), progress=False, fanout=settings)
    assert (out / EPISODES_NAME).read_text() == (tmp_path / "sequential" / EPISODES_NAME).read_text()
    assert (out / "summary.json").read_text() == (tmp_path / "sequential" / "summary.json").read_text()
    assert len(list((rows / "jobs").glob("[0-9]*"))) == 1  # one job: the rest of shard 1
    assert not list(rows.glob("shard_*.csv"))  # handed on, then removed


# ------------------------------------------------------------------------------------- real SLURM
def _slurm(tmp_path, shard_episodes=2, **extra):
    return FanoutSettings(executor=Executor.slurm, partition="cpu", shard_episodes=shard_episodes, max_jobs=4,
                          mem_gb=2, timeout_min=10, work_dir=str(tmp_path / "work"), **extra)


@pytest.mark.slow
@needs_slurm
@pytest.mark.parametrize("controller", ["lane_keeping", "ltv_mpc"])
def test_slurm_shards_write_the_local_rows(tmp_path, controller):
    config = _config(controller, 5 if controller == "lane_keeping" else 3)
    local = run_evaluation(config, "same\n", tmp_path / "local", Run(None), progress=False)
    slurm = run_evaluation(config, "same\n", tmp_path / "slurm", Run(None), progress=False, fanout=_slurm(tmp_path))
    assert slurm == local
    assert (tmp_path / "slurm" / EPISODES_NAME).read_text() == (tmp_path / "local" / EPISODES_NAME).read_text()


@pytest.mark.slow
@needs_slurm
def test_a_failed_slurm_job_is_one_line_with_its_log_after_the_rows_before_it(tmp_path, monkeypatch):
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join([str(ROOT), str(ROOT / "tests")]))  # the job imports this file
    handed_on = []
    with pytest.raises(JobFailed) as error:
        evaluate_in_jobs(scripted_setup, 6, FAILING_SEED - 3, _slurm(tmp_path), tmp_path / "rows", handed_on.append)
    message = str(error.value)
    assert "\n" not in message and "evaluation shard of episodes 2-3 (slurm job" in message
    assert f"ValueError: scripted failure at seed {FAILING_SEED}" in message
    log = Path(message.rsplit("log: ", 1)[1])
    assert log.is_file() and "scripted failure" in log.read_text()
    assert [r.episode for r in handed_on] == [0, 1, 2]  # episode 2 finished in the failing shard before episode 3
    assert handed_on == evaluate(*scripted_setup(), 3, FAILING_SEED - 3)


@pytest.mark.slow
@needs_slurm
def test_a_slurm_shard_signalled_before_its_time_limit_is_requeued_and_resumes(tmp_path):
    """``scancel -s USR2``: submitit's time-limit signal. The shard checkpoints, is requeued, and its second run
    resumes after the rows the first wrote; the evaluation's rows are the local run's. The shard's 300 episodes take
    seconds, so the signal, sent once 3 rows are written, reaches it mid-shard (30 took under 2 s once the kernels
    were cached: the job had finished first)."""
    config = _config("lane_keeping", 300)
    run_evaluation(config, "same\n", tmp_path / "local", Run(None), progress=False)
    environment = {**os.environ, "SRMPC_FANOUT": str(tmp_path / "fanout.yaml"), "TQDM_DISABLE": "1"}
    (tmp_path / "fanout.yaml").write_text(f"executor: slurm\npartition: cpu\nshard_episodes: 300\nmem_gb: 2\n"
                                          f"timeout_min: 10\nwork_dir: {tmp_path / 'work'}\n")
    out = tmp_path / "slurm"
    process = subprocess.Popen(
        [sys.executable, "-m", "srmpc", "+experiment=smoke", "controller=lane_keeping", "evaluation.episodes=300",
         "evaluation.seed=3", "tracking.enabled=false", f"evaluation.output_dir={out}",
         f"hydra.run.dir={tmp_path / 'hydra'}"], cwd=ROOT, env=environment, stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 300
        shard_files = []
        while time.monotonic() < deadline and process.poll() is None:
            shard_files = list((tmp_path / "work").glob("evaluation/*/shard_000000.csv"))
            if shard_files and len(complete_rows(shard_files[0])) >= 3:
                break
            time.sleep(0.5)
        assert shard_files and process.poll() is None, process.communicate()[0][-3000:]
        (job,) = [p.name for p in shard_files[0].parent.glob("jobs/[0-9]*")]
        subprocess.run(["scancel", "-s", "USR2", job], check=True)
        output = process.communicate(timeout=600)[0]
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 0, output[-3000:]
    assert (out / EPISODES_NAME).read_text() == (tmp_path / "local" / EPISODES_NAME).read_text()
    assert "Restarts=1" in subprocess.run(["scontrol", "show", "job", job], capture_output=True, text=True).stdout
    log = (shard_files[0].parent / "jobs" / job / f"{job}_0_log.out").read_text()  # both runs (--open-mode=append)
    assert log.count("Starting with JobEnvironment") == 2 and "Calling checkpoint method" in log, log


@pytest.mark.slow
@needs_slurm
def test_a_toy_training_through_slurm_equals_the_local_one(tmp_path):
    toy = ("agent=ppo_lsi agent.task=toy agent.num_envs=16 agent.frames_per_batch=256 agent.minibatch_size=128 "
           "agent.epochs=2 agent.multiplier_steps=2 agent.total_frames=1024 tracking.enabled=false agent.seed=1")
    (tmp_path / "fanout.yaml").write_text(f"executor: slurm\npartition: cpu\nmem_gb: 2\ntimeout_min: 10\n"
                                          f"work_dir: {tmp_path / 'work'}\n")
    results = {}
    for name, environment in (("local", {}), ("slurm", {"SRMPC_FANOUT": str(tmp_path / "fanout.yaml")})):
        run = f"{toy} agent.output_dir={tmp_path / name} hydra.run.dir={tmp_path / 'hydra' / name}"
        results[name] = subprocess.run([sys.executable, str(ROOT / "pipelines" / "train_runs.py"), "--jobs", "1", run],
                                       cwd=ROOT, capture_output=True, text=True, timeout=600,
                                       env={**os.environ, **environment})
        assert results[name].returncode == 0, results[name].stdout[-3000:] + results[name].stderr[-3000:]
    assert "slurm job" in results["slurm"].stdout and "exit 0" in results["slurm"].stdout
    summaries = [json.loads((tmp_path / name / "summary.json").read_text()) for name in ("local", "slurm")]
    apart = {"wall_s": None, SUMMARY_KEY: None}  # all but the wall time and the process's record (its threads)
    assert {**summaries[0], **apart} == {**summaries[1], **apart}
    policies = [torch.load(tmp_path / name / "policy.pt", weights_only=False) for name in ("local", "slurm")]
    assert _tensors(policies[0]) == _tensors(policies[1])


def _tensors(tree):
    """The tensors of a policy file, as nested lists (exact equality)."""
    if isinstance(tree, torch.Tensor):
        return tree.tolist()
    if isinstance(tree, dict):
        return {key: _tensors(value) for key, value in tree.items()}
    if isinstance(tree, list | tuple):
        return [_tensors(value) for value in tree]
    return tree


@pytest.mark.slow
def test_the_cli_without_sbatch_is_one_line(tmp_path):
    (tmp_path / "fanout.yaml").write_text("executor: slurm\npartition: cpu\n")
    environment = {**os.environ, "SRMPC_FANOUT": str(tmp_path / "fanout.yaml"),
                   "PATH": str(Path(sys.executable).parent)}
    result = subprocess.run([sys.executable, "-m", "srmpc", "+experiment=smoke", "tracking.enabled=false",
                             f"evaluation.output_dir={tmp_path / 'out'}", f"hydra.run.dir={tmp_path / 'hydra'}"],
                            cwd=ROOT, capture_output=True, text=True, env=environment, timeout=300)
    assert result.returncode == 2
    assert result.stderr.strip() == (f"srmpc: config error: SRMPC_FANOUT={tmp_path / 'fanout.yaml'}: executor: slurm, "
                                     "but there is no sbatch on PATH")
    assert not (tmp_path / "out" / EPISODES_NAME).exists()


@pytest.mark.slow
@needs_slurm
def test_dvc_repro_of_published_stages_through_slurm_locks_the_committed_hashes(tmp_path):
    """Two stages of dvc.yaml (lane keeping and LTV-MPC, light traffic: 1000 episodes each, in shards of 250, each
    a SLURM job), rerun by ``dvc repro`` in a clone with their outputs deleted, write into ``dvc.lock`` the
    hashes of the committed outputs (made by local processes): the fan-out is outside the stages' identity. A
    summary.json also records the machine that wrote it (``environment``): apart from that it equals the committed."""
    clone = tmp_path / "clone"
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True, timeout=300)
    stages = {"evaluate@table/lane_keeping-light": "results/evaluation/table/lane_keeping_light",
              "evaluate@table/ltv_mpc-light": "results/evaluation/table/ltv_mpc_light"}
    committed = _locked_outputs(clone / "dvc.lock", stages)
    bin_dir = Path(sys.executable).parent
    environment = {**os.environ, "PATH": f"{bin_dir}{os.pathsep}{os.environ['PATH']}", "TQDM_DISABLE": "1",
                   "SRMPC_FANOUT": str(tmp_path / "fanout.yaml")}
    (tmp_path / "fanout.yaml").write_text(f"executor: slurm\npartition: cpu\nmem_gb: 2\ntimeout_min: 20\n"
                                          f"shard_episodes: 250\nwork_dir: {tmp_path / 'work'}\n")
    subprocess.run([sys.executable, "-m", "srmpc.precompile"], cwd=clone, env=environment, check=True,
                   capture_output=True, timeout=1200)  # one compile, not one per shard (docs/scaling.md)
    for folder in stages.values():
        shutil.rmtree(clone / folder)
    for stage in stages:
        result = subprocess.run([str(bin_dir / "dvc"), "repro", "-s", stage], cwd=clone, env=environment,
                                capture_output=True, text=True, timeout=1800)
        assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert len(list((tmp_path / "work").rglob("*_submission.sh"))) >= 8  # the shards ran as SLURM jobs
    assert _locked_outputs(clone / "dvc.lock", stages) == committed
    for folder in stages.values():
        summary = json.loads((clone / folder / "summary.json").read_text())
        assert summary.pop(SUMMARY_KEY)["numerics"]
        assert summary == json.loads((ROOT / folder / "summary.json").read_text())


def _locked_outputs(lock: Path, stages: dict[str, str]) -> dict[str, str]:
    """Each output path of ``stages`` in ``lock`` and its MD5, but the summaries (they record the machine)."""
    locked = yaml.safe_load(lock.read_text())["stages"]
    return {out["path"]: out["md5"] for stage in stages for out in locked[stage]["outs"]
            if not out["path"].endswith("summary.json")}
