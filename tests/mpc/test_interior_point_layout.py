"""Layout of the interior-point solver's modules: every module and function stays short enough to read in one go."""

import ast
from pathlib import Path

import srmpc.mpc.solvers as solvers

MAX_FUNCTION_LINES = 60
"""Longest allowed function, from its ``def`` line to its last line (signature, docstring, body)."""
MAX_MODULE_LINES = 400
"""Longest allowed module of the interior point (docstring and code)."""
INTERIOR_POINT_MODULES = sorted(Path(solvers.__file__).parent.glob("ipm_*.py")) + [
    Path(solvers.__file__).parent / "interior_point.py"]
"""The interior point: the solves (``interior_point``) and its parts (``ipm_*``)."""


def function_lengths(source: str) -> dict[str, int]:
    """Lines of every function (nested ones included) in ``source``, by qualified name."""
    lengths = {}

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = prefix + child.name
                lengths[name] = child.end_lineno - child.lineno + 1
                visit(child, name + ".")
            elif isinstance(child, ast.ClassDef):
                visit(child, prefix + child.name + ".")

    visit(ast.parse(source), "")
    return lengths


def test_no_function_is_longer_than_the_limit():
    lengths = {f"{path.stem}.{name}": n for path in INTERIOR_POINT_MODULES
               for name, n in function_lengths(path.read_text()).items()}
    assert "interior_point.solve_ltv_mpc_qp" in lengths and "ipm_iteration.iterate" in lengths
    too_long = {name: n for name, n in lengths.items() if n > MAX_FUNCTION_LINES}
    assert not too_long, f"functions over {MAX_FUNCTION_LINES} lines: {too_long}"


def test_no_module_is_longer_than_the_limit():
    lines = {path.name: len(path.read_text().splitlines()) for path in INTERIOR_POINT_MODULES}
    assert len(lines) >= 6, lines
    too_long = {name: n for name, n in lines.items() if n > MAX_MODULE_LINES}
    assert not too_long, f"modules over {MAX_MODULE_LINES} lines: {too_long}"


def test_lengths_count_signature_docstring_and_body():
    source = "def f(a,\n      b):\n    '''Doc.'''\n    return a\n\n\ndef g():\n    def h():\n        pass\n"
    assert function_lengths(source) == {"f": 4, "g": 3, "g.h": 2}
