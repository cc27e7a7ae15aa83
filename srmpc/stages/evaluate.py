"""``stage=evaluate``: closed-loop episodes of one controller, resumable, tracked in MLflow.

Files in the output directory:
- ``config.yaml``: the composed config the episodes belong to (a different config refuses to
  write there, so earlier results are never mixed or lost);
- ``episodes.csv``: one row per finished episode, appended and flushed as each one ends, so an
  interrupted run keeps every finished episode and the next run with the same config resumes;
- ``summary.json``: the paper's table metrics over all episodes, replaced atomically at the end.
"""

from __future__ import annotations

import csv
import json
import os
from dataclasses import fields
from pathlib import Path

import gymnasium
import numpy as np

from srmpc import SCENARIO_ID
from srmpc.config.compose import ConfigError
from srmpc.config.schema import Config, ControllerName, SimulatorName
from srmpc.controllers import Controller
from srmpc.controllers.lane_keeping import LaneKeepingController, LaneKeepingGains
from srmpc.controllers.ltv_mpc import LtvMpcSceneController, ocp_config
from srmpc.controllers.policy import PolicyController
from srmpc.evaluation import EpisodeRecord, evaluate
from srmpc.metrics import EpisodeMetrics, aggregate_metrics
from srmpc.mpc.controller import LtvMpcController
from srmpc.mpc.ocp import CollisionGeometry, TrackingWeights
from srmpc.mpc.planner import StepOutcome
from srmpc.scenario import road
from srmpc.sim.single_env import TwinScenarioEnv
from srmpc.tracking import Run

OUTCOME_COLUMNS = [f"steps_{outcome.value}" for outcome in StepOutcome]
"""Per-episode planner outcome counts (0 for controllers without outcomes)."""
EPISODE_COLUMNS = ["episode", "seed", *[f.name for f in fields(EpisodeMetrics)], "termination", *OUTCOME_COLUMNS]


def build_controller(config: Config) -> Controller:
    """The controller named by ``evaluation.controller``, built from the config's plain values."""
    scenario = config.scenario
    name = config.evaluation.controller
    if name is ControllerName.lane_keeping:
        return LaneKeepingController(
            scenario.steering_max_rad, scenario.acceleration_min_mps2, scenario.acceleration_max_mps2,
            LaneKeepingGains(target_speed_mps=scenario.reward.vx_ref_mps),
        )
    if name is ControllerName.ltv_mpc:
        planner = config.planner
        weights = TrackingWeights(
            state=tuple(planner.state_weights), input=tuple(planner.input_weights),
            input_rate=tuple(planner.input_rate_weights),
            collision_slack_linear=planner.collision_slack_linear,
            collision_slack_quadratic=planner.collision_slack_quadratic,
            safety_slack_linear=planner.safety_slack_linear,
            safety_slack_quadratic=planner.safety_slack_quadratic,
        )
        geometry = CollisionGeometry(
            n_ego_circles=planner.n_ego_circles,
            safety_margin_longitudinal_m=planner.safety_margin_longitudinal_m,
            safety_margin_lateral_m=planner.safety_margin_lateral_m,
        )
        ocp = ocp_config(scenario, planner.horizon_steps, planner.max_vehicles, weights, geometry)
        y_ref = float(road.LANE_CENTERS[road.RIGHT_LANE])
        return LtvMpcSceneController(
            LtvMpcController(ocp, planner.solver, reference_lateral_position_m=y_ref,
                             reference_speed_m_s=scenario.reward.vx_ref_mps)
        )
    if name in (ControllerName.ppo_lsi, ControllerName.ppo):
        path = Path(config.evaluation.policy_path or f"results/training/{name.value}/policy.pt")
        if not path.is_file():
            raise ConfigError(f"evaluation.policy_path={str(path)!r}: no such policy file (train first: stage=train)")
        low = np.array([-scenario.steering_max_rad, scenario.acceleration_min_mps2])
        high = np.array([scenario.steering_max_rad, scenario.acceleration_max_mps2])
        return PolicyController.from_policy_file(path, low, high)
    raise ConfigError(f"evaluation.controller={name.value}: not implemented")


def atomic_write_text(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` via a temporary file and rename, so readers never see half a file."""
    temporary = path.with_name(path.name + ".tmp")
    temporary.write_text(text)
    os.replace(temporary, path)


def read_finished_episodes(path: Path) -> list[EpisodeRecord]:
    """Rows of ``episodes.csv``; a torn last line (a crash mid-write) is dropped."""
    if not path.exists():
        return []
    records = []
    with path.open(newline="") as handle:
        for row in csv.DictReader(handle):
            try:
                metrics = EpisodeMetrics(
                    episode_return=float(row["episode_return"]), event_cost=float(row["event_cost"]),
                    n_steps=int(row["n_steps"]), mean_vx=float(row["mean_vx"]),
                    si_cost_return=float(row["si_cost_return"]),
                )
                outcomes = {c.removeprefix("steps_"): int(row[c]) for c in OUTCOME_COLUMNS if int(row[c])}
                records.append(
                    EpisodeRecord(int(row["episode"]), int(row["seed"]), metrics, row["termination"], outcomes)
                )
            except (TypeError, ValueError, KeyError):
                break
    return records


def prepare_output_dir(output_dir: Path, config_yaml: str) -> list[EpisodeRecord]:
    """Claim ``output_dir`` for this config; return the episodes a previous run already finished."""
    output_dir.mkdir(parents=True, exist_ok=True)
    config_path = output_dir / "config.yaml"
    if config_path.exists() and config_path.read_text() != config_yaml:
        raise ConfigError(
            f"evaluation.output_dir={output_dir}: holds results of a different config ({config_path}); "
            "choose another directory"
        )
    atomic_write_text(config_path, config_yaml)
    finished = read_finished_episodes(output_dir / "episodes.csv")
    finished = [r for i, r in enumerate(finished) if r.episode == i]  # keep the contiguous prefix
    with (output_dir / "episodes.csv").open("w", newline="") as handle:  # rewrite without a torn tail
        writer = csv.writer(handle)
        writer.writerow(EPISODE_COLUMNS)
        for record in finished:
            writer.writerow(_row(record))
    return finished


def _row(record: EpisodeRecord) -> list:
    m = record.metrics
    outcomes = [record.outcomes.get(c.removeprefix("steps_"), 0) for c in OUTCOME_COLUMNS]
    return [record.episode, record.seed, m.episode_return, m.event_cost, m.n_steps, m.mean_vx,
            m.si_cost_return, record.termination, *outcomes]


def run_evaluation(config: Config, config_yaml: str, output_dir: Path, run: Run, progress: bool = True) -> dict:
    """Evaluate, appending to ``output_dir``; returns the summary written to ``summary.json``."""
    controller = build_controller(config)
    finished = prepare_output_dir(output_dir, config_yaml)
    episodes = config.evaluation.episodes
    if finished:
        run.set_tags({"resumed_from_episode": str(len(finished))})
    if config.evaluation.simulator is SimulatorName.twin:
        env = TwinScenarioEnv(config.scenario)
    else:
        env = gymnasium.make(SCENARIO_ID, params=config.scenario)
    csv_handle = (output_dir / "episodes.csv").open("a", newline="")
    writer = csv.writer(csv_handle)
    bar = None
    if progress:
        from tqdm import tqdm

        label = f"{config.evaluation.controller.value} {config.scenario.traffic}"
        bar = tqdm(total=episodes, initial=len(finished), desc=label, unit="ep")

    def on_episode(record: EpisodeRecord) -> None:
        writer.writerow(_row(record))
        csv_handle.flush()
        os.fsync(csv_handle.fileno())
        run.log_metrics({f"episode/{k}": v for k, v in record.metrics.as_dict().items()}, step=record.episode)
        if bar is not None:
            bar.update(1)

    try:
        records = finished + evaluate(
            env, controller, episodes, config.evaluation.seed, on_episode=on_episode, first_episode=len(finished)
        )
    finally:
        csv_handle.close()
        env.close()
        if bar is not None:
            bar.close()
    summary = aggregate_metrics([r.metrics for r in records]).as_dict()
    reasons = [r.termination for r in records]
    summary["terminations"] = {reason: reasons.count(reason) for reason in ("collision", "offroad", "truncated")}
    summary["outcomes"] = {
        c.removeprefix("steps_"): sum(r.outcomes.get(c.removeprefix("steps_"), 0) for r in records)
        for c in OUTCOME_COLUMNS
    }
    summary["controller"] = config.evaluation.controller.value
    summary["traffic"] = config.scenario.traffic
    summary["simulator"] = config.evaluation.simulator.value
    atomic_write_text(output_dir / "summary.json", json.dumps(summary, indent=2) + "\n")
    run.log_metrics({k: v for k, v in summary.items() if isinstance(v, float | int)})
    run.log_artifact(output_dir / "episodes.csv")
    run.log_artifact(output_dir / "summary.json")
    return summary
