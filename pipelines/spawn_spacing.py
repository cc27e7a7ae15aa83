"""DVC stage: measure the spawn spacing of light and dense traffic -> results/scenario/spawn_spacing.json.

Composes ``conf/`` itself (``dvc repro`` does not compose Hydra configs).
Usage: python -m pipelines.spawn_spacing [--resets N]
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import gymnasium

from srmpc import SCENARIO_ID
from srmpc.config.compose import compose_config, to_objects
from srmpc.scenario.spawning import spawn_statistics

OUTPUT = Path("results/scenario/spawn_spacing.json")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--resets", type=int, default=500, help="resets per traffic level")
    args = parser.parse_args()
    report = {}
    for traffic in ("light", "dense"):
        config = to_objects(compose_config([f"+experiment={traffic}_traffic"]))
        env = gymnasium.make(SCENARIO_ID, params=config.scenario).unwrapped
        stats = spawn_statistics(env, range(args.resets))
        stats["configured_mean_spawn_gap_m"] = config.scenario.mean_spawn_gap_m
        report[traffic] = stats
        print(traffic, json.dumps(stats))
    OUTPUT.parent.mkdir(parents=True, exist_ok=True)
    temporary = OUTPUT.with_suffix(".json.tmp")
    temporary.write_text(json.dumps(report, indent=2) + "\n")
    os.replace(temporary, OUTPUT)


if __name__ == "__main__":
    main()
