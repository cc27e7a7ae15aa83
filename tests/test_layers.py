"""The package's layers: every ``srmpc`` import runs down the floors (or within one room), never up.

Floors, from the ground up, in the order data flows through them (docs/layout.md):

-2. ``pinned_kernels``: torch's MKL ops rerouted to NumPy, which ``numerics`` registers under the pin
-1. ``numerics``: the numeric environment, which the package root applies before it imports anything else
0. ground: ``errors``, ``value_checks``, ``confidence_intervals``, ``metrics``, ``output_lock``, the package root
1. ``scenario``: the highway scenario (parameters, reward, safety index, observation, highway-env env)
2. ``sim``: the numba twin of the scenario
3. ``agents`` (PPO, PPO-L-SI) and ``mpc`` (the LTV-MPC QP and planner), side by side: neither imports the other
4. ``controllers``: policies and planners as closed-loop controllers (SRMPC among them), and beside them
   ``sb3_ppo``: Stable-Baselines3's PPO on the twin, the peer of ``agents``' PPO (it uses agents' parts)
5. ``episode_loop``, ``video``, ``result_table``: episodes of a controller, their records
6. ``config``: the typed schema and its composition, on top of what it composes, and beside it
   ``output_folder``: a run's files (the episodes CSV schema, the atomic write)
7. ``sweep``: Hydra multirun jobs (their directories, their MLflow parent), and beside it
   ``controller_factory``: the env and the controller a composed config names (stages, figures, benchmarks),
   and ``tracking``: MLflow runs, tagged and named from the composed config (the planner's defaults)
8. ``stages``: what an entry point runs (evaluate, train)
9. ``__main__``: the entry point

A module may import from its own room (package) and from any lower floor. Imports inside functions count.

Inside ``mpc`` the same holds for its rooms, from the ground up: ``problem`` (the OCP and its QP), ``solvers``
(the QP solvers), the planner (``planner``, ``compiled_step``: the modules at ``mpc``'s root), ``nmpc`` (the SQP
and its references), and the package's face ``srmpc.mpc``. A module outside a room imports it through its face
(``srmpc.mpc.problem``, not ``srmpc.mpc.problem.ocp``) and only the names the face exports (``__all__``); the
optional modules that need ``casadi`` (``solvers.hpipm_reference``, ``nmpc.casadi_reference``) are imported by
no other room.

No module imports another module's private (underscore) name: what another module needs is public, and
documented, in the module that owns it.
"""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "srmpc"

FLOOR = {
    "__init__": 0, "errors": 0, "value_checks": 0, "confidence_intervals": 0, "metrics": 0, "output_lock": 0,
    "numerics": -1, "pinned_kernels": -2,
    "scenario": 1,
    "sim": 2,
    "agents": 3, "mpc": 3,
    "controllers": 4, "sb3_ppo": 4,
    "episode_loop": 5, "video": 5, "result_table": 5,
    "config": 6, "output_folder": 6,
    "sweep": 7, "controller_factory": 7, "tracking": 7, "fanout": 7,
    "stages": 8,
    "__main__": 9, "precompile": 9,
}


def room_of(module: str) -> str:
    """``srmpc.sim.idm`` -> ``sim``; ``srmpc`` -> ``__init__``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def imports_of(path: Path) -> list[tuple[int, str]]:
    """(line, imported srmpc module) for every import statement in ``path``."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [node.module]
        elif isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        else:
            continue
        found += [(node.lineno, name) for name in names if name == "srmpc" or name.startswith("srmpc.")]
    return found


def modules() -> list[tuple[str, Path]]:
    return [(room_of("srmpc." + ".".join(p.relative_to(PACKAGE).with_suffix("").parts)), p)
            for p in sorted(PACKAGE.rglob("*.py"))]


def test_every_module_has_a_floor():
    rooms = {room for room, _ in modules()}
    assert rooms <= set(FLOOR), f"modules without a floor in this test: {sorted(rooms - set(FLOOR))}"
    # the walk found every room, sub-packages' modules included, and FLOOR names no room that is gone
    assert rooms == set(FLOOR), f"floors without a module: {sorted(set(FLOOR) - rooms)}"
    paths = {path for _, path in modules()}
    assert {PACKAGE / "__main__.py", PACKAGE / "sim" / "idm.py", PACKAGE / "config" / "schema.py"} <= paths


def test_no_import_runs_up_or_sideways():
    violations = []
    for room, path in modules():
        for line, imported in imports_of(path):
            target = room_of(imported)
            if target == room and room != "__init__":
                continue
            if target not in FLOOR:
                violations.append(f"{path.relative_to(PACKAGE.parent)}:{line} imports {imported}: no such room")
            elif FLOOR[target] >= FLOOR[room] and not (target == "__init__" and room != "__init__"):
                violations.append(f"{path.relative_to(PACKAGE.parent)}:{line}: {room} (floor {FLOOR[room]}) "
                                  f"imports {imported} (floor {FLOOR[target]})")
    assert not violations, "\n".join(violations)


def test_the_check_sees_an_upward_import(tmp_path):
    """The walk reads imports inside functions too (a config import hidden in a scenario function)."""
    source = tmp_path / "m.py"
    source.write_text("def f():\n    from srmpc.config.schema import Config\n    import srmpc.sim.idm\n")
    assert imports_of(source) == [(2, "srmpc.config.schema"), (3, "srmpc.sim.idm")]
    assert FLOOR[room_of("srmpc.config.schema")] > FLOOR["scenario"]


MPC_FLOOR = {"problem": 0, "solvers": 1, "planner": 2, "nmpc": 3, "__init__": 4}
"""``mpc``'s rooms from the ground up: its sub-packages, the planner (the modules at ``mpc``'s root) and its face."""
MPC_ROOMS = ("problem", "solvers", "nmpc")
"""The sub-packages, each with a face (``__init__`` with ``__all__``)."""


def mpc_room_of(module: str) -> str:
    """``srmpc.mpc.solvers.ipm_start`` -> ``solvers``; ``srmpc.mpc.compiled_step`` -> ``planner``; ``srmpc.mpc``
    -> ``__init__``."""
    parts = module.split(".")
    if len(parts) == 2:
        return "__init__"
    return parts[2] if parts[2] in MPC_ROOMS else "planner"


def from_imports_of(path: Path) -> list[tuple[int, str, list[str]]]:
    """(line, srmpc module, imported names) for every ``from srmpc... import`` in ``path``."""
    return [(node.lineno, node.module, [alias.name for alias in node.names])
            for node in ast.walk(ast.parse(path.read_text(), filename=str(path)))
            if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module
            and (node.module == "srmpc" or node.module.startswith("srmpc."))]


def module_name(path: Path) -> str:
    parts = ("srmpc",) + path.relative_to(PACKAGE).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def test_mpc_rooms_import_down():
    violations = []
    for room, path in modules():
        if room != "mpc":
            continue
        own = mpc_room_of(module_name(path))
        for line, imported in imports_of(path):
            if room_of(imported) != "mpc":
                continue
            target = mpc_room_of(imported)
            if target != own and MPC_FLOOR[target] >= MPC_FLOOR[own]:
                violations.append(f"{path.relative_to(PACKAGE.parent)}:{line}: mpc's {own} (floor {MPC_FLOOR[own]}) "
                                  f"imports {imported} (floor {MPC_FLOOR[target]})")
    assert not violations, "\n".join(violations)


def test_mpc_rooms_are_entered_through_their_faces():
    faces = {room: set(importlib.import_module(f"srmpc.mpc.{room}").__all__) for room in MPC_ROOMS}
    violations = []
    for _, path in modules():
        own = module_name(path)
        for line, imported, names in from_imports_of(path):
            if room_of(imported) != "mpc" or mpc_room_of(imported) not in MPC_ROOMS:
                continue
            room = mpc_room_of(imported)
            if own.startswith(f"srmpc.mpc.{room}.") or own == f"srmpc.mpc.{room}":
                continue
            where = f"{path.relative_to(PACKAGE.parent)}:{line}"
            if imported != f"srmpc.mpc.{room}":
                violations.append(f"{where} imports {imported}: enter mpc's {room} through srmpc.mpc.{room}")
            violations += [f"{where} imports {name} from srmpc.mpc.{room}, which does not export it"
                           for name in names if name not in faces[room]]
    assert not violations, "\n".join(violations)


def private_imports(path: Path) -> list[str]:
    """``from srmpc.x import _name`` in ``path`` (a dunder is not private)."""
    return [f"{line}: {name} from {imported}" for line, imported, names in from_imports_of(path)
            for name in names if name.startswith("_") and not name.startswith("__")]


def test_no_module_imports_a_private_name():
    violations = [f"{path.relative_to(PACKAGE.parent)}:{found}" for _, path in modules()
                  for found in private_imports(path)]
    assert not violations, "\n".join(violations)


def test_the_checks_see_a_private_name_and_a_face_bypass(tmp_path):
    source = tmp_path / "m.py"
    source.write_text("from srmpc.mpc.solvers.ipm_workspace import _Hidden, qp_tuple\n"
                      "def f():\n    from srmpc.mpc.problem import __all__, _private\n")
    assert private_imports(source) == ["1: _Hidden from srmpc.mpc.solvers.ipm_workspace",
                                       "3: _private from srmpc.mpc.problem"]
    assert [(imported, mpc_room_of(imported)) for _, imported, _ in from_imports_of(source)] == [
        ("srmpc.mpc.solvers.ipm_workspace", "solvers"), ("srmpc.mpc.problem", "problem")]
    assert MPC_FLOOR["problem"] < MPC_FLOOR["solvers"] < MPC_FLOOR[mpc_room_of("srmpc.mpc.planner")] < MPC_FLOOR["nmpc"]
