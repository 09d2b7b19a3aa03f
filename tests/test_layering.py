"""Imports point one way only (design.md §2, style.md): core/ imports nothing of ours but core; drivers/ may import
core.types and core.model.engine; service/ may import both. Parsed with ast so nothing is executed."""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ALLOWED = {
    "core": ("core",),
    "drivers": ("drivers", "frictionwatch.core.types", "frictionwatch.core.model.engine"),
    "service": ("service", "drivers", "core"),
}
OURS = ("core", "drivers", "service", "bench", "tests")


def imported_modules(path: Path):
    tree = ast.parse(path.read_text(), filename=str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            yield node.module


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_imports_point_one_way(package):
    bad = []
    for path in sorted((ROOT / package).rglob("*.py")):
        for mod in imported_modules(path):
            if mod.split(".")[0] in OURS:
                bad.append(f"{path.relative_to(ROOT)} imports {mod} (ours are imported as {PREFIX}*)")
                continue
            if not mod.startswith(PREFIX):
                continue
            mod = mod[len(PREFIX):]
            if not any(mod == a or mod.startswith(a + ".") for a in ALLOWED[package]):
                bad.append(f"{path.relative_to(ROOT)} imports {mod}")
    assert not bad, "imports against the layering:\n" + "\n".join(bad)
