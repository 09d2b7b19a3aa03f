"""The shape of the package, checked from the source with ast (nothing is executed):

- imports point one way only (design.md §2, style.md): core/ imports nothing of ours but core; drivers/ may import
  core.types and core.model.engine; service/ may import both;
- no import cycle among the modules of frictionwatch (core, drivers, service);
- no private name (``_x``) imported from another module of ours, except in tests/ (tests may reach kernels);
- every folder of core/, drivers/, service/ with an __init__.py is listed in pyproject.toml's
  ``[tool.setuptools] packages`` (else it is not installed).

Each check runs per top-level package, so one package's debts show on their own. The checks themselves are tried on
a small made-up tree (``test_the_checks_see_*``), so that a check that can no longer fail shows too.
"""

from __future__ import annotations

import ast
import tomllib
from collections import deque
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PREFIX = "frictionwatch."
PACKAGES = ("core", "drivers", "service")
ALLOWED = {
    "core": ("core",),
    "drivers": ("drivers", "core.types", "core.model.engine"),
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


# ---- the module import graph ------------------------------------------------------------------------------------
def module_files(root: Path, packages=PACKAGES) -> dict[str, Path]:
    """Module name (``drivers.logs.mcap_log``; a package by its folder: ``drivers.logs``) -> file."""
    out = {}
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def imports_of(name: str, path: Path, modules: dict[str, Path]):
    """(module it imports from, names taken) for every import of ours in the file, module names without the
    ``frictionwatch.`` prefix; relative imports resolved; ``import a.b`` takes no names. Imports inside functions
    count too: a lazy import is a dependency all the same."""
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import):
            found = [(a.name, ()) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            found = [(mod, tuple(a.name for a in node.names))]
        else:
            continue
        for mod, names in found:
            if mod.startswith(PREFIX):
                mod = mod[len(PREFIX):]
            if mod.split(".")[0] in PACKAGES:
                yield mod, names


def import_graph(root: Path) -> tuple[dict[str, set[str]], list[tuple[str, str]]]:
    """Edges module -> modules it imports (``from pkg import sub`` is an edge to the module pkg.sub; a name taken
    from a package is an edge to its __init__), and the private names imported: (importing module, what)."""
    modules = module_files(root)
    edges: dict[str, set[str]] = {m: set() for m in modules}
    private = []
    for name, path in modules.items():
        for mod, names in imports_of(name, path, modules):
            if not names:
                if mod in modules:
                    edges[name].add(mod)
                continue
            for n in names:
                if f"{mod}.{n}" in modules:
                    edges[name].add(f"{mod}.{n}")
                elif mod in modules:
                    edges[name].add(mod)
                if n.startswith("_") and not n.startswith("__"):
                    private.append((name, f"{mod}.{n}"))
        edges[name].discard(name)
    return edges, private


def find_cycle(edges: dict[str, set[str]], among: list[str]) -> list[str] | None:
    """One import cycle through a module of ``among`` (shortest from the first such module that has one), as the
    list of modules with the first repeated at the end; None if there is none."""
    for start in among:
        parent = {start: None}
        queue = deque([start])
        while queue:
            v = queue.popleft()
            for w in sorted(edges.get(v, ())):
                if w == start:
                    path = [v]
                    while parent[path[-1]] is not None:
                        path.append(parent[path[-1]])
                    return path[::-1] + [start]
                if w not in parent:
                    parent[w] = v
                    queue.append(w)
    return None


def unlisted_packages(root: Path, package: str) -> list[str]:
    """Folders of ``package`` with an __init__.py that pyproject.toml's [tool.setuptools] packages does not list."""
    listed = set(tomllib.loads((root / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = [PREFIX + ".".join(p.parent.relative_to(root).parts) for p in sorted((root / package).rglob("__init__.py"))]
    return [f for f in found if f not in listed]


@pytest.fixture(scope="module")
def graph():
    return import_graph(ROOT)


@pytest.mark.parametrize("package", PACKAGES)
def test_no_import_cycle(package, graph):
    edges, _ = graph
    cycle = find_cycle(edges, sorted(m for m in edges if m.split(".")[0] == package))
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


@pytest.mark.parametrize("package", PACKAGES)
def test_no_private_name_imported_across_modules(package, graph):
    _, private = graph
    bad = [f"{m} imports {what}" for m, what in private if m.split(".")[0] == package]
    assert not bad, "private names imported from another module (make them public where they belong):\n" + \
        "\n".join(bad)


@pytest.mark.parametrize("package", PACKAGES)
def test_every_package_folder_is_installed(package):
    missing = unlisted_packages(ROOT, package)
    assert not missing, f"not in pyproject.toml [tool.setuptools] packages: {missing}"


# ---- the checks on a made-up tree -------------------------------------------------------------------------------
def _tree(tmp_path: Path, files: dict[str, str], packages: list[str]) -> Path:
    for rel, text in files.items():
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text(text)
    (tmp_path / "pyproject.toml").write_text(f"[tool.setuptools]\npackages = {packages!r}\n")
    return tmp_path


def test_the_checks_see_a_cycle_a_private_import_and_an_unlisted_folder(tmp_path):
    root = _tree(tmp_path, {
        "core/__init__.py": "",
        "core/a.py": "from frictionwatch.core import b\n",
        "core/b.py": "def f():\n    from frictionwatch.core.c import _kernel\n",  # lazy: still an edge
        "core/c.py": "from .a import thing\n",
        "core/sub/__init__.py": "from frictionwatch.core.sub import d\n",  # a package re-exporting: no cycle
        "core/sub/d.py": "import frictionwatch.core.sub.e\n",
        "core/sub/e.py": "X = 1\n",
        "drivers/__init__.py": "",
        "service/__init__.py": "",
    }, ["frictionwatch.core", "frictionwatch.drivers", "frictionwatch.service"])
    edges, private = import_graph(root)
    assert edges["core.a"] == {"core.b"} and edges["core.b"] == {"core.c"} and edges["core.c"] == {"core.a"}
    assert edges["core.sub"] == {"core.sub.d"} and edges["core.sub.d"] == {"core.sub.e"}
    assert find_cycle(edges, ["core.a"]) == ["core.a", "core.b", "core.c", "core.a"]
    assert find_cycle(edges, ["core.sub", "core.sub.d", "core.sub.e"]) is None
    assert private == [("core.b", "core.c._kernel")]
    assert unlisted_packages(root, "core") == ["frictionwatch.core.sub"]
    assert unlisted_packages(root, "drivers") == []
