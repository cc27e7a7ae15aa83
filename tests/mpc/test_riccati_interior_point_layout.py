"""Layout of the interior-point solver's module: every function stays short enough to read in one go."""

import ast
from pathlib import Path

import srmpc.mpc.riccati_interior_point as riccati_interior_point

MAX_FUNCTION_LINES = 60
"""Longest allowed function, from its ``def`` line to its last line (signature, docstring, body)."""


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
    lengths = function_lengths(Path(riccati_interior_point.__file__).read_text())
    assert "solve_ltv_mpc_qp" in lengths
    too_long = {name: n for name, n in lengths.items() if n > MAX_FUNCTION_LINES}
    assert not too_long, f"functions over {MAX_FUNCTION_LINES} lines: {too_long}"


def test_lengths_count_signature_docstring_and_body():
    source = "def f(a,\n      b):\n    '''Doc.'''\n    return a\n\n\ndef g():\n    def h():\n        pass\n"
    assert function_lengths(source) == {"f": 4, "g": 3, "g.h": 2}
