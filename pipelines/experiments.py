"""DVC stage ``experiments``: what each published evaluation depends on, one file per experiment and traffic level.

    python -m pipelines.experiments

A published evaluation is an experiment file under a question folder, ``conf/experiment/<question>/<name>.yaml``
(``training/`` holds trainings, not evaluations), run in light and in dense traffic. For each, this composes
``+experiment=<question>/<name> scenario=<traffic>`` and writes its identity
(``srmpc.stages.evaluate.evaluation_identity``: the composed config without what changes no episode, plus the
SHA-256 of the policy it runs) to ``results/experiments/<question>/<name>_<traffic>.yaml``.

Stage ``evaluate`` takes that file as its ``params``, so DVC reruns a cell when, and only when, what the cell
composes to changes: a planner option it includes, a default in ``srmpc/``, its policy file. A new file under
``conf/`` or a retrained policy it does not run leaves it alone. ``dvc params diff`` shows what changed.
Files no longer composed (a deleted experiment) are removed.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import yaml

from srmpc.config.compose import CONFIG_DIR, NOT_EVALUATIONS, compose_config, recorded_yaml, to_objects
from srmpc.output_folder import atomic_write_text
from srmpc.stages.evaluate import evaluation_identity, identity_yaml

TRAFFIC = ("light", "dense")
"""The paper's two traffic levels: every published experiment runs in both."""
OUTPUT = Path("results/experiments")


def published_experiments(config_dir: Path = CONFIG_DIR) -> list[str]:
    """Every ``<question>/<name>`` under ``conf/experiment/`` that is an evaluation, sorted."""
    root = config_dir / "experiment"
    return sorted(str(path.relative_to(root).with_suffix("")) for path in root.glob("*/*.yaml")
                  if path.parent.name not in NOT_EVALUATIONS)


def identity_text(experiment: str, traffic: str) -> str:
    """The identity of ``+experiment=<experiment> scenario=<traffic>`` as YAML (module docstring)."""
    cfg = compose_config([f"+experiment={experiment}", f"scenario={traffic}"])
    identity = evaluation_identity(identity_yaml(to_objects(cfg), recorded_yaml(cfg)))
    return yaml.safe_dump(identity, sort_keys=False)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--output", type=Path, default=OUTPUT)
    args = parser.parse_args()
    written = set()
    for experiment in published_experiments():
        for traffic in TRAFFIC:
            path = args.output / f"{experiment}_{traffic}.yaml"
            path.parent.mkdir(parents=True, exist_ok=True)
            text = identity_text(experiment, traffic)
            if not path.is_file() or path.read_text() != text:  # unchanged files keep their mtime
                atomic_write_text(path, text)
            written.add(path)
    for stale in set(args.output.glob("*/*.yaml")) - written:
        stale.unlink()
    print(f"experiments: {len(written)} identities in {args.output}")


if __name__ == "__main__":
    main()
