"""README.md and docs/*.md say only what the repository holds.

- The README's headline table (between ``<!-- table:begin -->`` and ``<!-- table:end -->``) is
  generated from ``results/table.json`` (ours) and ``results/table.md`` (the paper's published values),
  never typed by hand. Refresh it with ``.venv/bin/python tests/test_docs.py``.
- Every relative link resolves to a file of the repository.
- Every command in a ```bash block parses: ``python -m srmpc`` overrides compose (every value of a
  ``-m`` sweep at least once), ``python <script>`` names a script that exists, ``make <target>`` a
  Makefile target, ``dvc repro <stage>`` a stage of ``dvc.yaml``.
- Every other number of the README's results and of docs/results.md: ``tests/test_numbers_traceable.py``.

The checkers are plain functions; the last tests feed them broken input to show that they fail.
"""

from __future__ import annotations

import difflib
import json
import re
import shlex
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
DOCS = [README, *sorted((ROOT / "docs").glob("*.md"))]
TABLE_BEGIN, TABLE_END = "<!-- table:begin -->", "<!-- table:end -->"
REFRESH = ".venv/bin/python tests/test_docs.py"

LABELS = {
    "ppo_lsi": "PPO-L-SI",
    "ltv_mpc": "LTV-MPC",
    "srmpc": "SRMPC (Algorithm 1)",
    "ppo": "PPO",
    "ppo_sb3": "PPO (Stable-Baselines3, same settings)",
    "lane_keeping": "Lane keeping (baseline)",
    "srmpc_recommended": "SRMPC, recommended (tracking the rollout, 1 m margin, fresh seeds)",
}
"""Row labels of the headline table by method key of ``results/table.json``; other keys show as themselves."""
PAPER_ROWS = ("PPO-L-SI", "LTV-MPC", "SRMPC")
"""The paper's rows, as ``results/table.md`` names them in its "Paper (published values)" tables."""


# ---------------------------------------------------------------------------------------------------
# the headline table


def _ci(value: float, ci: list[float], digits: int) -> str:
    return f"{value:.{digits}f} [{ci[0]:.{digits}f}, {ci[1]:.{digits}f}]"


def paper_values(table_md: str) -> dict[str, dict[str, tuple[str, str]]]:
    """{traffic: {algorithm: (J_c, v_x)}} from the "Paper (published values)" tables of results/table.md."""
    values: dict[str, dict[str, tuple[str, str]]] = {}
    for section in re.split(r"^### ", table_md, flags=re.MULTILINE)[1:]:
        traffic = section.split(maxsplit=1)[0]
        match = re.search(r"Paper \(published values\):\n\n(.*?)\n\n", section, flags=re.DOTALL)
        if not match:
            continue
        rows = {}
        for line in match.group(1).splitlines()[2:]:
            cells = [cell.strip() for cell in line.strip("|").split("|")]
            rows[cells[0]] = (cells[2], cells[5])  # Algorithm | J_r | J_c | rho_c | n_steps | v_x
        values[traffic] = rows
    return values


def headline_table(table: dict, table_md: str) -> str:
    """The README's headline table: J_c and v_x with 95% CIs per method and traffic level, then the paper's."""
    traffics = ("light", "dense")
    paper = paper_values(table_md)
    lines = [
        "| method | J_c light | v_x light [m/s] | J_c dense | v_x dense [m/s] |",
        "|---|---|---|---|---|",
    ]
    methods = list(dict.fromkeys(key for traffic in traffics for key in table[traffic]))
    for method in methods:
        cells = []
        for traffic in traffics:
            row = table[traffic].get(method)
            if row is None:
                cells += ["-", "-"]
                continue
            cells.append(_ci(row["mean_event_cost"], row["mean_event_cost_ci95"], 3))
            cells.append(_ci(row["mean_vx"], row["mean_vx_ci95"], 2))
        lines.append(f"| {LABELS.get(method, method)} | {' | '.join(cells)} |")
    for algorithm in PAPER_ROWS:
        cells = [value for traffic in traffics for value in paper[traffic][algorithm]]
        lines.append(f"| {algorithm} (paper) | {' | '.join(cells)} |")
    return "\n".join(lines)


def expected_table_block() -> str:
    table = json.loads((ROOT / "results" / "table.json").read_text())
    return headline_table(table, (ROOT / "results" / "table.md").read_text())


def readme_table_block(text: str) -> str:
    match = re.search(re.escape(TABLE_BEGIN) + r"\n(.*?)\n" + re.escape(TABLE_END), text, flags=re.DOTALL)
    assert match, f"README.md lacks the markers {TABLE_BEGIN} ... {TABLE_END} around the headline table"
    return match.group(1)


def refresh_readme() -> bool:
    """Rewrite the README's headline table from results/; True when it changed."""
    text = README.read_text()
    old = readme_table_block(text)
    new = expected_table_block()
    README.write_text(text.replace(f"{TABLE_BEGIN}\n{old}\n{TABLE_END}", f"{TABLE_BEGIN}\n{new}\n{TABLE_END}"))
    return old != new


# ---------------------------------------------------------------------------------------------------
# links


LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")


def broken_links(markdown: str, base: Path) -> list[str]:
    """Relative link targets of ``markdown`` (a file in ``base``) that name no existing file or folder."""
    markdown = re.sub(r"```.*?```", "", markdown, flags=re.DOTALL)
    broken = []
    for target in LINK.findall(markdown):
        if re.match(r"^[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
            continue  # http(s):, mailto:, an anchor on the same page
        path = target.split("#", 1)[0]
        if not (base / path).exists():
            broken.append(target)
    return broken


# ---------------------------------------------------------------------------------------------------
# commands


def bash_commands(markdown: str) -> list[str]:
    """Every command line of ``markdown``'s ```bash blocks: continuations joined, comments dropped."""
    commands = []
    for block in re.findall(r"```bash\n(.*?)```", markdown, flags=re.DOTALL):
        block = re.sub(r"\s*\\\n\s*", " ", block)
        for line in block.splitlines():
            command = re.split(r"(?:^|\s)#", line, maxsplit=1)[0].strip()
            if command:
                commands.append(command)
    return commands


SEPARATORS = {"&&", "||", ";", "|", "(", ")", "$(", "&"}


def simple_commands(command: str) -> list[list[str]]:
    """``command`` split at shell operators and ``$(...)`` into words, without leading ``VAR=`` / ``export``."""
    lexer = shlex.shlex(command, posix=True, punctuation_chars=";&|()")
    lexer.whitespace_split = True
    words: list[list[str]] = [[]]
    for token in lexer:
        if token in SEPARATORS or set(token) <= set(";&|()"):
            words.append([])
        else:
            words[-1].append(token)
    simple = []
    for part in words:
        while part and (part[0] in {"export", "env", "time"} or re.match(r"^[A-Za-z_]\w*=", part[0])):
            part = part[1:]
        if part:
            simple.append([word.rstrip("$") for word in part])
    return simple


def _makefile_targets() -> set[str]:
    text = (ROOT / "Makefile").read_text()
    return set(re.findall(r"^([A-Za-z][\w-]*)\s*:(?!=)", text, flags=re.MULTILINE))


def _dvc_stages() -> set[str]:
    return set(yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"])


def srmpc_override_sets(arguments: list[str]) -> list[list[str]]:
    """The override lists to compose for ``python -m srmpc <arguments>``: one for a run; for a ``-m``
    sweep, enough of its jobs that every swept value is composed at least once."""
    multirun = any(arg in {"-m", "--multirun"} for arg in arguments)
    overrides, skip = [], False
    for arg in arguments:
        if skip:
            skip = False
        elif arg in {"-m", "--multirun"}:
            continue
        elif arg in {"--cfg", "-c", "--package", "-p"}:
            skip = True
        elif arg.startswith("-"):
            raise ValueError(f"unknown flag {arg!r}")
        else:
            overrides.append(arg)
    if not multirun:
        return [overrides]
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
    from hydra.core.override_parser.overrides_parser import OverridesParser

    jobs = BasicSweeper.split_arguments(OverridesParser.create().parse_overrides(overrides), None)[0]
    chosen, covered = [], set()
    for job in jobs:  # greedy: a job that composes a value not composed yet
        if not set(job) <= covered:
            chosen.append(job)
            covered |= set(job)
    return chosen


def command_problems(command: str) -> list[str]:
    """What in ``command`` names something the repository lacks, or does not compose."""
    from srmpc.config.compose import ConfigError, compose_config

    problems = []
    for words in simple_commands(command):
        program, args = words[0], words[1:]
        if program in {"python", "python3", ".venv/bin/python"}:
            if args[:2] == ["-m", "srmpc"]:
                try:
                    override_sets = srmpc_override_sets(args[2:])
                except Exception as error:  # noqa: BLE001  (a sweep Hydra cannot parse)
                    problems.append(f"{' '.join(words)}: {error}")
                    continue
                for overrides in override_sets:
                    try:
                        compose_config(overrides)
                    except ConfigError as error:
                        problems.append(f"{' '.join(words)}: {error}")
            elif args[:1] == ["-m"]:
                continue  # another module (pytest, pip): nothing of ours to check
            elif args and not (ROOT / args[0]).is_file():
                problems.append(f"{' '.join(words)}: no script {args[0]}")
        elif program == "make":
            targets = [arg for arg in args if not arg.startswith("-") and "=" not in arg]
            problems += [f"{' '.join(words)}: no Makefile target {t!r}" for t in targets
                         if t not in _makefile_targets()]
        elif program == "dvc" and args[:1] == ["repro"]:
            stages = [arg.split("@", 1)[0] for arg in args[1:] if not arg.startswith("-")]
            problems += [f"{' '.join(words)}: no dvc.yaml stage {s!r}" for s in stages if s not in _dvc_stages()]
    return problems


# ---------------------------------------------------------------------------------------------------
# the tests


def test_readme_headline_table_is_results_table_json():
    shown = readme_table_block(README.read_text())
    expected = expected_table_block()
    diff = "\n".join(difflib.unified_diff(shown.splitlines(), expected.splitlines(), "README.md",
                                          "from results/table.json", lineterm=""))
    assert shown == expected, (
        f"README.md's headline table differs from results/table.json; run `{REFRESH}` to rewrite it.\n"
        f"{diff}\n\nExpected block:\n{TABLE_BEGIN}\n{expected}\n{TABLE_END}")


README_MAX_LINES = 200
README_MAX_PROSE_WIDTH = 120
"""The README's caps: lines, and characters per prose line (table rows and fenced code are not prose)."""


def prose_lines(text: str) -> list[tuple[int, str]]:
    """(line number, line) of ``text`` outside fenced code blocks and table rows."""
    lines, fenced = [], False
    for number, line in enumerate(text.splitlines(), start=1):
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced and not line.startswith("|"):
            lines.append((number, line))
    return lines


def test_readme_fits_in_200_lines_of_prose_at_most_120_wide():
    text = README.read_text()
    assert len(text.splitlines()) <= README_MAX_LINES
    wide = [f"line {n}: {len(line)} characters" for n, line in prose_lines(text) if len(line) > README_MAX_PROSE_WIDTH]
    assert not wide, f"README.md prose lines over {README_MAX_PROSE_WIDTH} characters: {wide}"


def test_prose_lines_skip_tables_and_fenced_code():
    text = "a\n| t | t |\n```\n" + "x" * 200 + "\n```\nb"
    assert prose_lines(text) == [(1, "a"), (6, "b")]


@pytest.mark.parametrize("path", DOCS, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_relative_links_resolve(path):
    broken = broken_links(path.read_text(), path.parent)
    assert not broken, f"{path.relative_to(ROOT)}: links to nothing: {', '.join(broken)}"


@pytest.mark.parametrize("path", DOCS, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_shown_commands_parse(path):
    problems = [problem for command in bash_commands(path.read_text()) for problem in command_problems(command)]
    assert not problems, f"{path.relative_to(ROOT)}, commands in ```bash blocks:\n" + "\n".join(problems)


def test_docs_have_no_issue_numbers():
    for path in DOCS:
        found = re.findall(r"[Ii]ssue \d+|#\d{1,3}\b", path.read_text())
        assert found == [], f"{path.relative_to(ROOT)}: {found}"


def test_the_checkers_catch_broken_input(tmp_path):
    (tmp_path / "there.md").write_text("x")
    page = "[ok](there.md#a) [web](https://example.org) [gone](missing.md) ![fig](nope.png)\n```bash\n[x](y)\n```"
    assert broken_links(page, tmp_path) == ["missing.md", "nope.png"]
    srmpc = ".venv/bin/python -m srmpc"
    says = {  # each broken command: one problem, naming the command and what it names that is not there
        ".venv/bin/python pipelines/no_such_script.py --x": "no script pipelines/no_such_script.py",
        "make no-such-target": "no Makefile target 'no-such-target'",
        "dvc repro no_such_stage": "no dvc.yaml stage 'no_such_stage'",
        f"{srmpc} +experiment=no_such_experiment": "no option 'no_such_experiment' in group 'experiment'",
        f"{srmpc} -m planner=ltv_mpc,no_such_planner": "no option 'no_such_planner' in group 'planner'",
        f"{srmpc} evaluation.episodes=0": "evaluation.episodes=0: must be an integer >= 1",
    }
    for command, problem in says.items():
        (found,) = command_problems(command)
        assert found.startswith(f"{command}: ") and problem in found, (command, found)
    assert not command_problems("export X=$(.venv/bin/python -m srmpc --cfg job) && make test FORCE=1")


def test_the_table_generator_follows_table_json():
    """One number of table.json changed: the table changes in that cell only (SRMPC's row, J_c light)."""
    table = json.loads((ROOT / "results" / "table.json").read_text())
    table["light"]["srmpc"]["mean_event_cost"] = 0.5
    before = expected_table_block().splitlines()
    after = headline_table(table, (ROOT / "results" / "table.md").read_text()).splitlines()
    changed = [i for i, (old, new) in enumerate(zip(before, after, strict=True)) if old != new]
    assert len(changed) == 1 and before[changed[0]].startswith(f"| {LABELS['srmpc']} |"), changed
    old_cells, new_cells = (line.strip("|").split("|") for line in (before[changed[0]], after[changed[0]]))
    assert new_cells[1].strip() == _ci(0.5, table["light"]["srmpc"]["mean_event_cost_ci95"], 3)  # J_c light
    assert new_cells[:1] + new_cells[2:] == old_cells[:1] + old_cells[2:]


def test_bash_blocks_split_into_commands():
    page = "```bash\nmake a \\\n  FORCE=1   # comment\n\n# only a comment\nX=1 make b && make c\n```\n"
    assert bash_commands(page) == ["make a FORCE=1", "X=1 make b && make c"]
    assert simple_commands("X=1 make b && make c") == [["make", "b"], ["make", "c"]]
    words = [["python", "s.py", "start", "--name", "a b"]]
    assert simple_commands("export P=$(python s.py start --name 'a b')") == words
    sweep = srmpc_override_sets(["-m", "scenario=light,dense", "planner=ltv_mpc,margin_1m,margin_2m", "--cfg", "job"])
    assert {o for job in sweep for o in job} >= {"scenario=light", "scenario=dense", "planner=margin_2m"}
    assert len(sweep) < 6


if __name__ == "__main__":
    changed = refresh_readme()
    print("README.md: headline table " + ("rewritten from results/table.json" if changed else "already current"))
    sys.exit(0)
