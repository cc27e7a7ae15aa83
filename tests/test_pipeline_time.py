"""benchmarks/pipeline_time.py on a three-stage DVC project: which stages train, which are downstream of
training, and the per-stage times parsed from `dvc repro -f` as it runs."""

import hashlib
import importlib.util
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SPEC = importlib.util.spec_from_file_location("pipeline_time", ROOT / "benchmarks" / "pipeline_time.py")
pipeline_time = importlib.util.module_from_spec(SPEC)
SPEC.loader.exec_module(pipeline_time)

DVC_YAML = """stages:
  scenario:
    cmd: python -c "open('scenario.txt', 'w').write('s')"
    outs: [scenario.txt]
  train:
    cmd: python -c "import time; time.sleep(1.5); open('policy.txt', 'w').write('p')"
    deps: [scenario.txt]
    outs: [policy.txt]
  evaluate:
    cmd: python -c "open('episodes.txt', 'w').write(open('policy.txt').read())"
    deps: [policy.txt]
    outs: [episodes.txt]
  table:
    cmd: python -c "open('table.txt', 'w').write(open('episodes.txt').read())"
    deps: [episodes.txt]
    outs: [table.txt]
"""


@pytest.fixture
def project(tmp_path):
    for command in (["git", "init", "-q"], [str(Path(sys.executable).parent / "dvc"), "init", "-q"]):
        subprocess.run(command, cwd=tmp_path, check=True, capture_output=True)
    (tmp_path / "dvc.yaml").write_text(DVC_YAML)
    return tmp_path


def test_stage_kinds_follow_the_graph(project):
    assert pipeline_time.training_stage_names(project / "dvc.yaml") == set()  # no srmpc training command
    kinds = pipeline_time.stage_kinds(project, {"train"})
    assert kinds == {"scenario": "other", "train": "training", "evaluate": "downstream", "table": "downstream"}


def test_training_stages_are_found_by_their_command(tmp_path):
    (tmp_path / "dvc.yaml").write_text(
        "stages:\n  a:\n    cmd: python -m srmpc stage=train agent=ppo\n"
        "  b:\n    cmd: python -m pipelines.train_runs 'agent=ppo'\n"
        "  c:\n    cmd: python -m srmpc +experiment=light_traffic\n")
    assert pipeline_time.training_stage_names(tmp_path / "dvc.yaml") == {"a", "b"}


def _part(project: Path):
    state = pipeline_time.RunState(project / "state.json", {"commit": "c", "setup_s": 0.0, "committed_outputs": {},
                                                            "parts": []})
    return state, state.new_part([])


def test_timed_repro_times_every_stage_in_order(project):
    state, part = _part(project)
    wall, stages, returncode = pipeline_time.timed_repro(project, Path(sys.executable).parent,
                                                         project / "repro.log", part, state, force=True)
    assert returncode == 0
    assert [s["name"] for s in stages] == ["scenario", "train", "evaluate", "table"]
    assert stages[1]["wall_s"] >= 1.5  # the stage that sleeps
    assert all(s["wall_s"] > 0 for s in stages)
    assert abs(sum(s["wall_s"] for s in stages) + stages[0]["started_s"] - wall) < 1e-6
    outputs = pipeline_time.locked_outputs(project / "dvc.lock")
    assert set(outputs) == {"scenario.txt", "policy.txt", "episodes.txt", "table.txt"}
    assert outputs == {name: hashlib.md5((project / name).read_bytes()).hexdigest() for name in outputs}


BURN = """import subprocess, sys
BURN_0_6_S = "import time\\nt = time.process_time()\\nwhile time.process_time() - t < 0.6: pass"
subprocess.run([sys.executable, "-c", BURN_0_6_S], check=True)
open("episodes.txt", "w").write(open("policy.txt").read())
"""


def test_each_stage_gets_the_core_seconds_of_its_processes(project):
    """A stage whose child process burns 0.6 s of CPU is charged at least that (the grandchild is reaped by the
    stage, the stage by DVC); the stage that sleeps 1.5 s is charged far less than its wall time."""
    (project / "burn.py").write_text(BURN)
    (project / "dvc.yaml").write_text(DVC_YAML.replace(
        '''python -c "open('episodes.txt', 'w').write(open('policy.txt').read())"''', "python burn.py"))
    state, part = _part(project)
    wall, stages, returncode = pipeline_time.timed_repro(project, Path(sys.executable).parent,
                                                         project / "repro.log", part, state, force=True)
    assert returncode == 0
    core = {s["name"]: s["core_s"] for s in stages}
    assert core["evaluate"] >= 0.6, core
    assert core["train"] < 1.0 < stages[1]["wall_s"], (core, stages)
    assert all(c > 0 for c in core.values()), core  # every stage starts a Python interpreter
    assert part["core_s"] >= sum(core.values()), (part["core_s"], core)  # DVC's own CPU on top
    _, merged = pipeline_time.merge_parts(state.state["parts"])
    assert [s["core_s"] for s in merged] == [core[s["name"]] for s in merged]


def test_a_failing_stage_gives_its_exit_code(project):
    (project / "dvc.yaml").write_text(DVC_YAML.replace("open('table.txt', 'w')", "exit(3) or open('table.txt', 'w')"))
    state, part = _part(project)
    wall, stages, returncode = pipeline_time.timed_repro(project, Path(sys.executable).parent,
                                                         project / "repro.log", part, state, force=True)
    assert returncode != 0 and stages[-1]["name"] == "table"


def test_a_cut_run_resumes_where_it_stopped_and_its_parts_add_up(project):
    """Part 1 stops at ``evaluate`` (it fails, as a cut would leave it); part 2, ``dvc repro`` without -f,
    skips the two finished stages and runs the rest; the state file read back merges them, each stage once."""
    bin_dir = Path(sys.executable).parent
    failing = DVC_YAML.replace("open('episodes.txt', 'w')", "exit(3) or open('episodes.txt', 'w')")
    (project / "dvc.yaml").write_text(failing)
    state, part = _part(project)
    _, first, returncode = pipeline_time.timed_repro(project, bin_dir, project / "repro.log", part, state,
                                                     force=True)
    assert returncode != 0 and [s["name"] for s in first] == ["scenario", "train", "evaluate"]
    (project / "dvc.yaml").write_text(DVC_YAML)
    state = pipeline_time.RunState.load(project / "state.json")  # as a new process would
    part = state.new_part([])
    _, second, returncode = pipeline_time.timed_repro(project, bin_dir, project / "repro.log", part, state,
                                                      force=False)
    assert returncode == 0 and [s["name"] for s in second] == ["evaluate", "table"]
    wall, merged = pipeline_time.merge_parts(pipeline_time.RunState.load(project / "state.json").state["parts"])
    assert [(s["name"], s["pieces"]) for s in merged] == [("scenario", 1), ("train", 1), ("evaluate", 2), ("table", 1)]
    parts = state.state["parts"]
    assert wall == pytest.approx(parts[0]["wall_s"] + parts[1]["wall_s"]) and not parts[0]["finished"]
    assert merged[2]["wall_s"] == pytest.approx(first[2]["wall_s"] + second[0]["wall_s"])
    assert merged[3]["started_s"] == pytest.approx(parts[0]["wall_s"] + second[1]["started_s"])
    assert (project / "table.txt").read_text() == "p"


def test_projections_reproduce_the_measured_machine_and_scale_the_parallel_stages():
    """On the measured core count the model gives back the measured times; on 8 cores the trainings run
    all six at once and an evaluation keeps its fixed start and spreads the rest; on SLURM the
    critical path runs through the longest training run and the longest evaluation."""
    runs = [{"stage": "train", "wall_s": 100.0} for _ in range(6)]
    stages = [{"name": "scenario", "kind": "other", "wall_s": 5.0},
              {"name": "train", "kind": "training", "wall_s": 330.0},  # 3 waves of 100 s on 2 cores, + 30 s
              {"name": "evaluate@a-light", "kind": "downstream", "wall_s": 108.5},
              {"name": "evaluate@b-light", "kind": "downstream", "wall_s": 58.5},
              {"name": "table", "kind": "downstream", "wall_s": 2.0}]
    upstreams = {"scenario": set(), "train": {"scenario"}, "evaluate@a-light": {"train"},
                 "evaluate@b-light": {"train"}, "table": {"evaluate@a-light", "evaluate@b-light"}}
    start = pipeline_time.EVALUATION_START_S
    result = pipeline_time.projections(stages, runs, {"evaluate"}, upstreams, measured_cores=2)
    assert result["laptop_2_cores"]["dvc_repro_wall_s"] == pytest.approx(sum(s["wall_s"] for s in stages))
    eight = 5.0 + 330.0 * 100.0 / 300.0 + (start + (108.5 - start) / 4) + (start + (58.5 - start) / 4) + 2.0
    assert result["workstation_8_cores"]["dvc_repro_wall_s"] == pytest.approx(eight)
    slurm = 5.0 + 330.0 * 100.0 / 300.0 + (start + (108.5 - start) / 4) + 2.0  # the longer evaluation only
    assert result["slurm_cluster"]["critical_path_s"] == pytest.approx(slurm)


def test_slurm_projection_schedules_one_core_jobs_after_their_upstream_stages():
    """Shards of 50 episodes and training runs are one-core jobs with the per-job overhead; a stage's jobs start when
    its upstream stages are done; with few cores the jobs queue (longest first), with many the critical path rules."""
    runs = [{"stage": "train", "wall_s": 100.0} for _ in range(4)]
    start = pipeline_time.EVALUATION_START_S
    stages = [{"name": "train", "kind": "training", "wall_s": 200.0},
              {"name": "evaluate@a-light", "kind": "downstream", "wall_s": start + 50.0},  # 100 core-s on 2 cores
              {"name": "table", "kind": "downstream", "wall_s": 2.0}]
    upstreams = {"train": set(), "evaluate@a-light": {"train"}, "table": {"evaluate@a-light"}}
    jobs = {s["name"]: pipeline_time.slurm_jobs(s, runs, {"evaluate"}, 2, 200, 5.0) for s in stages}
    assert jobs == {"train": [105.0] * 4, "evaluate@a-light": [30.0] * 4, "table": [2.0]}  # 200 episodes: 4 shards
    assert pipeline_time.slurm_schedule(jobs, upstreams, cores=64) == pytest.approx(105.0 + 30.0 + 2.0)
    assert pipeline_time.slurm_schedule(jobs, upstreams, cores=2) == pytest.approx(2 * 105.0 + 2 * 30.0 + 2.0)
    assert pipeline_time.slurm_schedule({"a": [3.0, 1.0, 1.0, 1.0]}, {}, cores=2) == pytest.approx(3.0)
    result = pipeline_time.projections(stages, runs, {"evaluate"}, upstreams, measured_cores=2,
                                       episodes={"evaluate@a-light": 200}, slurm_overhead_s=5.0)
    assert result["slurm_64_cores"]["wall_s"] == pytest.approx(137.0)
    assert result["slurm_64_cores"]["jobs"] == 9
    measured = {**stages[1], "core_s": 2 * start + 60.0}  # the stage's core-seconds, where measured, over its wall
    assert pipeline_time.slurm_jobs(measured, runs, {"evaluate"}, 2, 200, 5.0) == [20.0] * 4
    assert pipeline_time.slurm_job_overhead_s() > 0  # from the committed results/benchmarks/slurm_overhead.json


def test_evaluation_stages_are_found_by_their_command(tmp_path):
    (tmp_path / "dvc.yaml").write_text(
        "stages:\n  evaluate:\n    matrix: {m: [a]}\n    cmd: python -m srmpc evaluation.controller=${item.m}\n"
        "  sb3:\n    foreach: [light]\n    do:\n      cmd: python -m srmpc scenario=${item}\n"
        "  train:\n    cmd: python -m srmpc stage=train agent=ppo\n"
        "  table:\n    cmd: python -m pipelines.paper_table\n")
    assert pipeline_time.evaluation_stage_names(tmp_path / "dvc.yaml") == {"evaluate", "sb3"}



def test_a_lock_emptied_by_the_cut_is_put_back_from_its_copy(project):
    """A cut while DVC rewrites ``dvc.lock`` leaves it empty; the copy taken as the last stage started brings the
    finished stages back, so the resumed part runs only the rest; with no copy, resuming stops with one line."""
    bin_dir, backup = Path(sys.executable).parent, project / "dvc.lock.good"
    failing = DVC_YAML.replace("open('episodes.txt', 'w')", "exit(3) or open('episodes.txt', 'w')")
    (project / "dvc.yaml").write_text(failing)
    state, part = _part(project)
    pipeline_time.timed_repro(project, bin_dir, project / "repro.log", part, state, force=True, lock_backup=backup)
    assert set(pipeline_time.locked_outputs(backup)) == {"scenario.txt", "policy.txt"}
    (project / "dvc.yaml").write_text(DVC_YAML)
    (project / "dvc.lock").write_text("")  # the cut
    with pytest.raises(SystemExit, match="dvc.lock is unreadable .* holds no copy"):
        pipeline_time.prepare_resume(project, project / "no-copy")
    assert "put back" in pipeline_time.prepare_resume(project, backup)
    assert pipeline_time.prepare_resume(project, backup) is None  # readable now: left as it is
    part = state.new_part([])
    _, second, returncode = pipeline_time.timed_repro(project, bin_dir, project / "repro.log", part, state,
                                                      force=False, lock_backup=backup)
    assert returncode == 0 and [s["name"] for s in second] == ["evaluate", "table"]


def test_the_report_of_a_finished_run_covers_every_locked_stage_and_sums_its_groups(project):
    state, part = _part(project)
    _, stages, returncode = pipeline_time.timed_repro(project, Path(sys.executable).parent, project / "repro.log",
                                                      part, state, force=True)
    assert returncode == 0
    result = pipeline_time.report(state.state, project)
    assert result["covers_every_stage"] and result["n_stages"] == result["n_stages_in_dvc_lock"] == 4
    assert result["dvc_repro_wall_s"] == pytest.approx(part["wall_s"])
    assert sorted(g["group"] for g in result["groups"]) == ["evaluate", "scenario", "table", "train"]
    assert sum(g["core_s"] for g in result["groups"]) == pytest.approx(result["core_s"])
    assert sum(g["share_of_core_s"] for g in result["groups"]) == pytest.approx(1.0)
    # --regroup: the derived keys again from the measured stages alone, against the checkout's dvc.lock
    measured = {k: v for k, v in result.items() if k not in ("groups", "n_stages_in_dvc_lock", "covers_every_stage")}
    again = pipeline_time.regroup(measured, project)
    assert {k: v for k, v in again.items() if k != "dvc_lock_commit"} == result
    fewer = pipeline_time.regroup({**measured, "stages": measured["stages"][:-1]}, project)
    assert not fewer["covers_every_stage"] and fewer["n_stages"] == 3 and fewer["n_stages_in_dvc_lock"] == 4
    (project / "dvc.lock").write_text("")
    with pytest.raises(SystemExit, match="--regroup: .*dvc.lock is missing or unreadable"):
        pipeline_time.regroup(measured, project)


def test_stage_groups_follow_dvc_yaml():
    names = ["train", "designate_policy@ppo", "evaluate@nmpc/rollout-dense", "evaluate@nmpc/shifted-light", "table"]
    assert [pipeline_time.stage_group(n) for n in names] == ["train", "designate_policy", "evaluate@nmpc",
                                                             "evaluate@nmpc", "table"]
    groups = pipeline_time.stage_groups([{"name": n, "wall_s": 1.0, "core_s": float(i)} for i, n in enumerate(names)])
    assert [(g["group"], g["stages"], g["core_s"]) for g in groups] == [
        ("evaluate@nmpc", 2, 5.0), ("table", 1, 4.0), ("designate_policy", 1, 1.0), ("train", 1, 0.0)]
