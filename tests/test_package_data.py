"""Every data folder of core/, drivers/ and service/ (files, no __init__.py) is declared in pyproject.toml as a
package with its files as package data (issue 28 item 5): setuptools otherwise installs it with a 40-line "Package
would be ignored" warning each on every install, and says a later setuptools will leave the files out."""

from __future__ import annotations

import fnmatch
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TOP = {"core": "frictionwatch.core", "drivers": "frictionwatch.drivers", "service": "frictionwatch.service"}
NOT_DATA = {"__pycache__"}
NUMBA_CACHE = (".nbi", ".nbc")  # numba's cache files beside a kernel: not ours to install


def data_folders() -> dict[str, Path]:
    """Installed name -> folder, for each folder under the three packages that holds files but no __init__.py."""
    out = {}
    for top, name in TOP.items():
        for folder in sorted((ROOT / top).rglob("*")):
            if not folder.is_dir() or NOT_DATA & set(folder.parts) or (folder / "__init__.py").exists():
                continue
            if any(p.is_file() and not p.name.endswith(NUMBA_CACHE) for p in folder.iterdir()):
                out[".".join([name, *folder.relative_to(ROOT / top).parts])] = folder
    return out


def test_every_data_folder_is_a_declared_package_with_all_its_files():
    tool = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    folders = data_folders()
    assert {"frictionwatch.core.model.engines", "frictionwatch.service.dashboard.static"} <= set(folders)
    for name, folder in folders.items():
        assert name in tool["packages"], f"{folder.relative_to(ROOT)}: list {name!r} in [tool.setuptools] packages"
        globs = tool["package-data"].get(name, [])
        files = [p.name for p in folder.iterdir() if p.is_file() and not p.name.endswith(NUMBA_CACHE)]
        missed = [f for f in files if not any(fnmatch.fnmatch(f, g) for g in globs)]
        assert not missed, f"{folder.relative_to(ROOT)}: {missed} not in its package-data {globs}"
