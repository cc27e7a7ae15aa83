"""The spot check (pipelines/spot_check.py): recomputed first rows equal the committed ones on this machine, a
corrupted committed row is named, bad input is one line.

The sample cells reproduce on every CPU measured so far (lane keeping, SRMPC). Evaluations of a bare policy differ
in their last bits on a CPU whose OpenBLAS kernels differ from the committing Xeon's (docs/pipeline.md, "Checking
your reproduction"), so they are not in the default suite's sample.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from pipelines.spot_check import main
from pipelines.spot_check_cells import compare_metrics

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = "evaluate@table/lane_keeping-light,evaluate@table/srmpc-dense"
CELL = "evaluate@table/lane_keeping-light"
CELL_EPISODES = "results/evaluation/table/lane_keeping_light/episodes.csv"


def _report(path: Path) -> dict:
    return json.loads(path.read_text())


def test_a_sample_of_committed_evaluations_reproduces(tmp_path, capsys):
    """Two cells, one episode each, recomputed by their stages' own commands: byte-equal rows, exit status 0."""
    report_path = tmp_path / "spot_check.json"
    status = main(["--stages", SAMPLE, "--episodes", "1", "--json", str(report_path)])
    out = capsys.readouterr().out
    report = _report(report_path)
    assert status == 0, out
    assert report["evaluation_stages"] == {"equal": 2, "differs": 0, "failed": 0}, out
    assert report["first_differing_stage"] is None and report["passed"]
    assert {c["stage"] for c in report["cells"]} == set(SAMPLE.split(","))
    assert all(c["rows"] == 1 and "evaluation.episodes=1" in c["command"] for c in report["cells"])
    assert report["cpu"]["model"] and report["numerics"] in ("native", "pinned") and report["commit"]
    assert "first stage that differs: none" in out


def _copy_root(tmp_path: Path) -> Path:
    """A results tree holding the committed dvc.lock and the one cell's committed episodes.csv."""
    root = tmp_path / "root"
    (root / CELL_EPISODES).parent.mkdir(parents=True)
    shutil.copy(ROOT / "dvc.lock", root / "dvc.lock")
    shutil.copy(ROOT / CELL_EPISODES, root / CELL_EPISODES)
    return root


def test_a_corrupted_committed_row_is_reported_with_its_stage(tmp_path, capsys):
    root = _copy_root(tmp_path)
    lines = (root / CELL_EPISODES).read_bytes().splitlines(keepends=True)  # csv's \r\n kept
    header = lines[0].rstrip(b"\r\n").split(b",")
    row = lines[1].rstrip(b"\r\n").split(b",")
    row[header.index(b"mean_vx")] = b"12345.0"
    lines[1] = b",".join(row) + lines[1][len(lines[1].rstrip(b"\r\n")):]
    (root / CELL_EPISODES).write_bytes(b"".join(lines))

    report_path = tmp_path / "spot_check.json"
    status = main(["--root", str(root), "--stages", CELL, "--episodes", "1", "--json", str(report_path)])
    out = capsys.readouterr().out
    report = _report(report_path)
    assert status == 1
    assert report["first_differing_stage"] == CELL and not report["passed"]
    (cell,) = report["cells"]
    assert cell["result"] == "differs" and cell["row"] == 1 and "mean_vx: committed 12345.0" in cell["detail"]
    assert f"first stage that differs: {CELL}" in out


def test_a_missing_committed_file_is_one_line(tmp_path, capsys):
    root = _copy_root(tmp_path)
    (root / CELL_EPISODES).unlink()
    status = main(["--root", str(root), "--stages", CELL, "--json", str(tmp_path / "r.json")])
    err = capsys.readouterr().err
    assert status == 2 and not (tmp_path / "r.json").exists()
    assert err.count("\n") == 1 and CELL_EPISODES in err and "committed file missing" in err, err


@pytest.mark.parametrize(("arguments", "named"), [
    (["--episodes", "0"], "--episodes=0"),
    (["--workers", "-1"], "--workers=-1"),
    (["--episodes", "many"], "many"),
    (["--stages", "evaluate@nothing/*"], "--stages evaluate@nothing/*"),
    (["--root", "/nonexistent/checkout"], "no dvc.lock"),
])
def test_bad_input_is_one_line_naming_it(arguments, named, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        raise SystemExit(main([*arguments, "--json", str(tmp_path / "r.json")]))
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and err.count("\n") == 1 and named in err and "Traceback" not in err, err


def test_training_rows_compare_without_their_wall_clock_columns():
    header = b"iteration,frames,wall_s,episode/return,env_steps_per_s\n"
    committed = [header, b"1.0,32768.0,1.31,-296.18,24986.0\n", b"2.0,65536.0,2.55,-426.90,26282.6\n"]
    same_but_slower = [header, b"1.0,32768.0,9.99,-296.18,1.0\n", b"2.0,65536.0,19.9,-426.90,2.0\n"]
    assert compare_metrics(committed, same_but_slower, 2).equal
    other = [header, b"1.0,32768.0,1.31,-296.18,24986.0\n", b"2.0,65536.0,2.55,-426.91,26282.6\n"]
    comparison = compare_metrics(committed, other, 2)
    assert not comparison.equal and comparison.row == 2
    assert comparison.detail == "episode/return: committed -426.90, recomputed -426.91"
    assert not compare_metrics(committed, committed[:2], 2).equal  # a run that stopped early
