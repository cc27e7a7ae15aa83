"""An output directory belongs to one process at a time (srmpc/output_lock.py): a second evaluation or
training into it exits with status 2 and one line naming the directory and the holder's pid, before it
writes anything; a holder killed with SIGKILL leaves no stale lock."""

from __future__ import annotations

import csv
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import mlflow
import pytest

from srmpc.output_lock import LOCK_NAME, OutputDirectoryBusy, OutputDirectoryUnwritable, exclusive_output_dir

ROOT = Path(__file__).resolve().parents[1]
def _wait_for(condition, process: subprocess.Popen) -> None:
    deadline = time.monotonic() + 600  # generous: a loaded machine starts the process slowly
    while not condition() and process.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert condition(), process.communicate()[1][-3000:] if process.poll() is not None else "timeout"


def _tracking(tmp_path: Path, experiment: str) -> list[str]:
    return [f"tracking.uri=sqlite:///{tmp_path / 'mlflow.db'}", f"tracking.artifact_location={tmp_path / 'mlruns'}",
            f"tracking.experiment_name={experiment}"]


def _runs(tmp_path: Path, experiment: str) -> list:
    mlflow.set_tracking_uri(f"sqlite:///{tmp_path / 'mlflow.db'}")
    return mlflow.search_runs(experiment_names=[experiment], output_format="list")


def _refused_line(second: subprocess.Popen, directory: Path, key: str, holder: subprocess.Popen) -> str:
    stdout, stderr = second.communicate(timeout=300)
    assert second.returncode == 2, stderr[-3000:]
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert lines[0] == (f"srmpc: error: {key}={directory}: in use by process {holder.pid} on {socket.gethostname()}, "
                        f"which holds {directory / LOCK_NAME}; wait for it to end or choose another directory")
    return lines[0]


def test_a_second_holder_is_refused_naming_the_first(tmp_path):
    directory = tmp_path / "out"
    with exclusive_output_dir(directory, "evaluation.output_dir"):
        with pytest.raises(OutputDirectoryBusy, match=rf"evaluation.output_dir={directory}: in use by process "
                                                      rf"{os.getpid()} on "):
            with exclusive_output_dir(directory, "evaluation.output_dir"):
                pass
        assert (directory / LOCK_NAME).read_text().split()[0] == str(os.getpid())
    assert not directory.exists()  # created by the holder and left empty: removed with its lock file
    directory.mkdir()
    (directory / "episodes.csv").write_text("kept\n")
    with exclusive_output_dir(directory, "evaluation.output_dir"):
        pass
    assert sorted(p.name for p in directory.iterdir()) == ["episodes.csv"]  # an existing directory stays


def test_an_unwritable_directory_names_the_key(tmp_path):
    (tmp_path / "file").write_text("not a directory\n")
    with pytest.raises(OutputDirectoryUnwritable, match=rf"^agent.output_dir={tmp_path / 'file' / 'run'}: cannot"):
        with exclusive_output_dir(tmp_path / "file" / "run", "agent.output_dir"):
            pass


def test_sigkill_leaves_no_stale_lock(tmp_path, start_process):
    directory = tmp_path / "out"
    holder = start_process([sys.executable, "-c", "import sys, time; from pathlib import Path; "
                     "from srmpc.output_lock import exclusive_output_dir\n"
                     f"with exclusive_output_dir(Path({str(directory)!r}), 'k'):\n"
                     "    print('held', flush=True); time.sleep(600)"])
    assert holder.stdout.readline().strip() == "held"
    with pytest.raises(OutputDirectoryBusy, match=f"in use by process {holder.pid} on"):
        with exclusive_output_dir(directory, "k"):
            pass
    os.killpg(holder.pid, signal.SIGKILL)
    holder.communicate()
    assert (directory / LOCK_NAME).exists()  # the file stays behind, its lock does not
    with exclusive_output_dir(directory, "k"):
        assert (directory / LOCK_NAME).read_text().split()[0] == str(os.getpid())


def test_two_evaluations_into_one_directory(tmp_path, start_process):
    out, experiment, episodes = tmp_path / "eval", "srmpc-lock-eval-test", 10_000  # runs until the test ends it
    command = [sys.executable, "-m", "srmpc", "controller=lane_keeping", f"evaluation.episodes={episodes}",
               "evaluation.workers=1", "scenario.episode_steps=100", f"evaluation.output_dir={out}",
               *_tracking(tmp_path, experiment)]
    first = start_process([*command, f"hydra.run.dir={tmp_path / 'hydra1'}"])
    csv_path = out / "episodes.csv"
    _wait_for(lambda: csv_path.exists() and len(csv_path.read_text().splitlines()) >= 2, first)
    second = start_process([*command, f"hydra.run.dir={tmp_path / 'hydra2'}"])
    _refused_line(second, out, "evaluation.output_dir", first)
    assert first.poll() is None, "the first evaluation ended before the second was refused"
    first.send_signal(signal.SIGTERM)  # the first keeps its finished episodes
    first.communicate(timeout=300)
    with csv_path.open(newline="") as handle:
        done = [int(row["episode"]) for row in csv.DictReader(handle)]
    assert done == list(range(len(done))) and len(done) >= 1  # each episode once, in order
    assert [r.info.status for r in _runs(tmp_path, experiment)] == ["FAILED"]  # the first's; the refused one has none
    assert not (out / LOCK_NAME).exists()  # released and removed by the first on its way out


def test_two_trainings_into_one_directory(tmp_path, start_process):
    out, experiment = tmp_path / "train", "srmpc-lock-train-test"
    command = [sys.executable, "-m", "srmpc", "stage=train", "agent=ppo_lsi", "agent.task=toy", "agent.num_envs=16",
               "agent.frames_per_batch=256", "agent.minibatch_size=128", "agent.epochs=1", "agent.multiplier_steps=2",
               "agent.checkpoint_every=1", f"agent.total_frames={256 * 10_000}", f"agent.output_dir={out}",
               *_tracking(tmp_path, experiment)]
    first = start_process([*command, f"hydra.run.dir={tmp_path / 'hydra1'}"])
    metrics = out / "metrics.csv"
    _wait_for(lambda: metrics.exists() and len(metrics.read_text().splitlines()) >= 2, first)
    second = start_process([*command, f"hydra.run.dir={tmp_path / 'hydra2'}"])
    _refused_line(second, out, "agent.output_dir", first)
    assert first.poll() is None, "the first training ended before the second was refused"
    first.send_signal(signal.SIGTERM)  # the first keeps its checkpoint and rows
    first.communicate(timeout=300)
    with metrics.open(newline="") as handle:
        iterations = [int(float(row["iteration"])) for row in csv.DictReader(handle)]
    assert iterations == list(range(iterations[0], iterations[0] + len(iterations))) and len(iterations) >= 1
    assert [r.info.status for r in _runs(tmp_path, experiment)] == ["FAILED"]  # the first's, ended by SIGTERM


@pytest.mark.parametrize("directory", ["results/training/ppo/seed_0", "results/evaluation/twin/srmpc_dense"])
def test_the_lock_file_is_no_part_of_a_dvc_or_git_output(directory):
    """A training's directory is a DVC output as a whole: a run in progress must not change its hash."""
    path = f"{directory}/{LOCK_NAME}"
    dvc = Path(sys.executable).with_name("dvc")
    for command in ([str(dvc), "check-ignore", path], ["git", "check-ignore", path]):
        result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, timeout=120)
        assert result.returncode == 0 and result.stdout.strip() == path, (command, result.stdout, result.stderr)
