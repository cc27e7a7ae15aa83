"""PPO-L-SI loss: clipped PPO with a cost critic and a state-dependent Lagrange multiplier lambda(s).

Paper eq. (lagrangian2): L(pi, lambda) = E_s[-v_pi(s) + lambda(s) v_pi^c(s)], minimised over the
policy and maximised over lambda(s) >= 0. In PPO form, per sampled state s_t with action a_t,
ratio rho_t = pi(a_t|s_t) / pi_old(a_t|s_t), reward advantage A_t and cost advantage A^c_t (two
GAEs over the same batch):

    g_r(t) = min(rho_t A_t, clip(rho_t, 1-eps, 1+eps) A_t)          clipped reward surrogate (max)
    g_c(t) = max(rho_t A^c_t, clip(rho_t, 1-eps, 1+eps) A^c_t)      clipped cost surrogate (min;
                                                                    pessimistic like g_r)
    lam_t  = stop_grad(lambda(s_t))
    loss_objective   = mean_t[ -(g_r(t) - lam_t g_c(t)) / (1 + lam_t) ]
    loss_critic      = mean_t[ (v(s_t) - R_t)^2 ]                     R_t: reward GAE target
    loss_cost_critic = mean_t[ (v_c(s_t) - R^c_t)^2 ]                 R^c_t: cost GAE target
    violation_t      = v_c(s_t) - d,   divided by its minibatch std with ``violation_normalization``
    loss_multiplier  = -mean_t[ lambda(s_t) * stop_grad(clip(violation_t, -clip_low, clip_high)) ]
    loss_entropy     = -entropy_coeff * mean_t[ H(pi(.|s_t)) ]

With ``multiplier_loss_on_logit`` the multiplier loss is taken on the pre-softplus logit z(s) instead,
-mean(z(s) * violation), with the gradient stopped where z(s) is already at its bounds in the pushed
direction (z <= LOGIT_FLOOR and satisfied, lambda >= lambda_max and violated). The fixed points are
the same; the step no longer shrinks by sigmoid(z) = dlambda/dz, which is ~0.02 at lambda = 0.02, so
states whose lambda has collapsed to ~0 can rise again as fast as any other.

With ``violation_normalization`` (Ma et al.'s Safety_Index_Synthesis) the violation is divided by
its standard deviation over the minibatch before the clip, so the step of lambda(s) does not depend on
the units or the spread of v_c; the clip then bounds it in standard deviations.

The multiplier loss is Feasible Actor-Critic's (Ma et al. 2021) dual ascent on the state-wise
constraint v_c(s) <= d: gradient descent on it raises lambda(s) where the constraint is violated
(v_c(s) > d) and lowers it where it holds, until softplus drives it to ~0 (inactive constraint) or
the cap lambda_max (the paper's "infinite" multiplier: an infeasible state). The division by
1 + lam_t (as in PPO-Lagrangian implementations) keeps the policy-gradient scale bounded when
lambda is large. The reward advantage is standardised per minibatch; the cost advantage is only
centred, so that lambda keeps the cost's units. With ``constrained=False`` the module is plain
clipped PPO (loss_objective = mean(-g_r)); no cost critic or multiplier is needed.

Gradient routing: loss_objective and loss_entropy reach only the actor (advantages and lambda are
detached), loss_critic only v, loss_cost_critic only v_c, loss_multiplier only lambda(s).
"""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.utils import distance_loss
from torchrl.objectives.value import GAE
from torchrl.objectives.value.functional import generalized_advantage_estimate

from srmpc.agents import tanh_normal
from srmpc.agents.networks import ACTION_KEY, COST_VALUE_KEY, LOG_PROB_KEY, OBSERVATION_KEY, VALUE_KEY

COST_KEY = "cost"
COST_ADVANTAGE_KEY = "cost_advantage"
COST_VALUE_TARGET_KEY = "cost_value_target"
LOGIT_FLOOR = -5.0
"""Lower bound of the multiplier logit under ``multiplier_loss_on_logit`` (softplus(-5) = 0.0067)."""


def pearson(x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Pearson correlation of two 1-D tensors (0 where either is constant)."""
    x, y = x - x.mean(), y - y.mean()
    denominator = (x.pow(2).sum() * y.pow(2).sum()).sqrt()
    return torch.where(denominator > 0, (x * y).sum() / denominator.clamp_min(1e-30), torch.zeros_like(denominator))


ROW_BLOCK = 256
"""The critics' input rows in the GAE are padded to a multiple of this (see :func:`critic_inputs`)."""


def critic_inputs(observation: torch.Tensor, next_observation: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The states a critic must see for v(s_t) and v(s_{t+1}) of a (B, T) batch, each once.

    Returns ``rows``: the B T observations, then the next observations that are not the next
    row's observation (bitwise), then zero rows up to a multiple of :data:`ROW_BLOCK`; and
    ``elsewhere`` (B, T) bool marking those next observations: every last step, and the steps where
    the episode ended (the next observation is the terminal one, the next row the new episode's
    first). The padding is there because a matrix product's last M mod 4 rows go through another
    kernel (MKL's sgemm on this CPU: they can differ in the last bit from the same row inside a
    block), while the GAE modules' products (M = 2 B T) have no such tail.
    """
    elsewhere = torch.ones(next_observation.shape[:-1], dtype=torch.bool)
    elsewhere[:, :-1] = (next_observation[:, :-1] != observation[:, 1:]).any(-1)
    extra = next_observation[elsewhere]
    padding = extra.new_zeros((-(elsewhere.numel() + extra.shape[0]) % ROW_BLOCK, extra.shape[-1]))
    rows = torch.cat([observation.reshape(-1, observation.shape[-1]), extra, padding])
    return rows, elsewhere


def split_values(values: torch.Tensor, shape: torch.Size, elsewhere: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """(v(s_t), v(s_{t+1})), each (B, T, 1), from a critic's output on :func:`critic_inputs`' rows."""
    count = shape.numel()
    value = values[:count].reshape(*shape, -1)
    next_value = torch.empty_like(value)
    next_value[:, :-1] = value[:, 1:]
    next_value[elsewhere] = values[count:count + int(elsewhere.sum())]
    return value, next_value


class PPOLSILoss(ClipPPOLoss):
    """Clipped PPO (``constrained=False``) or PPO-L-SI (``constrained=True``).

    Args:
        actor_network: ProbabilisticActor writing ``action`` / ``action_log_prob``.
        critic_network: reward critic writing ``state_value``.
        cost_critic_network: cost critic writing ``cost_value`` (required when constrained).
        multiplier_network: lambda(s) writing ``lambda`` (required when constrained).
        constrained: PPO-L-SI when True, PPO when False.
        clip_epsilon: PPO ratio clip eps.
        entropy_coeff: weight of the entropy bonus.
        gamma, gae_lambda: discount and GAE lambda of the reward advantage.
        cost_gamma: discount gamma_c of the cost advantage (same GAE lambda).
        cost_threshold: d of the state-wise constraint v_c(s) <= d.
        violation_clip: (low, high): v_c(s) - d is clipped to [-low, high] in the multiplier loss,
            which bounds how fast lambda(s) falls on safe states and rises on unsafe ones.
        lambda_max: cap of lambda(s) (for the share-at-cap diagnostic; the network applies it).
        samples_mc_entropy: Monte-Carlo samples for the entropy (TanhNormal has no closed form).
        multiplier_loss_on_logit: take the multiplier loss on the pre-softplus logit (see module doc).
        violation_normalization: divide v_c(s) - d by its minibatch std before the clip (Ma et al.).
    """

    def __init__(
        self,
        actor_network: TensorDictModule,
        critic_network: TensorDictModule,
        cost_critic_network: TensorDictModule | None = None,
        multiplier_network: TensorDictModule | None = None,
        *,
        constrained: bool = True,
        clip_epsilon: float = 0.2,
        entropy_coeff: float = 0.0,
        gamma: float = 0.99,
        gae_lambda: float = 0.95,
        cost_gamma: float = 0.99,
        cost_threshold: float = 0.0,
        violation_clip: tuple[float, float] = (0.3, 100.0),
        lambda_max: float = 50.0,
        samples_mc_entropy: int = 1,
        multiplier_loss_on_logit: bool = False,
        violation_normalization: bool = False,
    ) -> None:
        super().__init__(
            actor_network, critic_network, clip_epsilon=clip_epsilon, entropy_bonus=True,
            entropy_coeff=entropy_coeff, samples_mc_entropy=samples_mc_entropy, critic_coeff=1.0,
            loss_critic_type="l2", normalize_advantage=False,
        )
        self.set_keys(sample_log_prob=LOG_PROB_KEY, value=VALUE_KEY)
        self.actor_box = tanh_normal.actor_box(actor_network)
        """(c, h) of the TanhNormal actor's box (:mod:`srmpc.agents.tanh_normal`), None for another actor."""
        self.make_value_estimator(gamma=gamma, lmbda=gae_lambda)  # GAE (TorchRL default estimator)
        self.constrained = constrained
        self.cost_threshold = cost_threshold
        self.violation_clip = violation_clip
        self.lambda_max = lambda_max
        self.multiplier_loss_on_logit = multiplier_loss_on_logit
        self.violation_normalization = violation_normalization
        if constrained:
            if cost_critic_network is None or multiplier_network is None:
                raise ValueError("constrained=True needs cost_critic_network and multiplier_network")
            self.cost_critic_network = cost_critic_network
            self.multiplier_network = multiplier_network
            # Second GAE over the cost signal: reads ("next", "cost"), writes cost_advantage / cost_value_target.
            self.cost_value_estimator = GAE(gamma=cost_gamma, lmbda=gae_lambda, value_network=cost_critic_network)
            self.cost_value_estimator.set_keys(
                reward=COST_KEY, value=COST_VALUE_KEY, advantage=COST_ADVANTAGE_KEY,
                value_target=COST_VALUE_TARGET_KEY,
            )

    @property
    def out_keys(self) -> list[str]:
        keys = ["loss_objective", "loss_critic", "loss_entropy", "entropy", "clip_fraction", "kl_approx"]
        if self.constrained:
            keys += ["loss_cost_critic", "loss_multiplier", "lambda_mean", "lambda_max", "lambda_share_at_max",
                     "violation_share", "lambda_cost_value_corr"]
        return keys

    @out_keys.setter
    def out_keys(self, values) -> None:  # ClipPPOLoss's constructor assigns it
        pass

    @torch.no_grad()
    def compute_advantages(self, batch: TensorDictBase) -> TensorDictBase:
        """Write advantage / value_target (reward GAE) and, if constrained, the cost ones, in place.

        The same floats as calling TorchRL's ``GAE`` modules (``self.value_estimator``,
        ``self.cost_value_estimator``) on the (B, T) batch, without their TensorDict plumbing and
        without evaluating a critic twice on one state: v(s_{t+1}) is v(s_{t+1}) of the next row of
        the batch wherever the next observation is that row's observation (bit for bit), and each
        critic runs once on the observations plus the other next observations (at the batch's last
        step and where an episode ended; :func:`critic_inputs`). A matrix product's row does not
        depend on the other rows, so these values are those of the GAE modules, which run each
        critic on all of s_t and all of s_{t+1}. TorchRL's own ``generalized_advantage_estimate``
        then runs the recursion over t (A_t = delta_t + gamma lambda (1 - done_t) A_{t+1},
        delta_t = r_t + gamma (1 - terminated_t) v(s_{t+1}) - v(s_t)) with the modules' gamma and lambda.
        """
        nxt = batch.get("next")
        observation, next_observation = batch.get(OBSERVATION_KEY), nxt.get(OBSERVATION_KEY)
        rows, elsewhere = critic_inputs(observation, next_observation)
        done, terminated = nxt.get("done"), nxt.get("terminated")
        estimators = [(self.value_estimator, self.critic_network, "reward", VALUE_KEY, self.tensor_keys.advantage,
                       self.tensor_keys.value_target)]
        if self.constrained:
            estimators.append((self.cost_value_estimator, self.cost_critic_network, COST_KEY, COST_VALUE_KEY,
                               COST_ADVANTAGE_KEY, COST_VALUE_TARGET_KEY))
        for estimator, critic, reward_key, value_key, advantage_key, target_key in estimators:
            value, next_value = split_values(critic.module(rows), observation.shape[:-1], elsewhere)
            advantage, value_target = generalized_advantage_estimate(
                estimator.gamma, estimator.lmbda, value, next_value, nxt.get(reward_key), done=done,
                terminated=terminated, time_dim=batch.ndim - 1)
            batch.set(value_key, value)
            nxt.set(value_key, next_value)
            batch.set(advantage_key, advantage)
            batch.set(target_key, value_target)
        return batch

    @property
    def training_keys(self) -> tuple[str, ...]:
        """The batch entries a minibatch needs, in :meth:`loss_terms`'s argument order."""
        keys = (OBSERVATION_KEY, ACTION_KEY, LOG_PROB_KEY, self.tensor_keys.advantage, self.tensor_keys.value_target)
        return keys + ((COST_ADVANTAGE_KEY, COST_VALUE_TARGET_KEY) if self.constrained else ())

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        return TensorDict(self.loss_terms(*(tensordict.get(key) for key in self.training_keys)), batch_size=[])

    @torch.no_grad()
    def multiplier_logits(self, observation: torch.Tensor) -> torch.Tensor:
        """z(s) (N, 1) of every row of ``observation`` (N, obs_dim), without autograd.

        The rows are padded to a multiple of :data:`ROW_BLOCK` (see :func:`critic_inputs`), so each
        z(s) is the one a minibatch's forward pass computes when the minibatch size is a multiple
        of :data:`ROW_BLOCK`.
        """
        padding = -observation.shape[0] % ROW_BLOCK
        rows = (torch.cat([observation, observation.new_zeros(padding, observation.shape[-1])]) if padding
                else observation)
        return self.multiplier_network.module.logit(rows)[:observation.shape[0]]

    def loss_terms(self, observation: torch.Tensor, action: torch.Tensor, sample_log_prob: torch.Tensor,
                   advantage: torch.Tensor, value_target: torch.Tensor, cost_advantage: torch.Tensor | None = None,
                   cost_value_target: torch.Tensor | None = None, *, multiplier_grad: bool = True,
                   multiplier_logit: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """Loss terms and diagnostics of one minibatch of N samples, on plain tensors.

        ``observation`` (N, obs_dim), ``action`` (N, 2), ``sample_log_prob`` (N,), the rest (N, 1).
        The same operations as ``ClipPPOLoss`` on a TensorDict (``_log_weight``, ``_get_entropy``,
        ``loss_critic``): the actor head, ``TanhNormal``'s log-probability of the stored action and
        TorchRL's entropy estimate (for a TanhNormal actor their arithmetic alone,
        :mod:`srmpc.agents.tanh_normal`) on the networks' own modules, whose parameters are the loss
        module's. Nothing is computed that no gradient or diagnostic reads: with ``entropy_coeff``
        0 the entropy (a Monte-Carlo estimate for TanhNormal, still drawn from torch's generator)
        is a diagnostic only and runs without autograd, and with ``multiplier_grad=False``
        (the iterations and minibatches where lambda(s) takes no step) so does lambda(s).
        ``multiplier_logit`` (N, 1): z(s) of these states, already computed
        (:meth:`multiplier_logits`, for the minibatches after lambda(s)'s last step of an iteration);
        only without ``multiplier_grad``.
        """
        if multiplier_logit is not None and multiplier_grad:
            raise ValueError("multiplier_logit is given: lambda(s) cannot take a gradient")
        advantage = (advantage - advantage.mean()) / advantage.std().clamp_min(1e-8)
        adv_shape = advantage.shape[:-1]
        head, probabilistic = self.actor_network.module[0], self.actor_network.module[-1]
        loc, scale = head.module(observation)
        if self.actor_box is not None:
            log_prob = tanh_normal.log_prob(action, loc, scale, *self.actor_box)
        else:
            dist = probabilistic.distribution_class(loc=loc, scale=scale, **probabilistic.distribution_kwargs)
            log_prob = dist.log_prob(action)
        log_weight = (log_prob - sample_log_prob).unsqueeze(-1)
        kl_approx = (sample_log_prob - log_prob).unsqueeze(-1)
        ratio = log_weight.exp()
        clipped_ratio = log_weight.clamp(*self._clip_bounds).exp()
        gain_reward = torch.minimum(ratio * advantage, clipped_ratio * advantage)

        out = {}
        if self.constrained:
            cost_advantage = cost_advantage - cost_advantage.mean()
            gain_cost = torch.maximum(ratio * cost_advantage, clipped_ratio * cost_advantage)
            with torch.set_grad_enabled(multiplier_grad and torch.is_grad_enabled()):
                logit = (self.multiplier_network.module.logit(observation) if multiplier_logit is None
                         else multiplier_logit)
                multiplier = torch.nn.functional.softplus(logit).clamp(max=self.lambda_max)
            lam = multiplier.detach()
            out["loss_objective"] = (-(gain_reward - lam * gain_cost) / (1.0 + lam)).mean()

            cost_value = self.cost_critic_network.module(observation)
            out["loss_cost_critic"] = (cost_value - cost_value_target).pow(2).mean()
            violation = cost_value.detach() - self.cost_threshold
            if self.violation_normalization:
                violation = violation / violation.std().clamp_min(1e-8)
            violation = violation.clamp(-self.violation_clip[0], self.violation_clip[1])
            with torch.set_grad_enabled(multiplier_grad and torch.is_grad_enabled()):
                if self.multiplier_loss_on_logit:
                    at_bound = ((logit <= LOGIT_FLOOR) & (violation < 0)) | ((lam >= self.lambda_max) & (violation > 0))
                    out["loss_multiplier"] = -(torch.where(at_bound, logit.detach(), logit) * violation).mean()
                else:
                    out["loss_multiplier"] = -(multiplier * violation).mean()
            out["lambda_mean"] = lam.mean()
            out["lambda_max"] = lam.max()
            out["lambda_share_at_max"] = (lam >= self.lambda_max * (1.0 - 1e-6)).float().mean()
            out["violation_share"] = (violation > 0).float().mean()
            out["lambda_cost_value_corr"] = pearson(lam.flatten(), cost_value.detach().flatten())
        else:
            out["loss_objective"] = (-gain_reward).mean()

        with torch.set_grad_enabled(bool(self.entropy_coeff != 0) and torch.is_grad_enabled()):
            if self.actor_box is not None:  # _get_entropy's Monte-Carlo estimate -E[log pi(a)]
                _, sample_log_prob = tanh_normal.rsample_and_log_prob(
                    loc, scale, *self.actor_box, torch.Size([self.samples_mc_entropy]))
                entropy = (-sample_log_prob.mean(0)).unsqueeze(-1)
            else:
                entropy = self._get_entropy(dist, adv_shape=adv_shape)
        out["entropy"] = entropy.detach().mean()
        out["loss_entropy"] = self._weighted_loss_entropy(entropy).mean()
        state_value = self.critic_network.module(observation)
        out["loss_critic"] = (self.critic_coeff * distance_loss(value_target, state_value,
                                                                loss_function=self.loss_critic_type)).mean()
        out["clip_fraction"] = (log_weight.detach().clamp(*self._clip_bounds) != log_weight.detach()).float().mean()
        out["kl_approx"] = kl_approx.detach().mean()
        return out
