"""The architecture's import rules: estimator/ runs on real recordings, so it imports
neither the simulator nor the bench; the simulator does not import the bench."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]

# package -> top-level packages of this repository it must never import
FORBIDDEN = {"estimator": {"sim", "scenarios"}, "sim": {"scenarios"}}


def imported_packages(path: Path) -> set[str]:
    """Top-level names of every import in a module, at any depth (functions included)."""
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            names.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def test_imported_packages_sees_imports_inside_functions(tmp_path):
    mod = tmp_path / "m.py"
    mod.write_text("import os\ndef f():\n    from scenarios.config import x\n    import sim\n")
    assert imported_packages(mod) == {"os", "scenarios", "sim"}


@pytest.mark.parametrize("package", sorted(FORBIDDEN))
def test_package_does_not_import_forbidden_packages(package):
    bad = [
        f"{p.relative_to(REPO)} imports {sorted(imported_packages(p) & FORBIDDEN[package])}"
        for p in sorted((REPO / package).rglob("*.py"))
        if imported_packages(p) & FORBIDDEN[package]
    ]
    assert not bad, "\n".join(bad)
