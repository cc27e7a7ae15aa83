"""Hyperparameters of PPO / PPO-L-SI. This dataclass is also the Hydra schema of ``conf/agent``.

The paper gives no training hyperparameters; the defaults are CleanRL's continuous-control PPO
values where they apply, Feasible Actor-Critic / Safety-Index-Synthesis values (Ma et al.) for the
multiplier, and the batch layout is chosen for a 2-core CPU with the batched simulator.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import Enum

from srmpc.value_checks import (
    DISCOUNT,
    FINITE,
    NON_NEGATIVE,
    POSITIVE,
    TEXT,
    UNIT_INTERVAL,
    Interval,
    Vector,
    at_least,
    check_fields,
)

MAX_HIDDEN_WIDTH = 4096
"""Widest hidden layer: a 4096 x 4096 layer holds 16.8M weights (67 MB in float32, 4x that with Adam's
moments and the gradient) for the actor, both critics and the multiplier each. Ours is a small 2 x 64
MLP (the paper states no architecture); a width of 10^9 asked torch for 120 GB and died in its allocator."""
MAX_NUM_ENVS = 65_536
"""Most parallel scenes B: the twin keeps about 5 kB per scene (41 vehicles), so 65,536 scenes are
about 0.3 GB, 64x the default 1024."""
MAX_FRAMES_PER_BATCH = 4_194_304
"""Most environment steps per iteration (2^22, 128x the default): the rollout buffer keeps about 300
bytes per step (observations, actions, log-probabilities, rewards, costs, values), about 1.3 GB."""


def _check(condition: bool, key: str, value: object, expectation: str) -> None:
    if not condition:
        raise ValueError(f"{key}={value!r}: {expectation}")


class TrainTask(Enum):
    """What the agent trains on."""

    twin_highway = "twin_highway"
    """The batched highway simulator srmpc.sim.torchrl_env.TwinHighwayEnv (the paper's task)."""
    toy = "toy"
    """srmpc.agents.toy_env.ToyConstrainedEnv: a seconds-long smoke task with the same keys."""


@dataclass
class PPOHyperparameters:
    """PPO (``constrained=False``) and PPO-L-SI (``constrained=True``) training settings."""

    name: str = "ppo_lsi"
    """Run label: "ppo" or "ppo_lsi" (names the output directory and the MLflow run)."""
    constrained: bool = True
    """PPO-L-SI: cost critic v_c(s), SI cost, state-dependent multiplier lambda(s). False: plain PPO."""
    hidden_sizes: list[int] = field(default_factory=lambda: [64, 64])
    """Hidden widths of actor, both critics and the multiplier net (paper: a small policy for real time)."""
    initial_std: float = 0.5
    """Initial standard deviation of the Gaussian before the tanh squash (state-independent, learned)."""
    gamma: float = 0.99
    """Reward discount gamma (horizon ~100 steps = 20 s at 5 Hz)."""
    cost_gamma: float = 0.9
    """Cost discount gamma_c (0: v_c(s) = E[c(s, a)], the per-step SI condition of Ma et al.). Short
    (~10 steps = 2 s, the SI's look-ahead scale) so that v_c(s) measures
    the state-wise SI constraint near s rather than the -0.1 floor accumulated over 20 s."""
    gae_lambda: float = 0.95
    """GAE lambda of both advantages."""
    clip_epsilon: float = 0.2
    """PPO ratio clip eps (applied to the reward and the cost surrogate)."""
    entropy_coef: float = 0.0
    """Entropy bonus weight (0 as in CleanRL's continuous PPO; the learned std explores)."""
    actor_lr: float = 3e-4
    """Adam learning rate of the actor."""
    critic_lr: float = 1e-3
    """Adam learning rate of the reward and cost critics."""
    multiplier_lr: float = 1e-3
    """Adam learning rate of lambda(s). With Adam the output of a 2x64 net moves by up to ~65 x lr per
    step, so 1e-3 lets lambda(s) cross [0, 50] within a few hundred iterations."""
    multiplier_lr_final: float | None = None
    """If set, the multiplier learning rate decays linearly from ``multiplier_lr`` to this over the
    training iterations (Feasible Actor-Critic: 5e-6 -> 1e-6). null: constant."""
    multiplier_update_every: int = 1
    """lambda(s) takes ``multiplier_steps`` Adam steps every this many iterations, while the actor and
    critics take ``epochs`` x (frames_per_batch / minibatch_size) of them: the slower timescale of the
    dual ascent (FAC: dual ascent every 12 updates)."""
    multiplier_steps: int = 4
    """Adam steps of lambda(s) per multiplier update, one on each of the iteration's first minibatches
    (4: the first epoch; Ma et al.: 5 per epoch), capped at the iteration's epochs x minibatches."""
    multiplier_max_grad_norm: float | None = None
    """Gradient-norm clip of lambda(s) (Feasible Actor-Critic: 3). null: no clip."""
    violation_normalization: bool = False
    """Divide the violation v_c(s) - d by its minibatch standard deviation before the clip (Ma et al.),
    so the clip [-violation_clip_low, violation_clip_high] is in standard deviations."""
    multiplier_loss_on_logit: bool = False
    """Take the multiplier loss on softplus's input z(s) rather than on lambda(s) (same fixed points; the
    step does not vanish where lambda ~ 0). False: FAC / Ma et al. as published."""
    lambda_max: float = 50.0
    """Cap of lambda(s): the paper's numerical 'infinite' multiplier (Ma et al. clip at 50)."""
    initial_lambda: float = 1.0
    """lambda(s) everywhere at initialisation (softplus bias set accordingly)."""
    cost_threshold: float = 0.0
    """d of the state-wise constraint v_c(s) <= d [units of the SI cost]."""
    violation_clip_low: float = 0.3
    """v_c(s) - d is clipped below at -violation_clip_low in the multiplier loss (how fast lambda falls)."""
    violation_clip_high: float = 100.0
    """... and above at violation_clip_high (how fast lambda rises)."""
    max_grad_norm: float = 0.5
    """Global gradient-norm clip of the actor and of the critics."""
    num_envs: int = 1024
    """Parallel simulator instances B (the batch of the batched env)."""
    frames_per_batch: int = 32_768
    """Environment steps collected per iteration (a multiple of num_envs: T = frames_per_batch / B)."""
    total_frames: int = 20_000_000
    """Environment steps of training (610 iterations). At 6M steps PPO-L-SI's episodic cost return
    was still moving (0.25 to 0.47 over the last 1M steps); 20M lets the curves settle."""
    minibatch_size: int = 8192
    """SGD minibatch size (divides frames_per_batch): 4 Adam steps per epoch."""
    epochs: int = 4
    """SGD passes over each batch. 4 (as Brax / Isaac Gym PPO at large batches), not CleanRL's 10: one
    pass over 32k samples costs ~0.6 s on one core (measured), so 10 epochs would cap training at
    ~10k env steps/s whatever the simulator's speed."""
    checkpoint_every: int = 10
    """Iterations between checkpoints (the last one is also written at the end and on SIGTERM)."""
    seed: int = 0
    """Seed of torch, the simulator and the minibatch shuffling."""
    num_threads: int = 1
    """torch intra-op threads. 1: 2x64 MLPs gain nothing from more, and on a shared 2-core machine two
    spinning OpenMP threads made iterations 10-20x slower (measured) when the other core was busy."""
    sim_threads: int = 1
    """numba threads of the simulator's step (1: the serial kernel, no OpenMP pool). With 2 threads the
    pool's spin-wait after each step slowed the torch update so much that end-to-end training fell
    from 9.6k to 1.8k env steps/s on the shared 2-core machine (measured side by side)."""
    task: TrainTask = TrainTask.twin_highway
    """Environment to train on (``toy`` only for smoke runs)."""
    output_dir: str | None = None
    """Checkpoints, policy.pt, metrics.csv, summary.json; null means results/training/<name>/seed_<seed>. Rerunning
    with a checkpoint there resumes it (the agent and scenario config must be the same)."""

    def __post_init__(self) -> None:
        check_fields(
            self, name=TEXT, hidden_sizes=Vector(Interval(1, MAX_HIDDEN_WIDTH), min_length=1), initial_std=POSITIVE,
            gamma=DISCOUNT,
            cost_gamma=UNIT_INTERVAL, gae_lambda=UNIT_INTERVAL,
            clip_epsilon=Interval(0.0, 1.0, low_open=True, high_open=True), entropy_coef=NON_NEGATIVE,
            actor_lr=POSITIVE, critic_lr=POSITIVE, multiplier_lr=POSITIVE, multiplier_lr_final=POSITIVE,
            multiplier_update_every=at_least(1), multiplier_steps=at_least(1), multiplier_max_grad_norm=POSITIVE,
            lambda_max=POSITIVE, initial_lambda=POSITIVE, cost_threshold=FINITE, violation_clip_low=NON_NEGATIVE,
            violation_clip_high=POSITIVE, max_grad_norm=POSITIVE, num_envs=Interval(1, MAX_NUM_ENVS),
            frames_per_batch=Interval(1, MAX_FRAMES_PER_BATCH),
            total_frames=at_least(1), minibatch_size=at_least(1), epochs=at_least(1), checkpoint_every=at_least(1),
            seed=NON_NEGATIVE, num_threads=at_least(1), sim_threads=at_least(1), output_dir=TEXT,
        )
        _check(self.frames_per_batch % self.num_envs == 0, "frames_per_batch", self.frames_per_batch,
               f"must be a multiple of num_envs={self.num_envs}")
        _check(self.frames_per_batch % self.minibatch_size == 0, "minibatch_size", self.minibatch_size,
               f"must divide frames_per_batch={self.frames_per_batch}")
        _check(self.total_frames >= self.frames_per_batch, "total_frames", self.total_frames,
               f"must be >= frames_per_batch={self.frames_per_batch}")
        _check(0.0 < self.initial_lambda < self.lambda_max, "initial_lambda", self.initial_lambda,
               "must lie in (0, lambda_max)")

    @property
    def iterations(self) -> int:
        """Number of collect-and-update iterations (total_frames rounded down to whole batches)."""
        return self.total_frames // self.frames_per_batch
