"""No import name of this repository shadows an installed distribution, whatever runs from the repository.

``python -m pytest``, ``python -c`` and most IDEs put the repository root on ``sys.path``; the tests'
conftest puts ``tests/helpers/`` there (pytest's own ``importlib`` mode adds no folder; ``tests/`` is checked
too, for a run in pytest's former ``prepend`` mode), and a script puts its own folder (``benchmarks/``,
``examples/``). A regular package or a module in one of these folders would be imported instead of an
installed distribution with the same top-level name: the repo's ``kernels/`` once hid Hugging Face's
``kernels`` from ``transformers`` (issue 38).
"""

from __future__ import annotations

import json
import subprocess
import sys
from importlib.metadata import packages_distributions
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# Folders that some command puts first on sys.path: the root (python -m, python -c, IDEs), tests/helpers/
# (conftest), tests/ (pytest's prepend mode), and the folders whose scripts are run directly.
PATH_FOLDERS = (ROOT, ROOT / "tests" / "helpers", ROOT / "tests", ROOT / "benchmarks", ROOT / "examples")


def _import_names(folder: Path) -> dict[str, Path]:
    """Top-level import names that ``folder`` offers when it is on sys.path: its modules and its folders
    (regular packages and namespace folders alike)."""
    names = {}
    for entry in folder.iterdir():
        if entry.name.startswith("."):
            continue
        if entry.is_dir() and entry.name.isidentifier():
            names[entry.name] = entry
        elif entry.suffix == ".py" and entry.stem.isidentifier():
            names[entry.stem] = entry
    return names


def test_no_regular_package_at_the_repository_root():
    """A folder at the root with an ``__init__.py`` would shadow any distribution of that name installed
    later, even one unknown today (a folder without one never wins over an installed regular package);
    ``kernels/`` and ``configs/`` reach the package as ``ogscene3d.kernels`` / ``ogscene3d.configs``."""
    offenders = [
        str(path.relative_to(ROOT))
        for name, path in _import_names(ROOT).items()
        if (path.is_dir() and (path / "__init__.py").is_file()) or path.is_file()
    ]
    assert offenders == [], f"importable from the repository root, would shadow a distribution: {offenders}"


def _shadowed(folder: Path, names: list[str]) -> dict[str, list[str]]:
    """The names among ``names`` that resolve to the folder's own module or folder of that name when
    ``folder`` is first on sys.path (in a fresh interpreter started there), with where they resolve. (Not
    to anything under the repository: a virtual environment made inside the checkout, ``.venv/``, holds
    the installed distribution there.)"""
    own = _import_names(folder)
    probe = (
        "import importlib.util, json, sys\n"
        f"sys.path.insert(0, {str(folder)!r})\n"
        "out = {}\n"
        "for name in json.loads(sys.argv[1]):\n"
        "    spec = importlib.util.find_spec(name)\n"
        "    out[name] = [spec.origin] + list(spec.submodule_search_locations or []) if spec else []\n"
        "print(json.dumps(out))\n"
    )
    done = subprocess.run(
        [sys.executable, "-c", probe, json.dumps(names)], cwd=folder, capture_output=True, text=True,
        check=True,
    )
    return {
        name: places
        for name, places in json.loads(done.stdout).items()
        if any(p and Path(p).resolve().is_relative_to(own[name].resolve()) for p in places)
    }


def test_installed_distributions_win_over_the_repository():
    """Every installed distribution whose import name one of the folders also offers (the test extra
    installs Hugging Face's ``kernels``) still imports from the installed distribution when that folder is
    first on sys.path, as ``python -m pytest`` puts the root."""
    installed = packages_distributions()
    shadowed = {}
    for folder in PATH_FOLDERS:
        clashes = sorted(set(_import_names(folder)) & set(installed))
        if clashes:
            shadowed.update({f"{folder.name}/{n}": p for n, p in _shadowed(folder, clashes).items()})
    assert shadowed == {}, f"repository names shadowing installed distributions: {shadowed}"


def test_the_kernels_package_imports_as_ogscene3d_kernels():
    """The Warp kernels still import under the package's name (from a wheel or a source checkout)."""
    from ogscene3d.kernels import raster

    assert Path(raster.__file__).name == "raster.py"
    import ogscene3d.kernels

    assert any(Path(p).name == "kernels" for p in ogscene3d.kernels.__path__)
