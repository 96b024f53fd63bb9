"""The code's layout (issue: a house someone new can move into): the application's packages use each other's
public names only, and no module or folder grows past what one reader takes in."""

from __future__ import annotations

import ast
import re
import sys
import tomllib
from importlib.metadata import packages_distributions
from pathlib import Path

from packaging.utils import canonicalize_name as canonical

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("vslam", "vslam_core")
#: Where each package's folder is: the application in app/ (src-style), the engine at the top level.
FOLDERS = {"vslam": ROOT / "app" / "vslam", "vslam_core": ROOT / "vslam_core"}


def _modules() -> list[Path]:
    return [p for package in PACKAGES for p in FOLDERS[package].rglob("*.py") if "__pycache__" not in p.parts]


def test_no_subpackage_imports_a_siblings_modules() -> None:
    app = FOLDERS["vslam"]
    subpackages = {p.name for p in app.iterdir() if (p / "__init__.py").is_file()}
    offences = []
    for path in app.rglob("*.py"):
        parts = path.relative_to(app).parts
        own = parts[0] if len(parts) > 1 else None
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = node.module.split(".")
                if names[0] == "vslam" and len(names) > 2 and names[1] in subpackages and names[1] != own:
                    offences.append(f"{path.relative_to(ROOT)}:{node.lineno} from {node.module}")
    assert offences == []


def test_no_module_over_500_lines_and_no_folder_over_15_modules() -> None:
    long = [f"{p.relative_to(ROOT)} ({n})" for p in _modules() if (n := len(p.read_text().splitlines())) > 500]
    folders: dict[Path, int] = {}
    for p in _modules():
        if p.name != "__init__.py":
            folders[p.parent] = folders.get(p.parent, 0) + 1
    crowded = [f"{folder.relative_to(ROOT)} ({n})" for folder, n in folders.items() if n > 15]
    assert long == [] and crowded == []


def test_only_the_projects_own_names_are_installed() -> None:
    text = (ROOT / "pyproject.toml").read_text()
    assert 'where = ["app", "."]' in text and 'include = ["vslam*", "vslam_core*"]' in text
    assert 'vslam = "vslam.cli:main"' in text
    assert not (ROOT / "app" / "__init__.py").exists() and not (ROOT / "vslam").exists()
    assert [p.name for p in (ROOT / "app").iterdir() if p.name != "__pycache__"] == ["vslam"]


def _imported_top_level_names() -> dict[str, str]:
    """Every top-level module name the packages import (at module level or inside a function) -> one place."""
    names: dict[str, str] = {}
    for path in _modules():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                found = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                found = [node.module]
            else:
                continue
            for name in found:
                names.setdefault(name.split(".")[0], f"{path.relative_to(ROOT)}:{node.lineno}")
    return names


def test_every_imported_package_is_a_declared_dependency() -> None:
    """A plain `pip install` (no extras) must give every third-party package the code imports: a package that
    only arrives with the test tools (e.g. scipy, through evo) makes `vslam run` fail for users. The `cluster`
    extra's packages are allowed (imported only where `--ray-address` is used)."""
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    requirements = [*project["dependencies"], *project["optional-dependencies"]["cluster"]]
    declared = {canonical(re.split(r"[<>=!~; \[]", requirement, maxsplit=1)[0]) for requirement in requirements}
    distributions = packages_distributions()
    undeclared = []
    for name, where in sorted(_imported_top_level_names().items()):
        if name in sys.stdlib_module_names or name in PACKAGES or name == "__future__":
            continue
        owners = {canonical(d) for d in distributions.get(name, [name])}
        if not owners & declared:
            undeclared.append(f"{name} ({where}; distribution {', '.join(sorted(owners))})")
    assert undeclared == []


#: The application's layers, lowest first: a package imports only from its own layer or those below it, so
#: writing recordings depends on nothing that reads or scores them (issue 56).
LAYERS = (("common",), ("recording",), ("rrd",), ("runs",), ("evaluation",), ("batch", "compare", "viewer", "cli"))


def test_the_applications_layers_import_downwards() -> None:
    rank = {package: level for level, packages in enumerate(LAYERS) for package in packages}
    app = FOLDERS["vslam"]
    upward = []
    for path in app.rglob("*.py"):
        parts = path.relative_to(app).parts
        if len(parts) < 2 or parts[0] not in rank:
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = node.module.split(".")
                if names[0] == "vslam" and len(names) > 1 and rank.get(names[1], -1) > rank[parts[0]]:
                    upward.append(f"{path.relative_to(ROOT)}:{node.lineno} from {node.module}")
    assert upward == []
    assert set(rank) <= {p.name for p in app.iterdir() if (p / "__init__.py").is_file()}
