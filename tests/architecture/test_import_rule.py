"""The import rule (docs/architecture.md, contracts in pyproject.toml) holds, and catches breaks.

The contracts are checked by import-linter on this repository. To show that they would fail,
each case below copies the packages into a temporary folder, adds a forbidden import to the
copy only (never to the package itself), and expects import-linter to name the broken
contract.
"""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

pytest.importorskip("importlinter")

REPO = Path(__file__).resolve().parents[2]
CONFIG = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["importlinter"]
PACKAGES: list[str] = CONFIG["root_packages"]

LAYERS = "Packages import downwards only"
SERVER_NOT_PLAYER = "The study server does not import the participant's player"
READERS = "Readers of results import no player, server, Pygame or OpenGL"
METRIC_ALONE = "The metric reads stimuli only"
NO_CIRCLES = "No import circle inside any package"


def lint(root: Path) -> subprocess.CompletedProcess[str]:
    """import-linter over the packages under ``root`` with the repository's contracts."""
    code = ("import sys; from importlinter.cli import lint_imports; "
            "sys.exit(lint_imports(no_cache=True, no_logo=True))")
    return subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True,
                          text=True, timeout=120, env={"PYTHONPATH": str(root),
                                                       "PATH": "/usr/bin:/bin"})


def broken_contracts(output: str) -> set[str]:
    return {line.rsplit(" BROKEN", 1)[0].strip() for line in output.splitlines()
            if line.rstrip().endswith("BROKEN")}


@pytest.fixture(scope="module")
def package_copy(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("packages")
    for name in PACKAGES:
        shutil.copytree(REPO / name, root / name,
                        ignore=shutil.ignore_patterns("__pycache__", "*.png", "*.ttf"))
    shutil.copy(REPO / "pyproject.toml", root / "pyproject.toml")
    return root


def test_the_repository_keeps_every_contract():
    result = lint(REPO)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "BROKEN" not in result.stdout


def test_the_untouched_copy_keeps_every_contract(package_copy: Path):
    """The cases below are meaningful only if the copy itself passes."""
    result = lint(package_copy)
    assert result.returncode == 0, result.stdout + result.stderr


def _module_file(root: Path, module: str) -> Path:
    path = root.joinpath(*module.split("."))
    return path / "__init__.py" if path.is_dir() else path.with_suffix(".py")


# (what the case stands for, imports added as (importer, imported), contracts that must break)
CASES = [
    ("analysis imports the player (the old study_app <-> analysis cycle)",
     [("analysis.sessions", "study_app.app")], {READERS, LAYERS}),
    ("the player imports the analysis", [("study_app.app", "analysis")], {LAYERS}),
    ("the server imports the player", [("study_server.app", "study_app.trial")],
     {SERVER_NOT_PLAYER}),
    ("the session contract imports the server", [("session_store.reader", "study_server")],
     {READERS, LAYERS}),
    ("the metric imports the session contract", [("cgvqm_core.batch", "session_store")],
     {METRIC_ALONE}),
    ("the manifests import pygame", [("stimuli_manifests.video", "pygame")], {READERS}),
    ("a circle between two manifest modules (the old ids <-> model)",
     [("stimuli_manifests.ids", "stimuli_manifests.model"),
      ("stimuli_manifests.model", "stimuli_manifests.ids")], {NO_CIRCLES}),
    ("a circle in the metric (the old distributed <-> ray_options)",
     [("cgvqm_core.distributed", "cgvqm_core.ray_options"),
      ("cgvqm_core.ray_options", "cgvqm_core.distributed")], {NO_CIRCLES}),
    ("a circle between the metric and its registry (the old batch <-> cgvqm_entry)",
     [("cgvqm_core.batch", "cgvqm_core.metrics.cgvqm_entry"),
      ("cgvqm_core.metrics.cgvqm_entry", "cgvqm_core.batch")], {NO_CIRCLES}),
    ("an upward import in the player (the old layout -> screens.textflow)",
     [("study_app.screens.textflow", "study_app.app"),
      ("study_app.app", "study_app.screens.textflow")], {NO_CIRCLES}),
    ("a circle in the server (the old state <-> dashboard)",
     [("study_server.state", "study_server.dashboard"),
      ("study_server.dashboard", "study_server.state")], {NO_CIRCLES}),
    ("a circle in the analysis (the old outliers -> screening -> scores -> outliers)",
     [("analysis.scores", "analysis.report"), ("analysis.report", "analysis.scores")],
     {NO_CIRCLES}),
]


@pytest.mark.parametrize(("added", "expected"), [(c[1], c[2]) for c in CASES],
                         ids=[c[0] for c in CASES])
def test_a_forbidden_import_breaks_the_rule(package_copy: Path,
                                            added: list[tuple[str, str]], expected: set[str]):
    originals: dict[Path, str] = {}
    try:
        for importer, imported in added:
            path = _module_file(package_copy, importer)
            assert path.is_file(), f"{importer} no longer exists: update this case"
            originals.setdefault(path, path.read_text())
            path.write_text(path.read_text() + f"\nimport {imported}  # added by the test\n")
        result = lint(package_copy)
    finally:
        for path, text in originals.items():
            path.write_text(text)
    assert result.returncode != 0, result.stdout
    broken = broken_contracts(result.stdout)
    for contract in expected:
        assert any(b.startswith(contract) for b in broken), (contract, broken, result.stdout)


def test_the_architecture_page_states_the_same_layers():
    """docs/architecture.md shows the layer contract as it is configured."""
    page = (REPO / "docs" / "architecture.md").read_text()
    block = re.search(r"```layers\n(.*?)```", page, re.S)
    assert block, "docs/architecture.md needs a ```layers block"
    stated = [line.strip() for line in block.group(1).splitlines() if line.strip()]
    layers = next(c for c in CONFIG["contracts"] if c["id"] == "layers")["layers"]
    assert stated == layers
