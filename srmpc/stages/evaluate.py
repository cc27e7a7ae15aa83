"""``stage=evaluate``: closed-loop episodes of one controller, resumable, tracked in MLflow.

Files in the output directory:
- ``config.yaml``: the composed config the episodes belong to, plus ``policy_sha256`` for a
  controller that runs a policy; a config that differs in what the episodes depend on (see
  :func:`evaluation_identity`: not the training hyperparameters, MLflow settings or output paths)
  refuses to write there, so earlier results are never mixed or lost;
- ``episodes.csv``: one row per finished episode, appended and flushed as each one ends, so an
  interrupted run keeps every finished episode and the next run with the same config resumes;
- ``summary.json``: the paper's table metrics over all episodes, replaced atomically at the end.
"""

from __future__ import annotations

import csv
import functools
import hashlib
import json
import os
from dataclasses import fields
from pathlib import Path

import gymnasium
import numpy as np
import yaml

from srmpc import SCENARIO_ID
from srmpc.config.compose import ConfigError
from srmpc.config.schema import Config, ControllerName, SimulatorName
from srmpc.controllers import Controller
from srmpc.controllers.lane_keeping import LaneKeepingController, LaneKeepingGains
from srmpc.controllers.ltv_mpc import LtvMpcController
from srmpc.controllers.outcomes import OUTCOME_KEYS
from srmpc.controllers.policy import PolicyController
from srmpc.controllers.scenario_ocp import ocp_config
from srmpc.controllers.srmpc import SceneSource, SrmpcController
from srmpc.episode_loop import EpisodeRecord, evaluate, evaluate_in_workers
from srmpc.metrics import EpisodeMetrics, aggregate_metrics
from srmpc.mpc.ocp import CollisionGeometry, OcpConfig, TrackingWeights, lane_keeping_tracking_reference
from srmpc.mpc.planner import LtvMpcPlanner
from srmpc.scenario import road
from srmpc.sim.constants import SimConstants
from srmpc.sim.mlp import MlpPolicy
from srmpc.sim.simulator import TwinSimulator
from srmpc.sim.single_env import HighwayEnvStartTwinEnv, TwinScenarioEnv
from srmpc.sim.state import SceneState
from srmpc.tracking import Run

REPOSITORY = Path(__file__).resolve().parents[2]
"""The repository root: default policy files are its results/training/<agent>/policy.pt, from any directory."""
OUTCOME_COLUMNS = [f"steps_{key}" for key in OUTCOME_KEYS]
"""Per-episode planner outcome counts (0 for controllers without outcomes): which link of the fallback
chain produced the applied input (solved, shifted_previous, emergency_brake), which linearization
reference a solved plan came from (solved_from_policy / _shifted / _lane_following) and the steps whose
policy rollout failed (SRMPC only)."""
EPISODE_COLUMNS = ["episode", "seed", *[f.name for f in fields(EpisodeMetrics)], "termination", *OUTCOME_COLUMNS]


def build_planner_objects(config: Config) -> tuple[OcpConfig, float]:
    """The OCP of ``planner`` for the scenario, and y_ref [m] (shared by LTV-MPC and SRMPC)."""
    scenario, planner = config.scenario, config.planner
    scale = planner.slack_price_scale  # a common factor on the four slack prices
    weights = TrackingWeights(
        state=tuple(planner.state_weights), input=tuple(planner.input_weights),
        input_rate=tuple(planner.input_rate_weights),
        collision_slack_linear=scale * planner.collision_slack_linear,
        collision_slack_quadratic=scale * planner.collision_slack_quadratic,
        safety_slack_linear=scale * planner.safety_slack_linear,
        safety_slack_quadratic=scale * planner.safety_slack_quadratic,
    )
    geometry = CollisionGeometry(
        n_ego_circles=planner.n_ego_circles,
        safety_margin_longitudinal_m=planner.safety_margin_longitudinal_m,
        safety_margin_lateral_m=planner.safety_margin_lateral_m,
    )
    ocp = ocp_config(scenario, planner.horizon_steps, planner.max_vehicles, weights, geometry)
    return ocp, float(road.LANE_CENTERS[road.RIGHT_LANE])


def policy_file(config: Config) -> tuple[Path, str, str] | None:
    """(file, agent, config key) of the policy the evaluated controller runs; None when it runs none."""
    name = config.evaluation.controller
    if name is ControllerName.srmpc:
        agent, path, key = config.srmpc.policy.value, config.srmpc.policy_path, "srmpc.policy_path"
    elif name in (ControllerName.ppo_lsi, ControllerName.ppo):
        agent, path, key = name.value, config.evaluation.policy_path, "evaluation.policy_path"
    else:
        return None
    return (Path(path) if path else REPOSITORY / "results" / "training" / agent / "policy.pt"), agent, key


def load_policy(config: Config, agent: str, path: str | None, key: str) -> MlpPolicy:
    """The deterministic actor of ``agent`` (TanhNormal mode) from ``path`` or its training output."""
    scenario = config.scenario
    policy_file = Path(path) if path else REPOSITORY / "results" / "training" / agent / "policy.pt"
    if not policy_file.is_file():
        raise ConfigError(f"{key}={str(policy_file)!r}: no such policy file (train first: stage=train agent={agent})")
    low = np.array([-scenario.steering_max_rad, scenario.acceleration_min_mps2])
    high = np.array([scenario.steering_max_rad, scenario.acceleration_max_mps2])
    return PolicyController.from_policy_file(policy_file, low, high).policy


def scene_source(env: gymnasium.Env) -> SceneSource:
    """SRMPC's copy of the live scene: the twin's own state, or a twin copy of the highway-env scene."""
    scenario_env = env.unwrapped
    if isinstance(scenario_env, TwinScenarioEnv):
        simulator = scenario_env.simulator
        return lambda: (simulator.state, simulator.constants)

    def copy_of_highway_env() -> tuple[SceneState, SimConstants]:
        twin = TwinSimulator.from_highway_env([scenario_env], threads=1)
        return twin.state, twin.constants

    return copy_of_highway_env


def build_controller(config: Config, env: gymnasium.Env) -> Controller:
    """The controller named by ``evaluation.controller`` for ``env``, built from the config's plain values."""
    scenario = config.scenario
    name = config.evaluation.controller
    if name is ControllerName.lane_keeping:
        return LaneKeepingController(
            scenario.steering_max_rad, scenario.acceleration_min_mps2, scenario.acceleration_max_mps2,
            LaneKeepingGains(target_speed_mps=scenario.reward.vx_ref_mps),
        )
    if name is ControllerName.ltv_mpc:
        ocp, y_ref = build_planner_objects(config)
        tracking = lane_keeping_tracking_reference(ocp.horizon, y_ref, scenario.reward.vx_ref_mps,
                                                   control_period_s=ocp.control_period_s)
        return LtvMpcController(LtvMpcPlanner(ocp, config.planner.solver), tracking)
    if name is ControllerName.srmpc:
        ocp, y_ref = build_planner_objects(config)
        srmpc = config.srmpc
        policy = load_policy(config, srmpc.policy.value, srmpc.policy_path, "srmpc.policy_path")
        tracking = lane_keeping_tracking_reference(ocp.horizon, y_ref, scenario.reward.vx_ref_mps,
                                                   control_period_s=ocp.control_period_s)
        return SrmpcController(policy, LtvMpcPlanner(ocp, config.planner.solver), scene_source(env), tracking,
                               srmpc)  # SrmpcConfig is the SrmpcSettings schema plus the policy's name and file
    if name in (ControllerName.ppo_lsi, ControllerName.ppo):
        return PolicyController(load_policy(config, name.value, config.evaluation.policy_path,
                                            "evaluation.policy_path"))
    raise ConfigError(f"evaluation.controller={name.value}: not implemented")


def make_env(config: Config) -> gymnasium.Env:
    """The scenario on ``evaluation.simulator``."""
    if config.evaluation.simulator is SimulatorName.twin:
        return TwinScenarioEnv(config.scenario)
    if config.evaluation.simulator is SimulatorName.twin_highway_env_resets:
        return HighwayEnvStartTwinEnv(config.scenario)
    return gymnasium.make(SCENARIO_ID, params=config.scenario)


def make_env_and_controller(config: Config) -> tuple[gymnasium.Env, Controller]:
    """The scenario on ``evaluation.simulator`` and ``evaluation.controller`` for it: what an evaluation,
    and each of its worker processes, builds once."""
    env = make_env(config)
    try:
        return env, build_controller(config, env)
    except Exception:
        env.close()
        raise


def available_cores() -> int:
    """CPU cores this process may run on (its affinity mask: a SLURM allocation, taskset)."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def evaluation_workers(config: Config, remaining: int) -> int:
    """Worker processes for ``remaining`` episodes: ``evaluation.workers`` (0: every available core),
    at most one per episode; 1 means this process runs them."""
    requested = config.evaluation.workers
    if requested < 0:
        raise ConfigError(f"evaluation.workers={requested}: must be >= 0 (0: one per CPU core, 1: this process)")
    return max(1, min(requested or available_cores(), remaining))


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


NOT_IDENTITY = (("agent",), ("tracking",), ("evaluation", "output_dir"), ("evaluation", "workers"))
"""Config entries that do not change an evaluation's episodes: the training hyperparameters (the
policy enters through its file's hash), MLflow settings, where the results go and how many processes
produce them."""


def evaluation_identity(config_yaml: str) -> dict:
    """What an evaluation's episodes depend on: the config without :data:`NOT_IDENTITY`, plus
    ``policy_sha256`` where the controller runs a policy."""
    try:
        identity = yaml.safe_load(config_yaml) or {}
    except yaml.YAMLError:
        identity = None
    if not isinstance(identity, dict):  # not a config mapping: the text itself is the identity
        return {"text": config_yaml}
    for path in NOT_IDENTITY:
        node = identity
        for key in path[:-1]:
            node = node.get(key, {}) if isinstance(node, dict) else {}
        if isinstance(node, dict):
            node.pop(path[-1], None)
    return identity


def identity_yaml(config: Config, config_yaml: str) -> str:
    """``config_yaml`` with the SHA-256 of the evaluated policy file appended (see evaluation_identity)."""
    policy = policy_file(config)
    if policy is None or not policy[0].is_file() or "text" in evaluation_identity(config_yaml):
        return config_yaml
    return config_yaml.rstrip("\n") + f"\npolicy_sha256: {hashlib.sha256(policy[0].read_bytes()).hexdigest()}\n"


def prepare_output_dir(output_dir: Path, config_yaml: str) -> list[EpisodeRecord]:
    """Claim ``output_dir`` for this config; return the episodes a previous run already finished.

    A directory whose ``config.yaml`` has another :func:`evaluation_identity` is refused (its episodes
    belong to another scenario, planner, controller, seed or policy)."""
    try:
        output_dir.mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise ConfigError(f"evaluation.output_dir={output_dir}: cannot write there ({error.strerror or error})"
                          ) from error
    config_path = output_dir / "config.yaml"
    if config_path.exists() and evaluation_identity(config_path.read_text()) != evaluation_identity(config_yaml):
        raise ConfigError(
            f"evaluation.output_dir={output_dir}: holds results of a different config or policy ({config_path}); "
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
    """Evaluate, appending to ``output_dir``; returns the summary written to ``summary.json``.

    The episodes run in ``evaluation.workers`` processes (:func:`evaluation_workers`); this process
    alone writes ``episodes.csv`` (in episode order, each row fsync'd), logs to MLflow and shows the
    progress bar, so the file is the same, and resumes the same, whatever the number of workers."""
    evaluation_workers(config, 1)  # a bad evaluation.workers fails before anything is written
    env, controller = make_env_and_controller(config)  # also in the parent: a bad policy fails here, in one line
    finished = prepare_output_dir(output_dir, identity_yaml(config, config_yaml))
    episodes = config.evaluation.episodes
    workers = evaluation_workers(config, episodes - len(finished))
    run.set_tags({"evaluation_workers": str(workers)})
    if finished:
        run.set_tags({"resumed_from_episode": str(len(finished))})
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
        if workers > 1:
            setup = functools.partial(make_env_and_controller, config)
            new = evaluate_in_workers(setup, episodes, config.evaluation.seed, workers, on_episode, len(finished))
        else:
            new = evaluate(env, controller, episodes, config.evaluation.seed, on_episode, len(finished))
        records = finished + new
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
