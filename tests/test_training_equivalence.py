"""The fast training paths compute what TorchRL's generic ones do, bit for bit.

Each test pits one of ours against the TorchRL (or previous) code it replaces, on the same inputs
and the same torch generator state, and asks for ``torch.equal``: the collection
(``RolloutCollector`` against ``torchrl.collectors.Collector``), the actor's random pass, the GAEs
(``PPOLSILoss.compute_advantages`` against TorchRL's ``GAE`` modules), the loss terms and their
gradients (``loss_terms`` against ``ClipPPOLoss``'s own pieces, as the loss was written before)
and the episode sums. No timing is asserted.
"""

from __future__ import annotations

import pytest
import torch
from tensordict import TensorDict
from torchrl.collectors import Collector
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import TanhNormal

from srmpc.agents import tanh_normal
from srmpc.agents.hyperparameters import PPOHyperparameters, TrainTask
from srmpc.agents.networks import COST_VALUE_KEY, LAMBDA_KEY
from srmpc.agents.ppo_lsi_loss import COST_ADVANTAGE_KEY, COST_VALUE_TARGET_KEY, LOGIT_FLOOR, pearson
from srmpc.agents.rollout import RolloutCollector, sample_actions
from srmpc.agents.tanh_normal import actor_box, affine_of_box
from srmpc.agents.toy_env import ToyConstrainedEnv
from srmpc.agents.trainer import EpisodeTracker, build_loss, parameter_groups

torch.set_num_threads(1)
LOW, HIGH = torch.tensor([-0.1, -5.0]), torch.tensor([0.1, 5.0])


def hyperparameters(**overrides) -> PPOHyperparameters:
    settings = dict(num_envs=16, frames_per_batch=16 * 20, minibatch_size=80, total_frames=16 * 20 * 10,
                    task=TrainTask.toy, violation_normalization=True)
    settings.update(overrides)
    return PPOHyperparameters(**settings)


def twin_env(num_envs: int, seed: int):
    from srmpc.scenario.parameters import ScenarioParameters
    from srmpc.sim.torchrl_env import TwinHighwayEnv

    return TwinHighwayEnv(ScenarioParameters(), num_envs, seed=seed, threads=1)


def collected(make_env, hp: PPOHyperparameters, ours: bool, iterations: int = 3) -> list[TensorDict]:
    """``iterations`` batches from a fresh env and loss (seed 0), with our collector or TorchRL's."""
    env = make_env()
    env.set_seed(hp.seed)
    torch.manual_seed(0)
    loss = build_loss(30, LOW, HIGH, hp)
    if ours:
        collector = RolloutCollector(env, loss.actor_network, hp.frames_per_batch)
        torch.manual_seed(1)
        batches = [collector.collect() for _ in range(iterations)]
    else:
        collector = Collector(env, loss.actor_network, frames_per_batch=hp.frames_per_batch, total_frames=-1,
                              auto_register_policy_transforms=False)
        torch.manual_seed(1)
        batches = [batch.clone() for batch in map(next, [iter(collector)] * iterations)]
        collector.shutdown()
    batches.append(TensorDict({"next_draw": torch.rand(4)}))  # the generator's state after collecting
    return batches


@pytest.mark.parametrize("env_name", ["toy", "twin"])
def test_rollout_collector_equals_torchrl_collector(env_name):
    hp = hyperparameters(num_envs=8, frames_per_batch=8 * 40, minibatch_size=80)
    make_env = (lambda: ToyConstrainedEnv(hp.num_envs, seed=3)) if env_name == "toy" else (lambda: twin_env(8, 3))
    ours, theirs = collected(make_env, hp, ours=True), collected(make_env, hp, ours=False)
    assert any(bool(b["next", "done"].any()) for b in ours[:-1]), "no episode ended: the resets go untested"
    for mine, reference in zip(ours, theirs, strict=True):
        for key in mine.keys(True, True):
            assert torch.equal(mine.get(key), reference.get(key)), key


def test_sample_actions_is_the_actor_random_pass():
    loss = build_loss(30, LOW, HIGH, hyperparameters())
    observation = torch.randn(64, 30) * 3
    with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
        torch.manual_seed(5)
        reference = loss.actor_network(TensorDict({"observation": observation}, batch_size=[64]))
        torch.manual_seed(5)
        action, log_prob = sample_actions(loss.actor_network, observation)
        torch.manual_seed(5)
        fast = sample_actions(loss.actor_network, observation, actor_box(loss.actor_network))
    assert torch.equal(action, reference["action"]) and torch.equal(log_prob, reference["action_log_prob"])
    assert torch.equal(fast[0], action) and torch.equal(fast[1], log_prob)


def test_tanh_normal_arithmetic_equals_torchrl_tanh_normal():
    generator = torch.Generator().manual_seed(3)
    loc = (torch.randn(500, 2, generator=generator) * 2).requires_grad_()
    log_std = torch.randn(2, generator=generator).requires_grad_()
    scale = log_std.exp().expand_as(loc)
    dist = TanhNormal(loc=loc, scale=scale, low=LOW, high=HIGH)
    box = affine_of_box(LOW, HIGH)
    inside = torch.rand(500, 2, generator=generator) * (HIGH - LOW) + LOW
    action = torch.cat([inside[:-4], torch.stack([LOW, HIGH, LOW * 0.999999, HIGH * 0.999999])])  # the edges too
    ours, theirs = tanh_normal.log_prob(action, loc, scale, *box), dist.log_prob(action)
    assert torch.equal(ours, theirs)
    our_grads = torch.autograd.grad(ours.sum(), (loc, log_std), retain_graph=True)
    their_grads = torch.autograd.grad(theirs.sum(), (loc, log_std), retain_graph=True)
    assert all(torch.equal(a, b) for a, b in zip(our_grads, their_grads, strict=True))
    for shape in (torch.Size(()), torch.Size([1]), torch.Size([3])):
        torch.manual_seed(9)
        reference = dist.rsample_and_log_prob(shape)
        torch.manual_seed(9)
        mine = tanh_normal.rsample_and_log_prob(loc, scale, *box, shape)
        assert all(torch.equal(a, b) for a, b in zip(mine, reference, strict=True)), shape
        grads = [torch.autograd.grad(x[1].sum(), (loc, log_std), retain_graph=True) for x in (mine, reference)]
        assert all(torch.equal(a, b) for a, b in zip(*grads, strict=True))


def random_batch(num_envs: int = 6, steps: int = 40, seed: int = 0) -> TensorDict:
    """A (B, T) batch whose next observation is the next row's except where an episode ended."""
    generator = torch.Generator().manual_seed(seed)
    states = torch.randn(num_envs, steps + 1, 30, generator=generator)
    done = torch.rand(num_envs, steps, 1, generator=generator) < 0.1
    terminated = done & (torch.rand(num_envs, steps, 1, generator=generator) < 0.5)
    terminal = torch.randn(num_envs, steps, 30, generator=generator)
    next_observation = torch.where(done, terminal, states[:, 1:])
    return TensorDict({
        "observation": states[:, :-1].clone(),
        "action": torch.rand(num_envs, steps, 2, generator=generator) * (HIGH - LOW) * 0.98 + LOW * 0.98,
        "action_log_prob": torch.randn(num_envs, steps, generator=generator),
        "next": {"observation": next_observation, "done": done, "terminated": terminated,
                 "truncated": done & ~terminated,
                 "reward": torch.rand(num_envs, steps, 1, generator=generator),
                 "cost": torch.randn(num_envs, steps, 1, generator=generator) * 0.1},
    }, batch_size=[num_envs, steps])


@pytest.mark.parametrize("layout", [(6, 40), (1024, 32)])
def test_advantages_equal_torchrl_gae_modules(layout):
    loss = build_loss(30, LOW, HIGH, hyperparameters())
    batch = random_batch(*layout)
    ours = loss.compute_advantages(batch.clone())
    reference = batch.clone()
    loss.value_estimator(reference)
    loss.cost_value_estimator(reference)
    for key in ("advantage", "value_target", COST_ADVANTAGE_KEY, COST_VALUE_TARGET_KEY, "state_value",
                ("next", "state_value"), COST_VALUE_KEY, ("next", COST_VALUE_KEY)):
        assert torch.equal(ours.get(key), reference.get(key)), key


def previous_forward(loss, td: TensorDict) -> dict[str, torch.Tensor]:
    """``PPOLSILoss.forward`` as it was written on TorchRL's ClipPPOLoss pieces (commit 961b49e)."""
    td = td.clone(False)
    advantage = td.get(loss.tensor_keys.advantage)
    advantage = (advantage - advantage.mean()) / advantage.std().clamp_min(1e-8)
    log_weight, dist, kl_approx, _ = loss._log_weight(td, adv_shape=advantage.shape[:-1])
    ratio = log_weight.exp()
    clipped_ratio = log_weight.clamp(*loss._clip_bounds).exp()
    gain_reward = torch.minimum(ratio * advantage, clipped_ratio * advantage)
    out = {}
    cost_advantage = td.get(COST_ADVANTAGE_KEY)
    cost_advantage = cost_advantage - cost_advantage.mean()
    gain_cost = torch.maximum(ratio * cost_advantage, clipped_ratio * cost_advantage)
    logit = loss.multiplier_network.module.logit(td.get(loss.multiplier_network.in_keys[0]))
    multiplier = torch.nn.functional.softplus(logit).clamp(max=loss.lambda_max)
    lam = multiplier.detach()
    out["loss_objective"] = (-(gain_reward - lam * gain_cost) / (1.0 + lam)).mean()
    cost_value = loss.cost_critic_network(td.select(*loss.cost_critic_network.in_keys)).get(COST_VALUE_KEY)
    out["loss_cost_critic"] = (cost_value - td.get(COST_VALUE_TARGET_KEY)).pow(2).mean()
    violation = cost_value.detach() - loss.cost_threshold
    if loss.violation_normalization:
        violation = violation / violation.std().clamp_min(1e-8)
    violation = violation.clamp(-loss.violation_clip[0], loss.violation_clip[1])
    if loss.multiplier_loss_on_logit:
        at_bound = ((logit <= LOGIT_FLOOR) & (violation < 0)) | ((lam >= loss.lambda_max) & (violation > 0))
        out["loss_multiplier"] = -(torch.where(at_bound, logit.detach(), logit) * violation).mean()
    else:
        out["loss_multiplier"] = -(multiplier * violation).mean()
    out["lambda_mean"] = lam.mean()
    out["lambda_max"] = lam.max()
    out["lambda_share_at_max"] = (lam >= loss.lambda_max * (1.0 - 1e-6)).float().mean()
    out["violation_share"] = (violation > 0).float().mean()
    out["lambda_cost_value_corr"] = pearson(lam.flatten(), cost_value.detach().flatten())
    entropy = loss._get_entropy(dist, adv_shape=advantage.shape[:-1])
    out["entropy"] = entropy.detach().mean()
    out["loss_entropy"] = loss._weighted_loss_entropy(entropy).mean()
    loss_critic, _, _ = loss.loss_critic(td)
    out["loss_critic"] = loss_critic.mean()
    out["clip_fraction"] = (log_weight.detach().clamp(*loss._clip_bounds) != log_weight.detach()).float().mean()
    out["kl_approx"] = kl_approx.detach().mean()
    return out


def terms_and_gradients(loss, compute) -> tuple[dict[str, torch.Tensor], dict[str, list[torch.Tensor]]]:
    torch.manual_seed(7)
    terms = compute()
    for params in parameter_groups(loss).values():
        for p in params:
            p.grad = None
    sum(v for k, v in terms.items() if k.startswith("loss_")).backward()
    grads = {name: [p.grad for p in params] for name, params in parameter_groups(loss).items()}
    return {k: v.detach() for k, v in terms.items()}, grads


@pytest.mark.parametrize(("on_logit", "entropy_coef"), [(False, 0.0), (True, 0.0), (False, 0.01)])
@pytest.mark.parametrize("multiplier_grad", [True, False])
def test_loss_terms_and_gradients_equal_the_clip_ppo_loss_pieces(on_logit, entropy_coef, multiplier_grad):
    loss = build_loss(30, LOW, HIGH, hyperparameters(multiplier_loss_on_logit=on_logit, entropy_coef=entropy_coef))
    batch = loss.compute_advantages(random_batch(8, 64)).reshape(-1)
    with torch.no_grad():  # move the actor off its initial point so the ratios are not all 1
        loss.actor_network.module[0].module.loc_net[0].weight.mul_(1.5)
    minibatch = batch[torch.randperm(batch.shape[0], generator=torch.Generator().manual_seed(2))[:256]]
    ours, our_grads = terms_and_gradients(loss, lambda: loss.loss_terms(
        *(minibatch.get(k) for k in loss.training_keys), multiplier_grad=multiplier_grad))
    theirs, their_grads = terms_and_gradients(loss, lambda: previous_forward(loss, minibatch))
    assert list(ours) == list(theirs)
    for key in ours:
        assert torch.equal(ours[key], theirs[key]), key
    for group in ("actor", "critic") + (("multiplier",) if multiplier_grad else ()):
        for mine, reference in zip(our_grads[group], their_grads[group], strict=True):
            assert torch.equal(mine, reference), group
    if not multiplier_grad:
        assert all(g is None for g in our_grads["multiplier"])
        # lambda(s) fixed for the rest of an iteration: z(s) of the whole batch, gathered per minibatch
        logits = loss.multiplier_logits(batch.get("observation"))
        index = torch.randperm(batch.shape[0], generator=torch.Generator().manual_seed(2))[:256]
        shared, _ = terms_and_gradients(loss, lambda: loss.loss_terms(
            *(minibatch.get(k) for k in loss.training_keys), multiplier_grad=False,
            multiplier_logit=logits.index_select(0, index)))
        assert all(torch.equal(shared[key], ours[key]) for key in ours)
    assert LAMBDA_KEY == loss.multiplier_network.out_keys[0]


def previous_episode_update(tracker: EpisodeTracker, batch: TensorDict) -> list[dict[str, float]]:
    """``EpisodeTracker.update`` as it was written, one tensor per key (commit 961b49e)."""
    nxt = batch.get("next")
    columns = {
        "return": nxt.get("reward_prime"), "train_return": nxt.get("reward"), "cost_return": nxt.get("event_cost"),
        "si_cost_return": nxt.get("cost"), "steps": torch.ones_like(nxt.get("reward_prime")), "vx_sum": nxt.get("vx"),
    }
    columns = {k: v.reshape(tracker.num_envs, -1).double() for k, v in columns.items()}
    done = nxt.get("done").reshape(tracker.num_envs, -1)
    tracker.total_event_cost += float(columns["cost_return"].sum())
    tracker.total_steps += done.numel()
    ended = []
    for t in range(done.shape[1]):
        for k in tracker.KEYS:
            tracker.sums[k] += columns[k][:, t]
        for i in done[:, t].nonzero().flatten().tolist():
            episode = {k: float(tracker.sums[k][i]) for k in tracker.KEYS}
            episode["vx"] = episode.pop("vx_sum") / max(episode["steps"], 1.0)
            ended.append(episode)
            for k in tracker.KEYS:
                tracker.sums[k][i] = 0.0
    return ended


def test_episode_sums_equal_the_per_key_loop():
    generator = torch.Generator().manual_seed(4)
    ours, reference = EpisodeTracker(12), EpisodeTracker(12)
    for _ in range(3):
        shape = (12, 30, 1)
        batch = TensorDict({"next": {
            "reward_prime": torch.randn(shape, generator=generator), "reward": torch.rand(shape, generator=generator),
            "event_cost": (torch.rand(shape, generator=generator) < 0.05).float(),
            "cost": torch.randn(shape, generator=generator), "vx": 20 + torch.randn(shape, generator=generator),
            "done": torch.rand(shape, generator=generator) < 0.08}}, batch_size=[12, 30])
        assert ours.update(batch) == previous_episode_update(reference, batch)
        assert ours.state()["sums"].keys() == reference.state()["sums"].keys()
        assert all(torch.equal(ours.sums[k], reference.sums[k]) for k in ours.KEYS)
        assert (ours.total_event_cost, ours.total_steps) == (reference.total_event_cost, reference.total_steps)
