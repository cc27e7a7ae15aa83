"""A batched twin of ``srmpc/Highway-v0``: B independent scenes stepped at once by numba kernels.

Modules:
- :mod:`~srmpc.sim.jit_cache`: drops numba's cached machine code when any kernel source changed.
- :mod:`~srmpc.sim.constants`: the scenario's numbers as a numba-friendly named tuple.
- :mod:`~srmpc.sim.state`: the float64 state of B scenes (structure of arrays), snapshot/restore.
- :mod:`~srmpc.sim.random`: a counter-free splitmix64 generator, one stream per scene.
- :mod:`~srmpc.sim.vehicle`: highway-env's kinematic bicycle, action clipping and lane projection.
- :mod:`~srmpc.sim.idm`: IDM vehicles (lane-following steering, IDM acceleration, leader search).
- :mod:`~srmpc.sim.collision`: rotated-rectangle collisions (separating axes, impact transition).
- :mod:`~srmpc.sim.spawning`: initial scenes with highway-env's ``create_random`` distributions.
- :mod:`~srmpc.sim.engine`: one control step of a scene, batched serially or over threads.
- :mod:`~srmpc.sim.simulator`: :class:`TwinSimulator`, the Python face of the engine.
- :mod:`~srmpc.sim.highway_copy`: copy reset ``SrmpcHighwayEnv`` scenes into the twin.
- :mod:`~srmpc.sim.mlp`: a 2x64 tanh MLP policy evaluated in numpy and inside numba kernels.
- :mod:`~srmpc.sim.rollout`: forward rollouts of a policy over H steps (SRMPC's prediction).
- :mod:`~srmpc.sim.torchrl_env`: :class:`TwinHighwayEnv`, a TorchRL ``EnvBase`` with batch [B].
- :mod:`~srmpc.sim.vector_env`: a gymnasium ``VectorEnv`` face.
"""

from srmpc.sim.jit_cache import drop_stale_numba_cache

drop_stale_numba_cache()  # before any kernel module is compiled or loaded from the cache

from srmpc.sim.simulator import StepResult, TwinSimulator  # noqa: E402
from srmpc.sim.state import SceneState  # noqa: E402

__all__ = ["SceneState", "StepResult", "TwinSimulator"]
