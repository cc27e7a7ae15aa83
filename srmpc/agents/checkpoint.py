"""Checkpoints: everything needed to continue a training run bit for bit on CPU.

A checkpoint holds the networks (the loss module's state dict), the three optimizers, the torch
and shuffling RNG states, the collector's carrier (the current observations of every env), the
simulator's runtime state (if the env exposes ``runtime_state()`` / ``load_runtime_state()``), the
per-env running episode sums, the iteration and frame counters. Files are written atomically
(temporary file + rename), so a crash mid-write leaves the previous checkpoint intact. A file that
cannot be read back (truncated, corrupted, not written by this module) raises :class:`CheckpointError`,
one line naming the path.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np
import torch

from srmpc.errors import FileFault

CHECKPOINT_NAME = "last.pt"
POLICY_NAME = "policy.pt"


class CheckpointError(FileFault):
    """A checkpoint or policy file that cannot be loaded; the message is one line naming the file."""


def _load(path: Path, what: str) -> dict[str, Any]:
    try:
        saved = torch.load(path, weights_only=False)
    except Exception as error:  # noqa: BLE001  (RuntimeError, UnpicklingError, EOFError, OSError EINVAL, ...)
        reason = getattr(error, "strerror", None) or (str(error).splitlines() or [type(error).__name__])[0]
        raise CheckpointError(f"{path}: not a readable {what} (truncated or corrupted? {reason})") from error
    if not isinstance(saved, dict):
        raise CheckpointError(f"{path}: not a {what} (holds a {type(saved).__name__})")
    return saved


def atomic_torch_save(obj: Any, path: Path) -> None:
    """torch.save to ``path`` via a temporary file and rename."""
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(path.name + ".tmp")
    torch.save(obj, temporary)
    os.replace(temporary, path)


def save_checkpoint(state: dict[str, Any], directory: Path) -> Path:
    """Write ``state`` as ``directory/last.pt``; return the path."""
    path = directory / CHECKPOINT_NAME
    atomic_torch_save(state, path)
    return path


def load_checkpoint(directory: Path) -> dict[str, Any] | None:
    """The state of ``directory/last.pt``, or None when there is none."""
    path = directory / CHECKPOINT_NAME
    if not path.exists():
        return None
    return _load(path, "training checkpoint (delete it to start over)")


def save_policy(actor_state: dict[str, torch.Tensor], metadata: dict[str, Any], path: Path) -> None:
    """A small deployable file: the actor's state dict and what is needed to rebuild it."""
    atomic_torch_save({"actor": actor_state, **metadata}, path)


def read_policy_file(path: Path) -> dict[str, Any]:
    """The dict a ``policy.pt`` holds (ours, or ``srmpc.sb3_ppo``'s with ``action_head``); one-line error if not."""
    return _load(path, "policy file")


ACTOR_MEAN_PREFIX = "module.0.module.loc_net."
"""Where our actor's state dict keeps the mean network's ``nn.Linear`` layers (``<index>.weight``, ``.bias``)."""


def load_actor_mean_layers(path: Path) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """The mean network of the actor saved in a ``policy.pt`` by :func:`save_policy`, as float64 (out, in)
    weights and (out,) biases in layer order: what :func:`load_actor` rebuilds, without TorchRL (whose
    import costs every evaluation process about 2 s). One-line :class:`CheckpointError` if it does not fit
    the file's ``observation_dim``, ``hidden_sizes`` and action size."""
    return actor_mean_layers(read_policy_file(path), path)


def actor_mean_layers(saved: dict[str, Any], path: Path) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """:func:`load_actor_mean_layers` of the dict :func:`read_policy_file` already read from ``path``
    (named in the errors)."""
    try:
        state = saved["actor"]
        indices = sorted({int(key[len(ACTOR_MEAN_PREFIX):].split(".")[0]) for key in state
                          if key.startswith(ACTOR_MEAN_PREFIX)})
        weights = [state[f"{ACTOR_MEAN_PREFIX}{i}.weight"].detach().double().numpy() for i in indices]
        biases = [state[f"{ACTOR_MEAN_PREFIX}{i}.bias"].detach().double().numpy() for i in indices]
        sizes = [int(saved["observation_dim"]), *map(int, saved["hidden_sizes"]), int(saved["action_low"].numel())]
    except (KeyError, TypeError, ValueError, AttributeError) as error:
        reason = (str(error).splitlines() or [type(error).__name__])[0]
        raise CheckpointError(f"{path}: not a policy file written by training ({type(error).__name__}: {reason})"
                              ) from error
    shapes = [tuple(w.shape) for w in weights]
    expected = list(zip(sizes[1:], sizes[:-1], strict=True))
    if shapes != expected or [b.shape[0] for b in biases] != sizes[1:]:
        raise CheckpointError(f"{path}: the actor's layers {shapes} do not match its sizes {sizes}")
    return weights, biases


def load_actor(path: Path):
    """Rebuild the actor (a ProbabilisticActor) saved in a ``policy.pt`` by :func:`save_policy`."""
    from srmpc.agents.networks import make_actor

    saved = read_policy_file(path)
    try:
        actor = make_actor(saved["observation_dim"], saved["action_low"], saved["action_high"], saved["hidden_sizes"])
        actor.load_state_dict(saved["actor"])
    except (KeyError, TypeError, ValueError, RuntimeError) as error:
        reason = (str(error).splitlines() or [type(error).__name__])[0]
        raise CheckpointError(f"{path}: not a policy file written by training ({type(error).__name__}: {reason})"
                              ) from error
    return actor
