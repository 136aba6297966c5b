"""Find the repository's data folders as subpackages when ogscene3d runs from a source checkout.

``kernels/`` and ``configs/`` at the repository root are installed as ``ogscene3d.kernels`` and
``ogscene3d.configs``. Neither holds an ``__init__.py``: the repository root is on ``sys.path`` whenever a
command runs from it (``python -m pytest``, ``python -c``, an IDE), and a regular package called ``kernels``
there would shadow the installed distribution of that name (Hugging Face's ``kernels``, which
``transformers`` imports). A folder without ``__init__.py`` never wins over a regular package.

A wheel installs both folders inside ``ogscene3d/`` and Python finds them there. setuptools' editable finder
does not resolve a mapped folder without ``__init__.py``, so from a source checkout a finder of this module
resolves each one to its folder at the repository root, on first import.
"""

from __future__ import annotations

import sys
from importlib.machinery import ModuleSpec
from pathlib import Path

MOUNTED_FOLDERS = ("kernels", "configs")


class SourceFolderFinder:
    """A meta path finder that resolves ``<package>.<folder>`` names to folders without ``__init__.py``."""

    def __init__(self, folders: dict[str, Path]):
        self.folders = folders

    def find_spec(self, fullname: str, path=None, target=None) -> ModuleSpec | None:
        folder = self.folders.get(fullname)
        if folder is None:
            return None
        spec = ModuleSpec(fullname, None, is_package=True)
        spec.submodule_search_locations = [str(folder)]
        return spec


def mount_source_folders(package: str, package_dir: Path) -> None:
    """Resolve ``<package>.<folder>``, for each of :data:`MOUNTED_FOLDERS` that is missing from
    ``package_dir`` but present at the root of the source tree that ``package_dir`` sits in
    (``<root>/src/<package>``), to that folder."""
    if package_dir.parent.name != "src":
        return
    root = package_dir.parent.parent
    folders = {
        f"{package}.{folder}": root / folder
        for folder in MOUNTED_FOLDERS
        if not (package_dir / folder).is_dir() and (root / folder).is_dir()
    }
    if folders and not any(isinstance(f, SourceFolderFinder) for f in sys.meta_path):
        sys.meta_path.append(SourceFolderFinder(folders))
