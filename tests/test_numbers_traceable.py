"""Every number printed in the README's results and in docs/results.md comes from a file under results/.

The prose read is README.md's "## Results" and "## The two commands" sections (up to "## Running one
experiment"), without the headline table between ``<!-- table:begin -->`` and ``<!-- table:end -->``
(``tests/test_docs.py`` checks that one against ``results/table.json``), all of docs/results.md, its tables
included, and the "## Timings" section of docs/pipeline.md (the whole pipeline's measured run). Fenced code blocks,
inline code spans and link targets are not prose; a link's text is.

The prose is cut into units: a table row, or one sentence of a paragraph or bullet. ``TRACED`` holds one
entry per unit that prints a number: a fragment of the text that finds the unit (it must find exactly one),
the result file, the keys whose values the unit prints, in the order it prints them, and the definitions:
fragments of the unit whose numbers are settings or conventions (``1000 episodes``, ``95%``, ``w_v 2``),
not results. A key is a dotted path into the JSON: dict keys, list indices, or a selector ``[a.b=v,c=w]``
that picks the one list element whose field ``a.b`` is v and ``c`` is w (a trade-off point by its
settings, not by its place in a list sorted by speed). ``file.json:path`` names another file under
results/ than the entry's. Then come ``|``-separated transforms, applied left to right:

    percent  x -> 100 x        cut  x -> 1 - x        negate  x -> -x        inv  x -> 1 / x
    minutes  x -> x / 60       hours  x -> x / 3600   (seconds printed in minutes or hours)

A printed number p with d decimals matches the value v when ``f"{v:.{d}f}"`` equals p (``−`` and ``-``
are minus, ``+`` no sign, ``-0.000`` is ``0.000``). Tokens: ``1-8 m`` and ``96-97%`` are two numbers,
``[−0.18, +0.07]`` two signed numbers, ``x0.05`` and ``1.9x`` plain numbers, ``1/57`` the one number 57
(trace it with ``inv``), ``4.2e-6`` one number, ``1,000`` one thousand; digits inside a word
(``AC4MPC``, ``Stable-Baselines3``) are a name, not a number.

The test fails, one line each, when a fragment finds no unit or more than one, when a unit prints more
or fewer numbers than its entry has keys, when a printed number differs from its key's value at the
printed precision, and when a number stands in no traced unit. A regeneration that moves a number thus
fails here until the text follows it.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
README = "README.md"
RESULTS_DOC = "docs/results.md"
PIPELINE_DOC = "docs/pipeline.md"

# ---------------------------------------------------------------------------------------------------
# the prose


def readme_results_prose(text: str) -> str:
    """README.md from "## Results" up to "## Running one experiment", without the generated headline table."""
    match = re.search(r"^## Results\n(.*?)^## Running one experiment", text, flags=re.MULTILINE | re.DOTALL)
    assert match, "README.md: no '## Results' section ending at '## Running one experiment'"
    return re.sub(r"<!-- table:begin -->.*?<!-- table:end -->", "", match.group(1), flags=re.DOTALL)


def pipeline_timings_prose(text: str) -> str:
    """docs/pipeline.md's "## Timings" section, up to the next section."""
    match = re.search(r"^## Timings\n(.*?)(?=^## )", text, flags=re.MULTILINE | re.DOTALL)
    assert match, "docs/pipeline.md: no '## Timings' section followed by another section"
    return match.group(1)


def plain(markdown: str) -> str:
    """``markdown`` without fenced code, inline code, link targets, images' targets and HTML comments."""
    markdown = re.sub(r"```.*?```", "", markdown, flags=re.DOTALL)
    markdown = re.sub(r"<!--.*?-->", "", markdown, flags=re.DOTALL)
    markdown = re.sub(r"`[^`\n]*`", "", markdown)
    return re.sub(r"(!?\[[^\]]*\])\([^)\s]*\)", r"\1", markdown)


ABBREVIATIONS = ("e.g.", "i.e.", "vs.", "Fig.", "cf.", "et al.")
SENTENCE_END = re.compile(r"[.!?](?=\s+[A-Z(*\[])")


def split_sentences(paragraph: str) -> list[str]:
    """``paragraph`` cut after each ``.``, ``!`` or ``?`` that a capital, ``(``, ``*`` or ``[`` follows."""
    sentences, start = [], 0
    for match in SENTENCE_END.finditer(paragraph):
        head = paragraph[start:match.end()]
        if any(head.endswith(abbreviation) for abbreviation in ABBREVIATIONS):
            continue
        sentences.append(head.strip())
        start = match.end()
    sentences.append(paragraph[start:].strip())
    return [sentence for sentence in sentences if sentence]


def units(markdown: str) -> list[str]:
    """The prose units of ``markdown``: each table row, and each sentence of each paragraph or bullet."""
    found: list[str] = []
    block: list[str] = []

    def close() -> None:
        if block:
            found.extend(split_sentences(" ".join(line.strip() for line in block)))
            block.clear()

    for line in plain(markdown).splitlines():
        stripped = line.strip()
        if not stripped or stripped.startswith("#"):
            close()
            if stripped:
                found.append(stripped)
        elif stripped.startswith("|"):
            close()
            found.append(stripped)
        elif re.match(r"^([-*]|\d+\.)\s", stripped):
            close()
            block.append(stripped)
        else:
            block.append(stripped)
    close()
    return found


# ---------------------------------------------------------------------------------------------------
# the numbers


@dataclass(frozen=True)
class Number:
    """One printed number: its text as printed, where it starts and ends, and how it reads."""

    text: str
    start: int
    end: int
    digits: str
    """The number without sign, thousands separators or ``%``: ``"0.058"``, ``"57"`` for ``1/57``."""
    negative: bool

    @property
    def decimals(self) -> int:
        mantissa = self.digits.split("e")[0]
        return len(mantissa.split(".")[1]) if "." in mantissa else 0

    @property
    def normalized(self) -> str:
        """The printed value as ``f"{value:.{decimals}f}"`` (or ``e``) writes it, ``-0.00`` read as ``0.00``."""
        text = ("-" if self.negative else "") + self.digits
        return _unsigned_zero(_canonical_exponent(text))


CANDIDATE = re.compile(r"\d{1,3}(?:,\d{3})+(?![\d,])|\d+(?:\.\d+)?(?:e[-−+]?\d+)?")
SIGNS = {"-": True, "−": True, "+": False}
SIGN_CONTEXT = set(" \t\n([{,;:/~=")


def numbers(text: str) -> list[Number]:
    """The numbers printed in ``text`` (see the module docstring for how each form reads)."""
    found: list[Number] = []
    position = 0
    while (match := CANDIDATE.search(text, position)) is not None:
        start, end = match.span()
        position = end
        before = text[start - 1] if start else ""
        if before == "/" and found and found[-1].end == start - 1 and found[-1].text == "1":
            fraction = found.pop()  # "1/57": the one number 57, read as 1/57
            found.append(Number(text[fraction.start:end], fraction.start, end, match.group(), False))
            continue
        if (before.isalpha() or before == "_") and not _is_multiplier_prefix(text, start):
            continue  # a digit inside a name: AC4MPC, Stable-Baselines3, H200
        if before == "." and start >= 2 and text[start - 2].isdigit():
            continue  # the third part of a version: 3.11.7
        negative, first = False, start
        if before in SIGNS and (start < 2 or text[start - 2] in SIGN_CONTEXT):
            negative, first = SIGNS[before], start - 1
        elif _is_multiplier_prefix(text, start):
            first = start - 1
        last = end + 1 if text[end:end + 1] == "%" else end
        digits = match.group().replace(",", "").replace("−", "-")
        found.append(Number(text[first:last], first, last, digits, negative))
    return found


def _is_multiplier_prefix(text: str, start: int) -> bool:
    """``x0.05``: an ``x`` right before the digits, itself not inside a word."""
    return start >= 1 and text[start - 1] == "x" and (start < 2 or not (text[start - 2].isalnum()
                                                                         or text[start - 2] == "_"))


def _canonical_exponent(text: str) -> str:
    """``4.2e-06`` and ``4.2e-6`` alike: the exponent without leading zeros or ``+``."""
    if "e" not in text:
        return text
    mantissa, exponent = text.split("e")
    return f"{mantissa}e{int(exponent)}"


def _unsigned_zero(text: str) -> str:
    return text[1:] if text.startswith("-") and not re.search(r"[1-9]", text.split("e")[0]) else text


# ---------------------------------------------------------------------------------------------------
# the keys


TRANSFORMS: dict[str, Callable[[float], float]] = {
    "percent": lambda x: 100.0 * x,
    "cut": lambda x: 1.0 - x,
    "negate": lambda x: -x,
    "inv": lambda x: 1.0 / x,
    "minutes": lambda x: x / 60.0,
    "hours": lambda x: x / 3600.0,
}


@cache
def load(name: str) -> dict:
    """``results/<name>`` parsed."""
    return json.loads((RESULTS / name).read_text())


PATH_PART = re.compile(r"\[[^\]]*\]|[^.\[\]]+")


def walk(node: object, path: str) -> object:
    """The node at dotted ``path``: a dict key, a list index, or ``[a.b=v,c=w]``, the one list element whose
    ``a.b`` is v and ``c`` is w (numbers compared as numbers)."""
    for part in PATH_PART.findall(path):
        if part.startswith("["):
            conditions = [condition.split("=", 1) for condition in part[1:-1].split(",")]
            if not isinstance(node, list):
                raise KeyError(f"{part} selects from a {type(node).__name__}, not a list")
            matches = [item for item in node if all(_equal(_get(item, field), value) for field, value in conditions)]
            if len(matches) != 1:
                raise KeyError(f"{part} selects {len(matches)} elements, not 1")
            node = matches[0]
        elif isinstance(node, list) and part.isdigit() and int(part) < len(node):
            node = node[int(part)]
        elif isinstance(node, dict) and part in node:
            node = node[part]
        else:
            raise KeyError(f"no {part!r}")
    return node


def _get(node: object, path: str) -> object:
    try:
        return walk(node, path)
    except KeyError:
        return None


def _equal(found: object, wanted: str) -> bool:
    if isinstance(found, (int, float)) and not isinstance(found, bool):
        try:
            return float(found) == float(wanted)
        except ValueError:
            return False
    return str(found) == wanted


def resolve(key: str, default_file: str, loader: Callable[[str], dict] = load) -> tuple[str, float]:
    """(``file:path|transforms`` as written, the value it names after its transforms)."""
    spec, *transforms = [part.strip() for part in key.split("|")]
    name, path = spec.split(":", 1) if ":" in spec else (default_file, spec)
    try:
        node = walk(loader(name), path)
    except KeyError as error:
        raise KeyError(f"{name}:{path}: {error.args[0]}") from None
    if isinstance(node, bool) or not isinstance(node, (int, float)):
        raise KeyError(f"{name}:{path} is {node!r}, not a number")
    value = float(node)
    for transform in transforms:
        if transform not in TRANSFORMS:
            raise KeyError(f"{name}:{path}: no transform {transform!r} (known: {', '.join(TRANSFORMS)})")
        value = TRANSFORMS[transform](value)
    return f"{name}:{path}" + "".join(f"|{t}" for t in transforms), value


def rendered(value: float, number: Number) -> str:
    """``value`` at the precision ``number`` is printed with, as ``Number.normalized`` writes it."""
    if "e" in number.digits:
        return _unsigned_zero(_canonical_exponent(f"{value:.{number.decimals}e}"))
    return _unsigned_zero(f"{value:.{number.decimals}f}")


def matches(value: float, number: Number) -> bool:
    """``number`` is ``value`` rounded to its printed precision; at an exact tie (0.475 to two decimals, which
    binary floating point stores just below or above) either neighbour counts."""
    nudge = abs(value) * 1e-12 + 1e-15
    return number.normalized in {rendered(value, number), rendered(value + nudge, number),
                                 rendered(value - nudge, number)}


# ---------------------------------------------------------------------------------------------------
# the map: one entry per unit that prints a number


@dataclass(frozen=True)
class Traced:
    """A unit of ``doc`` found by ``fragment``: its numbers, in order, are ``keys`` of ``file`` (under
    results/), except those inside one of the ``definitions`` fragments."""

    doc: str
    fragment: str
    file: str | None = None
    keys: tuple[str, ...] = ()
    definitions: tuple[str, ...] = ()


def _ci(path: str, *transforms: str) -> tuple[str, str, str]:
    """A value and its 95% CI as printed ``x [low, high]``: ``path``, ``path_ci95.0``, ``path_ci95.1``."""
    suffix = "".join(f"|{t}" for t in transforms)
    return f"{path}{suffix}", f"{path}_ci95.0{suffix}", f"{path}_ci95.1{suffix}"


def _ratio_ci(path: str) -> tuple[str, str, str]:
    """A paired ratio and its 95% CI (``confidence_intervals.paired_ratios``) as printed ``r [low, high]``."""
    return f"{path}.ratio", f"{path}.ratio_ci95.0", f"{path}.ratio_ci95.1"


TABLE_PLANNER = (8.0, 0.5, 1.0)
"""(safety margin [m], speed weight w_v, slack price scale) of the table's planner (conf/planner/ltv_mpc.yaml)."""
MARGINS = ((8.0, 0.5, 1.0), (4.0, 0.5, 1.0), (2.0, 0.5, 1.0), (1.0, 0.5, 1.0), (1.0, 2.0, 1.0))
"""The trade-off grid at the default slack prices, as docs/results.md's table orders it: 8, 4, 2, 1 m, 1 m w_v 2."""
OPERATING_POINT = "paper_operating_point"
SLACK_X005 = (1.0, 10.0, 0.05)
"""``planner=paper_operating_point``: 1 m, w_v 10, the slack prices x0.05."""


def _settings(setting: tuple[float, float, float], prefix: str = "settings") -> str:
    margin, speed_weight, slack = setting
    return (f"{prefix}.safety_margin_longitudinal_m={margin:g},{prefix}.speed_weight={speed_weight:g},"
            f"{prefix}.slack_price_scale={slack:g}")


def _point(traffic: str, curve: str, setting: tuple[float, float, float]) -> str:
    """The point of ``curve`` at ``setting`` in results/tradeoff.json."""
    return f"{traffic}.{curve}[{_settings(setting)}]"


def _pair(traffic: str, ltv: tuple[float, float, float], curve: str, setting: tuple[float, float, float]) -> str:
    """SRMPC ``curve`` at ``setting`` against LTV-MPC at ``ltv`` in results/tradeoff.json's dominance verdicts."""
    return (f"{traffic}.dominance[{_settings(ltv, 'ltv_mpc.settings')}]"
            f".srmpc_points[method={curve},{_settings(setting)}]")


PIPELINE = "benchmarks/pipeline.json"


def _group(group: str) -> tuple[str, str, str]:
    """A stage group's row of docs/pipeline.md: its stages, wall time [min] and share of the core-seconds [%]."""
    path = f"groups[group={group}]"
    return f"{path}.stages", f"{path}.wall_s|minutes", f"{path}.share_of_core_s|percent"


def _nmpc(traffic: str, path: str, planner: str = "ltv_mpc") -> str:
    """``path`` under results/nmpc.json's cell at ``planner`` (``ltv_mpc``: the table's; ``paper_operating_point``)."""
    return f"{planner}.{traffic}.{path}"


TRACED: tuple[Traced, ...] = (
    # README.md, "## Results"
    Traced(README, "1000 episodes per cell on the twin", definitions=("1000 episodes", "95% CIs")),
    Traced(README, "run seed 0's PPO-L-SI policy", definitions=("seed 0's",)),
    Traced(README, "The recommended SRMPC runs", definitions=("1000 fresh episodes", "seeds 100000 + i")),
    Traced(README, "**SRMPC has the lowest J_c", definitions=("seed 0's", "below 0")),
    Traced(README, "**Light: J_c and ρ_c more than", "table.json",
           ("light.srmpc.paired_ratios.ltv_mpc.mean_event_cost.ratio|cut|percent",
            "light.srmpc.paired_ratios.ppo_lsi.mean_event_cost.ratio|cut|percent"),
           ("30% below", "65% below")),
    Traced(README, "It beats LTV-MPC on both, but drives", "table.json",
           ("light.srmpc.paired_differences.ppo_lsi.mean_vx|negate",)),
    Traced(README, "It holds for seed 0's: the speeds", definitions=("seed 0's", "includes 0")),
    Traced(README, "It does not for seed 1's and 2's", "per_policy.json",
           (*_ci("dense.policies.1.srmpc_minus.ltv_mpc.mean_vx"), *_ci("dense.policies.2.srmpc_minus.ltv_mpc.mean_vx")),
           ("seed 1's and 2's",)),
    Traced(README, "**Training: PPO-L-SI ends with", "training/summary.json",
           (*_ci("paper_claim.cost_rate_ratio_lsi_over_ppo"), "paper_claim_vs_ppo_sb3.cost_rate_ratio_lsi_over_ppo")),
    Traced(README, "**At the paper's operating point**", definitions=("seeds 200000 + i",)),
    Traced(README, "rule written after the probes were seen", "operating_point.json",
           (*_ci("light.ltv_mpc.mean_event_cost"), "light.ltv_mpc.mean_vx",
            *_ci("declared_rule_probe.light.ltv_mpc.mean_event_cost"), "declared_rule_probe.light.ltv_mpc.mean_vx",
            "light.ltv_mpc.calibration_band.mean_event_cost.target",
            "light.ltv_mpc.calibration_band.mean_event_cost.half_width", "light.ltv_mpc.paper.mean_vx"),
           ("x0.05", "w_v 10", "1 m;", "x0.01", "w_v 2, 1 m")),
    Traced(README, "At the frozen one SRMPC cuts J_c", "operating_point.json",
           ("light.srmpc.paired_ratios.ltv_mpc.mean_event_cost.ratio|cut|percent",
            "dense.srmpc.paired_ratios.ltv_mpc.mean_event_cost.ratio|cut|percent",
            "tradeoff.json:light.paper_operating_point.paper_reduction|percent",
            "tradeoff.json:dense.paper_operating_point.paper_reduction|percent",
            *_ci("light.srmpc.paired_differences.ppo_lsi.mean_event_cost"),
            "declared_rule_probe.light.srmpc.paired_ratios.ltv_mpc.mean_event_cost.ratio|cut|percent",
            "declared_rule_probe.dense.srmpc.paired_ratios.ltv_mpc.mean_event_cost.ratio|cut|percent")),
    Traced(README, "**Future work: an RSS safety index**", "rss.json",
           (*_ci("training_claim.cost_rate_ratio_rss_over_ppo"),
            "evaluation.light.ppo_lsi/ppo_lsi_rss.mean_event_cost",
            "evaluation.dense.ppo_lsi/ppo_lsi_rss.mean_event_cost",
            "evaluation.light.ppo_lsi/ppo_lsi.mean_event_cost", "evaluation.dense.ppo_lsi/ppo_lsi.mean_event_cost",
            "evaluation.light.ppo_lsi/ppo_lsi_rss.minus_ppo_lsi.mean_vx|negate",
            "evaluation.dense.ppo_lsi/ppo_lsi_rss.minus_ppo_lsi.mean_vx|negate")),
    Traced(README, "**Future work: NMPC from the rollout**", "nmpc.json",
           ("initial_guess_study.per_guess.policy_rollout.iterations_median",
            "initial_guess_study.per_guess.constant_velocity.iterations_median",
            "initial_guess_study.per_guess.shifted_previous.iterations_median",
            "initial_guess_study.per_guess.policy_rollout.time_median_ms",
            "initial_guess_study.per_guess.policy_rollout.states_at_lowest_optimum",
            "initial_guess_study.per_guess.policy_rollout.states",
            "initial_guess_study.kkt_certification_by_ipopt.all_guesses.certified",
            "initial_guess_study.kkt_certification_by_ipopt.all_guesses.converged_plans"),
           ("target 1 ms",)),
    Traced(README, "In closed loop at the table's planner", "nmpc.json",
           (_nmpc("light", "nmpc_rollout.mean_event_cost"),
            _nmpc("dense", "nmpc_rollout.mean_event_cost"),
            _nmpc("light", "ltv_mpc.mean_event_cost"),
            _nmpc("dense", "ltv_mpc.mean_event_cost"),
            _nmpc("light", "nmpc_rollout.paired.srmpc.mean_vx"),
            _nmpc("dense", "nmpc_rollout.paired.srmpc.mean_vx"),
            _nmpc("dense", "nmpc_rollout.paired.srmpc.mean_event_cost"),
            _nmpc("light", "nmpc_rollout.paired.srmpc.mean_event_cost", OPERATING_POINT),
            _nmpc("dense", "nmpc_rollout.paired.srmpc.mean_event_cost", OPERATING_POINT))),
    Traced(README, "**Beyond the paper**", definitions=("margins 1-8 m", "dense 1 m, w_v 2", "slack x0.05")),
    Traced(README, "The recommended setting", "tradeoff.json",
           ("light.confirmation.paired_differences.ppo_lsi.mean_vx|negate",
            *_ratio_ci("light.confirmation.paired_ratios.ppo_lsi.mean_event_cost"),
            *_ratio_ci("dense.confirmation.paired_ratios.ppo_lsi.mean_event_cost"))),
    # docs/results.md
    Traced(RESULTS_DOC, "the paper's table, ours (", definitions=("1000 episodes", "95% CIs")),
    Traced(RESULTS_DOC, "at the longitudinal safety margins", definitions=(
        "every point but 8 m", "the 8 m points", "Algorithm 1", "margins 1, 2, 4 and 8 m", "at 1 m with",
        "at 2 instead of 0.5", "w_v 2")),
    Traced(RESULTS_DOC, "Each point is 1000 episodes", definitions=("1000 episodes",)),
    Traced(RESULTS_DOC, "| | 8 m | 4 m |", definitions=("8 m", "4 m", "2 m", "1 m |", "1 m, w_v 2")),
    *(Traced(RESULTS_DOC, f"| {traffic}: {label} |", "tradeoff.json",
             tuple(f"{_point(traffic, method, setting)}.{metric}" for setting in MARGINS
                   for metric in ("mean_event_cost", "mean_vx")),
             ("Algorithm 1",) if method == "srmpc" else ())
      for traffic in ("light", "dense")
      for method, label in (("ltv_mpc", "LTV-MPC"), ("srmpc", "SRMPC (Algorithm 1)"),
                            ("srmpc_track_rollout", "SRMPC, tracking the rollout"))),
    Traced(RESULTS_DOC, "PPO-L-SI: ", "tradeoff.json",
           ("light.ppo_lsi.0.mean_event_cost", "light.ppo_lsi.0.mean_vx", "dense.ppo_lsi.0.mean_event_cost",
            "dense.ppo_lsi.0.mean_vx")),
    Traced(RESULTS_DOC, "The paper's SRMPC: ", "operating_point.json",
           ("light.srmpc.paper.mean_event_cost", "light.srmpc.paper.mean_vx", "dense.srmpc.paper.mean_event_cost",
            "dense.srmpc.paper.mean_vx")),
    Traced(RESULTS_DOC, "**Dominance.**", "tradeoff.json",
           _ci(f"{_pair('dense', MARGINS[4], 'srmpc_track_rollout', SLACK_X005)}.paired_difference.mean_vx"),
           ("95% CIs", "dense 1 m, w_v 2", "slack x0.05")),
    Traced(RESULTS_DOC, "dominates LTV-MPC at every grid point but", "tradeoff.json",
           (f"{_pair('dense', TABLE_PLANNER, 'srmpc', TABLE_PLANNER)}.paired_difference.mean_vx|negate",
            f"{_pair('dense', TABLE_PLANNER, 'srmpc', TABLE_PLANNER)}.paired_difference.mean_vx_ci95.0",
            f"{_pair('dense', TABLE_PLANNER, 'srmpc', TABLE_PLANNER)}.paired_difference.mean_vx_ci95.1",
            *_ci(f"{_pair('dense', MARGINS[3], 'srmpc', MARGINS[3])}.paired_difference.mean_vx"),
            *_ci(f"{_pair('dense', MARGINS[4], 'srmpc', MARGINS[4])}.paired_difference.mean_vx")),
           ("Algorithm 1", "at 8 m", "at 1 m and at 1 m, w_v 2")),
    Traced(RESULTS_DOC, "Shrinking the margin from 8 m to 1 m", "tradeoff.json",
           tuple(f"{_point(traffic, 'ltv_mpc', MARGINS[3])}.versus_table_planner.{metric}"
                 for metric in ("mean_vx_difference", "mean_event_cost_ratio") for traffic in ("light", "dense")),
           ("from 8 m to 1 m",)),
    Traced(RESULTS_DOC, "gains 1.9 m/s in light traffic", "tradeoff.json",
           tuple(key for traffic in ("light", "dense") for key in (
               f"{_point(traffic, 'srmpc', MARGINS[3])}.versus_table_planner.mean_vx_difference",
               f"{_point(traffic, 'srmpc', TABLE_PLANNER)}.mean_event_cost",
               f"{_point(traffic, 'srmpc', MARGINS[3])}.mean_event_cost"))
           + (f"{_point('dense', 'ltv_mpc', MARGINS[3])}.mean_event_cost",),
           ("Algorithm 1", "at 8 m", "at 1 m")),
    Traced(RESULTS_DOC, "Tracking the rollout gains", "tradeoff.json",
           tuple(f"{_point(traffic, 'srmpc_track_rollout', setting)}.{metric}"
                 for setting, metric in ((MARGINS[3], "versus_table_planner.mean_vx_difference"),
                                         (TABLE_PLANNER, "mean_event_cost"), (MARGINS[3], "mean_event_cost"))
                 for traffic in ("light", "dense"))),
    Traced(RESULTS_DOC, "**Why SRMPC is slower than its policy.**", "table.json",
           ("light.srmpc.paired_differences.ppo_lsi.mean_vx|negate",
            "dense.srmpc.paired_differences.ppo_lsi.mean_vx|negate"),
           ("Algorithm 1",)),
    Traced(RESULTS_DOC, "safety region", "tradeoff.json",
           tuple(f"{_point(traffic, method, MARGINS[1])}.{metric}"
                 for method, metric in (("srmpc", "versus_table_planner.mean_vx_difference"),
                                        ("srmpc", "mean_event_cost"), ("ltv_mpc", "mean_event_cost"))
                 for traffic in ("light", "dense")),
           ("A 4 m",)),
    Traced(RESULTS_DOC, "**At PPO-L-SI's speed.**", "tradeoff.json",
           ("dense.at_policy_speed.srmpc_track_rollout.mean_event_cost", "dense.ppo_lsi.0.mean_event_cost")),
    Traced(RESULTS_DOC, "In light traffic no SRMPC point", "tradeoff.json",
           ("light.at_policy_speed.srmpc_track_rollout.settings.slack_price_scale",
            "light.at_policy_speed.srmpc_track_rollout.mean_vx",
            "light.at_policy_speed.srmpc_track_rollout.mean_event_cost", "light.ppo_lsi.0.mean_vx")),
    Traced(RESULTS_DOC, "**At the default slack prices the paper's operating point", "tradeoff.json",
           (f"{_point('light', 'ltv_mpc', MARGINS[4])}.mean_vx", f"{_point('dense', 'ltv_mpc', MARGINS[4])}.mean_vx",
            "light.paper_operating_point.paper_ltv_mpc_vx", "dense.paper_operating_point.paper_ltv_mpc_vx"),
           ("(1 m, w_v 2)",)),
    Traced(RESULTS_DOC, "There, SRMPC cuts J_c by", "tradeoff.json",
           (f"{_pair('light', MARGINS[4], 'srmpc', MARGINS[4])}.paired_ratios.mean_event_cost.ratio|cut|percent",
            f"{_pair('dense', MARGINS[4], 'srmpc', MARGINS[4])}.paired_ratios.mean_event_cost.ratio|cut|percent",
            "light.paper_operating_point.paper_reduction|percent",
            "dense.paper_operating_point.paper_reduction|percent",
            f"{_pair('light', MARGINS[4], 'srmpc', MARGINS[4])}.paired_difference.mean_event_cost",
            f"{_pair('dense', MARGINS[4], 'srmpc', MARGINS[4])}.paired_difference.mean_event_cost")),
    Traced(RESULTS_DOC, "chosen on the sweep and confirmed on", definitions=("1000 fresh", "seed 100000 + i")),
    *(Traced(RESULTS_DOC, f"| {traffic}: J_c / v_x |", "tradeoff.json",
             (*_ci(f"{traffic}.confirmation.srmpc_recommended.mean_event_cost"),
              f"{traffic}.confirmation.srmpc_recommended.mean_vx",
              *(f"{traffic}.confirmation.{method}.{metric}" for method in ("ppo_lsi", "ltv_mpc_margin_1m")
                for metric in ("mean_event_cost", "mean_vx"))))
      for traffic in ("light", "dense")),
    Traced(RESULTS_DOC, "- light traffic: ", "tradeoff.json",
           (*_ratio_ci("light.confirmation.paired_ratios.ppo_lsi.mean_event_cost"),
            "light.confirmation.paired_ratios.ppo_lsi.mean_event_cost.ratio_ci95.1|inv",
            "light.confirmation.paired_differences.ppo_lsi.mean_vx|negate",
            "light.confirmation.paired_differences.ppo_lsi.mean_vx_ci95.0",
            "light.confirmation.paired_differences.ppo_lsi.mean_vx_ci95.1"),
           ("1000 episodes",)),
    Traced(RESULTS_DOC, "- dense traffic: ", "tradeoff.json",
           (*_ratio_ci("dense.confirmation.paired_ratios.ppo_lsi.mean_event_cost"),
            "dense.confirmation.paired_ratios.ppo_lsi.mean_event_cost.ratio|inv",
            "dense.confirmation.paired_ratios.ppo_lsi.mean_event_cost.ratio_ci95.1|inv",
            "dense.confirmation.paired_differences.ppo_lsi.mean_vx|negate",
            "dense.confirmation.paired_differences.ppo_lsi.mean_vx_ci95.0",
            "dense.confirmation.paired_differences.ppo_lsi.mean_vx_ci95.1",
            "dense.confirmation.target.min_vx")),
    Traced(RESULTS_DOC, "The stretch goal", "tradeoff.json",
           ("light.confirmation.stretch.min_vx", "dense.confirmation.stretch.min_vx")),
    Traced(RESULTS_DOC, "compares the variants of", definitions=("1000 episodes",)),
    Traced(RESULTS_DOC, "runs the NMPC from each of four initial guesses", definitions=("1000 episodes",)),
    Traced(RESULTS_DOC, "- At the table's planner, NMPC from", "nmpc.json",
           (*_ci(_nmpc("light", "nmpc_rollout.mean_event_cost")),
            *_ci(_nmpc("dense", "nmpc_rollout.mean_event_cost")),
            _nmpc("light", "nmpc_rollout.mean_vx"),
            _nmpc("dense", "nmpc_rollout.mean_vx"),
            _nmpc("light", "ltv_mpc.mean_event_cost"),
            _nmpc("dense", "ltv_mpc.mean_event_cost"),
            *_ci(_nmpc("light", "nmpc_rollout.paired.srmpc.mean_vx")),
            *_ci(_nmpc("dense", "nmpc_rollout.paired.srmpc.mean_vx")),
            *_ci(_nmpc("light", "nmpc_rollout.paired.srmpc.mean_event_cost")),
            *_ci(_nmpc("dense", "nmpc_rollout.paired.srmpc.mean_event_cost")))),
    Traced(RESULTS_DOC, "Best of two (AC4MPC", "nmpc.json",
           (_nmpc("light", "nmpc_best_of_two.mean_event_cost"),
            _nmpc("dense", "nmpc_best_of_two.mean_event_cost"),
            _nmpc("light", "nmpc_best_of_two.mean_vx"),
            _nmpc("dense", "nmpc_best_of_two.mean_vx"),
            _nmpc("light", "nmpc_best_of_two.paired.nmpc_rollout.mean_vx|negate"),
            _nmpc("dense", "nmpc_best_of_two.paired.nmpc_rollout.mean_vx|negate"))),
    Traced(RESULTS_DOC, "- Solving to convergence about LTV-MPC's own guess", "nmpc.json",
           (_nmpc("light", "nmpc.paired.ltv_mpc.mean_event_cost"),
            _nmpc("dense", "nmpc.paired.ltv_mpc.mean_event_cost"),
            _nmpc("light", "nmpc.paired.ltv_mpc.mean_vx"),
            _nmpc("dense", "nmpc.paired.ltv_mpc.mean_vx"))),
    Traced(RESULTS_DOC, "From constant velocity at every step", "nmpc.json",
           (_nmpc("light", "nmpc_constant_velocity.mean_event_cost"),
            _nmpc("dense", "nmpc_constant_velocity.mean_event_cost"))),
    Traced(RESULTS_DOC, "- At the paper's operating point (slack prices", "nmpc.json",
           (_nmpc("light", "nmpc_rollout.mean_event_cost", OPERATING_POINT),
            _nmpc("dense", "nmpc_rollout.mean_event_cost", OPERATING_POINT),
            _nmpc("light", "srmpc.mean_event_cost", OPERATING_POINT),
            _nmpc("dense", "srmpc.mean_event_cost", OPERATING_POINT),
            _nmpc("light", "nmpc_rollout.paired.ltv_mpc.mean_event_cost|negate", OPERATING_POINT),
            _nmpc("dense", "nmpc_rollout.paired.ltv_mpc.mean_event_cost|negate", OPERATING_POINT)),
           ("x0.05",)),
    Traced(RESULTS_DOC, "- The rollout as the guess is safer", "nmpc.json",
           ("verdicts.6.paired.mean_event_cost", "verdicts.7.paired.mean_event_cost"),
           ("all 4 cells (8 pairs)",)),
    Traced(RESULTS_DOC, "So for the paper's proposal", "nmpc.json",
           ("initial_guess_study.per_guess.policy_rollout.iterations_median",
            "initial_guess_study.per_guess.constant_velocity.iterations_median",
            "initial_guess_study.per_guess.policy_rollout.iterations_median",
            "initial_guess_study.per_guess.shifted_previous.iterations_median",
            "initial_guess_study.per_guess.policy_rollout.states_at_lowest_optimum",
            "initial_guess_study.per_guess.policy_rollout.states",
            "initial_guess_study.per_guess.constant_velocity.states_at_lowest_optimum",
            "initial_guess_study.per_guess.shifted_previous.states_at_lowest_optimum")),
    Traced(RESULTS_DOC, "IPOPT, warm-started at each of the", "nmpc.json",
           ("initial_guess_study.kkt_certification_by_ipopt.all_guesses.converged_plans",
            "initial_guess_study.kkt_certification_by_ipopt.all_guesses.certified",
            "initial_guess_study.kkt_certification_by_ipopt.all_guesses.not_certified")),
    Traced(RESULTS_DOC, "give the same J_c as the twin's own resets", "evaluation/crosscheck.json",
           ("light.ltv_mpc.p_value", "light.srmpc.p_value",
            "dense.srmpc.twin.mean_event_cost", "dense.srmpc.highway_env_resets.mean_event_cost",
            "light.ltv_mpc.twin.mean_event_cost", "light.ltv_mpc.highway_env_resets.mean_event_cost"),
           ("1000 episodes",)),
    Traced(RESULTS_DOC, "also run 20 LTV-MPC and SRMPC episodes", definitions=("20 LTV-MPC",)),
    Traced(RESULTS_DOC, "overtakes a slower leader within", definitions=("30 s",)),
    Traced(RESULTS_DOC, "frames per second", definitions=("15 frames",)),
    # docs/pipeline.md, "## Timings": the whole pipeline's measured run
    Traced(PIPELINE_DOC, "every one of its", PIPELINE,
           ("n_stages", "dvc_repro_wall_s|minutes", "dvc_repro_wall_s|hours", "setup_s", "n_stages",
            "n_stages_in_dvc_lock"), ("2-core", "commit 5b35ceb")),
    Traced(PIPELINE_DOC, "The stages used", PIPELINE, ("core_s", "core_s|hours")),
    Traced(PIPELINE_DOC, "That is ", PIPELINE, ("ratio_to_target.dvc_repro_wall_s", "targets_s.dvc_repro_wall_s|hours")),
    Traced(PIPELINE_DOC, "Training took", PIPELINE, ("training_s|minutes", "training_concurrency",
                                                     "core_s_by_kind.training", "downstream_of_training_s|minutes")),
    Traced(PIPELINE_DOC, "| NMPC evaluations |", PIPELINE, _group("evaluate@nmpc")),
    Traced(PIPELINE_DOC, "| trade-off sweep evaluations |", PIPELINE, _group("evaluate@tradeoff")),
    Traced(PIPELINE_DOC, "| SRMPC variants' evaluations |", PIPELINE, _group("evaluate@variants")),
    Traced(PIPELINE_DOC, "| training PPO-L-SI and PPO |", PIPELINE, _group("train")),
    Traced(PIPELINE_DOC, "| training PPO-L-RSS |", PIPELINE, _group("train_rss")),
    Traced(PIPELINE_DOC, "| RSS evaluations |", PIPELINE, _group("evaluate@rss")),
    Traced(PIPELINE_DOC, "| operating point evaluations |", PIPELINE, _group("evaluate@operating_point")),
    Traced(PIPELINE_DOC, "| cross-checks (highway-env, its resets) |", PIPELINE, _group("evaluate@crosscheck")),
    Traced(PIPELINE_DOC, "| training Stable-Baselines3's PPO |", PIPELINE, _group("train_sb3")),
    Traced(PIPELINE_DOC, "| the table's evaluations |", PIPELINE, _group("evaluate@table")),
    Traced(PIPELINE_DOC, "| training the multiplier ablation |", PIPELINE, _group("train_multiplier_ablation")),
    Traced(PIPELINE_DOC, "| confirmation on fresh seeds |", PIPELINE, _group("evaluate@confirmation")),
    Traced(PIPELINE_DOC, "most evaluations run", definitions=("1000 episodes", "400 planner")),
    Traced(PIPELINE_DOC, "What would close the 3 h", definitions=("3 h", "1 ms")),
    Traced(PIPELINE_DOC, "an 8-core workstation", PIPELINE, ("projections.workstation_8_cores.dvc_repro_wall_s|minutes",),
           ("8-core", "8.5 s")),
    Traced(PIPELINE_DOC, "On a SLURM cluster of", PIPELINE,
           ("projections.slurm_64_cores.cores", "projections.slurm_64_cores.shard_episodes",
            "projections.slurm_64_cores.job_overhead_s", "projections.slurm_64_cores.jobs",
            "projections.slurm_64_cores.wall_s|minutes", "projections.slurm_64_cores.ratio_to_target",
            "projections.slurm_64_cores.target_s|minutes", "projections.slurm_64_cores.cores",
            "projections.slurm_64_cores.lower_bound_core_s_over_cores|minutes")),
    Traced(PIPELINE_DOC, "Of the 372 outputs", PIPELINE, ("outputs.compared", "outputs.same_md5_as_commit")),
    # README, "## The two commands"
    Traced(README, "Both need only", definitions=("(3.11)",)),
    Traced(README, "From nothing on 2 cores", PIPELINE,
           ("n_stages", "dvc_repro_wall_s|hours", "ratio_to_target.dvc_repro_wall_s", "targets_s.dvc_repro_wall_s|hours",
            "groups[group=evaluate@nmpc].share_of_core_s|percent"), ("2 cores", "commit 5b35ceb", "127.0.0.1:5000")),
)

# ---------------------------------------------------------------------------------------------------
# the checker


def untraced_problems(doc: str, prose: str, traced: tuple[Traced, ...],
                      loader: Callable[[str], dict] = load) -> list[str]:
    """One line per fault of ``traced`` against the units of ``prose`` (the prose of ``doc``)."""
    problems: list[str] = []
    found = units(prose)
    claimed: set[int] = set()
    for entry in (entry for entry in traced if entry.doc == doc):
        hits = [index for index, unit in enumerate(found) if entry.fragment in unit]
        if len(hits) != 1:
            problems.append(f"{doc}: fragment {entry.fragment!r} finds {len(hits)} units, not 1")
            continue
        if hits[0] in claimed:
            problems.append(f"{doc}: fragment {entry.fragment!r} finds a unit another entry traces")
            continue
        claimed.add(hits[0])
        problems += _entry_problems(doc, entry, found[hits[0]], loader)
    for index, unit in enumerate(found):
        if index not in claimed and (printed := numbers(unit)):
            listed = ", ".join(number.text for number in printed)
            problems.append(f"{doc}: untraced number(s) {listed} in {_short(unit)!r}")
    return problems


def _entry_problems(doc: str, entry: Traced, unit: str, loader: Callable[[str], dict]) -> list[str]:
    where = f"{doc}: {entry.fragment!r}"
    problems, spans = [], []
    for definition in entry.definitions:
        start = unit.find(definition)
        if start < 0:
            problems.append(f"{where}: definition {definition!r} is not in the text")
        elif not numbers(definition):
            problems.append(f"{where}: definition {definition!r} holds no number")
        else:
            spans.append((start, start + len(definition)))
    printed = [number for number in numbers(unit)
               if not any(start <= number.start and number.end <= end for start, end in spans)]
    if len(printed) != len(entry.keys):
        listed = ", ".join(number.text for number in printed) or "none"
        return [*problems, f"{where}: prints {len(printed)} result number(s) ({listed}) but traces "
                           f"{len(entry.keys)} key(s)"]
    for number, key in zip(printed, entry.keys, strict=True):
        try:
            name, value = resolve(key, entry.file or "", loader)
        except (KeyError, IndexError, ValueError, FileNotFoundError) as error:
            problems.append(f"{where}: {number.text}: {error.args[0] if error.args else error}")
            continue
        if not matches(value, number):
            problems.append(f"{where}: prints {number.text}, {name} is {rendered(value, number)} ({value!r})")
    return problems


def _short(unit: str, width: int = 90) -> str:
    return unit if len(unit) <= width else unit[:width - 3] + "..."


def prose_of(doc: str) -> str:
    text = (ROOT / doc).read_text()
    if doc == README:
        return readme_results_prose(text)
    return pipeline_timings_prose(text) if doc == PIPELINE_DOC else text


# ---------------------------------------------------------------------------------------------------
# the tests


@pytest.mark.parametrize("doc", [README, RESULTS_DOC, PIPELINE_DOC])
def test_every_number_is_traced_to_a_result_file(doc):
    problems = untraced_problems(doc, prose_of(doc), TRACED)
    assert not problems, f"{len(problems)} number(s) of {doc} not traced to results/:\n" + "\n".join(problems)


def test_every_entry_names_a_doc_read_here():
    assert {entry.doc for entry in TRACED} <= {README, RESULTS_DOC, PIPELINE_DOC}
    assert all(entry.file is None or (RESULTS / entry.file).is_file() for entry in TRACED)


def test_the_tokenizer_reads_every_printed_form():
    text = ("J_c 0.058 [0.045, 0.074], −0.189 / -0.537, +0.23 [+0.08, +0.39] m/s; margins 1-8 m, 96-97%; "
            "1/57 of it; slack x0.05; 1.9x / 2.2x; 4.2e-6; 1,000 runs; AC4MPC, Stable-Baselines3, w_v 2; 21/4.")
    assert [number.text for number in numbers(text)] == [
        "0.058", "0.045", "0.074", "−0.189", "-0.537", "+0.23", "+0.08", "+0.39", "1", "8", "96", "97%",
        "1/57", "x0.05", "1.9", "2.2", "4.2e-6", "1,000", "2", "21", "4"]
    assert [number.normalized for number in numbers("−0.000 +0.10 1/57 1,000 4.2e-06")] == [
        "0.000", "0.10", "57", "1000", "4.2e-6"]
    assert [number.decimals for number in numbers("0.058 24.1 57 4.2e-6")] == [3, 1, 0, 1]
    first = numbers("0.47 0.48 0.49 4.2e-6 -0.000")
    assert [matches(0.475, number) for number in first[:3]] == [True, True, False]
    assert matches(4.21e-6, first[3]) and matches(-0.0004, first[4]) and not matches(0.4749, first[1])


def test_units_are_sentences_and_table_rows():
    markdown = ("Intro, e.g. SRMPC at 0.5 m/s. Next (x0.05) one.\n- **A.** Bullet\n  continues 2.0 vs 3.\n\n"
                "| a | 1 |\n|---|---|\n```bash\nrun 5\n```\n`code 7` [link 8](x9.md)")
    assert units(markdown) == ["Intro, e.g. SRMPC at 0.5 m/s.", "Next (x0.05) one.",
                               "- **A.** Bullet continues 2.0 vs 3.", "| a | 1 |", "|---|---|", "[link 8]"]


def test_the_checker_catches_broken_input():
    data = {"a.json": {"x": {"v": 0.0581, "ci": [0.045, 0.074]}, "r": 0.0175}}
    loader = data.__getitem__
    prose = "Light: J_c 0.058 [0.045, 0.074] over 1000 episodes. At 1/57 of it. Then -104.7 here."
    good = (Traced("d", "Light:", "a.json", ("x.v", "x.ci.0", "x.ci.1"), ("1000 episodes",)),
            Traced("d", "At 1/57", "a.json", ("r|inv",)),
            Traced("d", "Then", "a.json", ("a.json:x.ci.0|cut|negate|inv|percent",)))
    assert untraced_problems("d", prose, good, loader) == []
    broken = untraced_problems("d", prose.replace("0.058", "0.059") + " Stray 3.5.", good, loader)
    assert len(broken) == 2 and "prints 0.059" in broken[0] and "untraced number(s) 3.5" in broken[1]
    assert "finds 0 units" in untraced_problems("d", prose, (Traced("d", "Gone", "a.json"),), loader)[0]
    assert "another entry traces" in untraced_problems("d", prose, (*good, Traced("d", "of it", "a.json")), loader)[0]
    assert "traces 2 key(s)" in untraced_problems("d", prose, (Traced("d", "At", "a.json", ("r", "r")),), loader)[0]
    assert "is not in the text" in untraced_problems(
        "d", prose, (Traced("d", "At", "a.json", ("r|inv",), ("9 m",)),), loader)[0]
    assert "no 'q'" in untraced_problems("d", prose, (Traced("d", "At", "a.json", ("q|inv",)),), loader)[0]


def test_a_selector_finds_one_list_element_by_its_fields():
    points = {"p": [{"s": {"m": 8.0, "w": 0.5}, "v": 1.0}, {"s": {"m": 1.0, "w": 0.5}, "v": 2.0},
                    {"s": {"m": 1.0, "w": 2.0}, "v": 3.0}]}
    assert resolve("p[s.m=1,s.w=2].v|negate", "a.json", {"a.json": points}.__getitem__) == (
        "a.json:p[s.m=1,s.w=2].v|negate", -3.0)
    assert walk(points, "p.1.v") == 2.0
    with pytest.raises(KeyError, match="selects 2 elements"):
        walk(points, "p[s.m=1].v")
    with pytest.raises(KeyError, match="selects 0 elements"):
        walk(points, "p[s.m=4].v")


def test_a_regenerated_number_fails_until_the_text_follows():
    def moved(name: str) -> dict:
        data = json.loads(json.dumps(load(name)))
        if name == "tradeoff.json":
            data["light"]["ppo_lsi"][0]["mean_vx"] += 0.1
        return data

    before = set(untraced_problems(RESULTS_DOC, prose_of(RESULTS_DOC), TRACED))
    after = set(untraced_problems(RESULTS_DOC, prose_of(RESULTS_DOC), TRACED, moved))
    assert after - before and all("tradeoff.json:light.ppo_lsi.0.mean_vx is 24.2" in line for line in after - before)
