"""The trained actor as a controller: numpy mode equals the torch actor's deterministic action."""

import numpy as np
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from srmpc.agents.networks import make_actor
from srmpc.controllers.policy import PolicyController
from srmpc.sim.mlp import MlpPolicy

LOW, HIGH = np.array([-0.1, -5.0]), np.array([0.1, 5.0])


def test_numpy_policy_equals_torch_deterministic_action():
    torch.manual_seed(0)
    actor = make_actor(30, torch.tensor(LOW, dtype=torch.float32), torch.tensor(HIGH, dtype=torch.float32), [64, 64])
    for parameter in actor.parameters():  # move away from the near-zero initial head
        parameter.data.add_(0.3 * torch.randn_like(parameter))
    observations = torch.randn(64, 30)
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        expected = actor(TensorDict({"observation": observations}, batch_size=[64]))["action"].double().numpy()
    controller = PolicyController(MlpPolicy.from_torch(actor, squash=True, action_low=LOW, action_high=HIGH))
    got = np.stack([controller.act(o) for o in observations.double().numpy()])
    np.testing.assert_allclose(got, expected, atol=1e-5)
    assert np.all(got >= LOW) and np.all(got <= HIGH)
