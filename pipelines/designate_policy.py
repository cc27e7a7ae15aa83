"""Designate one trained seed's policy as the agent's policy for every evaluation.

    python -m pipelines.designate_policy --agent ppo_lsi --seed 0 [--training-dir results/training]

Copies ``<training-dir>/<agent>/seed_<seed>/policy.pt`` to ``<training-dir>/<agent>/policy.pt`` (the
path the evaluations, SRMPC and the figures load) and writes ``designated.json`` next to it: the seed,
its SHA-256, its end-of-training summary and the reason. The pipeline designates seed 0, fixed before
any training ran, so the evaluated policy is not picked by its result; the spread over seeds is
reported in results/training/summary.json.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
REASON = ("seed 0, fixed before training so that the evaluated policy is not chosen by its result; "
          "the other seeds' end-of-training metrics are in results/training/summary.json")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--agent", required=True)
    parser.add_argument("--seed", type=int, required=True)
    parser.add_argument("--training-dir", type=Path, default=ROOT / "results/training")
    args = parser.parse_args()
    source = args.training_dir / args.agent / f"seed_{args.seed}" / "policy.pt"
    if not source.is_file():
        raise SystemExit(f"{source}: no trained policy (run the DVC stage train: dvc repro train)")
    target = args.training_dir / args.agent / "policy.pt"
    temporary = target.with_name(target.name + ".tmp")
    shutil.copyfile(source, temporary)
    os.replace(temporary, target)
    summary_path = source.parent / "summary.json"
    designated = {
        "agent": args.agent,
        "seed": args.seed,
        "source": os.path.relpath(source, ROOT),
        "sha256": hashlib.sha256(target.read_bytes()).hexdigest(),
        "reason": REASON,
        "training_summary": json.loads(summary_path.read_text()) if summary_path.exists() else None,
    }
    (target.parent / "designated.json").write_text(json.dumps(designated, indent=2) + "\n")
    print(f"{target} <- {source}")


if __name__ == "__main__":
    main()
