"""PPO and PPO-L-SI (PPO with a safety-index cost and a state-dependent Lagrange multiplier) in TorchRL.

- ``networks``: actor (tanh-squashed Gaussian in the action box), critics v(s), v_c(s), multiplier lambda(s);
- ``ppo_lsi_loss``: the LossModule (ClipPPOLoss subclass) with the named loss terms;
- ``hyperparameters``: every training setting (the Hydra schema of ``conf/agent``);
- ``rollout``: the collection of a (B, T) batch (TorchRL's Collector loop, same floats, no per-step TensorDicts);
- ``tanh_normal``: TorchRL's TanhNormal arithmetic on plain tensors (the actor's draws and log-probabilities);
- ``trainer``: collection, GAEs, minibatch SGD, metrics, checkpoints, resume, a per-section profile;
- ``checkpoint``: atomic checkpoint and policy files;
- ``toy_env``: a tiny batched constrained task with the simulator's keys (tests, smoke runs).
"""
