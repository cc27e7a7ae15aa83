"""The trained actor as a controller: numpy mode equals the torch actor's deterministic action."""

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from srmpc.agents.checkpoint import CheckpointError, save_policy
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


def test_a_policy_file_loads_without_torchrl_to_the_same_weights(tmp_path):
    """``from_policy_file`` reads the mean network from the state dict: bit for bit the layers of the
    rebuilt TorchRL actor; sizes that do not fit the layers are a one-line error naming the file."""
    torch.manual_seed(1)
    low, high = torch.tensor(LOW, dtype=torch.float32), torch.tensor(HIGH, dtype=torch.float32)
    actor = make_actor(30, low, high, [16, 8])
    metadata = {"observation_dim": 30, "action_low": low, "action_high": high, "hidden_sizes": [16, 8]}
    save_policy(actor.state_dict(), metadata, tmp_path / "policy.pt")
    loaded = PolicyController.from_policy_file(tmp_path / "policy.pt", LOW, HIGH).policy
    rebuilt = MlpPolicy.from_torch(actor, squash=True, action_low=LOW, action_high=HIGH)
    assert [w.shape for w in loaded.weights] == [(16, 30), (8, 16), (2, 8)]
    for got, expected in zip(loaded.weights + loaded.biases, rebuilt.weights + rebuilt.biases, strict=True):
        assert np.array_equal(got, expected)
    assert loaded.squash
    save_policy(actor.state_dict(), {**metadata, "hidden_sizes": [16, 16]}, tmp_path / "wrong.pt")
    mismatch = r"wrong.pt: the actor's layers .* do not match its sizes \[30, 16, 16, 2\]"
    with pytest.raises(CheckpointError, match=mismatch):
        PolicyController.from_policy_file(tmp_path / "wrong.pt", LOW, HIGH)
