"""The analysis package stays readable: modules share only public names, never import the
package's ``__init__``, and a long function says why it is long."""

from __future__ import annotations

import ast
from pathlib import Path

import analysis

PACKAGE = Path(analysis.__file__).parent
MAX_LINES = 80
REASON = "Long on purpose"


def _modules() -> list[tuple[str, ast.Module]]:
    return [(str(p.relative_to(PACKAGE.parent)), ast.parse(p.read_text(encoding="utf-8")))
            for p in sorted(PACKAGE.rglob("*.py"))]


def test_no_private_name_is_imported_across_modules() -> None:
    found = [f"{path}:{node.lineno} {alias.name}"
             for path, tree in _modules() for node in ast.walk(tree)
             if isinstance(node, ast.ImportFrom)
             for alias in node.names
             if alias.name.startswith("_") and not alias.name.startswith("__")]
    assert found == []


def test_no_module_imports_the_package_init() -> None:
    found = [f"{path}:{node.lineno}"
             for path, tree in _modules() if not path.endswith("__init__.py")
             for node in ast.walk(tree) if isinstance(node, ast.ImportFrom)
             if (node.level and node.module is None)
             or (node.level == 0 and node.module == "analysis")]
    assert found == []


def test_long_functions_say_why() -> None:
    found = [f"{path}:{node.lineno} {node.name} ({node.end_lineno - node.lineno + 1} lines)"
             for path, tree in _modules() for node in ast.walk(tree)
             if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
             and node.end_lineno - node.lineno + 1 > MAX_LINES
             and REASON not in (ast.get_docstring(node) or "")]
    assert found == []


def test_the_package_names_load_when_used_and_each_resolves() -> None:
    """``import analysis`` stays light (the study server reads its thresholds without the
    statistics stack); every public name still resolves to its module's object."""
    import importlib
    import subprocess
    import sys

    assert set(analysis.__all__) - {"__version__"} == set(analysis._EXPORTS)
    for name, module in analysis._EXPORTS.items():
        defining = importlib.import_module(module, "analysis")
        assert getattr(analysis, name) is getattr(defining, name), name
    probe = ("import sys, analysis, analysis.thresholds; "
             "print(sorted(m for m in ('pandas', 'scipy', 'pingouin', 'matplotlib') "
             "if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         check=True, cwd=PACKAGE.parent)
    assert out.stdout.strip() == "[]"
