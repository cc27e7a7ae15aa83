"""The README's cheap commands, run in a fresh copy of the repository, leave ``git status`` clean.

The copy holds what a clone of the working tree would (tracked and untracked, not ignored, files),
committed into a new repository; numba's kernel cache is copied along so the kernels do not
recompile. Each command writes only where the README says: ``outputs/`` (Hydra's run directories,
the smoke training), ``mlflow.db`` and ``mlruns/``, all ignored by git. The toy training without an
output directory, the command that once overwrote ``results/training/ppo_lsi``, is refused there.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
CHEAP = ("+experiment=smoke", "--cfg job", "agent.task=toy")
"""What marks a README command as seconds-long."""
DOCUMENTED_OUTPUTS = {"outputs/", "mlflow.db", "mlruns/"}


def readme_commands() -> list[str]:
    """Every ``python -m srmpc`` line of the README's bash blocks, without its comment."""
    text = (ROOT / "README.md").read_text()
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", text, flags=re.DOTALL):
        for line in block.splitlines():
            command = line.split("#", 1)[0].strip()
            if command.startswith(".venv/bin/python -m srmpc"):
                commands.append(command)
    return commands


def _git(cwd: Path, *args: str) -> str:
    return subprocess.run(["git", *args], cwd=cwd, check=True, capture_output=True, text=True).stdout


def fresh_copy(target: Path) -> Path:
    files = _git(ROOT, "ls-files", "-co", "--exclude-standard", "-z").split("\0")
    for name in filter(None, files):
        source = ROOT / name
        if source.is_file():
            (target / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, target / name)
    for package in ("sim", "scenario"):  # numba's cache, valid for sources with the same mtime and size
        cache = ROOT / "srmpc" / package / "__pycache__"
        if cache.is_dir():
            shutil.copytree(cache, target / "srmpc" / package / "__pycache__", copy_function=shutil.copy2,
                            ignore=shutil.ignore_patterns("*.pyc"), dirs_exist_ok=True)
    (target / ".venv").symlink_to(ROOT / ".venv")
    _git(target, "init", "-q")
    _git(target, "add", "-A")
    _git(target, "-c", "user.name=test", "-c", "user.email=test@example.com", "commit", "-q", "-m", "copy")
    return target


def test_the_readme_shows_the_cheap_commands():
    cheap = [c for c in readme_commands() if any(mark in c for mark in CHEAP)]
    assert len(cheap) == 3, cheap
    train = next(c for c in cheap if "stage=train" in c)
    assert "agent.output_dir=outputs/" in train


@pytest.mark.slow
def test_cheap_readme_commands_leave_git_status_clean(tmp_path):
    copy = fresh_copy(tmp_path / "clone")
    env = {**os.environ, "MLFLOW_TRACKING_URI": ""}
    env.pop("SRMPC_PARENT_RUN_ID", None)
    results_before = _git(copy, "ls-files", "-s", "results")
    for command in [c for c in readme_commands() if any(mark in c for mark in CHEAP)]:
        result = subprocess.run(command, shell=True, cwd=copy, capture_output=True, text=True, timeout=600, env=env)
        assert result.returncode == 0, f"{command}\n{result.stderr[-3000:]}"
        assert _git(copy, "status", "--porcelain") == "", command

    # the smoke training as it used to read, into the committed results/training/ppo_lsi: refused
    command = ".venv/bin/python -m srmpc stage=train agent.task=toy agent.total_frames=65536"
    result = subprocess.run(command, shell=True, cwd=copy, capture_output=True, text=True, timeout=600, env=env)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [result.stderr.strip()]
    assert re.search(r"^srmpc: config error: agent\.output_dir=results/training/ppo_lsi\S*: holds ", result.stderr)

    assert _git(copy, "status", "--porcelain") == ""
    assert _git(copy, "ls-files", "-s", "results") == results_before
    ignored = _git(copy, "status", "--porcelain", "--ignored").splitlines()
    new = {line[3:] for line in ignored if line.startswith("!! ")}
    new = {path for path in new if "__pycache__" not in path and path != ".venv"}
    assert new <= DOCUMENTED_OUTPUTS | {"srmpc.egg-info/"}, new
