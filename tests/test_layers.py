"""The package's layers: every ``srmpc`` import runs down the floors (or within one room), never up.

Floors, from the ground up, in the order data flows through them (docs/layout.md):

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
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "srmpc"

FLOOR = {
    "__init__": 0, "errors": 0, "value_checks": 0, "confidence_intervals": 0, "metrics": 0, "output_lock": 0,
    "scenario": 1,
    "sim": 2,
    "agents": 3, "mpc": 3,
    "controllers": 4, "sb3_ppo": 4,
    "episode_loop": 5, "video": 5, "result_table": 5,
    "config": 6, "output_folder": 6,
    "sweep": 7, "controller_factory": 7, "tracking": 7,
    "stages": 8,
    "__main__": 9,
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
